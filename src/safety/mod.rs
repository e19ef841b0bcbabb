//! Safety, in one place: the rules every command must pass, the gate's state and its
//! decisions. The rules themselves are pure functions — [`rules::check`] at intake
//! ([`gate_state::decide`] for one device, [`gate_state::decide_accel`] for `accel`, whose plan is
//! [`accel`]'s), [`wire::verdict`] right before a command goes out, [`gate_state::blockers`] for engaging
//! and the monitor, [`safe::state`] for the safe state and [`safe::manual`] for it while
//! a driver has taken over, [`owner::decide`] for who commands, [`bench::ready`] for a
//! bench procedure moving a device on its own, [`lease`] for gas that
//! lasts only while its key is held — and act on roles bound in the vehicle file, never
//! on device names.
//!
//! A driver's override is not a failure: the vehicle goes to the manual state (nothing
//! braking against the driver), the override is latched, and engaging is refused until
//! it is cleared with the driver's hands off.
//!
//! [`GateState`] is the gate's state over the [`crate::vehicle::Vehicle`]: engaged or not
//! (and why), who commands, the latched overrides, what was refused. Nothing here moves
//! the vehicle: the engine ([`crate::engine::Gate`]) applies these decisions to the
//! devices' slots and ports. The vehicle itself holds state and no policy.

pub(crate) mod accel;
pub(crate) mod ask;
pub(crate) mod bench;
pub(crate) mod facts;
pub(crate) mod gate_state;
pub(crate) mod lease;
pub mod owner;
pub mod rules;
pub(crate) mod safe;
pub(crate) mod wire;

pub use ask::{Ask, Done, Held, Refused};
pub use gate_state::{GateState, Seen};
pub use rules::{Facts, Plays, Reject, Rules};
pub use wire::{Verdict, Wait};
