//! The paper's measurements, repeated against simulated devices on real
//! pseudo-terminals, with every rule side by side in the same run (these machines are
//! noisy; only figures from one run compare):
//!
//! 1. The cued-command scenario: status polls of 100 ms, commands at 100 Hz — the
//!    paper's plain lock, the paper's lock with its 10 Hz rate cap, adrive's rule.
//! 2. Receipt → first-byte delay against the number of actuators (the paper's Fig. 3).
//! 3. CPU time against the command rate (the paper's Fig. 4).
//! 4. The command delay with recording off and on (raw traffic included), taken in
//!    turns: recording must cost the command path nothing measurable.
//!
//! Run: `cargo bench --bench paper` (about a minute and a half); `cargo bench --bench
//! paper -- record` runs only the fourth.

use adrive::config;
use adrive::driver;
use adrive::engine::Engine;
use adrive::record::{Options, Recorder, Target};
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

/// A vehicle of these actuators, each polled every 100 ms.
fn vehicle(names: &[&str]) -> String {
    let mut toml = String::from("[vehicle]\nname = \"bench\"\n");
    for n in names {
        toml.push_str(&device(n, "status_period = \"100ms\"", ""));
    }
    toml
}

/// The header of a table of [`row`]s.
fn table(first: &str) {
    println!(
        "{first:<34} {:>7} {:>9} {:>9} {:>9}",
        "sent", "p50 ms", "p99 ms", "max ms"
    );
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
    let only_record = std::env::args().skip(1).any(|a| a == "record");
    if !only_record {
        paper(secs);
    }
    recording(secs);
}

/// 4. Three actuators at 100 Hz, recording off and on in turns, each run alike.
fn recording(secs: f64) {
    println!();
    println!("== 4. recording off and on, in turns (3 actuators at 100 Hz, {secs} s each) ==");
    table("recording");
    let roles = ["steer", "gas", "brake"];
    let toml = vehicle(&roles);
    let dir = tempfile::tempdir().unwrap();
    for turn in 1..=2 {
        for on in [false, true] {
            let run = Run::start(&toml);
            let recorder = on.then(|| {
                let opts = Options {
                    target: Target::File(dir.path().join(format!("bench-{turn}.mcap"))),
                    raw: true,
                };
                Recorder::start(&run.vehicle, opts).unwrap()
            });
            run.drive(&roles, 100.0, secs);
            if let Some(r) = recorder {
                let late = r.shutdown(Duration::from_secs(5));
                assert!(late.is_empty(), "the recorder did not stop: {late:?}");
            }
            let extra = match run.vehicle.tap.status() {
                Some(v) => format!(
                    "{} messages, {} kB, {} left out{}",
                    v.messages,
                    v.bytes / 1000,
                    v.dropped,
                    v.error.map(|e| format!(", error: {e}")).unwrap_or_default()
                ),
                None => String::new(),
            };
            // Every actuator's commands, one summary: the worst device's p99.
            let worst = roles
                .iter()
                .map(|r| run.device(r).stats.snapshot().command_delay)
                .max_by(|a, b| a.p99_us.unwrap_or(0.0).total_cmp(&b.p99_us.unwrap_or(0.0)))
                .unwrap();
            let label = format!(
                "{} (turn {turn}, worst device)",
                if on { "on " } else { "off" }
            );
            row(&label, &worst, &extra);
        }
    }
}

/// 1 to 3: the paper's measurements.
fn paper(secs: f64) {
    println!("== 1. cued commands: status polls of ~100 ms, commands at 100 Hz for {secs} s ==");
    table("rule");
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

    println!();
    println!("== 2. delay against the number of actuators (100 Hz each, {secs} s) ==");
    table("actuators");
    let roles = ["steer", "gas", "brake"];
    for n in 1..=roles.len() {
        let toml = vehicle(&roles[..n]);
        let run = Run::start(&toml);
        run.drive(&roles[..n], 100.0, secs);
        for r in &roles[..n] {
            let s = run.device(r).stats.snapshot();
            row(&format!("{n} actuator(s): {r}"), &s.command_delay, "");
        }
    }

    println!();
    println!("== 3. CPU against the command rate (3 actuators, {secs} s each) ==");
    println!(
        "{:<34} {:>9} {:>12}",
        "commands/s per actuator", "CPU %", "delay p99 ms"
    );
    let toml = vehicle(&roles);
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
