//! Writes the weight blob the firmware embeds.
//!
//! If `GMAN_FIRMWARE_BLOB` names a file (e.g. one written by `gman export`), that blob is
//! embedded; otherwise a deterministic `Mcu`-preset int8 blob is made here from seeded random
//! weights with gman-core's own encoder, so a fresh clone builds with no artefacts checked in.

use gman_core::Dims;
use std::{env, fs, path::PathBuf};

#[path = "blobgen.rs"]
mod blobgen;

fn main() {
    println!("cargo:rerun-if-changed=memory.x");
    println!("cargo:rerun-if-changed=blobgen.rs");
    println!("cargo:rerun-if-env-changed=GMAN_FIRMWARE_BLOB");
    let out = PathBuf::from(env::var_os("OUT_DIR").expect("OUT_DIR"));
    fs::copy("memory.x", out.join("memory.x")).expect("copy memory.x");
    println!("cargo:rustc-link-search={}", out.display());

    let blob = match env::var_os("GMAN_FIRMWARE_BLOB") {
        Some(p) => {
            println!("cargo:rerun-if-changed={}", PathBuf::from(&p).display());
            fs::read(&p).unwrap_or_else(|e| panic!("GMAN_FIRMWARE_BLOB={p:?}: {e}"))
        }
        None => blobgen::seeded_blob(&Dims::MCU, 1),
    };
    fs::write(out.join("model.gman"), blob).expect("write blob");
}
