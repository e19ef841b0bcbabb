//! Property: whatever a planner sends and whatever the devices do, the simulated
//! devices never receive throttle above released while the brake is applied, never a
//! shift while moving or without the brake, and never throttle once adrive has seen
//! the e-stop pause — on a vehicle with any subset of the safety bindings, wherever a
//! rule's devices are bound; a rule without its devices is absent, and nothing
//! crashes. Generated vehicles and sequences of commands, waits and faults run against
//! the real engine, supervisor and gate on simulated devices; the checker reads what
//! each device received, in order, with the vehicle's speed and the gearbox's state at
//! that moment.
//!
//! `PROPTEST_CASES=64 cargo test --release --test interlock_properties` runs more.

mod common;

use adrive::safety::rules::{RELEASED, SHIFT_BRAKE, STOPPED};
use adrive::sim::SimEvent;
use adrive::value::{Command, DeviceId};
use common::Rig;
use proptest::prelude::*;
use std::sync::atomic::Ordering::Relaxed;
use std::time::{Duration, Instant};

/// Which optional bindings a generated vehicle has (throttle and brake always: they
/// are what the properties are about). The devices are always there; only the
/// bindings change, so an unbound gearbox takes its commands like any device.
#[derive(Clone, Copy, Debug)]
struct Bound {
    gear: bool,
    estop: bool,
    speed: bool,
    engine: bool,
}

impl Bound {
    const ALL: Bound = Bound {
        gear: true,
        estop: true,
        speed: true,
        engine: true,
    };
}

/// Alice at high baud with quick sensors, so a case takes a fraction of a second,
/// with the bindings of `b`.
fn vehicle(b: Bound) -> String {
    let mut roles = String::from("throttle = \"gas\"\nbrake = \"brake\"\n");
    if b.gear {
        roles.push_str("gear = \"trans\"\n");
    }
    if b.estop {
        roles.push_str("estop = \"estop\"\n");
    }
    if b.speed {
        roles.push_str("speed = \"obd.speed\"\n");
    }
    if b.engine {
        roles.push_str("engine_running = \"obd.running\"\n");
    }
    let gear = if b.gear {
        "[vehicle.gear]\nforward = [\"drive\"]\nreverse = [\"reverse\"]\npark = \"park\"\n"
    } else {
        ""
    };
    format!(
        r#"
[vehicle]
name = "fast Alice"
[vehicle.roles]
{roles}
{gear}

[[device]]
name = "gas"
kind = "setpoint"
range = [0.0, 1.0]
driver = "modbus"
baud = 115200
status_period = "20ms"
reply_timeout = "50ms"
[device.modbus]
slave = 2
registers = {{ target = 0, position = 0, status = 1, fault_mask = 0x00FF, scale = 0.0001 }}
[device.sim]
lag = "80ms"

[[device]]
name = "brake"
kind = "setpoint"
range = [0.0, 1.0]
readings = ["position", "pressure"]
driver = "modbus"
baud = 115200
status_period = "20ms"
reply_timeout = "50ms"
[device.modbus]
slave = 3
registers = {{ target = 0, position = 0, pressure = {{ register = 1, scale = 0.01 }}, status = 2, fault_mask = 0x00FF, scale = 0.0001 }}
[device.sim]
lag = "80ms"

[[device]]
name = "trans"
kind = "state"
states = ["park", "reverse", "neutral", "drive"]
driver = "modbus"
baud = 115200
status_period = "20ms"
command_timeout = "200ms"
reply_timeout = "50ms"
[device.modbus]
slave = 4
registers = {{ target = 0, control = 1, state = 0, status = 1, fault_mask = 0x00FF }}
codes = {{ park = 0, reverse = 1, neutral = 2, drive = 3 }}
[device.sim]
settle = "600ms"
transit = "neutral"

[[device]]
name = "estop"
kind = "sensor"
readings = ["estop"]
driver = "line"
baud = 115200
status_period = "10ms"
status_max_age = "200ms"

[[device]]
name = "obd"
kind = "sensor"
readings = ["rpm", "speed", "coolant", "running"]
driver = "line"
baud = 115200
status_period = "20ms"
"#
    )
}

const DRIVE: u8 = 3;

#[derive(Clone, Debug)]
enum Op {
    Gas(f64),
    Brake(f64),
    Accel(f64),
    Shift(u8),
    Wait(u64),
    /// Make a device stop answering (true) or answer again.
    Silent(&'static str, bool),
    /// E-stop to pause (true) or back to run.
    Pause(bool),
    Engage,
}

fn op() -> impl Strategy<Value = Op> {
    let actuator = prop_oneof![Just("gas"), Just("brake"), Just("trans")];
    prop_oneof![
        4 => (-1.0..=1.0f64).prop_map(Op::Accel),
        2 => (0.0..=1.0f64).prop_map(Op::Gas),
        2 => (0.0..=1.0f64).prop_map(Op::Brake),
        2 => (0u8..4).prop_map(Op::Shift),
        5 => (0u64..60).prop_map(Op::Wait),
        1 => (actuator, any::<bool>()).prop_map(|(r, on)| Op::Silent(r, on)),
        1 => any::<bool>().prop_map(Op::Pause),
        1 => Just(Op::Engage),
    ]
}

fn bound() -> impl Strategy<Value = Bound> {
    (any::<bool>(), any::<bool>(), any::<bool>(), any::<bool>()).prop_map(
        |(gear, estop, speed, engine)| Bound {
            gear,
            estop,
            speed,
            engine,
        },
    )
}

/// A command already on its way when adrive sees the pause may still arrive.
const PAUSE_GRACE: Duration = Duration::from_millis(20);

/// Every violation of the properties in what the devices received, for the rules the
/// vehicle's bindings make active.
fn violations(b: Bound, events: &[SimEvent], paused: &[(Instant, Option<Instant>)]) -> Vec<String> {
    let mut out = Vec::new();
    let mut brake = 1.0; // the simulated vehicle starts braked
    for e in events {
        match (e.name.as_str(), e.command) {
            ("brake", Command::Set(v)) => brake = v,
            ("gas", Command::Set(v)) if v > RELEASED => {
                if brake > RELEASED {
                    out.push(format!(
                        "gas {v:.3} received while the brake was at {brake:.3}"
                    ));
                }
                if b.estop
                    && paused
                        .iter()
                        .any(|(from, to)| e.at > *from + PAUSE_GRACE && to.is_none_or(|t| e.at < t))
                {
                    out.push(format!(
                        "gas {v:.3} received after the e-stop pause was seen"
                    ));
                }
            }
            ("trans", Command::State(g)) if b.gear && Some(g) != e.state_before => {
                if b.speed && e.speed.abs() >= STOPPED {
                    out.push(format!(
                        "shift to {} received at {:.2} m/s",
                        e.text, e.speed
                    ));
                }
                if brake < SHIFT_BRAKE {
                    out.push(format!(
                        "shift to {} received with the brake at {brake:.3}",
                        e.text
                    ));
                }
            }
            _ => {}
        }
    }
    out
}

fn run(b: Bound, ops: &[Op]) -> Vec<String> {
    let rig = Rig::supervised(&vehicle(b));
    rig.engage();
    let g = &rig.gate;
    let id = |n: &str| rig.id(n);
    // Start every case rolling in drive, where gas is allowed and the rules bite.
    let trans = rig.device("trans");
    g.submit(id("trans"), Command::State(DRIVE), Instant::now())
        .unwrap();
    common::wait_for("drive", || {
        trans.cached().reading.get(0) == Some(DRIVE as f64)
    });
    let gas = rig.device("gas");
    common::wait_for("gas", || {
        let _ = g.submit_accel(0.3, Instant::now());
        std::thread::sleep(Duration::from_millis(5));
        gas.slot().executed() == Some(Command::Set(0.3))
    });
    let mut paused: Vec<(Instant, Option<Instant>)> = Vec::new();
    for op in ops {
        let now = Instant::now();
        match op {
            Op::Gas(x) => drop(g.submit(id("gas"), Command::Set(*x), now)),
            Op::Brake(x) => drop(g.submit(id("brake"), Command::Set(*x), now)),
            Op::Accel(x) => drop(g.submit_accel(*x, now)),
            Op::Shift(s) => drop(g.submit(id("trans"), Command::State(*s), now)),
            Op::Wait(ms) => std::thread::sleep(Duration::from_millis(*ms)),
            Op::Silent(r, on) => rig.sim.faults(r).unwrap().silent.store(*on, Relaxed),
            Op::Engage => drop(g.engage("property test")),
            Op::Pause(true) => {
                rig.sim.apply("estop pause").unwrap();
                let end = Instant::now() + Duration::from_secs(2);
                let estop = rig.device("estop");
                // Seen by adrive: the e-stop's cache says pause (state 1).
                while estop.reading(0) != Some(1.0) && Instant::now() < end {
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
    // Let what is in flight land, with the safe state as the sentinel: each command
    // thread sends in order, so once both pedals acknowledged it, everything sent
    // before has landed.
    for d in ["gas", "brake"] {
        rig.sim.faults(d).unwrap().silent.store(false, Relaxed);
    }
    g.disengage(adrive::snapshot::DisengageCause::Stopping { why: None });
    assert!(
        g.wait_safe(Instant::now() + common::DEADLINE),
        "the safe state landed"
    );
    let mut events = rig.received();
    events.sort_by_key(|e| e.at);
    let mut bad = violations(b, &events, &paused);
    if !bad.is_empty() {
        // What each device received, to read the violation in.
        let t0 = events.first().map_or_else(Instant::now, |e| e.at);
        bad.push("received (ms, device, command, state before):".into());
        bad.extend(events.iter().map(|e| {
            format!(
                "  {:8.1} {} {} {:?}",
                (e.at - t0).as_secs_f64() * 1e3,
                e.name,
                e.text,
                e.state_before
            )
        }));
    }
    bad
}

proptest! {
    #![proptest_config(ProptestConfig {
        cases: std::env::var("PROPTEST_CASES").ok().and_then(|c| c.parse().ok()).unwrap_or(12),
        max_shrink_iters: 20,
        ..ProptestConfig::default()
    })]

    #[test]
    fn devices_never_receive_an_unsafe_command(ops in prop::collection::vec(op(), 10..40)) {
        let bad = run(Bound::ALL, &ops);
        prop_assert!(bad.is_empty(), "{}", bad.join("\n"));
    }

    #[test]
    fn the_rules_hold_wherever_their_devices_are_bound(
        b in bound(),
        ops in prop::collection::vec(op(), 10..30),
    ) {
        let bad = run(b, &ops);
        prop_assert!(bad.is_empty(), "{b:?}\n{}", bad.join("\n"));
    }
}

/// The checker itself must catch what it is meant to catch.
#[test]
fn the_checker_flags_gas_under_brake_and_unsafe_shifts() {
    let t = Instant::now();
    let ev = |name: &str, command, text: &str, at: u64, speed, state_before| SimEvent {
        device: DeviceId(0),
        name: name.into(),
        at: t + Duration::from_millis(at),
        command,
        text: text.into(),
        request: Vec::new(),
        note: None,
        speed,
        state_before,
    };
    let events = [
        ev("gas", Command::Set(0.4), "0.400", 1, 0.0, None),
        ev("brake", Command::Set(0.0), "0.000", 2, 0.0, None),
        ev("gas", Command::Set(0.4), "0.400", 3, 0.0, None),
        ev("trans", Command::State(0), "park", 4, 3.0, Some(DRIVE)),
        ev("gas", Command::Set(0.4), "0.400", 100, 0.0, None),
    ];
    let paused = [(t + Duration::from_millis(50), None)];
    let bad = violations(Bound::ALL, &events, &paused);
    assert_eq!(bad.len(), 4, "{bad:#?}");
    assert!(bad[0].contains("while the brake"));
    assert!(bad[1].contains("at 3.00 m/s") && bad[2].contains("brake at 0.000"));
    assert!(bad[3].contains("e-stop"));
    // Without a gearbox bound, the same shift is just a device's command; without an
    // e-stop bound, no pause rule.
    let none = Bound {
        gear: false,
        estop: false,
        speed: false,
        engine: false,
    };
    assert_eq!(
        violations(none, &events, &paused).len(),
        1,
        "only gas under brake"
    );
}
