//! The simulator: every device of the vehicle on its own pseudo-terminal, speaking its
//! wire protocol, in front of one shared [`model::Model`] of the vehicle.
//!
//! A pseudo-terminal passes bytes instantly, so each device's port loop holds every
//! reply for the time the request and the reply take on the wire at the configured
//! baud (10 bits a byte) plus the device's turnaround, and serves one transaction at a
//! time, as the real device does. Faults can be injected per device ([`Faults`]).
//!
//! Each device is reached through a stable symbolic link (`…/adrive-sim-PID-N/steer`)
//! to its current pseudo-terminal, just as `/dev/serial/by-id/…` points at the current
//! `ttyUSBn`: when a device "vanishes" its pseudo-terminal closes and the link goes;
//! when it comes back it does so on a new pseudo-terminal behind the same link.

pub mod device;
pub mod elm327;
pub mod line;
pub mod modbus;
pub mod model;
#[cfg(test)]
pub(crate) mod test_serve;

use crate::config::{DeviceConfig, DriverKind, VehicleConfig};
use crate::value::{Command, EstopState, Gear, Reading, Role};
use crossbeam_channel::Sender;
use device::{Plant, Responder};
use model::Model;
use parking_lot::Mutex;
use serialport::{SerialPort, TTYPort};
use std::io::{Read, Write};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, AtomicU32, AtomicU64, Ordering::Relaxed};
use std::sync::Arc;
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

/// Faults that can be injected into one simulated device, from tests, from
/// `adrive sim`'s standard input and from the console's bench view.
#[derive(Default, Debug)]
pub struct Faults {
    /// Swallow requests without answering.
    pub silent: AtomicBool,
    /// Answer every request with noise instead of the reply.
    pub garbage: AtomicBool,
    /// Flip a bit in the last byte of every reply (a bad CRC or checksum).
    pub corrupt: AtomicBool,
    /// Extra reply delay, in milliseconds.
    pub slow_ms: AtomicU64,
    /// Pending request to vanish for this many milliseconds (0: none).
    vanish_ms: AtomicU64,
}

/// The kinds of fault, by name, for command lines and keys.
pub const FAULT_NAMES: [&str; 5] = ["silent", "garbage", "corrupt", "slow", "vanish"];

impl Faults {
    /// Close the device's port now and bring it back, on a new pseudo-terminal behind
    /// the same path, after `down`.
    pub fn vanish(&self, down: Duration) {
        self.vanish_ms
            .store(down.as_millis().max(1) as u64, Relaxed);
    }

    /// Switch a fault by name: `silent`, `garbage`, `corrupt` take on/off; `slow` a
    /// delay in ms (0 off); `vanish` a down time in ms.
    pub fn set(&self, name: &str, arg: &str) -> Result<String, String> {
        let on = || match arg {
            "on" | "1" | "true" => Ok(true),
            "off" | "0" | "false" => Ok(false),
            _ => Err(format!("{name} takes on or off, got {arg:?}")),
        };
        let ms = || {
            arg.trim_end_matches("ms")
                .parse::<u64>()
                .map_err(|_| format!("{name} takes milliseconds, got {arg:?}"))
        };
        match name {
            "silent" => self.silent.store(on()?, Relaxed),
            "garbage" => self.garbage.store(on()?, Relaxed),
            "corrupt" => self.corrupt.store(on()?, Relaxed),
            "slow" => self.slow_ms.store(ms()?, Relaxed),
            "vanish" => self.vanish(Duration::from_millis(ms()?)),
            _ => {
                return Err(format!(
                    "unknown fault {name:?}: expected one of {}",
                    FAULT_NAMES.join(", ")
                ))
            }
        }
        Ok(format!("{name} {arg}"))
    }

    /// Clear every fault.
    pub fn clear(&self) {
        self.silent.store(false, Relaxed);
        self.garbage.store(false, Relaxed);
        self.corrupt.store(false, Relaxed);
        self.slow_ms.store(0, Relaxed);
    }

    /// The active faults, in words.
    pub fn describe(&self) -> String {
        let mut v = Vec::new();
        for (name, on) in [
            ("silent", self.silent.load(Relaxed)),
            ("garbage", self.garbage.load(Relaxed)),
            ("corrupt", self.corrupt.load(Relaxed)),
        ] {
            if on {
                v.push(name.to_string());
            }
        }
        let slow = self.slow_ms.load(Relaxed);
        if slow > 0 {
            v.push(format!("slow {slow}ms"));
        }
        if v.is_empty() {
            "none".into()
        } else {
            v.join(", ")
        }
    }
}

/// Something a simulated device received, for `adrive sim`'s log.
#[derive(Clone, Debug)]
pub struct SimEvent {
    pub role: Role,
    pub at: Instant,
    /// The command the device applied.
    pub command: Command,
    /// The raw request bytes; empty when the device acted on its own.
    pub request: Vec<u8>,
    /// Why, when the device acted on its own (its watchdog).
    pub note: Option<String>,
    /// The simulated vehicle's speed (m/s, signed) and gear when the command arrived.
    pub speed: f64,
    pub gear: Gear,
}

/// One simulated device's port.
pub struct SimPort {
    pub role: Role,
    /// The stable path adrive (or any tool) opens: a link to the current pty.
    pub path: String,
    /// The pseudo-terminal behind the link right now.
    pub pty: Arc<Mutex<String>>,
    pub faults: Arc<Faults>,
    /// How many times the device came (back) up.
    pub lives: Arc<AtomicU32>,
}

/// The running simulator.
pub struct Sim {
    pub ports: Vec<SimPort>,
    dir: PathBuf,
    model: Arc<Mutex<Model>>,
    stop: Arc<AtomicBool>,
    threads: Vec<JoinHandle<()>>,
}

/// Wire time of `bytes` at `baud`, 10 bits a byte (start, 8 data, stop).
pub fn wire_time(bytes: usize, baud: u32) -> Duration {
    Duration::from_nanos((bytes as u64 * 10 * 1_000_000_000) / baud.max(1) as u64)
}

fn responder_for(c: &DeviceConfig) -> Box<dyn Responder> {
    match (c.driver, &c.modbus) {
        (DriverKind::Modbus, Some(m)) => {
            Box::new(modbus::ModbusSlave::new(m.slave, m.registers.clone()))
        }
        (DriverKind::Elm327, _) => Box::new(elm327::Elm327Emulator::new()),
        (DriverKind::Line | DriverKind::Modbus, _) => Box::new(line::LineDevice),
    }
}

struct DevicePlant<'a> {
    role: Role,
    model: &'a Mutex<Model>,
    applied: Option<Command>,
    /// Speed and gear when the command arrived.
    before: (f64, Gear),
}

impl Plant for DevicePlant<'_> {
    fn reading(&mut self) -> Reading {
        self.model.lock().reading(self.role)
    }
    fn command(&mut self, command: Command) -> Result<(), String> {
        let mut m = self.model.lock();
        m.step();
        self.before = (m.velocity, m.gear);
        m.command(self.role, command)?;
        self.applied = Some(command);
        Ok(())
    }
}

static SIM_COUNT: AtomicU32 = AtomicU32::new(0);

/// A fresh pseudo-terminal pair, the link at `link` pointing at its device end.
fn bring_up(link: &Path) -> std::io::Result<(TTYPort, TTYPort, String)> {
    let (mut master, slave) = TTYPort::pair().map_err(std::io::Error::from)?;
    let pty = slave
        .name()
        .ok_or_else(|| std::io::Error::other("pseudo-terminal has no name"))?;
    master
        .set_timeout(Duration::from_millis(20))
        .map_err(std::io::Error::from)?;
    let _ = std::fs::remove_file(link);
    std::os::unix::fs::symlink(&pty, link)?;
    Ok((master, slave, pty))
}

impl Sim {
    /// Start a simulated device for every device of `config`. `events`, if given,
    /// receives every command a device applies.
    pub fn start(config: &VehicleConfig, events: Option<Sender<SimEvent>>) -> std::io::Result<Sim> {
        let dir = std::env::temp_dir().join(format!(
            "adrive-sim-{}-{}",
            std::process::id(),
            SIM_COUNT.fetch_add(1, Relaxed)
        ));
        std::fs::create_dir_all(&dir)?;
        let model = Arc::new(Mutex::new(Model::new()));
        let stop = Arc::new(AtomicBool::new(false));
        let mut ports = Vec::new();
        let mut threads = Vec::new();
        for c in &config.devices {
            let link = dir.join(c.name.as_str());
            let (master, slave, pty) = bring_up(&link)?;
            let port = SimPort {
                role: c.name,
                path: link.display().to_string(),
                pty: Arc::new(Mutex::new(pty)),
                faults: Arc::new(Faults::default()),
                lives: Arc::new(AtomicU32::new(1)),
            };
            let dev = Served {
                config: c.clone(),
                link,
                model: model.clone(),
                stop: stop.clone(),
                faults: port.faults.clone(),
                pty: port.pty.clone(),
                lives: port.lives.clone(),
                events: events.clone(),
            };
            let h = std::thread::Builder::new()
                .name(format!("sim/{}", c.name))
                .spawn(move || dev.run(master, slave))?;
            threads.push(h);
            ports.push(port);
        }
        Ok(Sim {
            ports,
            dir,
            model,
            stop,
            threads,
        })
    }

    fn port(&self, role: Role) -> Option<&SimPort> {
        self.ports.iter().find(|p| p.role == role)
    }

    /// The stable path of `role`'s device.
    pub fn path(&self, role: Role) -> Option<&str> {
        self.port(role).map(|p| p.path.as_str())
    }

    pub fn faults(&self, role: Role) -> Option<&Arc<Faults>> {
        self.port(role).map(|p| &p.faults)
    }

    /// The simulated vehicle, for tests and the console's bench view.
    pub fn model(&self) -> &Arc<Mutex<Model>> {
        &self.model
    }

    pub fn set_estop(&self, state: EstopState) {
        self.model.lock().estop = state;
    }

    /// Point every device of `config` at its simulated port.
    pub fn patch(&self, config: &mut VehicleConfig) {
        for d in &mut config.devices {
            if let Some(p) = self.path(d.name) {
                d.port = p.to_string();
            }
        }
    }

    /// Apply one line of the simulator's little command language (used by `adrive sim`
    /// on its standard input): `estop pause|run|disable`, `stall`,
    /// `nostart on|off`, `jam steer`, `stuck steer on|off`, `bias DEVICE X`,
    /// `FAULT DEVICE on|off|MS`, `clear DEVICE`.
    /// Returns what was done.
    pub fn apply(&self, line: &str) -> Result<String, String> {
        let words: Vec<&str> = line.split_whitespace().collect();
        let device = |name: &str| -> Result<&SimPort, String> {
            let r: Role = name.parse()?;
            self.port(r).ok_or_else(|| format!("{r} is not simulated"))
        };
        match words.as_slice() {
            ["estop", state] => {
                let s: EstopState = state.parse()?;
                self.set_estop(s);
                Ok(format!("estop is now {s}"))
            }
            ["stall"] => {
                self.model.lock().stall();
                Ok("engine stalled".into())
            }
            ["jam", "steer"] => {
                self.model.lock().jam_steering();
                Ok("steering drive fault latched (disable → enable clears it)".into())
            }
            ["stuck", "steer", on @ ("on" | "off")] => {
                self.model.lock().steer_stuck = *on == "on";
                Ok(format!("steering motor stuck {on} (no fault bits)"))
            }
            ["bias", name, x] => {
                let r: Role = name.parse()?;
                let x: f64 = x
                    .parse()
                    .ok()
                    .filter(|x: &f64| x.is_finite())
                    .ok_or_else(|| format!("bias takes a number, got {x:?}"))?;
                self.model.lock().bias[r as usize] = x;
                Ok(format!("{r} reports its position {x:+} off"))
            }
            ["nostart", on @ ("on" | "off")] => {
                self.model.lock().start_fails = *on == "on";
                Ok(format!("starter failure {on}"))
            }
            ["clear", name] => {
                device(name)?.faults.clear();
                Ok(format!("{name}: faults cleared"))
            }
            [fault, name, arg] => {
                let p = device(name)?;
                p.faults.set(fault, arg).map(|done| format!("{}: {done}", p.role))
            }
            _ => Err(format!(
                "unknown: {line:?}; expected `estop pause|run|disable`, `stall`, `nostart on|off`, `jam steer`, `stuck steer on|off`, `bias DEVICE X`, `clear DEVICE`, \
                 or `FAULT DEVICE ARG` with FAULT one of {} (e.g. `silent gas on`, `slow steer 80`, `vanish brake 2000`)",
                FAULT_NAMES.join(", ")
            )),
        }
    }
}

impl Drop for Sim {
    fn drop(&mut self) {
        self.stop.store(true, Relaxed);
        for t in self.threads.drain(..) {
            let _ = t.join();
        }
        let _ = std::fs::remove_dir_all(&self.dir);
    }
}

/// One simulated device and its port loop.
struct Served {
    config: DeviceConfig,
    link: PathBuf,
    model: Arc<Mutex<Model>>,
    stop: Arc<AtomicBool>,
    faults: Arc<Faults>,
    pty: Arc<Mutex<String>>,
    lives: Arc<AtomicU32>,
    events: Option<Sender<SimEvent>>,
}

impl Served {
    fn run(self, mut master: TTYPort, mut slave: TTYPort) {
        loop {
            // Holding the slave end open keeps the master readable while adrive closes
            // and reopens the port.
            self.serve(&mut master);
            let _ = &mut slave;
            let down = self.faults.vanish_ms.swap(0, Relaxed);
            if self.stop.load(Relaxed) || down == 0 {
                return;
            }
            // Vanish: close both ends and remove the link, as a USB unplug does.
            drop(master);
            drop(slave);
            let _ = std::fs::remove_file(&self.link);
            tracing::info!(device = %self.config.name, "simulated device vanished for {down} ms");
            let back = Instant::now() + Duration::from_millis(down);
            while Instant::now() < back {
                if self.stop.load(Relaxed) {
                    return;
                }
                std::thread::sleep(Duration::from_millis(5));
            }
            match bring_up(&self.link) {
                Ok((m, s, pty)) => {
                    tracing::info!(device = %self.config.name, pty = %pty, "simulated device is back");
                    *self.pty.lock() = pty;
                    self.lives.fetch_add(1, Relaxed);
                    (master, slave) = (m, s);
                }
                Err(e) => {
                    tracing::error!(device = %self.config.name, "simulated device cannot come back: {e}");
                    return;
                }
            }
        }
    }

    /// Serve requests until stopped or told to vanish.
    fn serve(&self, port: &mut TTYPort) {
        let c = &self.config;
        let mut responder = responder_for(c);
        let mut input: Vec<u8> = Vec::with_capacity(256);
        let mut chunk = [0u8; 256];
        let mut last_command = Instant::now();
        let mut tripped = false;
        while !self.stop.load(Relaxed) && self.faults.vanish_ms.load(Relaxed) == 0 {
            if let Some(limit) = c.sim.watchdog {
                if !tripped && last_command.elapsed() > limit {
                    tripped = true;
                    self.model.lock().watchdog_trip(c.name);
                    tracing::info!(device = %c.name, "simulated device watchdog: no command for {limit:?}, going safe");
                    let safe = match c.name {
                        Role::Brake => Some(Command::Set(1.0)),
                        Role::Gas => Some(Command::Set(0.0)),
                        _ => None,
                    };
                    if let (Some(tx), Some(command)) = (&self.events, safe) {
                        let (speed, gear) = {
                            let m = self.model.lock();
                            (m.velocity, m.gear)
                        };
                        let _ = tx.send(SimEvent {
                            speed,
                            gear,
                            role: c.name,
                            at: Instant::now(),
                            command,
                            request: Vec::new(),
                            note: Some(format!(
                                "device watchdog: no command for {}",
                                humantime::format_duration(limit)
                            )),
                        });
                    }
                }
            }
            match port.read(&mut chunk) {
                Ok(0) => continue,
                Ok(n) => input.extend_from_slice(&chunk[..n]),
                Err(e) if e.kind() == std::io::ErrorKind::TimedOut => continue,
                Err(_) => {
                    // No reader on the other side yet (EIO): wait and retry.
                    std::thread::sleep(Duration::from_millis(10));
                    continue;
                }
            }
            let mut arrived = Instant::now();
            loop {
                let mut plant = DevicePlant {
                    role: c.name,
                    model: &self.model,
                    applied: None,
                    before: (0.0, Gear::Park),
                };
                let Some(reply) = responder.respond(&input, &mut plant) else {
                    break;
                };
                let request: Vec<u8> = input.drain(..reply.consumed.min(input.len())).collect();
                if plant.applied.is_some() {
                    last_command = Instant::now();
                    tripped = false;
                }
                if let (Some(tx), Some(command)) = (&self.events, plant.applied) {
                    let _ = tx.send(SimEvent {
                        role: c.name,
                        at: arrived,
                        command,
                        request: request.clone(),
                        note: None,
                        speed: plant.before.0,
                        gear: plant.before.1,
                    });
                }
                if self.faults.silent.load(Relaxed) || reply.bytes.is_empty() {
                    continue;
                }
                let mut bytes = reply.bytes;
                if self.faults.garbage.load(Relaxed) {
                    bytes = b"\xff\x00?#garbage\xfe\r\n".to_vec();
                }
                if self.faults.corrupt.load(Relaxed) {
                    if let Some(last) = bytes.last_mut() {
                        *last ^= 0x01;
                    }
                }
                let processing = if plant.applied.is_some() {
                    c.sim.command_delay
                } else {
                    c.sim.poll_delay
                };
                let hold = wire_time(request.len() + bytes.len(), c.baud)
                    + c.sim.turnaround
                    + processing
                    + reply.extra
                    + Duration::from_millis(self.faults.slow_ms.load(Relaxed));
                let due = arrived + hold;
                let now = Instant::now();
                if due > now {
                    std::thread::sleep(due - now);
                }
                let _ = port.write_all(&bytes);
                let _ = port.flush();
                // A request that queued meanwhile starts being served now.
                arrived = Instant::now();
            }
        }
    }
}
