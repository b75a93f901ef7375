//! Adam (Kingma & Ba) with the AMSGrad option over a [`ParamSet`], with optional global
//! gradient-norm clipping and a byte encoding of its state for checkpoints.
//!
//! The update follows PyTorch's `torch.optim.Adam` (the reference implementation uses it with
//! `amsgrad=True`):
//!
//! ```text
//! m ← β1 m + (1 − β1) g            v ← β2 v + (1 − β2) g²
//! v̂ ← max(v̂, v) (AMSGrad) or v     θ ← θ − lr / (1 − β1^t) · m / (sqrt(v̂) / sqrt(1 − β2^t) + ε)
//! ```
//!
//! With clipping, `g` is first scaled by `max_norm / (‖g‖ + 1e-6)` when `‖g‖ > max_norm`
//! (PyTorch's `clip_grad_norm_`), `‖g‖` the norm over every tensor of the set.

use anyhow::{bail, Context, Result};

use super::params::{all_plus_zero, all_zero, ParamSet};

/// Hyper-parameters of [`Adam`].
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct AdamConfig {
    /// Learning rate.
    pub lr: f32,
    /// Decay of the first moment.
    pub beta1: f32,
    /// Decay of the second moment.
    pub beta2: f32,
    /// Denominator guard.
    pub eps: f32,
    /// Keep the running maximum of the second moment (AMSGrad).
    pub amsgrad: bool,
    /// Clip the global gradient norm to this value before the update.
    pub clip_norm: Option<f32>,
}

impl AdamConfig {
    /// Checks the hyper-parameters as the command line does: a finite positive learning rate,
    /// betas in [0, 1), a finite positive eps and clip norm.
    pub fn validate(&self) -> Result<()> {
        if !(self.lr.is_finite() && self.lr > 0.0) {
            bail!("Adam lr {} must be finite and positive", self.lr);
        }
        for (name, b) in [("beta1", self.beta1), ("beta2", self.beta2)] {
            if !(0.0..1.0).contains(&b) {
                bail!("Adam {name} {b} must be in [0, 1)");
            }
        }
        if !(self.eps.is_finite() && self.eps > 0.0) {
            bail!("Adam eps {} must be finite and positive", self.eps);
        }
        if let Some(c) = self.clip_norm {
            if !(c.is_finite() && c > 0.0) {
                bail!("Adam clip norm {c} must be finite and positive");
            }
        }
        Ok(())
    }
}

impl Default for AdamConfig {
    /// The reference's outer optimiser: lr 1e-4, betas (0.9, 0.999), eps 1e-8, AMSGrad.
    fn default() -> Self {
        AdamConfig {
            lr: 1e-4,
            beta1: 0.9,
            beta2: 0.999,
            eps: 1e-8,
            amsgrad: true,
            clip_norm: None,
        }
    }
}

/// What one [`Adam::step`] did.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct StepInfo {
    /// Global gradient norm before clipping.
    pub grad_norm: f64,
    /// True when the gradient was scaled down.
    pub clipped: bool,
}

/// Adam state for one [`ParamSet`] layout.
#[derive(Clone, Debug, PartialEq)]
pub struct Adam {
    /// Hyper-parameters (the learning rate may be changed between steps).
    pub cfg: AdamConfig,
    /// Number of updates done.
    pub t: u64,
    layout: Vec<(String, usize)>,
    m: Vec<Vec<f32>>,
    v: Vec<Vec<f32>>,
    vmax: Vec<Vec<f32>>,
}

const STATE_MAGIC: &[u8; 4] = b"ADAM";
const STATE_VERSION: u32 = 1;

impl Adam {
    /// Fresh state (zero moments) for the tensors of `params`.
    pub fn new(cfg: AdamConfig, params: &ParamSet) -> Adam {
        let layout: Vec<(String, usize)> = params
            .tensors
            .iter()
            .map(|p| (p.name.clone(), p.data.len()))
            .collect();
        let zeros = || layout.iter().map(|(_, n)| vec![0.0; *n]).collect();
        Adam {
            cfg,
            t: 0,
            m: zeros(),
            v: zeros(),
            vmax: if cfg.amsgrad { zeros() } else { Vec::new() },
            layout,
        }
    }

    fn check_layout(&self, set: &ParamSet, what: &str) -> Result<()> {
        let ok = set.tensors.len() == self.layout.len()
            && set
                .tensors
                .iter()
                .zip(&self.layout)
                .all(|(p, (n, l))| &p.name == n && p.data.len() == *l);
        if !ok {
            bail!(
                "Adam state was made for [{}], {what} has [{}]",
                self.layout
                    .iter()
                    .map(|(n, l)| format!("{n}:{l}"))
                    .collect::<Vec<_>>()
                    .join(", "),
                set.tensors
                    .iter()
                    .map(|p| format!("{}:{}", p.name, p.data.len()))
                    .collect::<Vec<_>>()
                    .join(", ")
            );
        }
        Ok(())
    }

    /// One update of `params` (descending `grads`). Fails, leaving everything unchanged, if
    /// the layouts differ or a gradient is not finite.
    pub fn step(&mut self, params: &mut ParamSet, grads: &ParamSet) -> Result<StepInfo> {
        self.check_layout(params, "the parameter set")?;
        self.check_layout(grads, "the gradient set")?;
        if !grads.all_finite() {
            bail!("non-finite gradient; update skipped");
        }
        let grad_norm = grads.global_norm();
        let (scale, clipped) = match self.cfg.clip_norm {
            Some(max) if grad_norm > max as f64 => ((max as f64 / (grad_norm + 1e-6)) as f32, true),
            _ => (1.0, false),
        };
        self.t = self.t.checked_add(1).ok_or_else(|| {
            anyhow::anyhow!(
                "Adam's step count t = {} cannot grow further (u64::MAX); the optimiser state is corrupt",
                self.t
            )
        })?;
        let c = self.cfg;
        let bc1 = 1.0 - (c.beta1 as f64).powi(self.t.min(i32::MAX as u64) as i32);
        let bc2 = 1.0 - (c.beta2 as f64).powi(self.t.min(i32::MAX as u64) as i32);
        let step_size = (c.lr as f64 / bc1) as f32;
        let bc2_sqrt = bc2.sqrt() as f32;
        let (b1, b2, eps) = (c.beta1, c.beta2, c.eps);
        for (k, (p, g)) in params.tensors.iter_mut().zip(&grads.tensors).enumerate() {
            let (m, v) = (&mut self.m[k][..], &mut self.v[k][..]);
            // A tensor with a zero gradient and both moments exactly +0 (one the method does
            // not train, e.g. G and D of the A3C baselines) is left as it is: the update
            // below would write m = v = +0 again and subtract +0 from every parameter, the
            // same bits.
            if all_zero(&g.data) && all_plus_zero(m) && all_plus_zero(v) {
                continue;
            }
            // Element-wise, the operations of the formula in the module docs in that order
            // (written over zipped slices so that the compiler vectorises it; every lane does
            // what the scalar loop did).
            let (pd, gd) = (&mut p.data[..], &g.data[..]);
            if c.amsgrad {
                let vmax = &mut self.vmax[k][..];
                for ((((p, &g), m), v), vm) in pd.iter_mut().zip(gd).zip(m).zip(v).zip(vmax) {
                    let gi = g * scale;
                    *m = b1 * *m + (1.0 - b1) * gi;
                    *v = b2 * *v + (1.0 - b2) * gi * gi;
                    *vm = if *v > *vm { *v } else { *vm };
                    let denom = vm.sqrt() / bc2_sqrt + eps;
                    *p -= step_size * *m / denom;
                }
            } else {
                for (((p, &g), m), v) in pd.iter_mut().zip(gd).zip(m).zip(v) {
                    let gi = g * scale;
                    *m = b1 * *m + (1.0 - b1) * gi;
                    *v = b2 * *v + (1.0 - b2) * gi * gi;
                    let denom = v.sqrt() / bc2_sqrt + eps;
                    *p -= step_size * *m / denom;
                }
            }
        }
        Ok(StepInfo { grad_norm, clipped })
    }

    /// The state as bytes (for a checkpoint blob): step count, configuration and moments.
    pub fn to_bytes(&self) -> Vec<u8> {
        let mut out = Vec::new();
        out.extend_from_slice(STATE_MAGIC);
        out.extend_from_slice(&STATE_VERSION.to_le_bytes());
        out.extend_from_slice(&self.t.to_le_bytes());
        let c = self.cfg;
        for v in [c.lr, c.beta1, c.beta2, c.eps] {
            out.extend_from_slice(&v.to_le_bytes());
        }
        out.push(c.amsgrad as u8);
        match c.clip_norm {
            Some(v) => {
                out.push(1);
                out.extend_from_slice(&v.to_le_bytes());
            }
            None => {
                out.push(0);
                out.extend_from_slice(&0f32.to_le_bytes());
            }
        }
        out.extend_from_slice(&(self.layout.len() as u32).to_le_bytes());
        for (k, (name, len)) in self.layout.iter().enumerate() {
            out.extend_from_slice(&(name.len() as u32).to_le_bytes());
            out.extend_from_slice(name.as_bytes());
            out.extend_from_slice(&(*len as u64).to_le_bytes());
            let mut vecs = vec![&self.m[k], &self.v[k]];
            if c.amsgrad {
                vecs.push(&self.vmax[k]);
            }
            for vec in vecs {
                for x in vec.iter() {
                    out.extend_from_slice(&x.to_le_bytes());
                }
            }
        }
        out
    }

    /// Restores a state written by [`Adam::to_bytes`] for the tensors of `params`; fails
    /// with a clear message on malformed bytes or a different parameter layout.
    pub fn from_bytes(bytes: &[u8], params: &ParamSet) -> Result<Adam> {
        let mut r = Reader { b: bytes, pos: 0 };
        if r.take(4)? != STATE_MAGIC {
            bail!("not an Adam state (bad magic)");
        }
        let ver = r.u32()?;
        if ver != STATE_VERSION {
            bail!("Adam state version {ver}, this build reads {STATE_VERSION}");
        }
        let t = r.u64()?;
        let lr = r.f32()?;
        let beta1 = r.f32()?;
        let beta2 = r.f32()?;
        let eps = r.f32()?;
        let amsgrad = r.u8()? != 0;
        let has_clip = r.u8()? != 0;
        let clip = r.f32()?;
        let cfg = AdamConfig {
            lr,
            beta1,
            beta2,
            eps,
            amsgrad,
            clip_norm: has_clip.then_some(clip),
        };
        cfg.validate().context("Adam state")?;
        let mut adam = Adam::new(cfg, params);
        adam.t = t;
        let n = r.u32()? as usize;
        if n != adam.layout.len() {
            bail!(
                "Adam state has {n} tensors, the parameter set {}",
                adam.layout.len()
            );
        }
        for k in 0..n {
            let nl = r.u32()? as usize;
            let name = std::str::from_utf8(r.take(nl)?)
                .context("Adam state: tensor name is not UTF-8")?
                .to_string();
            let len = r.u64()? as usize;
            let (want, wl) = &adam.layout[k];
            if &name != want || len != *wl {
                bail!("Adam state tensor {k} is {name:?} ({len} values), the parameter set has {want:?} ({wl} values)");
            }
            let mut read_vec = |dst: &mut Vec<f32>| -> Result<()> {
                for x in dst.iter_mut() {
                    *x = r.f32()?;
                }
                Ok(())
            };
            read_vec(&mut adam.m[k])?;
            read_vec(&mut adam.v[k])?;
            if amsgrad {
                read_vec(&mut adam.vmax[k])?;
            }
        }
        if r.pos != bytes.len() {
            bail!("Adam state has {} trailing bytes", bytes.len() - r.pos);
        }
        for (k, (name, _)) in adam.layout.iter().enumerate() {
            let bad_m = adam.m[k].iter().any(|x| !x.is_finite());
            let bad_v = adam.v[k]
                .iter()
                .chain(adam.vmax.get(k).into_iter().flatten())
                .any(|x| !(x.is_finite() && *x >= 0.0));
            if bad_m || bad_v {
                bail!(
                    "Adam state of tensor {name:?} holds non-finite (or negative second) moments"
                );
            }
        }
        Ok(adam)
    }
}

/// Little-endian reader with truncation errors.
struct Reader<'a> {
    b: &'a [u8],
    pos: usize,
}

impl<'a> Reader<'a> {
    fn take(&mut self, n: usize) -> Result<&'a [u8]> {
        match self.b.get(self.pos..self.pos.saturating_add(n)) {
            Some(s) => {
                self.pos += n;
                Ok(s)
            }
            None => bail!(
                "Adam state truncated at byte {} (needed {n} more)",
                self.pos
            ),
        }
    }
    fn u8(&mut self) -> Result<u8> {
        Ok(self.take(1)?[0])
    }
    fn u32(&mut self) -> Result<u32> {
        let s = self.take(4)?;
        Ok(u32::from_le_bytes([s[0], s[1], s[2], s[3]]))
    }
    fn u64(&mut self) -> Result<u64> {
        let s = self.take(8)?;
        let mut a = [0u8; 8];
        a.copy_from_slice(s);
        Ok(u64::from_le_bytes(a))
    }
    fn f32(&mut self) -> Result<f32> {
        Ok(f32::from_bits(self.u32()?))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::optim::params::Param;

    fn set(vals: &[f32]) -> ParamSet {
        let mut p = ParamSet::new();
        p.push(Param {
            name: "w".into(),
            rows: vals.len(),
            cols: 1,
            data: vals.to_vec(),
        })
        .unwrap();
        p
    }

    /// The update as it was written before it skipped tensors and was vectorised: one
    /// element at a time.
    fn reference_step(a: &mut Adam, p: &mut ParamSet, g: &ParamSet) {
        let grad_norm = g.global_norm();
        let scale = match a.cfg.clip_norm {
            Some(max) if grad_norm > max as f64 => (max as f64 / (grad_norm + 1e-6)) as f32,
            _ => 1.0,
        };
        a.t += 1;
        let c = a.cfg;
        let bc1 = 1.0 - (c.beta1 as f64).powi(a.t as i32);
        let bc2 = 1.0 - (c.beta2 as f64).powi(a.t as i32);
        let step_size = (c.lr as f64 / bc1) as f32;
        let bc2_sqrt = bc2.sqrt() as f32;
        for (k, (p, g)) in p.tensors.iter_mut().zip(&g.tensors).enumerate() {
            for i in 0..p.data.len() {
                let gi = g.data[i] * scale;
                a.m[k][i] = c.beta1 * a.m[k][i] + (1.0 - c.beta1) * gi;
                a.v[k][i] = c.beta2 * a.v[k][i] + (1.0 - c.beta2) * gi * gi;
                let vh = if c.amsgrad {
                    let vm = &mut a.vmax[k][i];
                    if a.v[k][i] > *vm {
                        *vm = a.v[k][i];
                    }
                    *vm
                } else {
                    a.v[k][i]
                };
                let denom = vh.sqrt() / bc2_sqrt + c.eps;
                p.data[i] -= step_size * a.m[k][i] / denom;
            }
        }
    }

    /// Tensors with zero gradients (+0 and −0, before and after others moved), skipped or
    /// not, AMSGrad or not, clipped or not: the bits of the element-wise reference.
    #[test]
    fn skipping_and_vectorising_keep_the_reference_bits() {
        let mut rng = gman_core::rng::Xoshiro128::seed_from_u64(9);
        let mut params = ParamSet::new();
        for (name, n) in [("a", 37), ("frozen", 300), ("b", 1000), ("late", 64)] {
            params
                .add(
                    name,
                    n,
                    1,
                    super::super::params::Init::Normal(0.5),
                    &mut rng,
                )
                .unwrap();
        }
        params.tensors[1].data[3] = -0.0;
        for amsgrad in [true, false] {
            for clip_norm in [None, Some(0.05)] {
                let cfg = AdamConfig {
                    lr: 1e-2,
                    amsgrad,
                    clip_norm,
                    ..AdamConfig::default()
                };
                let (mut p1, mut p2) = (params.clone(), params.clone());
                let (mut a1, mut a2) = (Adam::new(cfg, &p1), Adam::new(cfg, &p2));
                for step in 0..6 {
                    let mut g = params.zeros_like();
                    for (k, t) in g.tensors.iter_mut().enumerate() {
                        let live = match k {
                            1 => false,
                            3 => (2..4).contains(&step),
                            _ => true,
                        };
                        for (i, v) in t.data.iter_mut().enumerate() {
                            *v = if live {
                                ((i * 7 + step * 3) % 11) as f32 * 0.01 - 0.05
                            } else if i % 2 == 0 {
                                -0.0
                            } else {
                                0.0
                            };
                        }
                    }
                    let info = a1.step(&mut p1, &g).unwrap();
                    reference_step(&mut a2, &mut p2, &g);
                    assert_eq!(info.grad_norm.to_bits(), g.global_norm().to_bits());
                    let bits = |p: &ParamSet| -> Vec<u32> {
                        p.tensors
                            .iter()
                            .flat_map(|t| t.data.iter().map(|v| v.to_bits()))
                            .collect()
                    };
                    assert_eq!(bits(&p1), bits(&p2), "step {step} amsgrad {amsgrad}");
                    assert_eq!(a1, a2, "state, step {step}");
                }
            }
        }
    }

    /// Two steps computed by hand (f64) against the implementation.
    #[test]
    fn matches_hand_computed_steps() {
        for amsgrad in [false, true] {
            let cfg = AdamConfig {
                lr: 0.1,
                beta1: 0.9,
                beta2: 0.999,
                eps: 1e-8,
                amsgrad,
                clip_norm: None,
            };
            let mut p = set(&[1.0, -2.0]);
            let mut adam = Adam::new(cfg, &p);
            // Step 1, g = (0.5, -1): m = 0.1 g, v = 0.001 g², m̂ = g, v̂ = g², update = lr·sign(g).
            adam.step(&mut p, &set(&[0.5, -1.0])).unwrap();
            let e1 = [1.0 - 0.1, -2.0 + 0.1];
            for (a, e) in p.tensors[0].data.iter().zip(e1) {
                assert!((*a as f64 - e).abs() < 1e-6, "{a} vs {e}");
            }
            // Step 2, g = (0.1, 2.0).
            adam.step(&mut p, &set(&[0.1, 2.0])).unwrap();
            let g1 = [0.5f64, -1.0];
            let g2 = [0.1f64, 2.0];
            for i in 0..2 {
                let m1 = 0.1 * g1[i];
                let v1 = 0.001 * g1[i] * g1[i];
                let m2 = 0.9 * m1 + 0.1 * g2[i];
                let v2 = 0.999 * v1 + 0.001 * g2[i] * g2[i];
                let vh = if amsgrad { v1.max(v2) } else { v2 };
                let bc1 = 1.0 - 0.9f64.powi(2);
                let bc2 = 1.0 - 0.999f64.powi(2);
                let upd = 0.1 / bc1 * m2 / (vh.sqrt() / bc2.sqrt() + 1e-8);
                let e = e1[i] - upd;
                let a = p.tensors[0].data[i] as f64;
                assert!((a - e).abs() < 1e-5, "amsgrad {amsgrad} i {i}: {a} vs {e}");
            }
        }
    }

    /// AMSGrad keeps the larger second moment: after a big gradient, a small one moves less.
    #[test]
    fn amsgrad_differs_from_adam_after_a_large_gradient() {
        let run = |amsgrad| {
            let cfg = AdamConfig {
                lr: 0.1,
                amsgrad,
                ..AdamConfig::default()
            };
            let mut p = set(&[0.0]);
            let mut adam = Adam::new(cfg, &p);
            adam.step(&mut p, &set(&[10.0])).unwrap();
            for _ in 0..2000 {
                adam.step(&mut p, &set(&[0.0])).unwrap();
            }
            let before = p.tensors[0].data[0];
            adam.step(&mut p, &set(&[-0.01])).unwrap();
            (p.tensors[0].data[0] - before).abs()
        };
        assert!(run(true) < run(false));
    }

    #[test]
    fn clipping_scales_the_gradient() {
        let cfg = AdamConfig {
            lr: 1.0,
            beta1: 0.0,
            beta2: 0.0,
            eps: 0.0,
            amsgrad: false,
            clip_norm: Some(1.0),
        };
        // With beta1 = beta2 = 0 the update is g / |g| per element whatever the scale, so
        // check the reported norm and flag instead.
        let mut p = set(&[0.0, 0.0]);
        let mut adam = Adam::new(cfg, &p);
        let info = adam.step(&mut p, &set(&[3.0, 4.0])).unwrap();
        assert!(info.clipped);
        assert!((info.grad_norm - 5.0).abs() < 1e-12);
        let info = adam.step(&mut p, &set(&[0.3, 0.4])).unwrap();
        assert!(!info.clipped);
        // The clipped moment is what was stored: v = (0.6², 0.8²) after step 1.
        let mut p2 = set(&[0.0, 0.0]);
        let mut a2 = Adam::new(
            AdamConfig {
                clip_norm: None,
                ..cfg
            },
            &p2,
        );
        a2.step(&mut p2, &set(&[0.6, 0.8])).unwrap();
        let mut p1 = set(&[0.0, 0.0]);
        let mut a1 = Adam::new(cfg, &p1);
        a1.step(&mut p1, &set(&[3.0, 4.0])).unwrap();
        for (x, y) in a1.v[0].iter().zip(&a2.v[0]) {
            assert!((x - y).abs() < 1e-6);
        }
    }

    #[test]
    fn state_round_trip_and_errors() {
        let mut p = set(&[1.0, 2.0, 3.0]);
        let mut adam = Adam::new(
            AdamConfig {
                clip_norm: Some(2.5),
                ..AdamConfig::default()
            },
            &p,
        );
        adam.step(&mut p, &set(&[0.1, -0.2, 0.3])).unwrap();
        let bytes = adam.to_bytes();
        let back = Adam::from_bytes(&bytes, &p).unwrap();
        assert_eq!(back, adam);
        // Continuing from the restored state gives the same bits.
        let (mut pa, mut pb) = (p.clone(), p.clone());
        let mut a = adam.clone();
        let mut b = back;
        a.step(&mut pa, &set(&[0.5, 0.5, -0.5])).unwrap();
        b.step(&mut pb, &set(&[0.5, 0.5, -0.5])).unwrap();
        assert_eq!(pa, pb);
        assert!(Adam::from_bytes(&bytes[..bytes.len() - 1], &p).is_err());
        assert!(Adam::from_bytes(&bytes, &set(&[1.0])).is_err());
        assert!(Adam::from_bytes(b"nope", &p).is_err());
        assert!(adam.step(&mut p, &set(&[f32::NAN, 0.0, 0.0])).is_err());
        assert!(adam.step(&mut p, &set(&[0.0])).is_err());
    }
}
