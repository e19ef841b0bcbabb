//! A real pseudo-terminal for console tests: open one, start the real binary on its
//! slave side (as a login shell would, or without making it the controlling
//! terminal), and keep everything the program writes — until the master side is
//! closed, as a dropped SSH session closes it.

use std::fs::File;
use std::io::{Read, Write};
use std::os::fd::{AsRawFd, FromRawFd, OwnedFd};
use std::os::unix::process::CommandExt;
use std::process::{Child, Command, Stdio};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;

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

/// The master side of a pseudo-terminal whose program is running: what it wrote so
/// far, and a way to close the master as a dropped SSH session does.
pub struct Master {
    out: Arc<Mutex<Vec<u8>>>,
    close: Arc<AtomicBool>,
    reader: Option<JoinHandle<()>>,
    /// The master side again, for typing.
    keys: Option<File>,
}

impl Master {
    /// Start `cmd` on a new `cols`×`rows` terminal and read everything it writes.
    pub fn spawn(cmd: &mut Command, cols: u16, rows: u16, controlling: bool) -> (Child, Master) {
        let (master, slave) = openpty(cols, rows);
        attach(cmd, &slave, controlling);
        let child = cmd.spawn().expect("start the program on the terminal");
        // Only the child holds the slave now: the master is the last link to it.
        drop(slave);
        let (out, close) = (Arc::default(), Arc::new(AtomicBool::new(false)));
        let (o, c) = (Arc::clone(&out), Arc::clone(&close));
        let keys = master.try_clone().map(File::from).ok();
        let reader = std::thread::spawn(move || read_until_closed(File::from(master), &o, &c));
        let m = Master {
            out,
            close,
            reader: Some(reader),
            keys,
        };
        (child, m)
    }

    /// Everything the program wrote so far.
    pub fn bytes(&self) -> Vec<u8> {
        self.out.lock().unwrap().clone()
    }

    /// Type `text` on the terminal, as a user at its keyboard would.
    pub fn write(&mut self, text: &[u8]) {
        let keys = self.keys.as_mut().expect("the terminal is open");
        keys.write_all(text)
            .and_then(|()| keys.flush())
            .expect("typing");
    }

    /// Resize the terminal as a terminal window does: the kernel signals SIGWINCH to
    /// the program on it.
    #[allow(unsafe_code)]
    pub fn resize(&self, cols: u16, rows: u16) {
        let keys = self.keys.as_ref().expect("the terminal is open");
        let ws = libc::winsize {
            ws_row: rows,
            ws_col: cols,
            ws_xpixel: 0,
            ws_ypixel: 0,
        };
        // SAFETY: TIOCSWINSZ reads the struct from a valid terminal fd.
        let r = unsafe { libc::ioctl(keys.as_raw_fd(), libc::TIOCSWINSZ as _, &ws) };
        assert_eq!(r, 0, "TIOCSWINSZ: {}", std::io::Error::last_os_error());
    }

    /// Close the master side (every descriptor of it): the terminal hangs up.
    pub fn hang_up(&mut self) {
        self.keys = None;
        self.close.store(true, Ordering::Relaxed);
        if let Some(r) = self.reader.take() {
            r.join().expect("the terminal reader");
        }
    }
}

impl Drop for Master {
    fn drop(&mut self) {
        self.hang_up();
    }
}

/// Keep what the program writes, so it never blocks on a full terminal, until told
/// to close; the master is dropped (closed) on return.
#[allow(unsafe_code)]
fn read_until_closed(mut master: File, out: &Mutex<Vec<u8>>, close: &AtomicBool) {
    let mut buf = [0u8; 4096];
    while !close.load(Ordering::Relaxed) {
        let mut p = libc::pollfd {
            fd: master.as_raw_fd(),
            events: libc::POLLIN,
            revents: 0,
        };
        // SAFETY: one valid pollfd, a short timeout.
        if unsafe { libc::poll(&mut p, 1, 20) } <= 0 || p.revents & libc::POLLIN == 0 {
            if p.revents & (libc::POLLHUP | libc::POLLERR) != 0 {
                return;
            }
            continue;
        }
        match master.read(&mut buf) {
            Ok(0) | Err(_) => return,
            Ok(n) => out.lock().unwrap().extend_from_slice(&buf[..n]),
        }
    }
}
