//! Section 11: the command path seen from outside, as a user measures it — a planner's
//! `sendto` → the command's first byte readable at the device's end of its port — beside
//! the least any program can do, a bare relay (one thread, `recv` → write) onto the
//! same kind of pseudo-terminal, in the same run.
//!
//! The measured device (`steer`, the line protocol) is a pseudo-terminal whose master
//! this process holds: it answers `?` with the last commanded position and `! v` with
//! `ok`, and takes the time each `! v` line's first byte is read. Every datagram carries
//! a distinct value, matched to the first line that carries it.

use super::common::pty::openpty;
use super::floor::quantile;
use super::rig::{Adrive, Sim};
use super::{idle_actuator, vehicle};
use std::collections::HashMap;
use std::fs::File;
use std::io::{Read, Write};
use std::net::UdpSocket;
use std::os::fd::{AsRawFd, OwnedFd};
use std::path::Path;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

/// Datagrams a row sends, at [`RATE`].
const SENT: u64 = 1600;
const RATE: f64 = 100.0;

/// The device's end of a pseudo-terminal: every `! v` line's first byte, timed.
struct DeviceEnd {
    path: String,
    /// Value text → when its line's first byte was read.
    seen: Arc<Mutex<HashMap<String, Instant>>>,
    _slave: OwnedFd,
}

impl DeviceEnd {
    /// `answer`: reply to the host (adrive) as the device; a relay gets no replies.
    #[allow(unsafe_code)]
    fn open(answer: bool) -> DeviceEnd {
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
        let mut m = File::from(master);
        std::thread::Builder::new()
            .name("device-end".into())
            .spawn(move || {
                let mut w = m.try_clone().unwrap();
                let (mut line, mut started) = (Vec::new(), None::<Instant>);
                let mut pos = String::from("0.000");
                let mut chunk = [0u8; 256];
                while let Ok(n) = m.read(&mut chunk) {
                    if n == 0 {
                        return;
                    }
                    let at = Instant::now();
                    for &b in &chunk[..n] {
                        if line.is_empty() {
                            started = Some(at);
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
                            s.lock()
                                .unwrap()
                                .entry(v.to_string())
                                .or_insert(started.unwrap());
                            pos = v.to_string();
                            if answer {
                                let _ = w.write_all(b"ok\n");
                            }
                        } else if text == "?" && answer {
                            let _ = w.write_all(format!("= pos={pos}\n").as_bytes());
                        }
                    }
                }
            })
            .unwrap();
        DeviceEnd {
            path,
            seen,
            _slave: slave,
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

/// The value of datagram `i`, as adrive writes it (three decimals), distinct over a row.
fn value(i: u64) -> String {
    format!("{:.3}", (i % 1000) as f64 / 1000.0 - 0.5)
}

/// Send [`SENT`] datagrams at [`RATE`] with `send`, timing each `sendto`; then the
/// delays to the first byte at `end`, sorted.
fn measure(end: &DeviceEnd, mut send: impl FnMut(&str)) -> Vec<Duration> {
    super::precise_timers();
    let step = Duration::from_secs_f64(1.0 / RATE);
    let mut sent: Vec<(String, Instant)> = Vec::with_capacity(SENT as usize);
    let start = Instant::now();
    for i in 0..SENT {
        let next = start + step * i as u32;
        if let Some(d) = next.checked_duration_since(Instant::now()) {
            std::thread::sleep(d);
        }
        let v = value(i);
        let text = format!("steer {v}\n");
        let t0 = Instant::now();
        send(&text);
        sent.push((v, t0));
        // A value comes again after 1000 datagrams: match the earlier one first.
        if i % 1000 == 999 {
            std::thread::sleep(Duration::from_millis(50));
        }
    }
    std::thread::sleep(Duration::from_millis(200));
    let seen = end.seen.lock().unwrap();
    let mut d: Vec<Duration> = sent
        .iter()
        .filter_map(|(v, t0)| seen.get(v).map(|t| t.saturating_duration_since(*t0)))
        .collect();
    d.sort();
    d
}

/// p50, p99, max µs.
fn figures(d: &[Duration]) -> (f64, f64, f64) {
    let max = d.last().map_or(f64::NAN, |x| x.as_secs_f64() * 1e6);
    (quantile(d, 0.5), quantile(d, 0.99), max)
}

/// A bare relay: one thread, `recv` → write `! v\n` to its port.
fn relay() -> Vec<Duration> {
    let end = DeviceEnd::open(false);
    let rx = UdpSocket::bind("127.0.0.1:0").unwrap();
    let to = rx.local_addr().unwrap();
    let mut port = std::fs::OpenOptions::new()
        .read(true)
        .write(true)
        .open(&end.path)
        .unwrap();
    std::thread::Builder::new()
        .name("relay".into())
        .spawn(move || {
            let mut buf = [0u8; 256];
            let mut out = Vec::with_capacity(64);
            while let Ok(n) = rx.recv(&mut buf) {
                if n == 1 {
                    return;
                }
                let text = &buf[..n];
                let v = text.strip_prefix(b"steer ").unwrap_or(text);
                out.clear();
                out.extend_from_slice(b"! ");
                out.extend_from_slice(v);
                let _ = port.write_all(&out);
            }
        })
        .unwrap();
    let tx = UdpSocket::bind("127.0.0.1:0").unwrap();
    tx.connect(to).unwrap();
    let d = measure(&end, |t| {
        let _ = tx.send(t.as_bytes());
    });
    let _ = tx.send(b"x");
    d
}

/// One row of adrive: `steer` on the measured pseudo-terminal, with `others` more
/// devices on `adrive sim`'s ports, and `args`; `consoles` attached. Its delays and its
/// own figure for the same commands (receipt → first byte p50, p99).
fn adrive_row(
    dir: &Path,
    sim: Option<&Sim>,
    others: &[String],
    args: &[&str],
    consoles: usize,
) -> (Vec<Duration>, (f64, f64)) {
    let end = DeviceEnd::open(true);
    let steer = format!(
        "[[device]]\nname = \"steer\"\nkind = \"setpoint\"\ndriver = \"line\"\nport = \"{}\"\nrange = [-1.0, 1.0]\nreadings = [\"position\"]\nstatus_period = \"50ms\"\n",
        end.path
    );
    let mut devices: Vec<String> = others.iter().map(|n| idle_actuator(n)).collect();
    devices.insert(0, steer.clone());
    let mut toml = vehicle("", &devices);
    if let Some(sim) = sim {
        // The simulator's ports for the others; the measured device keeps its own.
        let rest = vehicle("", &devices[1..]);
        toml = format!("{}\n{steer}", sim.patch(&rest));
    }
    let a = Adrive::start_with(dir, "outside", &toml, args);
    let _clients = super::attach_consoles(&a, consoles);
    let d = measure(&end, |t| a.send(t));
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
    (d, own)
}

pub fn section11_outside(dir: &tempfile::TempDir, _secs: f64) {
    println!(
        "\n== 11. From outside: a planner's sendto → the first byte at the device, beside a bare relay; {SENT} datagrams at {RATE} Hz per row =="
    );
    println!(
        "{:<34} {:>6} {:>8} {:>8} {:>8} {:>7} {:>7}   {:>14}",
        "row", "seen", "p50 µs", "p99 µs", "max µs", "p50/rl", "p99/rl", "own p50/p99 µs"
    );
    let others: Vec<String> = (0..9).map(|i| format!("a{i:02}")).collect();
    let sim_file = dir.path().join("outside-sim.toml");
    std::fs::write(
        &sim_file,
        vehicle(
            "",
            &others.iter().map(|n| idle_actuator(n)).collect::<Vec<_>>(),
        ),
    )
    .unwrap();
    let sim = Sim::start(&sim_file);
    let rec = dir.path().join("outside.mcap");
    let rec = rec.to_string_lossy();
    for round in 1..=2 {
        let r = relay();
        let (rp50, rp99, rmax) = figures(&r);
        println!(
            "{:<34} {:>6} {rp50:>8.1} {rp99:>8.1} {rmax:>8.1} {:>6.2}× {:>6.2}×",
            format!("bare relay #{round}"),
            r.len(),
            1.0,
            1.0
        );
        let rows: [(&str, bool, &[&str], usize); 4] = [
            ("adrive, one device (line)", false, &[], 0),
            ("adrive, + 9 devices polling", true, &[], 0),
            (
                "adrive, + 9 polling, recording",
                true,
                &["--record", &rec],
                0,
            ),
            ("adrive, + 9 polling, 1 console", true, &[], 1),
        ];
        for (label, polling, args, consoles) in rows {
            let o: &[String] = if polling { &others } else { &[] };
            let (d, own) = adrive_row(dir.path(), polling.then_some(&sim), o, args, consoles);
            let (p50, p99, max) = figures(&d);
            println!(
                "{:<34} {:>6} {p50:>8.1} {p99:>8.1} {max:>8.1} {:>6.2}× {:>6.2}×   {:>6.1} / {:<6.1}",
                format!("{label} #{round}"),
                d.len(),
                p50 / rp50,
                p99 / rp99,
                own.0,
                own.1
            );
        }
    }
    println!("(rl: the bare relay of the same round; own: adrive's displayed delay, receipt → first byte, for the same commands.)");
}
