//! The live view: `--foxglove [ADDR]` serves the run to Foxglove and Lichtblick over
//! the Foxglove WebSocket protocol ([`proto`]), with the same channels, messages and
//! JSON Schemas as a recording ([`crate::record::message`]), so a plot of
//! `/steer/command.value` against `/steer/reading.position` works the same live and
//! afterwards.
//!
//! It never slows the vehicle. One thread (`foxglove/serve`) reads the vehicle's
//! [`Tap`](crate::vehicle::tap::Tap) as a reader of its own, beside the recorder: the
//! engine only ever `try_send`s into a bounded channel. The thread polls every
//! [`TURN`] (it never parks on the channel, so a send never has to wake it), keeps the
//! latest message of each channel (a viewer that subscribes mid-run gets it at once),
//! and hands each message to every viewer subscribed, through a bounded queue of
//! [`QUEUE`] messages per viewer over a non-blocking socket. A viewer that reads too
//! slowly loses its oldest messages, counted and shown in the network part of the
//! snapshot; nobody else waits for it.
//!
//! A synchronous `tungstenite` on one std thread, not the `foxglove` crate: the
//! protocol is small, and the crate brings a multi-threaded tokio runtime (see
//! docs/foxglove.md for what was measured). Read-only: no client publishing, services
//! or parameters; a client that asks is told so.

pub(crate) mod proto;

use crate::record::message::{self, Clock, Topic};
use crate::snapshot::{LiveView, ViewerView};
use crate::threads::{Group, StopSignal};
use crate::vehicle::tap::{Event, ReaderId, CAPACITY};
use crate::vehicle::Vehicle;
use crossbeam_channel::Receiver;
use parking_lot::Mutex;
use std::collections::{HashMap, VecDeque};
use std::io;
use std::net::{SocketAddr, TcpListener, TcpStream};
use std::sync::Arc;
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};
use tungstenite::handshake::server::{Callback, ErrorResponse, Request, Response, ServerHandshake};
use tungstenite::handshake::{HandshakeError, MidHandshake};
use tungstenite::http::{HeaderValue, StatusCode};
use tungstenite::{Message, WebSocket};

/// Where `--foxglove` listens when given no address: loopback, Foxglove's usual port.
pub(crate) const DEFAULT_ADDR: &str = "127.0.0.1:8765";
/// How often the thread takes what the tap holds (and at most how long it sleeps).
pub(crate) const TURN: Duration = Duration::from_millis(20);
/// Messages a viewer's queue holds; past it the oldest is dropped (and counted).
pub(crate) const QUEUE: usize = 1024;
/// Viewers served at once; one more is refused.
pub(crate) const MAX_VIEWERS: usize = 16;
/// What a viewer's socket buffers in the kernel: a stalled viewer costs at most this
/// and its queue.
const SEND_BUFFER: usize = 256 * 1024;
/// Client messages read from one viewer in one turn, and `status` replies it may have
/// waiting: a client that floods is served no faster, and costs no more memory.
const CLIENT_MESSAGES: usize = 64;
/// A handshake not done by then is dropped.
const HANDSHAKE: Duration = Duration::from_secs(5);
/// The WebSocket subprotocol header.
const PROTOCOL_HEADER: &str = "Sec-WebSocket-Protocol";

/// The running live view.
pub(crate) struct Foxglove {
    /// Dropped without [`Foxglove::shutdown`] (a panic unwinding): told to stop.
    threads: Group,
}

impl Foxglove {
    /// Listen on `addr` (port 0: any free port; the log says which) and serve
    /// what `vehicle`'s tap sees. An address that cannot be bound is an error here,
    /// before anything is driven.
    pub(crate) fn start(vehicle: &Arc<Vehicle>, addr: SocketAddr) -> io::Result<Foxglove> {
        let listener = TcpListener::bind(addr).map_err(|e| {
            let why = crate::config::network::bind_error(
                "--foxglove",
                addr,
                "--foxglove is where this adrive serves the live view: an address of this host",
                &e,
            );
            io::Error::new(e.kind(), why)
        })?;
        listener.set_nonblocking(true)?;
        let addr = listener.local_addr()?;
        let tapped = vehicle
            .tap()
            .open(false)
            .ok_or_else(|| io::Error::other("this vehicle's tap has no room for a live view"))?;
        let mut threads = Group::default();
        let v = vehicle.clone();
        threads.spawn("foxglove/serve", move |stop| {
            Server::new(v, listener, addr, tapped.rx, tapped.reader).run(stop)
        })?;
        tracing::info!("foxglove: live view at ws://{addr} (read-only)");
        Ok(Foxglove { threads })
    }
}

impl crate::threads::Shutdown for Foxglove {
    /// Close every viewer and stop; the names of threads that did not stop.
    fn shutdown(mut self, deadline: Duration) -> Vec<String> {
        self.threads.stop(Instant::now() + deadline)
    }
}

/// The handshake's callback: answer with the subprotocol the client offers, or refuse
/// with the names this server speaks (a viewer fails silently on a mismatch); when
/// [`MAX_VIEWERS`] are served already, refuse with 503 naming the limit.
struct Negotiate {
    chosen: Arc<Mutex<Option<&'static str>>>,
    full: bool,
}

/// What a viewer past [`MAX_VIEWERS`] is told.
fn full_answer() -> ErrorResponse {
    let mut e = ErrorResponse::new(Some(format!(
        "adrive's live view serves at most {MAX_VIEWERS} viewers at once; one must leave first\n"
    )));
    *e.status_mut() = StatusCode::SERVICE_UNAVAILABLE;
    e.headers_mut()
        .insert("Retry-After", HeaderValue::from_static("5"));
    e
}

impl Callback for Negotiate {
    fn on_request(self, req: &Request, mut resp: Response) -> Result<Response, ErrorResponse> {
        if self.full {
            return Err(full_answer());
        }
        let offered = req
            .headers()
            .get_all(PROTOCOL_HEADER)
            .iter()
            .filter_map(|v| v.to_str().ok());
        match proto::choose(offered) {
            Some(p) => {
                resp.headers_mut()
                    .insert(PROTOCOL_HEADER, HeaderValue::from_static(p));
                *self.chosen.lock() = Some(p);
                Ok(resp)
            }
            None => {
                let mut e = ErrorResponse::new(Some(format!(
                    "adrive's live view speaks the WebSocket subprotocol {} or {}\n",
                    proto::SUBPROTOCOLS[0],
                    proto::SUBPROTOCOLS[1]
                )));
                *e.status_mut() = StatusCode::BAD_REQUEST;
                Err(e)
            }
        }
    }
}

/// A connection still in its handshake.
struct Pending {
    mid: MidHandshake<ServerHandshake<TcpStream, Negotiate>>,
    chosen: Arc<Mutex<Option<&'static str>>>,
    addr: SocketAddr,
    since: Instant,
    /// Past the limit: its handshake is only read to be answered 503.
    refused: bool,
}

/// One connected viewer.
struct Viewer {
    ws: WebSocket<TcpStream>,
    addr: SocketAddr,
    subprotocol: &'static str,
    /// Channel id → the viewer's subscription id.
    subs: HashMap<u32, u32>,
    /// `serverInfo`, `advertise`, `status`: never dropped, sent first.
    control: VecDeque<Message>,
    /// Message data, at most [`QUEUE`].
    queue: VecDeque<Message>,
    sent: u64,
    dropped: u64,
    /// The socket took less than it was given: wait for it before writing more.
    blocked: bool,
    gone: bool,
}

impl Viewer {
    /// Queue message data; a full queue loses its oldest.
    fn offer(&mut self, m: Message) {
        if self.queue.len() >= QUEUE {
            self.queue.pop_front();
            self.dropped += 1;
        }
        self.queue.push_back(m);
    }

    /// Write what the socket takes now, without ever waiting for it.
    fn pump(&mut self) {
        if self.gone {
            return;
        }
        if self.blocked {
            match self.ws.flush() {
                Ok(()) => self.blocked = false,
                Err(e) if would_block(&e) => return,
                Err(_) => return self.gone = true,
            }
        }
        while let Some((m, data)) = match self.control.pop_front() {
            Some(m) => Some((m, false)),
            None => self.queue.pop_front().map(|m| (m, true)),
        } {
            match self.ws.write(m) {
                Ok(()) => self.sent += u64::from(data),
                // Taken into the WebSocket's buffer; the socket is full for now.
                Err(e) if would_block(&e) => {
                    self.sent += u64::from(data);
                    self.blocked = true;
                    return;
                }
                Err(_) => return self.gone = true,
            }
        }
        match self.ws.flush() {
            Ok(()) => {}
            Err(e) if would_block(&e) => self.blocked = true,
            Err(_) => self.gone = true,
        }
    }
}

fn would_block(e: &tungstenite::Error) -> bool {
    matches!(e, tungstenite::Error::Io(io) if io.kind() == io::ErrorKind::WouldBlock)
}

/// The thread's state.
struct Server {
    vehicle: Arc<Vehicle>,
    listener: TcpListener,
    addr: SocketAddr,
    rx: Receiver<Event>,
    reader: ReaderId,
    clock: Clock,
    /// Channel id − 1 → its topic.
    topics: Vec<Topic>,
    ids: HashMap<Topic, u32>,
    info: String,
    advertise: String,
    /// The latest event of each channel, for a viewer that subscribes later.
    latest: HashMap<u32, Event>,
    pending: Vec<Pending>,
    viewers: Vec<Viewer>,
    /// Dropped for viewers that have gone.
    dropped_gone: u64,
}

impl Server {
    fn new(
        vehicle: Arc<Vehicle>,
        listener: TcpListener,
        addr: SocketAddr,
        rx: Receiver<Event>,
        reader: ReaderId,
    ) -> Server {
        let config = vehicle.config();
        let topics = Topic::channels(&config.devices, false);
        let named: Vec<(String, String, String)> = topics
            .iter()
            .map(|t| {
                let (schema_name, schema) = t.schema(config);
                let schema = String::from_utf8(schema).expect("a JSON Schema is text");
                (t.name(&config.devices), schema_name, schema)
            })
            .collect();
        let channels: Vec<proto::Channel> = named
            .iter()
            .enumerate()
            .map(|(i, (topic, schema_name, schema))| proto::Channel {
                id: i as u32 + 1,
                topic,
                schema_name,
                schema,
            })
            .collect();
        let advertise = proto::advertise(&channels);
        let session = SystemTime::now()
            .duration_since(UNIX_EPOCH)
            .map_or(0, |d| d.as_millis())
            .to_string();
        let info = proto::server_info(
            &format!("adrive {}", env!("CARGO_PKG_VERSION")),
            &session,
            vehicle.name(),
        );
        let ids = topics
            .iter()
            .enumerate()
            .map(|(i, t)| (*t, i as u32 + 1))
            .collect();
        Server {
            vehicle,
            listener,
            addr,
            rx,
            reader,
            clock: Clock::now(),
            topics,
            ids,
            info,
            advertise,
            latest: HashMap::new(),
            pending: Vec::new(),
            viewers: Vec::new(),
            dropped_gone: 0,
        }
    }

    fn run(mut self, stop: &StopSignal) {
        while !stop.is_stopped() {
            self.wait();
            self.accept();
            self.handshakes();
            for i in 0..self.viewers.len() {
                self.read(i);
            }
            self.drain();
            for v in &mut self.viewers {
                v.pump();
            }
            self.forget_gone();
            self.publish();
        }
        for v in &mut self.viewers {
            let _ = v.ws.close(None);
            let _ = v.ws.flush();
        }
        self.vehicle.tap().close(self.reader);
        self.publish();
    }

    /// Sleep until a socket has something or [`TURN`] has passed.
    fn wait(&self) {
        use rustix::event::{PollFd, PollFlags, Timespec};
        let mut fds = vec![PollFd::new(&self.listener, PollFlags::IN)];
        fds.extend(
            self.pending
                .iter()
                .map(|p| PollFd::new(p.mid.get_ref().get_ref(), PollFlags::IN)),
        );
        fds.extend(self.viewers.iter().map(|v| {
            let out = if v.blocked {
                PollFlags::OUT
            } else {
                PollFlags::empty()
            };
            PollFd::new(v.ws.get_ref(), PollFlags::IN | out)
        }));
        let timeout = Timespec {
            tv_sec: 0,
            tv_nsec: TURN.as_nanos() as _,
        };
        let _ = rustix::event::poll(&mut fds, Some(&timeout));
    }

    /// Take new connections and start their handshakes.
    fn accept(&mut self) {
        loop {
            let (stream, addr) = match self.listener.accept() {
                Ok(c) => c,
                Err(e) if e.kind() == io::ErrorKind::WouldBlock => return,
                Err(e) => {
                    tracing::debug!("foxglove: accept: {e}");
                    return;
                }
            };
            let refusing = self.pending.iter().filter(|p| p.refused).count();
            let full = self.viewers.len() + self.pending.len() - refusing >= MAX_VIEWERS;
            if full && refusing >= MAX_VIEWERS {
                // A flood: past the limit and as many being answered already.
                tracing::debug!(
                    "foxglove: {addr} closed: {MAX_VIEWERS} viewers and {refusing} refused already"
                );
                continue;
            }
            let setup = stream
                .set_nonblocking(true)
                .and_then(|()| stream.set_nodelay(true))
                .and_then(|()| socket2::SockRef::from(&stream).set_send_buffer_size(SEND_BUFFER));
            if let Err(e) = setup {
                tracing::debug!("foxglove: {addr}: {e}");
                continue;
            }
            let chosen = Arc::new(Mutex::new(None));
            let negotiate = Negotiate {
                chosen: chosen.clone(),
                full,
            };
            let r = tungstenite::accept_hdr(stream, negotiate);
            self.handshaken(r, chosen, addr, Instant::now(), full);
        }
    }

    /// Carry on with each handshake the socket has answered.
    fn handshakes(&mut self) {
        for mut p in std::mem::take(&mut self.pending) {
            if p.since.elapsed() > HANDSHAKE {
                tracing::debug!("foxglove: {}: no handshake in {HANDSHAKE:?}", p.addr);
                // Told why, in HTTP, before the connection closes.
                let answer = format!(
                    "HTTP/1.1 408 Request Timeout\r\nConnection: close\r\nContent-Type: text/plain\r\n\r\n\
                     adrive's live view waits {} s at most for a WebSocket handshake\n",
                    HANDSHAKE.as_secs()
                );
                let _ = io::Write::write_all(p.mid.get_mut().get_mut(), answer.as_bytes());
                continue;
            }
            let r = p.mid.handshake();
            self.handshaken(r, p.chosen, p.addr, p.since, p.refused);
        }
    }

    fn handshaken(
        &mut self,
        r: Result<WebSocket<TcpStream>, HandshakeError<ServerHandshake<TcpStream, Negotiate>>>,
        chosen: Arc<Mutex<Option<&'static str>>>,
        addr: SocketAddr,
        since: Instant,
        refused: bool,
    ) {
        match r {
            Ok(ws) => {
                let subprotocol = chosen.lock().unwrap_or(proto::SUBPROTOCOLS[0]);
                tracing::info!("foxglove: viewer {addr} connected ({subprotocol})");
                self.viewers.push(Viewer {
                    ws,
                    addr,
                    subprotocol,
                    subs: HashMap::new(),
                    control: VecDeque::from([
                        Message::text(self.info.clone()),
                        Message::text(self.advertise.clone()),
                    ]),
                    queue: VecDeque::new(),
                    sent: 0,
                    dropped: 0,
                    blocked: false,
                    gone: false,
                });
            }
            Err(HandshakeError::Interrupted(mid)) => self.pending.push(Pending {
                mid,
                chosen,
                addr,
                since,
                refused,
            }),
            Err(HandshakeError::Failure(_)) if refused => {
                tracing::warn!("foxglove: {addr} refused (503): {MAX_VIEWERS} viewers already")
            }
            Err(HandshakeError::Failure(e)) => {
                tracing::warn!("foxglove: {addr}: handshake refused: {e}")
            }
        }
    }

    /// What viewer `i` has sent (at most [`CLIENT_MESSAGES`] a turn).
    fn read(&mut self, i: usize) {
        for _ in 0..CLIENT_MESSAGES {
            let text = match self.viewers[i].ws.read() {
                Ok(Message::Text(t)) => t.to_string(),
                Ok(Message::Binary(_)) => {
                    self.tell(
                        i,
                        1,
                        "adrive's live view is read-only: client messages are not taken",
                    );
                    continue;
                }
                Ok(_) => continue,
                Err(e) if would_block(&e) => return,
                Err(_) => {
                    self.viewers[i].gone = true;
                    return;
                }
            };
            match proto::parse(&text) {
                Ok(proto::ClientOp::Subscribe(list)) => {
                    for (sub, channel) in list {
                        self.subscribe(i, sub, channel);
                    }
                }
                Ok(proto::ClientOp::Unsubscribe(list)) => {
                    self.viewers[i].subs.retain(|_, s| !list.contains(s));
                }
                Ok(proto::ClientOp::Other(op)) => self.tell(
                    i,
                    1,
                    &format!("adrive's live view is read-only: {op} is not served"),
                ),
                Err(e) => self.tell(i, 2, &e),
            }
        }
    }

    fn tell(&mut self, i: usize, level: u8, message: &str) {
        let v = &mut self.viewers[i];
        if v.control.len() < CLIENT_MESSAGES {
            v.control
                .push_back(Message::text(proto::status(level, message)));
        }
    }

    /// Subscribe viewer `i` to `channel` as `sub`, and send it the channel's latest
    /// message at once.
    fn subscribe(&mut self, i: usize, sub: u32, channel: u32) {
        let v = &self.viewers[i];
        if channel == 0 || channel as usize > self.topics.len() {
            return self.tell(i, 2, &format!("subscribe: no channel {channel}"));
        }
        if v.subs.values().any(|s| *s == sub) {
            return self.tell(i, 2, &format!("subscribe: subscription {sub} is in use"));
        }
        self.viewers[i].subs.insert(channel, sub);
        if let Some(ev) = self.latest.get(&channel) {
            let (_, at, data) = message::encode(&self.vehicle, &self.clock, ev.clone());
            let m = Message::binary(proto::message_data(sub, at, &data));
            self.viewers[i].offer(m);
        }
    }

    /// What the tap holds: kept as each channel's latest, and to each subscriber.
    fn drain(&mut self) {
        for ev in self.rx.try_iter().take(CAPACITY) {
            let topic = message::topic(&ev);
            let Some(&channel) = self.ids.get(&topic) else {
                continue;
            };
            let watched = self.viewers.iter().any(|v| v.subs.contains_key(&channel));
            if watched {
                let (_, at, data) = message::encode(&self.vehicle, &self.clock, ev.clone());
                for v in &mut self.viewers {
                    if let Some(&sub) = v.subs.get(&channel) {
                        v.offer(Message::binary(proto::message_data(sub, at, &data)));
                    }
                }
            }
            self.latest.insert(channel, ev);
        }
    }

    fn forget_gone(&mut self) {
        let mut dropped = 0;
        self.viewers.retain(|v| {
            if v.gone {
                tracing::info!(
                    "foxglove: viewer {} left ({} sent, {} dropped)",
                    v.addr,
                    v.sent,
                    v.dropped
                );
                dropped += v.dropped;
            }
            !v.gone
        });
        self.dropped_gone += dropped;
    }

    /// Put the live view's account in the snapshot.
    fn publish(&self) {
        let viewers: Vec<ViewerView> = self
            .viewers
            .iter()
            .map(|v| ViewerView {
                addr: v.addr,
                subprotocol: v.subprotocol.into(),
                subscriptions: v.subs.len() as u32,
                sent: v.sent,
                dropped: v.dropped,
            })
            .collect();
        let dropped = self.dropped_gone + viewers.iter().map(|v| v.dropped).sum::<u64>();
        self.vehicle.tap().set_live(Some(LiveView {
            listen: self.addr,
            viewers,
            dropped,
            tap_dropped: self.vehicle.tap().dropped(self.reader),
        }));
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use serde_json::Value;

    /// The layout's panels are ones Lichtblick and Foxglove have (the log panel is
    /// `RosOut`: a `Log` panel is "Unknown panel type").
    #[test]
    fn the_shipped_layout_uses_panels_the_viewers_have() {
        let layout: Value =
            serde_json::from_str(include_str!("../../docs/foxglove-layout.json")).unwrap();
        for id in layout["configById"].as_object().unwrap().keys() {
            let kind = id.split('!').next().unwrap();
            assert!(
                [
                    "Plot",
                    "StateTransitions",
                    "RawMessages",
                    "RosOut",
                    "Table",
                    "Indicator",
                    "Gauge"
                ]
                .contains(&kind),
                "{id}: no such panel in Lichtblick"
            );
        }
    }

    /// Every message path in `layout`: plots', state transitions', raw messages' and
    /// the log panel's topic.
    fn paths(layout: &Value) -> Vec<String> {
        let mut out = Vec::new();
        for panel in layout["configById"].as_object().unwrap().values() {
            for p in panel["paths"].as_array().into_iter().flatten() {
                out.push(p["value"].as_str().unwrap().to_string());
            }
            for key in ["topicPath", "topicToRender"] {
                out.extend(panel[key].as_str().map(str::to_string));
            }
        }
        out
    }

    /// The schema of `field` inside `schema`, through arrays and nullable variants.
    fn field<'a>(schema: &'a Value, name: &str) -> Option<&'a Value> {
        let direct = schema["properties"].get(name);
        let items = schema["items"]["properties"].get(name);
        let variants = ["anyOf", "oneOf"]
            .iter()
            .flat_map(|k| schema[k].as_array().into_iter().flatten())
            .find_map(|s| field(s, name));
        direct.or(items).or(variants)
    }

    /// The shipped layout names only channels and fields that Alice's live view
    /// advertises, and every setpoint device of Alice's has its command, measured and
    /// estimated position plotted. (No viewer runs here: this is what is checked.)
    #[test]
    fn the_shipped_layout_plots_what_alice_advertises() {
        let text = include_str!("../../docs/foxglove-layout.json");
        let layout: Value = serde_json::from_str(text).expect("the layout is JSON");
        let alice = crate::config::VehicleConfig::alice();
        let devices = &alice.devices;
        let schemas: HashMap<String, Value> = Topic::channels(devices, false)
            .into_iter()
            .map(|t| {
                let (_, s) = t.schema(&alice);
                (t.name(devices), serde_json::from_slice(&s).unwrap())
            })
            .collect();
        let all = paths(&layout);
        for path in &all {
            let (topic, rest) = path.split_once('.').unwrap_or((path, ""));
            let schema = schemas
                .get(topic)
                .unwrap_or_else(|| panic!("{path}: no channel {topic}"));
            let mut at = schema;
            for step in rest.split('.').filter(|s| !s.is_empty()) {
                let (name, filter) = match step.split_once('[') {
                    Some((n, f)) => (n, Some(f)),
                    None => (step, None),
                };
                if let Some(f) = filter.and_then(|f| f.split_once("{name==\"")) {
                    let device = f.1.trim_end_matches("\"}");
                    assert!(alice.device(device).is_some(), "{path}: no device {device}");
                }
                at = field(at, name).unwrap_or_else(|| panic!("{path}: no field {name}"));
            }
        }
        for d in devices
            .iter()
            .filter(|d| d.kind == crate::value::Kind::Setpoint)
        {
            for want in [
                format!("/{}/command.value", d.name),
                format!("/{}/reading.position", d.name),
                format!(
                    "/snapshot.devices[:]{{name==\"{}\"}}.estimate.position",
                    d.name
                ),
            ] {
                assert!(all.contains(&want), "the layout plots {want}");
            }
        }
        assert!(all.iter().any(|p| p.starts_with("/snapshot.gate.engaged")));
        assert!(all.contains(&"/log".to_string()) && all.contains(&"/faults".to_string()));
    }
}
