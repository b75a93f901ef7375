//! `gman scene`: a top-down PNG map of a scene, optionally with an episode's path.

use std::path::PathBuf;

use anyhow::{bail, Result};
use clap::Args;
use gman_host_sim::sim::eval::drive;
use gman_host_sim::sim::{EvalConfig, Split};
use gman_render::draw_scene;

use super::args::WorldArgs;
use super::models::agent_factory;

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

/// Runs `gman scene`.
pub fn cmd_scene(a: SceneArgs) -> Result<()> {
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
    draw_scene(&world, scene, goal, &path, &a.png, None)?;
    eprintln!("wrote {}", a.png.display());
    Ok(())
}
