//! Seen/unseen geometry of the official val episodes under both object layouts: per room and
//! target kind (and per target category), the random agent's SR, the shortest-path (oracle)
//! length from the start, how often the target is visible over the scene's states, the
//! start's distance to the nearest goal instance and the goal's size.
//!
//! `cargo run --release -p gman-host-sim --example layout_report -- DATA [--by-category]`
use std::collections::BTreeMap;
use std::path::Path;

use gman_host_sim::sim::offline::OfflineOptions;
use gman_host_sim::sim::tables::UNREACHABLE;
use gman_host_sim::sim::{
    evaluate, EvalConfig, ObjectLayout, RandomAgent, Split, World, DEFAULT_WORLD_SEED,
};

#[derive(Default)]
struct Acc {
    n: usize,
    success: usize,
    oracle: Vec<u32>,
    unreachable: usize,
    vis_share: f64,
    start_m: f64,
    size_m: f64,
}

fn pct(v: &mut [u32], p: f64) -> u32 {
    v.sort_unstable();
    if v.is_empty() {
        return 0;
    }
    v[((v.len() - 1) as f64 * p) as usize]
}

fn main() -> anyhow::Result<()> {
    let args: Vec<String> = std::env::args().collect();
    let dir = Path::new(
        args.get(1)
            .map(String::as_str)
            .unwrap_or("../shared/data/gman"),
    );
    let by_cat = args.iter().any(|a| a == "--by-category");
    println!("| layout | room | kind | episodes | random SR | oracle mean | oracle p25/median/p75 | target visible in % of states | start to goal (m) | goal size (m) |");
    println!("|---|---|---|---:|---:|---:|---|---:|---:|---:|");
    for layout in [ObjectLayout::Rule, ObjectLayout::Thor5] {
        let w =
            World::load_with_layout(dir, DEFAULT_WORLD_SEED, &OfflineOptions::default(), layout)?;
        let eps = w.episodes(Split::Val, None)?;
        let cfg = EvalConfig {
            progress: false,
            ..Default::default()
        };
        let res = evaluate(&w, &eps, |_| Box::new(RandomAgent::new(0)), &cfg);
        let mut acc: BTreeMap<(String, String), Acc> = BTreeMap::new();
        for (e, r) in eps.iter().zip(&res) {
            let sc = &w.scenes[e.scene];
            let st = sc.state_index(e.start).expect("start");
            let goal = w.goal_table(e.scene, e.target);
            let t = w.tables(e.scene);
            let vis =
                t.obs.iter().filter(|o| o.is_visible(e.target)).count() as f64 / t.obs.len() as f64;
            let props = &w.categories[e.target as usize].props;
            let sizes: Vec<f32> = sc
                .instances_of(e.target)
                .map(|i| match &sc.objects[i].aabb {
                    Some(b) => b.size[0].max(b.size[2]),
                    None => 2.0 * props.radius,
                })
                .collect();
            let size = sizes.iter().sum::<f32>() / sizes.len().max(1) as f32;
            let kind = e.kind.name().to_string();
            let keys = if by_cat {
                vec![(kind.clone(), w.category_name(e.target).to_string())]
            } else {
                vec![
                    (e.room.name().to_string(), kind.clone()),
                    ("all".to_string(), kind.clone()),
                ]
            };
            for k in keys {
                let a = acc.entry(k).or_default();
                a.n += 1;
                a.success += r.metrics.success as usize;
                let d = goal.dist[st];
                if d == UNREACHABLE {
                    a.unreachable += 1;
                } else {
                    a.oracle.push(d as u32);
                }
                a.vis_share += vis;
                a.start_m +=
                    goal.meters[st / gman_host_sim::sim::types::STATES_PER_POSITION] as f64;
                a.size_m += size as f64;
            }
        }
        for ((a, b), mut v) in acc {
            let n = v.n as f64;
            let mean =
                v.oracle.iter().map(|&d| d as f64).sum::<f64>() / v.oracle.len().max(1) as f64;
            let (p25, p50, p75) = (
                pct(&mut v.oracle, 0.25),
                pct(&mut v.oracle, 0.5),
                pct(&mut v.oracle, 0.75),
            );
            println!(
                "| {layout} | {a} | {b} | {} | {:.2} | {mean:.2} | {p25}/{p50}/{p75}{} | {:.2} | {:.2} | {:.2} |",
                v.n,
                100.0 * v.success as f64 / n,
                if v.unreachable > 0 { format!(" ({} unreachable)", v.unreachable) } else { String::new() },
                100.0 * v.vis_share / n,
                v.start_m / n,
                v.size_m / n,
            );
        }
    }
    Ok(())
}
