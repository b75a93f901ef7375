//! Top-down PNG map of a scene (plotters bitmap backend). A band above the map holds the
//! title, the legend and a 1 m scale bar; the text needs a system font
//! ([`register_plot_font`]), the scale bar and the colour swatches do not.
//!
//! The map: a faint 0.25 m lattice over the whole floor the picture covers (the reachable
//! cells, the objects and their footprints), light grey squares the reachable cells from the
//! data, light blue squares cells added by gap filling; tinted rectangles are objects with an
//! AI2-THOR 5.0 box (the `thor5` layout, the box seen from above), filled discs other objects
//! with known positions, rings objects placed by the seeded rule (colour per category, disc
//! size from the footprint radius); goal instances have a thick black outline. A path is drawn
//! in red from a green start marker to a blue end marker, with a dark tick at every step
//! pointing where the agent faces (a turn in place adds a tick at the same cell, so every
//! action shows). The legend lists only what the picture shows. +x points right, +z up.

use std::path::Path;

use anyhow::{anyhow, Result};
use plotters::prelude::*;

use gman_sim::geometry::{heading_dir, Aabb, GRID};
use gman_sim::scene::Scene;
use gman_sim::types::{AgentState, CategoryId};
use gman_sim::util::hash_str;
use gman_sim::world::World;
use gman_sim::SceneId;

const CELL_PX: f32 = 28.0;
const MARGIN_M: f32 = 0.3;
/// Height of the band above the map (title, legend, scale bar), pixels.
const HEADER_PX: i32 = 110;
/// The picture is at least this wide, so that the legend fits.
const MIN_WIDTH_PX: f32 = 620.0;
/// Smallest drawn disc or ring radius, metres (4 px).
const MIN_RING_M: f32 = 4.0 / (CELL_PX / GRID);

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
    /// The floor the lattice covers: (min x, min z, max x, max z), metres, on cell edges.
    floor: [f32; 4],
}

impl Frame {
    /// The frame of `sc`'s cells and objects (with their footprints, `radius` of a category)
    /// with a margin, and the picture's size.
    fn of(sc: &Scene, radius: impl Fn(CategoryId) -> f32) -> (Frame, u32, u32) {
        let mut min = (f32::INFINITY, f32::INFINITY);
        let mut max = (f32::NEG_INFINITY, f32::NEG_INFINITY);
        let mut extend = |x: f32, z: f32| {
            min = (min.0.min(x), min.1.min(z));
            max = (max.0.max(x), max.1.max(z));
        };
        for &(x, z) in &sc.positions {
            let (cx, cz) = (x as f32 * GRID, z as f32 * GRID);
            extend(cx - GRID * 0.5, cz - GRID * 0.5);
            extend(cx + GRID * 0.5, cz + GRID * 0.5);
        }
        for o in &sc.objects {
            if let Some(b) = o.aabb {
                extend(b.center[0] - b.size[0] * 0.5, b.center[2] - b.size[2] * 0.5);
                extend(b.center[0] + b.size[0] * 0.5, b.center[2] + b.size[2] * 0.5);
            } else {
                let r = radius(o.category).max(MIN_RING_M);
                extend(o.pos[0] - r, o.pos[2] - r);
                extend(o.pos[0] + r, o.pos[2] + r);
            }
        }
        // The floor on cell edges (cells are centred on multiples of GRID).
        let edge = |v: f32, up: bool| {
            let k = (v / GRID - 0.5) + if up { 0.999 } else { 0.0 };
            (k.floor() + 0.5) * GRID
        };
        let floor = [
            edge(min.0, false),
            edge(min.1, false),
            edge(max.0, true),
            edge(max.1, true),
        ];
        let (x0, z0) = (floor[0] - MARGIN_M, floor[1] - MARGIN_M);
        let (x1, z1) = (floor[2] + MARGIN_M, floor[3] + MARGIN_M);
        let scale = CELL_PX / GRID;
        let w = ((x1 - x0) * scale).ceil().max(MIN_WIDTH_PX) as u32;
        let h = ((z1 - z0) * scale).ceil().max(1.0) as u32 + HEADER_PX as u32;
        (
            Frame {
                x0,
                z1,
                scale,
                floor,
            },
            w,
            h,
        )
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
    let (frame, w, h) = Frame::of(sc, |c| world.categories[c as usize].props.radius);
    let err = |e: &dyn std::fmt::Display| anyhow!("drawing {}: {e}", png.display());
    let labels = register_plot_font();
    let root = BitMapBackend::new(png, (w, h)).into_drawing_area();
    root.fill(&WHITE).map_err(|e| err(&e))?;
    let name = title.unwrap_or(sc.name.as_str());
    let legend = Legend::of(sc, goal, path);
    draw_header(&root, w, name, &legend, labels).map_err(|e| err(&e))?;
    draw_lattice(&root, &frame).map_err(|e| err(&e))?;
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
    let (frame, w, h) = Frame::of(sc, |c| world.categories[c as usize].props.radius);
    let mut buf = vec![0u8; w as usize * h as usize * 3];
    let err = |e: &dyn std::fmt::Display| anyhow!("drawing scene {}: {e}", sc.name);
    {
        let root = BitMapBackend::with_buffer(&mut buf, (w, h)).into_drawing_area();
        root.fill(&WHITE).map_err(|e| err(&e))?;
        let name = title.unwrap_or(sc.name.as_str());
        let legend = Legend::of(sc, goal, path);
        draw_header(&root, w, name, &legend, labels).map_err(|e| err(&e))?;
        draw_lattice(&root, &frame).map_err(|e| err(&e))?;
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

/// What the picture shows, so that the legend lists only that.
struct Legend {
    swatches: Vec<(RGBColor, &'static str)>,
    /// What the path's steps did, in words (empty without a path).
    steps: String,
    /// The object kinds drawn: "rectangle = AI2-THOR 5.0 box" and the like.
    objects: Vec<&'static str>,
}

impl Legend {
    fn of(sc: &Scene, goal: Option<CategoryId>, path: &[AgentState]) -> Legend {
        let mut swatches = vec![(RGBColor(215, 215, 215), "reachable")];
        if sc.filled.iter().any(|&f| f) {
            swatches.push((RGBColor(170, 205, 240), "gap-filled"));
        }
        if !path.is_empty() {
            swatches.push((GREEN, "start"));
            swatches.push((RED, "path"));
            swatches.push((TICK, "facing, per step"));
            swatches.push((BLUE, "end"));
        }
        if goal.is_some_and(|g| sc.objects.iter().any(|o| o.category == g)) {
            swatches.push((BLACK, "goal (outlined)"));
        }
        let mut objects = Vec::new();
        if sc.objects.iter().any(|o| o.aabb.is_some()) {
            objects.push("rectangle = AI2-THOR 5.0 box");
        }
        if sc.objects.iter().any(|o| o.aabb.is_none() && o.known) {
            objects.push("disc = known position");
        }
        if sc.objects.iter().any(|o| o.aabb.is_none() && !o.known) {
            objects.push("ring = placed by rule (size: footprint)");
        }
        Legend {
            swatches,
            objects,
            steps: step_summary(path),
        }
    }
}

/// The path's steps in words: how many moved, turned, tilted the camera or left the pose
/// unchanged (a blocked move, or the final Done where the path records it).
fn step_summary(path: &[AgentState]) -> String {
    let (mut moves, mut turns, mut tilts, mut still) = (0, 0, 0, 0);
    for w in path.windows(2) {
        let (a, b) = (&w[0], &w[1]);
        if (a.x, a.z) != (b.x, b.z) {
            moves += 1;
        } else if a.heading != b.heading {
            turns += 1;
        } else if a.horizon != b.horizon {
            tilts += 1;
        } else {
            still += 1;
        }
    }
    if path.len() < 2 {
        return String::new();
    }
    format!(
        "along the path: {moves} moves ahead, {turns} turns, {tilts} camera tilts, {still} steps \
         in place (a blocked move, or a recorded Done)"
    )
}

/// Colour of the per-step facing ticks.
const TICK: RGBColor = RGBColor(110, 0, 0);

/// The band above the map: the 1 m scale bar, the legend's swatches and, with `labels`, the
/// title and the legend's words.
fn draw_header<DB: DrawingBackend>(
    root: &DrawingArea<DB, plotters::coord::Shift>,
    w: u32,
    title: &str,
    legend: &Legend,
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
    // Swatches in rows of four, 150 px apart.
    let at = |i: usize| (10 + 150 * (i % 4) as i32, 50 + 20 * (i / 4) as i32);
    for (i, (c, _)) in legend.swatches.iter().enumerate() {
        let (x, y) = at(i);
        root.draw(&Rectangle::new([(x, y), (x + 12, y + 12)], c.filled()))?;
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
        for (i, (_, l)) in legend.swatches.iter().enumerate() {
            let (x, y) = at(i);
            root.draw(&Text::new(l.to_string(), (x + 16, y - 1), small.clone()))?;
        }
        if !legend.steps.is_empty() {
            let y = at(legend.swatches.len() - 1).1 + 20;
            root.draw(&Text::new(legend.steps.clone(), (10, y), small.clone()))?;
        }
        if !legend.objects.is_empty() {
            root.draw(&Text::new(
                format!(
                    "objects (colour per category): {}",
                    legend.objects.join(", ")
                ),
                (10, 30),
                small,
            ))?;
        }
    }
    Ok(())
}

/// A faint 0.25 m lattice over the floor the picture covers, outlined: the space the cells,
/// the objects and their footprints lie in.
fn draw_lattice<DB: DrawingBackend>(
    root: &DrawingArea<DB, plotters::coord::Shift>,
    frame: &Frame,
) -> Drawn<DB> {
    let [x0, z0, x1, z1] = frame.floor;
    let faint = RGBColor(232, 232, 232).stroke_width(1);
    let (nx, nz) = (
        ((x1 - x0) / GRID).round() as i32,
        ((z1 - z0) / GRID).round() as i32,
    );
    for i in 0..=nx {
        let x = x0 + i as f32 * GRID;
        root.draw(&PathElement::new(
            vec![frame.px(x, z0), frame.px(x, z1)],
            faint,
        ))?;
    }
    for i in 0..=nz {
        let z = z0 + i as f32 * GRID;
        root.draw(&PathElement::new(
            vec![frame.px(x0, z), frame.px(x1, z)],
            faint,
        ))?;
    }
    root.draw(&Rectangle::new(
        [frame.px(x0, z1), frame.px(x1, z0)],
        RGBColor(150, 150, 150).stroke_width(1),
    ))
}

/// The reachable cells: grey from the data, light blue added by gap filling.
fn draw_cells<DB: DrawingBackend>(
    root: &DrawingArea<DB, plotters::coord::Shift>,
    sc: &Scene,
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
    sc: &Scene,
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
    b: &Aabb,
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

/// The path in red from a green start marker to a blue end marker, and a tick at every step
/// pointing where the agent faces.
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
    // Where the agent faces at every step: a turn in place adds a tick at the same cell.
    for s in path {
        let (cx, cz) = (s.x as f32 * GRID, s.z as f32 * GRID);
        let (dx, dz) = heading_dir(s.heading);
        let len = GRID * 0.45;
        root.draw(&PathElement::new(
            vec![px(cx, cz), px(cx + dx * len, cz + dz * len)],
            TICK.stroke_width(2),
        ))?;
    }
    root.draw(&Circle::new(px(sx, sz), 6, GREEN.filled()))?;
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

#[cfg(test)]
mod tests {
    use super::{step_summary, AgentState};

    fn st(x: i32, z: i32, heading: u8, horizon: u8) -> AgentState {
        AgentState {
            x,
            z,
            heading,
            horizon,
        }
    }

    /// Turns in place and a tilt count as steps of their own, so a path that turns at its
    /// start says so (its line on the map is one cell long).
    #[test]
    fn step_summary_counts_turns_tilts_and_steps_in_place() {
        let path = [
            st(0, 0, 0, 0),
            st(0, 0, 1, 0),
            st(0, 0, 2, 0),
            st(0, 0, 2, 1),
            st(1, 0, 2, 1),
            st(1, 0, 2, 1),
        ];
        assert_eq!(
            step_summary(&path),
            "along the path: 1 moves ahead, 2 turns, 1 camera tilts, 1 steps in place (a blocked \
             move, or a recorded Done)"
        );
        assert_eq!(step_summary(&path[..1]), "");
    }
}
