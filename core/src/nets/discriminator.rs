//! The discriminator D of the environmental meta discriminator (paper Sec. 4.2), parameters ω,
//! and the adversarial losses of Eq. 1 (L_D, WGAN-GP) and Eq. 2 (L_G).
//!
//! ```text
//! D(v) = w2 · LeakyReLU_0.2( gain ⊙ (W1 v) + b1 ) + b2
//! ```
//!
//! # The gradient penalty in closed form
//! For this two-layer LeakyReLU critic the input gradient is piecewise constant in `v`:
//! with the activation slopes `m_j ∈ {1, 0.2}` at `v`,
//!
//! ```text
//! g(v) = ∇_v D(v) = W1ᵀ u,      u = gain ⊙ w2 ⊙ m
//! ```
//!
//! so the penalty `P = (‖g‖ − 1)²` has, with `c = 2 (‖g‖ − 1) / ‖g‖` (a.e., the slopes do not
//! move under an infinitesimal parameter change):
//!
//! ```text
//! ∂P/∂W1    = c · u gᵀ                       (outer product, DH x F)
//! ∂P/∂w2_j  = c · gain_j m_j (W1 g)_j
//! ∂P/∂gain_j = c · w2_j  m_j (W1 g)_j
//! ∂P/∂b1 = ∂P/∂b2 = 0
//! ```
//!
//! This is exact (it is what double back-propagation computes) at a cost of two extra
//! matrix-vector products per penalised sample, and needs no second-order autodiff on device.

use crate::error::{check_len, Result};
use crate::nn::activation::{leaky_relu, leaky_relu_grad};
use crate::nn::dense::{Dense, DenseGrads};
use crate::nn::matrix::{axpy, dot};

/// A read-only view of D.
#[derive(Clone, Copy, Debug)]
pub struct Discriminator<'a> {
    /// Hidden layer, `DH x F`.
    pub l1: Dense<'a>,
    /// Output weights, `DH`.
    pub w2: &'a [f32],
    /// Output bias.
    pub b2: f32,
}

/// Gradient accumulators (`+=`) of D's parameters ω.
#[derive(Debug)]
pub struct DiscGrads<'g> {
    /// Hidden layer (full `W1, b1`, or `gain, b1` in the parameter-efficient mode).
    pub l1: DenseGrads<'g>,
    /// Output weights.
    pub w2: &'g mut [f32],
    /// Output bias.
    pub b2: &'g mut f32,
}

/// Scratch of D's passes: `u`, `h`, `v`, `w1g` have `DH` floats, `g` and `mix` have `F`.
#[derive(Debug)]
pub struct DiscScratch<'a> {
    /// `W1 x` before the gain (`DH`).
    pub u: &'a mut [f32],
    /// Hidden activation (`DH`).
    pub h: &'a mut [f32],
    /// `gain ⊙ w2 ⊙ m` or a hidden-layer gradient (`DH`).
    pub v: &'a mut [f32],
    /// `W1 g` (`DH`).
    pub w1g: &'a mut [f32],
    /// Input gradient `g` (`F`).
    pub g: &'a mut [f32],
    /// The interpolate `x̃` (`F`).
    pub mix: &'a mut [f32],
}

/// Hyper-parameters of L_D (Eq. 1).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LdConfig {
    /// Gradient-penalty coefficient λ (paper: 10).
    pub lambda: f32,
    /// Factor on the critic terms `E[D(s)] − E[D(x)]`: 1 in the paper, 10 in the reference
    /// implementation (see `shared/notes`).
    pub critic_scale: f32,
}

impl Default for LdConfig {
    fn default() -> Self {
        LdConfig {
            lambda: 10.0,
            critic_scale: 1.0,
        }
    }
}

/// The value of L_D and its parts.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct LdValue {
    /// `critic_scale (E[D(s)] − E[D(x)]) − λ E[(‖∇D(x̃)‖ − 1)²]`, the quantity D ascends.
    pub loss: f32,
    /// `E[D(s)]` over the real (observation) samples.
    pub mean_real: f32,
    /// `E[D(x)]` over the generated samples.
    pub mean_fake: f32,
    /// `E[(‖∇D(x̃)‖ − 1)²]`.
    pub penalty: f32,
}

/// Where the gradient penalty is differentiated: a sample of a two-layer LeakyReLU critic
/// `w2 · LeakyReLU(gain ⊙ (W1 v) + b1) + b2` after its forward pass and input gradient.
#[derive(Clone, Copy, Debug)]
pub struct PenaltyPoint<'s> {
    /// Hidden activation after LeakyReLU (`DH`): gives the slopes `m`.
    pub h: &'s [f32],
    /// `u = gain ⊙ w2 ⊙ m` (`DH`).
    pub u: &'s [f32],
    /// The input gradient `g` over the penalised input columns (the first `g.len()`).
    pub g: &'s [f32],
    /// Zeros for the remaining input columns, which the penalty does not differentiate
    /// (the conditional critic's attribute columns of `gman-host-sim`); empty for D.
    pub zeros: &'s [f32],
}

/// The closed form of the module docs, the one implementation of the WGAN-GP penalty's
/// parameter gradient (used by D's L_D here and by the host's conditional pre-training
/// critic): adds `coef · ∂P/∂ω` for `P = (‖g‖ − 1)²` into `grads` (`W1` or the gains, and
/// `w2`; `b1`, `b2` get 0) using `w1g` (`DH`) as scratch. Returns `(P, ‖g‖)`.
pub fn add_penalty_grad(
    l1: &Dense<'_>,
    w2: &[f32],
    at: PenaltyPoint<'_>,
    coef: f32,
    w1g: &mut [f32],
    grads: &mut DiscGrads<'_>,
) -> Result<(f32, f32)> {
    let norm = libm::sqrtf(dot(at.g, at.g));
    let p = (norm - 1.0) * (norm - 1.0);
    if norm <= 0.0 || coef == 0.0 {
        return Ok((p, norm));
    }
    let c = coef * 2.0 * (norm - 1.0) / norm;
    let with_zeros = [at.g, at.zeros];
    let g_cols: &[&[f32]] = if at.zeros.is_empty() {
        &with_zeros[..1]
    } else {
        &with_zeros
    };
    // W1 g (columns beyond g multiply zeros)
    w1g.fill(0.0);
    l1.w.matvec_acc(g_cols, w1g)?;
    for j in 0..l1.out_dim() {
        let gain = l1.gain.map_or(1.0, |g| g.get(j).copied().unwrap_or(0.0));
        let w2j = w2.get(j).copied().unwrap_or(0.0);
        let m = leaky_relu_grad(at.h.get(j).copied().unwrap_or(0.0));
        let wg = w1g.get(j).copied().unwrap_or(0.0);
        if let Some(d) = grads.w2.get_mut(j) {
            *d += c * gain * m * wg;
        }
        if let DenseGrads::Gain { gain: dg, .. } = &mut grads.l1 {
            if let Some(d) = dg.get_mut(j) {
                *d += c * w2j * m * wg;
            }
        }
    }
    if let DenseGrads::Full { w, .. } = &mut grads.l1 {
        // c · u gᵀ (the zero columns get c · u · 0)
        crate::nn::batch::outer_acc(w, at.u, g_cols, c)?;
    }
    Ok((p, norm))
}

impl<'a> Discriminator<'a> {
    /// Input width F.
    #[inline]
    pub fn in_dim(&self) -> usize {
        self.l1.in_dim()
    }

    /// Hidden width DH.
    #[inline]
    pub fn hidden(&self) -> usize {
        self.l1.out_dim()
    }

    /// Checks the tensors against each other.
    pub fn validate(&self) -> Result<()> {
        self.l1.validate()?;
        check_len("discriminator.w2", self.hidden(), self.w2.len())
    }

    /// `D(x)`; leaves `W1 x` in `s.u` and the hidden activation in `s.h`.
    pub fn score(&self, x: &[f32], s: &mut DiscScratch<'_>) -> Result<f32> {
        self.validate()?;
        check_len("discriminator.x", self.in_dim(), x.len())?;
        self.l1.forward(&[x], s.u, s.h)?;
        for v in s.h.iter_mut() {
            *v = leaky_relu(*v);
        }
        Ok(dot(self.w2, s.h) + self.b2)
    }

    /// `g = ∇_x D(x)` into `s.g`, for the `x` whose activation is in `s.h` (call
    /// [`Discriminator::score`] first). Leaves `u = gain ⊙ w2 ⊙ m` in `s.v`.
    pub fn input_grad(&self, s: &mut DiscScratch<'_>) -> Result<()> {
        check_len("discriminator.g", self.in_dim(), s.g.len())?;
        check_len("discriminator.v", self.hidden(), s.v.len())?;
        for (j, v) in s.v.iter_mut().enumerate() {
            let gain = self
                .l1
                .gain
                .map_or(1.0, |g| g.get(j).copied().unwrap_or(0.0));
            let m = leaky_relu_grad(s.h.get(j).copied().unwrap_or(0.0));
            *v = gain * self.w2.get(j).copied().unwrap_or(0.0) * m;
        }
        s.g.fill(0.0);
        self.l1.w.matvec_t_acc(s.v, &mut [&mut *s.g])
    }

    /// Adds `coef · ∂D(x)/∂ω` into `grads`, for the `x` just scored (activations in `s`).
    fn accumulate_score_grad(
        &self,
        x: &[f32],
        coef: f32,
        s: &mut DiscScratch<'_>,
        grads: &mut DiscGrads<'_>,
    ) -> Result<()> {
        *grads.b2 += coef;
        axpy(coef, s.h, grads.w2);
        // dD/dpre_j = w2_j m_j
        for (j, v) in s.v.iter_mut().enumerate() {
            let m = leaky_relu_grad(s.h.get(j).copied().unwrap_or(0.0));
            *v = coef * self.w2.get(j).copied().unwrap_or(0.0) * m;
        }
        self.l1.backward(&[x], s.u, s.v, None, &mut grads.l1, s.w1g)
    }

    /// Adds `coef · ∂P/∂ω` for the penalty `P = (‖∇D(x̃)‖ − 1)²` at the `x̃` whose activations
    /// and input gradient are in `s` (after `score` + `input_grad`). Returns `P`.
    fn accumulate_penalty_grad(
        &self,
        coef: f32,
        s: &mut DiscScratch<'_>,
        grads: &mut DiscGrads<'_>,
    ) -> Result<f32> {
        let at = PenaltyPoint {
            h: s.h,
            u: s.v,
            g: s.g,
            zeros: &[],
        };
        Ok(add_penalty_grad(&self.l1, self.w2, at, coef, s.w1g, grads)?.0)
    }

    /// L_D of Eq. 1 over `n` real samples `real` (`n x F`, the observations Ψ_s) and `n`
    /// generated samples `fake` (`n x F`, Ψ_x), with interpolation weights `eps` (`n`, each in
    /// `[0, 1]`, drawn by the caller) pairing `real[t]` with `fake[t]`.
    ///
    /// When `grads` is given, adds `∇_ω L_D` into it (the ascent direction of line 16 of
    /// Algorithm 1).
    pub fn ld_loss(
        &self,
        real: &[f32],
        fake: &[f32],
        eps: &[f32],
        cfg: LdConfig,
        s: &mut DiscScratch<'_>,
        mut grads: Option<&mut DiscGrads<'_>>,
    ) -> Result<LdValue> {
        self.validate()?;
        let f = self.in_dim();
        let n = eps.len();
        check_len("ld.real", n * f, real.len())?;
        check_len("ld.fake", n * f, fake.len())?;
        check_len("ld.mix", f, s.mix.len())?;
        if n == 0 || f == 0 {
            return Ok(LdValue::default());
        }
        let inv = 1.0 / n as f32;
        let mut out = LdValue::default();
        for t in 0..n {
            let sr = &real[t * f..(t + 1) * f];
            let sf = &fake[t * f..(t + 1) * f];
            let dr = self.score(sr, s)?;
            out.mean_real += dr * inv;
            if let Some(g) = grads.as_deref_mut() {
                self.accumulate_score_grad(sr, cfg.critic_scale * inv, s, g)?;
            }
            let df = self.score(sf, s)?;
            out.mean_fake += df * inv;
            if let Some(g) = grads.as_deref_mut() {
                self.accumulate_score_grad(sf, -cfg.critic_scale * inv, s, g)?;
            }
            let e = eps[t];
            for ((m, &a), &b) in s.mix.iter_mut().zip(sr).zip(sf) {
                *m = e * a + (1.0 - e) * b;
            }
            // score needs the interpolate as a separate borrow from the scratch.
            let mix_copy = core::mem::take(&mut s.mix);
            let r = self.score(mix_copy, s);
            s.mix = mix_copy;
            r?;
            self.input_grad(s)?;
            let p = match grads.as_deref_mut() {
                Some(g) => self.accumulate_penalty_grad(-cfg.lambda * inv, s, g)?,
                None => {
                    let norm = libm::sqrtf(dot(s.g, s.g));
                    (norm - 1.0) * (norm - 1.0)
                }
            };
            out.penalty += p * inv;
        }
        out.loss = cfg.critic_scale * (out.mean_real - out.mean_fake) - cfg.lambda * out.penalty;
        Ok(out)
    }

    /// L_G of Eq. 2 over generated samples `fake` (`n x F`): `−E[D(x)]`. When `dfake` is given
    /// (`n x F`), writes `∂L_G/∂x_t = −∇D(x_t) / n` into it.
    pub fn lg_loss(
        &self,
        fake: &[f32],
        n: usize,
        s: &mut DiscScratch<'_>,
        mut dfake: Option<&mut [f32]>,
    ) -> Result<f32> {
        self.validate()?;
        let f = self.in_dim();
        check_len("lg.fake", n * f, fake.len())?;
        if let Some(d) = dfake.as_deref() {
            check_len("lg.dfake", n * f, d.len())?;
        }
        if n == 0 {
            return Ok(0.0);
        }
        let inv = 1.0 / n as f32;
        let mut loss = 0.0;
        for t in 0..n {
            let x = &fake[t * f..(t + 1) * f];
            loss -= self.score(x, s)? * inv;
            if let Some(d) = dfake.as_deref_mut() {
                self.input_grad(s)?;
                let row = &mut d[t * f..(t + 1) * f];
                for (o, &g) in row.iter_mut().zip(s.g.iter()) {
                    *o = -inv * g;
                }
            }
        }
        Ok(loss)
    }
}
