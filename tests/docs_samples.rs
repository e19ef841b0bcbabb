//! The guide's sample outputs are the real binary's: each block of README.md and
//! docs/*.md marked `<!-- sample NAME -->` is made here by running adrive as a user
//! would (a simulated drive recorded and watched, a vehicle file with a mistake, …),
//! and compared with the guide, every figure masked (times, counts, addresses, sizes:
//! each run of digits, with its unit). When the wording changes on purpose,
//!
//! ```sh
//! UPDATE_DOCS=1 cargo test --release --test docs_samples
//! ```
//!
//! rewrites the marked blocks from the real runs (review the diff). Every other block
//! of output — a fence with no language or `text` — must be marked
//! `<!-- illustrative -->`, and its text says that it is an example.

mod common;

use common::headless::with_network;
use common::simproc::{vehicle_file, SimProcess};
use common::{free_port, DEADLINE};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::{Command as Process, Output, Stdio};
use std::time::Instant;

const BIN: &str = env!("CARGO_BIN_EXE_adrive");

/// README.md and docs/*.md.
fn guide() -> Vec<PathBuf> {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let mut files = vec![root.join("README.md")];
    let mut docs: Vec<PathBuf> = std::fs::read_dir(root.join("docs"))
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|x| x == "md"))
        .collect();
    docs.sort();
    files.extend(docs);
    files
}

/// A fenced block: its line range (inside the fences), its info string, the marker
/// on the line before it.
struct Block {
    start: usize,
    end: usize,
    info: String,
    marker: Option<String>,
}

fn blocks(text: &str) -> Vec<Block> {
    let lines: Vec<&str> = text.lines().collect();
    let mut out = Vec::new();
    let mut i = 0;
    while i < lines.len() {
        if let Some(info) = lines[i].strip_prefix("```") {
            let close = (i + 1..lines.len())
                .find(|&j| lines[j].starts_with("```"))
                .expect("a closed fence");
            let marker = i
                .checked_sub(1)
                .and_then(|p| lines[p].trim().strip_prefix("<!--"))
                .and_then(|m| m.strip_suffix("-->"))
                .map(|m| m.trim().to_string());
            out.push(Block {
                start: i + 1,
                end: close,
                info: info.trim().to_string(),
                marker,
            });
            i = close + 1;
        } else {
            i += 1;
        }
    }
    out
}

/// `text` with every figure masked: a run of digits (with its decimals and a unit of
/// time after it) is `#`; runs of spaces are one (columns move with the figures).
fn mask(text: &str) -> String {
    let mut out = String::new();
    let mut chars = text.chars().peekable();
    while let Some(c) = chars.next() {
        if c.is_ascii_digit() {
            while chars
                .peek()
                .is_some_and(|c| c.is_ascii_digit() || *c == '.' || *c == ',')
            {
                chars.next();
            }
            for unit in ["µs", "ms", "s"] {
                let rest: String = chars.clone().take(unit.chars().count()).collect();
                let after = chars.clone().nth(unit.chars().count());
                if rest == unit && !after.is_some_and(char::is_alphanumeric) {
                    for _ in 0..unit.chars().count() {
                        chars.next();
                    }
                    break;
                }
            }
            out.push('#');
        } else if c == ' ' {
            while chars.peek() == Some(&' ') {
                chars.next();
            }
            out.push(' ');
        } else {
            out.push(c);
        }
    }
    out.lines()
        .map(str::trim_end)
        .collect::<Vec<_>>()
        .join("\n")
}

/// Each marked sample's text, from real runs.
fn generate() -> BTreeMap<&'static str, String> {
    let mut s = BTreeMap::new();
    drive(&mut s);
    replay_check(&mut s);
    exit_network(&mut s);
    cart_start(&mut s);
    config_errors(&mut s);
    s
}

/// The lines of `text` that `keep` picks, in order.
fn pick(text: &str, keep: impl Fn(&str) -> bool) -> Vec<String> {
    text.lines()
        .filter(|l| keep(l))
        .map(str::to_string)
        .collect()
}

/// A simulated Alice on `adrive sim`'s ports, recording, watched: an engage refused
/// while the e-stop is in pause, then a planner that engages and drives through a
/// stall and its recovery, and stops so that the watchdog disengages: `adrive watch`, `adrive send`,
/// the headless summary, `record info` and a headless replay of it.
fn drive(s: &mut BTreeMap<&'static str, String>) {
    let dir = common::tempdir("docs-drive");
    let mut sim = SimProcess::start();
    s.insert(
        "sim-ports",
        [
            sim_line(&sim.lines()[0], &dir),
            sim_line(&sim.lines()[1], &dir),
            "…".into(),
        ]
        .join("\n"),
    );
    let (listen, broadcast) = (
        format!("127.0.0.1:{}", free_port()),
        format!("127.0.0.1:{}", free_port()),
    );
    // On the tolerant Alice: the planner holds her engaged for seconds to make the
    // guide's samples, not to prove device timing.
    let file = common::tolerant(vehicle_file(dir.path(), &sim, ""));
    let text = std::fs::read_to_string(&file).unwrap();
    // The broadcast to `adrive watch` and to this test, which waits on the faults.
    let state = std::net::UdpSocket::bind("127.0.0.1:0").unwrap();
    state.set_read_timeout(Some(DEADLINE)).unwrap();
    let text = with_network(&text, &listen, &broadcast, "").replace(
        &format!("broadcast_to = [\"{broadcast}\"]"),
        &format!(
            "broadcast_to = [\"{broadcast}\", \"{}\"]",
            state.local_addr().unwrap()
        ),
    );
    std::fs::write(&file, text).unwrap();
    let faults = |what: &str, ok: &dyn Fn(&str) -> bool| {
        let end = Instant::now() + DEADLINE;
        let mut buf = vec![0u8; 65536];
        loop {
            assert!(Instant::now() < end, "no broadcast where {what}");
            let Ok(n) = state.recv(&mut buf) else {
                continue;
            };
            let v: serde_json::Value = serde_json::from_slice(&buf[..n]).unwrap();
            if ok(&v["supervisor"]["faults"].to_string()) {
                return;
            }
        }
    };
    let mut watch = common::Reaped(
        Process::new(BIN)
            .args(["watch", "--from", &broadcast])
            .stdout(Stdio::piped())
            .stderr(Stdio::null())
            .spawn()
            .unwrap(),
    );
    let watched = common::lines(watch.stdout.take().unwrap());
    let mut a = common::Reaped(
        Process::new(BIN)
            .args([
                "--config",
                "vehicle.toml",
                "--headless",
                "--record",
                "drive.mcap",
            ])
            .arg("--log-dir")
            .arg(dir.path().join("log"))
            .env("XDG_RUNTIME_DIR", dir.path())
            .current_dir(dir.path())
            .stdout(Stdio::piped())
            .stderr(Stdio::null())
            .spawn()
            .unwrap(),
    );
    let summary = common::lines(a.stdout.take().unwrap());
    let send = |args: &[&str]| -> Output {
        Process::new(BIN)
            .args(["send", "--to", &listen])
            .args(args)
            .output()
            .unwrap()
    };
    common::wait_for("adrive to listen", || {
        String::from_utf8_lossy(&send(&["gas", "0.2"]).stdout).contains("disengaged")
    });
    // Every device reporting, then the e-stop in pause: an engage is refused.
    let mut seen: Vec<String> = Vec::new();
    let mut until = |what: &str, ok: &dyn Fn(&str) -> bool| {
        let end = Instant::now() + DEADLINE;
        loop {
            let l = watched
                .recv_timeout(end.saturating_duration_since(Instant::now()))
                .unwrap_or_else(|_| panic!("adrive watch to show {what}"));
            let done = ok(&l);
            seen.push(l);
            if done {
                return;
            }
        }
    };
    until("every device reporting", &|l| {
        l.contains("estop run") && l.contains("rpm=") && !l.contains("rpm=-")
    });
    sim.say("estop pause");
    until("the e-stop in pause", &|l| l.contains("estop pause"));
    faults("the e-stop's fault", &|f| f.contains("estop_pause"));
    let refused = send(&["engage"]);
    assert!(
        String::from_utf8_lossy(&refused.stdout).contains("refused engage"),
        "{refused:?}"
    );
    sim.say("estop run");
    until("the e-stop back in run", &|l| l.contains("estop run"));
    faults("no fault", &|f| f == "[]");
    let planner = Process::new(BIN)
        .args(["send", "--to", &listen, "--rate", "20", "--count", "200"])
        .args(["engage", "trans", "drive", "accel", "0.3"])
        .stdout(Stdio::piped())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    sim.wait_for(&["gas", "<-", "0.300"]);
    let stalled = sim.mark();
    sim.say("stall");
    let (_, started) = sim.wait_after(stalled, &["trans", "<-", "start"]);
    sim.wait_after(started, &["trans", "<-", "drive"]);
    let out = planner.wait_with_output().unwrap();
    let replies = String::from_utf8_lossy(&out.stdout).to_string();
    // The engage, and the first `accel` refused while the gearbox shifts.
    let engaged = pick(&replies, |l| l.contains("ok engaged"));
    let shifting = pick(&replies, |l| l.contains("accel_while_shifting"));
    s.insert(
        "send-reply",
        [&engaged[..1], &shifting[..1]].concat().join("\n"),
    );
    let stopped = sim.mark();
    sim.wait_after(stopped, &["brake", "<-", "1.000"]);
    // The watch until the vehicle stands after the watchdog.
    until("the stop", &|l| l.starts_with("-- disengaged"));
    until("the vehicle standing", &|l| l.contains("speed=0.00"));
    common::stop(&mut watch);
    let at = |p: &str| seen.iter().rposition(|l| l.starts_with(p)).unwrap();
    let engaged = at("-- engaged");
    let driving = (engaged..seen.len())
        .find(|&i| seen[i].contains("trans drive/drive") && seen[i].contains("gas 0.30/0.3"))
        .expect("a line driving");
    let disengaged = at("-- disengaged");
    s.insert(
        "watch-engaged",
        [
            seen[engaged].clone(),
            seen[engaged + 1].clone(),
            seen[driving].clone(),
        ]
        .join("\n"),
    );
    s.insert(
        "watch-disengaged",
        [
            seen[disengaged].clone(),
            seen[disengaged + 1].clone(),
            seen.last().unwrap().clone(),
        ]
        .join("\n"),
    );
    common::signal(&a, libc::SIGTERM);
    assert_eq!(common::wait_exit(&mut a), Some(0));
    let summary: Vec<String> = summary.iter().collect();
    let table = summary
        .iter()
        .position(|l| l.starts_with("device "))
        .expect("the headless summary's table");
    s.insert("headless-summary", summary[table..table + 3].join("\n"));
    // record info, as a user runs it beside the file.
    let info = Process::new(BIN)
        .args(["record", "info", "drive.mcap"])
        .current_dir(dir.path())
        .output()
        .unwrap();
    let info = String::from_utf8_lossy(&info.stdout).to_string();
    let channels = [
        "/snapshot ",
        "/commands ",
        "/gas/command ",
        "/steer/reading ",
    ];
    // These channels in this order (a file lists them as they first came), then `…`.
    let mut lines = vec!["$ adrive record info drive.mcap".to_string()];
    for l in info.lines() {
        if !l.starts_with('/') {
            lines.push(l.to_string());
        } else if l.starts_with(channels[0]) {
            for c in channels {
                lines.extend(info.lines().find(|l| l.starts_with(c)).map(str::to_string));
            }
            lines.push("…".into());
        }
    }
    // Refusals by reason: which reasons a planner meets depends on timing.
    let lines: Vec<String> = lines
        .into_iter()
        .map(
            |l| match (l.starts_with("commands received"), l.find(" (")) {
                (true, Some(at)) => format!("{} (…)", &l[..at]),
                _ => l,
            },
        )
        .collect();
    s.insert("record-info", lines.join("\n"));
    let rx = std::net::UdpSocket::bind("127.0.0.1:0").unwrap();
    let to = rx.local_addr().unwrap().to_string();
    let replay = Process::new(BIN)
        .args([
            "replay",
            "drive.mcap",
            "--headless",
            "--speed",
            "32",
            "--broadcast",
            &to,
        ])
        .current_dir(dir.path())
        .stderr(Stdio::null())
        .output()
        .unwrap();
    let replay = String::from_utf8_lossy(&replay.stdout).replace(&to, "127.0.0.1:9000");
    s.insert(
        "replay-headless",
        pick(&replay, |l| {
            l.starts_with("replaying") || l.starts_with("sent ")
        })
        .join("\n"),
    );
    sim.stop();
}

/// `adrive replay --check` on a drive of the test corpus (`tests/drives/alice.mcap`, see
/// `tests/replay_check.rs`), beside its vehicle file and a copy whose steering is
/// narrowed, as a user runs it.
fn replay_check(s: &mut BTreeMap<&'static str, String>) {
    let dir = common::tempdir("docs-check");
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    std::fs::copy(
        root.join("tests/drives/alice.mcap"),
        dir.path().join("drive.mcap"),
    )
    .unwrap();
    let alice = std::fs::read_to_string(root.join("vehicles/alice.toml")).unwrap();
    std::fs::write(dir.path().join("vehicle.toml"), &alice).unwrap();
    std::fs::write(
        dir.path().join("narrow.toml"),
        alice.replacen("range = [-1.0, 1.0]", "range = [-0.4, 0.4]", 1),
    )
    .unwrap();
    let mut lines = Vec::new();
    for (vehicle, status) in [("vehicle.toml", 0), ("narrow.toml", 1)] {
        let out = Process::new(BIN)
            .args(["replay", "drive.mcap", "--check", vehicle])
            .current_dir(dir.path())
            .output()
            .unwrap();
        assert_eq!(out.status.code(), Some(status), "{out:?}");
        lines.push(format!("$ adrive replay drive.mcap --check {vehicle}"));
        lines.extend(
            String::from_utf8_lossy(&out.stdout)
                .lines()
                .map(str::to_string),
        );
    }
    s.insert("replay-check", lines.join("\n"));
}

/// One of `adrive sim`'s port lines, with the temporary directory as `/tmp`.
fn sim_line(line: &str, _dir: &tempfile::TempDir) -> String {
    let tmp = std::env::temp_dir().display().to_string();
    line.replace(tmp.trim_end_matches('/'), "/tmp")
}

/// A headless Alice sent a datagram that is no command and a command while she is
/// disengaged, then stopped: the summary's network line.
fn exit_network(s: &mut BTreeMap<&'static str, String>) {
    let dir = common::tempdir("docs-exit");
    let mut a = common::headless_piped(dir.path(), &[]);
    let out = common::lines(a.stdout.take().unwrap());
    let err = common::lines(a.stderr.take().unwrap());
    let listen = common::listen_address(&common::until(&err, "running headless"));
    assert!(common::reply_to(&listen, b"\xff\x00").starts_with("rejected: "));
    assert!(common::reply_to(&listen, b"steer 0.2").starts_with("rejected steer 0.2: disengaged"));
    common::signal(&a, libc::SIGTERM);
    assert_eq!(common::wait_exit(&mut a), Some(0));
    let line = common::to_the_end(&out)
        .into_iter()
        .find(|l| l.starts_with("network "))
        .expect("the summary's network line");
    s.insert("headless-network", line);
}

/// The cart, started: which interlock rules it has and which are off.
fn cart_start(s: &mut BTreeMap<&'static str, String>) {
    let a = common::headless::Adrive::start("docs-cart", include_str!("../vehicles/cart.toml"), "");
    let lines = pick(&a.startup.join("\n"), |l| {
        l.contains("interlock rules:") || l.contains(" is off: ")
    });
    s.insert(
        "cart-rules",
        lines
            .iter()
            // Without the time and the thread it was logged at.
            .map(|l| {
                let l = l
                    .split_once("Z ")
                    .map_or(l.as_str(), |(_, rest)| rest)
                    .trim();
                l.replacen(" main ", " ", 1)
            })
            .collect::<Vec<_>>()
            .join("\n"),
    );
}

/// The built-in Alice's file with one mistake each, as `adrive` refuses it.
fn config_errors(s: &mut BTreeMap<&'static str, String>) {
    let alice = adrive::config::ALICE_TOML;
    let dir = common::tempdir("docs-bad");
    let refuse = |from: &str, to: &str, nth: usize| -> String {
        let at = alice
            .match_indices(from)
            .nth(nth)
            .unwrap_or_else(|| panic!("alice.toml has {from:?} {nth} times"))
            .0;
        let bad = format!("{}{to}{}", &alice[..at], &alice[at + from.len()..]);
        std::fs::write(dir.path().join("bad.toml"), bad).unwrap();
        let out = Process::new(BIN)
            .args(["--config", "bad.toml", "--sim", "--headless"])
            .env("XDG_RUNTIME_DIR", dir.path())
            .current_dir(dir.path())
            .output()
            .unwrap();
        assert_eq!(out.status.code(), Some(2), "{out:?}");
        String::from_utf8_lossy(&out.stderr)
            .lines()
            .next()
            .unwrap()
            .to_string()
    };
    s.insert(
        "config-roles",
        refuse("brake = \"brake\"", "brake = \"gas\"", 0),
    );
    let errors = [
        refuse("driver = \"modbus\"", "driver = \"modbsu\"", 0),
        refuse("[[device]]", "[[devcie]]", 1),
        refuse("baud = 19200", "baud_rate = 19200", 0),
        refuse("reply_timeout = \"100ms\"", "reply_timeout = \"1000h\"", 2),
        refuse("name = \"gas\"", "name = \"steer\"", 0),
        refuse("steering = \"steer\"", "steering = \"wiper\"", 0),
        refuse("gear = \"trans\"", "gear = \"estop\"", 0),
        refuse(
            "codes = { park = 0, reverse = 1, neutral = 2, drive = 3 }",
            "codes = { park = 0, reverse = 1, neutral = 2 }",
            0,
        ),
        refuse("d = \"drive\"", "d = \"driev\"", 0),
    ];
    s.insert("config-errors", errors.join("\n"));
}

/// Every marked block is the real run's, figures masked; `UPDATE_DOCS=1` rewrites
/// them. Every other block of output is marked illustrative.
#[test]
fn the_guide_s_sample_outputs_are_the_real_binary_s() {
    let update = std::env::var_os("UPDATE_DOCS").is_some();
    let generated = generate();
    let mut used = Vec::new();
    let mut wrong = Vec::new();
    for path in guide() {
        let text = std::fs::read_to_string(&path).unwrap();
        let mut lines: Vec<String> = text.lines().map(str::to_string).collect();
        let name = path.file_name().unwrap().to_string_lossy().to_string();
        // From the end, so that a rewrite keeps the earlier blocks' lines.
        for b in blocks(&text).into_iter().rev() {
            let where_ = format!("{name}:{}", b.start);
            match b.marker.as_deref() {
                Some(m) if m.starts_with("sample ") => {
                    let key = m["sample ".len()..].trim();
                    let real = generated
                        .get(key)
                        .unwrap_or_else(|| panic!("{where_}: no sample named {key:?}"));
                    used.push(key.to_string());
                    let doc = lines[b.start..b.end].join("\n");
                    if mask(&doc) != mask(real) {
                        if update {
                            lines.splice(b.start..b.end, real.lines().map(str::to_string));
                        } else {
                            wrong.push(format!(
                                "{where_} (sample {key}): the guide says\n{doc}\n… the binary says\n{real}\n"
                            ));
                        }
                    }
                }
                Some("illustrative") => {}
                _ if b.info.is_empty() || b.info == "text" => wrong.push(format!(
                    "{where_}: a block of output with no marker: make it a sample \
                     (`<!-- sample NAME -->`, made in tests/docs_samples.rs) or mark it \
                     `<!-- illustrative -->` and say so in the text"
                )),
                _ => {}
            }
        }
        if update {
            let mut new = lines.join("\n");
            new.push('\n');
            if new != text {
                std::fs::write(&path, new).unwrap();
            }
        }
    }
    for key in generated.keys() {
        assert!(
            used.contains(&key.to_string()),
            "sample {key} is in no page"
        );
    }
    assert!(
        wrong.is_empty(),
        "{}\nrun `UPDATE_DOCS=1 cargo test --release --test docs_samples` to rewrite the \
         samples from the real runs, and review the diff",
        wrong.join("\n")
    );
}

#[test]
fn figures_are_masked_and_words_are_not() {
    assert_eq!(
        mask("   0.001s ok engaged  at 12.5ms, 310.6 kB"),
        " # ok engaged at #, # kB"
    );
    assert_ne!(mask("ok engaged"), mask("ok disengaged"));
    assert_eq!(mask("gas 0.30/0.27 |"), mask("gas 0.30/0.3 |"));
}
