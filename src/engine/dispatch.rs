//! Dispatch: an admitted command on its way to the devices. A command that passed the
//! intake ([`super::admit`]) goes on the wire from the admitting thread when its port
//! is idle ([`super::fast`]), else into the device's slot for its command thread
//! ([`crate::port::slot`], [`super::command`]). The safe (or manual) state that
//! engaging, disengaging, an operator's STOP, a driver's override and every way out
//! command ([`super::engagement`]), and the supervisor's own commands, go into the
//! slots past the interlocks ([`Gate::store`]).

use super::fast::{self, Sent};
use super::Gate;
use crate::value::{Command, DeviceId};
use crate::vehicle::stats::Stats;
use crate::vehicle::tap::{Asked, Source};
use crate::vehicle::Device;
use std::time::Instant;

impl Gate {
    /// An admitted command on its way: written from this thread when its port is idle
    /// and the wire check says send exactly it ([`fast`]) — the command thread then
    /// only reads the reply — else stored for the command thread.
    pub(super) fn dispatch(&self, d: &Device, command: Command, received: Instant) {
        crate::probe::stamp(crate::probe::Step::Checked);
        Stats::bump(&d.stats().received);
        match fast::send(self, d, command, received) {
            Sent::Written | Sent::Queued { superseded: false } => {}
            Sent::Queued { superseded: true } => Stats::bump(&d.stats().superseded),
            Sent::NotTaken => queue(d, command, received),
        }
    }

    /// Store a command for `d`'s command thread, past the interlocks (the safe state,
    /// the supervisor's own commands).
    pub(super) fn store(&self, d: &Device, command: Command, received: Instant) {
        Stats::bump(&d.stats().received);
        queue(d, command, received);
    }

    /// The supervisor's own commands: past the gate and the intake interlocks (the
    /// wire-level checks still apply).
    pub fn supervise(&self, id: DeviceId, command: Command) {
        let now = Instant::now();
        self.store(self.vehicle().device(id), command, now);
        self.tap_received(
            Source::Supervisor,
            Asked::Device(id, command),
            now,
            Ok(()),
            None,
        );
    }
}

/// Into the slot, for the command thread.
fn queue(d: &Device, command: Command, received: Instant) {
    if d.slot().submit(command, received) {
        Stats::bump(&d.stats().superseded);
    }
}
