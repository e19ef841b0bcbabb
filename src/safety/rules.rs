//! The interlock rules, as pure functions: what every command must pass at intake,
//! before it may reach a command slot, and again at the wire ([`super::wire`]). A
//! rejected command is counted and logged, never sent. The rules (DESIGN.md
//! "Safety"): no throttle while the brake is applied; throttle only in a driving gear,
//! with the engine running and the e-stop in run; shift only when stopped with the
//! brake applied, and keep the brake applied until the shift is through; while the
//! e-stop pauses or disables, the brake stays on; the starter runs only out of gear.
//!
//! Each rule acts on roles, never on device names, and applies only when the devices
//! it needs are bound ([`Rules::active`]): a cart without a gearbox has no shift rule.
//! [`check`] is a pure function of the command and a [`Facts`] value, so every rule is
//! unit- and property-tested without threads.

use crate::config::{Bindings, Role};
use crate::value::{Command, Control, EstopState};
pub use crate::vehicle::seen::Facts;
use serde::{Deserialize, Serialize};
use std::fmt;

/// Throttle or brake at or below this fraction of its range counts as released.
pub const RELEASED: f64 = 0.02;
/// Brake at or above this fraction of its range counts as applied for shifting.
pub const SHIFT_BRAKE: f64 = 0.3;
/// Below this speed (m/s) the vehicle counts as stopped.
pub const STOPPED: f64 = 0.1;

/// The vehicle is stopped: its speed is known and below [`STOPPED`]. An unknown speed
/// (the sensor has not reported, or reports nothing) is moving. The one meaning of
/// "stopped" for the shift rule ([`Reject::ShiftWhileMoving`]) and for the recovery
/// step that waits for it (`crate::supervisor::recovery`).
pub fn stopped(speed: Option<f64>) -> bool {
    speed.is_some_and(|s| s.abs() < STOPPED)
}

/// Why intake refused a command.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Reject {
    NoSuchDevice,
    NotAnActuator,
    WrongKind,
    NoSuchControl,
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
    AccelWhileShifting,
}

impl Reject {
    pub const ALL: [Reject; 18] = [
        Reject::NoSuchDevice,
        Reject::NotAnActuator,
        Reject::WrongKind,
        Reject::NoSuchControl,
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
        Reject::AccelWhileShifting,
    ];

    /// The interlock rules among the reasons.
    pub(crate) const RULES: [Reject; 9] = [
        Reject::GasWhileBraking,
        Reject::GasNotInGear,
        Reject::GasEngineOff,
        Reject::GasEstop,
        Reject::BrakeReleaseEstop,
        Reject::BrakeReleaseShifting,
        Reject::ShiftWhileMoving,
        Reject::ShiftWithoutBrake,
        Reject::StartInGear,
    ];

    pub fn as_str(self) -> &'static str {
        match self {
            Reject::NoSuchDevice => "no_such_device",
            Reject::NotAnActuator => "not_an_actuator",
            Reject::WrongKind => "wrong_kind",
            Reject::NoSuchControl => "no_such_control",
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
            Reject::AccelWhileShifting => "accel_while_shifting",
        }
    }

    pub fn index(self) -> usize {
        self as usize
    }

    /// The roles a rule needs bound to apply.
    pub fn needs(self) -> &'static [Role] {
        match self {
            Reject::GasWhileBraking => &[Role::Throttle, Role::Brake],
            Reject::GasNotInGear => &[Role::Throttle, Role::Gear],
            Reject::GasEngineOff => &[Role::Throttle, Role::EngineRunning],
            Reject::GasEstop => &[Role::Throttle, Role::Estop],
            Reject::BrakeReleaseEstop => &[Role::Brake, Role::Estop],
            Reject::BrakeReleaseShifting => &[Role::Brake, Role::Gear],
            Reject::ShiftWhileMoving => &[Role::Gear, Role::Speed],
            Reject::ShiftWithoutBrake => &[Role::Gear, Role::Brake],
            Reject::StartInGear => &[Role::Starter, Role::Gear],
            _ => &[],
        }
    }
}

impl fmt::Display for Reject {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Reject::NoSuchDevice => "no such device in this vehicle",
            Reject::NotAnActuator => "the device is a sensor and takes no commands",
            Reject::WrongKind => "wrong kind of value for this device",
            Reject::NoSuchControl => {
                "the device's protocol carries no such control (see its vehicle file)"
            }
            Reject::NotFinite => "value is not a finite number",
            Reject::OutOfRange => "value outside the device's range",
            Reject::GasWhileBraking => "no throttle while the brake is applied",
            Reject::GasNotInGear => "throttle only in a driving gear",
            Reject::GasEngineOff => "throttle only with the engine running",
            Reject::GasEstop => "no throttle unless the e-stop says run",
            Reject::BrakeReleaseEstop => "the brake stays on while the e-stop pauses",
            Reject::BrakeReleaseShifting => "the brake stays on until the shift is through",
            Reject::ShiftWhileMoving => "shift only when stopped",
            Reject::ShiftWithoutBrake => "shift only with the brake applied",
            Reject::StartInGear => "the starter runs only out of gear",
            Reject::Disengaged => "adrive is disengaged",
            Reject::Recovering => "a recovery procedure has the vehicle",
            Reject::AccelWhileShifting => {
                "no throttle until the shift is through (the brake stays on)"
            }
        })
    }
}

/// Which rules apply on a vehicle: those whose roles are all bound.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Rules(u32);

impl Rules {
    /// Every rule (tests of the rules alone).
    pub const ALL: Rules = Rules(u32::MAX);

    pub fn active(b: &Bindings) -> Rules {
        Rules(
            Reject::RULES
                .iter()
                .filter(|r| r.needs().iter().all(|role| b.is_bound(*role)))
                .fold(0, |m, r| m | 1 << r.index()),
        )
    }

    pub fn has(self, r: Reject) -> bool {
        self.0 & (1 << r.index()) != 0
    }

    /// The active rules, by name.
    pub fn names(self) -> Vec<&'static str> {
        Reject::RULES
            .iter()
            .filter(|r| self.has(**r))
            .map(|r| r.as_str())
            .collect()
    }

    /// What the vehicle lacks, in sentences, for the start-up log: each rule that is
    /// absent and why, and what the safe state cannot do.
    pub fn missing(b: &Bindings) -> Vec<String> {
        let mut out = Vec::new();
        if b.brake.is_none() {
            out.push("no brake bound: the safe state cannot brake".to_string());
        }
        if b.throttle.is_none() {
            out.push("no throttle bound: accel is not available".to_string());
        }
        if b.estop.is_none() {
            out.push("no estop bound: an e-stop pause is not watched".to_string());
        }
        for r in Reject::RULES {
            let absent: Vec<&str> = r
                .needs()
                .iter()
                .filter(|role| !b.is_bound(**role))
                .map(|role| role.as_str())
                .collect();
            // A rule about a role the vehicle lacks entirely is simply not there;
            // name only rules half-bound (their subject exists, a fact they need not).
            if !absent.is_empty() && absent.len() < r.needs().len() {
                out.push(format!(
                    "rule {} is off: no {} bound",
                    r.as_str(),
                    absent.join(", ")
                ));
            }
        }
        out
    }
}

/// The roles a command to one actuator plays, for [`check`].
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Plays {
    pub throttle: bool,
    pub brake: bool,
    pub gear: bool,
    pub starter: bool,
}

impl Plays {
    /// A throttle's commands.
    pub const THROTTLE: Plays = Plays {
        throttle: true,
        brake: false,
        gear: false,
        starter: false,
    };
    /// A brake's commands.
    pub const BRAKE: Plays = Plays {
        throttle: false,
        brake: true,
        gear: false,
        starter: false,
    };
    /// A gearbox's commands.
    pub const GEAR: Plays = Plays {
        throttle: false,
        brake: false,
        gear: true,
        starter: false,
    };

    pub fn of(roles: &[Role]) -> Plays {
        Plays {
            throttle: roles.contains(&Role::Throttle),
            brake: roles.contains(&Role::Brake),
            gear: roles.contains(&Role::Gear),
            starter: roles.contains(&Role::Starter),
        }
    }

    /// No rule looks at this device's commands.
    pub(crate) fn is_free(self) -> bool {
        self == Plays::default()
    }
}

/// One interlock, written once: does `command`, for a device that plays `plays`, break
/// `rule` given `f`? Intake ([`check`]) and the wire ([`super::wire::verdict`]) both ask
/// this; only what each does about a broken rule differs (intake refuses; the wire
/// waits, replaces or drops). A reason that is not an interlock breaks nothing.
pub(crate) fn breaks(rule: Reject, f: &Facts, plays: Plays, command: Command) -> bool {
    let gas = |v: f64| plays.throttle && v > RELEASED;
    let shift = |g: u8| plays.gear && Some(g) != f.gear;
    match (rule, command) {
        (Reject::GasWhileBraking, Command::Set(v)) => {
            gas(v) && f.brake_high.is_some_and(|b| b > RELEASED) && !f.brake_releasing
        }
        (Reject::GasNotInGear, Command::Set(v)) => gas(v) && !f.in_gear,
        (Reject::GasEngineOff, Command::Set(v)) => gas(v) && f.running != Some(true),
        (Reject::GasEstop, Command::Set(v)) => gas(v) && f.estop != Some(EstopState::Run),
        (Reject::BrakeReleaseEstop, Command::Set(v)) => {
            plays.brake
                && v < 1.0
                && matches!(f.estop, Some(EstopState::Pause | EstopState::Disable))
        }
        (Reject::BrakeReleaseShifting, Command::Set(v)) => {
            plays.brake && v < SHIFT_BRAKE && f.shifting
        }
        (Reject::ShiftWhileMoving, Command::State(g)) => shift(g) && !stopped(f.speed),
        (Reject::ShiftWithoutBrake, Command::State(g)) => {
            shift(g) && !f.brake_low.is_some_and(|b| b >= SHIFT_BRAKE)
        }
        (Reject::StartInGear, Command::Control(Control::Start)) => plays.starter && f.in_gear,
        _ => false,
    }
}

/// The intake check: the first active rule `command` breaks, in the order of
/// [`Reject::RULES`].
pub fn check(facts: &Facts, rules: Rules, plays: Plays, command: Command) -> Result<(), Reject> {
    match Reject::RULES
        .into_iter()
        .find(|r| rules.has(*r) && breaks(*r, facts, plays, command))
    {
        Some(r) => Err(r),
        None => Ok(()),
    }
}

/// The guide's table (docs/vehicles.md) of the interlock rules: each with the roles it needs bound and
/// what it refuses.
#[cfg_attr(not(test), allow(dead_code))]
pub(crate) fn markdown() -> String {
    let mut out = String::from("| rule | applies when bound | refuses |\n|---|---|---|\n");
    for r in Reject::RULES {
        let needs: Vec<String> = r
            .needs()
            .iter()
            .map(|n| format!("`{}`", n.as_str()))
            .collect();
        out.push_str(&format!(
            "| `{}` | {} | {} |\n",
            r.as_str(),
            needs.join(", "),
            r
        ));
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    const DRIVE: u8 = 3;

    /// A gearbox that is also the starter (Alice's `trans`).
    const TRANS: Plays = Plays {
        starter: true,
        ..Plays::GEAR
    };
    const PARK: u8 = 0;

    fn driving() -> Facts {
        Facts {
            brake_high: Some(0.0),
            brake_low: Some(0.0),
            brake_releasing: false,
            gear: Some(DRIVE),
            in_gear: true,
            running: Some(true),
            speed: Some(5.0),
            estop: Some(EstopState::Run),
            shifting: false,
            ..Facts::default()
        }
    }

    fn check_all(f: &Facts, plays: Plays, c: Command) -> Result<(), Reject> {
        check(f, Rules::ALL, plays, c)
    }

    /// Gas is refused while the brake is applied — above released — and passes with
    /// the brake at released.
    #[test]
    fn gas_is_refused_only_above_a_released_brake() {
        let gas = Command::Set(0.5);
        let at = Facts {
            brake_high: Some(RELEASED),
            ..driving()
        };
        assert_eq!(check_all(&at, Plays::THROTTLE, gas), Ok(()));
        let above = Facts {
            brake_high: Some(RELEASED + 0.01),
            ..driving()
        };
        assert_eq!(
            check_all(&above, Plays::THROTTLE, gas),
            Err(Reject::GasWhileBraking)
        );
        // And the throttle at released is no gas, under any brake.
        let released = Command::Set(RELEASED);
        assert_eq!(check_all(&above, Plays::THROTTLE, released), Ok(()));
        assert_eq!(
            check_all(&above, Plays::THROTTLE, Command::Set(RELEASED + 0.01)),
            Err(Reject::GasWhileBraking)
        );
    }

    /// While a shift is under way the brake is not released below the shift's brake;
    /// at it, it may be.
    #[test]
    fn a_shift_holds_the_brake_at_the_shifts_brake() {
        let shifting = Facts {
            shifting: true,
            ..driving()
        };
        assert_eq!(
            check_all(&shifting, Plays::BRAKE, Command::Set(SHIFT_BRAKE)),
            Ok(())
        );
        assert_eq!(
            check_all(&shifting, Plays::BRAKE, Command::Set(SHIFT_BRAKE - 0.01)),
            Err(Reject::BrakeReleaseShifting)
        );
    }

    /// The starter runs only out of gear.
    #[test]
    fn the_starter_runs_only_out_of_gear() {
        let starter = Plays {
            starter: true,
            ..Plays::default()
        };
        let start = Command::Control(Control::Start);
        assert_eq!(
            check_all(&driving(), starter, start),
            Err(Reject::StartInGear)
        );
        let parked = Facts {
            in_gear: false,
            ..driving()
        };
        assert_eq!(check_all(&parked, starter, start), Ok(()));
    }

    /// Stopped is a known speed below [`STOPPED`], either way; at it, or unknown, the
    /// vehicle is moving.
    #[test]
    fn stopped_is_a_known_speed_below_the_bound() {
        assert!(stopped(Some(0.0)) && stopped(Some(0.09)) && stopped(Some(-0.09)));
        assert!(!stopped(Some(STOPPED)) && !stopped(Some(-STOPPED)) && !stopped(None));
    }

    #[test]
    fn gas_passes_when_everything_allows_it() {
        assert_eq!(
            check_all(&driving(), Plays::THROTTLE, Command::Set(0.5)),
            Ok(())
        );
    }

    #[test]
    fn gas_while_braking_is_rejected() {
        let f = Facts {
            brake_high: Some(0.4),
            ..driving()
        };
        assert_eq!(
            check_all(&f, Plays::THROTTLE, Command::Set(0.3)),
            Err(Reject::GasWhileBraking)
        );
        // Releasing the gas is always allowed.
        assert_eq!(check_all(&f, Plays::THROTTLE, Command::Set(0.0)), Ok(()));
        // With a release on its way the gas may follow it (the wire holds it back).
        let releasing = Facts {
            brake_releasing: true,
            ..f
        };
        assert_eq!(
            check_all(&releasing, Plays::THROTTLE, Command::Set(0.3)),
            Ok(())
        );
        // The other rules still apply.
        let in_park = Facts {
            gear: Some(PARK),
            in_gear: false,
            ..releasing
        };
        assert_eq!(
            check_all(&in_park, Plays::THROTTLE, Command::Set(0.3)),
            Err(Reject::GasNotInGear)
        );
    }

    #[test]
    fn gas_out_of_gear_is_rejected() {
        let f = Facts {
            gear: Some(PARK),
            in_gear: false,
            ..driving()
        };
        assert_eq!(
            check_all(&f, Plays::THROTTLE, Command::Set(0.3)),
            Err(Reject::GasNotInGear)
        );
    }

    #[test]
    fn gas_with_the_engine_off_or_estop_not_run_is_rejected() {
        let f = Facts {
            running: Some(false),
            ..driving()
        };
        assert_eq!(
            check_all(&f, Plays::THROTTLE, Command::Set(0.3)),
            Err(Reject::GasEngineOff)
        );
        for estop in [Some(EstopState::Pause), Some(EstopState::Disable), None] {
            let f = Facts { estop, ..driving() };
            assert_eq!(
                check_all(&f, Plays::THROTTLE, Command::Set(0.3)),
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
            check_all(&moving, TRANS, Command::State(PARK)),
            Err(Reject::ShiftWhileMoving)
        );
        let stopped_no_brake = Facts {
            speed: Some(0.0),
            ..driving()
        };
        assert_eq!(
            check_all(&stopped_no_brake, TRANS, Command::State(PARK)),
            Err(Reject::ShiftWithoutBrake)
        );
        let ok = Facts {
            speed: Some(0.0),
            ..moving
        };
        assert_eq!(check_all(&ok, TRANS, Command::State(PARK)), Ok(()));
        // Re-sending the current gear is not a shift.
        assert_eq!(check_all(&moving, TRANS, Command::State(DRIVE)), Ok(()));
    }

    #[test]
    fn the_brake_stays_on_until_a_shift_is_through() {
        let f = Facts {
            shifting: true,
            speed: Some(0.0),
            ..driving()
        };
        assert_eq!(
            check_all(&f, Plays::BRAKE, Command::Set(0.0)),
            Err(Reject::BrakeReleaseShifting)
        );
        assert_eq!(check_all(&f, Plays::BRAKE, Command::Set(0.5)), Ok(()));
    }

    #[test]
    fn estop_pause_holds_the_brake() {
        let f = Facts {
            estop: Some(EstopState::Pause),
            ..driving()
        };
        assert_eq!(
            check_all(&f, Plays::BRAKE, Command::Set(0.2)),
            Err(Reject::BrakeReleaseEstop)
        );
        assert_eq!(check_all(&f, Plays::BRAKE, Command::Set(1.0)), Ok(()));
    }

    #[test]
    fn a_rule_without_its_devices_is_absent() {
        // A cart without a gearbox: gas needs no gear, and nothing is a shift.
        let b = Bindings {
            throttle: Some(crate::value::DeviceId(0)),
            brake: Some(crate::value::DeviceId(1)),
            ..Bindings::default()
        };
        let rules = Rules::active(&b);
        assert!(rules.has(Reject::GasWhileBraking));
        assert!(!rules.has(Reject::GasNotInGear));
        assert!(!rules.has(Reject::ShiftWhileMoving));
        let parked = Facts {
            gear: None,
            in_gear: false,
            running: None,
            estop: None,
            ..driving()
        };
        assert_eq!(
            check(&parked, rules, Plays::THROTTLE, Command::Set(0.5)),
            Ok(())
        );
        assert_eq!(rules.names(), vec!["gas_while_braking"]);
        // Said at start-up: what the safe state cannot do, and each rule whose subject
        // is there but a fact it needs is not; a rule about a role the vehicle lacks
        // entirely (a shift, with no gearbox) is simply not there.
        assert_eq!(
            Rules::missing(&b),
            [
                "no estop bound: an e-stop pause is not watched",
                "rule gas_not_in_gear is off: no gear bound",
                "rule gas_engine_off is off: no engine_running bound",
                "rule gas_estop is off: no estop bound",
                "rule brake_release_estop is off: no estop bound",
                "rule brake_release_shifting is off: no gear bound",
                "rule shift_without_brake is off: no gear bound",
            ]
        );
    }

    #[test]
    fn a_device_without_a_role_is_checked_by_no_rule() {
        let nobody = Plays::default();
        assert!(nobody.is_free());
        let f = Facts::default();
        for c in [
            Command::Set(1.0),
            Command::State(2),
            Command::Control(Control::Start),
        ] {
            assert_eq!(check_all(&f, nobody, c), Ok(()));
        }
    }

    /// The guide's table (docs/vehicles.md) of rules is this module's.
    #[test]
    fn the_guide_shows_the_rules_table() {
        let readme = include_str!("../../docs/vehicles.md");
        let table = markdown();
        crate::testkit::assert_guide_holds("docs/vehicles.md", readme, "rules", &table);
    }
}
