//! # gman-core
//!
//! The `no_std`, allocation-free half of **gman-rs**, a Rust implementation of GMAN, the
//! Generative Meta-Adversarial Network for navigating to unseen object categories
//! (Zhang et al., ECCV 2022). A robot controller links this crate and runs, every control
//! step, the feature generator G, the discriminator D and the navigation policy, and every
//! `k` steps the on-device adaptation of Algorithm 1. The host trainer (`gman-host-sim`) calls
//! the very same code for its inner loop, so what was meta-learned is exactly what runs.
//!
//! ## Map from the paper to the code
//! | paper | here |
//! |---|---|
//! | G(SE(y), z), parameters θ (Sec. 4.1) | [`generator::Generator`] |
//! | D, parameters ω; L_D (Eq. 1, WGAN-GP); L_G (Eq. 2) | [`discriminator::Discriminator`] |
//! | L_ad (Eq. 3) and its gradients | [`adapt`] |
//! | LSTM actor-critic policy π, parameters φ | [`lstm`], [`dense`] |
//! | every tensor, its shape, group and quantisation; the model flags | [`schema`] |
//! | weights | [`blob`] (postcard, CRC-32, int8/f32, zero-copy; the wire format of [`schema`]) |
//! | sizes | [`preset`] (`Paper`, `Mcu`, user-defined) |
//!
//! ## Design rules
//! * No heap, no `unsafe`, no panics on any input: every buffer is provided by the caller and
//!   every function that can meet bad input returns [`Error`].
//! * Deterministic: same inputs and seed, same bits, on x86 and on a Cortex-M4F (no fused
//!   multiply-add, a fixed summation order, `libm` for transcendental functions).
//! * Kernels take slices with explicit shapes (like llm.c) so the host trainer can run them on
//!   `Vec`s while the device runs them on static arrays sized by `const fn`s of the preset.
#![no_std]
#![forbid(unsafe_code)]
#![warn(missing_docs)]

pub mod action;
pub mod activation;
pub mod ad_loss;
pub mod adapt;
pub mod batch;
pub mod batch_cols;
pub mod blob;
pub mod crc32;
pub mod dense;
pub mod discriminator;
pub mod error;
pub mod generator;
pub mod inner;
pub mod lstm;
pub mod matrix;
pub mod memory;
pub mod navigator;
pub mod policy;
pub mod preset;
pub mod qkernel;
pub mod quant;
pub mod rng;
pub mod schema;
pub mod seeded;

pub use action::{Action, NUM_ACTIONS};
pub use error::{BlobError, Error, Result, ShapeError};
pub use preset::{Dims, Mcu, Paper, Preset};

/// Width of the semantic embedding SE(y) (the attribute vector), fixed by the data.
pub const ATTR_DIM: usize = 45;
/// Width of an observation embedding s_t and of a generated feature x_t.
pub const FEATURE_DIM: usize = 512;
