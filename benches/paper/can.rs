//! Section 13: a CAN bus. `n` actuators on one SLCAN adapter at 500 kbit/s, each
//! commanded at 100 Hz by a planner: receipt → first byte written to the adapter
//! (adrive's own figure, as for a serial device) beside the floors of the same window,
//! the delay of the last device against the first, and the frames a second the bus
//! carries behind the adapter.
//!
//! The adapter is played by the bench itself on a pseudo-terminal, as strictly as a
//! real one answers: CR to the bring-up, `z` CR for every frame, and a bus behind it
//! that carries one frame at a time at the bitrate (each frame's bits with worst-case
//! stuffing, [`adrive::can::Frame::wire_bits`]): a frame that comes while the bus is
//! busy waits its turn, as in the adapter's transmit buffer. Each actuator reports at
//! 50 Hz on the same bus, as a kit's modules do.

use crate::{delay_columns, delay_of, delay_row, drive, vehicle, with_floor};
use adrive::can::{Frame, Id};
use adrive::driver::slcan::proto::{encode_event, Command, Decoder, Event, FromHost, StatusFlags};
use parking_lot::Mutex;
use serialport::{SerialPort, TTYPort};
use std::io::{Read, Write};
use std::sync::atomic::{AtomicBool, Ordering::Relaxed};
use std::sync::Arc;
use std::time::{Duration, Instant};

const BITRATE: u32 = 500_000;

/// A DBC of `n` actuators: `CMD_i` (0x100 + i, a float request) and `REP_i` (0x200 + i,
/// the position).
fn dbc(n: usize) -> String {
    let mut t = String::from("VERSION \"\"\n\nNS_ :\n\nBS_:\n\nBU_: HOST NODE\n\n");
    for i in 0..n {
        t.push_str(&format!(
            "BO_ {} CMD_{i:02}: 8 HOST\n SG_ request : 0|32@1- (1,0) [-1|1] \"\" NODE\n\n",
            0x100 + i
        ));
        t.push_str(&format!(
            "BO_ {} REP_{i:02}: 8 NODE\n SG_ position : 0|16@1- (0.0001,0) [-3.2768|3.2767] \"\" HOST\n\n",
            0x200 + i
        ));
    }
    for i in 0..n {
        t.push_str(&format!("SIG_VALTYPE_ {} request : 1;\n", 0x100 + i));
    }
    t
}

fn actuator(i: usize) -> String {
    format!(
        "[[device]]\nname = \"c{i:02}\"\nkind = \"setpoint\"\nrange = [-1.0, 1.0]\ndriver = \"can\"\nbus = \"bus\"\ncommand_timeout = \"1s\"\nstatus_max_age = \"200ms\"\nreply_timeout = \"50ms\"\n[device.can]\ncommand = \"CMD_{i:02}.request\"\nreadings = {{ position = \"REP_{i:02}.position\" }}\n"
    )
}

/// What the bench's adapter saw.
#[derive(Default)]
struct Seen {
    /// Command frames from the host.
    commands: u64,
    /// Every frame's bits on the bus, both ways.
    bits: u64,
    /// Frames on the bus, both ways.
    frames: u64,
    /// The longest a frame waited for the bus, µs.
    max_wait_us: f64,
}

struct Adapter {
    seen: Mutex<Seen>,
    stop: AtomicBool,
}

impl Adapter {
    /// Play the adapter on `master` for `n` devices until stopped.
    fn start(mut master: TTYPort, n: usize) -> Arc<Adapter> {
        let a = Arc::new(Adapter {
            seen: Mutex::default(),
            stop: AtomicBool::new(false),
        });
        let me = a.clone();
        master.set_timeout(Duration::from_millis(1)).unwrap();
        std::thread::spawn(move || {
            let mut decoder = Decoder::<FromHost>::new();
            let mut buf = [0u8; 4096];
            let mut out = Vec::new();
            let bit = Duration::from_secs_f64(1.0 / f64::from(BITRATE));
            let mut bus_free = Instant::now();
            let mut next_report = Instant::now();
            let mut open = false;
            let mut on_bus = |f: &Frame, now: Instant, seen: &mut Seen| {
                let start = bus_free.max(now);
                let wait = start - now;
                bus_free = start + bit * f.wire_bits(true);
                seen.bits += u64::from(f.wire_bits(true));
                seen.frames += 1;
                seen.max_wait_us = seen.max_wait_us.max(wait.as_secs_f64() * 1e6);
            };
            while !me.stop.load(Relaxed) {
                let now = Instant::now();
                match master.read(&mut buf) {
                    Ok(k) if k > 0 => decoder.push(&buf[..k]),
                    Ok(_) => return,
                    Err(e) if e.kind() == std::io::ErrorKind::TimedOut => {}
                    Err(_) => return,
                }
                while let Some(c) = decoder.next() {
                    let answer = match c {
                        Ok(Command::Transmit(f)) => {
                            let mut s = me.seen.lock();
                            s.commands += 1;
                            on_bus(&f, now, &mut s);
                            Event::Sent {
                                extended: f.id().is_extended(),
                            }
                        }
                        Ok(Command::Open) => {
                            open = true;
                            Event::Ok
                        }
                        Ok(Command::Close) => {
                            open = false;
                            Event::Ok
                        }
                        Ok(Command::Status) => Event::Status(StatusFlags::default()),
                        Ok(_) => Event::Ok,
                        Err(_) => Event::Refused,
                    };
                    out.extend_from_slice(&encode_event(&answer));
                }
                if open && now >= next_report {
                    next_report = now + Duration::from_millis(20);
                    let mut s = me.seen.lock();
                    for i in 0..n {
                        let id = Id::standard(0x200 + i as u16).unwrap();
                        let f = Frame::new(id, &[0; 8]).unwrap();
                        on_bus(&f, now, &mut s);
                        out.extend_from_slice(&encode_event(&Event::Received {
                            frame: f,
                            timestamp: None,
                        }));
                    }
                }
                if !out.is_empty() && master.write_all(&out).is_err() {
                    return;
                }
                out.clear();
            }
        });
        a
    }
}

impl Drop for Adapter {
    fn drop(&mut self) {
        self.stop.store(true, Relaxed);
    }
}

pub fn section13_can(dir: &tempfile::TempDir, secs: f64) {
    println!(
        "\n== 13. A CAN bus: receipt → first byte to the SLCAN adapter, n actuators at 100 Hz each on one bus at {} kbit/s (reports at 50 Hz each), {secs} s ==",
        BITRATE / 1000
    );
    println!(
        "{} {:>9} {:>9} {:>8} {:>7} {:>9}",
        delay_columns("actuators", 10),
        "last/1st",
        "frames/s",
        "bus load",
        "cmd/s",
        "wait max"
    );
    for n in [1usize, 2, 4, 8, 16] {
        let (master, slave) = TTYPort::pair().expect("a pseudo-terminal pair");
        let path = slave.name().expect("a pty name");
        let adapter = Adapter::start(master, n);
        std::fs::write(dir.path().join(format!("can-{n}.dbc")), dbc(n)).unwrap();
        let head = format!(
            "\n[[bus]]\nname = \"bus\"\nport = \"{path}\"\nbitrate = {BITRATE}\ndbc = \"can-{n}.dbc\"\n"
        );
        let devices: Vec<String> = (0..n).map(actuator).collect();
        let names: Vec<String> = (0..n).map(|i| format!("c{i:02}")).collect();
        let a =
            crate::rig::Adrive::start(dir.path(), &format!("can-{n}"), &vehicle(&head, &devices));
        // Count from the planner's first command (the bring-up and engage before it).
        *adapter.seen.lock() = Seen::default();
        let t = Instant::now();
        let (_, floor) = with_floor(|| drive(&a, &names, 100.0, secs));
        let took = t.elapsed().as_secs_f64();
        let seen = std::mem::take(&mut *adapter.seen.lock());
        let snap = a.snapshot();
        let d = delay_of(&snap, &names);
        let first = delay_of(&snap, &names[..1]);
        let last = delay_of(&snap, &names[n - 1..]);
        println!(
            "{} {:>8.2}× {:>9.0} {:>7.1} % {:>7.0} {:>6.0} µs",
            delay_row(&n.to_string(), 10, &d, floor),
            last.p50 / first.p50,
            seen.frames as f64 / took,
            100.0 * seen.bits as f64 / took / f64::from(BITRATE),
            seen.commands as f64 / took,
            seen.max_wait_us
        );
        drop(a);
        drop(slave);
    }
    println!("(delay: adrive's own, from its listener's read to the kernel taking the frame's first byte to the adapter; frames/s and bus load: both ways on the simulated bus, worst-case stuffing; wait max: the longest a frame waited for the bus.)");
}
