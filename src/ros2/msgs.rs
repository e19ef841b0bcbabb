//! The ROS 2 messages adrive speaks, defined in Rust with serde from their official
//! definitions (Autoware's `autoware_vehicle_msgs` and `tier4_vehicle_msgs`, ROS's
//! `std_msgs`, `builtin_interfaces` and `diagnostic_msgs`), with their RIHS01 type
//! hashes. On the wire each is CDR, little-endian, after the 4-byte encapsulation header
//! (`00 01 00 00`), encoded by the `cdr` crate. `tests/ros2_interfaces.rs` checks every
//! hash and the bytes of every type against what `rosbags` computes from the official
//! definitions.

use super::keys::TypeInfo;
use serde::de::DeserializeOwned;
use serde::{Deserialize, Serialize};

/// A message type: its fields (serde) and its name and hash.
pub trait Message: Serialize + DeserializeOwned {
    const TYPE: TypeInfo;
}

/// CDR, little-endian, with the encapsulation header.
pub fn encode<M: Message>(m: &M) -> Vec<u8> {
    cdr::serialize::<_, _, cdr::CdrLe>(m, cdr::Infinite).expect("a message always encodes")
}

/// A message from CDR (either byte order, as its header says).
pub fn decode<M: Message>(bytes: &[u8]) -> Result<M, String> {
    cdr::deserialize::<M>(bytes).map_err(|e| format!("{}: {e}", M::TYPE.name))
}

macro_rules! message {
    ($ty:ident, $name:literal, $hash:literal) => {
        impl Message for $ty {
            const TYPE: TypeInfo = TypeInfo {
                name: $name,
                hash: $hash,
            };
        }
    };
}

/// `builtin_interfaces/msg/Time`.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct Time {
    pub sec: i32,
    pub nanosec: u32,
}

impl Time {
    /// From nanoseconds since the Unix epoch.
    pub(crate) fn from_ns(ns: i64) -> Time {
        Time {
            sec: ns.div_euclid(1_000_000_000) as i32,
            nanosec: ns.rem_euclid(1_000_000_000) as u32,
        }
    }

    pub fn now() -> Time {
        Time::from_ns(super::keys::now_ns())
    }

    pub(crate) fn is_zero(&self) -> bool {
        self.sec == 0 && self.nanosec == 0
    }
}

/// `std_msgs/msg/Header`.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Header {
    pub stamp: Time,
    pub frame_id: String,
}

/// `autoware_vehicle_msgs/msg/SteeringReport`: the tire angle, radians, left positive.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct SteeringReport {
    pub stamp: Time,
    pub steering_tire_angle: f32,
}
message!(
    SteeringReport,
    "autoware_vehicle_msgs/msg/SteeringReport",
    "RIHS01_aa3acc9ca95ebc4daf9dec0ecf87911ad9c196392857c3026bfead589db65a94"
);

/// `autoware_vehicle_msgs/msg/VelocityReport`: m/s (backward negative), rad/s.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct VelocityReport {
    pub header: Header,
    pub longitudinal_velocity: f32,
    pub lateral_velocity: f32,
    pub heading_rate: f32,
}
message!(
    VelocityReport,
    "autoware_vehicle_msgs/msg/VelocityReport",
    "RIHS01_9052adda949c32f4a98500abc1fb5bd23f2560e321eebdfbb25318d6108d4ce4"
);

/// Gear codes of `GearCommand` and `GearReport`.
pub mod gear {
    pub const NONE: u8 = 0;
    pub(crate) const NEUTRAL: u8 = 1;
    pub const DRIVE: u8 = 2;
    /// `DRIVE_18`, the last forward gear.
    pub(crate) const DRIVE_18: u8 = 19;
    pub const REVERSE: u8 = 20;
    pub(crate) const REVERSE_2: u8 = 21;
    pub(crate) const PARK: u8 = 22;
    pub(crate) const LOW: u8 = 23;
    pub(crate) const LOW_2: u8 = 24;
}

/// `autoware_vehicle_msgs/msg/GearCommand`.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct GearCommand {
    pub stamp: Time,
    pub command: u8,
}
message!(
    GearCommand,
    "autoware_vehicle_msgs/msg/GearCommand",
    "RIHS01_4aa982c6505fafa9bdca2d243d0a71e46ff9a1e7013767f13a533d0a5d30a1a6"
);

/// `autoware_vehicle_msgs/msg/GearReport`.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct GearReport {
    pub stamp: Time,
    pub report: u8,
}
message!(
    GearReport,
    "autoware_vehicle_msgs/msg/GearReport",
    "RIHS01_4d14bc3f186c1a6af6a732bb5ebd540cdd742a56770012f4c3cb9e762de8f391"
);

/// Modes of `ControlModeReport` and `ControlModeCommand`.
pub mod mode {
    pub(crate) const NO_COMMAND: u8 = 0;
    pub const AUTONOMOUS: u8 = 1;
    pub(crate) const MANUAL: u8 = 4;
    pub(crate) const NOT_READY: u8 = 6;
}

/// `autoware_vehicle_msgs/msg/ControlModeReport`.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct ControlModeReport {
    pub stamp: Time,
    pub mode: u8,
}
message!(
    ControlModeReport,
    "autoware_vehicle_msgs/msg/ControlModeReport",
    "RIHS01_968feaa6441be3c3b161f2eb65972a4b15394d0a7ddc4664318551280d1ff222"
);

/// Codes of the turn indicator and hazard light commands and reports.
pub mod lights {
    pub(crate) const NO_COMMAND: u8 = 0;
    pub const DISABLE: u8 = 1;
    /// Turn indicators: left; hazard lights: on (`ENABLE`).
    pub const ENABLE_LEFT: u8 = 2;
    pub const ENABLE_RIGHT: u8 = 3;
}

/// `autoware_vehicle_msgs/msg/TurnIndicatorsCommand`.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct TurnIndicatorsCommand {
    pub stamp: Time,
    pub command: u8,
}
message!(
    TurnIndicatorsCommand,
    "autoware_vehicle_msgs/msg/TurnIndicatorsCommand",
    "RIHS01_657d7f761a9b02c543e4bf3e0000405906b6169dc0bbfd6637c64fe00d98cec7"
);

/// `autoware_vehicle_msgs/msg/TurnIndicatorsReport`.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct TurnIndicatorsReport {
    pub stamp: Time,
    pub report: u8,
}
message!(
    TurnIndicatorsReport,
    "autoware_vehicle_msgs/msg/TurnIndicatorsReport",
    "RIHS01_c05a54cd244f1c9d683613b11c87a5b3ef816eed7a5f207368301221731a0964"
);

/// `autoware_vehicle_msgs/msg/HazardLightsCommand`.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct HazardLightsCommand {
    pub stamp: Time,
    pub command: u8,
}
message!(
    HazardLightsCommand,
    "autoware_vehicle_msgs/msg/HazardLightsCommand",
    "RIHS01_ad2386a78a210625f1fb35f8043ef4e78da58cf01f33c340fa9468e5e8cdd0bc"
);

/// `autoware_vehicle_msgs/msg/HazardLightsReport`.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct HazardLightsReport {
    pub stamp: Time,
    pub report: u8,
}
message!(
    HazardLightsReport,
    "autoware_vehicle_msgs/msg/HazardLightsReport",
    "RIHS01_01ce3b4293a5c2799fd7483b2d62a790e26fe8f2b5d60e48149163475685f28a"
);

/// `tier4_vehicle_msgs/msg/ActuationCommand`: raw pedal and steering values.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct ActuationCommand {
    pub accel_cmd: f64,
    pub brake_cmd: f64,
    pub steer_cmd: f64,
}
message!(
    ActuationCommand,
    "tier4_vehicle_msgs/msg/ActuationCommand",
    "RIHS01_9387a604220068362f43b8d172c5b8193dbb8b684003ac21998a2af2e8a6716b"
);

/// `tier4_vehicle_msgs/msg/ActuationCommandStamped`.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct ActuationCommandStamped {
    pub header: Header,
    pub actuation: ActuationCommand,
}
message!(
    ActuationCommandStamped,
    "tier4_vehicle_msgs/msg/ActuationCommandStamped",
    "RIHS01_7e8733fe7fe1ab38ea59515131eed65fde89209e397d3ef523c5ef423a9bf880"
);

/// `tier4_vehicle_msgs/msg/ActuationStatus`.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct ActuationStatus {
    pub accel_status: f64,
    pub brake_status: f64,
    pub steer_status: f64,
}
message!(
    ActuationStatus,
    "tier4_vehicle_msgs/msg/ActuationStatus",
    "RIHS01_45b7cbc43a7fb4420a6c48a8a8a66ee1fbf81effc6a0f6202043bcfc69505b71"
);

/// `tier4_vehicle_msgs/msg/ActuationStatusStamped`.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct ActuationStatusStamped {
    pub header: Header,
    pub status: ActuationStatus,
}
message!(
    ActuationStatusStamped,
    "tier4_vehicle_msgs/msg/ActuationStatusStamped",
    "RIHS01_5d8915c8cb84d6df9377f3225a44f84cffb9ad1f4eec4cf6650cf5e417a47e54"
);

/// `tier4_vehicle_msgs/msg/VehicleEmergencyStamped`.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct VehicleEmergencyStamped {
    pub stamp: Time,
    pub emergency: bool,
}
message!(
    VehicleEmergencyStamped,
    "tier4_vehicle_msgs/msg/VehicleEmergencyStamped",
    "RIHS01_017801df5493a599ad735d55f3e93ea132c46f8f630bce94a5f3eb2dc4a4bb3c"
);

/// `diagnostic_msgs/msg/KeyValue`.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct KeyValue {
    pub key: String,
    pub value: String,
}

/// Levels of a `DiagnosticStatus`.
pub mod level {
    pub const OK: u8 = 0;
    pub const WARN: u8 = 1;
    pub const ERROR: u8 = 2;
    pub(crate) const STALE: u8 = 3;
}

/// `diagnostic_msgs/msg/DiagnosticStatus`.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct DiagnosticStatus {
    pub level: u8,
    pub name: String,
    pub message: String,
    pub hardware_id: String,
    pub values: Vec<KeyValue>,
}

/// `diagnostic_msgs/msg/DiagnosticArray`.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct DiagnosticArray {
    pub header: Header,
    pub status: Vec<DiagnosticStatus>,
}
message!(
    DiagnosticArray,
    "diagnostic_msgs/msg/DiagnosticArray",
    "RIHS01_5a8a36efb05fb25070fa0fb3810290c0e6cd4862b54a8fb975a1ee8dc55a333e"
);

/// The service `autoware_vehicle_msgs/srv/ControlModeCommand` (its request and
/// response share the service's name and hash on the wire).
pub const CONTROL_MODE_COMMAND: TypeInfo = TypeInfo {
    name: "autoware_vehicle_msgs/srv/ControlModeCommand",
    hash: "RIHS01_1a4e4365e7f8f2bf8126953995042a6a9c40a5ba1e17988e95b0da1f2ddf79af",
};

/// `autoware_vehicle_msgs/srv/ControlModeCommand` request.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct ControlModeRequest {
    pub stamp: Time,
    pub mode: u8,
}
impl Message for ControlModeRequest {
    const TYPE: TypeInfo = CONTROL_MODE_COMMAND;
}

/// `autoware_vehicle_msgs/srv/ControlModeCommand` response.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct ControlModeResponse {
    pub success: bool,
}
impl Message for ControlModeResponse {
    const TYPE: TypeInfo = CONTROL_MODE_COMMAND;
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_steering_report_encodes_as_rosbags_does() {
        // rosbags 0.11.9, serialize_cdr of SteeringReport(stamp=(1, 2), 0.25).
        let m = SteeringReport {
            stamp: Time { sec: 1, nanosec: 2 },
            steering_tire_angle: 0.25,
        };
        let bytes = encode(&m);
        assert_eq!(
            bytes,
            [0, 1, 0, 0, 1, 0, 0, 0, 2, 0, 0, 0, 0, 0, 0x80, 0x3e]
        );
        assert_eq!(decode::<SteeringReport>(&bytes), Ok(m));
    }

    #[test]
    fn time_from_nanoseconds() {
        assert_eq!(
            Time::from_ns(1_500_000_000),
            Time {
                sec: 1,
                nanosec: 500_000_000
            }
        );
    }
}
