//! One control step: the generator, the policy, the action, Ψ's entry, and the in-step slices of
//! an inner update.

use crate::error::{check_len, Error, Result};
use crate::navigator::arena::Piece;
use crate::navigator::config::{select_action, Mode, Schedule, StepOutput};
use crate::navigator::psi::psi_store;
use crate::navigator::state::{draw_noise, Navigator, Phase, StepMarks, NUMERICAL_PROBS};
use crate::navigator::weights::{gen_view, policy_view, same_storage};
use crate::nets::generator::GeneratorCache;
use crate::nets::policy::{FuseTerms, PolicyCache, PolicyInput};
use crate::nn::activation::{all_finite, leaky_relu_inplace, sigmoid_inplace};
use crate::nn::dense::gain_bias;
use crate::nn::matrix::MatRef;
use crate::spec::preset::Dims;
use crate::spec::schema::NoiseMode;
use crate::spec::schema::TensorId;
use crate::{Action, NUM_ACTIONS};

impl<'w, M: Mode, const K: usize, S: AsRef<[f32]> + AsMut<[f32]>> Navigator<'w, M, K, S> {
    /// One control step on the observation embedding `obs` (`feat` floats) and, for policies
    /// with a PS input, the PS prediction `ps` (`ps` floats; pass `&[]` otherwise). For a
    /// model with a spatial map use [`Navigator::step_map`]. An `Err` changes nothing a
    /// later call reads (see [`Navigator::step_map`]'s Errors).
    pub fn step(&mut self, obs: &[f32], ps: &[f32]) -> Result<StepOutput> {
        self.step_map(obs, &[], ps)
    }

    /// One control step with the spatial observation map `map` (`map_cells x feat` floats,
    /// cell-major, see [`Dims::map_len`]; empty for a model without a map) besides the
    /// pooled embedding `obs` (on a real camera: the map's average over cells, as the
    /// reference average-pools the ResNet map for D) and the PS input `ps`.
    ///
    /// The same as [`Navigator::begin_step`], the policy's trunk on this navigator's state,
    /// then [`Navigator::finish_step`].
    ///
    /// # Errors
    /// An `Err` changes nothing a later call reads: the counters, Ψ, the LSTM state, the
    /// previous probabilities, the adapted and persistent parameters, the pending inner
    /// update and the random generator are as before the call, so the next steps give the
    /// bits of a navigator that never saw it. The inputs are checked before anything is
    /// written ([`Error::Config`], [`Error::UpdateNotReady`], [`Error::Shape`],
    /// [`Error::NonFiniteInput`]); a step whose probabilities or value come out non-finite
    /// ([`Error::NumericalFault`], e.g. an observation entry of 3e38) is undone before
    /// anything of it is committed. Only the scratch of the refused step's own G pass is left
    /// behind, in the diagnostic views [`Navigator::generated_feature`],
    /// [`Navigator::noise`] and [`Navigator::generator_activations`] (the next step
    /// overwrites it). Nothing has to be done to recover: step again with a good input.
    pub fn step_map(&mut self, obs: &[f32], map: &[f32], ps: &[f32]) -> Result<StepOutput> {
        self.step_with(obs, map, None, ps)
    }

    /// What a step changes before its outputs are known to be finite.
    fn marks(&self) -> StepMarks {
        StepMarks {
            rng: self.rng.clone(),
            begun: self.begun,
            g_pending: self.g_pending,
            x_valid: self.x_valid,
            u2_valid: self.u2_valid,
            fuse_blocks: self.fuse_blocks,
        }
    }

    /// A refused step: puts back what [`Navigator::marks`] recorded and returns the error
    /// (`None`: the outputs were not finite).
    #[cold]
    #[inline(never)]
    fn refused(&mut self, m: StepMarks, e: Option<Error>) -> Error {
        self.rng = m.rng;
        self.begun = m.begun;
        self.g_pending = m.g_pending;
        self.x_valid = m.x_valid;
        self.u2_valid = m.u2_valid;
        self.fuse_blocks = m.fuse_blocks;
        e.unwrap_or(NUMERICAL_PROBS)
    }

    /// [`Navigator::step_map`] with the map as the camera quantised it: `map[j] * scale` is
    /// the value of feature `j` (`map_cells x feat` u8 codes, cell-major, one `scale` for
    /// the map, finite and positive). On the integer path (an int8-activation blob) the
    /// map's cells are quantised straight from the codes, with no f32 pass over the map
    /// ([`crate::nn::qkernel::cell_layer_int8_u8`]); otherwise each cell is expanded to f32
    /// (`map[j] as f32 * scale`) as it is used. Its results are its own (the integer path
    /// quantises the codes, not their f32 values), the same on every target.
    pub fn step_map_u8(
        &mut self,
        obs: &[f32],
        map: &[u8],
        scale: f32,
        ps: &[f32],
    ) -> Result<StepOutput> {
        if !scale.is_finite() {
            return Err(Error::NonFiniteInput { what: "map scale" });
        }
        if scale <= 0.0 {
            return Err(Error::Config {
                what: "step_map_u8: the map's scale must be positive",
            });
        }
        self.step_with(obs, &[], Some((map, scale)), ps)
    }

    /// [`Navigator::step_map`] (`map_u8` `None`) and [`Navigator::step_map_u8`] (the map as
    /// u8 codes with their scale, `map` empty): the checks and G (line 7), the policy (line
    /// 8), then the commit of the step, or its refusal.
    #[inline(never)]
    fn step_with(
        &mut self,
        obs: &[f32],
        map: &[f32],
        map_u8: Option<(&[u8], f32)>,
        ps: &[f32],
    ) -> Result<StepOutput> {
        let marks = self.marks();
        let map_len = map_u8.map_or(map.len(), |(m, _)| m.len());
        // (Its errors come from checks made before anything is written.)
        self.begin_step_with(obs, (map, map_len), ps)?;
        // Line 8: the policy (trunk and heads in one pass).
        match self.run_policy(obs, map, map_u8) {
            Ok(v) if self.outputs_finite(v) => self.commit_checked(obs, v),
            r => Err(self.refused(marks, r.err())),
        }
    }

    /// Lines 5-7 of a step, for a host that runs the policies of many navigators as one
    /// batch: checks the inputs, keeps `ps` and generates x_t = G_θi(SE(y), z_t). The
    /// policy's inputs are then [`Navigator::generated_feature`], [`Navigator::attr`],
    /// [`Navigator::prev_probs`], `ps` and the state [`Navigator::hidden_state`] /
    /// [`Navigator::cell_state`]; run the policy's trunk (fusion and LSTM, whose weights no
    /// navigator adapts) on them and pass its new `(h, c)` to [`Navigator::finish_step`], with
    /// the same `obs`. `begin_step` again before `finish_step` draws a new x_t. An `Err`
    /// comes from the checks of the inputs and the call order, made before anything is
    /// written: nothing changed.
    pub fn begin_step(&mut self, obs: &[f32], map: &[f32], ps: &[f32]) -> Result<()> {
        self.begin_step_with(obs, (map, map.len()), ps)
    }

    /// [`Navigator::begin_step`] with a map of `map_len` values, of which `map` (f32) is
    /// checked for finite values (empty when the map comes as u8 codes).
    fn begin_step_with(
        &mut self,
        obs: &[f32],
        (map, map_len): (&[f32], usize),
        ps: &[f32],
    ) -> Result<()> {
        self.begin_checks(obs, (map, map_len), ps)?;
        // Line 7: x_t = G_θi(SE(y), z_t) (unless the caller fixed x_t for this episode).
        match self.cfg.model.noise {
            _ if self.x_fixed => {}
            NoiseMode::Gaussian => {
                draw_noise(&mut self.rng, self.arena.ram().z);
                self.run_generator(None)?;
            }
            NoiseMode::Zero => {
                if !self.x_valid {
                    self.arena.ram().z.fill(0.0);
                    self.run_generator(None)?;
                    self.x_valid = true;
                }
            }
        }
        self.g_pending = false;
        self.begun = true;
        Ok(())
    }

    /// The checks of a step's inputs, and `ps` into RAM.
    fn begin_checks(
        &mut self,
        obs: &[f32],
        (map, map_len): (&[f32], usize),
        ps: &[f32],
    ) -> Result<()> {
        if !self.ready {
            return Err(Error::Config {
                what: "call reset() before step()",
            });
        }
        if let Some(u) = self.upd {
            let d = self.cfg.model.inner_rule.commit_delay;
            if u.window >= d {
                // Only reachable with `Schedule::Manual`: the others commit at the window's end.
                return Err(Error::Config {
                    what: "commit window over: call adapt_now() before step() (Schedule::Manual)",
                });
            }
            if self.cfg.schedule == Schedule::Background
                && u.window + 1 == d
                && u.phase != Phase::Done
            {
                return Err(Error::UpdateNotReady {
                    slices_left: self.slices_left(),
                });
            }
        } else if self.n_buf >= K {
            // Only reachable with `Schedule::Manual` (`Auto` empties Ψ when it fills).
            return Err(Error::Config {
                what: "buffer full: call adapt_now() or clear_buffer() before step() (Schedule::Manual)",
            });
        }
        let d = self.w.dims;
        check_len("step.obs", d.feat, obs.len())?;
        check_len("step.ps", d.ps, ps.len())?;
        check_len("step.map", d.map_len(), map_len)?;
        if !all_finite(obs) {
            return Err(Error::NonFiniteInput { what: "obs" });
        }
        if !all_finite(map) {
            return Err(Error::NonFiniteInput { what: "map" });
        }
        if !all_finite(ps) {
            return Err(Error::NonFiniteInput { what: "ps" });
        }
        self.arena.ram().ps.copy_from_slice(ps);
        Ok(())
    }

    /// True when this navigator's G shares its weight matrices with every navigator over the
    /// same blob, so that [`Navigator::generate_batch`] can run it for many of them as one
    /// batch: the Efficient mode (only G's gains and biases are adapted), Gaussian noise, x_t
    /// not fixed by the caller.
    pub fn defers_generator(&self) -> bool {
        let r = self.arena.view();
        let (g1, g2) = (&r.gen1, &r.gen2);
        self.cfg.model.noise == NoiseMode::Gaussian
            && !self.x_fixed
            && g1.w.is_empty()
            && g2.w.is_empty()
            && !g1.gain.is_empty()
            && !g2.gain.is_empty()
    }

    /// [`Navigator::begin_step`] without line 7 when [`Navigator::defers_generator`]: the
    /// checks and the draw of z_t, after which x_t is pending until
    /// [`Navigator::generate_batch`] runs G for this navigator (with others). Returns whether
    /// G is pending; otherwise this was `begin_step` itself. Either way the step goes on as
    /// after `begin_step`, with the same bits.
    pub fn begin_step_defer_g(&mut self, obs: &[f32], map: &[f32], ps: &[f32]) -> Result<bool> {
        if !self.defers_generator() {
            self.begin_step(obs, map, ps)?;
            return Ok(false);
        }
        self.begin_checks(obs, (map, map.len()), ps)?;
        draw_noise(&mut self.rng, self.arena.ram().z);
        self.g_pending = true;
        self.begun = true;
        Ok(true)
    }

    /// Floats of the scratch [`Navigator::generate_batch`] needs for `n` navigators.
    pub fn generate_batch_scratch_len(dims: &Dims, n: usize) -> usize {
        let per = dims.noise + dims.attr + 2 * dims.gen_hidden + dims.feat;
        n.saturating_mul(per)
    }

    /// Line 7 for the navigators `navs[i]`, `i` in `who`, whose steps were begun with
    /// [`Navigator::begin_step_defer_g`] (G pending): x_t = G_θi(SE(y), z_t) for all of them,
    /// `W1 [z; a]` and `W2 h1` as one batch each through the batched kernels (the navigators
    /// share W1 and W2), each navigator's own gains and biases after them. Every navigator
    /// gets the bits its `begin_step` computes alone: the batched kernels give every vector
    /// the bits of the batch-1 kernels, and the element-wise steps are those of
    /// [`Dense::forward`](crate::nn::dense::Dense::forward) with a gain. `scratch` holds at least
    /// [`Navigator::generate_batch_scratch_len`] floats. Errors (nothing changed) when a
    /// navigator has no pending G, an index repeats or is out of range, or the navigators do
    /// not share G's weights.
    pub fn generate_batch(navs: &mut [Self], who: &[usize], scratch: &mut [f32]) -> Result<()> {
        let Some(&i0) = who.first() else {
            return Ok(());
        };
        let first = navs.get(i0).ok_or(Error::Config {
            what: "generate_batch: navigator index out of range",
        })?;
        let d = first.w.dims;
        let (nz, na, nh, nf) = (d.noise, d.attr, d.gen_hidden, d.feat);
        let n = who.len();
        let need = Self::generate_batch_scratch_len(&d, n);
        if scratch.len() < need {
            return Err(Error::Config {
                what: "generate_batch: scratch too short (generate_batch_scratch_len)",
            });
        }
        let (w1, w2) = (first.w.get(TensorId::GenW1), first.w.get(TensorId::GenW2));
        for (j, &i) in who.iter().enumerate() {
            let nav = navs.get(i).ok_or(Error::Config {
                what: "generate_batch: navigator index out of range",
            })?;
            if !nav.g_pending || who[..j].contains(&i) {
                return Err(Error::Config {
                    what:
                        "generate_batch: every navigator once, each begun with begin_step_defer_g",
                });
            }
            let same = |a: MatRef<'_>, b: MatRef<'_>| {
                a.rows() == b.rows() && a.cols() == b.cols() && same_storage(&a, &b)
            };
            if nav.w.dims != d
                || !same(nav.w.get(TensorId::GenW1), w1)
                || !same(nav.w.get(TensorId::GenW2), w2)
            {
                return Err(Error::Config {
                    what: "generate_batch: the navigators do not share G's weights",
                });
            }
        }
        let (zs, rest) = scratch[..need].split_at_mut(n * nz);
        let (attrs, rest) = rest.split_at_mut(n * na);
        let (u1s, rest) = rest.split_at_mut(n * nh);
        let (h1s, u2s) = rest.split_at_mut(n * nh);
        for (j, &i) in who.iter().enumerate() {
            let r = navs[i].arena.view();
            zs[j * nz..(j + 1) * nz].copy_from_slice(r.z);
            attrs[j * na..(j + 1) * na].copy_from_slice(r.attr);
        }
        // Layer 1: u1 = W1 [z; a] (Dense::forward with a gain: u from zero, then g u + b).
        u1s.fill(0.0);
        crate::nn::batch::matmul_acc(&w1, &[&*zs, &*attrs], &[nz, na], n, u1s)?;
        for (j, &i) in who.iter().enumerate() {
            let r = navs[i].arena.ram();
            r.u1.copy_from_slice(&u1s[j * nh..(j + 1) * nh]);
            gain_bias(r.h1, r.u1, r.gen1.gain, r.gen1.b)?;
            leaky_relu_inplace(r.h1);
            h1s[j * nh..(j + 1) * nh].copy_from_slice(r.h1);
        }
        // Layer 2: u2 = W2 h1, x = sigmoid(g u2 + b).
        u2s.fill(0.0);
        crate::nn::batch::matmul_acc(&w2, &[&*h1s], &[nh], n, u2s)?;
        for (j, &i) in who.iter().enumerate() {
            let nav = &mut navs[i];
            let r = nav.arena.ram();
            r.u2.copy_from_slice(&u2s[j * nf..(j + 1) * nf]);
            gain_bias(r.x, r.u2, r.gen2.gain, r.gen2.b)?;
            sigmoid_inplace(r.x);
            nav.u2_valid = true;
            nav.g_pending = false;
        }
        Ok(())
    }

    /// The rest of a step begun with [`Navigator::begin_step`], from the policy trunk's new
    /// LSTM state `h`, `c` (`lstm_hidden` each) computed by the caller: the actor head (this
    /// navigator's, adapted) and the critic, the action, Ψ and, every k steps, the inner
    /// update. Bit for bit [`Navigator::step_map`] when `(h, c)` are the trunk's output on
    /// this navigator's inputs (the batched trunk gives each row exactly those bits). An
    /// `Err` (a bad length, a non-finite `h`/`c`, or non-finite probabilities from them:
    /// [`Error::NumericalFault`]) commits nothing and leaves the step begun: `finish_step`
    /// again with a good state finishes it as if the refused call had not happened.
    pub fn finish_step(&mut self, obs: &[f32], h: &[f32], c: &[f32]) -> Result<StepOutput> {
        if !self.begun {
            return Err(Error::Config {
                what: "call begin_step() before finish_step()",
            });
        }
        if self.g_pending {
            return Err(Error::Config {
                what: "x_t is pending: call generate_batch() after begin_step_defer_g()",
            });
        }
        let d = self.w.dims;
        check_len("finish_step.obs", d.feat, obs.len())?;
        check_len("finish_step.h", d.lstm_hidden, h.len())?;
        check_len("finish_step.c", d.lstm_hidden, c.len())?;
        if !all_finite(h) || !all_finite(c) {
            return Err(Error::NonFiniteInput { what: "h, c" });
        }
        let r = self.arena.ram();
        r.h.copy_from_slice(h);
        r.c.copy_from_slice(c);
        let biases = [&*r.fuse_b, &*r.lstm_b, &*r.critic_b, &*r.cell_b];
        let actor = r.actor.view(self.w.get(TensorId::ActorW))?;
        let policy = policy_view(&self.w, biases, actor)?;
        let mut value = [0.0f32];
        policy.heads(1, r.h, r.actor_u, r.logits, r.probs, &mut value)?;
        self.commit_step(obs, value[0])
    }

    /// Lines 8-20 after the policy's outputs are in place: the action, Ψ, the state and, every
    /// k steps, the inner update. Its callers have checked `obs` (`feat` floats).
    fn commit_step(&mut self, obs: &[f32], value: f32) -> Result<StepOutput> {
        self.check_outputs(value)?;
        self.commit_checked(obs, value)
    }

    /// [`Error::NumericalFault`] unless the step's probabilities and `value` are finite.
    fn check_outputs(&self, value: f32) -> Result<()> {
        if self.outputs_finite(value) {
            Ok(())
        } else {
            Err(NUMERICAL_PROBS)
        }
    }

    /// True when the step's probabilities and `value` are finite.
    fn outputs_finite(&self, value: f32) -> bool {
        all_finite(self.arena.view().probs) && value.is_finite()
    }

    /// [`Navigator::commit_step`] after [`Navigator::check_outputs`].
    fn commit_checked(&mut self, obs: &[f32], value: f32) -> Result<StepOutput> {
        self.begun = false;
        let d = self.w.dims;
        let action = self.select();
        // Lines 11-13: record in Ψ (not in the commit window of a delayed update).
        let window = self.upd.is_some();
        if !window {
            let (f, z, lh, n) = (d.feat, d.noise, d.lstm_hidden, self.n_buf);
            let (compact, lean) = (self.cfg.model.compact_psi, self.lean);
            let r = self.arena.ram();
            if compact {
                let w = if lean { f.div_ceil(2) } else { f };
                psi_store(obs, &mut r.psi_s[n * w..(n + 1) * w], r.psi_sc.get_mut(n));
            } else {
                r.psi_s[n * f..(n + 1) * f].copy_from_slice(obs);
            }
            if self.cfg.model.noise == NoiseMode::Gaussian {
                r.psi_z[n * z..(n + 1) * z].copy_from_slice(r.z);
            }
            r.psi_p[n * NUM_ACTIONS..(n + 1) * NUM_ACTIONS].copy_from_slice(r.probs);
            r.psi_h[n * lh..(n + 1) * lh].copy_from_slice(r.h);
            self.record_psi_features(n);
            self.n_buf += 1;
        }
        let r = self.arena.ram();
        r.h_state.copy_from_slice(r.h);
        r.c_state.copy_from_slice(r.c);
        r.prev_probs.copy_from_slice(r.probs);
        let mut probs = [0.0f32; NUM_ACTIONS];
        probs.copy_from_slice(r.probs);
        self.counters.steps = self.counters.steps.saturating_add(1);
        self.counters.total_steps = self.counters.total_steps.saturating_add(1);
        // Lines 14-20: every k steps, the inner update; then empty Ψ. With a commit delay d
        // it starts here and commits at the end of the d-th step from now.
        let mut adapted = false;
        let (delay, sched) = (self.cfg.model.inner_rule.commit_delay, self.cfg.schedule);
        if let Some(mut u) = self.upd.filter(|_| window) {
            u.window += 1;
            self.upd = Some(u);
            if sched == Schedule::Auto {
                // This step's share of the work (all that is left at the last one).
                let target = if u.window >= delay {
                    u64::MAX
                } else {
                    u.total / delay as u64 * u.window as u64
                };
                while self
                    .upd
                    .is_some_and(|u| u.phase != Phase::Done && u.done < target)
                {
                    self.run_slice()?;
                }
            }
            if u.window >= delay && sched != Schedule::Manual {
                self.commit_update()?;
                adapted = true;
            }
        } else if self.n_buf == K {
            let can = self.can_adapt();
            match sched {
                Schedule::Manual => {
                    if can && delay > 0 {
                        self.start_update(true)?;
                    }
                }
                _ if can && delay == 0 => {
                    self.inner_update()?;
                    adapted = true;
                    self.n_buf = 0;
                }
                _ if can => self.start_update(true)?,
                _ => self.n_buf = 0,
            }
        }
        Ok(StepOutput {
            action,
            probs,
            value,
            adapted,
        })
    }

    /// G_θi(SE(y), z) at the current, possibly adapted θ, written into `out` (`feat`
    /// floats), leaving the step's own x_t and everything else the next step reads
    /// untouched (it runs in the navigator's G scratch). With the same `z` before and after
    /// the inner updates it shows how far they moved G (the firmware prints it). Call after
    /// [`Navigator::reset`].
    pub fn generator_output(&mut self, z: &[f32], out: &mut [f32]) -> Result<()> {
        if !self.ready {
            return Err(Error::Config {
                what: "call reset() before generator_output()",
            });
        }
        check_len("generator_output.z", self.w.dims.noise, z.len())?;
        check_len("generator_output.out", self.w.dims.feat, out.len())?;
        if !all_finite(z) {
            return Err(Error::NonFiniteInput { what: "z" });
        }
        self.run_generator(Some((z, out)))
    }

    /// Line 7, x_t = G_θi(SE(y), z_t), into the navigator's x_t (`None`) or, for
    /// [`Navigator::generator_output`], from a caller's noise into a caller's buffer.
    pub(super) fn run_generator(&mut self, z_out: Option<(&[f32], &mut [f32])>) -> Result<()> {
        // A probe leaves x_t alone but overwrites the activations of the step's G pass.
        self.u2_valid = z_out.is_none();
        let r = self.arena.ram();
        let gen = gen_view(&r.gen1, &r.gen2, &self.w)?;
        let (z, x) = match z_out {
            Some((z, x)) => (z, x),
            None => (&*r.z, &mut *r.x),
        };
        let mut cache = GeneratorCache {
            u1: r.u1,
            h1: r.h1,
            u2: r.u2,
            x,
        };
        gen.forward(z, r.attr, &mut cache)
    }

    /// Line 8, the policy on this step's inputs: the map as f32 values (`map`) or as u8
    /// codes with their scale (`map_u8`). With zero noise the fusion layer's terms of x_t
    /// and SE(y) are computed at the first step after a reset or a commit and kept
    /// (where the policy runs the integer path,
    /// [`crate::nets::policy::Policy::keeps_fuse_terms`]). Returns the value; the rest is in
    /// RAM.
    fn run_policy(
        &mut self,
        obs: &[f32],
        map: &[f32],
        map_u8: Option<(&[u8], f32)>,
    ) -> Result<f32> {
        let (d, zero) = (self.w.dims, self.cfg.model.noise == NoiseMode::Zero);
        let r = self.arena.ram();
        let biases = [&*r.fuse_b, &*r.lstm_b, &*r.critic_b, &*r.cell_b];
        let actor = r.actor.view(self.w.get(TensorId::ActorW))?;
        let policy = policy_view(&self.w, biases, actor)?;
        if zero && self.fuse_blocks.is_none() {
            self.fuse_blocks = policy.fuse_terms(r.x, r.attr, r.fuse_terms)?;
        }
        let terms = (self.fuse_blocks)
            .filter(|_| zero)
            .map(|b| FuseTerms::new(r.fuse_terms, d.embed, d.feat, b));
        let inp = PolicyInput {
            obs,
            feat: r.x,
            attr: r.attr,
            prev_probs: r.prev_probs,
            ps: r.ps,
            map,
        };
        let mut value = [0.0f32];
        let mut cache = PolicyCache {
            prod: r.prod,
            fuse: r.fuse,
            gates: r.gates,
            c: r.c,
            h: r.h,
            actor_u: r.actor_u,
            logits: r.logits,
            probs: r.probs,
            value: &mut value,
            cell: r.cell,
            cell_prod: r.cell_prod,
        };
        let (h, c) = (&*r.h_state, &*r.c_state);
        policy.forward_step(&inp, map_u8, terms.as_ref(), h, c, &mut cache)?;
        Ok(value[0])
    }

    fn select(&mut self) -> Action {
        select_action(self.cfg.selection, self.arena.view().probs, &mut self.rng)
    }
}
