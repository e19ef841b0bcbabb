//! Every keymap shipped in `keymaps/` loads (merged over the default, as `--keymap`
//! does), and a broken keymap file is refused with its file, line and expected form.

use adrive::config::Role;
use adrive::console::keymap::{Action, Keymap, Mode, Target};
use std::path::Path;

#[test]
fn every_shipped_keymap_loads() {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("keymaps");
    let mut n = 0;
    for entry in std::fs::read_dir(&dir).unwrap() {
        let path = entry.unwrap().path();
        if path.extension().is_some_and(|e| e == "toml") {
            let map = Keymap::load(&path).unwrap_or_else(|e| panic!("{e}"));
            for mode in Mode::ALL {
                assert!(!map.bindings(mode).is_empty(), "{}: {mode}", path.display());
            }
            // An emergency stop in every mode: no shipped keymap takes it away.
            assert!(map.warnings().is_empty(), "{:?}", map.warnings());
            for mode in Mode::ALL {
                assert!(
                    map.key_for(mode, Action::Stop).is_some(),
                    "{}: no STOP key in {mode}",
                    path.display()
                );
            }
            n += 1;
        }
    }
    assert!(n >= 2, "default.toml and at least one alternative");
}

#[test]
fn the_teleop_keymap_changes_what_it_says() {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("keymaps/teleop.toml");
    let map = Keymap::load(&path).unwrap();
    let key = |s: &str| s.parse().unwrap();
    assert_eq!(map.lookup(Mode::Main, key("i")), Some(Action::Teleop));
    assert_eq!(map.lookup(Mode::Main, key("<Space>")), Some(Action::Stop));
    assert_eq!(map.lookup(Mode::Teleop, key("i")), Some(Action::AccelUp));
    assert_eq!(map.lookup(Mode::Teleop, key("w")), None, "unbound");
    assert_eq!(map.lookup(Mode::Teleop, key("<Up>")), Some(Action::AccelUp));
    // The rest of the default is still there.
    assert_eq!(
        map.lookup(Mode::Main, key("s")),
        Some(Action::EditOf(Target::Device(Role::Steering)))
    );
}

#[test]
fn a_broken_keymap_file_names_file_line_and_form() {
    let dir = std::env::temp_dir().join(format!("adrive-keymap-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let cases = [
        (
            "[main]\nkeymap = [\n    { on = \"g\", run = \"edit gas\" },\n    { on = \"<Ctrl-x>\", run = \"quit\" },\n]\n",
            4,
            "expected a single character",
        ),
        (
            "[teleop]\nkeymap = [\n    { on = \"x\", run = \"turbo\" },\n]\n",
            3,
            "expected one of quit, help",
        ),
        (
            "[bench]\nkeymap = [\n    { on = \"x\", run = \"bench\" },\n    { on = \"y\", run = \"back\" },\n    { on = \"x\", run = \"back\" },\n]\n",
            5,
            "bound twice",
        ),
        ("[main]\nkeymap = [\n  { on = \"g\" \n", 3, ""),
        (
            "[main]\nkeymap = [\n    { on = \"<C-c>\", run = \"help\", desc = \"help\" },\n]\n",
            3,
            "<C-c> cannot be bound",
        ),
    ];
    for (i, (text, line, form)) in cases.iter().enumerate() {
        let path = dir.join(format!("broken{i}.toml"));
        std::fs::write(&path, text).unwrap();
        let e = Keymap::load(&path).unwrap_err();
        let shown = e.to_string();
        assert!(
            shown.starts_with(&format!("{}:{line}: ", path.display())),
            "case {i}: {shown}"
        );
        assert!(shown.contains(form), "case {i}: {shown}");
    }
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn the_binary_refuses_a_broken_keymap_before_starting() {
    let dir = std::env::temp_dir().join(format!("adrive-keymap-bin-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join("bad.toml");
    std::fs::write(
        &path,
        "[main]\nkeymap = [\n  { on = \"g\", run = \"fly\" },\n]\n",
    )
    .unwrap();
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_adrive"))
        .args(["--sim", "--log-dir"])
        .arg(&dir)
        .env("XDG_RUNTIME_DIR", &dir)
        .arg("--keymap")
        .arg(&path)
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{err}");
    assert!(
        err.contains(&format!("{}:3: unknown action \"fly\"", path.display())),
        "{err}"
    );
    let _ = std::fs::remove_dir_all(&dir);
}
