//! The virtual `accel` command (−1 … 1, as fractions of the pedals' ranges), decided
//! once: positive is throttle, negative is brake, never both. It is admitted or refused
//! as a whole — both of its parts pass, or it is refused and neither is stored — and an
//! admitted one is a [`Plan`]: what goes to the throttle and to the brake, and in which
//! order. The engine only carries a plan out ([`crate::engine::Gate::submit_accel`]).
//!
//! Going from braking to throttle, the brake's release goes first and the throttle
//! with it: the throttle's command thread holds it back until the release has reached
//! the brake ([`super::wire::Wait::BrakeReleased`]), so one `accel` is enough. While a
//! shift is under way the brake stays on, so positive `accel` is refused with its own
//! word ([`Reject::AccelWhileShifting`]): the sender sees that its throttle did not go
//! out, and sends it again once the gearbox is through.

use super::rules::{check, Facts, Plays, Reject, Rules, RELEASED};
use crate::config::DeviceConfig;
use crate::value::Command;

/// One of the two pedals `accel` drives.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Pedal {
    Throttle,
    Brake,
}

/// Both pedals: the facts an `accel` is decided over.
pub(crate) const PEDALS: Plays = Plays {
    throttle: true,
    brake: true,
    gear: false,
    starter: false,
};

/// What an admitted `accel` sends: each pedal's set point as a fraction of its range's
/// top, in the order they go.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct Plan {
    pub throttle: f64,
    pub brake: f64,
}

impl Plan {
    /// The parts of `a`: throttle above 0, brake below it, the other pedal released.
    pub(crate) fn of(a: f64) -> Plan {
        if a > 0.0 {
            Plan {
                throttle: a,
                brake: 0.0,
            }
        } else {
            Plan {
                throttle: 0.0,
                brake: -a,
            }
        }
    }

    /// The pedals in the order their commands go: the brake first when it is released
    /// for throttle (the throttle follows the release), the throttle first otherwise
    /// (its release before braking).
    pub(crate) fn order(self) -> [(Pedal, f64); 2] {
        if self.throttle > 0.0 {
            [(Pedal::Brake, self.brake), (Pedal::Throttle, self.throttle)]
        } else {
            [(Pedal::Throttle, self.throttle), (Pedal::Brake, self.brake)]
        }
    }

    /// A pedal's part as its device's command: the fraction of its range's top.
    pub(crate) fn command(d: &DeviceConfig, share: f64) -> Command {
        Command::Set(share * d.range[1])
    }
}

/// Why an `accel` was refused, and which pedal's part it was (counted on that device).
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct PedalReject {
    pub why: Reject,
    pub at: Pedal,
    /// The part refused, when it is the value that is.
    pub command: Option<Command>,
}

/// The value of `a` for these pedals: a finite number in −1 … 1 whose parts are inside
/// the pedals' ranges. (No state involved.)
pub(crate) fn check_value(
    throttle: &DeviceConfig,
    brake: &DeviceConfig,
    a: f64,
) -> Result<(), PedalReject> {
    let plan = Plan::of(a);
    for (pedal, d, share) in [
        (Pedal::Brake, brake, plan.brake),
        (Pedal::Throttle, throttle, plan.throttle),
    ] {
        let c = Plan::command(d, share);
        let why = if !a.is_finite() {
            Err(Reject::NotFinite)
        } else if !(-1.0..=1.0).contains(&a) {
            Err(Reject::OutOfRange)
        } else {
            super::gate_state::check_value(d, c)
        };
        if let Err(why) = why {
            return Err(PedalReject {
                why,
                at: pedal,
                command: Some(c),
            });
        }
    }
    Ok(())
}

/// The interlocks over both parts of `a`, given `f`, the facts of both pedals: while a
/// shift is under way positive `accel` is refused ([`Reject::AccelWhileShifting`]: its
/// brake release would break [`Reject::BrakeReleaseShifting`]); otherwise the brake's
/// part is checked first, and the throttle then as following that release (which the
/// wire holds it behind).
pub(crate) fn interlocks(f: &Facts, rules: Rules, a: f64) -> Result<(), PedalReject> {
    let refused = |why: Reject, at: Pedal| PedalReject {
        why,
        at,
        command: None,
    };
    let plan = Plan::of(a);
    if plan.throttle > 0.0 && f.shifting && rules.has(Reject::BrakeReleaseShifting) {
        return Err(refused(Reject::AccelWhileShifting, Pedal::Throttle));
    }
    check(f, rules, Plays::BRAKE, Command::Set(plan.brake))
        .map_err(|r| refused(r, Pedal::Brake))?;
    let behind_the_release = Facts {
        brake_releasing: f.brake_releasing || plan.brake <= RELEASED,
        ..*f
    };
    check(
        &behind_the_release,
        rules,
        Plays::THROTTLE,
        Command::Set(plan.throttle),
    )
    .map_err(|r| refused(r, Pedal::Throttle))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::value::EstopState;

    fn driving() -> Facts {
        Facts {
            brake_high: Some(0.0),
            brake_low: Some(0.0),
            gear: Some(3),
            in_gear: true,
            running: Some(true),
            speed: Some(5.0),
            estop: Some(EstopState::Run),
            ..Facts::default()
        }
    }

    #[test]
    fn accel_is_throttle_or_brake_never_both_and_the_release_goes_first() {
        assert_eq!(
            Plan::of(0.3).order(),
            [(Pedal::Brake, 0.0), (Pedal::Throttle, 0.3)]
        );
        assert_eq!(
            Plan::of(-0.6).order(),
            [(Pedal::Throttle, 0.0), (Pedal::Brake, 0.6)]
        );
        assert_eq!(
            Plan::of(0.0).order(),
            [(Pedal::Throttle, 0.0), (Pedal::Brake, 0.0)]
        );
    }

    /// A pedal's part is that fraction of its own range's top, whatever its units: half
    /// an `accel` on a brake that reads 0 … 80 is 40.
    #[test]
    fn a_pedal_s_part_is_its_share_of_its_range_s_top() {
        let mut brake = crate::config::VehicleConfig::alice()
            .devices
            .into_iter()
            .find(|d| d.name == "brake")
            .expect("Alice has a brake");
        brake.range = [0.0, 80.0];
        assert_eq!(Plan::command(&brake, 0.5), Command::Set(40.0));
        assert_eq!(Plan::command(&brake, 1.0), Command::Set(80.0));
        assert_eq!(check_value(&brake, &brake, -1.0), Ok(()));
    }

    /// An `accel` is a finite number in −1 … 1, both ends included; anything else is
    /// refused whole, named on the pedal checked first (the brake), with its part.
    #[test]
    fn an_accel_outside_minus_one_to_one_or_not_a_number_is_refused_whole() {
        let alice = crate::config::VehicleConfig::alice();
        let pedal = |name: &str| alice.devices.iter().find(|d| d.name == name).unwrap();
        let (gas, brake) = (pedal("gas"), pedal("brake"));
        for a in [-1.0, -0.5, 0.0, 0.5, 1.0] {
            assert_eq!(check_value(gas, brake, a), Ok(()), "{a}");
        }
        assert_eq!(
            check_value(gas, brake, 1.5),
            Err(PedalReject {
                why: Reject::OutOfRange,
                at: Pedal::Brake,
                command: Some(Command::Set(0.0))
            })
        );
        for (a, why) in [
            (-1.01, Reject::OutOfRange),
            (f64::NAN, Reject::NotFinite),
            (f64::INFINITY, Reject::NotFinite),
            (f64::NEG_INFINITY, Reject::NotFinite),
        ] {
            assert_eq!(
                check_value(gas, brake, a).map_err(|r| r.why),
                Err(why),
                "{a}"
            );
        }
    }

    /// While a shift is under way, positive `accel` is refused with its own word, on the
    /// throttle; braking through the shift is allowed, releasing the brake is not.
    #[test]
    fn positive_accel_during_a_shift_is_refused_in_its_own_words() {
        let shifting = Facts {
            shifting: true,
            brake_high: Some(1.0),
            brake_low: Some(1.0),
            speed: Some(0.0),
            ..driving()
        };
        assert_eq!(
            interlocks(&shifting, Rules::ALL, 0.3),
            Err(PedalReject {
                why: Reject::AccelWhileShifting,
                at: Pedal::Throttle,
                command: None
            })
        );
        assert_eq!(interlocks(&shifting, Rules::ALL, -0.5), Ok(()));
        assert_eq!(
            interlocks(&shifting, Rules::ALL, -0.1).map_err(|r| r.why),
            Err(Reject::BrakeReleaseShifting)
        );
        // Not shifting: the same `accel` goes.
        let through = Facts {
            shifting: false,
            ..shifting
        };
        assert_eq!(interlocks(&through, Rules::ALL, 0.3), Ok(()));
        // A vehicle without the shift rule has no shift to wait for.
        assert_eq!(interlocks(&shifting, Rules::default(), 0.3), Ok(()));
    }

    /// From braking, one `accel` releases the brake and the throttle follows; the other
    /// throttle rules still refuse it, on the throttle.
    #[test]
    fn throttle_follows_the_release_of_the_same_accel() {
        let braking = Facts {
            brake_high: Some(1.0),
            brake_low: Some(1.0),
            ..driving()
        };
        assert_eq!(interlocks(&braking, Rules::ALL, 0.3), Ok(()));
        let off = Facts {
            running: Some(false),
            ..braking
        };
        assert_eq!(
            interlocks(&off, Rules::ALL, 0.3),
            Err(PedalReject {
                why: Reject::GasEngineOff,
                at: Pedal::Throttle,
                command: None
            })
        );
        let paused = Facts {
            estop: Some(EstopState::Pause),
            ..braking
        };
        assert_eq!(
            interlocks(&paused, Rules::ALL, -0.5),
            Err(PedalReject {
                why: Reject::BrakeReleaseEstop,
                at: Pedal::Brake,
                command: None
            })
        );
    }
}
