//! The vehicle structure (the paper's "vehicle struct"): every device with its
//! configuration, cached state and statistics, and what the supervisor sees — the
//! vehicle's state, and how it is captured into one
//! [`Snapshot`](crate::snapshot::Snapshot). It has no policy and no machinery: the rules
//! that decide what may reach a device live in [`crate::safety`], the threads that carry
//! a command to it in [`crate::engine`], the port, slot and trace each device holds
//! below it, in [`crate::port`].
//!
//! - [`device`]: one device (it holds its port, slot and trace: [`crate::port`]);
//!   [`estimate`]: its state estimator; [`stats`]: its always-on figures; [`seen`]: what
//!   a decision of the intake saw; [`supervision`]: the supervisor's board; [`tap`]: where everything
//!   that happens is handed to a recording; [`capture`]: the one snapshot;
//!   [`bus`]: each CAN bus's frames, decoded, as the snapshot carries them.

pub(crate) mod bus;
pub(crate) mod capture;
pub(crate) mod device;
pub(crate) mod estimate;
pub(crate) mod seen;
pub(crate) mod stats;
pub mod supervision;
pub(crate) mod tap;

pub use device::{error_code, Cached, Device, Health, Settings, Unreported, FAULT_AFTER};

use crate::config::protocol_map::Wire;
use crate::config::roles::ReadingRef;
use crate::config::{Bindings, DeviceConfig, Role, VehicleConfig};
use crate::driver::slcan::{Bus, Kits};
use crate::port::Opener;
use crate::snapshot::{self, DeviceView, Pairs};
use crate::value::{DeviceId, EstopState};
use std::sync::atomic::Ordering::Relaxed;
use std::sync::Arc;
use std::time::Instant;
use tap::Tap;

/// The whole vehicle.
pub struct Vehicle {
    name: String,
    config: VehicleConfig,
    devices: Vec<Device>,
    /// The CAN buses, by index in the configuration's.
    buses: Vec<Arc<Bus>>,
    /// Whether the kits on the buses are to be enabled (set by the gate).
    kits: Arc<Kits>,
    /// What the supervisor sees: faults and the recovery in progress.
    supervision: Arc<supervision::Board>,
    /// Where a recording taps the run (off unless one runs).
    tap: Arc<Tap>,
    started: Instant,
}

impl Vehicle {
    /// Build the vehicle; `open` makes the opener of each device's port.
    pub fn new(config: VehicleConfig, open: impl FnMut(&DeviceConfig) -> Opener) -> Vehicle {
        Vehicle::with_tap(config, open, Arc::default())
    }

    /// [`Vehicle::new`] with a tap made beforehand (the log's recording layer holds it
    /// from the start).
    pub(crate) fn with_tap(
        config: VehicleConfig,
        mut open: impl FnMut(&DeviceConfig) -> Opener,
        tap: Arc<Tap>,
    ) -> Vehicle {
        let kits = Arc::<Kits>::default();
        let buses: Vec<Arc<Bus>> = config
            .buses
            .iter()
            .map(|b| Arc::new(Bus::new(b.clone(), kits.clone())))
            .collect();
        let devices = config
            .devices
            .iter()
            .enumerate()
            .map(|(i, c)| {
                let id = DeviceId(i as u16);
                let roles = config.roles.roles_of(id).collect();
                // A device on a CAN bus opens its bus's write half, not a port.
                let opener: Opener = match &c.wire {
                    Wire::Can(m) => {
                        let bus = buses[m.bus].clone();
                        Box::new(move || bus.link())
                    }
                    _ => open(c),
                };
                Device::new(id, c.clone(), roles, opener, tap.clone(), &buses)
            })
            .collect();
        Vehicle {
            name: config.vehicle.name.clone(),
            config,
            devices,
            buses,
            kits,
            supervision: Arc::new(supervision::Board::new(tap.clone())),
            tap,
            started: Instant::now(),
        }
    }

    pub fn name(&self) -> &str {
        &self.name
    }

    /// The vehicle file, checked.
    pub fn config(&self) -> &VehicleConfig {
        &self.config
    }

    /// Every device, in the vehicle file's order (a [`DeviceId`] indexes it).
    pub fn devices(&self) -> &[Device] {
        &self.devices
    }

    /// The CAN buses, in the vehicle file's order.
    pub fn buses(&self) -> &[Arc<Bus>] {
        &self.buses
    }

    /// The switch every bus's kit devices follow (the gate's to set).
    pub fn kits(&self) -> &Arc<Kits> {
        &self.kits
    }

    /// What the supervisor sees: faults and the recovery in progress.
    pub fn supervision(&self) -> &Arc<supervision::Board> {
        &self.supervision
    }

    /// Where a recording taps the run (off unless one runs).
    pub(crate) fn tap(&self) -> &Arc<Tap> {
        &self.tap
    }

    /// When the vehicle was set up.
    pub fn started(&self) -> Instant {
        self.started
    }

    pub fn bindings(&self) -> &Bindings {
        &self.config.roles
    }

    pub fn device(&self, id: DeviceId) -> &Device {
        &self.devices[id.index()]
    }

    /// A device by name (any case).
    pub fn find(&self, name: &str) -> Option<&Device> {
        self.devices
            .iter()
            .find(|d| d.name().eq_ignore_ascii_case(name))
    }

    /// The device bound to `role`.
    pub fn bound(&self, role: Role) -> Option<&Device> {
        self.config.roles.device(role).map(|id| self.device(id))
    }

    /// A bound reading's last good value.
    pub fn reading(&self, r: ReadingRef) -> Option<f64> {
        self.device(r.device).reading(r.reading)
    }

    /// The e-stop's last reported state (`None`: no e-stop bound, or no report yet).
    pub fn estop(&self) -> Option<EstopState> {
        let e = self.config.roles.estop?;
        self.reading(e.at).map(|v| e.state(v))
    }

    /// The devices' part of the snapshot, ages as of `now`. A device's acknowledged set
    /// points reach back over two supervisor periods, and further to its reading's
    /// time: a reading is judged against the commands that were driving it when it was
    /// taken, never only against one that came after it.
    pub(crate) fn device_views(&self, now: Instant) -> Vec<DeviceView> {
        let turns = now.checked_sub(2 * self.config.supervisor.period);
        self.devices
            .iter()
            .map(|d| {
                let since = match (turns, d.cached().at) {
                    (Some(t), Some(read)) => t.min(read),
                    (t, read) => t.or(read).unwrap_or(now),
                };
                view(d, &self.buses, now, since)
            })
            .collect()
    }

    /// The role bindings in words: role → device or device.reading.
    pub(crate) fn role_names(&self) -> Pairs<String> {
        let b = &self.config.roles;
        let name = |id: DeviceId| self.device(id).name().to_string();
        let reading = |r: ReadingRef| {
            format!(
                "{}.{}",
                name(r.device),
                self.device(r.device).config().readings[r.reading].name
            )
        };
        Role::ALL
            .into_iter()
            .filter_map(|role| {
                let target = match role {
                    Role::Estop => b.estop.map(|e| reading(e.at)),
                    Role::Speed => b.speed.map(reading),
                    Role::EngineRunning => b.engine_running.map(reading),
                    other => b.actuator(other).map(name),
                }?;
                Some((role.as_str().to_string(), target))
            })
            .collect()
    }
}

fn ms(d: std::time::Duration) -> f64 {
    d.as_secs_f64() * 1e3
}

/// One device as the snapshot carries it, ages as of `now`; its acknowledged set
/// points since `since`; a CAN device's bus by name and its fault codes by the DBC's.
fn view(d: &Device, buses: &[Arc<Bus>], now: Instant, since: Instant) -> DeviceView {
    let c = d.cached();
    let cfg = &d.config();
    let s = &d.stats();
    let age = c.at.map(|t| now.saturating_duration_since(t));
    let value = |cmd| cfg.command_value(cmd);
    DeviceView {
        name: cfg.name.clone(),
        kind: cfg.kind,
        roles: d.roles().iter().map(|r| r.as_str().to_string()).collect(),
        range: (cfg.kind == crate::value::Kind::Setpoint).then_some(cfg.range),
        units: cfg.units.clone(),
        states: cfg.states.clone(),
        readings: cfg
            .readings
            .iter()
            .enumerate()
            .map(|(i, r)| {
                (
                    r.name.clone(),
                    c.at.and(c.reading.get(i)).map(|v| r.value(v)),
                )
            })
            .collect(),
        reading_units: cfg
            .readings
            .iter()
            .map(|r| (r.name.clone(), r.units.clone()))
            .collect(),
        fault: c.reading.fault,
        faults: match &cfg.wire {
            Wire::Can(m) if c.at.is_some() => m.fault_names(c.reading.fault),
            _ => Vec::new(),
        },
        bus: match &cfg.wire {
            Wire::Can(m) => buses.get(m.bus).map(|b| b.name().to_string()),
            _ => None,
        },
        commanded: d.slot().latest().map(value),
        executed: d.slot().executed().map(value),
        executed_span: d.slot().acked_span(since),
        executed_age_ms: d
            .slot()
            .acked_last_at()
            .map(|t| ms(now.saturating_duration_since(t))),
        status_age_ms: age.map(ms),
        stale: age.is_none_or(|a| a > cfg.status_max_age),
        health: snapshot::Health {
            faulty: d.is_faulty(),
            connected: d.health().connected.load(Relaxed),
            missing: d.port_health().missing.load(Relaxed),
            opens: d.port_health().opens.load(Relaxed),
            status_error: d.health().status_error.load(Relaxed),
            command_error: d.health().command_error.load(Relaxed),
            last_error: d.health().last_error(),
            last_error_age_ms: d
                .health()
                .last_error_at()
                .map(|t| ms(now.saturating_duration_since(t))),
            quiet_ms: d.quiet_for(now).map(ms),
        },
        settings: snapshot::Settings {
            status_period_ms: ms(d.settings().status_period()),
            command_timeout_ms: ms(d.settings().command_timeout()),
            status_max_age_ms: ms(cfg.status_max_age),
            status_on: d.settings().status_enabled.load(Relaxed),
            command_on: d.settings().command_enabled.load(Relaxed),
            polling: cfg.polling.as_str().to_string(),
        },
        counters: snapshot::Counters {
            reconnects: d.port_health().opens.load(Relaxed).saturating_sub(1),
            ..s.counters()
        },
        delay_us: s.command_delay.summary(),
        command_txn_us: s.command_txn.summary(),
        status_txn_us: s.status_txn.summary(),
        estimate: d.estimate(now).map(|e| snapshot::EstimateView {
            position: e.position,
            sigma: e.sigma,
            velocity: e.velocity,
            drift: e.drift,
        }),
    }
}
