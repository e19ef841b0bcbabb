//! `adrive characterize` on the real binary against the simulator: a steering whose
//! `[device.sim]` the run does not know (drawn at random within the limits) is measured,
//! every figure is checked against what was set, and the `sim.toml` it writes makes a
//! twin that measures the same. And a STOP mid-run ends it at once with the vehicle
//! in its safe state, nothing written.

mod common;

use adrive::record::read::Recording;
use common::headless::BIN;
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
    let out_lines: Vec<String> = said.try_iter().collect();
    let err_lines: Vec<String> = errors.try_iter().collect();
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
    let status = |socket: &Path| -> serde_json::Value {
        let o = output_within(
            Process::new(BIN)
                .args(["ctl", "status", "--json", "--socket"])
                .arg(socket),
        );
        serde_json::from_slice(&o.stdout).unwrap_or_default()
    };
    let end = Instant::now() + DEADLINE;
    loop {
        let s = status(&socket);
        let steer = s["devices"]
            .as_array()
            .and_then(|d| d.iter().find(|d| d["name"] == "steer"))
            .and_then(|d| d["readings"]["position"].as_f64());
        if s["gate"]["engaged"] == true && steer.is_some_and(|x| x.abs() > 0.1) {
            break;
        }
        assert!(
            Instant::now() < end,
            "characterize never got under way: {s}"
        );
        std::thread::sleep(Duration::from_millis(20));
    }
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
    let out_lines: Vec<String> = said.try_iter().collect();
    let err_lines: Vec<String> = errors.try_iter().collect();
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
