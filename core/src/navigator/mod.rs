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
//! * θ: all of G in [`AdaptMode::Full`](crate::AdaptMode::Full); the per-unit gains and biases of G's two layers in
//!   [`AdaptMode::Efficient`](crate::AdaptMode::Efficient).
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
//! Ψ keeps no z_t and one x_t for all its entries (in every [`Footprint`](crate::Footprint)), and the
//! update's backward pass runs G and D once for all of Ψ (its entries share one noise, so
//! they form one group whose coefficients are summed, `inner::score_backward_part`).
//!
//! Algorithm 1 as printed records a step only when `t` is not a multiple of `k` (lines
//! 10-13), so its buffer would hold `k − 1` samples at each update. Here every step is
//! recorded and the update runs when Ψ holds `k` samples, i.e. every `k` steps.
//!
//! # Safety
//! Non-finite observations or attribute vectors are rejected with
//! [`Error::NonFiniteInput`](crate::Error::NonFiniteInput). An adaptation step whose loss is non-finite or above
//! [`NavConfig::loss_bound`], or whose update would make a parameter non-finite, is not
//! applied (it is *rolled back* before it is written, so no copy of the parameters is needed)
//! and counted in [`Counters::rollbacks`]. An action is only returned from finite
//! probabilities; otherwise [`Error::NumericalFault`](crate::Error::NumericalFault) is returned.
//!
//! # Where each part lives
//! * `config`: [`NavConfig`], the compile-time [`Mode`], [`Selection`], [`Schedule`] and
//!   what calls report ([`StepOutput`], [`Counters`], [`AdaptReport`], [`BufferView`]);
//! * `weights`: [`NavWeights`] and the layer views over the weights, the arena's adapted
//!   copies and their gradients;
//! * `arena`: the carve of the arena into its regions ([`memory`] lays them out);
//! * `psi`: the storage of Ψ's observations (f32 or compact int16);
//! * `state`: the [`Navigator`] itself, its construction, reset and accessors;
//! * `step`: one control step, and the in-step slices of an inner update;
//! * `update`: the inner update in slices, and its commit.
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

mod arena;
mod config;
mod psi;
mod state;
mod step;
mod update;
mod weights;

pub use crate::spec::schema::{Emd, NoiseMode, StepRule};
pub use config::{
    select_action, AdaptReport, BufferView, Counters, Efficient, Full, Mode, NavConfig, Schedule,
    Selection, StepOutput,
};
pub use state::{Navigator, NO_GAUSSIAN_NOISE};
pub use weights::NavWeights;
