//! `gman eval`: evaluate an agent on the episodes of a split (SR, SPL, EPA, DTS), one run or
//! the mean ± std over training seeds.

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{bail, Context, Result};
use clap::Args;
use gman_host_sim::sim::{
    evaluate, EpisodeLimits, EvalConfig, EvalReport, RewardKind, Split, World,
};

use super::args::WorldArgs;
use super::model_args::ModelArgs;
use super::models::{self, agent_factory};

/// `gman eval`.
#[derive(Debug, Args)]
#[command(mut_args(ModelArgs::eval_help))]
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
    #[arg(long, value_parser = super::args::method())]
    pub method: Option<gman_host_sim::model::Method>,
    /// Overrides of the model's settings (default: the model's own).
    #[command(flatten)]
    pub model: ModelArgs,
    /// The PS module of a PS variant's blob (`a3c-ps`, `gman-ps`, ...), which blobs do not
    /// carry: the `ps.ckpt` the run was trained with, or its training checkpoint.
    #[arg(long, value_name = "PS.ckpt")]
    pub ps: Option<PathBuf>,
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
    /// Write every episode's result here, one JSON object per line (scene, room, kind,
    /// target, success, path length, whether Done was called, the step the target was first
    /// visible at, DTS, ...), for analyses the summary does not hold.
    #[arg(long, value_name = "OUT.jsonl")]
    pub episodes_out: Option<PathBuf>,
    /// What the agent is told the target is: `true` (the episode's target) or `other` (a probe:
    /// another evaluation target of the same room type and kind, while success is judged on
    /// the true one; an agent that uses its target input loses success rate under it).
    #[arg(long, value_enum, default_value = "true")]
    pub target_input: TargetInput,
    /// No progress bar.
    #[arg(long)]
    pub quiet: bool,
}

/// `gman eval --target-input`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum TargetInput {
    /// The episode's target.
    True,
    /// Another evaluation target of the same room type and kind (a probe).
    Other,
}

impl EvalArgs {
    /// The model changes these arguments ask for.
    fn overrides(&self) -> models::ModelOverrides {
        models::ModelOverrides {
            method: self.method,
            model: self.model.clone(),
            ps: self.ps.clone(),
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

/// Checks `gman eval` flags: values that would give a wrong result are refused (`--episodes 0`,
/// a seed repeated in `--seeds`); flags without effect (the model overrides with a built-in
/// agent) are named in a warning, never silently dropped.
fn check_eval_flags(a: &EvalArgs) -> Result<()> {
    for (flag, v) in [
        ("--max-steps-living-room", a.max_steps_living_room),
        ("--max-steps-other", a.max_steps_other),
    ] {
        if v == 0 || v > super::train::MAX_EPISODE_STEPS {
            bail!(
                "{flag} {v} must be in 1..={} (an episode needs at least one step)",
                super::train::MAX_EPISODE_STEPS
            );
        }
    }
    if a.episodes == Some(0) {
        bail!("--episodes 0 evaluates nothing; give at least 1 (or omit it for every episode)");
    }
    let mut seen = std::collections::BTreeSet::new();
    if let Some(dup) = a.seeds.iter().find(|s| !seen.insert(**s)) {
        bail!("--seeds lists seed {dup} twice; each training seed must be averaged once");
    }
    if matches!(a.agent.as_str(), "random" | "oracle") {
        let method = a.method.is_some().then_some("--method");
        for flag in method.into_iter().chain(a.model.given()) {
            eprintln!(
                "warning: {flag} is ignored: it applies to model agents (a checkpoint or a weight blob), not to the built-in `{}` agent",
                a.agent
            );
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

/// Runs `gman eval`.
pub fn cmd_eval(a: EvalArgs) -> Result<()> {
    let split = Split::parse(&a.split)?;
    if split == Split::Train {
        bail!("split train has no official episodes; use --split val or --split test");
    }
    check_eval_flags(&a)?;
    if let Some(json) = &a.json {
        let agents: Vec<String> = if a.seeds.is_empty() {
            vec![a.agent.clone()]
        } else {
            a.seeds
                .iter()
                .map(|s| a.agent.replace("{seed}", &s.to_string()))
                .collect()
        };
        for p in &agents {
            super::args::refuse_output_over_inputs("--json", json, &[("--agent", Path::new(p))])?;
        }
    }
    if let Some(out) = &a.episodes_out {
        super::args::refuse_output_over_inputs(
            "--episodes-out",
            out,
            &[("--agent", Path::new(&a.agent))],
        )?;
    }
    if !a.seeds.is_empty() {
        if a.episodes_out.is_some() || a.target_input != TargetInput::True {
            bail!("--episodes-out and --target-input apply to one model; evaluate each seed on its own");
        }
        return eval_seeds(a, split);
    }
    let factory = agent_factory(&a.agent, a.seed, &a.overrides())?;
    let probe = a.target_input == TargetInput::Other;
    let factory = move |w: usize| -> Box<dyn gman_host_sim::sim::Agent + Send> {
        if probe {
            Box::new(gman_host_sim::sim::OtherTargetAgent::new(factory(w)))
        } else {
            factory(w)
        }
    };
    let t0 = Instant::now();
    let world = a.world.load()?;
    models::check_agent_for_world(&a.agent, &world, &a.overrides())?;
    let episodes = world.episodes(split, a.episodes)?;
    check_episodes(&world, &episodes, split, a.episodes)?;
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
    if let Some(path) = &a.episodes_out {
        write_episodes(path, &results)?;
    }
    check_failures(&report)
}

/// Writes every episode's result to `path`, one JSON object per line.
fn write_episodes(path: &Path, results: &[gman_host_sim::sim::EpisodeResult]) -> Result<()> {
    use std::io::Write;
    let file =
        std::fs::File::create(path).with_context(|| format!("cannot write {}", path.display()))?;
    let mut w = std::io::BufWriter::new(file);
    for r in results {
        serde_json::to_writer(&mut w, r)?;
        w.write_all(b"\n")?;
    }
    w.flush()
        .with_context(|| format!("cannot write {}", path.display()))
}

/// Reads the episodes' scenes now (an offline feature file with bad values is an error
/// naming it), then prints the counts of repeated episode lines and of episodes that cannot
/// succeed, if any ([`World::repeated_episodes_warning`],
/// [`World::unsolvable_episodes_warning`]).
fn check_episodes(
    world: &World,
    episodes: &[gman_host_sim::sim::EpisodeSpec],
    split: Split,
    per_file: Option<usize>,
) -> Result<()> {
    world.prepare_scenes(episodes.iter().map(|e| e.scene))?;
    if let Some(w) = world.repeated_episodes_warning(split, per_file)? {
        eprintln!("warning: {w}");
    }
    if let Some(w) = world.unsolvable_episodes_warning(episodes)? {
        eprintln!("warning: {w}");
    }
    Ok(())
}

/// `gman eval --seeds`: one evaluation per training seed, then mean ± std.
fn eval_seeds(a: EvalArgs, split: Split) -> Result<()> {
    if !a.agent.contains("{seed}") {
        bail!("--seeds needs an --agent path containing {{seed}}, e.g. runs/gman-seed{{seed}}/checkpoint.ckpt");
    }
    let t0 = Instant::now();
    let world = a.world.load()?;
    let episodes = world.episodes(split, a.episodes)?;
    check_episodes(&world, &episodes, split, a.episodes)?;
    let cfg = a.eval_config();
    let mut reports = Vec::new();
    for s in &a.seeds {
        let path = a.agent.replace("{seed}", &s.to_string());
        let factory = agent_factory(&path, a.seed, &a.overrides())?;
        models::check_agent_for_world(&path, &world, &a.overrides())?;
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
