//! The loop of the rollout engine ([`super::engine`]) over its lanes: the [`Lanes`] trait
//! (how the episodes of a kind make x_t, act and adapt), a running episode ([`Running`]),
//! and [`drive`], the ticks over the `B` slots: observe, x_t, one batched trunk, actions and
//! environment steps, complete segments bootstrapped, their BPTT now or waiting (with an
//! [`OwnCopy`] of their episode's adapted parameters), inner updates, episodes finished.

use anyhow::{anyhow, bail, Result};
use gman_core::navigator::{Mode, Navigator};
use gman_core::nets::generator::Generator;
use gman_core::nets::policy::Policy;
use gman_core::nn::activation::all_finite;
use gman_core::nn::dense::Dense;
use gman_core::nn::matrix::{MatRef, Weights};
use gman_core::{Action, Dims, NUM_ACTIONS};

use super::a3c::Objective;
use super::bptt::{Adapted, Backward, GenBufs, Rows, Segment, StepAct, Widths};
use super::lockstep::{
    backward_order, backward_segments, bootstrap_values, collect_losses, lockstep, put_row,
    BackwardCtx, Finished, PendingSeg, Recording, RowState, SegQueue, StepInputs, VecSettings,
};
use super::rollout::{expert_distribution, EpisodeStats};
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
    /// True when a complete segment's backward may wait for the update's one batched BPTT:
    /// the parameters it ran at do not change under it, or it keeps a copy ([`Lanes::own`]).
    /// Whether segments do wait is decided once, in [`drive`]: they wait when this holds and
    /// more than one episode runs at a time.
    fn segments_can_wait(&self) -> bool;
    /// What a waiting segment of slot `i` keeps of its parameters (`None`: it ran at
    /// [`Lanes::fixed`]).
    fn own(&self, i: usize) -> Result<Option<OwnCopy>>;
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
    /// True when complete segments wait for one batched BPTT over the update.
    defer: bool,
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
        defer: s.batch_envs > 1 && lanes.segments_can_wait(),
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
        let own = if b.defer { lanes.own(i)? } else { None };
        let attr = lanes.row(i, ep).attr.to_vec();
        fresh.push(b.queue.complete(i, ep.e, &mut ep.rec, attr, v, own));
    }
    if b.defer {
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
        |p| Ok(p.own.as_ref().map(|o| o.views(&policy, &gen))),
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
    use gman_core::nn::dense::Dense;
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

/// A copy of an episode's adapted parameters in the Efficient mode: the per-unit gains and
/// biases of its actor head and of G's two layers (their matrices are those of
/// [`Lanes::fixed`]).
pub(super) struct OwnCopy {
    layers: [(Option<Vec<f32>>, Vec<f32>); 3],
}

impl OwnCopy {
    /// The copy of `nav`'s adapted parameters; refused unless its matrices are those of the
    /// fixed trunk `policy` and generator `gen` (only gains and biases adapted).
    pub(super) fn of<M: Mode>(
        nav: &Navigator<'_, M, K>,
        policy: &Policy<'_>,
        gen: &Generator<'_>,
    ) -> Result<OwnCopy> {
        let (p, g) = (nav.policy()?, nav.generator()?);
        let mut layers: [(Option<Vec<f32>>, Vec<f32>); 3] = Default::default();
        for (k, (l, fixed)) in [(p.actor, policy.actor), (g.l1, gen.l1), (g.l2, gen.l2)]
            .into_iter()
            .enumerate()
        {
            if !same_matrix(&l.w, &fixed.w) {
                bail!("a waiting segment needs the model's matrices (Efficient mode)");
            }
            layers[k] = (l.gain.map(|v| v.to_vec()), l.b.to_vec());
        }
        Ok(OwnCopy { layers })
    }

    /// Views over the copy and the matrices of the fixed trunk `policy` and generator `gen`.
    pub(super) fn views<'a>(&'a self, policy: &Policy<'a>, gen: &Generator<'a>) -> Adapted<'a> {
        let d = |k: usize, w| Dense {
            w,
            b: &self.layers[k].1,
            gain: self.layers[k].0.as_deref(),
        };
        Adapted {
            actor: d(0, policy.actor.w),
            gen: Generator {
                l1: d(1, gen.l1.w),
                l2: d(2, gen.l2.w),
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
