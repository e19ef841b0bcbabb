//! Interoperability: adrive's Modbus RTU driver against pymodbus, a third-party Modbus
//! implementation, serving RTU on a real pseudo-terminal. The test provides its own
//! Python environment (a virtual environment under `target/` with pinned pymodbus and
//! pyserial) when the system Python lacks them, and fails loudly — never skips — when
//! that is impossible.

mod common;
#[path = "support/python_env.rs"]
mod python_env;

use adrive::config::protocol_map::{Field, ModbusMap, Wire};
use adrive::driver::modbus::ModbusDriver;
use adrive::driver::{Driver, DriverError};
use adrive::value::Command;
use common::DEADLINE;
use serialport::{SerialPort, TTYPort};
use std::io::{BufRead, BufReader};
use std::process::{Child, Command as Process, Stdio};
use std::sync::{mpsc, OnceLock};
use std::time::{Duration, Instant};

const PYMODBUS: &str = "pymodbus==3.8.6";
const PYSERIAL: &str = "pyserial==3.5";
const BAUD: u32 = 115_200;

/// A Python interpreter that can import the pinned pymodbus and pyserial.
fn python() -> &'static str {
    static PYTHON: OnceLock<String> = OnceLock::new();
    PYTHON.get_or_init(|| {
        python_env::python("pymodbus-venv", &[PYMODBUS, PYSERIAL], "serial, pymodbus")
    })
}

/// pymodbus serving RTU on one end of a pseudo-terminal pair.
struct Server {
    child: Child,
    writes: mpsc::Receiver<String>,
    /// The end adrive's driver talks through.
    link: TTYPort,
    _device_end: TTYPort,
}

impl Drop for Server {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

fn start_server() -> Server {
    let (link, device_end) = TTYPort::pair().expect("pseudo-terminal pair");
    let path = device_end.name().expect("pty path");
    let script = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/tests/support/pymodbus_server.py"
    );
    let mut child = Process::new(python())
        .arg(script)
        .arg(&path)
        .arg(BAUD.to_string())
        .stdout(Stdio::piped())
        .stderr(Stdio::inherit())
        .spawn()
        .expect("start the pymodbus server");
    let (tx, writes) = mpsc::channel();
    let out = child.stdout.take().unwrap();
    std::thread::spawn(move || {
        for line in BufReader::new(out).lines().map_while(Result::ok) {
            if tx.send(line).is_err() {
                break;
            }
        }
    });
    let ready = writes
        .recv_timeout(DEADLINE)
        .expect("pymodbus server started");
    assert_eq!(ready, "READY");
    Server {
        child,
        writes,
        link,
        _device_end: device_end,
    }
}

/// Alice's steering drive's register map, as her vehicle file has it.
fn steer_map() -> ModbusMap {
    match adrive::config::VehicleConfig::alice()
        .device("steer")
        .unwrap()
        .wire
        .clone()
    {
        Wire::Modbus(m) => m,
        other => panic!("{other:?}"),
    }
}

/// Poll until the server answers (it opens the port just after printing READY).
fn first_poll(drv: &mut ModbusDriver, link: &mut TTYPort) -> adrive::value::Reading {
    let end = Instant::now() + DEADLINE;
    loop {
        match drv.poll(link) {
            Ok(r) => return r,
            Err(DriverError::Timeout(_)) if Instant::now() < end => continue,
            Err(e) => panic!("poll against pymodbus failed: {e}"),
        }
    }
}

#[test]
fn the_modbus_driver_reads_and_writes_a_pymodbus_rtu_server() {
    let mut server = start_server();
    let mut drv = ModbusDriver::new(steer_map(), BAUD, Duration::from_millis(300));
    let r = first_poll(&mut drv, &mut server.link);
    assert_eq!(r.get(0), Some(0.25), "position");
    assert_eq!(r.get(1), Some(-0.1), "velocity");
    assert_eq!(r.fault, 0);

    drv.command(&mut server.link, Command::Set(-0.5)).unwrap();
    let write = server
        .writes
        .recv_timeout(DEADLINE)
        .expect("the server saw a write");
    assert_eq!(write, format!("WRITE 0 {}", (-5000i16) as u16));
}

#[test]
fn pymodbus_exceptions_and_silence_become_named_errors() {
    let mut server = start_server();
    let mut good = ModbusDriver::new(steer_map(), BAUD, Duration::from_millis(300));
    first_poll(&mut good, &mut server.link);

    // A register the server does not have: exception 02.
    let mut map = steer_map();
    map.fields
        .retain(|(_, f)| matches!(f, Field::Reading { index: 0, .. }));
    map.fields[0].0 = 40;
    let mut off_map = ModbusDriver::new(map, BAUD, Duration::from_millis(300));
    match off_map.poll(&mut server.link) {
        Err(DriverError::Refused(why)) => {
            assert!(why.to_lowercase().contains("illegal data address"), "{why}")
        }
        other => panic!("expected an illegal data address exception, got {other:?}"),
    }

    // Another slave id: a real server stays silent.
    let mut stranger = ModbusDriver::new(
        ModbusMap {
            slave: 9,
            ..steer_map()
        },
        BAUD,
        Duration::from_millis(200),
    );
    let r = stranger.poll(&mut server.link);
    assert!(matches!(r, Err(DriverError::Timeout(_))), "{r:?}");

    // The bus is not wedged: the right slave still answers.
    assert_eq!(good.poll(&mut server.link).unwrap().get(0), Some(0.25));
}
