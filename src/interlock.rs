//! Interlocks: the rules every command must pass at intake, before it may reach a
//! command slot. A rejected command is counted and logged, never sent. The rules
//! (DESIGN.md "Safety"): no gas while the brake is applied (gas that follows a brake
//! release on its way is held back at the wire until the release is there); gas only in
//! drive or reverse with the engine running; shift only when stopped with the brake applied,
//! and keep the brake applied until the shift is through;
//! e-stop pause or disable means gas zero and the brake held.
//!
//! [`check`] is a pure function of the command and a [`Facts`] snapshot, so every rule
//! is unit- and property-tested without threads.

use crate::value::{Command, Control, EstopState, Gear, Role};
use serde::Serialize;
use std::fmt;

/// Gas or brake at or below this counts as released.
pub const RELEASED: f64 = 0.02;
/// Brake at or above this counts as applied for shifting.
pub const SHIFT_BRAKE: f64 = 0.3;
/// Below this speed (m/s) the vehicle counts as stopped.
pub const STOPPED: f64 = 0.1;

/// What the interlocks know of the vehicle.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Facts {
    /// Highest brake value pending, sent or acknowledged (None: no brake device).
    pub brake_high: Option<f64>,
    /// Lowest brake value pending, sent or acknowledged.
    pub brake_low: Option<f64>,
    /// The brake's newest command releases it: gas may follow, held back at the wire
    /// until the release has reached the brake ([`crate::vehicle::Vehicle::clear_to_send`]).
    pub brake_releasing: bool,
    pub gear: Option<Gear>,
    pub running: Option<bool>,
    pub speed: Option<f64>,
    pub estop: Option<EstopState>,
    /// A shift is commanded and the gearbox does not report that gear yet.
    pub shifting: bool,
}

/// Why intake refused a command.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Reject {
    NoSuchDevice,
    NotAnActuator,
    WrongKind,
    NotFinite,
    OutOfRange,
    GasWhileBraking,
    GasNotInGear,
    GasEngineOff,
    GasEstop,
    BrakeReleaseEstop,
    BrakeReleaseShifting,
    ShiftWhileMoving,
    ShiftWithoutBrake,
    StartInGear,
    Disengaged,
    Recovering,
}

impl Reject {
    pub const ALL: [Reject; 16] = [
        Reject::NoSuchDevice,
        Reject::NotAnActuator,
        Reject::WrongKind,
        Reject::NotFinite,
        Reject::OutOfRange,
        Reject::GasWhileBraking,
        Reject::GasNotInGear,
        Reject::GasEngineOff,
        Reject::GasEstop,
        Reject::BrakeReleaseEstop,
        Reject::BrakeReleaseShifting,
        Reject::ShiftWhileMoving,
        Reject::ShiftWithoutBrake,
        Reject::StartInGear,
        Reject::Disengaged,
        Reject::Recovering,
    ];

    pub fn as_str(self) -> &'static str {
        match self {
            Reject::NoSuchDevice => "no_such_device",
            Reject::NotAnActuator => "not_an_actuator",
            Reject::WrongKind => "wrong_kind",
            Reject::NotFinite => "not_finite",
            Reject::OutOfRange => "out_of_range",
            Reject::GasWhileBraking => "gas_while_braking",
            Reject::GasNotInGear => "gas_not_in_gear",
            Reject::GasEngineOff => "gas_engine_off",
            Reject::GasEstop => "gas_estop",
            Reject::BrakeReleaseEstop => "brake_release_estop",
            Reject::BrakeReleaseShifting => "brake_release_shifting",
            Reject::ShiftWhileMoving => "shift_while_moving",
            Reject::ShiftWithoutBrake => "shift_without_brake",
            Reject::StartInGear => "start_in_gear",
            Reject::Disengaged => "disengaged",
            Reject::Recovering => "recovering",
        }
    }

    /// True for the safety rules (as opposed to malformed commands).
    pub fn is_interlock(self) -> bool {
        !matches!(
            self,
            Reject::NoSuchDevice
                | Reject::NotAnActuator
                | Reject::WrongKind
                | Reject::NotFinite
                | Reject::OutOfRange
                | Reject::Disengaged
                | Reject::Recovering
        )
    }

    pub fn index(self) -> usize {
        Reject::ALL.iter().position(|r| *r == self).expect("listed")
    }
}

impl fmt::Display for Reject {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Reject::NoSuchDevice => "no such device in this vehicle",
            Reject::NotAnActuator => "the device is a sensor and takes no commands",
            Reject::WrongKind => "wrong kind of value for this device",
            Reject::NotFinite => "value is not a finite number",
            Reject::OutOfRange => "value outside the device's range",
            Reject::GasWhileBraking => "no gas while the brake is applied",
            Reject::GasNotInGear => "gas only in drive or reverse",
            Reject::GasEngineOff => "gas only with the engine running",
            Reject::GasEstop => "no gas unless the e-stop says run",
            Reject::BrakeReleaseEstop => "the brake stays on while the e-stop pauses",
            Reject::BrakeReleaseShifting => "the brake stays on until the shift is through",
            Reject::ShiftWhileMoving => "shift only when stopped",
            Reject::ShiftWithoutBrake => "shift only with the brake applied",
            Reject::StartInGear => "the starter runs only in park or neutral",
            Reject::Disengaged => "adrive is disengaged",
            Reject::Recovering => "a recovery procedure has the vehicle",
        })
    }
}

/// The safety rules alone (range and kind are checked by the caller).
pub fn check(facts: &Facts, role: Role, command: Command) -> Result<(), Reject> {
    match (role, command) {
        (Role::Gas, Command::Set(v)) if v > RELEASED => {
            if facts.brake_high.is_some_and(|b| b > RELEASED) && !facts.brake_releasing {
                return Err(Reject::GasWhileBraking);
            }
            if !facts.gear.is_some_and(Gear::is_driving) {
                return Err(Reject::GasNotInGear);
            }
            if facts.running != Some(true) {
                return Err(Reject::GasEngineOff);
            }
            if facts.estop != Some(EstopState::Run) {
                return Err(Reject::GasEstop);
            }
            Ok(())
        }
        (Role::Brake, Command::Set(v)) if v < 1.0 => {
            if matches!(facts.estop, Some(EstopState::Pause | EstopState::Disable)) {
                return Err(Reject::BrakeReleaseEstop);
            }
            if facts.shifting && v < SHIFT_BRAKE {
                return Err(Reject::BrakeReleaseShifting);
            }
            Ok(())
        }
        (Role::Trans, Command::Gear(g)) if Some(g) != facts.gear => {
            if !facts.speed.is_some_and(|s| s.abs() < STOPPED) {
                return Err(Reject::ShiftWhileMoving);
            }
            if !facts.brake_low.is_some_and(|b| b >= SHIFT_BRAKE) {
                return Err(Reject::ShiftWithoutBrake);
            }
            Ok(())
        }
        (Role::Trans, Command::Control(Control::Start)) => {
            if facts.gear.is_some_and(Gear::is_driving) {
                return Err(Reject::StartInGear);
            }
            Ok(())
        }
        _ => Ok(()),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn driving() -> Facts {
        Facts {
            brake_high: Some(0.0),
            brake_low: Some(0.0),
            brake_releasing: false,
            gear: Some(Gear::Drive),
            running: Some(true),
            speed: Some(5.0),
            estop: Some(EstopState::Run),
            shifting: false,
        }
    }

    #[test]
    fn gas_passes_when_everything_allows_it() {
        assert_eq!(check(&driving(), Role::Gas, Command::Set(0.5)), Ok(()));
    }

    #[test]
    fn gas_while_braking_is_rejected() {
        let f = Facts {
            brake_high: Some(0.4),
            ..driving()
        };
        assert_eq!(
            check(&f, Role::Gas, Command::Set(0.3)),
            Err(Reject::GasWhileBraking)
        );
        // Releasing the gas is always allowed.
        assert_eq!(check(&f, Role::Gas, Command::Set(0.0)), Ok(()));
        // With a release on its way the gas may follow it (the wire holds it back).
        let releasing = Facts {
            brake_releasing: true,
            ..f
        };
        assert_eq!(check(&releasing, Role::Gas, Command::Set(0.3)), Ok(()));
        // The other rules still apply.
        let in_park = Facts {
            gear: Some(Gear::Park),
            ..releasing
        };
        assert_eq!(
            check(&in_park, Role::Gas, Command::Set(0.3)),
            Err(Reject::GasNotInGear)
        );
    }

    #[test]
    fn gas_in_park_or_neutral_or_unknown_gear_is_rejected() {
        for gear in [Some(Gear::Park), Some(Gear::Neutral), None] {
            let f = Facts { gear, ..driving() };
            assert_eq!(
                check(&f, Role::Gas, Command::Set(0.3)),
                Err(Reject::GasNotInGear)
            );
        }
        let f = Facts {
            gear: Some(Gear::Reverse),
            ..driving()
        };
        assert_eq!(check(&f, Role::Gas, Command::Set(0.3)), Ok(()));
    }

    #[test]
    fn gas_with_the_engine_off_or_estop_not_run_is_rejected() {
        let f = Facts {
            running: Some(false),
            ..driving()
        };
        assert_eq!(
            check(&f, Role::Gas, Command::Set(0.3)),
            Err(Reject::GasEngineOff)
        );
        for estop in [Some(EstopState::Pause), Some(EstopState::Disable), None] {
            let f = Facts { estop, ..driving() };
            assert_eq!(
                check(&f, Role::Gas, Command::Set(0.3)),
                Err(Reject::GasEstop)
            );
        }
    }

    #[test]
    fn shift_while_moving_or_without_brake_is_rejected() {
        let moving = Facts {
            brake_low: Some(1.0),
            brake_high: Some(1.0),
            ..driving()
        };
        assert_eq!(
            check(&moving, Role::Trans, Command::Gear(Gear::Park)),
            Err(Reject::ShiftWhileMoving)
        );
        let stopped_no_brake = Facts {
            speed: Some(0.0),
            ..driving()
        };
        assert_eq!(
            check(&stopped_no_brake, Role::Trans, Command::Gear(Gear::Park)),
            Err(Reject::ShiftWithoutBrake)
        );
        let ok = Facts {
            speed: Some(0.0),
            ..moving
        };
        assert_eq!(check(&ok, Role::Trans, Command::Gear(Gear::Park)), Ok(()));
        // Re-sending the current gear is not a shift.
        assert_eq!(
            check(&moving, Role::Trans, Command::Gear(Gear::Drive)),
            Ok(())
        );
    }

    #[test]
    fn the_brake_stays_on_until_a_shift_is_through() {
        let f = Facts {
            shifting: true,
            speed: Some(0.0),
            ..driving()
        };
        assert_eq!(
            check(&f, Role::Brake, Command::Set(0.0)),
            Err(Reject::BrakeReleaseShifting)
        );
        assert_eq!(check(&f, Role::Brake, Command::Set(0.5)), Ok(()));
    }

    #[test]
    fn estop_pause_holds_the_brake() {
        let f = Facts {
            estop: Some(EstopState::Pause),
            ..driving()
        };
        assert_eq!(
            check(&f, Role::Brake, Command::Set(0.2)),
            Err(Reject::BrakeReleaseEstop)
        );
        assert_eq!(check(&f, Role::Brake, Command::Set(1.0)), Ok(()));
    }
}
