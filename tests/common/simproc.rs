//! `adrive sim` in a process of its own, as a user runs it beside adrive: its port
//! paths, every line it prints, faults typed on its standard input; and the built-in
//! Alice pointed at its ports. For the tests that run the real binary against it.

use super::DEADLINE;
use adrive::config::ALICE_TOML;
use std::io::{BufRead, BufReader, Write};
use std::path::PathBuf;
use std::process::{Child, ChildStdin, Command as Process, Stdio};
use std::sync::{mpsc, Arc, Mutex};
use std::time::{Duration, Instant};

const BIN: &str = env!("CARGO_BIN_EXE_adrive");

/// `adrive sim` in its own process; every line it prints is kept.
pub struct SimProcess {
    pub child: Child,
    stdin: ChildStdin,
    lines: Arc<Mutex<Vec<String>>>,
    new: mpsc::Receiver<String>,
    /// Each device's port, in the vehicle's order.
    pub paths: Vec<String>,
}

impl SimProcess {
    /// `adrive sim` with the built-in Alice (six ports).
    pub fn start() -> SimProcess {
        SimProcess::start_with(&[], 6)
    }

    /// `adrive sim ARGS…`, which prints `ports` port lines first.
    pub fn start_with(args: &[&str], ports: usize) -> SimProcess {
        let mut child = Process::new(BIN)
            .arg("sim")
            .args(args)
            .stdin(Stdio::piped())
            .stdout(Stdio::piped())
            .stderr(Stdio::null())
            .spawn()
            .unwrap();
        let stdin = child.stdin.take().unwrap();
        let out = child.stdout.take().unwrap();
        let lines = Arc::new(Mutex::new(Vec::new()));
        let (tx, new) = mpsc::channel();
        let keep = lines.clone();
        std::thread::spawn(move || {
            for l in BufReader::new(out).lines().map_while(Result::ok) {
                keep.lock().unwrap().push(l.clone());
                let _ = tx.send(l);
            }
        });
        let mut sim = SimProcess {
            child,
            stdin,
            lines,
            new,
            paths: Vec::new(),
        };
        for _ in 0..ports {
            let l = sim.next_line();
            sim.paths
                .push(l.split_whitespace().nth(1).unwrap().to_string());
        }
        sim
    }

    /// Every line it printed so far.
    #[allow(dead_code)]
    pub fn lines(&self) -> Vec<String> {
        self.lines.lock().unwrap().clone()
    }

    pub fn next_line(&self) -> String {
        self.new
            .recv_timeout(DEADLINE)
            .expect("a line from adrive sim")
    }

    /// How many lines it printed so far (a mark for [`SimProcess::wait_after`]).
    pub fn mark(&self) -> usize {
        self.lines.lock().unwrap().len()
    }

    /// Wait for a line printed after `mark` containing every one of `words`; the line,
    /// and the mark just past it.
    pub fn wait_after(&self, mark: usize, words: &[&str]) -> (String, usize) {
        let end = Instant::now() + DEADLINE;
        loop {
            if let Some((i, l)) = self.lines.lock().unwrap()[mark..]
                .iter()
                .enumerate()
                .find(|(_, l)| words.iter().all(|w| l.contains(w)))
            {
                return (l.clone(), mark + i + 1);
            }
            assert!(Instant::now() < end, "adrive sim never printed {words:?}");
            let _ = self.new.recv_timeout(Duration::from_millis(50));
        }
    }

    /// Wait for a printed line containing every one of `words`.
    pub fn wait_for(&self, words: &[&str]) -> String {
        self.wait_after(0, words).0
    }

    pub fn say(&mut self, line: &str) {
        writeln!(self.stdin, "{line}").unwrap();
    }

    /// Stop it as a user would (SIGTERM), so that it removes its port links.
    pub fn stop(mut self) {
        super::signal(&self.child, libc::SIGTERM);
        let _ = super::wait_exit(&mut self.child);
    }

    /// The last command the named device received (`0.300`, `drive`, …).
    pub fn last_command(&self, device: &str) -> Option<String> {
        self.lines
            .lock()
            .unwrap()
            .iter()
            .rev()
            .filter_map(|l| {
                let w: Vec<&str> = l.split_whitespace().collect();
                (w.get(1) == Some(&device) && w.get(2) == Some(&"<-")).then(|| w[3].to_string())
            })
            .next()
    }
}

impl Drop for SimProcess {
    fn drop(&mut self) {
        // SIGTERM first: it removes its directory of links.
        super::stop(&mut self.child);
    }
}

/// The built-in Alice pointed at the simulator's ports.
pub fn vehicle_file(dir: &std::path::Path, sim: &SimProcess, extra: &str) -> PathBuf {
    let mut paths = sim.paths.iter();
    let mut text = String::new();
    for line in ALICE_TOML.lines() {
        if line.starts_with("port = ") {
            text.push_str(&format!("port = \"{}\"\n", paths.next().unwrap()));
        } else {
            text.push_str(line);
            text.push('\n');
        }
    }
    // Alice allows network engage; its broadcast goes to loopback.
    text.push_str(&format!("\n[supervisor]\n{extra}\n"));
    let path = dir.join("vehicle.toml");
    std::fs::write(&path, text).unwrap();
    path
}
