//! The gate's monitor thread (`gate/monitor`): it disengages an engaged vehicle as soon
//! as [`crate::safety::gate::blockers`] is not empty — a faulty or silent device, the
//! e-stop in pause or disable — whoever engaged it (console or network), and runs the
//! commander's watchdog ([`Gate::watch`]) at the same period. Looking every [`EVERY`],
//! it bounds how late a silent device, the e-stop first of all, is acted on.

use super::Gate;
use crate::threads::Owner;
use std::sync::Arc;
use std::time::{Duration, Instant};

/// How often the monitor looks.
pub(crate) const EVERY: Duration = Duration::from_millis(10);

/// The running monitor.
pub struct Monitor {
    threads: Owner,
}

impl Monitor {
    pub fn start(gate: Arc<Gate>) -> std::io::Result<Monitor> {
        let mut threads = Owner::default();
        threads.spawn_beating("gate/monitor", EVERY, move |stop, beat| {
            crate::threads::every(EVERY, stop, || {
                beat.turn(EVERY);
                gate.watch(Instant::now());
                if gate.is_engaged() {
                    if let Some(why) = gate.blockers().into_iter().next() {
                        gate.disengage(&why);
                    }
                }
            })
        })?;
        Ok(Monitor { threads })
    }

    /// Whether the monitor runs and turns every [`EVERY`].
    pub(crate) fn liveness(&self) -> crate::threads::Liveness {
        self.threads.liveness()
    }

    /// Stop and join; returns the thread's name if it did not stop.
    pub fn shutdown(mut self, deadline: Duration) -> Vec<String> {
        self.threads.stop(Instant::now() + deadline)
    }
}
