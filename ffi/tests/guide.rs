//! The C blocks of the integration guide (`docs/integrate.md`) compile against `gman.h`
//! (C99 and C11, warnings as errors); its Rust blocks are doc tests of this crate.

use std::path::PathBuf;
use std::process::Command;

fn c_blocks(md: &str) -> Vec<String> {
    let mut out = Vec::new();
    let mut cur: Option<String> = None;
    for line in md.lines() {
        match (&mut cur, line.trim_end()) {
            (None, "```c") => cur = Some(String::new()),
            (Some(_), "```") => out.extend(cur.take()),
            (Some(b), l) => {
                b.push_str(l);
                b.push('\n');
            }
            _ => {}
        }
    }
    out
}

#[test]
fn guide_c_blocks_compile() {
    let dir = PathBuf::from(env!("CARGO_MANIFEST_DIR"));
    let md = std::fs::read_to_string(dir.join("../docs/integrate.md")).expect("guide");
    let blocks = c_blocks(&md);
    assert!(blocks.len() >= 2, "the guide has {} C blocks", blocks.len());
    let tmp = std::env::temp_dir().join(format!("gman-guide-{}", std::process::id()));
    std::fs::create_dir_all(&tmp).unwrap();
    for (i, b) in blocks.iter().enumerate() {
        let f = tmp.join(format!("block{i}.c"));
        std::fs::write(&f, b).unwrap();
        for std in ["c99", "c11"] {
            let out = Command::new("cc")
                .args([
                    &format!("-std={std}"),
                    "-Wall",
                    "-Wextra",
                    "-Werror",
                    "-pedantic",
                ])
                .args(["-Wno-unused-function", "-c", "-o"])
                .arg(tmp.join(format!("block{i}.o")))
                .arg("-I")
                .arg(dir.join("include"))
                .arg(&f)
                .output()
                .expect("run cc");
            assert!(
                out.status.success(),
                "C block {i} of docs/integrate.md does not compile ({std}):\n{b}\n{}",
                String::from_utf8_lossy(&out.stderr)
            );
        }
    }
}
