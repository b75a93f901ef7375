//! What a rollout records of one step for back-propagation ([`StepRec`]): the data shared by
//! the rollouts ([`super::rollout`], [`super::engine`]), the loss ([`super::a3c`]) and
//! its gradient ([`super::bptt`]).

use gman_core::NUM_ACTIONS;

/// What back-propagation needs of one step.
#[derive(Clone, Debug)]
pub struct StepRec {
    /// Observation s_t.
    pub obs: Vec<f32>,
    /// PS input (empty without PS).
    pub ps: Vec<f32>,
    /// Spatial observation map M_t (empty for a model without a map).
    pub map: Vec<f32>,
    /// Generated feature x_t.
    pub x: Vec<f32>,
    /// Noise z_t.
    pub z: Vec<f32>,
    /// LSTM state before the step.
    pub h_prev: Vec<f32>,
    /// LSTM cell before the step.
    pub c_prev: Vec<f32>,
    /// Previous action probabilities.
    pub prev_probs: Vec<f32>,
    /// Action index.
    pub action: usize,
    /// Reward received.
    pub reward: f32,
    /// Action probabilities.
    pub probs: [f32; NUM_ACTIONS],
    /// The oracle's action distribution (imitation objective only; `None` for A3C).
    pub expert: Option<[f32; NUM_ACTIONS]>,
}
