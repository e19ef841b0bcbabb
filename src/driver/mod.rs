//! Drivers: one implementation of [`Driver`] per device protocol (the paper's wish for
//! "a basic actuator class"). A driver knows bytes and registers, nothing of threads:
//! the engine owns the port, opens it, hands it to the driver as a [`Link`] for one
//! transaction at a time, and measures around it.
//!
//! Every exchange — one request, one reply — ends at its [`Deadline`], the device's
//! `reply_timeout` after the request went out, whatever the device sends meanwhile:
//! each read waits only for the time left ([`read_some`], [`read_until`]). A driver call
//! makes a fixed, small number of exchanges (ELM327 poll: two or three; Modbus poll: one
//! per register block), so the port is held for a bounded time and the other thread of
//! the device gets its turn.

pub mod elm327;
pub(crate) mod line;
pub(crate) mod lock;
#[cfg(test)]
mod mock;
pub mod modbus;
pub(crate) mod serial;
pub mod slcan;

use crate::value::{Command, Reading};
use std::io::{self, Read, Write};
use std::time::{Duration, Instant};

/// The byte stream a driver talks over: a serial port in the field, a pseudo-terminal
/// under `--sim`, a scripted mock in unit tests.
pub trait Link: Read + Write + Send {
    /// How long a read may block before it fails with `TimedOut`.
    fn set_timeout(&mut self, timeout: Duration) -> io::Result<()>;
    /// Drop whatever the device sent that nobody asked for (a late reply, noise).
    fn discard_input(&mut self) -> io::Result<()>;
    /// The descriptor the device's replies arrive on, for a thread to sleep on until
    /// they do ([`crate::port::wake`]): a serial port's. `None` for a link without one
    /// (a CAN device's write half, whose replies its bus's reader takes; a test double).
    fn reply_fd(&self) -> Option<std::os::fd::BorrowedFd<'_>> {
        None
    }
}

impl Link for Box<dyn serialport::SerialPort> {
    fn set_timeout(&mut self, timeout: Duration) -> io::Result<()> {
        serialport::SerialPort::set_timeout(self.as_mut(), timeout).map_err(io::Error::from)
    }
    fn discard_input(&mut self) -> io::Result<()> {
        self.clear(serialport::ClearBuffer::Input)
            .map_err(io::Error::from)
    }
}

impl Link for serialport::TTYPort {
    fn set_timeout(&mut self, timeout: Duration) -> io::Result<()> {
        serialport::SerialPort::set_timeout(self, timeout).map_err(io::Error::from)
    }
    fn discard_input(&mut self) -> io::Result<()> {
        serialport::SerialPort::clear(self, serialport::ClearBuffer::Input).map_err(io::Error::from)
    }
    #[allow(unsafe_code)]
    fn reply_fd(&self) -> Option<std::os::fd::BorrowedFd<'_>> {
        use std::os::fd::AsRawFd;
        // SAFETY: the descriptor is open for as long as the port lives, and the borrow
        // cannot outlive it.
        Some(unsafe { std::os::fd::BorrowedFd::borrow_raw(self.as_raw_fd()) })
    }
}

/// Why a transaction failed. The engine counts every kind; `Io` errors that mean the
/// port is gone make it close the port and reopen it with backoff.
#[derive(Debug, thiserror::Error)]
pub enum DriverError {
    /// The device did not answer within the reply timeout.
    #[error("no reply within {0:?}")]
    Timeout(Duration),
    /// The device answered, but not in its protocol (garbage, bad checksum, wrong id).
    #[error("bad reply: {0}")]
    Garbled(String),
    /// The device answered in its protocol that it refuses (Modbus exception, `?`, `err`).
    #[error("device refused: {0}")]
    Refused(String),
    /// No reply within the reply timeout; it came later, `late` after the deadline, and
    /// was dropped (never taken for the next request's answer): the device answers
    /// slower than its reply timeout.
    #[error("no reply within {within:?}: it came {:.1} ms later and was dropped (slower than its reply_timeout)", late.as_secs_f64() * 1e3)]
    Late { within: Duration, late: Duration },
    /// The command cannot be expressed for this device (e.g. a gear sent to steering).
    #[error("unsupported command: {0}")]
    Unsupported(String),
    /// The port failed.
    #[error("port: {0}")]
    Io(#[from] io::Error),
}

impl DriverError {
    /// True when the port itself is gone (USB unplugged, pty closed): reopen it.
    pub(crate) fn is_disconnect(&self) -> bool {
        match self {
            DriverError::Io(e) => !matches!(
                e.kind(),
                io::ErrorKind::TimedOut | io::ErrorKind::WouldBlock | io::ErrorKind::Interrupted
            ),
            _ => false,
        }
    }

    /// A short stable name for counters and the broadcast.
    pub fn kind(&self) -> &'static str {
        match self {
            DriverError::Timeout(_) => "timeout",
            DriverError::Late { .. } => "late",
            DriverError::Garbled(_) => "garbled",
            DriverError::Refused(_) => "refused",
            DriverError::Unsupported(_) => "unsupported",
            DriverError::Io(_) => "io",
        }
    }
}

/// One device protocol, host side. Every call is one complete transaction: the engine
/// holds the port for exactly its duration.
///
/// A driver may also split a command's transaction in two halves — write the request
/// ([`Driver::send_command`]), read and check the reply ([`Driver::finish_command`]) —
/// so that the thread that admitted a command can put it on the wire itself and leave
/// the reply to the device's command thread. The engine calls the halves back to back
/// on the same port, which stays held in between; a driver that does not split
/// ([`Driver::sends_at_once`] false) is only ever asked for whole transactions.
pub trait Driver: Send {
    /// Bring a freshly opened port into a known state (e.g. the ELM327's reset
    /// sequence). Called again after every reconnect.
    fn open(&mut self, link: &mut dyn Link) -> Result<(), DriverError> {
        let _ = link;
        Ok(())
    }
    /// Ask the device for its state.
    fn poll(&mut self, link: &mut dyn Link) -> Result<Reading, DriverError>;
    /// The longest one transaction may hold the port: [`Driver::open`] after a reopen,
    /// then the longest of a poll and a command. Every exchange ends at its deadline, so
    /// this follows from the device's reply timeouts; it bounds how long a device's
    /// thread may legitimately be inside the driver (its liveness bound,
    /// [`crate::threads::Beat`]).
    fn longest(&self) -> Duration;
    /// Send one command and wait for the device's acknowledgement.
    fn command(&mut self, link: &mut dyn Link, command: Command) -> Result<(), DriverError>;
    /// Whether [`Driver::send_command`] would write its request now, without waiting
    /// (a Modbus line still in its inter-frame silence would wait). False for a driver
    /// that does not split its commands.
    fn sends_at_once(&self) -> bool {
        false
    }
    /// The first half of [`Driver::command`]: write the request. Only called when
    /// [`Driver::sends_at_once`] said so; [`Driver::finish_command`] follows on the same
    /// link when this succeeded.
    fn send_command(&mut self, link: &mut dyn Link, command: Command) -> Result<(), DriverError> {
        let _ = link;
        Err(DriverError::Unsupported(format!(
            "{command:?}: this driver sends whole transactions only"
        )))
    }
    /// The second half: read the reply to the request [`Driver::send_command`] wrote,
    /// within its deadline, and check it.
    fn finish_command(&mut self, link: &mut dyn Link) -> Result<(), DriverError> {
        let _ = link;
        Err(DriverError::Unsupported(
            "this driver sends whole transactions only".into(),
        ))
    }
}

/// The end of one exchange — a request and its reply. Every read of the reply waits
/// only for the time left until it, so the exchange ends by then whatever the device
/// sends: a device that trickles a byte now and then without ever finishing its reply
/// holds the port no longer than a silent one. (A per-read timeout would not do: each
/// byte would start the wait afresh.)
#[derive(Clone, Copy, Debug)]
pub(crate) struct Deadline {
    at: Instant,
    budget: Duration,
}

impl Deadline {
    /// The deadline `budget` from now (a device's reply timeout, taken as its request
    /// goes out).
    pub(crate) fn after(budget: Duration) -> Deadline {
        Deadline {
            at: Instant::now() + budget,
            budget,
        }
    }

    /// The time left: zero once it has passed.
    fn left(&self) -> Duration {
        self.at.saturating_duration_since(Instant::now())
    }

    /// The time left, or the timeout error once it has passed.
    pub(crate) fn remaining(&self) -> Result<Duration, DriverError> {
        let left = self.left();
        if left.is_zero() {
            Err(self.expired())
        } else {
            Ok(left)
        }
    }

    /// The error of an exchange that reached its deadline.
    pub(crate) fn expired(&self) -> DriverError {
        DriverError::Timeout(self.budget)
    }

    /// Let the link block no longer than the time left (before a write or a read).
    pub(crate) fn arm(&self, link: &mut dyn Link) -> Result<(), DriverError> {
        link.set_timeout(self.remaining()?)?;
        Ok(())
    }
}

/// One read of at most `buf.len()` bytes that waits no longer than `deadline` allows.
/// Returns how many bytes arrived (at least one); the deadline passing is
/// [`DriverError::Timeout`], the port closing is an I/O error.
///
/// Come to read at or after the deadline (this thread ran late: a loaded machine), what
/// has arrived is still read, without waiting: a device that answered in time is not a
/// device that did not. Only what has arrived: the first read that finds nothing is the
/// timeout, so nothing arriving later stretches the exchange.
pub(crate) fn read_some(
    link: &mut dyn Link,
    buf: &mut [u8],
    deadline: &Deadline,
) -> Result<usize, DriverError> {
    loop {
        let left = deadline.left();
        link.set_timeout(left)?;
        match link.read(buf) {
            Ok(0) => return Err(DriverError::Io(io::ErrorKind::UnexpectedEof.into())),
            Ok(n) => return Ok(n),
            Err(e) if e.kind() == io::ErrorKind::TimedOut => return Err(deadline.expired()),
            // Woken with nothing after all: wait again for the time left, if any.
            Err(e) if e.kind() == io::ErrorKind::Interrupted && !left.is_zero() => {}
            Err(e) if e.kind() == io::ErrorKind::Interrupted => return Err(deadline.expired()),
            Err(e) => return Err(DriverError::Io(e)),
        }
    }
}

/// Read from `link` until `terminator` arrives (included in `buf`), the reply grows past
/// `max` bytes, or `deadline` passes (what has arrived by then read, as [`read_some`]
/// reads it).
pub(crate) fn read_until(
    link: &mut dyn Link,
    buf: &mut Vec<u8>,
    terminator: u8,
    max: usize,
    deadline: &Deadline,
) -> Result<(), DriverError> {
    let mut chunk = [0u8; 64];
    loop {
        let n = read_some(link, &mut chunk, deadline)?;
        buf.extend_from_slice(&chunk[..n]);
        if buf.contains(&terminator) {
            return Ok(());
        }
        if buf.len() > max {
            return Err(DriverError::Garbled(format!(
                "reply longer than {max} bytes without a terminator"
            )));
        }
    }
}

/// Send one request and arm the exchange's deadline: input nobody asked for is dropped
/// first (the engine's port makes that a no-op after a clean transaction), and the
/// reply (read with [`read_until`] or [`read_some`]) must be complete `reply_timeout`
/// after the request went out.
pub(crate) fn send_request(
    link: &mut dyn Link,
    request: &[u8],
    reply_timeout: Duration,
) -> Result<Deadline, DriverError> {
    link.discard_input()?;
    let deadline = Deadline::after(reply_timeout);
    deadline.arm(link)?;
    link.write_all(request)?;
    link.flush()?;
    Ok(deadline)
}

/// How long a device of this driver may take to give its first answer after its port
/// opened because it searches the car's protocols first (an ELM327 adapter), if it
/// does: such a device that has not reported yet is searching, not silent.
pub fn protocol_search(kind: crate::config::DriverKind) -> Option<Duration> {
    match kind {
        crate::config::DriverKind::Elm327 => Some(elm327::SEARCH_TIMEOUT),
        _ => None,
    }
}

/// Build the driver a device's configuration asks for.
pub fn build(config: &crate::config::DeviceConfig) -> Box<dyn Driver> {
    build_on(config, &[])
}

/// [`build`], with the vehicle's buses for a device on a CAN bus.
pub fn build_on(
    config: &crate::config::DeviceConfig,
    buses: &[std::sync::Arc<slcan::Bus>],
) -> Box<dyn Driver> {
    use crate::config::protocol_map::Wire;
    match &config.wire {
        Wire::Can(m) => Box::new(slcan::CanDriver::new(
            (**m).clone(),
            buses
                .get(m.bus)
                .expect("a CAN device's driver is built with its bus")
                .clone(),
        )),
        Wire::Modbus(m) => Box::new(modbus::ModbusDriver::new(
            m.clone(),
            config.baud,
            config.reply_timeout,
        )),
        Wire::Elm327(m) => Box::new(elm327::Elm327Driver::new(m.clone(), config.reply_timeout)),
        Wire::Line(m) => Box::new(line::LineDriver::new(m.clone(), config.reply_timeout)),
    }
}

/// Open a serial port (or pseudo-terminal) by path at a baud rate, as a
/// [`serial::SerialLink`], for this process alone. An error names the path (`cannot
/// open /dev/ttyUSB0: No such file or directory`), and for a port in use, the process
/// holding it (kind `ResourceBusy`, [`lock`]).
pub fn open_serial(path: &str, baud: u32, timeout: Duration) -> io::Result<Box<dyn Link>> {
    let named = |e: io::Error| io::Error::new(e.kind(), format!("cannot open {path}: {e}"));
    let port = serialport::new(path, baud)
        .timeout(timeout)
        .open_native()
        .map_err(|e| named(lock::explain(path, e.into())))?;
    Ok(Box::new(
        serial::SerialLink::new(port, timeout).map_err(named)?,
    ))
}

#[cfg(test)]
mod tests {
    use super::*;
    use serialport::TTYPort;
    use std::sync::atomic::{AtomicBool, Ordering::Relaxed};
    use std::sync::Arc;

    /// A device on a real pseudo-terminal that sends one byte every `every` and never
    /// finishes its reply, until the returned flag is set.
    fn trickle(mut device: TTYPort, every: Duration) -> Arc<AtomicBool> {
        let stop = Arc::new(AtomicBool::new(false));
        let s = stop.clone();
        std::thread::spawn(move || {
            while !s.load(Relaxed) && device.write_all(b"x").is_ok() {
                std::thread::sleep(every);
            }
        });
        stop
    }

    /// A reply already there when a late thread comes to read it, past the deadline, is
    /// taken; only what has arrived: what is not complete then is a timeout.
    #[test]
    fn a_reply_read_late_is_still_a_reply_and_only_what_has_arrived() {
        use super::mock::{MockLink, Step};
        let late = || {
            let d = Deadline::after(Duration::from_millis(1));
            std::thread::sleep(Duration::from_millis(5));
            d
        };
        let mut link = MockLink::new([Step::Rx(b"ok\n".to_vec())]);
        let mut reply = Vec::new();
        let r = read_until(&mut link, &mut reply, b'\n', 100, &late());
        assert!(r.is_ok(), "{r:?}");
        assert_eq!(reply, b"ok\n");
        // Half a reply: the next look finds nothing, and that is the timeout (a read
        // after it would find the script empty and panic).
        let mut link = MockLink::new([Step::Rx(b"ok".to_vec()), Step::Silence]);
        let mut reply = Vec::new();
        let r = read_until(&mut link, &mut reply, b'\n', 100, &late());
        assert!(matches!(r, Err(DriverError::Timeout(_))), "{r:?}");
        assert_eq!(reply, b"ok");
        assert_eq!(
            link.timeout,
            Some(Duration::ZERO),
            "a late look never waits"
        );
    }

    #[test]
    fn a_trickling_device_cannot_stretch_an_exchange_past_its_deadline() {
        let (device, mut host) = TTYPort::pair().expect("a pseudo-terminal pair");
        // Each byte comes well within the budget of a single read.
        let stop = trickle(device, Duration::from_millis(30));
        let budget = Duration::from_millis(300);
        let started = Instant::now();
        let deadline = Deadline::after(budget);
        let mut reply = Vec::new();
        let r = read_until(&mut host, &mut reply, b'\n', 1000, &deadline);
        let took = started.elapsed();
        stop.store(true, Relaxed);
        assert!(
            matches!(r, Err(DriverError::Timeout(t)) if t == budget),
            "{r:?}"
        );
        assert!(reply.len() > 2, "the device did trickle: {reply:?}");
        assert!(
            took >= budget && took < budget + Duration::from_millis(200),
            "the exchange took {took:?} for a deadline of {budget:?}"
        );
    }

    #[test]
    fn a_deadline_that_passed_fails_without_reading() {
        let (_device, mut host) = TTYPort::pair().expect("a pseudo-terminal pair");
        let deadline = Deadline::after(Duration::ZERO);
        let mut buf = [0u8; 4];
        assert!(matches!(
            read_some(&mut host, &mut buf, &deadline),
            Err(DriverError::Timeout(_))
        ));
    }
}
