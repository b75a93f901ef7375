//! A blob's header: the records of every format version (v1-v5, see [`crate::blob`]), the
//! one header parser with its checksum rules, and the v5 settings section's reader.

use serde::{Deserialize, Serialize};

use crate::blob::crc32::{crc32, crc32_update};
use crate::blob::format::{RawBytes, MAGIC, MIN_FORMAT_VERSION};
use crate::error::BlobError;
use crate::error::SettingText;
use crate::spec::preset::Dims;
use crate::spec::schema::{AdaptMode, FLAG_FULL_ADAPT};
#[cfg(doc)]
use crate::spec::schema::{FLAG_ADAPT, FLAG_COSSIM, FLAG_ZERO_NOISE};
use crate::spec::AdaptSettings;
use crate::spec::SpecError;
use crate::spec::{apply_setting, name_index, ModelSpec, SettingError, SettingKey, SettingValue};

/// What [`Blob::parse_with`](super::Blob::parse_with) accepts beyond the checks every parse
/// makes.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct ParseOptions {
    /// Refuse blobs whose checksum does not cover the header (formats v1-v3, see
    /// [`ChecksumScope::Payload`]) with [`BlobError::HeaderNotCovered`]: a flipped flag bit,
    /// rate or map size in such a header goes unnoticed. For integrators who accept only
    /// blobs where every byte the device interprets is checksummed (format v4 and later);
    /// `gman upgrade-blob IN OUT` rewrites an older blob in that format.
    pub require_header_crc: bool,
}

#[derive(Serialize, Deserialize, Clone, Copy, Debug, PartialEq, Eq)]
pub(super) struct DimsRecord {
    pub(super) attr: u32,
    pub(super) noise: u32,
    pub(super) gen_hidden: u32,
    pub(super) feat: u32,
    pub(super) disc_hidden: u32,
    pub(super) lstm_hidden: u32,
    pub(super) embed: u32,
    pub(super) ps: u32,
}

impl DimsRecord {
    pub(super) fn from_dims(d: &Dims) -> Self {
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
pub(super) struct MapRecord {
    pub(super) map_rows: u32,
    pub(super) map_cols: u32,
    pub(super) cell_embed: u32,
}

impl MapRecord {
    pub(super) fn from_dims(d: &Dims) -> Self {
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
pub(super) struct HeaderV5Out<'a> {
    pub(super) magic: [u8; 4],
    pub(super) version: u16,
    pub(super) dims: DimsRecord,
    pub(super) map: MapRecord,
    pub(super) settings: RawBytes<'a>,
    pub(super) n_tensors: u16,
    pub(super) payload_len: u32,
}

/// One setting of a format-v5 header as the encoder writes it: its key
/// ([`crate::spec::setting_key::SETTING_KEYS`]) and its typed value (read back by
/// [`take_setting`]).
#[derive(Serialize)]
pub(super) struct SettingRecord<'a> {
    pub(super) key: &'a str,
    pub(super) value: SettingValue<'a>,
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
pub(super) struct HeaderV2 {
    pub(super) magic: [u8; 4],
    pub(super) version: u16,
    pub(super) dims: DimsRecord,
    pub(super) flags: u32,
    pub(super) settings: AdaptSettings,
    pub(super) n_tensors: u16,
    pub(super) payload_len: u32,
    pub(super) payload_crc: u32,
}

/// The blob header, as parsed from any supported format version (a v1 header reports the
/// paper's [`AdaptSettings`]). Only [`Blob::parse`](super::Blob::parse) makes one, so its
/// settings are always valid.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Header {
    pub(super) version: u16,
    pub(super) scope: ChecksumScope,
    pub(super) dims: DimsRecord,
    pub(super) map: MapRecord,
    pub(super) flags: u32,
    pub(super) settings: AdaptSettings,
    pub(super) n_tensors: u16,
    pub(super) payload_len: u32,
    pub(super) payload_crc: u32,
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
pub(super) fn parse_header(bytes: &[u8], opts: ParseOptions) -> Result<(Header, &[u8]), BlobError> {
    pub(super) fn map_err(e: postcard::Error) -> BlobError {
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
