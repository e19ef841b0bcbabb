//! The serial port as a [`Link`], with nothing between a command and the wire but the
//! one `write` that hands it to the kernel.
//!
//! `serialport` opens and configures the port (baud, raw mode, exclusive access); its
//! own `Read`/`Write` are general-purpose: every write first polls for `POLLOUT`, and
//! `flush` is a `tcdrain` that waits for the UART. On the command path that is two
//! system calls before and after the first byte for nothing: a port with room in its
//! output buffer takes the bytes at once, and the reply is read anyway. So this link
//! puts the descriptor in non-blocking mode and
//! - writes at once, polling for room only when the kernel says it has none
//!   (`EAGAIN`), within the timeout;
//! - reads after a poll for input with the time left (the reply is rarely there yet);
//! - flushes nothing (the kernel drains its buffer by itself; the reply comes after);
//! - discards pending input with `tcflush` when the driver asks (the port itself
//!   decides when that is needed: see [`crate::port`]).

use super::Link;
use rustix::event::{PollFd, PollFlags, Timespec};
use rustix::io::Errno;
use serialport::TTYPort;
use std::io::{self, Read, Write};
use std::os::fd::{AsFd, AsRawFd, BorrowedFd};
use std::time::Duration;

/// An open serial port (or pseudo-terminal), non-blocking underneath.
pub(crate) struct SerialLink {
    port: TTYPort,
    timeout: Duration,
}

impl SerialLink {
    /// Take over a port `serialport` opened and configured.
    pub(crate) fn new(port: TTYPort, timeout: Duration) -> io::Result<SerialLink> {
        let fd = port.as_raw_fd();
        #[allow(unsafe_code)]
        // SAFETY: the descriptor is open for as long as `port` lives, and it does here.
        let fd = unsafe { BorrowedFd::borrow_raw(fd) };
        let flags = rustix::fs::fcntl_getfl(fd)?;
        rustix::fs::fcntl_setfl(fd, flags | rustix::fs::OFlags::NONBLOCK)?;
        Ok(SerialLink { port, timeout })
    }

    /// A second handle on the same open port (a CAN bus: one thread reads every
    /// frame while the devices' command threads write).
    pub(crate) fn try_clone(&self) -> io::Result<SerialLink> {
        let port = self.port.try_clone_native().map_err(io::Error::from)?;
        Ok(SerialLink {
            port,
            timeout: self.timeout,
        })
    }

    #[allow(unsafe_code)]
    fn fd(&self) -> BorrowedFd<'_> {
        // SAFETY: as in `new`.
        unsafe { BorrowedFd::borrow_raw(self.port.as_raw_fd()) }
    }

    /// Wait until the port is ready for `events`, at most the timeout.
    fn wait(&self, events: PollFlags) -> io::Result<()> {
        let fd = self.fd();
        let mut fds = [PollFd::new(&fd, events)];
        let timeout = Timespec::try_from(self.timeout).unwrap_or(Timespec {
            tv_sec: i64::MAX,
            tv_nsec: 0,
        });
        loop {
            match rustix::event::poll(&mut fds, Some(&timeout)) {
                Ok(0) => return Err(io::ErrorKind::TimedOut.into()),
                Ok(_) => break,
                Err(Errno::INTR) => continue,
                Err(e) => return Err(e.into()),
            }
        }
        let got = fds[0].revents();
        if got.intersects(events) {
            Ok(())
        } else {
            // The other end hung up (a pseudo-terminal closed, an adapter unplugged).
            Err(io::Error::new(
                io::ErrorKind::BrokenPipe,
                format!("port hung up ({got:?})"),
            ))
        }
    }
}

impl Read for SerialLink {
    fn read(&mut self, buf: &mut [u8]) -> io::Result<usize> {
        self.wait(PollFlags::IN)?;
        loop {
            match rustix::io::read(self.fd(), &mut *buf) {
                Ok(n) => return Ok(n),
                Err(Errno::INTR) => continue,
                // Woken with nothing to read after all: the caller tries again within
                // its deadline (`read_some` re-arms and retries an interrupted read).
                Err(Errno::AGAIN) => return Err(io::ErrorKind::Interrupted.into()),
                Err(e) => return Err(e.into()),
            }
        }
    }
}

impl Write for SerialLink {
    fn write(&mut self, buf: &[u8]) -> io::Result<usize> {
        loop {
            match rustix::io::write(self.fd(), buf) {
                Ok(n) => return Ok(n),
                Err(Errno::INTR) => continue,
                Err(Errno::AGAIN) => self.wait(PollFlags::OUT)?,
                Err(e) => return Err(e.into()),
            }
        }
    }

    fn flush(&mut self) -> io::Result<()> {
        Ok(())
    }
}

impl Link for SerialLink {
    fn set_timeout(&mut self, timeout: Duration) -> io::Result<()> {
        self.timeout = timeout;
        Ok(())
    }

    fn discard_input(&mut self) -> io::Result<()> {
        rustix::termios::tcflush(self.fd(), rustix::termios::QueueSelector::IFlush)?;
        Ok(())
    }

    fn reply_fd(&self) -> Option<BorrowedFd<'_>> {
        Some(self.fd())
    }
}

impl AsFd for SerialLink {
    fn as_fd(&self) -> BorrowedFd<'_> {
        self.fd()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::driver::{read_some, read_until, Deadline, DriverError};
    use serialport::SerialPort;
    use std::time::Instant;

    fn pair() -> (TTYPort, SerialLink) {
        let (mut device, host) = TTYPort::pair().expect("a pseudo-terminal pair");
        SerialPort::set_timeout(&mut device, Duration::from_secs(5)).unwrap();
        (
            device,
            SerialLink::new(host, Duration::from_secs(5)).unwrap(),
        )
    }

    /// One line from the device, within a generous deadline.
    fn line(host: &mut SerialLink) -> Vec<u8> {
        let mut got = Vec::new();
        let deadline = Deadline::after(Duration::from_secs(5));
        read_until(host, &mut got, b'\n', 64, &deadline).unwrap();
        got
    }

    /// A deadline `budget` long that has passed (the reader's thread ran late).
    fn expired(budget: Duration) -> Deadline {
        let d = Deadline::after(budget);
        while d.remaining().is_ok() {
            std::thread::sleep(Duration::from_millis(1));
        }
        d
    }

    /// For every reader of a reply (a frame read by its length, a bus's adapter, a
    /// line): a thread come late to a reply that is there takes it; and a device
    /// trickling bytes after the deadline cannot hold the late reader, which takes what
    /// has arrived and stops at the first look that finds nothing.
    #[test]
    fn a_late_reader_takes_what_arrived_and_a_trickle_cannot_hold_it() {
        use std::sync::atomic::{AtomicBool, Ordering::Relaxed};
        let (mut device, mut host) = pair();
        device.write_all(&[0x01, 0x06, 0x00]).unwrap();
        host.wait(PollFlags::IN).unwrap();
        let mut buf = [0u8; 3];
        let r = read_some(&mut host, &mut buf, &expired(Duration::from_millis(1)));
        assert!(matches!(r, Ok(n) if n > 0), "{r:?}");
        // The trickle: a byte every 5 ms, for a reader whose budget was 2 s (one that
        // waited for it would read the 1000 bytes its reply may have, for 5 s).
        let stop = std::sync::Arc::new(AtomicBool::new(false));
        let s = stop.clone();
        let trickle = std::thread::spawn(move || {
            while !s.load(Relaxed) && device.write_all(b"x").is_ok() {
                std::thread::sleep(Duration::from_millis(5));
            }
        });
        host.set_timeout(Duration::from_secs(5)).unwrap();
        host.wait(PollFlags::IN).unwrap();
        let budget = Duration::from_secs(2);
        let d = expired(budget);
        let started = Instant::now();
        let mut reply = Vec::new();
        let r = read_until(&mut host, &mut reply, b'\n', 1000, &d);
        let took = started.elapsed();
        stop.store(true, Relaxed);
        trickle.join().unwrap();
        assert!(
            matches!(r, Err(DriverError::Timeout(t)) if t == budget),
            "{r:?}"
        );
        assert!(!reply.is_empty(), "what had arrived was read");
        assert!(
            took < budget,
            "a late reader was held {took:?} by a trickle ({} bytes)",
            reply.len()
        );
    }

    #[test]
    fn bytes_go_both_ways() {
        let (mut device, mut host) = pair();
        host.write_all(b"! 0.250\n").unwrap();
        let mut buf = [0u8; 8];
        device.read_exact(&mut buf).unwrap();
        assert_eq!(&buf, b"! 0.250\n");
        device.write_all(b"ok\n").unwrap();
        assert_eq!(line(&mut host), b"ok\n");
    }

    #[test]
    fn a_silent_device_times_out_at_the_deadline() {
        let (_device, mut host) = pair();
        let t = Instant::now();
        let r = read_some(
            &mut host,
            &mut [0u8; 4],
            &Deadline::after(Duration::from_millis(50)),
        );
        assert!(matches!(r, Err(DriverError::Timeout(_))), "{r:?}");
        assert!(t.elapsed() >= Duration::from_millis(50));
    }

    #[test]
    fn a_closed_device_end_is_a_disconnect() {
        let (device, mut host) = pair();
        drop(device);
        let r = read_some(
            &mut host,
            &mut [0u8; 4],
            &Deadline::after(Duration::from_secs(5)),
        );
        assert!(matches!(&r, Err(e) if e.is_disconnect()), "{r:?}");
    }

    #[test]
    fn discarding_drops_what_nobody_asked_for() {
        let (mut device, mut host) = pair();
        device.write_all(b"late reply\n").unwrap();
        // Let the bytes cross the pseudo-terminal before discarding them.
        host.wait(PollFlags::IN).unwrap();
        host.discard_input().unwrap();
        device.write_all(b"ok\n").unwrap();
        assert_eq!(line(&mut host), b"ok\n");
    }
}
