//! The engine: two threads per actuator, one per sensor, over the shared
//! [`Vehicle`].
//!
//! - The **status thread** polls its device every `status_period` (or, with adaptive
//!   polling, when the estimate needs it: [`polling`]) and stores the reading in the
//!   cache and the estimator. Readers (network, console, supervisor) only read them.
//! - The **command thread** sleeps on its slot ([`crate::engine::slot`]) until a
//!   command arrives, then sends
//!   the latest one at once; with nothing new for `command_timeout` it sends the last
//!   one again. Commands are never queued.
//! - Both share the device's port ([`crate::engine::port`]) under adrive's priority
//!   rule (or the paper's).
//! - Right before a command goes out, the command thread asks the safety rules'
//!   wire check ([`Gate::check_wire`]); a wait it asks for (braking waits for the
//!   throttle's release to go out) happens without the port held.
//! - A command that found its port idle was written by the thread that admitted it
//!   ([`crate::engine::fast`]): the command thread wakes to the transaction with the
//!   port held, reads the reply and keeps the books as for its own.
//!
//! Every thread is named `<device>/status` or `<device>/command`, stops when told, and
//! [`Engine::shutdown`] joins them with a deadline and names any that did not stop;
//! [`Engine::liveness`] tells whether each still runs (the service watchdog is fed
//! only while all do).
//! Command threads run where the vehicle file's [`placement`] puts the command path.

mod command;
pub mod dispatch;
pub mod fast;
mod gate;
pub mod intake;
pub mod monitor;
pub mod placement;

pub mod polling;
pub mod port;
pub mod slot;
mod status;

pub use dispatch::WireStep;
pub use gate::Gate;

use crate::threads::{Liveness, StopSignal, Threads};
use crate::vehicle::Vehicle;
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
        let vehicle = gate.vehicle().clone();
        for i in 0..vehicle.devices().len() {
            let name = vehicle.devices()[i].name().to_string();
            let (v, s) = (vehicle.clone(), stop.clone());
            let thread = format!("{name}/status");
            let fault = inject.clone().filter(|f| f.thread == thread);
            threads.spawn(thread, move || {
                let fault = fault.map(|f| (Instant::now() + f.after, f.panic));
                status::status_loop(&v.devices()[i], &s, fault)
            })?;
            if vehicle.devices()[i].is_actuator() {
                let g = gate.clone();
                threads.spawn(format!("{name}/command"), move || {
                    placement::apply(&g.vehicle().config().vehicle.placement);
                    command::command_loop(&g, &g.vehicle().devices()[i])
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
        self.gate.vehicle()
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
        for d in self.gate.vehicle().devices() {
            d.slot().stop();
            d.port().stop();
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
