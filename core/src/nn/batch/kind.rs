//! The weight formats as the blocked bodies read them ([`crate::nn::matrix::Weights`]: f32, f32
//! from little-endian bytes, int8), and the one dispatch from a matrix view to the body for its
//! format.

use crate::nn::matrix::Scales;

/// Most segments a batched input may have (the layers use at most four).
pub const MAX_SEGS: usize = 8;

/// One storage kind of weights.
pub(super) trait Kind {
    /// Raw unit of storage (`f32` or a byte).
    type R: Copy;
    /// Raw units per weight.
    const U: usize;
    /// Weights `8 c .. 8 c + 8` of a raw row segment.
    fn w8(raw: &[Self::R], c: usize) -> [f32; 8];
    /// Weight `j` of a raw row segment.
    fn w1(raw: &[Self::R], j: usize) -> f32;
}

pub(super) struct F32K;
impl Kind for F32K {
    type R = f32;
    const U: usize = 1;
    #[inline(always)]
    fn w8(raw: &[f32], c: usize) -> [f32; 8] {
        ld8(raw, c)
    }
    #[inline(always)]
    fn w1(raw: &[f32], j: usize) -> f32 {
        raw[j]
    }
}

pub(super) struct LeK;
impl Kind for LeK {
    type R = u8;
    const U: usize = 4;
    #[inline(always)]
    fn w8(raw: &[u8], c: usize) -> [f32; 8] {
        let s = &raw[32 * c..32 * c + 32];
        let mut o = [0.0f32; 8];
        for (k, v) in o.iter_mut().enumerate() {
            *v = f32::from_le_bytes([s[4 * k], s[4 * k + 1], s[4 * k + 2], s[4 * k + 3]]);
        }
        o
    }
    #[inline(always)]
    fn w1(raw: &[u8], j: usize) -> f32 {
        let s = &raw[4 * j..4 * j + 4];
        f32::from_le_bytes([s[0], s[1], s[2], s[3]])
    }
}

pub(super) struct I8K;
impl Kind for I8K {
    type R = u8;
    const U: usize = 1;
    #[inline(always)]
    fn w8(raw: &[u8], c: usize) -> [f32; 8] {
        let s = &raw[8 * c..8 * c + 8];
        let mut o = [0.0f32; 8];
        for (v, &b) in o.iter_mut().zip(s) {
            *v = b as i8 as f32;
        }
        o
    }
    #[inline(always)]
    fn w1(raw: &[u8], j: usize) -> f32 {
        raw[j] as i8 as f32
    }
}

/// A `rows x cols` matrix of one storage kind, with the int8 row scales.
pub(super) struct M<'a, K: Kind> {
    pub(super) d: &'a [K::R],
    pub(super) cols: usize,
    pub(super) scales: Option<Scales<'a>>,
}

impl<'a, K: Kind> M<'a, K> {
    /// Raw storage of row `r`, columns `c0 .. c0 + len`.
    #[inline(always)]
    pub(super) fn seg(&self, r: usize, c0: usize, len: usize) -> &'a [K::R] {
        let s = (r * self.cols + c0) * K::U;
        &self.d[s..s + len * K::U]
    }
}

/// Chunk `c` (elements `8 c .. 8 c + 8`) of an f32 slice.
#[inline(always)]
pub(super) fn ld8(s: &[f32], c: usize) -> [f32; 8] {
    let s = &s[8 * c..8 * c + 8];
    [s[0], s[1], s[2], s[3], s[4], s[5], s[6], s[7]]
}

/// The fixed reduction tree of the eight accumulators.
#[inline(always)]
pub(super) fn tree(a: &[f32; 8]) -> f32 {
    ((a[0] + a[4]) + (a[1] + a[5])) + ((a[2] + a[6]) + (a[3] + a[7]))
}

/// Calls `$body` with `$m` bound to the typed view of `$w`'s storage.
macro_rules! with_kind {
    ($w:expr, |$m:ident| $body:expr) => {
        match $w.weights() {
            Weights::F32(d) => {
                let $m = M::<F32K> {
                    d,
                    cols: $w.cols(),
                    scales: None,
                };
                $body
            }
            Weights::F32Le(d) => {
                let $m = M::<LeK> {
                    d,
                    cols: $w.cols(),
                    scales: None,
                };
                $body
            }
            Weights::I8 { q, scales } => {
                let $m = M::<I8K> {
                    d: q,
                    cols: $w.cols(),
                    scales: Some(scales),
                };
                $body
            }
        }
    };
}
pub(super) use with_kind;

// ---------------------------------------------------------------------------------------
// y += W x
