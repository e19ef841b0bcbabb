//! The engage gate as the rest of adrive holds it: the vehicle and the gate's state
//! ([`GateState`]), with the intake ([`super::admit`]) and the dispatch
//! ([`super::dispatch`]) that apply safety's decisions to the devices. Every front end
//! and the supervisor hold an `Arc<Gate>`; reading it (engaged, why, the snapshot)
//! takes no device lock.

use crate::safety::{GateState, Reject, Rules, Seen};
use crate::snapshot::{Blocker, GateCause, GateView, Pairs, Snapshot};
use crate::value::{Command, Source};
use crate::vehicle::tap::{Asked, Event, GateChange};
use crate::vehicle::{capture, Vehicle};
use std::sync::Arc;
use std::time::Instant;

/// The engage gate and command intake of one vehicle.
pub struct Gate {
    vehicle: Arc<Vehicle>,
    state: GateState,
}

impl Gate {
    pub fn new(vehicle: Arc<Vehicle>) -> Gate {
        Gate {
            state: GateState::new(&vehicle),
            vehicle,
        }
    }

    /// The vehicle this gate guards.
    pub fn vehicle(&self) -> &Arc<Vehicle> {
        &self.vehicle
    }

    /// The gate's state and decisions.
    pub fn state(&self) -> &GateState {
        &self.state
    }

    /// The rules active on this vehicle.
    pub fn rules(&self) -> Rules {
        self.state.rules()
    }

    /// Say which rules are active and what is missing, once, at start.
    pub(crate) fn announce(&self) {
        tracing::info!(
            vehicle = %self.vehicle.name(),
            "interlock rules: {}",
            match self.rules().names() {
                n if n.is_empty() => "none (no throttle, brake or gear bound)".to_string(),
                n => n.join(", "),
            }
        );
        for m in Rules::missing(self.vehicle.bindings()) {
            tracing::warn!(vehicle = %self.vehicle.name(), "{m}");
        }
    }

    /// Rejections so far, by reason.
    pub fn rejections(&self) -> Vec<(Reject, u64)> {
        self.state.rejections()
    }

    /// The interlock rules are on.
    pub(crate) fn interlocks_on(&self) -> bool {
        self.state.interlocks_on()
    }

    pub fn is_engaged(&self) -> bool {
        self.state.is_engaged()
    }

    /// Why the vehicle is engaged or not, in words.
    pub fn reason(&self) -> String {
        self.state.reason()
    }

    /// Why the vehicle is engaged or not, as a type.
    pub fn cause(&self) -> GateCause {
        self.state.cause()
    }

    /// Reasons engaging is refused right now (empty: it may engage).
    pub fn blockers(&self) -> Vec<Blocker> {
        self.state.blockers(&self.vehicle)
    }

    /// The devices a driver has taken over (latched overrides).
    pub fn overridden(&self) -> Vec<String> {
        self.state.overridden()
    }

    /// A recovery procedure takes these devices over (intake refuses them) or, with an
    /// empty list, hands everything back.
    pub(crate) fn set_recovering(&self, ids: &[crate::value::DeviceId]) {
        self.state.set_recovering(ids)
    }

    pub fn is_recovering(&self, id: crate::value::DeviceId) -> bool {
        self.state.is_recovering(id)
    }

    pub(crate) fn tap_gate(&self, change: GateChange, reason: impl FnOnce() -> String) {
        self.vehicle.tap().send(|| Event::Gate {
            at: Instant::now(),
            change,
            reason: reason(),
        });
    }

    pub(crate) fn tap_received(
        &self,
        source: Source,
        asked: Asked,
        at: Instant,
        done: Result<(), Reject>,
        seen: Option<Seen>,
    ) {
        self.vehicle.tap().send(|| Event::Received {
            at,
            source,
            asked,
            refused: done.err().map(Reject::as_str),
            seen,
        });
    }

    /// Count and log a rejection (see [`GateState::reject`]).
    pub(crate) fn reject(
        &self,
        device: Option<&crate::vehicle::Device>,
        command: Option<Command>,
        why: Reject,
    ) -> Reject {
        self.state.reject(device, command, why)
    }

    /// Count and log an accel refused as a whole (see [`GateState::reject_accel`]).
    pub(crate) fn reject_accel(
        &self,
        device: Option<&crate::vehicle::Device>,
        a: f64,
        part: Option<Command>,
        why: Reject,
    ) -> Reject {
        self.state.reject_accel(device, a, part, why)
    }

    /// The gate's part of the snapshot.
    pub fn view(&self, now: Instant) -> GateView {
        let b = self.vehicle.bindings();
        let who = self.command_view(now);
        let blocked_by = self.blockers();
        let cause = self.cause();
        GateView {
            commander: who.commander,
            watchdog: who.watchdog,
            refused: who.refused,
            last_refused: who.last_refused,
            engaged: self.is_engaged(),
            reason: cause.to_string(),
            cause,
            blockers: blocked_by.iter().map(Blocker::to_string).collect(),
            blocked_by,
            interlocks: self.interlocks_on(),
            rules: self
                .rules()
                .names()
                .into_iter()
                .map(str::to_string)
                .collect(),
            roles: self.vehicle.role_names(),
            accel: b.has_accel(),
            overridden: self.overridden(),
        }
    }

    /// The whole vehicle now (without the network part, which the network adds).
    pub fn snapshot(&self, seq: u64) -> Snapshot {
        self.snapshot_at(seq, Instant::now())
    }

    /// The whole vehicle, ages as of `now` (the console draws one instant).
    pub fn snapshot_at(&self, seq: u64, now: Instant) -> Snapshot {
        let rejections = self
            .rejections()
            .into_iter()
            .map(|(r, n)| (r.as_str().to_string(), n))
            .collect::<Pairs<u64>>();
        capture::snapshot(&self.vehicle, seq, now, self.view(now), rejections)
    }
}
