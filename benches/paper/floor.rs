//! The machine's floor: how long a bare condition-variable wake takes (parking_lot,
//! as adrive's command slot uses), from `notify` to the woken thread running. adrive's
//! receipt → first byte can only be this plus its own work, so every delay figure is
//! compared with a floor measured in the same window, on the same loaded machine.

use parking_lot::{Condvar, Mutex};
use std::sync::atomic::{AtomicBool, Ordering::Relaxed};
use std::sync::Arc;
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

/// Where the two threads of the floor run.
#[derive(Clone, Copy, Debug)]
pub enum Cpus {
    /// Wherever the kernel puts them.
    Any,
    /// Both on CPU 0.
    Same,
    /// Waker on CPU 0, waiter on CPU 1.
    Apart,
}

/// What the woken thread does before it stamps the wake.
#[derive(Clone, Copy, Debug)]
pub enum Then {
    /// Nothing: the bare wake.
    Stamp,
    /// Write a command's 8 bytes to a raw pseudo-terminal first, stamped once the
    /// kernel has taken them, as adrive stamps its first byte: the floor of a command
    /// that has to reach a port.
    Write,
    /// The same write, stamped when the thread draining the pseudo-terminal's other end
    /// reads the bytes: the write's return comes before the bytes are on their way or
    /// after, as the kernel's worker that delivers them happens to run (docs/
    /// performance.md, "What a pty write costs"); their arrival is one event whatever
    /// ran first.
    Deliver,
}

/// A raw pseudo-terminal whose master side is drained by a thread of its own: the
/// slave to write to, and the thread, which ends when the slave is closed and returns
/// how long after the instant last put in `sent` each read that found it returned.
#[allow(unsafe_code)]
fn pty(sent: Arc<Mutex<Option<Instant>>>) -> (std::fs::File, JoinHandle<Vec<Duration>>) {
    use std::io::Read;
    let (master, slave) = crate::common::pty::openpty(80, 24);
    for fd in [&master, &slave] {
        use std::os::fd::AsRawFd;
        // SAFETY: tcgetattr/tcsetattr on a terminal we own; cfmakeraw edits the struct.
        unsafe {
            let mut t: libc::termios = std::mem::zeroed();
            libc::tcgetattr(fd.as_raw_fd(), &mut t);
            libc::cfmakeraw(&mut t);
            libc::tcsetattr(fd.as_raw_fd(), libc::TCSANOW, &t);
        }
    }
    let mut m = std::fs::File::from(master);
    let drain = std::thread::spawn(move || {
        let mut buf = [0u8; 4096];
        let mut out = Vec::with_capacity(8192);
        while matches!(m.read(&mut buf), Ok(n) if n > 0) {
            if let Some(t) = sent.lock().take() {
                out.push(t.elapsed());
            }
        }
        out
    });
    (std::fs::File::from(slave), drain)
}

/// Wakes measured at `rate` Hz in the background until [`Floor::finish`].
pub struct Floor {
    stop: Arc<AtomicBool>,
    waker: Option<JoinHandle<()>>,
    waiter: Option<JoinHandle<Vec<Duration>>>,
    /// The delivery's stamps ([`Then::Deliver`]).
    drain: Option<JoinHandle<Vec<Duration>>>,
    pair: Arc<(Mutex<Option<Instant>>, Condvar)>,
}

#[allow(unsafe_code)]
fn pin(cpu: usize) {
    // SAFETY: a zeroed cpu_set_t is empty; CPU_SET stays within it.
    unsafe {
        let mut set: libc::cpu_set_t = std::mem::zeroed();
        libc::CPU_SET(cpu, &mut set);
        libc::sched_setaffinity(0, std::mem::size_of::<libc::cpu_set_t>(), &set);
    }
}

impl Floor {
    pub fn start(rate: f64, cpus: Cpus) -> Floor {
        Floor::start_then(rate, cpus, Then::Stamp)
    }

    pub fn start_then(rate: f64, cpus: Cpus, then: Then) -> Floor {
        let sent = Arc::new(Mutex::new(None::<Instant>));
        let (mut port, drain) = match then {
            Then::Stamp => (None, None),
            Then::Write | Then::Deliver => {
                let (port, drain) = pty(sent.clone());
                (Some(port), Some(drain))
            }
        };
        let pair = Arc::new((Mutex::new(None::<Instant>), Condvar::new()));
        let stop = Arc::new(AtomicBool::new(false));
        let (p, s) = (pair.clone(), stop.clone());
        let waiter = std::thread::spawn(move || {
            match cpus {
                Cpus::Same => pin(0),
                Cpus::Apart => pin(1),
                Cpus::Any => {}
            }
            let mut out = Vec::with_capacity(8192);
            let mut g = p.0.lock();
            loop {
                if s.load(Relaxed) {
                    return out;
                }
                if let Some(t) = g.take() {
                    if let Some(p) = port.as_mut() {
                        use std::io::Write;
                        if matches!(then, Then::Deliver) {
                            *sent.lock() = Some(t);
                        }
                        let _ = p.write(b"! 0.250\n");
                    }
                    if !matches!(then, Then::Deliver) {
                        out.push(t.elapsed());
                    }
                }
                p.1.wait(&mut g);
            }
        });
        let (p, s) = (pair.clone(), stop.clone());
        let waker = std::thread::spawn(move || {
            if !matches!(cpus, Cpus::Any) {
                pin(0);
            }
            let period = Duration::from_secs_f64(1.0 / rate);
            let mut next = Instant::now() + period / 2;
            while !s.load(Relaxed) {
                if let Some(d) = next.checked_duration_since(Instant::now()) {
                    std::thread::sleep(d);
                }
                next += period;
                *p.0.lock() = Some(Instant::now());
                p.1.notify_one();
            }
        });
        Floor {
            stop,
            waker: Some(waker),
            waiter: Some(waiter),
            drain,
            pair,
        }
    }

    /// Stop; every wake delay measured, sorted.
    pub fn finish(mut self) -> Vec<Duration> {
        self.stop.store(true, Relaxed);
        if let Some(w) = self.waker.take() {
            let _ = w.join();
        }
        self.pair.1.notify_all();
        let mut v = self
            .waiter
            .take()
            .map(|w| w.join().unwrap())
            .unwrap_or_default();
        // The waiter has dropped the slave: the drain thread reads its end and ends.
        if let Some(d) = self.drain.take() {
            v.extend(d.join().unwrap());
        }
        v.sort();
        v
    }
}

/// The `q` quantile of sorted samples, in µs.
pub fn quantile(sorted: &[Duration], q: f64) -> f64 {
    if sorted.is_empty() {
        return f64::NAN;
    }
    let i = ((sorted.len() - 1) as f64 * q).round() as usize;
    sorted[i].as_secs_f64() * 1e6
}
