//! `gman make-offline-fixture` (build feature `offline`): a small made-up data directory in
//! the AI2THOR offline format of SAVN/GMAN, for trying `--data` on it.

use std::path::PathBuf;

use anyhow::Result;
use clap::Args;

/// `gman make-offline-fixture`.
#[derive(Debug, Args)]
pub struct MakeOfflineFixtureArgs {
    /// Output directory: new, or empty (see `--force`).
    #[arg(long, value_name = "DIR")]
    pub out: PathBuf,
    /// Seed of the attribute vectors and feature values.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Replace `--out` when it is a fixture this command wrote earlier (any other
    /// non-empty directory is always refused; links inside are removed, never followed).
    #[arg(long)]
    pub force: bool,
    /// Name the kitchen and living-room folders `FloorPlanN_physics`, as SAVN's download does
    /// (default: `FloorPlanN`, GMAN's).
    #[arg(long)]
    pub savn_names: bool,
    /// Name of each folder's visibility file, e.g. `visible_object_map_1.5.json` (VTNet, HOZ);
    /// read it back with `--visible-file`.
    #[arg(long, value_name = "FILE", default_value = gman_host_sim::sim::offline::VISIBLE_FILE)]
    pub visible_file: String,
}

/// Runs `gman make-offline-fixture`.
pub fn cmd_make_offline_fixture(a: MakeOfflineFixtureArgs) -> Result<()> {
    let info = gman_host_sim::sim::offline::fixture::write_fixture_named_with(
        &a.out,
        a.seed,
        a.savn_names,
        &a.visible_file,
        a.force,
    )?;
    println!(
        "wrote {}: scenes {}, {} val episodes",
        a.out.display(),
        info.scenes.join(", "),
        info.episodes
    );
    Ok(())
}
