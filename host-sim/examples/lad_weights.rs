//! What the per-step weight of L_ad says about the scene. Eq. 3 sharpens the
//! actor head's action distribution at step t in proportion to a per-step score: D(x_t) for
//! GMAN (x_t = G(SE(y), z_t), whatever the agent sees) and cos(x_t, s_t) for gman-cossim (the
//! generated feature against the current observation). This runs a model's val episodes with
//! the device's schedule and reports, over all steps, how well each score separates the steps
//! where the target is visible (the steps where Done is right) from the others: the AUC
//! (0.5 = no information) and the means, over all steps and within episodes (each score
//! minus its episode's mean: what the score says about the step rather than the episode's
//! target and scene).
//!
//! `cargo run --release -p gman-host-sim --example lad_weights -- MODEL [DATA_DIR] [EPISODES_PER_FILE]`

use std::path::Path;

use anyhow::{bail, Result};
use gman_core::adapt::cosine;
use gman_core::navigator::{Efficient, Full, Mode, Navigator};
use gman_core::nets::discriminator::DiscScratch;
use gman_host_sim::model::episode::eval_mode_is_efficient;
use gman_host_sim::model::K;
use gman_host_sim::model::{load_model, NavModel};
use gman_host_sim::sim::spatial::MapGrid;
use gman_host_sim::sim::{Env, EpisodeLimits, RewardKind, Split, World};

/// Per step: (D(x_t), cos(x_t, s_t), target visible).
type Steps = Vec<(f32, f32, bool)>;

fn main() -> Result<()> {
    let args: Vec<String> = std::env::args().collect();
    let Some(path) = args.get(1) else {
        bail!("usage: lad_weights MODEL [DATA_DIR] [EPISODES_PER_FILE]")
    };
    let world = match args.get(2) {
        Some(d) => World::load(Path::new(d))?,
        None => World::synthetic(gman_host_sim::sim::DEFAULT_WORLD_SEED),
    };
    let per_file: usize = args.get(3).map(|s| s.parse()).transpose()?.unwrap_or(100);
    let model = load_model(Path::new(path), None)?;
    if model.method.uses_ps() {
        bail!("PS variants need the PS input; pick a non-PS model");
    }
    let (steps, episode_of) = if eval_mode_is_efficient(&model) {
        run::<Efficient>(&model, &world, per_file)?
    } else {
        run::<Full>(&model, &world, per_file)?
    };
    let n_vis = steps.iter().filter(|s| s.2).count();
    println!(
        "{path} ({}): {} steps of {} val episodes per file, target visible at {n_vis}",
        model.method.name(),
        steps.len(),
        per_file
    );
    let within = centred(&steps, &episode_of);
    for (name, get) in [
        (
            "D(x_t)",
            (|s: &(f32, f32, bool)| s.0) as fn(&(f32, f32, bool)) -> f32,
        ),
        ("cos(x_t, s_t)", |s| s.1),
    ] {
        let w = if name.starts_with('D') {
            &within.0
        } else {
            &within.1
        };
        let mean = |vis: bool| {
            let v: Vec<f64> = steps
                .iter()
                .filter(|s| s.2 == vis)
                .map(|s| get(s) as f64)
                .collect();
            v.iter().sum::<f64>() / v.len().max(1) as f64
        };
        println!(
            "  {name:<14} AUC for 'target visible' {:.3} (within episodes {:.3}); mean {:.4} when visible, {:.4} when not",
            auc(steps.iter().map(|s| (get(s), s.2)).collect()),
            auc(w.clone()),
            mean(true),
            mean(false)
        );
    }
    Ok(())
}

/// The val episodes with the device's schedule, recording each step's scores.
/// The steps and each step's episode index.
fn run<M: Mode>(model: &NavModel, world: &World, per_file: usize) -> Result<(Steps, Vec<usize>)> {
    let mut arena = vec![0.0f32; Navigator::<M, K>::arena_len(&model.dims)];
    let grid = MapGrid {
        rows: model.dims.map_rows,
        cols: model.dims.map_cols,
    };
    let mut map = vec![0.0f32; model.dims.map_len()];
    let (dh, f) = (model.dims.disc_hidden, model.dims.feat);
    let mut bufs = (vec![0.0f32; dh], vec![0.0f32; dh], vec![0.0f32; dh]);
    let mut bufs_f = (vec![0.0f32; f], vec![0.0f32; f], vec![0.0f32; dh]);
    let (mut out, mut ep) = (Steps::new(), Vec::new());
    for (e, spec) in world
        .episodes(Split::Val, Some(per_file))?
        .into_iter()
        .enumerate()
    {
        let mut nav: Navigator<'_, M, K> =
            Navigator::new(model.weights()?, &mut arena, model.nav_config(false))?;
        nav.reset(world.attributes(spec.target), spec.seed)?;
        let limits = EpisodeLimits::default().for_room(spec.room);
        let mut env = Env::new(world, &spec, RewardKind::Mixed, limits);
        while !env.is_done() {
            let obs = env.observe().features;
            if !map.is_empty() {
                env.observe_map(grid, &mut map);
            }
            let visible = env.oracle().goal_visible();
            let step = nav.step_map(&obs, &map, &[])?;
            // x_t of this step (an inner update in it changes G only from the next step on).
            let x = nav.generated_feature();
            let cos = cosine(x, &obs, None)?;
            let mut s = DiscScratch {
                u: &mut bufs.0,
                h: &mut bufs.1,
                v: &mut bufs.2,
                w1g: &mut bufs_f.2,
                g: &mut bufs_f.0,
                mix: &mut bufs_f.1,
            };
            let d = nav.discriminator()?.score(x, &mut s)?;
            out.push((d, cos, visible));
            ep.push(e);
            env.step(step.action);
        }
    }
    Ok((out, ep))
}

/// (score, target visible) per step.
type Scored = Vec<(f32, bool)>;

/// Each score minus its episode's mean, for D and for cos.
fn centred(steps: &Steps, episode_of: &[usize]) -> (Scored, Scored) {
    let n = episode_of.iter().max().map_or(0, |m| m + 1);
    let mut sum = vec![(0.0f64, 0.0f64, 0usize); n];
    for (s, &e) in steps.iter().zip(episode_of) {
        sum[e] = (sum[e].0 + s.0 as f64, sum[e].1 + s.1 as f64, sum[e].2 + 1);
    }
    let mean = |e: usize| (sum[e].0 / sum[e].2 as f64, sum[e].1 / sum[e].2 as f64);
    let d = steps.iter().zip(episode_of);
    (
        d.clone()
            .map(|(s, &e)| ((s.0 as f64 - mean(e).0) as f32, s.2))
            .collect(),
        d.map(|(s, &e)| ((s.1 as f64 - mean(e).1) as f32, s.2))
            .collect(),
    )
}

/// Area under the ROC curve of the scores for the visible steps (ties count one half).
fn auc(mut v: Scored) -> f64 {
    v.sort_by(|a, b| a.0.total_cmp(&b.0));
    let (np, nn) = (
        v.iter().filter(|s| s.1).count() as f64,
        v.iter().filter(|s| !s.1).count() as f64,
    );
    if np == 0.0 || nn == 0.0 {
        return f64::NAN;
    }
    // Rank sum of the positives, average ranks for ties.
    let mut rank_sum = 0.0;
    let mut i = 0;
    while i < v.len() {
        let mut j = i;
        while j < v.len() && v[j].0 == v[i].0 {
            j += 1;
        }
        let r = (i + 1 + j) as f64 / 2.0;
        rank_sum += r * v[i..j].iter().filter(|s| s.1).count() as f64;
        i = j;
    }
    (rank_sum - np * (np + 1.0) / 2.0) / (np * nn)
}
