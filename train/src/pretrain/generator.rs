//! Host-side helpers around gman-core's feature generator G(SE(y), z): parameter creation
//! with the blob tensor names, a view builder and owned forward/backward buffers.

use anyhow::Result;
use gman_core::blob::TensorId;
use gman_core::nets::generator::{Generator, GeneratorCache, GeneratorScratch};
use gman_core::rng::Xoshiro128;
use gman_core::Dims;

use super::params::{Init, ParamSet, INIT_STD};

/// The names of G's tensors, exactly gman-core's blob tensor ids:
/// `[GenW1, GenB1, GenW2, GenB2]`.
pub(crate) fn gen_names() -> [&'static str; 4] {
    TensorId::GENERATOR.map(TensorId::name)
}

/// Fresh parameters of G for `dims`: `GenW1` is `gen_hidden x (noise + attr)` (noise
/// columns first), `GenW2` is `feat x gen_hidden`, biases are `n x 1`; weights `N(0, 0.02)`,
/// biases 0, no gains.
pub fn init_generator(dims: &Dims, rng: &mut Xoshiro128) -> Result<ParamSet> {
    let mut p = ParamSet::new();
    for id in TensorId::GENERATOR {
        let (r, c) = id.shape(dims);
        let init = if id.is_vector() {
            Init::Zeros
        } else {
            Init::Normal(INIT_STD)
        };
        p.add(id.name(), r, c, init, rng)?;
    }
    Ok(p)
}

/// A gman-core [`Generator`] view over G's tensors in `p`.
pub fn generator_view(p: &ParamSet) -> Result<Generator<'_>> {
    let [w1, b1, w2, b2] = gen_names();
    let g = Generator {
        l1: p.dense(w1, b1)?,
        l2: p.dense(w2, b2)?,
    };
    g.validate()?;
    Ok(g)
}

/// Owned activation and scratch buffers for one sample's forward and backward pass of G.
#[derive(Clone, Debug)]
pub(crate) struct GenBuffers {
    /// Hidden activation (`H`).
    pub h1: Vec<f32>,
    /// Generated feature (`F`), valid after [`GenBuffers::forward`].
    pub x: Vec<f32>,
    dpre2: Vec<f32>,
    dh1: Vec<f32>,
    dpre1: Vec<f32>,
    tmp: Vec<f32>,
}

impl GenBuffers {
    /// Buffers for hidden width `h` and feature width `f`.
    pub fn new(h: usize, f: usize) -> GenBuffers {
        GenBuffers {
            h1: vec![0.0; h],
            x: vec![0.0; f],
            dpre2: vec![0.0; f],
            dh1: vec![0.0; h],
            dpre1: vec![0.0; h],
            tmp: vec![0.0; h.max(f)],
        }
    }

    /// gman-core's activation cache and backward scratch of G over these buffers.
    pub fn views(&mut self) -> (GeneratorCache<'_>, GeneratorScratch<'_>) {
        let cache = GeneratorCache {
            u1: &mut [],
            h1: &mut self.h1,
            u2: &mut [],
            x: &mut self.x,
        };
        let scratch = GeneratorScratch {
            dpre2: &mut self.dpre2,
            dh1: &mut self.dh1,
            dpre1: &mut self.dpre1,
            tmp: &mut self.tmp,
        };
        (cache, scratch)
    }

    /// `x = G(attr, z)` into `self.x` (gman-core's forward).
    pub fn forward(&mut self, g: &Generator<'_>, z: &[f32], attr: &[f32]) -> Result<()> {
        g.forward(z, attr, &mut self.views().0)?;
        Ok(())
    }

    /// Accumulates `∂L/∂θ` into the gradient twin `grads` from `dx = ∂L/∂x`, for the
    /// `(z, attr)` of the last [`GenBuffers::forward`] (gman-core's backward).
    pub fn backward(
        &mut self,
        g: &Generator<'_>,
        z: &[f32],
        attr: &[f32],
        dx: &[f32],
        grads: &mut ParamSet,
    ) -> Result<()> {
        let [w1, b1, w2, b2] = gen_names();
        let [gw1, gb1, gw2, gb2] = grads.slices_mut([w1, b1, w2, b2])?;
        let (cache, mut s) = self.views();
        g.backward(
            z,
            attr,
            &cache,
            dx,
            &mut gman_core::nn::dense::DenseGrads::Full { w: gw1, b: gb1 },
            &mut gman_core::nn::dense::DenseGrads::Full { w: gw2, b: gb2 },
            &mut s,
        )?;
        Ok(())
    }
}
