//! The host parameter store: named f32 tensors with shapes.
//!
//! A [`ParamSet`] owns the trainable tensors of one or more networks (row-major `rows x cols`,
//! biases are `rows x 1`). Forward and backward passes never run here: the store only hands
//! out read-only [`Dense`] views and [`DenseGrads`](gman_core::nn::dense::DenseGrads) accumulators so that gman-core's kernels
//! compute on the same buffers the optimiser updates. A gradient buffer is simply another
//! `ParamSet` with the same names and shapes ([`ParamSet::zeros_like`]).
//!
//! Initialisation follows the reference implementation: weights `N(0, 0.02)`, biases 0, from
//! gman-core's seedable Gaussian noise ([`gman_core::rng`]).

use anyhow::{anyhow, bail, Result};
use gman_core::nn::dense::Dense;
use gman_core::nn::matrix::MatRef;
use gman_core::rng::{fill_gaussian, Xoshiro128};

/// Standard deviation of the reference's weight initialisation.
pub(crate) const INIT_STD: f32 = 0.02;

/// One named tensor.
#[derive(Clone, Debug, PartialEq)]
pub struct Param {
    /// Name, unique within its set (e.g. `GenW1`).
    pub name: String,
    /// Rows (outputs of a weight matrix; length of a bias).
    pub rows: usize,
    /// Columns (inputs of a weight matrix; 1 for a bias).
    pub cols: usize,
    /// Values, row-major, `rows * cols` of them.
    pub data: Vec<f32>,
}

impl Param {
    /// A tensor of zeros.
    pub fn zeros(name: &str, rows: usize, cols: usize) -> Param {
        Param {
            name: name.to_string(),
            rows,
            cols,
            data: vec![0.0; rows * cols],
        }
    }

    /// Number of values.
    pub fn len(&self) -> usize {
        self.data.len()
    }

    /// True when the tensor holds no value.
    pub fn is_empty(&self) -> bool {
        self.data.is_empty()
    }
}

/// How a tensor is initialised.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Init {
    /// Every value 0 (biases).
    Zeros,
    /// Every value equal to the constant.
    Const(f32),
    /// Independent `N(0, std^2)` values (weights; the reference uses std 0.02).
    Normal(f32),
}

/// An ordered set of named tensors.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct ParamSet {
    /// The tensors, in insertion order (which is also the checkpoint and optimiser order).
    pub tensors: Vec<Param>,
}

impl ParamSet {
    /// An empty set.
    pub fn new() -> ParamSet {
        ParamSet::default()
    }

    /// Every value's bits, tensor after tensor (for tests that compare gradients bit for bit).
    #[cfg(test)]
    pub(crate) fn bits(&self) -> Vec<u32> {
        self.tensors
            .iter()
            .flat_map(|t| t.data.iter().map(|v| v.to_bits()))
            .collect()
    }

    /// Adds a tensor initialised by `init` (drawing from `rng` for [`Init::Normal`]).
    /// Fails if the name is already used.
    pub fn add(
        &mut self,
        name: &str,
        rows: usize,
        cols: usize,
        init: Init,
        rng: &mut Xoshiro128,
    ) -> Result<()> {
        let mut p = Param::zeros(name, rows, cols);
        match init {
            Init::Zeros => {}
            Init::Const(v) => p.data.fill(v),
            Init::Normal(std) => {
                fill_gaussian(rng, &mut p.data);
                p.data.iter_mut().for_each(|v| *v *= std);
            }
        }
        self.push(p)
    }

    /// Adds an existing tensor; fails if the name is already used or the data length does
    /// not match the shape.
    pub fn push(&mut self, p: Param) -> Result<()> {
        if self.index_of(&p.name).is_some() {
            bail!("parameter {:?} defined twice", p.name);
        }
        if p.data.len() != p.rows * p.cols {
            bail!(
                "parameter {:?}: {} values for shape {}x{}",
                p.name,
                p.data.len(),
                p.rows,
                p.cols
            );
        }
        self.tensors.push(p);
        Ok(())
    }

    /// Position of a tensor by name.
    pub fn index_of(&self, name: &str) -> Option<usize> {
        self.tensors.iter().position(|p| p.name == name)
    }

    /// A tensor by name.
    pub fn get(&self, name: &str) -> Option<&Param> {
        self.tensors.iter().find(|p| p.name == name)
    }

    /// A tensor by name, mutable.
    pub fn get_mut(&mut self, name: &str) -> Option<&mut Param> {
        self.tensors.iter_mut().find(|p| p.name == name)
    }

    /// A tensor by name, or an error naming it.
    pub fn tensor(&self, name: &str) -> Result<&Param> {
        self.get(name)
            .ok_or_else(|| anyhow!("parameter {name:?} not found (have: {})", self.names()))
    }

    /// A tensor by name with a required shape, or an error naming it.
    pub(crate) fn tensor_shaped(&self, name: &str, rows: usize, cols: usize) -> Result<&Param> {
        let p = self.tensor(name)?;
        if p.rows != rows || p.cols != cols {
            bail!(
                "parameter {name:?} has shape {}x{}, expected {rows}x{cols}",
                p.rows,
                p.cols
            );
        }
        Ok(p)
    }

    /// The names, comma separated (for messages).
    pub fn names(&self) -> String {
        self.tensors
            .iter()
            .map(|p| p.name.as_str())
            .collect::<Vec<_>>()
            .join(", ")
    }

    /// Disjoint mutable slices of the named tensors, in the order of `names`.
    pub(crate) fn slices_mut<const N: usize>(
        &mut self,
        names: [&str; N],
    ) -> Result<[&mut [f32]; N]> {
        for (i, a) in names.iter().enumerate() {
            if names[..i].contains(a) {
                bail!("parameter {a:?} requested twice");
            }
        }
        let mut out: [Option<&mut [f32]>; N] = std::array::from_fn(|_| None);
        for p in self.tensors.iter_mut() {
            if let Some(k) = names.iter().position(|n| *n == p.name) {
                out[k] = Some(p.data.as_mut_slice());
            }
        }
        let mut missing = Vec::new();
        for (k, o) in out.iter().enumerate() {
            if o.is_none() {
                missing.push(names[k]);
            }
        }
        if !missing.is_empty() {
            bail!("parameters not found: {}", missing.join(", "));
        }
        Ok(out.map(|o| o.unwrap_or_default()))
    }

    /// A gradient twin: same names and shapes, all zeros.
    pub fn zeros_like(&self) -> ParamSet {
        ParamSet {
            tensors: self
                .tensors
                .iter()
                .map(|p| Param::zeros(&p.name, p.rows, p.cols))
                .collect(),
        }
    }

    /// Sets every value to 0.
    pub fn zero(&mut self) {
        for p in &mut self.tensors {
            p.data.fill(0.0);
        }
    }

    /// Checks that `other` has the same names and shapes in the same order.
    pub(crate) fn check_same_layout(&self, other: &ParamSet) -> Result<()> {
        if self.tensors.len() != other.tensors.len() {
            bail!(
                "parameter sets differ: [{}] vs [{}]",
                self.names(),
                other.names()
            );
        }
        for (a, b) in self.tensors.iter().zip(&other.tensors) {
            if a.name != b.name || a.rows != b.rows || a.cols != b.cols {
                bail!(
                    "parameter sets differ: {:?} {}x{} vs {:?} {}x{}",
                    a.name,
                    a.rows,
                    a.cols,
                    b.name,
                    b.rows,
                    b.cols
                );
            }
        }
        Ok(())
    }

    /// `self += other` (same layout required), element by element in a fixed order.
    pub fn add_assign(&mut self, other: &ParamSet) -> Result<()> {
        self.check_same_layout(other)?;
        for (a, b) in self.tensors.iter_mut().zip(&other.tensors) {
            a.data.iter_mut().zip(&b.data).for_each(|(x, y)| *x += y);
        }
        Ok(())
    }

    /// Multiplies every value by `s`.
    pub fn scale(&mut self, s: f32) {
        for p in &mut self.tensors {
            p.data.iter_mut().for_each(|v| *v *= s);
        }
    }

    /// Total number of values.
    pub(crate) fn num_values(&self) -> usize {
        self.tensors.iter().map(|p| p.data.len()).sum()
    }

    /// Euclidean norm over all values (accumulated in f64, fixed order).
    pub(crate) fn global_norm(&self) -> f64 {
        // The squares are >= +0, so once the running sum is positive an all-zero tensor
        // adds nothing, and before that a sum of zeros is a zero of the same sign either
        // way: skipping the all-zero tensors (those a method does not train) gives the bits
        // of the full sum in tensor order. Only a set of nothing but zeros takes the full
        // sum, for the sign of its zero.
        let nonzero = |p: &&Param| !all_zero(&p.data);
        if !self.tensors.iter().any(|p| nonzero(&p)) {
            return self
                .tensors
                .iter()
                .flat_map(|p| p.data.iter())
                .map(|&v| (v as f64) * (v as f64))
                .sum::<f64>()
                .sqrt();
        }
        // `±0 + q == q` for the first square `q >= +0`, whatever zero a sum starts from.
        let mut sum = 0.0f64;
        for p in self.tensors.iter().filter(nonzero) {
            for &v in &p.data {
                sum += (v as f64) * (v as f64);
            }
        }
        sum.sqrt()
    }

    /// True when every value is finite.
    pub fn all_finite(&self) -> bool {
        // Chunks of 64 without an early exit inside (vectorised), an exit between them.
        self.tensors.iter().all(|p| {
            p.data
                .chunks(64)
                .all(|c| c.iter().fold(true, |ok, v| ok & v.is_finite()))
        })
    }

    /// A gman-core dense layer (no gain) from a weight `w` (`out x in`) and a bias `b`
    /// (`out` values).
    pub fn dense(&self, w: &str, b: &str) -> Result<Dense<'_>> {
        let wp = self.tensor(w)?;
        let bp = self.tensor(b)?;
        if bp.data.len() != wp.rows {
            bail!(
                "bias {b:?} has {} values, weight {w:?} has {} rows",
                bp.data.len(),
                wp.rows
            );
        }
        let d = Dense {
            w: MatRef::f32(wp.rows, wp.cols, &wp.data)?,
            b: &bp.data,
            gain: None,
        };
        d.validate()?;
        Ok(d)
    }

    /// [`DenseGrads::Full`] accumulators over the gradient tensors named `w` and `b` of a
    /// gradient twin.
    #[cfg(test)]
    pub(crate) fn dense_grads(
        &mut self,
        w: &str,
        b: &str,
    ) -> Result<gman_core::nn::dense::DenseGrads<'_>> {
        let [w, b] = self.slices_mut([w, b])?;
        Ok(gman_core::nn::dense::DenseGrads::Full { w, b })
    }
}

/// True when every value is ±0 (vectorised: chunks without an early exit inside).
pub(crate) fn all_zero(v: &[f32]) -> bool {
    v.chunks(256)
        .all(|c| c.iter().fold(0u32, |a, x| a | (x.to_bits() << 1)) == 0)
}

/// True when every value is +0 bit for bit (as [`all_zero`]).
pub(crate) fn all_plus_zero(v: &[f32]) -> bool {
    v.chunks(256)
        .all(|c| c.iter().fold(0u32, |a, x| a | x.to_bits()) == 0)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The plain sum over every value in tensor order (what `global_norm` computed before
    /// it skipped the all-zero tensors).
    fn plain_norm(p: &ParamSet) -> f64 {
        p.tensors
            .iter()
            .flat_map(|t| t.data.iter())
            .map(|&v| (v as f64) * (v as f64))
            .sum::<f64>()
            .sqrt()
    }

    #[test]
    fn global_norm_skipping_zero_tensors_is_the_plain_sum() {
        let mut rng = Xoshiro128::seed_from_u64(4);
        let mut p = ParamSet::new();
        p.add("z0", 50, 1, Init::Zeros, &mut rng).unwrap();
        p.add("a", 300, 3, Init::Normal(0.3), &mut rng).unwrap();
        p.add("z1", 70, 2, Init::Zeros, &mut rng).unwrap();
        p.add("b", 9, 1, Init::Normal(1e-3), &mut rng).unwrap();
        p.tensors[2].data[5] = -0.0;
        assert_eq!(p.global_norm().to_bits(), plain_norm(&p).to_bits());
        assert!(p.global_norm() > 0.0);
        let z = p.zeros_like();
        assert_eq!(z.global_norm().to_bits(), plain_norm(&z).to_bits());
        let mut n = p.clone();
        n.tensors[1].data[7] = f32::NAN;
        assert!(n.global_norm().is_nan());
    }

    #[test]
    fn zero_scans() {
        let mut v = vec![0.0f32; 1000];
        assert!(all_zero(&v) && all_plus_zero(&v));
        v[700] = -0.0;
        assert!(all_zero(&v) && !all_plus_zero(&v));
        v[700] = f32::from_bits(1); // the smallest subnormal
        assert!(!all_zero(&v) && !all_plus_zero(&v));
        v[700] = f32::NAN;
        assert!(!all_zero(&v));
        assert!(all_zero(&[]) && all_plus_zero(&[]));
    }

    #[test]
    fn init_is_seeded_and_has_the_reference_scale() {
        let build = |seed| {
            let mut rng = Xoshiro128::seed_from_u64(seed);
            let mut p = ParamSet::new();
            p.add("W", 200, 100, Init::Normal(INIT_STD), &mut rng)
                .unwrap();
            p.add("b", 200, 1, Init::Zeros, &mut rng).unwrap();
            p
        };
        let a = build(1);
        assert_eq!(a, build(1));
        assert_ne!(a, build(2));
        let w = &a.tensor("W").unwrap().data;
        let mean = w.iter().map(|&v| v as f64).sum::<f64>() / w.len() as f64;
        let var = w.iter().map(|&v| (v as f64 - mean).powi(2)).sum::<f64>() / w.len() as f64;
        assert!(mean.abs() < 0.001, "mean {mean}");
        assert!((var.sqrt() - 0.02).abs() < 0.001, "std {}", var.sqrt());
        assert!(a.tensor("b").unwrap().data.iter().all(|&v| v == 0.0));
    }

    #[test]
    fn lookups_and_errors() {
        let mut rng = Xoshiro128::seed_from_u64(0);
        let mut p = ParamSet::new();
        p.add("W", 3, 2, Init::Const(1.0), &mut rng).unwrap();
        p.add("b", 3, 1, Init::Zeros, &mut rng).unwrap();
        assert!(p.add("W", 1, 1, Init::Zeros, &mut rng).is_err());
        assert!(p.tensor("nope").unwrap_err().to_string().contains("nope"));
        assert!(p.tensor_shaped("W", 2, 3).is_err());
        let d = p.dense("W", "b").unwrap();
        assert_eq!((d.out_dim(), d.in_dim()), (3, 2));
        assert!(p.dense("b", "W").is_err());
        let mut g = p.zeros_like();
        assert!(g.slices_mut(["W", "W"]).is_err());
        assert!(g.slices_mut(["W", "x"]).is_err());
        match g.dense_grads("W", "b").unwrap() {
            gman_core::nn::dense::DenseGrads::Full { w, b } => {
                assert_eq!((w.len(), b.len()), (6, 3))
            }
            _ => panic!("expected full grads"),
        }
        g.add_assign(&p).unwrap();
        assert_eq!(g.global_norm(), 6f64.sqrt());
    }
}
