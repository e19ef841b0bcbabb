//! The simulator's CAN bus, as a host sees it: `Sim` started with vehicles/oscc.toml
//! presents one SLCAN adapter on a real pseudo-terminal behind a link named after the
//! bus; a host opens it, brings it onto the bus (`C`, `S6`, `Z0`, `O`), sends frames
//! encoded by the DBC, and reads the kit's reports and the vehicle's own messages. The
//! kit's modules move the simulated vehicle, the vehicle's speed, steering and brake
//! come back on the bus, and the simulator's commands (operator override, fault codes,
//! a bus in error, an unplugged adapter) show on the wire.

mod common;

use adrive::can::dbc::Database;
use adrive::can::Frame;
use adrive::config::{self, VehicleConfig};
use adrive::driver::slcan::proto::{
    encode_command, Command, Decoder, Event, FromAdapter, StatusFlags,
};
use adrive::sim::Sim;
use common::DEADLINE;
use serialport::TTYPort;
use std::collections::HashMap;
use std::io::{Read, Write};
use std::path::Path;
use std::sync::atomic::Ordering::Relaxed;
use std::sync::Arc;
use std::time::{Duration, Instant};

fn oscc() -> VehicleConfig {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("vehicles/oscc.toml");
    config::load(&path).unwrap_or_else(|e| panic!("{e}"))
}

/// A host on the simulated adapter: what it last heard of each message, and the
/// commands it keeps resending (as adrive does, every 40 ms here).
struct Host {
    port: TTYPort,
    db: Arc<Database>,
    decoder: Decoder<FromAdapter>,
    /// Everything but received frames, in order.
    answers: Vec<Event>,
    last: HashMap<String, (Instant, Frame)>,
    keep: HashMap<String, Frame>,
    resent: Instant,
}

impl Host {
    fn open(path: &str, db: &Arc<Database>) -> Host {
        let port = serialport::new(path, 115_200)
            .timeout(Duration::from_millis(5))
            .open_native()
            .unwrap_or_else(|e| panic!("open {path}: {e}"));
        Host {
            port,
            db: db.clone(),
            decoder: Decoder::new(),
            answers: Vec::new(),
            last: HashMap::new(),
            keep: HashMap::new(),
            resent: Instant::now(),
        }
    }

    /// Read what is there (a few milliseconds at most).
    fn pump(&mut self) {
        let mut buf = [0u8; 512];
        if let Ok(n) = self.port.read(&mut buf) {
            self.decoder.push(&buf[..n]);
        }
        while let Some(e) = self.decoder.next() {
            match e {
                Event::Received { frame, .. } => {
                    if let Some(m) = self.db.by_id(frame.id()) {
                        self.last
                            .insert(m.name().to_string(), (Instant::now(), frame));
                    }
                }
                e => self.answers.push(e),
            }
        }
        if self.resent.elapsed() >= Duration::from_millis(40) {
            self.resent = Instant::now();
            let frames: Vec<Frame> = self.keep.values().copied().collect();
            for f in frames {
                self.write(&encode_command(&Command::Transmit(f)));
            }
        }
    }

    fn write(&mut self, bytes: &[u8]) {
        self.port.write_all(bytes).expect("write to the adapter");
    }

    /// The answers to `n` commands (frames are kept aside meanwhile).
    fn answers(&mut self, n: usize) -> Vec<Event> {
        let end = Instant::now() + DEADLINE;
        while self.answers.len() < n {
            assert!(Instant::now() < end, "{n} answers, got {:?}", self.answers);
            self.pump();
        }
        self.answers.drain(..n).collect()
    }

    fn frame(&self, name: &str, values: &[(&str, f64)]) -> Frame {
        let m = self.db.message(name).unwrap();
        m.encode(values).unwrap_or_else(|e| panic!("{name}: {e}"))
    }

    /// Send `name` once.
    fn send(&mut self, name: &str, values: &[(&str, f64)]) {
        let f = self.frame(name, values);
        self.write(&encode_command(&Command::Transmit(f)));
    }

    /// Send `name` now and keep resending it.
    fn keep(&mut self, name: &str, values: &[(&str, f64)]) {
        let f = self.frame(name, values);
        self.keep.insert(name.to_string(), f);
        self.write(&encode_command(&Command::Transmit(f)));
    }

    /// The signal `signal` of the last `message` heard.
    fn signal(&self, message: &str, signal: &str) -> Option<f64> {
        let (_, f) = self.last.get(message)?;
        let m = self.db.message(message).unwrap();
        m.signal(signal).unwrap().decode(f.data())
    }

    /// Pump until `cond` holds; panics with `what` and what was heard at the deadline.
    fn until(&mut self, what: &str, mut cond: impl FnMut(&Host) -> bool) {
        let end = Instant::now() + DEADLINE;
        self.last.clear();
        loop {
            self.pump();
            if cond(self) {
                return;
            }
            assert!(
                Instant::now() < end,
                "timed out waiting for {what}; heard {:?}",
                self.last.keys().collect::<Vec<_>>()
            );
        }
    }
}

/// Open the bus's adapter as adrive does.
fn bring_up(sim: &Sim) -> Host {
    let config = oscc();
    let path = sim.bus_path("kit").expect("the bus's adapter");
    assert!(path.ends_with("/kit"), "{path}");
    let mut host = Host::open(path, &config.buses[0].dbc);
    host.write(b"C\rS6\rZ0\rO\r");
    assert_eq!(host.answers(4), vec![Event::Ok; 4]);
    host
}

fn position(sim: &Sim, name: &str) -> f64 {
    let m = sim.model().lock();
    m.device(m.find(name).unwrap()).position
}

fn near(a: Option<f64>, b: f64, tol: f64) -> bool {
    a.is_some_and(|a| (a - b).abs() <= tol)
}

#[test]
fn a_host_on_the_simulated_adapter_enables_and_commands_the_kit_and_the_vehicle_follows() {
    let config = oscc();
    let sim = Sim::start(&config, None).unwrap();
    assert!(sim.ports.is_empty(), "every device is on the bus");
    let mut host = bring_up(&sim);

    // Before enable, the reports say disabled and a command moves nothing.
    host.keep("STEERING_COMMAND", &[("torque_command", 0.5)]);
    host.until("a disabled steering report", |h| {
        h.signal("STEERING_REPORT", "enabled") == Some(0.0)
    });
    assert_eq!(position(&sim, "steer"), 0.0);

    host.send("STEERING_ENABLE", &[]);
    host.send("THROTTLE_ENABLE", &[]);
    host.keep("THROTTLE_COMMAND", &[("torque_request", 0.6)]);
    host.until(
        "steering and throttle enabled, the wheel at 270°, the car rolling",
        |h| {
            h.signal("STEERING_REPORT", "enabled") == Some(1.0)
                && h.signal("THROTTLE_REPORT", "enabled") == Some(1.0)
                && near(
                    h.signal("KIA_SOUL_STEERING_WHEEL_ANGLE", "steering_wheel_angle"),
                    270.0,
                    0.5,
                )
                && h.signal("KIA_SOUL_WHEEL_SPEED", "wheel_speed_rear_left") > Some(3.0)
        },
    );
    assert!((position(&sim, "steer") - 0.5).abs() < 1e-6);
    assert!((position(&sim, "gas") - 0.6).abs() < 1e-6);
    // The wheel speed is the model's (km/h on the bus; the `speed` role scales it back).
    let kmh = host
        .signal("KIA_SOUL_WHEEL_SPEED", "wheel_speed_rear_left")
        .unwrap();
    let v = sim.model().lock().velocity;
    assert!((kmh / 3.6 - v).abs() < 1.0, "bus {kmh} km/h, model {v} m/s");

    // The operator takes the wheel: the module disables itself and says why; its
    // torque goes.
    let done = sim.apply("override steer on").unwrap();
    assert!(done.contains("operator override on"), "{done}");
    host.until("steering overridden and disabled", |h| {
        h.signal("STEERING_REPORT", "enabled") == Some(0.0)
            && h.signal("STEERING_REPORT", "operator_override") == Some(1.0)
            && h.signal("FAULT_REPORT", "fault_origin_id") == Some(1.0)
    });
    common::wait_for("the steering torque to go", || {
        sim.model().lock().devices[0].command == 0.0
    });
    // Still held: an enable is refused.
    host.send("STEERING_ENABLE", &[]);
    host.until("steering still disabled", |h| {
        h.signal("STEERING_REPORT", "enabled") == Some(0.0)
    });
    // The driver lets go: the module clears its flag and its code by itself.
    sim.apply("override steer off").unwrap();
    host.until("the steering's override cleared by the module", |h| {
        h.signal("STEERING_REPORT", "operator_override") == Some(0.0)
            && h.signal("STEERING_REPORT", "dtcs") == Some(0.0)
    });

    // The steering's fault report disabled the throttle too, as OSCC's firmware does.
    host.until("the throttle disabled by the fault report", |h| {
        h.signal("THROTTLE_REPORT", "enabled") == Some(0.0)
    });
    host.send("THROTTLE_ENABLE", &[]);
    host.until("the throttle enabled again", |h| {
        h.signal("THROTTLE_REPORT", "enabled") == Some(1.0)
    });
    // The condition behind a fault code, by its DBC name.
    let done = sim.apply("fault gas INVALID_SENSOR_VAL on").unwrap();
    assert!(
        done.contains("throttle module's INVALID_SENSOR_VAL condition holds"),
        "{done}"
    );
    host.until("throttle faulted", |h| {
        h.signal("THROTTLE_REPORT", "enabled") == Some(0.0)
            && h.signal("THROTTLE_REPORT", "dtcs") == Some(1.0)
    });
    common::wait_for("the throttle to close", || position(&sim, "gas") == 0.0);
    sim.apply("fault gas INVALID_SENSOR_VAL off").unwrap();
    host.until("the throttle's code cleared by the module", |h| {
        h.signal("THROTTLE_REPORT", "dtcs") == Some(0.0)
    });
    let e = sim.apply("fault gas OVERHEAT on").unwrap_err();
    assert!(e.contains("INVALID_SENSOR_VAL, OPERATOR_OVERRIDE"), "{e}");

    // The brake: its pressure on the bus.
    host.send("BRAKE_ENABLE", &[]);
    host.keep("BRAKE_COMMAND", &[("pedal_command", 0.8)]);
    host.until("brake enabled at 80 bar", |h| {
        h.signal("BRAKE_REPORT", "enabled") == Some(1.0)
            && near(
                h.signal("KIA_SOUL_BRAKE_PRESSURE", "master_cylinder_pressure"),
                80.0,
                0.1,
            )
    });
    assert!((position(&sim, "brake") - 0.8).abs() < 1e-6);
    // Disabled, it leaves the car to its driver: no brake.
    host.keep.remove("BRAKE_COMMAND");
    host.send("BRAKE_DISABLE", &[]);
    host.until("brake disabled and released", |h| {
        h.signal("BRAKE_REPORT", "enabled") == Some(0.0)
            && h.signal("KIA_SOUL_BRAKE_PRESSURE", "master_cylinder_pressure") == Some(0.0)
    });
}

#[test]
fn a_bus_in_error_refuses_frames_delivers_none_and_says_so_in_its_status() {
    let config = oscc();
    let sim = Sim::start(&config, None).unwrap();
    let mut host = bring_up(&sim);
    host.until("reports", |h| h.last.contains_key("BRAKE_REPORT"));
    host.write(b"F\r");
    assert_eq!(host.answers(1), vec![Event::Status(StatusFlags(0))]);

    sim.apply("bus kit off").unwrap();
    // The next frame is refused: BEL (the fault reaches the adapter within a turn).
    let end = Instant::now() + DEADLINE;
    loop {
        host.send("BRAKE_ENABLE", &[]);
        match host.answers(1)[0] {
            Event::Refused => break,
            Event::Sent { .. } => assert!(Instant::now() < end, "never refused"),
            ref e => panic!("{e:?}"),
        }
    }
    host.write(b"F\r");
    let Event::Status(flags) = host.answers(1)[0] else {
        panic!("a status")
    };
    assert!(flags.to_string().contains("bus error"), "{flags}");
    // Nothing arrives from the bus.
    host.last.clear();
    let quiet = Instant::now() + Duration::from_millis(200);
    while Instant::now() < quiet {
        host.pump();
    }
    assert!(host.last.is_empty(), "{:?}", host.last.keys());

    sim.apply("bus kit on").unwrap();
    host.until("reports again", |h| h.last.contains_key("BRAKE_REPORT"));
    host.write(b"F\rF\r");
    assert_eq!(host.answers(2)[1], Event::Status(StatusFlags(0)));

    // The adapter's port faults are the port faults of every device on the bus, named
    // by the bus or by any device on it.
    let done = sim.apply("silent steer on").unwrap();
    assert_eq!(done, "kit: silent on");
    assert!(sim.faults("steer").unwrap().silent.load(Relaxed));
    // What was on its way before is read, then nothing more comes.
    let settle = Instant::now() + Duration::from_millis(100);
    while Instant::now() < settle {
        host.pump();
    }
    host.answers.clear();
    host.last.clear();
    host.write(b"V\r");
    let quiet = Instant::now() + Duration::from_millis(200);
    while Instant::now() < quiet {
        host.pump();
    }
    assert!(host.answers.is_empty() && host.last.is_empty());
    sim.apply("clear kit").unwrap();
    host.write(b"V\r");
    assert_eq!(host.answers(1), vec![Event::Version(*b"1013")]);
}

#[test]
fn an_unplugged_adapter_comes_back_behind_the_same_link_as_a_fresh_one() {
    let config = oscc();
    let sim = Sim::start(&config, None).unwrap();
    let path = sim.bus_path("kit").unwrap().to_string();
    let host = bring_up(&sim);
    drop(host);
    sim.apply("vanish kit 300ms").unwrap();
    common::wait_for("the link to go", || !Path::new(&path).exists());
    common::wait_for("the link to come back", || Path::new(&path).exists());
    assert_eq!(
        sim.buses[0]
            .lives
            .load(std::sync::atomic::Ordering::Relaxed),
        2
    );
    // Plugged in anew: closed, no bitrate; the bring-up works again.
    let mut host = Host::open(&path, &config.buses[0].dbc);
    host.write(b"O\r");
    assert_eq!(host.answers(1), vec![Event::Refused]);
    host.write(b"C\rS6\rZ0\rO\r");
    assert_eq!(host.answers(4), vec![Event::Ok; 4]);
    host.until("reports", |h| h.last.contains_key("THROTTLE_REPORT"));
}

#[test]
fn a_bus_whose_dbc_is_not_oscc_is_refused_at_start_by_name() {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/support");
    let text = r#"
[vehicle]
name = "other kit"

[[bus]]
name = "body"
port = "/dev/null"
dbc = "layouts.dbc"

[[device]]
name = "probe"
kind = "sensor"
driver = "can"
bus = "body"
readings = [{ name = "a", units = "V" }]
status_max_age = "100ms"
reply_timeout = "50ms"
[device.can]
readings = { a = "SHORT.w" }
"#;
    let config = config::parse(text, dir.join("other.toml").to_str().unwrap())
        .unwrap_or_else(|e| panic!("{e}"));
    let e = Sim::start(&config, None).err().expect("refused");
    let e = e.to_string();
    assert!(
        e.starts_with(
            "bus body: the simulator's only kit is OSCC, and this bus's DBC is not OSCC's:"
        ),
        "{e}"
    );
    assert!(e.contains("BRAKE_COMMAND"), "{e}");
}

/// The whole way: the real `adrive --sim --headless` on vehicles/oscc.toml, a planner
/// (`adrive send --rate 20`) engaging and commanding, and `adrive watch --json`
/// reading the kit's reports back through the engine's bus reader. The engage enables
/// the modules, their requests move the simulated vehicle, and the vehicle's messages
/// (steering wheel angle, wheel speed for the `speed` role) come back; when the
/// planner stops, the watchdog's safe state disables the modules.
#[test]
fn a_planner_drives_the_simulated_oscc_kit_through_adrive_and_the_modules_follow() {
    use common::headless::{Adrive, Watch, BIN};
    let manifest = env!("CARGO_MANIFEST_DIR");
    let text = std::fs::read_to_string(format!("{manifest}/vehicles/oscc.toml"))
        .unwrap()
        .replace("[network]\nallow_engage = true\n", "")
        .replace(
            "dbc = \"oscc.dbc\"",
            &format!("dbc = \"{manifest}/vehicles/oscc.dbc\""),
        );
    let adrive = Adrive::start("oscc", &text, "");
    let watch = Watch::start(&adrive.broadcast);
    let kit = ["steer", "gas", "brake"];
    let enabled = |s: &adrive::snapshot::Snapshot, name: &str| {
        s.device(name).and_then(|d| d.number("enabled"))
    };
    watch.until("the kit disabled and the car standing", |s| {
        kit.iter().all(|d| enabled(s, d) == Some(0.0))
            && s.device("car").and_then(|d| d.number("speed")) == Some(0.0)
    });

    let mut planner = std::process::Command::new(BIN)
        .args(["send", "--to", &adrive.listen, "--rate", "20"])
        .args(["engage", "steer 0.3", "gas 0.4", "brake 0"])
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::null())
        .spawn()
        .unwrap();
    let (s, _) = watch.until(
        "engaged, every module enabled, the wheel at 162°, the car rolling",
        |s| {
            s.gate.engaged
                && kit.iter().all(|d| enabled(s, d) == Some(1.0))
                && s.device("steer")
                    .and_then(|d| d.number("angle"))
                    .is_some_and(|a| (a - 0.3 * 540.0).abs() < 0.5)
                && s.device("car")
                    .and_then(|d| d.number("speed"))
                    .is_some_and(|v| v > 0.5)
        },
    );
    assert_eq!(s.device("gas").unwrap().number("override"), Some(0.0));
    assert_eq!(s.device("brake").unwrap().number("pressure"), Some(0.0));

    // The planner stops: the watchdog's safe state, then every module disabled.
    common::stop(&mut planner);
    watch.until("disengaged and every module disabled", |s| {
        !s.gate.engaged && kit.iter().all(|d| enabled(s, d) == Some(0.0))
    });
}
