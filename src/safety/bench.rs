//! When a bench procedure may move an actuator on its own (`adrive characterize`): a
//! procedure steps and sweeps a device with nobody's hand on a key, so it runs only
//! where that cannot move the vehicle — stopped, in park, with the brake held (unless
//! the brake is the device under test: park holds the vehicle then; or the gearbox is,
//! which shifts out of park: the brake alone holds it then, as for any shift), each proven by the
//! facts the interlocks read ([`Facts`]) — or on a bench where nothing
//! but the device under test is bound to a role (`--only DEVICE`). Checked before the
//! procedure starts and at every sample while it runs; a broken one ends it.
//!
//! The brake is held twice over: commanded (the interlocks' own fact, the lowest set
//! point on its way) and as it reports its position. A driver's foot that lifts the
//! brake changes no command; only the reading shows it, so a run does not wait for the
//! supervisor to name an override before it stops moving its device.

use super::rules::{stopped, Facts, SHIFT_BRAKE};
use crate::config::{Bindings, Role};
use crate::value::DeviceId;
use std::fmt;

/// Why a bench procedure may not move its device now.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Unready {
    /// The vehicle's speed is unknown or not below the rules' stopped.
    Moving,
    /// The gearbox does not report park.
    NotInPark,
    /// The brake is not held (at least the rules' shift brake).
    BrakeNotHeld,
    /// A role the proof needs is not bound (speed, gear with a park, brake).
    Unproven(Role),
}

impl fmt::Display for Unready {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Unready::Moving => f.write_str("the vehicle is not known to be stopped"),
            Unready::NotInPark => f.write_str("the gearbox is not in park"),
            Unready::BrakeNotHeld => f.write_str("the brake is not held"),
            Unready::Unproven(r) => write!(
                f,
                "no {r} bound to prove the vehicle still (bench: --only DEVICE)"
            ),
        }
    }
}

/// What proved that a bench procedure may move its device.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Proof {
    /// Nothing but the device is bound to a role: a bench.
    Bench,
    /// Stopped and in park, and the brake held — or the brake is the device under test
    /// (`brake_held` false), and park holds the vehicle; or the gearbox is (`in_park`
    /// false: it leaves park), and the brake holds it.
    Still { in_park: bool, brake_held: bool },
}

impl fmt::Display for Proof {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Proof::Bench => f.write_str("a bench: nothing else is bound to a role"),
            Proof::Still {
                in_park: true,
                brake_held: true,
            } => f.write_str("stopped, in park, the brake held"),
            Proof::Still {
                in_park: true,
                brake_held: false,
            } => f.write_str("stopped, in park (the brake is the device measured)"),
            Proof::Still {
                in_park: false,
                brake_held: _,
            } => f.write_str("stopped, the brake held (the gearbox is the device measured)"),
        }
    }
}

/// Only `device` is bound to a role, or nothing is: a bench, where moving it moves
/// nothing else.
fn bench(b: &Bindings, device: DeviceId) -> bool {
    Role::ALL
        .iter()
        .filter_map(|&r| b.device(r))
        .all(|d| d == device)
}

/// May a bench procedure move `device` now, the vehicle's roles `b`, what the rules
/// see `f` (gathered as for a gear command: brake, gear, speed) and where the brake
/// reports it is, as a fraction of its range (`None`: it reports no position)?
pub(crate) fn ready(
    b: &Bindings,
    device: DeviceId,
    f: &Facts,
    brake_reported: Option<f64>,
) -> Result<Proof, Unready> {
    if bench(b, device) {
        return Ok(Proof::Bench);
    }
    if b.speed.is_none() {
        return Err(Unready::Unproven(Role::Speed));
    }
    if !stopped(f.speed) {
        return Err(Unready::Moving);
    }
    // The gearbox under test leaves park by design: the brake alone holds the vehicle
    // then, as the rules ask of every shift.
    let gear_under_test = b.gear.as_ref().is_some_and(|g| g.device == device);
    if !gear_under_test {
        let park = b.gear.as_ref().and_then(|g| g.park);
        let Some(park) = park else {
            return Err(Unready::Unproven(Role::Gear));
        };
        if f.gear != Some(park) {
            return Err(Unready::NotInPark);
        }
        // The brake under test cannot also hold the vehicle: park does.
        if b.brake == Some(device) {
            return Ok(Proof::Still {
                in_park: true,
                brake_held: false,
            });
        }
    }
    if b.brake.is_none() {
        return Err(Unready::Unproven(Role::Brake));
    }
    if !f.brake_low.is_some_and(|lo| lo >= SHIFT_BRAKE) {
        return Err(Unready::BrakeNotHeld);
    }
    if brake_reported.is_some_and(|x| x < SHIFT_BRAKE) {
        return Err(Unready::BrakeNotHeld);
    }
    Ok(Proof::Still {
        in_park: !gear_under_test,
        brake_held: true,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::VehicleConfig;

    const PARK: u8 = 0;

    fn alice() -> (Bindings, DeviceId) {
        let c = VehicleConfig::alice();
        let steer = DeviceId(c.devices.iter().position(|d| d.name == "steer").unwrap() as u16);
        (c.roles, steer)
    }

    fn still() -> Facts {
        Facts {
            speed: Some(0.0),
            gear: Some(PARK),
            brake_low: Some(1.0),
            brake_high: Some(1.0),
            ..Facts::default()
        }
    }

    /// What the operator reads before a run ("Checked now: …") and when it is refused:
    /// each proof and each reason in its own words.
    #[test]
    fn each_proof_and_each_refusal_says_what_it_is() {
        let still = |in_park, brake_held| Proof::Still {
            in_park,
            brake_held,
        };
        for (proof, words) in [
            (Proof::Bench, "a bench: nothing else is bound to a role"),
            (still(true, true), "stopped, in park, the brake held"),
            (
                still(true, false),
                "stopped, in park (the brake is the device measured)",
            ),
            (
                still(false, true),
                "stopped, the brake held (the gearbox is the device measured)",
            ),
        ] {
            assert_eq!(proof.to_string(), words);
        }
        for (unready, words) in [
            (Unready::Moving, "the vehicle is not known to be stopped"),
            (Unready::NotInPark, "the gearbox is not in park"),
            (Unready::BrakeNotHeld, "the brake is not held"),
            (
                Unready::Unproven(Role::Speed),
                "no speed bound to prove the vehicle still (bench: --only DEVICE)",
            ),
        ] {
            assert_eq!(unready.to_string(), words);
        }
    }

    #[test]
    fn a_still_vehicle_in_park_with_the_brake_held_is_ready() {
        let (b, steer) = alice();
        assert_eq!(
            ready(&b, steer, &still(), Some(1.0)),
            Ok(Proof::Still {
                in_park: true,
                brake_held: true
            })
        );
    }

    #[test]
    fn moving_out_of_park_or_the_brake_let_go_each_refuse() {
        let (b, steer) = alice();
        let moving = Facts {
            speed: Some(0.5),
            ..still()
        };
        assert_eq!(ready(&b, steer, &moving, Some(1.0)), Err(Unready::Moving));
        let unknown = Facts {
            speed: None,
            ..still()
        };
        assert_eq!(ready(&b, steer, &unknown, Some(1.0)), Err(Unready::Moving));
        let drive = Facts {
            gear: Some(3),
            ..still()
        };
        assert_eq!(ready(&b, steer, &drive, Some(1.0)), Err(Unready::NotInPark));
        let released = Facts {
            brake_low: Some(SHIFT_BRAKE - 0.01),
            ..still()
        };
        assert_eq!(
            ready(&b, steer, &released, Some(1.0)),
            Err(Unready::BrakeNotHeld)
        );
        let unknown_brake = Facts {
            brake_low: None,
            ..still()
        };
        assert_eq!(
            ready(&b, steer, &unknown_brake, Some(1.0)),
            Err(Unready::BrakeNotHeld)
        );
    }

    /// A foot lifts the brake: its command still holds it, its reading does not.
    #[test]
    fn a_brake_held_on_the_wire_but_reported_released_is_not_held() {
        let (b, steer) = alice();
        assert_eq!(
            ready(&b, steer, &still(), Some(SHIFT_BRAKE - 0.01)),
            Err(Unready::BrakeNotHeld)
        );
        assert_eq!(
            ready(&b, steer, &still(), Some(SHIFT_BRAKE)),
            Ok(Proof::Still {
                in_park: true,
                brake_held: true
            })
        );
        assert_eq!(
            ready(&b, steer, &still(), None),
            Ok(Proof::Still {
                in_park: true,
                brake_held: true
            }),
            "no position reported"
        );
    }

    #[test]
    fn the_brake_under_test_need_not_hold_the_vehicle_but_park_must() {
        let (b, _) = alice();
        let brake = b.brake.unwrap();
        let released = Facts {
            brake_low: Some(0.0),
            ..still()
        };
        assert_eq!(
            ready(&b, brake, &released, Some(0.0)),
            Ok(Proof::Still {
                in_park: true,
                brake_held: false
            })
        );
        let drive = Facts {
            gear: Some(3),
            ..released
        };
        assert_eq!(ready(&b, brake, &drive, Some(0.0)), Err(Unready::NotInPark));
    }

    #[test]
    fn the_gearbox_under_test_may_leave_park_but_the_brake_must_hold() {
        let (b, _) = alice();
        let gear = b.gear.as_ref().unwrap().device;
        let drive = Facts {
            gear: Some(3),
            ..still()
        };
        assert_eq!(
            ready(&b, gear, &drive, Some(1.0)),
            Ok(Proof::Still {
                in_park: false,
                brake_held: true
            })
        );
        assert_eq!(
            ready(&b, gear, &drive, Some(0.1)),
            Err(Unready::BrakeNotHeld)
        );
        let moving = Facts {
            speed: Some(0.5),
            ..drive
        };
        assert_eq!(ready(&b, gear, &moving, Some(1.0)), Err(Unready::Moving));
    }

    #[test]
    fn a_bench_with_only_the_device_bound_is_ready_and_a_vehicle_without_proof_is_not() {
        let (b, steer) = alice();
        let only = Bindings {
            steering: Some(steer),
            ..Bindings::default()
        };
        assert_eq!(
            ready(&only, steer, &Facts::default(), None),
            Ok(Proof::Bench)
        );
        let no_speed = Bindings { speed: None, ..b };
        assert_eq!(
            ready(&no_speed, steer, &still(), Some(1.0)),
            Err(Unready::Unproven(Role::Speed))
        );
    }
}
