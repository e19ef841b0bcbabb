//! The install steps of docs/service.md, run as written into a scratch root (every
//! absolute path under it): they must install everything the units in `dist/systemd/`
//! reference — the binary of ExecStart and the files its flags name, the units
//! themselves, the manual page of `Documentation=man:…`, the user of `User=` — and
//! `systemd-analyze verify` then finds nothing to say, manual pages included.

mod common;

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::{Command as Process, Stdio};

const BIN: &str = env!("CARGO_BIN_EXE_adrive");

fn root_dir() -> &'static Path {
    Path::new(env!("CARGO_MANIFEST_DIR"))
}

/// The `sh` block under `## Install` in docs/service.md, one command a line (`&&`
/// splits a line).
fn install_steps() -> Vec<String> {
    let text = std::fs::read_to_string(root_dir().join("docs/service.md")).unwrap();
    let section = text
        .split("\n## Install\n")
        .nth(1)
        .expect("docs/service.md has an Install section");
    let block = section
        .split("```sh\n")
        .nth(1)
        .and_then(|b| b.split("```").next())
        .expect("the Install section has an sh block");
    block
        .lines()
        .map(|l| l.split(" #").next().unwrap_or(l).trim())
        .filter(|l| !l.is_empty())
        .flat_map(|l| l.split("&&").map(|c| c.trim().to_string()))
        .collect()
}

/// What running the steps left: files under `root`, and the users made (user → group).
struct Installed {
    root: tempfile::TempDir,
    users: BTreeMap<String, String>,
}

impl Installed {
    /// `path` (absolute, as the steps and the units write it) under the root.
    fn at(&self, path: &str) -> PathBuf {
        self.root.path().join(path.trim_start_matches('/'))
    }

    fn run(steps: &[String]) -> Installed {
        let mut me = Installed {
            root: common::tempdir("install-root"),
            users: BTreeMap::new(),
        };
        // What every system with systemd and udev has already.
        for d in [
            "/usr/local/bin",
            "/usr/local/share/man",
            "/etc/systemd/system",
            "/etc/udev/rules.d",
        ] {
            std::fs::create_dir_all(me.at(d)).unwrap();
        }
        for step in steps {
            let w: Vec<&str> = step.split_whitespace().collect();
            match w[..] {
                ["install", "-d", ref dirs @ ..] => {
                    for d in dirs {
                        std::fs::create_dir_all(me.at(d)).unwrap();
                    }
                }
                ["install", "-m", _mode, ref args @ ..] => {
                    let (dest, sources) = args.split_last().expect("install SRC… DEST");
                    let into_dir = dest.ends_with('/') || sources.len() > 1;
                    for src in sources {
                        let from = if *src == "target/release/adrive" {
                            PathBuf::from(BIN)
                        } else {
                            root_dir().join(src)
                        };
                        assert!(from.is_file(), "{step}: {src} is not in the clone");
                        let to = if into_dir {
                            me.at(dest).join(Path::new(src).file_name().unwrap())
                        } else {
                            me.at(dest)
                        };
                        assert!(
                            to.parent().unwrap().is_dir(),
                            "{step}: {} does not exist yet",
                            to.parent().unwrap().display()
                        );
                        std::fs::copy(&from, &to).unwrap();
                    }
                }
                ["useradd", ref args @ ..] => {
                    let user = args.last().unwrap().to_string();
                    let group = args
                        .windows(2)
                        .find(|p| p[0] == "--gid")
                        .map(|p| p[1].to_string())
                        .unwrap_or_else(|| user.clone());
                    me.users.insert(user, group);
                }
                // The installed binary writes its manual pages.
                [bin, "manpage", "--dir", dir] if bin.ends_with("adrive") => {
                    let installed = me.at(bin);
                    assert!(installed.is_file(), "{step}: {bin} is not installed yet");
                    let out = Process::new(BIN)
                        .args(["manpage", "--dir"])
                        .arg(me.at(dir))
                        .output()
                        .unwrap();
                    assert!(out.status.success(), "{step}: {out:?}");
                }
                // They change the running system, not the files.
                ["systemctl", ..] | ["udevadm", ..] | ["mandb", ..] => {}
                _ => panic!("an install step this test does not know: {step:?}; teach it"),
            }
        }
        me
    }
}

/// A unit file's `Key=value` lines by section.
fn unit(text: &str) -> BTreeMap<String, Vec<(String, String)>> {
    let mut out: BTreeMap<String, Vec<(String, String)>> = BTreeMap::new();
    let mut section = String::new();
    for line in text.lines().map(str::trim) {
        if line.starts_with('#') || line.is_empty() {
            continue;
        }
        if let Some(s) = line.strip_prefix('[').and_then(|l| l.strip_suffix(']')) {
            section = s.to_string();
        } else if let Some((k, v)) = line.split_once('=') {
            out.entry(section.clone())
                .or_default()
                .push((k.trim().into(), v.trim().into()));
        }
    }
    out
}

/// The incident: `Documentation=man:adrive(1)` made `systemd-analyze verify` fail after
/// the install steps of docs/service.md, which did not install the manual page.
#[test]
fn the_install_steps_install_everything_the_units_reference() {
    let steps = install_steps();
    let done = Installed::run(&steps);
    for name in ["adrive.service", "adrive-sim.service"] {
        let text = std::fs::read_to_string(root_dir().join("dist/systemd").join(name)).unwrap();
        let u = unit(&text);
        let get = |section: &str, key: &str| -> Vec<String> {
            u.get(section)
                .into_iter()
                .flatten()
                .filter(|(k, _)| k == key)
                .map(|(_, v)| v.clone())
                .collect()
        };
        assert!(
            done.at(&format!("/etc/systemd/system/{name}")).is_file(),
            "{name} is not installed: {steps:#?}"
        );
        // What systemd makes itself for the service.
        let managed: Vec<String> = [
            ("RuntimeDirectory", "/run/"),
            ("LogsDirectory", "/var/log/"),
            ("StateDirectory", "/var/lib/"),
        ]
        .iter()
        .flat_map(|(k, base)| {
            get("Service", k)
                .into_iter()
                .map(move |d| format!("{base}{d}"))
        })
        .collect();
        let exec = get("Service", "ExecStart").join(" ");
        for word in exec.split_whitespace().filter(|w| w.starts_with('/')) {
            if managed.iter().any(|m| word.starts_with(m.as_str())) {
                continue;
            }
            assert!(
                done.at(word).exists(),
                "{name}: ExecStart names {word}, which the install steps do not install"
            );
        }
        for doc in get("Unit", "Documentation")
            .iter()
            .flat_map(|d| d.split_whitespace().map(String::from).collect::<Vec<_>>())
        {
            let Some(page) = doc.strip_prefix("man:") else {
                continue;
            };
            let (title, section) = page
                .strip_suffix(')')
                .and_then(|p| p.split_once('('))
                .unwrap_or_else(|| panic!("{name}: Documentation={doc}"));
            let file = format!("/usr/local/share/man/man{section}/{title}.{section}");
            assert!(
                done.at(&file).is_file(),
                "{name}: Documentation={doc}, but the install steps install no {file}: {steps:#?}"
            );
        }
        for user in get("Service", "User") {
            let group = get("Service", "Group")
                .pop()
                .unwrap_or_else(|| user.clone());
            assert_eq!(
                done.users.get(&user),
                Some(&group),
                "{name}: User={user} Group={group}, not made so by the install steps"
            );
        }
    }

    // systemd itself, its manual page check included, looking where the steps put them.
    let have = Process::new("systemd-analyze")
        .arg("--version")
        .stdout(Stdio::null())
        .status()
        .is_ok_and(|s| s.success());
    assert!(
        have,
        "systemd-analyze is not installed: this test runs it on the installed units \
         (apt install systemd)"
    );
    let mut paths = Vec::new();
    for name in ["adrive.service", "adrive-sim.service"] {
        let installed = done.at(&format!("/etc/systemd/system/{name}"));
        let text = std::fs::read_to_string(&installed)
            .unwrap()
            .replace("/usr/local/bin/adrive", BIN);
        std::fs::write(&installed, text).unwrap();
        paths.push(installed);
    }
    let out = Process::new("systemd-analyze")
        .args(["verify", "--man=yes"])
        .args(&paths)
        .env("MANPATH", done.at("/usr/local/share/man"))
        .output()
        .unwrap();
    let said = String::from_utf8_lossy(&out.stderr);
    let about_ours: Vec<&str> = said.lines().filter(|l| l.contains("adrive")).collect();
    assert!(
        out.status.success() && about_ours.is_empty(),
        "systemd-analyze verify:\n{said}"
    );
}
