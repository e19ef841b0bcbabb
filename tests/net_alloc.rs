//! The command path from socket to serial write must not touch the heap: this binary
//! counts every allocation made on the test's thread while a datagram is parsed,
//! checked and counted.

use adrive::net::auth::Auth;
use adrive::net::proto::{parse, Reject, RejectCounts};
use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;

struct Counting;

thread_local! {
    static ALLOCATIONS: Cell<usize> = const { Cell::new(0) };
}

unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        let _ = ALLOCATIONS.try_with(|n| n.set(n.get() + 1));
        unsafe { System.alloc(layout) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
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
    let counts = RejectCounts::new();

    let n = allocations_in(|| {
        let d = parse(signed.as_bytes()).unwrap();
        assert_eq!(d.commands.len(), 4);
        auth.verify(&d, signed.as_bytes(), Some(11)).unwrap();
        assert_eq!(
            auth.verify(&d, signed.as_bytes(), Some(12)),
            Err(Reject::Replayed)
        );

        let d = parse(plain).unwrap();
        assert_eq!(auth.verify(&d, plain, None), Err(Reject::MissingTag));

        let e = parse(bad).unwrap_err();
        counts.incr(e.reason);
        assert_eq!(counts.get(Reject::UnknownDevice), 1);
    });
    assert_eq!(n, 0, "the command path allocated {n} times");
}
