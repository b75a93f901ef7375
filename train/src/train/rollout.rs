//! A training episode's pieces around gman-core's navigator: the per-worker buffers, an
//! episode's summary, the oracle's action distribution, the bootstrap value of a segment
//! and D's carry-over to the next episode (what every episode of a model does first, in
//! training and in evaluation, is in [`crate::model::episode`]).

use anyhow::Result;
use gman_core::navigator::{Mode, Navigator};
use gman_core::{Action, NUM_ACTIONS};

use super::a3c::SegmentLoss;
use crate::model::{NavModel, K};
use crate::pretrain::ps::PsBuffers;
use crate::sim::Env;

/// Summary of a training episode.
#[derive(Clone, Debug, Default)]
pub struct EpisodeStats {
    /// Successful Done.
    pub success: bool,
    /// Steps taken.
    pub steps: u32,
    /// Sum of rewards.
    pub total_reward: f32,
    /// Inner updates applied.
    pub adaptations: u32,
    /// Inner steps rolled back.
    pub rollbacks: u32,
    /// Mean over the episode's inner updates of `E[D(s)] − E[D(x)]` (how well D separates
    /// observations from generated features); NaN without updates.
    pub disc_gap: f32,
    /// Mean over the episode's inner updates of L_ad; NaN without updates.
    pub adapt_loss: f32,
    /// The A3C loss parts.
    pub loss: SegmentLoss,
    /// The actions taken (indices), in order.
    pub actions: Vec<u8>,
    /// G's output x_t at the last step (after the episode's inner updates).
    pub final_feature: Vec<f32>,
}

/// The oracle's distribution over the actions on a shortest path to a goal-visible state
/// (Done when the target is visible or cannot be reached).
pub(crate) fn expert_distribution(env: &Env<'_>) -> [f32; NUM_ACTIONS] {
    let acts = env.oracle().optimal_actions();
    let mut e = [0.0f32; NUM_ACTIONS];
    if acts.is_empty() {
        e[Action::Done.index()] = 1.0;
    } else {
        let w = 1.0 / acts.len() as f32;
        for a in acts {
            e[a.index()] = w;
        }
    }
    e
}

/// Per-worker buffers reused across episodes.
pub struct Worker {
    /// The navigator's arena.
    pub arena: Vec<f32>,
    /// PS activations.
    pub ps: Option<PsBuffers>,
    /// The spatial map of the current step (empty for a model without a map).
    pub map: Vec<f32>,
    /// One arena per environment slot of the vectorised episodes of a method with an inner
    /// loop ([`super::engine`]), grown on first use.
    pub arenas: Vec<Vec<f32>>,
}

impl Worker {
    /// Buffers for `model`.
    pub fn new(model: &NavModel) -> Worker {
        Worker {
            arena: vec![0.0; model.arena_len()],
            ps: model.ps.as_ref().map(|p| PsBuffers::new(p.hidden)),
            map: vec![0.0; model.dims.map_len()],
            arenas: Vec::new(),
        }
    }
}

/// ω after an episode, to carry to the next one (in the order `DiscW1`, `DiscB1`, `DiscW2`,
/// `DiscB2`); in the Efficient mode D's first layer is `gain ⊙ (W1 s) + b1`, carried to the
/// next episode (whose gains restart at 1) as `diag(gain) W1`.
pub(crate) fn disc_after_episode<M: Mode>(nav: &Navigator<'_, M, K>) -> Result<Vec<Vec<f32>>> {
    let d = nav.discriminator()?;
    let (r, cc) = (d.l1.w.rows(), d.l1.w.cols());
    // `gain[row] * W1[row, col]` (1.0 without a gain), row by row over W1's values.
    let mut w1 = vec![0.0f32; r * cc];
    d.l1.w.copy_to(&mut w1)?;
    if cc > 0 {
        for (i, row) in w1.chunks_exact_mut(cc).enumerate() {
            let g = d.l1.gain.map_or(1.0, |g| g[i]);
            for v in row {
                *v *= g;
            }
        }
    }
    Ok(vec![w1, d.l1.b.to_vec(), d.w2.to_vec(), vec![d.b2]])
}
