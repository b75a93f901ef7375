//! The training loop of the navigation methods: A3C baselines and GMAN's meta-adversarial
//! training (Algorithm 1), in one place.
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
//! * **Vectorised episodes** (`--batch-envs B`, methods without an inner loop in training):
//!   each worker steps `B` environments in lockstep with the policy's passes over them as
//!   matrices, see [`super::vec_rollout`]; `B = 1` (the default) is this loop's batch-1
//!   runner, and the vectorised runner with `B = 1` gives the same update bit for bit.
//! * **Baselines** run the same loop with the inner loop off (`a3c`, `a3c-fg`, `gman-nometa`):
//!   plain synchronous advantage actor-critic, with G's θ frozen at its pre-trained value.
//! * **The `gman-noemd` control** runs the loop with the inner loop off but lets Adam train θ
//!   like GMAN does, so comparing it with `gman` isolates what the inner loop (the EMD) adds
//!   and comparing it with `a3c-fg` what training θ adds (README "Results").
//! * **Adaptation mode.** The inner loop runs in the mode the model will run in on the
//!   device ([`NavModel::adapt_mode`](super::model::NavModel::adapt_mode), `--adapt-mode`,
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

use anyhow::{bail, Context, Result};
use gman_core::blob::TensorId;
use indicatif::{ProgressBar, ProgressStyle};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

use super::a3c::SegmentLoss;
use super::rollout::{train_episode, EpisodeStats, Worker};
use super::vec_rollout::{self, VecSettings};
use crate::sim::{EpisodeLimits, World};

use super::run_dir::open_csv;
pub use super::run_dir::{
    checkpoint_path, lock_run_dir, repair_csv, CsvRepair, RunLock, LOCK_FILE,
};
pub use super::state::{RunSettings, TrainState, TrainerMeta, WorldId, TRAINER_META_VERSION};

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

/// Seed of worker `w`'s episode at update `u`.
fn episode_seed(seed: u64, u: u64, w: usize, e: u32) -> u64 {
    let mut x = seed
        ^ 0x9E37_79B9_7F4A_7C15u64.wrapping_mul(u.wrapping_add(1))
        ^ ((w as u64) << 48)
        ^ ((e as u64) << 32);
    x = (x ^ (x >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    x = (x ^ (x >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    x ^ (x >> 31)
}

/// Runs (or continues) training until `opts.updates` updates are done.
pub fn train(world: &World, opts: &TrainOptions, state: &mut TrainState) -> Result<()> {
    let run = &opts.run;
    if run.workers == 0 {
        bail!("--workers must be at least 1");
    }
    if !(1..=2).contains(&run.meta_order) {
        bail!("--meta-order must be 1 or 2");
    }
    if run.batch_envs == 0 || run.batch_envs > vec_rollout::MAX_BATCH_ENVS {
        bail!(
            "--batch-envs must be in 1..={}, got {}",
            vec_rollout::MAX_BATCH_ENVS,
            run.batch_envs
        );
    }
    if run.batch_envs > 1 && !vec_rollout::supports(&state.model) {
        bail!(
            "--batch-envs {} is implemented for the methods without an inner loop in training (a3c, a3c-fg, a3c-ps, a3c-fg-ps, gman-nometa, gman-noemd); {} runs its inner loop per episode: use --batch-envs 1",
            run.batch_envs,
            state.model.method.name()
        );
    }
    if run.meta_order == 2 && state.model.method.uses_cossim() {
        bail!("--meta-order 2 is implemented for the discriminator EMD only; use --meta-order 1 with gman-cossim");
    }
    let _lock = lock_run_dir(&opts.out)?;
    let mut csv = open_csv(&opts.out, state.update)?;
    let ck_path = checkpoint_path(&opts.out);
    let limits = EpisodeLimits::default();
    let mut workers: Vec<(Worker, crate::train::params::ParamSet)> = (0..run.workers)
        .map(|_| (Worker::new(&state.model), state.model.params.zeros_like()))
        .collect();
    let bar = if opts.progress {
        let b = ProgressBar::new(opts.updates);
        b.set_style(
            ProgressStyle::with_template(
                "{spinner} train {prefix} [{elapsed_precise}] {bar:30} {pos}/{len} {msg}",
            )
            .unwrap_or_else(|_| ProgressStyle::default_bar()),
        );
        b.set_prefix(state.model.method.name());
        b.set_position(state.update);
        b
    } else {
        ProgressBar::hidden()
    };
    let disc_ids = TensorId::DISCRIMINATOR;
    let start = Instant::now();
    let steps_at_start = state.env_steps;
    let mut recent: std::collections::VecDeque<(bool, f32)> = Default::default();
    while state.update < opts.updates {
        let u = state.update;
        let model = &state.model;
        type Out = Vec<(EpisodeStats, Vec<Vec<f32>>)>;
        let results: Vec<Result<Out>> = std::thread::scope(|s| {
            let handles: Vec<_> = workers
                .iter_mut()
                .enumerate()
                .map(|(w, (worker, grads))| {
                    s.spawn(move || -> Result<Out> {
                        grads.zero();
                        let sample = |e: u32| -> Result<(crate::sim::EpisodeSpec, u32)> {
                            let mut rng =
                                ChaCha8Rng::seed_from_u64(episode_seed(run.seed, u, w, e));
                            let spec = world
                                .try_sample_train_episode_min(&mut rng, run.min_start_actions)?;
                            let max = run.max_steps.unwrap_or_else(|| limits.for_room(spec.room));
                            Ok((spec, max))
                        };
                        if run.batch_envs > 1 {
                            let settings = VecSettings {
                                batch_envs: run.batch_envs,
                                min_steps: run.min_steps,
                                reward: run.reward,
                                a3c: &run.a3c,
                                objective: run.objective,
                            };
                            let done = vec_rollout::run_worker(
                                world, model, &settings, worker, grads, sample,
                            )?;
                            return Ok(done.into_iter().map(|(_, st, d)| (st, d)).collect());
                        }
                        let mut out = Vec::new();
                        let mut steps = 0u32;
                        let mut e = 0u32;
                        while e == 0 || steps < run.min_steps {
                            let (spec, max) = sample(e)?;
                            let (st, disc) = train_episode(
                                world,
                                &spec,
                                model,
                                run.reward,
                                max,
                                &run.a3c,
                                run.objective,
                                run.meta_order,
                                worker,
                                grads,
                            )?;
                            steps += st.steps;
                            e += 1;
                            out.push((st, disc));
                        }
                        Ok(out)
                    })
                })
                .collect();
            handles
                .into_iter()
                .map(|h| {
                    h.join()
                        .unwrap_or_else(|_| Err(anyhow::anyhow!("worker panicked")))
                })
                .collect()
        });
        let mut total = state.model.params.zeros_like();
        let mut loss = SegmentLoss::default();
        let (mut succ, mut rew, mut steps, mut adapt, mut roll) = (0u32, 0.0f64, 0u64, 0u32, 0u32);
        let (mut gap, mut lad, mut ngap) = (0.0f64, 0.0f64, 0u32);
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
        let mut n_ep = 0u64;
        for (r, (_, grads)) in results.into_iter().zip(&workers) {
            total.add_assign(grads)?;
            for (st, disc) in r? {
                n_ep += 1;
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
                recent.push_back((st.success, st.total_reward));
                for ((acc, id), new) in disc_delta.iter_mut().zip(disc_ids).zip(&disc) {
                    let old = &state.model.params.tensor(id.name())?.data;
                    for ((a, n), o) in acc.iter_mut().zip(new).zip(old) {
                        *a += n - o;
                    }
                }
            }
        }
        while recent.len() > 100 {
            recent.pop_front();
        }
        total.scale(1.0 / run.workers as f32);
        if !total.all_finite() {
            bail!("non-finite gradient at update {u}");
        }
        let info = state.adam.step(&mut state.model.params, &total)?;
        for (id, delta) in disc_ids.iter().zip(&disc_delta) {
            let p = state.model.params.get_mut(id.name()).context("D tensor")?;
            for (v, d) in p.data.iter_mut().zip(delta) {
                *v += d;
            }
        }
        state.update += 1;
        state.episodes += n_ep;
        state.env_steps += steps;
        let n = n_ep as f64;
        let elapsed = start.elapsed().as_secs_f64();
        let nan_or = |v: f64, c: u32| if c > 0 { v / c as f64 } else { f64::NAN };
        writeln!(
            csv,
            "{},{},{},{:.4},{:.4},{:.2},{:.5},{:.5},{:.5},{:.5},{},{},{:.5},{:.5},{:.2}",
            state.update,
            state.episodes,
            state.env_steps,
            succ as f64 / n,
            rew / n,
            steps as f64 / n,
            loss.policy / loss.steps.max(1) as f64,
            loss.value / loss.steps.max(1) as f64,
            loss.entropy / loss.steps.max(1) as f64,
            info.grad_norm,
            adapt,
            roll,
            nan_or(gap, ngap),
            nan_or(lad, ngap),
            elapsed
        )?;
        let sr = recent.iter().filter(|r| r.0).count() as f64 / recent.len().max(1) as f64;
        let mr = recent.iter().map(|r| r.1 as f64).sum::<f64>() / recent.len().max(1) as f64;
        bar.set_position(state.update);
        bar.set_message(format!(
            "SR(100) {:.1}% R {:.2} {:.0} steps/s",
            100.0 * sr,
            mr,
            (state.env_steps - steps_at_start) as f64 / elapsed.max(1e-9)
        ));
        if state.update.is_multiple_of(opts.checkpoint_every) || state.update == opts.updates {
            csv.flush()?;
            state.save(&ck_path, run)?;
        }
    }
    bar.finish_and_clear();
    Ok(())
}
