//! `gman inspect`: a weight blob's header, tensors, quantisation and size.

use std::path::{Path, PathBuf};

use anyhow::{anyhow, Context, Result};
use clap::Args;
use gman_core::blob::{Blob, Quant};

/// `gman inspect`.
#[derive(Debug, Args)]
pub struct InspectArgs {
    /// A weight blob.
    pub blob: PathBuf,
}

/// `gman inspect`.
pub fn cmd_inspect(a: InspectArgs) -> Result<()> {
    let bytes = std::fs::read(&a.blob).with_context(|| format!("reading {}", a.blob.display()))?;
    let blob = Blob::parse(&bytes).map_err(|e| anyhow!("{}: {e}", a.blob.display()))?;
    if let Some(w) = gman_host_sim::blob_edit::unprotected_header_warning(&a.blob, &bytes) {
        eprintln!("{w}");
    }
    print_header(&a.blob, &blob);
    print_flags(&blob);
    print_tensors(&blob);
    Ok(())
}

/// The format, size, checksum and dims.
fn print_header(path: &Path, blob: &Blob<'_>) {
    let h = blob.header();
    let d = blob.dims();
    println!(
        "{}: GMAN weight blob, format v{}, {} bytes, checksum OK (CRC-32 {:#010x} over the {})",
        path.display(),
        h.version(),
        blob.len(),
        h.payload_crc(),
        h.checksum_scope().describe()
    );
    println!(
        "dims: attr {} noise {} gen_hidden {} feat {} disc_hidden {} lstm_hidden {} embed {} ps {}",
        d.attr, d.noise, d.gen_hidden, d.feat, d.disc_hidden, d.lstm_hidden, d.embed, d.ps
    );
    if d.map_cells() > 0 {
        println!(
            "spatial map: {} x {} cells, per-cell layer {} channels",
            d.map_rows, d.map_cols, d.cell_embed
        );
    }
}

/// The model flags, the inner-loop settings and the navigator configuration they give.
fn print_flags(blob: &Blob<'_>) {
    let h = blob.header();
    let mf = h.spec();
    let mut flags = Vec::new();
    if mf.adapt {
        flags.push("adapt (GMAN inner loop on)");
    }
    if mf.noise == gman_core::spec::schema::NoiseMode::Zero {
        flags.push("zero noise");
    }
    if mf.emd == gman_core::spec::schema::Emd::CosSim {
        flags.push("cosine-similarity EMD (no D)");
    }
    if mf.adapt {
        flags.push(match mf.adapt_mode {
            gman_core::navigator::memory::AdaptMode::Full => "Full adaptation mode",
            gman_core::navigator::memory::AdaptMode::Efficient => "Efficient adaptation mode",
        });
    }
    println!(
        "flags: {:#x} {}",
        h.flags(),
        if flags.is_empty() {
            "(no adaptation)".to_string()
        } else {
            flags.join(", ")
        }
    );
    print_settings(h);
    print_setting_keys(h);
    let st = h.adapt_settings();
    println!(
        "inner loop: alpha_disc (α1, D ascent) {:e}, alpha_adapt (α2, θ/φ descent) {:e}, \
         max {} inner updates per episode{}",
        st.alpha_disc,
        st.alpha_adapt,
        st.max_inner,
        if h.has_adapt_settings() {
            String::new()
        } else {
            format!(
                " (format v{} stores no settings: the paper's defaults)",
                h.version()
            )
        }
    );
    let cfg = blob.nav_config();
    println!(
        "navigator (NavConfig::from_header): adapt {}, emd {:?}, noise {:?}",
        cfg.model.adapt, cfg.model.emd, cfg.model.noise
    );
}

/// Every setting the flags hold, named, whether on or off.
fn print_settings(h: &gman_core::blob::Header) {
    use gman_core::spec::schema::{
        AdaptLossKind, StepRule, FLAG_COMPACT_PSI, FLAG_INT8_ACTIVATIONS,
    };
    let mf = h.spec().inner_rule;
    let on = |b: bool| if b { "on" } else { "off" };
    println!(
        "settings: D ascent steps per inner update {}, descent step rule {}, D head reset {}, \
         adaptation loss {}, L_D critic scale {}, head-only adaptation {}, commit delay {} \
         steps, int8 activations {}, compact Ψ {}",
        mf.disc_steps,
        match mf.step_rule {
            StepRule::Gradient => "gradient (paper)",
            StepRule::Normalized => "normalized",
            StepRule::PerGroup => "per-group normalized",
        },
        on(mf.disc_head_reset),
        match mf.adapt_loss {
            AdaptLossKind::Paper => "paper (Eq. 3)",
            AdaptLossKind::Reference => "reference implementation's",
        },
        mf.critic_scale(),
        on(mf.head_only),
        mf.commit_delay,
        on(h.flags() & FLAG_INT8_ACTIVATIONS != 0),
        on(h.flags() & FLAG_COMPACT_PSI != 0),
    );
}

/// Every setting by its key, as a format v5 header names it (`key=value`), whatever the
/// blob's version; `disc_lr` is shown as `(inner_lr)` when α1 is α2.
fn print_setting_keys(h: &gman_core::blob::Header) {
    use gman_core::spec::{SettingValue, SETTING_KEYS};
    let spec = h.spec();
    let shown: Vec<String> = SETTING_KEYS
        .iter()
        .map(|key| match spec.get(key) {
            Some(SettingValue::U32(n)) => format!("{key}={n}"),
            Some(SettingValue::F32(a)) => format!("{key}={a:e}"),
            Some(SettingValue::Name(n)) => format!("{key}={n}"),
            Some(SettingValue::Bool(b)) => format!("{key}={b}"),
            None => format!("{key}=(inner_lr)"),
        })
        .collect();
    println!("settings by key: {}", shown.join(" "));
}

/// One line per tensor, then the tensors a navigator needs that the blob lacks.
fn print_tensors(blob: &Blob<'_>) {
    println!(
        "{:<8} {:>6} {:>6} {:>5} {:>10} {:>14}",
        "tensor", "rows", "cols", "quant", "bytes", "max |err|/2"
    );
    for t in blob.tensors() {
        println!(
            "{:<8} {:>6} {:>6} {:>5} {:>10} {:>14}",
            t.id.name(),
            t.rows,
            t.cols,
            match t.quant {
                Quant::F32 => "f32",
                Quant::I8 => "int8",
            },
            t.storage_bytes(),
            match t.quant {
                Quant::F32 => "-".to_string(),
                Quant::I8 => format!("{:.3e}", t.max_rounding_error()),
            }
        );
    }
    let missing: Vec<&str> = gman_core::blob::TensorId::all_for(&blob.dims())
        .filter(|id| !blob.has(*id))
        .map(|id| id.name())
        .collect();
    if !missing.is_empty() {
        println!(
            "missing tensors (not a complete navigator): {}",
            missing.join(", ")
        );
    }
}
