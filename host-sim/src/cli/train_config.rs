//! `gman train`'s run configuration: the flags ([`TrainArgs`]), their defaults, the checks
//! of their ranges and combinations, and [`RunConfig`], the settings a run keeps, built from
//! the flags or from a checkpoint and validated by one function ([`RunConfig::validate`]);
//! resuming is [`RunConfig::resume`], one comparison over the tables of kept settings (the
//! model's, [`model_args::KEPT`], then the run's, [`KEPT`]). The model's flags are
//! [`ModelArgs`], shared with `gman eval` and `gman emd-report`.

use std::path::{Path, PathBuf};

use anyhow::{anyhow, bail, Context, Result};
use clap::builder::TypedValueParser;
use clap::{Args, ValueEnum};
use gman_core::navigator::memory::AdaptMode;
use gman_core::spec::{check_map_grid, MAX_GRID_SIDE};
use gman_host_sim::model::{InnerRule, Method, ModelSpec, NavModel};
use gman_host_sim::optim::adam::AdamConfig;
use gman_host_sim::sim::RewardKind;
use gman_host_sim::train::a3c::{A3cConfig, Objective};
use gman_host_sim::train::state::RunSettings;
use gman_host_sim::train::trainer::TrainOptions;

use super::args::{PresetArg, WorldArgs};
use super::model_args::{self, differs, kept, Kept, ModelArgs};

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
#[command(mut_args(ModelArgs::train_defaults))]
pub struct TrainArgs {
    /// World selection (training episodes come from the training scenes).
    #[command(flatten, next_help_heading = "World")]
    pub world: WorldArgs,
    /// Method (the rows of the paper's Tables 2 and 3).
    #[arg(help_heading = "Basics", long, value_parser = super::args::method(), default_value = "gman",
          long_help = format!("Method (the rows of the paper's Tables 2 and 3). Recipes, a preset with settings:\n{}", super::recipes::help()))]
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
    /// The model's settings (the paper's by default).
    #[command(flatten, next_help_heading = "Inner loop (adaptation)")]
    pub model: ModelArgs,
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
    /// Training objective: `a3c` (the paper's actor-critic loss) or `dagger` (imitation of
    /// the shortest-path oracle on the learner's own states: the imitation ceiling).
    #[arg(help_heading = "Optimisation", long, value_parser = super::args::named::<Objective>(), default_value = "a3c")]
    pub objective: Objective,
    /// The privileged-feature ceiling: the policy sees the target's true feature in the
    /// current scene in place of G's output (not exportable; methods without inner loop).
    #[arg(help_heading = "Model", long)]
    pub privileged_feature: bool,
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

/// Parses `--map`: `none` or `RxC` with 1 <= R, C <= [`MAX_GRID_SIDE`] (gman-core's
/// [`check_map_grid`]).
fn parse_map_grid(s: &str) -> std::result::Result<(usize, usize), String> {
    if s == "none" {
        return Ok((0, 0));
    }
    let bad = || {
        format!("expected `none` or ROWSxCOLS such as 3x3 (each 1..={MAX_GRID_SIDE}), got {s:?}")
    };
    let (r, c) = s.split_once(['x', 'X']).ok_or_else(bad)?;
    let (r, c): (usize, usize) = (r.parse().map_err(|_| bad())?, c.parse().map_err(|_| bad())?);
    check_map_grid(r, c).map_err(|_| bad())?;
    Ok((r, c))
}

/// The settings of a new run before its flags: the paper's ([`ModelSpec::paper`]) in the
/// preset's adaptation mode, whether the model adapts and its EMD from the method.
fn default_spec(a: &TrainArgs) -> ModelSpec {
    ModelSpec {
        adapt: a.method.adapts_at_eval(),
        emd: a.method.emd(),
        ..ModelSpec::paper(new_run_adapt_mode(a))
    }
}

/// The model's settings the flags ask for (those of a new run): [`default_spec`] with the
/// flags applied, checked (an error names the setting by its flag).
pub(super) fn model_spec(a: &TrainArgs) -> Result<ModelSpec> {
    let mut spec = default_spec(a);
    a.model.apply(&mut spec).map_err(|e| anyhow!("--{e}"))?;
    Ok(spec)
}

/// The adaptation mode of a new run: `--adapt-mode`, else Full for the paper preset and
/// Efficient (what a microcontroller runs) for mcu.
fn new_run_adapt_mode(a: &TrainArgs) -> AdaptMode {
    match (a.model.adapt_mode, a.preset) {
        (Some(m), _) => m,
        (None, PresetArg::Paper) => AdaptMode::Full,
        (None, _) => AdaptMode::Efficient,
    }
}

/// Combinations of a new run's flags that cannot work, refused before anything is loaded.
pub(super) fn check_train_flags(a: &TrainArgs) -> Result<()> {
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
        && new_run_adapt_mode(a) == AdaptMode::Efficient
    {
        bail!("--meta-order 2 is implemented for the Full adaptation mode; add --adapt-mode full");
    }
    // The commit delay only moves the update in time: the meta-gradient is the same recursion.
    // (The ranges are `RunConfig::validate`'s to report.)
    let mut spec = default_spec(a);
    a.model.write(&mut spec);
    let rule = InnerRule {
        commit_delay: 0,
        ..spec.inner_rule
    };
    if a.meta_order == 2 && a.method.adapts_in_training() && !rule.is_paper() {
        bail!("--meta-order 2 differentiates the paper's inner rule only (one D step, the gradient step, α1 = α2); use --meta-order 1 with --disc-lr, --disc-steps, --step-rule, --disc-head-reset, --adapt-loss, --reference-critic or --adapt-head-only");
    }
    Ok(())
}

/// The budget preset's update count and the outer learning rate, as the flags select them.
pub(super) fn updates_and_lr(a: &TrainArgs) -> (u64, f32) {
    let tiny = a.config == ConfigArg::Tiny;
    (
        a.updates.unwrap_or(if tiny { 300 } else { 4000 }),
        a.lr.unwrap_or(1e-3),
    )
}

/// The ranges of the flags that are not kept by a run (the update count and the checkpoint
/// interval of this invocation), checked before anything is loaded; the kept settings'
/// ranges are [`RunConfig::validate`]'s.
pub(super) fn check_train_numbers(a: &TrainArgs) -> Result<()> {
    if a.checkpoint_every == 0 {
        bail!("--checkpoint-every must be at least 1");
    }
    if a.updates.is_some_and(|n| n > MAX_UPDATES) || a.checkpoint_every > MAX_UPDATES {
        bail!("--updates and --checkpoint-every must be at most {MAX_UPDATES}");
    }
    Ok(())
}

/// Most `--workers` a run may have (one thread each).
const MAX_WORKERS: usize = 256;
/// Largest outer (Adam) learning rate `--lr` accepts.
const MAX_LR: f32 = 1.0;
/// Largest `--max-steps` (episode step limit).
pub const MAX_EPISODE_STEPS: u32 = 10_000;
/// Largest `--min-steps` (steps per worker and update, all held in memory for BPTT).
const MAX_MIN_STEPS: u32 = 10_000;
/// Largest `--cell-embed`.
const MAX_CELL_EMBED: usize = 1024;
/// Largest `--updates` (and `--checkpoint-every`): counters stay far from `u64::MAX`.
const MAX_UPDATES: u64 = 1 << 40;

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
pub(super) fn flag_options(a: &TrainArgs) -> TrainOptions {
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
            a3c: A3cConfig {
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

/// The settings a resumed run keeps: those of its model and its [`RunSettings`]. Built
/// from the flags ([`RunConfig::from_flags`]) or from a checkpoint ([`RunConfig::stored`]);
/// [`RunConfig::resume`] is the one comparison of the two.
#[derive(Clone, Debug)]
pub(super) struct RunConfig {
    method: Method,
    /// The map grid, `(0, 0)` without one.
    map: (usize, usize),
    /// The per-cell layer's width (`None`: not compared, a stored model without a map).
    cell_embed: Option<usize>,
    privileged_feature: bool,
    /// The adaptation mode (`None`: `--adapt-mode` not given, the preset's default).
    adapt_mode: Option<AdaptMode>,
    spec: ModelSpec,
    run: RunSettings,
}

/// The run's settings a resumed run keeps, in the order a resume checks them (after the
/// model's, [`model_args::KEPT`]).
#[rustfmt::skip]
const KEPT: &[Kept<RunConfig>] = &[
    kept!(RunConfig: "--method", "method", |c| Some(c.method)),
    kept!(RunConfig: "--adapt-mode", "adapt_mode", |c| c.adapt_mode),
    kept!(RunConfig: "--map", "map", |c| Some(c.map)),
    kept!(RunConfig: "--cell-embed", "cell_embed", |c| c.cell_embed),
    kept!(RunConfig: "--privileged-feature", "privileged_feature", |c| Some(c.privileged_feature)),
    kept!(RunConfig: "--objective", "objective", |c| Some(c.run.objective)),
    kept!(RunConfig: "--seed", "seed", |c| Some(c.run.seed)),
    kept!(RunConfig: "--workers (x ranks)", "workers", |c| Some(c.run.workers)),
    kept!(RunConfig: "--batch-envs", "batch_envs", |c| Some(c.run.batch_envs)),
    kept!(RunConfig: "--min-steps", "min_steps", |c| Some(c.run.min_steps)),
    kept!(RunConfig: "--min-start-actions", "min_start_actions", |c| Some(c.run.min_start_actions)),
    kept!(RunConfig: "--max-steps", "max_steps", |c| Some(c.run.max_steps)),
    kept!(RunConfig: "--meta-order", "meta_order", |c| Some(c.run.meta_order)),
    kept!(RunConfig: "--reward", "reward", |c| Some(c.run.reward)),
    kept!(RunConfig: "--lr", "lr", |c| Some(c.run.adam.lr)),
    kept!(RunConfig: "--entropy", "entropy", |c| Some(c.run.a3c.entropy)),
];

impl RunConfig {
    /// The settings the flags ask for (the model's checked, [`model_spec`]).
    pub(super) fn from_flags(a: &TrainArgs) -> Result<RunConfig> {
        Ok(RunConfig {
            method: a.method,
            map: a.map,
            cell_embed: Some(a.cell_embed),
            privileged_feature: a.privileged_feature,
            adapt_mode: a.model.adapt_mode,
            spec: model_spec(a)?,
            run: flag_options(a).run,
        })
    }

    /// The settings of a stored model and its stored [`RunSettings`].
    pub(super) fn stored(m: &NavModel, run: &RunSettings) -> RunConfig {
        let d = &m.dims;
        RunConfig {
            method: m.method,
            map: (d.map_rows, d.map_cols),
            cell_embed: (d.map_cells() > 0).then_some(d.cell_embed),
            privileged_feature: m.privileged,
            adapt_mode: Some(m.spec.adapt_mode),
            spec: m.spec(),
            run: run.clone(),
        }
    }

    /// The one check of the kept settings' ranges, for the flags of a run and for the
    /// settings a resumed run reads from its checkpoint (whose CRC says nothing about their
    /// sense). Each error names the setting by its flag.
    pub(super) fn validate(&self) -> Result<()> {
        self.spec.validate().map_err(|e| anyhow!("--{e}"))?;
        let r = &self.run;
        if r.workers == 0 || r.workers > MAX_WORKERS {
            bail!("--workers {} must be in 1..={MAX_WORKERS}", r.workers);
        }
        let max_b = gman_host_sim::train::lockstep::MAX_BATCH_ENVS;
        if r.batch_envs == 0 || r.batch_envs > max_b {
            bail!("--batch-envs {} must be in 1..={max_b}", r.batch_envs);
        }
        if !(1..=2).contains(&r.meta_order) {
            bail!("--meta-order must be 1 or 2, got {}", r.meta_order);
        }
        self.validate_optimisation()?;
        if r.max_steps == Some(0) || r.max_steps.is_some_and(|n| n > MAX_EPISODE_STEPS) {
            bail!(
                "--max-steps {} must be in 1..={MAX_EPISODE_STEPS} (default: 200 in living rooms, 100 elsewhere)",
                r.max_steps.unwrap_or(0)
            );
        }
        if r.min_steps == 0 || r.min_steps > MAX_MIN_STEPS {
            bail!(
                "--min-steps {} must be in 1..={MAX_MIN_STEPS} (steps per worker and update are buffered in memory)",
                r.min_steps
            );
        }
        self.validate_map()
    }

    /// [`RunConfig::validate`]'s part for the outer optimiser and the A3C loss.
    fn validate_optimisation(&self) -> Result<()> {
        let c = &self.run.a3c;
        if !(c.entropy.is_finite() && c.entropy >= 0.0) {
            bail!("--entropy {} must be finite and non-negative", c.entropy);
        }
        if !((0.0..=1.0).contains(&c.gamma) && (0.0..=1.0).contains(&c.tau)) {
            bail!("A3C gamma {} and tau {} must be in [0, 1]", c.gamma, c.tau);
        }
        if !(c.value_coef.is_finite() && c.value_coef >= 0.0) {
            bail!(
                "A3C value coefficient {} must be finite and non-negative",
                c.value_coef
            );
        }
        let lr = self.run.adam.lr;
        if !(lr.is_finite() && lr > 0.0 && lr <= MAX_LR) {
            bail!("--lr {lr} must be in (0, {MAX_LR}] (the paper's is 1e-3)");
        }
        self.run.adam.validate().map_err(|e| anyhow!("{e:#}"))
    }

    /// [`RunConfig::validate`]'s part for the map grid and the per-cell layer.
    fn validate_map(&self) -> Result<()> {
        let (rows, cols) = self.map;
        if (rows, cols) != (0, 0) && check_map_grid(rows, cols).is_err() {
            bail!(
                "--map {rows}x{cols}: a map grid has at most {MAX_GRID_SIDE} rows and {MAX_GRID_SIDE} columns"
            );
        }
        match self.cell_embed {
            Some(0) if rows > 0 => bail!("--cell-embed must be at least 1 with a --map"),
            Some(n) if n > MAX_CELL_EMBED => bail!(
                "--cell-embed {n} is more than {MAX_CELL_EMBED} (the reference's is 64; every map cell adds that many fusion inputs)"
            ),
            _ => Ok(()),
        }
    }

    /// Resuming a run whose checkpoint `ck` stored these settings: the stored settings win;
    /// a flag given explicitly (`explicit(id)`) must agree with its stored value, otherwise
    /// the resumed run would silently differ from an uninterrupted one; `--change-workers`
    /// lets the worker count change. The result is validated ([`RunConfig::validate`]) and
    /// its [`RunSettings`] returned, those the resumed run continues with.
    pub(super) fn resume(
        self,
        flags: &RunConfig,
        change_workers: bool,
        explicit: &dyn Fn(&str) -> bool,
        ck: &Path,
    ) -> Result<RunSettings> {
        let model = model_args::KEPT
            .iter()
            .map(|&(flag, id, value)| (flag, id, value(&flags.spec, &self.spec)));
        let run = KEPT
            .iter()
            .map(|&(flag, id, value)| (flag, id, value(flags, &self)));
        for (flag, id, differs) in model.chain(run) {
            if !explicit(id) || (change_workers && id == "workers") {
                continue;
            }
            if let Some((cli, stored)) = differs {
                bail!(
                    "{flag} {cli} conflicts with the resumed run, which was trained with {stored}; a \
                     resumed run keeps its own settings (omit the flag, or start a new run with --out)"
                );
            }
        }
        let mut kept = self;
        if change_workers {
            kept.run.workers = flags.run.workers;
        }
        kept.validate()
            .with_context(|| format!("{}: stored setting", ck.display()))?;
        Ok(kept.run)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use clap::{Args, Command};

    /// Every kept setting names a flag of `gman train` by its clap id (a wrong id would never
    /// be given explicitly, so its conflict would pass unnoticed), and no id appears twice.
    #[test]
    fn kept_settings_name_real_flags() {
        let cmd = TrainArgs::augment_args(Command::new("train"));
        let model = model_args::KEPT.iter().map(|k| (k.0, k.1));
        let kept: Vec<(&str, &str)> = model.chain(KEPT.iter().map(|k| (k.0, k.1))).collect();
        for (i, (flag, id)) in kept.iter().enumerate() {
            let arg = cmd
                .get_arguments()
                .find(|a| a.get_id() == *id)
                .unwrap_or_else(|| panic!("{flag}: no argument with id {id}"));
            let long = arg.get_long().expect("a long flag");
            assert!(flag.starts_with(&format!("--{long}")), "{flag} vs --{long}");
            assert!(kept[i + 1..].iter().all(|k| k.1 != *id), "{id} twice");
        }
    }
}
