//! The last check, made by a command thread right before its command goes on the
//! wire, against what the other actuators have pending, in flight or already on the
//! wire. Intake checked the same rules, but throttle and brake have threads of their
//! own, so a brake command submitted a moment after a throttle command could otherwise
//! reach its device first. Each thread has put its own command in flight before it
//! looks at the others', so of two racing threads at least one sees the other.
//!
//! [`verdict`] is a pure function of what the other devices' slots and caches hold
//! ([`WireFacts`]); the engine gathers them, asks, and acts. A wait happens before the
//! command thread takes its port, so no port is held while another device is awaited.

use super::rules::{Plays, Reject, Rules, RELEASED, SHIFT_BRAKE, STOPPED};
use crate::value::{Command, EstopState};

/// What the wire check knows. Throttle and brake as fractions of their range's top.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct WireFacts {
    /// The brake has, or is about to have, more than released: the highest value
    /// pending, in flight or last sent.
    pub brake_high: Option<f64>,
    /// The lowest brake value pending, in flight, sent or acknowledged.
    pub brake_low: Option<f64>,
    /// The brake's newest command on its way (pending, else in flight) releases it.
    pub brake_releasing: bool,
    /// The throttle has a value above released pending or in flight.
    pub throttle_going: bool,
    /// The throttle has nothing above released pending, in flight or last sent.
    pub throttle_released: bool,
    pub estop: Option<EstopState>,
    /// The gear reported.
    pub gear: Option<u8>,
    /// A gear command is pending or in flight for the gearbox that is not the last one
    /// sent.
    pub shift_on_its_way: bool,
    pub speed: Option<f64>,
}

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

/// The verdict on `command` for a device that plays `plays`; `waited` says the thread
/// already waited once (it then never waits again: braking goes out regardless).
/// Throttle and brake set points are fractions of their range's top.
pub fn verdict(
    f: &WireFacts,
    rules: Rules,
    plays: Plays,
    command: Command,
    waited: bool,
) -> Verdict {
    let on = |r: Reject| rules.has(r);
    match command {
        Command::Set(v) if plays.throttle && v > RELEASED => {
            if on(Reject::GasWhileBraking) && f.brake_high.is_some_and(|b| b > RELEASED) {
                // Throttle that follows a release on its way (one `accel` from braking)
                // waits for it once; otherwise, or if it did not land, it goes out as 0.
                if f.brake_releasing && !waited {
                    Verdict::Wait(Wait::BrakeReleased)
                } else {
                    Verdict::Replace(Command::Set(0.0), Reject::GasWhileBraking)
                }
            } else if on(Reject::GasEstop) && f.estop != Some(EstopState::Run) {
                Verdict::Replace(Command::Set(0.0), Reject::GasEstop)
            } else {
                Verdict::Send(command)
            }
        }
        Command::Set(v) if plays.brake => {
            if !waited && on(Reject::GasWhileBraking) && v > RELEASED && !f.throttle_released {
                Verdict::Wait(Wait::ThrottleReleased)
            } else if !waited
                && on(Reject::BrakeReleaseShifting)
                && v < SHIFT_BRAKE
                && f.shift_on_its_way
            {
                // A shift on its way keeps the brake on until it is out.
                Verdict::Wait(Wait::ShiftOut)
            } else {
                // Braking is never refused.
                Verdict::Send(command)
            }
        }
        Command::State(g) if plays.gear && Some(g) != f.gear => {
            if on(Reject::ShiftWhileMoving) && !f.speed.is_some_and(|s| s.abs() < STOPPED) {
                Verdict::Drop(Reject::ShiftWhileMoving)
            } else if on(Reject::ShiftWithoutBrake)
                && !f.brake_low.is_some_and(|b| b >= SHIFT_BRAKE)
            {
                Verdict::Drop(Reject::ShiftWithoutBrake)
            } else {
                Verdict::Send(command)
            }
        }
        _ => Verdict::Send(command),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const GAS: Plays = Plays {
        throttle: true,
        brake: false,
        gear: false,
        starter: false,
    };
    const BRAKE: Plays = Plays {
        throttle: false,
        brake: true,
        gear: false,
        starter: false,
    };
    const GEAR: Plays = Plays {
        throttle: false,
        brake: false,
        gear: true,
        starter: false,
    };

    fn calm() -> WireFacts {
        WireFacts {
            brake_high: Some(0.0),
            brake_low: Some(0.0),
            brake_releasing: false,
            throttle_going: false,
            throttle_released: true,
            estop: Some(EstopState::Run),
            gear: Some(3),
            shift_on_its_way: false,
            speed: Some(0.0),
        }
    }

    #[test]
    fn gas_against_a_brake_on_the_wire_goes_out_as_zero() {
        let f = WireFacts {
            brake_high: Some(0.5),
            ..calm()
        };
        assert_eq!(
            verdict(&f, Rules::ALL, GAS, Command::Set(0.4), false),
            Verdict::Replace(Command::Set(0.0), Reject::GasWhileBraking)
        );
        assert_eq!(
            verdict(&calm(), Rules::ALL, GAS, Command::Set(0.4), false),
            Verdict::Send(Command::Set(0.4))
        );
    }

    #[test]
    fn throttle_behind_a_release_on_its_way_waits_for_it_once() {
        let f = WireFacts {
            brake_high: Some(1.0),
            brake_releasing: true,
            ..calm()
        };
        assert_eq!(
            verdict(&f, Rules::ALL, GAS, Command::Set(0.4), false),
            Verdict::Wait(Wait::BrakeReleased)
        );
        assert_eq!(
            verdict(&f, Rules::ALL, GAS, Command::Set(0.4), true),
            Verdict::Replace(Command::Set(0.0), Reject::GasWhileBraking),
            "the release did not land: no throttle"
        );
    }

    #[test]
    fn braking_first_has_the_gas_released_and_is_never_refused() {
        let f = WireFacts {
            throttle_released: false,
            ..calm()
        };
        assert_eq!(
            verdict(&f, Rules::ALL, BRAKE, Command::Set(1.0), false),
            Verdict::Wait(Wait::ThrottleReleased)
        );
        assert_eq!(
            verdict(&f, Rules::ALL, BRAKE, Command::Set(1.0), true),
            Verdict::Send(Command::Set(1.0))
        );
    }

    #[test]
    fn a_brake_release_waits_for_a_real_shift_only() {
        let shifting = WireFacts {
            shift_on_its_way: true,
            ..calm()
        };
        assert_eq!(
            verdict(&shifting, Rules::ALL, BRAKE, Command::Set(0.0), false),
            Verdict::Wait(Wait::ShiftOut)
        );
        assert_eq!(
            verdict(&calm(), Rules::ALL, BRAKE, Command::Set(0.0), false),
            Verdict::Send(Command::Set(0.0)),
            "a no-op shift holds nothing"
        );
    }

    #[test]
    fn a_shift_that_became_unsafe_is_dropped() {
        let moving = WireFacts {
            speed: Some(3.0),
            brake_low: Some(1.0),
            brake_high: Some(1.0),
            ..calm()
        };
        assert_eq!(
            verdict(&moving, Rules::ALL, GEAR, Command::State(0), false),
            Verdict::Drop(Reject::ShiftWhileMoving)
        );
        let releasing = WireFacts {
            brake_low: Some(0.1),
            brake_high: Some(1.0),
            ..calm()
        };
        assert_eq!(
            verdict(&releasing, Rules::ALL, GEAR, Command::State(0), false),
            Verdict::Drop(Reject::ShiftWithoutBrake)
        );
    }
}
