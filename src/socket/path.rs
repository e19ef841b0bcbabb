//! Where the control socket lives, and how it is claimed and given back.
//!
//! - The default path: `$RUNTIME_DIRECTORY/adrive.sock` under systemd's
//!   `RuntimeDirectory=adrive` (`/run/adrive/adrive.sock`), else
//!   `$XDG_RUNTIME_DIR/adrive/adrive.sock` for a user, else
//!   `/tmp/adrive-UID/adrive.sock`.
//! - Claiming it: a socket file that answers belongs to a running adrive, which is
//!   named (pid and command line, from the kernel's peer credentials) and refused; one
//!   that does not answer was left by a process that died (`kill -9`) and is replaced;
//!   anything else at the path is refused and left alone.
//! - The socket is made mode 0660 (the process's group may attach) and removed when its
//!   [`Claim`] drops — on every way out of the process that unwinds — but only if it is
//!   still the file this process made; so is its directory, if this process made it
//!   and nothing else is in it (`/tmp/adrive-UID` is not left behind).

use std::io;
use std::os::unix::fs::{DirBuilderExt, FileTypeExt, MetadataExt, PermissionsExt};
use std::os::unix::net::{UnixListener, UnixStream};
use std::path::{Path, PathBuf};

/// The socket's file name in its directory.
pub(crate) const FILE: &str = "adrive.sock";

/// The default socket path, from the environment (see the module doc).
pub(crate) fn default_path() -> PathBuf {
    let var = |k: &str| std::env::var_os(k).filter(|v| !v.is_empty());
    if let Some(dirs) = var("RUNTIME_DIRECTORY") {
        // systemd lists several directories separated by `:`; adrive asks for one.
        let first = dirs
            .to_string_lossy()
            .split(':')
            .next()
            .unwrap_or("")
            .to_string();
        return Path::new(&first).join(FILE);
    }
    if let Some(dir) = var("XDG_RUNTIME_DIR") {
        return Path::new(&dir).join("adrive").join(FILE);
    }
    let uid = rustix::process::getuid().as_raw();
    std::env::temp_dir()
        .join(format!("adrive-{uid}"))
        .join(FILE)
}

/// Who is at the other end of a Unix socket, as the kernel says.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) struct Peer {
    pub pid: u32,
    pub(crate) uid: u32,
}

impl Peer {
    /// The peer of a connected stream.
    pub(crate) fn of(stream: &UnixStream) -> io::Result<Peer> {
        let c = rustix::net::sockopt::socket_peercred(stream)?;
        Ok(Peer {
            pid: rustix::process::Pid::as_raw(Some(c.pid)) as u32,
            uid: c.uid.as_raw(),
        })
    }

    /// `pid 4242 (adrive --sim)`: the process, with its command line when it can be read.
    pub(crate) fn describe(&self) -> String {
        let cmdline = std::fs::read(format!("/proc/{}/cmdline", self.pid))
            .ok()
            .map(|b| {
                b.split(|&c| c == 0)
                    .filter(|a| !a.is_empty())
                    .map(String::from_utf8_lossy)
                    .collect::<Vec<_>>()
                    .join(" ")
            })
            .filter(|s| !s.is_empty());
        match cmdline {
            Some(c) => format!("pid {} ({c})", self.pid),
            None => format!("pid {}", self.pid),
        }
    }
}

/// The socket file this process made; removed on drop if it is still this one.
#[derive(Debug)]
pub struct Claim {
    pub path: PathBuf,
    /// The file made, to leave alone a file another made since.
    id: FileId,
    /// The directory made for it, if it was not there: removed with it when empty.
    dir: Option<PathBuf>,
}

/// A file's identity: device and inode, and its change time, since a new file may get
/// the inode number of one just removed.
type FileId = (u64, u64, i64, i64);

fn file_id(m: &std::fs::Metadata) -> FileId {
    (m.dev(), m.ino(), m.ctime(), m.ctime_nsec())
}

impl Drop for Claim {
    fn drop(&mut self) {
        let ours = std::fs::symlink_metadata(&self.path)
            .map(|m| file_id(&m) == self.id)
            .unwrap_or(false);
        if ours {
            let _ = std::fs::remove_file(&self.path);
        }
        if let Some(dir) = &self.dir {
            // Refused while anything is in it.
            let _ = std::fs::remove_dir(dir);
        }
    }
}

/// Claim `path` and listen on it (see the module doc). The error says what is there
/// and what to do.
pub(crate) fn bind(path: &Path) -> Result<(UnixListener, Claim), String> {
    let shown = path.display();
    let parent = path.parent().filter(|d| !d.as_os_str().is_empty());
    let made_dir = parent.filter(|d| !d.exists()).map(Path::to_path_buf);
    if let Some(dir) = parent {
        std::fs::DirBuilder::new()
            .recursive(true)
            .mode(0o770)
            .create(dir)
            .map_err(|e| format!("control socket {shown}: cannot make its directory: {e}"))?;
    }
    match std::fs::symlink_metadata(path) {
        Err(e) if e.kind() == io::ErrorKind::NotFound => {}
        Err(e) => return Err(format!("control socket {shown}: {e}")),
        Ok(m) if !m.file_type().is_socket() => {
            return Err(format!(
                "control socket {shown}: something else is there (not a socket); \
                 move it away or pass --socket PATH"
            ))
        }
        Ok(_) => match UnixStream::connect(path) {
            Ok(s) => {
                let who = Peer::of(&s).map_or("another process".into(), |p| {
                    format!("another adrive, {}", p.describe())
                });
                return Err(format!(
                    "control socket {shown} is in use by {who}: stop it, or give this \
                     one its own with --socket PATH"
                ));
            }
            Err(e) if e.kind() == io::ErrorKind::ConnectionRefused => {
                std::fs::remove_file(path).map_err(|e| {
                    format!("control socket {shown}: cannot replace a stale socket: {e}")
                })?;
                tracing::info!(
                    "control socket {shown}: replaced a stale socket left by a process that ended"
                );
            }
            Err(e) => return Err(format!("control socket {shown}: {e}")),
        },
    }
    let listener = UnixListener::bind(path).map_err(|e| format!("control socket {shown}: {e}"))?;
    // Connecting needs write permission: the owner and the process's group.
    let made = std::fs::set_permissions(path, std::fs::Permissions::from_mode(0o660))
        .and_then(|()| std::fs::symlink_metadata(path));
    let m = match made {
        Ok(m) => m,
        Err(e) => {
            let _ = std::fs::remove_file(path);
            return Err(format!("control socket {shown}: {e}"));
        }
    };
    let claim = Claim {
        path: path.to_path_buf(),
        id: file_id(&m),
        dir: made_dir,
    };
    Ok((listener, claim))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_socket_is_made_0660_and_removed_when_its_claim_drops() {
        let dir = tempfile::Builder::new()
            .prefix("adrive-")
            .tempdir()
            .unwrap();
        let path = dir.path().join("run/adrive.sock");
        let (listener, claim) = bind(&path).unwrap();
        let mode = std::fs::metadata(&path).unwrap().permissions().mode() & 0o777;
        assert_eq!(mode, 0o660);
        drop(listener);
        drop(claim);
        assert!(!path.exists());
        // The directory it made goes with it; one that was there stays.
        assert!(!dir.path().join("run").exists(), "the directory it made");
        assert!(dir.path().exists());
        // One it made that holds something else stays, with it.
        let (listener, claim) = bind(&path).unwrap();
        std::fs::write(dir.path().join("run/other"), "").unwrap();
        drop((listener, claim));
        assert!(!path.exists());
        assert!(dir.path().join("run/other").exists());
    }

    #[test]
    fn a_live_socket_is_refused_naming_its_process_and_a_stale_one_is_replaced() {
        let dir = tempfile::Builder::new()
            .prefix("adrive-")
            .tempdir()
            .unwrap();
        let path = dir.path().join(FILE);
        let (live, claim) = bind(&path).unwrap();
        let e = bind(&path).unwrap_err();
        assert!(e.contains("in use by another adrive, pid "), "{e}");
        assert!(e.contains(&std::process::id().to_string()), "{e}");
        // A process that died without removing its socket: the file stays, nobody
        // listens.
        drop(live);
        std::mem::forget(claim);
        assert!(path.exists());
        let (_again, _claim) = bind(&path).unwrap();
        assert!(UnixStream::connect(&path).is_ok());
    }

    #[test]
    fn a_file_that_is_not_a_socket_is_left_alone() {
        let dir = tempfile::Builder::new()
            .prefix("adrive-")
            .tempdir()
            .unwrap();
        let path = dir.path().join(FILE);
        std::fs::write(&path, "notes").unwrap();
        let e = bind(&path).unwrap_err();
        assert!(e.contains("not a socket"), "{e}");
        assert_eq!(std::fs::read_to_string(&path).unwrap(), "notes");
    }

    #[test]
    fn a_claim_leaves_a_file_another_process_made_since() {
        let dir = tempfile::Builder::new()
            .prefix("adrive-")
            .tempdir()
            .unwrap();
        let path = dir.path().join(FILE);
        let (l, claim) = bind(&path).unwrap();
        drop(l);
        std::fs::remove_file(&path).unwrap();
        let (_l2, c2) = bind(&path).unwrap();
        drop(claim);
        assert!(
            path.exists(),
            "the second socket was removed by the first claim"
        );
        drop(c2);
    }
}
