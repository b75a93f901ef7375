//! `gman plot`: learning curves of training runs: the training success rate from each run's
//! `metrics.csv` and, where the run has them, the val success rates measured during training
//! (`RUN/curve/kN.json` beside `kN.at`, as `host-sim/scripts/paper-tables.sh` writes them).

use std::io::Read;
use std::path::{Path, PathBuf};

use anyhow::{anyhow, bail, Context, Result};
use clap::Args;

/// `gman plot`.
#[derive(Debug, Args)]
pub struct PlotArgs {
    /// Run directories (each with metrics.csv, or metrics.csv.gz); one colour per run.
    #[arg(long = "run", value_name = "RUN_DIR", required = true, num_args = 1..)]
    pub runs: Vec<PathBuf>,
    /// Output PNG.
    #[arg(long, value_name = "OUT.png")]
    pub png: PathBuf,
    /// Moving-average window (updates).
    #[arg(long, default_value_t = 50)]
    pub smooth: usize,
    /// One curve per method: runs whose directory names differ only in a trailing `-sN`
    /// (the seed) are averaged, and the legend says over how many seeds.
    #[arg(long)]
    pub by_method: bool,
}

/// One val evaluation during training: (env_steps, unseen SR %, seen SR %).
type ValPoint = (f64, f64, f64);

/// The val points of a run, in step order (empty when it has no `curve/`).
fn read_val_curve(run: &Path) -> Result<Vec<ValPoint>> {
    let dir = run.join("curve");
    let Ok(rd) = std::fs::read_dir(&dir) else {
        return Ok(Vec::new());
    };
    let mut out = Vec::new();
    for e in rd {
        let path = e
            .with_context(|| format!("listing {}", dir.display()))?
            .path();
        if path.extension().and_then(|x| x.to_str()) != Some("json") {
            continue;
        }
        let at = path.with_extension("at");
        let at_text = std::fs::read_to_string(&at).with_context(|| {
            format!(
                "reading {} (the step count of {})",
                at.display(),
                path.display()
            )
        })?;
        let steps: f64 = at_text
            .trim()
            .split(',')
            .nth(1)
            .and_then(|v| v.parse().ok())
            .ok_or_else(|| {
                anyhow!(
                    "{}: expected \"update,env_steps\", got {at_text:?}",
                    at.display()
                )
            })?;
        let text = std::fs::read_to_string(&path)
            .with_context(|| format!("reading {}", path.display()))?;
        let j: serde_json::Value = serde_json::from_str(&text)
            .with_context(|| format!("{} is not an evaluation JSON", path.display()))?;
        let sr = |split: &str| {
            j["results"][split]["sr"]
                .as_f64()
                .ok_or_else(|| anyhow!("{} has no results.{split}.sr", path.display()))
        };
        out.push((steps, sr("unseen")?, sr("seen")?));
    }
    out.sort_by(|a, b| a.0.total_cmp(&b.0));
    Ok(out)
}

/// One curve of the picture: its label, training rows and val points.
struct Curve {
    label: String,
    train: Vec<MetricRow>,
    val: Vec<ValPoint>,
}

/// The method of a run directory: its name without a trailing `-sN`.
fn method_of(run: &Path) -> String {
    let name = run
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_else(|| run.display().to_string());
    match name.rsplit_once("-s") {
        Some((m, seed)) if !seed.is_empty() && seed.bytes().all(|b| b.is_ascii_digit()) => {
            m.to_string()
        }
        _ => name,
    }
}

/// Averages runs of one method: the training rows (already smoothed) on a common grid of
/// environment steps within the range every seed covers, the val points by position.
fn average(label: String, runs: &[Curve], smooth_w: usize) -> Curve {
    let end = runs
        .iter()
        .map(|r| r.train.last().map_or(0.0, |p| p.0))
        .fold(f64::INFINITY, f64::min);
    let smoothed: Vec<Vec<MetricRow>> = runs.iter().map(|r| smoothed(&r.train, smooth_w)).collect();
    let at = |m: &[MetricRow], x: f64| -> (f64, f64) {
        let i = m.partition_point(|p| p.0 < x).min(m.len() - 1);
        (m[i].1, m[i].2)
    };
    let n = runs.len() as f64;
    let train = (1..=400)
        .map(|i| {
            let x = end * i as f64 / 400.0;
            let (s, w) = smoothed
                .iter()
                .map(|m| at(m, x))
                .fold((0.0, 0.0), |a, b| (a.0 + b.0, a.1 + b.1));
            (x, s / n, w / n)
        })
        .collect();
    let points = runs.iter().map(|r| r.val.len()).min().unwrap_or(0);
    let val = (0..points)
        .map(|k| {
            let sum = runs.iter().fold((0.0, 0.0, 0.0), |a, r| {
                (a.0 + r.val[k].0, a.1 + r.val[k].1, a.2 + r.val[k].2)
            });
            (sum.0 / n, sum.1 / n, sum.2 / n)
        })
        .collect();
    Curve {
        label: match runs.len() {
            1 => format!("{label} (1 seed)"),
            n => format!("{label} (mean of {n} seeds)"),
        },
        train,
        val,
    }
}

/// One row of a run's metrics: (env_steps, success_rate, mean_reward).
type MetricRow = (f64, f64, f64);

/// The text of a run's `metrics.csv`, or of its gzip-compressed `metrics.csv.gz` (what
/// `host-sim/scripts/paper-keep.sh` keeps of a finished run), and the path it came from.
fn metrics_text(run: &Path) -> Result<(PathBuf, String)> {
    let path = run.join("metrics.csv");
    let gz = run.join("metrics.csv.gz");
    if !path.exists() && gz.exists() {
        let mut text = String::new();
        flate2::read::GzDecoder::new(
            std::fs::File::open(&gz).with_context(|| format!("reading {}", gz.display()))?,
        )
        .read_to_string(&mut text)
        .with_context(|| format!("reading {} (gzip)", gz.display()))?;
        return Ok((gz, text));
    }
    let text = std::fs::read_to_string(&path)
        .with_context(|| format!("reading {} (nor is there a metrics.csv.gz)", path.display()))?;
    Ok((path, text))
}

/// Reads `metrics.csv` (or `metrics.csv.gz`) of a run.
fn read_metrics(run: &Path) -> Result<Vec<MetricRow>> {
    let (path, text) = metrics_text(run)?;
    let mut lines = text.lines();
    let header: Vec<&str> = lines
        .next()
        .ok_or_else(|| anyhow!("{} is empty", path.display()))?
        .split(',')
        .collect();
    let col = |n: &str| {
        header
            .iter()
            .position(|h| *h == n)
            .ok_or_else(|| anyhow!("{} has no column {n}", path.display()))
    };
    if header.first() != Some(&"update") {
        bail!(
            "{} line 1 is not the metrics header (it starts with {:?})",
            path.display(),
            header.first().copied().unwrap_or("")
        );
    }
    let (cs, csr, cr) = (col("env_steps")?, col("success_rate")?, col("mean_reward")?);
    let mut out = Vec::new();
    for (i, l) in lines.enumerate() {
        let f: Vec<&str> = l.split(',').collect();
        let bad = |what: &str| {
            anyhow!(
                "{} line {}: {what}: {l:?} (a resumed `gman train` repairs the file)",
                path.display(),
                i + 2
            )
        };
        if f.len() != header.len() {
            return Err(bad(&format!(
                "{} columns, the header has {}",
                f.len(),
                header.len()
            )));
        }
        let g = |c: usize| -> Result<f64> {
            f.get(c)
                .and_then(|v| v.parse::<f64>().ok())
                .filter(|v| v.is_finite())
                .ok_or_else(|| bad(&format!("column {} is not a finite number", header[c])))
        };
        out.push((g(cs)?, g(csr)?, g(cr)?));
    }
    if out.is_empty() {
        bail!("{} has no data rows", path.display());
    }
    Ok(out)
}

fn smooth(v: &[f64], w: usize) -> Vec<f64> {
    let w = w.max(1);
    (0..v.len())
        .map(|i| {
            let a = i.saturating_sub(w - 1);
            v[a..=i].iter().sum::<f64>() / (i - a + 1) as f64
        })
        .collect()
}

/// Smooths a run's training rows (success rate and reward) with a moving average.
fn smoothed(m: &[MetricRow], w: usize) -> Vec<MetricRow> {
    let sr = smooth(&m.iter().map(|p| p.1).collect::<Vec<_>>(), w);
    let rw = smooth(&m.iter().map(|p| p.2).collect::<Vec<_>>(), w);
    m.iter()
        .zip(sr)
        .zip(rw)
        .map(|((p, s), r)| (p.0, s, r))
        .collect()
}

/// Reads the runs and, with `--by-method`, averages each method's seeds.
fn curves(a: &PlotArgs) -> Result<Vec<Curve>> {
    let runs: Vec<Curve> = a
        .runs
        .iter()
        .map(|r| {
            Ok(Curve {
                label: r.file_name().map_or_else(
                    || r.display().to_string(),
                    |n| n.to_string_lossy().into_owned(),
                ),
                train: read_metrics(r)?,
                val: read_val_curve(r)?,
            })
        })
        .collect::<Result<_>>()?;
    if !a.by_method {
        return Ok(runs
            .into_iter()
            .map(|c| Curve {
                train: smoothed(&c.train, a.smooth),
                ..c
            })
            .collect());
    }
    let mut groups: Vec<(String, Vec<Curve>)> = Vec::new();
    for (dir, c) in a.runs.iter().zip(runs) {
        let m = method_of(dir);
        match groups.iter_mut().find(|g| g.0 == m) {
            Some(g) => g.1.push(c),
            None => groups.push((m, vec![c])),
        }
    }
    Ok(groups
        .into_iter()
        .map(|(m, cs)| average(m, &cs, a.smooth))
        .collect())
}

const COLOUR_NAMES: [&str; 8] = [
    "red", "blue", "green", "magenta", "cyan", "black", "orange", "purple",
];

/// What a panel draws: the training success rate, the reward, the val SR on unseen or on
/// seen targets.
#[derive(Clone, Copy, PartialEq)]
enum Series {
    TrainSr,
    Reward,
    ValUnseen,
    ValSeen,
}

impl Series {
    fn points(self, c: &Curve) -> Vec<(f64, f64)> {
        match self {
            Series::TrainSr => c.train.iter().map(|p| (p.0, p.1)).collect(),
            Series::Reward => c.train.iter().map(|p| (p.0, p.2)).collect(),
            Series::ValUnseen => c.val.iter().map(|p| (p.0, p.1)).collect(),
            Series::ValSeen => c.val.iter().map(|p| (p.0, p.2)).collect(),
        }
    }
}

/// One panel of the picture: its y range, series and title.
type Panel = ((f64, f64), Series, &'static str);

/// The panels: training SR, then val unseen / seen where the runs have val points, else the
/// reward.
fn panels(curves: &[Curve]) -> Vec<Panel> {
    let train = (
        (0.0, 1.0),
        Series::TrainSr,
        "training success rate (moving average)",
    );
    if curves.iter().any(|c| !c.val.is_empty()) {
        let vmax = curves
            .iter()
            .flat_map(|c| c.val.iter().flat_map(|p| [p.1, p.2]))
            .fold(10.0, f64::max)
            * 1.1;
        vec![
            train,
            (
                (0.0, vmax),
                Series::ValUnseen,
                "val success rate (%), unseen targets",
            ),
            (
                (0.0, vmax),
                Series::ValSeen,
                "val success rate (%), seen targets",
            ),
        ]
    } else {
        let rewards = || curves.iter().flat_map(|c| c.train.iter().map(|p| p.2));
        let (lo, hi) = (rewards().fold(0.0, f64::min), rewards().fold(1.0, f64::max));
        vec![
            train,
            (
                (lo, hi),
                Series::Reward,
                "mean episode reward (moving average)",
            ),
        ]
    }
}

/// The step axis' unit for a run of `xmax` steps: thousands below 2 M steps (a demo's 94 k
/// steps read 0, 10, 20, ... k), else millions with one decimal; every tick then differs.
fn step_axis(xmax: f64) -> (&'static str, fn(f64) -> String) {
    if xmax < 2e6 {
        ("environment steps (thousands)", |x| {
            format!("{:.0}k", x / 1e3)
        })
    } else {
        ("environment steps (millions)", |x| {
            format!("{:.1}M", x / 1e6)
        })
    }
}

/// Draws one panel with every curve in it.
fn draw_panel<DB: plotters::prelude::DrawingBackend>(
    area: &plotters::prelude::DrawingArea<DB, plotters::coord::Shift>,
    (range, series, title): &Panel,
    curves: &[Curve],
    xmax: f64,
    labels: bool,
) -> Result<()>
where
    DB::ErrorType: 'static,
{
    use plotters::prelude::*;
    // One legend, on the training curves' top left (empty while they start near zero): the
    // colours are the same in every panel, and a legend over the val panels hid their ends.
    let legend = labels && *series == Series::TrainSr;
    let colors = [
        RED,
        BLUE,
        GREEN,
        MAGENTA,
        CYAN,
        BLACK,
        RGBColor(255, 128, 0),
        RGBColor(128, 0, 255),
    ];
    let mut b = ChartBuilder::on(area);
    b.margin(15);
    if labels {
        b.caption(*title, ("sans-serif", 20))
            .x_label_area_size(35)
            .y_label_area_size(55);
    }
    let mut chart = b.build_cartesian_2d(0.0..xmax, range.0..range.1)?;
    let mut mesh = chart.configure_mesh();
    mesh.x_labels(8).y_labels(6);
    let (x_desc, x_fmt) = step_axis(xmax);
    let x_fmt = |x: &f64| x_fmt(*x);
    if labels {
        mesh.x_desc(x_desc)
            .x_label_formatter(&x_fmt)
            .label_style(("sans-serif", 14));
    } else {
        mesh.disable_x_axis().disable_y_axis();
    }
    mesh.draw()?;
    for (i, c) in curves.iter().enumerate() {
        let col = colors[i % colors.len()];
        let pts = series.points(c);
        if matches!(series, Series::ValUnseen | Series::ValSeen) {
            chart.draw_series(pts.iter().map(|&p| Circle::new(p, 3, col.filled())))?;
        }
        let s = chart.draw_series(LineSeries::new(pts, col.stroke_width(2)))?;
        if legend {
            s.label(c.label.clone()).legend(move |(x, y)| {
                PathElement::new(vec![(x, y), (x + 20, y)], col.stroke_width(2))
            });
        }
    }
    if legend {
        chart
            .configure_series_labels()
            .position(SeriesLabelPosition::UpperLeft)
            .background_style(WHITE.mix(0.8))
            .border_style(BLACK)
            .label_font(("sans-serif", 13))
            .draw()?;
    }
    Ok(())
}

/// `gman plot`: learning curves (success rate and reward against environment steps, and the
/// val success rates measured during training where the runs have them).
pub fn cmd_plot(a: PlotArgs) -> Result<()> {
    use plotters::prelude::*;
    let curves = curves(&a)?;
    let labels = gman_render::register_plot_font();
    let xmax = curves
        .iter()
        .flat_map(|c| c.train.iter().map(|p| p.0).chain(c.val.iter().map(|p| p.0)))
        .fold(1.0, f64::max);
    let panels = panels(&curves);
    {
        let root =
            BitMapBackend::new(&a.png, (1000, 400 * panels.len() as u32)).into_drawing_area();
        root.fill(&WHITE)?;
        for (area, panel) in root.split_evenly((panels.len(), 1)).iter().zip(&panels) {
            draw_panel(area, panel, &curves, xmax, labels)?;
        }
        root.present()?;
    }
    let has_val = panels.len() == 3;
    println!(
        "wrote {}: {}, x = environment steps (0..{xmax:.0}), moving average over {} updates{}{}",
        a.png.display(),
        if has_val {
            "top = training success rate (0..1), middle / bottom = val SR (%) on unseen / seen targets measured during training"
        } else {
            "top = training success rate (0..1), bottom = mean episode reward"
        },
        a.smooth,
        if a.by_method { ", seeds averaged" } else { "" },
        if labels {
            ""
        } else {
            " (no system font found: the PNG has no text)"
        }
    );
    for (i, c) in curves.iter().enumerate() {
        let last = c.train.last().map_or(f64::NAN, |p| p.1);
        let val = c.val.last().map_or(String::new(), |p| {
            format!(", last val SR {:.2} / {:.2} at {:.0} steps", p.1, p.2, p.0)
        });
        println!(
            "  colour {}: {} (final smoothed training success {:.1}%{val})",
            COLOUR_NAMES[i % 8],
            c.label,
            100.0 * last
        );
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn step_axis_labels_of_a_short_run_are_distinct_thousands() {
        let (desc, f) = super::step_axis(93_988.0);
        assert_eq!(desc, "environment steps (thousands)");
        let ticks: Vec<String> = (0..10).map(|i| f(i as f64 * 10_000.0)).collect();
        assert_eq!(ticks[..3], ["0k", "10k", "20k"]);
        let mut dedup = ticks.clone();
        dedup.dedup();
        assert_eq!(dedup, ticks);
        let (desc, f) = super::step_axis(8.77e6);
        assert_eq!(
            (desc, f(2.5e6).as_str()),
            ("environment steps (millions)", "2.5M")
        );
    }

    #[test]
    fn method_of_strips_only_a_seed_suffix() {
        assert_eq!(method_of(Path::new("runs/gman-s12")), "gman");
        assert_eq!(method_of(Path::new("runs/a3c-fg-ps-s3")), "a3c-fg-ps");
        assert_eq!(method_of(Path::new("runs/a3c-fg")), "a3c-fg");
        assert_eq!(method_of(Path::new("runs/gman-s")), "gman-s");
        assert_eq!(method_of(Path::new("runs/gman-sx1")), "gman-sx1");
    }

    fn write_point(dir: &Path, k: u64, steps: u64, unseen: f64, seen: f64) {
        std::fs::write(
            dir.join(format!("k{k}.at")),
            format!("{},{steps}\n", k / 100),
        )
        .unwrap();
        std::fs::write(
            dir.join(format!("k{k}.json")),
            format!(r#"{{"results":{{"unseen":{{"sr":{unseen}}},"seen":{{"sr":{seen}}}}}}}"#),
        )
        .unwrap();
    }

    #[test]
    fn val_curve_is_read_in_step_order_and_averaged_by_position() {
        let tmp = std::env::temp_dir().join(format!("gman-plot-test-{}", std::process::id()));
        let (a, b) = (tmp.join("m-s1"), tmp.join("m-s2"));
        for d in [&a, &b] {
            std::fs::create_dir_all(d.join("curve")).unwrap();
        }
        write_point(&a.join("curve"), 2000, 2100, 20.0, 30.0);
        write_point(&a.join("curve"), 1000, 1200, 10.0, 12.0);
        write_point(&b.join("curve"), 1000, 1000, 14.0, 16.0);
        let va = read_val_curve(&a).unwrap();
        assert_eq!(va, vec![(1200.0, 10.0, 12.0), (2100.0, 20.0, 30.0)]);
        let vb = read_val_curve(&b).unwrap();
        let train = vec![(0.0, 0.0, 0.0), (1000.0, 0.5, 1.0), (2000.0, 1.0, 2.0)];
        let curves = [
            Curve {
                label: "a".into(),
                train: train.clone(),
                val: va,
            },
            Curve {
                label: "b".into(),
                train,
                val: vb,
            },
        ];
        let m = average("m".into(), &curves, 1);
        assert_eq!(m.label, "m (mean of 2 seeds)");
        // Only the points both seeds have, averaged.
        assert_eq!(m.val, vec![(1100.0, 12.0, 14.0)]);
        assert_eq!(m.train.last().copied(), Some((2000.0, 1.0, 2.0)));
        // A point without its step count is an error naming the file.
        std::fs::remove_file(a.join("curve/k1000.at")).unwrap();
        let e = format!("{:#}", read_val_curve(&a).unwrap_err());
        assert!(e.contains("k1000.at"), "{e}");
        std::fs::remove_dir_all(&tmp).unwrap();
    }
}
