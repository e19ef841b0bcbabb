//! The paper's results section, measured again: `cargo bench --bench paper` prints,
//! side by side with the figures of the 2005 paper, what adrive does on this machine —
//! adrive headless in one process, `adrive sim` in another, a planner sending UDP
//! datagrams — and writes Fig. 3 and Fig. 4 as SVG into `target/paper/`.
//!
//! Every delay is compared with the machine's floor, a bare condition-variable wake
//! measured in the same window ([`floor`]): these machines are shared and noisy, and
//! only figures from one run compare. See docs/performance.md.
//!
//! Sections: 0 the floor; 1 receipt → first byte on an idle port, under each thread
//! placement; 2 delay against the number of actuators (Fig. 3); 3 CPU against the
//! command rate (Fig. 4); 4 the cued-command stall under each port rule, with the
//! effective bandwidth; 5 the findings of the command-path review; 6 memory; 7 the
//! console's output to its terminal; 8 the command delay with recording off and on; 9
//! fixed against adaptive polling, the paper's open problem ([`estimator`]); 10 the
//! command delay and adrive's CPU with the Foxglove live view off, on with no viewer,
//! and with two viewers subscribed to everything ([`viewer`]); 11 the command path from
//! outside — a planner's `sendto` to the first byte at the device — beside a bare relay,
//! by two methods (the relay's datagrams interleaved with adrive's in the same window;
//! the relay in a window of its own after adrive's), row by row, with its steps and the
//! command path's placements ([`outside`]); 12 attached consoles;
//! 13 a CAN bus: 1 … 16 actuators on one SLCAN adapter ([`can`]); 14 a commanding
//! console whose terminal stalls: the stall → the safe state at the device, and what
//! the liveness check costs ([`liveness`]); 15 hold-to-drive teleop: a key's release,
//! or its repeats' end, → the throttle's 0 at the device ([`teleop`]); 16 (built with
//! `--features fleet`) a fleet of 1 … 32 vehicles through one Zenoh router: listing,
//! the cost of being in it, remote against local, cross-talk, the router restarted
//! (`fleet`).

mod can;
mod estimator;
#[cfg(feature = "fleet")]
mod fleet;
mod floor;
mod liveness;
mod outside;
mod plot;
mod rig;
mod teleop;
mod viewer;

use adrive::snapshot::{LatencySummary, Snapshot};
use floor::{quantile, Cpus, Floor, Then};
use rig::{Adrive, Sim};
use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::{Duration, Instant};

/// Seconds each measured window lasts (`ADRIVE_BENCH_SECS` to change).
fn secs() -> f64 {
    std::env::var("ADRIVE_BENCH_SECS")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(6.0)
}

/// Holds a row of section 15 measures (`ADRIVE_BENCH_HOLDS` to change).
fn holds() -> usize {
    std::env::var("ADRIVE_BENCH_HOLDS")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(1000)
}

/// A setpoint actuator on the line protocol at 115200 baud whose port is idle when a
/// command comes: its status polls run once a second and take ~2 ms.
fn idle_actuator(name: &str) -> String {
    format!(
        "[[device]]\nname = \"{name}\"\nkind = \"setpoint\"\nrange = [-1.0, 1.0]\ndriver = \"line\"\nbaud = 115200\nstatus_period = \"1s\"\nstatus_max_age = \"2s\"\ncommand_timeout = \"1s\"\nreply_timeout = \"100ms\"\n[device.sim]\nturnaround = \"1ms\"\n"
    )
}

fn vehicle(head: &str, devices: &[String]) -> String {
    let mut t = format!("[vehicle]\nname = \"bench\"\n{head}\n");
    for d in devices {
        t.push_str(d);
    }
    t
}

/// Set the planner's thread to wake within a microsecond of when asked.
#[allow(unsafe_code)]
fn precise_timers() {
    // SAFETY: PR_SET_TIMERSLACK takes nanoseconds and touches nothing else.
    unsafe { libc::prctl(libc::PR_SET_TIMERSLACK, 1000) };
}

/// Send each device `hz` commands a second for `secs`, one datagram per command, the
/// devices' streams spread evenly over the period (independent controllers).
fn drive(a: &Adrive, names: &[String], hz: f64, secs: f64) {
    precise_timers();
    let step = Duration::from_secs_f64(1.0 / hz / names.len() as f64);
    let start = Instant::now();
    let mut next = start;
    let mut text = String::with_capacity(64);
    let mut i = 0u64;
    while start.elapsed().as_secs_f64() < secs {
        if let Some(d) = next.checked_duration_since(Instant::now()) {
            std::thread::sleep(d);
        }
        let name = &names[i as usize % names.len()];
        let v = ((i / names.len() as u64) % 50) as f64 / 100.0;
        text.clear();
        let _ = writeln!(text, "{name} {v:.2}");
        a.send(&text);
        i += 1;
        next += step;
    }
}

/// Delay figures over several devices: every command's mean, the median device's
/// p50, the worst device's p99.
#[derive(Clone, Copy, Default)]
struct Delay {
    count: u64,
    mean: f64,
    p50: f64,
    p99: f64,
}

fn delay_of(snap: &Snapshot, names: &[String]) -> Delay {
    let s: Vec<&LatencySummary> = names
        .iter()
        .filter_map(|n| snap.device(n).map(|d| &d.delay_us))
        .collect();
    let count: u64 = s.iter().map(|x| x.count).sum();
    let mean = s
        .iter()
        .map(|x| x.mean_us.unwrap_or(0.0) * x.count as f64)
        .sum::<f64>()
        / count.max(1) as f64;
    let mut p50: Vec<f64> = s.iter().filter_map(|x| x.p50_us).collect();
    p50.sort_by(f64::total_cmp);
    let p99 = s.iter().filter_map(|x| x.p99_us).fold(0.0, f64::max);
    Delay {
        count,
        mean,
        p50: p50.get(p50.len() / 2).copied().unwrap_or(f64::NAN),
        p99,
    }
}

/// The machine's floors in one window, p50 µs: a bare wake, and a wake followed by a
/// pty write (the least any command path can do: hand over to a thread, then to a port).
#[derive(Clone, Copy)]
struct Floors {
    wake: f64,
    write: f64,
}

/// The columns of a delay table whose first column, `first`, is `width` wide.
fn delay_columns(first: &str, width: usize) -> String {
    format!(
        "{first:<width$} {:>6} {:>8} {:>7} {:>8} {:>6} {:>6} {:>8} {:>8}",
        "sent", "mean µs", "p50 µs", "p99 µs", "wake", "+write", "p50/wake", "p50/+wr"
    )
}

/// One row of a delay table ([`delay_columns`]).
fn delay_row(label: &str, width: usize, d: &Delay, floor: Floors) -> String {
    format!(
        "{label:<width$} {:>6} {:>8.1} {:>7.1} {:>8.1} {:>6.1} {:>6.1} {:>7.2}× {:>7.2}×",
        d.count,
        d.mean,
        d.p50,
        d.p99,
        floor.wake,
        floor.write,
        d.p50 / floor.wake,
        d.p50 / floor.write
    )
}

/// The floors measured while `f` runs.
fn with_floor<T>(f: impl FnOnce() -> T) -> (T, Floors) {
    let wake = Floor::start(100.0, Cpus::Any);
    let write = Floor::start_then(100.0, Cpus::Any, Then::Write);
    let r = f();
    let p50 = |f: Floor| quantile(&f.finish(), 0.5);
    (
        r,
        Floors {
            wake: p50(wake),
            write: p50(write),
        },
    )
}

fn target_dir() -> PathBuf {
    std::env::var_os("CARGO_TARGET_DIR")
        .map(PathBuf::from)
        .unwrap_or_else(|| Path::new(env!("CARGO_MANIFEST_DIR")).join("target"))
        .join("paper")
}

fn load() -> String {
    std::fs::read_to_string("/proc/loadavg")
        .map(|s| s.split_whitespace().take(3).collect::<Vec<_>>().join(" "))
        .unwrap_or_default()
}

/// What the final table says, gathered along the way.
#[derive(Default)]
struct Results {
    idle: Option<(Delay, Floors)>,
    fig3: Vec<(usize, Delay, Floors)>,
    fig4: Vec<(f64, f64, f64)>,
    fig4_floor: Option<f64>,
    cued: Vec<(String, LatencySummary, f64, f64)>,
    rss_headless: u64,
    rss_console: u64,
    /// The console's output, bytes a second: idle, and with steering moving.
    console_output: Option<(f64, f64)>,
}

/// Run as the memory floor instead ([`section6_memory`]): a Rust program with twenty
/// sleeping threads and nothing else.
const IDLE: &str = "ADRIVE_BENCH_IDLE_THREADS";

fn main() {
    if let Ok(port) = std::env::var(outside::RELAY) {
        outside::relay_process(&port);
        return;
    }
    if std::env::var_os(IDLE).is_some() {
        let idle =
            (0..20).map(|_| std::thread::spawn(|| std::thread::sleep(Duration::from_millis(200))));
        idle.collect::<Vec<_>>()
            .into_iter()
            .for_each(|t| t.join().unwrap());
        return;
    }
    let secs = secs();
    let dir = common::tempdir("bench");
    let out = target_dir();
    std::fs::create_dir_all(&out).unwrap();
    let mut r = Results::default();
    println!(
        "adrive: the paper's results, measured on this machine ({} CPUs, load {}), {secs} s windows",
        std::thread::available_parallelism().map_or(0, |n| n.get()),
        load()
    );

    // `ADRIVE_BENCH_ONLY=3` (or `1,3`) runs just those sections, while working on one.
    let only = std::env::var("ADRIVE_BENCH_ONLY").unwrap_or_default();
    let on = |n: &str| only.is_empty() || only.split(',').any(|x| x.trim() == n);
    if on("0") {
        section0_floor();
    }
    if on("1") {
        section1_idle_port(&dir, secs, &mut r);
    }
    if on("2") {
        section2_fig3(&dir, secs, &out, &mut r);
    }
    if on("3") {
        section3_fig4(&dir, secs, &out, &mut r);
    }
    if on("4") {
        section4_cued(&dir, secs, &mut r);
    }
    if on("5") {
        section5_findings(&dir, secs);
    }
    if on("6") {
        section6_memory(&dir, &mut r);
    }
    if on("7") {
        section7_console_output(&dir, secs, &mut r);
    }
    if on("8") {
        section8_recording(&dir, secs);
    }
    if on("9") {
        for rule in ["priority", "paper"] {
            estimator::section9_estimator(rule, 20.0);
        }
    }
    if on("10") {
        section10_foxglove(&dir, secs);
    }
    if on("11") {
        outside::section11_outside(&dir, secs);
    }
    if on("12") {
        section12_consoles(&dir, secs);
    }
    if on("13") {
        can::section13_can(&dir, secs);
    }
    if on("14") {
        liveness::section14_terminal_stall(&dir, 100, secs);
    }
    if on("15") {
        teleop::section15_teleop(&dir, holds());
    }
    #[cfg(feature = "fleet")]
    if on("16") {
        fleet::section16_fleet(secs);
    }
    summary(&r, &out);
}

/// `n` consoles attached to `a` over its control socket: clients that say hello as
/// `adrive attach` does and read every frame (counted).
fn attach_consoles(
    a: &Adrive,
    n: usize,
) -> (
    Vec<std::os::unix::net::UnixStream>,
    std::sync::Arc<std::sync::atomic::AtomicU64>,
) {
    use adrive::socket::proto::{Op, Request, Role, VERSION};
    use std::io::{BufRead, Write};
    let frames = std::sync::Arc::new(std::sync::atomic::AtomicU64::new(0));
    let clients = (0..n)
        .map(|_| {
            let mut s =
                std::os::unix::net::UnixStream::connect(&a.socket).expect("the control socket");
            let hello = Request {
                id: 0,
                op: Op::Hello {
                    role: Role::Console,
                    version: VERSION,
                },
            };
            let mut line = serde_json::to_vec(&hello).unwrap();
            line.push(b'\n');
            s.write_all(&line).unwrap();
            let (r, count) = (s.try_clone().unwrap(), frames.clone());
            std::thread::spawn(move || {
                for l in std::io::BufReader::new(r).lines() {
                    match l {
                        Ok(l) if l.starts_with("{\"kind\":\"frame\"") => {
                            count.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
                        }
                        Ok(_) => {}
                        Err(_) => return,
                    }
                }
            });
            s
        })
        .collect();
    (clients, frames)
}

/// Three actuators at 100 Hz each with 0, 1 and 4 consoles attached over the control
/// socket, in turns: receipt → first byte and adrive's CPU. A console here is a client
/// that says hello as `adrive attach` does and reads every frame, so the cost measured is
/// the engine's (capturing, encoding and writing frames), not a terminal's.
fn section12_consoles(dir: &tempfile::TempDir, secs: f64) {
    println!(
        "\n== 12. Consoles attached over the control socket, in turns: 3 actuators, 100 Hz each, {secs} s =="
    );
    println!(
        "{}  cpu % of a core  frames read",
        delay_columns("consoles", 10)
    );
    let names: Vec<String> = (0..3).map(|i| format!("a{i:02}")).collect();
    let devices: Vec<String> = names.iter().map(|x| idle_actuator(x)).collect();
    let sim_file = dir.path().join("con-sim.toml");
    std::fs::write(&sim_file, vehicle("", &devices)).unwrap();
    let sim = Sim::start(&sim_file);
    let toml = sim.patch(&vehicle("", &devices));
    let mut base = Vec::new();
    for turn in 1..=2 {
        for consoles in [0usize, 1, 4] {
            let a = Adrive::start(dir.path(), "con", &toml);
            let (clients, frames) = attach_consoles(&a, consoles);
            let cpu0 = rig::cpu_time(a.pid());
            let t0 = Instant::now();
            let (_, floor) = with_floor(|| drive(&a, &names, 100.0, secs));
            let cpu = (rig::cpu_time(a.pid()) - cpu0).as_secs_f64() / t0.elapsed().as_secs_f64();
            let d = delay_of(&a.snapshot(), &names);
            let read = frames.load(std::sync::atomic::Ordering::Relaxed);
            drop(clients);
            if consoles == 0 {
                base.push(cpu);
            }
            let per = match consoles {
                0 => String::new(),
                n => format!(
                    " ({:+.2} per console)",
                    (cpu - base[turn - 1]) * 100.0 / n as f64
                ),
            };
            println!(
                "{}  {:>6.2}{per}  {read}",
                delay_row(&format!("{consoles} #{turn}"), 10, &d, floor),
                cpu * 100.0
            );
        }
    }
    println!("(p50: the median device's; p99: the worst device's; cpu: adrive's, all threads.)");
}

/// Three actuators at 100 Hz each, recording (raw traffic included) off and on in
/// turns, each run alike: recording must cost the command path nothing measurable.
fn section8_recording(dir: &tempfile::TempDir, secs: f64) {
    println!(
        "\n== 8. Recording off and on, in turns: 3 actuators, 100 Hz each, raw traffic recorded, {secs} s =="
    );
    println!("{}  recorded", delay_columns("recording", 10));
    let names: Vec<String> = (0..3).map(|i| format!("a{i:02}")).collect();
    let devices: Vec<String> = names.iter().map(|x| idle_actuator(x)).collect();
    let sim_file = dir.path().join("rec-sim.toml");
    std::fs::write(&sim_file, vehicle("", &devices)).unwrap();
    let sim = Sim::start(&sim_file);
    let toml = sim.patch(&vehicle("", &devices));
    for turn in 1..=2 {
        for on in [false, true] {
            let file = dir.path().join(format!("rec-{turn}.mcap"));
            let file = file.to_string_lossy();
            let args: &[&str] = if on {
                &["--record", &file, "--record-raw"]
            } else {
                &[]
            };
            let a = Adrive::start_with(dir.path(), "rec", &toml, args);
            let (_, floor) = with_floor(|| drive(&a, &names, 100.0, secs));
            let snap = a.snapshot();
            let d = delay_of(&snap, &names);
            let recorded = snap.record.map_or(String::new(), |r| {
                format!(
                    "{} messages, {} kB, {} left out",
                    r.messages,
                    r.bytes / 1000,
                    r.dropped
                )
            });
            let label = format!("{} {turn}", if on { "on" } else { "off" });
            println!("{}  {recorded}", delay_row(&label, 10, &d, floor));
        }
    }
    println!("(p50: the median device's; p99: the worst device's; mean: over every command.)");
}

/// Three actuators at 100 Hz each, the live view off, on with no viewer, and on with
/// two viewers subscribed to every channel, in turns: a viewer must cost the command
/// path nothing measurable. CPU: adrive's, all threads, over the window.
fn section10_foxglove(dir: &tempfile::TempDir, secs: f64) {
    println!(
        "\n== 10. The Foxglove live view: 3 actuators, 100 Hz each, off / no viewer / two viewers on every channel, {secs} s =="
    );
    println!(
        "{}  adrive CPU  viewers received",
        delay_columns("live view", 12)
    );
    let names: Vec<String> = (0..3).map(|i| format!("a{i:02}")).collect();
    let devices: Vec<String> = names.iter().map(|x| idle_actuator(x)).collect();
    let sim_file = dir.path().join("fox-sim.toml");
    std::fs::write(&sim_file, vehicle("", &devices)).unwrap();
    let sim = Sim::start(&sim_file);
    let toml = sim.patch(&vehicle("", &devices));
    for turn in 1..=2 {
        for viewers in [None, Some(0), Some(2)] {
            let port = viewer::free_tcp_port();
            let addr = format!("127.0.0.1:{port}");
            let args: &[&str] = match viewers {
                None => &[],
                Some(_) => &["--foxglove", &addr],
            };
            let a = Adrive::start_with(dir.path(), "fox", &toml, args);
            let watching: Vec<viewer::Viewer> = (0..viewers.unwrap_or(0))
                .map(|_| viewer::Viewer::start(addr.parse().unwrap()))
                .collect();
            let cpu0 = rig::cpu_time(a.pid());
            let t0 = Instant::now();
            let (_, floor) = with_floor(|| drive(&a, &names, 100.0, secs));
            let cpu = (rig::cpu_time(a.pid()) - cpu0).as_secs_f64() / t0.elapsed().as_secs_f64();
            let snap = a.snapshot();
            let d = delay_of(&snap, &names);
            let received: Vec<String> =
                watching.into_iter().map(|v| v.stop().to_string()).collect();
            let dropped = snap
                .net
                .as_ref()
                .and_then(|n| n.foxglove.as_ref())
                .map_or(0, |f| f.dropped + f.tap_dropped);
            let label = match viewers {
                None => format!("off {turn}"),
                Some(0) => format!("no viewer {turn}"),
                Some(n) => format!("{n} viewers {turn}"),
            };
            println!(
                "{}  {:>9.1}%  {}{}",
                delay_row(&label, 12, &d, floor),
                cpu * 100.0,
                if received.is_empty() {
                    "-".into()
                } else {
                    received.join(" + ")
                },
                if dropped > 0 {
                    format!(" ({dropped} dropped)")
                } else {
                    String::new()
                }
            );
        }
    }
    println!("(p50: the median device's; p99: the worst device's; CPU: adrive's, every thread, % of one core.)");
}

fn section0_floor() {
    println!("\n== 0. The floor: a bare parking_lot condition-variable wake, 100 Hz, 3 s ==");
    println!("{:<28} {:>9} {:>9}", "threads", "p50 µs", "p99 µs");
    for (label, cpus, then) in [
        ("anywhere (the kernel's)", Cpus::Any, Then::Stamp),
        ("both on one CPU", Cpus::Same, Then::Stamp),
        ("on two CPUs", Cpus::Apart, Then::Stamp),
        ("… then an 8-byte pty write", Cpus::Any, Then::Write),
        ("… the same on one CPU", Cpus::Same, Then::Write),
        ("… to the bytes read", Cpus::Any, Then::Deliver),
    ] {
        let f = Floor::start_then(100.0, cpus, then);
        std::thread::sleep(Duration::from_secs(3));
        let v = f.finish();
        println!(
            "{label:<28} {:>9.1} {:>9.1}",
            quantile(&v, 0.5),
            quantile(&v, 0.99)
        );
    }
    println!("(the write stamped once the kernel has taken it, as adrive stamps its first byte; \"to the bytes read\": stamped when a thread reading the terminal's other end has them)");
}

fn section1_idle_port(dir: &tempfile::TempDir, secs: f64, r: &mut Results) {
    println!(
        "\n== 1. Receipt → first byte, one actuator, idle port, planner at 100 Hz, {secs} s (the paper: 25.9 µs average) =="
    );
    println!("{}", delay_columns("where the command path runs", 36));
    let names = vec!["steer".to_string()];
    let sim_file = dir.path().join("idle-sim.toml");
    std::fs::write(&sim_file, vehicle("", &[idle_actuator("steer")])).unwrap();
    let sim = Sim::start(&sim_file);
    for (label, head) in [
        ("default: anywhere, normal priority", ""),
        ("cpus = [1]", "cpus = [1]"),
        ("realtime_priority = 50", "realtime_priority = 50"),
        (
            "cpus = [1], realtime_priority = 50",
            "cpus = [1]\nrealtime_priority = 50",
        ),
    ] {
        let a = Adrive::start(
            dir.path(),
            "idle",
            &sim.patch(&vehicle(head, &[idle_actuator("steer")])),
        );
        let (_, floor) = with_floor(|| drive(&a, &names, 100.0, secs));
        let d = delay_of(&a.snapshot(), &names);
        println!("{}", delay_row(label, 36, &d, floor));
        if head.is_empty() {
            r.idle = Some((d, floor));
        }
    }
    println!("(wake, +write: the floors' p50 µs in the same window, a bare condition-variable wake and one followed by an 8-byte pty write; p50 and p99 from adrive's histograms: a bucket's upper edge, within 1.6 %.)");
}

fn section2_fig3(dir: &tempfile::TempDir, secs: f64, out: &Path, r: &mut Results) {
    println!(
        "\n== 2. Fig. 3: receipt → first byte against the number of actuators, 100 Hz each, {secs} s =="
    );
    println!("{} {:>8}", delay_columns("actuators", 10), "p50/p50₁");
    let mut one = f64::NAN;
    for n in [1usize, 2, 4, 8, 16, 32, 64] {
        let names: Vec<String> = (0..n).map(|i| format!("a{i:02}")).collect();
        let devices: Vec<String> = names.iter().map(|x| idle_actuator(x)).collect();
        let sim_file = dir.path().join(format!("fig3-{n}.toml"));
        std::fs::write(&sim_file, vehicle("", &devices)).unwrap();
        let sim = Sim::start(&sim_file);
        let a = Adrive::start(dir.path(), "fig3", &sim.patch(&vehicle("", &devices)));
        let (_, floor) = with_floor(|| drive(&a, &names, 100.0, secs));
        let d = delay_of(&a.snapshot(), &names);
        if n == 1 {
            one = d.p50;
        }
        println!(
            "{} {:>7.2}×",
            delay_row(&n.to_string(), 10, &d, floor),
            d.p50 / one
        );
        r.fig3.push((n, d, floor));
    }
    println!("(p50: the median device's; p99: the worst device's; mean: over every command.)");
    type Of = fn(&(usize, Delay, Floors)) -> f64;
    let pts = |f: Of| -> Vec<(f64, f64)> { r.fig3.iter().map(|x| (x.0 as f64, f(x))).collect() };
    let path = out.join("fig3.svg");
    let lines: [(&str, (u8, u8, u8), Of); 5] = [
        ("adrive p50", (31, 119, 180), |x| x.1.p50),
        ("adrive mean", (44, 160, 44), |x| x.1.mean),
        ("adrive p99", (255, 127, 14), |x| x.1.p99),
        ("floor: condvar wake p50", (120, 120, 120), |x| x.2.wake),
        ("floor: wake + pty write p50", (148, 103, 189), |x| {
            x.2.write
        }),
    ];
    let series: Vec<plot::Series> = lines
        .iter()
        .map(|&(name, (red, green, blue), of)| plot::Series {
            name,
            color: plotters::style::RGBColor(red, green, blue),
            points: pts(of),
        })
        .collect();
    plot::save(
        &path,
        "Fig. 3: receipt → first byte (100 Hz per actuator)",
        ("actuators", "µs"),
        0.8..80.0,
        true,
        &series,
    );
}

/// Alice on the simulator, brought into drive with the brake on, ready for a planner.
fn alice_in_drive(dir: &tempfile::TempDir, sim: &Sim, name: &str) -> Adrive {
    let a = Adrive::start(dir.path(), name, &sim.patch(adrive::config::ALICE_TOML));
    a.send("engage\naccel -1\n");
    a.until("the brake applied", |s| {
        s.device("brake")
            .and_then(|d| d.position())
            .is_some_and(|p| p > 0.5)
    });
    a.send("engage\naccel -1\ntrans drive\n");
    a.until("drive", |s| {
        s.device("trans")
            .and_then(|d| d.readings.get("state").cloned().flatten())
            == Some(adrive::value::Value::Text("drive".into()))
    });
    a
}

fn section3_fig4(dir: &tempfile::TempDir, secs: f64, out: &Path, r: &mut Results) {
    println!(
        "\n== 3. Fig. 4: adrive's CPU against the command rate (Alice: steer, gas, brake, trans; `adrive send --rate`), {secs} s =="
    );
    println!(
        "{:<12} {:>10} {:>10} {:>12} {:>10} {:>9} {:>10}",
        "asked /s", "got /s", "CPU %", "µs/datagram", "rejected", "sim CPU %", "steer p50"
    );
    let alice = dir.path().join("alice.toml");
    std::fs::write(&alice, adrive::config::ALICE_TOML).unwrap();
    let body = ["engage", "steer 0.1", "accel -0.4", "trans drive"];
    let mut idle_cpu = 0.0;
    for rate in [0.0, 10.0, 100.0, 1000.0, 2000.0, 5000.0, 10000.0] {
        let sim = Sim::start(&alice);
        let a = alice_in_drive(dir, &sim, "fig4");
        let before = a.snapshot();
        let threads0 = rig::cpu_by_thread(a.pid());
        let (c0, s0, t0) = (
            rig::cpu_time(a.pid()),
            rig::cpu_time(sim.pid()),
            Instant::now(),
        );
        if rate == 0.0 {
            std::thread::sleep(Duration::from_secs_f64(secs));
        } else {
            let n = (rate * secs) as u64;
            rig::send_at(a.listen, rate, n, &body);
        }
        let wall = t0.elapsed().as_secs_f64();
        let cpu = (rig::cpu_time(a.pid()) - c0).as_secs_f64() / wall * 100.0;
        let sim_cpu = (rig::cpu_time(sim.pid()) - s0).as_secs_f64() / wall * 100.0;
        let after = a.snapshot();
        let datagrams = |s: &Snapshot| s.net.as_ref().map_or(0, |n| n.datagrams);
        let rejected = |s: &Snapshot| s.rejections.iter().map(|(_, n)| *n).sum::<u64>();
        let got = (datagrams(&after) - datagrams(&before)) as f64 / wall;
        if rate == 0.0 {
            idle_cpu = cpu;
        }
        let per = if got > 0.0 {
            (cpu - idle_cpu) / 100.0 / got * 1e6
        } else {
            f64::NAN
        };
        let p50 = after
            .device("steer")
            .and_then(|d| d.delay_us.p50_us)
            .unwrap_or(f64::NAN);
        println!(
            "{:<12} {:>10.0} {:>10.2} {:>12.1} {:>10} {:>9.2} {:>10.1}",
            rate,
            got,
            cpu,
            per,
            rejected(&after) - rejected(&before),
            sim_cpu,
            p50
        );
        r.fig4.push((rate, got, cpu));
        let why: Vec<String> = after
            .rejections
            .iter()
            .filter_map(|(reason, n)| {
                let n0 = before
                    .rejections
                    .iter()
                    .find(|x| x.0 == reason)
                    .map_or(0, |x| *x.1);
                (*n > n0).then(|| format!("{reason} {}", n - n0))
            })
            .collect();
        if !why.is_empty() {
            println!("             rejected: {}", why.join(", "));
        }
        if rate == 10000.0 || rate == 0.0 {
            let mut by: Vec<(String, f64)> = rig::cpu_by_thread(a.pid())
                .into_iter()
                .map(|(n, d)| {
                    let d0 = threads0
                        .iter()
                        .find(|x| x.0 == n)
                        .map_or(Duration::ZERO, |x| x.1);
                    (n, (d.saturating_sub(d0)).as_secs_f64() / wall * 100.0)
                })
                .filter(|x| x.1 >= 0.05)
                .collect();
            by.sort_by(|a, b| b.1.total_cmp(&a.1));
            let words: Vec<String> = by.iter().map(|(n, c)| format!("{n} {c:.2}")).collect();
            println!("             by thread, %: {}", words.join(", "));
        }
    }
    let (got, cpu) = bare_receiver(10000.0, secs);
    println!(
        "{:<12} {:>10.0} {:>10.2} {:>12.1}   the floor: a bare UDP receiver thread, one recv per datagram and nothing else",
        10000, got, cpu, cpu / 100.0 / got.max(1.0) * 1e6
    );
    r.fig4_floor = Some(cpu);
    println!("(CPU of the adrive process alone, all threads; µs/datagram above idle. The simulator and the sender run in their own processes.)");
    let path = out.join("fig4.svg");
    let series = [plot::Series {
        name: "adrive CPU, % of one core",
        color: plotters::style::RGBColor(31, 119, 180),
        points: r.fig4.iter().map(|x| (x.1.max(1.0), x.2)).collect(),
    }];
    plot::save(
        &path,
        "Fig. 4: CPU against the command rate (4 actuators)",
        ("datagrams per second (idle drawn at 1)", "% of one core"),
        0.8..15000.0,
        false,
        &series,
    );
}

/// The CPU floor of taking datagrams at all: a thread that only receives them (one
/// `recv` each, as adrive's listener does when they do not queue) at `rate` a second
/// from `adrive send`. Returns (datagrams a second, % of a core).
#[allow(unsafe_code)]
fn bare_receiver(rate: f64, secs: f64) -> (f64, f64) {
    let rx = std::net::UdpSocket::bind("127.0.0.1:0").unwrap();
    rx.set_read_timeout(Some(Duration::from_millis(300)))
        .unwrap();
    let to = rx.local_addr().unwrap();
    let counter = std::thread::spawn(move || {
        let thread_cpu = || {
            // SAFETY: an all-zero rusage is a valid out-parameter.
            let mut u: libc::rusage = unsafe { std::mem::zeroed() };
            // SAFETY: getrusage fills the struct we hand it.
            unsafe { libc::getrusage(libc::RUSAGE_THREAD, &mut u) };
            let t = |v: libc::timeval| Duration::new(v.tv_sec as u64, v.tv_usec as u32 * 1000);
            t(u.ru_utime) + t(u.ru_stime)
        };
        let mut buf = [0u8; 2048];
        let (mut got, mut start) = (0u64, None);
        let mut last = Instant::now();
        while rx.recv(&mut buf).is_ok() {
            got += 1;
            last = Instant::now();
            start.get_or_insert((last, thread_cpu()));
        }
        let (t0, c0) = start.unwrap_or((last, Duration::ZERO));
        let wall = last.duration_since(t0).as_secs_f64().max(1e-9);
        (
            got as f64 / wall,
            (thread_cpu() - c0).as_secs_f64() / wall * 100.0,
        )
    });
    rig::send_at(
        to,
        rate,
        (rate * secs) as u64,
        &["engage", "steer 0.1", "accel -0.4", "trans drive"],
    );
    counter.join().unwrap()
}

fn section4_cued(dir: &tempfile::TempDir, secs: f64, r: &mut Results) {
    println!(
        "\n== 4. The cued command (the paper: ~200 ms stalls, fixed by a 10 Hz cap): status polls of ~100 ms, commands of ~20 ms at 100 Hz, {secs} s =="
    );
    println!(
        "{:<28} {:>6} {:>8} {:>8} {:>8} {:>10} {:>10} {:>7}",
        "port rule", "sent", "p50 ms", "p99 ms", "max ms", "executed/s", "wire max/s", "share"
    );
    let names = vec!["steer".to_string()];
    for (label, extra) in [
        ("paper: plain lock", "port_rule = \"paper\""),
        (
            "paper + 10 Hz rate cap",
            "port_rule = \"paper\"\nmin_command_interval = \"100ms\"",
        ),
        ("adrive: priority (default)", "port_rule = \"priority\""),
    ] {
        let dev = format!(
            "[[device]]\nname = \"steer\"\nkind = \"setpoint\"\nrange = [-1.0, 1.0]\ndriver = \"line\"\nbaud = 38400\nstatus_period = \"100ms\"\nstatus_max_age = \"500ms\"\nreply_timeout = \"500ms\"\n{extra}\n[device.sim]\npoll_delay = \"95ms\"\ncommand_delay = \"20ms\"\n"
        );
        let sim_file = dir.path().join("cued.toml");
        std::fs::write(&sim_file, vehicle("", std::slice::from_ref(&dev))).unwrap();
        let sim = Sim::start(&sim_file);
        let a = Adrive::start(dir.path(), "cued", &sim.patch(&vehicle("", &[dev])));
        let before = a.snapshot();
        let t = Instant::now();
        drive(&a, &names, 100.0, secs);
        let wall = t.elapsed().as_secs_f64();
        let after = a.snapshot();
        let s = after.device("steer").unwrap();
        let executed =
            (s.counters.executed - before.device("steer").unwrap().counters.executed) as f64 / wall;
        let wire = 1e6 / s.command_txn_us.p50_us.unwrap_or(f64::NAN);
        let ms = |v: Option<f64>| v.map_or(f64::NAN, |x| x / 1000.0);
        println!(
            "{label:<28} {:>6} {:>8.2} {:>8.2} {:>8.2} {:>10.1} {:>10.1} {:>6.0}%",
            s.delay_us.count,
            ms(s.delay_us.p50_us),
            ms(s.delay_us.p99_us),
            ms(s.delay_us.max_us),
            executed,
            wire,
            executed / wire * 100.0
        );
        r.cued.push((label.to_string(), s.delay_us, executed, wire));
    }
    println!("(executed/s over wire max/s: fresh commands the device executed per second, over what its command transaction allows back to back.)");
}

fn section5_findings(dir: &tempfile::TempDir, secs: f64) {
    println!("\n== 5. Findings of the command-path review, each as a row ==");
    let alice = dir.path().join("alice.toml");
    std::fs::write(&alice, adrive::config::ALICE_TOML).unwrap();
    println!(
        "a) the brake behind a repeated `trans drive` (Alice in drive, 100 Hz, the brake alternating 0.6 / 0.1, {secs} s):"
    );
    println!(
        "   {:<36} {:>12} {:>10} {:>10}",
        "datagram", "brake exec/s", "p50 ms", "p99 ms"
    );
    for (label, extra) in [("accel", ""), ("accel + trans drive", "trans drive\n")] {
        let sim = Sim::start(&alice);
        let a = alice_in_drive(dir, &sim, "finding");
        let before = a.snapshot();
        let t = Instant::now();
        precise_timers();
        let mut i = 0u64;
        let mut next = Instant::now();
        while t.elapsed().as_secs_f64() < secs {
            let x = if i.is_multiple_of(2) { -0.6 } else { -0.1 };
            a.send(&format!("engage\naccel {x}\n{extra}"));
            i += 1;
            next += Duration::from_millis(10);
            if let Some(d) = next.checked_duration_since(Instant::now()) {
                std::thread::sleep(d);
            }
        }
        let wall = t.elapsed().as_secs_f64();
        let after = a.snapshot();
        let b = after.device("brake").unwrap();
        let exec =
            (b.counters.executed - before.device("brake").unwrap().counters.executed) as f64 / wall;
        println!(
            "   {label:<36} {:>12.1} {:>10.2} {:>10.2}",
            exec,
            b.delay_us.p50_us.unwrap_or(f64::NAN) / 1000.0,
            b.delay_us.p99_us.unwrap_or(f64::NAN) / 1000.0
        );
    }
    println!("   (before the fix: 38 vs 77 brake commands a second, p99 82.8 vs 21.6 ms)");

    let sim = Sim::start(&alice);
    let c0 = rig::cpu_time(sim.pid());
    let t = Instant::now();
    std::thread::sleep(Duration::from_secs(2));
    let cpu = (rig::cpu_time(sim.pid()) - c0).as_secs_f64() / t.elapsed().as_secs_f64() * 100.0;
    println!("b) `adrive sim --quiet`, idle: {cpu:.1} % of a core (before the fix: 100 %)");
    drop(sim);

    let rx = std::net::UdpSocket::bind("127.0.0.1:0").unwrap();
    rx.set_read_timeout(Some(Duration::from_millis(300)))
        .unwrap();
    let to = rx.local_addr().unwrap();
    let n = 20_000u64;
    let counter = std::thread::spawn(move || {
        let mut buf = [0u8; 2048];
        let (mut got, mut first, mut last) = (0u64, None, Instant::now());
        while rx.recv(&mut buf).is_ok() {
            got += 1;
            last = Instant::now();
            first.get_or_insert(last);
        }
        (
            got,
            first.map_or(0.0, |f| last.duration_since(f).as_secs_f64()),
        )
    });
    rig::send_at(to, 10000.0, n, &["steer 0.1"]);
    let (got, took) = counter.join().unwrap();
    println!(
        "c) `adrive send --rate 10000 --count {n}`: {got} datagrams at {:.0} a second (before the fix: ~250)",
        got as f64 / took.max(1e-9)
    );
    println!("d) this bench: Fig. 4 drives four actuators (Alice's steer, gas, brake, trans) and prints µs");
}

#[allow(unsafe_code)]
fn section6_memory(dir: &tempfile::TempDir, r: &mut Results) {
    println!("\n== 6. Memory: peak resident set (the paper: under 4 MB) ==");
    let me = std::env::current_exe().unwrap();
    println!(
        "the floor: a Rust program whose 20 threads sleep, peak {} kB; adrive printing its version, peak {} kB",
        rig::peak_kb_of(Command::new(me).env(IDLE, "1")),
        rig::peak_kb_of(Command::new(rig::adrive()).arg("--version"))
    );
    let alice = dir.path().join("alice.toml");
    std::fs::write(&alice, adrive::config::ALICE_TOML).unwrap();
    let sim = Sim::start(&alice);
    {
        let a = alice_in_drive(dir, &sim, "memory");
        rig::send_at(
            a.listen,
            1000.0,
            3000,
            &["engage", "steer 0.1", "accel -0.4", "trans drive"],
        );
        let _ = a.snapshot();
        let (bin, libs, anon) = rig::rss_parts(a.pid());
        r.rss_headless = rig::status_kb(a.pid(), "VmHWM:");
        println!(
            "headless, after 1000 datagrams/s: peak {} kB (now: binary {bin} kB, shared libraries {libs} kB, heap and stacks {anon} kB)",
            r.rss_headless
        );
    }
    let file = dir.path().join("console.toml");
    std::fs::write(&file, sim.patch(adrive::config::ALICE_TOML)).unwrap();
    let mut cmd = Command::new(rig::adrive());
    cmd.arg("--config")
        .arg(&file)
        .arg("--listen")
        .arg("127.0.0.1:0")
        .arg("--log-dir")
        .arg(dir.path().join("logs"))
        .env("XDG_RUNTIME_DIR", dir.path().join("logs"));
    let (mut child, master) = pty::Master::spawn(&mut cmd, 100, 36, true);
    std::thread::sleep(Duration::from_secs(3));
    let (bin, libs, anon) = rig::rss_parts(child.id());
    r.rss_console = rig::status_kb(child.id(), "VmHWM:");
    println!(
        "console (100×36 terminal), 3 s: peak {} kB (now: binary {bin} kB, shared libraries {libs} kB, heap and stacks {anon} kB)",
        r.rss_console
    );
    // SAFETY: kill(2) on our own child.
    unsafe { libc::kill(child.id() as i32, libc::SIGTERM) };
    let _ = child.wait();
    drop(master);
}

/// What the console costs a terminal (an SSH session over a slow link): bytes a second
/// it writes on a 100×30 terminal, idle, and with the steering moving at 10 Hz (a
/// planner alternating `steer 0.3` / `steer -0.3`).
#[allow(unsafe_code)]
fn section7_console_output(dir: &tempfile::TempDir, secs: f64, r: &mut Results) {
    println!(
        "\n== 7. The console's output on a 100×30 terminal (`adrive --sim`), {secs} s each =="
    );
    let port = rig::free_port();
    let mut cmd = Command::new(rig::adrive());
    cmd.arg("--sim")
        .args(["--listen", &format!("127.0.0.1:{port}")])
        .arg("--log-dir")
        .arg(dir.path().join("logs"))
        .env("XDG_RUNTIME_DIR", dir.path().join("logs"))
        .env("TERM", "xterm-256color")
        .env_remove("NO_COLOR");
    let (mut child, master) = pty::Master::spawn(&mut cmd, 100, 30, true);
    let planner = std::net::UdpSocket::bind("127.0.0.1:0").unwrap();
    planner.connect(("127.0.0.1", port)).unwrap();
    // Let the console settle: the first full frame, the devices' first reports.
    std::thread::sleep(Duration::from_secs(2));
    let window = Duration::from_secs_f64(secs);
    let n0 = master.bytes().len();
    std::thread::sleep(window);
    let idle = (master.bytes().len() - n0) as f64 / window.as_secs_f64();
    let n0 = master.bytes().len();
    let start = Instant::now();
    let mut i = 0u32;
    while start.elapsed() < window {
        let x = if i.is_multiple_of(2) { 0.3 } else { -0.3 };
        let _ = planner.send(format!("engage\nsteer {x}\n").as_bytes());
        i += 1;
        let next = start + Duration::from_millis(100) * i;
        std::thread::sleep(next.saturating_duration_since(Instant::now()));
    }
    let busy = (master.bytes().len() - n0) as f64 / start.elapsed().as_secs_f64();
    println!("idle: {idle:.0} B/s · steering at 10 Hz: {busy:.0} B/s");
    r.console_output = Some((idle, busy));
    // SAFETY: kill(2) on our own child.
    unsafe { libc::kill(child.id() as i32, libc::SIGTERM) };
    let _ = child.wait();
    drop(master);
}

#[path = "../../tests/common/mod.rs"]
mod common;
use common::pty;

fn summary(r: &Results, out: &Path) {
    println!("\n== The paper and adrive, side by side ==");
    println!(
        "{:<52} {:>16} {:>24}",
        "figure", "the paper (2005)", "adrive (this run)"
    );
    if let Some((d, floor)) = r.idle {
        println!(
            "{:<52} {:>16} {:>24}",
            "receipt → first byte, average",
            "25.9 µs",
            format!("{:.1} µs", d.mean)
        );
        println!(
            "{:<52} {:>16} {:>24}",
            "receipt → first byte, p50 / p99",
            "-",
            format!("{:.1} / {:.1} µs", d.p50, d.p99)
        );
        println!(
            "{:<52} {:>16} {:>24}",
            "the floor (condvar wake p50), same window",
            "-",
            format!("{:.1} µs ({:.2}×)", floor.wake, d.p50 / floor.wake)
        );
        println!(
            "{:<52} {:>16} {:>24}",
            "the floor with a pty write (wake + write p50)",
            "-",
            format!("{:.1} µs ({:.2}×)", floor.write, d.p50 / floor.write)
        );
        let bw = |mean_us: f64| 1.0 / (0.1 + 0.01 + mean_us * 1e-6);
        println!(
            "{:<52} {:>16} {:>24}",
            "effective bandwidth (10 Hz actuator, 100 Hz commands)",
            "9.0888 of 9.0909 Hz",
            format!("{:.4} of 9.0909 Hz", bw(d.mean))
        );
    }
    if let (Some(first), Some(last)) = (r.fig3.first(), r.fig3.iter().find(|x| x.0 == 32)) {
        println!(
            "{:<52} {:>16} {:>24}",
            "Fig. 3: delay p50 at 32 actuators / at 1",
            "flat",
            format!("{:.2}×", last.1.p50 / first.1.p50)
        );
    }
    if let Some(x) = r.fig4.iter().find(|x| x.0 == 10000.0) {
        println!(
            "{:<52} {:>16} {:>24}",
            "Fig. 4: CPU at 10,000 datagrams/s (4 actuators)",
            "flat, low",
            format!("{:.1} % of a core", x.2)
        );
    }
    if let Some(c) = r.fig4_floor {
        println!(
            "{:<52} {:>16} {:>24}",
            "  the floor: a bare UDP receiver at 10,000/s",
            "-",
            format!("{c:.1} % of a core")
        );
    }
    for (label, s, exec, wire) in &r.cued {
        println!(
            "{:<52} {:>16} {:>24}",
            format!("cued command, {label}: max delay"),
            if label.contains("cap") {
                "cap: 10 Hz"
            } else if label.starts_with("paper") {
                "~200 ms"
            } else {
                "-"
            },
            format!(
                "{:.0} ms, {:.0}% of the wire",
                s.max_us.unwrap_or(f64::NAN) / 1000.0,
                exec / wire * 100.0
            )
        );
    }
    if r.rss_headless > 0 {
        println!(
            "{:<52} {:>16} {:>24}",
            "peak memory, headless / console",
            "< 4 MB",
            format!(
                "{:.1} / {:.1} MB",
                r.rss_headless as f64 / 1024.0,
                r.rss_console as f64 / 1024.0
            )
        );
    }
    if let Some((idle, busy)) = r.console_output {
        println!(
            "{:<52} {:>16} {:>24}",
            "console output, idle / steering at 10 Hz",
            "-",
            format!("{:.1} / {:.1} kB/s", idle / 1000.0, busy / 1000.0)
        );
    }
    println!("\nplots: {}", out.display());
}
