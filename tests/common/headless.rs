//! The real binary as a user runs it headless on simulated devices (`adrive --sim
//! --headless --config FILE`), on ports of its own, and `adrive watch --json` reading
//! its broadcast: for tests of whole vehicles and of the network clients.

use super::{free_port, lines, tempdir, DEADLINE};
use adrive::snapshot::Snapshot;
use std::net::UdpSocket;
use std::process::{Child, Command as Process, Stdio};
use std::sync::mpsc;
use std::time::Instant;
use tempfile::TempDir;

pub const BIN: &str = env!("CARGO_BIN_EXE_adrive");

/// `vehicle` (a vehicle file's text) with its `[network]` section replaced by one on
/// `listen` broadcasting to `broadcast`, planners allowed to engage, and `extra` lines.
pub fn with_network(vehicle: &str, listen: &str, broadcast: &str, extra: &str) -> String {
    let network = format!(
        "[network]\nlisten = \"{listen}\"\nbroadcast_to = [\"{broadcast}\"]\nallow_engage = true\n{extra}\n\n"
    );
    let first_device = vehicle.find("[[device]]").expect("a vehicle has devices");
    match vehicle.find("[network]") {
        Some(start) => {
            let end = start
                + vehicle[start..]
                    .find("[[device]]")
                    .expect("devices after it");
            format!("{}{network}{}", &vehicle[..start], &vehicle[end..])
        }
        None => format!(
            "{}{network}{}",
            &vehicle[..first_device],
            &vehicle[first_device..]
        ),
    }
}

/// A headless simulated vehicle on its own ports; stopped (SIGTERM, safe state first)
/// on drop.
pub struct Adrive {
    pub child: Child,
    pub listen: String,
    pub broadcast: String,
    pub dir: TempDir,
    /// What it logged up to "running headless".
    pub startup: Vec<String>,
}

impl Adrive {
    /// Start `vehicle` (a vehicle file's text) with `network_extra` in its `[network]`.
    pub fn start(tag: &str, vehicle: &str, network_extra: &str) -> Adrive {
        Adrive::start_with(tag, vehicle, network_extra, &[])
    }

    /// [`Adrive::start`] with more arguments (`--foxglove 127.0.0.1:0`); its runtime
    /// directory (`XDG_RUNTIME_DIR`) is its own temporary directory.
    pub fn start_with(tag: &str, vehicle: &str, network_extra: &str, args: &[&str]) -> Adrive {
        let dir = tempdir(tag);
        let (listen, broadcast) = (
            format!("127.0.0.1:{}", free_port()),
            format!("127.0.0.1:{}", free_port()),
        );
        let path = dir.path().join("vehicle.toml");
        std::fs::write(
            &path,
            with_network(vehicle, &listen, &broadcast, network_extra),
        )
        .unwrap();
        let mut child = Process::new(BIN)
            .args(["--sim", "--headless", "--config"])
            .arg(&path)
            .arg("--log-dir")
            .arg(dir.path().join("log"))
            .args(args)
            .env("XDG_RUNTIME_DIR", dir.path())
            .stdout(Stdio::null())
            .stderr(Stdio::piped())
            .spawn()
            .unwrap();
        let err = lines(child.stderr.take().unwrap());
        let end = Instant::now() + DEADLINE;
        let mut startup = Vec::new();
        loop {
            let l = err
                .recv_timeout(end.saturating_duration_since(Instant::now()))
                .unwrap_or_else(|_| panic!("adrive to start; it said:\n{}", startup.join("\n")));
            let done = l.contains("running headless");
            startup.push(l);
            if done {
                break;
            }
        }
        // Keep draining its log.
        std::thread::spawn(move || for _ in err {});
        Adrive {
            child,
            listen,
            broadcast,
            dir,
            startup,
        }
    }

    /// `adrive send --to` it, with `args`.
    pub fn send(&self, args: &[&str]) -> std::process::Output {
        Process::new(BIN)
            .args(["send", "--to", &self.listen])
            .args(args)
            .current_dir(self.dir.path())
            .output()
            .unwrap()
    }

    /// A UDP socket connected to its command listener, as a planner's.
    pub fn planner(&self) -> UdpSocket {
        let s = UdpSocket::bind("127.0.0.1:0").unwrap();
        s.connect(&self.listen).unwrap();
        s
    }
}

impl Drop for Adrive {
    fn drop(&mut self) {
        super::stop(&mut self.child);
    }
}

/// `adrive watch --json`, one parsed broadcast at a time.
pub struct Watch {
    child: Child,
    rx: mpsc::Receiver<String>,
}

impl Watch {
    pub fn start(from: &str) -> Watch {
        let mut child = Process::new(BIN)
            .args(["watch", "--json", "--from", from])
            .stdout(Stdio::piped())
            .stderr(Stdio::null())
            .spawn()
            .unwrap();
        let rx = lines(child.stdout.take().unwrap());
        Watch { child, rx }
    }

    /// Broadcasts until `missing` finds nothing missing in one; returns it. At the
    /// deadline, fails naming what was still missing.
    pub fn until_complete(
        &self,
        what: &str,
        mut missing: impl FnMut(&Snapshot) -> Vec<String>,
    ) -> Snapshot {
        let end = Instant::now() + DEADLINE;
        let mut left = vec!["no broadcast".to_string()];
        loop {
            let wait = end.saturating_duration_since(Instant::now());
            let Ok(line) = self.rx.recv_timeout(wait) else {
                panic!(
                    "{what}: still missing at the deadline:\n{}",
                    left.join("\n")
                );
            };
            let v: Snapshot = serde_json::from_str(&line).expect("one snapshot per line");
            left = missing(&v);
            if left.is_empty() {
                return v;
            }
        }
    }

    /// Broadcasts until one satisfies `want`; returns it and when it arrived.
    pub fn until(
        &self,
        what: &str,
        mut want: impl FnMut(&Snapshot) -> bool,
    ) -> (Snapshot, Instant) {
        let end = Instant::now() + DEADLINE;
        let mut last = Snapshot::default();
        loop {
            let left = end.saturating_duration_since(Instant::now());
            let Ok(line) = self.rx.recv_timeout(left) else {
                panic!("no broadcast with {what}; the last:\n{last:#?}");
            };
            let v: Snapshot = serde_json::from_str(&line).expect("one snapshot per line");
            if want(&v) {
                return (v, Instant::now());
            }
            last = v;
        }
    }
}

impl Drop for Watch {
    fn drop(&mut self) {
        super::stop(&mut self.child);
    }
}
