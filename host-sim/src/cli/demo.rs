//! `gman demo`: the quick start (pre-train G, train A3C+FG and GMAN briefly, evaluate).

use std::path::PathBuf;
use std::sync::Arc;
use std::time::Instant;

use anyhow::{Context, Result};
use clap::Args;
use gman_host_sim::nav::agent::NavAgent;
use gman_host_sim::nav::model::{Method, NavModel};
use gman_host_sim::nav::trainer::{checkpoint_path, train, RunSettings, TrainOptions, TrainState};
use gman_host_sim::sim::RewardKind;
use gman_host_sim::train::adam::AdamConfig;
use gman_host_sim::train::fg::{self};

use super::args::{PresetArg, WorldArgs};

use super::train::ensure_fg;

/// `gman demo`.
#[derive(Debug, Args)]
pub struct DemoArgs {
    /// World selection.
    #[command(flatten)]
    pub world: WorldArgs,
    /// Output directory.
    #[arg(long, default_value = "runs/demo")]
    pub out: PathBuf,
    /// Training updates per method.
    #[arg(long, default_value_t = 1000)]
    pub updates: u64,
    /// Official episodes per file evaluated (8 files).
    #[arg(long, default_value_t = 50)]
    pub episodes: usize,
}

/// `gman demo`: pre-train G, train A3C+FG and GMAN briefly, evaluate them and a random agent.
pub fn cmd_demo(a: DemoArgs) -> Result<()> {
    let t0 = Instant::now();
    let world = a.world.load()?;
    std::fs::create_dir_all(&a.out).with_context(|| format!("creating {}", a.out.display()))?;
    let fg_path = ensure_fg(&world, PresetArg::Mcu, None, &a.out.join("fg"), true, 1)?;
    let gen = fg::load_generator(&fg_path, &gman_core::Dims::MCU)?;
    let split = gman_host_sim::sim::Split::Val;
    let episodes = world.episodes(split, Some(a.episodes))?;
    let cfg = gman_host_sim::sim::EvalConfig {
        reward: RewardKind::Mixed,
        limits: gman_host_sim::sim::EpisodeLimits::default(),
        progress: true,
    };
    let mut table = String::new();
    let rnd = gman_host_sim::sim::evaluate(
        &world,
        &episodes,
        |_| Box::new(gman_host_sim::sim::RandomAgent::new(0)),
        &cfg,
    );
    table.push_str(&gman_host_sim::sim::EvalReport::new(split.name(), "random", &rnd).table());
    for method in [Method::A3cFg, Method::Gman] {
        let dir = a.out.join(method.name());
        let state_path = checkpoint_path(&dir);
        let mut state = if state_path.exists() {
            TrainState::load(&state_path)?
        } else {
            // The setting of the README's results: the mcu preset with a 3 x 3 spatial map, the
            // inner loop in the device's Efficient mode.
            let dims = gman_core::Dims::MCU.with_map(3, 3, 8);
            let mut model = NavModel::init(method, dims, 1, Some(&gen), None)?;
            model.adapt_mode = gman_core::memory::AdaptMode::Efficient;
            TrainState::new(
                model,
                AdamConfig {
                    lr: 1e-3,
                    ..AdamConfig::default()
                },
            )
        };
        let opts = TrainOptions {
            updates: a.updates,
            run: RunSettings {
                adam: AdamConfig {
                    lr: 1e-3,
                    ..AdamConfig::default()
                },
                ..RunSettings::default()
            },
            checkpoint_every: 100,
            out: dir.clone(),
            progress: true,
        };
        train(&world, &opts, &mut state)?;
        let model = Arc::new(state.model);
        let res = gman_host_sim::sim::evaluate(
            &world,
            &episodes,
            |_| Box::new(NavAgent::new(model.clone())),
            &cfg,
        );
        table.push_str(
            &gman_host_sim::sim::EvalReport::new(split.name(), method.name(), &res).table(),
        );
    }
    println!("{table}");
    println!(
        "demo finished in {:.0} s; runs in {} (try `gman plot --run {}/gman --png curve.png`)",
        t0.elapsed().as_secs_f64(),
        a.out.display(),
        a.out.display()
    );
    Ok(())
}
