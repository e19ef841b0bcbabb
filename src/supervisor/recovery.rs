//! Recovery procedures as explicit state machines. Each is a list of steps; a step
//! issues its command once when it begins and is done when the vehicle shows its
//! effect (the device acknowledged, the gear reads park, the engine runs). A step that
//! does not complete within `step_timeout` restarts the procedure from the top, up to
//! `attempts` times; then it gives up. Every step is visible in the console and the
//! broadcast and is logged.
//!
//! - **engine stall** (the paper's example): gas off, brake, wait until stopped, park,
//!   starter, back to the previous gear, release. While it runs, intake refuses gas and
//!   shifts; afterwards the brake stays applied until the planner commands otherwise,
//!   and the gas slot holds 0 — nothing jumps back to a stale set point.
//! - **steering** (the paper's `e` key): gas off and brake, then disable, enable (a
//!   servo drive's fault latch clears on that cycle), home, hold where it is. Gas and
//!   brake stay taken until it is done: the vehicle stands while its steering is reset.
//! - **reconnect**: a vanished device; the engine reopens its port with backoff, the
//!   procedure waits for it to answer again.
//!
//! A procedure that moves an actuator ([`Procedure::moves`]: anything beyond the safe
//! state of gas 0 and brake full) runs only while the vehicle is engaged; the
//! supervisor holds that rule.

use crate::config::SupervisorConfig;
use crate::interlock;
use crate::value::{Command, Control, Gear, Role};
use crate::vehicle::{Vehicle, SAFE_BRAKE, SAFE_GAS};
use std::time::{Duration, Instant};

use super::status::RecoveryView;

/// One step of a procedure.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Step {
    GasOff,
    Brake,
    WaitStopped,
    Park,
    Start,
    Regear(Gear),
    Release,
    Disable,
    Enable,
    Home,
    Hold,
    Reopen(Role),
}

impl Step {
    pub fn name(self) -> String {
        match self {
            Step::GasOff => "gas off".into(),
            Step::Brake => "brake".into(),
            Step::WaitStopped => "wait stopped".into(),
            Step::Park => "park".into(),
            Step::Start => "starter".into(),
            Step::Regear(g) => format!("back in {g}"),
            Step::Release => "release".into(),
            Step::Disable => "disable".into(),
            Step::Enable => "enable".into(),
            Step::Home => "home".into(),
            Step::Hold => "hold position".into(),
            Step::Reopen(r) => format!("reopen {r}"),
        }
    }

    /// The step commands an actuator to anything but the safe state (gas 0, brake
    /// full): a gear, the starter, the steering drive's controls or a set point.
    pub fn moves(self) -> bool {
        match self {
            Step::GasOff | Step::Brake | Step::WaitStopped | Step::Release | Step::Reopen(_) => {
                false
            }
            Step::Park
            | Step::Start
            | Step::Regear(_)
            | Step::Disable
            | Step::Enable
            | Step::Home
            | Step::Hold => true,
        }
    }

    /// Issue the step's command.
    fn begin(self, v: &Vehicle) {
        match self {
            Step::GasOff => v.override_command(Role::Gas, Command::Set(SAFE_GAS)),
            Step::Brake => v.override_command(Role::Brake, Command::Set(SAFE_BRAKE)),
            Step::Park => v.override_command(Role::Trans, Command::Gear(Gear::Park)),
            Step::Start => v.override_command(Role::Trans, Command::Control(Control::Start)),
            Step::Regear(g) => v.override_command(Role::Trans, Command::Gear(g)),
            Step::Disable => v.override_command(Role::Steer, Command::Control(Control::Disable)),
            Step::Enable => v.override_command(Role::Steer, Command::Control(Control::Enable)),
            Step::Home => v.override_command(Role::Steer, Command::Control(Control::Home)),
            Step::Hold => {
                if let Some(p) = v
                    .device(Role::Steer)
                    .and_then(|d| d.cached().reading.position)
                {
                    v.override_command(Role::Steer, Command::Set(p));
                }
            }
            Step::WaitStopped | Step::Release | Step::Reopen(_) => {}
        }
    }

    /// The vehicle shows the step's effect.
    fn done(self, v: &Vehicle, began: Instant) -> bool {
        let executed = |role: Role, want: Command| {
            v.device(role)
                .is_none_or(|d| d.slot.executed() == Some(want))
        };
        let fresh = |role: Role| {
            v.device(role)
                .and_then(|d| d.cached().at)
                .is_some_and(|t| t > began)
        };
        let facts = v.facts();
        match self {
            Step::GasOff => executed(Role::Gas, Command::Set(SAFE_GAS)),
            Step::Brake => executed(Role::Brake, Command::Set(SAFE_BRAKE)),
            Step::WaitStopped => facts.speed.is_none_or(|s| s.abs() < interlock::STOPPED),
            Step::Park => fresh(Role::Trans) && facts.gear == Some(Gear::Park),
            Step::Start => fresh(Role::Obd) && facts.running == Some(true),
            Step::Regear(g) => fresh(Role::Trans) && facts.gear == Some(g),
            Step::Release => true,
            Step::Disable => executed(Role::Steer, Command::Control(Control::Disable)),
            Step::Enable => executed(Role::Steer, Command::Control(Control::Enable)),
            Step::Home => {
                executed(Role::Steer, Command::Control(Control::Home))
                    && fresh(Role::Steer)
                    && v.device(Role::Steer)
                        .is_some_and(|d| d.cached().reading.fault == 0)
            }
            Step::Hold => v
                .device(Role::Steer)
                .and_then(|d| d.slot.executed())
                .is_some_and(|c| matches!(c, Command::Set(_))),
            Step::Reopen(r) => v
                .device(r)
                .is_some_and(|d| !d.is_faulty() && d.cached().at.is_some_and(|t| t > began)),
        }
    }
}

/// How a turn of a procedure went.
#[derive(Debug, PartialEq)]
pub enum Progress {
    Running,
    Done,
    GaveUp(String),
}

/// A procedure in progress.
#[derive(Debug)]
pub struct Procedure {
    name: String,
    steps: Vec<Step>,
    /// Devices whose intake is refused while it runs.
    takes: Vec<Role>,
    step: usize,
    attempt: u32,
    attempts: u32,
    step_timeout: Duration,
    /// When the current step began (`None`: not begun yet).
    began: Option<Instant>,
    started: Instant,
}

impl Procedure {
    fn new(name: &str, steps: Vec<Step>, takes: Vec<Role>, cfg: &SupervisorConfig) -> Procedure {
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

    /// Engine stall: stop driving forward, park, start, back in `gear`, release.
    pub fn engine_stall(gear: Gear, cfg: &SupervisorConfig) -> Procedure {
        Procedure::new(
            "engine_stall",
            vec![
                Step::GasOff,
                Step::Brake,
                Step::WaitStopped,
                Step::Park,
                Step::Start,
                Step::Regear(gear),
                Step::Release,
            ],
            vec![Role::Gas, Role::Trans],
            cfg,
        )
    }

    /// Steering drive fault: stand still, then disable, enable, home, hold where it is.
    pub fn steering(cfg: &SupervisorConfig) -> Procedure {
        Procedure::new(
            "steering",
            vec![
                Step::GasOff,
                Step::Brake,
                Step::Disable,
                Step::Enable,
                Step::Home,
                Step::Hold,
            ],
            vec![Role::Steer, Role::Gas, Role::Brake],
            cfg,
        )
    }

    /// A vanished device: wait for the engine to reopen it and for it to answer.
    pub fn reconnect(role: Role, cfg: &SupervisorConfig) -> Procedure {
        Procedure::new(
            &format!("reconnect {role}"),
            vec![Step::Reopen(role)],
            vec![],
            cfg,
        )
    }

    pub fn name(&self) -> &str {
        &self.name
    }

    pub fn steps(&self) -> &[Step] {
        &self.steps
    }

    /// Some step moves an actuator ([`Step::moves`]).
    pub fn moves(&self) -> bool {
        self.steps.iter().any(|s| s.moves())
    }

    /// The rule for every procedure: a disengaged vehicle is never moved by adrive on
    /// its own, so one that moves an actuator runs only while the vehicle is engaged
    /// (engaging is the permission to move it). One that moves nothing — reconnect —
    /// always may.
    pub fn may_run(&self, v: &Vehicle) -> bool {
        !self.moves() || v.is_engaged()
    }

    pub fn elapsed(&self, now: Instant) -> Duration {
        now - self.started
    }

    pub fn view(&self) -> RecoveryView {
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
    pub fn advance(&mut self, v: &Vehicle, now: Instant) -> Progress {
        v.set_recovering(&self.takes);
        loop {
            let Some(&step) = self.steps.get(self.step) else {
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
                    v.supervision.note(format!(
                        "{} {}/{}: {}",
                        self.name,
                        self.step + 1,
                        self.steps.len(),
                        step.name()
                    ));
                    step.begin(v);
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
                v.supervision
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

    #[test]
    fn only_the_safe_state_and_waiting_count_as_not_moving() {
        let cfg = SupervisorConfig::default();
        assert!(Procedure::engine_stall(Gear::Drive, &cfg).moves());
        assert!(Procedure::steering(&cfg).moves());
        assert!(!Procedure::reconnect(Role::Brake, &cfg).moves());
        for step in [Step::GasOff, Step::Brake, Step::WaitStopped, Step::Release] {
            assert!(!step.moves(), "{}", step.name());
        }
        for step in [
            Step::Park,
            Step::Start,
            Step::Disable,
            Step::Home,
            Step::Hold,
        ] {
            assert!(step.moves(), "{}", step.name());
        }
    }
}
