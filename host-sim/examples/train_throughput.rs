//! Steady-state training throughput of one configuration (for profiling the trainer):
//! the rows of `gman bench`'s training table, one at a time, with the synthetic world's
//! scene tables built before the clock starts.
//!
//! ```sh
//! cargo run --release -p gman-host-sim --example train_throughput -- \
//!     [--method a3c|gman] [--preset mcu|paper] [--batch-envs B] [--workers W] \
//!     [--adapt-mode efficient|full] [--warmup N] [--updates N] [--reps R] [--min-steps S]
//! ```
//!
//! `--adapt-mode`: the navigator's adaptation mode (default `full`, `NavModel::init`'s, what
//! this example always measured; `gman train`'s default for `mcu` is `efficient`).
//!
//! Prints the environment steps per second of each repetition (each a fresh model, seed 1),
//! and the median.

use std::time::Instant;

use anyhow::{bail, Context, Result};
use gman_core::navigator::memory::AdaptMode;
use gman_core::rng::Xoshiro128;
use gman_core::Dims;
use gman_host_sim::model::{Method, NavModel};
use gman_host_sim::optim::adam::AdamConfig;
use gman_host_sim::pretrain::generator::init_generator;
use gman_host_sim::sim::types::Split;
use gman_host_sim::sim::{World, DEFAULT_WORLD_SEED};
use gman_host_sim::train::state::{RunSettings, TrainState};
use gman_host_sim::train::trainer::{train, TrainOptions};

struct Args {
    method: Method,
    dims: Dims,
    adapt_mode: Option<AdaptMode>,
    batch_envs: usize,
    workers: usize,
    warmup: u64,
    updates: u64,
    reps: usize,
    min_steps: u32,
}

fn parse() -> Result<Args> {
    let mut a = Args {
        method: Method::A3c,
        dims: Dims::MCU,
        adapt_mode: None,
        batch_envs: 16,
        workers: 1,
        warmup: 5,
        updates: 100,
        reps: 1,
        min_steps: 40,
    };
    let argv: Vec<String> = std::env::args().skip(1).collect();
    let mut it = argv.iter();
    while let Some(k) = it.next() {
        let v = it.next().with_context(|| format!("{k} needs a value"))?;
        match k.as_str() {
            "--method" => {
                a.method = match v.as_str() {
                    "a3c" => Method::A3c,
                    "gman" => Method::Gman,
                    _ => bail!("--method a3c|gman, got {v}"),
                }
            }
            "--preset" => {
                a.dims = match v.as_str() {
                    "mcu" => Dims::MCU,
                    "paper" => Dims::PAPER,
                    _ => bail!("--preset mcu|paper, got {v}"),
                }
            }
            "--adapt-mode" => {
                a.adapt_mode = Some(match v.as_str() {
                    "efficient" => AdaptMode::Efficient,
                    "full" => AdaptMode::Full,
                    _ => bail!("--adapt-mode efficient|full, got {v}"),
                })
            }
            "--batch-envs" => a.batch_envs = v.parse()?,
            "--workers" => a.workers = v.parse()?,
            "--warmup" => a.warmup = v.parse()?,
            "--updates" => a.updates = v.parse()?,
            "--reps" => a.reps = v.parse()?,
            "--min-steps" => a.min_steps = v.parse()?,
            _ => bail!("unknown argument {k}"),
        }
    }
    Ok(a)
}

/// CPU seconds (user + system) of this process so far, from `/proc/self/stat` (Linux; 0
/// elsewhere): unlike the wall clock, not inflated by other processes on a busy machine.
fn cpu_secs() -> f64 {
    let Ok(s) = std::fs::read_to_string("/proc/self/stat") else {
        return 0.0;
    };
    // Fields after the command name (which is in parentheses): utime and stime are the
    // 12th and 13th of them.
    let rest = s.rsplit_once(')').map_or("", |(_, r)| r);
    let f: Vec<&str> = rest.split_whitespace().collect();
    let ticks = |i: usize| f.get(i).and_then(|v| v.parse::<f64>().ok()).unwrap_or(0.0);
    (ticks(11) + ticks(12)) / 100.0
}

fn main() -> Result<()> {
    let a = parse()?;
    let world = World::synthetic(DEFAULT_WORLD_SEED);
    for &s in world.split_scenes(Split::Train)? {
        world.tables(s);
    }
    let gen = init_generator(&a.dims, &mut Xoshiro128::seed_from_u64(7))?;
    let adam = AdamConfig {
        lr: 1e-3,
        ..AdamConfig::default()
    };
    let mode = a.adapt_mode.unwrap_or(AdaptMode::Full);
    let out = std::env::temp_dir().join(format!("gman-tp-{}", std::process::id()));
    let (mut sps, mut cpus) = (Vec::new(), Vec::new());
    for rep in 0..a.reps {
        let mut model = NavModel::init(a.method, a.dims, 1, Some(&gen), None)?;
        model.spec.adapt_mode = mode;
        let mut state = TrainState::new(model, adam);
        let opts = TrainOptions {
            updates: a.warmup,
            run: RunSettings {
                workers: a.workers,
                batch_envs: a.batch_envs,
                min_steps: a.min_steps,
                adam,
                ..RunSettings::default()
            },
            checkpoint_every: u64::MAX,
            out: out.clone(),
            progress: false,
        };
        train(&world, &opts, &mut state)?;
        let s0 = state.env_steps;
        let (t0, c0) = (Instant::now(), cpu_secs());
        train(
            &world,
            &TrainOptions {
                updates: a.warmup + a.updates,
                ..opts
            },
            &mut state,
        )?;
        let secs = t0.elapsed().as_secs_f64();
        let cpu = cpu_secs() - c0;
        let steps = state.env_steps - s0;
        let r = steps as f64 / secs;
        println!(
            "rep {rep}: {} updates, {steps} env steps, {secs:.2} s: {r:.0} env steps/s; {cpu:.2} CPU s: {:.0} env steps per CPU second",
            a.updates,
            steps as f64 / cpu
        );
        sps.push(r);
        cpus.push(steps as f64 / cpu);
    }
    let _ = std::fs::remove_dir_all(&out);
    sps.sort_by(f64::total_cmp);
    cpus.sort_by(f64::total_cmp);
    println!(
        "median {:.0} env steps/s, {:.0} per CPU second (B={}, workers {}, {mode:?})",
        sps[sps.len() / 2],
        cpus[cpus.len() / 2],
        a.batch_envs,
        a.workers
    );
    Ok(())
}
