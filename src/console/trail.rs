//! The bench chart's memory: the last [`WINDOW`] of the bench device's measured
//! position, estimate and command, one sample a tick, kept by the console from the
//! frames it already draws (the engine keeps no history for it). Bench debugging of
//! a single actuator wants to see a step in the command, the drive following it and
//! the estimator tracking both; a reading of the snapshot alone shows only "now".

use crate::snapshot::DeviceView;
use crate::value::DeviceId;
use std::collections::VecDeque;
use std::time::{Duration, Instant};

/// How far back the chart looks.
pub(crate) const WINDOW: Duration = Duration::from_secs(10);

/// One instant of one device, in its units (`None`: not known then).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Sample {
    pub at: Instant,
    pub measured: Option<f64>,
    pub estimate: Option<f64>,
    pub command: Option<f64>,
}

impl Sample {
    pub fn of(d: &DeviceView, at: Instant) -> Sample {
        Sample {
            at,
            measured: d.position(),
            estimate: d.estimate.map(|e| e.position),
            command: d.commanded.as_ref().and_then(|v| v.as_f64()),
        }
    }
}

/// The samples of the device on the bench, oldest first, none older than [`WINDOW`].
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Trail {
    device: Option<DeviceId>,
    samples: VecDeque<Sample>,
}

impl Trail {
    /// Add device `id`'s state at `at`; another device than before starts afresh.
    pub fn push(&mut self, id: DeviceId, d: &DeviceView, at: Instant) {
        if self.device != Some(id) {
            self.device = Some(id);
            self.samples.clear();
        }
        if self.samples.back().is_some_and(|s| s.at > at) {
            self.samples.clear();
        }
        self.samples.push_back(Sample::of(d, at));
        while self
            .samples
            .front()
            .is_some_and(|s| at.saturating_duration_since(s.at) > WINDOW)
        {
            self.samples.pop_front();
        }
    }

    /// The samples of device `id` (none when the trail is another's).
    pub fn of(&self, id: DeviceId) -> impl Iterator<Item = &Sample> {
        let mine = self.device == Some(id);
        self.samples.iter().filter(move |_| mine)
    }

    /// How many samples it holds.
    pub fn len(&self) -> usize {
        self.samples.len()
    }

    pub fn is_empty(&self) -> bool {
        self.samples.is_empty()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::testkit;

    fn gas(now: Instant) -> DeviceView {
        let gate = testkit::gate(now);
        let snap = gate.snapshot_at(0, now);
        snap.devices
            .into_iter()
            .find(|d| d.name == "gas")
            .expect("alice has gas")
    }

    #[test]
    fn keeps_the_last_ten_seconds_of_one_device() {
        let t0 = Instant::now();
        let d = gas(t0);
        let mut t = Trail::default();
        for k in 0..150 {
            t.push(DeviceId(1), &d, t0 + Duration::from_millis(100 * k));
        }
        // 10 s at 10 Hz, both ends included.
        assert_eq!(t.len(), 101);
        assert_eq!(t.of(DeviceId(1)).count(), 101);
        assert_eq!(t.of(DeviceId(2)).count(), 0);
        let s = t.of(DeviceId(1)).next().unwrap();
        assert_eq!(s.measured, d.position());
        // Another device on the bench starts its own trail.
        t.push(DeviceId(2), &d, t0 + Duration::from_secs(20));
        assert_eq!(t.len(), 1);
    }
}
