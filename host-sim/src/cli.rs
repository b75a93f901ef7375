//! Command line of the `gman` binary.
//!
//! Without `--data`, every command uses the built-in synthetic demo world
//! ([`gman_host_sim::sim::synthetic`]); `--data DIR` switches to the real iTHOR floor plans and
//! the official GMAN episodes.

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{bail, Context, Result};
use clap::{Args, Parser, Subcommand};
use gman_host_sim::sim::eval::{drive, AgentFactory};
use gman_host_sim::sim::render::draw_scene;
use gman_host_sim::sim::{
    evaluate, EpisodeLimits, EvalConfig, EvalReport, OracleAgent, RandomAgent, RewardKind, Split,
    World, DEFAULT_WORLD_SEED,
};

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
}

/// Options that choose the world.
#[derive(Debug, Args, Clone)]
pub struct WorldArgs {
    /// Data directory (attributes.json, scenes/<split>/, episodes/<split>/). Without it the
    /// built-in synthetic demo world is used.
    #[arg(long, value_name = "DIR")]
    pub data: Option<PathBuf>,
    /// World seed: placement of objects without positions, feature model, scene styles (and the
    /// whole synthetic world).
    #[arg(long, default_value_t = DEFAULT_WORLD_SEED)]
    pub world_seed: u64,
}

impl WorldArgs {
    /// Loads the chosen world.
    pub fn load(&self) -> Result<World> {
        match &self.data {
            Some(dir) => World::load_with_seed(dir, self.world_seed),
            None => {
                eprintln!(
                    "note: no --data given, using the built-in synthetic demo world (seed {})",
                    self.world_seed
                );
                Ok(World::synthetic(self.world_seed))
            }
        }
    }
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
    /// Agent: `random`, `oracle`, or a model file.
    #[arg(long, default_value = "random")]
    pub agent: String,
    /// At most N episodes per episode file (file order).
    #[arg(long, value_name = "N")]
    pub episodes: Option<usize>,
    /// Seed of the agent's randomness.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
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

/// Runs a parsed command line.
pub fn run(cli: Cli) -> Result<()> {
    match cli.command {
        Commands::Eval(a) => eval(a),
        Commands::Scene(a) => scene(a),
    }
}

/// A built-in agent factory by name; a clear error for model files (not supported yet).
pub fn agent_factory(name: &str, seed: u64) -> Result<AgentFactory> {
    match name {
        "random" => Ok(Box::new(move |_| Box::new(RandomAgent::new(seed)))),
        "oracle" => Ok(Box::new(|_| Box::new(OracleAgent))),
        other => {
            let p = Path::new(other);
            if p.exists() {
                bail!("agent {other}: model-file agents are not supported yet (use --agent random or --agent oracle)")
            }
            bail!("agent {other}: not `random` or `oracle`, and no such model file")
        }
    }
}

fn eval(a: EvalArgs) -> Result<()> {
    let split = Split::parse(&a.split)?;
    if split == Split::Train {
        bail!("split train has no official episodes; use --split val or --split test");
    }
    let factory = agent_factory(&a.agent, a.seed)?;
    let t0 = Instant::now();
    let world = a.world.load()?;
    let episodes = world.episodes(split, a.episodes)?;
    let cfg = EvalConfig {
        reward: a.reward,
        limits: EpisodeLimits {
            living_room: a.max_steps_living_room,
            other: a.max_steps_other,
        },
        progress: !a.quiet,
    };
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
            let factory = agent_factory(&a.agent, a.seed)?;
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
