//! Host-side optimisation plumbing shared by every training stage: parameter store,
//! optimiser, checkpoints and deterministic data-parallel gradient accumulation.
//!
//! Module map:
//! * [`params`]: named f32 tensors ([`params::ParamSet`]) and views for the core kernels.
//! * [`adam`]: Adam / AMSGrad with clipping and a checkpointable state.
//! * [`checkpoint`]: versioned, checksummed, atomically written checkpoint files.
//! * [`parallel`]: fixed-chunk, order-deterministic gradient accumulation on rayon.
//!
//! The pre-training stages live in [`crate::pretrain`], the navigation trainer (`gman
//! train`) in [`crate::train`].

pub mod adam;
pub mod checkpoint;
pub mod parallel;
pub mod params;

use anyhow::{bail, Result};
use gman_core::rng::Xoshiro128;
use gman_core::Dims;

/// The preset sizes as JSON (for checkpoint metadata and reports).
pub(crate) fn dims_json(d: &Dims) -> serde_json::Value {
    let mut v = serde_json::json!({
        "attr": d.attr,
        "noise": d.noise,
        "gen_hidden": d.gen_hidden,
        "feat": d.feat,
        "disc_hidden": d.disc_hidden,
        "lstm_hidden": d.lstm_hidden,
        "embed": d.embed,
        "ps": d.ps,
    });
    // Written only for models with a spatial map, so earlier checkpoints stay byte for byte.
    if d.map_rows + d.map_cols + d.cell_embed > 0 {
        v["map_rows"] = d.map_rows.into();
        v["map_cols"] = d.map_cols.into();
        v["cell_embed"] = d.cell_embed.into();
    }
    v
}

/// The 16-byte state of a [`Xoshiro128`] (little-endian words), for a checkpoint blob.
pub(crate) fn rng_to_bytes(rng: &Xoshiro128) -> [u8; 16] {
    let mut out = [0u8; 16];
    for (o, w) in out.chunks_exact_mut(4).zip(rng.state()) {
        o.copy_from_slice(&w.to_le_bytes());
    }
    out
}

/// Restores a [`Xoshiro128`] from [`rng_to_bytes`].
pub(crate) fn rng_from_bytes(b: &[u8]) -> Result<Xoshiro128> {
    if b.len() != 16 {
        bail!("RNG state has {} bytes, expected 16", b.len());
    }
    let mut s = [0u32; 4];
    for (w, c) in s.iter_mut().zip(b.chunks_exact(4)) {
        *w = u32::from_le_bytes([c[0], c[1], c[2], c[3]]);
    }
    Ok(Xoshiro128::from_state(s))
}
