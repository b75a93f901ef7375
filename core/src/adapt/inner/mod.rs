//! The inner update of Algorithm 1 (lines 15-19) over the buffer Ψ, **batched**: the
//! entries go through G and D as matrices ([`crate::nn::batch`]), `b` at a time, in fixed
//! caller buffers ([`InnerWork`]; the navigator's are regions of its arena, see
//! [`crate::navigator::memory::adapt_batch`]).
//!
//! # The same bits as one entry at a time
//! Every function here gives exactly the bits of the batch-1 code it replaced
//! ([`Discriminator::ld_loss`] on one entry at a time, and the former one-entry-at-a-time
//! bodies of [`crate::adapt::adapt_generator_grad`] and
//! [`crate::adapt::adapt_generator_grad_cos`], which are now these passes with `b = 1`),
//! whatever `b`:
//! * the batched kernels give every vector the bits of the batch-1 kernel (the contract of
//!   [`crate::nn::batch`]), and every input keeps its segmentation (`[z; attr]` for G's first
//!   layer);
//! * every gradient element receives its `+=` in the order of the batch-1 loops: entry by
//!   entry, and within an entry real, fake, interpolate for D. The small vectors (biases,
//!   gains, D's output layer) are accumulated in an entry loop; a full weight gradient by one
//!   [`crate::nn::batch::outer_acc_batch_with`] per batch whose vectors are laid out in exactly
//!   that order (`alpha = 1` and the coefficient folded into `dy`: `1 · (c v) = c v`, and a
//!   zero row is skipped as the batch-1 loop skips it);
//! * G is not changed inside one inner update, so the features `x_t` are generated once
//!   ([`generate`]) and read by every pass (regenerating them per pass gives the same bits).
//!
//! `core/tests/batched_inner.rs` pins this against a transcription of the batch-1 code, for
//! batch sizes 1, 2, 3, n and more than n; whole episodes are checked against the f64 oracle
//! of `gman-tests` and between the host and the Cortex-M4F (QEMU).
//!
//! # Files
//! `work` holds the buffers and the inputs, `forward` G's forward pass, `disc` D's side and
//! L_D ([`ld_grad_sum`]), `score` L_ad's scores ([`adapt_scores`], [`adapt_grad`]) and
//! `backward` θ's gradient of the scores ([`score_backward`]).
//!
//! [`Discriminator::ld_loss`]: crate::nets::discriminator::Discriminator::ld_loss

mod backward;
mod disc;
mod forward;
mod score;
mod work;

pub(crate) use backward::shared_backward_half;
pub use backward::{score_backward, score_backward_part};
pub use disc::{ld_grad_sum, ld_grad_sum_from};
pub use forward::generate;
pub(crate) use forward::generate_mix;
pub use score::{adapt_grad, adapt_scores, adapt_scores_part};
pub(crate) use work::x_rows;
pub use work::{AdaptInputs, InnerWork, InnerWorkOf, NO_COSSIM};
