//! `gman train`: train a navigation method, or resume a run exactly.

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{anyhow, bail, Context, Result};
use clap::builder::TypedValueParser;
use clap::{Args, ValueEnum};
use gman_host_sim::nav::a3c::Objective;
use gman_host_sim::nav::dist::{Group, Single};
use gman_host_sim::nav::model::{InnerRule, Method, ModelSpec, NavModel};
use gman_host_sim::nav::trainer::{
    checkpoint_path, train_in, Distributed, RunSettings, TrainOptions, TrainState, WorldId,
};
use gman_host_sim::optim::adam::AdamConfig;
use gman_host_sim::pretrain::fg::{self, FgCollectConfig, FgTrainConfig};
use gman_host_sim::pretrain::ps::{self, PsDataConfig, PsModule, PsTrainConfig};
use gman_host_sim::sim::{RewardKind, World};

use gman_core::memory::AdaptMode;
use gman_core::navigator::{NoiseMode, StepRule};
use gman_core::schema::AdaptLossKind;

use super::args::{named, PresetArg, WorldArgs};

/// Training configuration presets.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum ConfigArg {
    /// A few minutes on 2 cores: short pre-training and a few hundred updates.
    Tiny,
    /// The budget of the reported runs.
    Default,
}

/// `gman train`.
#[derive(Debug, Args)]
pub struct TrainArgs {
    /// World selection (training episodes come from the training scenes).
    #[command(flatten, next_help_heading = "World")]
    pub world: WorldArgs,
    /// Method (the rows of the paper's Tables 2 and 3).
    #[arg(help_heading = "Basics", long, value_enum, default_value = "gman")]
    pub method: Method,
    /// Network sizes.
    #[arg(help_heading = "Basics", long, value_enum, default_value = "mcu")]
    pub preset: PresetArg,
    /// Budget preset: `tiny` (minutes) or `default`.
    #[arg(help_heading = "Basics", long, value_enum, default_value = "default")]
    pub config: ConfigArg,
    /// Updates to reach (overrides the config).
    #[arg(help_heading = "Basics", long, value_name = "N")]
    pub updates: Option<u64>,
    /// Seed of the run.
    #[arg(help_heading = "Basics", long, default_value_t = 1)]
    pub seed: u64,
    /// Run directory: metrics.csv, checkpoint.ckpt (and fg/, ps/ when pre-trained here).
    #[arg(
        help_heading = "Basics",
        long,
        value_name = "RUN_DIR",
        required_unless_present = "resume"
    )]
    pub out: Option<PathBuf>,
    /// Continue the run in RUN_DIR from its checkpoint (bit for bit).
    #[arg(
        help_heading = "Basics",
        long,
        value_name = "RUN_DIR",
        conflicts_with = "out"
    )]
    pub resume: Option<PathBuf>,
    /// Pre-trained generator (`gman pretrain-fg` output, fg.ckpt); pre-trained here if absent.
    #[arg(help_heading = "Basics", long, value_name = "FG_CKPT")]
    pub fg: Option<PathBuf>,
    /// Pre-trained PS module (ps.ckpt) for the PS variants; pre-trained here if absent.
    #[arg(help_heading = "Basics", long, value_name = "PS_CKPT")]
    pub ps: Option<PathBuf>,
    /// Parallel workers (one thread each); under MPI, per rank (the run has ranks x this).
    #[arg(help_heading = "Basics", long, default_value_t = 2)]
    pub workers: usize,
    /// Environments each worker steps in lockstep, with the policy's passes run over them
    /// as matrices (1: one episode at a time; methods with an inner loop: one navigator per
    /// episode, first-order meta-gradient only). Every update then holds at least this many
    /// episodes per worker. Default: 16 (measured: README, "Batched training, B = 16"), 1 with
    /// `--meta-order 2`; pass 1 to reproduce the one-episode-at-a-time results.
    #[arg(help_heading = "Optimisation", long)]
    pub batch_envs: Option<usize>,
    /// Outer Adam learning rate β (overrides the config).
    #[arg(help_heading = "Optimisation", long)]
    pub lr: Option<f32>,
    /// Inner learning rates α1 (D) and α2 (θ, φ) (paper: 1e-4).
    #[arg(help_heading = "Inner loop (adaptation)", long, default_value_t = 1e-4)]
    pub inner_lr: f32,
    /// At most this many inner updates per episode (GMAN variants).
    #[arg(help_heading = "Inner loop (adaptation)", long, default_value_t = gman_host_sim::nav::model::DEFAULT_MAX_INNER)]
    pub max_inner: u32,
    /// α1 alone, D's ascent rate on L_D (default: --inner-lr, the paper's α1 = α2).
    #[arg(help_heading = "Inner loop (adaptation)", long, value_name = "ALPHA1")]
    pub disc_lr: Option<f32>,
    /// D's ascent steps on L_D per inner update (paper: 1).
    #[arg(
        help_heading = "Inner loop (adaptation)",
        long,
        value_name = "N",
        default_value_t = 1
    )]
    pub disc_steps: u32,
    /// The descent step of θ and φ on L_ad: `gradient` (α2 ∇, the paper), `normalized`
    /// (α2 ∇/‖∇‖: --inner-lr is then the step's length) or `per-group` (θ and φ each
    /// normalised to that length). Recorded in the blob.
    #[arg(
        help_heading = "Inner loop (adaptation)",
        long,
        value_parser = named::<StepRule>(),
        default_value = "gradient"
    )]
    pub step_rule: StepRule,
    /// D restarts with every episode: layer 1 from ω, the output layer (w2, b2) at zero, so
    /// D's first ascent step sets the head from the episode's own buffer; ω then does not
    /// learn across episodes (paper: off, D persists). Recorded in the blob.
    #[arg(help_heading = "Inner loop (adaptation)", long)]
    pub disc_head_reset: bool,
    /// The form of L_ad: `paper` (Eq. 3) or `reference` (‖Σ_t a_t (−D(x_t))‖₂, the
    /// reference implementation's). Recorded in the blob.
    #[arg(
        help_heading = "Inner loop (adaptation)",
        long,
        value_parser = named::<AdaptLossKind>(),
        default_value = "paper"
    )]
    pub adapt_loss: AdaptLossKind,
    /// Scale L_D's critic terms by 10, as the reference implementation does (the paper: 1).
    /// Recorded in the blob.
    #[arg(help_heading = "Inner loop (adaptation)", long)]
    pub reference_critic: bool,
    /// The inner loop's descent step on L_ad adapts only the actor head; G stays at θ (the
    /// reference implementation's default, whose G gets no inner gradient; the paper: G and
    /// the head). Recorded in the blob.
    #[arg(help_heading = "Inner loop (adaptation)", long)]
    pub adapt_head_only: bool,
    /// The inner update's commit delay D in steps (0..=63): the update that starts when Ψ
    /// fills takes effect D steps later, the steps between acting on the current parameters
    /// and not recorded in Ψ; what a device that computes the update in slices, or at a lower
    /// priority, runs (see docs/device.md). 0: at once (the paper). Recorded in the blob.
    #[arg(
        help_heading = "Inner loop (adaptation)",
        long,
        default_value_t = 0,
        value_name = "D"
    )]
    pub commit_delay: u32,
    /// Minimum steps per worker and update.
    #[arg(help_heading = "Episodes and reward", long, default_value_t = 40)]
    pub min_steps: u32,
    /// Step limit of training episodes (default: 200 in living rooms, 100 elsewhere).
    #[arg(help_heading = "Episodes and reward", long)]
    pub max_steps: Option<u32>,
    /// Training starts need at least this many actions to see the target (0: any start).
    #[arg(help_heading = "Episodes and reward", long, default_value_t = 1)]
    pub min_start_actions: u32,
    /// Entropy bonus β of the A3C loss.
    #[arg(help_heading = "Optimisation", long, default_value_t = 0.01)]
    pub entropy: f32,
    /// Reward: navigation (R_n), distance (R_{n+d}), similarity (R_{n+s}) or mixed (R_{n+d+s}, the paper's).
    #[arg(long, default_value = "mixed", help_heading = "Episodes and reward", value_parser = clap::builder::PossibleValuesParser::new(["navigation", "distance", "similarity", "mixed"]).map(|s| s.parse::<RewardKind>().expect("a listed value")))]
    pub reward: RewardKind,
    /// Checkpoint every N updates.
    #[arg(help_heading = "Basics", long, default_value_t = 100)]
    pub checkpoint_every: u64,
    /// Spatial observation map fed to the policy: `RxC` sectors of the view (e.g. `3x3`,
    /// `1x3`, `7x7` as the reference's ResNet map), or `none` (the pooled embedding only).
    #[arg(help_heading = "Model", long, default_value = "none", value_parser = parse_map_grid)]
    pub map: (usize, usize),
    /// Channels of the shared per-cell layer over the map (the reference's 1x1 conv: 64).
    #[arg(help_heading = "Model", long, default_value_t = 8)]
    pub cell_embed: usize,
    /// Adaptation mode of the inner loop (in training and on the device; blobs record it):
    /// `efficient` (per-unit gains and biases, what the microcontroller runs) or `full`
    /// (every parameter). Default: efficient for the mcu preset, full for paper.
    #[arg(help_heading = "Inner loop (adaptation)", long, value_parser = named::<AdaptMode>())]
    pub adapt_mode: Option<AdaptMode>,
    /// Training objective: `a3c` (the paper's actor-critic loss) or `dagger` (imitation of
    /// the shortest-path oracle on the learner's own states: the imitation ceiling).
    #[arg(help_heading = "Optimisation", long, value_enum, default_value = "a3c")]
    pub objective: Objective,
    /// The privileged-feature ceiling: the policy sees the target's true feature in the
    /// current scene in place of G's output (not exportable; methods without inner loop).
    #[arg(help_heading = "Model", long)]
    pub privileged_feature: bool,
    /// Noise z of G at navigation time, in training and wherever the model runs (recorded in
    /// the checkpoint and the blob; a resumed run keeps its own).
    #[arg(
        help_heading = "Inner loop (adaptation)",
        long,
        value_parser = named::<NoiseMode>(),
        default_value = "gaussian"
    )]
    pub noise: NoiseMode,
    /// Meta-gradient order: 1 = first-order MAML (the gradient at the adapted parameters),
    /// 2 = exact through the inner SGD steps (Hessian-vector products by central finite
    /// differences of gradients).
    #[arg(help_heading = "Optimisation", long, default_value_t = 1, value_parser = clap::value_parser!(u8).range(1..=2))]
    pub meta_order: u8,
    /// No progress bar.
    #[arg(help_heading = "Basics", long)]
    pub quiet: bool,
    /// On --resume, continue with another total worker count (ranks x --workers) than the
    /// run was trained with; the run then no longer matches an uninterrupted one bit for bit.
    #[arg(help_heading = "Basics", long)]
    pub change_workers: bool,
    /// Under MPI: every N updates (and at the last) the ranks compare a hash of their
    /// parameters and Adam state and stop with an error if they differ (0: never).
    #[arg(help_heading = "Basics", long, value_name = "N", default_value_t = 10)]
    pub rank_check_every: u64,
}

/// Parses `--map`: `none` or `RxC` with 1 <= R, C <= 16.
fn parse_map_grid(s: &str) -> std::result::Result<(usize, usize), String> {
    if s == "none" {
        return Ok((0, 0));
    }
    let bad = || format!("expected `none` or ROWSxCOLS such as 3x3 (each 1..=16), got {s:?}");
    let (r, c) = s.split_once(['x', 'X']).ok_or_else(bad)?;
    let (r, c): (usize, usize) = (r.parse().map_err(|_| bad())?, c.parse().map_err(|_| bad())?);
    if !(1..=16).contains(&r) || !(1..=16).contains(&c) {
        return Err(bad());
    }
    Ok((r, c))
}

pub(super) fn preset_matches(model: &NavModel, preset: PresetArg) -> Result<()> {
    let d = preset.dims();
    let m = model.dims;
    if (m.gen_hidden, m.disc_hidden, m.lstm_hidden, m.embed, m.feat)
        != (d.gen_hidden, d.disc_hidden, d.lstm_hidden, d.embed, d.feat)
    {
        bail!(
            "the model has {:?} sizes, not the {} preset",
            m,
            preset.name()
        );
    }
    Ok(())
}

/// Pre-trains G into `dir` unless `given` names a checkpoint; returns its path.
pub(super) fn ensure_fg(
    world: &World,
    preset: PresetArg,
    given: Option<&Path>,
    dir: &Path,
    tiny: bool,
    seed: u64,
) -> Result<PathBuf> {
    if let Some(p) = given {
        return Ok(p.to_path_buf());
    }
    let path = dir.join("fg.ckpt");
    if path.exists() {
        eprintln!(
            "using the generator pre-trained earlier in {}",
            path.display()
        );
        return Ok(path);
    }
    eprintln!(
        "no --fg given: pre-training the feature generator into {}",
        dir.display()
    );
    let iters = match (tiny, preset) {
        (true, _) => 400,
        (false, PresetArg::Mcu) => 1500,
        (false, PresetArg::Paper) => 300,
    };
    let mut cfg = FgTrainConfig::new(iters, seed);
    cfg.progress = true;
    let collect = FgCollectConfig {
        seed,
        ..FgCollectConfig::default()
    };
    let r = fg::run_pretrain_fg(world, preset.name(), &preset.dims(), &collect, &cfg, dir)?;
    eprint!("{}", fg::report_table(&r));
    Ok(path)
}

/// Pre-trains the PS module into `dir` unless `given` names one; returns its path.
fn ensure_ps(world: &World, given: Option<&Path>, dir: &Path, seed: u64) -> Result<PathBuf> {
    if let Some(p) = given {
        return Ok(p.to_path_buf());
    }
    let path = dir.join("ps.ckpt");
    if path.exists() {
        return Ok(path);
    }
    eprintln!(
        "no --ps given: pre-training the PS module into {}",
        dir.display()
    );
    let cfg = PsTrainConfig {
        seed,
        progress: true,
        ..PsTrainConfig::default()
    };
    let collect = PsDataConfig {
        seed,
        ..PsDataConfig::default()
    };
    let r = ps::run_pretrain_ps(world, &collect, &cfg, dir)?;
    eprint!("{}", ps::report_table(&r));
    Ok(path)
}

/// One setting of a resumed run: the value stored in its checkpoint wins; a flag given
/// explicitly on the command line must agree with it (otherwise the resumed run would
/// silently differ from an uninterrupted one).
fn resumed<T: PartialEq + std::fmt::Debug>(
    flag: &str,
    cli: T,
    stored: T,
    explicit: bool,
) -> Result<T> {
    if explicit && stored != cli {
        bail!(
            "{flag} {cli:?} conflicts with the resumed run, which was trained with {stored:?}; a \
             resumed run keeps its own settings (omit the flag, or start a new run with --out)"
        );
    }
    Ok(stored)
}

/// The model's switches the flags ask for (those of a new run).
fn model_spec(a: &TrainArgs) -> ModelSpec {
    ModelSpec {
        noise: a.noise,
        inner_lr: a.inner_lr,
        max_inner: a.max_inner,
        adapt_mode: new_run_adapt_mode(a),
        inner_rule: InnerRule {
            disc_lr: a.disc_lr,
            disc_steps: a.disc_steps,
            step_rule: a.step_rule,
            disc_head_reset: a.disc_head_reset,
            adapt_loss: a.adapt_loss,
            reference_critic: a.reference_critic,
            head_only: a.adapt_head_only,
            commit_delay: a.commit_delay,
        },
    }
}

/// Most `--workers` a run may have (one thread each).
const MAX_WORKERS: usize = 256;

/// The checks on trainer settings, applied to the flags of a new run and to the settings a
/// resumed run reads from its checkpoint (whose CRC says nothing about their sense). `what`
/// names where they came from.
fn validate_train_settings(what: &str, opts: &TrainOptions) -> Result<()> {
    let bad = |msg: String| anyhow!("{what}: {msg}");
    if opts.run.workers == 0 || opts.run.workers > MAX_WORKERS {
        return Err(bad(format!(
            "workers must be in 1..={MAX_WORKERS}, got {}",
            opts.run.workers
        )));
    }
    if opts.checkpoint_every == 0 {
        return Err(bad("checkpoint-every must be at least 1".into()));
    }
    let max_b = gman_host_sim::nav::lockstep::MAX_BATCH_ENVS;
    if opts.run.batch_envs == 0 || opts.run.batch_envs > max_b {
        return Err(bad(format!(
            "batch-envs must be in 1..={max_b}, got {}",
            opts.run.batch_envs
        )));
    }
    let c = &opts.run.a3c;
    if !(c.entropy.is_finite() && c.entropy >= 0.0) {
        return Err(bad(format!(
            "entropy must be finite and non-negative, got {}",
            c.entropy
        )));
    }
    if !((0.0..=1.0).contains(&c.gamma) && (0.0..=1.0).contains(&c.tau)) {
        return Err(bad(format!(
            "A3C gamma {} and tau {} must be in [0, 1]",
            c.gamma, c.tau
        )));
    }
    if !(c.value_coef.is_finite() && c.value_coef >= 0.0) {
        return Err(bad(format!(
            "A3C value coefficient {} must be finite and non-negative",
            c.value_coef
        )));
    }
    opts.run
        .adam
        .validate()
        .map_err(|e| bad(format!("{e:#}")))?;
    if !(1..=2).contains(&opts.run.meta_order) {
        return Err(bad(format!(
            "meta-order must be 1 or 2, got {}",
            opts.run.meta_order
        )));
    }
    Ok(())
}

/// What world `w` selects (loaded as `world`), as stored in a run's checkpoint: kind, world
/// seed and, for a data directory, its object layout and a fingerprint of the contents that
/// layout reads (the path may change, the data must not).
fn world_identity(w: &WorldArgs, world: &World) -> Result<WorldId> {
    Ok(match &w.data {
        Some(dir) => WorldId::of_data_dir(dir, w.world_seed, &w.visible_file, world.layout)?,
        None => WorldId::Synthetic {
            world_seed: w.world_seed,
        },
    })
}

/// The adaptation mode of a new run: `--adapt-mode`, else Full for the paper preset and
/// Efficient (what a microcontroller runs) for mcu.
fn new_run_adapt_mode(a: &TrainArgs) -> gman_core::memory::AdaptMode {
    match (a.adapt_mode, a.preset) {
        (Some(m), _) => m,
        (None, PresetArg::Paper) => gman_core::memory::AdaptMode::Full,
        (None, _) => gman_core::memory::AdaptMode::Efficient,
    }
}

/// Combinations of the new flags that cannot work, refused before anything is loaded.
fn check_train_flags(a: &TrainArgs) -> Result<()> {
    if a.map.0 > 0 && a.cell_embed == 0 {
        bail!("--cell-embed must be at least 1 with a --map");
    }
    model_spec(a).validate().map_err(|e| anyhow!("--{e}"))?;
    if a.resume.is_some() {
        return Ok(());
    }
    if a.privileged_feature && a.method.adapts_in_training() {
        bail!(
            "--privileged-feature replaces G's output, so it goes with a method without inner loop (a3c, a3c-fg, a3c-ps, a3c-fg-ps), not {}",
            a.method.name()
        );
    }
    if a.meta_order == 2
        && a.method.adapts_in_training()
        && new_run_adapt_mode(a) == gman_core::memory::AdaptMode::Efficient
    {
        bail!("--meta-order 2 is implemented for the Full adaptation mode; add --adapt-mode full");
    }
    // The commit delay only moves the update in time: the meta-gradient is the same recursion.
    let rule = InnerRule {
        commit_delay: 0,
        ..model_spec(a).inner_rule
    };
    if a.meta_order == 2 && a.method.adapts_in_training() && !rule.is_paper() {
        bail!("--meta-order 2 differentiates the paper's inner rule only (one D step, the gradient step, α1 = α2); use --meta-order 1 with --disc-lr, --disc-steps, --step-rule, --disc-head-reset, --adapt-loss, --reference-critic or --adapt-head-only");
    }
    Ok(())
}
/// `gman train`. `explicit(id)` says whether the flag of field `id` was given on the command
/// line (on `--resume`, only those are checked against the checkpoint's settings). Started by
/// an MPI launcher (`mpirun`, `srun`; build with `--features mpi`), the run spans its ranks,
/// `--workers` per rank (see `docs/distributed.md`).
pub fn cmd_train(a: TrainArgs, explicit: &dyn Fn(&str) -> bool) -> Result<()> {
    #[cfg(feature = "mpi")]
    if gman_host_sim::nav::mpi::launched_by_mpi() {
        let mut g = gman_host_sim::nav::mpi::MpiGroup::init()?;
        let r = train_on(a, explicit, &mut g);
        if let Err(e) = &r {
            if g.size() > 1 {
                // The other ranks may wait in a collective: end the whole job.
                eprintln!("error (rank {}): {e:#}", g.rank());
                g.abort(1);
            }
        }
        return r;
    }
    #[cfg(not(feature = "mpi"))]
    if ["OMPI_COMM_WORLD_SIZE", "PMI_SIZE"]
        .iter()
        .any(|v| std::env::var(v).is_ok_and(|n| n != "1"))
    {
        bail!("this gman was built without MPI, so each of the launcher's processes would train alone; build it with `cargo build --release --features mpi`");
    }
    train_on(a, explicit, &mut Single)
}

/// [`cmd_train`] on the ranks of `group`.
fn train_on(
    mut a: TrainArgs,
    explicit: &dyn Fn(&str) -> bool,
    group: &mut dyn Group,
) -> Result<()> {
    check_train_flags(&a)?;
    check_train_numbers(&a)?;
    let (rank, ranks) = (group.rank(), group.size());
    let lead = rank == 0;
    if a.resume.is_some() && lead {
        // Flags that only shape a new run have no effect here: said so, not silently dropped.
        for (flag, id) in [("--fg", "fg"), ("--ps", "ps"), ("--config", "config")] {
            if explicit(id) && !(id == "config" && a.updates.is_none()) {
                eprintln!("warning: {flag} is ignored on --resume: a resumed run keeps the networks and settings it was started with");
            }
        }
    }
    let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
    if a.workers > cores && lead {
        eprintln!(
            "warning: --workers {} runs {} threads on {cores} core(s); the run is reproducible for its worker count but slower than with --workers {cores}",
            a.workers, a.workers
        );
    }
    // From here on `workers` counts the workers of all ranks, the number the run stores.
    a.workers *= ranks;
    if !lead {
        a.quiet = true;
    }
    let run_dir = a.resume.clone().or_else(|| a.out.clone());
    let _lock = match (&run_dir, lead) {
        (Some(d), true) => Some(gman_host_sim::nav::trainer::lock_run_dir(d)?),
        _ => None,
    };
    let world = load_world(&a)?;
    let world_id = world_identity(&a.world, &world)?;
    let mut opts = flag_options(&a);
    let mut state = match &a.resume {
        Some(dir) => {
            let (mut state, run) = open_resumed(&a, dir, &world_id, explicit)?;
            opts.out = dir.clone();
            opts.run = run;
            opts.updates = resumed_target(&a, &state, dir)?;
            state.target_updates = Some(opts.updates);
            state
        }
        None => {
            let out = a
                .out
                .clone()
                .ok_or_else(|| anyhow!("--out RUN_DIR is required"))?;
            // Rank 0 pre-trains G and the PS module into the run directory; the others
            // then load what it wrote.
            let mut state = None;
            if lead {
                state = Some(new_run(&a, &world, &out, world_id.clone())?);
            }
            group.barrier();
            let mut state = match state {
                Some(s) => s,
                None => new_run(&a, &world, &out, world_id)?,
            };
            validate_train_settings("command line", &opts)?;
            state.target_updates = Some(opts.updates);
            opts.out = out;
            state
        }
    };
    let t0 = Instant::now();
    let steps0 = state.env_steps;
    let mut dist = Distributed {
        group,
        check_every: a.rank_check_every,
    };
    let comm = train_in(&world, &opts, &mut state, &mut dist)?;
    if lead {
        report_trained(&state, &opts.out, steps0, t0.elapsed().as_secs_f64());
        if ranks > 1 {
            eprintln!("mpi: {}", comm.summary(ranks));
        }
    }
    check_finite_run(&state, &opts.out)
}

/// The update count a resumed run trains to: `--updates` when given (refused below the
/// checkpoint's update), else the target stored in the checkpoint; a checkpoint of an older
/// build without one needs `--updates` (the preset's count could be below the checkpoint's
/// update, or far beyond what the run was asked for). Printed either way.
fn resumed_target(a: &TrainArgs, st: &TrainState, dir: &Path) -> Result<u64> {
    let target = match (a.updates, st.target_updates) {
        (Some(n), _) => {
            if n < st.update {
                bail!(
                    "--updates {n} on resuming {}: the checkpoint is already at update {}; give a target of at least {}{}",
                    dir.display(),
                    st.update,
                    st.update,
                    st.target_updates.map_or(String::new(), |t| format!(
                        " (or omit --updates to continue to the stored target, {t})"
                    ))
                );
            }
            n
        }
        (None, Some(t)) => t,
        (None, None) => bail!(
            "{}: its checkpoint predates stored targets (it does not record the run's --updates, so where the run was meant to stop is unknown); it is at update {}: give --updates N (at least {}) to resume",
            dir.display(),
            st.update,
            st.update
        ),
    };
    eprintln!(
        "target: update {target} ({} to go){}",
        target.saturating_sub(st.update),
        if a.updates.is_some() {
            " (--updates)"
        } else {
            " (stored in the checkpoint)"
        }
    );
    Ok(target)
}

/// The budget preset's update count and the outer learning rate, as the flags select them.
fn updates_and_lr(a: &TrainArgs) -> (u64, f32) {
    let tiny = a.config == ConfigArg::Tiny;
    (
        a.updates.unwrap_or(if tiny { 300 } else { 4000 }),
        a.lr.unwrap_or(1e-3),
    )
}

/// The numeric flags' ranges, checked before anything is loaded.
fn check_train_numbers(a: &TrainArgs) -> Result<()> {
    if a.workers == 0 || a.checkpoint_every == 0 {
        bail!("--workers and --checkpoint-every must be at least 1");
    }
    if a.workers > MAX_WORKERS {
        bail!("--workers {} is more than {MAX_WORKERS}", a.workers);
    }
    if !(a.entropy.is_finite() && a.entropy >= 0.0) {
        bail!("--entropy must be finite and non-negative");
    }
    let (_, lr) = updates_and_lr(a);
    if !(lr.is_finite() && lr > 0.0 && lr <= MAX_LR) {
        bail!("--lr {lr} must be in (0, {MAX_LR}] (the paper's is 1e-3)");
    }
    if a.max_steps == Some(0) || a.max_steps.is_some_and(|n| n > MAX_EPISODE_STEPS) {
        bail!(
            "--max-steps {} must be in 1..={MAX_EPISODE_STEPS} (default: 200 in living rooms, 100 elsewhere)",
            a.max_steps.unwrap_or(0)
        );
    }
    if a.min_steps == 0 || a.min_steps > MAX_MIN_STEPS {
        bail!(
            "--min-steps {} must be in 1..={MAX_MIN_STEPS} (steps per worker and update are buffered in memory)",
            a.min_steps
        );
    }
    if a.map.0 > MAX_MAP_SIDE || a.map.1 > MAX_MAP_SIDE {
        bail!(
            "--map {}x{}: a map grid has at most {MAX_MAP_SIDE} rows and {MAX_MAP_SIDE} columns",
            a.map.0,
            a.map.1
        );
    }
    if a.cell_embed > MAX_CELL_EMBED {
        bail!(
            "--cell-embed {} is more than {MAX_CELL_EMBED} (the reference's is 64; every map cell adds that many fusion inputs)",
            a.cell_embed
        );
    }
    if a.updates.is_some_and(|n| n > MAX_UPDATES) || a.checkpoint_every > MAX_UPDATES {
        bail!("--updates and --checkpoint-every must be at most {MAX_UPDATES}");
    }
    Ok(())
}

/// Largest outer (Adam) learning rate `--lr` accepts.
const MAX_LR: f32 = 1.0;
/// Largest `--max-steps` (episode step limit).
pub(crate) const MAX_EPISODE_STEPS: u32 = 10_000;
/// Largest `--min-steps` (steps per worker and update, all held in memory for BPTT).
const MAX_MIN_STEPS: u32 = 10_000;
/// Largest map side (`--map RxC`, rows and columns each).
const MAX_MAP_SIDE: usize = 16;
/// Largest `--cell-embed`.
const MAX_CELL_EMBED: usize = 1024;
/// Largest `--updates` (and `--checkpoint-every`): counters stay far from `u64::MAX`.
const MAX_UPDATES: u64 = 1 << 40;

/// Loads the world, refusing a map grid offline data cannot serve, and fails now (not after
/// pre-training) if no training start can satisfy `--min-start-actions` (a separate
/// generator: the run's own draws are untouched).
fn load_world(a: &TrainArgs) -> Result<World> {
    let world = a.world.load()?;
    gman_host_sim::sim::spatial::check_grid_for_world(
        &world,
        a.map.0,
        a.map.1,
        &format!("--map {}x{}", a.map.0, a.map.1),
    )?;
    // Offline scenes are read now: a feature file with bad values is an error naming it.
    world.prepare_split(gman_host_sim::sim::Split::Train)?;
    use rand::SeedableRng;
    let mut probe = rand_chacha::ChaCha8Rng::seed_from_u64(0);
    world.try_sample_train_episode_min(&mut probe, a.min_start_actions)?;
    Ok(world)
}

/// `--batch-envs` when given, else the default: [`DEFAULT_BATCH_ENVS`], or 1 with
/// `--meta-order 2` (whose reverse recursion runs one episode at a time).
fn batch_envs(a: &TrainArgs) -> usize {
    a.batch_envs.unwrap_or(if a.meta_order == 2 {
        1
    } else {
        DEFAULT_BATCH_ENVS
    })
}

/// The default of `--batch-envs`: 16 environments per worker. Measured on the official val
/// episodes (README, "Batched training, B = 16"): at 6000 updates GMAN reaches 19.47 ± 0.70
/// unseen SR in about 6 minutes against 14.93 ± 2.76 at B = 1 after 45000 updates.
pub const DEFAULT_BATCH_ENVS: usize = 16;

/// The options the flags ask for (a resumed run replaces `run` and `out` by its own).
fn flag_options(a: &TrainArgs) -> TrainOptions {
    let (updates, lr) = updates_and_lr(a);
    TrainOptions {
        updates,
        run: RunSettings {
            seed: a.seed,
            workers: a.workers,
            batch_envs: batch_envs(a),
            min_steps: a.min_steps,
            reward: a.reward,
            max_steps: a.max_steps,
            min_start_actions: a.min_start_actions,
            adam: AdamConfig {
                lr,
                ..AdamConfig::default()
            },
            a3c: gman_host_sim::nav::a3c::A3cConfig {
                entropy: a.entropy,
                ..Default::default()
            },
            objective: a.objective,
            meta_order: a.meta_order,
        },
        checkpoint_every: a.checkpoint_every,
        out: PathBuf::new(),
        progress: !a.quiet,
    }
}

/// A new run in `out`: pre-trains (or loads) G and the PS module as the method needs, and
/// initialises the model with the flags' settings.
fn new_run(a: &TrainArgs, world: &World, out: &Path, world_id: WorldId) -> Result<TrainState> {
    std::fs::create_dir_all(out).with_context(|| format!("creating {}", out.display()))?;
    if checkpoint_path(out).exists() {
        bail!(
            "{} already holds a run; use --resume {} to continue it, or another --out",
            out.display(),
            out.display()
        );
    }
    let tiny = a.config == ConfigArg::Tiny;
    let gen = if a.method.uses_fg() {
        let p = ensure_fg(
            world,
            a.preset,
            a.fg.as_deref(),
            &out.join("fg"),
            tiny,
            a.seed,
        )?;
        Some(
            fg::load_generator(&p, &a.preset.dims())
                .with_context(|| format!("loading generator {}", p.display()))?,
        )
    } else {
        None
    };
    let psm = if a.method.uses_ps() {
        let p = ensure_ps(world, a.ps.as_deref(), &out.join("ps"), a.seed)?;
        Some(PsModule::load(&p).with_context(|| format!("loading PS module {}", p.display()))?)
    } else {
        None
    };
    let (rows, cols) = a.map;
    let dims = if rows > 0 {
        a.preset.dims().with_map(rows, cols, a.cell_embed)
    } else {
        a.preset.dims()
    };
    let mut model = NavModel::init(a.method, dims, a.seed, gen.as_ref(), psm)?;
    model.privileged = a.privileged_feature;
    model.set_spec(model_spec(a));
    let adam = AdamConfig {
        lr: updates_and_lr(a).1,
        ..AdamConfig::default()
    };
    let mut st = TrainState::new(model, adam);
    st.world = Some(world_id);
    Ok(st)
}

/// Opens the run in `dir` to continue it with its own settings (bit-exact resume): the
/// checkpoint's model and [`RunSettings`], checked against the world and against the flags
/// given explicitly.
fn open_resumed(
    a: &TrainArgs,
    dir: &Path,
    world_id: &WorldId,
    explicit: &dyn Fn(&str) -> bool,
) -> Result<(TrainState, RunSettings)> {
    let ck = checkpoint_path(dir);
    let (mut st, meta) = TrainState::load_with_settings(&ck)
        .with_context(|| format!("resuming {}", dir.display()))?;
    if let Some(w) = &st.world {
        if let Some(warning) = w
            .check_same(world_id)
            .with_context(|| format!("resuming {}", dir.display()))?
        {
            eprintln!("warning: resuming {}: {warning}", dir.display());
        }
        // The same data: from now on the checkpoint stores this build's fingerprint of it.
        st.world = Some(world_id.clone());
    }
    if explicit("preset") {
        preset_matches(&st.model, a.preset).with_context(|| {
            format!("--preset {} on resuming {}", a.preset.name(), dir.display())
        })?;
    }
    eprintln!(
        "resuming {} ({}) at update {}",
        dir.display(),
        st.model.method.name(),
        st.update
    );
    check_resumed_model(a, &st.model, explicit)?;
    let run = resumed_settings(a, &meta.run, explicit)?;
    let check = TrainOptions {
        run: run.clone(),
        ..flag_options(a)
    };
    validate_train_settings(&format!("{}: stored setting", ck.display()), &check)?;
    if !st.model.params.all_finite() {
        bail!(
            "{}: the model holds non-finite weights; the run diverged before this checkpoint and cannot be resumed",
            ck.display()
        );
    }
    if st.world.is_none() {
        // A checkpoint that does not record its world gets the one it resumes on.
        st.world = Some(world_id.clone());
    }
    Ok((st, run))
}

/// The model settings of a resumed run against the flags given explicitly.
fn check_resumed_model(a: &TrainArgs, m: &NavModel, explicit: &dyn Fn(&str) -> bool) -> Result<()> {
    resumed("--inner-lr", a.inner_lr, m.inner_lr, explicit("inner_lr"))?;
    resumed(
        "--max-inner",
        a.max_inner,
        m.max_inner,
        explicit("max_inner"),
    )?;
    let rule = &m.inner_rule;
    resumed("--disc-lr", a.disc_lr, rule.disc_lr, explicit("disc_lr"))?;
    resumed(
        "--disc-steps",
        a.disc_steps,
        rule.disc_steps,
        explicit("disc_steps"),
    )?;
    resumed(
        "--step-rule",
        a.step_rule,
        rule.step_rule,
        explicit("step_rule"),
    )?;
    resumed(
        "--disc-head-reset",
        a.disc_head_reset,
        m.inner_rule.disc_head_reset,
        explicit("disc_head_reset"),
    )?;
    resumed(
        "--adapt-loss",
        a.adapt_loss,
        m.inner_rule.adapt_loss,
        explicit("adapt_loss"),
    )?;
    resumed(
        "--reference-critic",
        a.reference_critic,
        m.inner_rule.reference_critic,
        explicit("reference_critic"),
    )?;
    resumed(
        "--adapt-head-only",
        a.adapt_head_only,
        m.inner_rule.head_only,
        explicit("adapt_head_only"),
    )?;
    resumed(
        "--commit-delay",
        a.commit_delay,
        m.inner_rule.commit_delay,
        explicit("commit_delay"),
    )?;
    resumed("--method", a.method, m.method, explicit("method"))?;
    if let Some(mode) = a.adapt_mode {
        resumed("--adapt-mode", mode, m.adapt_mode, explicit("adapt_mode"))?;
    }
    let d = &m.dims;
    resumed("--map", a.map, (d.map_rows, d.map_cols), explicit("map"))?;
    if d.map_cells() > 0 {
        resumed(
            "--cell-embed",
            a.cell_embed,
            d.cell_embed,
            explicit("cell_embed"),
        )?;
    }
    resumed(
        "--privileged-feature",
        a.privileged_feature,
        m.privileged,
        explicit("privileged_feature"),
    )?;
    Ok(())
}

/// The stored settings of a resumed run, each checked against its flag when given.
fn resumed_settings(
    a: &TrainArgs,
    s: &RunSettings,
    explicit: &dyn Fn(&str) -> bool,
) -> Result<RunSettings> {
    let (_, lr) = updates_and_lr(a);
    resumed(
        "--objective",
        a.objective,
        s.objective,
        explicit("objective"),
    )?;
    resumed("--seed", a.seed, s.seed, explicit("seed"))?;
    if !a.change_workers {
        resumed(
            "--workers (x ranks)",
            a.workers,
            s.workers,
            explicit("workers"),
        )?;
    }
    resumed(
        "--batch-envs",
        batch_envs(a),
        s.batch_envs,
        explicit("batch_envs"),
    )?;
    resumed(
        "--min-steps",
        a.min_steps,
        s.min_steps,
        explicit("min_steps"),
    )?;
    resumed(
        "--min-start-actions",
        a.min_start_actions,
        s.min_start_actions,
        explicit("min_start_actions"),
    )?;
    resumed(
        "--max-steps",
        a.max_steps,
        s.max_steps,
        explicit("max_steps"),
    )?;
    resumed(
        "--meta-order",
        a.meta_order,
        s.meta_order,
        explicit("meta_order"),
    )?;
    resumed("--reward", a.reward, s.reward, explicit("reward"))?;
    resumed("--lr", lr, s.adam.lr, explicit("lr"))?;
    resumed("--entropy", a.entropy, s.a3c.entropy, explicit("entropy"))?;
    let mut s = s.clone();
    if a.change_workers {
        s.workers = a.workers;
    }
    Ok(s)
}

/// The closing line of a run.
/// Training that produced non-finite weights or NaN/inf metrics fails (exit non-zero),
/// naming what and where: its checkpoint and curve are not a valid result.
fn check_finite_run(state: &TrainState, out: &Path) -> Result<()> {
    if !state.model.params.all_finite() {
        bail!(
            "training produced non-finite weights (update {}); {} is not a valid model",
            state.update,
            checkpoint_path(out).display()
        );
    }
    let csv = out.join("metrics.csv");
    if let Ok(text) = std::fs::read_to_string(&csv) {
        let bad: Vec<usize> = text
            .lines()
            .enumerate()
            .skip(1)
            .filter(|(_, l)| {
                // success_rate ..= grad_norm are always numbers (disc_gap and adapt_loss are
                // NaN by design in updates without an inner update).
                l.split(',').skip(3).take(7).any(|f| {
                    let f = f.trim().to_ascii_lowercase();
                    f.contains("nan") || f.contains("inf")
                })
            })
            .map(|(i, _)| i + 1)
            .collect();
        if let Some(first) = bad.first() {
            bail!(
                "training produced NaN or infinite metrics: {} row(s) of {} (first: line {first}); the run diverged",
                bad.len(),
                csv.display()
            );
        }
    }
    Ok(())
}

fn report_trained(state: &TrainState, out: &Path, steps0: u64, secs: f64) {
    let d = state.model.dims;
    let preset_name = [PresetArg::Mcu, PresetArg::Paper]
        .into_iter()
        .find(|p| {
            let pd = p.dims();
            (pd.gen_hidden, pd.disc_hidden, pd.lstm_hidden, pd.embed)
                == (d.gen_hidden, d.disc_hidden, d.lstm_hidden, d.embed)
        })
        .map_or("custom", |p| p.name());
    eprintln!(
        "trained {} ({}) to update {}: {} episodes, {} env steps ({:.0} steps/s over this run, {:.1} s); wrote {} and {}",
        state.model.method.name(),
        preset_name,
        state.update,
        state.episodes,
        state.env_steps,
        (state.env_steps - steps0) as f64 / secs.max(1e-9),
        secs,
        out.join("metrics.csv").display(),
        checkpoint_path(out).display()
    );
}
