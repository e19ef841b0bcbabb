//! The vehicle file as a TOML document, before serde gives it types.
//!
//! Serde knows the types but not the lines; this module knows where every key is. It
//! serves three kinds of error that must name a line: a syntax error told in the user's
//! terms (a misspelt table header rather than the "duplicate key" it causes twenty
//! lines later, a duplicate key named), a value that serde refuses (told with the key's
//! range from [`limits`]), and a check made after typing — a range, a rule between two
//! keys, a port that is missing outside `--sim`, a key file that cannot be read — which
//! asks [`Lines`] for the line of its key.

use super::limits;
use super::ConfigError;
use std::ops::Range;
use toml::de::{DeString, DeTable, DeValue};
use toml::Spanned;

/// Top-level tables of a vehicle file.
const TABLES: [&str; 10] = [
    "vehicle",
    "bus",
    "network",
    "console",
    "supervisor",
    "record",
    "ros2",
    "teleop",
    "fleet",
    "device",
];
/// Tables inside a `[[device]]` (headers, or keys whose value may be a table).
const DEVICE_TABLES: [&str; 7] = [
    "sim", "modbus", "line", "can", "response", "aliases", "readings",
];
/// What the headers of a vehicle file are, for messages.
const HEADERS: &str = "[vehicle] (with [vehicle.roles], [vehicle.gear]), [network], [console], [supervisor], [record], [ros2], [teleop], [fleet], [[bus]] (with [bus.sim]), [[device]] (with [device.sim], [device.modbus], [device.line], [device.can], [device.response])";

/// The line of every key and table of a vehicle file, by path: `network.listen`,
/// `device.steer` (its `[[device]]` header), `device.steer.sim.watchdog`. A device is
/// named by its `name` (unique once loaded), else by its index.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Lines {
    keys: Vec<(String, usize)>,
}

impl Lines {
    /// The line of `path`, if the file writes it.
    pub fn get(&self, path: &str) -> Option<usize> {
        self.keys.iter().find(|(p, _)| p == path).map(|&(_, l)| l)
    }

    /// The line of the first of `paths` the file writes; else 0, the file as a whole
    /// (a default that the file does not write is at no line of it).
    pub fn first(&self, paths: &[impl AsRef<str>]) -> usize {
        paths.iter().find_map(|p| self.get(p.as_ref())).unwrap_or(0)
    }
}

/// One key with its value's bytes: what [`Lines`] is built from.
struct Key {
    path: String,
    line: usize,
    value: Range<usize>,
}

/// A parsed vehicle file: where its keys are.
pub(crate) struct Document<'a> {
    text: &'a str,
    path: &'a str,
    keys: Vec<Key>,
}

impl<'a> Document<'a> {
    /// Parse `text` as TOML. A syntax error names its line; when a table header the
    /// vehicle file does not have comes first, that is named instead, as the likely
    /// cause (`[[devcie]]` makes the next `[device.modbus]` a duplicate).
    pub(crate) fn parse(text: &'a str, path: &'a str) -> Result<Document<'a>, ConfigError> {
        let (table, errors) = DeTable::parse_recoverable(text);
        let mut doc = Document {
            text,
            path,
            keys: Vec::new(),
        };
        doc.walk(table.get_ref(), "");
        let first_error = errors.first().map(|e| e.span().map_or(0, |s| s.start));
        if let Some(e) = doc.unknown_table(table.get_ref()) {
            if first_error.is_none_or(|at| e.line <= doc.line(at)) {
                return Err(e);
            }
        }
        match errors.into_iter().next() {
            None => Ok(doc),
            Some(e) => Err(doc.syntax_error(&e)),
        }
    }

    /// A configuration error at byte `offset`.
    pub(crate) fn error_at(&self, offset: usize, message: String) -> ConfigError {
        ConfigError {
            path: self.path.to_string(),
            line: self.line(offset),
            message: suggest_key(message),
        }
    }

    fn line(&self, offset: usize) -> usize {
        line_of(self.text, offset)
    }

    /// Every key's line, for checks after typing.
    pub(crate) fn lines(&self) -> Lines {
        Lines {
            keys: self.keys.iter().map(|k| (k.path.clone(), k.line)).collect(),
        }
    }

    /// The key whose value holds byte `offset` (the innermost one).
    fn key_at(&self, offset: usize) -> Option<&Key> {
        self.keys
            .iter()
            .filter(|k| k.value.contains(&offset))
            .min_by_key(|k| k.value.len())
    }

    /// A value serde refused, at `span`: named by its key, with the key's range when it
    /// has one (`attempts = -1`: "attempts: expected a whole number from 1 to 10, got -1").
    /// A field missing from the root (a table the file lacks) is about the file as a
    /// whole: it names no line, since no line is at fault.
    pub(crate) fn type_error(&self, span: Option<Range<usize>>, message: &str) -> ConfigError {
        let offset = span.map_or(0, |s| s.start);
        let Some(key) = self.key_at(offset) else {
            if !message.starts_with("missing field") {
                return self.error_at(offset, message.to_string());
            }
            let message = match message {
                "missing field `vehicle`" => {
                    "no [vehicle] table: a vehicle file has [vehicle] with name = \"…\"".into()
                }
                m => m.to_string(),
            };
            return ConfigError {
                path: self.path.to_string(),
                line: 0,
                message,
            };
        };
        let name = key.path.rsplit('.').next().unwrap_or(&key.path);
        let got = self.text[key.value.clone()].trim();
        let ctx = context(&key.path);
        let whole_device = key.path.starts_with("device.") && key.path.split('.').count() == 2;
        let message = match limit_of(&key.path) {
            Some(row) => format!(
                "{ctx}{}: expected {}, got {got}",
                row.name(),
                row.expected()
            ),
            None if whole_device
                || message.contains(&format!("`{name}`"))
                || message.starts_with(name) =>
            {
                format!("{ctx}{message}")
            }
            None => format!("{ctx}{name}: {message}"),
        };
        self.error_at(offset, message)
    }

    fn syntax_error(&self, e: &toml::de::Error) -> ConfigError {
        let span = e.span().unwrap_or(0..0);
        let message = e.message().trim();
        if message.starts_with("duplicate key") && !span.is_empty() {
            let key = self.text[span.clone()].trim();
            return self.error_at(
                span.start,
                format!("duplicate key `{key}`: each key is written once in its table"),
            );
        }
        self.error_at(span.start, message.to_string())
    }

    /// The first table the vehicle file has no place for, if any.
    fn unknown_table(&self, root: &DeTable<'_>) -> Option<ConfigError> {
        let mut unknown: Vec<(usize, String)> = Vec::new();
        for (k, v) in root {
            if is_table(v.get_ref()) && !TABLES.contains(&k.get_ref().as_ref()) {
                unknown.push((k.span().start, header(k.get_ref(), v.get_ref(), None)));
            }
        }
        if let Some(DeValue::Array(devices)) = root.get("device").map(|v| v.get_ref()) {
            for d in devices {
                let Some(t) = d.get_ref().as_table() else {
                    continue;
                };
                for (k, v) in t {
                    if is_table(v.get_ref()) && !DEVICE_TABLES.contains(&k.get_ref().as_ref()) {
                        unknown.push((
                            k.span().start,
                            header(k.get_ref(), v.get_ref(), Some("device")),
                        ));
                    }
                }
            }
        }
        let (at, name) = unknown.into_iter().min_by_key(|(at, _)| *at)?;
        let hint = suggest(&name)
            .map(|s| format!("did you mean {s}? "))
            .unwrap_or_default();
        Some(self.error_at(
            at,
            format!("unknown table {name}: {hint}a vehicle file has {HEADERS}"),
        ))
    }

    fn walk(&mut self, table: &DeTable<'_>, prefix: &str) {
        for (k, v) in table {
            let path = format!("{prefix}{}", k.get_ref());
            self.push(&path, k, v);
            match v.get_ref() {
                DeValue::Table(t) => self.walk(t, &format!("{path}.")),
                DeValue::Array(items) if path == "device" || path == "bus" => {
                    for (i, item) in items.iter().enumerate() {
                        let Some(t) = item.get_ref().as_table() else {
                            continue;
                        };
                        let name = t
                            .get("name")
                            .and_then(|n| n.get_ref().as_str())
                            .map_or_else(|| i.to_string(), str::to_string);
                        let path = format!("{path}.{name}");
                        // The `[[device]]` (`[[bus]]`) header, or the inline table.
                        let line = self.line(item.span().start);
                        self.keys.push(Key {
                            path: path.clone(),
                            line,
                            value: item.span(),
                        });
                        self.walk(t, &format!("{path}."));
                    }
                }
                _ => {}
            }
        }
    }

    fn push(&mut self, path: &str, k: &Spanned<DeString<'_>>, v: &Spanned<DeValue<'_>>) {
        let line = self.line(k.span().start);
        self.keys.push(Key {
            path: path.to_string(),
            line,
            value: v.span(),
        });
    }
}

/// What a message about `path` starts with: the device (`steer: `) or the section
/// (`[network] `) it is in.
pub(crate) fn context(path: &str) -> String {
    match path.split('.').collect::<Vec<_>>()[..] {
        ["device", name, ..] => format!("{name}: "),
        ["bus", name, ..] => format!("bus {name}: "),
        [section @ ("network" | "console" | "supervisor" | "record" | "ros2" | "teleop"
        | "fleet"), ..] => {
            format!("[{section}] ")
        }
        _ => String::new(),
    }
}

/// The limit of the key at `path`, if it has one: `device.steer.sim.watchdog` is
/// `[device.sim]` `watchdog`.
fn limit_of(path: &str) -> Option<&'static dyn limits::Row> {
    use limits::Section;
    let parts: Vec<&str> = path.split('.').collect();
    let (section, key) = match parts[..] {
        ["network", key] => (Section::Network, key),
        ["console", key] => (Section::Console, key),
        ["supervisor", key] => (Section::Supervisor, key),
        ["ros2", key] => (Section::Ros2, key),
        ["teleop", key] => (Section::Teleop, key),
        ["device", _, key] => (Section::Device, key),
        ["device", _, "sim", key] => (Section::DeviceSim, key),
        ["device", _, "modbus", key] => (Section::DeviceModbus, key),
        ["device", _, "response", key] => (Section::DeviceResponse, key),
        _ => return None,
    };
    limits::find(section, key)
}

/// A table, or an array of tables: what a header writes. (An unknown plain key is
/// serde's to name, with the keys it expected.)
fn is_table(v: &DeValue<'_>) -> bool {
    match v {
        DeValue::Table(_) => true,
        DeValue::Array(items) => items.iter().all(|i| i.get_ref().is_table()) && !items.is_empty(),
        _ => false,
    }
}

/// How a table was written: `[[devcie]]`, `[netwrok]`, `[device.simm]`.
fn header(key: &str, value: &DeValue<'_>, parent: Option<&str>) -> String {
    let name = match parent {
        Some(p) => format!("{p}.{key}"),
        None => key.to_string(),
    };
    match value {
        DeValue::Array(_) => format!("[[{name}]]"),
        _ => format!("[{name}]"),
    }
}

/// The header a misspelt one most likely meant.
fn suggest(written: &str) -> Option<String> {
    let known = [
        "[vehicle]",
        "[vehicle.roles]",
        "[vehicle.gear]",
        "[network]",
        "[supervisor]",
        "[record]",
        "[ros2]",
        "[teleop]",
        "[fleet]",
        "[[device]]",
        "[[bus]]",
        "[bus.sim]",
        "[device.can]",
        "[device.sim]",
        "[device.modbus]",
        "[device.line]",
        "[device.response]",
    ];
    known
        .iter()
        .map(|k| (strsim::damerau_levenshtein(k, written), k))
        .filter(|(d, _)| *d <= 3)
        .min_by_key(|(d, _)| *d)
        .map(|(_, k)| k.to_string())
}

/// serde's "unknown field `baud_rate`, expected one of `name`, …, `baud`, …" with the
/// key it most likely meant named first: "unknown field `baud_rate`: did you mean
/// `baud`? expected one of …". Likely is a key one or two edits away (`allow_engag`),
/// else a key the written one begins or ends with (`baud_rate`, `my_baud`), else one a
/// few edits away for its length.
fn suggest_key(message: String) -> String {
    const SEP: &str = ", expected one of ";
    let Some(start) = message.find("unknown field `") else {
        return message;
    };
    let Some(sep) = message[start..].find(SEP).map(|i| start + i) else {
        return message;
    };
    let written = message[start + "unknown field `".len()..sep].trim_end_matches('`');
    let known: Vec<&str> = message[sep + SEP.len()..]
        .split(", ")
        .map(|k| k.trim_matches('`'))
        .collect();
    let nearest = known
        .iter()
        .map(|k| (strsim::damerau_levenshtein(k, written), *k))
        .min_by_key(|(d, _)| *d);
    let affix = known
        .iter()
        .filter(|k| k.len() >= 3 && (written.starts_with(**k) || written.ends_with(**k)))
        .max_by_key(|k| k.len())
        .copied();
    let meant = match nearest {
        Some((d, k)) if d <= 2 => Some(k),
        _ => affix.or(nearest.filter(|(d, k)| *d <= k.len() / 4).map(|(_, k)| k)),
    };
    match meant {
        Some(k) => format!(
            "{}: did you mean `{k}`? expected one of {}",
            &message[..sep],
            &message[sep + SEP.len()..]
        ),
        None => message,
    }
}

/// The 1-based line of byte `offset`.
pub(crate) fn line_of(text: &str, offset: usize) -> usize {
    text.as_bytes()[..offset.min(text.len())]
        .iter()
        .filter(|&&b| b == b'\n')
        .count()
        + 1
}

/// `bytes` as text; a byte that is not UTF-8 is named with its line.
pub(crate) fn utf8<'b>(bytes: &'b [u8], path: &str) -> Result<&'b str, ConfigError> {
    std::str::from_utf8(bytes).map_err(|e| {
        let at = e.valid_up_to();
        let text = std::str::from_utf8(&bytes[..at]).expect("valid up to here");
        let column = text.len() - text.rfind('\n').map_or(0, |i| i + 1) + 1;
        ConfigError {
            path: path.to_string(),
            line: line_of(text, at),
            message: format!(
                "byte 0x{:02x} at column {column} is not UTF-8: a vehicle file is UTF-8 text",
                bytes[at]
            ),
        }
    })
}
