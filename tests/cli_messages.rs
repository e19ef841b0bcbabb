//! What a user reads when something is wrong, from the real binary: a vehicle file
//! with a value outside its range, a device without a port, a key file that is
//! missing or too short, a byte that is not UTF-8, `--deadman 0s`; and the shell
//! completions and manual page generated from the command-line definitions; `--ros2`
//! on a build without it; two roles bound to one device.

mod common;

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

const BIN: &str = env!("CARGO_BIN_EXE_adrive");

/// A directory for one test's files, removed when the test ends, passing or failing.
struct Scratch(tempfile::TempDir);

impl Scratch {
    fn new() -> Scratch {
        Scratch(common::tempdir("messages"))
    }
    fn file(&self, name: &str, contents: impl AsRef<[u8]>) -> PathBuf {
        let p = self.0.path().join(name);
        std::fs::write(&p, contents).unwrap();
        p
    }
}

fn adrive(args: &[&str], config: Option<&Path>, dir: &Scratch) -> Output {
    let mut cmd = Command::new(BIN);
    cmd.args(args)
        .arg("--log-dir")
        .arg(dir.0.path().join("log"))
        .env("XDG_RUNTIME_DIR", dir.0.path().join("log"));
    if let Some(c) = config {
        cmd.arg("--config").arg(c);
    }
    common::output_within(&mut cmd)
}

fn stderr(out: &Output) -> String {
    String::from_utf8_lossy(&out.stderr).into_owned()
}

const VEHICLE: &str = "[vehicle]\nname = \"bench\"\n\n[network]\nlisten = \"127.0.0.1:0\"\n\n[[device]]\nname = \"estop\"\nkind = \"sensor\"\nreadings = [\"estop\"]\ndriver = \"line\"\nport = \"/dev/null-estop\"\n";

/// `multicast_ttl = 300` reached the socket and came back as `Invalid argument (os error
/// 22)`; it is refused at its line, with the range, before anything starts.
#[test]
fn multicast_ttl_300_is_refused_at_its_line_not_by_the_os() {
    let dir = Scratch::new();
    let path = dir.file(
        "v.toml",
        VEHICLE.replace("listen =", "multicast_ttl = 300\nlisten ="),
    );
    let out = adrive(&["--headless"], Some(&path), &dir);
    let err = stderr(&out);
    assert_eq!(out.status.code(), Some(2), "{err}");
    assert!(
        err.contains(&format!(
            "{}:5: [network] multicast_ttl: expected a whole number from 0 to 255, got 300",
            path.display()
        )),
        "{err}"
    );
    assert!(!err.contains("os error"), "{err}");
    assert!(!dir.0.path().join("log").exists(), "nothing started");
}

/// A device with no `port` (or `port = ""`) ran forever, never connecting.
#[test]
fn a_device_without_a_port_is_refused_outside_sim() {
    let dir = Scratch::new();
    let path = dir.file(
        "v.toml",
        VEHICLE.replace("port = \"/dev/null-estop\"\n", ""),
    );
    let out = adrive(&["--headless"], Some(&path), &dir);
    let err = stderr(&out);
    assert_eq!(out.status.code(), Some(2), "{err}");
    assert!(
        err.contains(&format!(
            "{}:7: estop: port: expected the path of a serial port",
            path.display()
        )) && err.contains("--sim"),
        "{err}"
    );
    assert!(!dir.0.path().join("log").exists(), "nothing started");
}

/// A missing `key_file` named the key's path but not the vehicle file's line, and
/// printed the OS error twice: it names both, and says what is wrong once.
#[test]
fn a_missing_key_file_names_the_vehicle_file_line_and_the_os_error_once() {
    let dir = Scratch::new();
    let path = dir.file(
        "v.toml",
        VEHICLE.replace("listen =", "key_file = \"missing.key\"\nlisten ="),
    );
    let out = adrive(&["--headless"], Some(&path), &dir);
    let err = stderr(&out);
    assert_eq!(out.status.code(), Some(2), "{err}");
    let key = dir.0.path().join("missing.key");
    assert!(
        err.contains(&format!(
            "{}:5: [network] key_file: {}: no such file",
            path.display(),
            key.display()
        )),
        "{err}"
    );
    assert_eq!(err.matches("no such file").count(), 1, "{err}");
}

/// `adrive send --key short.key` said why twice.
#[test]
fn send_with_a_short_key_says_why_once() {
    let dir = Scratch::new();
    let key = dir.file("short.key", "short\n");
    let out = Command::new(BIN)
        .args(["send", "--to", "127.0.0.1:9", "--key"])
        .arg(&key)
        .args(["steer", "0"])
        .output()
        .unwrap();
    let err = stderr(&out);
    assert_eq!(out.status.code(), Some(2), "{err}");
    assert_eq!(
        err.trim_end(),
        format!(
            "adrive: --key {}: the key is 5 bytes; use at least 16 (e.g. `openssl rand -hex 32 > adrive.key`)",
            key.display()
        )
    );
}

/// A byte that is not UTF-8 was reported at line 0.
#[test]
fn a_byte_that_is_not_utf8_names_its_line() {
    let dir = Scratch::new();
    let mut bytes = VEHICLE.as_bytes().to_vec();
    bytes[VEHICLE.find("bench").unwrap()] = 0xe9;
    let path = dir.file("v.toml", bytes);
    let out = adrive(&["--headless"], Some(&path), &dir);
    let err = stderr(&out);
    assert_eq!(out.status.code(), Some(2), "{err}");
    assert!(
        err.contains(&format!(
            "{}:2: byte 0xe9 at column 9 is not UTF-8",
            path.display()
        )),
        "{err}"
    );
}

/// How a pseudo-terminal is set up: changed by anything that opens it as a serial
/// port (raw mode, the baud rate).
#[allow(unsafe_code)]
fn termios(port: &serialport::TTYPort) -> [libc::tcflag_t; 4] {
    use std::os::fd::AsRawFd;
    // SAFETY: a zeroed termios is a valid out-parameter.
    let mut t: libc::termios = unsafe { std::mem::zeroed() };
    // SAFETY: tcgetattr fills the struct from a terminal fd that is open.
    assert_eq!(unsafe { libc::tcgetattr(port.as_raw_fd(), &mut t) }, 0);
    [t.c_iflag, t.c_oflag, t.c_cflag, t.c_lflag]
}

/// Steering bound to the throttle device started, and ran one device in two roles;
/// throttle and brake on one device were refused at line 1. Both are refused at the
/// line of the second binding, quoting both, with status 2, and no port is opened: the
/// devices' port is a real pseudo-terminal, which is left as it was.
#[test]
fn two_roles_on_one_device_are_refused_at_the_second_binding_before_any_port_opens() {
    use serialport::SerialPort;
    let (mut host, device) = serialport::TTYPort::pair().expect("a pseudo-terminal pair");
    let port = device.name().expect("a named pseudo-terminal");
    let before = termios(&device);
    for (second, line) in [("steering", 11), ("brake", 11)] {
        let dir = Scratch::new();
        let path = dir.file(
            "v.toml",
            format!(
                "# my car\n[vehicle]\nname = \"mine\"\n\n[network]\nlisten = \"127.0.0.1:0\"\n\n\
                 [vehicle.roles]\nthrottle = \"gas\"\n# and, wrongly:\n{second} = \"gas\"\n\n\
                 [[device]]\nname = \"gas\"\nkind = \"setpoint\"\nrange = [0.0, 1.0]\n\
                 driver = \"line\"\nport = \"{port}\"\n"
            ),
        );
        // Spawned, not waited on blindly: an adrive that accepted the file would run on.
        let log = dir.file("stderr", "");
        let mut child = common::Reaped(
            Command::new(BIN)
                .args(["--headless", "--log-dir"])
                .arg(dir.0.path().join("log"))
                .env("XDG_RUNTIME_DIR", dir.0.path().join("log"))
                .arg("--config")
                .arg(&path)
                .stdout(std::process::Stdio::null())
                .stderr(std::fs::File::create(&log).unwrap())
                .spawn()
                .unwrap(),
        );
        let code = common::wait_exit(&mut child);
        let err = std::fs::read_to_string(&log).unwrap();
        assert_eq!(code, Some(2), "{err}");
        assert!(
            err.contains(&format!(
                "{}:{line}: roles: {second} = \"gas\" (line {line}) and throttle = \"gas\" (line 9) are one device, gas: a device plays one role, except gear with starter",
                path.display()
            )),
            "{err}"
        );
        assert!(!dir.0.path().join("log").exists(), "nothing started");
    }
    assert_eq!(termios(&device), before, "the port was never opened");
    let mut nothing = [0u8; 1];
    host.set_timeout(std::time::Duration::ZERO).unwrap();
    assert!(
        std::io::Read::read(&mut host, &mut nothing).is_err(),
        "nothing was written to the port"
    );
    // The check sees an open: the port opened as adrive opens it.
    drop(adrive::driver::open_serial(&port, 9600, std::time::Duration::from_millis(100)).unwrap());
    assert_ne!(termios(&device), before, "opening the port sets it up");
}

/// `--deadman 0s` was taken: the deadman then tripped on every key, or with a huge
/// value never.
#[test]
fn deadman_zero_is_refused_with_its_range() {
    for bad in ["0s", "1h"] {
        let dir = Scratch::new();
        let out = adrive(&["--sim", "--deadman", bad], None, &dir);
        let err = stderr(&out);
        assert_eq!(out.status.code(), Some(2), "{err}");
        assert!(
            err.contains(&format!("'{bad}' for '--deadman <DURATION>'"))
                && err.contains("from 100ms to 5s"),
            "{err}"
        );
        assert!(!dir.0.path().join("log").exists(), "nothing started");
    }
}

fn stdout_of(args: &[&str]) -> String {
    let out = Command::new(BIN).args(args).output().unwrap();
    assert!(out.status.success(), "{args:?}: {}", stderr(&out));
    String::from_utf8(out.stdout).unwrap()
}

#[test]
fn completions_cover_every_subcommand_and_option_in_each_shell() {
    let bash = stdout_of(&["completions", "bash"]);
    assert!(bash.contains("_adrive()") && bash.contains("complete -F _adrive"));
    let zsh = stdout_of(&["completions", "zsh"]);
    assert!(zsh.starts_with("#compdef adrive"), "{}", &zsh[..80]);
    let fish = stdout_of(&["completions", "fish"]);
    assert!(fish.contains("complete -c adrive"));
    for script in [&bash, &zsh, &fish] {
        for word in [
            "send", "watch", "sim", "ports", "deadman", "keymap", "count",
        ] {
            assert!(script.contains(word), "no {word} in\n{script}");
        }
    }
    // bash itself reads the script without a syntax error.
    let check = Command::new("bash").arg("-n").arg("-c").arg(&bash).output();
    match check {
        Ok(out) => assert!(out.status.success(), "{}", stderr(&out)),
        Err(e) => panic!("bash is needed to check the completion script: {e}"),
    }
}

#[test]
fn the_man_page_is_roff_with_every_option_and_subcommand() {
    let page = stdout_of(&["manpage"]);
    assert!(page.contains(".TH adrive 1"), "{page}");
    for section in [".SH NAME", ".SH SYNOPSIS", ".SH OPTIONS", ".SH SUBCOMMANDS"] {
        assert!(page.contains(section), "no {section}");
    }
    for word in [
        "\\-\\-deadman",
        "\\-\\-keymap",
        "\\-\\-listen",
        "adrive\\-send(1)",
        "adrive\\-watch(1)",
    ] {
        assert!(page.contains(word), "no {word} in\n{page}");
    }
    assert!(!page.contains("inject"), "a hidden option leaked");
    // With --dir, every page is written, the subcommands' included.
    let dir = Scratch::new();
    let out = Command::new(BIN)
        .args(["manpage", "--dir"])
        .arg(dir.0.path())
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", stderr(&out));
    let send = std::fs::read_to_string(dir.0.path().join("adrive-send.1")).unwrap();
    assert!(
        send.contains(".TH adrive-send 1") && send.contains("\\-\\-rate"),
        "{send}"
    );
    assert_eq!(
        std::fs::read_to_string(dir.0.path().join("adrive.1")).unwrap(),
        page,
        "the page on standard output is the one written"
    );
}

/// `--ros2` on a build without the feature says how to build it, and starts nothing
/// (it was refused once the devices were up: its log had begun).
#[cfg(not(feature = "ros2"))]
#[test]
fn ros2_without_the_feature_says_how_to_build_it() {
    let dir = Scratch::new();
    let path = dir.file("v.toml", VEHICLE);
    let out = adrive(&["--headless", "--ros2"], Some(&path), &dir);
    let err = stderr(&out);
    assert_eq!(out.status.code(), Some(2), "{err}");
    assert!(
        err.contains("--ros2: this adrive was built without ROS 2")
            && err.contains("cargo build --release --features ros2"),
        "{err}"
    );
    assert!(
        !dir.0.path().join("log").exists(),
        "it started before refusing: {:?}",
        std::fs::read_dir(dir.0.path().join("log")).map(|d| d.count())
    );
}

/// The incident: `adrive send bogus-verb 1` said "the devices are  (got …)", an empty
/// list, and the keywords it offered left out `release` and `clear`.
#[test]
fn send_with_a_word_that_is_no_device_nor_keyword_says_what_a_line_is() {
    let out = Command::new(BIN)
        .args(["send", "bogus-verb", "1"])
        .output()
        .unwrap();
    let err = stderr(&out);
    assert_eq!(out.status.code(), Some(2), "{err}");
    assert!(
        err.contains("unknown_verb: a line is a device (lowercase letters, digits and _) and a value, separated by a space (steer 0.2), or accel, engage, disengage, release, clear, seq or tag (got \"bogus-verb\")"),
        "{err}"
    );
    assert!(!err.contains("are  ") && !err.contains("()"), "{err}");
}

/// The incident: a vehicle named with an escape sequence was accepted, and the escape
/// reached the terminal in every log line. It is refused at its line, escaped.
#[test]
fn a_vehicle_name_with_an_escape_sequence_is_refused_at_its_line() {
    let dir = Scratch::new();
    let v = dir.file(
        "v.toml",
        VEHICLE.replace("name = \"bench\"", "name = \"bench\\u001b[2J\""),
    );
    let out = adrive(&["--sim", "--headless"], Some(&v), &dir);
    let err = stderr(&out);
    assert_eq!(out.status.code(), Some(2), "{err}");
    assert!(
        err.contains(&format!(
            "{}:2: vehicle name \"bench\\u{{1b}}[2J\": expected printable text on one line",
            v.display()
        )),
        "{err}"
    );
    assert!(!err.contains('\x1b'), "{err:?}");
}

/// The incident: an empty DBC file was reported as `no message "STEERING_COMMAND" (it
/// has )`. It is refused as a DBC error, at the file and line, saying it has no
/// messages.
#[test]
fn an_empty_dbc_is_refused_saying_it_has_no_messages() {
    let dir = Scratch::new();
    let oscc =
        std::fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join("vehicles/oscc.toml"))
            .unwrap();
    let v = dir.file("oscc.toml", oscc);
    let dbc = dir.file("oscc.dbc", "");
    let out = common::output_within(Command::new(BIN).args(["sim", "--config"]).arg(&v));
    let err = stderr(&out);
    assert_eq!(out.status.code(), Some(2), "{err}");
    assert!(
        err.contains(&format!(
            "bus kit: dbc: {}:1: the file has no messages",
            dbc.display()
        )),
        "{err}"
    );
    assert!(!err.contains("(it has )"), "{err}");
}
