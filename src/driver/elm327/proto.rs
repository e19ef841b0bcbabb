//! The ELM327 OBD-II adapter's text protocol as pure functions: the requests adrive
//! sends, and the parsing of replies as a real ELM327 v1.5 (and its many clones) sends
//! them: an optional echo of the command, `\r` line ends (with `\n` if linefeeds are
//! on), hex bytes with or without spaces and often with a trailing space,
//! `SEARCHING...` or `BUS INIT: ...OK` before the first answer, the adapter's error
//! words, and the `>` prompt that ends every reply.
//!
//! When several ECUs answer one request (engine and transmission both report rpm),
//! the rule is: with headers on, the engine ECU's line wins (CAN id `7E8`, or
//! `18 DA F1 10` with 29-bit ids); otherwise, and with headers off as adrive runs the
//! adapter, the first well-formed answer for the PID wins. The engine ECU has the
//! highest-priority CAN id, so on a CAN car its answer is the first on the bus.

use std::fmt;

/// The prompt that ends every reply: the adapter is ready for the next command.
pub(crate) const PROMPT: u8 = b'>';
/// Mode 01: current powertrain data.
pub(crate) const MODE_CURRENT: u8 = 0x01;
/// Mode 01 replies start with 0x40 + 0x01.
pub(crate) const MODE_CURRENT_REPLY: u8 = 0x41;

/// The OBD-II PIDs adrive reads.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Pid {
    /// 0x05: engine coolant temperature, A − 40 °C.
    Coolant,
    /// 0x0C: engine speed, (256 A + B) / 4 rpm.
    Rpm,
    /// 0x0D: vehicle speed, A km/h.
    Speed,
}

impl Pid {
    pub(crate) const ALL: [Pid; 3] = [Pid::Coolant, Pid::Rpm, Pid::Speed];

    pub(crate) fn code(self) -> u8 {
        match self {
            Pid::Coolant => 0x05,
            Pid::Rpm => 0x0C,
            Pid::Speed => 0x0D,
        }
    }

    pub(crate) fn from_code(code: u8) -> Option<Pid> {
        Pid::ALL.into_iter().find(|p| p.code() == code)
    }

    /// Data bytes in the answer.
    pub(crate) fn data_len(self) -> usize {
        match self {
            Pid::Rpm => 2,
            Pid::Coolant | Pid::Speed => 1,
        }
    }

    /// The request line, e.g. `010C\r`.
    pub(crate) fn request(self) -> String {
        format!("{:02X}{:02X}\r", MODE_CURRENT, self.code())
    }

    /// The value in adrive's units: rpm, m/s, °C.
    pub(crate) fn decode(self, data: &[u8]) -> f64 {
        match self {
            Pid::Rpm => (256.0 * data[0] as f64 + data[1] as f64) / 4.0,
            Pid::Speed => data[0] as f64 / 3.6,
            Pid::Coolant => data[0] as f64 - 40.0,
        }
    }

    /// The data bytes for a value in adrive's units (the simulator's side), clamped to
    /// what the PID can carry.
    pub(crate) fn encode(self, value: f64) -> Vec<u8> {
        match self {
            Pid::Rpm => {
                let raw = (value * 4.0).round().clamp(0.0, 65535.0) as u16;
                raw.to_be_bytes().to_vec()
            }
            Pid::Speed => vec![(value * 3.6).round().clamp(0.0, 255.0) as u8],
            Pid::Coolant => vec![(value + 40.0).round().clamp(0.0, 255.0) as u8],
        }
    }
}

impl fmt::Display for Pid {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Pid::Coolant => "coolant",
            Pid::Rpm => "rpm",
            Pid::Speed => "speed",
        })
    }
}

/// What an ELM327 reply can say besides data.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
pub(crate) enum ElmError {
    /// No ECU answered within the adapter's timeout (often: PID not supported).
    #[error("NO DATA")]
    NoData,
    /// The adapter did not understand the command.
    #[error("? (command not understood)")]
    Unknown,
    /// A byte arrived while the adapter was busy and it gave up.
    #[error("STOPPED")]
    Stopped,
    /// No OBD protocol answered (ignition off, not connected).
    #[error("UNABLE TO CONNECT")]
    UnableToConnect,
    /// Any other adapter message: BUS ERROR, CAN ERROR, BUS INIT: ...ERROR, ...
    #[error("adapter: {0}")]
    Adapter(String),
    /// The reply made no sense.
    #[error("{0}")]
    Garbled(String),
}

/// The lines of a reply up to its prompt: split at `\r` or `\n`, trimmed, empty lines
/// and the prompt dropped.
pub(crate) fn lines(reply: &[u8]) -> Vec<String> {
    let end = reply
        .iter()
        .rposition(|&b| b == PROMPT)
        .unwrap_or(reply.len());
    String::from_utf8_lossy(&reply[..end])
        .split(['\r', '\n'])
        .map(|l| l.trim().to_string())
        .filter(|l| !l.is_empty())
        .collect()
}

/// True when `line` is the echo of `command` (the adapter echoes what it received;
/// spaces and case do not matter).
fn is_echo(line: &str, command: &str) -> bool {
    let squash = |s: &str| {
        s.chars()
            .filter(|c| !c.is_whitespace())
            .collect::<String>()
            .to_ascii_uppercase()
    };
    let c = squash(command);
    !c.is_empty() && squash(line) == c
}

/// The lines that carry the answer: the echo, `SEARCHING...` and `BUS INIT: ...OK`
/// removed; an error word, if the adapter said one, as an error.
pub(crate) fn answer_lines(reply: &[u8], command: &str) -> Result<Vec<String>, ElmError> {
    let mut out = Vec::new();
    for (i, line) in lines(reply).into_iter().enumerate() {
        let upper = line.to_ascii_uppercase();
        if i == 0 && is_echo(&line, command) {
            continue;
        }
        if upper.starts_with("SEARCHING") {
            continue;
        }
        if let Some(rest) = upper.strip_prefix("BUS INIT:") {
            if rest.trim_start_matches([' ', '.']).starts_with("OK") {
                continue;
            }
            return Err(ElmError::Adapter(line));
        }
        match upper.as_str() {
            "NO DATA" => return Err(ElmError::NoData),
            "?" => return Err(ElmError::Unknown),
            "STOPPED" => return Err(ElmError::Stopped),
            "UNABLE TO CONNECT" => return Err(ElmError::UnableToConnect),
            "CAN ERROR" | "BUS ERROR" | "BUS BUSY" | "DATA ERROR" | "BUFFER FULL" | "FB ERROR"
            | "ACT ALERT" | "LV RESET" | "<RX ERROR" | "<DATA ERROR" => {
                return Err(ElmError::Adapter(line))
            }
            u if u.starts_with("ERR") => return Err(ElmError::Adapter(line)),
            _ => out.push(line),
        }
    }
    Ok(out)
}

/// Hex bytes of a data line, spaced (`41 0C 1A F8`) or not (`410C1AF8`). A token of
/// odd length starts with an 11-bit CAN header (`7E8`, or `7E804410C...` with spaces
/// off), kept whole as one value.
pub(crate) fn hex_tokens(line: &str) -> Option<Vec<u16>> {
    let mut out = Vec::new();
    for token in line.split_whitespace() {
        let mut token = token;
        if token.len() % 2 != 0 {
            out.push(u16::from_str_radix(token.get(..3)?, 16).ok()?);
            token = &token[3..];
        }
        for i in (0..token.len()).step_by(2) {
            out.push(u16::from_str_radix(token.get(i..i + 2)?, 16).ok()?);
        }
    }
    (!out.is_empty()).then_some(out)
}

/// True when a data line starts with the engine ECU's header.
fn from_engine(tokens: &[u16]) -> bool {
    tokens.first() == Some(&0x7E8) || tokens.starts_with(&[0x18, 0xDA, 0xF1, 0x10])
}

/// The data bytes of the answer to `pid` in `line`: the bytes after `41 <pid>`.
fn pid_data(tokens: &[u16], pid: Pid) -> Option<Vec<u8>> {
    let want = [MODE_CURRENT_REPLY as u16, pid.code() as u16];
    let at = tokens.windows(2).position(|w| w == want)?;
    let data = tokens.get(at + 2..at + 2 + pid.data_len())?;
    data.iter().map(|&b| u8::try_from(b).ok()).collect()
}

/// Parse the reply to a `01 <pid>` request, by the multi-ECU rule of this module.
pub(crate) fn parse_pid(reply: &[u8], pid: Pid) -> Result<f64, ElmError> {
    let request = pid.request();
    let lines = answer_lines(reply, request.trim_end())?;
    let mut first = None;
    for line in &lines {
        let Some(tokens) = hex_tokens(line) else {
            continue;
        };
        if let Some(data) = pid_data(&tokens, pid) {
            if from_engine(&tokens) {
                return Ok(pid.decode(&data));
            }
            first.get_or_insert(data);
        }
    }
    first.map(|d| pid.decode(&d)).ok_or_else(|| {
        ElmError::Garbled(format!(
            "no answer for PID {:02X} in {:?}",
            pid.code(),
            lines.join(" | ")
        ))
    })
}

/// Parse the reply to an AT command that answers `OK`.
pub(crate) fn parse_ok(reply: &[u8], command: &str) -> Result<(), ElmError> {
    let lines = answer_lines(reply, command)?;
    if lines.iter().any(|l| l.eq_ignore_ascii_case("OK")) {
        Ok(())
    } else {
        Err(ElmError::Garbled(format!(
            "{command} answered {:?}",
            lines.join(" | ")
        )))
    }
}

/// The identification line in the reply to `ATZ` or `ATI`, e.g. `ELM327 v1.5`.
pub(crate) fn parse_banner(reply: &[u8]) -> Result<String, ElmError> {
    lines(reply)
        .into_iter()
        .find(|l| l.to_ascii_uppercase().contains("ELM327"))
        .ok_or_else(|| {
            ElmError::Garbled(format!(
                "no ELM327 banner in {:?}",
                String::from_utf8_lossy(reply)
            ))
        })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn requests_are_mode_01_lines() {
        assert_eq!(Pid::Rpm.request(), "010C\r");
        assert_eq!(Pid::Speed.request(), "010D\r");
        assert_eq!(Pid::Coolant.request(), "0105\r");
    }

    #[test]
    fn values_decode_by_the_sae_formulas() {
        assert_eq!(Pid::Rpm.decode(&[0x1A, 0xF8]), 1726.0);
        assert_eq!(Pid::Speed.decode(&[36]), 10.0);
        assert_eq!(Pid::Coolant.decode(&[0x7B]), 83.0);
        for pid in Pid::ALL {
            let v = pid.decode(&pid.encode(pid.decode(&[0x40, 0x10][..pid.data_len()])));
            assert_eq!(pid.encode(v), [0x40u8, 0x10][..pid.data_len()].to_vec());
        }
    }

    #[test]
    fn a_reply_with_echo_and_trailing_spaces_parses() {
        assert_eq!(parse_pid(b"010C\r41 0C 1A F8 \r\r>", Pid::Rpm), Ok(1726.0));
        assert_eq!(parse_pid(b"41 0D 24 \r\r>", Pid::Speed), Ok(10.0));
        // Linefeeds on, spaces off.
        assert_eq!(
            parse_pid(b"0105\r\n41057B\r\n\r\n>", Pid::Coolant),
            Ok(83.0)
        );
    }

    #[test]
    fn searching_and_bus_init_are_skipped() {
        assert_eq!(
            parse_pid(b"010C\rSEARCHING...\r41 0C 0F A0 \r\r>", Pid::Rpm),
            Ok(1000.0)
        );
        assert_eq!(
            parse_pid(b"BUS INIT: ...OK\r41 0C 0F A0\r\r>", Pid::Rpm),
            Ok(1000.0)
        );
        assert!(matches!(
            parse_pid(b"BUS INIT: ...ERROR\r\r>", Pid::Rpm),
            Err(ElmError::Adapter(_))
        ));
    }

    #[test]
    fn adapter_words_are_errors() {
        assert_eq!(
            parse_pid(b"010C\rNO DATA\r\r>", Pid::Rpm),
            Err(ElmError::NoData)
        );
        assert_eq!(parse_pid(b"?\r\r>", Pid::Rpm), Err(ElmError::Unknown));
        assert_eq!(parse_pid(b"STOPPED\r\r>", Pid::Rpm), Err(ElmError::Stopped));
        assert_eq!(
            parse_pid(b"SEARCHING...\rUNABLE TO CONNECT\r\r>", Pid::Rpm),
            Err(ElmError::UnableToConnect)
        );
        assert!(matches!(
            parse_pid(b"CAN ERROR\r\r>", Pid::Rpm),
            Err(ElmError::Adapter(_))
        ));
        assert!(matches!(
            parse_pid(b"41 0C 1A\r\r>", Pid::Rpm),
            Err(ElmError::Garbled(_))
        ));
    }

    #[test]
    fn several_ecus_the_first_answer_wins_without_headers() {
        let reply = b"010C\r41 0C 1A F8 \r41 0C 00 00 \r\r>";
        assert_eq!(parse_pid(reply, Pid::Rpm), Ok(1726.0));
    }

    #[test]
    fn several_ecus_the_engine_wins_with_headers() {
        let reply = b"7E9 04 41 0C 00 00 \r7E8 04 41 0C 1A F8 \r\r>";
        assert_eq!(parse_pid(reply, Pid::Rpm), Ok(1726.0));
        let reply = b"7E904410C0000\r7E804410C1AF8\r\r>";
        assert_eq!(parse_pid(reply, Pid::Rpm), Ok(1726.0));
        let reply = b"18 DA F1 18 04 41 0C 00 00\r18 DA F1 10 04 41 0C 0F A0\r\r>";
        assert_eq!(parse_pid(reply, Pid::Rpm), Ok(1000.0));
    }

    #[test]
    fn at_replies_and_banner() {
        assert_eq!(parse_ok(b"ATE0\rOK\r\r>", "ATE0"), Ok(()));
        assert_eq!(parse_ok(b"OK\r\r>", "ATH0"), Ok(()));
        assert_eq!(parse_ok(b"ATH0\r?\r\r>", "ATH0"), Err(ElmError::Unknown));
        assert_eq!(
            parse_banner(b"ATZ\r\r\rELM327 v1.5\r\r>"),
            Ok("ELM327 v1.5".to_string())
        );
        assert!(parse_banner(b"\r\r>").is_err());
    }
}
