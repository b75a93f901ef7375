//! A navigation model: method, sizes, parameters named like the blob's tensors, the
//! host-side PS module, and what it builds: the navigator's weights and configuration, its
//! checkpoint and its blob.

use anyhow::{anyhow, bail, Context, Result};
use gman_core::blob::{
    encode_model, encode_model_scratch_len, encoded_model_len_bound, Blob, Quant, TensorId,
};
use gman_core::navigator::memory::{AdaptMode, Footprint};
use gman_core::navigator::{NavConfig, NavWeights, Selection};
use gman_core::nn::matrix::MatRef;
use gman_core::rng::Xoshiro128;
use gman_core::spec::ModelSpec;
use gman_core::Dims;

use crate::optim::checkpoint::Checkpoint;
use crate::optim::params::{Init, ParamSet};
use crate::pretrain::ps::PsModule;

use super::method::Method;
use super::record::{check_model_record, DimsMeta, ModelMeta, NAVIGATOR_KIND};

/// Capacity k of the navigation buffer Ψ (the paper's k = 20).
pub const K: usize = 20;
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
    /// The model's settings (gman-core's [`ModelSpec`]: noise, inner rates and cap, the
    /// adaptation mode, the inner rule, Ψ's form): what its checkpoints store and its
    /// blobs record. Whether it adapts and its EMD are the method's: [`NavModel::spec`]
    /// fills them in. The adaptation mode is that of the inner loop in training and
    /// wherever the model runs: `Efficient` (per-unit gains and biases over the base
    /// weights, what the microcontroller runs) or `Full` (every parameter of θ, ω and the
    /// actor head); checkpoints from before the setting existed were trained in `Full`.
    pub spec: ModelSpec,
    /// For a model loaded from a weight blob: the blob, whose weights the navigator then reads
    /// in place (int8 stays int8), exactly as on the device. `params` holds a dequantised
    /// copy for inspection.
    pub blob: Option<std::sync::Arc<Vec<u8>>>,
    /// The privileged-feature bound (a diagnostic, not a deployable model): the policy sees
    /// the target's true feature in the current scene (`World::object_feature`) in place of
    /// G's output x_t, in training and at evaluation, i.e. what a perfectly adapted G would
    /// give. G is not run or trained; such a model cannot be exported to a blob.
    pub privileged: bool,
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
            spec: ModelSpec::paper(AdaptMode::Full),
            blob: None,
            privileged: false,
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
        let spec = self.spec();
        NavConfig {
            model: ModelSpec { adapt, ..spec },
            selection: Selection::Sample,
            schedule: if training {
                gman_core::navigator::Schedule::Manual
            } else {
                gman_core::navigator::Schedule::Auto
            },
            // A host has the RAM: Ψ as one batch and G's pre-gain outputs kept (the same
            // bits as the device's compact layout).
            footprint: Footprint::Fast,
            ..NavConfig::from_spec(&spec)
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

    /// The model's settings as its blobs record them and its checkpoints store them:
    /// [`NavModel::spec`](field@NavModel::spec) with whether it adapts and its EMD, which are
    /// the method's, and f32 activations (how a blob runs is `gman export`'s choice).
    pub fn spec(&self) -> ModelSpec {
        ModelSpec {
            adapt: self.method.adapts_at_eval(),
            emd: self.method.emd(),
            int8_activations: false,
            ..self.spec
        }
    }

    /// Metadata stored in checkpoints: [`NavModel::meta`] as JSON (keys sorted, as always).
    pub fn metadata(&self) -> serde_json::Value {
        // Strings, numbers and booleans only: serialising to a `Value` cannot fail.
        serde_json::to_value(self.meta()).unwrap_or_default()
    }

    /// Adds the model's tensors (and the PS module's) to a checkpoint.
    pub(crate) fn add_to_checkpoint(&self, ck: &mut Checkpoint) -> Result<()> {
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
        Ok(NavModel {
            method,
            dims,
            params,
            ps,
            spec: m.spec,
            blob: None,
            privileged: m.privileged,
        })
    }

    /// Encodes the model as a gman-core weight blob (format v5, see `gman_core::blob`), int8
    /// (per-row scales) or f32. The header names the model's settings ([`NavModel::spec`],
    /// with f32 activations and Ψ kept as f32: `gman export --activations` sets those), so
    /// a device running `NavConfig::from_header` adapts exactly as this model was trained
    /// and evaluated.
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
        let spec = ModelSpec {
            int8_activations: false,
            compact_psi: false,
            ..self.spec()
        };
        let n = encode_model(
            &self.dims,
            &spec,
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

/// Floats of a navigator arena (capacity [`K`]) that fits `dims` in either adaptation
/// mode with the host's [`Footprint::Fast`].
pub(crate) fn host_arena_len(dims: &Dims) -> usize {
    use gman_core::navigator::{Efficient, Full, Navigator};
    Navigator::<Full, { K }>::arena_len_for(dims, Footprint::Fast).max(
        Navigator::<Efficient, { K }>::arena_len_for(dims, Footprint::Fast),
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    use crate::model::record::DEFAULT_MAX_INNER;
    use gman_core::navigator::NoiseMode;
    use gman_core::spec::schema::Emd;

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
        assert_eq!(Method::parse("gman-cossim"), Some(Method::GmanCossim));
    }

    /// The metadata the old untyped code wrote, written out: the typed settings must give
    /// the same JSON (so checkpoints stay byte for byte) and read it back.
    fn old_metadata(m: &NavModel) -> serde_json::Value {
        serde_json::json!({
            "kind": "gman-navigator",
            "method": m.method.name(),
            "dims": crate::optim::dims_json(&m.dims),
            "noise": match m.spec.noise { NoiseMode::Gaussian => "gaussian", NoiseMode::Zero => "zero" },
            "ps_hidden": m.ps.as_ref().map(|p| p.hidden),
            "inner_lr": m.spec.inner_lr,
            "max_inner": m.spec.max_inner,
            "privileged": m.privileged,
            "adapt_mode": match m.spec.adapt_mode { AdaptMode::Full => "full", AdaptMode::Efficient => "efficient" },
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
            m.spec.noise = NoiseMode::Zero;
            m.spec.inner_lr = 3e-3;
            m.spec.max_inner = 7;
            m.spec.adapt_mode = AdaptMode::Efficient;
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
                back.spec.noise,
                back.spec.inner_lr,
                back.spec.max_inner,
                back.privileged,
                back.spec.adapt_mode
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
    use crate::model::model_from_blob;
    use crate::optim::checkpoint::Checkpoint;

    #[test]
    fn inner_rule_round_trips_through_checkpoint_and_blob() {
        let g = crate::pretrain::generator::init_generator(
            &Dims::MCU,
            &mut Xoshiro128::seed_from_u64(1),
        )
        .unwrap();
        let mut m = NavModel::init(Method::Gman, Dims::MCU, 1, Some(&g), None).unwrap();
        m.spec.adapt_mode = AdaptMode::Efficient;
        m.spec.inner_lr = 0.5;
        // The paper's rule writes no `inner_rule` key (old checkpoints' JSON unchanged).
        assert!(m.metadata().get("inner_rule").is_none());
        m.spec.inner_rule = ModelSpec::EVERY_SETTING_CHANGED.inner_rule;
        let mut ck = Checkpoint::new(m.metadata());
        m.add_to_checkpoint(&mut ck).unwrap();
        let back = NavModel::from_checkpoint(&ck).unwrap();
        assert_eq!(back.spec.inner_rule, m.spec.inner_rule);
        // The blob carries it too, and the device's configuration follows.
        let blob = m.to_blob(false).unwrap();
        let b = model_from_blob(&blob, None).unwrap();
        assert_eq!(b.spec.inner_rule, m.spec.inner_rule);
        assert_eq!(b.spec.inner_lr, 0.5);
        let parsed = gman_core::blob::Blob::parse(&blob).unwrap();
        let cfg = parsed.nav_config();
        assert_eq!((cfg.model.alpha_disc(), cfg.model.inner_lr), (0.05, 0.5));
        assert_eq!(cfg.model.inner_rule, m.spec.inner_rule);
        assert_eq!(cfg.model.inner_rule.critic_scale(), 10.0);
        // The host runs what the device runs.
        for training in [false, true] {
            assert_eq!(
                m.nav_config(training).model.inner_rule,
                cfg.model.inner_rule
            );
        }
        // Nonsense in a file is refused with the field named.
        let mut bad = m.metadata();
        bad["inner_rule"]["disc_steps"] = serde_json::json!(0);
        let mut ck = Checkpoint::new(bad);
        m.add_to_checkpoint(&mut ck).unwrap();
        let err = format!("{:#}", NavModel::from_checkpoint(&ck).unwrap_err());
        assert!(err.contains("disc-steps"), "{err}");
    }
}
