//! Training side of gman-rs: the simulator ([`sim`]: the gman-sim crate with the parallel
//! evaluator), pre-training of G and of the PS network ([`pretrain`]), the navigation models
//! ([`model`]), their training ([`train`]) and evaluation ([`eval`]), the optimiser and
//! checkpoints ([`optim`]), Fig. 3 as a measurement ([`emd_report`]), blob re-encoding
//! ([`blob_edit`]), progress reporting ([`progress`]) and the AVX2 kernels ([`simd`]). No
//! command line, plots or terminal bars: the `gman` binary (gman-host-sim) parses the
//! arguments and draws the bars, gman-render draws the pictures. `ARCHITECTURE.md` at the
//! repository root maps the paper's equations to functions and draws the folders' dependency
//! direction.
#![warn(missing_docs)]
pub mod blob_edit;
pub mod emd_report;
pub mod eval;
pub mod model;
pub mod optim;
pub mod pretrain;
pub mod progress;
pub mod sim;
pub mod simd;
pub mod train;
