//! The engine: the command path's machinery, and the threads that run it — two per
//! actuator, one per sensor, over the shared [`Vehicle`]. The command path, from a
//! front end to the serial write, reads in this folder in this order:
//!
//! 1. [`admit`]: every front end (console, attached consoles, the network, ROS 2,
//!    `adrive ctl`) hands an [`Ask`](crate::safety::Ask) with its source to
//!    [`Gate::admit`], which applies the ownership rule and the commander's watchdog
//!    under one lock; then the interlocks and the engage gate decide
//!    ([`GateState::check`](crate::safety::GateState::check), pure rules in
//!    [`crate::safety`]).
//! 2. [`dispatch`]: an admitted command goes on its way — and so does every safe
//!    state, on every path that stops the vehicle.
//! 3. [`fast`]: a command for an idle port is written from the admitting thread, after
//!    the wire check; the command thread only reads the reply.
//! 4. [`slot`](crate::port::slot): otherwise the command waits in the device's slot,
//!    latest wins — never a queue — and wakes the command thread.
//! 5. [`command`] (the command thread): takes the newest command (or resends the last
//!    one every `command_timeout`), asks the wire check ([`Gate::check_wire`]; a wait
//!    for another device happens without the port held), takes the port, sends.
//! 6. [`port`](crate::port): the port's rule between a device's two threads (a waiting
//!    command first, an overdue poll still runs), and the open port itself: the
//!    [`crate::driver`] writes the request, and the first byte is timed.
//!
//! Beside it: [`engagement`] (engage, disengage, STOP, a driver's override: every way
//! in and out, each storing the safe or manual state past the interlocks), [`status`]
//! (the status thread polls every `status_period`, or when the estimate needs it:
//! [`polling`], and stores the reading; readers only read it),
//! [`monitor`] (`gate/monitor`: blockers, the commander's watchdog and the end of a
//! held pedal's [`lease`], every 10 ms) and
//! [`placement`] (which CPUs the command path runs on). The gate's state and every
//! decision live in [`crate::safety`]; the devices' state in [`crate::vehicle`]. The
//! port, the slot and the trace a device carries are a layer below the vehicle
//! ([`crate::port`]): the engine's threads drive them.
//!
//! Every thread is named `<device>/status` or `<device>/command`, stops when told, and
//! [`Engine::shutdown`] joins them with a deadline and names any that did not stop;
//! [`Engine::liveness`] tells whether each still runs and turns its loop within its
//! bound (the service watchdog is fed only while all do). docs/architecture.md draws
//! it.

pub(crate) mod admit;
pub(crate) mod bus;
pub(crate) mod command;
pub(crate) mod dispatch;
mod engagement;
pub(crate) mod fast;
mod gate;
pub(crate) mod lease;
pub mod monitor;
pub(crate) mod placement;
pub(crate) mod polling;
pub(crate) mod status;

pub use command::WireStep;
pub use gate::Gate;

use crate::threads::{Group, Liveness};
use crate::vehicle::Vehicle;
use std::sync::Arc;
use std::time::{Duration, Instant};

/// The running engine.
pub struct Engine {
    gate: Arc<Gate>,
    threads: Group,
    stopped: bool,
}

/// Fault injection for tests (`--inject-panic steer/status:3s`): a device's status
/// thread panics, or ends as if it had returned by mistake, once running this long.
#[derive(Clone, Debug)]
pub(crate) struct Injected {
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
    pub(crate) fn start_injected(
        gate: Arc<Gate>,
        inject: Option<Injected>,
    ) -> std::io::Result<Engine> {
        let mut threads = Group::default();
        let vehicle = gate.vehicle().clone();
        for b in 0..vehicle.buses().len() {
            let v = vehicle.clone();
            let name = v.buses()[b].name().to_string();
            threads.spawn_beating(format!("bus/{name}"), bus::TURN, move |stop, beat| {
                bus::reader_loop(&v, b, stop, beat)
            })?;
        }
        for i in 0..vehicle.devices().len() {
            let name = vehicle.devices()[i].name().to_string();
            let v = vehicle.clone();
            let thread = format!("{name}/status");
            let fault = inject.clone().filter(|f| f.thread == thread);
            // A device on a CAN bus is read by its bus's reader.
            let d = &vehicle.devices()[i];
            if !d.config().on_bus() {
                threads.spawn_beating(thread, status::turn_bound(d), move |stop, beat| {
                    let fault = fault.map(|f| (Instant::now() + f.after, f.panic));
                    status::status_loop(&v.devices()[i], stop, beat, fault)
                })?;
            }
            if d.is_actuator() {
                let g = gate.clone();
                let first = command::turn_bound(d, command::longest_wire_wait(&vehicle));
                // The command thread stops when its slot does (it sleeps there).
                threads.spawn_beating(format!("{name}/command"), first, move |_, beat| {
                    placement::apply(&g.vehicle().config().vehicle.placement);
                    command::command_loop(&g, &g.vehicle().devices()[i], beat)
                })?;
            }
        }
        Ok(Engine {
            gate,
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

    /// Whether each device thread runs and turns its loop within its bound.
    pub(crate) fn liveness(&self) -> Liveness {
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
        self.gate
            .disengage(crate::snapshot::DisengageCause::Stopping { why: None });
        self.gate.command_safe_state();
        let safe = self.gate.wait_safe(Instant::now() + deadline / 2);
        self.threads.signal().stop();
        for d in self.gate.vehicle().devices() {
            d.slot().stop();
            d.port().stop();
        }
        (safe, self.threads.stop(end))
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
