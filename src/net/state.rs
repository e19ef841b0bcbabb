//! The state broadcast: one JSON object per datagram, built from the caches only
//! (never the ports), at `broadcast_rate`. [`SCHEMA`] is its version; the README
//! documents every field ("The network protocol"). A field may be added without a new
//! version; renaming or removing one bumps it.

use super::status::{pairs, NetSnapshot};
use crate::engine::stats::{LatencySummary, StatsSnapshot};
use crate::value::{Command, Reading};
use crate::vehicle::Vehicle;
use serde::Serialize;
use std::time::{Instant, SystemTime, UNIX_EPOCH};

/// The version of the broadcast's schema.
pub const SCHEMA: u32 = 1;

/// One broadcast.
#[derive(Clone, Debug, Serialize)]
pub struct State {
    pub schema: u32,
    pub vehicle: String,
    /// Counts broadcasts from 0; a gap means a lost datagram.
    pub seq: u64,
    /// Wall clock, milliseconds since the Unix epoch.
    pub time_ms: u64,
    pub uptime_s: f64,
    pub engaged: bool,
    /// Why it is engaged or not ("engaged by network 127.0.0.1:40001",
    /// "disengaged: watchdog: …").
    pub gate: String,
    /// What would refuse an engage right now (empty: it may engage).
    pub blockers: Vec<String>,
    pub interlocks: bool,
    /// Every faulty device with its last error.
    pub faults: Vec<String>,
    /// The supervisor: named faults with cause and age, the recovery in progress step
    /// by step, the last outcome, recent history.
    pub supervisor: crate::supervisor::status::SupervisorSnapshot,
    /// Intake rejections of every command (network and console), by reason.
    #[serde(serialize_with = "pairs")]
    pub rejections: Vec<(&'static str, u64)>,
    /// Every device, by name, in the vehicle's order.
    #[serde(serialize_with = "pairs")]
    pub devices: Vec<(&'static str, DeviceState)>,
    /// The network side: listener, watchdog, senders, counters.
    pub net: Option<NetSnapshot>,
}

/// One device in a broadcast.
#[derive(Clone, Debug, Serialize)]
pub struct DeviceState {
    pub actuator: bool,
    /// The last reading (only the fields this device reports), `fault` bits included.
    pub measured: Reading,
    /// The command the device will have next (pending or last sent): a number, or a gear.
    pub commanded: Option<Command>,
    /// The last command the device acknowledged.
    pub executed: Option<Command>,
    /// Age of the cached reading, ms (null before the first good poll).
    pub status_age_ms: Option<f64>,
    pub faulty: bool,
    pub connected: bool,
    /// Error codes as on the paper's screen: 0 good, ≥ 1 bad (1 timeout, 2 garbled,
    /// 3 refused, 4 unsupported, 5 I/O).
    pub status_error: u32,
    pub command_error: u32,
    pub last_error: Option<String>,
    pub counters: Counters,
    /// Command receipt to first byte written, µs.
    pub delay_us: LatencySummary,
    /// One command transaction, µs.
    pub command_txn_us: LatencySummary,
    /// One status transaction, µs.
    pub status_txn_us: LatencySummary,
}

#[derive(Clone, Copy, Debug, Serialize)]
pub struct Counters {
    pub received: u64,
    pub executed: u64,
    pub superseded: u64,
    pub resent: u64,
    pub rejected: u64,
    pub command_errors: u64,
    pub polls: u64,
    pub status_errors: u64,
    pub reconnects: u64,
}

impl Counters {
    /// A device's counters; `opens` is how often its port was opened.
    fn new(s: &StatsSnapshot, opens: u64) -> Counters {
        Counters {
            received: s.received,
            executed: s.executed,
            superseded: s.superseded,
            resent: s.resent,
            rejected: s.rejected,
            command_errors: s.command_errors,
            polls: s.polls,
            status_errors: s.status_errors,
            reconnects: opens.saturating_sub(1),
        }
    }
}

/// Build a broadcast from the vehicle's caches and the network status.
pub fn build(vehicle: &Vehicle, net: Option<NetSnapshot>, seq: u64, started: Instant) -> State {
    use std::sync::atomic::Ordering::Relaxed;
    let devices = vehicle
        .devices
        .iter()
        .map(|d| {
            let c = d.cached();
            let s = d.stats.snapshot();
            let last_error = d.health.last_error.lock().as_ref().map(|(_, m)| m.clone());
            (
                d.role.as_str(),
                DeviceState {
                    actuator: d.is_actuator(),
                    measured: c.reading,
                    commanded: d.slot.latest(),
                    executed: d.slot.executed(),
                    status_age_ms: c.age().map(|a| a.as_secs_f64() * 1e3),
                    faulty: d.is_faulty(),
                    connected: d.health.connected.load(Relaxed),
                    status_error: d.health.status_error.load(Relaxed),
                    command_error: d.health.command_error.load(Relaxed),
                    last_error,
                    counters: Counters::new(
                        &s,
                        d.port_health
                            .opens
                            .load(std::sync::atomic::Ordering::Relaxed),
                    ),
                    delay_us: s.command_delay,
                    command_txn_us: s.command_txn,
                    status_txn_us: s.status_txn,
                },
            )
        })
        .collect::<Vec<_>>();
    let faults = vehicle
        .devices
        .iter()
        .filter_map(|d| Some(format!("{}: {}", d.role, d.fault()?)))
        .collect();
    State {
        schema: SCHEMA,
        vehicle: vehicle.name.clone(),
        seq,
        time_ms: SystemTime::now()
            .duration_since(UNIX_EPOCH)
            .map(|d| d.as_millis() as u64)
            .unwrap_or(0),
        uptime_s: started.elapsed().as_secs_f64(),
        engaged: vehicle.is_engaged(),
        gate: vehicle.gate_reason(),
        blockers: vehicle.engage_blockers(),
        interlocks: vehicle.interlocks.load(Relaxed),
        faults,
        supervisor: vehicle.supervision.snapshot(),
        rejections: vehicle
            .rejections()
            .into_iter()
            .map(|(r, n)| (r.as_str(), n))
            .collect(),
        devices,
        net,
    }
}
