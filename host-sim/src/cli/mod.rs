//! Command line of the `gman` binary: one module per command (cargo's
//! `src/bin/cargo/commands/` layout), each with its `clap` arguments and its `cmd_*` function;
//! argument types and checks shared by several commands are in [`args`], agents by name
//! (`random`, `oracle`, model files) in [`models`]. This file only lists the commands and
//! dispatches.
//!
//! Without `--data`, every command uses the built-in synthetic demo world
//! ([`gman_host_sim::sim::synthetic`]); `--data DIR` switches to the real iTHOR floor plans and
//! the official GMAN episodes.

pub mod args;
pub mod bench;
pub mod demo;
pub mod emd_report;
pub mod eval;
pub mod export;
pub mod inspect;
#[cfg(feature = "offline")]
pub mod make_offline_fixture;
pub mod model_args;
pub mod models;
pub mod plot;
pub mod pretrain_fg;
pub mod pretrain_ps;
pub mod progress;
pub mod recipes;
pub mod scene;
pub mod shift_report;
pub mod table;
pub mod train;
pub mod train_config;
pub mod upgrade_blob;

pub use args::PresetArg;

use anyhow::Result;
use clap::{Parser, Subcommand};

/// gman: GMAN (ECCV 2022) unseen-object navigation in Rust.
#[derive(Debug, Parser)]
#[command(name = "gman", version, about)]
pub struct Cli {
    /// The command to run.
    #[command(subcommand)]
    pub command: Commands,
}

/// Subcommands.
#[derive(Debug, Subcommand)]
pub enum Commands {
    /// Evaluate an agent on the episodes of a split (SR, SPL, EPA, DTS).
    Eval(eval::EvalArgs),
    /// Draw a top-down PNG map of a scene (and optionally an episode's path).
    Scene(scene::SceneArgs),
    /// Pre-train the feature generator G(SE(y), z) on seen-object features of the training
    /// scenes (conditional WGAN-GP, paper Sec. 4.1); writes OUT/fg.ckpt and OUT/fg_report.json.
    PretrainFg(pretrain_fg::PretrainFgArgs),
    /// Pre-train the PS module (observation -> semantic embedding of the objects in view) on
    /// training-scene views; writes OUT/ps.ckpt and OUT/ps_report.json.
    PretrainPs(pretrain_ps::PretrainPsArgs),
    /// Train a navigation method (A3C baselines, GMAN): writes RUN_DIR/metrics.csv and
    /// RUN_DIR/checkpoint.ckpt; `--resume RUN_DIR` continues a run exactly.
    Train(train::TrainArgs),
    /// Export a trained checkpoint as a gman-core weight blob (int8 or f32).
    Export(export::ExportArgs),
    /// Print a weight blob's header, tensors, quantisation and size (validates the checksum).
    Inspect(inspect::InspectArgs),
    /// Rewrite a weight blob in the current format (v4: the checksum covers the header too);
    /// for blobs of formats v1-v3, whose checksum covers the payload only.
    UpgradeBlob(upgrade_blob::UpgradeBlobArgs),
    /// Draw learning curves of training runs into a PNG.
    Plot(plot::PlotArgs),
    /// Fig. 3 as a measurement: how far a GMAN model's inner loop moves G toward the
    /// target's true feature in val scenes, with the picture (PCA of two scenes).
    EmdReport(emd_report::EmdReportArgs),
    /// Print the paper's table layout (mean ± std) from evaluation JSON files.
    Table(table::TableArgs),
    /// The domain-shift study's table and picture: SR of every row at every domain shift S,
    /// GMAN against its control and adaptation on against off, with t statistics.
    ShiftReport(shift_report::ShiftReportArgs),
    /// Quick start: pre-train G, train A3C+FG and GMAN briefly, evaluate them against random.
    Demo(demo::DemoArgs),
    /// Single-thread benchmarks: navigator step/adaptation latency against this machine's
    /// measured bandwidth and FMA peak, training throughput, firmware instruction counts.
    Bench(bench::BenchArgs),
    /// Write a small data directory in the AI2THOR offline format of SAVN/GMAN (HDF5 feature
    /// maps, state graph, visibility; made-up data) for trying `--data` on it.
    #[cfg(feature = "offline")]
    MakeOfflineFixture(make_offline_fixture::MakeOfflineFixtureArgs),
}

/// Runs a parsed command line (`matches` tells which flags were given explicitly).
pub fn run(cli: Cli, matches: &clap::ArgMatches) -> Result<()> {
    match cli.command {
        Commands::Eval(a) => eval::cmd_eval(a),
        Commands::Scene(a) => scene::cmd_scene(a),
        Commands::PretrainFg(a) => pretrain_fg::cmd_pretrain_fg(a),
        Commands::PretrainPs(a) => pretrain_ps::cmd_pretrain_ps(a),
        Commands::Train(a) => {
            let sub = matches.subcommand_matches("train");
            let explicit = |id: &str| {
                sub.and_then(|m| m.value_source(id)) == Some(clap::parser::ValueSource::CommandLine)
            };
            train::cmd_train(a, &explicit)
        }
        Commands::Export(a) => export::cmd_export(a),
        Commands::Inspect(a) => inspect::cmd_inspect(a),
        Commands::UpgradeBlob(a) => upgrade_blob::cmd_upgrade_blob(a),
        Commands::Plot(a) => plot::cmd_plot(a),
        Commands::EmdReport(a) => emd_report::cmd_emd_report(a),
        Commands::Table(a) => table::cmd_table(a),
        Commands::ShiftReport(a) => shift_report::cmd_shift_report(a),
        Commands::Demo(a) => demo::cmd_demo(a),
        Commands::Bench(a) => bench::cmd_bench(a),
        #[cfg(feature = "offline")]
        Commands::MakeOfflineFixture(a) => make_offline_fixture::cmd_make_offline_fixture(a),
    }
}
