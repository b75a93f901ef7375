//! Deterministic seeded `Mcu` int8 blob, shared by `build.rs` and the host-side parity test
//! (`tests/tests/firmware_qemu.rs`) so that both use the very same bytes.

use gman_core::blob::{
    encode_with_settings, encoded_len_bound, AdaptSettings, TensorData, TensorId, TensorSpec,
    FLAG_ADAPT,
};
use gman_core::quant::quantize_rows;
use gman_core::rng::{fill_gaussian, Xoshiro128};
use gman_core::Dims;

/// An int8 blob (format v2) of seeded N(0, 0.05) weights for every tensor of `dims`, flagged
/// [`FLAG_ADAPT`] with the paper's inner-loop settings ([`AdaptSettings::PAPER`]), so that the
/// firmware's `NavConfig::from_header` runs the GMAN inner loop on it.
pub fn seeded_blob(dims: &Dims, seed: u64) -> Vec<u8> {
    let mut rng = Xoshiro128::seed_from_u64(seed);
    // (id, f32 values, int8 values, row scales)
    type Stored = (TensorId, Vec<f32>, Vec<u8>, Vec<f32>);
    let mut store: Vec<Stored> = Vec::new();
    for id in TensorId::all_for(dims) {
        let (r, c) = id.shape(dims);
        let mut v = vec![0.0f32; r * c];
        fill_gaussian(&mut rng, &mut v);
        v.iter_mut().for_each(|x| *x *= 0.05);
        let (mut q, mut s) = (vec![0u8; r * c], vec![0.0f32; r]);
        if !id.is_vector() {
            quantize_rows(&v, r, c, &mut q, &mut s).expect("quantize");
        }
        store.push((id, v, q, s));
    }
    let specs: Vec<TensorSpec<'_>> = store
        .iter()
        .map(|(id, v, q, s)| TensorSpec {
            id: *id,
            data: if id.is_vector() {
                TensorData::F32(v)
            } else {
                TensorData::I8 { q, scales: s }
            },
        })
        .collect();
    let mut buf = vec![0u8; encoded_len_bound(&specs)];
    let n = encode_with_settings(dims, FLAG_ADAPT, AdaptSettings::PAPER, &specs, &mut buf)
        .expect("encode");
    buf.truncate(n);
    buf
}

/// The trained GMAN model shipped in the repository (relative to `firmware-example/`).
pub const TRAINED: &str = "../host-sim/models/gman-mcu-int8-seed1.gman";

/// The blob the firmware embeds by default: the shipped trained GMAN model when it is
/// present, else the seeded one. `base` is the `firmware-example/` directory.
#[allow(dead_code)]
pub fn default_blob_in(base: &std::path::Path) -> Vec<u8> {
    std::fs::read(base.join(TRAINED)).unwrap_or_else(|_| seeded_blob(&Dims::MCU, 1))
}

/// [`default_blob_in`] from the current directory (a build script runs in `firmware-example/`).
#[allow(dead_code)]
pub fn default_blob() -> Vec<u8> {
    default_blob_in(std::path::Path::new("."))
}
