//! The engage gate's blockers and its monitor. [`blockers`] is the one list of what
//! refuses an engage right now — a faulty device (failing, or silent for longer than
//! its `status_max_age`: [`crate::vehicle::Device::silence`]), a device that has not
//! reported yet (an opened ELM327 says it is searching the car's protocols), the e-stop
//! in pause or disable; the monitor thread (`gate/monitor`)
//! disengages an engaged vehicle as soon as that list is not empty, whoever engaged it
//! (console or network). Looking every [`EVERY`], it bounds how late a silent device,
//! the e-stop first of all, is acted on. Both read the caches only, and the devices a
//! driver has taken over (latched `override`s, held by the [`Gate`]). The same thread
//! runs the commander's watchdog ([`Gate::watch`]) at the same period.

use super::Gate;
use crate::config::DriverKind;
use crate::driver::elm327;
use crate::threads::{StopSignal, Threads};
use crate::value::EstopState;
use crate::vehicle::Vehicle;
use std::sync::atomic::Ordering::Relaxed;
use std::sync::Arc;
use std::time::{Duration, Instant};

/// How often the monitor looks.
pub const EVERY: Duration = Duration::from_millis(10);

/// What refuses an engage now, and disengages an engaged vehicle (empty: all clear).
pub fn blockers(v: &Vehicle, overridden: &[String]) -> Vec<String> {
    let mut why = Vec::new();
    for d in overridden {
        why.push(format!(
            "{d} is in the driver's hands (override): clear it once the driver has let go"
        ));
    }
    for d in &v.devices {
        if let Some(fault) = d.fault() {
            why.push(format!("{} is faulty ({fault})", d.name()));
        } else if d.cached().at.is_none() {
            // An ELM327 that opened has its first answer coming: it searches protocols.
            let opened = d.port_health.opens.load(Relaxed) > 0;
            why.push(match d.config.driver {
                DriverKind::Elm327 if opened => elm327::searching(d.name()),
                _ => format!("{} has not reported yet", d.name()),
            });
        }
    }
    if let Some(s @ (EstopState::Pause | EstopState::Disable)) = v.estop() {
        why.push(format!("e-stop is in {s}"));
    }
    why
}

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
