//! Diagnostics of the environmental meta discriminator on a trained GMAN model:
//! 1. Does adaptation move G's output towards the target's real feature in the scene
//!    (`World::object_feature`)? Distance of G(SE(y), 0) to it at the start of every val
//!    episode and at its end (after the inner updates).
//! 2. Does the policy use x_t? Success rate with G's weights zeroed (x_t constant) against
//!    the trained model.
//!
//! `cargo run --release -p gman-host-sim --example emd_analysis -- CKPT [DATA_DIR] [EPISODES_PER_FILE] [INNER_LR] [MAX_INNER] [PNG|-] [DISC_LR]`
//!
//! `INNER_LR` and `MAX_INNER` (`-` keeps the model's) override the model's inner-loop rate α (α1 = α2) and cap, `DISC_LR` sets α1 alone (for
//! sweeps).

use std::path::Path;
use std::sync::Arc;

use anyhow::{bail, Result};
use gman_host_sim::emd_report;
use gman_host_sim::eval::agent::NavAgent;
use gman_host_sim::model::load_model;
use gman_host_sim::sim::{
    evaluate, EpisodeLimits, EvalConfig, EvalReport, RewardKind, Split, TargetKind, World,
};

fn main() -> Result<()> {
    let args: Vec<String> = std::env::args().collect();
    let Some(ckpt) = args.get(1) else {
        bail!("usage: emd_analysis CKPT [DATA_DIR] [EPISODES_PER_FILE] [INNER_LR] [MAX_INNER] [PNG|-] [DISC_LR]")
    };
    let world = match args.get(2) {
        Some(d) => World::load(Path::new(d))?,
        None => World::synthetic(gman_host_sim::sim::DEFAULT_WORLD_SEED),
    };
    let per_file: usize = args.get(3).map(|s| s.parse()).transpose()?.unwrap_or(100);
    let mut model = load_model(Path::new(ckpt), None)?;
    if let Some(lr) = args.get(4).filter(|s| *s != "-") {
        model.spec.inner_lr = lr.parse()?;
    }
    if let Some(n) = args.get(5).filter(|s| *s != "-") {
        model.spec.max_inner = n.parse()?;
    }
    println!(
        "inner rate {} cap {}",
        model.spec.inner_lr, model.spec.max_inner
    );
    let episodes = world.episodes(Split::Val, Some(per_file))?;
    println!(
        "adaptation mode {:?}, spatial map {} x {}",
        model.spec.adapt_mode, model.dims.map_rows, model.dims.map_cols
    );
    if let Some(a) = args.get(7) {
        model.spec.inner_rule.disc_lr = Some(a.parse()?);
        model.spec.inner_rule.validate()?;
    }
    let records = emd_report::measure(&world, &model, &episodes)?;
    for (name, kind) in [("seen", TargetKind::Seen), ("unseen", TargetKind::Unseen)] {
        let m = emd_report::summarize(&records, kind);
        println!(
            "{name}: {} episodes with an inner update; mean |G(y,0) - true target feature| before {:.4}, after {:.4} ({:.2}% closed); mean change of G's output {:.5}; the episode's mean view is {:.4} from it; cosine of the move to the true feature {:.3}, to the mean view {:.3}; {:.2} inner updates per episode, {:.3} rollbacks per update",
            m.episodes, m.before, m.after, m.closed_percent, m.moved, m.view_mean, m.cos_to_true, m.cos_to_views, m.adaptations, m.rollbacks_per_update
        );
    }
    if let Some(png) = args.get(6).filter(|s| *s != "-") {
        let scenes = emd_report::busiest_scenes(&records);
        let fig = emd_report::figure(&records, &scenes, &world);
        let n = gman_host_sim::fig3::draw(&fig, Path::new(png))?;
        println!("wrote {png}: Fig. 3 for scenes {scenes:?} ({n} unseen-target episodes)");
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
