//! The navigator's state, its construction, reset and accessors.

use core::marker::PhantomData;

use crate::adapt::inner::{self};
use crate::error::BlobError;
use crate::error::{check_len, Error, Result};
use crate::navigator::arena::{carve_check, Arena};
use crate::navigator::config::{AdaptReport, BufferView, Counters, Mode, NavConfig, Schedule};
use crate::navigator::memory::{adapt_batch_with, arena_len_with, AdaptMode, Footprint};
use crate::navigator::weights::{copy_mat, layer_view, policy_view, NavWeights};
use crate::nets::discriminator::Discriminator;
use crate::nets::generator::Generator;
use crate::nets::policy::{FuseBlocks, Policy};
use crate::nn::activation::all_finite;
use crate::rng::Xoshiro128;
use crate::spec::preset::Dims;
use crate::spec::schema::TensorId;
use crate::spec::schema::{Emd, NoiseMode};
use crate::NUM_ACTIONS;

/// The on-device GMAN navigator. `M` is the adaptation mode ([`Full`](crate::navigator::Full) or [`Efficient`](crate::navigator::Efficient)),
/// `K` the capacity of the buffer Ψ (the paper's k = 20), `S` the storage of its RAM arena:
/// whoever holds the floats, as long as it lends them as a slice (`AsRef<[f32]> +
/// AsMut<[f32]>`, always the same slice). The default, `&'w mut [f32]`, is an arena the
/// caller owns (a firmware's `static` array, the C API's caller-owned buffer); a host may
/// give the navigator its own (`Vec<f32>`, `Box<[f32]>`) and keep it as one value
/// ([`Navigator::into_storage`] gives the buffer back).
pub struct Navigator<'w, M: Mode, const K: usize, S = &'w mut [f32]> {
    pub(super) w: NavWeights<'w>,
    pub(super) cfg: NavConfig,
    pub(super) rng: Xoshiro128,
    pub(super) arena: Arena<S>,
    pub(super) counters: Counters,
    pub(super) n_buf: usize,
    pub(super) ready: bool,
    /// A step was begun ([`Navigator::begin_step`]) and not yet finished.
    pub(super) begun: bool,
    /// The step was begun with [`Navigator::begin_step_defer_g`] and its x_t is not yet
    /// generated ([`Navigator::generate_batch`]).
    pub(super) g_pending: bool,
    pub(super) x_valid: bool,
    pub(super) x_fixed: bool,
    /// The step's G activations (`u2` in [`crate::navigator::arena::Ram`]) are those of its
    /// x_t (a [`Navigator::generator_output`] probe reuses them as scratch).
    pub(super) u2_valid: bool,
    /// Every entry of Ψ recorded its x_t (and, where Ψ keeps it, G's pre-gain output) at its
    /// step, from G at the current θ: the inner update need not regenerate Ψ_x.
    pub(super) psi_recorded: bool,
    /// [`Footprint::Minimal`]: no Ψ_x (regenerated batch by batch), Ψ's observations packed.
    pub(super) lean: bool,
    /// With zero noise: the fusion layer's terms of x_t and SE(y) in `fuse_terms` are those
    /// of the current x_t and SE(y) (`Policy::fuse_terms`'s blocks), or `None`.
    pub(super) fuse_blocks: Option<FuseBlocks>,
    pub(super) last: AdaptReport,
    /// The inner update in progress (between Ψ filling and its commit when
    /// a [commit delay](crate::spec::InnerRule::commit_delay) > 0).
    pub(super) upd: Option<Update>,
    /// The update's own generator (ε of L_D), forked from the navigator's when Ψ filled, so
    /// that the steps of the commit window draw what they would draw without the update.
    pub(super) upd_rng: Xoshiro128,
    pub(super) _mode: PhantomData<M>,
}

/// z_t ~ N(0, I) into `z` (gman-core's feature `gaussian-noise`; without it a navigator
/// with Gaussian noise is refused by [`Navigator::check_settings`], so nothing calls this).
#[inline]
pub(super) fn draw_noise(rng: &mut Xoshiro128, z: &mut [f32]) {
    #[cfg(feature = "gaussian-noise")]
    crate::rng::fill_gaussian(rng, z);
    #[cfg(not(feature = "gaussian-noise"))]
    let _ = (rng, z);
}

/// The error of a navigator with Gaussian noise in a build without it.
pub const NO_GAUSSIAN_NOISE: &str =
    "Gaussian noise: needs gman-core's feature `gaussian-noise` (or a `--noise zero` model)";

/// The error of a step whose probabilities or value are not finite.
pub(super) const NUMERICAL_PROBS: Error = Error::NumericalFault {
    what: "action probabilities",
};

/// What a step changes before it knows whether it will be refused ([`Navigator::step_map`]
/// puts it back when it is).
pub(super) struct StepMarks {
    pub(super) rng: Xoshiro128,
    pub(super) begun: bool,
    pub(super) g_pending: bool,
    pub(super) x_valid: bool,
    pub(super) u2_valid: bool,
    pub(super) fuse_blocks: Option<FuseBlocks>,
}

/// Where an inner update is: the phases of [`Navigator::inner_update`] in order, each over
/// Ψ's entries a batch ([`InnerWork::b`](crate::adapt::inner::InnerWork::b) entries) per slice.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum Phase {
    /// ∇_ω L_D over Ψ, then D's ascent (`disc_steps` times).
    Disc,
    /// Pass 1 of L_ad: the scores, then L_ad and its output gradients.
    Scores,
    /// Pass 2 of L_ad: θ's gradient through D (or the cosine) and G.
    Backward,
    /// The actor head's gradient.
    Head,
    /// Complete: the descent step of θ_i, φ_i is all that is left (the commit).
    Done,
}

/// The state of an inner update computed in slices (every bit the same as computing it at
/// once: the slices are the batches of the one computation, in its order).
#[derive(Clone, Copy, Debug)]
pub(super) struct Update {
    pub(super) phase: Phase,
    /// The next entry of Ψ in this phase.
    pub(super) t: usize,
    /// D's ascent steps taken, and to take.
    pub(super) disc_done: u32,
    pub(super) disc_steps: u32,
    pub(super) disc_ok: bool,
    pub(super) use_d: bool,
    /// ε comes from the update's own generator (a delayed update) instead of the navigator's.
    pub(super) forked: bool,
    /// Steps of the commit window taken.
    pub(super) window: u32,
    /// Estimated multiply-adds done and in all (the in-step schedule spreads them evenly).
    pub(super) done: u64,
    pub(super) total: u64,
    /// Slices run and upper bound of the slices in all.
    pub(super) slices: u32,
    /// The first half of a two-half backward pass ran ([`Navigator::split_backward`]).
    pub(super) half: bool,
    pub(super) report: AdaptReport,
}

impl<'w, M: Mode, const K: usize> Navigator<'w, M, K> {
    /// A navigator over `weights`, with all mutable state in `arena` (at least
    /// [`Navigator::arena_len`] floats), which the caller owns and lends for the navigator's
    /// life ([`Navigator::with_storage`] for other storage). D and the fixed biases are
    /// loaded from `weights`; call [`Navigator::reset`] before the first step.
    pub fn new(weights: NavWeights<'w>, arena: &'w mut [f32], cfg: NavConfig) -> Result<Self> {
        Self::with_storage(weights, arena, cfg)
    }
}

impl<'w, M: Mode, const K: usize, S: AsRef<[f32]> + AsMut<[f32]>> Navigator<'w, M, K, S> {
    /// Number of f32 the arena must hold: [`crate::navigator::memory::arena_len`] for these dims, `M`
    /// and `K` (the default [`Footprint::Compact`]).
    pub fn arena_len(dims: &Dims) -> usize {
        Self::arena_len_for(dims, Footprint::Compact)
    }

    /// Number of f32 the arena must hold with footprint `fp` ([`NavConfig::footprint`]).
    pub fn arena_len_for(dims: &Dims, fp: Footprint) -> usize {
        arena_len_with(dims, M::MODE, K, fp)
    }

    /// The navigator's arena storage, given back (its contents are the navigator's state;
    /// a new navigator over it starts afresh).
    pub fn into_storage(self) -> S {
        self.arena.store
    }

    /// Every check [`Navigator::with_storage`] makes of `weights` and `cfg` before it writes
    /// to the arena: the buffer capacity, the inner-loop rates, the loss bound, the dims, the
    /// adaptation mode, the commit delay and the schedule, the footprint. A caller that must
    /// not touch an arena for a navigator that would be refused (the C API's `gman_init` on
    /// the arena of a live navigator) calls it first.
    pub fn check_settings(weights: &NavWeights<'_>, cfg: &NavConfig) -> Result<()> {
        let bad = |what: &'static str| Err(Error::Config { what });
        if K == 0 {
            return bad("buffer capacity K must be at least 1");
        }
        // The blob parser's checks, for weights and settings from any source.
        if cfg.model.adapt_settings().validate().is_err() {
            return bad("alpha_disc, alpha_adapt: finite, in 0..=blob::MAX_INNER_RATE");
        }
        if cfg.loss_bound.is_nan() || cfg.loss_bound <= 0.0 {
            return bad("loss_bound must be > 0");
        }
        match crate::blob::check_model_dims(&weights.dims) {
            Ok(()) => {}
            Err(BlobError::DegenerateDims { .. }) => {
                return bad("degenerate dims: a width is zero or the map's dims are inconsistent (see Dims::degenerate_field)")
            }
            Err(_) => {
                return bad("dims too large: a size derived from them overflows usize")
            }
        }
        // (A model that does not adapt runs identically in both modes.)
        if cfg.model.adapt && cfg.check_mode && cfg.model.adapt_mode != M::MODE {
            return bad(
                "weights meta-trained in the other adaptation mode (NavConfig::check_mode)",
            );
        }
        if cfg.model.inner_rule.commit_delay > crate::spec::schema::MAX_COMMIT_DELAY {
            return bad("commit_delay above MAX_COMMIT_DELAY (63)");
        }
        if cfg.schedule == Schedule::Background && cfg.model.inner_rule.commit_delay == 0 {
            return bad("Schedule::Background needs a commit_delay of at least 1 step");
        }
        if cfg.model.noise == NoiseMode::Gaussian && !cfg!(feature = "gaussian-noise") {
            return bad(NO_GAUSSIAN_NOISE);
        }
        if cfg.model.adapt && cfg.model.emd == Emd::CosSim && !cfg!(feature = "cossim") {
            return Err(inner::NO_COSSIM);
        }
        let lean = cfg.footprint == Footprint::Minimal;
        if lean && !cfg.model.compact_psi {
            return bad("Footprint::Minimal needs Ψ in int16: export with `--psi int16`");
        }
        if lean
            && (M::MODE != AdaptMode::Efficient
                || (cfg.model.adapt && cfg.model.emd == Emd::CosSim))
        {
            return bad("Footprint::Minimal: Efficient, D only");
        }
        let dims = weights.dims;
        if crate::navigator::memory::try_arena_len_noise(
            &dims,
            M::MODE,
            K,
            cfg.footprint,
            cfg.model.noise,
        )
        .is_none()
        {
            return bad("dims too large: the arena size for these dims, mode and K overflows");
        }
        Ok(())
    }

    /// A navigator over `weights`, with all mutable state in the storage `arena` (at least
    /// [`Navigator::arena_len`] floats), which it keeps: [`Navigator::new`] for an arena the
    /// caller owns, e.g. `Vec<f32>` or `Box<[f32]>` for one the navigator owns. D and the
    /// fixed biases are loaded from `weights`; call [`Navigator::reset`] before the first
    /// step.
    pub fn with_storage(weights: NavWeights<'w>, mut arena: S, cfg: NavConfig) -> Result<Self> {
        Self::check_settings(&weights, &cfg)?;
        let dims = weights.dims;
        let lean = cfg.footprint == Footprint::Minimal;
        let zero = cfg.model.noise == NoiseMode::Zero;
        let (lens, _used) = carve_check(arena.as_mut(), &dims, M::MODE, K, (cfg.footprint, zero))?;
        let mut nav = Navigator {
            w: weights,
            cfg,
            rng: Xoshiro128::seed_from_u64(0),
            arena: Arena {
                store: arena,
                lens,
                full: M::MODE == AdaptMode::Full,
                b: adapt_batch_with(M::MODE, K, cfg.footprint).max(1),
            },
            counters: Counters::default(),
            n_buf: 0,
            ready: false,
            begun: false,
            g_pending: false,
            x_valid: false,
            x_fixed: false,
            u2_valid: false,
            psi_recorded: false,
            lean,
            fuse_blocks: None,
            last: AdaptReport::default(),
            upd: None,
            upd_rng: Xoshiro128::seed_from_u64(0),
            _mode: PhantomData,
        };
        // Validate every shape once by building the views.
        nav.reset_discriminator()?;
        let (w, r) = (&nav.w, nav.arena.ram());
        copy_mat(&w.get(TensorId::FuseB), r.fuse_b)?;
        copy_mat(&w.get(TensorId::LstmB), r.lstm_b)?;
        copy_mat(&w.get(TensorId::CriticB), r.critic_b)?;
        copy_mat(&w.get(TensorId::CellB), r.cell_b)?;
        nav.restore_adapted()?;
        nav.policy()?.validate()?;
        nav.generator()?.validate()?;
        nav.discriminator()?.validate()?;
        Ok(nav)
    }

    /// Restores D's parameters ω to the values in the weights (D otherwise persists across
    /// episodes, learning from every buffer).
    pub fn reset_discriminator(&mut self) -> Result<()> {
        let (w, mut r) = (self.w, self.arena.ram());
        r.disc1
            .restore(&w.get(TensorId::DiscW1), &w.get(TensorId::DiscB1))?;
        copy_mat(&w.get(TensorId::DiscW2), r.disc_w2)?;
        copy_mat(&w.get(TensorId::DiscB2), r.disc_b2)
    }

    fn restore_adapted(&mut self) -> Result<()> {
        let (w, mut r) = (self.w, self.arena.ram());
        r.gen1
            .restore(&w.get(TensorId::GenW1), &w.get(TensorId::GenB1))?;
        r.gen2
            .restore(&w.get(TensorId::GenW2), &w.get(TensorId::GenB2))?;
        r.actor
            .restore(&w.get(TensorId::ActorW), &w.get(TensorId::ActorB))
    }

    /// Starts an episode towards the category with attribute vector `attr` (SE(y)):
    /// restores θ and φ to their meta-learned values (line 4 of Algorithm 1), clears the LSTM
    /// state, the previous action probabilities and Ψ, and seeds the navigator's generator
    /// (noise, interpolation weights, sampling) with `seed`.
    pub fn reset(&mut self, attr: &[f32], seed: u64) -> Result<()> {
        check_len("reset.attr", self.w.dims.attr, attr.len())?;
        if !all_finite(attr) {
            return Err(Error::NonFiniteInput { what: "attr" });
        }
        self.settle()?;
        self.restore_adapted()?;
        if self.cfg.model.inner_rule.disc_head_reset {
            // D restarts with the episode: layer 1 from ω, the head at zero.
            self.reset_discriminator()?;
            let r = self.arena.ram();
            r.disc_w2.fill(0.0);
            r.disc_b2.fill(0.0);
        }
        let r = self.arena.ram();
        r.attr.copy_from_slice(attr);
        r.h_state.fill(0.0);
        r.c_state.fill(0.0);
        r.prev_probs.fill(0.0);
        self.rng = Xoshiro128::seed_from_u64(seed);
        self.n_buf = 0;
        self.x_valid = false;
        self.x_fixed = false;
        self.fuse_blocks = None;
        self.ready = true;
        self.begun = false;
        self.g_pending = false;
        let c = &mut self.counters;
        c.steps = 0;
        c.adaptations = 0;
        c.rollbacks = 0;
        if self.cfg.model.noise == NoiseMode::Zero {
            self.prepare_zero_noise()?;
        }
        Ok(())
    }

    /// With zero noise, what stays the same until the next commit or reset: x_t = G_θi(SE(y),
    /// 0) and the fusion layer's terms of x_t and SE(y) ([`Policy::fuse_terms`]), computed
    /// here at the reset so that the episode's first step is a plain one (after a commit the
    /// next step computes them).
    fn prepare_zero_noise(&mut self) -> Result<()> {
        self.arena.ram().z.fill(0.0);
        self.run_generator(None)?;
        self.x_valid = true;
        let r = self.arena.ram();
        let biases = [&*r.fuse_b, &*r.lstm_b, &*r.critic_b, &*r.cell_b];
        let actor = r.actor.view(self.w.get(TensorId::ActorW))?;
        let policy = policy_view(&self.w, biases, actor)?;
        self.fuse_blocks = policy.fuse_terms(r.x, r.attr, r.fuse_terms)?;
        Ok(())
    }

    /// Replaces the generated feature x_t by `x` (`feat` floats) for the rest of the episode
    /// (until the next [`Navigator::reset`]): G is not run in `step()` and the policy sees
    /// `x` every step. This is a diagnostic for hosts, not part of Algorithm 1: the trainer's
    /// privileged-feature bound feeds the target's true feature in the scene here, i.e. what
    /// a perfectly adapted G would produce. Use it with the inner loop off (`adapt: false`);
    /// the inner update would still score G's own output, not `x`.
    pub fn fix_generated_feature(&mut self, x: &[f32]) -> Result<()> {
        if !self.ready {
            return Err(Error::Config {
                what: "call reset() before fix_generated_feature()",
            });
        }
        check_len("fix_generated_feature.x", self.w.dims.feat, x.len())?;
        if !all_finite(x) {
            return Err(Error::NonFiniteInput { what: "x" });
        }
        let r = self.arena.ram();
        r.x.copy_from_slice(x);
        r.z.fill(0.0);
        self.x_fixed = true;
        self.fuse_blocks = None;
        Ok(())
    }

    /// The counters.
    pub fn counters(&self) -> Counters {
        self.counters
    }

    /// Diagnostics of the last inner update.
    pub fn last_adaptation(&self) -> AdaptReport {
        self.last
    }

    /// The sizes of the networks.
    pub fn dims(&self) -> &Dims {
        &self.w.dims
    }

    /// The configuration.
    pub fn config(&self) -> &NavConfig {
        &self.cfg
    }

    /// The generated target feature x_t of the last step (`feat` floats).
    pub fn generated_feature(&self) -> &[f32] {
        self.arena.view().x
    }

    /// G's activations of its last forward in the step's G scratch (the x_t of the last
    /// [`Navigator::begin_step`] that ran G, or the last [`Navigator::generator_output`]):
    /// `(u1, h1, u2)`, layer 1's `W1 [z; SE(y)]` before its gain (`gen_hidden`, empty
    /// without a gain), the hidden activation after the LeakyReLU (`gen_hidden`) and layer
    /// 2's `W2 h1` before its gain (`feat`, empty without a gain). A host's backward through
    /// x_t may reuse them (with [`Navigator::generated_feature`]) instead of running G again.
    pub fn generator_activations(&self) -> (&[f32], &[f32], &[f32]) {
        let r = self.arena.view();
        (r.u1, r.h1, r.u2)
    }

    /// The current LSTM hidden state.
    pub fn hidden_state(&self) -> &[f32] {
        self.arena.view().h_state
    }

    /// The current LSTM cell state.
    pub fn cell_state(&self) -> &[f32] {
        self.arena.view().c_state
    }

    /// The previous step's action probabilities (zeros before the first step).
    pub fn prev_probs(&self) -> &[f32] {
        self.arena.view().prev_probs
    }

    /// The noise z of the last generated feature.
    pub fn noise(&self) -> &[f32] {
        self.arena.view().z
    }

    /// The target attribute vector of the episode.
    pub fn attr(&self) -> &[f32] {
        self.arena.view().attr
    }

    /// True while more inner updates are allowed in this episode (`adapt` is on and fewer
    /// than `max_inner` were made).
    pub fn can_adapt(&self) -> bool {
        self.cfg.model.adapt && self.counters.adaptations < self.cfg.model.max_inner
    }

    /// Empties Ψ without adapting (line 20 alone).
    pub fn clear_buffer(&mut self) {
        self.n_buf = 0;
        self.upd = None;
    }

    /// True from the step that fills Ψ to the commit of its inner update when a [commit
    /// delay](crate::spec::InnerRule::commit_delay) > 0 (the commit window: steps are not recorded
    /// in Ψ).
    pub fn update_pending(&self) -> bool {
        self.upd.is_some()
    }

    /// True while a pending update's commit window has steps left to take: the steps after Ψ filled
    /// that run before the update takes effect (the model's [commit
    /// delay](crate::spec::InnerRule::commit_delay)). A trainer's segment ends when Ψ is full and
    /// this is false.
    pub fn in_commit_window(&self) -> bool {
        self.upd
            .is_some_and(|u| u.window < self.cfg.model.inner_rule.commit_delay)
    }

    /// Slices of the pending update still to run (0: none pending, or complete).
    pub fn slices_left(&self) -> u32 {
        match self.upd {
            Some(u) if u.phase != Phase::Done => self.slice_bound().saturating_sub(u.slices).max(1),
            _ => 0,
        }
    }

    /// Runs one bounded slice of the pending inner update (one batch of
    /// [`crate::navigator::memory::adapt_batch`] entries of one of its passes) — the call of
    /// [`Schedule::Background`]'s lower-priority context. Returns whether slices remain
    /// (false also when no update is pending). The slices never change what the steps
    /// read (the adapted θ_i, φ_i change only at the commit, D is not read by a step), and
    /// the update they compute is bit for bit the update computed at once.
    pub fn adapt_slice(&mut self) -> Result<bool> {
        match self.upd {
            Some(u) if u.phase != Phase::Done => {
                self.run_slice()?;
                Ok(self.upd.is_some_and(|u| u.phase != Phase::Done))
            }
            _ => Ok(false),
        }
    }

    /// Completes D's ascent of a pending inner update and drops the rest (θ_i, φ_i keep
    /// their values; [`Navigator::reset`] restores them anyway). [`Navigator::reset`] calls
    /// it, so that D, which persists across episodes, learns from every buffer that filled,
    /// whenever the episode ended; a host that reads D after an episode calls it first.
    pub fn settle(&mut self) -> Result<()> {
        while self.upd.is_some_and(|u| u.phase == Phase::Disc) {
            self.run_slice()?;
        }
        self.upd = None;
        Ok(())
    }

    /// Number of steps recorded in Ψ since it was last emptied.
    pub fn buffered(&self) -> usize {
        self.n_buf
    }

    /// Read-only views of the [`Navigator::buffered`] entries of Ψ, for host-side
    /// meta-gradients (they are what the next inner update's L_ad is computed on).
    pub fn buffer(&self) -> BufferView<'_> {
        let (d, n, r) = (&self.w.dims, self.n_buf, self.arena.view());
        BufferView {
            obs: if self.lean {
                &[]
            } else {
                &r.psi_s[..n * d.feat]
            },
            noise: if self.cfg.model.noise == NoiseMode::Zero {
                &[]
            } else {
                &r.psi_z[..n * d.noise]
            },
            probs: &r.psi_p[..n * NUM_ACTIONS],
            hidden: &r.psi_h[..n * d.lstm_hidden],
        }
    }

    /// The adapted generator θ_i as a view (for diagnostics and host-side meta-gradients).
    pub fn generator(&self) -> Result<Generator<'_>> {
        let r = self.arena.view();
        Ok(Generator {
            l1: layer_view(r.gen1, self.w.get(TensorId::GenW1))?,
            l2: layer_view(r.gen2, self.w.get(TensorId::GenW2))?,
        })
    }

    /// The current discriminator ω as a view.
    pub fn discriminator(&self) -> Result<Discriminator<'_>> {
        let r = self.arena.view();
        Ok(Discriminator {
            l1: layer_view(r.disc1, self.w.get(TensorId::DiscW1))?,
            w2: r.disc_w2,
            b2: r.disc_b2.first().copied().unwrap_or(0.0),
        })
    }

    /// The adapted policy φ_i as a view.
    pub fn policy(&self) -> Result<Policy<'_>> {
        let r = self.arena.view();
        let actor = layer_view(r.actor, self.w.get(TensorId::ActorW))?;
        policy_view(&self.w, [r.fuse_b, r.lstm_b, r.critic_b, r.cell_b], actor)
    }
}
