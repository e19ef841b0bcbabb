//! The gate's monitor thread (`gate/monitor`): it disengages an engaged vehicle as soon
//! as [`crate::safety::gate::blockers`] is not empty — a faulty or silent device, the
//! e-stop in pause or disable — whoever engaged it (console or network), and runs the
//! commander's watchdog ([`Gate::watch`]) at the same period. Looking every [`EVERY`],
//! it bounds how late a silent device, the e-stop first of all, is acted on.

use super::Gate;
use crate::threads::{StopSignal, Threads};
use std::sync::Arc;
use std::time::{Duration, Instant};

/// How often the monitor looks.
pub const EVERY: Duration = Duration::from_millis(10);

/// The running monitor.
pub struct Monitor {
    stop: Arc<StopSignal>,
    threads: Threads,
}

impl Monitor {
    pub fn start(gate: Arc<Gate>) -> std::io::Result<Monitor> {
        let stop = Arc::new(StopSignal::default());
        let mut threads = Threads::default();
        let s = stop.clone();
        threads.spawn("gate/monitor".into(), move || {
            crate::threads::every(EVERY, &s, || {
                gate.watch(Instant::now());
                if gate.is_engaged() {
                    if let Some(why) = gate.blockers().into_iter().next() {
                        gate.disengage(&why);
                    }
                }
            })
        })?;
        Ok(Monitor { stop, threads })
    }

    /// Stop and join; returns the thread's name if it did not stop.
    pub fn shutdown(self, deadline: Duration) -> Vec<String> {
        self.stop.stop();
        self.threads.join(Instant::now() + deadline)
    }
}
