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
use gman_core::navigator::{Full, Navigator};
use gman_host_sim::nav::agent::NavAgent;
use gman_host_sim::nav::model::load_model;
use gman_host_sim::nav::K;
use gman_host_sim::sim::{
    evaluate, Env, EpisodeLimits, EvalConfig, EvalReport, RewardKind, Split, World,
};

fn dist(a: &[f32], b: &[f32]) -> f64 {
    a.iter()
        .zip(b)
        .map(|(x, y)| ((x - y) as f64).powi(2))
        .sum::<f64>()
        .sqrt()
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
    let limits = EpisodeLimits::default();
    let mut arena = vec![0.0f32; Navigator::<Full, K>::arena_len(&model.dims)];
    let (mut d0s, mut d1s, mut moved, mut adapted) = (0.0f64, 0.0f64, 0.0f64, 0u64);
    let (mut to_target_gain, mut to_scene_mean) = (0.0f64, 0.0f64);
    let f = model.dims.feat;
    let gen_x = |nav: &Navigator<'_, Full, K>, attr: &[f32]| -> Result<Vec<f32>> {
        let g = nav.generator()?;
        let (mut h1, mut x) = (vec![0.0f32; g.hidden()], vec![0.0f32; f]);
        let z = vec![0.0f32; model.dims.noise];
        g.forward(
            &z,
            attr,
            &mut GeneratorCache {
                u1: &mut [],
                h1: &mut h1,
                u2: &mut [],
                x: &mut x,
            },
        )?;
        Ok(x)
    };
    for spec in &episodes {
        let mut nav: Navigator<'_, Full, K> =
            Navigator::new(model.weights()?, &mut arena, model.nav_config(false))?;
        let attr = world.attributes(spec.target).to_vec();
        nav.reset(&attr, spec.seed)?;
        let real = world.object_feature(spec.scene, spec.target);
        let x0 = gen_x(&nav, &attr)?;
        let mut env = Env::new(&world, spec, RewardKind::Mixed, limits.for_room(spec.room));
        let mut obs_mean = vec![0.0f64; f];
        let mut n = 0.0;
        while !env.is_done() {
            let o = env.observe().features;
            obs_mean
                .iter_mut()
                .zip(o.iter())
                .for_each(|(m, v)| *m += *v as f64);
            n += 1.0;
            let out = nav.step(&o, &[])?;
            env.step(out.action);
        }
        if nav.counters().adaptations == 0 {
            continue;
        }
        adapted += 1;
        let x1 = gen_x(&nav, &attr)?;
        let (d0, d1) = (dist(&x0, &real), dist(&x1, &real));
        d0s += d0;
        d1s += d1;
        moved += dist(&x0, &x1);
        to_target_gain += d0 - d1;
        let om: Vec<f32> = obs_mean.iter().map(|v| (v / n) as f32).collect();
        to_scene_mean += dist(&x0, &om) - dist(&x1, &om);
    }
    let a = adapted.max(1) as f64;
    println!(
        "episodes with at least one inner update: {adapted} of {}",
        episodes.len()
    );
    println!("mean |G(y,0) - real target feature|: before {:.4}, after {:.4} (mean change of G's output {:.5})", d0s / a, d1s / a, moved / a);
    println!("mean decrease of the distance to the real target feature: {:.5}; to the mean observation of the episode: {:.5}", to_target_gain / a, to_scene_mean / a);

    let cfg = EvalConfig {
        reward: RewardKind::Mixed,
        limits,
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
