//! The control socket's clients: [`Remote`], the [`Controls`] of `adrive attach` — the
//! same console over a running adrive's frames and intake — and [`once`], one
//! operator command for `adrive ctl`. Both reach adrive through a [`Dial`]: its
//! socket file, or a link over the fleet (`fleet::dial`) that carries the same
//! protocol.
//!
//! A thread (`attach/in`) reads what the server sends: frames replace the latest one,
//! replies wake the operation waiting for them. When the connection ends the console
//! is told through `on_gone`, and every waiting operation fails at once, with what is
//! known of who ended it: adrive's own word where it said why (`Bye`: it dropped this
//! console, it is stopping); else whether adrive still answers at its socket (it
//! closed this connection) or not (it went away).

use super::proto::{Answer, Msg, Op, Request, Role, WireScene, VERSION};
use crate::controls::{Controls, Scene, Tune};
use crate::logging::ring::{LogLine, KEEP};
use crate::safety::{Ask, Done, Refused};
use crate::value::{Command, DeviceId};
use crossbeam_channel::Sender;
use parking_lot::Mutex;
use std::collections::{HashMap, VecDeque};
use std::io::{BufRead, BufReader, Write};
use std::os::unix::net::UnixStream;
use std::path::PathBuf;
use std::sync::atomic::{AtomicU64, Ordering::Relaxed};
use std::sync::Arc;
use std::time::{Duration, Instant};

/// How long an operation waits for its reply.
pub(crate) const REPLY_WITHIN: Duration = Duration::from_secs(3);
/// How long connecting waits for the welcome (and a console for its first frame).
const HELLO_WITHIN: Duration = Duration::from_secs(5);

/// Why a client could not do what it was asked.
#[derive(Debug, thiserror::Error)]
pub(crate) enum ClientError {
    /// Nothing (or nothing that answers) at the path.
    #[error("no adrive at {path}: {why} (is it running? its socket is given with --socket PATH)")]
    Nobody { path: String, why: String },
    /// The server said no, or the connection ended (how, in words).
    #[error("{0}")]
    Refused(String),
    /// No reply in time.
    #[error("no reply from adrive within {} s", .0.as_secs())]
    NoReply(Duration),
}

/// A way to a running adrive: a stream that speaks the control protocol.
pub(crate) trait Dial: Send + Sync {
    /// A new connection to adrive.
    fn dial(&self) -> Result<UnixStream, ClientError>;
    /// Why a connection adrive closed without a word ended (`what`: how it ended
    /// here): whether adrive can still be reached tells which end it was.
    fn ended_without_word(&self, what: &str) -> String;
    /// Where the connection goes, for messages (`/run/user/1000/adrive/control.sock`).
    fn place(&self) -> String;
    /// Wait until the connections dialed, closed, have ended at the far end too (a
    /// link over the fleet says that it closes, so that a console that quit is not
    /// taken for one lost); the socket file's end at once.
    fn close(&self) {}
}

/// A running adrive's socket file.
impl Dial for PathBuf {
    fn dial(&self) -> Result<UnixStream, ClientError> {
        UnixStream::connect(self).map_err(|e| ClientError::Nobody {
            path: self.display().to_string(),
            why: e.to_string(),
        })
    }

    fn ended_without_word(&self, what: &str) -> String {
        match probe(self) {
            Ok(()) => format!(
                "adrive closed this console's connection without saying why ({what}); it still \
                 runs (`adrive ctl status` shows it)"
            ),
            Err(e) => format!("adrive went away ({what}); nothing answers at its socket now: {e}"),
        }
    }

    fn place(&self) -> String {
        self.display().to_string()
    }
}

fn connect(
    to: &dyn Dial,
    role: Role,
) -> Result<(UnixStream, BufReader<UnixStream>, String), ClientError> {
    let nobody = |e: std::io::Error| ClientError::Nobody {
        path: to.place(),
        why: e.to_string(),
    };
    let mut stream = to.dial()?;
    stream
        .set_read_timeout(Some(HELLO_WITHIN))
        .map_err(nobody)?;
    let hello = write_line(
        &mut stream,
        &Request {
            id: 0,
            op: Op::Hello {
                role,
                version: VERSION,
            },
        },
    );
    let mut reader = BufReader::new(stream.try_clone().map_err(nobody)?);
    // A server past its limit says why and closes at once, maybe before the hello
    // is written: what it said is read even then.
    let first = read_msg(&mut reader);
    if let Err(e) = hello {
        if !matches!(first, Ok(Some(Msg::Bye { .. }))) {
            return Err(nobody(e));
        }
    }
    match first.map_err(nobody)? {
        Some(Msg::Welcome { source, .. }) => Ok((stream, reader, source)),
        Some(Msg::Bye { why }) => Err(ClientError::Refused(why)),
        Some(other) => Err(ClientError::Refused(format!(
            "unexpected first message {other:?}"
        ))),
        None => Err(ClientError::Refused(
            "adrive closed the connection before it welcomed this client".into(),
        )),
    }
}

/// Whether an adrive answers `to` (without attaching to it).
pub(crate) fn probe(to: &dyn Dial) -> Result<(), ClientError> {
    connect(to, Role::Once).map(drop)
}

fn write_line(w: &mut impl Write, req: &Request) -> std::io::Result<()> {
    let mut line = serde_json::to_vec(req)?;
    line.push(b'\n');
    w.write_all(&line)
}

/// The next message; `None` at the end of the stream. Blank lines are skipped (adrive
/// starts its last word on a line of its own).
fn read_msg(r: &mut impl BufRead) -> std::io::Result<Option<Msg>> {
    let mut line = String::new();
    loop {
        line.clear();
        match r.read_line(&mut line) {
            Ok(0) => return Ok(None),
            // adrive ended with this client's words unread (killed, say): the kernel
            // resets the connection instead of closing it. To the client it is the
            // same end, told in the same words.
            Err(e) if e.kind() == std::io::ErrorKind::ConnectionReset => return Ok(None),
            Err(e) => return Err(e),
            Ok(_) => {}
        }
        if !line.trim().is_empty() {
            break;
        }
    }
    serde_json::from_str(&line)
        .map(Some)
        .map_err(|e| std::io::Error::new(std::io::ErrorKind::InvalidData, e))
}

/// One operator command (`adrive ctl`): connect, do `op`, return its answer.
pub(crate) fn once(to: &dyn Dial, op: Op) -> Result<Answer, ClientError> {
    let answer = once_on(to, op);
    to.close();
    answer
}

fn once_on(to: &dyn Dial, op: Op) -> Result<Answer, ClientError> {
    let (mut stream, mut reader, _) = connect(to, Role::Once)?;
    let gone =
        |e: std::io::Error| ClientError::Refused(format!("the connection to adrive failed: {e}"));
    stream.set_read_timeout(Some(REPLY_WITHIN)).map_err(gone)?;
    write_line(&mut stream, &Request { id: 1, op }).map_err(gone)?;
    loop {
        match read_msg(&mut reader) {
            Ok(Some(Msg::Reply { id: 1, answer })) => return Ok(answer),
            Ok(Some(Msg::Bye { why })) => return Err(ClientError::Refused(why)),
            Ok(Some(_)) => continue,
            Ok(None) => {
                return Err(ClientError::Refused(
                    to.ended_without_word("the connection closed before an answer"),
                ))
            }
            Err(e)
                if matches!(
                    e.kind(),
                    std::io::ErrorKind::WouldBlock | std::io::ErrorKind::TimedOut
                ) =>
            {
                return Err(ClientError::NoReply(REPLY_WITHIN))
            }
            Err(e) => return Err(gone(e)),
        }
    }
}

/// What the reading thread shares with the console.
struct Inbox {
    /// The latest frame and when it arrived.
    latest: Mutex<(WireScene, Instant)>,
    logs: Mutex<VecDeque<LogLine>>,
    pending: Mutex<HashMap<u64, Sender<Answer>>>,
    gone: Mutex<Option<String>>,
}

/// [`Controls`] over a running adrive's control socket.
pub(crate) struct Remote {
    /// The source this console is to the intake (`console #2`).
    pub source: String,
    writer: Mutex<UnixStream>,
    inbox: Arc<Inbox>,
    next: AtomicU64,
    /// The bench device last asked for.
    bench: Mutex<Option<Option<DeviceId>>>,
}

impl Remote {
    /// Attach to the adrive `to` reaches as a console. `on_gone` is called once, from
    /// the reading thread, if the connection ends.
    pub(crate) fn attach(
        to: Arc<dyn Dial>,
        on_gone: impl FnOnce(String) + Send + 'static,
    ) -> Result<Remote, ClientError> {
        let (stream, mut reader, source) = connect(&*to, Role::Console)?;
        let first = loop {
            match read_msg(&mut reader) {
                Ok(Some(Msg::Frame(f))) => break *f,
                Ok(Some(_)) => continue,
                Ok(None) => {
                    return Err(ClientError::Refused(to.ended_without_word(
                        "the connection closed before the first frame",
                    )))
                }
                Err(e) => return Err(ClientError::Refused(format!("no frame from adrive: {e}"))),
            }
        };
        let _ = stream.set_read_timeout(None);
        let inbox = Arc::new(Inbox {
            latest: Mutex::new((WireScene::default(), Instant::now())),
            logs: Mutex::new(VecDeque::with_capacity(KEEP)),
            pending: Mutex::new(HashMap::new()),
            gone: Mutex::new(None),
        });
        inbox.take(first);
        let i = inbox.clone();
        std::thread::Builder::new()
            .name("attach/in".into())
            .spawn(move || {
                let why = loop {
                    match read_msg(&mut reader) {
                        Ok(Some(Msg::Frame(f))) => i.take(*f),
                        Ok(Some(Msg::Reply { id, answer })) => {
                            if let Some(tx) = i.pending.lock().remove(&id) {
                                let _ = tx.send(answer);
                            }
                        }
                        Ok(Some(Msg::Bye { why })) => break why,
                        Ok(Some(Msg::Welcome { .. })) => {}
                        // A frame cut short where adrive dropped this console: its
                        // word follows on a line of its own.
                        Err(e) if e.kind() == std::io::ErrorKind::InvalidData => {}
                        Ok(None) => break to.ended_without_word("the connection closed"),
                        Err(e) => {
                            break to.ended_without_word(&format!("the connection failed: {e}"))
                        }
                    }
                };
                *i.gone.lock() = Some(why.clone());
                i.pending.lock().clear();
                on_gone(why);
            })
            .map_err(|e| ClientError::Refused(e.to_string()))?;
        Ok(Remote {
            source,
            writer: Mutex::new(stream),
            inbox,
            next: AtomicU64::new(1),
            bench: Mutex::new(None),
        })
    }

    /// Send `op` without waiting for its reply.
    fn post(&self, op: Op) {
        let id = self.next.fetch_add(1, Relaxed);
        let _ = write_line(&mut *self.writer.lock(), &Request { id, op });
    }

    /// Do `op` and wait for its answer.
    fn call(&self, op: Op) -> Result<Answer, String> {
        if let Some(why) = self.inbox.gone.lock().clone() {
            return Err(why);
        }
        let id = self.next.fetch_add(1, Relaxed);
        let (tx, rx) = crossbeam_channel::bounded(1);
        self.inbox.pending.lock().insert(id, tx);
        if let Err(e) = write_line(&mut *self.writer.lock(), &Request { id, op }) {
            self.inbox.pending.lock().remove(&id);
            return Err(format!("the connection to adrive failed: {e}"));
        }
        rx.recv_timeout(REPLY_WITHIN).map_err(|_| {
            self.inbox.pending.lock().remove(&id);
            match self.inbox.gone.lock().clone() {
                Some(why) => why,
                None => ClientError::NoReply(REPLY_WITHIN).to_string(),
            }
        })
    }
}

/// A console that goes closes its connection at once (its reading thread holds the
/// stream too): adrive sees it gone when it quits, not when its process ends.
impl Drop for Remote {
    fn drop(&mut self) {
        let _ = self.writer.lock().shutdown(std::net::Shutdown::Both);
    }
}

impl Inbox {
    fn take(&self, mut f: WireScene) {
        let mut logs = self.logs.lock();
        for l in f.logs.drain(..) {
            if logs.len() == KEEP {
                logs.pop_front();
            }
            logs.push_back(l.line());
        }
        *self.latest.lock() = (f, Instant::now());
    }
}

impl Controls for Remote {
    fn scene(&self, now: Instant, bench: Option<DeviceId>) -> Scene {
        {
            let mut asked = self.bench.lock();
            if *asked != Some(bench) {
                *asked = Some(bench);
                self.post(Op::Bench {
                    device: bench.map(|d| d.0),
                });
            }
        }
        let (f, at) = self.inbox.latest.lock().clone();
        Scene {
            logs: self.inbox.logs.lock().iter().cloned().collect(),
            trace: f.trace.iter().map(|t| t.entry(at)).collect(),
            buckets: f.buckets,
            can_inject: f.can_inject,
            read_only: false,
            sim_vehicle: f.sim_vehicle,
            sim_faults: f.sim_faults,
            sim_names: f.sim_names,
            you: Some(self.source.clone()),
            teleop: f.teleop,
            quiet: Some(now.saturating_duration_since(at))
                .filter(|q| *q > crate::controls::scene::QUIET_AFTER),
            snap: f.snap,
        }
    }
    fn parse(&self, id: DeviceId, text: &str) -> Result<Command, String> {
        match self.call(Op::Parse {
            device: id.0,
            text: text.into(),
        })? {
            Answer::Command(c) => Ok(c),
            Answer::Error(e) => Err(e),
            other => Err(format!("unexpected answer {other:?}")),
        }
    }
    /// Refused with the intake's reason, or with why adrive could not be asked.
    fn ask(&self, ask: Ask) -> Result<Done, Refused> {
        match self.call(Op::of_ask(ask)) {
            Ok(Answer::Done(d)) => Ok(d),
            Ok(Answer::Refused(r)) => Err(r),
            Ok(Answer::Error(e)) | Err(e) => Err(Refused::Unanswered(e)),
            Ok(other) => Err(Refused::Unanswered(format!("unexpected answer {other:?}"))),
        }
    }
    fn tune(&self, tune: Tune) -> Result<(), String> {
        match self.call(Op::of_tune(tune))? {
            Answer::Refused(r) => Err(r.to_string()),
            Answer::Error(e) => Err(e),
            _ => Ok(()),
        }
    }
    fn set_interlocks(&self, on: bool) -> Result<(), Refused> {
        match self.call(Op::Interlocks { on }) {
            Ok(Answer::Refused(r)) => Err(r),
            Ok(Answer::Error(e)) | Err(e) => Err(Refused::Unanswered(e)),
            Ok(_) => Ok(()),
        }
    }
    fn deadman(&self, armed: Option<Duration>) {
        self.post(Op::Deadman {
            ms: armed.map(|d| d.as_millis() as u64),
        });
    }
    fn sim(&self, line: &str) -> Option<Result<String, String>> {
        match self.call(Op::Sim { line: line.into() }) {
            Ok(Answer::NoSim) => None,
            Ok(Answer::Said(s)) => Some(Ok(s)),
            Ok(Answer::Error(e)) | Err(e) => Some(Err(e)),
            Ok(Answer::Refused(r)) => Some(Err(r.to_string())),
            Ok(other) => Some(Err(format!("unexpected answer {other:?}"))),
        }
    }
    /// A proof goes to adrive at once; adrive takes its arrival as the proof's time
    /// (the two clocks are not the same), and answers nothing.
    fn answered(&self, _at: Instant) {
        self.post(Op::Answered);
    }
    /// Refused here, before anything is sent: a run belongs to the console of the
    /// process that runs the engine (its leaving ends the run), and nothing of it
    /// travels over the control socket.
    fn characterize_check(&self, _: DeviceId) -> Result<String, String> {
        Err(crate::controls::CHARACTERIZE_WHERE.into())
    }
    fn characterize(
        &self,
        _: DeviceId,
        _: &[crate::characterize::Procedure],
        _: &std::path::Path,
    ) -> Result<(), String> {
        Err(crate::controls::CHARACTERIZE_WHERE.into())
    }
    fn characterizing(&self) -> Option<crate::controls::Characterizing> {
        None
    }
    fn characterize_end(&self, _: &str) {}
}

#[cfg(test)]
mod tests {
    use super::*;

    /// adrive gone with the client's last words unread resets the connection; the
    /// client reads it as the end it is, not as a failure.
    #[test]
    fn an_end_with_the_clients_words_unread_is_an_end() {
        for raw in [true, false] {
            let (mut client, adrive) = UnixStream::pair().unwrap();
            write_line(
                &mut client,
                &Request {
                    id: 1,
                    op: Op::Status,
                },
            )
            .unwrap();
            drop(adrive);
            let mut reader = BufReader::new(client);
            if raw {
                // What the kernel does, so that the case below is the reset one.
                let e = reader.read_line(&mut String::new()).unwrap_err();
                assert_eq!(e.kind(), std::io::ErrorKind::ConnectionReset);
            } else {
                assert!(matches!(read_msg(&mut reader), Ok(None)));
            }
        }
    }
}
