//! The simulator's little command language, typed on `adrive sim`'s standard input,
//! given as `--fault LINE`, and sent by the console's bench keys: one table,
//! [`VERBS`], holds every command with its argument forms, the devices it applies to
//! and what it does. Parsing reads the table, so an error names the form expected, and
//! `help` prints the same table, so the two cannot drift apart. Devices are named as
//! the vehicle file names them; a command for a drive (`jam`, `stuck`, `bias`, `override`) applies
//! to setpoint devices.

use crate::value::{DeviceId, EstopState, Kind};
use std::fmt::Write as _;

/// Which devices an argument may name.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Which {
    /// Any device.
    Any,
    /// A setpoint device (a drive with a position).
    Setpoint,
}

/// The devices of the simulated vehicle: name and kind, by id.
pub type Devices = [(String, Kind)];

/// One argument of a command.
#[derive(Clone, Copy, Debug)]
pub(crate) enum Arg {
    /// A device of the vehicle.
    Device(Which),
    /// `on` or `off` (also `1`/`0`, `true`/`false`).
    OnOff,
    /// Milliseconds: `80` or `80ms`.
    Millis,
    /// A finite number.
    Number(&'static str),
    /// An e-stop state.
    Estop,
    /// A finite number, or `off`.
    NumberOrOff(&'static str),
}

impl Arg {
    /// The argument's form, as help and errors show it.
    pub fn form(&self) -> String {
        match self {
            Arg::Device(Which::Any) => "DEVICE".into(),
            Arg::Device(Which::Setpoint) => "SETPOINT".into(),
            Arg::OnOff => "on|off".into(),
            Arg::Millis => "MS".into(),
            Arg::Number(name) => (*name).into(),
            Arg::Estop => "pause|run|disable".into(),
            Arg::NumberOrOff(name) => format!("{name}|off"),
        }
    }

    fn parse(&self, word: &str, devices: &Devices) -> Result<Value, String> {
        match self {
            Arg::Device(which) => {
                let Some(i) = devices.iter().position(|(n, _)| n == word) else {
                    return Err(format!(
                        "unknown device {word:?}; the devices are {}",
                        names(devices, Which::Any)
                    ));
                };
                if *which == Which::Setpoint && devices[i].1 != Kind::Setpoint {
                    return Err(format!(
                        "it applies to setpoint devices ({}), not {word} (a {})",
                        names(devices, Which::Setpoint),
                        devices[i].1
                    ));
                }
                Ok(Value::Device(DeviceId(i as u16)))
            }
            Arg::OnOff => match word {
                "on" | "1" | "true" => Ok(Value::On(true)),
                "off" | "0" | "false" => Ok(Value::On(false)),
                _ => Err(format!("expected on or off, got {word:?}")),
            },
            Arg::Millis => word
                .strip_suffix("ms")
                .unwrap_or(word)
                .parse()
                .map(Value::Millis)
                .map_err(|_| format!("expected milliseconds (80 or 80ms), got {word:?}")),
            Arg::Number(name) => word
                .parse::<f64>()
                .ok()
                .filter(|x| x.is_finite())
                .map(Value::Number)
                .ok_or_else(|| format!("{name} is a number, got {word:?}")),
            Arg::Estop => word.parse().map(Value::Estop),
            Arg::NumberOrOff(_) if word == "off" => Ok(Value::Off),
            Arg::NumberOrOff(name) => Arg::Number(name)
                .parse(word, devices)
                .map_err(|e| format!("{e} or off")),
        }
    }
}

/// The devices an argument may name, for messages.
fn names(devices: &Devices, which: Which) -> String {
    devices
        .iter()
        .filter(|(_, k)| which == Which::Any || *k == Kind::Setpoint)
        .map(|(n, _)| n.as_str())
        .collect::<Vec<_>>()
        .join(", ")
}

/// A parsed argument.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Value {
    Device(DeviceId),
    On(bool),
    Millis(u64),
    Number(f64),
    Estop(EstopState),
    Off,
}

/// One command of the language, parsed.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum SimCommand {
    Estop(EstopState),
    Stall,
    NoStart(bool),
    Jam(DeviceId),
    Stuck(DeviceId, bool),
    Bias(DeviceId, f64),
    /// A driver's hand pushes the device toward the position (`None`: lets go).
    Override(DeviceId, Option<f64>),
    Silent(DeviceId, bool),
    Garbage(DeviceId, bool),
    Corrupt(DeviceId, bool),
    Slow(DeviceId, u64),
    Vanish(DeviceId, u64),
    Clear(DeviceId),
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
    build: fn(&Values) -> SimCommand,
}

impl Verb {
    /// `name ARG…`, as help and errors show it.
    pub fn form(&self) -> String {
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
            v => unreachable!("the table says argument {i} is a device, got {v:?}"),
        }
    }
    fn on(&self, i: usize) -> bool {
        match self.0[i] {
            Value::On(b) => b,
            v => unreachable!("the table says argument {i} is on|off, got {v:?}"),
        }
    }
    fn ms(&self, i: usize) -> u64 {
        match self.0[i] {
            Value::Millis(ms) => ms,
            v => unreachable!("the table says argument {i} is milliseconds, got {v:?}"),
        }
    }
    fn number(&self, i: usize) -> f64 {
        match self.0[i] {
            Value::Number(x) => x,
            v => unreachable!("the table says argument {i} is a number, got {v:?}"),
        }
    }
    fn number_or_off(&self, i: usize) -> Option<f64> {
        match self.0[i] {
            Value::Number(x) => Some(x),
            Value::Off => None,
            v => unreachable!("the table says argument {i} is a number or off, got {v:?}"),
        }
    }
    fn estop(&self, i: usize) -> EstopState {
        match self.0[i] {
            Value::Estop(s) => s,
            v => unreachable!("the table says argument {i} is an e-stop state, got {v:?}"),
        }
    }
}

const ANY: Arg = Arg::Device(Which::Any);
const SETPOINT: Arg = Arg::Device(Which::Setpoint);

/// Every command the simulator takes.
pub(crate) const VERBS: &[Verb] = &[
    Verb {
        name: "estop",
        args: &[Arg::Estop],
        does: "change the e-stop state",
        example: "estop pause",
        build: |v| SimCommand::Estop(v.estop(0)),
    },
    Verb {
        name: "stall",
        args: &[],
        does: "the engine stalls",
        example: "stall",
        build: |_| SimCommand::Stall,
    },
    Verb {
        name: "nostart",
        args: &[Arg::OnOff],
        does: "the starter turns but the engine never catches",
        example: "nostart on",
        build: |v| SimCommand::NoStart(v.on(0)),
    },
    Verb {
        name: "silent",
        args: &[ANY, Arg::OnOff],
        does: "the device stops answering",
        example: "silent gas on",
        build: |v| SimCommand::Silent(v.device(0), v.on(1)),
    },
    Verb {
        name: "garbage",
        args: &[ANY, Arg::OnOff],
        does: "the device answers noise",
        example: "garbage steer on",
        build: |v| SimCommand::Garbage(v.device(0), v.on(1)),
    },
    Verb {
        name: "corrupt",
        args: &[ANY, Arg::OnOff],
        does: "flip a bit in every reply (bad CRC or checksum)",
        example: "corrupt brake on",
        build: |v| SimCommand::Corrupt(v.device(0), v.on(1)),
    },
    Verb {
        name: "slow",
        args: &[ANY, Arg::Millis],
        does: "answer MS later (0 clears)",
        example: "slow trans 80",
        build: |v| SimCommand::Slow(v.device(0), v.ms(1)),
    },
    Verb {
        name: "vanish",
        args: &[ANY, Arg::Millis],
        does:
            "close the port and remove its link (a USB unplug); back after MS behind the same link",
        example: "vanish obd 2000",
        build: |v| SimCommand::Vanish(v.device(0), v.ms(1)),
    },
    Verb {
        name: "clear",
        args: &[ANY],
        does: "clear the device's port faults (silent, garbage, corrupt, slow)",
        example: "clear gas",
        build: |v| SimCommand::Clear(v.device(0)),
    },
    Verb {
        name: "jam",
        args: &[SETPOINT],
        does: "the drive latches a fault (bit 0x0001; disable → enable clears it)",
        example: "jam steer",
        build: |v| SimCommand::Jam(v.device(0)),
    },
    Verb {
        name: "stuck",
        args: &[SETPOINT, Arg::OnOff],
        does: "the motor stops moving and its drive does not notice",
        example: "stuck steer on",
        build: |v| SimCommand::Stuck(v.device(0), v.on(1)),
    },
    Verb {
        name: "bias",
        args: &[SETPOINT, Arg::Number("X")],
        does: "the device reports its position X off (a slipped sensor; 0 clears)",
        example: "bias steer 0.3",
        build: |v| SimCommand::Bias(v.device(0), v.number(1)),
    },
    Verb {
        name: "override",
        args: &[SETPOINT, Arg::NumberOrOff("X")],
        does: "a driver's hand pushes the device toward X, stronger than its drive (off: lets go)",
        example: "override steer 0.5",
        build: |v| SimCommand::Override(v.device(0), v.number_or_off(1)),
    },
    Verb {
        name: "help",
        args: &[],
        does: "this list",
        example: "help",
        build: |_| SimCommand::Help,
    },
];

/// Parse one line against the vehicle's devices. An error says what was wrong and the
/// form expected.
pub fn parse(line: &str, devices: &Devices) -> Result<SimCommand, String> {
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
        .map(|(a, w)| a.parse(w, devices))
        .collect::<Result<Vec<_>, _>>()
        .map_err(|e| format!("{name}: {e}; the form is {}", form()))?;
    Ok((verb.build)(&Values(values)))
}

/// The table as help text: one line per command, then the vehicle's devices.
pub fn help(devices: &Devices) -> String {
    let width = VERBS.iter().map(|v| v.form().len()).max().unwrap_or(0);
    let mut s = String::new();
    for v in VERBS {
        let _ = writeln!(s, "  {:<width$}  {}", v.form(), v.does);
    }
    let _ = writeln!(s, "  DEVICE is one of {}", names(devices, Which::Any));
    let _ = writeln!(
        s,
        "  SETPOINT is one of {}",
        names(devices, Which::Setpoint)
    );
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Alice's devices.
    fn alice() -> Vec<(String, Kind)> {
        crate::config::VehicleConfig::alice()
            .devices
            .iter()
            .map(|d| (d.name.clone(), d.kind))
            .collect()
    }

    fn p(line: &str) -> Result<SimCommand, String> {
        parse(line, &alice())
    }

    const STEER: DeviceId = DeviceId(0);
    const GAS: DeviceId = DeviceId(1);

    #[test]
    fn every_example_in_the_table_parses_with_its_own_verb() {
        for v in VERBS {
            let parsed = p(v.example).unwrap_or_else(|e| panic!("{}: {e}", v.example));
            let again = p(&v.example.to_uppercase()).unwrap();
            assert_eq!(parsed, again, "keywords are case-insensitive");
        }
        assert_eq!(p("bias gas -0.25"), Ok(SimCommand::Bias(GAS, -0.25)));
        assert_eq!(p("slow steer 80ms"), Ok(SimCommand::Slow(STEER, 80)));
        assert_eq!(p("stuck gas on"), Ok(SimCommand::Stuck(GAS, true)));
        assert_eq!(p("override gas off"), Ok(SimCommand::Override(GAS, None)));
        assert_eq!(
            p("override steer -0.5"),
            Ok(SimCommand::Override(STEER, Some(-0.5)))
        );
        let e = p("override steer hard").unwrap_err();
        assert!(e.contains("X is a number, got \"hard\" or off"), "{e}");
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
    }

    #[test]
    fn errors_name_the_form_expected() {
        let e = p("wobble gas on").unwrap_err();
        assert!(e.starts_with("unknown command \"wobble\""), "{e}");
        assert!(e.contains("help"), "{e}");
        let e = p("silent gas").unwrap_err();
        assert!(
            e.contains("silent takes 2 arguments: `silent DEVICE on|off`"),
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
        assert!(h.contains("silent DEVICE on|off"), "{h}");
        assert!(h.contains("override SETPOINT X|off"), "{h}");
        assert!(h.contains("SETPOINT is one of steer, gas, brake"), "{h}");
    }
}
