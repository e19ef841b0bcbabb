//! Drivers: one implementation of [`Driver`] per device protocol (the paper's wish for
//! "a basic actuator class"). A driver knows bytes and registers, nothing of threads:
//! the engine owns the port, opens it, hands it to the driver as a [`Link`] for one
//! transaction at a time, and measures around it.

pub mod elm327;
pub mod line;
#[cfg(test)]
mod mock;
pub mod modbus;

use crate::value::{Command, Reading};
use std::io::{self, Read, Write};
use std::time::Duration;

/// The byte stream a driver talks over: a serial port in the field, a pseudo-terminal
/// under `--sim`, a scripted mock in unit tests.
pub trait Link: Read + Write + Send {
    /// How long a read may block before it fails with `TimedOut`.
    fn set_timeout(&mut self, timeout: Duration) -> io::Result<()>;
    /// Drop whatever the device sent that nobody asked for (a late reply, noise).
    fn discard_input(&mut self) -> io::Result<()>;
}

impl Link for Box<dyn serialport::SerialPort> {
    fn set_timeout(&mut self, timeout: Duration) -> io::Result<()> {
        serialport::SerialPort::set_timeout(self.as_mut(), timeout).map_err(io::Error::from)
    }
    fn discard_input(&mut self) -> io::Result<()> {
        self.clear(serialport::ClearBuffer::Input)
            .map_err(io::Error::from)
    }
}

impl Link for serialport::TTYPort {
    fn set_timeout(&mut self, timeout: Duration) -> io::Result<()> {
        serialport::SerialPort::set_timeout(self, timeout).map_err(io::Error::from)
    }
    fn discard_input(&mut self) -> io::Result<()> {
        serialport::SerialPort::clear(self, serialport::ClearBuffer::Input).map_err(io::Error::from)
    }
}

/// Why a transaction failed. The engine counts every kind; `Io` errors that mean the
/// port is gone make it close the port and reopen it with backoff.
#[derive(Debug, thiserror::Error)]
pub enum DriverError {
    /// The device did not answer within the reply timeout.
    #[error("no reply within {0:?}")]
    Timeout(Duration),
    /// The device answered, but not in its protocol (garbage, bad checksum, wrong id).
    #[error("bad reply: {0}")]
    Garbled(String),
    /// The device answered in its protocol that it refuses (Modbus exception, `?`, `err`).
    #[error("device refused: {0}")]
    Refused(String),
    /// The command cannot be expressed for this device (e.g. a gear sent to steering).
    #[error("unsupported command: {0}")]
    Unsupported(String),
    /// The port failed.
    #[error("port: {0}")]
    Io(#[from] io::Error),
}

impl DriverError {
    /// True when the port itself is gone (USB unplugged, pty closed): reopen it.
    pub fn is_disconnect(&self) -> bool {
        match self {
            DriverError::Io(e) => !matches!(
                e.kind(),
                io::ErrorKind::TimedOut | io::ErrorKind::WouldBlock | io::ErrorKind::Interrupted
            ),
            _ => false,
        }
    }

    /// A short stable name for counters and the broadcast.
    pub fn kind(&self) -> &'static str {
        match self {
            DriverError::Timeout(_) => "timeout",
            DriverError::Garbled(_) => "garbled",
            DriverError::Refused(_) => "refused",
            DriverError::Unsupported(_) => "unsupported",
            DriverError::Io(_) => "io",
        }
    }
}

/// One device protocol, host side. Every call is one complete transaction: the engine
/// holds the port for exactly its duration.
pub trait Driver: Send {
    /// Bring a freshly opened port into a known state (e.g. the ELM327's reset
    /// sequence). Called again after every reconnect.
    fn open(&mut self, link: &mut dyn Link) -> Result<(), DriverError> {
        let _ = link;
        Ok(())
    }
    /// Ask the device for its state.
    fn poll(&mut self, link: &mut dyn Link) -> Result<Reading, DriverError>;
    /// Send one command and wait for the device's acknowledgement.
    fn command(&mut self, link: &mut dyn Link, command: Command) -> Result<(), DriverError>;
}

/// Read from `link` until `terminator` arrives (included in `buf`), the reply grows past
/// `max` bytes, or the link's timeout passes.
pub fn read_until(
    link: &mut dyn Link,
    buf: &mut Vec<u8>,
    terminator: u8,
    max: usize,
    timeout: Duration,
) -> Result<(), DriverError> {
    let mut byte = [0u8; 64];
    loop {
        match link.read(&mut byte) {
            Ok(0) => return Err(DriverError::Io(io::ErrorKind::UnexpectedEof.into())),
            Ok(n) => {
                buf.extend_from_slice(&byte[..n]);
                if buf.contains(&terminator) {
                    return Ok(());
                }
                if buf.len() > max {
                    return Err(DriverError::Garbled(format!(
                        "reply longer than {max} bytes without a terminator"
                    )));
                }
            }
            Err(e) if e.kind() == io::ErrorKind::TimedOut => {
                return Err(DriverError::Timeout(timeout))
            }
            Err(e) if e.kind() == io::ErrorKind::Interrupted => {}
            Err(e) => return Err(DriverError::Io(e)),
        }
    }
}

/// Build the driver a device's configuration asks for.
pub fn build(config: &crate::config::DeviceConfig) -> Box<dyn Driver> {
    use crate::config::wire::Wire;
    match &config.wire {
        Wire::Modbus(m) => Box::new(modbus::ModbusDriver::new(
            m.clone(),
            config.baud,
            config.reply_timeout,
        )),
        Wire::Elm327(m) => Box::new(elm327::Elm327Driver::new(m.clone(), config.reply_timeout)),
        Wire::Line(m) => Box::new(line::LineDriver::new(m.clone(), config.reply_timeout)),
    }
}

/// Open a serial port (or pseudo-terminal) by path at a baud rate.
pub fn open_serial(path: &str, baud: u32, timeout: Duration) -> io::Result<Box<dyn Link>> {
    let port = serialport::new(path, baud)
        .timeout(timeout)
        .open_native()
        .map_err(io::Error::from)?;
    Ok(Box::new(port))
}
