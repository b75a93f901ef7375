//! Diagnostics of the environmental meta discriminator on a trained GMAN model:
//! 1. Does adaptation move G's output towards the target's real feature in the scene
//!    (`World::object_feature`)? Distance of G(SE(y), 0) to it at the start of every val
//!    episode and at its end (after the inner updates).
//! 2. Does the policy use x_t? Success rate with G's weights zeroed (x_t constant) against
//!    the trained model.
//!
//! `cargo run --release -p gman-host-sim --example emd_analysis -- CKPT [DATA_DIR] [EPISODES_PER_FILE] [INNER_LR] [MAX_INNER]`
//!
//! `INNER_LR` and `MAX_INNER` override the model's inner-loop rate α and cap (for sweeps).

use std::path::Path;
use std::sync::Arc;

use anyhow::{bail, Result};
use gman_core::generator::GeneratorCache;
use gman_core::memory::AdaptMode;
use gman_core::navigator::{Efficient, Full, Mode, Navigator};
use gman_host_sim::nav::agent::NavAgent;
use gman_host_sim::nav::model::{load_model, NavModel};
use gman_host_sim::nav::K;
use gman_host_sim::sim::spatial::MapGrid;
use gman_host_sim::sim::{
    evaluate, Env, EpisodeLimits, EpisodeSpec, EvalConfig, EvalReport, RewardKind, Split,
    TargetKind, World,
};

fn dist(a: &[f32], b: &[f32]) -> f64 {
    a.iter()
        .zip(b)
        .map(|(x, y)| ((x - y) as f64).powi(2))
        .sum::<f64>()
        .sqrt()
}

/// One val episode with the device's schedule in mode `M`; for an episode with at least one
/// inner update: the distance of G(SE(y), 0) to the target's true feature before and after,
/// how far G's output moved, and the decrease of its distance to the episode's mean view.
fn episode<M: Mode>(
    world: &World,
    model: &NavModel,
    spec: &EpisodeSpec,
) -> Result<Option<[f64; 4]>> {
    let limits = EpisodeLimits::default();
    let mut arena = vec![0.0f32; Navigator::<M, K>::arena_len(&model.dims)];
    let f = model.dims.feat;
    let gen_x = |nav: &Navigator<'_, M, K>, attr: &[f32]| -> Result<Vec<f32>> {
        let g = nav.generator()?;
        let (mut h1, mut x) = (vec![0.0f32; g.hidden()], vec![0.0f32; f]);
        let (mut u1, mut u2) = (vec![0.0f32; g.hidden()], vec![0.0f32; f]);
        let z = vec![0.0f32; model.dims.noise];
        let gains = g.l1.gain.is_some();
        g.forward(
            &z,
            attr,
            &mut GeneratorCache {
                u1: if gains { &mut u1 } else { &mut [] },
                h1: &mut h1,
                u2: if gains { &mut u2 } else { &mut [] },
                x: &mut x,
            },
        )?;
        Ok(x)
    };
    let mut nav: Navigator<'_, M, K> =
        Navigator::new(model.weights()?, &mut arena, model.nav_config(false))?;
    let attr = world.attributes(spec.target).to_vec();
    nav.reset(&attr, spec.seed)?;
    let real = world.object_feature(spec.scene, spec.target);
    let x0 = gen_x(&nav, &attr)?;
    let mut env = Env::new(world, spec, RewardKind::Mixed, limits.for_room(spec.room));
    let grid = MapGrid {
        rows: model.dims.map_rows,
        cols: model.dims.map_cols,
    };
    let mut map = vec![0.0f32; grid.len()];
    let mut obs_mean = vec![0.0f64; f];
    let mut n = 0.0;
    while !env.is_done() {
        let o = env.observe().features;
        obs_mean
            .iter_mut()
            .zip(o.iter())
            .for_each(|(m, v)| *m += *v as f64);
        n += 1.0;
        if !grid.is_empty() {
            env.observe_map(grid, &mut map);
        }
        let out = nav.step_map(&o, &map, &[])?;
        env.step(out.action);
    }
    if nav.counters().adaptations == 0 {
        return Ok(None);
    }
    let x1 = gen_x(&nav, &attr)?;
    let om: Vec<f32> = obs_mean.iter().map(|v| (v / n) as f32).collect();
    Ok(Some([
        dist(&x0, &real),
        dist(&x1, &real),
        dist(&x0, &x1),
        dist(&x0, &om) - dist(&x1, &om),
    ]))
}

fn main() -> Result<()> {
    let args: Vec<String> = std::env::args().collect();
    let Some(ckpt) = args.get(1) else {
        bail!("usage: emd_analysis CKPT [DATA_DIR] [EPISODES_PER_FILE] [INNER_LR] [MAX_INNER]")
    };
    let world = match args.get(2) {
        Some(d) => World::load(Path::new(d))?,
        None => World::synthetic(gman_host_sim::sim::DEFAULT_WORLD_SEED),
    };
    let per_file: usize = args.get(3).map(|s| s.parse()).transpose()?.unwrap_or(100);
    let mut model = load_model(Path::new(ckpt), None)?;
    if let Some(lr) = args.get(4) {
        model.inner_lr = lr.parse()?;
    }
    if let Some(n) = args.get(5) {
        model.max_inner = n.parse()?;
    }
    println!("inner rate {} cap {}", model.inner_lr, model.max_inner);
    let episodes = world.episodes(Split::Val, Some(per_file))?;
    println!(
        "adaptation mode {:?}, spatial map {} x {}",
        model.adapt_mode, model.dims.map_rows, model.dims.map_cols
    );
    // Per target kind: [adapted episodes, d0, d1, moved, decrease to the episode's mean view].
    let mut acc = [[0.0f64; 5]; 2];
    for spec in &episodes {
        let r = match model.adapt_mode {
            AdaptMode::Full => episode::<Full>(&world, &model, spec)?,
            AdaptMode::Efficient => episode::<Efficient>(&world, &model, spec)?,
        };
        if let Some(v) = r {
            let a = &mut acc[(spec.kind == TargetKind::Unseen) as usize];
            a[0] += 1.0;
            for i in 0..4 {
                a[i + 1] += v[i];
            }
        }
    }
    for (kind, a) in ["seen", "unseen"].iter().zip(&acc) {
        let n = a[0].max(1.0);
        println!(
            "{kind}: {} episodes with an inner update; mean |G(y,0) - true target feature| before {:.4}, after {:.4} ({:.2}% closed); mean change of G's output {:.5}; decrease of the distance to the episode's mean view {:.5}",
            a[0],
            a[1] / n,
            a[2] / n,
            100.0 * (a[1] - a[2]) / a[1].max(1e-12),
            a[3] / n,
            a[4] / n
        );
    }

    let cfg = EvalConfig {
        reward: RewardKind::Mixed,
        limits: EpisodeLimits::default(),
        progress: false,
    };
    let trained = Arc::new(model.clone());
    let r1 = EvalReport::new(
        "val",
        "trained",
        &evaluate(
            &world,
            &episodes,
            |_| Box::new(NavAgent::new(trained.clone())),
            &cfg,
        ),
    );
    let mut ablated = model.clone();
    for name in ["GenW1", "GenW2"] {
        ablated
            .params
            .get_mut(name)
            .expect("G tensor")
            .data
            .fill(0.0);
    }
    let ablated = Arc::new(ablated);
    let r2 = EvalReport::new(
        "val",
        "x_t ablated",
        &evaluate(
            &world,
            &episodes,
            |_| Box::new(NavAgent::new(ablated.clone())),
            &cfg,
        ),
    );
    println!(
        "SR trained: unseen {:.2} seen {:.2}; with G's weights zeroed (x_t constant): unseen {:.2} seen {:.2} ({} episodes)",
        r1.results.unseen.sr, r1.results.seen.sr, r2.results.unseen.sr, r2.results.seen.sr, episodes.len()
    );
    Ok(())
}
