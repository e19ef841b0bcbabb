//! `adrive characterize` on the real binary against the simulator: a steering whose
//! `[device.sim]` the run does not know (drawn at random within the limits) is measured,
//! every figure is checked against what was set, and the `sim.toml` it writes makes a
//! twin that measures the same. And a STOP mid-run ends it at once with the vehicle
//! in its safe state, nothing written; so does a precondition broken mid-run by a
//! driver's hand (the brake lifted, the gear lever moved), against `adrive sim` in a
//! process of its own.

mod common;

use adrive::record::read::Recording;
use common::headless::BIN;
use common::simproc::SimProcess;
use common::{lines, output_within, tempdir, until, wait_exit, Reaped, DEADLINE};
use std::path::Path;
use std::process::{Command as Process, Stdio};
use std::time::{Duration, Instant};

/// Alice's steering as the vehicle file's `[device.sim]` `sim` says (its
/// `[device.response]` left out: the run does not know the device in advance), in
/// Alice made tolerant of this shared machine's stalls as [`common::tolerant_alice`]
/// is: a stall of a few hundred ms rightly finds a device faulty and ends the run,
/// which is not what these tests are about.
fn alice_with_steering(sim: &str) -> String {
    let dir = tempdir("alice");
    let alice = std::fs::read_to_string(common::tolerant_alice(dir.path())).unwrap();
    let old = "[device.response]         # the real drive: full range a second\nrate = 1.0\n[device.sim]\nrate = 1.0                # full range a second\n";
    assert!(
        alice.contains(old),
        "Alice's steering as this test knows it"
    );
    alice.replace(old, &format!("{}\n", sim.trim_end()))
}

/// The set parameters, drawn from `seed` within the limits the procedures are made
/// for: (rate /s, lag s, deadband, backlash, delay s).
#[derive(Clone, Copy, Debug)]
struct Params {
    rate: f64,
    lag: f64,
    deadband: f64,
    backlash: f64,
    delay: f64,
}

fn draw(seed: u64) -> Params {
    let mut x = seed | 1;
    let mut u = |lo: f64, hi: f64| {
        x ^= x << 13;
        x ^= x >> 7;
        x ^= x << 17;
        let f = (x >> 11) as f64 / (1u64 << 53) as f64;
        // Rounded as a person writes them.
        ((lo + f * (hi - lo)) * 1e4).round() / 1e4
    };
    Params {
        rate: u(0.8, 2.0),
        lag: u(0.04, 0.12),
        deadband: u(0.02, 0.15),
        backlash: u(0.02, 0.15),
        delay: u(0.01, 0.2),
    }
}

fn sim_section(p: &Params) -> String {
    format!(
        "[device.sim]\nrate = {}\nlag = \"{}us\"\ndeadband = {}\nbacklash = {}\ndelay = \"{}us\"\n",
        p.rate,
        (p.lag * 1e6).round(),
        p.deadband,
        p.backlash,
        (p.delay * 1e6).round()
    )
}

/// The figures a run wrote: its summary, and its sim.toml's section.
struct Run {
    summary: serde_json::Value,
    sim: String,
    took: Duration,
}

fn characterize(dir: &Path, tag: &str, vehicle: &str) -> Run {
    characterize_with(dir, tag, vehicle, &[])
}

/// [`characterize`] with more arguments.
fn characterize_with(dir: &Path, tag: &str, vehicle: &str, extra: &[&str]) -> Run {
    let config = dir.join(format!("{tag}.toml"));
    std::fs::write(&config, vehicle).unwrap();
    let out = dir.join(tag);
    let started = Instant::now();
    let mut cmd = Process::new(BIN);
    cmd.args(["characterize", "steer", "--sim", "--yes", "--config"])
        .arg(&config)
        .arg("--out")
        .arg(&out)
        .arg("--socket")
        .arg(dir.join(format!("{tag}.sock")))
        .arg("--log-dir")
        .arg(dir.join("logs"))
        .args(extra)
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped());
    let mut child = Reaped(cmd.spawn().unwrap());
    let said = lines(child.0.stdout.take().unwrap());
    let errors = lines(child.0.stderr.take().unwrap());
    // A whole characterization takes tens of seconds: its own deadline.
    let end = Instant::now() + DEADLINE * 8;
    let code = loop {
        if let Some(s) = child.try_wait().unwrap() {
            break s.code();
        }
        assert!(
            Instant::now() < end,
            "characterize still ran after {:?}",
            DEADLINE * 8
        );
        std::thread::sleep(Duration::from_millis(50));
    };
    let took = started.elapsed();
    let out_lines: Vec<String> = common::to_the_end(&said);
    let err_lines: Vec<String> = common::to_the_end(&errors);
    assert_eq!(
        code,
        Some(0),
        "{}\n{}",
        out_lines.join("\n"),
        err_lines.join("\n")
    );
    assert!(
        out_lines
            .iter()
            .any(|l| l.contains("safe state acknowledged")),
        "{out_lines:?}"
    );
    for f in [
        "summary.json",
        "samples.csv",
        "sim.toml",
        "report.md",
        "run.svg",
        "map.svg",
    ] {
        assert!(out.join(f).is_file(), "{f} written");
    }
    // The report names each of its plots, and each is a well-formed SVG with its data.
    let report = std::fs::read_to_string(out.join("report.md")).unwrap();
    let samples = std::fs::read_to_string(out.join("samples.csv"))
        .unwrap()
        .lines()
        .count()
        - 1;
    // The step plots are there when the steps ran (all procedures, or `step` asked).
    let asked = extra
        .iter()
        .position(|a| *a == "--procedure")
        .map(|i| extra[i + 1]);
    let stepped = asked.is_none_or(|p| p.split(',').any(|p| p == "step"));
    for (plot, lines) in [
        ("run.svg", Some(vec![samples, samples])),
        ("steps-large.svg", None),
        ("steps-small.svg", None),
        ("map.svg", Some(vec![5, 5, 5])),
        ("delay.svg", Some(vec![])),
    ] {
        if plot.starts_with("steps") && !stepped {
            assert!(
                !report.contains(&format!("]({plot})")),
                "{plot} without steps"
            );
            continue;
        }
        assert!(
            report.contains(&format!("]({plot})")),
            "{plot} in report.md"
        );
        let svg = std::fs::read_to_string(out.join(plot)).unwrap();
        well_formed(&svg).unwrap_or_else(|e| panic!("{plot}: {e}\n{svg}"));
        let points = polylines(&svg);
        match lines {
            Some(n) => assert_eq!(points, n, "{plot}: one line per series, every point"),
            // Steps: 3 large (or 1 small) each way, a command and a reading each.
            None => assert_eq!(
                points.len(),
                if plot.contains("large") { 12 } else { 4 },
                "{plot}"
            ),
        }
    }
    let bars = std::fs::read_to_string(out.join("delay.svg"))
        .unwrap()
        .matches("<rect class=\"bar\"")
        .count();
    assert!(bars > 0, "the delay histogram has its buckets");
    let summary: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("summary.json")).unwrap()).unwrap();
    let sim = std::fs::read_to_string(out.join("sim.toml")).unwrap();
    Run { summary, sim, took }
}

/// The number of points of each polyline of `svg`.
fn polylines(svg: &str) -> Vec<usize> {
    svg.split("<polyline")
        .skip(1)
        .map(|l| {
            let pts = l
                .split("points=\"")
                .nth(1)
                .unwrap()
                .split('"')
                .next()
                .unwrap();
            pts.split_whitespace().count()
        })
        .collect()
}

/// Whether `xml` is well-formed as far as an SVG viewer cares: one root `<svg>`,
/// every element closed in order, every attribute quoted, no bare `<` or `&` in text.
fn well_formed(xml: &str) -> Result<(), String> {
    let mut open: Vec<&str> = Vec::new();
    let mut rest = xml.trim();
    if !rest.starts_with("<svg") {
        return Err("does not open with <svg".into());
    }
    let mut roots = 0;
    while !rest.is_empty() {
        let Some(lt) = rest.find('<') else {
            check_text(rest)?;
            break;
        };
        check_text(&rest[..lt])?;
        let gt = rest[lt..].find('>').ok_or("a tag never closed")? + lt;
        let tag = &rest[lt + 1..gt];
        if let Some(name) = tag.strip_prefix('/') {
            if open.pop() != Some(name.trim()) {
                return Err(format!("</{name}> closes what is not open"));
            }
        } else {
            if open.is_empty() {
                roots += 1;
            }
            let name = tag.split_whitespace().next().ok_or("an empty tag")?;
            if !tag.matches('"').count().is_multiple_of(2) || tag.contains('<') {
                return Err(format!("an unquoted attribute in <{tag}>"));
            }
            if !tag.ends_with('/') {
                open.push(name);
            }
        }
        rest = &rest[gt + 1..];
    }
    if !open.is_empty() || roots != 1 {
        return Err(format!("left open: {open:?}, roots: {roots}"));
    }
    Ok(())
}

fn check_text(text: &str) -> Result<(), String> {
    let mut t = text;
    while let Some(i) = t.find('&') {
        let end = t[i..].find(';').ok_or("a bare &")?;
        if !matches!(&t[i + 1..i + end], "amp" | "lt" | "gt" | "quot" | "apos") {
            return Err(format!("an unknown entity {}", &t[i..=i + end]));
        }
        t = &t[i + end + 1..];
    }
    Ok(())
}

fn figure(run: &Run, key: &str) -> f64 {
    run.summary[key]
        .as_f64()
        .unwrap_or_else(|| panic!("{key} in {}", run.summary))
}

/// `key = value` of sim.toml, a number or a duration in µs (as seconds).
fn sim_value(sim: &str, key: &str) -> f64 {
    let line = sim
        .lines()
        .find(|l| l.starts_with(&format!("{key} =")))
        .unwrap_or_else(|| panic!("{key} in\n{sim}"));
    let v = line.split('=').nth(1).unwrap().trim().trim_matches('"');
    match v.strip_suffix("us") {
        Some(us) => us.parse::<f64>().unwrap() * 1e-6,
        None => v.parse().unwrap(),
    }
}

fn within(what: &str, got: f64, want: f64, share: f64) {
    assert!(
        (got - want).abs() <= want.abs() * share,
        "{what}: {got} measured, {want} set (more than {}% apart)",
        share * 100.0
    );
}

fn delay_within(what: &str, got: f64, want: f64) {
    assert!(
        (got - want).abs() <= 0.005,
        "{what}: {:.2} ms measured, {:.2} ms set (more than 5 ms apart)",
        got * 1e3,
        want * 1e3
    );
}

/// Every figure against the parameters it must recover.
fn check(run: &Run, p: &Params, what: &str) {
    let s = &run.summary;
    eprintln!("{what}: set {p:?}\nmeasured {s}\n{}", run.sim);
    within(
        &format!("{what} rate_up"),
        figure(run, "rate_up"),
        p.rate,
        0.02,
    );
    within(
        &format!("{what} rate_down"),
        figure(run, "rate_down"),
        p.rate,
        0.02,
    );
    within(
        &format!("{what} deadband"),
        figure(run, "deadband"),
        p.deadband,
        0.02,
    );
    within(
        &format!("{what} backlash"),
        figure(run, "backlash"),
        p.backlash,
        0.02,
    );
    delay_within(
        &format!("{what} delay_ms"),
        figure(run, "delay_ms") / 1e3,
        p.delay,
    );
    within(
        &format!("{what} sim.toml lag"),
        sim_value(&run.sim, "lag"),
        p.lag,
        0.02,
    );
    within(&format!("{what} gain"), figure(run, "gain"), 1.0, 0.02);
    assert!(figure(run, "offset").abs() < 0.01, "{what} offset: {s}");
    assert!(
        figure(run, "overshoot_pct") < 1.0,
        "{what}: a lag does not overshoot: {s}"
    );
    assert!(s["map"].as_array().is_some_and(|m| m.len() == 5), "{s}");
    assert!(figure(run, "samples") > 1000.0, "{s}");
}

/// The incident this closes: a simulator tuned by guess. A steering with random
/// `[device.sim]` is measured and every figure matches what was set; the `sim.toml`
/// written makes a twin that measures the same.
#[test]
fn characterize_recovers_random_sim_parameters_and_its_twin_measures_the_same() {
    let seed = std::env::var("ADRIVE_SEED")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or_else(|| {
            std::time::SystemTime::now()
                .duration_since(std::time::UNIX_EPOCH)
                .unwrap()
                .as_nanos() as u64
        });
    let p = draw(seed);
    eprintln!("ADRIVE_SEED={seed}");
    let dir = tempdir("characterize");
    let first = characterize(dir.path(), "first", &alice_with_steering(&sim_section(&p)));
    eprintln!("a characterization took {:.1} s", first.took.as_secs_f64());
    check(&first, &p, "first");
    let body: String = first
        .sim
        .lines()
        .filter(|l| !l.starts_with('#'))
        .collect::<Vec<_>>()
        .join("\n");
    let twin = characterize(dir.path(), "twin", &alice_with_steering(&body));
    check(&twin, &p, "twin");
    for key in [
        "rate_up",
        "rate_down",
        "deadband",
        "backlash",
        "rise_ms",
        "settle_ms",
    ] {
        within(
            &format!("twin {key}"),
            figure(&twin, key),
            figure(&first, key),
            0.02,
        );
    }
    delay_within(
        "twin delay_ms",
        figure(&twin, "delay_ms") / 1e3,
        figure(&first, "delay_ms") / 1e3,
    );
}

/// Wait until the run is under way, as `adrive ctl status` on its socket shows it: the
/// bench commands the engaged vehicle and the steering has moved.
fn under_way(socket: &Path) {
    let end = Instant::now() + DEADLINE;
    loop {
        let o = output_within(
            Process::new(BIN)
                .args(["ctl", "status", "--json", "--socket"])
                .arg(socket),
        );
        let s: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap_or_default();
        let steer = s["devices"]
            .as_array()
            .and_then(|d| d.iter().find(|d| d["name"] == "steer"))
            .and_then(|d| d["readings"]["position"].as_f64());
        if s["gate"]["engaged"] == true && steer.is_some_and(|x| x.abs() > 0.1) {
            return;
        }
        assert!(
            Instant::now() < end,
            "characterize never got under way: {s}"
        );
        std::thread::sleep(Duration::from_millis(20));
    }
}

/// STOP while it steps the steering: it ends at once, disengaged into the safe state,
/// and writes nothing.
#[test]
fn stop_mid_run_ends_it_at_once_with_the_vehicle_safe() {
    let dir = tempdir("characterize-stop");
    let p = draw(7);
    let config = dir.path().join("v.toml");
    std::fs::write(&config, alice_with_steering(&sim_section(&p))).unwrap();
    let socket = dir.path().join("s.sock");
    let out = dir.path().join("out");
    let mut child = Reaped(
        Process::new(BIN)
            .args(["characterize", "steer", "--sim", "--yes", "--config"])
            .arg(&config)
            .arg("--out")
            .arg(&out)
            .arg("--socket")
            .arg(&socket)
            .arg("--log-dir")
            .arg(dir.path().join("logs"))
            .stdin(Stdio::null())
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .unwrap(),
    );
    let said = lines(child.0.stdout.take().unwrap());
    let errors = lines(child.0.stderr.take().unwrap());
    until(&said, "characterizing steer");
    // Under way: the bench commands the engaged vehicle and the steering has moved.
    under_way(&socket);
    let stopped = Instant::now();
    let o = output_within(
        Process::new(BIN)
            .args(["ctl", "stop", "--socket"])
            .arg(&socket),
    );
    // Its answer is `disengaged`, or the run ended on it before the answer went out.
    let answer =
        String::from_utf8_lossy(&o.stdout).to_string() + &String::from_utf8_lossy(&o.stderr);
    assert!(
        answer.contains("disengaged") || answer.contains("adrive is stopping"),
        "{o:?}"
    );
    let code = wait_exit(&mut child.0);
    let took = stopped.elapsed();
    let out_lines: Vec<String> = common::to_the_end(&said);
    let err_lines: Vec<String> = common::to_the_end(&errors);
    assert_eq!(code, Some(1), "{out_lines:?}\n{err_lines:?}");
    assert!(
        err_lines
            .iter()
            .any(|l| l.contains("characterize steer: the vehicle was disengaged")),
        "{err_lines:?}"
    );
    assert!(
        out_lines
            .iter()
            .any(|l| l.contains("safe state acknowledged") && !l.contains("NOT")),
        "{out_lines:?}"
    );
    assert!(
        !out.exists(),
        "nothing written for a run that did not finish"
    );
    // At once: well within a step of a run that takes tens of seconds.
    assert!(took < Duration::from_secs(5), "ended {took:?} after STOP");
}

/// A vehicle that cannot prove it stands still (no speed bound) is refused before
/// anything moves, and says why.
#[test]
fn a_vehicle_that_cannot_prove_it_stands_still_is_refused() {
    let dir = tempdir("characterize-unready");
    let vehicle =
        alice_with_steering(&sim_section(&draw(3))).replace("speed = \"obd.speed\"\n", "");
    let config = dir.path().join("v.toml");
    std::fs::write(&config, vehicle).unwrap();
    let o = output_within(
        Process::new(BIN)
            .args(["characterize", "steer", "--sim", "--yes", "--config"])
            .arg(&config)
            .arg("--out")
            .arg(dir.path().join("out"))
            .arg("--socket")
            .arg(dir.path().join("s.sock"))
            .arg("--log-dir")
            .arg(dir.path().join("logs")),
    );
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(1), "{err}");
    assert!(
        err.contains("not ready: no speed bound to prove the vehicle still"),
        "{err}"
    );
    assert!(!dir.path().join("out").exists());
}

/// `--record`: the run is recorded like any drive — every set point it commanded, as
/// the characterize source, accepted, and written to the steering, between its engage
/// and its `characterize done` — in a whole file `adrive replay` and every reader open.
#[test]
fn a_recorded_characterization_holds_its_commands() {
    let dir = tempdir("characterize-record");
    let file = dir.path().join("run.mcap");
    let run = characterize_with(
        dir.path(),
        "rec",
        &alice_with_steering(&sim_section(&draw(11))),
        &["--procedure", "sweep", "--record", file.to_str().unwrap()],
    );
    let rec = Recording::open(&file).unwrap();
    assert!(rec.complete && rec.cut.is_none(), "{:?}", rec.cut);
    let (msgs, _) = rec.json();
    let on = |topic: &str| -> Vec<serde_json::Value> {
        msgs.iter()
            .filter(|(t, _, _)| t == topic)
            .map(|(_, _, v)| v.clone())
            .collect()
    };
    let received: Vec<f64> = on("/commands")
        .iter()
        .filter(|c| c["source"] == "characterize" && c["device"] == "steer")
        .inspect(|c| assert_eq!(c["accepted"], true, "{c}"))
        .filter_map(|c| c["value"].as_f64())
        .collect();
    let written: Vec<f64> = on("/steer/command")
        .iter()
        .filter_map(|c| c["value"].as_f64())
        .collect();
    // Every point of the sweep's map was commanded and written.
    let map = run.summary["map"].as_array().expect("a map");
    for point in map {
        let c = point[0].as_f64().unwrap();
        assert!(
            received.iter().any(|v| (v - c).abs() < 1e-6),
            "{c} not among the recorded commands {received:?}"
        );
        assert!(
            written.iter().any(|v| (v - c).abs() < 1e-6),
            "{c} not written to the steering in the recording"
        );
    }
    let gate: Vec<String> = on("/gate")
        .iter()
        .map(|g| format!("{} {}", g["event"], g["reason"]))
        .collect();
    assert!(
        gate.iter().any(|g| g.starts_with("\"engaged\"")),
        "{gate:?}"
    );
    assert!(
        gate.iter()
            .any(|g| g.starts_with("\"disengaged\"") && g.contains("characterize done")),
        "{gate:?}"
    );
    // `adrive replay` takes it: `--check` decides its commands again, as they were.
    let o = output_within(
        Process::new(BIN)
            .arg("replay")
            .arg(&file)
            .arg("--check")
            .arg(dir.path().join("rec.toml")),
    );
    assert!(
        o.status.success(),
        "{}\n{}",
        String::from_utf8_lossy(&o.stdout),
        String::from_utf8_lossy(&o.stderr)
    );
}

/// `text` with each device's `port` pointing at the simulator's port of that device, in
/// the vehicle's order (as `adrive sim` prints them).
fn on_ports(text: &str, sim: &SimProcess) -> String {
    let mut paths = sim.paths.iter();
    text.lines()
        .map(|l| {
            if l.starts_with("port = ") {
                format!("port = \"{}\"\n", paths.next().expect("a port per device"))
            } else {
                format!("{l}\n")
            }
        })
        .collect()
}

/// What a run that a hand broke mid-run left.
struct Broken {
    code: Option<i32>,
    out_lines: Vec<String>,
    err_lines: Vec<String>,
    /// From the hand to the process's exit.
    took: Duration,
    /// The recording's messages: (topic, wall-clock ns, message).
    msgs: Vec<(String, u64, serde_json::Value)>,
    /// The wall-clock ns when the hand was typed into the simulator.
    hand_ns: u64,
    /// What the simulator printed after the hand.
    sim_after: Vec<String>,
    wrote: bool,
}

fn wall_ns() -> u64 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .unwrap()
        .as_nanos() as u64
}

/// `adrive sim` with `vehicle` in its own process, and `adrive characterize steer`
/// against its ports, recorded: once the steering moves under the bench's command,
/// `hand` is typed into the simulator, as a driver's hand acts on the vehicle.
fn broken_mid_run(tag: &str, vehicle: &str, hand: &str) -> Broken {
    let dir = tempdir(tag);
    let sim_file = dir.path().join("sim.toml");
    std::fs::write(&sim_file, vehicle).unwrap();
    let mut sim = SimProcess::start_with(&["--config", sim_file.to_str().unwrap()], 6);
    let config = dir.path().join("v.toml");
    std::fs::write(&config, on_ports(vehicle, &sim)).unwrap();
    let socket = dir.path().join("s.sock");
    let out = dir.path().join("out");
    let record = dir.path().join("run.mcap");
    let mut child = Reaped(
        Process::new(BIN)
            .args(["characterize", "steer", "--yes", "--config"])
            .arg(&config)
            .arg("--out")
            .arg(&out)
            .arg("--socket")
            .arg(&socket)
            .arg("--log-dir")
            .arg(dir.path().join("logs"))
            .arg("--record")
            .arg(&record)
            .stdin(Stdio::null())
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .unwrap(),
    );
    let said = lines(child.0.stdout.take().unwrap());
    let errors = lines(child.0.stderr.take().unwrap());
    until(&said, "characterizing steer");
    // Under way: the bench commands the engaged vehicle and the steering has moved.
    under_way(&socket);
    let mark = sim.mark();
    let hand_ns = wall_ns();
    let handed = Instant::now();
    sim.say(hand);
    let code = wait_exit(&mut child.0);
    let took = handed.elapsed();
    let rec = Recording::open(&record).unwrap();
    assert!(rec.complete, "{:?}", rec.cut);
    let (msgs, _) = rec.json();
    // The safe state's commands reach the simulator after the run ends.
    std::thread::sleep(Duration::from_millis(300));
    let sim_after = sim.lines()[mark..].to_vec();
    sim.stop();
    Broken {
        code,
        out_lines: common::to_the_end(&said),
        err_lines: common::to_the_end(&errors),
        took,
        msgs,
        hand_ns,
        sim_after,
        wrote: out.exists(),
    }
}

impl Broken {
    /// Ended as a STOP ends it: status 1, its cause in words on standard error and as
    /// the disengage's cause in the recording, the safe state acknowledged, nothing
    /// written. The time of the disengage (wall-clock ns).
    fn ended_by(&self, why: &str) -> u64 {
        let all = format!("{:?}\n{:?}", self.out_lines, self.err_lines);
        assert_eq!(self.code, Some(1), "{all}");
        assert!(
            self.err_lines.iter().any(|l| l.contains(&format!(
                "adrive: characterize steer: precondition broken: {why}"
            ))),
            "{all}"
        );
        assert!(
            self.out_lines
                .iter()
                .any(|l| l.contains("safe state acknowledged") && !l.contains("NOT")),
            "{all}"
        );
        assert!(!self.wrote, "nothing written for a run that did not finish");
        let (_, at, _) = self
            .msgs
            .iter()
            .find(|(t, _, m)| t == "/gate" && m["event"] == "disengaged")
            .unwrap_or_else(|| panic!("no disengage recorded: {all}"));
        let reason = self
            .msgs
            .iter()
            .filter(|(t, _, m)| t == "/gate" && m["event"] == "disengaged")
            .map(|(_, _, m)| m["reason"].as_str().unwrap_or_default().to_string())
            .collect::<Vec<_>>();
        assert_eq!(
            reason.first().map(String::as_str),
            Some(format!("disengaged: characterize ended: precondition broken: {why}").as_str()),
            "the first disengage is the bench's own, for its cause: {reason:?}"
        );
        *at
    }

    /// The first reading of `device` after the hand whose `field` satisfies `f` (ns).
    fn first_reading(&self, device: &str, f: impl Fn(&serde_json::Value) -> bool) -> u64 {
        self.msgs
            .iter()
            .find(|(t, at, m)| *t == format!("/{device}/reading") && *at > self.hand_ns && f(m))
            .map(|(_, at, _)| *at)
            .unwrap_or_else(|| panic!("no such reading of {device} recorded"))
    }

    /// The simulator received `command` for `device` after the hand.
    fn received(&self, device: &str, command: &str) -> bool {
        self.sim_after.iter().any(|l| {
            let w: Vec<&str> = l.split_whitespace().collect();
            w.get(1) == Some(&device) && w.get(2) == Some(&"<-") && w.get(3) == Some(&command)
        })
    }
}

/// How soon after the reading that shows a precondition broken the run lets go: it
/// checks at every turn (a millisecond), so a few turns on a loaded machine.
const AT_THE_SAMPLE: Duration = Duration::from_millis(100);

/// A driver's foot lifts the brake while the steering is characterized. No command
/// changed, so only the brake's reading shows it: the run ends at the first reading
/// below the rules' shift brake, and the brake is commanded full again (the safe
/// state). The brake's override detection is made slow here (its `override_time` the
/// longest allowed, 2 s), so that what ends the run is the bench's own check rather than
/// the supervisor's override, which would end it too, later.
#[test]
fn a_brake_released_mid_run_ends_it_at_the_first_reading_with_the_vehicle_safe() {
    let held = "lag = \"80ms\"\n[device.sim]\nlag = \"80ms\"\nwatchdog = \"1s\"           # the actuator's own watchdog: full brake";
    let vehicle = alice_with_steering(&sim_section(&draw(5)));
    assert!(
        vehicle.contains(held),
        "Alice's brake as this test knows it"
    );
    let vehicle = vehicle.replace(held, &format!("override_time = \"2s\"\n{held}"));
    let run = broken_mid_run("characterize-brake", &vehicle, "override brake 0");
    let disengaged = run.ended_by("the brake is not held");
    let released = run.first_reading("brake", |m| m["position"].as_f64().is_some_and(|x| x < 0.3));
    let after = Duration::from_nanos(disengaged.saturating_sub(released));
    assert!(
        disengaged >= released && after < AT_THE_SAMPLE,
        "let go {after:?} after the brake read released"
    );
    // The hand moves the brake at 2 ranges a second: 0.35 s to below 0.3, then at most
    // a status period (100 ms) until a reading shows it.
    let from_hand = Duration::from_nanos(disengaged.saturating_sub(run.hand_ns));
    assert!(
        from_hand < Duration::from_millis(350 + 100) + AT_THE_SAMPLE * 5,
        "let go {from_hand:?} after the hand"
    );
    assert!(
        run.took < Duration::from_secs(5),
        "exited {:?} after the hand",
        run.took
    );
    assert!(
        run.received("brake", "1.000") && run.received("gas", "0.000"),
        "the safe state at the devices: {:?}",
        run.sim_after
    );
}

/// A driver's hand moves the gear lever to drive while the steering is characterized:
/// the run ends at the first reading of the gearbox out of park, in the safe state.
#[test]
fn the_gear_moved_mid_run_ends_it_at_the_first_reading_with_the_vehicle_safe() {
    let vehicle = alice_with_steering(&sim_section(&draw(6)));
    let run = broken_mid_run("characterize-gear", &vehicle, "lever trans drive");
    let disengaged = run.ended_by("the gearbox is not in park");
    let moved = run.first_reading("trans", |m| m["state"] == "drive");
    let after = Duration::from_nanos(disengaged.saturating_sub(moved));
    assert!(
        disengaged >= moved && after < AT_THE_SAMPLE,
        "let go {after:?} after the gearbox read drive"
    );
    // At once in drive, then at most a status period (250 ms) until a reading shows it.
    let from_hand = Duration::from_nanos(disengaged.saturating_sub(run.hand_ns));
    assert!(
        from_hand < Duration::from_millis(250) + AT_THE_SAMPLE * 5,
        "let go {from_hand:?} after the hand"
    );
    assert!(
        run.took < Duration::from_secs(5),
        "exited {:?} after the hand",
        run.took
    );
    assert!(
        run.received("brake", "1.000") && run.received("gas", "0.000"),
        "the safe state at the devices: {:?}",
        run.sim_after
    );
    assert!(
        !run.sim_after.iter().any(|l| l.contains("trans <-")),
        "the gear is the driver's: adrive does not shift it back: {:?}",
        run.sim_after
    );
}

/// A run of `adrive characterize DEVICE --sim` on `vehicle` that must succeed: what it
/// wrote and printed.
struct Done {
    summary: serde_json::Value,
    sim: String,
    report: String,
    out: std::path::PathBuf,
    out_lines: Vec<String>,
    record: std::path::PathBuf,
}

fn characterize_device(dir: &Path, device: &str, vehicle: &str, extra: &[&str]) -> Done {
    let config = dir.join(format!("{device}.toml"));
    std::fs::write(&config, vehicle).unwrap();
    let out = dir.join(format!("{device}-out"));
    let record = dir.join(format!("{device}.mcap"));
    let mut child = Reaped(
        Process::new(BIN)
            .args(["characterize", device, "--sim", "--config"])
            .arg(&config)
            .arg("--out")
            .arg(&out)
            .arg("--socket")
            .arg(dir.join(format!("{device}.sock")))
            .arg("--log-dir")
            .arg(dir.join("logs"))
            .arg("--record")
            .arg(&record)
            .args(extra)
            .stdin(Stdio::null())
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .unwrap(),
    );
    let said = lines(child.0.stdout.take().unwrap());
    let errors = lines(child.0.stderr.take().unwrap());
    let end = Instant::now() + DEADLINE * 8;
    let code = loop {
        if let Some(s) = child.try_wait().unwrap() {
            break s.code();
        }
        assert!(Instant::now() < end, "characterize still ran");
        std::thread::sleep(Duration::from_millis(50));
    };
    let out_lines: Vec<String> = common::to_the_end(&said);
    let err_lines: Vec<String> = common::to_the_end(&errors);
    assert_eq!(code, Some(0), "{out_lines:?}\n{err_lines:?}");
    let read = |f: &str| std::fs::read_to_string(out.join(f)).unwrap();
    Done {
        summary: serde_json::from_str(&read("summary.json")).unwrap(),
        sim: read("sim.toml"),
        report: read("report.md"),
        out,
        out_lines,
        record,
    }
}

/// A time within 5 ms or 2 % of what was set, whichever is more.
fn time_within(what: &str, got: f64, want: f64) {
    assert!(
        (got - want).abs() <= (want.abs() * 0.02).max(0.005),
        "{what}: {:.2} ms measured, {:.2} ms set",
        got * 1e3,
        want * 1e3
    );
}

/// A gearbox whose shift time the run does not know (drawn at random) is timed
/// transition by transition: every ordered pair of its four states, five times each;
/// the shift time comes back within 5 ms or 2 %, each transition's median within half
/// the interval between readings of it, the neutral it passes through is named, and it
/// ends in park, where it began, the vehicle let go in its safe state.
#[test]
fn a_gearbox_s_every_transition_is_timed_and_its_shift_time_recovered() {
    let seed = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .unwrap()
        .as_nanos() as u64;
    let mut x = seed | 1;
    x ^= x << 13;
    x ^= x >> 7;
    x ^= x << 17;
    let settle_ms = 400 + (x % 600);
    eprintln!("shift time {settle_ms} ms");
    let dir = tempdir("characterize-gear");
    let shipped = "settle = \"600ms\"";
    let vehicle = alice_with_steering(&sim_section(&draw(9)));
    assert!(
        vehicle.contains(shipped),
        "Alice's gearbox as this test knows it"
    );
    let vehicle = vehicle.replace(shipped, &format!("settle = \"{settle_ms}ms\""));
    let run = characterize_device(dir.path(), "trans", &vehicle, &["--yes"]);
    let s = &run.summary;
    eprintln!("{s}\n{}", run.sim);
    assert_eq!(s["device"], "trans");
    assert_eq!(s["kind"], "state");
    assert!(s["samples"].as_u64().unwrap() > 100, "{s}");
    let transitions = s["transitions"].as_array().unwrap();
    let states = ["park", "reverse", "neutral", "drive"];
    let mut pairs: Vec<(String, String)> = Vec::new();
    for t in transitions {
        let (from, to) = (t["from"].as_str().unwrap(), t["to"].as_str().unwrap());
        assert!(
            states.contains(&from) && states.contains(&to) && from != to,
            "{t}"
        );
        pairs.push((from.into(), to.into()));
        assert_eq!(t["n"], 5, "{t}");
        let (median, lo, hi) = (
            t["ms_median"].as_f64().unwrap(),
            t["ms_min"].as_f64().unwrap(),
            t["ms_max"].as_f64().unwrap(),
        );
        assert!(lo <= median && median <= hi, "{t}");
        // A reading every 25 ms at the gearbox's 9600 baud, 50 ms when a resend's
        // transaction comes between two: each time is good to half of that.
        let want = if to == "neutral" {
            0.0
        } else {
            settle_ms as f64
        };
        assert!(
            (median - want).abs() <= 25.0,
            "{from} → {to}: {median} ms, {want} ms set"
        );
    }
    pairs.sort();
    pairs.dedup();
    assert_eq!(pairs.len(), 12, "every ordered pair once: {transitions:?}");
    time_within(
        "sim.toml settle",
        sim_value(&run.sim, "settle"),
        settle_ms as f64 / 1e3,
    );
    assert!(run.sim.contains("transit = \"neutral\""), "{}", run.sim);
    assert!(run.report.contains("| park | reverse |"), "{}", run.report);
    assert!(run.report.contains("](run.svg)"));
    well_formed(&std::fs::read_to_string(run.out.join("run.svg")).unwrap()).unwrap();
    assert!(
        run.out_lines
            .iter()
            .any(|l| l.contains("trans at park; safe state acknowledged")),
        "it ends where it began: {:?}",
        run.out_lines
    );
    // Every shift it asked for went through the rules and was taken: stopped, the brake
    // held.
    let rec = Recording::open(&run.record).unwrap();
    let (msgs, _) = rec.json();
    let asked: Vec<&serde_json::Value> = msgs
        .iter()
        .filter(|(t, _, m)| t == "/commands" && m["source"] == "characterize")
        .map(|(_, _, m)| m)
        .collect();
    assert!(asked.len() >= 60, "{}", asked.len());
    assert!(asked.iter().all(|m| m["accepted"] == true), "{asked:?}");
}

/// A sensor is listened to: its update rate and each reading's noise. The OBD-II
/// sensor with its rpm made noisy by an amount the run does not know gives it back
/// within 10 %; and nothing was commanded — no ask reached the intake, the vehicle was
/// never engaged — so it needs neither `--yes` nor a vehicle held still.
#[test]
fn a_sensor_s_update_rate_and_noise_are_measured_without_commanding_anything() {
    let seed = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .unwrap()
        .as_nanos() as u64;
    let noise = 20.0 + (seed % 8000) as f64 / 100.0;
    eprintln!("rpm noise {noise}");
    let dir = tempdir("characterize-sensor");
    // The OBD-II sensor is Alice's last device: its `[device.sim]` goes at the end.
    let vehicle = format!(
        "{}\n[device.sim]\nreadings = {{ rpm = {{ value = 1500.0, noise = {noise} }} }}\n",
        alice_with_steering(&sim_section(&draw(10)))
    );
    // No speed bound: a vehicle that could not prove it stands still is no matter here.
    let vehicle = vehicle.replace("speed = \"obd.speed\"\n", "");
    let run = characterize_device(dir.path(), "obd", &vehicle, &[]);
    let s = &run.summary;
    eprintln!("{s}\n{}", run.sim);
    assert_eq!(s["device"], "obd");
    assert_eq!(s["kind"], "sensor");
    let samples = s["samples"].as_u64().unwrap();
    assert!(samples >= 500, "{s}");
    within(
        "rpm noise",
        s["noise"]["rpm"]["sd"].as_f64().unwrap(),
        noise,
        0.10,
    );
    let (lo, hi) = (
        s["noise"]["rpm"]["min"].as_f64().unwrap(),
        s["noise"]["rpm"]["max"].as_f64().unwrap(),
    );
    assert!(lo < 1500.0 - noise && hi > 1500.0 + noise, "{s}");
    assert_eq!(
        s["noise"]["coolant"]["sd"], 0.0,
        "a constant reading has none: {s}"
    );
    // The rate: its readings over the time they took, as the CSV's times say.
    let csv = std::fs::read_to_string(run.out.join("samples.csv")).unwrap();
    let times: Vec<f64> = csv
        .lines()
        .skip(1)
        .map(|l| l.split(',').next().unwrap().parse().unwrap())
        .collect();
    assert_eq!(times.len() as u64, samples);
    let rate = (times.len() - 1) as f64 / (times[times.len() - 1] - times[0]);
    let hz = s["update_hz"].as_f64().unwrap();
    assert!(
        hz >= rate * 0.98 && hz > 1.0,
        "{hz} Hz, {rate} Hz from the samples"
    );
    assert!(
        run.sim.contains("readings.rpm = { value = 1") && run.sim.contains("noise = "),
        "{}",
        run.sim
    );
    assert!(run.report.contains("](rpm.svg)"), "{}", run.report);
    // Nothing commanded: the intake heard no ask, the gate never engaged.
    let rec = Recording::open(&run.record).unwrap();
    let (msgs, _) = rec.json();
    let asks: Vec<_> = msgs.iter().filter(|(t, _, _)| t == "/commands").collect();
    assert!(asks.is_empty(), "asks: {asks:?}");
    let engaged: Vec<_> = msgs
        .iter()
        .filter(|(t, _, m)| t == "/gate" && m["event"] == "engaged")
        .collect();
    assert!(engaged.is_empty(), "{engaged:?}");
    assert!(
        msgs.iter().filter(|(t, _, _)| t == "/obd/reading").count() as u64 >= samples,
        "the readings are in the recording"
    );
    // Its last word says it was listened to (it read `obd at ?`).
    assert!(
        run.out_lines
            .iter()
            .any(|l| l == "obd listened to; safe state acknowledged"),
        "{:?}",
        run.out_lines
    );
}

/// The bench commands under the planners' watchdog: on a vehicle whose
/// `watchdog_timeout` (90 ms) is shorter than the run's usual resend (100 ms), it
/// resends often enough to keep it fed, and the run ends as it should, not tripped at
/// the first move.
#[test]
fn a_watchdog_shorter_than_the_resend_is_kept_fed() {
    let dir = tempdir("characterize-watchdog");
    let shipped = "watchdog_timeout = \"500ms\"";
    let vehicle = alice_with_steering(&sim_section(&draw(21)));
    assert!(
        vehicle.contains(shipped),
        "Alice's watchdog as this test knows it"
    );
    let vehicle = vehicle.replace(shipped, "watchdog_timeout = \"90ms\"");
    let run = characterize_device(
        dir.path(),
        "steer",
        &vehicle,
        &["--yes", "--procedure", "rate"],
    );
    assert!(
        run.summary["rate_up"].as_f64().unwrap() > 0.0,
        "{}",
        run.summary
    );
    let rec = Recording::open(&run.record).unwrap();
    let (msgs, _) = rec.json();
    let sent: Vec<u64> = msgs
        .iter()
        .filter(|(t, _, m)| t == "/commands" && m["source"] == "characterize")
        .map(|(_, at, _)| *at)
        .collect();
    assert!(sent.len() > 50, "{}", sent.len());
    let longest = sent.windows(2).map(|w| w[1] - w[0]).max().unwrap();
    assert!(
        longest < 90_000_000,
        "{} ms between two",
        longest / 1_000_000
    );
}

/// A steering with no deadband is measured as having none. The search halves its step
/// until the readings cannot show a move that small; a step there, seen not to move
/// it, is no deadband — the figure says how far below it is known to be, and the twin's
/// `sim.toml` gets none (a deadband at the readings' floor was written there once).
#[test]
fn a_device_without_a_deadband_is_measured_as_having_none() {
    let dir = tempdir("characterize-no-deadband");
    let p = Params {
        deadband: 0.0,
        ..draw(33)
    };
    let run = characterize_device(
        dir.path(),
        "steer",
        &alice_with_steering(&sim_section(&p)),
        &["--yes", "--procedure", "deadband"],
    );
    assert_eq!(run.summary["deadband"], 0.0, "{}", run.summary);
    // Steering's span is 2: its readings resolve moves past 4e-4 of it.
    let below = run.summary["deadband_below"].as_f64().unwrap();
    assert!(below > 0.0 && below <= 2.0 * 8e-4, "{}", run.summary);
    assert!(!run.sim.contains("deadband"), "{}", run.sim);
    assert!(
        run.report.contains(&format!("| deadband | below {below} ")),
        "{}",
        run.report
    );
}

/// `--range` and `--resolution`: the sweep covers the middle of the part asked for at
/// the spacing asked for, every point inside it, and the device ends where it was
/// found, outside that part; a range outside the device's, or a resolution finer than a
/// thousandth of it, is refused before anything moves.
#[test]
fn a_part_of_the_range_is_swept_at_the_resolution_asked_and_the_rest_refused() {
    let dir = tempdir("characterize-range");
    let vehicle = alice_with_steering(&sim_section(&draw(12)));
    let run = characterize_device(
        dir.path(),
        "steer",
        &vehicle,
        &[
            "--yes",
            "--procedure",
            "sweep",
            "--range",
            "0.2,0.8",
            "--resolution",
            "0.06",
        ],
    );
    let map = run.summary["map"].as_array().unwrap();
    // The middle 60 % of 0.2 … 0.8 (0.36 wide) every 0.06: seven points.
    let commanded: Vec<f64> = map.iter().map(|p| p[0].as_f64().unwrap()).collect();
    assert_eq!(commanded.len(), 7, "{commanded:?}");
    for (i, c) in commanded.iter().enumerate() {
        let want = 0.32 + 0.06 * i as f64;
        assert!((c - want).abs() < 1e-6, "{commanded:?}");
    }
    // Found at 0, outside the part swept: back there at the end.
    assert!(
        run.out_lines
            .iter()
            .any(|l| l.starts_with("steer at ") && l.contains("safe state acknowledged")),
        "{:?}",
        run.out_lines
    );
    let word = run
        .out_lines
        .iter()
        .find_map(|l| l.strip_prefix("steer at ")?.split(';').next())
        .unwrap();
    // Written as every reading is (three decimals), not as the float happens to print
    // (it read `steer at 0.24230000000000002`).
    assert!(
        word.split_once('.').is_some_and(|(_, d)| d.len() == 3),
        "{word:?}"
    );
    let at: f64 = word.parse().unwrap();
    assert!(at.abs() < 0.2, "ended at {at}, found at 0");
    // Every set point it asked for stayed inside the part, but the last: home.
    let rec = Recording::open(&run.record).unwrap();
    let (msgs, _) = rec.json();
    let asked: Vec<f64> = msgs
        .iter()
        .filter(|(t, _, m)| t == "/commands" && m["source"] == "characterize")
        .filter_map(|(_, _, m)| m["value"].as_f64())
        .collect();
    let first_home = asked.iter().position(|v| v.abs() < 1e-3).unwrap();
    assert!(
        asked[..first_home].iter().all(|v| (0.2..=0.8).contains(v))
            && asked[first_home..].iter().all(|v| v.abs() < 1e-3),
        "inside the part, then home: {asked:?}"
    );

    for (args, says) in [
        (
            &["--range", "-2,0.5"][..],
            "steer: --range -2,0.5: expected LO,HI with LO < HI inside the device's range -1 … 1",
        ),
        (
            &["--range", "0.5,0.2"][..],
            "expected LO,HI with LO < HI inside the device's range",
        ),
        (
            &["--resolution", "0.0001"][..],
            "--resolution 0.0001: expected a step from 0.002 to 0.4",
        ),
    ] {
        let o = output_within(
            Process::new(BIN)
                .args(["characterize", "steer", "--sim", "--yes", "--config"])
                .arg(dir.path().join("steer.toml"))
                .arg("--out")
                .arg(dir.path().join("refused"))
                .arg("--socket")
                .arg(dir.path().join("r.sock"))
                .arg("--log-dir")
                .arg(dir.path().join("logs"))
                .args(args),
        );
        let err = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(2), "{args:?}: {err}");
        assert!(err.contains(says), "{args:?}: {err}");
        assert!(!dir.path().join("refused").exists());
    }
}
