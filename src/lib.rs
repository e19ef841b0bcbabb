//! adrive: an operator console with an embedded drive-by-wire actuator engine.
//!
//! The crate reads like the design: [`config`] describes a vehicle, [`vehicle`] holds
//! its devices and their cached state, [`engine`] runs two threads per actuator over a
//! [`driver::Driver`], [`interlock`] guards command intake, [`gate`] disengages on an
//! e-stop or a fault, [`net`] takes commands and broadcasts state over UDP, and [`sim`]
//! emulates the devices on real pseudo-terminals.

pub mod cli;
pub mod config;
pub mod console;
pub mod driver;
pub mod engine;
pub mod exit;
pub mod gate;
pub mod headless;
pub mod interlock;
pub mod logging;
pub mod net;
pub mod ports;
pub mod sim;
pub mod supervisor;
pub mod value;
pub mod vehicle;
