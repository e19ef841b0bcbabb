//! The supervisor (the paper's supervisory thread): it watches every device through
//! the snapshot, names each fault with its cause and time, reports it (console, state
//! broadcast, log), and runs recovery procedures as explicit state machines
//! ([`recovery`]). A procedure that gives up leaves the vehicle in the safe state,
//! disengaged, and — as a fatal device error — asks the process to end.
//!
//! The detectors ([`detect`]) are pure functions of a [`Snapshot`], the vehicle's
//! configuration and what the detector remembers between turns; they reach the
//! engine, the gearbox and the e-stop through the role bindings.
//!
//! The gate monitor ([`crate::safety::gate`]) disengages within milliseconds on an
//! e-stop or a faulty device; the supervisor works at its own, slower period on
//! diagnosis and recovery.

pub mod recovery;

use crate::config::roles::ReadingRef;
use crate::config::{SupervisorConfig, VehicleConfig};
use crate::exit::Exit;
use crate::safety::Gate;
use crate::snapshot::{DeviceView, FaultKind, Snapshot};
use crate::threads::{StopSignal, Threads};
use crate::value::{Kind, Value};
use crate::vehicle::supervision::Fault;
use recovery::{Procedure, Progress};
use std::collections::HashMap;
use std::sync::Arc;
use std::time::{Duration, Instant};

/// Where the supervisor sends a request to end the process (a fatal device error).
pub type ExitSink = Box<dyn Fn(Exit) + Send>;

/// Per-device memory between turns.
#[derive(Default)]
pub struct Track {
    /// (time, attempts, errors) samples over the error window.
    window: Vec<(Instant, u64, u64)>,
    /// Since when the measured value is away from the command.
    away_since: Option<Instant>,
}

/// What the detectors remember between turns.
pub struct Memory {
    tracks: HashMap<String, Track>,
    started: Instant,
}

impl Memory {
    pub fn new(started: Instant) -> Memory {
        Memory {
            tracks: HashMap::new(),
            started,
        }
    }
}

/// A bound reading's value in the snapshot.
fn reading<'a>(snap: &'a Snapshot, cfg: &VehicleConfig, r: ReadingRef) -> Option<&'a Value> {
    let d = &cfg.devices[r.device.index()];
    snap.device(&d.name)?.reading(&d.readings[r.reading].name)
}

/// Every fault visible in `snap`. `previous` keeps the `since` of faults that persist.
pub fn detect(
    snap: &Snapshot,
    cfg: &VehicleConfig,
    sup: &SupervisorConfig,
    mem: &mut Memory,
    previous: &[Fault],
    now: Instant,
) -> Vec<Fault> {
    let mut out = Vec::new();
    let mut raise = |kind, device: Option<&str>, cause: String| {
        let device = device.map(str::to_string);
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
    for (d, c) in snap.devices.iter().zip(&cfg.devices) {
        device_faults(d, c, sup, mem, now, &mut raise);
    }
    let b = &cfg.roles;
    let running = b.engine_running.and_then(|r| reading(snap, cfg, r));
    let gear = b.gear.as_ref().and_then(|g| {
        let d = &cfg.devices[g.device.index()];
        let v = snap.device(&d.name)?.reading("state")?.as_str()?;
        let s = d.state_index(v)?;
        g.drives(s).then(|| v.to_string())
    });
    if let (Some(Value::Flag(false)), Some(gear)) = (running, gear) {
        let rpm = b
            .engine_running
            .and_then(|r| snap.device(&cfg.devices[r.device.index()].name))
            .and_then(|d| d.number("rpm"))
            .unwrap_or(0.0);
        raise(
            FaultKind::EngineStall,
            None,
            format!("engine stopped ({rpm:.0} rpm) in {gear}"),
        );
    }
    if let Some(e) = b.estop {
        match reading(snap, cfg, e.at).and_then(Value::as_str) {
            Some("pause") => raise(FaultKind::EstopPause, None, "e-stop in pause".into()),
            Some("disable") => raise(FaultKind::EstopDisable, None, "e-stop in disable".into()),
            _ => {}
        }
    }
    out
}

fn device_faults(
    d: &DeviceView,
    c: &crate::config::DeviceConfig,
    sup: &SupervisorConfig,
    mem: &mut Memory,
    now: Instant,
    raise: &mut impl FnMut(FaultKind, Option<&str>, String),
) {
    let who = Some(d.name.as_str());
    let last_error = || d.health.last_error.clone().unwrap_or_default();
    let gone = d.health.opens > 0 && d.health.missing;
    if gone {
        raise(
            FaultKind::Disconnected,
            who,
            format!("port closed: {}", last_error()),
        );
    }
    let limit = c.status_max_age + c.reply_timeout;
    let age = d
        .status_age_ms
        .map_or(now - mem.started, |ms| Duration::from_secs_f64(ms / 1e3));
    if !gone && age > limit && d.settings.status_on {
        let what = if d.status_age_ms.is_some() {
            "no status"
        } else {
            "never answered"
        };
        raise(
            FaultKind::Silent,
            who,
            format!(
                "{what} for {} ms (max {} ms): {}",
                age.as_millis(),
                c.status_max_age.as_millis(),
                last_error()
            ),
        );
    }

    let track = mem.tracks.entry(d.name.clone()).or_default();
    let s = d.counters;
    let attempts = s.polls + s.executed + s.command_errors;
    let errors = s.status_errors + s.command_errors;
    track.window.push((now, attempts, errors));
    track
        .window
        .retain(|(t, _, _)| now - *t <= sup.error_window);
    if let (Some(first), Some(last)) = (track.window.first(), track.window.last()) {
        let (tries, errs) = (last.1 - first.1, last.2 - first.2);
        if tries >= 4 && errs as f64 / tries as f64 > sup.error_rate {
            raise(
                FaultKind::ErrorRate,
                who,
                format!(
                    "{errs} of {tries} transactions failed in {} s: {}",
                    sup.error_window.as_secs_f64(),
                    last_error()
                ),
            );
        }
    }

    let fresh = d.status_age_ms.is_some() && age <= limit;
    if !fresh {
        track.away_since = None;
        return;
    }
    if d.fault != 0 {
        raise(
            FaultKind::DeviceFault,
            who,
            format!("status word reports faults 0x{:04x}", d.fault),
        );
    }
    if c.kind != Kind::Setpoint {
        return;
    }
    let Some(pos) = d.position() else {
        return;
    };
    let [lo, hi] = c.range;
    let m = sup.range_margin * (hi - lo);
    if pos < lo - m || pos > hi + m {
        raise(
            FaultKind::OutOfRange,
            who,
            format!("reports {pos:.3}, outside [{lo}, {hi}]"),
        );
    }
    if let Some(Value::Number(cmd)) = d.executed {
        if (pos - cmd).abs() > sup.follow_tolerance {
            let since = *track.away_since.get_or_insert(now);
            if now - since > sup.follow_time {
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

/// Faults that take the vehicle out of the planner's hands.
pub fn disengages(kind: FaultKind) -> bool {
    !matches!(kind, FaultKind::EngineStall)
}

/// The procedure a fault calls for, if any (and if the vehicle has what it needs).
pub fn procedure_for(f: &Fault, gate: &Gate, cfg: &SupervisorConfig) -> Option<Procedure> {
    let v = &gate.vehicle;
    let b = v.bindings();
    let device = f.device.as_deref().and_then(|n| v.find(n)).map(|d| d.id);
    match (f.kind, device) {
        (FaultKind::EngineStall, _) => {
            let g = b.gear.as_ref()?;
            let d = v.device(g.device);
            let now = d
                .config
                .reading("state")
                .and_then(|i| d.reading(i))
                .map(|x| x as u8);
            let gear = now
                .filter(|s| g.drives(*s))
                .or_else(|| g.forward.first().copied())?;
            Procedure::engine_stall(v, gear, cfg)
        }
        (FaultKind::NotFollowing | FaultKind::DeviceFault, Some(id)) if b.steering == Some(id) => {
            Procedure::steering(v, cfg)
        }
        (FaultKind::Disconnected, Some(id)) => Some(Procedure::reconnect(v, id, cfg)),
        _ => None,
    }
}

/// The supervisor's state between turns: memory, current procedure, cool-downs.
pub struct Supervisor {
    cfg: SupervisorConfig,
    memory: Memory,
    procedure: Option<Procedure>,
    /// A procedure of this name may not start again before this time.
    cooldown: HashMap<String, Instant>,
    exit: ExitSink,
}

impl Supervisor {
    pub fn new(cfg: SupervisorConfig, exit: ExitSink) -> Supervisor {
        Supervisor {
            memory: Memory::new(Instant::now()),
            cfg,
            procedure: None,
            cooldown: HashMap::new(),
            exit,
        }
    }

    /// One turn: detect, report, act.
    pub fn tick(&mut self, gate: &Gate, now: Instant) {
        let v = &gate.vehicle;
        let board = &v.supervision;
        let before = board.faults();
        let snap = gate.snapshot(0);
        let faults = detect(&snap, &v.config, &self.cfg, &mut self.memory, &before, now);
        for f in &faults {
            if !before
                .iter()
                .any(|b| b.kind == f.kind && b.device == f.device)
            {
                tracing::warn!(fault = %f.kind, device = ?f.device, "fault: {}", f.describe());
                board.note(format!("fault: {}", f.describe()));
            }
        }
        for b in &before {
            if !faults
                .iter()
                .any(|f| f.kind == b.kind && f.device == b.device)
            {
                tracing::info!(fault = %b.kind, device = ?b.device, "cleared: {}", b.describe());
                board.note(format!(
                    "cleared: {} {}",
                    b.device.as_deref().unwrap_or(""),
                    b.kind
                ));
            }
        }
        board.set_faults(faults.clone());

        if gate.is_engaged() {
            if let Some(f) = faults.iter().find(|f| disengages(f.kind)) {
                gate.disengage(&format!("supervisor: {}", f.describe()));
            }
        }
        if self.procedure.is_none() {
            for f in &faults {
                if let Some(p) = procedure_for(f, gate, &self.cfg) {
                    if self.cooldown.get(p.name()).is_some_and(|t| now < *t) {
                        continue;
                    }
                    tracing::warn!("recovery {} started for {}", p.name(), f.describe());
                    board.note(format!("recovery {} started: {}", p.name(), f.describe()));
                    self.procedure = Some(p);
                    break;
                }
            }
        }
        if let Some(p) = self.procedure.as_mut() {
            let progress = p.advance(gate, now);
            board.set_recovery(Some(p.view()));
            match progress {
                Progress::Running => {}
                Progress::Done => {
                    let msg = format!(
                        "recovery {} done in {:.1} s",
                        p.name(),
                        p.elapsed(now).as_secs_f64()
                    );
                    tracing::info!("{msg}");
                    board.note(msg.clone());
                    board.set_outcome(msg);
                    self.finish(gate, now);
                }
                Progress::GaveUp(why) => {
                    let msg = format!("recovery {} gave up: {why}", p.name());
                    tracing::error!("{msg}");
                    board.note(msg.clone());
                    board.set_outcome(msg.clone());
                    gate.command_safe_state();
                    gate.disengage(&msg);
                    self.finish(gate, now);
                    if self.cfg.exit_on_give_up {
                        (self.exit)(Exit::Fatal(msg));
                    }
                }
            }
        }
    }

    fn finish(&mut self, gate: &Gate, now: Instant) {
        if let Some(p) = self.procedure.take() {
            self.cooldown
                .insert(p.name().to_string(), now + self.cfg.step_timeout);
        }
        gate.set_recovering(&[]);
        gate.vehicle.supervision.set_recovery(None);
    }
}

/// The supervisor thread, `supervisor`.
pub struct Running {
    stop: Arc<StopSignal>,
    threads: Threads,
}

/// Start the supervisor thread at `cfg.period`.
pub fn start(gate: Arc<Gate>, cfg: SupervisorConfig, exit: ExitSink) -> std::io::Result<Running> {
    let stop = Arc::new(StopSignal::default());
    let mut threads = Threads::default();
    let s = stop.clone();
    threads.spawn("supervisor".into(), move || {
        let period = cfg.period;
        let panic_at = cfg.panic_for_test.map(|d| Instant::now() + d);
        let mut sup = Supervisor::new(cfg, exit);
        crate::threads::every(period, &s, || {
            if panic_at.is_some_and(|t| Instant::now() >= t) {
                panic!("injected panic (--inject-panic supervisor)");
            }
            sup.tick(&gate, Instant::now());
        })
    })?;
    Ok(Running { stop, threads })
}

impl Running {
    pub fn shutdown(self, deadline: Duration) -> Vec<String> {
        self.stop.stop();
        self.threads.join(Instant::now() + deadline)
    }
}
