//! What is wrong with a path a person gave: a file to read (`--config`, `--keymap`, a
//! recording, `--key`), a directory to write into (`export --csv`, `manpage --dir`,
//! `--log-dir`) or a file to create (`--record`, `--socket`). The operating system
//! says `File exists (os error 17)` when a directory is wanted where a file is; these
//! checks say which part of the path is what, before anything is written.

use std::io;
use std::path::{Path, PathBuf};

/// The first of `path` and its ancestors that exists, if any (`.` for a relative path
/// whose first part is missing).
fn existing(path: &Path) -> Option<PathBuf> {
    let mut p = Some(path);
    while let Some(at) = p {
        let at = if at.as_os_str().is_empty() {
            Path::new(".")
        } else {
            at
        };
        if at.symlink_metadata().is_ok() {
            return Some(at.to_path_buf());
        }
        p = at.parent();
    }
    None
}

/// The directory `path` is in (`.` for a bare file name).
fn parent_of(path: &Path) -> &Path {
    match path.parent() {
        Some(p) if !p.as_os_str().is_empty() => p,
        _ => Path::new("."),
    }
}

/// `at` is in the way of a directory at `path`: a file where a directory is wanted.
fn not_a_directory(path: &Path, at: &Path) -> String {
    if at == path {
        "it is a file, not a directory".into()
    } else {
        format!("{} is a file, not a directory", at.display())
    }
}

/// `what PATH: problem`, or `PATH: problem` for a path given without a flag.
fn say(what: &str, path: &Path, problem: &str) -> String {
    if what.is_empty() {
        format!("{}: {problem}", path.display())
    } else {
        format!("{what} {}: {problem}", path.display())
    }
}

/// The directory `dir` (`what`: the flag that names it), created with its parents if
/// missing. The error says what is in the way.
pub(crate) fn create_dir(what: &str, dir: &Path) -> Result<(), String> {
    match std::fs::create_dir_all(dir) {
        Ok(()) => Ok(()),
        Err(e) => Err(say(what, dir, &dir_problem(dir, &e))),
    }
}

/// Why the directory `dir` could not be made or used.
fn dir_problem(dir: &Path, e: &io::Error) -> String {
    match existing(dir) {
        Some(at) if !at.is_dir() => not_a_directory(dir, &at),
        Some(at) if e.kind() == io::ErrorKind::PermissionDenied => {
            format!("permission denied: you cannot write in {}", at.display())
        }
        _ => e.to_string(),
    }
}

/// A file to read, `what` naming the flag (empty: a path given without one): it exists
/// and is a file, not a directory.
pub(crate) fn check_file(what: &str, path: &Path) -> Result<(), String> {
    let problem = match std::fs::metadata(path) {
        Ok(m) if m.is_dir() => "it is a directory, not a file".into(),
        Ok(_) => match std::fs::File::open(path) {
            Ok(_) => return Ok(()),
            Err(e) => file_problem(path, &e),
        },
        Err(e) => file_problem(path, &e),
    };
    Err(say(what, path, &problem))
}

/// Why the file `path` could not be read.
pub(crate) fn file_problem(path: &Path, e: &io::Error) -> String {
    match e.kind() {
        io::ErrorKind::IsADirectory => "it is a directory, not a file".into(),
        io::ErrorKind::PermissionDenied => "permission denied: you cannot read it".into(),
        io::ErrorKind::NotFound | io::ErrorKind::NotADirectory => {
            match existing(path).filter(|at| at != path) {
                Some(at) if !at.is_dir() => not_a_directory(path, &at),
                Some(at) if at.as_path() != parent_of(path) => {
                    format!("no such file: {} does not exist", parent_of(path).display())
                }
                _ => "no such file".into(),
            }
        }
        _ => e.to_string(),
    }
}

/// `cannot read: …` for a file that could not be read, in words.
pub(crate) fn cannot_read(path: &Path, e: &io::Error) -> String {
    format!("cannot read: {}", file_problem(path, e))
}

/// A directory that is made later (`--record DIR/`): nothing in the way of `dir` being
/// one, `what` naming the flag.
pub(crate) fn check_dir_possible(what: &str, dir: &Path) -> Result<(), String> {
    match existing(dir) {
        Some(at) if !at.is_dir() => Err(say(what, dir, &not_a_directory(dir, &at))),
        _ => Ok(()),
    }
}

/// A file made later in a directory made with it (a control socket): nothing in the
/// way of its directory being one, `what` naming the flag.
pub(crate) fn check_place(what: &str, path: &Path) -> Result<(), String> {
    match existing(parent_of(path)) {
        Some(at) if !at.is_dir() => Err(say(
            what,
            path,
            &format!("{} is a file, not a directory", at.display()),
        )),
        _ => Ok(()),
    }
}

/// A file to create at `path`, `what` naming the flag: its directory exists (a file in
/// the way is named) and it is not itself a directory.
pub(crate) fn check_new_file(what: &str, path: &Path) -> Result<(), String> {
    if path.is_dir() {
        return Err(say(what, path, "it is a directory, not a file"));
    }
    let parent = parent_of(path);
    if parent.is_dir() {
        return Ok(());
    }
    let problem = match existing(parent) {
        Some(at) if !at.is_dir() => format!("{} is a file, not a directory", at.display()),
        _ => format!("its directory {} does not exist", parent.display()),
    };
    Err(say(what, path, &problem))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The incident: `adrive export f.mcap --csv EXISTING_FILE` said "File exists (os
    /// error 17)". Each kind of path says what is wrong with it, naming the part in
    /// the way.
    #[test]
    fn each_path_says_what_is_wrong_with_it() {
        let dir = tempfile::Builder::new()
            .prefix("adrive-paths-")
            .tempdir()
            .unwrap();
        let file = dir.path().join("afile");
        std::fs::write(&file, b"x").unwrap();
        let f = file.display();
        assert_eq!(
            create_dir("--csv", &file).unwrap_err(),
            format!("--csv {f}: it is a file, not a directory")
        );
        let under = file.join("sub");
        assert_eq!(
            create_dir("--csv", &under).unwrap_err(),
            format!("--csv {}: {f} is a file, not a directory", under.display())
        );
        let made = dir.path().join("a/b");
        create_dir("--csv", &made).unwrap();
        assert!(made.is_dir());

        let d = dir.path().display();
        assert_eq!(
            check_file("--config", dir.path()).unwrap_err(),
            format!("--config {d}: it is a directory, not a file")
        );
        assert_eq!(
            check_file("", dir.path()).unwrap_err(),
            format!("{d}: it is a directory, not a file")
        );
        let missing = dir.path().join("none.toml");
        assert_eq!(
            check_file("--config", &missing).unwrap_err(),
            format!("--config {}: no such file", missing.display())
        );
        let deep = dir.path().join("x/y/none.toml");
        assert_eq!(
            check_file("--config", &deep).unwrap_err(),
            format!(
                "--config {}: no such file: {} does not exist",
                deep.display(),
                dir.path().join("x/y").display()
            )
        );
        check_file("--config", &file).unwrap();

        assert_eq!(
            check_new_file("--record", dir.path()).unwrap_err(),
            format!("--record {d}: it is a directory, not a file")
        );
        let in_file = file.join("r.mcap");
        assert_eq!(
            check_new_file("--record", &in_file).unwrap_err(),
            format!(
                "--record {}: {f} is a file, not a directory",
                in_file.display()
            )
        );
        let nowhere = dir.path().join("nodir/r.mcap");
        assert_eq!(
            check_new_file("--record", &nowhere).unwrap_err(),
            format!(
                "--record {}: its directory {} does not exist",
                nowhere.display(),
                dir.path().join("nodir").display()
            )
        );
        check_new_file("--record", &dir.path().join("r.mcap")).unwrap();
        let socket = file.join("s.sock");
        assert_eq!(
            check_place("--socket", &socket).unwrap_err(),
            format!(
                "--socket {}: {f} is a file, not a directory",
                socket.display()
            )
        );
        check_place("--socket", &dir.path().join("new/s.sock")).unwrap();
        assert_eq!(
            file_problem(
                Path::new("surely-not-here.toml"),
                &io::ErrorKind::NotFound.into()
            ),
            "no such file"
        );
    }
}
