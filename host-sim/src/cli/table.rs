//! `gman table`: the paper's table layout from evaluation JSON files.

use std::path::{Path, PathBuf};

use anyhow::{anyhow, bail, Context, Result};
use clap::Args;

/// `gman table`.
#[derive(Debug, Args)]
pub struct TableArgs {
    /// Evaluation JSON files, or directories of them (one row per argument: mean ± std over
    /// its files, like the paper's three seeds).
    #[arg(long, value_name = "DIR_OR_JSON", required = true, num_args = 1..)]
    pub runs: Vec<PathBuf>,
}

fn json_files(p: &Path) -> Result<Vec<PathBuf>> {
    if p.is_dir() {
        let mut v: Vec<PathBuf> = std::fs::read_dir(p)
            .with_context(|| format!("reading {}", p.display()))?
            .filter_map(|e| e.ok().map(|e| e.path()))
            .filter(|f| f.extension().is_some_and(|x| x == "json"))
            .collect();
        v.sort();
        if v.is_empty() {
            bail!("{} holds no .json evaluation files", p.display());
        }
        Ok(v)
    } else {
        Ok(vec![p.to_path_buf()])
    }
}

/// Mean and sample standard deviation.
fn mean_std(v: &[f64]) -> (f64, f64) {
    let n = v.len() as f64;
    let m = v.iter().sum::<f64>() / n;
    let s = if v.len() > 1 {
        (v.iter().map(|x| (x - m).powi(2)).sum::<f64>() / (n - 1.0)).sqrt()
    } else {
        0.0
    };
    (m, s)
}

/// `gman table`: Table 2/3 layout from evaluation JSON files.
pub fn cmd_table(a: TableArgs) -> Result<()> {
    println!(
        "{:<28} | {:^47} | {:^47}",
        "Method", "Unseen Objects", "Seen Objects"
    );
    println!(
        "{:<28} | {:>11} {:>11} {:>11} {:>11} | {:>11} {:>11} {:>11} {:>11}",
        "", "SR(%)", "SPL(%)", "EPA(%)", "DTS(m)", "SR(%)", "SPL(%)", "EPA(%)", "DTS(m)"
    );
    for run in &a.runs {
        let files = json_files(run)?;
        let mut vals: Vec<[f64; 8]> = Vec::new();
        let mut split = String::new();
        for f in &files {
            let text =
                std::fs::read_to_string(f).with_context(|| format!("reading {}", f.display()))?;
            let j: serde_json::Value =
                serde_json::from_str(&text).with_context(|| format!("parsing {}", f.display()))?;
            split = j["split"].as_str().unwrap_or("?").to_string();
            let g = |k: &str, m: &str| -> Result<f64> {
                j["results"][k][m]
                    .as_f64()
                    .ok_or_else(|| anyhow!("{}: results.{k}.{m} missing", f.display()))
            };
            vals.push([
                g("unseen", "sr")?,
                g("unseen", "spl")?,
                g("unseen", "epa")?,
                g("unseen", "dts")?,
                g("seen", "sr")?,
                g("seen", "spl")?,
                g("seen", "epa")?,
                g("seen", "dts")?,
            ]);
        }
        let cells: Vec<String> = (0..8)
            .map(|i| {
                let (m, s) = mean_std(&vals.iter().map(|v| v[i]).collect::<Vec<_>>());
                format!("{m:>6.2}±{s:<4.2}")
            })
            .collect();
        let name = format!(
            "{} [{} x{}]",
            run.file_name()
                .map(|s| s.to_string_lossy().to_string())
                .unwrap_or_default(),
            split,
            files.len()
        );
        println!(
            "{:<28} | {} | {}",
            name,
            cells[..4].join(" "),
            cells[4..].join(" ")
        );
    }
    println!("(mean ± sample std over the JSON files of each row)");
    Ok(())
}
