//! The A3C navigation loss L_nav (paper Sec. 3.2) of one rollout segment and its gradient by
//! back-propagation through time, on gman-core's policy kernels.
//!
//! For a segment of `T` steps with rewards `r_t`, values `V_t` and a bootstrap `V_T` (0 when
//! the episode ended):
//!
//! ```text
//! R_t   = r_t + γ R_{t+1},   R_T = V_T
//! δ_t   = r_t + γ V_{t+1} − V_t,   A_t = Σ_k (γτ)^k δ_{t+k}       (GAE)
//! L_nav = Σ_t [ −log π(a_t) A_t − β H(π_t) ] + c_v Σ_t ½ (R_t − V_t)²
//! ```
//!
//! with γ = 0.99, τ = 1, β = 0.01, c_v = 0.5 (the reference's values). The gradient flows
//! into the policy (fusion, LSTM, heads) and, through the generated feature x_t, into G.

use anyhow::{bail, Result};
use gman_core::blob::TensorId;
use gman_core::dense::DenseGrads;
use gman_core::generator::{GeneratorCache, GeneratorScratch};
use gman_core::lstm::LstmGrads;
use gman_core::navigator::{Mode, Navigator};
use gman_core::policy::{PolicyCache, PolicyGrads, PolicyInput, PolicyInputGrads, PolicyScratch};
use gman_core::NUM_ACTIONS;

use super::rollout::StepRec;
use crate::train::params::ParamSet;

/// Hyper-parameters of the A3C loss.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct A3cConfig {
    /// Discount γ.
    pub gamma: f32,
    /// GAE τ.
    pub tau: f32,
    /// Entropy bonus β.
    pub entropy: f32,
    /// Value-loss coefficient c_v.
    pub value_coef: f32,
}

impl Default for A3cConfig {
    fn default() -> Self {
        A3cConfig {
            gamma: 0.99,
            tau: 1.0,
            entropy: 0.01,
            value_coef: 0.5,
        }
    }
}

/// What the policy is trained to do.
#[derive(
    Clone,
    Copy,
    Debug,
    Default,
    PartialEq,
    Eq,
    serde::Serialize,
    serde::Deserialize,
    clap::ValueEnum,
)]
#[serde(rename_all = "kebab-case")]
pub enum Objective {
    /// The A3C loss L_nav of the module docs (the paper's). Default.
    #[default]
    A3c,
    /// Imitation of the shortest-path oracle, DAgger-style: the learner acts (sampled
    /// actions, so it visits its own states), and every step is labelled with the oracle's
    /// optimal actions (uniform over the actions on a shortest path to a goal-visible state,
    /// Done once the target is visible). The policy term becomes the cross-entropy
    /// `−Σ_a π*(a) log π(a)` (no entropy bonus); the critic keeps its A3C value loss. A
    /// ceiling diagnostic: what this network can learn from these observations.
    Dagger,
}

impl Objective {
    /// The name used on the command line and in checkpoints.
    pub fn name(self) -> &'static str {
        match self {
            Objective::A3c => "a3c",
            Objective::Dagger => "dagger",
        }
    }
}

/// The parts of L_nav over a segment.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct SegmentLoss {
    /// Policy-gradient term `Σ −log π(a_t) A_t`.
    pub policy: f64,
    /// `Σ ½ (R_t − V_t)²`.
    pub value: f64,
    /// `Σ H(π_t)`.
    pub entropy: f64,
    /// Steps.
    pub steps: usize,
}

impl SegmentLoss {
    /// The total loss `policy − β entropy + c_v value`.
    pub fn total(&self, cfg: &A3cConfig) -> f64 {
        self.policy - cfg.entropy as f64 * self.entropy + cfg.value_coef as f64 * self.value
    }

    /// Adds another segment's parts.
    pub fn add(&mut self, o: &SegmentLoss) {
        self.policy += o.policy;
        self.value += o.value;
        self.entropy += o.entropy;
        self.steps += o.steps;
    }
}

/// Names of the gradient tensors written by [`segment_backward`].
pub(crate) const GRAD_NAMES: [&str; 13] = [
    "FuseW", "FuseB", "LstmWx", "LstmWh", "LstmB", "ActorW", "ActorB", "CriticW", "CriticB",
    "GenW1", "GenB1", "GenW2", "GenB2",
];

/// Per-step activations recomputed for back-propagation.
struct StepCache {
    prod: Vec<f32>,
    fuse: Vec<f32>,
    gates: Vec<f32>,
    c: Vec<f32>,
    h: Vec<f32>,
    actor_u: Vec<f32>,
    logits: Vec<f32>,
    probs: Vec<f32>,
    value: f32,
    cell: Vec<f32>,
    cell_prod: Vec<f32>,
}

/// Loss gradients at the outputs of each step: `(dlogits, dvalue)`, and the loss parts.
pub fn output_grads(
    seg: &[StepRec],
    values: &[f32],
    bootstrap: f32,
    cfg: &A3cConfig,
) -> (Vec<[f32; NUM_ACTIONS]>, Vec<f32>, SegmentLoss) {
    let n = seg.len();
    let mut dl = vec![[0.0f32; NUM_ACTIONS]; n];
    let mut dv = vec![0.0f32; n];
    let mut loss = SegmentLoss {
        steps: n,
        ..SegmentLoss::default()
    };
    let mut ret = bootstrap;
    let mut gae = 0.0f32;
    let mut next_v = bootstrap;
    for t in (0..n).rev() {
        let s = &seg[t];
        ret = s.reward + cfg.gamma * ret;
        let v = values[t];
        let adv = ret - v;
        loss.value += 0.5 * (adv as f64) * (adv as f64);
        dv[t] = cfg.value_coef * (v - ret);
        let delta = s.reward + cfg.gamma * next_v - v;
        gae = gae * cfg.gamma * cfg.tau + delta;
        next_v = v;
        let p = &s.probs;
        let logp: Vec<f32> = p.iter().map(|&q| q.max(1e-12).ln()).collect();
        let h: f32 = -p.iter().zip(&logp).map(|(q, l)| q * l).sum::<f32>();
        loss.entropy += h as f64;
        if let Some(e) = &s.expert {
            // Imitation: cross-entropy to the oracle's distribution, ∂/∂logits = π − π*.
            for i in 0..NUM_ACTIONS {
                loss.policy -= (e[i] * logp[i]) as f64;
                dl[t][i] = p[i] - e[i];
            }
            continue;
        }
        loss.policy -= (logp[s.action] * gae) as f64;
        for i in 0..NUM_ACTIONS {
            let onehot = if i == s.action { 1.0 } else { 0.0 };
            dl[t][i] = gae * (p[i] - onehot) + cfg.entropy * p[i] * (logp[i] + h);
        }
    }
    (dl, dv, loss)
}

/// Accumulates `∇ L_nav` of a segment into `grads` (names as in blobs; see the module docs),
/// at the navigator's *current* parameters (those the segment ran with: call before the
/// inner update). With `train_generator`, G's gradient through x_t is included.
pub fn segment_backward<M: Mode, const K: usize>(
    nav: &Navigator<'_, M, K>,
    seg: &[StepRec],
    bootstrap: f32,
    cfg: &A3cConfig,
    train_generator: bool,
    grads: &mut ParamSet,
) -> Result<SegmentLoss> {
    if seg.is_empty() {
        return Ok(SegmentLoss::default());
    }
    let policy = nav.policy()?;
    let gen = nav.generator()?;
    let attr = nav.attr().to_vec();
    let (f, e, hd) = (
        seg[0].obs.len(),
        policy.fuse.out_dim(),
        policy.lstm.hidden(),
    );
    let actor_gain = policy.actor.gain.is_some();
    let dims = *nav.dims();
    let (cell_out, cell_f) = (dims.cell_out(), if dims.map_cells() > 0 { f } else { 0 });
    // Recompute every step's activations with the same kernels and inputs as the navigator.
    let mut caches = Vec::with_capacity(seg.len());
    for s in seg {
        let mut c = StepCache {
            prod: vec![0.0; f],
            fuse: vec![0.0; e],
            gates: vec![0.0; 4 * hd],
            c: vec![0.0; hd],
            h: vec![0.0; hd],
            actor_u: vec![0.0; if actor_gain { NUM_ACTIONS } else { 0 }],
            logits: vec![0.0; NUM_ACTIONS],
            probs: vec![0.0; NUM_ACTIONS],
            value: 0.0,
            cell: vec![0.0; cell_out],
            cell_prod: vec![0.0; cell_f],
        };
        let inp = PolicyInput {
            obs: &s.obs,
            feat: &s.x,
            attr: &attr,
            prev_probs: &s.prev_probs,
            ps: &s.ps,
            map: &s.map,
        };
        let mut pc = PolicyCache {
            prod: &mut c.prod,
            fuse: &mut c.fuse,
            gates: &mut c.gates,
            c: &mut c.c,
            h: &mut c.h,
            actor_u: &mut c.actor_u,
            logits: &mut c.logits,
            probs: &mut c.probs,
            value: 0.0,
            cell: &mut c.cell,
            cell_prod: &mut c.cell_prod,
        };
        policy.forward(&inp, &s.h_prev, &s.c_prev, &mut pc)?;
        c.value = pc.value;
        if c.probs
            .iter()
            .zip(&s.probs)
            .any(|(a, b)| a.to_bits() != b.to_bits())
        {
            bail!("recomputed policy step differs from the navigator's (parameters changed mid-segment?)");
        }
        caches.push(c);
    }
    let values: Vec<f32> = caches.iter().map(|c| c.value).collect();
    let (dl, dv, loss) = output_grads(seg, &values, bootstrap, cfg);

    // The per-cell layer's gradient is accumulated here and added to `grads` at the end
    // (its tensors exist only in models with a spatial map).
    let size = |id: TensorId| {
        let (r, c) = id.shape(&dims);
        r * c
    };
    let (mut cellw_g, mut cellb_g) = (
        vec![0.0f32; size(TensorId::CellW)],
        vec![0.0f32; size(TensorId::CellB)],
    );
    let [fw, fb, lwx, lwh, lb, aw, ab, cw, cb, g1w, g1b, g2w, g2b] =
        grads.slices_mut(GRAD_NAMES)?;
    let mut pg = PolicyGrads {
        fuse: DenseGrads::Full { w: fw, b: fb },
        lstm: Some(LstmGrads {
            wx: lwx,
            wh: lwh,
            b: lb,
        }),
        actor: DenseGrads::Full { w: aw, b: ab },
        critic: DenseGrads::Full { w: cw, b: cb },
        cell: if dims.map_cells() > 0 {
            DenseGrads::Full {
                w: &mut cellw_g,
                b: &mut cellb_g,
            }
        } else {
            DenseGrads::None
        },
    };
    let mut g1 = DenseGrads::Full { w: g1w, b: g1b };
    let mut g2 = DenseGrads::Full { w: g2w, b: g2b };
    let gh = gen.hidden();
    let mut scratch = (
        vec![0.0f32; e],
        vec![0.0f32; 4 * hd],
        vec![0.0f32; f],
        vec![0.0f32; e.max(NUM_ACTIONS)],
        vec![0.0f32; hd],
    );
    let mut gbuf = (vec![0.0f32; gh], vec![0.0f32; f]);
    let mut gain_u = (vec![0.0f32; gh], vec![0.0f32; f]);
    let mut gscr = (
        vec![0.0f32; f],
        vec![0.0f32; gh],
        vec![0.0f32; gh],
        vec![0.0f32; f.max(gh)],
    );
    let mut dh_next = vec![0.0f32; hd];
    let mut dc_next = vec![0.0f32; hd];
    let mut dh_prev = vec![0.0f32; hd];
    let mut dc_prev = vec![0.0f32; hd];
    let mut dfeat = vec![0.0f32; f];
    let (mut dcell, mut cell_tmp) = (vec![0.0f32; cell_out], vec![0.0f32; cell_f]);
    for t in (0..seg.len()).rev() {
        let s = &seg[t];
        let c = &mut caches[t];
        let inp = PolicyInput {
            obs: &s.obs,
            feat: &s.x,
            attr: &attr,
            prev_probs: &s.prev_probs,
            ps: &s.ps,
            map: &s.map,
        };
        let pc = PolicyCache {
            prod: &mut c.prod,
            fuse: &mut c.fuse,
            gates: &mut c.gates,
            c: &mut c.c,
            h: &mut c.h,
            actor_u: &mut c.actor_u,
            logits: &mut c.logits,
            probs: &mut c.probs,
            value: c.value,
            cell: &mut c.cell,
            cell_prod: &mut c.cell_prod,
        };
        dfeat.fill(0.0);
        let mut out = PolicyInputGrads {
            feat: &mut dfeat,
            h_prev: &mut dh_prev,
            c_prev: &mut dc_prev,
        };
        let mut sc = PolicyScratch {
            de: &mut scratch.0,
            dgates: &mut scratch.1,
            dprod: &mut scratch.2,
            tmp: &mut scratch.3,
            dh: &mut scratch.4,
            dcell: &mut dcell,
            cell_tmp: &mut cell_tmp,
        };
        policy.backward(
            &inp, &s.h_prev, &s.c_prev, &pc, &dl[t], dv[t], &dh_next, &dc_next, &mut pg, &mut out,
            &mut sc,
        )?;
        std::mem::swap(&mut dh_next, &mut dh_prev);
        std::mem::swap(&mut dc_next, &mut dc_prev);
        if train_generator {
            // In the Efficient mode G's layers carry adapted per-unit gains: the gradient of
            // the base θ (W, b) is taken through them (Dense::backward with a gain).
            let mut gc = GeneratorCache {
                u1: if gen.l1.gain.is_some() {
                    &mut gain_u.0
                } else {
                    &mut []
                },
                h1: &mut gbuf.0,
                u2: if gen.l2.gain.is_some() {
                    &mut gain_u.1
                } else {
                    &mut []
                },
                x: &mut gbuf.1,
            };
            gen.forward(&s.z, &attr, &mut gc)?;
            let mut gs = GeneratorScratch {
                dpre2: &mut gscr.0,
                dh1: &mut gscr.1,
                dpre1: &mut gscr.2,
                tmp: &mut gscr.3,
            };
            gen.backward(&s.z, &attr, &gc, &dfeat, &mut g1, &mut g2, &mut gs)?;
        }
    }
    if dims.map_cells() > 0 {
        for (name, g) in [("CellW", &cellw_g), ("CellB", &cellb_g)] {
            let p = grads
                .get_mut(name)
                .ok_or_else(|| anyhow::anyhow!("gradient set has no {name}"))?;
            for (a, b) in p.data.iter_mut().zip(g) {
                *a += b;
            }
        }
    }
    Ok(loss)
}
