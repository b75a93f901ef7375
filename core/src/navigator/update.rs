//! The inner update of Algorithm 1 (lines 15-20): D's ascent, L_ad's gradients, the descent of
//! θ_i and φ_i, in slices, and its commit.

use crate::adapt::actor_head_grad;
use crate::adapt::inner::{self};
use crate::error::{Error, Result};
use crate::navigator::arena::Ram;
use crate::navigator::config::{AdaptReport, Mode};
use crate::navigator::memory::AdaptMode;
use crate::navigator::psi::psi_load;
use crate::navigator::state::{Navigator, Phase, Update};
use crate::navigator::weights::{axpy_inplace, disc_view, gen_view, ok_update, ARENA_TOO_SMALL};
use crate::nets::discriminator::{DiscGrads, LdValue};
use crate::nets::generator::GeneratorCache;
use crate::nn::activation::all_finite;
use crate::rng::{uniform, Xoshiro128};
use crate::spec::schema::{Emd, NoiseMode};
use crate::spec::schema::{StepRule, TensorId};
use crate::NUM_ACTIONS;

impl<'w, M: Mode, const K: usize, S: AsRef<[f32]> + AsMut<[f32]>> Navigator<'w, M, K, S> {
    /// Runs the inner update (lines 15-20 of Algorithm 1) now on the steps buffered in Ψ, then
    /// empties Ψ, whatever the step count and the per-episode cap (which it still counts towards).
    /// Useful at the end of an episode, and for benchmarks; with [`Schedule::Manual`](crate::navigator::Schedule::Manual) and a [commit
    /// delay](crate::spec::InnerRule::commit_delay), the commit of the update that started when Ψ
    /// filled (its remaining slices first). Returns whether an update ran: false with nothing
    /// buffered, and false with the inner loop off ([`ModelSpec::adapt`](crate::spec::ModelSpec::adapt) false), which only empties
    /// Ψ.
    pub fn adapt_now(&mut self) -> Result<bool> {
        if !self.ready {
            return Err(Error::Config {
                what: "call reset() before adapt_now()",
            });
        }
        if self.upd.is_some() {
            while self.upd.is_some_and(|u| u.phase != Phase::Done) {
                self.run_slice()?;
            }
            self.commit_update()?;
            return Ok(true);
        }
        if self.n_buf == 0 {
            return Ok(false);
        }
        if !self.cfg.model.adapt {
            // The inner loop is off (`NavConfig::model.adapt == false`): nothing adapts, Ψ is
            // emptied like after an update.
            self.n_buf = 0;
            return Ok(false);
        }
        self.inner_update()?;
        self.n_buf = 0;
        Ok(true)
    }

    /// Lines 15-20 of Algorithm 1 on the `n_buf` (normally `K`) samples in Ψ: D ascends L_D
    /// (Eq. 1), then θ and the actor head φ descend L_ad (Eq. 3); a step whose loss or result
    /// is not finite or exceeds the loss bound is not applied (rolled back). All at once:
    /// the slices of [`Navigator::run_slice`] back to back, then the commit.
    pub(super) fn inner_update(&mut self) -> Result<()> {
        self.start_update(false)?;
        while self.upd.is_some_and(|u| u.phase != Phase::Done) {
            self.run_slice()?;
        }
        self.commit_update()
    }

    /// With zero noise and Ψ's one row of x_t not recorded by its first entry (the caller
    /// fixed x_t, or a probe overwrote G's activations first): G(0, SE(y)) at the current θ,
    /// once, into that row (the bits the steps' G pass gives).
    fn generate_shared_x(&mut self) -> Result<()> {
        if self.cfg.model.noise != NoiseMode::Zero || self.psi_recorded {
            return Ok(());
        }
        self.u2_valid = false;
        let f = self.w.dims.feat;
        let r = self.arena.ram();
        r.z.fill(0.0);
        let gen = gen_view(&r.gen1, &r.gen2, &self.w)?;
        let u2 = if r.psi_u2.is_empty() {
            r.u2
        } else {
            &mut r.psi_u2[..f]
        };
        let mut cache = GeneratorCache {
            u1: r.u1,
            h1: r.h1,
            u2,
            x: &mut r.psi_x[..f],
        };
        gen.forward(r.z, r.attr, &mut cache)?;
        self.psi_recorded = true;
        Ok(())
    }

    /// Starts the inner update on the `n_buf` entries of Ψ (`forked`: with the update's own
    /// generator, forked from the navigator's by one draw).
    pub(super) fn start_update(&mut self, forked: bool) -> Result<()> {
        self.generate_shared_x()?;
        // Lines 15-16: D ascends L_D over Ψ_s and Ψ_x, `disc_steps` times (the paper: once;
        // not with the CosSim variant, which has no D).
        let use_d = self.cfg.model.emd == Emd::Discriminator;
        let disc_steps = if use_d {
            self.cfg.model.inner_rule.disc_steps.clamp(1, 256)
        } else {
            0
        };
        if forked {
            self.upd_rng = Xoshiro128::seed_from_u64(rand_core::RngCore::next_u64(&mut self.rng));
        }
        // Ψ_x as the steps recorded it when they ran G at this θ (G is fixed until the
        // descent step of line 20), else each pass regenerates its batch's x_t: the same bits.
        let phase = if disc_steps > 0 {
            Phase::Disc
        } else {
            Phase::Scores
        };
        let mut u = Update {
            phase,
            t: 0,
            disc_done: 0,
            disc_steps,
            disc_ok: true,
            use_d,
            forked,
            window: 0,
            done: 0,
            total: 0,
            slices: 0,
            half: false,
            report: AdaptReport::default(),
        };
        u.total = self.cost_bound(&u);
        self.upd = Some(u);
        Ok(())
    }

    /// Estimated multiply-adds of one slice (a batch of `nb` entries) of `phase`: what the
    /// in-step schedule spreads evenly over the commit window.
    fn slice_cost(&self, phase: Phase, nb: usize) -> u64 {
        let d = self.w.dims;
        let (f, dh, h, zin) = (d.feat, d.disc_hidden, d.gen_hidden, d.noise + d.attr);
        let full = (M::MODE == AdaptMode::Full) as usize;
        let keep_u2 = !self.arena.view().psi_u2.is_empty() && self.psi_recorded;
        // Without Ψ_x, the Disc and Scores passes run G first.
        let g_pass = if self.psi_recorded {
            0
        } else {
            h * zin + f * h
        };
        // The transposed products (gradients) stay f32: with int8 activations they cost
        // about twice as much per multiply-add as the forward ones (`docs/kernels.md`).
        let tw = 1 + self.w.get(TensorId::GenW2).int8_activations() as usize;
        let per = match phase {
            // D on real, fake, interpolate and W1 g; its input gradient; W1's outer products.
            Phase::Disc => f * dh * (4 + tw * (1 + 3 * full)) + g_pass,
            Phase::Scores => f * dh + g_pass,
            Phase::Backward => {
                h * zin
                    + f * dh
                    + f * h * !keep_u2 as usize
                    + tw * (f * dh + f * h * (1 + full) + full * h * zin)
            }
            Phase::Head => d.lstm_hidden * NUM_ACTIONS * 2,
            Phase::Done => 0,
        };
        // With zero noise (and D) every entry shares one z_t: the backward pass is one
        // group, one pass of G and D for all of Ψ, run in two halves (`split_backward`).
        if phase == Phase::Backward && self.split_backward() {
            return per as u64;
        }
        (per * nb) as u64
    }

    /// With zero noise and D, Ψ's entries form one group of the backward pass, which runs
    /// as two slices (`inner::shared_backward_half`): G's and D's forward part, then G's
    /// backward pass.
    fn split_backward(&self) -> bool {
        self.cfg.model.noise == NoiseMode::Zero && self.cfg.model.emd == Emd::Discriminator
    }

    /// Estimated multiply-adds of the first half of a split backward pass (the rest of
    /// [`Navigator::slice_cost`]'s `Backward` is the second).
    fn backward_first_half_cost(&self) -> u64 {
        let d = self.w.dims;
        let (f, dh, h, zin) = (d.feat, d.disc_hidden, d.gen_hidden, d.noise + d.attr);
        let keep_u2 = !self.arena.view().psi_u2.is_empty() && self.psi_recorded;
        let tw = 1 + self.w.get(TensorId::GenW2).int8_activations() as usize;
        (h * zin + f * dh + f * h * !keep_u2 as usize + tw * f * dh) as u64
    }

    /// Upper bound of the update's estimated work, from the phase `u` starts in.
    fn cost_bound(&self, u: &Update) -> u64 {
        let n = self.n_buf;
        let mut c = u.disc_steps as u64 * self.slice_cost(Phase::Disc, n);
        c += self.slice_cost(Phase::Scores, n);
        if !self.cfg.model.inner_rule.head_only {
            c += self.slice_cost(Phase::Backward, n);
        }
        c + self.slice_cost(Phase::Head, n)
    }

    /// Upper bound of the slices of the pending update, in all.
    pub(super) fn slice_bound(&self) -> u32 {
        let Some(u) = self.upd else { return 0 };
        let per = self.n_buf.div_ceil(self.arena.b) as u32;
        let back = if self.cfg.model.inner_rule.head_only {
            0
        } else if self.split_backward() {
            per.max(2)
        } else {
            per
        };
        u.disc_steps * per + per + back + 1
    }

    /// One slice of the pending update: one batch of entries of its current phase (and the
    /// phase's step when the batch is its last).
    pub(super) fn run_slice(&mut self) -> Result<()> {
        let Some(mut u) = self.upd else {
            return Ok(());
        };
        let n = self.n_buf;
        let b = self.arena.b;
        let (t0, t1) = (u.t, (u.t + b).min(n));
        let phase = u.phase;
        let split = phase == Phase::Backward && self.split_backward();
        let cost = if split {
            let first = self.backward_first_half_cost();
            let all = self.slice_cost(phase, n);
            if u.half {
                all.saturating_sub(first)
            } else {
                first
            }
        } else {
            self.slice_cost(phase, t1 - t0)
        };
        u.done = u.done.saturating_add(cost);
        u.slices += 1;
        match phase {
            Phase::Disc => {
                if t0 == 0 {
                    u.report.ld = LdValue::default();
                }
                u.report.ld = self.disc_gradient(t0, t1, u.report.ld, u.forked)?;
                u.t = t1;
                if t1 >= n {
                    self.finish_disc_gradient();
                    u.disc_ok = self.ascend_disc(u.report.ld.loss);
                    u.disc_done += 1;
                    u.t = 0;
                    if !u.disc_ok || u.disc_done >= u.disc_steps {
                        u.phase = Phase::Scores;
                    }
                }
            }
            Phase::Scores => {
                if let Some(loss) = self.adapt_scores(t0, t1, u.use_d)? {
                    u.report.adapt_loss = loss;
                    u.t = 0;
                    u.phase = if self.cfg.model.inner_rule.head_only {
                        Phase::Head
                    } else {
                        Phase::Backward
                    };
                } else {
                    u.t = t1;
                }
            }
            Phase::Backward => {
                if split {
                    self.score_backward_half(!u.half)?;
                    u.t = if u.half { n } else { 0 };
                    u.half = !u.half;
                } else {
                    u.t = self.score_backward(t0, u.use_d)?;
                }
                if u.t >= n {
                    u.t = 0;
                    u.phase = Phase::Head;
                }
            }
            Phase::Head => {
                self.head_gradient()?;
                u.phase = Phase::Done;
            }
            Phase::Done => {}
        }
        self.upd = Some(u);
        Ok(())
    }

    /// Line 20 and the end of the update: the descent step of θ_i and φ_i (or its
    /// rollback), the counters, Ψ emptied. The update must be complete.
    pub(super) fn commit_update(&mut self) -> Result<()> {
        let Some(u) = self.upd.take() else {
            return Ok(());
        };
        if u.phase != Phase::Done {
            self.upd = Some(u);
            return Err(Error::UpdateNotReady {
                slices_left: self.slices_left(),
            });
        }
        let mut report = u.report;
        report.disc_applied = u.use_d && u.disc_ok;
        // Line 20: the descent step of θ_i and φ_i.
        let adapt_ok = self.descend_adapted(report.adapt_loss);
        report.adapt_applied = adapt_ok;
        let rolled = (!u.disc_ok) as u32 + (!adapt_ok) as u32;
        let c = &mut self.counters;
        c.rollbacks = c.rollbacks.saturating_add(rolled);
        c.total_rollbacks = c.total_rollbacks.saturating_add(rolled as u64);
        c.adaptations = c.adaptations.saturating_add(1);
        c.total_adaptations = c.total_adaptations.saturating_add(1);
        self.x_valid = false;
        self.fuse_blocks = None;
        self.last = report;
        self.n_buf = 0;
        Ok(())
    }
    /// Records the step's x_t in Ψ_x (and G's pre-gain output in Ψ_u2, where Ψ keeps it) as
    /// entry `n`, and whether all of Ψ now holds its entries' features. θ changes only in the
    /// inner update and in [`Navigator::reset`], and both empty Ψ, so every entry's x_t
    /// was made by G at the θ of the next inner update: the bits a regeneration by
    /// [`crate::adapt::inner::x_rows`] would give (the batched kernels give every row the
    /// batch-1 bits). Not when the caller fixed x_t ([`Navigator::fix_generated_feature`]):
    /// Ψ_x is then G's output, regenerated.
    pub(super) fn record_psi_features(&mut self, n: usize) {
        let f = self.w.dims.feat;
        let r = self.arena.ram();
        let keep_u2 = !r.psi_u2.is_empty();
        if self.cfg.model.noise == NoiseMode::Zero {
            // One row for every entry: the first entry's (G's output is the same until the
            // commit, which empties Ψ).
            if n == 0 {
                let ok = !self.x_fixed && (!keep_u2 || self.u2_valid);
                if ok {
                    r.psi_x[..f].copy_from_slice(r.x);
                    if keep_u2 {
                        r.psi_u2[..f].copy_from_slice(r.u2);
                    }
                }
                self.psi_recorded = ok;
            }
            return;
        }
        let ok = !self.lean && !self.x_fixed && (!keep_u2 || self.u2_valid);
        if ok {
            r.psi_x[n * f..(n + 1) * f].copy_from_slice(r.x);
            if keep_u2 {
                r.psi_u2[n * f..(n + 1) * f].copy_from_slice(r.u2);
            }
        }
        self.psi_recorded = (n == 0 || self.psi_recorded) && ok;
    }

    /// ∇_ω L_D (Eq. 1, WGAN-GP) over the entries `t0 .. t1` of Ψ added into D's gradient
    /// buffers (zeroed, with fresh interpolation weights ε for all of Ψ, at `t0 = 0`),
    /// continuing the sums `ld`; returns them. Ψ_x must be current.
    fn disc_gradient(
        &mut self,
        t0: usize,
        t1: usize,
        ld: LdValue,
        forked: bool,
    ) -> Result<LdValue> {
        if t0 == 0 {
            self.start_disc_gradient(forked);
        }
        let n = self.n_buf;
        let d = self.w.dims;
        let cfg = self.cfg;
        let (f, zd) = (d.feat, d.noise);
        let w = self.w;
        let (recorded, lean) = (self.psi_recorded, self.lean);
        let zero = self.cfg.model.noise == NoiseMode::Zero;
        let Ram {
            gen1,
            gen2,
            disc1,
            disc_w2,
            disc_b2,
            g_disc1,
            g_disc_w2,
            g_disc_b2,
            psi_s,
            psi_sc,
            psi_z,
            psi_x,
            attr,
            eps,
            iw,
            ..
        } = &mut self.arena.ram();
        let disc = disc_view(disc1, disc_w2, disc_b2, &w)?;
        let mut grads = DiscGrads {
            l1: g_disc1.grads(),
            w2: g_disc_w2,
            b2: &mut g_disc_b2[0],
        };
        let inv = 1.0 / n as f32;
        // Unless the steps recorded Ψ_x, the batch's x_t regenerated (into `mix`, then
        // swapped with `dpre2`, G's backward scratch); with Footprint::Minimal its s_t read
        // back into `u2` (G's pre-gain scratch, free once G ran). L_D's pass uses neither.
        let (nb, hf) = (t1 - t0, f.div_ceil(2));
        let mut xs: &mut [f32] = &mut [];
        let mut sb: &mut [f32] = &mut [];
        // With zero noise Ψ's one x_t, copied for a batch of more than one entry into `dpre2`.
        let mut xz: &mut [f32] = &mut [];
        let r = (|| {
            let fake: &[f32] = if recorded && zero {
                if nb > 1 {
                    xz = core::mem::take(&mut iw.dpre2);
                }
                inner::x_rows(psi_x, true, f, (t0, nb), xz)?
            } else if recorded {
                &psi_x[t0 * f..t1 * f]
            } else {
                let gen = gen_view(gen1, gen2, &w)?;
                inner::generate_mix(&gen, &psi_z[t0 * zd..t1 * zd], attr, nb, iw)?;
                core::mem::swap(&mut iw.mix, &mut iw.dpre2);
                xs = core::mem::take(&mut iw.dpre2);
                xs.get(..nb * f).ok_or(ARENA_TOO_SMALL)?
            };
            let real: &[f32] = if lean {
                sb = core::mem::take(&mut iw.u2);
                let s = sb.get_mut(..nb * f).ok_or(ARENA_TOO_SMALL)?;
                for (i, o) in s.chunks_exact_mut(f).enumerate() {
                    let t = t0 + i;
                    psi_load(&psi_s[t * hf..(t + 1) * hf], psi_sc[t], o);
                }
                s
            } else {
                &psi_s[t0 * f..t1 * f]
            };
            inner::ld_grad_sum_from(
                &disc,
                real,
                fake,
                &eps[t0..t1],
                cfg.ld(),
                inv,
                iw,
                &mut grads,
                ld,
            )
        })();
        if !xs.is_empty() {
            iw.dpre2 = core::mem::take(&mut iw.mix);
            iw.mix = xs;
        }
        if !xz.is_empty() {
            iw.dpre2 = xz;
        }
        if iw.u2.is_empty() {
            iw.u2 = sb;
        }
        r
    }

    /// D's gradient buffers zeroed and fresh interpolation weights ε for all of Ψ (from the
    /// update's own generator when `forked`): the start of [`Navigator::disc_gradient`].
    fn start_disc_gradient(&mut self, forked: bool) {
        let n = self.n_buf;
        let Ram {
            g_disc1,
            g_disc_w2,
            g_disc_b2,
            eps,
            ..
        } = &mut self.arena.ram();
        g_disc1.zero();
        g_disc_w2.fill(0.0);
        g_disc_b2.fill(0.0);
        let rng = if forked {
            &mut self.upd_rng
        } else {
            &mut self.rng
        };
        for e in eps[..n].iter_mut() {
            *e = uniform(rng);
        }
    }

    /// The mean over Ψ of D's gradient (after its last entry).
    fn finish_disc_gradient(&mut self) {
        let inv = 1.0 / self.n_buf as f32;
        let Ram {
            g_disc1,
            g_disc_w2,
            g_disc_b2,
            ..
        } = &mut self.arena.ram();
        g_disc1.scale(inv);
        g_disc_w2
            .iter_mut()
            .chain(g_disc_b2.iter_mut())
            .for_each(|v| *v *= inv);
    }
    /// Ascent ω ← ω + α1 ∇_ω L_D, only if everything stays finite and `|L_D|` within the
    /// loss bound; returns whether it was applied.
    fn ascend_disc(&mut self, loss: f32) -> bool {
        let cfg = self.cfg;
        let Ram {
            disc1,
            disc_w2,
            disc_b2,
            g_disc1,
            g_disc_w2,
            g_disc_b2,
            ..
        } = &mut self.arena.ram();
        // Ascent: ω ← ω + α1 ∇_ω L_D, only if everything stays finite and bounded.
        let a1 = cfg.model.alpha_disc();
        let disc_ok = loss.is_finite()
            && libm::fabsf(loss) <= cfg.loss_bound
            && g_disc1.finite()
            && all_finite(g_disc_w2)
            && all_finite(g_disc_b2)
            && g_disc1.update_ok(disc1, a1)
            && ok_update(disc_w2, g_disc_w2, a1)
            && ok_update(disc_b2, g_disc_b2, a1);
        if disc_ok {
            g_disc1.apply(disc1, a1);
            axpy_inplace(disc_w2, g_disc_w2, a1);
            axpy_inplace(disc_b2, g_disc_b2, a1);
        }
        disc_ok
    }

    /// Pass 1 of L_ad (Eq. 3) for the entries `t0 .. t1` of Ψ (the gradient buffers of θ and
    /// φ zeroed at `t0 = 0`); after the last entry L_ad with its output gradients
    /// (`Some(loss)`). D scores the generated features (`use_d`), else their cosine
    /// similarity to the observations does (CosSim). Ψ_x must be current.
    fn adapt_scores(&mut self, t0: usize, t1: usize, use_d: bool) -> Result<Option<f32>> {
        let n = self.n_buf;
        let d = self.w.dims;
        let cfg = self.cfg;
        let (f, zd) = (d.feat, d.noise);
        let w = self.w;
        let (recorded, lean) = (self.psi_recorded, self.lean);
        let zero = self.cfg.model.noise == NoiseMode::Zero;
        let Ram {
            gen1,
            gen2,
            disc1,
            disc_w2,
            disc_b2,
            g_gen1,
            g_gen2,
            g_actor,
            z: z0,
            psi_s,
            psi_z,
            psi_p,
            psi_x,
            psi_u2,
            d: dvals,
            dd,
            dprobs,
            attr,
            iw,
            ..
        } = &mut self.arena.ram();
        if t0 == 0 {
            g_gen1.zero();
            g_gen2.zero();
            g_actor.zero();
        }
        let gen = gen_view(gen1, gen2, &w)?;
        let disc = disc_view(disc1, disc_w2, disc_b2, &w)?;
        // With zero noise one row of z (the step's, zero), x_t and `W2 h1` for every entry.
        let (shared, nr) = if zero { (true, 1) } else { (false, n) };
        let inp = inner::AdaptInputs {
            attr,
            zs: if zero { z0 } else { &psi_z[..n * zd] },
            xs: recorded.then(|| &psi_x[..nr * f]),
            u2s: (recorded && !psi_u2.is_empty()).then(|| &psi_u2[..nr * f]),
            obs: if lean { &[] } else { &psi_s[..n * f] },
            shared,
        };
        let outs = (
            &mut dvals[..n],
            &mut dd[..n],
            &mut dprobs[..n * NUM_ACTIONS],
        );
        let (disc, probs) = (use_d.then_some(&disc), &psi_p[..n * NUM_ACTIONS]);
        inner::adapt_scores_part(
            cfg.model.inner_rule.adapt_loss,
            &gen,
            disc,
            inp,
            probs,
            outs,
            iw,
            (t0, t1),
        )
    }

    /// Pass 2 of L_ad from entry `t` for one batch: θ's gradient (G's backward pass through D
    /// or the cosine) added into its buffers; returns the entry to continue from. With
    /// `head_only` θ takes no step (`descend_adapted`) and this pass is skipped: its gradient
    /// stays zero, the head's is the same bits.
    fn score_backward(&mut self, t: usize, use_d: bool) -> Result<usize> {
        let n = self.n_buf;
        let d = self.w.dims;
        let (f, zd) = (d.feat, d.noise);
        let w = self.w;
        let (recorded, lean) = (self.psi_recorded, self.lean);
        let zero = self.cfg.model.noise == NoiseMode::Zero;
        let Ram {
            gen1,
            gen2,
            disc1,
            disc_w2,
            disc_b2,
            g_gen1,
            g_gen2,
            z: z0,
            psi_s,
            psi_z,
            psi_x,
            psi_u2,
            dd,
            attr,
            iw,
            ..
        } = &mut self.arena.ram();
        let gen = gen_view(gen1, gen2, &w)?;
        let disc = disc_view(disc1, disc_w2, disc_b2, &w)?;
        // With zero noise one row of z (the step's, zero), x_t and `W2 h1` for every entry.
        let (shared, nr) = if zero { (true, 1) } else { (false, n) };
        let inp = inner::AdaptInputs {
            attr,
            zs: if zero { z0 } else { &psi_z[..n * zd] },
            xs: recorded.then(|| &psi_x[..nr * f]),
            u2s: (recorded && !psi_u2.is_empty()).then(|| &psi_u2[..nr * f]),
            obs: if lean { &[] } else { &psi_s[..n * f] },
            shared,
        };
        inner::score_backward_part(
            &gen,
            use_d.then_some(&disc),
            inp,
            &dd[..n],
            iw,
            (&mut g_gen1.grads(), &mut g_gen2.grads()),
            (t, 1),
        )
    }

    /// One half of pass 2 of L_ad with zero noise and D (`first`: G's and D's forward part;
    /// else G's backward pass into θ's gradient), see [`Navigator::split_backward`].
    fn score_backward_half(&mut self, first: bool) -> Result<()> {
        let n = self.n_buf;
        let f = self.w.dims.feat;
        let w = self.w;
        let lean = self.lean;
        let Ram {
            gen1,
            gen2,
            disc1,
            disc_w2,
            disc_b2,
            g_gen1,
            g_gen2,
            z: z0,
            psi_s,
            psi_x,
            psi_u2,
            dd,
            attr,
            iw,
            ..
        } = &mut self.arena.ram();
        let gen = gen_view(gen1, gen2, &w)?;
        let disc = disc_view(disc1, disc_w2, disc_b2, &w)?;
        let inp = inner::AdaptInputs {
            attr,
            zs: z0,
            xs: Some(&psi_x[..f]),
            u2s: (!psi_u2.is_empty()).then(|| &psi_u2[..f]),
            obs: if lean { &[] } else { &psi_s[..n * f] },
            shared: true,
        };
        inner::shared_backward_half(
            &gen,
            &disc,
            inp,
            &dd[..n],
            iw,
            (&mut g_gen1.grads(), &mut g_gen2.grads()),
            first,
        )
    }

    /// The actor head's gradient of L_ad (line 19) from the output gradients of pass 1.
    fn head_gradient(&mut self) -> Result<()> {
        let n = self.n_buf;
        let lh = self.w.dims.lstm_hidden;
        let w = self.w;
        let Ram {
            actor,
            g_actor,
            psi_p,
            psi_h,
            dprobs,
            dlogits,
            actor_u,
            ..
        } = &mut self.arena.ram();
        let head = actor.view(w.get(TensorId::ActorW))?;
        actor_head_grad(
            &head,
            &psi_p[..n * NUM_ACTIONS],
            &dprobs[..n * NUM_ACTIONS],
            &psi_h[..n * lh],
            n,
            dlogits,
            actor_u,
            &mut g_actor.grads(),
        )
    }
    /// Line 20: θ_i, φ_i ← θ_i, φ_i − α2 ∇ (or the normalised step of [`StepRule`]), only if
    /// everything stays finite and `|L_ad|` within the loss bound; returns whether it was
    /// applied.
    fn descend_adapted(&mut self, loss: f32) -> bool {
        let cfg = self.cfg;
        let Ram {
            gen1,
            gen2,
            actor,
            g_gen1,
            g_gen2,
            g_actor,
            ..
        } = &mut self.arena.ram();
        // −α2 / ‖g‖ for a step of length α2 (none for a zero gradient)
        let unit = |sq: f32| {
            let norm = libm::sqrtf(sq);
            if norm > 0.0 {
                -cfg.model.inner_lr / norm
            } else {
                0.0
            }
        };
        // With `head_only` θ takes no step and has no say in the step's length.
        let theta = !cfg.model.inner_rule.head_only;
        let theta_sq = || {
            if theta {
                g_gen1.sum_sq() + g_gen2.sum_sq()
            } else {
                0.0
            }
        };
        let (a2, a2_phi) = match cfg.model.inner_rule.step_rule {
            StepRule::Gradient => (-cfg.model.inner_lr, -cfg.model.inner_lr),
            StepRule::Normalized => {
                let a = unit(theta_sq() + g_actor.sum_sq());
                (a, a)
            }
            StepRule::PerGroup => (unit(theta_sq()), unit(g_actor.sum_sq())),
        };
        let theta_ok = || {
            g_gen1.finite()
                && g_gen2.finite()
                && g_gen1.update_ok(gen1, a2)
                && g_gen2.update_ok(gen2, a2)
        };
        let adapt_ok = loss.is_finite()
            && libm::fabsf(loss) <= cfg.loss_bound
            && (!theta || theta_ok())
            && g_actor.finite()
            && g_actor.update_ok(actor, a2_phi);
        if adapt_ok {
            if theta {
                g_gen1.apply(gen1, a2);
                g_gen2.apply(gen2, a2);
            }
            g_actor.apply(actor, a2_phi);
        }
        adapt_ok
    }
}
