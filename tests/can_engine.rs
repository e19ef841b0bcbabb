//! The engine on a CAN bus: adrive's bus reader and command threads against a strict
//! SLCAN adapter with the OSCC kit behind it, on a real pseudo-terminal. What the kit
//! hears is logged frame by frame, so the order of enable, command and disable — what a
//! kit's safety depends on — is asserted as the adapter saw it.

mod common;

use adrive::can::dbc::Database;
use adrive::can::Frame;
use adrive::config::VehicleConfig;
use adrive::driver::slcan::proto::{Command as Slcan, Decoder, FromHost};
use adrive::engine::{Engine, Gate};
use adrive::sim::oscc::{Kit, Module};
use adrive::sim::slcan::SlcanPort;
use adrive::value::Command;
use adrive::vehicle::Vehicle;
use common::wait_for;
use parking_lot::Mutex;
use serialport::{SerialPort, TTYPort};
use std::io::{Read, Write};
use std::path::Path;
use std::sync::atomic::{AtomicBool, Ordering::Relaxed};
use std::sync::Arc;
use std::time::{Duration, Instant};

/// The adapter's end: the kit, every frame the host sent (in order, with when), and a
/// switch that makes the adapter refuse (a bus fault).
struct Adapter {
    port: Mutex<SlcanPort<Kit>>,
    heard: Mutex<Vec<(Instant, Frame)>>,
    stop: AtomicBool,
}

impl Adapter {
    fn start(mut master: TTYPort, db: &Database, watchdog: Option<Duration>) -> Arc<Adapter> {
        let now = Instant::now();
        let a = Arc::new(Adapter {
            port: Mutex::new(SlcanPort::new(Kit::new(db, watchdog, now).unwrap(), now)),
            heard: Mutex::new(Vec::new()),
            stop: AtomicBool::new(false),
        });
        let me = a.clone();
        master.set_timeout(Duration::from_millis(2)).unwrap();
        std::thread::spawn(move || {
            let mut decoder = Decoder::<FromHost>::new();
            let mut buf = [0u8; 256];
            let mut out = Vec::new();
            while !me.stop.load(Relaxed) {
                let now = Instant::now();
                match master.read(&mut buf) {
                    Ok(n) if n > 0 => {
                        decoder.push(&buf[..n]);
                        while let Some(c) = decoder.next() {
                            if let Ok(Slcan::Transmit(f)) = c {
                                me.heard.lock().push((now, f));
                            }
                        }
                        me.port.lock().input(&buf[..n], now, &mut out);
                    }
                    Ok(_) => return,
                    Err(e) if e.kind() == std::io::ErrorKind::TimedOut => {}
                    Err(_) => return,
                }
                if me.stop.load(Relaxed) {
                    return;
                }
                me.port.lock().tick(Instant::now(), &mut out);
                if !out.is_empty() && master.write_all(&out).is_err() {
                    return;
                }
                out.clear();
            }
        });
        a
    }

    fn enabled(&self, m: Module) -> bool {
        self.port.lock().node.state(m).enabled
    }

    /// Where the log of what the kit heard stands now.
    fn mark(&self) -> usize {
        self.heard.lock().len()
    }

    /// The identifiers the kit heard, in order, from `mark` on.
    fn ids_since(&self, mark: usize) -> Vec<(u32, Frame)> {
        self.heard.lock()[mark..]
            .iter()
            .map(|(_, f)| (f.id().raw(), *f))
            .collect()
    }
}

impl Drop for Adapter {
    fn drop(&mut self) {
        self.stop.store(true, Relaxed);
    }
}

struct Rig {
    /// The adapter's port is reached through this link, as `/dev/serial/by-id/…`.
    link: tempfile::TempDir,
    adapter: Mutex<Arc<Adapter>>,
    gate: Arc<Gate>,
    engine: Option<Engine>,
    supervisor: Option<(
        adrive::engine::monitor::Monitor,
        adrive::supervisor::Running,
    )>,
    _slave: Mutex<TTYPort>,
}

impl Rig {
    fn start() -> Rig {
        Rig::with_watchdog(None)
    }

    /// The kit's modules disabling themselves after `watchdog` without a command.
    fn with_watchdog(watchdog: Option<Duration>) -> Rig {
        let root = Path::new(env!("CARGO_MANIFEST_DIR"));
        let mut config = adrive::config::load(&root.join("vehicles/oscc.toml")).unwrap();
        let (master, slave) = TTYPort::pair().unwrap();
        let link = common::tempdir("can-engine");
        let path = link.path().join("adapter");
        std::os::unix::fs::symlink(slave.name().unwrap(), &path).unwrap();
        point_at(&mut config, path.to_str().unwrap());
        // These tests are about what the kit says, not about its timing: a machine
        // loaded by other builds must not make the kit look silent.
        for d in &mut config.devices {
            d.status_max_age = Duration::from_secs(1);
        }
        let db = config.buses[0].dbc.clone();
        let adapter = Mutex::new(Adapter::start(master, &db, watchdog));
        let vehicle = Arc::new(Vehicle::new(config, |_| {
            Box::new(|| Err(std::io::ErrorKind::NotFound.into()))
        }));
        let gate = Arc::new(Gate::new(vehicle));
        let engine = Engine::start(gate.clone()).unwrap();
        let rig = Rig {
            link,
            adapter,
            gate,
            engine: Some(engine),
            supervisor: None,
            _slave: Mutex::new(slave),
        };
        wait_for("every device on the bus to report", || {
            rig.gate
                .vehicle()
                .devices()
                .iter()
                .all(|d| d.cached().at.is_some())
        });
        rig
    }

    /// With the gate monitor and the supervisor running as in `adrive run`.
    fn supervised() -> Rig {
        Rig::supervised_with_watchdog(None)
    }

    fn supervised_with_watchdog(watchdog: Option<Duration>) -> Rig {
        let mut rig = Rig::with_watchdog(watchdog);
        let cfg = rig.gate.vehicle().config().supervisor.clone();
        let monitor = adrive::engine::monitor::Monitor::start(rig.gate.clone()).unwrap();
        let sup = adrive::supervisor::start(rig.gate.clone(), cfg, Box::new(|_| {})).unwrap();
        rig.supervisor = Some((monitor, sup));
        rig
    }

    fn faults(&self) -> Vec<String> {
        self.gate
            .vehicle()
            .supervision()
            .faults()
            .iter()
            .map(|f| {
                format!(
                    "{} {:?}: {}",
                    f.device.as_deref().unwrap_or("-"),
                    f.kind,
                    f.cause
                )
            })
            .collect()
    }

    fn adapter(&self) -> Arc<Adapter> {
        self.adapter.lock().clone()
    }

    /// Unplug the adapter: its port closes and its path goes.
    fn unplug(&self) {
        self.adapter().stop.store(true, Relaxed);
        std::fs::remove_file(self.link.path().join("adapter")).unwrap();
    }

    /// Plug a new adapter in behind the same path.
    fn plug(&self) {
        self.plug_with(|_| {});
    }

    /// Plug a new adapter in behind the same path, its kit set up by `setup` first.
    fn plug_with(&self, setup: impl FnOnce(&mut Kit)) {
        let (master, slave) = TTYPort::pair().unwrap();
        let db = self.gate.vehicle().config().buses[0].dbc.clone();
        let a = Adapter::start(master, &db, None);
        setup(&mut a.port.lock().node);
        *self.adapter.lock() = a;
        *self._slave.lock() = slave;
        let slave = self._slave.lock().name().unwrap();
        std::os::unix::fs::symlink(slave, self.link.path().join("adapter")).unwrap();
    }

    fn reading(&self, device: &str, reading: &str) -> Option<f64> {
        let d = self.gate.vehicle().find(device).unwrap();
        d.reading(d.config().reading(reading)?)
    }
}

impl Drop for Rig {
    fn drop(&mut self) {
        if let Some(e) = self.engine.take() {
            e.shutdown(Duration::from_secs(2));
        }
    }
}

fn point_at(config: &mut VehicleConfig, path: &str) {
    config.buses[0].port = path.to_string();
    for d in &mut config.devices {
        d.port = path.to_string();
    }
}

/// The float request of a command frame (bytes 2..6, little-endian, as the DBC says).
fn request(f: &Frame) -> f32 {
    f32::from_le_bytes(f.data()[2..6].try_into().unwrap())
}

const MODULES: [(Module, u32); 3] = [
    (Module::Brake, 0x70),
    (Module::Steering, 0x80),
    (Module::Throttle, 0x90),
];

#[test]
fn the_bus_reader_stores_each_device_s_readings_from_the_kit_s_reports() {
    let rig = Rig::start();
    for d in ["steer", "gas", "brake"] {
        assert_eq!(
            rig.reading(d, "enabled"),
            Some(0.0),
            "{d} is disabled at power-up"
        );
        assert_eq!(rig.reading(d, "override"), Some(0.0));
    }
    rig.adapter().port.lock().node.set_speed(36.0);
    wait_for("the wheel speed as the speed role's m/s", || {
        rig.reading("car", "speed")
            .is_some_and(|v| (v - 10.0).abs() < 0.05)
    });
    let bus = &rig.gate.vehicle().buses()[0];
    assert!(bus.stats.received.load(Relaxed) > 0);
    assert!(bus.down_reason().is_none(), "the adapter is on the bus");
}

#[test]
fn engage_enables_each_module_after_its_safe_command_and_disengage_disables_it_after_the_safe_command(
) {
    let rig = Rig::start();
    let before = rig.adapter().mark();
    rig.gate.engage("test").unwrap();
    wait_for("every module enabled", || {
        MODULES.iter().all(|(m, _)| rig.adapter().enabled(*m))
    });
    let heard = rig.adapter().ids_since(before);
    for (m, base) in MODULES {
        let (enable, command) = (base, base + 2);
        let first_enable = heard.iter().position(|(id, _)| *id == enable).unwrap();
        let commands: Vec<f32> = heard[..first_enable]
            .iter()
            .filter(|(id, _)| *id == command)
            .map(|(_, f)| request(f))
            .collect();
        let safe = if m == Module::Brake { 1.0 } else { 0.0 };
        assert!(
            !commands.is_empty() && commands.iter().all(|&v| v == safe),
            "{m}: only its safe command ({safe}) before its enable: {commands:?}"
        );
    }
    // Commands reach the kit while engaged.
    let v = rig.gate.vehicle();
    let steer = v.find("steer").unwrap().id();
    rig.gate
        .submit(steer, Command::Set(0.3), Instant::now())
        .unwrap();
    wait_for("the steering request", || {
        (rig.adapter()
            .port
            .lock()
            .node
            .state(Module::Steering)
            .request
            - 0.3)
            .abs()
            < 1e-6
    });

    let before = rig.adapter().mark();
    rig.gate
        .disengage(adrive::snapshot::DisengageCause::Disengage {
            by: "console".into(),
        });
    wait_for("every module disabled", || {
        MODULES.iter().all(|(m, _)| !rig.adapter().enabled(*m))
    });
    let heard = rig.adapter().ids_since(before);
    for (m, base) in MODULES {
        let (disable, command) = (base + 1, base + 2);
        let first_disable = heard.iter().position(|(id, _)| *id == disable).unwrap();
        let safe = if m == Module::Brake { 1.0 } else { 0.0 };
        let last_command = heard[..first_disable]
            .iter()
            .rev()
            .find(|(id, _)| *id == command)
            .map(|(_, f)| request(f));
        assert_eq!(
            last_command,
            Some(safe),
            "{m}: its safe command, then disable"
        );
    }
    // While disengaged the safe state is resent, each time followed by the disable.
    let t = rig.adapter().mark();
    wait_for("two resends of the safe state", || {
        rig.adapter()
            .ids_since(t)
            .iter()
            .filter(|(id, _)| *id == 0x71)
            .count()
            >= 2
    });
    assert!(MODULES.iter().all(|(m, _)| !rig.adapter().enabled(*m)));
}

#[test]
fn a_kit_that_is_never_engaged_is_never_enabled() {
    let rig = Rig::start();
    let v = rig.gate.vehicle();
    // Refused at intake while disengaged: nothing reaches the wire.
    assert!(rig
        .gate
        .submit(
            v.find("gas").unwrap().id(),
            Command::Set(0.5),
            Instant::now()
        )
        .is_err());
    // A sentinel: the shutdown's safe state reaches the kit, and still no enable.
    let e = {
        let mut r = rig;
        let engine = r.engine.take().unwrap();
        let (safe, stuck) = engine.shutdown(Duration::from_secs(2));
        assert!(safe && stuck.is_empty(), "{safe} {stuck:?}");
        r
    };
    let heard = e.adapter().ids_since(0);
    assert!(
        heard.iter().any(|(id, _)| *id == 0x71),
        "the brake's disable went out"
    );
    // The first frames each module heard: its disable, at bring-up.
    for (_, base) in MODULES {
        let first = heard
            .iter()
            .find(|(id, _)| id & 0xF0 == base)
            .map(|(id, _)| *id);
        assert_eq!(first, Some(base + 1), "0x{base:02x}: disabled first of all");
    }
    for (_, base) in MODULES {
        assert!(
            !heard.iter().any(|(id, _)| *id == base),
            "no enable of 0x{base:02x} ever: {:?}",
            heard.iter().map(|(id, _)| *id).collect::<Vec<_>>()
        );
    }
}

#[test]
fn the_kit_s_own_override_hands_the_vehicle_to_the_driver_and_disables_every_module() {
    let rig = Rig::supervised();
    rig.gate.engage("test").unwrap();
    wait_for("every module enabled", || {
        MODULES.iter().all(|(m, _)| rig.adapter().enabled(*m))
    });
    // The driver turns the wheel: OSCC's steering module disables itself and says so.
    let mark = rig.adapter().ids_since(0).len();
    rig.adapter()
        .port
        .lock()
        .node
        .set_override(Module::Steering, true, Instant::now());
    wait_for("the driver's override", || {
        rig.gate.overridden() == ["steer"] && !rig.gate.is_engaged()
    });
    assert!(
        rig.faults()
            .iter()
            .any(|f| f.contains("steer Override: the kit reports the driver's override")),
        "{:?}",
        rig.faults()
    );
    // adrive never brakes against the driver, and leaves no module enabled: each is
    // disabled by adrive's own message (the kit's override disables modules by itself,
    // before adrive has said anything).
    wait_for("adrive's disable of every module", || {
        let heard = rig.adapter().ids_since(mark);
        MODULES
            .iter()
            .all(|(_, base)| heard.iter().any(|(id, _)| *id == base + 1))
    });
    assert!(MODULES.iter().all(|(m, _)| !rig.adapter().enabled(*m)));
    // The last brake command before its last disable releases it: adrive never brakes
    // against the driver.
    let heard = rig.adapter().ids_since(0);
    let last_disable = heard.iter().rposition(|(id, _)| *id == 0x71).unwrap();
    let last_command = heard[..last_disable]
        .iter()
        .rev()
        .find(|(id, _)| *id == 0x72)
        .map(|(_, f)| request(f));
    assert_eq!(
        last_command,
        Some(0.0),
        "the manual state releases the brake"
    );
}

#[test]
fn a_module_that_faults_while_engaged_disengages_the_vehicle_naming_its_fault_code() {
    let rig = Rig::supervised();
    rig.gate.engage("test").unwrap();
    wait_for("every module enabled", || {
        MODULES.iter().all(|(m, _)| rig.adapter().enabled(*m))
    });
    rig.adapter()
        .port
        .lock()
        .node
        .set_fault(Module::Brake, "INVALID_SENSOR_VAL", true, Instant::now())
        .unwrap();
    wait_for("the fault to disengage the vehicle", || {
        !rig.gate.is_engaged()
    });
    let faults = rig.faults();
    assert!(
        faults
            .iter()
            .any(|f| f.starts_with("brake DeviceFault: the kit reports")
                && f.contains("INVALID_SENSOR_VAL")),
        "by name: {faults:?}"
    );
    wait_for("every module disabled", || {
        MODULES.iter().all(|(m, _)| !rig.adapter().enabled(*m))
    });
}

#[test]
fn resends_keep_a_kit_s_watchdog_fed_while_engaged_with_no_new_command() {
    // The modules disable themselves after 400 ms without a command (8 resends: room
    // for a loaded machine); adrive resends every command_timeout (50 ms).
    let rig = Rig::with_watchdog(Some(Duration::from_millis(400)));
    rig.gate.engage("test").unwrap();
    wait_for("every module enabled", || {
        MODULES.iter().all(|(m, _)| rig.adapter().enabled(*m))
    });
    let mark = rig.adapter().mark();
    wait_for("two seconds of resends (40 steering commands)", || {
        rig.adapter()
            .ids_since(mark)
            .iter()
            .filter(|(id, _)| *id == 0x82)
            .count()
            >= 40
    });
    let a = rig.adapter();
    let heard = a.heard.lock().clone();
    let gaps = |id: u32| -> f64 {
        let t: Vec<Instant> = heard
            .iter()
            .filter(|(_, f)| f.id().raw() == id)
            .map(|(t, _)| *t)
            .collect();
        t.windows(2)
            .map(|w| (w[1] - w[0]).as_secs_f64() * 1e3)
            .fold(0.0, f64::max)
    };
    for (m, base) in MODULES {
        assert!(
            rig.adapter().enabled(m),
            "{m} still enabled (longest gap between its commands: {:.0} ms; notes {:?})",
            gaps(base + 2),
            a.port.lock().node.take_notes()
        );
    }
    assert!(rig.gate.is_engaged());
}

#[test]
fn a_bus_fault_is_a_fault_of_every_device_on_the_bus_in_the_adapter_s_words() {
    let rig = Rig::supervised();
    rig.adapter().port.lock().adapter.set_bus_fault(true);
    wait_for("every device on the bus faulted", || {
        let f = rig.faults();
        ["steer", "gas", "brake", "car"].iter().all(|d| {
            f.iter()
                .any(|x| x.starts_with(&format!("{d} ")) && x.contains("bus error"))
        })
    });
    // Engage is refused while the bus is down.
    assert!(rig.gate.engage("test").is_err());
    rig.adapter().port.lock().adapter.set_bus_fault(false);
    wait_for("the faults to clear once the bus is back", || {
        rig.faults().is_empty()
    });
}

#[test]
fn an_adapter_unplugged_faults_every_device_on_its_bus_and_is_found_again_behind_its_path() {
    let rig = Rig::supervised();
    rig.unplug();
    wait_for("every device on the bus disconnected or silent", || {
        let f = rig.faults();
        ["steer", "gas", "brake", "car"]
            .iter()
            .all(|d| f.iter().any(|x| x.starts_with(&format!("{d} "))))
    });
    assert!(
        rig.gate.engage("test").is_err(),
        "no engage without the bus"
    );
    rig.plug();
    wait_for("the faults to clear once the adapter is back", || {
        rig.faults().is_empty()
    });
    let bus = &rig.gate.vehicle().buses()[0];
    assert!(
        bus.stats.opens.load(Relaxed) >= 2,
        "brought onto the bus again"
    );
    rig.gate.engage("test").unwrap();
    wait_for("every module enabled on the new adapter", || {
        MODULES.iter().all(|(m, _)| rig.adapter().enabled(*m))
    });
}

#[test]
fn a_module_that_disables_itself_while_engaged_is_a_fault_that_disengages() {
    let rig = Rig::supervised();
    rig.gate.engage("test").unwrap();
    wait_for("every module enabled", || {
        MODULES.iter().all(|(m, _)| rig.adapter().enabled(*m))
    });
    // The throttle module resets (it hears a disable from elsewhere on the bus): no
    // fault code, just disabled.
    let db = rig.gate.vehicle().config().buses[0].dbc.clone();
    let disable = db.message("THROTTLE_DISABLE").unwrap().encode(&[]).unwrap();
    {
        use adrive::sim::slcan::BusNode;
        let a = rig.adapter();
        a.port.lock().node.receive(&disable, Instant::now());
    }
    wait_for("the throttle's fault to disengage the vehicle", || {
        !rig.gate.is_engaged()
    });
    let faults = rig.faults();
    assert!(
        faults
            .iter()
            .any(|f| f.starts_with("gas DeviceFault: the kit reports gas disabled while engaged")),
        "{faults:?}"
    );
    wait_for("the other modules disabled by adrive", || {
        !rig.adapter().enabled(Module::Brake) && !rig.adapter().enabled(Module::Steering)
    });
}

#[test]
fn a_kit_left_enabled_is_disabled_as_soon_as_its_adapter_is_on_the_bus() {
    let rig = Rig::start();
    rig.unplug();
    wait_for("the bus down", || {
        rig.gate.vehicle().buses()[0].down_reason().is_some()
    });
    // Another program (or a killed adrive) left every module enabled.
    let db = rig.gate.vehicle().config().buses[0].dbc.clone();
    rig.plug_with(|kit| {
        use adrive::sim::slcan::BusNode;
        for name in ["BRAKE_ENABLE", "STEERING_ENABLE", "THROTTLE_ENABLE"] {
            let f = db.message(name).unwrap().encode(&[]).unwrap();
            kit.receive(&f, Instant::now());
        }
        assert!(kit.state(Module::Brake).enabled);
    });
    wait_for("every module disabled by adrive, never engaged", || {
        MODULES.iter().all(|(m, _)| !rig.adapter().enabled(*m))
    });
    assert!(!rig.gate.is_engaged());
}

/// The incident: on the OSCC kit, after the driver let go of the wheel the module kept
/// reporting its override flag, so `C` (clear) was refused with "the driver is still
/// moving steer" for ever and engage with it, even after restarting adrive. OSCC's
/// firmware clears the flag and the code on the first turn the driver no longer
/// overrides; a sensor fault clears the same way once the sensor reads valid again.
#[test]
fn the_kit_clears_its_override_and_its_sensor_fault_itself_and_the_vehicle_engages_again() {
    let rig = Rig::supervised();
    let all_enabled = |rig: &Rig| MODULES.iter().all(|(m, _)| rig.adapter().enabled(*m));
    rig.gate.engage("test").unwrap();
    wait_for("every module enabled", || all_enabled(&rig));
    let kit = |f: &dyn Fn(&mut Kit)| f(&mut rig.adapter().port.lock().node);
    kit(&|k| k.set_override(Module::Steering, true, Instant::now()));
    wait_for("the driver's override", || {
        rig.gate.overridden() == ["steer"] && !rig.gate.is_engaged()
    });
    assert!(rig.gate.clear_overrides().is_err(), "the hand is still on");
    kit(&|k| k.set_override(Module::Steering, false, Instant::now()));
    wait_for("the kit to report the override gone", || {
        rig.reading("steer", "override") == Some(0.0)
    });
    wait_for("the clear to be accepted", || {
        rig.gate.clear_overrides() == Ok(vec!["steer".to_string()])
    });
    rig.gate.engage("test").unwrap();
    wait_for("every module enabled again", || all_enabled(&rig));

    // The brake's pedal sensor reads grounded: the module faults, the vehicle stops.
    kit(&|k| {
        k.set_fault(Module::Brake, "INVALID_SENSOR_VAL", true, Instant::now())
            .unwrap()
    });
    wait_for("the sensor fault to disengage the vehicle", || {
        !rig.gate.is_engaged()
            && rig
                .faults()
                .iter()
                .any(|f| f.contains("INVALID_SENSOR_VAL"))
    });
    // It reads valid again: the module clears its code, and nobody else has to.
    kit(&|k| {
        k.set_fault(Module::Brake, "INVALID_SENSOR_VAL", false, Instant::now())
            .unwrap()
    });
    wait_for("the brake to report no fault code", || {
        rig.gate
            .vehicle()
            .find("brake")
            .unwrap()
            .cached()
            .reading
            .fault
            == 0
    });
    wait_for("the engage to be accepted", || {
        rig.gate.engage("test").is_ok()
    });
    wait_for("every module enabled again", || all_enabled(&rig));
    // Engaged and enabled for ten more brake reports: nothing faults it again.
    let mark = rig.adapter().mark();
    wait_for("ten commands to the brake while engaged", || {
        rig.adapter()
            .ids_since(mark)
            .iter()
            .filter(|(id, _)| *id == 0x72)
            .count()
            >= 10
    });
    assert!(rig.gate.is_engaged(), "{:?}", rig.faults());
    assert!(all_enabled(&rig));
}
