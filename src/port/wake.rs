//! What an actuator's command thread sleeps on when its port is a serial line: the
//! device's reply itself, rather than a signal from the thread that wrote the request.
//!
//! On the fast path ([`crate::engine::fast`]) the thread that admitted a command writes
//! its request, and the command thread reads the reply. Woken by a signal right after
//! the write, the command thread would run while the device's end is being woken by the
//! request's first byte — on a machine with few CPUs the two compete, and the command
//! pays for it. So the command thread waits in one `epoll` over three descriptors:
//! - a *bell* (an `eventfd`) the slot rings for what the thread must act on at once: a
//!   new command, a nudge, stop, a claim given up, a request that failed to go out;
//! - the port's own descriptor, *armed* (`EPOLLIN | EPOLLONESHOT`) by the thread that
//!   wrote a request, after writing it: the reply's first bytes wake the command thread,
//!   once. Disarmed otherwise, so a status poll's reply wakes nobody. Arming reports
//!   input already there, so a reply that came before the thread slept is not missed;
//! - a *timer* (a `timerfd`) armed in the same step to the reply's deadline: a device
//!   that stays silent still has its transaction ended at its deadline.
//!
//! Nothing here allocates; the descriptors are made once, with the device. A link
//! without a descriptor of its own (a CAN device's write half, a test double) is never
//! armed: its command thread is rung instead.

use rustix::event::epoll::{self, CreateFlags, Event, EventData, EventFlags};
use rustix::event::{eventfd, EventfdFlags};
use rustix::io::Errno;
use rustix::time::{
    timerfd_create, timerfd_settime, Itimerspec, TimerfdClockId, TimerfdFlags, TimerfdTimerFlags,
    Timespec,
};
use std::io;
use std::mem::MaybeUninit;
use std::os::fd::{AsFd, BorrowedFd, OwnedFd};
use std::sync::atomic::{AtomicBool, Ordering::SeqCst};
use std::time::Duration;

const BELL: u64 = 0;
const TIMER: u64 = 1;
const PORT: u64 = 2;

/// The command thread's wake-up: bell, armed port and reply timer, in one `epoll`.
pub(crate) struct PortWake {
    epoll: OwnedFd,
    bell: OwnedFd,
    timer: OwnedFd,
    /// The port is armed and has not woken the thread yet.
    port_armed: AtomicBool,
    /// The reply timer is set and has not woken the thread yet.
    timer_armed: AtomicBool,
}

/// What ended a [`PortWake::wait`].
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub(crate) struct Woken {
    pub bell: bool,
    /// The armed port has input (or hung up).
    pub port: bool,
    /// The reply's deadline passed.
    pub timer: bool,
}

impl PortWake {
    pub(crate) fn new() -> io::Result<PortWake> {
        let epoll = epoll::create(CreateFlags::CLOEXEC)?;
        let bell = eventfd(0, EventfdFlags::CLOEXEC | EventfdFlags::NONBLOCK)?;
        let timer = timerfd_create(
            TimerfdClockId::Monotonic,
            TimerfdFlags::CLOEXEC | TimerfdFlags::NONBLOCK,
        )?;
        epoll::add(&epoll, &bell, EventData::new_u64(BELL), EventFlags::IN)?;
        epoll::add(&epoll, &timer, EventData::new_u64(TIMER), EventFlags::IN)?;
        Ok(PortWake {
            epoll,
            bell,
            timer,
            port_armed: AtomicBool::new(false),
            timer_armed: AtomicBool::new(false),
        })
    }

    /// Wake the thread now.
    pub(crate) fn ring(&self) {
        // Only an overflowing count (never, at one ring per event) could refuse it.
        let _ = rustix::io::write(&self.bell, &1u64.to_ne_bytes());
    }

    /// A request just went out on `port`: its reply wakes the thread — input already
    /// there included — or, failing that, the deadline `within` from now. An error
    /// means nothing was armed: ring instead.
    pub(crate) fn arm(&self, port: BorrowedFd<'_>, within: Duration) -> io::Result<()> {
        let deadline = Itimerspec {
            it_interval: Timespec {
                tv_sec: 0,
                tv_nsec: 0,
            },
            it_value: Timespec::try_from(within).map_err(|_| io::ErrorKind::InvalidInput)?,
        };
        // Each flag is raised before its descriptor is armed: armed, it can wake the
        // thread at once (a reply already there, a deadline already past), whose wake
        // lowers the flag — raised after, the flag would stay up for a wake that came.
        self.timer_armed.store(true, SeqCst);
        if let Err(e) = timerfd_settime(&self.timer, TimerfdTimerFlags::empty(), &deadline) {
            self.timer_armed.store(false, SeqCst);
            return Err(e.into());
        }
        self.port_armed.store(true, SeqCst);
        let on = EventFlags::IN | EventFlags::ONESHOT;
        let armed = match epoll::modify(&self.epoll, port, EventData::new_u64(PORT), on) {
            // Not watched yet: a port just (re)opened.
            Err(Errno::NOENT) => epoll::add(&self.epoll, port, EventData::new_u64(PORT), on),
            other => other,
        };
        if let Err(e) = armed {
            self.port_armed.store(false, SeqCst);
            return Err(e.into());
        }
        Ok(())
    }

    /// The armed transaction is over: what did not wake the thread is disarmed, so
    /// neither a later status reply nor a past deadline wakes it for nothing.
    pub(crate) fn disarm(&self, port: Option<BorrowedFd<'_>>) {
        if self.timer_armed.swap(false, SeqCst) {
            let off = Itimerspec {
                it_interval: Timespec {
                    tv_sec: 0,
                    tv_nsec: 0,
                },
                it_value: Timespec {
                    tv_sec: 0,
                    tv_nsec: 0,
                },
            };
            let _ = timerfd_settime(&self.timer, TimerfdTimerFlags::empty(), &off);
        }
        if self.port_armed.swap(false, SeqCst) {
            if let Some(port) = port {
                // Still watched, reporting nothing (a hang-up at most, once).
                let _ = epoll::modify(
                    &self.epoll,
                    port,
                    EventData::new_u64(PORT),
                    EventFlags::ONESHOT,
                );
            }
        }
    }

    /// The port is armed and has not woken the thread yet.
    #[cfg(test)]
    pub(crate) fn port_armed(&self) -> bool {
        self.port_armed.load(SeqCst)
    }

    /// Sleep until rung, the armed port has input, the reply's deadline passes, or
    /// `timeout` (none: no limit). What woke it is cleared (the bell and the timer
    /// read, the port disarmed by its one shot).
    pub(crate) fn wait(&self, timeout: Option<Duration>) -> Woken {
        let mut events = [MaybeUninit::<Event>::uninit(); 3];
        // Rounded up to the millisecond by the system call: never early.
        let timeout = timeout.map(|t| {
            Timespec::try_from(t).unwrap_or(Timespec {
                tv_sec: i64::MAX / 1000,
                tv_nsec: 0,
            })
        });
        let mut woken = Woken::default();
        // A signal, or a failure the caller's loop re-checks after: a spurious wake-up
        // costs a turn, never a command.
        let Ok((got, _)) = epoll::wait(&self.epoll, &mut events, timeout.as_ref()) else {
            return woken;
        };
        for e in got.iter() {
            match e.data.u64() {
                BELL => woken.bell = true,
                TIMER => woken.timer = true,
                _ => woken.port = true,
            }
        }
        let mut count = [0u8; 8];
        if woken.bell {
            let _ = rustix::io::read(&self.bell, &mut count);
        }
        if woken.timer {
            let _ = rustix::io::read(&self.timer, &mut count);
            self.timer_armed.store(false, SeqCst);
        }
        if woken.port {
            self.port_armed.store(false, SeqCst);
        }
        woken
    }
}

impl AsFd for PortWake {
    /// The `epoll` descriptor.
    fn as_fd(&self) -> BorrowedFd<'_> {
        self.epoll.as_fd()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use serialport::TTYPort;
    use std::io::Write;
    use std::os::fd::AsRawFd;
    use std::time::Instant;

    #[allow(unsafe_code)]
    fn fd(port: &TTYPort) -> BorrowedFd<'_> {
        // SAFETY: the descriptor is open for as long as `port` lives.
        unsafe { BorrowedFd::borrow_raw(port.as_raw_fd()) }
    }

    /// Wait until `port` has input.
    fn readable(port: &TTYPort) {
        let fd = fd(port);
        let mut fds = [rustix::event::PollFd::new(
            &fd,
            rustix::event::PollFlags::IN,
        )];
        rustix::event::poll(&mut fds, None).unwrap();
    }

    /// A reply already waiting when the port is armed wakes the thread at once: arming
    /// after the write cannot miss a device faster than the writer.
    #[test]
    fn input_already_there_when_armed_wakes_at_once() {
        let (mut device, host) = TTYPort::pair().expect("a pseudo-terminal pair");
        let w = PortWake::new().unwrap();
        device.write_all(b"ok\n").unwrap();
        // Let the bytes cross the pseudo-terminal before arming.
        readable(&host);
        w.arm(fd(&host), Duration::from_secs(30)).unwrap();
        let woken = w.wait(Some(Duration::from_secs(30)));
        assert!(woken.port, "{woken:?}");
    }

    /// Disarmed, the port's input wakes nobody: the bell, rung after it, is what ends
    /// the wait (a barrier: the input came first).
    #[test]
    fn a_disarmed_port_wakes_nobody() {
        let (mut device, host) = TTYPort::pair().expect("a pseudo-terminal pair");
        let w = PortWake::new().unwrap();
        w.arm(fd(&host), Duration::from_secs(30)).unwrap();
        w.disarm(Some(fd(&host)));
        device.write_all(b"= pos=0.1\n").unwrap();
        readable(&host);
        w.ring();
        let woken = w.wait(Some(Duration::from_secs(30)));
        assert_eq!(
            woken,
            Woken {
                bell: true,
                ..Woken::default()
            }
        );
    }

    /// A silent device: the reply's deadline ends the wait, not the caller's timeout.
    #[test]
    fn a_silent_device_wakes_the_thread_at_the_reply_deadline() {
        let (_device, host) = TTYPort::pair().expect("a pseudo-terminal pair");
        let w = PortWake::new().unwrap();
        let t = Instant::now();
        w.arm(fd(&host), Duration::from_millis(30)).unwrap();
        let woken = w.wait(Some(Duration::from_secs(30)));
        assert!(woken.timer && !woken.port, "{woken:?}");
        assert!(t.elapsed() >= Duration::from_millis(30));
        assert!(t.elapsed() < Duration::from_secs(20));
    }
}
