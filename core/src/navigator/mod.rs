//! The on-device navigator: the policy, the navigation buffer Ψ and the inner loop of
//! Algorithm 1, one call per camera frame.
//!
//! ```text
//! reset(SE(y), seed)      θ_i ← θ, φ_i ← φ (line 4); clear LSTM state and Ψ
//! step(s_t) -> a_t        x_t = G_θi(SE(y), z_t)            (line 7)
//!                         a_t ~ π_{θi,φi}(· | s_t, x_t, ...)  (line 8)
//!                         Ψ ← Ψ ∪ {(s_t, x_t, a_t, h_t)}      (lines 11-13)
//!                         every k steps, while fewer than `max_inner` were made:
//!                           ω  ← ω  + α1 ∇_ω L_D             (lines 15-16, Eq. 1)
//!                           θi ← θi − α2 ∇_θi L_ad            (lines 17-18, Eq. 3)
//!                           φi ← φi − α2 ∇_φi L_ad            (line 19)
//!                           empty Ψ                           (line 20)
//! ```
//!
//! # What adapts, and how its gradient is taken
//! * θ: all of G in [`AdaptMode::Full`]; the per-unit gains and biases of G's two layers in
//!   [`AdaptMode::Efficient`].
//! * φ: the **actor head** (all of it in `Full`, its per-unit gains and biases in
//!   `Efficient`). The fusion layer, the LSTM and the critic keep their meta-learned values.
//! * ω (D): all of D in `Full`; its hidden layer's gains and biases and its output layer in
//!   `Efficient`. D is *not* restored by [`Navigator::reset`]: as in the paper it is
//!   learned across episodes.
//!
//! ∇_θ L_ad flows through D(x_t) into G (exact, see [`crate::adapt`]). ∇_φ L_ad flows through
//! the softmax into the actor head using the LSTM hidden state h_t stored in Ψ for each step:
//! exact for the actor head, with no back-propagation through time (a device cannot afford
//! it). The dependence of a_t on θ through the policy's input x_t is not followed (a
//! stop-gradient): L_ad adapts G through D only, and the policy through its head only.
//!
//! Ψ stores each step's generated x_t (Ψ_x, `F` floats per step) with its noise z_t: inside
//! one adaptation window θ does not change (it changes only in the inner update and in
//! `reset`, which both empty Ψ), so the update uses the recorded x_t and runs no forward
//! pass of G over Ψ (unless the caller fixed x_t, `Navigator::fix_generated_feature`).
//!
//! With [`NoiseMode::Zero`] x_t = G_θi(SE(y), 0) is the same at every step between two
//! inner updates: the step runs G once after `reset` and after each commit and keeps x_t;
//! Ψ keeps no z_t and one x_t for all its entries (in every [`Footprint`]), and the
//! update's backward pass runs G and D once for all of Ψ (its entries share one noise, so
//! they form one group whose coefficients are summed, `inner::score_backward_part`).
//!
//! Algorithm 1 as printed records a step only when `t` is not a multiple of `k` (lines
//! 10-13), so its buffer would hold `k − 1` samples at each update. Here every step is
//! recorded and the update runs when Ψ holds `k` samples, i.e. every `k` steps.
//!
//! # Safety
//! Non-finite observations or attribute vectors are rejected with
//! [`Error::NonFiniteInput`]. An adaptation step whose loss is non-finite or above
//! [`NavConfig::loss_bound`], or whose update would make a parameter non-finite, is not
//! applied (it is *rolled back* before it is written, so no copy of the parameters is needed)
//! and counted in [`Counters::rollbacks`]. An action is only returned from finite
//! probabilities; otherwise [`Error::NumericalFault`] is returned.
//!
//! # Example: a firmware loop
//! ```
//! use gman_core::navigator::{NavConfig, NavWeights, Navigator, Efficient};
//! use gman_core::navigator::memory::{arena_len, AdaptMode};
//! use gman_core::blob::Blob;
//! use gman_core::Dims;
//! # use gman_core::blob::{encode_model_scratch_len, encoded_model_len_bound, AdaptSettings, Quant};
//! # use gman_core::spec::schema::FLAG_ADAPT;
//! # // Hidden: make an Mcu int8 blob from seeded weights (a firmware embeds a trained one).
//! # let d = Dims::MCU;
//! # let mut bytes = vec![0u8; encoded_model_len_bound(&d, Quant::I8)];
//! # let (nf, nb) = encode_model_scratch_len(&d);
//! # let n = gman_core::blob::seeded::encode_seeded(&d, FLAG_ADAPT, AdaptSettings::PAPER, Quant::I8,
//! #     1, 0.05, &mut bytes, &mut vec![0.0; nf], &mut vec![0; nb]).unwrap();
//! # bytes.truncate(n);
//! // In firmware: `static BLOB: &[u8] = include_bytes!("model.gman");` and a static arena.
//! const LEN: usize = arena_len(&Dims::MCU, AdaptMode::Efficient, 20);
//! let mut arena = vec![0.0f32; LEN]; // firmware: a `static` array of LEN floats
//! let blob = Blob::parse(&bytes).expect("valid blob");
//! let weights = NavWeights::from_blob(&blob, &Dims::MCU).expect("MCU blob");
//! // The settings the model was trained with (adaptation, EMD, noise, α1, α2, cap), never
//! // the loader's own defaults.
//! let cfg = NavConfig::from_header(blob.header());
//! let mut nav: Navigator<'_, Efficient, 20> =
//!     Navigator::new(weights, &mut arena, cfg).expect("arena large enough");
//! let target_attributes = [0.5f32; 45]; // SE(y) of the category to find
//! nav.reset(&target_attributes, 42).expect("finite attributes");
//! let camera_features = [0.1f32; 512]; // s_t from the camera pipeline
//! for _ in 0..30 {
//!     let out = nav.step(&camera_features, &[]).expect("finite observation");
//!     if out.action == gman_core::Action::Done { break; }
//! }
//! assert_eq!(nav.counters().adaptations, 1); // one inner update after k = 20 steps
//! ```

pub mod memory;

use core::marker::PhantomData;
use core::ops::Deref;

use crate::adapt::actor_head_grad;
use crate::adapt::inner::{self, InnerWorkOf};
use crate::blob::{Blob, Header};
use crate::error::BlobError;
use crate::error::{check_len, Error, Result};
use crate::navigator::memory::{
    adapt_batch_with, arena_len_with, arena_table, first, region_lens, AdaptMode, Footprint,
    NUM_REGIONS,
};
use crate::nets::discriminator::{DiscGrads, Discriminator, LdConfig, LdValue};
use crate::nets::generator::{Generator, GeneratorCache};
use crate::nets::policy::{FuseBlocks, FuseTerms, Policy, PolicyCache, PolicyInput};
use crate::nn::activation::{all_finite, leaky_relu_inplace, sigmoid_inplace};
use crate::nn::dense::{gain_bias, Dense, DenseGrads};
use crate::nn::lstm::Lstm;
use crate::nn::matrix::MatRef;
use crate::rng::{uniform, Xoshiro128};
use crate::spec::preset::Dims;
pub use crate::spec::schema::{Emd, NoiseMode};
use crate::spec::schema::{TensorId, NUM_TENSORS};
use crate::spec::ModelSpec;
use crate::{Action, NUM_ACTIONS};

/// Compile-time choice of the adaptation mode (see [`AdaptMode`]).
pub trait Mode {
    /// The mode.
    const MODE: AdaptMode;
}

/// Marker for [`AdaptMode::Full`].
#[derive(Clone, Copy, Debug)]
pub struct Full;
impl Mode for Full {
    const MODE: AdaptMode = AdaptMode::Full;
}

/// Marker for [`AdaptMode::Efficient`].
#[derive(Clone, Copy, Debug)]
pub struct Efficient;
impl Mode for Efficient {
    const MODE: AdaptMode = AdaptMode::Efficient;
}

/// How the action is chosen from the probabilities.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum Selection {
    /// The most probable action (lowest index on ties). Default.
    #[default]
    Greedy,
    /// A sample from the probabilities, with the navigator's seeded generator.
    Sample,
}

/// When the inner update runs.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum Schedule {
    /// Inside `step()`, every `K` steps (what a robot runs). Default.
    #[default]
    Auto,
    /// Only when the caller asks ([`Navigator::adapt_now`] or [`Navigator::clear_buffer`]);
    /// `step()` refuses to run while Ψ is full. A trainer uses this to take the navigation
    /// loss's gradient at the parameters a segment was run with, before they adapt. The
    /// update itself is the same code. With a
    /// [commit delay](crate::spec::InnerRule::commit_delay) `d > 0` the `d` steps after Ψ
    /// fills run (unrecorded) before `step()` asks for `adapt_now()`.
    Manual,
    /// With a [commit delay](crate::spec::InnerRule::commit_delay) `d >= 1` (required): `step()`
    /// never computes the update; the caller runs it in slices with [`Navigator::adapt_slice`] from
    /// a context of lower priority than the control loop (an RTIC task, a lower interrupt priority,
    /// the main loop between timer ticks). The update commits at the end of the `d`-th step after Ψ
    /// filled, as with `Auto`; a step that would reach that point before every slice ran returns
    /// [`Error::UpdateNotReady`] and changes nothing.
    Background,
}

/// The navigator's configuration: the model's settings ([`ModelSpec`], what a blob records)
/// and the caller's run-time choices.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct NavConfig {
    /// The model's settings, every one a blob records and nothing else: whether the inner
    /// loop runs at all (`adapt`; false: the A3C+FG baseline with no adaptation), what
    /// scores the generated features in L_ad (`emd`), G's noise, the adaptation mode, α1
    /// ([`ModelSpec::alpha_disc`]) and α2 (`inner_lr`), at most `max_inner` inner updates
    /// per episode, the inner rule's levers ([`InnerRule`](crate::spec::InnerRule): D's
    /// ascent steps, 0 counting as 1; the step rule; D's head reset; the form of L_ad; L_D's
    /// critic scale; the head-only step; the commit delay) and Ψ's int16 form
    /// (`compact_psi`, [`crate::spec::schema::FLAG_COMPACT_PSI`]: the inner update sees those
    /// values in every [`Footprint`]; [`Footprint::Minimal`] needs it).
    ///
    /// The commit delay d ([`InnerRule::commit_delay`](crate::spec::InnerRule::commit_delay)):
    /// the inner update that starts when Ψ fills at step t takes effect at the end of step
    /// t + d. The `d` steps between act on the current parameters and are not recorded in
    /// Ψ; with [`Schedule::Auto`] each of them computes a bounded slice of the update, with
    /// [`Schedule::Background`] the caller does ([`Navigator::adapt_slice`]). 0 (the
    /// default): the update runs inside the step that fills Ψ. At most
    /// [`MAX_COMMIT_DELAY`](crate::spec::schema::MAX_COMMIT_DELAY).
    ///
    /// `int8_activations` is how a blob's weights run ([`NavWeights::from_blob`] applies
    /// it); the navigator does not read it here.
    pub model: ModelSpec,
    /// [`Navigator::new`] refuses weights whose `model.adapt_mode` is not the navigator's
    /// mode when the model adapts, since the inner loop would then not be the one that was
    /// meta-learned: true in the configuration of a blob or a model's settings
    /// ([`NavConfig::from_header`], [`NavConfig::from_spec`]); false (the default) runs the
    /// weights in any mode.
    pub check_mode: bool,
    /// When the inner update runs.
    pub schedule: Schedule,
    /// Action selection.
    pub selection: Selection,
    /// An adaptation step whose |loss| exceeds this is rolled back.
    pub loss_bound: f32,
    /// How much RAM the navigator trades for speed ([`Footprint::Compact`], the
    /// microcontroller's layout, by default; hosts use [`Footprint::Fast`]). Never changes
    /// a bit of what the navigator computes; the arena must hold
    /// [`Navigator::arena_len_for`] floats for it.
    pub footprint: Footprint,
    /// λ, the gradient penalty's weight in L_D (paper: 10; L_D's critic scale is the
    /// model's, [`InnerRule::critic_scale`](crate::spec::InnerRule::critic_scale)).
    pub ld_lambda: f32,
}

impl NavConfig {
    /// The navigator configuration a weight blob asks for, from its header: the settings
    /// it records ([`Header::spec`]) as `model`, with the mode check on.
    ///
    /// A blob records how its model was trained: whether the method adapts at inference
    /// ([`FLAG_ADAPT`](crate::spec::schema::FLAG_ADAPT)), what scores the generated features
    /// ([`FLAG_COSSIM`](crate::spec::schema::FLAG_COSSIM)), which noise drives G
    /// ([`FLAG_ZERO_NOISE`](crate::spec::schema::FLAG_ZERO_NOISE)), the adaptation mode, the inner rule's
    /// levers and, from format v2 on, the inner-loop rates and the cap on inner updates
    /// ([`AdaptSettings`](crate::blob::AdaptSettings); a v1 blob reports the paper's). Any loader —
    /// the firmware, the host's evaluation, a user's controller — must run the model with exactly
    /// these settings: the host meta-trained and evaluated the weights with them, so a device that
    /// ran its own defaults instead would silently execute a different algorithm (an A3C+FG
    /// baseline that adapts, a CosSim model whose features D scores instead, GMAN with other rates
    /// or another cap), and the two could no longer be compared bit for bit. Building the
    /// configuration here, in the core both sides link, is what keeps host and device from ever
    /// disagreeing.
    ///
    /// Everything else keeps its default: [`Schedule::Auto`], [`Selection::Greedy`], L_D's
    /// λ, the default loss bound and footprint. These are run-time choices of the caller,
    /// not properties of the trained weights (the host's evaluation, for one, samples its
    /// actions: it uses this configuration with `selection: Selection::Sample`). A v4 header
    /// has no unknown flag bits (the parser refuses them); a v1-v3 header's are ignored.
    ///
    /// Never fails: a parsed [`Header`]'s rates are finite and non-negative (checked by
    /// [`Blob::parse`]), so the result is accepted by [`Navigator::new`] as far as the rates
    /// are concerned. See also [`Blob::nav_config`].
    pub fn from_header(header: &Header) -> NavConfig {
        NavConfig::from_spec(&header.spec())
    }

    /// The configuration of a model's settings (gman-core's one carrier of them,
    /// [`ModelSpec`]): what a host that holds them runs before it writes them into a blob,
    /// [`NavConfig::from_header`] of that blob.
    pub fn from_spec(spec: &ModelSpec) -> NavConfig {
        NavConfig {
            model: *spec,
            check_mode: true,
            ..NavConfig::default()
        }
    }

    /// L_D's λ and critic scale.
    fn ld(&self) -> LdConfig {
        LdConfig {
            lambda: self.ld_lambda,
            critic_scale: self.model.inner_rule.critic_scale(),
        }
    }
}

impl Blob<'_> {
    /// The navigator configuration this blob asks for: [`NavConfig::from_header`] of its
    /// header.
    pub fn nav_config(&self) -> NavConfig {
        NavConfig::from_header(self.header())
    }
}

impl Default for NavConfig {
    /// The paper's settings ([`ModelSpec::paper`]): adaptation on with D as the EMD, Gaussian
    /// noise, α1 = α2 = 1e-4 and at most 4 inner updates per episode
    /// ([`AdaptSettings::PAPER`](crate::blob::AdaptSettings::PAPER)), the paper's inner rule;
    /// weights run in any mode, automatic schedule, greedy selection, the compact footprint, λ =
    /// 10.
    fn default() -> Self {
        NavConfig {
            model: ModelSpec::paper(AdaptMode::Full),
            check_mode: false,
            schedule: Schedule::Auto,
            selection: Selection::Greedy,
            loss_bound: 1e6,
            footprint: Footprint::Compact,
            ld_lambda: LdConfig::default().lambda,
        }
    }
}

pub use crate::spec::schema::StepRule;

/// The action chosen from the policy's probabilities `p` (`NUM_ACTIONS` values): the most
/// probable (first on ties) with [`Selection::Greedy`], or one draw of `rng` against the
/// cumulative probabilities with [`Selection::Sample`] (the last action if rounding leaves
/// the draw above the sum). The navigator's own choice, for hosts that step episodes outside
/// it (the trainer's vectorised episodes).
pub fn select_action(selection: Selection, p: &[f32], rng: &mut Xoshiro128) -> Action {
    let mut best = 0;
    match selection {
        Selection::Greedy => {
            for i in 1..p.len().min(NUM_ACTIONS) {
                if p[i] > p[best] {
                    best = i;
                }
            }
        }
        Selection::Sample => {
            let u = uniform(rng);
            let mut acc = 0.0;
            best = NUM_ACTIONS - 1;
            for (i, &pi) in p.iter().take(NUM_ACTIONS).enumerate() {
                acc += pi;
                if u < acc {
                    best = i;
                    break;
                }
            }
        }
    }
    Action::from_index(best).unwrap_or(Action::Done)
}

/// Counters, per episode (reset by [`Navigator::reset`]) and over the navigator's life.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Counters {
    /// Steps in this episode.
    pub steps: u32,
    /// Inner updates applied in this episode.
    pub adaptations: u32,
    /// Adaptation steps (D ascent or θ/φ descent) rolled back in this episode.
    pub rollbacks: u32,
    /// Steps over the navigator's life.
    pub total_steps: u64,
    /// Inner updates over the navigator's life.
    pub total_adaptations: u64,
    /// Rollbacks over the navigator's life.
    pub total_rollbacks: u64,
}

/// What one step returns.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct StepOutput {
    /// The chosen action.
    pub action: Action,
    /// The policy's action probabilities.
    pub probs: [f32; NUM_ACTIONS],
    /// The critic's value estimate.
    pub value: f32,
    /// True when this step ended with an inner update (applied or rolled back).
    pub adapted: bool,
}

/// Diagnostics of the last inner update.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct AdaptReport {
    /// L_D and its parts, before D's ascent step.
    pub ld: LdValue,
    /// L_ad before the descent step.
    pub adapt_loss: f32,
    /// Whether D's step was applied.
    pub disc_applied: bool,
    /// Whether θ/φ's step was applied.
    pub adapt_applied: bool,
}

/// The contents of the navigation buffer Ψ (`n` entries, row-major), see
/// [`Navigator::buffer`].
#[derive(Clone, Copy, Debug)]
pub struct BufferView<'a> {
    /// Observations s_t (`n x feat`).
    pub obs: &'a [f32],
    /// Noise z_t (`n x noise`; empty with [`NoiseMode::Zero`], where every z_t is zero and
    /// Ψ keeps none).
    pub noise: &'a [f32],
    /// Action probabilities a_t (`n x 6`).
    pub probs: &'a [f32],
    /// LSTM hidden states h_t after each step (`n x lstm_hidden`).
    pub hidden: &'a [f32],
}

/// Read-only views of every tensor the navigator needs (from a blob, or from a trainer's
/// f32 buffers), indexed by [`TensorId`].
#[derive(Clone, Copy, Debug)]
pub struct NavWeights<'w> {
    dims: Dims,
    t: [MatRef<'w>; NUM_TENSORS],
}

impl<'w> NavWeights<'w> {
    /// Views into a parsed blob (no copy); checks the blob's dims against `dims`. A blob with
    /// [`crate::spec::schema::FLAG_INT8_ACTIVATIONS`] gets int8 activations on its int8 views
    /// ([`NavWeights::with_int8_activations`]).
    pub fn from_blob(blob: &Blob<'w>, dims: &Dims) -> Result<Self> {
        blob.check_dims(dims)?;
        let mut t = [empty(); NUM_TENSORS];
        for id in TensorId::all_for(dims) {
            t[id as usize] = blob.matrix(id)?;
        }
        let w = NavWeights { dims: *dims, t };
        if blob.header().flags() & crate::spec::schema::FLAG_INT8_ACTIVATIONS != 0 {
            if !cfg!(feature = "int8-activations") {
                return Err(Error::Config {
                    what: "the blob needs int8 activations: build gman-core with the \
                           `int8-activations` feature",
                });
            }
            return Ok(w.with_int8_activations());
        }
        if !crate::nn::qkernel::F32_ACTIVATIONS && w.t.iter().any(MatRef::is_int8) {
            return Err(crate::nn::qkernel::NO_F32_ACTIVATIONS);
        }
        Ok(w)
    }

    /// The same views with int8 activations on every int8 weight matrix
    /// ([`MatRef::with_int8_activations`]; f32 views are unchanged).
    pub fn with_int8_activations(mut self) -> Self {
        for m in self.t.iter_mut() {
            *m = m.with_int8_activations();
        }
        self
    }

    /// Views built by `f` for each tensor of `dims` ([`TensorId::all_for`]; a trainer passes
    /// `MatRef::f32` over its buffers); shapes are checked against `dims`.
    pub fn from_fn(dims: &Dims, mut f: impl FnMut(TensorId) -> MatRef<'w>) -> Result<Self> {
        let mut t = [empty(); NUM_TENSORS];
        for id in TensorId::all_for(dims) {
            let m = f(id);
            let (r, c) = id.shape(dims);
            if m.rows() != r || m.cols() != c {
                return Err(Error::Blob(crate::BlobError::BadTensorShape {
                    id: id as u16,
                }));
            }
            t[id as usize] = m;
        }
        Ok(NavWeights { dims: *dims, t })
    }

    /// The same views running their kernels through `k` (see [`crate::nn::batch::Kernels`]; a
    /// host's wider-SIMD build of the same kernels). Every result keeps its bits; the f32
    /// copies the navigator adapts in RAM inherit `k` from the view they stand in for.
    pub fn with_kernels(mut self, k: &'static dyn crate::nn::batch::Kernels) -> Self {
        for m in self.t.iter_mut() {
            *m = m.with_kernels(k);
        }
        self
    }

    /// The dims.
    pub fn dims(&self) -> &Dims {
        &self.dims
    }

    /// The view of tensor `id`.
    pub fn get(&self, id: TensorId) -> MatRef<'w> {
        self.t[id as usize]
    }
}

fn empty() -> MatRef<'static> {
    match MatRef::f32(0, 0, &[]) {
        Ok(m) => m,
        Err(_) => empty(),
    }
}

/// Copies a (possibly int8 or LE-bytes) matrix into f32 RAM.
fn copy_mat(m: &MatRef<'_>, out: &mut [f32]) -> Result<()> {
    m.copy_to(out)
}

const ARENA_TOO_SMALL: Error = Error::Config {
    what: "arena too small for these dims, mode and k (see memory::arena_len)",
};

/// An adapted (or RAM-resident) dense layer: `w` is empty when the base weights are read
/// from the blob; `gain` is empty in `Full` mode.
#[derive(Default)]
struct LayerRam<T> {
    w: T,
    gain: T,
    b: T,
}

impl<T: Deref<Target = [f32]>> LayerRam<T> {
    fn view<'s>(&'s self, base: MatRef<'s>) -> Result<Dense<'s>> {
        dense_over([&self.w, &self.gain, &self.b], base)
    }
}

/// [`LayerRam::view`] of a read-only layer, for as long as its slices live.
fn layer_view<'s>(l: LayerRam<&'s [f32]>, base: MatRef<'s>) -> Result<Dense<'s>> {
    dense_over([l.w, l.gain, l.b], base)
}

/// The layer over RAM weights `w` (empty: the blob's `base`), gains (empty: none) and `b`.
fn dense_over<'s>([w, gain, b]: [&'s [f32]; 3], base: MatRef<'s>) -> Result<Dense<'s>> {
    let w = if w.is_empty() {
        base
    } else {
        MatRef::f32(base.rows(), base.cols(), w)?.kernels_from(&base)
    };
    Ok(Dense {
        w,
        b,
        gain: if gain.is_empty() { None } else { Some(gain) },
    })
}

impl LayerRam<&mut [f32]> {
    /// Restores the meta-learned values: `w` from the blob (Full) or gain 1 (Efficient).
    fn restore(&mut self, w: &MatRef<'_>, b: &MatRef<'_>) -> Result<()> {
        if !self.w.is_empty() {
            copy_mat(w, self.w)?;
        }
        self.gain.fill(1.0);
        copy_mat(b, self.b)
    }
}

/// Gradient buffers matching a [`LayerRam`] (`a` is dW in Full, dgain in Efficient).
#[derive(Default)]
struct LayerGrad<T> {
    a: T,
    b: T,
    full: bool,
}

impl LayerGrad<&mut [f32]> {
    fn grads(&mut self) -> DenseGrads<'_> {
        if self.full {
            DenseGrads::Full {
                w: self.a,
                b: self.b,
            }
        } else {
            DenseGrads::Gain {
                gain: self.a,
                b: self.b,
            }
        }
    }
    fn zero(&mut self) {
        self.a.fill(0.0);
        self.b.fill(0.0);
    }
    fn scale(&mut self, s: f32) {
        self.a
            .iter_mut()
            .chain(self.b.iter_mut())
            .for_each(|v| *v *= s);
    }
    fn finite(&self) -> bool {
        all_finite(self.a) && all_finite(self.b)
    }
    fn sum_sq(&self) -> f32 {
        self.a.iter().chain(self.b.iter()).map(|v| v * v).sum()
    }
    /// True if `p + step * g` stays finite everywhere.
    fn update_ok(&self, p: &LayerRam<&mut [f32]>, step: f32) -> bool {
        let target = if self.full { &*p.w } else { &*p.gain };
        ok_update(target, self.a, step) && ok_update(p.b, self.b, step)
    }
    fn apply(&self, p: &mut LayerRam<&mut [f32]>, step: f32) {
        let target = if self.full { &mut *p.w } else { &mut *p.gain };
        axpy_inplace(target, self.a, step);
        axpy_inplace(p.b, self.b, step);
    }
}

/// The view of G over its RAM layers (`gen1`, `gen2`) and the blob's base weights.
fn gen_view<'s, T: Deref<Target = [f32]>>(
    gen1: &'s LayerRam<T>,
    gen2: &'s LayerRam<T>,
    w: &NavWeights<'s>,
) -> Result<Generator<'s>> {
    Ok(Generator {
        l1: gen1.view(w.get(TensorId::GenW1))?,
        l2: gen2.view(w.get(TensorId::GenW2))?,
    })
}

/// Whether two matrix views read the same stored values (the same slices).
fn same_storage(a: &MatRef<'_>, b: &MatRef<'_>) -> bool {
    use crate::nn::matrix::{Scales, Weights};
    let sc = |s: Scales<'_>| match s {
        Scales::F32(v) => (v.as_ptr() as usize, v.len()),
        Scales::Le(v) => (v.as_ptr() as usize, v.len()),
    };
    match (a.weights(), b.weights()) {
        (Weights::F32(x), Weights::F32(y)) => x.as_ptr() == y.as_ptr() && x.len() == y.len(),
        (Weights::F32Le(x), Weights::F32Le(y)) => x.as_ptr() == y.as_ptr() && x.len() == y.len(),
        (Weights::I8 { q: x, scales: s }, Weights::I8 { q: y, scales: t }) => {
            x.as_ptr() == y.as_ptr() && x.len() == y.len() && sc(s) == sc(t)
        }
        _ => false,
    }
}

/// The view of D over its RAM parameters and the blob's base weights.
fn disc_view<'s, T: Deref<Target = [f32]>>(
    disc1: &'s LayerRam<T>,
    w2: &'s [f32],
    b2: &[f32],
    w: &NavWeights<'s>,
) -> Result<Discriminator<'s>> {
    Ok(Discriminator {
        l1: disc1.view(w.get(TensorId::DiscW1))?,
        w2,
        b2: b2.first().copied().unwrap_or(0.0),
    })
}

/// The policy's layers: the trunk's weights from `w` (never adapted), its biases
/// `[fuse, lstm, critic, cell]` and the actor head (adapted) from the navigator's RAM.
fn policy_view<'s>(
    w: &'s NavWeights<'_>,
    [fuse_b, lstm_b, critic_b, cell_b]: [&'s [f32]; 4],
    actor: Dense<'s>,
) -> Result<Policy<'s>> {
    let dense = |id, b| Dense {
        w: w.get(id),
        b,
        gain: None,
    };
    Ok(Policy {
        fuse: dense(TensorId::FuseW, fuse_b),
        lstm: Lstm {
            wx: w.get(TensorId::LstmWx),
            wh: w.get(TensorId::LstmWh),
            b: lstm_b,
        },
        actor,
        critic: dense(TensorId::CriticW, critic_b),
        cell: (w.dims.map_cells() > 0).then(|| dense(TensorId::CellW, cell_b)),
    })
}

fn ok_update(p: &[f32], g: &[f32], step: f32) -> bool {
    p.iter().zip(g).all(|(a, b)| (a + step * b).is_finite())
}

/// The int16 range of Ψ's compact observations ([`crate::spec::schema::FLAG_COMPACT_PSI`]).
const PSI_Q: f32 = 32767.0;

/// One observation `s` into Ψ's compact form: `q_j = round(s_j * (32767 / a))` (halves
/// away from zero, to the f32 rounding of `|t| + 0.5`, at most 32767 in magnitude) with
/// `a = max |s_j|` (all `q_j` 0 when `a` is 0),
/// read back as `q_j * (a / 32767)`. With `scale` (the [`Footprint::Minimal`] arena) `out`
/// gets the `q_j` as int16, two per float (entry `2i` in the low half of float `i`'s bits),
/// and `scale` the scale; without, `out` gets the values read back ([`psi_load`] gives the
/// same bits from the packed form). `s` is finite (the step checked it).
fn psi_store(s: &[f32], out: &mut [f32], scale: Option<&mut f32>) {
    let mut a = 0.0f32;
    for &v in s {
        let m = libm::fabsf(v);
        if m > a {
            a = m;
        }
    }
    // (All zeros: `inv` is infinite, `0 * inv` NaN, which `as` turns into 0.)
    let (sc, inv) = (a / PSI_Q, PSI_Q / a);
    let packed = scale.is_some();
    if let Some(dst) = scale {
        *dst = sc;
    }
    for (j, &v) in s.iter().enumerate() {
        let t = v * inv;
        let m = ((libm::fabsf(t) + 0.5) as i32).min(PSI_Q as i32);
        let q = if t < 0.0 { -m } else { m };
        let (i, hi) = if packed {
            (j / 2, j % 2 == 1)
        } else {
            (j, false)
        };
        if let Some(o) = out.get_mut(i) {
            *o = if !packed {
                q as f32 * sc
            } else if hi {
                f32::from_bits(o.to_bits() & 0xffff | (q as u16 as u32) << 16)
            } else {
                f32::from_bits(q as u16 as u32)
            };
        }
    }
}

/// The observation [`psi_store`] packed into `packed` with scale `sc`, read back into `out`.
fn psi_load(packed: &[f32], sc: f32, out: &mut [f32]) {
    for (o, p) in out.chunks_mut(2).zip(packed) {
        let b = p.to_bits();
        o[0] = (b as u16 as i16) as f32 * sc;
        if let Some(v) = o.get_mut(1) {
            *v = ((b >> 16) as u16 as i16) as f32 * sc;
        }
    }
}

fn axpy_inplace(p: &mut [f32], g: &[f32], step: f32) {
    for (a, b) in p.iter_mut().zip(g) {
        *a += step * b;
    }
}

/// A region of the arena as the carve splits it: a mutable or a shared slice.
trait Piece: Default {
    fn len(&self) -> usize;
    fn split(self, n: usize) -> (Self, Self);
}

impl Piece for &mut [f32] {
    fn len(&self) -> usize {
        <[f32]>::len(self)
    }
    fn split(self, n: usize) -> (Self, Self) {
        self.split_at_mut(n)
    }
}

impl Piece for &[f32] {
    fn len(&self) -> usize {
        <[f32]>::len(self)
    }
    fn split(self, n: usize) -> (Self, Self) {
        self.split_at(n)
    }
}

/// A group of regions of the arena table (a struct of the `Ram`), told the mode and the
/// inner update's batch after the carve.
trait Group {
    fn finish(&mut self, _full: bool, _b: usize) {}
}

impl<T> Group for LayerRam<T> {}

impl<T> Group for LayerGrad<T> {
    fn finish(&mut self, full: bool, _b: usize) {
        self.full = full;
    }
}

impl<T> Group for InnerWorkOf<T> {
    fn finish(&mut self, _full: bool, b: usize) {
        self.b = b;
    }
}

/// The type of a field of the `Ram`: a region (`T`) or a group of regions (`Kind<T>`).
macro_rules! ram_field {
    ($t:ident) => { $t };
    ($t:ident, $kind:ident) => { $kind<$t> };
}

/// Generates, from the arena table ([`crate::navigator::memory`]'s `arena_table`), the `Ram` struct
/// (one field per region or group of regions, in table order) and its carve.
macro_rules! arena_ram {
    (|$d:ident, $full:ident, $g:ident, $k:ident, $b:ident, $map:ident, $gen_in:ident, $fast:ident, $min:ident, $zero:ident|
     $($field:ident $(: $kind:ident)? in $part:ident
        $({ $($sub:ident = $sl:expr;)* })? $(= $len:expr;)?)*) => {
        /// All RAM regions of the navigator, carved from its arena: `T` is `&mut [f32]`, or
        /// `&[f32]` for a read-only view.
        struct Ram<T> {
            $($field: ram_field!(T $(, $kind)?),)*
        }

        impl<T: Default> Default for Ram<T> {
            fn default() -> Self {
                Ram { $($field: Default::default(),)* }
            }
        }

        impl<T: Piece> Ram<T> {
            /// Carves the regions of lengths `lens` (the arena table's, in its order) from
            /// `arena`; returns them, what is left of `arena`, and whether it was too short
            /// (then the regions that did not fit are empty).
            fn carve_lens(
                arena: T,
                lens: &[usize; NUM_REGIONS],
                full: bool,
                b: usize,
            ) -> (Self, T, bool) {
                let mut rest = arena;
                let mut short = false;
                // The regions in table order (one loop, so that the code stays small), then
                // each to its field.
                let mut parts: [T; NUM_REGIONS] = core::array::from_fn(|i| {
                    let r = core::mem::take(&mut rest);
                    if r.len() < lens[i] {
                        short = true;
                        return T::default();
                    }
                    let (a, tail) = r.split(lens[i]);
                    rest = tail;
                    a
                });
                let mut i = 0;
                let mut next = || {
                    let p = core::mem::take(&mut parts[i]);
                    i += 1;
                    p
                };
                let mut ram = Ram::<T>::default();
                $(
                    $($(ram.$field.$sub = next();)*)?
                    $(first!({ ram.$field = next(); }, $len);)?
                )*
                $($(first!(Group::finish(&mut ram.$field, full, b), $kind);)?)*
                (ram, rest, short)
            }
        }
    };
}

arena_table!(arena_ram);

/// The lengths of the regions of [`crate::navigator::memory`]'s arena table for `d`, `mode`, `k`,
/// `fp` and zero noise or not, checked against `arena` (too short: an error); returns them and the floats used.
fn carve_check(
    arena: &mut [f32],
    d: &Dims,
    mode: AdaptMode,
    k: usize,
    (fp, zero): (Footprint, bool),
) -> Result<([usize; NUM_REGIONS], usize)> {
    let total = arena.len();
    let lens = region_lens(d, mode, k, fp, zero).ok_or(ARENA_TOO_SMALL)?;
    let (_, rest, short) = Ram::carve_lens(arena, &lens, mode == AdaptMode::Full, 1);
    if short {
        return Err(ARENA_TOO_SMALL);
    }
    Ok((lens, total - rest.len()))
}

/// The navigator's arena: its storage and the lengths of the table's regions in it, carved
/// into the `Ram` on every access (the storage may be owned, so the navigator keeps no
/// slices into it).
struct Arena<S> {
    store: S,
    lens: [usize; NUM_REGIONS],
    /// Full mode (the gradients are full weight gradients).
    full: bool,
    /// Entries of Ψ per batch of the inner update (at least 1).
    b: usize,
}

impl<S: AsRef<[f32]> + AsMut<[f32]>> Arena<S> {
    /// The regions, writable. Not inlined: one copy of the carve in the image.
    #[inline(never)]
    fn ram(&mut self) -> Ram<&mut [f32]> {
        Ram::carve_lens(self.store.as_mut(), &self.lens, self.full, self.b).0
    }

    /// The regions, read-only. Not inlined, as [`Arena::ram`].
    #[inline(never)]
    fn view(&self) -> Ram<&[f32]> {
        Ram::carve_lens(self.store.as_ref(), &self.lens, self.full, self.b).0
    }
}

/// The on-device GMAN navigator. `M` is the adaptation mode ([`Full`] or [`Efficient`]),
/// `K` the capacity of the buffer Ψ (the paper's k = 20), `S` the storage of its RAM arena:
/// whoever holds the floats, as long as it lends them as a slice (`AsRef<[f32]> +
/// AsMut<[f32]>`, always the same slice). The default, `&'w mut [f32]`, is an arena the
/// caller owns (a firmware's `static` array, the C API's caller-owned buffer); a host may
/// give the navigator its own (`Vec<f32>`, `Box<[f32]>`) and keep it as one value
/// ([`Navigator::into_storage`] gives the buffer back).
pub struct Navigator<'w, M: Mode, const K: usize, S = &'w mut [f32]> {
    w: NavWeights<'w>,
    cfg: NavConfig,
    rng: Xoshiro128,
    arena: Arena<S>,
    counters: Counters,
    n_buf: usize,
    ready: bool,
    /// A step was begun ([`Navigator::begin_step`]) and not yet finished.
    begun: bool,
    /// The step was begun with [`Navigator::begin_step_defer_g`] and its x_t is not yet
    /// generated ([`Navigator::generate_batch`]).
    g_pending: bool,
    x_valid: bool,
    x_fixed: bool,
    /// The step's G activations (`u2` in [`Ram`]) are those of its x_t (a
    /// [`Navigator::generator_output`] probe reuses them as scratch).
    u2_valid: bool,
    /// Every entry of Ψ recorded its x_t (and, where Ψ keeps it, G's pre-gain output) at its
    /// step, from G at the current θ: the inner update need not regenerate Ψ_x.
    psi_recorded: bool,
    /// [`Footprint::Minimal`]: no Ψ_x (regenerated batch by batch), Ψ's observations packed.
    lean: bool,
    /// With zero noise: the fusion layer's terms of x_t and SE(y) in `fuse_terms` are those
    /// of the current x_t and SE(y) (`Policy::fuse_terms`'s blocks), or `None`.
    fuse_blocks: Option<FuseBlocks>,
    last: AdaptReport,
    /// The inner update in progress (between Ψ filling and its commit when
    /// a [commit delay](crate::spec::InnerRule::commit_delay) > 0).
    upd: Option<Update>,
    /// The update's own generator (ε of L_D), forked from the navigator's when Ψ filled, so
    /// that the steps of the commit window draw what they would draw without the update.
    upd_rng: Xoshiro128,
    _mode: PhantomData<M>,
}

/// z_t ~ N(0, I) into `z` (gman-core's feature `gaussian-noise`; without it a navigator
/// with Gaussian noise is refused by [`Navigator::check_settings`], so nothing calls this).
#[inline]
fn draw_noise(rng: &mut Xoshiro128, z: &mut [f32]) {
    #[cfg(feature = "gaussian-noise")]
    crate::rng::fill_gaussian(rng, z);
    #[cfg(not(feature = "gaussian-noise"))]
    let _ = (rng, z);
}

/// The error of a navigator with Gaussian noise in a build without it.
pub const NO_GAUSSIAN_NOISE: &str =
    "Gaussian noise: needs gman-core's feature `gaussian-noise` (or a `--noise zero` model)";

/// The error of a step whose probabilities or value are not finite.
const NUMERICAL_PROBS: Error = Error::NumericalFault {
    what: "action probabilities",
};

/// What a step changes before it knows whether it will be refused ([`Navigator::step_map`]
/// puts it back when it is).
struct StepMarks {
    rng: Xoshiro128,
    begun: bool,
    g_pending: bool,
    x_valid: bool,
    u2_valid: bool,
    fuse_blocks: Option<FuseBlocks>,
}

/// Where an inner update is: the phases of [`Navigator::inner_update`] in order, each over
/// Ψ's entries a batch ([`InnerWork::b`](crate::adapt::inner::InnerWork::b) entries) per slice.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Phase {
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
struct Update {
    phase: Phase,
    /// The next entry of Ψ in this phase.
    t: usize,
    /// D's ascent steps taken, and to take.
    disc_done: u32,
    disc_steps: u32,
    disc_ok: bool,
    use_d: bool,
    /// ε comes from the update's own generator (a delayed update) instead of the navigator's.
    forked: bool,
    /// Steps of the commit window taken.
    window: u32,
    /// Estimated multiply-adds done and in all (the in-step schedule spreads them evenly).
    done: u64,
    total: u64,
    /// Slices run and upper bound of the slices in all.
    slices: u32,
    /// The first half of a two-half backward pass ran ([`Navigator::split_backward`]).
    half: bool,
    report: AdaptReport,
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
    /// [`Dense::forward`] with a gain. `scratch` holds at least
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
    fn run_generator(&mut self, z_out: Option<(&[f32], &mut [f32])>) -> Result<()> {
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
    /// (where the policy runs the integer path, [`Policy::keeps_fuse_terms`]). Returns the
    /// value; the rest is in RAM.
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

    /// Runs the inner update (lines 15-20 of Algorithm 1) now on the steps buffered in Ψ, then
    /// empties Ψ, whatever the step count and the per-episode cap (which it still counts towards).
    /// Useful at the end of an episode, and for benchmarks; with [`Schedule::Manual`] and a [commit
    /// delay](crate::spec::InnerRule::commit_delay), the commit of the update that started when Ψ
    /// filled (its remaining slices first). Returns whether an update ran: false with nothing
    /// buffered, and false with the inner loop off ([`ModelSpec::adapt`] false), which only empties
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
    fn inner_update(&mut self) -> Result<()> {
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
    fn start_update(&mut self, forked: bool) -> Result<()> {
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
    fn slice_bound(&self) -> u32 {
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
    fn run_slice(&mut self) -> Result<()> {
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
    fn commit_update(&mut self) -> Result<()> {
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
    /// was made by G at the θ of the next inner update: the bits [`Self::generate_psi_x`]
    /// would give (the batched kernels give every row the batch-1 bits). Not when the caller
    /// fixed x_t ([`Navigator::fix_generated_feature`]): Ψ_x is then G's output, regenerated.
    fn record_psi_features(&mut self, n: usize) {
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

#[cfg(test)]
mod tests {
    extern crate std;
    use super::*;
    use std::vec;

    #[test]
    fn carve_uses_exactly_the_documented_layout() {
        for d in [Dims::MCU, Dims::MCU.with_ps(), Dims::PAPER] {
            for mode in [AdaptMode::Full, AdaptMode::Efficient] {
                for (k, fp) in [1usize, 20]
                    .into_iter()
                    .flat_map(|k| [(k, Footprint::Compact), (k, Footprint::Fast)])
                {
                    let n = crate::navigator::memory::arena_len_noise(
                        &d,
                        mode,
                        k,
                        fp,
                        NoiseMode::Gaussian,
                    );
                    assert!(n <= arena_len_with(&d, mode, k, fp));
                    let mut arena = vec![0.0f32; n + 7];
                    let base = arena.as_ptr() as usize;
                    let (lens, used) = carve_check(&mut arena, &d, mode, k, (fp, false)).unwrap();
                    let full = mode == AdaptMode::Full;
                    let (ram, _, short) = Ram::carve_lens(&mut arena[..], &lens, full, 1);
                    assert!(!short);
                    assert_eq!(used, n, "{d:?} {mode:?} k={k} {fp:?}");
                    // Ψ follows the parameters and gradients; the step's work ends the arena.
                    let l = crate::navigator::memory::NavLayout::new_with(&d, mode, k, fp);
                    let at = |s: &[f32]| (s.as_ptr() as usize - base) / 4;
                    let params = l.gen_params + l.disc_params + l.actor_params;
                    assert_eq!(at(ram.psi_s), params + l.fixed_biases + l.grads);
                    assert_eq!(at(ram.gen1.w), 0);
                    assert_eq!(at(ram.cell_prod) + ram.cell_prod.len(), n);
                    let mut small = vec![0.0f32; n - 1];
                    assert!(carve_check(&mut small, &d, mode, k, (fp, false)).is_err());
                }
            }
        }
    }
}
