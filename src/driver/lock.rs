//! One adrive per serial port. Two processes on one port would both write to the
//! device and each read half of its replies: each sees garbage and timeouts, and the
//! device obeys whichever wrote last. `serialport` opens every port for exclusive
//! access (`TIOCEXCL` and an advisory `flock`, which holds against root too); when
//! that fails, this module says who holds the port — from the lock table
//! (`/proc/locks`: another adrive), or for a program that only asked for exclusive
//! access, from who has the port open (`/proc/*/fd`).

use std::io;
use std::os::unix::fs::MetadataExt;
use std::path::{Path, PathBuf};

/// Opening `path` failed with `e`: when another process holds the port, an error of
/// kind `ResourceBusy` that names it; else `e`.
pub(crate) fn explain(path: &str, e: io::Error) -> io::Error {
    let locked = locker(Path::new(path), Path::new("/proc"));
    if locked.is_none() && e.raw_os_error() != Some(libc::EBUSY) {
        return e;
    }
    let who = locked
        .or_else(|| holder(Path::new(path), Path::new("/proc")))
        .map(|(pid, name)| format!("process {pid} ({name})"))
        .unwrap_or_else(|| "another process".into());
    io::Error::new(
        io::ErrorKind::ResourceBusy,
        format!("in use by {who}: one adrive per port"),
    )
}

/// A process's name, from `proc`/PID/comm.
fn name(proc: &Path, pid: u32) -> String {
    std::fs::read_to_string(proc.join(pid.to_string()).join("comm"))
        .map(|s| s.trim().to_string())
        .unwrap_or_else(|_| "?".into())
}

/// The other process (pid, name) holding an advisory lock on `path`, by `proc`/locks.
pub(crate) fn locker(path: &Path, proc: &Path) -> Option<(u32, String)> {
    let meta = std::fs::metadata(path).ok()?;
    let me = std::process::id();
    let id = format!(
        "{:02x}:{:02x}:{}",
        libc::major(meta.dev()),
        libc::minor(meta.dev()),
        meta.ino()
    );
    let locks = std::fs::read_to_string(proc.join("locks")).unwrap_or_default();
    let locked = locks.lines().find_map(|l| {
        // `1: FLOCK  ADVISORY  WRITE 1234 00:05:321 0 EOF`
        let w: Vec<&str> = l.split_whitespace().collect();
        let pid: u32 = w.get(4)?.parse().ok()?;
        (w.get(1) == Some(&"FLOCK") && w.get(5) == Some(&id.as_str()) && pid != me).then_some(pid)
    });
    locked.map(|pid| (pid, name(proc, pid)))
}

/// Another process (pid, name) that has `path` open, by `proc`/*/fd.
pub(crate) fn holder(path: &Path, proc: &Path) -> Option<(u32, String)> {
    let me = std::process::id();
    let target: PathBuf = std::fs::canonicalize(path).ok()?;
    std::fs::read_dir(proc).ok()?.flatten().find_map(|e| {
        let pid: u32 = e.file_name().to_str()?.parse().ok()?;
        if pid == me {
            return None;
        }
        let open = std::fs::read_dir(e.path().join("fd")).ok()?;
        open.flatten()
            .any(|fd| std::fs::read_link(fd.path()).is_ok_and(|t| t == target))
            .then(|| (pid, name(proc, pid)))
    })
}
