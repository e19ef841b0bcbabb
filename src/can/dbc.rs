//! A DBC file as adrive uses it: messages by name and identifier, and their signals
//! decoded from and encoded into a frame's bytes.
//!
//! The file is parsed by the `can-dbc` crate; this module turns its syntax tree into
//! what a bus reader and a command thread need without a second look: each signal's
//! bits, byte order, signedness, IEEE float type (`SIG_VALTYPE_ … : 1`, as OSCC's
//! pedal and torque requests are), scaling, range, value table (a kit's fault codes by
//! name) and start value (`GenSigStartValue`: the magic bytes a kit wants in every
//! frame), and each message's cycle time (`GenMsgCycleTime`). A rolling counter and a
//! checksum that a kit checks are filled in by a [`Sequence`].
//!
//! An error names the file and the line, as the vehicle file's do: a syntax error at
//! the parser's position, a signal that does not fit its message at the signal's line.

use super::{Frame, Id};
use can_dbc::{AttributeValue, ByteOrder as DbcOrder, MultiplexIndicator, SignalExtendedValueType};
use std::fmt;
use std::path::Path;
use std::time::Duration;

/// A DBC file that cannot be used: file, line (0: the file as a whole) and what is
/// wrong, printed `vehicles/oscc.dbc:12: …` as vehicle-file errors are.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct DbcError {
    pub path: String,
    pub line: usize,
    pub message: String,
}

impl fmt::Display for DbcError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self.line {
            0 => write!(f, "{}: {}", self.path, self.message),
            l => write!(f, "{}:{l}: {}", self.path, self.message),
        }
    }
}

impl std::error::Error for DbcError {}

/// How a message is written, for syntax errors.
const MESSAGE_FORM: &str = "a message is `BO_ <id> <name>: <length> <sender>`";
/// How a signal is written, for syntax errors.
const SIGNAL_FORM: &str = "a signal is `SG_ <name> : <start>|<size>@<1 Intel, 0 Motorola><+ unsigned, - signed> (<factor>,<offset>) [<min>|<max>] \"<unit>\" <receivers>`";

/// A value that a signal cannot carry.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum EncodeError {
    #[error("{message}.{signal}: {value} is outside its range [{min}, {max}]")]
    OutOfRange {
        message: String,
        signal: String,
        value: f64,
        min: f64,
        max: f64,
    },
    #[error("{message}.{signal}: {value} does not fit in {bits} bits")]
    TooWide {
        message: String,
        signal: String,
        value: f64,
        bits: u16,
    },
    #[error("{message}.{signal}: {value} is not a number")]
    NotFinite {
        message: String,
        signal: String,
        value: f64,
    },
    #[error("{message} has no signal {signal:?} ({have})")]
    NoSuchSignal {
        message: String,
        signal: String,
        have: String,
    },
    #[error("{message}.{signal} has no value named {name:?} ({have})")]
    NoSuchValue {
        message: String,
        signal: String,
        name: String,
        have: String,
    },
}

/// How a signal's bits are laid out in the frame.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ByteOrder {
    /// Intel (`@1`): the start bit is the least significant bit.
    Little,
    /// Motorola (`@0`): the start bit is the most significant bit, counted in the DBC's
    /// sawtooth numbering.
    Big,
}

/// What a signal's raw bits are.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Kind {
    /// An integer, signed (`-`) or unsigned (`+`).
    Integer { signed: bool },
    /// An IEEE 754 single (`SIG_VALTYPE_ … : 1`), 32 bits.
    Float32,
    /// An IEEE 754 double (`SIG_VALTYPE_ … : 2`), 64 bits.
    Float64,
}

/// Where a signal sits in a multiplexed message.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Mux {
    /// Always present.
    Plain,
    /// The multiplexor: its value says which multiplexed signals are present.
    Multiplexor,
    /// Present when the multiplexor has this value.
    When(u64),
}

/// One signal of a message.
#[derive(Clone, Debug, PartialEq)]
pub struct Signal {
    name: String,
    start_bit: u16,
    size: u16,
    order: ByteOrder,
    kind: Kind,
    factor: f64,
    offset: f64,
    /// The physical range, when the file gives one (`[0|0]` gives none).
    range: Option<(f64, f64)>,
    unit: String,
    mux: Mux,
    /// The raw value of a frame that does not set this signal (`GenSigStartValue`).
    start: u64,
    /// The value table: raw value and name.
    values: Vec<(i64, String)>,
    line: usize,
    /// The line of its value table (`VAL_`), or its own line without one.
    values_line: usize,
}

fn mask(size: u16) -> u64 {
    if size >= 64 {
        u64::MAX
    } else {
        (1u64 << size) - 1
    }
}

impl Signal {
    pub fn name(&self) -> &str {
        &self.name
    }
    pub fn size(&self) -> u16 {
        self.size
    }
    pub fn kind(&self) -> Kind {
        self.kind
    }
    pub fn byte_order(&self) -> ByteOrder {
        self.order
    }
    pub fn unit(&self) -> &str {
        &self.unit
    }
    pub fn mux(&self) -> Mux {
        self.mux
    }
    /// How much one raw step is worth (raw × factor + offset).
    pub fn factor(&self) -> f64 {
        self.factor
    }
    /// The physical range the file gives, if any.
    pub fn range(&self) -> Option<(f64, f64)> {
        self.range
    }
    /// The line of the DBC file that defines the signal.
    pub fn line(&self) -> usize {
        self.line
    }
    /// The value table, raw value and name.
    pub fn values(&self) -> &[(i64, String)] {
        &self.values
    }
    /// The line of the DBC file that gives its value table (`VAL_`), or its own line.
    pub fn values_line(&self) -> usize {
        self.values_line
    }

    /// The bit positions of the signal, least significant bit first, as the DBC numbers
    /// them (byte × 8 + bit in byte).
    fn bits(&self) -> impl Iterator<Item = u16> + '_ {
        let mut pos = self.start_bit;
        let mut order: [u16; 64] = [0; 64];
        match self.order {
            ByteOrder::Little => {
                for (i, slot) in order.iter_mut().enumerate().take(self.size as usize) {
                    *slot = self.start_bit + i as u16;
                }
            }
            ByteOrder::Big => {
                // From the most significant bit down, through the sawtooth.
                for i in (0..self.size as usize).rev() {
                    order[i] = pos;
                    pos = if pos.is_multiple_of(8) {
                        pos + 15
                    } else {
                        pos - 1
                    };
                }
            }
        }
        order.into_iter().take(self.size as usize)
    }

    /// The highest byte the signal touches, plus one: the least frame length that
    /// carries it.
    fn end_byte(&self) -> usize {
        self.bits().map(|b| b as usize / 8 + 1).max().unwrap_or(0)
    }

    /// The signal's raw bits in `data`; `None` when the frame is too short for it.
    pub fn raw(&self, data: &[u8]) -> Option<u64> {
        if data.len() < self.end_byte() {
            return None;
        }
        let mut raw = 0u64;
        for (i, b) in self.bits().enumerate() {
            let bit = (data[b as usize / 8] >> (b % 8)) & 1;
            raw |= (bit as u64) << i;
        }
        Some(raw)
    }

    /// Write raw bits into `data`; a frame too short for the signal is left as it is.
    pub fn set_raw(&self, raw: u64, data: &mut [u8]) {
        if data.len() < self.end_byte() {
            return;
        }
        for (i, b) in self.bits().enumerate() {
            let byte = &mut data[b as usize / 8];
            let bit = 1u8 << (b % 8);
            if (raw >> i) & 1 == 1 {
                *byte |= bit;
            } else {
                *byte &= !bit;
            }
        }
    }

    /// The raw bits as the number they stand for, before scaling (sign-extended, or the
    /// float they are).
    pub fn raw_number(&self, raw: u64) -> f64 {
        match self.kind {
            Kind::Integer { signed: false } => raw as f64,
            Kind::Integer { signed: true } => {
                let shift = 64 - self.size as u32;
                (((raw << shift) as i64) >> shift) as f64
            }
            Kind::Float32 => f32::from_bits(raw as u32) as f64,
            Kind::Float64 => f64::from_bits(raw),
        }
    }

    /// The physical value (raw × factor + offset) in `data`.
    pub fn decode(&self, data: &[u8]) -> Option<f64> {
        self.raw(data)
            .map(|raw| self.raw_number(raw) * self.factor + self.offset)
    }

    /// The raw bits for a physical value: the range checked (a value outside it is an
    /// error, never clamped), scaled, rounded for an integer, and checked to fit.
    pub fn to_raw(&self, message: &str, value: f64) -> Result<u64, EncodeError> {
        let name = || (message.to_string(), self.name.clone());
        if !value.is_finite() {
            let (message, signal) = name();
            return Err(EncodeError::NotFinite {
                message,
                signal,
                value,
            });
        }
        if let Some((min, max)) = self.range {
            // A hair of slack for values that went through a float on their way.
            let slack = 1e-9 * (max - min).abs().max(1.0);
            if value < min - slack || value > max + slack {
                let (message, signal) = name();
                return Err(EncodeError::OutOfRange {
                    message,
                    signal,
                    value,
                    min,
                    max,
                });
            }
        }
        let scaled = (value - self.offset) / self.factor;
        let too_wide = || {
            let (message, signal) = name();
            EncodeError::TooWide {
                message,
                signal,
                value,
                bits: self.size,
            }
        };
        match self.kind {
            Kind::Float32 => {
                let f = scaled as f32;
                if !f.is_finite() {
                    return Err(too_wide());
                }
                Ok(f.to_bits() as u64)
            }
            Kind::Float64 => Ok(scaled.to_bits()),
            Kind::Integer { signed } => {
                let r = scaled.round();
                let n = self.size as i32;
                let (lo, hi) = if signed {
                    (-(2f64.powi(n - 1)), 2f64.powi(n - 1) - 1.0)
                } else {
                    (0.0, 2f64.powi(n) - 1.0)
                };
                if r < lo || r > hi {
                    return Err(too_wide());
                }
                Ok(if signed {
                    (r as i64 as u64) & mask(self.size)
                } else {
                    r as u64
                })
            }
        }
    }

    /// The name the value table gives a raw value (`OPERATOR_OVERRIDE`).
    pub fn value_name(&self, raw: i64) -> Option<&str> {
        self.values
            .iter()
            .find(|(v, _)| *v == raw)
            .map(|(_, n)| n.as_str())
    }

    /// The raw value the value table gives a name (a fault injected by name).
    pub fn value_of(&self, name: &str) -> Option<i64> {
        self.values.iter().find(|(_, n)| n == name).map(|(v, _)| *v)
    }

    /// For a bitfield whose value table names single bits (a kit's DTCs): the names of
    /// the bits set in `raw`, and the bits set that the table does not name, as numbers.
    pub fn flag_names(&self, raw: u64) -> Vec<String> {
        (0..self.size.min(64))
            .filter(|bit| raw >> bit & 1 == 1)
            .map(|bit| {
                self.value_name(1i64 << bit)
                    .map_or_else(|| format!("bit {bit}"), str::to_string)
            })
            .collect()
    }
}

/// One message of the file.
#[derive(Clone, Debug, PartialEq)]
pub struct Message {
    id: Id,
    name: String,
    len: usize,
    sender: Option<String>,
    signals: Vec<Signal>,
    cycle: Option<Duration>,
    line: usize,
}

impl Message {
    pub fn id(&self) -> Id {
        self.id
    }
    pub fn name(&self) -> &str {
        &self.name
    }
    /// The frame length in bytes.
    pub fn len(&self) -> usize {
        self.len
    }
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }
    /// The node that sends it, if the file names one.
    pub fn sender(&self) -> Option<&str> {
        self.sender.as_deref()
    }
    pub fn signals(&self) -> &[Signal] {
        &self.signals
    }
    /// How often the sender sends it (`GenMsgCycleTime`), if the file says.
    pub fn cycle(&self) -> Option<Duration> {
        self.cycle
    }
    /// The line of the DBC file that defines the message.
    pub fn line(&self) -> usize {
        self.line
    }

    pub fn signal(&self, name: &str) -> Option<&Signal> {
        self.signals.iter().find(|s| s.name == name)
    }

    /// The signal named `name`, or an error that lists the message's signals.
    pub fn signal_named(&self, name: &str) -> Result<&Signal, EncodeError> {
        self.signal(name).ok_or_else(|| EncodeError::NoSuchSignal {
            message: self.name.clone(),
            signal: name.to_string(),
            have: self.signal_list(),
        })
    }

    fn signal_list(&self) -> String {
        it_has(self.signals.iter().map(|s| s.name.as_str()), "no signals")
    }

    /// The signals present in `frame` with their physical values: every plain signal,
    /// and of the multiplexed ones those the multiplexor selects. A signal the frame is
    /// too short for is left out.
    pub fn decode<'a>(&'a self, frame: &'a Frame) -> impl Iterator<Item = (&'a Signal, f64)> + 'a {
        let data = frame.data();
        let selector = self
            .signals
            .iter()
            .find(|s| s.mux == Mux::Multiplexor)
            .and_then(|s| s.raw(data));
        self.signals.iter().filter_map(move |s| {
            if let Mux::When(v) = s.mux {
                if selector != Some(v) {
                    return None;
                }
            }
            s.decode(data).map(|v| (s, v))
        })
    }

    /// A frame of this message: every signal named in `values` set to its physical
    /// value, every other one to its start value (`GenSigStartValue`, else 0).
    pub fn encode(&self, values: &[(&str, f64)]) -> Result<Frame, EncodeError> {
        for (name, _) in values {
            self.signal_named(name)?;
        }
        let mut data = [0u8; 8];
        let data = &mut data[..self.len];
        for s in &self.signals {
            let raw = match values.iter().find(|(n, _)| *n == s.name) {
                Some(&(_, v)) => s.to_raw(&self.name, v)?,
                None => s.start,
            };
            s.set_raw(raw, data);
        }
        Ok(Frame::new(self.id, data).expect("a DBC message is at most 8 bytes"))
    }

    /// Set one signal of `frame` to a value of its value table, by name.
    pub fn set_named(
        &self,
        frame: &mut Frame,
        signal: &str,
        name: &str,
    ) -> Result<(), EncodeError> {
        let s = self.signal_named(signal)?;
        let raw = s.value_of(name).ok_or_else(|| EncodeError::NoSuchValue {
            message: self.name.clone(),
            signal: signal.to_string(),
            name: name.to_string(),
            have: it_has(s.values.iter().map(|(_, n)| n.as_str()), "no value table"),
        })?;
        s.set_raw(raw as u64 & mask(s.size), frame.data_mut());
        Ok(())
    }
}

/// The messages of a DBC file.
#[derive(Clone, Debug, PartialEq)]
pub struct Database {
    path: String,
    messages: Vec<Message>,
}

impl Database {
    /// Read and parse the DBC file at `path`.
    pub fn load(path: &Path) -> Result<Database, DbcError> {
        let name = path.display().to_string();
        let bytes = std::fs::read(path).map_err(|e| DbcError {
            path: name.clone(),
            line: 0,
            message: crate::paths::cannot_read(path, &e),
        })?;
        let text = String::from_utf8(bytes).map_err(|e| {
            let at = e.utf8_error().valid_up_to();
            let line = e.as_bytes()[..at].iter().filter(|&&b| b == b'\n').count() + 1;
            DbcError {
                path: name.clone(),
                line,
                message: "not UTF-8 text (save the file as UTF-8; Windows-1252 DBC files \
                          from vendor tools need converting)"
                    .into(),
            }
        })?;
        Database::parse(&text, &name)
    }

    /// Parse DBC text; `path` names it in errors.
    pub fn parse(text: &str, path: &str) -> Result<Database, DbcError> {
        let err = |line: usize, message: String| DbcError {
            path: path.to_string(),
            line,
            message,
        };
        let dbc = can_dbc::Dbc::try_from(text).map_err(|e| match e {
            can_dbc::DbcError::Pest(p) => {
                let (line, col) = match p.line_col {
                    pest::error::LineColLocation::Pos(at) => at,
                    pest::error::LineColLocation::Span(at, _) => at,
                };
                let written = text.lines().nth(line.saturating_sub(1)).unwrap_or("");
                let form = match written.split_whitespace().next() {
                    Some("SG_") => SIGNAL_FORM,
                    Some("BO_") => MESSAGE_FORM,
                    _ => "see the DBC format's BO_, SG_, BA_, VAL_ and SIG_VALTYPE_ lines",
                };
                err(
                    line,
                    format!(
                        "column {col}: {} ({form})",
                        p.variant.message().replace('_', " ")
                    ),
                )
            }
            other => {
                // The crate's own checks carry no position: find the offending text.
                let said = other.to_string();
                let quoted = said.split('\'').nth(1).filter(|q| !q.is_empty());
                let line = quoted.map_or(0, |q| line_containing(text, q));
                err(line, said)
            }
        })?;
        if dbc.messages.is_empty() {
            // Nothing a vehicle file could map a device to.
            return Err(err(
                text.lines().count().max(1),
                "the file has no messages: a DBC describes each with a BO_ line and its \
                 signals with SG_ lines (e.g. `BO_ 112 BRAKE_COMMAND: 8 BRAKE`)"
                    .into(),
            ));
        }
        let lines = Lines::of(text);
        let mut messages = Vec::new();
        for (index, m) in dbc.messages.iter().enumerate() {
            let id = match m.id {
                can_dbc::MessageId::Standard(id) => Id::standard(id),
                can_dbc::MessageId::Extended(id) => Id::extended(id),
            };
            let mline = lines.message(index, m.id.raw());
            let id = id.ok_or_else(|| {
                err(
                    mline,
                    format!("message {}: identifier out of range", m.name),
                )
            })?;
            if m.size > 8 {
                return Err(err(
                    mline,
                    format!(
                        "message {} is {} bytes long; classic CAN carries at most 8",
                        m.name, m.size
                    ),
                ));
            }
            if let Some(other) = messages.iter().find(|o: &&Message| o.id == id) {
                return Err(err(
                    mline,
                    format!(
                        "message {} has the identifier {id} of {} (line {})",
                        m.name, other.name, other.line
                    ),
                ));
            }
            let cycle = match dbc.message_attribute(m.id, "GenMsgCycleTime") {
                Some(AttributeValue::Uint(ms)) if *ms > 0 => Some(Duration::from_millis(*ms)),
                Some(AttributeValue::Int(ms)) if *ms > 0 => Some(Duration::from_millis(*ms as u64)),
                Some(AttributeValue::Double(ms)) if *ms > 0.0 => {
                    Some(Duration::from_secs_f64(ms / 1000.0))
                }
                _ => None,
            };
            let mut signals = Vec::new();
            for s in &m.signals {
                let sline = lines.signal(index, m.id.raw(), &s.name);
                let serr =
                    |what: String| err(sline, format!("signal {}.{}: {what}", m.name, s.name));
                let kind = match dbc.extended_value_type_for_signal(m.id, &s.name) {
                    Some(SignalExtendedValueType::IEEEfloat32Bit) => Kind::Float32,
                    Some(SignalExtendedValueType::IEEEdouble64bit) => Kind::Float64,
                    _ => Kind::Integer {
                        signed: s.value_type == can_dbc::ValueType::Signed,
                    },
                };
                let want = match kind {
                    Kind::Float32 => Some(32),
                    Kind::Float64 => Some(64),
                    Kind::Integer { .. } => None,
                };
                if let Some(w) = want.filter(|&w| w != s.size) {
                    return Err(serr(format!(
                        "SIG_VALTYPE_ makes it an IEEE float of {w} bits, but it is {} bits long",
                        s.size
                    )));
                }
                if s.size == 0 || s.size > 64 {
                    return Err(serr(format!("{} bits: a signal has 1 to 64", s.size)));
                }
                if s.factor == 0.0 || !s.factor.is_finite() {
                    return Err(serr(format!(
                        "factor {}: must be a non-zero number",
                        s.factor
                    )));
                }
                let num = |v: &can_dbc::NumericValue| match *v {
                    can_dbc::NumericValue::Uint(u) => u as f64,
                    can_dbc::NumericValue::Int(i) => i as f64,
                    can_dbc::NumericValue::Double(d) => d,
                };
                let (min, max) = (num(&s.min), num(&s.max));
                let range = (!(min == 0.0 && max == 0.0)).then_some((min, max));
                let mux = match s.multiplexer_indicator {
                    MultiplexIndicator::Plain => Mux::Plain,
                    MultiplexIndicator::Multiplexor => Mux::Multiplexor,
                    MultiplexIndicator::MultiplexedSignal(v)
                    | MultiplexIndicator::MultiplexorAndMultiplexedSignal(v) => Mux::When(v),
                };
                let mut signal = Signal {
                    name: s.name.clone(),
                    start_bit: 0,
                    size: s.size as u16,
                    order: match s.byte_order {
                        DbcOrder::LittleEndian => ByteOrder::Little,
                        DbcOrder::BigEndian => ByteOrder::Big,
                    },
                    kind,
                    factor: s.factor,
                    offset: s.offset,
                    range,
                    unit: s.unit.clone(),
                    mux,
                    start: 0,
                    values: dbc
                        .value_descriptions_for_signal(m.id, &s.name)
                        .unwrap_or_default()
                        .iter()
                        .map(|d| (d.id, d.description.clone()))
                        .collect(),
                    line: sline,
                    values_line: lines.values(m.id.raw(), &s.name).unwrap_or(sline),
                };
                let fits = u16::try_from(s.start_bit).ok().filter(|&b| b < 64 * 8);
                signal.start_bit =
                    fits.ok_or_else(|| serr(format!("start bit {} is past 8 bytes", s.start_bit)))?;
                if signal.order == ByteOrder::Little
                    && signal.start_bit as usize + signal.size as usize > 64
                    || signal.order == ByteOrder::Big
                        && !big_endian_fits(signal.start_bit, signal.size)
                    || signal.end_byte() > m.size as usize
                {
                    return Err(serr(format!(
                        "bits {}|{}@{} do not fit in the message's {} bytes",
                        s.start_bit,
                        s.size,
                        if signal.order == ByteOrder::Little {
                            1
                        } else {
                            0
                        },
                        m.size
                    )));
                }
                if let Some(v) = dbc.signal_attribute(m.id, &s.name, "GenSigStartValue") {
                    let raw = match *v {
                        AttributeValue::Uint(u) => u as f64,
                        AttributeValue::Int(i) => i as f64,
                        AttributeValue::Double(d) => d,
                        AttributeValue::String(_) => {
                            return Err(serr("GenSigStartValue must be a number".into()))
                        }
                    };
                    // The start value is raw, as vendor tools write it.
                    signal.start = match kind {
                        Kind::Float32 => (raw as f32).to_bits() as u64,
                        Kind::Float64 => raw.to_bits(),
                        Kind::Integer { .. } => (raw.round() as i64 as u64) & mask(signal.size),
                    };
                }
                signals.push(signal);
            }
            messages.push(Message {
                id,
                name: m.name.clone(),
                len: m.size as usize,
                sender: m.transmitter.clone(),
                signals,
                cycle,
                line: mline,
            });
        }
        Ok(Database {
            path: path.to_string(),
            messages,
        })
    }

    /// The file it was read from, for messages.
    pub fn path(&self) -> &str {
        &self.path
    }

    pub fn messages(&self) -> &[Message] {
        &self.messages
    }

    /// The message of a received frame's identifier.
    pub fn by_id(&self, id: Id) -> Option<&Message> {
        self.messages.iter().find(|m| m.id == id)
    }

    pub fn message(&self, name: &str) -> Option<&Message> {
        self.messages.iter().find(|m| m.name == name)
    }

    /// The message named `name`, or an error naming the file and listing its messages
    /// (for a vehicle file that maps a device to a message).
    pub fn message_named(&self, name: &str) -> Result<&Message, DbcError> {
        self.message(name).ok_or_else(|| DbcError {
            path: self.path.clone(),
            line: 0,
            message: format!(
                "no message {name:?} ({})",
                it_has(self.messages.iter().map(|m| m.name.as_str()), "no messages")
            ),
        })
    }
}

/// `it has a, b, c` for a list of names, or `it has {none}` (`no signals`) when there
/// is none: a message never ends in an empty list.
fn it_has<'a>(names: impl Iterator<Item = &'a str>, none: &str) -> String {
    let names: Vec<&str> = names.collect();
    if names.is_empty() {
        format!("it has {none}")
    } else {
        format!("it has {}", names.join(", "))
    }
}

/// Whether a Motorola signal of `size` bits from `start` stays inside 8 bytes.
fn big_endian_fits(start: u16, size: u16) -> bool {
    let mut pos = start as u32;
    for _ in 1..size {
        pos = if pos.is_multiple_of(8) {
            pos + 15
        } else {
            pos - 1
        };
    }
    pos < 64
}

/// The 1-based line of the first line of `text` containing `needle`, else 0.
fn line_containing(text: &str, needle: &str) -> usize {
    text.lines()
        .position(|l| l.contains(needle))
        .map_or(0, |i| i + 1)
}

/// Where each message (`BO_`) and signal (`SG_`) is defined, in file order, for errors
/// found after parsing.
struct Lines {
    /// Per message: its identifier as written, its line, and its signals' lines.
    messages: Vec<Entry>,
    /// Each value table (`VAL_ ID SIGNAL …`): the identifier and signal it names, and
    /// its line.
    values: Vec<(u32, String, usize)>,
}

/// A message's identifier as written, its line, and its signals' names and lines.
type Entry = (u32, usize, Vec<(String, usize)>);

impl Lines {
    fn of(text: &str) -> Lines {
        let mut messages: Vec<Entry> = Vec::new();
        let mut values = Vec::new();
        let mut open = false;
        for (i, line) in text.lines().enumerate() {
            let mut words = line.split_whitespace();
            match words.next() {
                Some("VAL_") => {
                    open = false;
                    if let (Some(id), Some(signal)) = (
                        words.next().and_then(|w| w.parse::<u32>().ok()),
                        words.next(),
                    ) {
                        values.push((id, signal.to_string(), i + 1));
                    }
                }
                Some("BO_") => {
                    let id = words.next().and_then(|w| w.parse::<u32>().ok());
                    open = id.is_some();
                    if let Some(id) = id {
                        messages.push((id, i + 1, Vec::new()));
                    }
                }
                Some("SG_") if open => {
                    if let (Some(m), Some(name)) = (messages.last_mut(), words.next()) {
                        m.2.push((name.trim_end_matches(':').to_string(), i + 1));
                    }
                }
                Some(_) => open = false,
                None => {}
            }
        }
        Lines { messages, values }
    }

    /// The line of the value table of signal `name` of the message `raw`.
    fn values(&self, raw: u32, name: &str) -> Option<usize> {
        self.values
            .iter()
            .find(|(id, signal, _)| *id == raw && signal == name)
            .map(|v| v.2)
    }

    /// The `index`th message of the file (the parser keeps file order), if its
    /// identifier is `raw`; else the first message with that identifier.
    fn entry(&self, index: usize, raw: u32) -> Option<&Entry> {
        self.messages
            .get(index)
            .filter(|m| m.0 == raw)
            .or_else(|| self.messages.iter().find(|m| m.0 == raw))
    }

    fn message(&self, index: usize, raw: u32) -> usize {
        self.entry(index, raw).map_or(0, |m| m.1)
    }

    fn signal(&self, index: usize, raw: u32, name: &str) -> usize {
        self.entry(index, raw).map_or(0, |m| {
            m.2.iter().find(|(n, _)| n == name).map_or(m.1, |&(_, l)| l)
        })
    }
}

/// How a kit checks a frame's integrity.
#[derive(Clone, Copy, Debug)]
pub enum Checksum {
    /// The data bytes XORed together.
    Xor8,
    /// The data bytes added, modulo the signal's width.
    Sum8,
    /// A kit's own: given the identifier and the data (with the checksum's bits zero),
    /// the checksum's raw value.
    Custom(fn(Id, &[u8]) -> u64),
}

/// The rolling counter and checksum of one message that adrive fills in as it sends:
/// each frame the counter steps (wrapping at its width) and the checksum is computed
/// over the frame with its own bits zero, last.
#[derive(Clone, Debug)]
pub struct Sequence {
    counter: Option<Signal>,
    checksum: Option<(Signal, Checksum)>,
    count: u64,
}

impl Sequence {
    /// The sequence of `message`, with its counter and checksum signals named (either may
    /// be absent).
    pub fn new(
        message: &Message,
        counter: Option<&str>,
        checksum: Option<(&str, Checksum)>,
    ) -> Result<Sequence, EncodeError> {
        Ok(Sequence {
            counter: counter
                .map(|n| message.signal_named(n).cloned())
                .transpose()?,
            checksum: checksum
                .map(|(n, c)| message.signal_named(n).map(|s| (s.clone(), c)))
                .transpose()?,
            count: 0,
        })
    }

    /// Fill in the next counter value and the checksum of `frame`.
    pub fn stamp(&mut self, frame: &mut Frame) {
        let id = frame.id();
        let data = frame.data_mut();
        if let Some(c) = &self.counter {
            c.set_raw(self.count & mask(c.size), data);
            self.count = self.count.wrapping_add(1);
        }
        if let Some((s, kind)) = &self.checksum {
            s.set_raw(0, data);
            let sum = match kind {
                Checksum::Xor8 => data.iter().fold(0u8, |a, b| a ^ b) as u64,
                Checksum::Sum8 => data.iter().map(|&b| b as u64).sum(),
                Checksum::Custom(f) => f(id, data),
            };
            s.set_raw(sum & mask(s.size), data);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const TEST_DBC: &str = r#"VERSION ""

NS_ :
	BA_
	BA_DEF_
	BA_DEF_DEF_
	SIG_VALTYPE_
	VAL_

BS_:

BU_: KIT HOST

BO_ 256 MIXED: 8 KIT
 SG_ little_u : 0|12@1+ (0.5,-10) [-10|2037.5] "deg" HOST
 SG_ little_s : 12|12@1- (1,0) [0|0] "" HOST
 SG_ big_u : 39|16@0+ (1,0) [0|0] "" HOST
 SG_ big_nibbles : 51|12@0+ (1,0) [0|0] "" HOST

BO_ 114 COMMAND: 8 HOST
 SG_ magic : 0|16@1+ (1,0) [0|0] "" KIT
 SG_ request : 16|32@1- (1,0) [0|1] "" KIT
 SG_ counter : 48|4@1+ (1,0) [0|15] "" KIT
 SG_ checksum : 56|8@1+ (1,0) [0|255] "" KIT

BO_ 115 REPORT: 8 KIT
 SG_ enabled : 16|8@1+ (1,0) [0|1] "" HOST
 SG_ dtcs : 32|8@1+ (1,0) [0|0] "" HOST

BO_ 2566844672 EXT_MUX: 8 KIT
 SG_ page M : 0|8@1+ (1,0) [0|0] "" HOST
 SG_ first m0 : 8|8@1+ (1,0) [0|0] "" HOST
 SG_ second m1 : 8|16@1+ (1,0) [0|0] "" HOST

BA_DEF_ BO_ "GenMsgCycleTime" INT 0 10000;
BA_DEF_ SG_ "GenSigStartValue" INT 0 65535;
BA_DEF_DEF_ "GenMsgCycleTime" 0;
BA_DEF_DEF_ "GenSigStartValue" 0;
BA_ "GenMsgCycleTime" BO_ 115 20;
BA_ "GenSigStartValue" SG_ 114 magic 52229;
VAL_ 115 dtcs 1 "INVALID_SENSOR_VAL" 2 "OPERATOR_OVERRIDE" ;
VAL_ 115 enabled 0 "DISABLED" 1 "ENABLED" ;
SIG_VALTYPE_ 114 request : 1;
"#;

    fn db() -> Database {
        Database::parse(TEST_DBC, "test.dbc").expect("the test DBC loads")
    }

    fn frame(id: u16, data: &[u8]) -> Frame {
        Frame::new(Id::Standard(id), data).unwrap()
    }

    fn values(m: &Message, f: &Frame) -> Vec<(String, f64)> {
        m.decode(f)
            .map(|(s, v)| (s.name().to_string(), v))
            .collect()
    }

    #[test]
    fn little_and_big_endian_signed_and_scaled_signals_decode() {
        let db = db();
        let m = db.message("MIXED").unwrap();
        // little_u: raw 0x234 = 564 → 564 × 0.5 − 10; little_s: raw 0xFFF → −1;
        // big_u: bytes 4..6 big-endian 0xBEEF; big_nibbles: low nibble of byte 6 then
        // byte 7: 0x5A7.
        let f = frame(256, &[0x34, 0xF2, 0xFF, 0x00, 0xBE, 0xEF, 0xC5, 0xA7]);
        assert_eq!(
            values(m, &f),
            vec![
                ("little_u".into(), 272.0),
                ("little_s".into(), -1.0),
                ("big_u".into(), 48879.0),
                ("big_nibbles".into(), 1447.0),
            ]
        );
        let back = m
            .encode(&[
                ("little_u", 272.0),
                ("little_s", -1.0),
                ("big_u", 48879.0),
                ("big_nibbles", 1447.0),
            ])
            .unwrap();
        // Byte 6's high nibble belongs to no signal: encoding leaves it zero.
        assert_eq!(
            back.data(),
            &[0x34, 0xF2, 0xFF, 0x00, 0xBE, 0xEF, 0x05, 0xA7]
        );
        assert_eq!(m.line(), 14);
        assert_eq!(m.signal("big_u").unwrap().line(), 17);
    }

    #[test]
    fn an_ieee_float_request_with_the_start_value_in_every_frame() {
        let db = db();
        let m = db.message("COMMAND").unwrap();
        assert_eq!(m.signal("request").unwrap().kind(), Kind::Float32);
        let f = m.encode(&[("request", 0.25)]).unwrap();
        // The magic from GenSigStartValue (52229 = 0xCC05, little-endian: 05 CC), then
        // 0.25f32 little-endian (0x3E800000).
        assert_eq!(f.data(), &[0x05, 0xCC, 0x00, 0x00, 0x80, 0x3E, 0x00, 0x00]);
        assert_eq!(f.id(), Id::Standard(114));
        let got = values(m, &f);
        assert_eq!(got[0], ("magic".into(), 52229.0));
        assert_eq!(got[1], ("request".into(), 0.25));
    }

    #[test]
    fn a_value_outside_the_range_or_the_width_is_refused_never_clamped() {
        let db = db();
        let m = db.message("COMMAND").unwrap();
        let e = m.encode(&[("request", 1.5)]).unwrap_err();
        assert_eq!(
            e.to_string(),
            "COMMAND.request: 1.5 is outside its range [0, 1]"
        );
        assert!(matches!(
            m.encode(&[("request", f64::NAN)]),
            Err(EncodeError::NotFinite { .. })
        ));
        let e = m.encode(&[("requets", 0.5)]).unwrap_err();
        assert_eq!(
            e.to_string(),
            "COMMAND has no signal \"requets\" (it has magic, request, counter, checksum)"
        );
        let mixed = db.message("MIXED").unwrap();
        assert!(matches!(
            mixed.encode(&[("little_s", 2048.0)]),
            Err(EncodeError::TooWide { bits: 12, .. })
        ));
        assert!(mixed.encode(&[("little_s", -2048.0)]).is_ok());
    }

    #[test]
    fn fault_codes_and_states_by_name() {
        let db = db();
        let m = db.message("REPORT").unwrap();
        assert_eq!(m.cycle(), Some(Duration::from_millis(20)));
        let f = frame(115, &[0x05, 0xCC, 1, 0, 0b11, 0, 0, 0]);
        let dtcs = m.signal("dtcs").unwrap();
        assert_eq!(
            dtcs.flag_names(dtcs.raw(f.data()).unwrap()),
            vec!["INVALID_SENSOR_VAL", "OPERATOR_OVERRIDE"]
        );
        assert_eq!(dtcs.flag_names(0b100), vec!["bit 2"]);
        let enabled = m.signal("enabled").unwrap();
        assert_eq!(enabled.value_name(1), Some("ENABLED"));
        let mut g = m.encode(&[]).unwrap();
        m.set_named(&mut g, "dtcs", "OPERATOR_OVERRIDE").unwrap();
        assert_eq!(g.data()[4], 2);
        let e = m.set_named(&mut g, "dtcs", "OVERHEAT").unwrap_err();
        assert_eq!(
            e.to_string(),
            "REPORT.dtcs has no value named \"OVERHEAT\" (it has INVALID_SENSOR_VAL, OPERATOR_OVERRIDE)"
        );
    }

    #[test]
    fn multiplexed_signals_decode_only_on_their_page_of_an_extended_message() {
        let db = db();
        let m = db
            .by_id(Id::Extended(0x18FE_F100))
            .expect("the extended message");
        assert_eq!(m.name(), "EXT_MUX");
        let p0 = Frame::new(m.id(), &[0, 7, 1, 0, 0, 0, 0, 0]).unwrap();
        assert_eq!(
            values(m, &p0),
            vec![("page".into(), 0.0), ("first".into(), 7.0)]
        );
        let p1 = Frame::new(m.id(), &[1, 7, 1, 0, 0, 0, 0, 0]).unwrap();
        assert_eq!(
            values(m, &p1),
            vec![("page".into(), 1.0), ("second".into(), 263.0)]
        );
        // A standard frame with the same number is another message.
        assert!(db
            .by_id(Id::Standard(0x100))
            .is_some_and(|m| m.name() == "MIXED"));
    }

    #[test]
    fn the_counter_rolls_and_the_checksum_covers_the_frame() {
        let db = db();
        let m = db.message("COMMAND").unwrap();
        let mut seq =
            Sequence::new(m, Some("counter"), Some(("checksum", Checksum::Xor8))).unwrap();
        let mut counts = Vec::new();
        for _ in 0..17 {
            let mut f = m.encode(&[("request", 0.5)]).unwrap();
            seq.stamp(&mut f);
            let d = f.data();
            assert_eq!(
                d.iter().fold(0, |a, b| a ^ b),
                0,
                "XOR over a stamped frame is 0: {f}"
            );
            counts.push(d[6] & 0x0F);
        }
        assert_eq!(counts[..3], [0, 1, 2]);
        assert_eq!(counts[15..], [15, 0], "a 4-bit counter wraps");
        let custom = |_: Id, d: &[u8]| d.len() as u64 * 3;
        let mut seq = Sequence::new(m, None, Some(("checksum", Checksum::Custom(custom)))).unwrap();
        let mut f = m.encode(&[]).unwrap();
        seq.stamp(&mut f);
        assert_eq!(f.data()[7], 24);
        assert!(Sequence::new(m, Some("count"), None).is_err());
    }

    fn oscc() -> Database {
        let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("vehicles/oscc.dbc");
        Database::load(&path).unwrap_or_else(|e| panic!("{e}"))
    }

    fn physical(db: &Database, f: &Frame) -> Vec<(String, f64)> {
        values(db.by_id(f.id()).expect("a known message"), f)
    }

    #[test]
    fn oscc_requests_are_the_c_structures_bytes() {
        let db = oscc();
        let brake = db.message("BRAKE_COMMAND").unwrap();
        assert_eq!(brake.id(), Id::Standard(0x72));
        // oscc_brake_command_s { magic = 05 CC, float pedal_command = 0.5, reserved }.
        let f = brake.encode(&[("pedal_command", 0.5)]).unwrap();
        assert_eq!(f.data(), &[0x05, 0xCC, 0x00, 0x00, 0x00, 0x3F, 0x00, 0x00]);
        let steer = db.message("STEERING_COMMAND").unwrap();
        let f = steer.encode(&[("torque_command", -0.25)]).unwrap();
        assert_eq!(f.id(), Id::Standard(0x82));
        assert_eq!(f.data(), &[0x05, 0xCC, 0x00, 0x00, 0x80, 0xBE, 0x00, 0x00]);
        assert!(steer.encode(&[("torque_command", -1.01)]).is_err());
        let throttle = db.message("THROTTLE_COMMAND").unwrap();
        assert_eq!(throttle.id(), Id::Standard(0x92));
        assert!(
            throttle.encode(&[("torque_request", -0.1)]).is_err(),
            "no negative throttle"
        );
        for (name, id) in [
            ("BRAKE_ENABLE", 0x70),
            ("BRAKE_DISABLE", 0x71),
            ("STEERING_ENABLE", 0x80),
            ("STEERING_DISABLE", 0x81),
            ("THROTTLE_ENABLE", 0x90),
            ("THROTTLE_DISABLE", 0x91),
        ] {
            let m = db.message(name).unwrap();
            let f = m.encode(&[]).unwrap();
            assert_eq!(f.id(), Id::Standard(id), "{name}");
            assert_eq!(f.data(), &[0x05, 0xCC, 0, 0, 0, 0, 0, 0], "{name}");
        }
    }

    #[test]
    fn oscc_reports_and_faults_decode_by_name_at_50_hz() {
        let db = oscc();
        for name in ["BRAKE_REPORT", "STEERING_REPORT", "THROTTLE_REPORT"] {
            let m = db.message(name).unwrap();
            assert_eq!(m.cycle(), Some(Duration::from_millis(20)), "{name}");
        }
        // oscc_throttle_report_s: enabled, operator_override, dtcs = override.
        let f = frame(0x93, &[0x05, 0xCC, 0x01, 0x01, 0x02, 0x00, 0x00, 0x00]);
        let m = db.by_id(f.id()).unwrap();
        assert_eq!(m.name(), "THROTTLE_REPORT");
        let got = physical(&db, &f);
        assert_eq!(
            got[2..],
            [
                ("enabled".into(), 1.0),
                ("operator_override".into(), 1.0),
                ("dtcs".into(), 2.0)
            ]
        );
        assert_eq!(
            m.signal("dtcs").unwrap().flag_names(2),
            vec!["OPERATOR_OVERRIDE"]
        );
        // oscc_fault_report_s from the steering module: uint32 origin 1, dtcs 1.
        let f = frame(0xAF, &[0x05, 0xCC, 0x01, 0x00, 0x00, 0x00, 0x01, 0x00]);
        let m = db.by_id(f.id()).unwrap();
        let origin = m.signal("fault_origin_id").unwrap();
        assert_eq!(
            origin.value_name(origin.raw(f.data()).unwrap() as i64),
            Some("STEERING")
        );
        let dtcs = m.signal("dtcs").unwrap();
        assert_eq!(
            dtcs.flag_names(dtcs.raw(f.data()).unwrap()),
            vec!["INVALID_SENSOR_VAL"]
        );
    }

    #[test]
    fn the_kia_souls_own_messages_decode_as_osccs_api_does() {
        let db = oscc();
        // Front left raw 0x140 with noise in the high nibble of its second byte (the API
        // keeps the low nibble): 320 / 32 = 10 km/h; rear right raw 0xFFF.
        let f = frame(0x4B0, &[0x40, 0xF1, 0x00, 0x00, 0x20, 0x00, 0xFF, 0x0F]);
        assert_eq!(
            physical(&db, &f),
            vec![
                ("wheel_speed_front_left".into(), 10.0),
                ("wheel_speed_front_right".into(), 0.0),
                ("wheel_speed_rear_left".into(), 1.0),
                ("wheel_speed_rear_right".into(), 4095.0 / 32.0),
            ]
        );
        // 100 tenths of a degree, negated as get_steering_wheel_angle does.
        let f = frame(0x2B0, &[0x64, 0x00, 0, 0, 0, 0, 0, 0]);
        assert_eq!(
            physical(&db, &f),
            vec![("steering_wheel_angle".into(), -10.0)]
        );
        let f = frame(0x220, &[0, 0, 0, 0, 0x2C, 0xF1, 0, 0]);
        let got = physical(&db, &f);
        assert!((got[0].1 - 30.0).abs() < 1e-9, "{got:?}");
    }

    fn error_of(text: &str) -> String {
        Database::parse(text, "vehicles/kit.dbc")
            .unwrap_err()
            .to_string()
    }

    #[test]
    fn errors_name_the_file_and_the_line() {
        // A syntax error: a signal without its bit layout, on line 16.
        let broken = TEST_DBC.replace(" SG_ little_s : 12|12@1- ", " SG_ little_s : twelve ");
        let e = error_of(&broken);
        assert!(e.starts_with("vehicles/kit.dbc:16: column "), "{e}");
        assert!(
            e.contains("expected start bit (a signal is `SG_ <name> : <start>|<size>@"),
            "{e}"
        );
        // A float signal that is not 32 bits, at its line.
        let e = error_of(&TEST_DBC.replace("16|32@1- (1,0) [0|1]", "16|16@1- (1,0) [0|1]"));
        assert_eq!(
            e,
            "vehicles/kit.dbc:22: signal COMMAND.request: SIG_VALTYPE_ makes it an IEEE float of 32 bits, but it is 16 bits long"
        );
        // A signal past the end of its message.
        let e = error_of(&TEST_DBC.replace("BO_ 115 REPORT: 8 KIT", "BO_ 115 REPORT: 4 KIT"));
        assert_eq!(
            e,
            "vehicles/kit.dbc:28: signal REPORT.dtcs: bits 32|8@1 do not fit in the message's 4 bytes"
        );
        let e = error_of(&TEST_DBC.replace("BO_ 115 REPORT", "BO_ 114 REPORT"));
        assert!(
            e.starts_with(
                "vehicles/kit.dbc:26: message REPORT has the identifier 0x072 of COMMAND (line 20)"
            ),
            "{e}"
        );
        assert_eq!(
            Database::load(Path::new("/nonexistent/kit.dbc"))
                .unwrap_err()
                .to_string(),
            "/nonexistent/kit.dbc: cannot read: no such file: /nonexistent does not exist"
        );
        assert_eq!(
            db().message_named("BRAKE").unwrap_err().to_string(),
            "test.dbc: no message \"BRAKE\" (it has MIXED, COMMAND, REPORT, EXT_MUX)"
        );
    }

    /// The incident: an empty DBC file was reported as `no message "STEERING_COMMAND"
    /// (it has )`. A file without messages is refused at its end, as other DBC errors
    /// are, and no list the messages give is ever empty.
    #[test]
    fn a_dbc_without_messages_is_refused_and_no_list_is_empty() {
        assert_eq!(
            error_of(""),
            "vehicles/kit.dbc:1: the file has no messages: a DBC describes each with a BO_ line and its signals with SG_ lines (e.g. `BO_ 112 BRAKE_COMMAND: 8 BRAKE`)"
        );
        assert!(error_of("VERSION \"\"\n\nBU_: KIT\n")
            .starts_with("vehicles/kit.dbc:3: the file has no messages"));
        let db = Database::parse(
            "VERSION \"\"\n\nBU_: KIT\nBO_ 112 EMPTY: 8 KIT\nBO_ 113 ONE: 8 KIT\n SG_ s : 0|8@1+ (1,0) [0|255] \"\" KIT\n",
            "t.dbc",
        )
        .unwrap();
        let empty = db.message("EMPTY").unwrap();
        assert_eq!(
            empty.signal_named("s").unwrap_err().to_string(),
            "EMPTY has no signal \"s\" (it has no signals)"
        );
        let one = db.message("ONE").unwrap();
        let mut f = one.encode(&[]).unwrap();
        assert_eq!(
            one.set_named(&mut f, "s", "ON").unwrap_err().to_string(),
            "ONE.s has no value named \"ON\" (it has no value table)"
        );
    }
}
