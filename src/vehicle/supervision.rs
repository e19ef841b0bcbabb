//! What the supervisor knows, for everyone who shows it: the faults it sees (each with
//! a name, a cause and a time) and the recovery procedure in progress, step by step.
//! The supervisor thread writes it; the snapshot carries it to the console, the
//! broadcast and tests. Held in the [`Vehicle`](super::Vehicle), like every other state.

use super::tap::{Event, Tap};
pub use crate::snapshot::{
    FaultKind, FaultView, OutcomeKind, RecoveryView, StallView, SupervisorView, WaitingView,
};
use parking_lot::Mutex;
use std::collections::VecDeque;
use std::sync::Arc;
use std::time::{Duration, Instant};

/// One fault: what, where, why, since when.
#[derive(Clone, Debug, PartialEq)]
pub struct Fault {
    pub kind: FaultKind,
    /// The device, for device faults.
    pub device: Option<String>,
    pub cause: String,
    pub since: Instant,
}

impl Fault {
    /// `steer not_following: measured 0.02, commanded 0.50 for 2.6 s`
    pub fn describe(&self) -> String {
        match &self.device {
            Some(d) => format!("{d} {}: {}", self.kind, self.cause),
            None => format!("{}: {}", self.kind, self.cause),
        }
    }

    /// As the snapshot carries it, at `now`.
    pub fn view(&self, now: Instant) -> FaultView {
        FaultView {
            kind: self.kind,
            device: self.device.clone(),
            cause: self.cause.clone(),
            age_ms: ms(now - self.since),
        }
    }
}

#[derive(Default)]
struct Inner {
    /// Stalled engine threads: name, time since its last turn when seen, bound, seen at.
    stalled: Vec<(String, Duration, Duration, Instant)>,
    /// Devices gone, as the supervisor last said.
    waiting: Vec<WaitingView>,
    faults: Vec<Fault>,
    recovery: Option<(RecoveryView, Instant)>,
    last_outcome: Option<(OutcomeKind, String)>,
    outcomes: u64,
    history: VecDeque<String>,
}

/// Lines of history kept.
pub(crate) const HISTORY: usize = 32;

/// The supervisor's board: what it publishes for everyone, a recording included
/// (every fault raised and cleared, every line of history).
#[derive(Default)]
pub struct Board {
    inner: Mutex<Inner>,
    tap: Arc<Tap>,
}

impl Board {
    pub fn new(tap: Arc<Tap>) -> Board {
        Board {
            inner: Mutex::default(),
            tap,
        }
    }

    pub fn snapshot(&self) -> SupervisorView {
        let i = self.inner.lock();
        let now = Instant::now();
        SupervisorView {
            faults: i.faults.iter().map(|f| f.view(now)).collect(),
            recovery: i.recovery.as_ref().map(|(r, started)| RecoveryView {
                elapsed_ms: ms(now - *started),
                ..r.clone()
            }),
            last_outcome: i.last_outcome.as_ref().map(|(_, w)| w.clone()),
            outcome: i.last_outcome.as_ref().map(|(k, _)| *k),
            outcomes: i.outcomes,
            history: i.history.iter().cloned().collect(),
            stalled: stalled(&i, now),
            waiting: i.waiting.clone(),
        }
    }

    /// The devices gone, and what adrive does about each (the supervisor's words).
    pub(crate) fn set_waiting(&self, waiting: Vec<WaitingView>) {
        self.inner.lock().waiting = waiting;
    }

    /// The engine threads that are stalled now (the service watchdog's finding).
    pub fn stalled(&self) -> Vec<StallView> {
        stalled(&self.inner.lock(), Instant::now())
    }

    /// The engine threads found stalled (empty: every thread turns).
    pub(crate) fn set_stalled(&self, now: &[crate::threads::Stall]) {
        let at = Instant::now();
        self.inner.lock().stalled = now
            .iter()
            .map(|s| (s.thread.clone(), s.quiet, s.bound, at))
            .collect();
    }

    pub fn faults(&self) -> Vec<Fault> {
        self.inner.lock().faults.clone()
    }

    pub fn has(&self, kind: FaultKind, device: Option<&str>) -> bool {
        self.inner
            .lock()
            .faults
            .iter()
            .any(|f| f.kind == kind && f.device.as_deref() == device)
    }

    pub fn set_faults(&self, faults: Vec<Fault>) {
        let before = std::mem::replace(&mut self.inner.lock().faults, faults.clone());
        if !self.tap.is_on() {
            return;
        }
        let same = |a: &Fault, b: &Fault| a.kind == b.kind && a.device == b.device;
        let now = Instant::now();
        let raised = faults.iter().filter(|f| !before.iter().any(|b| same(b, f)));
        let cleared = before.iter().filter(|b| !faults.iter().any(|f| same(b, f)));
        for (f, up) in raised.map(|f| (f, true)).chain(cleared.map(|f| (f, false))) {
            self.tap.send(|| Event::Fault {
                at: now,
                raised: up,
                kind: f.kind,
                device: f.device.clone(),
                cause: f.cause.clone(),
            });
        }
    }

    pub(crate) fn set_recovery(&self, view: Option<RecoveryView>) {
        let mut i = self.inner.lock();
        i.recovery = match (view, i.recovery.take()) {
            (Some(v), Some((_, started))) => Some((v, started)),
            (Some(v), None) => Some((v, Instant::now())),
            (None, _) => None,
        };
    }

    pub fn note(&self, line: String) {
        self.tap.send(|| Event::Note {
            at: Instant::now(),
            text: line.clone(),
        });
        let mut i = self.inner.lock();
        if i.history.len() == HISTORY {
            i.history.pop_front();
        }
        i.history.push_back(line);
    }

    /// The last procedure ended as `kind`, said in `words`.
    pub(crate) fn set_outcome(&self, kind: OutcomeKind, words: String) {
        let mut i = self.inner.lock();
        i.last_outcome = Some((kind, words));
        i.outcomes += 1;
    }
}

fn stalled(i: &Inner, now: Instant) -> Vec<StallView> {
    i.stalled
        .iter()
        .map(|(thread, quiet, bound, at)| StallView {
            thread: thread.clone(),
            quiet_ms: ms(*quiet + now.saturating_duration_since(*at)),
            bound_ms: ms(*bound),
        })
        .collect()
}

fn ms(d: Duration) -> f64 {
    d.as_secs_f64() * 1000.0
}
