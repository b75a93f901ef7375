//! The navigation policy π(a_t | s_t, y) (paper Sec. 3.2 and Fig. 2), parameters φ.
//!
//! ```text
//! m_t,c = LeakyReLU( W_cell [M_t,c; M_t,c ⊙ x_t] + b_cell )   for every map cell c (optional)
//! e_t   = LeakyReLU( W_fuse [s_t; x_t; s_t ⊙ x_t; SE(y); p_{t-1}; ps_t; m_t] + b_fuse )
//! h_t, c_t = LSTM(e_t, h_{t-1}, c_{t-1})
//! p_t   = softmax(W_actor h_t + b_actor)        (6 action probabilities)
//! v_t   = W_critic h_t + b_critic               (state value)
//! ```
//!
//! The inputs are those of the reference implementation (observation embedding, generated
//! target feature x_t = G(SE(y), z), target attribute vector, previous action probabilities and,
//! for the "dagger" variants, the PS prediction), fused before the LSTM. One addition: the
//! element-wise product `s_t ⊙ x_t`, which lets a single linear layer express the similarity
//! between what the agent sees and what the generator imagines; without it, the fusion layer
//! can only learn that comparison through the LeakyReLU. The actor head may carry a per-unit
//! gain (parameter-efficient adaptation).
//!
//! **Spatial map.** With a map (`Dims::map_cells() > 0`) the policy also sees the view as a
//! grid of sectors M_t (the reference feeds the 512 x 7 x 7 ResNet map): one layer shared by
//! every cell (the reference's 1 x 1 convolution) turns each cell's embedding into
//! `cell_embed` channels, which are flattened into the fusion input, so the policy knows
//! *where* in the view things are. As with the pooled embedding, the cell layer also sees
//! the cell's element-wise product with x_t, so one linear layer can express "the imagined
//! target is in this sector"; that product is also how the navigation loss reaches G through
//! the map. Pooled s_t stays what D, Ψ and G's target see.
//!
//! [`Policy::forward`] is what the device runs every step; [`Policy::backward`] is one step of
//! back-propagation through time, used by the host trainer (A3C, meta-gradients).

use crate::error::{check_len, Result};
use crate::nn::activation::{leaky_relu_backward, leaky_relu_grad, leaky_relu_inplace, softmax};
use crate::nn::batch_cols::matmul_t_acc_cols;
use crate::nn::dense::{Dense, DenseGrads};
use crate::nn::lstm::{Lstm, LstmGrads};
use crate::nn::qkernel::SegTerms;
use crate::NUM_ACTIONS;

/// A read-only view of the policy's layers.
#[derive(Clone, Copy, Debug)]
pub struct Policy<'a> {
    /// Fusion layer, `embed x fuse_in`.
    pub fuse: Dense<'a>,
    /// LSTM cell, `embed -> lstm_hidden`.
    pub lstm: Lstm<'a>,
    /// Actor head, `6 x lstm_hidden`.
    pub actor: Dense<'a>,
    /// Critic head, `1 x lstm_hidden`.
    pub critic: Dense<'a>,
    /// The per-cell layer over the spatial map, `cell_embed x 2 feat` (`None`: no map).
    pub cell: Option<Dense<'a>>,
}

/// The inputs of one policy step.
#[derive(Clone, Copy, Debug)]
pub struct PolicyInput<'a> {
    /// Observation embedding s_t (`feat`).
    pub obs: &'a [f32],
    /// Generated target feature x_t (`feat`).
    pub feat: &'a [f32],
    /// Target attribute vector SE(y) (`attr`).
    pub attr: &'a [f32],
    /// Previous action probabilities (6; zeros at the first step).
    pub prev_probs: &'a [f32],
    /// PS prediction (`ps` wide; empty when the policy has no PS input).
    pub ps: &'a [f32],
    /// Spatial observation map M_t, `map_cells x feat` cell-major (empty without a map).
    pub map: &'a [f32],
}

/// Activations of `n` policy steps (the forward outputs and what backward needs), batch-major:
/// each field is `n` times the size given here, `n = 1` for [`Policy::forward`]. One
/// exception: `cell_prod` holds a single cell's product (`feat`) for [`Policy::forward`], which
/// runs the cells one at a time in the device's RAM, and every cell's (`n x map_cells x feat`)
/// for [`Policy::forward_batch`].
#[derive(Debug)]
pub struct PolicyCache<'a> {
    /// `s_t ⊙ x_t` (`feat`).
    pub prod: &'a mut [f32],
    /// Fused embedding after LeakyReLU (`embed`).
    pub fuse: &'a mut [f32],
    /// LSTM gates `[i f g o]` (`4 lstm_hidden`).
    pub gates: &'a mut [f32],
    /// New cell state (`lstm_hidden`).
    pub c: &'a mut [f32],
    /// New hidden state (`lstm_hidden`).
    pub h: &'a mut [f32],
    /// Actor `W h` before the gain (6, or empty when the actor has no gain).
    pub actor_u: &'a mut [f32],
    /// Actor logits (6).
    pub logits: &'a mut [f32],
    /// Action probabilities (6).
    pub probs: &'a mut [f32],
    /// State value (1 per step).
    pub value: &'a mut [f32],
    /// Per-cell layer outputs after LeakyReLU, `map_cells x cell_embed` (empty without a map).
    pub cell: &'a mut [f32],
    /// `M_t,c ⊙ x_t`: one cell's (`feat`) or every cell's, see above (empty without a map).
    pub cell_prod: &'a mut [f32],
}

/// The blocks [`Policy::fuse_terms`] wrote for x_t and for SE(y).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct FuseBlocks {
    /// Blocks of x_t's terms (0: its scale is 0, it adds nothing).
    pub feat: usize,
    /// Blocks of SE(y)'s terms.
    pub attr: usize,
}

/// The fusion layer's terms of x_t and SE(y), kept by the caller of [`Policy::fuse_terms`]
/// and given to [`Policy::forward_step`].
#[derive(Clone, Copy, Debug)]
pub struct FuseTerms<'a> {
    /// x_t's.
    pub feat: SegTerms<'a>,
    /// SE(y)'s.
    pub attr: SegTerms<'a>,
}

impl<'a> FuseTerms<'a> {
    /// The terms [`Policy::fuse_terms`] wrote into `buf` for a fusion layer of `embed` rows
    /// and a `feat`-wide x_t, with the blocks it returned.
    pub fn new(buf: &'a [f32], embed: usize, feat: usize, blocks: FuseBlocks) -> Self {
        let split = crate::nn::qkernel::segment_blocks(feat)
            .saturating_mul(embed)
            .min(buf.len());
        let (tf, ta) = buf.split_at(split);
        FuseTerms {
            feat: SegTerms {
                terms: tf,
                blocks: blocks.feat,
            },
            attr: SegTerms {
                terms: ta,
                blocks: blocks.attr,
            },
        }
    }
}

/// Floats [`Policy::fuse_terms`] writes at most for a fusion layer of `embed` rows, a
/// `feat`-wide x_t and an `attr`-wide SE(y) (`None`: overflow).
pub const fn fuse_terms_len(embed: usize, feat: usize, attr: usize) -> Option<usize> {
    let blocks =
        crate::nn::qkernel::segment_blocks(feat) + crate::nn::qkernel::segment_blocks(attr);
    embed.checked_mul(blocks)
}

/// Parameter-gradient accumulators of the policy (`+=`).
#[derive(Debug)]
pub struct PolicyGrads<'g> {
    /// Fusion layer.
    pub fuse: DenseGrads<'g>,
    /// LSTM (or `None` to skip).
    pub lstm: Option<LstmGrads<'g>>,
    /// Actor head.
    pub actor: DenseGrads<'g>,
    /// Critic head.
    pub critic: DenseGrads<'g>,
    /// Per-cell layer ([`DenseGrads::None`] without a map).
    pub cell: DenseGrads<'g>,
}

/// Gradients flowing out of one backward step.
#[derive(Debug)]
pub struct PolicyInputGrads<'g> {
    /// dL/dx_t (`feat`), accumulated; the route from the navigation loss into G. Empty: not
    /// wanted (G is not trained), and not computed (every other gradient keeps its bits).
    pub feat: &'g mut [f32],
    /// dL/dh_{t-1} (`lstm_hidden`), overwritten.
    pub h_prev: &'g mut [f32],
    /// dL/dc_{t-1} (`lstm_hidden`), overwritten.
    pub c_prev: &'g mut [f32],
}

/// Scratch of one backward step: `embed + 4 lstm_hidden + feat + max(embed, 6)` floats, plus
/// `map_cells x (cell_embed + feat)` with a map.
#[derive(Debug)]
pub struct PolicyScratch<'a> {
    /// `embed`.
    pub de: &'a mut [f32],
    /// `4 lstm_hidden`.
    pub dgates: &'a mut [f32],
    /// `feat` (gradient w.r.t. s_t ⊙ x_t).
    pub dprod: &'a mut [f32],
    /// `max(embed, 6)`.
    pub tmp: &'a mut [f32],
    /// `lstm_hidden`.
    pub dh: &'a mut [f32],
    /// `map_cells x cell_embed` (empty without a map).
    pub dcell: &'a mut [f32],
    /// `map_cells x feat` (empty without a map).
    pub cell_tmp: &'a mut [f32],
}

/// Whether the map's cell layer runs [`crate::nn::qkernel::cell_layer_int8`] (an int8 view on
/// int8 activations without a gain: the integer path's own form of `W [m; m ⊙ x]`).
fn int8_cells(cell: &Dense<'_>) -> bool {
    cell.w.int8_activations() && cell.gain.is_none()
}

/// The cell layer on the integer path for one step's cells: `out` (`cells x cell_embed`)
/// receives `LeakyReLU(W [m_c; m_c ⊙ x] + b)`.
fn cell_layer_int8(cell: &Dense<'_>, map: &[f32], x: &[f32], out: &mut [f32]) -> Result<()> {
    let ce = cell.out_dim();
    if ce == 0 {
        return Ok(());
    }
    for o in out.chunks_exact_mut(ce) {
        o.copy_from_slice(cell.b);
    }
    crate::nn::qkernel::cell_layer_int8(&cell.w, map, x, out)?;
    leaky_relu_inplace(out);
    Ok(())
}

impl<'a> Policy<'a> {
    /// Checks the layer shapes against each other.
    pub fn validate(&self) -> Result<()> {
        self.fuse.validate()?;
        self.lstm.validate()?;
        self.actor.validate()?;
        self.critic.validate()?;
        check_len("policy.lstm.in", self.fuse.out_dim(), self.lstm.in_dim())?;
        check_len("policy.actor.rows", NUM_ACTIONS, self.actor.out_dim())?;
        check_len("policy.actor.in", self.lstm.hidden(), self.actor.in_dim())?;
        check_len("policy.critic.rows", 1, self.critic.out_dim())?;
        check_len("policy.critic.in", self.lstm.hidden(), self.critic.in_dim())?;
        if let Some(cell) = &self.cell {
            cell.validate()?;
            if cell.in_dim() % 2 != 0 {
                return Err(crate::error::Error::Config {
                    what: "the per-cell layer's input must be [cell; cell * x_t] (2 feat wide)",
                });
            }
        }
        Ok(())
    }

    /// One step: writes activations, logits, probabilities and value into `cache`. The map's
    /// cells run one at a time through a single cell's scratch (`cache.cell_prod`, the device's
    /// RAM); everything after the cell layer is [`Policy::forward_batch`]'s with a batch of one.
    pub fn forward(
        &self,
        inp: &PolicyInput<'_>,
        h_prev: &[f32],
        c_prev: &[f32],
        cache: &mut PolicyCache<'_>,
    ) -> Result<()> {
        self.forward_step(inp, None, None, h_prev, c_prev, cache)
    }

    /// [`Policy::forward`] with the map given as the camera quantised it: `map[j] * scale`
    /// is the value of feature `j` (u8 codes, one scale for the map; `inp.map` is not read).
    /// On the integer path the cells are quantised straight from the codes
    /// ([`crate::nn::qkernel::cell_layer_int8_u8`]); otherwise each cell is expanded to f32
    /// (`map[j] as f32 * scale`) in `cache.prod`, free before the fusion layer, and runs as
    /// in [`Policy::forward`].
    pub fn forward_map_u8(
        &self,
        inp: &PolicyInput<'_>,
        map: (&[u8], f32),
        h_prev: &[f32],
        c_prev: &[f32],
        cache: &mut PolicyCache<'_>,
    ) -> Result<()> {
        self.forward_step(inp, Some(map), None, h_prev, c_prev, cache)
    }

    /// [`Policy::forward`] (`map_u8` `None`) or [`Policy::forward_map_u8`] (`Some((codes,
    /// scale))`), with the fusion layer's terms of x_t and SE(y) given (`terms`, from
    /// [`Policy::fuse_terms`] on this step's `inp.feat` and `inp.attr`) instead of computed
    /// again: the same bits. `terms` is used only where [`Policy::keeps_fuse_terms`].
    pub fn forward_step(
        &self,
        inp: &PolicyInput<'_>,
        map_u8: Option<(&[u8], f32)>,
        terms: Option<&FuseTerms<'_>>,
        h_prev: &[f32],
        c_prev: &[f32],
        cache: &mut PolicyCache<'_>,
    ) -> Result<()> {
        self.validate()?;
        let wd = match map_u8 {
            None => self.cells_step_f32(inp, cache)?,
            Some(m) => self.cells_step_u8(inp, m, cache)?,
        };
        let terms = terms.filter(|_| self.keeps_fuse_terms());
        self.forward_tail(1, wd, inp, h_prev, c_prev, cache, terms)
    }

    /// The cell layer of one step on an f32 map (`inp.map`); returns the step's widths.
    fn cells_step_f32(
        &self,
        inp: &PolicyInput<'_>,
        cache: &mut PolicyCache<'_>,
    ) -> Result<BatchWidths> {
        let wd = self.batch_widths(inp, 1, cache.cell.len())?;
        let (f, cells, ce) = (wd.f, wd.cells, wd.ce);
        match &self.cell {
            Some(cell) if int8_cells(cell) => {
                cell_layer_int8(cell, inp.map, inp.feat, &mut cache.cell[..cells * ce])?;
            }
            Some(cell) => self.cells_f32(cell, inp, f, cells, ce, cache)?,
            None => {}
        }
        Ok(wd)
    }

    /// The cell layer of one step on a map of u8 codes; returns the step's widths.
    fn cells_step_u8(
        &self,
        inp: &PolicyInput<'_>,
        (map, scale): (&[u8], f32),
        cache: &mut PolicyCache<'_>,
    ) -> Result<BatchWidths> {
        let wd = self.batch_widths_map(inp, 1, cache.cell.len(), map.len())?;
        let (f, cells, ce) = (wd.f, wd.cells, wd.ce);
        match &self.cell {
            Some(cell) if int8_cells(cell) => {
                let out = &mut cache.cell[..cells * ce];
                if ce > 0 {
                    for o in out.chunks_exact_mut(ce) {
                        o.copy_from_slice(cell.b);
                    }
                    crate::nn::qkernel::cell_layer_int8_u8(&cell.w, map, scale, inp.feat, out)?;
                    leaky_relu_inplace(out);
                }
            }
            Some(cell) => {
                check_len("policy.cell_prod", f, cache.cell_prod.len())?;
                check_len("policy.prod", f, cache.prod.len())?;
                for c in 0..cells {
                    let m = &map[c * f..(c + 1) * f];
                    for ((v, p), (&q, &x)) in cache
                        .prod
                        .iter_mut()
                        .zip(cache.cell_prod.iter_mut())
                        .zip(m.iter().zip(inp.feat))
                    {
                        *v = q as f32 * scale;
                        *p = *v * x;
                    }
                    let out = &mut cache.cell[c * ce..(c + 1) * ce];
                    cell.forward(&[cache.prod, cache.cell_prod], &mut [], out)?;
                    leaky_relu_inplace(out);
                }
            }
            None => {}
        }
        Ok(wd)
    }

    /// True when the fusion layer runs the integer path (int8 weights and activations, no
    /// gain), where each input segment adds its own terms
    /// ([`crate::nn::qkernel::segment_terms_int8`]): then [`Policy::fuse_terms`] can keep those
    /// of x_t and SE(y) while they are constant. On the f32-activation path the fusion
    /// layer sums every row's segments before its scale, and nothing is kept.
    pub fn keeps_fuse_terms(&self) -> bool {
        self.fuse.gain.is_none() && self.fuse.w.int8_activations()
    }

    /// The fusion layer's terms of the x_t segment `feat` and the SE(y) segment `attr` into
    /// `out` (at least [`fuse_terms_len`] floats), for [`Policy::forward_step`] while both are
    /// constant (with zero noise, between two inner updates). Returns the blocks written per
    /// segment, `None` (nothing written) unless [`Policy::keeps_fuse_terms`].
    pub fn fuse_terms(
        &self,
        feat: &[f32],
        attr: &[f32],
        out: &mut [f32],
    ) -> Result<Option<FuseBlocks>> {
        if !self.keeps_fuse_terms() {
            return Ok(None);
        }
        let (f, e) = (feat.len(), self.fuse.out_dim());
        let split = crate::nn::qkernel::segment_blocks(f)
            .saturating_mul(e)
            .min(out.len());
        let (of, oa) = out.split_at_mut(split);
        let w = &self.fuse.w;
        let feat_blocks = crate::nn::qkernel::segment_terms_int8(w, f, feat, of)?;
        let attr_blocks = crate::nn::qkernel::segment_terms_int8(w, 3 * f, attr, oa)?;
        Ok(Some(FuseBlocks {
            feat: feat_blocks,
            attr: attr_blocks,
        }))
    }

    /// The map's cells one at a time through a single cell's scratch (`cache.cell_prod`).
    fn cells_f32(
        &self,
        cell: &Dense<'_>,
        inp: &PolicyInput<'_>,
        f: usize,
        cells: usize,
        ce: usize,
        cache: &mut PolicyCache<'_>,
    ) -> Result<()> {
        check_len("policy.cell_prod", f, cache.cell_prod.len())?;
        for c in 0..cells {
            let m = &inp.map[c * f..(c + 1) * f];
            for ((p, &mv), &x) in cache.cell_prod.iter_mut().zip(m).zip(inp.feat) {
                *p = mv * x;
            }
            let out = &mut cache.cell[c * ce..(c + 1) * ce];
            cell.forward(&[m, cache.cell_prod], &mut [], out)?;
            leaky_relu_inplace(out);
        }
        Ok(())
    }

    /// The policy after the cell layer, over a batch of `n` rows: `s_t ⊙ x_t`, the fusion
    /// layer, the LSTM and both heads (the shared tail of [`Policy::forward`] and
    /// [`Policy::forward_batch`]; `t.cell` already holds the cell layer's outputs).
    #[allow(clippy::too_many_arguments)]
    fn forward_tail(
        &self,
        n: usize,
        wd: BatchWidths,
        inp: &PolicyInput<'_>,
        h_prev: &[f32],
        c_prev: &[f32],
        t: &mut PolicyCache<'_>,
        terms: Option<&FuseTerms<'_>>,
    ) -> Result<()> {
        let f = wd.f;
        check_len("policy.prod", inp.obs.len(), t.prod.len())?;
        check_len("policy.value", n, t.value.len())?;
        check_len("policy.probs", n * NUM_ACTIONS, t.probs.len())?;
        check_len("policy.logits", n * NUM_ACTIONS, t.logits.len())?;
        for ((p, &s), &x) in t.prod.iter_mut().zip(inp.obs).zip(inp.feat) {
            *p = s * x;
        }
        let segs: [&[f32]; 7] = [
            inp.obs,
            inp.feat,
            t.prod,
            inp.attr,
            inp.prev_probs,
            inp.ps,
            t.cell,
        ];
        let lens = [f, f, f, wd.a, NUM_ACTIONS, wd.ps, wd.cells * wd.ce];
        match terms {
            // One step with x_t's and SE(y)'s terms kept: the fusion layer's bias, then every
            // segment's terms in order (`matvec_acc_int8`'s bits, two segments not quantised).
            Some(k) if n == 1 => {
                check_len("policy.fuse", self.fuse.out_dim(), t.fuse.len())?;
                t.fuse.copy_from_slice(self.fuse.b);
                let (tf, ta) = (k.feat, k.attr);
                let cached = [None, Some(tf), None, Some(ta), None, None, None];
                crate::nn::qkernel::matvec_acc_int8_terms(&self.fuse.w, &segs, &cached, t.fuse)?;
            }
            _ => self.fuse.forward_batch(&segs, &lens, n, &mut [], t.fuse)?,
        }
        leaky_relu_inplace(t.fuse);
        let e = self.fuse.out_dim();
        self.lstm
            .forward_batch(&[t.fuse], &[e], n, h_prev, c_prev, t.gates, t.c, t.h)?;
        self.heads(n, t.h, t.actor_u, t.logits, t.probs, t.value)
    }

    /// The heads on `n` LSTM states `h` (`n x lstm_hidden`): the actor's logits (`actor_u`
    /// its pre-gain output, empty without a gain), the action probabilities and the critic's
    /// values (`n`). The last part of [`Policy::forward`]; a host that runs the trunk of many
    /// navigators as one batch finishes each row with its own (adapted) actor head here.
    pub fn heads(
        &self,
        n: usize,
        h: &[f32],
        actor_u: &mut [f32],
        logits: &mut [f32],
        probs: &mut [f32],
        value: &mut [f32],
    ) -> Result<()> {
        let hd = self.lstm.hidden();
        check_len("policy.h", n * hd, h.len())?;
        check_len("policy.probs", n * NUM_ACTIONS, probs.len())?;
        check_len("policy.logits", n * NUM_ACTIONS, logits.len())?;
        check_len("policy.value", n, value.len())?;
        self.actor.forward_batch(&[h], &[hd], n, actor_u, logits)?;
        for (l, p) in logits
            .chunks_exact(NUM_ACTIONS)
            .zip(probs.chunks_exact_mut(NUM_ACTIONS))
        {
            softmax(l, p)?;
        }
        self.critic.forward_batch(&[h], &[hd], n, &mut [], value)
    }

    /// One step of back-propagation through time.
    ///
    /// `dlogits` and `dvalue` are the loss gradients at this step's outputs; `dh_next` and
    /// `dc_next` arrive from the following step (zeros at the last step). Parameter gradients
    /// are accumulated into `grads`, and the gradients with respect to the generated feature,
    /// `h_{t-1}` and `c_{t-1}` are written into `out`. The gradient with respect to the
    /// observation, attributes, previous probabilities and PS input is not needed by any
    /// trainer and is not computed. This is [`Policy::backward_batch`] with a batch of one
    /// (host-side only: with a map, `s.cell_tmp` is `map_cells x feat`).
    #[allow(clippy::too_many_arguments)]
    pub fn backward(
        &self,
        inp: &PolicyInput<'_>,
        h_prev: &[f32],
        c_prev: &[f32],
        cache: &PolicyCache<'_>,
        dlogits: &[f32],
        dvalue: f32,
        dh_next: &[f32],
        dc_next: &[f32],
        grads: &mut PolicyGrads<'_>,
        out: &mut PolicyInputGrads<'_>,
        s: &mut PolicyScratch<'_>,
    ) -> Result<()> {
        let (dv, (h, c)) = ([dvalue], (h_prev, c_prev));
        self.backward_batch(
            1, inp, h, c, cache, dlogits, &dv, dh_next, dc_next, grads, out, s,
        )
    }
}

/// Per-vector widths of a batched policy input.
#[derive(Clone, Copy)]
struct BatchWidths {
    f: usize,
    a: usize,
    ps: usize,
    cells: usize,
    ce: usize,
}

impl<'a> Policy<'a> {
    /// Checks a batch of `n >= 1` inputs and returns the per-vector widths.
    fn batch_widths(
        &self,
        inp: &PolicyInput<'_>,
        n: usize,
        cell_out: usize,
    ) -> Result<BatchWidths> {
        self.batch_widths_map(inp, n, cell_out, inp.map.len())
    }

    /// [`Policy::batch_widths`] with a map of `map_len` values given apart from `inp`.
    fn batch_widths_map(
        &self,
        inp: &PolicyInput<'_>,
        n: usize,
        cell_out: usize,
        map_len: usize,
    ) -> Result<BatchWidths> {
        let per = |what: &'static str, len: usize| -> Result<usize> {
            let w = len / n;
            check_len(what, n * w, len)?;
            Ok(w)
        };
        let f = per("policy.obs", inp.obs.len())?;
        check_len("policy.feat", inp.obs.len(), inp.feat.len())?;
        let a = per("policy.attr", inp.attr.len())?;
        let ps = per("policy.ps", inp.ps.len())?;
        check_len("policy.prev_probs", n * NUM_ACTIONS, inp.prev_probs.len())?;
        let (cells, ce) = match &self.cell {
            None => {
                check_len("policy.map", 0, map_len)?;
                check_len("policy.cell_out", 0, cell_out)?;
                (0, 0)
            }
            Some(cell) => {
                check_len("policy.cell.in", 2 * f, cell.in_dim())?;
                let ce = cell.out_dim();
                let cells = (map_len / n).checked_div(f).unwrap_or(0);
                check_len("policy.map", n * cells * f, map_len)?;
                check_len("policy.cell_out", n * cells * ce, cell_out)?;
                (cells, ce)
            }
        };
        Ok(BatchWidths {
            f,
            a,
            ps,
            cells,
            ce,
        })
    }

    /// [`Policy::forward`] over a batch of `n` steps of independent episodes that share these
    /// parameters: the fields of `inp` are batch-major (`n` times their batch-1 sizes), and so
    /// are `h_prev`, `c_prev` and `cache` (see [`PolicyCache`]). Every step of the batch
    /// gets exactly the bits [`Policy::forward`] gives it alone.
    pub fn forward_batch(
        &self,
        n: usize,
        inp: &PolicyInput<'_>,
        h_prev: &[f32],
        c_prev: &[f32],
        cache: &mut PolicyCache<'_>,
    ) -> Result<()> {
        self.validate()?;
        if n == 0 {
            return Ok(());
        }
        let wd = self.batch_widths(inp, n, cache.cell.len())?;
        let f = wd.f;
        if let Some(cell) = &self.cell {
            let nc = n * wd.cells;
            check_len("policy.cell_prod", nc * f, cache.cell_prod.len())?;
            if f > 0 {
                for (b, x) in inp.feat.chunks_exact(f).enumerate() {
                    let m = &inp.map[b * wd.cells * f..(b + 1) * wd.cells * f];
                    let cp = &mut cache.cell_prod[b * wd.cells * f..(b + 1) * wd.cells * f];
                    for (pc, mc) in cp.chunks_exact_mut(f).zip(m.chunks_exact(f)) {
                        for ((p, &mv), &xv) in pc.iter_mut().zip(mc).zip(x) {
                            *p = mv * xv;
                        }
                    }
                }
            }
            if int8_cells(cell) && f > 0 {
                let (cells, ce) = (wd.cells, wd.ce);
                for ((m, x), o) in inp
                    .map
                    .chunks_exact(cells * f)
                    .zip(inp.feat.chunks_exact(f))
                    .zip(cache.cell.chunks_exact_mut(cells * ce))
                {
                    cell_layer_int8(cell, m, x, o)?;
                }
            } else {
                cell.forward_batch(
                    &[inp.map, cache.cell_prod],
                    &[f, f],
                    nc,
                    &mut [],
                    cache.cell,
                )?;
                leaky_relu_inplace(cache.cell);
            }
        }
        self.forward_tail(n, wd, inp, h_prev, c_prev, cache, None)
    }

    /// [`Policy::backward`] over a batch of `n` steps of independent episodes: every buffer is
    /// batch-major, `n` times its batch-1 size (`dvalue` is `n` values; in `s`, `tmp` is
    /// `n x max(embed, 6)`, `dcell` `n x map_cells x cell_embed` and `cell_tmp`
    /// `n x map_cells x feat`). Each parameter gradient is accumulated over the batch in the
    /// order `b = 0, 1, .., n - 1`, so the result is bit for bit that of calling
    /// [`Policy::backward`] for each step in batch order.
    #[allow(clippy::too_many_arguments)]
    pub fn backward_batch(
        &self,
        n: usize,
        inp: &PolicyInput<'_>,
        h_prev: &[f32],
        c_prev: &[f32],
        cache: &PolicyCache<'_>,
        dlogits: &[f32],
        dvalue: &[f32],
        dh_next: &[f32],
        dc_next: &[f32],
        grads: &mut PolicyGrads<'_>,
        out: &mut PolicyInputGrads<'_>,
        s: &mut PolicyScratch<'_>,
    ) -> Result<()> {
        self.validate()?;
        if n == 0 {
            return Ok(());
        }
        // Every shape the trunk needs is checked before the heads write anything.
        self.check_trunk_backward(n, inp, cache, dc_next, out, s)?;
        check_len("policy.dh_next", n * self.lstm.hidden(), dh_next.len())?;
        // Heads: dh = W_actorᵀ dlogits (+ gain) + W_criticᵀ dvalue + dh_next.
        s.dh.copy_from_slice(dh_next);
        self.heads_backward(
            n,
            cache.h,
            cache.actor_u,
            dlogits,
            dvalue,
            &mut grads.actor,
            &mut grads.critic,
            s.dh,
            &mut s.tmp[..n * NUM_ACTIONS],
        )?;
        self.trunk_backward_batch(n, inp, h_prev, c_prev, cache, dc_next, grads, out, s)
    }

    /// The buffer lengths [`Policy::trunk_backward_batch`] reads and writes over `n` rows.
    fn check_trunk_backward(
        &self,
        n: usize,
        inp: &PolicyInput<'_>,
        cache: &PolicyCache<'_>,
        dc_next: &[f32],
        out: &PolicyInputGrads<'_>,
        s: &PolicyScratch<'_>,
    ) -> Result<BatchWidths> {
        let wd = self.batch_widths(inp, n, cache.cell.len())?;
        let (f, hd, e) = (wd.f, self.lstm.hidden(), self.fuse.out_dim());
        check_len("policy.dh", n * hd, s.dh.len())?;
        check_len("policy.dc_next", n * hd, dc_next.len())?;
        if !out.feat.is_empty() {
            check_len("policy.dfeat", n * f, out.feat.len())?;
            check_len("policy.dprod", n * f, s.dprod.len())?;
        }
        check_len("policy.de", n * e, s.de.len())?;
        check_len("policy.tmp", n * e.max(NUM_ACTIONS), s.tmp.len())?;
        Ok(wd)
    }

    /// The heads' part of [`Policy::backward_batch`] over `n` rows: accumulates the actor's
    /// and the critic's parameter gradients (into `actor`, `critic`) and adds
    /// `W_actorᵀ dlogits` (through the gain) and `W_criticᵀ dvalue` to `dh` (`n x
    /// lstm_hidden`, holding `dh_next` on entry); `tmp` is `n x 6`. A host that runs the
    /// trunk of many navigators as one batch calls it row by row with each row's own
    /// (adapted) actor head, then [`Policy::trunk_backward_batch`] once: since every kernel
    /// accumulates over a batch in row order, the result is bit for bit that of
    /// [`Policy::backward_batch`] when the rows share one head.
    #[allow(clippy::too_many_arguments)]
    pub fn heads_backward(
        &self,
        n: usize,
        h: &[f32],
        actor_u: &[f32],
        dlogits: &[f32],
        dvalue: &[f32],
        actor: &mut DenseGrads<'_>,
        critic: &mut DenseGrads<'_>,
        dh: &mut [f32],
        tmp: &mut [f32],
    ) -> Result<()> {
        let hd = self.lstm.hidden();
        check_len("policy.h", n * hd, h.len())?;
        check_len("policy.dh", n * hd, dh.len())?;
        check_len("policy.dlogits", n * NUM_ACTIONS, dlogits.len())?;
        check_len("policy.dvalue", n, dvalue.len())?;
        check_len("policy.tmp", n * NUM_ACTIONS, tmp.len())?;
        self.actor.backward_batch(
            &[h],
            &[hd],
            n,
            actor_u,
            dlogits,
            Some((&mut [&mut *dh], &[hd])),
            actor,
            tmp,
        )?;
        self.critic.backward_batch(
            &[h],
            &[hd],
            n,
            &[],
            dvalue,
            Some((&mut [&mut *dh], &[hd])),
            critic,
            &mut tmp[..n],
        )
    }

    /// The trunk's part of [`Policy::backward_batch`] over `n` rows (LSTM, fusion layer and
    /// the map's cell layer, the parameters no navigator adapts), from `s.dh` = dL/dh_t (`n x
    /// lstm_hidden`, what [`Policy::heads_backward`] left there) and `dc_next`; the heads'
    /// gradients in `grads` are not touched. See [`Policy::backward_batch`] for the rest.
    #[allow(clippy::too_many_arguments)]
    pub fn trunk_backward_batch(
        &self,
        n: usize,
        inp: &PolicyInput<'_>,
        h_prev: &[f32],
        c_prev: &[f32],
        cache: &PolicyCache<'_>,
        dc_next: &[f32],
        grads: &mut PolicyGrads<'_>,
        out: &mut PolicyInputGrads<'_>,
        s: &mut PolicyScratch<'_>,
    ) -> Result<()> {
        self.validate()?;
        if n == 0 {
            return Ok(());
        }
        let wd = self.check_trunk_backward(n, inp, cache, dc_next, out, s)?;
        let (f, e) = (wd.f, self.fuse.out_dim());
        let want_feat = !out.feat.is_empty();
        s.de.fill(0.0);
        self.lstm.backward_batch(
            &[cache.fuse],
            &[e],
            n,
            h_prev,
            c_prev,
            cache.gates,
            cache.c,
            s.dh,
            dc_next,
            out.h_prev,
            out.c_prev,
            Some((&mut [&mut *s.de], &[e])),
            grads.lstm.as_mut().map(|g| LstmGrads {
                wx: &mut *g.wx,
                wh: &mut *g.wh,
                b: &mut *g.b,
            }),
            s.dgates,
        )?;
        let tmp = &mut s.tmp[..n * e];
        leaky_relu_backward(cache.fuse, s.de, tmp)?;
        let segs: [&[f32]; 7] = [
            inp.obs,
            inp.feat,
            cache.prod,
            inp.attr,
            inp.prev_probs,
            inp.ps,
            cache.cell,
        ];
        let lens = [f, f, f, wd.a, NUM_ACTIONS, wd.ps, wd.cells * wd.ce];
        self.fuse
            .backward_batch(&segs, &lens, n, &[], tmp, None, &mut grads.fuse, &mut [])?;
        if want_feat {
            matmul_t_acc_cols(&self.fuse.w, tmp, n, f, out.feat, f)?;
            s.dprod.fill(0.0);
            matmul_t_acc_cols(&self.fuse.w, tmp, n, 2 * f, s.dprod, f)?;
            for ((o, &d), &sv) in out.feat.iter_mut().zip(s.dprod.iter()).zip(inp.obs) {
                *o += d * sv;
            }
        }
        if let Some(cell) = &self.cell {
            let bufs = (&mut *s.dcell, &mut *s.cell_tmp, &mut *out.feat);
            let cc = (wd.cells, wd.ce);
            self.cell_backward_batch(cell, n, inp, cache.cell, tmp, cc, bufs, &mut grads.cell)?;
        }
        Ok(())
    }

    /// [`Policy::backward_batch`] through the per-cell layer (the per-cell part of
    /// [`Policy::backward`], batched; `dcell` is `n x cells x ce`, `cell_tmp` `n x cells x F`).
    #[allow(clippy::too_many_arguments)]
    fn cell_backward_batch(
        &self,
        cell: &Dense<'_>,
        n: usize,
        inp: &PolicyInput<'_>,
        act: &[f32],
        dfuse: &[f32],
        cells_ce: (usize, usize),
        (dcell, cell_tmp, dfeat): (&mut [f32], &mut [f32], &mut [f32]),
        grads: &mut DenseGrads<'_>,
    ) -> Result<()> {
        let f = inp.obs.len() / n.max(1);
        let (cells, ce) = cells_ce;
        let nc = n * cells;
        check_len("policy.dcell", nc * ce, dcell.len())?;
        check_len("policy.cell_tmp", nc * f, cell_tmp.len())?;
        let col0 = self.fuse.in_dim() - cells * ce;
        dcell.fill(0.0);
        matmul_t_acc_cols(&self.fuse.w, dfuse, n, col0, dcell, cells * ce)?;
        for (d, &a) in dcell.iter_mut().zip(act.iter()) {
            *d *= leaky_relu_grad(a);
        }
        if f > 0 {
            for (b, x) in inp.feat.chunks_exact(f).enumerate() {
                let m = &inp.map[b * cells * f..(b + 1) * cells * f];
                let cp = &mut cell_tmp[b * cells * f..(b + 1) * cells * f];
                for (pc, mc) in cp.chunks_exact_mut(f).zip(m.chunks_exact(f)) {
                    for ((p, &mv), &xv) in pc.iter_mut().zip(mc).zip(x) {
                        *p = mv * xv;
                    }
                }
            }
        }
        cell.backward_batch(
            &[inp.map, cell_tmp],
            &[f, f],
            nc,
            &[],
            dcell,
            None,
            grads,
            &mut [],
        )?;
        if dfeat.is_empty() {
            return Ok(());
        }
        cell_tmp.fill(0.0);
        matmul_t_acc_cols(&cell.w, dcell, nc, f, cell_tmp, f)?;
        if f > 0 {
            for (b, o) in dfeat.chunks_exact_mut(f).enumerate() {
                let m = &inp.map[b * cells * f..(b + 1) * cells * f];
                let ct = &cell_tmp[b * cells * f..(b + 1) * cells * f];
                for (dc, mc) in ct.chunks_exact(f).zip(m.chunks_exact(f)) {
                    for ((o, &d), &mv) in o.iter_mut().zip(dc).zip(mc) {
                        *o += d * mv;
                    }
                }
            }
        }
        Ok(())
    }
}
