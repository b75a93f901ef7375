//! Host side of gman-rs.
#![warn(missing_docs)]
pub mod emd_report;
pub mod nav;
pub mod optim;
pub mod pretrain;
pub mod progress;
pub mod ps;
pub mod sim;
pub mod simd;

/// The earlier home of [`optim`] and [`pretrain`] (one `train/` folder held both), kept so
/// that `gman_host_sim::train::...` paths keep working.
pub mod train {
    pub use crate::optim::{
        adam, checkpoint, dims_json, parallel, params, rng_from_bytes, rng_to_bytes,
    };
    pub use crate::pretrain::{critic, fg, generator, ps};
}
