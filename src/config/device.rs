//! One device of a vehicle file: its free name, its kind (setpoint, state or sensor),
//! what it takes (a range with units, or a list of named states), what it reports
//! (named readings with units), how often it is polled, and how its protocol maps all
//! of that to the wire ([`super::protocol_map`]). The raw TOML form is turned into a checked
//! [`DeviceConfig`] here; every refusal says what was expected.

use super::limits::{self, Violation};
use super::protocol_map::{self, Wire};
use super::response::{self, Polling, RawResponse, Response};
use super::{duration, opt_duration, SimConfig};
use crate::value::{Command, Kind};
use serde::Deserialize;
use std::time::Duration;
use toml::Spanned;

/// Words of the console's and the simulator's commands that cannot name a device,
/// beside the protocol's keywords ([`crate::value::Keyword`]).
const RESERVED: [&str; 3] = ["all", "help", "none"];

/// A word that cannot name a device: a keyword of the command protocol, or one of
/// [`RESERVED`].
fn reserved(name: &str) -> bool {
    crate::value::Keyword::from_word(name).is_some() || RESERVED.contains(&name)
}

/// The longest free-text name (a vehicle's name, units, a key's description).
pub(crate) const MAX_TEXT: usize = 64;

/// A free-text name a person wrote (a vehicle's name, a device's units, a key's
/// description), which adrive prints in its logs and on the terminal: printable text on
/// one line, at most [`MAX_TEXT`] characters, and not blank unless `blank` allows it. A
/// control character would split a log line (a newline) or reach the terminal (an
/// escape sequence); a blank name shows as nothing.
pub(crate) fn check_text(what: &str, text: &str, blank: bool) -> Result<(), String> {
    let form = || {
        format!(
            "expected printable text on one line{}, at most {MAX_TEXT} characters",
            if blank { "" } else { ", not blank" }
        )
    };
    if let Some(c) = text.chars().find(|c| c.is_control()) {
        return Err(format!(
            "{what} {text:?}: {} ({:?} is a control character)",
            form(),
            c
        ));
    }
    if (!blank && text.trim().is_empty()) || text.chars().count() > MAX_TEXT {
        return Err(format!("{what} {text:?}: {}", form()));
    }
    Ok(())
}

/// The longest device or reading name.
pub(crate) const MAX_NAME: usize = 32;

/// Check a device or reading name: `[a-z][a-z0-9_]*`, at most [`MAX_NAME`] characters.
pub(crate) fn check_name(what: &str, name: &str) -> Result<(), String> {
    let mut chars = name.chars();
    let ok = chars.next().is_some_and(|c| c.is_ascii_lowercase())
        && chars.all(|c| c.is_ascii_lowercase() || c.is_ascii_digit() || c == '_')
        && name.len() <= MAX_NAME;
    if !ok {
        return Err(format!(
            "{what} {name:?}: expected a name of lowercase letters, digits and _, starting with a letter, at most {MAX_NAME} characters (e.g. \"steer\", \"turn_signal\")"
        ));
    }
    if reserved(name) {
        let mut words: Vec<&str> = crate::value::Keyword::ALL
            .iter()
            .map(|k| k.word())
            .collect();
        words.extend(RESERVED);
        return Err(format!(
            "{what} {name:?} is a word of the command grammar; choose another name (reserved: {})",
            words.join(", ")
        ));
    }
    Ok(())
}

/// How a driver port is shared by a device's two threads.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Deserialize, Default)]
#[serde(rename_all = "lowercase")]
pub enum PortRule {
    /// adrive's rule: a status poll yields while a command waits for the port (but
    /// still runs at least every `status_max_age`).
    #[default]
    Priority,
    /// The paper's rule: first come, first served on a plain lock.
    Paper,
}

/// Which protocol a device speaks.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum DriverKind {
    /// The adrive ASCII line protocol.
    Line,
    /// Modbus RTU: servo drives, linear actuators, pedal robots, battery monitors.
    Modbus,
    /// An ELM327 OBD-II adapter.
    Elm327,
    /// A device on a CAN bus (a `[[bus]]` of the file), described by its DBC.
    Can,
}

impl DriverKind {
    /// Its name in a vehicle file (`driver = "modbus"`).
    pub fn as_str(self) -> &'static str {
        match self {
            DriverKind::Line => "line",
            DriverKind::Modbus => "modbus",
            DriverKind::Elm327 => "elm327",
            DriverKind::Can => "can",
        }
    }

    /// The protocol's name for a person, the one every output and the guide use: what
    /// adrive speaks on the port (a CAN device's port is its bus's SLCAN adapter).
    pub fn display_name(self) -> &'static str {
        match self {
            DriverKind::Line => "line",
            DriverKind::Modbus => "Modbus",
            DriverKind::Elm327 => "ELM327",
            DriverKind::Can => "SLCAN",
        }
    }
}

/// [`DriverKind::display_name`].
impl std::fmt::Display for DriverKind {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.display_name())
    }
}

/// What kind of value a reading holds.
#[derive(Clone, Debug, PartialEq)]
pub enum ReadingKind {
    /// A number in the reading's units.
    Number,
    /// Yes or no (an engine running), 1 or 0 on the wire.
    Flag,
    /// One of these named states (a gear, an e-stop state), by index.
    States(Vec<String>),
}

/// One named value a device reports.
#[derive(Clone, Debug, PartialEq)]
pub struct ReadingSpec {
    pub name: String,
    pub units: String,
    pub kind: ReadingKind,
}

impl ReadingSpec {
    /// The value for people and JSON.
    pub fn value(&self, v: f64) -> crate::value::Value {
        use crate::value::Value;
        match &self.kind {
            ReadingKind::Number => Value::Number(v),
            ReadingKind::Flag => Value::Flag(v != 0.0),
            ReadingKind::States(s) => s
                .get(v as usize)
                .map_or(Value::Number(v), |n| Value::Text(n.clone())),
        }
    }
}

/// A well-known reading: its default units and kind, so a vehicle file can just name it.
pub(crate) struct WellKnown {
    pub name: &'static str,
    pub units: &'static str,
    pub flag: bool,
    /// The key in the line protocol's status reply.
    pub(crate) line_key: &'static str,
    /// Decimals shown on screen.
    pub decimals: usize,
    /// What it is, for the guide's table (read by its test).
    #[cfg_attr(not(test), allow(dead_code))]
    pub what: &'static str,
}

/// The reading a setpoint actuator reports where it is by (its estimate's, the held
/// steering's, the brake's): see [`DeviceConfig::position`].
pub(crate) const POSITION: &str = "position";
/// The reading a state actuator reports its state by (the gear's): see
/// [`DeviceConfig::state`].
pub(crate) const STATE: &str = "state";

/// The readings adrive knows by name. Any other reading needs its `units`.
pub(crate) const WELL_KNOWN: [WellKnown; 14] = [
    WellKnown {
        name: POSITION,
        units: "",
        flag: false,
        line_key: "pos",
        decimals: 3,
        what: "where a setpoint actuator is, in its units",
    },
    WellKnown {
        name: "velocity",
        units: "/s",
        flag: false,
        line_key: "vel",
        decimals: 3,
        what: "how fast it moves, units per second",
    },
    WellKnown {
        name: "pressure",
        units: "bar",
        flag: false,
        line_key: "prs",
        decimals: 1,
        what: "brake line pressure",
    },
    WellKnown {
        name: STATE,
        units: "",
        flag: false,
        line_key: "state",
        decimals: 0,
        what: "the state a state actuator reports",
    },
    WellKnown {
        name: "estop",
        units: "",
        flag: false,
        line_key: "estop",
        decimals: 0,
        what: "disable, pause or run",
    },
    WellKnown {
        name: "rpm",
        units: "rpm",
        flag: false,
        line_key: "rpm",
        decimals: 0,
        what: "engine speed",
    },
    WellKnown {
        name: "speed",
        units: "m/s",
        flag: false,
        line_key: "spd",
        decimals: 2,
        what: "road speed",
    },
    WellKnown {
        name: "coolant",
        units: "°C",
        flag: false,
        line_key: "clt",
        decimals: 0,
        what: "coolant temperature",
    },
    WellKnown {
        name: "running",
        units: "",
        flag: true,
        line_key: "run",
        decimals: 0,
        what: "the engine runs (1) or not (0)",
    },
    WellKnown {
        name: super::can::ENABLED,
        units: "",
        flag: true,
        line_key: "en",
        decimals: 0,
        what: "a kit's module reports itself enabled (1) or not (0)",
    },
    WellKnown {
        name: super::can::OVERRIDE,
        units: "",
        flag: true,
        line_key: "ovr",
        decimals: 0,
        what: "a kit's module reports the driver's override (1) or not (0)",
    },
    WellKnown {
        name: "voltage",
        units: "V",
        flag: false,
        line_key: "volt",
        decimals: 1,
        what: "battery voltage",
    },
    WellKnown {
        name: "current",
        units: "A",
        flag: false,
        line_key: "amp",
        decimals: 1,
        what: "battery current",
    },
    WellKnown {
        name: "soc",
        units: "%",
        flag: false,
        line_key: "soc",
        decimals: 0,
        what: "battery state of charge",
    },
];

pub(crate) fn well_known(name: &str) -> Option<&'static WellKnown> {
    WELL_KNOWN.iter().find(|w| w.name == name)
}

/// The guide's table (docs/vehicles.md) of the well-known readings.
#[cfg_attr(not(test), allow(dead_code))]
pub(crate) fn well_known_markdown() -> String {
    let mut out = String::from("| reading | units | line protocol key | |\n|---|---|---|---|\n");
    for w in &WELL_KNOWN {
        let units = match (w.units, w.flag) {
            (_, true) => "1 or 0".to_string(),
            ("", _) => "—".to_string(),
            (u, _) => u.to_string(),
        };
        out.push_str(&format!(
            "| `{}` | {units} | `{}` | {} |\n",
            w.name, w.line_key, w.what
        ));
    }
    out
}

/// One device, checked.
#[derive(Clone, Debug, PartialEq)]
pub struct DeviceConfig {
    /// Its free name: how the vehicle file, the network and the console call it.
    pub name: String,
    pub kind: Kind,
    pub driver: DriverKind,
    /// Serial port path (`/dev/ttyUSB0`, `/dev/serial/by-id/…`). Unused under `--sim`.
    pub port: String,
    pub baud: u32,
    /// How often the status thread polls the device.
    pub status_period: Duration,
    /// The command thread resends the last command when no new one came for this long.
    pub command_timeout: Duration,
    /// A status poll happens at least this often, even while commands keep the port busy.
    pub status_max_age: Duration,
    /// How long one transaction may take, reply included.
    pub reply_timeout: Duration,
    /// The paper's rate cap: at least this long between two commands. Off by default.
    pub min_command_interval: Option<Duration>,
    pub port_rule: PortRule,
    /// A setpoint actuator's range `[min, max]`; `[0, 0]` for the others.
    pub range: [f64; 2],
    /// A setpoint actuator's units (for people; `""` when unitless).
    pub units: String,
    /// A state actuator's states, in order.
    pub states: Vec<String>,
    /// Other words for states (`d` for `drive`, the paper's `1`), by state index.
    pub(crate) aliases: Vec<(String, u8)>,
    /// What it reports, by index (the index of a value in a [`crate::value::Reading`]).
    pub readings: Vec<ReadingSpec>,
    /// What this device is commanded when the vehicle goes to its safe state (beyond
    /// what its role asks: throttle 0, brake full).
    pub safe: Option<Command>,
    pub sim: SimConfig,
    /// How the protocol maps the device to the wire.
    pub wire: Wire,
    /// How the real device answers its command (setpoint devices; the estimator's
    /// model). Without it the device has no estimate.
    pub response: Option<Response>,
    /// How its status thread schedules polls.
    pub polling: Polling,
}

impl DeviceConfig {
    /// Every limit and rule of one device, as the loader applies them to a vehicle
    /// file and the console to its in-place edits (`port` aside: see
    /// [`super::VehicleConfig::check_ports`]).
    pub(crate) fn check_limits(&self) -> Result<(), Violation> {
        use limits::*;
        BAUD.check(u64::from(self.baud))?;
        STATUS_PERIOD.check(self.status_period)?;
        STATUS_MAX_AGE.check(self.status_max_age)?;
        COMMAND_TIMEOUT.check(self.command_timeout)?;
        REPLY_TIMEOUT.check(self.reply_timeout)?;
        if let Some(i) = self.min_command_interval {
            MIN_COMMAND_INTERVAL.check(i)?;
        }
        SIM_TURNAROUND.check(self.sim.turnaround)?;
        SIM_POLL_DELAY.check(self.sim.poll_delay)?;
        SIM_COMMAND_DELAY.check(self.sim.command_delay)?;
        if let Some(w) = self.sim.watchdog {
            SIM_WATCHDOG.check(w)?;
        }
        if let Some(l) = self.sim.lag {
            SIM_LAG.check(l)?;
        }
        SIM_DELAY.check(self.sim.delay)?;
        SIM_SETTLE.check(self.sim.settle)?;
        self.check_sim_motion()?;
        if let Wire::Modbus(m) = &self.wire {
            MODBUS_SLAVE.check(u64::from(m.slave))?;
        }
        if let Some(r) = &self.response {
            response::check(r, self.range)?;
        }
        let show = fmt_duration;
        if self.status_max_age < self.status_period {
            return Err(MAX_AGE_COVERS_PERIOD.violation(
                &["status_max_age", "status_period"],
                format!(
                    "status_max_age {}, status_period {}",
                    show(self.status_max_age),
                    show(self.status_period)
                ),
            ));
        }
        if self.reply_timeout > self.status_max_age {
            return Err(REPLY_WITHIN_MAX_AGE.violation(
                &["reply_timeout", "status_max_age"],
                format!(
                    "reply_timeout {}, status_max_age {}",
                    show(self.reply_timeout),
                    show(self.status_max_age)
                ),
            ));
        }
        if let Some(w) = self.sim.watchdog.filter(|w| *w <= self.command_timeout) {
            return Err(WATCHDOG_OUTLASTS_RESEND.violation(
                &["sim.watchdog", "command_timeout"],
                format!(
                    "sim.watchdog {}, command_timeout {}",
                    show(w),
                    show(self.command_timeout)
                ),
            ));
        }
        Ok(())
    }

    /// How the simulated setpoint actuator moves, in its units ([`SIM_IN_UNITS`]).
    fn check_sim_motion(&self) -> Result<(), Violation> {
        use limits::SIM_IN_UNITS;
        let span = self.range[1] - self.range[0];
        let setpoint = self.kind == Kind::Setpoint;
        if let Some(r) = self.sim.rate {
            if !(setpoint && r.is_finite() && r > 0.0 && r <= span * 1000.0) {
                return Err(SIM_IN_UNITS.violation(&["sim.rate"], format!("sim.rate {r}")));
            }
        }
        for (key, v) in [
            ("sim.deadband", self.sim.deadband),
            ("sim.backlash", self.sim.backlash),
        ] {
            let written = v != 0.0;
            if written && !(setpoint && v.is_finite() && v > 0.0 && v <= span / 10.0) {
                return Err(SIM_IN_UNITS.violation(&[key], format!("{key} {v}")));
            }
        }
        for (name, r) in &self.sim.readings {
            if !(r.noise.is_finite() && r.noise >= 0.0) {
                return Err(SIM_IN_UNITS.violation(
                    &["sim.readings"],
                    format!("sim.readings.{name}.noise {}", r.noise),
                ));
            }
        }
        Ok(())
    }

    pub fn is_actuator(&self) -> bool {
        self.kind.is_actuator()
    }

    /// The command value domain of a setpoint actuator.
    pub fn range(&self) -> [f64; 2] {
        self.range
    }

    /// The index of a reading by name.
    pub fn reading(&self, name: &str) -> Option<usize> {
        self.readings.iter().position(|r| r.name == name)
    }

    /// Whether it is on a CAN bus (its bus's reader stores what it reports; what it is
    /// sent is not an answer).
    pub fn on_bus(&self) -> bool {
        matches!(self.wire, Wire::Can(_))
    }

    /// Its place on a CAN bus, when it is a kit's module that follows the gate (it has
    /// enable or disable messages).
    pub fn kit(&self) -> Option<&super::can::CanMap> {
        match &self.wire {
            Wire::Can(m) if m.is_kit() => Some(m),
            _ => None,
        }
    }

    /// Whether its protocol carries drive control `c` (enable, disable, home, start):
    /// the line protocol carries every one; a Modbus device one with a control register;
    /// a device on a CAN bus its enable and disable messages, if its file names them;
    /// an ELM327 none. `Err` says what it lacks. (Whether the device then obeys — a
    /// starter only on the device that has one — is the device's to answer.)
    pub fn takes_control(&self, c: crate::value::Control) -> Result<(), String> {
        use crate::value::Control;
        let has = match (&self.wire, c) {
            (Wire::Line(_), _) => true,
            (Wire::Modbus(m), _) => m.control.is_some(),
            (Wire::Can(m), Control::Enable) => m.enable.is_some(),
            (Wire::Can(m), Control::Disable) => m.disable.is_some(),
            (Wire::Can(_) | Wire::Elm327(_), _) => false,
        };
        if has {
            return Ok(());
        }
        Err(match &self.wire {
            Wire::Modbus(_) => {
                format!("{}: {c}: its Modbus map has no control register", self.name)
            }
            Wire::Can(_) => format!("{}: {c}: its CAN messages carry no {c}", self.name),
            _ => format!("{}: {c}: its protocol carries no drive controls", self.name),
        })
    }

    /// The index of its [`POSITION`] reading (every setpoint actuator has one).
    pub fn position(&self) -> Option<usize> {
        self.reading(POSITION)
    }

    /// The index of its [`STATE`] reading (a state actuator's, unless it names its
    /// readings otherwise).
    pub fn state(&self) -> Option<usize> {
        self.reading(STATE)
    }

    /// The state index of a word: a state's name or an alias, any case.
    pub fn state_index(&self, word: &str) -> Option<u8> {
        self.states
            .iter()
            .position(|s| s.eq_ignore_ascii_case(word))
            .map(|i| i as u8)
            .or_else(|| {
                self.aliases
                    .iter()
                    .find(|(a, _)| a.eq_ignore_ascii_case(word))
                    .map(|(_, i)| *i)
            })
    }

    /// A state's name by index.
    pub(crate) fn state_name(&self, i: u8) -> Option<&str> {
        self.states.get(i as usize).map(String::as_str)
    }

    /// A command as people and JSON write it.
    pub(crate) fn command_value(&self, c: Command) -> crate::value::Value {
        use crate::value::Value;
        match c {
            Command::Set(v) => Value::Number(v),
            Command::State(i) => Value::Text(
                self.state_name(i)
                    .map_or_else(|| format!("#{i}"), str::to_string),
            ),
            Command::Control(c) => Value::Text(c.as_str().to_string()),
        }
    }

    /// A command in words: `0.250`, `drive`, `home`.
    pub(crate) fn command_text(&self, c: Command) -> String {
        match c {
            Command::Set(v) => format!("{v:.3}"),
            other => self.command_value(other).to_string(),
        }
    }

    /// Read a command from a word, as the network and the console take it: a number
    /// for a setpoint actuator (finite, inside the range), a state or alias for a
    /// state actuator. The error says what was expected.
    pub(crate) fn parse_command(&self, word: &str) -> Result<Command, String> {
        match self.kind {
            Kind::Setpoint => {
                let [lo, hi] = self.range;
                let v: f64 = word.trim().parse().map_err(|_| {
                    format!("{word:?} is not a number: {} takes {lo} … {hi}", self.name)
                })?;
                if !v.is_finite() || v < lo || v > hi {
                    return Err(format!(
                        "{v} is out of range: {} takes {lo} … {hi}",
                        self.name
                    ));
                }
                Ok(Command::Set(v))
            }
            Kind::State => self
                .state_index(word.trim())
                .map(Command::State)
                .ok_or_else(|| {
                    format!(
                        "{} takes one of {}, got {word:?}",
                        self.name,
                        self.states.join(", ")
                    )
                }),
            Kind::Sensor => Err(format!("{} is a sensor: it takes no commands", self.name)),
        }
    }

    /// What the device takes, in words: `-1 … 1`, `park | reverse | neutral | drive`.
    pub fn domain(&self) -> String {
        match self.kind {
            Kind::Setpoint => {
                let [lo, hi] = self.range;
                format!("{lo} … {hi}{}", unit_suffix(&self.units))
            }
            Kind::State => self.states.join(" | "),
            Kind::Sensor => "reports only".into(),
        }
    }
}

fn unit_suffix(u: &str) -> String {
    if u.is_empty() {
        String::new()
    } else {
        format!(" {u}")
    }
}

/// A device as written in the vehicle file, before checking.
#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct RawDevice {
    name: Spanned<String>,
    kind: Spanned<Kind>,
    driver: Spanned<DriverKind>,
    #[serde(default)]
    port: Option<Spanned<String>>,
    #[serde(default = "default_baud")]
    baud: u32,
    #[serde(default = "default_status_period", deserialize_with = "duration")]
    status_period: Duration,
    #[serde(default = "default_command_timeout", deserialize_with = "duration")]
    command_timeout: Duration,
    #[serde(default = "default_status_max_age", deserialize_with = "duration")]
    status_max_age: Duration,
    #[serde(default = "default_reply_timeout", deserialize_with = "duration")]
    reply_timeout: Duration,
    #[serde(default, deserialize_with = "opt_duration")]
    min_command_interval: Option<Duration>,
    #[serde(default)]
    port_rule: PortRule,
    #[serde(default)]
    range: Option<Spanned<Vec<f64>>>,
    #[serde(default)]
    units: Option<Spanned<String>>,
    #[serde(default)]
    states: Option<Spanned<Vec<String>>>,
    #[serde(default)]
    aliases: Option<Spanned<toml::Table>>,
    #[serde(default)]
    readings: Option<Spanned<Vec<Spanned<toml::Value>>>>,
    #[serde(default)]
    safe: Option<Spanned<toml::Value>>,
    #[serde(default)]
    sim: SimConfig,
    #[serde(default)]
    modbus: Option<Spanned<protocol_map::RawModbus>>,
    #[serde(default)]
    line: Option<Spanned<protocol_map::RawLine>>,
    #[serde(default)]
    response: Option<Spanned<RawResponse>>,
    #[serde(default)]
    polling: Option<Spanned<Polling>>,
    #[serde(default)]
    bus: Option<Spanned<String>>,
    #[serde(default)]
    can: Option<Spanned<super::can::RawCan>>,
}

fn default_baud() -> u32 {
    limits::BAUD.default_value() as u32
}
fn default_status_period() -> Duration {
    limits::STATUS_PERIOD.default_value()
}
fn default_command_timeout() -> Duration {
    limits::COMMAND_TIMEOUT.default_value()
}
fn default_status_max_age() -> Duration {
    limits::STATUS_MAX_AGE.default_value()
}
fn default_reply_timeout() -> Duration {
    limits::REPLY_TIMEOUT.default_value()
}

/// A mistake in the vehicle file and where it is (a byte offset into the file).
pub(super) type Mistake = (usize, String);

impl RawDevice {
    /// Where the device starts, for messages about it as a whole.
    pub(super) fn at(&self) -> usize {
        self.name.span().start
    }

    pub(super) fn name(&self) -> &str {
        self.name.get_ref()
    }

    /// Check everything about the device on its own; `sim` says the port is not needed.
    pub(super) fn check(self, buses: &[super::can::BusConfig]) -> Result<DeviceConfig, Mistake> {
        let at_name = self.name.span().start;
        let name = self.name.into_inner();
        check_name("device", &name).map_err(|m| (at_name, m))?;
        let kind = *self.kind.get_ref();
        let at_driver = self.driver.span().start;
        let of = Of {
            name: &name,
            kind,
            at_name,
            at_kind: self.kind.span().start,
        };

        // What it takes.
        let range = of.range(self.range.as_ref())?;
        let states = of.states(self.states)?;
        let aliases = of.aliases(&states, self.aliases)?;

        // What it reports.
        let driver = *self.driver.get_ref();
        let readings = of.readings(
            &states,
            self.readings,
            self.units.as_ref().map(|u| u.get_ref().as_str()),
            driver == DriverKind::Can,
        )?;
        // Said at its own line.
        let at_units = self.units.as_ref().map_or(at_name, |u| u.span().start);
        let units = self.units.map(Spanned::into_inner).unwrap_or_default();
        check_text("units", &units, true).map_err(|m| (at_units, format!("{name}: {m}")))?;
        if kind != Kind::Setpoint && !units.is_empty() {
            return Err((
                at_units,
                format!("{name}: units are for setpoint devices (readings carry their own)"),
            ));
        }
        let response = of.response(range, self.response)?;
        let polling = of.polling(response.is_some(), self.polling)?;

        let partial = DeviceConfig {
            name: name.clone(),
            kind,
            driver,
            port: String::new(),
            baud: self.baud,
            status_period: self.status_period,
            command_timeout: self.command_timeout,
            status_max_age: self.status_max_age,
            reply_timeout: self.reply_timeout,
            min_command_interval: self.min_command_interval,
            port_rule: self.port_rule,
            range,
            units,
            states,
            aliases,
            readings,
            safe: None,
            sim: self.sim,
            wire: Wire::Line(protocol_map::LineMap::default()),
            response,
            polling,
        };
        let safe = match self.safe {
            None => None,
            Some(s) => {
                let at = s.span().start;
                Some(safe_value(&partial, s.get_ref()).map_err(|m| (at, m))?)
            }
        };
        let (wire, port) = if driver == DriverKind::Can {
            if let Some(p) = &self.port {
                return Err((
                    p.span().start,
                    format!("{name}: a CAN device has no port of its own (its bus has)"),
                ));
            }
            if let Some(m) = &self.modbus {
                return Err((
                    m.span().start,
                    format!("{name}: a [device.modbus] table goes with driver = \"modbus\" only"),
                ));
            }
            let map = super::can::resolve(&partial, at_driver, self.bus, self.can, buses)?;
            let port = buses[map.bus].port.clone();
            (Wire::Can(Box::new(map)), port)
        } else {
            if let Some(b) = &self.bus {
                return Err((
                    b.span().start,
                    format!("{name}: `bus` goes with driver = \"can\" only"),
                ));
            }
            if let Some(c) = &self.can {
                return Err((
                    c.span().start,
                    format!("{name}: a [device.can] table goes with driver = \"can\" only"),
                ));
            }
            let wire = protocol_map::resolve(&partial, at_driver, self.modbus, self.line)?;
            (wire, self.port.map(Spanned::into_inner).unwrap_or_default())
        };
        Ok(DeviceConfig {
            port,
            safe,
            wire,
            ..partial
        })
    }
}

/// The device being checked, for the checks of its keys: its name and kind, and where
/// they are written (a refusal about a missing key points there).
struct Of<'a> {
    name: &'a str,
    kind: Kind,
    at_name: usize,
    at_kind: usize,
}

impl Of<'_> {
    /// `range`: a setpoint device's `[min, max]`; `[0, 0]` for the others.
    fn range(&self, range: Option<&Spanned<Vec<f64>>>) -> Result<[f64; 2], Mistake> {
        let (name, kind) = (self.name, self.kind);
        match (kind, range) {
            (Kind::Setpoint, None) => Err((
                self.at_kind,
                format!("{name}: a setpoint device needs `range = [min, max]`"),
            )),
            (Kind::Setpoint, Some(r)) => {
                let v = r.get_ref();
                match v.as_slice() {
                    [lo, hi] if lo.is_finite() && hi.is_finite() && lo < hi => Ok([*lo, *hi]),
                    _ => Err((
                        r.span().start,
                        format!(
                            "{name}: range: expected [min, max], two finite numbers with min < max (got {v:?})"
                        ),
                    )),
                }
            }
            (_, Some(r)) => Err((
                r.span().start,
                format!("{name}: range is for setpoint devices ({name} is a {kind})"),
            )),
            (_, None) => Ok([0.0, 0.0]),
        }
    }

    /// `states`: a state device's, in order.
    fn states(&self, states: Option<Spanned<Vec<String>>>) -> Result<Vec<String>, Mistake> {
        let (name, kind) = (self.name, self.kind);
        match (kind, states) {
            (Kind::State, None) => Err((
                self.at_kind,
                format!("{name}: a state device needs `states = [\"…\", …]`"),
            )),
            (Kind::State, Some(s)) => {
                let at = s.span().start;
                let list = s.into_inner();
                check_states(name, &list).map_err(|m| (at, m))?;
                Ok(list)
            }
            (_, Some(s)) => Err((
                s.span().start,
                format!("{name}: states are for state devices ({name} is a {kind})"),
            )),
            (_, None) => Ok(Vec::new()),
        }
    }

    /// `aliases`: other words for a state device's states.
    fn aliases(
        &self,
        states: &[String],
        aliases: Option<Spanned<toml::Table>>,
    ) -> Result<Vec<(String, u8)>, Mistake> {
        let name = self.name;
        let mut out = Vec::new();
        let Some(a) = aliases else { return Ok(out) };
        let at = a.span().start;
        if self.kind != Kind::State {
            return Err((at, format!("{name}: aliases are for state devices")));
        }
        for (word, target) in a.into_inner() {
            if word.is_empty() || word.chars().any(|c| c.is_control() || c.is_whitespace()) {
                return Err((
                    at,
                    format!("{name}: aliases: {word:?}: expected one word of printable characters (a command's value is one word)"),
                ));
            }
            let Some(target) = target.as_str() else {
                return Err((
                    at,
                    format!("{name}: aliases: {word} = expected a state name in quotes"),
                ));
            };
            let Some(i) = states.iter().position(|s| s == target) else {
                return Err((
                    at,
                    format!(
                        "{name}: aliases: {word} = {target:?} is not a state (states: {})",
                        states.join(", ")
                    ),
                ));
            };
            if states.iter().any(|s| s.eq_ignore_ascii_case(&word)) {
                return Err((at, format!("{name}: aliases: {word:?} is already a state")));
            }
            out.push((word, i as u8));
        }
        Ok(out)
    }

    /// `readings`, or without it the one a setpoint or state device reports by
    /// default (its [`POSITION`] in `units`, its [`STATE`]).
    fn readings(
        &self,
        states: &[String],
        readings: Option<Spanned<Vec<Spanned<toml::Value>>>>,
        units: Option<&str>,
        can: bool,
    ) -> Result<Vec<ReadingSpec>, Mistake> {
        let (name, kind, at_name) = (self.name, self.kind, self.at_name);
        let readings = match readings {
            Some(r) => {
                let at = r.span().start;
                let list = r.into_inner();
                if list.is_empty() {
                    return Err((at, format!("{name}: readings: expected at least one")));
                }
                let mut out: Vec<ReadingSpec> = Vec::new();
                for item in list {
                    let at = item.span().start;
                    let spec =
                        reading_spec(name, kind, states, item.into_inner()).map_err(|m| (at, m))?;
                    if out.iter().any(|o| o.name == spec.name) {
                        return Err((at, format!("{name}: reading {} is listed twice", spec.name)));
                    }
                    out.push(spec);
                }
                out
            }
            None => match kind {
                Kind::Setpoint => vec![ReadingSpec {
                    name: POSITION.into(),
                    units: units.unwrap_or_default().to_string(),
                    kind: ReadingKind::Number,
                }],
                Kind::State => vec![ReadingSpec {
                    name: STATE.into(),
                    units: String::new(),
                    kind: ReadingKind::States(states.to_vec()),
                }],
                Kind::Sensor => {
                    return Err((
                        self.at_kind,
                        format!("{name}: a sensor needs `readings = [\"…\", …]` (what it reports)"),
                    ))
                }
            },
        };
        if readings.len() > crate::value::MAX_READINGS {
            return Err((
                at_name,
                format!(
                    "{name}: at most {} readings a device (got {})",
                    crate::value::MAX_READINGS,
                    readings.len()
                ),
            ));
        }
        // A kit on a CAN bus may report no position (OSCC's modules report only whether
        // they are enabled, overridden and faulted).
        if kind == Kind::Setpoint && !can && !readings.iter().any(|r| r.name == POSITION) {
            return Err((
                at_name,
                format!("{name}: a setpoint device reports its `position` (add it to readings)"),
            ));
        }
        Ok(readings)
    }

    /// `[device.response]`: how a setpoint device answers its command.
    fn response(
        &self,
        range: [f64; 2],
        response: Option<Spanned<RawResponse>>,
    ) -> Result<Option<Response>, Mistake> {
        let (name, kind) = (self.name, self.kind);
        let Some(r) = response else { return Ok(None) };
        let at = r.span().start;
        if kind != Kind::Setpoint {
            return Err((
                at,
                format!(
                    "{name}: [device.response] is for setpoint devices ({name} is a {kind}): {}",
                    limits::RESPONSE_ON_SETPOINTS.text
                ),
            ));
        }
        Ok(Some(
            r.into_inner().resolve(name, range).map_err(|m| (at, m))?,
        ))
    }

    /// `polling`: adaptive only with a response to estimate by.
    fn polling(
        &self,
        has_response: bool,
        polling: Option<Spanned<Polling>>,
    ) -> Result<Polling, Mistake> {
        let name = self.name;
        let Some(p) = polling else {
            return Ok(Polling::Fixed);
        };
        if *p.get_ref() == Polling::Adaptive && !has_response {
            return Err((
                p.span().start,
                format!(
                    "{name}: polling = \"adaptive\" needs a [device.response] (how the real device answers its command: the estimate adaptive polling polls by)"
                ),
            ));
        }
        Ok(p.into_inner())
    }
}

fn check_states(name: &str, list: &[String]) -> Result<(), String> {
    if list.len() < 2 {
        return Err(format!(
            "{name}: states: expected at least two names, e.g. [\"off\", \"on\"]"
        ));
    }
    if list.len() > u8::MAX as usize {
        return Err(format!("{name}: states: at most 255"));
    }
    for (i, s) in list.iter().enumerate() {
        check_name("state", s).map_err(|m| format!("{name}: {m}"))?;
        if list[..i].contains(s) {
            return Err(format!("{name}: state {s} is listed twice"));
        }
    }
    Ok(())
}

/// One entry of `readings`: a well-known name, or a table
/// `{ name, units, states = [..], flag = true }`.
fn reading_spec(
    device: &str,
    kind: Kind,
    states: &[String],
    v: toml::Value,
) -> Result<ReadingSpec, String> {
    let form = "expected a name (\"rpm\") or { name = \"voltage\", units = \"V\" } (or states = [..], flag = true)";
    let (name, units, rstates, flag) = match v {
        toml::Value::String(n) => (n, None, None, false),
        toml::Value::Table(mut t) => {
            let Some(toml::Value::String(name)) = t.remove("name") else {
                return Err(format!("{device}: readings: {form}"));
            };
            let units = match t.remove("units") {
                None => None,
                Some(toml::Value::String(u)) => Some(u),
                Some(_) => return Err(format!("{device}: reading {name}: units: expected text")),
            };
            let rstates = match t.remove("states") {
                None => None,
                Some(toml::Value::Array(a)) => Some(
                    a.into_iter()
                        .map(|s| match s {
                            toml::Value::String(s) => Ok(s),
                            _ => Err(format!("{device}: reading {name}: states: expected names")),
                        })
                        .collect::<Result<Vec<_>, _>>()?,
                ),
                Some(_) => {
                    return Err(format!(
                        "{device}: reading {name}: states: expected a list of names"
                    ))
                }
            };
            let flag = match t.remove("flag") {
                None => false,
                Some(toml::Value::Boolean(b)) => b,
                Some(_) => {
                    return Err(format!(
                        "{device}: reading {name}: flag: expected true or false"
                    ))
                }
            };
            if let Some(k) = t.keys().next() {
                return Err(format!(
                    "{device}: reading {name}: unknown key {k:?}; expected name, units, states, flag"
                ));
            }
            (name, units, rstates, flag)
        }
        _ => return Err(format!("{device}: readings: {form}")),
    };
    check_name("reading", &name).map_err(|m| format!("{device}: {m}"))?;
    let known = well_known(&name);
    let kind_of = if let Some(s) = rstates {
        check_states(&format!("{device}.{name}"), &s)?;
        ReadingKind::States(s)
    } else if flag || known.is_some_and(|k| k.flag) {
        ReadingKind::Flag
    } else if name == STATE {
        if kind != Kind::State {
            return Err(format!(
                "{device}: reading state: give its states (state = {{ name = \"state\", states = [..] }})"
            ));
        }
        ReadingKind::States(states.to_vec())
    } else if name == "estop" {
        ReadingKind::States(
            crate::value::EstopState::ALL
                .iter()
                .map(|s| s.as_str().to_string())
                .collect(),
        )
    } else {
        ReadingKind::Number
    };
    let units = match (units, known) {
        (Some(u), _) => u,
        (None, Some(k)) => k.units.to_string(),
        (None, None) if matches!(kind_of, ReadingKind::Number) => {
            return Err(format!(
                "{device}: reading {name} is not a well-known one: give its units, e.g. {{ name = \"{name}\", units = \"V\" }}"
            ))
        }
        (None, None) => String::new(),
    };
    check_text(&format!("reading {name}: units"), &units, true)
        .map_err(|m| format!("{device}: {m}"))?;
    Ok(ReadingSpec {
        name,
        units,
        kind: kind_of,
    })
}

/// A device's own `safe` value: a number in its range, or one of its states.
fn safe_value(d: &DeviceConfig, v: &toml::Value) -> Result<Command, String> {
    let name = &d.name;
    match (d.kind, v) {
        (Kind::Setpoint, toml::Value::Float(_) | toml::Value::Integer(_)) => {
            let x = v
                .as_float()
                .or(v.as_integer().map(|i| i as f64))
                .unwrap_or(f64::NAN);
            d.parse_command(&x.to_string())
                .map_err(|e| format!("safe: {e}"))
        }
        (Kind::State, toml::Value::String(s)) => {
            d.parse_command(s).map_err(|e| format!("safe: {e}"))
        }
        (Kind::Sensor, _) => Err(format!("{name}: safe is for actuators")),
        _ => Err(format!("{name}: safe: expected {}", d.domain())),
    }
}
