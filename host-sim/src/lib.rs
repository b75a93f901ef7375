//! The package of the `gman` command line (`src/main.rs`, one file per command in `src/cli/`).
//! Its library is gman-train re-exported whole, so that the package's tests, examples and
//! benches name the host's layers as `gman_host_sim::sim` (the gman-sim crate with the
//! evaluator), `gman_host_sim::model`, `gman_host_sim::train`, and so on, with what only the
//! host's programs use: the Fig. 3 picture ([`fig3`]) and seeded blobs for benchmarks and
//! tests ([`seeded`]).
//! `ARCHITECTURE.md` at the repository root draws the crates and their dependency direction.
#![warn(missing_docs)]

pub use gman_train::*;

pub mod fig3;
pub mod seeded;
