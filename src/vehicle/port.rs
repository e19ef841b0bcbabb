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
//! lazily, reopens it with exponential backoff after a disconnect, and timestamps the
//! first byte of every transaction.

use crate::config::PortRule;
use crate::driver::{Driver, DriverError, Link};
use crate::vehicle::slot::CommandSlot;
use crate::vehicle::trace::{Dir, Trace};
use parking_lot::{Condvar, Mutex, MutexGuard};
use std::io::{self, Read, Write};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering::Relaxed};
use std::sync::Arc;
use std::time::{Duration, Instant};

/// What readers may know of a device's port without touching it.
#[derive(Default, Debug)]
pub struct PortHealth {
    /// Times the port was opened (1 after start; more after reconnects).
    pub opens: AtomicU64,
    /// The last attempt to open it failed: the port is gone (unplugged, wrong path).
    pub missing: AtomicBool,
}

/// Opens a device's port (a serial port, a pseudo-terminal, a test double).
pub type Opener = Box<dyn FnMut() -> io::Result<Box<dyn Link>> + Send>;

const BACKOFF_MIN: Duration = Duration::from_millis(100);
const BACKOFF_MAX: Duration = Duration::from_secs(5);
/// After this many failed transactions in a row the port is closed and reopened, and
/// the driver's `open` runs again (it un-wedges adapters such as the ELM327).
pub const REOPEN_AFTER: u32 = 5;

#[derive(Default)]
struct Arb {
    busy: bool,
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
    arb: Mutex<Arb>,
    cv: Condvar,
    conn: Mutex<Conn>,
}

/// The port, held by one thread for one or more transactions.
pub struct PortGuard<'a> {
    port: &'a Port,
    conn: Option<MutexGuard<'a, Conn>>,
}

impl Port {
    pub fn new(rule: PortRule, conn: Conn) -> Port {
        Port {
            rule,
            arb: Mutex::new(Arb::default()),
            cv: Condvar::new(),
            conn: Mutex::new(conn),
        }
    }

    pub fn rule(&self) -> PortRule {
        self.rule
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
    pub fn acquire_command(&self) -> Option<PortGuard<'_>> {
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

    /// Take the port for a status poll, yielding to commands until `overdue_at`.
    /// `None` once stopped.
    pub fn acquire_status(&self, overdue_at: Instant, slot: &CommandSlot) -> Option<PortGuard<'_>> {
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
    pub fn transact<T>(
        &mut self,
        f: impl FnOnce(&mut dyn Driver, &mut dyn Link) -> Result<T, DriverError>,
    ) -> (Result<T, DriverError>, Option<Instant>) {
        self.conn.as_mut().expect("held").transact(f)
    }

    /// An overdue status poll is waiting: let it have the port next.
    pub fn status_waiting(&self) -> bool {
        self.port.arb.lock().status_urgent
    }

    pub fn is_connected(&self) -> bool {
        self.conn.as_ref().expect("held").link.is_some()
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
    /// Why the last open failed, repeated while waiting to retry.
    open_error: Option<String>,
}

impl Conn {
    pub fn new(
        driver: Box<dyn Driver>,
        opener: Opener,
        trace: Arc<Trace>,
        health: Arc<PortHealth>,
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
            open_error: None,
        }
    }

    fn fail_open(&mut self) {
        self.link = None;
        self.next_open = Instant::now() + self.backoff;
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
        };
        if let Err(e) = self.driver.open(&mut traced) {
            self.fail_open();
            return Err(e);
        }
        self.link = Some(link);
        self.backoff = BACKOFF_MIN;
        let n = self.health.opens.fetch_add(1, Relaxed);
        if n > 0 {
            tracing::info!(device = self.trace.device(), "port reopened");
        }
        Ok(())
    }

    fn transact<T>(
        &mut self,
        f: impl FnOnce(&mut dyn Driver, &mut dyn Link) -> Result<T, DriverError>,
    ) -> (Result<T, DriverError>, Option<Instant>) {
        if let Err(e) = self.ensure_open() {
            return (Err(e), None);
        }
        let link = self.link.as_mut().expect("opened").as_mut();
        let mut stamped = Stamped {
            inner: link,
            first_write: None,
            trace: &self.trace,
        };
        let r = f(self.driver.as_mut(), &mut stamped);
        let first = stamped.first_write;
        match &r {
            Ok(_) => self.failures = 0,
            Err(e) => {
                self.failures += 1;
                if e.is_disconnect() {
                    self.fail_open();
                } else if self.failures >= REOPEN_AFTER {
                    tracing::warn!(
                        device = self.trace.device(),
                        "{} failed transactions in a row: reopening the port",
                        self.failures
                    );
                    self.failures = 0;
                    // Reopen at the next transaction; backoff is for ports that fail
                    // to open.
                    self.link = None;
                }
            }
        }
        (r, first)
    }
}

/// A link that notes when the first byte of a transaction was handed to the port and
/// records the traffic in the device's trace.
struct Stamped<'a> {
    inner: &'a mut dyn Link,
    first_write: Option<Instant>,
    trace: &'a Trace,
}

impl Read for Stamped<'_> {
    fn read(&mut self, buf: &mut [u8]) -> io::Result<usize> {
        let n = self.inner.read(buf)?;
        self.trace.record(Dir::In, &buf[..n]);
        Ok(n)
    }
}

impl Write for Stamped<'_> {
    fn write(&mut self, buf: &[u8]) -> io::Result<usize> {
        if self.first_write.is_none() && !buf.is_empty() {
            self.first_write = Some(Instant::now());
        }
        let n = self.inner.write(buf)?;
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
        self.inner.discard_input()
    }
}
