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
pub mod quant;
pub mod seeded;

use serde::ser::SerializeSeq;
use serde::{Deserialize, Serialize, Serializer};

use crate::blob::crc32::{crc32, crc32_update};
use crate::error::BlobError;
use crate::error::SettingText;
use crate::nn::matrix::{MatRef, Scales};
use crate::spec::preset::Dims;
use crate::spec::schema::AdaptMode;
pub use crate::spec::schema::{
    TensorId, FLAG_ADAPT, FLAG_COSSIM, FLAG_FULL_ADAPT, FLAG_ZERO_NOISE, NUM_TENSORS,
};
pub use crate::spec::AdaptSettings;
use crate::spec::SpecError;
use crate::spec::SETTING_KEYS;
use crate::spec::{apply_setting, name_index, ModelSpec, SettingError, SettingKey, SettingValue};

/// The four magic bytes at the start of every blob.
pub const MAGIC: [u8; 4] = *b"GMAN";
/// The format version this build writes (v5: the header names its settings, the CRC covers
/// the header and the payload).
pub const FORMAT_VERSION: u16 = 5;
pub use crate::spec::preset::MAX_INNER_RATE;
/// The oldest format version this build still reads (v1: no inner-loop settings in the
/// header; they default to [`AdaptSettings::PAPER`]).
pub const MIN_FORMAT_VERSION: u16 = 1;
/// Bytes reserved for the header while encoding (the real header is shorter: at most 98
/// bytes for v3, about 410 for v5 with every setting at its longest).
const HEADER_RESERVE: usize = 512;

/// Quantisation of a stored tensor.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Quant {
    /// Little-endian f32.
    F32,
    /// int8 with one f32 scale per row.
    I8,
}

impl Quant {
    fn code(self) -> u8 {
        match self {
            Quant::F32 => 0,
            Quant::I8 => 1,
        }
    }
}

#[derive(Serialize, Deserialize, Clone, Copy, Debug, PartialEq, Eq)]
struct DimsRecord {
    attr: u32,
    noise: u32,
    gen_hidden: u32,
    feat: u32,
    disc_hidden: u32,
    lstm_hidden: u32,
    embed: u32,
    ps: u32,
}

impl DimsRecord {
    fn from_dims(d: &Dims) -> Self {
        let c = |v: usize| u32::try_from(v).unwrap_or(u32::MAX);
        DimsRecord {
            attr: c(d.attr),
            noise: c(d.noise),
            gen_hidden: c(d.gen_hidden),
            feat: c(d.feat),
            disc_hidden: c(d.disc_hidden),
            lstm_hidden: c(d.lstm_hidden),
            embed: c(d.embed),
            ps: c(d.ps),
        }
    }

    fn to_dims(self, map: MapRecord) -> Dims {
        Dims {
            attr: self.attr as usize,
            noise: self.noise as usize,
            gen_hidden: self.gen_hidden as usize,
            feat: self.feat as usize,
            disc_hidden: self.disc_hidden as usize,
            lstm_hidden: self.lstm_hidden as usize,
            embed: self.embed as usize,
            ps: self.ps as usize,
            map_rows: map.map_rows as usize,
            map_cols: map.map_cols as usize,
            cell_embed: map.cell_embed as usize,
        }
    }
}

/// The spatial-map dims of a v3 header (all 0 in v1/v2 blobs: no map).
#[derive(Serialize, Deserialize, Clone, Copy, Debug, PartialEq, Eq, Default)]
struct MapRecord {
    map_rows: u32,
    map_cols: u32,
    cell_embed: u32,
}

impl MapRecord {
    fn from_dims(d: &Dims) -> Self {
        let c = |v: usize| u32::try_from(v).unwrap_or(u32::MAX);
        MapRecord {
            map_rows: c(d.map_rows),
            map_cols: c(d.map_cols),
            cell_embed: c(d.cell_embed),
        }
    }
}

/// The `{magic, version}` prefix every header version starts with, decoded first to choose
/// the header struct.
#[derive(Deserialize)]
struct Prefix {
    magic: [u8; 4],
    version: u16,
}

/// The header of a format-v1 blob (read only; postcard has no field names, so the
/// underscored fields are decoded like any other and only checked through [`Prefix`]).
#[derive(Deserialize)]
#[cfg_attr(not(feature = "legacy-blobs"), allow(dead_code))]
struct HeaderV1 {
    _magic: [u8; 4],
    _version: u16,
    dims: DimsRecord,
    flags: u32,
    n_tensors: u16,
    payload_len: u32,
    payload_crc: u32,
}

/// The header of a format-v3 blob: v2 with the spatial-map dims after `dims`.
#[derive(Serialize, Deserialize)]
#[cfg_attr(not(feature = "legacy-blobs"), allow(dead_code))]
struct HeaderV3 {
    magic: [u8; 4],
    version: u16,
    dims: DimsRecord,
    map: MapRecord,
    flags: u32,
    settings: AdaptSettings,
    n_tensors: u16,
    payload_len: u32,
    payload_crc: u32,
}

/// The header of a format-v4 blob without its last field, the checksum (a varint after
/// these fields): CRC-32 of these bytes followed by the payload.
#[derive(Serialize, Deserialize)]
#[cfg_attr(not(feature = "legacy-blobs"), allow(dead_code))]
struct HeaderV4Body {
    magic: [u8; 4],
    version: u16,
    dims: DimsRecord,
    map: MapRecord,
    flags: u32,
    settings: AdaptSettings,
    n_tensors: u16,
    payload_len: u32,
}

#[cfg_attr(not(feature = "legacy-blobs"), allow(dead_code))]
impl HeaderV4Body {
    fn with_crc(self, payload_crc: u32) -> HeaderV3 {
        HeaderV3 {
            magic: self.magic,
            version: self.version,
            dims: self.dims,
            map: self.map,
            flags: self.flags,
            settings: self.settings,
            n_tensors: self.n_tensors,
            payload_len: self.payload_len,
            payload_crc,
        }
    }
}

/// The header of a format-v5 blob without its last field, the checksum (as v4): v4's
/// fields with the flags and the inner-loop settings replaced by the settings section, the
/// setting records as one byte string.
#[derive(Deserialize)]
struct HeaderV5Body<'a> {
    _magic: [u8; 4],
    _version: u16,
    dims: DimsRecord,
    map: MapRecord,
    settings: &'a [u8],
    n_tensors: u16,
    payload_len: u32,
}

/// [`HeaderV5Body`] as the encoder writes it.
#[derive(Serialize)]
struct HeaderV5Out<'a> {
    magic: [u8; 4],
    version: u16,
    dims: DimsRecord,
    map: MapRecord,
    settings: RawBytes<'a>,
    n_tensors: u16,
    payload_len: u32,
}

/// One setting of a format-v5 header as the encoder writes it: its key
/// ([`SETTING_KEYS`]) and its typed value (read back by [`take_setting`]).
#[derive(Serialize)]
struct SettingRecord<'a> {
    key: &'a str,
    value: SettingValue<'a>,
}

/// Decodes one setting record (postcard's form of [`SettingRecord`], read by hand so that
/// the parser stays small on a device) from the front of `bytes`: the key's bytes, the
/// value's type tag, the value as a `u32` (a varint, 4 bytes little-endian, or 1 byte 0
/// or 1; 0 for a name), the name's bytes (empty for the other types), the bytes after it.
/// `None` for a record that is not well formed.
fn take_setting(bytes: &[u8]) -> Option<(RawSetting<'_>, &[u8])> {
    let (key, rest) = take_bytes(bytes)?;
    let (tag, rest) = take_varint(rest)?;
    let (raw, name, rest) = match (tag, rest) {
        (0, _) => take_varint(rest).map(|(v, r)| (v, &[][..], r))?,
        (1, [a, b, c, d, r @ ..]) => (u32::from_le_bytes([*a, *b, *c, *d]), &[][..], r),
        (2, _) => take_bytes(rest).map(|(n, r)| (0, n, r))?,
        (3, [b @ (0 | 1), r @ ..]) => (u32::from(*b), &[][..], r),
        _ => return None,
    };
    Some((
        RawSetting {
            key,
            tag,
            raw,
            name,
        },
        rest,
    ))
}

/// A setting record as [`take_setting`] decodes it.
struct RawSetting<'a> {
    key: &'a [u8],
    tag: u32,
    raw: u32,
    name: &'a [u8],
}

/// A postcard `u32` varint and the rest (postcard's own decoder, which the checksum's
/// field needs anyway).
fn take_varint(b: &[u8]) -> Option<(u32, &[u8])> {
    postcard::take_from_bytes::<u32>(b).ok()
}

/// A postcard byte string (varint length, then the bytes) and the rest.
fn take_bytes(b: &[u8]) -> Option<(&[u8], &[u8])> {
    let (n, rest) = take_varint(b)?;
    (rest.len() >= n as usize).then(|| rest.split_at(n as usize))
}

/// What a blob's CRC-32 covers, by format version.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ChecksumScope {
    /// v1-v3: the payload (tensor records) only; the header is not covered.
    Payload,
    /// v4 and v5: every header byte before the checksum, then the payload: the whole blob.
    HeaderAndPayload,
}

impl ChecksumScope {
    /// A short description (`"header and payload"`, `"payload only"`), e.g. for `inspect`.
    pub fn describe(self) -> &'static str {
        match self {
            ChecksumScope::Payload => "payload only (format v1-v3 rule)",
            ChecksumScope::HeaderAndPayload => "header and payload (format v4-v5 rule)",
        }
    }
}

#[cfg_attr(not(feature = "legacy-blobs"), allow(dead_code))]
impl HeaderV3 {
    /// The checked [`Header`] (inner-loop rates first, then the sizes the dims imply).
    fn into_header(self, version: u16) -> Result<Header, BlobError> {
        let settings = self.settings;
        settings.validate()?;
        check_dims_fit(&self.dims, self.map)?;
        Ok(Header {
            version,
            scope: if version >= 4 {
                ChecksumScope::HeaderAndPayload
            } else {
                ChecksumScope::Payload
            },
            dims: self.dims,
            map: self.map,
            flags: self.flags,
            settings,
            n_tensors: self.n_tensors,
            payload_len: self.payload_len,
            payload_crc: self.payload_crc,
        })
    }
}

#[cfg_attr(not(feature = "legacy-blobs"), allow(dead_code))]
impl From<HeaderV2> for HeaderV3 {
    /// A v2 header is a v3 header without a map.
    fn from(h: HeaderV2) -> HeaderV3 {
        HeaderV3 {
            magic: h.magic,
            version: h.version,
            dims: h.dims,
            map: MapRecord::default(),
            flags: h.flags,
            settings: h.settings,
            n_tensors: h.n_tensors,
            payload_len: h.payload_len,
            payload_crc: h.payload_crc,
        }
    }
}

/// The header of a format-v2 blob (see the module docs for the field order).
#[derive(Serialize, Deserialize)]
#[cfg_attr(not(feature = "legacy-blobs"), allow(dead_code))]
struct HeaderV2 {
    magic: [u8; 4],
    version: u16,
    dims: DimsRecord,
    flags: u32,
    settings: AdaptSettings,
    n_tensors: u16,
    payload_len: u32,
    payload_crc: u32,
}

/// The blob header, as parsed from any supported format version (a v1 header reports the
/// paper's [`AdaptSettings`]). Only [`Blob::parse`] makes one, so its settings are always
/// valid.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Header {
    version: u16,
    scope: ChecksumScope,
    dims: DimsRecord,
    map: MapRecord,
    flags: u32,
    settings: AdaptSettings,
    n_tensors: u16,
    payload_len: u32,
    payload_crc: u32,
}

impl Header {
    /// The dims the blob was made for.
    pub fn dims(&self) -> Dims {
        self.dims.to_dims(self.map)
    }
    /// Model flags ([`FLAG_ADAPT`], [`FLAG_ZERO_NOISE`], [`FLAG_COSSIM`], ...). A v4 blob
    /// has only bits of [`crate::spec::schema::KNOWN_FLAGS`] (others are refused); a v1-v3 blob's
    /// unknown bits are kept and ignored, as they always were; a v5 blob's are those of its
    /// named settings ([`ModelSpec::bits`]).
    pub fn flags(&self) -> u32 {
        self.flags
    }
    /// Every setting the header records, whatever its version ([`ModelSpec::from_bits`] of
    /// a v1-v4 header's flags and inner-loop settings; a v5 header's named settings).
    pub fn spec(&self) -> ModelSpec {
        ModelSpec::from_bits(self.flags, self.settings)
    }
    /// The adaptation mode the model was meta-trained in and must run in:
    /// [`AdaptMode::Full`] with [`FLAG_FULL_ADAPT`], else
    /// [`AdaptMode::Efficient`].
    pub fn adapt_mode(&self) -> AdaptMode {
        if self.flags & FLAG_FULL_ADAPT != 0 {
            AdaptMode::Full
        } else {
            AdaptMode::Efficient
        }
    }
    /// Format version of the parsed blob (1 to 5).
    pub fn version(&self) -> u16 {
        self.version
    }
    /// What the blob's CRC-32 covers, the rule it was verified by: the payload only (v1-v3)
    /// or the header and the payload (v4).
    pub fn checksum_scope(&self) -> ChecksumScope {
        self.scope
    }
    /// True when the header stored the inner-loop settings (format v2 and later); false for
    /// a v1 blob, whose [`Header::adapt_settings`] are [`AdaptSettings::PAPER`].
    pub fn has_adapt_settings(&self) -> bool {
        self.version >= 2
    }
    /// The inner-loop settings the model was trained with (v1: [`AdaptSettings::PAPER`]).
    pub fn adapt_settings(&self) -> AdaptSettings {
        self.settings
    }
    /// α1, D's ascent rate (v1: 1e-4).
    pub fn alpha_disc(&self) -> f32 {
        self.settings.alpha_disc
    }
    /// α2, θ's and φ's descent rate (v1: 1e-4).
    pub fn alpha_adapt(&self) -> f32 {
        self.settings.alpha_adapt
    }
    /// Cap on inner updates per episode (v1: 4).
    pub fn max_inner(&self) -> u32 {
        self.settings.max_inner
    }
    /// Number of tensors.
    pub fn n_tensors(&self) -> u16 {
        self.n_tensors
    }
    /// Payload length in bytes.
    pub fn payload_len(&self) -> u32 {
        self.payload_len
    }
    /// The stored CRC-32: of the payload (v1-v3), or of the header's other bytes and the
    /// payload (v4); see [`Header::checksum_scope`].
    pub fn payload_crc(&self) -> u32 {
        self.payload_crc
    }
}

impl ModelSpec {
    /// Every setting a blob header records ([`Header::spec`]).
    pub fn from_header(header: &Header) -> ModelSpec {
        header.spec()
    }
}

/// [`BlobError::DegenerateDims`] for a zero width or an inconsistent map
/// ([`Dims::degenerate_field`]), [`BlobError::DimsTooLarge`] unless every size derived from
/// the header's dims fits in `usize` ([`Dims::checked_sizes`]).
fn check_dims_fit(d: &DimsRecord, map: MapRecord) -> Result<(), BlobError> {
    check_model_dims(&d.to_dims(map))
}

/// The one check of a model's dims, shared by the parser, the encoder and
/// [`Navigator::new`](crate::navigator::Navigator::new): no zero width and a consistent map
/// ([`BlobError::DegenerateDims`]), every derived size fits in `usize`
/// ([`BlobError::DimsTooLarge`]).
pub fn check_model_dims(d: &Dims) -> Result<(), BlobError> {
    if let Some(field) = d.degenerate_field() {
        return Err(BlobError::DegenerateDims { field });
    }
    if d.checked_sizes() {
        Ok(())
    } else {
        Err(BlobError::DimsTooLarge)
    }
}

/// Decodes and checks the header of any supported version (of a version `opts` accepts);
/// returns it and the bytes after it.
fn parse_header(bytes: &[u8], opts: ParseOptions) -> Result<(Header, &[u8]), BlobError> {
    fn map_err(e: postcard::Error) -> BlobError {
        match e {
            postcard::Error::DeserializeUnexpectedEnd => BlobError::Truncated,
            _ => BlobError::Malformed,
        }
    }
    let prefix = match postcard::take_from_bytes::<Prefix>(bytes) {
        Ok((p, _)) => p,
        Err(postcard::Error::DeserializeUnexpectedEnd) => return Err(BlobError::Truncated),
        Err(_) => {
            if bytes.len() >= 4 && bytes[..4] != MAGIC {
                return Err(BlobError::BadMagic);
            }
            return Err(BlobError::Malformed);
        }
    };
    if prefix.magic != MAGIC {
        return Err(BlobError::BadMagic);
    }
    // Before anything in an unprotected header is interpreted.
    if opts.require_header_crc && (MIN_FORMAT_VERSION..4).contains(&prefix.version) {
        return Err(BlobError::HeaderNotCovered {
            found: prefix.version,
        });
    }
    match prefix.version {
        #[cfg(not(feature = "legacy-blobs"))]
        found @ MIN_FORMAT_VERSION..=4 => Err(BlobError::LegacyFormat { found }),
        #[cfg(feature = "legacy-blobs")]
        1 => {
            // `magic` and `version` are decoded again (same bytes, same values as the prefix).
            let (h, rest) = postcard::take_from_bytes::<HeaderV1>(bytes).map_err(map_err)?;
            check_dims_fit(&h.dims, MapRecord::default())?;
            Ok((
                Header {
                    version: 1,
                    scope: ChecksumScope::Payload,
                    dims: h.dims,
                    map: MapRecord::default(),
                    flags: h.flags,
                    settings: AdaptSettings::PAPER,
                    n_tensors: h.n_tensors,
                    payload_len: h.payload_len,
                    payload_crc: h.payload_crc,
                },
                rest,
            ))
        }
        #[cfg(feature = "legacy-blobs")]
        2 => {
            let (h, rest) = postcard::take_from_bytes::<HeaderV2>(bytes).map_err(map_err)?;
            Ok((HeaderV3::from(h).into_header(2)?, rest))
        }
        #[cfg(feature = "legacy-blobs")]
        3 => {
            let (h, rest) = postcard::take_from_bytes::<HeaderV3>(bytes).map_err(map_err)?;
            Ok((h.into_header(3)?, rest))
        }
        #[cfg(feature = "legacy-blobs")]
        4 => {
            let (body, rest) = postcard::take_from_bytes::<HeaderV4Body>(bytes).map_err(map_err)?;
            let (crc, payload) = check_whole_blob(bytes, rest, body.payload_len)?;
            // After the checksum: these bits were written on purpose, by a newer build.
            crate::spec::schema::check_known_flags(body.flags)?;
            Ok((body.with_crc(crc).into_header(4)?, payload))
        }
        5 => {
            let (h, rest) =
                postcard::take_from_bytes::<HeaderV5Body<'_>>(bytes).map_err(map_err)?;
            let (crc, payload) = check_whole_blob(bytes, rest, h.payload_len)?;
            let mut header = Header {
                version: 5,
                scope: ChecksumScope::HeaderAndPayload,
                dims: h.dims,
                map: h.map,
                flags: 0,
                settings: AdaptSettings::PAPER,
                n_tensors: h.n_tensors,
                payload_len: h.payload_len,
                payload_crc: crc,
            };
            read_settings(h.settings, &mut header.flags, &mut header.settings)?;
            check_dims_fit(&h.dims, h.map)?;
            Ok((header, payload))
        }
        found => Err(BlobError::UnsupportedVersion { found }),
    }
}

/// The checksum of a v4/v5 blob whose header's fields before the checksum end where `rest`
/// starts, checked with the payload's length before anything in the header is interpreted
/// (a tampered header is reported as such, not as the odd setting it now holds). Returns
/// the checksum and the payload.
fn check_whole_blob<'a>(
    bytes: &'a [u8],
    rest: &'a [u8],
    payload_len: u32,
) -> Result<(u32, &'a [u8]), BlobError> {
    let covered = &bytes[..bytes.len() - rest.len()];
    let (crc, payload) = match postcard::take_from_bytes::<u32>(rest) {
        Ok(v) => v,
        Err(postcard::Error::DeserializeUnexpectedEnd) => return Err(BlobError::Truncated),
        Err(_) => return Err(BlobError::Malformed),
    };
    let plen = payload_len as usize;
    if payload.len() < plen {
        return Err(BlobError::Truncated);
    }
    if payload.len() != plen {
        return Err(BlobError::PayloadLength {
            expected: payload_len,
            actual: payload.len(),
        });
    }
    let actual = crc32_update(crc32(covered), payload);
    if actual != crc {
        return Err(BlobError::HeaderChecksumMismatch {
            expected: crc,
            actual,
        });
    }
    Ok((crc, payload))
}

/// Reads the settings of a v5 header's settings section into the v4 form, a flag word and
/// the inner-loop settings (from [`ModelSpec::BLOB_DEFAULT`]'s: no bit, the paper's rates;
/// α1 is α2 unless a record names `disc_lr`): every record well formed, its key known,
/// named once, of its setting's type, a known name, in range.
fn read_settings(
    mut records: &[u8],
    flags: &mut u32,
    settings: &mut AdaptSettings,
) -> Result<(), BlobError> {
    let mut seen = 0u32;
    while !records.is_empty() {
        let (rec, rest) = take_setting(records).ok_or(BlobError::Malformed)?;
        let RawSetting {
            key: name,
            tag,
            raw,
            name: value,
        } = rec;
        records = rest;
        let key = SettingKey::of(name).ok_or(BlobError::UnknownSetting {
            key: SettingText::new(name),
        })?;
        let bit = 1u32 << key.index();
        if seen & bit != 0 {
            return Err(BlobError::DuplicateSetting { key });
        }
        seen |= bit;
        let raw = if tag == 2 {
            name_index(key, value)
        } else {
            raw
        };
        apply_setting(key, tag, raw, flags, settings).map_err(|e| match e {
            SettingError::WrongType { expected } => BlobError::SettingType { key, expected },
            SettingError::UnknownName => BlobError::UnknownSettingValue {
                key,
                value: SettingText::new(value),
            },
            _ => BlobError::SettingOutOfRange { key, value: raw },
        })?;
    }
    if seen & (1 << SettingKey::DISC_LR.index()) == 0 {
        settings.alpha_disc = settings.alpha_adapt;
    }
    settings.validate()
}

impl From<SpecError> for BlobError {
    /// The setting out of its range, named by its key in a v5 header.
    fn from(e: SpecError) -> BlobError {
        match e {
            SpecError::InnerRate(a) => BlobError::BadInnerRate {
                field: "inner_lr",
                bits: a.to_bits(),
            },
            SpecError::DiscRate(a) => BlobError::BadInnerRate {
                field: "disc_lr",
                bits: a.to_bits(),
            },
            SpecError::DiscSteps(n) => BlobError::SettingOutOfRange {
                key: SettingKey::DISC_STEPS,
                value: n,
            },
            SpecError::CommitDelay(d) => BlobError::SettingOutOfRange {
                key: SettingKey::COMMIT_DELAY,
                value: d,
            },
            // Not a setting of a header (the map's dims are checked as dims).
            SpecError::MapGrid { .. } => BlobError::DegenerateDims { field: "map_rows" },
        }
    }
}

#[derive(Deserialize)]
struct RecordIn<'a> {
    id: u16,
    rows: u32,
    cols: u32,
    quant: u8,
    #[serde(borrow)]
    data: &'a [u8],
    #[serde(borrow)]
    scales: &'a [u8],
}

/// One tensor of a parsed blob (borrowed from the blob bytes).
#[derive(Clone, Copy, Debug)]
pub struct TensorView<'a> {
    /// Which tensor.
    pub id: TensorId,
    /// Rows.
    pub rows: usize,
    /// Columns (1 for vectors).
    pub cols: usize,
    /// Quantisation.
    pub quant: Quant,
    /// Raw data bytes.
    pub data: &'a [u8],
    /// Raw scale bytes (int8 only).
    pub scales: &'a [u8],
}

impl<'a> TensorView<'a> {
    /// The tensor as a kernel matrix view, without copying.
    pub fn matrix(&self) -> Result<MatRef<'a>, BlobError> {
        let r = match self.quant {
            Quant::F32 => MatRef::f32_le(self.rows, self.cols, self.data),
            Quant::I8 => MatRef::i8(self.rows, self.cols, self.data, Scales::Le(self.scales)),
        };
        r.map_err(|_| BlobError::BadTensorShape { id: self.id as u16 })
    }

    /// Bytes of storage (data plus scales).
    pub fn storage_bytes(&self) -> usize {
        self.data.len() + self.scales.len()
    }

    /// Largest absolute quantisation step `scale / 2` of an int8 tensor (0 for f32): the
    /// bound on the rounding error of each weight.
    pub fn max_rounding_error(&self) -> f32 {
        let mut m = 0.0f32;
        for c in self.scales.chunks_exact(4) {
            let s = f32::from_le_bytes([c[0], c[1], c[2], c[3]]);
            if s > m {
                m = s;
            }
        }
        m * 0.5
    }
}

/// A parsed, validated blob.
#[derive(Clone, Debug)]
pub struct Blob<'a> {
    header: Header,
    tensors: [Option<TensorView<'a>>; NUM_TENSORS],
    len: usize,
}

/// What [`Blob::parse_with`] accepts beyond the checks every parse makes.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct ParseOptions {
    /// Refuse blobs whose checksum does not cover the header (formats v1-v3, see
    /// [`ChecksumScope::Payload`]) with [`BlobError::HeaderNotCovered`]: a flipped flag bit,
    /// rate or map size in such a header goes unnoticed. For integrators who accept only
    /// blobs where every byte the device interprets is checksummed (format v4 and later);
    /// `gman upgrade-blob IN OUT` rewrites an older blob in that format.
    pub require_header_crc: bool,
}

impl<'a> Blob<'a> {
    /// Parses and validates `bytes` (see the module docs), accepting every supported
    /// format version ([`ParseOptions::default`]). Borrows, never copies.
    pub fn parse(bytes: &'a [u8]) -> Result<Blob<'a>, BlobError> {
        Self::parse_with(bytes, ParseOptions::default())
    }

    /// [`Blob::parse`] with the options `opts`, e.g.
    /// `ParseOptions { require_header_crc: true }` to refuse formats v1-v3.
    pub fn parse_with(bytes: &'a [u8], opts: ParseOptions) -> Result<Blob<'a>, BlobError> {
        let (header, payload) = parse_header(bytes, opts)?;
        if payload.len() < header.payload_len as usize {
            return Err(BlobError::Truncated);
        }
        if payload.len() != header.payload_len as usize {
            return Err(BlobError::PayloadLength {
                expected: header.payload_len,
                actual: payload.len(),
            });
        }
        let crc = crc32(payload);
        if header.scope == ChecksumScope::Payload && crc != header.payload_crc {
            return Err(BlobError::ChecksumMismatch {
                expected: header.payload_crc,
                actual: crc,
            });
        }
        let dims = header.dims();
        let mut tensors: [Option<TensorView<'a>>; NUM_TENSORS] = [None; NUM_TENSORS];
        let mut rest = payload;
        for _ in 0..header.n_tensors {
            let (rec, r) = match postcard::take_from_bytes::<RecordIn<'a>>(rest) {
                Ok(v) => v,
                Err(postcard::Error::DeserializeUnexpectedEnd) => return Err(BlobError::Truncated),
                Err(_) => return Err(BlobError::Malformed),
            };
            rest = r;
            let view = validate_record(&rec, &dims)?;
            let slot = &mut tensors[view.id as usize];
            if slot.is_some() {
                return Err(BlobError::DuplicateTensor { id: rec.id });
            }
            *slot = Some(view);
        }
        if !rest.is_empty() {
            return Err(BlobError::Malformed);
        }
        Ok(Blob {
            header,
            tensors,
            len: bytes.len(),
        })
    }

    /// The header.
    pub fn header(&self) -> &Header {
        &self.header
    }

    /// The dims the blob was made for.
    pub fn dims(&self) -> Dims {
        self.header.dims()
    }

    /// Total size of the blob in bytes.
    pub fn len(&self) -> usize {
        self.len
    }

    /// True for an empty blob (never the case for a parsed one).
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// Checks that the blob was made for `expected`, naming the first differing field.
    pub fn check_dims(&self, expected: &Dims) -> Result<(), BlobError> {
        let e = DimsRecord::from_dims(expected);
        let f = self.header.dims;
        let (em, fm) = (MapRecord::from_dims(expected), self.header.map);
        for (field, a, b) in [
            ("attr", e.attr, f.attr),
            ("noise", e.noise, f.noise),
            ("gen_hidden", e.gen_hidden, f.gen_hidden),
            ("feat", e.feat, f.feat),
            ("disc_hidden", e.disc_hidden, f.disc_hidden),
            ("lstm_hidden", e.lstm_hidden, f.lstm_hidden),
            ("embed", e.embed, f.embed),
            ("ps", e.ps, f.ps),
            ("map_rows", em.map_rows, fm.map_rows),
            ("map_cols", em.map_cols, fm.map_cols),
            ("cell_embed", em.cell_embed, fm.cell_embed),
        ] {
            if a != b {
                return Err(BlobError::DimensionMismatch {
                    field,
                    expected: a,
                    found: b,
                });
            }
        }
        Ok(())
    }

    /// The tensor `id`, or [`BlobError::MissingTensor`].
    pub fn tensor(&self, id: TensorId) -> Result<TensorView<'a>, BlobError> {
        self.tensors[id as usize].ok_or(BlobError::MissingTensor { id: id as u16 })
    }

    /// True when the blob holds tensor `id`.
    pub fn has(&self, id: TensorId) -> bool {
        self.tensors[id as usize].is_some()
    }

    /// Tensor `id` as a zero-copy matrix view.
    pub fn matrix(&self, id: TensorId) -> Result<MatRef<'a>, BlobError> {
        self.tensor(id)?.matrix()
    }

    /// All tensors present, in id order.
    pub fn tensors(&self) -> impl Iterator<Item = TensorView<'a>> + '_ {
        self.tensors.iter().filter_map(|t| *t)
    }

    /// Copies tensor `id` into `out` as f32 (dequantising int8). `out.len()` must be
    /// `rows * cols`.
    pub fn copy_f32(&self, id: TensorId, out: &mut [f32]) -> Result<(), BlobError> {
        let t = self.tensor(id)?;
        if out.len() != t.rows * t.cols {
            return Err(BlobError::BadTensorShape { id: id as u16 });
        }
        t.matrix()?
            .copy_to(out)
            .map_err(|_| BlobError::BadTensorShape { id: id as u16 })
    }
}

fn validate_record<'a>(rec: &RecordIn<'a>, dims: &Dims) -> Result<TensorView<'a>, BlobError> {
    let id = TensorId::from_raw(rec.id).ok_or(BlobError::UnknownTensor { id: rec.id })?;
    if !id.present(dims) {
        return Err(BlobError::UnknownTensor { id: rec.id });
    }
    let (rows, cols) = id.shape(dims);
    if rec.rows as usize != rows || rec.cols as usize != cols {
        return Err(BlobError::BadTensorShape { id: rec.id });
    }
    let n = rows
        .checked_mul(cols)
        .ok_or(BlobError::BadTensorShape { id: rec.id })?;
    let quant = match rec.quant {
        0 => Quant::F32,
        1 if !id.is_vector() => Quant::I8,
        _ => return Err(BlobError::BadQuantization { id: rec.id }),
    };
    match quant {
        Quant::F32 => {
            if rec.data.len() != n.saturating_mul(4) || !rec.scales.is_empty() {
                return Err(BlobError::BadTensorShape { id: rec.id });
            }
            for c in rec.data.chunks_exact(4) {
                if !f32::from_le_bytes([c[0], c[1], c[2], c[3]]).is_finite() {
                    return Err(BlobError::NonFiniteWeight { id: rec.id });
                }
            }
        }
        Quant::I8 => {
            if rec.data.len() != n || rec.scales.len() != rows.saturating_mul(4) {
                return Err(BlobError::BadTensorShape { id: rec.id });
            }
            for c in rec.scales.chunks_exact(4) {
                let s = f32::from_le_bytes([c[0], c[1], c[2], c[3]]);
                if !s.is_finite() || s < 0.0 {
                    return Err(BlobError::NonFiniteScale { id: rec.id });
                }
            }
        }
    }
    Ok(TensorView {
        id,
        rows,
        cols,
        quant,
        data: rec.data,
        scales: rec.scales,
    })
}

/// The values of a tensor to encode.
#[derive(Clone, Copy, Debug)]
pub enum TensorData<'a> {
    /// f32 values, row-major.
    F32(&'a [f32]),
    /// int8 values (bytes holding `i8`) and one scale per row.
    I8 {
        /// Quantised values.
        q: &'a [u8],
        /// Row scales.
        scales: &'a [f32],
    },
}

/// A tensor to encode into a blob.
#[derive(Clone, Copy, Debug)]
pub struct TensorSpec<'a> {
    /// Which tensor.
    pub id: TensorId,
    /// Its values.
    pub data: TensorData<'a>,
}

struct F32Bytes<'a>(&'a [f32]);
impl Serialize for F32Bytes<'_> {
    fn serialize<S: Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        // Same wire format as postcard's `serialize_bytes`: varint length + raw bytes.
        let mut seq = s.serialize_seq(Some(self.0.len() * 4))?;
        for v in self.0 {
            for b in v.to_le_bytes() {
                seq.serialize_element(&b)?;
            }
        }
        seq.end()
    }
}

struct RawBytes<'a>(&'a [u8]);
impl Serialize for RawBytes<'_> {
    fn serialize<S: Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        s.serialize_bytes(self.0)
    }
}

#[derive(Serialize)]
struct RecordOut<'a> {
    id: u16,
    rows: u32,
    cols: u32,
    quant: u8,
    data: DataOut<'a>,
    scales: DataOut<'a>,
}

enum DataOut<'a> {
    F32(F32Bytes<'a>),
    Raw(RawBytes<'a>),
}
impl Serialize for DataOut<'_> {
    fn serialize<S: Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        match self {
            DataOut::F32(v) => v.serialize(s),
            DataOut::Raw(v) => v.serialize(s),
        }
    }
}

/// Exact number of bytes [`encode`] writes for these tensors (an upper bound on the header).
pub fn encoded_len_bound(tensors: &[TensorSpec<'_>]) -> usize {
    let mut n = HEADER_RESERVE;
    for t in tensors {
        n += 32
            + match t.data {
                TensorData::F32(v) => 4 * v.len(),
                TensorData::I8 { q, scales } => q.len() + 4 * scales.len(),
            };
    }
    n
}

/// Encodes a blob (format v5) for `dims` holding `tensors` into `out` with the settings
/// [`ModelSpec::BLOB_DEFAULT`] (the paper's, no adaptation); see [`Encoder`].
pub fn encode(dims: &Dims, tensors: &[TensorSpec<'_>], out: &mut [u8]) -> Result<usize, BlobError> {
    encode_spec(dims, &ModelSpec::BLOB_DEFAULT, tensors, out)
}

/// Encodes a blob (format v5, see [`FORMAT_VERSION`]) for `dims` and the model's settings
/// `spec`, holding `tensors`, into `out`; returns the number of bytes written. Checks the
/// settings ([`ModelSpec::validate`]), the dims ([`check_model_dims`]), shapes, finiteness
/// and quantisation like the parser does, so what it writes always parses. See [`Encoder`]
/// for writing tensor by tensor.
pub fn encode_spec(
    dims: &Dims,
    spec: &ModelSpec,
    tensors: &[TensorSpec<'_>],
    out: &mut [u8],
) -> Result<usize, BlobError> {
    let mut e = Encoder::new(dims, spec, out)?;
    for t in tensors {
        e.push(t)?;
    }
    e.finish()
}

/// [`encode_spec`] of the settings a v1-v4 header's model `flags` and inner-loop `settings`
/// stand for ([`ModelSpec::from_bits`]); flag bits this build does not know are refused
/// ([`BlobError::UnknownFlagBit`]), and so are bad rates ([`AdaptSettings::validate`]).
pub fn encode_with_settings(
    dims: &Dims,
    flags: u32,
    settings: AdaptSettings,
    tensors: &[TensorSpec<'_>],
    out: &mut [u8],
) -> Result<usize, BlobError> {
    settings.validate()?;
    crate::spec::schema::check_known_flags(flags)?;
    encode_spec(dims, &ModelSpec::from_bits(flags, settings), tensors, out)
}

/// The one emitter of blobs: writes tensor records one by one into the caller's buffer, then
/// the header, format v5, in front of them ([`Encoder::finish`]). The `encode*` functions,
/// [`reencode`] and [`encode_model`] use it; it needs no allocation and no buffer beyond
/// `out`.
#[derive(Debug)]
pub struct Encoder<'o> {
    out: &'o mut [u8],
    dims: Dims,
    spec: ModelSpec,
    seen: [bool; NUM_TENSORS],
    n_tensors: u16,
    pos: usize,
}

impl<'o> Encoder<'o> {
    /// Starts a blob for `dims` and the model's settings `spec` in `out` (checks the
    /// settings, the dims, then that `out` can hold a header).
    pub fn new(dims: &Dims, spec: &ModelSpec, out: &'o mut [u8]) -> Result<Self, BlobError> {
        spec.validate()?;
        check_model_dims(dims)?;
        if out.len() < HEADER_RESERVE {
            return Err(BlobError::BufferTooSmall);
        }
        Ok(Encoder {
            out,
            dims: *dims,
            spec: *spec,
            seen: [false; NUM_TENSORS],
            n_tensors: 0,
            pos: HEADER_RESERVE,
        })
    }

    /// Appends one tensor record (checked like the parser checks it).
    pub fn push(&mut self, t: &TensorSpec<'_>) -> Result<(), BlobError> {
        let dims = &self.dims;
        let raw = t.id as u16;
        if core::mem::replace(&mut self.seen[t.id as usize], true) {
            return Err(BlobError::DuplicateTensor { id: raw });
        }
        if !t.id.present(dims) {
            return Err(BlobError::UnknownTensor { id: raw });
        }
        let (rows, cols) = t.id.shape(dims);
        let (quant, data, scales) = match t.data {
            TensorData::F32(v) => {
                if v.len() != rows * cols {
                    return Err(BlobError::BadTensorShape { id: raw });
                }
                if v.iter().any(|x| !x.is_finite()) {
                    return Err(BlobError::NonFiniteWeight { id: raw });
                }
                (
                    Quant::F32,
                    DataOut::F32(F32Bytes(v)),
                    DataOut::F32(F32Bytes(&[])),
                )
            }
            TensorData::I8 { q, scales } => {
                if t.id.is_vector() {
                    return Err(BlobError::BadQuantization { id: raw });
                }
                if q.len() != rows * cols || scales.len() != rows {
                    return Err(BlobError::BadTensorShape { id: raw });
                }
                if scales.iter().any(|s| !s.is_finite() || *s < 0.0) {
                    return Err(BlobError::NonFiniteScale { id: raw });
                }
                (
                    Quant::I8,
                    DataOut::Raw(RawBytes(q)),
                    DataOut::F32(F32Bytes(scales)),
                )
            }
        };
        self.write_record(raw, rows, cols, quant, data, scales)
    }

    /// Appends the record of a tensor of a parsed blob, its bytes as they are (the same
    /// record [`Encoder::push`] writes for its values), checked like [`Encoder::push`]
    /// checks values.
    pub fn push_view(&mut self, t: &TensorView<'_>) -> Result<(), BlobError> {
        let raw = t.id as u16;
        if core::mem::replace(&mut self.seen[t.id as usize], true) {
            return Err(BlobError::DuplicateTensor { id: raw });
        }
        if !t.id.present(&self.dims) || t.id.shape(&self.dims) != (t.rows, t.cols) {
            return Err(BlobError::BadTensorShape { id: raw });
        }
        let le = |b: &[u8]| -> f32 { f32::from_le_bytes([b[0], b[1], b[2], b[3]]) };
        let n = t.rows * t.cols;
        match t.quant {
            Quant::F32 => {
                if t.data.len() != 4 * n || !t.scales.is_empty() {
                    return Err(BlobError::BadTensorShape { id: raw });
                }
                if t.data.chunks_exact(4).any(|b| !le(b).is_finite()) {
                    return Err(BlobError::NonFiniteWeight { id: raw });
                }
            }
            Quant::I8 => {
                if t.id.is_vector() {
                    return Err(BlobError::BadQuantization { id: raw });
                }
                if t.data.len() != n || t.scales.len() != 4 * t.rows {
                    return Err(BlobError::BadTensorShape { id: raw });
                }
                let bad = |b: &[u8]| !le(b).is_finite() || le(b) < 0.0;
                if t.scales.chunks_exact(4).any(bad) {
                    return Err(BlobError::NonFiniteScale { id: raw });
                }
            }
        }
        let (data, scales) = (
            DataOut::Raw(RawBytes(t.data)),
            DataOut::Raw(RawBytes(t.scales)),
        );
        self.write_record(raw, t.rows, t.cols, t.quant, data, scales)
    }

    fn write_record(
        &mut self,
        raw: u16,
        rows: usize,
        cols: usize,
        quant: Quant,
        data: DataOut<'_>,
        scales: DataOut<'_>,
    ) -> Result<(), BlobError> {
        let rec = RecordOut {
            id: raw,
            rows: rows as u32,
            cols: cols as u32,
            quant: quant.code(),
            data,
            scales,
        };
        let n = postcard::to_slice(&rec, &mut self.out[self.pos..])
            .map_err(|_| BlobError::BufferTooSmall)?
            .len();
        self.pos += n;
        self.n_tensors = self.n_tensors.wrapping_add(1);
        Ok(())
    }

    /// Writes the header and returns the length of the blob, which starts at `out[0]`.
    pub fn finish(self) -> Result<usize, BlobError> {
        let Encoder {
            out,
            dims,
            spec,
            n_tensors,
            pos,
            ..
        } = self;
        let payload_len = pos - HEADER_RESERVE;
        let mut hbuf = [0u8; HEADER_RESERVE];
        let too_small = |_| BlobError::BufferTooSmall;
        let mut sbuf = [0u8; HEADER_RESERVE];
        let mut slen = 0;
        let default = ModelSpec::BLOB_DEFAULT;
        for key in SETTING_KEYS {
            match spec.get(key) {
                Some(value) if Some(value) != default.get(key) => {
                    let rec = SettingRecord { key, value };
                    slen += postcard::to_slice(&rec, &mut sbuf[slen..])
                        .map_err(too_small)?
                        .len();
                }
                _ => {}
            }
        }
        let body = HeaderV5Out {
            magic: MAGIC,
            version: FORMAT_VERSION,
            dims: DimsRecord::from_dims(&dims),
            map: MapRecord::from_dims(&dims),
            settings: RawBytes(&sbuf[..slen]),
            n_tensors,
            payload_len: payload_len as u32,
        };
        let blen = postcard::to_slice(&body, &mut hbuf)
            .map_err(too_small)?
            .len();
        let crc = crc32_update(crc32(&hbuf[..blen]), &out[HEADER_RESERVE..pos]);
        let written = postcard::to_slice(&crc, &mut hbuf[blen..]).map(|w| blen + w.len());
        let hlen = written.map_err(too_small)?;
        out.copy_within(HEADER_RESERVE..pos, hlen);
        out[..hlen].copy_from_slice(&hbuf[..hlen]);
        Ok(hlen + payload_len)
    }
}

/// Length of the `out` buffer [`reencode`] needs for the blob `bytes`.
pub const fn reencoded_len_bound(bytes: &[u8]) -> usize {
    bytes.len().saturating_add(HEADER_RESERVE)
}

/// The blob `bytes` emitted again through the one encoder with the settings `spec`: the
/// dims and every tensor record are kept byte for byte (a format v1-v4 blob comes out as
/// the current format). Writes into `out` (at least [`reencoded_len_bound`] bytes) and
/// returns the new blob's length. `gman export --blob --activations`, `gman upgrade-blob`
/// and the firmware's build script change [`ModelSpec::int8_activations`] and
/// [`ModelSpec::compact_psi`] of [`Header::spec`] with it.
pub fn reencode(bytes: &[u8], spec: &ModelSpec, out: &mut [u8]) -> Result<usize, BlobError> {
    let blob = Blob::parse(bytes)?;
    let mut e = Encoder::new(&blob.header().dims(), spec, out)?;
    for t in blob.tensors() {
        e.push_view(&t)?;
    }
    e.finish()
}

/// [`reencode`] with the settings a v1-v4 header's model `flags` stand for
/// ([`ModelSpec::from_bits`], the blob's own inner-loop settings); flag bits this build
/// does not know are refused ([`BlobError::UnknownFlagBit`]).
pub fn reencode_with_flags(bytes: &[u8], flags: u32, out: &mut [u8]) -> Result<usize, BlobError> {
    crate::spec::schema::check_known_flags(flags)?;
    let settings = Blob::parse(bytes)?.header().adapt_settings();
    reencode(bytes, &ModelSpec::from_bits(flags, settings), out)
}

/// Bytes a blob of every tensor of `d` takes at most, in `quant` (matrices; vectors are
/// always f32): the length of the `out` buffer [`encode_model`] needs (saturating).
pub const fn encoded_model_len_bound(d: &Dims, quant: Quant) -> usize {
    let mut n = HEADER_RESERVE;
    let mut i = 0;
    while i < TensorId::ALL.len() {
        let id = TensorId::ALL[i];
        i += 1;
        if !id.present(d) {
            continue;
        }
        let (r, c) = id.shape(d);
        let rc = r.saturating_mul(c);
        let bytes = match quant {
            Quant::I8 if !id.is_vector() => rc.saturating_add(r.saturating_mul(4)),
            _ => rc.saturating_mul(4),
        };
        n = n.saturating_add(32).saturating_add(bytes);
    }
    n
}

/// `(floats, bytes)` of scratch [`encode_model`] needs for `d`: the largest tensor plus its
/// row scales as f32, and the largest tensor as int8 (saturating).
pub const fn encode_model_scratch_len(d: &Dims) -> (usize, usize) {
    let (n, rows) = crate::spec::schema::max_tensor_len(d);
    (n.saturating_add(rows), n)
}

/// Encodes a whole model of `dims` (every tensor of [`TensorId::all_for`], in storage order)
/// whose f32 values `values(id, out)` writes into `out` (`rows * cols` floats), matrices
/// int8-quantised per row when `quant` is [`Quant::I8`] (vectors stay f32): the one
/// weights-to-blob builder of the workspace (seeded test weights, see
/// [`crate::blob::seeded`], and the host's exporter alike). `floats` and `bytes` are scratch of at
/// least [`encode_model_scratch_len`]; `out` should be [`encoded_model_len_bound`] long.
/// Returns the blob's length. Errors of `values` are passed through.
#[allow(clippy::too_many_arguments)]
pub fn encode_model<E: From<BlobError>>(
    dims: &Dims,
    spec: &ModelSpec,
    quant: Quant,
    mut values: impl FnMut(TensorId, &mut [f32]) -> Result<(), E>,
    out: &mut [u8],
    floats: &mut [f32],
    bytes: &mut [u8],
) -> Result<usize, E> {
    let mut e = Encoder::new(dims, spec, out)?;
    for id in TensorId::all_for(dims) {
        let (r, c) = id.shape(dims);
        let n = r * c;
        if floats.len() < n + r || (quant == Quant::I8 && bytes.len() < n) {
            return Err(BlobError::BufferTooSmall.into());
        }
        let (v, rest) = floats.split_at_mut(n);
        values(id, v)?;
        let data = if quant == Quant::I8 && !id.is_vector() {
            let (q, s) = (&mut bytes[..n], &mut rest[..r]);
            if v.iter().any(|x| !x.is_finite()) {
                // int8 quantisation would hide it; report it as the f32 path does.
                return Err(BlobError::NonFiniteWeight { id: id as u16 }.into());
            }
            crate::blob::quant::quantize_rows(v, r, c, q, s)
                .map_err(|_| BlobError::BadTensorShape { id: id as u16 })?;
            TensorData::I8 { q, scales: s }
        } else {
            TensorData::F32(v)
        };
        e.push(&TensorSpec { id, data })?;
    }
    Ok(e.finish()?)
}
