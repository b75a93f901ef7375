//! θ's gradient of a weighted sum of scores, batched ([`score_backward`]): entries with the
//! same noise grouped, G's forward pass, `∂L/∂x` from D or the cosine, G's backward pass.

use crate::adapt::ad_loss::cosine;
use crate::adapt::inner::disc::{disc_hidden, disc_input_grad};
use crate::adapt::inner::forward::{gen_forward_mix, gen_hidden, with_rows};
use crate::adapt::inner::work::{head, AdaptInputs, InnerWork, NO_COSSIM};
use crate::error::{check_len, Result};
use crate::nets::discriminator::Discriminator;
use crate::nets::generator::Generator;
use crate::nn::activation::{leaky_relu_backward, sigmoid_backward};
use crate::nn::dense::DenseGrads;

/// `∇_θ Σ_t c_t D(G_θ(z_t, attr))` (with `disc`; consecutive entries with bit-identical
/// noise share one pass of G with their coefficients summed in order) or
/// `∇_θ Σ_t c_t cos(G_θ(z_t, attr), s_t)` (`disc = None`, `obs` the `s_t`), added into
/// `grads1`/`grads2`, batched: the back-propagation pass of [`adapt_grad`] with caller-chosen
/// coefficients `coef` ([`crate::adapt::generator_score_backward`]). `xs` as in [`adapt_grad`].
///
/// [`adapt_grad`]: crate::adapt::inner::adapt_grad
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
