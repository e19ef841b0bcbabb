//! A simulated OSCC kit (Open Source Car Control, on a Kia Soul): the brake, steering
//! and throttle modules' firmware as the bus sees it, behind a simulated SLCAN adapter
//! ([`super::slcan::SlcanPort`]). Every frame is encoded and decoded with the kit's DBC
//! (`vehicles/oscc.dbc`), so the simulator, adrive's drivers and third-party tools read
//! the same layout.
//!
//! Each module does what OSCC's firmware does on the bus: it ignores a frame without
//! the magic bytes 0x05 0xCC; `*_ENABLE` enables it, `*_DISABLE` disables it; a
//! `*_COMMAND` while enabled sets its request; it reports at the report message's cycle
//! time (50 Hz) whether it is enabled, overridden and its fault codes. An operator
//! override (the driver turns the wheel or presses a pedal) or an injected fault
//! disables the module and sends one `FAULT_REPORT` naming it. A module cannot be
//! enabled while the operator still overrides it; enabling clears the override flag
//! and its fault code.
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
    /// The override flag of its report (set when the operator overrode it, until the
    /// next enable).
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

struct Unit {
    module: Module,
    enable: Id,
    disable: Id,
    command: Message,
    report: Message,
    period: Duration,
    state: ModuleState,
    /// The operator holds the wheel or a pedal right now.
    overriding: bool,
    watchdog: Watchdog,
    next_report: Instant,
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
    faults_due: Vec<Module>,
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
            units.push(Unit {
                module,
                enable: db.message_named(&name("ENABLE"))?.id(),
                disable: db.message_named(&name("DISABLE"))?.id(),
                command,
                period: report.cycle().unwrap_or(REPORT_PERIOD),
                report,
                state: ModuleState::default(),
                overriding: false,
                watchdog: Watchdog::new(watchdog),
                next_report: now,
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
            faults_due: Vec::new(),
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

    /// The identifier of a module's command message.
    pub fn command_id(&self, module: Module) -> Id {
        self.units
            .iter()
            .find(|u| u.module == module)
            .map(|u| u.command.id())
            .expect("every module has a unit")
    }

    /// The operator starts (`true`) or stops overriding `module`. Starting disables an
    /// enabled module, sets its override flag and fault code, and sends a fault report.
    pub fn set_override(&mut self, module: Module, on: bool, now: Instant) {
        let u = self.unit(module);
        u.overriding = on;
        if on && u.state.enabled {
            u.state.enabled = false;
            u.state.operator_override = true;
            let bit = dtc_bit(&u.report, "OPERATOR_OVERRIDE");
            u.state.dtcs |= bit;
            self.faults_due.push(module);
            self.note(module, now, "operator override: disabled".into());
        }
    }

    /// Inject the fault code named `dtc` (a name of the report's `dtcs` value table):
    /// the module disables itself and sends a fault report.
    pub fn inject_fault(&mut self, module: Module, dtc: &str, now: Instant) -> Result<(), String> {
        let u = self.unit(module);
        let dtcs = u
            .report
            .signal("dtcs")
            .ok_or_else(|| format!("{} has no dtcs signal", u.report.name()))?;
        let raw = dtcs
            .values()
            .iter()
            .find(|(_, n)| n.eq_ignore_ascii_case(dtc))
            .map(|(raw, _)| *raw);
        let raw = raw.ok_or_else(|| {
            let names: Vec<&str> = dtcs.values().iter().map(|(_, n)| n.as_str()).collect();
            format!(
                "no fault code {dtc:?} for the {module} ({})",
                names.join(", ")
            )
        })?;
        u.state.dtcs |= raw as u8;
        u.state.enabled = false;
        self.faults_due.push(module);
        self.note(module, now, format!("fault {dtc}: disabled"));
        Ok(())
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

/// The bit of the fault code named `name` in a report's `dtcs` (0 if the DBC lacks it).
fn dtc_bit(report: &Message, name: &str) -> u8 {
    report
        .signal("dtcs")
        .and_then(|s| s.value_of(name))
        .unwrap_or(0) as u8
}

impl BusNode for Kit {
    fn receive(&mut self, frame: &Frame, now: Instant) {
        if frame.data().get(..2) != Some(&MAGIC[..]) {
            return;
        }
        let id = frame.id();
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
            if u.overriding {
                self.note(module, now, "enable refused: the operator overrides".into());
            } else if !u.state.enabled {
                u.state.enabled = true;
                u.state.operator_override = false;
                u.state.dtcs &= !dtc_bit(&u.report, "OPERATOR_OVERRIDE");
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
        for module in std::mem::take(&mut self.faults_due) {
            let u = self.unit(module);
            let dtcs = u.state.dtcs as f64;
            let origin = self
                .fault
                .signal("fault_origin_id")
                .and_then(|s| s.value_of(module.prefix()))
                .unwrap_or(0) as f64;
            if let Ok(f) = self
                .fault
                .encode(&[("fault_origin_id", origin), ("dtcs", dtcs)])
            {
                bus.push(f);
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

    #[test]
    fn an_operator_override_disables_reports_and_blocks_enable_until_released() {
        let mut b = Bench::new(None);
        b.send(0, "BRAKE_ENABLE", &[]);
        b.run(0, 5);
        b.port.node.set_override(Module::Brake, true, b.t0 + 6 * MS);
        let frames = b.run(6, 20);
        let (enabled, overridden, dtcs) = b.report(&frames, Module::Brake);
        assert_eq!((enabled, overridden), (0.0, 1.0));
        assert_eq!(dtcs, vec!["OPERATOR_OVERRIDE"]);
        let fault = b.db.message("FAULT_REPORT").unwrap();
        let reports: Vec<&Frame> = frames.iter().filter(|f| f.id() == fault.id()).collect();
        assert_eq!(reports.len(), 1, "one fault report");
        let origin = fault.signal("fault_origin_id").unwrap();
        let raw = origin.raw(reports[0].data()).unwrap() as i64;
        assert_eq!(origin.value_name(raw), Some("BRAKE"));
        // Still held: enabling is refused.
        b.send(21, "BRAKE_ENABLE", &[]);
        assert!(!b.port.node.state(Module::Brake).enabled);
        b.port
            .node
            .set_override(Module::Brake, false, b.t0 + 22 * MS);
        b.send(23, "BRAKE_ENABLE", &[]);
        let frames = b.run(21, 40);
        assert_eq!(b.report(&frames, Module::Brake), (1.0, 0.0, vec![]));
    }

    #[test]
    fn a_fault_injected_by_name_disables_and_is_reported_by_name() {
        let mut b = Bench::new(None);
        b.send(0, "STEERING_ENABLE", &[]);
        let e = b.port.node.inject_fault(Module::Steering, "OVERHEAT", b.t0);
        assert_eq!(
            e.unwrap_err(),
            "no fault code \"OVERHEAT\" for the steering (INVALID_SENSOR_VAL, OPERATOR_OVERRIDE)"
        );
        b.port
            .node
            .inject_fault(Module::Steering, "INVALID_SENSOR_VAL", b.t0 + MS)
            .unwrap();
        let frames = b.run(1, 20);
        assert_eq!(
            b.report(&frames, Module::Steering),
            (0.0, 0.0, vec!["INVALID_SENSOR_VAL".to_string()])
        );
        let fault = b.db.message("FAULT_REPORT").unwrap();
        let f = frames.iter().find(|f| f.id() == fault.id()).unwrap();
        let got: Vec<(String, f64)> = fault.decode(f).map(|(s, v)| (s.name().into(), v)).collect();
        assert_eq!(
            got[2..],
            [("fault_origin_id".into(), 1.0), ("dtcs".into(), 1.0)]
        );
    }

    #[test]
    fn modules_by_name() {
        assert_eq!("steering".parse::<Module>(), Ok(Module::Steering));
        assert_eq!("THROTTLE".parse::<Module>(), Ok(Module::Throttle));
        assert!("gas".parse::<Module>().is_err());
    }
}
