//! Spatial observation maps: the view split into a grid of sectors, one embedding per sector,
//! the counterpart of the reference's 512 x 7 x 7 ResNet18 feature map.
//!
//! The pooled embedding of a view ([`crate::Observation::features`], what D, Ψ, G's
//! target and the PS module see) mixes every object in view by the share of the view it
//! fills. The map keeps *where* those objects are:
//!
//! 1. **Projection.** An object in view projects to the centre `(u, v)` of the square frame
//!    (normalised image coordinates in [-1, 1]: `u = tan(azimuth) / tan(FOV / 2)`, right
//!    positive; `v = -tan(elevation − pitch) / tan(FOV / 2)`, down positive) and covers a
//!    square of half-side `h = tan(atan(max(size / 2, radius) / d)) / tan(FOV / 2)` around
//!    it (`d` the 3-d distance to its centre), clipped to the frame.
//! 2. **Cells.** Cell `(r, c)` of an `R x C` grid covers `[−1 + 2c/C, −1 + 2(c+1)/C]` in `u`
//!    and `[−1 + 2r/R, −1 + 2(r+1)/R]` in `v` (row 0 at the top, column 0 at the left).
//!    An object's share of the view `w` (the same weight as in the pooled embedding) is
//!    spread over the cells its square overlaps, in proportion to the overlap, scaled by the
//!    number of cells: `w_c = w · R C · overlap_c / Σ overlap`. So the map's average share
//!    equals the pooled share, and a small object dominates the one sector it is in.
//! 3. **Mixing.** Each cell mixes the scene's styled object features with its styled
//!    background exactly as a pooled view does ([`crate::features::SceneStyle`]:
//!    shares scaled to at most 0.95 per cell, the same background in every cell), plus
//!    ±0.02 noise drawn per (scene, state, cell, dimension), clamped to [0, 1].
//!
//! Maps are computed on demand rather than cached (a 3 x 3 map of every state of the 100
//! floor plans would take gigabytes); that costs about 35 µs per 3 x 3 map, measured under
//! load (`cargo bench -p gman-host-sim --bench sim -- view_map`, see `SIMULATOR.md`), most of
//! it the per-dimension noise hashing.

use gman_core::FEATURE_DIM;

use super::features::{MAX_OBJECT_SHARE, NOISE_AMPLITUDE};
use super::geometry::{heading_dir, CAMERA_HEIGHT, FOV_DEG, GRID, HORIZON_STEP_DEG};
use super::types::CategoryProps;
use super::util::{hash2, mix64};
use super::{SceneId, World};

/// Rows and columns of a spatial map.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct MapGrid {
    /// Rows (top to bottom).
    pub rows: usize,
    /// Columns (left to right).
    pub cols: usize,
}

impl MapGrid {
    /// Number of cells.
    pub fn cells(&self) -> usize {
        self.rows * self.cols
    }

    /// Floats of one map, `cells * 512`.
    pub fn len(&self) -> usize {
        self.cells() * FEATURE_DIM
    }

    /// True for a grid without cells.
    pub fn is_empty(&self) -> bool {
        self.cells() == 0
    }
}

/// Where an object appears in the frame: centre `(u, v)` and half-side `half`, normalised
/// image coordinates (see the module docs).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Projection {
    /// Horizontal centre, right positive.
    pub u: f32,
    /// Vertical centre, down positive.
    pub v: f32,
    /// Half-side of the covered square.
    pub half: f32,
}

/// Projects an object seen from grid position (px, pz) with `heading`/`horizon`.
pub fn project(
    px: f32,
    pz: f32,
    heading: u8,
    horizon: u8,
    obj: [f32; 3],
    props: &CategoryProps,
) -> Projection {
    let t = (FOV_DEG * 0.5).to_radians().tan();
    let (dx, dz) = (obj[0] - px, obj[2] - pz);
    let (hx, hz) = heading_dir(heading);
    let ahead = dx * hx + dz * hz;
    let right = dx * hz - dz * hx;
    let azimuth = right.atan2(ahead.max(1e-3));
    let dc = (dx * dx + dz * dz).sqrt();
    let dy = obj[1] - CAMERA_HEIGHT;
    let elev = dy.atan2(dc.max(1e-3));
    let pitch = -(horizon as f32) * HORIZON_STEP_DEG.to_radians();
    let d3 = (dc * dc + dy * dy).sqrt().max(0.2);
    let extent = (0.5 * props.size).max(props.radius);
    Projection {
        u: (azimuth.tan() / t).clamp(-4.0, 4.0),
        v: (-(elev - pitch).tan() / t).clamp(-4.0, 4.0),
        half: ((extent / d3).atan().tan() / t).clamp(1e-3, 4.0),
    }
}

/// Overlap length of `[a0, a1]` and `[b0, b1]`.
fn overlap(a0: f32, a1: f32, b0: f32, b1: f32) -> f32 {
    (a1.min(b1) - a0.max(b0)).max(0.0)
}

/// Writes the spatial map of `state` of `scene` into `out` (`grid.len()` floats, cell-major).
pub fn view_map(world: &World, scene: SceneId, state: usize, grid: MapGrid, out: &mut [f32]) {
    let (rows, cols) = (grid.rows, grid.cols);
    let cells = grid.cells();
    assert_eq!(out.len(), grid.len(), "map buffer length");
    let sc = &world.scenes[scene];
    let tables = world.tables(scene);
    let obs = &tables.obs[state];
    let st = sc.state(state);
    let (px, pz) = (st.x as f32 * GRID, st.z as f32 * GRID);
    let (min_x, _, max_x, _) = sc.bounds();
    let fx = (st.x - min_x) as f32 / (max_x - min_x).max(1) as f32;
    let style = world.scene_style(scene);
    let bg = style.background(fx, st.heading, st.horizon);
    // Per cell: the objects' shares (before the 0.95 cap).
    let mut shares = vec![0f32; cells * obs.in_view.len()];
    let (cw, rh) = (2.0 / cols as f32, 2.0 / rows as f32);
    for (k, v) in obs.in_view.iter().enumerate() {
        let o = &sc.objects[v.instance as usize];
        let props = &world.categories[o.category as usize].props;
        let p = project(px, pz, st.heading, st.horizon, o.pos, props);
        let (u0, u1) = (p.u - p.half, p.u + p.half);
        let (v0, v1) = (p.v - p.half, p.v + p.half);
        let mut total = 0.0;
        for r in 0..rows {
            let oy = overlap(v0, v1, -1.0 + r as f32 * rh, -1.0 + (r + 1) as f32 * rh);
            for c in 0..cols {
                let ox = overlap(u0, u1, -1.0 + c as f32 * cw, -1.0 + (c + 1) as f32 * cw);
                shares[(r * cols + c) * obs.in_view.len() + k] = ox * oy;
                total += ox * oy;
            }
        }
        if total <= 0.0 {
            // In the field of view by its extent but centred outside the frame: the nearest
            // cell gets it.
            let c = (((p.u + 1.0) / cw).floor() as isize).clamp(0, cols as isize - 1) as usize;
            let r = (((p.v + 1.0) / rh).floor() as isize).clamp(0, rows as isize - 1) as usize;
            shares[(r * cols + c) * obs.in_view.len() + k] = 1.0;
            total = 1.0;
        }
        let scale = v.weight * cells as f32 / total;
        for cell in 0..cells {
            shares[cell * obs.in_view.len() + k] *= scale;
        }
    }
    let state_seed = hash2(hash2(sc.seed, 0x5A7A), state as u64);
    for cell in 0..cells {
        let w = &shares[cell * obs.in_view.len()..(cell + 1) * obs.in_view.len()];
        let total: f32 = w.iter().sum();
        let scale = if total > MAX_OBJECT_SHARE {
            MAX_OBJECT_SHARE / total
        } else {
            1.0
        };
        let o = &mut out[cell * FEATURE_DIM..(cell + 1) * FEATURE_DIM];
        let keep = 1.0 - total * scale;
        for (od, b) in o.iter_mut().zip(bg.iter()) {
            *od = keep * b;
        }
        for (v, &wk) in obs.in_view.iter().zip(w) {
            if wk <= 0.0 {
                continue;
            }
            let f = tables.styled(v.category);
            let wk = wk * scale;
            for (od, fv) in o.iter_mut().zip(f.iter()) {
                *od += wk * fv;
            }
        }
        // Noise: one splitmix stream per (scene, state, cell).
        let mut h = hash2(state_seed, cell as u64);
        for od in o.iter_mut() {
            h = mix64(h);
            let n = ((h >> 40) as f32 / (1u64 << 24) as f32 * 2.0 - 1.0) * NOISE_AMPLITUDE;
            *od = (*od + n).clamp(0.0, 1.0);
        }
    }
}

/// Side of the reference's ResNet18 feature map (7 x 7 cells).
pub const RESNET_SIDE: usize = 7;

pub use gman_core::spec::MAX_GRID_SIDE;

/// Refuses a `rows x cols` map grid no model takes: gman-core's rule for a map's dims
/// ([`gman_core::Dims::degenerate_field`]: rows and columns both non-zero) and at most
/// [`MAX_GRID_SIDE`] rows and columns. `what` names the argument in the error.
pub fn check_grid(rows: usize, cols: usize, what: &str) -> anyhow::Result<()> {
    if rows == 0 || cols == 0 {
        let d = gman_core::Dims::MCU.with_map(rows, cols, usize::from(rows.max(cols) > 0));
        let field = d.degenerate_field().unwrap_or("map_rows");
        anyhow::bail!(
            "{what}: a {rows}x{cols} map grid ({field} is 0): a map grid has at least one row and one column"
        );
    }
    if gman_core::spec::check_map_grid(rows, cols).is_err() {
        anyhow::bail!(
            "{what}: a {rows}x{cols} map grid, but a map grid has at most {MAX_GRID_SIDE} rows and {MAX_GRID_SIDE} columns"
        );
    }
    Ok(())
}

/// Refuses a model's `rows x cols` map grid that `world` cannot serve: offline data stores
/// 7 x 7 feature maps, so a grid there has at most 7 rows and 7 columns (the simulator's
/// own worlds render any grid). `what` names the model or flag in the error.
pub fn check_grid_for_world(
    world: &World,
    rows: usize,
    cols: usize,
    what: &str,
) -> anyhow::Result<()> {
    if matches!(world.source, super::WorldSource::Offline(_))
        && (rows > RESNET_SIDE || cols > RESNET_SIDE)
    {
        anyhow::bail!(
            "{what}: a {rows}x{cols} map grid, but offline data stores 7 x 7 feature maps, so a map grid has at most 7 rows and 7 columns"
        );
    }
    Ok(())
}

/// Average-pools a stored 512 x 7 x 7 feature map (`512 * 49` floats, channel-major as in
/// the offline data's `(1, 512, 7, 7)` datasets) to `grid` and writes it cell-major into
/// `out`. Cell `(r, c)` of an `R x C` grid averages the 7 x 7 cells `i` with
/// `floor(i R / 7) = r` (rows) and likewise for columns, so 7 x 7 is the map itself and
/// 1 x 1 the global average the pooled embedding is.
pub fn pool_map(map: &[f32], grid: MapGrid, out: &mut [f32]) {
    let n = RESNET_SIDE;
    assert_eq!(map.len(), FEATURE_DIM * n * n, "stored feature map length");
    assert_eq!(out.len(), grid.len(), "map buffer length");
    assert!(grid.rows <= n && grid.cols <= n, "a grid finer than 7 x 7");
    out.fill(0.0);
    let mut count = vec![0u32; grid.cells()];
    for i in 0..n {
        for j in 0..n {
            let cell = (i * grid.rows / n) * grid.cols + j * grid.cols / n;
            count[cell] += 1;
            let o = &mut out[cell * FEATURE_DIM..(cell + 1) * FEATURE_DIM];
            for (ch, v) in o.iter_mut().enumerate() {
                *v += map[ch * n * n + i * n + j];
            }
        }
    }
    for (cell, &k) in count.iter().enumerate() {
        let s = 1.0 / k.max(1) as f32;
        out[cell * FEATURE_DIM..(cell + 1) * FEATURE_DIM]
            .iter_mut()
            .for_each(|v| *v *= s);
    }
}
