//! `gman pretrain-ps`: pre-train the PS module (observation -> semantic embedding of the
//! objects in view); writes OUT/ps.ckpt and OUT/ps_report.json.

use std::path::PathBuf;
use std::time::Instant;

use anyhow::{bail, Result};
use clap::Args;
use gman_host_sim::pretrain::ps::{self, PsDataConfig, PsTrainConfig};

use super::args::{check_positive, check_unit, report_written, WorldArgs};

/// `gman pretrain-ps`.
#[derive(Debug, Args)]
pub struct PretrainPsArgs {
    /// World selection.
    #[command(flatten)]
    pub world: WorldArgs,
    /// Adam steps.
    #[arg(long, default_value_t = 500, value_name = "N")]
    pub iters: usize,
    /// Seed of initialisation, view sampling and batches.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Output directory (created if missing).
    #[arg(long, value_name = "DIR")]
    pub out: PathBuf,
    /// Hidden width of the PS network.
    #[arg(long, default_value_t = 128)]
    pub hidden: usize,
    /// Views per step.
    #[arg(long, default_value_t = 64)]
    pub batch: usize,
    /// Adam learning rate.
    #[arg(long, default_value_t = 1e-3)]
    pub lr: f32,
    /// Distinct training-scene views sampled (training plus held out).
    #[arg(long, default_value_t = 40_000)]
    pub views: usize,
    /// Share of the sampled training-scene views held out for the report.
    #[arg(long, default_value_t = 0.1)]
    pub holdout: f32,
    /// Distinct val-scene views for the report.
    #[arg(long, default_value_t = 8_000)]
    pub val_views: usize,
    /// No progress bar.
    #[arg(long)]
    pub quiet: bool,
}

/// Runs `gman pretrain-ps`.
pub fn cmd_pretrain_ps(a: PretrainPsArgs) -> Result<()> {
    if a.batch == 0 || a.hidden == 0 || a.views == 0 {
        bail!("--batch, --hidden and --views must be at least 1");
    }
    check_positive("lr", a.lr)?;
    check_unit("holdout", a.holdout)?;
    let t0 = Instant::now();
    let world = a.world.load()?;
    let collect = PsDataConfig {
        train_views: a.views,
        heldout: a.holdout,
        val_views: a.val_views,
        seed: a.seed,
    };
    let mut cfg = PsTrainConfig {
        hidden: a.hidden,
        iters: a.iters,
        batch: a.batch,
        seed: a.seed,
        progress: !a.quiet,
        ..PsTrainConfig::default()
    };
    cfg.adam.lr = a.lr;
    let report = ps::run_pretrain_ps(&world, &collect, &cfg, &a.out)?;
    print!("{}", ps::report_table(&report));
    report_written(&a.out, &["ps.ckpt", "ps_report.json"], t0);
    Ok(())
}
