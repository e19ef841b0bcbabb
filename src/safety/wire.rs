//! The last check, made by a command thread right before its command goes on the
//! wire, against what the other actuators have pending, in flight or already on the
//! wire. Intake checked the same rules, but throttle and brake have threads of their
//! own, so a brake command submitted a moment after a throttle command could otherwise
//! reach its device first. Each thread has put its own command in flight before it
//! looks at the others', so of two racing threads at least one sees the other.
//!
//! [`verdict`] is a pure function of what the other devices' slots and caches hold
//! ([`Facts`], the type the intake check asks over too); the engine gathers them, asks,
//! and acts. A wait happens before the command thread takes its port, so no port is
//! held while another device is awaited.

use super::rules::{breaks, Facts, Plays, Reject, Rules, RELEASED};
use crate::value::Command;

/// What the command thread does with its command.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Verdict {
    /// Send it.
    Send(Command),
    /// Send this instead (the original is counted as rejected for the reason).
    Replace(Command, Reject),
    /// Send nothing (counted as rejected for the reason).
    Drop(Reject),
    /// Wait for another device first (without holding the port), then ask again.
    Wait(Wait),
}

/// What to wait for.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Wait {
    /// Have the throttle released, and wait until its release went out.
    ThrottleReleased,
    /// Wait until a brake release on its way has gone out (or the brake is applied
    /// again).
    BrakeReleased,
    /// Wait until a shift on its way has gone out.
    ShiftOut,
}

impl Wait {
    /// Every wait there is.
    pub(crate) const ALL: [Wait; 3] = [Wait::ThrottleReleased, Wait::BrakeReleased, Wait::ShiftOut];
}

/// The verdict on `command` for a device that plays `plays`; `waited` says the thread
/// already waited once (it then never waits again: braking goes out regardless).
/// Throttle and brake set points are fractions of their range's top. Every refusal is
/// a rule of [`breaks`], the same function intake asks; the waits are the wire's own
/// ordering of two pedals' threads (braking first has the throttle released, a release
/// or a throttle waits for what is on its way), never a refusal.
pub(crate) fn verdict(
    f: &Facts,
    rules: Rules,
    plays: Plays,
    command: Command,
    waited: bool,
) -> Verdict {
    let broken = |r: Reject, f: &Facts| rules.has(r) && breaks(r, f, plays, command);
    match command {
        Command::Set(v) if plays.throttle && v > RELEASED => {
            // The brake applied, a release on its way or not: throttle that follows a
            // release (one `accel` from braking) waits for it once; otherwise, or if it
            // did not land, it goes out as 0.
            let applied = Facts {
                brake_releasing: false,
                ..*f
            };
            if broken(Reject::GasWhileBraking, &applied) {
                if f.brake_releasing && !waited {
                    Verdict::Wait(Wait::BrakeReleased)
                } else {
                    Verdict::Replace(Command::Set(0.0), Reject::GasWhileBraking)
                }
            } else if broken(Reject::GasEstop, f) {
                Verdict::Replace(Command::Set(0.0), Reject::GasEstop)
            } else {
                Verdict::Send(command)
            }
        }
        Command::Set(v) if plays.brake => {
            if !waited && rules.has(Reject::GasWhileBraking) && v > RELEASED && !f.throttle_released
            {
                Verdict::Wait(Wait::ThrottleReleased)
            } else if !waited
                && broken(
                    Reject::BrakeReleaseShifting,
                    &Facts {
                        shifting: f.shift_on_its_way,
                        ..*f
                    },
                )
            {
                // A shift on its way keeps the brake on until it is out: the rule of
                // intake, over the shift the wire sees.
                Verdict::Wait(Wait::ShiftOut)
            } else if broken(Reject::BrakeReleaseEstop, f) {
                // The e-stop paused between intake and the wire: the release (and the
                // throttle behind it, which then sees the brake applied) stays back.
                Verdict::Drop(Reject::BrakeReleaseEstop)
            } else {
                // Braking is never refused.
                Verdict::Send(command)
            }
        }
        Command::State(_) if plays.gear => {
            match [Reject::ShiftWhileMoving, Reject::ShiftWithoutBrake]
                .into_iter()
                .find(|r| broken(*r, f))
            {
                Some(r) => Verdict::Drop(r),
                None => Verdict::Send(command),
            }
        }
        _ => Verdict::Send(command),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::value::EstopState;

    fn calm() -> Facts {
        Facts {
            brake_high: Some(0.0),
            brake_low: Some(0.0),
            estop: Some(EstopState::Run),
            gear: Some(3),
            speed: Some(0.0),
            ..Facts::default()
        }
    }

    #[test]
    fn gas_against_a_brake_on_the_wire_goes_out_as_zero() {
        let f = Facts {
            brake_high: Some(0.5),
            ..calm()
        };
        assert_eq!(
            verdict(&f, Rules::ALL, Plays::THROTTLE, Command::Set(0.4), false),
            Verdict::Replace(Command::Set(0.0), Reject::GasWhileBraking)
        );
        assert_eq!(
            verdict(
                &calm(),
                Rules::ALL,
                Plays::THROTTLE,
                Command::Set(0.4),
                false
            ),
            Verdict::Send(Command::Set(0.4))
        );
    }

    #[test]
    fn throttle_behind_a_release_on_its_way_waits_for_it_once() {
        let f = Facts {
            brake_high: Some(1.0),
            brake_releasing: true,
            ..calm()
        };
        assert_eq!(
            verdict(&f, Rules::ALL, Plays::THROTTLE, Command::Set(0.4), false),
            Verdict::Wait(Wait::BrakeReleased)
        );
        assert_eq!(
            verdict(&f, Rules::ALL, Plays::THROTTLE, Command::Set(0.4), true),
            Verdict::Replace(Command::Set(0.0), Reject::GasWhileBraking),
            "the release did not land: no throttle"
        );
    }

    /// A brake at exactly [`RELEASED`] is a release: it does not wait for the throttle.
    /// Only a brake waits for the throttle: a steering command beside gas on its way
    /// goes out at once.
    #[test]
    fn only_braking_waits_for_the_gas_released() {
        let gas_on = Facts {
            throttle_released: false,
            ..calm()
        };
        let at = Command::Set(RELEASED);
        assert_eq!(
            verdict(&gas_on, Rules::ALL, Plays::BRAKE, at, false),
            Verdict::Send(at)
        );
        let steer = Plays::of(&[crate::config::Role::Steering]);
        assert_eq!(
            verdict(&gas_on, Rules::ALL, steer, Command::Set(0.5), false),
            Verdict::Send(Command::Set(0.5))
        );
    }

    #[test]
    fn braking_first_has_the_gas_released_and_is_never_refused() {
        let f = Facts {
            throttle_released: false,
            ..calm()
        };
        assert_eq!(
            verdict(&f, Rules::ALL, Plays::BRAKE, Command::Set(1.0), false),
            Verdict::Wait(Wait::ThrottleReleased)
        );
        assert_eq!(
            verdict(&f, Rules::ALL, Plays::BRAKE, Command::Set(1.0), true),
            Verdict::Send(Command::Set(1.0))
        );
    }

    #[test]
    fn a_brake_release_waits_for_a_real_shift_only() {
        let shifting = Facts {
            shift_on_its_way: true,
            ..calm()
        };
        assert_eq!(
            verdict(
                &shifting,
                Rules::ALL,
                Plays::BRAKE,
                Command::Set(0.0),
                false
            ),
            Verdict::Wait(Wait::ShiftOut)
        );
        assert_eq!(
            verdict(&calm(), Rules::ALL, Plays::BRAKE, Command::Set(0.0), false),
            Verdict::Send(Command::Set(0.0)),
            "a no-op shift holds nothing"
        );
    }

    #[test]
    fn a_shift_that_became_unsafe_is_dropped() {
        let moving = Facts {
            speed: Some(3.0),
            brake_low: Some(1.0),
            brake_high: Some(1.0),
            ..calm()
        };
        assert_eq!(
            verdict(&moving, Rules::ALL, Plays::GEAR, Command::State(0), false),
            Verdict::Drop(Reject::ShiftWhileMoving)
        );
        let releasing = Facts {
            brake_low: Some(0.1),
            brake_high: Some(1.0),
            ..calm()
        };
        assert_eq!(
            verdict(
                &releasing,
                Rules::ALL,
                Plays::GEAR,
                Command::State(0),
                false
            ),
            Verdict::Drop(Reject::ShiftWithoutBrake)
        );
    }
}
