//! Dispatch: what an admitted command does to the devices. A command that passed the
//! intake ([`super::admit`]) goes on the wire from the admitting thread when its port
//! is idle ([`super::fast`]), else into the device's slot for its command thread
//! ([`crate::port::slot`], [`super::command`]). Engaging, disengaging, an operator's
//! STOP, a driver's override and every way out ([`super::engagement`]) store the safe
//! (or manual) state in the slots the same way. Right before a command goes out its
//! command thread asks [`Gate::check_wire`]; a wait it asks for ([`Gate::wait_for`])
//! happens here, without the port held.

use super::fast::{self, Sent};
use super::Gate;
use crate::safety::{facts, Verdict, Wait};
use crate::value::{Command, DeviceId};
use crate::vehicle::stats::Stats;
use crate::vehicle::tap::{Asked, Source};
use crate::vehicle::Device;
use std::time::{Duration, Instant};

/// What the command thread does with its command, by the wire check.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum WireStep {
    Send(Command),
    Drop,
    Wait(Wait),
}

/// A command thread that waits at the wire for another device's command waits at most
/// two of that device's reply timeouts (the transaction on its wire, then this one) and
/// this much more.
const WIRE_SLACK: Duration = Duration::from_millis(50);

/// When a wait at the wire for `d` gives up.
fn wire_deadline(d: &Device) -> Instant {
    Instant::now() + d.config().reply_timeout * 2 + WIRE_SLACK
}

/// The longest a command may wait at the wire for another device ([`Gate::wait_for`]).
pub(crate) fn longest_wire_wait(v: &crate::vehicle::Vehicle) -> Duration {
    v.devices()
        .iter()
        .map(|d| d.config().reply_timeout * 2 + WIRE_SLACK)
        .max()
        .unwrap_or_default()
}

impl Gate {
    /// An admitted command on its way: written from this thread when its port is idle
    /// and the wire check says send exactly it ([`fast`]) — the command thread then
    /// only reads the reply — else stored for the command thread.
    pub(super) fn dispatch(&self, d: &Device, command: Command, received: Instant) {
        crate::probe::stamp(crate::probe::Step::Checked);
        Stats::bump(&d.stats().received);
        match fast::send(self, d, command, received) {
            Sent::Written | Sent::Queued { superseded: false } => {}
            Sent::Queued { superseded: true } => Stats::bump(&d.stats().superseded),
            Sent::NotTaken => queue(d, command, received),
        }
    }

    /// Store a command for `d`'s command thread, past the interlocks (the safe state,
    /// the supervisor's own commands).
    pub(super) fn store(&self, d: &Device, command: Command, received: Instant) {
        Stats::bump(&d.stats().received);
        queue(d, command, received);
    }

    /// The supervisor's own commands: past the gate and the intake interlocks (the
    /// wire-level checks still apply).
    pub fn supervise(&self, id: DeviceId, command: Command) {
        let now = Instant::now();
        self.store(self.vehicle().device(id), command, now);
        self.tap_received(
            Source::Supervisor,
            Asked::Device(id, command),
            now,
            Ok(()),
            None,
        );
    }

    /// The wire check for the command `d`'s thread has in flight: send it (or what
    /// to send instead), drop it, or first wait for another device — which the
    /// command thread does with [`Gate::wait_for`], without holding its port, and then
    /// asks again with `waited` set (braking then goes out regardless).
    pub(crate) fn check_wire(&self, d: &Device, command: Command, waited: bool) -> WireStep {
        match self
            .state()
            .wire_verdict(self.vehicle(), d, command, waited)
        {
            Verdict::Send(c) => WireStep::Send(c),
            Verdict::Replace(c, why) => {
                self.reject(Some(d), Some(command), why);
                WireStep::Send(c)
            }
            Verdict::Drop(why) => {
                self.reject(Some(d), Some(command), why);
                WireStep::Drop
            }
            Verdict::Wait(w) => WireStep::Wait(w),
        }
    }

    /// Do what a [`WireStep::Wait`] asks ([`facts::awaited`]: first the throttle's
    /// release, where that is what it waits for), bounded by two reply timeouts of the
    /// device waited for.
    pub fn wait_for(&self, w: Wait) {
        let Some(a) = facts::awaited(self.vehicle(), w) else {
            return;
        };
        if let Some(c) = a.first {
            self.store(a.device, c, Instant::now());
        }
        a.device
            .slot()
            .wait_wire(|s| (a.over)(a.device, s), wire_deadline(a.device));
    }
}

/// Into the slot, for the command thread.
fn queue(d: &Device, command: Command, received: Instant) {
    if d.slot().submit(command, received) {
        Stats::bump(&d.stats().superseded);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::safety::Reject;
    use crate::testkit as sample;
    use std::sync::Arc;

    /// Alice's sample with the brake sent full and its release waiting in its slot.
    fn releasing() -> Arc<Gate> {
        let gate = sample::gate(Instant::now());
        let brake = gate.vehicle().find("brake").unwrap();
        brake.slot().fly(Command::Set(1.0));
        brake.slot().finish(Command::Set(1.0), true);
        brake.slot().submit(Command::Set(0.0), Instant::now());
        gate
    }

    /// Gas and brake, and a throttle command the wire check holds behind the release.
    fn throttle_behind_the_release(gate: &Gate) -> (&Device, &Device, Command) {
        let (gas, brake) = (
            gate.vehicle().find("gas").unwrap(),
            gate.vehicle().find("brake").unwrap(),
        );
        let throttle = Command::Set(0.3);
        assert_eq!(
            gate.check_wire(gas, throttle, false),
            WireStep::Wait(Wait::BrakeReleased)
        );
        (gas, brake, throttle)
    }

    /// Throttle behind a release waits for it a bounded time — two brake reply timeouts
    /// and a little — and, the release not landed, goes out as 0.
    #[test]
    fn throttle_behind_a_release_that_never_lands_goes_out_as_zero() {
        let gate = releasing();
        let (gas, brake, throttle) = throttle_behind_the_release(&gate);
        let t = Instant::now();
        gate.wait_for(Wait::BrakeReleased);
        assert!(t.elapsed() >= brake.config().reply_timeout * 2 + WIRE_SLACK);
        assert_eq!(
            gate.check_wire(gas, throttle, true),
            WireStep::Send(Command::Set(0.0))
        );
    }

    /// Alice's sample engaged in drive (shifted, acknowledged, and reported by a status
    /// taken after that): its gearbox, its brake and the drive command.
    fn in_drive(gate: &Gate) -> (&Device, &Device, Command) {
        let v = gate.vehicle();
        let (trans, brake) = (v.find("trans").unwrap(), v.find("brake").unwrap());
        let drive = Command::State(trans.config().state_index("drive").unwrap());
        trans.slot().fly(drive);
        trans.slot().finish(drive, true);
        trans.store(crate::vehicle::Cached {
            reading: {
                let mut r = crate::value::Reading::default();
                r.set(0, 3.0);
                r
            },
            at: Some(Instant::now()),
        });
        gate.engage("test").unwrap();
        (trans, brake, drive)
    }

    /// The incident: a planner repeats `trans drive` in every datagram (the README's own
    /// example does). In drive, with the repeat pending in the gearbox's slot, a brake
    /// release waited up to 450 ms at the wire for that slot to drain although no
    /// shift was under way; brake commands executed per second halved. A gear command
    /// that repeats the last one sent is not a shift: the release goes out at once,
    /// from intake to the wire. (A real shift still holds it: the test after this.)
    #[test]
    fn a_repeated_trans_drive_does_not_hold_a_brake_release() {
        let gate = sample::gate(Instant::now());
        let (trans, brake, drive) = in_drive(&gate);
        // The planner's datagram: `trans drive` again, and the brake released.
        gate.submit(trans.id(), drive, Instant::now()).unwrap();
        let release = Command::Set(0.0);
        assert_eq!(gate.submit(brake.id(), release, Instant::now()), Ok(()));
        assert_eq!(
            gate.check_wire(brake, release, false),
            WireStep::Send(release),
            "the release must not wait for the repeated gear command"
        );
    }

    /// A real shift on its way (a gear other than the last one sent) still keeps the
    /// brake on until it is out.
    #[test]
    fn a_shift_on_its_way_holds_a_brake_release() {
        let gate = sample::gate(Instant::now());
        let v = &gate.vehicle();
        let (trans, brake) = (v.find("trans").unwrap(), v.find("brake").unwrap());
        let drive = Command::State(trans.config().state_index("drive").unwrap());
        trans.slot().submit(drive, Instant::now());
        assert_eq!(
            gate.check_wire(brake, Command::Set(0.0), false),
            WireStep::Wait(Wait::ShiftOut)
        );
    }

    /// Braking first has the throttle released: a throttle command still on its way
    /// when the brake's thread waits for it is replaced by the throttle's release — it
    /// never reaches the wire — and the wait is over at once, not at its bound.
    #[test]
    fn braking_first_has_a_throttle_on_its_way_released() {
        let gate = sample::gate(Instant::now());
        let v = gate.vehicle();
        let (gas, brake) = (v.find("gas").unwrap(), v.find("brake").unwrap());
        gas.slot().submit(Command::Set(0.4), Instant::now());
        assert_eq!(
            gate.check_wire(brake, Command::Set(1.0), false),
            WireStep::Wait(Wait::ThrottleReleased)
        );
        let t = Instant::now();
        gate.wait_for(Wait::ThrottleReleased);
        assert_eq!(gas.slot().wire().pending, Some(Command::Set(0.0)));
        assert!(
            t.elapsed() < gas.config().reply_timeout * 2,
            "released at once; the wait did not run to its bound"
        );
    }

    /// A brake release held behind a shift waits until the gear command has gone out,
    /// and no longer.
    #[test]
    fn a_release_behind_a_shift_waits_until_the_shift_is_out() {
        let gate = sample::gate(Instant::now());
        let v = gate.vehicle();
        let trans = v.find("trans").unwrap();
        let drive = Command::State(trans.config().state_index("drive").unwrap());
        trans.slot().submit(drive, Instant::now());
        let t = Instant::now();
        std::thread::scope(|s| {
            // The gearbox's command thread sends the shift.
            s.spawn(|| {
                let p = trans.slot().take_newer().expect("the shift");
                trans.slot().finish(p.command, true);
            });
            gate.wait_for(Wait::ShiftOut);
        });
        assert_eq!(trans.slot().sent(), Some(drive));
        assert!(
            t.elapsed() < trans.config().reply_timeout * 2,
            "over once the shift was out, not at the wait's bound"
        );
    }

    /// The incident (the interlock property, on a loaded machine): in drive, braked, a
    /// shift to reverse was on the wire and `trans drive` pending behind it; the
    /// pending command, the gear reported, hid the shift in flight. An `accel` then
    /// released the brake at once, and `drive` went out after it with the brake at 0:
    /// a command to the gear reported was no shift, though the gearbox was on its way
    /// to reverse. Every gear command on its way counts: the `accel` is refused while
    /// the shift is under way, a release waits for it at the wire, and `drive` behind `reverse` is a
    /// shift that needs the brake.
    #[test]
    fn a_shift_in_flight_behind_a_command_to_the_gear_reported_is_still_a_shift() {
        let gate = sample::gate(Instant::now());
        let (trans, brake, drive) = in_drive(&gate);
        let reverse = Command::State(trans.config().state_index("reverse").unwrap());
        brake.slot().fly(Command::Set(0.8));
        brake.slot().finish(Command::Set(0.8), true);
        // `reverse` written (in flight), `drive` pending behind it.
        trans.slot().fly(reverse);
        trans.slot().submit(drive, Instant::now());
        let before = brake.slot().wire();
        assert_eq!(
            gate.submit_accel(0.4, Instant::now()),
            Err(Reject::AccelWhileShifting)
        );
        assert_eq!(brake.slot().wire(), before, "the accel held the brake");
        assert_eq!(
            gate.submit(brake.id(), Command::Set(0.0), Instant::now()),
            Err(Reject::BrakeReleaseShifting)
        );
        assert_eq!(
            gate.check_wire(brake, Command::Set(0.0), false),
            WireStep::Wait(Wait::ShiftOut)
        );
        // `reverse` went out; had the brake been released meanwhile, `drive` is dropped.
        trans.slot().finish(reverse, true);
        brake.slot().fly(Command::Set(0.0));
        brake.slot().finish(Command::Set(0.0), true);
        brake.slot().reset(None);
        assert_eq!(trans.slot().take_newer().map(|p| p.command), Some(drive));
        trans.slot().fly(drive);
        assert_eq!(gate.check_wire(trans, drive, false), WireStep::Drop);
    }

    /// The release lands while the throttle waits: the throttle goes out as it is.
    #[test]
    fn throttle_behind_a_release_that_lands_goes_out() {
        let gate = releasing();
        let (gas, brake, throttle) = throttle_behind_the_release(&gate);
        std::thread::scope(|s| {
            s.spawn(|| {
                brake.slot().take_newer().expect("the release");
                brake.slot().fly(Command::Set(0.0));
                brake.slot().finish(Command::Set(0.0), true);
            });
            gate.wait_for(Wait::BrakeReleased);
        });
        assert_eq!(
            gate.check_wire(gas, throttle, true),
            WireStep::Send(throttle)
        );
    }
}
