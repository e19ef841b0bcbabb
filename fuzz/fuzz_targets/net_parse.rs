//! libFuzzer target for the command protocol: every input goes through the parser
//! and, when it parses, through authentication, via the oracle shared with the
//! stable fuzzer (`examples/fuzz_net.rs`), which panics on a broken invariant.
#![no_main]

use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let _ = adrive::net::fuzzing::exercise(data);
});
