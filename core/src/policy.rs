//! The navigation policy π(a_t | s_t, y) (paper Sec. 3.2 and Fig. 2), parameters φ.
//!
//! ```text
//! e_t   = LeakyReLU( W_fuse [s_t; x_t; s_t ⊙ x_t; SE(y); p_{t-1}; ps_t] + b_fuse )
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
//! [`Policy::forward`] is what the device runs every step; [`Policy::backward`] is one step of
//! back-propagation through time, used by the host trainer (A3C, meta-gradients).

use crate::activation::{leaky_relu_backward, leaky_relu_inplace, softmax};
use crate::dense::{Dense, DenseGrads};
use crate::error::{check_len, Result};
use crate::lstm::{Lstm, LstmGrads};
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
}

/// Activations of one policy step (forward output and what backward needs).
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
    /// State value.
    pub value: f32,
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
}

/// Gradients flowing out of one backward step.
#[derive(Debug)]
pub struct PolicyInputGrads<'g> {
    /// dL/dx_t (`feat`), accumulated; the route from the navigation loss into G.
    pub feat: &'g mut [f32],
    /// dL/dh_{t-1} (`lstm_hidden`), overwritten.
    pub h_prev: &'g mut [f32],
    /// dL/dc_{t-1} (`lstm_hidden`), overwritten.
    pub c_prev: &'g mut [f32],
}

/// Scratch of one backward step: `embed + 4 lstm_hidden + feat + max(embed, 6)` floats.
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
        check_len("policy.critic.in", self.lstm.hidden(), self.critic.in_dim())
    }

    /// One step: writes activations, logits, probabilities and value into `cache`.
    pub fn forward(
        &self,
        inp: &PolicyInput<'_>,
        h_prev: &[f32],
        c_prev: &[f32],
        cache: &mut PolicyCache<'_>,
    ) -> Result<()> {
        self.validate()?;
        check_len("policy.feat", inp.obs.len(), inp.feat.len())?;
        check_len("policy.prod", inp.obs.len(), cache.prod.len())?;
        check_len("policy.prev_probs", NUM_ACTIONS, inp.prev_probs.len())?;
        for ((p, &s), &x) in cache.prod.iter_mut().zip(inp.obs).zip(inp.feat) {
            *p = s * x;
        }
        let segs: [&[f32]; 6] = [
            inp.obs,
            inp.feat,
            cache.prod,
            inp.attr,
            inp.prev_probs,
            inp.ps,
        ];
        self.fuse.forward(&segs, &mut [], cache.fuse)?;
        leaky_relu_inplace(cache.fuse);
        self.lstm
            .forward(&[cache.fuse], h_prev, c_prev, cache.gates, cache.c, cache.h)?;
        self.actor
            .forward(&[cache.h], cache.actor_u, cache.logits)?;
        softmax(cache.logits, cache.probs)?;
        let mut v = [0.0f32];
        self.critic.forward(&[cache.h], &mut [], &mut v)?;
        cache.value = v[0];
        Ok(())
    }

    /// One step of back-propagation through time.
    ///
    /// `dlogits` and `dvalue` are the loss gradients at this step's outputs; `dh_next` and
    /// `dc_next` arrive from the following step (zeros at the last step). Parameter gradients
    /// are accumulated into `grads`, and the gradients with respect to the generated feature,
    /// `h_{t-1}` and `c_{t-1}` are written into `out`. The gradient with respect to the
    /// observation, attributes, previous probabilities and PS input is not needed by any
    /// trainer and is not computed.
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
        self.validate()?;
        let hd = self.lstm.hidden();
        check_len("policy.dh_next", hd, dh_next.len())?;
        check_len("policy.dh", hd, s.dh.len())?;
        check_len("policy.dfeat", inp.obs.len(), out.feat.len())?;
        check_len("policy.dprod", inp.obs.len(), s.dprod.len())?;
        // Heads: dh = W_actorᵀ dlogits (+ gain) + W_criticᵀ dvalue + dh_next.
        s.dh.copy_from_slice(dh_next);
        self.actor.backward(
            &[cache.h],
            cache.actor_u,
            dlogits,
            Some(&mut [&mut *s.dh]),
            &mut grads.actor,
            &mut s.tmp[..NUM_ACTIONS],
        )?;
        self.critic.backward(
            &[cache.h],
            &[],
            &[dvalue],
            Some(&mut [&mut *s.dh]),
            &mut grads.critic,
            &mut s.tmp[..1],
        )?;
        // LSTM.
        let e = self.fuse.out_dim();
        s.de.fill(0.0);
        self.lstm.backward(
            &[cache.fuse],
            h_prev,
            c_prev,
            cache.gates,
            cache.c,
            s.dh,
            dc_next,
            out.h_prev,
            out.c_prev,
            Some(&mut [&mut *s.de]),
            grads.lstm.as_mut().map(|g| LstmGrads {
                wx: &mut *g.wx,
                wh: &mut *g.wh,
                b: &mut *g.b,
            }),
            s.dgates,
        )?;
        // Fusion: LeakyReLU then the dense layer; only the x and s⊙x column blocks'
        // input gradients are needed.
        let tmp = &mut s.tmp[..e];
        leaky_relu_backward(cache.fuse, s.de, tmp)?;
        let segs: [&[f32]; 6] = [
            inp.obs,
            inp.feat,
            cache.prod,
            inp.attr,
            inp.prev_probs,
            inp.ps,
        ];
        self.fuse
            .backward(&segs, &[], tmp, None, &mut grads.fuse, &mut [])?;
        let f = inp.obs.len();
        self.fuse.w.matvec_t_acc_cols(tmp, f, out.feat)?;
        s.dprod.fill(0.0);
        self.fuse.w.matvec_t_acc_cols(tmp, 2 * f, s.dprod)?;
        for ((o, &d), &sv) in out.feat.iter_mut().zip(s.dprod.iter()).zip(inp.obs) {
            *o += d * sv;
        }
        Ok(())
    }
}
