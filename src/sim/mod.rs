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
//!
//! A CAN bus is one port for many devices: each `[[bus]]` is one simulated SLCAN
//! adapter behind a link named after the bus, with the bus's kit behind it ([`bus`]).

pub(crate) mod bus;
pub(crate) mod commands;
pub(crate) mod device;
pub(crate) mod elm327;
pub(crate) mod firmware;
pub(crate) mod line;
pub(crate) mod modbus;
pub(crate) mod model;
pub mod oscc;
pub mod slcan;
#[cfg(test)]
pub(crate) mod test_serve;

use crate::config::protocol_map::Wire;
use crate::config::{DeviceConfig, VehicleConfig};
use crate::value::{Command, DeviceId, EstopState, Kind, Reading};
use commands::{Names, Port, SimCommand};
use crossbeam_channel::Sender;
use device::{Plant, Responder};
use firmware::Watchdog;
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

impl Faults {
    /// Close the device's port now and bring it back, on a new pseudo-terminal behind
    /// the same path, after `down`.
    pub fn vanish(&self, down: Duration) {
        self.vanish_ms
            .store(down.as_millis().max(1) as u64, Relaxed);
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
    /// What the device did on its own (its watchdog, a kit module's firmware), in
    /// words: then `command` is where it stands, not something it received.
    pub note: Option<String>,
    /// The command in words (`0.250`, `drive`, `home`).
    pub text: String,
    /// The simulated vehicle's speed (m/s, signed) when the command arrived.
    pub speed: f64,
    /// A state device's state when the command arrived (a shift is a new state).
    pub state_before: Option<u8>,
}

/// Where the devices tell what they received (`adrive sim`'s printer, a test). A
/// device never waits for the reader: when a bounded receiver is full, the event is
/// counted as dropped instead.
#[derive(Clone, Default)]
struct Events {
    tx: Option<Sender<SimEvent>>,
    dropped: Arc<AtomicU64>,
}

impl Events {
    fn emit(&self, ev: SimEvent) {
        if let Some(tx) = &self.tx {
            if tx.try_send(ev).is_err() {
                self.dropped.fetch_add(1, Relaxed);
            }
        }
    }
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

impl SimPort {
    /// The port of `name`, up for the first time behind `link` on `pty`.
    fn new(name: &str, link: &Path, pty: String) -> SimPort {
        SimPort {
            name: name.to_string(),
            path: link.display().to_string(),
            pty: Arc::new(Mutex::new(pty)),
            faults: Arc::new(Faults::default()),
            lives: Arc::new(AtomicU32::new(1)),
        }
    }
}

/// The running simulator.
pub struct Sim {
    /// The devices' own ports.
    pub ports: Vec<SimPort>,
    /// One adapter per CAN bus, named after the bus.
    pub buses: Vec<SimPort>,
    /// The kit behind each bus's adapter, by bus index.
    kits: Vec<bus::SimKit>,
    /// The bus each device is on, by device id (`None`: its own port).
    bus_of: Vec<Option<usize>>,
    dir: PathBuf,
    model: Arc<Mutex<Model>>,
    stop: Arc<AtomicBool>,
    threads: Vec<JoinHandle<()>>,
    events: Events,
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
        Wire::Can(_) => unreachable!("a device on a CAN bus is simulated behind its bus's adapter"),
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
    /// receives every command a device applies; a device never waits for it (see
    /// [`Sim::dropped_events`]).
    pub fn start(config: &VehicleConfig, events: Option<Sender<SimEvent>>) -> std::io::Result<Sim> {
        let events = Events {
            tx: events,
            dropped: Arc::default(),
        };
        // A bus the simulator cannot serve is refused before anything starts.
        let mut kits = Vec::new();
        for (i, b) in config.buses.iter().enumerate() {
            if let Some(d) = config
                .devices
                .iter()
                .find(|d| d.name == b.name && !matches!(d.wire, Wire::Can(_)))
            {
                return Err(std::io::Error::other(format!(
                    "bus {} and device {} would share one link in the simulator: rename one",
                    b.name, d.name
                )));
            }
            kits.push(bus::SimKit::new(config, i, Instant::now())?);
        }
        let dir = std::env::temp_dir().join(format!(
            "adrive-sim-{}-{}",
            std::process::id(),
            SIM_COUNT.fetch_add(1, Relaxed)
        ));
        std::fs::create_dir_all(&dir)?;
        let model = Arc::new(Mutex::new(Model::new(config)));
        let stop = Arc::new(AtomicBool::new(false));
        // From here on, a port that cannot come up drops `sim`: its threads stop and
        // its directory goes.
        let mut sim = Sim {
            ports: Vec::new(),
            buses: Vec::new(),
            kits: kits.clone(),
            bus_of: config
                .devices
                .iter()
                .map(|d| match &d.wire {
                    Wire::Can(m) => Some(m.bus),
                    _ => None,
                })
                .collect(),
            dir: dir.clone(),
            model: model.clone(),
            stop: stop.clone(),
            threads: Vec::new(),
            events: events.clone(),
        };
        for (b, kit) in config.buses.iter().zip(kits) {
            let link = dir.join(b.name.as_str());
            let (master, slave, pty) = bring_up(&link)?;
            let port = SimPort::new(&b.name, &link, pty);
            let served = bus::ServedBus {
                config: b.clone(),
                link,
                kit,
                model: model.clone(),
                stop: stop.clone(),
                faults: port.faults.clone(),
                pty: port.pty.clone(),
                lives: port.lives.clone(),
                events: events.clone(),
            };
            let h = std::thread::Builder::new()
                .name(format!("sim/{}", b.name))
                .spawn(move || served.run(master, slave))?;
            sim.threads.push(h);
            sim.buses.push(port);
        }
        for (i, c) in config.devices.iter().enumerate() {
            if matches!(c.wire, Wire::Can(_)) {
                continue;
            }
            let link = dir.join(c.name.as_str());
            let (master, slave, pty) = bring_up(&link)?;
            let port = SimPort::new(&c.name, &link, pty);
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
            sim.threads.push(h);
            sim.ports.push(port);
        }
        Ok(sim)
    }

    /// Events lost because their bounded receiver was full.
    pub(crate) fn dropped_events(&self) -> u64 {
        self.events.dropped.load(Relaxed)
    }

    fn port(&self, name: &str) -> Option<&SimPort> {
        self.ports.iter().find(|p| p.name == name)
    }

    /// The stable path of a device's port.
    pub fn path(&self, name: &str) -> Option<&str> {
        self.port(name).map(|p| p.path.as_str())
    }

    /// The stable path of a bus's adapter.
    pub fn bus_path(&self, name: &str) -> Option<&str> {
        self.buses
            .iter()
            .find(|p| p.name == name)
            .map(|p| p.path.as_str())
    }

    /// A bus's adapter and kit, for tests: `f` runs with the kit locked.
    pub fn with_kit<R>(
        &self,
        bus: &str,
        f: impl FnOnce(&mut slcan::SlcanPort<oscc::Kit>) -> R,
    ) -> Option<R> {
        let i = self.buses.iter().position(|p| p.name == bus)?;
        let mut port = self.kits[i].port.lock();
        Some(f(&mut port))
    }

    /// The faults of a device's port: its own, or for a device on a CAN bus, its bus
    /// adapter's.
    pub fn faults(&self, name: &str) -> Option<&Arc<Faults>> {
        if let Some(p) = self.port(name) {
            return Some(&p.faults);
        }
        let id = self.model.lock().find(name)?;
        let bus = self.bus_of.get(id.index()).copied().flatten()?;
        self.buses.get(bus).map(|p| &p.faults)
    }

    /// The simulated vehicle, for tests and the console's bench view.
    pub fn model(&self) -> &Arc<Mutex<Model>> {
        &self.model
    }

    pub fn set_estop(&self, state: EstopState) {
        self.model.lock().estop = state;
    }

    /// Point every device of `config` at its simulated port, and every bus at its
    /// simulated adapter.
    pub fn patch(&self, config: &mut VehicleConfig) {
        for d in &mut config.devices {
            if let Some(p) = self.path(&d.name) {
                d.port = p.to_string();
            }
        }
        for b in &mut config.buses {
            if let Some(p) = self.bus_path(&b.name) {
                b.port = p.to_string();
            }
        }
    }

    /// What the simulator's commands may name, and what of the vehicle they act on
    /// shows: a device on its own port serves the model's readings; a device on a bus
    /// shows what its kit's messages carry.
    pub fn names(&self) -> Names {
        let m = self.model.lock();
        let devices: Vec<(String, Kind)> =
            m.devices.iter().map(|d| (d.name.clone(), d.kind)).collect();
        let own = |i: usize| self.bus_of.get(i).copied().flatten().is_none();
        let shown = |what: model::Shown| {
            (0..devices.len()).any(|i| own(i) && m.shows(DeviceId(i as u16), what))
        };
        let mut modules: Vec<DeviceId> = self
            .kits
            .iter()
            .flat_map(|k| k.bindings.iter().map(|b| b.device))
            .collect();
        modules.sort_unstable_by_key(|d| d.index());
        let positions = (0..devices.len())
            .map(|i| DeviceId(i as u16))
            .filter(|&id| devices[id.index()].1 == Kind::Setpoint)
            .filter(|&id| {
                if own(id.index()) {
                    return m.shows(id, model::Shown::Position);
                }
                self.module(id)
                    .is_some_and(|(kit, module)| kit.port.lock().node.reports_position(module))
            })
            .collect();
        let has = commands::Has {
            estop: shown(model::Shown::Estop),
            engine: shown(model::Shown::Engine),
            starter: m.starter().is_some_and(|id| own(id.index())),
            positions,
        };
        Names {
            devices,
            bus_of: self.bus_of.clone(),
            modules,
            buses: self.buses.iter().map(|p| p.name.clone()).collect(),
            has,
        }
    }

    /// The state of the kit's module that moves device `name`, in words, for the
    /// console's bench: `steering module enabled`, `brake module disabled, operator
    /// override · INVALID_SENSOR_VAL held` (`None`: no kit's module moves it).
    pub fn module_state(&self, name: &str) -> Option<String> {
        let id = self.model.lock().find(name)?;
        let (kit, module) = self.module(id)?;
        let port = kit.port.lock();
        let s = port.node.state(module);
        let mut out = format!(
            "{module} module {}",
            if s.enabled { "enabled" } else { "disabled" }
        );
        if s.operator_override {
            out.push_str(", operator override");
        }
        for dtc in port.node.fault_names(module) {
            if port.node.fault_held(module, &dtc) == Some(true) {
                out.push_str(&format!(" · {dtc} held"));
            }
        }
        Some(out)
    }

    /// The kit and module that move `id`.
    fn module(&self, id: DeviceId) -> Option<(&bus::SimKit, oscc::Module)> {
        self.kits
            .iter()
            .find_map(|k| k.module_of(id).map(|m| (k, m)))
    }

    /// Apply one line of the simulator's little command language
    /// ([`commands::VERBS`]; used by `adrive sim` on its standard input, `--fault` and
    /// the console's bench keys). Returns what was done (for `help`, the table).
    pub fn apply(&self, line: &str) -> Result<String, String> {
        let names = self.names();
        let name = |id: DeviceId| names.devices[id.index()].0.clone();
        let port_fault = |port: Port, what: &str, set: &dyn Fn(&Faults)| {
            let p = match port {
                Port::Device(id) => self.port(&name(id)).expect("parsed as a device's port"),
                Port::Bus(i) => &self.buses[i],
            };
            set(&p.faults);
            Ok(format!("{}: {what}", p.name))
        };
        let on_off = |on: bool| if on { "on" } else { "off" };
        let kit_override = |id: DeviceId, on: bool| {
            match self.module(id) {
            Some((kit, module)) => {
                kit.port
                    .lock()
                    .node
                    .set_override(module, on, Instant::now());
                Ok(format!(
                    "{}: the {module} module's operator override {}",
                    name(id),
                    on_off(on)
                ))
            }
            None => Err(format!(
                "{} is not driven by a kit's module: give the position a hand pushes it toward (`override {} 0.5`)",
                name(id),
                name(id)
            )),
        }
        };
        match commands::parse(line, &names)? {
            SimCommand::Help => Ok(format!("commands:\n{}", commands::help(&names).trim_end())),
            SimCommand::KitOverride(id, on) => kit_override(id, on),
            SimCommand::Lever(id, word) => {
                let state = self.model.lock().lever(id, &word)?;
                Ok(format!("{}: a hand moves its lever to {state}", name(id)))
            }
            SimCommand::Fault(id, dtc, on) => {
                let (kit, module) = self
                    .module(id)
                    .ok_or_else(|| format!("{} is not driven by a kit's module", name(id)))?;
                kit.port
                    .lock()
                    .node
                    .set_fault(module, &dtc, on, Instant::now())?;
                Ok(if on {
                    format!(
                        "{}: the {module} module's {dtc} condition holds: it disables itself and reports {dtc} until `fault {} {dtc} off`",
                        name(id),
                        name(id)
                    )
                } else {
                    format!(
                        "{}: the {module} module's {dtc} condition ended: it clears its fault codes",
                        name(id)
                    )
                })
            }
            SimCommand::Bus(i, on) => {
                self.kits[i].bus_fault.store(!on, Relaxed);
                Ok(if on {
                    format!("bus {} is well again", names.buses[i])
                } else {
                    format!(
                        "bus {} in error: its adapter refuses frames, delivers none, and its status says bus error",
                        names.buses[i]
                    )
                })
            }
            SimCommand::Estop(s) => {
                self.set_estop(s);
                Ok(format!("estop is now {s}"))
            }
            SimCommand::Stall => {
                self.model.lock().stall();
                Ok("engine stalled".into())
            }
            SimCommand::NoStart(on) => {
                self.model.lock().start_fails = on;
                Ok(format!("starter failure {}", on_off(on)))
            }
            SimCommand::Jam(id) => {
                self.model.lock().jam(id);
                Ok(format!(
                    "{}: drive fault latched (disable → enable clears it)",
                    name(id)
                ))
            }
            SimCommand::Stuck(id, on) => {
                self.model.lock().device_mut(id).stuck = on;
                Ok(format!(
                    "{}: motor stuck {} (no fault bits)",
                    name(id),
                    on_off(on)
                ))
            }
            SimCommand::Bias(id, x) => {
                self.model.lock().device_mut(id).bias = x;
                Ok(format!("{} reports its position {x:+} off", name(id)))
            }
            SimCommand::Override(id, to) => {
                self.model.lock().set_override(id, to);
                if self.module(id).is_some() {
                    kit_override(id, to.is_some())?;
                }
                Ok(match to {
                    Some(x) => format!("{}: a hand pushes it toward {x}", name(id)),
                    None => format!("{}: the hand lets go", name(id)),
                })
            }
            SimCommand::Silent(r, on) => port_fault(r, &format!("silent {}", on_off(on)), &|f| {
                f.silent.store(on, Relaxed)
            }),
            SimCommand::Garbage(r, on) => port_fault(r, &format!("garbage {}", on_off(on)), &|f| {
                f.garbage.store(on, Relaxed)
            }),
            SimCommand::Corrupt(r, on) => port_fault(r, &format!("corrupt {}", on_off(on)), &|f| {
                f.corrupt.store(on, Relaxed)
            }),
            SimCommand::Slow(r, ms) => port_fault(r, &format!("slow {ms} ms"), &|f| {
                f.slow_ms.store(ms, Relaxed)
            }),
            SimCommand::Vanish(r, ms) => port_fault(r, &format!("vanish for {ms} ms"), &|f| {
                f.vanish(Duration::from_millis(ms))
            }),
            SimCommand::Clear(r) => port_fault(r, "faults cleared", &|f| f.clear()),
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

/// One simulated device: its firmware (the watchdog) and its port loop.
struct Served {
    id: DeviceId,
    config: DeviceConfig,
    link: PathBuf,
    model: Arc<Mutex<Model>>,
    stop: Arc<AtomicBool>,
    faults: Arc<Faults>,
    pty: Arc<Mutex<String>>,
    lives: Arc<AtomicU32>,
    events: Events,
}

/// The device's USB link: up on a pseudo-terminal pair, or gone until a time.
enum Link {
    Up(Box<Up>),
    Down { back: Instant },
}

/// A link that is up: both ends of its pseudo-terminal (holding the device end open
/// keeps the adrive end readable while adrive closes and reopens the port), the
/// protocol and the bytes of a request not yet complete.
struct Up {
    master: TTYPort,
    _slave: TTYPort,
    responder: Box<dyn Responder>,
    input: Vec<u8>,
}

impl Served {
    /// The device thread: until stopped, its firmware's watchdog runs on every turn,
    /// whether the link is up or gone (a real actuator's microcontroller keeps running
    /// when its USB link drops); while the link is up, requests are served.
    fn run(self, master: TTYPort, slave: TTYPort) {
        let mut watchdog = Watchdog::new(self.config.sim.watchdog);
        let mut link = Link::Up(Box::new(self.up(master, slave)));
        while !self.stop.load(Relaxed) {
            if watchdog.expired(Instant::now()) {
                self.watchdog_trip(watchdog.limit().unwrap_or_default());
            }
            link = match link {
                Link::Up(mut up) => match self.faults.vanish_ms.swap(0, Relaxed) {
                    0 => {
                        if self.serve(&mut up) {
                            watchdog.feed(Instant::now());
                        }
                        Link::Up(up)
                    }
                    down => {
                        // Vanish: close both ends and remove the link, as a USB unplug does.
                        drop(up);
                        let _ = std::fs::remove_file(&self.link);
                        tracing::info!(device = %self.config.name, "simulated device vanished for {down} ms");
                        Link::Down {
                            back: Instant::now() + Duration::from_millis(down),
                        }
                    }
                },
                Link::Down { back } if Instant::now() < back => {
                    std::thread::sleep(Duration::from_millis(5));
                    Link::Down { back }
                }
                Link::Down { .. } => match bring_up(&self.link) {
                    Ok((m, s, pty)) => {
                        tracing::info!(device = %self.config.name, pty = %pty, "simulated device is back");
                        *self.pty.lock() = pty;
                        self.lives.fetch_add(1, Relaxed);
                        Link::Up(Box::new(self.up(m, s)))
                    }
                    Err(e) => {
                        tracing::error!(device = %self.config.name, "simulated device cannot come back: {e}");
                        return;
                    }
                },
            };
        }
    }

    fn up(&self, master: TTYPort, slave: TTYPort) -> Up {
        Up {
            master,
            _slave: slave,
            responder: responder_for(&self.config),
            input: Vec::with_capacity(256),
        }
    }

    /// The watchdog tripped: the device goes to its safe value by itself (gas to 0,
    /// brake on); a device without one (the steering) holds where it is, and nothing
    /// happened to tell.
    fn watchdog_trip(&self, limit: Duration) {
        let c = &self.config;
        let (speed, safe) = {
            let mut m = self.model.lock();
            let safe = m.watchdog_trip(self.id);
            (m.velocity, safe)
        };
        let Some(safe) = safe else {
            tracing::debug!(device = %c.name, "simulated device watchdog: no command for {limit:?}; no safe value, it holds");
            return;
        };
        let text = c.command_text(safe);
        let note = format!(
            "device watchdog: no command for {}; went to {text} by itself",
            humantime::format_duration(limit)
        );
        tracing::info!(device = %c.name, "simulated {note}");
        self.events.emit(SimEvent {
            speed,
            state_before: None,
            device: self.id,
            name: c.name.clone(),
            at: Instant::now(),
            command: safe,
            text,
            request: Vec::new(),
            note: Some(note),
        });
    }

    /// Wait briefly for bytes and serve every complete request, one transaction at a
    /// time. Returns whether a command was applied.
    fn serve(&self, up: &mut Up) -> bool {
        let c = &self.config;
        let mut chunk = [0u8; 256];
        match up.master.read(&mut chunk) {
            Ok(0) => return false,
            Ok(n) => up.input.extend_from_slice(&chunk[..n]),
            Err(e) if e.kind() == std::io::ErrorKind::TimedOut => return false,
            Err(_) => {
                // No reader on the other side yet (EIO): wait and retry.
                std::thread::sleep(Duration::from_millis(10));
                return false;
            }
        }
        let mut commanded = false;
        let mut arrived = Instant::now();
        loop {
            let mut plant = DevicePlant {
                id: self.id,
                model: &self.model,
                applied: None,
                before: (0.0, None),
            };
            let Some(reply) = up.responder.respond(&up.input, &mut plant) else {
                break;
            };
            let consumed = reply.consumed.min(up.input.len());
            let request: Vec<u8> = up.input.drain(..consumed).collect();
            if let Some(command) = plant.applied {
                commanded = true;
                self.events.emit(SimEvent {
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
            let _ = up.master.write_all(&bytes);
            let _ = up.master.flush();
            // A request that queued meanwhile starts being served now.
            arrived = Instant::now();
        }
        commanded
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::driver;

    /// Until `what` holds (20 s at most).
    fn until(what: &str, cond: impl Fn() -> bool) {
        let end = Instant::now() + Duration::from_secs(20);
        while !cond() {
            assert!(Instant::now() < end, "timed out waiting for {what}");
            std::thread::sleep(Duration::from_millis(2));
        }
    }

    /// The engine's fast path (`engine::fast`), on a simulated steering over a real
    /// pseudo-terminal, its command thread asleep and its port idle: a command goes the
    /// fast way only while the vehicle is engaged (one admitted just before a disengage
    /// is left to the command thread, behind the safe state) and only while commands
    /// are switched on. (Here, not in `engine`: the core imports no simulator.)
    #[test]
    fn the_fast_path_writes_only_for_an_engaged_vehicle_with_commands_on() {
        use crate::engine::fast::{send, Sent};
        use crate::engine::{Engine, Gate};
        use crate::value::Command;
        use std::sync::atomic::Ordering::Relaxed;
        use std::sync::Arc;
        let toml = "[vehicle]\nname = \"t\"\n[vehicle.roles]\nsteering = \"steer\"\n\
            [[device]]\nname = \"steer\"\nkind = \"setpoint\"\nrange = [-1.0, 1.0]\n\
            driver = \"line\"\nbaud = 38400\nstatus_period = \"10s\"\n\
            status_max_age = \"10s\"\ncommand_timeout = \"10s\"\n";
        let mut config = crate::config::parse(toml, "t.toml").expect("parses");
        let sim = Sim::start(&config, None).expect("the simulator starts");
        sim.patch(&mut config);
        let vehicle = Arc::new(crate::vehicle::Vehicle::new(config, |c| {
            let (path, baud, timeout) = (c.port.clone(), c.baud, c.reply_timeout);
            Box::new(move || crate::driver::open_serial(&path, baud, timeout))
        }));
        let gate = Arc::new(Gate::new(vehicle.clone()));
        let engine = Engine::start(gate.clone()).expect("the engine starts");
        let steer = vehicle.find("steer").unwrap();
        until("the steering to report", || gate.blockers().is_empty());
        let idle = || {
            until("the command thread to sleep", || steer.slot().is_idle());
        };
        // Disengaged: queued for the command thread, never written here.
        idle();
        let sent = send(&gate, steer, Command::Set(0.3), Instant::now());
        assert_eq!(sent, Sent::Queued { superseded: false });
        gate.engage("test").unwrap();
        until("the engage's hold to go out", || {
            steer.slot().executed().is_some() && steer.slot().wire().pending.is_none()
        });
        // Engaged: written.
        idle();
        assert_eq!(
            send(&gate, steer, Command::Set(0.4), Instant::now()),
            Sent::Written
        );
        until("its reply", || {
            steer.slot().executed() == Some(Command::Set(0.4))
        });
        // Commands switched off: not taken.
        steer.settings().command_enabled.store(false, Relaxed);
        idle();
        assert_eq!(
            send(&gate, steer, Command::Set(0.5), Instant::now()),
            Sent::NotTaken
        );
        steer.settings().command_enabled.store(true, Relaxed);
        engine.shutdown(Duration::from_secs(2));
    }

    const GAS_ONLY: &str = r#"
[vehicle]
name = "bench"

[vehicle.roles]
throttle = "gas"

[[device]]
name = "gas"
kind = "setpoint"
range = [0.0, 1.0]
driver = "line"
port = "simulated"
baud = 115200

[device.sim]
watchdog = "300ms"
"#;

    /// The incident: a vanished simulated gas actuator kept its last command (0.300)
    /// forever, because its watchdog ran only while its port was up. A real actuator's
    /// firmware keeps running when its USB link drops.
    #[test]
    fn a_vanished_gas_actuator_goes_to_zero_when_its_own_watchdog_trips() {
        let config = crate::config::parse(GAS_ONLY, "gas.toml").unwrap();
        let gas = config.device("gas").unwrap();
        let (tx, events) = crossbeam_channel::unbounded();
        let sim = Sim::start(&config, Some(tx)).unwrap();
        let path = sim.path("gas").unwrap().to_string();
        let mut link = driver::open_serial(&path, gas.baud, Duration::from_secs(2)).unwrap();
        let mut drv = driver::build(gas);
        let before = Instant::now();
        drv.command(link.as_mut(), Command::Set(0.3)).unwrap();
        assert_eq!(sim.model().lock().devices[0].command, 0.3);
        drop(link);
        sim.apply("vanish gas 60000").unwrap();

        let end = Instant::now() + Duration::from_secs(20);
        let trip = loop {
            let left = end.saturating_duration_since(Instant::now());
            let ev = events
                .recv_timeout(left)
                .expect("the device watchdog to trip");
            if ev.note.is_some() {
                break ev;
            }
        };
        // Still unplugged: the link is gone and the device has not come back.
        assert!(!Path::new(&path).exists(), "{path} is back");
        assert_eq!(sim.ports[0].lives.load(Relaxed), 1);
        assert_eq!(trip.command, Command::Set(0.0));
        let after = trip.at.duration_since(before);
        assert!(
            after >= Duration::from_millis(300),
            "tripped early: {after:?}"
        );
        assert!(
            after < Duration::from_millis(1300),
            "tripped late: {after:?}"
        );
        assert_eq!(sim.model().lock().devices[0].command, 0.0);
        let end = Instant::now() + Duration::from_secs(20);
        while sim.model().lock().reading(DeviceId(0)).get(0) > Some(0.01) {
            assert!(Instant::now() < end, "the gas never reached 0");
            std::thread::sleep(Duration::from_millis(5));
        }
    }
}
