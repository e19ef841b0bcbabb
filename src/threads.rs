//! Threads, named and stoppable: a stop signal sleeping threads wake up for, a set of
//! named threads joined with a deadline (naming any that did not stop), and [`every`],
//! the one periodic loop every periodic thread uses.

use parking_lot::{Condvar, Mutex};
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

    /// Join the threads that have ended, forgetting them (a server whose clients come
    /// and go keeps only the live ones).
    pub fn reap(&mut self) {
        let (done, live): (Vec<_>, Vec<_>) = std::mem::take(&mut self.handles)
            .into_iter()
            .partition(|(_, h)| h.is_finished());
        self.handles = live;
        for (_, h) in done {
            let _ = h.join();
        }
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

/// Run `tick` every `period` until `stop`; a turn that overruns its period is logged
/// and the next one starts at once (no burst of catch-up turns).
pub fn every(period: Duration, stop: &StopSignal, mut tick: impl FnMut()) {
    let mut next = Instant::now();
    loop {
        next += period;
        if !stop.sleep_until(next) {
            return;
        }
        let now = Instant::now();
        if now > next + period {
            next = now;
        }
        let t = Instant::now();
        tick();
        let took = t.elapsed();
        if took > period {
            tracing::debug!(
                thread = std::thread::current().name().unwrap_or("?"),
                "turn took {took:?} (period {period:?})"
            );
        }
    }
}
