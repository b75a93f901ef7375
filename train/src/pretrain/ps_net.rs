//! The PS network ("Predicts the Semantic embedding", paper Sec. 5.2) as the navigation model
//! uses it: its parameters, the forward pass, loading a `ps.ckpt`.
//!
//! ```text
//! PS(s) = σ( W2 · LeakyReLU_0.2( W1 s + b1 ) + b2 )      s: 512-d observation, out: 45
//! ```
//!
//! Both layers are gman-core [`Dense`] layers. Its pre-training (`gman pretrain-ps`, the BCE
//! gradient [`PsModule::backward_bce`]) is [`crate::pretrain::ps`].

use std::path::Path;

use anyhow::{bail, Context, Result};
use gman_core::nn::activation::{leaky_relu_inplace, sigmoid_inplace};
use gman_core::nn::dense::Dense;
use gman_core::rng::Xoshiro128;
use gman_core::{ATTR_DIM, FEATURE_DIM};

use crate::optim::checkpoint::Checkpoint;
use crate::optim::params::{Init, ParamSet, INIT_STD};

/// Name of the PS hidden weights, `hidden x 512`.
pub(crate) const PS_W1: &str = "PsW1";
/// Name of the PS hidden bias, `hidden`.
pub(crate) const PS_B1: &str = "PsB1";
/// Name of the PS output weights, `45 x hidden`.
pub(crate) const PS_W2: &str = "PsW2";
/// Name of the PS output bias, `45`.
pub(crate) const PS_B2: &str = "PsB2";

/// The PS network's parameters.
#[derive(Clone, Debug, PartialEq)]
pub struct PsModule {
    /// `PsW1`, `PsB1`, `PsW2`, `PsB2`.
    pub params: ParamSet,
    /// Hidden width.
    pub hidden: usize,
}

/// Activations and scratch of one PS sample.
#[derive(Clone, Debug)]
pub struct PsBuffers {
    /// Hidden activation after LeakyReLU.
    pub h: Vec<f32>,
    /// Output (after the sigmoid).
    pub y: Vec<f32>,
    pub(crate) dpre2: Vec<f32>,
    pub(crate) dh: Vec<f32>,
    pub(crate) dpre1: Vec<f32>,
}

impl PsBuffers {
    /// Buffers for hidden width `hidden`.
    pub fn new(hidden: usize) -> PsBuffers {
        PsBuffers {
            h: vec![0.0; hidden],
            y: vec![0.0; ATTR_DIM],
            dpre2: vec![0.0; ATTR_DIM],
            dh: vec![0.0; hidden],
            dpre1: vec![0.0; hidden],
        }
    }
}

impl PsModule {
    /// Fresh parameters (`N(0, 0.02)` weights, zero biases) with hidden width `hidden`.
    pub fn init(hidden: usize, rng: &mut Xoshiro128) -> Result<PsModule> {
        if hidden == 0 {
            bail!("PS hidden width must be at least 1");
        }
        let mut p = ParamSet::new();
        p.add(PS_W1, hidden, FEATURE_DIM, Init::Normal(INIT_STD), rng)?;
        p.add(PS_B1, hidden, 1, Init::Zeros, rng)?;
        p.add(PS_W2, ATTR_DIM, hidden, Init::Normal(INIT_STD), rng)?;
        p.add(PS_B2, ATTR_DIM, 1, Init::Zeros, rng)?;
        Ok(PsModule { params: p, hidden })
    }

    /// Wraps existing tensors, checking their shapes.
    pub(crate) fn from_params(params: ParamSet) -> Result<PsModule> {
        let hidden = params.tensor(PS_W1)?.rows;
        params.tensor_shaped(PS_W1, hidden, FEATURE_DIM)?;
        params.tensor_shaped(PS_B1, hidden, 1)?;
        params.tensor_shaped(PS_W2, ATTR_DIM, hidden)?;
        params.tensor_shaped(PS_B2, ATTR_DIM, 1)?;
        let params = ParamSet {
            tensors: [PS_W1, PS_B1, PS_W2, PS_B2]
                .iter()
                .map(|n| params.tensor(n).cloned())
                .collect::<Result<_>>()?,
        };
        Ok(PsModule { params, hidden })
    }

    /// Loads the tensors of a `ps.ckpt`.
    pub fn load(path: &Path) -> Result<PsModule> {
        let ck = Checkpoint::load(path)?;
        PsModule::from_params(ck.tensors.clone()).with_context(|| format!("{}", path.display()))
    }

    pub(crate) fn layers(&self) -> Result<(Dense<'_>, Dense<'_>)> {
        Ok((
            self.params.dense(PS_W1, PS_B1)?,
            self.params.dense(PS_W2, PS_B2)?,
        ))
    }

    /// Forward pass into `buf` (gman-core's dense kernels and activations).
    pub fn forward_buf(&self, obs: &[f32], buf: &mut PsBuffers) -> Result<()> {
        let (l1, l2) = self.layers()?;
        if obs.len() != FEATURE_DIM {
            bail!("PS input has {} values, expected {FEATURE_DIM}", obs.len());
        }
        l1.forward(&[obs], &mut [], &mut buf.h)?;
        leaky_relu_inplace(&mut buf.h);
        l2.forward(&[&buf.h], &mut [], &mut buf.y)?;
        sigmoid_inplace(&mut buf.y);
        Ok(())
    }

    /// The predicted semantic embedding of the objects in view of the observation `obs`
    /// (512 values); fails on a wrong input length.
    pub fn forward(&self, obs: &[f32], out: &mut [f32; ATTR_DIM]) -> Result<()> {
        let mut buf = PsBuffers::new(self.hidden);
        self.forward_buf(obs, &mut buf)?;
        out.copy_from_slice(&buf.y);
        Ok(())
    }
}
