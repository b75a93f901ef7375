//! Whether the device tools are here: QEMU, the Cortex-M4F target and, when asked, the ARM C
//! compiler. Without one a device test is skipped, or fails under `GMAN_REQUIRE_QEMU=1` (CI).
//! Shared by the device tests of gman-tests and gman-host-sim (included with `#[path]`).

use std::process::Command;

/// Panics with `why` under `GMAN_REQUIRE_QEMU=1`, else prints that `test` is skipped;
/// returns false.
pub fn skip_or_fail(test: &str, why: &str) -> bool {
    if std::env::var("GMAN_REQUIRE_QEMU").as_deref() == Ok("1") {
        panic!("{why} (GMAN_REQUIRE_QEMU=1)");
    }
    eprintln!("SKIPPED {test}: {why}");
    false
}

/// Whether `cmd arg` runs and succeeds.
pub fn runs(cmd: &str, arg: &str) -> bool {
    Command::new(cmd)
        .arg(arg)
        .output()
        .map(|o| o.status.success())
        .unwrap_or(false)
}

/// True when `qemu-system-arm`, the `thumbv7em-none-eabihf` target and (with `c_compiler`)
/// `arm-none-eabi-gcc` are here; else [`skip_or_fail`] for `test`.
pub fn device_tools(test: &str, c_compiler: bool) -> bool {
    if !runs("qemu-system-arm", "--version") {
        return skip_or_fail(
            test,
            "qemu-system-arm not found (apt-get install qemu-system-arm)",
        );
    }
    if c_compiler && !runs("arm-none-eabi-gcc", "--version") {
        return skip_or_fail(
            test,
            "arm-none-eabi-gcc not found (apt-get install gcc-arm-none-eabi)",
        );
    }
    let targets = Command::new("rustup")
        .args(["target", "list", "--installed"])
        .output();
    if !targets
        .map(|o| String::from_utf8_lossy(&o.stdout).contains("thumbv7em-none-eabihf"))
        .unwrap_or(false)
    {
        return skip_or_fail(
            test,
            "target thumbv7em-none-eabihf not installed (rustup target add thumbv7em-none-eabihf)",
        );
    }
    true
}
