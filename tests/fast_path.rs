//! The fast path over real pseudo-terminals: a command for an idle actuator is written
//! by the thread that admitted it, and its reply read by the device's command thread —
//! exactly once, with the port held in between — while a rate cap or the paper's port
//! rule keep the ordinary path, and a failed fast transaction is counted like any.
//! The command thread sleeps on its port: the reply wakes it, and nothing before it.

mod common;

use adrive::port::trace::Dir;
use adrive::value::Command;
use adrive::vehicle::Device;
use common::{steer_only, wait_for, Rig};
use std::sync::atomic::Ordering::Relaxed;
use std::time::{Duration, Instant};

fn set(v: f64) -> Command {
    Command::Set(v)
}

/// Engaged, with the engage hold executed and the command thread asleep in its slot.
fn engaged(rig: &Rig) -> &Device {
    engaged_named(rig, "steer")
}

/// [`engaged`], the steering device named `name`.
fn engaged_named<'r>(rig: &'r Rig, name: &str) -> &'r Device {
    rig.engage();
    let steer = rig.device(name);
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
    let t = Instant::now();
    assert!(submit_when_idle(&rig, steer, set(0.4)));
    wait_for("the timeout to be counted", || {
        steer.stats().command_errors.load(Relaxed) == 1
    });
    // The command thread, asleep on its port for the reply, is woken by the reply's
    // deadline: the transaction ends there, not at its next resend.
    assert!(
        t.elapsed() < Duration::from_secs(5),
        "a reply timeout of 50 ms ended after {:?} (command_timeout: 10 s)",
        t.elapsed()
    );
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

/// What the kernel says of one of this process's threads: whether it is asleep, and
/// how many times it went to sleep so far.
struct Sleeper {
    tid: String,
}

impl Sleeper {
    /// The thread named `name`.
    fn named(name: &str) -> Sleeper {
        let tasks = std::fs::read_dir("/proc/self/task").expect("/proc");
        for t in tasks {
            let t = t.unwrap();
            let comm = std::fs::read_to_string(t.path().join("comm")).unwrap_or_default();
            if comm.trim_end() == name {
                return Sleeper {
                    tid: t.file_name().to_string_lossy().into_owned(),
                };
            }
        }
        panic!("no thread named {name}");
    }

    fn read(&self, file: &str) -> String {
        std::fs::read_to_string(format!("/proc/self/task/{}/{file}", self.tid)).unwrap()
    }

    /// Asleep in the kernel (`S`), not running or runnable.
    fn asleep(&self) -> bool {
        let stat = self.read("stat");
        // After the name in parentheses: the state.
        stat.rsplit(')')
            .next()
            .unwrap()
            .trim_start()
            .starts_with('S')
    }

    /// How many times it went to sleep: its voluntary context switches.
    fn sleeps(&self) -> u64 {
        self.read("status")
            .lines()
            .find_map(|l| l.strip_prefix("voluntary_ctxt_switches:"))
            .expect("voluntary_ctxt_switches")
            .trim()
            .parse()
            .unwrap()
    }
}

/// The reason the command thread sleeps on its port: a command's request, written by
/// the thread that admitted it, wakes nobody — the device's reply wakes the command
/// thread, which reads it. Counted by the kernel: over fast commands whose device
/// answers 20 ms after the request, the command thread goes to sleep once per command
/// (asleep for the next one), not twice (woken after the write, asleep again in the
/// read of the reply) — nothing else runs between the request's first byte and the
/// device's answer.
#[test]
fn a_fast_command_s_reply_is_what_wakes_the_command_thread() {
    // Named apart from the other tests' devices: its thread is found by its name.
    let rig = Rig::start(
        &steer_only(
            "status_period = \"10s\"\nstatus_max_age = \"10s\"\ncommand_timeout = \"10s\"",
            "command_delay = \"20ms\"",
        )
        .replace("\"steer\"", "\"sleeper\""),
    );
    let steer = engaged_named(&rig, "sleeper");
    assert!(steer.slot().waits_on_port());
    let thread = Sleeper::named("sleeper/command");
    let asleep_idle = || steer.slot().is_idle() && thread.asleep();
    let (mut commands, mut sleeps) = (0u64, 0u64);
    for k in 1..=20 {
        let v = k as f64 / 100.0;
        wait_for("the command thread to sleep", asleep_idle);
        let before = thread.sleeps();
        if !submit_when_idle(&rig, steer, set(v)) {
            // The status thread's poll held the port: the ordinary path.
            continue;
        }
        wait_for("the reply to be read", || {
            steer.slot().executed() == Some(set(v))
        });
        wait_for("the command thread to sleep again", asleep_idle);
        commands += 1;
        sleeps += thread.sleeps() - before;
    }
    assert!(commands >= 10, "only {commands} of 20 went the fast way");
    // One per command; a little more allowed for a lock found taken on a loaded
    // machine. Woken after each write, it would sleep at least twice per command.
    assert!(
        sleeps * 2 < commands * 3,
        "the command thread slept {sleeps} times over {commands} fast commands"
    );
    assert_eq!(steer.stats().command_errors.load(Relaxed), 0);
}

/// Asleep on its port with nothing in flight, the command thread is rung for the safe
/// state when the engine stops: the safe state reaches the device, and every thread
/// stops in time.
#[test]
fn a_stop_while_the_command_thread_sleeps_on_its_port_commands_the_safe_state() {
    let mut rig = Rig::start(&steer_only(
        "status_period = \"10s\"\nstatus_max_age = \"10s\"\ncommand_timeout = \"10s\"\nsafe = -0.25",
        "",
    ));
    let steer = engaged(&rig);
    assert!(submit_when_idle(&rig, steer, set(0.5)));
    wait_for("the command to execute", || {
        steer.slot().executed() == Some(set(0.5))
    });
    wait_for("the command thread to sleep on its port", || {
        steer.slot().is_idle()
    });
    let engine = rig.engine.take().unwrap();
    let (safe, stuck) = engine.shutdown(Duration::from_secs(5));
    assert!(safe, "the safe state was acknowledged");
    assert!(stuck.is_empty(), "threads that did not stop: {stuck:?}");
    let got: Vec<Command> = rig.received().iter().map(|e| e.command).collect();
    assert_eq!(
        got.last(),
        Some(&set(-0.25)),
        "the safe state went out last: {got:?}"
    );
}
