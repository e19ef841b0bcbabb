//! `adrive ports`: the serial ports this machine has, with what the OS knows of each —
//! the stable `/dev/serial/by-id` name, USB vendor, product and serial number, the
//! kernel driver, and for USB serial adapters the driver's `latency_timer`. An FTDI
//! adapter defaults to 16 ms there, which adds up to 16 ms to every transaction: the
//! listing warns and says how to fix it. Pseudo-terminals are listed too, those of a
//! running `adrive sim` by the device each simulates.
//!
//! Read straight from sysfs and /dev, so it needs no libudev; the roots are parameters
//! so tests run it on a fake tree.

use std::fmt::Write as _;
use std::fs;
use std::path::{Path, PathBuf};

/// USB identity of an adapter.
#[derive(Clone, Debug, Default, PartialEq)]
pub(crate) struct Usb {
    pub(crate) vid: String,
    pub pid: String,
    pub(crate) manufacturer: Option<String>,
    pub product: Option<String>,
    pub serial: Option<String>,
}

/// One port.
#[derive(Clone, Debug, Default, PartialEq)]
pub(crate) struct PortInfo {
    /// `/dev/ttyUSB0`.
    pub path: PathBuf,
    /// Links in `/dev/serial/by-id` that point at it.
    pub by_id: Vec<PathBuf>,
    pub driver: Option<String>,
    pub usb: Option<Usb>,
    /// The USB serial driver's latency timer, ms.
    pub(crate) latency_timer_ms: Option<u32>,
}

impl PortInfo {
    /// The latency timer is above 1 ms.
    pub(crate) fn slow_latency(&self) -> bool {
        self.latency_timer_ms.is_some_and(|ms| ms > 1)
    }
}

fn read(dir: &Path, file: &str) -> Option<String> {
    fs::read_to_string(dir.join(file))
        .ok()
        .map(|s| s.trim().to_string())
        .filter(|s| !s.is_empty())
}

/// Serial hardware ports under `sys` (normally `/sys`) with device nodes under `dev`
/// (normally `/dev`).
pub(crate) fn scan(sys: &Path, dev: &Path) -> Vec<PortInfo> {
    let by_id: Vec<(PathBuf, PathBuf)> = fs::read_dir(dev.join("serial/by-id"))
        .into_iter()
        .flatten()
        .flatten()
        .filter_map(|e| {
            let link = e.path();
            let target = fs::read_link(&link).ok()?;
            let target = if target.is_absolute() {
                target
            } else {
                link.parent()?.join(target)
            };
            Some((link, normalize(&target)))
        })
        .collect();
    let mut ports = Vec::new();
    let Ok(entries) = fs::read_dir(sys.join("class/tty")) else {
        return ports;
    };
    for e in entries.flatten() {
        let name = e.file_name().to_string_lossy().to_string();
        let class_dir = e.path();
        let device = class_dir.join("device");
        let Ok(device) = fs::canonicalize(&device) else {
            // Virtual terminals, pty masters: no device behind them.
            continue;
        };
        // The nearest real driver: newer kernels put generic `ctrl` and `port` devices
        // of the serial-base bus between the tty and its UART driver.
        let driver = device.ancestors().find_map(|d| {
            let link = fs::read_link(d.join("driver")).ok()?;
            let bus = link
                .parent()?
                .parent()?
                .file_name()?
                .to_string_lossy()
                .to_string();
            let name = link.file_name()?.to_string_lossy().to_string();
            (bus != "serial-base").then_some(name)
        });
        // The 8250 driver lists ttyS0…31 whether or not a UART exists; type 0 means
        // none is there.
        if read(&class_dir, "type").as_deref() == Some("0") {
            continue;
        }
        let usb = device
            .ancestors()
            .find(|d| d.join("idVendor").exists())
            .map(|d| Usb {
                vid: read(d, "idVendor").unwrap_or_default(),
                pid: read(d, "idProduct").unwrap_or_default(),
                manufacturer: read(d, "manufacturer"),
                product: read(d, "product"),
                serial: read(d, "serial"),
            });
        let path = dev.join(&name);
        ports.push(PortInfo {
            by_id: by_id
                .iter()
                .filter(|(_, t)| *t == path)
                .map(|(l, _)| l.clone())
                .collect(),
            latency_timer_ms: read(&device, "latency_timer").and_then(|s| s.parse().ok()),
            path,
            driver,
            usb,
        });
    }
    ports.sort_by(|a, b| a.path.cmp(&b.path));
    ports
}

/// Resolve `.` and `..` without touching the file system.
fn normalize(p: &Path) -> PathBuf {
    let mut out = PathBuf::new();
    for c in p.components() {
        match c {
            std::path::Component::ParentDir => {
                out.pop();
            }
            std::path::Component::CurDir => {}
            c => out.push(c),
        }
    }
    out
}

/// Pseudo-terminals under `dev/pts`.
pub(crate) fn pseudo_terminals(dev: &Path) -> Vec<PathBuf> {
    let mut v: Vec<PathBuf> = fs::read_dir(dev.join("pts"))
        .into_iter()
        .flatten()
        .flatten()
        .filter(|e| e.file_name().to_string_lossy().parse::<u32>().is_ok())
        .map(|e| e.path())
        .collect();
    v.sort_by_key(|p| {
        p.file_name()
            .and_then(|n| n.to_string_lossy().parse::<u32>().ok())
            .unwrap_or(0)
    });
    v
}

/// A simulated device's pseudo-terminal, found through the link `adrive sim` keeps to
/// it (`$TMPDIR/adrive-sim-PID-N/steer`, see [`crate::sim`]).
#[derive(Clone, Debug, PartialEq)]
pub(crate) struct SimLink {
    /// `/dev/pts/5`.
    pub pty: PathBuf,
    /// The link a vehicle file names: `/tmp/adrive-sim-1234-0/steer`.
    pub link: PathBuf,
    pub device: String,
    /// The process simulating it.
    pub pid: u32,
}

/// The devices simulated by every `adrive sim` (or `adrive --sim`) still running: their
/// directories of links under `tmp` (normally the temporary directory), whose process
/// is alive under `proc` (normally `/proc`). A directory left by a killed simulator
/// is skipped: its links may point at pseudo-terminals reused by others.
pub(crate) fn simulated(tmp: &Path, proc: &Path) -> Vec<SimLink> {
    let mut out = Vec::new();
    for dir in fs::read_dir(tmp).into_iter().flatten().flatten() {
        let name = dir.file_name().to_string_lossy().to_string();
        let Some(pid) = name
            .strip_prefix("adrive-sim-")
            .and_then(|rest| rest.split('-').next())
            .and_then(|pid| pid.parse::<u32>().ok())
        else {
            continue;
        };
        if !proc.join(pid.to_string()).exists() {
            continue;
        }
        for link in fs::read_dir(dir.path()).into_iter().flatten().flatten() {
            let Ok(pty) = fs::read_link(link.path()) else {
                continue;
            };
            out.push(SimLink {
                pty,
                link: link.path(),
                device: link.file_name().to_string_lossy().to_string(),
                pid,
            });
        }
    }
    out.sort_by(|a, b| (&a.link, &a.pty).cmp(&(&b.link, &b.pty)));
    out
}

/// The listing `adrive ports` prints.
pub(crate) fn report(ports: &[PortInfo], ptys: &[PathBuf], sims: &[SimLink]) -> String {
    let mut out = String::new();
    if ports.is_empty() {
        out.push_str("no serial ports found: no USB serial adapters (ttyUSB, ttyACM) and no serial hardware.\n");
    }
    for p in ports {
        let _ = write!(out, "{}", p.path.display());
        if let Some(d) = &p.driver {
            let _ = write!(out, "  driver {d}");
        }
        if let Some(u) = &p.usb {
            let _ = write!(out, "  usb {}:{}", u.vid, u.pid);
            for s in [&u.manufacturer, &u.product].into_iter().flatten() {
                let _ = write!(out, " {s:?}");
            }
            if let Some(s) = &u.serial {
                let _ = write!(out, " serial {s}");
            }
        }
        out.push('\n');
        for l in &p.by_id {
            let _ = writeln!(out, "    by-id  {}", l.display());
        }
        if let Some(ms) = p.latency_timer_ms {
            let _ = writeln!(out, "    latency_timer  {ms} ms");
            if p.slow_latency() {
                let name = p.path.file_name().unwrap_or_default().to_string_lossy();
                let _ = writeln!(
                    out,
                    "    WARNING: the adapter holds received bytes up to {ms} ms before passing them on,\n    \
                     adding up to {ms} ms to every transaction. Set it to 1 ms:\n      \
                     echo 1 | sudo tee /sys/bus/usb-serial/devices/{name}/latency_timer\n    \
                     or for good, a udev rule (e.g. /etc/udev/rules.d/99-adrive-latency.rules):\n      \
                     ACTION==\"add\", SUBSYSTEM==\"usb-serial\", DRIVER==\"ftdi_sio\", ATTR{{latency_timer}}=\"1\""
                );
            }
        }
    }
    if !ports.is_empty() && ports.iter().all(|p| p.usb.is_none()) {
        out.push_str(
            "no USB serial adapter (ttyUSB, ttyACM) found: the ports above are this \
             machine's own serial hardware.\n",
        );
    }
    if !sims.is_empty() {
        out.push_str("simulated devices:\n");
        let width = sims.iter().map(|s| s.device.len()).max().unwrap_or(0);
        for s in sims {
            let _ = writeln!(
                out,
                "    {}  {:<width$}  adrive sim (pid {})  {}",
                s.pty.display(),
                s.device,
                s.pid,
                s.link.display()
            );
        }
    }
    let others: Vec<String> = ptys
        .iter()
        .filter(|p| !sims.iter().any(|s| s.pty == **p))
        .map(|p| p.display().to_string())
        .collect();
    if !others.is_empty() {
        let what = if sims.is_empty() {
            "pseudo-terminals"
        } else {
            "other pseudo-terminals"
        };
        let _ = writeln!(out, "{what}: {}", others.join(" "));
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::os::unix::fs::symlink;

    /// A fake /sys and /dev with one FTDI adapter, one CDC-ACM device, an absent 8250
    /// UART and a virtual console, laid out as the kernel does.
    fn fake_tree() -> tempfile::TempDir {
        let guard = tempfile::Builder::new()
            .prefix("adrive-ports-")
            .tempdir()
            .unwrap();
        let root = guard.path();
        let sys = root.join("sys");
        let usb = sys.join("devices/pci0000:00/usb1/1-1");
        let ftdi = usb.join("1-1:1.0/ttyUSB0");
        fs::create_dir_all(&ftdi).unwrap();
        fs::write(usb.join("idVendor"), "0403\n").unwrap();
        fs::write(usb.join("idProduct"), "6001\n").unwrap();
        fs::write(usb.join("manufacturer"), "FTDI\n").unwrap();
        fs::write(usb.join("product"), "FT232R USB UART\n").unwrap();
        fs::write(usb.join("serial"), "A10K1XYZ\n").unwrap();
        fs::write(ftdi.join("latency_timer"), "16\n").unwrap();
        let drivers = sys.join("bus/usb-serial/drivers");
        fs::create_dir_all(drivers.join("ftdi_sio")).unwrap();
        symlink(drivers.join("ftdi_sio"), ftdi.join("driver")).unwrap();

        let acm_usb = sys.join("devices/pci0000:00/usb1/1-2");
        let acm = acm_usb.join("1-2:1.0");
        fs::create_dir_all(&acm).unwrap();
        fs::write(acm_usb.join("idVendor"), "2341\n").unwrap();
        fs::write(acm_usb.join("idProduct"), "0043\n").unwrap();

        let uart = sys.join("devices/platform/serial8250");
        fs::create_dir_all(&uart).unwrap();
        fs::create_dir_all(sys.join("bus/platform/drivers/serial8250")).unwrap();
        symlink(
            sys.join("bus/platform/drivers/serial8250"),
            uart.join("driver"),
        )
        .unwrap();

        let class = sys.join("class/tty");
        for (name, dev) in [
            ("ttyUSB0", ftdi.clone()),
            ("ttyACM0", acm.clone()),
            ("ttyS0", uart),
        ] {
            fs::create_dir_all(class.join(name)).unwrap();
            symlink(dev, class.join(name).join("device")).unwrap();
        }
        fs::write(class.join("ttyS0/type"), "0\n").unwrap();
        fs::create_dir_all(class.join("tty1")).unwrap();

        let dev = root.join("dev");
        fs::create_dir_all(dev.join("serial/by-id")).unwrap();
        fs::create_dir_all(dev.join("pts")).unwrap();
        fs::write(dev.join("pts/ptmx"), "").unwrap();
        fs::write(dev.join("pts/3"), "").unwrap();
        symlink(
            "../../ttyUSB0",
            dev.join("serial/by-id/usb-FTDI_FT232R_USB_UART_A10K1XYZ-if00-port0"),
        )
        .unwrap();
        guard
    }

    #[test]
    fn a_fake_sysfs_lists_usb_adapters_with_identity_and_latency() {
        let guard = fake_tree();
        let root = guard.path();
        let ports = scan(&root.join("sys"), &root.join("dev"));
        let names: Vec<_> = ports
            .iter()
            .map(|p| p.path.file_name().unwrap().to_owned())
            .collect();
        assert_eq!(
            names,
            ["ttyACM0", "ttyUSB0"],
            "absent 8250 UART and consoles are skipped"
        );
        let ftdi = &ports[1];
        assert_eq!(ftdi.driver.as_deref(), Some("ftdi_sio"));
        let usb = ftdi.usb.as_ref().unwrap();
        assert_eq!((usb.vid.as_str(), usb.pid.as_str()), ("0403", "6001"));
        assert_eq!(usb.serial.as_deref(), Some("A10K1XYZ"));
        assert_eq!(ftdi.latency_timer_ms, Some(16));
        assert_eq!(ftdi.by_id.len(), 1);
        let text = report(&ports, &pseudo_terminals(&root.join("dev")), &[]);
        assert!(
            text.contains("WARNING") && text.contains("latency_timer"),
            "{text}"
        );
        assert!(text.contains("by-id"), "{text}");
        assert!(
            text.contains("pseudo-terminals:") && text.contains("pts/3"),
            "{text}"
        );
        assert!(!text.contains("ptmx"));
    }

    #[test]
    fn no_serial_hardware_is_said_plainly() {
        let text = report(&[], &[], &[]);
        assert!(text.starts_with("no serial ports found"), "{text}");
    }

    /// The incident: on a machine without USB serial hardware `adrive ports` listed
    /// `/dev/ttyS0  driver serial` and nothing more, as if that were the adapter to use.
    /// It says that no USB serial adapter was found.
    #[test]
    fn built_in_serial_ports_alone_say_there_is_no_usb_serial_adapter() {
        let uart = PortInfo {
            path: "/dev/ttyS0".into(),
            driver: Some("serial".into()),
            ..PortInfo::default()
        };
        let text = report(std::slice::from_ref(&uart), &[], &[]);
        assert!(text.starts_with("/dev/ttyS0  driver serial\n"), "{text}");
        assert!(
            text.contains("no USB serial adapter (ttyUSB, ttyACM) found"),
            "{text}"
        );
        let guard = fake_tree();
        let ports = scan(&guard.path().join("sys"), &guard.path().join("dev"));
        let text = report(&ports, &[], &[]);
        assert!(!text.contains("no USB serial adapter"), "{text}");
    }

    /// With `adrive sim` running, `adrive ports` listed its `/dev/pts/*` without saying
    /// which simulated device each is. The simulator's directory of links (in the
    /// temporary directory, `adrive-sim-PID-N/steer`) says it; one whose process is
    /// gone is left out.
    #[test]
    fn a_simulators_pseudo_terminals_are_named_by_device() {
        let guard = fake_tree();
        let root = guard.path();
        let dev = root.join("dev");
        fs::write(dev.join("pts/4"), "").unwrap();
        fs::write(dev.join("pts/5"), "").unwrap();
        let tmp = root.join("tmp");
        let me = std::process::id();
        let live = tmp.join(format!("adrive-sim-{me}-0"));
        fs::create_dir_all(&live).unwrap();
        symlink(dev.join("pts/3"), live.join("steer")).unwrap();
        symlink(dev.join("pts/4"), live.join("gas")).unwrap();
        // A simulator killed before it could clean up: its process is gone.
        let dead = tmp.join("adrive-sim-4000000000-0");
        fs::create_dir_all(&dead).unwrap();
        symlink(dev.join("pts/5"), dead.join("brake")).unwrap();
        let proc = root.join("proc");
        fs::create_dir_all(proc.join(me.to_string())).unwrap();
        let sims = simulated(&tmp, &proc);
        let text = report(&[], &pseudo_terminals(&dev), &sims);
        let line = |pts: &str| {
            text.lines()
                .find(|l| l.contains(&format!("pts/{pts} ")) || l.ends_with(&format!("pts/{pts}")))
                .unwrap_or_else(|| panic!("no pts/{pts} in:\n{text}"))
                .to_string()
        };
        let steer = line("3");
        assert!(
            steer.contains("steer")
                && steer.contains(&format!("adrive sim (pid {me})"))
                && steer.contains(&live.join("steer").display().to_string()),
            "{text}"
        );
        assert!(line("4").contains("gas"), "{text}");
        assert!(!line("5").contains("brake"), "{text}");
    }
}
