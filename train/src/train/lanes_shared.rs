//! The rollout engine's lanes for the methods without an inner loop in training
//! (`adapts_in_training()` false: `a3c`, `a3c-fg`, `a3c-ps`, `a3c-fg-ps`, `gman-nometa`,
//! `gman-noemd`). θ and φ stay at the outer parameters for the whole update, so the
//! episodes share one set of parameters and the navigator's step reduces to G, the policy
//! and the action draw. These are taken from a gman-core [`Navigator`] over the model (its
//! own views of G and the policy, in the model's adaptation mode), and each episode keeps
//! the navigator's per-episode state (LSTM state, previous probabilities, x_t, its generator
//! seeded like `Navigator::reset`). Because the batched kernels give every vector the bits
//! of the batch-1 kernels, each episode is bit for bit the episode the navigator runs alone.
//! The segments' backward waits for the end of the update with `B > 1` (one set of
//! parameters), see [`super::engine`].

use anyhow::{anyhow, bail, Result};
use gman_core::blob::TensorId;
use gman_core::navigator::{select_action, Mode, Navigator, NoiseMode, Selection};
use gman_core::nets::generator::Generator;
use gman_core::nets::policy::Policy;
use gman_core::nn::activation::{all_finite, leaky_relu_inplace, sigmoid_inplace};
use gman_core::nn::matrix::{MatRef, Weights};
use gman_core::rng::{fill_gaussian, Xoshiro128};
use gman_core::{Action, Dims, NUM_ACTIONS};

use super::bptt::{take_act, Adapted, GenBufs, Rows, Widths};
use super::lanes::{drive, Job, LaneStep, Lanes, OwnCopy, Running};
use super::lockstep::{Finished, RowState};
use super::rollout::{disc_after_episode, Worker};
use crate::model::{NavModel, K};
use crate::optim::params::ParamSet;
use crate::sim::{EpisodeSpec, World};

/// What an episode keeps of the navigator's per-episode state.
pub(super) struct SlotState {
    rng: Xoshiro128,
    attr: Vec<f32>,
    h: Vec<f32>,
    c: Vec<f32>,
    prev: Vec<f32>,
    x: Vec<f32>,
    z: Vec<f32>,
    x_valid: bool,
    x_fixed: bool,
}

/// The lanes over one set of parameter views.
struct Shared<'a> {
    model: &'a NavModel,
    policy: Policy<'a>,
    gen: Generator<'a>,
    w: Widths,
    d: Dims,
    gb: GenBatch,
    /// D after every episode (empty when it is the model's ω, see [`Finished`]).
    disc: Vec<Vec<f32>>,
}

/// The engine over shared lanes in the adaptation mode `M`.
pub(super) fn run<M: Mode, F: FnMut(u32) -> Result<(EpisodeSpec, u32)>>(
    job: Job<'_, '_, '_, F>,
    worker: &mut Worker,
) -> Result<Vec<Finished>> {
    let model = job.model;
    let cfg = model.nav_config(true);
    if cfg.model.adapt || cfg.selection != Selection::Sample {
        bail!("shared training lanes need a sampling navigator without inner loop");
    }
    // The navigator provides the parameter views (G and the policy, in the model's mode).
    let weights = model.weights()?;
    let Worker { arena, ps, .. } = worker;
    let mut nav: Navigator<'_, M, K> = Navigator::new(weights, arena, cfg)?;
    let d = *nav.dims();
    nav.reset(&vec![0.0; d.attr], 0)?;
    let policy = nav.policy()?;
    let gen = nav.generator()?;
    let disc = if is_omega(&nav, model)? {
        Vec::new()
    } else {
        disc_after_episode(&nav)?
    };
    let mut lanes = Shared {
        model,
        w: Widths::of(&policy, &d),
        d,
        gb: GenBatch {
            zero_g: is_zero(&gen.l1.w) && is_zero(&gen.l2.w),
            ..GenBatch::default()
        },
        disc,
        policy,
        gen,
    };
    let gbuf = GenBufs::new(&gen, lanes.w.f);
    drive(job, &mut lanes, gbuf, ps)
}

impl<'w> Lanes<'w> for Shared<'_> {
    type Ep = SlotState;

    fn widths(&self) -> &Widths {
        &self.w
    }

    fn dims(&self) -> &Dims {
        &self.d
    }

    fn start(&mut self, _: usize, world: &'w World, spec: &EpisodeSpec) -> Result<SlotState> {
        let w = &self.w;
        let attr = world.attributes(spec.target).to_vec();
        if !all_finite(&attr) {
            bail!("navigator: non-finite attr");
        }
        let (x, x_fixed) = if self.model.privileged {
            (world.object_feature(spec.scene, spec.target).to_vec(), true)
        } else {
            (vec![0.0; w.f], false)
        };
        Ok(SlotState {
            rng: Xoshiro128::seed_from_u64(spec.seed),
            attr,
            h: vec![0.0; w.hd],
            c: vec![0.0; w.hd],
            prev: vec![0.0; NUM_ACTIONS],
            x,
            z: vec![0.0; w.z],
            x_valid: false,
            x_fixed,
        })
    }

    fn prepare(&mut self, i: usize, ep: &mut Running<'w, SlotState>) -> Result<()> {
        let st = &mut ep.lane;
        if st.x_fixed {
            return Ok(());
        }
        match self.model.spec.noise {
            NoiseMode::Gaussian => {
                fill_gaussian(&mut st.rng, &mut st.z);
                self.gb.who.push(i);
            }
            NoiseMode::Zero => {
                if !st.x_valid {
                    st.z.fill(0.0);
                    self.gb.who.push(i);
                    st.x_valid = true;
                }
            }
        }
        Ok(())
    }

    fn generate(&mut self, slots: &mut [Option<Running<'w, SlotState>>]) -> Result<()> {
        let r = self.gb.generate(&self.gen, slots, &self.w);
        self.gb.who.clear();
        r
    }

    fn row<'s>(&'s self, _: usize, ep: &'s Running<'w, SlotState>) -> RowState<'s> {
        let st = &ep.lane;
        RowState {
            feat: &st.x,
            attr: &st.attr,
            prev: &st.prev,
            h: &st.h,
            c: &st.c,
        }
    }

    fn trunk(&self, _: usize) -> Result<Policy<'_>> {
        Ok(self.policy)
    }

    fn act(
        &mut self,
        rows: &mut Rows,
        j: usize,
        _: usize,
        ep: &mut Running<'w, SlotState>,
    ) -> Result<(Action, [f32; NUM_ACTIONS])> {
        let probs = &rows.probs[j * NUM_ACTIONS..(j + 1) * NUM_ACTIONS];
        if !all_finite(probs) || !rows.value[j].is_finite() {
            bail!("navigator: numerical fault in action probabilities");
        }
        let mut p = [0.0f32; NUM_ACTIONS];
        p.copy_from_slice(probs);
        Ok((select_action(Selection::Sample, &p, &mut ep.lane.rng), p))
    }

    fn after_act(
        &mut self,
        rows: &Rows,
        j: usize,
        _: usize,
        ep: &mut Running<'w, SlotState>,
        probs: &[f32; NUM_ACTIONS],
    ) -> Result<LaneStep> {
        let (w, st) = (&self.w, &mut ep.lane);
        Ok(LaneStep {
            act: take_act(rows, j, w),
            x: st.x.clone(),
            z: st.z.clone(),
            h_prev: std::mem::replace(&mut st.h, rows.h[j * w.hd..(j + 1) * w.hd].to_vec()),
            c_prev: std::mem::replace(&mut st.c, rows.c[j * w.hd..(j + 1) * w.hd].to_vec()),
            prev_probs: std::mem::replace(&mut st.prev, probs.to_vec()),
        })
    }

    fn in_commit_window(&self, _: usize) -> bool {
        false
    }

    fn segments_can_wait(&self) -> bool {
        true
    }

    fn own(&self, _: usize) -> Result<Option<OwnCopy>> {
        Ok(None)
    }

    fn fixed(&self) -> Result<(Policy<'_>, Generator<'_>)> {
        Ok((self.policy, self.gen))
    }

    fn live(&self, _: usize) -> Result<(Policy<'_>, Generator<'_>, Option<Adapted<'_>>)> {
        Ok((self.policy, self.gen, None))
    }

    fn after_segment(&mut self, _: usize, _: &mut Running<'w, SlotState>) -> Result<()> {
        Ok(())
    }

    fn finish(
        &mut self,
        _: usize,
        ep: Running<'w, SlotState>,
        _: &mut ParamSet,
    ) -> Result<Finished> {
        let m = ep.env.metrics();
        let mut stats = ep.stats;
        stats.success = m.success;
        stats.steps = ep.env.steps();
        stats.total_reward = m.total_reward;
        stats.adaptations = 0;
        stats.rollbacks = 0;
        stats.disc_gap = f32::NAN;
        stats.adapt_loss = f32::NAN;
        stats.final_feature = ep.lane.x;
        Ok((ep.e, stats, self.disc.clone()))
    }
}

/// G's forward over the episodes of a tick that draw a new x_t, as one batch.
#[derive(Default)]
struct GenBatch {
    /// Slots of the batch, in tick order.
    who: Vec<usize>,
    z: Vec<f32>,
    attr: Vec<f32>,
    u1: Vec<f32>,
    h1: Vec<f32>,
    u2: Vec<f32>,
    x: Vec<f32>,
    /// G's weight matrices are all zero (plain A3C: `--method a3c`, `a3c-ps`): then x_t
    /// depends on neither z_t nor SE(y) (see [`GenBatch::generate`]), so it is computed once
    /// per update and copied.
    zero_g: bool,
    /// With `zero_g`, the x_t of every episode (after the update's first batch).
    constant: Option<Vec<f32>>,
}

impl GenBatch {
    /// x_t = G(SE(y), z_t) for the slots in `who` (their `z` drawn), as one batch through
    /// the batched dense kernels: every vector gets the bits of `Generator::forward` alone
    /// (the kernels' contract; the activations are element-wise).
    fn generate(
        &mut self,
        gen: &Generator<'_>,
        slots: &mut [Option<Running<'_, SlotState>>],
        w: &Widths,
    ) -> Result<()> {
        let n = self.who.len();
        if n == 0 {
            return Ok(());
        }
        if let Some(x) = &self.constant {
            for &i in &self.who {
                lane(slots, i)?.x.copy_from_slice(x);
            }
            return Ok(());
        }
        gen.validate()?;
        let (h, a) = (gen.hidden(), w.a);
        if gen.in_dim() != w.z + a || gen.feat() != w.f {
            bail!("generator: widths do not match the model");
        }
        self.z.clear();
        self.attr.clear();
        for &i in &self.who {
            let st = lane(slots, i)?;
            self.z.extend_from_slice(&st.z);
            self.attr.extend_from_slice(&st.attr);
        }
        let sz = |v: &mut Vec<f32>, k: usize| {
            v.clear();
            v.resize(k, 0.0);
        };
        sz(&mut self.u1, if gen.l1.gain.is_some() { n * h } else { 0 });
        sz(&mut self.h1, n * h);
        sz(
            &mut self.u2,
            if gen.l2.gain.is_some() { n * w.f } else { 0 },
        );
        sz(&mut self.x, n * w.f);
        gen.l1.forward_batch(
            &[&self.z, &self.attr],
            &[w.z, a],
            n,
            &mut self.u1,
            &mut self.h1,
        )?;
        leaky_relu_inplace(&mut self.h1);
        gen.l2
            .forward_batch(&[&self.h1], &[h], n, &mut self.u2, &mut self.x)?;
        sigmoid_inplace(&mut self.x);
        if self.zero_g {
            // With W1 = 0 and W2 = 0 every product in G is ±0 (z_t and SE(y) are finite:
            // drawn, and checked when the episode starts), each layer's dot product is +0
            // (its sum starts at +0), so the pre-activations are the biases (through the
            // gain: g · (+0) + b) whatever the inputs, and the sigmoid maps ±0 alike: every
            // episode's x_t is this batch's first row, bit for bit, as the navigator alone
            // computes it.
            self.constant = Some(self.x[..w.f].to_vec());
        }
        for (&i, x) in self.who.iter().zip(self.x.chunks_exact(w.f)) {
            lane(slots, i)?.x.copy_from_slice(x);
        }
        Ok(())
    }
}

/// The state of the episode in slot `i`.
fn lane<'s>(
    slots: &'s mut [Option<Running<'_, SlotState>>],
    i: usize,
) -> Result<&'s mut SlotState> {
    slots[i]
        .as_mut()
        .map(|r| &mut r.lane)
        .ok_or_else(|| anyhow!("empty slot"))
}

/// True when every weight of `m` is exactly zero (either sign; int8: every code zero, so every
/// product is a zero before the row scale, whatever the scale).
fn is_zero(m: &MatRef<'_>) -> bool {
    match m.weights() {
        Weights::F32(d) => d.iter().all(|&v| v == 0.0),
        Weights::F32Le(d) => d
            .chunks_exact(4)
            .all(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]]) == 0.0),
        Weights::I8 { q, .. } => q.iter().all(|&b| b == 0),
    }
}

/// True when D as the navigator holds it after an episode without an inner loop
/// ([`disc_after_episode`]: `diag(gain) W1`, `b1`, `w2`, `b2`) is the model's ω bit for
/// bit: W1 in f32 with no gain or unit gains, and every value the model's.
fn is_omega<M: Mode>(nav: &Navigator<'_, M, K>, model: &NavModel) -> Result<bool> {
    let d = nav.discriminator()?;
    let w1 = match d.l1.w.weights() {
        Weights::F32(w) => w,
        _ => return Ok(false),
    };
    if d.l1
        .gain
        .is_some_and(|g| g.iter().any(|v| v.to_bits() != 1f32.to_bits()))
    {
        return Ok(false);
    }
    let b2 = [d.b2];
    let ids = TensorId::DISCRIMINATOR;
    for (id, v) in ids.iter().zip([w1, d.l1.b, d.w2, &b2[..]]) {
        let p = &model.params.tensor(id.name())?.data;
        if p.len() != v.len() || p.iter().zip(v).any(|(a, b)| a.to_bits() != b.to_bits()) {
            return Ok(false);
        }
    }
    Ok(ids.len() == 4)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The zero-G shortcut of [`GenBatch`] applies to zero matrices only, of any storage.
    #[test]
    fn zero_matrices_are_recognised() {
        let mut d = vec![0.0f32; 12];
        d[5] = -0.0;
        assert!(is_zero(&MatRef::f32(3, 4, &d).unwrap()));
        d[7] = 1e-38;
        assert!(!is_zero(&MatRef::f32(3, 4, &d).unwrap()));
        let le: Vec<u8> = [0.0f32, -0.0, 0.0, 0.0]
            .iter()
            .flat_map(|v| v.to_le_bytes())
            .collect();
        assert!(is_zero(&MatRef::f32_le(2, 2, &le).unwrap()));
        let le1: Vec<u8> = [0.0f32, 2.0].iter().flat_map(|v| v.to_le_bytes()).collect();
        assert!(!is_zero(&MatRef::f32_le(1, 2, &le1).unwrap()));
        let scales = [1.0f32, f32::NAN];
        let q = [0u8; 4];
        let sc = gman_core::nn::matrix::Scales::F32(&scales);
        assert!(is_zero(&MatRef::i8(2, 2, &q, sc).unwrap()));
        let q1 = [0u8, 0, 0xff, 0];
        assert!(!is_zero(&MatRef::i8(2, 2, &q1, sc).unwrap()));
    }
}
