//! How the vehicle is captured into one [`Snapshot`]: the devices' views, the
//! supervisor's faults, the recording's state and the CAN buses' monitor, with the
//! gate's part handed in by the engine. The broadcast, the console, headless, attached
//! consoles, the recorder, the live view and ROS 2 all read this one value.

use super::Vehicle;
use crate::snapshot::{GateView, Pairs, Snapshot, SCHEMA};
use std::time::{Instant, SystemTime, UNIX_EPOCH};

/// The whole vehicle, ages as of `now`, with `gate`'s view and its `rejections` (the
/// network part is the network's to add).
pub(crate) fn snapshot(
    v: &Vehicle,
    seq: u64,
    now: Instant,
    gate: GateView,
    rejections: Pairs<u64>,
) -> Snapshot {
    Snapshot {
        schema: SCHEMA,
        vehicle: v.name.clone(),
        seq,
        time_ms: SystemTime::now()
            .duration_since(UNIX_EPOCH)
            .map(|d| d.as_millis() as u64)
            .unwrap_or(0),
        uptime_s: now.saturating_duration_since(v.started).as_secs_f64(),
        gate,
        devices: v.device_views(now),
        supervisor: v.supervision.snapshot(),
        rejections,
        net: None,
        record: v.tap.status(),
        buses: super::bus::bus_views(v, now),
        part: None,
    }
}
