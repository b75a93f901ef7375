//! The model's settings, declared once: what a blob header records about how a model runs,
//! what a host checkpoint stores beside the weights, and what a command line sets.
//!
//! * [`Named`]: the one table of names of each setting enum ([`AdaptMode`], [`NoiseMode`],
//!   [`StepRule`], [`AdaptLossKind`], [`Emd`]), with its `FromStr`, `Display` and serde
//!   forms; a command line lists the table's values and their meaning.
//! * [`InnerRule`]: the inner loop's rule where it departs from the paper's (α1 apart from
//!   α2, D's steps, the step rule, D's head reset, the form of L_ad, the critic scale, the
//!   head-only step, the commit delay).
//! * [`ModelSpec`]: the carrier of every setting that changes what the model computes: the
//!   noise, the adaptation mode, the inner rates, the cap on inner updates, the
//!   [`InnerRule`], whether the model adapts and its EMD, and how a blob is run (int8
//!   activations, compact Ψ). [`ModelSpec::validate`] is the one check of their ranges;
//!   [`ModelSpec::get`] and [`ModelSpec::set`] read and write a setting by its key
//!   ([`SETTING_KEYS`]), which is how a format v5 blob header names them
//!   ([`crate::blob`]); [`ModelSpec::bits`], [`ModelSpec::adapt_settings`] and
//!   [`ModelSpec::from_bits`] are the v1-v4 header's form (its flag word and its
//!   [`AdaptSettings`] record).
//!
//! A host checkpoint stores the training method, not whether the model adapts and its EMD,
//! and a blob's run-time forms are set at export: those four fields are not part of the
//! serde form, so checkpoints keep their bytes.

pub(crate) mod action;
pub mod preset;
pub mod schema;
pub(crate) mod setting_key;

use core::fmt;
use core::str::FromStr;

use serde::{Deserialize, Deserializer, Serialize, Serializer};

use crate::error::BlobError;
use crate::spec::preset::MAX_INNER_RATE;
use crate::spec::schema::{AdaptLossKind, AdaptMode, Emd, NoiseMode, StepRule};
use crate::spec::schema::{
    COMMIT_DELAY_MASK, COMMIT_DELAY_SHIFT, DISC_STEPS_MASK, DISC_STEPS_SHIFT, FLAG_ADAPT,
    FLAG_COMPACT_PSI, FLAG_COSSIM, FLAG_DISC_HEAD_RESET, FLAG_FULL_ADAPT, FLAG_HEAD_ONLY,
    FLAG_INT8_ACTIVATIONS, FLAG_NORMALIZED_STEP, FLAG_PER_GROUP_STEP, FLAG_REFERENCE_ADAPT_LOSS,
    FLAG_REFERENCE_CRITIC_SCALE, FLAG_ZERO_NOISE, MAX_COMMIT_DELAY,
};
use crate::spec::setting_key::index_of;
pub use crate::spec::setting_key::{SettingKey, SETTING_KEYS};

/// A setting enum with one table of names: the form a command line, a checkpoint and a
/// report use. `FromStr`, `Display` and serde (as the name) derive from [`Named::NAMES`].
pub trait Named: Copy + PartialEq + Sized + 'static {
    /// Every value, its name and a one-line meaning, in the order a command line lists them.
    const NAMES: &'static [(Self, &'static str, &'static str)];

    /// Every value, in the order of [`Named::NAMES`] (without the help text a device need
    /// not link).
    const VALUES: &'static [Self];

    /// The name of this value.
    fn name(self) -> &'static str {
        Self::NAMES.iter().find(|e| e.0 == self).map_or("", |e| e.1)
    }

    /// The value named `s`.
    fn from_name(s: &str) -> Option<Self> {
        Self::NAMES.iter().find(|e| e.1 == s).map(|e| e.0)
    }
}

/// A name that none of a [`Named`] enum's values has.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct UnknownName {
    /// The names that exist.
    pub expected: &'static [&'static str],
}

impl fmt::Display for UnknownName {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write_names(f, self.expected.iter().copied(), self.expected.len())
    }
}

macro_rules! named {
    ($t:ty, $list:ident, [$(($v:expr, $name:literal, $help:literal)),* $(,)?]) => {
        impl Named for $t {
            const NAMES: &'static [(Self, &'static str, &'static str)] = &[$(($v, $name, $help)),*];
            const VALUES: &'static [Self] = &[$($v),*];

            // By the names alone: a device that parses a blob links no help text.
            fn name(self) -> &'static str {
                $(if self == $v {
                    return $name;
                })*
                ""
            }

            fn from_name(s: &str) -> Option<Self> {
                index_of(<$t>::$list, s.as_bytes()).and_then(|i| Self::VALUES.get(i).copied())
            }
        }

        impl $t {
            /// The names of the values ([`Named::NAMES`]).
            pub const $list: &'static [&'static str] = &[$($name),*];
        }

        impl FromStr for $t {
            type Err = UnknownName;
            fn from_str(s: &str) -> Result<Self, UnknownName> {
                <$t as Named>::from_name(s).ok_or(UnknownName { expected: <$t>::$list })
            }
        }

        impl fmt::Display for $t {
            fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
                f.write_str(Named::name(*self))
            }
        }

        impl Serialize for $t {
            fn serialize<S: Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
                s.serialize_str(Named::name(*self))
            }
        }

        impl<'de> Deserialize<'de> for $t {
            fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
                d.deserialize_str(NameVisitor::<$t>(core::marker::PhantomData))
            }
        }
    };
}

/// Reads a [`Named`] value from its name.
struct NameVisitor<T>(core::marker::PhantomData<T>);

impl<T: Named> serde::de::Visitor<'_> for NameVisitor<T> {
    type Value = T;

    fn expecting(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str("a name")
    }

    fn visit_str<E: serde::de::Error>(self, v: &str) -> Result<T, E> {
        T::from_name(v).ok_or_else(|| {
            E::custom(format_args!(
                "unknown variant `{v}`, {}",
                NameList::<T>(core::marker::PhantomData)
            ))
        })
    }
}

/// "expected `a`, `b` or `c`": the names of a [`Named`] enum.
struct NameList<T>(core::marker::PhantomData<T>);

impl<T: Named> fmt::Display for NameList<T> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write_names(f, T::NAMES.iter().map(|e| e.1), T::NAMES.len())
    }
}

fn write_names<'a>(
    f: &mut fmt::Formatter<'_>,
    names: impl Iterator<Item = &'a str>,
    n: usize,
) -> fmt::Result {
    f.write_str("expected ")?;
    for (i, name) in names.enumerate() {
        let sep = match i {
            0 => "",
            _ if i + 1 == n => " or ",
            _ => ", ",
        };
        write!(f, "{sep}`{name}`")?;
    }
    Ok(())
}

named!(
    AdaptMode,
    NAME_LIST,
    [
        (
            AdaptMode::Full,
            "full",
            "Every parameter of θ, ω and the actor head (hosts, application processors)"
        ),
        (
            AdaptMode::Efficient,
            "efficient",
            "Per-unit gains and biases over the base weights (microcontrollers)"
        ),
    ]
);

named!(
    NoiseMode,
    NAME_LIST,
    [
        (
            NoiseMode::Gaussian,
            "gaussian",
            "z ~ N(0, I) drawn per step (the paper)"
        ),
        (
            NoiseMode::Zero,
            "zero",
            "z = 0: G's output is a deterministic function of SE(y) (the reference's option)"
        ),
    ]
);

named!(
    StepRule,
    NAME_LIST,
    [
        (StepRule::Gradient, "gradient", "θ ← θ − α2 ∇ (the paper)"),
        (
            StepRule::Normalized,
            "normalized",
            "θ ← θ − α2 ∇/‖∇‖ (α2 is the step's length)"
        ),
        (
            StepRule::PerGroup,
            "per-group",
            "θ and φ each normalised: G moves by α2 whatever the actor head's gradient"
        ),
    ]
);

named!(
    AdaptLossKind,
    NAME_LIST,
    [
        (
            AdaptLossKind::Paper,
            "paper",
            "`−mean_t D(x_t) ‖a_t‖₂` (the paper's Eq. 3)"
        ),
        (
            AdaptLossKind::Reference,
            "reference",
            "`‖ Σ_t a_t (−D(x_t)) ‖₂` (the reference implementation)"
        ),
    ]
);

named!(
    Emd,
    NAME_LIST,
    [
        (
            Emd::Discriminator,
            "discriminator",
            "The learned discriminator D scores the generated features (GMAN)"
        ),
        (
            Emd::CosSim,
            "cossim",
            "The cosine similarity between x_t and s_t, D unused (the CosSim variant)"
        ),
    ]
);

/// Most rows (and most columns) of a model's map grid: the bound of `gman train --map`, of
/// Python's `map=` and of [`check_map_grid`].
pub const MAX_GRID_SIDE: usize = 16;

/// Refuses a `rows x cols` map grid no model takes: at least one row and one column, at
/// most [`MAX_GRID_SIDE`] of each ([`SpecError::MapGrid`]).
pub fn check_map_grid(rows: usize, cols: usize) -> Result<(), SpecError> {
    let side = 1..=MAX_GRID_SIDE;
    if side.contains(&rows) && side.contains(&cols) {
        Ok(())
    } else {
        Err(SpecError::MapGrid { rows, cols })
    }
}

/// The largest number of D's ascent steps per inner update a blob can record.
pub const MAX_DISC_STEPS: u32 = 256;

/// A setting of a [`ModelSpec`] out of its range. The message names the setting as its
/// command-line flag does (without the dashes).
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum SpecError {
    /// `inner_lr` (α2, and α1 unless [`InnerRule::disc_lr`] is set) is not in
    /// `0..=`[`MAX_INNER_RATE`].
    InnerRate(f32),
    /// [`InnerRule::disc_lr`] is not in `0..=`[`MAX_INNER_RATE`].
    DiscRate(f32),
    /// [`InnerRule::disc_steps`] is not in `1..=`[`MAX_DISC_STEPS`].
    DiscSteps(u32),
    /// [`InnerRule::commit_delay`] is above [`MAX_COMMIT_DELAY`].
    CommitDelay(u32),
    /// A map grid without a row or a column, or with more than [`MAX_GRID_SIDE`] of either
    /// ([`check_map_grid`]).
    MapGrid {
        /// Rows asked for.
        rows: usize,
        /// Columns asked for.
        cols: usize,
    },
}

impl fmt::Display for SpecError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let why = "(a larger step diverges at every adaptation; the paper's is 1e-4)";
        match *self {
            SpecError::InnerRate(a) => {
                write!(f, "inner-lr {a} must be in 0..={MAX_INNER_RATE} {why}")
            }
            SpecError::DiscRate(a) => {
                write!(f, "disc-lr {a} must be in 0..={MAX_INNER_RATE} {why}")
            }
            SpecError::DiscSteps(n) => {
                write!(f, "disc-steps must be in 1..={MAX_DISC_STEPS}, got {n}")
            }
            SpecError::CommitDelay(d) => {
                write!(f, "commit-delay must be in 0..={MAX_COMMIT_DELAY}, got {d}")
            }
            SpecError::MapGrid { rows, cols } => write!(
                f,
                "map {rows}x{cols}: a map grid has 1..={MAX_GRID_SIDE} rows and 1..={MAX_GRID_SIDE} columns"
            ),
        }
    }
}

impl core::error::Error for SpecError {}

fn rate_ok(a: f32) -> bool {
    a.is_finite() && (0.0..=MAX_INNER_RATE).contains(&a)
}

/// The inner loop's rule where it departs from the paper's (the levers of
/// docs/emd-analysis.md), recorded in checkpoints and blobs so that evaluation and the device
/// run the rule that was meta-learned. [`InnerRule::default`] is the paper's: α1 = α2, one
/// D step, the plain gradient step. Its serde form leaves out every lever at the paper's
/// value but `disc_steps` and `step_rule` (so records written before a lever existed keep
/// their bytes).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct InnerRule {
    /// α1 (D's ascent rate on L_D) when it differs from the model's `inner_lr` (then α2 only).
    #[serde(default)]
    pub disc_lr: Option<f32>,
    /// D's ascent steps per inner update (1..=[`MAX_DISC_STEPS`]).
    #[serde(default = "one")]
    pub disc_steps: u32,
    /// The descent step on L_ad: `gradient` (α2 ∇), `normalized` (α2 ∇/‖∇‖) or `per-group`
    /// (θ and φ each normalised to length α2).
    #[serde(default)]
    pub step_rule: StepRule,
    /// D restarts with every episode, its output layer at zero.
    #[serde(default, skip_serializing_if = "is_false")]
    pub disc_head_reset: bool,
    /// The form of L_ad: `paper` (Eq. 3) or `reference` (‖Σ_t a_t (−D(x_t))‖₂, the reference
    /// implementation's).
    #[serde(default, skip_serializing_if = "is_paper_loss")]
    pub adapt_loss: AdaptLossKind,
    /// L_D's critic terms scaled by 10, as the reference implementation does (the paper: 1).
    #[serde(default, skip_serializing_if = "is_false")]
    pub reference_critic: bool,
    /// The descent step on L_ad adapts only the actor head, G stays at θ (the reference
    /// implementation's default; the paper: G and the head).
    #[serde(default, skip_serializing_if = "is_false")]
    pub head_only: bool,
    /// The inner update's commit delay d in steps (see
    /// [`NavConfig::model`](crate::navigator::NavConfig::model)): it takes effect d steps
    /// after Ψ fills, the steps between not recorded (0: at once).
    #[serde(default, skip_serializing_if = "is_zero")]
    pub commit_delay: u32,
}

fn one() -> u32 {
    1
}

fn is_false(b: &bool) -> bool {
    !*b
}

fn is_zero(v: &u32) -> bool {
    *v == 0
}

fn is_paper_loss(l: &AdaptLossKind) -> bool {
    *l == AdaptLossKind::Paper
}

impl Default for InnerRule {
    fn default() -> Self {
        InnerRule::PAPER
    }
}

impl InnerRule {
    /// The paper's rule.
    pub const PAPER: InnerRule = InnerRule {
        disc_lr: None,
        disc_steps: 1,
        step_rule: StepRule::Gradient,
        disc_head_reset: false,
        adapt_loss: AdaptLossKind::Paper,
        reference_critic: false,
        head_only: false,
        commit_delay: 0,
    };

    /// The scale of L_D's critic terms: 10 with [`InnerRule::reference_critic`], else 1.
    pub fn critic_scale(&self) -> f32 {
        if self.reference_critic {
            10.0
        } else {
            1.0
        }
    }

    /// True for the paper's rule.
    pub fn is_paper(&self) -> bool {
        *self == InnerRule::PAPER
    }

    /// Checks the ranges: α1 in `0..=`[`MAX_INNER_RATE`], 1..=[`MAX_DISC_STEPS`] D steps, a
    /// commit delay of at most [`MAX_COMMIT_DELAY`].
    pub fn validate(&self) -> Result<(), SpecError> {
        if let Some(a) = self.disc_lr {
            if !rate_ok(a) {
                return Err(SpecError::DiscRate(a));
            }
        }
        if !(1..=MAX_DISC_STEPS).contains(&self.disc_steps) {
            return Err(SpecError::DiscSteps(self.disc_steps));
        }
        if self.commit_delay > MAX_COMMIT_DELAY {
            return Err(SpecError::CommitDelay(self.commit_delay));
        }
        Ok(())
    }
}

/// The inner-loop settings of Algorithm 1 a model was trained with, stored in the header of
/// a v2 blob (see [`crate::blob`]) so that the device adapts exactly as the trainer did.
///
/// Both rates must be finite, non-negative and at most [`MAX_INNER_RATE`]: the encoder
/// refuses other values, the parser rejects them with [`BlobError::BadInnerRate`], and
/// [`Navigator::new`](crate::navigator::Navigator::new) refuses them in a
/// [`NavConfig`](crate::navigator::NavConfig). Any `max_inner` is valid (0 turns
/// the inner loop off even for a blob with [`FLAG_ADAPT`]).
///
/// The settings themselves are [`ModelSpec`]'s (`inner_lr`, [`InnerRule::disc_lr`],
/// `max_inner`; [`ModelSpec::adapt_settings`], [`ModelSpec::from_bits`]); this is their v2-v4
/// header record (postcard: the three fields in this order).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct AdaptSettings {
    /// α1, the ascent rate of D on L_D (Eq. 1; paper: 1e-4): [`ModelSpec::alpha_disc`].
    pub alpha_disc: f32,
    /// α2, the SGD rate of θ and φ on L_ad (Eq. 3; paper: 1e-4): `ModelSpec::inner_lr`.
    pub alpha_adapt: f32,
    /// At most this many inner updates per episode (reference: 4): `ModelSpec::max_inner`.
    pub max_inner: u32,
}

impl AdaptSettings {
    /// The paper's settings, α1 = α2 = 1e-4 and at most 4 inner updates per episode: the
    /// values of [`NavConfig::default`](crate::navigator::NavConfig) (which is built from this
    /// constant) and the settings of every v1 blob.
    pub const PAPER: AdaptSettings = AdaptSettings {
        alpha_disc: 1e-4,
        alpha_adapt: 1e-4,
        max_inner: 4,
    };

    /// Checks that both rates are finite, non-negative and at most [`MAX_INNER_RATE`];
    /// otherwise returns [`BlobError::BadInnerRate`] naming the first bad one.
    pub fn validate(&self) -> Result<(), BlobError> {
        for (field, v) in [
            ("alpha_disc", self.alpha_disc),
            ("alpha_adapt", self.alpha_adapt),
        ] {
            if !(v.is_finite() && (0.0..=MAX_INNER_RATE).contains(&v)) {
                return Err(BlobError::BadInnerRate {
                    field,
                    bits: v.to_bits(),
                });
            }
        }
        Ok(())
    }
}

impl Default for AdaptSettings {
    /// [`AdaptSettings::PAPER`].
    fn default() -> Self {
        AdaptSettings::PAPER
    }
}

/// The model's switches a blob header records and a host checkpoint stores (under these
/// keys, beside the method and sizes): G's noise, the adaptation mode, the inner rates
/// (`inner_lr` = α2, and α1 unless the rule sets its own), the cap on inner updates and the
/// [`InnerRule`]. A field absent from a stored record takes the value the records written
/// before it existed were trained with.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct ModelSpec {
    /// Noise of G at navigation time (absent: Gaussian).
    #[serde(default)]
    pub noise: NoiseMode,
    /// Inner-loop rate α2 (and α1 unless [`InnerRule::disc_lr`]; absent: the paper's 1e-4).
    #[serde(default = "paper_rate")]
    pub inner_lr: f32,
    /// Cap on inner updates per episode (absent: 4, the paper's).
    #[serde(default = "paper_max_inner")]
    pub max_inner: u32,
    /// The adaptation mode the model was meta-trained in (absent: `full`, the mode of the
    /// records written before the setting existed).
    #[serde(default = "full_mode")]
    pub adapt_mode: AdaptMode,
    /// The inner rule's levers (absent, and not written, for the paper's rule).
    #[serde(default, skip_serializing_if = "InnerRule::is_paper")]
    pub inner_rule: InnerRule,
    /// The inner loop runs at inference (the training method's; a host checkpoint stores the
    /// method instead, so this is not part of the serde form).
    #[serde(skip, default = "yes")]
    pub adapt: bool,
    /// What scores the generated features in L_ad (the method's; not in the serde form).
    #[serde(skip)]
    pub emd: Emd,
    /// The int8 weight matrices multiply int8 activations ([`FLAG_INT8_ACTIVATIONS`]); how a
    /// blob is run, set by `gman export`, not in the serde form.
    #[serde(skip)]
    pub int8_activations: bool,
    /// Ψ keeps its observations as int16 ([`FLAG_COMPACT_PSI`]); not in the serde form.
    #[serde(skip)]
    pub compact_psi: bool,
}

fn yes() -> bool {
    true
}

fn paper_rate() -> f32 {
    AdaptSettings::PAPER.alpha_adapt
}

fn paper_max_inner() -> u32 {
    AdaptSettings::PAPER.max_inner
}

fn full_mode() -> AdaptMode {
    AdaptMode::Full
}

impl ModelSpec {
    /// The paper's settings in the given adaptation mode, with Gaussian noise.
    pub const fn paper(adapt_mode: AdaptMode) -> ModelSpec {
        ModelSpec {
            noise: NoiseMode::Gaussian,
            inner_lr: AdaptSettings::PAPER.alpha_adapt,
            max_inner: AdaptSettings::PAPER.max_inner,
            adapt_mode,
            inner_rule: InnerRule::PAPER,
            adapt: true,
            emd: Emd::Discriminator,
            int8_activations: false,
            compact_psi: false,
        }
    }

    /// The one check of the ranges (of flags, of a stored record, of overrides): `inner_lr`
    /// in `0..=`[`MAX_INNER_RATE`] and [`InnerRule::validate`]. Any `max_inner` is valid.
    pub fn validate(&self) -> Result<(), SpecError> {
        if !rate_ok(self.inner_lr) {
            return Err(SpecError::InnerRate(self.inner_lr));
        }
        self.inner_rule.validate()
    }

    /// Every setting as the flag word of a v1-v4 header (the `FLAG_*` bits and the
    /// [`DISC_STEPS_MASK`] and [`COMMIT_DELAY_MASK`] fields): the one mapping from the
    /// settings to the bits, the inverse of [`ModelSpec::from_bits`]. A `disc_steps` of 0 is
    /// written as 1 and one above [`MAX_DISC_STEPS`] as it, a `commit_delay` above
    /// [`MAX_COMMIT_DELAY`] as it. What [`Header::flags`](crate::blob::Header::flags)
    /// reports for a v5 blob.
    pub const fn bits(&self) -> u32 {
        let r = &self.inner_rule;
        let mut f = 0;
        if self.adapt {
            f |= FLAG_ADAPT;
        }
        if matches!(self.noise, NoiseMode::Zero) {
            f |= FLAG_ZERO_NOISE;
        }
        if matches!(self.emd, Emd::CosSim) {
            f |= FLAG_COSSIM;
        }
        if matches!(self.adapt_mode, AdaptMode::Full) {
            f |= FLAG_FULL_ADAPT;
        }
        let steps = if r.disc_steps == 0 {
            0
        } else if r.disc_steps > MAX_DISC_STEPS {
            MAX_DISC_STEPS - 1
        } else {
            r.disc_steps - 1
        };
        f |= steps << DISC_STEPS_SHIFT;
        match r.step_rule {
            StepRule::Gradient => {}
            StepRule::Normalized => f |= FLAG_NORMALIZED_STEP,
            StepRule::PerGroup => f |= FLAG_PER_GROUP_STEP,
        }
        if r.disc_head_reset {
            f |= FLAG_DISC_HEAD_RESET;
        }
        if matches!(r.adapt_loss, AdaptLossKind::Reference) {
            f |= FLAG_REFERENCE_ADAPT_LOSS;
        }
        if r.reference_critic {
            f |= FLAG_REFERENCE_CRITIC_SCALE;
        }
        if r.head_only {
            f |= FLAG_HEAD_ONLY;
        }
        let d = if r.commit_delay > MAX_COMMIT_DELAY {
            MAX_COMMIT_DELAY
        } else {
            r.commit_delay
        };
        f |= d << COMMIT_DELAY_SHIFT;
        if self.int8_activations {
            f |= FLAG_INT8_ACTIVATIONS;
        }
        if self.compact_psi {
            f |= FLAG_COMPACT_PSI;
        }
        f
    }

    /// α1, D's ascent rate on L_D: [`InnerRule::disc_lr`] when the rule sets its own, else
    /// `inner_lr` (α2).
    pub fn alpha_disc(&self) -> f32 {
        self.inner_rule.disc_lr.unwrap_or(self.inner_lr)
    }

    /// The blob header's inner-loop settings: α1 (`inner_lr` unless the rule sets its own),
    /// α2 = `inner_lr`, and `max_inner`.
    pub fn adapt_settings(&self) -> AdaptSettings {
        AdaptSettings {
            alpha_disc: self.alpha_disc(),
            alpha_adapt: self.inner_lr,
            max_inner: self.max_inner,
        }
    }

    /// The switches a v1-v4 blob's flag word and inner-loop settings record (the inverse of
    /// [`ModelSpec::bits`] and [`ModelSpec::adapt_settings`]; α1 is a separate `disc_lr`
    /// exactly when its bits differ from α2's). Bits outside
    /// [`KNOWN_FLAGS`](crate::spec::schema::KNOWN_FLAGS) are ignored here.
    pub fn from_bits(bits: u32, settings: AdaptSettings) -> ModelSpec {
        let on = |flag: u32| bits & flag != 0;
        let (a1, a2) = (settings.alpha_disc, settings.alpha_adapt);
        ModelSpec {
            noise: if on(FLAG_ZERO_NOISE) {
                NoiseMode::Zero
            } else {
                NoiseMode::Gaussian
            },
            inner_lr: a2,
            max_inner: settings.max_inner,
            adapt_mode: if on(FLAG_FULL_ADAPT) {
                AdaptMode::Full
            } else {
                AdaptMode::Efficient
            },
            inner_rule: InnerRule {
                disc_lr: (a1.to_bits() != a2.to_bits()).then_some(a1),
                disc_steps: ((bits & DISC_STEPS_MASK) >> DISC_STEPS_SHIFT) + 1,
                step_rule: if on(FLAG_PER_GROUP_STEP) {
                    StepRule::PerGroup
                } else if on(FLAG_NORMALIZED_STEP) {
                    StepRule::Normalized
                } else {
                    StepRule::Gradient
                },
                disc_head_reset: on(FLAG_DISC_HEAD_RESET),
                adapt_loss: if on(FLAG_REFERENCE_ADAPT_LOSS) {
                    AdaptLossKind::Reference
                } else {
                    AdaptLossKind::Paper
                },
                reference_critic: on(FLAG_REFERENCE_CRITIC_SCALE),
                head_only: on(FLAG_HEAD_ONLY),
                commit_delay: (bits & COMMIT_DELAY_MASK) >> COMMIT_DELAY_SHIFT,
            },
            adapt: on(FLAG_ADAPT),
            emd: if on(FLAG_COSSIM) {
                Emd::CosSim
            } else {
                Emd::Discriminator
            },
            int8_activations: on(FLAG_INT8_ACTIVATIONS),
            compact_psi: on(FLAG_COMPACT_PSI),
        }
    }
}

/// A setting's value as a format v5 blob header stores it: its type is part of the record,
/// so that a reader can tell a wrong type from a wrong value.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub enum SettingValue<'a> {
    /// A count (varint).
    U32(u32),
    /// A rate (4 bytes, little-endian).
    F32(f32),
    /// A value of a [`Named`] enum, by its name.
    Name(&'a str),
    /// A switch (one byte, 0 or 1).
    Bool(bool),
}

/// Why [`ModelSpec::set`] refused a setting.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SettingError {
    /// No setting has this key.
    UnknownKey,
    /// The value has another type than the setting's (`"u32"`, `"f32"`, `"name"`,
    /// `"bool"`).
    WrongType {
        /// The setting's type.
        expected: &'static str,
    },
    /// The value is a name that none of the setting's values has.
    UnknownName,
    /// A count out of the setting's range (`disc_steps`: 1..=[`MAX_DISC_STEPS`],
    /// `commit_delay`: 0..=[`MAX_COMMIT_DELAY`]).
    OutOfRange,
}

/// The type of each setting's value, in [`SETTING_KEYS`] order: the tag of its
/// [`SettingValue`] variant (0 `U32`, 1 `F32`, 2 `Name`, 3 `Bool`).
const SETTING_TYPES: [u8; 16] = [3, 2, 2, 2, 1, 1, 0, 0, 2, 3, 2, 3, 3, 0, 3, 3];

/// The index of the value named `name` of the setting `key` (`u32::MAX` for a name none
/// of its values has, or a setting without names).
#[inline(never)]
pub(crate) fn name_index(key: SettingKey, name: &[u8]) -> u32 {
    let names: &[&str] = match key.index() {
        1 => Emd::NAME_LIST,
        2 => NoiseMode::NAME_LIST,
        3 => AdaptMode::NAME_LIST,
        8 => StepRule::NAME_LIST,
        10 => AdaptLossKind::NAME_LIST,
        _ => &[],
    };
    index_of(names, name).map_or(u32::MAX, |j| j as u32)
}

/// Sets the setting `key` to `value` in a v1-v4 header's form of the settings, the flag
/// word `flags` and the inner-loop `settings` (`inner_lr` is α2, `disc_lr` α1): the one
/// table from each setting to its bits, read by the v5 parser and by [`ModelSpec::set`].
/// Checks the value's type, its name and the ranges the bits can hold; the rates are
/// [`AdaptSettings::validate`]'s.
///
/// The value comes as its type's tag (that of its [`SettingValue`] variant) and a `u32`: a
/// count, a rate's bits, a name's index ([`name_index`]), a switch as 0 or 1.
#[inline(never)]
pub(crate) fn apply_setting(
    key: SettingKey,
    tag: u32,
    raw: u32,
    flags: &mut u32,
    settings: &mut AdaptSettings,
) -> Result<(), SettingError> {
    let i = key.index();
    let expected = u32::from(SETTING_TYPES[i]);
    if tag != expected {
        let expected = ["u32", "f32", "name", "bool"][(expected & 3) as usize];
        return Err(SettingError::WrongType { expected });
    }
    // A name's or a switch's bits: the `raw`-th entry of its table.
    let pick = |table: &[u32]| {
        table
            .get(raw as usize)
            .copied()
            .ok_or(SettingError::UnknownName)
    };
    let (mask, bits) = match i {
        0 => (FLAG_ADAPT, pick(&[0, FLAG_ADAPT])?),
        1 => (FLAG_COSSIM, pick(&[0, FLAG_COSSIM])?),
        2 => (FLAG_ZERO_NOISE, pick(&[0, FLAG_ZERO_NOISE])?),
        3 => (FLAG_FULL_ADAPT, pick(&[FLAG_FULL_ADAPT, 0])?),
        4 => {
            settings.alpha_adapt = f32::from_bits(raw);
            return Ok(());
        }
        5 => {
            settings.alpha_disc = f32::from_bits(raw);
            return Ok(());
        }
        6 => {
            settings.max_inner = raw;
            return Ok(());
        }
        7 if (1..=MAX_DISC_STEPS).contains(&raw) => {
            (DISC_STEPS_MASK, (raw - 1) << DISC_STEPS_SHIFT)
        }
        8 => (
            FLAG_NORMALIZED_STEP | FLAG_PER_GROUP_STEP,
            pick(&[0, FLAG_NORMALIZED_STEP, FLAG_PER_GROUP_STEP])?,
        ),
        9 => (FLAG_DISC_HEAD_RESET, pick(&[0, FLAG_DISC_HEAD_RESET])?),
        10 => (
            FLAG_REFERENCE_ADAPT_LOSS,
            pick(&[0, FLAG_REFERENCE_ADAPT_LOSS])?,
        ),
        11 => (
            FLAG_REFERENCE_CRITIC_SCALE,
            pick(&[0, FLAG_REFERENCE_CRITIC_SCALE])?,
        ),
        12 => (FLAG_HEAD_ONLY, pick(&[0, FLAG_HEAD_ONLY])?),
        13 if raw <= MAX_COMMIT_DELAY => (COMMIT_DELAY_MASK, raw << COMMIT_DELAY_SHIFT),
        14 => (FLAG_INT8_ACTIVATIONS, pick(&[0, FLAG_INT8_ACTIVATIONS])?),
        15 => (FLAG_COMPACT_PSI, pick(&[0, FLAG_COMPACT_PSI])?),
        _ => return Err(SettingError::OutOfRange),
    };
    *flags = (*flags & !mask) | bits;
    Ok(())
}

impl ModelSpec {
    /// The settings of a format v5 blob header before its records are read: a key a record
    /// does not name keeps this value (the paper's rule and rates, Efficient mode, no
    /// adaptation, every run-time form off: what a v4 header with no flag bit says).
    pub const BLOB_DEFAULT: ModelSpec = ModelSpec {
        adapt: false,
        ..ModelSpec::paper(AdaptMode::Efficient)
    };

    /// Every setting away from its value in [`ModelSpec::BLOB_DEFAULT`] (so a blob's header
    /// writes a record of each), each within its range ([`ModelSpec::validate`]): the one spec the round-trip tests
    /// of every carrier (flag word, blob records, checkpoints, the C API and Python) start
    /// from, so that a new setting is covered where it is declared.
    pub const EVERY_SETTING_CHANGED: ModelSpec = ModelSpec {
        noise: NoiseMode::Zero,
        inner_lr: 0.5,
        max_inner: 7,
        adapt_mode: AdaptMode::Full,
        inner_rule: InnerRule {
            disc_lr: Some(0.05),
            disc_steps: 5,
            step_rule: StepRule::PerGroup,
            disc_head_reset: true,
            adapt_loss: AdaptLossKind::Reference,
            reference_critic: true,
            head_only: true,
            commit_delay: 17,
        },
        adapt: true,
        emd: Emd::CosSim,
        int8_activations: true,
        compact_psi: true,
    };

    /// The value of the setting `key` ([`SETTING_KEYS`]); `None` for an unknown key and for
    /// `disc_lr` when α1 is α2.
    pub fn get(&self, key: &str) -> Option<SettingValue<'static>> {
        use SettingValue::{Bool, Name, F32, U32};
        let r = &self.inner_rule;
        Some(match key {
            "adapt" => Bool(self.adapt),
            "emd" => Name(self.emd.name()),
            "noise" => Name(self.noise.name()),
            "adapt_mode" => Name(self.adapt_mode.name()),
            "inner_lr" => F32(self.inner_lr),
            "disc_lr" => F32(r.disc_lr?),
            "max_inner" => U32(self.max_inner),
            "disc_steps" => U32(r.disc_steps),
            "step_rule" => Name(r.step_rule.name()),
            "disc_head_reset" => Bool(r.disc_head_reset),
            "adapt_loss" => Name(r.adapt_loss.name()),
            "reference_critic" => Bool(r.reference_critic),
            "head_only" => Bool(r.head_only),
            "commit_delay" => U32(r.commit_delay),
            "int8_activations" => Bool(self.int8_activations),
            "compact_psi" => Bool(self.compact_psi),
            _ => return None,
        })
    }

    /// Sets the setting `key` to `value` (its type and, for a name, its value checked; the
    /// ranges are [`ModelSpec::validate`]'s).
    pub fn set(&mut self, key: &str, value: SettingValue<'_>) -> Result<(), SettingError> {
        let key = SettingKey::named(key).ok_or(SettingError::UnknownKey)?;
        let (mut flags, mut settings) = (self.bits(), self.adapt_settings());
        let (tag, raw) = match value {
            SettingValue::U32(n) => (0, n),
            SettingValue::F32(a) => (1, a.to_bits()),
            SettingValue::Name(n) => (2, name_index(key, n.as_bytes())),
            SettingValue::Bool(b) => (3, u32::from(b)),
        };
        apply_setting(key, tag, raw, &mut flags, &mut settings)?;
        if key.index() == 4 && self.inner_rule.disc_lr.is_none() {
            // α1 follows α2 unless it was set on its own.
            settings.alpha_disc = settings.alpha_adapt;
        }
        *self = ModelSpec::from_bits(flags, settings);
        Ok(())
    }
}

#[cfg(test)]
mod tests;
