//! Each driver against its simulated device over a real pseudo-terminal at the
//! simulator's baud timing, and the fault cases: bad CRC, garbage, silence, a slow
//! device, and a port that disappears and comes back behind the same path.

mod common;

use adrive::config::VehicleConfig;
use adrive::driver::{self, DriverError};
use adrive::sim::{wire_time, Sim};
use adrive::snapshot::Blocker;
use adrive::value::Command;
use common::{wait_for, Rig};
use std::sync::atomic::Ordering::Relaxed;
use std::time::{Duration, Instant};

/// Open a simulated device and its driver as adrive would.
fn connect(
    sim: &Sim,
    config: &VehicleConfig,
    name: &str,
) -> (Box<dyn driver::Link>, Box<dyn driver::Driver>) {
    let d = config.device(name).unwrap();
    let mut link = driver::open_serial(sim.path(name).unwrap(), d.baud, d.reply_timeout).unwrap();
    let mut drv = driver::build(d);
    drv.open(link.as_mut()).expect("driver open");
    (link, drv)
}

#[test]
fn modbus_actuators_answer_at_their_baud_timing() {
    let config = VehicleConfig::alice();
    let sim = Sim::start(&config, None).unwrap();
    // The transmission runs at 9600 baud: a poll (8-byte request, 9-byte reply) takes
    // at least 17 character times on the wire.
    let (mut link, mut drv) = connect(&sim, &config, "trans");
    let t = Instant::now();
    let r = drv.poll(link.as_mut()).unwrap();
    let took = t.elapsed();
    assert_eq!(r.get(0), Some(0.0), "park");
    assert!(took >= wire_time(17, 9600), "poll took {took:?}");
    drv.command(link.as_mut(), Command::State(2)).unwrap();
    // Writing a single register: 8 bytes each way.
    let t = Instant::now();
    drv.command(link.as_mut(), Command::State(2)).unwrap();
    assert!(t.elapsed() >= wire_time(16, 9600));

    let (mut link, mut drv) = connect(&sim, &config, "steer");
    drv.command(link.as_mut(), Command::Set(0.5)).unwrap();
    wait_for("the wheel to move", || {
        drv.poll(link.as_mut()).unwrap().get(0).unwrap() > 0.1
    });
}

#[test]
fn the_elm327_driver_initialises_and_reads_engine_data() {
    let config = VehicleConfig::alice();
    let sim = Sim::start(&config, None).unwrap();
    let t = Instant::now();
    let (mut link, mut drv) = connect(&sim, &config, "obd");
    // ATZ is slow on a real adapter (and on the simulated one).
    assert!(
        t.elapsed() >= Duration::from_millis(900),
        "{:?}",
        t.elapsed()
    );
    let r = drv.poll(link.as_mut()).unwrap();
    let rpm = r.get(0).unwrap();
    assert!((600.0..800.0).contains(&rpm), "idle rpm {rpm}");
    assert_eq!(r.get(1), Some(0.0), "speed");
    assert!(r.get(2).is_some(), "coolant");
    assert_eq!(r.get(3), Some(1.0), "running");
    assert!(matches!(
        drv.command(link.as_mut(), Command::Set(1.0)),
        Err(DriverError::Unsupported(_))
    ));
}

#[test]
fn the_line_protocol_estop_reports_state_changes() {
    let config = VehicleConfig::alice();
    let sim = Sim::start(&config, None).unwrap();
    let (mut link, mut drv) = connect(&sim, &config, "estop");
    assert_eq!(drv.poll(link.as_mut()).unwrap().get(0), Some(2.0), "run");
    sim.apply("estop pause").unwrap();
    assert_eq!(drv.poll(link.as_mut()).unwrap().get(0), Some(1.0), "pause");
}

/// Run the whole simulated Alice; inject `fault` into `victim` and check it is counted
/// as `kind` while steering keeps working.
fn fault_is_counted_and_isolated(victim: &str, fault: &str, kind: u32) {
    let rig = Rig::start(adrive::config::ALICE_TOML);
    rig.engage();
    let d = rig.device(victim);
    rig.sim.apply(&format!("{fault} {victim} on")).unwrap();
    wait_for("the fault to be counted", || {
        d.stats().status_errors.load(Relaxed) >= 3
    });
    wait_for("the device to be marked faulty", || d.is_faulty());
    assert_eq!(d.health().status_error.load(Relaxed), kind, "{fault}");
    assert!(d.cached().age().unwrap() > Duration::ZERO);

    let steer = rig.device("steer");
    let before = steer.stats().executed.load(Relaxed);
    for v in [0.3, -0.3] {
        rig.gate
            .submit(rig.id("steer"), Command::Set(v), Instant::now())
            .unwrap();
        wait_for("steering to execute", || {
            steer.slot().executed() == Some(Command::Set(v))
        });
    }
    assert!(steer.stats().executed.load(Relaxed) >= before + 2);
    assert!(!steer.is_faulty());

    rig.sim.apply(&format!("clear {victim}")).unwrap();
    wait_for("the device to recover", || !d.is_faulty());
}

#[test]
fn a_bad_crc_is_rejected_and_counted_as_garbled() {
    fault_is_counted_and_isolated("brake", "corrupt", 2);
}

#[test]
fn garbage_is_rejected_and_counted_as_garbled() {
    fault_is_counted_and_isolated("gas", "garbage", 2);
}

#[test]
fn silence_is_counted_as_timeouts() {
    fault_is_counted_and_isolated("trans", "silent", 1);
}

/// Alice's replies allowed 1 s ([`common::tolerant_text`]): 50 ms slow is then well
/// within its reply timeout however late a loaded machine runs the simulator, where her
/// own 100 ms left 50 ms for the scheduler.
#[test]
fn a_slow_device_shows_in_its_transaction_times() {
    let rig = Rig::start(&common::tolerant_text(adrive::config::ALICE_TOML));
    let gas = rig.device("gas");
    wait_for("a few polls", || gas.stats().polls.load(Relaxed) >= 3);
    rig.sim.apply("slow gas 50").unwrap();
    let polls = gas.stats().polls.load(Relaxed);
    wait_for("slow polls", || {
        gas.stats().polls.load(Relaxed) >= polls + 10
    });
    let s = gas.stats().status_txn.summary();
    assert!(s.max_us.unwrap() > 50_000.0, "{s:?}");
    assert!(!gas.is_faulty(), "slow but within its reply timeout");
}

/// A USB adapter unplugged and plugged back in: the port vanishes, the device is
/// marked faulty, and adrive reopens it (behind the same path, on a new
/// pseudo-terminal) while the other devices never stop.
#[test]
fn a_port_that_disappears_comes_back_behind_the_same_path() {
    let rig = Rig::start(adrive::config::ALICE_TOML);
    rig.engage();
    let brake = rig.device("brake");
    assert_eq!(brake.port_health().opens.load(Relaxed), 1);
    rig.sim
        .faults("brake")
        .unwrap()
        .vanish(Duration::from_millis(1500));
    wait_for("the brake to be marked faulty", || brake.is_faulty());
    assert!(!brake.health().connected.load(Relaxed));

    let steer = rig.device("steer");
    rig.gate
        .submit(rig.id("steer"), Command::Set(0.4), Instant::now())
        .unwrap();
    wait_for("steering meanwhile", || {
        steer.slot().executed() == Some(Command::Set(0.4))
    });

    wait_for("the brake to come back", || {
        brake.port_health().opens.load(Relaxed) >= 2 && !brake.is_faulty()
    });
    let port = rig.sim.ports.iter().find(|p| p.name == "brake").unwrap();
    // A new pseudo-terminal (the kernel may reuse the number, as with ttyUSBn).
    assert_eq!(port.lives.load(Relaxed), 2);
    rig.gate
        .submit(rig.id("brake"), Command::Set(0.8), Instant::now())
        .unwrap();
    wait_for("the brake to take commands again", || {
        brake.slot().executed() == Some(Command::Set(0.8))
    });
}

/// The first OBD answer may take 10 s (an ELM327 searches the car's protocols after it
/// is opened), and meanwhile the engage gate said only "obd has not reported yet". The
/// test plays the adapter on a real pseudo-terminal: it answers the reset and settings,
/// then holds its first answer as a search does; the blocker says why it waits (the
/// speed is read from it: engaging needs it), and is gone once the adapter answers.
#[test]
fn an_elm327_searching_the_protocols_is_named_as_such_by_the_engage_gate() {
    use adrive::engine::Gate;
    use adrive::vehicle::Vehicle;
    use serialport::SerialPort;
    use std::io::{Read, Write};
    use std::sync::Arc;

    let (mut adapter, port) = serialport::TTYPort::pair().expect("a pseudo-terminal pair");
    adapter.set_timeout(common::DEADLINE).unwrap();
    let toml = format!(
        "[vehicle]\nname = \"obd only\"\n[vehicle.roles]\nspeed = \"obd.speed\"\n\
         [[device]]\nname = \"obd\"\nkind = \"sensor\"\n\
         readings = [\"rpm\", \"speed\"]\ndriver = \"elm327\"\nport = \"{}\"\nbaud = 38400\n\
         status_period = \"10s\"\nstatus_max_age = \"10s\"\nreply_timeout = \"500ms\"\n",
        port.name().unwrap()
    );
    let config = adrive::config::parse(&toml, "obd.toml").unwrap();
    let vehicle = Arc::new(Vehicle::new(config, |c| {
        let (path, baud, timeout) = (c.port.clone(), c.baud, c.reply_timeout);
        Box::new(move || driver::open_serial(&path, baud, timeout))
    }));
    let gate = Arc::new(Gate::new(vehicle.clone()));
    let engine = adrive::engine::Engine::start(gate.clone()).unwrap();
    let mut writer = adapter.try_clone_native().unwrap();
    let mut request = || {
        let mut line = Vec::new();
        let mut b = [0u8];
        while b[0] != b'\r' {
            adapter.read_exact(&mut b).expect("a request from adrive");
            line.push(b[0]);
        }
        String::from_utf8(line).unwrap()
    };
    assert_eq!(request(), "ATZ\r");
    assert_eq!(
        gate.blockers(),
        [Blocker::NotReported {
            device: "obd".into()
        }],
        "not open yet"
    );
    let mut answer = |text: &str| writer.write_all(text.as_bytes()).unwrap();
    answer("\r\rELM327 v1.5\r\r>");
    for setting in driver::elm327::INIT {
        assert_eq!(request(), format!("{setting}\r"));
        answer("OK\r\r>");
    }
    assert_eq!(request(), "010C\r");
    answer("SEARCHING...\r");
    wait_for("the blocker to say why obd waits", || {
        gate.blockers()
            == [Blocker::Searching {
                device: "obd".into(),
                up_to_s: 10,
            }]
    });
    answer("41 0C 1A F8 \r\r>");
    assert_eq!(request(), "010D\r");
    answer("41 0D 00 \r\r>");
    wait_for("obd to report", || gate.blockers().is_empty());
    engine.shutdown(Duration::from_secs(2));
}
