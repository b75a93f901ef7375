//! The parsed blob, a zero-copy view of its tensors ([`Blob`], [`TensorView`]), and the
//! check of every tensor record against the header's dims.

use serde::Deserialize;

use crate::blob::crc32::crc32;
use crate::blob::format::Quant;
use crate::blob::header::{
    parse_header, ChecksumScope, DimsRecord, Header, MapRecord, ParseOptions,
};
use crate::error::BlobError;
use crate::nn::matrix::{MatRef, Scales};
use crate::spec::preset::Dims;
use crate::spec::schema::{TensorId, NUM_TENSORS};

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
    pub(super) header: Header,
    pub(super) tensors: [Option<TensorView<'a>>; NUM_TENSORS],
    pub(super) len: usize,
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
