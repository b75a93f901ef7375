//! Building the C API's static library and the C programs for the C tests.

use std::path::PathBuf;
use std::process::Command;

/// The workspace root.
pub fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("..")
}

/// Where the C tests build: a target directory of their own (the outer cargo holds the
/// workspace's while the tests run).
pub fn build_dir() -> PathBuf {
    root().join("target/capi")
}

/// Builds `libgman_ffi.a` (release) for `target` (None: the host) and returns its path.
pub fn staticlib(target: Option<&str>) -> PathBuf {
    library(target, "staticlib", "libgman_ffi.a")
}

/// Builds the host's `libgman_ffi.so` (release) and returns its path.
pub fn cdylib() -> PathBuf {
    library(None, "cdylib", "libgman_ffi.so")
}

fn library(target: Option<&str>, kind: &str, file: &str) -> PathBuf {
    let mut cmd = Command::new(env!("CARGO"));
    cmd.current_dir(root())
        .args(["rustc", "--release", "--quiet", "-p", "gman-ffi", "--lib"])
        .args(["--crate-type", kind, "--target-dir"])
        .arg(build_dir());
    if let Some(t) = target {
        cmd.args(["--target", t, "--no-default-features"]);
    }
    let status = cmd.status().expect("run cargo rustc -p gman-ffi");
    assert!(
        status.success(),
        "cargo rustc -p gman-ffi --crate-type {kind} failed"
    );
    let dir = match target {
        Some(t) => build_dir().join(t).join("release"),
        None => build_dir().join("release"),
    };
    dir.join(file)
}

/// Runs a compiler command, failing with its output.
pub fn run(cmd: &mut Command) {
    let out = cmd
        .output()
        .unwrap_or_else(|e| panic!("run {:?}: {e}", cmd.get_program()));
    assert!(
        out.status.success(),
        "{cmd:?} failed:\n{}{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
}

/// The C sources of the episode runner.
pub fn c_dir() -> PathBuf {
    root().join("firmware-example/c")
}

/// The header's directory.
pub fn include_dir() -> PathBuf {
    root().join("ffi/include")
}

/// The lines the Rust firmware prints for the episode (without its kernel self-test and
/// measurement lines), computed on the host from the same sources the firmware runs.
pub fn rust_episode_lines(
    run_episode: impl FnOnce(&[u8], &[u8]) -> Vec<String>,
    blob: &[u8],
) -> Vec<String> {
    let ep = std::fs::read(root().join("firmware-example/data/episode.gmep")).expect("episode");
    let mut v = run_episode(blob, &ep);
    v.push("OK".into());
    v
}

/// Compares two line lists, naming the first difference.
pub fn assert_same_lines(got: &[&str], want: &[String], what: &str) {
    for (i, (g, w)) in got.iter().zip(want).enumerate() {
        assert_eq!(g, w, "{what}: line {i} differs (C vs Rust)");
    }
    assert_eq!(
        got.len(),
        want.len(),
        "{what}: line counts differ\nC:\n{}",
        got.join("\n")
    );
}

/// The blob the Rust firmware embeds (`firmware-example/blobgen.rs`: the shipped trained
/// model, or the seeded one without it), written to the C tests' build directory.
pub fn write_blob(blob: &[u8]) -> PathBuf {
    std::fs::create_dir_all(build_dir()).unwrap();
    let p = build_dir().join("model.gman");
    std::fs::write(&p, blob).unwrap();
    p
}
