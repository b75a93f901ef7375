//! The gradient of the A3C loss L_nav ([`super::a3c`]) over rollout segments, by
//! back-propagation through time on gman-core's batched policy kernels — the one BPTT of the
//! trainer, used by the rollout engine (many segments at once, [`super::engine`]); one
//! segment at a navigator's current, possibly adapted, parameters is [`segment_backward`]
//! (the gradient checks' entry).
//!
//! ```text
//! for each segment: (∂L/∂logits_t, ∂L/∂V_t) from the returns and GAE     (a3c::output_grads)
//! for r = 0, 1, ..  (step T−1−r of every segment at least r+1 long, longest first)
//!   policy backward over those rows as a matrix: fusion, LSTM, heads, the map's cell layer
//!   with (∂h, ∂c) carried from step T−r to T−1−r
//!   G's backward per row through x_t = G(SE(y), z_t) (when θ is trained)
//! ```
//!
//! **Order.** Every tensor's gradient is summed step by step (last step first) and, within a
//! step, over the segments in the order given. With one segment this is the order of the
//! batch-1 kernels, and since the batched kernels give every row the bits of the batch-1
//! ones, the result is the batch-1 BPTT's bit for bit.

use anyhow::{anyhow, bail, Result};
use gman_core::blob::TensorId;
use gman_core::navigator::{Mode, Navigator};
use gman_core::nets::generator::{Generator, GeneratorCache, GeneratorScratch};
use gman_core::nets::policy::{
    Policy, PolicyCache, PolicyGrads, PolicyInput, PolicyInputGrads, PolicyScratch,
};
use gman_core::nn::activation::{
    leaky_relu_backward, leaky_relu_inplace, sigmoid_backward, sigmoid_inplace,
};
use gman_core::nn::batch::{matmul_acc, matmul_t_acc, outer_acc_batch_with};
use gman_core::nn::dense::{Dense, DenseGrads};
use gman_core::nn::lstm::LstmGrads;
use gman_core::nn::matrix::Weights;
use gman_core::{Dims, NUM_ACTIONS};

use super::a3c::{output_grads, A3cConfig, SegmentLoss};
use super::step::StepRec;
use crate::optim::params::ParamSet;

/// Names of the gradient tensors written by the backward pass (besides `CellW`, `CellB` of
/// a model with a spatial map).
pub(crate) const GRAD_NAMES: [&str; 13] = [
    "FuseW", "FuseB", "LstmWx", "LstmWh", "LstmB", "ActorW", "ActorB", "CriticW", "CriticB",
    "GenW1", "GenB1", "GenW2", "GenB2",
];

/// The widths of one policy step (inputs and activations).
#[derive(Clone, Copy, Debug)]
pub(crate) struct Widths {
    pub(crate) f: usize,
    pub(crate) a: usize,
    pub(crate) ps: usize,
    pub(crate) map: usize,
    pub(crate) e: usize,
    pub(crate) hd: usize,
    pub(crate) au: usize,
    pub(crate) cells: usize,
    pub(crate) ce: usize,
    pub(crate) z: usize,
}

/// Batch-major step buffers of `n` rows (inputs, states and activations).
#[derive(Default)]
pub(crate) struct Rows {
    pub(crate) obs: Vec<f32>,
    pub(crate) feat: Vec<f32>,
    pub(crate) attr: Vec<f32>,
    pub(crate) prev: Vec<f32>,
    pub(crate) ps: Vec<f32>,
    pub(crate) map: Vec<f32>,
    pub(crate) h_prev: Vec<f32>,
    pub(crate) c_prev: Vec<f32>,
    pub(crate) prod: Vec<f32>,
    pub(crate) fuse: Vec<f32>,
    pub(crate) gates: Vec<f32>,
    pub(crate) c: Vec<f32>,
    pub(crate) h: Vec<f32>,
    pub(crate) actor_u: Vec<f32>,
    pub(crate) logits: Vec<f32>,
    pub(crate) probs: Vec<f32>,
    pub(crate) value: Vec<f32>,
    pub(crate) cell: Vec<f32>,
    pub(crate) cell_prod: Vec<f32>,
}

impl Rows {
    pub(crate) fn resize(&mut self, n: usize, w: &Widths) {
        let sz = |v: &mut Vec<f32>, k: usize| v.resize(n * k, 0.0);
        sz(&mut self.obs, w.f);
        sz(&mut self.feat, w.f);
        sz(&mut self.attr, w.a);
        sz(&mut self.prev, NUM_ACTIONS);
        sz(&mut self.ps, w.ps);
        sz(&mut self.map, w.map);
        sz(&mut self.h_prev, w.hd);
        sz(&mut self.c_prev, w.hd);
        sz(&mut self.prod, w.f);
        sz(&mut self.fuse, w.e);
        sz(&mut self.gates, 4 * w.hd);
        sz(&mut self.c, w.hd);
        sz(&mut self.h, w.hd);
        sz(&mut self.actor_u, w.au);
        sz(&mut self.logits, NUM_ACTIONS);
        sz(&mut self.probs, NUM_ACTIONS);
        sz(&mut self.value, 1);
        sz(&mut self.cell, w.cells * w.ce);
        sz(&mut self.cell_prod, w.map);
    }

    /// Row `j`'s step inputs and LSTM state (`h`, `c` before the step).
    pub(crate) fn put_inputs(
        &mut self,
        j: usize,
        w: &Widths,
        inp: &PolicyInput<'_>,
        h: &[f32],
        c: &[f32],
    ) {
        let put = |dst: &mut Vec<f32>, k: usize, src: &[f32]| {
            dst[j * k..(j + 1) * k].copy_from_slice(src);
        };
        put(&mut self.obs, w.f, inp.obs);
        put(&mut self.feat, w.f, inp.feat);
        put(&mut self.attr, w.a, inp.attr);
        put(&mut self.prev, NUM_ACTIONS, inp.prev_probs);
        put(&mut self.ps, w.ps, inp.ps);
        put(&mut self.map, w.map, inp.map);
        put(&mut self.h_prev, w.hd, h);
        put(&mut self.c_prev, w.hd, c);
    }

    /// The batched forward over the first `n` rows.
    pub(crate) fn forward(&mut self, policy: &Policy<'_>, n: usize, w: &Widths) -> Result<()> {
        self.resize(n, w);
        let inp = PolicyInput {
            obs: &self.obs,
            feat: &self.feat,
            attr: &self.attr,
            prev_probs: &self.prev,
            ps: &self.ps,
            map: &self.map,
        };
        let mut cache = PolicyCache {
            prod: &mut self.prod,
            fuse: &mut self.fuse,
            gates: &mut self.gates,
            c: &mut self.c,
            h: &mut self.h,
            actor_u: &mut self.actor_u,
            logits: &mut self.logits,
            probs: &mut self.probs,
            value: &mut self.value,
            cell: &mut self.cell,
            cell_prod: &mut self.cell_prod,
        };
        policy.forward_batch(n, &inp, &self.h_prev, &self.c_prev, &mut cache)?;
        Ok(())
    }
}

impl Widths {
    /// The widths of `policy` over a model of sizes `d`.
    pub(crate) fn of(policy: &Policy<'_>, d: &Dims) -> Widths {
        Widths {
            f: d.feat,
            a: d.attr,
            ps: d.ps,
            map: d.map_len(),
            e: policy.fuse.out_dim(),
            hd: policy.lstm.hidden(),
            au: if policy.actor.gain.is_some() {
                NUM_ACTIONS
            } else {
                0
            },
            cells: d.map_cells(),
            ce: if d.map_cells() > 0 { d.cell_embed } else { 0 },
            z: d.noise,
        }
    }
}

/// The activations of one step the backward pass needs (saved from the rollout's forward).
#[derive(Clone)]
pub(crate) struct StepAct {
    prod: Vec<f32>,
    fuse: Vec<f32>,
    gates: Vec<f32>,
    c: Vec<f32>,
    h: Vec<f32>,
    actor_u: Vec<f32>,
    value: f32,
    cell: Vec<f32>,
    /// G's activations of the step's x_t (`u1`, `h1`, `u2` as in `GeneratorCache`), when
    /// the rollout kept them (`h1` empty: not kept, the backward runs G again).
    pub(crate) gen: (Vec<f32>, Vec<f32>, Vec<f32>),
}

/// Row `j`'s activations (the map products are not kept: the backward pass recomputes them).
pub(crate) fn take_act(rows: &Rows, j: usize, w: &Widths) -> StepAct {
    let get = |v: &[f32], k: usize| v[j * k..(j + 1) * k].to_vec();
    StepAct {
        prod: get(&rows.prod, w.f),
        fuse: get(&rows.fuse, w.e),
        gates: get(&rows.gates, 4 * w.hd),
        c: get(&rows.c, w.hd),
        h: get(&rows.h, w.hd),
        actor_u: get(&rows.actor_u, w.au),
        value: rows.value[j],
        cell: get(&rows.cell, w.cells * w.ce),
        gen: Default::default(),
    }
}

/// G's buffers (forward for x_t, and the backward of the segment gradient).
pub(crate) struct GenBufs {
    u1: Vec<f32>,
    h1: Vec<f32>,
    u2: Vec<f32>,
    x: Vec<f32>,
    dpre2: Vec<f32>,
    dh1: Vec<f32>,
    dpre1: Vec<f32>,
    tmp: Vec<f32>,
}

impl GenBufs {
    pub(crate) fn new(gen: &Generator<'_>, f: usize) -> GenBufs {
        let gh = gen.hidden();
        GenBufs {
            u1: vec![0.0; if gen.l1.gain.is_some() { gh } else { 0 }],
            h1: vec![0.0; gh],
            u2: vec![0.0; if gen.l2.gain.is_some() { f } else { 0 }],
            x: vec![0.0; f],
            dpre2: vec![0.0; f],
            dh1: vec![0.0; gh],
            dpre1: vec![0.0; gh],
            tmp: vec![0.0; f.max(gh)],
        }
    }
}

impl GenBufs {
    /// G's backward for one step: `∂L/∂x_t = dx` into the gradients of its two layers (in
    /// the Efficient mode through the adapted per-unit gains), after recomputing its forward.
    pub(crate) fn backward(
        &mut self,
        gen: &Generator<'_>,
        z: &[f32],
        attr: &[f32],
        dx: &[f32],
        g1: &mut DenseGrads<'_>,
        g2: &mut DenseGrads<'_>,
    ) -> Result<()> {
        let mut gc = GeneratorCache {
            u1: &mut self.u1,
            h1: &mut self.h1,
            u2: &mut self.u2,
            x: &mut self.x,
        };
        gen.forward(z, attr, &mut gc)?;
        let mut gs = GeneratorScratch {
            dpre2: &mut self.dpre2,
            dh1: &mut self.dh1,
            dpre1: &mut self.dpre1,
            tmp: &mut self.tmp,
        };
        gen.backward(z, attr, &gc, dx, g1, g2, &mut gs)?;
        Ok(())
    }
}

/// One segment for the backward pass: its steps, their forward activations, SE(y) of its
/// episode and the bootstrap value `V_T` (0 when the episode ended).
pub(crate) struct Segment<'a> {
    /// The steps.
    pub(crate) steps: &'a [StepRec],
    /// Their activations, from the rollout's forward.
    pub(crate) acts: &'a [StepAct],
    /// SE(y).
    pub(crate) attr: &'a [f32],
    /// `V_T`.
    pub(crate) bootstrap: f32,
    /// The parameters of this segment's episode that its inner updates adapt (the actor
    /// head and G, as the segment ran with them), or `None`: those of the `policy` and
    /// `gen` given to [`Backward::run`].
    pub(crate) own: Option<Adapted<'a>>,
}

/// An episode's adapted parameters (θ_i, the actor head of φ_i): views of its navigator.
#[derive(Clone, Copy)]
pub(crate) struct Adapted<'a> {
    /// The actor head.
    pub(crate) actor: Dense<'a>,
    /// G.
    pub(crate) gen: Generator<'a>,
}

/// Buffers of the batched backward pass, reused across calls.
#[derive(Default)]
pub(crate) struct Backward {
    rows: Rows,
    dl: Vec<f32>,
    dv: Vec<f32>,
    dh_next: Vec<f32>,
    dc_next: Vec<f32>,
    dh_prev: Vec<f32>,
    dc_prev: Vec<f32>,
    dfeat: Vec<f32>,
    de: Vec<f32>,
    dgates: Vec<f32>,
    dprod: Vec<f32>,
    tmp: Vec<f32>,
    dh: Vec<f32>,
    dcell: Vec<f32>,
    cell_tmp: Vec<f32>,
    grows: GenRows,
}

/// The output gradients `(∂L/∂logits, ∂L/∂V)` of a segment's steps.
type OutGrads = (Vec<[f32; NUM_ACTIONS]>, Vec<f32>);

fn clear_resize(v: &mut Vec<f32>, n: usize) {
    v.clear();
    v.resize(n, 0.0);
}

impl Backward {
    /// Accumulates `∇ L_nav` of `segs` (sorted longest first) into `grads` at `policy` and
    /// `gen` (G's part only with `train_generator`), in the order of the module docs.
    /// Returns each segment's loss.
    #[allow(clippy::too_many_arguments)]
    pub(crate) fn run(
        &mut self,
        policy: &Policy<'_>,
        gen: &Generator<'_>,
        segs: &[Segment<'_>],
        cfg: &A3cConfig,
        train_generator: bool,
        w: &Widths,
        d: &Dims,
        grads: &mut ParamSet,
        gbuf: &mut GenBufs,
    ) -> Result<Vec<SegmentLoss>> {
        if segs.windows(2).any(|p| p[0].steps.len() < p[1].steps.len()) {
            bail!("backward: segments must come longest first");
        }
        let (outs, losses): (Vec<OutGrads>, Vec<SegmentLoss>) = segs
            .iter()
            .map(|s| {
                let values: Vec<f32> = s.acts.iter().map(|a| a.value).collect();
                let (dl, dv, loss) = output_grads(s.steps, &values, s.bootstrap, cfg);
                ((dl, dv), loss)
            })
            .unzip();
        let size = |id: TensorId| {
            let (r, c) = id.shape(d);
            r * c
        };
        let has_map = d.map_cells() > 0;
        let (mut cellw_g, mut cellb_g) = (
            vec![0.0f32; size(TensorId::CellW)],
            vec![0.0f32; size(TensorId::CellB)],
        );
        let [fw, fb, lwx, lwh, lb, aw, ab, cw, cb, g1w, g1b, g2w, g2b] =
            grads.slices_mut(GRAD_NAMES)?;
        let mut pg = PolicyGrads {
            fuse: DenseGrads::Full { w: fw, b: fb },
            lstm: Some(LstmGrads {
                wx: lwx,
                wh: lwh,
                b: lb,
            }),
            actor: DenseGrads::Full { w: aw, b: ab },
            critic: DenseGrads::Full { w: cw, b: cb },
            cell: if has_map {
                DenseGrads::Full {
                    w: &mut cellw_g,
                    b: &mut cellb_g,
                }
            } else {
                DenseGrads::None
            },
        };
        let mut g1 = DenseGrads::Full { w: g1w, b: g1b };
        let mut g2 = DenseGrads::Full { w: g2w, b: g2b };
        let ns = segs.len();
        for v in [
            &mut self.dh_next,
            &mut self.dc_next,
            &mut self.dh_prev,
            &mut self.dc_prev,
        ] {
            clear_resize(v, ns * w.hd);
        }
        let max_len = segs.first().map_or(0, |s| s.steps.len());
        for r in 0..max_len {
            let n = segs.iter().take_while(|s| s.steps.len() > r).count();
            self.load_rows(segs, &outs, r, n, w);
            self.policy_step(policy, &segs[..n], w, &mut pg, train_generator)?;
            if train_generator {
                let gens: Vec<&Generator<'_>> = segs[..n]
                    .iter()
                    .map(|s| s.own.as_ref().map_or(gen, |o| &o.gen))
                    .collect();
                if n > 1 && shares_weights(&gens) {
                    self.grows
                        .backward(&gens, segs, r, &self.dfeat, w, &mut g1, &mut g2)?;
                } else {
                    for (j, s) in segs[..n].iter().enumerate() {
                        let z = &s.steps[s.steps.len() - 1 - r].z;
                        let dx = &self.dfeat[j * w.f..(j + 1) * w.f];
                        gbuf.backward(gens[j], z, s.attr, dx, &mut g1, &mut g2)?;
                    }
                }
            }
        }
        if has_map {
            for (name, g) in [("CellW", &cellw_g), ("CellB", &cellb_g)] {
                let p = grads
                    .get_mut(name)
                    .ok_or_else(|| anyhow!("gradient set has no {name}"))?;
                for (a, b) in p.data.iter_mut().zip(g) {
                    *a += b;
                }
            }
        }
        Ok(losses)
    }

    /// Rows `0..n` of the backward step `r`: step `T−1−r` of each of the first `n` segments
    /// (inputs, activations, output gradients); the scratch cleared.
    fn load_rows(
        &mut self,
        segs: &[Segment<'_>],
        outs: &[OutGrads],
        r: usize,
        n: usize,
        w: &Widths,
    ) {
        let rows = &mut self.rows;
        rows.resize(n, w);
        clear_resize(&mut self.dl, n * NUM_ACTIONS);
        clear_resize(&mut self.dv, n);
        for (j, s) in segs[..n].iter().enumerate() {
            let t = s.steps.len() - 1 - r;
            let (st, a) = (&s.steps[t], &s.acts[t]);
            let put = |dst: &mut Vec<f32>, k: usize, src: &[f32]| {
                dst[j * k..(j + 1) * k].copy_from_slice(src);
            };
            put(&mut rows.obs, w.f, &st.obs);
            put(&mut rows.feat, w.f, &st.x);
            put(&mut rows.attr, w.a, s.attr);
            put(&mut rows.prev, NUM_ACTIONS, &st.prev_probs);
            put(&mut rows.ps, w.ps, &st.ps);
            put(&mut rows.map, w.map, &st.map);
            put(&mut rows.h_prev, w.hd, &st.h_prev);
            put(&mut rows.c_prev, w.hd, &st.c_prev);
            put(&mut rows.prod, w.f, &a.prod);
            put(&mut rows.fuse, w.e, &a.fuse);
            put(&mut rows.gates, 4 * w.hd, &a.gates);
            put(&mut rows.c, w.hd, &a.c);
            put(&mut rows.h, w.hd, &a.h);
            put(&mut rows.actor_u, w.au, &a.actor_u);
            put(&mut rows.logits, NUM_ACTIONS, &[0.0; NUM_ACTIONS]);
            put(&mut rows.probs, NUM_ACTIONS, &st.probs);
            rows.value[j] = a.value;
            put(&mut rows.cell, w.cells * w.ce, &a.cell);
            put(&mut self.dl, NUM_ACTIONS, &outs[j].0[t]);
            self.dv[j] = outs[j].1[t];
        }
        clear_resize(&mut self.dfeat, n * w.f);
        clear_resize(&mut self.de, n * w.e);
        clear_resize(&mut self.dgates, n * 4 * w.hd);
        clear_resize(&mut self.dprod, n * w.f);
        clear_resize(&mut self.tmp, n * w.e.max(NUM_ACTIONS));
        clear_resize(&mut self.dh, n * w.hd);
        clear_resize(&mut self.dcell, n * w.cells * w.ce);
        clear_resize(&mut self.cell_tmp, n * w.map);
    }

    /// The policy's backward over the loaded rows (those of `segs`); `(∂h, ∂c)` move one
    /// step back. Without `train_generator` the gradient into x_t is not computed. When a
    /// segment has its own actor head, the heads run row by row (each row's head, in row
    /// order: the bits of the batched heads when the rows share one), then the trunk as one
    /// batch.
    fn policy_step(
        &mut self,
        policy: &Policy<'_>,
        segs: &[Segment<'_>],
        w: &Widths,
        pg: &mut PolicyGrads<'_>,
        train_generator: bool,
    ) -> Result<()> {
        let n = segs.len();
        let rows = &mut self.rows;
        let inp = PolicyInput {
            obs: &rows.obs,
            feat: &rows.feat,
            attr: &rows.attr,
            prev_probs: &rows.prev,
            ps: &rows.ps,
            map: &rows.map,
        };
        let cache = PolicyCache {
            prod: &mut rows.prod,
            fuse: &mut rows.fuse,
            gates: &mut rows.gates,
            c: &mut rows.c,
            h: &mut rows.h,
            actor_u: &mut rows.actor_u,
            logits: &mut rows.logits,
            probs: &mut rows.probs,
            value: &mut rows.value,
            cell: &mut rows.cell,
            cell_prod: &mut rows.cell_prod,
        };
        let nh = n * w.hd;
        let mut out = PolicyInputGrads {
            feat: if train_generator {
                &mut self.dfeat
            } else {
                &mut []
            },
            h_prev: &mut self.dh_prev[..nh],
            c_prev: &mut self.dc_prev[..nh],
        };
        let mut sc = PolicyScratch {
            de: &mut self.de,
            dgates: &mut self.dgates,
            dprod: &mut self.dprod,
            tmp: &mut self.tmp,
            dh: &mut self.dh,
            dcell: &mut self.dcell,
            cell_tmp: &mut self.cell_tmp,
        };
        if segs.iter().all(|s| s.own.is_none()) {
            policy.backward_batch(
                n,
                &inp,
                &rows.h_prev,
                &rows.c_prev,
                &cache,
                &self.dl,
                &self.dv,
                &self.dh_next[..nh],
                &self.dc_next[..nh],
                pg,
                &mut out,
                &mut sc,
            )?;
        } else {
            sc.dh.copy_from_slice(&self.dh_next[..nh]);
            let heads = HeadRows {
                h: &cache.h[..],
                actor_u: &cache.actor_u[..],
                dl: &self.dl,
                dv: &self.dv,
            };
            heads_backward_by_row(policy, segs, w, &heads, pg, &mut sc.dh[..], &mut sc.tmp[..])?;
            policy.trunk_backward_batch(
                n,
                &inp,
                &rows.h_prev,
                &rows.c_prev,
                &cache,
                &self.dc_next[..nh],
                pg,
                &mut out,
                &mut sc,
            )?;
        }
        std::mem::swap(&mut self.dh_next, &mut self.dh_prev);
        std::mem::swap(&mut self.dc_next, &mut self.dc_prev);
        Ok(())
    }
}

/// The rows' activations and output gradients the heads' backward reads.
struct HeadRows<'a> {
    h: &'a [f32],
    actor_u: &'a [f32],
    dl: &'a [f32],
    dv: &'a [f32],
}

/// The heads' backward row by row, each row at its segment's own actor head (the shared one
/// without), in row order: the bits of the batched heads when the rows share one. `dh` holds
/// `∂L/∂h` from the next step and receives the heads' part.
fn heads_backward_by_row(
    policy: &Policy<'_>,
    segs: &[Segment<'_>],
    w: &Widths,
    r: &HeadRows<'_>,
    pg: &mut PolicyGrads<'_>,
    dh: &mut [f32],
    tmp: &mut [f32],
) -> Result<()> {
    let hd = w.hd;
    for (j, s) in segs.iter().enumerate() {
        let p = match &s.own {
            Some(o) => Policy {
                actor: o.actor,
                ..*policy
            },
            None => *policy,
        };
        p.heads_backward(
            1,
            &r.h[j * hd..(j + 1) * hd],
            &r.actor_u[j * w.au..(j + 1) * w.au],
            &r.dl[j * NUM_ACTIONS..(j + 1) * NUM_ACTIONS],
            &r.dv[j..j + 1],
            &mut pg.actor,
            &mut pg.critic,
            &mut dh[j * hd..(j + 1) * hd],
            &mut tmp[..NUM_ACTIONS],
        )?;
    }
    Ok(())
}

/// Accumulates `∇ L_nav` of a segment into `grads` (names as in blobs; see the module docs),
/// at the navigator's *current* parameters (those the segment ran with: call before the
/// inner update; in the Efficient mode through its adapted per-unit gains). The forward
/// activations are recomputed from the recorded inputs, and checked against the recorded
/// probabilities bit for bit. With `train_generator`, G's gradient through x_t is included.
pub fn segment_backward<M: Mode, const K: usize>(
    nav: &Navigator<'_, M, K>,
    seg: &[StepRec],
    bootstrap: f32,
    cfg: &A3cConfig,
    train_generator: bool,
    grads: &mut ParamSet,
) -> Result<SegmentLoss> {
    if seg.is_empty() {
        return Ok(SegmentLoss::default());
    }
    let policy = nav.policy()?;
    let gen = nav.generator()?;
    let d = *nav.dims();
    let w = Widths::of(&policy, &d);
    let attr = nav.attr();
    let mut rows = Rows::default();
    let mut acts = Vec::with_capacity(seg.len());
    for s in seg {
        let inp = PolicyInput {
            obs: &s.obs,
            feat: &s.x,
            attr,
            prev_probs: &s.prev_probs,
            ps: &s.ps,
            map: &s.map,
        };
        rows.resize(1, &w);
        rows.put_inputs(0, &w, &inp, &s.h_prev, &s.c_prev);
        rows.forward(&policy, 1, &w)?;
        if rows
            .probs
            .iter()
            .zip(&s.probs)
            .any(|(a, b)| a.to_bits() != b.to_bits())
        {
            bail!("recomputed policy step differs from the navigator's (parameters changed mid-segment?)");
        }
        acts.push(take_act(&rows, 0, &w));
    }
    let segs = [Segment {
        steps: seg,
        acts: &acts,
        attr,
        bootstrap,
        own: None,
    }];
    let mut gbuf = GenBufs::new(&gen, w.f);
    let losses = Backward::default().run(
        &policy,
        &gen,
        &segs,
        cfg,
        train_generator,
        &w,
        &d,
        grads,
        &mut gbuf,
    )?;
    Ok(losses[0])
}

/// The weight data of a dense view when it is f32 (its identity: pointer and length).
fn f32_id(d: &Dense<'_>) -> Option<(*const f32, usize)> {
    match d.w.weights() {
        Weights::F32(v) => Some((v.as_ptr(), v.len())),
        _ => None,
    }
}

/// True when the generators share their weight matrices (f32) and differ at most in their
/// per-unit gains and biases, with a gain on every row or on none, per layer: one G, or the
/// episodes' θ_i of the Efficient mode.
fn shares_weights(gens: &[&Generator<'_>]) -> bool {
    let Some(first) = gens.first() else {
        return false;
    };
    let same = |a: &Dense<'_>, b: &Dense<'_>| {
        f32_id(a).is_some()
            && f32_id(a) == f32_id(b)
            && a.w.rows() == b.w.rows()
            && a.w.cols() == b.w.cols()
            && a.gain.is_some() == b.gain.is_some()
            && a.b.len() == b.b.len()
            && a.gain.is_none_or(|g| g.len() == a.b.len())
            && a.b.len() == a.w.rows()
    };
    gens.iter()
        .all(|g| same(&first.l1, &g.l1) && same(&first.l2, &g.l2))
}

/// G's forward (recomputed) and backward over the rows of one backward step as one batch,
/// for generators that share their weight matrices ([`shares_weights`]): each row with its
/// own gains and biases. Bit for bit [`GenBufs::backward`] row by row in row order: the
/// matrix products are the batched kernels (every row the bits of the batch-1 kernels, the
/// weight gradients accumulated over the rows in order), the per-row operations are the
/// dense layer's own (`gain * u + b`, `dpre * gain`, the bias gradient `+= dpre`), and each
/// gradient tensor sees the rows in order.
#[derive(Default)]
struct GenRows {
    z: Vec<f32>,
    attr: Vec<f32>,
    u1: Vec<f32>,
    h1: Vec<f32>,
    u2: Vec<f32>,
    x: Vec<f32>,
    dpre2: Vec<f32>,
    scaled: Vec<f32>,
    dh1: Vec<f32>,
    dpre1: Vec<f32>,
}

impl GenRows {
    /// The layer `l` of row `j`'s generator (`first`: layer 1).
    fn layer<'g>(g: &'g Generator<'_>, first: bool) -> &'g Dense<'g> {
        if first {
            &g.l1
        } else {
            &g.l2
        }
    }

    /// `pre = gain ⊙ (W x) + b` (with a gain: `u = W x` kept) or `pre = b + W x` per row, as
    /// [`Dense::forward_batch`] computes it for one G.
    fn dense_forward(
        gens: &[&Generator<'_>],
        first: bool,
        x: &[&[f32]],
        lens: &[usize],
        u: &mut Vec<f32>,
        pre: &mut Vec<f32>,
    ) -> Result<()> {
        let n = gens.len();
        let l0 = Self::layer(gens[0], first);
        let o = l0.out_dim();
        clear_resize(pre, n * o);
        match l0.gain {
            None => {
                for (p, g) in pre.chunks_exact_mut(o).zip(gens) {
                    p.copy_from_slice(Self::layer(g, first).b);
                }
                matmul_acc(&l0.w, x, lens, n, pre)?;
            }
            Some(_) => {
                clear_resize(u, n * o);
                matmul_acc(&l0.w, x, lens, n, u)?;
                for ((p, ur), g) in pre.chunks_exact_mut(o).zip(u.chunks_exact(o)).zip(gens) {
                    let l = Self::layer(g, first);
                    let gain = l.gain.ok_or_else(|| anyhow!("generator rows: gain"))?;
                    for (((p, &ui), &gi), &bi) in p.iter_mut().zip(ur).zip(gain).zip(l.b) {
                        *p = gi * ui + bi;
                    }
                }
            }
        }
        Ok(())
    }

    /// The parameter gradients of layer `first`/2 from `dpre` (`n x out`) and, with `dx`,
    /// `dx += Wᵀ (gain ⊙ dpre)`, as [`Dense::backward_batch`] computes them for one G.
    #[allow(clippy::too_many_arguments)]
    fn dense_backward(
        gens: &[&Generator<'_>],
        first: bool,
        x: &[&[f32]],
        lens: &[usize],
        dpre: &[f32],
        scaled: &mut Vec<f32>,
        dx: Option<(&mut [f32], usize)>,
        grads: &mut DenseGrads<'_>,
    ) -> Result<()> {
        let n = gens.len();
        let l0 = Self::layer(gens[0], first);
        let o = l0.out_dim();
        let dy: &[f32] = match l0.gain {
            None => dpre,
            Some(_) => {
                clear_resize(scaled, n * o);
                for ((s, d), g) in scaled
                    .chunks_exact_mut(o)
                    .zip(dpre.chunks_exact(o))
                    .zip(gens)
                {
                    let gain = Self::layer(g, first)
                        .gain
                        .ok_or_else(|| anyhow!("generator rows: gain"))?;
                    for ((s, &d), &gi) in s.iter_mut().zip(d).zip(gain) {
                        *s = d * gi;
                    }
                }
                scaled
            }
        };
        match grads {
            DenseGrads::Full { w, b } => {
                outer_acc_batch_with(l0.w.kernels(), w, dy, x, lens, n, 1.0)?;
                for d in dpre.chunks_exact(o) {
                    for (bi, &d) in b.iter_mut().zip(d) {
                        *bi += d;
                    }
                }
            }
            _ => bail!("generator rows: full gradients expected"),
        }
        if let Some((dx, len)) = dx {
            matmul_t_acc(&l0.w, dy, n, &mut [dx], &[len])?;
        }
        Ok(())
    }

    /// G's backward for backward step `r` of `segs` (row `j` with generator `gens[j]`, its
    /// step's z and SE(y), `dfeat`'s row `j` as `∂L/∂x_t`).
    #[allow(clippy::too_many_arguments)]
    fn backward(
        &mut self,
        gens: &[&Generator<'_>],
        segs: &[Segment<'_>],
        r: usize,
        dfeat: &[f32],
        w: &Widths,
        g1: &mut DenseGrads<'_>,
        g2: &mut DenseGrads<'_>,
    ) -> Result<()> {
        let n = gens.len();
        let (h, f) = (gens[0].hidden(), gens[0].feat());
        for g in gens {
            g.validate()?;
        }
        if f != w.f || gens[0].in_dim() != w.z + w.a {
            bail!("generator rows: widths do not match the model");
        }
        self.z.clear();
        self.attr.clear();
        for s in &segs[..n] {
            self.z.extend_from_slice(&s.steps[s.steps.len() - 1 - r].z);
            self.attr.extend_from_slice(s.attr);
        }
        let (zl, al) = (w.z, w.a);
        if self.z.len() != n * zl || self.attr.len() != n * al {
            bail!("generator rows: z or SE(y) of the wrong width");
        }
        // Forward: the rows' x_t with their activations, as the rollout kept them, else
        // recomputed (the same bits: the batched kernels give every row the batch-1 ones).
        let kept = |s: &Segment<'_>| {
            let t = s.steps.len() - 1 - r;
            let Some((u1, h1, u2)) = s.acts.get(t).map(|a| &a.gen) else {
                return false;
            };
            h1.len() == h && s.steps[t].x.len() == f && {
                let l1 = gens[0].l1.gain.map_or(0, |_| h);
                let l2 = gens[0].l2.gain.map_or(0, |_| f);
                u1.len() == l1 && u2.len() == l2
            }
        };
        let xin: [&[f32]; 2] = [&self.z, &self.attr];
        if segs[..n].iter().all(kept) {
            for v in [&mut self.u1, &mut self.h1, &mut self.u2, &mut self.x] {
                v.clear();
            }
            for s in &segs[..n] {
                let t = s.steps.len() - 1 - r;
                let (u1, h1, u2) = &s.acts[t].gen;
                self.u1.extend_from_slice(u1);
                self.h1.extend_from_slice(h1);
                self.u2.extend_from_slice(u2);
                self.x.extend_from_slice(&s.steps[t].x);
            }
        } else {
            Self::dense_forward(gens, true, &xin, &[zl, al], &mut self.u1, &mut self.h1)?;
            leaky_relu_inplace(&mut self.h1);
            Self::dense_forward(gens, false, &[&self.h1], &[h], &mut self.u2, &mut self.x)?;
            sigmoid_inplace(&mut self.x);
        }
        // Backward.
        clear_resize(&mut self.dpre2, n * f);
        sigmoid_backward(&self.x, &dfeat[..n * f], &mut self.dpre2)?;
        clear_resize(&mut self.dh1, n * h);
        Self::dense_backward(
            gens,
            false,
            &[&self.h1],
            &[h],
            &self.dpre2,
            &mut self.scaled,
            Some((&mut self.dh1, h)),
            g2,
        )?;
        clear_resize(&mut self.dpre1, n * h);
        leaky_relu_backward(&self.h1, &self.dh1, &mut self.dpre1)?;
        Self::dense_backward(
            gens,
            true,
            &xin,
            &[zl, al],
            &self.dpre1,
            &mut self.scaled,
            None,
            g1,
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::pretrain::generator::init_generator;
    use gman_core::nn::matrix::MatRef;
    use gman_core::rng::{uniform, Xoshiro128};

    /// G's backward over the rows of a step as one batch ([`GenRows`]) is bit for bit
    /// [`GenBufs::backward`] row by row, with one G (no gains) and with per-row gains and
    /// biases over shared matrices (the Efficient mode's θ_i).
    #[test]
    fn generator_rows_as_one_batch_are_the_rows_one_by_one() {
        let d = Dims::MCU;
        let mut rng = Xoshiro128::seed_from_u64(11);
        let p = init_generator(&d, &mut rng).unwrap();
        let t = |n: &str| p.tensor(n).unwrap().data.clone();
        let (w1, w2) = (t("GenW1"), t("GenW2"));
        let (h, f, n) = (d.gen_hidden, d.feat, 5);
        let mut r = |k: usize, a: f32, c: f32| -> Vec<f32> {
            (0..k).map(|_| c + a * (uniform(&mut rng) - 0.5)).collect()
        };
        // Per row: gains and biases of both layers, z, SE(y), ∂L/∂x.
        let rows: Vec<[Vec<f32>; 7]> = (0..n)
            .map(|_| {
                [
                    r(h, 0.4, 1.0),
                    r(h, 0.2, 0.0),
                    r(f, 0.4, 1.0),
                    r(f, 0.2, 0.0),
                    r(d.noise, 2.0, 0.0),
                    r(d.attr, 1.0, 0.5),
                    r(f, 0.1, 0.0),
                ]
            })
            .collect();
        let kern = crate::simd::host_kernels();
        let m = |r, c, v| {
            let m = MatRef::f32(r, c, v).unwrap();
            match kern {
                Some(k) => m.with_kernels(k),
                None => m,
            }
        };
        let (m1, m2) = (m(h, d.noise + d.attr, &w1[..]), m(f, h, &w2[..]));
        for (gains, keep) in [(false, false), (true, false), (false, true), (true, true)] {
            let gens: Vec<Generator<'_>> = rows
                .iter()
                .map(|rw| Generator {
                    l1: Dense {
                        w: m1,
                        b: &rw[1],
                        gain: gains.then_some(&rw[0][..]),
                    },
                    l2: Dense {
                        w: m2,
                        b: &rw[3],
                        gain: gains.then_some(&rw[2][..]),
                    },
                })
                .collect();
            // The rollout's activations of each row's x_t (`keep`), from G's own forward.
            let fwd: Vec<[Vec<f32>; 4]> = gens
                .iter()
                .zip(&rows)
                .map(|(g, rw)| {
                    let mut a = [
                        vec![0.0; if gains { h } else { 0 }],
                        vec![0.0; h],
                        vec![0.0; if gains { f } else { 0 }],
                        vec![0.0; f],
                    ];
                    let [u1, h1, u2, x] = &mut a;
                    let mut c = GeneratorCache { u1, h1, u2, x };
                    g.forward(&rw[4], &rw[5], &mut c).unwrap();
                    a
                })
                .collect();
            let acts: Vec<Vec<StepAct>> = fwd
                .iter()
                .map(|a| {
                    let gen = if keep {
                        (a[0].clone(), a[1].clone(), a[2].clone())
                    } else {
                        Default::default()
                    };
                    vec![StepAct {
                        prod: vec![],
                        fuse: vec![],
                        gates: vec![],
                        c: vec![],
                        h: vec![],
                        actor_u: vec![],
                        value: 0.0,
                        cell: vec![],
                        gen,
                    }]
                })
                .collect();
            let steps: Vec<Vec<StepRec>> = rows
                .iter()
                .zip(&fwd)
                .map(|(rw, a)| {
                    vec![StepRec {
                        obs: vec![],
                        ps: vec![],
                        map: vec![],
                        x: if keep { a[3].clone() } else { vec![] },
                        z: rw[4].clone(),
                        h_prev: vec![],
                        c_prev: vec![],
                        prev_probs: vec![],
                        action: 0,
                        reward: 0.0,
                        probs: [0.0; NUM_ACTIONS],
                        expert: None,
                    }]
                })
                .collect();
            let segs: Vec<Segment<'_>> = steps
                .iter()
                .zip(&rows)
                .zip(&acts)
                .map(|((s, rw), a)| Segment {
                    steps: s,
                    acts: a,
                    attr: &rw[5],
                    bootstrap: 0.0,
                    own: None,
                })
                .collect();
            let dfeat: Vec<f32> = rows.iter().flat_map(|rw| rw[6].clone()).collect();
            let w = Widths {
                f,
                a: d.attr,
                ps: 0,
                map: 0,
                e: d.embed,
                hd: d.lstm_hidden,
                au: 0,
                cells: 0,
                ce: 0,
                z: d.noise,
            };
            let zeros = |k: usize| vec![0.0f32; k];
            let (mut a1w, mut a1b, mut a2w, mut a2b) =
                (zeros(w1.len()), zeros(h), zeros(w2.len()), zeros(f));
            let refs: Vec<&Generator<'_>> = gens.iter().collect();
            assert!(shares_weights(&refs));
            GenRows::default()
                .backward(
                    &refs,
                    &segs,
                    0,
                    &dfeat,
                    &w,
                    &mut DenseGrads::Full {
                        w: &mut a1w,
                        b: &mut a1b,
                    },
                    &mut DenseGrads::Full {
                        w: &mut a2w,
                        b: &mut a2b,
                    },
                )
                .unwrap();
            let (mut b1w, mut b1b, mut b2w, mut b2b) =
                (zeros(w1.len()), zeros(h), zeros(w2.len()), zeros(f));
            let mut gb = GenBufs::new(&gens[0], f);
            for (j, g) in gens.iter().enumerate() {
                gb.backward(
                    g,
                    &rows[j][4],
                    &rows[j][5],
                    &rows[j][6],
                    &mut DenseGrads::Full {
                        w: &mut b1w,
                        b: &mut b1b,
                    },
                    &mut DenseGrads::Full {
                        w: &mut b2w,
                        b: &mut b2b,
                    },
                )
                .unwrap();
            }
            let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
            for (a, b, name) in [
                (&a1w, &b1w, "W1"),
                (&a1b, &b1b, "b1"),
                (&a2w, &b2w, "W2"),
                (&a2b, &b2b, "b2"),
            ] {
                assert!(a.iter().any(|&v| v != 0.0), "{name} gradient");
                assert_eq!(bits(a), bits(b), "gains {gains} kept {keep}: {name}");
            }
        }
        // Per-row weight matrices (the Full mode's θ_i) are not shared.
        let w1b = w1.iter().map(|v| v * 1.5).collect::<Vec<f32>>();
        let other = Generator {
            l1: Dense {
                w: m(h, d.noise + d.attr, &w1b[..]),
                b: &rows[0][1],
                gain: None,
            },
            l2: Dense {
                w: m2,
                b: &rows[0][3],
                gain: None,
            },
        };
        let one = Generator {
            l1: Dense {
                w: m1,
                b: &rows[0][1],
                gain: None,
            },
            ..other
        };
        assert!(!shares_weights(&[&one, &other]));
    }
}
