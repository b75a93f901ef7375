//! The second-order meta-gradient (`--meta-order 2`): the exact gradient of the episode's
//! navigation loss with respect to the *pre-adaptation* parameters, through the inner SGD
//! steps of Algorithm 1 (lines 17-19).
//!
//! # The computation being differentiated
//! An episode is cut into segments j = 0..J (k = 20 steps each, the last one shorter).
//! Segment j runs with G's parameters θ_j and the actor head φ_j (the only adapted part of
//! the policy, see [`gman_core::navigator`]). After segment j (j < J) the inner update is
//!
//! ```text
//! θ_{j+1} = θ_j − α g_θ(θ_j),     φ_{j+1} = φ_j − α g_φ(θ_j)
//! g = ∇ L_ad on the buffer Ψ_j = {(z_t, p_t, h_t)} with D's parameters ω_j
//! ```
//!
//! where ω_j is D *after* its ascent step (the value the descent step uses). The meta-loss is
//! `L_total = Σ_j L_nav,j(θ_j, φ_j)` (each segment's A3C surrogate, as in
//! [`super::bptt::segment_backward`]).
//!
//! **What is held constant (data).** As in standard MAML-RL and GAN practice, the sampled
//! trajectories (observations, actions, rewards, advantages, noise z_t), the stored buffer
//! contents (action probabilities p_t, LSTM states h_t) and D's ω_j are treated as data:
//! their dependence on θ_0, φ_0 through the environment, the sampling and D's ascent step is
//! not followed. With p_t stored, g_φ does not depend on φ; g_θ never depends on φ (L_ad
//! reaches θ through D(x_t(θ)) only). Hence ∂φ_{j+1}/∂φ_j = I, ∂θ_{j+1}/∂φ_j = 0.
//!
//! # Reverse recursion
//! ```text
//! v_θ, v_φ = ∇_θ L_nav,J, ∇_φ L_nav,J
//! for j = J−1 .. 0:
//!     if the update after segment j was applied:
//!         v_θ ← v_θ − α [ H_θθ(j) v_θ + J_φθ(j)ᵀ v_φ ]      (v_φ passes unchanged)
//!     v_θ += ∇_θ L_nav,j;   v_φ += ∇_φ L_nav,j
//! meta-gradient = (v_θ, v_φ)
//! ```
//! with `H_θθ(j) = ∂g_θ/∂θ` (symmetric: the Hessian of L_ad in θ) and `J_φθ(j) = ∂g_φ/∂θ`,
//! both at θ_j. An update that was rolled back (non-finite or out-of-bound loss) is the
//! identity and is skipped. First order (`--meta-order 1`) is the same sum without the
//! bracket.
//!
//! # Hessian-vector products: central finite differences of exact gradients
//! `H v ≈ [g_θ(θ + εv) − g_θ(θ − εv)] / (2ε)` with `ε = 1e-3 · max(‖θ‖, 1) / ‖v‖`, i.e. a
//! step of length 1e-3 · max(‖θ‖, 1) along v. g_θ is gman-core's exact L_ad gradient
//! ([`gman_core::adapt::adapt_generator_grad`]), evaluated on host views of the given θ
//! (the same kernels the device runs). Error: the truncation error is O(ε²‖v‖²) relative
//! (≈1e-6 for the step above) where the loss is smooth; f32 rounding of θ ± εv and of the
//! gradients contributes ≈ u_f32 · ‖θ‖/(ε‖v‖) ≈ 1e-4 relative; G and D are piecewise linear
//! (LeakyReLU), and a hidden unit whose pre-activation lies within the step of its kink
//! contributes an O(1) error for that unit's share — rare for a 1e-3 relative step, and the
//! reason the step is not made smaller still. Forward-over-reverse would be exact but needs
//! dual-number versions of every core kernel.
//!
//! # J_φθᵀ v_φ without a Jacobian
//! `g_φ = Σ_t (J_softmax(p_t) ∂L_ad/∂p_t) ⊗ [h_t; 1]` depends on θ only through the scores
//! `d_t = D(x_t(θ))`. So `J_φθᵀ v_φ = ∇_θ ⟨g_φ(θ), v_φ⟩ = Σ_t c_t ∇_θ D(x_t(θ))` with
//! `c_t = ∂⟨g_φ, v_φ⟩/∂d_t`, computed in closed form (see `score_coefficients`), and the
//! sum is back-propagated into G by [`gman_core::adapt::generator_score_backward`] — exact,
//! no finite differences.

use anyhow::{bail, ensure, Result};
use gman_core::adapt::{
    actor_head_grad, adapt_generator_grad, generator_score_backward, AdaptLossKind, AdaptWork,
};
use gman_core::blob::TensorId;
use gman_core::navigator::{Mode, Navigator};
use gman_core::nets::discriminator::{DiscScratch, Discriminator};
use gman_core::nets::generator::Generator;
use gman_core::nn::dense::{Dense, DenseGrads};
use gman_core::nn::matrix::MatRef;
use gman_core::{Dims, NUM_ACTIONS};

use crate::optim::params::ParamSet;
use crate::pretrain::generator::GenBuffers;

/// The adapted tensors of G (θ), in the order of the flat vectors of this module.
pub const THETA: [TensorId; 4] = TensorId::GENERATOR;

/// The adapted tensors of the policy (φ: the actor head), in flat-vector order.
pub const PHI: [TensorId; 2] = TensorId::ACTOR_HEAD;

fn len_of(ids: &[TensorId], d: &Dims) -> usize {
    ids.iter()
        .map(|id| {
            let (r, c) = id.shape(d);
            r * c
        })
        .sum()
}

/// Length of the flat θ vector.
pub(crate) fn theta_len(d: &Dims) -> usize {
    len_of(&THETA, d)
}

/// Length of the flat φ vector.
pub(crate) fn phi_len(d: &Dims) -> usize {
    len_of(&PHI, d)
}

/// Moves the θ and φ parts of a gradient set out into flat vectors (zeroing them in `g`).
pub fn take_adapted(g: &mut ParamSet) -> Result<(Vec<f32>, Vec<f32>)> {
    let mut out = (Vec::new(), Vec::new());
    for (ids, v) in [(&THETA[..], &mut out.0), (&PHI[..], &mut out.1)] {
        for id in ids {
            let p = g
                .get_mut(id.name())
                .ok_or_else(|| anyhow::anyhow!("gradient set has no {}", id.name()))?;
            v.extend_from_slice(&p.data);
            p.data.fill(0.0);
        }
    }
    Ok(out)
}

/// Adds flat θ and φ vectors into the matching tensors of `g`.
pub(crate) fn add_adapted(g: &mut ParamSet, theta: &[f32], phi: &[f32]) -> Result<()> {
    for (ids, v) in [(&THETA[..], theta), (&PHI[..], phi)] {
        let mut off = 0;
        for id in ids {
            let p = g
                .get_mut(id.name())
                .ok_or_else(|| anyhow::anyhow!("gradient set has no {}", id.name()))?;
            let n = p.data.len();
            ensure!(
                off + n <= v.len(),
                "flat vector too short for {}",
                id.name()
            );
            p.data
                .iter_mut()
                .zip(&v[off..off + n])
                .for_each(|(a, b)| *a += b);
            off += n;
        }
        ensure!(off == v.len(), "flat vector length mismatch");
    }
    Ok(())
}

/// D's parameters ω as host vectors (Full layout: no gain).
#[derive(Clone, Debug)]
pub struct DiscParams {
    /// `DH x F`.
    pub w1: Vec<f32>,
    /// `DH`.
    pub b1: Vec<f32>,
    /// `DH`.
    pub w2: Vec<f32>,
    /// Output bias.
    pub b2: f32,
}

impl DiscParams {
    /// Copies a (Full-mode) discriminator view.
    pub(crate) fn from_view(d: &Discriminator<'_>) -> Result<DiscParams> {
        if d.l1.gain.is_some() {
            bail!("the second-order meta-gradient needs the Full adaptation mode");
        }
        let mut w1 = vec![0.0; d.l1.w.rows() * d.l1.w.cols()];
        d.l1.w.copy_to(&mut w1)?;
        Ok(DiscParams {
            w1,
            b1: d.l1.b.to_vec(),
            w2: d.w2.to_vec(),
            b2: d.b2,
        })
    }

    fn view(&self, d: &Dims) -> Result<Discriminator<'_>> {
        Ok(Discriminator {
            l1: Dense {
                w: MatRef::f32(d.disc_hidden, d.feat, &self.w1)?,
                b: &self.b1,
                gain: None,
            },
            w2: &self.w2,
            b2: self.b2,
        })
    }
}

/// What the reverse recursion needs of one inner update (after segment j).
#[derive(Clone, Debug)]
pub struct InnerStep {
    /// θ_j, flat ([`THETA`] order).
    pub theta: Vec<f32>,
    /// Ψ's noise z_t (`n x Z`).
    pub noise: Vec<f32>,
    /// Ψ's action probabilities p_t (`n x 6`).
    pub probs: Vec<f32>,
    /// Ψ's LSTM states h_t (`n x LH`).
    pub hidden: Vec<f32>,
    /// ω_j: D after its ascent step (the D that L_ad's descent step used).
    pub disc: DiscParams,
    /// Whether the θ/φ step was applied (a rolled-back step is the identity).
    pub applied: bool,
}

impl InnerStep {
    /// Records θ_j and Ψ_j from `nav`; call right before [`Navigator::adapt_now`], then
    /// [`InnerStep::after_update`].
    pub fn before_update<M: Mode, const K: usize>(nav: &Navigator<'_, M, K>) -> Result<Self> {
        let gen = nav.generator()?;
        if gen.l1.gain.is_some() {
            bail!("the second-order meta-gradient needs the Full adaptation mode");
        }
        let mut theta = Vec::new();
        for l in [&gen.l1, &gen.l2] {
            let mut w = vec![0.0; l.w.rows() * l.w.cols()];
            l.w.copy_to(&mut w)?;
            theta.extend_from_slice(&w);
            theta.extend_from_slice(l.b);
        }
        let buf = nav.buffer();
        let disc = DiscParams::from_view(&nav.discriminator()?)?;
        Ok(InnerStep {
            theta,
            // (With zero noise Ψ keeps no z_t: every one is zero.)
            noise: if buf.noise.is_empty() {
                vec![0.0; buf.probs.len() / NUM_ACTIONS * nav.dims().noise]
            } else {
                buf.noise.to_vec()
            },
            probs: buf.probs.to_vec(),
            hidden: buf.hidden.to_vec(),
            disc,
            applied: false,
        })
    }

    /// Records ω_j and whether the step was applied; call right after `adapt_now`.
    pub fn after_update<M: Mode, const K: usize>(
        &mut self,
        nav: &Navigator<'_, M, K>,
    ) -> Result<()> {
        self.disc = DiscParams::from_view(&nav.discriminator()?)?;
        self.applied = nav.last_adaptation().adapt_applied;
        Ok(())
    }

    fn len(&self) -> usize {
        self.probs.len() / NUM_ACTIONS
    }
}

/// The fixed settings of the inner loop.
#[derive(Clone, Debug)]
pub struct InnerSetup {
    /// Sizes.
    pub dims: Dims,
    /// SE(y) of the episode.
    pub attr: Vec<f32>,
    /// Form of L_ad.
    pub kind: AdaptLossKind,
    /// α2, the inner SGD rate of θ and φ.
    pub alpha: f32,
}

impl InnerSetup {
    /// The setup of `nav`'s current episode.
    pub fn of<M: Mode, const K: usize>(nav: &Navigator<'_, M, K>) -> InnerSetup {
        let cfg = nav.config();
        InnerSetup {
            dims: *nav.dims(),
            attr: nav.attr().to_vec(),
            kind: cfg.model.inner_rule.adapt_loss,
            alpha: cfg.model.inner_lr,
        }
    }
}

/// Host work buffers of one L_ad pass.
struct Work {
    gen: GenBuffers,
    dh: Vec<f32>,
    dv: Vec<f32>,
    dw1g: Vec<f32>,
    dg: Vec<f32>,
    dmix: Vec<f32>,
    d: Vec<f32>,
    dd: Vec<f32>,
    dx: Vec<f32>,
}

impl Work {
    fn new(d: &Dims, n: usize) -> Work {
        let (h, f, dh) = (d.gen_hidden, d.feat, d.disc_hidden);
        Work {
            gen: GenBuffers::new(h, f),
            dh: vec![0.0; dh],
            dv: vec![0.0; dh],
            dw1g: vec![0.0; dh],
            dg: vec![0.0; f],
            dmix: vec![0.0; f],
            d: vec![0.0; n],
            dd: vec![0.0; n],
            dx: vec![0.0; f],
        }
    }

    fn view(&mut self) -> AdaptWork<'_> {
        let (gen, gen_scratch) = self.gen.views();
        AdaptWork {
            gen,
            gen_scratch,
            disc: DiscScratch {
                u: &mut [],
                h: &mut self.dh,
                v: &mut self.dv,
                w1g: &mut self.dw1g,
                g: &mut self.dg,
                mix: &mut self.dmix,
            },
            d: &mut self.d,
            dd: &mut self.dd,
            dx: &mut self.dx,
        }
    }
}

/// Splits a flat θ into `(W1, b1, W2, b2)`.
fn split_theta<'a>(d: &Dims, t: &'a [f32]) -> Result<[&'a [f32]; 4]> {
    ensure!(
        t.len() == theta_len(d),
        "θ has {} values, expected {}",
        t.len(),
        theta_len(d)
    );
    let (a, rest) = t.split_at(d.gen_hidden * d.gen_in());
    let (b, rest) = rest.split_at(d.gen_hidden);
    let (c, e) = rest.split_at(d.feat * d.gen_hidden);
    Ok([a, b, c, e])
}

fn split_theta_mut<'a>(d: &Dims, t: &'a mut [f32]) -> Result<[&'a mut [f32]; 4]> {
    ensure!(t.len() == theta_len(d), "θ gradient length mismatch");
    let (a, rest) = t.split_at_mut(d.gen_hidden * d.gen_in());
    let (b, rest) = rest.split_at_mut(d.gen_hidden);
    let (c, e) = rest.split_at_mut(d.feat * d.gen_hidden);
    Ok([a, b, c, e])
}

fn generator<'a>(d: &Dims, theta: &'a [f32]) -> Result<Generator<'a>> {
    let [w1, b1, w2, b2] = split_theta(d, theta)?;
    Ok(Generator {
        l1: Dense {
            w: MatRef::f32(d.gen_hidden, d.gen_in(), w1)?,
            b: b1,
            gain: None,
        },
        l2: Dense {
            w: MatRef::f32(d.feat, d.gen_hidden, w2)?,
            b: b2,
            gain: None,
        },
    })
}

/// The inner gradients `(g_θ, g_φ) = ∇ L_ad` at `theta` on `step`'s buffer and ω, with
/// gman-core's kernels (the computation the navigator's inner update runs, on host views).
pub fn inner_grads(
    s: &InnerSetup,
    theta: &[f32],
    step: &InnerStep,
) -> Result<(Vec<f32>, Vec<f32>)> {
    let d = &s.dims;
    let n = step.len();
    let gen = generator(d, theta)?;
    let disc = step.disc.view(d)?;
    let mut gt = vec![0.0f32; theta_len(d)];
    let mut dprobs = vec![0.0f32; n * NUM_ACTIONS];
    {
        let [w1, b1, w2, b2] = split_theta_mut(d, &mut gt)?;
        let mut work = Work::new(d, n);
        adapt_generator_grad(
            s.kind,
            &gen,
            &disc,
            &s.attr,
            &step.noise,
            &step.probs,
            &mut work.view(),
            &mut DenseGrads::Full { w: w1, b: b1 },
            &mut DenseGrads::Full { w: w2, b: b2 },
            &mut dprobs,
        )?;
    }
    // φ: gman-core's actor-head gradient of L_ad (the device's function), on a gain-free head
    // (Full mode) whose weights do not enter its gradient.
    let lh = d.lstm_hidden;
    let mut gp = vec![0.0f32; phi_len(d)];
    {
        let (gw, gb) = gp.split_at_mut(NUM_ACTIONS * lh);
        let zeros = vec![0.0f32; NUM_ACTIONS * lh];
        let head = Dense {
            w: MatRef::f32(NUM_ACTIONS, lh, &zeros)?,
            b: &[0.0; NUM_ACTIONS],
            gain: None,
        };
        let (mut dl, mut u) = ([0.0f32; NUM_ACTIONS], [0.0f32; NUM_ACTIONS]);
        actor_head_grad(
            &head,
            &step.probs,
            &dprobs,
            &step.hidden,
            n,
            &mut dl,
            &mut u,
            &mut DenseGrads::Full { w: gw, b: gb },
        )?;
    }
    Ok((gt, gp))
}

/// `c_t = ∂⟨g_φ, v_φ⟩/∂d_t` for the scores `d` (`n`), probabilities `probs` (`n x 6`),
/// states `hidden` (`n x LH`) and a direction `v_phi` ([`PHI`] layout), in closed form.
///
/// With `w_t = V_W h_t + V_b` and `q_t = J_softmax(p_t) w_t` (J_softmax is symmetric),
/// `⟨g_φ, v_φ⟩ = Σ_t ⟨∂L/∂p_t, q_t⟩` and
/// * paper form, `∂L/∂p_t = −d_t p_t / (n ‖p_t‖)`: `c_t = −⟨p_t, q_t⟩ / (n ‖p_t‖)`;
/// * reference form, `∂L/∂p_t = −d_t u`, `u = v/‖v‖`, `v = −Σ_s d_s p_s`: with
///   `Q = Σ_t d_t q_t`, `c_t = −⟨u, q_t⟩ + ⟨p_t, Q − u ⟨u, Q⟩⟩ / ‖v‖`.
pub(crate) fn score_coefficients(
    kind: AdaptLossKind,
    d: &[f32],
    probs: &[f32],
    hidden: &[f32],
    v_phi: &[f32],
) -> Vec<f32> {
    let n = d.len();
    let lh = hidden.len() / n.max(1);
    let (vw, vb) = v_phi.split_at(NUM_ACTIONS * lh);
    let dot = |a: &[f64], b: &[f64]| a.iter().zip(b).map(|(x, y)| x * y).sum::<f64>();
    let mut ps = Vec::with_capacity(n);
    let mut qs = Vec::with_capacity(n);
    for t in 0..n {
        let p: Vec<f64> = probs[t * NUM_ACTIONS..(t + 1) * NUM_ACTIONS]
            .iter()
            .map(|&x| x as f64)
            .collect();
        let h = &hidden[t * lh..(t + 1) * lh];
        let w: Vec<f64> = (0..NUM_ACTIONS)
            .map(|i| {
                vb[i] as f64
                    + vw[i * lh..(i + 1) * lh]
                        .iter()
                        .zip(h)
                        .map(|(a, b)| *a as f64 * *b as f64)
                        .sum::<f64>()
            })
            .collect();
        let pw = dot(&p, &w);
        let q: Vec<f64> = p.iter().zip(&w).map(|(pi, wi)| pi * (wi - pw)).collect();
        ps.push(p);
        qs.push(q);
    }
    match kind {
        AdaptLossKind::Paper => (0..n)
            .map(|t| {
                let norm = dot(&ps[t], &ps[t]).sqrt();
                if norm > 0.0 {
                    (-dot(&ps[t], &qs[t]) / (n as f64 * norm)) as f32
                } else {
                    0.0
                }
            })
            .collect(),
        AdaptLossKind::Reference => {
            let mut v = [0.0f64; NUM_ACTIONS];
            let mut qsum = [0.0f64; NUM_ACTIONS];
            for t in 0..n {
                for i in 0..NUM_ACTIONS {
                    v[i] -= d[t] as f64 * ps[t][i];
                    qsum[i] += d[t] as f64 * qs[t][i];
                }
            }
            let norm = dot(&v, &v).sqrt();
            if norm <= 0.0 {
                return vec![0.0; n];
            }
            let u: Vec<f64> = v.iter().map(|x| x / norm).collect();
            let uq = dot(&u, &qsum);
            let r: Vec<f64> = qsum.iter().zip(&u).map(|(q, ui)| q - ui * uq).collect();
            (0..n)
                .map(|t| (-dot(&u, &qs[t]) + dot(&ps[t], &r) / norm) as f32)
                .collect()
        }
    }
}

/// `J_φθᵀ v_φ = ∇_θ ⟨g_φ(θ), v_φ⟩` at `theta` (exact; see the module docs).
pub(crate) fn phi_theta_vjp(
    s: &InnerSetup,
    theta: &[f32],
    step: &InnerStep,
    v_phi: &[f32],
) -> Result<Vec<f32>> {
    let d = &s.dims;
    let n = step.len();
    ensure!(v_phi.len() == phi_len(d), "v_φ length mismatch");
    let gen = generator(d, theta)?;
    let disc = step.disc.view(d)?;
    let zd = d.noise;
    let mut work = Work::new(d, n);
    let mut scores = vec![0.0f32; n];
    {
        let mut w = work.view();
        for (t, sc) in scores.iter_mut().enumerate() {
            gen.forward(&step.noise[t * zd..(t + 1) * zd], &s.attr, &mut w.gen)?;
            *sc = disc.score(w.gen.x, &mut w.disc)?;
        }
    }
    let coef = score_coefficients(s.kind, &scores, &step.probs, &step.hidden, v_phi);
    let mut out = vec![0.0f32; theta_len(d)];
    {
        let [w1, b1, w2, b2] = split_theta_mut(d, &mut out)?;
        generator_score_backward(
            &gen,
            &disc,
            &s.attr,
            &step.noise,
            &coef,
            &mut work.view(),
            &mut DenseGrads::Full { w: w1, b: b1 },
            &mut DenseGrads::Full { w: w2, b: b2 },
        )?;
    }
    Ok(out)
}

fn norm(v: &[f32]) -> f64 {
    v.iter().map(|&x| x as f64 * x as f64).sum::<f64>().sqrt()
}

/// `H_θθ v ≈ [g_θ(θ + εv) − g_θ(θ − εv)] / (2ε)`, `ε = 1e-3 · max(‖θ‖, 1) / ‖v‖` (central
/// finite differences of exact gradients; see the module docs for the error).
pub(crate) fn hvp_theta(
    s: &InnerSetup,
    theta: &[f32],
    step: &InnerStep,
    v: &[f32],
) -> Result<Vec<f32>> {
    ensure!(v.len() == theta.len(), "v_θ length mismatch");
    let nv = norm(v);
    if nv == 0.0 {
        return Ok(vec![0.0; v.len()]);
    }
    let eps = 1e-3 * norm(theta).max(1.0) / nv;
    let shifted = |sign: f64| -> Vec<f32> {
        theta
            .iter()
            .zip(v)
            .map(|(&t, &vi)| (t as f64 + sign * eps * vi as f64) as f32)
            .collect()
    };
    let (gp, _) = inner_grads(s, &shifted(1.0), step)?;
    let (gm, _) = inner_grads(s, &shifted(-1.0), step)?;
    Ok(gp
        .iter()
        .zip(&gm)
        .map(|(a, b)| ((*a as f64 - *b as f64) / (2.0 * eps)) as f32)
        .collect())
}

/// The meta-gradient `(∂L_total/∂θ_0, ∂L_total/∂φ_0)` by the reverse recursion of the module
/// docs. `seg_grads[j]` is `(∇_θ L_nav,j, ∇_φ L_nav,j)` at `(θ_j, φ_j)`; `steps[j]` the update
/// after segment j (`None`: no update, e.g. the per-episode cap was reached). Only the first
/// `seg_grads.len() − 1` entries of `steps` are used.
pub fn meta_backward(
    s: &InnerSetup,
    steps: &[Option<InnerStep>],
    seg_grads: &[(Vec<f32>, Vec<f32>)],
) -> Result<(Vec<f32>, Vec<f32>)> {
    let d = &s.dims;
    let Some(((last_t, last_p), rest)) = seg_grads.split_last() else {
        return Ok((vec![0.0; theta_len(d)], vec![0.0; phi_len(d)]));
    };
    ensure!(
        steps.len() >= rest.len(),
        "one inner step per segment but the last"
    );
    let (mut vt, mut vp) = (last_t.clone(), last_p.clone());
    for (j, (gt, gp)) in rest.iter().enumerate().rev() {
        if let Some(step) = steps[j].as_ref().filter(|st| st.applied) {
            let hv = hvp_theta(s, &step.theta, step, &vt)?;
            let jv = phi_theta_vjp(s, &step.theta, step, &vp)?;
            for ((o, h), j) in vt.iter_mut().zip(&hv).zip(&jv) {
                *o -= s.alpha * (h + j);
            }
        }
        vt.iter_mut().zip(gt).for_each(|(a, b)| *a += b);
        vp.iter_mut().zip(gp).for_each(|(a, b)| *a += b);
    }
    Ok((vt, vp))
}
