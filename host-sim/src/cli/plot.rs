//! `gman plot`: learning curves of training runs.

use std::path::{Path, PathBuf};

use anyhow::{anyhow, bail, Context, Result};
use clap::Args;

/// `gman plot`.
#[derive(Debug, Args)]
pub struct PlotArgs {
    /// Run directories (each with metrics.csv); one colour per run.
    #[arg(long = "run", value_name = "RUN_DIR", required = true, num_args = 1..)]
    pub runs: Vec<PathBuf>,
    /// Output PNG.
    #[arg(long, value_name = "OUT.png")]
    pub png: PathBuf,
    /// Moving-average window (updates).
    #[arg(long, default_value_t = 50)]
    pub smooth: usize,
}

/// One row of a run's metrics: (env_steps, success_rate, mean_reward).
type MetricRow = (f64, f64, f64);

/// Reads `metrics.csv` of a run.
fn read_metrics(run: &Path) -> Result<Vec<MetricRow>> {
    let path = run.join("metrics.csv");
    let text =
        std::fs::read_to_string(&path).with_context(|| format!("reading {}", path.display()))?;
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

/// `gman plot`: learning curves (success rate and reward against environment steps).
pub fn cmd_plot(a: PlotArgs) -> Result<()> {
    use plotters::prelude::*;
    let runs: Vec<(String, Vec<MetricRow>)> = a
        .runs
        .iter()
        .map(|r| Ok((r.display().to_string(), read_metrics(r)?)))
        .collect::<Result<_>>()?;
    let labels = gman_host_sim::sim::render::register_plot_font();
    let xmax = runs
        .iter()
        .flat_map(|(_, m)| m.iter().map(|p| p.0))
        .fold(1.0, f64::max);
    let sm = |m: &[MetricRow], pick: usize| -> Vec<f64> {
        smooth(
            &m.iter()
                .map(|p| if pick == 1 { p.1 } else { p.2 })
                .collect::<Vec<_>>(),
            a.smooth,
        )
    };
    let rmin = runs.iter().flat_map(|(_, m)| sm(m, 2)).fold(0.0, f64::min);
    let rmax = runs.iter().flat_map(|(_, m)| sm(m, 2)).fold(1.0, f64::max);
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
    {
        let root = BitMapBackend::new(&a.png, (1000, 800)).into_drawing_area();
        root.fill(&WHITE)?;
        let (top, bottom) = root.split_vertically(400);
        for (panel, (lo, hi), pick, title) in [
            (&top, (0.0, 1.0), 1usize, "training success rate"),
            (&bottom, (rmin, rmax), 2usize, "mean episode reward"),
        ] {
            let mut b = ChartBuilder::on(panel);
            b.margin(15);
            if labels {
                b.caption(title, ("sans-serif", 20))
                    .x_label_area_size(35)
                    .y_label_area_size(55);
            }
            let mut chart = b.build_cartesian_2d(0.0..xmax, lo..hi)?;
            let mut mesh = chart.configure_mesh();
            mesh.x_labels(8).y_labels(6);
            if labels {
                mesh.x_desc("environment steps")
                    .label_style(("sans-serif", 14));
            } else {
                mesh.disable_x_axis().disable_y_axis();
            }
            mesh.draw()?;
            for (i, (name, m)) in runs.iter().enumerate() {
                let c = colors[i % colors.len()];
                let s = chart.draw_series(LineSeries::new(
                    m.iter().map(|p| p.0).zip(sm(m, pick)),
                    c.stroke_width(2),
                ))?;
                if labels {
                    s.label(name.clone()).legend(move |(x, y)| {
                        PathElement::new(vec![(x, y), (x + 20, y)], c.stroke_width(2))
                    });
                }
            }
            if labels {
                chart
                    .configure_series_labels()
                    .background_style(WHITE.mix(0.8))
                    .border_style(BLACK)
                    .label_font(("sans-serif", 13))
                    .draw()?;
            }
        }
        root.present()?;
    }
    println!(
        "wrote {}: top = training success rate (0..1), bottom = mean episode reward ({rmin:.2}..{rmax:.2}), x = environment steps (0..{xmax:.0}), moving average over {} updates{}",
        a.png.display(),
        a.smooth,
        if labels { "" } else { " (no system font found: the PNG has no text)" }
    );
    for (i, (name, m)) in runs.iter().enumerate() {
        let last = sm(m, 1).last().copied().unwrap_or(f64::NAN);
        println!(
            "  colour {}: {name} ({} updates, final smoothed success {:.1}%)",
            ["red", "blue", "green", "magenta", "cyan", "black", "orange", "purple"][i % 8],
            m.len(),
            100.0 * last
        );
    }
    Ok(())
}
