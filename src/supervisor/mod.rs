//! The supervisor (the paper's supervisory thread): it watches every device through
//! the cache, names each fault with its cause and time, reports it (console, state
//! broadcast, log), and runs recovery procedures as explicit state machines
//! ([`recovery`]). A procedure that gives up leaves the vehicle in the safe state,
//! disengaged, and — as a fatal device error — asks the process to end.
//!
//! The gate monitor ([`crate::gate`]) disengages within milliseconds on an e-stop or
//! a faulty device; the supervisor works at its own, slower period on diagnosis and
//! recovery.

pub mod recovery;
pub mod status;

use crate::config::SupervisorConfig;
use crate::engine::{StopSignal, Threads};
use crate::exit::Exit;
use crate::value::{Command, EstopState, Gear, Role};
use crate::vehicle::{Device, Vehicle};
use recovery::{Procedure, Progress};
use status::{Fault, FaultKind};
use std::collections::HashMap;
use std::sync::atomic::Ordering::Relaxed;
use std::sync::Arc;
use std::time::{Duration, Instant};

/// Where the supervisor sends a request to end the process (a fatal device error).
pub type ExitSink = Box<dyn Fn(Exit) + Send>;

/// Per-device memory between ticks.
#[derive(Default)]
struct Track {
    /// (time, attempts, errors) samples over the error window.
    window: Vec<(Instant, u64, u64)>,
    /// Since when the measured value is away from the command.
    away_since: Option<Instant>,
}

/// The fault detector, separate from the thread so tests can drive it.
pub struct Detector {
    cfg: SupervisorConfig,
    tracks: HashMap<Role, Track>,
    started: Instant,
}

impl Detector {
    pub fn new(cfg: SupervisorConfig) -> Detector {
        Detector {
            cfg,
            tracks: HashMap::new(),
            started: Instant::now(),
        }
    }

    /// Every fault visible now. `previous` keeps the `since` of faults that persist.
    pub fn detect(&mut self, v: &Vehicle, previous: &[Fault], now: Instant) -> Vec<Fault> {
        let mut out = Vec::new();
        let mut raise = |kind, device, cause: String| {
            let since = previous
                .iter()
                .find(|f| f.kind == kind && f.device == device)
                .map_or(now, |f| f.since);
            out.push(Fault {
                kind,
                device,
                cause,
                since,
            });
        };
        for d in &v.devices {
            self.device_faults(d, now, &mut raise);
        }
        let facts = v.facts();
        if facts.running == Some(false) && facts.gear.is_some_and(Gear::is_driving) {
            let rpm = v
                .device(Role::Obd)
                .and_then(|d| d.cached().reading.rpm)
                .unwrap_or(0.0);
            raise(
                FaultKind::EngineStall,
                None,
                format!(
                    "engine stopped ({rpm:.0} rpm) in {}",
                    facts.gear.expect("checked")
                ),
            );
        }
        match facts.estop {
            Some(EstopState::Pause) => raise(FaultKind::EstopPause, None, "e-stop in pause".into()),
            Some(EstopState::Disable) => {
                raise(FaultKind::EstopDisable, None, "e-stop in disable".into())
            }
            _ => {}
        }
        out
    }

    fn device_faults(
        &mut self,
        d: &Device,
        now: Instant,
        raise: &mut impl FnMut(FaultKind, Option<Role>, String),
    ) {
        let who = Some(d.role);
        let cached = d.cached();
        let opens = d.port_health.opens.load(Relaxed);
        // `: <the device's last error>`, or nothing when it has none (never an empty cause).
        let last_error = || {
            d.health
                .last_error
                .lock()
                .as_ref()
                .filter(|(_, m)| !m.is_empty())
                .map(|(_, m)| format!(": {m}"))
                .unwrap_or_default()
        };
        let gone = opens > 0 && d.port_health.missing.load(Relaxed);
        if gone {
            raise(
                FaultKind::Disconnected,
                who,
                format!("port closed{}", last_error()),
            );
        }
        // Silence is the device's own rule; one that never answered is measured from the
        // supervisor's start.
        let (what, quiet) = match d.quiet_for(now) {
            Some(q) => ("no answer", q),
            None => ("never answered", now - self.started),
        };
        if !gone && d.is_silent_after(quiet) {
            let mut cause = format!(
                "{what} for {} ms (max {} ms)",
                quiet.as_millis(),
                d.config.status_max_age.as_millis()
            );
            // The error that went with it, unless it is older than the last answer.
            if let Some((_, e)) = d
                .health
                .last_error
                .lock()
                .as_ref()
                .filter(|(t, _)| now - *t < quiet)
            {
                cause = format!("{cause}: {e}");
            }
            raise(FaultKind::Silent, who, cause);
        }
        // Readings this old are still judged (a poll may wait out a command flood).
        let limit = d.config.status_max_age + d.config.reply_timeout;
        let age = cached
            .at
            .map_or(now - self.started, |t| now.saturating_duration_since(t));

        let track = self.tracks.entry(d.role).or_default();
        let s = d.stats.snapshot();
        let attempts = s.polls + s.executed + s.command_errors;
        let errors = s.status_errors + s.command_errors;
        track.window.push((now, attempts, errors));
        track
            .window
            .retain(|(t, _, _)| now - *t <= self.cfg.error_window);
        // A port that cannot be opened fails every transaction: that is said above (or
        // as silence, for a port never opened), not again as an error rate.
        let missing = d.port_health.missing.load(Relaxed);
        if let (false, Some(first), Some(last)) =
            (missing, track.window.first(), track.window.last())
        {
            let (tries, errs) = (last.1 - first.1, last.2 - first.2);
            if tries >= 4 && errs as f64 / tries as f64 > self.cfg.error_rate {
                raise(
                    FaultKind::ErrorRate,
                    who,
                    format!(
                        "{errs} of {tries} transactions failed in {} s{}",
                        self.cfg.error_window.as_secs_f64(),
                        last_error()
                    ),
                );
            }
        }

        let fresh = cached.at.is_some() && age <= limit;
        if !fresh {
            track.away_since = None;
            return;
        }
        if cached.reading.fault != 0 {
            raise(
                FaultKind::DeviceFault,
                who,
                format!("status word reports faults 0x{:04x}", cached.reading.fault),
            );
        }
        let Some(pos) = cached.reading.position else {
            return;
        };
        if d.is_actuator() {
            let [lo, hi] = d.config.range();
            let m = self.cfg.range_margin * (hi - lo);
            if pos < lo - m || pos > hi + m {
                raise(
                    FaultKind::OutOfRange,
                    who,
                    format!("reports {pos:.3}, outside [{lo}, {hi}]"),
                );
            }
        }
        if let Some(Command::Set(cmd)) = d.slot.executed() {
            if (pos - cmd).abs() > self.cfg.follow_tolerance {
                let since = *track.away_since.get_or_insert(now);
                if now - since > self.cfg.follow_time {
                    raise(
                        FaultKind::NotFollowing,
                        who,
                        format!(
                            "measured {pos:.3}, commanded {cmd:.3} for {:.1} s",
                            (now - since).as_secs_f64()
                        ),
                    );
                }
            } else {
                track.away_since = None;
            }
        }
    }
}

/// Faults that take the vehicle out of the planner's hands.
pub fn disengages(kind: FaultKind) -> bool {
    !matches!(kind, FaultKind::EngineStall)
}

/// The procedure a fault calls for, if any.
pub fn procedure_for(f: &Fault, v: &Vehicle, cfg: &SupervisorConfig) -> Option<Procedure> {
    match (f.kind, f.device) {
        (FaultKind::EngineStall, _) => {
            let gear = v
                .facts()
                .gear
                .filter(|g| g.is_driving())
                .unwrap_or(Gear::Drive);
            Some(Procedure::engine_stall(gear, cfg))
        }
        (FaultKind::NotFollowing | FaultKind::DeviceFault, Some(Role::Steer)) => {
            Some(Procedure::steering(cfg))
        }
        (FaultKind::Disconnected, Some(role)) => Some(Procedure::reconnect(role, cfg)),
        _ => None,
    }
}

/// The supervisor's state between ticks: detector, current procedure, cool-downs.
pub struct Supervisor {
    cfg: SupervisorConfig,
    detector: Detector,
    procedure: Option<Procedure>,
    /// A procedure that waits for the vehicle to be engaged (said once).
    waiting: Option<String>,
    /// A procedure of this name may not start again before this time.
    cooldown: HashMap<String, Instant>,
    exit: ExitSink,
}

impl Supervisor {
    pub fn new(cfg: SupervisorConfig, exit: ExitSink) -> Supervisor {
        Supervisor {
            detector: Detector::new(cfg.clone()),
            cfg,
            procedure: None,
            waiting: None,
            cooldown: HashMap::new(),
            exit,
        }
    }

    /// One turn: detect, report, act.
    pub fn tick(&mut self, v: &Vehicle, now: Instant) {
        let status = &v.supervision;
        let before = status.faults();
        let faults = self.detector.detect(v, &before, now);
        let among = |list: &[Fault], f: &Fault| {
            list.iter()
                .any(|g| g.kind == f.kind && g.device == f.device)
        };
        let is_new = |f: &Fault| !among(&before, f);
        for f in faults.iter().filter(|f| is_new(f)) {
            tracing::warn!(fault = %f.kind, device = ?f.device, "fault: {}", f.describe());
            status.note(format!("fault: {}", f.describe()));
        }
        for b in &before {
            if !among(&faults, b) {
                tracing::info!(fault = %b.kind, device = ?b.device, "cleared: {}", b.describe());
                status.note(format!(
                    "cleared: {} {}",
                    b.device.map(|d| d.as_str()).unwrap_or(""),
                    b.kind
                ));
            }
        }
        status.set_faults(faults.clone());

        // A disengaged vehicle is never moved by adrive on its own: a procedure that
        // moves an actuator runs only while engaged, and stops when it no longer is
        // (the disengage has commanded the safe state). It starts again from the top at
        // the next engage if its fault is still there.
        if self.procedure.as_ref().is_some_and(|p| !p.may_run(v)) {
            let p = self.procedure.take().expect("checked");
            let msg = format!("recovery {} stopped: the vehicle is disengaged", p.name());
            tracing::warn!("{msg}");
            status.note(msg.clone());
            status.set_outcome(msg);
            v.set_recovering(&[]);
            status.set_recovery(None);
        }
        let start = match self.procedure {
            None => self.next_procedure(v, &faults, &is_new, now),
            Some(_) => None,
        };
        // A fault disengages the vehicle, unless it was there before and a procedure
        // (running, or starting now) deals with it: engaging with it is the permission
        // to recover.
        if v.is_engaged() {
            let dealt_with = |f: &Fault| {
                let p = self.procedure.as_ref().or(start.as_ref().map(|(p, _)| p));
                !is_new(f)
                    && p.is_some_and(|p| {
                        procedure_for(f, v, &self.cfg).is_some_and(|q| q.name() == p.name())
                    })
            };
            if let Some(f) = faults.iter().find(|f| disengages(f.kind) && !dealt_with(f)) {
                v.disengage(&format!("supervisor: {}", f.describe()));
            }
        }
        match start {
            Some((p, f)) if p.may_run(v) => {
                tracing::warn!("recovery {} started for {}", p.name(), f.describe());
                status.note(format!("recovery {} started: {}", p.name(), f.describe()));
                self.waiting = None;
                self.procedure = Some(p);
            }
            _ => {}
        }
        if self.procedure.is_none() {
            self.note_waiting(v, &faults, now);
        }
        if let Some(p) = self.procedure.as_mut() {
            let progress = p.advance(v, now);
            status.set_recovery(Some(p.view()));
            match progress {
                Progress::Running => {}
                Progress::Done => {
                    let msg = format!(
                        "recovery {} done in {:.1} s",
                        p.name(),
                        p.elapsed(now).as_secs_f64()
                    );
                    tracing::info!("{msg}");
                    status.note(msg.clone());
                    status.set_outcome(msg);
                    self.finish(v, now);
                }
                Progress::GaveUp(why) => {
                    let msg = format!("recovery {} gave up: {why}", p.name());
                    tracing::error!("{msg}");
                    status.note(msg.clone());
                    status.set_outcome(msg.clone());
                    v.command_safe_state();
                    v.disengage(&msg);
                    self.finish(v, now);
                    if self.cfg.exit_on_give_up {
                        (self.exit)(Exit::Fatal(msg));
                    }
                }
            }
        }
    }

    /// The procedure to start now, and the fault it is for: the first fault whose
    /// procedure is not cooling down and, if it moves an actuator, may move it — the
    /// vehicle is engaged and the fault is not one that disengages it this turn.
    fn next_procedure(
        &self,
        v: &Vehicle,
        faults: &[Fault],
        is_new: &dyn Fn(&Fault) -> bool,
        now: Instant,
    ) -> Option<(Procedure, Fault)> {
        faults.iter().find_map(|f| {
            let p = self.ready(f, v, now)?;
            let disengaging = p.moves() && disengages(f.kind) && is_new(f);
            (p.may_run(v) && !disengaging).then(|| (p, f.clone()))
        })
    }

    /// The procedure `f` calls for, unless it is cooling down after its last run.
    fn ready(&self, f: &Fault, v: &Vehicle, now: Instant) -> Option<Procedure> {
        let p = procedure_for(f, v, &self.cfg)?;
        let cooling = self.cooldown.get(p.name()).is_some_and(|t| now < *t);
        (!cooling).then_some(p)
    }

    /// Say once that a fault's procedure waits for the vehicle to be engaged.
    fn note_waiting(&mut self, v: &Vehicle, faults: &[Fault], now: Instant) {
        let waiting = faults.iter().find_map(|f| {
            let p = self.ready(f, v, now)?;
            (!p.may_run(v)).then(|| (p.name().to_string(), f))
        });
        let name = waiting.as_ref().map(|(n, _)| n.clone());
        if let Some((name, f)) = waiting.filter(|_| name != self.waiting) {
            let msg = format!("recovery {name} waits for engage: {}", f.describe());
            tracing::warn!("{msg}");
            v.supervision.note(msg.clone());
            v.supervision.set_outcome(msg);
        }
        self.waiting = name;
    }

    fn finish(&mut self, v: &Vehicle, now: Instant) {
        if let Some(p) = self.procedure.take() {
            self.cooldown
                .insert(p.name().to_string(), now + self.cfg.step_timeout);
        }
        v.set_recovering(&[]);
        v.supervision.set_recovery(None);
    }
}

/// The supervisor thread, `supervisor`.
pub struct Running {
    stop: Arc<StopSignal>,
    threads: Threads,
}

/// Start the supervisor thread at `cfg.period`.
pub fn start(v: Arc<Vehicle>, cfg: SupervisorConfig, exit: ExitSink) -> std::io::Result<Running> {
    let stop = Arc::new(StopSignal::default());
    let mut threads = Threads::default();
    let s = stop.clone();
    threads.spawn("supervisor".into(), move || {
        let period = cfg.period;
        let panic_at = cfg.panic_for_test.map(|d| Instant::now() + d);
        let mut sup = Supervisor::new(cfg, exit);
        let mut next = Instant::now();
        loop {
            next += period;
            if !s.sleep_until(next) {
                return;
            }
            next = next.max(Instant::now());
            if panic_at.is_some_and(|t| Instant::now() >= t) {
                panic!("injected panic (--inject-panic supervisor)");
            }
            let t = Instant::now();
            sup.tick(&v, t);
            if t.elapsed() > period {
                tracing::warn!("supervisor turn took {:?} (period {period:?})", t.elapsed());
            }
        }
    })?;
    Ok(Running { stop, threads })
}

impl Running {
    pub fn shutdown(self, deadline: Duration) -> Vec<String> {
        self.stop.stop();
        self.threads.join(Instant::now() + deadline)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::VehicleConfig;

    /// The console once set a status period longer than `status_max_age`: the device
    /// answered every poll, so it had no last error, and its `silent` fault was logged
    /// as `… (max 250 ms): ` with an empty cause.
    #[test]
    fn a_silent_device_without_an_error_has_no_empty_cause() {
        let mut config = VehicleConfig::alice();
        config.retain_only(&[Role::Steer]);
        let v = Vehicle::new(config, |_| {
            Box::new(|| Err(std::io::Error::other("no port in this test")))
        });
        // It answered when it started, and not since: 2 s later it is silent.
        let answered = v.devices[0].started;
        let now = answered + Duration::from_secs(2);
        v.devices[0].cache.lock().at = Some(answered);
        v.devices[0].record_ok(answered);
        let faults = Detector::new(SupervisorConfig::default()).detect(&v, &[], now);
        let silent = faults
            .iter()
            .find(|f| f.kind == FaultKind::Silent)
            .expect("silent");
        assert_eq!(silent.cause, "no answer for 2000 ms (max 250 ms)");
        *v.devices[0].health.last_error.lock() = Some((now, "timeout".into()));
        let faults = Detector::new(SupervisorConfig::default()).detect(&v, &[], now);
        assert!(
            faults[0].cause.ends_with("(max 250 ms): timeout"),
            "{faults:?}"
        );
    }
}
