//! Engagement: every way in and out of it, in one place. Engaging (refused while
//! anything blocks it), disengaging, an operator's STOP, a driver's override (and
//! clearing it), and the e-stop's pause: each records why in the gate's state
//! ([`crate::safety::GateState`]) and stores the safe (or manual) state in every
//! actuator's slot, past the interlocks, the kits' switch following the gate. The
//! decisions are safety's; this is where the engine carries them out.

use super::Gate;
use crate::config::Role;
use crate::snapshot::{Blocker, DisengageCause};
use crate::value::{Command, DeviceId};
use crate::vehicle::tap::GateChange;
use std::time::Instant;

impl Gate {
    /// A driver took `device` over (`why`: the supervisor's `override`): latch it and
    /// hand the vehicle to the driver — disengaged, in the manual state (throttle and
    /// brake released, the steering no longer commanded). Already latched: nothing.
    pub fn take_over(&self, device: &str, why: &str) {
        // Latched and disengaged in one step; said to be cleared once it is
        // ([`crate::safety::GateState::cause`]).
        let Some(was) = self.state().take_over(device) else {
            return;
        };
        tracing::warn!(device, "driver override: {why}");
        // Nothing admitted from now on: what was pending for the driver's device goes.
        self.leave_to_the_driver();
        let state = self.state().stop_state(self.vehicle());
        self.disengage_with(|_| was, state);
    }

    /// Nothing is resent to a device the manual state does not command (the steering
    /// in the driver's hands): its pending command is dropped and its resend forgotten.
    fn leave_to_the_driver(&self) {
        let v = self.vehicle();
        let manual = crate::safety::safe::manual(v.config());
        for d in v.devices().iter().filter(|d| d.is_actuator()) {
            if !manual.iter().any(|(id, _)| *id == d.id()) {
                d.slot().reset(None);
            }
        }
    }

    /// Clear the latched overrides, unless a driver's hand is still on one of them
    /// (the supervisor still names its `override`). Returns what was cleared, or why
    /// not.
    pub fn clear_overrides(&self) -> Result<Vec<String>, String> {
        let still: Vec<String> = self
            .vehicle()
            .supervision()
            .faults()
            .into_iter()
            .filter(|f| f.kind == crate::snapshot::FaultKind::Override)
            .filter_map(|f| f.device)
            .collect();
        let cleared = self.state().clear_overrides(&still)?;
        if !cleared.is_empty() {
            tracing::info!("override cleared: {}", cleared.join(", "));
        }
        Ok(cleared)
    }

    /// Engage: accept commands from now on. Refused while anything blocks it. Every
    /// command slot is reset first so nothing resends a stale set point: the safe
    /// state (throttle 0, brake full), steering held where it is, the rest left as
    /// they are.
    pub fn engage(&self, by: &str) -> Result<(), Vec<Blocker>> {
        let blockers = self.blockers();
        if !blockers.is_empty() {
            let said = Blocker::said(&blockers);
            tracing::warn!(by, "engage refused: {said}");
            self.tap_gate(GateChange::EngageRefused, || format!("{by}: {said}"));
            return Err(blockers);
        }
        let v = self.vehicle();
        for d in v.devices().iter().filter(|d| d.is_actuator()) {
            d.slot().reset(None);
        }
        // Kits enable after the safe command, never before it.
        self.state().engaging();
        self.command_safe_state();
        self.kits_follow(true, &self.state().stop_state(v));
        if let Some(s) = v.bound(Role::Steering) {
            if let Some(p) = s.config().position().and_then(|i| s.reading(i)) {
                self.store(s, Command::Set(p), Instant::now());
            }
        }
        self.state().set_engaged(by);
        tracing::info!(by, "engaged");
        self.tap_gate(GateChange::Engaged, || {
            let by = by.to_string();
            crate::snapshot::GateCause::Engaged { by }.to_string()
        });
        Ok(())
    }

    /// Disengage and command the safe state. Returns false if it was not engaged.
    pub fn disengage(&self, why: DisengageCause) -> bool {
        self.disengage_into(why, self.state().stop_state(self.vehicle()))
    }

    /// An operator's STOP: disengage into the full safe state — throttle 0, brake full
    /// — even while a driver has taken over. Only the stops adrive makes on its own
    /// (a fault, the watchdog, an exit) leave a driver's vehicle in the manual state;
    /// a person pressing STOP has decided to brake.
    pub fn stop(&self, why: DisengageCause) -> bool {
        self.disengage_into(why, crate::safety::safe::state(self.vehicle().config()))
    }

    /// Disengage for `why`, decided while engaged (a blocker seen, a fault, a stalled
    /// thread, the watchdog), and command the safe state — only if it is still
    /// engaged: whoever disengaged it since that look (a driver's override, an
    /// operator's STOP) keeps their cause and the state they commanded. Returns
    /// whether this disengaged it.
    pub fn disengage_engaged(&self, why: DisengageCause) -> bool {
        if !self.state().set_disengaged_if_engaged(why) {
            return false;
        }
        self.disengage_with(|_| true, self.state().stop_state(self.vehicle()))
    }

    fn disengage_into(&self, why: DisengageCause, state: Vec<(DeviceId, Command)>) -> bool {
        self.disengage_with(|g| g.set_disengaged(why), state)
    }

    /// Disengage (`set` records why, in the gate's state) into `state`.
    fn disengage_with(
        &self,
        set: impl FnOnce(&crate::safety::GateState) -> bool,
        state: Vec<(DeviceId, Command)>,
    ) -> bool {
        // Kits disable with it ([`GateState::engaging`]), after the safe command.
        let was = set(self.state());
        let now = Instant::now();
        for &(id, c) in &state {
            self.store(self.vehicle().device(id), c, now);
        }
        self.kits_follow(false, &state);
        if was {
            let reason = self.reason();
            tracing::warn!("{reason}");
            self.tap_gate(GateChange::Disengaged, || reason);
        }
        was
    }

    /// The kit devices on a CAN bus that `state` does not command get their enable
    /// (`engaged`) or disable message on their own; the others send it after their
    /// command ([`crate::driver::slcan::CanDriver`]).
    fn kits_follow(&self, engaged: bool, state: &[(DeviceId, Command)]) {
        let v = self.vehicle();
        if v.buses().is_empty() {
            return;
        }
        let now = Instant::now();
        let control = Command::Control(if engaged {
            crate::value::Control::Enable
        } else {
            crate::value::Control::Disable
        });
        for d in v.devices().iter().filter(|d| d.config().kit().is_some()) {
            if !state.iter().any(|(id, _)| *id == d.id()) {
                self.store(d, control, now);
            }
        }
    }

    /// Command the safe state to every actuator there is, bypassing the interlocks
    /// (the safe state is always allowed) — the manual state while a driver has taken
    /// over.
    pub(crate) fn command_safe_state(&self) {
        let now = Instant::now();
        if !self.overridden().is_empty() {
            // A command that raced the override (checked before it, stored after its
            // reset) must not be left to resend to the driver's device.
            self.leave_to_the_driver();
        }
        for (id, c) in self.state().stop_state(self.vehicle()) {
            self.store(self.vehicle().device(id), c, now);
        }
    }

    /// The e-stop went to `state`, pause or disable, while disengaged: its rule is commanded
    /// (the safe state: [`GateState::stop_state`](crate::safety::GateState)), and the
    /// e-stop is why the vehicle is disengaged now.
    pub(crate) fn follow_estop(&self, state: crate::value::EstopState) {
        tracing::warn!("e-stop in {state}: brake and gas by the e-stop's rule");
        self.disengage(DisengageCause::Blocked {
            blocker: Blocker::Estop { state },
        });
    }

    /// Wait until every reachable device acknowledged its part of the safe state.
    /// Returns false if one the rules act on ([`crate::safety::gate_state::needed`]) did not
    /// by the deadline.
    pub fn wait_safe(&self, deadline: Instant) -> bool {
        let mut ok = true;
        for (id, want) in self.state().stop_state(self.vehicle()) {
            let d = self.vehicle().device(id);
            if d.slot().wait_executed(|c| c == want, deadline) {
                continue;
            }
            // A device the rules do not act on (a horn) says nothing of whether the
            // vehicle may still move.
            if crate::safety::gate_state::needed(self.vehicle(), d) {
                tracing::error!(device = %d.name(), "did not acknowledge the safe state");
                ok = false;
            } else {
                tracing::warn!(device = %d.name(), "did not acknowledge its safe state (it holds up nothing)");
            }
        }
        ok
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::testkit as sample;

    /// A kit is enabled only while the vehicle is engaged: the one switch the buses'
    /// kits follow is the gate's, on through an engage and off with every way out of
    /// it (disengage, STOP, a driver's override).
    #[test]
    fn the_kits_switch_follows_the_gate() {
        let gate = sample::gate(Instant::now());
        let kits = gate.vehicle().kits().clone();
        assert!(!kits.enabled(), "off before any engage");
        let ways_out: [&dyn Fn(&Gate); 3] = [
            &|g| {
                g.disengage(DisengageCause::Disengage { by: "test".into() });
            },
            &|g| {
                g.stop(DisengageCause::Stop { by: "test".into() });
            },
            &|g| g.take_over("steer", "test"),
        ];
        for out in ways_out {
            gate.engage("test").unwrap();
            assert!(kits.enabled(), "on while engaged");
            out(&gate);
            assert!(!gate.is_engaged());
            assert!(!kits.enabled(), "off once disengaged");
            let _ = gate.clear_overrides();
        }
    }

    /// A latched override is cleared only once the supervisor no longer names a
    /// driver's hand on it — another fault of that device does not hold it — and the
    /// clearing is logged.
    #[test]
    fn an_override_clears_once_no_hand_is_named_on_it() {
        use crate::snapshot::FaultKind;
        use crate::vehicle::supervision::Fault;
        let gate = sample::gate(Instant::now());
        let v = gate.vehicle();
        let fault = |kind| Fault {
            kind,
            device: Some("brake".into()),
            cause: "test".into(),
            since: Instant::now(),
        };
        gate.engage("test").unwrap();
        gate.take_over("brake", "a foot on the pedal");
        v.supervision().set_faults(vec![fault(FaultKind::Override)]);
        assert!(gate.clear_overrides().is_err(), "a foot still on it");
        assert_eq!(gate.overridden(), ["brake"]);
        v.supervision()
            .set_faults(vec![fault(FaultKind::NotFollowing)]);
        let mut cleared = None;
        let lines = sample::logged(|| cleared = Some(gate.clear_overrides()));
        assert_eq!(cleared, Some(Ok(vec!["brake".to_string()])));
        assert!(gate.overridden().is_empty());
        assert!(
            lines
                .iter()
                .any(|l| l.starts_with("override cleared: brake")),
            "{lines:#?}"
        );
        let lines = sample::logged(|| assert_eq!(gate.clear_overrides(), Ok(vec![])));
        assert!(
            lines.is_empty(),
            "nothing to clear, nothing said: {lines:#?}"
        );
    }

    /// A kit the safe state leaves alone (here OSCC's steering without a safe value)
    /// is enabled with the engage and disabled with the disengage on its own; one the
    /// safe state commands gets its command, and its driver sends the enable or the
    /// disable after it.
    #[test]
    fn a_kit_the_safe_state_leaves_alone_follows_the_gate_on_its_own() {
        use crate::value::Control;
        let shipped = include_str!("../../vehicles/oscc.toml");
        let text = shipped.replace(
            "safe = 0.0                 # no torque in the safe state\n",
            "",
        );
        assert_ne!(text, shipped, "OSCC's steering without its safe value");
        let config = crate::config::parse(&text, "vehicles/oscc.toml").expect("OSCC parses");
        let gate = sample::gate_of(config, Instant::now());
        let v = gate.vehicle();
        let (steer, gas) = (v.find("steer").unwrap(), v.find("gas").unwrap());
        gate.engage("test").unwrap();
        assert_eq!(
            steer.slot().latest(),
            Some(Command::Control(Control::Enable))
        );
        assert_eq!(
            gas.slot().latest(),
            Some(Command::Set(0.0)),
            "its safe command"
        );
        gate.disengage(DisengageCause::Disengage { by: "test".into() });
        assert_eq!(
            steer.slot().latest(),
            Some(Command::Control(Control::Disable))
        );
        assert_eq!(gas.slot().latest(), Some(Command::Set(0.0)));
    }

    /// The e-stop in pause while disengaged: its rule commanded, and the e-stop said
    /// to be why the vehicle is disengaged.
    #[test]
    fn the_e_stop_paused_is_why_the_vehicle_is_disengaged() {
        let gate = sample::gate(Instant::now());
        let brake = gate.vehicle().find("brake").unwrap();
        gate.follow_estop(crate::value::EstopState::Pause);
        assert_eq!(gate.reason(), "disengaged: e-stop is in pause");
        assert_eq!(brake.slot().latest(), Some(Command::Set(1.0)), "brake full");
    }

    /// The safe state is acknowledged only when every device the rules act on has
    /// executed its part of it; until then the wait says so at its deadline.
    #[test]
    fn the_safe_state_is_waited_for_until_each_device_executed_it() {
        let gate = sample::gate(Instant::now());
        let v = gate.vehicle();
        gate.command_safe_state();
        let soon = || Instant::now() + std::time::Duration::from_millis(20);
        assert!(!gate.wait_safe(soon()), "nothing executed yet");
        for (id, c) in gate.state().stop_state(v) {
            v.device(id).slot().fly(c);
            v.device(id).slot().finish(c, true);
        }
        assert!(gate.wait_safe(soon()));
    }

    /// A command that raced a driver's override (checked before it, stored after the
    /// override's reset) is dropped by the next safe state, not left to resend to the
    /// driver's wheel.
    #[test]
    fn a_command_that_raced_the_override_is_dropped_by_the_safe_state() {
        let gate = sample::gate(Instant::now());
        let steer = gate.vehicle().find("steer").unwrap();
        gate.engage("test").unwrap();
        gate.take_over("brake", "a foot on the pedal");
        steer.slot().submit(Command::Set(0.4), Instant::now());
        gate.command_safe_state();
        assert_eq!(steer.slot().wire().pending, None);
    }

    /// A disengage decided while engaged (the monitor's blocker, a fault, the watchdog)
    /// commands the safe state when it is the one that disengages, and nothing once
    /// someone else disengaged since its look: an operator's STOP keeps what it
    /// commanded, nothing is sent after it.
    #[test]
    fn a_disengage_decided_while_engaged_commands_only_a_vehicle_still_engaged() {
        let gate = sample::gate(Instant::now());
        let v = gate.vehicle();
        let brake = v.find("brake").unwrap();
        // Every command pending executed, as the command threads would.
        let executed = || {
            for d in v.devices() {
                if let Some(p) = d.slot().take_newer() {
                    d.slot().finish(p.command, true);
                }
            }
        };
        let decided = || DisengageCause::Disengage {
            by: "a look while engaged".into(),
        };
        gate.engage("test").unwrap();
        executed();
        assert!(gate.disengage_engaged(decided()));
        assert!(!gate.is_engaged());
        assert_eq!(
            brake.slot().wire().pending,
            Some(Command::Set(1.0)),
            "brake full"
        );
        executed();
        gate.engage("test").unwrap();
        gate.stop(DisengageCause::Stop {
            by: "operator".into(),
        });
        executed();
        assert!(!gate.disengage_engaged(decided()));
        for d in v.devices() {
            assert_eq!(
                d.slot().wire().pending,
                None,
                "{} commanded after the STOP",
                d.name()
            );
        }
    }

    /// A driver's override hands the vehicle over in the manual state: throttle and
    /// brake released, and nothing more sent to the steering — its pending command is
    /// dropped, not delivered after the driver has taken the wheel.
    #[test]
    fn a_driver_takes_over_and_the_steering_is_no_longer_commanded() {
        let gate = sample::gate(Instant::now());
        let v = gate.vehicle();
        let (steer, gas, brake) = (
            v.find("steer").unwrap(),
            v.find("gas").unwrap(),
            v.find("brake").unwrap(),
        );
        gate.engage("test").unwrap();
        gate.submit(steer.id(), Command::Set(0.5), Instant::now())
            .unwrap();
        assert_eq!(steer.slot().wire().pending, Some(Command::Set(0.5)));
        gate.take_over("brake", "a foot on the pedal");
        assert!(!gate.is_engaged());
        assert_eq!(steer.slot().wire().pending, None, "the steering's dropped");
        assert_eq!(
            gas.slot().latest(),
            Some(Command::Set(0.0)),
            "throttle released"
        );
        assert_eq!(
            brake.slot().latest(),
            Some(Command::Set(0.0)),
            "brake released"
        );
    }
}
