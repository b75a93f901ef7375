//! # gman-core
//!
//! The `no_std`, allocation-free half of **gman-rs**, a Rust implementation of GMAN, the
//! Generative Meta-Adversarial Network for navigating to unseen object categories
//! (Zhang et al., ECCV 2022). A robot controller links this crate and runs, every control
//! step, the feature generator G, the discriminator D and the navigation policy, and every
//! `k` steps the on-device adaptation of Algorithm 1. The host trainer (`gman-host-sim`) calls
//! the very same code for its inner loop, so what was meta-learned is exactly what runs.
//!
//! ## The device loop
//! Everything a controller needs is at the crate root: a [`Blob`] read in place (e.g. from
//! flash), [`NavWeights`] viewing it, a [`Navigator`] whose whole state lives in a
//! caller-owned arena of [`arena_len`] floats (a compile-time constant), and one
//! [`Navigator::step_map`] per camera frame; every `K`-th step also runs the inner update.
//! The integration guide (`docs/integrate.md`) covers the C API, static sizing, scheduling
//! the inner update and model updates in the field.
//!
//! ```
//! use gman_core::{arena_len, Action, AdaptMode, Blob, Dims, Efficient, NavWeights, Navigator};
//!
//! const DIMS: Dims = Dims::MCU.with_map(3, 3, 8); // the shipped map models' sizes
//! const K: usize = 20; // an inner update every 20 steps
//! const ARENA: usize = arena_len(&DIMS, AdaptMode::Efficient, K);
//! static BLOB: &[u8] = include_bytes!("../../host-sim/models/gman-map3-b16-mcu-int8-seed5.gman");
//!
//! # fn main() -> gman_core::Result<()> {
//! # let mut arena = vec![0.0f32; ARENA]; // a `static` array on a microcontroller
//! let blob = Blob::parse(BLOB)?; // header, format version, CRC, every tensor
//! let weights = NavWeights::from_blob(&blob, &DIMS)?; // views into the blob, no copy
//! let mut nav: Navigator<'_, Efficient, K> = Navigator::new(weights, &mut arena, blob.nav_config())?;
//! nav.reset(&[0.5; DIMS.attr], 7)?; // the target's attribute vector SE(y), a seed
//! let (mut obs, mut map) = ([0.0f32; DIMS.feat], [0.0f32; DIMS.map_len()]);
//! for t in 0..25 {
//!     obs.fill(0.4); // the camera's pooled embedding s_t ...
//!     map.fill(0.4); // ... and its 3 x 3 map, features in [0, 1]
//!     let out = nav.step_map(&obs, &map, &[])?;
//!     assert_eq!(out.adapted, t == K - 1); // the inner update ends every K-th step
//!     if out.action == Action::Done { break; }
//! }
//! # Ok(()) }
//! ```
//!
//! ## Map from the paper to the code
//! | paper | here |
//! |---|---|
//! | G(SE(y), z), parameters θ (Sec. 4.1) | [`nets::generator::Generator`] |
//! | D, parameters ω; L_D (Eq. 1, WGAN-GP); L_G (Eq. 2) | [`nets::discriminator::Discriminator`] |
//! | L_ad (Eq. 3) and its gradients; the inner loop's steps | [`adapt`], [`adapt::inner`] |
//! | LSTM actor-critic policy π, parameters φ | [`nets::policy`], [`nn::lstm`], [`nn::dense`] |
//! | Algorithm 1 on the device: the step, Ψ, the inner update | [`navigator`] |
//! | every tensor, its shape, group and quantisation; the model flags | [`spec::schema`] |
//! | weights | [`blob`] (postcard, CRC-32, int8/f32, zero-copy; the wire format of [`spec::schema`]) |
//! | sizes | [`spec::preset`] (`Paper`, `Mcu`, user-defined) |
//!
//! ## Modules
//! | module | what it holds |
//! |---|---|
//! | [`spec`] | the model's settings ([`spec::ModelSpec`]), sizes ([`spec::preset`]), tensors and flags ([`spec::schema`]), the action space ([`Action`]) |
//! | [`blob`] | the weight format: [`Blob`], its CRC-32 ([`blob::crc32`]), int8 rows ([`blob::quant`]), seeded weights ([`blob::seeded`]) |
//! | [`nn`] | the kernels: matrices and their formats, batched products, int8 kernels, activations, dense, LSTM |
//! | [`nets`] | the networks G, D and π |
//! | [`adapt`] | L_ad and its gradients, the inner loop's steps ([`adapt::inner`]) |
//! | [`navigator`] | the on-device [`Navigator`] and its arena ([`navigator::memory`]) |
//! | [`rng`] | the deterministic generator every draw comes from |
//! | [`error`] | [`Error`] and its parts |
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

pub mod adapt;
pub mod blob;
pub mod error;
pub mod navigator;
pub mod nets;
pub mod nn;
pub mod rng;
pub mod spec;

// What an integrator needs, at the root (the device loop above uses only these).
pub use blob::{Blob, Header};
pub use error::{BlobError, Error, Result, ShapeError};
pub use navigator::memory::{arena_len, try_arena_len, Footprint};
pub use navigator::{
    AdaptReport, Counters, Efficient, Full, Mode, NavConfig, NavWeights, Navigator, Schedule,
    Selection, StepOutput,
};
pub use spec::action::{Action, NUM_ACTIONS};
pub use spec::preset::{Dims, Mcu, Paper, Preset};
pub use spec::schema::AdaptMode;

/// Width of the semantic embedding SE(y) (the attribute vector), fixed by the data.
pub const ATTR_DIM: usize = 45;
/// Width of an observation embedding s_t and of a generated feature x_t.
pub const FEATURE_DIM: usize = 512;
