//! The command protocol: what a planner (or a person with `nc`) sends adrive over UDP,
//! as pure functions on bytes. The listener thread hands each datagram to [`parse`],
//! checks it with [`Auth`](super::auth::Auth) when a key is set, and then applies the
//! commands; nothing here touches a socket, a clock or the heap, so the whole path from
//! socket to serial write stays allocation-free and every rule is tested on bytes.
//!
//! # Grammar
//!
//! A datagram is UTF-8 text of at most [`MAX_DATAGRAM`] bytes: one item per line.
//!
//! ```text
//! datagram = line *( EOL line ) [ EOL ]        EOL = "\n" | "\r\n"
//! line     = [ item ] [ "#" comment ]          blank lines and comments are ignored
//! item     = DEVICE SP value                   any actuator of the vehicle, by name:
//!                                              a number in a setpoint device's range,
//!                                              or a state device's state (or alias)
//!          | "accel" SP number                 -1 … 1: < 0 brakes, > 0 throttle (when
//!                                              throttle and brake are bound)
//!          | "engage" | "disengage"
//!          | "release"                         give command up (the vehicle stays engaged
//!                                              for a handover; see docs/safety.md)
//!          | "clear"                           clear a driver's latched override
//!          | "seq" SP u64                      header: the sender's counter
//!          | "tag" SP 64 hex digits            header: HMAC-SHA256, must be the last line
//! ```
//!
//! - Words are separated by spaces or tabs; leading and trailing blanks are ignored.
//! - Keywords, device names and state names are case-insensitive (`STEER 0.2`,
//!   `trans Drive`). Which devices exist, their ranges and states come from the
//!   vehicle file ([`Vocabulary`]); on the built-in Alice they are `steer -1…1`,
//!   `gas 0…1`, `brake 0…1`, `trans park|reverse|neutral|drive` (also `p r rev n d`
//!   and the paper's `-1 0 1`).
//! - A number is a decimal such as `0.25`, `-1`, `.5`, `+1e-1`. It must be finite and
//!   inside the range above; an out-of-range value is rejected, never clamped.
//! - A datagram holds at least one command and at most [`MAX_COMMANDS`]. Its commands
//!   are applied in order, so the last one for a device wins.
//! - **A datagram is one intent**: if any line is bad, the whole datagram is rejected
//!   and none of its commands is applied.
//! - `seq` may appear once, anywhere before `tag`. Without a key it is optional and
//!   lets adrive notice a sender that is alive but frozen (the same counter again and
//!   again). With a key it is required and must be strictly greater than the last one
//!   accepted from that key, so a captured datagram cannot be replayed.
//! - `tag` may appear once, as the last line (its own line ending may follow, nothing
//!   else). It is the HMAC-SHA256, under the shared key, of **every byte before the
//!   `tag` line**, line endings included, written as 64 hex digits (either case).
//!
//! # Examples with `nc`
//!
//! Without a key, type commands by hand:
//!
//! ```text
//! echo 'steer 0.2' | nc -u -w0 127.0.0.1 47576
//! printf 'engage\ntrans drive\n' | nc -u -w0 127.0.0.1 47576
//! printf 'seq 17\nsteer -0.25\ngas 0.3  # gentle\n' | nc -u -w0 127.0.0.1 47576
//! echo 'accel -0.5' | nc -u -w0 127.0.0.1 47576
//! echo 'disengage' | nc -u -w0 127.0.0.1 47576
//! ```
//!
//! # Signing from a shell
//!
//! With a key file (its text, without surrounding whitespace, is the key — see
//! [`Auth::from_key_file`](super::auth::Auth::from_key_file)), sign with `openssl`.
//! `date +%s%N` gives a counter that grows from one call to the next:
//!
//! ```text
//! openssl rand -hex 32 > adrive.key            # once; give the same file to adrive
//! KEY=$(cat adrive.key)
//! body=$(printf 'seq %s\nsteer 0.2\ngas 0.1' "$(date +%s%N)")
//! tag=$(printf '%s\n' "$body" | openssl dgst -sha256 -hmac "$KEY" | awk '{print $NF}')
//! printf '%s\ntag %s\n' "$body" "$tag" | nc -u -w0 127.0.0.1 47576
//! ```
//!
//! The signed bytes are exactly `seq …\nsteer 0.2\ngas 0.1\n`: `$(…)` drops the final
//! newline of `body`, and both `printf '%s\n'` put it back.
//!
//! # Rejections
//!
//! Every rejected datagram has one [`BadDatagram`] reason, with a stable snake_case name
//! for counters and logs ([`BadDatagram::as_str`]); [`ParseError`] adds the line number and
//! the offending word for a person (`line 2: out_of_range: steer takes -1 to 1 (got
//! "1.5")`). [`BadDatagramCounts`] counts them without locks.

use crate::config::DeviceConfig;
use crate::value::Keyword as Verb;
use crate::value::{Command, DeviceId, Kind};
use arrayvec::{ArrayString, ArrayVec};
use std::fmt;
use std::fmt::Write as _;
use std::ops::Range;
use std::sync::atomic::{AtomicU64, Ordering};

/// The largest datagram accepted, in bytes; a larger one is rejected as `oversized`.
/// Sixteen commands with long numbers, a `seq` and a `tag` fit with room to spare.
pub const MAX_DATAGRAM: usize = 1024;

/// The most commands one datagram may carry; more is `too_many_commands`.
pub(crate) const MAX_COMMANDS: usize = 16;

/// One thing a datagram asks of adrive.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum NetCommand {
    /// A command for one actuator.
    Set(DeviceId, Command),
    /// Combined pedal: below zero brakes, above zero throttle (−1…1).
    Accel(f64),
    /// Let network commands drive the actuators.
    Engage,
    /// Stop taking network commands and bring the vehicle to its safe state.
    Disengage,
    /// Give command up: another source may then take it by engaging.
    Release,
    /// Clear a driver's latched override (refused while a hand is still on it).
    Clear,
}

/// The words a datagram may use on one vehicle: its actuators by name, with their
/// ranges and states, and whether `accel` exists. [`Vocabulary::open`] is for a client
/// that does not know the vehicle (`adrive send`): it checks only the shape of each
/// line, so the vehicle's reply has the last word.
#[derive(Clone, Copy, Debug)]
pub struct Vocabulary<'a> {
    devices: &'a [DeviceConfig],
    accel: bool,
    open: bool,
}

/// The device id an open vocabulary gives every device.
pub(crate) const UNKNOWN: DeviceId = DeviceId(u16::MAX);

impl<'a> Vocabulary<'a> {
    pub fn new(devices: &'a [DeviceConfig], accel: bool) -> Vocabulary<'a> {
        Vocabulary {
            devices,
            accel,
            open: false,
        }
    }

    /// The words of a vehicle.
    pub fn of(config: &'a crate::config::VehicleConfig) -> Vocabulary<'a> {
        Vocabulary::new(&config.devices, config.roles.has_accel())
    }

    /// Any well-formed device line passes (device ids are [`UNKNOWN`]).
    pub fn open() -> Vocabulary<'static> {
        Vocabulary {
            devices: &[],
            accel: true,
            open: true,
        }
    }

    fn find(&self, word: &str) -> Option<(DeviceId, &'a DeviceConfig)> {
        self.devices
            .iter()
            .enumerate()
            .find(|(_, d)| d.name.eq_ignore_ascii_case(word))
            .map(|(i, d)| (DeviceId(i as u16), d))
    }

    /// A command as one protocol line (without its line ending); [`parse`] reads it
    /// back to the same command, exactly (`f64` prints its shortest round-trip form).
    pub fn line(&self, c: &NetCommand) -> String {
        let name = |id: DeviceId| {
            self.devices
                .get(id.index())
                .map_or("?", |d| d.name.as_str())
        };
        match c {
            NetCommand::Set(id, Command::Set(v)) => format!("{} {}", name(*id), Num(*v)),
            NetCommand::Set(id, Command::State(s)) => format!(
                "{} {}",
                name(*id),
                self.devices
                    .get(id.index())
                    .and_then(|d| d.state_name(*s))
                    .unwrap_or("?")
            ),
            NetCommand::Set(id, Command::Control(k)) => format!("{} {k}", name(*id)),
            NetCommand::Accel(v) => format!("accel {}", Num(*v)),
            NetCommand::Engage => "engage".into(),
            NetCommand::Disengage => "disengage".into(),
            NetCommand::Release => "release".into(),
            NetCommand::Clear => "clear".into(),
        }
    }

    /// Whether a word reads as some device's value (a number, or a state or alias of a
    /// state device), which makes an unknown word before it a misspelt device rather
    /// than an unknown command.
    fn looks_like_value(&self, word: &str) -> bool {
        parse_f64(word).is_some()
            || self
                .devices
                .iter()
                .any(|d| d.kind == Kind::State && d.state_index(word).is_some())
    }

    /// The actuators, for messages: `steer, gas, brake and trans`.
    fn names(&self, out: &mut Expected) {
        let mut first = true;
        let n = self.devices.iter().filter(|d| d.is_actuator()).count();
        for (i, d) in self.devices.iter().filter(|d| d.is_actuator()).enumerate() {
            let sep = if first {
                ""
            } else if i + 1 == n {
                " and "
            } else {
                ", "
            };
            first = false;
            if out.try_push_str(sep).is_err() || out.try_push_str(&d.name).is_err() {
                let _ = out.try_push_str("…");
                return;
            }
        }
    }
}

/// A value as the protocol writes it: plain decimal, or scientific for tiny values
/// (`1e-300`), whose plain form would not fit a line. Either way the shortest digits
/// that read back to the same `f64`.
struct Num(f64);

impl fmt::Display for Num {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        if self.0 == 0.0 || self.0.abs() >= 1e-4 || !self.0.is_finite() {
            write!(f, "{}", self.0)
        } else {
            write!(f, "{:e}", self.0)
        }
    }
}

/// The commands of one datagram, in order, without touching the heap.
pub type Commands = ArrayVec<NetCommand, MAX_COMMANDS>;

/// A datagram that follows the grammar. Whether it may be applied (tag, counter,
/// engage state, interlocks) is for the caller to decide.
#[derive(Clone, Debug, PartialEq)]
pub struct Datagram {
    /// The sender's counter (`seq` line), if any.
    pub seq: Option<u64>,
    /// The HMAC-SHA256 tag (`tag` line), if any.
    pub tag: Option<[u8; 32]>,
    /// The bytes the tag covers: everything before the `tag` line (the whole datagram
    /// when there is none), as offsets into the bytes given to [`parse`].
    pub signed: Range<usize>,
    /// The commands, in datagram order; never empty.
    pub commands: Commands,
}

impl Datagram {
    /// The signed part of `bytes`, which must be the bytes this datagram was parsed from.
    #[cfg_attr(not(test), allow(dead_code))]
    pub(crate) fn signed_bytes<'a>(&self, bytes: &'a [u8]) -> &'a [u8] {
        bytes.get(self.signed.clone()).unwrap_or(&[])
    }
}

/// Why a datagram was rejected. Each reason has a stable snake_case name
/// ([`BadDatagram::as_str`]) used by counters, logs and the state broadcast.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum BadDatagram {
    /// No bytes, or no command (only blanks, comments or headers).
    Empty,
    /// Longer than [`MAX_DATAGRAM`].
    Oversized,
    /// Not valid UTF-8.
    NotUtf8,
    /// A control byte other than tab, LF, or CR before LF: binary data.
    Binary,
    /// A line with the wrong number of words (`steer`, `engage now`).
    BadSyntax,
    /// A first word that is no command.
    UnknownVerb,
    /// A name that is not one of the vehicle's devices (`stear 0.2`).
    UnknownDevice,
    /// A device that takes no commands (a sensor such as `estop` or `obd`).
    NotAllowed,
    /// A value that is not a number (or, for a state device, one of its states).
    BadValue,
    /// NaN or infinity, written or by overflow (`1e999`).
    NotFinite,
    /// A number outside the device's range.
    OutOfRange,
    /// More than [`MAX_COMMANDS`] commands.
    TooManyCommands,
    /// A malformed, repeated or misplaced `seq` or `tag` line.
    BadHeader,
    /// A key is set and the datagram has no `seq`.
    MissingSeq,
    /// A key is set and the datagram has no `tag`.
    MissingTag,
    /// The tag does not match the signed bytes under the key.
    BadTag,
    /// The `seq` is not greater than the last one accepted.
    Replayed,
}

impl BadDatagram {
    /// Every reason, in a fixed order: the index of a reason here is its counter slot.
    pub const ALL: [BadDatagram; 17] = [
        BadDatagram::Empty,
        BadDatagram::Oversized,
        BadDatagram::NotUtf8,
        BadDatagram::Binary,
        BadDatagram::BadSyntax,
        BadDatagram::UnknownVerb,
        BadDatagram::UnknownDevice,
        BadDatagram::NotAllowed,
        BadDatagram::BadValue,
        BadDatagram::NotFinite,
        BadDatagram::OutOfRange,
        BadDatagram::TooManyCommands,
        BadDatagram::BadHeader,
        BadDatagram::MissingSeq,
        BadDatagram::MissingTag,
        BadDatagram::BadTag,
        BadDatagram::Replayed,
    ];

    /// The number of reasons.
    pub(crate) const COUNT: usize = BadDatagram::ALL.len();

    /// The stable name, for counters and logs.
    pub fn as_str(self) -> &'static str {
        match self {
            BadDatagram::Empty => "empty",
            BadDatagram::Oversized => "oversized",
            BadDatagram::NotUtf8 => "not_utf8",
            BadDatagram::Binary => "binary",
            BadDatagram::BadSyntax => "bad_syntax",
            BadDatagram::UnknownVerb => "unknown_verb",
            BadDatagram::UnknownDevice => "unknown_device",
            BadDatagram::NotAllowed => "not_allowed",
            BadDatagram::BadValue => "bad_value",
            BadDatagram::NotFinite => "not_finite",
            BadDatagram::OutOfRange => "out_of_range",
            BadDatagram::TooManyCommands => "too_many_commands",
            BadDatagram::BadHeader => "bad_header",
            BadDatagram::MissingSeq => "missing_seq",
            BadDatagram::MissingTag => "missing_tag",
            BadDatagram::BadTag => "bad_tag",
            BadDatagram::Replayed => "replayed",
        }
    }

    /// Its slot in [`BadDatagram::ALL`].
    pub fn index(self) -> usize {
        self as usize
    }

    /// A sentence for a person.
    pub fn describe(self) -> &'static str {
        match self {
            BadDatagram::Empty => "the datagram holds no command",
            BadDatagram::Oversized => "the datagram is over 1024 bytes",
            BadDatagram::NotUtf8 => "the datagram is not UTF-8 text",
            BadDatagram::Binary => "the datagram holds a control byte (binary data)",
            BadDatagram::BadSyntax => "a line has the wrong number of words",
            BadDatagram::UnknownVerb => "a line starts with no known command",
            BadDatagram::UnknownDevice => "a command names an unknown device",
            BadDatagram::NotAllowed => "a command is not allowed",
            BadDatagram::BadValue => "a value is not a number or one of the device's states",
            BadDatagram::NotFinite => "a value is NaN or infinite",
            BadDatagram::OutOfRange => "a value is out of range",
            BadDatagram::TooManyCommands => "the datagram holds more than 16 commands",
            BadDatagram::BadHeader => "a seq or tag line is malformed, repeated or misplaced",
            BadDatagram::MissingSeq => "the datagram has no seq line and a key is set",
            BadDatagram::MissingTag => "the datagram has no tag line and a key is set",
            BadDatagram::BadTag => "the tag does not match the key",
            BadDatagram::Replayed => "the seq is not greater than the last one accepted",
        }
    }
}

impl fmt::Display for BadDatagram {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}: {}", self.as_str(), self.describe())
    }
}

impl std::error::Error for BadDatagram {}

/// A rejection with where and why, for a person: `line 2: out_of_range: steer takes
/// -1 to 1 (got "1.5")`. Built without allocating (the word is copied, truncated).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ParseError {
    /// The reason, for counters.
    pub reason: BadDatagram,
    /// The 1-based line, when one line is at fault.
    pub line: Option<u32>,
    expected: Expected,
    got: Snippet,
}

/// What was expected, in words, inline (no heap).
pub(crate) type Expected = ArrayString<160>;

fn expected(text: &str) -> Expected {
    let mut e = Expected::new();
    for c in text.chars() {
        if e.try_push(c).is_err() {
            break;
        }
    }
    e
}

impl ParseError {
    fn new(reason: BadDatagram, line: Option<u32>, what: &str, got: &str) -> Self {
        ParseError {
            reason,
            line,
            expected: expected(what),
            got: Snippet::new(got),
        }
    }

    fn with(reason: BadDatagram, line: Option<u32>, what: Expected, got: &str) -> Self {
        ParseError {
            reason,
            line,
            expected: what,
            got: Snippet::new(got),
        }
    }

    /// The offending word, possibly truncated; empty when there is none.
    pub fn got(&self) -> &str {
        self.got.as_str()
    }
}

impl From<ParseError> for BadDatagram {
    fn from(e: ParseError) -> BadDatagram {
        e.reason
    }
}

impl fmt::Display for ParseError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        if let Some(line) = self.line {
            write!(f, "line {line}: ")?;
        }
        write!(f, "{}: {}", self.reason.as_str(), self.expected.as_str())?;
        if !self.got.as_str().is_empty() {
            write!(f, " (got \"{}", self.got.as_str().escape_debug())?;
            if self.got.truncated {
                f.write_str("…")?;
            }
            f.write_str("\")")?;
        }
        Ok(())
    }
}

impl std::error::Error for ParseError {}

/// A short inline copy of the offending word.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
struct Snippet {
    buf: [u8; Snippet::CAP],
    len: u8,
    truncated: bool,
}

impl Snippet {
    const CAP: usize = 24;

    fn new(s: &str) -> Self {
        let mut len = s.len().min(Self::CAP);
        while !s.is_char_boundary(len) {
            len -= 1;
        }
        let mut buf = [0; Self::CAP];
        buf[..len].copy_from_slice(&s.as_bytes()[..len]);
        Snippet {
            buf,
            len: len as u8,
            truncated: len < s.len(),
        }
    }

    fn as_str(&self) -> &str {
        // Cut at a char boundary of a &str in `new`, so always valid.
        std::str::from_utf8(&self.buf[..self.len as usize]).unwrap_or("")
    }
}

/// Reads one datagram against a vehicle's words. Allocation-free; never panics,
/// whatever the bytes.
pub fn parse(bytes: &[u8], vocab: &Vocabulary) -> Result<Datagram, ParseError> {
    if bytes.is_empty() {
        return Err(ParseError::new(
            BadDatagram::Empty,
            None,
            "the datagram is empty",
            "",
        ));
    }
    if bytes.len() > MAX_DATAGRAM {
        return Err(ParseError::new(
            BadDatagram::Oversized,
            None,
            "a datagram holds at most 1024 bytes",
            "",
        ));
    }
    if let Some(at) = bytes.iter().position(|&b| is_binary(b)) {
        return Err(ParseError::new(
            BadDatagram::Binary,
            Some(line_of(bytes, at)),
            "text only: control bytes other than tab and line endings are not allowed",
            "",
        ));
    }
    let text = match std::str::from_utf8(bytes) {
        Ok(text) => text,
        Err(e) => {
            return Err(ParseError::new(
                BadDatagram::NotUtf8,
                Some(line_of(bytes, e.valid_up_to())),
                "the datagram must be UTF-8 text",
                "",
            ))
        }
    };

    let mut datagram = Datagram {
        seq: None,
        tag: None,
        signed: 0..bytes.len(),
        commands: Commands::new(),
    };
    let mut start = 0;
    let mut line_no = 0u32;
    while start < text.len() {
        let (raw, next) = match text[start..].find('\n') {
            Some(i) => (&text[start..start + i], start + i + 1),
            None => (&text[start..], text.len()),
        };
        line_no += 1;
        let line = Some(line_no);
        if datagram.tag.is_some() {
            return Err(ParseError::new(
                BadDatagram::BadHeader,
                line,
                "the tag line must be the last line",
                raw,
            ));
        }
        let content = raw.strip_suffix('\r').unwrap_or(raw);
        if content.contains('\r') {
            return Err(ParseError::new(
                BadDatagram::Binary,
                line,
                "a carriage return may only end a line (CR LF)",
                "",
            ));
        }
        let content = content.split('#').next().unwrap_or("");
        let mut words = content.split_ascii_whitespace();
        let Some(verb) = words.next() else {
            start = next;
            continue;
        };
        let arg = words.next();
        let extra = words.next();
        let one_arg = |usage: &'static str| match (arg, extra) {
            (Some(a), None) => Ok(a),
            (None, _) => Err(ParseError::new(BadDatagram::BadSyntax, line, usage, verb)),
            (Some(_), Some(x)) => Err(ParseError::new(BadDatagram::BadSyntax, line, usage, x)),
        };

        let command = match Verb::from_word(verb) {
            Some(Verb::Seq) => {
                let a =
                    one_arg("seq takes one counter (0 to 18446744073709551615)").map_err(|e| {
                        ParseError {
                            reason: BadDatagram::BadHeader,
                            ..e
                        }
                    })?;
                if datagram.seq.is_some() {
                    return Err(ParseError::new(
                        BadDatagram::BadHeader,
                        line,
                        "only one seq line is allowed",
                        a,
                    ));
                }
                datagram.seq = Some(parse_seq(a).ok_or_else(|| {
                    ParseError::new(
                        BadDatagram::BadHeader,
                        line,
                        "seq takes a decimal counter from 0 to 18446744073709551615",
                        a,
                    )
                })?);
                None
            }
            Some(Verb::Tag) => {
                let a = one_arg("tag takes 64 hex digits").map_err(|e| ParseError {
                    reason: BadDatagram::BadHeader,
                    ..e
                })?;
                datagram.tag = Some(parse_hex32(a).ok_or_else(|| {
                    ParseError::new(BadDatagram::BadHeader, line, "tag takes 64 hex digits", a)
                })?);
                datagram.signed = 0..start;
                None
            }
            Some(k) if !k.takes_value() && arg.is_some() => {
                let mut e = Expected::new();
                let _ = Verb::list(|k| !k.takes_value(), " and ", &mut e);
                let _ = e.try_push_str(" take no value");
                return Err(ParseError::with(
                    BadDatagram::BadSyntax,
                    line,
                    e,
                    arg.unwrap_or(""),
                ));
            }
            Some(Verb::Engage) => Some(NetCommand::Engage),
            Some(Verb::Disengage) => Some(NetCommand::Disengage),
            Some(Verb::Release) => Some(NetCommand::Release),
            Some(Verb::Clear) => Some(NetCommand::Clear),
            Some(Verb::Accel) if !vocab.accel => {
                return Err(ParseError::new(
                    BadDatagram::UnknownVerb,
                    line,
                    "this vehicle has no accel (it needs throttle and brake bound)",
                    verb,
                ))
            }
            Some(Verb::Accel) => {
                let a = one_arg("accel takes one value from -1 to 1")?;
                Some(NetCommand::Accel(number(a, -1.0, 1.0, line, || {
                    expected("accel takes -1 to 1")
                })?))
            }
            None => Some(device_line(vocab, verb, arg, extra, line)?),
        };
        if let Some(command) = command {
            if datagram.commands.try_push(command).is_err() {
                return Err(ParseError::new(
                    BadDatagram::TooManyCommands,
                    line,
                    "a datagram holds at most 16 commands",
                    "",
                ));
            }
        }
        start = next;
    }
    if datagram.commands.is_empty() {
        return Err(ParseError::new(
            BadDatagram::Empty,
            None,
            "the datagram holds no command",
            "",
        ));
    }
    Ok(datagram)
}

/// A line that names a device: `DEVICE VALUE`.
fn device_line(
    vocab: &Vocabulary,
    verb: &str,
    arg: Option<&str>,
    extra: Option<&str>,
    line: Option<u32>,
) -> Result<NetCommand, ParseError> {
    let usage = |what: &str| {
        let mut e = Expected::new();
        let _ = write!(e, "{what} takes one value");
        e
    };
    let Some((id, d)) = vocab.find(verb) else {
        if vocab.open
            && crate::config::device::check_name("device", &verb.to_ascii_lowercase()).is_ok()
        {
            return match (arg, extra) {
                (Some(a), None) => {
                    let v = parse_f64(a);
                    if v.is_some_and(|v| !v.is_finite()) {
                        return Err(ParseError::new(
                            BadDatagram::NotFinite,
                            line,
                            "a finite number",
                            a,
                        ));
                    }
                    Ok(NetCommand::Set(
                        UNKNOWN,
                        v.map_or(Command::State(0), Command::Set),
                    ))
                }
                (None, _) => Err(ParseError::with(
                    BadDatagram::BadSyntax,
                    line,
                    usage(verb),
                    verb,
                )),
                (Some(_), Some(x)) => Err(ParseError::with(
                    BadDatagram::BadSyntax,
                    line,
                    usage(verb),
                    x,
                )),
            };
        }
        let mut e = Expected::new();
        let actuators = vocab.devices.iter().any(|d| d.is_actuator());
        let reason = if !vocab.open
            && actuators
            && extra.is_none()
            && arg.is_some_and(|a| vocab.looks_like_value(a))
        {
            let _ = e.try_push_str("the devices are ");
            vocab.names(&mut e);
            BadDatagram::UnknownDevice
        } else {
            if vocab.open {
                // A client that does not know the vehicle has no devices to list: the
                // word is no name a device may have.
                let _ = e.try_push_str(
                    "a line is a device (lowercase letters, digits and _) and a value, separated by a space (steer 0.2), or ",
                );
            } else if actuators {
                let _ = e.try_push_str("a line is a device and a value (");
                vocab.names(&mut e);
                let _ = e.try_push_str("), or ");
            } else {
                let _ = e.try_push_str("no device of this vehicle takes commands; a line is ");
            }
            let _ = Verb::list(|_| true, " or ", &mut e);
            BadDatagram::UnknownVerb
        };
        return Err(ParseError::with(reason, line, e, verb));
    };
    let a = match (arg, extra) {
        (Some(a), None) => a,
        (None, _) => {
            return Err(ParseError::with(
                BadDatagram::BadSyntax,
                line,
                usage(&d.name),
                verb,
            ))
        }
        (Some(_), Some(x)) => {
            return Err(ParseError::with(
                BadDatagram::BadSyntax,
                line,
                usage(&d.name),
                x,
            ))
        }
    };
    match d.kind {
        Kind::Sensor => {
            let mut e = Expected::new();
            let _ = write!(e, "{} is a sensor: it takes no commands", d.name);
            Err(ParseError::with(BadDatagram::NotAllowed, line, e, verb))
        }
        Kind::Setpoint => {
            let [lo, hi] = d.range;
            let range = || {
                let mut e = Expected::new();
                let _ = write!(e, "{} takes {lo} to {hi}", d.name);
                e
            };
            Ok(NetCommand::Set(
                id,
                Command::Set(number(a, lo, hi, line, range)?),
            ))
        }
        Kind::State => {
            if let Some(s) = d.state_index(a) {
                return Ok(NetCommand::Set(id, Command::State(s)));
            }
            let mut e = Expected::new();
            let _ = write!(e, "{} takes ", d.name);
            for (i, st) in d.states.iter().enumerate() {
                let sep = if i == 0 { "" } else { ", " };
                if e.try_push_str(sep).is_err() || e.try_push_str(st).is_err() {
                    let _ = e.try_push_str("…");
                    break;
                }
            }
            let reason = match parse_f64(a) {
                Some(v) if !v.is_finite() => BadDatagram::NotFinite,
                Some(_) => BadDatagram::OutOfRange,
                None => BadDatagram::BadValue,
            };
            Err(ParseError::with(reason, line, e, a))
        }
    }
}

/// A control byte other than tab, LF and CR (CR is checked per line), or DEL.
fn is_binary(b: u8) -> bool {
    (b < 0x20 && !matches!(b, b'\t' | b'\n' | b'\r')) || b == 0x7f
}

/// The 1-based line that byte `at` sits on.
fn line_of(bytes: &[u8], at: usize) -> u32 {
    let newlines = bytes[..at.min(bytes.len())]
        .iter()
        .filter(|&&b| b == b'\n')
        .count();
    u32::try_from(newlines).map_or(u32::MAX, |n| n.saturating_add(1))
}

fn parse_f64(word: &str) -> Option<f64> {
    word.parse::<f64>().ok()
}

/// A finite number inside `lo..=hi`. `range` says so in words, built only for a
/// refusal: formatting two numbers costs more than the rest of a datagram's parse.
fn number(
    word: &str,
    lo: f64,
    hi: f64,
    line: Option<u32>,
    range: impl FnOnce() -> Expected,
) -> Result<f64, ParseError> {
    let v = parse_f64(word).ok_or_else(|| {
        ParseError::new(
            BadDatagram::BadValue,
            line,
            "a decimal number such as 0.25",
            word,
        )
    })?;
    if !v.is_finite() {
        return Err(ParseError::new(
            BadDatagram::NotFinite,
            line,
            "a finite number",
            word,
        ));
    }
    if !(lo..=hi).contains(&v) {
        return Err(ParseError::with(
            BadDatagram::OutOfRange,
            line,
            range(),
            word,
        ));
    }
    Ok(v)
}

/// Decimal digits only (no sign), within u64.
fn parse_seq(word: &str) -> Option<u64> {
    if word.is_empty() || !word.bytes().all(|b| b.is_ascii_digit()) {
        return None;
    }
    word.parse().ok()
}

/// Exactly 64 hex digits, either case.
pub(crate) fn parse_hex32(word: &str) -> Option<[u8; 32]> {
    let bytes = word.as_bytes();
    if bytes.len() != 64 {
        return None;
    }
    let mut out = [0u8; 32];
    for (o, pair) in out.iter_mut().zip(bytes.chunks_exact(2)) {
        *o = (hex_digit(pair[0])? << 4) | hex_digit(pair[1])?;
    }
    Some(out)
}

pub(crate) fn hex_digit(b: u8) -> Option<u8> {
    match b {
        b'0'..=b'9' => Some(b - b'0'),
        b'a'..=b'f' => Some(b - b'a' + 10),
        b'A'..=b'F' => Some(b - b'A' + 10),
        _ => None,
    }
}

/// Rejected datagrams by reason, lock-free: the listener counts, the console and the
/// state broadcast read.
#[derive(Debug)]
pub struct BadDatagramCounts([AtomicU64; BadDatagram::COUNT]);

impl BadDatagramCounts {
    pub const fn new() -> Self {
        BadDatagramCounts([const { AtomicU64::new(0) }; BadDatagram::COUNT])
    }

    pub fn incr(&self, reason: BadDatagram) {
        self.0[reason.index()].fetch_add(1, Ordering::Relaxed);
    }

    pub fn get(&self, reason: BadDatagram) -> u64 {
        self.0[reason.index()].load(Ordering::Relaxed)
    }

    /// Every datagram rejected, for any reason.
    pub fn total(&self) -> u64 {
        self.0.iter().map(|c| c.load(Ordering::Relaxed)).sum()
    }

    /// `(name, count)` for every reason, in [`BadDatagram::ALL`] order, zeros included.
    pub fn iter(&self) -> impl Iterator<Item = (&'static str, u64)> + '_ {
        BadDatagram::ALL
            .into_iter()
            .map(|r| (r.as_str(), self.get(r)))
    }
}

impl Default for BadDatagramCounts {
    fn default() -> Self {
        Self::new()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::VehicleConfig;
    use std::sync::LazyLock;

    static ALICE: LazyLock<VehicleConfig> = LazyLock::new(VehicleConfig::alice);

    pub(crate) fn alice() -> Vocabulary<'static> {
        Vocabulary::of(&ALICE)
    }

    fn parse(bytes: &[u8]) -> Result<Datagram, ParseError> {
        super::parse(bytes, &alice())
    }

    fn ok(text: &str) -> Datagram {
        parse(text.as_bytes()).unwrap_or_else(|e| panic!("{text:?} rejected: {e}"))
    }

    fn reason(bytes: &[u8]) -> BadDatagram {
        match parse(bytes) {
            Ok(d) => panic!("{:?} accepted as {d:?}", String::from_utf8_lossy(bytes)),
            Err(e) => e.reason,
        }
    }

    fn id(name: &str) -> DeviceId {
        DeviceId(ALICE.devices.iter().position(|d| d.name == name).unwrap() as u16)
    }

    fn set(name: &str, v: f64) -> NetCommand {
        NetCommand::Set(id(name), Command::Set(v))
    }

    fn state(name: &str, s: &str) -> NetCommand {
        let d = ALICE.device(name).unwrap();
        NetCommand::Set(id(name), Command::State(d.state_index(s).unwrap()))
    }

    #[test]
    fn one_command_typed_by_hand() {
        let d = ok("steer 0.2\n");
        assert_eq!(d.commands.as_slice(), [set("steer", 0.2)]);
        assert_eq!(d.seq, None);
        assert_eq!(d.tag, None);
        assert_eq!(d.signed, 0..10);
        // `echo -n` and the last line without a newline.
        assert_eq!(ok("steer 0.2").commands.as_slice(), [set("steer", 0.2)]);
    }

    #[test]
    fn several_lines_keep_their_order() {
        let d = ok("seq 9\nengage\nsteer -0.25\ngas 0.3\nbrake 1\naccel -0.5\ntrans drive\n");
        assert_eq!(d.seq, Some(9));
        assert_eq!(
            d.commands.as_slice(),
            [
                NetCommand::Engage,
                set("steer", -0.25),
                set("gas", 0.3),
                set("brake", 1.0),
                NetCommand::Accel(-0.5),
                state("trans", "drive"),
            ]
        );
        assert_eq!(ok("disengage").commands.as_slice(), [NetCommand::Disengage]);
    }

    #[test]
    fn crlf_blanks_comments_case_and_tabs() {
        let d = ok("# planner v2\r\n\r\n  STEER\t-1  \r\nGas 0 # coast\r\n\r\n");
        assert_eq!(d.commands.as_slice(), [set("steer", -1.0), set("gas", 0.0)]);
    }

    #[test]
    fn gears_by_name_short_form_and_paper_code() {
        for (word, gear) in [
            ("park", "park"),
            ("P", "park"),
            ("0", "park"),
            ("Reverse", "reverse"),
            ("-1", "reverse"),
            ("neutral", "neutral"),
            ("n", "neutral"),
            ("DRIVE", "drive"),
            ("1", "drive"),
        ] {
            let d = ok(&format!("trans {word}"));
            assert_eq!(d.commands.as_slice(), [state("trans", gear)], "{word}");
        }
        assert_eq!(reason(b"trans 2"), BadDatagram::OutOfRange);
        assert_eq!(reason(b"trans sport"), BadDatagram::BadValue);
        assert_eq!(reason(b"trans nan"), BadDatagram::NotFinite);
    }

    #[test]
    fn range_edges_are_inclusive_and_never_clamped() {
        ok("steer -1\nsteer 1\ngas 0\ngas 1\nbrake 0\nbrake 1\naccel -1\naccel 1");
        for bad in [
            "steer 1.0001",
            "steer -1.5",
            "gas -0.1",
            "gas 1.01",
            "brake 2",
            "brake -1",
            "accel 1.5",
        ] {
            assert_eq!(reason(bad.as_bytes()), BadDatagram::OutOfRange, "{bad}");
        }
    }

    #[test]
    fn every_reject_reason_from_bytes() {
        let cases: &[(&[u8], BadDatagram)] = &[
            (b"", BadDatagram::Empty),
            (b"\n# nothing to do\n  \n", BadDatagram::Empty),
            (b"seq 4\n", BadDatagram::Empty),
            (&[b' '; MAX_DATAGRAM + 1], BadDatagram::Oversized),
            (b"steer 0.\xff2", BadDatagram::NotUtf8),
            (b"\xc3\x28", BadDatagram::NotUtf8),
            (b"steer 0\x002", BadDatagram::Binary),
            (b"\x1b[A", BadDatagram::Binary),
            (b"steer 0.2\rgas 0", BadDatagram::Binary),
            (b"steer", BadDatagram::BadSyntax),
            (b"steer 0.1 0.2", BadDatagram::BadSyntax),
            (b"engage now", BadDatagram::BadSyntax),
            (b"hello", BadDatagram::UnknownVerb),
            (b"set steer 0.2", BadDatagram::UnknownVerb),
            (b"stear 0.2", BadDatagram::UnknownDevice),
            (b"gear drive", BadDatagram::UnknownDevice),
            (b"wiper 0.5", BadDatagram::UnknownDevice),
            (b"estop 1", BadDatagram::NotAllowed),
            (b"obd 0", BadDatagram::NotAllowed),
            (b"steer left", BadDatagram::BadValue),
            (b"gas 0x1", BadDatagram::BadValue),
            (b"steer NaN", BadDatagram::NotFinite),
            (b"gas inf", BadDatagram::NotFinite),
            (b"brake -infinity", BadDatagram::NotFinite),
            (b"accel 1e999", BadDatagram::NotFinite),
            (b"steer 1.5", BadDatagram::OutOfRange),
            (b"seq -1\nsteer 0", BadDatagram::BadHeader),
            (b"seq 1\nseq 2\nsteer 0", BadDatagram::BadHeader),
            (b"seq 18446744073709551616\nsteer 0", BadDatagram::BadHeader),
            (b"steer 0\ntag 00", BadDatagram::BadHeader),
            (b"steer 0\ntag abc", BadDatagram::BadHeader),
        ];
        for (bytes, want) in cases {
            assert_eq!(reason(bytes), *want, "{:?}", String::from_utf8_lossy(bytes));
        }
        let many = "gas 0\n".repeat(MAX_COMMANDS + 1);
        assert_eq!(reason(many.as_bytes()), BadDatagram::TooManyCommands);
        ok(&"gas 0\n".repeat(MAX_COMMANDS));
    }

    #[test]
    fn one_bad_line_rejects_the_whole_datagram() {
        let err = parse(b"steer 0.2\ngas 0.3\nbrake 7\n").unwrap_err();
        assert_eq!(err.reason, BadDatagram::OutOfRange);
        assert_eq!(err.line, Some(3));
    }

    #[test]
    fn largest_datagram_is_accepted() {
        let mut text = "steer 0.5\n".to_string();
        text.push_str(&"#".repeat(MAX_DATAGRAM - text.len()));
        assert_eq!(text.len(), MAX_DATAGRAM);
        ok(&text);
    }

    #[test]
    fn tag_covers_every_byte_before_its_line() {
        let tag = "ab".repeat(32);
        let text = format!("seq 3\r\nsteer 0.2\r\ntag {tag}\r\n");
        let d = ok(&text);
        assert_eq!(d.tag, Some([0xab; 32]));
        assert_eq!(d.seq, Some(3));
        assert_eq!(d.signed_bytes(text.as_bytes()), b"seq 3\r\nsteer 0.2\r\n");
        let upper = format!("steer 0.2\ntag {}", tag.to_uppercase());
        assert_eq!(ok(&upper).tag, Some([0xab; 32]));
    }

    #[test]
    fn nothing_may_follow_the_tag_line() {
        let tag = "00".repeat(32);
        for text in [
            format!("tag {tag}\nsteer 0.2\n"),
            format!("steer 0.2\ntag {tag}\n# note\n"),
            format!("steer 0.2\ntag {tag}\n\n"),
            format!("steer 0.2\ntag {tag}\ntag {tag}"),
        ] {
            assert_eq!(reason(text.as_bytes()), BadDatagram::BadHeader, "{text:?}");
        }
    }

    #[test]
    fn error_names_line_reason_and_word() {
        let err = parse(b"steer 0.2\n\nsteer 1.5\n").unwrap_err();
        assert_eq!(
            err.to_string(),
            "line 3: out_of_range: steer takes -1 to 1 (got \"1.5\")"
        );
        let err = parse(b"stear 0.2").unwrap_err();
        assert_eq!(
            err.to_string(),
            "line 1: unknown_device: the devices are steer, gas, brake and trans (got \"stear\")"
        );
        let long = format!("{} 1", "x".repeat(100));
        let err = parse(long.as_bytes()).unwrap_err();
        assert_eq!(err.got(), "x".repeat(24));
        assert!(err.to_string().ends_with("…\")"), "{err}");
        assert_eq!(
            parse(b"").unwrap_err().to_string(),
            "empty: the datagram is empty"
        );
    }

    /// The incident: `adrive send bogus-verb 1` said "the devices are  (got …)" with
    /// an empty list, and an unknown first word was told the keywords without `release`
    /// and `clear`. The keywords come from the one list that defines them, and a list
    /// that would be empty is not offered.
    #[test]
    fn an_unknown_first_word_is_told_every_keyword_and_no_empty_list() {
        let every = "accel, engage, disengage, release, clear, seq or tag";
        let e = super::parse(b"bogus-verb 1", &Vocabulary::open()).unwrap_err();
        assert_eq!(e.reason, BadDatagram::UnknownVerb);
        assert_eq!(
            e.to_string(),
            format!("line 1: unknown_verb: a line is a device (lowercase letters, digits and _) and a value, separated by a space (steer 0.2), or {every} (got \"bogus-verb\")")
        );
        let e = parse(b"wobble on now").unwrap_err();
        assert_eq!(
            e.to_string(),
            format!("line 1: unknown_verb: a line is a device and a value (steer, gas, brake and trans), or {every} (got \"wobble\")")
        );
        let sensors = crate::config::parse(
            "[vehicle]\nname = \"s\"\n[[device]]\nname = \"obd\"\nkind = \"sensor\"\ndriver = \"line\"\nreadings = [\"rpm\"]\n",
            "s.toml",
        )
        .unwrap();
        let e = super::parse(b"stear 0.2", &Vocabulary::of(&sensors)).unwrap_err();
        assert_eq!(
            e.to_string(),
            format!("line 1: unknown_verb: no device of this vehicle takes commands; a line is {every} (got \"stear\")")
        );
        let e = parse(b"release now").unwrap_err();
        assert_eq!(
            e.to_string(),
            "line 1: bad_syntax: engage, disengage, release and clear take no value (got \"now\")"
        );
        for k in crate::value::Keyword::ALL {
            assert!(
                crate::config::device::check_name("device", k.word()).is_err(),
                "a device may be named {}",
                k.word()
            );
        }
    }

    #[test]
    fn messages_quote_the_limits_in_force() {
        assert!(BadDatagram::Oversized
            .describe()
            .contains(&MAX_DATAGRAM.to_string()));
        assert!(BadDatagram::TooManyCommands
            .describe()
            .contains(&MAX_COMMANDS.to_string()));
        let err = parse(&[b'#'; MAX_DATAGRAM + 1]).unwrap_err();
        assert!(err.to_string().contains(&MAX_DATAGRAM.to_string()));
    }

    #[test]
    fn reject_names_are_distinct_snake_case_and_indexed() {
        for (i, r) in BadDatagram::ALL.into_iter().enumerate() {
            assert_eq!(r.index(), i);
            assert!(r
                .as_str()
                .bytes()
                .all(|b| b.is_ascii_lowercase() || b.is_ascii_digit() || b == b'_'));
            assert_eq!(
                BadDatagram::ALL
                    .iter()
                    .filter(|o| o.as_str() == r.as_str())
                    .count(),
                1
            );
        }
    }

    #[test]
    fn reject_counts_by_reason() {
        static COUNTS: BadDatagramCounts = BadDatagramCounts::new();
        COUNTS.incr(BadDatagram::BadTag);
        COUNTS.incr(BadDatagram::BadTag);
        COUNTS.incr(BadDatagram::Binary);
        assert_eq!(COUNTS.get(BadDatagram::BadTag), 2);
        assert_eq!(COUNTS.get(BadDatagram::Replayed), 0);
        assert_eq!(COUNTS.total(), 3);
        let all: Vec<_> = COUNTS.iter().collect();
        assert_eq!(all.len(), BadDatagram::COUNT);
        assert!(all.contains(&("bad_tag", 2)));
        assert!(all.contains(&("binary", 1)));
    }

    #[test]
    fn commands_print_as_lines_that_parse_back() {
        let cmds = [
            set("steer", -0.25),
            set("gas", 1e-7),
            set("brake", 1.0),
            NetCommand::Accel(-0.0),
            state("trans", "reverse"),
            NetCommand::Engage,
            NetCommand::Disengage,
            NetCommand::Clear,
            NetCommand::Release,
        ];
        let v = alice();
        let text: String = cmds.iter().map(|c| format!("{}\n", v.line(c))).collect();
        assert_eq!(ok(&text).commands.as_slice(), cmds);
        assert_eq!(v.line(&set("steer", -0.25)), "steer -0.25");
        assert_eq!(v.line(&set("gas", 1e-300)), "gas 1e-300");
        assert_eq!(v.line(&NetCommand::Accel(-0.0)), "accel -0");
    }

    #[test]
    fn any_device_by_name_with_its_own_range_and_states() {
        let cart = crate::config::parse(
            "[vehicle]\nname = \"c\"\n[[device]]\nname = \"wiper\"\nkind = \"setpoint\"\nrange = [0.0, 100.0]\nunits = \"%\"\ndriver = \"line\"\n[[device]]\nname = \"signal\"\nkind = \"state\"\nstates = [\"off\", \"left\", \"right\", \"hazard\"]\ndriver = \"line\"\n",
            "c.toml",
        )
        .unwrap();
        let v = Vocabulary::of(&cart);
        let d = super::parse(b"wiper 50\nSIGNAL left\n", &v).unwrap();
        assert_eq!(
            d.commands.as_slice(),
            [
                NetCommand::Set(DeviceId(0), Command::Set(50.0)),
                NetCommand::Set(DeviceId(1), Command::State(1))
            ]
        );
        let e = super::parse(b"wiper 101", &v).unwrap_err();
        assert_eq!(
            e.to_string(),
            "line 1: out_of_range: wiper takes 0 to 100 (got \"101\")"
        );
        let e = super::parse(b"signal up", &v).unwrap_err();
        assert_eq!(e.reason, BadDatagram::BadValue);
        assert!(e.to_string().contains("off, left, right, hazard"), "{e}");
        let e = super::parse(b"accel 0.1", &v).unwrap_err();
        assert_eq!(
            e.reason,
            BadDatagram::UnknownVerb,
            "no accel without throttle and brake"
        );
        // A client that does not know the vehicle checks the shape alone.
        assert!(super::parse(b"horn on\nwiper 0.5", &Vocabulary::open()).is_ok());
        assert_eq!(
            super::parse(b"horn", &Vocabulary::open())
                .unwrap_err()
                .reason,
            BadDatagram::BadSyntax
        );
    }

    /// `adrive send steer=0.2` answered "a line is a device and a value (), accel, …":
    /// the client knows no devices to list, so the brackets were empty.
    #[test]
    fn a_line_sent_without_the_vehicle_shows_the_form_not_empty_brackets() {
        let e = super::parse(b"steer=0.2", &Vocabulary::open()).unwrap_err();
        let s = e.to_string();
        assert!(!s.contains("()"), "{s}");
        assert!(
            s.contains("and a value, separated by a space (steer 0.2)"),
            "{s}"
        );
    }

    mod props {
        use super::*;
        use crate::net::auth::Auth;
        use crate::net::fuzzing::{exercise, FUZZ_KEY};
        use proptest::prelude::*;
        use proptest::sample::select;

        /// Any value in 0…1, tiny and edge values included; callers add a sign.
        fn magnitude() -> impl Strategy<Value = f64> {
            prop_oneof![
                0.0..=1.0,
                select(vec![0.0, 1.0, 1e-300, 5e-324, 1e-4, 0.1, 1.0 / 3.0]),
                (prop::num::f64::NORMAL | prop::num::f64::SUBNORMAL)
                    .prop_map(f64::abs)
                    .prop_filter("at most 1", |v| *v <= 1.0),
            ]
        }

        fn signed_value() -> impl Strategy<Value = f64> {
            (magnitude(), any::<bool>()).prop_map(|(v, neg)| if neg { -v } else { v })
        }

        fn command() -> impl Strategy<Value = NetCommand> {
            prop_oneof![
                signed_value().prop_map(|v| set("steer", v)),
                magnitude().prop_map(|v| set("gas", v)),
                magnitude().prop_map(|v| set("brake", v)),
                signed_value().prop_map(NetCommand::Accel),
                select(vec!["park", "reverse", "neutral", "drive"]).prop_map(|g| state("trans", g)),
                Just(NetCommand::Engage),
                Just(NetCommand::Disengage),
                Just(NetCommand::Clear),
                Just(NetCommand::Release),
            ]
        }

        /// How a sender might lay out one line around the words `c` prints as.
        #[derive(Debug, Clone)]
        struct Layout {
            indent: &'static str,
            gap: &'static str,
            upper: bool,
            comment: bool,
            crlf: bool,
        }

        fn layout() -> impl Strategy<Value = Layout> {
            (
                select(vec!["", " ", "\t", " \t "]),
                select(vec![" ", "\t", "   ", " \t"]),
                any::<bool>(),
                any::<bool>(),
                any::<bool>(),
            )
                .prop_map(|(indent, gap, upper, comment, crlf)| Layout {
                    indent,
                    gap,
                    upper,
                    comment,
                    crlf,
                })
        }

        fn render(c: &NetCommand, l: &Layout) -> String {
            let mut line = alice().line(c).replace(' ', l.gap);
            if l.upper {
                line = line.to_uppercase();
            }
            let comment = if l.comment { " # note" } else { "" };
            let eol = if l.crlf { "\r\n" } else { "\n" };
            format!("{}{line}{comment}{eol}", l.indent)
        }

        /// Words and shapes the grammar cares about, to reach past the first check.
        fn protocol_text() -> impl Strategy<Value = Vec<u8>> {
            let word = prop_oneof![
                select(crate::net::fuzzing::DICTIONARY.to_vec()).prop_map(String::from),
                "[ -~]{0,12}",
                "[0-9a-fA-F]{64}",
            ];
            let sep = select(vec![" ", "\t", "\n", "\r\n", "\r", "  "]);
            prop::collection::vec((word, sep), 0..40).prop_map(|parts| {
                parts
                    .into_iter()
                    .flat_map(|(w, s)| [w, s.to_string()])
                    .collect::<String>()
                    .into_bytes()
            })
        }

        proptest! {
            #[test]
            fn parse_never_panics_on_any_bytes(
                bytes in prop::collection::vec(any::<u8>(), 0..MAX_DATAGRAM + 64)
            ) {
                let _ = exercise(&bytes);
            }

            #[test]
            fn parse_never_panics_on_protocol_like_text(bytes in protocol_text()) {
                let _ = exercise(&bytes);
            }

            #[test]
            fn formatted_commands_parse_back(
                lines in prop::collection::vec((command(), layout()), 1..=MAX_COMMANDS),
                seq in prop::option::of(any::<u64>()),
            ) {
                let mut text = seq.map(|s| format!("seq {s}\n")).unwrap_or_default();
                for (c, l) in &lines {
                    text.push_str(&render(c, l));
                }
                prop_assert!(text.len() <= MAX_DATAGRAM, "{} bytes", text.len());
                let d = parse(text.as_bytes()).map_err(|e| {
                    TestCaseError::fail(format!("{text:?}: {e}"))
                })?;
                let want: Vec<NetCommand> = lines.iter().map(|(c, _)| *c).collect();
                prop_assert_eq!(d.commands.as_slice(), want.as_slice());
                prop_assert_eq!(d.seq, seq);
                prop_assert_eq!(exercise(text.as_bytes()), Ok(d));
            }

            #[test]
            fn signed_commands_verify_and_parse_back(
                cmds in prop::collection::vec(command(), 1..=MAX_COMMANDS),
                seq in any::<u64>(),
            ) {
                let auth = Auth::from_key_bytes(FUZZ_KEY).unwrap();
                let body: String = cmds.iter().map(|c| format!("{}\n", alice().line(c))).collect();
                let text = auth.sign(&body, seq);
                let d = parse(text.as_bytes()).unwrap();
                prop_assert_eq!(d.commands.as_slice(), cmds.as_slice());
                prop_assert_eq!(auth.verify(&d, text.as_bytes(), seq.checked_sub(1)), Ok(()));
            }
        }
    }
}
