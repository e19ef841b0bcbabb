//! The network side of the engine: the command protocol planners and people speak to
//! adrive over UDP ([`proto`]) and the shared-key authentication that can guard it
//! ([`auth`]). These are pure functions on bytes; the listener thread that owns the
//! socket, the engage gate and the watchdog build on them.

pub mod auth;
#[doc(hidden)]
pub mod fuzzing;
pub mod proto;
