//! A device gone — unplugged, a wrong path, an adapter that vanished — never ends the
//! run. The engine reopens its port with a capped backoff for as long as adrive runs (a
//! bus's reader its adapter, [`crate::engine::bus`]); the vehicle is kept safe (a device
//! the rules need refuses engage while it is gone, [`crate::safety::gate_state::needed`]);
//! every other device is polled and commanded as ever. What this part adds is words:
//! what adrive waits for, said plainly in the log, the snapshot
//! (`supervisor.waiting`) and the console —
//! `waiting for horn on /dev/ttyUSB3: No such file or directory, retrying every 5s` —
//! and when each device is back. Ending the run instead is the operator's choice
//! (`give_up_after`, [`Waiting::longest`]).

use crate::snapshot::{FaultKind, OutcomeKind, WaitingView};
use crate::vehicle::supervision::Fault;
use crate::vehicle::Vehicle;
use std::collections::BTreeMap;
use std::sync::atomic::Ordering::Relaxed;
use std::time::{Duration, Instant};

/// How often a device still gone is said again in the log.
const REMIND_EVERY: Duration = Duration::from_secs(60);

/// One device gone.
struct Gone {
    since: Instant,
    port: String,
    error: String,
    /// When it was last said in the log.
    said: Instant,
}

/// The devices gone, by name.
#[derive(Default)]
pub(crate) struct Waiting {
    gone: BTreeMap<String, Gone>,
}

impl Waiting {
    /// One supervisor turn at `now`, over this turn's `faults` (`disconnected`: a port
    /// that cannot be opened): say who went, who is back, who is still awaited (once a
    /// minute); the views for the snapshot.
    pub(crate) fn turn(&mut self, v: &Vehicle, faults: &[Fault], now: Instant) -> Vec<WaitingView> {
        let board = v.supervision();
        let gone: Vec<&Fault> = faults
            .iter()
            .filter(|f| f.kind == FaultKind::Disconnected)
            .collect();
        let back: Vec<String> = self
            .gone
            .keys()
            .filter(|name| !gone.iter().any(|f| f.device.as_ref() == Some(*name)))
            .cloned()
            .collect();
        for name in back {
            let g = self.gone.remove(&name).expect("listed");
            let msg = format!(
                "{name} is back on {} after {:.1} s",
                g.port,
                (now - g.since).as_secs_f64()
            );
            tracing::info!(device = %name, "{msg}");
            board.note(msg.clone());
            board.set_outcome(OutcomeKind::Back, msg);
            if self.gone.is_empty() {
                crate::service::running();
            }
        }
        let mut views = Vec::new();
        for f in gone {
            let Some(d) = f.device.as_deref().and_then(|n| v.find(n)) else {
                continue;
            };
            let port = d.config().port.clone();
            let error = reason(&f.cause, &port);
            let view = |g: &Gone| WaitingView {
                device: d.name().to_string(),
                port: g.port.clone(),
                error: g.error.clone(),
                gone_ms: (now - g.since).as_secs_f64() * 1e3,
                retry_ms: d.port_health().retry_ms.load(Relaxed) as f64,
                needed: crate::safety::gate_state::needed(v, d),
            };
            let effect = if crate::safety::gate_state::needed(v, d) {
                "engage is refused until it is back"
            } else {
                "it holds up nothing"
            };
            match self.gone.get_mut(d.name()) {
                None => {
                    let g = Gone {
                        since: f.since,
                        port,
                        error,
                        said: now,
                    };
                    let w = view(&g);
                    tracing::warn!(device = %w.device, "{}; the other devices run on, {effect}", w.describe());
                    board.note(w.describe());
                    crate::service::status(&w.describe());
                    self.gone.insert(d.name().to_string(), g);
                    views.push(w);
                }
                Some(g) => {
                    if g.error != error || now - g.said >= REMIND_EVERY {
                        g.error = error;
                        g.said = now;
                        let w = view(g);
                        tracing::warn!(
                            device = %w.device,
                            "still {} (gone {}), {effect}",
                            w.describe(),
                            humantime::format_duration(Duration::from_secs((now - g.since).as_secs()))
                        );
                    }
                    views.push(view(g));
                }
            }
        }
        views
    }

    /// The device gone the longest, and for how long.
    pub(crate) fn longest(&self, now: Instant) -> Option<(&str, Duration)> {
        self.gone
            .iter()
            .map(|(n, g)| (n.as_str(), now - g.since))
            .max_by_key(|(_, d)| *d)
    }
}

/// Why the port cannot be opened, without the path said beside it:
/// `cannot open /dev/ttyUSB3: No such file or directory` is `No such file or directory`.
fn reason(cause: &str, port: &str) -> String {
    cause
        .strip_prefix(&format!("cannot open {port}: "))
        .unwrap_or(cause)
        .to_string()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_reason_leaves_out_the_path_said_beside_it() {
        assert_eq!(
            reason(
                "cannot open /dev/ttyUSB3: No such file or directory",
                "/dev/ttyUSB3"
            ),
            "No such file or directory"
        );
        assert_eq!(
            reason("bus kit: adapter lost", "/dev/ttyACM0"),
            "bus kit: adapter lost"
        );
    }
}
