//! D's side, batched: its hidden layer, score and input gradient on a batch, and L_D with its
//! ω gradient over Ψ ([`ld_grad_sum`], [`ld_grad_sum_from`]).

use crate::adapt::inner::work::{head, rows, InnerWork};
use crate::error::{check_len, Result};
use crate::nets::discriminator::{DiscGrads, Discriminator, LdConfig, LdValue};
use crate::nn::activation::{leaky_relu, leaky_relu_grad};
use crate::nn::batch::{matmul_acc, matmul_t_acc, outer_acc_batch_with};
use crate::nn::dense::DenseGrads;
use crate::nn::matrix::{axpy, dot};

/// D's hidden layer on `nb` inputs `x` (`nb x F`) into block `blk` of `w.du`/`w.dh`.
pub(super) fn disc_hidden(
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
pub(super) fn disc_input_grad(
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
pub(super) fn disc_score(disc: &Discriminator<'_>, w: &InnerWork<'_>, blk: usize, i: usize) -> f32 {
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
