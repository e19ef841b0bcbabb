//! The engage gate's monitor: while the vehicle is engaged, an e-stop that pauses or
//! disables, or a device that turns faulty — failing, or silent for longer than its
//! `status_max_age` ([`crate::vehicle::Device::silence`]) — disengages it at once (which
//! commands the safe state). Looking every [`EVERY`], it bounds how late a silent
//! device, the e-stop first of all, is acted on. Engaging is refused in those same conditions
//! ([`Vehicle::engage_blockers`]); this thread covers their arriving while engaged,
//! whoever engaged it (console or network). One thread, `gate/monitor`, reading caches.

use crate::engine::{StopSignal, Threads};
use crate::value::EstopState;
use crate::vehicle::Vehicle;
use std::sync::Arc;
use std::time::{Duration, Instant};

/// How often the monitor looks.
pub const EVERY: Duration = Duration::from_millis(10);

/// Why an engaged vehicle must disengage now, if it must.
pub fn trip_reason(vehicle: &Vehicle) -> Option<String> {
    if let Some(s @ (EstopState::Pause | EstopState::Disable)) = vehicle.estop() {
        return Some(format!("e-stop {s}"));
    }
    vehicle
        .devices
        .iter()
        .find_map(|d| Some(format!("{} is faulty ({})", d.role, d.fault()?)))
}

/// The running monitor.
pub struct Monitor {
    stop: Arc<StopSignal>,
    threads: Threads,
}

impl Monitor {
    pub fn start(vehicle: Arc<Vehicle>) -> std::io::Result<Monitor> {
        let stop = Arc::new(StopSignal::default());
        let mut threads = Threads::default();
        let s = stop.clone();
        threads.spawn("gate/monitor".into(), move || {
            let mut next = Instant::now();
            loop {
                next += EVERY;
                if !s.sleep_until(next) {
                    return;
                }
                next = next.max(Instant::now());
                if vehicle.is_engaged() {
                    if let Some(why) = trip_reason(&vehicle) {
                        vehicle.disengage(&why);
                    }
                }
            }
        })?;
        Ok(Monitor { stop, threads })
    }

    /// Stop and join; returns the thread's name if it did not stop.
    pub fn shutdown(self, deadline: Duration) -> Vec<String> {
        self.stop.stop();
        self.threads.join(Instant::now() + deadline)
    }
}
