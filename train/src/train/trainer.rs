//! The training loop of the navigation methods: A3C baselines and GMAN's meta-adversarial
//! training (Algorithm 1), in one place, readable top to bottom:
//!
//! 1. [`train`] — the outer loop (lines 1-3, 21-22): the workers' updates in parallel, then
//!    `outer_step`: Adam on the summed ∇L_nav (Eq. 4), ω carried across episodes;
//! 2. `worker_update` — a worker's tasks τ_i, seeded by `(seed, update, worker, episode)`;
//! 3. the worker's episodes (lines 4-20), `B` in lockstep in the rollout engine
//!    ([`super::engine::run_worker`]; `B = 1`, the baselines and `--meta-order 2` are its
//!    cases): each segment's ∇L_nav (the loss in [`super::a3c`], one batched BPTT in
//!    [`super::bptt`]) and the inner update (lines 14-20: Eq. 1 ascent, Eq. 3 descent, in
//!    gman-core);
//! 4. `Log` — one `metrics.csv` row per update.
//!
//! [`train_episode`] runs one task through the same engine (one slot, one episode). The
//! checkpoint ([`super::state`]) and the run directory ([`super::run_dir`]) live beside.
//!
//! ```text
//! for update u = 1, 2, ...                                   (Algorithm 1, line 1)
//!   W workers in parallel, each a few tasks τ ~ p(T):         (lines 2-3)
//!     a training episode sampled from the training scenes, seeded by (seed, u, w)
//!     run with gman-core's navigator from θ, φ, ω               (line 4)
//!     every k = 20 steps: ∇L_nav of the segment at (θ_i, φ_i)  (A3C, Sec. 3.2)
//!                         then the inner update: D ascent, θ_i, φ_i descent (lines 15-20)
//!   θ, φ ← Adam(θ, φ, Σ_w ∇L_nav)                              (lines 21-22, first order)
//!   ω ← ω + Σ_w (ω_w − ω)                                      (D learns across episodes)
//! ```
//!
//! * **Meta-gradient order 1** (first-order MAML, `--meta-order 1`, the default): the
//!   gradient of L_nav with respect to the adapted parameters is applied to the
//!   pre-adaptation ones.
//! * **Meta-gradient order 2** (`--meta-order 2`): the exact gradient through the inner SGD
//!   steps of θ and φ (Hessian-vector products by finite differences of gradients), see
//!   [`super::meta`]; the buffers, rollouts and D are treated as data.
//! * **Workers** are synchronous: each worker (one per core) runs whole episodes until it has
//!   taken at least `min_steps` steps, their gradients are summed in worker order, then one
//!   Adam step. Every random choice of an update derives from
//!   `(seed, update, worker)`, so a run is reproducible bit for bit for a given worker count
//!   and a resumed run continues exactly where the checkpoint left off.
//! * **Vectorised episodes** (`--batch-envs B`, default 16 in `gman train`): each worker
//!   steps `B` environments in lockstep with the policy's passes over them as matrices, see
//!   [`super::engine`] (for the methods with an inner loop one navigator per episode, each
//!   with its own inner loop; `B > 1` with the first-order meta-gradient only). With `B = 1`
//!   an update is its episodes run one at a time by [`train_episode`], bit for bit.
//! * **Baselines** run the same loop with the inner loop off (`a3c`, `a3c-fg`, `gman-nometa`):
//!   plain synchronous advantage actor-critic, with G's θ frozen at its pre-trained value.
//! * **The `gman-noemd` control** runs the loop with the inner loop off but lets Adam train θ
//!   like GMAN does, so comparing it with `gman` isolates what the inner loop (the EMD) adds
//!   and comparing it with `a3c-fg` what training θ adds (README "Results").
//! * **Adaptation mode.** The inner loop runs in the mode the model will run in on the
//!   device (`NavModel::spec.adapt_mode`, `--adapt-mode`,
//!   Efficient by default for `mcu`): in `Efficient` the segment gradients of θ and of the
//!   actor head are taken through the adapted per-unit gains, exactly the parameters the
//!   robot adapts. The exported blob records the mode.
//! * **Objectives** ([`Objective`]): the A3C loss, or DAgger imitation of the shortest-path
//!   oracle (`--objective dagger`, a ceiling diagnostic: the learner acts, the oracle labels).
//!   `--privileged-feature` replaces x_t by the target's true feature in the scene (the
//!   privileged-feature bound). `--map RxC` gives the policy a spatial observation map.
//! * **Resuming** (`gman train --resume`) restores the model, Adam's state, the counters and
//!   the trainer settings stored in the checkpoint, so a resumed run ends bit for bit where
//!   an uninterrupted one does.

use std::io::Write;
use std::path::PathBuf;
use std::time::Instant;

use anyhow::{anyhow, bail, Context, Result};
use gman_core::blob::TensorId;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

use super::a3c::{A3cConfig, Objective, SegmentLoss};
use super::dist::{
    decode_shares, encode_shares, fnv1a, params_hash, CommStats, Group, Single, WorkerShare,
};
use super::engine;
use super::lockstep::{check_batch_envs, VecSettings};
use super::rollout::{EpisodeStats, Worker};
use super::run_dir::{checkpoint_path, lock_run_dir, open_csv};
use super::state::{RunSettings, TrainState};
use crate::model::NavModel;
use crate::optim::params::ParamSet;
use crate::progress::{BarKind, NoProgress, Progress};
use crate::sim::{EpisodeLimits, EpisodeSpec, RewardKind, World};

/// Options of one training invocation: the run's stored settings and what only this
/// invocation decides.
#[derive(Clone, Debug)]
pub struct TrainOptions {
    /// Updates to reach (counting those of a resumed run).
    pub updates: u64,
    /// The settings that shape the updates (stored in the checkpoint).
    pub run: RunSettings,
    /// Write a checkpoint every this many updates (and at the end).
    pub checkpoint_every: u64,
    /// Run directory (`metrics.csv`, `checkpoint.ckpt`).
    pub out: PathBuf,
    /// Show a progress bar.
    pub progress: bool,
}

/// A worker's share of an update: its episodes' statistics and D after each.
type WorkerOut = Vec<(EpisodeStats, Vec<Vec<f32>>)>;

// ---------------------------------------------------------------------------------------
// The outer loop (Algorithm 1, lines 1-3 and 21-22)
// ---------------------------------------------------------------------------------------

/// Runs (or continues) training until `opts.updates` updates are done.
pub fn train(world: &World, opts: &TrainOptions, state: &mut TrainState) -> Result<()> {
    let mut one = Single;
    let mut dist = Distributed {
        group: &mut one,
        check_every: 0,
    };
    train_in(world, opts, state, &mut dist).map(|_| ())
}

/// How a run is spread over processes (see [`super::dist`]).
pub struct Distributed<'g> {
    /// The ranks; `opts.run.workers` counts the workers of all of them.
    pub group: &'g mut dyn Group,
    /// Every this many updates (and at the last) the ranks compare a hash of their
    /// parameters and Adam state, and stop with an error if they differ (0: never).
    pub check_every: u64,
}

/// [`train`] over the ranks of `dist`: rank `r` of `N` runs the global workers
/// `r·W .. r·W + W` (`W = opts.run.workers / N`), the ranks exchange their workers'
/// gradients and episodes, and every rank runs the same outer step on all of them, in global
/// worker order, so the run has the bits of one process with `opts.run.workers` workers.
/// Rank 0 alone locks the run directory and writes `metrics.csv` and the checkpoints.
/// Returns what the exchanges cost.
pub fn train_in(
    world: &World,
    opts: &TrainOptions,
    state: &mut TrainState,
    dist: &mut Distributed<'_>,
) -> Result<CommStats> {
    check_options(&opts.run, &state.model)?;
    let (rank, ranks) = (dist.group.rank(), dist.group.size());
    if ranks == 0 || !opts.run.workers.is_multiple_of(ranks) {
        bail!(
            "the run has {} workers, which {ranks} ranks cannot share equally; use a rank count that divides it",
            opts.run.workers
        );
    }
    let local = opts.run.workers / ranks;
    let lead = rank == 0;
    let _lock = if lead {
        Some(lock_run_dir(&opts.out)?)
    } else {
        None
    };
    let mut csv = if lead {
        Some(open_csv(&opts.out, state.update)?)
    } else {
        None
    };
    let ck_path = checkpoint_path(&opts.out);
    let bar = if lead {
        progress_bar(opts, state)
    } else {
        Box::new(NoProgress)
    };
    let mut workers: Vec<(Worker, ParamSet)> = (0..local)
        .map(|_| (Worker::new(&state.model), state.model.params.zeros_like()))
        .collect();
    let mut log = Log::new(state.env_steps);
    let mut comm = CommStats::default();
    let fault = test_fault();
    if ranks > 1 && dist.check_every > 0 {
        check_ranks_agree(dist.group, state)?;
    }
    // Line 1: while not converged.
    while state.update < opts.updates {
        let t_update = Instant::now();
        // Lines 2-20: every worker samples its tasks τ_i ~ p(T) and runs them from θ, φ, ω
        // (each with its own θ_i, φ_i and inner loop), accumulating ∇L_nav into its grads.
        let per_worker = run_workers(world, state, &opts.run, rank * local, &mut workers)?;
        // Lines 21-22 (Eq. 4): θ, φ ← Adam(Σ_τ ∇L_nav(ω, θ_i, φ_i)); ω keeps what the
        // episodes' inner loops taught D.
        let (grad_norm, episodes) = if ranks == 1 {
            let episodes: Vec<_> = per_worker.into_iter().flatten().collect();
            let grads: Vec<&ParamSet> = workers.iter().map(|(_, g)| g).collect();
            (outer_step(state, &grads, &episodes)?, episodes)
        } else {
            let shares = exchange(dist.group, &workers, &per_worker, state, &mut comm)?;
            let grads: Vec<&ParamSet> = shares.iter().map(|(g, _)| g).collect();
            let episodes: Vec<_> = shares.iter().flat_map(|(_, e)| e.iter().cloned()).collect();
            (outer_step(state, &grads, &episodes)?, episodes)
        };
        state.count_update(
            episodes.len() as u64,
            episodes.iter().map(|(st, _)| st.steps as u64).sum::<u64>(),
        )?;
        fault.apply(rank, state);
        if ranks > 1
            && dist.check_every > 0
            && (state.update.is_multiple_of(dist.check_every) || state.update == opts.updates)
        {
            check_ranks_agree(dist.group, state)?;
        }
        if let Some(csv) = csv.as_mut() {
            log.row(csv, state, &episodes, grad_norm, bar.as_ref())?;
            if state.update.is_multiple_of(opts.checkpoint_every) || state.update == opts.updates {
                csv.flush()?;
                state.save(&ck_path, &opts.run)?;
            }
        }
        comm.update_secs += t_update.elapsed().as_secs_f64();
    }
    bar.finish();
    Ok(comm)
}

/// This rank's workers' shares of the update `state.update`, one thread each: worker `w`
/// of `workers` is the global worker `first + w`.
fn run_workers(
    world: &World,
    state: &TrainState,
    run: &RunSettings,
    first: usize,
    workers: &mut [(Worker, ParamSet)],
) -> Result<Vec<WorkerOut>> {
    let (u, model) = (state.update, &state.model);
    let results: Vec<Result<WorkerOut>> = std::thread::scope(|s| {
        let handles: Vec<_> = workers
            .iter_mut()
            .enumerate()
            .map(|(w, (worker, grads))| {
                s.spawn(move || worker_update(world, model, run, u, first + w, worker, grads))
            })
            .collect();
        handles
            .into_iter()
            .map(|h| h.join().unwrap_or_else(|_| Err(anyhow!("worker panicked"))))
            .collect()
    });
    results.into_iter().collect()
}

/// Every rank's workers' gradients and episodes, in global worker order, on every rank.
fn exchange(
    group: &mut dyn Group,
    workers: &[(Worker, ParamSet)],
    per_worker: &[WorkerOut],
    state: &TrainState,
    comm: &mut CommStats,
) -> Result<Vec<WorkerShare>> {
    let t0 = Instant::now();
    let mine: Vec<_> = workers
        .iter()
        .zip(per_worker)
        .map(|((_, g), e)| (g, &e[..]))
        .collect();
    let omega: Vec<&[f32]> = TensorId::DISCRIMINATOR
        .iter()
        .map(|id| {
            state
                .model
                .params
                .get(id.name())
                .map_or(&[][..], |p| &p.data[..])
        })
        .collect();
    let bytes = encode_shares(&mine, &omega);
    let t1 = Instant::now();
    group.barrier();
    let t2 = Instant::now();
    let all = group.all_gather(&bytes)?;
    let t3 = Instant::now();
    let mut shares = Vec::new();
    for (r, b) in all.iter().enumerate() {
        shares.extend(decode_shares(b, &state.model.params, &omega, r)?);
    }
    let t4 = Instant::now();
    comm.updates += 1;
    comm.bytes_sent += bytes.len() as u64;
    comm.bytes_received += all.iter().map(|b| b.len() as u64).sum::<u64>() - bytes.len() as u64;
    comm.codec_secs += (t1 - t0).as_secs_f64() + (t4 - t3).as_secs_f64();
    comm.wait_secs += (t2 - t1).as_secs_f64();
    comm.transfer_secs += (t3 - t2).as_secs_f64();
    Ok(shares)
}

/// Stops the run if the ranks hold different parameters or Adam states.
fn check_ranks_agree(group: &mut dyn Group, state: &TrainState) -> Result<()> {
    let mut b = params_hash(&state.model.params).to_le_bytes().to_vec();
    b.extend_from_slice(&fnv1a(&state.adam.to_bytes()).to_le_bytes());
    let all = group.all_gather(&b)?;
    if all.iter().any(|h| h != &all[0]) {
        let list: Vec<String> = all
            .iter()
            .enumerate()
            .map(|(r, h)| {
                format!(
                    "rank {r}: {}",
                    h.iter().map(|x| format!("{x:02x}")).collect::<String>()
                )
            })
            .collect();
        bail!(
            "the ranks diverged at update {}: their parameter/Adam hashes differ ({}); the last checkpoint is intact, resume from it",
            state.update,
            list.join(", ")
        );
    }
    Ok(())
}

/// A fault injected by the environment variable `GMAN_DIST_FAULT=KIND:RANK:UPDATE` (test
/// hook of the distributed checks): after update `UPDATE`, rank `RANK` either perturbs one
/// parameter (`perturb`) or exits at once with code 3 without a word to the others (`exit`).
#[derive(Clone, Copy, Debug, Default)]
struct TestFault {
    kind: u8,
    rank: usize,
    update: u64,
}

fn test_fault() -> TestFault {
    let Ok(v) = std::env::var("GMAN_DIST_FAULT") else {
        return TestFault::default();
    };
    let parts: Vec<&str> = v.split(':').collect();
    match (parts.first(), parts.get(1), parts.get(2)) {
        (Some(k), Some(r), Some(u)) => TestFault {
            kind: match *k {
                "perturb" => 1,
                "exit" => 2,
                _ => 0,
            },
            rank: r.parse().unwrap_or(usize::MAX),
            update: u.parse().unwrap_or(u64::MAX),
        },
        _ => TestFault::default(),
    }
}

impl TestFault {
    fn apply(self, rank: usize, state: &mut TrainState) {
        if self.kind == 0 || rank != self.rank || state.update != self.update {
            return;
        }
        if self.kind == 2 {
            std::process::exit(3);
        }
        if let Some(v) = state
            .model
            .params
            .tensors
            .iter_mut()
            .find_map(|t| t.data.first_mut())
        {
            *v = f32::from_bits(v.to_bits() ^ 1);
        }
    }
}

/// The settings [`train`] cannot run.
fn check_options(run: &RunSettings, model: &NavModel) -> Result<()> {
    if run.workers == 0 {
        bail!("--workers must be at least 1");
    }
    if !(1..=2).contains(&run.meta_order) {
        bail!("--meta-order must be 1 or 2");
    }
    check_batch_envs(model, run.batch_envs, run.meta_order)?;
    if run.meta_order == 2 && model.method.uses_cossim() {
        bail!("--meta-order 2 is implemented for the discriminator EMD only; use --meta-order 1 with gman-cossim");
    }
    Ok(())
}

/// Worker `w`'s share of update `u` (Algorithm 1, lines 2-3): whole episodes (tasks)
/// `e = 0, 1, ..`, each sampled from the training scenes with the seed `(seed, u, w, e)`,
/// until the worker has taken at least `min_steps` steps; their ∇L_nav summed into `grads`
/// (zeroed first), `B` episodes in lockstep (see [`super::engine`]).
fn worker_update(
    world: &World,
    model: &NavModel,
    run: &RunSettings,
    u: u64,
    w: usize,
    worker: &mut Worker,
    grads: &mut ParamSet,
) -> Result<WorkerOut> {
    grads.zero();
    let limits = EpisodeLimits::default();
    let sample = |e: u32| -> Result<(EpisodeSpec, u32)> {
        let mut rng = ChaCha8Rng::seed_from_u64(episode_seed(run.seed, u, w, e));
        let spec = world.try_sample_train_episode_min(&mut rng, run.min_start_actions)?;
        let max = run.max_steps.unwrap_or_else(|| limits.for_room(spec.room));
        Ok((spec, max))
    };
    let settings = VecSettings {
        batch_envs: run.batch_envs,
        min_steps: run.min_steps,
        reward: run.reward,
        a3c: &run.a3c,
        objective: run.objective,
        meta_order: run.meta_order,
    };
    let done = engine::run_worker(world, model, &settings, worker, grads, sample)?;
    Ok(done.into_iter().map(|(_, st, d)| (st, d)).collect())
}

/// The outer step (Algorithm 1, lines 21-22): the workers' gradients summed in worker order
/// and averaged over the workers, one Adam step on θ, φ (and the rest of the policy); D's ω
/// moves by the sum of what each episode's inner loop changed (`ω_e − ω`), in episode order
/// (not with D's head reset, where D restarts from ω with every episode). Returns the
/// gradient norm.
fn outer_step(
    state: &mut TrainState,
    worker_grads: &[&ParamSet],
    episodes: &[(EpisodeStats, Vec<Vec<f32>>)],
) -> Result<f64> {
    let mut total = state.model.params.zeros_like();
    for g in worker_grads {
        total.add_assign(g)?;
    }
    total.scale(1.0 / worker_grads.len() as f32);
    if !total.all_finite() {
        bail!("non-finite gradient at update {}", state.update);
    }
    // With D's head reset, D restarts from ω with every episode (on the device too), so ω
    // does not learn across episodes: carrying the episodes' layer-1 changes over lets the
    // gradient penalty grow layer 1 without bound (it diverged after ~6500 updates).
    let disc_delta = if state.model.spec.inner_rule.disc_head_reset {
        None
    } else {
        Some(disc_deltas(state, episodes)?)
    };
    let info = state.adam.step(&mut state.model.params, &total)?;
    for (id, delta) in TensorId::DISCRIMINATOR
        .iter()
        .zip(disc_delta.iter().flatten())
    {
        let p = state.model.params.get_mut(id.name()).context("D tensor")?;
        for (v, d) in p.data.iter_mut().zip(delta) {
            *v += d;
        }
    }
    Ok(info.grad_norm)
}

/// `Σ_e (ω_e − ω)` per D tensor, in episode order: what the episodes' inner loops changed in
/// D, from the model's ω.
fn disc_deltas(
    state: &TrainState,
    episodes: &[(EpisodeStats, Vec<Vec<f32>>)],
) -> Result<Vec<Vec<f32>>> {
    let disc_ids = TensorId::DISCRIMINATOR;
    let mut disc_delta: Vec<Vec<f32>> = disc_ids
        .iter()
        .map(|id| {
            vec![
                0.0;
                state
                    .model
                    .params
                    .get(id.name())
                    .map_or(0, |p| p.data.len())
            ]
        })
        .collect();
    for (_, disc) in episodes {
        for ((acc, id), new) in disc_delta.iter_mut().zip(disc_ids).zip(disc) {
            let old = &state.model.params.tensor(id.name())?.data;
            for ((a, n), o) in acc.iter_mut().zip(new).zip(old) {
                *a += n - o;
            }
        }
    }
    Ok(disc_delta)
}

/// Seed of worker `w`'s episode `e` at update `u`.
fn episode_seed(seed: u64, u: u64, w: usize, e: u32) -> u64 {
    let mut x = seed
        ^ 0x9E37_79B9_7F4A_7C15u64.wrapping_mul(u.wrapping_add(1))
        ^ ((w as u64) << 48)
        ^ ((e as u64) << 32);
    x = (x ^ (x >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    x = (x ^ (x >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    x ^ (x >> 31)
}

// ---------------------------------------------------------------------------------------
// One task τ_i (Algorithm 1, lines 4-20)
// ---------------------------------------------------------------------------------------

/// Runs one training episode: the rollout engine ([`super::engine`]) with one slot and one
/// episode. Every `K` steps (or at the end) the segment's A3C gradient is accumulated into
/// `grads` at the parameters the segment ran with, then, for the methods that adapt, the
/// navigator's inner update (Algorithm 1, lines 15-20) runs. Returns the episode's
/// statistics and D's parameters after the episode (in the order `DiscW1`, `DiscB1`,
/// `DiscW2`, `DiscB2`; empty when they are the model's ω), since ω learns across episodes.
///
/// `meta_order` 1 sums the segments' gradients at the adapted parameters (first-order MAML);
/// 2 (for the methods that adapt) back-propagates the θ and φ parts through the inner SGD
/// steps instead (see [`super::meta`]); the fusion, LSTM and critic gradients are the same
/// sum in both.
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
    let settings = VecSettings {
        batch_envs: 1,
        min_steps: 0,
        reward,
        a3c,
        objective,
        meta_order,
    };
    let mut done = engine::run_worker(world, model, &settings, worker, grads, |_| {
        Ok((spec.clone(), max_steps))
    })?;
    match (done.pop(), done.is_empty()) {
        (Some((_, stats, disc)), true) if disc.is_empty() => {
            // D after the episode is the model's ω (see `Finished`): a copy of it.
            let omega = TensorId::DISCRIMINATOR
                .iter()
                .map(|id| Ok(model.params.tensor(id.name())?.data.clone()))
                .collect::<Result<_>>()?;
            Ok((stats, omega))
        }
        (Some((_, stats, disc)), true) => Ok((stats, disc)),
        _ => bail!("one training episode ran as {} episodes", done.len() + 1),
    }
}

// ---------------------------------------------------------------------------------------
// Progress: metrics.csv and the progress bar
// ---------------------------------------------------------------------------------------

fn progress_bar(opts: &TrainOptions, state: &TrainState) -> Box<dyn Progress> {
    let method = state.model.method.name();
    let b = crate::progress::bar(BarKind::Train { method }, opts.updates, opts.progress);
    b.set_position(state.update);
    b
}

/// The learning curve: one `metrics.csv` row per update, the last 100 episodes on the bar.
struct Log {
    start: Instant,
    steps_at_start: u64,
    recent: std::collections::VecDeque<(bool, f32)>,
}

impl Log {
    fn new(steps_at_start: u64) -> Log {
        Log {
            start: Instant::now(),
            steps_at_start,
            recent: Default::default(),
        }
    }

    /// The row of the update just done (`state` counts it), and the bar's message.
    fn row(
        &mut self,
        csv: &mut impl Write,
        state: &TrainState,
        episodes: &[(EpisodeStats, Vec<Vec<f32>>)],
        grad_norm: f64,
        bar: &dyn Progress,
    ) -> Result<()> {
        let mut loss = SegmentLoss::default();
        let (mut succ, mut rew, mut steps, mut adapt, mut roll) = (0u32, 0.0f64, 0u64, 0u32, 0u32);
        let (mut gap, mut lad, mut ngap) = (0.0f64, 0.0f64, 0u32);
        for (st, _) in episodes {
            loss.add(&st.loss);
            succ += st.success as u32;
            rew += st.total_reward as f64;
            steps += st.steps as u64;
            adapt += st.adaptations;
            roll += st.rollbacks;
            if st.disc_gap.is_finite() {
                gap += st.disc_gap as f64;
                lad += st.adapt_loss as f64;
                ngap += 1;
            }
            self.recent.push_back((st.success, st.total_reward));
        }
        while self.recent.len() > 100 {
            self.recent.pop_front();
        }
        let n = episodes.len() as f64;
        let elapsed = self.start.elapsed().as_secs_f64();
        let nan_or = |v: f64, c: u32| if c > 0 { v / c as f64 } else { f64::NAN };
        let per_step = |v: f64| v / loss.steps.max(1) as f64;
        writeln!(
            csv,
            "{},{},{},{:.4},{:.4},{:.2},{:.5},{:.5},{:.5},{:.5},{},{},{:.5},{:.5},{:.2}",
            state.update,
            state.episodes,
            state.env_steps,
            succ as f64 / n,
            rew / n,
            steps as f64 / n,
            per_step(loss.policy),
            per_step(loss.value),
            per_step(loss.entropy),
            grad_norm,
            adapt,
            roll,
            nan_or(gap, ngap),
            nan_or(lad, ngap),
            elapsed
        )?;
        let r = &self.recent;
        let sr = r.iter().filter(|x| x.0).count() as f64 / r.len().max(1) as f64;
        let mr = r.iter().map(|x| x.1 as f64).sum::<f64>() / r.len().max(1) as f64;
        bar.set_position(state.update);
        bar.set_message(format!(
            "SR(100) {:.1}% R {:.2} {:.0} steps/s",
            100.0 * sr,
            mr,
            (state.env_steps - self.steps_at_start) as f64 / elapsed.max(1e-9)
        ));
        Ok(())
    }
}
