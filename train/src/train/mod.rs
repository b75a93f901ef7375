//! Training of a navigation model (Algorithm 1 with the A3C loss L_nav): the outer loop,
//! the rollout engine that runs a worker's episodes through gman-core's navigator, the loss
//! and its gradients, the inner update, the run over several processes, the run directory
//! and the checkpoint's trainer settings. The models it trains are [`crate::model`]'s.
//!
//! | module | holds |
//! | --- | --- |
//! | [`trainer`] | the training loop, top to bottom (Algorithm 1) |
//! | [`engine`] | the rollout engine: `B` training episodes in lockstep (`--batch-envs`), `B = 1`, the baselines and `--meta-order 2` included |
//! | `lanes` | the engine's loop over its lanes: the `Lanes` trait, the ticks, the segments' backward |
//! | `lanes_shared` | the engine's lanes without an inner loop: one set of parameter views |
//! | `lanes_nav` | the engine's lanes with an inner loop: one navigator per episode |
//! | [`lockstep`] | the engine's frame: settings, slots, inputs, bootstrap, the waiting segments and their batched BPTT |
//! | [`rollout`] | worker buffers, an episode's summary, bootstrap values, D's carry-over |
//! | [`step`] | what a rollout records of a step |
//! | `inner` | the inner update when Ψ is full, its tally, an episode's closing statistics |
//! | [`a3c`] | the loss L_nav (Sec. 3.2): returns, GAE, output gradients |
//! | [`bptt`] | L_nav's gradient through the policy and G (batched kernels; one BPTT) |
//! | [`meta`] | the second-order meta-gradient (`--meta-order 2`) |
//! | [`dist`] | a run over several processes (ranks; MPI with `--features mpi`) |
//! | [`state`] | what a checkpoint restores; the typed, versioned trainer settings |
//! | [`run_dir`] | `metrics.csv` and the run directory's lock |
//!
//! Every episode runs gman-core's [`Navigator`] — the code the robot runs — over weights
//! held here; training adds the losses and the outer loop.
//!
//! [`Navigator`]: gman_core::navigator::Navigator

pub mod a3c;
pub mod bptt;
pub mod dist;
pub mod engine;
mod inner;
mod lanes;
mod lanes_nav;
mod lanes_shared;
pub mod lockstep;
pub mod meta;
#[cfg(feature = "mpi")]
pub mod mpi;
pub mod rollout;
pub mod run_dir;
pub mod state;
pub mod step;
pub mod trainer;
