//! The one oracle every fuzzer of the command protocol runs: the libFuzzer target in
//! `fuzz/`, the stable mutation loop in `examples/fuzz_net.rs`, and the property tests.
//! It feeds bytes to [`parse`] and, when they parse, to [`Auth::verify`], and panics if
//! an accepted datagram breaks a promise the engine relies on. Not part of the API.

use super::auth::Auth;
use super::proto::{parse, BadDatagram, Datagram, NetCommand, Vocabulary, MAX_COMMANDS};
use crate::config::VehicleConfig;
use crate::value::{Command, Kind};
use std::sync::LazyLock;

/// The vehicle the fuzzers speak to: the built-in Alice.
static ALICE: LazyLock<VehicleConfig> = LazyLock::new(VehicleConfig::alice);

/// Words and shapes the grammar cares about: fuzzers splice them into their inputs to
/// get past the first check (the stable loop, the property tests).
pub const DICTIONARY: &[&str] = &[
    "steer",
    "gas",
    "brake",
    "trans",
    "accel",
    "engage",
    "disengage",
    "seq",
    "tag",
    "estop",
    "obd",
    "STEER",
    "drive",
    "park",
    "neutral",
    "reverse",
    "r",
    "-1",
    "0",
    "1",
    "-0",
    "0.5",
    "1.0000001",
    "-1e0",
    "+.5",
    "1e-300",
    "5e-324",
    "1e999",
    "NaN",
    "inf",
    "-infinity",
    "0x1",
    "18446744073709551615",
    "18446744073709551616",
    " ",
    "\t",
    "\n",
    "\r\n",
    "\r",
    "#",
    "é",
    "\u{0}",
    "\u{7f}",
];

/// The key the oracle checks tags with (and that fuzz seeds are signed with).
pub const FUZZ_KEY: &[u8] = b"adrive fuzzing key, not a secret";

/// Parses `bytes`, checks every invariant of an accepted datagram, runs
/// [`Auth::verify`] on it, and returns what [`parse`] decided. Panics on a broken
/// invariant; that panic is the fuzzers' finding.
pub fn exercise(bytes: &[u8]) -> Result<Datagram, BadDatagram> {
    let datagram = parse(bytes, &Vocabulary::of(&ALICE)).map_err(|e| {
        // The human message must render for any input.
        let _ = e.to_string();
        e.reason
    })?;
    check_accepted(&datagram, bytes);
    let auth = Auth::from_key_bytes(FUZZ_KEY).expect("fuzz key is long enough");
    match auth.verify(&datagram, bytes, None) {
        Ok(()) => {
            let seq = datagram.seq.expect("a verified datagram has a seq");
            assert_eq!(
                auth.verify(&datagram, bytes, Some(seq)),
                Err(BadDatagram::Replayed)
            );
        }
        Err(BadDatagram::MissingTag) => assert!(datagram.tag.is_none()),
        Err(BadDatagram::BadTag | BadDatagram::MissingSeq) => assert!(datagram.tag.is_some()),
        Err(other) => panic!("verify gave {other:?}"),
    }
    Ok(datagram)
}

/// The promises of an accepted datagram.
fn check_accepted(d: &Datagram, bytes: &[u8]) {
    assert!(!d.commands.is_empty() && d.commands.len() <= MAX_COMMANDS);
    assert_eq!(d.signed.start, 0);
    assert!(d.signed.end <= bytes.len());
    if d.tag.is_none() {
        assert_eq!(d.signed.end, bytes.len());
    }
    for c in &d.commands {
        match *c {
            NetCommand::Accel(v) => {
                assert!((-1.0..=1.0).contains(&v), "accepted out of range: {c:?}")
            }
            NetCommand::Set(id, command) => {
                let dev = &ALICE.devices[id.index()];
                match (dev.kind, command) {
                    (Kind::Setpoint, Command::Set(v)) => {
                        let [lo, hi] = dev.range;
                        assert!((lo..=hi).contains(&v), "accepted out of range: {c:?}")
                    }
                    (Kind::State, Command::State(s)) => {
                        assert!((s as usize) < dev.states.len(), "no such state: {c:?}")
                    }
                    _ => panic!("accepted a command its device does not take: {c:?}"),
                }
            }
            NetCommand::Engage
            | NetCommand::Disengage
            | NetCommand::Release
            | NetCommand::Clear => {}
        }
    }
    // What was accepted prints back to lines that parse to the same commands.
    let vocab = Vocabulary::of(&ALICE);
    let text: String = d
        .commands
        .iter()
        .map(|c| format!("{}\n", vocab.line(c)))
        .collect();
    let again = parse(text.as_bytes(), &vocab).unwrap_or_else(|e| panic!("{text:?}: {e}"));
    assert_eq!(again.commands, d.commands, "{text:?}");
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::path::Path;

    /// The libFuzzer seeds must be good datagrams, or the fuzzer starts nowhere; the
    /// `signed` one was made with `openssl` and `FUZZ_KEY`, and must verify.
    #[test]
    fn fuzz_seeds_are_good_datagrams() {
        let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("fuzz/seeds/net_parse");
        let mut seen = 0;
        for entry in std::fs::read_dir(&dir).unwrap() {
            let path = entry.unwrap().path();
            let bytes = std::fs::read(&path).unwrap();
            let d = exercise(&bytes).unwrap_or_else(|r| panic!("{}: {r}", path.display()));
            if path.ends_with("signed") {
                let auth = Auth::from_key_bytes(FUZZ_KEY).unwrap();
                assert_eq!(auth.verify(&d, &bytes, None), Ok(()));
            }
            seen += 1;
        }
        assert!(seen >= 5, "only {seen} seeds in {}", dir.display());
    }
}
