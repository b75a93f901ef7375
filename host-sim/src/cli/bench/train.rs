//! The training-throughput rows of `gman bench`: environment steps per second of
//! `gman train` on the synthetic world for a3c and gman, the `mcu` and `paper` presets,
//! one environment per worker (`--batch-envs 1`) and each of [`BATCH_ENVS`] in lockstep
//! (`--min-steps 40`, the default; for `mcu` also `B = 64` with [`FULL_BATCH_MIN_STEPS`]), 1
//! and 2 workers, all measured in one run.
//!
//! Each row trains a fresh model (seed 1, a random generator) for two warm-up updates (not
//! timed), then times as many more as take at least the same number of environment steps in
//! every row of a preset (an update holds at least `B` episodes per worker) and at least
//! [`MIN_TIMED_SECS`] seconds. Each row runs in `gman train`'s default adaptation mode for its preset (`efficient` for `mcu`, `full` for
//! `paper`); `gman`'s `B > 1` rows (`mcu` only) run one navigator per episode
//! (`gman_host_sim::train::engine`).

use std::time::Instant;

use anyhow::{Context, Result};
use gman_core::navigator::memory::AdaptMode;
use gman_core::rng::Xoshiro128;
use gman_core::Dims;
use gman_host_sim::model::{Method, NavModel};
use gman_host_sim::optim::adam::AdamConfig;
use gman_host_sim::pretrain::generator::init_generator;
use gman_host_sim::sim::{World, DEFAULT_WORLD_SEED};
use gman_host_sim::train::state::{RunSettings, TrainState};
use gman_host_sim::train::trainer::{train, TrainOptions};
use serde_json::{json, Value};

/// The batched settings the bench measures next to `--batch-envs 1` (an update holds at least
/// `B` episodes per worker, so a larger `B` is also a larger update).
pub const BATCH_ENVS: [usize; 2] = [16, 64];

/// `--min-steps` of the extra `mcu` rows with `B = 64` that keep the batch full: with the
/// default 40 a worker starts its `B` episodes and no more, so the batch drains while the
/// update's longest episode runs (the synthetic world's episodes of an untrained agent are
/// short); with `40 B` ended episodes are replaced for most of the update (a larger update).
pub const FULL_BATCH_MIN_STEPS: u32 = 40 * 64;

/// One measured training configuration.
pub struct TrainRow {
    method: &'static str,
    preset: &'static str,
    batch_envs: usize,
    min_steps: u32,
    workers: usize,
    updates: u64,
    env_steps: u64,
    secs: f64,
}

impl TrainRow {
    fn sps(&self) -> f64 {
        self.env_steps as f64 / self.secs
    }
}

/// Steps per worker and update (`--min-steps`, the CLI default).
const MIN_STEPS: u32 = 40;

/// Shortest timed part of a row (seconds): a batched update holds hundreds of steps, and a
/// timing of a few updates would measure mostly the machine's noise.
const MIN_TIMED_SECS: f64 = 2.0;

/// Measures every row: each times at least `updates x 40 x workers` environment steps (the
/// steps of `updates` batch-1 updates; `paper` a tenth of that) and at least
/// [`MIN_TIMED_SECS`] seconds.
pub fn rows(updates: u64) -> Result<Vec<TrainRow>> {
    let world = World::synthetic(DEFAULT_WORLD_SEED);
    let mut rows = Vec::new();
    for (preset, dims, scale) in [("mcu", Dims::MCU, 1), ("paper", Dims::PAPER, 10)] {
        let gen = init_generator(&dims, &mut Xoshiro128::seed_from_u64(7))?;
        for method in [Method::A3c, Method::Gman] {
            let full = (preset == "mcu").then_some((64, FULL_BATCH_MIN_STEPS));
            let configs = std::iter::once(1)
                .chain(BATCH_ENVS)
                .map(|b| (b, MIN_STEPS))
                .chain(full);
            for (b, min_steps) in configs {
                // gman `paper` (Full mode) with B > 1: one copy of G per slot (its arena)
                // and no speed-up (docs/training.md); not measured.
                if b > 1 && method == Method::Gman && preset == "paper" {
                    continue;
                }
                let mut model = NavModel::init(method, dims, 1, Some(&gen), None)?;
                model.spec.adapt_mode = if preset == "paper" {
                    AdaptMode::Full
                } else {
                    AdaptMode::Efficient
                };
                for workers in [1usize, 2] {
                    let target = updates / scale * MIN_STEPS as u64 * workers as u64;
                    eprintln!(
                        "bench: train {} ({preset}) --batch-envs {b} --min-steps {min_steps} --workers {workers}, >= {target} env steps ...",
                        method.name()
                    );
                    let m = model.clone();
                    rows.push(row(&world, m, preset, (b, min_steps), workers, target)?);
                }
            }
        }
    }
    Ok(rows)
}

fn row(
    world: &World,
    model: NavModel,
    preset: &'static str,
    (batch_envs, min_steps): (usize, u32),
    workers: usize,
    target_steps: u64,
) -> Result<TrainRow> {
    let method = model.method.name();
    let out = std::env::temp_dir().join(format!(
        "gman-bench-{}-{method}-{preset}-{batch_envs}-{min_steps}-{workers}",
        std::process::id(),
    ));
    let adam = AdamConfig {
        lr: 1e-3,
        ..AdamConfig::default()
    };
    let mut state = TrainState::new(model, adam);
    let opts = TrainOptions {
        updates: 1,
        run: RunSettings {
            workers,
            batch_envs,
            min_steps,
            adam,
            ..RunSettings::default()
        },
        checkpoint_every: u64::MAX,
        out: out.clone(),
        progress: false,
    };
    // Warm-up updates (allocation, page faults, thread start-up) are not timed; they also
    // give the steps per update, from which the timed updates are chosen to take about
    // `target_steps` steps. `updates` counts from the start of the run, so the timed call
    // continues it.
    let warm = 2;
    let mut r = train(
        world,
        &TrainOptions {
            updates: warm,
            ..opts.clone()
        },
        &mut state,
    );
    let (u0, s0) = (state.update, state.env_steps);
    let per_update = (s0 / warm).max(1);
    // Timed in chunks of updates until the row has at least `target_steps` steps and
    // MIN_TIMED_SECS seconds (the first chunk takes the steps; each next one the time left,
    // at the rate measured so far).
    let mut chunk = target_steps.div_ceil(per_update).max(2);
    let t0 = Instant::now();
    while r.is_ok() {
        r = train(
            world,
            &TrainOptions {
                updates: state.update + chunk,
                ..opts.clone()
            },
            &mut state,
        );
        let (done, secs) = (state.update - u0, t0.elapsed().as_secs_f64());
        if secs >= MIN_TIMED_SECS {
            break;
        }
        chunk = ((MIN_TIMED_SECS - secs) * done as f64 / secs.max(1e-6)).ceil() as u64 + 1;
    }
    let secs = t0.elapsed().as_secs_f64();
    let _ = std::fs::remove_dir_all(&out);
    r.with_context(|| format!("training {method} ({preset}, --batch-envs {batch_envs})"))?;
    Ok(TrainRow {
        method,
        preset,
        batch_envs,
        min_steps,
        workers,
        updates: state.update - u0,
        env_steps: state.env_steps - s0,
        secs,
    })
}

/// The same (method, preset) row with `B = 1` and one worker.
fn base<'a>(rows: &'a [TrainRow], r: &TrainRow) -> Option<&'a TrainRow> {
    rows.iter().find(|t| {
        t.method == r.method && t.preset == r.preset && t.batch_envs == 1 && t.workers == 1
    })
}

/// The same row with one worker.
fn one_worker<'a>(rows: &'a [TrainRow], r: &TrainRow) -> Option<&'a TrainRow> {
    rows.iter().find(|t| {
        t.method == r.method
            && t.preset == r.preset
            && t.batch_envs == r.batch_envs
            && t.min_steps == r.min_steps
            && t.workers == 1
    })
}

/// The rows as JSON.
pub fn json(rows: &[TrainRow]) -> Vec<Value> {
    rows.iter()
        .map(|t| {
            json!({
                "method": t.method, "preset": t.preset, "batch_envs": t.batch_envs,
                "min_steps": t.min_steps, "workers": t.workers, "updates": t.updates, "env_steps": t.env_steps,
                "secs": t.secs, "env_steps_per_s": t.sps(),
                "scaling_vs_1_worker": one_worker(rows, t).map(|b| t.sps() / b.sps()),
                "speedup_vs_b1_1_worker": base(rows, t).map(|b| t.sps() / b.sps()),
            })
        })
        .collect()
}

/// Prints the rows as a markdown table.
pub fn print_table(rows: &[TrainRow]) {
    if rows.is_empty() {
        return;
    }
    println!();
    println!(
        "| train (synthetic world) | preset | --batch-envs | --min-steps | --workers | env steps/s | updates, steps, s | vs 1 worker | vs B=1, 1 worker |"
    );
    println!("|---|---|---:|---:|---:|---:|---:|---:|---:|");
    for t in rows {
        let ratio =
            |o: Option<&TrainRow>| o.map_or("-".into(), |b| format!("{:.2}x", t.sps() / b.sps()));
        println!(
            "| {} | {} | {} | {} | {} | {:.0} | {}, {}, {:.1} | {} | {} |",
            t.method,
            t.preset,
            t.batch_envs,
            t.min_steps,
            t.workers,
            t.sps(),
            t.updates,
            t.env_steps,
            t.secs,
            ratio(one_worker(rows, t)),
            ratio(base(rows, t)),
        );
    }
}
