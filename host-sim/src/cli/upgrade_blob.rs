//! `gman upgrade-blob IN OUT`: a weight blob rewritten in the current format, whose checksum
//! covers the header as well as the payload.

use std::path::PathBuf;

use anyhow::{anyhow, Context, Result};
use clap::Args;
use gman_core::blob::Blob;

use super::args::refuse_output_over_inputs;

/// `gman upgrade-blob`.
#[derive(Debug, Args)]
pub struct UpgradeBlobArgs {
    /// The weight blob to read (any format this build reads, v1 to the current one).
    pub input: PathBuf,
    /// Where to write it in the current format (must not be the same file as IN).
    pub output: PathBuf,
}

/// `gman upgrade-blob`.
pub fn cmd_upgrade_blob(a: UpgradeBlobArgs) -> Result<()> {
    refuse_output_over_inputs("OUT", &a.output, &[("IN", &a.input)])?;
    let bytes =
        std::fs::read(&a.input).with_context(|| format!("reading {}", a.input.display()))?;
    let old = Blob::parse(&bytes).map_err(|e| anyhow!("{}: {e}", a.input.display()))?;
    let version = old.header().version();
    let out = gman_host_sim::blob_edit::upgrade_blob(&bytes)
        .with_context(|| format!("upgrading {}", a.input.display()))?;
    std::fs::write(&a.output, &out).with_context(|| format!("writing {}", a.output.display()))?;
    let new = Blob::parse(&out).map_err(|e| anyhow!("the upgraded blob does not parse: {e}"))?;
    println!(
        "{} (format v{version}, {} bytes) -> {} (format v{}, {} bytes, checksum over the {})",
        a.input.display(),
        bytes.len(),
        a.output.display(),
        new.header().version(),
        out.len(),
        new.header().checksum_scope().describe()
    );
    Ok(())
}
