//! `gman shift-report`: the domain-shift study's table and picture from its kept evaluations
//! (`host-sim/scripts/shift-study.sh` writes `DIR/S/ROW/sN.json`, adaptation off
//! `DIR/S/ROW-adaptoff/sN.json`; `host-sim/scripts/shift-step0.sh` the zero-step control's
//! `DIR/S/ROW-int8/sN.json` and `DIR/S/ROW-int8-step0/sN.json`).

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use anyhow::{bail, Context, Result};
use clap::Args;

use super::table::{mean_std, paired_t, welch_t};

/// `gman shift-report`.
#[derive(Debug, Args)]
pub struct ShiftReportArgs {
    /// The study's folder: one sub-folder per domain shift S (`0`, `0.25`, ..., named by the
    /// level), each with one folder of `sN.json` evaluations per row.
    #[arg(long, value_name = "DIR", default_value = "results/shift")]
    pub dir: PathBuf,
    /// Print Markdown (for the results document) instead of text.
    #[arg(long)]
    pub markdown: bool,
    /// Draw unseen SR against S for every row (adaptation on solid, off dashed; mean ± one
    /// sample std over seeds) into this PNG.
    #[arg(long, value_name = "FILE")]
    pub png: Option<PathBuf>,
    /// Print instead the per-model table of the `gman emd-report` results kept in `DIR/emd/`
    /// (`S-sN.json`, the gman row's model at level S, seed N), on unseen targets, beside the
    /// model's adaptation on − off (`DIR/S/gman/sN.json` − `DIR/S/gman-adaptoff/sN.json`) and
    /// on − step 0 (`DIR/S/gman-int8/sN.json` − `DIR/S/gman-int8-step0/sN.json`).
    #[arg(long)]
    pub emd: bool,
}

/// One row at one level: seed -> (unseen SR, seen SR, unseen SPL).
type Seeds = BTreeMap<String, [f64; 3]>;

/// Level (as written) -> row -> seeds.
struct Study {
    levels: Vec<(f64, String)>,
    cells: BTreeMap<String, BTreeMap<String, Seeds>>,
}

fn number(v: &serde_json::Value, path: &[&str], file: &Path) -> Result<f64> {
    let mut x = v;
    for k in path {
        x = x
            .get(k)
            .with_context(|| format!("{}: no {}", file.display(), path.join(".")))?;
    }
    x.as_f64()
        .with_context(|| format!("{}: {} is not a number", file.display(), path.join(".")))
}

/// A kept JSON file, its errors naming it.
fn read_json(p: &Path) -> Result<serde_json::Value> {
    let text = std::fs::read_to_string(p).with_context(|| format!("reading {}", p.display()))?;
    serde_json::from_str(&text).with_context(|| format!("parsing {}", p.display()))
}

fn read_seeds(dir: &Path) -> Result<Seeds> {
    let mut out = Seeds::new();
    for e in std::fs::read_dir(dir).with_context(|| format!("reading {}", dir.display()))? {
        let p = e?.path();
        let name = p.file_name().and_then(|n| n.to_str()).unwrap_or_default();
        if !(name.starts_with('s') && name.ends_with(".json")) {
            continue;
        }
        let v = read_json(&p)?;
        let seed = name.trim_end_matches(".json").to_string();
        out.insert(
            seed,
            [
                number(&v, &["results", "unseen", "sr"], &p)?,
                number(&v, &["results", "seen", "sr"], &p)?,
                number(&v, &["results", "unseen", "spl"], &p)?,
            ],
        );
    }
    Ok(out)
}

fn read_study(dir: &Path) -> Result<Study> {
    let mut levels = Vec::new();
    let mut cells = BTreeMap::new();
    for e in std::fs::read_dir(dir).with_context(|| format!("reading {}", dir.display()))? {
        let p = e?.path();
        let Some(name) = p.file_name().and_then(|n| n.to_str()).map(str::to_string) else {
            continue;
        };
        let Ok(s) = name.parse::<f64>() else { continue };
        if !p.is_dir() {
            continue;
        }
        let mut rows = BTreeMap::new();
        for r in std::fs::read_dir(&p)? {
            let rp = r?.path();
            let Some(row) = rp.file_name().and_then(|n| n.to_str()).map(str::to_string) else {
                continue;
            };
            if rp.is_dir() && !matches!(row.as_str(), "runs" | "models" | "ps" | "fg" | "bin") {
                let seeds = read_seeds(&rp)?;
                if !seeds.is_empty() {
                    rows.insert(row, seeds);
                }
            }
        }
        levels.push((s, name.clone()));
        cells.insert(name, rows);
    }
    if levels.is_empty() {
        bail!(
            "{}: no level folders (named by the domain shift, e.g. 0.5/) with evaluations",
            dir.display()
        );
    }
    levels.sort_by(|a, b| a.0.total_cmp(&b.0));
    Ok(Study { levels, cells })
}

/// The rows in the study's order, then any other.
fn row_order(study: &Study) -> Vec<String> {
    const ORDER: [&str; 14] = [
        "random",
        "a3c",
        "a3c-fg",
        "gman-noemd",
        "gman",
        "gman-adaptoff",
        "gman-ref",
        "gman-ref-adaptoff",
        "privileged",
        "gman-nometa",
        "gman-int8",
        "gman-int8-step0",
        "gman-ref-int8",
        "gman-ref-int8-step0",
    ];
    let mut all: Vec<String> = study
        .cells
        .values()
        .flat_map(|r| r.keys().cloned())
        .collect();
    all.sort();
    all.dedup();
    let mut out: Vec<String> = ORDER
        .iter()
        .filter(|r| all.iter().any(|a| a == *r))
        .map(|r| r.to_string())
        .collect();
    out.extend(all.into_iter().filter(|a| !ORDER.contains(&a.as_str())));
    out
}

fn col(seeds: &Seeds, k: usize) -> Vec<f64> {
    seeds.values().map(|v| v[k]).collect()
}

fn fmt_cell(seeds: Option<&Seeds>) -> String {
    match seeds {
        None => "".into(),
        Some(s) => {
            let (u, us) = mean_std(&col(s, 0));
            let (se, ss) = mean_std(&col(s, 1));
            let (p, _) = mean_std(&col(s, 2));
            if s.len() < 2 {
                // One seed has no spread.
                return format!("{u:.2} / {se:.2} / {p:.2} (1)");
            }
            format!("{u:.2}±{us:.2} / {se:.2}±{ss:.2} / {p:.2} ({})", s.len())
        }
    }
}

/// `a − b` in unseen SR with Welch's t, or the paired t when `paired` (same seeds).
fn compare(a: Option<&Seeds>, b: Option<&Seeds>, paired: bool) -> String {
    let (Some(a), Some(b)) = (a, b) else {
        return "".into();
    };
    if paired {
        let common: Vec<&String> = a.keys().filter(|k| b.contains_key(*k)).collect();
        let x: Vec<f64> = common.iter().map(|k| a[*k][0]).collect();
        let y: Vec<f64> = common.iter().map(|k| b[*k][0]).collect();
        let d = mean_std(&x).0 - mean_std(&y).0;
        format!(
            "{d:+.2} (paired t {}, {})",
            fmt_t(paired_t(&x, &y)),
            x.len()
        )
    } else {
        let (x, y) = (col(a, 0), col(b, 0));
        let d = mean_std(&x).0 - mean_std(&y).0;
        format!("{d:+.2} (Welch t {})", fmt_t(welch_t(&x, &y)))
    }
}

/// A t statistic, or `n/a` where it has no value (one seed, or no spread at all).
fn fmt_t(t: f64) -> String {
    if t.is_finite() {
        format!("{t:.2}")
    } else {
        "n/a".into()
    }
}

/// One table line: a Markdown row, or the cells two spaces apart.
fn print_line(cells: &[String], markdown: bool) {
    if markdown {
        println!("| {} |", cells.join(" | "));
    } else {
        println!("{}", cells.join("  "));
    }
}

fn print(study: &Study, markdown: bool) {
    let rows = row_order(study);
    let line = |cells: Vec<String>| print_line(&cells, markdown);
    println!("Val SR unseen ± std / seen ± std / unseen SPL (seeds), per domain shift S:");
    println!();
    let mut head = vec!["row".to_string()];
    head.extend(study.levels.iter().map(|(_, n)| format!("S = {n}")));
    let n = head.len();
    line(head);
    if markdown {
        println!("|{}", "---|".repeat(n));
    }
    for r in &rows {
        let mut cells = vec![r.clone()];
        for (_, l) in &study.levels {
            cells.push(fmt_cell(study.cells[l].get(r)));
        }
        line(cells);
    }
    println!();
    println!("Unseen SR differences per level:");
    println!();
    let mut head = vec!["S".to_string()];
    let pairs: [(&str, &str, &str, bool); 7] = [
        ("gman − gman-noemd", "gman", "gman-noemd", false),
        ("gman − a3c-fg", "gman", "a3c-fg", false),
        ("gman on − off", "gman", "gman-adaptoff", true),
        (
            "gman on − step 0 (int8)",
            "gman-int8",
            "gman-int8-step0",
            true,
        ),
        ("gman-ref on − off", "gman-ref", "gman-ref-adaptoff", true),
        (
            "gman-ref on − step 0 (int8)",
            "gman-ref-int8",
            "gman-ref-int8-step0",
            true,
        ),
        ("a3c − random", "a3c", "random", false),
    ];
    head.extend(pairs.iter().map(|p| p.0.to_string()));
    let n = head.len();
    line(head);
    if markdown {
        println!("|{}", "---|".repeat(n));
    }
    for (_, l) in &study.levels {
        let c = &study.cells[l];
        let mut cells = vec![l.clone()];
        for (_, a, b, paired) in pairs {
            cells.push(compare(c.get(a), c.get(b), paired));
        }
        line(cells);
    }
    println!();
}

/// One kept `gman emd-report` result: level, seed, and its unseen-target figures.
struct EmdRow {
    level: (f64, String),
    seed: u32,
    moved: f64,
    closed_percent: f64,
    adaptations: f64,
    rollbacks_per_update: f64,
}

/// Reads `DIR/emd/S-sN.json`, ordered by level then seed.
fn read_emd(dir: &Path) -> Result<Vec<EmdRow>> {
    let emd = dir.join("emd");
    let mut out = Vec::new();
    for e in std::fs::read_dir(&emd).with_context(|| format!("reading {}", emd.display()))? {
        let p = e?.path();
        let name = p.file_name().and_then(|n| n.to_str()).unwrap_or_default();
        let Some(stem) = name.strip_suffix(".json") else {
            continue;
        };
        let parsed = stem.rsplit_once("-s").and_then(|(l, n)| {
            let s = l.parse::<f64>().ok()?;
            Some(((s, l.to_string()), n.parse::<u32>().ok()?))
        });
        let Some((level, seed)) = parsed else {
            bail!(
                "{}: not named S-sN.json (level S, seed N, e.g. 0.5-s2.json)",
                p.display()
            );
        };
        let v = read_json(&p)?;
        out.push(EmdRow {
            level,
            seed,
            moved: number(&v, &["unseen", "moved"], &p)?,
            closed_percent: number(&v, &["unseen", "closed_percent"], &p)?,
            adaptations: number(&v, &["unseen", "adaptations"], &p)?,
            rollbacks_per_update: number(&v, &["unseen", "rollbacks_per_update"], &p)?,
        });
    }
    if out.is_empty() {
        bail!("{}: no emd-report results (S-sN.json)", emd.display());
    }
    out.sort_by(|a, b| a.level.0.total_cmp(&b.level.0).then(a.seed.cmp(&b.seed)));
    Ok(out)
}

/// The per-model table of `--emd`.
fn print_emd(study: &Study, rows: &[EmdRow], markdown: bool) {
    let head = [
        "S",
        "seed",
        "on − off unseen SR",
        "on − step 0 (int8)",
        "G moved",
        "distance to the true feature closed",
        "inner updates per episode",
        "rollbacks per update",
    ];
    let line = |cells: &[String]| print_line(cells, markdown);
    println!("Inner-loop effect on unseen targets, per gman model (gman emd-report):");
    println!();
    line(&head.map(String::from));
    if markdown {
        println!("|---|---|---:|---:|---:|---:|---:|---:|");
    }
    for r in rows {
        let seed = format!("s{}", r.seed);
        let cell = |row: &str| {
            study
                .cells
                .get(&r.level.1)
                .and_then(|c| c.get(row))
                .and_then(|s| s.get(&seed))
                .map(|v| v[0])
        };
        let diff = |on: &str, off: &str| match (cell(on), cell(off)) {
            (Some(on), Some(off)) => format!("{:+.2}", on - off),
            _ => "".into(),
        };
        line(&[
            r.level.1.clone(),
            r.seed.to_string(),
            diff("gman", "gman-adaptoff"),
            diff("gman-int8", "gman-int8-step0"),
            format!("{:.3}", r.moved),
            format!("{:+.1}%", r.closed_percent),
            format!("{:.2}", r.adaptations),
            format!("{:.2}", r.rollbacks_per_update),
        ]);
    }
    println!();
}

/// Unseen SR against S, one line per row (not the zero-step control's `-int8` rows, which
/// repeat `gman` and `gman-ref` on the int8 blobs: their on − step 0 is in the table).
fn draw(study: &Study, png: &Path) -> Result<()> {
    use plotters::prelude::*;
    let labels = gman_render::register_plot_font();
    let rows: Vec<String> = row_order(study)
        .into_iter()
        .filter(|r| !r.contains("-int8"))
        .collect();
    let xmax = study.levels.last().map_or(1.0, |l| l.0).max(1.0) * 1.05;
    let ymax = study
        .cells
        .values()
        .flat_map(|r| r.values().flat_map(|s| s.values().map(|v| v[0])))
        .fold(10.0, f64::max)
        * 1.6;
    let root = BitMapBackend::new(png, (900, 600)).into_drawing_area();
    root.fill(&WHITE)?;
    let mut b = ChartBuilder::on(&root);
    b.margin(16);
    if labels {
        b.caption(
            "val SR on unseen targets against the domain shift S",
            ("sans-serif", 20),
        )
        .x_label_area_size(40)
        .y_label_area_size(50);
    }
    let mut chart = b.build_cartesian_2d(-0.05..xmax, 0.0..ymax)?;
    let mut mesh = chart.configure_mesh();
    if labels {
        mesh.x_desc("domain shift S (1: the default simulator)")
            .y_desc("unseen SR (%), mean ± std over seeds")
            .label_style(("sans-serif", 14));
    }
    mesh.draw()?;
    for (i, r) in rows.iter().enumerate() {
        let colour = Palette99::pick(i).to_rgba();
        let off = r.ends_with("-adaptoff");
        let pts: Vec<(f64, f64, f64)> = study
            .levels
            .iter()
            .filter_map(|(s, l)| {
                let seeds = study.cells[l].get(r)?;
                let (m, sd) = mean_std(&col(seeds, 0));
                Some((*s, m, sd))
            })
            .collect();
        let style = ShapeStyle {
            color: colour,
            filled: false,
            stroke_width: 2,
        };
        let path: Vec<(f64, f64)> = pts.iter().map(|p| (p.0, p.1)).collect();
        let series = if off {
            chart.draw_series(DashedLineSeries::new(path, 8, 5, style))?
        } else {
            chart.draw_series(LineSeries::new(path, style))?
        };
        if labels {
            series.label(r.clone()).legend(move |(x, y)| {
                PathElement::new(vec![(x, y), (x + 18, y)], colour.stroke_width(2))
            });
        }
        chart.draw_series(pts.iter().map(|&(s, m, sd)| {
            PathElement::new(vec![(s, m - sd), (s, m + sd)], colour.stroke_width(1))
        }))?;
        chart.draw_series(
            pts.iter()
                .map(|&(s, m, _)| Circle::new((s, m), 3, colour.filled())),
        )?;
    }
    if labels {
        chart
            .configure_series_labels()
            .position(SeriesLabelPosition::UpperRight)
            .background_style(WHITE.mix(0.85))
            .border_style(BLACK)
            .label_font(("sans-serif", 14))
            .draw()?;
    }
    root.present()?;
    Ok(())
}

/// Runs `gman shift-report`.
pub fn cmd_shift_report(a: ShiftReportArgs) -> Result<()> {
    let study = read_study(&a.dir)?;
    if a.emd {
        print_emd(&study, &read_emd(&a.dir)?, a.markdown);
    } else {
        print(&study, a.markdown);
    }
    if let Some(png) = &a.png {
        draw(&study, png).with_context(|| format!("drawing {}", png.display()))?;
        eprintln!("wrote {}", png.display());
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn write(dir: &Path, rel: &str, unseen: f64) {
        let p = dir.join(rel);
        std::fs::create_dir_all(p.parent().unwrap()).unwrap();
        let j = serde_json::json!({"results": {
            "unseen": {"sr": unseen, "spl": 1.0},
            "seen": {"sr": 2.0 * unseen, "spl": 1.0}}});
        std::fs::write(p, j.to_string()).unwrap();
    }

    #[test]
    fn reads_levels_in_numeric_order_and_pairs_seeds() {
        let d = std::env::temp_dir().join(format!("gman-shift-report-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&d);
        write(&d, "2/gman/s1.json", 20.0);
        write(&d, "2/gman/s2.json", 22.0);
        write(&d, "2/gman-adaptoff/s1.json", 19.0);
        write(&d, "2/gman-adaptoff/s2.json", 20.0);
        write(&d, "0.25/a3c/s1.json", 10.0);
        std::fs::create_dir_all(d.join("0.25/runs/x")).unwrap();
        let s = read_study(&d).unwrap();
        let names: Vec<&str> = s.levels.iter().map(|l| l.1.as_str()).collect();
        assert_eq!(names, ["0.25", "2"]);
        assert!(!s.cells["0.25"].contains_key("runs"));
        let c = &s.cells["2"];
        // differences 1 and 2: mean 1.5, std 0.707, paired t 3
        let cmp = compare(c.get("gman"), c.get("gman-adaptoff"), true);
        assert!(cmp.starts_with("+1.50 (paired t 3.00, 2)"), "{cmp}");
        assert_eq!(compare(c.get("gman"), None, false), "");
        // One seed: no spread, no t.
        let one = &s.cells["0.25"]["a3c"];
        assert_eq!(fmt_cell(Some(one)), "10.00 / 20.00 / 1.00 (1)");
        assert_eq!(compare(Some(one), Some(one), false), "+0.00 (Welch t n/a)");
        let _ = std::fs::remove_dir_all(&d);
        assert!(read_study(&d).is_err());
    }

    #[test]
    fn emd_rows_are_ordered_and_misnamed_files_refused() {
        let d = std::env::temp_dir().join(format!("gman-shift-emd-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&d);
        std::fs::create_dir_all(d.join("emd")).unwrap();
        let emd = |rel: &str, moved: f64| {
            let j = serde_json::json!({"unseen": {"moved": moved, "closed_percent": -1.5,
                "adaptations": 2.5, "rollbacks_per_update": 0.0}});
            std::fs::write(d.join("emd").join(rel), j.to_string()).unwrap();
        };
        emd("2-s1.json", 0.5);
        emd("0.25-s10.json", 0.25);
        emd("0.25-s2.json", 0.125);
        let rows = read_emd(&d).unwrap();
        let order: Vec<(&str, u32)> = rows.iter().map(|r| (r.level.1.as_str(), r.seed)).collect();
        assert_eq!(order, [("0.25", 2), ("0.25", 10), ("2", 1)]);
        assert_eq!(rows[2].moved, 0.5);
        // A file without a number where one belongs names the file.
        std::fs::write(d.join("emd/1-s1.json"), r#"{"unseen": {"moved": "x"}}"#).unwrap();
        let e = format!("{:#}", read_emd(&d).err().unwrap());
        assert!(e.contains("1-s1.json") && e.contains("unseen.moved"), "{e}");
        std::fs::remove_file(d.join("emd/1-s1.json")).unwrap();
        std::fs::write(d.join("emd/gman.json"), "{}").unwrap();
        let e = format!("{:#}", read_emd(&d).err().unwrap());
        assert!(e.contains("gman.json") && e.contains("S-sN.json"), "{e}");
        let _ = std::fs::remove_dir_all(&d);
    }
}
