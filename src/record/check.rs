//! `adrive replay FILE.mcap --check VEHICLE.toml`: replay as a safety check (openpilot's
//! safety replay). Every command a recording received (`/commands`) carries what its
//! decision saw of the vehicle — the gate's state and the interlocks' facts
//! ([`crate::safety::Seen`]) — so the intake's pure decision
//! ([`crate::safety::gate_state::decide`], [`crate::safety::gate_state::decide_accel`]) can take it
//! again under another vehicle file's rules (the roles it binds) and limits (each
//! device's range and states). Each decision that would now differ — accepted then and
//! refused now, the other way round, or refused for another reason — is reported with
//! its time: a user changing a limit sees what their last drives would have met.
//!
//! Not decided again: a command refused because another source commanded (ownership is
//! no vehicle file's), the supervisor's own (past the gate), a datagram refused whole
//! (a recording keeps its reason only) and a command recorded without what its decision
//! saw (a recording made before adrive kept it). A fact the recorded decision did not
//! need (a role the recorded vehicle did not bind to that device) is unknown to the
//! check, which takes it as the rules do: unknown is unsafe.

use super::message::Received;
use super::read::Recording;
use crate::config::{DeviceConfig, VehicleConfig};
use crate::safety::gate_state::{decide, decide_accel};
use crate::safety::{Plays, Reject, Rules, Seen};
use crate::value::{Command, Control, DeviceId, Kind};

/// One decision that would now differ.
#[derive(Clone, Debug, PartialEq)]
pub(crate) struct Differs {
    /// Seconds from the recording's first message.
    pub at: f64,
    /// `network 127.0.0.1:40001`, `console`.
    pub source: String,
    /// The ask in words: `steer 0.500`, `accel 0.300`.
    pub ask: String,
    /// Refused then, and why (`None`: accepted).
    pub then: Option<String>,
    /// Refused now, and why (`None`: accepted).
    pub now: Option<Reject>,
}

/// What the check found.
#[derive(Clone, Debug, Default, PartialEq)]
pub(crate) struct Report {
    /// Commands decided again.
    pub decided: usize,
    /// Commands decided by no vehicle file's rule: another source commanded, or the
    /// supervisor's own.
    pub not_rules: usize,
    /// Commands recorded without what their decision saw.
    pub unseen: usize,
    /// The decisions that would now differ, in the recording's order.
    pub differ: Vec<Differs>,
    /// Where the readable part of the file ends early, and why.
    pub cut: Option<String>,
}

impl Report {
    /// The exit status: 1 when any decision differs, else 0.
    pub(crate) fn status(&self) -> i32 {
        i32::from(!self.differ.is_empty())
    }

    /// The report in words, for a terminal: a summary line, then each decision that
    /// would differ.
    pub(crate) fn render(&self, file: &str, vehicle: &str) -> String {
        let mut out = format!(
            "{file} under {vehicle}: {} commands decided again, {}\n",
            self.decided,
            match self.differ.len() {
                0 => "none would be decided otherwise".to_string(),
                1 => "1 would be decided otherwise".to_string(),
                n => format!("{n} would be decided otherwise"),
            }
        );
        if self.not_rules > 0 {
            out.push_str(&format!(
                "({} not decided by the vehicle file: another source commanded, or the supervisor's own)\n",
                self.not_rules
            ));
        }
        if self.unseen > 0 {
            out.push_str(&format!(
                "({} recorded without what their decision saw, by an older adrive: not decided again)\n",
                self.unseen
            ));
        }
        if let Some(why) = &self.cut {
            out.push_str(&format!(
                "(the file is read up to where it is cut: {why})\n"
            ));
        }
        for d in &self.differ {
            let then = match &d.then {
                None => "accepted then".to_string(),
                Some(why) => format!("refused then ({why})"),
            };
            let now = match d.now {
                None => "accepted now".to_string(),
                Some(r) => format!("refused now: {}: {r}", r.as_str()),
            };
            out.push_str(&format!(
                "{:>9.1} s  {}  {}: {then}, {now}\n",
                d.at, d.source, d.ask
            ));
        }
        out
    }
}

/// Decide every command of `rec` again under `config`.
pub(crate) fn check(rec: &Recording, config: &VehicleConfig) -> Report {
    let mut report = Report::default();
    let mut first = None;
    let rules = Rules::active(&config.roles);
    report.cut = rec.for_each(|m| {
        let start = *first.get_or_insert(m.log_time);
        if m.topic != "/commands" {
            return;
        }
        let Ok(r) = serde_json::from_slice::<Received>(m.data) else {
            return;
        };
        let (Some(device), Some(command)) = (&r.device, &r.command) else {
            return; // A datagram refused whole.
        };
        let Some(seen) = r.seen else {
            match r.reason.as_deref() {
                Some("other_commander") => report.not_rules += 1,
                _ if r.source == "supervisor" => report.not_rules += 1,
                _ => report.unseen += 1,
            }
            return;
        };
        report.decided += 1;
        let now = decide_again(config, rules, device, command, r.value, seen);
        let same = match (&now, r.accepted) {
            (Ok(()), true) => true,
            (Err(why), false) => r.reason.as_deref() == Some(why.as_str()),
            _ => false,
        };
        if !same {
            report.differ.push(Differs {
                at: m.log_time.saturating_sub(start) as f64 / 1e9,
                source: r.source.clone(),
                ask: format!("{device} {command}"),
                then: (!r.accepted).then(|| r.reason.clone().unwrap_or_default()),
                now: now.err(),
            });
        }
    });
    report
}

/// The decision on one recorded ask under `config`: `accel`, or a command for a device
/// found by name (in its words: a set point's exact value, a state's name, a control).
fn decide_again(
    config: &VehicleConfig,
    rules: Rules,
    device: &str,
    command: &str,
    value: Option<f64>,
    seen: Seen,
) -> Result<(), Reject> {
    let seen = in_this_vehicle(config, seen);
    if device == "accel" {
        let b = &config.roles;
        let (Some(t), Some(br), Some(a)) = (b.throttle, b.brake, value) else {
            return Err(Reject::NoSuchDevice);
        };
        let d = |id: DeviceId| &config.devices[id.index()];
        return decide_accel(d(t), d(br), rules, a, &seen)
            .map(drop)
            .map_err(|r| r.why);
    }
    let Some(i) = config.devices.iter().position(|d| d.name == device) else {
        return Err(Reject::NoSuchDevice);
    };
    let d = &config.devices[i];
    let id = DeviceId(i as u16);
    let plays = Plays::of(&config.roles.roles_of(id).collect::<Vec<_>>());
    let command = command_in(d, command, value)?;
    decide(d, plays, rules, command, &seen)
}

/// A recorded command as `d` of the vehicle file takes it.
fn command_in(d: &DeviceConfig, text: &str, value: Option<f64>) -> Result<Command, Reject> {
    if let Some(s) = d.state_index(text).filter(|_| d.kind == Kind::State) {
        return Ok(Command::State(s));
    }
    if let Ok(k) = text.parse::<Control>() {
        return Ok(Command::Control(k));
    }
    match (d.kind, value) {
        (Kind::Setpoint, Some(v)) => Ok(Command::Set(v)),
        // A state this file's device does not have.
        (Kind::State, _) => Err(Reject::OutOfRange),
        (Kind::Sensor, _) => Err(Reject::NotAnActuator),
        _ => Err(Reject::WrongKind),
    }
}

/// What was seen, as this vehicle file reads it: whether the gear reported drives the
/// wheels is this file's gear binding's to say.
fn in_this_vehicle(config: &VehicleConfig, mut seen: Seen) -> Seen {
    if let Some(f) = &mut seen.facts {
        if let (Some(g), Some(gear)) = (f.gear, &config.roles.gear) {
            f.in_gear = gear.drives(g);
        }
    }
    seen
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::vehicle::seen::Facts;

    fn engaged(facts: Option<Facts>) -> Seen {
        Seen {
            engaged: true,
            recovering: false,
            interlocks: true,
            facts,
        }
    }

    /// The same vehicle file decides as it did; a narrower range refuses what it took.
    #[test]
    fn a_command_is_decided_again_under_the_file_s_limits() {
        let alice = VehicleConfig::alice();
        let rules = Rules::active(&alice.roles);
        let seen = engaged(None);
        assert_eq!(
            decide_again(&alice, rules, "steer", "0.500", Some(0.5), seen),
            Ok(())
        );
        let mut narrow = alice.clone();
        narrow.devices[0].range = [-0.4, 0.4];
        assert_eq!(narrow.devices[0].name, "steer");
        assert_eq!(
            decide_again(&narrow, rules, "steer", "0.500", Some(0.5), seen),
            Err(Reject::OutOfRange)
        );
        assert_eq!(
            decide_again(&alice, rules, "wiper", "0.500", Some(0.5), seen),
            Err(Reject::NoSuchDevice)
        );
        assert_eq!(
            decide_again(
                &alice,
                rules,
                "trans",
                "drive",
                Some(3.0),
                engaged(Some(Facts {
                    speed: Some(0.0),
                    brake_low: Some(1.0),
                    brake_high: Some(1.0),
                    gear: Some(0),
                    ..Facts::default()
                }))
            ),
            Ok(())
        );
        assert_eq!(
            decide_again(&alice, rules, "trans", "overdrive", Some(4.0), seen),
            Err(Reject::OutOfRange)
        );
    }

    /// A gear that drives in one vehicle file need not in another: the file's binding
    /// says, not the recording.
    #[test]
    fn whether_the_gear_drives_is_the_file_s_to_say() {
        let alice = VehicleConfig::alice();
        let drive = alice.roles.gear.as_ref().unwrap().forward[0];
        let facts = Facts {
            gear: Some(drive),
            in_gear: false,
            ..Facts::default()
        };
        let seen = in_this_vehicle(&alice, engaged(Some(facts)));
        assert!(seen.facts.unwrap().in_gear);
    }
}
