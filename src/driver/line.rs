//! The adrive ASCII line protocol: a minimal request/reply protocol that any
//! microcontroller can speak and any terminal can type. The built-in Alice uses it for
//! the e-stop; any device can use it (`driver = "line"`).
//!
//! ```text
//! host → device   ?\n                      ask for status
//! device → host   = pos=0.120 vel=0.000\n  status: space-separated key=value pairs
//! host → device   ! 0.250\n                command: a number, a gear (drive, park…) or a
//!                                          control word (disable, enable, home, start)
//! device → host   ok\n                     accepted
//! device → host   err <reason>\n           refused
//! ```
//!
//! Status keys: `pos` position, `vel` velocity, `prs` pressure, `gear`
//! (park|reverse|neutral|drive), `estop` (disable|pause|run), `rpm`, `spd` speed m/s,
//! `clt` coolant °C, `run` engine running 0|1, `flt` fault bits. Unknown keys are
//! ignored (newer firmware may report more). Lines end in `\n`; a `\r` before it is
//! ignored.

use super::{read_until, send_request, Driver, DriverError, Link};
use crate::value::{Command, Control, Gear, Reading};
use std::io::Write;
use std::time::Duration;

/// Longest line either side sends.
pub const MAX_LINE: usize = 128;
/// The status request.
pub const POLL: &[u8] = b"?\n";

/// Encode a command into `out` (no allocation); returns the length.
pub fn encode_command(command: Command, out: &mut [u8; 32]) -> usize {
    let mut cursor = std::io::Cursor::new(&mut out[..]);
    // 32 bytes always hold "! " + a gear word or a 3-decimal number in −1e6…1e6.
    let _ = match command {
        Command::Set(v) => writeln!(cursor, "! {:.3}", v.clamp(-1e6, 1e6)),
        Command::Gear(g) => writeln!(cursor, "! {g}"),
        Command::Control(c) => writeln!(cursor, "! {}", c.as_str()),
    };
    cursor.position() as usize
}

fn trim_line(line: &[u8]) -> &[u8] {
    let mut l = line;
    while let [rest @ .., b'\n' | b'\r'] = l {
        l = rest;
    }
    l
}

/// Decode a status reply line (`= k=v …`).
pub fn decode_status(line: &[u8]) -> Result<Reading, String> {
    let text = std::str::from_utf8(trim_line(line)).map_err(|_| "not ASCII".to_string())?;
    let rest = text
        .strip_prefix('=')
        .ok_or_else(|| format!("status reply must start with '=': {text:?}"))?;
    let mut r = Reading::default();
    for pair in rest.split_whitespace() {
        let (k, v) = pair
            .split_once('=')
            .ok_or_else(|| format!("expected key=value, got {pair:?}"))?;
        let num = || {
            v.parse::<f64>()
                .ok()
                .filter(|x| x.is_finite())
                .ok_or_else(|| format!("{k}: expected a number, got {v:?}"))
        };
        match k {
            "pos" => r.position = Some(num()?),
            "vel" => r.velocity = Some(num()?),
            "prs" => r.pressure = Some(num()?),
            "rpm" => r.rpm = Some(num()?),
            "spd" => r.speed = Some(num()?),
            "clt" => r.coolant = Some(num()?),
            "run" => r.running = Some(num()? != 0.0),
            "flt" => {
                r.fault = v
                    .parse()
                    .map_err(|_| format!("flt: expected 0…65535, got {v:?}"))?
            }
            "gear" => r.gear = Some(v.parse()?),
            "estop" => r.estop = Some(v.parse()?),
            _ => {}
        }
    }
    Ok(r)
}

/// Encode a status reply (device side).
pub fn encode_status(r: &Reading) -> Vec<u8> {
    let mut s = String::from("=");
    let mut put = |k: &str, v: Option<String>| {
        if let Some(v) = v {
            s.push(' ');
            s.push_str(k);
            s.push('=');
            s.push_str(&v);
        }
    };
    put("pos", r.position.map(|v| format!("{v:.4}")));
    put("vel", r.velocity.map(|v| format!("{v:.4}")));
    put("prs", r.pressure.map(|v| format!("{v:.3}")));
    put("gear", r.gear.map(|g| g.to_string()));
    put("estop", r.estop.map(|e| e.to_string()));
    put("rpm", r.rpm.map(|v| format!("{v:.0}")));
    put("spd", r.speed.map(|v| format!("{v:.3}")));
    put("clt", r.coolant.map(|v| format!("{v:.1}")));
    put("run", r.running.map(|v| u8::from(v).to_string()));
    put("flt", Some(r.fault.to_string()));
    s.push('\n');
    s.into_bytes()
}

/// A request as the device sees it.
#[derive(Debug, PartialEq)]
pub enum Request {
    Poll,
    Command(Command),
}

/// Decode one request line (device side).
pub fn decode_request(line: &[u8]) -> Result<Request, String> {
    let text = std::str::from_utf8(trim_line(line)).map_err(|_| "not ASCII".to_string())?;
    if text == "?" {
        return Ok(Request::Poll);
    }
    let arg = text
        .strip_prefix('!')
        .map(str::trim)
        .ok_or_else(|| format!("unknown request {text:?}"))?;
    if let Ok(v) = arg.parse::<f64>() {
        if v.is_finite() {
            return Ok(Request::Command(Command::Set(v)));
        }
    }
    if let Ok(c) = arg.parse::<Control>() {
        return Ok(Request::Command(Command::Control(c)));
    }
    arg.parse::<Gear>()
        .map(|g| Request::Command(Command::Gear(g)))
        .map_err(|_| format!("bad command value {arg:?}"))
}

/// Decode the reply to a command.
pub fn decode_ack(line: &[u8]) -> Result<(), DriverError> {
    let l = trim_line(line);
    if l == b"ok" {
        Ok(())
    } else if let Some(reason) = l.strip_prefix(b"err") {
        Err(DriverError::Refused(
            String::from_utf8_lossy(reason).trim().to_string(),
        ))
    } else {
        Err(DriverError::Garbled(format!(
            "expected ok or err, got {:?}",
            String::from_utf8_lossy(l)
        )))
    }
}

/// Host side of the line protocol.
pub struct LineDriver {
    reply_timeout: Duration,
    buf: Vec<u8>,
}

impl LineDriver {
    pub fn new(reply_timeout: Duration) -> Self {
        LineDriver {
            reply_timeout,
            buf: Vec::with_capacity(MAX_LINE * 2),
        }
    }

    /// One request and its reply line, over by `reply_timeout` whatever the device sends.
    fn transact(&mut self, link: &mut dyn Link, request: &[u8]) -> Result<&[u8], DriverError> {
        let deadline = send_request(link, request, self.reply_timeout)?;
        self.buf.clear();
        read_until(link, &mut self.buf, b'\n', MAX_LINE, &deadline)?;
        Ok(&self.buf)
    }
}

impl Driver for LineDriver {
    fn poll(&mut self, link: &mut dyn Link) -> Result<Reading, DriverError> {
        let line = self.transact(link, POLL)?;
        decode_status(line).map_err(DriverError::Garbled)
    }

    fn command(&mut self, link: &mut dyn Link, command: Command) -> Result<(), DriverError> {
        let mut frame = [0u8; 32];
        let n = encode_command(command, &mut frame);
        let line = self.transact(link, &frame[..n])?;
        decode_ack(line)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::value::EstopState;

    #[test]
    fn commands_encode_without_allocation_into_a_line() {
        let mut out = [0u8; 32];
        let n = encode_command(Command::Set(-0.25), &mut out);
        assert_eq!(&out[..n], b"! -0.250\n");
        let n = encode_command(Command::Gear(Gear::Drive), &mut out);
        assert_eq!(&out[..n], b"! drive\n");
        let n = encode_command(Command::Set(f64::MAX), &mut out);
        assert_eq!(&out[..n], b"! 1000000.000\n");
    }

    #[test]
    fn status_round_trips_through_the_wire_form() {
        let r = Reading {
            position: Some(0.5),
            velocity: Some(-0.1),
            gear: Some(Gear::Reverse),
            estop: Some(EstopState::Pause),
            running: Some(true),
            fault: 3,
            ..Reading::default()
        };
        assert_eq!(decode_status(&encode_status(&r)), Ok(r));
    }

    #[test]
    fn status_accepts_crlf_and_ignores_unknown_keys() {
        let r = decode_status(b"= pos=0.1 temp=33 \r\n").unwrap();
        assert_eq!(r.position, Some(0.1));
    }

    #[test]
    fn garbage_status_is_an_error_naming_the_problem() {
        assert!(decode_status(b"pos=1\n").unwrap_err().contains("'='"));
        assert!(decode_status(b"= pos=abc\n").unwrap_err().contains("pos"));
        assert!(decode_status(b"= pos=NaN\n").is_err());
        assert!(decode_status(b"= gear=sport\n").is_err());
    }

    #[test]
    fn requests_decode_on_the_device_side() {
        assert_eq!(decode_request(b"?\n"), Ok(Request::Poll));
        assert_eq!(
            decode_request(b"! 0.250\r\n"),
            Ok(Request::Command(Command::Set(0.25)))
        );
        assert_eq!(
            decode_request(b"! park\n"),
            Ok(Request::Command(Command::Gear(Gear::Park)))
        );
        assert!(decode_request(b"! inf\n").is_err());
        assert!(decode_request(b"hello\n").is_err());
    }

    #[test]
    fn acks_and_refusals() {
        assert!(decode_ack(b"ok\n").is_ok());
        assert!(matches!(decode_ack(b"err busy\n"), Err(DriverError::Refused(r)) if r == "busy"));
        assert!(matches!(
            decode_ack(b"OKAY\n"),
            Err(DriverError::Garbled(_))
        ));
    }
}
