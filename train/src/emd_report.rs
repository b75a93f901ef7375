//! The paper's Fig. 3 as a measurement: does the environmental meta discriminator move G's
//! output toward the target's true feature in the current scene?
//!
//! For every val episode run with the device's schedule (the blob's adaptation mode, its
//! inner rate α and cap), this records G(SE(y), 0) before the episode and after its inner
//! updates, and its distance to the target's true feature in that scene
//! ([`World::object_feature`]). [`Summary`] averages over episodes with at least one inner
//! update; the target is that adaptation closes at least 25% of the distance.
//! [`figure`] gives the points of Fig. 3: environment features (the views the agent saw),
//! initial, adapted and true target features of two scenes, projected on their first two
//! principal components (the `gman` binary draws them).

use anyhow::Result;
use gman_core::navigator::memory::AdaptMode;
use gman_core::navigator::{Efficient, Full, Mode, Navigator};
use gman_core::nets::generator::GeneratorCache;
use serde::Serialize;

use crate::model::{NavModel, K};
use crate::pretrain::fg::l2 as dist;
use crate::sim::spatial::MapGrid;
use crate::sim::{Env, EpisodeLimits, EpisodeSpec, RewardKind, TargetKind, World};

/// Keep every this many steps' view as an environment feature of the picture.
pub const VIEW_STRIDE: usize = 4;

/// One val episode with at least one inner update.
#[derive(Clone, Debug, Serialize)]
pub struct Record {
    /// Scene index in the world.
    pub scene: usize,
    /// Target category.
    pub target: usize,
    /// Seen or unseen target.
    pub kind: TargetKind,
    /// G(SE(y), 0) at the start of the episode.
    pub initial: Vec<f32>,
    /// G(SE(y), 0) after the episode's inner updates.
    pub adapted: Vec<f32>,
    /// The target's true feature in this scene.
    pub real: Vec<f32>,
    /// Some of the views the agent saw (every [`VIEW_STRIDE`]-th step).
    pub views: Vec<Vec<f32>>,
    /// Inner updates applied.
    pub adaptations: u32,
    /// Adaptation steps rolled back.
    pub rollbacks: u32,
}

impl Record {
    /// Distance of the initial G output to the true feature.
    pub fn before(&self) -> f64 {
        dist(&self.initial, &self.real)
    }
    /// Distance of the adapted G output to the true feature.
    pub fn after(&self) -> f64 {
        dist(&self.adapted, &self.real)
    }
    /// How far adaptation moved G's output.
    pub fn moved(&self) -> f64 {
        dist(&self.initial, &self.adapted)
    }
    /// Mean of the kept views.
    fn view_mean(&self) -> Vec<f32> {
        let n = self.views.len().max(1) as f32;
        let mut m = vec![0.0f32; self.real.len()];
        for v in &self.views {
            m.iter_mut().zip(v).for_each(|(a, b)| *a += b / n);
        }
        m
    }
    /// Cosine between G's move (adapted - initial) and the direction from the initial output
    /// to `to`: 1 means adaptation moved straight toward it.
    fn cos_toward(&self, to: &[f32]) -> f64 {
        let (mut d, mut a, mut b) = (0.0f64, 0.0f64, 0.0f64);
        for ((x0, x1), t) in self.initial.iter().zip(&self.adapted).zip(to) {
            let (m, w) = ((x1 - x0) as f64, (t - x0) as f64);
            d += m * w;
            a += m * m;
            b += w * w;
        }
        d / (a.sqrt() * b.sqrt()).max(1e-30)
    }
    /// Cosine between G's move and the direction to the true target feature.
    pub fn cos_to_true(&self) -> f64 {
        self.cos_toward(&self.real)
    }
    /// Cosine between G's move and the direction to the mean of the kept views.
    pub fn cos_to_views(&self) -> f64 {
        self.cos_toward(&self.view_mean())
    }
    /// The share of [`Record::before`] that the best point on the segment from G's initial
    /// output to the mean view closes: what a move straight toward the scene's average look
    /// (the direction an EMD that only learned "look like this scene" gives) can close at
    /// its best length. In `[0, 1]`.
    pub fn best_toward_views(&self) -> f64 {
        let v = self.view_mean();
        let (mut uw, mut uu) = (0.0f64, 0.0f64);
        for ((x0, m), t) in self.initial.iter().zip(&v).zip(&self.real) {
            let (u, w) = ((m - x0) as f64, (t - x0) as f64);
            uw += u * w;
            uu += u * u;
        }
        let lam = (uw / uu.max(1e-30)).clamp(0.0, 1.0);
        let best: Vec<f32> = self
            .initial
            .iter()
            .zip(&v)
            .map(|(x0, m)| (*x0 as f64 + lam * (m - x0) as f64) as f32)
            .collect();
        let before = self.before();
        ((before - dist(&best, &self.real)) / before.max(1e-12)).max(0.0)
    }
    /// Share of G's initial output dimensions within 0.01 of the sigmoid's bounds (0 or 1),
    /// where its gradient is nearly zero and adaptation can hardly move them.
    pub fn saturated(&self) -> f64 {
        let n = self.initial.len().max(1) as f64;
        self.initial
            .iter()
            .filter(|v| **v < 0.01 || **v > 0.99)
            .count() as f64
            / n
    }
    /// Distance of the mean of the kept views to the true feature: where a G that only
    /// learned the scene's average look would land (a reference point, not a bound).
    pub(crate) fn view_mean_distance(&self) -> f64 {
        dist(&self.view_mean(), &self.real)
    }
}

fn generated<M: Mode>(nav: &Navigator<'_, M, K>, noise: usize, attr: &[f32]) -> Result<Vec<f32>> {
    let g = nav.generator()?;
    let gains = g.l1.gain.is_some();
    let (mut h1, mut u1) = (vec![0.0f32; g.hidden()], vec![0.0f32; g.hidden()]);
    let (mut x, mut u2) = (vec![0.0f32; g.feat()], vec![0.0f32; g.feat()]);
    g.forward(
        &vec![0.0f32; noise],
        attr,
        &mut GeneratorCache {
            u1: if gains { &mut u1 } else { &mut [] },
            h1: &mut h1,
            u2: if gains { &mut u2 } else { &mut [] },
            x: &mut x,
        },
    )?;
    Ok(x)
}

fn episode<M: Mode>(world: &World, model: &NavModel, spec: &EpisodeSpec) -> Result<Option<Record>> {
    let limits = EpisodeLimits::default();
    let mut arena = vec![0.0f32; model.arena_len()];
    let mut nav: Navigator<'_, M, K> =
        Navigator::new(model.weights()?, &mut arena, model.nav_config(false))?;
    let attr = world.attributes(spec.target).to_vec();
    nav.reset(&attr, spec.seed)?;
    let initial = generated(&nav, model.dims.noise, &attr)?;
    let mut env = Env::new(world, spec, RewardKind::Mixed, limits.for_room(spec.room));
    let grid = MapGrid {
        rows: model.dims.map_rows,
        cols: model.dims.map_cols,
    };
    let mut map = vec![0.0f32; grid.len()];
    let mut views = Vec::new();
    let mut t = 0usize;
    while !env.is_done() {
        let o = env.observe().features;
        if t.is_multiple_of(VIEW_STRIDE) {
            views.push(o.to_vec());
        }
        t += 1;
        if !grid.is_empty() {
            env.observe_map(grid, &mut map);
        }
        let out = nav.step_map(&o, &map, &[])?;
        env.step(out.action);
    }
    let c = nav.counters();
    if c.adaptations == 0 {
        return Ok(None);
    }
    Ok(Some(Record {
        scene: spec.scene,
        target: spec.target as usize,
        kind: spec.kind,
        adapted: generated(&nav, model.dims.noise, &attr)?,
        initial,
        real: world.object_feature(spec.scene, spec.target).to_vec(),
        views,
        adaptations: c.adaptations,
        rollbacks: c.rollbacks,
    }))
}

/// Runs `episodes` with `model`'s own adaptation mode and inner rule (in parallel; the order of
/// the returned records is the order of `episodes`).
pub fn measure(world: &World, model: &NavModel, episodes: &[EpisodeSpec]) -> Result<Vec<Record>> {
    use rayon::prelude::*;
    let out: Vec<Option<Record>> = episodes
        .par_iter()
        .map(|spec| match model.spec.adapt_mode {
            AdaptMode::Full => episode::<Full>(world, model, spec),
            AdaptMode::Efficient => episode::<Efficient>(world, model, spec),
        })
        .collect::<Result<_>>()?;
    Ok(out.into_iter().flatten().collect())
}

/// Means over the adapted episodes of one target kind.
#[derive(Clone, Debug, Default, Serialize)]
pub struct Summary {
    /// Episodes with at least one inner update.
    pub episodes: usize,
    /// Mean distance of G's initial output to the true target feature.
    pub before: f64,
    /// Mean distance after the inner updates.
    pub after: f64,
    /// Share of the distance closed, `(before - after) / before`, in percent.
    pub closed_percent: f64,
    /// Mean distance G's output moved.
    pub moved: f64,
    /// Mean distance of the episode's mean view to the true target feature.
    pub view_mean: f64,
    /// Mean share of the distance (percent) that the best point on the segment from G's
    /// output to the episode's mean view closes ([`Record::best_toward_views`]).
    pub best_toward_views_percent: f64,
    /// Mean share (percent) of G's output dimensions saturated at the sigmoid's bounds.
    pub saturated_percent: f64,
    /// Mean cosine between G's move and the direction to the true target feature.
    pub cos_to_true: f64,
    /// Mean cosine between G's move and the direction to the episode's mean view.
    pub cos_to_views: f64,
    /// Inner updates per adapted episode.
    pub adaptations: f64,
    /// Rolled-back steps per inner update.
    pub rollbacks_per_update: f64,
}

/// [`Summary`] of the records of `kind`.
pub fn summarize(records: &[Record], kind: TargetKind) -> Summary {
    let r: Vec<&Record> = records.iter().filter(|r| r.kind == kind).collect();
    if r.is_empty() {
        return Summary::default();
    }
    let n = r.len() as f64;
    let before = r.iter().map(|r| r.before()).sum::<f64>() / n;
    let after = r.iter().map(|r| r.after()).sum::<f64>() / n;
    let updates: f64 = r.iter().map(|r| r.adaptations as f64).sum();
    Summary {
        episodes: r.len(),
        before,
        after,
        closed_percent: 100.0 * (before - after) / before.max(1e-12),
        moved: r.iter().map(|r| r.moved()).sum::<f64>() / n,
        view_mean: r.iter().map(|r| r.view_mean_distance()).sum::<f64>() / n,
        best_toward_views_percent: 100.0 * r.iter().map(|r| r.best_toward_views()).sum::<f64>() / n,
        saturated_percent: 100.0 * r.iter().map(|r| r.saturated()).sum::<f64>() / n,
        cos_to_true: r.iter().map(|r| r.cos_to_true()).sum::<f64>() / n,
        cos_to_views: r.iter().map(|r| r.cos_to_views()).sum::<f64>() / n,
        adaptations: updates / n,
        rollbacks_per_update: r.iter().map(|r| r.rollbacks as f64).sum::<f64>() / updates.max(1.0),
    }
}

/// The top two principal axes of `points` (power iteration with deflation on the covariance,
/// f64, deterministic start) and the mean.
fn pca2(points: &[&[f32]]) -> (Vec<f64>, [Vec<f64>; 2]) {
    let d = points.first().map_or(0, |p| p.len());
    let n = points.len().max(1) as f64;
    let mut mean = vec![0.0f64; d];
    for p in points {
        mean.iter_mut()
            .zip(p.iter())
            .for_each(|(m, v)| *m += *v as f64 / n);
    }
    let centered: Vec<Vec<f64>> = points
        .iter()
        .map(|p| p.iter().zip(&mean).map(|(v, m)| *v as f64 - m).collect())
        .collect();
    let mut axes: [Vec<f64>; 2] = [vec![0.0; d], vec![0.0; d]];
    for k in 0..2 {
        let mut v: Vec<f64> = (0..d).map(|i| 1.0 + (i % 7) as f64 * 0.1).collect();
        for _ in 0..200 {
            // w = C v = sum_p (p . v) p, with earlier axes projected out.
            let mut w = vec![0.0f64; d];
            for p in &centered {
                let s: f64 = p.iter().zip(&v).map(|(a, b)| a * b).sum();
                w.iter_mut().zip(p).for_each(|(wi, pi)| *wi += s * pi);
            }
            for a in axes.iter().take(k) {
                let s: f64 = w.iter().zip(a).map(|(x, y)| x * y).sum();
                w.iter_mut().zip(a).for_each(|(wi, ai)| *wi -= s * ai);
            }
            let norm = w.iter().map(|x| x * x).sum::<f64>().sqrt();
            if norm < 1e-300 {
                break;
            }
            v = w.into_iter().map(|x| x / norm).collect();
        }
        axes[k] = v;
    }
    (mean, axes)
}

/// The two val scenes with the most adapted unseen-target episodes.
pub fn busiest_scenes(records: &[Record]) -> Vec<usize> {
    let mut count: std::collections::BTreeMap<usize, usize> = Default::default();
    for r in records.iter().filter(|r| r.kind == TargetKind::Unseen) {
        *count.entry(r.scene).or_default() += 1;
    }
    let mut v: Vec<(usize, usize)> = count.into_iter().collect();
    v.sort_by(|a, b| b.1.cmp(&a.1).then(a.0.cmp(&b.0)));
    v.into_iter().take(2).map(|(s, _)| s).collect()
}

/// The first two principal components of a point set, as a projection to the plane.
struct Plane {
    mean: Vec<f64>,
    axes: [Vec<f64>; 2],
}

impl Plane {
    fn of(pts: &[&[f32]]) -> Self {
        let (mean, axes) = pca2(pts);
        Plane { mean, axes }
    }

    fn project(&self, p: &[f32]) -> (f64, f64) {
        let c = |a: &[f64]| -> f64 {
            p.iter()
                .zip(&self.mean)
                .zip(a)
                .map(|((v, m), a)| (*v as f64 - m) * a)
                .sum()
        };
        (c(&self.axes[0]), c(&self.axes[1]))
    }
}

/// The drawing range of `all` (a unit square centred on 0 when empty), padded by 5%.
fn plot_range(all: &[(f64, f64)]) -> (std::ops::Range<f64>, std::ops::Range<f64>) {
    let (mut x0, mut x1, mut y0, mut y1) = (f64::MAX, f64::MIN, f64::MAX, f64::MIN);
    for &(x, y) in all {
        x0 = x0.min(x);
        x1 = x1.max(x);
        y0 = y0.min(y);
        y1 = y1.max(y);
    }
    if all.is_empty() {
        (x0, x1, y0, y1) = (-1.0, 1.0, -1.0, 1.0);
    }
    let pad = 0.05 * ((x1 - x0).max(y1 - y0)).max(1e-6);
    ((x0 - pad)..(x1 + pad), (y0 - pad)..(y1 + pad))
}

/// One episode's target points of Fig. 3, on the plane: G's initial and adapted features and
/// the true target feature.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TargetPoints {
    /// G(SE(y), 0) at the start of the episode.
    pub initial: (f64, f64),
    /// G(SE(y), 0) after the episode's inner updates.
    pub adapted: (f64, f64),
    /// The target's true feature in the scene.
    pub real: (f64, f64),
}

/// One scene's points of Fig. 3.
#[derive(Clone, Debug, PartialEq)]
pub struct ScenePoints {
    /// The scene's name.
    pub name: String,
    /// The environment features (the views the agent saw), episode after episode.
    pub views: Vec<(f64, f64)>,
    /// The target points, one per episode in the order of the records.
    pub targets: Vec<TargetPoints>,
}

/// What Fig. 3 shows: the points of the unseen-target episodes of some scenes on the first
/// two principal components of all of them, and the range that holds them.
#[derive(Clone, Debug, PartialEq)]
pub struct Figure {
    /// One entry per scene asked for, in that order.
    pub scenes: Vec<ScenePoints>,
    /// The drawing range along the first component (5% padding).
    pub x: std::ops::Range<f64>,
    /// The drawing range along the second component.
    pub y: std::ops::Range<f64>,
    /// Episodes drawn (their target points).
    pub episodes: usize,
}

/// The points of Fig. 3 for the unseen-target episodes of `scenes`: environment features, G's
/// initial, adapted and true target features, per scene, projected on the first two principal
/// components of all these points.
pub fn figure(records: &[Record], scenes: &[usize], world: &World) -> Figure {
    let sel: Vec<&Record> = records
        .iter()
        .filter(|r| r.kind == TargetKind::Unseen && scenes.contains(&r.scene))
        .collect();
    let mut pts: Vec<&[f32]> = Vec::new();
    for r in &sel {
        pts.extend(r.views.iter().map(|v| v.as_slice()));
        pts.extend([
            r.initial.as_slice(),
            r.adapted.as_slice(),
            r.real.as_slice(),
        ]);
    }
    let plane = Plane::of(&pts);
    let all: Vec<(f64, f64)> = pts.iter().map(|p| plane.project(p)).collect();
    let (x, y) = plot_range(&all);
    let proj = |p: &[f32]| plane.project(p);
    let scenes = scenes
        .iter()
        .map(|&s| {
            let rs: Vec<&&Record> = sel.iter().filter(|r| r.scene == s).collect();
            ScenePoints {
                name: world
                    .scenes
                    .get(s)
                    .map_or_else(|| format!("scene {s}"), |sc| sc.name.clone()),
                views: rs
                    .iter()
                    .flat_map(|r| r.views.iter().map(|v| proj(v)))
                    .collect(),
                targets: rs
                    .iter()
                    .map(|r| TargetPoints {
                        initial: proj(&r.initial),
                        adapted: proj(&r.adapted),
                        real: proj(&r.real),
                    })
                    .collect(),
            }
        })
        .collect();
    Figure {
        scenes,
        x,
        y,
        episodes: sel.len(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn record(kind: TargetKind, initial: &[f32], adapted: &[f32], real: &[f32]) -> Record {
        Record {
            scene: 0,
            target: 0,
            kind,
            initial: initial.to_vec(),
            adapted: adapted.to_vec(),
            real: real.to_vec(),
            views: vec![vec![2.0, 0.0], vec![4.0, 0.0]],
            adaptations: 2,
            rollbacks: 1,
        }
    }

    #[test]
    fn summary_measures_the_distance_closed() {
        // Moves from (0, 0) to (1, 0) toward (4, 0): 25% of the distance closed, straight on.
        let r = [
            record(TargetKind::Unseen, &[0.0, 0.0], &[1.0, 0.0], &[4.0, 0.0]),
            record(TargetKind::Seen, &[0.0, 0.0], &[0.0, 1.0], &[4.0, 0.0]),
        ];
        let s = summarize(&r, TargetKind::Unseen);
        assert_eq!(s.episodes, 1);
        assert!((s.before - 4.0).abs() < 1e-9 && (s.after - 3.0).abs() < 1e-9);
        assert!((s.closed_percent - 25.0).abs() < 1e-9);
        assert!((s.cos_to_true - 1.0).abs() < 1e-9);
        // views (2, 0) and (4, 0): mean (3, 0), 1 from the true feature
        assert!((s.view_mean - 1.0).abs() < 1e-9);
        assert!((s.rollbacks_per_update - 0.5).abs() < 1e-9);
        // the seen record moved at right angles: nothing closed, cosine 0
        let s = summarize(&r, TargetKind::Seen);
        assert!(s.cos_to_true.abs() < 1e-9 && s.closed_percent < 0.0);
        assert_eq!(summarize(&r[..0], TargetKind::Seen).episodes, 0);
    }

    #[test]
    fn best_point_toward_the_views_and_saturation() {
        // From (0, 0) toward the mean view (3, 0) with the truth at (4, 0): the whole
        // segment helps, the best point is (3, 0), 3 of 4 closed.
        let r = record(TargetKind::Unseen, &[0.0, 0.0], &[0.0, 0.0], &[4.0, 0.0]);
        assert!((r.best_toward_views() - 0.75).abs() < 1e-9);
        // Truth at (0, 3), at right angles to the views: nothing to gain that way.
        let r = record(TargetKind::Unseen, &[0.0, 0.0], &[0.0, 0.0], &[0.0, 3.0]);
        assert!(r.best_toward_views().abs() < 1e-9);
        // Truth at (3, 3): the best point is the foot (3, 0), 3 of √18 left: 1 − 1/√2 closed.
        let r = record(TargetKind::Unseen, &[0.0, 0.0], &[0.0, 0.0], &[3.0, 3.0]);
        assert!((r.best_toward_views() - (1.0 - std::f64::consts::FRAC_1_SQRT_2)).abs() < 1e-6);
        let r = record(TargetKind::Unseen, &[0.005, 0.5], &[0.0, 0.0], &[1.0, 1.0]);
        assert!((r.saturated() - 0.5).abs() < 1e-12);
        let s = summarize(&[r], TargetKind::Unseen);
        assert!((s.saturated_percent - 50.0).abs() < 1e-9);
    }

    #[test]
    fn pca_finds_the_spread_direction() {
        // Points spread along (1, 1, 0) with a little spread along (0, 0, 1).
        let pts: Vec<[f32; 3]> = (0..20)
            .map(|i| {
                let t = i as f32 - 10.0;
                [t, t, 0.1 * ((i % 3) as f32 - 1.0)]
            })
            .collect();
        let refs: Vec<&[f32]> = pts.iter().map(|p| p.as_slice()).collect();
        let (mean, axes) = pca2(&refs);
        assert!(mean.iter().map(|m| m.abs()).fold(0.0, f64::max) < 0.6);
        let h = std::f64::consts::FRAC_1_SQRT_2;
        let c = axes[0][0] * h + axes[0][1] * h;
        assert!(c.abs() > 0.999, "first axis {:?}", axes[0]);
        assert!(axes[1][2].abs() > 0.99, "second axis {:?}", axes[1]);
    }
}
