//! The fast path: a command for an idle actuator goes on the wire from the thread that
//! admitted it, without waking the device's command thread first.
//!
//! On the ordinary path intake stores a command in the slot and wakes the command
//! thread, which writes it: the wake (tens of microseconds on a loaded machine, more
//! across CPUs) sits between a command's receipt and its first byte. When the port is
//! idle — nobody holds it, no command thread is queued for it, no overdue status poll
//! waits, the command thread sleeps in its slot with nothing in flight — the admitting
//! thread can write the request itself: it [claims](crate::port::slot::CommandSlot::claim) the slot (the
//! command is in flight from then on, as if the command thread had taken it), asks the
//! safety rules' wire check (it must say send *this* command), takes
//! the port without waiting, writes the request, and
//! [hands the transaction over](crate::port::slot::CommandSlot::hand_over) with the port still held. The
//! command thread reads the reply and does the bookkeeping as for any command
//! ([`crate::port::Port::resume`]), then releases the port. It is woken by the reply
//! itself, not by the thread that wrote the request: it sleeps on its port, which that
//! thread arms after the write ([`crate::port::wake`]) — on a machine with few CPUs a
//! wake-up right after the write would compete with the device's end being woken by the
//! first byte. (A device without a descriptor to sleep on, a CAN device, has its command
//! thread woken by the handover.)
//!
//! Anything else and the path is the ordinary one: the paper's port rule (first come,
//! first served), a rate cap (`min_command_interval`), commands switched off, a driver
//! that does not split its transactions or must wait before writing (a Modbus line in
//! its inter-frame silence), a port not open yet or whose last transaction failed (a
//! device that stopped answering or reading could make the write wait, and the thread
//! that admits every command must not wait on one device). A claimed command that
//! cannot go out after all is queued for the command thread in the same step.

use super::Gate;
use crate::port::slot::{Handover, Pending};
use crate::safety::Verdict;
use crate::value::Command;
use crate::vehicle::Device;
use std::sync::atomic::Ordering::Relaxed;
use std::time::Instant;

/// Whether `d`'s configuration allows the fast path at all (the port's own rule is
/// the port's to apply: [`crate::port::Port::try_acquire_idle`]).
pub(crate) fn allowed(d: &Device) -> bool {
    d.is_actuator() && d.config().min_command_interval.is_none()
}

/// What [`send`] did with a command.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Sent {
    /// Its request is on the wire; the command thread reads the reply.
    Written,
    /// The port was not idle after all: the command is pending in the slot for the
    /// command thread, as if submitted (`superseded`: a command stored meanwhile, such
    /// as a safe state, stands instead).
    Queued { superseded: bool },
    /// Not taken: the slot is as before, for the caller to submit the command.
    NotTaken,
}

/// Write `command`, received at `received`, to `d`'s port now if the port is idle and
/// the wire check says send exactly it (asked with the command already in flight, so
/// that what it sees of the other devices cannot change under it).
pub(crate) fn send(gate: &Gate, d: &Device, command: Command, received: Instant) -> Sent {
    if !allowed(d) || !d.settings().command_enabled.load(Relaxed) {
        return Sent::NotTaken;
    }
    if !d.slot().claim(command) {
        return Sent::NotTaken;
    }
    let claim = Claim(d.slot());
    let may_send = gate.is_engaged()
        && matches!(
            gate.state().wire_verdict(gate.vehicle(), d, command, false),
            Verdict::Send(_)
        );
    let port = if may_send {
        d.port().try_acquire_idle()
    } else {
        None
    };
    let Some(mut port) = port else {
        std::mem::forget(claim);
        let superseded = d.slot().unclaim(Some(received));
        return Sent::Queued { superseded };
    };
    let (sent, first) = port.send_command(command);
    crate::probe::stamp(crate::probe::Step::FastWritten);
    if sent.is_ok() {
        crate::vehicle::stats::Stats::bump(&d.stats().fast);
    }
    // Armed after the write: the reply (or its deadline) wakes the command thread, and
    // nothing does before it.
    let armed = port.hand_over(sent.is_ok());
    std::mem::forget(claim);
    d.slot().hand_over(
        Handover {
            pending: Pending { command, received },
            first,
            sent,
        },
        armed,
    );
    Sent::Written
}

/// A claim on a slot, ended if the thread that holds it unwinds (a bug in a check or a
/// driver must not leave the command thread waiting for a transaction that never
/// comes: it would never send the safe state).
struct Claim<'a>(&'a crate::port::slot::CommandSlot);

impl Drop for Claim<'_> {
    fn drop(&mut self) {
        self.0.unclaim(None);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::port::slot::{CommandSlot, Wake};
    use std::sync::Arc;
    use std::time::Duration;

    /// The fast path is an actuator's, and not one under the paper's rate cap (its
    /// command thread keeps the interval between commands).
    #[test]
    fn the_fast_path_is_an_uncapped_actuators() {
        let text = crate::config::ALICE_TOML.replace(
            "name = \"brake\"            # 0 … 1\n",
            "name = \"brake\"            # 0 … 1\nmin_command_interval = \"20ms\"\n",
        );
        let config = crate::config::parse(&text, "capped.toml").expect("Alice, brake capped");
        let v = crate::testkit::vehicle_of(config, Instant::now());
        let allows = |name: &str| allowed(v.find(name).unwrap());
        assert!(allows("steer") && allows("gas") && allows("trans"));
        assert!(!allows("brake"), "rate-capped");
        assert!(!allows("estop") && !allows("obd"), "sensors");
    }

    /// A thread that unwinds while holding a claim (a bug in a check or a driver) ends
    /// it: the command thread is not left waiting for a transaction that never comes,
    /// and takes the next command — the safe state — as ever.
    #[test]
    fn a_claim_is_ended_when_its_thread_unwinds() {
        let slot = Arc::new(CommandSlot::default());
        let s2 = slot.clone();
        let waiter = std::thread::spawn(move || s2.wait(Duration::from_secs(30)));
        let end = Instant::now() + Duration::from_secs(20);
        while !slot.claim(Command::Set(0.1)) {
            assert!(Instant::now() < end, "the command thread never slept");
            std::thread::yield_now();
        }
        let unwound = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
            let _claim = Claim(&slot);
            panic!("a bug while claimed");
        }));
        assert!(unwound.is_err());
        assert_eq!(slot.wire().flight, None, "the claim ended");
        slot.submit(Command::Set(-1.0), Instant::now());
        assert!(
            matches!(waiter.join().unwrap(), Wake::Command(p) if p.command == Command::Set(-1.0))
        );
    }
}
