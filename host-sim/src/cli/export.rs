//! `gman export`: a trained checkpoint as a gman-core weight blob.

use std::path::PathBuf;

use anyhow::Result;
use clap::{Args, ValueEnum};
use gman_host_sim::nav::model::load_model;

use super::args::PresetArg;

use super::train::preset_matches;

/// `gman export`.
#[derive(Debug, Args)]
pub struct ExportArgs {
    /// Trained checkpoint.
    #[arg(long, value_name = "CKPT")]
    pub ckpt: PathBuf,
    /// Preset the checkpoint must have (checked).
    #[arg(long, value_enum, default_value = "mcu")]
    pub preset: PresetArg,
    /// Weight format.
    #[arg(long, value_enum, default_value = "int8")]
    pub quant: QuantArg,
    /// Output blob.
    #[arg(long, value_name = "MODEL.gman")]
    pub out: PathBuf,
}

/// Weight format of an exported blob.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum QuantArg {
    /// f32 weights.
    F32,
    /// int8 weights with per-row scales.
    Int8,
}

/// `gman export`.
pub fn cmd_export(a: ExportArgs) -> Result<()> {
    super::args::refuse_output_over_inputs("--out", &a.out, &[("--ckpt", &a.ckpt)])?;
    let model = load_model(&a.ckpt, None)?;
    preset_matches(&model, a.preset)?;
    if model.method.uses_ps() {
        eprintln!(
            "note: the PS module is not part of the blob; the device must supply the PS input"
        );
    }
    let bytes = model.to_blob(a.quant == QuantArg::Int8)?;
    gman_host_sim::train::checkpoint::write_atomic(&a.out, |f| {
        std::io::Write::write_all(f, &bytes)
    })?;
    eprintln!(
        "wrote {} ({} bytes, {:?}, method {})",
        a.out.display(),
        bytes.len(),
        a.quant,
        model.method.name()
    );
    Ok(())
}
