//! The simulator's CAN buses: for each `[[bus]]` of the vehicle, one simulated SLCAN
//! adapter on its own pseudo-terminal, behind a stable link named after the bus (as a
//! device's is), with the bus's kit behind it ([`SlcanPort`] of an [`oscc::Kit`] built
//! from the bus's DBC, its modules' firmware watchdog from `[bus.sim] watchdog`). The
//! one kit simulated today is OSCC: a bus whose DBC lacks OSCC's messages is refused at
//! start, by name; another kit would be another [`super::slcan::BusNode`].
//!
//! The kit drives the simulated vehicle through the bindings, as every simulated device
//! does. Each module's request moves the device whose `[device.can] command` is in the
//! module's command message while the module is enabled; a disabled module leaves the
//! car to its driver (no torque, no throttle, no brake). And the vehicle's own messages
//! on the bus carry the model: its road speed in the wheel speed message (so the
//! `speed` role sees it), the steering device's position as the steering wheel angle
//! ([`STEERING_WHEEL_DEG`] at full travel) and the brake's as the master cylinder
//! pressure ([`BRAKE_FULL_BAR`] at full pedal).
//!
//! The port loop answers the host at once, as an adapter does. Frames share the bus one
//! after another, each taking its wire time at the bus's bitrate ([`Frame::wire_bits`],
//! without stuffing): a frame from the kit reaches the host when its last bit has.
//!
//! [`oscc::Kit`]: super::oscc::Kit

use super::oscc::{Kit, Module};
use super::slcan::{Adapter, SlcanPort};
use super::{bring_up, Events, Faults, Model, SimEvent};
use crate::can::Frame;
use crate::config::can::BusConfig;
use crate::config::protocol_map::Wire;
use crate::config::{DeviceConfig, VehicleConfig};
use crate::driver::slcan::proto;
use crate::value::{Command, DeviceId};
use parking_lot::Mutex;
use serialport::{SerialPort, TTYPort};
use std::collections::VecDeque;
use std::io::{Read, Write};
use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, AtomicU32, Ordering::Relaxed};
use std::sync::Arc;
use std::time::{Duration, Instant};

/// The steering wheel's angle, in degrees, at full travel of the steering device (±1):
/// a turn and a half each way, as on most cars.
pub(crate) const STEERING_WHEEL_DEG: f64 = 540.0;
/// The brake master cylinder's pressure, in bar, at full pedal.
pub(crate) const BRAKE_FULL_BAR: f64 = 100.0;
/// The longest the port loop waits for the host before it looks at the bus again.
const TURN: Duration = Duration::from_millis(5);

/// A kit's module and the vehicle's device its requests move.
#[derive(Clone, Debug)]
pub(crate) struct Binding {
    pub module: Module,
    /// The module's command message.
    pub command: crate::can::Id,
    pub device: DeviceId,
    pub config: DeviceConfig,
}

/// One simulated bus as the simulator's commands reach it: its adapter and kit, which
/// module moves which device, and whether the bus is in error.
#[derive(Clone)]
pub(crate) struct SimKit {
    pub port: Arc<Mutex<SlcanPort<Kit>>>,
    pub bindings: Vec<Binding>,
    /// The bus is in error (`bus kit off`): the adapter refuses and delivers nothing.
    pub bus_fault: Arc<AtomicBool>,
}

impl SimKit {
    /// The kit of bus `index` of `config`, powered up at `now`; refused, by name, when
    /// the bus's DBC is not OSCC's.
    pub(crate) fn new(
        config: &VehicleConfig,
        index: usize,
        now: Instant,
    ) -> std::io::Result<SimKit> {
        let bus = &config.buses[index];
        let kit = Kit::new(&bus.dbc, bus.sim.watchdog, now).map_err(|e| {
            std::io::Error::other(format!(
                "bus {}: the simulator's only kit is OSCC, and this bus's DBC is not OSCC's: {e}",
                bus.name
            ))
        })?;
        let bindings = Module::ALL
            .into_iter()
            .filter_map(|module| {
                let id = kit.command_id(module);
                let (i, c) = config.devices.iter().enumerate().find(|(_, d)| {
                    matches!(&d.wire, Wire::Can(m) if m.bus == index
                        && m.command.as_ref().is_some_and(|c| c.message == id))
                })?;
                Some(Binding {
                    module,
                    command: id,
                    device: DeviceId(i as u16),
                    config: c.clone(),
                })
            })
            .collect();
        Ok(SimKit {
            port: Arc::new(Mutex::new(SlcanPort::new(kit, now))),
            bindings,
            bus_fault: Arc::default(),
        })
    }

    /// The module that moves `device`.
    pub(crate) fn module_of(&self, device: DeviceId) -> Option<Module> {
        self.bindings
            .iter()
            .find(|b| b.device == device)
            .map(|b| b.module)
    }
}

/// The frames on the bus, one after another at its bitrate.
struct Timeline {
    /// One bit's time.
    bit: Duration,
    /// When the bus is next free.
    free: Instant,
    /// Frames from the kit on their way, with the time their last bit is out.
    on_the_way: VecDeque<(Instant, Frame)>,
}

impl Timeline {
    fn new(bitrate: u32, now: Instant) -> Timeline {
        Timeline {
            bit: Duration::from_nanos(1_000_000_000 / u64::from(bitrate.max(1))),
            free: now,
            on_the_way: VecDeque::new(),
        }
    }

    /// `frame` goes on the bus at `now` (or when the bus is free): when its last bit is
    /// out.
    fn put(&mut self, frame: &Frame, now: Instant) -> Instant {
        let done = self.free.max(now) + self.bit * frame.wire_bits(false);
        self.free = done;
        done
    }

    /// When the next frame of the kit is through.
    fn next(&self) -> Option<Instant> {
        self.on_the_way.front().map(|(at, _)| *at)
    }
}

/// The adapter's USB link: up on a pseudo-terminal pair, or gone until a time.
enum Link {
    /// Both ends: holding the device end keeps the host's end readable while the host
    /// closes and reopens it.
    Up {
        master: TTYPort,
        _slave: TTYPort,
    },
    Down {
        back: Instant,
    },
}

/// One simulated bus's port loop.
pub(super) struct ServedBus {
    pub(super) config: BusConfig,
    pub(super) link: PathBuf,
    pub(super) kit: SimKit,
    pub(super) model: Arc<Mutex<Model>>,
    pub(super) stop: Arc<AtomicBool>,
    pub(super) faults: Arc<Faults>,
    pub(super) pty: Arc<Mutex<String>>,
    pub(super) lives: Arc<AtomicU32>,
    pub(super) events: Events,
}

impl ServedBus {
    /// The bus's thread: until stopped, the kit runs (its reports, its watchdog) whether
    /// or not the adapter is plugged in; while it is, the host's bytes are answered and
    /// the bus's frames reach the host.
    pub(crate) fn run(self, master: TTYPort, slave: TTYPort) {
        let now = Instant::now();
        let mut link = Link::Up {
            master,
            _slave: slave,
        };
        let mut wire = Timeline::new(self.config.bitrate.bits_per_second(), now);
        let mut applied: Vec<Option<f64>> = vec![None; self.kit.bindings.len()];
        let mut bus_fault = false;
        let mut out = Vec::with_capacity(1024);
        let mut chunk = [0u8; 512];
        while !self.stop.load(Relaxed) {
            out.clear();
            let mut sent: Vec<Frame> = Vec::new();
            // The host's bytes, waiting no longer than the bus's next frame.
            let wait = {
                let now = Instant::now();
                let p = self.kit.port.lock();
                let mut wait = p.wait(now).min(TURN);
                if let Some(at) = wire.next() {
                    wait = wait.min(at.saturating_duration_since(now));
                }
                wait.max(Duration::from_millis(1))
            };
            link = match link {
                Link::Up { .. } if self.faults.vanish_ms.load(Relaxed) > 0 => {
                    let down = self.faults.vanish_ms.swap(0, Relaxed);
                    // A USB unplug: both ends close and the link goes; the bus runs on.
                    drop(link);
                    let _ = std::fs::remove_file(&self.link);
                    tracing::info!(bus = %self.config.name, "simulated adapter vanished for {down} ms");
                    Link::Down {
                        back: Instant::now() + Duration::from_millis(down),
                    }
                }
                Link::Up { mut master, _slave } => {
                    let _ = master.set_timeout(wait);
                    let n = match master.read(&mut chunk) {
                        Ok(n) => n,
                        Err(e) if e.kind() == std::io::ErrorKind::TimedOut => 0,
                        Err(_) => {
                            std::thread::sleep(wait);
                            0
                        }
                    };
                    if n > 0 {
                        let now = Instant::now();
                        let mut p = self.kit.port.lock();
                        sent.extend_from_slice(p.input(&chunk[..n], now, &mut out));
                        for f in &sent {
                            wire.put(f, now);
                        }
                    }
                    Link::Up { master, _slave }
                }
                Link::Down { back } if Instant::now() < back => {
                    std::thread::sleep(wait);
                    Link::Down { back }
                }
                Link::Down { .. } => match bring_up(&self.link) {
                    Ok((master, slave, pty)) => {
                        tracing::info!(bus = %self.config.name, pty = %pty, "simulated adapter is back");
                        *self.pty.lock() = pty;
                        self.lives.fetch_add(1, Relaxed);
                        // A new adapter: closed, no bitrate, as plugged in.
                        self.kit.port.lock().adapter = Adapter::new(Instant::now());
                        bus_fault = false;
                        Link::Up {
                            master,
                            _slave: slave,
                        }
                    }
                    Err(e) => {
                        tracing::error!(bus = %self.config.name, "simulated adapter cannot come back: {e}");
                        return;
                    }
                },
            };
            let now = Instant::now();
            // The bus runs: the model feeds the vehicle's messages, the kit speaks, the
            // frames that are through reach the host.
            let (states, notes) = {
                let (speed, angle, pressure) = self.vehicle();
                let mut p = self.kit.port.lock();
                let fault = self.kit.bus_fault.load(Relaxed);
                if fault != bus_fault {
                    p.adapter.set_bus_fault(fault);
                    bus_fault = fault;
                }
                p.node.set_speed(speed * 3.6);
                p.node.set_steering_angle(angle);
                p.node.set_brake_pressure(pressure);
                let mut frames = Vec::new();
                frames.extend_from_slice(p.poll(now));
                for f in frames {
                    let at = wire.put(&f, now);
                    wire.on_the_way.push_back((at, f));
                }
                while let Some((at, f)) = wire.on_the_way.front().copied() {
                    if at > now {
                        break;
                    }
                    wire.on_the_way.pop_front();
                    if matches!(link, Link::Up { .. }) {
                        p.adapter.deliver(&f, at, &mut out);
                    }
                }
                let states: Vec<_> = self
                    .kit
                    .bindings
                    .iter()
                    .map(|b| p.node.state(b.module))
                    .collect();
                (states, p.node.take_notes())
            };
            self.drive(&states, &mut applied, &sent, &notes);
            if let Link::Up { master, .. } = &mut link {
                self.answer(master, &mut out);
            }
        }
    }

    /// The model's road speed (m/s), steering wheel angle (degrees) and brake pressure
    /// (bar), now: each position as its sensor reports it (a `bias` slips it).
    fn vehicle(&self) -> (f64, f64, f64) {
        let mut m = self.model.lock();
        m.step();
        let position = |module: Module| {
            self.kit
                .bindings
                .iter()
                .find(|b| b.module == module)
                .map_or(0.0, |b| {
                    let d = m.device(b.device);
                    d.position + d.bias
                })
        };
        (
            m.velocity.abs(),
            position(Module::Steering) * STEERING_WHEEL_DEG,
            position(Module::Brake).max(0.0) * BRAKE_FULL_BAR,
        )
    }

    /// Apply the modules' requests to the model (what a disabled module asks is
    /// nothing), and tell what the kit received and did.
    fn drive(
        &self,
        states: &[super::oscc::ModuleState],
        applied: &mut [Option<f64>],
        sent: &[Frame],
        notes: &[super::oscc::Note],
    ) {
        let speed = self.model.lock().velocity;
        for ((b, s), last) in self.kit.bindings.iter().zip(states).zip(applied.iter_mut()) {
            let want = if s.enabled { s.request } else { 0.0 };
            if *last != Some(want) {
                let _ = self.model.lock().command(b.device, Command::Set(want));
                *last = Some(want);
            }
            for f in sent.iter().filter(|f| f.id() == b.command && s.enabled) {
                let command = Command::Set(s.request);
                self.events.emit(SimEvent {
                    device: b.device,
                    name: b.config.name.clone(),
                    at: Instant::now(),
                    command,
                    text: b.config.command_text(command),
                    request: proto::encode_command(&proto::Command::Transmit(*f)).to_vec(),
                    note: None,
                    speed,
                    state_before: None,
                });
            }
        }
        for n in notes {
            tracing::info!(bus = %self.config.name, "simulated {} module: {}", n.module, n.what);
            let Some((b, last)) = self
                .kit
                .bindings
                .iter()
                .zip(applied.iter())
                .find(|(b, _)| b.module == n.module)
            else {
                continue;
            };
            let command = Command::Set(last.unwrap_or(0.0));
            self.events.emit(SimEvent {
                device: b.device,
                name: b.config.name.clone(),
                at: n.at,
                command,
                text: b.config.command_text(command),
                request: Vec::new(),
                note: Some(format!("{} module: {}", n.module, n.what)),
                speed,
                state_before: None,
            });
        }
    }

    /// Send the host what the adapter has for it, through the port's faults.
    fn answer(&self, master: &mut TTYPort, out: &mut Vec<u8>) {
        if out.is_empty() || self.faults.silent.load(Relaxed) {
            return;
        }
        if self.faults.garbage.load(Relaxed) {
            *out = b"\xff\x00?#garbage\xfe\r\n".to_vec();
        }
        if self.faults.corrupt.load(Relaxed) {
            if let Some(last) = out.last_mut() {
                *last ^= 0x01;
            }
        }
        let slow = self.faults.slow_ms.load(Relaxed);
        if slow > 0 {
            std::thread::sleep(Duration::from_millis(slow));
        }
        // A host that does not read (none has the port open) must not stall the bus:
        // what the pseudo-terminal cannot take is lost, as an adapter's USB buffer does.
        let _ = master.set_timeout(Duration::from_millis(1));
        let _ = master.write_all(out);
        let _ = master.flush();
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::can::Id;

    #[test]
    fn frames_share_the_bus_one_after_another_at_its_bitrate() {
        let t0 = Instant::now();
        let mut wire = Timeline::new(500_000, t0);
        let full = Frame::new(Id::Standard(0x73), &[0; 8]).unwrap();
        // 111 bits at 2 µs each; the second waits for the first.
        assert_eq!(wire.put(&full, t0), t0 + Duration::from_micros(222));
        assert_eq!(wire.put(&full, t0), t0 + Duration::from_micros(444));
        // A frame after the bus went quiet starts when it is put.
        let later = t0 + Duration::from_millis(20);
        assert_eq!(wire.put(&full, later), later + Duration::from_micros(222));
    }

    #[test]
    fn an_operator_override_on_a_device_without_a_kit_asks_for_a_position() {
        let sim = super::super::Sim::start(&VehicleConfig::alice(), None).unwrap();
        let e = sim.apply("override gas on").unwrap_err();
        assert_eq!(
            e,
            "gas is not driven by a kit's module: give the position a hand pushes it toward (`override gas 0.5`)"
        );
        let e = sim.apply("fault gas INVALID_SENSOR_VAL on").unwrap_err();
        assert!(
            e.contains(
                "gas is not driven by a simulated kit's module (kit modules: none in this vehicle)"
            ),
            "{e}"
        );
    }

    /// `fault MODULE DTC on` holds the condition behind the code; `off` ends it, and
    /// the module clears the code by itself, as OSCC's firmware does.
    #[test]
    fn a_kit_modules_fault_holds_until_its_condition_is_switched_off() {
        let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("vehicles/oscc.toml");
        let config = crate::config::load(&path).unwrap();
        let sim = super::super::Sim::start(&config, None).unwrap();
        let dtcs = || {
            sim.with_kit("kit", |p| p.node.state(Module::Brake).dtcs)
                .unwrap()
        };
        let done = sim.apply("fault brake INVALID_SENSOR_VAL on").unwrap();
        assert!(
            done.contains("until `fault brake INVALID_SENSOR_VAL off`"),
            "{done}"
        );
        // A disabled module with no code does not look: it sees the grounded sensor
        // once enabled.
        sim.with_kit("kit", |p| {
            let f = config.buses[0]
                .dbc
                .message("BRAKE_ENABLE")
                .unwrap()
                .encode(&[])
                .unwrap();
            super::super::slcan::BusNode::receive(&mut p.node, &f, Instant::now());
        });
        let end = Instant::now() + Duration::from_secs(20);
        while dtcs() != 1 {
            assert!(Instant::now() < end, "the brake never reported the fault");
            std::thread::sleep(Duration::from_millis(5));
        }
        sim.apply("fault brake INVALID_SENSOR_VAL off").unwrap();
        while dtcs() != 0 {
            assert!(Instant::now() < end, "the brake never cleared its code");
            std::thread::sleep(Duration::from_millis(5));
        }
    }
}
