//! Navigation models: the methods of the paper's tables and their parameters.

use std::path::Path;

use anyhow::{anyhow, bail, Context, Result};
use gman_core::blob::{
    encode_with_settings, encoded_len_bound, AdaptSettings, Blob, TensorData, TensorId, TensorSpec,
    FLAG_ADAPT, FLAG_COSSIM, FLAG_FULL_ADAPT, FLAG_ZERO_NOISE,
};
use gman_core::matrix::MatRef;
use gman_core::memory::AdaptMode;
use gman_core::navigator::{NavConfig, NavWeights, NoiseMode, Selection};
use gman_core::quant::quantize_rows;
use gman_core::rng::Xoshiro128;
use gman_core::Dims;
use serde::{Deserialize, Serialize};

use crate::train::checkpoint::Checkpoint;
use crate::train::params::{Init, Param, ParamSet};
use crate::train::ps::PsModule;

/// A navigation method (rows of the paper's Tables 2 and 3).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize, clap::ValueEnum)]
#[serde(rename_all = "kebab-case")]
pub enum Method {
    /// A3C baseline: observation, target attributes, previous action → LSTM → actor-critic.
    A3c,
    /// A3C + the pre-trained feature generator's target feature (FG), no adaptation.
    A3cFg,
    /// A3C with the PS module (A3C†).
    A3cPs,
    /// A3C + FG + PS.
    A3cFgPs,
    /// GMAN: FG + environmental meta discriminator, meta-trained (Algorithm 1).
    Gman,
    /// GMAN with the PS module (GMAN†).
    GmanPs,
    /// EMD without meta-learning: trained as A3C + FG, adapted at test time only.
    GmanNometa,
    /// EMD variant: cosine similarity between x_t and s_t in place of D (paper Table 3),
    /// meta-trained like GMAN.
    GmanCossim,
    /// Control without the EMD: G's θ and the policy are trained by the outer loop exactly as
    /// in GMAN, but no inner loop runs, in training or at evaluation. It differs from `a3c-fg`
    /// only in that θ is trained, and from `gman` only in the adaptation, so it separates the
    /// two sources of GMAN's gain.
    GmanNoemd,
}

impl Method {
    /// The name used on the command line and in files.
    pub fn name(self) -> &'static str {
        match self {
            Method::A3c => "a3c",
            Method::A3cFg => "a3c-fg",
            Method::A3cPs => "a3c-ps",
            Method::A3cFgPs => "a3c-fg-ps",
            Method::Gman => "gman",
            Method::GmanPs => "gman-ps",
            Method::GmanNometa => "gman-nometa",
            Method::GmanCossim => "gman-cossim",
            Method::GmanNoemd => "gman-noemd",
        }
    }

    /// Parses [`Method::name`].
    pub fn parse(s: &str) -> Option<Method> {
        [
            Method::A3c,
            Method::A3cFg,
            Method::A3cPs,
            Method::A3cFgPs,
            Method::Gman,
            Method::GmanPs,
            Method::GmanNometa,
            Method::GmanCossim,
            Method::GmanNoemd,
        ]
        .into_iter()
        .find(|m| m.name() == s)
    }

    /// Uses the pre-trained feature generator (otherwise G is zero and x_t carries nothing).
    pub fn uses_fg(self) -> bool {
        !matches!(self, Method::A3c | Method::A3cPs)
    }

    /// Feeds the PS module's prediction to the policy.
    pub fn uses_ps(self) -> bool {
        matches!(self, Method::A3cPs | Method::A3cFgPs | Method::GmanPs)
    }

    /// Runs the inner loop during training (and therefore meta-learns θ and φ through it).
    pub fn adapts_in_training(self) -> bool {
        matches!(self, Method::Gman | Method::GmanPs | Method::GmanCossim)
    }

    /// Scores generated features with the cosine similarity instead of D.
    pub fn uses_cossim(self) -> bool {
        matches!(self, Method::GmanCossim)
    }

    /// Runs the inner loop at evaluation.
    pub fn adapts_at_eval(self) -> bool {
        matches!(
            self,
            Method::Gman | Method::GmanPs | Method::GmanNometa | Method::GmanCossim
        )
    }

    /// The outer loop updates G's θ (the meta-trained methods and their `gman-noemd`
    /// control; the FG baselines keep the pre-trained generator frozen, as the paper's "FG"
    /// row).
    pub fn trains_generator(self) -> bool {
        self.adapts_in_training() || self == Method::GmanNoemd
    }
}

/// `full` / `efficient`, as in checkpoints and on the command line.
pub fn mode_name(m: AdaptMode) -> &'static str {
    match m {
        AdaptMode::Full => "full",
        AdaptMode::Efficient => "efficient",
    }
}

/// Default cap on inner updates per episode (gman-core's default).
pub const DEFAULT_MAX_INNER: u32 = 4;

/// The names of the tensors of a model, as in blobs and checkpoints.
pub fn tensor_name(id: TensorId) -> &'static str {
    id.name()
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
    /// actor head). Blobs record it ([`FLAG_FULL_ADAPT`]), so the device adapts exactly as
    /// the trainer meta-learned. Checkpoints from before this setting existed were trained in
    /// `Full`.
    pub adapt_mode: AdaptMode,
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
            inner_lr: 1e-4,
            max_inner: DEFAULT_MAX_INNER,
            blob: None,
            privileged: false,
            adapt_mode: AdaptMode::Full,
        })
    }

    /// Zero-copy views of the parameters for gman-core's navigator.
    pub fn weights(&self) -> Result<NavWeights<'_>> {
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
        NavConfig {
            adapt,
            noise: self.noise,
            selection: Selection::Sample,
            emd: if self.method.uses_cossim() {
                gman_core::navigator::Emd::CosSim
            } else {
                gman_core::navigator::Emd::Discriminator
            },
            alpha_disc: self.inner_lr,
            alpha_adapt: self.inner_lr,
            max_inner_updates: self.max_inner,
            schedule: if training {
                gman_core::navigator::Schedule::Manual
            } else {
                gman_core::navigator::Schedule::Auto
            },
            mode: Some(self.adapt_mode),
            ..NavConfig::default()
        }
    }

    /// Metadata stored in checkpoints.
    pub fn metadata(&self) -> serde_json::Value {
        serde_json::json!({
            "kind": "gman-navigator",
            "method": self.method.name(),
            "dims": crate::train::dims_json(&self.dims),
            "noise": match self.noise { NoiseMode::Gaussian => "gaussian", NoiseMode::Zero => "zero" },
            "ps_hidden": self.ps.as_ref().map(|p| p.hidden),
            "inner_lr": self.inner_lr,
            "max_inner": self.max_inner,
            "privileged": self.privileged,
            "adapt_mode": mode_name(self.adapt_mode),
        })
    }

    /// Adds the model's tensors (and the PS module's) to a checkpoint.
    pub fn add_to_checkpoint(&self, ck: &mut Checkpoint) -> Result<()> {
        ck.add_tensors(&self.params)?;
        if let Some(ps) = &self.ps {
            ck.add_tensors(&ps.params)?;
        }
        Ok(())
    }

    /// Rebuilds a model from a checkpoint written by the trainer.
    pub fn from_checkpoint(ck: &Checkpoint) -> Result<NavModel> {
        let meta = &ck.metadata;
        if meta.get("kind").and_then(|v| v.as_str()) != Some("gman-navigator") {
            bail!(
                "not a navigator checkpoint (metadata kind {:?})",
                meta.get("kind")
            );
        }
        let method = meta
            .get("method")
            .and_then(|v| v.as_str())
            .and_then(Method::parse)
            .ok_or_else(|| anyhow!("checkpoint has no known method"))?;
        let d = meta
            .get("dims")
            .ok_or_else(|| anyhow!("checkpoint has no dims"))?;
        let get = |k: &str| -> Result<usize> {
            d.get(k)
                .and_then(|v| v.as_u64())
                .map(|v| v as usize)
                .ok_or_else(|| anyhow!("dims.{k} missing"))
        };
        let dims = Dims {
            attr: get("attr")?,
            noise: get("noise")?,
            gen_hidden: get("gen_hidden")?,
            feat: get("feat")?,
            disc_hidden: get("disc_hidden")?,
            lstm_hidden: get("lstm_hidden")?,
            embed: get("embed")?,
            ps: get("ps")?,
            // Absent before spatial maps existed: no map.
            map_rows: get("map_rows").unwrap_or(0),
            map_cols: get("map_cols").unwrap_or(0),
            cell_embed: get("cell_embed").unwrap_or(0),
        };
        let mut params = ParamSet::new();
        for id in TensorId::all_for(&dims) {
            let (r, c) = id.shape(&dims);
            params.push(ck.tensor(id.name(), r, c)?.clone())?;
        }
        let ps = match meta.get("ps_hidden").and_then(|v| v.as_u64()) {
            Some(h) => {
                let h = h as usize;
                let mut set = ParamSet::new();
                for (name, r, c) in [
                    (crate::train::ps::PS_W1, h, gman_core::FEATURE_DIM),
                    (crate::train::ps::PS_B1, h, 1),
                    (crate::train::ps::PS_W2, gman_core::ATTR_DIM, h),
                    (crate::train::ps::PS_B2, gman_core::ATTR_DIM, 1),
                ] {
                    set.push(ck.tensor(name, r, c)?.clone())?;
                }
                Some(PsModule::from_params(set)?)
            }
            None => None,
        };
        let noise = match meta.get("noise").and_then(|v| v.as_str()) {
            Some("zero") => NoiseMode::Zero,
            _ => NoiseMode::Gaussian,
        };
        let inner_lr = meta
            .get("inner_lr")
            .and_then(|v| v.as_f64())
            .unwrap_or(1e-4) as f32;
        // The checks `gman train` applies to the flags, applied to what the file says.
        if !(inner_lr.is_finite() && inner_lr >= 0.0) {
            bail!("stored inner_lr {inner_lr} is invalid: it must be finite and non-negative (like --inner-lr)");
        }
        if method.uses_ps() != (dims.ps > 0) || method.uses_ps() != ps.is_some() {
            bail!(
                "stored method {} does not match the model (PS input width {}, PS module {}); the metadata was changed",
                method.name(),
                dims.ps,
                if ps.is_some() { "present" } else { "absent" }
            );
        }
        let max_inner = meta
            .get("max_inner")
            .and_then(|v| v.as_u64())
            .map_or(DEFAULT_MAX_INNER, |v| v.min(u32::MAX as u64) as u32);
        Ok(NavModel {
            method,
            dims,
            params,
            ps,
            noise,
            inner_lr,
            max_inner,
            blob: None,
            privileged: meta
                .get("privileged")
                .and_then(|v| v.as_bool())
                .unwrap_or(false),
            adapt_mode: match meta.get("adapt_mode").and_then(|v| v.as_str()) {
                None | Some("full") => AdaptMode::Full,
                Some("efficient") => AdaptMode::Efficient,
                Some(other) => {
                    bail!("checkpoint adapt_mode {other:?} (expected full or efficient)")
                }
            },
        })
    }

    /// Blob flags of this model.
    pub fn blob_flags(&self) -> u32 {
        let mut f = 0;
        if self.method.adapts_at_eval() {
            f |= FLAG_ADAPT;
        }
        if self.noise == NoiseMode::Zero {
            f |= FLAG_ZERO_NOISE;
        }
        if self.method.uses_cossim() {
            f |= FLAG_COSSIM;
        }
        if self.adapt_mode == AdaptMode::Full {
            f |= FLAG_FULL_ADAPT;
        }
        f
    }

    /// The inner-loop settings stored in the model's blobs: `inner_lr` as both α1 and α2,
    /// and `max_inner`.
    pub fn adapt_settings(&self) -> AdaptSettings {
        AdaptSettings {
            alpha_disc: self.inner_lr,
            alpha_adapt: self.inner_lr,
            max_inner: self.max_inner,
        }
    }

    /// Encodes the model as a gman-core weight blob (format v2), int8 (per-row scales) or
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
        let mut quantised: Vec<(TensorId, Vec<u8>, Vec<f32>)> = Vec::new();
        if int8 {
            for id in TensorId::all_for(&self.dims).filter(|id| !id.is_vector()) {
                let p = self.params.tensor(id.name())?;
                let (mut q, mut s) = (vec![0u8; p.data.len()], vec![0.0f32; p.rows]);
                quantize_rows(&p.data, p.rows, p.cols, &mut q, &mut s)?;
                quantised.push((id, q, s));
            }
        }
        let mut specs = Vec::new();
        for id in TensorId::all_for(&self.dims) {
            let data = match quantised.iter().find(|(q, _, _)| *q == id) {
                Some((_, q, s)) => TensorData::I8 { q, scales: s },
                None => TensorData::F32(&self.params.tensor(id.name())?.data),
            };
            specs.push(TensorSpec { id, data });
        }
        let mut out = vec![0u8; encoded_len_bound(&specs)];
        let n = encode_with_settings(
            &self.dims,
            self.blob_flags(),
            self.adapt_settings(),
            &specs,
            &mut out,
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
    let blob = Blob::parse(bytes).map_err(|e| anyhow!("{e}"))?;
    let dims = blob.dims();
    let flags = blob.header().flags();
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
    let method = method.unwrap_or(match (flags & FLAG_ADAPT != 0, dims.ps > 0) {
        (true, false) if flags & FLAG_COSSIM != 0 => Method::GmanCossim,
        (true, false) => Method::Gman,
        (true, true) => Method::GmanPs,
        (false, false) => Method::A3cFg,
        (false, true) => Method::A3cFgPs,
    });
    if method.uses_ps() {
        bail!("blob evaluation of PS variants needs the PS module, which blobs do not carry; evaluate the checkpoint instead");
    }
    let noise = if flags & FLAG_ZERO_NOISE != 0 {
        NoiseMode::Zero
    } else {
        NoiseMode::Gaussian
    };
    let settings = blob.header().adapt_settings();
    if settings.alpha_disc.to_bits() != settings.alpha_adapt.to_bits() {
        bail!(
            "the blob's inner-loop rates differ (alpha_disc {}, alpha_adapt {}); the host \
             models one rate for both (--inner-lr)",
            settings.alpha_disc,
            settings.alpha_adapt
        );
    }
    Ok(NavModel {
        method,
        dims,
        params,
        ps: None,
        noise,
        inner_lr: settings.alpha_adapt,
        max_inner: settings.max_inner,
        blob: Some(std::sync::Arc::new(bytes.to_vec())),
        privileged: false,
        adapt_mode: blob.header().adapt_mode(),
    })
}

/// Reads a model from a checkpoint (`.ckpt`) or a blob (`.gman`) file.
pub fn load_model(path: &Path, method: Option<Method>) -> Result<NavModel> {
    let bytes = std::fs::read(path).with_context(|| format!("reading model {}", path.display()))?;
    if bytes.starts_with(&gman_core::blob::MAGIC) && !bytes.starts_with(b"GMANCKPT") {
        return model_from_blob(&bytes, method).with_context(|| format!("blob {}", path.display()));
    }
    let ck = Checkpoint::from_bytes(&bytes, Some(path))?;
    let mut m =
        NavModel::from_checkpoint(&ck).with_context(|| format!("checkpoint {}", path.display()))?;
    if let Some(method) = method {
        m.method = method;
    }
    Ok(m)
}
