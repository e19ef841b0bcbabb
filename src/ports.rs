//! `adrive ports`: the serial ports this machine has, with what the OS knows of each —
//! the stable `/dev/serial/by-id` name, USB vendor, product and serial number, the
//! kernel driver, and for USB serial adapters the driver's `latency_timer`. An FTDI
//! adapter defaults to 16 ms there, which adds up to 16 ms to every transaction: the
//! listing warns and says how to fix it. Pseudo-terminals (e.g. `adrive sim`'s) are
//! listed too.
//!
//! Read straight from sysfs and /dev, so it needs no libudev; the roots are parameters
//! so tests run it on a fake tree.

use std::fmt::Write as _;
use std::fs;
use std::path::{Path, PathBuf};

/// USB identity of an adapter.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Usb {
    pub vid: String,
    pub pid: String,
    pub manufacturer: Option<String>,
    pub product: Option<String>,
    pub serial: Option<String>,
}

/// One port.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct PortInfo {
    /// `/dev/ttyUSB0`.
    pub path: PathBuf,
    /// Links in `/dev/serial/by-id` that point at it.
    pub by_id: Vec<PathBuf>,
    pub driver: Option<String>,
    pub usb: Option<Usb>,
    /// The USB serial driver's latency timer, ms.
    pub latency_timer_ms: Option<u32>,
}

impl PortInfo {
    /// The latency timer is above 1 ms.
    pub fn slow_latency(&self) -> bool {
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
pub fn scan(sys: &Path, dev: &Path) -> Vec<PortInfo> {
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
pub fn pseudo_terminals(dev: &Path) -> Vec<PathBuf> {
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

/// The listing `adrive ports` prints.
pub fn report(ports: &[PortInfo], ptys: &[PathBuf]) -> String {
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
    if !ptys.is_empty() {
        let names: Vec<String> = ptys.iter().map(|p| p.display().to_string()).collect();
        let _ = writeln!(out, "pseudo-terminals: {}", names.join(" "));
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
        let text = report(&ports, &pseudo_terminals(&root.join("dev")));
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
        let text = report(&[], &[]);
        assert!(text.starts_with("no serial ports found"), "{text}");
    }
}
