//! The fast path: a command for an idle actuator goes on the wire from the thread that
//! admitted it, without waking the device's command thread first.
//!
//! On the ordinary path intake stores a command in the slot and wakes the command
//! thread, which writes it: the wake (tens of microseconds on a loaded machine, more
//! across CPUs) sits between a command's receipt and its first byte. When the port is
//! idle — nobody holds it, no command thread is queued for it, no overdue status poll
//! waits, the command thread sleeps in its slot with nothing in flight — the admitting
//! thread can write the request itself: it [claims](super::slot::CommandSlot::claim) the slot (the
//! command is in flight from then on, as if the command thread had taken it), asks the
//! caller's check (the safety rules' wire check: it must say send *this* command), takes
//! the port without waiting, writes the request, and
//! [hands the transaction over](super::slot::CommandSlot::hand_over) with the port still held. The
//! command thread, woken after the first byte is out, reads the reply and does the
//! bookkeeping as for any command ([`crate::vehicle::port::Port::resume`]), then
//! releases the port.
//!
//! Anything else and the path is the ordinary one: the paper's port rule (first come,
//! first served), a rate cap (`min_command_interval`), commands switched off, a driver
//! that does not split its transactions or must wait before writing (a Modbus line in
//! its inter-frame silence), a port not open yet.

use super::slot::{Handover, Pending};
use super::Device;
use crate::value::Command;
use std::sync::atomic::Ordering::Relaxed;
use std::time::Instant;

/// Whether `d`'s configuration allows the fast path at all (the port's own rule is
/// the port's to apply: [`crate::vehicle::port::Port::try_acquire_idle`]).
pub fn allowed(d: &Device) -> bool {
    d.is_actuator() && d.config.min_command_interval.is_none()
}

/// Write `command`, received at `received`, to `d`'s port now if the port is idle and
/// `may_send` agrees (asked with the command already in flight). Returns false when it
/// did not: nothing was written and the slot is as before, for the caller to store the
/// command the ordinary way.
pub fn send(
    d: &Device,
    command: Command,
    received: Instant,
    may_send: impl FnOnce() -> bool,
) -> bool {
    if !allowed(d) || !d.settings.command_enabled.load(Relaxed) {
        return false;
    }
    if !d.slot.claim(command) {
        return false;
    }
    let port = if may_send() {
        d.port.try_acquire_idle()
    } else {
        None
    };
    let Some(mut port) = port else {
        d.slot.unclaim();
        return false;
    };
    let (sent, first) = port.send_command(command);
    super::stats::Stats::bump(&d.stats.fast);
    port.hand_over();
    d.slot.hand_over(Handover {
        pending: Pending { command, received },
        first,
        sent,
    });
    true
}
