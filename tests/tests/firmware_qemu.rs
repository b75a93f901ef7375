//! Builds the Cortex-M4F firmware, runs it under QEMU (`mps2-an386`) and checks that it prints
//! bit for bit what the same source (`firmware-example/src/selftest.rs`) prints on the host
//! with the same blob: x86 and thumbv7em-none-eabihf builds of gman-core must agree exactly.
//!
//! Needs `qemu-system-arm` and the `thumbv7em-none-eabihf` target. Without them the test
//! says so and returns, unless `GMAN_REQUIRE_QEMU=1` (set by CI), where it fails.

use std::path::PathBuf;
use std::process::Command;

#[path = "../../firmware-example/src/selftest.rs"]
#[allow(dead_code)]
mod selftest;

#[path = "../../firmware-example/blobgen.rs"]
mod blobgen;

fn have(cmd: &str, arg: &str) -> bool {
    Command::new(cmd)
        .arg(arg)
        .output()
        .map(|o| o.status.success())
        .unwrap_or(false)
}

fn skip_or_fail(why: &str) {
    if std::env::var("GMAN_REQUIRE_QEMU").as_deref() == Ok("1") {
        panic!("{why} (GMAN_REQUIRE_QEMU=1)");
    }
    eprintln!("SKIPPED firmware_qemu: {why}");
}

#[test]
fn firmware_under_qemu_matches_host_bit_for_bit() {
    if !have("qemu-system-arm", "--version") {
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
    let fw = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../firmware-example");
    let status = Command::new(env!("CARGO"))
        .current_dir(&fw)
        .args(["build", "--release", "--quiet"])
        .env_remove("GMAN_FIRMWARE_BLOB")
        .status()
        .expect("run cargo build for the firmware");
    assert!(status.success(), "firmware build failed");
    let elf = fw.join("target/thumbv7em-none-eabihf/release/gman-firmware-example");
    let out = Command::new("timeout")
        .args(["120", "qemu-system-arm", "-M", "mps2-an386", "-nographic"])
        .args(["-semihosting-config", "enable=on,target=native", "-kernel"])
        .arg(&elf)
        .output()
        .expect("run qemu");
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "QEMU run failed ({:?}):\n{stdout}\n{}",
        out.status,
        String::from_utf8_lossy(&out.stderr)
    );
    let device: Vec<&str> = stdout.lines().map(str::trim_end).collect();
    assert_eq!(
        device.last(),
        Some(&"OK"),
        "firmware did not finish: {stdout}"
    );

    let blob = blobgen::seeded_blob(&gman_core::Dims::MCU, 1);
    let mut host = Vec::new();
    selftest::run(&blob, &mut |a| host.push(a.to_string())).expect("host self-test");
    assert!(host.len() >= 6, "host printed too little: {host:?}");
    assert_eq!(
        &device[..device.len() - 1],
        &host.iter().map(String::as_str).collect::<Vec<_>>()[..]
    );
}
