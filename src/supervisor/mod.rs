//! The supervisor (the paper's supervisory thread): it watches every device through
//! the snapshot, names each fault with its cause and time, reports it (console, state
//! broadcast, log), and runs recovery procedures as explicit state machines
//! ([`recovery`]). A procedure that gives up leaves the vehicle in the safe state,
//! disengaged. A device gone is waited for, said plainly ([`waiting`]). Neither ends
//! the run: only the operator's `give_up_after` makes a device gone that long, or a
//! recovery that gave up after trying that long, a fatal device error that asks the
//! process to end.
//!
//! The detectors ([`detect`]) are pure functions of a [`Snapshot`], the vehicle's
//! configuration and what the detector remembers between turns; they reach the
//! engine, the gearbox and the e-stop through the role bindings.
//!
//! The gate monitor ([`crate::safety::gate_state`]) disengages within milliseconds on an
//! e-stop or a faulty device; the supervisor works at its own, slower period on
//! diagnosis and recovery.
//!
//! Beside it runs the `service/watchdog` thread ([`start_watching`]): it feeds systemd's
//! watchdog ([`crate::service::Watchdog`]) only while every engine thread — the
//! devices', the buses', the gate monitor and the supervisor itself — turns its loop
//! within its bound: a thread that ended or stalls is named, refuses engage and gets
//! adrive restarted.

pub(crate) mod causes;
mod kit;
pub(crate) mod recovery;
mod waiting;

use crate::config::roles::ReadingRef;
use crate::config::{SupervisorConfig, VehicleConfig};
use crate::engine::Gate;
use crate::exit::Exit;
use crate::snapshot::{DeviceView, DisengageCause, FaultKind, OutcomeKind, Snapshot};
use crate::threads::{Group, Liveness};
use crate::value::{Kind, Value};
use crate::vehicle::supervision::Fault;
use recovery::{Procedure, Progress};
use std::collections::HashMap;
use std::sync::Arc;
use std::time::{Duration, Instant};

/// Where the supervisor sends a request to end the process (a fatal device error).
pub(crate) type ExitSink = Box<dyn Fn(Exit) + Send>;

/// Per-device memory between turns.
#[derive(Default)]
pub(crate) struct Track {
    /// (time, attempts, errors) samples over the error window.
    window: Vec<(Instant, u64, u64)>,
    /// Since when the measured value is away from the command.
    away_since: Option<Instant>,
    /// A device with a declared response: the span of its commands, when and how far
    /// away from it (by the estimate) the current headway window began.
    headway: Option<([f64; 2], Instant, f64)>,
    /// A device with a declared response: where its commands alone can have taken it
    /// (from its readings, never away from its command nor faster than declared), when
    /// that was, and since when a reading has been further than `override_threshold`
    /// from it.
    explained: Option<(f64, Instant)>,
    unexplained_since: Option<Instant>,
    /// A kit's override flag has been handed to the driver (latched by the gate) since
    /// it was raised: the module keeps the flag until its next enable, so it no longer
    /// tells whether a hand is still on.
    kit_flag_handled: bool,
    /// The port's open count at the last turn, and whether it has been seen gone
    /// (missing) since it was last opened.
    opens: u64,
    gone: bool,
    /// When the port was last seen back after a disconnect ([`Track::reopen`]).
    reopened: Option<Instant>,
}

impl Track {
    /// Follow the port through `h`: a port opened again after it was seen gone (a USB
    /// unplug, a wrong path at start) is back at `now`. From then on the device is
    /// judged afresh — its silence counts from the reopen, its error rate over the
    /// transactions since — as it is at start. A port reopened while the device stays
    /// silent (after failed transactions, never gone) is no new start.
    fn reopen(&mut self, h: &crate::snapshot::Health, now: Instant) {
        if h.missing {
            self.gone = true;
        } else if h.opens > self.opens && self.gone {
            self.gone = false;
            self.reopened = Some(now);
            self.window.clear();
        }
        self.opens = h.opens;
    }
}

/// Slack on a declared response when judging what a command explains (a declared rate
/// or lag is not exact, and a reading is a status period old).
const EXPLAIN_SLACK: f64 = 1.5;

/// A device with a declared response makes headway when it gets at least this share
/// of the way its response promises: a slow but healthy actuator does.
const HEADWAY: f64 = 0.25;

/// What the detectors remember between turns.
pub struct Memory {
    tracks: HashMap<String, Track>,
    started: Instant,
    /// Since when the vehicle is engaged (as the snapshots saw it).
    engaged_since: Option<Instant>,
}

impl Memory {
    pub fn new(started: Instant) -> Memory {
        Memory {
            tracks: HashMap::new(),
            started,
            engaged_since: None,
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
    mem.engaged_since = match (snap.gate.engaged, mem.engaged_since) {
        (false, _) => None,
        (true, since) => Some(since.unwrap_or(now)),
    };
    let engaged_for = mem.engaged_since.map(|t| now - t);
    for (d, c) in snap.devices.iter().zip(&cfg.devices) {
        let pushes = causes::pushes(snap, cfg, d, c);
        device_faults(d, c, &pushes, sup, mem, previous, now, &mut raise);
        if d.status_age_ms
            .is_some_and(|a| Duration::from_secs_f64(a / 1e3) <= c.status_max_age + c.reply_timeout)
        {
            let track = mem.tracks.entry(d.name.clone()).or_default();
            let latched = snap.gate.overridden.contains(&d.name);
            kit::faults(
                d,
                c,
                engaged_for,
                latched,
                &mut track.kit_flag_handled,
                &mut raise,
            );
        }
    }
    let b = &cfg.roles;
    let running = b.engine_running.and_then(|r| reading(snap, cfg, r));
    let gear = b.gear.as_ref().and_then(|g| {
        let d = &cfg.devices[g.device.index()];
        let v = snap.device(&d.name)?.state()?;
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

/// One device's faults. A set point device is judged against `pushes`, every known
/// cause that can be moving it ([`causes`]): what they explain is neither a driver's
/// override nor a failure to follow.
#[allow(clippy::too_many_arguments)]
fn device_faults(
    d: &DeviceView,
    c: &crate::config::DeviceConfig,
    pushes: &[causes::Push],
    sup: &SupervisorConfig,
    mem: &mut Memory,
    previous: &[Fault],
    now: Instant,
    raise: &mut impl FnMut(FaultKind, Option<&str>, String),
) {
    let who = Some(d.name.as_str());
    let h = &d.health;
    let from_ms = |ms: f64| Duration::from_secs_f64(ms / 1e3);
    // `: <the device's last error>`, or nothing when it has none (never an empty cause).
    let last_error = || {
        h.last_error
            .as_deref()
            .filter(|m| !m.is_empty())
            .map(|m| format!(": {m}"))
            .unwrap_or_default()
    };
    // A port that cannot be opened — unplugged, or a wrong path from the start — is
    // gone; its error names the path (`cannot open /dev/ttyUSB7: No such file or
    // directory`), said first so that a narrow line keeps it.
    let gone = h.missing;
    let track = mem.tracks.entry(d.name.clone()).or_default();
    track.reopen(h, now);
    let since_reopen = track.reopened.map(|t| now - t);
    if gone {
        let cause = h
            .last_error
            .as_deref()
            .map(|m| m.strip_prefix("port: ").unwrap_or(m))
            .filter(|m| !m.is_empty())
            .unwrap_or("port closed");
        raise(FaultKind::Disconnected, who, cause.to_string());
    }
    // Silence is the device's own rule (`Device::silence`); one that never answered
    // is measured from the supervisor's start.
    let (what, quiet) = match (h.quiet_ms.map(from_ms), since_reopen) {
        (Some(q), Some(r)) if r < q => ("no answer since the port reopened", r),
        (Some(q), _) => ("no answer", q),
        (None, r) => ("never answered", r.unwrap_or(now - mem.started)),
    };
    if !gone && d.settings.status_on && quiet > c.status_max_age {
        let mut cause = format!(
            "{what} for {} ms (max {} ms)",
            quiet.as_millis(),
            c.status_max_age.as_millis()
        );
        // The error that went with it, unless it is older than the last answer.
        if h.last_error_age_ms.is_some_and(|a| from_ms(a) < quiet) {
            cause.push_str(&last_error());
        }
        raise(FaultKind::Silent, who, cause);
    }
    // Readings this old are still judged (a poll may wait out a command flood).
    let limit = c.status_max_age + c.reply_timeout;
    let age = d.status_age_ms.map_or(now - mem.started, from_ms);

    let s = d.counters;
    let attempts = s.polls + s.executed + s.command_errors;
    let errors = s.status_errors + s.command_errors;
    track.window.push((now, attempts, errors));
    track
        .window
        .retain(|(t, _, _)| now - *t <= sup.error_window);
    // A port that cannot be opened fails every transaction: that is said above (or as
    // silence, for a port never opened), not again as an error rate.
    // Nor is one back after a disconnect judged before it had its `status_max_age` to
    // answer (the window holds only the transactions since the reopen).
    let settling = since_reopen.is_some_and(|r| r <= c.status_max_age);
    if let (false, false, Some(first), Some(last)) = (
        h.missing,
        settling,
        track.window.first(),
        track.window.last(),
    ) {
        let (tries, errs) = (last.1 - first.1, last.2 - first.2);
        if tries >= 4 && errs as f64 / tries as f64 > sup.error_rate {
            raise(
                FaultKind::ErrorRate,
                who,
                format!(
                    "{errs} of {tries} transactions failed in {} s{}",
                    sup.error_window.as_secs_f64(),
                    last_error()
                ),
            );
        }
    }

    let fresh = d.status_age_ms.is_some() && age <= limit;
    if !fresh {
        track.away_since = None;
        track.headway = None;
        track.explained = None;
        track.unexplained_since = None;
        return;
    }
    // A kit's fault codes are judged with what else it says of itself (`kit`).
    if d.fault != 0 && c.kit().is_none() {
        raise(
            FaultKind::DeviceFault,
            who,
            match d.faults.as_slice() {
                [] => format!("status word reports faults 0x{:04x}", d.fault),
                names => format!("reports faults {} (0x{:04x})", names.join(" "), d.fault),
            },
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
    if let (Some(r), Some(&Value::Number(cmd))) = (c.response, d.executed.as_ref()) {
        // Every set point acknowledged since the last turn (and since its reading) may
        // have driven it — a controller alternating two set points faster than this
        // turn comes must not look like a hand pushing toward the one not seen — and so
        // may every other known cause: the e-stop, its own watchdog.
        let span = causes::hull(pushes).unwrap_or([cmd, cmd]);
        let unexplained = unexplained(track, &r, c.range, pos, pushes, span, now);
        // Once named, an override lasts until the device is back at its command: a
        // hand that holds still explains itself no better than a stuck motor would.
        let named = previous
            .iter()
            .any(|f| f.kind == FaultKind::Override && f.device.as_deref() == who);
        let off_span = (span[0] - pos).max(pos - span[1]).max(0.0);
        if named && off_span > r.override_threshold {
            raise(
                FaultKind::Override,
                who,
                format!("measured {pos:.3}, commanded {cmd:.3}: held away from its command (a driver's hand)"),
            );
            track.explained = None;
            track.headway = None;
            return;
        }
        if unexplained > r.override_threshold {
            let since = *track.unexplained_since.get_or_insert(now);
            if now - since > r.override_time {
                raise(
                    FaultKind::Override,
                    who,
                    format!(
                        "measured {pos:.3}, commanded {cmd:.3}: {unexplained:.3} from where its command can have taken it for {:.1} s (a driver's hand)",
                        (now - since).as_secs_f64()
                    ),
                );
                // Held by a hand, it is not failing to follow.
                track.headway = None;
                return;
            }
        } else {
            track.unexplained_since = None;
        }
    }
    if let (Some(r), Some(e), Some(&Value::Number(cmd))) =
        (c.response, d.estimate, d.executed.as_ref())
    {
        // By the estimate: no headway toward the commands for `stall_time` (inside the
        // span of those acknowledged since the last turn, or where another known cause
        // holds it, it is where they drive it).
        let span = causes::hull(pushes).unwrap_or([cmd, cmd]);
        let gap = (span[0] - e.position).max(e.position - span[1]).max(0.0);
        match track.headway {
            _ if gap <= r.deadband => track.headway = None,
            Some((was, since, gap0)) if was == span => {
                let elapsed = now - since;
                let promised = r.progress(gap0, elapsed);
                let made = gap0 - gap;
                if elapsed > sup.stall_time && made < HEADWAY * promised {
                    raise(
                        FaultKind::NotFollowing,
                        who,
                        format!(
                            "measured {pos:.3}, commanded {cmd:.3}: {made:.3} of the {promised:.3} its response promises in {:.1} s",
                            elapsed.as_secs_f64()
                        ),
                    );
                } else if elapsed > sup.stall_time {
                    // Headway made: judge the next window from here.
                    track.headway = Some((span, now, gap));
                }
            }
            _ => track.headway = Some((span, now, gap)),
        }
    } else if let Some(Value::Number(cmd)) = d.executed {
        let [from, to] = causes::hull(pushes).unwrap_or([cmd, cmd]);
        let off = (from - pos).max(pos - to).max(0.0);
        if off > sup.follow_tolerance * (hi - lo) {
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

/// How far the reading `pos` is from where the known causes (`pushes`, [`causes`]) can
/// have taken the device since the last turn: adrive's commands — every set point in
/// `span` — at its declared response, any other cause (the e-stop, its own watchdog:
/// not the actuator's motor) at any speed. 0 for a device that follows as declared,
/// lags behind (a slow or stuck motor), rests at an end stop or is moved by a known
/// cause; the distance it was pushed for a device that moved away from all of them or
/// faster than its response allows (a driver's hand). What is explained follows the
/// readings; what is not stays put, so a hand that pushes and holds keeps the distance.
fn unexplained(
    track: &mut Track,
    r: &crate::config::Response,
    range: [f64; 2],
    pos: f64,
    pushes: &[causes::Push],
    span: [f64; 2],
    now: Instant,
) -> f64 {
    let Some((from, at)) = track.explained else {
        track.explained = Some((pos, now));
        return 0.0;
    };
    let dt = (now - at).mul_f64(EXPLAIN_SLACK);
    let toward = |cmd: f64| from + r.progress(cmd - from, dt).copysign(cmd - from);
    let [min, max] = range;
    let (mut lo, mut hi) = (toward(span[0]).min(from), toward(span[1]).max(from));
    for p in pushes.iter().filter(|p| p.cause != causes::Cause::Command) {
        (lo, hi) = (lo.min(p.toward[0]), hi.max(p.toward[1]));
    }
    let explained = pos.clamp(lo.max(min), hi.min(max).max(lo.max(min)));
    track.explained = Some((explained, now));
    // A reading's own scatter and the dead band explain themselves, but never move
    // what is explained: a slow push gets no further by them.
    ((pos - explained).abs() - 3.0 * r.noise - r.deadband).max(0.0)
}

/// Faults that take the vehicle out of the planner's hands into the safe state (an
/// override hands it to the driver instead: [`Gate::take_over`]).
pub fn disengages(kind: FaultKind) -> bool {
    !matches!(kind, FaultKind::EngineStall | FaultKind::Override)
}

/// The procedure a fault calls for, if any (and if the vehicle has what it needs).
pub(crate) fn procedure_for(f: &Fault, gate: &Gate, cfg: &SupervisorConfig) -> Option<Procedure> {
    let v = &gate.vehicle();
    let b = v.bindings();
    let device = f.device.as_deref().and_then(|n| v.find(n)).map(|d| d.id());
    match (f.kind, device) {
        (FaultKind::EngineStall, _) => {
            let g = b.gear.as_ref()?;
            let d = v.device(g.device);
            let now = d
                .config()
                .state()
                .and_then(|i| d.reading(i))
                .map(|x| x as u8);
            let gear = now
                .filter(|s| g.drives(*s))
                .or_else(|| g.forward.first().copied())?;
            Procedure::engine_stall(v, gear, cfg)
        }
        // A kit's module is not homed nor re-enabled by adrive while disengaged.
        (FaultKind::NotFollowing | FaultKind::DeviceFault, Some(id))
            if b.steering == Some(id) && v.device(id).config().kit().is_none() =>
        {
            Procedure::steering(v, cfg)
        }
        _ => None,
    }
}

/// `2.1 s, longer than give_up_after (2s)`
fn over(d: Duration, limit: Duration) -> String {
    format!(
        "{:.1} s, longer than give_up_after ({})",
        d.as_secs_f64(),
        crate::config::limits::fmt_duration(limit)
    )
}

/// The supervisor's state between turns: memory, current procedure, cool-downs.
pub(crate) struct Supervisor {
    cfg: SupervisorConfig,
    memory: Memory,
    procedure: Option<Procedure>,
    /// A procedure that waits for the vehicle to be engaged (said once).
    waiting: Option<String>,
    /// A procedure of this name may not start again before this time.
    cooldown: HashMap<String, Instant>,
    /// Since when each procedure has been trying, by name: from its first start until
    /// it is done (it runs again after giving up, at the next engage).
    trying_since: HashMap<String, Instant>,
    /// The devices gone.
    gone: waiting::Waiting,
    exit: ExitSink,
    /// The run was asked to end (`give_up_after`): asked once.
    ended: bool,
}

impl Supervisor {
    pub(crate) fn new(cfg: SupervisorConfig, exit: ExitSink) -> Supervisor {
        Supervisor {
            memory: Memory::new(Instant::now()),
            cfg,
            procedure: None,
            waiting: None,
            cooldown: HashMap::new(),
            trying_since: HashMap::new(),
            gone: waiting::Waiting::default(),
            exit,
            ended: false,
        }
    }

    /// One turn: detect, report, act.
    pub(crate) fn tick(&mut self, gate: &Gate, now: Instant) {
        let v = &gate.vehicle();
        let board = &v.supervision();
        let before = board.faults();
        let snap = gate.snapshot(0);
        let faults = detect(&snap, v.config(), &self.cfg, &mut self.memory, &before, now);
        let among = |list: &[Fault], f: &Fault| {
            list.iter()
                .any(|g| g.kind == f.kind && g.device == f.device)
        };
        let is_new = |f: &Fault| !among(&before, f);
        for f in faults.iter().filter(|f| is_new(f)) {
            tracing::warn!(fault = %f.kind, device = f.device.as_deref(), "fault: {}", f.describe());
            board.note(format!("fault: {}", f.describe()));
        }
        for b in &before {
            if !among(&faults, b) {
                tracing::info!(fault = %b.kind, device = b.device.as_deref(), "cleared: {}", b.describe());
                board.note(format!(
                    "cleared: {} {}",
                    b.device.as_deref().unwrap_or(""),
                    b.kind
                ));
            }
        }
        board.set_faults(faults.clone());
        board.set_waiting(self.gone.turn(v, &faults, now));
        for f in faults.iter().filter(|f| f.kind == FaultKind::Override) {
            if let Some(device) = f.device.as_deref() {
                gate.take_over(device, &f.describe());
            }
        }

        // A disengaged vehicle is never moved by adrive on its own: a procedure that
        // moves an actuator runs only while engaged, and stops when it no longer is
        // (the disengage has commanded the safe state). It starts again from the top at
        // the next engage if its fault is still there.
        if self.procedure.as_ref().is_some_and(|p| !p.may_run(gate)) {
            let p = self.procedure.take().expect("checked");
            let msg = format!("recovery {} stopped: the vehicle is disengaged", p.name());
            tracing::warn!("{msg}");
            board.note(msg.clone());
            board.set_outcome(OutcomeKind::Stopped, msg);
            gate.set_recovering(&[]);
            board.set_recovery(None);
        }
        let start = match self.procedure {
            None => self.next_procedure(gate, &faults, &is_new, now),
            Some(_) => None,
        };
        // A fault disengages the vehicle, unless it was there before and a procedure
        // (running, or starting now) deals with it: engaging with it is the permission
        // to recover. A vehicle with a blocker (a device faulty or silent by its own
        // rule, the e-stop) is the gate monitor's to disengage, within its period and
        // in its words: the supervisor disengages for what only it sees, so that one
        // thread decides each disengage.
        if gate.is_engaged() && gate.blockers().is_empty() {
            let dealt_with = |f: &Fault| {
                let p = self.procedure.as_ref().or(start.as_ref().map(|(p, _)| p));
                !is_new(f)
                    && p.is_some_and(|p| {
                        procedure_for(f, gate, &self.cfg).is_some_and(|q| q.name() == p.name())
                    })
            };
            // A device the rules do not act on (a horn) is shown, never a reason to stop.
            let needed = |f: &Fault| {
                f.device
                    .as_deref()
                    .and_then(|n| v.find(n))
                    .is_none_or(|d| crate::safety::gate_state::needed(v, d))
            };
            if let Some(f) = faults
                .iter()
                .find(|f| disengages(f.kind) && needed(f) && !dealt_with(f))
            {
                gate.disengage_engaged(DisengageCause::Fault { fault: f.view(now) });
            }
        }
        match start {
            Some((p, f)) if p.may_run(gate) => {
                tracing::warn!("recovery {} started for {}", p.name(), f.describe());
                board.note(format!("recovery {} started: {}", p.name(), f.describe()));
                self.waiting = None;
                self.trying_since.entry(p.name().to_string()).or_insert(now);
                self.procedure = Some(p);
            }
            _ => {}
        }
        if self.procedure.is_none() {
            self.note_waiting(gate, &faults, now);
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
                    board.set_outcome(OutcomeKind::Done, msg);
                    self.trying_since.remove(p.name());
                    self.finish(gate, now);
                }
                Progress::GaveUp(why) => {
                    let cause = DisengageCause::GaveUp {
                        recovery: p.name().to_string(),
                        why,
                    };
                    let msg = cause.to_string();
                    // The vehicle safe first; then the outcome is told, so that whoever
                    // reads it finds the vehicle already disengaged.
                    gate.command_safe_state();
                    gate.disengage(cause);
                    tracing::error!("{msg}; it runs again from the top at the next engage");
                    board.note(msg.clone());
                    board.set_outcome(OutcomeKind::GaveUp, msg.clone());
                    let tried = self
                        .trying_since
                        .get(p.name())
                        .map_or(Duration::ZERO, |t| now - *t);
                    let give_up = self.cfg.give_up_after.filter(|limit| tried >= *limit);
                    if let Some(limit) = give_up {
                        self.end(gate, format!("{msg}, trying for {}", over(tried, limit)));
                    }
                    self.finish(gate, now);
                }
            }
        }
        if let Some(why) = self.gone_too_long(&faults, now) {
            self.end(gate, why);
        }
    }

    /// End the run, as the operator asked (`give_up_after`): the safe state, then the
    /// request to end (once).
    fn end(&mut self, gate: &Gate, why: String) {
        if !std::mem::replace(&mut self.ended, true) {
            tracing::error!("giving up: {why}");
            gate.command_safe_state();
            gate.disengage(DisengageCause::GivingUp { why: why.clone() });
            (self.exit)(Exit::Fatal(why));
        }
    }

    /// Why the run is to end now, if the operator asked for that (`give_up_after`): a
    /// device gone that long. `None` without `give_up_after`: a device gone never ends
    /// the run.
    fn gone_too_long(&self, faults: &[Fault], now: Instant) -> Option<String> {
        let limit = self.cfg.give_up_after?;
        let (device, gone) = self.gone.longest(now).filter(|(_, d)| *d >= limit)?;
        let cause = faults
            .iter()
            .find(|f| f.kind == FaultKind::Disconnected && f.device.as_deref() == Some(device))
            .map_or_else(String::new, |f| format!(": {}", f.cause));
        Some(format!("{device} gone for {}{cause}", over(gone, limit)))
    }

    /// The procedure to start now, and the fault it is for: the first fault whose
    /// procedure is not cooling down and, if it moves an actuator, may move it — the
    /// vehicle is engaged and the fault is not one that disengages it this turn.
    fn next_procedure(
        &self,
        gate: &Gate,
        faults: &[Fault],
        is_new: &dyn Fn(&Fault) -> bool,
        now: Instant,
    ) -> Option<(Procedure, Fault)> {
        faults.iter().find_map(|f| {
            let p = self.ready(f, gate, now)?;
            let disengaging = p.moves(gate) && disengages(f.kind) && is_new(f);
            (p.may_run(gate) && !disengaging).then(|| (p, f.clone()))
        })
    }

    /// The procedure `f` calls for, unless it is cooling down after its last run.
    fn ready(&self, f: &Fault, gate: &Gate, now: Instant) -> Option<Procedure> {
        let p = procedure_for(f, gate, &self.cfg)?;
        let cooling = self.cooldown.get(p.name()).is_some_and(|t| now < *t);
        (!cooling).then_some(p)
    }

    /// Say once that a fault's procedure waits for the vehicle to be engaged.
    fn note_waiting(&mut self, gate: &Gate, faults: &[Fault], now: Instant) {
        let waiting = faults.iter().find_map(|f| {
            let p = self.ready(f, gate, now)?;
            (!p.may_run(gate)).then(|| (p.name().to_string(), f))
        });
        let name = waiting.as_ref().map(|(n, _)| n.clone());
        if let Some((name, f)) = waiting.filter(|_| name != self.waiting) {
            let msg = format!("recovery {name} waits for engage: {}", f.describe());
            tracing::warn!("{msg}");
            gate.vehicle().supervision().note(msg.clone());
            gate.vehicle()
                .supervision()
                .set_outcome(OutcomeKind::Waits, msg);
        }
        self.waiting = name;
    }

    fn finish(&mut self, gate: &Gate, now: Instant) {
        if let Some(p) = self.procedure.take() {
            self.cooldown
                .insert(p.name().to_string(), now + self.cfg.step_timeout);
        }
        gate.set_recovering(&[]);
        gate.vehicle().supervision().set_recovery(None);
    }
}

/// The supervisor thread, `supervisor`, and the service watchdog's, `service/watchdog`.
pub struct Running {
    threads: Group,
}

/// How often the service watchdog looks at the threads' heartbeats.
const WATCHDOG_EVERY: Duration = Duration::from_millis(100);

/// Start the supervisor thread at `cfg.period`.
pub fn start(gate: Arc<Gate>, cfg: SupervisorConfig, exit: ExitSink) -> std::io::Result<Running> {
    start_watching(gate, cfg, exit, Liveness::default())
}

/// [`start`], and the `service/watchdog` thread: it feeds the service watchdog while
/// every thread of `watched` (the engine's, [`crate::engine::Engine::liveness`], and
/// the gate monitor's) and the supervisor itself runs and turns its loop within its
/// bound. A thread that stalls is named in the log, to systemd and in the snapshot
/// (`supervisor.stalled`); engage is refused while it is stalled
/// ([`crate::safety::gate_state::blockers`]), and an engaged vehicle is disengaged at once —
/// the gate monitor may be the thread that stalled.
pub(crate) fn start_watching(
    gate: Arc<Gate>,
    cfg: SupervisorConfig,
    exit: ExitSink,
    watched: Liveness,
) -> std::io::Result<Running> {
    let mut threads = Group::default();
    let g = gate.clone();
    let period = cfg.period;
    threads.spawn_beating("supervisor", period, move |stop, beat| {
        let panic_at = cfg.panic_for_test.map(|d| Instant::now() + d);
        let mut sup = Supervisor::new(cfg, exit);
        crate::threads::every(period, stop, || {
            beat.turn(period);
            if panic_at.is_some_and(|t| Instant::now() >= t) {
                panic!("injected panic (--inject-panic supervisor)");
            }
            sup.tick(&g, Instant::now());
        })
    })?;
    let watched = watched.with(&threads.liveness());
    threads.spawn("service/watchdog", move |stop| {
        let mut watchdog = crate::service::Watchdog::new(watched);
        crate::threads::every(WATCHDOG_EVERY, stop, || {
            let turn = watchdog.turn(Instant::now());
            if turn.changed {
                gate.vehicle().supervision().set_stalled(&turn.stalled);
            }
            if let (Some(s), true) = (turn.new.first(), gate.is_engaged()) {
                let stall = crate::snapshot::StallView {
                    thread: s.thread.clone(),
                    quiet_ms: s.quiet.as_secs_f64() * 1e3,
                    bound_ms: s.bound.as_secs_f64() * 1e3,
                };
                gate.disengage_engaged(DisengageCause::Stalled { stall });
            }
        })
    })?;
    Ok(Running { threads })
}

impl crate::threads::Shutdown for Running {
    fn shutdown(mut self, deadline: Duration) -> Vec<String> {
        self.threads.stop(Instant::now() + deadline)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::device::POSITION;
    use crate::testkit;

    /// Where the world takes `device` of Alice when `cause` acts on it, or `None`
    /// where that cause does not move it — written here from what Alice's devices do,
    /// not from [`causes::pushes`]: the e-stop's rule and the pedals' own watchdogs
    /// release the gas and apply the brake; the steering has neither.
    fn world(cause: causes::Cause, device: &str, commanded: f64) -> Option<f64> {
        use causes::Cause::*;
        match (cause, device) {
            (Command, _) => Some(commanded),
            (Estop | OwnWatchdog, "gas") => Some(0.0),
            (Estop | OwnWatchdog, "brake") => Some(1.0),
            _ => None,
        }
    }

    /// Run the supervisor's turns (every 50 ms) over Alice while `cause` moves
    /// `device` from `start` to where it takes it, `speed` a share of the range a
    /// turn (1: at once); adrive has `commanded` it (acknowledged, then resent
    /// unless the cause is its silence). Returns the overrides and failures to follow
    /// named for it.
    fn judged(
        cause: causes::Cause,
        device: &str,
        start: f64,
        commanded: f64,
        speed: f64,
    ) -> Vec<(u32, FaultKind)> {
        let t0 = Instant::now();
        let gate = testkit::gate(t0);
        let v = &gate.vehicle();
        let sup = SupervisorConfig::default();
        let target = world(cause, device, commanded).expect("a cause that moves it");
        let [lo, hi] = v.find(device).unwrap().config().range;
        let mut mem = Memory::new(t0);
        let mut faults: Vec<Fault> = Vec::new();
        let mut named = Vec::new();
        let mut pos = start;
        for k in 0..60u32 {
            let now = t0 + Duration::from_millis(50 * u64::from(k));
            let mut snap = gate.snapshot_at(0, now);
            if cause == causes::Cause::Estop {
                let e = snap.devices.iter_mut().find(|d| d.name == "estop").unwrap();
                if let Some((_, x)) = e.readings.0.iter_mut().find(|(n, _)| n == "estop") {
                    *x = Some(Value::Text("pause".into()));
                }
            }
            let d = snap.devices.iter_mut().find(|d| d.name == device).unwrap();
            if k > 0 {
                let step = speed * (hi - lo);
                pos += (target - pos).clamp(-step, step);
            }
            if let Some((_, x)) = d.readings.0.iter_mut().find(|(n, _)| n == POSITION) {
                *x = Some(Value::Number(pos));
            }
            d.status_age_ms = Some(5.0);
            d.stale = false;
            d.executed = Some(Value::Number(commanded));
            d.commanded = Some(Value::Number(commanded));
            d.executed_span = Some([commanded, commanded]);
            // Silent for 2 s already when its own watchdog acts; resent every 250 ms
            // otherwise.
            d.executed_age_ms = Some(if cause == causes::Cause::OwnWatchdog {
                2000.0 + 50.0 * f64::from(k)
            } else {
                f64::from(k % 5) * 50.0
            });
            if let Some(e) = d.estimate.as_mut() {
                e.position = pos;
            }
            faults = detect(&snap, v.config(), &sup, &mut mem, &faults, now);
            named.extend(
                faults
                    .iter()
                    .filter(|f| f.device.as_deref() == Some(device))
                    .map(|f| (k, f.kind))
                    .filter(|(_, k)| matches!(k, FaultKind::Override | FaultKind::NotFollowing)),
            );
        }
        named
    }

    proptest::proptest! {
        #![proptest_config(proptest::prelude::ProptestConfig::with_cases(64))]
        /// A fault is named after its cause: an actuator moved by a known cause — the
        /// e-stop, its own watchdog, adrive's command (a stop's safe or manual state,
        /// a recovery step) — at any speed the cause has that is no slower than the
        /// actuator's response (slower, it is not following whatever moves it), from
        /// anywhere, is never a driver's override nor an actuator that does not follow.
        /// Every cause × every set point actuator of Alice.
        #[test]
        fn an_actuator_moved_by_a_known_cause_is_never_an_override(
            cause in proptest::sample::select(causes::Cause::ALL.to_vec()),
            device in proptest::sample::select(vec!["steer", "gas", "brake"]),
            start in 0.0..1.0f64,
            commanded in 0.0..1.0f64,
            speed in proptest::sample::select(vec![0.05f64, 0.1, 0.5, 1.0]),
        ) {
            proptest::prop_assume!(world(cause, device, commanded).is_some());
            // Where adrive's command drives it the same way as the cause does (the cause
            // is that command, or the e-stop or its own watchdog pushes it where adrive
            // commanded it too), it moves at least as its response says: the steering
            // at its rate (1/s: 0.05 a turn, faster is a hand), the pedals at least that
            // fast (an 80 ms lag goes most of the way in a 50 ms turn). Slower, it does
            // not follow adrive's command, which is what that detector is for.
            let toward = world(cause, device, commanded).unwrap_or(commanded);
            let with_command = (commanded - start) * (toward - start) > 0.0;
            let speed = match (cause, device) {
                (causes::Cause::Command, "steer") => 0.05,
                _ if with_command => speed.max(0.05),
                _ => speed,
            };
            let named = judged(cause, device, start, commanded, speed);
            proptest::prop_assert!(named.is_empty(), "{cause:?} on {device}: {named:?}");
        }
    }

    /// The incident, at the detector: after an override on the steering was cleared,
    /// the brake was in the manual state (commanded 0) when the e-stop paused and the
    /// brake went full; it was named "driver override on brake". A foot on the same
    /// brake with the e-stop in run still is one.
    #[test]
    fn the_brake_applied_under_an_e_stop_pause_is_no_override_a_foot_still_is() {
        let named = judged(causes::Cause::Estop, "brake", 0.0, 0.0, 1.0);
        assert!(named.is_empty(), "{named:?}");
        // The same move with no known cause behind it: a driver's foot.
        let t0 = Instant::now();
        let gate = testkit::gate(t0);
        let v = &gate.vehicle();
        let sup = SupervisorConfig::default();
        let mut mem = Memory::new(t0);
        let mut faults: Vec<Fault> = Vec::new();
        for k in 0..20u64 {
            let now = t0 + Duration::from_millis(50 * k);
            let mut snap = gate.snapshot_at(0, now);
            let d = snap.devices.iter_mut().find(|d| d.name == "brake").unwrap();
            if let Some((_, x)) = d.readings.0.iter_mut().find(|(n, _)| n == POSITION) {
                *x = Some(Value::Number(if k == 0 { 0.0 } else { 1.0 }));
            }
            d.status_age_ms = Some(5.0);
            d.executed = Some(Value::Number(0.0));
            d.executed_span = Some([0.0, 0.0]);
            d.executed_age_ms = Some(10.0);
            faults = detect(&snap, v.config(), &sup, &mut mem, &faults, now);
        }
        assert!(
            faults
                .iter()
                .any(|f| f.kind == FaultKind::Override && f.device.as_deref() == Some("brake")),
            "{faults:?}"
        );
    }

    /// Which faults take the vehicle to the safe state: every one but a stalled engine
    /// (its own procedure restarts it, the brake held) and a driver's hand (the driver
    /// takes over, the gate hands the vehicle to them).
    #[test]
    fn every_fault_disengages_but_a_stalled_engine_and_a_hand() {
        use FaultKind::*;
        for kind in [EngineStall, Override] {
            assert!(!disengages(kind), "{kind:?}");
        }
        for kind in [
            Silent,
            Disconnected,
            ErrorRate,
            DeviceFault,
            OutOfRange,
            NotFollowing,
            EstopPause,
            EstopDisable,
        ] {
            assert!(disengages(kind), "{kind:?}");
        }
    }

    /// The procedure a fault calls for: a stalled engine its restart; the steering not
    /// following, or faulty, its homing — Alice's own steering only, not another
    /// device, and not a kit's module (adrive neither homes nor enables one while
    /// disengaged); anything else none.
    #[test]
    fn a_fault_calls_for_its_procedure_on_the_device_that_has_one() {
        let now = Instant::now();
        let sup = SupervisorConfig::default();
        let fault = |kind, device: Option<&str>| Fault {
            kind,
            device: device.map(str::to_string),
            cause: String::new(),
            since: now,
        };
        let alice = testkit::gate(now);
        let called = |gate: &Gate, kind, device| {
            procedure_for(&fault(kind, device), gate, &sup).map(|p| p.name().to_string())
        };
        assert_eq!(
            called(&alice, FaultKind::EngineStall, None).as_deref(),
            Some("engine_stall")
        );
        for kind in [FaultKind::NotFollowing, FaultKind::DeviceFault] {
            assert_eq!(
                called(&alice, kind, Some("steer")).as_deref(),
                Some("steering"),
                "{kind:?}"
            );
            assert_eq!(
                called(&alice, kind, Some("gas")),
                None,
                "{kind:?} on the gas"
            );
            assert_eq!(called(&alice, kind, None), None, "{kind:?} of no device");
        }
        assert_eq!(called(&alice, FaultKind::Silent, Some("steer")), None);
        let oscc = crate::config::parse(
            include_str!("../../vehicles/oscc.toml"),
            "vehicles/oscc.toml",
        )
        .expect("the OSCC vehicle parses");
        let kit = testkit::gate_of(oscc, now);
        let steering = kit.vehicle().bindings().steering.expect("OSCC steers");
        let name = kit.vehicle().device(steering).config().name.clone();
        assert_eq!(
            called(&kit, FaultKind::NotFollowing, Some(&name)),
            None,
            "a kit's steering module"
        );
    }

    /// A fault that persists keeps the time it was first seen — its own: the same
    /// kind on the same device, not the same kind on another device, nor another kind
    /// on the same device (the display's "for 3 s" and how long a fault has lasted).
    #[test]
    fn a_persisting_fault_keeps_its_own_since() {
        let gate = testkit::gate(Instant::now());
        let v = &gate.vehicle();
        let sup = SupervisorConfig::default();
        // Nothing has answered: every device silent 2 s on.
        let t0 = v.find("steer").unwrap().started();
        let now = t0 + Duration::from_secs(2);
        let snap = gate.snapshot_at(0, now);
        let silent = FaultKind::Silent;
        let was = |kind, device: &str, ago: u64| Fault {
            kind,
            device: Some(device.into()),
            cause: String::new(),
            since: now - Duration::from_millis(ago),
        };
        let previous = [
            was(silent, "steer", 700),
            was(silent, "gas", 500),
            was(FaultKind::Override, "brake", 300),
        ];
        let faults = detect(
            &snap,
            v.config(),
            &sup,
            &mut Memory::new(t0),
            &previous,
            now,
        );
        let since = |device: &str| {
            faults
                .iter()
                .find(|f| f.kind == silent && f.device.as_deref() == Some(device))
                .unwrap_or_else(|| panic!("{device} silent: {faults:?}"))
                .since
        };
        assert_eq!(now - since("steer"), Duration::from_millis(700));
        assert_eq!(now - since("gas"), Duration::from_millis(500));
        assert_eq!(
            since("brake"),
            now,
            "another kind on the brake is not its silence"
        );
    }

    /// A kit's module may keep its override flag until it is enabled again, and
    /// adrive enables no module while disengaged: the flag, once the gate had latched
    /// the override, kept the supervisor naming it, so the operator could never clear
    /// it (clearing is refused while a hand is named on) nor engage to clear the flag.
    /// The flag names the override until the gate latches it, then no more; a flag
    /// raised again after the next enable names it again.
    #[test]
    fn a_kit_s_latched_override_flag_names_the_override_once_not_forever() {
        let now = Instant::now();
        let config = crate::config::parse(
            include_str!("../../vehicles/oscc.toml"),
            "vehicles/oscc.toml",
        )
        .expect("the OSCC vehicle parses");
        let gate = testkit::gate_of(config, now);
        let v = &gate.vehicle();
        let sup = SupervisorConfig::default();
        let mut mem = Memory::new(now);
        let mut turn_aged = |flag: bool, age_ms: f64| {
            let mut snap = gate.snapshot_at(0, now);
            let d = snap.devices.iter_mut().find(|d| d.name == "steer").unwrap();
            if let Some((_, x)) = d.readings.0.iter_mut().find(|(n, _)| n == "override") {
                *x = Some(Value::Flag(flag));
            }
            d.status_age_ms = Some(age_ms);
            let faults = detect(&snap, v.config(), &sup, &mut mem, &[], now);
            let named = faults
                .iter()
                .any(|f| f.kind == FaultKind::Override && f.device.as_deref() == Some("steer"));
            if named {
                gate.take_over("steer", "the kit's flag");
            }
            named
        };
        // A flag is believed from a status no older than the module's bound (200 ms,
        // and the 50 ms a reply may take), not from an older one.
        assert!(
            !turn_aged(true, 260.0),
            "a flag from a status too old to trust"
        );
        assert!(
            turn_aged(true, 245.0),
            "the flag raised: the driver's override"
        );
        let mut turn = |flag: bool| turn_aged(flag, 5.0);
        assert!(!turn(true), "latched: the flag is a memory now");
        assert_eq!(gate.clear_overrides(), Ok(vec!["steer".to_string()]));
        assert!(!turn(true), "cleared, the module still keeps its flag");
        assert!(!turn(false), "enabled again: the flag is down");
        assert!(turn(true), "raised again: a new override");
    }

    /// One thread decides each disengage: a vehicle with a blocker (here a faulty
    /// steering) is the gate monitor's to disengage, so the supervisor names the fault it
    /// sees there and leaves the vehicle to the monitor (no monitor runs here: it stays
    /// engaged); a fault only the supervisor sees, on a vehicle with no blocker, it
    /// disengages for itself, in its words.
    #[test]
    fn the_supervisor_disengages_only_for_what_the_gate_monitor_does_not() {
        for blocked in [true, false] {
            let now = Instant::now();
            let gate = testkit::gate(now);
            let v = &gate.vehicle();
            gate.engage("test").unwrap();
            let steer = v.find("steer").expect("alice steers");
            if blocked {
                testkit::make_faulty(v, "steer", now);
            }
            // A fresh reading far outside -1…1: out of range, which only the
            // supervisor judges.
            let mut c = steer.cached();
            c.reading.set(0, 5.0);
            c.at = Some(now);
            steer.store(c);
            assert_eq!(gate.blockers().is_empty(), !blocked);
            let mut sup = Supervisor::new(SupervisorConfig::default(), Box::new(|_| {}));
            sup.tick(&gate, Instant::now());
            assert!(
                v.supervision().has(FaultKind::OutOfRange, Some("steer")),
                "named either way"
            );
            assert_eq!(gate.is_engaged(), blocked, "{}", gate.reason());
            if !blocked {
                assert!(
                    gate.reason()
                        .starts_with("disengaged: supervisor: steer out_of_range"),
                    "{}",
                    gate.reason()
                );
            }
        }
    }

    /// The console once set a status period longer than `status_max_age`: the device
    /// answered every poll, so it had no last error, and its `silent` fault was logged
    /// as `… (max 250 ms): ` with an empty cause.
    #[test]
    fn a_silent_device_without_an_error_has_no_empty_cause() {
        let gate = testkit::gate(Instant::now());
        let v = &gate.vehicle();
        let steer = v.find("steer").expect("alice steers");
        let answered = steer.started() + Duration::from_millis(100);
        steer.record_ok(answered);
        // It answered, and not since: 2 s later it is silent.
        let now = answered + Duration::from_secs(2);
        let sup = SupervisorConfig::default();
        let silent = |faults: Vec<Fault>| {
            faults
                .into_iter()
                .find(|f| f.kind == FaultKind::Silent && f.device.as_deref() == Some("steer"))
                .expect("steer is silent")
        };
        let mut mem = Memory::new(answered);
        let snap = gate.snapshot_at(0, now);
        let f = silent(detect(&snap, v.config(), &sup, &mut mem, &[], now));
        assert_eq!(f.cause, "no answer for 2000 ms (max 250 ms)");
        *steer.health().last_error.lock() = Some((now, "timeout".into()));
        let snap = gate.snapshot_at(0, now);
        let f = silent(detect(&snap, v.config(), &sup, &mut mem, &[], now));
        assert!(f.cause.ends_with("(max 250 ms): timeout"), "{f:?}");
    }

    /// A controller alternating the brake between 0.1 and 0.6 every 10 ms, seen by
    /// turns that always fall on the 0.6 (a 100 ms period locked to a 20 ms cycle):
    /// the brake hovers between the two, moving toward each in turn. Judged by the one
    /// command a turn sees, it is pushed toward 0.1 by a foot (an override, which
    /// releases the brake) and makes no headway toward 0.6 (not following, which stops
    /// the vehicle) — the bench's section 5 ran into both. Judged by every set point
    /// acknowledged since the last turn, it is simply following.
    #[test]
    fn a_brake_alternating_faster_than_the_turns_is_neither_pushed_nor_stuck() {
        let t0 = Instant::now();
        let gate = testkit::gate(t0);
        let v = &gate.vehicle();
        let sup = SupervisorConfig::default();
        let turns = |span: Option<[f64; 2]>| {
            let mut mem = Memory::new(t0);
            let mut faults: Vec<Fault> = Vec::new();
            let mut named = Vec::new();
            for k in 0..40u32 {
                let now = t0 + Duration::from_millis(100 * u64::from(k));
                let mut snap = gate.snapshot_at(0, now);
                let b = snap.devices.iter_mut().find(|d| d.name == "brake").unwrap();
                let pos = 0.35 - 0.05 * f64::from(k % 2);
                if let Some((_, x)) = b.readings.0.iter_mut().find(|(n, _)| n == POSITION) {
                    *x = Some(Value::Number(pos));
                }
                b.status_age_ms = Some(5.0);
                b.stale = false;
                b.executed = Some(Value::Number(0.6));
                b.executed_span = span;
                if let Some(e) = b.estimate.as_mut() {
                    e.position = pos;
                }
                faults = detect(&snap, v.config(), &sup, &mut mem, &faults, now);
                named.extend(
                    faults
                        .iter()
                        .filter(|f| f.device.as_deref() == Some("brake"))
                        .map(|f| f.kind)
                        .filter(|k| matches!(k, FaultKind::Override | FaultKind::NotFollowing)),
                );
            }
            named
        };
        assert_eq!(turns(Some([0.1, 0.6])), vec![], "following its commands");
        let old = turns(None);
        assert!(
            old.contains(&FaultKind::Override) || old.contains(&FaultKind::NotFollowing),
            "judged by the one command a turn sees, it is at fault: {old:?}"
        );
    }

    /// The incident: after `vanish steer 3000` the supervisor named `silent` and
    /// `error_rate` the moment the port reopened — its last answer was 3 s old and the
    /// failed transactions of the unplug were still in the error window — and cleared
    /// them once it answered. A port back after a disconnect is judged from its reopen:
    /// silent only after its own `status_max_age` without an answer since, its error
    /// rate only over the transactions since. A device that still does not answer is
    /// named silent once that grace has passed; one whose port is reopened while it stays
    /// silent (after failed transactions, not a disconnect) gets no grace at all.
    #[test]
    fn a_port_back_after_a_disconnect_gets_its_status_max_age_before_silent_or_error_rate() {
        let t0 = Instant::now();
        let gate = testkit::gate(t0);
        let v = &gate.vehicle();
        let sup = SupervisorConfig::default();
        // Steer (status_max_age 250 ms), turn by turn every 50 ms: answering up to 1 s,
        // then its transactions fail; `unplugged` (500 ms later, for 3 s) its port is
        // gone; from `reopened` on, open again; answering again from `answers` (if ever).
        let run = |unplugged: bool, answers: Option<u64>| {
            let mut mem = Memory::new(t0);
            let mut faults: Vec<Fault> = Vec::new();
            let mut named: Vec<(u64, FaultKind)> = Vec::new();
            let (mut polls, mut errors, mut answered) = (0u64, 0u64, 0u64);
            let reopened = if unplugged { 4500 } else { 1500 };
            for ms in (0..6000u64).step_by(50) {
                let now = t0 + Duration::from_millis(ms);
                let mut snap = gate.snapshot_at(0, now);
                let d = snap.devices.iter_mut().find(|d| d.name == "steer").unwrap();
                let ok = ms < 1000 || answers.is_some_and(|a| ms >= a);
                if ok {
                    polls += 1;
                    answered = ms;
                } else if !(unplugged && (1500..reopened).contains(&ms)) {
                    errors += 1;
                }
                d.counters.polls = polls + errors;
                d.counters.status_errors = errors;
                d.health.quiet_ms = Some((ms - answered) as f64);
                d.status_age_ms = Some((ms - answered) as f64);
                d.health.missing = unplugged && (1500..reopened).contains(&ms);
                d.health.opens = if ms < reopened { 1 } else { 2 };
                d.health.last_error = (!ok).then(|| "no reply within 100ms".into());
                d.health.last_error_age_ms = (!ok).then_some(10.0);
                faults = detect(&snap, v.config(), &sup, &mut mem, &faults, now);
                named.extend(
                    faults
                        .iter()
                        .filter(|f| f.device.as_deref() == Some("steer"))
                        .map(|f| (ms, f.kind))
                        .filter(|(_, k)| matches!(k, FaultKind::Silent | FaultKind::ErrorRate)),
                );
            }
            named
        };
        // Back, and answering within its status_max_age (250 ms): nothing after the reopen.
        let back = run(true, Some(4700));
        assert!(
            back.iter().all(|(ms, _)| *ms < 4500),
            "named after the reopen: {back:?}"
        );
        assert!(back.contains(&(1250, FaultKind::Silent)), "{back:?}");
        // Back, never answering: silent once 250 ms passed since the reopen, not before.
        let mute = run(true, None);
        let first = mute
            .iter()
            .find(|(ms, k)| *ms >= 4500 && *k == FaultKind::Silent)
            .expect("named silent after its grace");
        assert_eq!(first.0, 4800, "{mute:?}");
        // Reopened while silent, never gone: still silent, turn after turn.
        let silent = run(false, None);
        assert!(
            (1250..6000)
                .step_by(50)
                .all(|ms| silent.contains(&(ms, FaultKind::Silent))),
            "{silent:?}"
        );
    }

    /// The incident: a vehicle file naming a port that does not exist was reported as
    /// `steer silent … never answered`, not `disconnected` as the fault table says, so
    /// no reconnect procedure ran for it. A port that cannot be opened is disconnected,
    /// opened before or not, and the cause names the path.
    #[test]
    fn a_port_that_cannot_be_opened_at_start_is_disconnected_not_silent() {
        let t0 = Instant::now();
        let gate = testkit::gate(t0);
        let v = &gate.vehicle();
        let sup = SupervisorConfig::default();
        let mut mem = Memory::new(t0);
        let now = t0 + Duration::from_secs(2);
        let mut snap = gate.snapshot_at(0, now);
        let d = snap.devices.iter_mut().find(|d| d.name == "steer").unwrap();
        d.health.opens = 0;
        d.health.missing = true;
        d.health.quiet_ms = None;
        d.status_age_ms = None;
        d.health.last_error =
            Some("port: cannot open /dev/ttyUSB7: No such file or directory".into());
        d.health.last_error_age_ms = Some(5.0);
        let faults = detect(&snap, v.config(), &sup, &mut mem, &[], now);
        let steer: Vec<&Fault> = faults
            .iter()
            .filter(|f| f.device.as_deref() == Some("steer"))
            .collect();
        assert_eq!(steer.len(), 1, "{steer:?}");
        assert_eq!(steer[0].kind, FaultKind::Disconnected);
        assert_eq!(
            steer[0].cause,
            "cannot open /dev/ttyUSB7: No such file or directory"
        );
        let f = &steer[0];
        assert!(
            procedure_for(f, &gate, &sup).is_none(),
            "a device gone is waited for, not recovered"
        );
    }

    /// A fault's log line, in the console's log pane and the log file, named its device
    /// `device=Some("steer")`, and a fault of no device (an engine stall) `device=None`.
    #[test]
    fn a_fault_log_line_names_its_device_plainly() {
        use tracing_subscriber::layer::SubscriberExt;
        let ring = crate::logging::ring::LogRing::default();
        let sub = tracing_subscriber::registry().with(ring.layer());
        let gate = testkit::gate(Instant::now());
        let v = &gate.vehicle();
        let set = |device: &str, i: usize, x: f64| {
            let d = v.find(device).expect("an alice device");
            let mut c = d.cached();
            c.reading.set(i, x);
            d.store(c);
        };
        set("steer", 0, 5.0); // position, far outside -1…1
        set("obd", 0, 0.0); // rpm: the engine stopped …
        set("obd", 3, 0.0); // … not running …
        set("trans", 0, 3.0); // … in drive
        let mut sup = Supervisor::new(SupervisorConfig::default(), Box::new(|_| {}));
        tracing::subscriber::with_default(sub, || sup.tick(&gate, Instant::now()));
        let lines: Vec<String> = ring.recent().into_iter().map(|l| l.text).collect();
        let logged = |start: &str| {
            lines
                .iter()
                .find(|l| l.starts_with(start))
                .unwrap_or_else(|| panic!("{start}… is logged: {lines:#?}"))
        };
        let range = logged("fault: steer out_of_range");
        assert!(
            range.ends_with(" fault=out_of_range device=steer"),
            "{range}"
        );
        let stall = logged("fault: engine_stall");
        assert!(stall.ends_with(" fault=engine_stall"), "{stall}");
        assert!(
            lines
                .iter()
                .all(|l| !l.contains("Some(") && !l.contains("None")),
            "{lines:#?}"
        );
    }

    /// A kit's fault codes by the DBC's names in the fault the console and the log show,
    /// beside the status word; a device without names keeps the word alone.
    #[test]
    fn a_device_fault_names_the_kits_fault_codes() {
        let now = Instant::now();
        let gate = testkit::gate(now);
        let v = &gate.vehicle();
        let mut snap = gate.snapshot_at(0, now);
        for d in snap
            .devices
            .iter_mut()
            .filter(|d| d.name == "steer" || d.name == "gas")
        {
            d.fault = 2;
            d.status_age_ms = Some(5.0);
        }
        let steer = snap.devices.iter_mut().find(|d| d.name == "steer").unwrap();
        steer.faults = vec!["OPERATOR_OVERRIDE".into()];
        let sup = SupervisorConfig::default();
        let faults = detect(&snap, v.config(), &sup, &mut Memory::new(now), &[], now);
        let cause = |name: &str| {
            faults
                .iter()
                .find(|f| f.kind == FaultKind::DeviceFault && f.device.as_deref() == Some(name))
                .map(|f| f.cause.clone())
                .unwrap_or_else(|| panic!("{name} device_fault: {faults:?}"))
        };
        assert_eq!(cause("steer"), "reports faults OPERATOR_OVERRIDE (0x0002)");
        assert_eq!(cause("gas"), "status word reports faults 0x0002");
    }

    /// One turn of the supervisor over Alice at `now`, the steering's view changed by
    /// `edit`: the faults of `kind` it names for the steering.
    fn steer_turn(
        gate: &Gate,
        mem: &mut Memory,
        now: Instant,
        kind: FaultKind,
        edit: impl FnOnce(&mut DeviceView),
    ) -> Vec<Fault> {
        let mut snap = gate.snapshot_at(0, now);
        edit(snap.devices.iter_mut().find(|d| d.name == "steer").unwrap());
        let sup = SupervisorConfig::default();
        detect(&snap, gate.vehicle().config(), &sup, mem, &[], now)
            .into_iter()
            .filter(|f| f.kind == kind && f.device.as_deref() == Some("steer"))
            .collect()
    }

    /// A device's error rate counts every transaction of the window — its polls, good
    /// or failed, its acknowledged commands and its failed ones — and names how many
    /// failed of how many; it judges no fewer than 4, and forgets a burst once it has
    /// left the window.
    #[test]
    fn the_error_rate_counts_every_transaction_of_its_window() {
        let t0 = Instant::now();
        let gate = testkit::gate(t0);
        let mut mem = Memory::new(t0);
        // (polls, of which failed, commands acknowledged, commands failed) so far.
        let counted = |n: (u64, u64, u64, u64)| {
            move |d: &mut DeviceView| {
                (
                    d.counters.polls,
                    d.counters.status_errors,
                    d.counters.executed,
                    d.counters.command_errors,
                ) = n;
                d.health.last_error = Some("no reply within 100ms".into());
                d.health.last_error_age_ms = Some(10.0);
            }
        };
        let rate = |mem: &mut Memory, ms: u64, n| {
            let now = t0 + Duration::from_millis(ms);
            steer_turn(&gate, mem, now, FaultKind::ErrorRate, counted(n))
        };
        assert_eq!(rate(&mut mem, 0, (100, 10, 50, 5)), vec![]);
        // Since: 6 polls (4 failed), 3 commands acknowledged, 2 failed: 6 of 11.
        let f = rate(&mut mem, 1000, (106, 14, 53, 7));
        assert_eq!(f.len(), 1, "{f:?}");
        assert_eq!(
            f[0].cause,
            "6 of 11 transactions failed in 2 s: no reply within 100ms"
        );
        // 2.5 s after the burst, nothing more failed, nothing more was tried.
        assert_eq!(rate(&mut mem, 3500, (106, 14, 53, 7)), vec![], "forgotten");

        // Too few to judge: 3 transactions, every one failed; then a 4th.
        let mut mem = Memory::new(t0);
        assert_eq!(rate(&mut mem, 0, (100, 10, 50, 5)), vec![]);
        assert_eq!(rate(&mut mem, 100, (102, 12, 50, 6)), vec![], "3 tries");
        let f = rate(&mut mem, 200, (103, 13, 50, 6));
        assert_eq!(
            f.iter().map(|f| f.cause.as_str()).collect::<Vec<_>>(),
            ["4 of 4 transactions failed in 2 s: no reply within 100ms"]
        );
    }

    /// A reading older than `status_max_age` + `reply_timeout` (the steering's 250 +
    /// 100 ms) is not believed: its fault bits name no device fault (its silence is
    /// named instead); one within that age is judged.
    #[test]
    fn fault_bits_count_from_a_status_no_older_than_its_max_age_and_reply_timeout() {
        let t0 = Instant::now();
        let gate = testkit::gate(t0);
        let faulted = |age_ms: f64| {
            let now = t0 + Duration::from_secs(1);
            let mut mem = Memory::new(t0);
            steer_turn(&gate, &mut mem, now, FaultKind::DeviceFault, |d| {
                d.fault = 0x0004;
                d.status_age_ms = Some(age_ms);
            })
        };
        let f = faulted(345.0);
        assert_eq!(f.len(), 1, "{f:?}");
        assert_eq!(f[0].cause, "status word reports faults 0x0004");
        assert_eq!(faulted(355.0), vec![], "a status too old to believe");
    }

    /// A position may stray `range_margin` of the range outside it (the steering's
    /// [-1, 1]: 0.1 either side) and no further: at the margin it is in range, past it
    /// on either side it is out, named with its value.
    #[test]
    fn a_position_is_out_of_range_past_its_margin_not_at_it() {
        let t0 = Instant::now();
        let gate = testkit::gate(t0);
        let out = |pos: f64| {
            let mut mem = Memory::new(t0);
            let f = steer_turn(&gate, &mut mem, t0, FaultKind::OutOfRange, |d| {
                if let Some((_, x)) = d.readings.0.iter_mut().find(|(n, _)| n == POSITION) {
                    *x = Some(Value::Number(pos));
                }
                d.status_age_ms = Some(5.0);
            });
            f.into_iter().map(|f| f.cause).collect::<Vec<_>>()
        };
        for pos in [-1.1, -1.09, -1.0, 0.0, 1.0, 1.09, 1.1] {
            assert_eq!(out(pos), Vec::<String>::new(), "{pos} is in range");
        }
        assert_eq!(out(-1.11), ["reports -1.110, outside [-1, 1]"]);
        assert_eq!(out(1.11), ["reports 1.110, outside [-1, 1]"]);
    }

    /// Alice at rest — every device answering, no fault bit set — has no fault; a kit's
    /// module with a fault code, disengaged, is shown by name but is no device fault
    /// (the kit's own rule, [`kit`]).
    #[test]
    fn a_vehicle_at_rest_has_no_fault_and_a_kit_s_codes_disengaged_block_nothing() {
        let now = Instant::now();
        let gate = testkit::gate(now);
        let sup = SupervisorConfig::default();
        let snap = gate.snapshot_at(0, now);
        let v = &gate.vehicle();
        let faults = detect(&snap, v.config(), &sup, &mut Memory::new(now), &[], now);
        assert_eq!(faults, vec![]);

        let config = crate::config::parse(
            include_str!("../../vehicles/oscc.toml"),
            "vehicles/oscc.toml",
        )
        .expect("the OSCC vehicle parses");
        let gate = testkit::gate_of(config, now);
        let v = &gate.vehicle();
        let mut snap = gate.snapshot_at(0, now);
        let d = snap.devices.iter_mut().find(|d| d.name == "steer").unwrap();
        d.fault = 0x0002;
        d.status_age_ms = Some(5.0);
        let faults = detect(&snap, v.config(), &sup, &mut Memory::new(now), &[], now);
        assert!(
            faults.iter().all(|f| f.kind != FaultKind::DeviceFault),
            "{faults:?}"
        );
    }

    /// The vehicle at `now` with its steering measured at `pos`, commanded and executed
    /// `cmd` 10 ms before, its status 5 ms old: a hand holding it, or not.
    fn steering_held(gate: &Gate, now: Instant, pos: f64, cmd: f64) -> Snapshot {
        let mut snap = gate.snapshot_at(0, now);
        let d = snap.devices.iter_mut().find(|d| d.name == "steer").unwrap();
        if let Some((_, x)) = d.readings.0.iter_mut().find(|(n, _)| n == POSITION) {
            *x = Some(Value::Number(pos));
        }
        d.status_age_ms = Some(5.0);
        d.executed = Some(Value::Number(cmd));
        d.commanded = Some(Value::Number(cmd));
        d.executed_span = Some([cmd, cmd]);
        d.executed_age_ms = Some(10.0);
        if let Some(e) = d.estimate.as_mut() {
            e.position = pos;
        }
        snap
    }

    /// A steering held exactly `override_threshold` from where its command can have
    /// taken it, once its noise and dead band are taken off (all binary fractions here,
    /// so that "exactly" is exact), is within it: never named, however long; a
    /// hundredth further is, after `override_time` (300 ms, turns every 50 ms).
    #[test]
    fn a_steering_exactly_at_the_threshold_is_no_override() {
        let t0 = Instant::now();
        let text = crate::config::ALICE_TOML.replace(
            "[device.response]         # the real drive: full range a second\nrate = 1.0\n",
            "[device.response]         # the real drive: full range a second\nrate = 1.0\nnoise = 0.0009765625\ndeadband = 0.00390625\noverride_threshold = 0.25\n",
        );
        let config = crate::config::parse(&text, "quiet.toml")
            .expect("Alice, her steering in binary fractions");
        let steer = config
            .device("steer")
            .unwrap()
            .response
            .expect("a response");
        assert_eq!((steer.noise, steer.deadband), (1.0 / 1024.0, 1.0 / 256.0));
        let gate = testkit::gate_of(config, t0);
        let v = &gate.vehicle();
        let sup = SupervisorConfig::default();
        let steer_at = |now: Instant, pos: f64| steering_held(&gate, now, pos, 0.25);
        let mut mem = Memory::new(t0);
        let mut faults: Vec<Fault> = Vec::new();
        let mut named = Vec::new();
        for k in 0..40u64 {
            let pos = match k {
                0 => 0.25,
                // 0.25 away once three noises and the dead band are taken off, exactly.
                1..=19 => 0.25 + 0.25 + 3.0 / 1024.0 + 1.0 / 256.0,
                _ => 0.26 + 0.25 + 3.0 / 1024.0 + 1.0 / 256.0,
            };
            let now = t0 + Duration::from_millis(50 * k);
            faults = detect(
                &steer_at(now, pos),
                v.config(),
                &sup,
                &mut mem,
                &faults,
                now,
            );
            if faults.iter().any(|f| f.kind == FaultKind::Override) {
                named.push(k);
            }
        }
        assert_eq!(named.first(), Some(&27), "{named:?}");
    }

    /// A hand that pushes the steering (commanded 0.3) to 0.8 and holds it there: named
    /// a driver's override once it has been away longer than `override_time` (300 ms,
    /// turns every 50 ms), then held away from its command as long as it stays further
    /// than `override_threshold` (0.2) from it, on either side, keeping the since of
    /// its naming; back within 0.2 of its command, the override is over. An override
    /// named on another device names none on the steering.
    #[test]
    fn a_hand_on_the_steering_is_named_after_override_time_and_lasts_until_it_is_back() {
        let t0 = Instant::now();
        let gate = testkit::gate(t0);
        let v = &gate.vehicle();
        let sup = SupervisorConfig::default();
        let steer_at = |now: Instant, pos: f64| steering_held(&gate, now, pos, 0.3);
        let mut mem = Memory::new(t0);
        let mut faults: Vec<Fault> = Vec::new();
        let mut named = Vec::new();
        for k in 0..21u64 {
            let pos = match k {
                0 => 0.3,
                1..=11 => 0.8,
                12..=14 => -0.2,
                15..=17 => 0.5,
                _ => 0.45,
            };
            let now = t0 + Duration::from_millis(50 * k);
            faults = detect(
                &steer_at(now, pos),
                v.config(),
                &sup,
                &mut mem,
                &faults,
                now,
            );
            named.extend(
                faults
                    .iter()
                    .filter(|f| {
                        f.kind == FaultKind::Override && f.device.as_deref() == Some("steer")
                    })
                    .map(|f| (k, f.cause.clone(), f.since - t0)),
            );
        }
        let turns: Vec<u64> = named.iter().map(|(k, _, _)| *k).collect();
        assert_eq!(turns, (8..=14).collect::<Vec<_>>(), "{named:#?}");
        let since = Duration::from_millis(400);
        assert!(named.iter().all(|(_, _, s)| *s == since), "{named:#?}");
        let (_, first, _) = &named[0];
        assert!(
            first.starts_with("measured 0.800, commanded 0.300: 0.474 from where its command can have taken it for ")
                && first.ends_with(" s (a driver's hand)"),
            "{first}"
        );
        let held = |pos: &str| {
            format!("measured {pos}, commanded 0.300: held away from its command (a driver's hand)")
        };
        assert_eq!(named[1].1, held("0.800"));
        assert_eq!(named[6].1, held("-0.200"));

        // Another device's override is not the steering's.
        let now = t0 + Duration::from_secs(2);
        let brake = Fault {
            kind: FaultKind::Override,
            device: Some("brake".into()),
            cause: String::new(),
            since: t0,
        };
        let faults = detect(
            &steer_at(now, 0.8),
            v.config(),
            &sup,
            &mut Memory::new(t0),
            &[brake],
            now,
        );
        assert!(
            faults
                .iter()
                .all(|f| !(f.kind == FaultKind::Override && f.device.as_deref() == Some("steer"))),
            "{faults:?}"
        );
    }

    /// Turns of the supervisor every `every` over the steering of `config` (Alice's,
    /// or one with another response), commanded `cmd(k)` and measured at `pos(k)` at
    /// turn `k`: the turns that name it not following, and the words of the first.
    fn following(
        config: VehicleConfig,
        every: Duration,
        turns: u32,
        cmd: impl Fn(u32) -> f64,
        pos: impl Fn(u32) -> f64,
    ) -> (Vec<u32>, Option<String>) {
        let t0 = Instant::now();
        let gate = testkit::gate_of(config, t0);
        let v = &gate.vehicle();
        let sup = SupervisorConfig::default();
        let mut mem = Memory::new(t0);
        let mut faults: Vec<Fault> = Vec::new();
        let (mut named, mut first) = (Vec::new(), None);
        for k in 0..turns {
            let now = t0 + every * k;
            let mut snap = gate.snapshot_at(0, now);
            let d = snap.devices.iter_mut().find(|d| d.name == "steer").unwrap();
            if let Some((_, x)) = d.readings.0.iter_mut().find(|(n, _)| n == POSITION) {
                *x = Some(Value::Number(pos(k)));
            }
            d.status_age_ms = Some(5.0);
            d.executed = Some(Value::Number(cmd(k)));
            d.commanded = Some(Value::Number(cmd(k)));
            d.executed_span = Some([cmd(k), cmd(k)]);
            d.executed_age_ms = Some(10.0);
            if let Some(e) = d.estimate.as_mut() {
                e.position = pos(k);
            }
            faults = detect(&snap, v.config(), &sup, &mut mem, &faults, now);
            for f in &faults {
                if f.kind == FaultKind::NotFollowing && f.device.as_deref() == Some("steer") {
                    named.push(k);
                    first.get_or_insert_with(|| f.cause.clone());
                }
            }
        }
        (named, first)
    }

    /// A stuck steering motor (full range a second, commanded 0.8 from 0, not moving)
    /// is named not following once it has made no headway for longer than
    /// `stall_time` (500 ms; turns every 50 ms), with what it made of what its
    /// response promised; a new command gives it that time again. One making 40 % of
    /// its promise (slow but healthy), or resting within its dead band of its command,
    /// is following.
    #[test]
    fn a_stuck_steering_is_not_following_after_stall_time_a_slow_one_is() {
        let turn = Duration::from_millis(50);
        let (named, first) = following(VehicleConfig::alice(), turn, 30, |_| 0.8, |_| 0.0);
        assert_eq!(named, (11..30).collect::<Vec<_>>());
        assert_eq!(
            first.as_deref(),
            Some("measured 0.000, commanded 0.800: 0.000 of the 0.550 its response promises in 0.6 s")
        );
        let cmd = |k: u32| if k < 6 { 0.8 } else { 0.6 };
        let (named, first) = following(VehicleConfig::alice(), turn, 30, cmd, |_| 0.0);
        assert_eq!(named, (17..30).collect::<Vec<_>>(), "from the new command");
        assert_eq!(
            first.as_deref(),
            Some("measured 0.000, commanded 0.600: 0.000 of the 0.550 its response promises in 0.6 s")
        );
        let slow = |k: u32| (0.02 * f64::from(k)).min(0.8);
        let (named, _) = following(VehicleConfig::alice(), turn, 30, |_| 0.8, slow);
        assert_eq!(named, Vec::<u32>::new(), "slow but healthy");
        let (named, _) = following(VehicleConfig::alice(), turn, 30, |_| 0.8, |_| 0.79);
        assert_eq!(named, Vec::<u32>::new(), "within its dead band");
    }

    /// A set point device without a declared response (here the steering, range [-1,
    /// 1]) is not following once measured further than `follow_tolerance` of its range
    /// (0.2) from its command, on either side, for longer than `follow_time` (2.5 s;
    /// turns every 100 ms); at that distance or nearer it is following.
    #[test]
    fn a_device_without_a_response_is_not_following_past_its_tolerance_for_follow_time() {
        let mut config = VehicleConfig::alice();
        let steer = config
            .devices
            .iter_mut()
            .find(|d| d.name == "steer")
            .unwrap();
        steer.response = None;
        let turn = Duration::from_millis(100);
        let away = |at: f64| following(config.clone(), turn, 30, |_| 0.3, move |_| at);
        let (named, first) = away(0.0);
        assert_eq!(named, (26..30).collect::<Vec<_>>());
        assert_eq!(
            first.as_deref(),
            Some("measured 0.000, commanded 0.300 for 2.6 s")
        );
        assert_eq!(away(0.6).0, (26..30).collect::<Vec<_>>());
        for near in [0.15, 0.2, 0.4, 0.5] {
            assert_eq!(
                away(near).0,
                Vec::<u32>::new(),
                "{near} is within 0.2 of 0.3"
            );
        }
    }

    /// What its command explains is never faster than its response: a hand that turns
    /// the steering (full range a second) from -0.8 to its command 0.8 at once is a
    /// driver's override, named once `override_time` has passed (turns every 50 ms).
    #[test]
    fn a_hand_faster_than_the_response_toward_the_command_is_still_an_override() {
        let t0 = Instant::now();
        let gate = testkit::gate(t0);
        let v = &gate.vehicle();
        let sup = SupervisorConfig::default();
        let mut mem = Memory::new(t0);
        let mut faults: Vec<Fault> = Vec::new();
        let mut named = Vec::new();
        for k in 0..12u32 {
            let now = t0 + Duration::from_millis(50 * u64::from(k));
            let pos = if k == 0 { -0.8 } else { 0.8 };
            let mut snap = gate.snapshot_at(0, now);
            let d = snap.devices.iter_mut().find(|d| d.name == "steer").unwrap();
            if let Some((_, x)) = d.readings.0.iter_mut().find(|(n, _)| n == POSITION) {
                *x = Some(Value::Number(pos));
            }
            d.status_age_ms = Some(5.0);
            d.executed = Some(Value::Number(0.8));
            d.commanded = Some(Value::Number(0.8));
            d.executed_span = Some([0.8, 0.8]);
            d.executed_age_ms = Some(10.0);
            if let Some(e) = d.estimate.as_mut() {
                e.position = pos;
            }
            faults = detect(&snap, v.config(), &sup, &mut mem, &faults, now);
            if faults
                .iter()
                .any(|f| f.kind == FaultKind::Override && f.device.as_deref() == Some("steer"))
            {
                named.push(k);
            }
        }
        assert_eq!(named, (8..12).collect::<Vec<_>>());
    }
}
