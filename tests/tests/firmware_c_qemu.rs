//! The C firmware (`firmware-example/c/`: `device.c`, `episode.c`, `blob.S`, `link.ld`),
//! built with `arm-none-eabi-gcc` against the C API's static library for
//! `thumbv7em-none-eabihf`, runs the recorded episode under QEMU `mps2-an386` and must print
//! bit for bit the lines of the Rust firmware (the same as the Rust navigator on the host,
//! which `firmware_qemu.rs` checks against the Rust firmware).
//!
//! Needs `qemu-system-arm`, `arm-none-eabi-gcc` and the `thumbv7em-none-eabihf` target.
//! Without them the test says so and returns, unless `GMAN_REQUIRE_QEMU=1` (set by CI).

use std::process::Command;

#[path = "support/device_tools.rs"]
mod device_tools;

#[path = "../../firmware-example/src/episode.rs"]
#[allow(dead_code)]
mod episode;

#[path = "../../firmware-example/blobgen.rs"]
mod blobgen;

#[path = "support/capi.rs"]
#[allow(dead_code)]
mod capi;

struct Lines(Vec<String>);
impl episode::Probe for Lines {
    fn line(&mut self, args: std::fmt::Arguments<'_>) {
        self.0.push(args.to_string());
    }
}

fn rust_lines(blob: &[u8], ep: &[u8]) -> Vec<String> {
    let mut out = Lines(Vec::new());
    let mut arena = vec![0.0f32; episode::ARENA_LEN];
    // The C program gives the navigator the map as f32 values (`gman_step_map`).
    episode::run_f32_map(blob, &mut episode::Bytes(ep), &mut arena, &mut out)
        .expect("Rust episode");
    out.0
}

const TARGET: &str = "thumbv7em-none-eabihf";

#[test]
fn c_firmware_under_qemu_matches_the_rust_firmware_bit_for_bit() {
    if !device_tools::device_tools("firmware_c_qemu", true) {
        return;
    }
    let lib = capi::staticlib(Some(TARGET));
    let blob = blobgen::default_blob_in(&capi::root().join("firmware-example"));
    let model = capi::write_blob(&blob);
    let c = capi::c_dir();
    let dir = capi::build_dir();
    let cflags = [
        "-mcpu=cortex-m4",
        "-mthumb",
        "-mfloat-abi=hard",
        "-mfpu=fpv4-sp-d16",
        "-O2",
        "-std=c11",
        "-ffp-contract=off",
        "-fno-math-errno",
        "-ffreestanding",
        "-ffunction-sections",
        "-fdata-sections",
        "-Wall",
        "-Wextra",
        "-Werror",
    ];
    let elf = dir.join("gman-c-firmware.elf");
    capi::run(
        Command::new("arm-none-eabi-gcc")
            .args(cflags)
            .arg("-I")
            .arg(capi::include_dir())
            .arg(format!("-DGMAN_BLOB_PATH=\"{}\"", model.display()))
            .arg(c.join("device.c"))
            .arg(c.join("episode.c"))
            .arg(c.join("blob.S"))
            .args([
                "-nostdlib",
                "-nostartfiles",
                "-Wl,--gc-sections,-z,noexecstack",
                "-T",
            ])
            .arg(c.join("link.ld"))
            .arg(&lib)
            .args(["-lgcc", "-o"])
            .arg(&elf),
    );
    // In firmware-example/: the firmware opens data/episode.gmep there through semihosting.
    let out = Command::new("timeout")
        .current_dir(capi::root().join("firmware-example"))
        .args(["120", "qemu-system-arm", "-M", "mps2-an386", "-nographic"])
        .args(["-icount", "shift=0"])
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
    let got: Vec<&str> = stdout.lines().map(str::trim_end).collect();
    let want = capi::rust_episode_lines(rust_lines, &blob);
    assert!(want.iter().any(|l| l.starts_with("  inner update")));
    capi::assert_same_lines(&got, &want, "C firmware under QEMU");
}
