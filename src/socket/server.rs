//! The control socket's server: a thread that accepts, and two threads per client —
//! `socket/N` reads its operations and answers them through the intake as the source
//! the client is, `socket/N/out` sends it a frame every console tick.
//!
//! Nothing here holds the engine: a frame is captured from the cache as the embedded
//! console captures its own, and written by the client's own thread with a write
//! deadline, so a client that stops reading (a frozen SSH session) costs its own
//! threads a blocked write, then its connection. When a connection ends, for any
//! reason, the source is gone: a console that commanded the engaged vehicle is that
//! source's watchdog ([`Gate::gone`]: the safe state, disengaged); a watcher changes
//! nothing.

use super::path::{Claim, Peer};
use super::proto::{Answer, Msg, Op, Request, Role, WireFrame, WireLog, WireTrace, VERSION};
use crate::console::controls::{capture, Controls, Live, Sources};
use crate::console::TICK;
use crate::engine::Gate;
use crate::safety::Ask;
use crate::threads::{Owner, StopSignal, Threads};
use crate::value::{DeviceId, Source};
use parking_lot::Mutex;
use std::io::{BufRead, BufReader, Write};
use std::os::unix::net::{UnixListener, UnixStream};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, AtomicU32, Ordering::Relaxed};
use std::sync::Arc;
use std::time::{Duration, Instant};

/// A client that does not take a frame within this long is dropped.
pub(crate) const WRITE_DEADLINE: Duration = Duration::from_secs(2);
/// The longest request line read (a command is a few dozen bytes).
const MAX_LINE: usize = 4096;
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

/// The running control socket.
pub struct Server {
    shared: Arc<Shared>,
    accept: Owner,
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
        let mut accept = Owner::default();
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

    /// Refuse every operation and end every connection (the process is stopping: no
    /// command may follow the safe state).
    pub fn close(&self) {
        self.shared.closed.store(true, Relaxed);
        self.shared.stop.stop();
        for (_, c) in self.shared.open.lock().drain(..) {
            let _ = c.shutdown(std::net::Shutdown::Both);
        }
    }

    /// Close, join every thread within `deadline`, remove the socket file; the names of
    /// threads that did not stop.
    pub fn shutdown(mut self, deadline: Duration) -> Vec<String> {
        self.stop(deadline)
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

/// On a way out that skips [`Server::shutdown`] (a panic unwinding the main thread),
/// the clients' threads still end before what they hold goes: the simulator among
/// them, whose directory of port links is removed only when it is dropped.
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
                if let Err(e) = serve(stream, s) {
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
fn serve(stream: UnixStream, s: &Arc<Shared>) -> std::io::Result<()> {
    stream.set_nonblocking(false)?;
    stream.set_write_timeout(Some(WRITE_DEADLINE))?;
    if s.open.lock().len() >= MAX_CLIENTS {
        let mut line = serde_json::to_vec(&Msg::Bye {
            why: format!("adrive serves {MAX_CLIENTS} clients at most; one must go first"),
        })?;
        line.push(b'\n');
        let mut stream = stream;
        let _ = stream.write_all(&line);
        return Ok(());
    }
    let peer = Peer::of(&stream)?;
    let n = s.next.fetch_add(1, Relaxed);
    s.open.lock().push((n, stream.try_clone()?));
    // The threads of clients gone before.
    s.threads.lock().reap();
    let writer = Arc::new(Mutex::new(stream.try_clone()?));
    let conn = Arc::new(Conn {
        n,
        peer,
        writer,
        bench: Mutex::new(None),
        role: Mutex::new(None),
        seen_logs: Mutex::new(0),
        ended: AtomicBool::new(false),
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
    peer: Peer,
    writer: Arc<Mutex<UnixStream>>,
    bench: Mutex<Option<DeviceId>>,
    /// Set by its hello.
    role: Mutex<Option<Role>>,
    /// Log lines sent so far.
    seen_logs: Mutex<u64>,
    /// Its reading thread ended: so do its frames.
    ended: AtomicBool,
}

impl Conn {
    fn source(&self) -> Option<Source> {
        self.role.lock().map(|r| self.source_as(r))
    }

    fn source_as(&self, role: Role) -> Source {
        match role {
            Role::Console => Source::Attached(self.n),
            Role::Once => Source::Operator(self.peer.uid),
        }
    }

    /// Send one message; a client that does not take it in time is cut off.
    fn send(&self, msg: &Msg) -> std::io::Result<()> {
        let mut line = serde_json::to_vec(msg)?;
        line.push(b'\n');
        let mut w = self.writer.lock();
        let r = w.write_all(&line);
        if r.is_err() {
            let _ = w.shutdown(std::net::Shutdown::Both);
        }
        r
    }
}

fn read_loop(stream: UnixStream, s: &Shared, c: &Conn) {
    let mut reader = BufReader::new(stream);
    let mut line = String::new();
    let why = loop {
        line.clear();
        match std::io::Read::take(&mut reader, MAX_LINE as u64).read_line(&mut line) {
            Ok(0) => break "its connection closed".to_string(),
            Ok(_) if !line.ends_with('\n') => break "it sent a line too long".into(),
            Ok(_) => {}
            Err(e) => break format!("its connection failed: {e}"),
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
            break "adrive is stopping".into();
        }
        if let Op::Hello { role, version } = req.op {
            if version != VERSION {
                let _ = c.send(&Msg::Bye {
                    why: format!(
                        "this adrive speaks control protocol {VERSION}, the client {version}: \
                         use the same adrive version on both ends"
                    ),
                });
                break "another protocol version".into();
            }
            let source = c.source_as(role);
            if role == Role::Console {
                tracing::info!(
                    "{} attached ({}, uid {}), watching",
                    crate::safety::owner::Commander(source),
                    c.peer.describe(),
                    c.peer.uid
                );
            }
            let welcome = Msg::Welcome {
                version: VERSION,
                source: crate::safety::owner::Commander(source).to_string(),
            };
            if c.send(&welcome).is_err() {
                break "its connection failed".into();
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
        let answer = answer(s, c, source, req.op);
        if c.send(&Msg::Reply { id: req.id, answer }).is_err() {
            break "it stopped reading".into();
        }
    };
    // Its frames stop too.
    c.ended.store(true, Relaxed);
    let _ = c.writer.lock().shutdown(std::net::Shutdown::Both);
    s.open.lock().retain(|(n, _)| *n != c.n);
    // A stopping process brings the vehicle to the safe state itself, with its reason.
    let stopping = s.closed.load(Relaxed);
    if let Some(source) = c.source().filter(|_| *c.role.lock() == Some(Role::Console)) {
        if stopping || !s.gate.gone(source, &why) {
            tracing::info!(
                "{} detached ({why})",
                crate::safety::owner::Commander(source)
            );
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
    };
    let ask = |a: Ask| match live.ask(a) {
        Ok(done) => Answer::Done(done),
        Err(r) => Answer::Refused(r),
    };
    let unit = |r: Result<(), String>| match r {
        Ok(()) => Answer::Ok,
        Err(e) => Answer::Error(e),
    };
    let console = source.is_console();
    match op {
        Op::Hello { .. } => Answer::Error("already said hello".into()),
        Op::Engage => ask(Ask::Engage),
        Op::Disengage => ask(Ask::Disengage),
        Op::Stop => ask(Ask::Stop),
        Op::Release => ask(Ask::Release),
        Op::Status => {
            let mut snap = s.gate.snapshot(0);
            snap.net = s.sources.net.as_ref().map(|n| n.snapshot(&s.gate));
            Answer::Snapshot(Box::new(snap))
        }
        // The rest is a console's: an operator's one-shot command only engages, stops,
        // disengages, releases and reads.
        _ if !console => Answer::Error("only an attached console may do this".into()),
        Op::Take => ask(Ask::Take),
        Op::Hold => ask(Ask::Hold),
        Op::Clear => ask(Ask::Clear),
        Op::Set { device, command } => ask(Ask::Set(DeviceId(device), command)),
        Op::Accel { accel } => ask(Ask::Accel(accel)),
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
        Op::StatusPeriod { device, us } => {
            unit(live.set_status_period(DeviceId(device), Duration::from_micros(us)))
        }
        Op::CommandTimeout { device, us } => {
            unit(live.set_command_timeout(DeviceId(device), Duration::from_micros(us)))
        }
        Op::Enabled { device, thread, on } => match s.gate.tune(source) {
            Ok(()) => {
                live.set_enabled(DeviceId(device), thread, on);
                Answer::Ok
            }
            Err(r) => Answer::Refused(r),
        },
        Op::Wake { device } => match s.gate.tune(source) {
            Ok(()) => {
                live.wake(DeviceId(device));
                Answer::Ok
            }
            Err(r) => Answer::Refused(r),
        },
        Op::Sim { line } => match live.sim(&line) {
            None => Answer::NoSim,
            Some(Ok(said)) => Answer::Said(said),
            Some(Err(e)) => Answer::Error(e),
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
        if c.send(&Msg::Frame(Box::new(frame(s, c, now)))).is_err() {
            return;
        }
    }
}

/// The frame for one console: its bench device's traffic, the log lines it has not had.
fn frame(s: &Shared, c: &Conn, now: Instant) -> WireFrame {
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
    WireFrame {
        logs,
        trace: f.trace.iter().map(|e| WireTrace::of(e, now)).collect(),
        buckets: f.buckets,
        can_inject: f.can_inject,
        sim_vehicle: f.sim_vehicle,
        sim_faults: f.sim_faults,
        sim_names: f.sim_names,
        snap: f.snap,
    }
}
