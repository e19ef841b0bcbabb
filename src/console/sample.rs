//! A vehicle at rest with plausible readings and figures, built without threads or
//! ports: for the console's tests, snapshots and the fault screenshot.

use crate::config::VehicleConfig;
use crate::supervisor::status::{Fault, FaultKind, RecoveryView};
use crate::value::{EstopState, Gear, Reading, Role};
use crate::vehicle::{Cached, Vehicle, FAULT_AFTER};
use std::sync::atomic::Ordering::Relaxed;
use std::time::{Duration, Instant};

/// The built-in Alice, not started, every device having reported 20 ms before `now`.
pub fn vehicle(now: Instant) -> Vehicle {
    let v = Vehicle::new(VehicleConfig::alice(), |_| {
        Box::new(|| Err(std::io::Error::other("sample vehicle: no port")))
    });
    let at = Some(now - Duration::from_millis(20));
    for d in &v.devices {
        let reading = match d.role {
            Role::Steer => Reading {
                position: Some(0.231),
                velocity: Some(0.012),
                ..Reading::default()
            },
            Role::Gas => Reading {
                position: Some(0.0),
                ..Reading::default()
            },
            Role::Brake => Reading {
                position: Some(1.0),
                pressure: Some(80.0),
                ..Reading::default()
            },
            Role::Trans => Reading {
                gear: Some(Gear::Park),
                ..Reading::default()
            },
            Role::Estop => Reading {
                estop: Some(EstopState::Run),
                ..Reading::default()
            },
            Role::Obd => Reading {
                rpm: Some(700.0),
                speed: Some(0.0),
                coolant: Some(85.0),
                running: Some(true),
                ..Reading::default()
            },
        };
        *d.cache.lock() = Cached { reading, at };
        let s = &d.stats;
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
        d.health.connected.store(true, Relaxed);
    }
    v
}

/// Make `role` faulty: no reply three times in a row.
pub fn make_faulty(v: &Vehicle, role: Role, now: Instant) {
    if let Some(d) = v.device(role) {
        d.health.consecutive_errors.store(FAULT_AFTER, Relaxed);
        d.health.status_error.store(1, Relaxed);
        *d.health.last_error.lock() = Some((now, "no reply within 200ms".into()));
        d.cache.lock().at = Some(now - Duration::from_millis(1_500));
    }
}

/// An engine stall being recovered: the supervisor's fault, its procedure at step 4
/// of 7 (park, first try), and the faulty brake it also sees; the engine reads
/// stopped, in drive.
pub fn make_recovering(v: &Vehicle, now: Instant) {
    if let Some(d) = v.device(Role::Obd) {
        let mut c = d.cache.lock();
        c.reading.rpm = Some(0.0);
        c.reading.running = Some(false);
    }
    make_faulty(v, Role::Brake, now);
    let s = &v.supervision;
    s.set_faults(vec![
        Fault {
            kind: FaultKind::EngineStall,
            device: None,
            cause: "engine stopped (0 rpm) in drive".into(),
            since: now - Duration::from_secs(3),
        },
        Fault {
            kind: FaultKind::Silent,
            device: Some(Role::Brake),
            cause: "no status for 1700 ms (max 500 ms): no reply within 200ms".into(),
            since: now - Duration::from_millis(1_200),
        },
    ]);
    s.set_recovery(Some(RecoveryView {
        step: 3,
        elapsed_ms: 0.0,
        ..crate::supervisor::recovery::Procedure::engine_stall(
            crate::value::Gear::Drive,
            &crate::config::SupervisorConfig::default(),
        )
        .view()
    }));
    s.set_outcome("recovery steering done in 0.9 s".into());
}
