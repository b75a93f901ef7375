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
//! * **Baselines** run the same loop with the inner loop off (`a3c`, `a3c-fg`, `gman-nometa`):
//!   plain synchronous advantage actor-critic, with G's θ frozen at its pre-trained value.
//! * **The `gman-noemd` control** runs the loop with the inner loop off but lets Adam train θ
//!   like GMAN does, so comparing it with `gman` isolates what the inner loop (the EMD) adds
//!   and comparing it with `a3c-fg` what training θ adds (README "Results").
//! * **Resuming** (`gman train --resume`) restores the model, Adam's state, the counters and
//!   the trainer settings stored in the checkpoint, so a resumed run ends bit for bit where
//!   an uninterrupted one does.

use std::fs::{File, OpenOptions};
use std::io::{BufRead, BufReader, Write};
use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{bail, Context, Result};
use gman_core::blob::TensorId;
use indicatif::{ProgressBar, ProgressStyle};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

use super::a3c::{A3cConfig, Objective, SegmentLoss};
use super::model::NavModel;
use super::rollout::{train_episode, EpisodeStats, Worker};
use crate::sim::{EpisodeLimits, RewardKind, World};
use crate::train::adam::{Adam, AdamConfig};
use crate::train::checkpoint::Checkpoint;

/// Settings of a training run.
#[derive(Clone, Debug)]
pub struct TrainOptions {
    /// Updates to reach (counting those of a resumed run).
    pub updates: u64,
    /// Seed of the run.
    pub seed: u64,
    /// Parallel workers.
    pub workers: usize,
    /// Each worker runs whole episodes (tasks) until it has taken at least this many steps
    /// in the update (at least one episode).
    pub min_steps: u32,
    /// Reward.
    pub reward: RewardKind,
    /// Step limit of training episodes (`None`: the evaluation limits, 200/100).
    pub max_steps: Option<u32>,
    /// Training starts need at least this many actions to see the target (1: never in view at
    /// the start).
    pub min_start_actions: u32,
    /// Outer optimiser.
    pub adam: AdamConfig,
    /// A3C loss.
    pub a3c: A3cConfig,
    /// What the policy learns from: the A3C loss or imitation of the oracle (DAgger).
    pub objective: Objective,
    /// Meta-gradient order: 1 (first-order MAML, the gradient at the adapted parameters
    /// applied to the pre-adaptation ones) or 2 (exact through the inner SGD steps, see
    /// [`super::meta`]).
    pub meta_order: u8,
    /// Write a checkpoint every this many updates (and at the end).
    pub checkpoint_every: u64,
    /// Run directory (`metrics.csv`, `checkpoint.ckpt`).
    pub out: PathBuf,
    /// Show a progress bar.
    pub progress: bool,
}

/// Everything a checkpoint restores.
pub struct TrainState {
    /// The model (θ, ω, φ and the PS module).
    pub model: NavModel,
    /// Adam over the model's parameters.
    pub adam: Adam,
    /// Updates done.
    pub update: u64,
    /// Episodes run.
    pub episodes: u64,
    /// Environment steps taken.
    pub env_steps: u64,
}

const CSV_HEADER: &str = "update,episodes,env_steps,success_rate,mean_reward,mean_steps,policy_loss,value_loss,entropy,grad_norm,adaptations,rollbacks,disc_gap,adapt_loss,elapsed_s";

/// Path of the run's checkpoint.
pub fn checkpoint_path(out: &Path) -> PathBuf {
    out.join("checkpoint.ckpt")
}

impl TrainState {
    /// A fresh state.
    pub fn new(model: NavModel, adam: AdamConfig) -> TrainState {
        let adam = Adam::new(adam, &model.params);
        TrainState {
            model,
            adam,
            update: 0,
            episodes: 0,
            env_steps: 0,
        }
    }

    /// Writes the checkpoint atomically.
    pub fn save(&self, path: &Path, opts: &TrainOptions) -> Result<()> {
        let mut meta = self.model.metadata();
        meta["trainer"] = serde_json::json!({
            "update": self.update,
            "episodes": self.episodes,
            "env_steps": self.env_steps,
            "seed": opts.seed,
            "workers": opts.workers,
            "min_steps": opts.min_steps,
            "reward": format!("{:?}", opts.reward),
            "max_steps": opts.max_steps,
            "min_start_actions": opts.min_start_actions,
            "adam": opts.adam,
            "a3c": opts.a3c,
            "meta_order": opts.meta_order,
            "objective": opts.objective.name(),
        });
        let mut ck = Checkpoint::new(meta);
        self.model.add_to_checkpoint(&mut ck)?;
        ck.add_blob("adam", self.adam.to_bytes());
        ck.save(path)?;
        Ok(())
    }

    /// Restores a state saved by [`TrainState::save`].
    pub fn load(path: &Path) -> Result<TrainState> {
        Ok(Self::load_with_options(path)?.0)
    }

    /// Restores a state like [`TrainState::load`] and also returns the trainer options the
    /// run was last saved with (the `trainer` object of the checkpoint's metadata: seed,
    /// workers, reward, Adam and A3C settings, meta-gradient order, ...), so that a resumed
    /// run can continue with exactly the settings it was trained with.
    pub fn load_with_options(path: &Path) -> Result<(TrainState, serde_json::Value)> {
        let ck = Checkpoint::load(path)?;
        let model = NavModel::from_checkpoint(&ck)?;
        let adam = Adam::from_bytes(ck.blob("adam")?, &model.params)?;
        let t = &ck.metadata["trainer"];
        let get = |k: &str| {
            t.get(k)
                .and_then(|v| v.as_u64())
                .with_context(|| format!("checkpoint trainer.{k} missing"))
        };
        let state = TrainState {
            model,
            adam,
            update: get("update")?,
            episodes: get("episodes")?,
            env_steps: get("env_steps")?,
        };
        Ok((state, t.clone()))
    }
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

/// Opens `metrics.csv` for appending, keeping only rows up to `update` (so a resumed run
/// continues the file where its checkpoint was written).
fn open_csv(out: &Path, update: u64) -> Result<File> {
    let path = out.join("metrics.csv");
    let mut keep = vec![CSV_HEADER.to_string()];
    if update > 0 && path.exists() {
        let f = File::open(&path).with_context(|| format!("reading {}", path.display()))?;
        for line in BufReader::new(f).lines().skip(1) {
            let line = line?;
            match line.split(',').next().and_then(|v| v.parse::<u64>().ok()) {
                Some(u) if u <= update => keep.push(line),
                _ => {}
            }
        }
    }
    let mut f = File::create(&path).with_context(|| format!("writing {}", path.display()))?;
    for l in keep {
        writeln!(f, "{l}")?;
    }
    drop(f);
    Ok(OpenOptions::new().append(true).open(&path)?)
}

/// Runs (or continues) training until `opts.updates` updates are done.
pub fn train(world: &World, opts: &TrainOptions, state: &mut TrainState) -> Result<()> {
    if opts.workers == 0 {
        bail!("--workers must be at least 1");
    }
    if !(1..=2).contains(&opts.meta_order) {
        bail!("--meta-order must be 1 or 2");
    }
    if opts.meta_order == 2 && state.model.method.uses_cossim() {
        bail!("--meta-order 2 is implemented for the discriminator EMD only; use --meta-order 1 with gman-cossim");
    }
    std::fs::create_dir_all(&opts.out)
        .with_context(|| format!("creating {}", opts.out.display()))?;
    let mut csv = open_csv(&opts.out, state.update)?;
    let ck_path = checkpoint_path(&opts.out);
    let limits = EpisodeLimits::default();
    let mut workers: Vec<(Worker, crate::train::params::ParamSet)> = (0..opts.workers)
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
    let disc_ids = [
        TensorId::DiscW1,
        TensorId::DiscB1,
        TensorId::DiscW2,
        TensorId::DiscB2,
    ];
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
                        let mut out = Vec::new();
                        let mut steps = 0u32;
                        let mut e = 0u32;
                        while e == 0 || steps < opts.min_steps {
                            let mut rng =
                                ChaCha8Rng::seed_from_u64(episode_seed(opts.seed, u, w, e));
                            let spec =
                                world.sample_train_episode_min(&mut rng, opts.min_start_actions);
                            let max = opts.max_steps.unwrap_or_else(|| limits.for_room(spec.room));
                            let (st, disc) = train_episode(
                                world,
                                &spec,
                                model,
                                opts.reward,
                                max,
                                &opts.a3c,
                                opts.objective,
                                opts.meta_order,
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
        total.scale(1.0 / opts.workers as f32);
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
            state.save(&ck_path, opts)?;
        }
    }
    bar.finish_and_clear();
    Ok(())
}
