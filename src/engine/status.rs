//! A device's status thread: poll it every `status_period` (or, with adaptive polling,
//! when the estimate needs it: [`super::polling`]), store the reading in the cache and
//! the estimator, and count. Readers (network, console, supervisor) only ever read
//! what this thread stored. The poll takes the port under the port's rule
//! ([`crate::port`]): it yields to a waiting command unless it is overdue.
//!
//! At every turn it proves its progress ([`Beat`]): the next turn is due within its
//! period, its wait for the port ([`turn_bound`]) and a transaction; once it holds the
//! port, within one transaction ([`crate::port::Port::longest`]).

use crate::threads::{Beat, StopSignal};
use crate::vehicle::stats::Stats;
use crate::vehicle::{Cached, Device};
use std::sync::atomic::Ordering::Relaxed;
use std::time::{Duration, Instant};

/// How long a turn of `d`'s status thread may take: its sleep (the status period), its
/// wait for the port (an overdue poll waits no longer than `status_max_age` for
/// commands, then for the one transaction on the wire — a sensor has no command
/// thread), and its own poll.
pub(crate) fn turn_bound(d: &Device) -> Duration {
    let txn = d.port().longest();
    let commands = if d.is_actuator() {
        d.config().status_max_age + txn
    } else {
        Duration::ZERO
    };
    d.settings().status_period() + commands + txn
}

/// `fault`: when to end, and whether by a panic (`--inject-panic`, tests only).
pub(crate) fn status_loop(
    d: &Device,
    stop: &StopSignal,
    beat: &Beat,
    fault: Option<(Instant, bool)>,
) {
    let mut next = Instant::now();
    // The first poll is due at once.
    let mut last_attempt: Option<Instant> = None;
    let mut schedule = super::polling::Schedule::default();
    loop {
        beat.turn(turn_bound(d));
        if !stop.sleep_until(next) {
            return;
        }
        if let Some((_, panic)) = fault.filter(|&(at, _)| Instant::now() >= at) {
            if panic {
                panic!("injected panic (--inject-panic {}/status)", d.name());
            }
            tracing::warn!(device = %d.name(), "status thread ends (--inject-panic, quietly)");
            return;
        }
        let period = d.settings().status_period();
        next = (next + period).max(Instant::now());
        if !d.settings().status_enabled.load(Relaxed) || !schedule.due(d, Instant::now()) {
            continue;
        }
        let overdue_at = last_attempt.map_or_else(Instant::now, |t| t + d.config().status_max_age);
        let Some(mut port) = d.port().acquire_status(overdue_at, d.slot()) else {
            return;
        };
        beat.turn(d.port().longest());
        let started = Instant::now();
        schedule.start(d, started);
        let (result, first) = port.transact(|drv, link| drv.poll(link));
        let done = Instant::now();
        drop(port);
        // The period counts from this poll: after a wait for the port (a command's
        // transaction), the wake-up due meanwhile would poll again at once and learn
        // nothing the reading just stored did not say.
        next = next.max(started + period);
        d.tap_polled(first, done, result.as_ref());
        last_attempt = Some(started);
        Stats::bump(&d.stats().polls);
        if let Some(first) = first {
            d.stats().status_txn.record(done - first);
        }
        match result {
            Ok(reading) => {
                d.store(Cached {
                    reading,
                    at: Some(done),
                    asked: first,
                });
                let correction = d.estimate_reading(&reading, done);
                schedule.finish(correction.is_some_and(|c| c.surprise));
                d.health().status_error.store(0, Relaxed);
                d.record_ok(done);
            }
            Err(e) => {
                d.transaction_failed(&e, false);
                // Nothing learnt: try again at the next wake-up.
                schedule.finish(true);
            }
        }
    }
}
