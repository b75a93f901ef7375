//! L_ad (Eq. 3) over Ψ: the scores D(x_t) or cos(x_t, s_t) and the loss's gradients
//! ([`adapt_scores`], [`adapt_scores_part`]), and with θ's gradient ([`adapt_grad`]).

use crate::adapt::ad_loss::{adapt_loss, cosine, AdaptLossKind};
use crate::adapt::inner::backward::score_backward;
use crate::adapt::inner::disc::{disc_hidden, disc_score};
use crate::adapt::inner::forward::generate_mix;
use crate::adapt::inner::work::{rows, x_rows, AdaptInputs, InnerWork, NO_COSSIM};
use crate::error::{check_len, Result};
use crate::nets::discriminator::Discriminator;
use crate::nets::generator::Generator;
use crate::nn::dense::DenseGrads;

/// L_ad (Eq. 3) over Ψ and its θ gradient, batched: [`crate::adapt::adapt_generator_grad`]
/// (with `disc`) or [`crate::adapt::adapt_generator_grad_cos`] (`disc = None`; `obs` are the
/// observations). `xs` are the features [`generate`] made (`None`: regenerated from `zs`,
/// batch by batch, as the batch-1 functions do). `d`, `dd` (`n`) receive the scores and
/// `∂L/∂d_t`, `dprobs` (`n x 6`) `∂L/∂a_t`; the θ gradient is added into `grads1`/`grads2`.
///
/// [`generate`]: crate::adapt::inner::generate
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
