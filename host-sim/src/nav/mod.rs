//! The neural navigator on the host: models (methods, parameters, checkpoints, blobs), the
//! episode runner shared by training and evaluation, the A3C loss, and the evaluation agent.
//!
//! Every episode, in training and in evaluation, runs gman-core's [`Navigator`] — the code
//! the robot runs — over weights held here. Training only adds the outer loop.
//!
//! [`Navigator`]: gman_core::navigator::Navigator

pub mod a3c;
pub mod agent;
pub mod bptt;
pub mod meta;
pub mod model;
pub mod rollout;
pub mod run_dir;
pub mod state;
pub mod step;
pub mod trainer;
pub mod vec_rollout;

/// Capacity k of the navigation buffer Ψ (the paper's k = 20).
pub const K: usize = 20;
