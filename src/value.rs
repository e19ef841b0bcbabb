//! The values adrive speaks in: gears, e-stop states, actuator commands and the
//! readings a device reports. Every part (drivers, engine, network, console, simulator)
//! shares these types, so a value means the same thing everywhere.

use serde::{Deserialize, Serialize};
use std::fmt;
use std::str::FromStr;

/// The role a device plays in the vehicle; a device's name in the config is its role.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Role {
    Steer,
    Gas,
    Brake,
    Trans,
    Estop,
    Obd,
}

impl Role {
    pub const ALL: [Role; 6] = [
        Role::Steer,
        Role::Gas,
        Role::Brake,
        Role::Trans,
        Role::Estop,
        Role::Obd,
    ];

    pub fn as_str(self) -> &'static str {
        match self {
            Role::Steer => "steer",
            Role::Gas => "gas",
            Role::Brake => "brake",
            Role::Trans => "trans",
            Role::Estop => "estop",
            Role::Obd => "obd",
        }
    }

    /// Actuators take commands; sensors only report.
    pub fn is_actuator(self) -> bool {
        !matches!(self, Role::Estop | Role::Obd)
    }
}

impl fmt::Display for Role {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.as_str())
    }
}

impl FromStr for Role {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        Role::ALL
            .into_iter()
            .find(|r| r.as_str() == s)
            .ok_or_else(|| {
                format!("unknown device {s:?}: expected steer, gas, brake, trans, estop or obd")
            })
    }
}

/// Transmission position. The paper's numeric codes are accepted too:
/// −1 reverse, 0 park, 1 drive.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Gear {
    Park,
    Reverse,
    Neutral,
    Drive,
}

impl Gear {
    pub const ALL: [Gear; 4] = [Gear::Park, Gear::Reverse, Gear::Neutral, Gear::Drive];

    pub fn as_str(self) -> &'static str {
        match self {
            Gear::Park => "park",
            Gear::Reverse => "reverse",
            Gear::Neutral => "neutral",
            Gear::Drive => "drive",
        }
    }

    /// A gear in which the engine drives the wheels.
    pub fn is_driving(self) -> bool {
        matches!(self, Gear::Drive | Gear::Reverse)
    }

    /// Register code used on the wire by the Modbus transmission (0 park, 1 reverse,
    /// 2 neutral, 3 drive: the PRND order of a shifter).
    pub fn code(self) -> u16 {
        match self {
            Gear::Park => 0,
            Gear::Reverse => 1,
            Gear::Neutral => 2,
            Gear::Drive => 3,
        }
    }

    pub fn from_code(code: u16) -> Option<Gear> {
        Gear::ALL.get(code as usize).copied()
    }
}

impl fmt::Display for Gear {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.as_str())
    }
}

impl FromStr for Gear {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match s.trim().to_ascii_lowercase().as_str() {
            "park" | "p" | "0" => Ok(Gear::Park),
            "reverse" | "rev" | "r" | "-1" => Ok(Gear::Reverse),
            "neutral" | "n" => Ok(Gear::Neutral),
            "drive" | "d" | "1" => Ok(Gear::Drive),
            other => Err(format!(
                "unknown gear {other:?}: expected park, reverse, neutral, drive (or -1, 0, 1)"
            )),
        }
    }
}

/// The DARPA e-stop states: `disable` ends the run, `pause` must bring the vehicle
/// to a stop and hold it, `run` lets it drive.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum EstopState {
    Disable,
    Pause,
    Run,
}

impl EstopState {
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
    /// Run the starter motor until the engine catches (transmission controller).
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

    pub fn from_code(code: u16) -> Option<Control> {
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
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
#[serde(untagged)]
pub enum Command {
    /// A set point in the device's value domain (steer −1…1, gas and brake 0…1).
    Set(f64),
    /// A transmission position.
    Gear(Gear),
    /// Drive control (enable, home, starter…).
    Control(Control),
}

impl Command {
    /// The command as a number, for plots and JSON: gears by the paper's code.
    pub fn as_f64(self) -> f64 {
        match self {
            Command::Set(v) => v,
            Command::Gear(Gear::Reverse) => -1.0,
            Command::Gear(Gear::Park) => 0.0,
            Command::Gear(Gear::Drive) => 1.0,
            Command::Gear(Gear::Neutral) => 2.0,
            Command::Control(_) => f64::NAN,
        }
    }

    /// The set point, for a `Set` command.
    pub fn set_point(self) -> Option<f64> {
        match self {
            Command::Set(v) => Some(v),
            _ => None,
        }
    }
}

impl fmt::Display for Command {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Command::Set(v) => write!(f, "{v:.3}"),
            Command::Gear(g) => write!(f, "{g}"),
            Command::Control(c) => f.write_str(c.as_str()),
        }
    }
}

/// What a device last reported. Each device fills the fields it knows; the rest stay
/// `None`. Units: positions in the device's domain, speed in m/s, temperature in °C.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
pub struct Reading {
    #[serde(skip_serializing_if = "Option::is_none")]
    pub position: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub velocity: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub pressure: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub gear: Option<Gear>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub estop: Option<EstopState>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub rpm: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub speed: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub coolant: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub running: Option<bool>,
    /// Device-reported fault bits; 0 is good.
    pub fault: u16,
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn gears_parse_names_and_paper_codes() {
        assert_eq!("drive".parse::<Gear>(), Ok(Gear::Drive));
        assert_eq!("-1".parse::<Gear>(), Ok(Gear::Reverse));
        assert_eq!("0".parse::<Gear>(), Ok(Gear::Park));
        assert_eq!("N".parse::<Gear>(), Ok(Gear::Neutral));
        assert!("sport".parse::<Gear>().is_err());
        for g in Gear::ALL {
            assert_eq!(g.to_string().parse::<Gear>(), Ok(g));
            assert_eq!(Gear::from_code(g.code()), Some(g));
        }
    }

    #[test]
    fn estop_states_round_trip() {
        for s in [EstopState::Disable, EstopState::Pause, EstopState::Run] {
            assert_eq!(s.to_string().parse::<EstopState>(), Ok(s));
        }
    }
}
