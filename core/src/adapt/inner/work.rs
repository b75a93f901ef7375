//! What every pass of the inner update shares: the work buffers ([`InnerWorkOf`]), the
//! inputs of L_ad ([`AdaptInputs`]), the error of CosSim without its feature, and the row
//! helpers.

use crate::error::{check_len, Result};

/// The error of an adapting CosSim model in a build without the feature `cossim`.
pub const NO_COSSIM: crate::Error = crate::Error::Config {
    what: "CosSim EMD: needs gman-core's feature `cossim`",
};
/// Buffers of the batched inner update for batches of up to `b` entries (`b >= 1`).
/// `Z, A, H, F` are G's noise, attribute, hidden and feature widths, `DH` D's hidden width;
/// "gain" buffers are needed only when the layer has a gain (else they may be empty), the
/// `outer_*` ones only when D's `W1` gradient is full.
#[derive(Debug, Default)]
pub struct InnerWorkOf<T> {
    /// Entries per batch.
    pub b: usize,
    /// `b x Z`: the noise of each entry of a batch.
    pub z: T,
    /// `b x A`: the attribute, repeated.
    pub attr: T,
    /// `b x H` (gain): `W1 [z; a]`.
    pub u1: T,
    /// `b x H`: G's hidden activation.
    pub h1: T,
    /// `b x F` (gain): `W2 h1`.
    pub u2: T,
    /// `b x F`.
    pub dpre2: T,
    /// `b x H`.
    pub dh1: T,
    /// `b x H`.
    pub dpre1: T,
    /// `3b x DH` (gain): D's `W1 v` for the real, fake and interpolated inputs (3 blocks).
    pub du: T,
    /// `3b x DH`: D's hidden activations (3 blocks).
    pub dh: T,
    /// `3b x DH`: `gain ⊙ w2 ⊙ m` and hidden-layer gradients (3 blocks).
    pub dv: T,
    /// `b x DH`: `W1 g`.
    pub w1g: T,
    /// `b x F`: D's input gradients.
    pub g: T,
    /// `b x F`: interpolates, features, G's backward scratch.
    pub mix: T,
    /// `3b x F` (full `W1` gradient of D): the outer products' inputs, in entry order.
    pub outer_x: T,
    /// `3b x DH` (full `W1` gradient of D): their output gradients.
    pub outer_dy: T,
}

/// [`InnerWorkOf`] over mutable slices: the buffers the inner update's functions write.
pub type InnerWork<'a> = InnerWorkOf<&'a mut [f32]>;

/// What L_ad is computed on: SE(y), the entries' noise (`n x Z`), their features
/// (`n x F`; `None`: regenerated from the noise) and observations (`n x F`; read by CosSim
/// only, may be empty with D).
#[derive(Clone, Copy, Debug)]
pub struct AdaptInputs<'a> {
    /// The attribute vector SE(y).
    pub attr: &'a [f32],
    /// `n x Z` noise.
    pub zs: &'a [f32],
    /// `n x F` features made by [`generate`], or `None`.
    ///
    /// [`generate`]: crate::adapt::inner::generate
    pub xs: Option<&'a [f32]>,
    /// `n x F` pre-gain outputs `W2 h1` of G's layer 2 for the same entries (a layer 2 with
    /// gains, Efficient mode), or `None`: with them and `xs`, L_ad's backward pass runs no
    /// forward pass of G's layer 2 (the same bits: they are what that pass gives).
    pub u2s: Option<&'a [f32]>,
    /// `n x F` observations (CosSim).
    pub obs: &'a [f32],
    /// Every entry has the same noise, feature and pre-gain output (G's noise is zero and
    /// θ is fixed within the update): `zs`, `xs` and `u2s` then hold that one row (`Z`,
    /// `F`, `F` floats) for all `n` entries, with the bits `n` copies of it give.
    pub shared: bool,
}

impl AdaptInputs<'_> {
    /// The row of `zs`, `xs` and `u2s` that holds entry `t`'s.
    #[inline]
    pub(super) fn row(&self, t: usize) -> usize {
        if self.shared {
            0
        } else {
            t
        }
    }

    /// Rows (entries) `zs`, `xs` and `u2s` hold for `n` entries.
    #[inline]
    pub(super) fn rows_for(&self, n: usize) -> usize {
        if self.shared {
            1
        } else {
            n
        }
    }
}

/// The features of entries `t0 .. t0 + nb` as `nb x F` rows: `xs`'s own rows, or for
/// `shared` inputs its one row, as is for one entry, else copied `nb` times into `mix`.
pub(crate) fn x_rows<'a>(
    xs: &'a [f32],
    shared: bool,
    f: usize,
    (t0, nb): (usize, usize),
    mix: &'a mut [f32],
) -> Result<&'a [f32]> {
    if !shared {
        return rows(xs, f, t0, nb);
    }
    let x = rows(xs, f, 0, 1)?;
    if nb == 1 {
        return Ok(x);
    }
    let len = mix.len();
    let m = mix
        .get_mut(..nb * f)
        .ok_or(crate::Error::Shape(crate::ShapeError {
            what: "inner.mix",
            expected: nb * f,
            actual: len,
        }))?;
    for r in m.chunks_exact_mut(f.max(1)) {
        r.copy_from_slice(x);
    }
    Ok(m)
}

/// The first `n` floats of `s` (all of it when shorter: the kernels then report the
/// length error).
#[inline]
pub(super) fn head(s: &mut [f32], n: usize) -> &mut [f32] {
    let l = n.min(s.len());
    &mut s[..l]
}

/// Rows `t0 .. t0 + nb` of a row-major matrix with rows of `w` floats.
#[inline]
pub(super) fn rows(s: &[f32], w: usize, t0: usize, nb: usize) -> Result<&[f32]> {
    let (a, e) = (t0 * w, (t0 + nb) * w);
    s.get(a..e).ok_or(crate::Error::Shape(crate::ShapeError {
        what: "inner.rows",
        expected: e,
        actual: s.len(),
    }))
}

impl InnerWork<'_> {
    pub(super) fn check(&self) -> Result<()> {
        if self.b == 0 {
            return check_len("inner.b", 1, 0);
        }
        Ok(())
    }

    /// Fills the `b` rows of `self.attr` with `attr`.
    pub(super) fn fill_attr(&mut self, attr: &[f32]) -> Result<()> {
        check_len("inner.attr", self.b * attr.len(), self.attr.len())?;
        if !attr.is_empty() {
            for r in self.attr.chunks_exact_mut(attr.len()) {
                r.copy_from_slice(attr);
            }
        }
        Ok(())
    }
}
