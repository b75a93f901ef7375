//! `gman pretrain-fg`: pre-train the feature generator G(SE(y), z) (conditional WGAN-GP,
//! paper Sec. 4.1); writes OUT/fg.ckpt and OUT/fg_report.json.

use std::path::PathBuf;
use std::time::Instant;

use anyhow::{bail, Result};
use clap::Args;
use gman_host_sim::pretrain::fg::{self, FgCollectConfig, FgTrainConfig};

use super::args::{check_positive, check_unit, report_written, PresetArg, WorldArgs};

/// `gman pretrain-fg`.
#[derive(Debug, Args)]
pub struct PretrainFgArgs {
    /// World selection.
    #[command(flatten)]
    pub world: WorldArgs,
    /// Network sizes.
    #[arg(long, value_enum, default_value = "mcu")]
    pub preset: PresetArg,
    /// Generator steps (default: 1500 for mcu, 300 for paper).
    #[arg(long, value_name = "N")]
    pub iters: Option<usize>,
    /// Seed of initialisation, batches and noise.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Output directory (created if missing).
    #[arg(long, value_name = "DIR")]
    pub out: PathBuf,
    /// Samples per step.
    #[arg(long, default_value_t = 64)]
    pub batch: usize,
    /// Critic steps per generator step.
    #[arg(long, default_value_t = 5)]
    pub n_critic: usize,
    /// Gradient-penalty coefficient.
    #[arg(long, default_value_t = 10.0)]
    pub lambda: f32,
    /// Adam learning rate (both networks).
    #[arg(long, default_value_t = 5e-4)]
    pub lr: f32,
    /// Adam beta1 (both networks).
    #[arg(long, default_value_t = 0.5)]
    pub beta1: f32,
    /// Weight of the feature-regression term (mean squared distance of G(a, z) to the mean
    /// training feature of the category); 0 = pure WGAN-GP.
    #[arg(long, default_value_t = fg::DEFAULT_REG)]
    pub reg: f32,
    /// Dominant views per object instance.
    #[arg(long, default_value_t = 6)]
    pub views_per_instance: usize,
    /// Minimum share of the view the object must fill.
    #[arg(long, default_value_t = 0.2)]
    pub min_weight: f32,
    /// Share of each seen category's training-scene instances held out for the report.
    #[arg(long, default_value_t = 0.2)]
    pub holdout: f32,
    /// No progress bar.
    #[arg(long)]
    pub quiet: bool,
}

/// Runs `gman pretrain-fg`.
pub fn cmd_pretrain_fg(a: PretrainFgArgs) -> Result<()> {
    let dims = a.preset.dims();
    let iters = a.iters.unwrap_or(match a.preset {
        PresetArg::Mcu => 1500,
        PresetArg::Paper => 300,
    });
    if a.batch == 0 || a.n_critic == 0 || a.views_per_instance == 0 {
        bail!("--batch, --n-critic and --views-per-instance must be at least 1");
    }
    check_positive("lr", a.lr)?;
    check_unit("beta1", a.beta1)?;
    check_unit("holdout", a.holdout)?;
    if !(a.lambda.is_finite() && a.lambda >= 0.0 && a.reg.is_finite() && a.reg >= 0.0) {
        bail!("--lambda and --reg must be finite and non-negative");
    }
    if !(0.0..=1.0).contains(&a.min_weight) {
        bail!("--min-weight must be in [0, 1], got {}", a.min_weight);
    }
    let t0 = Instant::now();
    let world = a.world.load()?;
    let collect = FgCollectConfig {
        views_per_instance: a.views_per_instance,
        min_weight: a.min_weight,
        holdout: a.holdout,
        seed: a.seed,
    };
    let mut cfg = FgTrainConfig::new(iters, a.seed);
    cfg.batch = a.batch;
    cfg.n_critic = a.n_critic;
    cfg.lambda = a.lambda;
    cfg.reg = a.reg;
    for adam in [&mut cfg.adam_gen, &mut cfg.adam_critic] {
        adam.lr = a.lr;
        adam.beta1 = a.beta1;
    }
    cfg.progress = !a.quiet;
    let report = fg::run_pretrain_fg(&world, a.preset.name(), &dims, &collect, &cfg, &a.out)?;
    print!("{}", fg::report_table(&report));
    report_written(&a.out, &["fg.ckpt", "fg_report.json"], t0);
    Ok(())
}
