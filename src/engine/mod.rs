//! The engine: two threads per actuator, one per sensor, over the shared
//! [`Vehicle`].
//!
//! - The **status thread** polls its device every `status_period` (or, with adaptive
//!   polling, when the estimate needs it: [`polling`]) and stores the reading in the
//!   cache and the estimator. Readers (network, console, supervisor) only read them.
//! - The **command thread** sleeps on its slot ([`crate::vehicle::slot`]) until a
//!   command arrives, then sends
//!   the latest one at once; with nothing new for `command_timeout` it sends the last
//!   one again. Commands are never queued.
//! - Both share the device's port ([`crate::vehicle::port`]) under adrive's priority
//!   rule (or the paper's).
//! - Right before a command goes out, the command thread asks the safety rules'
//!   wire check ([`Gate::check_wire`]); a wait it asks for (braking waits for the
//!   throttle's release to go out) happens without the port held.
//! - A command that found its port idle was written by the thread that admitted it
//!   ([`crate::vehicle::fast`]): the command thread wakes to the transaction with the
//!   port held, reads the reply and keeps the books as for its own.
//!
//! Every thread is named `<device>/status` or `<device>/command`, stops when told, and
//! [`Engine::shutdown`] joins them with a deadline and names any that did not stop;
//! [`Engine::liveness`] tells whether each still runs (the service watchdog is fed
//! only while all do).
//! Command threads run where the vehicle file's [`placement`] puts the command path.

pub mod placement;

pub mod polling;

use crate::config::PortRule;
use crate::safety::{Gate, WireStep};
use crate::threads::{Liveness, StopSignal, Threads};
use crate::vehicle::port::PortGuard;
use crate::vehicle::slot::{Pending, Wake};
use crate::vehicle::stats::Stats;
use crate::vehicle::{Cached, Device, Vehicle};
use std::sync::atomic::Ordering::Relaxed;
use std::sync::Arc;
use std::time::{Duration, Instant};

/// The running engine.
pub struct Engine {
    gate: Arc<Gate>,
    stop: Arc<StopSignal>,
    threads: Threads,
    stopped: bool,
}

/// Fault injection for tests (`--inject-panic steer/status:3s`): a device's status
/// thread panics, or ends as if it had returned by mistake, once running this long.
#[derive(Clone, Debug)]
pub struct Injected {
    /// The thread, `<device>/status`.
    pub thread: String,
    pub after: Duration,
    /// Panic (else return quietly).
    pub panic: bool,
}

impl Engine {
    /// Start the status thread of every device and the command thread of every actuator.
    pub fn start(gate: Arc<Gate>) -> std::io::Result<Engine> {
        Engine::start_injected(gate, None)
    }

    /// [`Engine::start`], with a fault injected into one thread.
    pub fn start_injected(gate: Arc<Gate>, inject: Option<Injected>) -> std::io::Result<Engine> {
        let stop = Arc::new(StopSignal::default());
        let mut threads = Threads::default();
        let vehicle = gate.vehicle.clone();
        for i in 0..vehicle.devices.len() {
            let name = vehicle.devices[i].name().to_string();
            let (v, s) = (vehicle.clone(), stop.clone());
            let thread = format!("{name}/status");
            let fault = inject.clone().filter(|f| f.thread == thread);
            threads.spawn(thread, move || {
                let fault = fault.map(|f| (Instant::now() + f.after, f.panic));
                status_loop(&v.devices[i], &s, fault)
            })?;
            if vehicle.devices[i].is_actuator() {
                let g = gate.clone();
                threads.spawn(format!("{name}/command"), move || {
                    placement::apply(&g.vehicle.config.vehicle.placement);
                    command_loop(&g, &g.vehicle.devices[i])
                })?;
            }
        }
        Ok(Engine {
            gate,
            stop,
            threads,
            stopped: false,
        })
    }

    pub fn gate(&self) -> &Arc<Gate> {
        &self.gate
    }

    pub fn vehicle(&self) -> &Arc<Vehicle> {
        &self.gate.vehicle
    }

    pub fn thread_names(&self) -> Vec<&str> {
        self.threads.names()
    }

    /// Whether each device thread runs.
    pub fn liveness(&self) -> Liveness {
        self.threads.liveness()
    }

    /// Bring the vehicle to the safe state, then stop and join every thread.
    /// Returns whether the safe state was acknowledged and which threads did not stop.
    pub fn shutdown(mut self, deadline: Duration) -> (bool, Vec<String>) {
        self.stop_all(deadline)
    }

    fn stop_all(&mut self, deadline: Duration) -> (bool, Vec<String>) {
        self.stopped = true;
        let end = Instant::now() + deadline;
        // Refuse every command from here on, then the safe state.
        self.gate.disengage("stopping");
        self.gate.command_safe_state();
        let safe = self.gate.wait_safe(Instant::now() + deadline / 2);
        self.stop.stop();
        for d in &self.gate.vehicle.devices {
            d.slot.stop();
            d.port.stop();
        }
        (safe, std::mem::take(&mut self.threads).join(end))
    }
}

/// An engine dropped without [`Engine::shutdown`] — e.g. while a panic unwinds the
/// thread that owns it — still commands the safe state before its threads stop.
impl Drop for Engine {
    fn drop(&mut self) {
        if !self.stopped {
            tracing::error!("engine dropped without shutdown: commanding the safe state");
            let (safe, _) = self.stop_all(Duration::from_secs(2));
            if safe {
                tracing::info!("safe state acknowledged");
            }
        }
    }
}

/// `fault`: when to end, and whether by a panic (`--inject-panic`, tests only).
fn status_loop(d: &Device, stop: &StopSignal, fault: Option<(Instant, bool)>) {
    let mut next = Instant::now();
    // The first poll is due at once.
    let mut last_attempt: Option<Instant> = None;
    let mut schedule = polling::Schedule::default();
    loop {
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
        let period = d.settings.status_period();
        next = (next + period).max(Instant::now());
        if !d.settings.status_enabled.load(Relaxed) || !schedule.due(d, Instant::now()) {
            continue;
        }
        let overdue_at = last_attempt.map_or_else(Instant::now, |t| t + d.config.status_max_age);
        let Some(mut port) = d.port.acquire_status(overdue_at, &d.slot) else {
            return;
        };
        let started = Instant::now();
        schedule.start(d, started);
        let (result, first) = port.transact(|drv, link| drv.poll(link));
        let done = Instant::now();
        drop(port);
        d.tap_polled(first, done, result.as_ref());
        last_attempt = Some(started);
        Stats::bump(&d.stats.polls);
        if let Some(first) = first {
            d.stats.status_txn.record(done - first);
        }
        match result {
            Ok(reading) => {
                *d.cache.lock() = Cached {
                    reading,
                    at: Some(done),
                };
                let correction = d.estimate_reading(&reading, done);
                schedule.finish(correction.is_some_and(|c| c.surprise));
                d.health.status_error.store(0, Relaxed);
                d.record_ok(done);
            }
            Err(e) => {
                Stats::bump(&d.stats.status_errors);
                d.record_error(&e, false);
                // Nothing learnt: try again at the next wake-up.
                schedule.finish(true);
            }
        }
    }
}

/// One actuator's command thread: wait for a command (or the resend timeout), have
/// it checked at the wire, take the port, send the newest command, keep the port for
/// a newer one that arrived meanwhile. A command the admitting thread already wrote
/// ([`crate::vehicle::fast`]) arrives with the port held: the thread reads its reply.
fn command_loop(gate: &Gate, d: &Device) {
    let mut last_sent_at: Option<Instant> = None;
    loop {
        // 1. Something to send: a new command (in flight from now on), or the last
        //    one again. Set points and states are resent; a drive-control command
        //    (enable, home, the starter) happens once, when asked.
        let (mut job, mut fresh) = match d.slot.wait(d.settings.command_timeout()) {
            Wake::Stop => return,
            Wake::Handed(h) => {
                let Some(mut port) = d.port.resume() else {
                    // Cannot happen (a handover leaves the port held); never a reason
                    // for the thread that sends the safe state to stop.
                    tracing::error!(device = %d.name(), "a handed-over command found its port not held");
                    d.slot.finish(h.pending.command, false);
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
                keep_port(gate, d, port, &mut last_sent_at);
                continue;
            }
            Wake::Command(p) => (p, true),
            Wake::Timeout | Wake::Nudge => match d.slot.resend() {
                Some(crate::value::Command::Control(_)) | None => continue,
                Some(command) => {
                    d.slot.fly(command);
                    let p = Pending {
                        command,
                        received: Instant::now(),
                    };
                    (p, false)
                }
            },
        };
        if !d.settings.command_enabled.load(Relaxed) {
            d.slot.drop_flight();
            continue;
        }
        // 2. The paper's rate cap, when configured: hold off, letting newer commands
        //    replace this one meanwhile.
        if let (Some(min), Some(t)) = (d.config.min_command_interval, last_sent_at) {
            if !d.slot.sleep_until(t + min) {
                return;
            }
            if let Some(newer) = d.slot.take_newer() {
                Stats::bump(&d.stats.superseded);
                (job, fresh) = (newer, true);
            }
        }
        if !send(gate, d, job, fresh, None, &mut last_sent_at) {
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
) -> bool {
    let mut waited = false;
    loop {
        let command = match gate.check_wire(d, job.command, waited) {
            WireStep::Send(c) => c,
            WireStep::Drop => {
                d.slot.drop_flight();
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
                let Some(p) = d.port.acquire_command() else {
                    return false;
                };
                let p = port.insert(p);
                // A command that arrived while we waited for the port replaces this
                // one. (The paper's thread sent the value it had cued before
                // blocking: that staleness is what its field tests saw as ~200 ms
                // stalls, so the paper rule keeps it.)
                if d.port.rule() == PortRule::Priority {
                    if let Some(newer) = d.slot.take_newer() {
                        Stats::bump(&d.stats.superseded);
                        (job, fresh, waited) = (newer, true, false);
                        continue;
                    }
                }
                p
            }
        };
        if command != job.command {
            d.slot.fly(command);
        }
        let (result, first) = held.transact(|drv, link| drv.command(link, command));
        finished(d, job, fresh, command, result, first, last_sent_at);
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
) {
    if let Some(next) = newer_for_held_port(d, &port) {
        send(gate, d, next, true, Some(port), last_sent_at);
    }
}

/// A command that came in while the port was held, to send on it next — unless an
/// overdue status poll is waiting or a rate cap applies.
fn newer_for_held_port(d: &Device, held: &PortGuard<'_>) -> Option<Pending> {
    if d.port.rule() == PortRule::Priority
        && d.config.min_command_interval.is_none()
        && !held.status_waiting()
    {
        d.slot.take_newer()
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
            d.stats.command_delay.record(first - job.received);
            crate::probe::first_byte(job.received, first);
        }
        d.stats.command_txn.record(done - first);
        *last_sent_at = Some(first);
    }
    d.slot.finish(command, result.is_ok());
    match result {
        Ok(()) => {
            d.estimate_command(command, first.unwrap_or(done));
            Stats::bump(&d.stats.executed);
            if !fresh {
                Stats::bump(&d.stats.resent);
            }
            d.health.command_error.store(0, Relaxed);
            d.record_ok(done);
        }
        Err(e) => {
            Stats::bump(&d.stats.command_errors);
            d.record_error(&e, true);
        }
    }
}
