//! The crate's test kit: a vehicle at rest with plausible readings and figures, built
//! without threads or ports, for the tests of every layer (safety, snapshot,
//! supervisor, the front ends), the console's screen snapshots and its fault
//! screenshot; and the check that the guide holds a table the code generates. It sits
//! below the layers that use it and imports only the core.

use crate::config::{SupervisorConfig, VehicleConfig};
use crate::engine::Gate;
use crate::snapshot::FaultKind;
use crate::snapshot::RecoveryView;
use crate::value::Reading;
use crate::vehicle::supervision::Fault;
use crate::vehicle::{Cached, Vehicle, FAULT_AFTER};
use std::sync::atomic::Ordering::Relaxed;
use std::sync::Arc;
use std::time::{Duration, Instant};

/// A device's reading, by reading name.
fn reading(v: &Vehicle, device: &str, values: &[(&str, f64)]) -> Reading {
    let d = v.find(device).expect("a device of Alice");
    let mut r = Reading::default();
    for (name, x) in values {
        r.set(
            d.config().reading(name).expect("a reading of the device"),
            *x,
        );
    }
    r
}

/// The built-in Alice, not started, every device having reported 20 ms before `now`.
pub fn vehicle(now: Instant) -> Vehicle {
    vehicle_of(VehicleConfig::alice(), now)
}

/// A vehicle of `config` with no ports, every reading 0 (the e-stop in run), each
/// device having reported just now: it may engage, and nothing in it moves (the
/// allocation test and the benchmark's in-process intake run on it).
pub fn vehicle_zeroed(config: VehicleConfig) -> Vehicle {
    let v = Vehicle::new(config, |_| {
        Box::new(|| Err(std::io::Error::other("test kit: no port")))
    });
    for d in v.devices() {
        let mut reading = Reading::default();
        for i in 0..d.config().readings.len() {
            reading.set(i, 0.0);
        }
        if d.name() == "estop" {
            reading.set(0, 2.0); // run
        }
        d.store(Cached {
            reading,
            at: Some(Instant::now()),
            asked: None,
        });
    }
    v
}

/// A reading of a device other than Alice's, at rest: the value its simulator
/// starts from when the vehicle file gives one, else the engine idling in park with
/// the e-stop in run, else 0 (a first state).
fn at_rest(d: &crate::vehicle::Device, i: usize) -> f64 {
    let name = d.config().readings[i].name.as_str();
    if let Some(r) = d.config().sim.readings.get(name) {
        return r.value;
    }
    match name {
        "rpm" => 700.0,
        "coolant" => 85.0,
        "running" => 1.0,
        "estop" => 2.0,
        _ => 0.0,
    }
}

/// A vehicle of `config`, not started, every device having reported 20 ms before
/// `now` (Alice's devices with her readings at rest, any other's at its simulator's
/// starting values, or idling in park).
pub fn vehicle_of(config: VehicleConfig, now: Instant) -> Vehicle {
    let v = Vehicle::new(config, |_| {
        Box::new(|| Err(std::io::Error::other("sample vehicle: no port")))
    });
    let at = Some(now - Duration::from_millis(20));
    for d in v.devices() {
        let alice: &[(&str, f64)] = match d.name() {
            "steer" => &[("position", 0.231), ("velocity", 0.012)],
            "gas" => &[("position", 0.0)],
            "brake" => &[("position", 1.0), ("pressure", 80.0)],
            "trans" => &[("state", 0.0)],
            "estop" => &[("estop", 2.0)],
            "obd" => &[
                ("rpm", 700.0),
                ("speed", 0.0),
                ("coolant", 85.0),
                ("running", 1.0),
            ],
            _ => &[],
        };
        // Alice's figures where the device is Alice's (a device of another vehicle may
        // share a name and not her readings: OSCC's `steer` reports no position).
        let r = if !alice.is_empty() && alice.iter().all(|(n, _)| d.config().reading(n).is_some()) {
            reading(&v, d.name(), alice)
        } else {
            let mut r = Reading::default();
            for i in 0..d.config().readings.len() {
                r.set(i, at_rest(d, i));
            }
            r
        };
        d.store(Cached {
            reading: r,
            at,
            asked: None,
        });
        if let Some(at) = at {
            d.estimate_reading(&r, at);
        }
        d.record_ok(now - Duration::from_millis(20));
        let s = &d.stats();
        s.polls.store(1200, Relaxed);
        if d.is_actuator() {
            s.received.store(120, Relaxed);
            s.executed.store(118, Relaxed);
            s.superseded.store(2, Relaxed);
            s.resent.store(40, Relaxed);
            for us in [20, 26, 26, 30, 45, 1200] {
                s.command_delay.record(Duration::from_micros(us));
            }
            s.command_txn.record(Duration::from_micros(4_200));
        }
        s.status_txn.record(Duration::from_micros(3_100));
        d.stats().refresh();
        d.health().connected.store(true, Relaxed);
    }
    v
}

/// The sample vehicle behind its gate.
pub fn gate(now: Instant) -> Arc<Gate> {
    gate_of(VehicleConfig::alice(), now)
}

/// A sample vehicle of `config` behind its gate.
pub(crate) fn gate_of(config: VehicleConfig, now: Instant) -> Arc<Gate> {
    Arc::new(Gate::new(Arc::new(vehicle_of(config, now))))
}

/// Make a device faulty: no reply three times in a row.
pub fn make_faulty(v: &Vehicle, name: &str, now: Instant) {
    if let Some(d) = v.find(name) {
        d.health().consecutive_errors.store(FAULT_AFTER, Relaxed);
        d.health().status_error.store(1, Relaxed);
        *d.health().last_error.lock() = Some((now, "no reply within 200ms".into()));
        d.store(Cached {
            at: Some(now - Duration::from_millis(1_500)),
            ..d.cached()
        });
    }
}

/// The engine-stall procedure's steps on Alice, as the supervisor runs them.
pub fn engine_stall() -> RecoveryView {
    let v = vehicle(Instant::now());
    crate::supervisor::recovery::Procedure::engine_stall(&v, 3, &SupervisorConfig::default())
        .expect("Alice binds everything an engine stall needs")
        .view()
}

/// An engine stall being recovered: the supervisor's fault, its procedure at step 4
/// of 7 (park, first try), and the faulty brake it also sees; the engine reads
/// stopped, in drive.
pub fn make_recovering(v: &Vehicle, now: Instant) {
    if let Some(d) = v.find("obd") {
        let mut c = d.cached();
        c.reading.set(0, 0.0);
        c.reading.set(3, 0.0);
        d.store(c);
    }
    make_faulty(v, "brake", now);
    let s = &v.supervision();
    s.set_faults(vec![
        Fault {
            kind: FaultKind::EngineStall,
            device: None,
            cause: "engine stopped (0 rpm) in drive".into(),
            since: now - Duration::from_secs(3),
        },
        Fault {
            kind: FaultKind::Silent,
            device: Some("brake".into()),
            cause: "no status for 1700 ms (max 500 ms): no reply within 200ms".into(),
            since: now - Duration::from_millis(1_200),
        },
    ]);
    s.set_recovery(Some(RecoveryView {
        step: 3,
        elapsed_ms: 0.0,
        ..engine_stall()
    }));
    s.set_outcome(
        crate::snapshot::OutcomeKind::Done,
        "recovery steering done in 0.9 s".into(),
    );
}

/// `doc` (the guide's page `name`) holds, verbatim, `table`: the Markdown table of
/// `what` that the code it describes generates — a header, its rule and a row at least
/// (an empty table is in every page).
#[cfg(test)]
pub(crate) fn assert_guide_holds(name: &str, doc: &str, what: &str, table: &str) {
    let rows = table.lines().filter(|l| l.starts_with('|')).count();
    assert!(rows >= 3, "the table of {what} has no rows:\n{table}");
    assert!(
        doc.contains(table),
        "{name} must contain, verbatim, the table of {what}:\n{table}"
    );
}

/// Every line `f` logs on this thread, at any level, in the words of the log file.
#[cfg(test)]
pub(crate) fn logged(f: impl FnOnce()) -> Vec<String> {
    use parking_lot::Mutex;
    use tracing_subscriber::layer::{Context, Layer, SubscriberExt};
    struct Lines(Arc<Mutex<Vec<String>>>);
    impl<S: tracing::Subscriber> Layer<S> for Lines {
        fn on_event(&self, e: &tracing::Event<'_>, _: Context<'_, S>) {
            self.0.lock().push(crate::logging::EventText::of(e).line());
        }
    }
    let lines = Arc::new(Mutex::new(Vec::new()));
    let sub = tracing_subscriber::registry().with(Lines(lines.clone()));
    tracing::subscriber::with_default(sub, f);
    let lines = lines.lock().clone();
    lines
}
