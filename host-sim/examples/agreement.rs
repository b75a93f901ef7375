//! Per-step action agreement between a checkpoint's f32 navigator (Full mode, the host path)
//! and its int8 export run through gman-core in the device's Efficient mode, fed the same
//! observations and seeds in lockstep along the f32 agent's trajectory.
//!
//! `cargo run --release -p gman-host-sim --example agreement -- CKPT [DATA_DIR] [EPISODES_PER_FILE]`

use std::path::Path;

use anyhow::{bail, Result};
use gman_core::blob::Blob;
use gman_core::navigator::{Efficient, Full, NavWeights, Navigator};
use gman_host_sim::model::{load_model, K};
use gman_host_sim::sim::{Env, EpisodeLimits, RewardKind, Split, World};

fn main() -> Result<()> {
    let args: Vec<String> = std::env::args().collect();
    let Some(ckpt) = args.get(1) else {
        bail!("usage: agreement CKPT [DATA_DIR] [EPISODES_PER_FILE]")
    };
    let world = match args.get(2) {
        Some(d) => World::load(Path::new(d))?,
        None => World::synthetic(gman_host_sim::sim::DEFAULT_WORLD_SEED),
    };
    let per_file: usize = args.get(3).map(|s| s.parse()).transpose()?.unwrap_or(100);
    let model = load_model(Path::new(ckpt), None)?;
    if model.method.uses_ps() {
        bail!("PS variants need the PS input on the device; pick a non-PS checkpoint");
    }
    let bytes = model.to_blob(true)?;
    let blob = Blob::parse(&bytes).map_err(|e| anyhow::anyhow!("{e}"))?;
    let limits = EpisodeLimits::default();
    let (mut same, mut total) = (0u64, 0u64);
    let mut a1 = vec![0.0f32; Navigator::<Full, K>::arena_len(&model.dims)];
    let mut a2 = vec![0.0f32; Navigator::<Efficient, K>::arena_len(&model.dims)];
    for spec in world.episodes(Split::Val, Some(per_file))? {
        let mut f32nav: Navigator<'_, Full, K> =
            Navigator::new(model.weights()?, &mut a1, model.nav_config(false))?;
        let mut i8nav: Navigator<'_, Efficient, K> = Navigator::new(
            NavWeights::from_blob(&blob, &model.dims)?,
            &mut a2,
            model.nav_config(false),
        )?;
        f32nav.reset(world.attributes(spec.target), spec.seed)?;
        i8nav.reset(world.attributes(spec.target), spec.seed)?;
        let mut env = Env::new(&world, &spec, RewardKind::Mixed, limits.for_room(spec.room));
        while !env.is_done() {
            let obs = env.observe().features;
            let a = f32nav.step(&obs, &[])?;
            let b = i8nav.step(&obs, &[])?;
            same += (a.action == b.action) as u64;
            total += 1;
            env.step(a.action);
        }
    }
    println!(
        "{ckpt}: int8 (Efficient) chose the f32 (Full) action at {same} of {total} steps = {:.2}%",
        100.0 * same as f64 / total.max(1) as f64
    );
    Ok(())
}
