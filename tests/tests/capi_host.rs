//! The C API on the host: a C program (`firmware-example/c/host.c` + `episode.c`, built with
//! the system's `cc` against `libgman_ffi.a`) loads the shipped blob, replays the recorded
//! episode through the C API in two navigators (two arenas, both misaligned on purpose) and
//! must print bit for bit the lines the Rust navigator prints for it (at its commit delay,
//! 20), linked with the static library and with the shared one; a third navigator on the
//! background schedule (`gman_adapt_slice` between the steps) must print the same lines but
//! for the one naming the schedule
//! (`firmware-example/src/episode.rs`, what the Rust firmware runs).

use std::process::Command;

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

/// Builds the host program against the static library, or the shared one (`shared`).
fn build(shared: bool) -> std::path::PathBuf {
    let c = capi::c_dir();
    let exe = capi::build_dir().join(if shared { "capi-host-so" } else { "capi-host" });
    let mut cmd = Command::new("cc");
    cmd.args(["-std=c11", "-O2", "-Wall", "-Wextra", "-Werror"])
        .args(["-ffp-contract=off", "-fno-math-errno", "-I"])
        .arg(capi::include_dir())
        .arg(c.join("host.c"))
        .arg(c.join("episode.c"));
    if shared {
        let so = capi::cdylib();
        let dir = so.parent().unwrap();
        cmd.arg("-L")
            .arg(dir)
            .arg(format!("-Wl,-rpath,{}", dir.display()))
            .arg("-lgman_ffi");
    } else {
        cmd.arg(capi::staticlib(None))
            .args(["-lpthread", "-ldl", "-lm"]);
    }
    capi::run(cmd.arg("-o").arg(&exe));
    exe
}

#[test]
fn c_host_program_matches_the_rust_navigator_bit_for_bit() {
    let blob = blobgen::default_blob_in(&capi::root().join("firmware-example"));
    let model = capi::write_blob(&blob);
    // The static library, then the shared one: the same lines.
    for shared in [false, true] {
        check(&build(shared), &model, &blob, shared);
    }
}

fn check(exe: &std::path::Path, model: &std::path::Path, blob: &[u8], shared: bool) {
    // Without cargo's library path, whose deps/ may hold another build of the shared
    // library: the program loads the one it was linked with (its rpath).
    let out = Command::new(exe)
        .env_remove("LD_LIBRARY_PATH")
        .arg(model)
        .arg(capi::root().join("firmware-example/data/episode.gmep"))
        .output()
        .expect("run the C host program");
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "C host program failed:\n{stdout}{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let got: Vec<&str> = stdout.lines().collect();
    let want = capi::rust_episode_lines(rust_lines, blob);
    assert!(want.iter().any(|l| l.starts_with("  inner update")));
    let what = if shared {
        "C on the host, libgman_ffi.so"
    } else {
        "C on the host, libgman_ffi.a"
    };
    capi::assert_same_lines(&got, &want, what);
}
