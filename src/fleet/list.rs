//! `adrive fleet`: every vehicle on the fleet's network, from what Zenoh already
//! knows — the liveliness tokens say who is there (and, withdrawn, who went away: the
//! vehicle stopped, or the network to it broke, within its session's lease), the state
//! each publishes says how it is. Once, after a window for discovery (a list, or
//! `--json`: an array of entries); or `--watch`: a line for each vehicle that comes,
//! changes ([`Change`]) or goes.

use super::keys;
use super::state::Change;
use crate::config::ros2::Mode;
use crate::snapshot::Snapshot;
use serde::Serialize;
use std::collections::BTreeMap;
use std::io::Write as _;
use std::sync::atomic::{AtomicBool, Ordering::Relaxed};
use std::time::{Duration, Instant};
use zenoh::sample::SampleKind;
use zenoh::Wait;

/// What `adrive fleet` was asked.
#[derive(Clone, Debug)]
pub(crate) struct Options {
    /// Routers or peers to connect to.
    pub connect: Vec<String>,
    /// How long to listen before the list (without `watch`).
    pub wait: Duration,
    /// A line per change until stopped, instead of one list.
    pub watch: bool,
    pub json: bool,
}

/// Whether a vehicle is there.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub(crate) enum Status {
    /// Its token is on the network.
    Live,
    /// Its token was withdrawn: it stopped, or the network to it broke.
    Gone,
}

/// What happened to a vehicle, for `--watch`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub(crate) enum Event {
    Live,
    State,
    Gone,
}

/// One vehicle as `adrive fleet --json` prints it: the fleet's view of it (there or
/// gone, how old its last state is) and that state, the snapshot's head as it
/// publishes it.
#[derive(Serialize)]
pub(crate) struct Entry<'a> {
    #[serde(skip_serializing_if = "Option::is_none")]
    event: Option<Event>,
    pub id: &'a str,
    pub status: Status,
    /// Since its last state arrived, ms (null: none yet).
    pub state_age_ms: Option<f64>,
    /// The last round trip to it and back, ms (null: none answered).
    pub rtt_ms: Option<f64>,
    pub state: Option<&'a Snapshot>,
}

/// One vehicle seen.
pub(crate) struct Seen {
    status: Status,
    state: Option<Snapshot>,
    at: Option<Instant>,
    /// The last round trip measured to it.
    rtt: Option<Duration>,
    /// The last change a `--watch` line told.
    told: Option<Change>,
}

impl Seen {
    fn entry<'a>(&'a self, id: &'a str, event: Option<Event>, now: Instant) -> Entry<'a> {
        Entry {
            event,
            id,
            status: self.status,
            state_age_ms: self.at.map(|at| now.duration_since(at).as_secs_f64() * 1e3),
            rtt_ms: self.rtt.map(|d| d.as_secs_f64() * 1e3),
            state: self.state.as_ref(),
        }
    }
}

enum Heard {
    Token(String, bool),
    State(String, Vec<u8>, Instant),
    /// A vehicle's round trip, measured.
    Rtt(String, Duration),
}

/// The fleet as a session hears it: its tokens and states as they come (and, when
/// asked, the round trips, measured every [`PING_EVERY`] by `fleet/ping`), taken in
/// by [`Watching::hear`].
pub(crate) struct Watching {
    session: zenoh::Session,
    rx: crossbeam_channel::Receiver<Heard>,
    tx: crossbeam_channel::Sender<Heard>,
    /// Every vehicle heard of, by id.
    pub fleet: BTreeMap<String, Seen>,
    subscribers: Vec<zenoh::pubsub::Subscriber<()>>,
    /// Stops the pings.
    pinging: Option<(std::sync::Arc<AtomicBool>, std::thread::JoinHandle<()>)>,
}

impl Watching {
    /// Join the fleet's network through `connect` and listen.
    pub(crate) fn start(connect: &[String]) -> anyhow::Result<Watching> {
        let session = super::open(&super::Network {
            mode: Mode::Client,
            connect,
            listen: &[],
            multicast_scouting: false,
        })?;
        let (tx, rx) = crossbeam_channel::unbounded();
        let t = tx.clone();
        let tokens = session
            .liveliness()
            .declare_subscriber(keys::TOKENS)
            .history(true)
            .callback(move |s| {
                let alive = s.kind() == SampleKind::Put;
                let _ = t.send(Heard::Token(s.key_expr().as_str().to_string(), alive));
            })
            .wait()
            .map_err(|e| anyhow::anyhow!("fleet: liveliness subscription: {e}"))?;
        let t = tx.clone();
        let states = session
            .declare_subscriber(keys::STATES)
            .callback(move |s| {
                let at = Instant::now();
                let _ = t.send(Heard::State(
                    s.key_expr().as_str().to_string(),
                    s.payload().to_bytes().into_owned(),
                    at,
                ));
            })
            .wait()
            .map_err(|e| anyhow::anyhow!("fleet: state subscription: {e}"))?;
        Ok(Watching {
            session,
            rx,
            tx,
            fleet: BTreeMap::new(),
            subscribers: vec![tokens, states],
            pinging: None,
        })
    }

    /// Measure every vehicle's round trip now, and then every [`PING_EVERY`].
    pub(crate) fn ping_every(&mut self) -> std::io::Result<()> {
        let stop = std::sync::Arc::new(AtomicBool::new(false));
        let (s, session, tx) = (stop.clone(), self.session.clone(), self.tx.clone());
        let h = std::thread::Builder::new()
            .name("fleet/ping".into())
            .spawn(move || {
                while !s.load(Relaxed) {
                    for (id, rtt) in ping(&session) {
                        let _ = tx.send(Heard::Rtt(id, rtt));
                    }
                    let until = Instant::now() + PING_EVERY;
                    while !s.load(Relaxed) && Instant::now() < until {
                        std::thread::sleep(Duration::from_millis(50));
                    }
                }
            })?;
        self.pinging = Some((stop, h));
        Ok(())
    }

    /// Take in what was heard, waiting at most `within` for the first; the vehicle and
    /// the event worth a `--watch` line, if one came.
    fn hear(&mut self, within: Duration) -> Option<(String, Event)> {
        let heard = self.rx.recv_timeout(within).ok()?;
        hear(&mut self.fleet, heard)
    }

    /// Take in everything heard so far.
    pub(crate) fn hear_all(&mut self) {
        while let Ok(h) = self.rx.try_recv() {
            hear(&mut self.fleet, h);
        }
    }

    /// Every vehicle as `--json` prints it.
    pub(crate) fn entries(&self, now: Instant) -> Vec<Entry<'_>> {
        self.fleet
            .iter()
            .map(|(id, s)| s.entry(id, None, now))
            .collect()
    }

    /// Stop listening and close the session.
    pub(crate) fn close(mut self) {
        if let Some((stop, h)) = self.pinging.take() {
            stop.store(true, Relaxed);
            let _ = h.join();
        }
        self.subscribers.clear();
        let _ = self.session.close().wait();
    }
}

/// Run `adrive fleet`; the process status.
pub(crate) fn run(opts: &Options, stop: &AtomicBool) -> anyhow::Result<i32> {
    let mut w = Watching::start(&opts.connect)?;
    if opts.watch {
        w.ping_every()?;
    }
    let mut out = std::io::stdout().lock();
    let end = Instant::now() + opts.wait;
    let tick = Duration::from_millis(100);
    while !stop.load(Relaxed) {
        let left = if opts.watch {
            tick
        } else {
            end.saturating_duration_since(Instant::now())
        };
        if !opts.watch && left.is_zero() {
            break;
        }
        let Some((id, event)) = w.hear(left.min(tick)) else {
            continue;
        };
        if opts.watch {
            let seen = &w.fleet[&id];
            let line = if opts.json {
                serde_json::to_string(&seen.entry(&id, Some(event), Instant::now()))?
            } else {
                watch_line(&id, event, seen)
            };
            writeln!(out, "{line}")?;
            out.flush()?;
        }
    }
    if !opts.watch {
        // Once: the round trips measured now, for the list.
        for (id, rtt) in ping(&w.session) {
            hear(&mut w.fleet, Heard::Rtt(id, rtt));
        }
        let now = Instant::now();
        let entries = w.entries(now);
        if opts.json {
            writeln!(out, "{}", serde_json::to_string(&entries)?)?;
        } else {
            write!(out, "{}", table(&entries))?;
        }
    }
    w.close();
    Ok(0)
}

/// How often the round trips are measured.
const PING_EVERY: Duration = Duration::from_secs(2);
/// How long a ping is waited for.
const PING_WITHIN: Duration = Duration::from_secs(1);

/// Ask every vehicle at once for a ping: the round trip of each that answers.
fn ping(session: &zenoh::Session) -> Vec<(String, Duration)> {
    let asked = Instant::now();
    let replies = match session.get(keys::PINGS).timeout(PING_WITHIN).wait() {
        Ok(r) => r,
        Err(e) => {
            tracing::debug!("fleet: ping: {e}");
            return Vec::new();
        }
    };
    let mut out = Vec::new();
    while let Ok(reply) = replies.recv() {
        let took = asked.elapsed();
        if let Ok(sample) = reply.result() {
            if let Some(id) = keys::id_of_ping(sample.key_expr().as_str()) {
                out.push((id.to_string(), took));
            }
        }
    }
    out
}

/// Take in what was heard; the vehicle and the event worth a `--watch` line, if any.
fn hear(fleet: &mut BTreeMap<String, Seen>, heard: Heard) -> Option<(String, Event)> {
    match heard {
        Heard::Token(key, alive) => {
            let id = keys::id_of_token(&key)?.to_string();
            let status = if alive { Status::Live } else { Status::Gone };
            let seen = fleet.entry(id.clone()).or_insert(Seen {
                status,
                state: None,
                at: None,
                rtt: None,
                told: None,
            });
            let was = seen.status;
            seen.status = status;
            match (alive, was) {
                (true, _) => {
                    seen.told = None;
                    Some((id, Event::Live))
                }
                (false, Status::Live) => Some((id, Event::Gone)),
                (false, Status::Gone) => None,
            }
        }
        Heard::State(key, bytes, at) => {
            let id = keys::id_of_state(&key)?;
            // A state from a vehicle not (or no longer) announced is not shown as if
            // it were there.
            let seen = fleet.get_mut(id).filter(|s| s.status == Status::Live)?;
            let snap: Snapshot = match serde_json::from_slice(&bytes) {
                Ok(s) => s,
                Err(e) => {
                    tracing::debug!("fleet: {id}'s state does not read: {e}");
                    return None;
                }
            };
            let change = Change::of(&snap);
            seen.state = Some(snap);
            seen.at = Some(at);
            if seen.told.as_ref() == Some(&change) {
                return None;
            }
            seen.told = Some(change);
            Some((id.to_string(), Event::State))
        }
        Heard::Rtt(id, rtt) => {
            if let Some(seen) = fleet.get_mut(&id) {
                seen.rtt = Some(rtt);
            }
            None
        }
    }
}

/// Who commands, in words.
fn commander(s: &Snapshot) -> &str {
    s.gate.commander.as_deref().unwrap_or("nobody")
}

/// The faults, in words.
fn faults(s: &Snapshot) -> String {
    if s.supervisor.faults.is_empty() {
        return "none".into();
    }
    let all: Vec<String> = s.supervisor.faults.iter().map(|f| f.describe()).collect();
    all.join("; ")
}

/// A `--watch` line without `--json`.
fn watch_line(id: &str, event: Event, seen: &Seen) -> String {
    match (event, &seen.state) {
        (Event::Live, _) => format!("{id} live"),
        (Event::Gone, _) => {
            format!("{id} gone: it left the network (it stopped, or the network to it broke)")
        }
        (Event::State, None) => format!("{id} live"),
        (Event::State, Some(s)) => format!(
            "{id} {}; commanded by {}; faults: {}",
            s.gate.reason,
            commander(s),
            faults(s)
        ),
    }
}

/// The list's columns.
pub(crate) const HEAD: [&str; 8] = [
    "ID",
    "STATUS",
    "ENGAGED",
    "WHY",
    "COMMANDER",
    "FAULTS",
    "STATE AGE",
    "RTT",
];

/// One vehicle's row of the list.
pub(crate) fn cells(e: &Entry<'_>) -> [String; 8] {
    let status = match e.status {
        Status::Live => "live",
        Status::Gone => "gone",
    };
    let age = e
        .state_age_ms
        .map_or("-".into(), |ms| format!("{:.1} s", ms / 1e3));
    let rtt = e.rtt_ms.map_or("-".into(), |ms| format!("{ms:.1} ms"));
    match e.state {
        Some(s) => [
            e.id.to_string(),
            status.into(),
            if s.gate.engaged { "yes" } else { "no" }.into(),
            s.gate.cause.why(),
            commander(s).into(),
            faults(s),
            age,
            rtt,
        ],
        None => [
            e.id.to_string(),
            status.into(),
            "-".into(),
            "no state yet".into(),
            "-".into(),
            "-".into(),
            age,
            rtt,
        ],
    }
}

/// The list without `--json`: a row per vehicle.
fn table(entries: &[Entry<'_>]) -> String {
    if entries.is_empty() {
        return "no vehicle on the network\n".into();
    }
    let head = HEAD;
    let rows: Vec<[String; 8]> = entries.iter().map(cells).collect();
    let mut width = head.map(str::len);
    for r in &rows {
        for (w, c) in width.iter_mut().zip(r) {
            *w = (*w).max(c.chars().count());
        }
    }
    let mut out = String::new();
    let mut line = |cells: &[&str]| {
        let mut l = String::new();
        for (i, c) in cells.iter().enumerate() {
            if i + 1 == cells.len() {
                l.push_str(c);
            } else {
                l.push_str(&format!("{c:<w$}  ", w = width[i]));
            }
        }
        out.push_str(l.trim_end());
        out.push('\n');
    };
    line(&head);
    for r in &rows {
        line(&r.each_ref().map(String::as_str));
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn state(engaged: bool) -> Vec<u8> {
        let mut s = Snapshot::default();
        s.gate.engaged = engaged;
        serde_json::to_vec(&s).unwrap()
    }

    #[test]
    fn a_vehicle_comes_changes_and_goes_and_only_changes_are_told() {
        let mut fleet = BTreeMap::new();
        let now = Instant::now();
        let token = |alive| Heard::Token("adrive/car1".into(), alive);
        let st = |e| Heard::State("adrive/car1/state".into(), state(e), now);
        assert_eq!(
            hear(&mut fleet, st(false)),
            None,
            "a state before its token"
        );
        assert_eq!(
            hear(&mut fleet, token(true)),
            Some(("car1".into(), Event::Live))
        );
        assert_eq!(
            hear(&mut fleet, st(false)),
            Some(("car1".into(), Event::State))
        );
        assert_eq!(hear(&mut fleet, st(false)), None, "the same state again");
        assert_eq!(
            hear(&mut fleet, st(true)),
            Some(("car1".into(), Event::State))
        );
        assert_eq!(
            hear(&mut fleet, token(false)),
            Some(("car1".into(), Event::Gone))
        );
        assert_eq!(hear(&mut fleet, st(true)), None, "a state after it went");
        assert_eq!(fleet["car1"].status, Status::Gone);
        assert_eq!(
            hear(&mut fleet, Heard::Token("adrive/car1/state".into(), true)),
            None,
            "not a vehicle's token"
        );
    }

    #[test]
    fn the_list_has_a_row_per_vehicle() {
        let mut fleet = BTreeMap::new();
        let now = Instant::now();
        hear(&mut fleet, Heard::Token("adrive/car2".into(), true));
        hear(&mut fleet, Heard::Token("adrive/car1".into(), true));
        hear(
            &mut fleet,
            Heard::State("adrive/car1/state".into(), state(false), now),
        );
        fleet.get_mut("car1").unwrap().rtt = Some(Duration::from_micros(1250));
        let entries: Vec<Entry<'_>> = fleet.iter().map(|(id, s)| s.entry(id, None, now)).collect();
        let t = table(&entries);
        let lines: Vec<&str> = t.lines().collect();
        assert!(lines[0].starts_with("ID    STATUS  ENGAGED"), "{t}");
        assert!(
            lines[1].starts_with("car1  live    no       not engaged yet  nobody"),
            "{t}"
        );
        assert!(lines[1].ends_with("0.0 s      1.2 ms"), "{t}");
        assert!(
            lines[2].starts_with("car2  live    -        no state yet"),
            "{t}"
        );
        assert!(lines[2].ends_with('-'), "{t}");
        assert_eq!(table(&[]), "no vehicle on the network\n");
    }
}
