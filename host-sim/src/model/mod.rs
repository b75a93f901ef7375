//! Navigation models: the methods of the paper's tables and their parameters, what a
//! checkpoint or blob holds of them, and what every episode of a model does first
//! ([`episode`]: the navigator started on a target, the PS input, the map grid), in training
//! ([`crate::train`]) and in evaluation ([`crate::eval`]) alike.
//!
//! This folder imports neither: training and evaluation build on it.

use std::path::Path;

use anyhow::{anyhow, bail, Context, Result};
use gman_core::blob::{
    encode_model, encode_model_scratch_len, encoded_model_len_bound, AdaptSettings, Blob, Quant,
    TensorId,
};
use gman_core::matrix::MatRef;
use gman_core::memory::{AdaptMode, Footprint};
use gman_core::navigator::{NavConfig, NavWeights, NoiseMode, Selection};
use gman_core::rng::Xoshiro128;
use gman_core::schema::{Emd, ModelFlags};
pub use gman_core::spec::{InnerRule, ModelSpec, Named};
use gman_core::Dims;
use serde::{Deserialize, Serialize};

use crate::optim::checkpoint::Checkpoint;
use crate::optim::params::{Init, Param, ParamSet};
use crate::pretrain::ps::PsModule;

pub mod episode;

/// Capacity k of the navigation buffer Ψ (the paper's k = 20).
pub const K: usize = 20;

/// When the inner loop of Algorithm 1 (the EMD's adaptation) runs.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum InnerLoop {
    /// Never (the A3C baselines and the `gman-noemd` control).
    Off,
    /// At evaluation only: trained without it, adapted at test time (`gman-nometa`).
    EvalOnly,
    /// In training and at evaluation, so θ and φ are meta-learned through it (GMAN).
    Meta,
}

/// A navigation method: independent switches. The rows of the paper's Tables 2 and 3 are
/// the named presets of [`Method::PRESETS`] (`--method a3c`, `gman`, ...); a new variant is
/// one line there plus the maths of its new switch.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct Method {
    /// Uses the pre-trained feature generator G (FG); otherwise G is zero and x_t carries
    /// nothing.
    pub fg: bool,
    /// Feeds the PS module's prediction to the policy (the † rows).
    pub ps: bool,
    /// When the inner loop runs.
    pub inner: InnerLoop,
    /// What scores generated features in the inner loop (D, or the cosine similarity).
    pub emd: Emd,
    /// The outer loop updates G's θ (the FG baselines keep the pre-trained generator frozen,
    /// as the paper's "FG" row).
    pub train_theta: bool,
}

/// One preset: its name on the command line and in files, its switches, its help text.
type Preset = (&'static str, Method, &'static str);

const fn m(fg: bool, ps: bool, inner: InnerLoop, emd: Emd, train_theta: bool) -> Method {
    Method {
        fg,
        ps,
        inner,
        emd,
        train_theta,
    }
}

use Emd::{CosSim, Discriminator as D};
use InnerLoop::{EvalOnly, Meta, Off};

#[allow(non_upper_case_globals)]
impl Method {
    /// The paper's rows, in `--help` order: name, switches
    /// (`fg, ps, inner loop, EMD, θ trained`), help.
    #[rustfmt::skip]
    pub const PRESETS: [Preset; 11] = [
        ("a3c", m(false, false, Off, D, false),
         "A3C baseline: observation, target attributes, previous action → LSTM → actor-critic"),
        ("a3c-fg", m(true, false, Off, D, false),
         "A3C + the pre-trained feature generator's target feature (FG), no adaptation"),
        ("a3c-ps", m(false, true, Off, D, false), "A3C with the PS module (A3C†)"),
        ("a3c-fg-ps", m(true, true, Off, D, false), "A3C + FG + PS"),
        ("gman", m(true, false, Meta, D, true),
         "GMAN: FG + environmental meta discriminator, meta-trained (Algorithm 1)"),
        ("gman-ps", m(true, true, Meta, D, true), "GMAN with the PS module (GMAN†)"),
        ("gman-nometa", m(true, false, EvalOnly, D, false),
         "EMD without meta-learning: trained as A3C + FG, adapted at test time only"),
        ("gman-cossim", m(true, false, Meta, CosSim, true),
         "EMD variant: cosine similarity between x_t and s_t in place of D (paper Table 3), meta-trained like GMAN"),
        ("gman-noemd", m(true, false, Off, D, true),
         "Control without the EMD: θ and the policy trained by the outer loop as in GMAN, but no inner loop runs, in training or at evaluation (differs from a3c-fg only in that θ is trained, from gman only in the adaptation)"),
        ("gman-fixed-g", m(true, false, Meta, D, false),
         "GMAN with G kept at the pre-trained generator by the outer loop: only the inner loop moves θ, per episode (the outer loop meta-trains the policy; the meta-trained G of `gman` drifts off the feature space)"),
        ("gman-noemd-ps", m(true, true, Off, D, true),
         "Control of GMAN† without the EMD: `gman-noemd` with the PS module (differs from gman-ps only in the adaptation)"),
    ];
    /// A3C baseline.
    pub const A3c: Method = Method::PRESETS[0].1;
    /// A3C + FG.
    pub const A3cFg: Method = Method::PRESETS[1].1;
    /// A3C with the PS module (A3C†).
    pub const A3cPs: Method = Method::PRESETS[2].1;
    /// A3C + FG + PS.
    pub const A3cFgPs: Method = Method::PRESETS[3].1;
    /// GMAN (Algorithm 1).
    pub const Gman: Method = Method::PRESETS[4].1;
    /// GMAN with the PS module (GMAN†).
    pub const GmanPs: Method = Method::PRESETS[5].1;
    /// EMD without meta-learning (adapted at test time only).
    pub const GmanNometa: Method = Method::PRESETS[6].1;
    /// The CosSim EMD variant, meta-trained.
    pub const GmanCossim: Method = Method::PRESETS[7].1;
    /// θ trained as in GMAN, no inner loop.
    pub const GmanNoemd: Method = Method::PRESETS[8].1;
    /// GMAN with θ frozen in the outer loop (adapted per episode only).
    pub const GmanFixedG: Method = Method::PRESETS[9].1;
    /// θ trained as in GMAN†, no inner loop (the control of GMAN†).
    pub const GmanNoemdPs: Method = Method::PRESETS[10].1;

    /// Every preset, in `--help` order.
    const ALL: [Method; Method::PRESETS.len()] = {
        let mut out = [Method::A3c; Method::PRESETS.len()];
        let mut i = 0;
        while i < Method::PRESETS.len() {
            out[i] = Method::PRESETS[i].1;
            i += 1;
        }
        out
    };

    fn preset(self) -> Option<&'static Preset> {
        Method::PRESETS.iter().find(|p| p.1 == self)
    }

    /// The preset name used on the command line and in files; `"custom"` for a combination
    /// of switches that is no preset (such a method cannot be stored in a checkpoint).
    pub fn name(self) -> &'static str {
        self.preset().map_or("custom", |p| p.0)
    }

    /// Parses [`Method::name`].
    pub fn parse(s: &str) -> Option<Method> {
        Method::PRESETS.iter().find(|p| p.0 == s).map(|p| p.1)
    }

    /// Uses the pre-trained feature generator (otherwise G is zero and x_t carries nothing).
    pub fn uses_fg(self) -> bool {
        self.fg
    }

    /// Feeds the PS module's prediction to the policy.
    pub fn uses_ps(self) -> bool {
        self.ps
    }

    /// Runs the inner loop during training (and therefore meta-learns θ and φ through it).
    pub fn adapts_in_training(self) -> bool {
        self.inner == Meta
    }

    /// Scores generated features with the cosine similarity instead of D.
    pub fn uses_cossim(self) -> bool {
        self.emd == CosSim
    }

    /// What scores generated features in the inner loop.
    pub fn emd(self) -> Emd {
        self.emd
    }

    /// Runs the inner loop at evaluation.
    pub fn adapts_at_eval(self) -> bool {
        self.inner != Off
    }

    /// The outer loop updates G's θ (the meta-trained methods and their `gman-noemd`
    /// control; the FG baselines keep the pre-trained generator frozen, as the paper's "FG"
    /// row).
    pub fn trains_generator(self) -> bool {
        self.train_theta
    }
}

impl clap::ValueEnum for Method {
    fn value_variants<'a>() -> &'a [Self] {
        &Method::ALL
    }

    fn to_possible_value(&self) -> Option<clap::builder::PossibleValue> {
        self.preset()
            .map(|p| clap::builder::PossibleValue::new(p.0).help(p.2))
    }
}

impl Serialize for Method {
    /// As its preset name (the form checkpoints store); `"custom"` for a
    /// combination that is no preset, which [`Method::parse`] then refuses on reading.
    fn serialize<S: serde::Serializer>(&self, s: S) -> std::result::Result<S::Ok, S::Error> {
        s.serialize_str(self.name())
    }
}

impl<'de> Deserialize<'de> for Method {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> std::result::Result<Method, D::Error> {
        let name = String::deserialize(d)?;
        Method::parse(&name)
            .ok_or_else(|| serde::de::Error::custom(format!("unknown method {name:?}")))
    }
}

/// Default cap on inner updates per episode (gman-core's default).
pub const DEFAULT_MAX_INNER: u32 = AdaptSettings::PAPER.max_inner;

/// The `kind` of a navigator checkpoint's metadata.
pub const NAVIGATOR_KIND: &str = "gman-navigator";

/// The model settings of a navigator checkpoint (its metadata; the trainer adds its own
/// `trainer` object beside them), typed and serde-serialised. Written by
/// [`NavModel::metadata`], read by [`NavModel::from_checkpoint`]; the fields that did not
/// exist in the first checkpoints default to the values those runs had.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ModelMeta {
    /// Always [`NAVIGATOR_KIND`].
    pub kind: String,
    /// The method (its preset name).
    pub method: Method,
    /// The sizes.
    pub dims: DimsMeta,
    /// Hidden width of the PS module (PS variants only; `null` otherwise).
    #[serde(default)]
    pub ps_hidden: Option<usize>,
    /// The privileged-feature bound (absent: false).
    #[serde(default)]
    pub privileged: bool,
    /// The model's switches (`noise`, `inner_lr`, `max_inner`, `adapt_mode`, `inner_rule`,
    /// each absent in the first checkpoints: gman-core's [`ModelSpec`] defaults).
    #[serde(flatten)]
    pub spec: ModelSpec,
}

/// [`Dims`] as stored in checkpoints: the eight sizes, and the spatial-map sizes only for a
/// model with a map (absent: no map), so checkpoints without one are byte for byte as before
/// maps existed.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct DimsMeta(pub Dims);

#[derive(Serialize, Deserialize)]
struct DimsRecord {
    attr: usize,
    noise: usize,
    gen_hidden: usize,
    feat: usize,
    disc_hidden: usize,
    lstm_hidden: usize,
    embed: usize,
    ps: usize,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    map_rows: Option<usize>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    map_cols: Option<usize>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    cell_embed: Option<usize>,
}

impl Serialize for DimsMeta {
    fn serialize<S: serde::Serializer>(&self, s: S) -> std::result::Result<S::Ok, S::Error> {
        let d = &self.0;
        let map = d.map_rows + d.map_cols + d.cell_embed > 0;
        DimsRecord {
            attr: d.attr,
            noise: d.noise,
            gen_hidden: d.gen_hidden,
            feat: d.feat,
            disc_hidden: d.disc_hidden,
            lstm_hidden: d.lstm_hidden,
            embed: d.embed,
            ps: d.ps,
            map_rows: map.then_some(d.map_rows),
            map_cols: map.then_some(d.map_cols),
            cell_embed: map.then_some(d.cell_embed),
        }
        .serialize(s)
    }
}

impl<'de> Deserialize<'de> for DimsMeta {
    fn deserialize<D: serde::Deserializer<'de>>(de: D) -> std::result::Result<Self, D::Error> {
        let r = DimsRecord::deserialize(de)?;
        Ok(DimsMeta(Dims {
            attr: r.attr,
            noise: r.noise,
            gen_hidden: r.gen_hidden,
            feat: r.feat,
            disc_hidden: r.disc_hidden,
            lstm_hidden: r.lstm_hidden,
            embed: r.embed,
            ps: r.ps,
            map_rows: r.map_rows.unwrap_or(0),
            map_cols: r.map_cols.unwrap_or(0),
            cell_embed: r.cell_embed.unwrap_or(0),
        }))
    }
}

/// A navigation model: method, sizes, parameters (named like the blob's tensors), and the
/// host-side PS module for the dagger variants.
#[derive(Clone, Debug)]
pub struct NavModel {
    /// Method.
    pub method: Method,
    /// Sizes (with `ps = attr` for the PS variants).
    pub dims: Dims,
    /// θ, ω and φ, named by [`TensorId::name`].
    pub params: ParamSet,
    /// The PS module (PS variants only).
    pub ps: Option<PsModule>,
    /// Noise of G at navigation time.
    pub noise: NoiseMode,
    /// Inner-loop rates α1 (D ascent) and α2 (θ, φ descent) (paper: 1e-4).
    pub inner_lr: f32,
    /// At most this many inner updates per episode (default 4, as gman-core's
    /// [`NavConfig::default`]).
    pub max_inner: u32,
    /// For a model loaded from a weight blob: the blob, whose weights the navigator then reads
    /// in place (int8 stays int8), exactly as on the device. `params` holds a dequantised
    /// copy for inspection.
    pub blob: Option<std::sync::Arc<Vec<u8>>>,
    /// The privileged-feature bound (a diagnostic, not a deployable model): the policy sees
    /// the target's true feature in the current scene (`World::object_feature`) in place of
    /// G's output x_t, in training and at evaluation, i.e. what a perfectly adapted G would
    /// give. G is not run or trained; such a model cannot be exported to a blob.
    pub privileged: bool,
    /// The adaptation mode of the inner loop, in training and wherever the model runs
    /// (gman-core's [`AdaptMode`]): `Efficient` (per-unit gains and biases over the base
    /// weights, what the microcontroller runs) or `Full` (every parameter of θ, ω and the
    /// actor head). Blobs record it ([`FLAG_FULL_ADAPT`](gman_core::schema::FLAG_FULL_ADAPT)), so the device adapts exactly as
    /// the trainer meta-learned. Checkpoints from before this setting existed were trained in
    /// `Full`.
    pub adapt_mode: AdaptMode,
    /// The inner rule's levers beyond `inner_lr` and `max_inner` (default: the paper's).
    pub inner_rule: InnerRule,
    /// Ψ's observations kept as int16 (a blob with
    /// [`FLAG_COMPACT_PSI`](gman_core::schema::FLAG_COMPACT_PSI); [`NavConfig::compact_psi`]).
    pub compact_psi: bool,
}

impl NavModel {
    /// A fresh model. `generator` supplies G's pre-trained tensors (`GenW1`..`GenB2`), needed
    /// by every method that uses FG; `ps` the PS module of the PS variants.
    pub fn init(
        method: Method,
        base: Dims,
        seed: u64,
        generator: Option<&ParamSet>,
        ps: Option<PsModule>,
    ) -> Result<NavModel> {
        let dims = if method.uses_ps() {
            base.with_ps()
        } else {
            Dims { ps: 0, ..base }
        };
        if method.uses_ps() && ps.is_none() {
            bail!(
                "method {} needs a PS module (run `gman pretrain-ps` and pass --ps)",
                method.name()
            );
        }
        let mut rng = Xoshiro128::seed_from_u64(seed ^ 0x6d61_6e5f_696e_6974);
        let mut params = ParamSet::new();
        // (The per-cell layer comes last in `ALL`, so models without a map draw exactly the
        // random numbers they always did.)
        for id in TensorId::all_for(&dims) {
            let (r, c) = id.shape(&dims);
            let init = match id {
                _ if id.is_vector() => Init::Zeros,
                // G: pre-trained (below) or zero for plain A3C.
                TensorId::GenW1 | TensorId::GenW2 => Init::Zeros,
                // D: N(0, 0.02) as the reference (ω is randomly initialised, Algorithm 1).
                TensorId::DiscW1 | TensorId::DiscW2 => Init::Normal(0.02),
                // A small actor so that the initial policy is close to uniform.
                TensorId::ActorW => Init::Normal(0.01),
                // Policy layers: N(0, 1/in), like PyTorch's default scale.
                _ => Init::Normal(1.0 / (c as f32).sqrt()),
            };
            params.add(id.name(), r, c, init, &mut rng)?;
        }
        if method.uses_fg() {
            let g = generator.ok_or_else(|| {
                anyhow!("method {} needs a pre-trained generator (run `gman pretrain-fg` and pass --fg)", method.name())
            })?;
            for id in TensorId::GENERATOR {
                let (r, c) = id.shape(&dims);
                let src = g
                    .tensor_shaped(id.name(), r, c)
                    .with_context(|| format!("pre-trained generator for preset {:?}", dims))?;
                params
                    .get_mut(id.name())
                    .ok_or_else(|| anyhow!("missing {}", id.name()))?
                    .data
                    .copy_from_slice(&src.data);
            }
        }
        Ok(NavModel {
            method,
            dims,
            params,
            ps,
            noise: NoiseMode::Gaussian,
            inner_lr: AdaptSettings::PAPER.alpha_adapt,
            max_inner: DEFAULT_MAX_INNER,
            blob: None,
            privileged: false,
            adapt_mode: AdaptMode::Full,
            inner_rule: InnerRule::PAPER,
            compact_psi: false,
        })
    }

    /// Zero-copy views of the parameters for gman-core's navigator.
    pub fn weights(&self) -> Result<NavWeights<'_>> {
        // The host's fastest kernels (AVX2 when the CPU has it): the same bits as the portable
        // build (see `crate::simd`), so training, evaluation and the device agree.
        let w = self.weights_portable()?;
        Ok(match crate::simd::host_kernels() {
            Some(k) => w.with_kernels(k),
            None => w,
        })
    }

    /// [`NavModel::weights`] on the portable kernels.
    fn weights_portable(&self) -> Result<NavWeights<'_>> {
        if let Some(bytes) = &self.blob {
            let blob = Blob::parse(bytes).map_err(|e| anyhow!("{e}"))?;
            return Ok(NavWeights::from_blob(&blob, &self.dims)?);
        }
        let mut err = None;
        let w = NavWeights::from_fn(&self.dims, |id| {
            let (r, c) = id.shape(&self.dims);
            match self
                .params
                .tensor(id.name())
                .and_then(|p| Ok(MatRef::f32(r, c, &p.data)?))
            {
                Ok(m) => m,
                Err(e) => {
                    err.get_or_insert(e);
                    MatRef::f32(0, 0, &[]).expect("empty matrix")
                }
            }
        });
        if let Some(e) = err {
            return Err(e);
        }
        Ok(w?)
    }

    /// The navigator settings of this model: adaptation on for the methods that adapt
    /// (in training: `Manual` schedule driven by the trainer; at evaluation: `Auto`).
    pub fn nav_config(&self, training: bool) -> NavConfig {
        let adapt = if training {
            self.method.adapts_in_training()
        } else {
            self.method.adapts_at_eval()
        };
        // The blob's own mapping (what the device will run), with the host's run-time
        // choices: the training schedule, sampled actions, adaptation as the method trains.
        NavConfig {
            adapt,
            selection: Selection::Sample,
            schedule: if training {
                gman_core::navigator::Schedule::Manual
            } else {
                gman_core::navigator::Schedule::Auto
            },
            // A host has the RAM: Ψ as one batch and G's pre-gain outputs kept (the same
            // bits as the device's compact layout).
            footprint: Footprint::Fast,
            compact_psi: self.compact_psi,
            ..NavConfig::from_spec(
                &self.spec(),
                self.method.adapts_at_eval(),
                self.method.emd(),
            )
        }
    }

    /// Floats of a navigator arena that fits this model in either adaptation mode with the
    /// host's footprint ([`NavModel::nav_config`]).
    pub fn arena_len(&self) -> usize {
        host_arena_len(&self.dims)
    }

    /// The typed settings stored in checkpoints ([`ModelMeta`]).
    pub fn meta(&self) -> ModelMeta {
        ModelMeta {
            kind: NAVIGATOR_KIND.to_string(),
            method: self.method,
            dims: DimsMeta(self.dims),
            ps_hidden: self.ps.as_ref().map(|p| p.hidden),
            privileged: self.privileged,
            spec: self.spec(),
        }
    }

    /// The model's switches (gman-core's [`ModelSpec`]): what its blobs record and its
    /// checkpoints store.
    pub fn spec(&self) -> ModelSpec {
        ModelSpec {
            noise: self.noise,
            inner_lr: self.inner_lr,
            max_inner: self.max_inner,
            adapt_mode: self.adapt_mode,
            inner_rule: self.inner_rule,
        }
    }

    /// Sets the model's switches to `spec`.
    pub fn set_spec(&mut self, spec: ModelSpec) {
        let ModelSpec {
            noise,
            inner_lr,
            max_inner,
            adapt_mode,
            inner_rule,
        } = spec;
        (self.noise, self.inner_lr, self.max_inner) = (noise, inner_lr, max_inner);
        (self.adapt_mode, self.inner_rule) = (adapt_mode, inner_rule);
    }

    /// Metadata stored in checkpoints: [`NavModel::meta`] as JSON (keys sorted, as always).
    pub fn metadata(&self) -> serde_json::Value {
        // Strings, numbers and booleans only: serialising to a `Value` cannot fail.
        serde_json::to_value(self.meta()).unwrap_or_default()
    }

    /// Adds the model's tensors (and the PS module's) to a checkpoint.
    pub fn add_to_checkpoint(&self, ck: &mut Checkpoint) -> Result<()> {
        ck.add_tensors(&self.params)?;
        if let Some(ps) = &self.ps {
            ck.add_tensors(&ps.params)?;
        }
        Ok(())
    }

    /// Rebuilds a model from a checkpoint written by the trainer (any build: the fields
    /// [`ModelMeta`] gained over time default to what earlier checkpoints were trained with).
    pub fn from_checkpoint(ck: &Checkpoint) -> Result<NavModel> {
        let meta = &ck.metadata;
        if meta.get("kind").and_then(|v| v.as_str()) != Some(NAVIGATOR_KIND) {
            bail!(
                "not a navigator checkpoint (metadata kind {:?})",
                meta.get("kind")
            );
        }
        let m: ModelMeta = serde_json::from_value(meta.clone())
            .map_err(|e| anyhow!("checkpoint metadata: {e}"))?;
        check_model_record(meta)?;
        let (method, dims) = (m.method, m.dims.0);
        let mut params = ParamSet::new();
        for id in TensorId::all_for(&dims) {
            let (r, c) = id.shape(&dims);
            params.push(ck.tensor(id.name(), r, c)?.clone())?;
        }
        let ps = match m.ps_hidden {
            Some(h) => {
                let mut set = ParamSet::new();
                for (name, r, c) in [
                    (crate::pretrain::ps::PS_W1, h, gman_core::FEATURE_DIM),
                    (crate::pretrain::ps::PS_B1, h, 1),
                    (crate::pretrain::ps::PS_W2, gman_core::ATTR_DIM, h),
                    (crate::pretrain::ps::PS_B2, gman_core::ATTR_DIM, 1),
                ] {
                    set.push(ck.tensor(name, r, c)?.clone())?;
                }
                Some(PsModule::from_params(set)?)
            }
            None => None,
        };
        // The checks `gman train` applies to the flags, applied to what the file says.
        m.spec
            .validate()
            .context("stored model settings are invalid")?;
        if method.uses_ps() != (dims.ps > 0) || method.uses_ps() != ps.is_some() {
            bail!(
                "stored method {} does not match the model (PS input width {}, PS module {}); the metadata was changed",
                method.name(),
                dims.ps,
                if ps.is_some() { "present" } else { "absent" }
            );
        }
        let mut model = NavModel {
            method,
            dims,
            params,
            ps,
            noise: NoiseMode::Gaussian,
            inner_lr: 0.0,
            max_inner: 0,
            blob: None,
            privileged: m.privileged,
            adapt_mode: AdaptMode::Full,
            inner_rule: InnerRule::PAPER,
            compact_psi: false,
        };
        model.set_spec(m.spec);
        Ok(model)
    }

    /// Blob flags of this model.
    pub fn blob_flags(&self) -> u32 {
        self.model_flags().bits()
    }

    /// The model flags of this model's blobs.
    pub fn model_flags(&self) -> ModelFlags {
        self.spec()
            .flags(self.method.adapts_at_eval(), self.method.emd())
    }

    /// The inner-loop settings stored in the model's blobs ([`ModelSpec::adapt_settings`]).
    pub fn adapt_settings(&self) -> AdaptSettings {
        self.spec().adapt_settings()
    }

    /// Encodes the model as a gman-core weight blob (format v4, see `gman_core::blob`), int8 (per-row scales) or
    /// f32. The header carries the model's flags ([`NavModel::blob_flags`]) and its
    /// inner-loop settings ([`NavModel::adapt_settings`]), so a device running
    /// `NavConfig::from_header` adapts exactly as this model was trained and evaluated.
    pub fn to_blob(&self, int8: bool) -> Result<Vec<u8>> {
        if self.privileged {
            bail!("a privileged-feature model reads the simulator's true target feature and cannot run on a device; it is not exported");
        }
        // int8 quantisation would turn NaN into 0 and write a valid-looking blob.
        for id in TensorId::all_for(&self.dims) {
            let p = self.params.tensor(id.name())?;
            if let Some(i) = p.data.iter().position(|v| !v.is_finite()) {
                bail!(
                    "tensor {} has a non-finite weight ({} at index {i}); refusing to export a diverged model",
                    id.name(),
                    p.data[i]
                );
            }
        }
        let quant = if int8 { Quant::I8 } else { Quant::F32 };
        let mut out = vec![0u8; encoded_model_len_bound(&self.dims, quant)];
        let (nf, nb) = encode_model_scratch_len(&self.dims);
        let n = encode_model(
            &self.dims,
            self.blob_flags(),
            self.adapt_settings(),
            quant,
            |id, v: &mut [f32]| -> Result<()> {
                v.copy_from_slice(&self.params.tensor(id.name())?.data);
                Ok(())
            },
            &mut out,
            &mut vec![0.0; nf],
            &mut vec![0; nb],
        )
        .map_err(|e| anyhow!("encoding the blob: {e}"))?;
        out.truncate(n);
        Ok(out)
    }
}

/// Loads a model parameter set from the tensors of a blob (dequantising int8), so a blob can
/// be evaluated like a checkpoint. The method comes from the blob's flags (adapting or not)
/// and its PS width; `method` overrides it. The noise comes from the flags and `inner_lr` /
/// `max_inner` from the header's inner-loop settings (a v1 blob: 1e-4 and 4), so that
/// without an override [`NavModel::nav_config`]`(false)` is the blob's
/// `NavConfig::from_header` with sampled actions. A blob whose α1 and α2 differ is refused
/// (a `NavModel` has one inner rate).
pub fn model_from_blob(bytes: &[u8], method: Option<Method>) -> Result<NavModel> {
    model_from_blob_with_ps(bytes, method, None)
}

/// [`model_from_blob`] with the PS module a PS variant's blob needs (blobs do not carry it;
/// the PS variants are evaluated with the `ps.ckpt` they were trained with, or the tensors of
/// their training checkpoint). A PS module for a model without a PS input is refused.
pub fn model_from_blob_with_ps(
    bytes: &[u8],
    method: Option<Method>,
    ps: Option<PsModule>,
) -> Result<NavModel> {
    let blob = Blob::parse(bytes).map_err(|e| anyhow!("{e}"))?;
    let dims = blob.dims();
    let flags = blob.header().model_flags();
    // Every tensor must be present before anything is allocated from the header's dims
    // (present tensors were checked against the dims by the parser, so their sizes are backed
    // by bytes of the file).
    let missing: Vec<&str> = TensorId::all_for(&dims)
        .filter(|id| !blob.has(*id))
        .map(|id| id.name())
        .collect();
    if !missing.is_empty() {
        bail!(
            "the blob is not a complete navigator: tensor(s) {} missing",
            missing.join(", ")
        );
    }
    let mut params = ParamSet::new();
    for id in TensorId::all_for(&dims) {
        let (r, c) = id.shape(&dims);
        let mut p = Param::zeros(id.name(), r, c);
        blob.copy_f32(id, &mut p.data)
            .map_err(|e| anyhow!("{}: {e}", id.name()))?;
        params.push(p)?;
    }
    let method = method.unwrap_or(match (flags.adapt, dims.ps > 0) {
        (true, false) if flags.emd == Emd::CosSim => Method::GmanCossim,
        (true, false) => Method::Gman,
        (true, true) => Method::GmanPs,
        (false, false) => Method::A3cFg,
        (false, true) => Method::A3cFgPs,
    });
    match (method.uses_ps(), &ps) {
        (true, None) => bail!(
            "{} is a PS variant and blobs do not carry the PS module: give the one it was trained \
             with (`--ps ps.ckpt`, or its training checkpoint), or evaluate the checkpoint",
            method.name()
        ),
        (false, Some(_)) => bail!(
            "a PS module was given, but {} has no PS input",
            method.name()
        ),
        _ => {}
    }
    let spec = ModelSpec::from_header(blob.header());
    Ok(NavModel {
        method,
        dims,
        params,
        ps,
        noise: spec.noise,
        inner_lr: spec.inner_lr,
        max_inner: spec.max_inner,
        blob: Some(std::sync::Arc::new(bytes.to_vec())),
        privileged: false,
        adapt_mode: spec.adapt_mode,
        inner_rule: spec.inner_rule,
        compact_psi: blob.header().flags() & gman_core::schema::FLAG_COMPACT_PSI != 0,
    })
}

/// Reads a model from a checkpoint (`.ckpt`) or a blob (`.gman`) file.
pub fn load_model(path: &Path, method: Option<Method>) -> Result<NavModel> {
    load_model_with_ps(path, method, None)
}

/// [`load_model`]; a blob of a PS variant takes its PS module from the checkpoint file
/// `ps_path` (a `ps.ckpt` of `gman pretrain-ps`, or the run's training checkpoint). A
/// checkpoint carries its own PS module, so `ps_path` is refused with one.
pub fn load_model_with_ps(
    path: &Path,
    method: Option<Method>,
    ps_path: Option<&Path>,
) -> Result<NavModel> {
    let bytes = std::fs::read(path).with_context(|| format!("reading model {}", path.display()))?;
    if bytes.starts_with(&gman_core::blob::MAGIC) && !bytes.starts_with(b"GMANCKPT") {
        let ps = match ps_path {
            Some(p) => Some(
                PsModule::load(p).with_context(|| format!("loading PS module {}", p.display()))?,
            ),
            None => None,
        };
        return model_from_blob_with_ps(&bytes, method, ps)
            .with_context(|| format!("blob {}", path.display()));
    }
    if let Some(p) = ps_path {
        bail!(
            "checkpoint {}: a checkpoint carries its own PS module; --ps {} is for blobs",
            path.display(),
            p.display()
        );
    }
    let ck = Checkpoint::from_bytes(&bytes, Some(path))?;
    let mut m =
        NavModel::from_checkpoint(&ck).with_context(|| format!("checkpoint {}", path.display()))?;
    if let Some(method) = method {
        if method.uses_ps() != m.method.uses_ps() {
            bail!(
                "checkpoint {}: it was trained as {} ({} the PS module) and cannot be evaluated as {}; \
                 use a method {} the PS module (e.g. gman-noemd-ps for gman-ps with adaptation off)",
                path.display(),
                m.method.name(),
                if m.method.uses_ps() { "with" } else { "without" },
                method.name(),
                if m.method.uses_ps() { "with" } else { "without" },
            );
        }
        m.method = method;
    }
    Ok(m)
}

/// Floats of a navigator arena (capacity [`K`]) that fits `dims` in either adaptation
/// mode with the host's [`Footprint::Fast`].
pub fn host_arena_len(dims: &Dims) -> usize {
    use gman_core::navigator::{Efficient, Full, Navigator};
    Navigator::<Full, { K }>::arena_len_for(dims, Footprint::Fast).max(
        Navigator::<Efficient, { K }>::arena_len_for(dims, Footprint::Fast),
    )
}

/// The model settings of a checkpoint's metadata: every top-level key but `trainer`.
fn model_settings(metadata: &serde_json::Value) -> serde_json::Map<String, serde_json::Value> {
    let mut m = metadata.as_object().cloned().unwrap_or_default();
    m.remove("trainer");
    m
}

/// Refuses a checkpoint whose model settings differ from the copy the trainer stored beside
/// them (the trainer settings' `model`), naming the first setting that differs and both values.
/// Checkpoints without a copy (older builds, pre-training) pass.
pub fn check_model_record(metadata: &serde_json::Value) -> Result<()> {
    let Some(copy) = metadata
        .get("trainer")
        .and_then(|t| t.get("model"))
        .filter(|c| !c.is_null())
    else {
        return Ok(());
    };
    let now = serde_json::Value::Object(model_settings(metadata));
    let mut diffs = Vec::new();
    json_diffs("", &now, copy, &mut diffs);
    if let Some((key, a, b)) = diffs.first() {
        bail!(
            "the checkpoint's model settings were changed after training wrote it: {key} is {a} but was {b} when the checkpoint was written ({} setting(s) differ); the tensors were trained with the recorded settings",
            diffs.len()
        );
    }
    Ok(())
}

/// Leaves of `a` and `b` that differ, as (dotted key, value in `a`, value in `b`).
fn json_diffs(
    at: &str,
    a: &serde_json::Value,
    b: &serde_json::Value,
    out: &mut Vec<(String, String, String)>,
) {
    use serde_json::Value;
    match (a, b) {
        (Value::Object(x), Value::Object(y)) => {
            let keys: std::collections::BTreeSet<&String> = x.keys().chain(y.keys()).collect();
            for k in keys {
                let key = if at.is_empty() {
                    k.clone()
                } else {
                    format!("{at}.{k}")
                };
                let show = |v: Option<&Value>| v.map_or("absent".to_string(), |v| v.to_string());
                match (x.get(k), y.get(k)) {
                    (Some(p), Some(q)) => json_diffs(&key, p, q, out),
                    (p, q) => out.push((key, show(p), show(q))),
                }
            }
        }
        _ if a != b => out.push((at.to_string(), a.to_string(), b.to_string())),
        _ => {}
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The presets answer the six predicates as the truth table written out here pins them,
    /// have distinct switches and round-trip their names.
    #[test]
    fn presets_answer_the_pinned_predicates_and_names() {
        // name, uses_fg, uses_ps, adapts_in_training, uses_cossim, adapts_at_eval,
        // trains_generator
        let old = [
            ("a3c", [false, false, false, false, false, false]),
            ("a3c-fg", [true, false, false, false, false, false]),
            ("a3c-ps", [false, true, false, false, false, false]),
            ("a3c-fg-ps", [true, true, false, false, false, false]),
            ("gman", [true, false, true, false, true, true]),
            ("gman-ps", [true, true, true, false, true, true]),
            ("gman-nometa", [true, false, false, false, true, false]),
            ("gman-cossim", [true, false, true, true, true, true]),
            ("gman-noemd", [true, false, false, false, false, true]),
            // added after the enum: meta-trained, θ frozen in the outer loop
            ("gman-fixed-g", [true, false, true, false, true, false]),
            ("gman-noemd-ps", [true, true, false, false, false, true]),
        ];
        assert_eq!(old.len(), Method::PRESETS.len());
        for (name, p) in old {
            let m = Method::parse(name).unwrap();
            assert_eq!(m.name(), name);
            let got = [
                m.uses_fg(),
                m.uses_ps(),
                m.adapts_in_training(),
                m.uses_cossim(),
                m.adapts_at_eval(),
                m.trains_generator(),
            ];
            assert_eq!(got, p, "{name}");
            assert_eq!(serde_json::to_value(m).unwrap(), serde_json::json!(name));
            let back: Method = serde_json::from_value(serde_json::json!(name)).unwrap();
            assert_eq!(back, m);
        }
        for (i, a) in Method::PRESETS.iter().enumerate() {
            for b in &Method::PRESETS[i + 1..] {
                assert_ne!(a.1, b.1, "{} and {} have the same switches", a.0, b.0);
            }
        }
        let custom = Method {
            emd: Emd::CosSim,
            ..Method::GmanNometa
        };
        assert_eq!(custom.name(), "custom");
        let v = serde_json::to_value(custom).unwrap();
        assert!(serde_json::from_value::<Method>(v).is_err());
        assert!(Method::parse("gman-x").is_none());
        assert_eq!(
            <Method as clap::ValueEnum>::from_str("gman-cossim", false).unwrap(),
            Method::GmanCossim
        );
    }

    /// The metadata the old untyped code wrote, written out: the typed settings must give
    /// the same JSON (so checkpoints stay byte for byte) and read it back.
    fn old_metadata(m: &NavModel) -> serde_json::Value {
        serde_json::json!({
            "kind": "gman-navigator",
            "method": m.method.name(),
            "dims": crate::optim::dims_json(&m.dims),
            "noise": match m.noise { NoiseMode::Gaussian => "gaussian", NoiseMode::Zero => "zero" },
            "ps_hidden": m.ps.as_ref().map(|p| p.hidden),
            "inner_lr": m.inner_lr,
            "max_inner": m.max_inner,
            "privileged": m.privileged,
            "adapt_mode": match m.adapt_mode { AdaptMode::Full => "full", AdaptMode::Efficient => "efficient" },
        })
    }

    #[test]
    fn typed_metadata_is_the_old_json_and_reads_old_checkpoints() {
        let g = crate::pretrain::generator::init_generator(
            &Dims::MCU,
            &mut Xoshiro128::seed_from_u64(1),
        )
        .unwrap();
        for (method, dims) in [
            (Method::Gman, Dims::MCU),
            (Method::A3cFg, Dims::MCU.with_map(3, 3, 8)),
        ] {
            let mut m = NavModel::init(method, dims, 1, Some(&g), None).unwrap();
            m.noise = NoiseMode::Zero;
            m.inner_lr = 3e-3;
            m.max_inner = 7;
            m.adapt_mode = AdaptMode::Efficient;
            let old = old_metadata(&m);
            assert_eq!(m.metadata().to_string(), old.to_string());
            let mut ck = Checkpoint::new(old);
            m.add_to_checkpoint(&mut ck).unwrap();
            let back = NavModel::from_checkpoint(&ck).unwrap();
            assert_eq!(back.meta(), m.meta());
            assert_eq!(back.params.names(), m.params.names());
            assert_eq!(back.params.num_values(), m.params.num_values());
        }
        // The first checkpoints had none of the later fields: their defaults apply.
        let m = NavModel::init(Method::Gman, Dims::MCU, 2, Some(&g), None).unwrap();
        let mut first = serde_json::json!({
            "kind": "gman-navigator",
            "method": "gman",
            "dims": crate::optim::dims_json(&m.dims),
            "ps_hidden": null,
        });
        let mut ck = Checkpoint::new(first.clone());
        m.add_to_checkpoint(&mut ck).unwrap();
        let back = NavModel::from_checkpoint(&ck).unwrap();
        assert_eq!(
            (
                back.noise,
                back.inner_lr,
                back.max_inner,
                back.privileged,
                back.adapt_mode
            ),
            (
                NoiseMode::Gaussian,
                1e-4,
                DEFAULT_MAX_INNER,
                false,
                AdaptMode::Full
            )
        );
        // A wrong type is a typed error naming the field, not a silent default.
        first["adapt_mode"] = serde_json::json!("sideways");
        ck.metadata = first;
        let e = NavModel::from_checkpoint(&ck).unwrap_err().to_string();
        assert!(e.contains("sideways") || e.contains("variant"), "{e}");
    }
}

#[cfg(test)]
mod inner_rule_tests {
    use super::*;
    use crate::optim::checkpoint::Checkpoint;
    use gman_core::navigator::StepRule;
    use gman_core::schema::AdaptLossKind;

    #[test]
    fn inner_rule_round_trips_through_checkpoint_and_blob() {
        let g = crate::pretrain::generator::init_generator(
            &Dims::MCU,
            &mut Xoshiro128::seed_from_u64(1),
        )
        .unwrap();
        let mut m = NavModel::init(Method::Gman, Dims::MCU, 1, Some(&g), None).unwrap();
        m.adapt_mode = AdaptMode::Efficient;
        m.inner_lr = 0.5;
        // The paper's rule writes no `inner_rule` key (old checkpoints' JSON unchanged).
        assert!(m.metadata().get("inner_rule").is_none());
        m.inner_rule = InnerRule {
            disc_lr: Some(0.05),
            disc_steps: 5,
            step_rule: StepRule::PerGroup,
            disc_head_reset: true,
            adapt_loss: AdaptLossKind::Reference,
            reference_critic: true,
            head_only: true,
            commit_delay: 17,
        };
        let mut ck = Checkpoint::new(m.metadata());
        m.add_to_checkpoint(&mut ck).unwrap();
        let back = NavModel::from_checkpoint(&ck).unwrap();
        assert_eq!(back.inner_rule, m.inner_rule);
        // The blob carries it too, and the device's configuration follows.
        let blob = m.to_blob(false).unwrap();
        let b = model_from_blob(&blob, None).unwrap();
        assert_eq!(b.inner_rule, m.inner_rule);
        assert_eq!(b.inner_lr, 0.5);
        let parsed = gman_core::blob::Blob::parse(&blob).unwrap();
        let cfg = parsed.nav_config();
        assert_eq!((cfg.alpha_disc, cfg.alpha_adapt), (0.05, 0.5));
        assert_eq!((cfg.disc_steps, cfg.step_rule), (5, StepRule::PerGroup));
        assert!(cfg.disc_head_reset && m.nav_config(false).disc_head_reset);
        assert!(cfg.head_only && m.nav_config(false).head_only);
        assert_eq!(cfg.adapt_loss, AdaptLossKind::Reference);
        assert_eq!(cfg.ld.critic_scale, 10.0);
        assert_eq!(m.nav_config(false).ld.critic_scale, 10.0);
        assert_eq!(cfg.disc_steps, m.nav_config(false).disc_steps);
        assert_eq!(cfg.commit_delay, 17);
        assert_eq!(m.nav_config(true).commit_delay, 17);
        // Nonsense in a file is refused with the field named.
        let mut bad = m.metadata();
        bad["inner_rule"]["disc_steps"] = serde_json::json!(0);
        let mut ck = Checkpoint::new(bad);
        m.add_to_checkpoint(&mut ck).unwrap();
        let err = format!("{:#}", NavModel::from_checkpoint(&ck).unwrap_err());
        assert!(err.contains("disc-steps"), "{err}");
    }
}
