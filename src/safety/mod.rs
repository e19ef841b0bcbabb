//! Safety, in one place: the rules every command must pass and the gate that applies
//! them to the vehicle. The rules themselves are pure functions —
//! [`rules::check`] at intake, [`wire::verdict`] right before a command goes out,
//! [`gate::blockers`] for engaging and the monitor, [`safe::state`] for the safe state
//! and [`safe::manual`] for it while a driver has taken over — and act on roles bound
//! in the vehicle file, never on device names.
//!
//! A driver's override ([`Gate::take_over`]) is not a failure: the vehicle goes to the
//! manual state (nothing braking against the driver), the override is latched, and
//! engaging is refused until it is cleared ([`Gate::clear_overrides`]) with the driver's
//! hands off.
//!
//! [`Gate`] is the policy object over the [`Vehicle`]: it is engaged or not (and says
//! why), takes commands from every source (network, console, supervisor) through
//! [`Gate::submit`], counts what it rejects, and commands the safe state. The vehicle
//! itself holds state and no policy.

pub mod facts;
pub mod gate;
pub mod intake;
pub mod owner;
pub mod rules;
pub mod safe;
pub mod wire;

pub use intake::{Ask, Done, Refused};
pub use rules::{Facts, Plays, Reject, Rules};

use crate::config::Role;
use crate::logging::RateLimit;
use crate::snapshot::{GateView, Pairs, Snapshot, SCHEMA};
use crate::value::{Command, DeviceId, Kind};
use crate::vehicle::tap::{Asked, Event, GateChange, Source};
use crate::vehicle::{Device, Vehicle};
use parking_lot::Mutex;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering::Relaxed, Ordering::SeqCst};
use std::sync::Arc;
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};
use wire::Verdict;

pub use wire::Wait;

/// What the command thread does with its command, by the wire check.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum WireStep {
    Send(Command),
    Drop,
    Wait(Wait),
}

/// A command thread that waits at the wire for another device's command waits at most
/// two of that device's reply timeouts (the transaction on its wire, then this one) and
/// this much more.
const WIRE_SLACK: Duration = Duration::from_millis(50);

/// When a wait at the wire for `d` gives up.
fn wire_deadline(d: &Device) -> Instant {
    Instant::now() + d.config.reply_timeout * 2 + WIRE_SLACK
}

/// The engage gate and command intake of one vehicle.
pub struct Gate {
    pub vehicle: Arc<Vehicle>,
    rules: Rules,
    /// The roles each device's commands are checked for, by device.
    plays: Vec<Plays>,
    /// Interlock rules at intake and at the wire; switched off only from a console,
    /// with confirmation ([`Gate::set_interlocks`]).
    interlocks: AtomicBool,
    /// Who commands, and the commander's watchdog ([`intake`]).
    owner: Mutex<intake::Owner>,
    engaged: AtomicBool,
    /// Why the vehicle is (dis)engaged, for the console and the broadcast.
    reason: Mutex<String>,
    /// Devices a recovery procedure has taken over: intake refuses them.
    recovering: Vec<AtomicBool>,
    /// Devices a driver has taken over (latched `override`), by name, in order.
    overridden: Mutex<Vec<String>>,
    rejections: [AtomicU64; Reject::ALL.len()],
    /// Rejections are logged at most 10 a second (a planner at 100 Hz must not flood).
    reject_log: Mutex<RateLimit>,
}

impl Gate {
    pub fn new(vehicle: Arc<Vehicle>) -> Gate {
        let plays = vehicle
            .devices
            .iter()
            .map(|d| Plays::of(&d.roles))
            .collect();
        let recovering = vehicle
            .devices
            .iter()
            .map(|_| AtomicBool::new(false))
            .collect();
        Gate {
            rules: Rules::active(vehicle.bindings()),
            plays,
            interlocks: AtomicBool::new(true),
            owner: Mutex::new(intake::Owner::new(Instant::now())),
            engaged: AtomicBool::new(false),
            reason: Mutex::new("not engaged yet".into()),
            recovering,
            overridden: Mutex::new(Vec::new()),
            rejections: Default::default(),
            reject_log: Mutex::new(RateLimit::new(10)),
            vehicle,
        }
    }

    /// The rules active on this vehicle.
    pub fn rules(&self) -> Rules {
        self.rules
    }

    /// Say which rules are active and what is missing, once, at start.
    pub fn announce(&self) {
        tracing::info!(
            vehicle = %self.vehicle.name,
            "interlock rules: {}",
            match self.rules.names() {
                n if n.is_empty() => "none (no throttle, brake or gear bound)".to_string(),
                n => n.join(", "),
            }
        );
        for m in Rules::missing(self.vehicle.bindings()) {
            tracing::warn!(vehicle = %self.vehicle.name, "{m}");
        }
    }

    /// Rejections so far, by reason.
    pub fn rejections(&self) -> Vec<(Reject, u64)> {
        Reject::ALL
            .iter()
            .map(|r| (*r, self.rejections[r.index()].load(Relaxed)))
            .collect()
    }

    fn reject(&self, device: Option<&Device>, command: Option<Command>, why: Reject) -> Reject {
        self.rejections[why.index()].fetch_add(1, Relaxed);
        if let Some(d) = device {
            crate::vehicle::stats::Stats::bump(&d.stats.rejected);
        }
        if !self.reject_log.lock().allow(Instant::now()) {
            return why;
        }
        tracing::info!(
            device = device.map(|d| d.name()).unwrap_or("-"),
            command = match (device, command) {
                (Some(d), Some(c)) => d.config.command_text(c),
                (None, Some(c)) => format!("{c:?}"),
                _ => String::new(),
            },
            "rejected: {why}"
        );
        why
    }

    /// The interlock rules are on.
    pub fn interlocks_on(&self) -> bool {
        self.interlocks.load(Relaxed)
    }

    pub fn is_engaged(&self) -> bool {
        self.engaged.load(SeqCst)
    }

    /// Why the vehicle is engaged or not.
    pub fn reason(&self) -> String {
        self.reason.lock().clone()
    }

    /// Reasons engaging is refused right now (empty: it may engage).
    pub fn blockers(&self) -> Vec<String> {
        gate::blockers(&self.vehicle, &self.overridden.lock())
    }

    /// The devices a driver has taken over (latched overrides).
    pub fn overridden(&self) -> Vec<String> {
        self.overridden.lock().clone()
    }

    /// A driver took `device` over (`why`: the supervisor's `override`): latch it and
    /// hand the vehicle to the driver — disengaged, in the manual state (throttle and
    /// brake released, the steering no longer commanded). Already latched: nothing.
    pub fn take_over(&self, device: &str, why: &str) {
        {
            let mut o = self.overridden.lock();
            if o.iter().any(|d| d == device) {
                return;
            }
            o.push(device.to_string());
        }
        tracing::warn!(device, "driver override: {why}");
        self.leave_to_the_driver();
        self.disengage(&format!("driver override on {device}"));
    }

    /// Nothing is resent to a device the manual state does not command (the steering
    /// in the driver's hands): its pending command is dropped and its resend forgotten.
    fn leave_to_the_driver(&self) {
        let manual = safe::manual(&self.vehicle.config);
        for d in self.vehicle.devices.iter().filter(|d| d.is_actuator()) {
            if !manual.iter().any(|(id, _)| *id == d.id) {
                d.slot.reset(None);
            }
        }
    }

    /// Clear the latched overrides, unless a driver's hand is still on one of them
    /// (the supervisor still names its `override`). Returns what was cleared, or why
    /// not.
    pub fn clear_overrides(&self) -> Result<Vec<String>, String> {
        let still: Vec<String> = self
            .vehicle
            .supervision
            .faults()
            .into_iter()
            .filter(|f| f.kind == crate::snapshot::FaultKind::Override)
            .filter_map(|f| f.device)
            .collect();
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
        let cleared = std::mem::take(&mut *o);
        if !cleared.is_empty() {
            tracing::info!("override cleared: {}", cleared.join(", "));
        }
        Ok(cleared)
    }

    /// What the vehicle is commanded when it must stop: the safe state, or the manual
    /// state while a driver has taken over (one rule for every path that stops it).
    fn stop_state(&self) -> Vec<(DeviceId, Command)> {
        if self.overridden.lock().is_empty() {
            safe::state(&self.vehicle.config)
        } else {
            safe::manual(&self.vehicle.config)
        }
    }

    /// Engage: accept commands from now on. Refused while anything blocks it. Every
    /// command slot is reset first so nothing resends a stale set point: the safe
    /// state (throttle 0, brake full), steering held where it is, the rest left as
    /// they are.
    pub fn engage(&self, by: &str) -> Result<(), Vec<String>> {
        let blockers = self.blockers();
        if !blockers.is_empty() {
            tracing::warn!(by, "engage refused: {}", blockers.join("; "));
            self.tap_gate(GateChange::EngageRefused, || {
                format!("{by}: {}", blockers.join("; "))
            });
            return Err(blockers);
        }
        for d in self.vehicle.devices.iter().filter(|d| d.is_actuator()) {
            d.slot.reset(None);
        }
        self.command_safe_state();
        if let Some(s) = self.vehicle.bound(Role::Steering) {
            if let Some(p) = s.config.reading("position").and_then(|i| s.reading(i)) {
                self.store(s, Command::Set(p), Instant::now());
            }
        }
        // The reason and the state change together: a reader of both (the snapshot)
        // never sees one without the other.
        let mut reason = self.reason.lock();
        *reason = format!("engaged by {by}");
        self.engaged.store(true, SeqCst);
        drop(reason);
        tracing::info!(by, "engaged");
        self.tap_gate(GateChange::Engaged, || format!("engaged by {by}"));
        Ok(())
    }

    /// Disengage and command the safe state. Returns false if it was not engaged.
    pub fn disengage(&self, reason: &str) -> bool {
        self.disengage_into(reason, self.stop_state())
    }

    /// An operator's STOP: disengage into the full safe state — throttle 0, brake full
    /// — even while a driver has taken over. Only the stops adrive makes on its own
    /// (a fault, the watchdog, an exit) leave a driver's vehicle in the manual state;
    /// a person pressing STOP has decided to brake.
    pub fn stop(&self, reason: &str) -> bool {
        self.disengage_into(reason, safe::state(&self.vehicle.config))
    }

    fn disengage_into(&self, reason: &str, state: Vec<(DeviceId, Command)>) -> bool {
        // The reason and the state change together (see `engage`): whoever sees the
        // vehicle disengaged and then asks why reads this reason, never the last engage's.
        let mut why = self.reason.lock();
        let was = self.engaged.swap(false, SeqCst);
        *why = format!("disengaged: {reason}");
        drop(why);
        let now = Instant::now();
        for (id, c) in state {
            self.store(self.vehicle.device(id), c, now);
        }
        if was {
            tracing::warn!("disengaged: {reason}");
            self.tap_gate(GateChange::Disengaged, || format!("disengaged: {reason}"));
        }
        was
    }

    fn tap_gate(&self, change: GateChange, reason: impl FnOnce() -> String) {
        self.vehicle.tap.send(|| Event::Gate {
            at: Instant::now(),
            change,
            reason: reason(),
        });
    }

    fn tap_received(&self, source: Source, asked: Asked, at: Instant, done: Result<(), Reject>) {
        self.vehicle.tap.send(|| Event::Received {
            at,
            source,
            asked,
            refused: done.err().map(Reject::as_str),
        });
    }

    /// Check a command for a device: it must be an actuator, the value of its kind and
    /// inside its range. (Intake's first half; no state involved.)
    pub fn check_value(&self, d: &Device, command: Command) -> Result<(), Reject> {
        match (d.kind(), command) {
            (Kind::Sensor, _) => Err(Reject::NotAnActuator),
            (_, Command::Control(_)) => Ok(()),
            (Kind::State, Command::State(s)) if (s as usize) < d.config.states.len() => Ok(()),
            (Kind::State, Command::State(_)) => Err(Reject::OutOfRange),
            (Kind::Setpoint, Command::Set(v)) => {
                if !v.is_finite() {
                    return Err(Reject::NotFinite);
                }
                let [lo, hi] = d.config.range;
                if v < lo || v > hi {
                    return Err(Reject::OutOfRange);
                }
                Ok(())
            }
            _ => Err(Reject::WrongKind),
        }
    }

    /// Command intake: check the command, then store it in the device's slot and wake
    /// its command thread. `received` is when the command was born (socket read, key
    /// press). Nothing is written here; a rejected command never reaches the slot.
    pub fn submit(&self, id: DeviceId, command: Command, received: Instant) -> Result<(), Reject> {
        let Some(d) = self.vehicle.devices.get(id.index()) else {
            return Err(self.reject(None, Some(command), Reject::NoSuchDevice));
        };
        if let Err(why) = self.check_value(d, command) {
            return Err(self.reject(Some(d), Some(command), why));
        }
        if !self.is_engaged() {
            return Err(self.reject(Some(d), Some(command), Reject::Disengaged));
        }
        if self.recovering[id.index()].load(Relaxed) {
            return Err(self.reject(Some(d), Some(command), Reject::Recovering));
        }
        let plays = self.plays[id.index()];
        if !plays.is_free() && self.interlocks_on() {
            let facts = facts::gather(&self.vehicle, plays);
            if let Err(why) = rules::check(&facts, self.rules, plays, self.scaled(d, command)) {
                return Err(self.reject(Some(d), Some(command), why));
            }
        }
        self.admit_checked(d, command, received);
        // A disengage that raced this command (it checks the gate, then stores): the
        // safe state must be the last word.
        if !self.is_engaged() {
            self.command_safe_state();
        }
        Ok(())
    }

    /// The command as the rules see it: throttle and brake set points as fractions of
    /// their range's top.
    fn scaled(&self, d: &Device, command: Command) -> Command {
        match command {
            Command::Set(v) if d.plays(Role::Throttle) || d.plays(Role::Brake) => {
                Command::Set(facts::share(d, v))
            }
            other => other,
        }
    }

    /// Intake by device name (the console and tools).
    pub fn submit_named(
        &self,
        name: &str,
        command: Command,
        received: Instant,
    ) -> Result<(), Reject> {
        match self.vehicle.find(name) {
            Some(d) => self.submit(d.id, command, received),
            None => Err(self.reject(None, Some(command), Reject::NoSuchDevice)),
        }
    }

    /// Store an admitted command — or, when its port is idle and the wire check says
    /// send exactly it, write it from this thread ([`crate::vehicle::fast`]): the
    /// command thread then only reads the reply.
    fn admit_checked(&self, d: &Device, command: Command, received: Instant) {
        crate::probe::stamp(crate::probe::Step::Checked);
        crate::vehicle::stats::Stats::bump(&d.stats.received);
        use crate::vehicle::fast::{self, Sent};
        match fast::send(d, command, received, || {
            self.is_engaged() && matches!(self.wire_verdict(d, command, false), Verdict::Send(_))
        }) {
            Sent::Written | Sent::Queued { superseded: false } => {}
            Sent::Queued { superseded: true } => {
                crate::vehicle::stats::Stats::bump(&d.stats.superseded)
            }
            Sent::NotTaken => Self::queue(d, command, received),
        }
    }

    fn store(&self, d: &Device, command: Command, received: Instant) {
        crate::vehicle::stats::Stats::bump(&d.stats.received);
        Self::queue(d, command, received);
    }

    /// Into the slot, for the command thread.
    fn queue(d: &Device, command: Command, received: Instant) {
        if d.slot.submit(command, received) {
            crate::vehicle::stats::Stats::bump(&d.stats.superseded);
        }
    }

    /// The follower's virtual `accel` command, −1…1 of the pedals' ranges: positive is
    /// throttle, negative is brake; it never applies both. It is admitted or refused as
    /// a whole ([`rules::check_accel`]): a refused `accel` leaves both slots exactly as
    /// they were. Going from braking to throttle, the release is stored and the
    /// throttle with it: the throttle's command thread holds it back until the release
    /// has reached the brake ([`Wait::BrakeReleased`]), so one `accel` is enough. While
    /// a shift is under way the brake holds and positive `accel` waits. Needs throttle
    /// and brake bound.
    pub fn submit_accel(&self, a: f64, received: Instant) -> Result<(), Reject> {
        let b = self.vehicle.bindings();
        let (Some(tid), Some(bid)) = (b.throttle, b.brake) else {
            return Err(self.reject(None, None, Reject::NoSuchDevice));
        };
        let (t, br) = (self.vehicle.device(tid), self.vehicle.device(bid));
        let (throttle, brake) = if a > 0.0 { (a, 0.0) } else { (0.0, -a) };
        let top = |d: &Device| d.config.range[1];
        let parts = [
            (br, Command::Set(brake * top(br))),
            (t, Command::Set(throttle * top(t))),
        ];
        for (d, c) in parts {
            let why = if !a.is_finite() {
                Err(Reject::NotFinite)
            } else if !(-1.0..=1.0).contains(&a) {
                Err(Reject::OutOfRange)
            } else {
                self.check_value(d, c)
            };
            if let Err(why) = why {
                return Err(self.reject(Some(d), Some(c), why));
            }
        }
        if !self.is_engaged() {
            return Err(self.reject(Some(t), None, Reject::Disengaged));
        }
        if self.recovering[tid.index()].load(Relaxed) || self.recovering[bid.index()].load(Relaxed)
        {
            return Err(self.reject(Some(t), None, Reject::Recovering));
        }
        if self.interlocks_on() {
            let both = Plays {
                throttle: true,
                brake: true,
                ..Plays::default()
            };
            let facts = facts::gather(&self.vehicle, both);
            if a > 0.0 && facts.shifting {
                tracing::debug!("accel {a}: the brake holds until the shift is through");
                return Ok(());
            }
            if let Err(why) = rules::check_accel(&facts, self.rules, a) {
                let at = if why.needs().first() == Some(&Role::Brake) {
                    br
                } else {
                    t
                };
                return Err(self.reject(Some(at), None, why));
            }
        }
        // Both parts pass: the brake's first (a release the throttle follows, or the
        // throttle's release before braking), then the other.
        let (first, second) = if a > 0.0 {
            (parts[0], parts[1])
        } else {
            (parts[1], parts[0])
        };
        self.admit_checked(first.0, first.1, received);
        self.admit_checked(second.0, second.1, received);
        if !self.is_engaged() {
            self.command_safe_state();
        }
        Ok(())
    }

    /// A recovery procedure takes these devices over (intake refuses them) or, with an
    /// empty list, hands everything back.
    pub fn set_recovering(&self, ids: &[DeviceId]) {
        for (i, r) in self.recovering.iter().enumerate() {
            r.store(ids.contains(&DeviceId(i as u16)), Relaxed);
        }
    }

    pub fn is_recovering(&self, id: DeviceId) -> bool {
        self.recovering[id.index()].load(Relaxed)
    }

    /// The supervisor's own commands: past the gate and the intake interlocks (the
    /// wire-level checks still apply).
    pub fn supervise(&self, id: DeviceId, command: Command) {
        let now = Instant::now();
        self.store(self.vehicle.device(id), command, now);
        self.tap_received(Source::Supervisor, Asked::Device(id, command), now, Ok(()));
    }

    /// The wire check for the command `d`'s thread has in flight: send it (or what
    /// to send instead), drop it, or first wait for another device — which the
    /// command thread does with [`Gate::wait_for`], without holding its port, and then
    /// asks again with `waited` set (braking then goes out regardless).
    pub fn check_wire(&self, d: &Device, command: Command, waited: bool) -> WireStep {
        match self.wire_verdict(d, command, waited) {
            Verdict::Send(_) => WireStep::Send(command),
            Verdict::Replace(c, why) => {
                self.reject(Some(d), Some(command), why);
                // The rules replace with "released": the bottom of the range.
                WireStep::Send(match c {
                    Command::Set(_) => Command::Set(d.config.range[0]),
                    other => other,
                })
            }
            Verdict::Drop(why) => {
                self.reject(Some(d), Some(command), why);
                WireStep::Drop
            }
            Verdict::Wait(w) => WireStep::Wait(w),
        }
    }

    /// The wire check's verdict on `command` for `d`, counting nothing: [`wire::verdict`]
    /// over what the other devices have on their way, or `Send` when no rule applies.
    fn wire_verdict(&self, d: &Device, command: Command, waited: bool) -> Verdict {
        let plays = self.plays[d.id.index()];
        if plays.is_free() || !self.interlocks_on() {
            return Verdict::Send(command);
        }
        let f = facts::gather_wire(&self.vehicle, plays);
        wire::verdict(&f, self.rules, plays, self.scaled(d, command), waited)
    }

    /// Do what a [`WireStep::Wait`] asks, bounded by two reply timeouts of the device
    /// waited for.
    pub fn wait_for(&self, w: Wait) {
        let b = self.vehicle.bindings();
        match w {
            Wait::ThrottleReleased => {
                let Some(t) = b.throttle.map(|id| self.vehicle.device(id)) else {
                    return;
                };
                let wire = t.slot.wire();
                let going = [wire.pending, wire.flight]
                    .into_iter()
                    .flatten()
                    .filter_map(Command::set_point)
                    .any(|x| facts::share(t, x) > rules::RELEASED);
                if going {
                    self.store(t, Command::Set(t.config.range[0]), Instant::now());
                }
                t.slot
                    .wait_wire(|w| facts::released_on_wire(t, w), wire_deadline(t));
            }
            Wait::BrakeReleased => {
                let Some(br) = b.brake.map(|id| self.vehicle.device(id)) else {
                    return;
                };
                br.slot.wait_wire(
                    |w| facts::released_on_wire(br, w) || facts::brake_applied_again(br, w),
                    wire_deadline(br),
                );
            }
            Wait::ShiftOut => {
                let Some(g) = b.gear.as_ref().map(|g| self.vehicle.device(g.device)) else {
                    return;
                };
                g.slot.wait_wire(
                    |w| w.pending.or(w.flight).is_none_or(|c| Some(c) == w.sent),
                    wire_deadline(g),
                );
            }
        }
    }

    /// Command the safe state to every actuator there is, bypassing the interlocks
    /// (the safe state is always allowed) — the manual state while a driver has taken
    /// over.
    pub fn command_safe_state(&self) {
        let now = Instant::now();
        if !self.overridden.lock().is_empty() {
            // A command that raced the override (checked before it, stored after its
            // reset) must not be left to resend to the driver's device.
            self.leave_to_the_driver();
        }
        for (id, c) in self.stop_state() {
            self.store(self.vehicle.device(id), c, now);
        }
    }

    /// Wait until every reachable device acknowledged its part of the safe state.
    /// Returns false if one did not by the deadline.
    pub fn wait_safe(&self, deadline: Instant) -> bool {
        let mut ok = true;
        for (id, want) in self.stop_state() {
            let d = self.vehicle.device(id);
            if !d.slot.wait_executed(|c| c == want, deadline) {
                tracing::error!(device = %d.name(), "did not acknowledge the safe state");
                ok = false;
            }
        }
        ok
    }

    /// The gate's part of the snapshot.
    pub fn view(&self, now: Instant) -> GateView {
        let b = self.vehicle.bindings();
        let who = self.command_view(now);
        GateView {
            commander: who.commander,
            watchdog: who.watchdog,
            refused: who.refused,
            last_refused: who.last_refused,
            engaged: self.is_engaged(),
            reason: self.reason(),
            blockers: self.blockers(),
            interlocks: self.interlocks_on(),
            rules: self.rules.names().into_iter().map(str::to_string).collect(),
            roles: self.vehicle.role_names(),
            accel: b.has_accel(),
            overridden: self.overridden(),
        }
    }

    /// The whole vehicle now (without the network part, which the network adds).
    pub fn snapshot(&self, seq: u64) -> Snapshot {
        self.snapshot_at(seq, Instant::now())
    }

    /// The whole vehicle, ages as of `now` (the console draws one instant).
    pub fn snapshot_at(&self, seq: u64, now: Instant) -> Snapshot {
        Snapshot {
            schema: SCHEMA,
            vehicle: self.vehicle.name.clone(),
            seq,
            time_ms: SystemTime::now()
                .duration_since(UNIX_EPOCH)
                .map(|d| d.as_millis() as u64)
                .unwrap_or(0),
            uptime_s: now
                .saturating_duration_since(self.vehicle.started)
                .as_secs_f64(),
            gate: self.view(now),
            devices: self.vehicle.device_views(now),
            supervisor: self.vehicle.supervision.snapshot(),
            rejections: self
                .rejections()
                .into_iter()
                .map(|(r, n)| (r.as_str().to_string(), n))
                .collect::<Pairs<u64>>(),
            net: None,
            record: self.vehicle.tap.status(),
            part: None,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::console::sample;

    /// Alice's sample with the brake sent full and its release waiting in its slot.
    fn releasing() -> Arc<Gate> {
        let gate = sample::gate(Instant::now());
        let brake = gate.vehicle.find("brake").unwrap();
        brake.slot.fly(Command::Set(1.0));
        brake.slot.finish(Command::Set(1.0), true);
        brake.slot.submit(Command::Set(0.0), Instant::now());
        gate
    }

    /// Throttle behind a release waits for it a bounded time — two brake reply timeouts
    /// and a little — and, the release not landed, goes out as 0.
    #[test]
    fn throttle_behind_a_release_that_never_lands_goes_out_as_zero() {
        let gate = releasing();
        let (gas, brake) = (
            gate.vehicle.find("gas").unwrap(),
            gate.vehicle.find("brake").unwrap(),
        );
        let throttle = Command::Set(0.3);
        assert_eq!(
            gate.check_wire(gas, throttle, false),
            WireStep::Wait(Wait::BrakeReleased)
        );
        let t = Instant::now();
        gate.wait_for(Wait::BrakeReleased);
        assert!(t.elapsed() >= brake.config.reply_timeout * 2 + WIRE_SLACK);
        assert_eq!(
            gate.check_wire(gas, throttle, true),
            WireStep::Send(Command::Set(0.0))
        );
    }

    /// The incident: a planner repeats `trans drive` in every datagram (the README's own
    /// example does). In drive, with the repeat pending in the gearbox's slot, a brake
    /// release waited up to 450 ms at the wire for that slot to drain although no
    /// shift was under way; brake commands executed per second halved. A gear command
    /// that repeats the last one sent is not a shift: the release goes out at once,
    /// from intake to the wire. (A real shift still holds it: the test after this.)
    #[test]
    fn a_repeated_trans_drive_does_not_hold_a_brake_release() {
        let gate = sample::gate(Instant::now());
        let v = &gate.vehicle;
        let (trans, brake) = (v.find("trans").unwrap(), v.find("brake").unwrap());
        let drive = Command::State(trans.config.state_index("drive").unwrap());
        // In drive: shifted, acknowledged, and reported by a status taken after that.
        trans.slot.fly(drive);
        trans.slot.finish(drive, true);
        *trans.cache.lock() = crate::vehicle::Cached {
            reading: {
                let mut r = crate::value::Reading::default();
                r.set(0, 3.0);
                r
            },
            at: Some(Instant::now()),
        };
        gate.engage("test").unwrap();
        // The planner's datagram: `trans drive` again, and the brake released.
        gate.submit(trans.id, drive, Instant::now()).unwrap();
        let release = Command::Set(0.0);
        assert_eq!(gate.submit(brake.id, release, Instant::now()), Ok(()));
        assert_eq!(
            gate.check_wire(brake, release, false),
            WireStep::Send(release),
            "the release must not wait for the repeated gear command"
        );
    }

    /// A real shift on its way (a gear other than the last one sent) still keeps the
    /// brake on until it is out.
    #[test]
    fn a_shift_on_its_way_holds_a_brake_release() {
        let gate = sample::gate(Instant::now());
        let v = &gate.vehicle;
        let (trans, brake) = (v.find("trans").unwrap(), v.find("brake").unwrap());
        let drive = Command::State(trans.config.state_index("drive").unwrap());
        trans.slot.submit(drive, Instant::now());
        assert_eq!(
            gate.check_wire(brake, Command::Set(0.0), false),
            WireStep::Wait(Wait::ShiftOut)
        );
    }

    /// The release lands while the throttle waits: the throttle goes out as it is.
    #[test]
    fn throttle_behind_a_release_that_lands_goes_out() {
        let gate = releasing();
        let (gas, brake) = (
            gate.vehicle.find("gas").unwrap(),
            gate.vehicle.find("brake").unwrap(),
        );
        let throttle = Command::Set(0.3);
        assert_eq!(
            gate.check_wire(gas, throttle, false),
            WireStep::Wait(Wait::BrakeReleased)
        );
        std::thread::scope(|s| {
            s.spawn(|| {
                brake.slot.take_newer().expect("the release");
                brake.slot.fly(Command::Set(0.0));
                brake.slot.finish(Command::Set(0.0), true);
            });
            gate.wait_for(Wait::BrakeReleased);
        });
        assert_eq!(
            gate.check_wire(gas, throttle, true),
            WireStep::Send(throttle)
        );
    }
}
