//! When do agents stop? The early-Done pattern measured on the official val episodes.
//!
//! For each model (or `random`), over all episodes: the share that end by Done rather than
//! by the step limit, the distribution of the step at which Done is issued, and the success
//! rate of Done calls by that step. With the shortest-path lengths of the same episodes, this
//! says whether stopping early is a learnt shortcut or merely reflects short episodes.
//!
//! `cargo run --release -p gman-host-sim --example done_analysis -- DATA_DIR EPISODES_PER_FILE MODEL|random...`

use std::path::Path;
use std::sync::Arc;

use anyhow::{bail, Result};
use gman_host_sim::eval::agent::NavAgent;
use gman_host_sim::model::load_model;
use gman_host_sim::sim::{
    evaluate, Agent, EpisodeLimits, EvalConfig, RandomAgent, RewardKind, Split, World,
};

fn main() -> Result<()> {
    let args: Vec<String> = std::env::args().collect();
    if args.len() < 4 {
        bail!("usage: done_analysis DATA_DIR EPISODES_PER_FILE MODEL|random...");
    }
    let world = World::load(Path::new(&args[1]))?;
    let per_file: usize = args[2].parse()?;
    let episodes = world.episodes(Split::Val, Some(per_file))?;
    let limits = EpisodeLimits::default();
    let cfg = EvalConfig {
        reward: RewardKind::Mixed,
        limits,
        progress: false,
    };
    let shortest: Vec<u32> = {
        let r = evaluate(
            &world,
            &episodes,
            |_| Box::new(gman_host_sim::sim::OracleAgent) as Box<dyn Agent + Send>,
            &cfg,
        );
        r.iter().map(|e| e.metrics.path_length).collect()
    };
    let mut sorted = shortest.clone();
    sorted.sort_unstable();
    println!(
        "{} val episodes; shortest path (actions incl. Done): median {}, 10th percentile {}, 90th {}",
        episodes.len(),
        sorted[sorted.len() / 2],
        sorted[sorted.len() / 10],
        sorted[sorted.len() * 9 / 10]
    );
    println!("| agent | ends by Done | median Done step | Done within 5 steps | Done within shortest path | SR of Done ≤ 5 | SR of Done > 5 | SR |");
    println!("|---|---:|---:|---:|---:|---:|---:|---:|");
    for name in &args[3..] {
        let results = if name == "random" {
            evaluate(
                &world,
                &episodes,
                |_| Box::new(RandomAgent::new(0)) as Box<dyn Agent + Send>,
                &cfg,
            )
        } else {
            let model = Arc::new(load_model(Path::new(name), None)?);
            evaluate(
                &world,
                &episodes,
                |_| Box::new(NavAgent::new(model.clone())) as Box<dyn Agent + Send>,
                &cfg,
            )
        };
        let n = results.len() as f64;
        let (mut done, mut early, mut early_ok, mut late_ok, mut within_opt, mut ok) =
            (0usize, 0usize, 0usize, 0usize, 0usize, 0usize);
        let mut done_steps = Vec::new();
        for (r, spec) in results.iter().zip(&episodes) {
            let m = &r.metrics;
            ok += m.success as usize;
            // An episode ends by Done when it stops before the step limit (or succeeds).
            if m.success || m.path_length < limits.for_room(spec.room) {
                done += 1;
                done_steps.push(m.path_length);
                if m.path_length <= 5 {
                    early += 1;
                    early_ok += m.success as usize;
                } else {
                    late_ok += m.success as usize;
                }
                within_opt += (m.path_length < shortest[r.index]) as usize;
            }
        }
        done_steps.sort_unstable();
        let pct = |a: usize, b: usize| 100.0 * a as f64 / (b.max(1) as f64);
        println!(
            "| {name} | {:.1}% | {} | {:.1}% | {:.1}% | {:.1}% | {:.1}% | {:.2}% |",
            pct(done, results.len()),
            done_steps.get(done_steps.len() / 2).copied().unwrap_or(0),
            pct(early, results.len()),
            pct(within_opt, results.len()),
            pct(early_ok, early),
            pct(late_ok, done - early),
            100.0 * ok as f64 / n
        );
    }
    Ok(())
}
