//! The one control interface below the consoles: what a console reads from and does to
//! a running vehicle, whichever console it is and wherever the vehicle runs.
//!
//! [`Controls`] is a console's only door to the vehicle. It has three parts:
//!
//! - **scenes** ([`scene`]): what to draw, captured at one instant;
//! - **asks** ([`Ask`]): everything that goes through the one intake — a command,
//!   engage, STOP, taking command — answered with [`Done`] or [`Refused`];
//! - **tuning** ([`Tune`]): a device's settings and threads, as the bench changes them,
//!   checked as the vehicle file is.
//!
//! Each operation a console uses is written once, here, over those three; an
//! implementation supplies only the ways there: [`Live`] over the engine in this
//! process (the embedded console, and the control socket's server for each attached
//! console), the attach client's `Remote` over the control socket
//! ([`crate::socket::client`]), the console's replay (read-only), and the recording
//! fake of the console's tests. The console's `update` takes a `&dyn Controls`, so it
//! is tested with no threads.

pub(crate) mod live;
pub(crate) mod scene;

pub use live::Live;
pub use scene::{capture, secs, Scene, SimFaults, Sources};

pub use crate::characterize::background::{Characterizing, Headline};
pub use crate::characterize::Deadband;
use crate::characterize::Procedure;
pub use crate::characterize::{Progress, Stage};
use crate::safety::{Ask, Done, Held, Refused};
use crate::value::{Command, DeviceId};
use std::path::Path;
use std::time::{Duration, Instant};

/// Why an attached console may not characterize: the run needs the engine's process.
pub(crate) const CHARACTERIZE_WHERE: &str = "characterize runs where the vehicle's engine \
runs: use `adrive characterize` on that host (or the console it runs with)";

/// How often a console draws a frame, and the control socket sends one to each
/// attached console.
pub(crate) const TICK: Duration = Duration::from_millis(100);

/// Which thread of a device.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Thread {
    Status,
    Command,
}

/// A change of one device's settings or threads, from the bench. Only a console may
/// tune, when it commands or nobody does; a value the vehicle file would refuse is
/// refused, with the reason.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Tune {
    StatusPeriod(DeviceId, Duration),
    CommandTimeout(DeviceId, Duration),
    /// Switch a thread on or off.
    Enabled(DeviceId, Thread, bool),
    /// Wake a command thread (it resends its last command).
    Wake(DeviceId),
}

/// What a console can do to the vehicle. An implementation gives the ways there (a
/// scene, a command read from text, an ask through the intake, a tuning, the
/// interlocks' switch, the deadman, the simulator, the liveness check's answers); every
/// other operation is written once below, over them.
pub trait Controls {
    /// Capture what to draw; `bench` gets its histogram and trace filled in.
    fn scene(&self, now: Instant, bench: Option<DeviceId>) -> Scene;
    /// Read a device's command from text, as the vehicle file defines it (a number in
    /// range, a state or an alias).
    fn parse(&self, id: DeviceId, text: &str) -> Result<Command, String>;
    /// Through the one intake, as this console: what it did, or why not. `Err` also
    /// when it could not be asked (an attached console whose adrive did not answer).
    fn ask(&self, ask: Ask) -> Result<Done, Refused>;
    /// Change a device's settings or threads; refused, with the reason, for a console
    /// that may not tune, or a value the vehicle file would refuse.
    fn tune(&self, tune: Tune) -> Result<(), String>;
    fn set_interlocks(&self, on: bool) -> Result<(), Refused>;
    /// Arm (and feed: a teleop key) or disarm the teleop deadman, the console's
    /// watchdog.
    fn deadman(&self, armed: Option<Duration>);
    /// One line of the simulator's command language ([`crate::sim::Sim::apply`]), e.g.
    /// `silent gas on`, `stall`, `estop pause`; `None` when the devices are not
    /// simulated in the adrive it runs on.
    fn sim(&self, line: &str) -> Option<Result<String, String>>;
    /// The console's terminal answered a round trip of its liveness check, read at
    /// `at`: a proof that the operator still sees the vehicle
    /// ([`crate::engine::Gate::answered`]), and the characterization it started.
    fn answered(&self, at: Instant);
    /// Whether device `id` may be characterized now: what proved the vehicle still
    /// (`stopped, in park, the brake held`), or why not
    /// ([`crate::characterize::background::check`]).
    fn characterize_check(&self, id: DeviceId) -> Result<String, String>;
    /// Characterize device `id` (`adrive characterize`'s procedures) into directory
    /// `out`, in the process that runs the engine, on a thread of its own: refused,
    /// with the reason, where it cannot run or the check refuses.
    fn characterize(
        &self,
        id: DeviceId,
        procedures: &[Procedure],
        out: &Path,
    ) -> Result<(), String>;
    /// Where this console's characterization stands, or how its last one ended.
    fn characterizing(&self) -> Option<Characterizing>;
    /// End this console's characterization at once — the runner disengages, the safe
    /// state — saying why (`the operator left the bench view`).
    fn characterize_end(&self, why: &str);

    /// A command through the one intake, as the console's.
    fn submit(&self, id: DeviceId, command: Command) -> Result<(), Refused> {
        self.ask(Ask::Set(id, command)).map(drop)
    }
    fn submit_accel(&self, accel: f64) -> Result<(), Refused> {
        self.ask(Ask::Accel(accel)).map(drop)
    }
    /// The accel while a key is held ([`Ask::Held`]): gas lasts `lease` from now
    /// unless renewed, then the engine commands `release` (never gas) on its own.
    fn submit_held(&self, accel: f64, lease: Duration, release: f64) -> Result<(), Refused> {
        self.ask(Ask::Held(Held {
            accel,
            lease,
            release,
        }))
        .map(drop)
    }
    /// The key is still held: the running lease lasts `lease` from now. `Ok(false)`
    /// when it had run out (the engine ended the gas; only a new press gives it again).
    fn renew(&self, lease: Duration) -> Result<bool, Refused> {
        self.ask(Ask::Renew(lease)).map(|d| d == Done::Commanded)
    }
    /// Engage, as the console: what it did ([`Done`]'s words are the answer every
    /// front end gives).
    fn engage(&self) -> Result<Done, Refused> {
        self.ask(Ask::Engage)
    }
    /// Disengage: what it did. Never refused by the intake.
    fn disengage(&self) -> Result<Done, Refused> {
        self.ask(Ask::Disengage)
    }
    /// The operator's STOP: disengage, throttle 0, brake full — even while a driver
    /// has taken over ([`crate::engine::Gate::stop`]). Never refused by the intake.
    fn stop(&self) -> Result<(), Refused> {
        self.ask(Ask::Stop).map(drop)
    }
    /// Take command from whoever commands the engaged vehicle (after the operator's
    /// confirmation).
    fn take(&self) -> Result<(), Refused> {
        self.ask(Ask::Take).map(drop)
    }
    /// Give command up (the vehicle stays engaged for the handover).
    fn release(&self) -> Result<(), Refused> {
        self.ask(Ask::Release).map(drop)
    }
    /// Hold: the safe state (throttle 0, brake full), staying engaged — when the
    /// console commands.
    fn hold(&self) -> Result<(), Refused> {
        self.ask(Ask::Hold).map(drop)
    }
    /// Clear the latched driver overrides (as the network's `clear`): what was
    /// cleared, or why not (the driver's hand still on).
    fn clear_overrides(&self) -> Result<Vec<String>, Refused> {
        match self.ask(Ask::Clear)? {
            Done::Cleared(c) => Ok(c),
            _ => Ok(Vec::new()),
        }
    }
    /// Refused, with the reason, when the vehicle file would refuse the value.
    fn set_status_period(&self, id: DeviceId, d: Duration) -> Result<(), String> {
        self.tune(Tune::StatusPeriod(id, d))
    }
    /// Refused, with the reason, when the vehicle file would refuse the value.
    fn set_command_timeout(&self, id: DeviceId, d: Duration) -> Result<(), String> {
        self.tune(Tune::CommandTimeout(id, d))
    }
    /// Switch a thread on or off; refused, with the reason, for a console that does
    /// not command.
    fn set_enabled(&self, id: DeviceId, thread: Thread, on: bool) -> Result<(), String> {
        self.tune(Tune::Enabled(id, thread, on))
    }
    /// Wake a command thread; refused, with the reason, for a console that does not
    /// command.
    fn wake(&self, id: DeviceId) -> Result<(), String> {
        self.tune(Tune::Wake(id))
    }
}
