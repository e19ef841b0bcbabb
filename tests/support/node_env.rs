//! Node.js packages pinned by a lock file, for the interoperability tests that run a
//! third-party implementation written in JavaScript (Foxglove Studio's channel reader):
//! `npm ci` of `tests/support/<name>/package-lock.json` into `target/tmp/<name>`, done
//! once and again whenever the lock changes. It fails loudly, with the reason, when
//! Node.js or npm is missing or the install fails: these tests never skip.

use std::path::{Path, PathBuf};
use std::process::Command as Process;

/// The `node_modules` of `tests/support/<name>`'s lock file, installed.
pub fn modules(name: &str) -> PathBuf {
    let src = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/support")
        .join(name);
    let dir = PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join(name);
    let lock = std::fs::read(src.join("package-lock.json")).expect("the lock file");
    let installed = dir.join("node_modules/.package-lock.json");
    let stamp = dir.join("installed-lock.json");
    if installed.exists() && std::fs::read(&stamp).is_ok_and(|s| s == lock) {
        return dir.join("node_modules");
    }
    let node = Process::new("node").arg("--version").output();
    assert!(
        node.as_ref().is_ok_and(|o| o.status.success()),
        "this interoperability test needs Node.js (`node`) and npm: {node:?}"
    );
    std::fs::create_dir_all(&dir).unwrap();
    for f in ["package.json", "package-lock.json"] {
        std::fs::copy(src.join(f), dir.join(f)).unwrap();
    }
    let out = Process::new("npm")
        .args(["ci", "--no-audit", "--no-fund", "--ignore-scripts"])
        .current_dir(&dir)
        .output();
    match out {
        Ok(o) if o.status.success() => {}
        other => panic!(
            "this interoperability test needs the npm packages of {}; `npm ci` in {} failed \
             (it needs npm and the npm registry the first time): {}",
            src.join("package.json").display(),
            dir.display(),
            match other {
                Ok(o) => format!(
                    "{}\n{}{}",
                    o.status,
                    String::from_utf8_lossy(&o.stdout),
                    String::from_utf8_lossy(&o.stderr)
                ),
                Err(e) => e.to_string(),
            }
        ),
    }
    std::fs::write(&stamp, lock).unwrap();
    dir.join("node_modules")
}
