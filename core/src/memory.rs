//! RAM accounting: how many bytes of RAM the on-device navigator needs, per preset and
//! adaptation mode, as `const fn`s so a firmware can size its static arena at compile time.
//!
//! # The two adaptation modes
//! * [`AdaptMode::Full`] — the paper's inner loop: every generator parameter θ, the
//!   discriminator ω and the actor head of φ are f32 tensors in RAM and all of them are
//!   updated by SGD (for hosts and Cortex-A class devices).
//! * [`AdaptMode::Efficient`] — for microcontrollers: the base weights of G, D and the actor
//!   head stay int8 in flash and are never written; each of their layers carries a per-unit
//!   gain (initialised to 1) and bias in RAM, and only those are adapted (θ and φ's adapted
//!   part become `2 (H + F)` and `2 · 6` numbers; ω becomes gain, bias and output layer of D).
//!
//! In both modes the remaining policy weights (fusion layer, LSTM, critic) are read in place
//! from the blob (int8 or f32); only their biases are copied to RAM. Gradients get a buffer of
//! the same size as what they update. Rollback of a rejected adaptation step needs no copy:
//! the update is validated (finite, bounded) before it is written.
//!
//! `cargo run -p gman-core --example memory_table` prints the figures of both presets and
//! modes (from [`NavLayout::total_bytes`] and [`int8_weight_bytes`]); the README quotes them.

use crate::preset::{sat, tri, Dims};
use crate::NUM_ACTIONS;

pub use crate::schema::AdaptMode;

const fn max(a: usize, b: usize) -> usize {
    if a > b {
        a
    } else {
        b
    }
}

/// Sizes (in f32 elements) of every RAM region of the navigator.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct NavLayout {
    /// Adapted generator parameters (θ or its gains and biases).
    pub gen_params: usize,
    /// Discriminator parameters in RAM (ω or its gains, biases and output layer).
    pub disc_params: usize,
    /// Adapted actor-head parameters.
    pub actor_params: usize,
    /// Biases of the non-adapted policy layers (fusion, LSTM, critic).
    pub fixed_biases: usize,
    /// Gradient buffers (same size as the three adapted groups).
    pub grads: usize,
    /// The navigation buffer Ψ: `k` observations, noises, action probabilities and LSTM
    /// hidden states (the actor head's inputs).
    pub psi: usize,
    /// Per-step activations and scratch of G, D, the policy and the adaptation.
    pub work: usize,
}

impl NavLayout {
    /// The layout for `dims`, `mode` and buffer capacity `k`. When a size does not fit in
    /// `usize` (absurd dims from a hostile blob, see [`NavLayout::try_new`]) every field is
    /// `usize::MAX`, so the arena asked for can never be provided and nothing wraps.
    pub const fn new(d: &Dims, mode: AdaptMode, k: usize) -> NavLayout {
        match NavLayout::try_new(d, mode, k) {
            Some(l) => l,
            None => NavLayout {
                gen_params: usize::MAX,
                disc_params: usize::MAX,
                actor_params: usize::MAX,
                fixed_biases: usize::MAX,
                grads: usize::MAX,
                psi: usize::MAX,
                work: usize::MAX,
            },
        }
    }

    /// The layout for `dims`, `mode` and buffer capacity `k`, or `None` when any region or
    /// the total byte count overflows `usize` (checked arithmetic throughout).
    pub const fn try_new(d: &Dims, mode: AdaptMode, k: usize) -> Option<NavLayout> {
        let (h, f, z, a, dh, lh, e) = (
            d.gen_hidden,
            d.feat,
            d.noise,
            d.attr,
            d.disc_hidden,
            d.lstm_hidden,
            d.embed,
        );
        let gain = matches!(mode, AdaptMode::Efficient);
        let gen_params = match mode {
            AdaptMode::Full => tri!(d.checked_gen_params()),
            AdaptMode::Efficient => tri!(tri!(h.checked_add(f)).checked_mul(2)),
        };
        let disc_params = match mode {
            AdaptMode::Full => tri!(d.checked_disc_params()),
            AdaptMode::Efficient => tri!(tri!(dh.checked_mul(3)).checked_add(1)),
        };
        let lh4 = tri!(lh.checked_mul(4));
        let actor_params = match mode {
            AdaptMode::Full => tri!(tri!(lh.checked_mul(NUM_ACTIONS)).checked_add(NUM_ACTIONS)),
            AdaptMode::Efficient => 2 * NUM_ACTIONS,
        };
        let map = tri!(d.map_rows.checked_mul(d.map_cols)) > 0;
        let cell_b = if map { d.cell_embed } else { 0 };
        let fixed_biases = tri!(tri!(tri!(e.checked_add(lh4)).checked_add(1)).checked_add(cell_b));
        let grads = tri!(tri!(gen_params.checked_add(disc_params)).checked_add(actor_params));
        let per_step = tri!(tri!(tri!(f.checked_add(z)).checked_add(NUM_ACTIONS)).checked_add(lh));
        let psi = tri!(k.checked_mul(per_step));
        // With gains (Efficient) some buffers exist, otherwise they are empty (`g` is 0 or 1).
        let g = if gain { 1 } else { 0 };
        let gen_work = tri!(sum(&[g * h, h, g * f, f, f, h, h, max(f, h)]));
        let disc_work = tri!(sum(&[
            g * dh,
            tri!(dh.checked_mul(3)),
            tri!(f.checked_mul(2))
        ]));
        let adapt_work = tri!(sum(&[
            tri!(k.checked_mul(3)),
            tri!(k.checked_mul(NUM_ACTIONS)),
            f
        ]));
        let policy_work = tri!(sum(&[
            f,
            e,
            lh4,
            lh4,
            4 * NUM_ACTIONS,
            g * NUM_ACTIONS,
            z,
            a,
            d.ps,
            tri!(d.checked_cell_out()),
            if map { f } else { 0 }
        ]));
        let work = tri!(sum(&[gen_work, disc_work, adapt_work, policy_work]));
        let l = NavLayout {
            gen_params,
            disc_params,
            actor_params,
            fixed_biases,
            grads,
            psi,
            work,
        };
        // The total in floats and in bytes must fit as well.
        tri!(tri!(l.checked_total_floats()).checked_mul(4));
        Some(l)
    }

    const fn checked_total_floats(&self) -> Option<usize> {
        sum(&[
            self.gen_params,
            self.disc_params,
            self.actor_params,
            self.fixed_biases,
            self.grads,
            self.psi,
            self.work,
        ])
    }

    /// Total f32 elements (`usize::MAX` if that does not fit).
    pub const fn total_floats(&self) -> usize {
        sat(self.checked_total_floats())
    }

    /// Total bytes of RAM for the navigator's arena (`usize::MAX` if that does not fit).
    pub const fn total_bytes(&self) -> usize {
        self.total_floats().saturating_mul(4)
    }
}

/// Checked sum of `v`.
const fn sum(v: &[usize]) -> Option<usize> {
    let mut acc = 0usize;
    let mut i = 0;
    while i < v.len() {
        acc = tri!(acc.checked_add(v[i]));
        i += 1;
    }
    Some(acc)
}

/// Length in f32 of the arena a navigator needs: use as a static array length,
/// `[f32; arena_len(&Dims::MCU, AdaptMode::Efficient, 20)]`. `usize::MAX` when the size
/// does not fit in `usize` (see [`try_arena_len`]): no arena is that long, so
/// [`Navigator::new`](crate::navigator::Navigator::new) refuses it.
pub const fn arena_len(d: &Dims, mode: AdaptMode, k: usize) -> usize {
    sat(try_arena_len(d, mode, k))
}

/// [`arena_len`], or `None` when it overflows `usize`.
pub const fn try_arena_len(d: &Dims, mode: AdaptMode, k: usize) -> Option<usize> {
    match NavLayout::try_new(d, mode, k) {
        Some(l) => l.checked_total_floats(),
        None => None,
    }
}

/// Bytes of flash the int8 weights of `dims` take (values plus one f32 scale per row; biases
/// are f32), i.e. the payload of an int8 blob without its small header. `usize::MAX` when
/// that does not fit (see [`checked_int8_weight_bytes`]).
pub const fn int8_weight_bytes(d: &Dims) -> usize {
    sat(checked_int8_weight_bytes(d))
}

/// [`int8_weight_bytes`], or `None` when it overflows `usize`.
pub const fn checked_int8_weight_bytes(d: &Dims) -> Option<usize> {
    let params = tri!(sum(&[
        tri!(d.checked_gen_params()),
        tri!(d.checked_disc_params()),
        tri!(d.checked_policy_params())
    ]));
    let lh4 = tri!(d.lstm_hidden.checked_mul(4));
    let lh8 = tri!(d.lstm_hidden.checked_mul(8));
    // The per-cell layer (with a map): one bias vector and `cell_embed` rows.
    let cell = if tri!(d.map_rows.checked_mul(d.map_cols)) > 0 {
        d.cell_embed
    } else {
        0
    };
    // Bias vectors (stored f32).
    let vectors = tri!(sum(&[
        d.gen_hidden,
        d.feat,
        d.disc_hidden,
        1,
        d.embed,
        lh4,
        NUM_ACTIONS,
        1,
        cell
    ]));
    // Rows of all matrices, one f32 scale each.
    let rows = tri!(sum(&[
        d.gen_hidden,
        d.feat,
        d.disc_hidden,
        1,
        d.embed,
        lh8,
        NUM_ACTIONS,
        1,
        cell
    ]));
    // The biases are part of the parameters, so this cannot underflow; checked anyway.
    let weights = tri!(params.checked_sub(vectors));
    sum(&[
        weights,
        tri!(rows.checked_mul(4)),
        tri!(vectors.checked_mul(4)),
    ])
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn int8_bytes_match_tensor_shapes() {
        use crate::schema::TensorId;
        for d in [
            Dims::PAPER,
            Dims::MCU,
            Dims::MCU.with_ps(),
            Dims::MCU.with_map(3, 3, 8),
        ] {
            let mut bytes = 0;
            for id in TensorId::all_for(&d) {
                let (r, c) = id.shape(&d);
                bytes += if id.is_vector() { 4 * r } else { r * c + 4 * r };
            }
            assert_eq!(bytes, int8_weight_bytes(&d));
        }
    }

    #[test]
    fn efficient_mode_is_much_smaller() {
        for d in [Dims::PAPER, Dims::MCU] {
            let full = NavLayout::new(&d, AdaptMode::Full, 20).total_bytes();
            let eff = NavLayout::new(&d, AdaptMode::Efficient, 20).total_bytes();
            assert!(eff * 4 < full, "{d:?}: {eff} vs {full}");
        }
    }
}
