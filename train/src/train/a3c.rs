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
//! with γ = 0.99, τ = 1, β = 0.01, c_v = 0.5 (the reference's values). This module is the
//! loss maths only: [`output_grads`] gives `∂L/∂logits_t` and `∂L/∂V_t`; their
//! back-propagation through the policy (fusion, LSTM, heads) and, through the generated
//! feature x_t, into G is [`super::bptt`].

use gman_core::spec::Named;
use gman_core::NUM_ACTIONS;

use super::step::StepRec;

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
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
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

impl Named for Objective {
    const NAMES: &'static [(Objective, &'static str, &'static str)] = &[
        (
            Objective::A3c,
            "a3c",
            "The A3C loss L_nav of the module docs (the paper's). Default",
        ),
        (
            Objective::Dagger,
            "dagger",
            "Imitation of the shortest-path oracle, DAgger-style: the learner acts (sampled \
             actions, so it visits its own states), and every step is labelled with the \
             oracle's optimal actions (uniform over the actions on a shortest path to a \
             goal-visible state, Done once the target is visible). The policy term becomes \
             the cross-entropy `−Σ_a π*(a) log π(a)` (no entropy bonus); the critic keeps its \
             A3C value loss. A ceiling diagnostic: what this network can learn from these \
             observations",
        ),
    ];
    const VALUES: &'static [Objective] = &[Objective::A3c, Objective::Dagger];
}

impl Objective {
    /// The name used on the command line and in checkpoints.
    pub fn name(self) -> &'static str {
        Named::name(self)
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
