//! Section 16: a fleet on one machine, on loopback, through one Zenoh router (built
//! with the cargo feature `fleet`). N = 1, 4, 16, 32 vehicles, each `adrive --sim
//! --headless --fleet carK` on a vehicle of one simulated actuator (the fleet's cost,
//! not a vehicle's), and the router in a process of its own (`adrive fleet --router`),
//! so that its CPU and memory are its own:
//!
//! - how long a fresh `adrive fleet --watch` takes to show all N;
//! - CPU and memory each vehicle pays for being in the fleet (the same N vehicles
//!   without `--fleet`, measured in the same run), and the router's;
//! - a status asked over the fleet against the local socket, and a console's first
//!   frame, and a console's operation's round trip, remote against local (p50/p99);
//! - a console's command to the device — its `write` to the first byte at a device's
//!   end of a pseudo-terminal this process holds (section 11's) — over the fleet and
//!   over the local socket, alternated;
//! - cross-talk: commands at every vehicle not addressed, over every command sent;
//! - the router killed and started again: how long until every vehicle is listed
//!   again, and how long an engaged vehicle whose remote commander it cut off takes
//!   to the safe state.

use crate::common::{lines, stop, tempdir};
use crate::rig::{adrive, cpu_time, free_port, status_kb};
use adrive::socket::proto::{Answer, Op, Request, Role, VERSION};
use serde_json::Value;
use std::io::{BufRead, BufReader, Write};
use std::os::unix::net::UnixStream;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::sync::mpsc::Receiver;
use std::time::{Duration, Instant};

const DEADLINE: Duration = Duration::from_secs(60);
const KEY: &str = "0123456789abcdef0123456789abcdef";

struct Router(Child);

impl Router {
    fn start(endpoint: &str) -> Router {
        let child = Command::new(adrive())
            .args(["fleet", "--router", "--listen", endpoint])
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .spawn()
            .unwrap();
        let addr = endpoint.trim_start_matches("tcp/");
        let end = Instant::now() + DEADLINE;
        while std::net::TcpStream::connect(addr).is_err() {
            assert!(Instant::now() < end, "the router did not listen");
            std::thread::sleep(Duration::from_millis(20));
        }
        Router(child)
    }
}

impl Drop for Router {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

/// One vehicle: its process and its control socket.
struct Car {
    child: Child,
    socket: PathBuf,
}

impl Car {
    /// Start adrive headless on vehicle file `file` (with `args`: `--sim`, `--fleet ID
    /// --fleet-connect ENDPOINT`) on its own command port and at `socket`; its log lines
    /// with it, to wait on ([`Car::ready`]).
    fn spawn(dir: &Path, file: &Path, socket: PathBuf, args: &[&str]) -> (Car, Receiver<String>) {
        let mut child = Command::new(adrive())
            .arg("--headless")
            .args(args)
            .arg("--config")
            .arg(file)
            .arg("--listen")
            .arg(format!("127.0.0.1:{}", free_port()))
            .arg("--socket")
            .arg(&socket)
            .arg("--log-dir")
            .arg(dir.join("logs"))
            .stdout(Stdio::null())
            .stderr(Stdio::piped())
            .spawn()
            .expect("adrive starts");
        let err = lines(child.stderr.take().unwrap());
        (Car { child, socket }, err)
    }

    /// Once it runs (its log drained from then on).
    fn ready((car, err): (Car, Receiver<String>)) -> Car {
        while !err
            .recv_timeout(DEADLINE)
            .expect("a vehicle to start")
            .contains("running headless")
        {}
        std::thread::spawn(move || for _ in err {});
        car
    }
}

impl Drop for Car {
    fn drop(&mut self) {
        stop(&mut self.child);
    }
}

/// Start `n` vehicles at once (in the fleet at `endpoint` if given) and wait for each.
fn cars(dir: &Path, n: usize, endpoint: Option<&str>) -> Vec<Car> {
    // One simulated actuator; in the fleet, commanded with the key.
    let file = dir.join(format!("car-{}.toml", endpoint.is_some()));
    std::fs::write(dir.join("car.key"), KEY).unwrap();
    let fleet = if endpoint.is_some() {
        "[fleet]\ncommand = true\n"
    } else {
        ""
    };
    let toml = format!(
        "[vehicle]\nname = \"car\"\n[network]\nkey_file = \"car.key\"\n{}{fleet}",
        crate::idle_actuator("steer")
    );
    std::fs::write(&file, toml).unwrap();
    let started: Vec<_> = (0..n)
        .map(|k| {
            let socket = dir.join(format!("car{k}-{}.sock", endpoint.is_some()));
            let id = format!("car{k}");
            let mut args = vec!["--sim"];
            if let Some(e) = endpoint {
                args.extend(["--fleet", &id, "--fleet-connect", e]);
            }
            Car::spawn(dir, &file, socket, &args)
        })
        .collect();
    started.into_iter().map(Car::ready).collect()
}

/// How long a fresh `adrive fleet --watch` takes to have heard the state of `n`.
fn time_to_list(endpoint: &str, n: usize) -> Duration {
    let t = Instant::now();
    let mut watch = Command::new(adrive())
        .args(["fleet", "--watch", "--json", "--connect", endpoint])
        .stdout(Stdio::piped())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    let rx = lines(watch.stdout.take().unwrap());
    let mut seen = std::collections::HashSet::new();
    while seen.len() < n {
        let l = rx.recv_timeout(DEADLINE).expect("the fleet listed");
        let v: Value = serde_json::from_str(&l).unwrap();
        if v["event"] == "state" {
            seen.insert(v["id"].as_str().unwrap().to_string());
        }
    }
    let took = t.elapsed();
    let _ = watch.kill();
    let _ = watch.wait();
    took
}

/// A client of a control socket (or of a link carrying one).
struct Client {
    w: UnixStream,
    r: BufReader<UnixStream>,
    next: u64,
}

impl Client {
    /// Say hello as `role`; with a console, wait for its first frame.
    fn hello(s: UnixStream, role: Role) -> Client {
        s.set_read_timeout(Some(Duration::from_secs(10))).unwrap();
        let mut c = Client {
            r: BufReader::new(s.try_clone().unwrap()),
            w: s,
            next: 1,
        };
        c.send(Op::Hello {
            role,
            version: VERSION,
        });
        loop {
            let m = c.read();
            match m["kind"].as_str() {
                Some("welcome") if role == Role::Once => return c,
                Some("frame") if role == Role::Console => return c,
                Some("bye") => panic!("{m}"),
                _ => {}
            }
        }
    }

    fn send(&mut self, op: Op) -> u64 {
        let id = self.next;
        self.next += 1;
        let mut line = serde_json::to_vec(&Request { id, op }).unwrap();
        line.push(b'\n');
        self.w.write_all(&line).unwrap();
        id
    }

    /// The next message, as JSON (its `kind`: welcome, frame, reply, bye).
    fn read(&mut self) -> Value {
        let mut line = String::new();
        loop {
            line.clear();
            assert!(self.r.read_line(&mut line).unwrap() > 0, "the link closed");
            if !line.trim().is_empty() {
                return serde_json::from_str(&line).unwrap();
            }
        }
    }

    /// Do `op`: its answer. A commanding console proves its operator is there before
    /// each, as `adrive attach` does every 250 ms.
    fn call(&mut self, op: Op) -> Answer {
        self.send(Op::Answered);
        let id = self.send(op);
        loop {
            let m = self.read();
            if m["kind"] == "reply" && m["id"] == id {
                return serde_json::from_value(m["answer"].clone()).unwrap();
            }
        }
    }
}

fn local(car: &Car) -> UnixStream {
    UnixStream::connect(&car.socket).unwrap()
}

fn remote(endpoint: &str, id: &str, key: bool) -> UnixStream {
    let key = key.then(|| adrive::net::auth::Auth::from_key_bytes(KEY.as_bytes()).unwrap());
    adrive::fleet::dial::connect(&[endpoint.to_string()], id, key).unwrap()
}

fn us(d: Duration) -> f64 {
    d.as_secs_f64() * 1e6
}

fn p50_p99(mut v: Vec<f64>) -> (f64, f64) {
    v.sort_by(f64::total_cmp);
    let at = |q: f64| v[((v.len() - 1) as f64 * q).round() as usize];
    (at(0.5), at(0.99))
}

/// Every command each vehicle has taken or refused at its intake.
fn commands_at(car: &Car) -> u64 {
    let mut c = Client::hello(local(car), Role::Once);
    match c.call(Op::Status) {
        Answer::Snapshot(s) => s
            .devices
            .iter()
            .map(|d| d.counters.received + d.counters.rejected)
            .sum(),
        other => panic!("{other:?}"),
    }
}

/// Engaged, as the gate says over the local socket.
fn engaged(c: &mut Client) -> bool {
    match c.call(Op::Status) {
        Answer::Snapshot(s) => s.gate.engaged,
        other => panic!("{other:?}"),
    }
}

pub fn section16_fleet(secs: f64) {
    println!("\n== 16. A fleet: N vehicles through one Zenoh router, on loopback ==");
    println!(
        "{:>3} {:>10} {:>12} {:>12} {:>12} {:>12}",
        "N", "listed in", "CPU/vehicle", "in fleet +", "RSS/vehicle", "router"
    );
    for n in [1usize, 4, 16, 32] {
        let dir = tempdir("bench-fleet");
        // Without the fleet first, then with it: each vehicle's CPU over a window.
        let plain = cars(dir.path(), n, None);
        std::thread::sleep(Duration::from_secs(1));
        let (cpu0, rss0) = window(&plain, secs);
        drop(plain);
        let endpoint = format!("tcp/127.0.0.1:{}", free_port());
        let router = Router::start(&endpoint);
        let fleet = cars(dir.path(), n, Some(&endpoint));
        let listed = time_to_list(&endpoint, n);
        let r0 = cpu_time(router.0.id());
        let (cpu1, rss1) = window(&fleet, secs);
        let router_cpu = (cpu_time(router.0.id()) - r0).as_secs_f64() / secs * 1e3;
        let router_rss = status_kb(router.0.id(), "VmRSS");
        println!(
            "{n:>3} {:>8.0}ms {:>9.2}ms/s {:>9.2}ms/s {:>9}kB {:>6.2}ms/s {:>6}kB",
            listed.as_secs_f64() * 1e3,
            cpu1,
            cpu1 - cpu0,
            rss1,
            router_cpu,
            router_rss,
        );
        println!(
            "    (RSS without the fleet {rss0} kB: +{} kB a vehicle)",
            rss1 as i64 - rss0 as i64
        );
        if n == 4 {
            remote_against_local(&fleet, &endpoint);
            to_the_device(dir.path(), &endpoint);
            router_restart(fleet, router, &endpoint);
        }
    }
}

/// Each vehicle's CPU (ms a second) and RSS (kB), averaged over `cars`, over `secs`.
fn window(cars: &[Car], secs: f64) -> (f64, u64) {
    let before: Vec<_> = cars.iter().map(|c| cpu_time(c.child.id())).collect();
    std::thread::sleep(Duration::from_secs_f64(secs));
    let cpu: f64 = cars
        .iter()
        .zip(before)
        .map(|(c, b)| (cpu_time(c.child.id()) - b).as_secs_f64())
        .sum::<f64>()
        / cars.len() as f64
        / secs
        * 1e3;
    let rss = cars
        .iter()
        .map(|c| status_kb(c.child.id(), "VmRSS"))
        .sum::<u64>()
        / cars.len() as u64;
    (cpu, rss)
}

/// Remote against local, alternated: a status, a console's first frame, a console's
/// operation's round trip; then cross-talk.
fn remote_against_local(cars: &[Car], endpoint: &str) {
    const RUNS: usize = 30;
    let car = &cars[0];
    let (mut st, mut frame) = ([Vec::new(), Vec::new()], [Vec::new(), Vec::new()]);
    for _ in 0..RUNS {
        for (i, remote_too) in [false, true].into_iter().enumerate() {
            let t = Instant::now();
            let s = if remote_too {
                remote(endpoint, "car0", false)
            } else {
                local(car)
            };
            let mut c = Client::hello(s, Role::Once);
            let _ = c.call(Op::Status);
            st[i].push(us(t.elapsed()));
            let t = Instant::now();
            let s = if remote_too {
                remote(endpoint, "car0", false)
            } else {
                local(car)
            };
            let _c = Client::hello(s, Role::Console);
            frame[i].push(us(t.elapsed()));
        }
    }
    // A console's operations: engaged, a set point 200 times, round trip each.
    let before: Vec<u64> = cars.iter().map(commands_at).collect();
    let mut op = [Vec::new(), Vec::new()];
    let mut sent = 0u64;
    for (i, remote_too) in [false, true].into_iter().enumerate() {
        let s = if remote_too {
            remote(endpoint, "car0", true)
        } else {
            local(car)
        };
        let mut c = Client::hello(s, Role::Console);
        let end = Instant::now() + DEADLINE;
        while !matches!(c.call(Op::Engage), Answer::Done(_)) {
            assert!(Instant::now() < end, "car0 did not engage");
            std::thread::sleep(Duration::from_millis(100));
        }
        for k in 0..200 {
            let t = Instant::now();
            let a = c.call(Op::Set {
                device: 0,
                command: adrive::value::Command::Set(f64::from(k % 50) / 100.0),
            });
            op[i].push(us(t.elapsed()));
            assert!(matches!(a, Answer::Done(_)), "{a:?}");
            sent += 1;
        }
        let _ = c.call(Op::Disengage);
    }
    let after: Vec<u64> = cars.iter().map(commands_at).collect();
    let others: u64 = before.iter().zip(&after).skip(1).map(|(b, a)| a - b).sum();
    println!(
        "    remote against local socket, N = {}, p50 / p99 µs:",
        cars.len()
    );
    for (what, v) in [
        ("a status (connect, hello, ask)", &st),
        ("a console's first frame", &frame),
        ("a console's operation, round trip", &op),
    ] {
        let (l50, l99) = p50_p99(v[0].clone());
        let (r50, r99) = p50_p99(v[1].clone());
        println!(
            "    {what:<36} local {l50:>7.0} / {l99:>7.0}   fleet {r50:>7.0} / {r99:>7.0}   ({:.1}× at p50)",
            r50 / l50
        );
    }
    println!(
        "    cross-talk: {others} commands at the {} vehicles not addressed, over {sent} sent to car0",
        cars.len() - 1
    );
}

/// The router killed under an engaged vehicle commanded from the fleet, and started
/// again.
fn router_restart(cars: Vec<Car>, router: Router, endpoint: &str) {
    let mut commander = Client::hello(remote(endpoint, "car0", true), Role::Console);
    let end = Instant::now() + DEADLINE;
    while !matches!(commander.call(Op::Engage), Answer::Done(_)) {
        assert!(Instant::now() < end, "car0 did not engage");
        std::thread::sleep(Duration::from_millis(100));
    }
    let mut watch = Client::hello(local(&cars[0]), Role::Once);
    assert!(engaged(&mut watch));
    // Its last proof just sent: what ends it is the link, not its terminal's silence.
    commander.send(Op::Answered);
    let cut = Instant::now();
    drop(router);
    while engaged(&mut watch) {
        assert!(cut.elapsed() < DEADLINE, "car0 stayed engaged");
    }
    let safe = cut.elapsed();
    let _router = Router::start(endpoint);
    let back = Instant::now();
    time_to_list(endpoint, cars.len());
    println!(
        "    router killed: car0 (commanded from the fleet) in the safe state after {:.1} ms; \
         router back: all {} listed again after {:.0} ms",
        us(safe) / 1e3,
        cars.len(),
        back.elapsed().as_secs_f64() * 1e3
    );
    drop(cars);
}

/// A console's command to the device, over the fleet and over the local socket: a
/// vehicle ("meas") whose steering is a pseudo-terminal this process reads, each set
/// point's first byte timed there against when the console wrote it (one clock, one
/// machine), 200 a way in turns of 50.
fn to_the_device(dir: &Path, endpoint: &str) {
    use crate::outside::{measured_device, value, DeviceEnd, Proto};
    let end = DeviceEnd::open(Proto::Line, true);
    let file = dir.join("meas.toml");
    std::fs::write(
        &file,
        format!(
            "[vehicle]\nname = \"meas\"\n[network]\nkey_file = \"car.key\"\n{}[fleet]\ncommand = true\n",
            measured_device("steer", Proto::Line, &end.path)
        ),
    )
    .unwrap();
    let meas = Car::ready(Car::spawn(
        dir,
        &file,
        dir.join("meas.sock"),
        &["--fleet", "meas", "--fleet-connect", endpoint],
    ));
    let mut delays = [Vec::new(), Vec::new()];
    let mut i = 0u64;
    for _turn in 0..4 {
        for (w, remote_too) in [false, true].into_iter().enumerate() {
            let s = if remote_too {
                remote(endpoint, "meas", true)
            } else {
                local(&meas)
            };
            let mut c = Client::hello(s, Role::Console);
            let until = Instant::now() + DEADLINE;
            while !matches!(c.call(Op::Engage), Answer::Done(_)) {
                assert!(Instant::now() < until, "meas did not engage");
                std::thread::sleep(Duration::from_millis(100));
            }
            let mut sent = Vec::new();
            for _ in 0..50 {
                let v = value(i);
                i += 1;
                let at = adrive::probe::mono_ns();
                let a = c.call(Op::Set {
                    device: 0,
                    command: adrive::value::Command::Set(v.parse().unwrap()),
                });
                assert!(matches!(a, Answer::Done(_)), "{a:?}");
                sent.push((v, at));
                // Commands 20 ms apart, as a console's keys come, not a flood.
                std::thread::sleep(Duration::from_millis(20));
            }
            let _ = c.call(Op::Disengage);
            let seen = end.seen.lock().unwrap();
            delays[w]
                .extend(sent.iter().filter_map(|(v, at)| {
                    seen.get(v).map(|&t| t.saturating_sub(*at) as f64 / 1e3)
                }));
        }
    }
    let (l50, l99) = p50_p99(delays[0].clone());
    let (r50, r99) = p50_p99(delays[1].clone());
    println!(
        "    {:<36} local {l50:>7.0} / {l99:>7.0}   fleet {r50:>7.0} / {r99:>7.0}   ({:.1}× at p50; {} and {} of 200 seen)",
        "a console's command to the device",
        r50 / l50,
        delays[0].len(),
        delays[1].len()
    );
    drop(meas);
}
