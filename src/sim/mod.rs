//! The simulator: every device of the vehicle on its own pseudo-terminal, speaking its
//! wire protocol, in front of one shared [`model::Model`] of the vehicle.
//!
//! A pseudo-terminal passes bytes instantly, so each device's port loop holds every
//! reply for the time the request and the reply take on the wire at the configured
//! baud (10 bits a byte) plus the device's turnaround, and serves one transaction at a
//! time, as the real device does. Faults can be injected per device ([`Faults`]).

pub mod device;
pub mod elm327;
pub mod line;
pub mod model;
pub mod modbus;
#[cfg(test)]
pub(crate) mod test_serve;

use crate::config::{DeviceConfig, DriverKind, VehicleConfig};
use crate::value::{Command, EstopState, Reading, Role};
use crossbeam_channel::Sender;
use device::{Plant, Responder};
use model::Model;
use parking_lot::Mutex;
use serialport::{SerialPort, TTYPort};
use std::io::{Read, Write};
use std::sync::atomic::{AtomicBool, Ordering::Relaxed};
use std::sync::Arc;
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

/// Faults that can be injected into one simulated device.
#[derive(Default, Debug)]
pub struct Faults {
    /// Swallow requests without answering.
    pub silent: AtomicBool,
}

/// Something a simulated device received, for `adrive sim`'s log.
#[derive(Clone, Debug)]
pub struct SimEvent {
    pub role: Role,
    pub at: Instant,
    /// The command the device applied.
    pub command: Command,
    /// The raw request bytes.
    pub request: Vec<u8>,
}

/// One simulated device's port.
pub struct SimPort {
    pub role: Role,
    /// Path of the pseudo-terminal adrive (or any tool) opens.
    pub path: String,
    pub faults: Arc<Faults>,
}

/// The running simulator.
pub struct Sim {
    pub ports: Vec<SimPort>,
    model: Arc<Mutex<Model>>,
    stop: Arc<AtomicBool>,
    threads: Vec<JoinHandle<()>>,
}

/// Wire time of `bytes` at `baud`, 10 bits a byte (start, 8 data, stop).
pub fn wire_time(bytes: usize, baud: u32) -> Duration {
    Duration::from_nanos((bytes as u64 * 10 * 1_000_000_000) / baud.max(1) as u64)
}

fn responder_for(c: &DeviceConfig) -> Box<dyn Responder> {
    match c.driver {
        DriverKind::Line => Box::new(line::LineDevice),
    }
}

struct DevicePlant<'a> {
    role: Role,
    model: &'a Mutex<Model>,
    applied: Option<Command>,
}

impl Plant for DevicePlant<'_> {
    fn reading(&mut self) -> Reading {
        self.model.lock().reading(self.role)
    }
    fn command(&mut self, command: Command) -> Result<(), String> {
        self.model.lock().command(self.role, command)?;
        self.applied = Some(command);
        Ok(())
    }
}

impl Sim {
    /// Start a simulated device for every device of `config`. `events`, if given,
    /// receives every command a device applies.
    pub fn start(config: &VehicleConfig, events: Option<Sender<SimEvent>>) -> std::io::Result<Sim> {
        let model = Arc::new(Mutex::new(Model::new()));
        let stop = Arc::new(AtomicBool::new(false));
        let mut ports = Vec::new();
        let mut threads = Vec::new();
        for c in &config.devices {
            let (mut master, slave) = TTYPort::pair().map_err(std::io::Error::from)?;
            let path = slave
                .name()
                .ok_or_else(|| std::io::Error::other("pseudo-terminal has no name"))?;
            master
                .set_timeout(Duration::from_millis(20))
                .map_err(std::io::Error::from)?;
            let faults = Arc::new(Faults::default());
            let (cfg, m, s, f, ev) = (
                c.clone(),
                model.clone(),
                stop.clone(),
                faults.clone(),
                events.clone(),
            );
            let h = std::thread::Builder::new()
                .name(format!("sim/{}", c.name))
                .spawn(move || {
                    // Holding the slave end open keeps the master readable while adrive
                    // closes and reopens the port.
                    let _slave = slave;
                    serve(&cfg, master, &m, &s, &f, ev.as_ref());
                })?;
            threads.push(h);
            ports.push(SimPort {
                role: c.name,
                path,
                faults,
            });
        }
        Ok(Sim {
            ports,
            model,
            stop,
            threads,
        })
    }

    pub fn path(&self, role: Role) -> Option<&str> {
        self.ports
            .iter()
            .find(|p| p.role == role)
            .map(|p| p.path.as_str())
    }

    pub fn faults(&self, role: Role) -> Option<&Arc<Faults>> {
        self.ports
            .iter()
            .find(|p| p.role == role)
            .map(|p| &p.faults)
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
}

impl Drop for Sim {
    fn drop(&mut self) {
        self.stop.store(true, Relaxed);
        for t in self.threads.drain(..) {
            let _ = t.join();
        }
    }
}

fn serve(
    c: &DeviceConfig,
    mut port: TTYPort,
    model: &Mutex<Model>,
    stop: &AtomicBool,
    faults: &Faults,
    events: Option<&Sender<SimEvent>>,
) {
    let mut responder = responder_for(c);
    let mut input: Vec<u8> = Vec::with_capacity(256);
    let mut chunk = [0u8; 256];
    while !stop.load(Relaxed) {
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
                model,
                applied: None,
            };
            let Some(reply) = responder.respond(&input, &mut plant) else {
                break;
            };
            let request: Vec<u8> = input.drain(..reply.consumed.min(input.len())).collect();
            if let (Some(tx), Some(command)) = (events, plant.applied) {
                let _ = tx.send(SimEvent {
                    role: c.name,
                    at: arrived,
                    command,
                    request: request.clone(),
                });
            }
            if faults.silent.load(Relaxed) || reply.bytes.is_empty() {
                continue;
            }
            let processing = if plant.applied.is_some() {
                c.sim.command_delay
            } else {
                c.sim.poll_delay
            };
            let hold = wire_time(request.len() + reply.bytes.len(), c.baud)
                + c.sim.turnaround
                + processing
                + reply.extra;
            let due = arrived + hold;
            let now = Instant::now();
            if due > now {
                std::thread::sleep(due - now);
            }
            let _ = port.write_all(&reply.bytes);
            let _ = port.flush();
            // A request that queued meanwhile starts being served now.
            arrived = Instant::now();
        }
    }
}
