//! Weight blobs: the versioned, checksummed `postcard` container the core loads weights from.
//!
//! # Layout (format version 2; v3 inserts `map` after `dims`; v4 is v3 with a checksum over the
//! whole blob; v5 replaces the flags and rates by named settings, see "Versions")
//! ```text
//! blob    = header payload
//! header  = postcard(HeaderV2)        in this order:
//!             magic        [u8; 4]      "GMAN" (4 raw bytes)
//!             version      u16 varint   2 (3)
//!             dims         8 x u32 varint  attr noise gen_hidden feat disc_hidden
//!                                          lstm_hidden embed ps
//!            (map          3 x u32 varint  map_rows map_cols cell_embed       v3 only)
//!             flags        u32 varint   FLAG_ADAPT | FLAG_ZERO_NOISE | FLAG_COSSIM
//!                                       | FLAG_FULL_ADAPT
//!             alpha_disc   f32 (4 bytes, little-endian)  α1, D's ascent rate
//!             alpha_adapt  f32 (4 bytes, little-endian)  α2, θ/φ's descent rate
//!             max_inner    u32 varint   cap on inner updates per episode
//!             n_tensors    u16 varint
//!             payload_len  u32 varint   bytes after the header
//!             payload_crc  u32 varint   CRC-32 (IEEE) of the payload; always the last field
//!                                       (v4: of every header byte before it, then the
//!                                       payload)
//! payload = postcard(Tensor) * count  id, rows, cols, quantisation, data bytes, scale bytes
//! ```
//! Tensor data are little-endian f32 (`quant = 0`, `4 * rows * cols` bytes, no scales) or int8
//! (`quant = 1`, `rows * cols` bytes read as `i8`, plus `rows` little-endian f32 scales).
//! Vectors (biases) are f32 with `cols = 1`.
//!
//! # Versions
//! * **v5** (what the encoders write) names its settings. After `magic`, `version`, `dims`
//!   and `map` (as v4) comes the settings section, then `n_tensors`, `payload_len` and the
//!   CRC-32 of every header byte before it followed by the payload (as v4):
//!   ```text
//!   settings    u32 varint   bytes of the records that follow
//!   setting     key    str (varint length + ASCII)   one of spec::SETTING_KEYS
//!               value  u32 varint tag + payload      0 u32 (varint) | 1 f32 (4 bytes LE)
//!                                                    | 2 name (varint length + ASCII)
//!                                                    | 3 bool (1 byte: 0 or 1)
//!   ```
//!   The one encoder ([`Encoder`]) writes, in [`SETTING_KEYS`] order, every setting of
//!   the carrier, [`ModelSpec`], whose value departs from
//!   [`ModelSpec::BLOB_DEFAULT`] (the paper's rule and rates, Efficient mode, no
//!   adaptation; `disc_lr` only when α1 is not α2), e.g. `commit_delay = U32(3)`,
//!   `step_rule = Name("per-group")`; a key a record does not name keeps its default.
//!   So a newer build's setting left at its default does not stop an older reader, and
//!   one in use does. After the
//!   checksum, the parser refuses, naming the key: a key this build does not know
//!   ([`BlobError::UnknownSetting`]: a setting of a newer build is never run as if it were
//!   off), a value of another type ([`BlobError::SettingType`]), a name none of the
//!   setting's values has ([`BlobError::UnknownSettingValue`]), a key given twice
//!   ([`BlobError::DuplicateSetting`]) and a value out of its range
//!   ([`BlobError::SettingOutOfRange`], [`BlobError::BadInnerRate`]); an unknown value
//!   type is [`BlobError::Malformed`]. [`Header::flags`] of a v5 blob is the v4 flag word
//!   of the same settings, [`Header::spec`] the settings themselves.
//! * **v4** (what the encoders wrote before v5) has the v3 header, but its last field is the CRC-32
//!   of the whole blob without that field: the header's bytes before it (magic, version,
//!   dims, map, flags, rates, cap, counts) followed by the payload. In v1-v3 the CRC covered
//!   the payload only, so a changed flag, rate or map size went unnoticed; in v4 every byte
//!   the device interprets is covered, and a v4 blob with any header bit flipped is refused
//!   ([`BlobError::HeaderChecksumMismatch`], or a decoding error). Older blobs are still
//!   read and verified by their own rule ([`Header::checksum_scope`] says which one).
//! * **v3** (what the encoders wrote for a model with a spatial observation map) adds the
//!   map's dims (`map_rows`, `map_cols`, `cell_embed`) after `dims`, and the per-cell layer's
//!   tensors [`TensorId::CellW`] and [`TensorId::CellB`]. A v1/v2 blob has no map and may not
//!   carry the per-cell tensors.
//! * **v2** (what the encoders wrote for a model without a map) adds
//!   the inner-loop settings of Algorithm 1 the model was trained with, `alpha_disc`,
//!   `alpha_adapt` and `max_inner` (see [`AdaptSettings`]), between `flags` and `n_tensors`.
//!   A model meta-trained with other rates or another cap than the paper's would silently
//!   run on the device with different settings if the blob did not carry them.
//! * **v1** has the same header without those three fields. It is still read; its settings
//!   are the paper's ([`AdaptSettings::PAPER`]: α1 = α2 = 1e-4, at most 4 inner updates per
//!   episode, i.e. the values of [`NavConfig::default`](crate::navigator::NavConfig)), which
//!   is what every v1 blob was trained and run with.
//!
//! Any other version is [`BlobError::UnsupportedVersion`]. postcard is sequential and has no
//! field tags, so the parser first decodes the `{magic, version}` prefix, then the header
//! struct of that version.
//!
//! [`NavConfig::from_header`](crate::navigator::NavConfig::from_header) (or
//! [`Blob::nav_config`]) turns the flags and the settings into the navigator configuration
//! the blob asks for, so that the host and the device run the same inner loop.
//!
//! # Zero copy
//! [`Blob::parse`] borrows from the input (`&'a [u8]`, e.g. a `&'static` blob in flash): each
//! tensor's bytes are a sub-slice of the blob and [`Blob::matrix`] hands them to the kernels
//! in place (int8 and f32 alike, through [`crate::nn::matrix::Weights::I8`] and
//! [`crate::nn::matrix::Weights::F32Le`]). Only what must be mutable (adapted parameters, biases)
//! is ever copied to RAM, by the caller, with [`Blob::copy_f32`].
//!
//! # Validation
//! Parsing checks, in order: decoding of the `{magic, version}` prefix, magic, version,
//! decoding of that version's header, (v4: payload length and the CRC-32 over header and
//! payload,) the inner-loop rates (v2 and later: finite, non-negative and at most
//! [`MAX_INNER_RATE`], else [`BlobError::BadInnerRate`]), the dims (no zero width and a
//! consistent map, else [`BlobError::DegenerateDims`], see [`Dims::degenerate_field`]; every
//! size derived from them, parameter counts, tensor bytes, RAM layout, must fit in `usize`,
//! else [`BlobError::DimsTooLarge`]; see [`Dims::checked_sizes`]), (v1-v3:) payload length,
//! CRC-32 of the payload, then every record (known id, no
//! duplicates, shape implied by the dims, byte lengths, allowed quantisation, finite f32
//! weights, finite non-negative scales). Any failure is a typed [`BlobError`]; nothing panics,
//! whatever the bytes (a property test and a fuzz target check this).

pub mod crc32;
mod encode;
mod format;
mod header;
pub mod quant;
pub mod seeded;
mod view;

pub use crate::spec::preset::MAX_INNER_RATE;
pub use crate::spec::schema::{
    TensorId, FLAG_ADAPT, FLAG_COSSIM, FLAG_FULL_ADAPT, FLAG_ZERO_NOISE, NUM_TENSORS,
};
pub use crate::spec::AdaptSettings;
pub use encode::*;
pub use format::*;
pub use header::*;
pub use view::*;

// Named by the module's documentation.
#[cfg(doc)]
use crate::error::BlobError;
#[cfg(doc)]
use crate::spec::{preset::Dims, ModelSpec, SETTING_KEYS};
