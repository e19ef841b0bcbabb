//! Does the terminal report key releases? The start-up probe, as a pure state machine.
//!
//! The kitty keyboard protocol's own way to ask: write `CSI ? u` (the flags in force)
//! and then `CSI c` (the primary device attributes, which every terminal answers). A
//! flags answer before the attributes means the protocol is there; the attributes alone
//! mean it is not. crossterm's `supports_keyboard_enhancement` asks the same but waits
//! up to 2 s for an answer; here a terminal that answers nothing costs [`WAIT`] and is
//! taken as [`Keyboard::PressesOnly`] — and if its answers come late after all, the
//! verdict is upgraded then.
//!
//! Under a terminal multiplexer on this machine (tmux, screen: `TMUX` or `STY` in the
//! environment, or a `TERM` of theirs) the probe is not sent: the multiplexer answers
//! for the terminal, does not pass releases on, and is what the liveness check's
//! round trip reaches instead of the operator's terminal ([`multiplexer`]).

use super::Keyboard;
use std::time::{Duration, Instant};

/// How long the probe waits for the device attributes before it goes on without.
pub(crate) const WAIT: Duration = Duration::from_millis(100);
/// What the probe writes.
pub(crate) const QUERY: &[u8] = b"\x1b[?u\x1b[c";

/// The probe's progress.
#[derive(Clone, Debug, PartialEq)]
pub(crate) struct Probe {
    sent: Instant,
    /// A flags answer came (and no attributes after it yet).
    flags: bool,
    /// What was told so far.
    told: Option<Keyboard>,
}

impl Probe {
    /// A probe written at `sent`.
    pub(crate) fn sent(sent: Instant) -> Probe {
        Probe {
            sent,
            flags: false,
            told: None,
        }
    }

    /// No probe: what the terminal reports is known already (`keyboard`).
    pub(crate) fn known(keyboard: Keyboard, now: Instant) -> Probe {
        Probe {
            sent: now,
            flags: false,
            told: Some(keyboard),
        }
    }

    /// What was told so far (`None` while the probe waits).
    pub(crate) fn verdict(&self) -> Option<Keyboard> {
        self.told
    }

    /// When the probe stops waiting, if it still waits.
    pub(crate) fn deadline(&self) -> Option<Instant> {
        self.told.is_none().then_some(self.sent + WAIT)
    }

    /// The terminal's flags answer arrived.
    pub(crate) fn flags(&mut self) {
        self.flags = true;
    }

    /// The device attributes arrived: the verdict, if it is news.
    pub(crate) fn attributes(&mut self) -> Option<Keyboard> {
        let found = if std::mem::take(&mut self.flags) {
            Keyboard::Releases
        } else {
            Keyboard::PressesOnly
        };
        self.tell(match (self.told, found) {
            // A late answer upgrades; nothing downgrades what was found.
            (Some(Keyboard::Releases), _) => Keyboard::Releases,
            (_, found) => found,
        })
    }

    /// Time passed: past [`WAIT`] with no answer, the terminal is taken as reporting
    /// presses only.
    pub(crate) fn tick(&mut self, now: Instant) -> Option<Keyboard> {
        match self.deadline() {
            Some(d) if now >= d => self.tell(Keyboard::PressesOnly),
            _ => None,
        }
    }

    fn tell(&mut self, k: Keyboard) -> Option<Keyboard> {
        (self.told.replace(k) != Some(k)).then_some(k)
    }
}

/// A terminal multiplexer runs between adrive and the operator's terminal, on this
/// machine: its name. It answers requests itself (so a round trip proves only that it
/// runs, not that the operator's link does), and drops key releases.
pub(crate) fn multiplexer(var: impl Fn(&str) -> Option<String>) -> Option<&'static str> {
    let term = var("TERM").unwrap_or_default();
    if var("TMUX").is_some_and(|v| !v.is_empty()) || term.starts_with("tmux") {
        Some("tmux")
    } else if var("STY").is_some_and(|v| !v.is_empty()) || term.starts_with("screen") {
        Some("screen")
    } else {
        None
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn ms(n: u64) -> Duration {
        Duration::from_millis(n)
    }

    #[test]
    fn flags_then_attributes_is_the_kitty_protocol() {
        let t = Instant::now();
        let mut p = Probe::sent(t);
        p.flags();
        assert_eq!(p.attributes(), Some(Keyboard::Releases));
        assert_eq!(p.tick(t + ms(500)), None, "decided: no timeout after");
    }

    #[test]
    fn attributes_alone_is_presses_only() {
        let t = Instant::now();
        let mut p = Probe::sent(t);
        assert_eq!(p.attributes(), Some(Keyboard::PressesOnly));
        assert_eq!(p.attributes(), None, "told once");
    }

    /// A terminal that answers nothing costs the probe's wait, no more; answers that
    /// come late upgrade the verdict.
    #[test]
    fn silence_is_presses_only_after_the_wait_and_a_late_answer_upgrades() {
        // crossterm's own probe waits up to 2 s; this one costs a start-up ~100 ms at most.
        assert!(WAIT <= Duration::from_millis(100), "{WAIT:?}");
        let t = Instant::now();
        let mut p = Probe::sent(t);
        assert_eq!(p.deadline(), Some(t + WAIT));
        assert_eq!(p.tick(t + WAIT - ms(1)), None);
        assert_eq!(p.tick(t + WAIT), Some(Keyboard::PressesOnly));
        assert_eq!(p.deadline(), None);
        p.flags();
        assert_eq!(p.attributes(), Some(Keyboard::Releases));
        assert_eq!(p.verdict(), Some(Keyboard::Releases));
        // Attributes again (another program asked) never downgrade.
        assert_eq!(p.attributes(), None);
    }

    #[test]
    fn a_multiplexer_is_known_from_the_environment() {
        let env = |pairs: &'static [(&'static str, &'static str)]| {
            move |k: &str| {
                pairs
                    .iter()
                    .find(|(n, _)| *n == k)
                    .map(|(_, v)| v.to_string())
            }
        };
        assert_eq!(
            multiplexer(env(&[("TMUX", "/tmp/tmux-0/default,1,0")])),
            Some("tmux")
        );
        assert_eq!(multiplexer(env(&[("TERM", "tmux-256color")])), Some("tmux"));
        assert_eq!(multiplexer(env(&[("STY", "123.pts-0")])), Some("screen"));
        assert_eq!(
            multiplexer(env(&[("TERM", "screen.xterm")])),
            Some("screen")
        );
        assert_eq!(multiplexer(env(&[("TERM", "xterm-kitty")])), None);
        assert_eq!(multiplexer(env(&[("TMUX", "")])), None);
    }
}
