//! The README's device sequence, run as written: its three lines (train, export, build and run
//! the firmware under QEMU) taken from README.md's "Train, export, run on the device" block and
//! run by `bash` in a scratch root (`common::scratch`), with one change: the training budget
//! `--updates N` becomes `--config tiny --updates 10` (the written budget is minutes of
//! training). Everything else (the method and its settings, the export's flags, the firmware's
//! build with the exported blob) is the README's text, so a blob the documented commands make
//! must run on the documented firmware. Without `../shared` the `--data` argument is dropped
//! and the built-in world trains the model. Needs qemu-system-arm and the
//! thumbv7em-none-eabihf target: skipped without them unless `GMAN_REQUIRE_QEMU=1` (CI).

mod common;

use common::scratch::{at_test_budget, block_commands, checkout, device_tools, sh_block, Scratch};

/// The commands of the README's device block.
fn device_block(readme: &str) -> Vec<String> {
    let section = readme
        .split("\n## Train, export, run on the device\n")
        .nth(1)
        .expect("README.md has a section \"Train, export, run on the device\"");
    let block = sh_block(section, "gman train ")
        .expect("the section's ```sh block starts with `gman train`");
    block_commands(block)
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
    assert_eq!(
        at_test_budget(
            "nice -n 5 gman eval --data D --agent 'a{seed}.gman' --json x.json",
            true
        ),
        "nice -n 5 gman eval --data D --agent 'a{seed}.gman' --json x.json --episodes 5"
    );
    assert_eq!(
        at_test_budget("gman export --out a.gman", false),
        "gman export --out a.gman"
    );
}

#[cfg(unix)]
#[test]
fn readme_device_sequence_runs_as_written() {
    let readme = std::fs::read_to_string(checkout().join("README.md")).expect("README.md");
    let lines = device_block(&readme);
    assert_eq!(lines.len(), 3, "train, export, firmware: {lines:?}");
    assert!(lines[0].starts_with("gman train "), "{}", lines[0]);
    assert!(lines[1].starts_with("gman export "), "{}", lines[1]);
    assert!(lines[2].contains("firmware-example"), "{}", lines[2]);
    if !device_tools("readme_device") {
        return;
    }
    assert!(
        lines[0].contains(" --updates "),
        "the README's training line sets no --updates: {}",
        lines[0]
    );
    let s = Scratch::new("readme-device");
    s.run(
        "README device line 1",
        &at_test_budget(&lines[0], s.have_data),
    );
    s.run("README device line 2", &lines[1]);
    let out = s.run("README device line 3", &lines[2]);
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert_eq!(
        stdout.lines().map(str::trim_end).next_back(),
        Some("OK"),
        "the firmware did not finish its episode:\n{stdout}"
    );
    assert!(
        stdout.lines().any(|l| l.starts_with("t=39 ")),
        "the firmware did not print the episode's 40 steps:\n{stdout}"
    );
    assert!(
        s.root.join("gman.gman").is_file(),
        "the export wrote no gman.gman"
    );
}
