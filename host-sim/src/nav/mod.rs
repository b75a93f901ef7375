//! The neural navigator on the host: models (methods, parameters, checkpoints, blobs), the
//! episode runner shared by training and evaluation, the training loop, and the evaluation
//! agent.
//!
//! | module | holds |
//! | --- | --- |
//! | [`trainer`] | the training loop, top to bottom (Algorithm 1) |
//! | [`dist`] | a run over several processes (ranks; MPI with `--features mpi`) |
//! | [`a3c`] | the loss L_nav (Sec. 3.2): returns, GAE, output gradients |
//! | [`bptt`] | L_nav's gradient through the policy and G (batched kernels; one BPTT) |
//! | [`meta`] | the second-order meta-gradient (`--meta-order 2`) |
//! | [`step`] | what a rollout records of a step |
//! | [`rollout`] | worker buffers, evaluation episodes, pieces shared with training |
//! | `inner` | the inner update when Ψ is full, its tally, an episode's closing statistics |
//! | [`lockstep`] | what the vectorised episodes share: settings, slots, inputs, bootstrap, batched BPTT |
//! | [`vec_rollout`] | `B` training episodes in lockstep (`--batch-envs`) |
//! | [`vec_adapt`] | the same for the methods with an inner loop: one navigator per episode |
//! | [`state`] | what a checkpoint restores; the typed, versioned trainer settings |
//! | [`run_dir`] | `metrics.csv` and the run directory's lock |
//! | [`model`], [`agent`] | methods, parameters, blobs; the evaluation agent |
//!
//! Every episode, in training and in evaluation, runs gman-core's [`Navigator`] — the code
//! the robot runs — over weights held here. Training only adds the outer loop.
//!
//! [`Navigator`]: gman_core::navigator::Navigator

pub mod a3c;
pub mod agent;
pub mod bptt;
pub mod dist;
mod inner;
pub mod lockstep;
pub mod meta;
pub mod model;
#[cfg(feature = "mpi")]
pub mod mpi;
pub mod rollout;
pub mod run_dir;
pub mod state;
pub mod step;
pub mod trainer;
pub mod vec_adapt;
pub mod vec_rollout;

/// Capacity k of the navigation buffer Ψ (the paper's k = 20).
pub const K: usize = 20;
