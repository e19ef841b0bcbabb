//! `adrive characterize DEVICE`: measure a setpoint actuator at the bench — its delay,
//! slew rates, step response, deadband, backlash, static map, repeatability and noise —
//! and write what it measured, with the `[device.sim]` that makes the simulator behave
//! like it ([`mod@write`]).
//!
//! It moves the device on its own, so it is safe by construction: it commands through
//! the one intake as its own source ([`Source::Bench`]), engaged like any commander, so
//! every rule and the watchdog apply; it runs only while [`safety::bench::ready`] holds
//! (stopped, in park, brake held, or a bench with nothing else bound), checked at every
//! sample; it ends at once — disengaging, which commands the safe state — on STOP, a
//! fault, an override (each disengages the vehicle, so it no longer commands), a broken
//! precondition or a signal; it keeps its set points inside the device's range, a
//! twentieth of it clear of each end; and when it is done it brings the device back to
//! where it found it before it lets go. The figures are [`analyze`]'s, from the samples
//! alone.
//!
//! A state actuator (a gearbox) is timed transition by transition ([`state`]), on the
//! same terms; a sensor is listened to ([`sensor`]): its update rate and noise, with
//! nothing commanded. [`run_any`] picks by the device's kind.

pub(crate) mod analyze;
pub(crate) mod background;
pub(crate) mod sensor;
pub(crate) mod state;
pub(crate) mod write;

use crate::engine::Gate;
use crate::safety::{self, Ask};
use crate::snapshot::DisengageCause;
use crate::value::{Command, DeviceId, Kind, Source};
use analyze::{Sample, StepFigures};
use std::time::{Duration, Instant};

/// One procedure of `--procedure`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum Procedure {
    /// Large steps up and down: rise, overshoot, settling (and rate, delay); then
    /// small steps, whose figures the report shows beside the large ones'.
    Step,
    /// Points up the range and back down: the static map (gain, offset, table).
    Sweep,
    /// The smallest step that moves it.
    Deadband,
    /// Where it settles approaching a point from below and from above.
    Backlash,
    /// The slew rate each way.
    Rate,
    /// Command to first movement.
    Delay,
}

impl Procedure {
    pub const ALL: [Procedure; 6] = [
        Procedure::Step,
        Procedure::Sweep,
        Procedure::Deadband,
        Procedure::Backlash,
        Procedure::Rate,
        Procedure::Delay,
    ];
}

/// What part of a setpoint actuator's range a run covers, and how finely
/// (`--range`, `--resolution`); by default all of it, five sweep points and eleven
/// halvings of the deadband search.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub(crate) struct Scope {
    /// The part of the device's range to characterize, `[lo, hi]`.
    pub range: Option<[f64; 2]>,
    /// The sweep's point spacing and the deadband search's floor, in the device's units.
    pub resolution: Option<f64>,
}

/// Sweep points by default.
const SWEEP_POINTS: usize = 5;
/// The sweep covers this share of the range in its middle; the deadband search starts
/// from a step of [`DEADBAND_FROM`] of it.
const SWEEP_SHARE: f64 = 0.6;
const DEADBAND_FROM: f64 = 0.12;

impl Scope {
    /// Whether the scope fits a device of range `of`: the range inside it, lo < hi,
    /// the resolution a positive number from a thousandth of the range to a fifth of it.
    pub(crate) fn check(&self, of: [f64; 2]) -> Result<(), String> {
        let [lo, hi] = self.range.unwrap_or(of);
        if !(lo.is_finite() && hi.is_finite() && lo < hi && of[0] <= lo && hi <= of[1]) {
            return Err(format!(
                "--range {lo},{hi}: expected LO,HI with LO < HI inside the device's range {} … {}",
                of[0], of[1]
            ));
        }
        if let Some(r) = self.resolution {
            let span = hi - lo;
            if !(r.is_finite() && r >= span / 1000.0 && r <= span / 5.0) {
                return Err(format!(
                    "--resolution {r}: expected a step from {} to {} (a thousandth to a fifth of the range characterized, {lo} … {hi})",
                    span / 1000.0,
                    span / 5.0
                ));
            }
        }
        Ok(())
    }

    /// The sweep's points over `span` (the range characterized).
    pub(crate) fn sweep_points(&self, span: f64) -> usize {
        self.resolution
            .map_or(SWEEP_POINTS, |r| {
                (SWEEP_SHARE * span / r).round() as usize + 1
            })
            .max(2)
    }

    /// Halvings of the deadband search over `span`: until the step is below the
    /// resolution.
    pub(crate) fn deadband_steps(&self, span: f64) -> usize {
        self.resolution.map_or(DEADBAND_STEPS, |r| {
            ((DEADBAND_FROM * span / r).log2().ceil().max(1.0)) as usize
        })
    }
}

/// Points of a sweep, each (commanded, settled reading).
pub(crate) type Settled = Vec<(f64, f64)>;

/// What the deadband search found. A step it judged not to move the device is evidence
/// of a deadband only if a move that size could have been seen: well past the readings'
/// own resolution (four times their stillness, and no finer than their step). Searching
/// below it, every device reads as having a deadband there.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Deadband {
    /// The smallest step up that moved it, larger than one that was seen not to.
    Measured(f64),
    /// Every step its readings could show moving moved it: any deadband is below this,
    /// the smallest step seen to move it.
    Below(f64),
}

impl Deadband {
    /// The figure a simulator or a step's size takes: none, when below what was seen.
    pub fn value(self) -> f64 {
        match self {
            Deadband::Measured(d) => d,
            Deadband::Below(_) => 0.0,
        }
    }
}

/// Why a characterization ended before it was done.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
#[error("{0}")]
pub(crate) struct Ended(pub String);

/// What a characterization measured (`None`: not asked for, or not seen).
#[derive(Clone, Debug, Default)]
pub(crate) struct Figures {
    pub device: String,
    pub units: String,
    pub range: [f64; 2],
    pub up: Vec<StepFigures>,
    pub down: Vec<StepFigures>,
    pub deadband: Option<Deadband>,
    pub backlash: Option<f64>,
    pub map: Vec<[f64; 2]>,
    pub gain_offset: Option<(f64, f64)>,
    pub repeatability: Option<f64>,
    pub noise: Option<f64>,
    pub samples: Vec<Sample>,
    /// How long it took, seconds.
    pub took: f64,
    /// The command path's own delay during the run (receipt to first byte written):
    /// its median and 99th percentile, and how many commands, as the engine kept them.
    pub command_path: Option<crate::snapshot::LatencySummary>,
    /// Small steps each way (a tenth of the range, or twice the deadband if that is
    /// more): the report shows their figures; `summary.json`'s are the large steps'.
    pub small_up: Vec<StepFigures>,
    pub small_down: Vec<StepFigures>,
    /// Every step's samples, timed from its command's arrival, for the report's plots.
    pub responses: Vec<Response>,
    /// The sweep's settled points, up the range and back down (the hysteresis loop).
    pub sweep: Option<(Settled, Settled)>,
    /// The command path's delay histogram during the run: (bucket's upper end in µs,
    /// commands in it), the non-empty buckets in order.
    pub command_path_buckets: Vec<(f64, u64)>,
}

/// One step's response, for the report: each sample timed from the moment the step's
/// command reached the device.
#[derive(Clone, Debug, Default)]
pub(crate) struct Response {
    /// A small step (else a large one).
    pub small: bool,
    pub samples: Vec<Sample>,
}

impl Figures {
    /// The median over the steps: one step a stall of the machine distorted does not
    /// move it.
    fn mean(v: &[StepFigures], f: impl Fn(&StepFigures) -> f64) -> Option<f64> {
        analyze::median(&v.iter().map(f).collect::<Vec<_>>())
    }
    pub(crate) fn rate_up(&self) -> Option<f64> {
        Self::mean(&self.up, |s| s.rate)
    }
    pub(crate) fn rate_down(&self) -> Option<f64> {
        Self::mean(&self.down, |s| s.rate)
    }
    fn all_steps(&self) -> Vec<StepFigures> {
        self.up.iter().chain(&self.down).copied().collect()
    }
    /// Seconds.
    pub(crate) fn delay(&self) -> Option<f64> {
        Self::mean(&self.all_steps(), |s| s.delay)
    }
    pub(crate) fn rise(&self) -> Option<f64> {
        Self::mean(&self.all_steps(), |s| s.rise)
    }
    pub(crate) fn overshoot_pct(&self) -> Option<f64> {
        Self::mean(&self.all_steps(), |s| s.overshoot_pct)
    }
    pub(crate) fn settle(&self) -> Option<f64> {
        Self::mean(&self.all_steps(), |s| s.settle)
    }
    /// The tail's lag: the median of the steps that showed one, where most did (a
    /// drive that stops at its rate shows none; a step whose tail a stall of the
    /// machine thinned out below a fit does not take the lag from the others).
    pub(crate) fn lag(&self) -> Option<f64> {
        let lags: Vec<f64> = self.all_steps().iter().filter_map(|s| s.lag).collect();
        (lags.len() * 2 > self.all_steps().len())
            .then(|| analyze::median(&lags))
            .flatten()
    }
}

/// How long a reading must stay within [`Bench::still`] to count as settled.
const STILL_FOR: Duration = Duration::from_millis(200);
/// The longest a move may take to start, and to settle.
const START_WITHIN: Duration = Duration::from_secs(3);
const SETTLE_WITHIN: Duration = Duration::from_secs(10);
/// Resend the set point at least this often (the commander's watchdog), or more often
/// where the watchdog is shorter ([`resend_every`]).
const RESEND: Duration = Duration::from_millis(100);

/// How often a run resends its command: [`RESEND`], or a third of the vehicle's
/// `[network] watchdog_timeout` where that is shorter — the bench commands as a
/// planner does, under the same watchdog, and a run on a vehicle whose watchdog is
/// shorter than the resend would trip it at the first move.
fn resend_every(gate: &Gate) -> Duration {
    RESEND.min(gate.vehicle().config().network.watchdog_timeout / 3)
}
/// Steps of a deadband search (halving the interval each).
const DEADBAND_STEPS: usize = 11;

/// A new reading, and what is known of when the device took it.
struct Fresh {
    reading: crate::value::Reading,
    /// When it came.
    at: Instant,
    /// When it was taken, seconds after the start: halfway through the poll that read
    /// it (about half a status transaction before it came, for a reading no request
    /// asked for).
    t: f64,
    /// Its own poll stalled — longer than half as long again as the device's median
    /// poll, and 1 ms: the device took it somewhere in that poll, and a busy machine's
    /// late wake-up to read the reply would date it late. A response's shape leaves it
    /// out (a lag's tail dated late reads slow); a bracket keeps it, by the edge of its
    /// poll that keeps the bracket true ([`Fresh::bounds`]); a count of readings keeps
    /// it.
    loose: bool,
    /// Its poll, seconds after the start: from the request's first byte to the reply
    /// (`t` for both, for a reading no request asked for).
    poll: (f64, f64),
}

impl Fresh {
    /// When it was taken, at the earliest and the latest, seconds after the start: at
    /// `t`, or, when its poll stalled, anywhere in the poll.
    fn bounds(&self) -> (f64, f64) {
        if self.loose {
            self.poll
        } else {
            (self.t, self.t)
        }
    }
}

/// A reading of device `d` newer than `last` (the `at` of the one before, updated
/// here). `None` when no new reading came, and for one that came after a stall of the
/// machine — a gap of more than four of the device's turns (its status period, a poll,
/// and a command's transaction the poll may wait for) and 10 ms: it was read before
/// the stall, not when it came, so its time is unknown and it is left out. The one
/// rule for every kind of device characterized.
fn fresh(d: &crate::vehicle::Device, last: &mut Option<Instant>, start: Instant) -> Option<Fresh> {
    let c = d.cached();
    if c.at == *last {
        return None;
    }
    let before = std::mem::replace(last, c.at);
    let at = c.at?;
    let stats = d.stats();
    let txn = |s: &crate::vehicle::stats::Latency| s.summary().p50_us.unwrap_or(0.0) * 1e-6;
    let (status, command) = (txn(&stats.status_txn), txn(&stats.command_txn));
    let turn = d.settings().status_period().as_secs_f64() + status + command;
    let gap = before.map_or(0.0, |b| at.saturating_duration_since(b).as_secs_f64());
    if gap > 4.0 * turn + 0.01 {
        return None;
    }
    let since = |i: Instant| i.saturating_duration_since(start).as_secs_f64();
    let (taken, loose) = match c.asked {
        Some(asked) => {
            let took = at.saturating_duration_since(asked);
            (asked + took / 2, took.as_secs_f64() > 1.5 * status + 0.001)
        }
        None => (
            at.checked_sub(Duration::from_secs_f64(status / 2.0))
                .unwrap_or(at),
            false,
        ),
    };
    let t = since(taken);
    Some(Fresh {
        reading: c.reading,
        at,
        t,
        loose,
        poll: c.asked.map_or((t, t), |asked| (since(asked), since(at))),
    })
}

/// When `command` reached device `d`, seconds after `start`, once the device
/// acknowledged it: about half a command transaction after the transaction's first byte
/// (as a reading is taken about half a status transaction before it is complete), or,
/// where that is not known, half a transaction before the acknowledgement. The first
/// byte's stamp is the better: a late wake-up of the command thread on a busy machine
/// moves the acknowledgement's, not it. A delay measured from here is the device's own,
/// without the command path's.
fn arrived(d: &crate::vehicle::Device, command: Command, start: Instant) -> Option<f64> {
    let w = d.slot().wire();
    let acked = w.acked_at.filter(|_| w.acked == Some(command))?;
    let txn = d.stats().command_txn.summary().p50_us.unwrap_or(0.0) * 1e-6;
    let since = |t: Instant| t.saturating_duration_since(start).as_secs_f64();
    Some(match w.acked_from {
        Some(first) => since(first) + txn / 2.0,
        None => since(acked) - txn / 2.0,
    })
}

/// A characterization in progress: the one commander of the engaged vehicle.
pub(crate) struct Bench<'a> {
    gate: &'a Gate,
    watch: &'a Watch<'a>,
    id: DeviceId,
    position: usize,
    range: [f64; 2],
    started: Instant,
    /// Where the device was found: where it is brought back to.
    found: f64,
    /// The set point in force, and when it was last sent.
    set: f64,
    /// How often the set point is resent ([`resend_every`]).
    resend: Duration,
    sent: Instant,
    last_at: Option<Instant>,
    samples: Vec<Sample>,
    /// A reading within this of another is the same position.
    still: f64,
    /// Once known: the delay and the lag, to wait for a move and a settling.
    delay: Option<f64>,
    lag: Option<f64>,
    /// How far settled readings spread, per point and direction.
    settled: Vec<(i64, bool, f64)>,
    /// Deviations from the mean of settled windows.
    residuals: Vec<f64>,
    /// Where the run stands, for [`Watch::progress`].
    progress: Progress,
}

/// Whether a bench procedure may move device `id` now ([`safety::bench::ready`]), from
/// what the rules see (gathered as for a gear command) and where the brake reports it is.
pub(crate) fn ready(
    gate: &Gate,
    id: DeviceId,
) -> Result<safety::bench::Proof, safety::bench::Unready> {
    let v = gate.vehicle();
    safety::bench::ready(
        v.bindings(),
        id,
        &safety::facts::gather(v, safety::Plays::GEAR),
        safety::facts::brake_reported(v),
    )
}

/// Wait for device `id` to report its reading `reading` (named `what`) and for the
/// vehicle to be ready, then engage as the bench's own source: the first reading.
/// `Err` says why not (nothing moved).
pub(crate) fn engage_as_bench(
    gate: &Gate,
    id: DeviceId,
    reading: usize,
    what: &str,
) -> Result<f64, Ended> {
    let v = gate.vehicle();
    let d = v.device(id);
    let deadline = Instant::now() + START_WITHIN;
    while d.reading(reading).is_none() || d.is_faulty() {
        if Instant::now() > deadline {
            return Err(Ended(format!(
                "{} does not report its {what}: {}",
                d.name(),
                d.fault().unwrap_or_else(|| "no reading yet".into())
            )));
        }
        std::thread::sleep(Duration::from_millis(10));
    }
    // What proves the vehicle still comes from its other devices' first reports.
    while let Err(u) = ready(gate, id) {
        if Instant::now() > deadline {
            return Err(Ended(format!("not ready: {u}")));
        }
        std::thread::sleep(Duration::from_millis(10));
    }
    let first = d.reading(reading).expect("checked");
    // Engaging waits for what blocks it to clear (a device's first reports), as long
    // as the vehicle may take to report at all.
    while let Err(r) = gate.admit(Source::Bench, Ask::Engage, Instant::now()) {
        if Instant::now() > deadline || !matches!(r, safety::Refused::Blocked(_)) {
            return Err(Ended(format!("engage refused: {r}")));
        }
        std::thread::sleep(Duration::from_millis(10));
    }
    Ok(first)
}

/// What ends a run that commands device `id` at once: a signal, a disengage (STOP, a
/// fault, an override, the watchdog: named by its cause), another commander, a fault
/// of the device, a broken precondition.
pub(crate) fn interrupted(gate: &Gate, watch: &Watch, id: DeviceId) -> Result<(), Ended> {
    if let Some(why) = (watch.stop)() {
        return Err(Ended(format!("stopped: {why}")));
    }
    if !gate.is_engaged() {
        return Err(Ended(format!(
            "the vehicle was disengaged: {}",
            gate.cause().why()
        )));
    }
    match gate.commander() {
        Some(Source::Bench) => {}
        Some(other) => return Err(Ended(format!("the vehicle was taken by {other}"))),
        // Nobody commands an engaged vehicle only on its way to disengaged (a STOP, a
        // disengage, a trip take command away first): said as the disengage it is,
        // once it is one.
        None => {
            let until = Instant::now() + Duration::from_millis(200);
            while gate.is_engaged() && Instant::now() < until {
                std::thread::sleep(Duration::from_millis(1));
            }
            return Err(Ended(if gate.is_engaged() {
                "nobody commands the vehicle any more".into()
            } else {
                format!("the vehicle was disengaged: {}", gate.cause().why())
            }));
        }
    }
    let d = gate.vehicle().device(id);
    if let Some(f) = d.fault() {
        return Err(Ended(format!("{}: {f}", d.name())));
    }
    ready(gate, id)
        .map(|_| ())
        .map_err(|u| Ended(format!("precondition broken: {u}")))
}

/// Whether `device` can be characterized here: a setpoint actuator with a position
/// reading, on this vehicle.
pub(crate) fn check_device(gate: &Gate, device: &str) -> Result<(DeviceId, usize), String> {
    let v = gate.vehicle();
    let d = v
        .devices()
        .iter()
        .find(|d| d.name() == device)
        .ok_or_else(|| format!("no device {device:?} in this vehicle"))?;
    if d.kind() != Kind::Setpoint {
        return Err(format!(
            "{device} is a {} device: characterize measures a setpoint actuator",
            d.kind()
        ));
    }
    let position = d
        .config()
        .position()
        .ok_or_else(|| format!("{device} reports no position to measure"))?;
    Ok((d.id(), position))
}

impl<'a> Bench<'a> {
    /// Engage as the bench's own source, once the vehicle is ready and the device
    /// reports; `Err` says why not (nothing moved).
    pub(crate) fn engage(
        gate: &'a Gate,
        watch: &'a Watch<'a>,
        device: &str,
        procedures: &[Procedure],
        scope: &Scope,
    ) -> Result<Bench<'a>, Ended> {
        let (id, position) = check_device(gate, device).map_err(Ended)?;
        let full = gate.vehicle().device(id).config().range();
        scope.check(full).map_err(Ended)?;
        let set = engage_as_bench(gate, id, position, "position")?;
        let range = scope.range.unwrap_or(full);
        let now = Instant::now();
        let mut b = Bench {
            gate,
            watch,
            id,
            position,
            range,
            started: now,
            found: set,
            set,
            resend: resend_every(gate),
            sent: now - RESEND,
            last_at: None,
            samples: Vec::new(),
            still: (range[1] - range[0]) * 1e-4,
            delay: None,
            lag: None,
            settled: Vec::new(),
            residuals: Vec::new(),
            progress: Progress {
                stage: Stage::Starting,
                done: 0,
                total: plan(procedures, scope, range[1] - range[0])
                    .iter()
                    .map(|(_, n)| n)
                    .sum(),
                elapsed: Duration::ZERO,
            },
        };
        b.command(set)?;
        Ok(b)
    }

    /// A stage begins: say so.
    fn stage(&mut self, stage: Stage) {
        self.progress.stage = stage;
        self.report();
    }

    /// One move (or deadband probe) of the plan done: say so.
    fn moved(&mut self) {
        self.progress.done = (self.progress.done + 1).min(self.progress.total);
        self.report();
    }

    fn report(&mut self) {
        self.progress.elapsed = self.started.elapsed();
        (self.watch.progress)(&self.progress);
    }

    fn span(&self) -> f64 {
        self.range[1] - self.range[0]
    }

    /// The travel the procedures stay within: a twentieth of the range clear of each end.
    fn clamp(&self, v: f64) -> f64 {
        let m = self.span() / 20.0;
        v.clamp(self.range[0] + m, self.range[1] - m)
    }

    /// Send set point `v` through the intake, inside the travel ([`Bench::clamp`]); a
    /// refusal ends the run.
    fn command(&mut self, v: f64) -> Result<(), Ended> {
        self.send(self.clamp(v))
    }

    /// Send set point `v` through the intake as it is (the intake checks it against
    /// the device's range); a refusal ends the run.
    fn send(&mut self, v: f64) -> Result<(), Ended> {
        let now = Instant::now();
        self.gate
            .admit(Source::Bench, Ask::Set(self.id, Command::Set(v)), now)
            .map_err(|r| Ended(format!("refused: {r}")))?;
        self.set = v;
        self.sent = now;
        Ok(())
    }

    /// Seconds since the start.
    fn now(&self) -> f64 {
        self.started.elapsed().as_secs_f64()
    }

    /// One turn: end at once on a signal, a disengage (STOP, a fault, an override, the
    /// watchdog), a fault of the device or a broken precondition; keep the set point
    /// alive; take a new reading, if one came.
    fn tick(&mut self) -> Result<(), Ended> {
        std::thread::sleep(Duration::from_millis(1));
        interrupted(self.gate, self.watch, self.id)?;
        let v = self.gate.vehicle();
        let d = v.device(self.id);
        if self.sent.elapsed() >= self.resend {
            self.send(self.set)?;
        }
        let fresh = fresh(d, &mut self.last_at, self.started).filter(|f| !f.loose);
        if let Some(Fresh { reading, t, .. }) = fresh {
            if let Some(y) = reading.get(self.position) {
                self.samples.push(Sample {
                    t,
                    commanded: self.set,
                    measured: y,
                });
            }
        }
        Ok(())
    }

    fn wait(&mut self, d: Duration) -> Result<(), Ended> {
        let end = Instant::now() + d;
        while Instant::now() < end {
            self.tick()?;
        }
        Ok(())
    }

    fn last(&self) -> f64 {
        self.samples.last().map_or(self.set, |s| s.measured)
    }

    /// Wait until the reading stays still for [`STILL_FOR`] (and a few lags more,
    /// once the lag is known); the mean of its last 50 ms.
    fn settle(&mut self) -> Result<f64, Ended> {
        let deadline = Instant::now() + SETTLE_WITHIN;
        let from = self.samples.len();
        loop {
            self.tick()?;
            let now = self.now();
            let window: Vec<f64> = self.samples[from..]
                .iter()
                .filter(|s| s.t >= now - STILL_FOR.as_secs_f64())
                .map(|s| s.measured)
                .collect();
            let covered = self.samples[from..]
                .first()
                .is_some_and(|s| s.t <= now - STILL_FOR.as_secs_f64());
            let (lo, hi) = window
                .iter()
                .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &x| {
                    (a.min(x), b.max(x))
                });
            if covered && window.len() >= 3 && hi - lo <= self.still * 2.0 {
                break;
            }
            if Instant::now() > deadline {
                return Err(Ended(format!(
                    "the device did not settle within {} s",
                    SETTLE_WITHIN.as_secs()
                )));
            }
        }
        if let Some(l) = self.lag {
            self.wait(Duration::from_secs_f64(4.0 * l))?;
        }
        let now = self.now();
        let last: Vec<f64> = self
            .samples
            .iter()
            .rev()
            .take_while(|s| s.t >= now - 0.05)
            .map(|s| s.measured)
            .collect();
        let (m, _) = analyze::mean_sd(&last).unwrap_or((self.last(), 0.0));
        self.residuals.extend(last.iter().map(|x| x - m));
        Ok(m)
    }

    /// Go to `v` (a move larger than any deadband) and settle there: the settled
    /// reading, and the samples from the command on.
    fn move_to(&mut self, v: f64) -> Result<(f64, f64, usize), Ended> {
        let before = self.last();
        let from = self.samples.len();
        self.command(v)?;
        let mut at = None;
        let target = self.set;
        let deadline = Instant::now() + START_WITHIN;
        let moved = (target - before).abs() * 0.05;
        while at.is_none() || (self.last() - before).abs() <= moved.max(self.still * 2.0) {
            self.tick()?;
            at = at.or_else(|| self.arrived(target));
            if Instant::now() > deadline {
                return Err(Ended(format!(
                    "the device did not move toward {target} within {} s",
                    START_WITHIN.as_secs()
                )));
            }
        }
        let y = self.settle()?;
        self.settled
            .push(((target * 1e6).round() as i64, target > before, y));
        self.moved();
        Ok((y, at.unwrap_or_default(), from))
    }

    /// When set point `target` reached the device, seconds since the start, once it
    /// acknowledged it ([`arrived`]).
    fn arrived(&self, target: f64) -> Option<f64> {
        arrived(
            self.gate.vehicle().device(self.id),
            Command::Set(target),
            self.started,
        )
    }

    /// Large steps up and down, each approached in its own direction (so the play is
    /// taken up before it): the step figures each way, and where it settles.
    pub(crate) fn steps(&mut self, reps: usize, f: &mut Figures) -> Result<(), Ended> {
        let (m, s) = ((self.range[0] + self.range[1]) / 2.0, self.span());
        for _ in 0..reps {
            self.step_pair(m - 0.3 * s, m + 0.3 * s, 0.15 * s, false, f)?;
            self.delay = f.delay();
            self.lag = f.lag();
        }
        Ok(())
    }

    /// Small steps up and down about the middle, each approached in its own direction:
    /// a tenth of the range, or twice `deadband` if that is more (so each one moves it).
    pub(crate) fn small_steps(
        &mut self,
        reps: usize,
        deadband: Option<f64>,
        f: &mut Figures,
    ) -> Result<(), Ended> {
        let (m, s) = ((self.range[0] + self.range[1]) / 2.0, self.span());
        let size = (0.1 * s).max(2.0 * deadband.unwrap_or(0.0)).min(0.3 * s);
        for _ in 0..reps {
            self.step_pair(m - size / 2.0, m + size / 2.0, 0.15 * s, true, f)?;
        }
        Ok(())
    }

    /// A step from `a` up to `b` and one from `b` down to `a`, each approached from
    /// `lead` beyond its start; their figures and responses go into `f`.
    fn step_pair(
        &mut self,
        a: f64,
        b: f64,
        lead: f64,
        small: bool,
        f: &mut Figures,
    ) -> Result<(), Ended> {
        for (from_, to, before) in [(a, b, a - lead), (b, a, b + lead)] {
            self.move_to(before)?;
            let (start, _, _) = self.move_to(from_)?;
            let (end, at, from) = self.move_to(to)?;
            let samples = &self.samples[from..];
            if let Some(x) = analyze::step(samples, at, start, end) {
                match (small, to > from_) {
                    (false, true) => f.up.push(x),
                    (false, false) => f.down.push(x),
                    (true, true) => f.small_up.push(x),
                    (true, false) => f.small_down.push(x),
                }
            }
            f.responses.push(Response {
                small,
                samples: samples
                    .iter()
                    .map(|s| Sample { t: s.t - at, ..*s })
                    .collect(),
            });
        }
        Ok(())
    }

    /// The smallest step up that moves it, by halving: from a point approached from
    /// below, a step either moves it (the point it follows is then the new one) or not.
    pub(crate) fn deadband(&mut self, steps: usize) -> Result<Deadband, Ended> {
        let (m, s) = ((self.range[0] + self.range[1]) / 2.0, self.span());
        let base0 = m - 0.35 * s;
        self.move_to(base0 - 0.15 * s)?;
        self.move_to(base0)?;
        let mut base = self.set;
        let (mut lo, mut hi) = (0.0, DEADBAND_FROM * s);
        let wait = self.delay.unwrap_or(0.1) + 5.0 * self.lag.unwrap_or(0.02) + 0.05;
        for _ in 0..steps {
            let step = (lo + hi) / 2.0;
            let before = self.last();
            self.command(base + step)?;
            let end = Instant::now() + Duration::from_secs_f64(wait);
            let mut moved = false;
            while Instant::now() < end {
                self.tick()?;
                if self.seen_to_move(before) {
                    moved = true;
                    break;
                }
            }
            if moved {
                self.settle()?;
                base = self.set;
                hi = step;
            } else {
                lo = step;
            }
            self.moved();
        }
        // A step no larger than twice the resolution may not change what is sent or
        // what is read at all (a protocol rounds both): not moving it says nothing.
        Ok(if lo >= 2.0 * self.resolution() {
            Deadband::Measured(hi)
        } else {
            Deadband::Below(hi)
        })
    }

    /// Whether the reading has moved from `before`, as far as the readings show: past
    /// four times their stillness.
    fn seen_to_move(&self, before: f64) -> bool {
        (self.last() - before).abs() > self.still * 4.0
    }

    /// The smallest move the readings resolve: what [`Bench::seen_to_move`] needs, and
    /// no finer than the smallest step seen between two readings (a protocol that
    /// writes thousandths reads in thousandths).
    fn resolution(&self) -> f64 {
        let rounding = self.still * 1e-3;
        let quantum = self
            .samples
            .windows(2)
            .map(|w| (w[1].measured - w[0].measured).abs())
            .filter(|d| *d > rounding)
            .fold(f64::INFINITY, f64::min);
        (self.still * 4.0).max(if quantum.is_finite() { quantum } else { 0.0 })
    }

    /// Points up the range and back down, each settled: (commanded, measured) each way.
    ///
    /// A `fine` sweep (`--resolution`, or a part of the range) may step less than the
    /// deadband: a point the device does not move to is where it stays
    /// ([`Bench::probe_to`]).
    pub(crate) fn sweep(&mut self, points: usize, fine: bool) -> Result<(Settled, Settled), Ended> {
        let s = self.span();
        let at: Vec<f64> = (0..points)
            .map(|i| {
                self.range[0]
                    + s * ((1.0 - SWEEP_SHARE) / 2.0
                        + SWEEP_SHARE * i as f64 / (points - 1).max(1) as f64)
            })
            .collect();
        self.sweep_to(self.range[0], fine)?;
        let mut up = Vec::new();
        for &c in &at {
            let y = self.sweep_to(c, fine)?;
            up.push((self.set, y));
        }
        self.sweep_to(self.range[1], fine)?;
        let mut down = Vec::new();
        for &c in at.iter().rev() {
            let y = self.sweep_to(c, fine)?;
            down.push((self.set, y));
        }
        Ok((up, down))
    }

    /// A sweep's point: a move ([`Bench::move_to`]), or where a `probe` settles.
    fn sweep_to(&mut self, c: f64, probe: bool) -> Result<f64, Ended> {
        if probe {
            self.probe_to(c)
        } else {
            self.move_to(c).map(|(y, _, _)| y)
        }
    }

    /// Go toward `v`, a step that may be within the deadband: wait as long as a move
    /// takes to start (its delay and lags, once known), then settle, moved or not.
    fn probe_to(&mut self, v: f64) -> Result<f64, Ended> {
        let before = self.last();
        self.command(v)?;
        let target = self.set;
        let wait = self.delay.unwrap_or(0.1) + 5.0 * self.lag.unwrap_or(0.02) + 0.05;
        let end = Instant::now() + Duration::from_secs_f64(wait);
        while Instant::now() < end {
            self.tick()?;
            if self.seen_to_move(before) {
                break;
            }
        }
        let y = self.settle()?;
        self.settled
            .push(((target * 1e6).round() as i64, target > before, y));
        Ok(y)
    }

    /// How far settled readings at one point, approached one way, spread (max − min).
    fn repeatability(&self) -> Option<f64> {
        let mut worst: Option<f64> = None;
        for (i, (p, dir, _)) in self.settled.iter().enumerate() {
            let same: Vec<f64> = self.settled[i..]
                .iter()
                .filter(|(q, d, _)| q == p && d == dir)
                .map(|x| x.2)
                .collect();
            if same.len() > 1 {
                let (lo, hi) = same
                    .iter()
                    .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &x| {
                        (a.min(x), b.max(x))
                    });
                worst = Some(worst.map_or(hi - lo, |w: f64| w.max(hi - lo)));
            }
        }
        worst
    }

    /// Bring the device back to where it was found, and let go (disengage: the safe
    /// state).
    fn finish(mut self, home: f64) -> Result<Vec<Sample>, Ended> {
        self.stage(Stage::Home);
        // Where it was found, though that be outside the part characterized; a move
        // waits out the device's delay, unknown to a sweep alone (a step within the
        // deadband does not move it: then it waits as long as a move may take to start).
        let before = self.last();
        self.send(home)?;
        let end = Instant::now() + START_WITHIN;
        while Instant::now() < end && !self.seen_to_move(before) {
            self.tick()?;
        }
        self.settle()?;
        self.moved();
        self.gate
            .disengage(DisengageCause::Characterize { ended: None });
        Ok(self.samples)
    }
}

/// What a characterization measured, by the kind of device.
pub(crate) enum Measured {
    Setpoint(Box<Figures>),
    State(state::Figures),
    Sensor(sensor::Figures),
}

impl Measured {
    /// How long it took, seconds.
    pub(crate) fn took(&self) -> f64 {
        match self {
            Measured::Setpoint(f) => f.took,
            Measured::State(f) => f.took,
            Measured::Sensor(f) => f.took,
        }
    }

    /// `summary.json`'s object.
    pub(crate) fn summary(&self) -> serde_json::Value {
        match self {
            Measured::Setpoint(f) => write::summary(f),
            Measured::State(f) => state::summary(f),
            Measured::Sensor(f) => sensor::summary(f),
        }
    }

    /// Every file into `dir`.
    pub(crate) fn write_all(&self, dir: &std::path::Path) -> std::io::Result<()> {
        match self {
            Measured::Setpoint(f) => write::all(dir, f),
            Measured::State(f) => state::write_all(dir, f),
            Measured::Sensor(f) => sensor::write_all(dir, f),
        }
    }
}

/// Characterize `device`, whatever its kind: a setpoint actuator by `procedures`, a
/// state actuator by its transitions, a sensor by listening.
pub(crate) fn run_any(
    gate: &Gate,
    watch: &Watch,
    device: &str,
    procedures: &[Procedure],
    scope: &Scope,
) -> Result<Measured, Ended> {
    let kind = gate
        .vehicle()
        .find(device)
        .map(|d| d.kind())
        .ok_or_else(|| Ended(format!("no device {device:?} in this vehicle")))?;
    match kind {
        Kind::Setpoint => {
            run(gate, watch, device, procedures, scope).map(|f| Measured::Setpoint(Box::new(f)))
        }
        Kind::State => state::run(gate, watch, device).map(Measured::State),
        Kind::Sensor => sensor::run(gate, watch, device).map(Measured::Sensor),
    }
}

/// Run the procedures asked for on `device` of the engaged-and-ready vehicle behind
/// `gate`; every way out of here but success has disengaged it (the safe state).
pub(crate) fn run(
    gate: &Gate,
    watch: &Watch,
    device: &str,
    procedures: &[Procedure],
    scope: &Scope,
) -> Result<Figures, Ended> {
    let mut bench = Bench::engage(gate, watch, device, procedures, scope)?;
    let home = bench.found;
    let result = measure(&mut bench, procedures, scope);
    let mut f = match result {
        Ok(f) => f,
        Err(e) => {
            gate.disengage(DisengageCause::Characterize {
                ended: Some(e.to_string()),
            });
            return Err(e);
        }
    };
    f.repeatability = bench.repeatability();
    let (_, sd) = analyze::mean_sd(&bench.residuals).unwrap_or((0.0, 0.0));
    f.noise = Some(sd);
    let started = bench.started;
    f.samples = match bench.finish(home) {
        Ok(s) => s,
        Err(e) => {
            gate.disengage(DisengageCause::Characterize {
                ended: Some(e.to_string()),
            });
            return Err(e);
        }
    };
    f.took = started.elapsed().as_secs_f64();
    let stats = gate.vehicle().device(bench_id(gate, device)?).stats();
    stats.refresh();
    f.command_path = Some(stats.command_delay.summary());
    f.command_path_buckets = stats.command_delay.buckets();
    Ok(f)
}

fn bench_id(gate: &Gate, device: &str) -> Result<DeviceId, Ended> {
    check_device(gate, device).map(|(id, _)| id).map_err(Ended)
}

fn measure(b: &mut Bench, procedures: &[Procedure], scope: &Scope) -> Result<Figures, Ended> {
    let d = b.gate.vehicle().device(b.id);
    let mut f = Figures {
        device: d.name().to_string(),
        units: d.config().units.clone(),
        range: b.range,
        ..Figures::default()
    };
    let wants = |p: &[Procedure]| p.iter().any(|x| procedures.contains(x));
    if wants(STEPS_FOR) {
        b.stage(Stage::Steps);
        b.steps(STEP_REPS, &mut f)?;
    }
    if wants(&[Procedure::Deadband]) {
        b.stage(Stage::Deadband);
        f.deadband = Some(b.deadband(scope.deadband_steps(b.span()))?);
    }
    if wants(&[Procedure::Sweep, Procedure::Backlash]) {
        b.stage(Stage::Sweep);
        let fine = scope.resolution.is_some() || scope.range.is_some();
        let (up, down) = b.sweep(scope.sweep_points(b.span()), fine)?;
        let (map, line) = analyze::static_map(&up, &down);
        f.map = map;
        f.gain_offset = line;
        f.backlash = analyze::backlash(&up, &down);
        f.sweep = Some((up, down));
    }
    if wants(&[Procedure::Step]) {
        b.stage(Stage::SmallSteps);
        b.small_steps(SMALL_REPS, f.deadband.map(Deadband::value), &mut f)?;
    }
    Ok(f)
}

/// The procedures that need the large steps (their delay and lag, for the deadband).
const STEPS_FOR: &[Procedure] = &[
    Procedure::Step,
    Procedure::Rate,
    Procedure::Delay,
    Procedure::Deadband,
];
/// Large steps each way, and small steps each way.
const STEP_REPS: usize = 3;
const SMALL_REPS: usize = 1;

/// A stage of a run, in the order they run: what the progress names.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Stage {
    /// Waiting for the device's first reading, the precondition, the engage.
    Starting,
    /// The large steps (step, rate, delay, and what the deadband needs).
    Steps,
    Deadband,
    /// Up the range and back down (sweep, backlash).
    Sweep,
    SmallSteps,
    /// Back to where the device was found.
    Home,
}

impl std::fmt::Display for Stage {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            Stage::Starting => "starting",
            Stage::Steps => "large steps",
            Stage::Deadband => "deadband",
            Stage::Sweep => "sweep",
            Stage::SmallSteps => "small steps",
            Stage::Home => "back home",
        })
    }
}

/// The moves (each a command and its settling, or a deadband probe) each stage of
/// `procedures` takes, in order: what a run's progress counts.
pub(crate) fn plan(procedures: &[Procedure], scope: &Scope, span: f64) -> Vec<(Stage, usize)> {
    let wants = |p: &[Procedure]| p.iter().any(|x| procedures.contains(x));
    let mut out = Vec::new();
    if wants(STEPS_FOR) {
        // Each pair: each way, its lead-in, its start and the step.
        out.push((Stage::Steps, STEP_REPS * 2 * 3));
    }
    if wants(&[Procedure::Deadband]) {
        out.push((Stage::Deadband, 2 + scope.deadband_steps(span)));
    }
    if wants(&[Procedure::Sweep, Procedure::Backlash]) {
        out.push((Stage::Sweep, 2 * (scope.sweep_points(span) + 1)));
    }
    if wants(&[Procedure::Step]) {
        out.push((Stage::SmallSteps, SMALL_REPS * 2 * 3));
    }
    out.push((Stage::Home, 1));
    out
}

/// Where a run stands.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Progress {
    pub stage: Stage,
    /// Moves done, of `total` planned ([`plan`]).
    pub done: usize,
    pub total: usize,
    /// Since it engaged.
    pub elapsed: Duration,
}

impl Progress {
    /// How long is left, at the pace so far (`None` before the first move: no pace yet).
    pub(crate) fn left(&self) -> Option<Duration> {
        if self.done == 0 {
            return None;
        }
        let per = self.elapsed.as_secs_f64() / self.done as f64;
        Some(Duration::from_secs_f64(
            per * self.total.saturating_sub(self.done) as f64,
        ))
    }
}

/// How a run is watched: where its progress goes as it goes, and what ends it early
/// (`Some(why)`: a signal, the operator leaving), checked at every sample.
pub(crate) struct Watch<'a> {
    pub progress: &'a dyn Fn(&Progress),
    pub stop: &'a dyn Fn() -> Option<String>,
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The incident: a lag measured 4 % slow on a busy machine — its tail's readings
    /// dated when a late wake-up read them. A reading is dated halfway through the poll
    /// that read it; one whose poll stalled is marked loose (a response leaves it out, a
    /// bracket takes it as anywhere in its poll);
    /// a reading no request asked for (a bus's) is dated half a median poll before it
    /// came.
    #[test]
    fn a_reading_is_dated_within_its_poll_and_one_whose_poll_stalled_is_marked_loose() {
        let start = Instant::now();
        let g = crate::testkit::gate(start);
        let d = g.vehicle().device(g.vehicle().find("steer").unwrap().id());
        for _ in 0..20 {
            d.stats().status_txn.record(Duration::from_millis(2));
        }
        // The median poll: 2 ms (the summary read is refreshed only now and then).
        let p50 = d.stats().status_txn.summary_now().p50_us.unwrap();
        assert!((p50 - 2000.0).abs() < 40.0, "{p50}");
        let ms = |n: u64| Duration::from_millis(n);
        let read = |asked: Option<Instant>, at: Instant| {
            d.store(crate::vehicle::Cached {
                reading: crate::value::Reading::default(),
                at: Some(at),
                asked,
            });
        };
        let mut last = None;
        let dated = |last: &mut Option<Instant>| {
            fresh(d, last, start).map(|f| {
                let (lo, hi) = f.bounds();
                assert!(lo <= f.t && f.t <= hi, "{lo} {} {hi}", f.t);
                (f.t, f.loose, (lo, hi))
            })
        };
        // A poll of 2.5 ms: halfway through it.
        read(
            Some(start + ms(10)),
            start + ms(10) + Duration::from_micros(2500),
        );
        let (t, loose, bounds) = dated(&mut last).unwrap();
        assert!((t - 0.01125).abs() < 1e-6 && !loose, "{t}");
        assert_eq!(bounds, (t, t));
        // Nothing new: nothing.
        assert!(dated(&mut last).is_none());
        // A poll that took 5 ms of a median 2: loosely dated, taken anywhere in it.
        read(Some(start + ms(20)), start + ms(25));
        let (_, loose, (lo, hi)) = dated(&mut last).unwrap();
        assert!(loose);
        assert!(
            (lo - 0.020).abs() < 1e-6 && (hi - 0.025).abs() < 1e-6,
            "{lo} {hi}"
        );
        // 4 ms is still within half as long again and 1 ms.
        read(Some(start + ms(30)), start + ms(34));
        let (t, loose, _) = dated(&mut last).unwrap();
        assert!((t - 0.032).abs() < 1e-6 && !loose, "{t}");
        // Unasked: half a median poll before it came (a bucket's edge, within 2 %).
        read(None, start + ms(40));
        let (t, loose, bounds) = dated(&mut last).unwrap();
        assert!((t - 0.039).abs() < 2e-5 && !loose, "{t}");
        assert_eq!(bounds, (t, t));
    }

    /// A STOP (or a disengage) takes command away, then disengages: a run that looks
    /// between the two is not told another source took the vehicle; it waits for the
    /// disengage and says it, with its cause.
    #[test]
    fn a_stop_half_done_is_not_another_source_taking_the_vehicle() {
        let t = Instant::now();
        let g = crate::testkit::gate(t);
        let id = g.vehicle().find("steer").unwrap().id();
        let no_stop = || None;
        let watch = Watch {
            progress: &|_| {},
            stop: &no_stop,
        };
        assert_eq!(
            g.admit(Source::Bench, Ask::Engage, t),
            Ok(crate::safety::Done::Engaged)
        );
        // Command taken away, the vehicle still engaged: no one took it.
        g.state().owner().nobody();
        let Err(Ended(said)) = interrupted(&g, &watch, id) else {
            panic!("a run nobody commands goes on");
        };
        assert_eq!(said, "nobody commands the vehicle any more");
        // The disengage done: said with its cause.
        g.disengage(DisengageCause::Stop {
            by: "operator".into(),
        });
        let Err(Ended(said)) = interrupted(&g, &watch, id) else {
            panic!("a run on a disengaged vehicle goes on");
        };
        assert!(
            said.starts_with("the vehicle was disengaged: ") && said.contains("stop from operator"),
            "{said}"
        );
    }

    /// The lag is the steps' median where most showed one: a step a stall thinned out
    /// does not take it away, a drive that stops at its rate has none.
    #[test]
    fn the_lag_is_the_steps_median_where_most_showed_one() {
        let step = |lag: Option<f64>| StepFigures {
            lag,
            ..StepFigures::default()
        };
        let figures = |lags: &[Option<f64>]| Figures {
            up: lags[..3].iter().map(|&l| step(l)).collect(),
            down: lags[3..].iter().map(|&l| step(l)).collect(),
            ..Figures::default()
        };
        let l = Some(0.08);
        assert_eq!(figures(&[l, l, l, l, l, l]).lag(), Some(0.08));
        assert_eq!(
            figures(&[l, Some(0.07), None, l, Some(0.09), l]).lag(),
            Some(0.08)
        );
        assert_eq!(figures(&[l, None, None, l, None, l]).lag(), None);
        assert_eq!(figures(&[None; 6]).lag(), None);
    }

    /// The plan counts every move the procedures make, as the docs count them: 18
    /// large, 13 for the deadband (its two lead-ins and eleven probes), 12 for the
    /// sweep, 6 small, and the way home.
    #[test]
    fn the_plan_counts_each_stages_moves() {
        let plan = |p: &[Procedure]| plan(p, &Scope::default(), 2.0);
        let total = |p: &[Procedure]| plan(p).iter().map(|(_, n)| n).sum::<usize>();
        assert_eq!(
            plan(&Procedure::ALL),
            [
                (Stage::Steps, 18),
                (Stage::Deadband, 13),
                (Stage::Sweep, 12),
                (Stage::SmallSteps, 6),
                (Stage::Home, 1)
            ]
        );
        assert_eq!(total(&[Procedure::Sweep]), 13);
        assert_eq!(total(&[Procedure::Deadband]), 18 + 13 + 1);
        assert_eq!(total(&[Procedure::Step]), 18 + 6 + 1);
    }

    #[test]
    fn what_is_left_is_the_pace_so_far_times_the_moves_to_come() {
        let p = |done, secs| Progress {
            stage: Stage::Steps,
            done,
            total: 50,
            elapsed: Duration::from_secs(secs),
        };
        assert_eq!(p(0, 3).left(), None);
        assert_eq!(p(10, 6).left(), Some(Duration::from_secs(24)));
        assert_eq!(p(50, 30).left(), Some(Duration::ZERO));
        assert_eq!(p(60, 30).left(), Some(Duration::ZERO));
    }
}
