//! What a characterization leaves in its directory: `summary.json` (one object of its
//! figures), `samples.csv` (every reading with the command in force), `sim.toml` (the
//! `[device.sim]` that makes the simulator behave like the measured device) and
//! `report.md` (the figures in tables, and the plots as SVG: the run, the step
//! responses, the sweep's hysteresis loop and the command path's delay histogram).

use super::{analyze, Deadband, Figures};
use analyze::StepFigures;
use std::fmt::Write as _;
use std::path::Path;

/// Rounded to 4 significant digits (for people and for a vehicle file).
pub(super) fn sig(x: f64) -> f64 {
    if x == 0.0 || !x.is_finite() {
        return x;
    }
    let k = 10f64.powi(3 - x.abs().log10().floor() as i32);
    (x * k).round() / k
}

/// `summary.json`'s object.
pub(crate) fn summary(f: &Figures) -> serde_json::Value {
    let ms = |s: Option<f64>| s.map(|x| sig(x * 1000.0));
    serde_json::json!({
        "device": f.device,
        "rate_up": f.rate_up().map(sig),
        "rate_down": f.rate_down().map(sig),
        "delay_ms": ms(f.delay()),
        "deadband": f.deadband.map(|d| sig(d.value())),
        "deadband_below": match f.deadband {
            Some(Deadband::Below(d)) => Some(sig(d)),
            _ => None,
        },
        "backlash": f.backlash.map(sig),
        "rise_ms": ms(f.rise()),
        "overshoot_pct": f.overshoot_pct().map(sig),
        "settle_ms": ms(f.settle()),
        "gain": f.gain_offset.map(|g| sig(g.0)),
        "offset": f.gain_offset.map(|g| sig(g.1)),
        "noise": f.noise.map(sig),
        "samples": f.samples.len(),
        "map": f.map.iter().map(|p| [sig(p[0]), sig(p[1])]).collect::<Vec<_>>(),
    })
}

/// `sim.toml`: the `[device.sim]` section of what was measured.
pub(crate) fn sim_toml(f: &Figures) -> String {
    let mut out = format!(
        "# {}: measured by adrive characterize in {:.0} s\n[device.sim]\n",
        f.device, f.took
    );
    let rate = match (f.rate_up(), f.rate_down()) {
        (Some(u), Some(d)) => Some((u + d) / 2.0),
        (u, d) => u.or(d),
    };
    if let Some(r) = rate {
        let _ = writeln!(out, "rate = {}", sig(r));
    }
    if let Some(l) = f.lag() {
        let _ = writeln!(out, "lag = \"{}us\"", (l * 1e6).round());
    }
    if let Some(d) = f.deadband.map(Deadband::value).filter(|d| *d > 0.0) {
        let _ = writeln!(out, "deadband = {}", sig(d));
    }
    if let Some(b) = f.backlash.filter(|b| *b > 0.0) {
        let _ = writeln!(out, "backlash = {}", sig(b));
    }
    if let Some(d) = f.delay().filter(|d| *d > 0.0) {
        let _ = writeln!(out, "delay = \"{}us\"", (d * 1e6).round());
    }
    out
}

/// The samples as CSV: `t_s,commanded,measured`.
pub(crate) fn samples_csv(f: &Figures) -> String {
    let mut out = String::from("t_s,commanded,measured\n");
    for s in &f.samples {
        let _ = writeln!(out, "{:.6},{},{}", s.t, s.commanded, s.measured);
    }
    out
}

/// `text` safe inside an SVG's text or attribute (units come from a vehicle file).
fn esc(text: &str) -> String {
    text.replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
        .replace('"', "&quot;")
}

/// The colours of the plots: the command, and the measured position moving up, down.
pub(super) const COMMAND: &str = "#999";
pub(super) const UP: &str = "#1f5fbf";
pub(super) const DOWN: &str = "#d9730d";

/// A plot's frame: its size, and what it shows on each axis.
pub(super) struct Frame {
    pub x_label: String,
    pub y_label: String,
    /// (colour, what it shows) for each kind of line.
    pub legend: Vec<(&'static str, String)>,
}

const W: f64 = 640.0;
const H: f64 = 240.0;
const PAD: f64 = 30.0;

/// The extent of `points`: (x0, x1, y0, y1).
fn extent<'a>(points: impl Iterator<Item = &'a (f64, f64)>) -> (f64, f64, f64, f64) {
    points.fold(
        (
            f64::INFINITY,
            f64::NEG_INFINITY,
            f64::INFINITY,
            f64::NEG_INFINITY,
        ),
        |(a, b, c, d), &(x, y)| (a.min(x), b.max(x), c.min(y), d.max(y)),
    )
}

/// The SVG's opening (size, background, axis labels with the extent, legend).
fn open(frame: &Frame, (x0, x1, y0, y1): (f64, f64, f64, f64)) -> String {
    let mut out = format!(
        "<svg xmlns=\"http://www.w3.org/2000/svg\" width=\"{W}\" height=\"{H}\" font-size=\"11\">\n\
         <rect width=\"{W}\" height=\"{H}\" fill=\"white\" stroke=\"#ccc\"/>\n\
         <text x=\"{PAD}\" y=\"14\">{} ({y0:.3} … {y1:.3})</text>\n\
         <text x=\"{}\" y=\"{}\" text-anchor=\"end\">{} ({x0:.2} … {x1:.2})</text>\n",
        esc(&frame.y_label),
        W - PAD,
        H - 8.0,
        esc(&frame.x_label),
    );
    for (i, (colour, what)) in frame.legend.iter().enumerate() {
        let _ = writeln!(
            out,
            "<text x=\"{}\" y=\"{}\" text-anchor=\"end\" fill=\"{colour}\">{}</text>",
            W - PAD,
            14.0 + 12.0 * i as f64,
            esc(what)
        );
    }
    out
}

/// A small SVG of `series` (each a colour and its points, one polyline each), x and y
/// scaled to fit.
pub(super) fn svg(series: &[(&str, Vec<(f64, f64)>)], frame: &Frame) -> String {
    let (x0, x1, y0, y1) = extent(series.iter().flat_map(|s| s.1.iter()));
    let sx = |x: f64| PAD + (x - x0) / (x1 - x0).max(1e-9) * (W - 2.0 * PAD);
    let sy = |y: f64| H - PAD - (y - y0) / (y1 - y0).max(1e-9) * (H - 2.0 * PAD);
    let mut out = open(frame, (x0, x1, y0, y1));
    for (colour, points) in series {
        let line: Vec<String> = points
            .iter()
            .map(|&(x, y)| format!("{:.1},{:.1}", sx(x), sy(y)))
            .collect();
        let _ = writeln!(
            out,
            "<polyline fill=\"none\" stroke=\"{colour}\" stroke-width=\"1\" points=\"{}\"/>",
            line.join(" ")
        );
    }
    out.push_str("</svg>\n");
    out
}

/// A histogram of `buckets` (each its upper end and its count), one bar each, on a
/// logarithmic axis of the upper end.
fn histogram(buckets: &[(f64, u64)], frame: &Frame) -> String {
    let logs: Vec<(f64, f64)> = buckets
        .iter()
        .map(|&(end, n)| (end.max(1e-3).log10(), n as f64))
        .collect();
    let (x0, x1, _, y1) = extent(logs.iter());
    let sx = |x: f64| PAD + (x - x0) / (x1 - x0).max(1e-9) * (W - 2.0 * PAD - 4.0);
    let mut out = open(
        frame,
        (
            buckets.first().map_or(0.0, |b| b.0),
            buckets.last().map_or(0.0, |b| b.0),
            0.0,
            y1.max(0.0),
        ),
    );
    for &(x, n) in &logs {
        let h = n / y1.max(1.0) * (H - 2.0 * PAD);
        let _ = writeln!(
            out,
            "<rect class=\"bar\" x=\"{:.1}\" y=\"{:.1}\" width=\"4\" height=\"{h:.1}\" fill=\"{UP}\"/>",
            sx(x),
            H - PAD - h
        );
    }
    out.push_str("</svg>\n");
    out
}

/// The step responses of one size overlaid: the command and the reading of each,
/// against the time from the command's arrival.
fn steps_svg(f: &Figures, small: bool, units: &str) -> String {
    let mut series = Vec::new();
    for r in f.responses.iter().filter(|r| r.small == small) {
        let up = r.samples.last().map(|s| s.commanded) > r.samples.first().map(|s| s.measured);
        series.push((
            COMMAND,
            r.samples.iter().map(|s| (s.t, s.commanded)).collect(),
        ));
        series.push((
            if up { UP } else { DOWN },
            r.samples.iter().map(|s| (s.t, s.measured)).collect(),
        ));
    }
    svg(
        &series,
        &Frame {
            x_label: "s from the command".into(),
            y_label: units.into(),
            legend: vec![
                (COMMAND, "commanded".into()),
                (UP, "measured, a step up".into()),
                (DOWN, "measured, a step down".into()),
            ],
        },
    )
}

/// `report.md`: the figures, and the plots beside it: `run.svg` (the whole run),
/// `steps-large.svg` and `steps-small.svg` (the step responses), `map.svg` (the
/// sweep's legs: the hysteresis loop) and `delay.svg` (the command path's delay
/// histogram).
pub(crate) fn report(f: &Figures) -> (String, Vec<(&'static str, String)>) {
    // A rounding error of a zero figure (an overshoot of 2e-14 %) reads as 0.
    let show = |x: Option<f64>, unit: &str| {
        x.map_or("—".into(), |v| {
            format!("{} {unit}", if v.abs() < 1e-9 { 0.0 } else { sig(v) })
        })
    };
    let u = if f.units.is_empty() {
        "units"
    } else {
        &f.units
    };
    let mut md = format!(
        "# {} characterized\n\n{} samples in {:.0} s, range {} … {} {u}.\n\n| figure | value |\n|---|---|\n",
        f.device,
        f.samples.len(),
        f.took,
        f.range[0],
        f.range[1]
    );
    let rows = [
        (
            "delay, command to first movement",
            show(f.delay().map(|d| d * 1e3), "ms"),
        ),
        ("slew rate up", show(f.rate_up(), &format!("{u}/s"))),
        ("slew rate down", show(f.rate_down(), &format!("{u}/s"))),
        ("rise 10–90 %", show(f.rise().map(|d| d * 1e3), "ms")),
        ("overshoot", show(f.overshoot_pct(), "%")),
        ("settling to 2 %", show(f.settle().map(|d| d * 1e3), "ms")),
        ("lag of the tail", show(f.lag().map(|d| d * 1e3), "ms")),
        (
            "deadband",
            match f.deadband {
                Some(Deadband::Below(d)) => format!(
                    "below {} (every step its readings resolve moved it)",
                    show(Some(d), u)
                ),
                d => show(d.map(Deadband::value), u),
            },
        ),
        ("backlash", show(f.backlash, u)),
        ("gain", show(f.gain_offset.map(|g| g.0), "")),
        ("offset", show(f.gain_offset.map(|g| g.1), u)),
        ("repeatability", show(f.repeatability, u)),
        ("noise (σ)", show(f.noise, u)),
        (
            "the command path's own delay, p50 / p99 (receipt to first byte)",
            f.command_path.map_or("—".into(), |l| {
                let ms = |x: Option<f64>| x.map_or("—".into(), |v| format!("{:.2}", v / 1e3));
                format!(
                    "{} / {} ms over {} commands",
                    ms(l.p50_us),
                    ms(l.p99_us),
                    l.count
                )
            }),
        ),
    ];
    for (k, v) in rows {
        let _ = writeln!(md, "| {k} | {v} |");
    }
    md.push_str("\n## The run\n\nCommanded (grey) and measured (blue) against time.\n\n![the run](run.svg)\n");
    let run = svg(
        &[
            (
                COMMAND,
                f.samples.iter().map(|s| (s.t, s.commanded)).collect(),
            ),
            (UP, f.samples.iter().map(|s| (s.t, s.measured)).collect()),
        ],
        &Frame {
            x_label: "s".into(),
            y_label: u.into(),
            legend: vec![(COMMAND, "commanded".into()), (UP, "measured".into())],
        },
    );
    let mut files = vec![("run.svg", run)];
    if !f.responses.is_empty() {
        md.push_str(
            "\n## Step responses\n\nEach step's command (grey) and measured position (blue up, \
             orange down) against the time from the command's arrival at the device, overlaid; \
             each figure is the median over the steps of its size and direction.\n\n\
             | steps | delay | rate | rise 10–90 % | overshoot | settling to 2 % |\n|---|---|---|---|---|---|\n",
        );
        let sets = [
            ("large, up", &f.up),
            ("large, down", &f.down),
            ("small, up", &f.small_up),
            ("small, down", &f.small_down),
        ];
        for (what, v) in sets.into_iter().filter(|(_, v)| !v.is_empty()) {
            let m =
                |g: fn(&StepFigures) -> f64| analyze::median(&v.iter().map(g).collect::<Vec<_>>());
            let _ = writeln!(
                md,
                "| {what} ({}) | {} | {} | {} | {} | {} |",
                v.len(),
                show(m(|s| s.delay * 1e3), "ms"),
                show(m(|s| s.rate), &format!("{u}/s")),
                show(m(|s| s.rise * 1e3), "ms"),
                show(m(|s| s.overshoot_pct), "%"),
                show(m(|s| s.settle * 1e3), "ms"),
            );
        }
        for (small, name, what) in [
            (false, "steps-large.svg", "large steps"),
            (true, "steps-small.svg", "small steps"),
        ] {
            if f.responses.iter().any(|r| r.small == small) {
                let _ = write!(md, "\n![the {what}]({name})\n");
                files.push((name, steps_svg(f, small, u)));
            }
        }
    }
    if let Some((up, down)) = &f.sweep {
        md.push_str(
            "\n## The sweep\n\nMeasured against commanded, settled at each point: up the range \
             (blue) and back down (orange), the hysteresis loop between them; the static map is \
             their mean (grey).\n\n![the sweep](map.svg)\n",
        );
        files.push((
            "map.svg",
            svg(
                &[
                    (COMMAND, f.map.iter().map(|p| (p[0], p[1])).collect()),
                    (UP, up.clone()),
                    (DOWN, down.clone()),
                ],
                &Frame {
                    x_label: format!("commanded {u}"),
                    y_label: format!("measured {u}"),
                    legend: vec![
                        (UP, "up the range".into()),
                        (DOWN, "down the range".into()),
                        (COMMAND, "the map (their mean)".into()),
                    ],
                },
            ),
        ));
    }
    if !f.command_path_buckets.is_empty() {
        md.push_str(
            "\n## The command path's delay\n\nHow long each command of the run took from its \
             receipt to its first byte on the wire: commands per bucket of the engine's histogram, \
             on a logarithmic axis.\n\n![the command path's delay](delay.svg)\n",
        );
        files.push((
            "delay.svg",
            histogram(
                &f.command_path_buckets,
                &Frame {
                    x_label: "µs, receipt to first byte".into(),
                    y_label: "commands".into(),
                    legend: vec![],
                },
            ),
        ));
    }
    (md, files)
}

/// Write every file into `dir` (created if missing).
pub(crate) fn all(dir: &Path, f: &Figures) -> std::io::Result<()> {
    files(dir, &summary(f), &samples_csv(f), &sim_toml(f), report(f))
}

/// The files of a characterization of any kind into `dir` (created if missing):
/// summary.json, samples.csv, sim.toml, report.md and the report's plots.
pub(crate) fn files<N: AsRef<Path>>(
    dir: &Path,
    summary: &serde_json::Value,
    csv: &str,
    sim: &str,
    (md, plots): (String, Vec<(N, String)>),
) -> std::io::Result<()> {
    std::fs::create_dir_all(dir)?;
    let json = serde_json::to_string_pretty(summary).map_err(std::io::Error::other)?;
    std::fs::write(dir.join("summary.json"), json + "\n")?;
    std::fs::write(dir.join("samples.csv"), csv)?;
    std::fs::write(dir.join("sim.toml"), sim)?;
    std::fs::write(dir.join("report.md"), md)?;
    for (name, text) in plots {
        std::fs::write(dir.join(name), text)?;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::characterize::analyze::{Sample, StepFigures};
    use crate::characterize::Response;

    /// The points of each polyline of `svg`, and its bars.
    fn shapes(svg: &str) -> (Vec<usize>, usize) {
        let lines = svg
            .split("<polyline")
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
            .collect();
        (lines, svg.matches("<rect class=\"bar\"").count())
    }

    #[test]
    fn the_report_plots_every_step_both_sweep_legs_and_the_delay_histogram() {
        let response = |small: bool, n: usize, up: bool| Response {
            small,
            samples: (0..n)
                .map(|i| Sample {
                    t: i as f64 * 0.005,
                    commanded: if up { 1.0 } else { 0.0 },
                    measured: if up {
                        i as f64 / n as f64
                    } else {
                        1.0 - i as f64 / n as f64
                    },
                })
                .collect(),
        };
        let step = StepFigures {
            delay: 0.03,
            rate: 1.0,
            rise: 0.4,
            overshoot_pct: 1.5,
            settle: 0.8,
            lag: None,
        };
        let f = Figures {
            device: "steer".into(),
            units: "rad<&>".into(),
            range: [-1.0, 1.0],
            up: vec![step; 3],
            down: vec![step; 3],
            small_up: vec![StepFigures {
                rise: 0.123,
                overshoot_pct: 2.2e-14,
                ..step
            }],
            small_down: vec![step],
            responses: vec![
                response(false, 40, true),
                response(false, 41, false),
                response(true, 12, true),
                response(true, 13, false),
            ],
            sweep: Some((
                vec![(-0.5, -0.45), (0.0, 0.02), (0.5, 0.52)],
                vec![(0.5, 0.56), (0.0, 0.06), (-0.5, -0.41)],
            )),
            map: vec![[-0.5, -0.43], [0.0, 0.04], [0.5, 0.54]],
            command_path_buckets: vec![(20.0, 3), (40.0, 10), (1200.0, 1)],
            ..Figures::default()
        };
        let (md, files) = report(&f);
        let names: Vec<&str> = files.iter().map(|(n, _)| *n).collect();
        assert_eq!(
            names,
            [
                "run.svg",
                "steps-large.svg",
                "steps-small.svg",
                "map.svg",
                "delay.svg"
            ]
        );
        for n in &names {
            assert!(md.contains(&format!("]({n})")), "{n} in the report:\n{md}");
        }
        for section in [
            "## Step responses",
            "## The sweep",
            "## The command path's delay",
        ] {
            assert!(md.contains(section), "{section}");
        }
        assert!(md.contains("| small, up (1) |"), "{md}");
        assert!(
            md.contains("| 123 ms | 0 % |"),
            "a zero overshoot reads 0:\n{md}"
        );
        let svg = |n: &str| &files.iter().find(|f| f.0 == n).unwrap().1;
        assert!(!svg("run.svg").contains("rad<&>") && svg("run.svg").contains("rad&lt;&amp;&gt;"));
        // Each step's command and reading, one line each, with every sample.
        assert_eq!(shapes(svg("steps-large.svg")), (vec![40, 40, 41, 41], 0));
        assert_eq!(shapes(svg("steps-small.svg")), (vec![12, 12, 13, 13], 0));
        let large = svg("steps-large.svg");
        assert!(
            large.contains(UP) && large.contains(DOWN),
            "up and down told apart"
        );
        // The map, then each leg of the loop in its own colour.
        assert_eq!(shapes(svg("map.svg")), (vec![3, 3, 3], 0));
        let map = svg("map.svg");
        assert!(
            map.contains(&format!("stroke=\"{UP}\""))
                && map.contains(&format!("stroke=\"{DOWN}\""))
        );
        assert_eq!(shapes(svg("delay.svg")), (vec![], 3));
    }

    #[test]
    fn sim_toml_is_a_device_sim_section_the_vehicle_file_takes_back() {
        let step = StepFigures {
            delay: 0.0315,
            rate: 1.25,
            rise: 0.5,
            overshoot_pct: 0.0,
            settle: 0.9,
            lag: Some(0.06),
        };
        let f = Figures {
            device: "steer".into(),
            range: [-1.0, 1.0],
            up: vec![step],
            down: vec![step],
            deadband: Some(Deadband::Measured(0.031)),
            backlash: Some(0.042),
            ..Figures::default()
        };
        let text = sim_toml(&f);
        let fragment = format!(
            "name = \"steer\"\nkind = \"setpoint\"\nrange = [-1.0, 1.0]\ndriver = \"line\"\nport = \"/dev/null\"\n{}",
            text.lines().filter(|l| !l.starts_with('#')).collect::<Vec<_>>().join("\n")
        );
        let d = crate::config::one_device(&fragment);
        assert_eq!(d.sim.rate, Some(1.25));
        assert_eq!(d.sim.lag, Some(std::time::Duration::from_millis(60)));
        assert_eq!(d.sim.deadband, 0.031);
        assert_eq!(d.sim.backlash, 0.042);
        assert_eq!(d.sim.delay, std::time::Duration::from_micros(31_500));
        let s = summary(&f);
        for key in [
            "device",
            "rate_up",
            "rate_down",
            "delay_ms",
            "deadband",
            "deadband_below",
            "backlash",
            "rise_ms",
            "overshoot_pct",
            "settle_ms",
            "gain",
            "offset",
            "noise",
            "samples",
            "map",
        ] {
            assert!(s.get(key).is_some(), "{key} in {s}");
        }
        assert_eq!(s.as_object().unwrap().len(), 15, "exactly the named fields");
        assert_eq!(s["delay_ms"], 31.5);
        assert_eq!(s["deadband_below"], serde_json::Value::Null);
    }

    /// A deadband below what the readings resolve is no deadband for the simulator,
    /// and the report and summary say how far below it is known to be.
    #[test]
    fn a_deadband_below_the_readings_resolution_is_none_and_says_so() {
        let f = Figures {
            device: "steer".into(),
            units: "rad".into(),
            range: [-1.0, 1.0],
            deadband: Some(Deadband::Below(0.0009375)),
            ..Figures::default()
        };
        assert!(!sim_toml(&f).contains("deadband"), "{}", sim_toml(&f));
        let s = summary(&f);
        assert_eq!(
            (s["deadband"].as_f64(), s["deadband_below"].as_f64()),
            (Some(0.0), Some(0.0009375))
        );
        let (md, _) = report(&f);
        assert!(
            md.contains(
                "| deadband | below 0.0009375 rad (every step its readings resolve moved it) |"
            ),
            "{md}"
        );
    }
}
