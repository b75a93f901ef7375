//! `gman bench`: single-thread latency of the on-device navigator (`step()` and one inner
//! update on k = 20 buffered steps) for the `mcu` and `paper` presets, f32 and int8 weights,
//! `Full` and `Efficient` adaptation, next to this machine's limits measured in the same run
//! (a STREAM-like copy bandwidth, a read bandwidth and a peak multiply-add loop), plus the
//! training throughput of `gman train` ([`train`]) and the firmware's QEMU instruction
//! counts as the firmware printed them ([`firmware`]).
//!
//! Timing uses `std::time::Instant` and medians over repetitions; nothing here is a test.
//! The methods and a recorded run are in `host-sim/BENCHMARKS.md`. [`cmd_bench`] measures
//! ([`limits`], [`navigator`], [`train`], [`firmware`]), then reports ([`report`]).

mod firmware;
mod limits;
mod navigator;
mod report;
mod train;

use std::path::PathBuf;
use std::time::Instant;

use anyhow::{Context, Result};
use clap::{Args, ValueEnum};

use crate::cli::PresetArg;

/// Buffer size of the inner update (the paper's k).
const K: usize = 20;

/// `gman bench`.
#[derive(Debug, Args)]
pub struct BenchArgs {
    /// Presets to measure (repeat the flag; default: mcu and paper).
    #[arg(long, value_enum)]
    pub preset: Vec<PresetArg>,
    /// Weight storage to measure (repeat; default: f32, int8 and int8-act).
    #[arg(long, value_enum)]
    pub quant: Vec<QuantArg>,
    /// Repetitions per timing (the median is reported).
    #[arg(long, default_value_t = 15)]
    pub reps: usize,
    /// Size of each array of the STREAM-like copy (MiB; source and destination each).
    #[arg(long, default_value_t = 256)]
    pub stream_mib: usize,
    /// Updates per training-throughput run (0: skip the training rows).
    #[arg(long, default_value_t = 150)]
    pub train_updates: u64,
    /// Also write every number as JSON to this file (`-` for stdout, then no table).
    #[arg(long, value_name = "OUT")]
    pub json: Option<PathBuf>,
    /// The firmware's output under QEMU to read the firmware row from (default: the file the
    /// firmware test `cargo test --release -p gman-tests --test firmware_qemu` writes).
    #[arg(long, value_name = "FILE", default_value = firmware::DEFAULT_LOG)]
    pub firmware_log: PathBuf,
}

/// Weight storage of the blob.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum QuantArg {
    /// f32 weights.
    F32,
    /// int8 weights with per-row scales.
    Int8,
    /// int8 weights times int8 activations into i32 accumulators (gman-core's integer
    /// kernels, a blob exported with `--activations int8`).
    Int8Act,
}

impl QuantArg {
    fn name(self) -> &'static str {
        match self {
            QuantArg::F32 => "f32",
            QuantArg::Int8 => "int8",
            QuantArg::Int8Act => "int8-act",
        }
    }
}

/// Smallest value of a sample: the estimate of a machine limit (other jobs on the machine
/// can only slow a limit loop down).
fn best(v: &[f64]) -> f64 {
    v.iter().copied().fold(f64::INFINITY, f64::min)
}

/// Median of a non-empty sample (the upper middle for even lengths).
fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(|a, b| a.total_cmp(b));
    v.get(v.len() / 2).copied().unwrap_or(f64::NAN)
}

/// Runs the benchmark.
pub fn cmd_bench(a: BenchArgs) -> Result<()> {
    let started = Instant::now();
    eprintln!("bench: machine limits ...");
    let lim = limits::measure_limits(&a);
    eprintln!("bench: kernels ...");
    let kernels = navigator::kernel_rows(a.reps)?;
    let nav = navigator::nav_rows(&a)?;
    let train = if a.train_updates > 0 {
        train::rows(a.train_updates)?
    } else {
        Vec::new()
    };
    let m = report::Measured {
        lim,
        kernels,
        nav,
        train,
        firmware: firmware::read(&a.firmware_log)?,
        firmware_log: a.firmware_log.display().to_string(),
        stream_mib: a.stream_mib,
        reps: a.reps,
    };
    let report = report::json(&m, started.elapsed().as_secs_f64());
    match &a.json {
        Some(p) if p.as_os_str() == "-" => {
            println!("{}", serde_json::to_string_pretty(&report)?);
            return Ok(());
        }
        Some(p) => {
            std::fs::write(p, serde_json::to_string_pretty(&report)? + "\n")
                .with_context(|| format!("writing {}", p.display()))?;
        }
        None => {}
    }
    report::print(&m, started.elapsed().as_secs_f64());
    Ok(())
}
