//! An actuator's command thread: the paper's design, kept. It sleeps on the device's
//! slot ([`crate::port::slot`]) until a command arrives, has it checked at the wire
//! ([`crate::engine::Gate::check_wire`]), takes the port ([`crate::port`]) and sends the
//! newest command at once; with nothing new for `command_timeout` it sends the last one
//! again. Commands are never queued: a newer one replaces one not yet sent. A command
//! the admitting thread already wrote ([`super::fast`]) arrives with the port held: the
//! thread reads its reply and keeps the books as for its own.
//!
//! At every turn, and after every transaction, it proves its progress ([`Beat`]): the
//! next is due within [`turn_bound`]. A thread asleep on its slot legitimately waits up
//! to `command_timeout`.

use super::{Gate, WireStep};
use crate::config::PortRule;
use crate::port::slot::{Pending, Wake};
use crate::port::PortGuard;
use crate::threads::Beat;
use crate::vehicle::stats::Stats;
use crate::vehicle::Device;
use std::sync::atomic::Ordering::Relaxed;
use std::time::{Duration, Instant};

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
        wire_wait: super::dispatch::longest_wire_wait(gate.vehicle()),
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
    d.slot().finish(command, result.is_ok());
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
        Err(e) => {
            Stats::bump(&d.stats().command_errors);
            d.record_error(&e, true);
        }
    }
}
