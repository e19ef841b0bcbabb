//! The simulator: every device of the vehicle on its own pseudo-terminal, speaking its
//! real wire protocol at its real baud timing, in front of a simple vehicle model.

pub mod device;
pub mod elm327;
pub mod modbus;
#[cfg(test)]
pub(crate) mod test_serve;
