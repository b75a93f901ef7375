//! Shared helpers of the end-to-end tests of gman-rs.
//!
//! [`reference`](mod@reference) is an f64 implementation of GMAN's networks and losses written with plain
//! loops over `Vec<f64>`, independently of gman-core's kernels; tests compare the core's f32
//! results and analytic gradients against it (and against its finite differences).
#![warn(missing_docs)]

pub mod reference;
