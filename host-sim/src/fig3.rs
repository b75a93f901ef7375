//! The picture of the paper's Fig. 3 (plotters): the points gman-train's
//! [`emd_report::figure`](crate::emd_report::figure) computes, drawn to a PNG.

use std::path::Path;

use anyhow::{Context, Result};
use plotters::prelude::*;

use crate::emd_report::{Figure, ScenePoints};

type Chart<'a, 'b> = plotters::chart::ChartContext<
    'a,
    BitMapBackend<'b>,
    Cartesian2d<plotters::coord::types::RangedCoordf64, plotters::coord::types::RangedCoordf64>,
>;

/// One scene's points: environment features, then for each episode the line from the initial
/// to the adapted feature, the initial (triangle), adapted (circle) and true (cross) features.
fn draw_scene_points(
    chart: &mut Chart<'_, '_>,
    sp: &ScenePoints,
    c: RGBColor,
    labels: bool,
) -> Result<()> {
    let name = &sp.name;
    let ts = &sp.targets;
    let e = chart.draw_series(
        sp.views
            .iter()
            .map(|&p| Circle::new(p, 2, c.mix(0.25).filled())),
    )?;
    if labels {
        e.label(format!("{name}: environment features"))
            .legend(move |(x, y)| Circle::new((x + 10, y), 3, c.mix(0.4).filled()));
    }
    chart.draw_series(
        ts.iter()
            .map(|t| PathElement::new(vec![t.initial, t.adapted], c)),
    )?;
    let s1 = chart.draw_series(
        ts.iter()
            .map(|t| TriangleMarker::new(t.initial, 6, c.filled())),
    )?;
    if labels {
        s1.label(format!("{name}: initial G(y)"))
            .legend(move |(x, y)| TriangleMarker::new((x + 10, y), 6, c.filled()));
    }
    let s2 = chart.draw_series(
        ts.iter()
            .map(|t| Circle::new(t.adapted, 5, c.stroke_width(2))),
    )?;
    if labels {
        s2.label(format!("{name}: adapted G(y)"))
            .legend(move |(x, y)| Circle::new((x + 10, y), 5, c.stroke_width(2)));
    }
    let s3 = chart.draw_series(ts.iter().map(|t| Cross::new(t.real, 6, c.stroke_width(2))))?;
    if labels {
        s3.label(format!("{name}: true target feature"))
            .legend(move |(x, y)| Cross::new((x + 10, y), 6, c.stroke_width(2)));
    }
    Ok(())
}

/// Draws Fig. 3 into a PNG at `png`: environment features (small dots), G's initial
/// (triangles), adapted (circles, joined to the initial point) and true target features
/// (crosses), one colour per scene. Returns how many target points were drawn.
pub fn draw(fig: &Figure, png: &Path) -> Result<usize> {
    let labels = gman_render::register_plot_font();
    let root = BitMapBackend::new(png, (1000, 800)).into_drawing_area();
    root.fill(&WHITE)?;
    let mut b = ChartBuilder::on(&root);
    b.margin(15);
    if labels {
        b.caption(
            "Fig. 3: environment features, initial / adapted / true target features (PCA)",
            ("sans-serif", 18),
        )
        .x_label_area_size(35)
        .y_label_area_size(55);
    }
    let mut chart = b.build_cartesian_2d(fig.x.clone(), fig.y.clone())?;
    let mut mesh = chart.configure_mesh();
    if labels {
        mesh.x_desc("PC 1").y_desc("PC 2");
    } else {
        mesh.disable_x_axis().disable_y_axis();
    }
    mesh.draw()?;
    let colours = [RGBColor(30, 90, 200), RGBColor(220, 60, 30)];
    for (i, sp) in fig.scenes.iter().enumerate() {
        draw_scene_points(&mut chart, sp, colours[i % 2], labels)?;
    }
    if labels {
        chart
            .configure_series_labels()
            .position(SeriesLabelPosition::LowerRight)
            .background_style(WHITE.mix(0.8))
            .border_style(BLACK)
            .label_font(("sans-serif", 13))
            .draw()?;
    }
    root.present()
        .with_context(|| format!("writing {}", png.display()))?;
    Ok(fig.episodes)
}
