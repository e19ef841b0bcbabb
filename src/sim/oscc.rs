//! A simulated OSCC kit (Open Source Car Control, on a Kia Soul): the brake, steering
//! and throttle modules' firmware as the bus sees it, behind a simulated SLCAN adapter
//! ([`super::slcan::SlcanPort`]). Every frame is encoded and decoded with the kit's DBC
//! (`vehicles/oscc.dbc`), so the simulator, adrive's drivers and third-party tools read
//! the same layout.
//!
//! Each module does what OSCC's firmware (v1.2.4, `firmware/*/src/*_control.cpp`) does
//! on the bus: it ignores a frame without the magic bytes 0x05 0xCC; `*_ENABLE` enables
//! it unless its override flag is set, `*_DISABLE` disables it; a `*_COMMAND` while
//! enabled sets its request; a `FAULT_REPORT` from another module disables it; it
//! reports at the report message's cycle time (50 Hz) whether it is enabled, its
//! override flag and its fault codes.
//!
//! Its faults follow the firmware's `check_for_faults`, which runs on every turn of the
//! module's loop while it is enabled or holds a fault code. A condition — the driver
//! overriding it, its sensor reading grounded (disconnected) — that holds for
//! [`FAULT_HYSTERESIS`] (the steering's override: at once, through its filter) disables
//! the module, sets the condition's fault code (and the override flag for an override)
//! and sends a `FAULT_REPORT`. **When no condition holds any more, the next turn clears
//! every fault code and the override flag**: the driver letting go of the wheel, or the
//! sensor reading valid again, is the kit's own way back. A module that is disabled and
//! holds no code does not look at all: a driver's hand on a disabled module is seen
//! only once it is enabled. The simulator holds a condition on and off by name (its
//! fault code's DBC name, [`Kit::set_fault`]; [`Kit::set_override`] for the driver).
//!
//! A firmware watchdog disables a module that hears no command for its timeout. OSCC
//! v1.0 had one (`check_for_controller_command_timeout`), v1.2.4 has not; kits that
//! people drive with adrive (PACMod, Dataspeed) do, and adrive resends the latest
//! command every `command_timeout` so that it never trips in normal running: the
//! simulator keeps it to show what happens when adrive stops talking.

use super::firmware::Watchdog;
use super::slcan::BusNode;
use crate::can::dbc::{Database, DbcError, Message};
use crate::can::{Frame, Id};
use std::fmt;
use std::str::FromStr;
use std::time::{Duration, Instant};

/// The first two bytes of every OSCC frame.
pub const MAGIC: [u8; 2] = [0x05, 0xCC];
/// How long a condition must hold before a module acts on it: OSCC's
/// `FAULT_HYSTERESIS` for the Kia Soul (`api/include/vehicles/kia_soul_petrol.h`).
pub const FAULT_HYSTERESIS: Duration = Duration::from_millis(100);
/// The fault code of a driver's override, by its DBC name; it also sets the report's
/// override flag.
pub const OPERATOR_OVERRIDE: &str = "OPERATOR_OVERRIDE";
/// The report period when the DBC gives no cycle time (OSCC's 50 Hz).
pub const REPORT_PERIOD: Duration = Duration::from_millis(20);
/// How often the vehicle's own messages (wheel speed, steering wheel angle, brake
/// pressure) go out.
pub const WHEEL_SPEED_PERIOD: Duration = Duration::from_millis(20);
/// The vehicle's own messages the kit's DBC carries, beside the wheel speed: each is
/// sent when the DBC has it.
pub const STEERING_WHEEL_ANGLE: &str = "KIA_SOUL_STEERING_WHEEL_ANGLE";
pub const BRAKE_PRESSURE: &str = "KIA_SOUL_BRAKE_PRESSURE";

/// One of the kit's modules.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Module {
    Brake,
    Steering,
    Throttle,
}

impl Module {
    pub const ALL: [Module; 3] = [Module::Brake, Module::Steering, Module::Throttle];

    /// The prefix of its messages in the DBC, and its name in `FAULT_REPORT`.
    pub fn prefix(self) -> &'static str {
        match self {
            Module::Brake => "BRAKE",
            Module::Steering => "STEERING",
            Module::Throttle => "THROTTLE",
        }
    }

    /// The request signal of its command message.
    pub fn request_signal(self) -> &'static str {
        match self {
            Module::Brake => "pedal_command",
            Module::Steering => "torque_command",
            Module::Throttle => "torque_request",
        }
    }
}

impl fmt::Display for Module {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Module::Brake => "brake",
            Module::Steering => "steering",
            Module::Throttle => "throttle",
        })
    }
}

impl FromStr for Module {
    type Err = String;
    fn from_str(s: &str) -> Result<Module, String> {
        Module::ALL
            .into_iter()
            .find(|m| m.to_string() == s || m.prefix() == s)
            .ok_or_else(|| format!("no module {s:?} (brake, steering, throttle)"))
    }
}

/// What a module's firmware holds, as its report tells it.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct ModuleState {
    pub enabled: bool,
    /// The override flag of its report: set when the firmware acts on the driver's
    /// override, cleared on the first turn the driver no longer overrides it.
    pub operator_override: bool,
    /// Its fault codes (a bitfield: the DBC's value table names the bits).
    pub dtcs: u8,
    /// The last request applied.
    pub request: f64,
}

/// Something a module did on its own or was told, for `adrive sim`'s log.
#[derive(Clone, Debug, PartialEq)]
pub struct Note {
    pub module: Module,
    pub at: Instant,
    pub what: String,
}

/// The firmware's `condition_exceeded_duration`: since when a condition has held, as
/// the module saw it on the turns it looked.
#[derive(Clone, Copy, Debug, Default)]
struct Hysteresis {
    since: Option<Instant>,
}

impl Hysteresis {
    /// Whether the condition, `active` now, has held for `max` (it starts counting on
    /// the first turn it is seen; a turn without it starts again).
    fn exceeded(&mut self, active: bool, max: Duration, now: Instant) -> bool {
        if !active {
            self.since = None;
            return false;
        }
        now.saturating_duration_since(*self.since.get_or_insert(now)) >= max
    }
}

/// One condition a module's firmware checks, named by its fault code.
#[derive(Clone, Debug)]
struct Condition {
    /// Its fault code's bit in the report's `dtcs`, and its DBC name.
    bit: u8,
    name: String,
    /// How long it must hold before the module acts.
    hold: Duration,
    /// It holds now (the driver's hand, a grounded sensor).
    active: bool,
    seen: Hysteresis,
}

struct Unit {
    module: Module,
    enable: Id,
    disable: Id,
    command: Message,
    report: Message,
    period: Duration,
    state: ModuleState,
    /// The conditions its firmware checks, in the order it checks them (the sensor
    /// before the driver, as `check_for_faults` does).
    conditions: Vec<Condition>,
    watchdog: Watchdog,
    next_report: Instant,
    /// While a fault holds, the firmware sends a fault report on every turn of its
    /// loop; the simulator sends one a report period.
    next_fault_report: Option<Instant>,
}

impl Unit {
    fn condition(&mut self, name: &str) -> Result<&mut Condition, String> {
        let module = self.module;
        let names = self
            .conditions
            .iter()
            .map(|c| c.name.as_str())
            .collect::<Vec<_>>()
            .join(", ");
        self.conditions
            .iter_mut()
            .find(|c| c.name.eq_ignore_ascii_case(name))
            .ok_or_else(|| {
                if names.is_empty() {
                    format!("the {module} module's report names no fault codes")
                } else {
                    format!("no fault code {name:?} for the {module} ({names})")
                }
            })
    }
}

/// The simulated kit, and the vehicle's own messages: wheel speed (always), steering
/// wheel angle and brake pressure (when the DBC has them).
pub struct Kit {
    units: Vec<Unit>,
    fault: Message,
    wheel: Message,
    angle: Option<Message>,
    pressure: Option<Message>,
    next_wheel: Instant,
    speed_kmh: f64,
    angle_deg: f64,
    pressure_bar: f64,
    notes: Vec<Note>,
}

impl Kit {
    /// The kit described by `db`, its modules' watchdogs tripping `watchdog` after the
    /// last command (none: never), powered up at `now`.
    pub fn new(db: &Database, watchdog: Option<Duration>, now: Instant) -> Result<Kit, DbcError> {
        let mut units = Vec::new();
        for module in Module::ALL {
            let name = |what: &str| format!("{}_{what}", module.prefix());
            let command = db.message_named(&name("COMMAND"))?.clone();
            if command.signal(module.request_signal()).is_none() {
                return Err(DbcError {
                    path: db.path().to_string(),
                    line: command.line(),
                    message: format!(
                        "{} has no signal {}",
                        command.name(),
                        module.request_signal()
                    ),
                });
            }
            let report = db.message_named(&name("REPORT"))?.clone();
            let mut conditions: Vec<Condition> = report
                .signal("dtcs")
                .map(|s| s.values().to_vec())
                .unwrap_or_default()
                .into_iter()
                .filter(|(raw, _)| (1..=0xff).contains(raw))
                .map(|(raw, name)| Condition {
                    bit: raw as u8,
                    // The steering filters the driver's torque and acts on it at once.
                    hold: if module == Module::Steering && name == OPERATOR_OVERRIDE {
                        Duration::ZERO
                    } else {
                        FAULT_HYSTERESIS
                    },
                    name,
                    active: false,
                    seen: Hysteresis::default(),
                })
                .collect();
            conditions.sort_by_key(|c| c.bit);
            units.push(Unit {
                module,
                enable: db.message_named(&name("ENABLE"))?.id(),
                disable: db.message_named(&name("DISABLE"))?.id(),
                command,
                period: report.cycle().unwrap_or(REPORT_PERIOD),
                report,
                state: ModuleState::default(),
                conditions,
                watchdog: Watchdog::new(watchdog),
                next_report: now,
                next_fault_report: None,
            });
        }
        Ok(Kit {
            units,
            fault: db.message_named("FAULT_REPORT")?.clone(),
            wheel: db.message_named("KIA_SOUL_WHEEL_SPEED")?.clone(),
            angle: db.message(STEERING_WHEEL_ANGLE).cloned(),
            pressure: db.message(BRAKE_PRESSURE).cloned(),
            next_wheel: now,
            speed_kmh: 0.0,
            angle_deg: 0.0,
            pressure_bar: 0.0,
            notes: Vec::new(),
        })
    }

    fn unit(&mut self, module: Module) -> &mut Unit {
        self.units
            .iter_mut()
            .find(|u| u.module == module)
            .expect("every module has a unit")
    }

    /// A module's state.
    pub fn state(&self, module: Module) -> ModuleState {
        self.units
            .iter()
            .find(|u| u.module == module)
            .map(|u| u.state)
            .unwrap_or_default()
    }

    /// What happened since the last call.
    pub fn take_notes(&mut self) -> Vec<Note> {
        std::mem::take(&mut self.notes)
    }

    fn note(&mut self, module: Module, at: Instant, what: String) {
        self.notes.push(Note { module, at, what });
    }

    /// The vehicle's speed, for the wheel speed message (all four wheels alike).
    pub fn set_speed(&mut self, kmh: f64) {
        self.speed_kmh = kmh;
    }

    /// The steering wheel's angle in degrees, for its message.
    pub fn set_steering_angle(&mut self, deg: f64) {
        self.angle_deg = deg;
    }

    /// The brake master cylinder's pressure in bar, for its message.
    pub fn set_brake_pressure(&mut self, bar: f64) {
        self.pressure_bar = bar;
    }

    /// Whether the vehicle's own messages carry the position `module` moves: the
    /// steering wheel angle, the brake pressure (none for the throttle).
    pub fn reports_position(&self, module: Module) -> bool {
        match module {
            Module::Steering => self.angle.is_some(),
            Module::Brake => self.pressure.is_some(),
            Module::Throttle => false,
        }
    }

    /// The identifier of a module's command message.
    pub fn command_id(&self, module: Module) -> Id {
        self.units
            .iter()
            .find(|u| u.module == module)
            .map(|u| u.command.id())
            .expect("every module has a unit")
    }

    /// The driver starts (`true`) or stops overriding `module` (turning the wheel,
    /// pressing a pedal): the condition of its `OPERATOR_OVERRIDE` code. The module acts
    /// on it as its firmware does, on the next turns of its loop.
    pub fn set_override(&mut self, module: Module, on: bool, now: Instant) {
        // A DBC without the code has no override to hold.
        let _ = self.set_fault(module, OPERATOR_OVERRIDE, on, now);
    }

    /// Hold (`true`) or end the condition behind the fault code named `dtc` (a name of
    /// the report's `dtcs` value table): `INVALID_SENSOR_VAL` is the module's sensor
    /// reading grounded, as a disconnected one does; `OPERATOR_OVERRIDE` the driver's
    /// hand. While it holds, the module disables itself, sets the code and reports it;
    /// once it ends, the module clears its codes on its next turn.
    pub fn set_fault(
        &mut self,
        module: Module,
        dtc: &str,
        on: bool,
        _now: Instant,
    ) -> Result<(), String> {
        self.unit(module).condition(dtc)?.active = on;
        Ok(())
    }

    /// Whether the condition behind `dtc` holds on `module` (`None`: no such code).
    pub fn fault_held(&self, module: Module, dtc: &str) -> Option<bool> {
        self.units
            .iter()
            .find(|u| u.module == module)?
            .conditions
            .iter()
            .find(|c| c.name.eq_ignore_ascii_case(dtc))
            .map(|c| c.active)
    }

    /// The fault code names of `module`'s report, in the order its firmware checks them.
    pub fn fault_names(&self, module: Module) -> Vec<String> {
        self.units
            .iter()
            .find(|u| u.module == module)
            .map(|u| u.conditions.iter().map(|c| c.name.clone()).collect())
            .unwrap_or_default()
    }

    /// One turn of a module's `check_for_faults`, at `now`: whether it sends a fault
    /// report.
    fn check_for_faults(&mut self, i: usize, now: Instant) -> bool {
        let u = &mut self.units[i];
        if !u.state.enabled && u.state.dtcs == 0 {
            return false;
        }
        // Every condition is looked at on every turn; the first that has held long
        // enough acts.
        let mut acting = None;
        for (k, c) in u.conditions.iter_mut().enumerate() {
            if c.seen.exceeded(c.active, c.hold, now) && acting.is_none() {
                acting = Some(k);
            }
        }
        let module = u.module;
        let Some(k) = acting else {
            u.next_fault_report = None;
            if u.state.dtcs != 0 || u.state.operator_override {
                let names = dtc_names(&u.report, u.state.dtcs);
                u.state.dtcs = 0;
                u.state.operator_override = false;
                self.note(module, now, format!("{names} cleared: the condition ended"));
            }
            return false;
        };
        let c = &u.conditions[k];
        let (bit, name, is_override) = (c.bit, c.name.clone(), c.name == OPERATOR_OVERRIDE);
        let was_enabled = std::mem::replace(&mut u.state.enabled, false);
        let new = u.state.dtcs & bit == 0;
        u.state.dtcs |= bit;
        if is_override {
            u.state.operator_override = true;
        }
        let report = u.next_fault_report.is_none_or(|at| now >= at);
        if report {
            u.next_fault_report = Some(now + u.period);
        }
        if new || was_enabled {
            let what = if is_override {
                "operator override".to_string()
            } else {
                format!("fault {name}")
            };
            let disabled = if was_enabled { ": disabled" } else { "" };
            self.note(module, now, format!("{what}{disabled}"));
        }
        report
    }

    /// Every module but `from` hears a fault report: each disables itself, as the
    /// firmware's `process_fault_report` does.
    fn hear_fault_report(&mut self, from: Option<Module>, now: Instant) {
        for i in 0..self.units.len() {
            let u = &mut self.units[i];
            if Some(u.module) == from || !u.state.enabled {
                continue;
            }
            u.state.enabled = false;
            let module = u.module;
            let why = match from {
                Some(m) => format!("disabled: the {m} module's fault report"),
                None => "disabled: a fault report".to_string(),
            };
            self.note(module, now, why);
        }
    }

    /// `module`'s fault report: its origin and its fault codes.
    fn fault_report(&self, module: Module) -> Option<Frame> {
        let u = self.units.iter().find(|u| u.module == module)?;
        let origin = self
            .fault
            .signal("fault_origin_id")
            .and_then(|s| s.value_of(module.prefix()))
            .unwrap_or(0) as f64;
        self.fault
            .encode(&[
                ("fault_origin_id", origin),
                ("dtcs", f64::from(u.state.dtcs)),
            ])
            .ok()
    }

    fn report(u: &Unit) -> Frame {
        let s = &u.state;
        u.report
            .encode(&[
                ("enabled", s.enabled as u8 as f64),
                ("operator_override", s.operator_override as u8 as f64),
                ("dtcs", s.dtcs as f64),
            ])
            .expect("a report carries its own state")
    }
}

/// `message` with every signal set to `value`, held within the signal's range.
fn every_signal(message: &Message, value: f64) -> Option<Frame> {
    let values: Vec<(&str, f64)> = message
        .signals()
        .iter()
        .map(|s| {
            let (lo, hi) = s.range().unwrap_or((f64::MIN, f64::MAX));
            (s.name(), value.clamp(lo, hi))
        })
        .collect();
    message.encode(&values).ok()
}

/// The names of the fault codes set in `dtcs`, for notes (`INVALID_SENSOR_VAL`).
fn dtc_names(report: &Message, dtcs: u8) -> String {
    let names = report
        .signal("dtcs")
        .map(|s| s.flag_names(u64::from(dtcs)))
        .unwrap_or_default();
    if names.is_empty() {
        format!("fault codes 0x{dtcs:02x}")
    } else {
        names.join(", ")
    }
}

impl BusNode for Kit {
    fn receive(&mut self, frame: &Frame, now: Instant) {
        if frame.data().get(..2) != Some(&MAGIC[..]) {
            return;
        }
        let id = frame.id();
        if id == self.fault.id() {
            self.hear_fault_report(None, now);
            return;
        }
        let Some(i) = self
            .units
            .iter()
            .position(|u| u.enable == id || u.disable == id || u.command.id() == id)
        else {
            return;
        };
        let u = &mut self.units[i];
        let module = u.module;
        if id == u.enable {
            if u.state.operator_override {
                self.note(module, now, "enable refused: the operator overrides".into());
            } else if !u.state.enabled {
                u.state.enabled = true;
                u.watchdog.feed(now);
                self.note(module, now, "enabled".into());
            }
        } else if id == u.disable {
            if u.state.enabled {
                u.state.enabled = false;
                self.note(module, now, "disabled".into());
            }
        } else if u.state.enabled {
            let signal = u
                .command
                .signal(module.request_signal())
                .expect("checked when the kit was built");
            if let Some(v) = signal.decode(frame.data()).filter(|v| v.is_finite()) {
                let (lo, hi) = signal.range().unwrap_or((f64::MIN, f64::MAX));
                u.state.request = v.clamp(lo, hi);
                u.watchdog.feed(now);
            }
        }
    }

    fn tick(&mut self, now: Instant, bus: &mut Vec<Frame>) {
        for i in 0..self.units.len() {
            let u = &mut self.units[i];
            if u.state.enabled && u.watchdog.expired(now) {
                u.state.enabled = false;
                let limit = u.watchdog.limit().unwrap_or_default();
                let module = u.module;
                self.note(
                    module,
                    now,
                    format!("watchdog: no command for {limit:?}, disabled"),
                );
            }
            if self.check_for_faults(i, now) {
                let module = self.units[i].module;
                bus.extend(self.fault_report(module));
                self.hear_fault_report(Some(module), now);
            }
            let u = &mut self.units[i];
            if now >= u.next_report {
                bus.push(Kit::report(u));
                u.next_report += u.period;
                if u.next_report <= now {
                    // Far behind (the port loop stalled): report from now on.
                    u.next_report = now + u.period;
                }
            }
        }
        if now >= self.next_wheel {
            bus.extend(every_signal(&self.wheel, self.speed_kmh.max(0.0)));
            if let Some(m) = &self.angle {
                bus.extend(every_signal(m, self.angle_deg));
            }
            if let Some(m) = &self.pressure {
                bus.extend(every_signal(m, self.pressure_bar));
            }
            self.next_wheel += WHEEL_SPEED_PERIOD;
            if self.next_wheel <= now {
                self.next_wheel = now + WHEEL_SPEED_PERIOD;
            }
        }
    }

    fn next_due(&self) -> Instant {
        self.units
            .iter()
            .map(|u| u.next_report)
            .chain([self.next_wheel])
            .min()
            .expect("the kit has modules")
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::driver::slcan::proto::{encode_command, Command, Decoder, Event, FromAdapter};
    use crate::sim::slcan::SlcanPort;
    use std::path::Path;

    const MS: Duration = Duration::from_millis(1);

    fn db() -> Database {
        let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("vehicles/oscc.dbc");
        Database::load(&path).unwrap_or_else(|e| panic!("{e}"))
    }

    /// The kit behind an adapter opened at 500 kbit/s, as a host leaves it.
    struct Bench {
        db: Database,
        port: SlcanPort<Kit>,
        t0: Instant,
        decoder: Decoder<FromAdapter>,
    }

    impl Bench {
        fn new(watchdog: Option<Duration>) -> Bench {
            let db = db();
            let t0 = Instant::now();
            let kit = Kit::new(&db, watchdog, t0).unwrap();
            let mut b = Bench {
                port: SlcanPort::new(kit, t0),
                db,
                t0,
                decoder: Decoder::new(),
            };
            assert_eq!(b.host(0, b"S6\rO\r"), vec![Event::Ok, Event::Ok]);
            b
        }

        /// Bytes from the host at `ms` after power-up; the adapter's answers.
        fn host(&mut self, ms: u64, bytes: &[u8]) -> Vec<Event> {
            let mut out = Vec::new();
            self.port
                .input(bytes, self.t0 + Duration::from_millis(ms), &mut out);
            self.decoder.push(&out);
            std::iter::from_fn(|| self.decoder.next()).collect()
        }

        /// Send the DBC message `name` with `values` at `ms`.
        fn send(&mut self, ms: u64, name: &str, values: &[(&str, f64)]) -> Vec<Event> {
            let f = self.db.message(name).unwrap().encode(values).unwrap();
            self.host(ms, &encode_command(&Command::Transmit(f)))
        }

        /// Run the bus from `from` to `to` ms in 1 ms steps; the frames the host gets.
        fn run(&mut self, from: u64, to: u64) -> Vec<Frame> {
            let mut out = Vec::new();
            for ms in from..=to {
                self.port
                    .tick(self.t0 + Duration::from_millis(ms), &mut out);
            }
            self.decoder.push(&out);
            std::iter::from_fn(|| self.decoder.next())
                .map(|e| match e {
                    Event::Received { frame, .. } => frame,
                    other => panic!("only frames come unasked: {other:?}"),
                })
                .collect()
        }

        /// The last report of `module` among `frames`, decoded by name.
        fn report(&self, frames: &[Frame], module: Module) -> (f64, f64, Vec<String>) {
            let m = self
                .db
                .message(&format!("{}_REPORT", module.prefix()))
                .unwrap();
            let f = frames
                .iter()
                .rev()
                .find(|f| f.id() == m.id())
                .expect("a report");
            let get = |n: &str| m.signal(n).unwrap().decode(f.data()).unwrap();
            let dtcs = m.signal("dtcs").unwrap();
            (
                get("enabled"),
                get("operator_override"),
                dtcs.flag_names(dtcs.raw(f.data()).unwrap()),
            )
        }
    }

    #[test]
    fn each_module_reports_at_50_hz_and_the_car_its_wheel_speed() {
        let mut b = Bench::new(None);
        b.port.node.set_speed(36.0);
        b.port.node.set_steering_angle(-90.0);
        b.port.node.set_brake_pressure(42.5);
        let frames = b.run(0, 100);
        for module in Module::ALL {
            let id =
                b.db.message(&format!("{}_REPORT", module.prefix()))
                    .unwrap()
                    .id();
            let n = frames.iter().filter(|f| f.id() == id).count();
            assert_eq!(n, 6, "{module}: at 0, 20, … 100 ms");
        }
        let wheel = b.db.message("KIA_SOUL_WHEEL_SPEED").unwrap();
        let f = frames.iter().find(|f| f.id() == wheel.id()).unwrap();
        assert!(wheel.decode(f).all(|(_, v)| v == 36.0), "{f}");
        for (name, want) in [(STEERING_WHEEL_ANGLE, -90.0), (BRAKE_PRESSURE, 42.5)] {
            let m = b.db.message(name).unwrap();
            let sent: Vec<&Frame> = frames.iter().filter(|f| f.id() == m.id()).collect();
            assert_eq!(sent.len(), 6, "{name}: at 0, 20, … 100 ms");
            assert!(
                m.decode(sent[0]).all(|(_, v)| (v - want).abs() < 1e-9),
                "{name}: {}",
                sent[0]
            );
        }
        let own = [
            wheel.id(),
            b.db.message(STEERING_WHEEL_ANGLE).unwrap().id(),
            b.db.message(BRAKE_PRESSURE).unwrap().id(),
        ];
        assert!(frames
            .iter()
            .all(|f| f.data()[..2] == MAGIC || own.contains(&f.id())));
    }

    #[test]
    fn enable_then_command_then_disable_as_the_reports_show() {
        let mut b = Bench::new(None);
        // A command before enable is ignored, as the firmware does.
        b.send(0, "THROTTLE_COMMAND", &[("torque_request", 0.3)]);
        assert_eq!(b.port.node.state(Module::Throttle).request, 0.0);
        assert_eq!(
            b.send(1, "THROTTLE_ENABLE", &[]),
            vec![Event::Sent { extended: false }]
        );
        b.send(2, "THROTTLE_COMMAND", &[("torque_request", 0.3)]);
        let frames = b.run(0, 20);
        assert_eq!(b.report(&frames, Module::Throttle).0, 1.0, "enabled");
        assert!((b.port.node.state(Module::Throttle).request - 0.3).abs() < 1e-6);
        assert_eq!(
            b.report(&frames, Module::Brake).0,
            0.0,
            "the brake was not enabled"
        );
        b.send(21, "THROTTLE_DISABLE", &[]);
        let frames = b.run(21, 40);
        assert_eq!(b.report(&frames, Module::Throttle).0, 0.0);
        let notes: Vec<String> = b
            .port
            .node
            .take_notes()
            .into_iter()
            .map(|n| n.what)
            .collect();
        assert_eq!(notes, vec!["enabled", "disabled"]);
    }

    #[test]
    fn a_frame_without_the_magic_bytes_is_ignored() {
        let mut b = Bench::new(None);
        let id = b.db.message("BRAKE_ENABLE").unwrap().id();
        let f = Frame::new(id, &[0, 0, 0, 0, 0, 0, 0, 0]).unwrap();
        b.host(0, &encode_command(&Command::Transmit(f)));
        assert!(!b.port.node.state(Module::Brake).enabled);
    }

    #[test]
    fn the_firmware_watchdog_disables_a_module_that_hears_no_command() {
        let mut b = Bench::new(Some(Duration::from_millis(100)));
        b.send(0, "STEERING_ENABLE", &[]);
        // Commands every 50 ms keep it enabled through 300 ms.
        for ms in (10..=300u64).step_by(50) {
            b.run(ms.saturating_sub(49), ms);
            b.send(ms, "STEERING_COMMAND", &[("torque_command", -0.2)]);
        }
        b.run(261, 360);
        assert!(
            b.port.node.state(Module::Steering).enabled,
            "fed every 50 ms"
        );
        // Silence: the last command was at 260 ms; at 361 ms it is past 100 ms.
        let frames = b.run(361, 400);
        assert!(!b.port.node.state(Module::Steering).enabled);
        assert_eq!(b.report(&frames, Module::Steering).0, 0.0);
        let notes = b.port.node.take_notes();
        let last = notes.last().unwrap();
        assert_eq!(last.what, "watchdog: no command for 100ms, disabled");
        assert_eq!(last.at, b.t0 + 361 * MS);
    }

    /// The firmware's fault reports of `module` among `frames`.
    fn fault_reports<'a>(b: &Bench, frames: &'a [Frame]) -> Vec<&'a Frame> {
        let fault = b.db.message("FAULT_REPORT").unwrap();
        frames.iter().filter(|f| f.id() == fault.id()).collect()
    }

    /// The incident: after `override steer on` then `off`, the simulated module kept
    /// reporting the override for ever (it cleared only on an enable, which adrive
    /// never sends while a module reports the driver's hand), so the override could
    /// never be cleared and the vehicle never engaged again. OSCC's firmware clears it
    /// on the first turn of `check_for_faults` after the driver lets go.
    #[test]
    fn an_operator_override_disables_and_clears_itself_once_the_driver_lets_go() {
        let mut b = Bench::new(None);
        b.send(0, "BRAKE_ENABLE", &[]);
        b.send(0, "THROTTLE_ENABLE", &[]);
        b.run(0, 5);
        b.port.node.set_override(Module::Brake, true, b.t0 + 6 * MS);
        // A pedal override must hold for the firmware's hysteresis first.
        b.run(6, 100);
        assert!(b.port.node.state(Module::Brake).enabled, "before 100 ms");
        let frames = b.run(101, 126);
        let (enabled, overridden, dtcs) = b.report(&frames, Module::Brake);
        assert_eq!((enabled, overridden), (0.0, 1.0));
        assert_eq!(dtcs, vec!["OPERATOR_OVERRIDE"]);
        let reports = fault_reports(&b, &frames);
        assert_eq!(reports.len(), 2, "one a report period while it holds");
        let fault = b.db.message("FAULT_REPORT").unwrap();
        let origin = fault.signal("fault_origin_id").unwrap();
        let raw = origin.raw(reports[0].data()).unwrap() as i64;
        assert_eq!(origin.value_name(raw), Some("BRAKE"));
        // The throttle heard the brake's fault report and disabled itself.
        assert!(!b.port.node.state(Module::Throttle).enabled);
        // Still held: enabling is refused.
        b.send(127, "BRAKE_ENABLE", &[]);
        assert!(!b.port.node.state(Module::Brake).enabled);
        // The driver lets go: the next turn clears the flag and the code, with no
        // enable from anyone.
        b.port
            .node
            .set_override(Module::Brake, false, b.t0 + 128 * MS);
        let frames = b.run(128, 150);
        assert_eq!(b.report(&frames, Module::Brake), (0.0, 0.0, vec![]));
        assert!(fault_reports(&b, &frames[frames.len() / 2..]).is_empty());
        b.send(151, "BRAKE_ENABLE", &[]);
        let frames = b.run(151, 170);
        assert_eq!(b.report(&frames, Module::Brake), (1.0, 0.0, vec![]));
        let notes: Vec<String> = b
            .port
            .node
            .take_notes()
            .into_iter()
            .filter(|n| n.module == Module::Brake)
            .map(|n| n.what)
            .collect();
        assert_eq!(
            notes,
            [
                "enabled",
                "operator override: disabled",
                "enable refused: the operator overrides",
                "OPERATOR_OVERRIDE cleared: the condition ended",
                "enabled"
            ]
        );
    }

    /// The steering module filters the driver's torque and acts on it at once.
    #[test]
    fn the_steering_override_acts_at_once() {
        let mut b = Bench::new(None);
        b.send(0, "STEERING_ENABLE", &[]);
        b.port
            .node
            .set_override(Module::Steering, true, b.t0 + 2 * MS);
        b.run(2, 3);
        assert!(b.port.node.state(Module::Steering).operator_override);
    }

    /// A disabled module with no fault code does not check for faults: a hand on it is
    /// seen once it is enabled, after the hysteresis.
    #[test]
    fn a_disabled_module_sees_the_drivers_hand_only_once_enabled() {
        let mut b = Bench::new(None);
        b.port.node.set_override(Module::Throttle, true, b.t0);
        let frames = b.run(0, 300);
        assert_eq!(b.report(&frames, Module::Throttle), (0.0, 0.0, vec![]));
        b.send(301, "THROTTLE_ENABLE", &[]);
        b.run(301, 400);
        assert!(b.port.node.state(Module::Throttle).enabled);
        let frames = b.run(401, 420);
        assert_eq!(
            b.report(&frames, Module::Throttle),
            (0.0, 1.0, vec!["OPERATOR_OVERRIDE".to_string()])
        );
    }

    /// The incident: `fault brake INVALID_SENSOR_VAL` latched for ever, with no way
    /// back. The code is the firmware's verdict on a sensor reading grounded: it holds
    /// while the sensor does, and clears on the first turn the sensor reads valid.
    #[test]
    fn a_sensor_fault_holds_while_the_sensor_reads_grounded_and_clears_when_it_reads_valid() {
        let mut b = Bench::new(None);
        b.send(0, "STEERING_ENABLE", &[]);
        let e = b
            .port
            .node
            .set_fault(Module::Steering, "OVERHEAT", true, b.t0);
        assert_eq!(
            e.unwrap_err(),
            "no fault code \"OVERHEAT\" for the steering (INVALID_SENSOR_VAL, OPERATOR_OVERRIDE)"
        );
        b.port
            .node
            .set_fault(Module::Steering, "invalid_sensor_val", true, b.t0 + MS)
            .unwrap();
        assert_eq!(
            b.port
                .node
                .fault_held(Module::Steering, "INVALID_SENSOR_VAL"),
            Some(true)
        );
        let frames = b.run(1, 120);
        assert_eq!(
            b.report(&frames, Module::Steering),
            (0.0, 0.0, vec!["INVALID_SENSOR_VAL".to_string()])
        );
        let fault = b.db.message("FAULT_REPORT").unwrap();
        let f = fault_reports(&b, &frames)[0];
        let got: Vec<(String, f64)> = fault.decode(f).map(|(s, v)| (s.name().into(), v)).collect();
        assert_eq!(
            got[2..],
            [("fault_origin_id".into(), 1.0), ("dtcs".into(), 1.0)]
        );
        // Held: the code stays, disabled or not, long after.
        let frames = b.run(121, 2000);
        assert_eq!(
            b.report(&frames, Module::Steering),
            (0.0, 0.0, vec!["INVALID_SENSOR_VAL".to_string()])
        );
        b.port
            .node
            .set_fault(
                Module::Steering,
                "INVALID_SENSOR_VAL",
                false,
                b.t0 + 2001 * MS,
            )
            .unwrap();
        let frames = b.run(2001, 2030);
        assert_eq!(b.report(&frames, Module::Steering), (0.0, 0.0, vec![]));
        b.send(2031, "STEERING_ENABLE", &[]);
        let frames = b.run(2031, 2200);
        assert_eq!(b.report(&frames, Module::Steering), (1.0, 0.0, vec![]));
    }

    #[test]
    fn modules_by_name() {
        assert_eq!("steering".parse::<Module>(), Ok(Module::Steering));
        assert_eq!("THROTTLE".parse::<Module>(), Ok(Module::Throttle));
        assert!("gas".parse::<Module>().is_err());
    }
}
