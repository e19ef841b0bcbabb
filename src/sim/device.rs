//! The device side of a simulated serial device: a [`Responder`] speaks one wire
//! protocol and turns requests into replies; a [`Plant`] is the piece of the simulated
//! vehicle behind it. The simulator's port loop (in [`crate::sim`]) owns the
//! pseudo-terminal, holds each reply for its wire time and serves one transaction at a
//! time, so a responder is pure protocol.

use crate::value::{Command, Reading};
use std::time::Duration;

/// What a simulated device can be asked and told, in adrive's value domain.
pub(crate) trait Plant {
    /// The device's current state.
    fn reading(&mut self) -> Reading;
    /// Apply a command; `Err` is the device's refusal, in words.
    fn command(&mut self, command: Command) -> Result<(), String>;
}

/// One answer from a responder.
#[derive(Debug, Default, PartialEq)]
pub(crate) struct Reply {
    /// Bytes of the input that made up this request (and are now done with).
    pub(crate) consumed: usize,
    /// Bytes to send back; empty for no reply (e.g. a broadcast, or a frame ignored).
    pub bytes: Vec<u8>,
    /// Extra processing time on top of the protocol's turnaround (e.g. an ELM327's
    /// slow reset).
    pub extra: Duration,
}

/// A device protocol, device side.
pub(crate) trait Responder: Send {
    /// Look at the bytes received so far. `None`: no complete request yet, wait for
    /// more. `Some(reply)`: one request was handled.
    fn respond(&mut self, input: &[u8], plant: &mut dyn Plant) -> Option<Reply>;
}
