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

use std::fs::{File, OpenOptions};
use std::io::Write;
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
use super::vec_rollout::{self, VecSettings};
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
    /// Environments each worker steps in lockstep (`B`, see [`super::vec_rollout`]); 1 is
    /// the batch-1 episode runner. Stored in the checkpoint (absent in older ones: 1).
    pub batch_envs: usize,
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
    /// What world the run trains on (`{"kind": "synthetic" | "data", "world_seed": .., and
    /// for data "fingerprint": ..}`, see the CLI), stored in the checkpoint so that a resumed
    /// run can refuse another world; `None` when unknown (library use, older checkpoints).
    pub world: Option<serde_json::Value>,
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
            world: None,
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
            "batch_envs": opts.batch_envs,
            "min_steps": opts.min_steps,
            "reward": format!("{:?}", opts.reward),
            "max_steps": opts.max_steps,
            "min_start_actions": opts.min_start_actions,
            "adam": opts.adam,
            "a3c": opts.a3c,
            "meta_order": opts.meta_order,
            "objective": opts.objective.name(),
            "method": self.model.method.name(),
        });
        if let Some(w) = &self.world {
            meta["trainer"]["world"] = w.clone();
        }
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
        // The method is stored twice (model and trainer metadata): a relabelled one is refused.
        if let Some(m) = t.get("method").and_then(|v| v.as_str()) {
            if m != model.method.name() {
                bail!(
                    "{}: the model's method is {} but the run was trained as {m}; the metadata was changed",
                    path.display(),
                    model.method.name()
                );
            }
        }
        let state = TrainState {
            model,
            adam,
            update: get("update")?,
            episodes: get("episodes")?,
            env_steps: get("env_steps")?,
            world: t.get("world").cloned(),
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

/// Number of columns of `metrics.csv`.
fn csv_columns() -> usize {
    CSV_HEADER.split(',').count()
}

/// What [`repair_csv`] kept and dropped.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct CsvRepair {
    /// Rows kept (without the header), in order: one per update `1..=update` that had a
    /// well-formed row.
    pub rows: Vec<String>,
    /// 1-based line numbers of malformed rows (wrong column count, a value that is not a
    /// number) and of duplicate or out-of-order updates, dropped.
    pub dropped: Vec<usize>,
    /// Updates `1..=update` that have no well-formed row.
    pub missing: u64,
}

/// Keeps the well-formed rows of a `metrics.csv` text for updates `1..=update`, in order,
/// dropping (and listing) malformed, duplicate and out-of-order rows; rows after `update`
/// (written after the checkpoint a run resumes from) are dropped silently. The header line
/// may be absent (its first data row is then kept, not skipped).
pub fn repair_csv(text: &str, update: u64) -> CsvRepair {
    let mut r = CsvRepair::default();
    let mut last = 0u64;
    for (i, line) in text.lines().enumerate() {
        if line == CSV_HEADER || line.trim().is_empty() {
            continue;
        }
        let f: Vec<&str> = line.split(',').collect();
        let u = f[0].parse::<u64>().ok();
        let numeric = f[1..].iter().all(|v| v.parse::<f64>().is_ok());
        match u {
            Some(u) if u > update && f.len() == csv_columns() && numeric => {}
            Some(u) if f.len() == csv_columns() && numeric && u > last && u <= update => {
                last = u;
                r.rows.push(line.to_string());
            }
            // A partial last row written when the process was killed is normal when it lies
            // after the checkpoint; anything else malformed is reported.
            Some(u) if u > update => {}
            _ => r.dropped.push(i + 1),
        }
    }
    r.missing = update - r.rows.len() as u64;
    r
}

/// Rewrites `metrics.csv` atomically (temporary file, fsync, rename) keeping only the rows up
/// to `update` (so a resumed run continues the file where its checkpoint was written), with
/// malformed and duplicate rows dropped and counted in a warning, then opens it for appending.
fn open_csv(out: &Path, update: u64) -> Result<File> {
    let path = out.join("metrics.csv");
    let mut keep = vec![CSV_HEADER.to_string()];
    if update > 0 && path.exists() {
        let text = std::fs::read(&path).with_context(|| format!("reading {}", path.display()))?;
        let r = repair_csv(&String::from_utf8_lossy(&text), update);
        if !r.dropped.is_empty() {
            let shown: Vec<String> = r.dropped.iter().take(10).map(|l| l.to_string()).collect();
            eprintln!(
                "warning: {}: dropped {} malformed or duplicate row(s) at or before update {update} (line {}{})",
                path.display(),
                r.dropped.len(),
                shown.join(", "),
                if r.dropped.len() > 10 { ", ..." } else { "" }
            );
        }
        if r.missing > 0 {
            eprintln!(
                "warning: {}: {} of the {update} updates before the checkpoint have no row; the learning curve has a gap there",
                path.display(),
                r.missing
            );
        }
        keep.extend(r.rows);
    }
    crate::train::checkpoint::write_atomic(&path, |f| {
        let mut w = std::io::BufWriter::new(f);
        for l in &keep {
            writeln!(w, "{l}")?;
        }
        w.flush()
    })?;
    OpenOptions::new()
        .append(true)
        .open(&path)
        .with_context(|| format!("opening {} for appending", path.display()))
}

/// An exclusive lock on a run directory, held while a trainer writes into it (released when
/// dropped, or by the OS when the process dies). See [`lock_run_dir`].
#[derive(Debug)]
pub struct RunLock {
    file: Option<File>,
    key: PathBuf,
}

impl Drop for RunLock {
    fn drop(&mut self) {
        if self.file.take().is_some() {
            if let Ok(mut held) = held_locks().lock() {
                held.retain(|k| k != &self.key);
            }
        }
    }
}

fn held_locks() -> &'static std::sync::Mutex<Vec<PathBuf>> {
    static HELD: std::sync::OnceLock<std::sync::Mutex<Vec<PathBuf>>> = std::sync::OnceLock::new();
    HELD.get_or_init(Default::default)
}

/// Name of the lock file in a run directory.
pub const LOCK_FILE: &str = ".lock";

/// Takes an exclusive advisory lock (`flock`, through `fs4`) on `RUN_DIR/.lock`, so that a
/// second trainer writing into the same run directory is refused with a clear error instead
/// of interleaving `metrics.csv` and checkpoints. Taking it again in the same process (the
/// CLI holds it while pre-training, then [`train`] asks for it) returns a guard that does
/// nothing. After the lock is taken, stale temporary files of atomic writes
/// (`.NAME.tmp.PID`, left by a process that was killed) are removed from the directory and
/// its `fg/` and `ps/` subdirectories, with a note on stderr.
pub fn lock_run_dir(out: &Path) -> Result<RunLock> {
    std::fs::create_dir_all(out).with_context(|| format!("creating {}", out.display()))?;
    let key = out
        .canonicalize()
        .with_context(|| format!("resolving {}", out.display()))?;
    let mut held = held_locks()
        .lock()
        .map_err(|_| anyhow::anyhow!("run-directory lock registry poisoned"))?;
    if held.contains(&key) {
        return Ok(RunLock { file: None, key });
    }
    let path = out.join(LOCK_FILE);
    let file = OpenOptions::new()
        .create(true)
        .truncate(false)
        .write(true)
        .open(&path)
        .with_context(|| format!("creating lock file {}", path.display()))?;
    let locked = fs4::fs_std::FileExt::try_lock_exclusive(&file)
        .with_context(|| format!("locking {}", path.display()))?;
    if !locked {
        bail!(
            "{} is in use by another trainer (lock {} is held); wait for it to finish, or use another --out",
            out.display(),
            path.display()
        );
    }
    held.push(key.clone());
    drop(held);
    remove_stale_temporaries(out);
    Ok(RunLock {
        file: Some(file),
        key,
    })
}

/// Removes `.NAME.tmp.PID` files (temporaries of [`crate::train::checkpoint::write_atomic`])
/// of other processes from `dir`, `dir/fg` and `dir/ps`. Only called with the run
/// directory's lock held, so no other writer can be using them.
fn remove_stale_temporaries(dir: &Path) {
    let me = std::process::id().to_string();
    let (mut n, mut bytes) = (0usize, 0u64);
    for d in [dir.to_path_buf(), dir.join("fg"), dir.join("ps")] {
        let Ok(entries) = std::fs::read_dir(&d) else {
            continue;
        };
        for e in entries.flatten() {
            let name = e.file_name().to_string_lossy().into_owned();
            let Some((stem, pid)) = name.rsplit_once(".tmp.") else {
                continue;
            };
            if !stem.starts_with('.')
                || pid.is_empty()
                || !pid.bytes().all(|b| b.is_ascii_digit())
                || pid == me
            {
                continue;
            }
            let len = e.metadata().map(|m| m.len()).unwrap_or(0);
            if std::fs::remove_file(e.path()).is_ok() {
                n += 1;
                bytes += len;
            }
        }
    }
    if n > 0 {
        eprintln!(
            "note: removed {n} stale temporary file(s) ({bytes} bytes) left in {} by killed runs",
            dir.display()
        );
    }
}

/// Runs (or continues) training until `opts.updates` updates are done.
pub fn train(world: &World, opts: &TrainOptions, state: &mut TrainState) -> Result<()> {
    if opts.workers == 0 {
        bail!("--workers must be at least 1");
    }
    if !(1..=2).contains(&opts.meta_order) {
        bail!("--meta-order must be 1 or 2");
    }
    if opts.batch_envs == 0 || opts.batch_envs > vec_rollout::MAX_BATCH_ENVS {
        bail!(
            "--batch-envs must be in 1..={}, got {}",
            vec_rollout::MAX_BATCH_ENVS,
            opts.batch_envs
        );
    }
    if opts.batch_envs > 1 && !vec_rollout::supports(&state.model) {
        bail!(
            "--batch-envs {} is implemented for the methods without an inner loop in training (a3c, a3c-fg, a3c-ps, a3c-fg-ps, gman-nometa, gman-noemd); {} runs its inner loop per episode: use --batch-envs 1",
            opts.batch_envs,
            state.model.method.name()
        );
    }
    if opts.meta_order == 2 && state.model.method.uses_cossim() {
        bail!("--meta-order 2 is implemented for the discriminator EMD only; use --meta-order 1 with gman-cossim");
    }
    let _lock = lock_run_dir(&opts.out)?;
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
                                ChaCha8Rng::seed_from_u64(episode_seed(opts.seed, u, w, e));
                            let spec = world
                                .try_sample_train_episode_min(&mut rng, opts.min_start_actions)?;
                            let max = opts.max_steps.unwrap_or_else(|| limits.for_room(spec.room));
                            Ok((spec, max))
                        };
                        if opts.batch_envs > 1 {
                            let settings = VecSettings {
                                batch_envs: opts.batch_envs,
                                min_steps: opts.min_steps,
                                reward: opts.reward,
                                a3c: &opts.a3c,
                                objective: opts.objective,
                            };
                            let done = vec_rollout::run_worker(
                                world, model, &settings, worker, grads, sample,
                            )?;
                            return Ok(done.into_iter().map(|(_, st, d)| (st, d)).collect());
                        }
                        let mut out = Vec::new();
                        let mut steps = 0u32;
                        let mut e = 0u32;
                        while e == 0 || steps < opts.min_steps {
                            let (spec, max) = sample(e)?;
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
        // With D's head reset, D restarts from ω with every episode (on the device too), so
        // ω does not learn across episodes: carrying the episodes' layer-1 changes over lets
        // the gradient penalty grow layer 1 without bound (it diverged after ~6500 updates).
        let carry_disc = !state.model.inner_rule.disc_head_reset;
        for (id, delta) in disc_ids.iter().zip(&disc_delta).filter(|_| carry_disc) {
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
