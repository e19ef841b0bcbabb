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
//! commands and the commander's watchdog, its state private behind its decisions —
//! [`Owner::decide`] for an act, [`Owner::expired`] for the bound that ran out (a
//! network sender's silence, a console's deadman or terminal, a handover), named as a
//! [`Trip`], and [`Owner::lease_turn`] for held gas; the engine's intake
//! ([`crate::engine::Gate::admit`]) applies the decision under the one lock around
//! `Owner`, so that no command slips between a decision and a change of hands. The guide's table (docs/safety.md) of these rules is
//! [`markdown`], checked by a test.

use super::ask::Ask;
use crate::snapshot::{TripKind, WatchdogState, WatchdogView};
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
            Source::Fleet => f.write_str("fleet operator (adrive ctl --vehicle)"),
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

/// The bounds of the commander's watchdog, from the vehicle file.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) struct Bounds {
    /// A network sender's or ROS 2's watchdog (`[network] watchdog_timeout`), and the
    /// handover after a release.
    pub watchdog: Duration,
    /// A commanding console's terminal must answer within this (`[console]
    /// terminal_timeout`).
    pub terminal: Duration,
}

/// Why the commander's watchdog tripped: the cause as a type, its words in [`Display`].
///
/// [`Display`]: std::fmt::Display
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Trip {
    /// A commanding console's terminal stopped answering round trips for `quiet`.
    Terminal { commander: Source, quiet: Duration },
    /// A teleoperating console sent no teleop key for its deadman's `bound`.
    Deadman { bound: Duration },
    /// The commander's rolling counter stopped advancing for `quiet`.
    Frozen { commander: Source, quiet: Duration },
    /// No valid command from the commander for `quiet`.
    Silent { commander: Source, quiet: Duration },
    /// Released by `from`, and nobody took command within the handover.
    Handover { from: Source },
    /// The commander went away for good; `how` is what it did, in words
    /// (`went away (its connection closed)`).
    Gone { commander: Source, how: String },
}

impl std::fmt::Display for Trip {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Trip::Terminal { commander, quiet } => write!(
                f,
                "{}: its terminal stopped answering for {:.1} s",
                Commander(*commander),
                quiet.as_secs_f64()
            ),
            Trip::Deadman { bound } => {
                write!(f, "deadman: no teleop key for {:.1}s", bound.as_secs_f64())
            }
            Trip::Frozen { commander, quiet } => write!(
                f,
                "the rolling counter of {} stopped advancing for {} ms",
                Commander(*commander),
                quiet.as_millis()
            ),
            Trip::Silent { commander, quiet } => write!(
                f,
                "no valid command from {} for {} ms",
                Commander(*commander),
                quiet.as_millis()
            ),
            Trip::Handover { from } => {
                write!(
                    f,
                    "released by {} and nobody took command",
                    Commander(*from)
                )
            }
            Trip::Gone { commander, how } => write!(f, "{} {how}", Commander(*commander)),
        }
    }
}

impl Trip {
    /// The cause without its particulars, for the snapshot.
    pub fn kind(&self) -> TripKind {
        match self {
            Trip::Terminal { .. } => TripKind::Terminal,
            Trip::Deadman { .. } => TripKind::Deadman,
            Trip::Frozen { .. } => TripKind::Frozen,
            Trip::Silent { .. } => TripKind::Silent,
            Trip::Handover { .. } => TripKind::Handover,
            Trip::Gone { .. } => TripKind::Gone,
        }
    }
}

/// What a source going away does ([`Owner::gone`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) struct Gone {
    /// It had switched the interlocks off: they come back on.
    pub interlocks_on: bool,
    /// It commanded the engaged vehicle: its watchdog trips.
    pub trips: bool,
}

/// What the monitor's turn does to a held pedal's lease ([`Owner::lease_turn`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) enum LeaseTurn {
    /// No lease, or one still running: nothing.
    Nothing,
    /// Its holder no longer commands the engaged vehicle: dropped, nothing commanded
    /// (the stop that ended its command commanded the safe state).
    Dropped,
    /// It ran out: ended; the gas goes to its release level.
    Ended(super::lease::Lease),
}

/// Who commands and the commander's watchdog, under the gate's one intake lock. Its
/// state is its own: the engine asks it to decide ([`Owner::decide`],
/// [`Owner::expired`], [`Owner::lease_turn`]) and tells it what happened; it never
/// writes a field.
#[derive(Debug)]
pub struct Owner {
    commander: Option<Source>,
    /// The commander's last admitted ask (what its watchdog watches).
    last: Instant,
    /// The commander's stream is alive but frozen (a rolling counter that stopped).
    frozen: bool,
    /// The console's deadman while it teleoperates (its watchdog); `None`: not watched.
    deadman: Option<Duration>,
    /// Gas held on a lease by the commander ([`super::lease`]); `None`: none.
    lease: Option<super::lease::Lease>,
    /// A commanding console's terminal last answered a round trip then (or it took
    /// command then): its link's watchdog ([`terminal_silent`]).
    answered: Instant,
    /// Released by this source; the handover ends at this instant.
    handover: Option<(Source, Instant)>,
    /// The watchdog tripped and the vehicle was not engaged since.
    tripped: bool,
    last_trip: Option<Trip>,
    /// The console that switched the interlocks off (they come back on when it goes).
    interlocks_off_by: Option<Source>,
    /// Asks refused because another source commands (or nobody does).
    refused: u64,
    last_refused: Option<(Source, Ask, Refusal)>,
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

    /// Who commands the vehicle, when it is `engaged` (nobody otherwise).
    pub(crate) fn commander(&self, engaged: bool) -> Option<Source> {
        self.commander.filter(|_| engaged)
    }

    /// `source` is the one that commands (engaged or not: the caller knows).
    pub(crate) fn is(&self, source: Source) -> bool {
        self.commander == Some(source)
    }

    /// The ownership rule ([`decide`]) over who commands now.
    pub(crate) fn decide(
        &self,
        engaged: bool,
        source: Source,
        act: Act,
    ) -> Result<Outcome, Refusal> {
        decide(engaged, self.commander, source, act)
    }

    /// An ask of `source` was refused by ownership: counted, the last one kept.
    pub(crate) fn refuse(&mut self, source: Source, ask: Ask, why: Refusal) {
        self.refused += 1;
        self.last_refused = Some((source, ask, why));
    }

    /// `source` commands from `now` (engaged, took command, or picked it up after a
    /// release). Returns who commanded before, or released it: the one it took from.
    pub(crate) fn commands(&mut self, source: Source, now: Instant) -> Option<Source> {
        let from = self.commander.or(self.handover.map(|(s, _)| s));
        self.commander = Some(source);
        self.last = now;
        self.frozen = false;
        self.handover = None;
        // A deadman is the teleoperating console's own, armed by its next teleop key.
        self.deadman = None;
        self.lease = None;
        // A console's link is proved from here on.
        self.answered = now;
        from
    }

    /// `source` engaged the vehicle at `now` and commands it: the last trip is over.
    pub(crate) fn engages(&mut self, source: Source, now: Instant) {
        self.commands(source, now);
        self.tripped = false;
    }

    /// `source` released command at `now`: nobody commands; the handover ends after
    /// `handover`.
    pub(crate) fn releases(&mut self, source: Source, now: Instant, handover: Duration) {
        self.nobody();
        self.handover = Some((source, now + handover));
    }

    /// Nobody commands (stopped, disengaged, or the vehicle is not engaged).
    pub(crate) fn nobody(&mut self) {
        self.commander = None;
        self.handover = None;
        self.lease = None;
    }

    /// The commander did something admitted at `at`: a sign of life for its watchdog.
    pub(crate) fn alive(&mut self, at: Instant) {
        self.last = self.last.max(at);
        self.frozen = false;
    }

    /// `source`'s stream is alive but frozen; only the commander's counts.
    pub(crate) fn freeze(&mut self, source: Source) {
        if self.is(source) {
            self.frozen = true;
        }
    }

    /// Arm or disarm the commanding console's deadman (arming feeds it); any other
    /// source has none.
    pub(crate) fn deadman(&mut self, source: Source, armed: Option<Duration>, now: Instant) {
        if source.is_console() && self.is(source) {
            self.deadman = armed;
            self.last = now;
        }
    }

    /// A console's terminal answered at `at`: only the commanding console's feeds its
    /// link's watchdog.
    pub(crate) fn answered(&mut self, source: Source, at: Instant) {
        if source.is_console() && self.is(source) {
            self.answered = self.answered.max(at);
        }
    }

    /// `source` switched the interlocks `on` (or off: it is remembered, they come back
    /// on when it goes).
    pub(crate) fn interlocks(&mut self, source: Source, on: bool) {
        self.interlocks_off_by = (!on).then_some(source);
    }

    /// `source` went away for good, the vehicle `engaged` or not: what that does.
    pub(crate) fn gone(&mut self, source: Source, engaged: bool) -> Gone {
        let interlocks_on = self.interlocks_off_by == Some(source);
        if interlocks_on {
            self.interlocks_off_by = None;
        }
        Gone {
            interlocks_on,
            trips: engaged && self.is(source),
        }
    }

    /// The watchdog's timeout of `source` as commander (`None`: not watched): the
    /// network's for a network sender or ROS 2, the deadman for a console while it
    /// teleoperates, none for an operator's one-shot `engage`.
    pub(crate) fn timeout(&self, source: Source, bounds: Bounds) -> Option<Duration> {
        match source {
            // A bench procedure commands on its own, as a planner does.
            Source::Network(_) | Source::Ros2 | Source::Bench => Some(bounds.watchdog),
            Source::Console | Source::Attached(_) => self.deadman,
            // An operator's one-shot `engage` moves nothing: it holds the vehicle as a
            // console does outside teleop, until it is released, stopped or taken.
            Source::Operator(_) | Source::Fleet | Source::Supervisor => None,
        }
    }

    /// Which bound ran out at `now` on the engaged vehicle, if one did: a commanding
    /// console's terminal silent, a commander quiet for its timeout (deadman, frozen
    /// counter, silence), a handover nobody picked up. Pure: the caller trips.
    pub(crate) fn expired(&self, now: Instant, bounds: Bounds) -> Option<Trip> {
        if let Some(quiet) = terminal_silent(self, bounds.terminal, now) {
            return Some(Trip::Terminal {
                commander: self.commander?,
                quiet,
            });
        }
        match (self.commander, self.handover) {
            (Some(c), _) => {
                let t = self.timeout(c, bounds)?;
                let quiet = now.saturating_duration_since(self.last);
                if quiet < t {
                    return None;
                }
                Some(match c {
                    Source::Console | Source::Attached(_) => Trip::Deadman { bound: t },
                    _ if self.frozen => Trip::Frozen {
                        commander: c,
                        quiet,
                    },
                    _ => Trip::Silent {
                        commander: c,
                        quiet,
                    },
                })
            }
            (None, Some((from, end))) if now >= end => Some(Trip::Handover { from }),
            _ => None,
        }
    }

    /// The watchdog tripped for `cause`: nobody commands, no deadman, and the cause
    /// kept for the snapshot.
    pub(crate) fn trip(&mut self, cause: Trip) {
        self.nobody();
        self.deadman = None;
        self.tripped = true;
        self.last_trip = Some(cause);
    }

    /// Gas on `lease` (or none) from now on: a held key granted, or any other pedal
    /// command, a hold or a stop that ends it.
    pub(crate) fn lease(&mut self, lease: Option<super::lease::Lease>) {
        self.lease = lease;
    }

    /// `source` renews its running lease at `now` for `length`: whether it was.
    pub(crate) fn renew(&mut self, source: Source, now: Instant, length: Duration) -> bool {
        self.lease
            .as_mut()
            .is_some_and(|l| l.renew(source, now, length))
    }

    /// The monitor's turn of the lease at `now`, the vehicle `engaged` or not: a lease
    /// whose holder no longer commands is dropped, one that ran out ends.
    pub(crate) fn lease_turn(&mut self, engaged: bool, now: Instant) -> LeaseTurn {
        let Some(lease) = self.lease else {
            return LeaseTurn::Nothing;
        };
        if !engaged || !self.is(lease.source) {
            self.lease = None;
            return LeaseTurn::Dropped;
        }
        if lease.runs(now) {
            return LeaseTurn::Nothing;
        }
        self.lease = None;
        LeaseTurn::Ended(lease)
    }

    /// The watchdog's state on a vehicle `engaged` or not, its commander watched for
    /// `timeout` (`None`: not watched).
    pub(crate) fn watchdog_state(&self, engaged: bool, timeout: Option<Duration>) -> WatchdogState {
        match (engaged, timeout) {
            (false, _) if self.tripped => WatchdogState::Tripped,
            (false, _) => WatchdogState::Off,
            (true, Some(_)) => WatchdogState::Armed,
            (true, None) => WatchdogState::Idle,
        }
    }

    /// How long the commander has been quiet at `now`.
    pub(crate) fn quiet(&self, now: Instant) -> Duration {
        now.saturating_duration_since(self.last)
    }

    /// Why the watchdog last tripped.
    pub(crate) fn last_trip(&self) -> Option<&Trip> {
        self.last_trip.as_ref()
    }

    /// Asks refused by ownership, and the last one: who, what, why.
    pub(crate) fn refused(&self) -> (u64, Option<(Source, Ask, Refusal)>) {
        (self.refused, self.last_refused)
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
        crate::testkit::assert_guide_holds("docs/safety.md", readme, "who commands", &table);
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

    const BOUNDS: Bounds = Bounds {
        watchdog: Duration::from_millis(500),
        terminal: Duration::from_millis(1000),
    };

    /// Each bound names its cause the instant it runs out, and not a moment before:
    /// a network commander's silence (or its frozen counter), a console's deadman
    /// once armed, its terminal's silence, a handover nobody picked up.
    #[test]
    fn expired_names_the_bound_that_ran_out_at_its_instant() {
        let t = Instant::now();
        let ms = Duration::from_millis;
        let mut o = Owner::new(t);
        assert_eq!(o.expired(t + ms(10_000), BOUNDS), None, "nobody commands");
        o.engages(net(1), t);
        assert_eq!(o.expired(t + ms(499), BOUNDS), None);
        let silent = Trip::Silent {
            commander: net(1),
            quiet: ms(500),
        };
        assert_eq!(o.expired(t + ms(500), BOUNDS), Some(silent));
        o.alive(t + ms(400));
        assert_eq!(o.expired(t + ms(899), BOUNDS), None, "fed");
        o.freeze(net(2));
        assert!(matches!(
            o.expired(t + ms(900), BOUNDS),
            Some(Trip::Silent { .. })
        ));
        o.freeze(net(1));
        assert_eq!(
            o.expired(t + ms(900), BOUNDS),
            Some(Trip::Frozen {
                commander: net(1),
                quiet: ms(500)
            })
        );
        o.alive(t + ms(900));
        assert!(matches!(
            o.expired(t + ms(1400), BOUNDS),
            Some(Trip::Silent { .. })
        ));
        // A console: no deadman until armed; its terminal's silence regardless.
        o.commands(Source::Console, t);
        o.answered(Source::Console, t + ms(5000));
        assert_eq!(o.expired(t + ms(5999), BOUNDS), None, "not teleoperating");
        assert_eq!(
            o.expired(t + ms(6000), BOUNDS),
            Some(Trip::Terminal {
                commander: Source::Console,
                quiet: ms(1000)
            })
        );
        o.deadman(Source::Console, Some(ms(300)), t + ms(5000));
        assert_eq!(o.expired(t + ms(5299), BOUNDS), None);
        assert_eq!(
            o.expired(t + ms(5300), BOUNDS),
            Some(Trip::Deadman { bound: ms(300) })
        );
        o.deadman(Source::Attached(1), None, t + ms(5300));
        assert!(o.expired(t + ms(5300), BOUNDS).is_some(), "not its deadman");
        // A release nobody picks up.
        o.releases(Source::Console, t + ms(5000), BOUNDS.watchdog);
        assert_eq!(o.expired(t + ms(5499), BOUNDS), None);
        assert_eq!(
            o.expired(t + ms(5500), BOUNDS),
            Some(Trip::Handover {
                from: Source::Console
            })
        );
        assert_eq!(o.commands(net(3), t + ms(5400)), Some(Source::Console));
        assert_eq!(o.expired(t + ms(5500), BOUNDS), None, "picked up");
        // An operator's one-shot engage is not watched.
        o.commands(Source::Operator(1000), t);
        assert_eq!(o.expired(t + ms(60_000), BOUNDS), None);
    }

    /// A trip leaves nobody commanding and no deadman armed, keeps its cause, and the
    /// watchdog shows tripped until the next engage.
    #[test]
    fn a_trip_is_kept_until_the_next_engage() {
        let t = Instant::now();
        let mut o = Owner::new(t);
        let d = Some(Duration::from_millis(100));
        assert_eq!(o.watchdog_state(false, None), WatchdogState::Off);
        o.engages(Source::Console, t);
        o.deadman(Source::Console, d, t);
        assert_eq!(o.timeout(Source::Console, BOUNDS), d);
        assert_eq!(o.watchdog_state(true, d), WatchdogState::Armed);
        assert_eq!(o.watchdog_state(true, None), WatchdogState::Idle);
        let cause = Trip::Deadman {
            bound: Duration::from_millis(100),
        };
        o.trip(cause.clone());
        assert_eq!(o.commander(true), None);
        assert_eq!(o.timeout(Source::Console, BOUNDS), None);
        assert_eq!(o.last_trip(), Some(&cause));
        assert_eq!(o.watchdog_state(false, None), WatchdogState::Tripped);
        o.commands(Source::Console, t);
        assert_eq!(o.watchdog_state(false, None), WatchdogState::Tripped);
        o.engages(Source::Console, t);
        assert_eq!(o.watchdog_state(false, None), WatchdogState::Off);
        assert_eq!(o.timeout(net(1), BOUNDS), Some(BOUNDS.watchdog));
        assert_eq!(o.timeout(Source::Ros2, BOUNDS), Some(BOUNDS.watchdog));
    }

    /// Going away: the interlocks come back on only for the console that switched
    /// them off; the watchdog trips only for the commander of the engaged vehicle.
    #[test]
    fn going_away_restores_ones_own_interlocks_and_trips_only_the_commander() {
        let t = Instant::now();
        let (a, b) = (Source::Attached(1), Source::Attached(2));
        let mut o = Owner::new(t);
        o.engages(a, t);
        o.interlocks(a, false);
        let nothing = Gone {
            interlocks_on: false,
            trips: false,
        };
        assert_eq!(o.gone(b, true), nothing);
        assert_eq!(
            o.gone(a, false),
            Gone {
                interlocks_on: true,
                trips: false
            }
        );
        assert_eq!(o.gone(a, false), nothing, "switched on once");
        o.interlocks(a, true);
        assert_eq!(
            o.gone(a, true),
            Gone {
                interlocks_on: false,
                trips: true
            }
        );
    }

    /// The lease's turn: running, nothing; its holder no longer commanding or the
    /// vehicle disengaged, dropped; run out, ended once.
    #[test]
    fn a_lease_ends_once_when_it_runs_out_and_drops_with_its_holder() {
        use super::super::lease::Lease;
        let t = Instant::now();
        let ms = Duration::from_millis;
        let mut o = Owner::new(t);
        assert_eq!(o.lease_turn(true, t), LeaseTurn::Nothing);
        o.engages(Source::Console, t);
        let l = Lease::new(Source::Console, t, ms(60), -0.3);
        o.lease(Some(l));
        assert_eq!(o.lease_turn(true, t + ms(59)), LeaseTurn::Nothing);
        assert!(o.renew(Source::Console, t + ms(50), ms(60)));
        assert!(!o.renew(Source::Attached(1), t + ms(50), ms(60)));
        assert_eq!(o.lease_turn(true, t + ms(109)), LeaseTurn::Nothing);
        let ended = Lease {
            until: t + ms(110),
            ..l
        };
        assert_eq!(o.lease_turn(true, t + ms(110)), LeaseTurn::Ended(ended));
        assert_eq!(o.lease_turn(true, t + ms(200)), LeaseTurn::Nothing);
        assert!(!o.renew(Source::Console, t + ms(200), ms(60)));
        o.lease(Some(l));
        assert_eq!(o.lease_turn(false, t), LeaseTurn::Dropped);
        o.lease(Some(l));
        o.commands(net(1), t);
        assert_eq!(
            o.lease_turn(true, t),
            LeaseTurn::Nothing,
            "a change of hands drops it"
        );
        o.lease(Some(l));
        assert_eq!(o.lease_turn(true, t), LeaseTurn::Dropped);
    }

    /// Refusals are counted and the last kept; a sign of life only moves forward.
    #[test]
    fn refusals_are_counted_and_the_last_kept() {
        let t = Instant::now();
        let mut o = Owner::new(t);
        o.refuse(net(1), Ask::Engage, Refusal::NotEngaged);
        o.refuse(net(2), Ask::Release, Refusal::NotCommanding);
        assert_eq!(
            o.refused(),
            (2, Some((net(2), Ask::Release, Refusal::NotCommanding)))
        );
        o.engages(net(1), t + Duration::from_secs(1));
        o.alive(t);
        assert_eq!(o.quiet(t + Duration::from_secs(1)), Duration::ZERO);
        // Quiet since its last sign of life (the engage), not since the stale one.
        assert_eq!(o.quiet(t + Duration::from_secs(3)), Duration::from_secs(2));
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
