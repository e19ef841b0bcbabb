//! The fast path over real pseudo-terminals: a command for an idle actuator is written
//! by the thread that admitted it, and its reply read by the device's command thread —
//! exactly once, with the port held in between — while a rate cap or the paper's port
//! rule keep the ordinary path, and a failed fast transaction is counted like any.

mod common;

use adrive::port::trace::Dir;
use adrive::value::Command;
use adrive::vehicle::Device;
use common::{steer_only, wait_for, Rig};
use std::sync::atomic::Ordering::Relaxed;
use std::time::Instant;

fn set(v: f64) -> Command {
    Command::Set(v)
}

/// Engaged, with the engage hold executed and the command thread asleep in its slot.
fn engaged(rig: &Rig) -> &Device {
    rig.engage();
    let steer = rig.device("steer");
    wait_for("the engage hold to execute", || {
        steer.stats().executed.load(Relaxed) == 1
    });
    rig.received();
    steer
}

/// Submit `command` when the command thread sleeps in its slot; true if it went out
/// by the fast path.
fn submit_when_idle(rig: &Rig, steer: &Device, command: Command) -> bool {
    wait_for("the command thread to sleep", || steer.slot().is_idle());
    let fast = steer.stats().fast.load(Relaxed);
    rig.gate
        .submit(steer.id(), command, Instant::now())
        .unwrap();
    steer.stats().fast.load(Relaxed) > fast
}

/// The bytes the host wrote last, per the device's trace.
fn last_written(steer: &Device) -> Vec<u8> {
    steer
        .trace()
        .entries()
        .iter()
        .rev()
        .find(|e| e.dir == Dir::Out)
        .map(|e| e.bytes().to_vec())
        .unwrap_or_default()
}

#[test]
fn a_command_on_an_idle_port_is_on_the_wire_when_intake_returns_and_counted_once() {
    let rig = Rig::start(&steer_only(
        "status_period = \"10s\"\nstatus_max_age = \"10s\"\ncommand_timeout = \"10s\"",
        "command_delay = \"20ms\"",
    ));
    let steer = engaged(&rig);
    assert!(submit_when_idle(&rig, steer, set(0.3)), "the fast path");
    // Written by intake itself: the request is in the trace before the command thread
    // could have woken.
    assert_eq!(last_written(steer), b"! 0.300\n");
    wait_for("the reply to be read", || {
        steer.slot().executed() == Some(set(0.3))
    });
    // A second command as a barrier: whatever the first transaction counted is in.
    assert!(submit_when_idle(&rig, steer, set(-0.2)));
    wait_for("the second to execute", || {
        steer.slot().executed() == Some(set(-0.2))
    });
    let got: Vec<Command> = rig.received().iter().map(|e| e.command).collect();
    assert_eq!(got, vec![set(0.3), set(-0.2)], "each went out once");
    steer.stats().refresh();
    let s = steer.stats().counters();
    assert_eq!((s.received, s.executed, s.command_errors), (3, 3, 0));
    assert_eq!(steer.stats().fast.load(Relaxed), 2);
    assert_eq!(
        steer.stats().command_delay.summary().count,
        3,
        "every fresh command's delay, once"
    );
    assert_eq!(steer.stats().command_txn.summary().count, 3);
    assert_eq!(steer.slot().wire().flight, None, "nothing left in flight");
}

/// The port stays held from the request to its reply: a status thread that wants the
/// port all the while (polling every 20 ms, overdue after 150 ms, against a device that
/// takes 100 ms to answer a command) polls only after the reply is in.
#[test]
fn a_status_poll_never_comes_between_a_fast_request_and_its_reply() {
    let rig = Rig::start(&steer_only(
        "status_period = \"20ms\"\nstatus_max_age = \"150ms\"\nreply_timeout = \"150ms\"\ncommand_timeout = \"10s\"",
        "command_delay = \"100ms\"",
    ));
    let steer = engaged(&rig);
    // A poll may hold the port at the moment of a submit: then the path is the
    // ordinary one; try again until one goes the fast way. Each try waits for a poll
    // to end after the last command: the poll that waited for the port through the
    // command's 100 ms would otherwise take it again just as the slot goes idle, and a
    // loaded machine would lose that race every time.
    let mut v = 0.0;
    loop {
        v += 0.001;
        assert!(v < 0.5, "no command found the port idle");
        let polls = steer.stats().polls.load(Relaxed);
        wait_for("a poll after the last command", || {
            steer.stats().polls.load(Relaxed) > polls
        });
        let fast = submit_when_idle(&rig, steer, set(v));
        wait_for("the command to execute", || {
            steer.slot().executed() == Some(set(v))
        });
        if fast {
            break;
        }
    }
    let polls = steer.stats().polls.load(Relaxed);
    wait_for("polls to go on after the reply", || {
        steer.stats().polls.load(Relaxed) > polls + 2
    });
    let entries = steer.trace().entries();
    let request = format!("! {v:.3}\n");
    let at = entries
        .iter()
        .rposition(|e| e.dir == Dir::Out && e.bytes() == request.as_bytes())
        .expect("the request in the trace");
    let reply: Vec<_> = entries[at + 1..]
        .iter()
        .take_while(|e| !(e.dir == Dir::In && e.bytes().ends_with(b"\n")))
        .collect();
    assert!(
        reply.iter().all(|e| e.dir == Dir::In),
        "something was written between the request and its reply: {:?}",
        reply.iter().map(|e| e.ascii()).collect::<Vec<_>>()
    );
    assert!(
        entries[at + 1 + reply.len()].bytes().ends_with(b"ok\n"),
        "the reply follows the request"
    );
    assert_eq!(steer.stats().command_errors.load(Relaxed), 0);
}

/// With the paper's rate cap, or the paper's port rule (first come, first served),
/// commands go the ordinary way: through the slot and the command thread.
#[test]
fn a_rate_cap_or_the_paper_rule_keeps_the_ordinary_path() {
    for extra in ["min_command_interval = \"20ms\"", "port_rule = \"paper\""] {
        let rig = Rig::start(&steer_only(
            &format!("status_period = \"10s\"\nstatus_max_age = \"10s\"\ncommand_timeout = \"10s\"\n{extra}"),
            "",
        ));
        let steer = engaged(&rig);
        for v in [0.1, 0.2, 0.3] {
            assert!(
                !submit_when_idle(&rig, steer, set(v)),
                "{extra}: fast path taken"
            );
            wait_for("the command to execute", || {
                steer.slot().executed() == Some(set(v))
            });
        }
        assert_eq!(steer.stats().fast.load(Relaxed), 0, "{extra}");
        assert_eq!(steer.stats().executed.load(Relaxed), 4, "{extra}");
    }
}

/// A fast-path command the device never answers ends at its reply timeout, is counted
/// as a command error with the timeout's code, and the next command goes out the
/// ordinary way — a port that stopped answering is never written by the thread that
/// admits commands, which must not wait on it — and is acknowledged as usual; after that
/// clean transaction the fast path is back.
#[test]
fn a_timed_out_fast_path_transaction_is_counted_and_the_next_goes_out() {
    let rig = Rig::start(&steer_only(
        "status_period = \"10s\"\nstatus_max_age = \"10s\"\ncommand_timeout = \"10s\"\nreply_timeout = \"50ms\"",
        "",
    ));
    let steer = engaged(&rig);
    let faults = rig.sim.faults("steer").unwrap();
    faults.silent.store(true, Relaxed);
    assert!(submit_when_idle(&rig, steer, set(0.4)));
    wait_for("the timeout to be counted", || {
        steer.stats().command_errors.load(Relaxed) == 1
    });
    assert_eq!(
        steer.health().command_error.load(Relaxed),
        1,
        "timeout code"
    );
    assert_ne!(
        steer.slot().executed(),
        Some(set(0.4)),
        "never acknowledged"
    );
    faults.silent.store(false, Relaxed);
    assert!(
        !submit_when_idle(&rig, steer, set(-0.4)),
        "after a failed transaction, the command thread's"
    );
    wait_for("the next to execute", || {
        steer.slot().executed() == Some(set(-0.4))
    });
    assert_eq!(steer.stats().command_errors.load(Relaxed), 1);
    assert_eq!(steer.health().command_error.load(Relaxed), 0);
    assert_eq!(steer.stats().executed.load(Relaxed), 2);
    assert!(
        submit_when_idle(&rig, steer, set(0.2)),
        "the fast path again"
    );
    wait_for("it to execute", || {
        steer.slot().executed() == Some(set(0.2))
    });
    assert_eq!(steer.stats().executed.load(Relaxed), 3);
}
