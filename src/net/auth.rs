//! Datagram authentication: with a shared key set, adrive takes a command datagram
//! only if it carries an HMAC-SHA256 `tag` of its bytes under that key and a `seq`
//! greater than the last one accepted, so that nobody else on the network can steer
//! the vehicle and a captured datagram cannot be played again. The grammar (which
//! bytes are signed, the `openssl` recipe) is in [`proto`](super::proto); this module
//! holds the key, checks tags in constant time, and signs for `adrive send`.
//!
//! # Key files
//!
//! A key file holds the key as text; surrounding whitespace (the final newline) is not
//! part of it, so `openssl dgst -sha256 -hmac "$(cat adrive.key)"` signs with the same
//! key. A key of raw bytes is written as `hex:` followed by its hex digits; sign with
//! it as `openssl dgst -sha256 -mac HMAC -macopt hexkey:HEX`. A key is at least
//! [`MIN_KEY_LEN`] bytes: `openssl rand -hex 32 > adrive.key` makes a good one.

use super::proto::{hex_digit, BadDatagram, Datagram};
use hmac::{Hmac, Mac};
use sha2::Sha256;
use std::fmt::{self, Write as _};
use std::path::{Path, PathBuf};

type HmacSha256 = Hmac<Sha256>;

/// The shortest key accepted, in bytes.
pub(crate) const MIN_KEY_LEN: usize = 16;

/// A shared key, ready to check and sign datagrams. Only the keyed HMAC state is kept,
/// and `Debug` never prints it.
#[derive(Clone)]
pub struct Auth {
    mac: HmacSha256,
}

/// Why a key could not be used.
#[derive(Debug, thiserror::Error)]
pub enum KeyError {
    #[error("the key is empty")]
    Empty,
    #[error("the key is {0} bytes; use at least 16 (e.g. `openssl rand -hex 32 > adrive.key`)")]
    TooShort(usize),
    #[error("the key after `hex:` must be an even number of hex digits")]
    BadHex,
    // The cause is part of the message, not a `source`: a chain would print it twice.
    #[error("{}: {error}", path.display())]
    Read {
        path: PathBuf,
        error: std::io::Error,
    },
    #[error("{}: {error}", path.display())]
    InFile { path: PathBuf, error: Box<KeyError> },
}

impl Auth {
    /// A key of raw bytes.
    pub fn from_key_bytes(key: &[u8]) -> Result<Auth, KeyError> {
        if key.is_empty() {
            return Err(KeyError::Empty);
        }
        if key.len() < MIN_KEY_LEN {
            return Err(KeyError::TooShort(key.len()));
        }
        let mac = HmacSha256::new_from_slice(key).map_err(|_| KeyError::Empty)?;
        Ok(Auth { mac })
    }

    /// A key written as hex digits (e.g. from a `--key-hex` option).
    pub(crate) fn from_hex(hex: &str) -> Result<Auth, KeyError> {
        let digits = hex.trim().as_bytes();
        if !digits.len().is_multiple_of(2) {
            return Err(KeyError::BadHex);
        }
        let key = digits
            .chunks_exact(2)
            .map(|p| Some((hex_digit(p[0])? << 4) | hex_digit(p[1])?))
            .collect::<Option<Vec<u8>>>()
            .ok_or(KeyError::BadHex)?;
        Auth::from_key_bytes(&key)
    }

    /// A key from the contents of a key file: its text without surrounding whitespace,
    /// or `hex:` and hex digits for a key of raw bytes.
    pub(crate) fn from_key_file(contents: &[u8]) -> Result<Auth, KeyError> {
        let text = contents.trim_ascii();
        match text.strip_prefix(b"hex:") {
            Some(hex) => Auth::from_hex(std::str::from_utf8(hex).map_err(|_| KeyError::BadHex)?),
            None => Auth::from_key_bytes(text),
        }
    }

    /// Reads a key file; errors name the file.
    pub fn load(path: &Path) -> Result<Auth, KeyError> {
        let contents = std::fs::read(path).map_err(|error| KeyError::Read {
            path: path.to_owned(),
            error,
        })?;
        Auth::from_key_file(&contents).map_err(|e| KeyError::InFile {
            path: path.to_owned(),
            error: Box::new(e),
        })
    }

    /// The HMAC-SHA256 of `signed` under the key.
    pub fn tag(&self, signed: &[u8]) -> [u8; 32] {
        let mut mac = self.mac.clone();
        mac.update(signed);
        mac.finalize().into_bytes().into()
    }

    /// Whether `tag` is the HMAC-SHA256 of `signed` under the key, compared in
    /// constant time (a fleet link's messages).
    #[cfg_attr(not(feature = "fleet"), allow(dead_code))]
    pub(crate) fn check(&self, signed: &[u8], tag: &[u8]) -> bool {
        let mut mac = self.mac.clone();
        mac.update(signed);
        mac.verify_slice(tag).is_ok()
    }

    /// Checks a parsed datagram against the key and the last counter accepted from
    /// this key (`None` before the first). `bytes` are the bytes it was parsed from.
    /// The tag is compared in constant time and checked before the counter, so an
    /// unsigned sender learns nothing about the counter. Allocation-free.
    pub fn verify(
        &self,
        datagram: &Datagram,
        bytes: &[u8],
        last_seq: Option<u64>,
    ) -> Result<(), BadDatagram> {
        let tag = datagram.tag.ok_or(BadDatagram::MissingTag)?;
        let signed = bytes
            .get(datagram.signed.clone())
            .ok_or(BadDatagram::BadTag)?;
        let mut mac = self.mac.clone();
        mac.update(signed);
        mac.verify_slice(&tag).map_err(|_| BadDatagram::BadTag)?;
        let seq = datagram.seq.ok_or(BadDatagram::MissingSeq)?;
        if last_seq.is_some_and(|last| seq <= last) {
            return Err(BadDatagram::Replayed);
        }
        Ok(())
    }

    /// A complete signed datagram: `seq`, then `body` (protocol lines, given a final
    /// newline if it lacks one), then the `tag` line. For `adrive send` and tests.
    pub fn sign(&self, body: &str, seq: u64) -> String {
        let mut out = String::with_capacity(body.len() + 96);
        let _ = writeln!(out, "seq {seq}");
        out.push_str(body);
        if !body.is_empty() && !body.ends_with('\n') {
            out.push('\n');
        }
        let tag = self.tag(out.as_bytes());
        out.push_str("tag ");
        for b in tag {
            let _ = write!(out, "{b:02x}");
        }
        out.push('\n');
        out
    }
}

impl fmt::Debug for Auth {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str("Auth { key: <redacted> }")
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::net::proto::{NetCommand, Vocabulary};
    use crate::value::{Command, DeviceId};

    fn parse(bytes: &[u8]) -> Result<crate::net::proto::Datagram, crate::net::proto::ParseError> {
        let alice = crate::config::VehicleConfig::alice();
        crate::net::proto::parse(bytes, &Vocabulary::of(&alice))
    }

    const KEY: &[u8] = b"correct horse battery staple";

    fn auth() -> Auth {
        Auth::from_key_bytes(KEY).unwrap()
    }

    fn check(bytes: &[u8], last_seq: Option<u64>) -> Result<(), BadDatagram> {
        let d = parse(bytes).map_err(BadDatagram::from)?;
        auth().verify(&d, bytes, last_seq)
    }

    /// Made on this machine with OpenSSL 3.0 by the recipe in the `proto` docs:
    /// `printf 'correct horse battery staple\n' > adrive.key; KEY=$(cat adrive.key)`,
    /// `body=$(printf 'seq %s\nsteer 0.2\ngas 0.1' 1001)`, then the `openssl dgst
    /// -sha256 -hmac "$KEY"` and `printf '%s\ntag %s\n'` lines.
    const OPENSSL_DATAGRAM: &[u8] = b"seq 1001\nsteer 0.2\ngas 0.1\n\
        tag ed5d727bdc32b79c5bea4a4ac7d922fabb8b5e9a161727b5f477591b86a974ab\n";

    #[test]
    fn datagram_signed_with_openssl_verifies() {
        let d = parse(OPENSSL_DATAGRAM).unwrap();
        assert_eq!(d.seq, Some(1001));
        assert_eq!(
            d.commands.as_slice(),
            [
                NetCommand::Set(DeviceId(0), Command::Set(0.2)),
                NetCommand::Set(DeviceId(1), Command::Set(0.1)),
            ]
        );
        auth().verify(&d, OPENSSL_DATAGRAM, Some(1000)).unwrap();
        // The same key from the key file the recipe used.
        let from_file = Auth::from_key_file(b"correct horse battery staple\n").unwrap();
        from_file.verify(&d, OPENSSL_DATAGRAM, None).unwrap();
        // And `sign` writes exactly what the shell wrote.
        assert_eq!(
            auth().sign("steer 0.2\ngas 0.1", 1001).as_bytes(),
            OPENSSL_DATAGRAM
        );
    }

    #[test]
    fn signed_datagram_verifies_and_parses_to_its_body() {
        let text = auth().sign("engage\r\nsteer -0.5\r\n", 7);
        let d = parse(text.as_bytes()).unwrap();
        assert_eq!(d.seq, Some(7));
        assert_eq!(d.commands.len(), 2);
        auth().verify(&d, text.as_bytes(), None).unwrap();
        auth().verify(&d, text.as_bytes(), Some(6)).unwrap();
    }

    #[test]
    fn any_flipped_byte_is_rejected() {
        let good = auth().sign("steer 0.2\ngas 0.1\n", 42);
        for i in 0..good.len() {
            let mut bytes = good.clone().into_bytes();
            bytes[i] ^= 0x01;
            // Some flips break the grammar first; none may be accepted.
            let got = check(&bytes, None);
            assert!(
                got.is_err(),
                "flip at {i} accepted: {:?}",
                String::from_utf8_lossy(&bytes)
            );
            if bytes[..i].ends_with(b"steer 0.") {
                // `0.2` → `0.3`: still a good command, so only the tag catches it.
                assert_eq!(got, Err(BadDatagram::BadTag));
            }
        }
    }

    #[test]
    fn wrong_key_is_bad_tag() {
        let other = Auth::from_key_bytes(b"another key of 16+ bytes").unwrap();
        let text = other.sign("steer 0.2", 1);
        assert_eq!(check(text.as_bytes(), None), Err(BadDatagram::BadTag));
    }

    #[test]
    fn unsigned_datagram_is_missing_tag() {
        assert_eq!(
            check(b"seq 5\nsteer 0.2\n", None),
            Err(BadDatagram::MissingTag)
        );
        assert_eq!(check(b"steer 0.2\n", None), Err(BadDatagram::MissingTag));
    }

    #[test]
    fn signed_without_seq_is_missing_seq() {
        let mut text = String::from("steer 0.2\n");
        let tag: String = auth()
            .tag(text.as_bytes())
            .iter()
            .map(|b| format!("{b:02x}"))
            .collect();
        text.push_str(&format!("tag {tag}\n"));
        assert_eq!(check(text.as_bytes(), None), Err(BadDatagram::MissingSeq));
    }

    #[test]
    fn replayed_or_older_seq_is_rejected() {
        let text = auth().sign("steer 0.2", 100);
        assert_eq!(
            check(text.as_bytes(), Some(100)),
            Err(BadDatagram::Replayed)
        );
        assert_eq!(
            check(text.as_bytes(), Some(101)),
            Err(BadDatagram::Replayed)
        );
        assert_eq!(check(text.as_bytes(), Some(99)), Ok(()));
        let zero = auth().sign("steer 0.2", 0);
        assert_eq!(check(zero.as_bytes(), None), Ok(()));
    }

    #[test]
    fn bytes_that_do_not_match_the_datagram_are_bad_tag() {
        let text = auth().sign("steer 0.2", 3);
        let d = parse(text.as_bytes()).unwrap();
        assert_eq!(auth().verify(&d, b"short", None), Err(BadDatagram::BadTag));
    }

    #[test]
    fn key_file_forms() {
        let text = Auth::from_key_file(b"  0123456789abcdef0123\r\n").unwrap();
        let same = Auth::from_key_bytes(b"0123456789abcdef0123").unwrap();
        assert_eq!(text.tag(b"x"), same.tag(b"x"));

        let hex = Auth::from_key_file(b"hex:00ff00ff00ff00ff00ff00ff00ff00ff\n").unwrap();
        let raw = Auth::from_key_bytes(&[0x00, 0xff].repeat(8)).unwrap();
        assert_eq!(hex.tag(b"x"), raw.tag(b"x"));
        assert_eq!(
            Auth::from_hex("00FF00FF00FF00FF00FF00FF00FF00FF")
                .unwrap()
                .tag(b"x"),
            raw.tag(b"x")
        );

        assert!(matches!(Auth::from_key_file(b"\n"), Err(KeyError::Empty)));
        assert!(matches!(
            Auth::from_key_file(b"secret\n"),
            Err(KeyError::TooShort(6))
        ));
        assert!(matches!(
            Auth::from_key_file(b"hex:abc"),
            Err(KeyError::BadHex)
        ));
        assert!(matches!(
            Auth::from_key_file(b"hex:zz"),
            Err(KeyError::BadHex)
        ));
    }

    #[test]
    fn key_file_errors_name_the_file_and_debug_hides_the_key() {
        let guard = tempfile::Builder::new()
            .prefix("adrive-auth-")
            .tempdir()
            .unwrap();
        let dir = guard.path();
        let path = dir.join("short.key");
        std::fs::write(&path, "secret\n").unwrap();
        let err = Auth::load(&path).unwrap_err().to_string();
        assert!(err.starts_with(&path.display().to_string()), "{err}");
        assert!(err.contains("at least 16"), "{err}");
        let missing = Auth::load(&dir.join("none.key")).unwrap_err().to_string();
        assert!(missing.contains("none.key"), "{missing}");

        assert!(!format!("{:?}", auth()).contains("horse"));
    }
}
