//! `gman export`: a trained checkpoint as a gman-core weight blob.

use std::path::PathBuf;

use anyhow::{bail, Context, Result};
use clap::{Args, ValueEnum};
use gman_host_sim::blob_edit::{default_int8_activations, reencode_with_flags_of};
use gman_host_sim::model::load_model;

use super::args::PresetArg;

use super::train::preset_matches;

/// `gman export`.
#[derive(Debug, Args)]
pub struct ExportArgs {
    /// Trained checkpoint.
    #[arg(
        long,
        value_name = "CKPT",
        required_unless_present = "blob",
        conflicts_with = "blob"
    )]
    pub ckpt: Option<PathBuf>,
    /// An existing weight blob to re-emit with other activations (`--activations`), weights,
    /// flags and settings otherwise unchanged; instead of `--ckpt`.
    #[arg(long, value_name = "MODEL.gman")]
    pub blob: Option<PathBuf>,
    /// Preset the checkpoint must have (checked).
    #[arg(long, value_enum, default_value = "mcu")]
    pub preset: PresetArg,
    /// Weight format.
    #[arg(long, value_enum, default_value = "int8")]
    pub quant: QuantArg,
    /// Activations of the int8 weight matrices: `auto` (int8 for `--preset mcu --quant int8`,
    /// what the default firmware runs; with `--blob`, the blob's own), `f32` (int8 weights
    /// widened to f32), or `int8` (int8 activations into i32 accumulators, gman-core's
    /// integer kernels; needs `--quant int8`).
    #[arg(long, value_enum, default_value = "auto")]
    pub activations: ActArg,
    /// How the navigator keeps Ψ's observations: `auto` (int16 with int8 activations, else
    /// f32), `f32`, or `int16` (`FLAG_COMPACT_PSI`: one scale per entry; the firmware's
    /// smallest arena, `Footprint::Minimal`, needs it).
    #[arg(long, value_enum, default_value = "auto")]
    pub psi: PsiArg,
    /// Output blob.
    #[arg(long, value_name = "MODEL.gman")]
    pub out: PathBuf,
}

/// Activations of an exported blob's int8 matrices.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum ActArg {
    /// int8 for `--preset mcu --quant int8` (with `--blob`: the blob's own), else f32.
    Auto,
    /// f32 activations.
    F32,
    /// int8 activations, i32 accumulators (`FLAG_INT8_ACTIVATIONS`).
    Int8,
}

/// How an exported blob's navigator keeps Ψ's observations.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum PsiArg {
    /// int16 with int8 activations, else f32.
    Auto,
    /// f32.
    F32,
    /// int16 with one scale per entry (`FLAG_COMPACT_PSI`).
    Int16,
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
    for (flag, input) in [("--ckpt", &a.ckpt), ("--blob", &a.blob)] {
        if let Some(input) = input {
            super::args::refuse_output_over_inputs("--out", &a.out, &[(flag, input)])?;
        }
    }
    let int8_act = match (a.activations, &a.blob) {
        (ActArg::Int8, _) => true,
        (ActArg::F32, _) => false,
        (ActArg::Auto, Some(path)) => {
            let bytes = std::fs::read(path)
                .with_context(|| format!("reading the blob {}", path.display()))?;
            let blob = gman_core::blob::Blob::parse(&bytes)
                .map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))?;
            blob.header().flags() & gman_core::spec::schema::FLAG_INT8_ACTIVATIONS != 0
        }
        (ActArg::Auto, None) => {
            default_int8_activations(a.preset == PresetArg::Mcu, a.quant == QuantArg::Int8)
        }
    };
    let compact = match a.psi {
        PsiArg::Auto => int8_act,
        PsiArg::F32 => false,
        PsiArg::Int16 => true,
    };
    let (bytes, method) = match (&a.ckpt, &a.blob) {
        (_, Some(path)) => {
            let bytes = std::fs::read(path)
                .with_context(|| format!("reading the blob {}", path.display()))?;
            let out = reencode_with_flags_of(&bytes, int8_act, compact)
                .with_context(|| format!("re-emitting the blob {}", path.display()))?;
            (out, "(from blob)".to_string())
        }
        (Some(ckpt), None) => {
            if int8_act && a.quant != QuantArg::Int8 {
                bail!("--activations int8 needs --quant int8 (the integer kernels multiply int8 weights)");
            }
            let model = load_model(ckpt, None)?;
            preset_matches(&model, a.preset)?;
            if model.method.uses_ps() {
                eprintln!(
                    "note: the PS module is not part of the blob; the device must supply the PS input (gman eval: --ps PS.ckpt)"
                );
            }
            let bytes = model.to_blob(a.quant == QuantArg::Int8)?;
            let bytes = if int8_act || compact {
                reencode_with_flags_of(&bytes, int8_act, compact)?
            } else {
                bytes
            };
            (bytes, model.method.name().to_string())
        }
        (None, None) => bail!("give --ckpt or --blob"),
    };
    // Like `gman train --out`, the destination's directory is made when it is missing.
    if let Some(dir) = a.out.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir)
            .with_context(|| format!("{}: cannot create the directory", dir.display()))?;
    }
    gman_host_sim::optim::checkpoint::write_atomic(&a.out, |f| {
        std::io::Write::write_all(f, &bytes)
    })?;
    eprintln!(
        "wrote {} ({} bytes, {:?} weights, {:?} activations, Ψ observations {}, method {})",
        a.out.display(),
        bytes.len(),
        a.quant,
        a.activations,
        if compact { "int16" } else { "f32" },
        method
    );
    Ok(())
}
