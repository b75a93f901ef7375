//! Vectorised training episodes: one worker steps `B` environments in lockstep and runs the
//! policy's forward and backward passes over them as matrices (`Policy::forward_batch`,
//! `Policy::backward_batch` on gman-core's batched kernels).
//!
//! ```text
//! while a slot is free and the worker's step budget is not spent: start episode e in it
//! every tick:
//!   each running episode: observation, PS input, map; noise z_t
//!   x_t = G(SE(y), z_t) for the running episodes, as one batch
//!   one batched policy forward over the running episodes          (Algorithm 1, line 8)
//!   each episode: its action from its own generator, the environment steps
//!   the episodes whose segment is complete (k = 20 steps, or the episode ended):
//!     bootstrap values (one batched forward); the segment waits for its backward
//!   an ended episode frees its slot for the next one (no waiting for the others)
//! at the end of the update (B > 1): one batched BPTT over all the waiting segments
//! ```
//!
//! The methods with an inner loop in training (`gman`, ...) run through
//! [`super::vec_adapt`] (one navigator per episode, per-row adapted heads and θ_i); this
//! module's own path serves the others, below.
//!
//! **For the methods without an inner loop** (`adapts_in_training()` false: `a3c`,
//! `a3c-fg`, `a3c-ps`, `a3c-fg-ps`, `gman-nometa`, `gman-noemd`). There θ and φ stay at the
//! outer parameters for the whole update, so the episodes share one set of parameters and
//! the navigator's step reduces to G, the policy and the action draw. These are taken from a
//! gman-core [`Navigator`] over the model (its own views of G and the policy, in the model's
//! adaptation mode), and each episode keeps the navigator's per-episode state (LSTM state,
//! previous probabilities, x_t, its generator seeded like `Navigator::reset`). Because the
//! batched kernels give every vector the bits of the batch-1 kernels, **each episode is bit
//! for bit the episode the navigator runs alone** (same actions, probabilities, rewards);
//! `tests/vec_rollout.rs` pins this against [`super::trainer::train_episode`].
//!
//! **Gradient order.** θ and φ do not change within an update, so a segment's backward can
//! wait: with `B > 1` every segment of the worker's update joins one batched BPTT at the end
//! of the update (or earlier, whenever [`MAX_PENDING_STEPS`] steps wait, which bounds the
//! memory), ordered by length (longest first), then by the order the segments completed (tick,
//! then slot). Within it every tensor's gradient is summed step by step (last step first)
//! and, within a step, over the batch in order. This batches the backward over all the
//! update's episodes (a tick completes only a few segments, the update tens). The order is
//! fixed by `(seed, update, worker, B)`, so runs stay reproducible and resumable bit for bit;
//! the sum differs from the per-episode sum by float rounding only (`tests/vec_rollout.rs`
//! checks the gradient against it within `1e-4` of each tensor's largest value; this
//! module's tests pin the order). With `B = 1` each segment's backward runs as it completes: exactly the order
//! of [`super::trainer::train_episode`], so `B = 1` gives the same update bit for bit.
//!
//! **Episodes per update.** A worker starts episodes (indices `e = 0, 1, ..`, seeded as in the
//! batch-1 trainer) while it has taken fewer than `min_steps` steps in the update, and the
//! update ends when all its running episodes have ended; so an update holds at least `B`
//! episodes per worker (with `B = 1` exactly the batch-1 rule).
//!
//! [`MAX_PENDING_STEPS`]: super::lockstep::MAX_PENDING_STEPS

use anyhow::{anyhow, bail, Result};
use gman_core::activation::{all_finite, leaky_relu_inplace, sigmoid_inplace};
use gman_core::blob::TensorId;
use gman_core::generator::Generator;
use gman_core::matrix::{MatRef, Weights};
use gman_core::memory::AdaptMode;
use gman_core::navigator::{select_action, Efficient, Full, Mode, Navigator, NoiseMode, Selection};
use gman_core::policy::Policy;
use gman_core::rng::{fill_gaussian, Xoshiro128};
use gman_core::{Dims, NUM_ACTIONS};

use super::a3c::Objective;
use super::bptt::{take_act, Backward, GenBufs, Rows, Widths};
use super::lockstep::{
    backward_segments, bootstrap_values, check_batch_envs, collect_losses, lockstep, put_row,
    without_inner_loop, BackwardCtx, Finished, PendingSeg, Recording, RowState, SegQueue, Share,
    StepInputs, VecSettings,
};
use super::rollout::{disc_after_episode, expert_distribution, EpisodeStats, Worker};
use super::step::StepRec;
use crate::model::{NavModel, K};
use crate::optim::params::ParamSet;
use crate::pretrain::ps::PsBuffers;
use crate::sim::spatial::MapGrid;
use crate::sim::{Env, EpisodeSpec, RewardKind, World};

/// One environment slot: a running episode and the navigator state it carries.
struct Slot<'w> {
    e: u32,
    env: Env<'w>,
    rng: Xoshiro128,
    attr: Vec<f32>,
    h: Vec<f32>,
    c: Vec<f32>,
    prev: Vec<f32>,
    x: Vec<f32>,
    z: Vec<f32>,
    x_valid: bool,
    x_fixed: bool,
    rec: Recording,
    stats: EpisodeStats,
    /// This step's inputs (before the forward).
    inp: StepInputs,
}

/// Runs one worker's share of an update with `s.batch_envs` environments in lockstep:
/// episodes `e = 0, 1, ..` come from `sample(e)` (spec and step limit), the A3C gradient of
/// every segment is accumulated into `grads` (see the module docs for the order). Returns the
/// finished episodes sorted by index. A method with an inner loop in training runs through
/// [`super::vec_adapt::run_worker`].
pub fn run_worker(
    world: &World,
    model: &NavModel,
    s: &VecSettings<'_>,
    worker: &mut Worker,
    grads: &mut ParamSet,
    sample: impl FnMut(u32) -> Result<(EpisodeSpec, u32)>,
) -> Result<Vec<Finished>> {
    let job = Share {
        world,
        model,
        s,
        worker,
        grads,
        sample,
    };
    if !without_inner_loop(model) {
        return super::vec_adapt::run_worker(job);
    }
    match model.adapt_mode {
        AdaptMode::Full => run_worker_in::<Full>(job, None),
        AdaptMode::Efficient => run_worker_in::<Efficient>(job, None),
    }
}

/// What every tick of a worker's update reads: the model, the settings, the parameter views
/// (from a navigator over the model, in its adaptation mode) and the widths.
struct Ctx<'a> {
    model: &'a NavModel,
    s: &'a VecSettings<'a>,
    policy: Policy<'a>,
    gen: Generator<'a>,
    w: Widths,
    d: Dims,
    grid: MapGrid,
    train_generator: bool,
}

/// The buffers a worker's update reuses across ticks.
struct Bufs<'b> {
    ps: &'b mut Option<PsBuffers>,
    rows: Rows,
    bw: Backward,
    gen: GenBufs,
    gb: GenBatch,
    /// Segments whose forward is done, waiting for their backward (see the module docs),
    /// and the losses of those whose backward ran.
    queue: SegQueue,
}

/// G's forward over the episodes of a tick that draw a new x_t, as one batch.
#[derive(Default)]
struct GenBatch {
    /// Slots (indices into `slots`) of the batch, in tick order.
    who: Vec<usize>,
    z: Vec<f32>,
    attr: Vec<f32>,
    u1: Vec<f32>,
    h1: Vec<f32>,
    u2: Vec<f32>,
    x: Vec<f32>,
    /// G's weight matrices are all zero (plain A3C: `--method a3c`, `a3c-ps`): then x_t
    /// depends on neither z_t nor SE(y) (see [`GenBatch::generate`]), so it is computed once
    /// per update and copied.
    zero_g: bool,
    /// With `zero_g`, the x_t of every episode (after the update's first batch).
    constant: Option<Vec<f32>>,
}

fn check_settings(model: &NavModel, s: &VecSettings<'_>) -> Result<()> {
    check_batch_envs(model, s.batch_envs, 1)?;
    if !without_inner_loop(model) {
        bail!(
            "the vectorised rollout runs the methods without an inner loop in training; {} runs its inner loop per episode",
            model.method.name()
        );
    }
    let cfg = model.nav_config(true);
    if cfg.adapt || cfg.selection != Selection::Sample {
        bail!("vectorised episodes need a sampling navigator without inner loop");
    }
    Ok(())
}

/// [`run_worker`] for a method without an inner loop, in the adaptation mode `M`; `keep`
/// (the tests') takes the update's last waiting segments instead of their backward.
fn run_worker_in<'w, M: Mode>(
    job: Share<'_, 'w, impl FnMut(u32) -> Result<(EpisodeSpec, u32)>>,
    keep: Option<&mut Vec<PendingSeg>>,
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
    // The navigator provides the parameter views (G and the policy, in the model's mode).
    let weights = model.weights()?;
    let Worker {
        arena, ps: ps_buf, ..
    } = worker;
    let mut nav: Navigator<'_, M, K> = Navigator::new(weights, arena, model.nav_config(true))?;
    let d = *nav.dims();
    nav.reset(&vec![0.0; d.attr], 0)?;
    let policy = nav.policy()?;
    let w = Widths::of(&policy, &d);
    // D after an episode: unchanged without an inner loop (see [`Finished`]).
    let disc = if is_omega(&nav, model)? {
        Vec::new()
    } else {
        disc_after_episode(&nav)?
    };
    let cx = Ctx {
        model,
        s,
        w,
        d,
        grid: MapGrid {
            rows: d.map_rows,
            cols: d.map_cols,
        },
        train_generator: model.method.trains_generator() && !model.privileged,
        gen: nav.generator()?,
        policy,
    };
    let mut bufs = Bufs {
        ps: ps_buf,
        rows: Rows::default(),
        bw: Backward::default(),
        gen: GenBufs::new(&cx.gen, w.f),
        gb: GenBatch {
            zero_g: is_zero(&cx.gen.l1.w) && is_zero(&cx.gen.l2.w),
            ..GenBatch::default()
        },
        queue: SegQueue::new(),
    };
    let mut done: Vec<Finished> = Vec::new();
    lockstep(
        s.batch_envs,
        s.min_steps,
        sample,
        &mut (),
        |_, _, e, spec, max| start_slot(world, spec, model, s.reward, max, e, &w),
        |_, slots: &mut [Option<Slot<'w>>]| {
            let active: Vec<usize> = (0..slots.len()).filter(|&i| slots[i].is_some()).collect();
            let taken = step_slots(&cx, &mut bufs, slots, &active)?;
            close_segments(&cx, &mut bufs, slots, &active, grads, &mut done, &disc)?;
            Ok(taken)
        },
    )?;
    match keep {
        // The tests' view of the final batch: its segments, instead of their backward.
        Some(k) => *k = bufs.queue.take(),
        None => flush(&cx, &mut bufs, grads)?,
    }
    collect_losses(bufs.queue.losses, done)
}

/// The segments complete at this tick (k = 20 steps, or the episode ended): their bootstrap
/// values, then they wait for their backward (run at once with `B = 1`, the order of
/// [`super::trainer::train_episode`], or when [`MAX_PENDING_STEPS`] steps wait); the ended
/// episodes leave their slots, each with `disc`, D after it.
///
/// [`MAX_PENDING_STEPS`]: super::lockstep::MAX_PENDING_STEPS
fn close_segments(
    cx: &Ctx<'_>,
    bufs: &mut Bufs<'_>,
    slots: &mut [Option<Slot<'_>>],
    active: &[usize],
    grads: &mut ParamSet,
    done: &mut Vec<Finished>,
    disc: &[Vec<f32>],
) -> Result<()> {
    let ready: Vec<usize> = active
        .iter()
        .copied()
        .filter(|&i| {
            slots[i]
                .as_ref()
                .is_some_and(|s| s.rec.len() == K || s.env.is_done())
        })
        .collect();
    if ready.is_empty() {
        return Ok(());
    }
    pend_ready(cx, bufs, slots, &ready)?;
    if cx.s.batch_envs == 1 || bufs.queue.full() {
        flush(cx, bufs, grads)?;
    }
    for slot in slots.iter_mut() {
        if slot.as_ref().is_some_and(|s| s.env.is_done()) {
            if let Some(sl) = slot.take() {
                done.push(finish(sl, disc.to_vec()));
            }
        }
    }
    Ok(())
}

/// One tick of the running episodes `active`: their inputs and x_t, one batched policy
/// forward, each episode's action from its own generator and the environment's step, the
/// step recorded for the backward. Returns the steps taken.
fn step_slots(
    cx: &Ctx<'_>,
    b: &mut Bufs<'_>,
    slots: &mut [Option<Slot<'_>>],
    active: &[usize],
) -> Result<u64> {
    let (w, n) = (&cx.w, active.len());
    b.gb.who.clear();
    for &i in active {
        let sl = slots[i].as_mut().ok_or_else(|| anyhow!("empty slot"))?;
        observe(sl, cx.model, b.ps, cx.grid, w.map)?;
        sl.inp.expert = (cx.s.objective == Objective::Dagger).then(|| expert_distribution(&sl.env));
        if !sl.x_fixed {
            match cx.model.noise {
                NoiseMode::Gaussian => {
                    fill_gaussian(&mut sl.rng, &mut sl.z);
                    b.gb.who.push(i);
                }
                NoiseMode::Zero => {
                    if !sl.x_valid {
                        sl.z.fill(0.0);
                        b.gb.who.push(i);
                        sl.x_valid = true;
                    }
                }
            }
        }
    }
    b.gb.generate(&cx.gen, slots, w)?;
    let rows = &mut b.rows;
    rows.resize(n, w);
    for (j, &i) in active.iter().enumerate() {
        let sl = slots[i].as_ref().ok_or_else(|| anyhow!("empty slot"))?;
        put_inputs(rows, j, sl, w);
    }
    rows.forward(&cx.policy, n, w)?;
    for (j, &i) in active.iter().enumerate() {
        let sl = slots[i].as_mut().ok_or_else(|| anyhow!("empty slot"))?;
        let probs = &rows.probs[j * NUM_ACTIONS..(j + 1) * NUM_ACTIONS];
        if !all_finite(probs) || !rows.value[j].is_finite() {
            bail!("navigator: numerical fault in action probabilities");
        }
        let mut p = [0.0f32; NUM_ACTIONS];
        p.copy_from_slice(probs);
        let action = select_action(Selection::Sample, &p, &mut sl.rng);
        sl.stats.actions.push(action.index() as u8);
        let o = sl.env.step(action);
        let act = take_act(rows, j, w);
        let step = StepRec {
            obs: std::mem::take(&mut sl.inp.obs),
            ps: std::mem::take(&mut sl.inp.ps),
            map: std::mem::take(&mut sl.inp.map),
            x: sl.x.clone(),
            z: sl.z.clone(),
            h_prev: std::mem::replace(&mut sl.h, rows.h[j * w.hd..(j + 1) * w.hd].to_vec()),
            c_prev: std::mem::replace(&mut sl.c, rows.c[j * w.hd..(j + 1) * w.hd].to_vec()),
            prev_probs: std::mem::replace(&mut sl.prev, probs.to_vec()),
            action: action.index(),
            reward: o.reward,
            probs: p,
            expert: sl.inp.expert.take(),
        };
        sl.rec.push(step, act);
    }
    Ok(n as u64)
}

/// The segments complete at this tick (`ready`): their bootstrap values (one batched
/// forward, at the parameters they ran with), then they join the pending segments, numbered
/// in `ready`'s (slot) order; the slots' segments are cleared.
fn pend_ready(
    cx: &Ctx<'_>,
    b: &mut Bufs<'_>,
    slots: &mut [Option<Slot<'_>>],
    ready: &[usize],
) -> Result<()> {
    let boot = bootstrap(cx, b, slots, ready)?;
    for (&i, boot) in ready.iter().zip(boot) {
        let sl = slots[i].as_mut().ok_or_else(|| anyhow!("empty slot"))?;
        let seg = b
            .queue
            .complete(i, sl.e, &mut sl.rec, sl.attr.clone(), boot, ());
        b.queue.wait(seg);
    }
    Ok(())
}

/// The backward of the pending segments as one batched BPTT (see
/// [`super::lockstep::backward_segments`]), at the update's parameters. Their losses are
/// collected as `(episode, seq, loss)`; nothing is pending afterwards.
fn flush(cx: &Ctx<'_>, b: &mut Bufs<'_>, grads: &mut ParamSet) -> Result<()> {
    let mut pend = b.queue.take();
    let bx = BackwardCtx {
        policy: &cx.policy,
        gen: &cx.gen,
        a3c: cx.s.a3c,
        train_generator: cx.train_generator,
        w: &cx.w,
        d: &cx.d,
    };
    backward_segments(
        &bx,
        &mut pend,
        |_| Ok(None),
        |_| {},
        grads,
        &mut b.bw,
        &mut b.gen,
        &mut b.queue.losses,
    )
}

impl GenBatch {
    /// x_t = G(SE(y), z_t) for the slots in `who` (their `z` drawn), as one batch through
    /// the batched dense kernels: every vector gets the bits of `Generator::forward` alone
    /// (the kernels' contract; the activations are element-wise).
    fn generate(
        &mut self,
        gen: &Generator<'_>,
        slots: &mut [Option<Slot<'_>>],
        w: &Widths,
    ) -> Result<()> {
        let n = self.who.len();
        if n == 0 {
            return Ok(());
        }
        if let Some(x) = &self.constant {
            for &i in &self.who {
                let sl = slots[i].as_mut().ok_or_else(|| anyhow!("empty slot"))?;
                sl.x.copy_from_slice(x);
            }
            return Ok(());
        }
        gen.validate()?;
        let (h, a) = (gen.hidden(), w.a);
        if gen.in_dim() != w.z + a || gen.feat() != w.f {
            bail!("generator: widths do not match the model");
        }
        self.z.clear();
        self.attr.clear();
        for &i in &self.who {
            let sl = slots[i].as_ref().ok_or_else(|| anyhow!("empty slot"))?;
            self.z.extend_from_slice(&sl.z);
            self.attr.extend_from_slice(&sl.attr);
        }
        let sz = |v: &mut Vec<f32>, k: usize| {
            v.clear();
            v.resize(k, 0.0);
        };
        sz(&mut self.u1, if gen.l1.gain.is_some() { n * h } else { 0 });
        sz(&mut self.h1, n * h);
        sz(
            &mut self.u2,
            if gen.l2.gain.is_some() { n * w.f } else { 0 },
        );
        sz(&mut self.x, n * w.f);
        gen.l1.forward_batch(
            &[&self.z, &self.attr],
            &[w.z, a],
            n,
            &mut self.u1,
            &mut self.h1,
        )?;
        leaky_relu_inplace(&mut self.h1);
        gen.l2
            .forward_batch(&[&self.h1], &[h], n, &mut self.u2, &mut self.x)?;
        sigmoid_inplace(&mut self.x);
        if self.zero_g {
            // With W1 = 0 and W2 = 0 every product in G is ±0 (z_t and SE(y) are finite:
            // drawn, and checked when the episode starts), each layer's dot product is +0
            // (its sum starts at +0), so the pre-activations are the biases (through the
            // gain: g · (+0) + b) whatever the inputs, and the sigmoid maps ±0 alike: every
            // episode's x_t is this batch's first row, bit for bit, as the navigator alone
            // computes it.
            self.constant = Some(self.x[..w.f].to_vec());
        }
        for (&i, x) in self.who.iter().zip(self.x.chunks_exact(w.f)) {
            let sl = slots[i].as_mut().ok_or_else(|| anyhow!("empty slot"))?;
            sl.x.copy_from_slice(x);
        }
        Ok(())
    }
}

/// True when every weight of `m` is exactly zero (either sign; int8: every code zero, so every
/// product is a zero before the row scale, whatever the scale).
fn is_zero(m: &MatRef<'_>) -> bool {
    match m.weights() {
        Weights::F32(d) => d.iter().all(|&v| v == 0.0),
        Weights::F32Le(d) => d
            .chunks_exact(4)
            .all(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]]) == 0.0),
        Weights::I8 { q, .. } => q.iter().all(|&b| b == 0),
    }
}

fn start_slot<'w>(
    world: &'w World,
    spec: &EpisodeSpec,
    model: &NavModel,
    reward: RewardKind,
    max: u32,
    e: u32,
    w: &Widths,
) -> Result<Slot<'w>> {
    let attr = world.attributes(spec.target).to_vec();
    if !all_finite(&attr) {
        bail!("navigator: non-finite attr");
    }
    let (x, x_fixed) = if model.privileged {
        (world.object_feature(spec.scene, spec.target).to_vec(), true)
    } else {
        (vec![0.0; w.f], false)
    };
    Ok(Slot {
        e,
        env: Env::new(world, spec, reward, max),
        rng: Xoshiro128::seed_from_u64(spec.seed),
        attr,
        h: vec![0.0; w.hd],
        c: vec![0.0; w.hd],
        prev: vec![0.0; NUM_ACTIONS],
        x,
        z: vec![0.0; w.z],
        x_valid: false,
        x_fixed,
        rec: Recording::new(),
        stats: EpisodeStats::default(),
        inp: StepInputs::default(),
    })
}

/// The slot's current observation, PS input and map, checked finite.
fn observe(
    sl: &mut Slot<'_>,
    model: &NavModel,
    ps_buf: &mut Option<PsBuffers>,
    grid: MapGrid,
    map_len: usize,
) -> Result<()> {
    sl.inp.observe(&sl.env, model, ps_buf, grid, map_len)?;
    let inp = &sl.inp;
    if !all_finite(&inp.obs) || !all_finite(&inp.map) || !all_finite(&inp.ps) {
        bail!("navigator: non-finite input");
    }
    Ok(())
}

/// Copies the slot's step inputs (and LSTM state) into row `j`.
fn put_inputs(rows: &mut Rows, j: usize, sl: &Slot<'_>, w: &Widths) {
    let st = RowState {
        feat: &sl.x,
        attr: &sl.attr,
        prev: &sl.prev,
        h: &sl.h,
        c: &sl.c,
    };
    put_row(rows, j, w, &sl.inp, st);
}

/// The critic's values of the next observations of the ready slots whose episode goes on
/// (one batched forward), 0 for the ended ones; in `ready`'s order.
fn bootstrap(
    cx: &Ctx<'_>,
    b: &mut Bufs<'_>,
    slots: &mut [Option<Slot<'_>>],
    ready: &[usize],
) -> Result<Vec<f32>> {
    let going: Vec<usize> = ready
        .iter()
        .copied()
        .filter(|&i| slots[i].as_ref().is_some_and(|s| !s.env.is_done()))
        .collect();
    let ps = &mut *b.ps;
    bootstrap_values(
        ready,
        &going,
        &cx.policy,
        &cx.w,
        &mut b.rows,
        |rows, j, i| {
            let sl = slots[i].as_mut().ok_or_else(|| anyhow!("empty slot"))?;
            observe(sl, cx.model, ps, cx.grid, cx.w.map)?;
            put_inputs(rows, j, sl, &cx.w);
            // The inputs are observed again at the next step.
            sl.inp.obs.clear();
            Ok(())
        },
    )
}

/// True when D as the navigator holds it after an episode without an inner loop
/// ([`disc_after_episode`]: `diag(gain) W1`, `b1`, `w2`, `b2`) is the model's ω bit for
/// bit: W1 in f32 with no gain or unit gains, and every value the model's.
fn is_omega<M: Mode>(nav: &Navigator<'_, M, K>, model: &NavModel) -> Result<bool> {
    let d = nav.discriminator()?;
    let w1 = match d.l1.w.weights() {
        Weights::F32(w) => w,
        _ => return Ok(false),
    };
    if d.l1
        .gain
        .is_some_and(|g| g.iter().any(|v| v.to_bits() != 1f32.to_bits()))
    {
        return Ok(false);
    }
    let b2 = [d.b2];
    let ids = TensorId::DISCRIMINATOR;
    for (id, v) in ids.iter().zip([w1, d.l1.b, d.w2, &b2[..]]) {
        let p = &model.params.tensor(id.name())?.data;
        if p.len() != v.len() || p.iter().zip(v).any(|(a, b)| a.to_bits() != b.to_bits()) {
            return Ok(false);
        }
    }
    Ok(ids.len() == 4)
}

fn finish(sl: Slot<'_>, disc: Vec<Vec<f32>>) -> Finished {
    let m = sl.env.metrics();
    let mut stats = sl.stats;
    stats.success = m.success;
    stats.steps = sl.env.steps();
    stats.total_reward = m.total_reward;
    stats.adaptations = 0;
    stats.rollbacks = 0;
    stats.disc_gap = f32::NAN;
    stats.adapt_loss = f32::NAN;
    stats.final_feature = sl.x;
    (sl.e, stats, disc)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::Method;
    use crate::pretrain::generator::init_generator;
    use crate::train::a3c::A3cConfig;
    use crate::train::bptt::Segment;
    use gman_core::rng::Xoshiro128;
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
            let model = NavModel::init(method, d, 3, Some(&g), None).unwrap();
            let a3c = A3cConfig::default();
            let s = VecSettings {
                batch_envs: 6,
                min_steps: 60,
                reward: RewardKind::Mixed,
                a3c: &a3c,
                objective: Objective::A3c,
            };
            let sample = |e: u32| -> Result<(EpisodeSpec, u32)> {
                let mut rng = ChaCha8Rng::seed_from_u64(900 + e as u64);
                Ok((world.try_sample_train_episode_min(&mut rng, 1)?, 45))
            };
            let run = |keep: Option<&mut Vec<PendingSeg>>| {
                let mut grads = model.params.zeros_like();
                let mut worker = Worker::new(&model);
                let job = Share {
                    world: &world,
                    model: &model,
                    s: &s,
                    worker: &mut worker,
                    grads: &mut grads,
                    sample,
                };
                let done = run_worker_in::<Efficient>(job, keep).unwrap();
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
            fn seg(p: &PendingSeg) -> Segment<'_> {
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

    /// The zero-G shortcut of [`GenBatch`] applies to zero matrices only, of any storage.
    #[test]
    fn zero_matrices_are_recognised() {
        let mut d = vec![0.0f32; 12];
        d[5] = -0.0;
        assert!(is_zero(&MatRef::f32(3, 4, &d).unwrap()));
        d[7] = 1e-38;
        assert!(!is_zero(&MatRef::f32(3, 4, &d).unwrap()));
        let le: Vec<u8> = [0.0f32, -0.0, 0.0, 0.0]
            .iter()
            .flat_map(|v| v.to_le_bytes())
            .collect();
        assert!(is_zero(&MatRef::f32_le(2, 2, &le).unwrap()));
        let le1: Vec<u8> = [0.0f32, 2.0].iter().flat_map(|v| v.to_le_bytes()).collect();
        assert!(!is_zero(&MatRef::f32_le(1, 2, &le1).unwrap()));
        let scales = [1.0f32, f32::NAN];
        let q = [0u8; 4];
        let sc = gman_core::matrix::Scales::F32(&scales);
        assert!(is_zero(&MatRef::i8(2, 2, &q, sc).unwrap()));
        let q1 = [0u8, 0, 0xff, 0];
        assert!(!is_zero(&MatRef::i8(2, 2, &q1, sc).unwrap()));
    }
}
