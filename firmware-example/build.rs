//! Writes the weight blob the firmware embeds.
//!
//! In order of preference: the file named by `GMAN_FIRMWARE_BLOB` (e.g. one written by
//! `gman export`); the trained GMAN model shipped in the repository
//! (`host-sim/models/gman-thor5-map3-b16-mcu-int8-seed3.gman`, see `blobgen::TRAINED`); otherwise a
//! deterministic int8 blob of the same shapes (`Mcu` with the 3 x 3 map) made here from seeded
//! random weights with gman-core's
//! own encoder. With the feature `int8-activations` (the default) the shipped or seeded blob
//! is re-emitted with int8 activations (`blobgen::with_int8_activations`), and without the
//! feature `gaussian-noise` (the default image) with G's noise z = 0
//! (`blobgen::with_zero_noise`).

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
        None => {
            println!("cargo:rerun-if-changed={}", blobgen::TRAINED);
            // The default feature `int8-activations` runs the integer path: the shipped model
            // re-emitted with int8 activations (its tensors unchanged).
            let int8 = env::var_os("CARGO_FEATURE_INT8_ACTIVATIONS").is_some();
            // Without the feature `gaussian-noise` (the default image), with G's noise z = 0.
            let gaussian = env::var_os("CARGO_FEATURE_GAUSSIAN_NOISE").is_some();
            blobgen::firmware_blob_in(std::path::Path::new("."), int8, gaussian)
                .unwrap_or_else(|e| panic!("{}: {e}", blobgen::TRAINED))
        }
    };
    fs::write(out.join("model.gman"), blob).expect("write blob");
}
