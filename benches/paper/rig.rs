//! The processes a measurement runs, as in the field: `adrive sim` in a process of its
//! own, adrive headless in another on the simulator's ports, and a planner sending
//! datagrams. The bench reads adrive's own figures from its state broadcast (the one
//! snapshot every client reads) and its CPU time and memory from `/proc`.

use adrive::snapshot::{Assembler, Snapshot};
use std::io::{BufRead, BufReader};
use std::net::{SocketAddr, UdpSocket};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

/// The adrive binary cargo built for this bench, or the one `ADRIVE_BENCH_BIN` names
/// (to compare builds, e.g. another profile, with one bench binary).
pub fn adrive() -> String {
    std::env::var("ADRIVE_BENCH_BIN").unwrap_or_else(|_| env!("CARGO_BIN_EXE_adrive").into())
}

/// Long enough for anything that works; a bench that waits this long has failed.
const DEADLINE: Duration = Duration::from_secs(30);

pub use crate::common::free_port;
use crate::common::stop;

/// `adrive send` as a planner: `count` datagrams of `body` to `to`, `rate` a second,
/// waiting for it to finish.
pub fn send_at(to: SocketAddr, rate: f64, count: u64, body: &[&str]) {
    let _ = Command::new(adrive())
        .args(["send", "--to", &to.to_string(), "--rate", &rate.to_string()])
        .args(["--count", &count.to_string()])
        .args(body)
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .status();
}

/// CPU time of a process, all its threads, from the scheduler's own accounting.
pub fn cpu_time(pid: u32) -> Duration {
    let mut ns = 0u64;
    if let Ok(tasks) = std::fs::read_dir(format!("/proc/{pid}/task")) {
        for t in tasks.flatten() {
            if let Ok(s) = std::fs::read_to_string(t.path().join("schedstat")) {
                ns += s
                    .split_whitespace()
                    .next()
                    .and_then(|x| x.parse::<u64>().ok())
                    .unwrap_or(0);
            }
        }
    }
    Duration::from_nanos(ns)
}

/// CPU time of each thread of a process, by name (threads of one name summed).
pub fn cpu_by_thread(pid: u32) -> Vec<(String, Duration)> {
    let mut out: Vec<(String, Duration)> = Vec::new();
    if let Ok(tasks) = std::fs::read_dir(format!("/proc/{pid}/task")) {
        for t in tasks.flatten() {
            let name = std::fs::read_to_string(t.path().join("comm")).unwrap_or_default();
            let ns = std::fs::read_to_string(t.path().join("schedstat"))
                .ok()
                .and_then(|s| s.split_whitespace().next()?.parse::<u64>().ok())
                .unwrap_or(0);
            let name = name.trim().to_string();
            match out.iter_mut().find(|(n, _)| *n == name) {
                Some((_, d)) => *d += Duration::from_nanos(ns),
                None => out.push((name, Duration::from_nanos(ns))),
            }
        }
    }
    out
}

/// A field of `/proc/PID/status` in kB (`VmHWM`: peak resident set).
pub fn status_kb(pid: u32, field: &str) -> u64 {
    std::fs::read_to_string(format!("/proc/{pid}/status"))
        .ok()
        .and_then(|s| {
            s.lines()
                .find(|l| l.starts_with(field))
                .and_then(|l| l.split_whitespace().nth(1)?.parse().ok())
        })
        .unwrap_or(0)
}

/// The peak resident set of a command run to its end, kB (from `wait4`'s usage).
#[allow(unsafe_code)]
pub fn peak_kb_of(cmd: &mut Command) -> u64 {
    #[expect(clippy::zombie_processes, reason = "reaped by wait4 below")]
    let child = cmd
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    let mut status = 0;
    // SAFETY: an all-zero rusage is valid; wait4 fills it for our own child.
    let mut usage: libc::rusage = unsafe { std::mem::zeroed() };
    // SAFETY: waiting for our own child, with valid out-pointers.
    unsafe { libc::wait4(child.id() as i32, &mut status, 0, &mut usage) };
    usage.ru_maxrss as u64
}

/// Resident memory by what it is: (the binary, shared libraries, heap and stacks), kB.
pub fn rss_parts(pid: u32) -> (u64, u64, u64) {
    let smaps = std::fs::read_to_string(format!("/proc/{pid}/smaps")).unwrap_or_default();
    let (mut bin, mut libs, mut anon) = (0, 0, 0);
    let mut what = 2;
    for l in smaps.lines() {
        let f: Vec<&str> = l.split_whitespace().collect();
        if f.first()
            .is_some_and(|a| a.contains('-') && !a.ends_with(':'))
        {
            what = match f.get(5) {
                Some(p) if p.ends_with("/adrive") => 0,
                Some(p) if p.starts_with('/') => 1,
                _ => 2,
            };
        } else if f.first() == Some(&"Rss:") {
            let kb: u64 = f.get(1).and_then(|x| x.parse().ok()).unwrap_or(0);
            match what {
                0 => bin += kb,
                1 => libs += kb,
                _ => anon += kb,
            }
        }
    }
    (bin, libs, anon)
}

/// `adrive sim --quiet` in its own process.
pub struct Sim {
    child: Child,
    /// Device name → the stable path of its port.
    pub ports: Vec<(String, String)>,
}

impl Sim {
    pub fn start(vehicle: &Path) -> Sim {
        let mut child = Command::new(adrive())
            .args(["sim", "--quiet", "--config"])
            .arg(vehicle)
            .stdin(Stdio::null())
            .stdout(Stdio::piped())
            .stderr(Stdio::null())
            .spawn()
            .expect("adrive sim starts");
        let mut ports = Vec::new();
        let out = BufReader::new(child.stdout.take().expect("piped"));
        for line in out.lines() {
            let line = line.expect("adrive sim's output");
            if line.starts_with("type `help`") {
                break;
            }
            let mut w = line.split_whitespace();
            if let (Some(name), Some(path)) = (w.next(), w.next()) {
                ports.push((name.to_string(), path.to_string()));
            }
        }
        Sim { child, ports }
    }

    pub fn pid(&self) -> u32 {
        self.child.id()
    }

    /// A vehicle file's text with every device's `port` pointed at this simulator.
    pub fn patch(&self, toml: &str) -> String {
        let mut out = String::new();
        let mut device = None;
        for line in toml.lines() {
            let t = line.trim();
            if t.starts_with("[[device]]") {
                device = None;
            }
            if let Some(name) = t.strip_prefix("name = \"") {
                device = name.split('"').next().map(str::to_string);
            }
            if t.starts_with("port = ") {
                continue;
            }
            out.push_str(line);
            out.push('\n');
            if let Some((_, path)) = self.ports.iter().find(|(n, _)| Some(n) == device.as_ref()) {
                if t.starts_with("name = ") {
                    out.push_str(&format!("port = \"{path}\"\n"));
                }
            }
        }
        out
    }
}

impl Drop for Sim {
    fn drop(&mut self) {
        stop(&mut self.child);
    }
}

/// adrive headless on a vehicle file, with a planner's socket and a broadcast receiver.
pub struct Adrive {
    child: Child,
    pub listen: SocketAddr,
    /// Its control socket (one per run: runs may overlap).
    pub socket: PathBuf,
    planner: UdpSocket,
    broadcast: UdpSocket,
    _dir: PathBuf,
}

/// `toml` without the table `header` (its header line and keys, up to the next table).
fn without_table(toml: &str, header: &str) -> String {
    let mut out = String::new();
    let mut inside = false;
    for line in toml.lines() {
        let t = line.trim_start();
        if t.starts_with('[') {
            inside = t.starts_with(header);
        }
        if !inside {
            out.push_str(line);
            out.push('\n');
        }
    }
    out
}

impl Adrive {
    /// Start adrive headless on `toml` (its `[network]` section is added here), wait
    /// until every device reported and engage it from the planner's socket.
    pub fn start(dir: &Path, name: &str, toml: &str) -> Adrive {
        Adrive::start_with(dir, name, toml, &[])
    }

    /// [`Adrive::start`] with more arguments (`--record FILE`).
    pub fn start_with(dir: &Path, name: &str, toml: &str, args: &[&str]) -> Adrive {
        let broadcast = UdpSocket::bind("127.0.0.1:0").expect("a broadcast socket");
        broadcast
            .set_read_timeout(Some(Duration::from_millis(500)))
            .unwrap();
        let to = broadcast.local_addr().unwrap();
        let file = dir.join(format!("{name}.toml"));
        let network = format!(
            "\n[network]\nallow_engage = true\nwatchdog_timeout = \"2s\"\nbroadcast_to = [\"{to}\"]\nbroadcast_rate = 10.0\n"
        );
        // The vehicle's own [network] is replaced; this one must come before the first
        // [[device]] table to be top-level.
        let toml = &without_table(toml, "[network]");
        let text = match toml.find("[[device]]") {
            Some(i) => format!("{}{network}\n{}", &toml[..i], &toml[i..]),
            None => format!("{toml}{network}"),
        };
        std::fs::write(&file, text).unwrap();
        let listen: SocketAddr = format!("127.0.0.1:{}", free_port()).parse().unwrap();
        static RUNS: std::sync::atomic::AtomicU32 = std::sync::atomic::AtomicU32::new(0);
        let run = RUNS.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
        let socket = dir.join("logs").join(format!("{name}-{run}.sock"));
        let child = Command::new(adrive())
            .args(["--headless", "--config"])
            .arg(&file)
            .arg("--listen")
            .arg(listen.to_string())
            .arg("--log-dir")
            .arg(dir.join("logs"))
            .arg("--socket")
            .arg(&socket)
            .args(args)
            .stdin(Stdio::null())
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .spawn()
            .expect("adrive starts");
        let planner = UdpSocket::bind("127.0.0.1:0").unwrap();
        planner.connect(listen).unwrap();
        planner
            .set_read_timeout(Some(Duration::from_millis(100)))
            .unwrap();
        let a = Adrive {
            child,
            listen,
            socket,
            planner,
            broadcast,
            _dir: dir.to_path_buf(),
        };
        a.engage();
        a
    }

    fn engage(&self) {
        let end = Instant::now() + DEADLINE;
        let mut buf = [0u8; 1024];
        loop {
            assert!(Instant::now() < end, "adrive did not engage");
            let _ = self.planner.send(b"engage\n");
            if let Ok(n) = self.planner.recv(&mut buf) {
                if buf[..n].starts_with(b"ok engaged") {
                    return;
                }
            }
            std::thread::sleep(Duration::from_millis(100));
        }
    }

    pub fn pid(&self) -> u32 {
        self.child.id()
    }

    /// Send one datagram as the planner.
    pub fn send(&self, text: &str) {
        let _ = self.planner.send(text.as_bytes());
    }

    /// A whole state broadcast taken after now (its figures at most 200 ms old then),
    /// reassembled when a vehicle of many devices sends it in parts.
    pub fn snapshot(&self) -> Snapshot {
        let asked = Instant::now();
        let mut buf = vec![0u8; 65536];
        let end = asked + DEADLINE;
        let mut parts = Assembler::default();
        loop {
            assert!(Instant::now() < end, "no state broadcast");
            let Ok(n) = self.broadcast.recv(&mut buf) else {
                continue;
            };
            // Broadcasts queued before the question are stale.
            if asked.elapsed() < Duration::from_millis(250) {
                continue;
            }
            if let Some(whole) = parts.push(serde_json::from_slice(&buf[..n]).expect("a snapshot"))
            {
                return whole;
            }
        }
    }

    /// Wait until `cond` holds for a broadcast.
    pub fn until(&self, what: &str, cond: impl Fn(&Snapshot) -> bool) -> Snapshot {
        let end = Instant::now() + DEADLINE;
        loop {
            let s = self.snapshot();
            if cond(&s) {
                return s;
            }
            assert!(Instant::now() < end, "timed out waiting for {what}");
        }
    }
}

impl Drop for Adrive {
    fn drop(&mut self) {
        stop(&mut self.child);
    }
}
