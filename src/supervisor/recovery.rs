//! Recovery procedures as explicit state machines. Each is a list of steps; a step
//! issues its command once when it begins and is done when the vehicle shows its
//! effect (the device acknowledged, the gear reads park, the engine runs). A step that
//! does not complete within `step_timeout` restarts the procedure from the top, up to
//! `attempts` times; then it gives up. Every step is visible in the console and the
//! broadcast and is logged. Procedures reach devices through the role bindings.
//!
//! - **engine stall** (the paper's example): throttle off, brake, wait until stopped,
//!   park, starter, back to the previous gear, release. While it runs, intake refuses
//!   the throttle, the brake and the gearbox; afterwards the brake stays applied until the planner
//!   commands otherwise, and the throttle slot holds 0 — nothing jumps back to a stale
//!   set point. It needs throttle, brake, gear, starter and engine_running bound.
//! - **steering** (the paper's `e` key): throttle off and brake, then disable, enable (a
//!   servo drive's fault latch clears on that cycle), home, hold where it is. Throttle
//!   and brake stay taken until it is done: the vehicle stands while its steering is
//!   reset.
//!
//! A device gone is no procedure: the engine reopens its port for as long as adrive
//! runs, and the supervisor says what it waits for ([`super::waiting`]).
//!
//! A procedure that gives up leaves the vehicle in the safe state, disengaged; the fault
//! stays named, and the procedure runs again from the top at the next engage. It ends
//! the run only when the operator asked for that (`give_up_after`).
//!
//! A procedure that moves an actuator ([`Procedure::moves`]: anything beyond the safe
//! state of gas 0 and brake full) runs only while the vehicle is engaged; the
//! supervisor holds that rule.

use crate::config::roles::ReadingRef;
use crate::config::SupervisorConfig;
use crate::engine::Gate;
use crate::safety::rules;
use crate::snapshot::RecoveryView;
use crate::value::{Command, Control, DeviceId};
use crate::vehicle::Vehicle;
use std::time::{Duration, Instant};

/// One step of a procedure.
#[derive(Clone, Debug, PartialEq)]
pub(crate) enum Step {
    /// Command a value and wait until the device acknowledged it.
    Send {
        device: DeviceId,
        command: Command,
        label: String,
    },
    /// Wait until the vehicle stopped ([`rules::stopped`]: an unknown speed is moving,
    /// so a silent speed sensor holds the step until it times out). Done at once on a
    /// vehicle with no speed bound, which has no shift rule either: nothing there can
    /// tell stopped from moving.
    WaitStopped(Option<ReadingRef>),
    /// Shift and wait until the gearbox reports the state in a fresh status.
    Shift {
        device: DeviceId,
        state: u8,
        label: String,
    },
    /// Run the starter until a fresh status says the engine runs.
    Start {
        starter: DeviceId,
        running: ReadingRef,
    },
    /// Home a drive: done when it acknowledged and a fresh status shows no fault bits.
    Home(DeviceId),
    /// Command a drive to hold where it is now.
    Hold(DeviceId),
    /// Hand the pedals back (nothing to do: the brake stays until commanded).
    Release,
}

impl Step {
    pub(crate) fn name(&self) -> String {
        match self {
            Step::Send { label, .. } | Step::Shift { label, .. } => label.clone(),
            Step::WaitStopped(_) => "wait stopped".into(),
            Step::Start { .. } => "starter".into(),
            Step::Home(_) => "home".into(),
            Step::Hold(_) => "hold position".into(),
            Step::Release => "release".into(),
        }
    }

    /// Issue the step's command.
    fn begin(&self, gate: &Gate) {
        let v = &gate.vehicle();
        match self {
            Step::Send {
                device, command, ..
            } => gate.supervise(*device, *command),
            Step::Shift { device, state, .. } => gate.supervise(*device, Command::State(*state)),
            Step::Start { starter, .. } => {
                gate.supervise(*starter, Command::Control(Control::Start))
            }
            Step::Home(d) => gate.supervise(*d, Command::Control(Control::Home)),
            Step::Hold(d) => {
                let dev = v.device(*d);
                if let Some(p) = dev.config().position().and_then(|i| dev.reading(i)) {
                    gate.supervise(*d, Command::Set(p));
                }
            }
            Step::WaitStopped(_) | Step::Release => {}
        }
    }

    /// The vehicle shows the step's effect.
    fn done(&self, v: &Vehicle, began: Instant) -> bool {
        let fresh = |d: DeviceId| v.device(d).cached().at.is_some_and(|t| t > began);
        match self {
            Step::Send {
                device, command, ..
            } => v.device(*device).slot().executed() == Some(*command),
            Step::WaitStopped(speed) => speed.is_none_or(|r| rules::stopped(v.reading(r))),
            Step::Shift { device, state, .. } => {
                let d = v.device(*device);
                fresh(*device)
                    && d.config().state().and_then(|i| d.reading(i)) == Some(*state as f64)
            }
            Step::Start { running, .. } => {
                fresh(running.device) && v.reading(*running).is_some_and(|x| x != 0.0)
            }
            Step::Home(d) => {
                let dev = v.device(*d);
                dev.slot().executed() == Some(Command::Control(Control::Home))
                    && fresh(*d)
                    && dev.cached().reading.fault == 0
            }
            Step::Hold(d) => matches!(v.device(*d).slot().executed(), Some(Command::Set(_))),
            Step::Release => true,
        }
    }

    /// The step moves an actuator (as opposed to waiting or commanding the safe state).
    pub(crate) fn moves(&self, gate: &Gate) -> bool {
        let safe = crate::safety::safe::state(gate.vehicle().config());
        match self {
            Step::Send {
                device, command, ..
            } => !safe.contains(&(*device, *command)),
            Step::Shift { .. } | Step::Start { .. } | Step::Home(_) | Step::Hold(_) => true,
            Step::WaitStopped(_) | Step::Release => false,
        }
    }
}

/// Throttle off and full brake, for the pedals that are bound: the first steps of the
/// safe state ([`crate::safety::safe::state`]).
fn stand_still(v: &Vehicle) -> Vec<Step> {
    let b = v.bindings();
    crate::safety::safe::state(v.config())
        .into_iter()
        .filter(|(d, _)| [b.throttle, b.brake].contains(&Some(*d)))
        .map(|(device, command)| {
            let name = v.device(device).name();
            Step::Send {
                device,
                command,
                label: if b.throttle == Some(device) {
                    format!("{name} off")
                } else {
                    name.to_string()
                },
            }
        })
        .collect()
}

/// How a turn of a procedure went.
#[derive(Debug, PartialEq)]
pub(crate) enum Progress {
    Running,
    Done,
    GaveUp(String),
}

/// A procedure in progress.
#[derive(Debug)]
pub(crate) struct Procedure {
    name: String,
    steps: Vec<Step>,
    /// Devices whose intake is refused while it runs.
    takes: Vec<DeviceId>,
    step: usize,
    attempt: u32,
    attempts: u32,
    step_timeout: Duration,
    /// When the current step began (`None`: not begun yet).
    began: Option<Instant>,
    started: Instant,
}

impl Procedure {
    fn new(
        name: &str,
        steps: Vec<Step>,
        takes: Vec<DeviceId>,
        cfg: &SupervisorConfig,
    ) -> Procedure {
        Procedure {
            name: name.to_string(),
            steps,
            takes,
            step: 0,
            attempt: 1,
            attempts: cfg.attempts.max(1),
            step_timeout: cfg.step_timeout,
            began: None,
            started: Instant::now(),
        }
    }

    /// Engine stall: stop driving, park, start, back in `gear` (a state of the gear
    /// device), release. `None` when the vehicle lacks a binding it needs.
    pub(crate) fn engine_stall(v: &Vehicle, gear: u8, cfg: &SupervisorConfig) -> Option<Procedure> {
        let b = v.bindings();
        let (throttle, brake, g, starter, running) = (
            b.throttle?,
            b.brake?,
            b.gear.as_ref()?,
            b.starter?,
            b.engine_running?,
        );
        let state = |s: u8| {
            v.device(g.device)
                .config()
                .state_name(s)
                .unwrap_or("?")
                .to_string()
        };
        let mut steps = stand_still(v);
        steps.push(Step::WaitStopped(b.speed));
        if let Some(park) = g.park {
            steps.push(Step::Shift {
                device: g.device,
                state: park,
                label: state(park),
            });
        }
        steps.push(Step::Start { starter, running });
        steps.push(Step::Shift {
            device: g.device,
            state: gear,
            label: format!("back in {}", state(gear)),
        });
        steps.push(Step::Release);
        // The brake too: the planner must not release it while the vehicle is held
        // for the restart (the release step hands it back, still applied).
        let mut takes = vec![throttle, brake, g.device];
        if !takes.contains(&starter) {
            takes.push(starter);
        }
        Some(Procedure::new("engine_stall", steps, takes, cfg))
    }

    /// Steering drive fault: stand still (throttle off and brake, where bound), then
    /// disable, enable, home — each its protocol carries (a kit's module has no home) —
    /// and hold where it is.
    pub(crate) fn steering(v: &Vehicle, cfg: &SupervisorConfig) -> Option<Procedure> {
        let b = v.bindings();
        let s = b.steering?;
        let takes = |c: Control| v.device(s).config().takes_control(c).is_ok();
        let mut steps = stand_still(v);
        for c in [Control::Disable, Control::Enable] {
            if takes(c) {
                steps.push(Step::Send {
                    device: s,
                    command: Command::Control(c),
                    label: c.as_str().into(),
                });
            }
        }
        if takes(Control::Home) {
            steps.push(Step::Home(s));
        }
        steps.push(Step::Hold(s));
        let takes = [Some(s), b.throttle, b.brake]
            .into_iter()
            .flatten()
            .collect();
        Some(Procedure::new("steering", steps, takes, cfg))
    }

    pub(crate) fn name(&self) -> &str {
        &self.name
    }

    #[cfg_attr(not(test), allow(dead_code))]
    pub(crate) fn steps(&self) -> &[Step] {
        &self.steps
    }

    /// The procedure moves an actuator at some step ([`Step::moves`]).
    pub(crate) fn moves(&self, gate: &Gate) -> bool {
        self.steps.iter().any(|s| s.moves(gate))
    }

    /// The rule for every procedure: a disengaged vehicle is never moved by adrive on
    /// its own, so one that moves an actuator runs only while the vehicle is engaged
    /// (engaging is the permission to move it). One that moves nothing always may.
    pub(crate) fn may_run(&self, gate: &Gate) -> bool {
        !self.moves(gate) || gate.is_engaged()
    }

    pub(crate) fn elapsed(&self, now: Instant) -> Duration {
        now - self.started
    }

    pub(crate) fn view(&self) -> RecoveryView {
        RecoveryView {
            name: self.name.clone(),
            steps: self.steps.iter().map(|s| s.name()).collect(),
            step: self.step,
            attempt: self.attempt,
            attempts: self.attempts,
            elapsed_ms: 0.0,
        }
    }

    /// Move the procedure on as far as the vehicle allows now.
    pub(crate) fn advance(&mut self, gate: &Gate, now: Instant) -> Progress {
        let v = &gate.vehicle();
        gate.set_recovering(&self.takes);
        loop {
            let Some(step) = self.steps.get(self.step) else {
                return Progress::Done;
            };
            let began = match self.began {
                Some(t) => t,
                None => {
                    tracing::info!(
                        "recovery {}: step {}/{} {} (try {}/{})",
                        self.name,
                        self.step + 1,
                        self.steps.len(),
                        step.name(),
                        self.attempt,
                        self.attempts
                    );
                    v.supervision().note(format!(
                        "{} {}/{}: {}",
                        self.name,
                        self.step + 1,
                        self.steps.len(),
                        step.name()
                    ));
                    step.begin(gate);
                    self.began = Some(now);
                    now
                }
            };
            if step.done(v, began) {
                self.step += 1;
                self.began = None;
                continue;
            }
            if now - began > self.step_timeout {
                let why = format!(
                    "step {} did not complete within {:?}",
                    step.name(),
                    self.step_timeout
                );
                if self.attempt >= self.attempts {
                    return Progress::GaveUp(format!(
                        "{why} (try {}/{})",
                        self.attempt, self.attempts
                    ));
                }
                tracing::warn!("recovery {}: {why}; trying again", self.name);
                v.supervision()
                    .note(format!("{}: {why}; try {}", self.name, self.attempt + 1));
                self.attempt += 1;
                self.step = 0;
                self.began = None;
                continue;
            }
            return Progress::Running;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::value::Reading;

    /// Alice's OBD adapter with its speed reported as `speed` (`None`: not reported),
    /// the engine stopped.
    fn speed(v: &Vehicle, speed: Option<f64>) {
        let obd = v.find("obd").expect("obd");
        let mut r = Reading::default();
        r.set(0, 0.0); // rpm
        if let Some(s) = speed {
            r.set(1, s);
        }
        r.set(2, 85.0); // coolant
        r.set(3, 0.0); // running
        obd.store(crate::vehicle::Cached {
            reading: r,
            at: Some(Instant::now()),
            asked: None,
        });
    }

    /// The incident this guards: the wait for stopped took an unknown speed for
    /// stopped, where the shift rule takes it for moving, and the stall procedure went
    /// on to shift into park. One meaning now: the step holds while the speed is
    /// unknown, and the procedure gives up (safe state, disengaged) rather than go on.
    #[test]
    fn an_unknown_speed_is_moving_and_the_stall_procedure_never_shifts_on_it() {
        let gate = crate::testkit::gate(Instant::now());
        let v = gate.vehicle();
        let wait = Step::WaitStopped(v.bindings().speed);
        for (s, done) in [(None, false), (Some(3.0), false), (Some(0.0), true)] {
            speed(v, s);
            assert_eq!(wait.done(v, Instant::now()), done, "speed {s:?}");
        }
        assert!(
            Step::WaitStopped(None).done(v, Instant::now()),
            "no speed bound: nothing to wait for"
        );

        speed(v, None);
        let cfg = SupervisorConfig {
            attempts: 2,
            step_timeout: Duration::from_millis(100),
            ..SupervisorConfig::default()
        };
        let drive = v.bindings().gear.as_ref().expect("gear").forward[0];
        let mut p = Procedure::engine_stall(v, drive, &cfg).expect("alice has it all");
        let trans = v.find("trans").expect("trans");
        let before = trans.slot().latest();
        let t0 = Instant::now();
        let mut outcome = Progress::Running;
        for ms in (0..=400).step_by(10) {
            outcome = p.advance(&gate, t0 + Duration::from_millis(ms));
            // The pedals acknowledge what the procedure commands them.
            for name in ["gas", "brake"] {
                let d = v.find(name).expect("pedal");
                if let Some(c) = d.slot().take_newer() {
                    d.slot().fly(c.command);
                    d.slot().finish(c.command, true);
                }
            }
            assert!(p.view().step <= 2, "went past wait stopped: {:?}", p.view());
            if outcome != Progress::Running {
                break;
            }
        }
        assert_eq!(trans.slot().latest(), before, "no shift was commanded");
        assert!(
            matches!(&outcome, Progress::GaveUp(why) if why.contains("wait stopped")),
            "{outcome:?}"
        );
    }

    #[test]
    fn only_the_safe_state_and_waiting_count_as_not_moving() {
        let cfg = SupervisorConfig::default();
        let gate = crate::testkit::gate(Instant::now());
        let v = &gate.vehicle();
        let b = v.bindings();
        let drive = b.gear.as_ref().expect("gear").forward[0];
        let stall = Procedure::engine_stall(v, drive, &cfg).expect("alice has it all");
        assert!(stall.moves(&gate));
        let steering = Procedure::steering(v, &cfg).expect("steering bound");
        assert!(steering.moves(&gate));
        let names = |p: &Procedure, moving: bool| -> Vec<String> {
            p.steps()
                .iter()
                .filter(|s| s.moves(&gate) == moving)
                .map(Step::name)
                .collect()
        };
        assert_eq!(
            names(&stall, false),
            ["gas off", "brake", "wait stopped", "release"]
        );
        assert_eq!(
            names(&steering, true),
            ["disable", "enable", "home", "hold position"]
        );
    }

    /// The steering procedure sends only the controls its drive's protocol carries:
    /// OSCC's steering module is disabled and enabled, and has no home.
    #[test]
    fn the_steering_procedure_sends_only_what_the_drive_takes() {
        let config = crate::config::parse(
            include_str!("../../vehicles/oscc.toml"),
            "vehicles/oscc.toml",
        )
        .expect("OSCC parses");
        let gate = crate::testkit::gate_of(config, Instant::now());
        let steering =
            Procedure::steering(gate.vehicle(), &SupervisorConfig::default()).expect("bound");
        let names: Vec<String> = steering.steps().iter().map(Step::name).collect();
        assert!(
            names.ends_with(&["disable".into(), "enable".into(), "hold position".into()]),
            "{names:?}"
        );
        assert!(!names.contains(&"home".into()), "{names:?}");
    }
}
