//! The command path from socket to serial write must not touch the heap: this binary
//! counts every allocation made on the test's thread while a datagram is parsed,
//! checked and counted, and — on a real engine over a real pseudo-terminal — while the
//! same thread writes the request to the port, arms the port's wake and hands the
//! transaction over to the device's command thread (the fast path).

mod common;

use adrive::config::VehicleConfig;
use adrive::net::auth::Auth;
use adrive::net::proto::{parse, BadDatagram, BadDatagramCounts, Vocabulary};
use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;

struct Counting;

thread_local! {
    static ALLOCATIONS: Cell<usize> = const { Cell::new(0) };
}

#[allow(unsafe_code)]
// SAFETY: every call is handed on to the system allocator unchanged.
unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        let _ = ALLOCATIONS.try_with(|n| n.set(n.get() + 1));
        // SAFETY: the caller keeps `alloc`'s contract, which is System's.
        unsafe { System.alloc(layout) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        // SAFETY: the caller keeps `dealloc`'s contract: `ptr` came from System.
        unsafe { System.dealloc(ptr, layout) }
    }
}

#[global_allocator]
static GLOBAL: Counting = Counting;

fn allocations_in(f: impl FnOnce()) -> usize {
    let before = ALLOCATIONS.with(Cell::get);
    f();
    ALLOCATIONS.with(Cell::get) - before
}

/// The listener's intake of `gate`'s vehicle, with its vehicle file's network.
fn intake_of(gate: &std::sync::Arc<adrive::engine::Gate>) -> adrive::net::intake::Intake {
    use adrive::net::NetStatus;
    use std::sync::atomic::AtomicBool;
    use std::sync::Arc;

    let network = gate.vehicle().config().network.clone();
    let status = Arc::new(NetStatus::of(
        gate.vehicle(),
        network.listen,
        network.watchdog_timeout,
    ));
    adrive::net::intake::Intake::new(
        gate.clone(),
        network,
        None,
        status,
        Arc::new(AtomicBool::new(false)),
    )
}

#[test]
fn parse_verify_and_count_do_not_allocate() {
    let auth = Auth::from_key_bytes(b"a key of at least sixteen bytes").unwrap();
    let signed = auth.sign("engage\nsteer -0.25\ngas 0.3\ntrans drive\n", 12);
    let plain = b"seq 4\r\nsteer 0.2 # left\r\naccel -0.5\r\n";
    let bad = b"steer 0.2\nstear 0.3\n";
    let counts = BadDatagramCounts::new();
    let alice = VehicleConfig::alice();
    let vocab = Vocabulary::of(&alice);
    let parse = |b: &[u8]| parse(b, &vocab);

    let n = allocations_in(|| {
        let d = parse(signed.as_bytes()).unwrap();
        assert_eq!(d.commands.len(), 4);
        auth.verify(&d, signed.as_bytes(), Some(11)).unwrap();
        assert_eq!(
            auth.verify(&d, signed.as_bytes(), Some(12)),
            Err(BadDatagram::Replayed)
        );

        let d = parse(plain).unwrap();
        assert_eq!(auth.verify(&d, plain, None), Err(BadDatagram::MissingTag));

        let e = parse(bad).unwrap_err();
        counts.incr(e.reason);
        assert_eq!(counts.get(BadDatagram::UnknownDevice), 1);
    });
    assert_eq!(n, 0, "the command path allocated {n} times");
}

/// The listener's whole decision on a command datagram from the commander of an
/// engaged vehicle — sender table, counter, commander, interlocks, slot — and the
/// repeated `engage` of a planner (which is not answered): no allocation.
#[test]
fn the_listener_path_of_an_accepted_datagram_does_not_allocate() {
    use adrive::engine::Gate;
    use adrive::value::Command;
    use std::sync::Arc;
    use std::time::Instant;

    // Every device has "reported": the vehicle may engage (no engine runs here).
    let vehicle = Arc::new(adrive::testkit::vehicle_zeroed(VehicleConfig::alice()));
    let gate = Arc::new(Gate::new(vehicle.clone()));
    let mut intake = intake_of(&gate);
    let from = "127.0.0.1:40000".parse().unwrap();
    let reply = intake.handle(b"engage\n", from, Instant::now()).unwrap();
    assert_eq!(reply.as_str(), "ok engaged\n");
    let datagrams: [&[u8]; 3] = [
        b"seq 1\nsteer 0.2\naccel -0.3\n",
        b"seq 2\nengage\nsteer -0.1 # planner\naccel -0.5\n",
        b"seq 3\nbrake 1\ngas 0\n",
    ];
    let mut replies = Vec::with_capacity(3);
    let n = allocations_in(|| {
        for d in datagrams {
            replies.push(intake.handle(d, from, Instant::now()));
        }
    });
    assert_eq!(n, 0, "the listener path allocated {n} times");
    assert!(gate.is_engaged());
    assert_eq!(
        vehicle.find("steer").unwrap().slot().latest(),
        Some(Command::Set(-0.1))
    );
    assert!(
        replies.iter().all(Option::is_none),
        "accepted commands and a repeated engage are not answered: {replies:?}"
    );
}

/// The whole way of a command datagram on the thread that reads it, up to the serial
/// write and beyond: the network's checks, the one intake, then the fast path — the
/// request written to the device's pseudo-terminal, the port's wake armed for the
/// reply ([`adrive::engine`]'s command thread sleeps on it), the transaction handed
/// over to that thread. Counted command by command, each sent when the command thread
/// sleeps with the port idle, and each proven to have gone the fast way.
#[test]
fn the_fast_path_from_datagram_to_serial_write_does_not_allocate() {
    use adrive::value::Command;
    use common::{steer_only, wait_for, Rig};
    use std::sync::atomic::Ordering::Relaxed;
    use std::time::Instant;

    // No status poll and no resend comes between the commands: each finds the port idle.
    let toml = steer_only(
        "status_period = \"10s\"\nstatus_max_age = \"10s\"\ncommand_timeout = \"10s\"",
        "",
    ) + "\n[network]\nallow_engage = true\n";
    let rig = Rig::start(&toml);
    let mut intake = intake_of(&rig.gate);
    let from = "127.0.0.1:40000".parse().unwrap();
    wait_for("the device to report", || rig.gate.blockers().is_empty());
    let reply = intake.handle(b"engage\n", from, Instant::now()).unwrap();
    assert_eq!(reply.as_str(), "ok engaged\n");
    let steer = rig.device("steer");
    let stats = steer.stats();
    wait_for("the engage hold to execute", || {
        stats.executed.load(Relaxed) == 1
    });
    // One command `v` by the fast path; the allocations its datagram made on this
    // thread.
    let mut send = |text: &[u8], v: f64| {
        wait_for("the command thread to sleep", || steer.slot().is_idle());
        let fast = stats.fast.load(Relaxed);
        let n = allocations_in(|| {
            assert!(intake.handle(text, from, Instant::now()).is_none());
        });
        assert_eq!(
            stats.fast.load(Relaxed),
            fast + 1,
            "{v} went out by the fast path"
        );
        wait_for("the reply to be read", || {
            steer.slot().executed() == Some(Command::Set(v))
        });
        n
    };
    // The first of each step on this thread and this port may set something up once.
    send(b"steer 0.1\n", 0.1);
    let datagrams: [(&[u8], f64); 4] = [
        (b"steer 0.2\n", 0.2),
        (b"seq 1\nsteer -0.3\n", -0.3),
        (b"steer 0.45 # planner\n", 0.45),
        (b"seq 2\nsteer -0.05\n", -0.05),
    ];
    let n: usize = datagrams.iter().map(|&(d, v)| send(d, v)).sum();
    assert_eq!(n, 0, "the fast path allocated {n} times in 4 commands");
    assert_eq!(stats.command_errors.load(Relaxed), 0);
}
