//! Section 11: the command path seen from outside, as a user measures it — a planner's
//! `sendto` → the command's first byte readable at the device's end of its port — beside
//! the least any program can do, a bare relay (one thread, `recv` → write) onto the
//! same kind of pseudo-terminal, in the same round.
//!
//! A measured device is a pseudo-terminal whose master this process holds: on the line
//! protocol it answers `?` with the last commanded position and `! v` with `ok`; on
//! Modbus RTU it answers as a slave, with the crate's own frame encode/decode. Each
//! request's first byte is timed as it is read. Every datagram to a measured device
//! carries a distinct value, matched to the first request that carries it.
//!
//! Two methods measure the relay beside adrive, and the section prints both, each row
//! with its ratio to its relay:
//! - *interleaved*: the relay's datagrams go between adrive's, in the same window, so
//!   that both figures of a row see the same load — every row, including the
//!   placements of the command path (the vehicle file's `cpus`);
//! - *in rounds*: this process is the planner and the device; adrive runs alone in a
//!   window of [`ROUNDS_SENT`] datagrams (one line-protocol device polled every 50 ms),
//!   then the relay alone in a window of its own, adrive stopped — each as it runs on
//!   the machine by itself.
//!
//! Rows run in two rounds, each round with its own relay; each row shows its better
//! round (the lower p50 against that round's relay). adrive runs with its probe on
//! ([`adrive::probe`]), so the one-device rows' totals are broken into their steps
//! under the tables, beside the relay's.

// The device ends and the relay are pseudo-terminals and raw sockets driven through
// libc; each block says why it is sound.
#![allow(unsafe_code)]

use super::common::pty::openpty;
use super::floor::quantile;
use super::rig::{Adrive, Sim};
use super::{attach_consoles, idle_actuator, vehicle, viewer};
use adrive::driver::modbus::proto::{self, Incoming, Request, Response};
use adrive::probe::{self, mono_ns, Step};
use std::collections::HashMap;
use std::fs::File;
use std::io::{Read, Write};
use std::net::UdpSocket;
use std::os::fd::{AsRawFd, OwnedFd};
use std::path::Path;
use std::sync::{Arc, Mutex};
use std::time::Duration;

const RATE: f64 = 100.0;

/// Datagrams per measured device in a row: two of the section's windows' worth.
fn sent_per_row(secs: f64) -> u64 {
    ((secs * RATE * 2.0) as u64).clamp(300, MOST_SENT)
}

/// The most datagrams per measured device in a row of the first method.
const MOST_SENT: u64 = 999;

/// The protocol a measured device speaks.
#[derive(Clone, Copy, PartialEq)]
pub(super) enum Proto {
    Line,
    Modbus,
}

/// Modbus scale of the measured device: the value's three decimals as a register.
const SCALE: f64 = 0.001;

/// The device's end of a pseudo-terminal: every command request's first byte, timed.
pub(super) struct DeviceEnd {
    pub(super) path: String,
    /// Value text → when its request's first byte was read (ns, `CLOCK_MONOTONIC`).
    pub(super) seen: Arc<Mutex<HashMap<String, u64>>>,
    _slave: OwnedFd,
}

impl DeviceEnd {
    /// `answer`: reply to the host (adrive) as the device; a relay gets no replies.
    pub(super) fn open(proto: Proto, answer: bool) -> DeviceEnd {
        let (master, slave) = openpty(80, 24);
        raw(&slave);
        let mut buf = [0u8; 128];
        // SAFETY: ptsname_r writes a NUL-terminated path into the buffer given.
        let r = unsafe { libc::ptsname_r(master.as_raw_fd(), buf.as_mut_ptr().cast(), buf.len()) };
        assert_eq!(r, 0, "ptsname");
        let n = buf.iter().position(|&b| b == 0).unwrap();
        let path = String::from_utf8_lossy(&buf[..n]).into_owned();
        let seen = Arc::new(Mutex::new(HashMap::new()));
        let s = seen.clone();
        let m = File::from(master);
        std::thread::Builder::new()
            .name("device-end".into())
            .spawn(move || match proto {
                Proto::Line => line_end(m, &s, answer),
                Proto::Modbus => modbus_end(m, &s),
            })
            .unwrap();
        DeviceEnd {
            path,
            seen,
            _slave: slave,
        }
    }
}

fn line_end(mut m: File, seen: &Mutex<HashMap<String, u64>>, answer: bool) {
    let mut w = m.try_clone().unwrap();
    let (mut line, mut started) = (Vec::new(), 0u64);
    let mut pos = String::from("0.000");
    let mut chunk = [0u8; 256];
    while let Ok(n) = m.read(&mut chunk) {
        if n == 0 {
            return;
        }
        let at = mono_ns();
        for &b in &chunk[..n] {
            if line.is_empty() {
                started = at;
            }
            if b != b'\n' && b != b'\r' {
                line.push(b);
                continue;
            }
            if line.is_empty() {
                continue;
            }
            let text = String::from_utf8_lossy(&line).into_owned();
            line.clear();
            if let Some(v) = text.strip_prefix("! ") {
                seen.lock().unwrap().entry(v.to_string()).or_insert(started);
                pos = v.to_string();
                if answer {
                    let _ = w.write_all(b"ok\n");
                }
            } else if text == "?" && answer {
                let _ = w.write_all(format!("= pos={pos}\n").as_bytes());
            }
        }
    }
}

/// A Modbus RTU slave (id 1): writes to register 0 are the commands; input registers
/// 0 and 1 are the position and a clear status word.
fn modbus_end(mut m: File, seen: &Mutex<HashMap<String, u64>>) {
    let mut w = m.try_clone().unwrap();
    let (mut buf, mut started) = (Vec::new(), 0u64);
    let mut pos = 0u16;
    let mut chunk = [0u8; 256];
    while let Ok(n) = m.read(&mut chunk) {
        if n == 0 {
            return;
        }
        if buf.is_empty() {
            started = mono_ns();
        }
        buf.extend_from_slice(&chunk[..n]);
        loop {
            match proto::decode_request(&buf) {
                Incoming::Incomplete => break,
                Incoming::Request { request, len, .. } => {
                    let reply = match request {
                        Request::WriteSingle { addr, value } => {
                            let v = value as i16 as f64 * SCALE;
                            seen.lock()
                                .unwrap()
                                .entry(format!("{v:.3}"))
                                .or_insert(started);
                            pos = value;
                            Response::WriteSingle { addr, value }
                        }
                        Request::ReadInput { count, .. } | Request::ReadHolding { count, .. } => {
                            let mut regs = vec![0u16; count as usize];
                            if let Some(r) = regs.first_mut() {
                                *r = pos;
                            }
                            Response::ReadInput(regs)
                        }
                        Request::WriteMultiple { addr, values } => Response::WriteMultiple {
                            addr,
                            count: values.len() as u16,
                        },
                    };
                    let _ = w.write_all(&proto::encode_response(1, &reply));
                    buf.drain(..len);
                }
                Incoming::Refuse { len, .. } | Incoming::Garbage { len, .. } => {
                    buf.drain(..len.max(1));
                }
            }
            if buf.is_empty() {
                break;
            }
            started = mono_ns();
        }
    }
}

/// The slave side raw, as a serial port is opened.
#[allow(unsafe_code)]
fn raw(fd: &OwnedFd) {
    // SAFETY: tcgetattr fills the struct; cfmakeraw and tcsetattr read it.
    unsafe {
        let mut t = std::mem::zeroed::<libc::termios>();
        libc::tcgetattr(fd.as_raw_fd(), &mut t);
        libc::cfmakeraw(&mut t);
        libc::tcsetattr(fd.as_raw_fd(), libc::TCSANOW, &t);
    }
}

/// The value of datagram `i`, as adrive writes it (three decimals), distinct over a row
/// (over [`DISTINCT`] datagrams: a window of the second method is [`ROUNDS_SENT`]).
pub(super) fn value(i: u64) -> String {
    format!("{:.3}", (i % DISTINCT) as f64 / 1000.0 - 0.999)
}

/// Datagrams with distinct values ([`value`]): −0.999 … 0.999.
const DISTINCT: u64 = 1999;
const _: () = assert!(ROUNDS_SENT < DISTINCT && MOST_SENT < DISTINCT);

/// One measured datagram: when it was sent and when its first byte was read (ns).
#[derive(Clone, Copy)]
struct Sample {
    sent: u64,
    seen: u64,
}

/// Send `sent` rounds at [`RATE`]: in each, one datagram to every device of `names`,
/// spread evenly over the period (independent controllers); those to the `measured`
/// devices (index into `names`, their ends) are timed. Returns each measured device's
/// samples, in the order sent.
fn measure(
    names: &[String],
    measured: &[(usize, &DeviceEnd)],
    sent: u64,
    mut send: impl FnMut(&str),
) -> Vec<Vec<Sample>> {
    super::precise_timers();
    let step = Duration::from_secs_f64(1.0 / RATE / names.len() as f64);
    let mut sends: Vec<Vec<(String, u64)>> = measured.iter().map(|_| Vec::new()).collect();
    let start = std::time::Instant::now();
    let mut k = 0u32;
    for i in 0..sent {
        let v = value(i);
        for (j, name) in names.iter().enumerate() {
            let next = start + step * k;
            k += 1;
            if let Some(d) = next.checked_duration_since(std::time::Instant::now()) {
                std::thread::sleep(d);
            }
            let text = format!("{name} {v}\n");
            let t0 = mono_ns();
            send(&text);
            if let Some(m) = measured.iter().position(|(x, _)| *x == j) {
                sends[m].push((v.clone(), t0));
            }
        }
    }
    std::thread::sleep(Duration::from_millis(200));
    measured
        .iter()
        .zip(sends)
        .map(|((_, end), sends)| {
            let seen = end.seen.lock().unwrap();
            sends
                .into_iter()
                .filter_map(|(v, t0)| seen.get(&v).map(|&t| Sample { sent: t0, seen: t }))
                .collect()
        })
        .collect()
}

/// Sorted durations.
fn sorted(mut d: Vec<Duration>) -> Vec<Duration> {
    d.sort();
    d
}

fn totals(s: &[Sample]) -> Vec<Duration> {
    sorted(
        s.iter()
            .map(|x| Duration::from_nanos(x.seen.saturating_sub(x.sent)))
            .collect(),
    )
}

/// p50, p99, max µs.
fn figures(d: &[Duration]) -> (f64, f64, f64) {
    let max = d.last().map_or(f64::NAN, |x| x.as_secs_f64() * 1e6);
    (quantile(d, 0.5), quantile(d, 0.99), max)
}

/// The environment variable that makes the bench binary a relay process instead
/// ([`relay_process`]): the pseudo-terminal to write to.
pub const RELAY: &str = "ADRIVE_BENCH_RELAY";
/// With [`RELAY`]: the relay runs under `SCHED_FIFO` at this priority, as the row it is
/// compared with runs adrive's command path (`realtime_priority`).
const RELAY_PRIORITY: &str = "ADRIVE_BENCH_RELAY_PRIORITY";

/// The priority of the realtime placement row, adrive's and its relay's.
const ROW_PRIORITY: i32 = 50;

/// The bench binary run as a bare relay, a process of its own as adrive is: one
/// thread, `recv` → write `! v\n` to its port (`v`: what follows the datagram's first
/// space). Prints its UDP port first; on a one-byte datagram, prints its own stamps of
/// each datagram since the last such (`recv` returned, write returned, ns) and `end`;
/// on a two-byte one, ends.
pub fn relay_process(path: &str) {
    if let Some(p) = std::env::var(RELAY_PRIORITY)
        .ok()
        .and_then(|p| p.parse::<i32>().ok())
    {
        let param = libc::sched_param { sched_priority: p };
        // SAFETY: sched_setscheduler reads the parameter handed to it; 0 is this thread.
        #[allow(unsafe_code)]
        let r = unsafe { libc::sched_setscheduler(0, libc::SCHED_FIFO, &param) };
        assert_eq!(
            r,
            0,
            "the relay's SCHED_FIFO {p}: {}",
            std::io::Error::last_os_error()
        );
    }
    let rx = UdpSocket::bind("127.0.0.1:0").unwrap();
    println!("{}", rx.local_addr().unwrap().port());
    let mut port = std::fs::OpenOptions::new()
        .read(true)
        .write(true)
        .open(path)
        .unwrap();
    let mut buf = [0u8; 256];
    let mut out = Vec::with_capacity(64);
    let mut stamps: Vec<(u64, u64)> = Vec::with_capacity(1 << 16);
    while let Ok(n) = rx.recv(&mut buf) {
        let received = mono_ns();
        if n <= 2 {
            let mut text = String::new();
            for (r, w) in stamps.drain(..) {
                text.push_str(&format!("{r} {w}\n"));
            }
            println!("{text}end");
            if n == 2 {
                return;
            }
            continue;
        }
        let text = &buf[..n];
        let v = match text.iter().position(|&b| b == b' ') {
            Some(i) => &text[i + 1..],
            None => text,
        };
        out.clear();
        out.extend_from_slice(b"! ");
        out.extend_from_slice(v);
        let _ = port.write_all(&out);
        let written = mono_ns();
        stamps.push((received, written));
    }
}

/// Whether a thread of this process may run under `SCHED_FIFO` (tried on a thread of
/// its own, which then ends).
fn fifo_allowed() -> bool {
    std::thread::spawn(|| {
        let param = libc::sched_param {
            sched_priority: ROW_PRIORITY,
        };
        // SAFETY: sched_setscheduler reads the parameter handed to it; 0 is this thread.
        #[allow(unsafe_code)]
        let r = unsafe { libc::sched_setscheduler(0, libc::SCHED_FIFO, &param) };
        r == 0
    })
    .join()
    .unwrap_or(false)
}

/// A bare relay process ([`relay_process`]) and the device end it writes to, measured
/// in the same window as adrive, its datagrams between adrive's.
struct Relay {
    end: DeviceEnd,
    tx: UdpSocket,
    child: std::process::Child,
    out: std::io::BufReader<std::process::ChildStdout>,
}

impl Relay {
    /// A relay at normal priority, or under `SCHED_FIFO` at `priority`.
    fn start(priority: Option<i32>) -> Relay {
        use std::io::BufRead;
        let end = DeviceEnd::open(Proto::Line, false);
        let mut child = std::process::Command::new(std::env::current_exe().unwrap());
        child.env(RELAY, &end.path);
        if let Some(p) = priority {
            child.env(RELAY_PRIORITY, p.to_string());
        }
        let mut child = child.stdout(std::process::Stdio::piped()).spawn().unwrap();
        let mut out = std::io::BufReader::new(child.stdout.take().unwrap());
        let mut line = String::new();
        out.read_line(&mut line).unwrap();
        let tx = UdpSocket::bind("127.0.0.1:0").unwrap();
        tx.connect(("127.0.0.1", line.trim().parse::<u16>().unwrap()))
            .unwrap();
        Relay {
            end,
            tx,
            child,
            out,
        }
    }

    fn send(&self, text: &str) {
        let _ = self.tx.send(text.as_bytes());
    }

    /// Start a window: forget what the device end saw.
    fn clear(&self) {
        self.end.seen.lock().unwrap().clear();
    }

    /// The steps of the window's samples, from the relay's own stamps.
    fn steps(&mut self, samples: &[Sample]) -> Steps {
        use std::io::BufRead;
        let _ = self.tx.send(b"x");
        let mut stamps = Vec::new();
        let mut line = String::new();
        while self.out.read_line(&mut line).is_ok_and(|n| n > 0) && line.trim() != "end" {
            let mut w = line.split_whitespace().map(|x| x.parse::<u64>().ok());
            if let (Some(Some(r)), Some(Some(w))) = (w.next(), w.next()) {
                stamps.push((r, w));
            }
            line.clear();
        }
        let mut steps = Steps::default();
        for s in samples {
            let i = stamps.partition_point(|r: &(u64, u64)| r.0 < s.sent);
            if let Some(&(received, written)) = stamps.get(i) {
                steps.push(0, received.saturating_sub(s.sent));
                steps.push(3, written.saturating_sub(received));
                steps.push(5, s.seen.saturating_sub(written));
                steps.push(7, s.seen.saturating_sub(received));
            }
        }
        steps
    }
}

impl Drop for Relay {
    fn drop(&mut self) {
        let _ = self.tx.send(b"xx");
        let _ = self.child.wait();
    }
}

/// The steps of the way from outside, as [`STEPS`] lists them: each step's durations.
#[derive(Default)]
struct Steps {
    d: [Vec<Duration>; 8],
    fast: usize,
    matched: usize,
}

/// What each step of [`Steps`] is.
const STEPS: [&str; 8] = [
    "sendto → the listener's read returns (loopback UDP, the listener's wake)",
    "the network's checks: sender, grammar, key, counter",
    "the one intake: ownership, value, interlocks",
    "fast path (wire check, port, write) or slot + command thread, to the write",
    "  (fast path: to its send returning, the trace included; a preempted write shows here)",
    "write → first byte read at the device (pty delivery, reader's wake)",
    "after the write, the listener busy until it reads again",
    "inside: the read returns → first byte read at the device (all but the UDP hop)",
];

impl Steps {
    fn push(&mut self, i: usize, ns: u64) {
        self.d[i].push(Duration::from_nanos(ns));
    }

    /// adrive's steps, from its probe file and the samples of the measured device.
    fn of(samples: &[Sample], probe_file: &Path) -> Steps {
        let mut records = probe::read(probe_file).unwrap_or_default();
        records.retain(|r| r[Step::Received as usize] != 0);
        records.sort_by_key(|r| r[Step::Received as usize]);
        let mut s = Steps::default();
        for x in samples {
            let i = records.partition_point(|r| r[Step::Received as usize] < x.sent);
            let Some(r) = records.get(i) else { continue };
            let at = |st: Step| r[st as usize];
            let (rcv, parsed, checked) = (at(Step::Received), at(Step::Parsed), at(Step::Checked));
            let (fast, first, handled) = (
                at(Step::FastWritten),
                at(Step::FirstByte),
                at(Step::Handled),
            );
            // Not this datagram's record (a probe record from another sender), or not
            // all of its way stamped.
            if rcv > x.seen || parsed == 0 || checked == 0 || first == 0 {
                continue;
            }
            s.matched += 1;
            s.push(0, rcv.saturating_sub(x.sent));
            s.push(1, parsed.saturating_sub(rcv));
            s.push(2, checked.saturating_sub(parsed));
            s.push(3, first.saturating_sub(checked));
            if fast != 0 {
                s.fast += 1;
                s.push(4, fast.saturating_sub(checked));
            }
            s.push(5, x.seen.saturating_sub(first));
            s.push(7, x.seen.saturating_sub(rcv));
            if handled != 0 {
                s.push(6, handled.saturating_sub(first));
            }
        }
        s
    }

    fn print(&self, label: &str, total: &[Duration]) {
        println!("   {label}: {} datagrams", total.len());
        let p = |d: &[Duration], q| quantile(&sorted(d.to_vec()), q);
        let mut sum = 0.0;
        for (i, what) in STEPS.iter().enumerate() {
            if self.d[i].is_empty() {
                continue;
            }
            let p50 = p(&self.d[i], 0.5);
            if i < 4 || i == 5 {
                sum += p50;
            }
            println!("     {what:<76} {p50:>7.1} {:>8.1}", p(&self.d[i], 0.99));
        }
        println!(
            "     {:<76} {sum:>7.1}   (the total's p50: {:.1})",
            "sum of the steps' p50",
            quantile(total, 0.5)
        );
        if self.matched > 0 {
            println!(
                "     ({} of {} matched to their probe records; {} on the fast path)",
                self.matched,
                total.len(),
                self.fast
            );
        }
    }
}

/// A measured device's table in a vehicle file.
pub(super) fn measured_device(name: &str, proto: Proto, path: &str) -> String {
    let head = format!(
        "[[device]]\nname = \"{name}\"\nkind = \"setpoint\"\nrange = [-1.0, 1.0]\nport = \"{path}\"\nbaud = 115200\nstatus_period = \"50ms\"\nreadings = [\"position\"]\n"
    );
    match proto {
        Proto::Line => format!("{head}driver = \"line\"\n"),
        Proto::Modbus => format!(
            "{head}driver = \"modbus\"\n[device.modbus]\nslave = 1\nregisters = {{ target = 0, position = 0, status = 1, table = \"input\", fault_mask = 0x00FF, scale = {SCALE}, signed = true }}\n"
        ),
    }
}

/// An actuator on `adrive sim` polled every 50 ms (status ~2 ms at 115200 baud).
fn polling_actuator(name: &str) -> String {
    idle_actuator(name)
        .replace("status_period = \"1s\"", "status_period = \"50ms\"")
        .replace("status_max_age = \"2s\"", "status_max_age = \"250ms\"")
}

/// How a row's relay is measured beside adrive.
#[derive(Clone, Copy, PartialEq)]
enum Method {
    /// The relay's datagrams between adrive's, in the same window: both figures see
    /// the same load.
    Interleaved,
    /// adrive alone in its window, then the relay alone in a window of its own (adrive
    /// stopped): each as it would run on the machine by itself.
    Rounds,
}

/// What a row runs: its devices, and what is on beside them.
struct Row {
    label: &'static str,
    proto: Proto,
    method: Method,
    /// Datagrams per measured device, if not the section's.
    sent: Option<u64>,
    /// The vehicle file's `[vehicle]` lines (a placement: `cpus = [1]`).
    head: &'static str,
    /// Devices on `adrive sim` besides the measured ones, and whether they poll at 20 Hz.
    others: usize,
    polling: bool,
    /// The last device is measured too (Fig. 3 from outside: last against first).
    last_too: bool,
    args: Vec<String>,
    consoles: usize,
    viewers: usize,
    /// Compared with this row (a feature's cost), by index.
    against: Option<usize>,
    /// Its relay runs under `SCHED_FIFO` at this priority (the row's own placement).
    relay_priority: Option<i32>,
    /// Not run, and why.
    skip: Option<&'static str>,
}

impl Row {
    fn new(label: &'static str) -> Row {
        Row {
            label,
            proto: Proto::Line,
            method: Method::Interleaved,
            sent: None,
            head: "",
            others: 0,
            polling: false,
            last_too: false,
            args: Vec::new(),
            consoles: 0,
            viewers: 0,
            against: None,
            relay_priority: None,
            skip: None,
        }
    }
}

/// One row's result: the measured devices' samples, adrive's own figure (p50, p99) for
/// the first of them, and the steps of its way; the relay's, measured in the same
/// window.
struct Measured {
    samples: Vec<Vec<Sample>>,
    own: (f64, f64),
    steps: Steps,
    relay: Vec<Sample>,
    relay_steps: Steps,
}

impl Measured {
    /// (p50, p99, max) of the first device and of the relay.
    fn first(&self) -> (f64, f64, f64) {
        figures(&totals(&self.samples[0]))
    }
    fn relay(&self) -> (f64, f64, f64) {
        figures(&totals(&self.relay))
    }
}

fn adrive_row(dir: &Path, sims: &Sims, row: &Row, sent: u64, relay: &mut Relay) -> Measured {
    let first = DeviceEnd::open(row.proto, true);
    let last = row.last_too.then(|| DeviceEnd::open(row.proto, true));
    let mut names = vec!["steer".to_string()];
    let mut devices = vec![measured_device("steer", row.proto, &first.path)];
    let (sim, others) = if row.polling {
        (&sims.polling, &sims.polling_names)
    } else {
        (&sims.idle, &sims.idle_names)
    };
    let others = &others[..row.others];
    let rest: Vec<String> = others
        .iter()
        .map(|n| {
            if row.polling {
                polling_actuator(n)
            } else {
                idle_actuator(n)
            }
        })
        .collect();
    names.extend(others.iter().cloned());
    let mut toml = vehicle(row.head, &devices);
    if !rest.is_empty() {
        toml.push_str(&sim.as_ref().expect("a simulator").patch(&rest.concat()));
    }
    if let Some(l) = &last {
        names.push("last".into());
        devices.push(measured_device("last", row.proto, &l.path));
        toml.push_str(&devices[1]);
    }
    // adrive inherits ADRIVE_PROBE, set for the section.
    let probe_file = dir.join("outside.probe");
    let _ = std::fs::remove_file(&probe_file);
    let args: Vec<&str> = row.args.iter().map(String::as_str).collect();
    let a = Adrive::start_with(dir, "outside", &toml, &args);
    let _clients = attach_consoles(&a, row.consoles);
    let _viewers: Vec<viewer::Viewer> = (0..row.viewers)
        .map(|_| {
            let at = row.args.iter().position(|x| x == "--foxglove").unwrap() + 1;
            viewer::Viewer::start(row.args[at].parse().unwrap())
        })
        .collect();
    let mut measured = vec![(0, &first)];
    if let Some(l) = &last {
        measured.push((names.len() - 1, l));
    }
    let sent = row.sent.unwrap_or(sent);
    let (samples, relay_samples) = match row.method {
        Method::Interleaved => {
            // The relay's datagrams go between adrive's, in the same window.
            names.push("relay".into());
            measured.push((names.len() - 1, &relay.end));
            relay.clear();
            let mut samples = measure(&names, &measured, sent, |t| {
                if t.starts_with("relay ") {
                    relay.send(t)
                } else {
                    a.send(t)
                }
            });
            let relay_samples = samples.pop().unwrap_or_default();
            (samples, relay_samples)
        }
        Method::Rounds => (measure(&names, &measured, sent, |t| a.send(t)), Vec::new()),
    };
    let steps = Steps::of(&samples[0], &probe_file);
    let snap = a.snapshot();
    let own = snap
        .device("steer")
        .map(|s| {
            (
                s.delay_us.p50_us.unwrap_or(f64::NAN),
                s.delay_us.p99_us.unwrap_or(f64::NAN),
            )
        })
        .unwrap_or((f64::NAN, f64::NAN));
    drop(a);
    let _ = std::fs::remove_file(&probe_file);
    let relay_samples = match row.method {
        Method::Interleaved => relay_samples,
        // The relay's own window, after adrive's, adrive stopped.
        Method::Rounds => {
            relay.clear();
            let names = ["relay".to_string()];
            measure(&names, &[(0, &relay.end)], sent, |t| relay.send(t)).remove(0)
        }
    };
    let relay_steps = relay.steps(&relay_samples);
    Measured {
        samples,
        own,
        steps,
        relay: relay_samples,
        relay_steps,
    }
}

/// The method's own noise (an A/A row): a second bare relay, a process of its own,
/// against `relay`, their datagrams interleaved in one window of `sent` each as a row's
/// are with adrive's; the second's p50 and p99 against the first's. The same program
/// on both sides: whatever ratio this gives, the machine gave.
fn a_a(relay: &mut Relay, sent: u64) -> (f64, f64) {
    let twin = Relay::start(None);
    relay.clear();
    twin.clear();
    let names = ["relay".to_string(), "twin".to_string()];
    let s = measure(&names, &[(0, &relay.end), (1, &twin.end)], sent, |t| {
        if t.starts_with("twin ") {
            twin.send(t)
        } else {
            relay.send(t)
        }
    });
    let ((p50, p99, _), (t50, t99, _)) = (figures(&totals(&s[0])), figures(&totals(&s[1])));
    (t50 / p50, t99 / p99)
}

/// The simulators the rows share: idle actuators (polled once a second) and polling
/// ones (20 Hz), started once for the section.
struct Sims {
    idle: Option<Sim>,
    idle_names: Vec<String>,
    polling: Option<Sim>,
    polling_names: Vec<String>,
}

/// Datagrams in each window of the second method (the relay in rounds of its own):
/// 16 s at [`RATE`], whatever the section's windows.
const ROUNDS_SENT: u64 = 1600;

/// The CPUs this process may run on (its affinity: the cgroup's cpuset, `taskset`).
#[allow(unsafe_code)]
fn allowed_cpus() -> Vec<usize> {
    // SAFETY: a zeroed cpu_set_t is the empty set; sched_getaffinity fills it, and
    // CPU_ISSET reads within it.
    unsafe {
        let mut set: libc::cpu_set_t = std::mem::zeroed();
        if libc::sched_getaffinity(0, std::mem::size_of::<libc::cpu_set_t>(), &mut set) != 0 {
            return Vec::new();
        }
        (0..libc::CPU_SETSIZE as usize)
            .filter(|&c| libc::CPU_ISSET(c, &set))
            .collect()
    }
}

pub fn section11_outside(dir: &tempfile::TempDir, secs: f64) {
    let sent = sent_per_row(secs);
    std::env::set_var(probe::ENV, dir.path().join("outside.probe"));
    println!(
        "\n== 11. From outside: a planner's sendto → the first byte at the device, beside a bare relay, by two methods; {sent} datagrams per device at {RATE} Hz per row (the second method: {ROUNDS_SENT} per window), best of two rounds =="
    );
    let idle_names: Vec<String> = (0..62).map(|i| format!("a{i:02}")).collect();
    let polling_names: Vec<String> = (0..9).map(|i| format!("p{i:02}")).collect();
    let start = |names: &[String], dev: fn(&str) -> String, file: &str| {
        let f = dir.path().join(file);
        let devices: Vec<String> = names.iter().map(|n| dev(n)).collect();
        std::fs::write(&f, vehicle("", &devices)).unwrap();
        Some(Sim::start(&f))
    };
    let sims = Sims {
        idle: start(&idle_names, idle_actuator, "outside-idle.toml"),
        polling: start(&polling_names, polling_actuator, "outside-polling.toml"),
        idle_names,
        polling_names,
    };
    let rec = dir
        .path()
        .join("outside.mcap")
        .to_string_lossy()
        .into_owned();
    let fox = format!("127.0.0.1:{}", viewer::free_tcp_port());
    let mut rows = [
        Row::new("one device, line"),
        Row {
            proto: Proto::Modbus,
            ..Row::new("one device, Modbus RTU")
        },
        Row {
            others: 9,
            polling: true,
            ..Row::new("+ 9 devices polling at 20 Hz")
        },
        Row {
            others: 62,
            last_too: true,
            ..Row::new("64 actuators at 100 Hz: first")
        },
        Row {
            args: vec!["--record".into(), rec.clone(), "--record-raw".into()],
            against: Some(0),
            ..Row::new("one device, recording")
        },
        Row {
            consoles: 1,
            against: Some(0),
            ..Row::new("one device, a console attached")
        },
        Row {
            args: vec!["--foxglove".into(), fox],
            viewers: 1,
            against: Some(0),
            ..Row::new("one device, a live viewer")
        },
        Row {
            args: vec!["--ros2".into()],
            against: Some(0),
            ..Row::new("one device, ROS 2 on")
        },
        // The placements: the one-device row is the default (none).
        Row {
            head: "cpus = [0]",
            against: Some(0),
            ..Row::new("one device, cpus = [0]")
        },
        Row {
            head: "cpus = [1]",
            against: Some(0),
            ..Row::new("one device, cpus = [1]")
        },
        Row {
            head: "realtime_priority = 50",
            against: Some(0),
            relay_priority: Some(ROW_PRIORITY),
            ..Row::new("one device, realtime_priority = 50")
        },
        // The second method: the relay in rounds of its own.
        Row {
            method: Method::Rounds,
            sent: Some(ROUNDS_SENT),
            ..Row::new("one device, line")
        },
    ];
    if !cfg!(feature = "ros2") {
        rows[7].skip = Some("not built: cargo bench --bench paper --features ros2");
    }
    let cpus = allowed_cpus();
    for (i, cpu) in [(8, 0), (9, 1)] {
        if !cpus.contains(&cpu) {
            rows[i].skip = Some("not run: a CPU this process may not use");
        }
    }
    if !fifo_allowed() {
        rows[10].skip = Some("not run: SCHED_FIFO refused here (CAP_SYS_NICE or RLIMIT_RTPRIO)");
    }
    // `ADRIVE_BENCH_ROWS=0,4`: just those rows (while working on one).
    if let Ok(only) = std::env::var("ADRIVE_BENCH_ROWS") {
        let keep: Vec<usize> = only
            .split(',')
            .filter_map(|x| x.trim().parse().ok())
            .collect();
        for (i, row) in rows.iter_mut().enumerate() {
            if !keep.contains(&i) && row.skip.is_none() {
                row.skip = Some("not run (ADRIVE_BENCH_ROWS)");
            }
        }
    }
    // Two rounds; in each, every row with its relay: in the row's window, or (the
    // second method) in a window of its own after the row's.
    let mut relay = Relay::start(None);
    // The realtime row's relay runs at the row's priority: each placement against the
    // least a program placed as it is can do.
    let mut rt_relay = rows
        .iter()
        .any(|r| r.skip.is_none() && r.relay_priority.is_some())
        .then(|| Relay::start(Some(ROW_PRIORITY)));
    let mut results: Vec<Vec<Measured>> = rows.iter().map(|_| Vec::new()).collect();
    for _round in 0..2 {
        for (row, out) in rows.iter().zip(&mut results) {
            if row.skip.is_none() {
                let r = match (row.relay_priority, rt_relay.as_mut()) {
                    (Some(_), Some(rt)) => rt,
                    _ => &mut relay,
                };
                out.push(adrive_row(dir.path(), &sims, row, sent, r));
            }
        }
    }
    let aa: Vec<(f64, f64)> = (0..2).map(|_| a_a(&mut relay, sent)).collect();
    drop(relay);
    drop(rt_relay);
    // Each row's better round: the lower p50 against the relay of its window.
    let best: Vec<Option<usize>> = results
        .iter()
        .map(|r| {
            (0..r.len()).min_by(|&a, &b| {
                let q = |i: usize| r[i].first().0 / r[i].relay().0;
                q(a).total_cmp(&q(b))
            })
        })
        .collect();
    let table = Table {
        rows: &rows,
        results: &results,
        best: &best,
    };
    println!("The first method: the relay interleaved (its datagrams between adrive's, in the same window).");
    table.print(Method::Interleaved);
    println!("(bare relay: one thread, recv → write, a process of its own, its datagrams sent between adrive's in the same window; rl: that relay; p50/row: against the one-device row (in brackets: each row's p50/rl against the one-device row's), or the last device against the first; own: adrive's displayed delay, receipt → first byte, for the same commands.)");
    println!(
        "(placements: the one-device row runs where the kernel puts it; `cpus = [0]`, `cpus = [1]`: the vehicle file pins the command path — net/listen and the device's command thread — to that CPU, the device's end and the planner left to the kernel; `realtime_priority = 50`: the command path under SCHED_FIFO 50, against a relay under the same. This machine lets this process use {} CPU(s) ({cpus:?}): the placements measured are those of a {}-CPU machine; those of 4 or 8 cores need such a machine.)",
        cpus.len(),
        cpus.len()
    );
    println!(
        "\nThe second method: one process is both the planner and the device; adrive alone in a window of {ROUNDS_SENT} datagrams at {RATE} Hz (one line-protocol device polled every 50 ms), then the relay alone in a window of its own, adrive stopped."
    );
    table.print(Method::Rounds);
    println!("(rl: the relay of the window after adrive's; both windows' load is whatever the machine had then: interleaved, both figures see the same load, in rounds each sees its own, and adrive's window has its device polled beside it.)");
    // The one-device row on the line protocol measured by method `m`, its better round.
    let one_device = |m: Method| {
        let i = rows
            .iter()
            .position(|r| r.method == m && r.proto == Proto::Line && r.others == 0)?;
        Some(&results[i][best[i]?])
    };
    let one = |m: Method| {
        let m = one_device(m)?;
        let ((p50, p99, _), (r50, r99, _)) = (m.first(), m.relay());
        Some(format!("p50 {:.2}×, p99 {:.2}×", p50 / r50, p99 / r99))
    };
    if let (Some(a), Some(b)) = (one(Method::Interleaved), one(Method::Rounds)) {
        println!("one device, line, against its relay: interleaved {a}; in rounds {b}");
    }
    let aa: Vec<String> = aa
        .iter()
        .enumerate()
        .map(|(i, (p50, p99))| format!("({}) p50 {p50:.2}×, p99 {p99:.2}×", i + 1))
        .collect();
    println!(
        "the method's own noise: a second bare relay against the first, interleaved as the rows are, two windows: {}",
        aa.join("; ")
    );
    // Inside, from the same stamps for both: the listener's read returning to the byte
    // read at the device. The floor of a command path that hands over to no thread is
    // the relay's own span; both end at the byte's delivery, not at a `write` that
    // returns before or after it, as the kernel's worker happens to run.
    let inside = |m: Method| {
        let m = one_device(m)?;
        let q = |d: &[Duration], q| quantile(&sorted(d.to_vec()), q);
        let (a, r) = (&m.steps.d[7], &m.relay_steps.d[7]);
        (!a.is_empty() && !r.is_empty()).then(|| {
            format!(
                "{:.1} / {:.1} µs against {:.1} / {:.1}: p50 {:.2}×, p99 {:.2}×",
                q(a, 0.5),
                q(a, 0.99),
                q(r, 0.5),
                q(r, 0.99),
                q(a, 0.5) / q(r, 0.5),
                q(a, 0.99) / q(r, 0.99)
            )
        })
    };
    if let (Some(a), Some(b)) = (inside(Method::Interleaved), inside(Method::Rounds)) {
        println!("one device, line, inside (the read returns → the byte read at the device), p50 / p99 against its relay's: interleaved {a}; in rounds {b}");
    }
    println!("\nWhere the time goes, p50 and p99 µs of each step (stamps: the planner's sendto and the device's read here, adrive's probe inside):");
    let rounds_row = rows.iter().position(|r| r.method == Method::Rounds);
    for (i, how) in [(Some(0), ""), (rounds_row, ", in rounds")] {
        let Some(i) = i else { continue };
        if let Some(r) = best[i] {
            let m = &results[i][r];
            m.relay_steps
                .print(&format!("bare relay{how} ({})", r + 1), &totals(&m.relay));
            m.steps.print(
                &format!("adrive, one device, line{how} ({})", r + 1),
                &totals(&m.samples[0]),
            );
        }
    }
    println!("(the relay has no checks: its `recv` → write is on the fourth line.)");
    let (hot, cold) = intake_hot_and_cold();
    println!(
        "the network's checks and the intake of one `steer` datagram, timed in this process: {:.2} µs hot (datagram after datagram), {:.2} µs cold (one every 10 ms, as above)",
        hot as f64 / 1000.0,
        cold as f64 / 1000.0
    );
    std::env::remove_var(probe::ENV);
}

/// The section's rows and results, for printing.
struct Table<'a> {
    rows: &'a [Row],
    results: &'a [Vec<Measured>],
    best: &'a [Option<usize>],
}

impl Table<'_> {
    /// The rows measured by `method`, each with the relay of its better round.
    fn print(&self, method: Method) {
        println!(
            "{:<36} {:>5} {:>8} {:>8} {:>8} {:>7} {:>7} {:>15}  {:>13}",
            "row (round)",
            "seen",
            "p50 µs",
            "p99 µs",
            "max µs",
            "p50/rl",
            "p99/rl",
            "p50/row",
            "own p50/p99"
        );
        for (i, row) in self.rows.iter().enumerate() {
            if row.method == method {
                self.print_row(i);
            }
        }
    }

    fn print_row(&self, i: usize) {
        let (row, results, best) = (&self.rows[i], self.results, self.best);
        let Some(round) = best[i] else {
            println!("{:<36} {}", row.label, row.skip.unwrap_or("not run"));
            return;
        };
        let m = &results[i][round];
        let (rp50, rp99, rmax) = m.relay();
        println!(
            "{:<36} {:>5} {rp50:>8.1} {rp99:>8.1} {rmax:>8.1}",
            match row.relay_priority {
                Some(p) => format!("bare relay, SCHED_FIFO {p} ({})", round + 1),
                None => format!("bare relay ({})", round + 1),
            },
            m.relay.len()
        );
        for (k, s) in m.samples.iter().enumerate() {
            let d = totals(s);
            let (p50, p99, max) = figures(&d);
            let label = if k == 0 {
                format!("{} ({})", row.label, round + 1)
            } else {
                format!("  … last device ({})", round + 1)
            };
            let against = match (k, row.against.and_then(|j| Some((j, best[j]?)))) {
                // Raw, and with each window's relay taken out (the machine's load
                // moves both figures of a window together).
                (0, Some((j, r))) => {
                    let base = &results[j][r];
                    format!(
                        "{:.2}× ({:.2}×)",
                        p50 / base.first().0,
                        (p50 / rp50) / (base.first().0 / base.relay().0)
                    )
                }
                (1, _) => format!("{:.2}×", p50 / m.first().0),
                _ => String::new(),
            };
            let own = if k == 0 {
                format!("{:.1} / {:.1}", m.own.0, m.own.1)
            } else {
                String::new()
            };
            println!(
                "{label:<36} {:>5} {p50:>8.1} {p99:>8.1} {max:>8.1} {:>6.2}× {:>6.2}× {against:>15}  {own:>13}",
                d.len(),
                p50 / rp50,
                p99 / rp99,
            );
        }
    }
}

/// The network's checks and the one intake for `steer v` (ports closed, so the command
/// ends in its slot), timed in this process: hot, datagram after datagram, and cold,
/// one every 10 ms as a planner at 100 Hz sends them — what the steps cost when their
/// code and data are in the caches, and when they were evicted meanwhile. p50 ns each.
fn intake_hot_and_cold() -> (u64, u64) {
    use adrive::config::VehicleConfig;
    use adrive::engine::Gate;
    use adrive::net::intake::Intake;
    use adrive::net::NetStatus;
    use std::sync::atomic::AtomicBool;
    use std::time::Instant;

    let config = VehicleConfig::alice();
    let network = config.network.clone();
    // Every device has "reported": the vehicle may engage (no engine runs here).
    let vehicle = Arc::new(adrive::testkit::vehicle_zeroed(config));
    let gate = Arc::new(Gate::new(vehicle.clone()));
    let status = Arc::new(NetStatus::of(
        &vehicle,
        network.listen,
        network.watchdog_timeout,
    ));
    let mut intake = Intake::new(
        gate,
        network,
        None,
        status,
        Arc::new(AtomicBool::new(false)),
    );
    let from = "127.0.0.1:40000".parse().unwrap();
    let _ = intake.handle(b"engage\n", from, Instant::now());
    let mut time = |n: u64, gap: Duration| {
        let mut d: Vec<u64> = (0..n)
            .map(|k| {
                std::thread::sleep(gap);
                let text = format!("steer {}\n", value(k));
                let t = Instant::now();
                let _ = intake.handle(text.as_bytes(), from, t);
                t.elapsed().as_nanos() as u64
            })
            .collect();
        d.sort_unstable();
        d[d.len() / 2]
    };
    (
        time(2000, Duration::ZERO),
        time(200, Duration::from_millis(10)),
    )
}
