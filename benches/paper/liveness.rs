//! Section 14: a commanding console whose terminal stalls. The real binary's console
//! runs in a pseudo-terminal played by the terminal player (tests/common); the devices
//! are `adrive sim`'s, in a process of their own, which prints every command a device
//! receives. Each trial engages at the console, releases the brake to 0.3 (so the safe
//! state shows at the device), waits a random fraction of the request period, and
//! stalls the terminal (it stops reading and answering): the time to the brake's 1.000
//! at the device is measured from the stall and from the terminal's last answer. Then
//! what the check costs while commanding: bytes a second on the link, and adrive's CPU
//! commanding against watching.

use super::common::pty::Master;
use super::common::simproc::{vehicle_file, SimProcess};
use super::floor::quantile;
use super::rig;
use std::process::Command;
use std::time::{Duration, Instant};

/// The console on `sim`'s devices in a played terminal, its control socket in `dir`.
struct Console {
    child: std::process::Child,
    term: Master,
    socket: std::path::PathBuf,
}

impl Console {
    fn start(dir: &std::path::Path, sim: &SimProcess) -> Console {
        let file = vehicle_file(dir, sim, "");
        let socket = dir.join("s14.sock");
        let mut cmd = Command::new(rig::adrive());
        cmd.arg("--config")
            .arg(&file)
            .args(["--listen", "127.0.0.1:0", "--log-dir"])
            .arg(dir.join("s14-logs"))
            .arg("--socket")
            .arg(&socket)
            .env("TERM", "xterm-256color")
            .env_remove("TMUX")
            .env_remove("STY");
        let (child, term) = Master::spawn(&mut cmd, 100, 30, true);
        let c = Console {
            child,
            term,
            socket,
        };
        let end = Instant::now() + Duration::from_secs(30);
        while !c.gate()["blockers"].as_array().is_some_and(Vec::is_empty) {
            assert!(Instant::now() < end, "the devices never all reported");
            std::thread::sleep(Duration::from_millis(100));
        }
        c
    }

    fn gate(&self) -> serde_json::Value {
        let out = Command::new(rig::adrive())
            .args(["ctl", "status", "--json", "--socket"])
            .arg(&self.socket)
            .output()
            .unwrap();
        serde_json::from_slice::<serde_json::Value>(&out.stdout)
            .map(|s| s["gate"].clone())
            .unwrap_or_default()
    }

    /// Keys, each after the frame that shows what it acts on had time to be drawn.
    fn keys(&mut self, k: &str) {
        self.term.write(k.as_bytes());
        std::thread::sleep(Duration::from_millis(250));
    }

    /// `E` `y` until engaged, then the brake released to 0.3 (seen at the device).
    fn engage_braking(&mut self, sim: &SimProcess) {
        loop {
            self.keys("E");
            self.keys("y");
            if self.gate()["engaged"] == true {
                break;
            }
        }
        let mark = sim.mark();
        self.keys("b");
        self.keys("\x150.3\r");
        sim.wait_after(mark, &["brake", "<-", "0.300"]);
    }
}

impl Drop for Console {
    fn drop(&mut self) {
        let _ = rig_kill(&self.child);
        let _ = self.child.wait();
    }
}

#[allow(unsafe_code)]
fn rig_kill(child: &std::process::Child) -> i32 {
    // SAFETY: kill(2) on our own child.
    unsafe { libc::kill(child.id() as i32, libc::SIGTERM) }
}

fn ms(us: f64) -> String {
    format!("{:.0} ms", us / 1000.0)
}

pub fn section14_terminal_stall(dir: &tempfile::TempDir, trials: usize, secs: f64) {
    println!(
        "\n== 14. A commanding console whose terminal stalls: stall → brake 1.000 at the device, {trials} stalls; what the check costs =="
    );
    let sim = SimProcess::start();
    let mut c = Console::start(dir.path(), &sim);
    let mut from_stall = Vec::new();
    let mut from_answer = Vec::new();
    let mut seed = 0x2545_f491_4f6c_dd1du64;
    // Trials whose vehicle something else stopped first (a device the loaded machine
    // starved past its deadline): not this check's figure, counted and said.
    let mut disturbed = 0;
    while from_stall.len() < trials {
        c.engage_braking(&sim);
        // A random phase of the 250 ms request period.
        seed ^= seed << 13;
        seed ^= seed >> 7;
        seed ^= seed << 17;
        std::thread::sleep(Duration::from_millis(seed % 250));
        let mark = sim.mark();
        let stalled = Instant::now();
        c.term.stop_reading();
        sim.wait_after(mark, &["brake", "<-", "1.000"]);
        let at = Instant::now();
        let last = c.term.last_answer();
        c.term.set(|p| p.reading = true);
        let why = c.gate()["reason"].as_str().unwrap_or("").to_string();
        if !why.contains("stopped answering") {
            disturbed += 1;
            assert!(
                disturbed <= trials,
                "the vehicle kept stopping for other reasons: {why}"
            );
            continue;
        }
        from_stall.push(at - stalled);
        if let Some(last) = last {
            from_answer.push(at.saturating_duration_since(last));
        }
    }
    from_stall.sort();
    from_answer.sort();
    if disturbed > 0 {
        println!("({disturbed} trials left out: the vehicle was stopped for another reason first)");
    }
    println!(
        "stall → brake 1.000 at the device: p50 {}  p99 {}  max {}",
        ms(quantile(&from_stall, 0.5)),
        ms(quantile(&from_stall, 0.99)),
        ms(quantile(&from_stall, 1.0))
    );
    println!(
        "last answer → brake 1.000 at the device (the bound is 1000 ms): p50 {}  p99 {}  max {}",
        ms(quantile(&from_answer, 0.5)),
        ms(quantile(&from_answer, 0.99)),
        ms(quantile(&from_answer, 1.0))
    );
    // What the check costs while commanding: the bytes of its requests and answers on
    // the link, and adrive's CPU commanding against watching.
    let window = Duration::from_secs_f64(secs);
    c.engage_braking(&sim);
    let (asked, answered) = (c.term.cursor_requests(), c.term.cursor_answers());
    let cpu = rig::cpu_time(c.child.id());
    std::thread::sleep(window);
    let cpu_commanding = (rig::cpu_time(c.child.id()) - cpu).as_secs_f64() / window.as_secs_f64();
    let asks = (c.term.cursor_requests() - asked) as f64 / window.as_secs_f64();
    let answers = (c.term.cursor_answers() - answered) as f64 / window.as_secs_f64();
    // `ESC[6n` out, `ESC[1;1R` back (a real cursor report is 6 to 10 bytes).
    let bytes = asks * 4.0 + answers * 6.0;
    c.keys(" ");
    let cpu = rig::cpu_time(c.child.id());
    std::thread::sleep(window);
    let cpu_watching = (rig::cpu_time(c.child.id()) - cpu).as_secs_f64() / window.as_secs_f64();
    println!(
        "the check while commanding: {asks:.1} requests/s, {bytes:.0} B/s on the link (requests and answers); adrive's CPU {:.1} % of a core commanding, {:.1} % watching",
        cpu_commanding * 100.0,
        cpu_watching * 100.0
    );
}
