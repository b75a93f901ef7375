//! The C API on the host: a C program (`firmware-example/c/host.c` + `episode.c`, built with
//! the system's `cc` against `libgman_ffi.a`) loads the shipped blob, replays the recorded
//! episode through the C API in two navigators (two arenas, both misaligned on purpose) and
//! must print bit for bit the lines the Rust navigator prints for it
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
    episode::run(blob, &mut episode::Bytes(ep), &mut arena, &mut out).expect("Rust episode");
    out.0
}

#[test]
fn c_host_program_matches_the_rust_navigator_bit_for_bit() {
    let lib = capi::staticlib(None);
    let exe = capi::build_dir().join("capi-host");
    let c = capi::c_dir();
    capi::run(
        Command::new("cc")
            .args(["-std=c11", "-O2", "-Wall", "-Wextra", "-Werror"])
            .args(["-ffp-contract=off", "-fno-math-errno", "-I"])
            .arg(capi::include_dir())
            .arg(c.join("host.c"))
            .arg(c.join("episode.c"))
            .arg(&lib)
            .args(["-lpthread", "-ldl", "-lm", "-o"])
            .arg(&exe),
    );
    let blob = blobgen::default_blob_in(&capi::root().join("firmware-example"));
    let model = capi::write_blob(&blob);
    let out = Command::new(&exe)
        .arg(&model)
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
    let want = capi::rust_episode_lines(rust_lines, &blob);
    assert!(want.iter().any(|l| l.starts_with("  inner update")));
    capi::assert_same_lines(&got, &want, "C on the host");
}
