//! The gate's state and its decisions: whether the vehicle is engaged and why, who
//! commands it ([`super::owner`]), whether the interlocks are on, which devices a
//! recovery or a driver has taken over, and what was refused. Each decision is a
//! function of that state and the vehicle's caches — [`blockers`] for engaging,
//! [`GateState::check`] for a command at intake, [`GateState::wire_verdict`] right
//! before one goes out — and none moves anything: the engine applies them
//! ([`crate::engine::Gate`]).

use super::accel::{self, Pedal, Plan};
use super::facts;
use super::owner::Owner;
use super::rules::{self, Plays, Reject, Rules};
use super::safe;
use super::wire::{self, Verdict};
use crate::config::{DeviceConfig, Role};
use crate::driver::slcan::Kits;
use crate::logging::RateLimit;
use crate::snapshot::{Blocker, DisengageCause, GateCause};
use crate::value::{Command, DeviceId, EstopState, Kind};
pub use crate::vehicle::seen::Seen;
use crate::vehicle::{Device, Unreported, Vehicle};
use parking_lot::{Mutex, MutexGuard};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering::Relaxed, Ordering::SeqCst};
use std::sync::Arc;
use std::time::Instant;

/// Whether engaging needs `d`: the rules act on it (it is bound to a role — steering,
/// throttle, brake, gear, e-stop, speed, engine running, starter), so the vehicle is not
/// engaged without it. A device bound to no role (a horn, turn signals, a battery
/// monitor) is shown when it is faulty or gone, and never refuses nor ends an
/// engagement: it cannot make the vehicle unsafe, and a vehicle that would wait for its
/// horn is a vehicle that cannot be driven.
pub(crate) fn needed(v: &Vehicle, d: &Device) -> bool {
    Role::ALL
        .into_iter()
        .any(|r| v.bindings().device(r) == Some(d.id()))
}

/// Whether a remote source (a network sender, the ROS 2 node) may ask to engage: where
/// the vehicle file lets the network engage (`allow_engage`), or when the vehicle is
/// engaged already — picking up a vehicle a console engaged and released engages
/// nothing, and who may pick it up is ownership's to decide ([`super::owner`]).
pub(crate) fn remote_may_engage(allow_engage: bool, engaged: bool) -> bool {
    allow_engage || engaged
}

/// What refuses an engage now, and disengages an engaged vehicle (empty: all clear).
pub(crate) fn blockers(v: &Vehicle, overridden: &[String]) -> Vec<Blocker> {
    let mut why: Vec<Blocker> = overridden
        .iter()
        .map(|d| Blocker::Overridden { device: d.clone() })
        .collect();
    for d in v.devices().iter().filter(|d| needed(v, d)) {
        let device = d.name().to_string();
        if let Some(fault) = d.fault() {
            why.push(Blocker::Faulty { device, fault });
        } else if let Some(u) = d.unreported() {
            why.push(match u {
                Unreported::SearchingProtocols(up_to) => Blocker::Searching {
                    device,
                    up_to_s: up_to.as_secs(),
                },
                Unreported::NotYet => Blocker::NotReported { device },
            });
        }
    }
    if let Some(state @ (EstopState::Pause | EstopState::Disable)) = v.estop() {
        why.push(Blocker::Estop { state });
    }
    for stall in v.supervision().stalled() {
        why.push(Blocker::Stalled { stall });
    }
    why
}

/// Check a command for a device: it must be an actuator, the value of its kind and
/// inside its range, or a drive control its protocol carries. (Intake's first half;
/// no state involved.)
pub(crate) fn check_value(d: &DeviceConfig, command: Command) -> Result<(), Reject> {
    match (d.kind, command) {
        (Kind::Sensor, _) => Err(Reject::NotAnActuator),
        (_, Command::Control(c)) => d.takes_control(c).map_err(|_| Reject::NoSuchControl),
        (Kind::State, Command::State(s)) if (s as usize) < d.states.len() => Ok(()),
        (Kind::State, Command::State(_)) => Err(Reject::OutOfRange),
        (Kind::Setpoint, Command::Set(v)) => {
            if !v.is_finite() {
                return Err(Reject::NotFinite);
            }
            let [lo, hi] = d.range;
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
pub(crate) fn scaled(d: &DeviceConfig, plays: Plays, command: Command) -> Command {
    match command {
        Command::Set(v) if plays.throttle || plays.brake => Command::Set(facts::share(d, v)),
        other => other,
    }
}

/// The intake's decision on `command` for a device `d` of a vehicle file, whose
/// commands are checked for the roles `plays`, under `rules`, given what it `seen`: its
/// value, the gate, a recovery, then the interlocks. A pure function: the live intake
/// ([`GateState::check`]) and `adrive replay --check` both decide with it.
pub(crate) fn decide(
    d: &DeviceConfig,
    plays: Plays,
    rules: Rules,
    command: Command,
    seen: &Seen,
) -> Result<(), Reject> {
    check_value(d, command)?;
    if !seen.engaged {
        return Err(Reject::Disengaged);
    }
    if seen.recovering {
        return Err(Reject::Recovering);
    }
    if !plays.is_free() && seen.interlocks {
        let facts = seen.facts.unwrap_or_default();
        rules::check(&facts, rules, plays, scaled(d, plays, command))?;
    }
    Ok(())
}

/// The intake's decision on the virtual `accel` for these pedals (as [`decide`] for one
/// device): its value, the gate, a recovery of either pedal, then the interlocks over
/// both ([`accel::interlocks`]). Admitted, what it sends.
pub(crate) fn decide_accel(
    throttle: &DeviceConfig,
    brake: &DeviceConfig,
    rules: Rules,
    a: f64,
    seen: &Seen,
) -> Result<Plan, accel::PedalReject> {
    accel::check_value(throttle, brake, a)?;
    let refused = |why| accel::PedalReject {
        why,
        at: Pedal::Throttle,
        command: None,
    };
    if !seen.engaged {
        return Err(refused(Reject::Disengaged));
    }
    if seen.recovering {
        return Err(refused(Reject::Recovering));
    }
    if seen.interlocks {
        accel::interlocks(&seen.facts.unwrap_or_default(), rules, a)?;
    }
    Ok(Plan::of(a))
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
    /// The vehicle's kit switch ([`Kits`]): a kit is enabled only while the vehicle is
    /// engaged — on from the start of an engage ([`GateState::engaging`]), off with the
    /// disengage, in the same step as `engaged`.
    kits: Arc<Kits>,
    /// Why the vehicle is (dis)engaged ([`GateState::cause`]).
    cause: Mutex<GateCause>,
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
            kits: vehicle.kits().clone(),
            cause: Mutex::new(GateCause::NotEngagedYet),
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

    /// Why the vehicle is engaged or not, as a type: a driver's override is said to be
    /// cleared once it is no longer latched.
    pub fn cause(&self) -> GateCause {
        let mut cause = self.cause.lock().clone();
        if let GateCause::Disengaged {
            why: DisengageCause::Override { device, cleared },
        } = &mut cause
        {
            *cleared = !self.overridden.lock().contains(device);
        }
        cause
    }

    /// Why the vehicle is engaged or not, in the words every reader shows — the
    /// snapshot (the broadcast, `adrive ctl status`, consoles, recordings), the
    /// network's answers and the logs: [`GateCause`]'s.
    pub fn reason(&self) -> String {
        self.cause().to_string()
    }

    /// An engage begins: the kits may be enabled from now on, each once its safe
    /// command has gone out (a kit is enabled only while the vehicle is engaged, and
    /// never before the command it will act on).
    pub(crate) fn engaging(&self) {
        self.kits.set(true);
    }

    /// Engaged by `by`. The cause and the state change together: a reader of both
    /// (the snapshot) never sees one without the other.
    pub(crate) fn set_engaged(&self, by: &str) {
        let mut cause = self.cause.lock();
        *cause = GateCause::Engaged { by: by.to_string() };
        self.engaged.store(true, SeqCst);
    }

    /// Disengaged for `why`; returns whether it was engaged. The cause and the state
    /// change together: whoever sees the vehicle disengaged and then asks why reads
    /// this cause, never the last engage's.
    pub(crate) fn set_disengaged(&self, why: DisengageCause) -> bool {
        let mut cause = self.cause.lock();
        self.disengaged(&mut cause, why)
    }

    /// Disengaged for `why`, under the cause's lock (`cause`); whether it was engaged.
    fn disengaged(&self, cause: &mut GateCause, why: DisengageCause) -> bool {
        let was = self.engaged.swap(false, SeqCst);
        // Kits disable with the vehicle, before the stop's commands are stored.
        self.kits.set(false);
        *cause = GateCause::Disengaged { why };
        was
    }

    /// Disengaged for `why` if it is still engaged; otherwise nothing changes and
    /// false. For the decisions taken while engaged (a blocker, a fault, a stalled
    /// thread, the watchdog): whoever disengaged first between that look and this
    /// step (a driver's override, an operator's STOP) keeps their cause.
    pub(crate) fn set_disengaged_if_engaged(&self, why: DisengageCause) -> bool {
        let mut cause = self.cause.lock();
        self.is_engaged() && self.disengaged(&mut cause, why)
    }

    /// Count (and log, at most 10 a second) a rejection of `command` for `device`.
    pub(crate) fn reject(
        &self,
        device: Option<&Device>,
        command: Option<Command>,
        why: Reject,
    ) -> Reject {
        self.rejected(device, why, || match (device, command) {
            (Some(d), Some(c)) => d.config().command_text(c),
            (None, Some(c)) => format!("{c:?}"),
            _ => "-".into(),
        })
    }

    /// [`GateState::reject`] for an accel `a` refused as a whole (at `device`, the
    /// pedal that refused it, where one did, and `part`, its share, where that is what
    /// was refused): logged as the accel asked, `accel 1.500 (gas 1.500)` (it was
    /// logged with `command=""`).
    pub(crate) fn reject_accel(
        &self,
        device: Option<&Device>,
        a: f64,
        part: Option<Command>,
        why: Reject,
    ) -> Reject {
        self.rejected(device, why, || match (device, part) {
            (Some(d), Some(c)) => {
                format!("accel {a:.3} ({} {})", d.name(), d.config().command_text(c))
            }
            _ => format!("accel {a:.3}"),
        })
    }

    fn rejected(
        &self,
        device: Option<&Device>,
        why: Reject,
        said: impl FnOnce() -> String,
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
            command = said(),
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
    pub fn blockers(&self, v: &Vehicle) -> Vec<Blocker> {
        blockers(v, &self.overridden.lock())
    }

    /// The devices a driver has taken over (latched overrides).
    pub fn overridden(&self) -> Vec<String> {
        self.overridden.lock().clone()
    }

    /// A driver took `device` over: latch it and disengage for it in one step, so that
    /// nobody sees the override latched on a vehicle still engaged (the gate's monitor
    /// would take it for a blocker and disengage for it, and its words, not the
    /// override's, would be said). `None` if it was latched already (nothing changes);
    /// otherwise whether the vehicle was engaged.
    pub(crate) fn take_over(&self, device: &str) -> Option<bool> {
        let mut cause = self.cause.lock();
        {
            let mut o = self.overridden.lock();
            if o.iter().any(|d| d == device) {
                return None;
            }
            o.push(device.to_string());
        }
        let why = DisengageCause::Override {
            device: device.to_string(),
            cleared: false,
        };
        Some(self.disengaged(&mut cause, why))
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
        self.decided(v, d, command).0
    }

    /// [`GateState::check`], and what it saw ([`decide`]).
    pub(crate) fn decided(
        &self,
        v: &Vehicle,
        d: &Device,
        command: Command,
    ) -> (Result<(), Reject>, Seen) {
        let plays = self.plays[d.id().index()];
        let seen = self.seen(v, plays, self.is_recovering(d.id()));
        (decide(d.config(), plays, self.rules, command, &seen), seen)
    }

    /// The intake's decision on the virtual `accel` (−1 … 1) for the bound pedals, and
    /// what it saw ([`decide_accel`]); `None` where throttle and brake are not both
    /// bound.
    pub(crate) fn decided_accel(
        &self,
        v: &Vehicle,
        a: f64,
    ) -> Option<(Result<Plan, accel::PedalReject>, Seen)> {
        let b = v.bindings();
        let (t, br) = (b.throttle?, b.brake?);
        let recovering = self.is_recovering(t) || self.is_recovering(br);
        let seen = self.seen(v, accel::PEDALS, recovering);
        let (t, br) = (v.device(t).config(), v.device(br).config());
        Some((decide_accel(t, br, self.rules, a, &seen), seen))
    }

    /// What a decision for a device that plays `plays` sees now: the gate's state and,
    /// where the interlocks will look, their facts (gathered only then).
    fn seen(&self, v: &Vehicle, plays: Plays, recovering: bool) -> Seen {
        let engaged = self.is_engaged();
        let interlocks = self.interlocks_on();
        let look = engaged && !recovering && interlocks && !plays.is_free();
        Seen {
            engaged,
            recovering,
            interlocks,
            facts: look.then(|| facts::gather(v, plays)),
        }
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
        let c = d.config();
        match wire::verdict(&f, self.rules, plays, scaled(c, plays, command), waited) {
            // The rules replace with "released": the bottom of the range.
            Verdict::Replace(Command::Set(_), why) => Verdict::Replace(facts::release(c), why),
            Verdict::Send(_) => Verdict::Send(command),
            other => other,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn state() -> (Vehicle, GateState) {
        let v = crate::testkit::vehicle(Instant::now());
        let s = GateState::new(&v);
        (v, s)
    }

    /// The words every reader shows (the snapshot, the network's answers, the logs) are
    /// the cause's: not engaged yet, engaged by whom, disengaged and why — a driver's
    /// override said to be cleared once it is no longer latched.
    #[test]
    fn the_reason_is_the_causes_words() {
        let (_v, s) = state();
        assert_eq!(s.reason(), "not engaged yet");
        s.set_engaged("console #1");
        assert_eq!(s.reason(), "engaged by console #1");
        s.set_disengaged(DisengageCause::Stop {
            by: "console #2".into(),
        });
        assert_eq!(s.reason(), "disengaged: stop from console #2");
        assert_eq!(s.take_over("brake"), Some(false));
        assert_eq!(s.reason(), "disengaged: driver override on brake");
        s.clear_overrides(&[]).unwrap();
        assert_eq!(s.reason(), "disengaged: driver override on brake, cleared");
        assert_eq!(s.reason(), s.cause().to_string());
    }

    /// Engaging needs every device bound to a role, and no other: a horn that is
    /// faulty holds up nothing, a brake that is does.
    #[test]
    fn engaging_needs_the_devices_bound_to_a_role_and_no_other() {
        let now = Instant::now();
        let text = format!(
            "{}\n[[device]]\nname = \"horn\"\nkind = \"setpoint\"\nrange = [0.0, 1.0]\ndriver = \"line\"\n",
            crate::config::ALICE_TOML
        );
        let config = crate::config::parse(&text, "horn.toml").expect("Alice with a horn");
        let v = crate::testkit::vehicle_of(config, now);
        let s = GateState::new(&v);
        for d in v.devices() {
            assert_eq!(needed(&v, d), d.name() != "horn", "{}", d.name());
        }
        crate::testkit::make_faulty(&v, "horn", now);
        assert_eq!(s.blockers(&v), []);
        crate::testkit::make_faulty(&v, "brake", now);
        let b = s.blockers(&v);
        assert!(
            matches!(&*b, [Blocker::Faulty { device, .. }] if device == "brake"),
            "{b:?}"
        );
    }

    /// A command's value, before any state: a sensor takes nothing, not even a
    /// control; an actuator takes a control, a state among its states, a finite set
    /// point inside its range, and nothing of another kind.
    #[test]
    fn a_commands_value_is_its_devices_kind_inside_its_range() {
        use crate::value::Control;
        let v = crate::testkit::vehicle(Instant::now());
        let of = |name: &str, c: Command| check_value(v.find(name).unwrap().config(), c);
        assert_eq!(of("estop", Command::Set(1.0)), Err(Reject::NotAnActuator));
        assert_eq!(
            of("estop", Command::Control(Control::Enable)),
            Err(Reject::NotAnActuator)
        );
        assert_eq!(of("steer", Command::Control(Control::Enable)), Ok(()));
        assert_eq!(of("trans", Command::Control(Control::Start)), Ok(()));
        assert_eq!(of("trans", Command::State(3)), Ok(()), "drive");
        assert_eq!(of("trans", Command::State(4)), Err(Reject::OutOfRange));
        assert_eq!(of("trans", Command::Set(0.5)), Err(Reject::WrongKind));
        assert_eq!(of("steer", Command::State(1)), Err(Reject::WrongKind));
        assert_eq!(of("steer", Command::Set(-1.0)), Ok(()));
        assert_eq!(of("steer", Command::Set(1.01)), Err(Reject::OutOfRange));
        assert_eq!(of("steer", Command::Set(f64::NAN)), Err(Reject::NotFinite));
        // Alice's gas is a Modbus drive without a control register.
        assert_eq!(
            of("gas", Command::Control(Control::Home)),
            Err(Reject::NoSuchControl)
        );
    }

    /// A drive control the device's protocol does not carry is refused at intake, by
    /// its own reason: OSCC's steering module has enable and disable messages and no
    /// home (the console's `e` sent one, which the driver dropped at the wire, the
    /// module's own watchdog then disabled it, and the vehicle disengaged).
    #[test]
    fn a_control_is_taken_only_where_the_device_s_protocol_carries_it() {
        use crate::value::Control;
        let oscc = crate::config::parse(
            include_str!("../../vehicles/oscc.toml"),
            "vehicles/oscc.toml",
        )
        .expect("OSCC parses");
        let steer = oscc.device("steer").unwrap();
        let of = |c| check_value(steer, Command::Control(c));
        assert_eq!(of(Control::Enable), Ok(()));
        assert_eq!(of(Control::Disable), Ok(()));
        assert_eq!(of(Control::Home), Err(Reject::NoSuchControl));
        assert_eq!(of(Control::Start), Err(Reject::NoSuchControl));
        assert_eq!(
            steer.takes_control(Control::Home),
            Err("steer: home: its CAN messages carry no home".into())
        );
        // The line protocol carries every control (the cart's throttle speaks it).
        let cart = crate::config::parse(
            include_str!("../../vehicles/cart.toml"),
            "vehicles/cart.toml",
        )
        .expect("the cart parses");
        let throttle = cart.device("throttle").unwrap();
        for c in Control::ALL {
            assert_eq!(check_value(throttle, Command::Control(c)), Ok(()), "{c}");
        }
    }

    /// The rules see throttle and brake set points as fractions of their range's top,
    /// any other device's as they are; the rules active are the vehicle's.
    #[test]
    fn the_rules_see_pedals_as_fractions_and_the_vehicles_rules_are_active() {
        let of = |range: &str| {
            crate::config::one_device(&format!(
                "name = \"d\"\nkind = \"setpoint\"\nrange = {range}\ndriver = \"line\""
            ))
        };
        let (percent, wheel) = (of("[0.0, 100.0]"), of("[-30.0, 30.0]"));
        assert_eq!(
            scaled(&percent, Plays::BRAKE, Command::Set(50.0)),
            Command::Set(0.5)
        );
        assert_eq!(
            scaled(&percent, Plays::THROTTLE, Command::Set(20.0)),
            Command::Set(0.2)
        );
        assert_eq!(
            scaled(&wheel, Plays::default(), Command::Set(15.0)),
            Command::Set(15.0)
        );
        let (v, s) = state();
        assert_eq!(s.rules(), Rules::active(v.bindings()));
        assert!(s.rules().has(Reject::GasWhileBraking));
    }

    /// A decision taken while engaged (a blocker seen, a fault) disengages only a
    /// vehicle still engaged: one disengaged meanwhile keeps its cause — a driver's
    /// override latched between the monitor's look and its step is said as the
    /// override, not as the blocker the monitor then saw.
    #[test]
    fn a_disengage_decided_while_engaged_keeps_an_earlier_cause() {
        let (_v, s) = state();
        s.set_engaged("test");
        let blocked = || DisengageCause::Blocked {
            blocker: Blocker::Overridden {
                device: "steer".into(),
            },
        };
        assert_eq!(s.take_over("steer"), Some(true));
        assert!(!s.set_disengaged_if_engaged(blocked()));
        assert_eq!(s.reason(), "disengaged: driver override on steer");
        s.set_engaged("test");
        assert!(s.set_disengaged_if_engaged(blocked()));
        assert!(!s.is_engaged());
        assert_eq!(s.cause(), GateCause::Disengaged { why: blocked() });
    }

    /// A remote source may ask to engage where the vehicle file lets the network
    /// engage, or a vehicle engaged already (picking it up engages nothing).
    #[test]
    fn a_remote_engage_is_the_vehicle_files_or_a_pick_up() {
        assert!(remote_may_engage(true, false));
        assert!(remote_may_engage(true, true));
        assert!(remote_may_engage(false, true));
        assert!(!remote_may_engage(false, false));
    }

    /// A driver's override is latched once per device, each device on its own,
    /// disengages with it in the same step, and refuses the engage until it is
    /// cleared.
    #[test]
    fn an_override_is_latched_once_per_device_and_blocks_until_cleared() {
        let (v, s) = state();
        assert_eq!(s.blockers(&v), [], "Alice at rest may engage");
        s.set_engaged("test");
        assert_eq!(s.take_over("brake"), Some(true), "it was engaged");
        assert!(!s.is_engaged());
        assert_eq!(s.reason(), "disengaged: driver override on brake");
        assert_eq!(s.take_over("brake"), None, "latched already");
        assert_eq!(s.take_over("steer"), Some(false), "another device");
        assert_eq!(s.overridden(), ["brake", "steer"]);
        assert_eq!(
            s.blockers(&v),
            [
                Blocker::Overridden {
                    device: "brake".into()
                },
                Blocker::Overridden {
                    device: "steer".into()
                }
            ]
        );
        assert!(
            s.clear_overrides(&["steer".into()]).is_err(),
            "a hand still on it"
        );
        assert_eq!(
            s.clear_overrides(&[]),
            Ok(vec!["brake".into(), "steer".into()])
        );
        assert_eq!(s.blockers(&v), []);
    }

    /// A recovery's devices are refused at intake — the accel when either pedal is
    /// one of them — and handed back with an empty list.
    #[test]
    fn a_recoverys_devices_are_refused_until_handed_back() {
        let (v, s) = state();
        s.set_engaged("test");
        let (gas, brake, steer) = (
            v.find("gas").unwrap(),
            v.find("brake").unwrap(),
            v.find("steer").unwrap(),
        );
        assert_eq!(s.check(&v, steer, Command::Set(0.2)), Ok(()));
        s.set_recovering(&[brake.id()]);
        assert!(s.is_recovering(brake.id()) && !s.is_recovering(gas.id()));
        assert_eq!(
            s.check(&v, brake, Command::Set(0.5)),
            Err(Reject::Recovering)
        );
        assert_eq!(s.check(&v, steer, Command::Set(0.2)), Ok(()));
        let accel = |a| s.decided_accel(&v, a).unwrap().0.map_err(|r| r.why);
        assert_eq!(accel(-0.3).err(), Some(Reject::Recovering), "the brake's");
        s.set_recovering(&[gas.id()]);
        assert_eq!(
            accel(-0.3).err(),
            Some(Reject::Recovering),
            "the throttle's"
        );
        s.set_recovering(&[]);
        assert!(!s.is_recovering(gas.id()));
        assert!(accel(-0.3).is_ok());
        assert_eq!(
            s.check(&v, steer, Command::Set(7.0)),
            Err(Reject::OutOfRange)
        );
    }

    /// A decision gathers the vehicle's facts only where the interlocks will look at
    /// them — engaged, not recovering, interlocks on, a device the rules play — so that
    /// what a recording keeps of it is what it decided on.
    #[test]
    fn a_decision_sees_facts_only_where_the_interlocks_look() {
        let (v, s) = state();
        let (gas, steer) = (v.find("gas").unwrap(), v.find("steer").unwrap());
        let looked = |d: &Device| s.decided(&v, d, Command::Set(0.0)).1.facts.is_some();
        assert!(!looked(gas), "disengaged");
        s.set_engaged("test");
        assert!(looked(gas));
        assert!(!looked(steer), "no rule plays the steering");
        s.set_recovering(&[gas.id()]);
        assert!(!looked(gas), "recovering");
        s.set_recovering(&[]);
        s.set_interlocks(false);
        assert!(!looked(gas), "interlocks off");
    }

    /// The wire checks a command only while the interlocks are on: throttle behind a
    /// brake still applied is held back, and goes out as it is with them switched off.
    #[test]
    fn the_wire_checks_only_while_the_interlocks_are_on() {
        let (v, s) = state();
        let (gas, brake) = (v.find("gas").unwrap(), v.find("brake").unwrap());
        brake.slot().fly(Command::Set(1.0));
        brake.slot().finish(Command::Set(1.0), true);
        let gas_on = Command::Set(0.5);
        assert_ne!(
            s.wire_verdict(&v, gas, gas_on, false),
            Verdict::Send(gas_on)
        );
        s.set_interlocks(false);
        assert_eq!(
            s.wire_verdict(&v, gas, gas_on, false),
            Verdict::Send(gas_on)
        );
    }

    /// Every refusal is counted, by reason and at its device; its log line is limited
    /// (a planner refused at 100 Hz must not flood the log), and the first is always
    /// logged.
    #[test]
    fn every_refusal_is_counted_and_the_first_logged_not_each() {
        let (v, s) = state();
        let (brake, steer) = (v.find("brake").unwrap(), v.find("steer").unwrap());
        let lines = crate::testkit::logged(|| {
            s.reject(
                Some(brake),
                Some(Command::Set(0.0)),
                Reject::BrakeReleaseEstop,
            );
            for _ in 0..29 {
                s.reject(Some(steer), Some(Command::Set(2.0)), Reject::OutOfRange);
            }
        });
        let of = |device: &str| {
            lines
                .iter()
                .filter(|l| l.starts_with("rejected: ") && l.contains(&format!("device={device}")))
                .count()
        };
        assert_eq!(of("brake"), 1, "the first is logged: {lines:#?}");
        assert!(of("steer") < 29, "not every one: {lines:#?}");
        let count = |r: Reject| s.rejections().into_iter().find(|(x, _)| *x == r).unwrap().1;
        assert_eq!(count(Reject::OutOfRange), 29);
        assert_eq!(count(Reject::BrakeReleaseEstop), 1);
        assert_eq!(count(Reject::Disengaged), 0);
        assert_eq!(steer.stats().rejected.load(Relaxed), 29);
        assert_eq!(brake.stats().rejected.load(Relaxed), 1);
    }
}
