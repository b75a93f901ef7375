//! Host side of gman-rs.
#![warn(missing_docs)]
pub mod sim;
