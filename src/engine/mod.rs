//! The engine: two threads per actuator, one per sensor, over the shared
//! [`Vehicle`].
//!
//! - The **status thread** polls its device every `status_period` and stores the
//!   reading in the cache. Readers (network, console, supervisor) only read the cache.
//! - The **command thread** sleeps on its [`slot`] until a command arrives, then sends
//!   the latest one at once; with nothing new for `command_timeout` it sends the last
//!   one again. Commands are never queued.
//! - Both share the device's [`port`] under adrive's priority rule (or the paper's).
//!
//! Every thread is named `<device>/status` or `<device>/command`, stops when told, and
//! [`Engine::shutdown`] joins them with a deadline and names any that did not stop.

pub mod port;
pub mod slot;
pub mod stats;
pub mod trace;

use crate::config::PortRule;
use crate::engine::slot::{Pending, Wake};
use crate::engine::stats::Stats;
use crate::value::Command;
use crate::vehicle::{Device, Vehicle};
use parking_lot::{Condvar, Mutex};
use std::sync::atomic::Ordering::Relaxed;
use std::sync::Arc;
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

/// A stop signal that sleeping threads wake up for.
#[derive(Default)]
pub struct StopSignal {
    stopped: Mutex<bool>,
    cv: Condvar,
}

impl StopSignal {
    pub fn stop(&self) {
        *self.stopped.lock() = true;
        self.cv.notify_all();
    }
    pub fn is_stopped(&self) -> bool {
        *self.stopped.lock()
    }
    /// Sleep until `until`; false if stopped meanwhile.
    pub fn sleep_until(&self, until: Instant) -> bool {
        let mut s = self.stopped.lock();
        while !*s && Instant::now() < until {
            self.cv.wait_until(&mut s, until);
        }
        !*s
    }
}

/// Named threads with a stop signal, joined with a deadline.
#[derive(Default)]
pub struct Threads {
    handles: Vec<(String, JoinHandle<()>)>,
}

impl Threads {
    pub fn spawn(
        &mut self,
        name: String,
        f: impl FnOnce() + Send + 'static,
    ) -> std::io::Result<()> {
        let h = std::thread::Builder::new().name(name.clone()).spawn(f)?;
        self.handles.push((name, h));
        Ok(())
    }

    pub fn names(&self) -> Vec<&str> {
        self.handles.iter().map(|(n, _)| n.as_str()).collect()
    }

    /// Join every thread, waiting at most until `deadline`; returns the names of those
    /// still running (and logs them).
    pub fn join(self, deadline: Instant) -> Vec<String> {
        let mut stuck = Vec::new();
        for (name, h) in self.handles {
            while !h.is_finished() && Instant::now() < deadline {
                std::thread::sleep(Duration::from_millis(2));
            }
            if h.is_finished() {
                if h.join().is_err() {
                    tracing::error!(thread = %name, "thread panicked");
                }
            } else {
                tracing::error!(thread = %name, "thread did not stop in time");
                stuck.push(name);
            }
        }
        stuck
    }
}

/// The running engine.
pub struct Engine {
    vehicle: Arc<Vehicle>,
    stop: Arc<StopSignal>,
    threads: Threads,
    stopped: bool,
}

impl Engine {
    /// Start the status thread of every device and the command thread of every actuator.
    pub fn start(vehicle: Arc<Vehicle>) -> std::io::Result<Engine> {
        let stop = Arc::new(StopSignal::default());
        let mut threads = Threads::default();
        for i in 0..vehicle.devices.len() {
            let role = vehicle.devices[i].role;
            let (v, s) = (vehicle.clone(), stop.clone());
            threads.spawn(format!("{role}/status"), move || {
                status_loop(&v.devices[i], &s)
            })?;
            if vehicle.devices[i].is_actuator() {
                let v = vehicle.clone();
                threads.spawn(format!("{role}/command"), move || {
                    command_loop(&v, &v.devices[i])
                })?;
            }
        }
        Ok(Engine {
            vehicle,
            stop,
            threads,
            stopped: false,
        })
    }

    pub fn vehicle(&self) -> &Arc<Vehicle> {
        &self.vehicle
    }

    pub fn thread_names(&self) -> Vec<&str> {
        self.threads.names()
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
        self.vehicle.disengage("stopping");
        self.vehicle.command_safe_state();
        let safe = self.vehicle.wait_safe(Instant::now() + deadline / 2);
        self.stop.stop();
        for d in &self.vehicle.devices {
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
                tracing::info!("safe state acknowledged: gas 0, brake full");
            }
        }
    }
}

fn status_loop(d: &Device, stop: &StopSignal) {
    let mut next = Instant::now();
    // The first poll is due at once.
    let mut last_attempt: Option<Instant> = None;
    loop {
        if !stop.sleep_until(next) {
            return;
        }
        let period = d.settings.status_period();
        next = (next + period).max(Instant::now());
        if !d.settings.status_enabled.load(Relaxed) {
            continue;
        }
        let overdue_at = last_attempt.map_or_else(Instant::now, |t| t + d.config.status_max_age);
        let Some(mut port) = d.port.acquire_status(overdue_at, &d.slot) else {
            return;
        };
        let started = Instant::now();
        let (result, first) = port.transact(|drv, link| drv.poll(link));
        let done = Instant::now();
        drop(port);
        last_attempt = Some(started);
        Stats::bump(&d.stats.polls);
        if let Some(first) = first {
            d.stats.status_txn.record(done - first);
        }
        match result {
            Ok(reading) => {
                *d.cache.lock() = crate::vehicle::Cached {
                    reading,
                    at: Some(done),
                };
                d.health.status_error.store(0, Relaxed);
                d.record_ok(done);
            }
            Err(e) => {
                Stats::bump(&d.stats.status_errors);
                d.record_error(&e, false);
            }
        }
    }
}

fn command_loop(v: &Vehicle, d: &Device) {
    let mut last_sent_at: Option<Instant> = None;
    loop {
        let (mut job, mut resend) = match d.slot.wait(d.settings.command_timeout()) {
            Wake::Stop => return,
            Wake::Command(p) => (p, false),
            // Set points and gears are resent; a drive-control command (enable, home,
            // the starter) happens once, when asked.
            Wake::Timeout | Wake::Nudge => match d.slot.resend() {
                Some(Command::Control(_)) | None => continue,
                Some(command) => (
                    Pending {
                        command,
                        received: Instant::now(),
                    },
                    true,
                ),
            },
        };
        if !d.settings.command_enabled.load(Relaxed) {
            continue;
        }
        // The paper's rate cap, when configured: hold off, letting newer commands
        // replace this one meanwhile.
        if let (Some(min), Some(t)) = (d.config.min_command_interval, last_sent_at) {
            if !d.slot.sleep_until(t + min) {
                return;
            }
            if let Some(newer) = d.slot.take_newer() {
                Stats::bump(&d.stats.superseded);
                (job, resend) = (newer, false);
            }
        }
        let Some(mut port) = d.port.acquire_command() else {
            return;
        };
        // A command that arrived while we waited for the port replaces this one. (The
        // paper's thread sent the value it had cued before blocking: that staleness is
        // what its field tests saw as ~200 ms stalls, so the paper rule keeps it.)
        if d.port.rule() == PortRule::Priority {
            if let Some(newer) = d.slot.take_newer() {
                Stats::bump(&d.stats.superseded);
                (job, resend) = (newer, false);
            }
        }
        loop {
            d.slot.set_last(job.command);
            // The wire-level interlock check; it may replace the command (gas while
            // braking goes out as 0), drop it (a shift that became unsafe), or wait a
            // moment (braking waits for the gas release to reach the wire).
            let Some(command) = v.clear_to_send(d.role, job.command) else {
                d.slot.restore_last(d.slot.sent());
                break;
            };
            if command != job.command {
                d.slot.set_last(command);
            }
            let (result, first) = port.transact(|drv, link| drv.command(link, command));
            let done = Instant::now();
            d.slot.set_sent(command);
            if let Some(first) = first {
                if !resend {
                    d.stats.command_delay.record(first - job.received);
                }
                d.stats.command_txn.record(done - first);
                last_sent_at = Some(first);
            }
            match result {
                Ok(()) => {
                    Stats::bump(&d.stats.executed);
                    if resend {
                        Stats::bump(&d.stats.resent);
                    }
                    d.health.command_error.store(0, Relaxed);
                    d.record_ok(done);
                    d.slot.set_executed(command);
                }
                Err(e) => {
                    Stats::bump(&d.stats.command_errors);
                    d.record_error(&e, true);
                }
            }
            // Keep the port for a command that came in meanwhile, unless an overdue
            // status poll is waiting or a rate cap applies.
            if d.port.rule() == PortRule::Priority
                && d.config.min_command_interval.is_none()
                && !port.status_waiting()
            {
                if let Some(next) = d.slot.take_newer() {
                    (job, resend) = (next, false);
                    continue;
                }
            }
            break;
        }
    }
}
