//! Synthetic "ResNet-like" observation features that carry the structure GMAN exploits.
//!
//! We cannot render AI2THOR, so a view's 512-d embedding is computed from the state:
//!
//! 1. **Category appearance.** A fixed random network of the category's *real attribute
//!    vector*: hidden `u_c = tanh(W1 SE(c) + b1)` (64 units), logits
//!    `l_c = 1.5 W2 u_c + b2 + r_c` (512), appearance `sigmoid(l_c)`. `r_c` is a
//!    category-specific residual (N(0, 0.7) per dimension, roughly 10% of the logit variance):
//!    attributes predict appearance well but not perfectly, so a generator trained
//!    attributes -> features on seen categories transfers to unseen ones.
//! 2. **Scene style.** Every scene changes how things look, coherently for all its objects
//!    and its background: the hidden code is transformed, `u' = u + G_s u + beta_s` (a random
//!    64x64 matrix with `||G_s u|| ~ 2 ||u||`, a shift `beta_s ~ N(0, 0.3)`), the logits get a
//!    per-dimension shift (N(0, 0.3)) and a contrast factor, and the output a per-dimension gain
//!    (log-normal, sigma 0.25), offset (N(0, 0.05)) and a lighting factor (U(0.7, 1.3)), clamped
//!    to [0, 1]. The hidden-space part moves objects *along the directions in which categories
//!    differ*, so a feature generated from attributes alone (the average over training scenes)
//!    is systematically off in a new scene: the gap that the environmental meta discriminator
//!    closes (paper Fig. 3). It is shared by every view of the scene, so it can be picked up
//!    from a few observations of that scene.
//! 3. **Background.** Each scene has styled background vectors (a base, one per heading, a
//!    floor vector seen when looking down, two vectors blended across the room), made by the
//!    same network from random pseudo-attributes.
//! 4. **A view** mixes the styled features of the objects in view, each weighted by the share
//!    of the view it fills (apparent size from distance and position in the view, see
//!    [`crate::geometry::appearance`]; at most 0.95 in total), with the background, adds
//!    +-0.02 noise that is a hash of (scene, state, dimension), and clamps to [0, 1]. Same
//!    state, same features, so they are cached per scene.
//!
//! An object that fills the view yields nearly its styled feature: this is
//! [`crate::World::object_feature`], the ideal generated target feature for the scene.

use gman_core::{ATTR_DIM, FEATURE_DIM};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

use super::types::{Category, NUM_HEADINGS};
use super::util::{hash2, mix64, unit_f32};

/// Hidden units of the appearance network.
pub const HIDDEN: usize = 64;
/// Amplitude of the deterministic per-state noise.
pub const NOISE_AMPLITUDE: f32 = 0.02;
/// Largest share of a view that objects can fill (the rest is background).
pub const MAX_OBJECT_SHARE: f32 = 0.95;
/// Std of a category's logit residual.
pub const RESIDUAL_STD: f32 = 0.7;
/// Relative size of a scene's hidden-code transform `||G_s u|| / ||u||`.
pub const STYLE_TRANSFORM: f32 = 2.0;
/// Std of a scene's hidden-code shift.
pub const STYLE_HIDDEN_SHIFT: f32 = 0.3;
/// Std of a scene's per-dimension logit shift.
pub const STYLE_LOGIT_SHIFT: f32 = 0.3;

/// The strength S of the scene style (`--domain-shift`, `host-sim/SIMULATOR.md`): S multiplies
/// every per-scene deviation of the style from the identity (the hidden-code transform and
/// shift, the logit shift, the contrast's and gains' logarithms, the offsets, the lighting's
/// distance from 1), drawn from the same seeds at every S. 1 is the simulator's default and
/// bit for bit what it was before the knob existed; 0 makes every object look the same in
/// every scene.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(try_from = "f32", into = "f32")]
pub struct DomainShift(f32);

impl DomainShift {
    /// The largest S: at 3 the lighting factor spans U(0.1, 1.9); beyond it, it would turn
    /// negative.
    pub const MAX: f32 = 3.0;
    /// S = 1, the default.
    pub const DEFAULT: DomainShift = DomainShift(1.0);

    /// S, refused unless finite and in [0, [`DomainShift::MAX`]].
    pub fn new(s: f32) -> Result<DomainShift, String> {
        if s.is_finite() && (0.0..=Self::MAX).contains(&s) {
            // -0.0 and 0.0 are one level
            Ok(DomainShift(s + 0.0))
        } else {
            Err(format!(
                "the domain shift must be a number in [0, {}] (1: the default), got {s}",
                Self::MAX
            ))
        }
    }

    /// The value of S.
    pub fn get(self) -> f32 {
        self.0
    }

    /// Whether S is the default 1.
    pub fn is_default(&self) -> bool {
        *self == Self::DEFAULT
    }

    /// `x · S`, exact at S = 1.
    #[inline]
    fn scale(self, x: f32) -> f32 {
        x * self.0
    }
}

// Every value `new` accepts is finite, so equality is an equivalence.
impl Eq for DomainShift {}

impl Default for DomainShift {
    fn default() -> Self {
        Self::DEFAULT
    }
}

impl TryFrom<f32> for DomainShift {
    type Error = String;
    fn try_from(s: f32) -> Result<Self, String> {
        DomainShift::new(s)
    }
}

impl From<DomainShift> for f32 {
    fn from(s: DomainShift) -> f32 {
        s.0
    }
}

impl std::fmt::Display for DomainShift {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{}", self.0)
    }
}

impl std::str::FromStr for DomainShift {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        let v: f32 = s
            .trim()
            .parse()
            .map_err(|_| format!("the domain shift must be a number, got {s:?}"))?;
        DomainShift::new(v)
    }
}

fn normal(rng: &mut ChaCha8Rng) -> f32 {
    let u1: f32 = rng.random_range(1e-7f32..1.0);
    let u2: f32 = rng.random();
    (-2.0 * u1.ln()).sqrt() * (std::f32::consts::TAU * u2).cos()
}

#[inline]
fn sigmoid(x: f32) -> f32 {
    1.0 / (1.0 + (-x).exp())
}

/// A category-like thing to render: its hidden code and logit residual.
#[derive(Clone, Debug)]
pub struct Code {
    hidden: [f32; HIDDEN],
    residual: Vec<f32>,
}

/// The fixed attribute -> appearance network and every category's code.
#[derive(Clone, Debug)]
pub struct FeatureModel {
    w1: Vec<f32>,
    b1: Vec<f32>,
    w2: Vec<f32>,
    b2: Vec<f32>,
    codes: Vec<Code>,
}

impl FeatureModel {
    /// Builds the network from `seed` and the code of every category.
    pub fn new(categories: &[Category], seed: u64) -> FeatureModel {
        let mut rng = ChaCha8Rng::seed_from_u64(mix64(seed ^ 0xFEA7));
        let w1 = (0..HIDDEN * ATTR_DIM)
            .map(|_| 0.6 * normal(&mut rng))
            .collect();
        let b1 = (0..HIDDEN).map(|_| 0.3 * normal(&mut rng)).collect();
        let w2 = (0..FEATURE_DIM * HIDDEN)
            .map(|_| 0.3 * normal(&mut rng))
            .collect();
        let b2 = (0..FEATURE_DIM)
            .map(|_| -0.5 + 0.5 * normal(&mut rng))
            .collect();
        let mut m = FeatureModel {
            w1,
            b1,
            w2,
            b2,
            codes: Vec::new(),
        };
        m.codes = categories
            .iter()
            .enumerate()
            .map(|(i, c)| m.code(&c.attributes, hash2(seed, 1000 + i as u64)))
            .collect();
        m
    }

    /// Code of an attribute vector with a residual seeded by `residual_seed`.
    pub fn code(&self, attrs: &[f32; ATTR_DIM], residual_seed: u64) -> Code {
        let mut hidden = [0f32; HIDDEN];
        for (j, hv) in hidden.iter_mut().enumerate() {
            let row = &self.w1[j * ATTR_DIM..(j + 1) * ATTR_DIM];
            let s: f32 = row.iter().zip(attrs).map(|(w, a)| w * a).sum();
            *hv = (s + self.b1[j]).tanh();
        }
        let mut rng = ChaCha8Rng::seed_from_u64(residual_seed);
        let residual = (0..FEATURE_DIM)
            .map(|_| RESIDUAL_STD * normal(&mut rng))
            .collect();
        Code { hidden, residual }
    }

    /// Code of category `c`.
    pub fn category_code(&self, c: usize) -> &Code {
        &self.codes[c]
    }

    /// Logits `1.5 W2 u + b2 + r` of a hidden code and residual.
    fn logits(&self, hidden: &[f32; HIDDEN], residual: &[f32]) -> [f32; FEATURE_DIM] {
        let mut out = [0f32; FEATURE_DIM];
        for (d, o) in out.iter_mut().enumerate() {
            let row = &self.w2[d * HIDDEN..(d + 1) * HIDDEN];
            let s: f32 = row.iter().zip(hidden).map(|(w, h)| w * h).sum();
            *o = 1.5 * s + self.b2[d] + residual[d];
        }
        out
    }

    /// Scene-free appearance `sigmoid(l_c)` of category `c`.
    pub fn appearance(&self, c: usize) -> [f32; FEATURE_DIM] {
        let code = &self.codes[c];
        self.logits(&code.hidden, &code.residual).map(sigmoid)
    }
}

/// A scene's appearance style and its styled background (see the module docs).
#[derive(Clone, Debug)]
pub struct SceneStyle {
    transform: Vec<f32>,
    hidden_shift: [f32; HIDDEN],
    logit_shift: Vec<f32>,
    contrast: f32,
    gain: Vec<f32>,
    offset: Vec<f32>,
    light: f32,
    base: [f32; FEATURE_DIM],
    walls: Vec<[f32; FEATURE_DIM]>,
    floor: [f32; FEATURE_DIM],
    side_a: [f32; FEATURE_DIM],
    side_b: [f32; FEATURE_DIM],
    seed: u64,
}

impl SceneStyle {
    /// Style and styled background of the scene with seed `scene_seed`, at the default
    /// domain shift.
    pub fn new(model: &FeatureModel, scene_seed: u64) -> SceneStyle {
        Self::with_shift(model, scene_seed, DomainShift::DEFAULT)
    }

    /// Style and styled background of the scene with seed `scene_seed`, every deviation from
    /// the identity scaled by `shift` (the same draws at every level).
    pub fn with_shift(model: &FeatureModel, scene_seed: u64, shift: DomainShift) -> SceneStyle {
        let mut rng = ChaCha8Rng::seed_from_u64(mix64(scene_seed ^ 0x57E1));
        let tscale = STYLE_TRANSFORM / (HIDDEN as f32).sqrt();
        let transform = (0..HIDDEN * HIDDEN)
            .map(|_| shift.scale(tscale * normal(&mut rng)))
            .collect();
        let mut hidden_shift = [0f32; HIDDEN];
        hidden_shift
            .iter_mut()
            .for_each(|v| *v = shift.scale(STYLE_HIDDEN_SHIFT * normal(&mut rng)));
        let logit_shift = (0..FEATURE_DIM)
            .map(|_| shift.scale(STYLE_LOGIT_SHIFT * normal(&mut rng)))
            .collect();
        let contrast = shift.scale(0.15 * normal(&mut rng)).exp();
        let gain = (0..FEATURE_DIM)
            .map(|_| shift.scale(0.25 * normal(&mut rng)).exp())
            .collect();
        let offset = (0..FEATURE_DIM)
            .map(|_| shift.scale(0.05 * normal(&mut rng)))
            .collect();
        let light = rng.random_range(0.7f32..1.3);
        // 1 + S (l - 1), and l itself at S = 1 (bit for bit)
        let light = if shift.is_default() {
            light
        } else {
            1.0 + shift.scale(light - 1.0)
        };
        let mut style = SceneStyle {
            transform,
            hidden_shift,
            logit_shift,
            contrast,
            gain,
            offset,
            light,
            base: [0.0; FEATURE_DIM],
            walls: Vec::new(),
            floor: [0.0; FEATURE_DIM],
            side_a: [0.0; FEATURE_DIM],
            side_b: [0.0; FEATURE_DIM],
            seed: scene_seed,
        };
        let bg = |rng: &mut ChaCha8Rng| {
            let mut a = [0f32; ATTR_DIM];
            for v in a.iter_mut() {
                if rng.random::<f32>() < 0.25 {
                    *v = rng.random();
                }
            }
            let code = model.code(&a, rng.random());
            style.render(model, &code)
        };
        let base = bg(&mut rng);
        let walls = (0..NUM_HEADINGS).map(|_| bg(&mut rng)).collect();
        let floor = bg(&mut rng);
        let side_a = bg(&mut rng);
        let side_b = bg(&mut rng);
        style.base = base;
        style.walls = walls;
        style.floor = floor;
        style.side_a = side_a;
        style.side_b = side_b;
        style
    }

    /// The styled feature of a code in this scene (what a view filled by it looks like, minus
    /// noise).
    pub fn render(&self, model: &FeatureModel, code: &Code) -> [f32; FEATURE_DIM] {
        let mut h = code.hidden;
        for (j, hv) in h.iter_mut().enumerate() {
            let row = &self.transform[j * HIDDEN..(j + 1) * HIDDEN];
            *hv += row
                .iter()
                .zip(&code.hidden)
                .map(|(g, u)| g * u)
                .sum::<f32>()
                + self.hidden_shift[j];
        }
        let logits = model.logits(&h, &code.residual);
        let mut out = [0f32; FEATURE_DIM];
        for d in 0..FEATURE_DIM {
            let y = sigmoid(self.contrast * logits[d] + self.logit_shift[d]);
            out[d] = (self.light * self.gain[d] * y + self.offset[d]).clamp(0.0, 1.0);
        }
        out
    }

    /// Styled background of a view: base, heading wall, a blend across the room (`fx` in
    /// [0, 1] is the position's relative x), and the floor when looking down.
    pub fn background(&self, fx: f32, heading: u8, horizon: u8) -> [f32; FEATURE_DIM] {
        let wall = &self.walls[heading as usize % NUM_HEADINGS];
        let mut out = [0f32; FEATURE_DIM];
        let fl = if horizon > 0 { 0.4 } else { 0.0 };
        for d in 0..FEATURE_DIM {
            let v = 0.5 * self.base[d]
                + 0.3 * wall[d]
                + 0.2 * (fx * self.side_a[d] + (1.0 - fx) * self.side_b[d]);
            out[d] = (1.0 - fl) * v + fl * self.floor[d];
        }
        out
    }

    /// The embedding of a view: the styled background `bg` mixed with `(weight, styled object
    /// feature)` pairs (object shares scaled to at most 0.95 in total), plus the deterministic
    /// noise of `state`, clamped to [0, 1].
    pub fn view_embedding<'a>(
        &self,
        bg: &[f32; FEATURE_DIM],
        objects: impl Iterator<Item = (f32, &'a [f32; FEATURE_DIM])> + Clone,
        state: u64,
    ) -> [f32; FEATURE_DIM] {
        let total: f32 = objects.clone().map(|(w, _)| w).sum();
        let scale = if total > MAX_OBJECT_SHARE {
            MAX_OBJECT_SHARE / total
        } else {
            1.0
        };
        let share = total * scale;
        let mut out = [0f32; FEATURE_DIM];
        for d in 0..FEATURE_DIM {
            out[d] = (1.0 - share) * bg[d];
        }
        for (w, f) in objects {
            let w = w * scale;
            for d in 0..FEATURE_DIM {
                out[d] += w * f[d];
            }
        }
        let sh = hash2(self.seed, state);
        for (d, o) in out.iter_mut().enumerate() {
            let n = (unit_f32(hash2(sh, d as u64)) * 2.0 - 1.0) * NOISE_AMPLITUDE;
            *o = (*o + n).clamp(0.0, 1.0);
        }
        out
    }
}
