//! The gradient of the A3C loss L_nav ([`super::a3c`]) over rollout segments, by
//! back-propagation through time on gman-core's batched policy kernels — the one BPTT of the
//! trainer, used by the vectorised rollout (many segments at once, [`super::vec_rollout`])
//! and by the navigator's episode runner (one segment at the navigator's current, possibly
//! adapted, parameters: [`segment_backward`]).
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
use gman_core::dense::{Dense, DenseGrads};
use gman_core::generator::{Generator, GeneratorCache, GeneratorScratch};
use gman_core::lstm::LstmGrads;
use gman_core::navigator::{Mode, Navigator};
use gman_core::policy::{
    Policy, PolicyCache, PolicyGrads, PolicyInput, PolicyInputGrads, PolicyScratch,
};
use gman_core::{Dims, NUM_ACTIONS};

use super::a3c::{output_grads, A3cConfig, SegmentLoss};
use super::step::StepRec;
use crate::train::params::ParamSet;

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
                for (j, s) in segs[..n].iter().enumerate() {
                    let z = &s.steps[s.steps.len() - 1 - r].z;
                    let dx = &self.dfeat[j * w.f..(j + 1) * w.f];
                    let gen = s.own.as_ref().map_or(gen, |o| &o.gen);
                    gbuf.backward(gen, z, s.attr, dx, &mut g1, &mut g2)?;
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
            let hd = w.hd;
            sc.dh.copy_from_slice(&self.dh_next[..nh]);
            for (j, s) in segs.iter().enumerate() {
                let p = match &s.own {
                    Some(o) => Policy {
                        actor: o.actor,
                        ..*policy
                    },
                    None => *policy,
                };
                let au = &cache.actor_u[j * w.au..(j + 1) * w.au];
                p.heads_backward(
                    1,
                    &cache.h[j * hd..(j + 1) * hd],
                    au,
                    &self.dl[j * NUM_ACTIONS..(j + 1) * NUM_ACTIONS],
                    &self.dv[j..j + 1],
                    &mut pg.actor,
                    &mut pg.critic,
                    &mut sc.dh[j * hd..(j + 1) * hd],
                    &mut sc.tmp[..NUM_ACTIONS],
                )?;
            }
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
