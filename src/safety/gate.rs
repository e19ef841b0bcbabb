//! The gate's state and its decisions: whether the vehicle is engaged and why, who
//! commands it ([`super::owner`]), whether the interlocks are on, which devices a
//! recovery or a driver has taken over, and what was refused. Each decision is a
//! function of that state and the vehicle's caches — [`blockers`] for engaging,
//! [`GateState::check`] for a command at intake, [`GateState::wire_verdict`] right
//! before one goes out — and none moves anything: the engine applies them
//! ([`crate::engine::Gate`]).

use super::facts;
use super::owner::Owner;
use super::rules::{self, Plays, Reject, Rules};
use super::safe;
use super::wire::{self, Verdict};
use crate::config::{DriverKind, Role};
use crate::driver::elm327;
use crate::logging::RateLimit;
use crate::value::{Command, DeviceId, EstopState, Kind};
use crate::vehicle::{Device, Vehicle};
use parking_lot::{Mutex, MutexGuard};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering::Relaxed, Ordering::SeqCst};
use std::time::Instant;

/// Whether engaging needs `d`: the rules act on it (it is bound to a role — steering,
/// throttle, brake, gear, e-stop, speed, engine running, starter), so the vehicle is not
/// engaged without it. A device bound to no role (a horn, turn signals, a battery
/// monitor) is shown when it is faulty or gone, and never refuses nor ends an
/// engagement: it cannot make the vehicle unsafe, and a vehicle that would wait for its
/// horn is a vehicle that cannot be driven.
pub fn needed(v: &Vehicle, d: &Device) -> bool {
    Role::ALL
        .into_iter()
        .any(|r| v.bindings().device(r) == Some(d.id()))
}

/// What refuses an engage now, and disengages an engaged vehicle (empty: all clear).
pub fn blockers(v: &Vehicle, overridden: &[String]) -> Vec<String> {
    let mut why = Vec::new();
    for d in overridden {
        why.push(format!(
            "{d} is in the driver's hands (override): clear it once the driver has let go"
        ));
    }
    for d in v.devices().iter().filter(|d| needed(v, d)) {
        if let Some(fault) = d.fault() {
            why.push(format!("{} is faulty ({fault})", d.name()));
        } else if d.cached().at.is_none() {
            // An ELM327 that opened has its first answer coming: it searches protocols.
            let opened = d.port_health().opens.load(Relaxed) > 0;
            why.push(match d.config().driver {
                DriverKind::Elm327 if opened => elm327::searching(d.name()),
                _ => format!("{} has not reported yet", d.name()),
            });
        }
    }
    if let Some(s @ (EstopState::Pause | EstopState::Disable)) = v.estop() {
        why.push(format!("e-stop is in {s}"));
    }
    for s in v.supervision().stalled() {
        why.push(format!("thread {}", s.describe()));
    }
    why
}

/// Check a command for a device: it must be an actuator, the value of its kind and
/// inside its range. (Intake's first half; no state involved.)
pub(crate) fn check_value(d: &Device, command: Command) -> Result<(), Reject> {
    match (d.kind(), command) {
        (Kind::Sensor, _) => Err(Reject::NotAnActuator),
        (_, Command::Control(_)) => Ok(()),
        (Kind::State, Command::State(s)) if (s as usize) < d.config().states.len() => Ok(()),
        (Kind::State, Command::State(_)) => Err(Reject::OutOfRange),
        (Kind::Setpoint, Command::Set(v)) => {
            if !v.is_finite() {
                return Err(Reject::NotFinite);
            }
            let [lo, hi] = d.config().range;
            if v < lo || v > hi {
                return Err(Reject::OutOfRange);
            }
            Ok(())
        }
        _ => Err(Reject::WrongKind),
    }
}

/// The command as the rules see it: throttle and brake set points as fractions of
/// their range's top.
pub fn scaled(d: &Device, command: Command) -> Command {
    match command {
        Command::Set(v) if d.plays(Role::Throttle) || d.plays(Role::Brake) => {
            Command::Set(facts::share(d, v))
        }
        other => other,
    }
}

/// Why the vehicle is (dis)engaged: the words, and the device whose driver's override
/// it was (the words then say whether that override is still latched).
struct Reason {
    words: String,
    overridden: Option<String>,
}

impl Reason {
    fn said(words: &str) -> Reason {
        Reason {
            words: words.to_string(),
            overridden: None,
        }
    }
}

/// The engage gate's state over one vehicle.
pub struct GateState {
    rules: Rules,
    /// The roles each device's commands are checked for, by device.
    plays: Vec<Plays>,
    /// Interlock rules at intake and at the wire; switched off only from a console,
    /// with confirmation.
    interlocks: AtomicBool,
    /// Who commands, and the commander's watchdog: the intake's one lock.
    owner: Mutex<Owner>,
    engaged: AtomicBool,
    /// Why the vehicle is (dis)engaged, rendered by [`GateState::reason`].
    reason: Mutex<Reason>,
    /// Devices a recovery procedure has taken over: intake refuses them.
    recovering: Vec<AtomicBool>,
    /// Devices a driver has taken over (latched `override`), by name, in order.
    overridden: Mutex<Vec<String>>,
    rejections: [AtomicU64; Reject::ALL.len()],
    /// Rejections are logged at most 10 a second (a planner at 100 Hz must not flood).
    reject_log: Mutex<RateLimit>,
}

impl GateState {
    pub fn new(vehicle: &Vehicle) -> GateState {
        GateState {
            rules: Rules::active(vehicle.bindings()),
            plays: vehicle
                .devices()
                .iter()
                .map(|d| Plays::of(d.roles()))
                .collect(),
            interlocks: AtomicBool::new(true),
            owner: Mutex::new(Owner::new(Instant::now())),
            engaged: AtomicBool::new(false),
            reason: Mutex::new(Reason::said("not engaged yet")),
            recovering: vehicle
                .devices()
                .iter()
                .map(|_| AtomicBool::new(false))
                .collect(),
            overridden: Mutex::new(Vec::new()),
            rejections: Default::default(),
            reject_log: Mutex::new(RateLimit::new(10)),
        }
    }

    /// The rules active on this vehicle.
    pub fn rules(&self) -> Rules {
        self.rules
    }

    /// Who commands, under the intake's lock.
    pub fn owner(&self) -> MutexGuard<'_, Owner> {
        self.owner.lock()
    }

    /// The interlock rules are on.
    pub(crate) fn interlocks_on(&self) -> bool {
        self.interlocks.load(Relaxed)
    }

    /// Switch the interlocks (the intake decides who may: [`super::owner`]).
    pub(crate) fn set_interlocks(&self, on: bool) {
        self.interlocks.store(on, Relaxed);
    }

    pub fn is_engaged(&self) -> bool {
        self.engaged.load(SeqCst)
    }

    /// Why the vehicle is engaged or not, in the words every reader shows — the
    /// snapshot (the broadcast, `adrive ctl status`, consoles, recordings), the
    /// network's answers and the logs: the one place they are rendered.
    pub fn reason(&self) -> String {
        let r = self.reason.lock();
        match &r.overridden {
            Some(d) if !self.overridden.lock().contains(d) => format!("{}, cleared", r.words),
            _ => r.words.clone(),
        }
    }

    /// Engaged by `by`. The reason and the state change together: a reader of both
    /// (the snapshot) never sees one without the other.
    pub(crate) fn set_engaged(&self, by: &str) {
        let mut reason = self.reason.lock();
        *reason = Reason::said(&format!("engaged by {by}"));
        self.engaged.store(true, SeqCst);
    }

    /// Disengaged for `reason`; returns whether it was engaged. The reason and the
    /// state change together: whoever sees the vehicle disengaged and then asks why
    /// reads this reason, never the last engage's.
    pub(crate) fn set_disengaged(&self, reason: &str) -> bool {
        self.disengaged_for(Reason::said(&format!("disengaged: {reason}")))
    }

    /// Disengaged because a driver took `device` over: said so while the override is
    /// latched, and said to be cleared once it is ([`GateState::reason`]).
    pub(crate) fn set_disengaged_by_override(&self, device: &str) -> bool {
        self.disengaged_for(Reason {
            words: format!("disengaged: driver override on {device}"),
            overridden: Some(device.to_string()),
        })
    }

    fn disengaged_for(&self, reason: Reason) -> bool {
        let mut why = self.reason.lock();
        let was = self.engaged.swap(false, SeqCst);
        *why = reason;
        was
    }

    /// Count (and log, at most 10 a second) a rejection of `command` for `device`.
    pub(crate) fn reject(
        &self,
        device: Option<&Device>,
        command: Option<Command>,
        why: Reject,
    ) -> Reject {
        self.rejections[why.index()].fetch_add(1, Relaxed);
        if let Some(d) = device {
            crate::vehicle::stats::Stats::bump(&d.stats().rejected);
        }
        if !self.log_allowed(Instant::now()) {
            return why;
        }
        tracing::info!(
            device = device.map(|d| d.name()).unwrap_or("-"),
            command = match (device, command) {
                (Some(d), Some(c)) => d.config().command_text(c),
                (None, Some(c)) => format!("{c:?}"),
                _ => String::new(),
            },
            "rejected: {why}"
        );
        why
    }

    /// Whether a refusal at `at` may be logged (at most 10 a second).
    pub(crate) fn log_allowed(&self, at: Instant) -> bool {
        self.reject_log.lock().allow(at)
    }

    /// Rejections so far, by reason.
    pub fn rejections(&self) -> Vec<(Reject, u64)> {
        Reject::ALL
            .iter()
            .map(|r| (*r, self.rejections[r.index()].load(Relaxed)))
            .collect()
    }

    /// Reasons engaging is refused right now (empty: it may engage).
    pub fn blockers(&self, v: &Vehicle) -> Vec<String> {
        blockers(v, &self.overridden.lock())
    }

    /// The devices a driver has taken over (latched overrides).
    pub fn overridden(&self) -> Vec<String> {
        self.overridden.lock().clone()
    }

    /// Latch a driver's override of `device`; false if it was latched already.
    pub(crate) fn latch_override(&self, device: &str) -> bool {
        let mut o = self.overridden.lock();
        if o.iter().any(|d| d == device) {
            return false;
        }
        o.push(device.to_string());
        true
    }

    /// Clear the latched overrides, unless a driver's hand is still on one of them
    /// (`still`: the devices the supervisor still names an `override` for). Returns
    /// what was cleared, or why not.
    pub fn clear_overrides(&self, still: &[String]) -> Result<Vec<String>, String> {
        let mut o = self.overridden.lock();
        let held: Vec<&str> = o
            .iter()
            .filter(|d| still.contains(d))
            .map(String::as_str)
            .collect();
        if !held.is_empty() {
            return Err(format!(
                "override not cleared: the driver is still moving {} (let go first)",
                held.join(", ")
            ));
        }
        Ok(std::mem::take(&mut *o))
    }

    /// What the vehicle is commanded when it must stop: the safe state, or the manual
    /// state while a driver has taken over (one rule for every path that stops it).
    /// While the e-stop is in pause or disable its rule holds — brake full, gas 0 —
    /// over a driver's too: a person stopped the vehicle, as with an operator's STOP.
    pub(crate) fn stop_state(&self, v: &Vehicle) -> Vec<(DeviceId, Command)> {
        let halted = v.estop().is_some_and(EstopState::halts);
        if halted || self.overridden.lock().is_empty() {
            safe::state(v.config())
        } else {
            safe::manual(v.config())
        }
    }

    /// A recovery procedure takes these devices over (intake refuses them) or, with an
    /// empty list, hands everything back.
    pub(crate) fn set_recovering(&self, ids: &[DeviceId]) {
        for (i, r) in self.recovering.iter().enumerate() {
            r.store(ids.contains(&DeviceId(i as u16)), Relaxed);
        }
    }

    pub fn is_recovering(&self, id: DeviceId) -> bool {
        self.recovering[id.index()].load(Relaxed)
    }

    /// The intake's decision on `command` for `d`: its value, the gate, a recovery,
    /// then the interlocks over what the vehicle is doing now.
    pub fn check(&self, v: &Vehicle, d: &Device, command: Command) -> Result<(), Reject> {
        check_value(d, command)?;
        if !self.is_engaged() {
            return Err(Reject::Disengaged);
        }
        if self.is_recovering(d.id()) {
            return Err(Reject::Recovering);
        }
        let plays = self.plays[d.id().index()];
        if !plays.is_free() && self.interlocks_on() {
            let facts = facts::gather(v, plays);
            rules::check(&facts, self.rules, plays, scaled(d, command))?;
        }
        Ok(())
    }

    /// The wire check's verdict on `command` for `d`, counting nothing: [`wire::verdict`]
    /// over what the other devices have on their way, or `Send` when no rule applies.
    pub(crate) fn wire_verdict(
        &self,
        v: &Vehicle,
        d: &Device,
        command: Command,
        waited: bool,
    ) -> Verdict {
        let plays = self.plays[d.id().index()];
        if plays.is_free() || !self.interlocks_on() {
            return Verdict::Send(command);
        }
        let f = facts::gather_wire(v, plays);
        wire::verdict(&f, self.rules, plays, scaled(d, command), waited)
    }
}
