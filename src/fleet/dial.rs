//! The asking end of a link ([`super::link`]): `adrive attach --vehicle ID` and
//! `adrive ctl --vehicle ID` reach a vehicle of the fleet through a [`Dialer`], which
//! hands the socket's clients one end of a local stream pair and carries the other
//! over Zenoh, so that they speak to the vehicle as they do to a local socket.
//!
//! Two threads carry a link: `fleet/link/up` reads the client's lines, signs them
//! with the key (if one was given) and sends them; when the client closes its end, it
//! withdraws the link's token and closes the session. `fleet/link/down` writes what
//! the vehicle sends into the client's end, and closes it when the vehicle ends the
//! link or leaves the network. A process that is killed, or whose network breaks,
//! loses its session, and with it the token the vehicle watches.

use super::keys;
use super::link::{hex, nonce_of, random, Down, Up, CLOSE, NONCE};
use crate::config::ros2::Mode;
use crate::net::auth::Auth;
use crate::socket::client::{ClientError, Dial, REPLY_WITHIN};
use crossbeam_channel::{Receiver, RecvTimeoutError};
use std::io::{BufRead, BufReader, Write};
use std::os::unix::net::UnixStream;
use std::time::Duration;
use zenoh::qos::CongestionControl;
use zenoh::sample::SampleKind;
use zenoh::Wait;

/// How long the vehicle has to answer an opening.
const CHALLENGE_WITHIN: Duration = Duration::from_secs(5);
/// How long a closing link waits for the vehicle to take its close.
const CLOSE_WITHIN: Duration = Duration::from_secs(1);

/// A connection to vehicle `id`'s control socket over the fleet, through `connect`,
/// proving `key` if given: the stream `adrive attach --vehicle` and `adrive ctl
/// --vehicle` speak the socket's protocol on (for tools, and the benchmark).
pub fn connect(connect: &[String], id: &str, key: Option<Auth>) -> Result<UnixStream, String> {
    let d = Dialer {
        connect: connect.to_vec(),
        id: id.to_string(),
        key,
        links: parking_lot::Mutex::default(),
    };
    d.dial().map_err(|e| e.to_string())
}

/// The way to vehicle `id` of the fleet, through `connect`, proving `key` if given.
pub(crate) struct Dialer {
    pub connect: Vec<String>,
    pub id: String,
    pub key: Option<Auth>,
    /// Each link's `fleet/link/up`, which ends once its link has closed.
    pub links: parking_lot::Mutex<Vec<std::thread::JoinHandle<()>>>,
}

/// What the link's down thread hears.
enum Heard {
    Down(Vec<u8>),
    /// The vehicle's token was withdrawn.
    VehicleGone,
}

impl Dialer {
    fn session(&self) -> Result<zenoh::Session, ClientError> {
        super::open(&super::Network {
            mode: Mode::Client,
            connect: &self.connect,
            listen: &[],
            multicast_scouting: false,
        })
        .map_err(|e| ClientError::Refused(e.to_string()))
    }

    /// Whether the vehicle is on the network now.
    fn there(&self, session: &zenoh::Session) -> Result<bool, ClientError> {
        let replies = session
            .liveliness()
            .get(keys::token(&self.id))
            .timeout(REPLY_WITHIN)
            .wait()
            .map_err(|e| ClientError::Refused(format!("fleet: asking for {}: {e}", self.id)))?;
        Ok(matches!(replies.recv(), Ok(r) if r.result().is_ok()))
    }

    fn absent(&self) -> ClientError {
        ClientError::Refused(format!(
            "no vehicle {} on the fleet's network (through {}; `adrive fleet` lists those there)",
            self.id,
            self.connect.join(", ")
        ))
    }
}

impl Dial for Dialer {
    fn dial(&self) -> Result<UnixStream, ClientError> {
        let session = self.session()?;
        let linked = self.link(&session);
        if linked.is_err() {
            let _ = session.close().wait();
        }
        linked
    }

    fn ended_without_word(&self, what: &str) -> String {
        let id = &self.id;
        match self.session().and_then(|s| {
            let there = self.there(&s);
            let _ = s.close().wait();
            there
        }) {
            Ok(true) => format!(
                "{id} closed this link without saying why ({what}); it is still on the fleet \
                 (`adrive fleet` shows it)"
            ),
            Ok(false) => format!("{id} left the fleet's network ({what})"),
            Err(e) => {
                format!("the link to {id} ended ({what}), and the fleet cannot be asked: {e}")
            }
        }
    }

    fn place(&self) -> String {
        format!(
            "{} on the fleet (through {})",
            self.id,
            self.connect.join(", ")
        )
    }
}

impl Dialer {
    /// Open a link on `session`: the client's end of it.
    fn link(&self, session: &zenoh::Session) -> Result<UnixStream, ClientError> {
        let refused = |what: &str, e: &dyn std::fmt::Display| {
            ClientError::Refused(format!("fleet: {what}: {e}"))
        };
        let id = self.id.as_str();
        if !self.there(session)? {
            return Err(self.absent());
        }
        let sid = hex(&random::<16>().map_err(|e| refused("a link id", &e))?);
        let (tx, rx) = crossbeam_channel::unbounded();
        let t = tx.clone();
        let down = session
            .declare_subscriber(keys::down(id, &sid))
            .callback(move |s| {
                let _ = t.send(Heard::Down(s.payload().to_bytes().into_owned()));
            })
            .wait()
            .map_err(|e| refused("subscribing", &e))?;
        let vehicle = session
            .liveliness()
            .declare_subscriber(keys::token(id))
            .callback(move |s| {
                if s.kind() == SampleKind::Delete {
                    let _ = tx.send(Heard::VehicleGone);
                }
            })
            .wait()
            .map_err(|e| refused("watching the vehicle", &e))?;
        let token = session
            .liveliness()
            .declare_token(keys::link(id, &sid))
            .wait()
            .map_err(|e| refused("the link's token", &e))?;
        let up = session
            .declare_publisher(keys::up(id, &sid))
            .congestion_control(CongestionControl::Block)
            .express(true)
            .wait()
            .map_err(|e| refused("publishing", &e))?;
        let put = |m: Up<'_>| {
            up.put(m.encode())
                .wait()
                .map_err(|e| refused("sending", &e))
        };
        put(Up::signed(None, (id, &sid, &[0; NONCE]), 0, b""))?;
        let nonce = challenge(&rx, id)?;
        let mut seq = 1;
        if let Some(key) = &self.key {
            put(Up::signed(Some(key), (id, &sid, &nonce), seq, b""))?;
            seq += 1;
        }
        let (mine, theirs) = UnixStream::pair().map_err(|e| refused("a stream pair", &e))?;
        let ends = (
            theirs.try_clone().map_err(|e| refused("a stream", &e))?,
            theirs,
        );
        let key = self.key.clone();
        let (id, s) = (self.id.clone(), session.clone());
        // Dropped when the vehicle has ended the link (or left).
        let (down_done, ended) = crossbeam_channel::bounded::<()>(0);
        std::thread::Builder::new()
            .name("fleet/link/down".into())
            .spawn(move || {
                carry_down(&rx, ends.0);
                drop(down_done);
            })
            .map_err(|e| refused("a thread", &e))?;
        let up_thread = std::thread::Builder::new()
            .name("fleet/link/up".into())
            .spawn(move || {
                let mut reader = BufReader::new(&ends.1);
                let mut line = Vec::new();
                loop {
                    line.clear();
                    match reader.read_until(b'\n', &mut line) {
                        Ok(0) | Err(_) => break,
                        Ok(_) => {}
                    }
                    let m = Up::signed(key.as_ref(), (&id, &sid, &nonce), seq, &line);
                    seq += 1;
                    if up.put(m.encode()).wait().is_err() {
                        break;
                    }
                }
                // The client closed its end: the link goes (said, so that the vehicle
                // knows a console left rather than lost), and its token with it.
                let bye = Up::signed(key.as_ref(), (&id, &sid, &nonce), CLOSE, b"");
                if up.put(bye.encode()).wait().is_ok() {
                    // The token goes once the vehicle has taken it (its end follows
                    // it down): Zenoh carries a token's withdrawal ahead of data.
                    let _ = ended.recv_timeout(CLOSE_WITHIN);
                }
                let _ = ends.1.shutdown(std::net::Shutdown::Both);
                drop((down, vehicle));
                let _ = token.undeclare().wait();
                let _ = s.close().wait();
            })
            .map_err(|e| refused("a thread", &e))?;
        self.links.lock().push(up_thread);
        Ok(mine)
    }
}

/// The vehicle's nonce, from its answer to the opening.
fn challenge(rx: &Receiver<Heard>, id: &str) -> Result<[u8; NONCE], ClientError> {
    loop {
        match rx.recv_timeout(CHALLENGE_WITHIN) {
            Ok(Heard::Down(bytes)) => {
                if let Some(Down::Challenge(c)) = Down::decode(&bytes) {
                    return nonce_of(&c.nonce).ok_or_else(|| {
                        ClientError::Refused(format!(
                            "{id} answered a challenge that does not read"
                        ))
                    });
                }
            }
            Ok(Heard::VehicleGone) => {
                return Err(ClientError::Refused(format!(
                    "{id} left the fleet's network as the link opened"
                )))
            }
            Err(RecvTimeoutError::Timeout) => return Err(ClientError::NoReply(CHALLENGE_WITHIN)),
            Err(RecvTimeoutError::Disconnected) => {
                return Err(ClientError::Refused("fleet: the session closed".into()))
            }
        }
    }
}

/// What the vehicle sends, into the client's end, until the vehicle ends the link or
/// leaves — also once the client has closed its end (what comes then is dropped):
/// its end is what the closing waits for.
fn carry_down(rx: &Receiver<Heard>, mut end: UnixStream) {
    let mut open = true;
    while let Ok(heard) = rx.recv() {
        match heard {
            Heard::Down(bytes) => match Down::decode(&bytes) {
                Some(Down::Line(line)) => {
                    open = open && end.write_all(&line).is_ok();
                }
                Some(Down::End) => break,
                // Another challenge, or what is not a message: nothing to carry.
                Some(Down::Challenge(_)) | None => {}
            },
            Heard::VehicleGone => break,
        }
    }
    let _ = end.shutdown(std::net::Shutdown::Both);
}
