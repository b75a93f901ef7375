//! The README's device sequence, run as written: its three lines (train, export, build and run
//! the firmware under QEMU) taken from README.md's "Train, export, run on the device" block and
//! run by `bash` in a scratch root, with one change: the training budget `--updates N` becomes
//! `--config tiny --updates 10` (the written budget is minutes of training). Everything else
//! (the method and its settings, the export's flags, the firmware's build with the exported
//! blob) is the README's text, so a blob the documented commands make must run on the
//! documented firmware.
//!
//! The scratch root is `target/readme-device/root`, the checkout's entries linked into it:
//! `gman` on `PATH` is this build's binary, `../shared` links to the checkout's neighbour (without
//! it the `--data` argument is dropped and the built-in world trains the model), and the
//! firmware builds into its own target directory so the firmware test's images stay as they
//! are. Needs qemu-system-arm and the thumbv7em-none-eabihf target: skipped without them
//! unless `GMAN_REQUIRE_QEMU=1` (CI), where it fails instead.

use std::path::{Path, PathBuf};
use std::process::Command;

fn root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("..")
        .canonicalize()
        .expect("the checkout")
}

/// The shell lines of the README's device block.
fn device_block(readme: &str) -> Vec<String> {
    let section = readme
        .split("\n## Train, export, run on the device\n")
        .nth(1)
        .expect("README.md has a section \"Train, export, run on the device\"");
    let block = section
        .split("```sh\n")
        .nth(1)
        .and_then(|b| b.split("```").next())
        .expect("the section opens with a ```sh block");
    block
        .lines()
        .map(str::trim)
        .filter(|l| !l.is_empty() && !l.starts_with('#'))
        .map(String::from)
        .collect()
}

/// The README's training line at the test's budget: `--updates N` becomes `--config tiny
/// --updates 10`; without the data directory the `--data DIR` argument goes.
fn at_test_budget(train: &str, have_data: bool) -> String {
    let words: Vec<&str> = train.split_whitespace().collect();
    let mut out = Vec::new();
    let mut i = 0;
    let mut budget = false;
    while i < words.len() {
        match words[i] {
            "--updates" => {
                out.extend(["--config", "tiny", "--updates", "10"]);
                budget = true;
                i += 2;
            }
            "--data" if !have_data => i += 2,
            w => {
                out.push(w);
                i += 1;
            }
        }
    }
    assert!(
        budget,
        "the README's training line sets no --updates: {train}"
    );
    out.join(" ")
}

fn skip_or_fail(why: &str) -> bool {
    if std::env::var("GMAN_REQUIRE_QEMU").as_deref() == Ok("1") {
        panic!("{why} (GMAN_REQUIRE_QEMU=1)");
    }
    eprintln!("SKIPPED readme_device: {why}");
    false
}

fn device_tools() -> bool {
    let qemu = Command::new("qemu-system-arm").arg("--version").output();
    if !qemu.map(|o| o.status.success()).unwrap_or(false) {
        return skip_or_fail("qemu-system-arm not found (apt-get install qemu-system-arm)");
    }
    let targets = Command::new("rustup")
        .args(["target", "list", "--installed"])
        .output();
    if !targets
        .map(|o| String::from_utf8_lossy(&o.stdout).contains("thumbv7em-none-eabihf"))
        .unwrap_or(false)
    {
        return skip_or_fail(
            "target thumbv7em-none-eabihf not installed (rustup target add thumbv7em-none-eabihf)",
        );
    }
    true
}

#[cfg(unix)]
fn link(from: &Path, to: &Path) {
    let _ = std::fs::remove_file(to);
    std::os::unix::fs::symlink(from, to)
        .unwrap_or_else(|e| panic!("link {} -> {}: {e}", to.display(), from.display()));
}

/// Links every entry of `from` into `to` but those named in `except`.
#[cfg(unix)]
fn mirror(from: &Path, to: &Path, except: &[&str]) {
    for entry in std::fs::read_dir(from).expect("read the checkout") {
        let entry = entry.expect("a directory entry");
        let name = entry.file_name();
        if !except.iter().any(|e| name == *e) {
            link(&entry.path(), &to.join(&name));
        }
    }
}

#[test]
fn training_line_takes_the_test_budget() {
    let line = "gman train --data ../shared/data/gman --method gman --updates 6000 --out runs/gman";
    assert_eq!(
        at_test_budget(line, true),
        "gman train --data ../shared/data/gman --method gman --config tiny --updates 10 --out runs/gman"
    );
    assert_eq!(
        at_test_budget(line, false),
        "gman train --method gman --config tiny --updates 10 --out runs/gman"
    );
}

#[cfg(unix)]
#[test]
fn readme_device_sequence_runs_as_written() {
    let repo = root();
    let readme = std::fs::read_to_string(repo.join("README.md")).expect("README.md");
    let lines = device_block(&readme);
    assert_eq!(lines.len(), 3, "train, export, firmware: {lines:?}");
    assert!(lines[0].starts_with("gman train "), "{}", lines[0]);
    assert!(lines[1].starts_with("gman export "), "{}", lines[1]);
    assert!(lines[2].contains("firmware-example"), "{}", lines[2]);
    if !device_tools() {
        return;
    }

    let scratch = repo.join("target/readme-device");
    let run_root = scratch.join("root");
    let _ = std::fs::remove_dir_all(&run_root);
    std::fs::create_dir_all(&run_root).expect("the scratch root");
    // A mirror of the checkout through links, with firmware-example a real directory: the
    // README's `$PWD/../gman.gman` (from inside firmware-example) must name the scratch root.
    mirror(
        &repo,
        &run_root,
        &["target", "runs", "gman.gman", "firmware-example"],
    );
    let fw = run_root.join("firmware-example");
    std::fs::create_dir(&fw).expect("the scratch firmware directory");
    mirror(&repo.join("firmware-example"), &fw, &["target"]);
    let shared = repo.join("../shared");
    let have_data = shared.join("data/gman/attributes.json").is_file();
    if have_data {
        link(&shared.canonicalize().unwrap(), &scratch.join("shared"));
    }
    let bin = Path::new(env!("CARGO_BIN_EXE_gman")).parent().unwrap();
    let path = format!(
        "{}:{}",
        bin.display(),
        std::env::var("PATH").unwrap_or_default()
    );

    let script = [
        at_test_budget(&lines[0], have_data),
        lines[1].clone(),
        lines[2].clone(),
    ];
    for (i, line) in script.iter().enumerate() {
        let out = Command::new("timeout")
            .arg("900")
            .args(["bash", "-eo", "pipefail", "-c", line])
            .current_dir(&run_root)
            .env("PATH", &path)
            .env("CARGO_TARGET_DIR", scratch.join("firmware-target"))
            .env_remove("GMAN_FIRMWARE_BLOB")
            .output()
            .expect("run bash");
        let stdout = String::from_utf8_lossy(&out.stdout);
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert!(
            out.status.success(),
            "README device line {} failed ({:?}): {line}\n--- stdout\n{stdout}\n--- stderr\n{stderr}",
            i + 1,
            out.status
        );
        if i == 2 {
            assert_eq!(
                stdout.lines().map(str::trim_end).next_back(),
                Some("OK"),
                "the firmware did not finish its episode:\n{stdout}\n{stderr}"
            );
            assert!(
                stdout.lines().any(|l| l.starts_with("t=39 ")),
                "the firmware did not print the episode's 40 steps:\n{stdout}"
            );
        }
    }
    assert!(
        run_root.join("gman.gman").is_file(),
        "the export wrote no gman.gman"
    );
}
