//! Command line of the `gman` binary.
//!
//! Without `--data`, every command uses the built-in synthetic demo world
//! ([`gman_host_sim::sim::synthetic`]); `--data DIR` switches to the real iTHOR floor plans and
//! the official GMAN episodes.

pub mod args;
pub mod demo;
pub mod emd_report;
pub mod export;
pub mod inspect;
pub mod models;
pub mod plot;
pub mod table;
pub mod train;

pub use args::{PresetArg, WorldArgs};

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{bail, Context, Result};
use clap::{Args, Parser, Subcommand};
use gman_host_sim::sim::eval::{drive, AgentFactory};
use gman_host_sim::sim::render::draw_scene;
use gman_host_sim::sim::{
    evaluate, EpisodeLimits, EvalConfig, EvalReport, OracleAgent, RandomAgent, RewardKind, Split,
};
use gman_host_sim::train::fg::{self, FgCollectConfig, FgTrainConfig};
use gman_host_sim::train::ps::{self, PsDataConfig, PsTrainConfig};

/// gman: GMAN (ECCV 2022) unseen-object navigation in Rust.
#[derive(Debug, Parser)]
#[command(name = "gman", version, about)]
pub struct Cli {
    /// The command to run.
    #[command(subcommand)]
    pub command: Commands,
}

/// Subcommands.
#[derive(Debug, Subcommand)]
pub enum Commands {
    /// Evaluate an agent on the episodes of a split (SR, SPL, EPA, DTS).
    Eval(EvalArgs),
    /// Draw a top-down PNG map of a scene (and optionally an episode's path).
    Scene(SceneArgs),
    /// Pre-train the feature generator G(SE(y), z) on seen-object features of the training
    /// scenes (conditional WGAN-GP, paper Sec. 4.1); writes OUT/fg.ckpt and OUT/fg_report.json.
    PretrainFg(PretrainFgArgs),
    /// Pre-train the PS module (observation -> semantic embedding of the objects in view) on
    /// training-scene views; writes OUT/ps.ckpt and OUT/ps_report.json.
    PretrainPs(PretrainPsArgs),
    /// Train a navigation method (A3C baselines, GMAN): writes RUN_DIR/metrics.csv and
    /// RUN_DIR/checkpoint.ckpt; `--resume RUN_DIR` continues a run exactly.
    Train(train::TrainArgs),
    /// Export a trained checkpoint as a gman-core weight blob (int8 or f32).
    Export(export::ExportArgs),
    /// Print a weight blob's header, tensors, quantisation and size (validates the checksum).
    Inspect(inspect::InspectArgs),
    /// Draw learning curves of training runs into a PNG.
    Plot(plot::PlotArgs),
    /// Fig. 3 as a measurement: how far a GMAN model's inner loop moves G toward the
    /// target's true feature in val scenes, with the picture (PCA of two scenes).
    EmdReport(emd_report::EmdReportArgs),
    /// Print the paper's table layout (mean ± std) from evaluation JSON files.
    Table(table::TableArgs),
    /// Quick start: pre-train G, train A3C+FG and GMAN briefly, evaluate them against random.
    Demo(demo::DemoArgs),
    /// Single-thread benchmarks: navigator step/adaptation latency against this machine's
    /// measured bandwidth and FMA peak, training throughput, firmware instruction counts.
    Bench(crate::cli_bench::BenchArgs),
    /// Write a small data directory in the AI2THOR offline format of SAVN/GMAN (HDF5 feature
    /// maps, state graph, visibility; made-up data) for trying `--data` on it.
    #[cfg(feature = "offline")]
    MakeOfflineFixture(MakeOfflineFixtureArgs),
}

/// `gman make-offline-fixture`.
#[cfg(feature = "offline")]
#[derive(Debug, Args)]
pub struct MakeOfflineFixtureArgs {
    /// Output directory (created if missing).
    #[arg(long, value_name = "DIR")]
    pub out: PathBuf,
    /// Seed of the attribute vectors and feature values.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
}

/// `gman pretrain-fg`.
#[derive(Debug, Args)]
pub struct PretrainFgArgs {
    /// World selection.
    #[command(flatten)]
    pub world: WorldArgs,
    /// Network sizes.
    #[arg(long, value_enum, default_value = "mcu")]
    pub preset: PresetArg,
    /// Generator steps (default: 1500 for mcu, 300 for paper).
    #[arg(long, value_name = "N")]
    pub iters: Option<usize>,
    /// Seed of initialisation, batches and noise.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Output directory (created if missing).
    #[arg(long, value_name = "DIR")]
    pub out: PathBuf,
    /// Samples per step.
    #[arg(long, default_value_t = 64)]
    pub batch: usize,
    /// Critic steps per generator step.
    #[arg(long, default_value_t = 5)]
    pub n_critic: usize,
    /// Gradient-penalty coefficient.
    #[arg(long, default_value_t = 10.0)]
    pub lambda: f32,
    /// Adam learning rate (both networks).
    #[arg(long, default_value_t = 5e-4)]
    pub lr: f32,
    /// Adam beta1 (both networks).
    #[arg(long, default_value_t = 0.5)]
    pub beta1: f32,
    /// Weight of the feature-regression term (mean squared distance of G(a, z) to the mean
    /// training feature of the category); 0 = pure WGAN-GP.
    #[arg(long, default_value_t = fg::DEFAULT_REG)]
    pub reg: f32,
    /// Dominant views per object instance.
    #[arg(long, default_value_t = 6)]
    pub views_per_instance: usize,
    /// Minimum share of the view the object must fill.
    #[arg(long, default_value_t = 0.2)]
    pub min_weight: f32,
    /// Share of each seen category's training-scene instances held out for the report.
    #[arg(long, default_value_t = 0.2)]
    pub holdout: f32,
    /// No progress bar.
    #[arg(long)]
    pub quiet: bool,
}

/// `gman pretrain-ps`.
#[derive(Debug, Args)]
pub struct PretrainPsArgs {
    /// World selection.
    #[command(flatten)]
    pub world: WorldArgs,
    /// Adam steps.
    #[arg(long, default_value_t = 500, value_name = "N")]
    pub iters: usize,
    /// Seed of initialisation, view sampling and batches.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Output directory (created if missing).
    #[arg(long, value_name = "DIR")]
    pub out: PathBuf,
    /// Hidden width of the PS network.
    #[arg(long, default_value_t = 128)]
    pub hidden: usize,
    /// Views per step.
    #[arg(long, default_value_t = 64)]
    pub batch: usize,
    /// Adam learning rate.
    #[arg(long, default_value_t = 1e-3)]
    pub lr: f32,
    /// Distinct training-scene views sampled (training plus held out).
    #[arg(long, default_value_t = 40_000)]
    pub views: usize,
    /// Share of the sampled training-scene views held out for the report.
    #[arg(long, default_value_t = 0.1)]
    pub holdout: f32,
    /// Distinct val-scene views for the report.
    #[arg(long, default_value_t = 8_000)]
    pub val_views: usize,
    /// No progress bar.
    #[arg(long)]
    pub quiet: bool,
}

/// `gman eval`.
#[derive(Debug, Args)]
pub struct EvalArgs {
    /// World selection.
    #[command(flatten)]
    pub world: WorldArgs,
    /// Split to evaluate (val or test).
    #[arg(long, default_value = "val")]
    pub split: String,
    /// Agent: `random`, `oracle`, or a model file (a training checkpoint, or a weight blob
    /// evaluated through gman-core as on the device).
    #[arg(long, default_value = "random")]
    pub agent: String,
    /// Treat a model file as this method (e.g. evaluate an `a3c-fg` checkpoint as
    /// `gman-nometa`: adversarial adaptation at test time only).
    #[arg(long, value_enum)]
    pub method: Option<gman_host_sim::nav::model::Method>,
    /// Override the model's inner-loop rate α (α1 = α2) at evaluation (checkpoints store the
    /// rate they were trained with; blobs do not and default to the paper's 1e-4).
    #[arg(long, value_name = "ALPHA")]
    pub inner_lr: Option<f32>,
    /// Override the cap on inner updates per episode at evaluation (default: the model's, 4).
    #[arg(long, value_name = "N")]
    pub max_inner: Option<u32>,
    /// At most N episodes per episode file (file order).
    #[arg(long, value_name = "N")]
    pub episodes: Option<usize>,
    /// Seed of the agent's randomness.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Average several training runs: the model path must contain `{seed}`, replaced by each
    /// of these (e.g. `--agent runs/gman-seed{seed}/checkpoint.ckpt --seeds 1,2,3`); prints
    /// and writes mean ± sample standard deviation like the paper.
    #[arg(long, value_delimiter = ',', value_name = "S1,S2,..")]
    pub seeds: Vec<u64>,
    /// Write the JSON report here.
    #[arg(long, value_name = "OUT.json")]
    pub json: Option<PathBuf>,
    /// Reward (navigation, distance, similarity, mixed); only affects reported returns.
    #[arg(long, default_value = "mixed")]
    pub reward: RewardKind,
    /// Step limit in living rooms.
    #[arg(long, default_value_t = 200)]
    pub max_steps_living_room: u32,
    /// Step limit in other rooms.
    #[arg(long, default_value_t = 100)]
    pub max_steps_other: u32,
    /// No progress bar.
    #[arg(long)]
    pub quiet: bool,
}

impl EvalArgs {
    /// The model changes these arguments ask for.
    fn overrides(&self) -> models::ModelOverrides {
        models::ModelOverrides {
            method: self.method,
            inner_lr: self.inner_lr,
            max_inner: self.max_inner,
        }
    }

    /// The evaluation settings these arguments ask for.
    fn eval_config(&self) -> EvalConfig {
        EvalConfig {
            reward: self.reward,
            limits: EpisodeLimits {
                living_room: self.max_steps_living_room,
                other: self.max_steps_other,
            },
            progress: !self.quiet,
        }
    }
}

/// `gman scene`.
#[derive(Debug, Args)]
pub struct SceneArgs {
    /// World selection.
    #[command(flatten)]
    pub world: WorldArgs,
    /// Split of the scene.
    #[arg(long, default_value = "val")]
    pub split: String,
    /// Scene name, e.g. FloorPlan22 (lists the split's scenes when unknown).
    #[arg(long)]
    pub scene: String,
    /// Output PNG.
    #[arg(long, value_name = "OUT.png")]
    pub png: PathBuf,
    /// Draw the path of the K-th episode (0-based, file order) of this scene.
    #[arg(long, value_name = "K")]
    pub episode: Option<usize>,
    /// Agent that walks the episode: `oracle` or `random`.
    #[arg(long, default_value = "oracle")]
    pub agent: String,
    /// Seed of the random agent.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
}

/// Runs a parsed command line (`matches` tells which flags were given explicitly).
pub fn run(cli: Cli, matches: &clap::ArgMatches) -> Result<()> {
    match cli.command {
        Commands::Eval(a) => eval(a),
        Commands::Scene(a) => scene(a),
        Commands::PretrainFg(a) => pretrain_fg(a),
        Commands::PretrainPs(a) => pretrain_ps(a),
        Commands::Train(a) => {
            let sub = matches.subcommand_matches("train");
            let explicit = |id: &str| {
                sub.and_then(|m| m.value_source(id)) == Some(clap::parser::ValueSource::CommandLine)
            };
            train::cmd_train(a, &explicit)
        }
        Commands::Export(a) => export::cmd_export(a),
        Commands::Inspect(a) => inspect::cmd_inspect(a),
        Commands::Plot(a) => plot::cmd_plot(a),
        Commands::EmdReport(a) => emd_report::cmd_emd_report(a),
        Commands::Table(a) => table::cmd_table(a),
        Commands::Demo(a) => demo::cmd_demo(a),
        Commands::Bench(a) => crate::cli_bench::cmd_bench(a),
        #[cfg(feature = "offline")]
        Commands::MakeOfflineFixture(a) => {
            let info = gman_host_sim::sim::offline::fixture::write_fixture(&a.out, a.seed)?;
            println!(
                "wrote {}: scenes {}, {} val episodes",
                a.out.display(),
                info.scenes.join(", "),
                info.episodes
            );
            Ok(())
        }
    }
}

/// A built-in agent factory by name; a clear error for model files (not supported yet).
pub fn agent_factory(name: &str, seed: u64, ov: &models::ModelOverrides) -> Result<AgentFactory> {
    match name {
        "random" => Ok(Box::new(move |_| Box::new(RandomAgent::new(seed)))),
        "oracle" => Ok(Box::new(|_| Box::new(OracleAgent))),
        other => {
            let p = Path::new(other);
            if p.exists() {
                return Ok(models::model_factory(p, ov)?.0);
            }
            bail!("agent {other}: not `random` or `oracle`, and no such model file")
        }
    }
}

/// Checks `gman eval` flags: values that would give a wrong result are refused (`--episodes 0`,
/// a seed repeated in `--seeds`); flags without effect (the model overrides with a built-in
/// agent) are named in a warning, never silently dropped.
fn check_eval_flags(a: &EvalArgs) -> Result<()> {
    if a.episodes == Some(0) {
        bail!("--episodes 0 evaluates nothing; give at least 1 (or omit it for every episode)");
    }
    let mut seen = std::collections::BTreeSet::new();
    if let Some(dup) = a.seeds.iter().find(|s| !seen.insert(**s)) {
        bail!("--seeds lists seed {dup} twice; each training seed must be averaged once");
    }
    if matches!(a.agent.as_str(), "random" | "oracle") {
        for (flag, given) in [
            ("--method", a.method.is_some()),
            ("--inner-lr", a.inner_lr.is_some()),
            ("--max-inner", a.max_inner.is_some()),
        ] {
            if given {
                eprintln!(
                    "warning: {flag} is ignored: it applies to model agents (a checkpoint or a weight blob), not to the built-in `{}` agent",
                    a.agent
                );
            }
        }
    }
    Ok(())
}

/// Prints the first failed episodes of `report` to stderr and returns an error when any
/// episode failed (after the table and the JSON were written, so that they can be read).
fn check_failures(report: &EvalReport) -> Result<()> {
    if report.failed_episodes == 0 {
        return Ok(());
    }
    for f in report.failures.iter().take(3) {
        eprintln!(
            "warning: episode {} ({}) ended early: {}",
            f.index, f.scene, f.error
        );
    }
    bail!(
        "{} of {} episodes of {} ended early with an error; the metrics above count them as they ended and are not a valid result",
        report.failed_episodes,
        report.episodes,
        report.agent
    )
}

fn eval(a: EvalArgs) -> Result<()> {
    let split = Split::parse(&a.split)?;
    if split == Split::Train {
        bail!("split train has no official episodes; use --split val or --split test");
    }
    check_eval_flags(&a)?;
    if !a.seeds.is_empty() {
        return eval_seeds(a, split);
    }
    let factory = agent_factory(&a.agent, a.seed, &a.overrides())?;
    let t0 = Instant::now();
    let world = a.world.load()?;
    let episodes = world.episodes(split, a.episodes)?;
    let cfg = a.eval_config();
    let results = evaluate(&world, &episodes, |w| factory(w), &cfg);
    let report = EvalReport::new(split.name(), &a.agent, &results);
    print!("{}", report.table());
    eprintln!(
        "evaluated {} episodes in {:.1} s",
        results.len(),
        t0.elapsed().as_secs_f64()
    );
    if let Some(path) = &a.json {
        let text = serde_json::to_string_pretty(&report)?;
        std::fs::write(path, text + "\n")
            .with_context(|| format!("cannot write {}", path.display()))?;
    }
    check_failures(&report)
}

/// `gman eval --seeds`: one evaluation per training seed, then mean ± std.
fn eval_seeds(a: EvalArgs, split: Split) -> Result<()> {
    if !a.agent.contains("{seed}") {
        bail!("--seeds needs an --agent path containing {{seed}}, e.g. runs/gman-seed{{seed}}/checkpoint.ckpt");
    }
    let t0 = Instant::now();
    let world = a.world.load()?;
    let episodes = world.episodes(split, a.episodes)?;
    let cfg = a.eval_config();
    let mut reports = Vec::new();
    for s in &a.seeds {
        let path = a.agent.replace("{seed}", &s.to_string());
        let factory = agent_factory(&path, a.seed, &a.overrides())?;
        let results = evaluate(&world, &episodes, |w| factory(w), &cfg);
        let report = EvalReport::new(split.name(), &path, &results);
        print!("{}", report.table());
        reports.push(report);
    }
    let failed: usize = reports.iter().map(|r| r.failed_episodes).sum();
    let mut agg = serde_json::Map::new();
    let mut std = serde_json::Map::new();
    println!("mean ± std over seeds {:?}:", a.seeds);
    for kind in ["unseen", "seen"] {
        let mut m = serde_json::Map::new();
        let mut sd = serde_json::Map::new();
        let mut line = format!("  {kind:<7}");
        for metric in ["sr", "spl", "epa", "dts"] {
            let v: Vec<f64> = reports
                .iter()
                .map(|r| {
                    let k = if kind == "seen" {
                        &r.results.seen
                    } else {
                        &r.results.unseen
                    };
                    match metric {
                        "sr" => k.sr,
                        "spl" => k.spl,
                        "epa" => k.epa,
                        _ => k.dts,
                    }
                })
                .collect();
            let n = v.len() as f64;
            let mean = v.iter().sum::<f64>() / n;
            let s = if v.len() > 1 {
                (v.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / (n - 1.0)).sqrt()
            } else {
                0.0
            };
            line.push_str(&format!(" {metric} {mean:.2}±{s:.2}"));
            m.insert(metric.into(), mean.into());
            sd.insert(metric.into(), s.into());
        }
        let eps = reports
            .first()
            .map(|r| {
                if kind == "seen" {
                    r.results.seen.episodes
                } else {
                    r.results.unseen.episodes
                }
            })
            .unwrap_or(0);
        m.insert("episodes".into(), eps.into());
        println!("{line}");
        agg.insert(kind.into(), m.into());
        std.insert(kind.into(), sd.into());
    }
    eprintln!(
        "evaluated {} runs in {:.1} s",
        reports.len(),
        t0.elapsed().as_secs_f64()
    );
    if let Some(path) = &a.json {
        let j = serde_json::json!({
            "split": split.name(),
            "agent": a.agent,
            "seeds": a.seeds,
            "episodes": episodes.len(),
            "results": agg,
            "std": std,
            "failed_episodes": failed,
            "runs": reports,
        });
        std::fs::write(path, serde_json::to_string_pretty(&j)? + "\n")
            .with_context(|| format!("cannot write {}", path.display()))?;
    }
    for r in &reports {
        check_failures(r)?;
    }
    Ok(())
}

fn scene(a: SceneArgs) -> Result<()> {
    let split = Split::parse(&a.split)?;
    let world = a.world.load()?;
    let ids = world.split_scenes(split)?;
    let Some(scene) = world.scene_id(&a.scene).filter(|s| ids.contains(s)) else {
        let names: Vec<&str> = ids.iter().map(|&s| world.scenes[s].name.as_str()).collect();
        bail!(
            "unknown scene {:?} in split {split}; available: {}",
            a.scene,
            names.join(", ")
        );
    };
    let (goal, path) = match a.episode {
        None => (None, Vec::new()),
        Some(k) => {
            let eps = world.episodes(split, None)?;
            let mine: Vec<_> = eps.iter().filter(|e| e.scene == scene).collect();
            let Some(spec) = mine.get(k) else {
                bail!(
                    "scene {} has {} episodes in split {split}; --episode {k} is out of range",
                    a.scene,
                    mine.len()
                );
            };
            let factory = agent_factory(&a.agent, a.seed, &Default::default())?;
            let mut agent = factory(0);
            let cfg = EvalConfig::default();
            let mut env = gman_host_sim::sim::Env::new(
                &world,
                spec,
                cfg.reward,
                cfg.limits.for_room(spec.room),
            );
            env.record_trajectory(true);
            drive(&mut env, spec, agent.as_mut());
            let m = env.metrics();
            eprintln!(
                "episode {k} of {}: target {}, success {}, path {} actions, shortest {:?}",
                a.scene,
                world.category_name(spec.target),
                m.success,
                m.path_length,
                m.shortest_path_length
            );
            (Some(spec.target), env.trajectory().to_vec())
        }
    };
    draw_scene(&world, scene, goal, &path, &a.png)?;
    eprintln!("wrote {}", a.png.display());
    Ok(())
}

fn check_unit(name: &str, v: f32) -> Result<()> {
    if !(0.0..1.0).contains(&v) {
        bail!("--{name} must be in [0, 1), got {v}");
    }
    Ok(())
}

fn check_positive(name: &str, v: f32) -> Result<()> {
    if !(v.is_finite() && v > 0.0) {
        bail!("--{name} must be a positive number, got {v}");
    }
    Ok(())
}

fn pretrain_fg(a: PretrainFgArgs) -> Result<()> {
    let dims = a.preset.dims();
    let iters = a.iters.unwrap_or(match a.preset {
        PresetArg::Mcu => 1500,
        PresetArg::Paper => 300,
    });
    if a.batch == 0 || a.n_critic == 0 || a.views_per_instance == 0 {
        bail!("--batch, --n-critic and --views-per-instance must be at least 1");
    }
    check_positive("lr", a.lr)?;
    check_unit("beta1", a.beta1)?;
    check_unit("holdout", a.holdout)?;
    if !(a.lambda.is_finite() && a.lambda >= 0.0 && a.reg.is_finite() && a.reg >= 0.0) {
        bail!("--lambda and --reg must be finite and non-negative");
    }
    if !(0.0..=1.0).contains(&a.min_weight) {
        bail!("--min-weight must be in [0, 1], got {}", a.min_weight);
    }
    let t0 = Instant::now();
    let world = a.world.load()?;
    let collect = FgCollectConfig {
        views_per_instance: a.views_per_instance,
        min_weight: a.min_weight,
        holdout: a.holdout,
        seed: a.seed,
    };
    let mut cfg = FgTrainConfig::new(iters, a.seed);
    cfg.batch = a.batch;
    cfg.n_critic = a.n_critic;
    cfg.lambda = a.lambda;
    cfg.reg = a.reg;
    for adam in [&mut cfg.adam_gen, &mut cfg.adam_critic] {
        adam.lr = a.lr;
        adam.beta1 = a.beta1;
    }
    cfg.progress = !a.quiet;
    let report = fg::run_pretrain_fg(&world, a.preset.name(), &dims, &collect, &cfg, &a.out)?;
    print!("{}", fg::report_table(&report));
    eprintln!(
        "wrote {} and {} ({:.1} s in all)",
        a.out.join("fg.ckpt").display(),
        a.out.join("fg_report.json").display(),
        t0.elapsed().as_secs_f64()
    );
    Ok(())
}

fn pretrain_ps(a: PretrainPsArgs) -> Result<()> {
    if a.batch == 0 || a.hidden == 0 || a.views == 0 {
        bail!("--batch, --hidden and --views must be at least 1");
    }
    check_positive("lr", a.lr)?;
    check_unit("holdout", a.holdout)?;
    let t0 = Instant::now();
    let world = a.world.load()?;
    let collect = PsDataConfig {
        train_views: a.views,
        heldout: a.holdout,
        val_views: a.val_views,
        seed: a.seed,
    };
    let mut cfg = PsTrainConfig {
        hidden: a.hidden,
        iters: a.iters,
        batch: a.batch,
        seed: a.seed,
        progress: !a.quiet,
        ..PsTrainConfig::default()
    };
    cfg.adam.lr = a.lr;
    let report = ps::run_pretrain_ps(&world, &collect, &cfg, &a.out)?;
    print!("{}", ps::report_table(&report));
    eprintln!(
        "wrote {} and {} ({:.1} s in all)",
        a.out.join("ps.ckpt").display(),
        a.out.join("ps_report.json").display(),
        t0.elapsed().as_secs_f64()
    );
    Ok(())
}
