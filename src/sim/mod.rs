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

use crate::config::wire::Wire;
use crate::config::{DeviceConfig, VehicleConfig};
use crate::value::{Command, DeviceId, EstopState, Kind, Reading};
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
    pub device: DeviceId,
    /// The device's name.
    pub name: String,
    pub at: Instant,
    /// The command the device applied.
    pub command: Command,
    /// The raw request bytes; empty when the device acted on its own.
    pub request: Vec<u8>,
    /// Why, when the device acted on its own (its watchdog).
    pub note: Option<String>,
    /// The simulated vehicle's speed (m/s, signed) when the command arrived.
    pub speed: f64,
    /// A state device's state when the command arrived (a shift is a new state).
    pub state_before: Option<u8>,
    /// The command in words (`0.250`, `drive`, `home`).
    pub text: String,
}

/// One simulated device's port.
pub struct SimPort {
    pub name: String,
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
    match &c.wire {
        Wire::Modbus(m) => Box::new(modbus::ModbusSlave::new(m.clone())),
        Wire::Elm327(m) => Box::new(elm327::Elm327Emulator::new(m.clone())),
        Wire::Line(m) => Box::new(line::LineDevice(m.clone())),
    }
}

struct DevicePlant<'a> {
    id: DeviceId,
    model: &'a Mutex<Model>,
    applied: Option<Command>,
    /// The vehicle's speed, and the device's state, when the command arrived.
    before: (f64, Option<u8>),
}

impl Plant for DevicePlant<'_> {
    fn reading(&mut self) -> Reading {
        self.model.lock().reading(self.id)
    }
    fn command(&mut self, command: Command) -> Result<(), String> {
        let mut m = self.model.lock();
        m.step();
        let d = m.device(self.id);
        let state = (d.kind == Kind::State).then_some(d.state);
        self.before = (m.velocity, state);
        m.command(self.id, command)?;
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
        let model = Arc::new(Mutex::new(Model::new(config)));
        let stop = Arc::new(AtomicBool::new(false));
        let mut ports = Vec::new();
        let mut threads = Vec::new();
        for (i, c) in config.devices.iter().enumerate() {
            let link = dir.join(c.name.as_str());
            let (master, slave, pty) = bring_up(&link)?;
            let port = SimPort {
                name: c.name.clone(),
                path: link.display().to_string(),
                pty: Arc::new(Mutex::new(pty)),
                faults: Arc::new(Faults::default()),
                lives: Arc::new(AtomicU32::new(1)),
            };
            let dev = Served {
                id: DeviceId(i as u16),
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

    fn port(&self, name: &str) -> Option<&SimPort> {
        self.ports.iter().find(|p| p.name == name)
    }

    /// The stable path of a device's port.
    pub fn path(&self, name: &str) -> Option<&str> {
        self.port(name).map(|p| p.path.as_str())
    }

    pub fn faults(&self, name: &str) -> Option<&Arc<Faults>> {
        self.port(name).map(|p| &p.faults)
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
            if let Some(p) = self.path(&d.name) {
                d.port = p.to_string();
            }
        }
    }

    /// Apply one line of the simulator's little command language (used by `adrive sim`
    /// on its standard input, `--fault`, the console's bench keys and tests); returns
    /// what was done. `help` lists it all ([`COMMANDS`]).
    pub fn apply(&self, line: &str) -> Result<String, String> {
        let words: Vec<&str> = line.split_whitespace().collect();
        let Some((&verb, args)) = words.split_first() else {
            return Err("empty line; `help` lists the commands".into());
        };
        let Some(cmd) = COMMANDS.iter().find(|c| c.verb == verb) else {
            return Err(format!(
                "unknown command {verb:?}; `help` lists them: {}",
                COMMANDS
                    .iter()
                    .map(|c| c.verb)
                    .collect::<Vec<_>>()
                    .join(", ")
            ));
        };
        let usage = || format!("usage: {} {} ({})", cmd.verb, cmd.args, cmd.what);
        if args.len() != cmd.args.split_whitespace().count() {
            return Err(usage());
        }
        let device = |name: &str, want: Option<Kind>| -> Result<(DeviceId, &SimPort), String> {
            let m = self.model.lock();
            let id = m.find(name).ok_or_else(|| {
                format!(
                    "no device {name:?}; the devices are {}",
                    m.devices
                        .iter()
                        .map(|d| d.name.as_str())
                        .collect::<Vec<_>>()
                        .join(", ")
                )
            })?;
            if let Some(k) = want {
                if m.device(id).kind != k {
                    return Err(format!(
                        "{name} is a {} device; {} is for {k} devices. {}",
                        m.device(id).kind,
                        cmd.verb,
                        usage()
                    ));
                }
            }
            drop(m);
            Ok((id, self.port(name).expect("every device has a port")))
        };
        let on_off = |w: &str| match w {
            "on" | "1" | "true" => Ok(true),
            "off" | "0" | "false" => Ok(false),
            _ => Err(usage()),
        };
        match (verb, args) {
            ("help", _) => Ok(help()),
            ("estop", [state]) => {
                let s: EstopState = state.parse()?;
                self.set_estop(s);
                Ok(format!("estop is now {s}"))
            }
            ("stall", _) => {
                self.model.lock().stall();
                Ok("engine stalled".into())
            }
            ("nostart", [on]) => {
                let on = on_off(on)?;
                self.model.lock().start_fails = on;
                Ok(format!("starter failure {}", if on { "on" } else { "off" }))
            }
            ("jam", [name]) => {
                let (id, _) = device(name, Some(Kind::Setpoint))?;
                self.model.lock().jam(id);
                Ok(format!(
                    "{name}: drive fault latched (disable → enable clears it)"
                ))
            }
            ("stuck", [name, on]) => {
                let (id, _) = device(name, Some(Kind::Setpoint))?;
                let on = on_off(on)?;
                self.model.lock().device_mut(id).stuck = on;
                Ok(format!(
                    "{name}: motor stuck {} (no fault bits)",
                    if on { "on" } else { "off" }
                ))
            }
            ("bias", [name, x]) => {
                let (id, _) = device(name, Some(Kind::Setpoint))?;
                let x: f64 = x
                    .parse()
                    .ok()
                    .filter(|x: &f64| x.is_finite())
                    .ok_or_else(usage)?;
                self.model.lock().device_mut(id).bias = x;
                Ok(format!("{name} reports its position {x:+} off"))
            }
            ("clear", [name]) => {
                let (_, p) = device(name, None)?;
                p.faults.clear();
                Ok(format!("{name}: faults cleared"))
            }
            (fault, [name, arg]) => {
                let (_, p) = device(name, None)?;
                p.faults
                    .set(fault, arg)
                    .map(|done| format!("{name}: {done}"))
            }
            _ => Err(usage()),
        }
    }
}

/// One command of the simulator's language.
pub struct SimCommand {
    pub verb: &'static str,
    pub args: &'static str,
    pub what: &'static str,
}

/// The simulator's little language: one table for parsing, errors and `help`.
pub const COMMANDS: [SimCommand; 13] = [
    SimCommand {
        verb: "estop",
        args: "disable|pause|run",
        what: "change the e-stop state",
    },
    SimCommand {
        verb: "stall",
        args: "",
        what: "the engine stalls",
    },
    SimCommand {
        verb: "nostart",
        args: "on|off",
        what: "the starter turns but the engine never catches",
    },
    SimCommand {
        verb: "silent",
        args: "DEVICE on|off",
        what: "any device: stop answering",
    },
    SimCommand {
        verb: "garbage",
        args: "DEVICE on|off",
        what: "any device: answer noise",
    },
    SimCommand {
        verb: "corrupt",
        args: "DEVICE on|off",
        what: "any device: flip a bit in every reply (bad CRC / checksum)",
    },
    SimCommand {
        verb: "slow",
        args: "DEVICE MS",
        what: "any device: answer MS later (0 clears)",
    },
    SimCommand {
        verb: "vanish",
        args: "DEVICE MS",
        what: "any device: close the port and remove its link (a USB unplug), back after MS",
    },
    SimCommand {
        verb: "jam",
        args: "DEVICE",
        what: "a setpoint device's drive latches a fault (bit 0x0001; disable → enable clears it)",
    },
    SimCommand {
        verb: "stuck",
        args: "DEVICE on|off",
        what: "a setpoint device's motor stops and its drive does not notice",
    },
    SimCommand {
        verb: "bias",
        args: "DEVICE X",
        what: "a setpoint device reports its position X off (a slipped sensor)",
    },
    SimCommand {
        verb: "clear",
        args: "DEVICE",
        what: "clear a device's port faults",
    },
    SimCommand {
        verb: "help",
        args: "",
        what: "this list",
    },
];

/// The language, one command a line.
pub fn help() -> String {
    COMMANDS
        .iter()
        .map(|c| {
            format!(
                "{:<28} {}",
                format!("{} {}", c.verb, c.args).trim_end(),
                c.what
            )
        })
        .collect::<Vec<_>>()
        .join("\n")
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
    id: DeviceId,
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
                    let safe = self.model.lock().watchdog_trip(self.id);
                    tracing::info!(device = %c.name, "simulated device watchdog: no command for {limit:?}, going safe");
                    if let (Some(tx), Some(command)) = (&self.events, safe) {
                        let speed = self.model.lock().velocity;
                        let _ = tx.send(SimEvent {
                            device: self.id,
                            name: c.name.clone(),
                            speed,
                            at: Instant::now(),
                            command,
                            text: c.command_text(command),
                            state_before: None,
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
                    id: self.id,
                    model: &self.model,
                    applied: None,
                    before: (0.0, None),
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
                        device: self.id,
                        name: c.name.clone(),
                        at: arrived,
                        command,
                        text: c.command_text(command),
                        request: request.clone(),
                        note: None,
                        speed: plant.before.0,
                        state_before: plant.before.1,
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
