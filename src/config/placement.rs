//! Where the command path runs: the `[vehicle]` keys `cpus` and `realtime_priority`.
//!
//! The command path is the command listener (`net/listen`) and every command thread:
//! the threads between a datagram and the first byte on the wire. Nothing else is
//! moved. By default they run wherever the kernel schedules them, at normal priority,
//! which needs no privilege and is fast on an idle machine; on a loaded one, pinning
//! them to a CPU of their own and giving them a real-time priority (`SCHED_FIFO`, as
//! ros2_control's `thread_priority` does) keeps other work from delaying a command.
//! The engine applies this ([`crate::engine::placement`]); the benchmark shows each
//! option's effect.

use super::limits::Violation;
use serde::Deserialize;

/// The highest `SCHED_FIFO` priority Linux has.
pub(crate) const MAX_PRIORITY: u64 = 99;
/// CPUs a pinning may name: 0 to this, exclusive (glibc's `CPU_SETSIZE`).
pub(crate) const MAX_CPUS: usize = 1024;

/// Where the command path runs.
#[derive(Clone, Debug, Default, PartialEq, Eq, Deserialize)]
pub struct Placement {
    /// Pin the command path to these CPUs (empty: anywhere).
    #[serde(default)]
    pub cpus: Vec<usize>,
    /// Run it under `SCHED_FIFO` at this priority, 1 to 99 (none: normal scheduling).
    #[serde(default)]
    pub realtime_priority: Option<u64>,
}

impl Placement {
    /// Every value within its range.
    pub fn check(&self) -> Result<(), Violation> {
        if let Some(p) = self.realtime_priority {
            if !(1..=MAX_PRIORITY).contains(&p) {
                return Err(Violation {
                    paths: vec!["realtime_priority".into()],
                    message: format!(
                        "realtime_priority: expected a SCHED_FIFO priority from 1 to \
                         {MAX_PRIORITY}, got {p} (leave it out for normal scheduling)"
                    ),
                });
            }
        }
        if let Some(c) = self.cpus.iter().find(|c| **c >= MAX_CPUS) {
            return Err(Violation {
                paths: vec!["cpus".into()],
                message: format!(
                    "cpus: expected CPU numbers from 0 to {}, got {c}",
                    MAX_CPUS - 1
                ),
            });
        }
        Ok(())
    }

    /// Nothing asked: the kernel's defaults.
    #[cfg_attr(not(test), allow(dead_code))]
    pub(crate) fn is_default(&self) -> bool {
        self == &Placement::default()
    }
}

#[cfg(test)]
mod tests {
    use crate::config::parse;

    fn vehicle(keys: &str) -> String {
        format!("[vehicle]\nname = \"t\"\n{keys}\n")
    }

    #[test]
    fn placement_is_read_from_the_vehicle_table() {
        let c = parse(&vehicle("cpus = [1]\nrealtime_priority = 40"), "t.toml").unwrap();
        assert_eq!(c.vehicle.placement.cpus, [1]);
        assert_eq!(c.vehicle.placement.realtime_priority, Some(40));
        let c = parse(&vehicle(""), "t.toml").unwrap();
        assert!(c.vehicle.placement.is_default());
    }

    #[test]
    fn an_absurd_priority_or_cpu_is_refused_at_its_line() {
        let e = parse(&vehicle("realtime_priority = 120"), "t.toml").unwrap_err();
        assert_eq!(e.line, 3, "{e}");
        assert!(e.message.contains("from 1 to 99"), "{e}");
        let e = parse(&vehicle("\ncpus = [0, 5000]"), "t.toml").unwrap_err();
        assert_eq!(e.line, 4, "{e}");
        assert!(e.message.contains("cpus"), "{e}");
    }
}
