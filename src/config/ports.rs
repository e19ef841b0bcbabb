//! Every serial port of a vehicle has one user: a device, or a CAN bus's adapter. Two
//! on one port would fight over it — two `[[bus]]` tables on one adapter would each
//! start a reader — and one port has many spellings: `/dev/ttyUSB0` and
//! `/dev/./ttyUSB0`, a `/dev/serial/by-id/…` link and its target. So ports are compared
//! by what they resolve to ([`Resolved`]): the device number (`st_rdev`) where both are
//! device files, else the canonical path where the port exists, else — a port not
//! plugged in yet — its path with `.`, `..` and repeated slashes taken out (below its
//! longest existing directory, itself canonical). A file that names a port twice is
//! refused at the second's line, naming the first with its own.

use super::device::DriverKind;
use super::limits::Violation;
use super::{ConfigError, VehicleConfig};
use std::os::unix::fs::FileTypeExt;
use std::os::unix::fs::MetadataExt;
use std::path::{Component, Path, PathBuf};

/// A port as the system resolves it.
#[derive(Clone, Debug, PartialEq, Eq)]
pub(crate) struct Resolved {
    /// The canonical path (or, for a port that does not exist, the normalized one).
    pub path: PathBuf,
    /// The device number, for a character or block device.
    pub rdev: Option<u64>,
}

impl Resolved {
    /// Resolve `port` (relative: to the working directory, where it is opened).
    pub(crate) fn of(port: &str) -> Resolved {
        let path = Path::new(port);
        let rdev = std::fs::metadata(path).ok().and_then(|m| {
            let t = m.file_type();
            (t.is_char_device() || t.is_block_device()).then(|| m.rdev())
        });
        Resolved {
            path: canonical(path),
            rdev,
        }
    }

    /// The two are one port.
    pub(crate) fn same(&self, other: &Resolved) -> bool {
        match (self.rdev, other.rdev) {
            (Some(a), Some(b)) => a == b,
            _ => self.path == other.path,
        }
    }
}

/// The canonical path of `path` where it exists; else that of its longest existing
/// ancestor, with the rest normalized.
fn canonical(path: &Path) -> PathBuf {
    if let Ok(c) = std::fs::canonicalize(path) {
        return c;
    }
    let absolute = if path.is_absolute() {
        path.to_path_buf()
    } else {
        std::env::current_dir().unwrap_or_default().join(path)
    };
    let normal = normalize(&absolute);
    let mut rest = Vec::new();
    let mut at = normal.as_path();
    loop {
        if let Ok(c) = std::fs::canonicalize(at) {
            return rest.iter().rev().fold(c, |p, name| p.join(name));
        }
        match (at.parent(), at.file_name()) {
            (Some(parent), Some(name)) => {
                rest.push(name.to_os_string());
                at = parent;
            }
            _ => return normal,
        }
    }
}

/// `path` without `.` and with each `..` taking out the name before it.
fn normalize(path: &Path) -> PathBuf {
    let mut out = PathBuf::new();
    for c in path.components() {
        match c {
            Component::CurDir => {}
            Component::ParentDir => {
                out.pop();
            }
            c => out.push(c),
        }
    }
    out
}

/// Who uses a port: a device or a bus's adapter.
struct User<'a> {
    /// `device.steer`, `bus.kit`: where its keys are.
    owner: String,
    /// `steer's port`, `the adapter of bus kit`.
    what: String,
    port: &'a str,
    resolved: Resolved,
    /// The line of its `port` key (else of its table).
    line: usize,
}

impl User<'_> {
    /// The bus, for a bus's adapter.
    fn bus(&self) -> Option<&str> {
        self.owner.strip_prefix("bus.")
    }
}

impl VehicleConfig {
    /// The user of a port: a `device` or a `bus`, by name.
    fn user<'a>(&self, table: &str, name: &str, port: &'a str) -> User<'a> {
        let owner = format!("{table}.{name}");
        User {
            line: self.lines.first(&[format!("{owner}.port"), owner.clone()]),
            what: match table {
                "bus" => format!("the adapter of bus {name}"),
                _ => format!("{name}'s port"),
            },
            resolved: Resolved::of(port),
            owner,
            port,
        }
    }

    /// Every device that is not simulated needs a port to open, and every port has one
    /// user: a device, or a bus's adapter (devices that share a wire are on a CAN
    /// `[[bus]]`, whose adapter's port is the bus's). Ports are compared by what they
    /// resolve to ([`Resolved`]).
    pub(crate) fn check_ports(&self) -> Result<(), ConfigError> {
        for b in &self.buses {
            if b.port.trim().is_empty() {
                let v = Violation {
                    paths: vec!["port".into()],
                    message: format!(
                        "port: expected the path of the SLCAN adapter's serial port \
                         (\"/dev/ttyACM0\", \"/dev/serial/by-id/…\"), got {:?}; without \
                         hardware, run with --sim",
                        b.port
                    ),
                };
                return Err(self.refuse(&format!("bus.{}", b.name), v));
            }
        }
        for d in self.devices.iter().filter(|d| d.driver != DriverKind::Can) {
            if d.port.trim().is_empty() {
                let v = Violation {
                    paths: vec!["port".into()],
                    message: format!(
                        "port: expected the path of a serial port (\"/dev/ttyUSB0\", \
                         \"/dev/serial/by-id/…\"), got {:?}; without hardware, run with --sim",
                        d.port
                    ),
                };
                return Err(self.refuse(&format!("device.{}", d.name), v));
            }
        }
        let mut users: Vec<User<'_>> = self
            .buses
            .iter()
            .map(|b| self.user("bus", &b.name, &b.port))
            .chain(
                self.devices
                    .iter()
                    .filter(|d| d.driver != DriverKind::Can)
                    .map(|d| self.user("device", &d.name, &d.port)),
            )
            .collect();
        // The second in the file is the one at fault.
        users.sort_by_key(|u| u.line);
        for (i, second) in users.iter().enumerate() {
            let Some(first) = users[..i]
                .iter()
                .find(|f| f.resolved.same(&second.resolved))
            else {
                continue;
            };
            let named = if first.port == second.port {
                format!("{} is {} too", second.port, first.what)
            } else if first.resolved.path == second.resolved.path {
                format!(
                    "{} is {}, {}, by another name (both are {})",
                    second.port,
                    first.what,
                    first.port,
                    first.resolved.path.display()
                )
            } else {
                let rdev = first.resolved.rdev.unwrap_or_default();
                format!(
                    "{} is {}, {}, by another name (both are device {}:{})",
                    second.port,
                    first.what,
                    first.port,
                    libc::major(rdev),
                    libc::minor(rdev)
                )
            };
            let at = match first.line {
                0 => self.source.clone(),
                l => format!("{}:{l}", self.source),
            };
            let why = match (first.bus(), second.bus()) {
                (None, None) => "a serial port has one device".to_string(),
                (Some(bus), None) => {
                    format!("a device on the bus is `driver = \"can\"`, `bus = \"{bus}\"`")
                }
                (None, Some(_)) => "a CAN adapter's port is its bus's alone".to_string(),
                (Some(_), Some(_)) => {
                    "one adapter is one bus: its devices go on one [[bus]]".to_string()
                }
            };
            let v = Violation {
                paths: vec!["port".into()],
                message: format!("port: {named} ({at}): {why}"),
            };
            return Err(self.refuse(&second.owner, v));
        }
        Ok(())
    }
}
