//! Records one navigation episode for the firmware's scripted replay
//! (`firmware-example/data/episode.gmep`, format in `firmware-example/src/episode.rs`).
//!
//! ```text
//! cargo run --release -p gman-host-sim --example record_episode -- \
//!     [--data DIR] [--world-seed S] [--episode I] [--steps N] [--out FILE]
//! ```
//! Loads the world (`--data DIR`, default the built-in synthetic world; the checked-in file is
//! recorded with `--data ../shared/data/gman`, the real floor plans), takes val episode
//! `I` (default: the first one with an unseen target, since unseen objects are what GMAN is
//! about), and walks it for `N` steps (default 40 = two inner updates at k = 20): the oracle's
//! shortest-path action until the target is first visible, then `RotateRight` in place for the
//! rest (so the replay keeps showing new views instead of ending with `Done`). Each step's
//! 512-d observation embedding and its 3 x 3 spatial map (`Env::observe_map`, what `gman train
//! --map 3x3` feeds the policy) are stored as u8 (`round(v * 255)`, features are in [0, 1]),
//! with the target's 45 attribute floats and the episode seed.
//!
//! The host parity test includes this file (`#[path]`) and checks that [`record`] with the
//! defaults on the real floor plans reproduces the checked-in file byte for byte, so the file cannot silently drift
//! from the simulator. That is also why it parses its few arguments by hand (no clap).

use std::path::PathBuf;

use gman_core::blob::crc32::crc32;
use gman_core::Action;
use gman_host_sim::sim::spatial::MapGrid;
use gman_host_sim::sim::{
    Env, EpisodeLimits, RewardKind, Split, TargetKind, World, DEFAULT_WORLD_SEED,
};

/// Errors as boxed trait objects rather than `anyhow`, so that the test crate can include
/// this file without another dependency.
type Result<T> = std::result::Result<T, Box<dyn std::error::Error + Send + Sync>>;

/// Steps recorded by default: two inner updates with the paper's k = 20.
pub const DEFAULT_STEPS: usize = 40;

/// The map recorded: the firmware model's 3 x 3 sectors.
pub const GRID: MapGrid = MapGrid { rows: 3, cols: 3 };

/// Serialises an episode of `n` steps (format: `firmware-example/src/episode.rs`); `obs` holds
/// each step's pooled vector and map, `(1 + cells) * 512` bytes per step.
fn encode(label: &str, seed: u64, attr: &[f32; 45], script: &[u8], obs: &[u8]) -> Vec<u8> {
    let n = script.len();
    assert_eq!(obs.len(), n * (1 + GRID.cells()) * 512);
    let mut body = Vec::with_capacity(label.len() + 4 * 45 + n + obs.len());
    body.extend_from_slice(label.as_bytes());
    attr.iter()
        .for_each(|v| body.extend_from_slice(&v.to_le_bytes()));
    body.extend_from_slice(script);
    body.extend_from_slice(obs);
    let mut out = Vec::with_capacity(28 + body.len());
    out.extend_from_slice(b"GMEP");
    out.extend_from_slice(&2u16.to_le_bytes());
    out.extend_from_slice(&(n as u16).to_le_bytes());
    out.extend_from_slice(&512u16.to_le_bytes());
    out.extend_from_slice(&45u16.to_le_bytes());
    out.extend_from_slice(&seed.to_le_bytes());
    out.extend_from_slice(&(GRID.cells() as u16).to_le_bytes());
    out.extend_from_slice(&(label.len() as u16).to_le_bytes());
    out.extend_from_slice(&crc32(&body).to_le_bytes());
    out.extend_from_slice(&body);
    out
}

/// Records `steps` steps of val episode `episode` of `world` (`None`: the first with an unseen
/// target) and returns the encoded file.
pub fn record(world: &World, episode: Option<usize>, steps: usize) -> Result<Vec<u8>> {
    if steps == 0 || steps > u16::MAX as usize {
        return Err("--steps must be in 1..=65535".into());
    }
    let episodes = world.episodes(Split::Val, None)?;
    let spec = match episode {
        Some(i) => episodes
            .get(i)
            .ok_or_else(|| format!("--episode {i}: only {} val episodes", episodes.len()))?,
        None => episodes
            .iter()
            .find(|e| e.kind == TargetKind::Unseen)
            .ok_or("no val episode with an unseen target")?,
    };
    // The step limit does not matter: the walk never issues Done.
    let limit = EpisodeLimits::default()
        .for_room(spec.room)
        .max(steps as u32 + 1);
    let mut env = Env::new(world, spec, RewardKind::default(), limit);
    let mut reached_at = None;
    let step_bytes = (1 + GRID.cells()) * 512;
    let (mut script, mut obs) = (
        Vec::with_capacity(steps),
        Vec::with_capacity(steps * step_bytes),
    );
    let mut map = vec![0.0f32; GRID.len()];
    let quantise = |v: f32| (v.clamp(0.0, 1.0) * 255.0).round() as u8;
    for t in 0..steps {
        obs.extend(env.observe().features.iter().map(|&v| quantise(v)));
        env.observe_map(GRID, &mut map);
        obs.extend(map.iter().map(|&v| quantise(v)));
        let oracle = env.oracle();
        if reached_at.is_none() && oracle.goal_visible() {
            reached_at = Some(t);
        }
        let a = if reached_at.is_some() {
            Action::RotateRight
        } else {
            oracle.optimal_action()
        };
        script.push(a.index() as u8);
        env.step(a);
    }
    let label = format!(
        "{} {} (val #{}), {} target {}, goal first visible at step {}",
        world.scenes[spec.scene].name,
        spec.room.name(),
        spec.index,
        spec.kind.name(),
        world.category_name(spec.target),
        reached_at.map_or("never".to_string(), |t| t.to_string()),
    );
    // The firmware reads the label into a fixed buffer (`episode::LABEL_MAX`).
    if label.len() > 160 {
        return Err(format!("label longer than 160 bytes: {label}").into());
    }
    Ok(encode(
        &label,
        spec.seed,
        world.attributes(spec.target),
        &script,
        &obs,
    ))
}

/// The checked-in file, relative to the workspace root.
pub const DEFAULT_OUT: &str = "firmware-example/data/episode.gmep";

#[allow(dead_code)] // unused when the parity test includes this file
fn main() -> Result<()> {
    let mut data: Option<PathBuf> = None;
    let mut world_seed = DEFAULT_WORLD_SEED;
    let mut episode = None;
    let mut steps = DEFAULT_STEPS;
    let mut out = PathBuf::from(DEFAULT_OUT);
    let mut args = std::env::args().skip(1);
    while let Some(flag) = args.next() {
        let mut value = || args.next().ok_or_else(|| format!("{flag} needs a value"));
        match flag.as_str() {
            "--data" => data = Some(value()?.into()),
            "--world-seed" => world_seed = value()?.parse()?,
            "--episode" => episode = Some(value()?.parse()?),
            "--steps" => steps = value()?.parse()?,
            "--out" => out = value()?.into(),
            "-h" | "--help" => {
                println!(
                    "record_episode [--data DIR] [--world-seed S] [--episode I] [--steps N] [--out FILE]"
                );
                return Ok(());
            }
            other => return Err(format!("unknown argument {other:?} (see --help)").into()),
        }
    }
    let world = match &data {
        // The object layout the shipped model was trained under (`--object-layout rule`).
        Some(d) => World::load_with_layout(
            d,
            world_seed,
            &gman_host_sim::sim::offline::OfflineOptions::default(),
            gman_host_sim::sim::ObjectLayout::Rule,
        )?,
        None => World::synthetic(world_seed),
    };
    let bytes = record(&world, episode, steps)?;
    std::fs::write(&out, &bytes).map_err(|e| format!("write {}: {e}", out.display()))?;
    let label_len = u16::from_le_bytes([bytes[22], bytes[23]]) as usize;
    println!(
        "{}: {} bytes, {} steps: {}",
        out.display(),
        bytes.len(),
        steps,
        String::from_utf8_lossy(&bytes[28..28 + label_len])
    );
    Ok(())
}
