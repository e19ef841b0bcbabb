//! Vehicles other than Alice, as a user runs them: the shipped utility cart, and a
//! vehicle file of 40 devices of every kind with free names, each on the real binary
//! (`adrive --sim --headless --config FILE`), commanded over the network and read back
//! from the state broadcast through `adrive watch`.

mod common;

use adrive::snapshot::{Snapshot, WatchdogState};
use adrive::value::{Kind, Value};
use common::headless::{Adrive, Watch};
use std::fmt::Write as _;
use std::sync::atomic::{AtomicBool, Ordering::Relaxed};
use std::sync::Arc;
use std::time::Duration;

const CART: &str = include_str!("../vehicles/cart.toml");

fn number(v: &Snapshot, device: &str, reading: &str) -> f64 {
    v.device(device)
        .and_then(|d| d.number(reading))
        .unwrap_or(f64::NAN)
}

fn text(v: &Snapshot, device: &str, reading: &str) -> Option<String> {
    v.device(device)?
        .reading(reading)
        .and_then(Value::as_str)
        .map(str::to_string)
}

/// Send each of `bodies` with an advancing counter every 50 ms, as a planner, until
/// `stop`.
fn planner(a: &Adrive, bodies: Vec<String>, stop: Arc<AtomicBool>) -> std::thread::JoinHandle<()> {
    let socket = a.planner();
    std::thread::spawn(move || {
        let mut seq = 0u64;
        while !stop.load(Relaxed) {
            for body in &bodies {
                seq += 1;
                let _ = socket.send(format!("seq {seq}\n{body}").as_bytes());
            }
            std::thread::sleep(Duration::from_millis(50));
        }
    })
}

/// The cart (no engine, no gearbox: a direction switch bound as `gear`) says at start
/// which rules are on and which are off; a planner engages it, selects forward and
/// gives throttle, and it drives; the planner stops and the watchdog stops the cart.
#[test]
fn the_utility_cart_drives_forward_and_the_watchdog_stops_it() {
    let a = Adrive::start("cart", CART, "watchdog_timeout = \"500ms\"");
    let log = a.startup.join("\n");
    assert!(
        log.contains("interlock rules: gas_while_braking, gas_not_in_gear, gas_estop,"),
        "{log}"
    );
    assert!(
        log.contains("rule gas_engine_off is off: no engine_running bound"),
        "{log}"
    );
    let watch = Watch::start(&a.broadcast);
    let (v, _) = watch.until("every device reporting", |v| v.gate.blockers.is_empty());
    assert_eq!(v.vehicle, "Cart");
    assert_eq!(v.devices.len(), 10);
    assert!(v.gate.accel, "throttle and brake are bound");
    assert_eq!(
        text(&v, "signals", "state").as_deref(),
        Some("hazard"),
        "safe"
    );

    let stop = Arc::new(AtomicBool::new(false));
    let sender = planner(
        &a,
        vec!["engage\ndirection forward\nsignals left\naccel 0.5\n".into()],
        stop.clone(),
    );
    let (v, _) = watch.until("forward, throttle given", |v| {
        v.gate.engaged
            && text(v, "direction", "state").as_deref() == Some("forward")
            && number(v, "throttle", "position") > 0.45
    });
    assert_eq!(
        v.device("brake").unwrap().commanded,
        Some(Value::Number(0.0)),
        "released"
    );
    assert_eq!(text(&v, "signals", "state").as_deref(), Some("left"));
    let s0 = number(&v, "wheels", "speed");
    let (v, _) = watch.until("the cart picking up speed", |v| {
        number(v, "wheels", "speed") > s0 + 1.0
    });
    assert!(
        number(&v, "battery", "voltage") > 50.0,
        "the battery reports"
    );

    // The planner goes away: the watchdog commands the safe state and disengages.
    stop.store(true, Relaxed);
    sender.join().unwrap();
    let (v, _) = watch.until("the watchdog to trip", |v| !v.gate.engaged);
    assert!(
        matches!(
            v.gate.cause,
            adrive::snapshot::GateCause::Disengaged {
                why: adrive::snapshot::DisengageCause::Watchdog { .. }
            }
        ),
        "{}",
        v.gate.reason
    );
    assert_eq!(
        v.gate.watchdog.as_ref().unwrap().state,
        WatchdogState::Tripped
    );
    let (v, _) = watch.until("the cart standing, full brake, hazards on", |v| {
        number(v, "wheels", "speed") == 0.0
            && number(v, "brake", "position") > 0.99
            && number(v, "throttle", "position") < 0.01
            && text(v, "signals", "state").as_deref() == Some("hazard")
    });
    assert_eq!(
        v.device("throttle").unwrap().commanded,
        Some(Value::Number(0.0))
    );
}

/// One device of the generated vehicle: its name, kind, TOML, the command line that
/// moves it and the value it then reports.
struct Generated {
    name: String,
    kind: Kind,
    toml: String,
    command: Option<(String, Value)>,
}

/// `n` devices: setpoints, states and sensors on every driver that can speak them.
fn generated(n: usize) -> Vec<Generated> {
    let words = [
        "wiper", "hitch", "boom", "lamp", "pump", "valve", "fan", "winch", "mirror", "seat",
    ];
    (0..n)
        .map(|i| {
            let name = format!("{}_{i}", words[i % words.len()]);
            let mut toml = format!("[[device]]\nname = \"{name}\"\n");
            let (kind, command) = match i % 6 {
                0 | 1 => {
                    let driver = if i % 6 == 0 { "line" } else { "modbus" };
                    // Exactly what the command line says.
                    let v: f64 = format!("{:.1}", i as f64 / 10.0 - 2.0).parse().unwrap();
                    let _ = write!(
                        toml,
                        "kind = \"setpoint\"\nrange = [-5.0, 5.0]\nunits = \"cm\"\ndriver = \"{driver}\"\n"
                    );
                    if driver == "modbus" {
                        let _ = write!(
                            toml,
                            "[device.modbus]\nslave = {}\nregisters = {{ target = 0, position = 0, table = \"input\", scale = 0.001, signed = true }}\n",
                            1 + i
                        );
                    }
                    (Kind::Setpoint, Some((format!("{name} {v}"), Value::Number(v))))
                }
                2 | 3 => {
                    let driver = if i % 6 == 2 { "line" } else { "modbus" };
                    let _ = write!(
                        toml,
                        "kind = \"state\"\nstates = [\"off\", \"low\", \"high\"]\ndriver = \"{driver}\"\n"
                    );
                    if driver == "modbus" {
                        let _ = write!(
                            toml,
                            "[device.modbus]\nslave = {}\nregisters = {{ target = 0, state = 0, table = \"input\" }}\ncodes = {{ off = 0, low = 1, high = 2 }}\n",
                            1 + i
                        );
                    }
                    (
                        Kind::State,
                        Some((format!("{name} high"), Value::Text("high".into()))),
                    )
                }
                4 => {
                    let _ = write!(
                        toml,
                        "kind = \"sensor\"\nreadings = [{{ name = \"level\", units = \"%\" }}]\ndriver = \"line\"\n[device.sim]\nreadings = {{ level = {{ value = {i}.0 }} }}\n"
                    );
                    (Kind::Sensor, None)
                }
                _ => {
                    let _ = write!(
                        toml,
                        "kind = \"sensor\"\nreadings = [{{ name = \"temperature\", units = \"°C\" }}]\ndriver = \"modbus\"\n[device.modbus]\nslave = {}\nregisters = {{ temperature = {{ register = 0, scale = 0.1 }}, table = \"input\" }}\n[device.sim]\nreadings = {{ temperature = {{ value = {i}.5 }} }}\n",
                        1 + i
                    );
                    (Kind::Sensor, None)
                }
            };
            Generated {
                name,
                kind,
                toml,
                command,
            }
        })
        .collect()
}

/// A vehicle file of 40 devices of every kind with free names runs under `--sim`: a
/// command to each actuator reaches its simulated device, which reports it back, each
/// sensor reports, and the broadcast lists all 40.
#[test]
fn forty_devices_of_every_kind_are_commanded_by_name_and_broadcast() {
    run_generated(40);
}

/// 64 devices: the broadcast no longer fits one datagram and goes in parts, which
/// `adrive watch` joins.
#[test]
fn sixty_four_devices_are_commanded_and_broadcast_in_parts() {
    run_generated(64);
}

/// A generated vehicle of `n` devices under `--sim`, every actuator commanded by name.
fn run_generated(n: usize) {
    let devices = generated(n);
    let mut vehicle = format!("[vehicle]\nname = \"Generated {n}\"\n\n");
    for d in &devices {
        vehicle.push_str(&d.toml);
        vehicle.push('\n');
    }
    let a = Adrive::start("forty", &vehicle, "watchdog_timeout = \"2s\"");
    let watch = Watch::start(&a.broadcast);
    let (v, _) = watch.until("every device reporting", |v| {
        v.devices.len() == n && v.gate.blockers.is_empty()
    });
    let names: Vec<&str> = v.devices.iter().map(|d| d.name.as_str()).collect();
    let want: Vec<&str> = devices.iter().map(|d| d.name.as_str()).collect();
    assert_eq!(names, want, "all {n}, in the file's order");
    for (d, g) in v.devices.iter().zip(&devices) {
        assert_eq!(d.kind, g.kind, "{}", g.name);
    }

    // A datagram holds at most 16 commands: the planner sends two.
    let lines: Vec<&str> = devices
        .iter()
        .filter_map(|d| d.command.as_ref().map(|(l, _)| l.as_str()))
        .collect();
    let bodies: Vec<String> = lines
        .chunks(15)
        .map(|c| format!("engage\n{}\n", c.join("\n")))
        .collect();
    assert!(bodies.len() >= 2);
    let stop = Arc::new(AtomicBool::new(false));
    let sender = planner(&a, bodies, stop.clone());
    // What is not there yet: a device whose command was not acknowledged or not
    // reported back, a sensor without its readings.
    let unmet = |v: &Snapshot| -> Vec<String> {
        devices
            .iter()
            .filter(|g| {
                let Some(d) = v.device(&g.name) else {
                    return true;
                };
                let done = match (&g.command, g.kind) {
                    (Some((_, want)), Kind::Setpoint) => {
                        d.executed.as_ref() == Some(want)
                            && d.position()
                                .is_some_and(|p| (p - want.as_f64().unwrap()).abs() < 0.002)
                    }
                    (Some((_, want)), _) => {
                        d.executed.as_ref() == Some(want) && d.reading("state") == Some(want)
                    }
                    (None, _) => d.readings.iter().all(|(_, r)| r.is_some()),
                };
                !done
            })
            .map(|g| match v.device(&g.name) {
                Some(d) => format!(
                    "{}: acknowledged {:?}, reports {:?}",
                    g.name, d.executed, d.readings
                ),
                None => format!("{}: not in the broadcast", g.name),
            })
            .collect()
    };
    let v = watch.until_complete("every command acknowledged and reported back", |v| {
        let mut left = unmet(v);
        if !v.gate.engaged {
            left.push(format!("engaged ({})", v.gate.reason));
        }
        left
    });
    stop.store(true, Relaxed);
    sender.join().unwrap();
    let net = v.net.as_ref().unwrap();
    let r = &net.rejected;
    let none = |p: &adrive::snapshot::Pairs<u64>| p.iter().all(|(_, n)| *n == 0);
    assert!(
        none(&r.datagram) && none(&r.intake) && none(&r.refused),
        "{r:?}"
    );
    assert!(
        v.rejections.iter().all(|(_, n)| *n == 0),
        "{:?}",
        v.rejections
    );
    let level = v.device(&devices[4].name).unwrap();
    assert_eq!(level.number("level"), Some(4.0));
    assert_eq!(
        level.reading_units.get("level").map(String::as_str),
        Some("%")
    );
}
