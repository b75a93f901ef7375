//! Seeded weights: reproducible N(0, scale²) values for every tensor of a model, for tests,
//! benches, the firmware's parity blob and `gman bench` (a firmware embeds a trained blob).
//!
//! The values are drawn in storage order ([`TensorId::all_for`]) from one
//! [`Xoshiro128`] seeded with `seed`, each tensor filled with [`fill_gaussian`] and scaled;
//! [`encode_seeded`] writes them as a blob through [`encode_model`], the one
//! weights-to-blob builder.

use crate::blob::{encode_model, AdaptSettings, Quant};
use crate::error::BlobError;
use crate::rng::{fill_gaussian, Xoshiro128};
use crate::spec::preset::Dims;
use crate::spec::schema::TensorId;
use crate::spec::ModelSpec;

/// The stream of seeded weights: call [`SeededWeights::fill`] once per tensor, in storage
/// order.
#[derive(Clone, Debug)]
pub struct SeededWeights {
    rng: Xoshiro128,
    scale: f32,
}

impl SeededWeights {
    /// A stream seeded with `seed` whose values are N(0, 1) times `scale`.
    pub fn new(seed: u64, scale: f32) -> Self {
        SeededWeights {
            rng: Xoshiro128::seed_from_u64(seed),
            scale,
        }
    }

    /// Fills `out` with the next tensor's values.
    pub fn fill(&mut self, out: &mut [f32]) {
        fill_gaussian(&mut self.rng, out);
        out.iter_mut().for_each(|x| *x *= self.scale);
    }
}

/// Encodes a blob of seeded weights ([`SeededWeights::new`]`(seed, scale)`) for every tensor
/// of `dims` with the settings a v1-v4 header's model `flags` and inner-loop `settings`
/// stand for ([`ModelSpec::from_bits`]; unknown flag bits and bad rates are refused),
/// matrices in `quant`; see [`encode_model`] for `out`, `floats` and `bytes`.
#[allow(clippy::too_many_arguments)]
pub fn encode_seeded(
    dims: &Dims,
    flags: u32,
    settings: AdaptSettings,
    quant: Quant,
    seed: u64,
    scale: f32,
    out: &mut [u8],
    floats: &mut [f32],
    bytes: &mut [u8],
) -> Result<usize, BlobError> {
    settings.validate()?;
    crate::spec::schema::check_known_flags(flags)?;
    let mut w = SeededWeights::new(seed, scale);
    encode_model(
        dims,
        &ModelSpec::from_bits(flags, settings),
        quant,
        |_: TensorId, v: &mut [f32]| {
            w.fill(v);
            Ok::<(), BlobError>(())
        },
        out,
        floats,
        bytes,
    )
}
