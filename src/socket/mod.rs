//! The control socket: consoles that come and go on an engine that keeps running.
//!
//! Every adrive that runs an engine (the console, `--sim`, `--headless`, the service)
//! listens on a local Unix socket ([`path`]: where, and how it is claimed and given
//! back). Over it ([`proto`]: the messages) an attached console — `adrive attach`, the
//! same Sparrow console as the embedded one — gets the frames the embedded console
//! draws and sends the operator's operations; an operator's one-shot command (`adrive
//! ctl status|engage|stop|disengage|release`) does one thing and goes. Remote users
//! reach it over SSH like everything else on the vehicle, or, on a vehicle in a fleet,
//! over a link the fleet carries to it (`fleet::serve`, through [`server::Door`]).
//!
//! An attached console is one more source to the intake ([`Source::Attached`]): it
//! starts watching, engages when nobody commands, takes command under the ownership
//! rules, and when it goes away while it commands, that is its watchdog. [`server`]
//! serves the socket; [`client`] is the other end.
//!
//! [`Source::Attached`]: crate::value::Source::Attached

pub(crate) mod client;
pub(crate) mod path;
pub mod proto;
pub(crate) mod server;

pub use server::Server;
