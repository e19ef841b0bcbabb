//! The control socket's server: a thread that accepts, and two threads per client —
//! `socket/N` reads its operations and answers them through the intake as the source
//! the client is, `socket/N/out` sends it a frame every console tick.
//!
//! Nothing here holds the engine: a frame is captured from the cache as the embedded
//! console captures its own, and written by the client's own thread with a write
//! deadline, so a client that stops reading (a frozen SSH session, a process stopped
//! with Ctrl-Z) costs its own threads a blocked write, then its connection. When a
//! connection ends, for any reason, the source is gone: a console that commanded the
//! engaged vehicle is that source's watchdog ([`Gate::gone`]: the safe state,
//! disengaged); a watcher changes nothing.
//!
//! Every ending is named for what adrive knows of it ([`Ending`]): the client closed
//! its connection, or adrive dropped it — it stopped reading for so long (measured
//! from the last time everything sent had been read), it sent what adrive does not
//! take, adrive is stopping. Where adrive ended it, the client is told why
//! (`Bye`): at once, or — a client that stopped reading — once it reads again, within
//! [`BYE_GRACE`]; from then on nothing it sends is done.

use super::path::{Claim, Peer};
use super::proto::{Answer, Msg, Op, Request, Role, WireLog, WireScene, WireTrace, VERSION};
use crate::controls::{capture, Controls, Live, Sources, TICK};
use crate::engine::Gate;
use crate::safety::Ask;
use crate::threads::{Group, StopSignal, Threads};
use crate::value::{DeviceId, Source};
use parking_lot::Mutex;
use std::io::{BufRead, BufReader, ErrorKind, Write};
use std::os::unix::net::{UnixListener, UnixStream};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, AtomicU32, Ordering::Relaxed};
use std::sync::Arc;
use std::time::{Duration, Instant};

/// A client that does not take a frame within this long is dropped.
pub(crate) const WRITE_DEADLINE: Duration = Duration::from_secs(2);
/// How long a dropped client that stopped reading has to read again and be told why.
const BYE_GRACE: Duration = Duration::from_secs(60);
/// The longest request line read (a command is a few dozen bytes).
const MAX_LINE: usize = 4096;
/// What an operator's one-shot command is told when it asks what only a console may.
const ONLY_CONSOLES: &str = "only an attached console may do this";
/// The most clients at once; more are told so and closed.
pub(crate) const MAX_CLIENTS: usize = 32;

/// What every connection shares.
struct Shared {
    gate: Arc<Gate>,
    sources: Sources,
    stop: Arc<StopSignal>,
    /// Refuse every operation from now on (the process is stopping).
    closed: AtomicBool,
    next: AtomicU32,
    /// Every open connection, by number, to end them on shutdown.
    open: Mutex<Vec<(u32, UnixStream)>>,
    threads: Mutex<Threads>,
}

/// A connection that did not come through the socket file: a console or an
/// operator's command linked over the fleet (`fleet::serve`), whose link carries the
/// same protocol.
pub(crate) struct Linked {
    /// Where it comes from, for the log (`fleet link 3f2a…`).
    pub from: String,
    /// Whether it may command.
    pub permit: Arc<Permit>,
    /// Why the link ended, where the far end knows better than a closed stream (its
    /// token withdrawn): what the gate and the log say of the source that went.
    pub lost: Arc<Mutex<Option<String>>>,
}

/// Whether a linked connection may command the vehicle, or only watch it, and why:
/// set by whoever proves the link (its key), read at every operation.
#[derive(Debug)]
pub(crate) struct Permit(Mutex<Result<(), String>>);

#[cfg_attr(not(feature = "fleet"), allow(dead_code))]
impl Permit {
    /// Watching only, for this reason, until [`Permit::grant`].
    pub(crate) fn watch_only(why: String) -> Permit {
        Permit(Mutex::new(Err(why)))
    }
    pub(crate) fn grant(&self) {
        *self.0.lock() = Ok(());
    }
    pub(crate) fn deny(&self, why: String) {
        *self.0.lock() = Err(why);
    }
    fn get(&self) -> Result<(), String> {
        self.0.lock().clone()
    }
}

/// Who is at the other end of a connection.
#[cfg_attr(not(feature = "fleet"), allow(dead_code))]
enum Origin {
    /// A process on this machine, through the socket file.
    Local(Peer),
    /// A link over the fleet.
    Linked(Linked),
}

/// The door a linked connection comes in by: serves a stream as a client of the
/// control socket, with every rule a local one meets.
#[derive(Clone)]
#[cfg_attr(not(feature = "fleet"), allow(dead_code))]
pub(crate) struct Door(Arc<Shared>);

#[cfg_attr(not(feature = "fleet"), allow(dead_code))]
impl Door {
    /// Serve `stream` (one end of a pair whose other end the link carries) as a
    /// client.
    pub(crate) fn serve(&self, stream: UnixStream, linked: Linked) -> std::io::Result<()> {
        serve(stream, Origin::Linked(linked), &self.0)
    }
}

/// The running control socket.
pub struct Server {
    shared: Arc<Shared>,
    accept: Group,
    path: PathBuf,
    /// Removes the socket file when the server goes.
    _claim: Claim,
}

impl Server {
    /// Serve the socket claimed with [`super::path::bind`] (claimed before anything starts,
    /// so that a live socket — another adrive — stops a run before it drives anything).
    pub fn start(
        gate: Arc<Gate>,
        sources: Sources,
        (listener, claim): (UnixListener, Claim),
    ) -> Result<Server, String> {
        let path = claim.path.clone();
        listener
            .set_nonblocking(true)
            .map_err(|e| format!("control socket: {e}"))?;
        let mut accept = Group::default();
        let shared = Arc::new(Shared {
            gate,
            sources,
            stop: accept.signal().clone(),
            closed: AtomicBool::new(false),
            next: AtomicU32::new(1),
            open: Mutex::new(Vec::new()),
            threads: Mutex::new(Threads::default()),
        });
        let s = shared.clone();
        accept
            .spawn("socket/accept", move |_| accept_loop(listener, &s))
            .map_err(|e| format!("control socket: {e}"))?;
        tracing::info!("control socket at {}", path.display());
        Ok(Server {
            shared,
            accept,
            path,
            _claim: claim,
        })
    }

    pub fn path(&self) -> &Path {
        &self.path
    }

    /// The way in for connections linked from elsewhere (the fleet).
    #[cfg_attr(not(feature = "fleet"), allow(dead_code))]
    pub(crate) fn door(&self) -> Door {
        Door(self.shared.clone())
    }

    /// Refuse every operation and end every connection (the process is stopping: no
    /// command may follow the safe state). Each client that takes it at once is told.
    pub fn close(&self) {
        self.shared.closed.store(true, Relaxed);
        self.shared.stop.stop();
        for (_, c) in self.shared.open.lock().drain(..) {
            if let Some(Ok(line)) = Ending::Stopping.told().map(|t| bye_line(&t)) {
                // Never wait on a client here: one that does not take it is not told.
                let _ = c.set_nonblocking(true);
                let _ = (&c).write_all(&line);
            }
            let _ = c.shutdown(std::net::Shutdown::Both);
        }
    }

    fn stop(&mut self, deadline: Duration) -> Vec<String> {
        self.close();
        let until = Instant::now() + deadline;
        let mut stuck = self.accept.stop(until);
        let threads = std::mem::take(&mut *self.shared.threads.lock());
        stuck.extend(threads.join(until));
        stuck
    }
}

impl crate::threads::Shutdown for Server {
    /// Close, join every thread within `deadline`, remove the socket file; the names of
    /// threads that did not stop.
    fn shutdown(mut self, deadline: Duration) -> Vec<String> {
        self.stop(deadline)
    }
}

/// On a way out that skips the shutdown ([`crate::threads::Shutdown`]: a panic
/// unwinding the main thread), the clients' threads still end before what they hold
/// goes: the simulator among them, whose directory of port links is removed only when
/// it is dropped.
impl Drop for Server {
    fn drop(&mut self) {
        self.stop(Duration::from_millis(500));
    }
}

fn accept_loop(listener: UnixListener, s: &Arc<Shared>) {
    use rustix::event::{poll, PollFd, PollFlags, Timespec};
    let wait = Timespec {
        tv_sec: 0,
        tv_nsec: 200_000_000,
    };
    while !s.stop.is_stopped() {
        let mut fds = [PollFd::new(&listener, PollFlags::IN)];
        if poll(&mut fds, Some(&wait)).unwrap_or(0) == 0 {
            continue;
        }
        match listener.accept() {
            Ok((stream, _)) => {
                if let Err(e) = Peer::of(&stream).and_then(|p| serve(stream, Origin::Local(p), s)) {
                    tracing::warn!("control socket: a client could not be served: {e}");
                }
            }
            Err(e) if e.kind() == std::io::ErrorKind::WouldBlock => {}
            Err(e) => {
                tracing::warn!("control socket: accept: {e}");
                std::thread::sleep(Duration::from_millis(100));
            }
        }
    }
}

/// Start a client's threads.
fn serve(stream: UnixStream, origin: Origin, s: &Arc<Shared>) -> std::io::Result<()> {
    stream.set_nonblocking(false)?;
    stream.set_write_timeout(Some(WRITE_DEADLINE))?;
    if s.open.lock().len() >= MAX_CLIENTS {
        let line = bye_line(&format!(
            "adrive serves {MAX_CLIENTS} clients at most; one must go first"
        ))?;
        let mut stream = stream;
        let _ = stream.write_all(&line);
        return Ok(());
    }
    let n = s.next.fetch_add(1, Relaxed);
    s.open.lock().push((n, stream.try_clone()?));
    // The threads of clients gone before.
    s.threads.lock().reap();
    let writer = Arc::new(Mutex::new(stream.try_clone()?));
    let conn = Arc::new(Conn {
        n,
        origin,
        writer,
        bench: Mutex::new(None),
        role: Mutex::new(None),
        seen_logs: Mutex::new(0),
        ended: AtomicBool::new(false),
        drained: Mutex::new(Instant::now()),
        departed: AtomicBool::new(false),
    });
    let (s2, c2) = (s.clone(), conn.clone());
    s.threads
        .lock()
        .spawn(format!("socket/{n}"), move || read_loop(stream, &s2, &c2))?;
    let (s3, c3) = (s.clone(), conn);
    s.threads
        .lock()
        .spawn(format!("socket/{n}/out"), move || frame_loop(&s3, &c3))?;
    Ok(())
}

/// One client.
struct Conn {
    n: u32,
    origin: Origin,
    writer: Arc<Mutex<UnixStream>>,
    bench: Mutex<Option<DeviceId>>,
    /// Set by its hello.
    role: Mutex<Option<Role>>,
    /// Log lines sent so far.
    seen_logs: Mutex<u64>,
    /// Its reading thread ended: so do its frames.
    ended: AtomicBool,
    /// When everything sent to it had last been read.
    drained: Mutex<Instant>,
    /// Its source is gone ([`depart`]): nothing it sends is done any more.
    departed: AtomicBool,
}

/// How a client's connection ended, as far as adrive knows.
#[derive(Clone, Debug, PartialEq)]
enum Ending {
    /// The client closed it: its process ended, its terminal closed, its SSH session
    /// dropped.
    Closed,
    /// It stopped reading (a frozen session, a stopped process): nothing read for this
    /// long, and adrive dropped it.
    StoppedReading(Duration),
    /// It sent a request line longer than adrive reads.
    TooLong,
    /// It speaks another version of the protocol.
    Version,
    /// The connection failed under adrive (the error).
    Failed(String),
    /// adrive is stopping.
    Stopping,
}

impl Ending {
    /// What its source did, after its name: the log's words and the gate's reason
    /// (`console #2 stopped reading for 4.1 s: dropped`).
    fn did(&self) -> String {
        match self {
            Ending::Closed => "went away (its connection closed)".into(),
            Ending::StoppedReading(d) => {
                format!("stopped reading for {:.1} s: dropped", d.as_secs_f64())
            }
            Ending::TooLong => "sent a line too long: dropped".into(),
            Ending::Version => "speaks another protocol version: dropped".into(),
            Ending::Failed(e) => format!("lost its connection ({e})"),
            Ending::Stopping => "adrive is stopping".into(),
        }
    }

    /// What the client is told, where adrive ended the connection.
    fn told(&self) -> Option<String> {
        Some(match self {
            Ending::StoppedReading(d) => format!(
                "adrive dropped this console: it stopped reading for {:.1} s (a console \
                 must take what adrive sends within {} s)",
                d.as_secs_f64(),
                WRITE_DEADLINE.as_secs()
            ),
            Ending::TooLong => {
                format!(
                    "adrive dropped this client: a request line is at most {MAX_LINE} bytes, and it sent a longer one"
                )
            }
            Ending::Stopping => "adrive is stopping".into(),
            // The client ended it, or was told already (its version).
            Ending::Closed | Ending::Version | Ending::Failed(_) => return None,
        })
    }
}

/// A `Bye` as it goes on the wire: after a line break, so that it starts a line of its
/// own even after a frame cut short.
fn bye_line(why: &str) -> std::io::Result<Vec<u8>> {
    let mut line = vec![b'\n'];
    serde_json::to_writer(&mut line, &Msg::Bye { why: why.into() })?;
    line.push(b'\n');
    Ok(line)
}

/// How many bytes sent on `stream` its reader has not read yet (`SIOCOUTQ`).
#[allow(unsafe_code)]
fn unread(stream: &UnixStream) -> Option<usize> {
    use std::os::fd::AsRawFd;
    let mut n: libc::c_int = 0;
    // SAFETY: TIOCOUTQ (SIOCOUTQ) writes one int for a valid socket fd.
    let r = unsafe { libc::ioctl(stream.as_raw_fd(), libc::TIOCOUTQ as _, &mut n) };
    (r == 0).then(|| usize::try_from(n).unwrap_or(0))
}

impl Conn {
    fn source(&self) -> Option<Source> {
        self.role.lock().map(|r| self.source_as(r))
    }

    fn source_as(&self, role: Role) -> Source {
        match (role, &self.origin) {
            (Role::Console, _) => Source::Attached(self.n),
            (Role::Once, Origin::Local(peer)) => Source::Operator(peer.uid),
            (Role::Once, Origin::Linked(_)) => Source::Fleet,
        }
    }

    /// Whether it may command, and why not.
    fn permit(&self) -> Result<(), String> {
        match &self.origin {
            Origin::Local(_) => Ok(()),
            Origin::Linked(l) => l.permit.get(),
        }
    }

    /// Where it comes from, for the log.
    fn describe(&self) -> String {
        match &self.origin {
            Origin::Local(peer) => format!("{}, uid {}", peer.describe(), peer.uid),
            Origin::Linked(l) => l.from.clone(),
        }
    }

    /// Send one message; `Err` with how the connection ended when it cannot be.
    fn send(&self, msg: &Msg) -> Result<(), Ending> {
        let mut line = serde_json::to_vec(msg).map_err(|e| Ending::Failed(e.to_string()))?;
        line.push(b'\n');
        let mut w = self.writer.lock();
        match w.write_all(&line) {
            Ok(()) => {
                if unread(&w) == Some(0) {
                    *self.drained.lock() = Instant::now();
                }
                Ok(())
            }
            Err(e) if matches!(e.kind(), ErrorKind::WouldBlock | ErrorKind::TimedOut) => {
                Err(Ending::StoppedReading(self.drained.lock().elapsed()))
            }
            Err(e) if matches!(e.kind(), ErrorKind::BrokenPipe | ErrorKind::ConnectionReset) => {
                Err(Ending::Closed)
            }
            Err(e) => Err(Ending::Failed(e.to_string())),
        }
    }

    /// Tell the client why adrive ends its connection, within `grace` (one that stopped
    /// reading may read again), then close it.
    fn farewell(&self, ending: &Ending, grace: Duration) {
        let w = self.writer.lock();
        if let Some(Ok(line)) = ending.told().map(|t| bye_line(&t)) {
            let _ = w.set_write_timeout(Some(grace));
            let _ = (&*w).write_all(&line);
        }
        let _ = w.shutdown(std::net::Shutdown::Both);
    }
}

/// The client's source is gone, for `ending` (once, whoever notices first): a
/// console that commanded the engaged vehicle is its watchdog; the log says what
/// happened.
fn depart(s: &Shared, c: &Conn, ending: &Ending) {
    if c.departed.swap(true, Relaxed) {
        return;
    }
    c.ended.store(true, Relaxed);
    let console = *c.role.lock() == Some(Role::Console);
    let Some(source) = c.source().filter(|_| console) else {
        return;
    };
    let who = crate::safety::owner::Commander(source);
    // A stopping process ends every connection, and brings the vehicle to the safe
    // state itself, with its reason.
    if s.closed.load(Relaxed) {
        tracing::info!("{who} detached: {}", Ending::Stopping.did());
        return;
    }
    let did = match &c.origin {
        Origin::Linked(l) => l.lost.lock().clone(),
        Origin::Local(_) => None,
    }
    .unwrap_or_else(|| ending.did());
    if s.gate.gone(source, &did) {
        return;
    }
    match ending {
        Ending::Closed | Ending::Stopping => tracing::info!("{who} detached: {did}"),
        _ => tracing::warn!("{who} detached: {did}"),
    }
}

fn read_loop(stream: UnixStream, s: &Shared, c: &Conn) {
    let mut reader = BufReader::new(stream);
    let mut line = String::new();
    let ending = loop {
        line.clear();
        match std::io::Read::take(&mut reader, MAX_LINE as u64).read_line(&mut line) {
            Ok(0) => break Ending::Closed,
            Ok(_) if !line.ends_with('\n') => break Ending::TooLong,
            Ok(_) => {}
            // A client that ends with frames it never read resets its end: it closed.
            Err(e) if e.kind() == ErrorKind::ConnectionReset => break Ending::Closed,
            Err(e) => break Ending::Failed(e.to_string()),
        }
        // Dropped (it stopped reading): what it sends after is not done.
        if c.departed.load(Relaxed) {
            return finish(s, c, &Ending::Closed);
        }
        let req: Request = match serde_json::from_str(&line) {
            Ok(r) => r,
            Err(e) => {
                let _ = c.send(&Msg::Reply {
                    id: 0,
                    answer: Answer::Error(format!("not a request: {e}")),
                });
                continue;
            }
        };
        if s.closed.load(Relaxed) {
            break Ending::Stopping;
        }
        if let Op::Hello { role, version } = req.op {
            if version != VERSION {
                let _ = c.send(&Msg::Bye {
                    why: format!(
                        "this adrive speaks control protocol {VERSION}, the client {version}: \
                         use the same adrive version on both ends"
                    ),
                });
                break Ending::Version;
            }
            let source = c.source_as(role);
            if role == Role::Console {
                tracing::info!(
                    "{} attached ({}), watching",
                    crate::safety::owner::Commander(source),
                    c.describe(),
                );
            }
            let welcome = Msg::Welcome {
                version: VERSION,
                source: crate::safety::owner::Commander(source).to_string(),
            };
            if let Err(ending) = c.send(&welcome) {
                break ending;
            }
            // Frames after the welcome.
            *c.role.lock() = Some(role);
            continue;
        }
        let Some(source) = c.source() else {
            let _ = c.send(&Msg::Reply {
                id: req.id,
                answer: Answer::Error("say hello first".into()),
            });
            continue;
        };
        // A console's proof that its operator is there: fed at once, never answered.
        if req.op == Op::Answered {
            if source.is_console() {
                s.gate.answered(source, Instant::now());
            }
            continue;
        }
        let answer = answer(s, c, source, req.op);
        if let Err(ending) = c.send(&Msg::Reply { id: req.id, answer }) {
            break ending;
        }
    };
    finish(s, c, &ending);
}

/// The reading side is done: the source departs (if it has not), the client is told
/// why where adrive ended it, and the connection closes.
fn finish(s: &Shared, c: &Conn, ending: &Ending) {
    depart(s, c, ending);
    // Its place among the clients is free before it hears of its end: a client told
    // goodbye that connects again (or the next one) finds the place it left.
    s.open.lock().retain(|(n, _)| *n != c.n);
    match ending {
        Ending::TooLong | Ending::Stopping => c.farewell(ending, WRITE_DEADLINE),
        _ => {
            let _ = c.writer.lock().shutdown(std::net::Shutdown::Both);
        }
    }
}

/// What one operation comes to, done as `source` through the same [`Live`] controls
/// the embedded console uses.
fn answer(s: &Shared, c: &Conn, source: Source, op: Op) -> Answer {
    let live = Live {
        gate: &s.gate,
        sources: &s.sources,
        source,
        characterize: None,
    };
    let unit = |r: Result<(), String>| match r {
        Ok(()) => Answer::Ok,
        Err(e) => Answer::Error(e),
    };
    let console = source.is_console();
    // A link that may only watch reads, and asks nothing of the vehicle.
    let reads = matches!(
        op,
        Op::Status | Op::Bench { .. } | Op::Parse { .. } | Op::Answered
    );
    if let (false, Err(why)) = (reads, c.permit()) {
        return Answer::Error(why);
    }
    if let Some(ask) = op.ask() {
        // An operator's one-shot command only engages, stops, disengages and releases
        // (and reads); the rest is a console's.
        let once = matches!(ask, Ask::Engage | Ask::Disengage | Ask::Stop | Ask::Release);
        if !console && !once {
            return Answer::Error(ONLY_CONSOLES.into());
        }
        return match live.ask(ask) {
            Ok(done) => Answer::Done(done),
            Err(r) => Answer::Refused(r),
        };
    }
    match op {
        Op::Hello { .. } => Answer::Error("already said hello".into()),
        Op::Answered => Answer::Ok,
        Op::Status => {
            let mut snap = s.gate.snapshot(0);
            snap.net = s.sources.net.as_ref().map(|n| n.snapshot(&s.gate));
            Answer::Snapshot(Box::new(snap))
        }
        _ if !console => Answer::Error(ONLY_CONSOLES.into()),
        Op::Bench { device } => {
            *c.bench.lock() = device.map(DeviceId);
            Answer::Ok
        }
        Op::Parse { device, text } => match live.parse(DeviceId(device), &text) {
            Ok(cmd) => Answer::Command(cmd),
            Err(e) => Answer::Error(e),
        },
        Op::Deadman { ms } => {
            live.deadman(ms.map(Duration::from_millis));
            Answer::Ok
        }
        Op::Interlocks { on } => match live.set_interlocks(on) {
            Ok(()) => Answer::Ok,
            Err(r) => Answer::Refused(r),
        },
        Op::Sim { line } => match live.sim(&line) {
            None => Answer::NoSim,
            Some(Ok(said)) => Answer::Said(said),
            Some(Err(e)) => Answer::Error(e),
        },
        // The asks are answered above: what is left is a tuning. A console that may
        // not tune is refused with the intake's reason.
        op => match (op.tune(), s.gate.tune(source)) {
            (Some(t), Ok(())) => unit(live.tune(t)),
            (Some(_), Err(r)) => Answer::Refused(r),
            (None, _) => Answer::Error(format!("{op:?}: not an operation")),
        },
    }
}

/// A frame every console tick, until the connection or the server ends.
fn frame_loop(s: &Shared, c: &Conn) {
    let mut next = Instant::now();
    loop {
        if !s.stop.sleep_until(next) {
            return;
        }
        next += TICK;
        let now = Instant::now();
        if next < now {
            next = now + TICK;
        }
        if c.ended.load(Relaxed) {
            return;
        }
        // Frames only to a console, once it said so.
        if *c.role.lock() != Some(Role::Console) {
            continue;
        }
        if let Err(ending) = c.send(&Msg::Frame(Box::new(scene(s, c, now)))) {
            // The vehicle first; then, if it reads again, the client is told why.
            depart(s, c, &ending);
            if matches!(ending, Ending::StoppedReading(_)) {
                c.farewell(&ending, BYE_GRACE);
            } else {
                let _ = c.writer.lock().shutdown(std::net::Shutdown::Both);
            }
            return;
        }
    }
}

/// The frame for one console: its bench device's traffic, the log lines it has not had.
fn scene(s: &Shared, c: &Conn, now: Instant) -> WireScene {
    let f = capture(&s.gate, &s.sources, now, *c.bench.lock());
    let logs = match &s.sources.logs {
        Some(ring) => {
            let mut seen = c.seen_logs.lock();
            let (lines, total) = ring.since(*seen);
            *seen = total;
            lines.iter().map(WireLog::of).collect()
        }
        None => Vec::new(),
    };
    WireScene {
        logs,
        trace: f.trace.iter().map(|e| WireTrace::of(e, now)).collect(),
        buckets: f.buckets,
        can_inject: f.can_inject,
        sim_vehicle: f.sim_vehicle,
        sim_faults: f.sim_faults,
        teleop: f.teleop,
        sim_names: f.sim_names,
        snap: f.snap,
    }
}
