//! The inner update of Algorithm 1 (lines 15-19) over the buffer Ψ, **batched**: the
//! entries go through G and D as matrices ([`crate::nn::batch`]), `b` at a time, in fixed
//! caller buffers ([`InnerWork`]; the navigator's are regions of its arena, see
//! [`crate::navigator::memory::adapt_batch`]).
//!
//! # The same bits as one entry at a time
//! Every function here gives exactly the bits of the batch-1 code it replaced
//! ([`Discriminator::ld_loss`] on one entry at a time, and the former one-entry-at-a-time
//! bodies of [`crate::adapt::adapt_generator_grad`] and
//! [`crate::adapt::adapt_generator_grad_cos`], which are now these passes with `b = 1`),
//! whatever `b`:
//! * the batched kernels give every vector the bits of the batch-1 kernel (the contract of
//!   [`crate::nn::batch`]), and every input keeps its segmentation (`[z; attr]` for G's first
//!   layer);
//! * every gradient element receives its `+=` in the order of today's loops: entry by
//!   entry, and within an entry real, fake, interpolate for D. The small vectors (biases,
//!   gains, D's output layer) are accumulated in an entry loop; a full weight gradient by one
//!   [`crate::nn::batch::outer_acc_batch_with`] per batch whose vectors are laid out in exactly
//!   that order (`alpha = 1` and the coefficient folded into `dy`: `1 · (c v) = c v`, and a
//!   zero row is skipped as the batch-1 loop skips it);
//! * G is not changed inside one inner update, so the features `x_t` are generated once
//!   ([`generate`]) and read by every pass (today's code regenerated them, with the same bits).
//!
//! `core/tests/batched_inner.rs` pins this against a transcription of the batch-1 code, for
//! batch sizes 1, 2, 3, n and more than n; whole episodes are checked against the f64 oracle
//! of `gman-tests` and between the host and the Cortex-M4F (QEMU).

use crate::adapt::ad_loss::{adapt_loss, cosine, AdaptLossKind};
use crate::error::{check_len, Result};
use crate::nets::discriminator::{DiscGrads, Discriminator, LdConfig, LdValue};
use crate::nets::generator::Generator;
use crate::nn::activation::{
    leaky_relu, leaky_relu_backward, leaky_relu_grad, leaky_relu_inplace, sigmoid_backward,
    sigmoid_inplace,
};
use crate::nn::batch::{matmul_acc, matmul_t_acc, outer_acc_batch_with};
use crate::nn::dense::DenseGrads;
use crate::nn::matrix::{axpy, dot};

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
    fn row(&self, t: usize) -> usize {
        if self.shared {
            0
        } else {
            t
        }
    }

    /// Rows (entries) `zs`, `xs` and `u2s` hold for `n` entries.
    #[inline]
    fn rows_for(&self, n: usize) -> usize {
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
fn head(s: &mut [f32], n: usize) -> &mut [f32] {
    let l = n.min(s.len());
    &mut s[..l]
}

/// Rows `t0 .. t0 + nb` of a row-major matrix with rows of `w` floats.
#[inline]
fn rows(s: &[f32], w: usize, t0: usize, nb: usize) -> Result<&[f32]> {
    let (a, e) = (t0 * w, (t0 + nb) * w);
    s.get(a..e).ok_or(crate::Error::Shape(crate::ShapeError {
        what: "inner.rows",
        expected: e,
        actual: s.len(),
    }))
}

impl InnerWork<'_> {
    fn check(&self) -> Result<()> {
        if self.b == 0 {
            return check_len("inner.b", 1, 0);
        }
        Ok(())
    }

    /// Fills the `b` rows of `self.attr` with `attr`.
    fn fill_attr(&mut self, attr: &[f32]) -> Result<()> {
        check_len("inner.attr", self.b * attr.len(), self.attr.len())?;
        if !attr.is_empty() {
            for r in self.attr.chunks_exact_mut(attr.len()) {
                r.copy_from_slice(attr);
            }
        }
        Ok(())
    }
}

/// `x_t = G(z_t, attr)` for the `n` noise vectors `zs` (`n x Z`) into `xs` (`n x F`),
/// `w.b` entries at a time.
pub fn generate(
    gen: &Generator<'_>,
    zs: &[f32],
    attr: &[f32],
    xs: &mut [f32],
    w: &mut InnerWork<'_>,
) -> Result<()> {
    w.check()?;
    gen.validate()?;
    let (zd, h, f) = (
        gen.in_dim().saturating_sub(attr.len()),
        gen.hidden(),
        gen.feat(),
    );
    check_len("generator.z+attr", gen.in_dim(), zd + attr.len())?;
    let n = xs.len() / f.max(1);
    check_len("inner.xs", n * f, xs.len())?;
    check_len("inner.zs", n * zd, zs.len())?;
    if w.b > 1 {
        w.fill_attr(attr)?;
    }
    let mut t0 = 0;
    while t0 < n {
        let nb = w.b.min(n - t0);
        let z = rows(zs, zd, t0, nb)?;
        with_rows(w, nb, (Some(z), attr, zd), |w, r| gen_hidden(gen, r, nb, w))?;
        let x = &mut xs[t0 * f..(t0 + nb) * f];
        gen.l2
            .forward_batch(&[head(w.h1, nb * h)], &[h], nb, head(w.u2, nb * f), x)?;
        sigmoid_inplace(x);
        t0 += nb;
    }
    Ok(())
}

/// G's forward pass for the `nb` noise rows `z` (`nb x Z`) with SE(y) `attr` into the first
/// `nb x F` floats of `w.mix`: the x_t of a batch of Ψ's entries, the bits [`generate`]
/// gives them (the pass L_ad's scores and L_D's pass run when Ψ holds no x_t). For
/// `1 <= nb <= w.b` (its callers' batches).
pub(crate) fn generate_mix(
    gen: &Generator<'_>,
    z: &[f32],
    attr: &[f32],
    nb: usize,
    w: &mut InnerWork<'_>,
) -> Result<()> {
    if w.b > 1 {
        w.fill_attr(attr)?;
    }
    // (`z`'s length is checked by G's first layer.)
    let zd = gen.in_dim().saturating_sub(attr.len());
    with_rows(w, nb, (Some(z), attr, zd), |w, r| {
        gen_forward_mix(gen, r, nb, w)
    })
}

/// G's first layer for `nb` rows: noise `z` (`nb x Z`) and attribute rows `ar` (`nb x A`)
/// into `w.u1`, `w.h1` (after the LeakyReLU).
fn gen_hidden(
    gen: &Generator<'_>,
    (z, ar): (&[f32], &[f32]),
    nb: usize,
    w: &mut InnerWork<'_>,
) -> Result<()> {
    let h = gen.hidden();
    let (zd, a) = (z.len() / nb.max(1), ar.len() / nb.max(1));
    let hb = head(w.h1, nb * h);
    gen.l1
        .forward_batch(&[z, ar], &[zd, a], nb, head(w.u1, nb * h), hb)?;
    leaky_relu_inplace(hb);
    Ok(())
}

/// G's forward pass for `nb` rows (see [`gen_hidden`]); the features go to `w.mix`.
fn gen_forward_mix(
    gen: &Generator<'_>,
    rows: (&[f32], &[f32]),
    nb: usize,
    w: &mut InnerWork<'_>,
) -> Result<()> {
    let (h, f) = (gen.hidden(), gen.feat());
    gen_hidden(gen, rows, nb, w)?;
    check_len("inner.mix", w.b * f, w.mix.len())?;
    let x = &mut w.mix[..nb * f];
    gen.l2
        .forward_batch(&[head(w.h1, nb * h)], &[h], nb, head(w.u2, nb * f), x)?;
    sigmoid_inplace(x);
    Ok(())
}

/// Runs `body` with the noise and attribute rows of a batch of `nb` rows: the noise rows
/// `z` when given (`nb x Z`), else `w.z` (filled by the caller); for one row the caller's
/// `attr` (no copy: the batch-1 buffers have no room for it), else `w.attr`.
fn with_rows<R>(
    w: &mut InnerWork<'_>,
    nb: usize,
    (z, attr, zd): (Option<&[f32]>, &[f32], usize),
    body: impl FnOnce(&mut InnerWork<'_>, (&[f32], &[f32])) -> Result<R>,
) -> Result<R> {
    if let (Some(z), 1) = (z, nb) {
        return body(w, (z, attr));
    }
    let (wz, war) = (core::mem::take(&mut w.z), core::mem::take(&mut w.attr));
    let a = attr.len();
    let zr = match z {
        Some(z) => Some(z),
        None => wz.get(..nb * zd),
    };
    let ar = if nb == 1 {
        Some(attr)
    } else {
        war.get(..nb * a)
    };
    let r = match (zr, ar) {
        (Some(zr), Some(ar)) => body(w, (zr, ar)),
        _ => Err(crate::Error::Shape(crate::ShapeError {
            what: "inner.rows",
            expected: nb * (zd + a),
            actual: wz.len() + war.len(),
        })),
    };
    w.z = wz;
    w.attr = war;
    r
}

/// D's hidden layer on `nb` inputs `x` (`nb x F`) into block `blk` of `w.du`/`w.dh`.
fn disc_hidden(
    disc: &Discriminator<'_>,
    x: &[f32],
    nb: usize,
    blk: usize,
    w: &mut InnerWork<'_>,
) -> Result<()> {
    let (dh, f) = (disc.hidden(), disc.in_dim());
    let at = blk * w.b * dh;
    let u = w.du.get_mut(at..at + nb * dh).unwrap_or(&mut []);
    let hb = w.dh.get_mut(at..at + nb * dh).unwrap_or(&mut []);
    disc.l1.forward_batch(&[x], &[f], nb, u, hb)?;
    for v in hb.iter_mut() {
        *v = leaky_relu(*v);
    }
    Ok(())
}

/// `v = gain ⊙ w2 ⊙ m` from the hidden activations of block `blk` into block `blk` of
/// `w.dv`, then `g = W1ᵀ v` into `w.g` (D's input gradients, [`Discriminator::input_grad`]).
fn disc_input_grad(
    disc: &Discriminator<'_>,
    nb: usize,
    blk: usize,
    w: &mut InnerWork<'_>,
) -> Result<()> {
    let (dh, f) = (disc.hidden(), disc.in_dim());
    let at = blk * w.b * dh;
    let hb = w.dh.get(at..at + nb * dh).unwrap_or(&[]);
    let vb = w.dv.get_mut(at..at + nb * dh).unwrap_or(&mut []);
    check_len("inner.dv", nb * dh, vb.len())?;
    for (vr, hr) in vb.chunks_exact_mut(dh).zip(hb.chunks_exact(dh)) {
        for (j, v) in vr.iter_mut().enumerate() {
            let gain = disc
                .l1
                .gain
                .map_or(1.0, |g| g.get(j).copied().unwrap_or(0.0));
            let m = leaky_relu_grad(hr.get(j).copied().unwrap_or(0.0));
            *v = gain * disc.w2.get(j).copied().unwrap_or(0.0) * m;
        }
    }
    let g = head(w.g, nb * f);
    g.fill(0.0);
    matmul_t_acc(&disc.l1.w, vb, nb, &mut [g], &[f])
}

/// `dot(w2, h) + b2` for row `i` of block `blk` of `w.dh`.
fn disc_score(disc: &Discriminator<'_>, w: &InnerWork<'_>, blk: usize, i: usize) -> f32 {
    let dh = disc.hidden();
    let at = (blk * w.b + i) * dh;
    dot(disc.w2, w.dh.get(at..at + dh).unwrap_or(&[])) + disc.b2
}

/// The sum over the `n` entries of Ψ of `inv ·` L_D of each entry alone (Eq. 1 with one
/// real sample `real[t]`, one generated sample `fake[t]` and the interpolation weight
/// `eps[t]`), and `∇_ω` of each entry's L_D (unscaled) added into `grads`: exactly what
/// calling [`Discriminator::ld_loss`] on every entry in order and summing its parts times
/// `inv` gives, bit for bit. `real` and `fake` are `n x F`.
#[allow(clippy::too_many_arguments)]
pub fn ld_grad_sum(
    disc: &Discriminator<'_>,
    real: &[f32],
    fake: &[f32],
    eps: &[f32],
    cfg: LdConfig,
    inv: f32,
    w: &mut InnerWork<'_>,
    grads: &mut DiscGrads<'_>,
) -> Result<LdValue> {
    ld_grad_sum_from(
        disc,
        real,
        fake,
        eps,
        cfg,
        inv,
        w,
        grads,
        LdValue::default(),
    )
}

/// [`ld_grad_sum`] continuing the sums `ld0` of earlier entries: called on consecutive
/// ranges of Ψ's entries (each range's `real`, `fake`, `eps`) with the previous call's
/// result, it gives the bits of one call over all of them (every `+=` in entry order; the
/// batch split never changes a bit). The sliced inner update runs it a few entries at a time.
#[allow(clippy::too_many_arguments)]
pub fn ld_grad_sum_from(
    disc: &Discriminator<'_>,
    real: &[f32],
    fake: &[f32],
    eps: &[f32],
    cfg: LdConfig,
    inv: f32,
    w: &mut InnerWork<'_>,
    grads: &mut DiscGrads<'_>,
    ld0: LdValue,
) -> Result<LdValue> {
    w.check()?;
    disc.validate()?;
    let (f, dh) = (disc.in_dim(), disc.hidden());
    let n = eps.len();
    check_len("ld.real", n * f, real.len())?;
    check_len("ld.fake", n * f, fake.len())?;
    let mut ld = ld0;
    if n == 0 || f == 0 {
        return Ok(ld);
    }
    let full = matches!(grads.l1, DenseGrads::Full { .. });
    let (b, b3) = (w.b, 3 * w.b);
    check_len("inner.dh", b3 * dh, w.dh.len())?;
    check_len("inner.dv", b3 * dh, w.dv.len())?;
    if disc.l1.gain.is_some() {
        check_len("inner.du", b3 * dh, w.du.len())?;
    }
    check_len("inner.w1g", b * dh, w.w1g.len())?;
    check_len("inner.g", b * f, w.g.len())?;
    check_len("inner.mix", b * f, w.mix.len())?;
    if full {
        check_len("inner.outer_x", b3 * f, w.outer_x.len())?;
        check_len("inner.outer_dy", b3 * dh, w.outer_dy.len())?;
    }
    let mut t0 = 0;
    while t0 < n {
        let nb = w.b.min(n - t0);
        let (sr, sf) = (rows(real, f, t0, nb)?, rows(fake, f, t0, nb)?);
        disc_hidden(disc, sr, nb, 0, w)?;
        disc_hidden(disc, sf, nb, 1, w)?;
        let mix = head(w.mix, nb * f);
        for (i, m) in mix.chunks_exact_mut(f).enumerate() {
            let e = eps[t0 + i];
            let (a, b) = (&sr[i * f..(i + 1) * f], &sf[i * f..(i + 1) * f]);
            for ((m, &a), &b) in m.iter_mut().zip(a).zip(b) {
                *m = e * a + (1.0 - e) * b;
            }
        }
        let mix = core::mem::take(&mut w.mix);
        let r = disc_hidden(disc, &mix[..nb * f], nb, 2, w);
        w.mix = mix;
        r?;
        disc_input_grad(disc, nb, 2, w)?;
        let w1g = head(w.w1g, nb * dh);
        w1g.fill(0.0);
        matmul_acc(&disc.l1.w, &[head(w.g, nb * f)], &[f], nb, w1g)?;
        for i in 0..nb {
            let v = ld_entry(
                disc,
                cfg,
                (&sr[i * f..(i + 1) * f], &sf[i * f..(i + 1) * f]),
                i,
                full,
                w,
                grads,
            )?;
            ld.loss += v.loss * inv;
            ld.mean_real += v.mean_real * inv;
            ld.mean_fake += v.mean_fake * inv;
            ld.penalty += v.penalty * inv;
        }
        if let DenseGrads::Full { w: gw, .. } = &mut grads.l1 {
            outer_acc_batch_with(
                disc.l1.w.kernels(),
                gw,
                &w.outer_dy[..3 * nb * dh],
                &[&w.outer_x[..3 * nb * f]],
                &[f],
                3 * nb,
                1.0,
            )?;
        }
        t0 += nb;
    }
    Ok(ld)
}

/// One entry (row `i` of the batch) of [`ld_grad_sum`]: [`Discriminator::ld_loss`] with
/// `n = 1` on the activations already in `w`. The small gradient vectors are accumulated
/// here; with a full `W1` gradient its three outer products are laid out in `w.outer_*`.
fn ld_entry(
    disc: &Discriminator<'_>,
    cfg: LdConfig,
    (sr, sf): (&[f32], &[f32]),
    i: usize,
    full: bool,
    w: &mut InnerWork<'_>,
    grads: &mut DiscGrads<'_>,
) -> Result<LdValue> {
    let (f, dh) = (disc.in_dim(), disc.hidden());
    let inv1 = 1.0f32;
    let mut out = LdValue::default();
    let dr = disc_score(disc, w, 0, i);
    out.mean_real += dr * inv1;
    score_grad(disc, cfg.critic_scale * inv1, 0, i, w, grads)?;
    let df = disc_score(disc, w, 1, i);
    out.mean_fake += df * inv1;
    score_grad(disc, -cfg.critic_scale * inv1, 1, i, w, grads)?;
    if full {
        let o = 3 * i * f;
        w.outer_x[o..o + f].copy_from_slice(sr);
        w.outer_x[o + f..o + 2 * f].copy_from_slice(sf);
    }
    // The penalty (Discriminator::accumulate_penalty_grad).
    let coef = -cfg.lambda * inv1;
    let g = &w.g[i * f..(i + 1) * f];
    let norm = libm::sqrtf(dot(g, g));
    let p = (norm - 1.0) * (norm - 1.0);
    let oy = (3 * i + 2) * dh;
    if norm <= 0.0 || coef == 0.0 {
        if full {
            // A zero row: the batched outer product skips it, as this entry adds nothing.
            w.outer_dy[oy..oy + dh].fill(0.0);
            w.outer_x[(3 * i + 2) * f..(3 * i + 3) * f].copy_from_slice(g);
        }
    } else {
        let c = coef * 2.0 * (norm - 1.0) / norm;
        let hm = &w.dh[(2 * w.b + i) * dh..(2 * w.b + i + 1) * dh];
        let wg = &w.w1g[i * dh..(i + 1) * dh];
        for j in 0..dh {
            let gain = disc
                .l1
                .gain
                .map_or(1.0, |g| g.get(j).copied().unwrap_or(0.0));
            let w2 = disc.w2.get(j).copied().unwrap_or(0.0);
            let m = leaky_relu_grad(hm[j]);
            if let Some(d) = grads.w2.get_mut(j) {
                *d += c * gain * m * wg[j];
            }
            if let DenseGrads::Gain { gain: dg, .. } = &mut grads.l1 {
                if let Some(d) = dg.get_mut(j) {
                    *d += c * w2 * m * wg[j];
                }
            }
        }
        if full {
            // outer_acc(w, v, [g], c): row j adds (c v_j) g.
            let vm = &w.dv[(2 * w.b + i) * dh..(2 * w.b + i + 1) * dh];
            for (o, &v) in w.outer_dy[oy..oy + dh].iter_mut().zip(vm) {
                *o = c * v;
            }
            w.outer_x[(3 * i + 2) * f..(3 * i + 3) * f].copy_from_slice(g);
        }
    }
    out.penalty += p * inv1;
    out.loss = cfg.critic_scale * (out.mean_real - out.mean_fake) - cfg.lambda * out.penalty;
    Ok(out)
}

/// `coef · ∂D/∂ω` for row `i` of block `blk` (Discriminator::accumulate_score_grad): the
/// small vectors here, the outer product's row `3 i + blk` laid out in `w.outer_dy` (its
/// input row is the caller's).
fn score_grad(
    disc: &Discriminator<'_>,
    coef: f32,
    blk: usize,
    i: usize,
    w: &mut InnerWork<'_>,
    grads: &mut DiscGrads<'_>,
) -> Result<()> {
    let dh = disc.hidden();
    let at = (blk * w.b + i) * dh;
    let h = &w.dh[at..at + dh];
    *grads.b2 += coef;
    axpy(coef, h, grads.w2);
    let v = &mut w.dv[at..at + dh];
    for (j, v) in v.iter_mut().enumerate() {
        let m = leaky_relu_grad(h[j]);
        *v = coef * disc.w2.get(j).copied().unwrap_or(0.0) * m;
    }
    let v = &w.dv[at..at + dh];
    match &mut grads.l1 {
        DenseGrads::None => {}
        DenseGrads::Full { b, .. } => {
            check_len("dense.db", dh, b.len())?;
            let oy = (3 * i + blk) * dh;
            let o = &mut w.outer_dy[oy..oy + dh];
            match disc.l1.gain {
                None => o.copy_from_slice(v),
                Some(g) => {
                    for ((o, &d), &gi) in o.iter_mut().zip(v).zip(g) {
                        *o = d * gi;
                    }
                }
            }
            for (bi, &d) in b.iter_mut().zip(v) {
                *bi += d;
            }
        }
        DenseGrads::Gain { gain, b } => {
            check_len("dense.dgain", dh, gain.len())?;
            check_len("dense.db", dh, b.len())?;
            let u = &w.du[at..at + dh];
            for ((gg, &d), &ui) in gain.iter_mut().zip(v).zip(u) {
                *gg += d * ui;
            }
            for (bi, &d) in b.iter_mut().zip(v) {
                *bi += d;
            }
        }
    }
    Ok(())
}

/// L_ad (Eq. 3) over Ψ and its θ gradient, batched: [`crate::adapt::adapt_generator_grad`]
/// (with `disc`) or [`crate::adapt::adapt_generator_grad_cos`] (`disc = None`; `obs` are the
/// observations). `xs` are the features [`generate`] made (`None`: regenerated from `zs`,
/// batch by batch, as the batch-1 functions do). `d`, `dd` (`n`) receive the scores and
/// `∂L/∂d_t`, `dprobs` (`n x 6`) `∂L/∂a_t`; the θ gradient is added into `grads1`/`grads2`.
#[allow(clippy::too_many_arguments)]
pub fn adapt_grad(
    kind: AdaptLossKind,
    gen: &Generator<'_>,
    disc: Option<&Discriminator<'_>>,
    inp: AdaptInputs<'_>,
    probs: &[f32],
    (d, dd, dprobs): (&mut [f32], &mut [f32], &mut [f32]),
    w: &mut InnerWork<'_>,
    grads1: &mut DenseGrads<'_>,
    grads2: &mut DenseGrads<'_>,
) -> Result<f32> {
    let loss = adapt_scores(kind, gen, disc, inp, probs, (d, dd, dprobs), w)?;
    // Pass 2.
    score_backward(gen, disc, inp, dd, w, grads1, grads2)?;
    Ok(loss)
}

/// [`adapt_grad`] without its θ gradient: the scores `d`, L_ad, `∂L/∂d_t` (`dd`) and
/// `∂L/∂a_t` (`dprobs`), every bit as [`adapt_grad`] computes them (its first pass; the θ
/// gradient is its second). For an inner rule that adapts only the actor head, which needs
/// `dprobs` and not θ's gradient.
#[allow(clippy::too_many_arguments)]
pub fn adapt_scores(
    kind: AdaptLossKind,
    gen: &Generator<'_>,
    disc: Option<&Discriminator<'_>>,
    inp: AdaptInputs<'_>,
    probs: &[f32],
    (d, dd, dprobs): (&mut [f32], &mut [f32], &mut [f32]),
    w: &mut InnerWork<'_>,
) -> Result<f32> {
    let n = d.len();
    let loss = adapt_scores_part(kind, gen, disc, inp, probs, (d, dd, dprobs), w, (0, n))?;
    loss.ok_or(crate::Error::Config {
        what: "adapt: no scores",
    })
}

/// Pass 1 of [`adapt_scores`] for the entries `t0 .. t1` only (the scores `d[t0..t1]`), and
/// once `t1` reaches the end L_ad with `dd` and `dprobs` (`Some(loss)`; before: `None`). Over
/// consecutive ranges it gives the bits of [`adapt_scores`] (each score is its own entry's).
#[allow(clippy::too_many_arguments)]
pub fn adapt_scores_part(
    kind: AdaptLossKind,
    gen: &Generator<'_>,
    disc: Option<&Discriminator<'_>>,
    inp: AdaptInputs<'_>,
    probs: &[f32],
    (d, dd, dprobs): (&mut [f32], &mut [f32], &mut [f32]),
    w: &mut InnerWork<'_>,
    (t_begin, t_end): (usize, usize),
) -> Result<Option<f32>> {
    let AdaptInputs {
        attr,
        zs,
        xs,
        obs,
        shared,
        ..
    } = inp;
    w.check()?;
    gen.validate()?;
    let (n, f) = (d.len(), gen.feat());
    let zd = gen.in_dim().saturating_sub(attr.len());
    let nr = inp.rows_for(n);
    check_len("adapt.zs", nr * zd, zs.len())?;
    check_len("adapt.dd", n, dd.len())?;
    match xs {
        Some(xs) => check_len("adapt.xs", nr * f, xs.len())?,
        None if shared => {
            return Err(crate::Error::Config {
                what: "adapt: shared inputs need their feature (xs)",
            })
        }
        None => {}
    }
    match disc {
        Some(dc) => check_len("adapt.disc_in", f, dc.in_dim())?,
        None => check_len("adapt.obs", n * f, obs.len())?,
    }
    if w.b > 1 {
        w.fill_attr(attr)?;
    }
    // Pass 1: the scores D(x_t) (or cos(x_t, s_t)).
    let t_end = t_end.min(n);
    let mut t0 = t_begin;
    while t0 < t_end {
        let nb = w.b.min(t_end - t0);
        if xs.is_none() {
            generate_mix(gen, rows(zs, zd, t0, nb)?, attr, nb, w)?;
        }
        let mix = core::mem::take(&mut w.mix);
        let x = match xs {
            Some(xs) => x_rows(xs, shared, f, (t0, nb), &mut *mix),
            None => rows(mix, f, 0, nb),
        };
        let r = x.and_then(|x| {
            let d = &mut d[t0..t0 + nb];
            match disc {
                Some(dc) => {
                    disc_hidden(dc, x, nb, 0, w)?;
                    for (i, di) in d.iter_mut().enumerate() {
                        *di = disc_score(dc, w, 0, i);
                    }
                    Ok(())
                }
                // (Without the feature `cossim` a navigator refuses CosSim models that adapt.)
                None if !cfg!(feature = "cossim") => Err(NO_COSSIM),
                None => {
                    for (i, di) in d.iter_mut().enumerate() {
                        let t = t0 + i;
                        *di = cosine(&x[i * f..(i + 1) * f], &obs[t * f..(t + 1) * f], None)?;
                    }
                    Ok(())
                }
            }
        });
        w.mix = mix;
        r?;
        t0 += nb;
    }
    if t_end < n {
        return Ok(None);
    }
    adapt_loss(kind, d, probs, dd, dprobs).map(Some)
}

/// `∇_θ Σ_t c_t D(G_θ(z_t, attr))` (with `disc`; consecutive entries with bit-identical
/// noise share one pass of G with their coefficients summed in order) or
/// `∇_θ Σ_t c_t cos(G_θ(z_t, attr), s_t)` (`disc = None`, `obs` the `s_t`), added into
/// `grads1`/`grads2`, batched: the back-propagation pass of [`adapt_grad`] with caller-chosen
/// coefficients `coef` ([`crate::adapt::generator_score_backward`]). `xs` as in [`adapt_grad`].
#[allow(clippy::too_many_arguments)]
pub fn score_backward(
    gen: &Generator<'_>,
    disc: Option<&Discriminator<'_>>,
    inp: AdaptInputs<'_>,
    coef: &[f32],
    w: &mut InnerWork<'_>,
    grads1: &mut DenseGrads<'_>,
    grads2: &mut DenseGrads<'_>,
) -> Result<()> {
    score_backward_part(gen, disc, inp, coef, w, (grads1, grads2), (0, usize::MAX)).map(|_| ())
}

/// [`score_backward`] from entry `t` (the first entry of a group, 0 at first) for at most
/// `batches` batches; returns the entry to continue from (`coef.len()` when done). Resumed
/// until done, it gives the bits of [`score_backward`] (the gradients receive every `+=` in
/// entry order; a batch never changes a bit).
pub fn score_backward_part(
    gen: &Generator<'_>,
    disc: Option<&Discriminator<'_>>,
    inp: AdaptInputs<'_>,
    coef: &[f32],
    w: &mut InnerWork<'_>,
    (grads1, grads2): (&mut DenseGrads<'_>, &mut DenseGrads<'_>),
    (t_start, batches): (usize, usize),
) -> Result<usize> {
    let AdaptInputs {
        attr,
        zs,
        xs,
        u2s,
        obs,
        shared,
    } = inp;
    w.check()?;
    gen.validate()?;
    let (n, f) = (coef.len(), gen.feat());
    let zd = gen.in_dim().saturating_sub(attr.len());
    let nr = inp.rows_for(n);
    check_len("adapt.zs", nr * zd, zs.len())?;
    if let Some(xs) = xs {
        check_len("adapt.xs", nr * f, xs.len())?;
    }
    if let Some(u2s) = u2s {
        check_len("adapt.u2s", nr * f, u2s.len())?;
        if xs.is_none() {
            return Err(crate::Error::Config {
                what: "adapt: G's pre-gain outputs (u2s) need the features (xs)",
            });
        }
    }
    check_len("inner.mix", w.b * f, w.mix.len())?;
    check_len("inner.g", w.b * f, w.g.len())?;
    if w.b > 1 {
        check_len("inner.z", w.b * zd, w.z.len())?;
        w.fill_attr(attr)?;
    }
    let grouped = disc.is_some();
    let mut t = t_start;
    let mut done = 0;
    while t < n && done < batches {
        done += 1;
        // A batch of up to `b` groups (their first entries' noise rows).
        let (t_first, mut nb) = (t, 0);
        while nb < w.b && t < n {
            if w.b > 1 {
                let r = inp.row(t);
                w.z[nb * zd..(nb + 1) * zd].copy_from_slice(&zs[r * zd..(r + 1) * zd]);
            }
            t = group_end(zs, zd, t, n, (grouped, shared));
            nb += 1;
        }
        let r1 = inp.row(t_first);
        let z1 = (nb == 1).then(|| &zs[r1 * zd..(r1 + 1) * zd]);
        let groups = Groups {
            zs,
            coef,
            zd,
            t: t_first,
            grouped,
            shared,
        };
        with_rows(w, nb, (z1, attr, zd), |w, r| {
            group_backward(
                gen,
                disc,
                r,
                (xs, u2s, obs),
                groups,
                nb,
                w,
                (&mut *grads1, &mut *grads2),
            )
        })?;
    }
    Ok(t.min(n))
}

/// The end of the group starting at entry `t`: with `grouped`, the run of entries whose
/// noise has the bits of entry `t`'s (with `shared` noise, every entry from `t` on); else
/// `t + 1`.
fn group_end(zs: &[f32], zd: usize, t: usize, n: usize, (grouped, shared): (bool, bool)) -> usize {
    if shared {
        return if grouped { n } else { t + 1 };
    }
    let z = &zs[t * zd..(t + 1) * zd];
    let mut end = t + 1;
    while grouped && end < n && same_bits(&zs[end * zd..(end + 1) * zd], z) {
        end += 1;
    }
    end
}

/// The groups of one batch of [`score_backward`], from entry `t` on.
#[derive(Clone, Copy)]
struct Groups<'a> {
    zs: &'a [f32],
    coef: &'a [f32],
    zd: usize,
    t: usize,
    grouped: bool,
    shared: bool,
}

impl<'a> Groups<'a> {
    /// `(first entry, summed coefficient)` of each group in order: `c = coef[t]`, then
    /// `c += coef[e]` for the group's other entries, as the batch-1 loop sums them.
    fn each(self) -> impl Iterator<Item = (usize, f32)> + 'a {
        let n = self.coef.len();
        let mut t = self.t;
        core::iter::from_fn(move || {
            if t >= n {
                return None;
            }
            let end = group_end(self.zs, self.zd, t, n, (self.grouped, self.shared));
            let mut c = self.coef[t];
            for &ce in &self.coef[t + 1..end] {
                c += ce;
            }
            let first = t;
            t = end;
            Some((first, c))
        })
    }
}

/// One batch of [`score_backward`]: G's forward pass (or the features `xs`), `∂L/∂x` from D's
/// input gradient or the cosine's, then G's backward pass.
#[allow(clippy::too_many_arguments)]
fn group_backward(
    gen: &Generator<'_>,
    disc: Option<&Discriminator<'_>>,
    rows: (&[f32], &[f32]),
    inputs: (Option<&[f32]>, Option<&[f32]>, &[f32]),
    groups: Groups<'_>,
    nb: usize,
    w: &mut InnerWork<'_>,
    (grads1, grads2): (&mut DenseGrads<'_>, &mut DenseGrads<'_>),
) -> Result<()> {
    group_forward(gen, disc, rows, inputs, groups, nb, w)?;
    gen_backward(gen, rows, nb, w, grads1, grads2)
}

/// The score backward pass of shared inputs ([`AdaptInputs::shared`]) with D, in two halves
/// the sliced update runs as two slices: `first` runs G's forward pass and D's input
/// gradient for the one group all entries form (into `w`'s activations, `mix` and `g`,
/// which nothing else writes between the two), the other half G's backward pass into the
/// gradients. Together the bits of [`score_backward_part`] on the same inputs.
pub(crate) fn shared_backward_half(
    gen: &Generator<'_>,
    disc: &Discriminator<'_>,
    inp: AdaptInputs<'_>,
    coef: &[f32],
    w: &mut InnerWork<'_>,
    (grads1, grads2): (&mut DenseGrads<'_>, &mut DenseGrads<'_>),
    first: bool,
) -> Result<()> {
    w.check()?;
    gen.validate()?;
    let f = gen.feat();
    let zd = gen.in_dim().saturating_sub(inp.attr.len());
    if !inp.shared || coef.is_empty() {
        return Err(crate::Error::Config {
            what: "adapt: the two-half backward pass needs shared inputs and entries",
        });
    }
    check_len("adapt.zs", zd, inp.zs.len())?;
    check_len("inner.mix", w.b * f, w.mix.len())?;
    check_len("inner.g", w.b * f, w.g.len())?;
    let rows = (inp.zs, inp.attr);
    if !first {
        return gen_backward(gen, rows, 1, w, grads1, grads2);
    }
    let groups = Groups {
        zs: inp.zs,
        coef,
        zd,
        t: 0,
        grouped: true,
        shared: true,
    };
    group_forward(
        gen,
        Some(disc),
        rows,
        (inp.xs, inp.u2s, inp.obs),
        groups,
        1,
        w,
    )
}

/// The first part of [`group_backward`]: G's forward pass (or the features `xs`) and
/// `∂L/∂x` from D's input gradient or the cosine's, into `w.g`.
fn group_forward(
    gen: &Generator<'_>,
    disc: Option<&Discriminator<'_>>,
    rows: (&[f32], &[f32]),
    (xs, u2s, obs): (Option<&[f32]>, Option<&[f32]>, &[f32]),
    groups: Groups<'_>,
    nb: usize,
    w: &mut InnerWork<'_>,
) -> Result<()> {
    let f = gen.feat();
    match xs {
        // Layer 2's forward pass is not needed when x is known and its pre-gain output
        // `u2` is either not used (no gain) or known too.
        Some(xs) if gen.l2.gain.is_none() || u2s.is_some() => {
            gen_hidden(gen, rows, nb, w)?;
            for (i, (t, _)) in groups.each().take(nb).enumerate() {
                let r = if groups.shared { 0 } else { t };
                w.mix[i * f..(i + 1) * f].copy_from_slice(&xs[r * f..(r + 1) * f]);
                if let Some(u2s) = u2s.filter(|_| gen.l2.gain.is_some()) {
                    w.u2[i * f..(i + 1) * f].copy_from_slice(&u2s[r * f..(r + 1) * f]);
                }
            }
        }
        _ => gen_forward_mix(gen, rows, nb, w)?,
    }
    match disc {
        Some(dc) => {
            let mix = core::mem::take(&mut w.mix);
            let r = disc_hidden(dc, &mix[..nb * f], nb, 0, w);
            w.mix = mix;
            r?;
            disc_input_grad(dc, nb, 0, w)?;
            for (i, (_, c)) in groups.each().take(nb).enumerate() {
                // `c * g` as the batch-1 code writes it (operand order kept for NaN payloads).
                #[allow(clippy::assign_op_pattern)]
                for o in w.g[i * f..(i + 1) * f].iter_mut() {
                    *o = c * *o;
                }
            }
        }
        None if !cfg!(feature = "cossim") => return Err(NO_COSSIM),
        None => {
            for (i, (t, c)) in groups.each().take(nb).enumerate() {
                let (x, g) = (&w.mix[i * f..(i + 1) * f], &mut w.g[i * f..(i + 1) * f]);
                cosine(x, &obs[t * f..(t + 1) * f], Some(&mut *g))?;
                g.iter_mut().for_each(|v| *v *= c);
            }
        }
    }
    Ok(())
}

/// G's backward pass for the `nb` batch rows (`rows` = noise and attribute rows, the
/// activations of their forward pass in `w`, the features in `mix`, `∂L/∂x` in `g`),
/// accumulating into `grads1`/`grads2` in row order ([`Generator::backward`] per row).
fn gen_backward(
    gen: &Generator<'_>,
    (z, ar): (&[f32], &[f32]),
    nb: usize,
    w: &mut InnerWork<'_>,
    grads1: &mut DenseGrads<'_>,
    grads2: &mut DenseGrads<'_>,
) -> Result<()> {
    let (h, f) = (gen.hidden(), gen.feat());
    let (zd, a) = (z.len() / nb.max(1), ar.len() / nb.max(1));
    let dpre2 = head(w.dpre2, nb * f);
    sigmoid_backward(head(w.mix, nb * f), head(w.g, nb * f), dpre2)?;
    let dh1 = head(w.dh1, nb * h);
    dh1.fill(0.0);
    gen.l2.backward_batch(
        &[head(w.h1, nb * h)],
        &[h],
        nb,
        head(w.u2, nb * f),
        dpre2,
        Some((&mut [&mut *dh1], &[h])),
        grads2,
        head(w.mix, nb * f),
    )?;
    let dpre1 = head(w.dpre1, nb * h);
    leaky_relu_backward(head(w.h1, nb * h), dh1, dpre1)?;
    gen.l1.backward_batch(
        &[z, ar],
        &[zd, a],
        nb,
        head(w.u1, nb * h),
        dpre1,
        None,
        grads1,
        dh1,
    )
}

fn same_bits(a: &[f32], b: &[f32]) -> bool {
    a.len() == b.len() && a.iter().zip(b).all(|(x, y)| x.to_bits() == y.to_bits())
}
