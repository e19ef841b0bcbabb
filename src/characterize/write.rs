//! What a characterization leaves in its directory: `summary.json` (one object of its
//! figures), `samples.csv` (every reading with the command in force), `sim.toml` (the
//! `[device.sim]` that makes the simulator behave like the measured device) and
//! `report.md` (the figures in a table, and the run as an SVG plot).

use super::Figures;
use std::fmt::Write as _;
use std::path::Path;

/// Rounded to 4 significant digits (for people and for a vehicle file).
fn sig(x: f64) -> f64 {
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
        "deadband": f.deadband.map(sig),
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
    if let Some(d) = f.deadband.filter(|d| *d > 0.0) {
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

/// A small SVG of `series` (each a colour and its points), x and y scaled to fit.
fn svg(series: &[(&str, Vec<(f64, f64)>)], x_label: &str, y_label: &str) -> String {
    let (w, h, pad) = (640.0, 240.0, 30.0);
    let pts = series.iter().flat_map(|s| s.1.iter());
    let (x0, x1, y0, y1) = pts.fold(
        (
            f64::INFINITY,
            f64::NEG_INFINITY,
            f64::INFINITY,
            f64::NEG_INFINITY,
        ),
        |(a, b, c, d), &(x, y)| (a.min(x), b.max(x), c.min(y), d.max(y)),
    );
    let sx = |x: f64| pad + (x - x0) / (x1 - x0).max(1e-9) * (w - 2.0 * pad);
    let sy = |y: f64| h - pad - (y - y0) / (y1 - y0).max(1e-9) * (h - 2.0 * pad);
    let mut out = format!(
        "<svg xmlns=\"http://www.w3.org/2000/svg\" width=\"{w}\" height=\"{h}\" font-size=\"11\">\n\
         <rect width=\"{w}\" height=\"{h}\" fill=\"white\" stroke=\"#ccc\"/>\n\
         <text x=\"{pad}\" y=\"14\">{y_label} ({y0:.3} … {y1:.3})</text>\n\
         <text x=\"{}\" y=\"{}\" text-anchor=\"end\">{x_label} ({x0:.2} … {x1:.2})</text>\n",
        w - pad,
        h - 8.0
    );
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

/// `report.md`: the figures, and the plots beside it (`run.svg`, `map.svg`).
pub(crate) fn report(f: &Figures) -> (String, Vec<(&'static str, String)>) {
    let show =
        |x: Option<f64>, unit: &str| x.map_or("—".into(), |v| format!("{} {unit}", sig(v)));
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
        ("deadband", show(f.deadband, u)),
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
                "#999",
                f.samples.iter().map(|s| (s.t, s.commanded)).collect(),
            ),
            (
                "#1f5fbf",
                f.samples.iter().map(|s| (s.t, s.measured)).collect(),
            ),
        ],
        "s",
        u,
    );
    let mut files = vec![("run.svg", run)];
    if !f.map.is_empty() {
        md.push_str("\n## The static map\n\nMeasured against commanded (the mean of both directions).\n\n![the map](map.svg)\n");
        files.push((
            "map.svg",
            svg(
                &[("#1f5fbf", f.map.iter().map(|p| (p[0], p[1])).collect())],
                "commanded",
                "measured",
            ),
        ));
    }
    (md, files)
}

/// Write every file into `dir` (created if missing).
pub(crate) fn all(dir: &Path, f: &Figures) -> std::io::Result<()> {
    std::fs::create_dir_all(dir)?;
    let json = serde_json::to_string_pretty(&summary(f)).map_err(std::io::Error::other)?;
    std::fs::write(dir.join("summary.json"), json + "\n")?;
    std::fs::write(dir.join("samples.csv"), samples_csv(f))?;
    std::fs::write(dir.join("sim.toml"), sim_toml(f))?;
    let (md, plots) = report(f);
    std::fs::write(dir.join("report.md"), md)?;
    for (name, text) in plots {
        std::fs::write(dir.join(name), text)?;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::characterize::analyze::StepFigures;

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
            deadband: Some(0.031),
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
        assert_eq!(s.as_object().unwrap().len(), 14, "exactly the named fields");
        assert_eq!(s["delay_ms"], 31.5);
    }
}
