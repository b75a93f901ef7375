//! Synthetic "ResNet-like" observation features that carry the structure GMAN exploits.
//!
//! We cannot render AI2THOR, so a view's 512-d embedding is computed from the state:
//!
//! 1. **Category appearance** `app(c) = sigmoid(h(SE(c)) + r_c)`: `h` is a fixed random
//!    two-layer network (45 -> 64 tanh -> 512) of the category's *real attribute vector*, and
//!    `r_c` a category-specific residual (N(0, 0.7) per dimension, about 15% of the pre-sigmoid
//!    variance). Attributes predict appearance well but not perfectly, so a generator trained
//!    attributes -> features on seen categories transfers to unseen ones.
//! 2. **Scene style** `style_s(v) = clamp(light_s * gain_s . v + offset_s, 0, 1)` with a
//!    per-dimension gain (log-normal, sigma 0.35), offset (N(0, 0.06)) and a lighting factor
//!    (U(0.65, 1.35)). A feature generated from attributes alone is systematically off in a new
//!    scene: the gap the environmental meta discriminator closes (paper Fig. 3).
//! 3. **Background**: each scene has background vectors (a base, one per heading, a floor
//!    vector seen when looking down, and two vectors blended across the room), made by the
//!    same appearance network from random pseudo-attributes.
//! 4. **A view** mixes the raw appearances of the objects in view, each weighted by the share
//!    of the view it fills (apparent size from distance and position in the view, see
//!    [`crate::sim::geometry::appearance`]; at most 0.95 in total), with the background, applies
//!    the scene style, adds +-0.02 noise that is a hash of (scene, state, dimension) and clamps
//!    to [0, 1]. Same state, same features, so they are cached per scene.
//!
//! An object that fills the view yields nearly `style_s(app(c))`: this is
//! [`crate::sim::World::object_feature`], the ideal generated target feature for the scene.

use gman_core::{ATTR_DIM, FEATURE_DIM};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use super::types::{Category, NUM_HEADINGS};
use super::util::{hash2, mix64, unit_f32};

const HIDDEN: usize = 64;
/// Amplitude of the deterministic per-state noise.
pub const NOISE_AMPLITUDE: f32 = 0.02;
/// Largest share of a view that objects can fill (the rest is background).
pub const MAX_OBJECT_SHARE: f32 = 0.95;

fn normal(rng: &mut ChaCha8Rng) -> f32 {
    let u1: f32 = rng.random_range(1e-7f32..1.0);
    let u2: f32 = rng.random();
    (-2.0 * u1.ln()).sqrt() * (std::f32::consts::TAU * u2).cos()
}

#[inline]
fn sigmoid(x: f32) -> f32 {
    1.0 / (1.0 + (-x).exp())
}

/// The fixed attribute -> appearance network and every category's appearance.
#[derive(Clone, Debug)]
pub struct FeatureModel {
    w1: Vec<f32>,
    b1: Vec<f32>,
    w2: Vec<f32>,
    b2: Vec<f32>,
    appearance: Vec<[f32; FEATURE_DIM]>,
}

impl FeatureModel {
    /// Builds the network from `seed` and computes every category's appearance.
    pub fn new(categories: &[Category], seed: u64) -> FeatureModel {
        let mut rng = ChaCha8Rng::seed_from_u64(mix64(seed ^ 0xFEA7));
        let w1 = (0..HIDDEN * ATTR_DIM).map(|_| 0.6 * normal(&mut rng)).collect();
        let b1 = (0..HIDDEN).map(|_| 0.3 * normal(&mut rng)).collect();
        let w2 = (0..FEATURE_DIM * HIDDEN).map(|_| 0.3 * normal(&mut rng)).collect();
        let b2 = (0..FEATURE_DIM).map(|_| -0.5 + 0.5 * normal(&mut rng)).collect();
        let mut m = FeatureModel { w1, b1, w2, b2, appearance: Vec::new() };
        m.appearance = categories
            .iter()
            .enumerate()
            .map(|(i, c)| m.raw_appearance(&c.attributes, hash2(seed, 1000 + i as u64), 0.7))
            .collect();
        m
    }

    /// `sigmoid(h(attrs) + residual)` with an N(0, `residual_std`) residual seeded by `residual_seed`.
    pub fn raw_appearance(&self, attrs: &[f32; ATTR_DIM], residual_seed: u64, residual_std: f32) -> [f32; FEATURE_DIM] {
        let h = self.attribute_part(attrs);
        let mut rng = ChaCha8Rng::seed_from_u64(residual_seed);
        let mut out = [0f32; FEATURE_DIM];
        for (o, v) in out.iter_mut().zip(h.iter()) {
            *o = sigmoid(v + residual_std * normal(&mut rng));
        }
        out
    }

    /// The attribute-explained pre-sigmoid part `h(attrs)`.
    pub fn attribute_part(&self, attrs: &[f32; ATTR_DIM]) -> [f32; FEATURE_DIM] {
        let mut hid = [0f32; HIDDEN];
        for (j, hv) in hid.iter_mut().enumerate() {
            let row = &self.w1[j * ATTR_DIM..(j + 1) * ATTR_DIM];
            let s: f32 = row.iter().zip(attrs).map(|(w, a)| w * a).sum();
            *hv = (s + self.b1[j]).tanh();
        }
        let mut out = [0f32; FEATURE_DIM];
        for (d, o) in out.iter_mut().enumerate() {
            let row = &self.w2[d * HIDDEN..(d + 1) * HIDDEN];
            let s: f32 = row.iter().zip(&hid).map(|(w, h)| w * h).sum();
            *o = 1.5 * s + self.b2[d];
        }
        out
    }

    /// Raw (unstyled) appearance of category `c`.
    pub fn appearance(&self, c: usize) -> &[f32; FEATURE_DIM] {
        &self.appearance[c]
    }
}

/// A scene's appearance style and background.
#[derive(Clone, Debug)]
pub struct SceneStyle {
    /// Per-dimension gain.
    pub gain: Vec<f32>,
    /// Per-dimension offset.
    pub offset: Vec<f32>,
    /// Lighting factor.
    pub light: f32,
    base: [f32; FEATURE_DIM],
    walls: Vec<[f32; FEATURE_DIM]>,
    floor: [f32; FEATURE_DIM],
    side_a: [f32; FEATURE_DIM],
    side_b: [f32; FEATURE_DIM],
    seed: u64,
}

impl SceneStyle {
    /// Style and background of the scene with seed `scene_seed`.
    pub fn new(model: &FeatureModel, scene_seed: u64) -> SceneStyle {
        let mut rng = ChaCha8Rng::seed_from_u64(mix64(scene_seed ^ 0x57E1));
        let gain = (0..FEATURE_DIM).map(|_| (0.35 * normal(&mut rng)).exp()).collect();
        let offset = (0..FEATURE_DIM).map(|_| 0.06 * normal(&mut rng)).collect();
        let light = rng.random_range(0.65f32..1.35);
        let mut bg = |rng: &mut ChaCha8Rng| {
            let mut a = [0f32; ATTR_DIM];
            for v in a.iter_mut() {
                if rng.random::<f32>() < 0.25 {
                    *v = rng.random();
                }
            }
            let s = rng.random();
            model.raw_appearance(&a, s, 0.7)
        };
        let base = bg(&mut rng);
        let walls = (0..NUM_HEADINGS).map(|_| bg(&mut rng)).collect();
        let floor = bg(&mut rng);
        let side_a = bg(&mut rng);
        let side_b = bg(&mut rng);
        SceneStyle { gain, offset, light, base, walls, floor, side_a, side_b, seed: scene_seed }
    }

    /// `clamp(light * gain . v + offset, 0, 1)`.
    pub fn apply(&self, v: &[f32; FEATURE_DIM]) -> [f32; FEATURE_DIM] {
        let mut out = [0f32; FEATURE_DIM];
        for d in 0..FEATURE_DIM {
            out[d] = (self.light * self.gain[d] * v[d] + self.offset[d]).clamp(0.0, 1.0);
        }
        out
    }

    /// Raw background of a view: base, heading wall, a blend across the room (`fx` in [0, 1]
    /// is the position's relative x), and the floor when looking down.
    pub fn background(&self, fx: f32, heading: u8, horizon: u8) -> [f32; FEATURE_DIM] {
        let wall = &self.walls[heading as usize % NUM_HEADINGS];
        let mut out = [0f32; FEATURE_DIM];
        let fl = if horizon > 0 { 0.4 } else { 0.0 };
        for d in 0..FEATURE_DIM {
            let v = 0.5 * self.base[d] + 0.3 * wall[d] + 0.2 * (fx * self.side_a[d] + (1.0 - fx) * self.side_b[d]);
            out[d] = (1.0 - fl) * v + fl * self.floor[d];
        }
        out
    }

    /// The embedding of a view: background `bg` mixed with `(weight, raw appearance)` pairs,
    /// styled, plus the deterministic noise of `state`, clamped to [0, 1].
    pub fn view_embedding<'a>(
        &self,
        bg: &[f32; FEATURE_DIM],
        objects: impl Iterator<Item = (f32, &'a [f32; FEATURE_DIM])> + Clone,
        state: u64,
    ) -> [f32; FEATURE_DIM] {
        let total: f32 = objects.clone().map(|(w, _)| w).sum();
        let scale = if total > MAX_OBJECT_SHARE { MAX_OBJECT_SHARE / total } else { 1.0 };
        let share = total * scale;
        let mut mix = [0f32; FEATURE_DIM];
        for d in 0..FEATURE_DIM {
            mix[d] = (1.0 - share) * bg[d];
        }
        for (w, app) in objects {
            let w = w * scale;
            for d in 0..FEATURE_DIM {
                mix[d] += w * app[d];
            }
        }
        let mut out = self.apply(&mix);
        let sh = hash2(self.seed, state);
        for (d, o) in out.iter_mut().enumerate() {
            let n = (unit_f32(hash2(sh, d as u64)) * 2.0 - 1.0) * NOISE_AMPLITUDE;
            *o = (*o + n).clamp(0.0, 1.0);
        }
        out
    }
}
