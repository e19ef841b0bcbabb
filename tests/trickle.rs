//! A device that trickles: it starts its reply, then sends a byte now and then and never
//! finishes it. Seen in the field on the line-protocol e-stop (a byte every 150–400 ms
//! with `reply_timeout = 200ms`) and on the ELM327: each byte restarted the read's
//! timeout, the device held its port for 11–12 s, and the command thread could not send
//! meanwhile. A transaction now ends at its deadline whatever the device sends.
//!
//! Each protocol's driver runs in the real engine against a scripted device on a real
//! pseudo-terminal; the test measures, at the device, when the next request arrives.

mod common;

use adrive::config;
use adrive::driver;
use adrive::engine::Engine;
use adrive::engine::Gate;
use adrive::value::Command;
use adrive::vehicle::Vehicle;
use common::DEADLINE;
use crossbeam_channel::{Receiver, Sender};
use serialport::{SerialPort, TTYPort};
use std::io::{Read, Write};
use std::sync::atomic::{AtomicBool, Ordering::Relaxed};
use std::sync::Arc;
use std::time::{Duration, Instant};

/// Scheduling noise allowed past a deadline on a loaded machine.
const MARGIN: Duration = Duration::from_millis(300);

/// What the scripted device does with one request.
enum Answer {
    /// Reply at once.
    Reply(Vec<u8>),
    /// Send `head`, then one byte every `every`, forever.
    Trickle(Vec<u8>, Duration),
}

/// How the device tells where a request ends.
#[derive(Clone, Copy)]
enum Framing {
    /// Requests end with this byte.
    Terminator(u8),
    /// Requests are this long (Modbus RTU requests of functions 03, 04, 06).
    Fixed(usize),
}

/// A device on the master side of a pseudo-terminal, answering by a script and
/// reporting every request with the time it arrived.
struct Scripted {
    path: String,
    requests: Receiver<(Instant, Vec<u8>)>,
    stop: Arc<AtomicBool>,
    _host: TTYPort,
}

impl Scripted {
    fn start(framing: Framing, mut answer: impl FnMut(&[u8]) -> Answer + Send + 'static) -> Self {
        let (mut device, host) = TTYPort::pair().expect("a pseudo-terminal pair");
        device.set_timeout(Duration::from_millis(5)).unwrap();
        let path = host.name().expect("the pseudo-terminal has a path");
        let (tx, requests): (Sender<(Instant, Vec<u8>)>, _) = crossbeam_channel::unbounded();
        let stop = Arc::new(AtomicBool::new(false));
        let s = stop.clone();
        std::thread::spawn(move || {
            let mut pending = Vec::new();
            let mut trickle: Option<(Duration, Instant)> = None;
            let mut chunk = [0u8; 64];
            while !s.load(Relaxed) {
                if let Ok(n) = device.read(&mut chunk) {
                    pending.extend_from_slice(&chunk[..n]);
                }
                while let Some(end) = match framing {
                    Framing::Terminator(t) => pending.iter().position(|b| *b == t).map(|i| i + 1),
                    Framing::Fixed(n) => (pending.len() >= n).then_some(n),
                } {
                    let request: Vec<u8> = pending.drain(..end).collect();
                    if tx.send((Instant::now(), request.clone())).is_err() {
                        return;
                    }
                    let reply = match answer(&request) {
                        Answer::Reply(bytes) => bytes,
                        Answer::Trickle(head, every) => {
                            trickle = Some((every, Instant::now() + every));
                            head
                        }
                    };
                    let _ = device.write_all(&reply);
                }
                if let Some((every, next)) = trickle.as_mut() {
                    if Instant::now() >= *next {
                        let _ = device.write_all(b"x");
                        *next += *every;
                    }
                }
            }
        });
        Scripted {
            path,
            requests,
            stop,
            _host: host,
        }
    }

    /// The next request the device receives that `matches`.
    fn next(&self, what: &str, matches: impl Fn(&[u8]) -> bool) -> Instant {
        let end = Instant::now() + DEADLINE;
        loop {
            let left = end.saturating_duration_since(Instant::now());
            match self.requests.recv_timeout(left) {
                Ok((t, r)) if matches(&r) => return t,
                Ok(_) => {}
                Err(_) => panic!("the device never received {what}"),
            }
        }
    }

    /// Run the engine on a one-device vehicle whose device is this one.
    fn engine(&self, device: &str) -> Engine {
        let toml = format!(
            "[vehicle]\nname = \"bench\"\n\n[[device]]\nport = \"{}\"\n{device}",
            self.path
        );
        let config = config::parse(&toml, "trickle.toml").expect("test config parses");
        let vehicle = Arc::new(Vehicle::new(config, |c| {
            let (path, baud, timeout) = (c.port.clone(), c.baud, c.reply_timeout);
            Box::new(move || driver::open_serial(&path, baud, timeout))
        }));
        Engine::start(Arc::new(Gate::new(vehicle))).expect("engine starts")
    }
}

impl Drop for Scripted {
    fn drop(&mut self) {
        self.stop.store(true, Relaxed);
    }
}

/// The poll that met the trickle ended at its deadline: its transaction time, as the
/// engine measured it, is within `reply_timeout` and the margin.
fn poll_ended_at_its_deadline(engine: &Engine, device: &str, reply_timeout: Duration) {
    let d = engine.vehicle().find(device).unwrap();
    common::wait_for("the trickled poll to fail", || {
        d.stats().status_errors.load(Relaxed) >= 1
    });
    let took = d.stats().status_txn.summary().max_us.unwrap();
    assert!(
        took <= (reply_timeout + MARGIN).as_micros() as f64,
        "a status transaction took {took} µs (reply timeout {reply_timeout:?})"
    );
}

/// Steering is commanded 0.25 while the trickled poll (begun at `polled`) holds the
/// port: the command thread gets the port and the command (`is_command`) reaches the
/// device once the poll's deadline has passed, not when the device stops trickling.
fn command_follows_the_trickled_poll(
    device: &Scripted,
    engine: &Engine,
    polled: Instant,
    reply_timeout: Duration,
    is_command: impl Fn(&[u8]) -> bool,
) {
    let steer = engine.vehicle().find("steer").unwrap().id();
    engine.gate().supervise(steer, Command::Set(0.25));
    let sent = device.next("the command", is_command);
    assert!(
        sent - polled <= reply_timeout + MARGIN,
        "the command reached the device {:?} after the trickled poll began",
        sent - polled
    );
    poll_ended_at_its_deadline(engine, "steer", reply_timeout);
}

#[test]
fn a_trickling_line_device_holds_its_port_no_longer_than_its_reply_timeout() {
    let reply_timeout = Duration::from_millis(300);
    let device = Scripted::start(Framing::Terminator(b'\n'), |request| {
        if request.starts_with(b"?") {
            // A status line begun and never finished: a byte every 100 ms.
            Answer::Trickle(b"= pos=0.1".to_vec(), Duration::from_millis(100))
        } else {
            Answer::Reply(b"ok\n".to_vec())
        }
    });
    let engine = device.engine(
        "name = \"steer\"\nkind = \"setpoint\"\nrange = [-1.0, 1.0]\ndriver = \"line\"\nbaud = 38400\nreply_timeout = \"300ms\"\n\
         status_period = \"50ms\"\nstatus_max_age = \"10s\"\ncommand_timeout = \"10s\"\n",
    );
    let polled = device.next("a status request", |r| r == b"?\n");
    command_follows_the_trickled_poll(&device, &engine, polled, reply_timeout, |r| {
        r.starts_with(b"! 0.250")
    });
}

#[test]
fn a_trickling_modbus_slave_holds_its_port_no_longer_than_its_reply_timeout() {
    let reply_timeout = Duration::from_millis(600);
    let device = Scripted::start(Framing::Fixed(8), |request| {
        match request[1] {
            // A read: the header of an 11-byte reply, then a byte just inside each
            // read's own wait — 550 ms apart against a 600 ms reply timeout.
            0x03 | 0x04 => {
                Answer::Trickle(vec![request[0], request[1], 6], Duration::from_millis(550))
            }
            // A write is echoed.
            _ => Answer::Reply(request.to_vec()),
        }
    });
    let engine = device.engine(
        "name = \"steer\"\nkind = \"setpoint\"\nrange = [-1.0, 1.0]\ndriver = \"modbus\"\nbaud = 115200\nreply_timeout = \"600ms\"\n\
         status_period = \"50ms\"\nstatus_max_age = \"10s\"\ncommand_timeout = \"10s\"\n\
         [device.modbus]\nslave = 1\n\
         registers = { target = 0, position = 0, status = 2, table = \"input\", scale = 0.0001, signed = true }\n",
    );
    let polled = device.next("a register read", |r| r[1] == 0x04);
    // Write single register (06) 0 = 2500.
    command_follows_the_trickled_poll(&device, &engine, polled, reply_timeout, |r| {
        r[1..6] == [0x06, 0, 0, 0x09, 0xC4]
    });
}

#[test]
fn a_trickling_elm327_holds_its_port_no_longer_than_its_reply_timeout() {
    let reply_timeout = Duration::from_millis(300);
    let mut rpm_requests = 0;
    let device = Scripted::start(Framing::Terminator(b'\r'), move |request| {
        let reply: &[u8] = match request {
            b"ATZ\r" => b"\r\rELM327 v1.5\r\r>",
            b"010C\r" => {
                rpm_requests += 1;
                if rpm_requests > 1 {
                    // After one good poll: an answer begun and never ended by the prompt.
                    return Answer::Trickle(b"41 0C".to_vec(), Duration::from_millis(100));
                }
                b"41 0C 0C 80 \r\r>"
            }
            b"010D\r" => b"41 0D 00 \r\r>",
            b"0105\r" => b"41 05 7B \r\r>",
            _ => b"OK\r\r>",
        };
        Answer::Reply(reply.to_vec())
    });
    let engine = device.engine(
        "name = \"obd\"\nkind = \"sensor\"\nreadings = [\"rpm\", \"speed\", \"coolant\", \"running\"]\ndriver = \"elm327\"\nbaud = 38400\nreply_timeout = \"300ms\"\n\
         status_period = \"50ms\"\nstatus_max_age = \"10s\"\n",
    );
    device.next("the first rpm request", |r| r == b"010C\r");
    let trickled = device.next("the second rpm request", |r| r == b"010C\r");
    // A sensor has no command thread: the status thread's next request shows the port
    // free again.
    let next = device.next("the request after it", |_| true);
    assert!(
        next - trickled <= reply_timeout + MARGIN,
        "the next request came {:?} after the trickled one",
        next - trickled
    );
    poll_ended_at_its_deadline(&engine, "obd", reply_timeout);
    engine.shutdown(Duration::from_secs(2));
}
