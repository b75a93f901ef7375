//! The inner loop's bookkeeping shared by every rollout of training: the inner update when Ψ
//! is full (Algorithm 1, lines 14-20) with its tally, and an episode's closing statistics.

use anyhow::Result;
use gman_core::navigator::{Mode, Navigator};

use super::meta::InnerStep;
use super::rollout::EpisodeStats;
use crate::model::K;
use crate::sim::Env;

/// What the inner updates of an episode did: `E[D(s)] − E[D(x)]` and L_ad summed over them.
#[derive(Default)]
pub(crate) struct InnerTally {
    gap: f64,
    adapt_loss: f64,
    n: u32,
}

/// Algorithm 1, lines 14-20, when Ψ holds `K` steps: the navigator's inner update (D's
/// ascent on L_D, Eq. 1; θ_i, φ_i's descent on L_ad, Eq. 3; rolled back if it fails) while
/// the per-episode cap allows, else Ψ is emptied. With `second` (meta-order 2) the inner
/// step is recorded for the reverse recursion.
pub(crate) fn inner_update<M: Mode>(
    nav: &mut Navigator<'_, M, K>,
    second: bool,
    tally: &mut InnerTally,
) -> Result<Option<InnerStep>> {
    if nav.buffered() != K {
        return Ok(None);
    }
    if !nav.can_adapt() {
        nav.clear_buffer();
        return Ok(None);
    }
    let mut step = if second {
        Some(InnerStep::before_update(nav)?)
    } else {
        None
    };
    nav.adapt_now()?;
    if let Some(st) = step.as_mut() {
        st.after_update(nav)?;
    }
    let r = nav.last_adaptation();
    tally.gap += (r.ld.mean_real - r.ld.mean_fake) as f64;
    tally.adapt_loss += r.adapt_loss as f64;
    tally.n += 1;
    Ok(step)
}

/// The episode's outcome and inner-loop summary into `stats`.
pub(crate) fn finish_stats<M: Mode>(
    stats: &mut EpisodeStats,
    env: &Env<'_>,
    nav: &Navigator<'_, M, K>,
    tally: &InnerTally,
) {
    let m = env.metrics();
    let c = nav.counters();
    stats.success = m.success;
    stats.steps = env.steps();
    stats.total_reward = m.total_reward;
    stats.adaptations = c.adaptations;
    stats.rollbacks = c.rollbacks;
    let mean = |v: f64| {
        if tally.n > 0 {
            (v / tally.n as f64) as f32
        } else {
            f32::NAN
        }
    };
    stats.disc_gap = mean(tally.gap);
    stats.adapt_loss = mean(tally.adapt_loss);
    stats.final_feature = nav.generated_feature().to_vec();
}
