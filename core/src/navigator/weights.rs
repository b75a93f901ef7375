//! The weights a navigator reads ([`NavWeights`]) and the layer views over them and over the
//! arena's adapted copies and gradients.

use core::ops::Deref;

use crate::blob::Blob;
use crate::error::{Error, Result};
use crate::nets::discriminator::Discriminator;
use crate::nets::generator::Generator;
use crate::nets::policy::Policy;
use crate::nn::activation::all_finite;
use crate::nn::dense::{Dense, DenseGrads};
use crate::nn::lstm::Lstm;
use crate::nn::matrix::MatRef;
use crate::spec::preset::Dims;
use crate::spec::schema::{TensorId, NUM_TENSORS};

/// Read-only views of every tensor the navigator needs (from a blob, or from a trainer's
/// f32 buffers), indexed by [`TensorId`].
#[derive(Clone, Copy, Debug)]
pub struct NavWeights<'w> {
    pub(super) dims: Dims,
    pub(super) t: [MatRef<'w>; NUM_TENSORS],
}

impl<'w> NavWeights<'w> {
    /// Views into a parsed blob (no copy); checks the blob's dims against `dims`. A blob with
    /// [`crate::spec::schema::FLAG_INT8_ACTIVATIONS`] gets int8 activations on its int8 views
    /// ([`NavWeights::with_int8_activations`]).
    pub fn from_blob(blob: &Blob<'w>, dims: &Dims) -> Result<Self> {
        blob.check_dims(dims)?;
        let mut t = [empty(); NUM_TENSORS];
        for id in TensorId::all_for(dims) {
            t[id as usize] = blob.matrix(id)?;
        }
        let w = NavWeights { dims: *dims, t };
        if blob.header().flags() & crate::spec::schema::FLAG_INT8_ACTIVATIONS != 0 {
            if !cfg!(feature = "int8-activations") {
                return Err(Error::Config {
                    what: "the blob needs int8 activations: build gman-core with the \
                           `int8-activations` feature",
                });
            }
            return Ok(w.with_int8_activations());
        }
        if !crate::nn::qkernel::F32_ACTIVATIONS && w.t.iter().any(MatRef::is_int8) {
            return Err(crate::nn::qkernel::NO_F32_ACTIVATIONS);
        }
        Ok(w)
    }

    /// The same views with int8 activations on every int8 weight matrix
    /// ([`MatRef::with_int8_activations`]; f32 views are unchanged).
    pub fn with_int8_activations(mut self) -> Self {
        for m in self.t.iter_mut() {
            *m = m.with_int8_activations();
        }
        self
    }

    /// Views built by `f` for each tensor of `dims` ([`TensorId::all_for`]; a trainer passes
    /// `MatRef::f32` over its buffers); shapes are checked against `dims`.
    pub fn from_fn(dims: &Dims, mut f: impl FnMut(TensorId) -> MatRef<'w>) -> Result<Self> {
        let mut t = [empty(); NUM_TENSORS];
        for id in TensorId::all_for(dims) {
            let m = f(id);
            let (r, c) = id.shape(dims);
            if m.rows() != r || m.cols() != c {
                return Err(Error::Blob(crate::BlobError::BadTensorShape {
                    id: id as u16,
                }));
            }
            t[id as usize] = m;
        }
        Ok(NavWeights { dims: *dims, t })
    }

    /// The same views running their kernels through `k` (see [`crate::nn::batch::Kernels`]; a
    /// host's wider-SIMD build of the same kernels). Every result keeps its bits; the f32
    /// copies the navigator adapts in RAM inherit `k` from the view they stand in for.
    pub fn with_kernels(mut self, k: &'static dyn crate::nn::batch::Kernels) -> Self {
        for m in self.t.iter_mut() {
            *m = m.with_kernels(k);
        }
        self
    }

    /// The dims.
    pub fn dims(&self) -> &Dims {
        &self.dims
    }

    /// The view of tensor `id`.
    pub fn get(&self, id: TensorId) -> MatRef<'w> {
        self.t[id as usize]
    }
}

pub(super) fn empty() -> MatRef<'static> {
    match MatRef::f32(0, 0, &[]) {
        Ok(m) => m,
        Err(_) => empty(),
    }
}

/// Copies a (possibly int8 or LE-bytes) matrix into f32 RAM.
pub(super) fn copy_mat(m: &MatRef<'_>, out: &mut [f32]) -> Result<()> {
    m.copy_to(out)
}

pub(super) const ARENA_TOO_SMALL: Error = Error::Config {
    what: "arena too small for these dims, mode and k (see memory::arena_len)",
};

/// An adapted (or RAM-resident) dense layer: `w` is empty when the base weights are read
/// from the blob; `gain` is empty in `Full` mode.
#[derive(Default)]
pub(super) struct LayerRam<T> {
    pub(super) w: T,
    pub(super) gain: T,
    pub(super) b: T,
}

impl<T: Deref<Target = [f32]>> LayerRam<T> {
    pub(super) fn view<'s>(&'s self, base: MatRef<'s>) -> Result<Dense<'s>> {
        dense_over([&self.w, &self.gain, &self.b], base)
    }
}

/// [`LayerRam::view`] of a read-only layer, for as long as its slices live.
pub(super) fn layer_view<'s>(l: LayerRam<&'s [f32]>, base: MatRef<'s>) -> Result<Dense<'s>> {
    dense_over([l.w, l.gain, l.b], base)
}

/// The layer over RAM weights `w` (empty: the blob's `base`), gains (empty: none) and `b`.
pub(super) fn dense_over<'s>([w, gain, b]: [&'s [f32]; 3], base: MatRef<'s>) -> Result<Dense<'s>> {
    let w = if w.is_empty() {
        base
    } else {
        MatRef::f32(base.rows(), base.cols(), w)?.kernels_from(&base)
    };
    Ok(Dense {
        w,
        b,
        gain: if gain.is_empty() { None } else { Some(gain) },
    })
}

impl LayerRam<&mut [f32]> {
    /// Restores the meta-learned values: `w` from the blob (Full) or gain 1 (Efficient).
    pub(super) fn restore(&mut self, w: &MatRef<'_>, b: &MatRef<'_>) -> Result<()> {
        if !self.w.is_empty() {
            copy_mat(w, self.w)?;
        }
        self.gain.fill(1.0);
        copy_mat(b, self.b)
    }
}

/// Gradient buffers matching a [`LayerRam`] (`a` is dW in Full, dgain in Efficient).
#[derive(Default)]
pub(super) struct LayerGrad<T> {
    pub(super) a: T,
    pub(super) b: T,
    pub(super) full: bool,
}

impl LayerGrad<&mut [f32]> {
    pub(super) fn grads(&mut self) -> DenseGrads<'_> {
        if self.full {
            DenseGrads::Full {
                w: self.a,
                b: self.b,
            }
        } else {
            DenseGrads::Gain {
                gain: self.a,
                b: self.b,
            }
        }
    }
    pub(super) fn zero(&mut self) {
        self.a.fill(0.0);
        self.b.fill(0.0);
    }
    pub(super) fn scale(&mut self, s: f32) {
        self.a
            .iter_mut()
            .chain(self.b.iter_mut())
            .for_each(|v| *v *= s);
    }
    pub(super) fn finite(&self) -> bool {
        all_finite(self.a) && all_finite(self.b)
    }
    pub(super) fn sum_sq(&self) -> f32 {
        self.a.iter().chain(self.b.iter()).map(|v| v * v).sum()
    }
    /// True if `p + step * g` stays finite everywhere.
    pub(super) fn update_ok(&self, p: &LayerRam<&mut [f32]>, step: f32) -> bool {
        let target = if self.full { &*p.w } else { &*p.gain };
        ok_update(target, self.a, step) && ok_update(p.b, self.b, step)
    }
    pub(super) fn apply(&self, p: &mut LayerRam<&mut [f32]>, step: f32) {
        let target = if self.full { &mut *p.w } else { &mut *p.gain };
        axpy_inplace(target, self.a, step);
        axpy_inplace(p.b, self.b, step);
    }
}

/// The view of G over its RAM layers (`gen1`, `gen2`) and the blob's base weights.
pub(super) fn gen_view<'s, T: Deref<Target = [f32]>>(
    gen1: &'s LayerRam<T>,
    gen2: &'s LayerRam<T>,
    w: &NavWeights<'s>,
) -> Result<Generator<'s>> {
    Ok(Generator {
        l1: gen1.view(w.get(TensorId::GenW1))?,
        l2: gen2.view(w.get(TensorId::GenW2))?,
    })
}

/// Whether two matrix views read the same stored values (the same slices).
pub(super) fn same_storage(a: &MatRef<'_>, b: &MatRef<'_>) -> bool {
    use crate::nn::matrix::{Scales, Weights};
    let sc = |s: Scales<'_>| match s {
        Scales::F32(v) => (v.as_ptr() as usize, v.len()),
        Scales::Le(v) => (v.as_ptr() as usize, v.len()),
    };
    match (a.weights(), b.weights()) {
        (Weights::F32(x), Weights::F32(y)) => x.as_ptr() == y.as_ptr() && x.len() == y.len(),
        (Weights::F32Le(x), Weights::F32Le(y)) => x.as_ptr() == y.as_ptr() && x.len() == y.len(),
        (Weights::I8 { q: x, scales: s }, Weights::I8 { q: y, scales: t }) => {
            x.as_ptr() == y.as_ptr() && x.len() == y.len() && sc(s) == sc(t)
        }
        _ => false,
    }
}

/// The view of D over its RAM parameters and the blob's base weights.
pub(super) fn disc_view<'s, T: Deref<Target = [f32]>>(
    disc1: &'s LayerRam<T>,
    w2: &'s [f32],
    b2: &[f32],
    w: &NavWeights<'s>,
) -> Result<Discriminator<'s>> {
    Ok(Discriminator {
        l1: disc1.view(w.get(TensorId::DiscW1))?,
        w2,
        b2: b2.first().copied().unwrap_or(0.0),
    })
}

/// The policy's layers: the trunk's weights from `w` (never adapted), its biases
/// `[fuse, lstm, critic, cell]` and the actor head (adapted) from the navigator's RAM.
pub(super) fn policy_view<'s>(
    w: &'s NavWeights<'_>,
    [fuse_b, lstm_b, critic_b, cell_b]: [&'s [f32]; 4],
    actor: Dense<'s>,
) -> Result<Policy<'s>> {
    let dense = |id, b| Dense {
        w: w.get(id),
        b,
        gain: None,
    };
    Ok(Policy {
        fuse: dense(TensorId::FuseW, fuse_b),
        lstm: Lstm {
            wx: w.get(TensorId::LstmWx),
            wh: w.get(TensorId::LstmWh),
            b: lstm_b,
        },
        actor,
        critic: dense(TensorId::CriticW, critic_b),
        cell: (w.dims.map_cells() > 0).then(|| dense(TensorId::CellW, cell_b)),
    })
}

pub(super) fn ok_update(p: &[f32], g: &[f32], step: f32) -> bool {
    p.iter().zip(g).all(|(a, b)| (a + step * b).is_finite())
}

pub(super) fn axpy_inplace(p: &mut [f32], g: &[f32], step: f32) {
    for (a, b) in p.iter_mut().zip(g) {
        *a += step * b;
    }
}
