//! Host side of gman-rs.
#![warn(missing_docs)]
pub mod emd_report;
pub mod nav;
pub mod sim;
pub mod train;
