//! The LSTM cell of the navigation policy, forward and backward.
//!
//! Gate layout follows PyTorch's `LSTMCell`: the `4H` gate rows are `[i, f, g, o]`,
//!
//! ```text
//! [i f g o]_pre = Wx x + Wh h_prev + b
//! i = σ(i_pre)  f = σ(f_pre)  g = tanh(g_pre)  o = σ(o_pre)
//! c = f ⊙ c_prev + i ⊙ g        h = o ⊙ tanh(c)
//! ```
//!
//! The forward pass keeps the post-activation gates and `c` in caller buffers; they are all
//! the backward pass (backpropagation through time on the host trainer) needs.

use crate::nn::activation::{sigmoid_inplace, tanh};

use crate::error::{check_len, Result};
use crate::nn::batch::{matmul_acc, matmul_t_acc, outer_acc_batch_with, seg_lens};
use crate::nn::matrix::{seg_len, MatRef};

/// A read-only view of an LSTM cell's parameters.
#[derive(Clone, Copy, Debug)]
pub struct Lstm<'a> {
    /// Input weights, `4H x in`.
    pub wx: MatRef<'a>,
    /// Recurrent weights, `4H x H`.
    pub wh: MatRef<'a>,
    /// Bias, `4H` (PyTorch's `b_ih + b_hh` folded into one).
    pub b: &'a [f32],
}

/// Gradients of an LSTM cell's parameters, accumulated with `+=`.
#[derive(Debug)]
pub struct LstmGrads<'g> {
    /// dL/dWx, `4H x in`.
    pub wx: &'g mut [f32],
    /// dL/dWh, `4H x H`.
    pub wh: &'g mut [f32],
    /// dL/db, `4H`.
    pub b: &'g mut [f32],
}

impl<'a> Lstm<'a> {
    /// Hidden size `H`.
    #[inline]
    pub fn hidden(&self) -> usize {
        self.wh.cols()
    }

    /// Input size.
    #[inline]
    pub fn in_dim(&self) -> usize {
        self.wx.cols()
    }

    /// Checks the shapes of the three tensors against each other.
    pub fn validate(&self) -> Result<()> {
        let h = self.hidden();
        check_len("lstm.wh.rows", 4 * h, self.wh.rows())?;
        check_len("lstm.wx.rows", 4 * h, self.wx.rows())?;
        check_len("lstm.b", 4 * h, self.b.len())
    }

    /// One step. `gates` (`4H`) receives the post-activation `[i f g o]`; `c` and `h` (`H`)
    /// receive the new cell and hidden state. `x` is the (segmented, at most
    /// [`crate::nn::batch::MAX_SEGS`] segments) input. [`Lstm::forward_batch`] with a batch of one.
    pub fn forward(
        &self,
        x: &[&[f32]],
        h_prev: &[f32],
        c_prev: &[f32],
        gates: &mut [f32],
        c: &mut [f32],
        h: &mut [f32],
    ) -> Result<()> {
        let lens = seg_lens(x.iter().map(|s| s.len()))?;
        self.forward_batch(x, &lens[..x.len()], 1, h_prev, c_prev, gates, c, h)
    }

    /// Backward through one step.
    ///
    /// Inputs: the step's input `x`, `h_prev`, `c_prev`, and the `gates` and `c` its forward
    /// pass produced; `dh` = dL/dh and `dc` = dL/dc arriving from later (`dc` from the next
    /// step's cell, zero at the last step). Outputs: `dh_prev` and `dc_prev` are *overwritten*;
    /// `dx` (if given) is accumulated; parameter gradients are accumulated into `grads` (if
    /// given). `dgates` (`4H`) is scratch that holds the pre-activation gate gradients.
    /// [`Lstm::backward_batch`] with a batch of one.
    #[allow(clippy::too_many_arguments)]
    pub fn backward(
        &self,
        x: &[&[f32]],
        h_prev: &[f32],
        c_prev: &[f32],
        gates: &[f32],
        c: &[f32],
        dh: &[f32],
        dc: &[f32],
        dh_prev: &mut [f32],
        dc_prev: &mut [f32],
        dx: Option<&mut [&mut [f32]]>,
        grads: Option<LstmGrads<'_>>,
        dgates: &mut [f32],
    ) -> Result<()> {
        check_len("lstm.x", self.in_dim(), seg_len(x))?;
        let lens = seg_lens(x.iter().map(|s| s.len()))?;
        let lens = &lens[..x.len()];
        let (hp, cp, dp, dcp) = (h_prev, c_prev, dh_prev, dc_prev);
        match dx {
            None => self.backward_batch(
                x, lens, 1, hp, cp, gates, c, dh, dc, dp, dcp, None, grads, dgates,
            ),
            Some(dx) => {
                let dlens = seg_lens(dx.iter().map(|s| s.len()))?;
                let nd = dx.len();
                let dx = Some((dx, &dlens[..nd]));
                self.backward_batch(
                    x, lens, 1, hp, cp, gates, c, dh, dc, dp, dcp, dx, grads, dgates,
                )
            }
        }
    }
}

impl<'a> Lstm<'a> {
    /// [`Lstm::forward`] over a batch of `n` steps of independent sequences: `x` batch-major
    /// segments with per-vector lengths `lens` (see [`crate::nn::batch`]), `h_prev`, `c_prev`,
    /// `c`, `h` `n x H`, `gates` `n x 4H`. Every vector gets the bits of [`Lstm::forward`].
    #[allow(clippy::too_many_arguments)]
    pub fn forward_batch(
        &self,
        x: &[&[f32]],
        lens: &[usize],
        n: usize,
        h_prev: &[f32],
        c_prev: &[f32],
        gates: &mut [f32],
        c: &mut [f32],
        h: &mut [f32],
    ) -> Result<()> {
        self.validate()?;
        let hd = self.hidden();
        let nh = n.saturating_mul(hd);
        check_len("lstm.h_prev", nh, h_prev.len())?;
        check_len("lstm.c_prev", nh, c_prev.len())?;
        check_len("lstm.gates", nh.saturating_mul(4), gates.len())?;
        check_len("lstm.c", nh, c.len())?;
        check_len("lstm.h", nh, h.len())?;
        if hd == 0 {
            return Ok(());
        }
        for g in gates.chunks_exact_mut(4 * hd) {
            g.copy_from_slice(self.b);
        }
        matmul_acc(&self.wx, x, lens, n, gates)?;
        matmul_acc(&self.wh, &[h_prev], &[hd], n, gates)?;
        for b in 0..n {
            let gates = &mut gates[b * 4 * hd..(b + 1) * 4 * hd];
            let (gi, rest) = gates.split_at_mut(hd);
            let (gf, rest) = rest.split_at_mut(hd);
            let (gg, go) = rest.split_at_mut(hd);
            let cp = &c_prev[b * hd..(b + 1) * hd];
            let cb = &mut c[b * hd..(b + 1) * hd];
            let hb = &mut h[b * hd..(b + 1) * hd];
            // The gates' activations in place (element-wise: the same bits as one at a time).
            sigmoid_inplace(gi);
            sigmoid_inplace(gf);
            gg.iter_mut().for_each(|v| *v = tanh(*v));
            sigmoid_inplace(go);
            for j in 0..hd {
                let (i, f, g, o) = (gi[j], gf[j], gg[j], go[j]);
                let cj = f * cp[j] + i * g;
                cb[j] = cj;
                hb[j] = o * tanh(cj);
            }
        }
        Ok(())
    }

    /// [`Lstm::backward`] over a batch of `n` steps of independent sequences (all buffers
    /// batch-major, `n` times the batch-1 sizes; `dx` batch-major segments with their
    /// per-vector lengths). Parameter gradients are accumulated for `b = 0, .., n - 1` in that
    /// order: bit for bit [`Lstm::backward`] called for each vector in batch order.
    #[allow(clippy::too_many_arguments)]
    pub fn backward_batch(
        &self,
        x: &[&[f32]],
        lens: &[usize],
        n: usize,
        h_prev: &[f32],
        c_prev: &[f32],
        gates: &[f32],
        c: &[f32],
        dh: &[f32],
        dc: &[f32],
        dh_prev: &mut [f32],
        dc_prev: &mut [f32],
        dx: Option<crate::nn::dense::BatchDx<'_, '_>>,
        grads: Option<LstmGrads<'_>>,
        dgates: &mut [f32],
    ) -> Result<()> {
        self.validate()?;
        let hd = self.hidden();
        let nh = n.saturating_mul(hd);
        for (what, s) in [
            ("lstm.h_prev", h_prev),
            ("lstm.c_prev", c_prev),
            ("lstm.c", c),
            ("lstm.dh", dh),
            ("lstm.dc", dc),
        ] {
            check_len(what, nh, s.len())?;
        }
        check_len("lstm.dh_prev", nh, dh_prev.len())?;
        check_len("lstm.dc_prev", nh, dc_prev.len())?;
        check_len("lstm.gates", nh.saturating_mul(4), gates.len())?;
        check_len("lstm.dgates", nh.saturating_mul(4), dgates.len())?;
        if n == 0 || hd == 0 {
            return Ok(());
        }
        for b in 0..n {
            let g4 = &gates[b * 4 * hd..(b + 1) * 4 * hd];
            let d4 = &mut dgates[b * 4 * hd..(b + 1) * 4 * hd];
            let r = b * hd;
            for j in 0..hd {
                let (i, f, g, o) = (g4[j], g4[hd + j], g4[2 * hd + j], g4[3 * hd + j]);
                let tc = tanh(c[r + j]);
                let d_o = dh[r + j] * tc;
                let dct = dc[r + j] + dh[r + j] * o * (1.0 - tc * tc);
                let d_i = dct * g;
                let d_g = dct * i;
                let d_f = dct * c_prev[r + j];
                dc_prev[r + j] = dct * f;
                d4[j] = d_i * i * (1.0 - i);
                d4[hd + j] = d_f * f * (1.0 - f);
                d4[2 * hd + j] = d_g * (1.0 - g * g);
                d4[3 * hd + j] = d_o * o * (1.0 - o);
            }
        }
        if let Some(gr) = grads {
            outer_acc_batch_with(self.wx.kernels(), gr.wx, dgates, x, lens, n, 1.0)?;
            outer_acc_batch_with(self.wh.kernels(), gr.wh, dgates, &[h_prev], &[hd], n, 1.0)?;
            check_len("lstm.db", 4 * hd, gr.b.len())?;
            for d in dgates.chunks_exact(4 * hd) {
                for (b, &d) in gr.b.iter_mut().zip(d) {
                    *b += d;
                }
            }
        }
        dh_prev.fill(0.0);
        matmul_t_acc(&self.wh, dgates, n, &mut [dh_prev], &[hd])?;
        if let Some((dx, dx_lens)) = dx {
            matmul_t_acc(&self.wx, dgates, n, dx, dx_lens)?;
        }
        Ok(())
    }
}
