//! Host side of gman-rs: the simulator ([`sim`]: the gman-sim crate with the evaluator and
//! the renderer), pre-training ([`pretrain`]), the
//! navigation models ([`model`]), their training ([`train`]) and evaluation ([`eval`]), the
//! optimiser and checkpoints ([`optim`]), the PS network ([`ps`]), Fig. 3 as a measurement
//! ([`emd_report`]) and the AVX2 kernels ([`simd`]). The `gman` binary's commands are in
//! `src/cli/`, one file each. `ARCHITECTURE.md` at the repository root maps the paper's
//! equations to functions and draws the folders' dependency direction.
#![warn(missing_docs)]
pub mod blob_edit;
pub mod emd_report;
pub mod eval;
pub mod model;
pub mod optim;
pub mod pretrain;
pub mod progress;
pub mod ps;
pub mod seeded;
pub mod sim;
pub mod simd;
pub mod train;
