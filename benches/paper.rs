//! The paper's measurements, repeated against simulated devices on real
//! pseudo-terminals, with every rule side by side in the same run (these machines are
//! noisy; only figures from one run compare):
//!
//! 1. The cued-command scenario: status polls of 100 ms, commands at 100 Hz — the
//!    paper's plain lock, the paper's lock with its 10 Hz rate cap, adrive's rule.
//! 2. Receipt → first-byte delay against the number of actuators (the paper's Fig. 3).
//! 3. CPU time against the command rate (the paper's Fig. 4).
//! 4. The paper's open problem: fixed against adaptive polling on a 9600 baud link
//!    with commands at 100 Hz, the simulator's true position known — command
//!    transactions, polls, and the error of what adrive believes.
//!
//! Run: `cargo bench --bench paper` (about a minute and a half); `cargo bench --bench
//! paper -- 4` runs section 4 alone.

use adrive::config;
use adrive::driver;
use adrive::engine::Engine;
use adrive::safety::Gate;
use adrive::sim::Sim;
use adrive::value::Command;
use adrive::vehicle::stats::LatencySummary;
use adrive::vehicle::{Device, Vehicle};
use std::sync::Arc;
use std::time::{Duration, Instant};

struct Run {
    vehicle: Arc<Vehicle>,
    gate: Arc<Gate>,
    engine: Option<Engine>,
    _sim: Sim,
}

impl Run {
    fn start(toml: &str) -> Run {
        let mut c = config::parse(toml, "bench.toml").unwrap();
        let sim = Sim::start(&c, None).unwrap();
        sim.patch(&mut c);
        let vehicle = Arc::new(Vehicle::new(c, |d| {
            let (p, b, t) = (d.port.clone(), d.baud, d.reply_timeout);
            Box::new(move || driver::open_serial(&p, b, t))
        }));
        let gate = Arc::new(Gate::new(vehicle.clone()));
        let engine = Engine::start(gate.clone()).unwrap();
        let end = Instant::now() + Duration::from_secs(20);
        while !gate.blockers().is_empty() {
            assert!(Instant::now() < end, "devices did not report");
            std::thread::sleep(Duration::from_millis(5));
        }
        gate.engage("bench").unwrap();
        Run {
            vehicle,
            gate,
            engine: Some(engine),
            _sim: sim,
        }
    }

    fn device(&self, name: &str) -> &Device {
        self.vehicle
            .find(name)
            .expect("a device of the bench vehicle")
    }

    /// Send `rate` Hz of commands to every actuator listed for `secs`.
    fn drive(&self, names: &[&str], rate: f64, secs: f64) {
        let ids: Vec<_> = names.iter().map(|n| self.device(n).id).collect();
        let period = Duration::from_secs_f64(1.0 / rate);
        let start = Instant::now();
        let mut next = start;
        let mut i = 0u64;
        while start.elapsed().as_secs_f64() < secs {
            let v = (i % 50) as f64 / 100.0;
            for id in &ids {
                let _ = self.gate.submit(*id, Command::Set(v), Instant::now());
            }
            i += 1;
            next += period;
            if let Some(d) = next.checked_duration_since(Instant::now()) {
                std::thread::sleep(d);
            }
        }
    }
}

impl Drop for Run {
    fn drop(&mut self) {
        if let Some(e) = self.engine.take() {
            e.shutdown(Duration::from_secs(2));
        }
    }
}

fn device(name: &str, extra: &str, sim: &str) -> String {
    format!("[[device]]\nname = \"{name}\"\nkind = \"setpoint\"\nrange = [-1.0, 1.0]\ndriver = \"line\"\nbaud = 38400\nreply_timeout = \"500ms\"\n{extra}\n[device.sim]\n{sim}\n")
}

fn ms(v: Option<f64>) -> String {
    v.map_or("-".into(), |us| format!("{:.2}", us / 1000.0))
}

fn row(label: &str, s: &LatencySummary, extra: &str) {
    println!(
        "{label:<34} {:>7} {:>9} {:>9} {:>9}  {extra}",
        s.count,
        ms(s.p50_us),
        ms(s.p99_us),
        ms(s.max_us)
    );
}

fn cpu_time() -> Duration {
    // SAFETY: getrusage fills the struct we hand it.
    let mut u: libc::rusage = unsafe { std::mem::zeroed() };
    unsafe { libc::getrusage(libc::RUSAGE_SELF, &mut u) };
    let t = |v: libc::timeval| Duration::new(v.tv_sec as u64, v.tv_usec as u32 * 1000);
    t(u.ru_utime) + t(u.ru_stime)
}

fn main() {
    let secs = 4.0;
    let only: Vec<String> = std::env::args()
        .skip(1)
        .filter(|a| !a.starts_with('-'))
        .collect();
    let runs = |n: &str| only.is_empty() || only.iter().any(|o| o == n);
    if runs("1") {
        cued(secs);
    }
    if runs("2") {
        actuators(secs);
    }
    if runs("3") {
        cpu(secs);
    }
    if runs("4") {
        for rule in ["priority", "paper"] {
            estimator(rule, 20.0);
        }
    }
}

fn cued(secs: f64) {
    println!("== 1. cued commands: status polls of ~100 ms, commands at 100 Hz for {secs} s ==");
    println!(
        "{:<34} {:>7} {:>9} {:>9} {:>9}",
        "rule", "sent", "p50 ms", "p99 ms", "max ms"
    );
    for (label, extra) in [
        ("paper: plain lock", "port_rule = \"paper\""),
        (
            "paper + 10 Hz rate cap",
            "port_rule = \"paper\"\nmin_command_interval = \"100ms\"",
        ),
        ("adrive: priority (default)", "port_rule = \"priority\""),
    ] {
        let toml = format!(
            "[vehicle]\nname = \"bench\"\n{}",
            device(
                "steer",
                &format!("status_period = \"100ms\"\nstatus_max_age = \"500ms\"\n{extra}"),
                "poll_delay = \"95ms\"\ncommand_delay = \"20ms\""
            )
        );
        let run = Run::start(&toml);
        run.drive(&["steer"], 100.0, secs);
        let s = run.device("steer").stats.snapshot();
        row(
            label,
            &s.command_delay,
            &format!(
                "executed {} superseded {} polls {}",
                s.executed, s.superseded, s.polls
            ),
        );
    }
}

const ROLES: [&str; 3] = ["steer", "gas", "brake"];

fn actuators(secs: f64) {
    println!();
    println!("== 2. delay against the number of actuators (100 Hz each, {secs} s) ==");
    println!(
        "{:<34} {:>7} {:>9} {:>9} {:>9}",
        "actuators", "sent", "p50 ms", "p99 ms", "max ms"
    );
    let roles = ROLES;
    for n in 1..=roles.len() {
        let mut toml = String::from("[vehicle]\nname = \"bench\"\n");
        for r in &roles[..n] {
            toml.push_str(&device(r, "status_period = \"100ms\"", ""));
        }
        let run = Run::start(&toml);
        run.drive(&roles[..n], 100.0, secs);
        for r in &roles[..n] {
            let s = run.device(r).stats.snapshot();
            row(&format!("{n} actuator(s): {r}"), &s.command_delay, "");
        }
    }
}

fn cpu(secs: f64) {
    let roles = ROLES;
    println!();
    println!("== 3. CPU against the command rate (3 actuators, {secs} s each) ==");
    println!(
        "{:<34} {:>9} {:>12}",
        "commands/s per actuator", "CPU %", "delay p99 ms"
    );
    let mut toml = String::from("[vehicle]\nname = \"bench\"\n");
    for r in &roles {
        toml.push_str(&device(r, "status_period = \"100ms\"", ""));
    }
    for rate in [0.0, 10.0, 100.0, 1000.0] {
        let run = Run::start(&toml);
        let t0 = cpu_time();
        let w0 = Instant::now();
        if rate == 0.0 {
            std::thread::sleep(Duration::from_secs_f64(secs));
        } else {
            run.drive(&["steer", "gas"], rate, secs);
        }
        // The simulator runs in this process too; its share is included.
        let cpu = (cpu_time() - t0).as_secs_f64() / w0.elapsed().as_secs_f64() * 100.0;
        let p99 = run.device("steer").stats.snapshot().command_delay.p99_us;
        println!("{rate:<34} {cpu:>9.1} {:>12}", ms(p99));
    }
}

/// The command profile of section 4 at `t` seconds: a path follower's set point —
/// a step, a hold, a ramp at half the drive's rate, a hold — repeated every 4 s.
fn profile(t: f64) -> f64 {
    match t % 4.0 {
        c if c < 2.0 => 0.5,
        c if c < 3.0 => 0.5 - 0.5 * (c - 2.0),
        _ => 0.0,
    }
}

/// Section 4: two identical drives on 9600 baud lines in one run, one polled every
/// 50 ms, one adaptively (50 ms … 1 s); both commanded at 100 Hz under the port rule
/// `rule`; the simulator's true position sampled every millisecond against the cache
/// (what the paper's adrive believes) and the estimate.
fn estimator(rule: &str, secs: f64) {
    println!();
    println!(
        "== 4. fixed against adaptive polling: 9600 baud, commands at 100 Hz, port rule {rule}, {secs} s =="
    );
    let drive = |name: &str, polling: &str| {
        format!(
            "[[device]]\nname = \"{name}\"\nkind = \"setpoint\"\nrange = [-1.0, 1.0]\ndriver = \"line\"\nbaud = 9600\nstatus_period = \"50ms\"\nstatus_max_age = \"1s\"\nreply_timeout = \"200ms\"\npolling = \"{polling}\"\nport_rule = \"{rule}\"\n[device.response]\nrate = 1.0\n[device.sim]\nrate = 1.0\n"
        )
    };
    let toml = format!(
        "[vehicle]\nname = \"bench\"\n{}{}",
        drive("fixed", "fixed"),
        drive("adaptive", "adaptive")
    );
    let run = Run::start(&toml);
    let names = ["fixed", "adaptive"];
    let devices: Vec<&Device> = names.iter().map(|n| run.device(n)).collect();
    let before: Vec<_> = devices.iter().map(|d| d.stats.snapshot()).collect();
    let model = run._sim.model().clone();
    let sim_index: Vec<usize> = names
        .iter()
        .map(|n| {
            model
                .lock()
                .devices
                .iter()
                .position(|d| d.name == *n)
                .unwrap()
        })
        .collect();
    // Per device: squared and worst error of the cache and of the estimate.
    let mut err = [[(0.0f64, 0.0f64); 2]; 2];
    let mut samples = 0u64;
    let start = Instant::now();
    let mut next_command = start;
    while start.elapsed().as_secs_f64() < secs {
        let now = Instant::now();
        if now >= next_command {
            let v = profile(start.elapsed().as_secs_f64());
            for d in &devices {
                let _ = run.gate.submit(d.id, Command::Set(v), now);
            }
            next_command += Duration::from_millis(10);
        }
        let truth: Vec<f64> = {
            let mut m = model.lock();
            m.step();
            sim_index.iter().map(|&i| m.devices[i].position).collect()
        };
        for (i, d) in devices.iter().enumerate() {
            let cached = d.reading(d.config.reading("position").unwrap());
            let estimate = d.estimate(now).map(|e| e.position);
            for (k, belief) in [cached, estimate].into_iter().enumerate() {
                let e = (belief.unwrap_or(0.0) - truth[i]).abs();
                err[i][k].0 += e * e;
                err[i][k].1 = err[i][k].1.max(e);
            }
        }
        samples += 1;
        std::thread::sleep(Duration::from_millis(1));
    }
    let elapsed = start.elapsed().as_secs_f64();
    println!(
        "{:<10} {:>10} {:>8} {:>10} {:>10} {:>10} {:>10}",
        "polling", "commands/s", "polls/s", "cache rms", "cache max", "est rms", "est max"
    );
    for (i, d) in devices.iter().enumerate() {
        let s = d.stats.snapshot();
        let rms = |k: usize| (err[i][k].0 / samples as f64).sqrt();
        println!(
            "{:<10} {:>10.1} {:>8.1} {:>10.4} {:>10.4} {:>10.4} {:>10.4}",
            names[i],
            (s.executed - before[i].executed) as f64 / elapsed,
            (s.polls - before[i].polls) as f64 / elapsed,
            rms(0),
            err[i][0].1,
            rms(1),
            err[i][1].1,
        );
    }
}
