//! What every subcommand does with where it writes, from the real binary: each one, as
//! clap defines them (so a new subcommand is not forgotten), run with its standard
//! output a pipe whose reader has gone (`adrive sim | head`) ends quietly with status
//! 0; and each path argument that is not what it must be (a file where a directory is
//! wanted, a directory where a file is) says so.

mod common;

use clap::CommandFactory;
use common::{free_port, lines, signal, tempdir, until, wait_exit, Reaped};
use std::path::{Path, PathBuf};
use std::process::{Command as Process, Output, Stdio};

const BIN: &str = env!("CARGO_BIN_EXE_adrive");

/// Every subcommand path clap knows (`["ctl", "status"]`), leaves only.
fn leaves(cmd: &clap::Command, above: &[String], out: &mut Vec<Vec<String>>) {
    for sub in cmd.get_subcommands().filter(|s| s.get_name() != "help") {
        let mut path = above.to_vec();
        path.push(sub.get_name().to_string());
        if sub.has_subcommands() {
            leaves(sub, &path, out);
        } else {
            out.push(path);
        }
    }
}

/// What the fixture must be first.
#[derive(Clone, Copy, PartialEq)]
enum First {
    Nothing,
    /// Ready to engage, and not engaged.
    Disengaged,
    /// Engaged by another operator.
    Engaged,
}

/// How a subcommand is made to print.
enum How {
    /// It prints and ends by itself, the fixture made so first.
    Prints(Vec<String>, First),
    /// It runs until stopped: started, awaited until its standard error says `ready`
    /// and five of its state broadcasts reached `sentinel` (it has run: a recording
    /// holds snapshots), then sent SIGTERM.
    UntilStopped(Vec<String>, &'static str, std::net::UdpSocket),
    /// It is a console: without a terminal it is refused before anything starts.
    NeedsTerminal(Vec<String>),
    /// It is not built in (a cargo feature): refused, saying how to build it.
    NotBuilt(Vec<String>),
    /// Its case needs more around it than the table has: added in the test.
    Elsewhere,
}

/// What the walk needs around it: a headless adrive to talk to, and where to put files.
struct Around {
    dir: tempfile::TempDir,
    listen: String,
    broadcast: String,
    socket: PathBuf,
    recording: PathBuf,
    _adrive: Reaped,
}

impl Around {
    fn start() -> Around {
        let dir = tempdir("outputs");
        let listen = format!("127.0.0.1:{}", free_port());
        let broadcast = format!("127.0.0.1:{}", free_port());
        let socket = dir.path().join("fixture.sock");
        // On the tolerant Alice: the walk may leave the fixture engaged while later
        // cases run, and what is tested is their output, not device timing.
        let vehicle = common::tolerant_alice(dir.path()).display().to_string();
        let (adrive, _, err) = common::headless_sim(
            dir.path(),
            &[
                "--config",
                &vehicle,
                "--listen",
                &listen,
                "--broadcast-to",
                &broadcast,
                "--socket",
                &socket.display().to_string(),
            ],
        );
        std::thread::spawn(move || for _ in err {});
        let recording = dir.path().join("run.mcap");
        Around {
            dir,
            listen,
            broadcast,
            socket,
            recording,
            _adrive: adrive,
        }
    }

    fn path(&self, name: &str) -> String {
        self.dir.path().join(name).display().to_string()
    }

    /// `adrive ctl WHAT` on the fixture, its output read.
    fn ctl(&self, what: &str) -> Output {
        Process::new(BIN)
            .args(["ctl", what, "--socket"])
            .arg(&self.socket)
            .output()
            .unwrap()
    }

    /// Make the fixture so.
    fn make(&self, first: First) {
        if first == First::Nothing {
            return;
        }
        // Engage is refused until every device has reported.
        common::wait_for("the fixture engaged", || {
            self.ctl("engage").status.success()
        });
        if first == First::Disengaged {
            assert!(self.ctl("disengage").status.success());
        }
    }

    /// How `path` is made to print, and what must be so first; `None`: the table lacks
    /// it.
    fn case(&self, path: &[String]) -> Option<How> {
        let s = |v: &[&str]| v.iter().map(|w| w.to_string()).collect::<Vec<_>>();
        let socket = self.socket.display().to_string();
        let recording = self.recording.display().to_string();
        Some(
            match path.iter().map(String::as_str).collect::<Vec<_>>()[..] {
                // Headless (the console needs a terminal), recording for the cases below.
                ["run"] => {
                    let sentinel = std::net::UdpSocket::bind("127.0.0.1:0").unwrap();
                    let to = sentinel.local_addr().unwrap().to_string();
                    How::UntilStopped(
                        s(&[
                            "run",
                            "--sim",
                            "--headless",
                            "--listen",
                            "127.0.0.1:0",
                            "--broadcast-to",
                            &to,
                            "--socket",
                            &self.path("run.sock"),
                            "--log-dir",
                            &self.path("run-log"),
                            "--record",
                            &recording,
                        ]),
                        "running headless",
                        sentinel,
                    )
                }
                ["sim"] => How::Prints(s(&["sim"]), First::Nothing),
                // On the tolerant Alice: the run holds the vehicle engaged for seconds,
                // and what is tested is its output, not device timing on a loaded
                // machine (common::tolerant_alice).
                ["characterize"] => How::Prints(
                    s(&[
                        "characterize",
                        "steer",
                        "--sim",
                        "--config",
                        &common::tolerant_alice(self.dir.path())
                            .display()
                            .to_string(),
                        "--yes",
                        "--procedure",
                        "sweep",
                        "--out",
                        &self.path("characterized"),
                        "--socket",
                        &self.path("characterize.sock"),
                        "--log-dir",
                        &self.path("characterize-log"),
                    ]),
                    First::Nothing,
                ),
                ["ports"] => How::Prints(s(&["ports"]), First::Nothing),
                ["send"] => How::Prints(
                    s(&["send", "--to", &self.listen, "disengage"]),
                    First::Nothing,
                ),
                ["watch"] => How::Prints(s(&["watch", "--from", &self.broadcast]), First::Nothing),
                ["attach"] => How::NeedsTerminal(s(&["attach", "--socket", &socket])),
                // With the fleet built in, it needs a router: the test runs one.
                ["fleet"] if cfg!(feature = "fleet") => How::Elsewhere,
                ["fleet"] => How::NotBuilt(s(&["fleet"])),
                ["ctl", what] => How::Prints(
                    s(&["ctl", what, "--socket", &socket]),
                    match what {
                        "engage" => First::Disengaged,
                        "release" => First::Engaged,
                        _ => First::Nothing,
                    },
                ),
                ["replay"] => How::Prints(
                    s(&[
                        "replay",
                        &recording,
                        "--headless",
                        "--speed",
                        "32",
                        "--broadcast",
                        &format!("127.0.0.1:{}", free_port()),
                    ]),
                    First::Nothing,
                ),
                ["record", "info"] => {
                    How::Prints(s(&["record", "info", &recording]), First::Nothing)
                }
                // A finished recording: it says there is nothing to repair.
                ["record", "repair"] => {
                    How::Prints(s(&["record", "repair", &recording]), First::Nothing)
                }
                ["export"] => How::Prints(
                    s(&["export", &recording, "--csv", &self.path("csv")]),
                    First::Nothing,
                ),
                ["completions"] => How::Prints(s(&["completions", "bash"]), First::Nothing),
                ["manpage"] => How::Prints(s(&["manpage"]), First::Nothing),
                _ => return None,
            },
        )
    }
}

/// `adrive ARGS` with its standard output a pipe whose reader is gone before the first
/// write (so every write fails, whatever the pipe holds); its standard error piped.
fn closed(args: &[String], tmp: &Path) -> Reaped {
    let (reader, writer) = std::io::pipe().unwrap();
    drop(reader);
    Reaped(
        Process::new(BIN)
            .args(args)
            .env("TMPDIR", tmp)
            .env("XDG_RUNTIME_DIR", tmp)
            .stdin(Stdio::null())
            .stdout(writer)
            .stderr(Stdio::piped())
            .spawn()
            .unwrap(),
    )
}

/// The incident: `adrive sim | head` (and the ROS 2 watch into a closed pipe) panicked
/// with a backtrace and status 101. Every subcommand, walked from clap's definitions,
/// ends quietly with status 0 when its standard output is closed; a console without a
/// terminal is refused as it always is (status 2), without a panic.
#[test]
fn every_subcommand_ends_quietly_with_status_0_on_a_closed_standard_output() {
    let around = Around::start();
    let tmp = tempdir("outputs-tmp");
    let mut paths = Vec::new();
    leaves(&adrive::cli::Cli::command(), &[], &mut paths);
    let missing: Vec<String> = paths
        .iter()
        .filter(|p| around.case(p).is_none())
        .map(|p| p.join(" "))
        .collect();
    assert!(
        missing.is_empty(),
        "no case for {missing:?}: add how each prints to the table"
    );
    let mut cases: Vec<How> = paths.iter().filter_map(|p| around.case(p)).collect();
    if cfg!(feature = "ros2") {
        cases.push(How::Prints(
            [
                "watch",
                "--ros2",
                "--connect",
                &format!("tcp/127.0.0.1:{}", free_port()),
            ]
            .map(String::from)
            .to_vec(),
            First::Nothing,
        ));
    }
    // `adrive fleet` lists what a router it reaches knows (nothing, here).
    #[cfg(feature = "fleet")]
    let _router = {
        let (router, endpoint) = common::zenoh_router::start();
        cases.push(How::Prints(
            ["fleet", "--connect", &endpoint, "--wait", "200ms"]
                .map(String::from)
                .to_vec(),
            First::Nothing,
        ));
        router
    };
    for how in cases {
        let (args, status, said) = match how {
            How::Prints(args, first) => {
                around.make(first);
                let mut child = closed(&args, tmp.path());
                let err = lines(child.stderr.take().unwrap());
                let status = wait_exit(&mut child);
                (args, status, err.iter().collect::<Vec<_>>().join("\n"))
            }
            How::UntilStopped(args, ready, sentinel) => {
                let mut child = closed(&args, tmp.path());
                let err = lines(child.stderr.take().unwrap());
                let mut seen = until(&err, ready);
                sentinel.set_read_timeout(Some(common::DEADLINE)).unwrap();
                let mut buf = vec![0u8; 65536];
                for _ in 0..5 {
                    sentinel.recv(&mut buf).expect("its state broadcast");
                }
                signal(&child, libc::SIGTERM);
                let status = wait_exit(&mut child);
                seen.extend(err.iter());
                (args, status, seen.join("\n"))
            }
            How::NeedsTerminal(args) => {
                let mut child = closed(&args, tmp.path());
                let err = lines(child.stderr.take().unwrap());
                let status = wait_exit(&mut child);
                let err = err.iter().collect::<Vec<_>>().join("\n");
                assert_eq!(status, Some(2), "{args:?}: {err}");
                assert!(err.contains("needs a terminal"), "{args:?}: {err}");
                assert!(!err.contains("panicked"), "{args:?}: {err}");
                continue;
            }
            How::NotBuilt(args) => {
                let mut child = closed(&args, tmp.path());
                let err = lines(child.stderr.take().unwrap());
                let status = wait_exit(&mut child);
                let err = err.iter().collect::<Vec<_>>().join("\n");
                assert_eq!(status, Some(2), "{args:?}: {err}");
                assert!(
                    err.contains("cargo build --release --features"),
                    "{args:?}: {err}"
                );
                assert!(!err.contains("panicked"), "{args:?}: {err}");
                continue;
            }
            How::Elsewhere => continue,
        };
        assert_eq!(status, Some(0), "{args:?}: {said}");
        assert!(
            !said.contains("panicked") && !said.contains("Broken pipe"),
            "{args:?}: {said}"
        );
    }
    assert_eq!(
        common::sim_dirs(tmp.path()),
        Vec::<String>::new(),
        "adrive sim left its links behind"
    );
}

/// The incident: `adrive export f.mcap --csv EXISTING_FILE` said "File exists (os error
/// 17)". Every path argument that is not what it must be says what is wrong with it.
#[test]
fn every_path_argument_says_what_is_wrong_with_it() {
    let dir = tempdir("paths");
    let file = dir.path().join("afile");
    std::fs::write(&file, b"not a directory").unwrap();
    let f = file.display().to_string();
    let d = dir.path().display().to_string();
    let run = |args: &[&str]| {
        let out = common::output_within(
            Process::new(BIN)
                .args(args)
                .env("XDG_RUNTIME_DIR", dir.path()),
        );
        (
            out.status.code(),
            String::from_utf8_lossy(&out.stderr).into_owned(),
        )
    };
    let under = format!("{f}/sub");
    let record = format!("{f}/r.mcap");
    let socket = format!("{f}/s.sock");
    let cases: Vec<(Vec<&str>, String)> = vec![
        (
            vec!["manpage", "--dir", &f],
            format!("manpage --dir {f}: it is a file, not a directory"),
        ),
        (
            vec!["manpage", "--dir", &under],
            format!("manpage --dir {under}: {f} is a file, not a directory"),
        ),
        (
            vec!["record", "info", &d],
            format!("{d}: it is a directory, not a file"),
        ),
        (
            vec!["record", "repair", &d],
            format!("{d}: it is a directory, not a file"),
        ),
        (
            vec!["record", "repair", &f, "--out", &record],
            format!("--out {record}: {f} is a file, not a directory"),
        ),
        (
            vec!["export", &d, "--csv", &under],
            format!("{d}: it is a directory, not a file"),
        ),
        (
            vec!["replay", &d, "--headless", "--broadcast"],
            format!("{d}: it is a directory, not a file"),
        ),
        (
            vec!["send", "--key", &d, "steer", "0"],
            format!("--key {d}: it is a directory, not a file"),
        ),
        (
            vec!["--sim", "--headless", "--config", &d],
            format!("{d}: cannot read: it is a directory, not a file"),
        ),
        (
            vec!["--sim", "--headless", "--log-dir", &f],
            format!("--log-dir {f}: it is a file, not a directory"),
        ),
        (
            vec!["--sim", "--headless", "--record", &record],
            format!("--record {record}: {f} is a file, not a directory"),
        ),
        (
            vec!["--sim", "--headless", "--socket", &socket],
            format!("--socket {socket}: {f} is a file, not a directory"),
        ),
    ];
    // The same of the paths a vehicle file names.
    let vehicle = dir.path().join("v.toml");
    std::fs::write(
        &vehicle,
        "[vehicle]\nname = \"bench\"\n\n[network]\nkey_file = \".\"\n\n[[device]]\nname = \"steer\"\nkind = \"setpoint\"\nrange = [-1.0, 1.0]\ndriver = \"line\"\n",
    )
    .unwrap();
    let v = vehicle.display().to_string();
    let in_file = std::fs::read_to_string(&vehicle).unwrap().replace(
        "[network]\nkey_file = \".\"\n",
        "[record]\ndir = \"afile/rec\"\n",
    );
    let recorded = dir.path().join("r.toml");
    std::fs::write(&recorded, in_file).unwrap();
    let r = recorded.display().to_string();
    let cases: Vec<(Vec<&str>, String)> = cases
        .into_iter()
        .chain([
            (
                vec!["--sim", "--headless", "--config", &v],
                format!("{v}:5: [network] key_file: {d}/.: it is a directory, not a file"),
            ),
            (
                vec!["--sim", "--headless", "--config", &r],
                format!("[record] dir {f}/rec: {f} is a file, not a directory"),
            ),
        ])
        .collect();
    for (args, want) in cases {
        let (status, err) = run(&args);
        assert_eq!(status, Some(2), "{args:?}: {err}");
        assert!(err.contains(&want), "{args:?}:\n{err}\nwanted: {want}");
        assert!(!err.contains("os error"), "{args:?}: {err}");
    }

    // export --csv onto a file, with a real recording.
    let recording = dir.path().join("r.mcap");
    let (mut adrive, _, _) = common::headless_sim(
        dir.path(),
        &[
            "--listen",
            "127.0.0.1:0",
            "--broadcast-to",
            &format!("127.0.0.1:{}", free_port()),
            "--record",
            &recording.display().to_string(),
        ],
    );
    signal(&adrive, libc::SIGTERM);
    assert_eq!(wait_exit(&mut adrive), Some(0));
    let r = recording.display().to_string();
    let (status, err) = run(&["export", &r, "--csv", &f]);
    assert_eq!(status, Some(2), "{err}");
    assert!(
        err.contains(&format!("--csv {f}: it is a file, not a directory")),
        "{err}"
    );
}
