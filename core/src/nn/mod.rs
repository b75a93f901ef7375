//! The kernels every network is built from, on slices with explicit shapes: matrices and
//! their weight formats ([`matrix`]), the batched matrix products ([`batch`], `batch_cols`),
//! the int8 kernels ([`qkernel`]), activations ([`activation`]), a dense layer ([`dense`]) and
//! an LSTM cell ([`lstm`]).

pub mod activation;
pub mod batch;
pub(crate) mod batch_cols;
pub mod dense;
pub mod lstm;
pub mod matrix;
pub mod qkernel;
