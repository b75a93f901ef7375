//! Writes the weight blob the firmware embeds.
//!
//! In order of preference: the file named by `GMAN_FIRMWARE_BLOB` (e.g. one written by
//! `gman export`); a trained GMAN model shipped in the repository: without the feature
//! `gaussian-noise` (the default image) the one trained with G's noise z = 0
//! (`host-sim/models/gman-zero-thor5-map3-b16-mcu-int8-seed2.gman`, `blobgen::TRAINED_ZERO`),
//! with it the one trained with Gaussian noise
//! (`host-sim/models/gman-thor5-map3-b16-mcu-int8-seed3.gman`, `blobgen::TRAINED`); otherwise a
//! deterministic int8 blob of the same shapes (`Mcu` with the 3 x 3 map) made here from seeded
//! random weights with gman-core's own encoder. With the feature `int8-activations` (the
//! default) the blob carries int8 activations and Ψ in int16, without it neither
//! (`blobgen::firmware_blob_in`).

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
            println!("cargo:rerun-if-changed={}", blobgen::TRAINED_ZERO);
            // The default feature `int8-activations` runs the integer path: the shipped model
            // with int8 activations (its tensors unchanged).
            let int8 = env::var_os("CARGO_FEATURE_INT8_ACTIVATIONS").is_some();
            // Without the feature `gaussian-noise` (the default image), with G's noise z = 0.
            let gaussian = env::var_os("CARGO_FEATURE_GAUSSIAN_NOISE").is_some();
            blobgen::firmware_blob_in(std::path::Path::new("."), int8, gaussian)
                .unwrap_or_else(|e| panic!("the shipped model: {e}"))
        }
    };
    fs::write(out.join("model.gman"), blob).expect("write blob");
}
