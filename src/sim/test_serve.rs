//! Test support: run a [`Responder`] on one end of a real pseudo-terminal pair with a
//! minimal port loop (read, respond, write), so a driver on the other end is tested
//! over the same kind of byte stream `--sim` gives it, kernel buffering included.

use super::device::{Plant, Responder};
use crate::value::{Command, Reading};
use serialport::{SerialPort, TTYPort};
use std::io::{self, Read, Write};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::thread::JoinHandle;
use std::time::Duration;

/// A plant that reports a fixed reading and records every command.
#[derive(Clone, Debug, Default)]
pub(crate) struct TestPlant {
    pub reading: Reading,
    pub commands: Vec<Command>,
    /// When set, every command is refused with this reason.
    pub(crate) refuse: Option<String>,
}

impl Plant for TestPlant {
    fn reading(&mut self) -> Reading {
        self.reading
    }

    fn command(&mut self, command: Command) -> Result<(), String> {
        match &self.refuse {
            Some(why) => Err(why.clone()),
            None => {
                self.commands.push(command);
                Ok(())
            }
        }
    }
}

/// A responder being served; `stop` ends the loop and hands the plant back.
pub(crate) struct Served<P> {
    stop: Arc<AtomicBool>,
    handle: JoinHandle<P>,
}

impl<P> Served<P> {
    pub(crate) fn stop(self) -> P {
        self.stop.store(true, Ordering::Relaxed);
        self.handle.join().expect("the port loop panicked")
    }
}

/// Serve `responder` in front of `plant` on a new pseudo-terminal; returns the loop
/// and the other end, for the driver.
pub(crate) fn serve_pty<R, P>(mut responder: R, mut plant: P) -> (Served<P>, TTYPort)
where
    R: Responder + 'static,
    P: Plant + Send + 'static,
{
    let (mut device, host) = TTYPort::pair().expect("a pseudo-terminal pair");
    device
        .set_timeout(Duration::from_millis(20))
        .expect("set timeout");
    let stop = Arc::new(AtomicBool::new(false));
    let flag = stop.clone();
    let handle = std::thread::Builder::new()
        .name("test/pty".into())
        .spawn(move || {
            let mut input = Vec::new();
            let mut chunk = [0u8; 256];
            while !flag.load(Ordering::Relaxed) {
                match device.read(&mut chunk) {
                    Ok(n) => input.extend_from_slice(&chunk[..n]),
                    Err(e) if e.kind() == io::ErrorKind::TimedOut => continue,
                    Err(_) => break,
                }
                while let Some(reply) = responder.respond(&input, &mut plant) {
                    input.drain(..reply.consumed.min(input.len()));
                    if !reply.bytes.is_empty() {
                        std::thread::sleep(reply.extra);
                        if device.write_all(&reply.bytes).is_err() {
                            return plant;
                        }
                    }
                }
            }
            plant
        })
        .expect("spawn the port loop");
    (Served { stop, handle }, host)
}
