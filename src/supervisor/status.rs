//! What the supervisor knows, for everyone who shows it: the faults it sees (each with
//! a name, a cause and a time) and the recovery procedure in progress, step by step.
//! The supervisor thread writes it; the console, the state broadcast and tests read
//! snapshots. Held in the [`Vehicle`](crate::vehicle::Vehicle), like every other state.

use crate::value::Role;
use parking_lot::Mutex;
use serde::Serialize;
use std::collections::VecDeque;
use std::fmt;
use std::time::{Duration, Instant};

/// The kinds of fault the supervisor detects.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum FaultKind {
    /// No status for longer than the device's `status_max_age`.
    Silent,
    /// Its port is gone (USB unplugged).
    Disconnected,
    /// Too many failed transactions in the recent window.
    ErrorRate,
    /// It reports a value outside its range.
    OutOfRange,
    /// Its measured value stays away from the command.
    NotFollowing,
    /// It reports fault bits in its status word.
    DeviceFault,
    /// Engine stopped while in gear.
    EngineStall,
    EstopPause,
    EstopDisable,
}

impl FaultKind {
    pub fn as_str(self) -> &'static str {
        match self {
            FaultKind::Silent => "silent",
            FaultKind::Disconnected => "disconnected",
            FaultKind::ErrorRate => "error_rate",
            FaultKind::OutOfRange => "out_of_range",
            FaultKind::NotFollowing => "not_following",
            FaultKind::DeviceFault => "device_fault",
            FaultKind::EngineStall => "engine_stall",
            FaultKind::EstopPause => "estop_pause",
            FaultKind::EstopDisable => "estop_disable",
        }
    }
}

impl fmt::Display for FaultKind {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.as_str())
    }
}

/// One fault: what, where, why, since when.
#[derive(Clone, Debug, PartialEq)]
pub struct Fault {
    pub kind: FaultKind,
    /// The device, for device faults.
    pub device: Option<Role>,
    pub cause: String,
    pub since: Instant,
}

impl Fault {
    /// `steer not_following: measured 0.02, commanded 0.50 for 2.6 s`
    pub fn describe(&self) -> String {
        match self.device {
            Some(d) => format!("{d} {}: {}", self.kind, self.cause),
            None => format!("{}: {}", self.kind, self.cause),
        }
    }
}

/// A fault as the broadcast carries it.
#[derive(Clone, Debug, Serialize)]
pub struct FaultView {
    pub kind: FaultKind,
    pub device: Option<Role>,
    pub cause: String,
    pub age_ms: f64,
}

/// Where a recovery procedure is.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct RecoveryView {
    /// `engine_stall`, `steering`, `reconnect brake`.
    pub name: String,
    /// Every step, in order.
    pub steps: Vec<String>,
    /// The step now running (index into `steps`).
    pub step: usize,
    /// This try, from 1, and how many are allowed.
    pub attempt: u32,
    pub attempts: u32,
    pub elapsed_ms: f64,
}

impl RecoveryView {
    /// `engine_stall 3/6 park (try 1/3)`
    pub fn describe(&self) -> String {
        format!(
            "{} {}/{} {} (try {}/{})",
            self.name,
            self.step + 1,
            self.steps.len(),
            self.steps
                .get(self.step)
                .map(String::as_str)
                .unwrap_or("done"),
            self.attempt,
            self.attempts
        )
    }
}

/// A copy of the supervisor's state.
#[derive(Clone, Debug, Default, Serialize)]
pub struct SupervisorSnapshot {
    pub faults: Vec<FaultView>,
    pub recovery: Option<RecoveryView>,
    /// The last procedure's outcome, e.g. `engine_stall recovered in 2.3 s`.
    pub last_outcome: Option<String>,
    /// Recent steps and outcomes, newest last.
    pub history: Vec<String>,
}

#[derive(Default)]
struct Inner {
    faults: Vec<Fault>,
    recovery: Option<(RecoveryView, Instant)>,
    last_outcome: Option<String>,
    history: VecDeque<String>,
}

/// Lines of history kept.
pub const HISTORY: usize = 32;

/// The supervisor's shared state.
#[derive(Default)]
pub struct Status {
    inner: Mutex<Inner>,
}

impl Status {
    pub fn snapshot(&self) -> SupervisorSnapshot {
        let i = self.inner.lock();
        let now = Instant::now();
        SupervisorSnapshot {
            faults: i
                .faults
                .iter()
                .map(|f| FaultView {
                    kind: f.kind,
                    device: f.device,
                    cause: f.cause.clone(),
                    age_ms: ms(now - f.since),
                })
                .collect(),
            recovery: i.recovery.as_ref().map(|(r, started)| RecoveryView {
                elapsed_ms: ms(now - *started),
                ..r.clone()
            }),
            last_outcome: i.last_outcome.clone(),
            history: i.history.iter().cloned().collect(),
        }
    }

    pub fn faults(&self) -> Vec<Fault> {
        self.inner.lock().faults.clone()
    }

    pub fn has(&self, kind: FaultKind, device: Option<Role>) -> bool {
        self.inner
            .lock()
            .faults
            .iter()
            .any(|f| f.kind == kind && f.device == device)
    }

    pub(crate) fn set_faults(&self, faults: Vec<Fault>) {
        self.inner.lock().faults = faults;
    }

    pub(crate) fn set_recovery(&self, view: Option<RecoveryView>) {
        let mut i = self.inner.lock();
        i.recovery = match (view, i.recovery.take()) {
            (Some(v), Some((_, started))) => Some((v, started)),
            (Some(v), None) => Some((v, Instant::now())),
            (None, _) => None,
        };
    }

    pub(crate) fn note(&self, line: String) {
        let mut i = self.inner.lock();
        if i.history.len() == HISTORY {
            i.history.pop_front();
        }
        i.history.push_back(line);
    }

    pub(crate) fn set_outcome(&self, outcome: String) {
        self.inner.lock().last_outcome = Some(outcome);
    }
}

fn ms(d: Duration) -> f64 {
    d.as_secs_f64() * 1000.0
}
