//! What a console draws, captured at one instant: a [`Scene`] — the vehicle's one
//! [`Snapshot`] plus what only a console shows (log lines, the bench device's traffic
//! and histogram, the simulator's state) — and [`capture`], which takes one from the
//! engine's cache. The embedded console captures its own every tick; the control
//! socket captures one per attached console and sends it over the wire; a replay makes
//! them from a recording. The view draws a scene without touching the engine.
//!
//! The network panel shows the snapshot's network part when the listener runs and
//! "not running" otherwise. Under `--sim` a console also holds the in-process
//! [`Sim`], so the bench view can inject faults through [`Sim::apply`].

use crate::engine::Gate;
use crate::logging::ring::{LogLine, LogRing};
use crate::net::NetStatus;
use crate::port::trace::TraceEntry;
use crate::sim::{Faults, Sim};
use crate::snapshot::{DeviceView, FaultKind, FaultView, Snapshot};
use crate::value::DeviceId;
use std::sync::atomic::Ordering::Relaxed;
use std::sync::Arc;
use std::time::{Duration, Instant};

/// The faults switched on in one simulated device.
#[derive(Clone, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct SimFaults {
    pub silent: bool,
    pub garbage: bool,
    pub corrupt: bool,
    /// Extra reply delay (0: off).
    pub slow_ms: u64,
    /// A driver's hand pushes its drive toward this (not a fault of the device: a
    /// driver's override, for the supervisor to notice).
    pub hand: Option<f64>,
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
            hand: None,
            text: f.describe(),
        }
    }

    pub fn any(&self) -> bool {
        self.silent || self.garbage || self.corrupt || self.slow_ms > 0
    }
}

/// Everything the console draws, captured at one instant: the vehicle's one
/// [`Snapshot`] (which `Scene` dereferences to) and what only the console shows.
#[derive(Clone, Debug, Default)]
pub struct Scene {
    pub snap: Snapshot,
    pub logs: Vec<LogLine>,
    /// Raw traffic of the bench device, oldest first.
    pub trace: Vec<TraceEntry>,
    /// The bench device's histogram (receipt → first byte for an actuator, the status
    /// transaction for a sensor): (upper edge µs, count).
    pub(crate) buckets: Vec<(f64, u64)>,
    /// Fault injection is available (the devices are simulated in this process).
    pub can_inject: bool,
    /// A replay: nothing can be sent.
    pub(crate) read_only: bool,
    /// The simulated vehicle's own state (e-stop, engine, the bench device's drive).
    pub sim_vehicle: Option<String>,
    /// The faults injected into each simulated device, by device (`--sim` only).
    pub sim_faults: Vec<Option<SimFaults>>,
    /// What the simulator's commands may name and what the vehicle has for them
    /// (`--sim` only): a bench key the simulator would refuse is not offered.
    pub sim_names: Option<crate::sim::commands::Names>,
    /// An attached console: the source it is to the intake (`console #2`), to tell
    /// whether it commands or watches. `None` in the embedded console.
    pub(crate) you: Option<String>,
    /// The vehicle file's `[teleop]`: what teleop starts from.
    pub teleop: crate::config::TeleopConfig,
    /// An attached console whose adrive has sent no frame for longer than
    /// [`QUIET_AFTER`]: how long (adrive stopped, frozen, or its link stalled). What
    /// the screen shows is that old.
    pub(crate) quiet: Option<Duration>,
}

/// An attached console's adrive sends a frame every console tick; none for this long
/// and the screen says so: what it shows is no longer the vehicle's state.
pub(crate) const QUIET_AFTER: Duration = Duration::from_secs(1);

impl std::ops::Deref for Scene {
    type Target = Snapshot;
    fn deref(&self) -> &Snapshot {
        &self.snap
    }
}

impl Scene {
    /// A device by id (its place in the vehicle).
    pub fn at(&self, id: DeviceId) -> Option<&DeviceView> {
        self.snap.devices.get(id.index())
    }

    /// The id of a device by name.
    pub fn id_of(&self, name: &str) -> Option<DeviceId> {
        self.snap
            .devices
            .iter()
            .position(|d| d.name == name)
            .map(|i| DeviceId(i as u16))
    }

    /// The device bound to a role.
    pub(crate) fn bound_id(&self, role: crate::config::Role) -> Option<DeviceId> {
        self.snap
            .bound(role.as_str())
            .and_then(|d| self.id_of(&d.name))
    }

    /// The throttle and brake as the intake accepted them, each a share of its range
    /// (`None` before it was commanded); `None` without both bound.
    fn pedals(&self) -> Option<(Option<f64>, Option<f64>)> {
        let part = |role: crate::config::Role| {
            let d = self.snap.bound(role.as_str())?;
            let top = d.range?[1];
            let v = d.commanded.as_ref()?.as_f64()?;
            (top > 0.0).then(|| v / top)
        };
        // Both bound, or the vehicle has no accel.
        self.snap.bound(crate::config::Role::Throttle.as_str())?;
        self.snap.bound(crate::config::Role::Brake.as_str())?;
        Some((
            part(crate::config::Role::Throttle),
            part(crate::config::Role::Brake),
        ))
    }

    /// The throttle and brake as the intake accepted them, as the one `accel` value
    /// the console and teleop command them with (−1 full brake … 1 full throttle; the
    /// inverse of the intake's split): what the vehicle was told, not what the console
    /// asked. `None` without both bound, or before either was commanded.
    pub(crate) fn accel(&self) -> Option<f64> {
        let a = match self.pedals()? {
            (Some(gas), _) if gas > 0.0 => gas,
            (_, Some(brake)) => -brake,
            (Some(gas), None) => gas,
            (None, None) => return None,
        };
        // Three decimals, as the console asks; never −0.
        Some((a * 1000.0).round() / 1000.0 + 0.0)
    }

    /// Gas and brake both applied, as only interlocks off let them be (each commanded
    /// on its own): the one accel value cannot say it, and must not say gas alone.
    pub(crate) fn gas_and_brake(&self) -> Option<(f64, f64)> {
        match self.pedals()? {
            (Some(gas), Some(brake)) if gas > 0.0 && brake > 0.0 => Some((gas, brake)),
            _ => None,
        }
    }

    /// This console commands the engaged vehicle (the embedded console is `console`,
    /// an attached one the source it was welcomed as).
    pub(crate) fn commands(&self) -> bool {
        let you = self.you.as_deref().unwrap_or("console");
        self.snap.gate.engaged && self.snap.gate.commander.as_deref() == Some(you)
    }

    /// The steering's command as the intake accepted it.
    pub(crate) fn steering(&self) -> Option<f64> {
        self.snap
            .bound(crate::config::Role::Steering.as_str())?
            .commanded
            .as_ref()?
            .as_f64()
    }

    /// The steering's range (`[-1, 1]` without one): teleop steers from -1, full left,
    /// to 1, full right, whatever the device's units (a cart's -30 … 30 degrees).
    fn steering_range(&self) -> [f64; 2] {
        self.snap
            .bound(crate::config::Role::Steering.as_str())
            .and_then(|d| d.range)
            .filter(|[lo, hi]| hi > lo)
            .unwrap_or([-1.0, 1.0])
    }

    /// Teleop's steering `x` (-1 … 1) in the device's units, rounded to the thousandth
    /// the wire carries: -1 its range's left end, 1 its right, and 0 straight ahead
    /// (0, where the range spans it; else its middle).
    pub(crate) fn steering_units(&self, x: f64) -> f64 {
        let [lo, hi] = self.steering_range();
        let v = match (lo < 0.0 && hi > 0.0, x < 0.0) {
            (true, true) => -x * lo,
            (true, false) => x * hi,
            (false, _) => (lo + hi) / 2.0 + x * (hi - lo) / 2.0,
        };
        (v * 1000.0).round() / 1000.0
    }

    /// A steering set point `v` in the device's units as teleop's -1 … 1
    /// ([`Scene::steering_units`] undone).
    pub(crate) fn steering_share(&self, v: f64) -> f64 {
        let [lo, hi] = self.steering_range();
        let x = match (lo < 0.0 && hi > 0.0, v < 0.0) {
            (true, true) => -v / lo,
            (true, false) => v / hi,
            (false, _) => (v - (lo + hi) / 2.0) / ((hi - lo) / 2.0),
        };
        x.clamp(-1.0, 1.0)
    }

    /// Red on screen: faulty to the engine (no replies) or to the supervisor (any
    /// fault it names this device in).
    pub fn red(&self, d: &DeviceView) -> bool {
        d.health.faulty
            || self.snap.supervisor.faults.iter().any(|f| {
                f.kind != FaultKind::Override && f.device.as_deref() == Some(d.name.as_str())
            })
    }

    /// A driver has taken the device over (latched) or has a hand on it now: not a
    /// failure, shown apart from faults.
    pub fn overridden(&self, d: &DeviceView) -> bool {
        self.snap.gate.overridden.contains(&d.name)
            || self.snap.supervisor.faults.iter().any(|f| {
                f.kind == FaultKind::Override && f.device.as_deref() == Some(d.name.as_str())
            })
    }

    /// One line per device in the driver's hands: latched, and whether the hand is
    /// still on it.
    pub(crate) fn override_texts(&self) -> Vec<String> {
        self.snap
            .devices
            .iter()
            .filter(|d| self.overridden(d))
            .map(|d| {
                let held = self.snap.supervisor.faults.iter().any(|f| {
                    f.kind == FaultKind::Override && f.device.as_deref() == Some(d.name.as_str())
                });
                let state = if held {
                    "driver's hand on it"
                } else {
                    "let go: clear to engage again"
                };
                format!("{} in manual ({state})", d.name)
            })
            .collect()
    }

    pub(crate) fn sim_of(&self, id: DeviceId) -> Option<&SimFaults> {
        self.sim_faults.get(id.index()).and_then(Option::as_ref)
    }

    /// Every fault to show, in words: an engine thread that stalled (`STALLED
    /// steer/status has not turned its loop for 1.4 s …`), the supervisor's faults
    /// (`steer silent 1.5s no status for …`), then any device the engine marks faulty that the supervisor has not
    /// named yet (`steer faulty: no reply within 200ms`; it notices at its next turn).
    pub(crate) fn fault_texts(&self) -> Vec<String> {
        let sup = &self.snap.supervisor;
        // A stuck engine thread first: nothing it serves can be trusted.
        let mut out: Vec<String> = sup
            .stalled
            .iter()
            .map(|s| format!("STALLED {}", s.describe()))
            .collect();
        // A device gone says what adrive waits for (`waiting for horn on /dev/ttyUSB3:
        // No such file or directory, retrying every 5s`).
        out.extend(
            sup.faults
                .iter()
                .filter(|f| f.kind != FaultKind::Override)
                .map(|f| {
                    let waiting = sup.waiting.iter().find(|w| {
                        f.kind == FaultKind::Disconnected && f.device.as_ref() == Some(&w.device)
                    });
                    match waiting {
                        Some(w) => format!("{} {} {}", fault_name(f), secs(f.age_ms), w.describe()),
                        None => format!("{} {} {}", fault_name(f), secs(f.age_ms), f.cause),
                    }
                }),
        );
        for d in self.snap.devices.iter().filter(|d| d.health.faulty) {
            if !sup
                .faults
                .iter()
                .any(|f| f.device.as_deref() == Some(d.name.as_str()))
            {
                out.push(format!(
                    "{} faulty: {}",
                    d.name,
                    d.health.last_error.as_deref().unwrap_or("no reply")
                ));
            }
        }
        out
    }

    /// How many lines the supervisor has to show under a small screen's panels: the
    /// recovery in progress, then one per fault.
    pub(crate) fn strip_len(&self) -> usize {
        usize::from(self.snap.supervisor.recovery.is_some()) + self.fault_texts().len()
    }
}

/// Seconds with one decimal: `2.1s`.
pub fn secs(ms: f64) -> String {
    format!("{:.1}s", ms / 1000.0)
}

/// `steer silent` or `engine_stall`.
fn fault_name(f: &FaultView) -> String {
    match &f.device {
        Some(d) => format!("{d} {}", f.kind),
        None => f.kind.to_string(),
    }
}

/// The console's sources beyond the vehicle.
#[derive(Clone, Default)]
pub struct Sources {
    pub net: Option<Arc<NetStatus>>,
    pub logs: Option<LogRing>,
    /// The simulator, when the devices are simulated in this process (`--sim`).
    pub sim: Option<Arc<Sim>>,
}

/// The simulated vehicle's state in words, only what the vehicle has: `e-stop run ·
/// engine running · steer drive ok` (the drive of `device`, when it is a setpoint
/// actuator; for a kit's module, the module: `steering module enabled`).
fn sim_vehicle(sim: &Sim, device: Option<&str>) -> Option<String> {
    let has = sim.names().has;
    let module = device.and_then(|n| sim.module_state(n));
    let mut parts = Vec::new();
    let m = sim.model().lock();
    if has.estop {
        parts.insert(0, format!("e-stop {}", m.estop));
    }
    if has.engine {
        let engine = if m.running {
            "engine running"
        } else {
            "ENGINE STOPPED"
        };
        parts.insert(usize::from(has.estop), engine.to_string());
    }
    if let Some(d) = device.and_then(|n| m.find(n)).map(|id| m.device(id)) {
        if let Some(module) = module {
            parts.push(module);
        } else if d.kind == crate::value::Kind::Setpoint {
            let drive = match (d.fault_latched, d.enabled, d.stuck) {
                (true, _, _) => "FAULT LATCHED",
                (false, false, _) => "disabled",
                (false, true, true) => "stuck",
                (false, true, false) => "ok",
            };
            parts.push(format!("{} drive {drive}", d.name));
        }
        if let Some(x) = d.hand {
            parts.push(format!("a hand pushes it toward {x}"));
        }
    }
    (!parts.is_empty()).then(|| parts.join(" · "))
}

/// Capture a scene of the vehicle behind `gate` as of `now`.
pub fn capture(gate: &Gate, sources: &Sources, now: Instant, bench: Option<DeviceId>) -> Scene {
    let v = &gate.vehicle();
    let mut snap = gate.snapshot_at(0, now);
    snap.net = sources.net.as_ref().map(|n| n.snapshot(gate));
    let bench_dev = bench.and_then(|id| v.devices().get(id.index()));
    Scene {
        logs: sources
            .logs
            .as_ref()
            .map(|l| l.recent())
            .unwrap_or_default(),
        trace: bench_dev.map(|d| d.trace().entries()).unwrap_or_default(),
        buckets: bench_dev
            .map(|d| {
                if d.is_actuator() {
                    d.stats().command_delay.buckets()
                } else {
                    d.stats().status_txn.buckets()
                }
            })
            .unwrap_or_default(),
        can_inject: sources.sim.is_some(),
        read_only: false,
        sim_vehicle: sources
            .sim
            .as_deref()
            .and_then(|s| sim_vehicle(s, bench_dev.map(|d| d.name()))),
        sim_names: sources.sim.as_deref().map(Sim::names),
        sim_faults: v
            .devices()
            .iter()
            .map(|d| {
                let sim = sources.sim.as_ref()?;
                let mut f = SimFaults::of(sim.faults(d.name())?);
                let m = sim.model().lock();
                f.hand = m.find(d.name()).and_then(|id| m.device(id).hand);
                Some(f)
            })
            .collect(),
        you: None,
        teleop: v.config().teleop,
        quiet: None,
        snap,
    }
}
