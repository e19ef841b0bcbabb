//! What can move an actuator besides a driver's hand. A fault is named after its cause:
//! before the supervisor calls a set point device's movement a driver's override, or
//! its place a failure to follow, it asks which known causes can have put it there —
//! and where each can take it. A device is judged against all of them at once:
//!
//! - [`Cause::Command`]: adrive's own commands — the planner's, the safe or manual
//!   state of a stop, a recovery step — every set point acknowledged since its
//!   reading was taken (the snapshot's span reaches back to the reading), and the
//!   one on its way;
//! - [`Cause::Estop`]: the e-stop in pause or disable holds the brake full and the
//!   throttle released — its rule, and on many vehicles its own hardware;
//! - [`Cause::OwnWatchdog`]: an actuator with a watchdog of its own (the
//!   `[device.sim] watchdog` that describes it) goes to its safe value by itself once
//!   no set point reached it for that long.
//!
//! Each is data the judgement receives ([`Push`]), so a new cause is one more arm
//! here, not a special case in a detector.

use crate::config::{DeviceConfig, VehicleConfig};
use crate::snapshot::{DeviceView, Snapshot};
use crate::value::{Command, EstopState, Value};
use std::time::Duration;

/// A known cause that can move an actuator: never a driver's override.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Cause {
    /// adrive's own commands (the planner's, a stop's, a recovery step's).
    Command,
    /// The e-stop in pause or disable: brake full, throttle released.
    Estop,
    /// The actuator's own watchdog: no set point reached it for its time.
    OwnWatchdog,
}

#[cfg(test)]
impl Cause {
    /// Every cause, for the properties that range over them.
    pub(crate) const ALL: [Cause; 3] = [Cause::Command, Cause::Estop, Cause::OwnWatchdog];
}

/// A cause and the set points it can drive the device toward: from `toward[0]` to
/// `toward[1]`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct Push {
    pub cause: Cause,
    pub toward: [f64; 2],
}

/// Every known cause that can be moving set point device `d` (configured as `c` on
/// `cfg`) in `snap`, and where to.
pub(crate) fn pushes(
    snap: &Snapshot,
    cfg: &VehicleConfig,
    d: &DeviceView,
    c: &DeviceConfig,
) -> Vec<Push> {
    let mut out = Vec::new();
    let mut push = |cause, at: f64| match out.iter_mut().find(|p: &&mut Push| p.cause == cause) {
        Some(p) => p.toward = [p.toward[0].min(at), p.toward[1].max(at)],
        None => out.push(Push {
            cause,
            toward: [at, at],
        }),
    };
    for v in [&d.executed, &d.commanded].into_iter().flatten() {
        if let Value::Number(x) = v {
            push(Cause::Command, *x);
        }
    }
    if let Some([lo, hi]) = d.executed_span {
        push(Cause::Command, lo);
        push(Cause::Command, hi);
    }
    // Where the safe state puts this device (the e-stop's rule, its own watchdog).
    let id = cfg.devices.iter().position(|x| x.name == c.name);
    let safe = id.and_then(|i| {
        crate::safety::safe::state(cfg)
            .into_iter()
            .find(|(x, _)| x.index() == i)
            .and_then(|(_, cmd)| match cmd {
                Command::Set(v) => Some(v),
                _ => None,
            })
    });
    let pedal = id.is_some_and(|i| {
        let b = &cfg.roles;
        [b.throttle, b.brake]
            .into_iter()
            .flatten()
            .any(|x| x.index() == i)
    });
    if let (true, Some(at), true) = (estop(snap, cfg).is_some_and(EstopState::halts), safe, pedal) {
        push(Cause::Estop, at);
    }
    let own = c.sim.watchdog;
    let quiet = d
        .executed_age_ms
        .map(|ms| Duration::from_secs_f64(ms / 1e3));
    if let (Some(w), Some(at)) = (own, safe) {
        // Never acknowledged one, or not for longer than its watchdog.
        if quiet.is_none_or(|q| q >= w) {
            push(Cause::OwnWatchdog, at);
        }
    }
    out
}

/// The e-stop's state in the snapshot, through its binding.
fn estop(snap: &Snapshot, cfg: &VehicleConfig) -> Option<EstopState> {
    let e = cfg.roles.estop?;
    let d = &cfg.devices[e.at.device.index()];
    let v = snap
        .device(&d.name)?
        .reading(&d.readings[e.at.reading].name)?;
    v.as_str()?.parse().ok()
}

/// Everything the causes in `pushes` can drive the device toward: the lowest and
/// highest of their set points (`None`: no known cause).
pub(crate) fn hull(pushes: &[Push]) -> Option<[f64; 2]> {
    pushes
        .iter()
        .map(|p| p.toward)
        .reduce(|a, b| [a[0].min(b[0]), a[1].max(b[1])])
}
