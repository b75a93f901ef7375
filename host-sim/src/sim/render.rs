//! Top-down PNG map of a scene (plotters bitmap backend). A band above the map holds the
//! title, the legend and a 1 m scale bar; the text needs a system font
//! ([`register_plot_font`]), the scale bar and the colour swatches do not.
//!
//! Legend: light grey squares are reachable cells from the data, light blue squares cells added
//! by gap filling; tinted rectangles are objects with an AI2-THOR 5.0 box (the `thor5` layout,
//! the box seen from above), filled discs other objects with known positions, rings objects
//! placed by the seeded rule (colour per category, disc size from the footprint radius); goal
//! instances have a thick black outline. A path is drawn in red from a green start marker (with a heading tick)
//! to a blue end marker. +x points right, +z up.

use std::path::Path;

use anyhow::{anyhow, Result};
use plotters::prelude::*;

use super::geometry::{heading_dir, GRID};
use super::types::{AgentState, CategoryId};
use super::util::hash_str;
use super::world::World;
use super::SceneId;

const CELL_PX: f32 = 28.0;
const MARGIN_M: f32 = 0.6;
/// Height of the band above the map (title, legend, scale bar), pixels.
const HEADER_PX: i32 = 78;

fn category_color(name: &str) -> RGBColor {
    let h = hash_str(7, name);
    let hue = (h % 360) as f64 / 360.0;
    let c = HSLColor(hue, 0.75, 0.45);
    let (r, g, b) = c.rgb();
    RGBColor(r, g, b)
}

/// Where the map lies in the picture: metres to pixels.
#[derive(Clone, Copy)]
struct Frame {
    /// Left edge, metres (x).
    x0: f32,
    /// Top edge, metres (z).
    z1: f32,
    /// Pixels per metre.
    scale: f32,
}

impl Frame {
    /// The frame of `sc`'s cells and objects with a margin, and the picture's size.
    fn of(sc: &super::scene::Scene) -> (Frame, u32, u32) {
        let mut min = (f32::INFINITY, f32::INFINITY);
        let mut max = (f32::NEG_INFINITY, f32::NEG_INFINITY);
        let mut extend = |x: f32, z: f32| {
            min = (min.0.min(x), min.1.min(z));
            max = (max.0.max(x), max.1.max(z));
        };
        for &(x, z) in &sc.positions {
            extend(x as f32 * GRID, z as f32 * GRID);
        }
        for o in &sc.objects {
            extend(o.pos[0], o.pos[2]);
            if let Some(b) = o.aabb {
                extend(b.center[0] - b.size[0] * 0.5, b.center[2] - b.size[2] * 0.5);
                extend(b.center[0] + b.size[0] * 0.5, b.center[2] + b.size[2] * 0.5);
            }
        }
        let (x0, z0) = (min.0 - MARGIN_M, min.1 - MARGIN_M);
        let (x1, z1) = (max.0 + MARGIN_M, max.1 + MARGIN_M);
        let scale = CELL_PX / GRID;
        let w = ((x1 - x0) * scale).ceil().max(560.0) as u32;
        let h = ((z1 - z0) * scale).ceil().max(1.0) as u32 + HEADER_PX as u32;
        (Frame { x0, z1, scale }, w, h)
    }

    /// The pixel of the point (x, z) metres.
    fn px(&self, x: f32, z: f32) -> (i32, i32) {
        (
            ((x - self.x0) * self.scale) as i32,
            ((self.z1 - z) * self.scale) as i32 + HEADER_PX,
        )
    }
}

/// What a drawing step returns: plotters' error of the backend.
type Drawn<DB> = std::result::Result<(), DrawingAreaErrorKind<<DB as DrawingBackend>::ErrorType>>;

/// Draws `scene` (and optionally a path of states and the goal category) to `png`, with
/// `title` (the scene's name when `None`), a legend and a scale bar above the map.
pub fn draw_scene(
    world: &World,
    scene: SceneId,
    goal: Option<CategoryId>,
    path: &[AgentState],
    png: &Path,
    title: Option<&str>,
) -> Result<()> {
    let sc = &world.scenes[scene];
    let (frame, w, h) = Frame::of(sc);
    let err = |e: &dyn std::fmt::Display| anyhow!("drawing {}: {e}", png.display());
    let labels = register_plot_font();
    let root = BitMapBackend::new(png, (w, h)).into_drawing_area();
    root.fill(&WHITE).map_err(|e| err(&e))?;
    let name = title.unwrap_or(sc.name.as_str());
    draw_header(&root, w, name, labels).map_err(|e| err(&e))?;
    draw_cells(&root, sc, &frame).map_err(|e| err(&e))?;
    draw_objects(&root, world, sc, goal, &frame).map_err(|e| err(&e))?;
    draw_path(&root, path, &frame).map_err(|e| err(&e))?;
    root.present().map_err(|e| err(&e))?;
    Ok(())
}

/// [`draw_scene`] into memory instead of a PNG file (a video frame): returns the RGB pixels
/// (row-major, 3 bytes a pixel) with the picture's width and height, which depend on the
/// scene only. A black tick from the end marker shows the last state's heading (the
/// direction the agent faces now).
pub fn draw_scene_rgb(
    world: &World,
    scene: SceneId,
    goal: Option<CategoryId>,
    path: &[AgentState],
    title: Option<&str>,
) -> Result<(Vec<u8>, u32, u32)> {
    static LABELS: std::sync::OnceLock<bool> = std::sync::OnceLock::new();
    let labels = *LABELS.get_or_init(register_plot_font);
    let sc = &world.scenes[scene];
    let (frame, w, h) = Frame::of(sc);
    let mut buf = vec![0u8; w as usize * h as usize * 3];
    let err = |e: &dyn std::fmt::Display| anyhow!("drawing scene {}: {e}", sc.name);
    {
        let root = BitMapBackend::with_buffer(&mut buf, (w, h)).into_drawing_area();
        root.fill(&WHITE).map_err(|e| err(&e))?;
        let name = title.unwrap_or(sc.name.as_str());
        draw_header(&root, w, name, labels).map_err(|e| err(&e))?;
        draw_cells(&root, sc, &frame).map_err(|e| err(&e))?;
        draw_objects(&root, world, sc, goal, &frame).map_err(|e| err(&e))?;
        draw_path(&root, path, &frame).map_err(|e| err(&e))?;
        if let Some(s) = path.last() {
            let (x, z) = (s.x as f32 * GRID, s.z as f32 * GRID);
            let (dx, dz) = heading_dir(s.heading);
            let tick = vec![
                frame.px(x, z),
                frame.px(x + dx * GRID * 1.2, z + dz * GRID * 1.2),
            ];
            root.draw(&PathElement::new(tick, BLACK.stroke_width(3)))
                .map_err(|e| err(&e))?;
        }
        root.present().map_err(|e| err(&e))?;
    }
    Ok((buf, w, h))
}

/// The band above the map: the 1 m scale bar, the legend's swatches and, with `labels`, the
/// title and the legend's words.
fn draw_header<DB: DrawingBackend>(
    root: &DrawingArea<DB, plotters::coord::Shift>,
    w: u32,
    title: &str,
    labels: bool,
) -> Drawn<DB> {
    // Scale bar: 1 m, with end ticks, at the top right of the band.
    let bar = (1.0 / GRID * CELL_PX) as i32;
    let (bx, by) = (w as i32 - bar - 14, 22);
    for seg in [
        vec![(bx, by), (bx + bar, by)],
        vec![(bx, by - 5), (bx, by + 5)],
        vec![(bx + bar, by - 5), (bx + bar, by + 5)],
    ] {
        root.draw(&PathElement::new(seg, BLACK.stroke_width(2)))?;
    }
    let swatches: [(RGBColor, &str); 6] = [
        (RGBColor(215, 215, 215), "reachable"),
        (RGBColor(170, 205, 240), "gap-filled"),
        (GREEN, "start"),
        (RED, "path"),
        (BLUE, "end"),
        (BLACK, "goal (black outline)"),
    ];
    for (i, (c, _)) in swatches.iter().enumerate() {
        let x = 10 + 92 * i as i32;
        root.draw(&Rectangle::new([(x, 50), (x + 12, 62)], c.filled()))?;
    }
    if labels {
        let font = ("sans-serif", 15).into_font();
        root.draw(&Text::new(title.to_string(), (10, 8), font.clone()))?;
        root.draw(&Text::new(
            "1 m".to_string(),
            (bx + bar / 2 - 10, by + 8),
            font,
        ))?;
        let small = ("sans-serif", 12).into_font();
        for (i, (_, l)) in swatches.iter().enumerate() {
            let x = 10 + 92 * i as i32;
            root.draw(&Text::new(l.to_string(), (x + 16, 49), small.clone()))?;
        }
        root.draw(&Text::new(
            "objects: rectangle = AI2-THOR 5.0 box, disc = known position, ring = placed by rule"
                .to_string(),
            (10, 30),
            small,
        ))?;
    }
    Ok(())
}

/// The reachable cells: grey from the data, light blue added by gap filling.
fn draw_cells<DB: DrawingBackend>(
    root: &DrawingArea<DB, plotters::coord::Shift>,
    sc: &super::scene::Scene,
    frame: &Frame,
) -> Drawn<DB> {
    let half = GRID * 0.48;
    for (i, &(x, z)) in sc.positions.iter().enumerate() {
        let (cx, cz) = (x as f32 * GRID, z as f32 * GRID);
        let color = if sc.filled[i] {
            RGBColor(170, 205, 240)
        } else {
            RGBColor(215, 215, 215)
        };
        root.draw(&Rectangle::new(
            [
                frame.px(cx - half, cz + half),
                frame.px(cx + half, cz - half),
            ],
            color.filled(),
        ))?;
    }
    Ok(())
}

/// The objects: boxes where AI2-THOR 5.0 gives one, else discs at known positions and rings
/// where the rule placed them; the goal's instances outlined in black.
fn draw_objects<DB: DrawingBackend>(
    root: &DrawingArea<DB, plotters::coord::Shift>,
    world: &World,
    sc: &super::scene::Scene,
    goal: Option<CategoryId>,
    frame: &Frame,
) -> Drawn<DB> {
    for o in &sc.objects {
        let name = world.category_name(o.category);
        let color = category_color(name);
        if let Some(b) = o.aabb {
            draw_box(root, &b, color, goal == Some(o.category), frame)?;
            continue;
        }
        let r = ((world.categories[o.category as usize].props.radius * frame.scale) as i32).max(4);
        let c = frame.px(o.pos[0], o.pos[2]);
        if goal == Some(o.category) {
            root.draw(&Circle::new(c, r + 4, BLACK.filled()))?;
        }
        let style = if o.known {
            color.filled()
        } else {
            color.stroke_width(3)
        };
        if !o.known {
            root.draw(&Circle::new(c, r, WHITE.filled()))?;
        }
        root.draw(&Circle::new(c, r, style))?;
    }
    Ok(())
}

/// An object's AI2-THOR 5.0 box seen from above (its x-z rectangle, at least 8 px a side so
/// that small objects stay visible): tinted inside, outlined in the category's colour, a goal
/// instance outlined in black.
fn draw_box<DB: DrawingBackend>(
    root: &DrawingArea<DB, plotters::coord::Shift>,
    b: &super::geometry::Aabb,
    color: RGBColor,
    goal: bool,
    frame: &Frame,
) -> Drawn<DB> {
    let (x0, z1) = frame.px(b.center[0] - b.size[0] * 0.5, b.center[2] + b.size[2] * 0.5);
    let (x1, z0) = frame.px(b.center[0] + b.size[0] * 0.5, b.center[2] - b.size[2] * 0.5);
    let (cx, cz) = ((x0 + x1) / 2, (z0 + z1) / 2);
    let (hx, hz) = (((x1 - x0) / 2).max(4), ((z0 - z1) / 2).max(4));
    let corners = [(cx - hx, cz - hz), (cx + hx, cz + hz)];
    root.draw(&Rectangle::new(corners, color.mix(0.3).filled()))?;
    root.draw(&Rectangle::new(corners, color.stroke_width(2)))?;
    if goal {
        let outer = [(cx - hx - 3, cz - hz - 3), (cx + hx + 3, cz + hz + 3)];
        root.draw(&Rectangle::new(outer, BLACK.stroke_width(3)))?;
    }
    Ok(())
}

/// The path in red, from a green start marker with a heading tick to a blue end marker.
fn draw_path<DB: DrawingBackend>(
    root: &DrawingArea<DB, plotters::coord::Shift>,
    path: &[AgentState],
    frame: &Frame,
) -> Drawn<DB> {
    let (Some(first), Some(last)) = (path.first(), path.last()) else {
        return Ok(());
    };
    let px = |x: f32, z: f32| frame.px(x, z);
    let pts: Vec<(i32, i32)> = path
        .iter()
        .map(|s| px(s.x as f32 * GRID, s.z as f32 * GRID))
        .collect();
    root.draw(&PathElement::new(pts, RED.stroke_width(3)))?;
    let (sx, sz) = (first.x as f32 * GRID, first.z as f32 * GRID);
    let (dx, dz) = heading_dir(first.heading);
    root.draw(&PathElement::new(
        vec![px(sx, sz), px(sx + dx * GRID * 1.2, sz + dz * GRID * 1.2)],
        GREEN.stroke_width(4),
    ))?;
    root.draw(&Circle::new(px(sx, sz), 7, GREEN.filled()))?;
    root.draw(&Circle::new(
        px(last.x as f32 * GRID, last.z as f32 * GRID),
        6,
        BLUE.filled(),
    ))?;
    Ok(())
}

/// Registers a system TrueType font for plot labels, if one is installed; returns whether
/// labels can be drawn (the PNG is still written without one).
pub fn register_plot_font() -> bool {
    const CANDIDATES: [&str; 3] = [
        "/usr/share/fonts/truetype/dejavu/DejaVuSans.ttf",
        "/usr/share/fonts/TTF/DejaVuSans.ttf",
        "/usr/share/fonts/truetype/liberation/LiberationSans-Regular.ttf",
    ];
    for c in CANDIDATES {
        if let Ok(bytes) = std::fs::read(c) {
            let bytes: &'static [u8] = Box::leak(bytes.into_boxed_slice());
            if plotters::style::register_font(
                "sans-serif",
                plotters::style::FontStyle::Normal,
                bytes,
            )
            .is_ok()
            {
                return true;
            }
        }
    }
    false
}
