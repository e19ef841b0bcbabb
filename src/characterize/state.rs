//! `adrive characterize` of a state actuator (a gearbox): how long each transition
//! takes, from the command's arrival at the device to the first reading of the new
//! state, for every ordered pair of its states, each several times — and the
//! `[device.sim]` (`settle`, `transit`) that makes the simulator shift like it.
//!
//! It shifts the device on its own, so it runs as the setpoint procedures do: through
//! the one intake as the bench's own source, engaged, every rule applied (a shift only
//! stopped with the brake held), ended at once by what ends any run
//! ([`super::interrupted`]); a gearbox under test may leave park, the brake holding the
//! vehicle ([`crate::safety::bench::ready`]). It walks every transition once per round
//! in one circuit from the state it found the device in back to it ([`circuit`]), so it
//! ends where it began before it lets go.
//!
//! A reading is timed at the middle of its status transaction, a command at the middle
//! of its command transaction, as for a setpoint actuator; the new state is taken to
//! have come halfway between the last reading without it and the first with it, so
//! each time is good to half the interval between readings ([`bracket`]: a reading
//! whose poll stalled on a busy machine counts as taken anywhere in its poll). The
//! readings' period is drawn anew for each shift ([`Shifter::vary_polls`]), so the
//! shift time falls anywhere between two readings, and the simulator's `settle` is
//! where most of the shifts' brackets overlap ([`analyze::deepest`]): good to a few ms.

use super::analyze::{self, Sample};
use super::write::{self, Frame, COMMAND, UP};
use super::{engage_as_bench, interrupted, resend_every, Ended, RESEND, SETTLE_WITHIN};
use crate::engine::Gate;
use crate::safety::Ask;
use crate::snapshot::DisengageCause;
use crate::value::{Command, DeviceId, Source};
use std::fmt::Write as _;
use std::path::Path;
use std::time::{Duration, Instant};

/// How many times each transition is timed.
pub(crate) const ROUNDS: usize = 5;

/// One transition's times, ms: each the middle of its [`Transition::within`].
#[derive(Clone, Debug, Default, PartialEq)]
pub(crate) struct Transition {
    pub from: u8,
    pub to: u8,
    pub ms: Vec<f64>,
    /// Each time's bracket: from the last reading without the new state to the first
    /// with it (ms after the command's arrival).
    pub within: Vec<(f64, f64)>,
}

/// What a state actuator's characterization measured.
#[derive(Clone, Debug, Default)]
pub(crate) struct Figures {
    pub device: String,
    pub states: Vec<String>,
    /// Every ordered pair, in the order first taken.
    pub transitions: Vec<Transition>,
    /// The state it reports mid-shift, where the shifts show one.
    pub transit: Option<u8>,
    /// Every reading: the state commanded and the state read, as numbers.
    pub samples: Vec<Sample>,
    /// The median interval between readings, seconds.
    pub interval: f64,
    /// How long it took, seconds.
    pub took: f64,
}

impl Figures {
    fn name(&self, s: u8) -> String {
        self.states
            .get(usize::from(s))
            .cloned()
            .unwrap_or_else(|| s.to_string())
    }

    /// The shift time the simulator's `settle` takes, seconds: the time most of the
    /// brackets of every transition not into the transit state (which the simulator
    /// reports at once) agree on ([`analyze::deepest`]) — good to far less than one
    /// bracket, whose width is an interval between readings.
    pub(crate) fn settle(&self) -> Option<f64> {
        let all: Vec<(f64, f64)> = self
            .transitions
            .iter()
            .filter(|t| Some(t.to) != self.transit)
            .flat_map(|t| t.within.iter().copied())
            .collect();
        analyze::deepest(&all).map(|ms| ms / 1e3)
    }
}

/// Every ordered pair of `n` states once, as one walk from `home` back to `home` (an
/// Eulerian circuit of the complete directed graph: every state has as many ways in as
/// out, so one exists; Hierholzer's algorithm finds it).
pub(crate) fn circuit(n: u8, home: u8) -> Vec<(u8, u8)> {
    let mut unused: Vec<Vec<u8>> = (0..n)
        .map(|a| (0..n).filter(|&b| b != a).rev().collect())
        .collect();
    let (mut stack, mut path) = (vec![home], Vec::new());
    while let Some(&v) = stack.last() {
        match unused[usize::from(v)].pop() {
            Some(w) => stack.push(w),
            None => path.extend(stack.pop()),
        }
    }
    path.reverse();
    path.windows(2).map(|w| (w[0], w[1])).collect()
}

/// The run: the one commander of the engaged vehicle, shifting one device.
struct Shifter<'a> {
    gate: &'a Gate,
    watch: &'a super::Watch<'a>,
    id: DeviceId,
    reading: usize,
    started: Instant,
    set: u8,
    sent: Instant,
    last_at: Option<Instant>,
    samples: Vec<Sample>,
    /// When each sample was taken, at the earliest and the latest ([`super::Fresh::bounds`]).
    taken: Vec<(f64, f64)>,
    /// The next resend's interval, and where it is drawn from.
    resend: Duration,
    draw: u64,
}

impl Shifter<'_> {
    /// The interval to the next resend, drawn from half of [`resend_every`] to all of it. Each
    /// resend is a command transaction the polls wait for, so resends at a fixed
    /// interval would lock the polls' phase to the shift, and a shift time would always
    /// fall at the same place between two readings: drawn, the place is anywhere, and
    /// the median over the rounds is not biased by it.
    fn next_resend(&mut self) -> Duration {
        resend_every(self.gate).mul_f64(0.5 + 0.5 * self.uniform())
    }

    /// A number drawn from [0, 1).
    fn uniform(&mut self) -> f64 {
        self.draw ^= self.draw << 13;
        self.draw ^= self.draw >> 7;
        self.draw ^= self.draw << 17;
        (self.draw >> 11) as f64 / (1u64 << 53) as f64
    }

    /// Draw the readings' period for the next shift, from one status transaction to
    /// one and a half. Polled back to back, the readings' phase is locked to the
    /// shift's command (the first poll waits for it), and a resend moves it by only
    /// the difference between a command's transaction and a poll's, which on a
    /// register-mapped gearbox is a byte: every shift time would fall at the same
    /// place between two readings, and its median be off by up to half their
    /// interval. Drawn, the place is anywhere and the median unbiased.
    fn vary_polls(&mut self) {
        let d = self.gate.vehicle().device(self.id);
        let Some(txn) = d.stats().status_txn.summary().p50_us else {
            return;
        };
        let period = Duration::from_secs_f64(txn * 1e-6 * (1.0 + 0.5 * self.uniform()));
        // A period past the device's limits leaves it polled as it was.
        let _ = d.change_settings(|c| c.status_period = period);
    }

    fn command(&mut self, s: u8) -> Result<(), Ended> {
        let now = Instant::now();
        self.gate
            .admit(Source::Bench, Ask::Set(self.id, Command::State(s)), now)
            .map_err(|r| Ended(format!("refused: {r}")))?;
        self.set = s;
        self.sent = now;
        self.resend = self.next_resend();
        Ok(())
    }

    /// One turn: end at once on what ends any run; keep the command alive; take a new
    /// reading, if one came (one after a stall of the machine is left out: when it was
    /// taken is not known; one whose own poll stalled is kept, taken anywhere in it).
    fn tick(&mut self) -> Result<(), Ended> {
        std::thread::sleep(Duration::from_millis(1));
        interrupted(self.gate, self.watch, self.id)?;
        if self.sent.elapsed() >= self.resend {
            self.command(self.set)?;
        }
        let d = self.gate.vehicle().device(self.id);
        if let Some(f) = super::fresh(d, &mut self.last_at, self.started) {
            if let Some(y) = f.reading.get(self.reading) {
                self.samples.push(Sample {
                    t: f.t,
                    commanded: f64::from(self.set),
                    measured: y,
                });
                self.taken.push(f.bounds());
            }
        }
        Ok(())
    }

    /// When state `s` reached the device, seconds since the start, once it
    /// acknowledged it ([`super::arrived`]).
    fn arrived(&self, s: u8) -> Option<f64> {
        super::arrived(
            self.gate.vehicle().device(self.id),
            Command::State(s),
            self.started,
        )
    }

    fn shows(&self, s: u8) -> bool {
        self.samples
            .last()
            .is_some_and(|x| x.measured == f64::from(s))
    }

    /// Shift to `to` and wait for a reading of it: when the new state came (ms after
    /// the command's arrival), bracketed by the last reading without it and the first
    /// with it, and the states read in between that are neither the old one nor the new.
    fn shift(&mut self, to: u8) -> Result<((f64, f64), Vec<u8>), Ended> {
        let from = self.set;
        let n0 = self.samples.len();
        self.vary_polls();
        self.command(to)?;
        let deadline = Instant::now() + SETTLE_WITHIN;
        let mut at = None;
        // Wait for the acknowledgement, and a reading of the new state taken after it.
        loop {
            self.tick()?;
            at = at.or_else(|| self.arrived(to));
            if let Some(a) = at {
                if self.shows(to) && self.samples.last().is_some_and(|x| x.t > a) {
                    break;
                }
            }
            if Instant::now() > deadline {
                return Err(Ended(format!(
                    "the device did not reach {to} within {} s",
                    SETTLE_WITHIN.as_secs()
                )));
            }
        }
        let at = at.expect("waited for");
        let (first, (before, after)) = bracket(&self.samples, &self.taken, n0, to, at);
        let between = self.samples[n0..first]
            .iter()
            .filter(|x| x.t > at)
            .map(|x| x.measured as u8)
            .filter(|&s| s != from && s != to)
            .collect();
        Ok((((before - at) * 1e3, (after - at) * 1e3), between))
    }
}

/// When state `to`, commanded to arrive at `at`, came, seconds after the start: the
/// first of the readings since `n0` from which on every one shows it (its index), and
/// the bracket from the last reading without it (at its earliest: the state changed
/// after it was taken) to that first one (at its latest: before it was taken), neither
/// before `at`. A reading whose poll stalled widens the bracket by what is not known of
/// it and never moves it past the truth, as leaving it out would (to the next reading).
/// The last sample shows `to`.
fn bracket(
    samples: &[Sample],
    taken: &[(f64, f64)],
    n0: usize,
    to: u8,
    at: f64,
) -> (usize, (f64, f64)) {
    let to = f64::from(to);
    let first = (n0..samples.len())
        .find(|&i| samples[i..].iter().all(|x| x.measured == to))
        .expect("the last reading shows it");
    let before = first.checked_sub(1).map_or(at, |i| taken[i].0.max(at));
    (first, (before, taken[first].1.max(at)))
}

/// The most frequent state read between the old and the new one, if at least half the
/// shifts that could show it (neither from it nor into it) did.
fn transit(seen: &[(u8, u8, Vec<u8>)]) -> Option<u8> {
    let mut counts = std::collections::BTreeMap::<u8, usize>::new();
    for (_, _, between) in seen {
        let mut b = between.clone();
        b.dedup();
        for s in b {
            *counts.entry(s).or_default() += 1;
        }
    }
    let (&s, &n) = counts.iter().max_by_key(|(_, n)| **n)?;
    let could = seen
        .iter()
        .filter(|(from, to, _)| *from != s && *to != s)
        .count();
    (2 * n >= could).then_some(s)
}

/// Time every transition of state device `device` ([`ROUNDS`] times each); every way
/// out of here but success has disengaged the vehicle (the safe state).
pub(crate) fn run(gate: &Gate, watch: &super::Watch, device: &str) -> Result<Figures, Ended> {
    let v = gate.vehicle();
    let d = v
        .find(device)
        .ok_or_else(|| Ended(format!("no device {device:?} in this vehicle")))?;
    let reading = d
        .config()
        .state()
        .ok_or_else(|| Ended(format!("{device} reports no state to measure")))?;
    let id = d.id();
    let states = d.config().states.clone();
    let found = engage_as_bench(gate, id, reading, "state")? as u8;
    let period = d.settings().status_period();
    let now = Instant::now();
    let mut s = Shifter {
        gate,
        watch,
        id,
        reading,
        started: now,
        set: found,
        sent: now - RESEND,
        last_at: None,
        samples: Vec::new(),
        taken: Vec::new(),
        resend: resend_every(gate),
        draw: std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map_or(1, |d| d.as_nanos() as u64)
            | 1,
    };
    let ended = |e: Ended| {
        gate.disengage(DisengageCause::Characterize {
            ended: Some(e.to_string()),
        });
        e
    };
    let plan = circuit(states.len() as u8, found);
    let mut transitions: Vec<Transition> = plan
        .iter()
        .map(|&(from, to)| Transition {
            from,
            to,
            ms: Vec::new(),
            within: Vec::new(),
        })
        .collect();
    let mut seen = Vec::new();
    let mut go = || -> Result<(), Ended> {
        s.command(found)?;
        for _ in 0..ROUNDS {
            for &(from, to) in &plan {
                let ((lo, hi), between) = s.shift(to)?;
                if let Some(t) = transitions
                    .iter_mut()
                    .find(|t| (t.from, t.to) == (from, to))
                {
                    t.ms.push((lo + hi) / 2.0);
                    t.within.push((lo, hi));
                }
                seen.push((from, to, between));
            }
        }
        Ok(())
    };
    let went = go()
        .and_then(|()| {
            // The circuit ends where it began; let go there.
            if s.shows(found) {
                Ok(())
            } else {
                s.shift(found).map(drop)
            }
        })
        .map_err(ended);
    // The safe state first (above, on a way out), then the polls as they were.
    let _ = d.change_settings(|c| c.status_period = period);
    went?;
    gate.disengage(DisengageCause::Characterize { ended: None });
    let gaps: Vec<f64> = s.samples.windows(2).map(|w| w[1].t - w[0].t).collect();
    Ok(Figures {
        device: device.to_string(),
        states,
        transitions,
        transit: transit(&seen),
        interval: analyze::median(&gaps).unwrap_or(0.0),
        took: s.started.elapsed().as_secs_f64(),
        samples: s.samples,
    })
}

/// `summary.json`'s object.
pub(crate) fn summary(f: &Figures) -> serde_json::Value {
    let ms = |x: f64| write::sig(x);
    serde_json::json!({
        "device": f.device,
        "kind": "state",
        "transitions": f.transitions.iter().map(|t| {
            let lo = t.ms.iter().copied().fold(f64::INFINITY, f64::min);
            let hi = t.ms.iter().copied().fold(f64::NEG_INFINITY, f64::max);
            serde_json::json!({
                "from": f.name(t.from),
                "to": f.name(t.to),
                "ms_median": analyze::median(&t.ms).map(ms),
                "ms_min": lo.is_finite().then(|| ms(lo)),
                "ms_max": hi.is_finite().then(|| ms(hi)),
                "n": t.ms.len(),
            })
        }).collect::<Vec<_>>(),
        "samples": f.samples.len(),
    })
}

/// `sim.toml`: the `[device.sim]` section that shifts like the device.
pub(crate) fn sim_toml(f: &Figures) -> String {
    let mut out = format!(
        "# {}: measured by adrive characterize in {:.0} s\n[device.sim]\n",
        f.device, f.took
    );
    if let Some(s) = f.settle() {
        let _ = writeln!(out, "settle = \"{}us\"", (s * 1e6).round());
    }
    if let Some(t) = f.transit {
        let _ = writeln!(out, "transit = \"{}\"", f.name(t));
    }
    out
}

/// `report.md` and its plot, `run.svg` (the state commanded and read against time).
pub(crate) fn report(f: &Figures) -> (String, Vec<(&'static str, String)>) {
    let mut md = format!(
        "# {} characterized\n\n{} samples in {:.0} s; a reading every {:.1} ms (median), \
         so each time is good to about {:.1} ms. States: {}.\n\n\
         Each transition timed {} times, from the command's arrival at the device to the \
         first reading of the new state.\n\n\
         | from | to | median | min | max | n |\n|---|---|---|---|---|---|\n",
        f.device,
        f.samples.len(),
        f.took,
        f.interval * 1e3,
        f.interval * 1e3 / 2.0,
        f.states.join(", "),
        ROUNDS,
    );
    for t in &f.transitions {
        let show = |x: Option<f64>| x.map_or("—".into(), |v| format!("{v:.1} ms"));
        let lo = t.ms.iter().copied().reduce(f64::min);
        let hi = t.ms.iter().copied().reduce(f64::max);
        let _ = writeln!(
            md,
            "| {} | {} | {} | {} | {} | {} |",
            f.name(t.from),
            f.name(t.to),
            show(analyze::median(&t.ms)),
            show(lo),
            show(hi),
            t.ms.len()
        );
    }
    if let Some(t) = f.transit {
        let _ = write!(
            md,
            "\nMid-shift it reads {}: a shift into it is over at once.\n",
            f.name(t)
        );
    }
    md.push_str(
        "\n## The run\n\nThe state commanded (grey) and read (blue) against time, by number \
         (0 the first state).\n\n![the run](run.svg)\n",
    );
    let run = write::svg(
        &[
            (
                COMMAND,
                f.samples.iter().map(|s| (s.t, s.commanded)).collect(),
            ),
            (UP, f.samples.iter().map(|s| (s.t, s.measured)).collect()),
        ],
        &Frame {
            x_label: "s".into(),
            y_label: "state".into(),
            legend: vec![(COMMAND, "commanded".into()), (UP, "read".into())],
        },
    );
    (md, vec![("run.svg", run)])
}

/// Every file into `dir`: summary.json, samples.csv (`t_s,commanded,measured`, the
/// states by name), sim.toml, report.md and its plot.
pub(crate) fn write_all(dir: &Path, f: &Figures) -> std::io::Result<()> {
    let mut csv = String::from("t_s,commanded,measured\n");
    for s in &f.samples {
        let _ = writeln!(
            csv,
            "{:.6},{},{}",
            s.t,
            f.name(s.commanded as u8),
            f.name(s.measured as u8)
        );
    }
    super::write::files(dir, &summary(f), &csv, &sim_toml(f), report(f))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The incident: on a busy CI machine, a reading of neutral whose poll stalled was
    /// left out, and the shift into neutral (at once, in the simulator) was timed at the
    /// readings after it: 34 ms for 0. A stalled reading now bounds the bracket by its
    /// poll's edge: the old state's at its first byte, the new one's at its reply.
    #[test]
    fn a_reading_whose_poll_stalled_widens_the_bracket_and_never_moves_it_past_the_truth() {
        let sample = |t: f64, measured: f64| Sample {
            t,
            commanded: 2.0,
            measured,
        };
        // Reverse (1) read at 0.100; the shift to neutral (2) arrives at 0.105; neutral read
        // in a stalled poll from 0.110 to 0.150, then at 0.160 and 0.185.
        let samples = [
            sample(0.100, 1.0),
            sample(0.130, 2.0),
            sample(0.160, 2.0),
            sample(0.185, 2.0),
        ];
        let taken = [
            (0.100, 0.100),
            (0.110, 0.150),
            (0.160, 0.160),
            (0.185, 0.185),
        ];
        let (first, (lo, hi)) = bracket(&samples, &taken, 1, 2, 0.105);
        assert_eq!(first, 1);
        assert_eq!((lo, hi), (0.105, 0.150));
        // A stalled reading of the old state after the arrival: at its first byte.
        let samples = [sample(0.120, 1.0), sample(0.145, 2.0)];
        let taken = [(0.108, 0.132), (0.145, 0.145)];
        assert_eq!(bracket(&samples, &taken, 0, 2, 0.105), (1, (0.108, 0.145)));
        // A state seen, lost and seen again: from the last time it was lost.
        let samples = [sample(0.12, 2.0), sample(0.14, 1.0), sample(0.16, 2.0)];
        let taken = [(0.12, 0.12), (0.14, 0.14), (0.16, 0.16)];
        assert_eq!(bracket(&samples, &taken, 0, 2, 0.105), (2, (0.14, 0.16)));
    }

    #[test]
    fn the_circuit_takes_every_transition_once_from_home_back_to_home() {
        for n in 2..=6u8 {
            for home in 0..n {
                let c = circuit(n, home);
                assert_eq!(c.len(), usize::from(n) * usize::from(n - 1), "{n}");
                assert_eq!(c.first().map(|t| t.0), Some(home));
                assert_eq!(c.last().map(|t| t.1), Some(home));
                assert!(c.windows(2).all(|w| w[0].1 == w[1].0), "a walk: {c:?}");
                let mut pairs = c.clone();
                pairs.sort_unstable();
                pairs.dedup();
                assert_eq!(pairs.len(), c.len(), "each once: {c:?}");
                assert!(c.iter().all(|(a, b)| a != b));
            }
        }
    }

    #[test]
    fn the_transit_state_is_the_one_most_shifts_pass_through() {
        // Alice: park 0, reverse 1, neutral 2, drive 3; every shift passes neutral.
        let seen: Vec<(u8, u8, Vec<u8>)> = circuit(4, 0)
            .into_iter()
            .map(|(a, b)| {
                let between = if a != 2 && b != 2 { vec![2, 2] } else { vec![] };
                (a, b, between)
            })
            .collect();
        assert_eq!(transit(&seen), Some(2));
        let none: Vec<(u8, u8, Vec<u8>)> = circuit(4, 0)
            .into_iter()
            .map(|(a, b)| (a, b, vec![]))
            .collect();
        assert_eq!(transit(&none), None);
    }

    #[test]
    fn sim_toml_says_the_shift_time_without_the_transitions_into_the_transit_state() {
        // Each time bracketed by readings 20 ms apart.
        let t = |from, to, ms: &[f64]| Transition {
            from,
            to,
            ms: ms.to_vec(),
            within: ms.iter().map(|m| (m - 10.0, m + 10.0)).collect(),
        };
        let f = Figures {
            device: "trans".into(),
            states: ["park", "reverse", "neutral", "drive"]
                .map(String::from)
                .to_vec(),
            transitions: vec![
                t(0, 1, &[600.0, 602.0, 598.0]),
                t(1, 2, &[4.0, 6.0, 5.0]),
                t(2, 3, &[601.0, 599.0, 600.0]),
            ],
            transit: Some(2),
            ..Figures::default()
        };
        let text = sim_toml(&f);
        assert!(text.contains("settle = \"600000us\""), "{text}");
        assert!(text.contains("transit = \"neutral\""), "{text}");
        let s = summary(&f);
        assert_eq!(s["kind"], "state");
        assert_eq!(s["transitions"][1]["to"], "neutral");
        assert_eq!(s["transitions"][0]["ms_median"], 600.0);
        assert_eq!(s["transitions"][0]["ms_min"], 598.0);
        assert_eq!(s["transitions"][0]["n"], 3);
    }
}
