//! The simulator's little command language, typed on `adrive sim`'s standard input,
//! given as `--fault LINE`, and sent by the console's bench keys: one table,
//! [`VERBS`], holds every command with its argument forms, the devices it applies to
//! and what it does. Parsing reads the table, so an error names the form expected, and
//! `help` prints the same table, so the two cannot drift apart. Devices are named as
//! the vehicle file names them; a command for a drive (`jam`, `stuck`, `bias`, `override`) applies
//! to setpoint devices. A CAN bus is named as its `[[bus]]` is: its adapter is a port
//! like a device's (`vanish kit 2s`), the bus itself can fail (`bus kit off`), and the
//! kit's modules behind it take the operator's override and fault codes by name.
//!
//! A command that would act on something the vehicle does not have — `estop` without a
//! device reading the e-stop, `stall` where nothing reports the engine, `jam` on a kit's
//! module (it has no drive fault latch) — is refused with what is missing ([`Need`]),
//! and `help` lists it apart, so nothing answers a success that changed nothing.

use crate::value::{DeviceId, EstopState, Kind};
use std::fmt::Write as _;

/// Which devices an argument may name.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Which {
    /// Any device.
    Any,
    /// A setpoint device (a drive with a position).
    Setpoint,
    /// A state device (a gearbox and its lever).
    State,
    /// A device that a simulated kit's module drives (on a CAN bus).
    Module,
}

/// The devices of the simulated vehicle: name and kind, by id.
pub(crate) type Devices = [(String, Kind)];

/// Everything a command may name: the vehicle's devices, which of them are on a CAN
/// bus (and so have no port of their own) and which a simulated kit's module drives,
/// and the simulated buses; and what of the vehicle the commands act on shows.
#[derive(Clone, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Names {
    /// Name and kind, by device id.
    pub devices: Vec<(String, Kind)>,
    /// The bus each device is on, by device id (`None`: it has its own port).
    pub bus_of: Vec<Option<usize>>,
    /// The devices a simulated kit's module drives.
    pub modules: Vec<DeviceId>,
    /// The simulated buses, by index.
    pub buses: Vec<String>,
    /// What the simulated vehicle shows of what some commands act on.
    pub has: Has,
}

/// What of the simulated vehicle some device shows, so that a command acting on it
/// can be seen to: a reading on a device's own port, or a kit's message.
#[derive(Clone, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Has {
    /// A device reads the e-stop's state.
    pub estop: bool,
    /// A device reports the engine (its rpm, or whether it runs).
    pub engine: bool,
    /// A device is bound to the starter role.
    pub starter: bool,
    /// The setpoint devices whose position something reports.
    pub positions: Vec<DeviceId>,
}

impl Names {
    fn ports(&self) -> String {
        let mut v: Vec<&str> = self.devices.iter().map(|(n, _)| n.as_str()).collect();
        v.extend(self.buses.iter().map(String::as_str));
        or_none(v)
    }

    fn modules(&self) -> String {
        or_none(
            self.modules
                .iter()
                .map(|id| self.devices[id.index()].0.as_str())
                .collect(),
        )
    }

    fn buses(&self) -> String {
        or_none(self.buses.iter().map(String::as_str).collect())
    }
}

/// A port that faults apply to: a device's own, or a bus's adapter.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Port {
    Device(DeviceId),
    Bus(usize),
}

/// One argument of a command.
#[derive(Clone, Copy, Debug)]
pub(crate) enum Arg {
    /// A device of the vehicle.
    Device(Which),
    /// A device's port, or a bus's: a device on a bus has its bus adapter's.
    Port,
    /// A simulated CAN bus.
    Bus,
    /// A fault code by the name the DBC's value table gives it.
    Dtc,
    /// `on` or `off` (also `1`/`0`, `true`/`false`).
    OnOff,
    /// Milliseconds: `80`, `80ms` or `2s`.
    Millis,
    /// A finite number.
    Number(&'static str),
    /// An e-stop state.
    Estop,
    /// A finite number, `on` or `off`.
    NumberOrOnOff(&'static str),
    /// A word (a state's name), resolved against the device when applied.
    Name(&'static str),
}

impl Arg {
    /// The argument's form, as help and errors show it.
    pub(crate) fn form(&self) -> String {
        match self {
            Arg::Device(Which::Any) => "DEVICE".into(),
            Arg::Device(Which::Setpoint) => "SETPOINT".into(),
            Arg::Device(Which::State) => "STATEDEV".into(),
            Arg::Device(Which::Module) => "MODULE".into(),
            Arg::Port => "PORT".into(),
            Arg::Bus => "BUS".into(),
            Arg::Dtc => "DTC".into(),
            Arg::OnOff => "on|off".into(),
            Arg::Millis => "MS".into(),
            Arg::Number(name) => (*name).into(),
            Arg::Estop => "pause|run|disable".into(),
            Arg::NumberOrOnOff(name) => format!("{name}|on|off"),
            Arg::Name(name) => (*name).into(),
        }
    }

    fn parse(&self, word: &str, names: &Names) -> Result<Value, String> {
        let devices = &*names.devices;
        match self {
            Arg::Device(Which::Module) => {
                let id = Arg::Device(Which::Any).parse(word, names)?;
                if !names.modules.iter().any(|m| Value::Device(*m) == id) {
                    return Err(format!(
                        "{word} is not driven by a simulated kit's module (kit modules: {})",
                        names.modules()
                    ));
                }
                Ok(id)
            }
            Arg::Port => {
                if let Some(b) = names.buses.iter().position(|b| b == word) {
                    return Ok(Value::Port(Port::Bus(b)));
                }
                let Some(i) = devices.iter().position(|(n, _)| n == word) else {
                    return Err(format!(
                        "unknown device or bus {word:?}; the ports are {}",
                        names.ports()
                    ));
                };
                // A device on a bus has no port of its own: its port is the adapter's.
                Ok(Value::Port(match names.bus_of.get(i).copied().flatten() {
                    None => Port::Device(DeviceId(i as u16)),
                    Some(b) => Port::Bus(b),
                }))
            }
            Arg::Bus => names
                .buses
                .iter()
                .position(|b| b == word)
                .map(Value::Bus)
                .ok_or_else(|| format!("unknown bus {word:?}; the buses are {}", names.buses())),
            Arg::Dtc => Ok(Value::Word(word.to_ascii_uppercase())),
            Arg::Name(_) => Ok(Value::Word(word.to_string())),
            Arg::Device(which) => {
                let Some(i) = devices.iter().position(|(n, _)| n == word) else {
                    return Err(format!(
                        "unknown device {word:?}; the devices are {}",
                        list(devices, Which::Any)
                    ));
                };
                for (w, kind, what) in [
                    (Which::Setpoint, Kind::Setpoint, "setpoint"),
                    (Which::State, Kind::State, "state"),
                ] {
                    if *which == w && devices[i].1 != kind {
                        return Err(format!(
                            "it applies to {what} devices ({}), not {word} (a {})",
                            list(devices, w),
                            devices[i].1
                        ));
                    }
                }
                Ok(Value::Device(DeviceId(i as u16)))
            }
            Arg::OnOff => match word {
                "on" | "1" | "true" => Ok(Value::On(true)),
                "off" | "0" | "false" => Ok(Value::On(false)),
                _ => Err(format!("expected on or off, got {word:?}")),
            },
            Arg::Millis => {
                let (number, per) = match word.strip_suffix("ms") {
                    Some(n) => (n, 1),
                    None => match word.strip_suffix('s') {
                        Some(n) => (n, 1000),
                        None => (word, 1),
                    },
                };
                number
                    .parse::<u64>()
                    .ok()
                    .and_then(|n| n.checked_mul(per))
                    .map(Value::Millis)
                    .ok_or_else(|| format!("expected milliseconds (80, 80ms or 2s), got {word:?}"))
            }
            Arg::Number(name) => word
                .parse::<f64>()
                .ok()
                .filter(|x| x.is_finite())
                .map(Value::Number)
                .ok_or_else(|| format!("{name} is a number, got {word:?}")),
            Arg::Estop => word.parse().map(Value::Estop),
            Arg::NumberOrOnOff(_) if word == "on" => Ok(Value::On(true)),
            Arg::NumberOrOnOff(_) if word == "off" => Ok(Value::Off),
            Arg::NumberOrOnOff(name) => Arg::Number(name)
                .parse(word, names)
                .map_err(|e| format!("{e}, on or off")),
        }
    }
}

/// The devices an argument may name, for messages.
fn list(devices: &Devices, which: Which) -> String {
    or_none(
        devices
            .iter()
            .filter(|(_, k)| match which {
                Which::Setpoint => *k == Kind::Setpoint,
                Which::State => *k == Kind::State,
                Which::Any | Which::Module => true,
            })
            .map(|(n, _)| n.as_str())
            .collect(),
    )
}

/// Names for a message, or that there are none: never an empty list.
fn or_none(names: Vec<&str>) -> String {
    if names.is_empty() {
        "none in this vehicle".into()
    } else {
        names.join(", ")
    }
}

/// A parsed argument.
#[derive(Clone, Debug, PartialEq)]
pub(crate) enum Value {
    Device(DeviceId),
    Port(Port),
    Bus(usize),
    Word(String),
    On(bool),
    Millis(u64),
    Number(f64),
    Estop(EstopState),
    Off,
}

/// One command of the language, parsed.
#[derive(Clone, Debug, PartialEq)]
pub(crate) enum SimCommand {
    Estop(EstopState),
    Stall,
    NoStart(bool),
    Jam(DeviceId),
    Stuck(DeviceId, bool),
    Bias(DeviceId, f64),
    /// A driver's hand pushes the device toward the position (`None`: lets go); on a
    /// kit's module, its operator override goes on with it (off with `None`).
    Override(DeviceId, Option<f64>),
    /// A driver's hand moves a state device's lever (a gear lever) to the state named:
    /// it is in that state at once, as a manual shift leaves it, with no command.
    Lever(DeviceId, String),
    /// A kit's module: the operator overrides it (`true`) or lets go.
    KitOverride(DeviceId, bool),
    /// A kit's module: the condition behind the fault code named holds (`true`) or
    /// ends.
    Fault(DeviceId, String, bool),
    /// A bus is well (`true`) or in error (`false`).
    Bus(usize, bool),
    Silent(Port, bool),
    Garbage(Port, bool),
    Corrupt(Port, bool),
    Slow(Port, u64),
    Vanish(Port, u64),
    Clear(Port),
    Help,
}

/// One entry of the table.
pub(crate) struct Verb {
    pub name: &'static str,
    pub args: &'static [Arg],
    /// What it does, for help.
    pub does: &'static str,
    /// A line that uses it (help shows it; a test parses every one).
    pub example: &'static str,
    /// What of the vehicle it acts on, which must exist.
    pub needs: Need,
    build: fn(&Values) -> SimCommand,
}

/// What a command acts on beyond the devices its arguments name, which the vehicle
/// must have for the command to do anything.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Need {
    Nothing,
    /// A device reading the e-stop.
    Estop,
    /// A device reporting the engine.
    Engine,
    /// A starter, and a device reporting the engine.
    Starter,
    /// The device of the first argument has a drive of its own (not a kit's module),
    /// whose fault latch its status shows.
    Drive,
    /// Something reports the position of the device of the first argument.
    Position,
}

impl Need {
    /// Whether the vehicle has it, for the parsed arguments: else what is missing.
    fn check(self, values: &Values, names: &Names) -> Result<(), String> {
        let has = &names.has;
        let name = |i: usize| names.devices[values.device(i).index()].0.as_str();
        match self {
            Need::Estop if !has.estop => {
                Err("no e-stop is bound on this vehicle (no device reads an e-stop state)".into())
            }
            Need::Engine | Need::Starter if !has.engine => Err(
                "no device of this vehicle reports the engine (its rpm, or whether it runs)".into(),
            ),
            Need::Starter if !has.starter => {
                Err("no starter is bound on this vehicle (the starter role)".into())
            }
            Need::Drive => {
                let id = values.device(0);
                match names.bus_of.get(id.index()).copied().flatten() {
                    None => Ok(()),
                    Some(b) if names.modules.contains(&id) => Err(format!(
                        "{} is driven by a kit's module on bus {}, which has no drive fault latch (`fault {} DTC on` holds a fault of its module)",
                        name(0),
                        names.buses.get(b).map_or("?", String::as_str),
                        name(0)
                    )),
                    Some(b) => Err(format!(
                        "{} is on bus {}, where the simulator drives no drive of its",
                        name(0),
                        names.buses.get(b).map_or("?", String::as_str)
                    )),
                }
            }
            Need::Position if !has.positions.contains(&values.device(0)) => Err(format!(
                "nothing reports {}'s position on this vehicle",
                name(0)
            )),
            _ => Ok(()),
        }
    }

    /// What the vehicle lacks for it, when that does not depend on the arguments.
    fn missing(self, names: &Names) -> Option<String> {
        let none = Values(Vec::new());
        match self {
            Need::Estop | Need::Engine | Need::Starter => self.check(&none, names).err(),
            _ => None,
        }
    }
}

impl Verb {
    /// `name ARG…`, as help and errors show it.
    pub(crate) fn form(&self) -> String {
        let mut s = self.name.to_string();
        for a in self.args {
            s.push(' ');
            s.push_str(&a.form());
        }
        s
    }
}

/// The arguments of one line, in the verb's order (checked against its table entry).
pub(crate) struct Values(Vec<Value>);

impl Values {
    fn device(&self, i: usize) -> DeviceId {
        match self.0[i] {
            Value::Device(r) => r,
            ref v => unreachable!("the table says argument {i} is a device, got {v:?}"),
        }
    }
    fn port(&self, i: usize) -> Port {
        match self.0[i] {
            Value::Port(p) => p,
            ref v => unreachable!("the table says argument {i} is a port, got {v:?}"),
        }
    }
    fn bus(&self, i: usize) -> usize {
        match self.0[i] {
            Value::Bus(b) => b,
            ref v => unreachable!("the table says argument {i} is a bus, got {v:?}"),
        }
    }
    fn word(&self, i: usize) -> String {
        match &self.0[i] {
            Value::Word(w) => w.clone(),
            v => unreachable!("the table says argument {i} is a word, got {v:?}"),
        }
    }
    fn on(&self, i: usize) -> bool {
        match self.0[i] {
            Value::On(b) => b,
            ref v => unreachable!("the table says argument {i} is on|off, got {v:?}"),
        }
    }
    fn ms(&self, i: usize) -> u64 {
        match self.0[i] {
            Value::Millis(ms) => ms,
            ref v => unreachable!("the table says argument {i} is milliseconds, got {v:?}"),
        }
    }
    fn number(&self, i: usize) -> f64 {
        match self.0[i] {
            Value::Number(x) => x,
            ref v => unreachable!("the table says argument {i} is a number, got {v:?}"),
        }
    }
    fn number_or_off(&self, i: usize) -> Option<f64> {
        match self.0[i] {
            Value::Number(x) => Some(x),
            Value::Off => None,
            ref v => unreachable!("the table says argument {i} is a number or off, got {v:?}"),
        }
    }
    fn estop(&self, i: usize) -> EstopState {
        match self.0[i] {
            Value::Estop(s) => s,
            ref v => unreachable!("the table says argument {i} is an e-stop state, got {v:?}"),
        }
    }
}

const SETPOINT: Arg = Arg::Device(Which::Setpoint);
const MODULE: Arg = Arg::Device(Which::Module);
const STATEDEV: Arg = Arg::Device(Which::State);

/// Every command the simulator takes.
pub(crate) const VERBS: &[Verb] = &[
    Verb {
        name: "estop",
        args: &[Arg::Estop],
        does: "change the e-stop state",
        example: "estop pause",
        needs: Need::Estop,
        build: |v| SimCommand::Estop(v.estop(0)),
    },
    Verb {
        name: "stall",
        args: &[],
        does: "the engine stalls",
        example: "stall",
        needs: Need::Engine,
        build: |_| SimCommand::Stall,
    },
    Verb {
        name: "nostart",
        args: &[Arg::OnOff],
        does: "the starter turns but the engine never catches",
        example: "nostart on",
        needs: Need::Starter,
        build: |v| SimCommand::NoStart(v.on(0)),
    },
    Verb {
        name: "silent",
        args: &[Arg::Port, Arg::OnOff],
        does: "the device (or a bus's adapter) stops answering",
        example: "silent gas on",
        needs: Need::Nothing,
        build: |v| SimCommand::Silent(v.port(0), v.on(1)),
    },
    Verb {
        name: "garbage",
        args: &[Arg::Port, Arg::OnOff],
        does: "the device answers noise",
        example: "garbage steer on",
        needs: Need::Nothing,
        build: |v| SimCommand::Garbage(v.port(0), v.on(1)),
    },
    Verb {
        name: "corrupt",
        args: &[Arg::Port, Arg::OnOff],
        does: "flip a bit in every reply (bad CRC or checksum)",
        example: "corrupt brake on",
        needs: Need::Nothing,
        build: |v| SimCommand::Corrupt(v.port(0), v.on(1)),
    },
    Verb {
        name: "slow",
        args: &[Arg::Port, Arg::Millis],
        does: "answer MS later (0 clears)",
        example: "slow trans 80",
        needs: Need::Nothing,
        build: |v| SimCommand::Slow(v.port(0), v.ms(1)),
    },
    Verb {
        name: "vanish",
        args: &[Arg::Port, Arg::Millis],
        does:
            "close the port and remove its link (a USB unplug); back after MS behind the same link",
        example: "vanish obd 2s",
        needs: Need::Nothing,
        build: |v| SimCommand::Vanish(v.port(0), v.ms(1)),
    },
    Verb {
        name: "clear",
        args: &[Arg::Port],
        does: "clear the port's faults (silent, garbage, corrupt, slow)",
        example: "clear gas",
        needs: Need::Nothing,
        build: |v| SimCommand::Clear(v.port(0)),
    },
    Verb {
        name: "jam",
        args: &[SETPOINT],
        does: "the drive latches a fault (bit 0x0001; disable → enable clears it)",
        example: "jam steer",
        needs: Need::Drive,
        build: |v| SimCommand::Jam(v.device(0)),
    },
    Verb {
        name: "stuck",
        args: &[SETPOINT, Arg::OnOff],
        does: "the motor stops moving and its drive does not notice",
        example: "stuck steer on",
        needs: Need::Nothing,
        build: |v| SimCommand::Stuck(v.device(0), v.on(1)),
    },
    Verb {
        name: "bias",
        args: &[SETPOINT, Arg::Number("X")],
        does: "the device reports its position X off (a slipped sensor; 0 clears)",
        example: "bias steer 0.3",
        needs: Need::Position,
        build: |v| SimCommand::Bias(v.device(0), v.number(1)),
    },
    Verb {
        name: "override",
        args: &[SETPOINT, Arg::NumberOrOnOff("X")],
        does: "a driver's hand pushes the device toward X, stronger than its drive (off: lets go); a kit's module also reports the operator's override (on: just that)",
        example: "override steer 0.5",
        needs: Need::Nothing,
        build: |v| match v.0[1] {
            Value::On(_) => SimCommand::KitOverride(v.device(0), true),
            _ => SimCommand::Override(v.device(0), v.number_or_off(1)),
        },
    },
    Verb {
        name: "lever",
        args: &[STATEDEV, Arg::Name("STATE")],
        does: "a driver's hand moves the lever of a state device (the gear lever) to STATE: it is in STATE at once, with no command; adrive's next command moves it again",
        example: "lever trans drive",
        needs: Need::Nothing,
        build: |v| SimCommand::Lever(v.device(0), v.word(1)),
    },
    Verb {
        name: "fault",
        args: &[MODULE, Arg::Dtc, Arg::OnOff],
        does: "the condition behind a kit module's fault code DTC (by its DBC name) holds: INVALID_SENSOR_VAL its sensor reads grounded; the module disables itself and reports the code while it holds, and clears it once off",
        example: "fault brake INVALID_SENSOR_VAL on",
        needs: Need::Nothing,
        build: |v| SimCommand::Fault(v.device(0), v.word(1), v.on(2)),
    },
    Verb {
        name: "bus",
        args: &[Arg::Bus, Arg::OnOff],
        does: "off: the bus is in error (bus-off); its adapter refuses frames, delivers none, and its status says bus error",
        example: "bus kit off",
        needs: Need::Nothing,
        build: |v| SimCommand::Bus(v.bus(0), v.on(1)),
    },
    Verb {
        name: "help",
        args: &[],
        does: "this list",
        example: "help",
        needs: Need::Nothing,
        build: |_| SimCommand::Help,
    },
];

/// Parse one line against the vehicle's devices. An error says what was wrong and the
/// form expected.
pub(crate) fn parse(line: &str, names: &Names) -> Result<SimCommand, String> {
    let lower = line.trim().to_ascii_lowercase();
    let words: Vec<&str> = lower.split_whitespace().collect();
    let Some((&name, args)) = words.split_first() else {
        return Err("empty line; type help for the commands".into());
    };
    let Some(verb) = VERBS.iter().find(|v| v.name == name) else {
        let names: Vec<&str> = VERBS.iter().map(|v| v.name).collect();
        return Err(format!(
            "unknown command {name:?}: expected one of {}; type help for the forms",
            names.join(", ")
        ));
    };
    let form = || format!("`{}` (e.g. `{}`)", verb.form(), verb.example);
    if args.len() != verb.args.len() {
        return Err(format!(
            "{name} takes {} argument{}: {}",
            verb.args.len(),
            if verb.args.len() == 1 { "" } else { "s" },
            form()
        ));
    }
    let values = verb
        .args
        .iter()
        .zip(args)
        .map(|(a, w)| a.parse(w, names))
        .collect::<Result<Vec<_>, _>>()
        .map_err(|e| format!("{name}: {e}; the form is {}", form()))?;
    let values = Values(values);
    verb.needs
        .check(&values, names)
        .map_err(|e| format!("{name}: {e}"))?;
    Ok((verb.build)(&values))
}

/// The table as help text: one line per command, then what each argument may name.
pub(crate) fn help(names: &Names) -> String {
    let devices = &*names.devices;
    let width = VERBS.iter().map(|v| v.form().len()).max().unwrap_or(0);
    let mut s = String::new();
    let mut absent = Vec::new();
    for v in VERBS {
        match v.needs.missing(names) {
            None => {
                let _ = writeln!(s, "  {:<width$}  {}", v.form(), v.does);
            }
            Some(why) => absent.push(format!("{} ({why})", v.name)),
        }
    }
    if !absent.is_empty() {
        let _ = writeln!(s, "  not on this vehicle: {}", absent.join("; "));
    }
    let _ = writeln!(s, "  SETPOINT is one of {}", list(devices, Which::Setpoint));
    let _ = writeln!(
        s,
        "  STATEDEV is one of {}; STATE one of its states",
        list(devices, Which::State)
    );
    let _ = writeln!(
        s,
        "  PORT is a device or a bus (a device on a bus: its bus's adapter): {}",
        names.ports()
    );
    let _ = writeln!(s, "  BUS is one of {}", names.buses());
    let _ = writeln!(
        s,
        "  MODULE is a device a kit's module drives: {}",
        names.modules()
    );
    let _ = writeln!(
        s,
        "  DTC is a fault code of the module's report, as its DBC names it"
    );
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Alice's devices, each on its own port: the e-stop, the engine and a starter, and
    /// the drives' positions, all reported.
    fn alice() -> Names {
        let devices: Vec<(String, Kind)> = crate::config::VehicleConfig::alice()
            .devices
            .iter()
            .map(|d| (d.name.clone(), d.kind))
            .collect();
        Names {
            bus_of: vec![None; devices.len()],
            has: Has {
                estop: true,
                engine: true,
                starter: true,
                positions: vec![STEER, GAS, BRAKE],
            },
            devices,
            ..Names::default()
        }
    }

    /// The OSCC Kia Soul: three kit modules and the car, all on bus `kit`.
    fn oscc() -> Names {
        let devices = ["steer", "gas", "brake"]
            .map(|n| (n.to_string(), Kind::Setpoint))
            .into_iter()
            .chain([("car".to_string(), Kind::Sensor)])
            .collect();
        Names {
            devices,
            bus_of: vec![Some(0); 4],
            modules: vec![DeviceId(0), DeviceId(1), DeviceId(2)],
            buses: vec!["kit".into()],
            // The steering wheel angle and the brake pressure are on the bus; nothing
            // reads an e-stop or the engine.
            has: Has {
                positions: vec![STEER, BRAKE],
                ..Has::default()
            },
        }
    }

    fn p(line: &str) -> Result<SimCommand, String> {
        parse(line, &alice())
    }

    fn k(line: &str) -> Result<SimCommand, String> {
        parse(line, &oscc())
    }

    const STEER: DeviceId = DeviceId(0);
    const GAS: DeviceId = DeviceId(1);
    const BRAKE: DeviceId = DeviceId(2);

    #[test]
    fn every_example_in_the_table_parses_with_its_own_verb() {
        for v in VERBS {
            let parsed = p(v.example)
                .or_else(|_| k(v.example))
                .unwrap_or_else(|e| panic!("{}: {e}", v.example));
            let again = p(&v.example.to_uppercase())
                .or_else(|_| k(&v.example.to_uppercase()))
                .unwrap();
            assert_eq!(parsed, again, "keywords are case-insensitive");
        }
        assert_eq!(p("bias gas -0.25"), Ok(SimCommand::Bias(GAS, -0.25)));
        assert_eq!(
            p("slow steer 80ms"),
            Ok(SimCommand::Slow(Port::Device(STEER), 80))
        );
        assert_eq!(
            p("vanish steer 2s"),
            Ok(SimCommand::Vanish(Port::Device(STEER), 2000))
        );
        assert_eq!(p("stuck gas on"), Ok(SimCommand::Stuck(GAS, true)));
        assert_eq!(p("override gas off"), Ok(SimCommand::Override(GAS, None)));
        assert_eq!(
            p("override steer -0.5"),
            Ok(SimCommand::Override(STEER, Some(-0.5)))
        );
        let e = p("override steer hard").unwrap_err();
        assert!(e.contains("X is a number, got \"hard\", on or off"), "{e}");
    }

    #[test]
    fn a_kits_bus_and_modules_take_their_own_commands() {
        assert_eq!(
            k("override steer on"),
            Ok(SimCommand::KitOverride(STEER, true))
        );
        assert_eq!(
            k("override steer off"),
            Ok(SimCommand::Override(STEER, None))
        );
        assert_eq!(
            k("fault brake invalid_sensor_val on"),
            Ok(SimCommand::Fault(BRAKE, "INVALID_SENSOR_VAL".into(), true))
        );
        assert_eq!(
            k("fault brake INVALID_SENSOR_VAL off"),
            Ok(SimCommand::Fault(BRAKE, "INVALID_SENSOR_VAL".into(), false))
        );
        assert_eq!(k("bus kit off"), Ok(SimCommand::Bus(0, false)));
        assert_eq!(
            k("vanish kit 2s"),
            Ok(SimCommand::Vanish(Port::Bus(0), 2000))
        );
        assert_eq!(
            k("silent kit on"),
            Ok(SimCommand::Silent(Port::Bus(0), true))
        );
        assert_eq!(
            k("silent steer on"),
            Ok(SimCommand::Silent(Port::Bus(0), true)),
            "a device on a bus: its bus's adapter"
        );
        let e = k("fault car INVALID_SENSOR_VAL on").unwrap_err();
        assert!(
            e.contains(
                "car is not driven by a simulated kit's module (kit modules: steer, gas, brake)"
            ),
            "{e}"
        );
        let e = k("bus can2 off").unwrap_err();
        assert!(e.contains("unknown bus \"can2\"; the buses are kit"), "{e}");
        let e = p("bus kit off").unwrap_err();
        assert!(e.contains("the buses are none in this vehicle"), "{e}");
    }

    /// The incident: on the OSCC kit, `estop pause` answered "estop is now pause" and
    /// `stall` "engine stalled", though nothing of the vehicle reads an e-stop or the
    /// engine, and the bench box then showed states that do not exist. A command is
    /// refused with what the vehicle lacks for it, and `help` lists it apart.
    #[test]
    fn a_command_for_what_the_vehicle_does_not_have_says_what_is_missing() {
        let e = k("estop pause").unwrap_err();
        assert_eq!(
            e,
            "estop: no e-stop is bound on this vehicle (no device reads an e-stop state)"
        );
        let e = k("stall").unwrap_err();
        assert_eq!(
            e,
            "stall: no device of this vehicle reports the engine (its rpm, or whether it runs)"
        );
        assert!(k("nostart on").unwrap_err().contains("reports the engine"));
        let e = k("jam steer").unwrap_err();
        assert_eq!(
            e,
            "jam: steer is driven by a kit's module on bus kit, which has no drive fault latch (`fault steer DTC on` holds a fault of its module)"
        );
        let e = k("bias gas 0.1").unwrap_err();
        assert_eq!(e, "bias: nothing reports gas's position on this vehicle");
        assert_eq!(k("bias steer 0.1"), Ok(SimCommand::Bias(STEER, 0.1)));
        assert_eq!(k("stuck gas on"), Ok(SimCommand::Stuck(GAS, true)));
        let no_starter = Names {
            has: Has {
                starter: false,
                ..alice().has
            },
            ..alice()
        };
        let e = parse("nostart on", &no_starter).unwrap_err();
        assert_eq!(
            e,
            "nostart: no starter is bound on this vehicle (the starter role)"
        );
        assert_eq!(p("stall"), Ok(SimCommand::Stall));

        let h = help(&oscc());
        for gone in ["estop pause|run|disable", "  stall ", "nostart on|off"] {
            assert!(!h.contains(gone), "{gone} offered:\n{h}");
        }
        assert!(
            h.contains("not on this vehicle: estop (no e-stop is bound on this vehicle (no device reads an e-stop state)); stall (no device"),
            "{h}"
        );
        assert!(!help(&alice()).contains("not on this vehicle"));
    }

    /// A list of devices in a message is never empty.
    #[test]
    fn a_vehicle_without_setpoint_devices_says_so() {
        let sensors = Names {
            devices: vec![("obd".into(), Kind::Sensor)],
            bus_of: vec![None],
            ..Names::default()
        };
        let e = parse("stuck obd on", &sensors).unwrap_err();
        assert!(
            e.contains("it applies to setpoint devices (none in this vehicle), not obd (a sensor)"),
            "{e}"
        );
        assert!(help(&sensors).contains("SETPOINT is one of none in this vehicle"));
    }

    /// The incident: `stuck gas on` was refused with a message that did not say
    /// `stuck` is for drives only, and `bias estop 1` was accepted.
    #[test]
    fn a_command_for_the_wrong_device_says_which_devices_it_applies_to() {
        let e = p("bias estop 1").unwrap_err();
        assert!(
            e.contains("applies to setpoint devices (steer, gas, brake), not estop (a sensor)"),
            "{e}"
        );
        assert!(e.contains("`bias SETPOINT X`"), "{e}");
        let e = p("jam trans").unwrap_err();
        assert!(e.contains("not trans (a state)"), "{e}");
        let e = p("lever steer drive").unwrap_err();
        assert!(
            e.contains("applies to state devices (trans), not steer (a setpoint)"),
            "{e}"
        );
        assert!(e.contains("`lever STATEDEV STATE`"), "{e}");
        assert_eq!(
            p("lever trans Drive"),
            Ok(SimCommand::Lever(DeviceId(3), "drive".into()))
        );
    }

    #[test]
    fn errors_name_the_form_expected() {
        let e = p("wobble gas on").unwrap_err();
        assert!(e.starts_with("unknown command \"wobble\""), "{e}");
        assert!(e.contains("help"), "{e}");
        let e = p("silent gas").unwrap_err();
        assert!(
            e.contains("silent takes 2 arguments: `silent PORT on|off`"),
            "{e}"
        );
        let e = p("silent gas maybe").unwrap_err();
        assert!(e.contains("expected on or off, got \"maybe\""), "{e}");
        let e = p("slow gas fast").unwrap_err();
        assert!(e.contains("milliseconds"), "{e}");
        let e = p("bias steer nan").unwrap_err();
        assert!(e.contains("X is a number"), "{e}");
        let e = p("estop stop").unwrap_err();
        assert!(e.contains("pause"), "{e}");
        let e = p("silent wiper on").unwrap_err();
        assert!(
            e.contains(
                "unknown device or bus \"wiper\"; the ports are steer, gas, brake, trans, estop, obd"
            ),
            "{e}"
        );
        let e = p("stuck wiper on").unwrap_err();
        assert!(
            e.contains(
                "unknown device \"wiper\"; the devices are steer, gas, brake, trans, estop, obd"
            ),
            "{e}"
        );
    }

    #[test]
    fn help_lists_every_command_with_its_form_and_the_devices() {
        let h = help(&alice());
        for v in VERBS {
            assert!(h.contains(&v.form()), "help lacks {}:\n{h}", v.form());
        }
        assert!(h.contains("stuck SETPOINT on|off"), "{h}");
        assert!(h.contains("silent PORT on|off"), "{h}");
        assert!(h.contains("override SETPOINT X|on|off"), "{h}");
        assert!(h.contains("SETPOINT is one of steer, gas, brake"), "{h}");
        let h = help(&oscc());
        assert!(h.contains("fault MODULE DTC on|off"), "{h}");
        assert!(h.contains("bus BUS on|off"), "{h}");
        assert!(
            h.contains("PORT is a device or a bus (a device on a bus: its bus's adapter): steer, gas, brake, car, kit"),
            "{h}"
        );
        assert!(
            h.contains("MODULE is a device a kit's module drives: steer, gas, brake"),
            "{h}"
        );
    }
}
