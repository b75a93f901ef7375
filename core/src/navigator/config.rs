//! Settings of a navigator ([`NavConfig`], the compile-time [`Mode`], action [`Selection`] and
//! the inner update's [`Schedule`]) and what its calls report ([`StepOutput`], [`Counters`],
//! [`AdaptReport`], [`BufferView`]).

use crate::blob::{Blob, Header};
use crate::navigator::memory::{AdaptMode, Footprint};
use crate::nets::discriminator::{LdConfig, LdValue};
use crate::rng::{uniform, Xoshiro128};
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
    /// Only when the caller asks ([`Navigator::adapt_now`](crate::Navigator::adapt_now) or [`Navigator::clear_buffer`](crate::Navigator::clear_buffer));
    /// `step()` refuses to run while Ψ is full. A trainer uses this to take the navigation
    /// loss's gradient at the parameters a segment was run with, before they adapt. The
    /// update itself is the same code. With a
    /// [commit delay](crate::spec::InnerRule::commit_delay) `d > 0` the `d` steps after Ψ
    /// fills run (unrecorded) before `step()` asks for `adapt_now()`.
    Manual,
    /// With a [commit delay](crate::spec::InnerRule::commit_delay) `d >= 1` (required): `step()`
    /// never computes the update; the caller runs it in slices with [`Navigator::adapt_slice`](crate::Navigator::adapt_slice) from
    /// a context of lower priority than the control loop (an RTIC task, a lower interrupt priority,
    /// the main loop between timer ticks). The update commits at the end of the `d`-th step after Ψ
    /// filled, as with `Auto`; a step that would reach that point before every slice ran returns
    /// [`Error::UpdateNotReady`](crate::Error::UpdateNotReady) and changes nothing.
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
    /// [`Schedule::Background`] the caller does ([`Navigator::adapt_slice`](crate::Navigator::adapt_slice)). 0 (the
    /// default): the update runs inside the step that fills Ψ. At most
    /// [`MAX_COMMIT_DELAY`](crate::spec::schema::MAX_COMMIT_DELAY).
    ///
    /// `int8_activations` is how a blob's weights run ([`NavWeights::from_blob`](crate::NavWeights::from_blob) applies
    /// it); the navigator does not read it here.
    pub model: ModelSpec,
    /// [`Navigator::new`](crate::Navigator::new) refuses weights whose `model.adapt_mode` is not the navigator's
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
    /// [`Navigator::arena_len_for`](crate::Navigator::arena_len_for) floats for it.
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
    /// [`Blob::parse`]), so the result is accepted by [`Navigator::new`](crate::Navigator::new) as far as the rates
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
    pub(super) fn ld(&self) -> LdConfig {
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

/// Counters, per episode (reset by [`Navigator::reset`](crate::Navigator::reset)) and over the navigator's life.
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
/// [`Navigator::buffer`](crate::Navigator::buffer).
#[derive(Clone, Copy, Debug)]
pub struct BufferView<'a> {
    /// Observations s_t (`n x feat`).
    pub obs: &'a [f32],
    /// Noise z_t (`n x noise`; empty with [`NoiseMode::Zero`](crate::spec::schema::NoiseMode::Zero), where every z_t is zero and
    /// Ψ keeps none).
    pub noise: &'a [f32],
    /// Action probabilities a_t (`n x 6`).
    pub probs: &'a [f32],
    /// LSTM hidden states h_t after each step (`n x lstm_hidden`).
    pub hidden: &'a [f32],
}
