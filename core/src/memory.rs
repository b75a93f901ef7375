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

/// How much RAM the navigator trades for speed. **Never the bits**: every footprint gives
/// every step, score, gradient and adapted parameter the same bits (the batched kernels'
/// contract, see [`crate::inner`]); `tests/tests/navigator.rs` checks whole episodes.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Default)]
pub enum Footprint {
    /// The microcontroller's layout (the default): in [`AdaptMode::Efficient`] the inner
    /// update processes Ψ [`EFFICIENT_ADAPT_BATCH`] entries at a time and regenerates G's
    /// pre-gain output for L_ad's backward pass.
    #[default]
    Compact,
    /// For hosts: all `k` entries of Ψ as one batch in both modes, and in
    /// [`AdaptMode::Efficient`] Ψ also keeps G's pre-gain output `W2 h1` of every entry
    /// (`k x feat` floats more), so an inner update runs no forward pass of G at all. It
    /// costs `k x feat` floats of Ψ and the batch buffers of `k` entries instead of 2: for
    /// `k = 20` in Efficient mode 452 KiB instead of 145 KiB for `mcu`, 2.5 MiB instead of
    /// 512 KiB for `paper` (`cargo run -p gman-core --example memory_table`). In Full mode
    /// the two layouts are the same.
    Fast,
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
        NavLayout::new_with(d, mode, k, Footprint::Compact)
    }

    /// [`NavLayout::new`] for a [`Footprint`].
    pub const fn new_with(d: &Dims, mode: AdaptMode, k: usize, fp: Footprint) -> NavLayout {
        match NavLayout::try_new_with(d, mode, k, fp) {
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
    /// the total byte count overflows `usize` (checked arithmetic throughout). Each field is
    /// the sum of its regions of the arena table (`region_lens`, the one statement of the layout).
    pub const fn try_new(d: &Dims, mode: AdaptMode, k: usize) -> Option<NavLayout> {
        NavLayout::try_new_with(d, mode, k, Footprint::Compact)
    }

    /// [`NavLayout::try_new`] for a [`Footprint`].
    pub const fn try_new_with(
        d: &Dims,
        mode: AdaptMode,
        k: usize,
        fp: Footprint,
    ) -> Option<NavLayout> {
        let lens = tri!(region_lens(d, mode, k, fp));
        let mut sums = [0usize; 7];
        let mut i = 0;
        while i < NUM_REGIONS {
            let g = REGION_PART[i] as usize;
            sums[g] = tri!(sums[g].checked_add(lens[i]));
            i += 1;
        }
        let l = NavLayout {
            gen_params: sums[Part::GenParams as usize],
            disc_params: sums[Part::DiscParams as usize],
            actor_params: sums[Part::ActorParams as usize],
            fixed_biases: sums[Part::FixedBiases as usize],
            grads: sums[Part::Grads as usize],
            psi: sums[Part::Psi as usize],
            work: sums[Part::Work as usize],
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

/// The [`NavLayout`] field a region of the arena counts towards.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Part {
    GenParams,
    DiscParams,
    ActorParams,
    FixedBiases,
    Grads,
    Psi,
    Work,
}

macro_rules! arena_regions {
    (|$d:ident, $full:ident, $g:ident, $k:ident, $b:ident, $map:ident, $gen_in:ident, $fast:ident|
     $($(#[$m:meta])* $name:ident in $part:ident = $len:expr;)*) => {
        /// One region of the navigator's arena, in carve order (`Ram::carve` in
        /// `navigator.rs` takes each by name; [`NavLayout`] sums them per field).
        #[derive(Clone, Copy, Debug, PartialEq, Eq)]
        #[allow(missing_docs)]
        pub(crate) enum Region { $($(#[$m])* $name),* }

        /// Number of regions.
        pub(crate) const NUM_REGIONS: usize = [$(Region::$name),*].len();

        const REGION_PART: [Part; NUM_REGIONS] = [$(Part::$part),*];

        /// Length in f32 of every region, in carve order, for `d`, `mode`, buffer
        /// capacity `k` and footprint `fp` (`None` when one overflows `usize`). The one
        /// statement of the arena layout.
        pub(crate) const fn region_lens(
            $d: &Dims,
            mode: AdaptMode,
            $k: usize,
            fp: Footprint,
        ) -> Option<[usize; NUM_REGIONS]> {
            let $full = matches!(mode, AdaptMode::Full);
            let $fast = matches!(fp, Footprint::Fast);
            // With gains (Efficient) some buffers exist, otherwise they are empty.
            let $g: usize = if $full { 0 } else { 1 };
            let $map = tri!($d.map_rows.checked_mul($d.map_cols)) > 0;
            let $gen_in = tri!($d.checked_gen_in());
            // Entries of Ψ the batched inner update processes at a time.
            let $b: usize = adapt_batch_with(mode, $k, fp);
            Some([$($len),*])
        }
    };
}

/// `n` in `Full` mode, else 0.
const fn if_full(full: bool, n: Option<usize>) -> Option<usize> {
    if full {
        n
    } else {
        Some(0)
    }
}

/// Most entries of Ψ the inner update processes at a time in [`AdaptMode::Efficient`]
/// (the microcontroller mode, where RAM is the limit; see [`adapt_batch`]).
pub const EFFICIENT_ADAPT_BATCH: usize = 2;

/// Entries of Ψ the inner update processes as one batch (a matrix through the batched
/// kernels of [`crate::batch`]): all `k` in [`AdaptMode::Full`], at most
/// [`EFFICIENT_ADAPT_BATCH`] in [`AdaptMode::Efficient`]. Only the speed and the RAM
/// depend on it, never the bits (see `crate::inner`).
pub const fn adapt_batch(mode: AdaptMode, k: usize) -> usize {
    adapt_batch_with(mode, k, Footprint::Compact)
}

/// [`adapt_batch`] for a [`Footprint`]: with [`Footprint::Fast`] all `k` entries in both
/// modes.
pub const fn adapt_batch_with(mode: AdaptMode, k: usize, fp: Footprint) -> usize {
    match (mode, fp) {
        (AdaptMode::Full, _) | (_, Footprint::Fast) => k,
        (AdaptMode::Efficient, Footprint::Compact) => {
            if k < EFFICIENT_ADAPT_BATCH {
                k
            } else {
                EFFICIENT_ADAPT_BATCH
            }
        }
    }
}

arena_regions! { |d, full, g, k, b, map, gen_in, fast|
    // Adapted G (θ, or its gains and biases): weights in Full, gains in Efficient, biases.
    Gen1W in GenParams = tri!(if_full(full, d.gen_hidden.checked_mul(gen_in)));
    Gen1Gain in GenParams = g * d.gen_hidden;
    Gen1B in GenParams = d.gen_hidden;
    Gen2W in GenParams = tri!(if_full(full, d.feat.checked_mul(d.gen_hidden)));
    Gen2Gain in GenParams = g * d.feat;
    Gen2B in GenParams = d.feat;
    // D in RAM (ω, or its hidden layer's gains and biases and its output layer).
    Disc1W in DiscParams = tri!(if_full(full, d.disc_hidden.checked_mul(d.feat)));
    Disc1Gain in DiscParams = g * d.disc_hidden;
    Disc1B in DiscParams = d.disc_hidden;
    DiscW2 in DiscParams = d.disc_hidden;
    DiscB2 in DiscParams = 1;
    // The adapted actor head.
    ActorW in ActorParams = tri!(if_full(full, d.lstm_hidden.checked_mul(NUM_ACTIONS)));
    ActorGain in ActorParams = g * NUM_ACTIONS;
    ActorB in ActorParams = NUM_ACTIONS;
    // Biases of the layers read in place from the blob.
    FuseB in FixedBiases = d.embed;
    LstmB in FixedBiases = tri!(d.lstm_hidden.checked_mul(4));
    CriticB in FixedBiases = 1;
    CellB in FixedBiases = if map { d.cell_embed } else { 0 };
    // Gradients: dW (Full) or dgain (Efficient), and db, of each adapted layer.
    GGen1A in Grads = if full { tri!(d.gen_hidden.checked_mul(gen_in)) } else { d.gen_hidden };
    GGen1B in Grads = d.gen_hidden;
    GGen2A in Grads = if full { tri!(d.feat.checked_mul(d.gen_hidden)) } else { d.feat };
    GGen2B in Grads = d.feat;
    GDisc1A in Grads = if full { tri!(d.disc_hidden.checked_mul(d.feat)) } else { d.disc_hidden };
    GDisc1B in Grads = d.disc_hidden;
    GDiscW2 in Grads = d.disc_hidden;
    GDiscB2 in Grads = 1;
    GActorA in Grads = if full { tri!(d.lstm_hidden.checked_mul(NUM_ACTIONS)) } else { NUM_ACTIONS };
    GActorB in Grads = NUM_ACTIONS;
    // Ψ: k observations, noises, action probabilities and LSTM hidden states.
    PsiS in Psi = tri!(k.checked_mul(d.feat));
    PsiZ in Psi = tri!(k.checked_mul(d.noise));
    PsiP in Psi = tri!(k.checked_mul(NUM_ACTIONS));
    PsiH in Psi = tri!(k.checked_mul(d.lstm_hidden));
    // Ψ_x: the generated feature of every entry, made once per inner update (G is fixed
    // within an adaptation window, so these are the bits each entry's forward pass gives).
    PsiX in Psi = tri!(k.checked_mul(d.feat));
    // Fast footprint, Efficient mode: G's pre-gain output `W2 h1` of every entry, recorded
    // at its step, so that L_ad's backward pass needs no forward pass of G (`inner`).
    PsiU2 in Psi = if fast { g * tri!(k.checked_mul(d.feat)) } else { 0 };
    // G activations of the step.
    U1 in Work = g * d.gen_hidden;
    H1 in Work = d.gen_hidden;
    U2 in Work = g * d.feat;
    X in Work = d.feat;
    // Batched inner update (`b` entries at a time): G's inputs, activations and scratch.
    BZ in Work = tri!(b.checked_mul(d.noise));
    BAttr in Work = tri!(b.checked_mul(d.attr));
    BU1 in Work = g * tri!(b.checked_mul(d.gen_hidden));
    BH1 in Work = tri!(b.checked_mul(d.gen_hidden));
    BU2 in Work = g * tri!(b.checked_mul(d.feat));
    DPre2 in Work = tri!(b.checked_mul(d.feat));
    DH1 in Work = tri!(b.checked_mul(d.gen_hidden));
    DPre1 in Work = tri!(b.checked_mul(d.gen_hidden));
    // D's activations for `3 b` inputs (real, fake, interpolate) and scratch.
    DU in Work = g * tri!(tri!(b.checked_mul(3)).checked_mul(d.disc_hidden));
    DH in Work = tri!(tri!(b.checked_mul(3)).checked_mul(d.disc_hidden));
    DV in Work = tri!(tri!(b.checked_mul(3)).checked_mul(d.disc_hidden));
    DW1G in Work = tri!(b.checked_mul(d.disc_hidden));
    DG in Work = tri!(b.checked_mul(d.feat));
    DMix in Work = tri!(b.checked_mul(d.feat));
    // Full: the inputs and output gradients of D's `3 b` weight-gradient outer products.
    DOuterX in Work = tri!(if_full(full, tri!(b.checked_mul(3)).checked_mul(d.feat)));
    DOuterY in Work = tri!(if_full(full, tri!(b.checked_mul(3)).checked_mul(d.disc_hidden)));
    // Adaptation work.
    Eps in Work = k;
    D in Work = k;
    DD in Work = k;
    DProbs in Work = tri!(k.checked_mul(NUM_ACTIONS));
    // Policy work and state.
    Prod in Work = d.feat;
    Fuse in Work = d.embed;
    Gates in Work = tri!(d.lstm_hidden.checked_mul(4));
    HNew in Work = d.lstm_hidden;
    CNew in Work = d.lstm_hidden;
    HState in Work = d.lstm_hidden;
    CState in Work = d.lstm_hidden;
    Logits in Work = NUM_ACTIONS;
    Probs in Work = NUM_ACTIONS;
    PrevProbs in Work = NUM_ACTIONS;
    DLogits in Work = NUM_ACTIONS;
    ActorU in Work = g * NUM_ACTIONS;
    Z in Work = d.noise;
    Attr in Work = d.attr;
    Ps in Work = d.ps;
    Cell in Work = tri!(d.checked_cell_out());
    CellProd in Work = if map { d.feat } else { 0 };
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

/// [`arena_len`] for a [`Footprint`].
pub const fn arena_len_with(d: &Dims, mode: AdaptMode, k: usize, fp: Footprint) -> usize {
    sat(try_arena_len_with(d, mode, k, fp))
}

/// [`arena_len`], or `None` when it overflows `usize`.
pub const fn try_arena_len(d: &Dims, mode: AdaptMode, k: usize) -> Option<usize> {
    try_arena_len_with(d, mode, k, Footprint::Compact)
}

/// [`arena_len_with`], or `None` when it overflows `usize`.
pub const fn try_arena_len_with(
    d: &Dims,
    mode: AdaptMode,
    k: usize,
    fp: Footprint,
) -> Option<usize> {
    match NavLayout::try_new_with(d, mode, k, fp) {
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

/// The overflow check of [`Dims`] over everything derived from them. It lives here, beside
/// the RAM layout it checks last, so that [`crate::preset`] only declares sizes and the
/// schema and the layout derive from it (no module depends back on its users).
impl Dims {
    /// True when every size derived from these dims fits in `usize`: the input widths, the
    /// element and byte counts of every tensor (f32 and int8), the parameter counts of G, D
    /// and the policy and their f32 bytes, the MACs per step, and the RAM layout of both
    /// adaptation modes for a buffer of one step ([`NavLayout::try_new`]; a
    /// navigator checks its own `K` again). [`crate::blob::Blob::parse`] rejects dims for
    /// which this is false ([`crate::BlobError::DimsTooLarge`]), so sizes computed from a
    /// parsed blob's dims never overflow.
    pub const fn checked_sizes(&self) -> bool {
        let (g, d, p) = match (
            self.checked_gen_params(),
            self.checked_disc_params(),
            self.checked_policy_params(),
        ) {
            (Some(g), Some(d), Some(p)) => (g, d, p),
            _ => return false,
        };
        let total = match g.checked_add(d) {
            Some(v) => v.checked_add(p),
            None => None,
        };
        let f32_bytes = match total {
            Some(t) => t.checked_mul(4),
            None => None,
        };
        f32_bytes.is_some()
            && self.checked_macs_per_step().is_some()
            && checked_int8_weight_bytes(self).is_some()
            && crate::schema::checked_tensor_bytes(self)
            && NavLayout::try_new(self, AdaptMode::Full, 1).is_some()
            && NavLayout::try_new(self, AdaptMode::Efficient, 1).is_some()
            && NavLayout::try_new_with(self, AdaptMode::Efficient, 1, Footprint::Fast).is_some()
    }
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

    /// The layout derived from the region table, pinned (every region's figures per mode,
    /// with the batched inner update's regions: Ψ_x, `k x F`, in `psi`; batch buffers for
    /// `adapt_batch(mode, k)` entries in `work`). Long because most of it is that table of
    /// pinned figures.
    #[test]
    fn region_table_gives_the_pinned_layout() {
        let expected = [
            (
                AdaptMode::Full,
                1,
                [154880, 32897, 390, 321, 188167, 1139, 6549],
            ),
            (
                AdaptMode::Full,
                20,
                [154880, 32897, 390, 321, 188167, 22780, 93550],
            ),
            (
                AdaptMode::Efficient,
                1,
                [1536, 193, 12, 321, 1741, 1139, 6555],
            ),
            (
                AdaptMode::Efficient,
                20,
                [1536, 193, 12, 321, 1741, 22780, 10528],
            ),
            (
                AdaptMode::Full,
                1,
                [2470400, 526337, 3078, 2561, 2999815, 1587, 35541],
            ),
            (
                AdaptMode::Full,
                20,
                [2470400, 526337, 3078, 2561, 2999815, 31740, 523822],
            ),
            (
                AdaptMode::Efficient,
                1,
                [9216, 3073, 12, 2561, 12301, 1587, 43227],
            ),
            (
                AdaptMode::Efficient,
                20,
                [9216, 3073, 12, 2561, 12301, 31740, 72160],
            ),
            (
                AdaptMode::Full,
                1,
                [154880, 32897, 390, 321, 188167, 1139, 6594],
            ),
            (
                AdaptMode::Full,
                20,
                [154880, 32897, 390, 321, 188167, 22780, 93595],
            ),
            (
                AdaptMode::Efficient,
                1,
                [1536, 193, 12, 321, 1741, 1139, 6600],
            ),
            (
                AdaptMode::Efficient,
                20,
                [1536, 193, 12, 321, 1741, 22780, 10573],
            ),
            (
                AdaptMode::Full,
                1,
                [154880, 32897, 390, 329, 188167, 1139, 7133],
            ),
            (
                AdaptMode::Full,
                20,
                [154880, 32897, 390, 329, 188167, 22780, 94134],
            ),
            (
                AdaptMode::Efficient,
                1,
                [1536, 193, 12, 329, 1741, 1139, 7139],
            ),
            (
                AdaptMode::Efficient,
                20,
                [1536, 193, 12, 329, 1741, 22780, 11112],
            ),
        ];
        let dims = [
            Dims::MCU,
            Dims::PAPER,
            Dims::MCU.with_ps(),
            Dims::MCU.with_map(3, 3, 8),
        ];
        for (i, (mode, k, e)) in expected.iter().enumerate() {
            let l = NavLayout::new(&dims[i / 4], *mode, *k);
            let got = [
                l.gen_params,
                l.disc_params,
                l.actor_params,
                l.fixed_biases,
                l.grads,
                l.psi,
                l.work,
            ];
            assert_eq!(got, *e, "{:?} {mode:?} k={k}", dims[i / 4]);
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
