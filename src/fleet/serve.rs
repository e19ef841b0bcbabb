//! The vehicle's end of the fleet's links ([`super::link`]): the thread `fleet/links`
//! takes each link that opens to this vehicle — only one whose liveliness token is
//! there, since that token is how its going is known — to the control socket's server
//! as a client ([`Door`]), with every rule a local client meets; and a thread per link,
//! `fleet/link/N`, sends what the server answers back down it.
//!
//! A link commands only if this vehicle's `[fleet]` allows command from the fleet
//! and the link proved the vehicle's key; until then, and otherwise, it watches, and
//! what it asks of the vehicle is refused with the reason ([`Permit`]). A message on a
//! link that proved the key is taken only signed with it and numbered after the last
//! one taken: one that is not is dropped and counted in the log.
//!
//! When a link's token is withdrawn — the process at the other end stopped or was
//! killed, or the network to it broke (within Zenoh's lease) — its connection to the
//! server is closed: a console that commanded the engaged vehicle was its own
//! watchdog, and the vehicle goes to the safe state as for a local console gone.

use super::keys;
use super::link::{hex, random, valid_sid, Challenge, Down, Up, CLOSE, NONCE};
use crate::net::auth::Auth;
use crate::socket::server::{Door, Linked, Permit};
use crate::threads::{Group, StopSignal, Threads};
use crossbeam_channel::{Receiver, RecvTimeoutError};
use std::collections::{HashMap, HashSet};
use std::io::{BufRead, BufReader, Write};
use std::os::unix::net::UnixStream;
use std::sync::Arc;
use std::time::{Duration, Instant};
use zenoh::qos::CongestionControl;
use zenoh::sample::SampleKind;
use zenoh::Wait;

/// How long an opening waits for its link's token (which may arrive after it).
const TOKEN_WITHIN: Duration = Duration::from_secs(3);
/// How long a write into a link's connection may block before the link is dropped.
const WRITE_WITHIN: Duration = Duration::from_secs(1);

/// Who may command over the fleet.
pub(crate) struct Rule {
    /// The vehicle's key, if it has one.
    pub key: Option<Auth>,
    /// Its `[fleet]` allows command from the fleet.
    pub command: bool,
}

impl Rule {
    /// Why a link that has not proved the key may not command.
    fn before_proof(&self, id: &str) -> String {
        if self.command {
            format!(
                "over the fleet, {id} takes commands only from a link that proves its key \
                 (--key FILE); this one watches"
            )
        } else {
            self.refused(id)
        }
    }

    fn refused(&self, id: &str) -> String {
        format!(
            "{id} takes no command from the fleet (its [fleet] command = false); this link \
             watches"
        )
    }
}

/// What `fleet/links` hears.
enum Heard {
    Up(String, Vec<u8>),
    Token(String, bool),
}

/// The subscriptions that feed `fleet/links`; they live as long as the member.
pub(crate) struct Subscriptions {
    _up: zenoh::pubsub::Subscriber<()>,
    _tokens: zenoh::pubsub::Subscriber<()>,
}

/// Start taking links to vehicle `id` to the server behind `door`.
pub(crate) fn start(
    session: &zenoh::Session,
    id: &str,
    door: Door,
    rule: Rule,
    threads: &mut Group,
) -> anyhow::Result<Subscriptions> {
    let (tx, rx) = crossbeam_channel::unbounded();
    let t = tx.clone();
    let who = id.to_string();
    let up = session
        .declare_subscriber(keys::ups(id))
        .callback(move |s| {
            if let Some(sid) = keys::sid_of(&who, s.key_expr().as_str(), "/up") {
                let _ = t.send(Heard::Up(sid.into(), s.payload().to_bytes().into_owned()));
            }
        })
        .wait()
        .map_err(|e| anyhow::anyhow!("fleet: subscribing to links: {e}"))?;
    let who = id.to_string();
    let tokens = session
        .liveliness()
        .declare_subscriber(keys::links(id))
        .history(true)
        .callback(move |s| {
            if let Some(sid) = keys::sid_of(&who, s.key_expr().as_str(), "") {
                let _ = tx.send(Heard::Token(sid.into(), s.kind() == SampleKind::Put));
            }
        })
        .wait()
        .map_err(|e| anyhow::anyhow!("fleet: watching links: {e}"))?;
    let mut links = Links {
        session: session.clone(),
        id: id.to_string(),
        door,
        rule,
        live: HashSet::new(),
        waiting: HashMap::new(),
        open: HashMap::new(),
        threads: Threads::default(),
    };
    threads.spawn("fleet/links", move |stop| links.run(&rx, stop))?;
    Ok(Subscriptions {
        _up: up,
        _tokens: tokens,
    })
}

/// One open link.
struct Link {
    /// This end of its connection to the server.
    end: UnixStream,
    nonce: [u8; NONCE],
    permit: Arc<Permit>,
    /// It proved the key: every message must be signed.
    keyed: bool,
    /// The last message taken.
    seq: u64,
    /// Messages dropped (not signed, or out of order).
    dropped: u64,
    /// Why it ended, for the server to say.
    lost: Arc<parking_lot::Mutex<Option<String>>>,
}

/// `fleet/links`' state.
struct Links {
    session: zenoh::Session,
    id: String,
    door: Door,
    rule: Rule,
    /// Links whose token is there.
    live: HashSet<String>,
    /// Openings waiting for their token, since when.
    waiting: HashMap<String, Instant>,
    open: HashMap<String, Link>,
    /// Each link's `fleet/link/N`.
    threads: Threads,
}

impl Links {
    fn run(&mut self, rx: &Receiver<Heard>, stop: &StopSignal) {
        while !stop.is_stopped() {
            match rx.recv_timeout(Duration::from_millis(100)) {
                Ok(Heard::Up(sid, bytes)) => self.up(&sid, &bytes),
                Ok(Heard::Token(sid, true)) => {
                    self.live.insert(sid.clone());
                    if self.waiting.remove(&sid).is_some() {
                        self.open(&sid);
                    }
                }
                Ok(Heard::Token(sid, false)) => {
                    self.live.remove(&sid);
                    self.close(
                        &sid,
                        Some(
                            "its token was withdrawn: the process at the other end ended, or \
                             the network to it broke",
                        ),
                    );
                }
                Err(RecvTimeoutError::Timeout) => {}
                Err(RecvTimeoutError::Disconnected) => break,
            }
            let now = Instant::now();
            self.waiting
                .retain(|_, since| now.duration_since(*since) < TOKEN_WITHIN);
        }
        for sid in self.open.keys().cloned().collect::<Vec<_>>() {
            self.close(&sid, Some("the vehicle is leaving the fleet"));
        }
        let threads = std::mem::take(&mut self.threads);
        let stuck = threads.join(Instant::now() + Duration::from_secs(1));
        if !stuck.is_empty() {
            tracing::warn!("fleet: link threads did not stop: {stuck:?}");
        }
    }

    fn up(&mut self, sid: &str, bytes: &[u8]) {
        let Some(m) = Up::decode(bytes).filter(|_| valid_sid(sid)) else {
            return tracing::debug!("fleet: link {sid}: a message that does not read");
        };
        if m.seq == 0 {
            if self.open.contains_key(sid) {
                return;
            }
            if self.live.contains(sid) {
                self.open(sid);
            } else {
                self.waiting.insert(sid.to_string(), Instant::now());
            }
            return;
        }
        let Some(link) = self.open.get_mut(sid) else {
            return;
        };
        let on = (self.id.as_str(), sid, &link.nonce);
        // The key's proof: the link may command (if the vehicle lets the fleet).
        if m.seq == 1 && m.line.is_empty() && !link.keyed {
            link.seq = 1;
            match &self.rule.key {
                Some(key) if m.holds(key, on) => {
                    link.keyed = true;
                    if self.rule.command {
                        link.permit.grant();
                        tracing::info!(
                            "fleet: link {sid} proved {}'s key: it may command",
                            self.id
                        );
                    }
                }
                _ => {
                    link.permit.deny(format!(
                        "this link's key is not {}'s: it watches, and may not command",
                        self.id
                    ));
                    tracing::warn!("fleet: link {sid} gave a key that is not {}'s", self.id);
                }
            }
            return;
        }
        let signed = match &self.rule.key {
            Some(key) if link.keyed => m.holds(key, on),
            _ => !link.keyed,
        };
        if !signed || m.seq <= link.seq {
            link.dropped += 1;
            return tracing::warn!(
                "fleet: link {sid}: a message {} dropped ({} so far)",
                if signed {
                    "out of order"
                } else {
                    "not signed with the key"
                },
                link.dropped
            );
        }
        link.seq = m.seq;
        if m.seq == CLOSE {
            // Its client closed its end, as a local client closes its connection.
            return self.close(sid, None);
        }
        if (&link.end).write_all(m.line).is_err() {
            self.close(sid, Some("its connection did not take what it sent"));
        }
    }

    /// Open link `sid`: its connection to the server, its thread, its challenge.
    fn open(&mut self, sid: &str) {
        if let Err(e) = self.try_open(sid) {
            tracing::warn!("fleet: link {sid} could not be opened: {e}");
        }
    }

    fn try_open(&mut self, sid: &str) -> anyhow::Result<()> {
        let nonce: [u8; NONCE] = random()?;
        let down = self
            .session
            .declare_publisher(keys::down(&self.id, sid))
            .congestion_control(CongestionControl::Block)
            .express(true)
            .wait()
            .map_err(|e| anyhow::anyhow!("{e}"))?;
        let challenge = Down::Challenge(Challenge { nonce: hex(&nonce) });
        down.put(challenge.encode())
            .wait()
            .map_err(|e| anyhow::anyhow!("{e}"))?;
        let (end, theirs) = UnixStream::pair()?;
        end.set_write_timeout(Some(WRITE_WITHIN))?;
        let permit = Arc::new(Permit::watch_only(self.rule.before_proof(&self.id)));
        let lost = Arc::new(parking_lot::Mutex::new(None));
        self.door.serve(
            theirs,
            Linked {
                from: format!("fleet link {sid}"),
                permit: permit.clone(),
                lost: lost.clone(),
            },
        )?;
        let reader = end.try_clone()?;
        self.threads.reap();
        self.threads
            .spawn(format!("fleet/link/{}", &sid[..8]), move || {
                carry_down(reader, &down);
            })?;
        self.open.insert(
            sid.to_string(),
            Link {
                end,
                nonce,
                permit,
                keyed: false,
                seq: 0,
                dropped: 0,
                lost,
            },
        );
        tracing::info!("fleet: link {sid} opened to {}", self.id);
        Ok(())
    }

    /// Close link `sid`'s connection (the server sees its client gone): lost, for
    /// `why`, or (`None`) closed by its client.
    fn close(&mut self, sid: &str, why: Option<&str>) {
        if let Some(link) = self.open.remove(sid) {
            match why {
                Some(why) => {
                    tracing::info!("fleet: link {sid} lost: {why}");
                    *link.lost.lock() = Some(format!("lost its link over the fleet ({why})"));
                }
                None => tracing::info!("fleet: link {sid} closed by its client"),
            }
            let _ = link.end.shutdown(std::net::Shutdown::Both);
        }
    }
}

/// What the server sends a link's client, down the link, until it closes.
fn carry_down(end: UnixStream, down: &zenoh::pubsub::Publisher<'static>) {
    let mut reader = BufReader::new(end);
    let mut line = Vec::new();
    loop {
        line.clear();
        match reader.read_until(b'\n', &mut line) {
            Ok(0) | Err(_) => break,
            Ok(_) => {}
        }
        if down.put(Down::Line(line.clone()).encode()).wait().is_err() {
            break;
        }
    }
    let _ = down.put(Down::End.encode()).wait();
}
