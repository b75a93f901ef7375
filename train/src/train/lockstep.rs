//! The rollout engine's frame ([`super::engine`]): the settings of a worker's update, the
//! loop over `B` slots (`lockstep`: free slots take new episodes while the step budget
//! lasts, every tick runs the episodes in the slots), an episode's step inputs and their row
//! in the batched pass, the segment being recorded (`Recording`), the batched bootstrap
//! values, the complete segments numbered and waiting (`SegQueue`) and their one batched
//! BPTT, and each episode's losses collected at the end.

use anyhow::{bail, Result};
use gman_core::nets::policy::{Policy, PolicyInput};
use gman_core::{Dims, NUM_ACTIONS};

use super::a3c::{A3cConfig, Objective, SegmentLoss};
use super::bptt::{Adapted, Backward, GenBufs, Rows, Segment, StepAct, Widths};
use super::rollout::EpisodeStats;
use super::step::StepRec;
use crate::model::episode::ps_input;
use crate::model::{NavModel, K};
use crate::optim::params::ParamSet;
use crate::pretrain::ps::PsBuffers;
use crate::sim::spatial::MapGrid;
use crate::sim::{Env, EpisodeSpec, RewardKind};
use gman_core::nets::generator::Generator;

/// Most environments a worker steps in lockstep.
pub const MAX_BATCH_ENVS: usize = 256;

/// With `B > 1`, the backward of the waiting segments runs once this many steps wait (and at
/// the end of the update): the bound on the memory they hold.
pub(crate) const MAX_PENDING_STEPS: usize = 4096;

/// What the vectorised worker needs besides the model.
#[derive(Clone, Copy, Debug)]
pub struct VecSettings<'a> {
    /// Environments in lockstep (`B`).
    pub batch_envs: usize,
    /// The worker starts episodes while it has taken fewer steps than this in the update.
    pub min_steps: u32,
    /// Reward.
    pub reward: RewardKind,
    /// A3C loss.
    pub a3c: &'a A3cConfig,
    /// Objective.
    pub objective: Objective,
    /// Meta-gradient order (2: `B = 1` and an inner loop, see [`super::meta`]).
    pub meta_order: u8,
}

/// One finished episode of a worker's update: its index, statistics and D after it. Without
/// an inner loop D after every episode is the model's ω; when its values are ω's bit for bit
/// (checked once per update) the list is empty, which the trainer's delta sum
/// `Σ_e (ω_e − ω)` (a zip over the tensors given) reads as no change — the same bits as the
/// +0 that `ω_e − ω` gives for every value, without copying D for every episode.
pub(crate) type Finished = (u32, EpisodeStats, Vec<Vec<f32>>);

/// A segment's loss, with its episode and completion number: `(e, seq, loss)`.
pub(super) type SegLoss = (u32, u32, SegmentLoss);

/// True when `model`'s method runs without an inner loop in training (the engine's shared
/// lanes serve it; the others run one navigator per episode).
pub(crate) fn without_inner_loop(model: &NavModel) -> bool {
    !model.method.adapts_in_training()
}

/// Refuses a `B` out of `1..=MAX_BATCH_ENVS`, and `B > 1` for a method with an inner loop
/// in training with the second-order meta-gradient (its reverse recursion runs over one
/// episode's inner steps, so the engine runs those episodes one at a time).
pub(crate) fn check_batch_envs(model: &NavModel, batch_envs: usize, meta_order: u8) -> Result<()> {
    if !(1..=MAX_BATCH_ENVS).contains(&batch_envs) {
        bail!("--batch-envs must be in 1..={MAX_BATCH_ENVS}, got {batch_envs}");
    }
    if batch_envs > 1 && !without_inner_loop(model) && meta_order != 1 {
        bail!(
            "--batch-envs {batch_envs} with {} is implemented for the first-order meta-gradient; --meta-order {meta_order} runs its episodes one at a time: use --batch-envs 1",
            model.method.name()
        );
    }
    Ok(())
}

/// The engine's loop, the same on both paths: `batch_envs` slots; free slots take new
/// episodes while the step budget lasts (episode `e`'s spec and step limit from `sample(e)`,
/// started in slot `i` by `start(state, i, e, spec, max)`), and every tick runs the episodes
/// in the slots (`tick`, which returns the steps taken and empties the slots of the ended
/// episodes), until no episode runs. `state` is what both steps change.
pub(super) fn lockstep<T, S>(
    batch_envs: usize,
    min_steps: u32,
    mut sample: impl FnMut(u32) -> Result<(EpisodeSpec, u32)>,
    state: &mut S,
    mut start: impl FnMut(&mut S, usize, u32, &EpisodeSpec, u32) -> Result<T>,
    mut tick: impl FnMut(&mut S, &mut [Option<T>]) -> Result<u64>,
) -> Result<()> {
    let mut slots: Vec<Option<T>> = (0..batch_envs).map(|_| None).collect();
    let (mut next, mut taken) = (0u32, 0u64);
    loop {
        fill_free_slots(&mut slots, &mut next, taken, min_steps, |i, e| {
            let (spec, max) = sample(e)?;
            start(state, i, e, &spec, max)
        })?;
        if slots.iter().all(Option::is_none) {
            return Ok(());
        }
        taken += tick(state, &mut slots)?;
    }
}

/// Free slots take new episodes while the step budget lasts: the worker starts episode
/// `next` (then `next + 1`, ...) with `start(slot, e)` while it has taken fewer than
/// `min_steps` steps in the update (always at least one episode).
fn fill_free_slots<T>(
    slots: &mut [Option<T>],
    next: &mut u32,
    taken: u64,
    min_steps: u32,
    mut start: impl FnMut(usize, u32) -> Result<T>,
) -> Result<()> {
    for (i, slot) in slots.iter_mut().enumerate() {
        if slot.is_some() {
            continue;
        }
        if *next > 0 && taken >= min_steps as u64 {
            break;
        }
        *slot = Some(start(i, *next)?);
        *next += 1;
    }
    Ok(())
}

/// An episode's inputs of the current step: the observation, the PS input, the map and, for
/// DAgger, the oracle's labels.
#[derive(Default)]
pub(super) struct StepInputs {
    pub obs: Vec<f32>,
    pub ps: Vec<f32>,
    pub map: Vec<f32>,
    pub expert: Option<[f32; NUM_ACTIONS]>,
}

impl StepInputs {
    /// The observation, PS input and map of `env`'s current state (the labels untouched).
    pub fn observe(
        &mut self,
        env: &Env<'_>,
        model: &NavModel,
        ps_buf: &mut Option<PsBuffers>,
        grid: MapGrid,
        map_len: usize,
    ) -> Result<()> {
        let obs = env.observe();
        self.obs = obs.features.to_vec();
        self.ps = ps_input(model, ps_buf, &self.obs)?;
        self.map = vec![0.0; map_len];
        if !grid.is_empty() {
            env.observe_map(grid, &mut self.map);
        }
        Ok(())
    }
}

/// The recurrent state and conditioning of one episode's row: x_t, SE(y), the previous
/// probabilities and the LSTM state.
pub(super) struct RowState<'a> {
    pub feat: &'a [f32],
    pub attr: &'a [f32],
    pub prev: &'a [f32],
    pub h: &'a [f32],
    pub c: &'a [f32],
}

/// Copies an episode's step inputs and state into row `j` of the batched pass.
pub(super) fn put_row(rows: &mut Rows, j: usize, w: &Widths, inp: &StepInputs, st: RowState<'_>) {
    let p = PolicyInput {
        obs: &inp.obs,
        feat: st.feat,
        attr: st.attr,
        prev_probs: st.prev,
        ps: &inp.ps,
        map: &inp.map,
    };
    rows.put_inputs(j, w, &p, st.h, st.c);
}

/// The critic's values of the next observations of the `going` episodes (those of `ready`
/// that go on; `fill(rows, j, slot)` observes slot's episode and puts it into row `j`), one
/// batched forward at `policy`; 0 for the ended ones; in `ready`'s order.
pub(super) fn bootstrap_values(
    ready: &[usize],
    going: &[usize],
    policy: &Policy<'_>,
    w: &Widths,
    rows: &mut Rows,
    mut fill: impl FnMut(&mut Rows, usize, usize) -> Result<()>,
) -> Result<Vec<f32>> {
    let mut out = vec![0.0f32; ready.len()];
    if going.is_empty() {
        return Ok(out);
    }
    rows.resize(going.len(), w);
    for (j, &i) in going.iter().enumerate() {
        fill(rows, j, i)?;
    }
    rows.forward(policy, going.len(), w)?;
    for (k, &i) in ready.iter().enumerate() {
        if let Some(j) = going.iter().position(|&g| g == i) {
            out[k] = rows.value[j];
        }
    }
    Ok(out)
}

/// A complete segment of episode `e` (run in `slot`, numbered `seq` in the order the
/// segments of the update completed): its steps, their activations, SE(y), `V_T`, and `own`,
/// what the backward needs of the parameters it ran with.
pub(super) struct PendingSeg<O = ()> {
    pub slot: usize,
    pub e: u32,
    pub seq: u32,
    pub steps: Vec<StepRec>,
    pub acts: Vec<StepAct>,
    pub attr: Vec<f32>,
    pub bootstrap: f32,
    pub own: O,
}

/// The segment an episode is recording: its steps and their activations (at most k = 20).
pub(super) struct Recording {
    pub steps: Vec<StepRec>,
    pub acts: Vec<StepAct>,
}

impl Recording {
    /// An empty segment.
    pub fn new() -> Recording {
        Recording {
            steps: Vec::with_capacity(K),
            acts: Vec::with_capacity(K),
        }
    }

    /// Steps recorded.
    pub fn len(&self) -> usize {
        self.steps.len()
    }

    /// True before the segment's first step.
    pub fn is_empty(&self) -> bool {
        self.steps.is_empty()
    }

    /// Records a step and its activations.
    pub fn push(&mut self, step: StepRec, act: StepAct) {
        self.steps.push(step);
        self.acts.push(act);
    }

    /// The recorded segment (steps, activations); the recording starts anew.
    pub fn take(&mut self) -> (Vec<StepRec>, Vec<StepAct>) {
        let old = std::mem::replace(self, Recording::new());
        (old.steps, old.acts)
    }
}

/// The complete segments of a worker's update: numbered in the order they complete, those
/// whose backward waits (and their steps), and the losses of those whose backward ran.
pub(super) struct SegQueue<O = ()> {
    /// The waiting segments.
    pub pending: Vec<PendingSeg<O>>,
    /// Their steps.
    pub steps: usize,
    /// The segments' losses so far.
    pub losses: Vec<SegLoss>,
    /// Segments numbered so far.
    seq: u32,
}

impl<O> SegQueue<O> {
    /// Nothing complete yet.
    pub fn new() -> SegQueue<O> {
        SegQueue {
            pending: Vec::new(),
            steps: 0,
            losses: Vec::new(),
            seq: 0,
        }
    }

    /// Episode `e`'s complete segment (run in `slot`, recorded in `rec`, which starts anew),
    /// numbered as the next to complete.
    pub fn complete(
        &mut self,
        slot: usize,
        e: u32,
        rec: &mut Recording,
        attr: Vec<f32>,
        bootstrap: f32,
        own: O,
    ) -> PendingSeg<O> {
        let (steps, acts) = rec.take();
        let seq = self.seq;
        self.seq += 1;
        PendingSeg {
            slot,
            e,
            seq,
            steps,
            acts,
            attr,
            bootstrap,
            own,
        }
    }

    /// `seg` waits for its backward.
    pub fn wait(&mut self, seg: PendingSeg<O>) {
        self.steps += seg.steps.len();
        self.pending.push(seg);
    }

    /// True when [`MAX_PENDING_STEPS`] steps or more wait.
    pub fn full(&self) -> bool {
        self.steps >= MAX_PENDING_STEPS
    }

    /// The waiting segments; none wait afterwards.
    pub fn take(&mut self) -> Vec<PendingSeg<O>> {
        self.steps = 0;
        std::mem::take(&mut self.pending)
    }
}

/// What one batched BPTT reads besides its segments.
pub(super) struct BackwardCtx<'a> {
    pub policy: &'a Policy<'a>,
    pub gen: &'a Generator<'a>,
    pub a3c: &'a A3cConfig,
    pub train_generator: bool,
    pub w: &'a Widths,
    pub d: &'a Dims,
}

/// Sorts segments into the order of their batched BPTT: longest first, then in the order they
/// completed, so that the segments running at each backward step are a prefix of the batch.
pub(super) fn backward_order<O>(segs: &mut [PendingSeg<O>]) {
    segs.sort_by_key(|p| (std::cmp::Reverse(p.steps.len()), p.seq));
}

/// The backward of `segs` as one batched BPTT in [`backward_order`], each row at the
/// parameters `own(seg)` gives (`None`: `cx`'s). `inspect` sees the batch before it runs.
/// Their losses are collected into `losses`.
#[allow(clippy::too_many_arguments)]
pub(super) fn backward_segments<'p, O>(
    cx: &BackwardCtx<'_>,
    segs: &'p mut [PendingSeg<O>],
    own: impl Fn(&'p PendingSeg<O>) -> Result<Option<Adapted<'p>>>,
    inspect: impl FnOnce(&[Segment<'_>]),
    grads: &mut ParamSet,
    bw: &mut Backward,
    gbuf: &mut GenBufs,
    losses: &mut Vec<SegLoss>,
) -> Result<()> {
    if segs.is_empty() {
        return Ok(());
    }
    backward_order(segs);
    let pend: &'p [PendingSeg<O>] = segs;
    let mut batch: Vec<Segment<'p>> = Vec::with_capacity(pend.len());
    for p in pend {
        batch.push(Segment {
            steps: &p.steps,
            acts: &p.acts,
            attr: &p.attr,
            bootstrap: p.bootstrap,
            own: own(p)?,
        });
    }
    inspect(&batch);
    let ls = bw.run(
        cx.policy,
        cx.gen,
        &batch,
        cx.a3c,
        cx.train_generator,
        cx.w,
        cx.d,
        grads,
        gbuf,
    )?;
    losses.extend(pend.iter().zip(ls).map(|(p, l)| (p.e, p.seq, l)));
    Ok(())
}

/// Adds each segment's loss to its episode's statistics (in the order of its segments) and
/// sorts the episodes by index; refuses a loss whose episode did not finish.
pub(super) fn collect_losses(
    mut losses: Vec<SegLoss>,
    mut done: Vec<Finished>,
) -> Result<Vec<Finished>> {
    losses.sort_by_key(|&(e, q, _)| (e, q));
    done.sort_by_key(|f| f.0);
    let mut li = losses.iter().peekable();
    for f in done.iter_mut() {
        while let Some((_, _, l)) = li.next_if(|(e, _, _)| *e == f.0) {
            f.1.loss.add(l);
        }
    }
    if li.next().is_some() {
        bail!("vectorised rollout: a segment's episode did not finish");
    }
    Ok(done)
}
