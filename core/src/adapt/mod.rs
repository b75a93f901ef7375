//! The adaptation loss L_ad of Eq. 3 and its gradients (the inner loop's objective).
//!
//! Paper (Eq. 3): `L_ad = −E_t[ D(x_t) · ‖a_t‖₂ ]` over the buffer Ψ, where `a_t` is the
//! policy's action-probability vector at step `t`.
//!
//! Reference implementation (see `shared/notes/gman-reference-facts.md`):
//! `L_ad = ‖ Σ_t a_t · (−D(x_t)) ‖₂`, the norm of a 6-vector. Selected with
//! [`AdaptLossKind::Reference`].
//!
//! Both give, per buffer entry, `∂L/∂D(x_t)` (which back-propagates through D's input gradient
//! into G's parameters θ) and `∂L/∂a_t` (which back-propagates through the softmax into the
//! adapted policy parameters φ).

pub(crate) mod ad_loss;
pub mod inner;

use crate::adapt::inner::{AdaptInputs, InnerWork};
use crate::error::{check_len, Result};
use crate::nets::discriminator::{DiscScratch, Discriminator};
use crate::nets::generator::{Generator, GeneratorCache, GeneratorScratch};
use crate::nn::activation::softmax_backward;
use crate::nn::dense::{Dense, DenseGrads};
use crate::NUM_ACTIONS;

pub use crate::adapt::ad_loss::{adapt_loss, cosine, AdaptLossKind};

/// Everything [`adapt_generator_grad`] writes besides the gradients (its batch-1 buffers:
/// the functions here are [`crate::adapt::inner`]'s batched passes with a batch of one).
#[derive(Debug)]
pub struct AdaptWork<'a> {
    /// G's activations (reused per buffer entry; `x` is not written, the feature goes to
    /// `disc.mix`).
    pub gen: GeneratorCache<'a>,
    /// G's backward scratch (`tmp` is not used).
    pub gen_scratch: GeneratorScratch<'a>,
    /// D's scratch (`mix` holds the generated feature).
    pub disc: DiscScratch<'a>,
    /// `n` floats: receives `D(x_t)`.
    pub d: &'a mut [f32],
    /// `n` floats: receives `∂L_ad/∂D(x_t)`.
    pub dd: &'a mut [f32],
    /// `F` floats (checked, not written).
    pub dx: &'a mut [f32],
}

impl AdaptWork<'_> {
    /// The buffers as a batch-of-one [`InnerWork`] (G's noise and attribute rows are then
    /// read in place, so it needs no room for them).
    fn inner(&mut self) -> InnerWork<'_> {
        InnerWork {
            b: 1,
            z: &mut [],
            attr: &mut [],
            u1: self.gen.u1,
            h1: self.gen.h1,
            u2: self.gen.u2,
            dpre2: self.gen_scratch.dpre2,
            dh1: self.gen_scratch.dh1,
            dpre1: self.gen_scratch.dpre1,
            du: self.disc.u,
            dh: self.disc.h,
            dv: self.disc.v,
            w1g: self.disc.w1g,
            g: self.disc.g,
            mix: self.disc.mix,
            outer_x: &mut [],
            outer_dy: &mut [],
        }
    }
}

/// L_ad over a buffer of `n` steps and its gradient with respect to G's parameters θ and to
/// the action probabilities.
///
/// `zs` holds the `n` noise vectors (`n x Z`) the buffer's features were generated with;
/// the features are regenerated from them (G is unchanged inside one adaptation window, so
/// this is exact, and it spares the device the `n x H` activations). Entries with
/// bit-identical noise (always the case with the reference's fixed zero noise) share one
/// forward/backward pass of G with their `∂L/∂x` summed. `probs` is `n x 6`.
/// The θ gradient is accumulated into `grads1`/`grads2`; `dprobs` (`n x 6`) is overwritten.
/// [`crate::adapt::inner::adapt_grad`] one entry at a time (the navigator's inner update runs it
/// batched: the same bits).
#[allow(clippy::too_many_arguments)]
pub fn adapt_generator_grad(
    kind: AdaptLossKind,
    gen: &Generator<'_>,
    disc: &Discriminator<'_>,
    attr: &[f32],
    zs: &[f32],
    probs: &[f32],
    w: &mut AdaptWork<'_>,
    grads1: &mut DenseGrads<'_>,
    grads2: &mut DenseGrads<'_>,
    dprobs: &mut [f32],
) -> Result<f32> {
    check_len("adapt.dx", gen.feat(), w.dx.len())?;
    check_len("adapt.disc_in", gen.feat(), disc.in_dim())?;
    adapt_one_by_one(
        kind,
        gen,
        Some(disc),
        (attr, zs, &[]),
        probs,
        w,
        (grads1, grads2),
        dprobs,
    )
}

/// [`adapt_generator_grad`] and [`adapt_generator_grad_cos`]: the batched passes with a
/// batch of one over `w`'s buffers.
#[allow(clippy::too_many_arguments)]
fn adapt_one_by_one(
    kind: AdaptLossKind,
    gen: &Generator<'_>,
    disc: Option<&Discriminator<'_>>,
    (attr, zs, obs): (&[f32], &[f32], &[f32]),
    probs: &[f32],
    w: &mut AdaptWork<'_>,
    (grads1, grads2): (&mut DenseGrads<'_>, &mut DenseGrads<'_>),
    dprobs: &mut [f32],
) -> Result<f32> {
    let inp = AdaptInputs {
        attr,
        zs,
        xs: None,
        u2s: None,
        obs,
        shared: false,
    };
    let AdaptWork { d, dd, .. } = w;
    let (d, dd) = (core::mem::take(d), core::mem::take(dd));
    let r = inner::adapt_grad(
        kind,
        gen,
        disc,
        inp,
        probs,
        (&mut *d, &mut *dd, dprobs),
        &mut w.inner(),
        grads1,
        grads2,
    );
    w.d = d;
    w.dd = dd;
    r
}

/// Accumulates `∇_θ Σ_t c_t D(G_θ(z_t, attr))` into `grads1`/`grads2`: the back-propagation
/// pass of [`adapt_generator_grad`] with caller-chosen per-entry coefficients `coef` (`n`
/// floats; `zs` is `n x Z`). With `coef = ∂L_ad/∂d_t` it is L_ad's θ gradient; a host-side
/// meta-gradient uses it for vector-Jacobian products of other functions of the scores
/// `d_t = D(x_t)`. Only `w.gen`, `w.gen_scratch` and `w.disc` are written
/// ([`crate::adapt::inner::score_backward`] one entry at a time).
#[allow(clippy::too_many_arguments)]
pub fn generator_score_backward(
    gen: &Generator<'_>,
    disc: &Discriminator<'_>,
    attr: &[f32],
    zs: &[f32],
    coef: &[f32],
    w: &mut AdaptWork<'_>,
    grads1: &mut DenseGrads<'_>,
    grads2: &mut DenseGrads<'_>,
) -> Result<()> {
    check_len("adapt.dx", gen.feat(), w.dx.len())?;
    check_len("adapt.disc_in", gen.feat(), disc.in_dim())?;
    let inp = AdaptInputs {
        attr,
        zs,
        xs: None,
        u2s: None,
        obs: &[],
        shared: false,
    };
    inner::score_backward(gen, Some(disc), inp, coef, &mut w.inner(), grads1, grads2)
}

/// L_ad with the cosine similarity `cos(x_t, s_t)` between each generated feature and the
/// observation it was generated with, in place of `D(x_t)`: the "CosSim" variant of the
/// environmental meta discriminator (paper Table 3). `obs` holds the buffer's observations
/// (`n x F`); the other arguments are those of [`adapt_generator_grad`] (D's scratch in `w`
/// holds the features and input gradients). Accumulates the θ gradient into
/// `grads1`/`grads2`, overwrites `dprobs`.
#[allow(clippy::too_many_arguments)]
pub fn adapt_generator_grad_cos(
    kind: AdaptLossKind,
    gen: &Generator<'_>,
    attr: &[f32],
    zs: &[f32],
    obs: &[f32],
    probs: &[f32],
    w: &mut AdaptWork<'_>,
    grads1: &mut DenseGrads<'_>,
    grads2: &mut DenseGrads<'_>,
    dprobs: &mut [f32],
) -> Result<f32> {
    check_len("adapt.dx", gen.feat(), w.dx.len())?;
    adapt_one_by_one(
        kind,
        gen,
        None,
        (attr, zs, obs),
        probs,
        w,
        (grads1, grads2),
        dprobs,
    )
}

/// The actor head's (φ's) gradient of L_ad (Eq. 3), accumulated into `grads`: for every
/// entry `t` of Ψ, `dlogits_t = J_softmax(p_t) ∂L/∂p_t` back through the head `y = W h_t + b`
/// (and its gains in the Efficient mode). `probs` and `dprobs` are `n x 6` (from
/// [`adapt_loss`]), `hidden` is `n x LH` (the LSTM states Ψ_h the actions were taken in).
/// `dlogits` (6) and `actor_u` (6; used when the head has gains) are scratch. The on-device
/// inner loop and the host's second-order meta-gradient both use this one function.
#[allow(clippy::too_many_arguments)]
pub fn actor_head_grad(
    head: &Dense<'_>,
    probs: &[f32],
    dprobs: &[f32],
    hidden: &[f32],
    n: usize,
    dlogits: &mut [f32],
    actor_u: &mut [f32],
    grads: &mut DenseGrads<'_>,
) -> Result<()> {
    let lh = head.in_dim();
    check_len("actor_head.probs", n * NUM_ACTIONS, probs.len())?;
    check_len("actor_head.dprobs", n * NUM_ACTIONS, dprobs.len())?;
    check_len("actor_head.hidden", n * lh, hidden.len())?;
    let mut logits = [0.0f32; NUM_ACTIONS];
    let mut tmp = [0.0f32; NUM_ACTIONS];
    for t in 0..n {
        let p = &probs[t * NUM_ACTIONS..(t + 1) * NUM_ACTIONS];
        let dp = &dprobs[t * NUM_ACTIONS..(t + 1) * NUM_ACTIONS];
        softmax_backward(p, dp, dlogits)?;
        let ht = &hidden[t * lh..(t + 1) * lh];
        if head.gain.is_some() {
            head.forward(&[ht], actor_u, &mut logits)?;
        }
        head.backward(&[ht], actor_u, dlogits, None, grads, &mut tmp)?;
    }
    Ok(())
}
