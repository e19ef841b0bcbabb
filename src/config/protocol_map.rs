//! How each protocol maps a device to the wire: which line-protocol key carries which
//! reading and which word each state, which Modbus register holds the set point, the
//! state code, each reading and the status word, which PIDs an ELM327 reads. The
//! drivers and the simulated devices are built from these checked maps, so the host
//! side and the device side of a protocol always agree.

use super::device::{DeviceConfig, DriverKind, Mistake, ReadingKind};
use crate::value::Kind;
use serde::Deserialize;
use toml::Spanned;

/// A device's wire mapping, by protocol.
#[derive(Clone, Debug, PartialEq)]
pub enum Wire {
    Line(LineMap),
    Modbus(ModbusMap),
    Elm327(ElmMap),
    Can(Box<super::can::CanMap>),
}

/// The adrive line protocol: status keys by reading, words by state.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct LineMap {
    /// The status key of each reading, by reading index.
    pub keys: Vec<String>,
    /// The word of each of the device's states, by state index (commands and its
    /// `state` reading).
    pub words: Vec<String>,
    /// For each reading, the words of its states (empty for numbers and flags).
    pub(crate) reading_words: Vec<Vec<String>>,
    /// Which readings are flags (written 1 or 0).
    pub(crate) flags: Vec<bool>,
}

/// `[device.line]` as written.
#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct RawLine {
    #[serde(default)]
    keys: toml::Table,
    #[serde(default)]
    words: toml::Table,
}

/// The register table feedback is read from.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum RegisterKind {
    /// Read/write registers (function 03 to read); "4xxxx" in data sheets.
    Holding,
    /// Read-only registers (function 04); "3xxxx" in data sheets.
    #[default]
    Input,
}

/// value = raw × scale + offset, raw read as i16 or u16.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Scale {
    pub scale: f64,
    pub(crate) offset: f64,
    pub signed: bool,
}

impl Scale {
    pub(crate) const ONE: Scale = Scale {
        scale: 1.0,
        offset: 0.0,
        signed: false,
    };

    /// A register's raw contents as a number, by `signed`.
    pub fn number(&self, raw: u16) -> f64 {
        if self.signed {
            raw as i16 as f64
        } else {
            raw as f64
        }
    }

    /// value = raw × scale + offset.
    pub fn value(&self, raw: u16) -> f64 {
        self.number(raw) * self.scale + self.offset
    }

    /// raw = round((value − offset) / scale), or `None` when that does not fit.
    pub fn raw(&self, value: f64) -> Option<u16> {
        to_register((value - self.offset) / self.scale, self.signed)
    }

    /// The raw form of `value`, clamped into the register (device side: a reading
    /// outside what the register holds reads as its end).
    pub(crate) fn raw_clamped(&self, value: f64) -> u16 {
        let x = (value - self.offset) / self.scale;
        let x = if self.signed {
            x.clamp(i16::MIN as f64, i16::MAX as f64)
        } else {
            x.clamp(0.0, u16::MAX as f64)
        };
        to_register(x, self.signed).unwrap_or(0)
    }
}

/// `x` rounded into a register, or `None` when it does not fit.
pub fn to_register(x: f64, signed: bool) -> Option<u16> {
    let x = x.round();
    if !x.is_finite() {
        return None;
    }
    if signed {
        (i16::MIN as f64..=i16::MAX as f64)
            .contains(&x)
            .then_some(x as i16 as u16)
    } else {
        (0.0..=u16::MAX as f64).contains(&x).then_some(x as u16)
    }
}

/// What one feedback register holds.
#[derive(Clone, Debug, PartialEq)]
pub enum Field {
    /// Reading `index`, converted by `scale`; a state reading is a code (the device's
    /// own states through `codes`, other state readings by index); a flag is non-zero.
    Reading { index: usize, scale: Scale },
    /// The status word; its bits under `fault_mask` are faults.
    Status,
}

/// A Modbus RTU device's slave id and register map. Addresses are the 0-based ones on
/// the wire: data sheet 40001 is holding register 0, 30001 is input register 0.
#[derive(Clone, Debug, PartialEq)]
pub struct ModbusMap {
    pub slave: u8,
    /// Holding register that takes the set point or the state code (actuators).
    pub target: Option<u16>,
    /// Holding register of the drive's control word (see [`crate::value::Control`]).
    pub control: Option<u16>,
    /// The table feedback is read from.
    pub table: RegisterKind,
    /// The feedback registers, by address.
    pub fields: Vec<(u16, Field)>,
    pub fault_mask: u16,
    /// The set point's conversion.
    pub scale: Scale,
    /// The code of each of the device's states, by state index.
    pub codes: Vec<u16>,
    /// The kind of each reading, by index (to decode states and flags).
    pub kinds: Vec<ReadingKind>,
    /// Reading indices whose states are the device's own (decoded through `codes`).
    pub own_states: Vec<bool>,
}

/// A run of contiguous registers read in one transaction.
#[derive(Clone, Debug, PartialEq, Eq)]
pub(crate) struct Block {
    pub start: u16,
    /// Indices into [`ModbusMap::fields`].
    pub fields: Vec<usize>,
}

/// The most registers one read asks for (a Modbus limit).
pub(crate) const MAX_READ: usize = 125;

impl ModbusMap {
    /// The reads a poll makes: each run of adjacent feedback registers is one read
    /// (a device may refuse a read that spans an unmapped hole, so holes split runs).
    pub(crate) fn read_plan(&self) -> Vec<Block> {
        let mut blocks: Vec<Block> = Vec::new();
        for (i, (addr, _)) in self.fields.iter().enumerate() {
            match blocks.last_mut() {
                Some(b)
                    if b.start as u32 + b.fields.len() as u32 == *addr as u32
                        && b.fields.len() < MAX_READ =>
                {
                    b.fields.push(i)
                }
                _ => blocks.push(Block {
                    start: *addr,
                    fields: vec![i],
                }),
            }
        }
        blocks
    }

    /// The feedback field at `addr`, if any.
    pub(crate) fn field_at(&self, addr: u16) -> Option<&Field> {
        self.fields.iter().find(|(a, _)| *a == addr).map(|(_, f)| f)
    }

    /// The state index a code stands for.
    pub(crate) fn state_of_code(&self, code: u16) -> Option<u8> {
        self.codes.iter().position(|c| *c == code).map(|i| i as u8)
    }
}

/// `[device.modbus]` as written.
#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct RawModbus {
    slave: Spanned<i64>,
    registers: Spanned<toml::Table>,
    #[serde(default)]
    codes: Option<Spanned<toml::Table>>,
}

/// The ELM327's catalogue: which reading each PID fills.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct ElmMap {
    pub rpm: Option<usize>,
    pub speed: Option<usize>,
    pub coolant: Option<usize>,
    pub running: Option<usize>,
}

/// The readings an ELM327 can report.
pub(crate) const ELM327_READINGS: [&str; 4] = ["rpm", "speed", "coolant", "running"];

/// Check and build the wire mapping of `d` (whose wire field is not filled yet).
pub(super) fn resolve(
    d: &DeviceConfig,
    at_driver: usize,
    modbus: Option<Spanned<RawModbus>>,
    line: Option<Spanned<RawLine>>,
) -> Result<Wire, Mistake> {
    let name = &d.name;
    match (d.driver, modbus, line) {
        (DriverKind::Modbus, Some(m), None) => modbus_map(d, m),
        (DriverKind::Modbus, None, _) => Err((
            at_driver,
            format!("{name}: driver \"modbus\" needs a [device.modbus] table with `slave` and `registers`"),
        )),
        (DriverKind::Line, None, l) => line_map(d, l),
        (DriverKind::Elm327, None, None) => elm_map(d, at_driver),
        (driver, Some(m), _) if driver != DriverKind::Modbus => Err((
            m.span().start,
            format!("{name}: a [device.modbus] table goes with driver = \"modbus\" only"),
        )),
        (_, _, Some(l)) => Err((
            l.span().start,
            format!("{name}: a [device.line] table goes with driver = \"line\" only"),
        )),
        _ => unreachable!("every combination is listed"),
    }
}

fn line_map(d: &DeviceConfig, raw: Option<Spanned<RawLine>>) -> Result<Wire, Mistake> {
    let name = &d.name;
    let (at, raw) = match raw {
        Some(r) => (r.span().start, Some(r.into_inner())),
        None => (0, None),
    };
    let (keys_t, words_t) = raw.map(|r| (r.keys, r.words)).unwrap_or_default();
    let mut keys: Vec<String> = d
        .readings
        .iter()
        .map(|r| {
            super::device::well_known(&r.name).map_or(r.name.clone(), |w| w.line_key.to_string())
        })
        .collect();
    for (reading, key) in keys_t {
        let Some(i) = d.reading(&reading) else {
            return Err((
                at,
                format!(
                    "{name}: line.keys: {reading:?} is not one of its readings ({})",
                    reading_names(d)
                ),
            ));
        };
        let Some(key) = key.as_str().filter(|k| is_word(k)) else {
            return Err((
                at,
                format!(
                    "{name}: line.keys: {reading} = expected a key word in quotes (no spaces or =)"
                ),
            ));
        };
        keys[i] = key.to_string();
    }
    for (i, k) in keys.iter().enumerate() {
        if keys[..i].contains(k) {
            return Err((at, format!("{name}: line: two readings use the key {k:?}")));
        }
    }
    let mut words = d.states.clone();
    for (state, word) in words_t {
        let Some(i) = d.states.iter().position(|s| *s == state) else {
            return Err((
                at,
                format!(
                    "{name}: line.words: {state:?} is not one of its states ({})",
                    d.states.join(", ")
                ),
            ));
        };
        let Some(word) = word.as_str().filter(|w| is_word(w)) else {
            return Err((
                at,
                format!("{name}: line.words: {state} = expected a word in quotes (no spaces)"),
            ));
        };
        words[i] = word.to_string();
    }
    let reading_words = d
        .readings
        .iter()
        .map(|r| match &r.kind {
            ReadingKind::States(s) if *s == d.states => words.clone(),
            ReadingKind::States(s) => s.clone(),
            _ => Vec::new(),
        })
        .collect();
    let flags = d
        .readings
        .iter()
        .map(|r| r.kind == ReadingKind::Flag)
        .collect();
    Ok(Wire::Line(LineMap {
        keys,
        words,
        reading_words,
        flags,
    }))
}

fn is_word(s: &str) -> bool {
    !s.is_empty() && s.len() <= 24 && s.bytes().all(|b| b.is_ascii_graphic() && b != b'=')
}

fn reading_names(d: &DeviceConfig) -> String {
    d.readings
        .iter()
        .map(|r| r.name.as_str())
        .collect::<Vec<_>>()
        .join(", ")
}

fn elm_map(d: &DeviceConfig, at: usize) -> Result<Wire, Mistake> {
    let name = &d.name;
    if d.kind != Kind::Sensor {
        return Err((
            at,
            format!("{name}: the elm327 driver is for sensors (an OBD-II adapter only reports)"),
        ));
    }
    let mut m = ElmMap::default();
    for (i, r) in d.readings.iter().enumerate() {
        let slot = match r.name.as_str() {
            "rpm" => &mut m.rpm,
            "speed" => &mut m.speed,
            "coolant" => &mut m.coolant,
            "running" => &mut m.running,
            other => {
                return Err((
                    at,
                    format!(
                        "{name}: an ELM327 reports {}; it cannot report {other:?}",
                        ELM327_READINGS.join(", ")
                    ),
                ))
            }
        };
        *slot = Some(i);
    }
    Ok(Wire::Elm327(m))
}

fn reg(v: &toml::Value) -> Option<u16> {
    v.as_integer().and_then(|i| u16::try_from(i).ok())
}

fn modbus_map(d: &DeviceConfig, raw: Spanned<RawModbus>) -> Result<Wire, Mistake> {
    let name = &d.name;
    let raw = raw.into_inner();
    let slave = modbus_slave(name, &raw.slave)?;
    let at = raw.registers.span().start;
    let bad = |m: String| (at, format!("{name}: modbus.registers: {m}"));
    let r = Registers::parse(raw.registers.into_inner(), &bad)?;
    match (d.kind, r.target) {
        (Kind::Sensor, Some(_)) => {
            return Err(bad(
                "target: a sensor takes no commands; remove target".into()
            ))
        }
        (Kind::Setpoint | Kind::State, None) => {
            return Err(bad(format!(
                "target: expected the holding register that takes the {}",
                if d.kind == Kind::State {
                    "state code"
                } else {
                    "set point"
                }
            )))
        }
        _ => {}
    }
    let mut fields: Vec<(u16, Field)> = Vec::new();
    for (reading, v) in &r.readings {
        fields.push(reading_field(d, reading, v, r.scale, &bad)?);
    }
    if let Some(s) = r.status {
        fields.push((s, Field::Status));
    }
    fields.sort_by_key(|(a, _)| *a);
    check_fields(d, &fields, &bad)?;
    let codes = modbus_codes(d, raw.codes, at)?;
    let kinds = d.readings.iter().map(|r| r.kind.clone()).collect();
    let own_states = d
        .readings
        .iter()
        .map(|r| d.kind == Kind::State && r.kind == ReadingKind::States(d.states.clone()))
        .collect();
    Ok(Wire::Modbus(ModbusMap {
        slave,
        target: r.target,
        control: r.control,
        table: r.table,
        fields,
        fault_mask: r.fault_mask,
        scale: r.scale,
        codes,
        kinds,
        own_states,
    }))
}

/// `modbus.slave`, within the limits table's range (the one rule for a slave id).
fn modbus_slave(name: &str, slave: &Spanned<i64>) -> Result<u8, Mistake> {
    let at_slave = slave.span().start;
    let slave = *slave.get_ref();
    let limit = &super::limits::MODBUS_SLAVE;
    let slave = u64::try_from(slave)
        .map_err(|_| {
            limit.violation(format!(
                "{}: expected {}, got {slave}",
                limit.name(),
                limit.expected()
            ))
        })
        .and_then(|s| limit.check(s))
        .map_err(|v| (at_slave, format!("{name}: {}", v.message)))? as u8;
    Ok(slave)
}

/// `modbus.registers` as written: the device's own registers and defaults, and the
/// keys left over (its readings, checked against the device after).
struct Registers {
    target: Option<u16>,
    control: Option<u16>,
    status: Option<u16>,
    fault_mask: u16,
    table: RegisterKind,
    scale: Scale,
    readings: Vec<(String, toml::Value)>,
}

impl Registers {
    fn parse(table: toml::Table, bad: &dyn Fn(String) -> Mistake) -> Result<Registers, Mistake> {
        let mut r = Registers {
            target: None,
            control: None,
            status: None,
            fault_mask: 0xFFFF,
            table: RegisterKind::Input,
            scale: Scale::ONE,
            readings: Vec::new(),
        };
        for (key, v) in table {
            let addr = || {
                reg(&v).ok_or_else(|| {
                    bad(format!(
                        "{key}: expected a register address from 0 to 65535"
                    ))
                })
            };
            match key.as_str() {
                "target" => r.target = Some(addr()?),
                "control" => r.control = Some(addr()?),
                "status" => r.status = Some(addr()?),
                "fault_mask" => r.fault_mask = addr()?,
                "table" | "position_kind" => {
                    r.table = match v.as_str() {
                        Some("input") => RegisterKind::Input,
                        Some("holding") => RegisterKind::Holding,
                        _ => return Err(bad(format!("{key}: expected \"input\" or \"holding\""))),
                    }
                }
                "scale" => {
                    r.scale.scale = number(&v)
                        .filter(|s| *s != 0.0)
                        .ok_or_else(|| bad("scale: expected a finite number other than 0".into()))?
                }
                "offset" => {
                    r.scale.offset =
                        number(&v).ok_or_else(|| bad("offset: expected a finite number".into()))?
                }
                "signed" => {
                    r.scale.signed = v
                        .as_bool()
                        .ok_or_else(|| bad("signed: expected true or false".into()))?
                }
                _ => r.readings.push((key, v)),
            }
        }
        Ok(r)
    }
}

/// One reading's register: an address, or `{ register = N, scale = … }` over the
/// reading's default scale (the device's for its position and velocity).
fn reading_field(
    d: &DeviceConfig,
    reading: &str,
    v: &toml::Value,
    scale: Scale,
    bad: &dyn Fn(String) -> Mistake,
) -> Result<(u16, Field), Mistake> {
    let Some(index) = d.reading(reading) else {
        return Err(bad(format!(
            "unknown key {reading:?}: expected target, control, status, fault_mask, table, scale, offset, signed, or one of its readings ({})",
            reading_names(d)
        )));
    };
    let default = match reading {
        super::device::POSITION => scale,
        "velocity" => Scale {
            offset: 0.0,
            ..scale
        },
        _ => Scale {
            signed: scale.signed,
            ..Scale::ONE
        },
    };
    let (addr, s) = match v {
        toml::Value::Integer(_) => (
            reg(v).ok_or_else(|| {
                bad(format!(
                    "{reading}: expected a register address from 0 to 65535"
                ))
            })?,
            default,
        ),
        toml::Value::Table(t) => {
            let mut s = default;
            let mut addr = None;
            for (k, x) in t {
                match k.as_str() {
                    "register" => addr = reg(x),
                    "scale" => s.scale = number(x).filter(|s| *s != 0.0).ok_or_else(|| bad(format!("{reading}.scale: expected a finite number other than 0")))?,
                    "offset" => s.offset = number(x).ok_or_else(|| bad(format!("{reading}.offset: expected a finite number")))?,
                    "signed" => s.signed = x.as_bool().ok_or_else(|| bad(format!("{reading}.signed: expected true or false")))?,
                    other => return Err(bad(format!("{reading}: unknown key {other:?}; expected register, scale, offset, signed"))),
                }
            }
            (
                addr.ok_or_else(|| {
                    bad(format!(
                        "{reading}: expected {{ register = N, scale = …, offset = …, signed = … }}"
                    ))
                })?,
                s,
            )
        }
        _ => {
            return Err(bad(format!(
                "{reading}: expected a register address or {{ register = N, scale = … }}"
            )))
        }
    };
    Ok((addr, Field::Reading { index, scale: s }))
}

/// The feedback fields, sorted by address: no two share a register, and every
/// reading has one.
fn check_fields(
    d: &DeviceConfig,
    fields: &[(u16, Field)],
    bad: &dyn Fn(String) -> Mistake,
) -> Result<(), Mistake> {
    for w in fields.windows(2) {
        if w[0].0 == w[1].0 {
            return Err(bad(format!(
                "two feedback fields share register {}",
                w[0].0
            )));
        }
    }
    for (i, r) in d.readings.iter().enumerate() {
        if !fields
            .iter()
            .any(|(_, f)| matches!(f, Field::Reading { index, .. } if *index == i))
        {
            return Err(bad(format!(
                "reading {} has no register (add {} = ADDRESS)",
                r.name, r.name
            )));
        }
    }
    Ok(())
}

/// `modbus.codes`: a state device's code for each of its states, each once; no other
/// device has them.
fn modbus_codes(
    d: &DeviceConfig,
    codes: Option<Spanned<toml::Table>>,
    at: usize,
) -> Result<Vec<u16>, Mistake> {
    let name = &d.name;
    match (d.kind, codes) {
        (Kind::State, None) => Err((
            at,
            format!(
                "{name}: modbus.codes: expected the code of each state, e.g. codes = {{ {} }}",
                d.states
                    .iter()
                    .enumerate()
                    .map(|(i, s)| format!("{s} = {i}"))
                    .collect::<Vec<_>>()
                    .join(", ")
            ),
        )),
        (Kind::State, Some(c)) => {
            let at = c.span().start;
            let mut codes: Vec<Option<u16>> = vec![None; d.states.len()];
            for (state, v) in c.into_inner() {
                let Some(i) = d.states.iter().position(|s| *s == state) else {
                    return Err((
                        at,
                        format!(
                            "{name}: modbus.codes: {state:?} is not one of its states ({})",
                            d.states.join(", ")
                        ),
                    ));
                };
                codes[i] = Some(reg(&v).ok_or_else(|| {
                    (
                        at,
                        format!("{name}: modbus.codes: {state} = expected a code from 0 to 65535"),
                    )
                })?);
            }
            let mut out = Vec::new();
            for (i, c) in codes.into_iter().enumerate() {
                let Some(c) = c else {
                    return Err((
                        at,
                        format!("{name}: modbus.codes: state {} has no code", d.states[i]),
                    ));
                };
                if out.contains(&c) {
                    return Err((at, format!("{name}: modbus.codes: code {c} is used twice")));
                }
                out.push(c);
            }
            Ok(out)
        }
        (_, Some(c)) => Err((
            c.span().start,
            format!("{name}: modbus.codes are for state devices"),
        )),
        (_, None) => Ok(Vec::new()),
    }
}

fn number(v: &toml::Value) -> Option<f64> {
    v.as_float()
        .or_else(|| v.as_integer().map(|i| i as f64))
        .filter(|x| x.is_finite())
}
