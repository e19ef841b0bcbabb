//! The values adrive speaks in: device identities and kinds, commands, readings, and
//! the e-stop's states. Every part (drivers, engine, network, console, simulator)
//! shares these types, so a value means the same thing everywhere. What a number or a
//! state index *names* — a device's states, its readings and their units — is in the
//! device's configuration ([`crate::config::DeviceConfig`]).

use schemars::JsonSchema;
use serde::{Deserialize, Serialize};
use std::fmt;
use std::net::SocketAddr;
use std::str::FromStr;

/// `x`, or 0 where it is subnormal. A filter, an integrator or a decay that settles
/// toward 0 (a lag closing on its command, a Kalman state whose innovations vanish)
/// walks down through the subnormal numbers, which are slow to compute with and mean
/// nothing to a reader (`1.5e-323` in a snapshot); each such state is flushed with this
/// after every step.
pub(crate) fn flush_subnormal(x: f64) -> f64 {
    if x.is_subnormal() {
        0.0
    } else {
        x
    }
}

/// Where a command comes from: every command of every front end enters the one intake
/// ([`crate::engine::admit`]) tagged with its source, and the vehicle is commanded by
/// at most one of them at a time.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Source {
    /// The console of this process.
    Console,
    /// A console attached over the control socket (`adrive attach`), numbered by its
    /// connection (1, 2, …) for the life of the process.
    Attached(u32),
    /// An operator's one-shot command over the control socket (`adrive ctl`), by the
    /// user id the socket vouches for: the same person's `engage` and `release` are one
    /// source.
    Operator(u32),
    /// An operator's one-shot command over the fleet (`adrive ctl --vehicle`), by the
    /// vehicle's key its link proved: every holder of the key is one source, as one
    /// user is on the socket.
    Fleet,
    /// A network sender, by address.
    Network(SocketAddr),
    /// The ROS 2 node (one actuation publisher at a time within it).
    Ros2,
    /// The supervisor's recovery procedures (past ownership: they act on a vehicle in
    /// trouble, and only on the devices they take over).
    Supervisor,
    /// A bench procedure measuring one actuator (`adrive characterize`).
    Bench,
}

impl Source {
    /// A console, which may take command from any other source (with the operator's
    /// confirmation); the network and ROS 2 never take it from a console.
    pub(crate) fn is_console(self) -> bool {
        matches!(self, Source::Console | Source::Attached(_))
    }
}

impl fmt::Display for Source {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Source::Console => f.write_str("console"),
            Source::Attached(n) => write!(f, "console #{n}"),
            Source::Operator(uid) => write!(f, "operator uid {uid}"),
            Source::Fleet => f.write_str("fleet operator"),
            Source::Network(a) => write!(f, "{a}"),
            Source::Ros2 => f.write_str("ros2"),
            Source::Supervisor => f.write_str("supervisor"),
            Source::Bench => f.write_str("characterize"),
        }
    }
}

/// A device's place in its vehicle (the vehicle file's order, from 0). Cheap to copy
/// and to compare; names are for people and the wire.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
pub struct DeviceId(pub u16);

impl DeviceId {
    pub fn index(self) -> usize {
        self.0 as usize
    }
}

/// The keywords of the command protocol (docs/network.md): the one list that the
/// protocol's parser, `adrive send`'s splitting of words into lines, their messages and
/// the names a device may not take are all read from. Every other first word of a line
/// names a device.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Keyword {
    Accel,
    Engage,
    Disengage,
    Release,
    Clear,
    Seq,
    Tag,
}

impl Keyword {
    /// Every keyword, in the order messages list them.
    pub const ALL: [Keyword; 7] = [
        Keyword::Accel,
        Keyword::Engage,
        Keyword::Disengage,
        Keyword::Release,
        Keyword::Clear,
        Keyword::Seq,
        Keyword::Tag,
    ];

    /// Its word on the wire.
    pub fn word(self) -> &'static str {
        match self {
            Keyword::Accel => "accel",
            Keyword::Engage => "engage",
            Keyword::Disengage => "disengage",
            Keyword::Release => "release",
            Keyword::Clear => "clear",
            Keyword::Seq => "seq",
            Keyword::Tag => "tag",
        }
    }

    /// The keyword `word` is (case-insensitive).
    pub fn from_word(word: &str) -> Option<Keyword> {
        Keyword::ALL
            .into_iter()
            .find(|k| k.word().eq_ignore_ascii_case(word))
    }

    /// It takes a value on its line (`accel 0.3`, `seq 17`); the others stand alone.
    pub fn takes_value(self) -> bool {
        matches!(self, Keyword::Accel | Keyword::Seq | Keyword::Tag)
    }

    /// A header of the datagram rather than a command.
    pub fn is_header(self) -> bool {
        matches!(self, Keyword::Seq | Keyword::Tag)
    }

    /// The words of those for which `which` holds, for a person: `engage, disengage,
    /// release and clear`, with `last` (`and`, `or`) before the last one. Written into
    /// `out` without allocating.
    pub fn list(
        which: impl Fn(Keyword) -> bool,
        last: &str,
        out: &mut impl fmt::Write,
    ) -> fmt::Result {
        let n = Keyword::ALL.iter().filter(|k| which(**k)).count();
        for (i, k) in Keyword::ALL.into_iter().filter(|k| which(*k)).enumerate() {
            if i > 0 {
                out.write_str(if i + 1 == n { last } else { ", " })?;
            }
            out.write_str(k.word())?;
        }
        Ok(())
    }
}

/// What a device is.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize, JsonSchema)]
#[serde(rename_all = "lowercase")]
pub enum Kind {
    /// An actuator that takes a number in a range (steering, throttle, brake, a wiper).
    Setpoint,
    /// An actuator that takes one of its named states (a gearbox, turn signals, a horn).
    State,
    /// A device that only reports (OBD-II, an e-stop, a battery monitor).
    Sensor,
}

impl Kind {
    pub fn as_str(self) -> &'static str {
        match self {
            Kind::Setpoint => "setpoint",
            Kind::State => "state",
            Kind::Sensor => "sensor",
        }
    }

    /// Actuators take commands; sensors only report.
    pub fn is_actuator(self) -> bool {
        self != Kind::Sensor
    }
}

impl fmt::Display for Kind {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.as_str())
    }
}

/// The DARPA e-stop states: `disable` ends the run, `pause` must bring the vehicle
/// to a stop and hold it, `run` lets it drive. A device bound to the `estop` role
/// reports a state reading that has these three among its states.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize, JsonSchema)]
#[serde(rename_all = "lowercase")]
pub enum EstopState {
    Disable,
    Pause,
    Run,
}

impl EstopState {
    pub const ALL: [EstopState; 3] = [EstopState::Disable, EstopState::Pause, EstopState::Run];

    /// Pause or disable: the e-stop holds the vehicle (its rule: brake full, gas 0).
    pub fn halts(self) -> bool {
        self != EstopState::Run
    }

    pub fn as_str(self) -> &'static str {
        match self {
            EstopState::Disable => "disable",
            EstopState::Pause => "pause",
            EstopState::Run => "run",
        }
    }
}

impl fmt::Display for EstopState {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.as_str())
    }
}

impl FromStr for EstopState {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match s.trim().to_ascii_lowercase().as_str() {
            "disable" | "d" | "0" => Ok(EstopState::Disable),
            "pause" | "p" | "1" => Ok(EstopState::Pause),
            "run" | "r" | "2" => Ok(EstopState::Run),
            other => Err(format!(
                "unknown e-stop state {other:?}: expected disable, pause or run"
            )),
        }
    }
}

/// A drive-control command: what a servo drive's control word or a transmission
/// controller's ignition input does. The supervisor's recovery procedures use them.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Control {
    /// Power stage off (a servo drive's fault latch clears on disable → enable).
    Disable,
    /// Power stage on.
    Enable,
    /// Enable and find the reference position again.
    Home,
    /// Run the starter motor until the engine catches.
    Start,
}

impl Control {
    pub const ALL: [Control; 4] = [
        Control::Disable,
        Control::Enable,
        Control::Home,
        Control::Start,
    ];

    pub fn as_str(self) -> &'static str {
        match self {
            Control::Disable => "disable",
            Control::Enable => "enable",
            Control::Home => "home",
            Control::Start => "start",
        }
    }

    /// The value written to a Modbus device's `control` register.
    pub fn code(self) -> u16 {
        match self {
            Control::Disable => 0,
            Control::Enable => 1,
            Control::Home => 3,
            Control::Start => 4,
        }
    }

    pub(crate) fn from_code(code: u16) -> Option<Control> {
        Control::ALL.into_iter().find(|c| c.code() == code)
    }
}

impl fmt::Display for Control {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.as_str())
    }
}

impl FromStr for Control {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        Control::ALL
            .into_iter()
            .find(|c| c.as_str() == s)
            .ok_or_else(|| {
                format!("unknown control {s:?}: expected disable, enable, home or start")
            })
    }
}

/// One command for one actuator. `Copy` and allocation-free: it travels from the
/// socket to the serial write without touching the heap.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Command {
    /// A set point in a setpoint actuator's range.
    Set(f64),
    /// One of a state actuator's states, by its index in the device's `states`.
    State(u8),
    /// Drive control (enable, home, starter…).
    Control(Control),
}

impl Command {
    /// The set point, for a `Set` command.
    pub fn set_point(self) -> Option<f64> {
        match self {
            Command::Set(v) => Some(v),
            _ => None,
        }
    }

    /// The state index, for a `State` command.
    pub fn state(self) -> Option<u8> {
        match self {
            Command::State(s) => Some(s),
            _ => None,
        }
    }

    /// The command as a number, for plots: set points as they are, states by index.
    pub fn as_f64(self) -> f64 {
        match self {
            Command::Set(v) => v,
            Command::State(s) => s as f64,
            Command::Control(_) => f64::NAN,
        }
    }
}

/// The most readings one device reports.
pub(crate) const MAX_READINGS: usize = 16;

/// What a device last reported: one value per reading the device declares, by the
/// reading's index in its configuration (numbers as they are, flags as 0 or 1, states
/// by index), and the device's fault bits. `Copy` and heap-free, so the cache and
/// every reader can hold it cheaply.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Reading {
    values: [Option<f64>; MAX_READINGS],
    /// Device-reported fault bits; 0 is good.
    pub fault: u16,
}

impl Reading {
    /// The value of reading `i` (`None`: not reported).
    pub fn get(&self, i: usize) -> Option<f64> {
        self.values.get(i).copied().flatten()
    }

    /// Set reading `i`; an index past [`MAX_READINGS`] is ignored (configurations
    /// cannot declare one).
    pub fn set(&mut self, i: usize, v: f64) {
        if let Some(slot) = self.values.get_mut(i) {
            *slot = Some(v);
        }
    }

    /// Every reported value, by index.
    pub fn values(&self) -> impl Iterator<Item = (usize, f64)> + '_ {
        self.values
            .iter()
            .enumerate()
            .filter_map(|(i, v)| v.map(|v| (i, v)))
    }
}

/// A value for people and JSON: a number, a flag, or a state's name.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(untagged)]
pub enum Value {
    Flag(bool),
    Number(f64),
    Text(String),
}

impl Value {
    pub fn as_f64(&self) -> Option<f64> {
        match self {
            Value::Number(v) => Some(*v),
            Value::Flag(b) => Some(f64::from(u8::from(*b))),
            Value::Text(_) => None,
        }
    }

    pub fn as_str(&self) -> Option<&str> {
        match self {
            Value::Text(s) => Some(s),
            _ => None,
        }
    }
}

impl fmt::Display for Value {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Value::Flag(b) => write!(f, "{}", if *b { "yes" } else { "no" }),
            Value::Number(v) => write!(f, "{v:.3}"),
            Value::Text(s) => f.write_str(s),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn estop_states_round_trip() {
        for s in EstopState::ALL {
            assert_eq!(s.to_string().parse::<EstopState>(), Ok(s));
        }
    }

    #[test]
    fn a_reading_holds_values_by_index_and_ignores_the_impossible() {
        let mut r = Reading::default();
        r.set(0, 0.5);
        r.set(3, 1.0);
        r.set(MAX_READINGS, 9.0);
        assert_eq!(r.get(0), Some(0.5));
        assert_eq!(r.get(1), None);
        assert_eq!(r.values().collect::<Vec<_>>(), vec![(0, 0.5), (3, 1.0)]);
    }

    #[test]
    fn values_serialize_as_plain_json() {
        let v = vec![
            Value::Number(0.25),
            Value::Flag(true),
            Value::Text("drive".into()),
        ];
        let json = serde_json::to_string(&v).unwrap();
        assert_eq!(json, r#"[0.25,true,"drive"]"#);
        assert_eq!(serde_json::from_str::<Vec<Value>>(&json).unwrap(), v);
    }
}
