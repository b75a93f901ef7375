//! The rollout engine: one worker's share of an update, `B` training episodes in lockstep
//! (`--batch-envs B`), the policy's forward and backward passes over them as matrices
//! (`Policy::forward_batch`, `Policy::backward_batch` on gman-core's batched kernels). Every
//! training episode runs here: `B = 1`, the methods without an inner loop and the
//! second-order meta-gradient are cases of it.
//!
//! ```text
//! while a slot is free and the worker's step budget is not spent: start episode e in it
//! every tick:
//!   each running episode: observation, PS input, map; its x_t = G_θi(SE(y), z_t)   (line 7)
//!     (G of all of them as one batch)
//!   one batched policy forward over the running episodes                        (line 8)
//!   each episode: its action (its own actor head, its own generator), the environment
//!     steps, the step recorded (lines 9-13)
//!   the episodes whose segment is complete (k = 20 steps, then a delayed update's commit
//!   window; or the episode ended):
//!     bootstrap values (one batched forward)
//!     their backward now (one batched BPTT over them, each row at the parameters it ran
//!       with), or they wait for one batched BPTT over the update
//!     then each of them (slot order): the episode ended -> its statistics and D, slot freed;
//!       else its inner update (lines 14-20)
//! at the end of the update: one batched BPTT over the waiting segments
//! ```
//!
//! **Two kinds of lanes** ([`Lanes`]) carry the episodes; the loop above is the same for both:
//! * [`super::lanes_shared`], the methods without an inner loop in training (`a3c`,
//!   `a3c-fg`, `gman-noemd`, ...): θ and φ stay at the outer parameters for the whole
//!   update, so the episodes share one set of parameter views (from a gman-core navigator
//!   over the model) and each keeps the navigator's per-episode state.
//! * [`super::lanes_nav`], the methods with an inner loop (`gman`, ...): each episode runs
//!   on its own gman-core [`Navigator`](gman_core::navigator::Navigator) (the device's code,
//!   in the model's adaptation mode), whose step is split around the batched trunk.
//!
//! Either way **each episode is bit for bit the episode the navigator runs alone** (same
//! actions, probabilities, rewards, inner updates): the batched kernels give every row the
//! bits of the batch-1 kernels (`tests/engine.rs`, `tests/tests/navigator.rs`).
//!
//! **When a segment's backward runs.** A segment's A3C gradient is taken at the parameters
//! it ran with (first-order meta-gradient: the gradient at the adapted parameters is summed
//! into that of the pre-adaptation ones).
//! * It **waits** ([`Lanes::defer`], `B > 1`) when the parameters cannot change under it or
//!   can be copied cheaply: without an inner loop (one set of parameters), and in the
//!   Efficient mode (the adapted parameters are the per-unit gains and biases of the actor
//!   head and of G, ~1.5k floats for `mcu`; a waiting segment keeps a copy, [`OwnCopy`]).
//!   All the update's waiting segments then join one batched BPTT at its end (or earlier,
//!   whenever [`MAX_PENDING_STEPS`] steps wait), longest first, then in the order they
//!   completed (tick, then slot).
//! * Otherwise (the Full mode, whose θ_i is all of G; and `B = 1`) the segments completing
//!   at a tick run **now**, as one batched BPTT (longest first, then by slot), each row
//!   through its episode's live views, before the episode's inner update.
//!
//! Within a BPTT every tensor's gradient is summed step by step (last step first) and, within
//! a step, over the rows in order. The order is fixed by `(seed, update, worker, B)`, so runs
//! are reproducible and resume bit for bit; with `B > 1` the sum is the per-episode sum
//! within float rounding (`tests/engine.rs` checks 1e-4 of each tensor's largest value;
//! this module's tests pin the order).
//!
//! **The second-order meta-gradient** (`--meta-order 2`, `B = 1`, Full mode): each
//! segment's gradient is taken into a buffer of its own, its θ, φ parts kept with the
//! episode's inner steps, and at the end of the episode [`super::meta`]'s reverse recursion
//! adds them through the inner SGD steps.
//!
//! **Episodes per update.** A worker starts episodes (`e = 0, 1, ..`, from `sample(e)`) while
//! it has taken fewer than `min_steps` steps in the update, and the update ends when all its
//! running episodes have ended; so an update holds at least `B` episodes per worker.
//!
//! [`MAX_PENDING_STEPS`]: super::lockstep::MAX_PENDING_STEPS

use anyhow::{anyhow, bail, Result};
use gman_core::activation::all_finite;
use gman_core::generator::Generator;
use gman_core::memory::AdaptMode;
use gman_core::navigator::{Efficient, Full, Selection};
use gman_core::policy::Policy;
use gman_core::{Action, Dims, NUM_ACTIONS};

use super::a3c::Objective;
use super::bptt::{Adapted, Backward, GenBufs, Rows, Segment, StepAct, Widths};
use super::lanes_nav::OwnCopy;
use super::lockstep::{
    backward_order, backward_segments, bootstrap_values, check_batch_envs, collect_losses,
    lockstep, put_row, without_inner_loop, BackwardCtx, Finished, PendingSeg, Recording, RowState,
    SegQueue, StepInputs, VecSettings,
};
use super::rollout::{expert_distribution, EpisodeStats, Worker};
use super::step::StepRec;
use crate::model::episode::map_grid;
use crate::model::{NavModel, K};
use crate::optim::params::ParamSet;
use crate::pretrain::ps::PsBuffers;
use crate::sim::spatial::MapGrid;
use crate::sim::{Env, EpisodeSpec, World};

/// A complete segment, with a copy of its episode's adapted parameters when it waits for a
/// backward after its episode's inner update.
pub(super) type Pending = PendingSeg<Option<OwnCopy>>;

/// A running episode in a slot: its environment, the segment being recorded, its
/// statistics, this step's inputs, and what its kind of lane keeps of it (`lane`).
pub(super) struct Running<'w, X> {
    pub e: u32,
    pub env: Env<'w>,
    pub rec: Recording,
    pub stats: EpisodeStats,
    pub inp: StepInputs,
    pub lane: X,
}

/// What a lane gives of a step it took, for the backward: x_t, z_t, the state before the
/// step and the step's activations.
pub(super) struct LaneStep {
    pub x: Vec<f32>,
    pub z: Vec<f32>,
    pub h_prev: Vec<f32>,
    pub c_prev: Vec<f32>,
    pub prev_probs: Vec<f32>,
    pub act: StepAct,
}

/// How the episodes of a kind run: their parameters, their per-episode state (`Ep`), how
/// x_t, the action and the inner update are made. The engine's loop calls these in order.
pub(super) trait Lanes<'w> {
    /// What the lanes keep of a running episode.
    type Ep;
    /// The widths of the batched pass.
    fn widths(&self) -> &Widths;
    /// The dimensions.
    fn dims(&self) -> &Dims;
    /// Starts the episode `spec` in slot `i`.
    fn start(&mut self, i: usize, world: &'w World, spec: &EpisodeSpec) -> Result<Self::Ep>;
    /// After the episode in slot `i` observed: its x_t, or its place in [`Lanes::generate`].
    fn prepare(&mut self, i: usize, ep: &mut Running<'w, Self::Ep>) -> Result<()>;
    /// The x_t [`Lanes::prepare`] left to a batch, as one batch.
    fn generate(&mut self, slots: &mut [Option<Running<'w, Self::Ep>>]) -> Result<()>;
    /// Slot `i`'s x_t, SE(y), previous probabilities and LSTM state.
    fn row<'s>(&'s self, i: usize, ep: &'s Running<'w, Self::Ep>) -> RowState<'s>;
    /// The policy whose trunk runs the batched forward (the first row is slot `i`'s).
    fn trunk(&self, i: usize) -> Result<Policy<'_>>;
    /// Slot `i`'s action after the batched forward (row `j`), and its probabilities.
    fn act(
        &mut self,
        rows: &mut Rows,
        j: usize,
        i: usize,
        ep: &mut Running<'w, Self::Ep>,
    ) -> Result<(Action, [f32; NUM_ACTIONS])>;
    /// After the environment stepped: what the backward needs of the step.
    fn after_act(
        &mut self,
        rows: &Rows,
        j: usize,
        i: usize,
        ep: &mut Running<'w, Self::Ep>,
        probs: &[f32; NUM_ACTIONS],
    ) -> Result<LaneStep>;
    /// True while slot `i`'s delayed inner update is in its commit window.
    fn in_commit_window(&self, i: usize) -> bool;
    /// True when complete segments wait for one batched BPTT over the update.
    fn defer(&self) -> bool;
    /// What a waiting segment of slot `i` keeps of its parameters.
    fn own(&self, i: usize) -> Result<Option<OwnCopy>>;
    /// Views over a waiting segment's copy.
    fn own_views<'s>(&'s self, own: &'s OwnCopy) -> Result<Adapted<'s>>;
    /// The parameters of the waiting segments' backward (those no segment adapted).
    fn fixed(&self) -> Result<(Policy<'_>, Generator<'_>)>;
    /// Slot `i`'s live parameters: trunk, G, and the row's own heads and G (if its own).
    fn live(&self, i: usize) -> Result<(Policy<'_>, Generator<'_>, Option<Adapted<'_>>)>;
    /// True with the second-order meta-gradient.
    fn second_order(&self) -> bool {
        false
    }
    /// Second order: a segment's gradient `g` (of the episode in `ep`) taken, before it is
    /// added to the worker's.
    fn segment_grad(&mut self, _ep: &mut Self::Ep, _g: &mut ParamSet) -> Result<()> {
        Ok(())
    }
    /// After a segment of an episode that goes on: its inner update.
    fn after_segment(&mut self, i: usize, ep: &mut Running<'w, Self::Ep>) -> Result<()>;
    /// The ended episode of slot `i`: its statistics and D after it.
    fn finish(
        &mut self,
        i: usize,
        ep: Running<'w, Self::Ep>,
        grads: &mut ParamSet,
    ) -> Result<Finished>;
}

/// What a test sees of a worker's update: `keep` takes the update's last waiting segments
/// instead of their backward, `log` records every backward's batch.
#[derive(Default)]
pub(super) struct Hooks<'l> {
    pub keep: Option<&'l mut Vec<Pending>>,
    pub log: Option<&'l mut Vec<TickLog>>,
}

/// Runs one worker's share of an update with `s.batch_envs` environments in lockstep (see
/// the module docs): episodes `e = 0, 1, ..` from `sample(e)` (spec and step limit), the A3C
/// gradient of every segment accumulated into `grads`. Returns the finished episodes sorted
/// by index, each with D after it (empty when it is the model's ω, see [`Finished`]).
pub fn run_worker(
    world: &World,
    model: &NavModel,
    s: &VecSettings<'_>,
    worker: &mut Worker,
    grads: &mut ParamSet,
    sample: impl FnMut(u32) -> Result<(EpisodeSpec, u32)>,
) -> Result<Vec<Finished>> {
    run_hooked(world, model, s, worker, grads, sample, Hooks::default())
}

/// [`run_worker`] with the tests' hooks.
pub(super) fn run_hooked(
    world: &World,
    model: &NavModel,
    s: &VecSettings<'_>,
    worker: &mut Worker,
    grads: &mut ParamSet,
    sample: impl FnMut(u32) -> Result<(EpisodeSpec, u32)>,
    hooks: Hooks<'_>,
) -> Result<Vec<Finished>> {
    check_settings(model, s)?;
    let job = Job {
        world,
        model,
        s,
        grads,
        sample,
        hooks,
    };
    match (without_inner_loop(model), model.adapt_mode) {
        (true, AdaptMode::Full) => super::lanes_shared::run::<Full, _>(job, worker),
        (true, AdaptMode::Efficient) => super::lanes_shared::run::<Efficient, _>(job, worker),
        (false, AdaptMode::Full) => super::lanes_nav::run::<Full, _>(job, worker),
        (false, AdaptMode::Efficient) => super::lanes_nav::run::<Efficient, _>(job, worker),
    }
}

/// The settings the engine refuses.
fn check_settings(model: &NavModel, s: &VecSettings<'_>) -> Result<()> {
    if !(1..=2).contains(&s.meta_order) {
        bail!("--meta-order must be 1 or 2, not {}", s.meta_order);
    }
    check_batch_envs(model, s.batch_envs, s.meta_order)?;
    if model.privileged && model.method.adapts_in_training() {
        bail!("the privileged-feature bound replaces G's output and cannot adapt G; use it with a method without inner loop (a3c-fg)");
    }
    if model.nav_config(true).selection != Selection::Sample {
        bail!("training episodes need a sampling navigator");
    }
    Ok(())
}

/// A worker's share of an update as the lanes hand it to [`drive`].
pub(super) struct Job<'a, 'w, 'l, F> {
    pub world: &'w World,
    pub model: &'a NavModel,
    pub s: &'a VecSettings<'a>,
    pub grads: &'a mut ParamSet,
    pub sample: F,
    pub hooks: Hooks<'l>,
}

/// What every tick reads.
struct Ctx<'a> {
    model: &'a NavModel,
    s: &'a VecSettings<'a>,
    grid: MapGrid,
    train_generator: bool,
}

/// The buffers a worker's update reuses across ticks.
struct Bufs<'b, 'l> {
    ps: &'b mut Option<PsBuffers>,
    rows: Rows,
    bw: Backward,
    gbuf: GenBufs,
    /// The waiting segments, and the losses of those whose backward ran.
    queue: SegQueue<Option<OwnCopy>>,
    /// Second order: one segment's gradient, before it joins the worker's.
    seg_g: Option<ParamSet>,
    hooks: Hooks<'l>,
}

/// The engine's loop (see the module docs) over `lanes`, with G's backward buffers `gbuf`
/// and the worker's PS buffer `ps`.
pub(super) fn drive<'w, L: Lanes<'w>>(
    job: Job<'_, 'w, '_, impl FnMut(u32) -> Result<(EpisodeSpec, u32)>>,
    lanes: &mut L,
    gbuf: GenBufs,
    ps: &mut Option<PsBuffers>,
) -> Result<Vec<Finished>> {
    let Job {
        world,
        model,
        s,
        grads,
        sample,
        hooks,
    } = job;
    let cx = Ctx {
        model,
        s,
        grid: map_grid(model),
        train_generator: model.method.trains_generator() && !model.privileged,
    };
    let mut b = Bufs {
        ps,
        rows: Rows::default(),
        bw: Backward::default(),
        gbuf,
        queue: SegQueue::new(),
        seg_g: lanes.second_order().then(|| grads.zeros_like()),
        hooks,
    };
    let mut done: Vec<Finished> = Vec::new();
    lockstep(
        s.batch_envs,
        s.min_steps,
        sample,
        lanes,
        |lanes, i, e, spec, max| {
            Ok(Running {
                e,
                env: Env::new(world, spec, s.reward, max),
                rec: Recording::new(),
                stats: EpisodeStats::default(),
                inp: StepInputs::default(),
                lane: lanes.start(i, world, spec)?,
            })
        },
        |lanes, slots| {
            let taken = tick(&cx, lanes, &mut b, slots)?;
            close_ready(&cx, lanes, &mut b, slots, grads, &mut done)?;
            Ok(taken)
        },
    )?;
    match b.hooks.keep.take() {
        Some(k) => *k = b.queue.take(),
        None => flush(&cx, lanes, &mut b, grads)?,
    }
    collect_losses(b.queue.losses, done)
}

fn slot<'s, 'w, X>(
    slots: &'s mut [Option<Running<'w, X>>],
    i: usize,
) -> Result<&'s mut Running<'w, X>> {
    slots[i].as_mut().ok_or_else(|| anyhow!("empty slot"))
}

/// An episode's observation, PS input and map, checked finite.
fn observe<X>(
    cx: &Ctx<'_>,
    ps: &mut Option<PsBuffers>,
    ep: &mut Running<'_, X>,
    map_len: usize,
) -> Result<()> {
    ep.inp.observe(&ep.env, cx.model, ps, cx.grid, map_len)?;
    let inp = &ep.inp;
    if !all_finite(&inp.obs) || !all_finite(&inp.map) || !all_finite(&inp.ps) {
        bail!("navigator: non-finite input");
    }
    Ok(())
}

/// One tick of the running episodes: their inputs and x_t, one batched policy forward, each
/// episode's action and the environment's step, the step recorded. Returns the steps taken.
fn tick<'w, L: Lanes<'w>>(
    cx: &Ctx<'_>,
    lanes: &mut L,
    b: &mut Bufs<'_, '_>,
    slots: &mut [Option<Running<'w, L::Ep>>],
) -> Result<u64> {
    let active: Vec<usize> = (0..slots.len())
        .filter(|&i| slots[i].as_ref().is_some_and(|e| !e.env.is_done()))
        .collect();
    let (n, w) = (active.len(), *lanes.widths());
    if n == 0 {
        return Ok(0);
    }
    for &i in &active {
        let ep = slot(slots, i)?;
        observe(cx, b.ps, ep, w.map)?;
        ep.inp.expert = (cx.s.objective == Objective::Dagger).then(|| expert_distribution(&ep.env));
        lanes.prepare(i, ep)?;
    }
    lanes.generate(slots)?;
    b.rows.resize(n, &w);
    for (j, &i) in active.iter().enumerate() {
        let ep = slots[i].as_ref().ok_or_else(|| anyhow!("empty slot"))?;
        put_row(&mut b.rows, j, &w, &ep.inp, lanes.row(i, ep));
    }
    // Line 8: the trunk of every running episode as one batch.
    b.rows.forward(&lanes.trunk(active[0])?, n, &w)?;
    for (j, &i) in active.iter().enumerate() {
        let ep = slot(slots, i)?;
        let (action, probs) = lanes.act(&mut b.rows, j, i, ep)?;
        ep.stats.actions.push(action.index() as u8);
        let o = ep.env.step(action);
        let st = lanes.after_act(&b.rows, j, i, ep, &probs)?;
        let step = StepRec {
            obs: std::mem::take(&mut ep.inp.obs),
            ps: std::mem::take(&mut ep.inp.ps),
            map: std::mem::take(&mut ep.inp.map),
            x: st.x,
            z: st.z,
            h_prev: st.h_prev,
            c_prev: st.c_prev,
            prev_probs: st.prev_probs,
            action: action.index(),
            reward: o.reward,
            probs,
            expert: ep.inp.expert.take(),
        };
        ep.rec.push(step, st.act);
    }
    Ok(n as u64)
}

/// After a tick: the segments complete at it (k recorded steps, then the commit window of a
/// delayed update if any; or the episode ended) get their bootstrap values and either wait
/// or run their backward now; then each of those episodes ends or runs its inner update.
fn close_ready<'w, L: Lanes<'w>>(
    cx: &Ctx<'_>,
    lanes: &mut L,
    b: &mut Bufs<'_, '_>,
    slots: &mut [Option<Running<'w, L::Ep>>],
    grads: &mut ParamSet,
    done: &mut Vec<Finished>,
) -> Result<()> {
    let ready: Vec<usize> = (0..slots.len())
        .filter(|&i| {
            slots[i].as_ref().is_some_and(|e| {
                (e.rec.len() >= K && !lanes.in_commit_window(i)) || e.env.is_done()
            })
        })
        .collect();
    if ready.is_empty() {
        return Ok(());
    }
    let boot = bootstrap(cx, lanes, b, slots, &ready)?;
    let mut fresh: Vec<Pending> = Vec::new();
    for (&i, v) in ready.iter().zip(boot) {
        let ep = slot(slots, i)?;
        if ep.rec.is_empty() {
            continue;
        }
        let own = if lanes.defer() { lanes.own(i)? } else { None };
        let attr = lanes.row(i, ep).attr.to_vec();
        fresh.push(b.queue.complete(i, ep.e, &mut ep.rec, attr, v, own));
    }
    if lanes.defer() {
        for seg in fresh {
            b.queue.wait(seg);
        }
        if b.queue.full() {
            flush(cx, lanes, b, grads)?;
        }
    } else {
        backward_now(cx, lanes, b, slots, fresh, grads)?;
    }
    for &i in &ready {
        if slots[i].as_ref().is_some_and(|e| e.env.is_done()) {
            let ep = slots[i].take().ok_or_else(|| anyhow!("empty slot"))?;
            done.push(lanes.finish(i, ep, grads)?);
        } else {
            lanes.after_segment(i, slot(slots, i)?)?;
        }
    }
    Ok(())
}

/// The critic's values of the next observations of the `ready` episodes that go on (one
/// batched forward; the critic is never adapted), 0 for the ended ones; in `ready`'s order.
fn bootstrap<'w, L: Lanes<'w>>(
    cx: &Ctx<'_>,
    lanes: &L,
    b: &mut Bufs<'_, '_>,
    slots: &mut [Option<Running<'w, L::Ep>>],
    ready: &[usize],
) -> Result<Vec<f32>> {
    let going: Vec<usize> = ready
        .iter()
        .copied()
        .filter(|&i| slots[i].as_ref().is_some_and(|e| !e.env.is_done()))
        .collect();
    let Some(&first) = going.first() else {
        return Ok(vec![0.0; ready.len()]);
    };
    let policy = lanes.trunk(first)?;
    let w = *lanes.widths();
    let ps = &mut *b.ps;
    bootstrap_values(ready, &going, &policy, &w, &mut b.rows, |rows, j, i| {
        let ep = slot(slots, i)?;
        observe(cx, ps, ep, w.map)?;
        put_row(rows, j, &w, &ep.inp, lanes.row(i, ep));
        Ok(())
    })
}

/// One batched BPTT over the segments `fresh` completing at this tick (longest first, then
/// by slot), each row at its episode's live parameters (before its inner update); with the
/// second-order meta-gradient through the segment's own gradient buffer.
fn backward_now<'w, L: Lanes<'w>>(
    cx: &Ctx<'_>,
    lanes: &mut L,
    b: &mut Bufs<'_, '_>,
    slots: &mut [Option<Running<'w, L::Ep>>],
    mut fresh: Vec<Pending>,
    grads: &mut ParamSet,
) -> Result<()> {
    if fresh.is_empty() {
        return Ok(());
    }
    backward_order(&mut fresh);
    let mut seg_g = b.seg_g.take();
    {
        let l: &L = lanes;
        let (policy, gen, _) = l.live(fresh[0].slot)?;
        let (w, d) = (*l.widths(), *l.dims());
        let bx = BackwardCtx {
            policy: &policy,
            gen: &gen,
            a3c: cx.s.a3c,
            train_generator: cx.train_generator,
            w: &w,
            d: &d,
        };
        let target = match seg_g.as_mut() {
            Some(g) => {
                g.zero();
                g
            }
            None => &mut *grads,
        };
        backward_logged(&bx, &mut fresh, |p| Ok(l.live(p.slot)?.2), b, target)?;
    }
    if let Some(g) = seg_g.as_mut() {
        for p in &fresh {
            lanes.segment_grad(&mut slot(slots, p.slot)?.lane, g)?;
        }
        grads.add_assign(g)?;
    }
    b.seg_g = seg_g;
    Ok(())
}

/// The backward of the waiting segments as one batched BPTT, longest first (then in the
/// order they completed), each row at its copy of its episode's parameters (or, without
/// one, at the parameters no segment adapted); nothing waits afterwards.
fn flush<'w, L: Lanes<'w>>(
    cx: &Ctx<'_>,
    lanes: &L,
    b: &mut Bufs<'_, '_>,
    grads: &mut ParamSet,
) -> Result<()> {
    let mut pend = b.queue.take();
    let (policy, gen) = lanes.fixed()?;
    let (w, d) = (*lanes.widths(), *lanes.dims());
    let bx = BackwardCtx {
        policy: &policy,
        gen: &gen,
        a3c: cx.s.a3c,
        train_generator: cx.train_generator,
        w: &w,
        d: &d,
    };
    backward_logged(
        &bx,
        &mut pend,
        |p| p.own.as_ref().map(|o| lanes.own_views(o)).transpose(),
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
    let log = &mut b.hooks.log;
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

/// A logged segment: steps, activations, SE(y), `V_T`.
#[cfg(test)]
pub(super) type LoggedSeg = (Vec<StepRec>, Vec<StepAct>, Vec<f32>, f32);

/// A copy of a dense layer: `W` (row-major), `b`, the gain.
#[cfg(test)]
pub(super) type LayerCopy = (Vec<f32>, Vec<f32>, Option<Vec<f32>>);

/// What the test of the order records of one backward: the segments (in the order given to
/// the BPTT) with a copy of each row's own parameters (when it has them).
#[cfg(test)]
pub(super) struct TickLog {
    pub segs: Vec<LoggedSeg>,
    /// Per row: actor, G layer 1, G layer 2.
    pub params: Vec<[LayerCopy; 3]>,
}

#[cfg(not(test))]
pub(super) struct TickLog;

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
            .filter_map(|s| s.own.as_ref())
            .map(|o| [dense(&o.actor), dense(&o.gen.l1), dense(&o.gen.l2)])
            .collect(),
    }
}

#[cfg(not(test))]
fn tick_log(_: &[Segment<'_>]) -> TickLog {
    TickLog
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::Method;
    use crate::pretrain::generator::init_generator;
    use crate::sim::EpisodeSpec;
    use crate::sim::RewardKind;
    use crate::train::a3c::A3cConfig;
    use crate::train::bptt::Segment;
    use gman_core::dense::Dense;
    use gman_core::generator::Generator;
    use gman_core::matrix::MatRef;
    use gman_core::navigator::Navigator;
    use gman_core::rng::Xoshiro128;
    use gman_core::Dims;
    use rand::SeedableRng;
    use rand_chacha::ChaCha8Rng;

    /// The deferred backward's order, pinned: the gradient of a `B > 1` update is that of
    /// one batched BPTT over all the update's segments sorted by length (longest first),
    /// then by the order they completed — and that order matters (the same segments one at
    /// a time give other bits).
    #[test]
    fn the_update_is_one_backward_over_its_segments_longest_first() {
        let world = World::synthetic(7);
        let d = Dims::MCU;
        let g = init_generator(&d, &mut Xoshiro128::seed_from_u64(5)).unwrap();
        for method in [Method::A3cFg, Method::GmanNoemd] {
            let mut model = NavModel::init(method, d, 3, Some(&g), None).unwrap();
            model.adapt_mode = AdaptMode::Efficient;
            let a3c = A3cConfig::default();
            let s = VecSettings {
                batch_envs: 6,
                min_steps: 60,
                reward: RewardKind::Mixed,
                a3c: &a3c,
                objective: Objective::A3c,
                meta_order: 1,
            };
            let sample = |e: u32| -> Result<(EpisodeSpec, u32)> {
                let mut rng = ChaCha8Rng::seed_from_u64(900 + e as u64);
                Ok((world.try_sample_train_episode_min(&mut rng, 1)?, 45))
            };
            let run = |keep: Option<&mut Vec<Pending>>| {
                let mut grads = model.params.zeros_like();
                let mut worker = Worker::new(&model);
                let hooks = Hooks { keep, log: None };
                let done =
                    run_hooked(&world, &model, &s, &mut worker, &mut grads, sample, hooks).unwrap();
                (grads, done)
            };
            let (got, done) = run(None);
            // D is the model's ω: no copy of it per episode.
            assert!(done.iter().all(|f| f.2.is_empty()));
            let mut segs = Vec::new();
            let (none, _) = run(Some(&mut segs));
            assert!(
                none.bits().iter().all(|&b| b == 0),
                "nothing flushed before the end"
            );
            assert!(
                done.len() >= 6 && segs.len() >= done.len(),
                "{}",
                segs.len()
            );
            let lens: Vec<usize> = segs.iter().map(|p| p.steps.len()).collect();
            assert!(
                lens.iter().any(|&l| l != lens[0]),
                "segments of several lengths"
            );
            // The documented order, computed here.
            segs.sort_by_key(|p| (std::cmp::Reverse(p.steps.len()), p.seq));
            let weights = model.weights().unwrap();
            let mut arena = vec![0.0; crate::model::host_arena_len(&d)];
            let mut nav: Navigator<'_, Efficient, K> =
                Navigator::new(weights, &mut arena, model.nav_config(true)).unwrap();
            nav.reset(&vec![0.0; d.attr], 0).unwrap();
            let (policy, gen) = (nav.policy().unwrap(), nav.generator().unwrap());
            let w = Widths::of(&policy, &d);
            let train_g = method.trains_generator();
            fn seg(p: &Pending) -> Segment<'_> {
                Segment {
                    steps: &p.steps,
                    acts: &p.acts,
                    attr: &p.attr,
                    bootstrap: p.bootstrap,
                    own: None,
                }
            }
            let backward = |segs: &[Segment<'_>], grads: &mut ParamSet| {
                let mut gb = GenBufs::new(&gen, w.f);
                Backward::default()
                    .run(&policy, &gen, segs, &a3c, train_g, &w, &d, grads, &mut gb)
                    .unwrap();
            };
            let mut want = model.params.zeros_like();
            let all: Vec<Segment<'_>> = segs.iter().map(seg).collect();
            backward(&all, &mut want);
            assert_eq!(
                got.bits(),
                want.bits(),
                "{}: the pinned order",
                method.name()
            );
            // The rows given their own heads and G, all equal to the shared ones (the per-row
            // path of methods with an inner loop: heads row by row, then the trunk): the
            // same bits as the shared batched pass.
            let mut rows_own = model.params.zeros_like();
            let own: Vec<Segment<'_>> = segs
                .iter()
                .map(|p| Segment {
                    own: Some(crate::train::bptt::Adapted {
                        actor: policy.actor,
                        gen,
                    }),
                    ..seg(p)
                })
                .collect();
            backward(&own, &mut rows_own);
            assert_eq!(
                rows_own.bits(),
                want.bits(),
                "{}: per-row heads",
                method.name()
            );
            // One segment at a time (completion order): a different sum of the same terms.
            segs.sort_by_key(|p| p.seq);
            let mut one = model.params.zeros_like();
            for p in &segs {
                backward(&[seg(p)], &mut one);
            }
            assert_ne!(got.bits(), one.bits(), "{}: order-sensitive", method.name());
        }
    }

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
                meta_order: 1,
            };
            let sample = |e: u32| -> Result<(EpisodeSpec, u32)> {
                let mut rng = ChaCha8Rng::seed_from_u64(900 + e as u64);
                Ok((world.try_sample_train_episode_min(&mut rng, 1)?, 45))
            };
            let mut got = model.params.zeros_like();
            let mut worker = Worker::new(&model);
            let mut log = Vec::new();
            let hooks = Hooks {
                keep: None,
                log: Some(&mut log),
            };
            let done =
                run_hooked(&world, &model, &s, &mut worker, &mut got, sample, hooks).unwrap();
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
