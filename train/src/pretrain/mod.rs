//! The pre-training stages of GMAN (before `gman train`): the feature generator G and the PS
//! module.
//!
//! Every forward and backward pass of a network runs on gman-core's kernels
//! ([`gman_core::nn::dense::Dense`], [`gman_core::nets::generator::Generator`], ...), so the host trains
//! exactly what the device runs; these modules add batching, data and I/O on top of
//! [`crate::optim`].
//!
//! Module map:
//! * [`generator`]: G's parameters (the schema's tensor names) and owned buffers.
//! * [`critic`]: the conditional WGAN-GP critic of feature-generator pre-training (not the
//!   policy's value head, whose tensors the schema calls `CriticW`/`CriticB`); its penalty
//!   gradient is gman-core's one closed form
//!   ([`gman_core::nets::discriminator::add_penalty_grad`]).
//! * [`fg`]: `gman pretrain-fg` (paper Sec. 4.1).
//! * [`ps`]: `gman pretrain-ps` (paper Sec. 5.2): the PS module's BCE gradient and training,
//!   and, re-exported from the private `ps_net`, the network the PS variants run at inference.

pub mod critic;
pub mod fg;
pub mod generator;
pub mod ps;
mod ps_net;

// The plumbing these modules build on, under the paths they have always used (`super::adam`).
use crate::optim::{adam, checkpoint, dims_json, parallel, params, rng_from_bytes, rng_to_bytes};
