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
    /// Print the table and the comparisons as Markdown (for the results document).
    #[arg(long)]
    pub markdown: bool,
    /// Also draw every file's SR as a dot, with each row's mean ± std, unseen and seen targets
    /// side by side, into this PNG (the seed-to-seed spread at a glance).
    #[arg(long, value_name = "FILE")]
    pub png: Option<PathBuf>,
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
pub(super) fn mean_std(v: &[f64]) -> (f64, f64) {
    let n = v.len() as f64;
    let m = v.iter().sum::<f64>() / n;
    let s = if v.len() > 1 {
        (v.iter().map(|x| (x - m).powi(2)).sum::<f64>() / (n - 1.0)).sqrt()
    } else {
        0.0
    };
    (m, s)
}

/// Welch's t of `mean(a) − mean(b)` (unequal variances); NaN with fewer than two values on a
/// side or no spread at all.
pub(super) fn welch_t(a: &[f64], b: &[f64]) -> f64 {
    if a.len() < 2 || b.len() < 2 {
        return f64::NAN;
    }
    let ((ma, sa), (mb, sb)) = (mean_std(a), mean_std(b));
    let se = (sa * sa / a.len() as f64 + sb * sb / b.len() as f64).sqrt();
    if se > 0.0 {
        (ma - mb) / se
    } else {
        f64::NAN
    }
}

/// Paired t of the differences `a[i] − b[i]` (the same seeds on both sides); NaN with fewer
/// than two pairs or no spread.
pub(super) fn paired_t(a: &[f64], b: &[f64]) -> f64 {
    if a.len() != b.len() || a.len() < 2 {
        return f64::NAN;
    }
    let d: Vec<f64> = a.iter().zip(b).map(|(x, y)| x - y).collect();
    let (m, s) = mean_std(&d);
    if s > 0.0 {
        m / (s / (d.len() as f64).sqrt())
    } else {
        f64::NAN
    }
}

/// One row of the table: its label, the file names it averages and each file's eight metrics
/// (SR, SPL, EPA, DTS unseen, then seen).
struct Row {
    name: String,
    files: Vec<String>,
    vals: Vec<[f64; 8]>,
}

const METRICS: [&str; 4] = ["SR(%)", "SPL(%)", "EPA(%)", "DTS(m)"];

fn load_row(run: &Path) -> Result<Row> {
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
    let name = format!(
        "{} [{} x{}]",
        run.file_name()
            .map(|s| s.to_string_lossy().to_string())
            .unwrap_or_default(),
        split,
        files.len()
    );
    let files = files
        .iter()
        .map(|f| {
            f.file_name()
                .map_or(String::new(), |n| n.to_string_lossy().into_owned())
        })
        .collect();
    Ok(Row { name, files, vals })
}

/// The eight cells of a row: mean ± sample std, the mean alone for one file.
fn cells(r: &Row) -> Vec<String> {
    (0..8)
        .map(|i| {
            let (m, s) = mean_std(&r.vals.iter().map(|v| v[i]).collect::<Vec<_>>());
            if r.vals.len() > 1 {
                format!("{m:>6.2}±{s:<4.2}")
            } else {
                format!("{m:>6.2}     ")
            }
        })
        .collect()
}

/// A t value, or "-" where it is undefined (fewer than two files a side, or no spread).
fn t_cell(t: f64) -> String {
    if t.is_finite() {
        format!("{t:5.2}")
    } else {
        "    -".to_string()
    }
}

/// Each row's SR against the first row's: difference of the means, Welch's t, and the paired t
/// where both rows hold the same file names.
fn comparisons(rows: &[Row]) -> Vec<String> {
    let Some((first, rest)) = rows.split_first() else {
        return Vec::new();
    };
    let col = |v: &[[f64; 8]], i: usize| v.iter().map(|r| r[i]).collect::<Vec<_>>();
    let w = name_width(rows);
    rest.iter()
        .map(|r| {
            let paired = r.files == first.files;
            let d = |i: usize| {
                let (a, b) = (col(&first.vals, i), col(&r.vals, i));
                let p = if paired { paired_t(&a, &b) } else { f64::NAN };
                (mean_std(&a).0 - mean_std(&b).0, welch_t(&a, &b), p)
            };
            let ((du, tu, pu), (ds, ts, ps)) = (d(0), d(4));
            let pcell = |p: f64| {
                if paired {
                    format!(", paired t {}", t_cell(p))
                } else {
                    String::new()
                }
            };
            format!(
                "{:<w$} unseen {du:+6.2} (t {}{})  seen {ds:+6.2} (t {}{})",
                r.name,
                t_cell(tu),
                pcell(pu),
                t_cell(ts),
                pcell(ps)
            )
        })
        .collect()
}

/// `gman table`: Table 2/3 layout from evaluation JSON files, then each row's SR against the
/// first row's with Welch's t, and a paired t where both rows hold the same file names (the
/// same seeds, e.g. a run evaluated with adaptation on and off).
pub fn cmd_table(a: TableArgs) -> Result<()> {
    let rows = a
        .runs
        .iter()
        .map(|r| load_row(r))
        .collect::<Result<Vec<_>>>()?;
    if a.markdown {
        print_markdown(&rows);
    } else {
        print_text(&rows);
    }
    if let Some(png) = &a.png {
        draw_spread(&rows, png).with_context(|| format!("writing {}", png.display()))?;
        println!(
            "wrote {}: SR (%) of every file as a dot, each row's mean as a bar with ± one sample \
             std, unseen targets left, seen right",
            png.display()
        );
    }
    Ok(())
}

/// The row's label without its `[split xN]` suffix.
fn short_name(r: &Row) -> &str {
    r.name.split(" [").next().unwrap_or(&r.name)
}

/// The picture of `--png`: one panel per split, one line per row (the first on top), its
/// files' SR as dots, its mean as a vertical bar and ± one sample std as a horizontal one.
fn draw_spread(rows: &[Row], png: &Path) -> Result<()> {
    use plotters::prelude::*;
    let labels = gman_render::register_plot_font();
    let n = rows.len();
    let xmax = rows
        .iter()
        .flat_map(|r| r.vals.iter().flat_map(|v| [v[0], v[4]]))
        .filter(|v| v.is_finite())
        .fold(10.0, f64::max)
        * 1.1;
    let root = BitMapBackend::new(png, (1000, 90 + 55 * n as u32)).into_drawing_area();
    root.fill(&WHITE)?;
    for (area, (col, title)) in root.split_evenly((1, 2)).iter().zip([
        (0, "val SR (%), unseen targets"),
        (4, "val SR (%), seen targets"),
    ]) {
        let mut b = ChartBuilder::on(area);
        b.margin(12);
        if labels {
            b.caption(title, ("sans-serif", 18)).x_label_area_size(30);
        }
        let mut chart = b.build_cartesian_2d(0.0..xmax, -0.6..(n as f64 - 0.4))?;
        let mut mesh = chart.configure_mesh();
        mesh.x_labels(8).disable_y_axis().disable_y_mesh();
        if labels {
            mesh.label_style(("sans-serif", 13));
        } else {
            mesh.disable_x_axis();
        }
        mesh.draw()?;
        for (i, r) in rows.iter().enumerate() {
            let y = (n - 1 - i) as f64;
            let v: Vec<f64> = r.vals.iter().map(|v| v[col]).collect();
            let (m, sd) = mean_std(&v);
            if labels {
                chart.draw_series([Text::new(
                    short_name(r).to_string(),
                    (xmax * 0.01, y + 0.42),
                    ("sans-serif", 13),
                )])?;
            }
            let k = v.len().max(2) as f64 - 1.0;
            chart.draw_series(v.iter().enumerate().map(|(j, &x)| {
                Circle::new((x, y - 0.15 + 0.3 * j as f64 / k), 4, BLUE.filled())
            }))?;
            chart.draw_series([
                PathElement::new(vec![(m, y - 0.3), (m, y + 0.3)], RED.stroke_width(3)),
                PathElement::new(vec![(m - sd, y), (m + sd, y)], RED.stroke_width(2)),
            ])?;
        }
    }
    root.present()?;
    Ok(())
}

/// The width of the text form's method column: 28, or the longest row name.
fn name_width(rows: &[Row]) -> usize {
    rows.iter()
        .map(|r| r.name.chars().count())
        .max()
        .unwrap_or(0)
        .max(28)
}

fn print_text(rows: &[Row]) {
    let w = name_width(rows);
    println!(
        "{:<w$} | {:^47} | {:^47}",
        "Method", "Unseen Objects", "Seen Objects"
    );
    let heads = format!(
        "{:>11} {:>11} {:>11} {:>11}",
        METRICS[0], METRICS[1], METRICS[2], METRICS[3]
    );
    println!("{:<w$} | {heads} | {heads}", "");
    for r in rows {
        let c = cells(r);
        println!(
            "{:<w$} | {} | {}",
            r.name,
            c[..4].join(" "),
            c[4..].join(" ")
        );
    }
    println!("(mean ± sample std over the JSON files of each row; t is \"-\" with fewer than two files a side)");
    let lines = comparisons(rows);
    if !lines.is_empty() {
        println!(
            "SR against {} (difference of the means, Welch's t; paired t over the same \
             file names where both rows have them):",
            rows[0].name
        );
        for l in lines {
            println!("  − {l}");
        }
    }
}

fn print_markdown(rows: &[Row]) {
    let heads: Vec<String> = ["unseen", "seen"]
        .iter()
        .flat_map(|s| METRICS.iter().map(move |m| format!("{m} {s}")))
        .collect();
    println!("| method | {} |", heads.join(" | "));
    println!("|---|{}", "---:|".repeat(8));
    for r in rows {
        let c: Vec<String> = cells(r).iter().map(|c| c.trim().to_string()).collect();
        println!("| {} | {} |", r.name, c.join(" | "));
    }
    let lines = comparisons(rows);
    if !lines.is_empty() {
        println!();
        println!(
            "SR against {} (difference of the means, Welch's t; paired t over the same seeds):",
            rows[0].name
        );
        println!();
        for l in lines {
            println!("* {}", l.split_whitespace().collect::<Vec<_>>().join(" "));
        }
    }
}

#[cfg(test)]
mod tests {
    use super::welch_t;

    #[test]
    fn paired_t_matches_a_hand_computation() {
        // differences 1, 2, 3: mean 2, sd 1, t = 2 / (1 / sqrt 3)
        let t = super::paired_t(&[2.0, 4.0, 6.0], &[1.0, 2.0, 3.0]);
        assert!((t - 2.0 * 3f64.sqrt()).abs() < 1e-12, "{t}");
        assert!(super::paired_t(&[1.0, 2.0], &[1.0]).is_nan());
        assert!(super::paired_t(&[2.0, 3.0], &[1.0, 2.0]).is_nan());
    }

    /// The values `gman eval --json` writes read back exactly: a3c's five unseen SRs of the
    /// reference-budget sweep average to 11.935000000000000497..., which prints 11.94 (a
    /// reader off by one unit in the last place printed 11.93, and the table disagreed with
    /// its JSON files).
    #[test]
    fn eval_json_numbers_read_back_exactly() {
        let dir = std::env::temp_dir().join(format!("gman-table-exact-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        for (i, sr) in [
            "10.225000000000001",
            "13.475000000000001",
            "12.600000000000001",
            "10.600000000000001",
            "12.775",
        ]
        .iter()
        .enumerate()
        {
            let row =
                format!(r#"{{"episodes": 4000, "sr": {sr}, "spl": 1.0, "epa": 1.0, "dts": 1.0}}"#);
            let text =
                format!(r#"{{"split": "val", "results": {{"unseen": {row}, "seen": {row}}}}}"#);
            std::fs::write(dir.join(format!("s{}.json", i + 1)), text).unwrap();
        }
        let row = super::load_row(&dir).unwrap();
        std::fs::remove_dir_all(&dir).unwrap();
        assert_eq!(row.vals[0][0], 10.225000000000001);
        assert_eq!(super::cells(&row)[0].trim(), "11.94±1.43");
    }

    #[test]
    fn welch_t_matches_a_hand_computation() {
        // means 2 and 5, variances 1 and 4, n = 3 each: t = -3 / sqrt(1/3 + 4/3).
        let t = welch_t(&[1.0, 2.0, 3.0], &[3.0, 5.0, 7.0]);
        assert!((t - (-3.0 / (5.0f64 / 3.0).sqrt())).abs() < 1e-12, "{t}");
        assert!(welch_t(&[1.0], &[2.0, 3.0]).is_nan());
        assert!(welch_t(&[1.0, 1.0], &[1.0, 1.0]).is_nan());
    }
}
