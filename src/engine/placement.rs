//! Puts a thread of the command path where the vehicle file asks
//! ([`Placement`]): pinned to CPUs, under `SCHED_FIFO`. Each thread calls [`apply`]
//! for itself as it starts (`net/listen`, every `<device>/command`).
//!
//! Pinning needs no privilege. A real-time priority does (`CAP_SYS_NICE`, or an
//! `RLIMIT_RTPRIO` at least that high): without it the thread keeps normal scheduling
//! and the first refusal is logged once, with what to do — adrive runs on, as fast as
//! it is without the option.

use crate::config::placement::Placement;
use std::sync::atomic::{AtomicBool, Ordering::Relaxed};

/// A refusal has been logged (once per process, whichever thread met it).
static WARNED_PRIORITY: AtomicBool = AtomicBool::new(false);
static WARNED_CPUS: AtomicBool = AtomicBool::new(false);

/// What applying a placement to the calling thread did.
#[derive(Debug, PartialEq, Eq)]
pub(crate) struct Applied {
    pub pinned: Result<(), String>,
    pub(crate) realtime: Result<(), String>,
}

/// Place the calling thread. Refusals are logged once and returned, never fatal.
pub(crate) fn apply(p: &Placement) -> Applied {
    let pinned = if p.cpus.is_empty() {
        Ok(())
    } else {
        pin(&p.cpus).inspect_err(|e| {
            if !WARNED_CPUS.swap(true, Relaxed) {
                tracing::warn!(
                    "cpus = {:?}: the kernel refused to pin the command path ({e}); it runs \
                     wherever the kernel puts it (see `nproc` and the cgroup's cpuset)",
                    p.cpus
                );
            }
        })
    };
    let realtime = match p.realtime_priority {
        None => Ok(()),
        Some(prio) => fifo(prio).inspect_err(|e| {
            if !WARNED_PRIORITY.swap(true, Relaxed) {
                tracing::warn!(
                    "realtime_priority = {prio}: the kernel refused SCHED_FIFO ({e}); the \
                     command path runs at normal priority. Grant it with `sudo setcap \
                     cap_sys_nice+ep $(command -v adrive)`, `LimitRTPRIO={prio}` in a \
                     systemd unit, or an `rtprio` line in /etc/security/limits.conf"
                );
            }
        }),
    };
    Applied { pinned, realtime }
}

fn pin(cpus: &[usize]) -> Result<(), String> {
    #[allow(unsafe_code)]
    // SAFETY: a zeroed cpu_set_t is the empty set; CPU_SET stays within it for numbers
    // below CPU_SETSIZE, which the vehicle file's check guarantees.
    let r = unsafe {
        let mut set: libc::cpu_set_t = std::mem::zeroed();
        for &c in cpus {
            if c < crate::config::placement::MAX_CPUS {
                libc::CPU_SET(c, &mut set);
            }
        }
        libc::sched_setaffinity(0, std::mem::size_of::<libc::cpu_set_t>(), &set)
    };
    if r == 0 {
        Ok(())
    } else {
        Err(std::io::Error::last_os_error().to_string())
    }
}

fn fifo(priority: u64) -> Result<(), String> {
    let param = libc::sched_param {
        sched_priority: priority as i32,
    };
    #[allow(unsafe_code)]
    // SAFETY: sched_setscheduler reads the parameter we hand it; 0 is this thread.
    let r = unsafe { libc::sched_setscheduler(0, libc::SCHED_FIFO, &param) };
    if r == 0 {
        Ok(())
    } else {
        Err(std::io::Error::last_os_error().to_string())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The current thread's CPUs.
    #[allow(unsafe_code)]
    fn allowed() -> Vec<usize> {
        // SAFETY: sched_getaffinity fills the set we hand it.
        unsafe {
            let mut set: libc::cpu_set_t = std::mem::zeroed();
            libc::sched_getaffinity(0, std::mem::size_of::<libc::cpu_set_t>(), &mut set);
            (0..64).filter(|c| libc::CPU_ISSET(*c, &set)).collect()
        }
    }

    #[test]
    fn a_thread_is_pinned_where_asked() {
        let first = allowed()[0];
        let got = std::thread::spawn(move || {
            let a = apply(&Placement {
                cpus: vec![first],
                realtime_priority: None,
            });
            (a, allowed())
        })
        .join()
        .unwrap();
        assert_eq!(got.0.pinned, Ok(()));
        assert_eq!(got.1, [first]);
    }

    #[test]
    fn a_cpu_the_machine_lacks_is_refused_not_fatal() {
        let a = std::thread::spawn(|| {
            apply(&Placement {
                cpus: vec![1000],
                realtime_priority: None,
            })
        })
        .join()
        .unwrap();
        assert!(a.pinned.is_err(), "{a:?}");
    }

    /// With the privilege the thread runs under SCHED_FIFO; without it the refusal comes
    /// back (and is logged), and the thread runs on at normal priority.
    #[test]
    #[allow(unsafe_code)]
    fn a_realtime_priority_is_taken_or_refused_with_a_reason() {
        let (a, policy) = std::thread::spawn(|| {
            let a = apply(&Placement {
                cpus: vec![],
                realtime_priority: Some(10),
            });
            // SAFETY: plain query of this thread's policy.
            (a, unsafe { libc::sched_getscheduler(0) })
        })
        .join()
        .unwrap();
        match a.realtime {
            Ok(()) => assert_eq!(policy, libc::SCHED_FIFO),
            Err(e) => {
                assert_eq!(policy, libc::SCHED_OTHER);
                assert!(!e.is_empty());
            }
        }
    }
}
