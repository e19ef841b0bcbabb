//! adrive under systemd: the notify protocol (`sd_notify(3)`) that tells the service
//! manager when adrive is ready (`READY=1`), that it is still sound (`WATCHDOG=1`), what
//! it is doing (`STATUS=…`) and that it is stopping (`STOPPING=1`).
//!
//! It exists so that `systemctl start adrive` returns once every device thread runs,
//! and so that systemd restarts adrive when it is no longer sound: the service watchdog
//! thread feeds the watchdog ([`Watchdog`]) only while every engine thread makes
//! progress — each device's status and command threads, each bus reader, the gate
//! monitor and the supervisor turn their loops within their bounds
//! ([`crate::threads::Liveness`]) — so a thread that ended or is stuck (in a system
//! call, on a lock) stops the feeding, said with its name, and systemd stops and
//! restarts the service after `WatchdogSec`. A stuck thread that turns again makes the
//! feeding resume.
//!
//! Each notification is one datagram to the socket named by `NOTIFY_SOCKET`: a path,
//! or an abstract socket written `@name` (which the `sd-notify` crate does not reach,
//! hence these few lines over a `UnixDatagram`). Without `NOTIFY_SOCKET` — adrive not
//! run by systemd — every call here does nothing.

use crate::threads::{Liveness, Stall};
use std::ffi::OsStr;
use std::os::unix::ffi::OsStrExt;
use std::os::unix::net::{SocketAddr, UnixDatagram};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::OnceLock;
use std::time::{Duration, Instant};

/// Where notifications go: the service manager's socket.
pub(crate) struct Notifier {
    socket: UnixDatagram,
    to: SocketAddr,
    /// A failed send was logged (once: the manager may be gone for good).
    warned: AtomicBool,
}

impl Notifier {
    /// The socket `NOTIFY_SOCKET` names (`/run/systemd/notify`, or `@name` for an
    /// abstract one); `None` when the variable is unset or names neither.
    pub(crate) fn at(var: &OsStr) -> Option<Notifier> {
        let to = address(var)?;
        let socket = UnixDatagram::unbound().ok()?;
        Some(Notifier {
            socket,
            to,
            warned: AtomicBool::new(false),
        })
    }

    /// Send `state`, newline-separated `KEY=VALUE` assignments, in one datagram.
    pub(crate) fn send(&self, state: &str) {
        if let Err(e) = self.socket.send_to_addr(state.as_bytes(), &self.to) {
            if !self.warned.swap(true, Ordering::Relaxed) {
                tracing::warn!("service manager notification failed (NOTIFY_SOCKET): {e}");
            }
        }
    }
}

/// The address `NOTIFY_SOCKET` names: a path starting with `/`, or an abstract
/// socket starting with `@`.
fn address(var: &OsStr) -> Option<SocketAddr> {
    match var.as_bytes() {
        [b'/', ..] => SocketAddr::from_pathname(var).ok(),
        [b'@', name @ ..] if !name.is_empty() => {
            use std::os::linux::net::SocketAddrExt;
            SocketAddr::from_abstract_name(name).ok()
        }
        _ => None,
    }
}

/// The service manager, read from the environment once.
fn manager() -> Option<&'static Notifier> {
    static MANAGER: OnceLock<Option<Notifier>> = OnceLock::new();
    MANAGER
        .get_or_init(|| std::env::var_os("NOTIFY_SOCKET").and_then(|v| Notifier::at(&v)))
        .as_ref()
}

fn notify(state: &str) {
    if let Some(m) = manager() {
        m.send(state);
    }
}

/// The status line while all is well, as [`ready`] said it (said again once a stalled
/// thread turns again).
static RUNNING: OnceLock<String> = OnceLock::new();

/// Startup is finished: every device thread runs. `status` is shown by
/// `systemctl status`.
pub(crate) fn ready(status: &str) {
    let _ = RUNNING.set(status.to_string());
    notify(&format!("READY=1\nSTATUS={status}"));
}

/// The stop has begun (the safe state comes next); `why` for `systemctl status`.
pub(crate) fn stopping(why: &str) {
    notify(&format!("STOPPING=1\nSTATUS=stopping: {why}"));
}

/// A line for `systemctl status`.
pub(crate) fn status(text: &str) {
    notify(&format!("STATUS={text}"));
}

/// `systemctl status` back to the line [`ready`] said: all is well again.
pub(crate) fn running() {
    status(RUNNING.get().map_or("running", String::as_str));
}

/// Tell the service manager adrive is still sound.
pub(crate) fn feed() {
    notify("WATCHDOG=1");
}

/// How often to feed the watchdog: half of `WATCHDOG_USEC`, as `sd_watchdog_enabled(3)`
/// advises; `None` when systemd keeps no watchdog on this process (no `WATCHDOG_USEC`,
/// or `WATCHDOG_PID` names another process).
pub(crate) fn watchdog_period() -> Option<Duration> {
    let usec = std::env::var("WATCHDOG_USEC").ok();
    let pid = std::env::var("WATCHDOG_PID").ok();
    watchdog_every(usec.as_deref(), pid.as_deref(), std::process::id())
}

fn watchdog_every(usec: Option<&str>, pid: Option<&str>, me: u32) -> Option<Duration> {
    let usec: u64 = usec?.trim().parse().ok().filter(|&u| u > 0)?;
    if let Some(pid) = pid {
        if pid.trim().parse::<u32>().ok()? != me {
            return None;
        }
    }
    Some(Duration::from_micros(usec) / 2)
}

/// The service watchdog, turned by the `service/watchdog` thread: `WATCHDOG=1` every
/// half `WATCHDOG_USEC`, and only while every thread it watches runs and turns its loop
/// within its bound. A thread that ended is logged once, at ERROR; a thread that
/// stalls is logged at ERROR when it stalls (`STATUS=` says which) and at WARN when it
/// turns again, and the feeding resumes.
pub(crate) struct Watchdog {
    every: Option<Duration>,
    fed: Option<Instant>,
    threads: Liveness,
    told: Vec<String>,
    /// The threads stalled at the last turn.
    stalled: Vec<Stall>,
}

/// What one turn of the [`Watchdog`] found.
#[derive(Debug, Default, PartialEq)]
pub(crate) struct Turn {
    /// `WATCHDOG=1` was sent.
    pub fed: bool,
    /// The threads stalled now.
    pub stalled: Vec<Stall>,
    /// Of those, the ones that stalled since the last turn.
    pub new: Vec<Stall>,
    /// The set of stalled threads is not the last turn's.
    pub changed: bool,
}

impl Watchdog {
    /// Watch `threads`, feeding at [`watchdog_period`].
    pub(crate) fn new(threads: Liveness) -> Watchdog {
        Watchdog::every(watchdog_period(), threads)
    }

    /// Watch `threads`, feeding every `every` (`None`: never, only watch).
    pub(crate) fn every(every: Option<Duration>, threads: Liveness) -> Watchdog {
        Watchdog {
            every,
            fed: None,
            threads,
            told: Vec::new(),
            stalled: Vec::new(),
        }
    }

    /// One turn at `now`: what it found, and whether the watchdog was fed.
    pub(crate) fn turn(&mut self, now: Instant) -> Turn {
        let effect = match self.every {
            Some(_) => {
                "the service watchdog is no longer fed: systemd will stop and restart adrive"
            }
            None => "adrive must be restarted",
        };
        let ended = self.threads.ended();
        for name in &ended {
            if !self.told.iter().any(|t| t == name) {
                tracing::error!(thread = %name, "thread ended: {effect}");
                status(&format!("thread {name} ended"));
                self.told.push(name.to_string());
            }
        }
        let stalled = self.threads.stalled(now);
        let was = |s: &Stall| self.stalled.iter().any(|t| t.thread == s.thread);
        let new: Vec<Stall> = stalled.iter().filter(|s| !was(s)).cloned().collect();
        for s in &new {
            tracing::error!(thread = %s.thread, "stalled: {}; {effect}", s.describe());
            status(&format!("stalled: {}", s.describe()));
        }
        let resumed: Vec<&Stall> = self
            .stalled
            .iter()
            .filter(|t| !stalled.iter().any(|s| s.thread == t.thread))
            .collect();
        for s in &resumed {
            let again = match (self.every, stalled.is_empty() && ended.is_empty()) {
                (Some(_), true) => ": the service watchdog is fed again",
                _ => "",
            };
            tracing::warn!(thread = %s.thread, "{} turns its loop again{again}", s.thread);
        }
        if !resumed.is_empty() && stalled.is_empty() && ended.is_empty() {
            running();
        }
        let changed = !new.is_empty() || !resumed.is_empty();
        self.stalled = stalled.clone();
        let fed = match self.every {
            Some(every) if ended.is_empty() && stalled.is_empty() => {
                let due = self
                    .fed
                    .is_none_or(|t| now.saturating_duration_since(t) >= every);
                if due {
                    feed();
                    self.fed = Some(now);
                }
                due
            }
            _ => false,
        };
        Turn {
            fed,
            stalled,
            new,
            changed,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::threads::{StopSignal, Threads};
    use std::sync::Arc;

    #[test]
    fn notify_socket_names_a_path_or_an_abstract_socket() {
        let path = address(OsStr::new("/run/systemd/notify")).unwrap();
        assert_eq!(
            path.as_pathname(),
            Some(std::path::Path::new("/run/systemd/notify"))
        );
        use std::os::linux::net::SocketAddrExt;
        let abs = address(OsStr::new("@adrive/notify")).unwrap();
        assert_eq!(abs.as_abstract_name(), Some(&b"adrive/notify"[..]));
        for other in ["", "@", "relative/path", "vsock:2:1234"] {
            assert!(address(OsStr::new(other)).is_none(), "{other:?}");
        }
    }

    /// systemd runs its managers in containers with an abstract `NOTIFY_SOCKET`:
    /// a notification reaches a socket bound there, as one datagram.
    #[test]
    fn a_notification_reaches_an_abstract_socket() {
        use std::os::linux::net::SocketAddrExt;
        let name = format!("adrive-test-notify-{}", std::process::id());
        let listener =
            UnixDatagram::bind_addr(&SocketAddr::from_abstract_name(name.as_bytes()).unwrap())
                .unwrap();
        listener
            .set_read_timeout(Some(Duration::from_secs(10)))
            .unwrap();
        let n = Notifier::at(OsStr::new(&format!("@{name}"))).unwrap();
        n.send("READY=1\nSTATUS=running");
        let mut buf = [0; 256];
        let got = listener.recv(&mut buf).unwrap();
        assert_eq!(&buf[..got], b"READY=1\nSTATUS=running");
    }

    #[test]
    fn the_watchdog_is_fed_at_half_its_period_and_only_for_this_process() {
        let half = Some(Duration::from_secs(5));
        assert_eq!(watchdog_every(Some("10000000"), None, 7), half);
        assert_eq!(watchdog_every(Some("10000000"), Some("7"), 7), half);
        assert_eq!(watchdog_every(Some("10000000"), Some("8"), 7), None);
        assert_eq!(watchdog_every(Some("10000000"), Some("x"), 7), None);
        assert_eq!(watchdog_every(Some("0"), None, 7), None);
        assert_eq!(watchdog_every(Some("soon"), None, 7), None);
        assert_eq!(watchdog_every(None, Some("7"), 7), None);
    }

    /// Fed once a period while every thread runs; never again once one has ended.
    #[test]
    fn the_watchdog_is_fed_only_while_every_thread_runs() {
        let stop = Arc::new(StopSignal::default());
        let mut threads = Threads::default();
        let s = stop.clone();
        threads
            .spawn("steer/status".into(), move || {
                s.sleep_until(Instant::now() + Duration::from_secs(60));
            })
            .unwrap();
        let alive = threads.liveness();
        assert!(alive
            .wait_running(Instant::now() + Duration::from_secs(10))
            .is_empty());
        let every = Duration::from_millis(500);
        let mut w = Watchdog::every(Some(every), alive.clone());
        let t0 = Instant::now();
        assert!(w.turn(t0).fed, "fed at the first turn");
        assert!(!w.turn(t0 + every / 2).fed, "not before its period");
        assert!(w.turn(t0 + every).fed, "fed again a period later");
        stop.stop();
        threads.join(Instant::now() + Duration::from_secs(10));
        assert_eq!(alive.ended(), ["steer/status"]);
        for k in 2..6 {
            assert!(!w.turn(t0 + every * k).fed, "fed after the thread ended");
        }
        assert_eq!(w.told, ["steer/status"], "said once");
    }

    /// Liveness is progress: a thread that runs but does not turn its loop within its
    /// bound (and the grace) stops the feeding, named; once it turns again the feeding
    /// resumes at once.
    #[test]
    fn the_watchdog_is_not_fed_while_a_thread_is_past_its_bound_and_is_once_it_turns() {
        use crate::threads::{Group, STALL_GRACE};
        let bound = Duration::from_millis(200);
        let mut group = Group::default();
        let (turn, turns) = std::sync::mpsc::channel::<Duration>();
        let (turned, done) = std::sync::mpsc::channel::<Instant>();
        group
            .spawn_beating("brake/command", bound, move |_, beat| {
                // Turns when told, with the bound it is told, as a loop stuck in a
                // system call would when the call returns.
                while let Ok(within) = turns.recv() {
                    beat.turn(within);
                    let _ = turned.send(Instant::now());
                }
            })
            .unwrap();
        let alive = group.liveness();
        assert!(alive
            .wait_running(Instant::now() + Duration::from_secs(10))
            .is_empty());
        // It turns between `before` and `t0`.
        let before = Instant::now();
        turn.send(bound).unwrap();
        let t0 = done.recv_timeout(Duration::from_secs(10)).unwrap();
        let every = Duration::from_millis(100);
        let mut w = Watchdog::every(Some(every), alive);
        let first = w.turn(t0);
        assert!(first.fed && first.stalled.is_empty());
        // Within its bound and the grace: still fed.
        let fed = (before + bound + STALL_GRACE).max(t0 + every);
        assert!(w.turn(fed).fed);
        // Past them: not fed, and named once.
        let late = t0 + bound + STALL_GRACE + Duration::from_millis(1);
        let stalled = w.turn(late);
        assert!(!stalled.fed);
        assert_eq!(stalled.new.len(), 1);
        assert_eq!(stalled.new[0].thread, "brake/command");
        assert_eq!(stalled.new[0].bound, bound);
        assert!(stalled.changed);
        let still = w.turn(late + every);
        assert!(!still.fed && !still.changed && still.new.is_empty());
        assert_eq!(still.stalled.len(), 1);
        // It turns again (with a bound that covers the turns below): fed at the next
        // turn, a period after the last feed, with no wait for another.
        turn.send(Duration::from_secs(60)).unwrap();
        done.recv_timeout(Duration::from_secs(10)).unwrap();
        let back = w.turn(fed + every);
        assert!(
            back.fed && back.changed && back.stalled.is_empty(),
            "{back:?}"
        );
    }
}
