//! Who commands the vehicle: the ownership rule, as one pure function.
//!
//! At most one [`Source`] commands the engaged vehicle, and command changes hands only
//! explicitly and visibly:
//! - a source **engages** a disengaged vehicle and commands it from then on;
//! - the commander **releases** it: the vehicle stays engaged for a short handover (the
//!   network watchdog's timeout) in which another source takes it by engaging; if
//!   none does, it is brought to the safe state and disengaged;
//! - an operator at a **console takes** it (one key, with a confirmation): a console
//!   outranks the network and ROS 2, never the other way round;
//! - anyone allowed to send may always **stop** or **disengage** it; then nobody
//!   commands.
//!
//! [`decide`] says what an act leads to given who commands now; [`Owner`] is who
//! commands and the commander's watchdog; the engine's intake
//! ([`crate::engine::Gate::admit`]) applies the decision under the one lock around
//! `Owner`, so that no command slips between a decision and a change of hands. The guide's table (docs/safety.md) of these rules is
//! [`markdown`], checked by a test.

use super::ask::Ask;
use crate::snapshot::WatchdogView;
use crate::value::Source;
use std::time::{Duration, Instant};

/// What a source does, as far as ownership goes.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Act {
    /// Engage (or take a vehicle handed over).
    Engage,
    /// Command a device (or `accel`).
    Command,
    /// Give command up.
    Release,
    /// Take command from whoever has it (a console, with a confirmation).
    Take,
    /// Stop or disengage.
    Stop,
    /// Switch the interlocks (a console, with a confirmation).
    Interlocks,
    /// Tune a device from a console: its delays, its threads on or off, a wake of its
    /// command thread, a simulated fault.
    Tune,
}

/// Why ownership refuses an act.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Refusal {
    /// Another source commands the engaged vehicle.
    Commander(Source),
    /// The vehicle is engaged and handed over: nobody commands it until a source
    /// engages.
    NobodyCommands,
    /// The source does not command the vehicle (nothing to release).
    NotCommanding,
    /// Only a console may do this.
    NotAConsole,
    /// The vehicle is not engaged (nothing to take).
    NotEngaged,
}

impl std::fmt::Display for Refusal {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Refusal::Commander(c) => write!(f, "commanded by {}", Commander(*c)),
            Refusal::NobodyCommands => {
                f.write_str("nobody commands the vehicle: engage to take command")
            }
            Refusal::NotCommanding => f.write_str("this source does not command the vehicle"),
            Refusal::NotAConsole => f.write_str("only an operator at a console may do this"),
            Refusal::NotEngaged => f.write_str("the vehicle is not engaged: engage instead"),
        }
    }
}

/// A commander as people read it: `console`, `network 127.0.0.1:5555`, `ros2`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) struct Commander(pub Source);

impl std::fmt::Display for Commander {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self.0 {
            Source::Network(a) => write!(f, "network {a}"),
            Source::Operator(uid) => write!(f, "operator (uid {uid}, adrive ctl)"),
            other => write!(f, "{other}"),
        }
    }
}

/// What an allowed act does to who commands.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Outcome {
    /// Who commands stays as it is (the commander's own command or repeat).
    Same,
    /// The source engages a disengaged vehicle and commands it.
    Engages,
    /// The source now commands the engaged vehicle (taken, or picked up after a
    /// release); the previous commander, if any, does not.
    Commands,
    /// Nobody commands; the vehicle stays engaged for the handover.
    Released,
    /// The vehicle stops (or disengages); nobody commands.
    Stops,
}

/// The ownership rule: what `act` by `source` leads to, when the vehicle is `engaged`
/// and `commander` commands it (meaningful only while engaged).
pub(crate) fn decide(
    engaged: bool,
    commander: Option<Source>,
    source: Source,
    act: Act,
) -> Result<Outcome, Refusal> {
    let commander = commander.filter(|_| engaged);
    let mine = commander == Some(source);
    match act {
        Act::Stop => Ok(Outcome::Stops),
        Act::Engage if !engaged => Ok(Outcome::Engages),
        Act::Engage | Act::Command | Act::Release if mine => Ok(match act {
            Act::Release => Outcome::Released,
            _ => Outcome::Same,
        }),
        Act::Engage => match commander {
            None => Ok(Outcome::Commands),
            Some(c) => Err(Refusal::Commander(c)),
        },
        // Disengaged: the gate refuses the command itself (`disengaged`).
        Act::Command if !engaged => Ok(Outcome::Same),
        Act::Command => Err(commander.map_or(Refusal::NobodyCommands, Refusal::Commander)),
        Act::Release => Err(Refusal::NotCommanding),
        Act::Take if !source.is_console() => Err(Refusal::NotAConsole),
        Act::Take if !engaged => Err(Refusal::NotEngaged),
        Act::Take if mine => Ok(Outcome::Same),
        Act::Take => Ok(Outcome::Commands),
        Act::Interlocks | Act::Tune if !source.is_console() => Err(Refusal::NotAConsole),
        Act::Interlocks | Act::Tune => match commander {
            Some(c) if c != source => Err(Refusal::Commander(c)),
            _ => Ok(Outcome::Same),
        },
    }
}

/// The guide's table (docs/safety.md) of who may do what, from [`decide`] itself.
#[cfg_attr(not(test), allow(dead_code))]
pub(crate) fn markdown() -> String {
    use std::net::{IpAddr, Ipv4Addr, SocketAddr};
    let planner = Source::Network(SocketAddr::new(IpAddr::V4(Ipv4Addr::LOCALHOST), 5555));
    let other = Source::Network(SocketAddr::new(IpAddr::V4(Ipv4Addr::LOCALHOST), 6666));
    let acts = [
        (Act::Engage, "engage"),
        (Act::Command, "a command (`steer 0.1`, `accel 0.2`…)"),
        (Act::Release, "release"),
        (Act::Take, "take (console key `A`, confirmed)"),
        (Act::Stop, "stop / disengage"),
        (
            Act::Interlocks,
            "interlocks on/off (console key `I`, confirmed)",
        ),
        (
            Act::Tune,
            "a device's delays, threads on/off, wake (console)",
        ),
    ];
    let states: [(&str, bool, Option<Source>); 4] = [
        ("disengaged", false, None),
        ("engaged, the console commands", true, Some(Source::Console)),
        ("engaged, another sender commands", true, Some(other)),
        ("engaged, released (nobody commands)", true, None),
    ];
    let cell = |r: Result<Outcome, Refusal>| match r {
        Ok(Outcome::Same) => "yes".to_string(),
        Ok(Outcome::Engages) => "yes: engages, commands".to_string(),
        Ok(Outcome::Commands) => "yes: commands from now on".to_string(),
        Ok(Outcome::Released) => "yes: nobody commands".to_string(),
        Ok(Outcome::Stops) => "yes: safe state, nobody commands".to_string(),
        Err(Refusal::Commander(c)) => format!("refused: {}", Refusal::Commander(c)),
        Err(e) => format!("refused: {e}"),
    };
    let mut out = String::from(
        "| the vehicle is | act | by a network sender or ROS 2 | by the console | by another console (attached) | by an operator (`adrive ctl`) |\n|---|---|---|---|---|---|\n",
    );
    for (state, engaged, commander) in states {
        for (act, name) in acts {
            // Ownership lets a command through to the gate, which refuses it while
            // disengaged.
            let say = |r: Result<Outcome, Refusal>| match (engaged, act, r) {
                (false, Act::Command, Ok(_)) => "refused: adrive is disengaged".to_string(),
                (_, _, r) => cell(r),
            };
            out.push_str(&format!(
                "| {state} | {name} | {} | {} | {} | {} |\n",
                say(decide(engaged, commander, planner, act)),
                say(decide(engaged, commander, Source::Console, act)),
                say(decide(engaged, commander, Source::Attached(2), act)),
                say(decide(engaged, commander, Source::Operator(1000), act)),
            ));
        }
    }
    out
}

/// Who commands and the commander's watchdog, under the gate's one intake lock.
#[derive(Debug)]
pub struct Owner {
    pub(crate) commander: Option<Source>,
    /// The commander's last admitted ask (what its watchdog watches).
    pub(crate) last: Instant,
    /// The commander's stream is alive but frozen (a rolling counter that stopped).
    pub(crate) frozen: bool,
    /// The console's deadman while it teleoperates (its watchdog); `None`: not watched.
    pub(crate) deadman: Option<Duration>,
    /// Gas held on a lease by the commander ([`super::lease`]); `None`: none.
    pub(crate) lease: Option<super::lease::Lease>,
    /// A commanding console's terminal last answered a round trip then (or it took
    /// command then): its link's watchdog ([`terminal_silent`]).
    pub(crate) answered: Instant,
    /// Released by this source; the handover ends at this instant.
    pub(crate) handover: Option<(Source, Instant)>,
    /// The watchdog tripped and the vehicle was not engaged since.
    pub(crate) tripped: bool,
    pub(crate) last_trip: Option<String>,
    /// The console that switched the interlocks off (they come back on when it goes).
    pub(crate) interlocks_off_by: Option<Source>,
    /// Asks refused because another source commands (or nobody does).
    pub(crate) refused: u64,
    pub(crate) last_refused: Option<(Source, Ask, Refusal)>,
}

impl Owner {
    pub fn new(now: Instant) -> Owner {
        Owner {
            commander: None,
            last: now,
            frozen: false,
            deadman: None,
            lease: None,
            answered: now,
            handover: None,
            tripped: false,
            last_trip: None,
            interlocks_off_by: None,
            refused: 0,
            last_refused: None,
        }
    }

    pub(crate) fn commands(&mut self, source: Source, now: Instant) {
        self.commander = Some(source);
        self.last = now;
        self.frozen = false;
        self.handover = None;
        // A deadman is the teleoperating console's own, armed by its next teleop key.
        self.deadman = None;
        self.lease = None;
        // A console's link is proved from here on.
        self.answered = now;
    }

    pub(crate) fn nobody(&mut self) {
        self.commander = None;
        self.handover = None;
        self.lease = None;
    }
}

/// The link's watchdog of a commanding console: a terminal answers a round trip by
/// itself, so while its answers come the operator sees the vehicle and can reach it.
/// How long the commanding console's terminal has not answered (measured from the
/// last answer, or from when it took command — never from a schedule of requests),
/// once that reaches `bound`; `None` while it answers, or when the commander is no
/// console.
pub(crate) fn terminal_silent(o: &Owner, bound: Duration, now: Instant) -> Option<Duration> {
    if !o.commander?.is_console() {
        return None;
    }
    let quiet = now.saturating_duration_since(o.answered);
    (quiet >= bound).then_some(quiet)
}

/// What the snapshot shows of who commands.
#[derive(Clone, Debug, Default, PartialEq)]
pub(crate) struct CommandView {
    pub commander: Option<String>,
    pub watchdog: Option<WatchdogView>,
    pub refused: u64,
    pub(crate) last_refused: Option<String>,
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::net::{Ipv4Addr, SocketAddr};

    fn net(port: u16) -> Source {
        Source::Network(SocketAddr::from((Ipv4Addr::LOCALHOST, port)))
    }

    /// The incident: the console engaged and was teleoperating; a single `adrive send
    /// steer 0.5` from another terminal took the wheel. The network never takes
    /// command from a console.
    #[test]
    fn a_network_sender_never_takes_the_consoles_vehicle() {
        let c = Some(Source::Console);
        for act in [Act::Engage, Act::Command, Act::Release, Act::Take] {
            assert!(
                decide(true, c, net(5555), act).is_err(),
                "{act:?} from the network while the console commands"
            );
        }
        assert_eq!(
            decide(true, c, net(5555), Act::Command),
            Err(Refusal::Commander(Source::Console))
        );
        assert_eq!(
            decide(true, c, Source::Console, Act::Command),
            Ok(Outcome::Same)
        );
    }

    #[test]
    fn stopping_is_never_refused() {
        for engaged in [false, true] {
            for c in [
                None,
                Some(Source::Console),
                Some(net(1)),
                Some(Source::Ros2),
            ] {
                for s in [Source::Console, net(2), Source::Ros2] {
                    assert_eq!(decide(engaged, c, s, Act::Stop), Ok(Outcome::Stops));
                }
            }
        }
    }

    #[test]
    fn command_changes_hands_only_explicitly() {
        // Released: the next to engage commands; a bare command does not take it.
        assert_eq!(
            decide(true, None, net(1), Act::Command),
            Err(Refusal::NobodyCommands)
        );
        assert_eq!(
            decide(true, None, net(1), Act::Engage),
            Ok(Outcome::Commands)
        );
        // One network sender never takes from another.
        assert_eq!(
            decide(true, Some(net(1)), net(2), Act::Engage),
            Err(Refusal::Commander(net(1)))
        );
        // The console takes, with its key.
        assert_eq!(
            decide(true, Some(net(1)), Source::Console, Act::Take),
            Ok(Outcome::Commands)
        );
        assert_eq!(
            decide(true, Some(Source::Console), net(1), Act::Take),
            Err(Refusal::NotAConsole)
        );
        assert_eq!(
            decide(true, Some(net(1)), net(1), Act::Release),
            Ok(Outcome::Released)
        );
        assert_eq!(
            decide(true, Some(net(1)), net(2), Act::Release),
            Err(Refusal::NotCommanding)
        );
    }

    #[test]
    fn the_guide_shows_who_commands() {
        let readme = include_str!("../../docs/safety.md");
        let table = markdown();
        if let Some(path) = std::env::var_os("ADRIVE_PRINT_OWNER_TABLE") {
            std::fs::write(path, &table).unwrap();
        }
        assert!(
            readme.contains(&table),
            "docs/safety.md must contain, verbatim, the table of who commands:\n{table}"
        );
    }

    /// A console's link is measured from its last answer: a slow but live terminal
    /// keeps command however late each answer is within the bound; silence past it
    /// does not; a network commander has no terminal.
    #[test]
    fn a_commanding_consoles_terminal_must_keep_answering() {
        let t = Instant::now();
        let bound = Duration::from_millis(1000);
        let mut o = Owner::new(t);
        o.commands(Source::Attached(1), t);
        assert_eq!(terminal_silent(&o, bound, t + bound / 2), None);
        for i in 1..=200u32 {
            // Answers 300 ms apart: late, but live.
            o.answered = t + Duration::from_millis(300) * i;
            let now = o.answered + Duration::from_millis(299);
            assert_eq!(terminal_silent(&o, bound, now), None);
        }
        let last = o.answered;
        assert_eq!(
            terminal_silent(&o, bound, last + bound),
            Some(bound),
            "silent for the bound"
        );
        o.commands(net(1), last + bound);
        assert_eq!(terminal_silent(&o, bound, last + bound * 5), None);
        o.nobody();
        assert_eq!(terminal_silent(&o, bound, last + bound * 5), None);
    }

    #[test]
    fn interlocks_switch_only_from_a_console_that_may_command() {
        assert_eq!(
            decide(false, None, Source::Console, Act::Interlocks),
            Ok(Outcome::Same)
        );
        assert_eq!(
            decide(true, Some(net(1)), Source::Console, Act::Interlocks),
            Err(Refusal::Commander(net(1)))
        );
        assert_eq!(
            decide(false, None, net(1), Act::Interlocks),
            Err(Refusal::NotAConsole)
        );
    }
}
