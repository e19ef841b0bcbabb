//! Property: whatever a planner sends and whatever the devices do, the simulated
//! devices never receive gas above 0 while the brake is applied, never a shift while
//! moving or without the brake, and never gas above 0 once adrive has seen the e-stop
//! pause. Generated sequences of commands, waits and faults run against the real
//! engine, supervisor and gate on simulated devices; the checker reads what each device
//! received, in order, with the vehicle's speed and gear at that moment.
//!
//! `PROPTEST_CASES=64 cargo test --release --test interlock_properties` runs more.

mod common;

use adrive::interlock::{RELEASED, SHIFT_BRAKE, STOPPED};
use adrive::sim::SimEvent;
use adrive::value::{Command, EstopState, Gear, Role};
use common::Rig;
use proptest::prelude::*;
use std::sync::atomic::Ordering::Relaxed;
use std::time::{Duration, Instant};

/// Alice at high baud with quick sensors, so a case takes a fraction of a second.
const VEHICLE: &str = r#"
[vehicle]
name = "fast Alice"

[[device]]
name = "gas"
driver = "modbus"
baud = 115200
status_period = "20ms"
reply_timeout = "50ms"
[device.modbus]
slave = 2
registers = { target = 0, position = 0, status = 1, fault_mask = 0x00FF, scale = 0.0001 }

[[device]]
name = "brake"
driver = "modbus"
baud = 115200
status_period = "20ms"
reply_timeout = "50ms"
[device.modbus]
slave = 3
registers = { target = 0, position = 0, pressure = 1, status = 2, fault_mask = 0x00FF, scale = 0.0001, pressure_scale = 0.01 }

[[device]]
name = "trans"
driver = "modbus"
baud = 115200
status_period = "20ms"
command_timeout = "200ms"
reply_timeout = "50ms"
[device.modbus]
slave = 4
registers = { target = 0, control = 1, gear = 0, status = 1, fault_mask = 0x00FF }

[[device]]
name = "estop"
driver = "line"
baud = 115200
status_period = "10ms"
status_max_age = "200ms"

[[device]]
name = "obd"
driver = "line"
baud = 115200
status_period = "20ms"
"#;

#[derive(Clone, Debug)]
enum Op {
    Gas(f64),
    Brake(f64),
    Accel(f64),
    Shift(Gear),
    Wait(u64),
    /// Make a device stop answering (true) or answer again.
    Silent(Role, bool),
    /// E-stop to pause (true) or back to run.
    Pause(bool),
    Engage,
}

fn op() -> impl Strategy<Value = Op> {
    let gear = prop_oneof![
        Just(Gear::Park),
        Just(Gear::Reverse),
        Just(Gear::Neutral),
        Just(Gear::Drive)
    ];
    let actuator = prop_oneof![Just(Role::Gas), Just(Role::Brake), Just(Role::Trans)];
    prop_oneof![
        4 => (-1.0..=1.0f64).prop_map(Op::Accel),
        2 => (0.0..=1.0f64).prop_map(Op::Gas),
        2 => (0.0..=1.0f64).prop_map(Op::Brake),
        2 => gear.prop_map(Op::Shift),
        5 => (0u64..60).prop_map(Op::Wait),
        1 => (actuator, any::<bool>()).prop_map(|(r, on)| Op::Silent(r, on)),
        1 => any::<bool>().prop_map(Op::Pause),
        1 => Just(Op::Engage),
    ]
}

/// A command already on its way when adrive sees the pause may still arrive.
const PAUSE_GRACE: Duration = Duration::from_millis(20);

/// Every violation of the properties in what the devices received.
fn violations(events: &[SimEvent], paused: &[(Instant, Option<Instant>)]) -> Vec<String> {
    let mut out = Vec::new();
    let mut brake = 1.0; // the simulated vehicle starts braked
    for e in events {
        match (e.role, e.command) {
            (Role::Brake, Command::Set(v)) => brake = v,
            (Role::Gas, Command::Set(v)) if v > RELEASED => {
                if brake > RELEASED {
                    out.push(format!(
                        "gas {v:.3} received while the brake was at {brake:.3}"
                    ));
                }
                if paused
                    .iter()
                    .any(|(from, to)| e.at > *from + PAUSE_GRACE && to.is_none_or(|t| e.at < t))
                {
                    out.push(format!(
                        "gas {v:.3} received after the e-stop pause was seen"
                    ));
                }
            }
            (Role::Trans, Command::Gear(g)) if g != e.gear => {
                if e.speed.abs() >= STOPPED {
                    out.push(format!("shift to {g} received at {:.2} m/s", e.speed));
                }
                if brake < SHIFT_BRAKE {
                    out.push(format!(
                        "shift to {g} received with the brake at {brake:.3}"
                    ));
                }
            }
            _ => {}
        }
    }
    out
}

fn run(ops: &[Op]) -> Vec<String> {
    let rig = Rig::supervised(VEHICLE);
    rig.engage();
    let v = &rig.vehicle;
    // Start every case rolling in drive, where gas is allowed and the rules bite.
    let trans = v.device(Role::Trans).unwrap();
    v.submit(Role::Trans, Command::Gear(Gear::Drive), Instant::now())
        .unwrap();
    common::wait_for("drive", || trans.cached().reading.gear == Some(Gear::Drive));
    let gas = v.device(Role::Gas).unwrap();
    common::wait_for("gas", || {
        let _ = v.submit_accel(0.3, Instant::now());
        std::thread::sleep(Duration::from_millis(5));
        gas.slot.executed() == Some(Command::Set(0.3))
    });
    let mut paused: Vec<(Instant, Option<Instant>)> = Vec::new();
    for op in ops {
        let now = Instant::now();
        match op {
            Op::Gas(x) => drop(v.submit(Role::Gas, Command::Set(*x), now)),
            Op::Brake(x) => drop(v.submit(Role::Brake, Command::Set(*x), now)),
            Op::Accel(x) => drop(v.submit_accel(*x, now)),
            Op::Shift(g) => drop(v.submit(Role::Trans, Command::Gear(*g), now)),
            Op::Wait(ms) => std::thread::sleep(Duration::from_millis(*ms)),
            Op::Silent(r, on) => rig.sim.faults(*r).unwrap().silent.store(*on, Relaxed),
            Op::Engage => drop(v.engage("property test")),
            Op::Pause(true) => {
                rig.sim.apply("estop pause").unwrap();
                let end = Instant::now() + Duration::from_secs(2);
                while v.estop() != Some(EstopState::Pause) && Instant::now() < end {
                    std::thread::sleep(Duration::from_millis(1));
                }
                if paused.last().is_none_or(|p| p.1.is_some()) {
                    paused.push((Instant::now(), None));
                }
            }
            Op::Pause(false) => {
                if let Some(p) = paused.last_mut().filter(|p| p.1.is_none()) {
                    p.1 = Some(Instant::now());
                }
                rig.sim.apply("estop run").unwrap();
            }
        }
    }
    // Everything in flight has landed once each actuator answered a poll behind it.
    rig.settle(&[Role::Gas, Role::Brake, Role::Trans]);
    let mut events = rig.received();
    events.sort_by_key(|e| e.at);
    violations(&events, &paused)
}

proptest! {
    #![proptest_config(ProptestConfig {
        cases: std::env::var("PROPTEST_CASES").ok().and_then(|c| c.parse().ok()).unwrap_or(12),
        max_shrink_iters: 20,
        ..ProptestConfig::default()
    })]

    #[test]
    fn devices_never_receive_an_unsafe_command(ops in prop::collection::vec(op(), 10..40)) {
        let bad = run(&ops);
        prop_assert!(bad.is_empty(), "{}", bad.join("\n"));
    }
}

/// The checker itself must catch what it is meant to catch.
#[test]
fn the_checker_flags_gas_under_brake_and_unsafe_shifts() {
    let t = Instant::now();
    let ev = |role, command, at: u64, speed, gear| SimEvent {
        role,
        at: t + Duration::from_millis(at),
        command,
        request: Vec::new(),
        note: None,
        speed,
        gear,
    };
    let events = [
        ev(Role::Gas, Command::Set(0.4), 1, 0.0, Gear::Drive),
        ev(Role::Brake, Command::Set(0.0), 2, 0.0, Gear::Drive),
        ev(Role::Gas, Command::Set(0.4), 3, 0.0, Gear::Drive),
        ev(Role::Trans, Command::Gear(Gear::Park), 4, 3.0, Gear::Drive),
        ev(Role::Gas, Command::Set(0.4), 100, 0.0, Gear::Drive),
    ];
    let bad = violations(&events, &[(t + Duration::from_millis(50), None)]);
    assert_eq!(bad.len(), 4, "{bad:#?}");
    assert!(bad[0].contains("while the brake"));
    assert!(bad[1].contains("at 3.00 m/s") && bad[2].contains("brake at 0.000"));
    assert!(bad[3].contains("e-stop"));
}
