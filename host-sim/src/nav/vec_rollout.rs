//! Vectorised training episodes: one worker steps `B` environments in lockstep and runs the
//! policy's forward and backward passes over them as matrices (`Policy::forward_batch`,
//! `Policy::backward_batch` on gman-core's batched kernels).
//!
//! ```text
//! while a slot is free and the worker's step budget is not spent: start episode e in it
//! every tick:
//!   each running episode: observation, PS input, map; noise z_t and x_t = G(SE(y), z_t)
//!   one batched policy forward over the running episodes          (Algorithm 1, line 8)
//!   each episode: its action from its own generator, the environment steps
//!   the episodes whose segment is complete (k = 20 steps, or the episode ended):
//!     bootstrap values (one batched forward), then one batched BPTT over their segments
//!   an ended episode frees its slot for the next one (no waiting for the others)
//! ```
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
//! `tests/vec_rollout.rs` pins this against [`super::rollout::train_episode`].
//!
//! **Gradient order.** The segments that complete at the same tick form one backward batch,
//! ordered by length (longest first, then slot); within it every tensor's gradient is summed
//! step by step (last step first) and, within a step, over the batch in order. With `B = 1`
//! this is exactly the order of [`super::rollout::train_episode`] (one segment at a time), so
//! `B = 1` gives the same update bit for bit; with `B > 1` the order is fixed by
//! `(seed, update, worker, B)`, so runs stay reproducible and resumable bit for bit.
//!
//! **Episodes per update.** A worker starts episodes (indices `e = 0, 1, ..`, seeded as in the
//! batch-1 trainer) while it has taken fewer than `min_steps` steps in the update, and the
//! update ends when all its running episodes have ended; so an update holds at least `B`
//! episodes per worker (with `B = 1` exactly the batch-1 rule).

use anyhow::{anyhow, bail, Result};
use gman_core::activation::all_finite;
use gman_core::blob::TensorId;
use gman_core::dense::DenseGrads;
use gman_core::generator::{Generator, GeneratorCache, GeneratorScratch};
use gman_core::lstm::LstmGrads;
use gman_core::memory::AdaptMode;
use gman_core::navigator::{Efficient, Full, Mode, Navigator, NoiseMode, Selection};
use gman_core::policy::{
    Policy, PolicyBatchCache, PolicyGrads, PolicyInput, PolicyInputGrads, PolicyScratch,
};
use gman_core::rng::{fill_gaussian, uniform, Xoshiro128};
use gman_core::{Action, NUM_ACTIONS};

use super::a3c::{output_grads, A3cConfig, Objective, SegmentLoss, GRAD_NAMES};
use super::model::NavModel;
use super::rollout::{expert_distribution, EpisodeStats, StepRec, Worker};
use super::K;
use crate::sim::spatial::MapGrid;
use crate::sim::{Env, EpisodeSpec, RewardKind, World};
use crate::train::params::ParamSet;
use crate::train::ps::PsBuffers;

/// Most environments a worker steps in lockstep.
pub const MAX_BATCH_ENVS: usize = 256;

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
}

/// True when `model`'s method can be trained by [`run_worker`] (no inner loop in training).
pub fn supports(model: &NavModel) -> bool {
    !model.method.adapts_in_training()
}

/// The widths of one policy step of `model`.
#[derive(Clone, Copy, Debug)]
struct Widths {
    f: usize,
    a: usize,
    ps: usize,
    map: usize,
    e: usize,
    hd: usize,
    au: usize,
    cells: usize,
    ce: usize,
    z: usize,
}

/// Batch-major step buffers of `n` rows (inputs, states and activations).
#[derive(Default)]
struct Rows {
    obs: Vec<f32>,
    feat: Vec<f32>,
    attr: Vec<f32>,
    prev: Vec<f32>,
    ps: Vec<f32>,
    map: Vec<f32>,
    h_prev: Vec<f32>,
    c_prev: Vec<f32>,
    prod: Vec<f32>,
    fuse: Vec<f32>,
    gates: Vec<f32>,
    c: Vec<f32>,
    h: Vec<f32>,
    actor_u: Vec<f32>,
    logits: Vec<f32>,
    probs: Vec<f32>,
    value: Vec<f32>,
    cell: Vec<f32>,
    cell_prod: Vec<f32>,
}

impl Rows {
    fn resize(&mut self, n: usize, w: &Widths) {
        let sz = |v: &mut Vec<f32>, k: usize| v.resize(n * k, 0.0);
        sz(&mut self.obs, w.f);
        sz(&mut self.feat, w.f);
        sz(&mut self.attr, w.a);
        sz(&mut self.prev, NUM_ACTIONS);
        sz(&mut self.ps, w.ps);
        sz(&mut self.map, w.map);
        sz(&mut self.h_prev, w.hd);
        sz(&mut self.c_prev, w.hd);
        sz(&mut self.prod, w.f);
        sz(&mut self.fuse, w.e);
        sz(&mut self.gates, 4 * w.hd);
        sz(&mut self.c, w.hd);
        sz(&mut self.h, w.hd);
        sz(&mut self.actor_u, w.au);
        sz(&mut self.logits, NUM_ACTIONS);
        sz(&mut self.probs, NUM_ACTIONS);
        sz(&mut self.value, 1);
        sz(&mut self.cell, w.cells * w.ce);
        sz(&mut self.cell_prod, w.map);
    }

    /// The batched forward over the first `n` rows.
    fn forward(&mut self, policy: &Policy<'_>, n: usize, w: &Widths) -> Result<()> {
        self.resize(n, w);
        let inp = PolicyInput {
            obs: &self.obs,
            feat: &self.feat,
            attr: &self.attr,
            prev_probs: &self.prev,
            ps: &self.ps,
            map: &self.map,
        };
        let mut cache = PolicyBatchCache {
            prod: &mut self.prod,
            fuse: &mut self.fuse,
            gates: &mut self.gates,
            c: &mut self.c,
            h: &mut self.h,
            actor_u: &mut self.actor_u,
            logits: &mut self.logits,
            probs: &mut self.probs,
            value: &mut self.value,
            cell: &mut self.cell,
            cell_prod: &mut self.cell_prod,
        };
        policy.forward_batch(n, &inp, &self.h_prev, &self.c_prev, &mut cache)?;
        Ok(())
    }
}

/// The activations of one step the backward pass needs (saved from the rollout's forward).
struct StepAct {
    prod: Vec<f32>,
    fuse: Vec<f32>,
    gates: Vec<f32>,
    c: Vec<f32>,
    h: Vec<f32>,
    actor_u: Vec<f32>,
    value: f32,
    cell: Vec<f32>,
}

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
    seg: Vec<StepRec>,
    acts: Vec<StepAct>,
    stats: EpisodeStats,
    // This step's inputs (before the forward).
    obs: Vec<f32>,
    ps: Vec<f32>,
    map: Vec<f32>,
    expert: Option<[f32; NUM_ACTIONS]>,
}

/// One finished episode of a worker's update: its index, statistics and D after it.
pub type Finished = (u32, EpisodeStats, Vec<Vec<f32>>);

/// Runs one worker's share of an update with `s.batch_envs` environments in lockstep:
/// episodes `e = 0, 1, ..` come from `sample(e)` (spec and step limit), the A3C gradient of
/// every segment is accumulated into `grads` (see the module docs for the order). Returns the
/// finished episodes sorted by index.
pub fn run_worker(
    world: &World,
    model: &NavModel,
    s: &VecSettings<'_>,
    worker: &mut Worker,
    grads: &mut ParamSet,
    sample: impl FnMut(u32) -> Result<(EpisodeSpec, u32)>,
) -> Result<Vec<Finished>> {
    match model.adapt_mode {
        AdaptMode::Full => run_worker_in::<Full>(world, model, s, worker, grads, sample),
        AdaptMode::Efficient => run_worker_in::<Efficient>(world, model, s, worker, grads, sample),
    }
}

fn run_worker_in<'w, M: Mode>(
    world: &'w World,
    model: &NavModel,
    s: &VecSettings<'_>,
    worker: &mut Worker,
    grads: &mut ParamSet,
    mut sample: impl FnMut(u32) -> Result<(EpisodeSpec, u32)>,
) -> Result<Vec<Finished>> {
    if !supports(model) {
        bail!(
            "--batch-envs > 1 is implemented for the methods without an inner loop in training (a3c, a3c-fg, a3c-ps, a3c-fg-ps, gman-nometa, gman-noemd); {} runs its inner loop per episode: use --batch-envs 1",
            model.method.name()
        );
    }
    if !(1..=MAX_BATCH_ENVS).contains(&s.batch_envs) {
        bail!(
            "--batch-envs must be in 1..={MAX_BATCH_ENVS}, got {}",
            s.batch_envs
        );
    }
    let cfg = model.nav_config(true);
    if cfg.adapt || cfg.selection != Selection::Sample {
        bail!("vectorised episodes need a sampling navigator without inner loop");
    }
    let train_generator = model.method.trains_generator() && !model.privileged;
    // The navigator provides the parameter views (G and the policy, in the model's mode).
    let weights = model.weights()?;
    let Worker {
        arena,
        ps: ps_buf,
        map: _,
    } = worker;
    let mut nav: Navigator<'_, M, K> = Navigator::new(weights, arena, cfg)?;
    let d = *nav.dims();
    nav.reset(&vec![0.0; d.attr], 0)?;
    let policy = nav.policy()?;
    let gen = nav.generator()?;
    let w = Widths {
        f: d.feat,
        a: d.attr,
        ps: d.ps,
        map: d.map_len(),
        e: policy.fuse.out_dim(),
        hd: policy.lstm.hidden(),
        au: if policy.actor.gain.is_some() {
            NUM_ACTIONS
        } else {
            0
        },
        cells: d.map_cells(),
        ce: if d.map_cells() > 0 { d.cell_embed } else { 0 },
        z: d.noise,
    };
    let grid = MapGrid {
        rows: d.map_rows,
        cols: d.map_cols,
    };
    // D after an episode: unchanged without an inner loop (in the Efficient mode its unit
    // gains, 1, folded into W1 as the batch-1 trainer does).
    let disc = {
        let dd = nav.discriminator()?;
        let (r, cc) = (dd.l1.w.rows(), dd.l1.w.cols());
        let w1: Vec<f32> = (0..r * cc)
            .map(|i| dd.l1.gain.map_or(1.0, |g| g[i / cc]) * dd.l1.w.get(i / cc, i % cc))
            .collect();
        vec![w1, dd.l1.b.to_vec(), dd.w2.to_vec(), vec![dd.b2]]
    };
    let mut gbuf = GenBufs::new(&gen, w.f);
    let mut slots: Vec<Option<Slot<'w>>> = (0..s.batch_envs).map(|_| None).collect();
    let mut done: Vec<Finished> = Vec::new();
    let (mut next_e, mut taken) = (0u32, 0u64);
    let mut rows = Rows::default();
    let mut bw = Backward::default();
    loop {
        // Free slots take new episodes while the step budget lasts.
        for slot in slots.iter_mut().filter(|s| s.is_none()) {
            if next_e > 0 && taken >= s.min_steps as u64 {
                break;
            }
            let (spec, max) = sample(next_e)?;
            *slot = Some(start_slot(world, &spec, model, s.reward, max, next_e, &w)?);
            next_e += 1;
        }
        let active: Vec<usize> = (0..slots.len()).filter(|&i| slots[i].is_some()).collect();
        if active.is_empty() {
            break;
        }
        // Inputs of this step.
        let n = active.len();
        rows.resize(n, &w);
        for (j, &i) in active.iter().enumerate() {
            let sl = slots[i].as_mut().ok_or_else(|| anyhow!("empty slot"))?;
            observe(sl, model, ps_buf, grid, w.map, s.objective)?;
            if !sl.x_fixed {
                match model.noise {
                    NoiseMode::Gaussian => {
                        fill_gaussian(&mut sl.rng, &mut sl.z);
                        gbuf.generate(&gen, &sl.z, &sl.attr, &mut sl.x)?;
                    }
                    NoiseMode::Zero => {
                        if !sl.x_valid {
                            sl.z.fill(0.0);
                            gbuf.generate(&gen, &sl.z, &sl.attr, &mut sl.x)?;
                            sl.x_valid = true;
                        }
                    }
                }
            }
            put_inputs(&mut rows, j, sl, &w);
        }
        rows.forward(&policy, n, &w)?;
        for (j, &i) in active.iter().enumerate() {
            let sl = slots[i].as_mut().ok_or_else(|| anyhow!("empty slot"))?;
            let probs = &rows.probs[j * NUM_ACTIONS..(j + 1) * NUM_ACTIONS];
            if !all_finite(probs) || !rows.value[j].is_finite() {
                bail!("navigator: numerical fault in action probabilities");
            }
            let mut p = [0.0f32; NUM_ACTIONS];
            p.copy_from_slice(probs);
            let action = select(&mut sl.rng, &p);
            sl.stats.actions.push(action.index() as u8);
            let o = sl.env.step(action);
            taken += 1;
            sl.acts.push(take_act(&rows, j, &w));
            let rec = StepRec {
                obs: std::mem::take(&mut sl.obs),
                ps: std::mem::take(&mut sl.ps),
                map: std::mem::take(&mut sl.map),
                x: sl.x.clone(),
                z: sl.z.clone(),
                h_prev: std::mem::replace(&mut sl.h, rows.h[j * w.hd..(j + 1) * w.hd].to_vec()),
                c_prev: std::mem::replace(&mut sl.c, rows.c[j * w.hd..(j + 1) * w.hd].to_vec()),
                prev_probs: std::mem::replace(&mut sl.prev, probs.to_vec()),
                action: action.index(),
                reward: o.reward,
                probs: p,
                expert: sl.expert.take(),
            };
            sl.seg.push(rec);
        }
        // Segments complete at this tick: bootstrap, then one batched backward.
        let ready: Vec<usize> = active
            .iter()
            .copied()
            .filter(|&i| {
                slots[i]
                    .as_ref()
                    .is_some_and(|s| s.seg.len() == K || s.env.is_done())
            })
            .collect();
        if ready.is_empty() {
            continue;
        }
        let boot = bootstrap(
            &mut slots, &ready, model, ps_buf, grid, &policy, &w, &mut rows,
        )?;
        let mut batch: Vec<(usize, f32)> = ready.iter().copied().zip(boot).collect();
        // Longest segment first (then slot), so the segments running at each backward step
        // are a prefix of the batch.
        batch.sort_by_key(|&(i, _)| {
            (
                std::cmp::Reverse(slots[i].as_ref().map_or(0, |s| s.seg.len())),
                i,
            )
        });
        let segs: Vec<&Slot<'_>> = batch
            .iter()
            .filter_map(|&(i, _)| slots[i].as_ref())
            .collect();
        let boots: Vec<f32> = batch.iter().map(|b| b.1).collect();
        let losses = bw.run(
            &policy,
            &gen,
            &segs,
            &boots,
            s.a3c,
            train_generator,
            &w,
            &d,
            grads,
            &mut gbuf,
        )?;
        for (&(i, _), l) in batch.iter().zip(&losses) {
            let slot = &mut slots[i];
            let sl = slot.as_mut().ok_or_else(|| anyhow!("empty slot"))?;
            sl.stats.loss.add(l);
            sl.seg.clear();
            sl.acts.clear();
            if sl.env.is_done() {
                if let Some(sl) = slot.take() {
                    done.push(finish(sl, disc.clone()));
                }
            }
        }
    }
    done.sort_by_key(|f| f.0);
    Ok(done)
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
        seg: Vec::with_capacity(K),
        acts: Vec::with_capacity(K),
        stats: EpisodeStats::default(),
        obs: Vec::new(),
        ps: Vec::new(),
        map: Vec::new(),
        expert: None,
    })
}

/// The slot's current observation, PS input, map (and the oracle's labels for DAgger).
fn observe(
    sl: &mut Slot<'_>,
    model: &NavModel,
    ps_buf: &mut Option<PsBuffers>,
    grid: MapGrid,
    map_len: usize,
    objective: Objective,
) -> Result<()> {
    let obs = sl.env.observe();
    sl.obs = obs.features.to_vec();
    sl.ps = match (&model.ps, ps_buf) {
        (Some(ps), Some(b)) => {
            ps.forward_buf(&sl.obs, b)?;
            b.y.clone()
        }
        _ => Vec::new(),
    };
    sl.map = vec![0.0; map_len];
    if !grid.is_empty() {
        sl.env.observe_map(grid, &mut sl.map);
    }
    if !all_finite(&sl.obs) || !all_finite(&sl.map) || !all_finite(&sl.ps) {
        bail!("navigator: non-finite input");
    }
    sl.expert = (objective == Objective::Dagger).then(|| expert_distribution(&sl.env));
    Ok(())
}

/// Copies the slot's step inputs (and LSTM state) into row `j`.
fn put_inputs(rows: &mut Rows, j: usize, sl: &Slot<'_>, w: &Widths) {
    let put = |dst: &mut Vec<f32>, k: usize, src: &[f32]| {
        dst[j * k..(j + 1) * k].copy_from_slice(src);
    };
    put(&mut rows.obs, w.f, &sl.obs);
    put(&mut rows.feat, w.f, &sl.x);
    put(&mut rows.attr, w.a, &sl.attr);
    put(&mut rows.prev, NUM_ACTIONS, &sl.prev);
    put(&mut rows.ps, w.ps, &sl.ps);
    put(&mut rows.map, w.map, &sl.map);
    put(&mut rows.h_prev, w.hd, &sl.h);
    put(&mut rows.c_prev, w.hd, &sl.c);
}

/// Row `j`'s activations (the map products are not kept: the backward pass recomputes them).
fn take_act(rows: &Rows, j: usize, w: &Widths) -> StepAct {
    let get = |v: &[f32], k: usize| v[j * k..(j + 1) * k].to_vec();
    StepAct {
        prod: get(&rows.prod, w.f),
        fuse: get(&rows.fuse, w.e),
        gates: get(&rows.gates, 4 * w.hd),
        c: get(&rows.c, w.hd),
        h: get(&rows.h, w.hd),
        actor_u: get(&rows.actor_u, w.au),
        value: rows.value[j],
        cell: get(&rows.cell, w.cells * w.ce),
    }
}

/// The navigator's sampling draw (`Selection::Sample`).
fn select(rng: &mut Xoshiro128, p: &[f32; NUM_ACTIONS]) -> Action {
    let u = uniform(rng);
    let mut acc = 0.0;
    let mut best = NUM_ACTIONS - 1;
    for (i, &pi) in p.iter().enumerate() {
        acc += pi;
        if u < acc {
            best = i;
            break;
        }
    }
    Action::from_index(best).unwrap_or(Action::Done)
}

/// The critic's values of the next observations of the ready slots whose episode goes on
/// (one batched forward), 0 for the ended ones; in `ready`'s order.
#[allow(clippy::too_many_arguments)]
fn bootstrap(
    slots: &mut [Option<Slot<'_>>],
    ready: &[usize],
    model: &NavModel,
    ps_buf: &mut Option<PsBuffers>,
    grid: MapGrid,
    policy: &Policy<'_>,
    w: &Widths,
    rows: &mut Rows,
) -> Result<Vec<f32>> {
    let going: Vec<usize> = ready
        .iter()
        .copied()
        .filter(|&i| slots[i].as_ref().is_some_and(|s| !s.env.is_done()))
        .collect();
    let mut out = vec![0.0f32; ready.len()];
    if going.is_empty() {
        return Ok(out);
    }
    rows.resize(going.len(), w);
    for (j, &i) in going.iter().enumerate() {
        let sl = slots[i].as_mut().ok_or_else(|| anyhow!("empty slot"))?;
        observe(sl, model, ps_buf, grid, w.map, Objective::A3c)?;
        put_inputs(rows, j, sl, w);
        // The inputs are observed again at the next step.
        sl.obs.clear();
    }
    rows.forward(policy, going.len(), w)?;
    for (k, &i) in ready.iter().enumerate() {
        if let Some(j) = going.iter().position(|&g| g == i) {
            out[k] = rows.value[j];
        }
    }
    Ok(out)
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

/// G's buffers (forward for x_t, and the backward of the segment gradient).
struct GenBufs {
    u1: Vec<f32>,
    h1: Vec<f32>,
    u2: Vec<f32>,
    x: Vec<f32>,
    dpre2: Vec<f32>,
    dh1: Vec<f32>,
    dpre1: Vec<f32>,
    tmp: Vec<f32>,
}

impl GenBufs {
    fn new(gen: &Generator<'_>, f: usize) -> GenBufs {
        let gh = gen.hidden();
        GenBufs {
            u1: vec![0.0; if gen.l1.gain.is_some() { gh } else { 0 }],
            h1: vec![0.0; gh],
            u2: vec![0.0; if gen.l2.gain.is_some() { f } else { 0 }],
            x: vec![0.0; f],
            dpre2: vec![0.0; f],
            dh1: vec![0.0; gh],
            dpre1: vec![0.0; gh],
            tmp: vec![0.0; f.max(gh)],
        }
    }

    fn cache(&mut self) -> GeneratorCache<'_> {
        GeneratorCache {
            u1: &mut self.u1,
            h1: &mut self.h1,
            u2: &mut self.u2,
            x: &mut self.x,
        }
    }

    fn generate(
        &mut self,
        gen: &Generator<'_>,
        z: &[f32],
        attr: &[f32],
        x: &mut [f32],
    ) -> Result<()> {
        let mut c = self.cache();
        gen.forward(z, attr, &mut c)?;
        x.copy_from_slice(&self.x);
        Ok(())
    }
}

/// Buffers of the batched backward pass, reused across ticks.
#[derive(Default)]
struct Backward {
    rows: Rows,
    dl: Vec<f32>,
    dv: Vec<f32>,
    dh_next: Vec<f32>,
    dc_next: Vec<f32>,
    dh_prev: Vec<f32>,
    dc_prev: Vec<f32>,
    dfeat: Vec<f32>,
    de: Vec<f32>,
    dgates: Vec<f32>,
    dprod: Vec<f32>,
    tmp: Vec<f32>,
    dh: Vec<f32>,
    dcell: Vec<f32>,
    cell_tmp: Vec<f32>,
}

impl Backward {
    /// Accumulates `∇ L_nav` of the segments `segs` (sorted longest first; bootstraps
    /// `boots`) into `grads`, in the order of the module docs. Returns each segment's loss.
    #[allow(clippy::too_many_arguments)]
    fn run(
        &mut self,
        policy: &Policy<'_>,
        gen: &Generator<'_>,
        segs: &[&Slot<'_>],
        boots: &[f32],
        cfg: &A3cConfig,
        train_generator: bool,
        w: &Widths,
        d: &gman_core::Dims,
        grads: &mut ParamSet,
        gbuf: &mut GenBufs,
    ) -> Result<Vec<SegmentLoss>> {
        let ns = segs.len();
        // Output gradients per segment (the batch-1 code's `output_grads`).
        let mut outs = Vec::with_capacity(ns);
        let mut losses = Vec::with_capacity(ns);
        for (sl, &b) in segs.iter().zip(boots) {
            let values: Vec<f32> = sl.acts.iter().map(|a| a.value).collect();
            let (dl, dv, loss) = output_grads(&sl.seg, &values, b, cfg);
            outs.push((dl, dv));
            losses.push(loss);
        }
        let size = |id: TensorId| {
            let (r, c) = id.shape(d);
            r * c
        };
        let has_map = d.map_cells() > 0;
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
            cell: if has_map {
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
        let sz = |v: &mut Vec<f32>, k: usize| {
            v.clear();
            v.resize(ns * k, 0.0);
        };
        sz(&mut self.dh_next, w.hd);
        sz(&mut self.dc_next, w.hd);
        sz(&mut self.dh_prev, w.hd);
        sz(&mut self.dc_prev, w.hd);
        let max_len = segs.first().map_or(0, |s| s.seg.len());
        for r in 0..max_len {
            let n = segs.iter().take_while(|s| s.seg.len() > r).count();
            let rows = &mut self.rows;
            rows.resize(n, w);
            let szn = |v: &mut Vec<f32>, k: usize| {
                v.clear();
                v.resize(n * k, 0.0);
            };
            szn(&mut self.dl, NUM_ACTIONS);
            szn(&mut self.dv, 1);
            for (j, sl) in segs[..n].iter().enumerate() {
                let t = sl.seg.len() - 1 - r;
                let (st, a) = (&sl.seg[t], &sl.acts[t]);
                let put = |dst: &mut Vec<f32>, k: usize, src: &[f32]| {
                    dst[j * k..(j + 1) * k].copy_from_slice(src);
                };
                put(&mut rows.obs, w.f, &st.obs);
                put(&mut rows.feat, w.f, &st.x);
                put(&mut rows.attr, w.a, &sl.attr);
                put(&mut rows.prev, NUM_ACTIONS, &st.prev_probs);
                put(&mut rows.ps, w.ps, &st.ps);
                put(&mut rows.map, w.map, &st.map);
                put(&mut rows.h_prev, w.hd, &st.h_prev);
                put(&mut rows.c_prev, w.hd, &st.c_prev);
                put(&mut rows.prod, w.f, &a.prod);
                put(&mut rows.fuse, w.e, &a.fuse);
                put(&mut rows.gates, 4 * w.hd, &a.gates);
                put(&mut rows.c, w.hd, &a.c);
                put(&mut rows.h, w.hd, &a.h);
                put(&mut rows.actor_u, w.au, &a.actor_u);
                put(&mut rows.logits, NUM_ACTIONS, &[0.0; NUM_ACTIONS]);
                put(&mut rows.probs, NUM_ACTIONS, &st.probs);
                rows.value[j] = a.value;
                put(&mut rows.cell, w.cells * w.ce, &a.cell);
                put(&mut self.dl, NUM_ACTIONS, &outs[j].0[t]);
                self.dv[j] = outs[j].1[t];
            }
            szn(&mut self.dfeat, w.f);
            szn(&mut self.de, w.e);
            szn(&mut self.dgates, 4 * w.hd);
            szn(&mut self.dprod, w.f);
            szn(&mut self.tmp, w.e.max(NUM_ACTIONS));
            szn(&mut self.dh, w.hd);
            szn(&mut self.dcell, w.cells * w.ce);
            szn(&mut self.cell_tmp, w.map);
            let inp = PolicyInput {
                obs: &rows.obs,
                feat: &rows.feat,
                attr: &rows.attr,
                prev_probs: &rows.prev,
                ps: &rows.ps,
                map: &rows.map,
            };
            let cache = PolicyBatchCache {
                prod: &mut rows.prod,
                fuse: &mut rows.fuse,
                gates: &mut rows.gates,
                c: &mut rows.c,
                h: &mut rows.h,
                actor_u: &mut rows.actor_u,
                logits: &mut rows.logits,
                probs: &mut rows.probs,
                value: &mut rows.value,
                cell: &mut rows.cell,
                cell_prod: &mut rows.cell_prod,
            };
            let nh = n * w.hd;
            let mut out = PolicyInputGrads {
                feat: &mut self.dfeat,
                h_prev: &mut self.dh_prev[..nh],
                c_prev: &mut self.dc_prev[..nh],
            };
            let mut sc = PolicyScratch {
                de: &mut self.de,
                dgates: &mut self.dgates,
                dprod: &mut self.dprod,
                tmp: &mut self.tmp,
                dh: &mut self.dh,
                dcell: &mut self.dcell,
                cell_tmp: &mut self.cell_tmp,
            };
            policy.backward_batch(
                n,
                &inp,
                &rows.h_prev,
                &rows.c_prev,
                &cache,
                &self.dl,
                &self.dv,
                &self.dh_next[..nh],
                &self.dc_next[..nh],
                &mut pg,
                &mut out,
                &mut sc,
            )?;
            std::mem::swap(&mut self.dh_next, &mut self.dh_prev);
            std::mem::swap(&mut self.dc_next, &mut self.dc_prev);
            if train_generator {
                for (j, sl) in segs[..n].iter().enumerate() {
                    let t = sl.seg.len() - 1 - r;
                    let z = &sl.seg[t].z;
                    let gb = &mut *gbuf;
                    let mut gc = GeneratorCache {
                        u1: &mut gb.u1,
                        h1: &mut gb.h1,
                        u2: &mut gb.u2,
                        x: &mut gb.x,
                    };
                    gen.forward(z, &sl.attr, &mut gc)?;
                    let mut gs = GeneratorScratch {
                        dpre2: &mut gb.dpre2,
                        dh1: &mut gb.dh1,
                        dpre1: &mut gb.dpre1,
                        tmp: &mut gb.tmp,
                    };
                    gen.backward(
                        z,
                        &sl.attr,
                        &gc,
                        &self.dfeat[j * w.f..(j + 1) * w.f],
                        &mut g1,
                        &mut g2,
                        &mut gs,
                    )?;
                }
            }
        }
        if has_map {
            for (name, g) in [("CellW", &cellw_g), ("CellB", &cellb_g)] {
                let p = grads
                    .get_mut(name)
                    .ok_or_else(|| anyhow!("gradient set has no {name}"))?;
                for (a, b) in p.data.iter_mut().zip(g) {
                    *a += b;
                }
            }
        }
        Ok(losses)
    }
}
