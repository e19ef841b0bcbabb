//! What Autoware's messages mean on this vehicle, as pure functions: a command message
//! becomes typed [`Ask`]s for the one intake every source goes through
//! ([`crate::engine::Gate::admit`]: one commander, the watchdog, ranges, the
//! interlocks, the engage gate), and the [`Snapshot`] becomes the reports. Which device is
//! which comes from the vehicle's role bindings (steering, throttle, brake, gear, speed)
//! and from `[ros2]` for turn indicators and hazard lights.

use super::msgs::{self, gear, lights, mode, Time};
use crate::config::{Role, Ros2Config, VehicleConfig};
use crate::safety::Ask;
use crate::snapshot::{DeviceView, Snapshot};
use crate::value::{Command, DeviceId};
use std::fmt;

/// The asks one actuation message becomes: steering, then the pedals.
pub(crate) type Asks = arrayvec::ArrayVec<Ask, 3>;

/// A state device commanded by Autoware codes: its id and the states by code.
#[derive(Clone, Debug, PartialEq)]
struct States {
    device: DeviceId,
    /// (code, state index) pairs.
    by_code: Vec<(u8, Option<u8>)>,
}

/// The gear device's states in Autoware's terms.
#[derive(Clone, Debug, PartialEq)]
struct GearMap {
    device: String,
    forward: Option<String>,
    reverse: Option<String>,
    park: Option<String>,
    neutral: Option<String>,
    /// Every forward and reverse state.
    forwards: Vec<String>,
    reverses: Vec<String>,
}

/// The vehicle as the bridge sees it: device names by what Autoware commands.
#[derive(Clone, Debug, PartialEq)]
pub(crate) struct VehicleMap {
    steering: Option<String>,
    /// Throttle and brake, with the top of their ranges.
    throttle: Option<(String, f64)>,
    brake: Option<(String, f64)>,
    accel: bool,
    gear: Option<GearMap>,
    /// The device and reading of the speed (m/s).
    speed: Option<(String, String)>,
    turn_indicators: Option<String>,
    hazard_lights: Option<String>,
    tire_angle_per_unit: f64,
    /// The devices commands go to, by id.
    steering_id: Option<DeviceId>,
    throttle_id: Option<DeviceId>,
    brake_id: Option<DeviceId>,
    gear_states: Option<States>,
    turn_states: Option<States>,
    hazard_states: Option<States>,
}

/// A command message that does not apply to this vehicle, and why.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Unmapped {
    /// The vehicle has no device for it (no gear, no turn indicators…).
    NoDevice(&'static str),
    /// A code the message type does not define, or one that asks for nothing.
    Code(&'static str, u8),
}

impl fmt::Display for Unmapped {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Unmapped::NoDevice(what) => write!(f, "this vehicle has no {what}"),
            Unmapped::Code(what, c) => write!(f, "{what} {c} is not a command adrive takes"),
        }
    }
}

impl VehicleMap {
    pub(crate) fn new(config: &VehicleConfig, ros2: &Ros2Config) -> VehicleMap {
        let name = |role| config.bound(role).map(|d| d.name.clone());
        let top = |role| config.bound(role).map(|d| (d.name.clone(), d.range[1]));
        let gear = config.roles.gear.as_ref().map(|g| {
            let d = &config.devices[g.device.index()];
            let names = |ids: &[u8]| -> Vec<String> {
                ids.iter()
                    .filter_map(|&i| d.state_name(i).map(str::to_string))
                    .collect()
            };
            let forwards = names(&g.forward);
            let reverses = names(&g.reverse);
            GearMap {
                device: d.name.clone(),
                forward: forwards.first().cloned(),
                reverse: reverses.first().cloned(),
                park: g.park.and_then(|p| d.state_name(p)).map(str::to_string),
                neutral: d
                    .state_index("neutral")
                    .and_then(|i| d.state_name(i))
                    .map(str::to_string),
                forwards,
                reverses,
            }
        });
        let speed = config.roles.speed.map(|r| {
            let d = &config.devices[r.device.index()];
            (d.name.clone(), d.readings[r.reading].name.clone())
        });
        let id = |role| config.roles.device(role);
        let find = |name: &str| {
            config
                .devices
                .iter()
                .position(|d| d.name == name)
                .map(|i| DeviceId(i as u16))
        };
        let states = |device: Option<&String>, codes: &[(u8, &str)]| {
            let device = find(device?)?;
            let d = &config.devices[device.index()];
            Some(States {
                device,
                by_code: codes
                    .iter()
                    .map(|(c, name)| (*c, d.state_index(name)))
                    .collect(),
            })
        };
        let gear_states = config.roles.gear.as_ref().map(|g| {
            let d = &config.devices[g.device.index()];
            States {
                device: g.device,
                by_code: vec![
                    (gear::NEUTRAL, d.state_index("neutral")),
                    (gear::DRIVE, g.forward.first().copied()),
                    (gear::REVERSE, g.reverse.first().copied()),
                    (gear::PARK, g.park),
                ],
            }
        });
        VehicleMap {
            steering_id: id(Role::Steering),
            throttle_id: id(Role::Throttle),
            brake_id: id(Role::Brake),
            gear_states,
            turn_states: states(
                ros2.turn_indicators.as_ref(),
                &[
                    (lights::DISABLE, "off"),
                    (lights::ENABLE_LEFT, "left"),
                    (lights::ENABLE_RIGHT, "right"),
                ],
            ),
            hazard_states: states(
                ros2.hazard_lights.as_ref(),
                &[(lights::DISABLE, "off"), (lights::ENABLE_LEFT, "on")],
            ),
            steering: name(Role::Steering),
            throttle: top(Role::Throttle),
            brake: top(Role::Brake),
            accel: config.roles.has_accel(),
            gear,
            speed,
            turn_indicators: ros2.turn_indicators.clone(),
            hazard_lights: ros2.hazard_lights.clone(),
            tire_angle_per_unit: ros2.tire_angle_per_unit,
        }
    }

    pub(crate) fn has_turn_indicators(&self) -> bool {
        self.turn_indicators.is_some()
    }

    pub(crate) fn has_hazard_lights(&self) -> bool {
        self.hazard_lights.is_some()
    }

    /// Raw actuation as asks: `steer` to the steering device, and the pedals as one
    /// `accel` (braking wins: a brake command above 0 brakes, whatever the accelerator
    /// says), each as a fraction of its device's range; without `accel`, the pedal
    /// released first, then the other.
    pub(crate) fn actuation(&self, a: &msgs::ActuationCommand) -> Asks {
        let mut out = Asks::new();
        if let Some(s) = self.steering_id {
            out.push(Ask::Set(s, Command::Set(a.steer_cmd)));
        }
        let (Some((_, t_top)), Some((_, b_top)), Some(t), Some(b)) =
            (&self.throttle, &self.brake, self.throttle_id, self.brake_id)
        else {
            return out;
        };
        let braking = a.brake_cmd > 0.0 || a.brake_cmd.is_nan();
        if self.accel {
            out.push(Ask::Accel(if braking {
                -a.brake_cmd / b_top
            } else {
                a.accel_cmd / t_top
            }));
        } else if braking {
            out.push(Ask::Set(t, Command::Set(0.0)));
            out.push(Ask::Set(b, Command::Set(a.brake_cmd)));
        } else {
            out.push(Ask::Set(b, Command::Set(0.0)));
            out.push(Ask::Set(t, Command::Set(a.accel_cmd)));
        }
        out
    }

    /// A gear command as an ask; `None` for `NONE`.
    pub(crate) fn gear(&self, code: u8) -> Result<Option<Ask>, Unmapped> {
        if code == gear::NONE {
            return Ok(None);
        }
        let key = match code {
            gear::NEUTRAL => gear::NEUTRAL,
            gear::DRIVE..=gear::DRIVE_18 | gear::LOW | gear::LOW_2 => gear::DRIVE,
            gear::REVERSE | gear::REVERSE_2 => gear::REVERSE,
            gear::PARK => gear::PARK,
            _ => return Err(Unmapped::Code("gear", code)),
        };
        state_ask(self.gear_states.as_ref(), "gear", key, code)
    }

    /// A turn indicators command as an ask; `None` for `NO_COMMAND`.
    pub(crate) fn turn_indicators(&self, code: u8) -> Result<Option<Ask>, Unmapped> {
        if code == lights::NO_COMMAND {
            return Ok(None);
        }
        state_ask(self.turn_states.as_ref(), "turn indicators", code, code)
    }

    /// A hazard lights command as an ask; `None` for `NO_COMMAND`.
    pub(crate) fn hazard_lights(&self, code: u8) -> Result<Option<Ask>, Unmapped> {
        if code == lights::NO_COMMAND {
            return Ok(None);
        }
        state_ask(self.hazard_states.as_ref(), "hazard lights", code, code)
    }

    /// The reports of one snapshot, stamped `stamp`. A report whose device has not
    /// reported yet is left out.
    pub(crate) fn reports(&self, snap: &Snapshot, stamp: Time) -> Reports {
        let position = |name: &Option<String>| {
            name.as_ref()
                .and_then(|n| snap.device(n))
                .and_then(DeviceView::position)
        };
        let pedal = |d: &Option<(String, f64)>| {
            d.as_ref()
                .and_then(|(n, _)| snap.device(n))
                .and_then(DeviceView::position)
        };
        let gear_state = self.gear.as_ref().and_then(|g| {
            let d = snap.device(&g.device)?;
            d.readings
                .iter()
                .find_map(|(_, v)| v.as_ref()?.as_str().map(str::to_string))
        });
        let gear_code = self.gear.as_ref().zip(gear_state.as_ref()).map(|(g, s)| {
            if g.forwards.contains(s) {
                gear::DRIVE
            } else if g.reverses.contains(s) {
                gear::REVERSE
            } else if g.park.as_ref() == Some(s) {
                gear::PARK
            } else if g.neutral.as_ref() == Some(s) {
                gear::NEUTRAL
            } else {
                gear::NONE
            }
        });
        let speed = self
            .speed
            .as_ref()
            .and_then(|(d, r)| snap.device(d)?.number(r));
        let steer = position(&self.steering);
        let mode = if snap.gate.engaged {
            mode::AUTONOMOUS
        } else if !snap.gate.blocked_by.is_empty() {
            mode::NOT_READY
        } else {
            mode::MANUAL
        };
        let state_code = |d: &Option<String>, codes: &[(&str, u8)]| {
            let d = snap.device(d.as_ref()?)?;
            let s = d
                .readings
                .iter()
                .find_map(|(_, v)| v.as_ref()?.as_str().map(str::to_string))?;
            codes.iter().find(|(n, _)| *n == s).map(|&(_, c)| c)
        };
        let header = msgs::Header {
            stamp,
            frame_id: "base_link".into(),
        };
        Reports {
            steering: steer.map(|p| msgs::SteeringReport {
                stamp,
                steering_tire_angle: (p * self.tire_angle_per_unit) as f32,
            }),
            velocity: speed.map(|v| {
                let backward = gear_code == Some(gear::REVERSE);
                msgs::VelocityReport {
                    header: header.clone(),
                    longitudinal_velocity: if backward { -v } else { v } as f32,
                    lateral_velocity: 0.0,
                    heading_rate: 0.0,
                }
            }),
            gear: gear_code.map(|report| msgs::GearReport { stamp, report }),
            control_mode: msgs::ControlModeReport { stamp, mode },
            actuation: msgs::ActuationStatusStamped {
                header,
                status: msgs::ActuationStatus {
                    accel_status: pedal(&self.throttle).unwrap_or(0.0),
                    brake_status: pedal(&self.brake).unwrap_or(0.0),
                    steer_status: steer.unwrap_or(0.0),
                },
            },
            turn_indicators: state_code(
                &self.turn_indicators,
                &[
                    ("off", lights::DISABLE),
                    ("left", lights::ENABLE_LEFT),
                    ("right", lights::ENABLE_RIGHT),
                ],
            )
            .map(|report| msgs::TurnIndicatorsReport { stamp, report }),
            hazard_lights: state_code(
                &self.hazard_lights,
                &[("off", lights::DISABLE), ("on", lights::ENABLE_LEFT)],
            )
            .map(|report| msgs::HazardLightsReport { stamp, report }),
        }
    }
}

/// The reports of one instant.
#[derive(Clone, Debug, PartialEq)]
pub(crate) struct Reports {
    pub steering: Option<msgs::SteeringReport>,
    pub velocity: Option<msgs::VelocityReport>,
    pub gear: Option<msgs::GearReport>,
    pub(crate) control_mode: msgs::ControlModeReport,
    pub actuation: msgs::ActuationStatusStamped,
    pub(crate) turn_indicators: Option<msgs::TurnIndicatorsReport>,
    pub(crate) hazard_lights: Option<msgs::HazardLightsReport>,
}

/// The vehicle's health as `diagnostic_msgs`: the gate, then one status per device
/// (ERROR when faulty, STALE when its reading is old, else OK), its readings as values.
pub(crate) fn diagnostics(snap: &Snapshot, stamp: Time) -> msgs::DiagnosticArray {
    use msgs::{level, DiagnosticStatus, KeyValue};
    let kv = |k: &str, v: String| KeyValue {
        key: k.into(),
        value: v,
    };
    let mut status = vec![DiagnosticStatus {
        level: if snap.supervisor.faults.is_empty() {
            level::OK
        } else {
            level::ERROR
        },
        name: format!("adrive: {}", snap.vehicle),
        message: snap.gate.reason.clone(),
        hardware_id: snap.vehicle.clone(),
        values: std::iter::once(kv("engaged", snap.gate.engaged.to_string()))
            .chain(snap.gate.blockers.iter().map(|b| kv("blocker", b.clone())))
            .chain(
                snap.supervisor
                    .faults
                    .iter()
                    .map(|f| kv("fault", f.describe())),
            )
            .collect(),
    }];
    for d in &snap.devices {
        let (lvl, message) = if d.health.faulty {
            (
                level::ERROR,
                d.health
                    .last_error
                    .clone()
                    .unwrap_or_else(|| "faulty".into()),
            )
        } else if d.stale {
            (level::STALE, "no recent reading".into())
        } else {
            (level::OK, "ok".into())
        };
        status.push(DiagnosticStatus {
            level: lvl,
            name: format!("adrive: {}", d.name),
            message,
            hardware_id: d.name.clone(),
            values: d
                .readings
                .iter()
                .map(|(k, v)| kv(k, v.as_ref().map_or_else(String::new, |v| v.to_string())))
                .collect(),
        });
    }
    msgs::DiagnosticArray {
        header: msgs::Header {
            stamp,
            frame_id: String::new(),
        },
        status,
    }
}

/// The ask for the state a code names on a state device (`key` is the code as the
/// map lists it; `code` as it came, for the error).
fn state_ask(
    states: Option<&States>,
    what: &'static str,
    key: u8,
    code: u8,
) -> Result<Option<Ask>, Unmapped> {
    let s = states.ok_or(Unmapped::NoDevice(what))?;
    let state = s
        .by_code
        .iter()
        .find(|(c, _)| *c == key)
        .and_then(|(_, i)| *i)
        .ok_or(Unmapped::Code(what, code))?;
    Ok(Some(Ask::Set(s.device, Command::State(state))))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn alice() -> VehicleMap {
        let c = VehicleConfig::alice();
        VehicleMap::new(&c, &c.ros2)
    }

    fn id(name: &str) -> DeviceId {
        let c = VehicleConfig::alice();
        DeviceId(c.devices.iter().position(|d| d.name == name).unwrap() as u16)
    }

    fn state(device: &str, name: &str) -> Ask {
        let c = VehicleConfig::alice();
        let d = id(device);
        Ask::Set(
            d,
            Command::State(c.devices[d.index()].state_index(name).unwrap()),
        )
    }

    #[test]
    fn raw_actuation_becomes_steer_and_one_accel_with_braking_first() {
        let m = alice();
        let asks = m.actuation(&msgs::ActuationCommand {
            accel_cmd: 0.3,
            brake_cmd: 0.0,
            steer_cmd: -0.25,
        });
        assert_eq!(
            asks.as_slice(),
            [Ask::Set(id("steer"), Command::Set(-0.25)), Ask::Accel(0.3)]
        );
        let asks = m.actuation(&msgs::ActuationCommand {
            accel_cmd: 0.3,
            brake_cmd: 0.5,
            steer_cmd: 1e-300,
        });
        assert_eq!(
            asks.as_slice(),
            [
                Ask::Set(id("steer"), Command::Set(1e-300)),
                Ask::Accel(-0.5)
            ]
        );
    }

    #[test]
    fn gears_map_to_the_gear_devices_states() {
        let m = alice();
        assert_eq!(m.gear(gear::DRIVE_18), Ok(Some(state("trans", "drive"))));
        assert_eq!(m.gear(gear::REVERSE), Ok(Some(state("trans", "reverse"))));
        assert_eq!(m.gear(gear::PARK), Ok(Some(state("trans", "park"))));
        assert_eq!(m.gear(gear::NEUTRAL), Ok(Some(state("trans", "neutral"))));
        assert_eq!(m.gear(gear::NONE), Ok(None));
        assert_eq!(m.gear(99), Err(Unmapped::Code("gear", 99)));
    }

    #[test]
    fn alice_has_no_turn_indicators_nor_hazard_lights() {
        let m = alice();
        assert_eq!(
            m.turn_indicators(lights::ENABLE_LEFT),
            Err(Unmapped::NoDevice("turn indicators"))
        );
        assert_eq!(
            m.hazard_lights(lights::ENABLE_LEFT),
            Err(Unmapped::NoDevice("hazard lights"))
        );
        assert!(!m.has_turn_indicators() && !m.has_hazard_lights());
    }
}
