//! Host side of gman-rs.
#![warn(missing_docs)]
pub mod nav;
pub mod sim;
pub mod simd;
pub mod train;
