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

use crate::preset::Dims;
use crate::NUM_ACTIONS;

/// Which parameters adaptation updates, and where they live. See the module docs.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum AdaptMode {
    /// All of θ, ω and the actor head in f32 RAM.
    Full,
    /// Per-unit gain and bias over int8 base weights in flash.
    Efficient,
}

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
    /// The layout for `dims`, `mode` and buffer capacity `k`.
    pub const fn new(d: &Dims, mode: AdaptMode, k: usize) -> NavLayout {
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
            AdaptMode::Full => d.gen_params(),
            AdaptMode::Efficient => 2 * (h + f),
        };
        let disc_params = match mode {
            AdaptMode::Full => d.disc_params(),
            AdaptMode::Efficient => 3 * dh + 1,
        };
        let actor_params = match mode {
            AdaptMode::Full => NUM_ACTIONS * lh + NUM_ACTIONS,
            AdaptMode::Efficient => 2 * NUM_ACTIONS,
        };
        let map = d.map_cells() > 0;
        let fixed_biases = e + 4 * lh + 1 + if map { d.cell_embed } else { 0 };
        let grads = gen_params + disc_params + actor_params;
        let psi = k * (f + z + NUM_ACTIONS + lh);
        let g = if gain { 1 } else { 0 };
        let gen_work = g * h + h + g * f + f + f + h + h + max(f, h);
        let disc_work = g * dh + 3 * dh + 2 * f;
        let adapt_work = 3 * k + k * NUM_ACTIONS + f;
        let policy_work = f
            + e
            + 4 * lh
            + 4 * lh
            + 4 * NUM_ACTIONS
            + g * NUM_ACTIONS
            + z
            + a
            + d.ps
            + d.cell_out()
            + if map { f } else { 0 };
        NavLayout {
            gen_params,
            disc_params,
            actor_params,
            fixed_biases,
            grads,
            psi,
            work: gen_work + disc_work + adapt_work + policy_work,
        }
    }

    /// Total f32 elements.
    pub const fn total_floats(&self) -> usize {
        self.gen_params
            + self.disc_params
            + self.actor_params
            + self.fixed_biases
            + self.grads
            + self.psi
            + self.work
    }

    /// Total bytes of RAM for the navigator's arena.
    pub const fn total_bytes(&self) -> usize {
        4 * self.total_floats()
    }
}

/// Length in f32 of the arena a navigator needs: use as a static array length,
/// `[f32; arena_len(&Dims::MCU, AdaptMode::Efficient, 20)]`.
pub const fn arena_len(d: &Dims, mode: AdaptMode, k: usize) -> usize {
    NavLayout::new(d, mode, k).total_floats()
}

/// Bytes of flash the int8 weights of `dims` take (values plus one f32 scale per row; biases
/// are f32), i.e. the payload of an int8 blob without its small header.
pub const fn int8_weight_bytes(d: &Dims) -> usize {
    let params = d.gen_params() + d.disc_params() + d.policy_params();
    let cell = if d.map_cells() > 0 { d.cell_embed } else { 0 };
    // Bias vectors (stored f32).
    let vectors = d.gen_hidden
        + d.feat
        + d.disc_hidden
        + 1
        + d.embed
        + 4 * d.lstm_hidden
        + NUM_ACTIONS
        + 1
        + cell;
    // Rows of all matrices, one f32 scale each.
    let rows = d.gen_hidden
        + d.feat
        + d.disc_hidden
        + 1
        + d.embed
        + 8 * d.lstm_hidden
        + NUM_ACTIONS
        + 1
        + cell;
    (params - vectors) + 4 * rows + 4 * vectors
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn int8_bytes_match_tensor_shapes() {
        use crate::blob::TensorId;
        for d in [
            Dims::PAPER,
            Dims::MCU,
            Dims::MCU.with_ps(),
            Dims::MCU.with_map(3, 3, 8),
        ] {
            let mut bytes = 0;
            for &id in TensorId::ALL.iter().filter(|id| id.present(&d)) {
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
