//! What the console reads from and does to the engine, behind one trait.
//!
//! [`Controls`] is the console's only door to the running vehicle: [`update`] takes a
//! `&dyn Controls`, so it is tested with a recording fake and no threads. [`Live`] is
//! the real one over a [`Vehicle`]. Reading goes through [`Snapshot`]: plain data
//! captured once per tick, which the view draws without touching the engine.
//!
//! The network panel takes a [`NetSource`] when the listener runs and shows "not
//! running" otherwise. Under `--sim` the console also holds the in-process
//! [`Sim`], so the bench view can inject faults through [`Sim::apply`].
//!
//! [`update`]: super::update::update

use crate::engine::stats::StatsSnapshot;
use crate::engine::trace::TraceEntry;
use crate::interlock::Reject;
use crate::sim::{Faults, Sim};
use crate::supervisor::status::SupervisorSnapshot;
use crate::value::{Command, Reading, Role};
use crate::vehicle::Vehicle;
use std::sync::atomic::Ordering::Relaxed;
use std::sync::Arc;
use std::time::{Duration, Instant};

use super::logring::{LogLine, LogRing};

/// One device as the console shows it.
#[derive(Clone, Debug, PartialEq)]
pub struct DeviceSnap {
    pub role: Role,
    pub actuator: bool,
    pub range: [f64; 2],
    /// The command it will have next (pending or last sent).
    pub latest: Option<Command>,
    /// The last command it acknowledged.
    pub executed: Option<Command>,
    pub reading: Reading,
    /// Age of the reading; `None` before the first good poll.
    pub age: Option<Duration>,
    /// The reading is older than the device's `status_max_age` (or there is none).
    pub stale: bool,
    pub status_period: Duration,
    pub command_timeout: Duration,
    pub status_on: bool,
    pub command_on: bool,
    pub status_error: u32,
    pub command_error: u32,
    pub faulty: bool,
    pub last_error: Option<String>,
    pub stats: StatsSnapshot,
    /// Times the port was reopened after the first open.
    pub reconnects: u64,
    /// Receipt → first byte histogram, (upper edge µs, count); filled for the bench.
    pub delay_buckets: Vec<(f64, u64)>,
    /// The faults injected into the simulated device (`--sim` only).
    pub sim: Option<SimFaults>,
}

/// The faults switched on in one simulated device.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct SimFaults {
    pub silent: bool,
    pub garbage: bool,
    pub corrupt: bool,
    /// Extra reply delay (0: off).
    pub slow_ms: u64,
    /// All of them in words ([`Faults::describe`]): `none`, `silent, slow 150ms`.
    pub text: String,
}

impl SimFaults {
    pub fn of(f: &Faults) -> SimFaults {
        SimFaults {
            silent: f.silent.load(Relaxed),
            garbage: f.garbage.load(Relaxed),
            corrupt: f.corrupt.load(Relaxed),
            slow_ms: f.slow_ms.load(Relaxed),
            text: f.describe(),
        }
    }

    pub fn any(&self) -> bool {
        self.silent || self.garbage || self.corrupt || self.slow_ms > 0
    }
}

/// The network listener's state, as `src/net` will publish it.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct NetStatus {
    pub listen: String,
    /// Addresses commands came from recently.
    pub senders: Vec<String>,
    /// Commands accepted per device.
    pub commands: Vec<(Role, u64)>,
    /// Commands refused, by reason.
    pub rejections: Vec<(String, u64)>,
    pub watchdog: Watchdog,
}

/// The network command watchdog.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub enum Watchdog {
    /// No command yet: nothing to watch.
    #[default]
    Idle,
    /// Commands arriving; the last one this long ago.
    Ok {
        since_last: Duration,
        timeout: Duration,
    },
    /// Commands stopped: the vehicle was brought to a safe stop.
    Tripped,
}

/// Where the network panel's figures come from (implemented by `src/net`).
pub trait NetSource: Send + Sync {
    fn status(&self) -> NetStatus;
}

/// Everything the console draws, captured at one instant.
#[derive(Clone, Debug, Default)]
pub struct Snapshot {
    pub vehicle: String,
    pub devices: Vec<DeviceSnap>,
    pub engaged: bool,
    pub gate_reason: String,
    pub blockers: Vec<String>,
    pub interlocks: bool,
    /// Intake rejections by reason (non-zero only).
    pub rejections: Vec<(Reject, u64)>,
    pub net: Option<NetStatus>,
    pub logs: Vec<LogLine>,
    /// Raw traffic of the bench device, oldest first.
    pub trace: Vec<TraceEntry>,
    /// Fault injection is available (the devices are simulated in this process).
    pub can_inject: bool,
    /// The simulated vehicle's own state (e-stop, engine, steering drive), in words.
    pub sim_vehicle: Option<String>,
    /// Faults and recovery as the supervisor sees them.
    pub supervision: SupervisorSnapshot,
}

impl Snapshot {
    pub fn device(&self, role: Role) -> Option<&DeviceSnap> {
        self.devices.iter().find(|d| d.role == role)
    }
}

/// Which thread of a device.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Thread {
    Status,
    Command,
}

/// What the console can do to the engine.
pub trait Controls {
    /// Capture what to draw; `bench` gets its histogram (and trace) filled in.
    fn snapshot(&self, now: Instant, bench: Option<Role>) -> Snapshot;
    fn submit(&self, role: Role, command: Command) -> Result<(), Reject>;
    fn submit_accel(&self, accel: f64) -> Result<(), Reject>;
    fn engage(&self) -> Result<(), Vec<String>>;
    fn disengage(&self, reason: &str);
    fn set_interlocks(&self, on: bool);
    /// Refused, with the reason, when the vehicle file would refuse the value.
    fn set_status_period(&self, role: Role, d: Duration) -> Result<(), String>;
    /// Refused, with the reason, when the vehicle file would refuse the value.
    fn set_command_timeout(&self, role: Role, d: Duration) -> Result<(), String>;
    fn set_enabled(&self, role: Role, thread: Thread, on: bool);
    /// Wake a command thread (broadcast its condition variable).
    fn wake(&self, role: Role);
    /// Gas 0, brake full, bypassing the interlocks.
    fn safe_state(&self);
    /// One line of the simulator's command language ([`Sim::apply`]), e.g.
    /// `silent gas on`, `stall`, `estop pause`; `None` when the devices are not
    /// simulated in this process.
    fn sim(&self, line: &str) -> Option<Result<String, String>>;
}

/// The console's sources beyond the vehicle.
#[derive(Clone, Default)]
pub struct Sources {
    pub net: Option<Arc<dyn NetSource>>,
    pub logs: Option<LogRing>,
    /// The simulator, when the devices are simulated in this process (`--sim`).
    pub sim: Option<Arc<Sim>>,
}

/// [`Controls`] over the real vehicle.
pub struct Live<'a> {
    pub vehicle: &'a Vehicle,
    pub sources: &'a Sources,
}

/// The simulated vehicle's state in words: `e-stop run · engine running · steering ok`.
fn sim_vehicle(sim: &Sim) -> String {
    let m = sim.model().lock();
    let engine = if m.running {
        "engine running"
    } else {
        "ENGINE STOPPED"
    };
    let steering = match (m.steer_fault, m.steer_enabled) {
        (true, _) => "steering FAULT LATCHED",
        (false, false) => "steering disabled",
        (false, true) => "steering ok",
    };
    format!("e-stop {} · {engine} · {steering}", m.estop)
}

/// Capture a snapshot of `vehicle` as of `now`.
pub fn capture(
    vehicle: &Vehicle,
    sources: &Sources,
    now: Instant,
    bench: Option<Role>,
) -> Snapshot {
    let supervision = vehicle.supervision.snapshot();
    let devices = vehicle
        .devices
        .iter()
        .map(|d| {
            let cached = d.cached();
            let age = cached.at.map(|t| now.saturating_duration_since(t));
            DeviceSnap {
                role: d.role,
                actuator: d.is_actuator(),
                range: d.config.range(),
                latest: d.slot.latest(),
                executed: d.slot.executed(),
                reading: cached.reading,
                age,
                stale: age.is_none_or(|a| a > d.config.status_max_age),
                status_period: d.settings.status_period(),
                command_timeout: d.settings.command_timeout(),
                status_on: d.settings.status_enabled.load(Relaxed),
                command_on: d.settings.command_enabled.load(Relaxed),
                status_error: d.health.status_error.load(Relaxed),
                command_error: d.health.command_error.load(Relaxed),
                // Faulty to the engine (no replies) or to the supervisor (any fault
                // it names this device in).
                faulty: d.is_faulty()
                    || supervision.faults.iter().any(|f| f.device == Some(d.role)),
                last_error: d.health.last_error.lock().as_ref().map(|(_, m)| m.clone()),
                stats: d.stats.snapshot(),
                reconnects: d
                    .port_health
                    .opens
                    .load(std::sync::atomic::Ordering::Relaxed)
                    .saturating_sub(1),
                delay_buckets: if bench == Some(d.role) {
                    if d.is_actuator() {
                        d.stats.command_delay.buckets()
                    } else {
                        d.stats.status_txn.buckets()
                    }
                } else {
                    Vec::new()
                },
                sim: sources
                    .sim
                    .as_ref()
                    .and_then(|s| s.faults(d.role))
                    .map(|f| SimFaults::of(f)),
            }
        })
        .collect();
    Snapshot {
        vehicle: vehicle.name.clone(),
        devices,
        engaged: vehicle.is_engaged(),
        gate_reason: vehicle.gate_reason(),
        blockers: if vehicle.is_engaged() {
            Vec::new()
        } else {
            vehicle.engage_blockers()
        },
        interlocks: vehicle.interlocks.load(Relaxed),
        rejections: vehicle
            .rejections()
            .into_iter()
            .filter(|(_, n)| *n > 0)
            .collect(),
        net: sources.net.as_ref().map(|n| n.status()),
        logs: sources
            .logs
            .as_ref()
            .map(|l| l.recent())
            .unwrap_or_default(),
        trace: bench
            .and_then(|r| vehicle.device(r))
            .map(|d| d.trace.entries())
            .unwrap_or_default(),
        can_inject: sources.sim.is_some(),
        sim_vehicle: sources.sim.as_deref().map(sim_vehicle),
        supervision,
    }
}

/// A console edit of a device's settings, checked as the vehicle file is, and logged.
pub fn change_settings(
    vehicle: &Vehicle,
    role: Role,
    change: impl FnOnce(&mut crate::config::DeviceConfig),
) -> Result<(), String> {
    let dev = vehicle
        .device(role)
        .ok_or_else(|| format!("no device {role}"))?;
    dev.change_settings(change).map_err(|v| v.message)?;
    tracing::info!(
        device = %role,
        "from the console: status_period {}, command_timeout {}",
        crate::config::fmt_duration(dev.settings.status_period()),
        crate::config::fmt_duration(dev.settings.command_timeout())
    );
    Ok(())
}

impl Controls for Live<'_> {
    fn snapshot(&self, now: Instant, bench: Option<Role>) -> Snapshot {
        capture(self.vehicle, self.sources, now, bench)
    }
    fn submit(&self, role: Role, command: Command) -> Result<(), Reject> {
        self.vehicle.submit(role, command, Instant::now())
    }
    fn submit_accel(&self, accel: f64) -> Result<(), Reject> {
        self.vehicle.submit_accel(accel, Instant::now())
    }
    fn engage(&self) -> Result<(), Vec<String>> {
        self.vehicle.engage("console")
    }
    fn disengage(&self, reason: &str) {
        self.vehicle.disengage(reason);
    }
    fn set_interlocks(&self, on: bool) {
        self.vehicle.interlocks.store(on, Relaxed);
        tracing::warn!(
            "interlocks switched {} from the console",
            if on { "on" } else { "off" }
        );
    }
    fn set_status_period(&self, role: Role, d: Duration) -> Result<(), String> {
        change_settings(self.vehicle, role, |c| c.status_period = d)
    }
    fn set_command_timeout(&self, role: Role, d: Duration) -> Result<(), String> {
        change_settings(self.vehicle, role, |c| c.command_timeout = d)
    }
    fn set_enabled(&self, role: Role, thread: Thread, on: bool) {
        if let Some(dev) = self.vehicle.device(role) {
            let flag = match thread {
                Thread::Status => &dev.settings.status_enabled,
                Thread::Command => &dev.settings.command_enabled,
            };
            flag.store(on, Relaxed);
            tracing::info!(device = %role, "{thread:?} thread {}", if on { "enabled" } else { "disabled" });
        }
    }
    fn wake(&self, role: Role) {
        if let Some(dev) = self.vehicle.device(role) {
            dev.slot.nudge();
        }
    }
    fn safe_state(&self) {
        self.vehicle.command_safe_state();
    }
    fn sim(&self, line: &str) -> Option<Result<String, String>> {
        let sim = self.sources.sim.as_ref()?;
        let done = sim.apply(line);
        match &done {
            Ok(what) => tracing::warn!("simulator, from the console: {what}"),
            Err(e) => tracing::info!("simulator refused {line:?}: {e}"),
        }
        Some(done)
    }
}
