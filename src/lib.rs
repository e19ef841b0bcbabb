//! adrive: an operator console with an embedded drive-by-wire actuator engine.
//!
//! The crate reads like the design, from the bottom up: [`value`] is what devices
//! speak, [`config`] describes a vehicle — devices by name and kind, and the safety
//! roles bound to them — [`can`] is CAN frames and the DBC files that give them
//! meaning, and [`driver`] speaks each protocol; [`port`] is what carries one device's
//! bytes and commands (its port, command slot and trace). [`snapshot`] is the one
//! state type every reader shares; [`vehicle`] holds the devices and their cached
//! state; [`safety`] holds every rule and the engage gate; [`engine`] runs two threads
//! per actuator; [`supervisor`] names faults and recovers; [`net`] takes commands and
//! broadcasts state over UDP; `ros2` (cargo feature `ros2`) speaks ROS 2 and
//! Autoware over Zenoh through the same intake; `fleet` (cargo feature `fleet`) puts
//! many vehicles on one Zenoh network, each watchable from anywhere on it; [`socket`] lets consoles attach to a
//! running engine and operators command it once; [`sim`] emulates the devices on real
//! pseudo-terminals; [`record`] keeps a run in an MCAP file, and [`foxglove`] serves it
//! live to Foxglove and Lichtblick; [`console`] is the operator's screen (and replays
//! recordings), and [`controls`] the one interface it and attached consoles reach the
//! vehicle through; [`port_list`] lists the serial ports (`adrive ports`) and [`cli`] puts
//! it all together; [`service`] tells systemd how it goes.

#![warn(unreachable_pub)]

// The API: the modules the binary (`src/main.rs`), the integration tests, the benchmark
// (`benches/paper`) and the examples import from.
pub mod can;
pub mod cli;
pub mod config;
pub mod console;
pub mod controls;
pub mod driver;
pub mod engine;
pub mod exit;
#[cfg(feature = "fleet")]
pub mod fleet;
pub mod logging;
pub mod net;
pub mod port;
pub mod probe;
pub mod record;
#[cfg(feature = "ros2")]
pub mod ros2;
pub mod safety;
pub mod sim;
pub mod snapshot;
pub mod socket;
pub mod supervisor;
/// Fixtures for tests: public (and hidden from the docs) because the screen tests in
/// `tests/console_screen.rs` build their vehicles with it, as the unit tests do.
#[doc(hidden)]
pub mod testkit;
pub mod threads;
pub mod value;
pub mod vehicle;

// Internal: only the crate reaches these, so `unreachable_pub` holds their items to
// `pub(crate)` and the compiler names what nothing uses.
mod characterize;
mod foxglove;
mod headless;
mod paths;
mod port_list;
mod service;
