//! Section 9, the paper's open problem: fixed against adaptive polling on a 9600 baud
//! link with commands at 100 Hz. It runs in this process (engine and simulator), so
//! that the simulator's true position can be sampled every millisecond against what
//! adrive believes — the cache (the paper's way) and the estimate.

use adrive::config;
use adrive::driver;
use adrive::engine::Engine;
use adrive::engine::Gate;
use adrive::sim::Sim;
use adrive::value::Command;
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
}

impl Drop for Run {
    fn drop(&mut self) {
        if let Some(e) = self.engine.take() {
            e.shutdown(Duration::from_secs(2));
        }
    }
}

/// The command profile of section 9 at `t` seconds: a path follower's set point —
/// a step, a hold, a ramp at half the drive's rate, a hold — repeated every 4 s.
fn profile(t: f64) -> f64 {
    match t % 4.0 {
        c if c < 2.0 => 0.5,
        c if c < 3.0 => 0.5 - 0.5 * (c - 2.0),
        _ => 0.0,
    }
}

/// Section 9: two identical drives on 9600 baud lines in one run, one polled every
/// 50 ms, one adaptively (50 ms … 1 s); both commanded at 100 Hz under the port rule
/// `rule`; the simulator's true position sampled every millisecond against the cache
/// (what the paper's adrive believes) and the estimate.
pub fn section9_estimator(rule: &str, secs: f64) {
    println!();
    println!(
        "== 9. fixed against adaptive polling: 9600 baud, commands at 100 Hz, port rule {rule}, {secs} s =="
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
    let before: Vec<_> = devices.iter().map(|d| d.stats().counters()).collect();
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
                let _ = run.gate.submit(d.id(), Command::Set(v), now);
            }
            next_command += Duration::from_millis(10);
        }
        let truth: Vec<f64> = {
            let mut m = model.lock();
            m.step();
            sim_index.iter().map(|&i| m.devices[i].position).collect()
        };
        for (i, d) in devices.iter().enumerate() {
            let cached = d.reading(d.config().reading("position").unwrap());
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
        let s = d.stats().counters();
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
