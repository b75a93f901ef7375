//! Running one episode with gman-core's navigator, for training (with the A3C gradient of
//! every segment and the Manual inner-loop schedule) and for evaluation.

use anyhow::{anyhow, Result};
use gman_core::memory::AdaptMode;
use gman_core::navigator::{Efficient, Full, Mode, Navigator};
use gman_core::policy::{PolicyCache, PolicyInput};
use gman_core::{Action, NUM_ACTIONS};

use super::a3c::{A3cConfig, Objective, SegmentLoss};
use super::bptt::segment_backward;
use super::meta::{add_adapted, meta_backward, take_adapted, InnerSetup, InnerStep};
use super::model::NavModel;
use super::step::StepRec;
use super::K;
use crate::sim::spatial::MapGrid;
use crate::sim::{Env, EpisodeSpec, RewardKind, World};
use crate::train::params::ParamSet;
use crate::train::ps::PsBuffers;

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
pub fn expert_distribution(env: &Env<'_>) -> [f32; NUM_ACTIONS] {
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

/// Starts `nav` on `spec`'s target: SE(y) and the episode seed, and for the
/// privileged-feature bound the target's true feature in the scene as x_t.
fn begin<M: Mode>(
    nav: &mut Navigator<'_, M, K>,
    world: &World,
    spec: &EpisodeSpec,
    model: &NavModel,
) -> Result<()> {
    nav.reset(world.attributes(spec.target), spec.seed)?;
    if model.privileged {
        nav.fix_generated_feature(&world.object_feature(spec.scene, spec.target))?;
    }
    Ok(())
}

/// The map grid of `model` (empty without a map).
fn map_grid(model: &NavModel) -> MapGrid {
    MapGrid {
        rows: model.dims.map_rows,
        cols: model.dims.map_cols,
    }
}

/// Per-worker buffers reused across episodes.
pub struct Worker {
    /// The navigator's arena.
    pub arena: Vec<f32>,
    /// PS activations.
    pub ps: Option<PsBuffers>,
    /// The spatial map of the current step (empty for a model without a map).
    pub map: Vec<f32>,
}

impl Worker {
    /// Buffers for `model`.
    pub fn new(model: &NavModel) -> Worker {
        // The Full layout is the larger one; an Efficient navigator fits in it too.
        Worker {
            arena: vec![0.0; Navigator::<Full, K>::arena_len(&model.dims)],
            ps: model.ps.as_ref().map(|p| PsBuffers::new(p.hidden)),
            map: vec![0.0; model.dims.map_len()],
        }
    }
}

fn ps_input(model: &NavModel, buf: &mut Option<PsBuffers>, obs: &[f32]) -> Result<Vec<f32>> {
    match (&model.ps, buf) {
        (Some(ps), Some(b)) => {
            ps.forward_buf(obs, b)?;
            Ok(b.y.clone())
        }
        _ => Ok(Vec::new()),
    }
}

/// The critic's value of the next observation at the navigator's current state, for
/// bootstrapping a segment that did not end the episode.
fn bootstrap_value<M: Mode>(
    nav: &Navigator<'_, M, K>,
    obs: &[f32],
    map: &[f32],
    ps: &[f32],
) -> Result<f32> {
    let p = nav.policy()?;
    let (f, e, hd) = (obs.len(), p.fuse.out_dim(), p.lstm.hidden());
    let d = *nav.dims();
    let mut cell = vec![0.0; d.cell_out()];
    let mut cell_prod = vec![0.0; if d.map_cells() > 0 { f } else { 0 }];
    let mut actor_u = vec![
        0.0;
        if p.actor.gain.is_some() {
            NUM_ACTIONS
        } else {
            0
        }
    ];
    let (mut prod, mut fuse, mut gates, mut c, mut h) = (
        vec![0.0; f],
        vec![0.0; e],
        vec![0.0; 4 * hd],
        vec![0.0; hd],
        vec![0.0; hd],
    );
    let (mut logits, mut probs) = ([0.0f32; NUM_ACTIONS], [0.0f32; NUM_ACTIONS]);
    let mut cache = PolicyCache {
        prod: &mut prod,
        fuse: &mut fuse,
        gates: &mut gates,
        c: &mut c,
        h: &mut h,
        actor_u: &mut actor_u,
        logits: &mut logits,
        probs: &mut probs,
        value: 0.0,
        cell: &mut cell,
        cell_prod: &mut cell_prod,
    };
    let inp = PolicyInput {
        obs,
        feat: nav.generated_feature(),
        attr: nav.attr(),
        prev_probs: nav.prev_probs(),
        ps,
        map,
    };
    p.forward(&inp, nav.hidden_state(), nav.cell_state(), &mut cache)?;
    Ok(cache.value)
}

/// Runs one training episode: every `K` steps (or at the end) the segment's A3C gradient is
/// accumulated into `grads` at the parameters the segment ran with, then — for the methods
/// that adapt — the navigator's inner update (Algorithm 1, lines 15-20) runs. Returns the
/// episode's statistics and D's parameters after the episode (in the order `DiscW1`,
/// `DiscB1`, `DiscW2`, `DiscB2`), since ω learns across episodes.
///
/// `meta_order` 1 sums the segments' gradients at the adapted parameters (first-order MAML);
/// 2 (for the methods that adapt) back-propagates the θ and φ parts through the inner SGD
/// steps instead (see [`super::meta`]); the fusion, LSTM and critic gradients are the same
/// sum in both.
///
/// The inner loop runs in the model's adaptation mode ([`NavModel::adapt_mode`]), the mode
/// its blob will record and the device will run: in `Efficient`, the segment gradients of θ
/// and of the actor head are taken through the adapted per-unit gains and biases, and D's
/// adapted gains are folded into its first layer when ω is carried to the next episode.
#[allow(clippy::too_many_arguments)]
pub fn train_episode(
    world: &World,
    spec: &EpisodeSpec,
    model: &NavModel,
    reward: RewardKind,
    max_steps: u32,
    a3c: &A3cConfig,
    objective: Objective,
    meta_order: u8,
    worker: &mut Worker,
    grads: &mut ParamSet,
) -> Result<(EpisodeStats, Vec<Vec<f32>>)> {
    match model.adapt_mode {
        AdaptMode::Full => train_episode_in::<Full>(
            world, spec, model, reward, max_steps, a3c, objective, meta_order, worker, grads,
        ),
        AdaptMode::Efficient => train_episode_in::<Efficient>(
            world, spec, model, reward, max_steps, a3c, objective, meta_order, worker, grads,
        ),
    }
}

#[allow(clippy::too_many_arguments)]
fn train_episode_in<M: Mode>(
    world: &World,
    spec: &EpisodeSpec,
    model: &NavModel,
    reward: RewardKind,
    max_steps: u32,
    a3c: &A3cConfig,
    objective: Objective,
    meta_order: u8,
    worker: &mut Worker,
    grads: &mut ParamSet,
) -> Result<(EpisodeStats, Vec<Vec<f32>>)> {
    if !(1..=2).contains(&meta_order) {
        return Err(anyhow!("meta order must be 1 or 2, not {meta_order}"));
    }
    if model.privileged && model.method.adapts_in_training() {
        return Err(anyhow!(
            "the privileged-feature bound replaces G's output and cannot adapt G; use it with a method without inner loop (a3c-fg)"
        ));
    }
    let train_generator = model.method.trains_generator() && !model.privileged;
    let second = meta_order == 2 && model.method.adapts_in_training();
    if second && M::MODE != AdaptMode::Full {
        return Err(anyhow!(
            "the second-order meta-gradient is implemented for the Full adaptation mode; use --adapt-mode full or --meta-order 1"
        ));
    }
    // Order 2: each segment's gradient goes to `seg_g` first; its θ, φ parts are kept per
    // segment (with the inner steps) for the reverse recursion at the end of the episode.
    let mut seg_g = if second {
        Some(grads.zeros_like())
    } else {
        None
    };
    let mut seg_grads: Vec<(Vec<f32>, Vec<f32>)> = Vec::new();
    let mut steps: Vec<Option<InnerStep>> = Vec::new();
    let weights = model.weights()?;
    let mut nav: Navigator<'_, M, K> =
        Navigator::new(weights, &mut worker.arena, model.nav_config(true))?;
    begin(&mut nav, world, spec, model)?;
    let mut env = Env::new(world, spec, reward, max_steps);
    let mut stats = EpisodeStats::default();
    let (mut gap, mut lad, mut n_upd) = (0.0f64, 0.0f64, 0u32);
    let mut seg: Vec<StepRec> = Vec::with_capacity(K);
    let mut actions = Vec::new();
    let grid = map_grid(model);
    loop {
        seg.clear();
        while seg.len() < K && !env.is_done() {
            let obs = env.observe();
            let ps = ps_input(model, &mut worker.ps, &obs.features)?;
            if !grid.is_empty() {
                env.observe_map(grid, &mut worker.map);
            }
            let h_prev = nav.hidden_state().to_vec();
            let c_prev = nav.cell_state().to_vec();
            let prev_probs = nav.prev_probs().to_vec();
            let expert = (objective == Objective::Dagger).then(|| expert_distribution(&env));
            let out = nav.step_map(&obs.features, &worker.map, &ps)?;
            actions.push(out.action.index() as u8);
            let o = env.step(out.action);
            seg.push(StepRec {
                obs: obs.features.to_vec(),
                ps,
                map: worker.map.clone(),
                x: nav.generated_feature().to_vec(),
                z: nav.noise().to_vec(),
                h_prev,
                c_prev,
                prev_probs,
                action: out.action.index(),
                reward: o.reward,
                probs: out.probs,
                expert,
            });
        }
        let bootstrap = if env.is_done() {
            0.0
        } else {
            let obs = env.observe();
            let ps = ps_input(model, &mut worker.ps, &obs.features)?;
            if !grid.is_empty() {
                env.observe_map(grid, &mut worker.map);
            }
            bootstrap_value(&nav, &obs.features, &worker.map, &ps)?
        };
        let l = match seg_g.as_mut() {
            Some(g) => {
                g.zero();
                let l = segment_backward(&nav, &seg, bootstrap, a3c, train_generator, g)?;
                seg_grads.push(take_adapted(g)?);
                grads.add_assign(g)?;
                l
            }
            None => segment_backward(&nav, &seg, bootstrap, a3c, train_generator, grads)?,
        };
        stats.loss.add(&l);
        if env.is_done() {
            break;
        }
        let mut step = None;
        if nav.buffered() == K {
            if nav.can_adapt() {
                let mut st = if second {
                    Some(InnerStep::before_update(&nav)?)
                } else {
                    None
                };
                nav.adapt_now()?;
                if let Some(st) = st.as_mut() {
                    st.after_update(&nav)?;
                }
                step = st;
                let r = nav.last_adaptation();
                gap += (r.ld.mean_real - r.ld.mean_fake) as f64;
                lad += r.adapt_loss as f64;
                n_upd += 1;
            } else {
                nav.clear_buffer();
            }
        }
        if second {
            steps.push(step);
        }
    }
    if second {
        let (mt, mp) = meta_backward(&InnerSetup::of(&nav), &steps, &seg_grads)?;
        add_adapted(grads, &mt, &mp)?;
    }
    let m = env.metrics();
    let c = nav.counters();
    stats.success = m.success;
    stats.steps = env.steps();
    stats.total_reward = m.total_reward;
    stats.adaptations = c.adaptations;
    stats.rollbacks = c.rollbacks;
    stats.disc_gap = if n_upd > 0 {
        (gap / n_upd as f64) as f32
    } else {
        f32::NAN
    };
    stats.adapt_loss = if n_upd > 0 {
        (lad / n_upd as f64) as f32
    } else {
        f32::NAN
    };
    stats.actions = actions;
    stats.final_feature = nav.generated_feature().to_vec();
    Ok((stats, disc_after_episode(&nav)?))
}

/// ω after an episode, to carry to the next one (in the order `DiscW1`, `DiscB1`, `DiscW2`,
/// `DiscB2`); in the Efficient mode D's first layer is `gain ⊙ (W1 s) + b1`, carried to the
/// next episode (whose gains restart at 1) as `diag(gain) W1`.
pub(crate) fn disc_after_episode<M: Mode>(nav: &Navigator<'_, M, K>) -> Result<Vec<Vec<f32>>> {
    let d = nav.discriminator()?;
    let (r, cc) = (d.l1.w.rows(), d.l1.w.cols());
    let w1: Vec<f32> = (0..r * cc)
        .map(|i| d.l1.gain.map_or(1.0, |g| g[i / cc]) * d.l1.w.get(i / cc, i % cc))
        .collect();
    Ok(vec![w1, d.l1.b.to_vec(), d.w2.to_vec(), vec![d.b2]])
}

/// Runs one evaluation episode in `env` with the device's schedule (inner update inside
/// `step`, every `K` steps). D starts from the model's ω in every episode, so results do not
/// depend on episode order or worker count. On a navigator error the agent issues Done (and
/// the error is returned for reporting).
///
/// The model runs in its adaptation mode ([`NavModel::adapt_mode`]; a blob's is recorded in
/// its header), a blob over its weights in place, exactly as on the device.
pub fn eval_episode(
    env: &mut Env<'_>,
    spec: &EpisodeSpec,
    model: &NavModel,
    worker: &mut Worker,
) -> Result<()> {
    if eval_mode_is_efficient(model) {
        eval_episode_in::<Efficient>(env, spec, model, worker)
    } else {
        eval_episode_in::<Full>(env, spec, model, worker)
    }
}

/// True when `model` runs in the `Efficient` adaptation mode (what the microcontroller runs).
pub fn eval_mode_is_efficient(model: &NavModel) -> bool {
    model.adapt_mode == AdaptMode::Efficient
}

fn eval_episode_in<M: Mode>(
    env: &mut Env<'_>,
    spec: &EpisodeSpec,
    model: &NavModel,
    worker: &mut Worker,
) -> Result<()> {
    let weights = model.weights()?;
    let mut nav: Navigator<'_, M, K> =
        Navigator::new(weights, &mut worker.arena, model.nav_config(false))?;
    begin(&mut nav, env.world(), spec, model)?;
    let grid = map_grid(model);
    while !env.is_done() {
        let obs = env.observe();
        let ps = ps_input(model, &mut worker.ps, &obs.features)?;
        if !grid.is_empty() {
            env.observe_map(grid, &mut worker.map);
        }
        match nav.step_map(&obs.features, &worker.map, &ps) {
            Ok(out) => {
                env.step(out.action);
            }
            Err(e) => {
                env.step(Action::Done);
                return Err(anyhow!("navigator: {e}"));
            }
        }
    }
    Ok(())
}
