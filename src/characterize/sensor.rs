//! `adrive characterize` of a sensor (a device with readings and no commands): how
//! often it gives a new reading, and how much each reading wanders at rest — its
//! noise (the standard deviation about its trend, so a coolant warming up is not
//! taken for noise) and the range it spans.
//!
//! It only listens: it commands nothing, so it does not engage, needs no vehicle held
//! still and moves nothing ([`run`] never reaches the intake). It still ends at once on
//! a signal or a fault of the sensor, and writes nothing then. The sensor is polled as
//! fast as it answers (every 5 ms, or its own `status_period` if shorter), so
//! `update_hz` is the most it gives; a reading that comes after a stall of the machine
//! is left out of the noise and the rate (its time is unknown).

use super::analyze;
use super::write::{self, Frame};
use super::Ended;
use crate::engine::Gate;
use crate::value::Kind;
use std::fmt::Write as _;
use std::path::Path;
use std::time::{Duration, Instant};

/// How long it listens at least, and how many readings it takes at least (within
/// [`LISTEN_AT_MOST`]): enough for the standard deviation to be good to a few percent.
pub(crate) const LISTEN: Duration = Duration::from_secs(10);
pub(crate) const READINGS: usize = 500;
pub(crate) const LISTEN_AT_MOST: Duration = Duration::from_secs(60);

/// One reading's figures at rest.
#[derive(Clone, Debug, Default, PartialEq)]
pub(crate) struct Noise {
    pub name: String,
    /// The standard deviation about the least-squares line through it over time.
    pub sd: f64,
    pub min: f64,
    pub max: f64,
}

/// What a sensor's characterization measured.
#[derive(Clone, Debug, Default)]
pub(crate) struct Figures {
    pub device: String,
    /// New readings a second: (readings − 1) over the time from the first to the last.
    pub update_hz: Option<f64>,
    pub noise: Vec<Noise>,
    /// Every poll: its time (seconds since the start) and every reading of it.
    pub samples: Vec<(f64, Vec<Option<f64>>)>,
    /// The names of the readings, in the order of the samples.
    pub names: Vec<String>,
    pub took: f64,
}

/// The noise of one reading over `points` (time, value): about its trend.
pub(crate) fn noise(name: &str, points: &[(f64, f64)]) -> Option<Noise> {
    if points.len() < 3 {
        return None;
    }
    let (k, b) = analyze::fit_line(points).unwrap_or((0.0, points[0].1));
    let residuals: Vec<f64> = points.iter().map(|(t, y)| y - (k * t + b)).collect();
    let (_, sd) = analyze::mean_sd(&residuals)?;
    let (min, max) = points
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, c), p| {
            (a.min(p.1), c.max(p.1))
        });
    Some(Noise {
        name: name.to_string(),
        sd,
        min,
        max,
    })
}

/// Listen to sensor `device` ([`LISTEN`], at least [`READINGS`] readings); it commands
/// nothing.
pub(crate) fn run(gate: &Gate, watch: &super::Watch, device: &str) -> Result<Figures, Ended> {
    let v = gate.vehicle();
    let d = v
        .find(device)
        .ok_or_else(|| Ended(format!("no device {device:?} in this vehicle")))?;
    if d.kind() != Kind::Sensor {
        return Err(Ended(format!("{device} is not a sensor")));
    }
    let names: Vec<String> = d.config().readings.iter().map(|r| r.name.clone()).collect();
    let started = Instant::now();
    let mut samples: Vec<(f64, Vec<Option<f64>>)> = Vec::new();
    let mut last_at = None;
    let mut first_at = None;
    loop {
        std::thread::sleep(Duration::from_millis(1));
        if let Some(why) = (watch.stop)() {
            return Err(Ended(format!("stopped: {why}")));
        }
        if let Some(f) = d.fault() {
            return Err(Ended(format!("{device}: {f}")));
        }
        if let Some(super::Fresh { reading, at, t, .. }) = super::fresh(d, &mut last_at, started) {
            first_at = first_at.or(Some(at));
            samples.push((t, (0..names.len()).map(|i| reading.get(i)).collect()));
        }
        let listened = first_at.map_or(Duration::ZERO, |f| f.elapsed());
        if (listened >= LISTEN && samples.len() >= READINGS) || listened >= LISTEN_AT_MOST {
            break;
        }
        if first_at.is_none() && started.elapsed() > super::START_WITHIN {
            return Err(Ended(format!("{device} does not report")));
        }
    }
    // The rate from the readings taken in a row: a stall's gap is not the sensor's.
    let gaps: Vec<f64> = samples.windows(2).map(|w| w[1].0 - w[0].0).collect();
    let update_hz = analyze::median(&gaps).filter(|g| *g > 0.0).map(|_| {
        let span = samples.last().map_or(0.0, |s| s.0) - samples[0].0;
        let typical = analyze::median(&gaps).unwrap_or(0.0);
        // Stalls (gaps past four typical ones) are taken out of the time.
        let stalled: f64 = gaps.iter().filter(|g| **g > 4.0 * typical).sum();
        let kept = gaps.iter().filter(|g| **g <= 4.0 * typical).count();
        kept as f64 / (span - stalled)
    });
    let noise = names
        .iter()
        .enumerate()
        .filter_map(|(i, name)| {
            let points: Vec<(f64, f64)> = samples
                .iter()
                .filter_map(|(t, r)| r[i].map(|y| (*t, y)))
                .collect();
            noise(name, &points)
        })
        .collect();
    Ok(Figures {
        device: device.to_string(),
        update_hz,
        noise,
        samples,
        names,
        took: started.elapsed().as_secs_f64(),
    })
}

/// `summary.json`'s object.
pub(crate) fn summary(f: &Figures) -> serde_json::Value {
    let noise: serde_json::Map<String, serde_json::Value> = f
        .noise
        .iter()
        .map(|n| {
            (
                n.name.clone(),
                serde_json::json!({
                    "sd": write::sig(n.sd),
                    "min": write::sig(n.min),
                    "max": write::sig(n.max),
                }),
            )
        })
        .collect();
    serde_json::json!({
        "device": f.device,
        "kind": "sensor",
        "update_hz": f.update_hz.map(write::sig),
        "noise": noise,
        "samples": f.samples.len(),
    })
}

/// `sim.toml`: the `[device.sim]` readings' noise, each about the mean it read (a
/// reading the simulated vehicle serves, a role's, keeps its source without one).
pub(crate) fn sim_toml(f: &Figures) -> String {
    let mut out = format!(
        "# {}: measured by adrive characterize in {:.0} s\n[device.sim]\n",
        f.device, f.took
    );
    for n in f.noise.iter().filter(|n| n.sd > 0.0) {
        let i = f.names.iter().position(|x| *x == n.name);
        let values: Vec<f64> = f
            .samples
            .iter()
            .filter_map(|(_, r)| i.and_then(|i| r[i]))
            .collect();
        let mean = analyze::mean_sd(&values).map_or(0.0, |m| m.0);
        let _ = writeln!(
            out,
            "readings.{} = {{ value = {:?}, noise = {:?} }}",
            n.name,
            write::sig(mean),
            write::sig(n.sd)
        );
    }
    out
}

/// `report.md` and its plots: each reading over time (`NAME.svg`).
pub(crate) fn report(f: &Figures) -> (String, Vec<(String, String)>) {
    let mut md = format!(
        "# {} characterized\n\n{} readings in {:.0} s, listening only (nothing commanded). \
         It gives a new reading {} times a second.\n\n\
         | reading | noise (σ, about its trend) | min | max |\n|---|---|---|---|\n",
        f.device,
        f.samples.len(),
        f.took,
        f.update_hz
            .map_or("—".into(), |h| format!("{}", write::sig(h))),
    );
    for n in &f.noise {
        let _ = writeln!(
            md,
            "| {} | {} | {} | {} |",
            n.name,
            write::sig(n.sd),
            write::sig(n.min),
            write::sig(n.max)
        );
    }
    let mut files = Vec::new();
    md.push_str("\n## The readings over time\n");
    for (i, name) in f.names.iter().enumerate() {
        let points: Vec<(f64, f64)> = f
            .samples
            .iter()
            .filter_map(|(t, r)| r[i].map(|y| (*t, y)))
            .collect();
        if points.is_empty() {
            continue;
        }
        let file = format!("{name}.svg");
        let _ = write!(md, "\n![{name}]({file})\n");
        files.push((
            file,
            write::svg(
                &[(write::UP, points)],
                &Frame {
                    x_label: "s".into(),
                    y_label: name.clone(),
                    legend: vec![(write::UP, name.clone())],
                },
            ),
        ));
    }
    (md, files)
}

/// Every file into `dir`: summary.json, samples.csv (`t_s` and each reading), sim.toml,
/// report.md and its plots.
pub(crate) fn write_all(dir: &Path, f: &Figures) -> std::io::Result<()> {
    let mut csv = format!("t_s,{}\n", f.names.join(","));
    for (t, r) in &f.samples {
        let cells: Vec<String> = r
            .iter()
            .map(|x| x.map_or(String::new(), |v| v.to_string()))
            .collect();
        let _ = writeln!(csv, "{t:.6},{}", cells.join(","));
    }
    super::write::files(dir, &summary(f), &csv, &sim_toml(f), report(f))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn noise_is_taken_about_the_trend_and_the_range_is_the_raw_one() {
        // A coolant warming 1 °C a second with ±0.5 of alternating noise (σ 0.5).
        let points: Vec<(f64, f64)> = (0..200)
            .map(|i| {
                let t = i as f64 * 0.05;
                (t, 80.0 + t + if i % 2 == 0 { 0.5 } else { -0.5 })
            })
            .collect();
        let n = noise("coolant", &points).unwrap();
        assert!((n.sd - 0.5).abs() < 0.01, "{n:?}");
        // The raw extremes: the second point, low, and the last even one, high.
        assert!((n.min - (80.05 - 0.5)).abs() < 1e-9, "{n:?}");
        assert!((n.max - (80.0 + 9.9 + 0.5)).abs() < 1e-9, "{n:?}");
        assert_eq!(noise("x", &points[..2]), None);
    }

    #[test]
    fn the_summary_names_each_reading_s_noise() {
        let f = Figures {
            device: "obd".into(),
            update_hz: Some(40.0),
            noise: vec![Noise {
                name: "rpm".into(),
                sd: 25.0,
                min: 700.0,
                max: 900.0,
            }],
            names: vec!["rpm".into()],
            samples: vec![(0.0, vec![Some(800.0)]), (0.1, vec![Some(800.0)])],
            ..Figures::default()
        };
        let s = summary(&f);
        assert_eq!(s["kind"], "sensor");
        assert_eq!(s["update_hz"], 40.0);
        assert_eq!(s["noise"]["rpm"]["sd"], 25.0);
        assert_eq!(s["samples"], 2);
        let sim = sim_toml(&f);
        assert!(
            sim.contains("readings.rpm = { value = 800.0, noise = 25.0 }"),
            "{sim}"
        );
    }
}
