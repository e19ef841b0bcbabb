//! A simulated ELM327 v1.5 OBD-II adapter in front of the simulated engine, so the
//! OBD sensor runs under `--sim` through the real driver, quirks included: echo on
//! after every reset until `ATE0`, `\r` line ends (`\r\n` after `ATL1`), spaced hex
//! with a trailing space, the `>` prompt, a slow `ATZ`, `SEARCHING...` before the first
//! answer after a reset or `ATSP0`, `NO DATA` for a PID the car lacks, `?` for what it
//! does not understand. With [`Elm327Emulator::with_second_ecu`] a second ECU (a
//! transmission controller, CAN id 7E9) answers rpm and speed too, after the engine and
//! with rpm 0, as some cars do: it exercises the driver's multi-ECU rule.
//!
//! Serial terminal programs work against it too: type `ATI`, `010C`, or an empty line
//! to repeat the last command.

use super::device::{Plant, Reply, Responder};
use crate::config::protocol_map::ElmMap;
use crate::driver::elm327::proto::{Pid, MODE_CURRENT, MODE_CURRENT_REPLY};
use crate::value::Reading;
use std::time::Duration;

/// The identification line.
pub(crate) const BANNER: &str = "ELM327 v1.5";
/// How long `ATZ` takes before the banner.
pub(crate) const RESET_TIME: Duration = Duration::from_secs(1);
/// How long a protocol search takes.
pub(crate) const SEARCH_TIME: Duration = Duration::from_millis(300);
/// How long the car's ECU takes to answer a PID.
pub(crate) const ECU_TIME: Duration = Duration::from_millis(40);
/// How long the adapter waits for a silent car before `NO DATA` (ATST default).
pub(crate) const NO_DATA_TIME: Duration = Duration::from_millis(200);
/// Longest command line before the adapter gives up on it.
const MAX_LINE: usize = 64;

/// The device side of an ELM327.
#[derive(Clone, Debug)]
pub(crate) struct Elm327Emulator {
    echo: bool,
    linefeeds: bool,
    headers: bool,
    spaces: bool,
    /// The next OBD request searches the protocols first.
    search: bool,
    second_ecu: bool,
    last: Option<String>,
    /// Where the plant's reading keeps rpm, speed and coolant.
    map: ElmMap,
}

impl Elm327Emulator {
    /// An adapter just powered on, reporting the readings `map` names.
    pub(crate) fn new(map: ElmMap) -> Elm327Emulator {
        Elm327Emulator {
            map,
            echo: true,
            linefeeds: false,
            headers: false,
            spaces: true,
            search: true,
            second_ecu: false,
            last: None,
        }
    }

    /// Let a second ECU answer rpm and speed requests too.
    #[cfg_attr(not(test), allow(dead_code))]
    pub(crate) fn with_second_ecu(mut self, on: bool) -> Elm327Emulator {
        self.second_ecu = on;
        self
    }

    fn reset(&mut self) {
        let second = self.second_ecu;
        *self = Elm327Emulator::new(self.map.clone());
        self.second_ecu = second;
    }

    fn eol(&self) -> &'static str {
        if self.linefeeds {
            "\r\n"
        } else {
            "\r"
        }
    }

    /// One data line: `41 0C 1A F8 ` (with a header `7E8 04 ` when headers are on).
    fn data_line(&self, ecu: u16, bytes: &[u8]) -> String {
        let mut tokens = Vec::new();
        if self.headers {
            tokens.push(format!("{ecu:03X}"));
            tokens.push(format!("{:02X}", bytes.len()));
        }
        tokens.extend(bytes.iter().map(|b| format!("{b:02X}")));
        if self.spaces {
            tokens.join(" ") + " "
        } else {
            tokens.concat()
        }
    }

    /// The lines answering an AT command (without "AT"), and the time it takes.
    fn at(&mut self, cmd: &str) -> (Vec<String>, Duration) {
        let ok = || vec!["OK".to_string()];
        let flag = |rest: &str| match rest {
            "0" => Some(false),
            "1" => Some(true),
            _ => None,
        };
        let lines = match cmd {
            "Z" | "WS" => {
                self.reset();
                let time = if cmd == "Z" {
                    RESET_TIME
                } else {
                    RESET_TIME / 10
                };
                // The banner follows two empty lines.
                return (vec![String::new(), String::new(), BANNER.into()], time);
            }
            "D" => {
                self.reset();
                ok()
            }
            "I" => vec![BANNER.into()],
            "@1" => vec!["OBDII to RS232 Interpreter".into()],
            "RV" => vec!["12.6V".into()],
            "DP" => vec![if self.search {
                "AUTO".into()
            } else {
                "AUTO, ISO 15765-4 (CAN 11/500)".into()
            }],
            "DPN" => vec![if self.search { "A0" } else { "A6" }.into()],
            _ => {
                let (name, rest) = cmd.split_at(1.min(cmd.len()));
                let set = match name {
                    "E" => flag(rest).map(|on| self.echo = on),
                    "L" => flag(rest).map(|on| self.linefeeds = on),
                    "H" => flag(rest).map(|on| self.headers = on),
                    "S" if !rest.starts_with('P') && !rest.starts_with('T') => {
                        flag(rest).map(|on| self.spaces = on)
                    }
                    _ => None,
                };
                if set.is_some() {
                    ok()
                } else if let Some(p) = cmd.strip_prefix("SP").or_else(|| cmd.strip_prefix("TP")) {
                    if p.is_empty() {
                        vec!["?".into()]
                    } else {
                        self.search = p == "0" || p.starts_with('A');
                        ok()
                    }
                } else if !cmd.is_empty()
                    && cmd.chars().all(|c| c.is_ascii_alphanumeric() || c == '@')
                {
                    ok()
                } else {
                    vec!["?".into()]
                }
            }
        };
        (lines, Duration::ZERO)
    }

    /// The lines answering an OBD request given as hex digits.
    fn obd(&mut self, hex: &str, plant: &mut dyn Plant) -> (Vec<String>, Duration) {
        // An odd digit at the end is the "number of responses" suffix; ignore it.
        let digits = &hex[..hex.len() - hex.len() % 2];
        let bytes: Option<Vec<u8>> = (0..digits.len())
            .step_by(2)
            .map(|i| u8::from_str_radix(&digits[i..i + 2], 16).ok())
            .collect();
        let Some(bytes) = bytes.filter(|b| !b.is_empty()) else {
            return (vec!["?".into()], Duration::ZERO);
        };
        let mut lines = Vec::new();
        let mut time = Duration::ZERO;
        if self.search {
            self.search = false;
            lines.push("SEARCHING...".to_string());
            time += SEARCH_TIME;
        }
        let reading = plant.reading();
        let answers = self.answers(&bytes, &reading);
        if answers.is_empty() {
            lines.push("NO DATA".into());
            time += NO_DATA_TIME;
        } else {
            lines.extend(answers);
            time += ECU_TIME;
        }
        (lines, time)
    }

    fn answers(&self, request: &[u8], reading: &Reading) -> Vec<String> {
        if request.len() != 2 || request[0] != MODE_CURRENT {
            return Vec::new();
        }
        let engine = |data: Vec<u8>| {
            let mut b = vec![MODE_CURRENT_REPLY, request[1]];
            b.extend(data);
            b
        };
        let data = match request[1] {
            // Supported PIDs 01–20: 05, 0C, 0D.
            0x00 => Some(vec![0x08, 0x18, 0x00, 0x00]),
            code => Pid::from_code(code).and_then(|pid| {
                let at = match pid {
                    Pid::Rpm => self.map.rpm,
                    Pid::Speed => self.map.speed,
                    Pid::Coolant => self.map.coolant,
                };
                let value = at.and_then(|i| reading.get(i));
                value.map(|v| pid.encode(v))
            }),
        };
        let Some(data) = data else {
            return Vec::new();
        };
        let mut lines = vec![self.data_line(0x7E8, &engine(data))];
        if self.second_ecu {
            let second = match Pid::from_code(request[1]) {
                Some(Pid::Rpm) => Some(Pid::Rpm.encode(0.0)),
                Some(Pid::Speed) => self
                    .map
                    .speed
                    .and_then(|i| reading.get(i))
                    .map(|v| Pid::Speed.encode(v)),
                _ => None,
            };
            if let Some(d) = second {
                lines.push(self.data_line(0x7E9, &engine(d)));
            }
        }
        lines
    }
}

impl Responder for Elm327Emulator {
    fn respond(&mut self, input: &[u8], plant: &mut dyn Plant) -> Option<Reply> {
        let Some(end) = input.iter().position(|&b| b == b'\r') else {
            // A line that never ends: the adapter drops it and complains.
            return (input.len() > MAX_LINE).then(|| Reply {
                consumed: input.len(),
                bytes: format!("?{0}{0}>", self.eol()).into_bytes(),
                extra: Duration::ZERO,
            });
        };
        let raw = &input[..end];
        let mut out = String::new();
        if self.echo {
            out.push_str(&String::from_utf8_lossy(raw));
            out.push_str(self.eol());
        }
        // The adapter ignores spaces, control characters and case.
        let mut cmd = String::from_utf8_lossy(raw)
            .chars()
            .filter(|c| c.is_ascii_graphic())
            .collect::<String>()
            .to_ascii_uppercase();
        if cmd.is_empty() {
            match &self.last {
                Some(last) => cmd = last.clone(),
                None => {
                    out.push('>');
                    return Some(Reply {
                        consumed: end + 1,
                        bytes: out.into_bytes(),
                        extra: Duration::ZERO,
                    });
                }
            }
        }
        let (lines, extra) = if let Some(at) = cmd.strip_prefix("AT") {
            self.at(at)
        } else if cmd.chars().all(|c| c.is_ascii_hexdigit()) {
            self.last = Some(cmd.clone());
            self.obd(&cmd, plant)
        } else {
            (vec!["?".into()], Duration::ZERO)
        };
        // `self.eol()` after the command: a reset has just turned linefeeds off.
        let eol = self.eol();
        for line in lines {
            out.push_str(&line);
            out.push_str(eol);
        }
        out.push_str(eol);
        out.push('>');
        Some(Reply {
            consumed: end + 1,
            bytes: out.into_bytes(),
            extra,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::driver::elm327::proto::parse_pid;
    use crate::driver::elm327::{Elm327Driver, COOLANT_EVERY};
    use crate::driver::{Driver, DriverError};
    use crate::sim::test_serve::{serve_pty, TestPlant};
    use crate::value::Command;

    fn map() -> ElmMap {
        ElmMap {
            rpm: Some(0),
            speed: Some(1),
            coolant: Some(2),
            running: Some(3),
        }
    }

    fn engine() -> TestPlant {
        let mut reading = Reading::default();
        reading.set(0, 1726.0);
        reading.set(1, 10.0);
        reading.set(2, 83.0);
        TestPlant {
            reading,
            ..TestPlant::default()
        }
    }

    fn say(e: &mut Elm327Emulator, p: &mut TestPlant, line: &str) -> (String, Duration) {
        let input = format!("{line}\r");
        let r = e.respond(input.as_bytes(), p).expect("a whole line");
        assert_eq!(r.consumed, input.len());
        (String::from_utf8(r.bytes).unwrap(), r.extra)
    }

    #[test]
    fn a_reset_is_slow_and_echoes() {
        let (mut e, mut p) = (Elm327Emulator::new(map()), engine());
        let (out, extra) = say(&mut e, &mut p, "ATZ");
        assert_eq!(out, "ATZ\r\r\rELM327 v1.5\r\r>");
        assert!(extra >= Duration::from_millis(500));
        assert_eq!(say(&mut e, &mut p, "ATI").0, "ATI\rELM327 v1.5\r\r>");
        assert_eq!(say(&mut e, &mut p, "ATE0").0, "ATE0\rOK\r\r>");
        assert_eq!(say(&mut e, &mut p, "ATH0").0, "OK\r\r>");
        assert_eq!(say(&mut e, &mut p, "at l1").0, "OK\r\n\r\n>");
        // Echo stays as set until the reset, and the reset turns linefeeds off.
        assert_eq!(say(&mut e, &mut p, "ATZ").0, "\r\rELM327 v1.5\r\r>");
        assert_eq!(say(&mut e, &mut p, "ATI").0, "ATI\rELM327 v1.5\r\r>");
    }

    #[test]
    fn the_first_request_searches_then_answers() {
        let (mut e, mut p) = (Elm327Emulator::new(map()), engine());
        let (out, _) = say(&mut e, &mut p, "010C");
        assert_eq!(out, "010C\rSEARCHING...\r41 0C 1A F8 \r\r>");
        let (out, _) = say(&mut e, &mut p, "ATE0");
        assert_eq!(out, "ATE0\rOK\r\r>");
        assert_eq!(say(&mut e, &mut p, "010D").0, "41 0D 24 \r\r>");
        assert_eq!(say(&mut e, &mut p, "0105").0, "41 05 7B \r\r>");
        // An empty line repeats the last request.
        assert_eq!(say(&mut e, &mut p, "").0, "41 05 7B \r\r>");
        say(&mut e, &mut p, "ATSP0");
        assert!(say(&mut e, &mut p, "010C").0.starts_with("SEARCHING...\r"));
    }

    #[test]
    fn unknowns_and_missing_pids() {
        let (mut e, mut p) = (Elm327Emulator::new(map()), engine());
        say(&mut e, &mut p, "ATE0");
        say(&mut e, &mut p, "0100");
        assert_eq!(say(&mut e, &mut p, "HELLO").0, "?\r\r>");
        let (out, extra) = say(&mut e, &mut p, "0111");
        assert_eq!(out, "NO DATA\r\r>");
        assert_eq!(extra, NO_DATA_TIME);
        p.reading = {
            let mut r = Reading::default();
            r.set(0, 1726.0);
            r.set(1, 10.0);
            r
        };
        assert_eq!(say(&mut e, &mut p, "0105").0, "NO DATA\r\r>");
        assert_eq!(say(&mut e, &mut p, "0100").0, "41 00 08 18 00 00 \r\r>");
    }

    #[test]
    fn a_second_ecu_answers_after_the_engine() {
        let (mut e, mut p) = (Elm327Emulator::new(map()).with_second_ecu(true), engine());
        say(&mut e, &mut p, "ATE0");
        let (out, _) = say(&mut e, &mut p, "010C");
        assert_eq!(out, "SEARCHING...\r41 0C 1A F8 \r41 0C 00 00 \r\r>");
        assert_eq!(parse_pid(out.as_bytes(), Pid::Rpm), Ok(1726.0));
        say(&mut e, &mut p, "ATH1");
        say(&mut e, &mut p, "ATS0");
        let (out, _) = say(&mut e, &mut p, "010C");
        assert_eq!(out, "7E804410C1AF8\r7E904410C0000\r\r>");
        assert_eq!(parse_pid(out.as_bytes(), Pid::Rpm), Ok(1726.0));
    }

    #[test]
    fn bytes_arrive_in_pieces() {
        let (mut e, mut p) = (Elm327Emulator::new(map()), engine());
        assert_eq!(e.respond(b"01", &mut p), None);
        let r = e.respond(b"010D\r01", &mut p).unwrap();
        assert_eq!(r.consumed, 5);
    }

    #[test]
    fn the_driver_and_the_emulator_agree_over_a_pseudo_terminal() {
        let (server, mut link) =
            serve_pty(Elm327Emulator::new(map()).with_second_ecu(true), engine());
        let mut d = Elm327Driver::new(map(), Duration::from_secs(2));
        d.open(&mut link).unwrap();
        assert_eq!(d.banner(), Some(BANNER));
        for i in 0..COOLANT_EVERY + 1 {
            let r = d.poll(&mut link).unwrap();
            assert_eq!(r.get(0), Some(1726.0), "poll {i}");
            assert!((r.get(1).unwrap() - 10.0).abs() < 0.2);
            assert_eq!(r.get(2), Some(83.0));
            assert_eq!(r.get(3), Some(1.0), "running");
        }
        assert!(matches!(
            d.command(&mut link, Command::Set(0.0)),
            Err(DriverError::Unsupported(_))
        ));
        // A reconnect runs the whole sequence again, echo and all.
        d.open(&mut link).unwrap();
        d.poll(&mut link).unwrap();
        server.stop();
    }
}
