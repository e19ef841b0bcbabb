//! What a fleet member publishes, and when. The state is the engine's own snapshot
//! (one schema for every reader), cut to what a hundred vehicles on one network can
//! afford twice a second: its head ([`Snapshot::head`]: the gate, the supervisor's
//! faults and recovery, the rejections) without the supervisor's history — about a
//! seventh of the whole (1.2 kB of 8.2 kB for Alice). A change of what the fleet
//! watches for (engaged or not and why, who commands, which faults) is told at once,
//! between the periodic ones.

use crate::snapshot::{FaultKind, GateCause, Snapshot};
use std::time::Duration;

/// The state is published at least this often.
pub const PERIOD: Duration = Duration::from_millis(500);
/// How often a member looks for a change worth telling at once.
pub const LOOK: Duration = Duration::from_millis(100);

/// The state a member publishes from the whole snapshot `snap`.
pub fn compact(snap: &Snapshot) -> Snapshot {
    let mut head = snap.head();
    head.supervisor.history.clear();
    head
}

/// What the fleet watches for in a vehicle's state: when it differs from the last
/// one told, the state is told at once (and `adrive fleet --watch` prints a line).
#[derive(Clone, Debug, PartialEq)]
pub struct Change {
    engaged: bool,
    cause: GateCause,
    commander: Option<String>,
    /// Each fault by kind and device (its words and age change as it lasts).
    faults: Vec<(FaultKind, Option<String>)>,
}

impl Change {
    pub fn of(s: &Snapshot) -> Change {
        Change {
            engaged: s.gate.engaged,
            cause: s.gate.cause.clone(),
            commander: s.gate.commander.clone(),
            faults: s
                .supervisor
                .faults
                .iter()
                .map(|f| (f.kind, f.device.clone()))
                .collect(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::snapshot::{DisengageCause, FaultView};

    fn fault(cause: &str, age_ms: f64) -> FaultView {
        FaultView {
            kind: FaultKind::Silent,
            device: Some("gas".into()),
            cause: cause.into(),
            age_ms,
        }
    }

    #[test]
    fn engaged_its_cause_the_commander_and_the_faults_are_changes_ages_are_not() {
        let base = Snapshot::default();
        let c = Change::of(&base);
        let mut s = base.clone();
        s.seq = 7;
        s.supervisor.history.push("a line".into());
        assert_eq!(Change::of(&s), c, "a new seq or history line is no change");
        let mut s = base.clone();
        s.gate.engaged = true;
        assert_ne!(Change::of(&s), c);
        let mut s = base.clone();
        s.gate.cause = GateCause::Disengaged {
            why: DisengageCause::Stop {
                by: "console".into(),
            },
        };
        assert_ne!(Change::of(&s), c);
        let mut s = base.clone();
        s.gate.commander = Some("console".into());
        assert_ne!(Change::of(&s), c);
        let mut s = base.clone();
        s.supervisor
            .faults
            .push(fault("no reply within 100ms", 10.0));
        let faulty = Change::of(&s);
        assert_ne!(faulty, c);
        s.supervisor.faults[0] = fault("no reply within 100ms for 3 s", 3000.0);
        assert_eq!(Change::of(&s), faulty, "a fault lasting is no change");
    }

    #[test]
    fn the_published_state_is_the_head_without_history() {
        let mut s = crate::testkit::gate(std::time::Instant::now()).snapshot(3);
        s.supervisor.history.push("a line".into());
        let c = compact(&s);
        assert!(c.devices.is_empty() && c.net.is_none() && c.buses.is_empty());
        assert!(c.supervisor.history.is_empty());
        assert_eq!((c.gate, c.vehicle, c.seq), (s.gate, s.vehicle, s.seq));
    }
}
