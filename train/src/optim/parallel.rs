//! Deterministic data-parallel gradient accumulation.
//!
//! A batch of `n` samples is cut into a fixed number of contiguous chunks (independent of
//! the number of threads). Each chunk accumulates its samples' gradients sequentially into its
//! own buffer, the chunks run in parallel on rayon, and the buffers are then added in chunk
//! order. Floating-point sums therefore happen in the same order whatever the thread count or
//! scheduling, so a seed fixes the result bit for bit.

use std::ops::{AddAssign, Range};

use anyhow::Result;
use rayon::prelude::*;

use super::params::ParamSet;

/// Per-chunk gradient buffers and scratch space, reused across steps.
#[derive(Debug)]
pub(crate) struct ChunkPool<S> {
    /// One `(gradient buffer, scratch)` per chunk.
    pub chunks: Vec<(ParamSet, S)>,
}

/// The contiguous range of chunk `k` of `n_chunks` over `n` samples (sizes differ by at most
/// one; empty when `n < n_chunks`).
pub(crate) fn chunk_range(n: usize, n_chunks: usize, k: usize) -> Range<usize> {
    let n_chunks = n_chunks.max(1);
    let base = n / n_chunks;
    let rem = n % n_chunks;
    let start = k * base + k.min(rem);
    let len = base + usize::from(k < rem);
    start..start + len
}

impl<S: Send> ChunkPool<S> {
    /// `n_chunks` (at least 1) zeroed gradient twins of `like`, each with a scratch from
    /// `scratch()`.
    pub fn new(like: &ParamSet, n_chunks: usize, scratch: impl Fn() -> S) -> ChunkPool<S> {
        ChunkPool {
            chunks: (0..n_chunks.max(1))
                .map(|_| (like.zeros_like(), scratch()))
                .collect(),
        }
    }

    /// Runs `work(range, grads, scratch)` for every chunk of `0..n` in parallel (grads
    /// zeroed first), then writes the chunk gradients' sum, added in chunk order, into
    /// `total` (overwritten). Returns the chunks' statistics summed in chunk order.
    pub(crate) fn accumulate<R, F>(&mut self, n: usize, total: &mut ParamSet, work: F) -> Result<R>
    where
        R: Send + Default + AddAssign,
        F: Fn(Range<usize>, &mut ParamSet, &mut S) -> Result<R> + Sync,
    {
        let k = self.chunks.len();
        let stats: Vec<Result<R>> = self
            .chunks
            .par_iter_mut()
            .enumerate()
            .map(|(i, (g, s))| {
                g.zero();
                work(chunk_range(n, k, i), g, s)
            })
            .collect();
        let mut sum = R::default();
        for r in stats {
            sum += r?;
        }
        total.zero();
        for (g, _) in &self.chunks {
            total.add_assign(g)?;
        }
        Ok(sum)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ranges_cover_the_batch_once() {
        for n in 0..40 {
            for k in 1..10 {
                let mut next = 0;
                for i in 0..k {
                    let r = chunk_range(n, k, i);
                    assert_eq!(r.start, next);
                    next = r.end;
                }
                assert_eq!(next, n);
            }
        }
    }
}
