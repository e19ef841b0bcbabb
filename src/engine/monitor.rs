//! The gate's monitor thread (`gate/monitor`): it disengages an engaged vehicle as soon
//! as [`crate::safety::gate_state::blockers`] is not empty — a faulty or silent device, the
//! e-stop in pause or disable — whoever engaged it (console or network), and runs the
//! commander's watchdog ([`Gate::watch`]) and ends a held pedal's lease that ran out
//! ([`Gate::end_lease`]) at the same period. Looking every [`EVERY`],
//! it bounds how late a silent device, the e-stop first of all, is acted on. The
//! e-stop's rule (brake full, gas 0) holds whether the vehicle was engaged or not: an
//! e-stop that pauses a disengaged vehicle gets the safe state commanded too, so that
//! the brake is applied by adrive's command, said as such, never by the actuator's own
//! watchdog against a released command that the wire refuses to send.

use super::Gate;
use crate::snapshot::DisengageCause;
use crate::threads::Group;
use std::sync::Arc;
use std::time::{Duration, Instant};

/// How often the monitor looks.
pub(crate) const EVERY: Duration = Duration::from_millis(10);

/// The running monitor.
pub struct Monitor {
    threads: Group,
}

impl Monitor {
    pub fn start(gate: Arc<Gate>) -> std::io::Result<Monitor> {
        let mut threads = Group::default();
        threads.spawn_beating("gate/monitor", EVERY, move |stop, beat| {
            let mut halted = false;
            crate::threads::every(EVERY, stop, || {
                beat.turn(EVERY);
                let now = Instant::now();
                gate.end_lease(now);
                gate.watch(now);
                let engaged = gate.is_engaged();
                if engaged {
                    if let Some(blocker) = gate.blockers().into_iter().next() {
                        gate.disengage_engaged(DisengageCause::Blocked { blocker });
                    }
                }
                // The e-stop's rule holds a disengaged vehicle too: brake full, gas 0
                // (an engaged one got it with its disengage).
                let halting = gate.vehicle().estop().filter(|e| e.halts());
                if let (Some(state), false, false) = (halting, halted, engaged) {
                    gate.follow_estop(state);
                }
                halted = halting.is_some();
            })
        })?;
        Ok(Monitor { threads })
    }

    /// Whether the monitor runs and turns every [`EVERY`].
    pub(crate) fn liveness(&self) -> crate::threads::Liveness {
        self.threads.liveness()
    }
}

impl crate::threads::Shutdown for Monitor {
    /// Stop and join; returns the thread's name if it did not stop.
    fn shutdown(mut self, deadline: Duration) -> Vec<String> {
        self.threads.stop(Instant::now() + deadline)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::threads::Shutdown;

    /// A monitor held up (here on the intake's lock, as a wedged commander's ask would
    /// hold it) is seen stalled past its bound by the liveness it gives the
    /// supervisor, and named by a shutdown it does not meet in time; running, it stops
    /// within the deadline and names nothing.
    #[test]
    fn a_monitor_held_up_is_seen_stalled_and_named_at_shutdown() {
        let gate = crate::testkit::gate(Instant::now());
        let end = Instant::now() + Duration::from_secs(20);
        let m = Monitor::start(gate.clone()).unwrap();
        assert!(m.liveness().wait_running(end).is_empty());
        assert_eq!(m.shutdown(Duration::from_secs(10)), Vec::<String>::new());
        let m = Monitor::start(gate.clone()).unwrap();
        let live = m.liveness();
        assert!(live.wait_running(end).is_empty());
        let held = gate.state().owner();
        let stalled = loop {
            let s = live.stalled(Instant::now());
            if !s.is_empty() {
                break s;
            }
            assert!(Instant::now() < end, "never seen stalled");
            std::thread::sleep(Duration::from_millis(5));
        };
        assert_eq!(stalled[0].thread, "gate/monitor");
        assert_eq!(stalled[0].bound, EVERY);
        assert_eq!(m.shutdown(Duration::from_millis(20)), ["gate/monitor"]);
        drop(held);
    }
}
