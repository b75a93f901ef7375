//! The blob the firmware embeds, shared by `build.rs` and the host-side parity test
//! (`tests/tests/firmware_qemu.rs`) so that both use the very same bytes: a shipped trained
//! model, or a deterministic seeded int8 blob of the same shapes. Without the feature
//! `gaussian-noise` (the default image) the GMAN model trained with G's noise z = 0
//! ([`TRAINED_ZERO`]); with it the one trained with Gaussian noise ([`TRAINED`]). With the
//! firmware's default feature `int8-activations` the blob carries int8 activations and Ψ in
//! int16 (as `gman export --preset mcu --quant int8` writes), without it neither.

use gman_core::blob::seeded::encode_seeded;
use gman_core::blob::{
    encode_model_scratch_len, encoded_model_len_bound, reencode_with_flags, reencoded_len_bound,
    AdaptSettings, Blob, Quant,
};
use gman_core::spec::schema::{
    FLAG_ADAPT, FLAG_COMPACT_PSI, FLAG_INT8_ACTIVATIONS, FLAG_ZERO_NOISE,
};
use gman_core::Dims;

/// An int8 blob (format v2) of seeded N(0, 0.05) weights for every tensor of `dims`, flagged
/// [`FLAG_ADAPT`] with the paper's inner-loop settings ([`AdaptSettings::PAPER`]), so that the
/// firmware's `NavConfig::from_header` runs the GMAN inner loop on it.
pub fn seeded_blob(dims: &Dims, seed: u64) -> Vec<u8> {
    let mut buf = vec![0u8; encoded_model_len_bound(dims, Quant::I8)];
    let (nf, nb) = encode_model_scratch_len(dims);
    let n = encode_seeded(
        dims,
        FLAG_ADAPT,
        AdaptSettings::PAPER,
        Quant::I8,
        seed,
        0.05,
        &mut buf,
        &mut vec![0.0; nf],
        &mut vec![0; nb],
    )
    .expect("encode");
    buf.truncate(n);
    buf
}

/// The shapes the firmware runs: `Mcu` with the 3 x 3 spatial map and 8 channels per cell
/// (the same value as `src/episode.rs`'s `DIMS`, which the parity test checks; a build script
/// cannot include that file).
pub const FIRMWARE_DIMS: Dims = Dims::MCU.with_map(3, 3, 8);

/// The trained GMAN model shipped in the repository, trained with Gaussian noise (relative to
/// `firmware-example/`): the image with the feature `gaussian-noise` embeds it.
pub const TRAINED: &str = "../host-sim/models/gman-thor5-map3-b16-mcu-int8-seed3.gman";

/// The trained GMAN model shipped in the repository, trained with G's noise z = 0 (relative to
/// `firmware-example/`; `results/paper/models/gman-zero-s2.gman`): the default image embeds it.
pub const TRAINED_ZERO: &str = "../host-sim/models/gman-zero-thor5-map3-b16-mcu-int8-seed2.gman";

/// The blob the firmware embeds by default: the shipped trained GMAN map model when it is
/// present, else the seeded one. `base` is the `firmware-example/` directory.
#[allow(dead_code)]
pub fn default_blob_in(base: &std::path::Path) -> Vec<u8> {
    std::fs::read(base.join(TRAINED)).unwrap_or_else(|_| seeded_blob(&FIRMWARE_DIMS, 1))
}

/// `bytes` re-emitted with the header flags `flags` makes of its own: every tensor and the
/// inner-loop settings kept, the CRC recomputed.
fn with_flags(
    bytes: &[u8],
    flags: impl FnOnce(u32) -> u32,
) -> Result<Vec<u8>, gman_core::BlobError> {
    let flags = flags(Blob::parse(bytes)?.header().flags());
    let mut out = vec![0u8; reencoded_len_bound(bytes)];
    let n = reencode_with_flags(bytes, flags, &mut out)?;
    out.truncate(n);
    Ok(out)
}

/// `bytes` re-emitted with [`FLAG_ZERO_NOISE`] (G's noise z = 0 at navigation): every tensor,
/// the other flags and the inner-loop settings kept, the CRC recomputed.
pub fn with_zero_noise(bytes: &[u8]) -> Result<Vec<u8>, gman_core::BlobError> {
    with_flags(bytes, |f| f | FLAG_ZERO_NOISE)
}

/// The blob the firmware embeds for its features: without `gaussian_noise` (the firmware's
/// default) [`TRAINED_ZERO`] (else the seeded blob with zero noise), with it
/// [`default_blob_in`]; with int8 activations and Ψ in int16 when `int8_activations` (the
/// firmware's default feature), with neither otherwise.
#[allow(dead_code)]
pub fn firmware_blob_in(
    base: &std::path::Path,
    int8_activations: bool,
    gaussian_noise: bool,
) -> Result<Vec<u8>, gman_core::BlobError> {
    let blob = if gaussian_noise {
        default_blob_in(base)
    } else {
        match std::fs::read(base.join(TRAINED_ZERO)) {
            Ok(b) => b,
            Err(_) => with_zero_noise(&seeded_blob(&FIRMWARE_DIMS, 1))?,
        }
    };
    let act = FLAG_INT8_ACTIVATIONS | FLAG_COMPACT_PSI;
    with_flags(&blob, |f| if int8_activations { f | act } else { f & !act })
}
