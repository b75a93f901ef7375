//! `include/gman.h` is what cbindgen generates from `src/lib.rs`: this test regenerates it
//! and fails on any difference (`GMAN_BLESS=1` rewrites the file instead). It also compiles
//! the header as C99, C11, C++11 and C++17 with the system's `cc` / `c++`.

use std::path::{Path, PathBuf};
use std::process::Command;

fn crate_dir() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

fn generate() -> String {
    let dir = crate_dir();
    let config = cbindgen::Config::from_file(dir.join("cbindgen.toml")).expect("cbindgen.toml");
    let mut out = Vec::new();
    cbindgen::Builder::new()
        .with_crate(&dir)
        .with_config(config)
        .generate()
        .expect("cbindgen")
        .write(&mut out);
    String::from_utf8(out).expect("utf-8 header")
}

#[test]
fn header_matches_the_source() {
    let path = crate_dir().join("include/gman.h");
    let fresh = generate();
    if std::env::var("GMAN_BLESS").as_deref() == Ok("1") {
        std::fs::write(&path, &fresh).expect("write gman.h");
        return;
    }
    let committed = std::fs::read_to_string(&path).unwrap_or_default();
    assert!(
        committed == fresh,
        "{} is out of date with src/lib.rs: run `GMAN_BLESS=1 cargo test -p gman-ffi --test header` and commit it",
        path.display()
    );
}

fn compiles(compiler: &str, std: &str, lang: &str, header: &Path) {
    let src = format!(
        "#include \"{}\"\nint main(void) {{ gman_info i; (void)i; return (int)gman_api_version() - GMAN_API_VERSION; }}\n",
        header.display()
    );
    let dir = std::env::temp_dir().join(format!("gman-h-{}-{std}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let file = dir.join(if lang == "c" { "t.c" } else { "t.cpp" });
    std::fs::write(&file, src).unwrap();
    let out = Command::new(compiler)
        .args([
            &format!("-std={std}"),
            "-Wall",
            "-Wextra",
            "-Werror",
            "-pedantic",
            "-fsyntax-only",
        ])
        .arg(&file)
        .output()
        .unwrap_or_else(|e| panic!("run {compiler}: {e}"));
    assert!(
        out.status.success(),
        "gman.h does not compile with {compiler} -std={std}:\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
}

#[test]
fn header_compiles_as_c_and_cpp() {
    let h = crate_dir().join("include/gman.h");
    for std in ["c99", "c11"] {
        compiles("cc", std, "c", &h);
    }
    for std in ["c++11", "c++17"] {
        compiles("c++", std, "c++", &h);
    }
}
