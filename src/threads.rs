//! Threads, named and stoppable: a stop signal sleeping threads wake up for, a set of
//! named threads joined with a deadline (naming any that did not stop), whether each
//! still makes progress ([`Liveness`], which the service watchdog is fed by), [`Group`],
//! the one way a part that runs threads stops them, and [`every`], the one periodic
//! loop every periodic thread uses.
//!
//! **Liveness means progress.** A thread that has not ended may still be stuck — in a
//! system call on a port that never returns, on a lock — and a stuck status or command
//! thread leaves a device unread or uncommanded while everything else looks alive. So
//! each engine thread proves it turns its loop: at every turn it says, through its
//! [`Beat`] (two atomic stores: no lock, nothing allocated, so the command thread can
//! afford it), by when it will turn again — a bound it works out from its own period
//! and timeouts. A thread past that bound by more than [`STALL_GRACE`] is stalled
//! ([`Liveness::stalled`]) until it turns again.

use parking_lot::{Condvar, Mutex};
use std::sync::atomic::{AtomicBool, AtomicU64, AtomicU8, Ordering};
use std::sync::{Arc, OnceLock};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

/// A part of adrive that runs threads of its own (the network, the supervisor, the
/// gate's monitor, the control socket, the recorder, the live view, ROS 2): told to
/// shut down, it does what it must first (refuse new work, finish a file, close a
/// session), stops its threads and joins them within `deadline`. Every part stops the
/// same way, so the way out stops them one after the other and names, together, every
/// thread that did not stop. The engine is not one: its way out commands the safe
/// state first and says whether it was acknowledged ([`crate::engine::Engine::shutdown`]).
pub trait Shutdown {
    /// Stop within `deadline`; the names of the threads that did not stop.
    fn shutdown(self, deadline: Duration) -> Vec<String>;
}

/// A part that may not run (a recording, the live view, ROS 2, each when asked for).
impl<T: Shutdown> Shutdown for Option<T> {
    fn shutdown(self, deadline: Duration) -> Vec<String> {
        self.map(|p| p.shutdown(deadline)).unwrap_or_default()
    }
}

/// A stop signal that sleeping threads wake up for.
#[derive(Default)]
pub struct StopSignal {
    stopped: Mutex<bool>,
    cv: Condvar,
}

impl StopSignal {
    pub fn stop(&self) {
        *self.stopped.lock() = true;
        self.cv.notify_all();
    }
    pub(crate) fn is_stopped(&self) -> bool {
        *self.stopped.lock()
    }
    /// Sleep until `until`; false if stopped meanwhile.
    pub(crate) fn sleep_until(&self, until: Instant) -> bool {
        let mut s = self.stopped.lock();
        while !*s && Instant::now() < until {
            self.cv.wait_until(&mut s, until);
        }
        !*s
    }
}

/// Named threads with a stop signal, joined with a deadline.
#[derive(Default)]
pub(crate) struct Threads {
    handles: Vec<(String, JoinHandle<()>)>,
    states: Vec<Watched>,
}

/// One thread as [`Liveness`] sees it: its name, whether it runs, and its heartbeat if
/// it keeps one.
#[derive(Clone)]
struct Watched {
    name: String,
    state: Arc<AtomicU8>,
    heart: Option<Arc<Heart>>,
}

/// A thread spawned, not yet running its work.
const SPAWNED: u8 = 0;
/// A thread running its work.
const RUNNING: u8 = 1;
/// A thread whose work returned or panicked.
const ENDED: u8 = 2;

/// Marks its thread ended when dropped: when the work returns, and while a panic
/// unwinds it.
struct EndMark(Arc<AtomicU8>);

impl Drop for EndMark {
    fn drop(&mut self) {
        self.0.store(ENDED, Ordering::Release);
    }
}

impl Threads {
    pub(crate) fn spawn(
        &mut self,
        name: String,
        f: impl FnOnce() + Send + 'static,
    ) -> std::io::Result<()> {
        self.spawn_with(name, None, f)
    }

    /// [`Threads::spawn`], the thread keeping `heart` (its first bound counts from now).
    fn spawn_with(
        &mut self,
        name: String,
        heart: Option<Arc<Heart>>,
        f: impl FnOnce() + Send + 'static,
    ) -> std::io::Result<()> {
        let state = Arc::new(AtomicU8::new(SPAWNED));
        let mark = EndMark(state.clone());
        let h = std::thread::Builder::new()
            .name(name.clone())
            .spawn(move || {
                mark.0.store(RUNNING, Ordering::Release);
                f();
                drop(mark);
            })?;
        self.states.push(Watched {
            name: name.clone(),
            state,
            heart,
        });
        self.handles.push((name, h));
        Ok(())
    }

    /// Join the threads that have ended, forgetting them (a server whose clients come
    /// and go keeps only the live ones).
    pub(crate) fn reap(&mut self) {
        let (done, live): (Vec<_>, Vec<_>) = std::mem::take(&mut self.handles)
            .into_iter()
            .partition(|(_, h)| h.is_finished());
        self.handles = live;
        for (name, h) in done {
            let _ = h.join();
            self.states.retain(|w| w.name != name);
        }
    }

    /// Whether each thread runs and turns, readable from other threads while these run.
    pub(crate) fn liveness(&self) -> Liveness {
        Liveness(self.states.clone().into())
    }

    pub(crate) fn names(&self) -> Vec<&str> {
        self.handles.iter().map(|(n, _)| n.as_str()).collect()
    }

    /// Join every thread, waiting at most until `deadline`; returns the names of those
    /// still running (and logs them).
    pub(crate) fn join(self, deadline: Instant) -> Vec<String> {
        let mut stuck = Vec::new();
        for (name, h) in self.handles {
            while !h.is_finished() && Instant::now() < deadline {
                std::thread::sleep(Duration::from_millis(2));
            }
            if h.is_finished() {
                if h.join().is_err() {
                    tracing::error!(thread = %name, "thread panicked");
                }
            } else {
                tracing::error!(thread = %name, "thread did not stop in time");
                stuck.push(name);
            }
        }
        stuck
    }
}

/// The threads of one part (the network, the recorder, the supervisor, …) and the stop
/// signal they watch, stopped together: what every part that starts threads holds.
/// [`Group::stop`] signals, joins with a deadline and names the threads that did not
/// end; a group dropped without it (a panic unwinding, an error before the part was
/// up) signals its threads and does not wait for them.
#[derive(Default)]
pub struct Group {
    signal: Arc<StopSignal>,
    threads: Threads,
}

impl Group {
    /// A group whose threads watch `signal`, shared with others that stop them too.
    pub fn watching(signal: Arc<StopSignal>) -> Group {
        Group {
            signal,
            threads: Threads::default(),
        }
    }

    /// Start a named thread; `f` is handed the stop signal to watch.
    pub fn spawn(
        &mut self,
        name: impl Into<String>,
        f: impl FnOnce(&StopSignal) + Send + 'static,
    ) -> std::io::Result<()> {
        let signal = self.signal.clone();
        self.threads.spawn(name.into(), move || f(&signal))
    }

    /// Start a named thread that proves its progress: `f` is handed the stop signal and
    /// its [`Beat`], and must turn it at every turn of its loop; its first turn is due
    /// `first` after now (its start-up: opening a port, a first transaction).
    pub fn spawn_beating(
        &mut self,
        name: impl Into<String>,
        first: Duration,
        f: impl FnOnce(&StopSignal, &Beat) + Send + 'static,
    ) -> std::io::Result<()> {
        let name = name.into();
        let heart = Arc::new(Heart::new(&name, first));
        let beat = Beat(heart.clone());
        let signal = self.signal.clone();
        self.threads
            .spawn_with(name, Some(heart), move || f(&signal, &beat))
    }

    /// The stop signal its threads watch.
    pub fn signal(&self) -> &Arc<StopSignal> {
        &self.signal
    }

    pub fn names(&self) -> Vec<&str> {
        self.threads.names()
    }

    /// Whether each thread runs.
    pub(crate) fn liveness(&self) -> Liveness {
        self.threads.liveness()
    }

    /// Tell the threads to stop and join them, waiting at most until `deadline`; the
    /// names of those that did not end (logged). A second call finds none left.
    pub fn stop(&mut self, deadline: Instant) -> Vec<String> {
        self.signal.stop();
        std::mem::take(&mut self.threads).join(deadline)
    }
}

impl Drop for Group {
    fn drop(&mut self) {
        self.signal.stop();
    }
}

/// Whether each of a set of threads has started its work, whether it has ended
/// (returned or panicked), and — for a thread that keeps a heartbeat — whether it still
/// turns its loop, by name.
#[derive(Clone, Default)]
pub struct Liveness(Arc<[Watched]>);

/// A thread that has not turned its loop within its bound (and [`STALL_GRACE`]).
#[derive(Clone, Debug, PartialEq)]
pub struct Stall {
    pub thread: String,
    /// Since its last turn.
    pub quiet: Duration,
    /// The bound it gave at that turn: when it was to turn again.
    pub bound: Duration,
}

impl Stall {
    /// `steer/status has not turned its loop for 1.4 s (bound 0.45 s)`
    pub fn describe(&self) -> String {
        format!(
            "{} has not turned its loop for {:.1} s (bound {:.2} s)",
            self.thread,
            self.quiet.as_secs_f64(),
            self.bound.as_secs_f64()
        )
    }
}

impl Liveness {
    /// The names of the threads whose work has ended.
    pub fn ended(&self) -> Vec<&str> {
        self.names_in(ENDED)
    }

    /// The threads, running and keeping a heartbeat, that are past their bound by more
    /// than [`STALL_GRACE`] at `now`.
    pub fn stalled(&self, now: Instant) -> Vec<Stall> {
        self.0
            .iter()
            .filter(|w| w.state.load(Ordering::Acquire) == RUNNING)
            .filter_map(|w| {
                let heart = w.heart.as_ref()?;
                heart.stalled(now).map(|(quiet, bound)| Stall {
                    thread: w.name.clone(),
                    quiet,
                    bound,
                })
            })
            .collect()
    }

    /// These threads and `other`'s, watched as one set.
    pub(crate) fn with(&self, other: &Liveness) -> Liveness {
        Liveness(self.0.iter().chain(other.0.iter()).cloned().collect())
    }

    /// Every thread has started its work and none has ended.
    pub(crate) fn all_running(&self) -> bool {
        self.0
            .iter()
            .all(|w| w.state.load(Ordering::Acquire) == RUNNING)
    }

    /// Wait until every thread has started its work, at most until `deadline`; the
    /// names of those still not running (not yet started, or already ended).
    pub(crate) fn wait_running(&self, deadline: Instant) -> Vec<&str> {
        while !self.all_running() && Instant::now() < deadline {
            std::thread::sleep(Duration::from_millis(1));
        }
        self.0
            .iter()
            .filter(|w| w.state.load(Ordering::Acquire) != RUNNING)
            .map(|w| w.name.as_str())
            .collect()
    }

    fn names_in(&self, state: u8) -> Vec<&str> {
        self.0
            .iter()
            .filter(|w| w.state.load(Ordering::Acquire) == state)
            .map(|w| w.name.as_str())
            .collect()
    }
}

/// How far past its own bound a thread may be before it counts as stalled: the
/// scheduling noise of a loaded machine (a runnable thread waits its turn for a CPU),
/// never a hang. A thread's bound already holds every wait its loop may legitimately
/// make.
pub const STALL_GRACE: Duration = Duration::from_millis(500);

/// The time origin of heartbeats: an [`Instant`] as nanoseconds in an atomic.
fn epoch() -> Instant {
    static EPOCH: OnceLock<Instant> = OnceLock::new();
    *EPOCH.get_or_init(Instant::now)
}

fn nanos(t: Instant) -> u64 {
    t.saturating_duration_since(epoch()).as_nanos() as u64
}

/// A thread's heartbeat: when it last turned its loop and by when it said it would turn
/// again. Written by its thread only, read by anyone.
struct Heart {
    /// The last turn, ns since [`epoch`].
    at: AtomicU64,
    /// The next turn is due by then, ns since [`epoch`]: what the thread is judged by.
    due: AtomicU64,
    /// A hang injected for a test (`--inject-hang`).
    hang: Option<Hang>,
}

impl Heart {
    fn new(name: &str, first: Duration) -> Heart {
        let now = Instant::now();
        Heart {
            at: AtomicU64::new(nanos(now)),
            due: AtomicU64::new(nanos(now + first)),
            hang: HANG
                .get()
                .filter(|h| h.thread == name)
                .map(|h| Hang::new(now + h.after, h.hang)),
        }
    }

    /// How long since the last turn and the bound given then, if the thread is past
    /// that bound by more than [`STALL_GRACE`] at `now`.
    fn stalled(&self, now: Instant) -> Option<(Duration, Duration)> {
        let due = self.due.load(Ordering::Acquire);
        let now = nanos(now);
        if now <= due.saturating_add(STALL_GRACE.as_nanos() as u64) {
            return None;
        }
        let at = self.at.load(Ordering::Relaxed).min(due);
        Some((
            Duration::from_nanos(now - at),
            Duration::from_nanos(due - at),
        ))
    }
}

/// The thread's own side of its heartbeat (handed to it by [`Group::spawn_beating`]).
pub struct Beat(Arc<Heart>);

impl Beat {
    /// The thread turns its loop now and will turn it again within `within`: the longest
    /// its next wait and the work after it may legitimately take, from its own period
    /// and timeouts. Two atomic stores; no lock, nothing allocated.
    pub fn turn(&self, within: Duration) {
        if let Some(h) = &self.0.hang {
            h.maybe();
        }
        let now = Instant::now();
        self.0.at.store(nanos(now), Ordering::Relaxed);
        self.0.due.store(nanos(now + within), Ordering::Release);
    }
}

/// Fault injection for tests (`--inject-hang THREAD:AFTER:FOR`): one thread blocks in a
/// system call, once, `after` its start, for `hang` — as a port stuck in the kernel
/// would hold it — then carries on.
#[derive(Clone, Debug)]
pub(crate) struct HangSpec {
    pub thread: String,
    pub after: Duration,
    pub hang: Duration,
}

static HANG: OnceLock<HangSpec> = OnceLock::new();

/// Make the thread named `spec.thread` hang once (for tests; before the threads start).
pub(crate) fn inject_hang(spec: HangSpec) {
    let _ = HANG.set(spec);
}

struct Hang {
    at: Instant,
    hang: Duration,
    done: AtomicBool,
}

impl Hang {
    fn new(at: Instant, hang: Duration) -> Hang {
        Hang {
            at,
            hang,
            done: AtomicBool::new(false),
        }
    }

    fn maybe(&self) {
        if Instant::now() < self.at || self.done.swap(true, Ordering::Relaxed) {
            return;
        }
        let name = std::thread::current().name().unwrap_or("?").to_string();
        tracing::warn!(thread = %name, "injected hang: blocking in a system call for {:?} (--inject-hang)", self.hang);
        // A real system call (clock_nanosleep), as a read or write stuck in the kernel.
        std::thread::sleep(self.hang);
        tracing::warn!(thread = %name, "injected hang over");
    }
}

/// Run `tick` every `period` until `stop`; a turn that overruns its period is logged
/// and the next one starts at once (no burst of catch-up turns).
pub fn every(period: Duration, stop: &StopSignal, mut tick: impl FnMut()) {
    let mut next = Instant::now();
    loop {
        next += period;
        if !stop.sleep_until(next) {
            return;
        }
        let now = Instant::now();
        if now > next + period {
            next = now;
        }
        let t = Instant::now();
        tick();
        let took = t.elapsed();
        if took > period {
            tracing::debug!(
                thread = std::thread::current().name().unwrap_or("?"),
                "turn took {took:?} (period {period:?})"
            );
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every part's shutdown: its threads are told to stop and joined; one that does
    /// not end by the deadline is named, not waited for; a group dropped without
    /// stopping still tells its threads to stop.
    #[test]
    fn a_group_stops_its_threads_and_names_those_that_did_not_end() {
        let mut group = Group::default();
        group
            .spawn("waits", |stop| {
                stop.sleep_until(Instant::now() + Duration::from_secs(60));
            })
            .unwrap();
        let (release, held) = std::sync::mpsc::channel::<()>();
        group
            .spawn("deaf", move |_| {
                let _ = held.recv();
            })
            .unwrap();
        assert_eq!(group.names(), ["waits", "deaf"]);
        let t = Instant::now();
        let stuck = group.stop(Instant::now() + Duration::from_millis(300));
        assert_eq!(stuck, ["deaf"]);
        assert!(t.elapsed() < Duration::from_secs(30), "the deadline held");
        assert!(
            group.stop(Instant::now()).is_empty(),
            "nothing left to join"
        );
        drop(release);

        let signal = {
            let mut dropped = Group::default();
            let (tx, ended) = std::sync::mpsc::channel();
            dropped
                .spawn("waits", move |stop| {
                    stop.sleep_until(Instant::now() + Duration::from_secs(60));
                    let _ = tx.send(());
                })
                .unwrap();
            let signal = dropped.signal().clone();
            drop(dropped);
            ended
                .recv_timeout(Duration::from_secs(30))
                .expect("a dropped group's thread is told to stop");
            signal
        };
        assert!(signal.is_stopped());
    }

    /// The service watchdog stops being fed when a device thread ends: a thread that
    /// returns and one that panics are both seen as ended; one that waits is running.
    #[test]
    fn a_thread_that_returns_or_panics_is_seen_ended_one_that_waits_is_running() {
        let stop = Arc::new(StopSignal::default());
        let mut threads = Threads::default();
        let s = stop.clone();
        threads
            .spawn("waits".into(), move || {
                s.sleep_until(Instant::now() + Duration::from_secs(60));
            })
            .unwrap();
        let alive = threads.liveness();
        assert!(alive
            .wait_running(Instant::now() + Duration::from_secs(10))
            .is_empty());
        assert!(alive.ended().is_empty());
        threads.spawn("returns".into(), || {}).unwrap();
        threads
            .spawn("panics".into(), || panic!("injected in a test"))
            .unwrap();
        let alive = threads.liveness();
        let end = Instant::now() + Duration::from_secs(10);
        while alive.ended().len() < 2 && Instant::now() < end {
            std::thread::sleep(Duration::from_millis(1));
        }
        assert_eq!(alive.ended(), ["returns", "panics"]);
        assert!(!alive.all_running());
        stop.stop();
        threads.join(Instant::now() + Duration::from_secs(10));
        assert_eq!(alive.ended(), ["waits", "returns", "panics"]);
    }
}
