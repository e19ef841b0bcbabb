//! A real pseudo-terminal for console tests: open one, start the real binary on its
//! slave side (as a login shell would, or without making it the controlling
//! terminal), and play the terminal on its master side ([`Master`]) — until the
//! master side is closed, as a dropped SSH session closes it.

use std::os::fd::{FromRawFd, OwnedFd};
use std::os::unix::process::CommandExt;
use std::process::{Command, Stdio};

/// Open a pseudo-terminal of the given size: (master, slave).
#[allow(unsafe_code)]
pub fn openpty(cols: u16, rows: u16) -> (OwnedFd, OwnedFd) {
    let (mut m, mut s) = (0, 0);
    let ws = libc::winsize {
        ws_row: rows,
        ws_col: cols,
        ws_xpixel: 0,
        ws_ypixel: 0,
    };
    // SAFETY: openpty writes two fds into the given ints; the winsize is read only.
    let r = unsafe { libc::openpty(&mut m, &mut s, std::ptr::null_mut(), std::ptr::null(), &ws) };
    assert_eq!(r, 0, "openpty: {}", std::io::Error::last_os_error());
    for fd in [m, s] {
        // A program started on the slave must not inherit the master, or closing ours
        // would not hang the terminal up.
        // SAFETY: setting a flag on a fd we own.
        let r = unsafe { libc::fcntl(fd, libc::F_SETFD, libc::FD_CLOEXEC) };
        assert_eq!(r, 0);
    }
    // SAFETY: both fds were just opened and are owned by nobody else.
    unsafe { (OwnedFd::from_raw_fd(m), OwnedFd::from_raw_fd(s)) }
}

/// Give `cmd` the slave as its standard input, output and error, in a session of its
/// own. `controlling`: the slave becomes its controlling terminal (as in an SSH
/// session), so the kernel sends it SIGHUP when the master closes; without, nothing
/// but the dead terminal itself tells it.
#[allow(unsafe_code)]
pub fn attach(cmd: &mut Command, slave: &OwnedFd, controlling: bool) {
    let io = |fd: &OwnedFd| Stdio::from(fd.try_clone().unwrap());
    cmd.stdin(io(slave)).stdout(io(slave)).stderr(io(slave));
    // SAFETY: only async-signal-safe calls between fork and exec.
    unsafe {
        cmd.pre_exec(move || {
            if libc::setsid() < 0 || (controlling && libc::ioctl(0, libc::TIOCSCTTY as _, 0) < 0) {
                return Err(std::io::Error::last_os_error());
            }
            Ok(())
        });
    }
}

/// The master side of a pseudo-terminal whose program is running: a terminal that
/// reads everything the program writes and answers its requests as a real terminal
/// does (see [`super::terminal_player`]).
pub type Master = super::terminal_player::Player;
