//! The conditional WGAN-GP critic `D_c(x, SE(y))` used to pre-train the feature generator
//! (f-CLSWGAN style, paper Sec. 4.1 / ref. \[58\]). Host-only: the on-device discriminator of
//! the environmental meta discriminator is gman-core's unconditional
//! [`gman_core::nets::discriminator::Discriminator`].
//!
//! ```text
//! D_c(x, a) = w2 · LeakyReLU_0.2( W1 [x; a] + b1 ) + b2        W1 = [W1x | W1a], DH x (F + A)
//! ```
//!
//! The layer is a gman-core [`Dense`] with the segmented input `[x, a]`; all matrix products
//! go through gman-core's kernels.
//!
//! # Gradient penalty (w.r.t. x only), closed form
//! With the activation slopes `m_j ∈ {1, 0.2}`, `u = w2 ⊙ m` and
//! `g = ∇_x D_c = W1xᵀ u`, the penalty `P = (‖g‖ − 1)²` has, with `c = 2 (‖g‖ − 1) / ‖g‖`,
//!
//! ```text
//! ∂P/∂W1x = c · u gᵀ        ∂P/∂w2_j = c · m_j (W1x g)_j
//! ∂P/∂W1a = 0   ∂P/∂b1 = 0   ∂P/∂b2 = 0
//! ```
//!
//! (exact almost everywhere: the slopes do not move under an infinitesimal change). This is
//! gman-core's closed form ([`gman_core::nets::discriminator::add_penalty_grad`], the one
//! implementation) with the attribute columns held at zero; the tests check it against finite
//! differences of an independent f64 implementation.

use anyhow::{bail, Result};
use gman_core::nets::discriminator::{add_penalty_grad, DiscGrads, PenaltyPoint};
use gman_core::nn::activation::{leaky_relu, leaky_relu_grad};
use gman_core::nn::dense::{Dense, DenseGrads};
use gman_core::nn::matrix::{axpy, dot};
use gman_core::rng::Xoshiro128;
use gman_core::Dims;

use super::params::{Init, ParamSet, INIT_STD};

/// Name of the critic's hidden weights, `DH x (F + A)` (feature columns first).
pub(crate) const CRITIC_W1: &str = "CriticW1";
/// Name of the critic's hidden bias, `DH`.
pub(crate) const CRITIC_B1: &str = "CriticB1";
/// Name of the critic's output weights, `1 x DH`.
pub(crate) const CRITIC_W2: &str = "CriticW2";
/// Name of the critic's output bias, `1`.
pub(crate) const CRITIC_B2: &str = "CriticB2";

/// Fresh critic parameters for `dims` (hidden width `disc_hidden`, input `feat + attr`),
/// weights `N(0, 0.02)`, biases 0.
pub(crate) fn init_critic(dims: &Dims, rng: &mut Xoshiro128) -> Result<ParamSet> {
    let mut p = ParamSet::new();
    let dh = dims.disc_hidden;
    p.add(
        CRITIC_W1,
        dh,
        dims.feat + dims.attr,
        Init::Normal(INIT_STD),
        rng,
    )?;
    p.add(CRITIC_B1, dh, 1, Init::Zeros, rng)?;
    p.add(CRITIC_W2, 1, dh, Init::Normal(INIT_STD), rng)?;
    p.add(CRITIC_B2, 1, 1, Init::Zeros, rng)?;
    Ok(p)
}

/// A read-only view of the conditional critic.
#[derive(Clone, Copy, Debug)]
pub(crate) struct CondCritic<'a> {
    /// Hidden layer over `[x; a]`.
    pub l1: Dense<'a>,
    /// Output weights (`DH`).
    pub w2: &'a [f32],
    /// Output bias.
    pub b2: f32,
    /// Feature width F (the first F input columns).
    pub feat: usize,
}

/// Gradient accumulators (`+=`) of the critic's parameters: gman-core's [`DiscGrads`] (the
/// hidden layer over `[x; a]`, the output weights and bias).
pub(crate) type CriticGrads<'g> = DiscGrads<'g>;

/// Accumulators over a gradient twin of [`init_critic`]'s parameters.
pub(crate) fn critic_grads(g: &mut ParamSet) -> Result<CriticGrads<'_>> {
    let [w1, b1, w2, b2] = g.slices_mut([CRITIC_W1, CRITIC_B1, CRITIC_W2, CRITIC_B2])?;
    let Some(b2) = b2.first_mut() else {
        bail!("{CRITIC_B2} is empty");
    };
    Ok(CriticGrads {
        l1: DenseGrads::Full { w: w1, b: b1 },
        w2,
        b2,
    })
}

/// Scratch of one critic evaluation (sized by [`CriticScratch::new`]).
#[derive(Clone, Debug)]
pub(crate) struct CriticScratch {
    /// Hidden activation after LeakyReLU (`DH`).
    pub h: Vec<f32>,
    /// `w2 ⊙ m`, or a hidden-layer gradient (`DH`).
    pub u: Vec<f32>,
    /// `W1x g` (`DH`).
    pub w1g: Vec<f32>,
    /// Input gradient w.r.t. x (`F`).
    pub g: Vec<f32>,
    /// Zeros standing for the attribute columns (`A`).
    pub zeros_a: Vec<f32>,
    /// Interpolate buffer (`F`).
    pub mix: Vec<f32>,
}

impl CriticScratch {
    /// Scratch for a critic with hidden width `dh`, feature width `f` and attribute width `a`.
    pub fn new(dh: usize, f: usize, a: usize) -> CriticScratch {
        CriticScratch {
            h: vec![0.0; dh],
            u: vec![0.0; dh],
            w1g: vec![0.0; dh],
            g: vec![0.0; f],
            zeros_a: vec![0.0; a],
            mix: vec![0.0; f],
        }
    }
}

/// Sums over a chunk of samples of one critic step (divide by the batch size for means).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub(crate) struct CriticSums {
    /// Σ D(x_real, a).
    pub real: f64,
    /// Σ D(x_fake, a).
    pub fake: f64,
    /// Σ (‖∇_x D(x̂, a)‖ − 1)².
    pub penalty: f64,
    /// Σ ‖∇_x D(x̂, a)‖.
    pub grad_norm: f64,
}

impl std::ops::AddAssign for CriticSums {
    fn add_assign(&mut self, o: CriticSums) {
        self.real += o.real;
        self.fake += o.fake;
        self.penalty += o.penalty;
        self.grad_norm += o.grad_norm;
    }
}

impl<'a> CondCritic<'a> {
    /// A view over [`init_critic`]-shaped parameters; `feat` is the feature width F.
    pub(crate) fn from_params(p: &'a ParamSet, feat: usize) -> Result<CondCritic<'a>> {
        let l1 = p.dense(CRITIC_W1, CRITIC_B1)?;
        let dh = l1.out_dim();
        let w2 = &p.tensor_shaped(CRITIC_W2, 1, dh)?.data;
        let b2 = p.tensor_shaped(CRITIC_B2, 1, 1)?.data[0];
        if feat > l1.in_dim() {
            bail!(
                "critic input has {} columns, fewer than the feature width {feat}",
                l1.in_dim()
            );
        }
        Ok(CondCritic { l1, w2, b2, feat })
    }

    /// Hidden width DH.
    #[cfg(test)]
    pub fn hidden(&self) -> usize {
        self.l1.out_dim()
    }

    /// Attribute width A.
    pub fn attr(&self) -> usize {
        self.l1.in_dim() - self.feat
    }

    /// A scratch sized for this critic.
    #[cfg(test)]
    pub fn scratch(&self) -> CriticScratch {
        CriticScratch::new(self.hidden(), self.feat, self.attr())
    }

    /// `D_c(x, a)`; leaves the hidden activation in `s.h`.
    pub fn score(&self, x: &[f32], a: &[f32], s: &mut CriticScratch) -> Result<f32> {
        self.l1.forward(&[x, a], &mut [], &mut s.h)?;
        for v in s.h.iter_mut() {
            *v = leaky_relu(*v);
        }
        Ok(dot(self.w2, &s.h) + self.b2)
    }

    /// `g = ∇_x D_c(x, a)` into `s.g` for the sample just scored; leaves `u = w2 ⊙ m` in
    /// `s.u`.
    pub fn input_grad(&self, s: &mut CriticScratch) -> Result<()> {
        for ((u, &w), &h) in s.u.iter_mut().zip(self.w2).zip(&s.h) {
            *u = w * leaky_relu_grad(h);
        }
        s.g.fill(0.0);
        self.l1.w.matvec_t_acc_cols(&s.u, 0, &mut s.g)?;
        Ok(())
    }

    /// Adds `coef · ∂D_c(x, a)/∂ω` for the sample just scored (activations in `s`).
    pub(crate) fn add_score_grad(
        &self,
        x: &[f32],
        a: &[f32],
        coef: f32,
        s: &mut CriticScratch,
        grads: &mut CriticGrads<'_>,
    ) -> Result<()> {
        *grads.b2 += coef;
        axpy(coef, &s.h, grads.w2);
        for ((u, &w), &h) in s.u.iter_mut().zip(self.w2).zip(&s.h) {
            *u = coef * w * leaky_relu_grad(h);
        }
        self.l1
            .backward(&[x, a], &[], &s.u, None, &mut grads.l1, &mut [])?;
        Ok(())
    }

    /// Adds `coef · ∂P/∂ω` for `P = (‖g‖ − 1)²` at the sample whose activation and input
    /// gradient are in `s` (after [`CondCritic::score`] and [`CondCritic::input_grad`]).
    /// Returns `(P, ‖g‖)`.
    pub fn add_penalty_grad(
        &self,
        coef: f32,
        s: &mut CriticScratch,
        grads: &mut CriticGrads<'_>,
    ) -> Result<(f32, f32)> {
        let at = PenaltyPoint {
            h: &s.h,
            u: &s.u,
            g: &s.g,
            zeros: &s.zeros_a,
        };
        Ok(add_penalty_grad(
            &self.l1, self.w2, at, coef, &mut s.w1g, grads,
        )?)
    }

    /// Accumulates the gradient of the WGAN-GP critic loss
    /// `L = mean D(fake) − mean D(real) + λ mean P(x̂)`, `x̂ = ε x_real + (1 − ε) x_fake`,
    /// over a chunk of `eps.len()` samples (rows of `real`, `fake`, `attr`), each weighted
    /// `inv_n` (1 / the full batch size). Returns the chunk's sums.
    #[allow(clippy::too_many_arguments)]
    pub(crate) fn wgan_gp_accumulate(
        &self,
        real: &[f32],
        fake: &[f32],
        attr: &[f32],
        eps: &[f32],
        lambda: f32,
        inv_n: f32,
        s: &mut CriticScratch,
        grads: &mut CriticGrads<'_>,
    ) -> Result<CriticSums> {
        let (f, a, n) = (self.feat, self.attr(), eps.len());
        if real.len() != n * f || fake.len() != n * f || attr.len() != n * a {
            bail!(
                "critic batch: {n} samples need {} real, {} fake, {} attribute values; got {}, {}, {}",
                n * f,
                n * f,
                n * a,
                real.len(),
                fake.len(),
                attr.len()
            );
        }
        let mut sums = CriticSums::default();
        for t in 0..n {
            let xr = &real[t * f..(t + 1) * f];
            let xf = &fake[t * f..(t + 1) * f];
            let at = &attr[t * a..(t + 1) * a];
            sums.real += self.score(xr, at, s)? as f64;
            self.add_score_grad(xr, at, -inv_n, s, grads)?;
            sums.fake += self.score(xf, at, s)? as f64;
            self.add_score_grad(xf, at, inv_n, s, grads)?;
            let e = eps[t];
            let mut mix = std::mem::take(&mut s.mix);
            for ((m, &r), &q) in mix.iter_mut().zip(xr).zip(xf) {
                *m = e * r + (1.0 - e) * q;
            }
            let r = self.score(&mix, at, s);
            s.mix = mix;
            r?;
            self.input_grad(s)?;
            let (p, norm) = self.add_penalty_grad(lambda * inv_n, s, grads)?;
            sums.penalty += p as f64;
            sums.grad_norm += norm as f64;
        }
        Ok(sums)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::optim::params::Param;
    use gman_core::rng::fill_gaussian;

    /// Independent f64 implementation of the critic, its input gradient and the penalty.
    struct Ref {
        w1: Vec<f64>,
        b1: Vec<f64>,
        w2: Vec<f64>,
        b2: f64,
        dh: usize,
        f: usize,
        a: usize,
    }

    impl Ref {
        fn from(p: &ParamSet, f: usize) -> Ref {
            let g = |n: &str| -> Vec<f64> {
                p.get(n).unwrap().data.iter().map(|&v| v as f64).collect()
            };
            let w1 = g(CRITIC_W1);
            let dh = p.get(CRITIC_B1).unwrap().rows;
            let a = w1.len() / dh - f;
            Ref {
                w1,
                b1: g(CRITIC_B1),
                w2: g(CRITIC_W2),
                b2: g(CRITIC_B2)[0],
                dh,
                f,
                a,
            }
        }
        fn pre(&self, x: &[f64], at: &[f64]) -> Vec<f64> {
            let cols = self.f + self.a;
            (0..self.dh)
                .map(|j| {
                    let row = &self.w1[j * cols..(j + 1) * cols];
                    self.b1[j]
                        + row[..self.f].iter().zip(x).map(|(w, v)| w * v).sum::<f64>()
                        + row[self.f..]
                            .iter()
                            .zip(at)
                            .map(|(w, v)| w * v)
                            .sum::<f64>()
                })
                .collect()
        }
        fn score(&self, x: &[f64], at: &[f64]) -> f64 {
            self.pre(x, at)
                .iter()
                .zip(&self.w2)
                .map(|(&p, w)| w * if p > 0.0 { p } else { 0.2 * p })
                .sum::<f64>()
                + self.b2
        }
        fn input_grad(&self, x: &[f64], at: &[f64]) -> Vec<f64> {
            let cols = self.f + self.a;
            let pre = self.pre(x, at);
            let mut g = vec![0.0; self.f];
            for (j, &pj) in pre.iter().enumerate() {
                let m = if pj > 0.0 { 1.0 } else { 0.2 };
                for (i, gi) in g.iter_mut().enumerate() {
                    *gi += self.w1[j * cols + i] * self.w2[j] * m;
                }
            }
            g
        }
        fn penalty(&self, x: &[f64], at: &[f64]) -> f64 {
            let n = self
                .input_grad(x, at)
                .iter()
                .map(|v| v * v)
                .sum::<f64>()
                .sqrt();
            (n - 1.0) * (n - 1.0)
        }
        fn min_abs_pre(&self, x: &[f64], at: &[f64]) -> f64 {
            self.pre(x, at).iter().fold(f64::MAX, |m, p| m.min(p.abs()))
        }
    }

    fn setup(seed: u64, scale: f32) -> (ParamSet, Vec<f32>, Vec<f32>) {
        let (f, a, dh) = (7, 3, 5);
        let mut rng = Xoshiro128::seed_from_u64(seed);
        let dims = Dims {
            feat: f,
            attr: a,
            disc_hidden: dh,
            ..Dims::MCU
        };
        let mut p = init_critic(&dims, &mut rng).unwrap();
        for t in &mut p.tensors {
            fill_gaussian(&mut rng, &mut t.data);
            t.data.iter_mut().for_each(|v| *v *= scale);
        }
        let mut x = vec![0.0; f];
        let mut at = vec![0.0; a];
        fill_gaussian(&mut rng, &mut x);
        fill_gaussian(&mut rng, &mut at);
        (p, x, at)
    }

    fn to64(v: &[f32]) -> Vec<f64> {
        v.iter().map(|&x| x as f64).collect()
    }

    /// Central differences of an f64 function of the parameters, one value at a time.
    fn fd(p: &ParamSet, f: usize, fun: &dyn Fn(&Ref) -> f64) -> Vec<Param> {
        let h = 1e-6;
        let base = Ref::from(p, f);
        let mut out = Vec::new();
        for t in &p.tensors {
            let mut g = Param::zeros(&t.name, t.rows, t.cols);
            for i in 0..t.data.len() {
                let eval = |d: f64| {
                    let mut r = Ref {
                        w1: base.w1.clone(),
                        b1: base.b1.clone(),
                        w2: base.w2.clone(),
                        ..base
                    };
                    let v = match t.name.as_str() {
                        CRITIC_W1 => &mut r.w1[i],
                        CRITIC_B1 => &mut r.b1[i],
                        CRITIC_W2 => &mut r.w2[i],
                        _ => &mut r.b2,
                    };
                    *v += d;
                    fun(&r)
                };
                g.data[i] = ((eval(h) - eval(-h)) / (2.0 * h)) as f32;
            }
            out.push(g);
        }
        out
    }

    fn assert_close(name: &str, got: &[f32], want: &[f32]) {
        for (i, (g, w)) in got.iter().zip(want).enumerate() {
            let tol = 2e-3 * (1.0 + w.abs());
            assert!(
                (g - w).abs() <= tol,
                "{name}[{i}]: analytic {g} vs finite difference {w}"
            );
        }
    }

    #[test]
    fn input_gradient_matches_finite_differences() {
        let (p, x, at) = setup(11, 0.5);
        let c = CondCritic::from_params(&p, 7).unwrap();
        let mut s = c.scratch();
        let r = Ref::from(&p, 7);
        let (x64, a64) = (to64(&x), to64(&at));
        let d = c.score(&x, &at, &mut s).unwrap();
        assert!((d as f64 - r.score(&x64, &a64)).abs() < 1e-5);
        c.input_grad(&mut s).unwrap();
        let h = 1e-6;
        for i in 0..7 {
            let (mut xp, mut xm) = (x64.clone(), x64.clone());
            xp[i] += h;
            xm[i] -= h;
            let fdv = (r.score(&xp, &a64) - r.score(&xm, &a64)) / (2.0 * h);
            assert!((s.g[i] as f64 - fdv).abs() < 1e-4, "g[{i}]");
        }
    }

    #[test]
    fn penalty_gradient_matches_finite_differences() {
        let mut checked = 0;
        for seed in 0..20 {
            // Scales that put ‖g‖ both below and above 1.
            for scale in [0.4f32, 1.5] {
                let (p, x, at) = setup(seed, scale);
                let r = Ref::from(&p, 7);
                let (x64, a64) = (to64(&x), to64(&at));
                if r.min_abs_pre(&x64, &a64) < 1e-3 {
                    continue; // too close to a kink for finite differences
                }
                let c = CondCritic::from_params(&p, 7).unwrap();
                let mut s = c.scratch();
                let mut g = p.zeros_like();
                let mut cg = critic_grads(&mut g).unwrap();
                c.score(&x, &at, &mut s).unwrap();
                c.input_grad(&mut s).unwrap();
                let (pen, _) = c.add_penalty_grad(1.0, &mut s, &mut cg).unwrap();
                assert!((pen as f64 - r.penalty(&x64, &a64)).abs() < 1e-4 * (1.0 + pen as f64));
                let want = fd(&p, 7, &|rr| rr.penalty(&x64, &a64));
                for (gt, wt) in g.tensors.iter().zip(&want) {
                    assert_close(&gt.name, &gt.data, &wt.data);
                }
                // The attribute columns, b1 and b2 get nothing.
                let w1 = &g.get(CRITIC_W1).unwrap().data;
                for j in 0..5 {
                    assert!(w1[j * 10 + 7..j * 10 + 10].iter().all(|&v| v == 0.0));
                }
                checked += 1;
            }
        }
        assert!(checked >= 20, "only {checked} cases away from kinks");
    }

    #[test]
    fn wgan_gp_loss_gradient_matches_finite_differences() {
        let (p, _, _) = setup(3, 0.7);
        let mut rng = Xoshiro128::seed_from_u64(99);
        let n = 4;
        let mut real = vec![0.0; n * 7];
        let mut fake = vec![0.0; n * 7];
        let mut attr = vec![0.0; n * 3];
        fill_gaussian(&mut rng, &mut real);
        fill_gaussian(&mut rng, &mut fake);
        fill_gaussian(&mut rng, &mut attr);
        let eps = [0.1f32, 0.5, 0.9, 0.3];
        let lambda = 10.0;
        let mixes: Vec<Vec<f64>> = (0..n)
            .map(|t| {
                (0..7)
                    .map(|i| (eps[t] * real[t * 7 + i] + (1.0 - eps[t]) * fake[t * 7 + i]) as f64)
                    .collect()
            })
            .collect();
        let loss = |r: &Ref| {
            let mut l = 0.0;
            for t in 0..n {
                let at = to64(&attr[t * 3..t * 3 + 3]);
                l += r.score(&to64(&fake[t * 7..t * 7 + 7]), &at)
                    - r.score(&to64(&real[t * 7..t * 7 + 7]), &at)
                    + lambda as f64 * r.penalty(&mixes[t], &at);
            }
            l / n as f64
        };
        let c = CondCritic::from_params(&p, 7).unwrap();
        let mut s = c.scratch();
        let mut g = p.zeros_like();
        let mut cg = critic_grads(&mut g).unwrap();
        let sums = c
            .wgan_gp_accumulate(
                &real,
                &fake,
                &attr,
                &eps,
                lambda,
                1.0 / n as f32,
                &mut s,
                &mut cg,
            )
            .unwrap();
        // Bad shapes are errors, not panics.
        assert!(c
            .wgan_gp_accumulate(&real[1..], &fake, &attr, &eps, 1.0, 1.0, &mut s, &mut cg)
            .is_err());
        let r = Ref::from(&p, 7);
        let l = (sums.fake - sums.real + lambda as f64 * sums.penalty) / n as f64;
        assert!((l - loss(&r)).abs() < 1e-4 * (1.0 + l.abs()));
        let want = fd(&p, 7, &loss);
        for (gt, wt) in g.tensors.iter().zip(&want) {
            assert_close(&gt.name, &gt.data, &wt.data);
        }
    }
}
