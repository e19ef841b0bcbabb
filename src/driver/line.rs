//! The adrive ASCII line protocol: a minimal request/reply protocol that any
//! microcontroller can speak and any terminal can type. The built-in Alice uses it for
//! the e-stop; any device can use it (`driver = "line"`).
//!
//! ```text
//! host → device   ?\n                      ask for status
//! device → host   = pos=0.120 vel=0.000\n  status: space-separated key=value pairs
//! host → device   ! 0.250\n                command: a number, a state's word (drive,
//!                                          left…) or a control word (disable, enable,
//!                                          home, start)
//! device → host   ok\n                     accepted
//! device → host   err <reason>\n           refused
//! ```
//!
//! Each reading has a status key: the well-known ones by default `pos` position, `vel`
//! velocity, `prs` pressure, `state`, `estop` (disable|pause|run), `rpm`, `spd` speed
//! m/s, `clt` coolant °C, `run` engine running 0|1, `volt`, `amp`, `soc`; any other
//! reading by its name; `flt` carries fault bits. A vehicle file may rename keys and
//! state words (`[device.line] keys = {…}, words = {…}`): the map is
//! [`LineMap`]. Unknown keys are ignored (newer firmware may report more). Lines end
//! in `\n`; a `\r` before it is ignored.

use super::{read_until, send_request, Deadline, Driver, DriverError, Link};
use crate::config::protocol_map::LineMap;
use crate::value::{Command, Control, Reading};
use std::io::Write;
use std::time::Duration;

/// Longest line either side sends.
pub(crate) const MAX_LINE: usize = 128;
/// The status request.
pub(crate) const POLL: &[u8] = b"?\n";

/// Encode a command into `out` (no allocation); returns the length. A state goes out
/// as its word.
pub(crate) fn encode_command(command: Command, map: &LineMap, out: &mut [u8; 48]) -> usize {
    let mut cursor = std::io::Cursor::new(&mut out[..]);
    // 48 bytes always hold "! " + a word of at most 24 bytes or a 3-decimal number in
    // −1e6…1e6.
    let _ = match command {
        Command::Set(v) => {
            let mut digits = [0u8; 16];
            let n = thousandths(v.clamp(-1e6, 1e6), &mut digits);
            cursor
                .write_all(b"! ")
                .and_then(|()| cursor.write_all(&digits[..n]))
                .and_then(|()| cursor.write_all(b"\n"))
        }
        Command::State(i) => writeln!(
            cursor,
            "! {}",
            map.words.get(i as usize).map_or("?", String::as_str)
        ),
        Command::Control(c) => writeln!(cursor, "! {}", c.as_str()),
    };
    cursor.position() as usize
}

/// `v` (within ±1e6) with three decimals, as `{:.3}` writes it, without the
/// formatting machinery, which costs microseconds on every command's way to its first
/// byte. A thousandth is the protocol's resolution; a value within a rounding error of a
/// half-thousandth may round the other way than the exact decimal would, and a negative
/// value that rounds to zero is written `0.000`.
fn thousandths(v: f64, out: &mut [u8; 16]) -> usize {
    let m = (v * 1000.0).round_ties_even() as i64;
    let mut n = 0;
    if m < 0 {
        out[0] = b'-';
        n = 1;
    }
    let (whole, frac) = (m.unsigned_abs() / 1000, m.unsigned_abs() % 1000);
    let mut int = [0u8; 8];
    let mut k = 0;
    let mut w = whole;
    loop {
        int[k] = b'0' + (w % 10) as u8;
        k += 1;
        w /= 10;
        if w == 0 {
            break;
        }
    }
    for &d in int[..k].iter().rev() {
        out[n] = d;
        n += 1;
    }
    out[n] = b'.';
    out[n + 1] = b'0' + (frac / 100) as u8;
    out[n + 2] = b'0' + (frac / 10 % 10) as u8;
    out[n + 3] = b'0' + (frac % 10) as u8;
    n + 4
}

fn trim_line(line: &[u8]) -> &[u8] {
    let mut l = line;
    while let [rest @ .., b'\n' | b'\r'] = l {
        l = rest;
    }
    l
}

/// Decode a status reply line (`= k=v …`) by the device's keys.
pub(crate) fn decode_status(line: &[u8], map: &LineMap) -> Result<Reading, String> {
    let text = std::str::from_utf8(trim_line(line)).map_err(|_| "not ASCII".to_string())?;
    let rest = text
        .strip_prefix('=')
        .ok_or_else(|| format!("status reply must start with '=': {text:?}"))?;
    let mut r = Reading::default();
    for pair in rest.split_whitespace() {
        let (k, v) = pair
            .split_once('=')
            .ok_or_else(|| format!("expected key=value, got {pair:?}"))?;
        if k == "flt" {
            r.fault = v
                .parse()
                .map_err(|_| format!("flt: expected 0…65535, got {v:?}"))?;
            continue;
        }
        // Unknown keys are ignored: newer firmware may report more.
        let Some(i) = map.keys.iter().position(|key| key == k) else {
            continue;
        };
        let words = &map.reading_words[i];
        let value = if !words.is_empty() {
            words
                .iter()
                .position(|w| w.eq_ignore_ascii_case(v))
                .ok_or_else(|| format!("{k}: expected one of {}, got {v:?}", words.join(", ")))?
                as f64
        } else {
            let x = v
                .parse::<f64>()
                .ok()
                .filter(|x| x.is_finite())
                .ok_or_else(|| format!("{k}: expected a number, got {v:?}"))?;
            if map.flags[i] {
                f64::from(u8::from(x != 0.0))
            } else {
                x
            }
        };
        r.set(i, value);
    }
    Ok(r)
}

/// Encode a status reply (device side).
pub(crate) fn encode_status(r: &Reading, map: &LineMap) -> Vec<u8> {
    let mut s = String::from("=");
    for (i, v) in r.values() {
        let (Some(key), Some(words)) = (map.keys.get(i), map.reading_words.get(i)) else {
            continue;
        };
        s.push(' ');
        s.push_str(key);
        s.push('=');
        if !words.is_empty() {
            s.push_str(words.get(v as usize).map_or("?", String::as_str));
        } else if map.flags[i] {
            s.push_str(if v != 0.0 { "1" } else { "0" });
        } else {
            s.push_str(&format!("{v:.4}"));
        }
    }
    s.push_str(&format!(" flt={}\n", r.fault));
    s.into_bytes()
}

/// A request as the device sees it.
#[derive(Debug, PartialEq)]
pub(crate) enum Request {
    Poll,
    Command(Command),
}

/// Decode one request line (device side). A word is one of the device's states, then
/// a control word.
pub(crate) fn decode_request(line: &[u8], map: &LineMap) -> Result<Request, String> {
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
    if let Some(i) = map.words.iter().position(|w| w.eq_ignore_ascii_case(arg)) {
        return Ok(Request::Command(Command::State(i as u8)));
    }
    arg.parse::<Control>()
        .map(|c| Request::Command(Command::Control(c)))
        .map_err(|_| format!("bad command value {arg:?}"))
}

/// Decode the reply to a command.
pub(crate) fn decode_ack(line: &[u8]) -> Result<(), DriverError> {
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
pub(crate) struct LineDriver {
    map: LineMap,
    reply_timeout: Duration,
    buf: Vec<u8>,
    /// The deadline of a command whose request went out and whose reply is still to
    /// be read ([`Driver::send_command`] → [`Driver::finish_command`]).
    awaiting: Option<Deadline>,
}

impl LineDriver {
    pub(crate) fn new(map: LineMap, reply_timeout: Duration) -> Self {
        LineDriver {
            map,
            reply_timeout,
            buf: Vec::with_capacity(MAX_LINE * 2),
            awaiting: None,
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
    fn longest(&self) -> Duration {
        self.reply_timeout
    }

    fn poll(&mut self, link: &mut dyn Link) -> Result<Reading, DriverError> {
        self.transact(link, POLL)?;
        decode_status(&self.buf, &self.map).map_err(DriverError::Garbled)
    }

    fn command(&mut self, link: &mut dyn Link, command: Command) -> Result<(), DriverError> {
        self.send_command(link, command)?;
        self.finish_command(link)
    }

    fn sends_at_once(&self) -> bool {
        true
    }

    fn send_command(&mut self, link: &mut dyn Link, command: Command) -> Result<(), DriverError> {
        let mut frame = [0u8; 48];
        let n = encode_command(command, &self.map, &mut frame);
        self.awaiting = None;
        self.awaiting = Some(send_request(link, &frame[..n], self.reply_timeout)?);
        Ok(())
    }

    fn finish_command(&mut self, link: &mut dyn Link) -> Result<(), DriverError> {
        let deadline = self.awaiting.take().ok_or_else(|| {
            DriverError::Unsupported("a reply awaited with no command sent".into())
        })?;
        self.buf.clear();
        read_until(link, &mut self.buf, b'\n', MAX_LINE, &deadline)?;
        decode_ack(&self.buf)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::protocol_map::Wire;
    use crate::driver::mock::{rx, tx, MockLink, Step};

    fn map(device: &str) -> LineMap {
        match crate::config::one_device(device).wire {
            Wire::Line(m) => m,
            other => panic!("{other:?}"),
        }
    }

    fn gearbox() -> LineMap {
        map("name = \"trans\"\nkind = \"state\"\nstates = [\"park\", \"drive\"]\ndriver = \"line\"\n[device.line]\nwords = { drive = \"D\" }")
    }

    fn sensor() -> LineMap {
        map("name = \"obd\"\nkind = \"sensor\"\nreadings = [\"rpm\", \"running\", { name = \"volts\", units = \"V\" }, \"estop\"]\ndriver = \"line\"")
    }

    #[test]
    fn set_points_are_written_as_the_formatter_writes_three_decimals() {
        // Thousandths and values between them (not within a rounding error of a tie).
        let grid = (-1_000_000..=1_000_000)
            .step_by(997)
            .flat_map(|k| [k as f64 / 1000.0, k as f64 / 1000.0 + 0.0002]);
        let binary = (-4096..=4096).map(|k| k as f64 / 1024.0);
        let odd = (0..2000).map(|k| (k as f64 * 0.618_033_988_7) % 1.0 * 2000.0 - 1000.0);
        for v in grid
            .chain(binary)
            .chain(odd)
            .chain([1e6, -1e6, 0.0, 999_999.999])
        {
            let mut out = [0u8; 16];
            let n = thousandths(v, &mut out);
            let want = format!("{v:.3}");
            let want = want
                .strip_prefix("-")
                .filter(|w| *w == "0.000")
                .unwrap_or(&want);
            assert_eq!(std::str::from_utf8(&out[..n]).unwrap(), want, "{v}");
        }
    }

    #[test]
    fn commands_encode_without_allocation_into_a_line() {
        let mut out = [0u8; 48];
        let m = gearbox();
        let n = encode_command(Command::Set(-0.25), &m, &mut out);
        assert_eq!(&out[..n], b"! -0.250\n");
        let n = encode_command(Command::State(1), &m, &mut out);
        assert_eq!(&out[..n], b"! D\n", "a state goes out as its word");
        let n = encode_command(Command::Set(f64::MAX), &m, &mut out);
        assert_eq!(&out[..n], b"! 1000000.000\n");
        let n = encode_command(Command::Control(Control::Home), &m, &mut out);
        assert_eq!(&out[..n], b"! home\n");
    }

    #[test]
    fn status_round_trips_through_the_wire_form() {
        let m = sensor();
        let mut r = Reading::default();
        r.set(0, 812.0);
        r.set(1, 1.0);
        r.set(2, 47.5);
        r.set(3, 1.0);
        r.fault = 3;
        let wire = encode_status(&r, &m);
        assert_eq!(
            wire,
            b"= rpm=812.0000 run=1 volts=47.5000 estop=pause flt=3\n"
        );
        assert_eq!(decode_status(&wire, &m), Ok(r));
    }

    #[test]
    fn status_accepts_crlf_and_ignores_unknown_keys() {
        let r = decode_status(b"= rpm=700 temp=33 \r\n", &sensor()).unwrap();
        assert_eq!(r.get(0), Some(700.0));
        assert_eq!(r.get(2), None);
    }

    #[test]
    fn garbage_status_is_an_error_naming_the_problem() {
        let m = sensor();
        assert!(decode_status(b"rpm=1\n", &m).unwrap_err().contains("'='"));
        assert!(decode_status(b"= rpm=abc\n", &m)
            .unwrap_err()
            .contains("rpm"));
        assert!(decode_status(b"= rpm=NaN\n", &m).is_err());
        assert!(decode_status(b"= estop=sport\n", &m)
            .unwrap_err()
            .contains("disable, pause, run"));
    }

    #[test]
    fn requests_decode_on_the_device_side() {
        let m = gearbox();
        assert_eq!(decode_request(b"?\n", &m), Ok(Request::Poll));
        assert_eq!(
            decode_request(b"! 0.250\r\n", &m),
            Ok(Request::Command(Command::Set(0.25)))
        );
        assert_eq!(
            decode_request(b"! d\n", &m),
            Ok(Request::Command(Command::State(1)))
        );
        assert_eq!(
            decode_request(b"! enable\n", &m),
            Ok(Request::Command(Command::Control(Control::Enable)))
        );
        assert!(decode_request(b"! inf\n", &m).is_err());
        assert!(decode_request(b"hello\n", &m).is_err());
    }

    fn steering() -> LineDriver {
        LineDriver::new(
            map("name = \"steer\"\nkind = \"setpoint\"\nrange = [-1.0, 1.0]\ndriver = \"line\""),
            Duration::from_millis(50),
        )
    }

    /// A command split in two halves puts the same bytes on the wire as a whole one:
    /// the first half only writes (the script has nothing to read before the request
    /// is out), the second only reads and checks the reply.
    #[test]
    fn a_command_splits_into_its_request_and_its_reply() {
        let mut d = steering();
        assert!(d.sends_at_once());
        let mut link = MockLink::new([tx(b"! 0.250\n")]);
        d.send_command(&mut link, Command::Set(0.25)).unwrap();
        link.done();
        let mut link = MockLink::new([rx(b"ok\n")]);
        d.finish_command(&mut link).unwrap();
        drop(link);
        let mut link = MockLink::new([tx(b"! -0.500\n"), rx(b"err limit\n")]);
        assert!(matches!(
            d.command(&mut link, Command::Set(-0.5)),
            Err(DriverError::Refused(r)) if r == "limit"
        ));
    }

    #[test]
    fn a_split_reply_ends_at_the_requests_deadline() {
        let mut d = steering();
        let mut link = MockLink::new([tx(b"! 0.100\n")]);
        d.send_command(&mut link, Command::Set(0.1)).unwrap();
        drop(link);
        let mut link = MockLink::new([rx(b"o"), Step::Silence]);
        assert!(matches!(
            d.finish_command(&mut link),
            Err(DriverError::Timeout(_))
        ));
        drop(link);
        // Nothing is awaited any more: a reply with no request is an error, not a read.
        let mut link = MockLink::new([]);
        assert!(d.finish_command(&mut link).is_err());
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
