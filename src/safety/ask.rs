//! What a source asks of the vehicle, and what comes back: the intake's vocabulary.
//! Every front end (the console, attached consoles, the network, ROS 2, `adrive ctl`)
//! turns what it receives into an [`Ask`] tagged with its [`crate::value::Source`];
//! the engine's intake ([`crate::engine::Gate::admit`]) answers with [`Done`] or
//! [`Refused`], which each front end turns into its reply, log line or message.

use super::owner::{self, Act};
use super::Reject;
use crate::snapshot::Blocker;
use crate::value::{Command, DeviceId};
use std::time::Duration;

/// What a source asks of the vehicle.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Ask {
    /// Engage a disengaged vehicle, or pick up one handed over; command it.
    Engage,
    /// Disengage into the stop state (the manual state while a driver has taken over).
    Disengage,
    /// The operator's STOP: disengage, throttle 0, brake full (always).
    Stop,
    /// Give command up: the vehicle stays engaged for the handover.
    Release,
    /// Take command from whoever has it (a console, after its confirmation).
    Take,
    /// Clear the latched driver overrides (moves nothing).
    Clear,
    /// Hold: the safe state (throttle 0, brake full), staying engaged — a console
    /// leaving teleop.
    Hold,
    /// A command for one device.
    Set(DeviceId, Command),
    /// The virtual `accel` (−1 … 1): throttle and brake, as a whole.
    Accel(f64),
    /// The virtual `accel` while a key is held: gas only on a lease
    /// ([`super::lease`]) that the engine ends, whatever the console does.
    Held(Held),
    /// The key is still held: the running lease lasts this long from now. A lease that
    /// ran out is not renewed ([`Done::Same`]).
    Renew(Duration),
}

/// The accel of a held key ([`Ask::Held`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Held {
    /// The accel now (−1 … 1).
    pub accel: f64,
    /// Gas (`accel` above 0) lasts this long from the ask's receipt unless renewed.
    pub lease: Duration,
    /// The accel when the lease runs out: never gas (the brake at its hold level).
    pub release: f64,
}

impl Ask {
    pub(crate) fn act(self) -> Option<Act> {
        Some(match self {
            Ask::Engage => Act::Engage,
            Ask::Disengage | Ask::Stop => Act::Stop,
            Ask::Release => Act::Release,
            Ask::Take => Act::Take,
            Ask::Set(..) | Ask::Accel(_) | Ask::Held(_) | Ask::Renew(_) | Ask::Hold => Act::Command,
            Ask::Clear => return None,
        })
    }
}

/// Why the intake refused an ask. Nothing changed.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Refused {
    /// Ownership: another source commands, nobody does, …
    Owner(owner::Refusal),
    /// The value or an interlock (counted by reason).
    Rule(Reject),
    /// Engaging is blocked right now (a faulty device, the e-stop…).
    Blocked(Vec<Blocker>),
    /// The ask never reached an intake that could decide it (adrive did not answer
    /// over the control socket; a replay sends nothing).
    Unanswered(String),
    /// An override cannot be cleared yet: the driver's hand is still on.
    Clear(String),
}

impl std::fmt::Display for Refused {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Refused::Owner(r) => write!(f, "{r}"),
            Refused::Rule(r) => write!(f, "{r}"),
            Refused::Blocked(why) => f.write_str(&Blocker::said(why)),
            Refused::Unanswered(why) => f.write_str(why),
            Refused::Clear(why) => f.write_str(why),
        }
    }
}

/// What an admitted ask did.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Done {
    /// The command is on its way.
    Commanded,
    /// Engaged; the source commands.
    Engaged,
    /// The source commands the engaged vehicle from now on (taken or picked up).
    Commanding,
    /// Nothing changed (the commander repeating `engage`, a console taking what it has).
    Same,
    /// Command given up; the vehicle stays engaged for the handover.
    Released,
    /// Disengaged (`true`: it was engaged).
    Disengaged(bool),
    /// The cleared overrides (empty: there was nothing to clear).
    Cleared(Vec<String>),
}

/// What an admitted ask did, in words: the one answer every front end gives (the
/// network's reply after `ok `, `adrive ctl`, the console's message line, ROS 2's
/// log). A disengage on a vehicle that was not engaged still commands the safe state,
/// and says it was `already disengaged`.
impl std::fmt::Display for Done {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Done::Commanded => f.write_str("commanded"),
            Done::Engaged | Done::Commanding => f.write_str("engaged"),
            Done::Same => f.write_str("nothing changed"),
            Done::Released => f.write_str("released"),
            Done::Disengaged(true) => f.write_str("disengaged"),
            Done::Disengaged(false) => f.write_str("already disengaged"),
            Done::Cleared(c) if c.is_empty() => f.write_str("nothing to clear"),
            Done::Cleared(c) => {
                f.write_str("cleared override on ")?;
                for (i, d) in c.iter().enumerate() {
                    if i > 0 {
                        f.write_str(", ")?;
                    }
                    f.write_str(d)?;
                }
                Ok(())
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The words every front end answers with: each outcome its own, the cleared
    /// overrides listed once each, separated by commas.
    #[test]
    fn each_outcome_has_its_words_and_cleared_overrides_are_listed() {
        let said = |d: Done| d.to_string();
        assert_eq!(said(Done::Commanded), "commanded");
        assert_eq!(said(Done::Engaged), "engaged");
        assert_eq!(said(Done::Commanding), "engaged");
        assert_eq!(said(Done::Same), "nothing changed");
        assert_eq!(said(Done::Released), "released");
        assert_eq!(said(Done::Disengaged(true)), "disengaged");
        assert_eq!(said(Done::Disengaged(false)), "already disengaged");
        assert_eq!(said(Done::Cleared(vec![])), "nothing to clear");
        assert_eq!(
            said(Done::Cleared(vec!["steer".into()])),
            "cleared override on steer"
        );
        assert_eq!(
            said(Done::Cleared(vec!["steer".into(), "brake".into()])),
            "cleared override on steer, brake"
        );
    }
}
