//! Seeded models for benchmarks, profiling and tests: gman-core's seeded weights
//! ([`gman_core::blob::seeded`], the one seeded-weights builder) as an int8 blob in a `Vec`.

use anyhow::{anyhow, Result};
use gman_core::blob::{encode_model_scratch_len, encoded_model_len_bound, AdaptSettings, Quant};
use gman_core::Dims;

/// The int8 blob of gman-core's seeded weights for `dims` (N(0, `scale`²) from `seed`, no
/// model flags, the paper's inner-loop settings).
pub fn int8_blob(dims: &Dims, seed: u64, scale: f32) -> Result<Vec<u8>> {
    let mut buf = vec![0u8; encoded_model_len_bound(dims, Quant::I8)];
    let (nf, nb) = encode_model_scratch_len(dims);
    let n = gman_core::blob::seeded::encode_seeded(
        dims,
        0,
        AdaptSettings::PAPER,
        Quant::I8,
        seed,
        scale,
        &mut buf,
        &mut vec![0.0; nf],
        &mut vec![0; nb],
    )
    .map_err(|e| anyhow!("encoding the seeded blob: {e:?}"))?;
    buf.truncate(n);
    Ok(buf)
}
