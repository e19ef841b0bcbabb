//! A link over the fleet: how a console or an operator's command elsewhere reaches a
//! vehicle's control socket, carrying the socket's own protocol line by line (pure:
//! what goes on the wire and how it is signed; [`super::dial`] is the end that asks,
//! [`super::serve`] the vehicle's).
//!
//! The asking end names its link with a random id (`sid`), declares the liveliness
//! token `adrive/<id>/link/<sid>` — the link is there as long as that token is, and a
//! console that commands the vehicle is its own watchdog through it — and sends
//! [`Up`] messages at `…/up`: the first (`seq` 0) opens the link, the vehicle answers
//! at `…/down` with a [`Challenge`] (a fresh nonce, and whether it takes commands from
//! the fleet at all), and from then on every message carries the next `seq` and the
//! lines of the protocol, each going to the socket's server as from a local client;
//! the last, numbered [`CLOSE`], says the client closed its end.
//!
//! **Who may command.** A link proves the vehicle's key (the `[network]` key that signs
//! its command datagrams, [`Auth`]) by signing every message after the challenge:
//! HMAC-SHA256 over [`signed`] — a domain, the vehicle's id, the link's id, the
//! vehicle's nonce, the counter and the line — so that a message cannot be taken to
//! another vehicle or another link, played again in this link or in a later one, or
//! changed. A link whose proof (`seq` 1) holds may command, if the vehicle's `[fleet]`
//! allows it; any other only watches, and everything it asks of the vehicle is refused
//! with the reason. Zenoh's own access control was the other choice; it is set up on
//! the router, grants by network identity rather than by vehicle, and leaves a
//! vehicle's safety to a router's configuration: the key keeps it end to end, and it
//! is the key the vehicle already has.

use crate::net::auth::Auth;

/// The bytes every signature starts with: a link's, no other's.
const DOMAIN: &[u8] = b"adrive fleet link 1";
/// How long a tag is.
pub(crate) const TAG: usize = 32;
/// How long the vehicle's nonce is.
pub(crate) const NONCE: usize = 16;
/// The counter of the message that closes a link (its client closed its end): no
/// line follows it.
pub(crate) const CLOSE: u64 = u64::MAX;
/// The longest line a link carries up (the socket's own bound, with room).
pub(crate) const MAX_UP: usize = 8 + TAG + 4096;

/// A message from the asking end: `seq` (8 bytes, big-endian), its tag (32 bytes:
/// zeros where the link has no key) and a line of the protocol (none in the opening
/// and the proof).
#[derive(Clone, Debug, PartialEq, Eq)]
pub(crate) struct Up<'a> {
    pub seq: u64,
    pub tag: [u8; TAG],
    pub line: &'a [u8],
}

impl<'a> Up<'a> {
    pub(crate) fn encode(&self) -> Vec<u8> {
        let mut out = Vec::with_capacity(8 + TAG + self.line.len());
        out.extend_from_slice(&self.seq.to_be_bytes());
        out.extend_from_slice(&self.tag);
        out.extend_from_slice(self.line);
        out
    }

    /// The message in `bytes`, if it is one.
    pub(crate) fn decode(bytes: &'a [u8]) -> Option<Up<'a>> {
        if bytes.len() < 8 + TAG || bytes.len() > MAX_UP {
            return None;
        }
        let (seq, rest) = bytes.split_at(8);
        let (tag, line) = rest.split_at(TAG);
        Some(Up {
            seq: u64::from_be_bytes(seq.try_into().ok()?),
            tag: tag.try_into().ok()?,
            line,
        })
    }

    /// The message numbered `seq` carrying `line`, signed with `key` on the link
    /// `(id, sid)` the vehicle challenged with `nonce` (unsigned without a key).
    pub(crate) fn signed(
        key: Option<&Auth>,
        (id, sid, nonce): (&str, &str, &[u8; NONCE]),
        seq: u64,
        line: &'a [u8],
    ) -> Up<'a> {
        let tag = key.map_or([0; TAG], |k| k.tag(&signed(id, sid, nonce, seq, line)));
        Up { seq, tag, line }
    }

    /// Whether `key` signed it on that link.
    pub(crate) fn holds(&self, key: &Auth, (id, sid, nonce): (&str, &str, &[u8; NONCE])) -> bool {
        key.check(&signed(id, sid, nonce, self.seq, self.line), &self.tag)
    }
}

/// The bytes a link's message is signed over.
pub(crate) fn signed(id: &str, sid: &str, nonce: &[u8; NONCE], seq: u64, line: &[u8]) -> Vec<u8> {
    let mut out = Vec::with_capacity(DOMAIN.len() + id.len() + sid.len() + 40 + line.len());
    for part in [DOMAIN, id.as_bytes(), sid.as_bytes()] {
        out.extend_from_slice(part);
        out.push(0);
    }
    out.extend_from_slice(nonce);
    out.extend_from_slice(&seq.to_be_bytes());
    out.extend_from_slice(line);
    out
}

/// The vehicle's answer to an opening: the nonce every later message is signed with.
#[derive(Clone, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub(crate) struct Challenge {
    /// The nonce, in hex.
    pub nonce: String,
}

/// What the vehicle sends down a link: its challenge, lines of the protocol, and its
/// end (the socket's server closed the connection).
#[derive(Clone, Debug, PartialEq, Eq)]
pub(crate) enum Down {
    Challenge(Challenge),
    Line(Vec<u8>),
    End,
}

impl Down {
    pub(crate) fn encode(&self) -> Vec<u8> {
        match self {
            Down::Challenge(c) => {
                let mut out = vec![b'C'];
                serde_json::to_writer(&mut out, c).expect("a challenge serializes");
                out
            }
            Down::Line(l) => [b"L".as_slice(), l].concat(),
            Down::End => b"E".to_vec(),
        }
    }

    pub(crate) fn decode(bytes: &[u8]) -> Option<Down> {
        match bytes.split_first()? {
            (b'C', json) => serde_json::from_slice(json).ok().map(Down::Challenge),
            (b'L', line) => Some(Down::Line(line.to_vec())),
            (b'E', []) => Some(Down::End),
            _ => None,
        }
    }
}

/// Random bytes from the system.
pub(crate) fn random<const N: usize>() -> std::io::Result<[u8; N]> {
    use std::io::Read;
    let mut out = [0; N];
    std::fs::File::open("/dev/urandom")?.read_exact(&mut out)?;
    Ok(out)
}

/// Bytes as lower-case hex.
pub(crate) fn hex(bytes: &[u8]) -> String {
    bytes.iter().map(|b| format!("{b:02x}")).collect()
}

/// A nonce from its hex.
pub(crate) fn nonce_of(hex: &str) -> Option<[u8; NONCE]> {
    if hex.len() != 2 * NONCE || !hex.is_ascii() {
        return None;
    }
    let mut out = [0; NONCE];
    for (i, o) in out.iter_mut().enumerate() {
        *o = u8::from_str_radix(&hex[2 * i..2 * i + 2], 16).ok()?;
    }
    Some(out)
}

/// Is `sid` a link's id: 32 lower-case hex digits (16 random bytes).
pub(crate) fn valid_sid(sid: &str) -> bool {
    sid.len() == 32 && sid.bytes().all(|b| matches!(b, b'0'..=b'9' | b'a'..=b'f'))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn key(k: &str) -> Auth {
        Auth::from_key_bytes(k.as_bytes()).unwrap()
    }

    #[test]
    fn a_message_holds_on_its_own_link_only() {
        let k = key("0123456789abcdef0123");
        let nonce = [7; NONCE];
        let link = ("car1", "ab", &nonce);
        let up = Up::signed(Some(&k), link, 3, b"{\"id\":1}\n");
        let bytes = up.encode();
        let back = Up::decode(&bytes).unwrap();
        assert_eq!(back, up);
        assert!(back.holds(&k, link));
        // Another key, vehicle, link, challenge, counter or line: it does not hold.
        assert!(!back.holds(&key("another key, long enough"), link));
        assert!(!back.holds(&k, ("car2", "ab", &nonce)));
        assert!(!back.holds(&k, ("car1", "ac", &nonce)));
        assert!(!back.holds(&k, ("car1", "ab", &[8; NONCE])));
        assert!(!Up {
            seq: 4,
            ..back.clone()
        }
        .holds(&k, link));
        assert!(!Up {
            line: b"{\"id\":2}\n",
            ..back.clone()
        }
        .holds(&k, link));
        // No key: no tag, which holds under none.
        let open = Up::signed(None, link, 0, b"");
        assert_eq!(open.tag, [0; TAG]);
        assert!(!open.holds(&k, link));
        // The parts are separated: "car1"+"ab" is not "car"+"1ab".
        assert_ne!(
            signed("car1", "ab", &nonce, 1, b""),
            signed("car", "1ab", &nonce, 1, b"")
        );
    }

    #[test]
    fn what_is_not_a_message_is_refused() {
        assert_eq!(Up::decode(&[0; 8 + TAG - 1]), None);
        assert!(Up::decode(&[0; 8 + TAG]).is_some());
        assert_eq!(Up::decode(&vec![0; MAX_UP + 1]), None);
        assert_eq!(Down::decode(b""), None);
        assert_eq!(Down::decode(b"X"), None);
        assert_eq!(Down::decode(b"C{"), None);
        assert_eq!(Down::decode(b"Ex"), None);
        let c = Down::Challenge(Challenge {
            nonce: hex(&[1; NONCE]),
        });
        for d in [c, Down::Line(b"{}\n".to_vec()), Down::End] {
            assert_eq!(Down::decode(&d.encode()), Some(d));
        }
    }

    #[test]
    fn ids_and_nonces_read_back() {
        let n: [u8; NONCE] = random().unwrap();
        assert_eq!(nonce_of(&hex(&n)), Some(n));
        assert_eq!(nonce_of("zz"), None);
        assert_eq!(nonce_of(&"é".repeat(16)), None);
        assert!(valid_sid(&hex(&random::<16>().unwrap())));
        for bad in ["", "AB", &"a".repeat(31), &"g".repeat(32), "../../x"] {
            assert!(!valid_sid(bad), "{bad}");
        }
    }
}
