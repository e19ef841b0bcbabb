//! A characterization started from a console (the bench view's key): [`super::run`],
//! the one runner `adrive characterize` uses, on a thread of its own in the process
//! that runs the engine — so the console's loop keeps drawing and every key, STOP above
//! all, keeps working while it runs. The console reads where it stands
//! ([`Background::state`]) each tick and ends it at once ([`Background::end`]) when the
//! operator leaves the bench view, quits, or the console's terminal goes away; the
//! runner then disengages, which commands the safe state, as on every way it ends.
//!
//! The console's loop is not what holds the operator's link: a terminal frozen without
//! closing (a laptop asleep, a Wi-Fi link gone) leaves it running. While a run is under
//! way the console asks its terminal for round trips as a commanding console does
//! (`console/input/link.rs`) and hands each answer here ([`Background::answered`]); the
//! run's own thread ends it once none came for `[console] terminal_timeout`, as the
//! gate's monitor stops a commanding console's vehicle: the operator who started it no
//! longer sees it.
//!
//! The device is polled at [`POLL`] for the run (its own period, if shorter), as the
//! command line does from the start, and its period is put back when the run ends.

use super::{Deadband, Ended, Figures, Procedure, Progress, Stage, Watch};
use crate::engine::Gate;
use crate::value::{DeviceId, Source};
use parking_lot::Mutex;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

/// How often a characterization polls the device it measures, at most.
pub(crate) const POLL: Duration = Duration::from_millis(5);

/// What a run does to device `name` and asks of the vehicle, for the operator's
/// confirmation.
pub(crate) fn what_it_does(name: &str) -> String {
    format!(
        "moves {name} over 90 % of its range for about 30 s; the vehicle must be stopped, \
         in park, with the brake held"
    )
}

/// The figures a console shows when a run is done (`None`: not measured).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Headline {
    pub units: String,
    /// Units a second.
    pub rate_up: Option<f64>,
    pub rate_down: Option<f64>,
    /// Seconds.
    pub delay: Option<f64>,
    pub deadband: Option<Deadband>,
    pub backlash: Option<f64>,
    pub rise: Option<f64>,
    pub overshoot_pct: Option<f64>,
    pub settle: Option<f64>,
    /// How long it took, seconds.
    pub took: f64,
}

impl Headline {
    pub(crate) fn of(f: &Figures) -> Headline {
        Headline {
            units: f.units.clone(),
            rate_up: f.rate_up(),
            rate_down: f.rate_down(),
            delay: f.delay(),
            deadband: f.deadband,
            backlash: f.backlash,
            rise: f.rise(),
            overshoot_pct: f.overshoot_pct(),
            settle: f.settle(),
            took: f.took,
        }
    }

    /// The figures in words, a group each: `rate up 1.00 /s`, `delay 12 ms`, …
    pub fn words(&self) -> Vec<String> {
        let num = |x: Option<f64>| x.map_or("-".into(), |v| format!("{v:.3}"));
        let ms = |x: Option<f64>| x.map_or("-".into(), |v| format!("{:.0} ms", v * 1e3));
        let u = if self.units.is_empty() {
            String::new()
        } else {
            format!(" {}", self.units)
        };
        vec![
            format!("rate up {} /s", num(self.rate_up)),
            format!("down {} /s", num(self.rate_down)),
            format!("delay {}", ms(self.delay)),
            match self.deadband {
                Some(Deadband::Below(d)) => format!("deadband < {}{u}", num(Some(d))),
                d => format!("deadband {}{u}", num(d.map(Deadband::value))),
            },
            format!("backlash {}{u}", num(self.backlash)),
            format!("rise {}", ms(self.rise)),
            format!(
                "overshoot {}",
                self.overshoot_pct
                    .map_or("-".into(), |v| format!("{:.1} %", v.max(0.0)))
            ),
            format!("settle {}", ms(self.settle)),
        ]
    }
}

/// A characterization from a console: where it stands, and how it ended.
#[derive(Clone, Debug, PartialEq)]
pub struct Characterizing {
    pub device: DeviceId,
    pub name: String,
    pub procedures: Vec<Procedure>,
    /// Where it writes its files.
    pub out: PathBuf,
    pub progress: Progress,
    /// `None` while it runs; its figures once done and written, or why it ended early
    /// (nothing written then).
    pub end: Option<Result<Headline, String>>,
}

impl Characterizing {
    pub fn running(&self) -> bool {
        self.end.is_none()
    }
}

/// What was checked before a run may start, in words (`stopped, in park, brake held`),
/// or why it may not: `device` must be a setpoint actuator with a position reading,
/// nobody may command the engaged vehicle, and the vehicle must stand still
/// ([`safety::bench::ready`]).
pub(crate) fn check(gate: &Gate, device: DeviceId) -> Result<String, String> {
    let v = gate.vehicle();
    let d = v
        .devices()
        .get(device.index())
        .ok_or_else(|| format!("no device #{}", device.index()))?;
    let (id, _) = super::check_device(gate, d.name())?;
    if gate.is_engaged() {
        return Err(format!(
            "the vehicle is engaged (by {}): disengage first, characterize engages as its own source",
            gate.commander()
                .map_or("nobody".into(), |s: Source| s.to_string())
        ));
    }
    super::ready(gate, id)
        .map(|p| p.to_string())
        .map_err(|u| format!("not ready: {u}"))
}

/// Where a run of device `name` started at `at` writes, in the directory adrive runs
/// in: `characterize-steer-20261127-140812` (UTC), so that no run overwrites another.
pub(crate) fn out_dir(name: &str, at: std::time::SystemTime) -> PathBuf {
    let digits: String = humantime::format_rfc3339_seconds(at)
        .to_string()
        .chars()
        .filter(char::is_ascii_digit)
        .collect();
    let (day, time) = digits.split_at(digits.len().min(8));
    let here = std::env::current_dir().unwrap_or_default();
    here.join(format!("characterize-{name}-{day}-{time}"))
}

/// The one characterization a console may run at a time, on its own thread.
pub struct Background {
    gate: Arc<Gate>,
    shared: Arc<Shared>,
    thread: Mutex<Option<JoinHandle<()>>>,
}

#[derive(Default)]
struct Shared {
    state: Mutex<Option<Characterizing>>,
    /// Why the run is to end now (set by [`Background::end`]).
    stop: Mutex<Option<String>>,
    /// The console's terminal's last answer to a round trip while the run is under way
    /// (its start, before the first).
    answered: Mutex<Option<Instant>>,
}

impl Shared {
    /// Why the run is to end now: told to, or the console's terminal silent for
    /// `bound`.
    fn why_stop(&self, bound: Duration) -> Option<String> {
        self.stop.lock().clone().or_else(|| {
            let quiet = (*self.answered.lock())?.elapsed();
            (quiet >= bound).then(|| {
                format!(
                    "the console's terminal stopped answering for {:.1} s",
                    quiet.as_secs_f64()
                )
            })
        })
    }
}

/// How long [`Background::end`] waits for the runner to have let the vehicle go.
const END_WITHIN: Duration = Duration::from_secs(2);

impl Background {
    pub fn new(gate: Arc<Gate>) -> Background {
        Background {
            gate,
            shared: Arc::default(),
            thread: Mutex::new(None),
        }
    }

    /// Start characterizing `device` into `out`: refused, with the reason, while a run
    /// is under way or when [`check`] refuses.
    pub(crate) fn start(
        &self,
        device: DeviceId,
        procedures: &[Procedure],
        out: &Path,
    ) -> Result<(), String> {
        let mut thread = self.thread.lock();
        if self.state().is_some_and(|s| s.running()) {
            return Err("a characterization is already running".into());
        }
        check(&self.gate, device)?;
        crate::paths::check_dir_possible("characterize's directory", out)?;
        if out.exists() {
            return Err(format!("{} exists already", out.display()));
        }
        if let Some(t) = thread.take() {
            let _ = t.join();
        }
        let name = self.gate.vehicle().device(device).name().to_string();
        let span = {
            let r = self.gate.vehicle().device(device).config().range();
            r[1] - r[0]
        };
        let total = super::plan(procedures, &super::Scope::default(), span)
            .iter()
            .map(|(_, n)| n)
            .sum();
        *self.shared.stop.lock() = None;
        *self.shared.answered.lock() = Some(Instant::now());
        *self.shared.state.lock() = Some(Characterizing {
            device,
            name: name.clone(),
            procedures: procedures.to_vec(),
            out: out.to_path_buf(),
            progress: Progress {
                stage: Stage::Starting,
                done: 0,
                total,
                elapsed: Duration::ZERO,
            },
            end: None,
        });
        let (gate, shared) = (self.gate.clone(), self.shared.clone());
        let (procedures, out) = (procedures.to_vec(), out.to_path_buf());
        tracing::warn!(
            "characterize {name}: started from the console, writing to {}",
            out.display()
        );
        let handle = std::thread::Builder::new()
            .name("characterize".into())
            .spawn(move || {
                let end = measure(&gate, &shared, device, &name, &procedures, &out);
                match &end {
                    Ok(h) => tracing::warn!(
                        "characterize {name}: done in {:.1} s, written to {}: {}",
                        h.took,
                        out.display(),
                        h.words().join(", ")
                    ),
                    Err(why) => {
                        tracing::warn!("characterize {name}: ended early, nothing written: {why}")
                    }
                }
                if let Some(s) = shared.state.lock().as_mut() {
                    s.end = Some(end);
                }
            })
            .map_err(|e| format!("cannot start its thread: {e}"))?;
        *thread = Some(handle);
        Ok(())
    }

    /// The console's terminal answered a round trip at `at`: the operator still sees
    /// the run.
    pub(crate) fn answered(&self, at: Instant) {
        if let Some(last) = self.shared.answered.lock().as_mut() {
            *last = (*last).max(at);
        }
    }

    /// Where the run stands, or how the last one ended; `None` before the first.
    pub fn state(&self) -> Option<Characterizing> {
        self.shared.state.lock().clone()
    }

    /// End the run under way at once, saying `why`: the runner disengages (the safe
    /// state) within a sample; this waits for it, a bounded while.
    pub fn end(&self, why: &str) {
        let mut thread = self.thread.lock();
        if !self.state().is_some_and(|s| s.running()) {
            return;
        }
        *self.shared.stop.lock() = Some(why.to_string());
        let deadline = Instant::now() + END_WITHIN;
        while thread.as_ref().is_some_and(|t| !t.is_finished()) && Instant::now() < deadline {
            std::thread::sleep(Duration::from_millis(2));
        }
        match thread.take() {
            Some(t) if t.is_finished() => {
                let _ = t.join();
            }
            Some(t) => {
                tracing::error!(
                    "characterize did not end within {} s of being told to",
                    END_WITHIN.as_secs()
                );
                *thread = Some(t);
            }
            None => {}
        }
    }
}

impl Drop for Background {
    fn drop(&mut self) {
        self.end("the console closed");
    }
}

/// The run, then its files: its headline figures, or why it ended early.
fn measure(
    gate: &Gate,
    shared: &Shared,
    device: DeviceId,
    name: &str,
    procedures: &[Procedure],
    out: &Path,
) -> Result<Headline, String> {
    let d = gate.vehicle().device(device);
    let period = d.settings().status_period();
    if let Err(v) = d.change_settings(|c| c.status_period = c.status_period.min(POLL)) {
        tracing::info!(
            "characterize {name}: polled at its own period: {}",
            v.message
        );
    }
    let progress = |p: &Progress| {
        if let Some(s) = shared.state.lock().as_mut() {
            s.progress = *p;
        }
    };
    let bound = gate.vehicle().config().console.terminal_timeout;
    let stop = || shared.why_stop(bound);
    let watch = Watch {
        progress: &progress,
        stop: &stop,
    };
    let result = super::run(gate, &watch, name, procedures, &super::Scope::default());
    if let Err(v) = d.change_settings(|c| c.status_period = period) {
        tracing::warn!(
            "characterize {name}: its status period not put back: {}",
            v.message
        );
    }
    let figures = result.map_err(|Ended(why)| why)?;
    super::write::all(out, &figures).map_err(|e| format!("{}: {e}", out.display()))?;
    Ok(Headline::of(&figures))
}
