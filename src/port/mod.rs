//! What carries one device's bytes and commands, below the vehicle that holds it: its
//! port, shared under the port's rule (here), its latest-wins command slot ([`slot`])
//! and the trace of its traffic ([`trace`]). A layer of its own: it imports the driver,
//! the configuration and the values only, so the vehicle holds a device's port and
//! slot, and safety reads what a slot has on its way, without reaching up into the
//! engine, whose threads drive them (`crate::engine`).
//!
//! The shared port of one device and the rule by which its two threads take turns.
//!
//! The paper's Adrive guarded the port with a plain mutex. Field testing found
//! commands waiting ~200 ms: while a command was on the wire the status thread queued
//! on the mutex, took the port as soon as the command finished, and the next command
//! then waited for the whole status poll. The paper patched it with a 10 Hz rate cap.
//!
//! adrive's rule ([`PortRule::Priority`]): a status poll yields while a command waits
//! — whether the command thread is already queued on the port or the command is still
//! in its slot — and a command thread that finishes with a newer command pending keeps
//! the port for it. A poll still runs once it is `status_max_age` overdue, so the cache
//! never goes stale under a command flood. The paper's first-come-first-served lock
//! stays available ([`PortRule::Paper`]) so the difference can be shown.
//!
//! The [`Conn`] behind the arbiter owns the driver and the open port: it opens the port
//! lazily, reopens it with exponential backoff after a disconnect (capped at
//! [`BACKOFF_MAX`], for as long as adrive runs: a device gone never ends the run), and
//! timestamps the
//! first byte of every transaction the moment the kernel has taken it. It also decides
//! when input nobody asked for may be waiting: only after a transaction that failed or
//! timed out (a late reply may follow) or a fresh open. After a clean transaction the
//! reply was read to its end, so the driver's discard before the next request is
//! skipped — one system call less between a command and the wire.
//!
//! **A late reply is never taken for the next request's answer.** A device that
//! answers after the deadline of a request would have its reply read as the answer to
//! the next one — the same shape when both are polls — and look healthy while it is
//! slow. So an exchange that ends at its deadline with nothing heard — its whole reply
//! may still come — drains the line before the port is let go ([`Conn::drain`]): it
//! reads and drops whatever arrives until the line has been quiet for a while — as long
//! as the device's silence rule affords ([`drain_quiet`]: up to a whole reply timeout),
//! or, once the device has been seen answering late, as late as it answered and a
//! quarter of a reply timeout more (up to two). A reply that came meanwhile says the
//! device is slow ([`DriverError::Late`]). A reply begun and cut short, or a device that
//! trickles, leaves only a tail, which the next reply's framing refuses: there the port
//! is let go at once. The drain never costs
//! a device that lost one request more than its `status_max_age` leaves after its
//! period and one reply timeout, so one lost frame never makes it silent. (Requests of different
//! shapes are also told apart by each driver: a Modbus reply must echo its request's
//! function, byte count or written value, a line-protocol ack is no status line, an
//! ELM327 reply names its PID.)

use self::slot::CommandSlot;
use self::trace::{Dir, Trace};
use crate::config::PortRule;
use crate::driver::{Driver, DriverError, Link};
use parking_lot::{Condvar, Mutex, MutexGuard};
use std::io::{self, Read, Write};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering::Relaxed};
use std::sync::Arc;
use std::time::{Duration, Instant};

pub(crate) mod slot;
pub mod trace;
pub(crate) mod wake;

/// What readers may know of a device's port without touching it.
#[derive(Default, Debug)]
pub struct PortHealth {
    /// Times the port was opened (1 after start; more after reconnects).
    pub opens: AtomicU64,
    /// The last attempt to open it failed: the port is gone (unplugged, wrong path).
    pub missing: AtomicBool,
    /// While it is gone: how long after a failed open it is tried again, ms (the
    /// backoff, doubling up to its cap).
    pub retry_ms: AtomicU64,
}

/// Opens a device's port (a serial port, a pseudo-terminal, a test double).
pub(crate) type Opener = Box<dyn FnMut() -> io::Result<Box<dyn Link>> + Send>;

const BACKOFF_MIN: Duration = Duration::from_millis(100);
/// The longest wait between two tries to open a port that is gone.
pub const BACKOFF_MAX: Duration = crate::snapshot::RETRY_AT_MOST;
/// After this many failed transactions in a row the port is closed and reopened, and
/// the driver's `open` runs again (it un-wedges adapters such as the ELM327).
pub(crate) const REOPEN_AFTER: u32 = 5;

#[derive(Default)]
struct Arb {
    busy: bool,
    /// The port is held across threads: a command's request went out from the thread
    /// that admitted it, and the device's command thread is to read the reply
    /// ([`PortGuard::hand_over`], [`Port::resume`]). `busy` stays set throughout.
    handed: bool,
    /// Command threads queued for the port.
    commands_waiting: u32,
    /// An overdue status poll is next in line.
    status_urgent: bool,
    next_ticket: u64,
    serving: u64,
    stopped: bool,
}

/// The arbiter of one device's port.
pub struct Port {
    rule: PortRule,
    /// The longest one transaction may hold it: the drain after a missed reply, then the
    /// driver's longest ([`Driver::longest`]).
    longest: Duration,
    arb: Mutex<Arb>,
    cv: Condvar,
    conn: Mutex<Conn>,
}

/// The port, held by one thread for one or more transactions.
pub(crate) struct PortGuard<'a> {
    port: &'a Port,
    conn: Option<MutexGuard<'a, Conn>>,
}

impl Port {
    pub fn new(rule: PortRule, conn: Conn) -> Port {
        Port {
            rule,
            longest: conn.longest_drain() + conn.driver.longest(),
            arb: Mutex::new(Arb::default()),
            cv: Condvar::new(),
            conn: Mutex::new(conn),
        }
    }

    pub fn rule(&self) -> PortRule {
        self.rule
    }

    /// The longest one transaction may hold the port: a thread waiting for it waits no
    /// longer than this for the holder.
    pub fn longest(&self) -> Duration {
        self.longest
    }

    fn take(&self, mut a: MutexGuard<'_, Arb>) -> Option<PortGuard<'_>> {
        if a.stopped {
            return None;
        }
        a.busy = true;
        drop(a);
        Some(PortGuard {
            port: self,
            conn: Some(self.conn.lock()),
        })
    }

    fn wait_ticket(&self, a: &mut MutexGuard<'_, Arb>) {
        let ticket = a.next_ticket;
        a.next_ticket += 1;
        while !a.stopped && (a.busy || a.serving != ticket) {
            self.cv.wait(a);
        }
        a.serving += 1;
    }

    /// Take the port for a command. `None` once stopped.
    pub(crate) fn acquire_command(&self) -> Option<PortGuard<'_>> {
        let mut a = self.arb.lock();
        match self.rule {
            PortRule::Paper => self.wait_ticket(&mut a),
            PortRule::Priority => {
                a.commands_waiting += 1;
                while !a.stopped && (a.busy || a.status_urgent) {
                    self.cv.wait(&mut a);
                }
                a.commands_waiting -= 1;
            }
        }
        self.take(a)
    }

    /// Take the port for a command at once, only if it is idle: nobody holds it, no
    /// command thread is queued for it, no overdue status poll is waiting, and the
    /// device's driver can write a request now without waiting. Never under the paper's
    /// rule (first come, first served: no command may jump the queue). `None`
    /// otherwise; it never blocks.
    pub(crate) fn try_acquire_idle(&self) -> Option<PortGuard<'_>> {
        if self.rule != PortRule::Priority {
            return None;
        }
        let mut a = self.arb.lock();
        if a.stopped || a.busy || a.commands_waiting > 0 || a.status_urgent {
            return None;
        }
        // Asked before the port is marked busy, so a refusal wakes nobody. Free while
        // the port is not busy; a release still under way is a refusal too.
        let conn = self.conn.try_lock()?;
        if !conn.ready_at_once() {
            return None;
        }
        a.busy = true;
        drop(a);
        Some(PortGuard {
            port: self,
            conn: Some(conn),
        })
    }

    /// Take back the port a [`PortGuard::hand_over`] left held, in the thread that is to
    /// finish its transaction. `None` if nothing was handed over.
    pub(crate) fn resume(&self) -> Option<PortGuard<'_>> {
        let mut a = self.arb.lock();
        if !a.handed {
            return None;
        }
        debug_assert!(a.busy, "a handed-over port stays busy");
        a.handed = false;
        drop(a);
        Some(PortGuard {
            port: self,
            conn: Some(self.conn.lock()),
        })
    }

    /// Take the port for a status poll, yielding to commands until `overdue_at`.
    /// `None` once stopped.
    pub(crate) fn acquire_status(
        &self,
        overdue_at: Instant,
        slot: &CommandSlot,
    ) -> Option<PortGuard<'_>> {
        let mut a = self.arb.lock();
        match self.rule {
            PortRule::Paper => self.wait_ticket(&mut a),
            PortRule::Priority => loop {
                if a.stopped {
                    return None;
                }
                let overdue = Instant::now() >= overdue_at;
                let command_waiting = a.commands_waiting > 0 || slot.has_pending();
                if !a.busy && (overdue || !command_waiting) {
                    break;
                }
                if overdue {
                    a.status_urgent = true;
                    self.cv.wait(&mut a);
                } else {
                    // Woken by a release; re-check at the deadline in any case.
                    self.cv.wait_until(&mut a, overdue_at);
                }
            },
        }
        a.status_urgent = false;
        self.take(a)
    }

    /// Wake every waiter and refuse further acquisitions.
    pub fn stop(&self) {
        self.arb.lock().stopped = true;
        self.cv.notify_all();
    }
}

impl PortGuard<'_> {
    /// Run one transaction; returns its result and when its first byte was written.
    pub(crate) fn transact<T>(
        &mut self,
        f: impl FnOnce(&mut dyn Driver, &mut dyn Link) -> Result<T, DriverError>,
    ) -> (Result<T, DriverError>, Option<Instant>) {
        self.conn.as_mut().expect("held").transact(f)
    }

    /// Write a command's request: the first half of a transaction split in two
    /// ([`crate::driver::Driver::send_command`]). Returns its result and when its first
    /// byte was taken by the kernel. The port's bookkeeping (failures, what to discard
    /// next) counts a failed half as a failed transaction; after a good one,
    /// [`PortGuard::finish_command`] must follow on this port, in this thread or — after
    /// [`PortGuard::hand_over`] — in the one that resumes it.
    pub(crate) fn send_command(
        &mut self,
        command: crate::value::Command,
    ) -> (Result<(), DriverError>, Option<Instant>) {
        self.conn.as_mut().expect("held").send_half(command)
    }

    /// Read and check the reply to the request [`PortGuard::send_command`] wrote: the
    /// second half, which ends the transaction.
    pub(crate) fn finish_command(&mut self) -> Result<(), DriverError> {
        self.conn.as_mut().expect("held").finish_half()
    }

    /// Leave the port held — `busy`, so no status poll and no other command can take it
    /// — while this thread lets go of it, for the thread that calls [`Port::resume`].
    /// With `reply_expected` (the request went out), the reply — or its deadline — is
    /// to wake that thread ([`wake::PortWake::arm`]); returns whether it will, or the
    /// thread must be woken otherwise.
    pub(crate) fn hand_over(mut self, reply_expected: bool) -> bool {
        let armed = reply_expected && self.conn.as_ref().expect("held").arm_wake();
        drop(self.conn.take());
        self.port.arb.lock().handed = true;
        // Not dropped: the port stays busy until the resumed guard is.
        std::mem::forget(self);
        armed
    }

    /// The handed-over transaction is over: what was armed to wake its reader and did
    /// not is disarmed.
    pub(crate) fn disarm_wake(&self) {
        self.conn.as_ref().expect("held").disarm_wake();
    }

    /// An overdue status poll is waiting: let it have the port next.
    pub(crate) fn status_waiting(&self) -> bool {
        self.port.arb.lock().status_urgent
    }
}

impl Drop for PortGuard<'_> {
    fn drop(&mut self) {
        drop(self.conn.take());
        self.port.arb.lock().busy = false;
        self.port.cv.notify_all();
    }
}

/// The driver and its open port.
pub struct Conn {
    driver: Box<dyn Driver>,
    link: Option<Box<dyn Link>>,
    opener: Opener,
    next_open: Instant,
    backoff: Duration,
    /// Open count and whether the port can be opened (shared with readers).
    health: Arc<PortHealth>,
    trace: Arc<Trace>,
    failures: u32,
    /// The last transaction succeeded: its reply was read to the end, nothing is left
    /// on the line to discard.
    clean: bool,
    /// Why the last open failed, repeated while waiting to retry.
    open_error: Option<String>,
    /// Reopens after failed transactions (a device that stays silent is reopened every
    /// few transactions): logged when they start, then once a minute with a count.
    reopens: crate::logging::Repeats,
    /// The next open is to be logged ("port reopened"): after a disconnect, or after
    /// a reopen that was logged.
    announce_open: bool,
    /// The device's reply timeout: what the drain after a missed reply is measured in.
    reply_timeout: Duration,
    /// How long the line must be quiet after a missed reply ([`drain_quiet`]).
    quiet_base: Duration,
    /// How long after its deadline the latest late reply came.
    seen_late: Duration,
    /// The last exchange heard something after its request (a reply begun, a
    /// trickle): a miss then leaves no whole late reply to come.
    heard: bool,
    /// What the device's command thread sleeps on, for a request handed over to it to
    /// wake it by its reply ([`PortGuard::hand_over`]).
    wake: Option<Arc<wake::PortWake>>,
}

impl Conn {
    pub fn new(
        driver: Box<dyn Driver>,
        opener: Opener,
        trace: Arc<Trace>,
        health: Arc<PortHealth>,
        config: &crate::config::DeviceConfig,
    ) -> Conn {
        Conn {
            driver,
            link: None,
            opener,
            next_open: Instant::now(),
            backoff: BACKOFF_MIN,
            health,
            trace,
            failures: 0,
            clean: false,
            open_error: None,
            reopens: crate::logging::Repeats::default(),
            announce_open: false,
            reply_timeout: config.reply_timeout,
            quiet_base: drain_quiet(config),
            seen_late: Duration::ZERO,
            heard: false,
            wake: None,
        }
    }

    /// Have the reply to a request handed over wake the command thread sleeping on
    /// `wake`.
    pub(crate) fn woken_by(mut self, wake: Arc<wake::PortWake>) -> Conn {
        self.wake = Some(wake);
        self
    }

    /// Arm the command thread's wake-up on the reply to the request just written (see
    /// [`wake`]). False when nothing was armed — no wake-up, a link without a
    /// descriptor, a failure — and the thread must be woken otherwise.
    fn arm_wake(&self) -> bool {
        let (Some(w), Some(link)) = (&self.wake, &self.link) else {
            return false;
        };
        link.reply_fd()
            .is_some_and(|fd| w.arm(fd, self.reply_timeout).is_ok())
    }

    fn disarm_wake(&self) {
        if let Some(w) = &self.wake {
            w.disarm(self.link.as_ref().and_then(|l| l.reply_fd()));
        }
    }

    /// How long the line must be quiet after a missed reply before the next request:
    /// [`drain_quiet`], or — once the device has been seen answering late — as late as
    /// it answered and a quarter of a reply timeout more, up to two reply timeouts.
    fn quiet(&self) -> Duration {
        self.quiet_base
            .max(self.seen_late + self.reply_timeout / 4)
            .min(self.reply_timeout * 2)
    }

    /// The longest a drain may take: twice the longest quiet.
    fn longest_drain(&self) -> Duration {
        self.reply_timeout * 4
    }

    /// A transaction that missed its deadline with nothing heard: its whole reply may
    /// still come. Before the port is let go, read and drop what the device still sends
    /// until the line has been quiet for [`Conn::quiet`] since the deadline or the last
    /// byte (at most twice that in all, so a babbling device cannot hold the port);
    /// every byte goes to the device's trace. Returns how late the reply came, if it
    /// did. Done here, by the thread that missed, before it lets the port go: a
    /// command's own transaction never drains between its wire check and its write.
    fn drain(&mut self) -> Option<Duration> {
        let missed = Instant::now();
        let quiet = self.quiet();
        let link = self.link.as_mut()?;
        let cap = missed + quiet * 2;
        let mut until = missed + quiet;
        let mut late = None;
        let mut buf = [0u8; 64];
        while Instant::now() < until.min(cap) {
            let wait = until.min(cap).saturating_duration_since(Instant::now());
            if link
                .set_timeout(wait.max(Duration::from_millis(1)))
                .is_err()
            {
                break;
            }
            match link.read(&mut buf) {
                Ok(n) if n > 0 => {
                    let at = Instant::now();
                    self.trace.record(Dir::In, &buf[..n]);
                    late.get_or_insert(at.saturating_duration_since(missed));
                    until = at + quiet;
                }
                Err(e) if e.kind() == io::ErrorKind::Interrupted => {}
                Err(e) if e.kind() == io::ErrorKind::TimedOut => {}
                // Closed or failing: the next transaction will see.
                _ => break,
            }
        }
        if let Some(l) = late {
            self.seen_late = self.seen_late.max(l);
        }
        late
    }

    /// The result of an exchange that ended with `r`: one that missed its deadline with
    /// nothing heard is drained ([`Conn::drain`]), and says so when its reply came late
    /// — the device is slower than its reply timeout.
    fn drained<T>(&mut self, r: Result<T, DriverError>) -> Result<T, DriverError> {
        match r {
            Err(DriverError::Timeout(within)) if !self.heard => match self.drain() {
                Some(late) => Err(DriverError::Late { within, late }),
                None => Err(DriverError::Timeout(within)),
            },
            r => r,
        }
    }

    fn fail_open(&mut self) {
        self.link = None;
        self.announce_open = true;
        self.next_open = Instant::now() + self.backoff;
        self.health
            .retry_ms
            .store(self.backoff.as_millis() as u64, Relaxed);
        self.backoff = (self.backoff * 2).min(BACKOFF_MAX);
    }

    fn ensure_open(&mut self) -> Result<(), DriverError> {
        if self.link.is_some() {
            return Ok(());
        }
        if Instant::now() < self.next_open {
            // Waiting to retry: the same words as the failed open, so a log that
            // reports changes of error stays quiet until something changes.
            return Err(DriverError::Io(io::Error::new(
                io::ErrorKind::NotConnected,
                self.open_error.as_deref().unwrap_or("port closed"),
            )));
        }
        let mut link = match (self.opener)() {
            Ok(l) => l,
            Err(e) => {
                self.health.missing.store(true, Relaxed);
                self.open_error = Some(e.to_string());
                self.fail_open();
                return Err(DriverError::Io(e));
            }
        };
        self.health.missing.store(false, Relaxed);
        self.open_error = None;
        let mut traced = Stamped {
            inner: link.as_mut(),
            first_write: None,
            trace: &self.trace,
            clean: false,
            heard: false,
        };
        self.clean = false;
        if let Err(e) = self.driver.open(&mut traced) {
            self.fail_open();
            return Err(e);
        }
        self.link = Some(link);
        self.backoff = BACKOFF_MIN;
        let n = self.health.opens.fetch_add(1, Relaxed);
        if n > 0 && std::mem::take(&mut self.announce_open) {
            tracing::info!(device = self.trace.device(), "port reopened");
        }
        Ok(())
    }

    fn transact<T>(
        &mut self,
        f: impl FnOnce(&mut dyn Driver, &mut dyn Link) -> Result<T, DriverError>,
    ) -> (Result<T, DriverError>, Option<Instant>) {
        if let Err(e) = self.ensure_open() {
            // Not a transaction: the port is closed (waiting to retry, or failed to
            // open, which `ensure_open` accounted for).
            return (Err(e), None);
        }
        let (r, first) = self.run(f);
        let r = self.drained(r);
        self.settle(&r);
        (r, first)
    }

    /// Whether a request can go out at once, from a thread that must not wait: the
    /// port is open, its driver needs no pause before writing, and its last
    /// transaction ended cleanly (a device that stopped answering or reading, whose
    /// write might wait for room until the reply deadline, is left to its command
    /// thread).
    fn ready_at_once(&self) -> bool {
        self.link.is_some() && self.clean && self.failures == 0 && self.driver.sends_at_once()
    }

    /// The first half of a split command transaction: only a failure ends it here.
    fn send_half(
        &mut self,
        command: crate::value::Command,
    ) -> (Result<(), DriverError>, Option<Instant>) {
        if let Err(e) = self.ensure_open() {
            return (Err(e), None);
        }
        let (r, first) = self.run(|drv, link| drv.send_command(link, command));
        if r.is_err() {
            self.settle(&r);
        } else {
            // The reply is on its way: until it is read to its end, what is on the line
            // is not known to be clean (a driver reading garbage mid-reply discards).
            self.clean = false;
        }
        (r, first)
    }

    /// The second half: the reply, and the transaction's end.
    fn finish_half(&mut self) -> Result<(), DriverError> {
        if self.link.is_none() {
            // Cannot happen after a good first half; nothing to account for.
            return Err(DriverError::Io(io::ErrorKind::NotConnected.into()));
        }
        let (r, _) = self.run(|drv, link| drv.finish_command(link));
        let r = self.drained(r);
        self.settle(&r);
        r
    }

    /// Run `f` on the open port, stamping its first byte.
    fn run<T>(
        &mut self,
        f: impl FnOnce(&mut dyn Driver, &mut dyn Link) -> Result<T, DriverError>,
    ) -> (Result<T, DriverError>, Option<Instant>) {
        let Some(link) = self.link.as_mut() else {
            return (
                Err(DriverError::Io(io::ErrorKind::NotConnected.into())),
                None,
            );
        };
        let link = link.as_mut();
        let mut stamped = Stamped {
            inner: link,
            first_write: None,
            trace: &self.trace,
            clean: self.clean,
            heard: false,
        };
        let r = f(self.driver.as_mut(), &mut stamped);
        let (first, heard) = (stamped.first_write, stamped.heard);
        self.heard = heard;
        (r, first)
    }

    /// Account for a transaction that ended with `r`: what to discard before the next
    /// request, failures in a row, a reopen.
    fn settle<T>(&mut self, r: &Result<T, DriverError>) {
        self.clean = r.is_ok();
        match r {
            Ok(_) => {
                self.failures = 0;
                self.reopens.clear();
            }
            Err(e) => {
                self.failures += 1;
                if e.is_disconnect() {
                    self.fail_open();
                } else if self.failures >= REOPEN_AFTER {
                    let what = format!(
                        "{} failed transactions in a row: reopening the port",
                        self.failures
                    );
                    if let Some(repeats) = self.reopens.note(&what, Instant::now()) {
                        tracing::warn!(device = self.trace.device(), "{what}{repeats}");
                        self.announce_open = true;
                    }
                    self.failures = 0;
                    // Reopen at the next transaction; backoff is for ports that fail
                    // to open.
                    self.link = None;
                }
            }
        }
    }
}

/// How long the line must be quiet after a missed reply before a device's next
/// request: a whole reply timeout, unless its silence rule cannot afford it. After one
/// lost request the device's last answer is at most a status period older than that
/// request; its deadline, this quiet and the next answer (a quarter of a reply timeout
/// allowed for it) must come within `status_max_age`, or one lost frame would make it
/// silent. Never less than a quarter of a reply timeout.
pub(crate) fn drain_quiet(c: &crate::config::DeviceConfig) -> Duration {
    let t = c.reply_timeout;
    c.status_max_age
        .saturating_sub(c.status_period + t + t / 4)
        .clamp(t / 4, t)
}

/// A link that notes when the first byte of a transaction was taken by the port and
/// records the traffic in the device's trace.
struct Stamped<'a> {
    inner: &'a mut dyn Link,
    first_write: Option<Instant>,
    trace: &'a Trace,
    /// Nothing unasked-for can be waiting: the first discard of this transaction (the
    /// one before its request) has nothing to do. A later one — a driver that read
    /// garbage mid-reply — still discards.
    clean: bool,
    /// A byte came since the last request was written.
    heard: bool,
}

impl Read for Stamped<'_> {
    fn read(&mut self, buf: &mut [u8]) -> io::Result<usize> {
        let n = self.inner.read(buf)?;
        self.trace.record(Dir::In, &buf[..n]);
        self.heard |= n > 0;
        Ok(n)
    }
}

impl Write for Stamped<'_> {
    fn write(&mut self, buf: &[u8]) -> io::Result<usize> {
        let n = self.inner.write(buf)?;
        // Stamped once the kernel has the first byte, not before the call.
        if self.first_write.is_none() && n > 0 {
            self.first_write = Some(Instant::now());
        }
        if n > 0 {
            self.heard = false;
        }
        self.trace.record(Dir::Out, &buf[..n]);
        Ok(n)
    }
    fn flush(&mut self) -> io::Result<()> {
        self.inner.flush()
    }
}

impl Link for Stamped<'_> {
    fn set_timeout(&mut self, timeout: Duration) -> io::Result<()> {
        self.inner.set_timeout(timeout)
    }
    fn discard_input(&mut self) -> io::Result<()> {
        if std::mem::take(&mut self.clean) {
            return Ok(());
        }
        self.inner.discard_input()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::driver::line::LineDriver;
    use crate::value::Command;
    use std::collections::VecDeque;
    use std::sync::atomic::AtomicUsize;

    /// A device that answers each request with the next scripted reply (`None`: silence)
    /// and counts how often the host discarded its input.
    struct Device {
        replies: VecDeque<Option<&'static [u8]>>,
        out: Vec<u8>,
        discards: Arc<AtomicUsize>,
    }

    impl Read for Device {
        fn read(&mut self, buf: &mut [u8]) -> io::Result<usize> {
            if self.out.is_empty() {
                return Err(io::ErrorKind::TimedOut.into());
            }
            let n = buf.len().min(self.out.len());
            buf[..n].copy_from_slice(&self.out[..n]);
            self.out.drain(..n);
            Ok(n)
        }
    }

    impl Write for Device {
        fn write(&mut self, buf: &[u8]) -> io::Result<usize> {
            if buf.ends_with(b"\n") {
                self.out = self
                    .replies
                    .pop_front()
                    .flatten()
                    .unwrap_or_default()
                    .to_vec();
            }
            Ok(buf.len())
        }
        fn flush(&mut self) -> io::Result<()> {
            Ok(())
        }
    }

    impl Link for Device {
        fn set_timeout(&mut self, _: Duration) -> io::Result<()> {
            Ok(())
        }
        fn discard_input(&mut self) -> io::Result<()> {
            self.discards.fetch_add(1, Relaxed);
            Ok(())
        }
    }

    /// Input is discarded before a request only when something unasked-for may be
    /// waiting: after the port opened and after a transaction that failed — never
    /// after a clean one, whose reply was read to its end.
    #[test]
    fn input_is_discarded_only_after_an_open_or_a_failed_transaction() {
        let (mut conn, discards) =
            scripted([Some(&b"ok\n"[..]), Some(b"ok\n"), None, Some(b"ok\n")]);
        let mut send = || {
            let (r, first) = conn.transact(|drv, link| drv.command(link, Command::Set(0.5)));
            assert!(first.is_some(), "the request went out");
            r.is_ok()
        };
        assert!(send());
        assert_eq!(discards.load(Relaxed), 1, "a fresh port is discarded once");
        assert!(send());
        assert_eq!(
            discards.load(Relaxed),
            1,
            "nothing to discard after a clean reply"
        );
        assert!(!send(), "the device stays silent");
        assert_eq!(discards.load(Relaxed), 1);
        assert!(send());
        assert_eq!(
            discards.load(Relaxed),
            2,
            "a late reply may follow a timeout"
        );
    }

    /// A command split in two halves — the request written by one thread, the port
    /// handed over still held, the reply read by another — keeps the port's books as a
    /// whole transaction does: nobody can take the port in between, a clean reply
    /// leaves nothing to discard, a timed-out one has the next request discard first —
    /// and leaves that request to the command thread.
    #[test]
    fn a_split_transaction_keeps_the_books_of_a_whole_one() {
        let (conn, discards) = scripted([Some(&b"ok\n"[..]), Some(b"ok\n"), None, Some(b"ok\n")]);
        let port = Port::new(PortRule::Priority, conn);
        let set = Command::Set(0.5);
        assert!(
            port.try_acquire_idle().is_none(),
            "a port not open yet is opened by a whole transaction"
        );
        let mut g = port.acquire_command().unwrap();
        assert!(g.transact(|drv, link| drv.command(link, set)).0.is_ok());
        drop(g);
        assert_eq!(discards.load(Relaxed), 1, "a fresh port is discarded once");

        let split = |port: &Port| {
            let mut g = port.try_acquire_idle().expect("an idle, open port");
            let (sent, first) = g.send_command(set);
            assert!(sent.is_ok() && first.is_some(), "the request went out");
            g.hand_over(true);
            assert!(
                port.try_acquire_idle().is_none(),
                "the port stays held between the halves"
            );
            std::thread::scope(|s| {
                s.spawn(|| port.resume().expect("handed over").finish_command())
                    .join()
                    .unwrap()
            })
        };
        assert!(split(&port).is_ok());
        assert_eq!(
            discards.load(Relaxed),
            1,
            "nothing to discard after a clean reply"
        );
        assert!(matches!(split(&port), Err(DriverError::Timeout(_))));
        assert_eq!(discards.load(Relaxed), 1);
        assert!(
            port.try_acquire_idle().is_none(),
            "after a failed transaction the next one is the command thread's"
        );
        let mut g = port.acquire_command().unwrap();
        assert!(g.transact(|drv, link| drv.command(link, set)).0.is_ok());
        drop(g);
        assert_eq!(
            discards.load(Relaxed),
            2,
            "a late reply may follow a timeout"
        );
        assert!(
            port.try_acquire_idle().is_some(),
            "idle again after a clean transaction"
        );
        assert!(port.resume().is_none(), "nothing handed over any more");
    }

    /// The incident: a vanished brake was never reopened. Each transaction refused while
    /// the port waited to retry counted as a disconnect, which pushed the retry further
    /// (and doubled the backoff), so the retry never came. A port whose open failed is
    /// opened again once its backoff has passed, however often it is asked meanwhile.
    #[test]
    fn a_port_waiting_to_reopen_is_reopened_after_its_backoff_however_often_asked() {
        let (mut conn, _) = scripted([Some(&b"ok\n"[..])]);
        let mut inner = std::mem::replace(&mut conn.opener, Box::new(|| unreachable!()));
        let mut refused = false;
        conn.opener = Box::new(move || {
            if !std::mem::replace(&mut refused, true) {
                return Err(io::ErrorKind::NotFound.into());
            }
            inner()
        });
        let set = Command::Set(0.5);
        assert!(
            conn.transact(|d, l| d.command(l, set)).0.is_err(),
            "open fails"
        );
        let end = Instant::now() + Duration::from_secs(20);
        // Asked every millisecond, as a command flood would.
        while conn.transact(|d, l| d.command(l, set)).0.is_err() {
            assert!(Instant::now() < end, "the port was never reopened");
            std::thread::sleep(Duration::from_millis(1));
        }
        assert_eq!(conn.health.opens.load(Relaxed), 1);
    }

    /// The incident: a device answering later than its reply timeout had its late reply
    /// read as the answer to the next request about half the time, so it looked
    /// healthy. Over a real pseudo-terminal, a line device that answers its n-th request
    /// with `pos=n` (so a reply names the request it answers), one at a time, first 20
    /// ms after the deadline: no poll takes another request's answer, the failures say
    /// it is slower than its reply timeout, and once it is fast again every reply taken
    /// is its own request's. The drain waits for a whole reply timeout of quiet (200
    /// ms, which its `status_max_age` affords): the device's thread may be scheduled
    /// 180 ms late (a loaded machine) and its reply still come within it — the scenario
    /// holds there too (with 50 ms, 30 ms late was a reply after the drain, the case no
    /// drain can tell).
    #[test]
    fn a_late_reply_is_drained_never_taken_for_the_next_request_s() {
        use crate::config::protocol_map::Wire;
        use serialport::TTYPort;
        use std::sync::atomic::AtomicU64;
        let config = crate::config::one_device(
            "name = \"d\"\nkind = \"setpoint\"\nrange = [-1.0, 1.0]\ndriver = \"line\"\nreply_timeout = \"200ms\"\nstatus_max_age = \"2s\"",
        );
        assert_eq!(drain_quiet(&config), config.reply_timeout);
        let Wire::Line(map) = config.wire.clone() else {
            panic!("a line device")
        };
        let (mut device, host) = TTYPort::pair().expect("a pseudo-terminal pair");
        device.set_timeout(Duration::from_millis(20)).unwrap();
        // How late it answers, ms after a request arrives; u64::MAX stops it.
        let slow = Arc::new(AtomicU64::new(220));
        let s = slow.clone();
        let served = std::thread::spawn(move || {
            let (mut n, mut line) = (0u64, Vec::new());
            let mut b = [0u8; 1];
            while s.load(Relaxed) != u64::MAX {
                match device.read(&mut b) {
                    Ok(1) if b[0] == b'\n' => {
                        n += 1;
                        line.clear();
                        std::thread::sleep(Duration::from_millis(s.load(Relaxed)));
                        let _ = device.write_all(format!("= pos={n}\n").as_bytes());
                    }
                    Ok(_) => line.push(b[0]),
                    Err(_) => {}
                }
            }
        });
        // Opened again by its path after failed transactions, as a serial port is.
        let path = serialport::SerialPort::name(&host).expect("a pty's path");
        let mut host = Some(host);
        let reply_timeout = config.reply_timeout;
        let opener: Opener = Box::new(move || match host.take() {
            Some(h) => Ok(Box::new(h) as Box<dyn Link>),
            None => crate::driver::open_serial(&path, 115_200, reply_timeout),
        });
        let driver = Box::new(LineDriver::new(map, config.reply_timeout));
        let mut conn = Conn::new(
            driver,
            opener,
            Arc::new(Trace::new("d")),
            Arc::default(),
            &config,
        );
        let mut poll = || conn.transact(|drv, link| drv.poll(link)).0;
        let (mut late, mut own) = (0, 0);
        for k in 1..=12 {
            match poll() {
                // A host itself scheduled later than the reply (a loaded machine) finds
                // it waiting: its own request's answer, which it may take.
                Ok(r) if r.get(0) == Some(k as f64) => own += 1,
                Ok(r) => panic!(
                    "poll {k} took {:?}, the answer to another request",
                    r.get(0)
                ),
                Err(DriverError::Late { .. }) => late += 1,
                Err(DriverError::Timeout(_)) => {}
                Err(e) => panic!("poll {k}: {e}"),
            }
        }
        assert!(
            late + own >= 10,
            "named slow: {late} of 12 ({own} taken late by a late host)"
        );
        // Fast again: each reply taken is its own request's (the device has answered k
        // requests when the host's k-th is done).
        slow.store(1, Relaxed);
        let mut k = 12;
        let mut good = 0;
        while good < 5 {
            k += 1;
            assert!(k < 40, "never answered in time again");
            if let Ok(r) = poll() {
                assert_eq!(r.get(0), Some(k as f64), "poll {k} took another's answer");
                good += 1;
            }
        }
        slow.store(u64::MAX, Relaxed);
        served.join().unwrap();
    }

    /// Under the paper's rule a command never jumps the queue for the port.
    #[test]
    fn the_paper_rule_never_gives_the_port_at_once() {
        let (conn, _) = scripted([Some(&b"ok\n"[..])]);
        let port = Port::new(PortRule::Paper, conn);
        let mut g = port.acquire_command().unwrap();
        assert!(g
            .transact(|drv, link| drv.command(link, Command::Set(0.5)))
            .0
            .is_ok());
        drop(g);
        assert!(port.try_acquire_idle().is_none());
    }

    /// A connection to a scripted line device answering each request with the next
    /// reply (`None`: silence), and its count of discards.
    fn scripted<const N: usize>(replies: [Option<&'static [u8]>; N]) -> (Conn, Arc<AtomicUsize>) {
        let discards = Arc::new(AtomicUsize::new(0));
        let mut device = Some(Device {
            replies: replies.into(),
            out: Vec::new(),
            discards: discards.clone(),
        });
        let opener: Opener =
            Box::new(move || Ok(Box::new(device.take().expect("opened once")) as Box<dyn Link>));
        let config = crate::config::one_device(
            "name = \"d\"\nkind = \"setpoint\"\nrange = [-1.0, 1.0]\ndriver = \"line\"\nreply_timeout = \"50ms\"",
        );
        let map = match &config.wire {
            crate::config::protocol_map::Wire::Line(m) => m.clone(),
            other => panic!("{other:?}"),
        };
        let driver = Box::new(LineDriver::new(map, Duration::from_millis(50)));
        let conn = Conn::new(
            driver,
            opener,
            Arc::new(Trace::new("d")),
            Arc::default(),
            &config,
        );
        (conn, discards)
    }
}
