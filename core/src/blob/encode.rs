//! The one weights-to-blob encoder ([`Encoder`]) and its entry points: tensors to a blob,
//! a blob re-emitted under other settings, a model's weights in storage order.

use serde::ser::SerializeSeq;
use serde::{Serialize, Serializer};

use crate::blob::crc32::{crc32, crc32_update};
use crate::blob::format::{Quant, RawBytes, FORMAT_VERSION, HEADER_RESERVE, MAGIC};
#[cfg(doc)]
use crate::blob::header::Header;
use crate::blob::header::{check_model_dims, DimsRecord, HeaderV5Out, MapRecord, SettingRecord};
use crate::blob::view::{Blob, TensorView};
use crate::error::BlobError;
use crate::spec::preset::Dims;
use crate::spec::schema::{TensorId, NUM_TENSORS};
use crate::spec::AdaptSettings;
use crate::spec::ModelSpec;
use crate::spec::SETTING_KEYS;

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
    pub(super) out: &'o mut [u8],
    pub(super) dims: Dims,
    pub(super) spec: ModelSpec,
    pub(super) seen: [bool; NUM_TENSORS],
    pub(super) n_tensors: u16,
    pub(super) pos: usize,
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
