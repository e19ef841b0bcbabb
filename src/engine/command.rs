//! An actuator's command thread: the paper's design, kept. It sleeps on the device's
//! slot ([`crate::port::slot`]) — a device on a serial line: on its port as well
//! ([`crate::port::wake`]), so that the reply to a request written by the admitting
//! thread is what wakes it — until a command arrives, has it checked at the wire
//! ([`Gate::check_wire`]; a wait for another device it asks for, [`Gate::wait_for`],
//! happens without the port held), takes the port ([`crate::port`]) and sends the
//! newest command at once; with nothing new for `command_timeout` it sends the last one
//! again. Commands are never queued: a newer one replaces one not yet sent. A command
//! the admitting thread already wrote ([`super::fast`]) arrives with the port held: the
//! thread reads its reply and keeps the books as for its own.
//!
//! At every turn, and after every transaction, it proves its progress ([`Beat`]): the
//! next is due within [`turn_bound`]. A thread asleep on its slot legitimately waits up
//! to `command_timeout`.

use super::Gate;
use crate::config::PortRule;
use crate::port::slot::{Pending, Wake};
use crate::port::PortGuard;
use crate::safety::{facts, Verdict, Wait};
use crate::threads::Beat;
use crate::value::Command;
use crate::vehicle::stats::Stats;
use crate::vehicle::Device;
use std::sync::atomic::Ordering::Relaxed;
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

/// How long a wait at the wire for `d` may last before it gives up.
fn wire_wait(d: &Device) -> Duration {
    d.config().reply_timeout * 2 + WIRE_SLACK
}

/// The longest a command may wait at the wire for another device ([`Gate::wait_for`]):
/// the slowest of the devices waited for ([`facts::awaitable`]), none other.
pub(crate) fn longest_wire_wait(v: &crate::vehicle::Vehicle) -> Duration {
    facts::awaitable(v).map(wire_wait).max().unwrap_or_default()
}

/// How long a turn of `d`'s command thread may take: its sleep on the slot (a resend is
/// due every `command_timeout`; a command the admitting thread is writing meanwhile
/// is one transaction), the paper's rate cap, a wait at the wire for another device
/// (`wire_wait`), the wait for the port (a poll on the wire) and its own transaction.
pub(crate) fn turn_bound(d: &Device, wire_wait: Duration) -> Duration {
    d.settings().command_timeout()
        + d.config().min_command_interval.unwrap_or_default()
        + wire_wait
        + d.port().longest() * 3
}

/// What the command thread's beat needs: the beat, and the vehicle's longest wait at
/// the wire.
struct Pulse<'b> {
    beat: &'b Beat,
    wire_wait: Duration,
}

impl Pulse<'_> {
    fn turn(&self, d: &Device) {
        self.beat.turn(turn_bound(d, self.wire_wait));
    }
}

/// One actuator's command thread: wait for a command (or the resend timeout), have
/// it checked at the wire, take the port, send the newest command, keep the port for
/// a newer one that arrived meanwhile. A command the admitting thread already wrote
/// ([`crate::engine::fast`]) arrives with the port held: the thread reads its reply.
pub(crate) fn command_loop(gate: &Gate, d: &Device, beat: &Beat) {
    let mut last_sent_at: Option<Instant> = None;
    let pulse = Pulse {
        beat,
        wire_wait: longest_wire_wait(gate.vehicle()),
    };
    loop {
        pulse.turn(d);
        // 1. Something to send: a new command (in flight from now on), or the last
        //    one again. Set points and states are resent; a drive-control command
        //    (enable, home, the starter) happens once, when asked.
        let (mut job, mut fresh) = match d.slot().wait(d.settings().command_timeout()) {
            Wake::Stop => return,
            Wake::Handed(h) => {
                let Some(mut port) = d.port().resume() else {
                    // Cannot happen (a handover leaves the port held); never a reason
                    // for the thread that sends the safe state to stop.
                    tracing::error!(device = %d.name(), "a handed-over command found its port not held");
                    d.slot().finish(h.pending.command, false);
                    continue;
                };
                let job = h.pending;
                let result = h.sent.and_then(|()| port.finish_command());
                finished(
                    d,
                    job,
                    true,
                    job.command,
                    result,
                    h.first,
                    &mut last_sent_at,
                );
                // After the books: off the way from the reply to the slot.
                port.disarm_wake();
                keep_port(gate, d, port, &mut last_sent_at, &pulse);
                continue;
            }
            Wake::Command(p) => (p, true),
            Wake::Timeout | Wake::Nudge => match d.slot().resend() {
                Some(crate::value::Command::Control(_)) | None => continue,
                Some(command) => {
                    d.slot().fly(command);
                    let p = Pending {
                        command,
                        received: Instant::now(),
                    };
                    (p, false)
                }
            },
        };
        if !d.settings().command_enabled.load(Relaxed) {
            d.slot().drop_flight();
            continue;
        }
        // 2. The paper's rate cap, when configured: hold off, letting newer commands
        //    replace this one meanwhile.
        if let (Some(min), Some(t)) = (d.config().min_command_interval, last_sent_at) {
            if !d.slot().sleep_until(t + min) {
                return;
            }
            if let Some(newer) = d.slot().take_newer() {
                Stats::bump(&d.stats().superseded);
                (job, fresh) = (newer, true);
            }
        }
        if !send(gate, d, job, fresh, None, &mut last_sent_at, &pulse) {
            return;
        }
    }
}

/// Send `job` (and any newer command taken on the way): the wire check (it may replace
/// the command — gas while braking goes out as 0 — or drop it — a shift that became
/// unsafe — or first wait for another device, never while holding the port), then the
/// port (`port`, if already held), then one transaction. A newer command taken on the
/// way is checked in its turn; the port is kept for it unless it must wait. Returns
/// false once the port is stopped.
fn send<'d>(
    gate: &Gate,
    d: &'d Device,
    mut job: Pending,
    mut fresh: bool,
    mut port: Option<PortGuard<'d>>,
    last_sent_at: &mut Option<Instant>,
    pulse: &Pulse<'_>,
) -> bool {
    let mut waited = false;
    loop {
        let command = match gate.check_wire(d, job.command, waited) {
            WireStep::Send(c) => c,
            WireStep::Drop => {
                d.slot().drop_flight();
                return true;
            }
            WireStep::Wait(w) => {
                port = None;
                gate.wait_for(w);
                waited = true;
                continue;
            }
        };
        let held = match port.as_mut() {
            Some(p) => p,
            None => {
                let Some(p) = d.port().acquire_command() else {
                    return false;
                };
                let p = port.insert(p);
                // A command that arrived while we waited for the port replaces this
                // one. (The paper's thread sent the value it had cued before
                // blocking: that staleness is what its field tests saw as ~200 ms
                // stalls, so the paper rule keeps it.)
                if d.port().rule() == PortRule::Priority {
                    if let Some(newer) = d.slot().take_newer() {
                        Stats::bump(&d.stats().superseded);
                        (job, fresh, waited) = (newer, true, false);
                        continue;
                    }
                }
                p
            }
        };
        if command != job.command {
            d.slot().fly(command);
        }
        let (result, first) = held.transact(|drv, link| drv.command(link, command));
        finished(d, job, fresh, command, result, first, last_sent_at);
        pulse.turn(d);
        // Keep the port for a command that came in meanwhile.
        match newer_for_held_port(d, held) {
            Some(next) => (job, fresh, waited) = (next, true, false),
            None => return true,
        }
    }
}

/// After a handed-over transaction: keep the port for a command that came in meanwhile
/// (as [`send`] does after its own), else release it.
fn keep_port<'d>(
    gate: &Gate,
    d: &'d Device,
    port: PortGuard<'d>,
    last_sent_at: &mut Option<Instant>,
    pulse: &Pulse<'_>,
) {
    if let Some(next) = newer_for_held_port(d, &port) {
        send(gate, d, next, true, Some(port), last_sent_at, pulse);
    }
}

/// A command that came in while the port was held, to send on it next — unless an
/// overdue status poll is waiting or a rate cap applies.
fn newer_for_held_port(d: &Device, held: &PortGuard<'_>) -> Option<Pending> {
    if d.port().rule() == PortRule::Priority
        && d.config().min_command_interval.is_none()
        && !held.status_waiting()
    {
        d.slot().take_newer()
    } else {
        None
    }
}

/// The bookkeeping of one command transaction, however it went out: the recording,
/// the delay and transaction time, the slot, the counters and the device's health.
fn finished(
    d: &Device,
    job: Pending,
    fresh: bool,
    command: crate::value::Command,
    result: Result<(), crate::driver::DriverError>,
    first: Option<Instant>,
    last_sent_at: &mut Option<Instant>,
) {
    let done = Instant::now();
    d.tap_written(
        command,
        job.received,
        first,
        done,
        fresh,
        result.as_ref().err(),
    );
    if let Some(first) = first {
        if fresh {
            d.stats().command_delay.record(first - job.received);
            crate::probe::first_byte(job.received, first);
        }
        d.stats().command_txn.record(done - first);
        *last_sent_at = Some(first);
    }
    // The books first, the slot last: whoever waits on the slot for this command's end
    // (a test, the fast path's next command, characterize) then reads counts, codes and
    // health that already include it.
    let ok = result.is_ok();
    match result {
        Ok(()) => {
            d.estimate_command(command, first.unwrap_or(done));
            Stats::bump(&d.stats().executed);
            if !fresh {
                Stats::bump(&d.stats().resent);
            }
            d.health().command_error.store(0, Relaxed);
            // A frame handed to a CAN adapter is no answer from the module: only its
            // reports are (the bus reader's).
            if !d.config().on_bus() {
                d.record_ok(done);
            }
        }
        Err(e) => d.transaction_failed(&e, true),
    }
    d.slot().finish_sent(command, ok, first);
}

impl Gate {
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
        a.device.slot().wait_wire(
            |s| (a.over)(a.device, s),
            Instant::now() + wire_wait(a.device),
        );
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::safety::Reject;
    use crate::testkit as sample;
    use std::sync::Arc;

    /// The longest wait at the wire is the slowest awaited device's: two of its reply
    /// timeouts and the slack (Alice's gearbox: 200 ms twice and 50 ms; never her OBD
    /// adapter's 500 ms, a sensor no command waits for, which would loosen every
    /// command thread's watchdog by 600 ms); none on a vehicle without pedals or gears.
    #[test]
    fn the_longest_wait_at_the_wire_is_the_slowest_awaited_devices() {
        let v = crate::testkit::vehicle(Instant::now());
        assert_eq!(longest_wire_wait(&v), Duration::from_millis(450));
        let text = "[vehicle]\nname = \"t\"\n[[device]]\nname = \"steer\"\nkind = \"setpoint\"\n\
                    range = [-1.0, 1.0]\ndriver = \"line\"\nreply_timeout = \"900ms\"\nstatus_max_age = \"2s\"\n";
        let config = crate::config::parse(text, "t.toml").expect("a vehicle of one device");
        let bare = crate::testkit::vehicle_of(config, Instant::now());
        assert_eq!(longest_wire_wait(&bare), Duration::ZERO);
    }

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
            asked: None,
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
