//! Vectorised training episodes of the methods with an inner loop in training (`gman`,
//! `gman-cossim`, `gman-fixed-g`, `gman-ps`, ...): one worker steps `B` environments in
//! lockstep, each episode run by **its own gman-core [`Navigator`]** (the device's code, in
//! the mode the model records), with the policy's trunk of all of them as one batch.
//!
//! ```text
//! while a slot is free and the worker's step budget is not spent: start episode e in it
//!   (the slot's navigator: D from the model's ω, reset to θ, φ with episode e's seed)
//! every tick:
//!   each running episode: observation, PS input, map;
//!     Navigator::begin_step: x_t = G_θi(SE(y), z_t) from this episode's θ_i   (line 7)
//!   one batched trunk forward (fusion + LSTM, never adapted) over the running episodes
//!   each episode: Navigator::finish_step with its row's (h, c): its own adapted actor head,
//!     the critic, the action, Ψ (lines 8-13); the environment steps
//!   the episodes whose segment is complete (k = 20 steps, or the episode ended):
//!     bootstrap values (one batched trunk forward)
//!     Full mode or B = 1: ONE batched BPTT over these segments now, each row at its
//!       episode's live adapted actor head φ_i and G θ_i
//!     Efficient mode, B > 1: the segments wait with a copy of their episode's adapted
//!       gains and biases
//!     then each of them (slot order): the episode ended -> its statistics and D, slot freed;
//!       else the inner update on its own Ψ (Navigator::adapt_now, lines 14-20)
//! at the end of the update (Efficient, B > 1): ONE batched BPTT over all waiting segments
//! ```
//!
//! **When a segment's backward runs.** Every k = 20 steps an episode's inner update changes
//! its θ_i and φ_i, and the A3C gradient of the segment before it must be taken at the
//! parameters it ran with (first-order meta-gradient: the gradient at the adapted parameters
//! is summed into that of the pre-adaptation ones, as [`super::trainer::train_episode`] does
//! with [`super::bptt::segment_backward`]). Two ways keep that, and each mode takes the one
//! that is cheap for it:
//! * **Efficient mode** (the `mcu` default): the adapted parameters are the per-unit gains
//!   and biases of the actor head and of G's two layers (~1.5k floats for `mcu`), the
//!   matrices are the model's. A complete segment keeps a copy of them and waits, like the
//!   a3c path's segments ([`super::vec_rollout`]): one batched BPTT over all the update's
//!   segments (or earlier, whenever [`MAX_PENDING_STEPS`] steps wait), each row through its
//!   copy. The backward's batches are then as large as the a3c path's, and G's backward
//!   runs over them as one batch (the rows share G's matrices). G's activations of every
//!   x_t are kept from the navigator's step (`Navigator::generator_activations`), so the
//!   backward does not run G again.
//! * **Full mode** (the `paper` default): θ_i is all of G (~154k floats for `mcu`), too
//!   large to copy per segment. A complete segment's backward runs at once, batched over
//!   the segments completing at the same tick, each row through its navigator's live views,
//!   before that navigator's inner update; G's backward runs row by row (each row its own
//!   matrices).
//!
//! **Gradient order.** Efficient, `B > 1`: one batched BPTT over the segments of the update
//! (or of each [`MAX_PENDING_STEPS`] chunk), longest first, then in the order they completed
//! (tick, then slot). Full (and `B = 1`): ticks in order, within a tick one batched BPTT over
//! its complete segments, longest first, then by slot. Within a BPTT
//! (`bptt::Backward::run`) every tensor's gradient is summed step by step (last step
//! first) and, within a step, over the rows in order; the actor head's and the critic's rows
//! run one at a time in that order (each row its own head), the trunk as one batch. The order
//! is fixed by `(seed, update, worker, B)`, so runs are reproducible and resume bit for bit.
//! With `B = 1` every batch is one segment, completing before its episode's inner update:
//! [`super::trainer::train_episode`]'s order, bit for bit (`tests/vec_rollout.rs`); with
//! `B > 1` the sum is the per-episode sum within float rounding (the same test file checks
//! 1e-4 of each tensor's largest value; this module's test pins the order in both modes).
//!
//! **Each episode is the episode its navigator runs alone**, bit for bit (actions,
//! probabilities, inner updates, D after it): `begin_step` / `finish_step` are `step` split
//! around the trunk (`tests/tests/navigator.rs`), and the batched trunk gives every row the
//! bits of the batch-1 one. A slot's navigator is reused across the slot's episodes: D is
//! restored from the model's ω and the navigator reset for each, the state a new navigator
//! has (what [`super::trainer::train_episode`] builds per episode). D's carry-over across
//! episodes is the batch-1 trainer's: every episode starts from ω, and the outer step adds
//! `Σ_e (ω_e − ω)` in episode order.
//!
//! **Memory.** A worker holds `B` navigator arenas (`Navigator::arena_len_for` the host's
//! `Footprint::Fast`: 452 KiB each for `mcu` in the Efficient mode; in the Full mode each
//! holds a copy of G and D, 1.9 MiB for `mcu`), plus the waiting segments (at most
//! [`MAX_PENDING_STEPS`] steps).
//!
//! Not served here: `--meta-order 2` (its reverse recursion runs per episode, refused with
//! `B > 1`) and the privileged-feature bound (refused with an inner loop, as in batch 1).
//!
//! [`MAX_PENDING_STEPS`]: super::lockstep::MAX_PENDING_STEPS

use anyhow::{anyhow, bail, Result};
use gman_core::blob::TensorId;
use gman_core::dense::Dense;
use gman_core::generator::Generator;
use gman_core::matrix::{MatRef, Weights};
use gman_core::memory::AdaptMode;
use gman_core::navigator::{
    Efficient, Full, Mode, NavConfig, NavWeights, Navigator, NoiseMode, Selection,
};
use gman_core::policy::Policy;
use gman_core::{Dims, NUM_ACTIONS};

use super::a3c::{A3cConfig, Objective};
use super::bptt::{take_act, Adapted, Backward, GenBufs, Rows, Segment, Widths};
use super::inner::{finish_stats, inner_update, InnerTally};
use super::lockstep::{
    backward_order, backward_segments, bootstrap_values, check_batch_envs, collect_losses,
    lockstep, put_row, BackwardCtx, Finished, PendingSeg, Recording, RowState, SegQueue, Share,
    StepInputs, VecSettings,
};
use super::rollout::{disc_after_episode, expert_distribution, EpisodeStats, Worker};
use super::step::StepRec;
use crate::model::episode::{begin, map_grid};
use crate::model::{NavModel, K};
use crate::optim::params::ParamSet;
use crate::pretrain::ps::PsBuffers;
use crate::sim::spatial::MapGrid;
use crate::sim::{Env, EpisodeSpec, World};

/// Runs one worker's share of an update of a method with an inner loop with
/// `s.batch_envs` environments in lockstep (see the module docs); episodes `e = 0, 1, ..`
/// from `sample(e)`, started while the worker has taken fewer than `s.min_steps` steps, as
/// in [`super::vec_rollout::run_worker`]. Returns the finished episodes sorted by index, each
/// with D after it.
pub fn run_worker(
    job: Share<'_, '_, impl FnMut(u32) -> Result<(EpisodeSpec, u32)>>,
) -> Result<Vec<Finished>> {
    match job.model.adapt_mode {
        AdaptMode::Full => run_in::<Full>(job, None),
        AdaptMode::Efficient => run_in::<Efficient>(job, None),
    }
}

/// A running episode: its environment, the segment being recorded and its statistics (the
/// navigator is the slot's).
struct Ep<'w> {
    e: u32,
    env: Env<'w>,
    rec: Recording,
    stats: EpisodeStats,
    tally: InnerTally,
    /// This step's inputs.
    inp: StepInputs,
    // The navigator's state before this step.
    h_prev: Vec<f32>,
    c_prev: Vec<f32>,
    prev: Vec<f32>,
}

/// A logged segment: steps, activations, SE(y), `V_T`.
#[cfg(test)]
type LoggedSeg = (Vec<StepRec>, Vec<super::bptt::StepAct>, Vec<f32>, f32);

/// A copy of a dense layer: `W` (row-major), `b`, the gain.
#[cfg(test)]
type LayerCopy = (Vec<f32>, Vec<f32>, Option<Vec<f32>>);

/// What the test of the order records of one backward: the segments (in the order given to
/// the BPTT) with a copy of each row's adapted parameters.
#[cfg(test)]
pub(crate) struct TickLog {
    segs: Vec<LoggedSeg>,
    /// Per row: actor, G layer 1, G layer 2.
    params: Vec<[LayerCopy; 3]>,
}

#[cfg(not(test))]
pub(crate) struct TickLog;

/// A complete segment, with (when its backward waits) a copy of the episode's adapted
/// parameters it ran with.
type Pending = PendingSeg<Option<OwnCopy>>;

/// What every tick of a worker's update reads: the model and its settings, the widths, and
/// the trunk (and a G) of a navigator over the model's weights that does not adapt, for the
/// waiting segments' backward.
struct Fixed<'a, 'w> {
    model: &'a NavModel,
    objective: Objective,
    grid: MapGrid,
    weights: NavWeights<'w>,
    trunk: Policy<'a>,
    gen: Generator<'a>,
    a3c: &'a A3cConfig,
    train_generator: bool,
    w: Widths,
    d: Dims,
    /// Efficient and B > 1: the segments' backward waits (see the module docs).
    defer: bool,
}

/// The buffers and running tallies of a worker's update.
struct Bufs<'b, 'l> {
    ps: &'b mut Option<PsBuffers>,
    rows: Rows,
    gen_scratch: Vec<f32>,
    bw: Backward,
    gbuf: GenBufs,
    /// The waiting segments (Efficient, B > 1), the losses of those whose backward ran.
    queue: SegQueue<Option<OwnCopy>>,
    log: Option<&'l mut Vec<TickLog>>,
}

/// The settings this module refuses: a method without inner loop, the privileged feature, a
/// navigator that does not sample.
fn check_settings(model: &NavModel, s: &VecSettings<'_>) -> Result<()> {
    check_batch_envs(model, s.batch_envs, 1)?;
    if !model.method.adapts_in_training() {
        bail!("vec_adapt runs the methods with an inner loop in training");
    }
    if model.privileged {
        bail!("the privileged-feature bound replaces G's output and cannot adapt G; use it with a method without inner loop (a3c-fg)");
    }
    if model.nav_config(true).selection != Selection::Sample {
        bail!("vectorised episodes need a sampling navigator");
    }
    Ok(())
}

/// The slots' navigators: `b` of them over the model, each in its own arena of `arenas`
/// (grown on first use).
fn slot_navigators<'a, M: Mode>(
    model: &NavModel,
    weights: NavWeights<'a>,
    cfg: NavConfig,
    arenas: &'a mut Vec<Vec<f32>>,
    b: usize,
) -> Result<Vec<Navigator<'a, M, K>>> {
    let alen = Navigator::<M, K>::arena_len_for(&model.dims, cfg.footprint);
    if arenas.len() < b {
        arenas.resize_with(b, Vec::new);
    }
    let mut navs: Vec<Navigator<'_, M, K>> = Vec::with_capacity(b);
    for a in arenas.iter_mut().take(b) {
        if a.len() < alen {
            a.resize(alen, 0.0);
        }
        navs.push(Navigator::new(weights, a, cfg)?);
    }
    Ok(navs)
}

/// [`run_worker`] in the adaptation mode `M`; `log` (the tests') records every backward's
/// batch.
fn run_in<'w, M: Mode>(
    job: Share<'_, 'w, impl FnMut(u32) -> Result<(EpisodeSpec, u32)>>,
    log: Option<&mut Vec<TickLog>>,
) -> Result<Vec<Finished>> {
    let Share {
        world,
        model,
        s,
        worker,
        grads,
        sample,
    } = job;
    check_settings(model, s)?;
    let cfg = model.nav_config(true);
    let b = s.batch_envs;
    let weights = model.weights()?;
    let Worker {
        ps: ps_buf, arenas, ..
    } = worker;
    let mut navs = slot_navigators::<M>(model, weights, cfg, arenas, b)?;
    let d = *navs[0].dims();
    let w = Widths::of(&navs[0].policy()?, &d);
    let mut fixed_arena =
        vec![0.0f32; Navigator::<M, K>::arena_len_for(&model.dims, cfg.footprint)];
    let fixed_nav: Navigator<'_, M, K> = Navigator::new(
        weights,
        &mut fixed_arena,
        NavConfig {
            adapt: false,
            ..cfg
        },
    )?;
    let fx = Fixed {
        model,
        objective: s.objective,
        grid: map_grid(model),
        weights,
        trunk: fixed_nav.policy()?,
        gen: fixed_nav.generator()?,
        a3c: s.a3c,
        train_generator: model.method.trains_generator(),
        w,
        d,
        defer: M::MODE == AdaptMode::Efficient && b > 1,
    };
    let mut bufs = Bufs {
        ps: ps_buf,
        rows: Rows::default(),
        gen_scratch: Vec::new(),
        bw: Backward::default(),
        gbuf: GenBufs::new(&navs[0].generator()?, w.f),
        queue: SegQueue::new(),
        log,
    };
    let mut done: Vec<Finished> = Vec::new();
    lockstep(
        b,
        s.min_steps,
        sample,
        &mut navs,
        |navs, i, e, spec, max| start_episode(&mut navs[i], world, spec, model, s, max, e),
        |navs, eps: &mut [Option<Ep<'w>>]| {
            let active: Vec<usize> = (0..eps.len())
                .filter(|&i| eps[i].as_ref().is_some_and(|e| !e.env.is_done()))
                .collect();
            let taken = tick(&fx, &mut bufs, navs, eps, &active)?;
            close_ready(&fx, &mut bufs, navs, eps, grads, &mut done)?;
            Ok(taken)
        },
    )?;
    flush_copies(&fx, &mut bufs, grads)?;
    collect_losses(bufs.queue.losses, done)
}

/// After a tick: the segments complete at it (k recorded steps, then the commit window of a
/// delayed update if any; or the episode ended) get their bootstrap values and either wait
/// (Efficient, `B > 1`) or join this tick's batched BPTT; then each of those episodes ends or
/// runs its inner update.
fn close_ready<M: Mode>(
    fx: &Fixed<'_, '_>,
    bufs: &mut Bufs<'_, '_>,
    navs: &mut [Navigator<'_, M, K>],
    eps: &mut [Option<Ep<'_>>],
    grads: &mut ParamSet,
    done: &mut Vec<Finished>,
) -> Result<()> {
    let ready: Vec<usize> = (0..eps.len())
        .filter(|&i| {
            eps[i].as_ref().is_some_and(|e| {
                (e.rec.len() >= K && !navs[i].in_commit_window()) || e.env.is_done()
            })
        })
        .collect();
    if ready.is_empty() {
        return Ok(());
    }
    let fresh = complete_segments(fx, bufs, navs, eps, &ready)?;
    if fx.defer {
        // Efficient, B > 1: the segments wait, with copies of their episodes' gains and
        // biases, for one batched BPTT over the update.
        for seg in fresh {
            bufs.queue.wait(seg);
        }
        if bufs.queue.full() {
            flush_copies(fx, bufs, grads)?;
        }
    } else {
        backward_live(fx, bufs, navs, fresh, grads)?;
    }
    close_or_adapt(&ready, navs, eps, done)
}

/// Starts episode `e` in a slot: its navigator in the state of a new navigator over the
/// model (what the batch-1 trainer builds for every episode): D from ω, θ_i = θ, φ_i = φ, the
/// episode's seed.
fn start_episode<'w, M: Mode>(
    nav: &mut Navigator<'_, M, K>,
    world: &'w World,
    spec: &EpisodeSpec,
    model: &NavModel,
    s: &VecSettings<'_>,
    max: u32,
    e: u32,
) -> Result<Ep<'w>> {
    nav.reset_discriminator()?;
    begin(nav, world, spec, model)?;
    Ok(Ep {
        e,
        env: Env::new(world, spec, s.reward, max),
        rec: Recording::new(),
        stats: EpisodeStats::default(),
        tally: InnerTally::default(),
        inp: StepInputs::default(),
        h_prev: Vec::new(),
        c_prev: Vec::new(),
        prev: Vec::new(),
    })
}

/// The segments complete at this tick (`ready`): their bootstrap values, then each
/// non-empty one taken from its episode, numbered in slot order (`seq`: the order they
/// completed), with a copy of the episode's adapted parameters when its backward waits.
fn complete_segments<M: Mode>(
    fx: &Fixed<'_, '_>,
    b: &mut Bufs<'_, '_>,
    navs: &[Navigator<'_, M, K>],
    eps: &mut [Option<Ep<'_>>],
    ready: &[usize],
) -> Result<Vec<Pending>> {
    let boot = bootstrap(fx, b, navs, eps, ready)?;
    let mut fresh: Vec<Pending> = Vec::new();
    for (&i, bootv) in ready.iter().zip(boot) {
        let ep = eps[i].as_mut().ok_or_else(|| anyhow!("empty slot"))?;
        if ep.rec.is_empty() {
            continue;
        }
        let nav = &navs[i];
        let own = if fx.defer {
            Some(OwnCopy::of(nav, &fx.weights)?)
        } else {
            None
        };
        let attr = nav.attr().to_vec();
        fresh.push(b.queue.complete(i, ep.e, &mut ep.rec, attr, bootv, own));
    }
    Ok(fresh)
}

/// One batched BPTT over this tick's segments (longest first, then by slot), each row at its
/// episode's live adapted parameters (before its inner update).
fn backward_live<M: Mode>(
    fx: &Fixed<'_, '_>,
    b: &mut Bufs<'_, '_>,
    navs: &[Navigator<'_, M, K>],
    mut fresh: Vec<Pending>,
    grads: &mut ParamSet,
) -> Result<()> {
    if fresh.is_empty() {
        return Ok(());
    }
    backward_order(&mut fresh);
    let trunk = navs[fresh[0].slot].policy()?;
    let gen0 = navs[fresh[0].slot].generator()?;
    let bx = BackwardCtx {
        policy: &trunk,
        gen: &gen0,
        a3c: fx.a3c,
        train_generator: fx.train_generator,
        w: &fx.w,
        d: &fx.d,
    };
    backward_logged(
        &bx,
        &mut fresh,
        |p| {
            let nav = &navs[p.slot];
            Ok(Some(Adapted {
                actor: nav.policy()?.actor,
                gen: nav.generator()?,
            }))
        },
        b,
        grads,
    )
}

/// [`backward_segments`] over `pend` with `b`'s buffers, the batch shown to the test log.
fn backward_logged<'p>(
    bx: &BackwardCtx<'_>,
    pend: &'p mut [Pending],
    own: impl Fn(&'p Pending) -> Result<Option<Adapted<'p>>>,
    b: &mut Bufs<'_, '_>,
    grads: &mut ParamSet,
) -> Result<()> {
    let log = &mut b.log;
    backward_segments(
        bx,
        pend,
        own,
        |segs| {
            if let Some(l) = log.as_deref_mut() {
                l.push(tick_log(segs));
            }
        },
        grads,
        &mut b.bw,
        &mut b.gbuf,
        &mut b.queue.losses,
    )
}

/// Each of the `ready` episodes in slot order: an ended one gives its statistics and D and
/// frees its slot; the others run their inner update on Ψ.
fn close_or_adapt<M: Mode>(
    ready: &[usize],
    navs: &mut [Navigator<'_, M, K>],
    eps: &mut [Option<Ep<'_>>],
    done: &mut Vec<Finished>,
) -> Result<()> {
    for &i in ready {
        let nav = &mut navs[i];
        let ended = eps[i].as_ref().is_some_and(|e| e.env.is_done());
        if ended {
            let ep = eps[i].take().ok_or_else(|| anyhow!("empty slot"))?;
            let mut stats = ep.stats;
            finish_stats(&mut stats, &ep.env, nav, &ep.tally);
            // D learns from a buffer whose delayed update had not committed yet.
            nav.settle()?;
            done.push((ep.e, stats, disc_after_episode(nav)?));
        } else {
            let ep = eps[i].as_mut().ok_or_else(|| anyhow!("empty slot"))?;
            inner_update(nav, false, &mut ep.tally)?;
        }
    }
    Ok(())
}

/// A copy of an episode's adapted parameters in the Efficient mode: the per-unit gains and
/// biases of its actor head and of G's two layers (their matrices are the model's).
struct OwnCopy {
    layers: [(Option<Vec<f32>>, Vec<f32>); 3],
}

impl OwnCopy {
    /// The copy of `nav`'s adapted parameters; refused unless its views' matrices are the
    /// model's `weights` (only gains and biases adapted).
    fn of<M: Mode>(nav: &Navigator<'_, M, K>, weights: &NavWeights<'_>) -> Result<OwnCopy> {
        let (p, g) = (nav.policy()?, nav.generator()?);
        let mut layers: [(Option<Vec<f32>>, Vec<f32>); 3] = Default::default();
        for (k, (l, id)) in [
            (p.actor, TensorId::ActorW),
            (g.l1, TensorId::GenW1),
            (g.l2, TensorId::GenW2),
        ]
        .into_iter()
        .enumerate()
        {
            if !same_matrix(&l.w, &weights.get(id)) {
                bail!("vec_adapt: a waiting segment needs the model's matrices (Efficient mode)");
            }
            layers[k] = (l.gain.map(|v| v.to_vec()), l.b.to_vec());
        }
        Ok(OwnCopy { layers })
    }

    /// Views over the copy and the model's matrices.
    fn views<'a>(&'a self, weights: &NavWeights<'a>) -> Adapted<'a> {
        let d = |k: usize, id: TensorId| Dense {
            w: weights.get(id),
            b: &self.layers[k].1,
            gain: self.layers[k].0.as_deref(),
        };
        Adapted {
            actor: d(0, TensorId::ActorW),
            gen: Generator {
                l1: d(1, TensorId::GenW1),
                l2: d(2, TensorId::GenW2),
            },
        }
    }
}

/// True when two views read the same f32 matrix.
fn same_matrix(a: &MatRef<'_>, b: &MatRef<'_>) -> bool {
    match (a.weights(), b.weights()) {
        (Weights::F32(x), Weights::F32(y)) => {
            x.as_ptr() == y.as_ptr() && x.len() == y.len() && a.rows() == b.rows()
        }
        _ => false,
    }
}

/// The backward of the waiting segments as one batched BPTT, longest first (then in the
/// order they completed), each row at the copy of its episode's adapted parameters; their
/// losses collected as `(episode, seq, loss)`; nothing waits afterwards.
fn flush_copies(fx: &Fixed<'_, '_>, b: &mut Bufs<'_, '_>, grads: &mut ParamSet) -> Result<()> {
    let mut pend = b.queue.take();
    let bx = BackwardCtx {
        policy: &fx.trunk,
        gen: &fx.gen,
        a3c: fx.a3c,
        train_generator: fx.train_generator,
        w: &fx.w,
        d: &fx.d,
    };
    backward_logged(
        &bx,
        &mut pend,
        |p| {
            let own = p
                .own
                .as_ref()
                .ok_or_else(|| anyhow!("vec_adapt: a waiting segment without its parameters"))?;
            Ok(Some(own.views(&fx.weights)))
        },
        b,
        grads,
    )
}

#[cfg(test)]
fn tick_log(segs: &[Segment<'_>]) -> TickLog {
    use gman_core::dense::Dense;
    fn dense(l: &Dense<'_>) -> LayerCopy {
        let (r, c) = (l.w.rows(), l.w.cols());
        let w = (0..r * c).map(|i| l.w.get(i / c, i % c)).collect();
        (w, l.b.to_vec(), l.gain.map(|g| g.to_vec()))
    }
    TickLog {
        segs: segs
            .iter()
            .map(|s| {
                (
                    s.steps.to_vec(),
                    s.acts.to_vec(),
                    s.attr.to_vec(),
                    s.bootstrap,
                )
            })
            .collect(),
        params: segs
            .iter()
            .map(|s| {
                let o = s.own.as_ref().expect("own parameters");
                [dense(&o.actor), dense(&o.gen.l1), dense(&o.gen.l2)]
            })
            .collect(),
    }
}

#[cfg(not(test))]
fn tick_log(_: &[Segment<'_>]) -> TickLog {
    TickLog
}

/// One tick of the running episodes `active`: each navigator's `begin_step` (x_t: in the
/// Efficient mode G of all of them as one batch, `Navigator::generate_batch`, the same bits),
/// one batched trunk forward, each navigator's `finish_step` (its own actor head, the action,
/// Ψ), the environment's step; the step and its activations recorded for the backward.
/// Returns the steps taken.
fn tick<M: Mode>(
    fx: &Fixed<'_, '_>,
    b: &mut Bufs<'_, '_>,
    navs: &mut [Navigator<'_, M, K>],
    eps: &mut [Option<Ep<'_>>],
    active: &[usize],
) -> Result<u64> {
    let (n, w) = (active.len(), &fx.w);
    if n == 0 {
        return Ok(0);
    }
    b.rows.resize(n, w);
    let mut pending = Vec::with_capacity(n);
    for &i in active {
        let ep = eps[i].as_mut().ok_or_else(|| anyhow!("empty slot"))?;
        let nav = &mut navs[i];
        ep.inp.observe(&ep.env, fx.model, b.ps, fx.grid, w.map)?;
        ep.inp.expert = (fx.objective == Objective::Dagger).then(|| expert_distribution(&ep.env));
        ep.h_prev = nav.hidden_state().to_vec();
        ep.c_prev = nav.cell_state().to_vec();
        ep.prev = nav.prev_probs().to_vec();
        // Line 7: x_t from this episode's θ_i (here, or below with the others).
        if nav.begin_step_defer_g(&ep.inp.obs, &ep.inp.map, &ep.inp.ps)? {
            pending.push(i);
        }
    }
    let need = Navigator::<M, K>::generate_batch_scratch_len(&fx.model.dims, pending.len());
    if b.gen_scratch.len() < need {
        b.gen_scratch.resize(need, 0.0);
    }
    Navigator::generate_batch(navs, &pending, &mut b.gen_scratch)?;
    for (j, &i) in active.iter().enumerate() {
        let ep = eps[i].as_ref().ok_or_else(|| anyhow!("empty slot"))?;
        put_inputs(&mut b.rows, j, ep, &navs[i], w);
    }
    // Line 8: the trunk of every running episode as one batch (the heads computed here are
    // the first navigator's; each row's own follow).
    b.rows.forward(&navs[active[0]].policy()?, n, w)?;
    // G ran in every begin_step (a new z_t each step): its activations are this step's.
    let ran_g = fx.model.noise == NoiseMode::Gaussian && !fx.model.privileged;
    for (j, &i) in active.iter().enumerate() {
        let ep = eps[i].as_mut().ok_or_else(|| anyhow!("empty slot"))?;
        finish_row(&mut b.rows, j, w, &mut navs[i], ep, ran_g)?;
    }
    Ok(n as u64)
}

/// Row `j` of a tick after the batched trunk: its navigator's `finish_step` with the row's
/// (h, c) (its own actor head, the critic, the action, Ψ), the row's heads recomputed for the
/// backward's activations (checked against the step's bits), the environment's step, and the
/// step recorded.
fn finish_row<M: Mode>(
    rows: &mut Rows,
    j: usize,
    w: &Widths,
    nav: &mut Navigator<'_, M, K>,
    ep: &mut Ep<'_>,
    ran_g: bool,
) -> Result<()> {
    let hd = w.hd;
    let (h, c) = (&rows.h[j * hd..(j + 1) * hd], &rows.c[j * hd..(j + 1) * hd]);
    let out = nav.finish_step(&ep.inp.obs, h, c)?;
    row_heads(rows, j, w, nav, &out.probs, out.value)?;
    ep.stats.actions.push(out.action.index() as u8);
    let o = ep.env.step(out.action);
    let mut act = take_act(rows, j, w);
    if ran_g {
        // G's activations of this x_t, for the backward (instead of running G again).
        let (u1, h1, u2) = nav.generator_activations();
        act.gen = (u1.to_vec(), h1.to_vec(), u2.to_vec());
    }
    let step = StepRec {
        obs: std::mem::take(&mut ep.inp.obs),
        ps: std::mem::take(&mut ep.inp.ps),
        map: std::mem::take(&mut ep.inp.map),
        x: nav.generated_feature().to_vec(),
        z: nav.noise().to_vec(),
        h_prev: std::mem::take(&mut ep.h_prev),
        c_prev: std::mem::take(&mut ep.c_prev),
        prev_probs: std::mem::take(&mut ep.prev),
        action: out.action.index(),
        reward: o.reward,
        probs: out.probs,
        expert: ep.inp.expert.take(),
    };
    ep.rec.push(step, act);
    Ok(())
}

/// Row `j`'s heads at the episode's actor head, for the backward's activations (the bits
/// `finish_step` computed, `probs` and `value`: refused if they differ).
fn row_heads<M: Mode>(
    rows: &mut Rows,
    j: usize,
    w: &Widths,
    nav: &Navigator<'_, M, K>,
    probs_out: &[f32; NUM_ACTIONS],
    value_out: f32,
) -> Result<()> {
    let Rows {
        h,
        actor_u,
        logits,
        probs,
        value,
        ..
    } = rows;
    let (hd, au, na) = (w.hd, w.au, NUM_ACTIONS);
    nav.policy()?.heads(
        1,
        &h[j * hd..(j + 1) * hd],
        &mut actor_u[j * au..(j + 1) * au],
        &mut logits[j * na..(j + 1) * na],
        &mut probs[j * na..(j + 1) * na],
        &mut value[j..j + 1],
    )?;
    if probs[j * na..(j + 1) * na]
        .iter()
        .zip(probs_out)
        .any(|(a, b)| a.to_bits() != b.to_bits())
        || value[j].to_bits() != value_out.to_bits()
    {
        bail!("vectorised episode: the row's heads differ from the navigator's step");
    }
    Ok(())
}

/// Row `j`'s policy inputs: the episode's observation, PS input and map, and its
/// navigator's x_t, SE(y), previous probabilities and LSTM state.
fn put_inputs<M: Mode>(
    rows: &mut Rows,
    j: usize,
    ep: &Ep<'_>,
    nav: &Navigator<'_, M, K>,
    w: &Widths,
) {
    let st = RowState {
        feat: nav.generated_feature(),
        attr: nav.attr(),
        prev: nav.prev_probs(),
        h: nav.hidden_state(),
        c: nav.cell_state(),
    };
    put_row(rows, j, w, &ep.inp, st);
}

/// The critic's values of the next observations of the `ready` episodes that go on (one
/// batched trunk forward at their navigators' states; the critic is never adapted), 0 for
/// the ended ones; in `ready`'s order.
fn bootstrap<M: Mode>(
    fx: &Fixed<'_, '_>,
    b: &mut Bufs<'_, '_>,
    navs: &[Navigator<'_, M, K>],
    eps: &mut [Option<Ep<'_>>],
    ready: &[usize],
) -> Result<Vec<f32>> {
    let going: Vec<usize> = ready
        .iter()
        .copied()
        .filter(|&i| eps[i].as_ref().is_some_and(|e| !e.env.is_done()))
        .collect();
    let Some(&first) = going.first() else {
        return Ok(vec![0.0; ready.len()]);
    };
    let policy = navs[first].policy()?;
    let ps = &mut *b.ps;
    bootstrap_values(ready, &going, &policy, &fx.w, &mut b.rows, |rows, j, i| {
        let ep = eps[i].as_mut().ok_or_else(|| anyhow!("empty slot"))?;
        ep.inp.observe(&ep.env, fx.model, ps, fx.grid, fx.w.map)?;
        put_inputs(rows, j, ep, &navs[i], &fx.w);
        Ok(())
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::Method;
    use crate::pretrain::generator::init_generator;
    use crate::sim::RewardKind;
    use crate::train::a3c::A3cConfig;
    use gman_core::dense::Dense;
    use gman_core::generator::Generator;
    use gman_core::matrix::MatRef;
    use gman_core::rng::Xoshiro128;
    use gman_core::Dims;
    use rand::SeedableRng;
    use rand_chacha::ChaCha8Rng;

    type Copy3 = (Vec<f32>, Vec<f32>, Option<Vec<f32>>);

    /// A dense view over a copy, on the kernels of `like`.
    fn view<'a>(c: &'a Copy3, shape: (usize, usize), like: &MatRef<'_>) -> Dense<'a> {
        Dense {
            w: MatRef::f32(shape.0, shape.1, &c.0)
                .unwrap()
                .kernels_from(like),
            b: &c.1,
            gain: c.2.as_deref(),
        }
    }

    /// The order of a `B > 1` update, pinned: its gradient is, tick by tick, one batched
    /// BPTT over the segments completing at the tick (longest first, then by slot), each
    /// row at its own episode's adapted actor head and G (recomputed here from copies of
    /// them). Both matter: the same segments one at a time, or at the shared (unadapted)
    /// parameters, give other bits.
    #[test]
    fn each_tick_is_one_backward_over_its_segments_at_their_own_parameters() {
        let world = World::synthetic(7);
        let d = Dims::MCU;
        let g = init_generator(&d, &mut Xoshiro128::seed_from_u64(5)).unwrap();
        for mode in [AdaptMode::Efficient, AdaptMode::Full] {
            let mut model = NavModel::init(Method::Gman, d, 3, Some(&g), None).unwrap();
            model.adapt_mode = mode;
            model.inner_lr = 0.05;
            model.params.get_mut("ActorB").unwrap().data[gman_core::Action::Done.index()] -= 1.5;
            let a3c = A3cConfig::default();
            let s = VecSettings {
                batch_envs: 8,
                min_steps: 300,
                reward: RewardKind::Mixed,
                a3c: &a3c,
                objective: Objective::A3c,
            };
            let sample = |e: u32| -> Result<(EpisodeSpec, u32)> {
                let mut rng = ChaCha8Rng::seed_from_u64(900 + e as u64);
                Ok((world.try_sample_train_episode_min(&mut rng, 1)?, 45))
            };
            let mut got = model.params.zeros_like();
            let mut worker = Worker::new(&model);
            let mut log = Vec::new();
            let job = Share {
                world: &world,
                model: &model,
                s: &s,
                worker: &mut worker,
                grads: &mut got,
                sample,
            };
            let done = match mode {
                AdaptMode::Efficient => run_in::<Efficient>(job, Some(&mut log)),
                AdaptMode::Full => run_in::<Full>(job, Some(&mut log)),
            }
            .unwrap();
            assert!(done.iter().filter(|f| f.1.adaptations > 0).count() >= 3);
            // Efficient: one backward for the update (copies of the gains and biases);
            // Full: one per tick that completes segments.
            match mode {
                AdaptMode::Efficient => assert_eq!(log.len(), 1),
                AdaptMode::Full => assert!(log.len() > 5, "{}", log.len()),
            }
            assert!(
                log.iter()
                    .any(|t| t.segs.len() >= 2
                        && t.segs.iter().any(|s| s.0.len() != t.segs[0].0.len())),
                "a tick completes segments of several lengths"
            );
            // The rows' parameters differ (adapted episodes).
            assert!(log
                .iter()
                .flat_map(|t| &t.params)
                .any(|p| p[0] != log[0].params[0][0]));
            // The trunk and the shapes from a navigator over the model.
            let weights = model.weights().unwrap();
            let nav_cfg = gman_core::navigator::NavConfig {
                adapt: false,
                ..model.nav_config(true)
            };
            let mut arena = vec![0.0; Navigator::<Full, K>::arena_len(&d)];
            let mut nav: Navigator<'_, Full, K> =
                Navigator::new(weights, &mut arena, nav_cfg).unwrap();
            nav.reset(&vec![0.0; d.attr], 0).unwrap();
            let (trunk, gen0) = (nav.policy().unwrap(), nav.generator().unwrap());
            let mut w = Widths::of(&trunk, &d);
            // The actor's pre-gain output is kept when the episodes' heads have gains.
            w.au = if log[0].params[0][0].2.is_some() {
                NUM_ACTIONS
            } else {
                0
            };
            let shapes = [
                (trunk.actor.w.rows(), trunk.actor.w.cols()),
                (gen0.l1.w.rows(), gen0.l1.w.cols()),
                (gen0.l2.w.rows(), gen0.l2.w.cols()),
            ];
            let like = trunk.fuse.w;
            fn seg<'a>(
                t: &'a TickLog,
                k: usize,
                own: bool,
                shapes: &[(usize, usize); 3],
                like: &MatRef<'_>,
            ) -> Segment<'a> {
                let (steps, acts, attr, boot) = &t.segs[k];
                let p = &t.params[k];
                Segment {
                    steps,
                    acts,
                    attr,
                    bootstrap: *boot,
                    own: own.then(|| Adapted {
                        actor: view(&p[0], shapes[0], like),
                        gen: Generator {
                            l1: view(&p[1], shapes[1], like),
                            l2: view(&p[2], shapes[2], like),
                        },
                    }),
                }
            }
            let seg = |t, k, own| seg(t, k, own, &shapes, &like);
            // G's buffers sized as the episodes' G (with gains in the Efficient mode).
            let p0 = &log[0].params[0];
            let gen_rows = Generator {
                l1: view(&p0[1], shapes[1], &like),
                l2: view(&p0[2], shapes[2], &like),
            };
            let backward = |segs: &[Segment<'_>], grads: &mut ParamSet| {
                let mut gb = GenBufs::new(&gen_rows, w.f);
                Backward::default()
                    .run(&trunk, &gen0, segs, &a3c, true, &w, &d, grads, &mut gb)
                    .unwrap();
            };
            let mut want = model.params.zeros_like();
            for t in &log {
                let segs: Vec<Segment<'_>> = (0..t.segs.len()).map(|k| seg(t, k, true)).collect();
                backward(&segs, &mut want);
            }
            assert_eq!(got.bits(), want.bits(), "{mode:?}: the pinned order");
            // One segment at a time: a different sum of the same terms.
            let mut one = model.params.zeros_like();
            for t in &log {
                for k in 0..t.segs.len() {
                    backward(&[seg(t, k, true)], &mut one);
                }
            }
            assert_ne!(got.bits(), one.bits(), "{mode:?}: order-sensitive");
            // At the unadapted parameters: another gradient.
            let mut shared = model.params.zeros_like();
            for t in &log {
                let segs: Vec<Segment<'_>> = (0..t.segs.len()).map(|k| seg(t, k, false)).collect();
                backward(&segs, &mut shared);
            }
            assert_ne!(got.bits(), shared.bits(), "{mode:?}: per-row parameters");
        }
    }
}
