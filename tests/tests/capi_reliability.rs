//! The C API's reliability cases and its sweep (`tests/c/reliability.c`), compiled with
//! `-fsanitize=address,undefined` when the system's `cc` supports it: a refused `gman_init`
//! leaves a live navigator in the same arena untouched, a step refused as numerical changes
//! nothing, overlapping spans are refused, the alignment status text, the option that
//! requires a header-covering blob format, and every function under hostile arguments
//! (NULL, empty, huge, misaligned, overlapping, NaN, wrong order).

use std::process::Command;

#[path = "support/capi.rs"]
#[allow(dead_code)]
mod capi;

/// The sanitizer flags `cc` accepts (compiles and runs a trivial program with them), or none.
fn sanitizers() -> Vec<&'static str> {
    let flags = vec![
        "-fsanitize=address,undefined",
        "-fno-sanitize-recover=undefined",
        "-fno-omit-frame-pointer",
    ];
    let dir = capi::build_dir();
    std::fs::create_dir_all(&dir).unwrap();
    let (src, exe) = (dir.join("san-probe.c"), dir.join("san-probe"));
    std::fs::write(&src, "int main(void) { return 0; }\n").unwrap();
    let built = Command::new("cc")
        .args(&flags)
        .arg(&src)
        .arg("-o")
        .arg(&exe)
        .output()
        .is_ok_and(|o| o.status.success());
    if built && Command::new(&exe).status().is_ok_and(|s| s.success()) {
        flags
    } else {
        eprintln!("cc does not support -fsanitize=address,undefined here: building without");
        Vec::new()
    }
}

#[test]
fn c_api_refused_calls_change_nothing_and_hostile_arguments_get_a_status() {
    let lib = capi::staticlib(None);
    let exe = capi::build_dir().join("capi-reliability");
    let san = sanitizers();
    let mut cmd = Command::new("cc");
    cmd.args(["-std=c11", "-O1", "-g", "-Wall", "-Wextra", "-Werror"])
        .args(&san)
        .arg("-I")
        .arg(capi::include_dir())
        .arg(capi::root().join("tests/c/reliability.c"))
        .arg(lib)
        .args(["-lpthread", "-ldl", "-lm", "-o"])
        .arg(&exe);
    capi::run(&mut cmd);
    let models = capi::root().join("host-sim/models");
    // Format v3 with commit delay 0, and format v4; the same sizes.
    let old = models.join("gman-map3-b16-mcu-int8-seed5.gman");
    let new = models.join("gman-thor5-map3-b16-mcu-int8-seed3.gman");
    let out = Command::new(&exe)
        .arg(&old)
        .arg(&new)
        .env("ASAN_OPTIONS", "detect_leaks=1:abort_on_error=0")
        .env("UBSAN_OPTIONS", "print_stacktrace=1:halt_on_error=1")
        .output()
        .expect("run the C reliability program");
    let stdout = String::from_utf8_lossy(&out.stdout);
    let stderr = String::from_utf8_lossy(&out.stderr);
    println!("{stdout}");
    assert!(
        out.status.success() && stdout.ends_with("OK\n"),
        "the C reliability program failed (sanitizers: {san:?}):\n{stdout}{stderr}"
    );
    assert!(stdout.contains("sweep: "), "{stdout}");
}
