//! The command path from socket to serial write must not touch the heap: this binary
//! counts every allocation made on the test's thread while a datagram is parsed,
//! checked and counted.

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
    use adrive::net::intake::Intake;
    use adrive::net::NetStatus;
    use adrive::value::Command;
    use std::sync::atomic::AtomicBool;
    use std::sync::Arc;
    use std::time::Instant;

    let config = VehicleConfig::alice();
    let network = config.network.clone();
    // Every device has "reported": the vehicle may engage (no engine runs here).
    let vehicle = Arc::new(adrive::testkit::vehicle_zeroed(config));
    let gate = Arc::new(Gate::new(vehicle.clone()));
    let names = vehicle
        .devices()
        .iter()
        .map(|d| d.name().to_string())
        .collect();
    let status = Arc::new(NetStatus::new(
        network.listen,
        network.watchdog_timeout,
        names,
    ));
    let mut intake = Intake::new(
        gate.clone(),
        network,
        None,
        status,
        Arc::new(AtomicBool::new(false)),
    );
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
