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

use crate::spec::preset::{sat, tri, Dims};
use crate::NUM_ACTIONS;

pub use crate::spec::schema::AdaptMode;
use crate::spec::schema::NoiseMode;

/// How much RAM the navigator trades for speed. **Never the bits**: every footprint gives
/// every step, score, gradient and adapted parameter the same bits (the batched kernels'
/// contract, see [`crate::adapt::inner`]); `tests/tests/navigator.rs` checks whole episodes.
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
    /// The smallest layout, for blobs with [`FLAG_COMPACT_PSI`](crate::spec::schema::FLAG_COMPACT_PSI)
    /// in [`AdaptMode::Efficient`]: [`Footprint::Compact`] without Ψ_x (the inner update
    /// regenerates each entry's x_t from its noise, batch by batch: the same bits, more
    /// work; with zero noise Ψ keeps the one x_t every entry shares, as every footprint does)
    /// and with Ψ's observations as int16 with one scale per entry (two per f32 of the
    /// arena). A navigator refuses it for other blobs, for `Full` mode and for CosSim models
    /// that adapt ([`crate::Error::Config`]).
    Minimal,
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
    /// the sum of its regions of the arena table (`memory::arena_table`, the one statement of the layout).
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
        NavLayout::try_new_noise(d, mode, k, fp, NoiseMode::Gaussian)
    }

    /// [`NavLayout::try_new_with`] for G's noise mode: with [`NoiseMode::Zero`] Ψ keeps no
    /// noise and one row of Ψ_x (every entry's x_t is the same).
    pub const fn try_new_noise(
        d: &Dims,
        mode: AdaptMode,
        k: usize,
        fp: Footprint,
        noise: NoiseMode,
    ) -> Option<NavLayout> {
        let zero = matches!(noise, NoiseMode::Zero);
        let lens = tri!(region_lens(d, mode, k, fp, zero));
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

/// Generates, from the arena table ([`arena_table`]), what the RAM accounting needs: the
/// length of every region in carve order (`region_lens`) and the [`NavLayout`] field each
/// counts towards. The navigator generates its `Ram` struct and carve from the same table.
macro_rules! arena_lens {
    (|$d:ident, $full:ident, $g:ident, $k:ident, $b:ident, $map:ident, $gen_in:ident, $fast:ident, $min:ident, $zero:ident|
     $($field:ident $(: $kind:ident)? in $part:ident
        $({ $($sub:ident = $sl:expr;)* })? $(= $len:expr;)?)*) => {
        /// The [`NavLayout`] field of every region, in carve order.
        const REGION_PART: &[Part] = &[$($($(first!(Part::$part, $sub),)*)? $(first!(Part::$part, $len),)?)*];

        /// Number of regions.
        pub(crate) const NUM_REGIONS: usize = REGION_PART.len();

        /// Length in f32 of every region, in carve order, for `d`, `mode`, buffer
        /// capacity `k`, footprint `fp` and G's noise (`zero`: [`NoiseMode::Zero`]) (`None`
        /// when one overflows `usize`).
        pub(crate) const fn region_lens(
            $d: &Dims,
            mode: AdaptMode,
            $k: usize,
            fp: Footprint,
            $zero: bool,
        ) -> Option<[usize; NUM_REGIONS]> {
            let $full = matches!(mode, AdaptMode::Full);
            let $fast = matches!(fp, Footprint::Fast);
            let $min = matches!(fp, Footprint::Minimal);
            // With gains (Efficient) some buffers exist, otherwise they are empty.
            let $g: usize = if $full { 0 } else { 1 };
            let $map = tri!($d.map_rows.checked_mul($d.map_cols)) > 0;
            let $gen_in = tri!($d.checked_gen_in());
            // Entries of Ψ the batched inner update processes at a time.
            let $b: usize = adapt_batch_with(mode, $k, fp);
            Some([$($($($sl,)*)? $($len,)?)*])
        }
    };
}

/// Expands to its first argument (a repetition of the arena table driven by the second).
macro_rules! first {
    ($a:expr, $($rest:tt)*) => {
        $a
    };
}
pub(crate) use first;

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
/// kernels of [`crate::nn::batch`]): all `k` in [`AdaptMode::Full`], at most
/// [`EFFICIENT_ADAPT_BATCH`] in [`AdaptMode::Efficient`]. Only the speed and the RAM
/// depend on it, never the bits (see `crate::adapt::inner`).
pub const fn adapt_batch(mode: AdaptMode, k: usize) -> usize {
    adapt_batch_with(mode, k, Footprint::Compact)
}

/// [`adapt_batch`] for a [`Footprint`]: with [`Footprint::Fast`] all `k` entries in both
/// modes.
pub const fn adapt_batch_with(mode: AdaptMode, k: usize, fp: Footprint) -> usize {
    match (mode, fp) {
        (AdaptMode::Full, _) | (_, Footprint::Fast) => k,
        // One entry at a time: the smallest buffers, and slices of the delayed update half
        // as long (the passes over Ψ regenerate x_t, so each entry costs more).
        (AdaptMode::Efficient, Footprint::Minimal) => {
            if k < 1 {
                k
            } else {
                1
            }
        }
        (AdaptMode::Efficient, Footprint::Compact) => {
            if k < EFFICIENT_ADAPT_BATCH {
                k
            } else {
                EFFICIENT_ADAPT_BATCH
            }
        }
    }
}

/// The arena table: every region of the navigator's arena, in carve order, with the
/// [`NavLayout`] field it counts towards and its length in f32 (an expression of `d`, the
/// dims; `full`, Full mode; `g`, 1 with gains (Efficient) else 0; `k`, Ψ's capacity; `b`,
/// the entries of Ψ the inner update processes at a time; `map`, a spatial map; `gen_in`,
/// G's input width; `fast`, [`Footprint::Fast`]; `min`, [`Footprint::Minimal`]). The one statement of the arena: a region
/// is named here only. `field in Part = len;` is a region of its own; `field: Kind in Part
/// { sub = len; .. }` groups regions into one struct of the navigator (`LayerRam`, an
/// adapted layer; `LayerGrad`, its gradient; `InnerWorkOf`, the batched inner update's
/// buffers). It expands to `$gen! { table }`: [`NavLayout`] sums it with `arena_lens`, the
/// navigator generates its `Ram` struct and carve from it with `arena_ram`.
macro_rules! arena_table {
    ($gen:ident) => {
        $gen! { |d, full, g, k, b, map, gen_in, fast, min, zero|
            // Adapted G (θ, or its gains and biases): weights in Full, gains in Efficient,
            // biases.
            gen1: LayerRam in GenParams {
                w = tri!(if_full(full, d.gen_hidden.checked_mul(gen_in)));
                gain = g * d.gen_hidden;
                b = d.gen_hidden;
            }
            gen2: LayerRam in GenParams {
                w = tri!(if_full(full, d.feat.checked_mul(d.gen_hidden)));
                gain = g * d.feat;
                b = d.feat;
            }
            // D in RAM (ω, or its hidden layer's gains and biases and its output layer).
            disc1: LayerRam in DiscParams {
                w = tri!(if_full(full, d.disc_hidden.checked_mul(d.feat)));
                gain = g * d.disc_hidden;
                b = d.disc_hidden;
            }
            disc_w2 in DiscParams = d.disc_hidden;
            disc_b2 in DiscParams = 1;
            // The adapted actor head.
            actor: LayerRam in ActorParams {
                w = tri!(if_full(full, d.lstm_hidden.checked_mul(NUM_ACTIONS)));
                gain = g * NUM_ACTIONS;
                b = NUM_ACTIONS;
            }
            // Biases of the layers read in place from the blob.
            fuse_b in FixedBiases = d.embed;
            lstm_b in FixedBiases = tri!(d.lstm_hidden.checked_mul(4));
            critic_b in FixedBiases = 1;
            cell_b in FixedBiases = if map { d.cell_embed } else { 0 };
            // Gradients: dW (Full) or dgain (Efficient), and db, of each adapted layer.
            g_gen1: LayerGrad in Grads {
                a = if full { tri!(d.gen_hidden.checked_mul(gen_in)) } else { d.gen_hidden };
                b = d.gen_hidden;
            }
            g_gen2: LayerGrad in Grads {
                a = if full { tri!(d.feat.checked_mul(d.gen_hidden)) } else { d.feat };
                b = d.feat;
            }
            g_disc1: LayerGrad in Grads {
                a = if full { tri!(d.disc_hidden.checked_mul(d.feat)) } else { d.disc_hidden };
                b = d.disc_hidden;
            }
            g_disc_w2 in Grads = d.disc_hidden;
            g_disc_b2 in Grads = 1;
            g_actor: LayerGrad in Grads {
                a = if full { tri!(d.lstm_hidden.checked_mul(NUM_ACTIONS)) } else { NUM_ACTIONS };
                b = NUM_ACTIONS;
            }
            // Ψ: k observations, noises, action probabilities and LSTM hidden states (the
            // Minimal footprint: the observations as int16, two per float, and their scales).
            psi_s in Psi = tri!(k.checked_mul(if min { d.feat.div_ceil(2) } else { d.feat }));
            psi_sc in Psi = if min { k } else { 0 };
            // (With zero noise every z_t is zero: Ψ keeps none.)
            psi_z in Psi = if zero { 0 } else { tri!(k.checked_mul(d.noise)) };
            psi_p in Psi = tri!(k.checked_mul(NUM_ACTIONS));
            psi_h in Psi = tri!(k.checked_mul(d.lstm_hidden));
            // Ψ_x: the generated feature of every entry, made once per inner update (G is
            // fixed within an adaptation window, so these are the bits each entry's forward
            // pass gives). With zero noise one row in every footprint: every entry's x_t is
            // G(0, SE(y)) at the update's θ.
            psi_x in Psi = if zero {
                d.feat
            } else if min {
                0
            } else {
                tri!(k.checked_mul(d.feat))
            };
            // Fast footprint, Efficient mode: G's pre-gain output `W2 h1` of every entry,
            // recorded at its step, so that L_ad's backward pass needs no forward pass of G
            // (`inner`); one row with zero noise.
            psi_u2 in Psi = if fast {
                g * if zero { d.feat } else { tri!(k.checked_mul(d.feat)) }
            } else {
                0
            };
            // G activations of the step.
            u1 in Work = g * d.gen_hidden;
            h1 in Work = d.gen_hidden;
            u2 in Work = g * d.feat;
            x in Work = d.feat;
            // The batched inner update (`b` entries at a time): G's inputs, activations and
            // scratch; D's activations for `3 b` inputs (real, fake, interpolate) and scratch;
            // in Full mode the inputs and output gradients of D's `3 b` weight-gradient outer
            // products.
            iw: InnerWorkOf in Work {
                z = tri!(b.checked_mul(d.noise));
                attr = tri!(b.checked_mul(d.attr));
                u1 = g * tri!(b.checked_mul(d.gen_hidden));
                h1 = tri!(b.checked_mul(d.gen_hidden));
                u2 = g * tri!(b.checked_mul(d.feat));
                dpre2 = tri!(b.checked_mul(d.feat));
                dh1 = tri!(b.checked_mul(d.gen_hidden));
                dpre1 = tri!(b.checked_mul(d.gen_hidden));
                du = g * tri!(tri!(b.checked_mul(3)).checked_mul(d.disc_hidden));
                dh = tri!(tri!(b.checked_mul(3)).checked_mul(d.disc_hidden));
                dv = tri!(tri!(b.checked_mul(3)).checked_mul(d.disc_hidden));
                w1g = tri!(b.checked_mul(d.disc_hidden));
                g = tri!(b.checked_mul(d.feat));
                mix = tri!(b.checked_mul(d.feat));
                outer_x = tri!(if_full(full, tri!(b.checked_mul(3)).checked_mul(d.feat)));
                outer_dy = tri!(if_full(full, tri!(b.checked_mul(3)).checked_mul(d.disc_hidden)));
            }
            // Adaptation work.
            eps in Work = k;
            d in Work = k;
            dd in Work = k;
            dprobs in Work = tri!(k.checked_mul(NUM_ACTIONS));
            // Policy work and state (`h`, `c`: the step's new LSTM state).
            prod in Work = d.feat;
            fuse in Work = d.embed;
            gates in Work = tri!(d.lstm_hidden.checked_mul(4));
            h in Work = d.lstm_hidden;
            c in Work = d.lstm_hidden;
            h_state in Work = d.lstm_hidden;
            c_state in Work = d.lstm_hidden;
            logits in Work = NUM_ACTIONS;
            probs in Work = NUM_ACTIONS;
            prev_probs in Work = NUM_ACTIONS;
            dlogits in Work = NUM_ACTIONS;
            actor_u in Work = g * NUM_ACTIONS;
            z in Work = d.noise;
            attr in Work = d.attr;
            ps in Work = d.ps;
            cell in Work = tri!(d.checked_cell_out());
            cell_prod in Work = if map { d.feat } else { 0 };
            // With zero noise, the fusion layer's terms of x_t and SE(y), kept between two
            // inner updates on the integer path (`Policy::fuse_terms`).
            fuse_terms in Work = if zero {
                tri!(crate::nets::policy::fuse_terms_len(d.embed, d.feat, d.attr))
            } else {
                0
            };
        }
    };
}
pub(crate) use arena_table;

arena_table!(arena_lens);

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

/// [`arena_len`] for a [`Footprint`]: enough for a navigator of either noise mode (the
/// larger of [`arena_len_noise`]'s two).
pub const fn arena_len_with(d: &Dims, mode: AdaptMode, k: usize, fp: Footprint) -> usize {
    sat(try_arena_len_with(d, mode, k, fp))
}

/// [`arena_len_with`] for one noise mode of G
/// ([`ModelSpec::noise`](crate::spec::ModelSpec::noise)): with [`NoiseMode::Zero`] Ψ keeps
/// no noise and one x_t, so a firmware that knows its blob's mode can size the arena exactly.
pub const fn arena_len_noise(
    d: &Dims,
    mode: AdaptMode,
    k: usize,
    fp: Footprint,
    noise: NoiseMode,
) -> usize {
    sat(try_arena_len_noise(d, mode, k, fp, noise))
}

/// [`arena_len_noise`], or `None` when it overflows `usize`.
pub const fn try_arena_len_noise(
    d: &Dims,
    mode: AdaptMode,
    k: usize,
    fp: Footprint,
    noise: NoiseMode,
) -> Option<usize> {
    match NavLayout::try_new_noise(d, mode, k, fp, noise) {
        Some(l) => l.checked_total_floats(),
        None => None,
    }
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
    let g = tri!(try_arena_len_noise(d, mode, k, fp, NoiseMode::Gaussian));
    let z = tri!(try_arena_len_noise(d, mode, k, fp, NoiseMode::Zero));
    Some(if g > z { g } else { z })
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
/// the RAM layout it checks last, so that [`crate::spec::preset`] only declares sizes and the
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
            && crate::spec::schema::checked_tensor_bytes(self)
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
        use crate::spec::schema::TensorId;
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

    /// The regions of each [`NavLayout`] field are contiguous in the arena, the fields in
    /// their declaration order (what `docs/memory.md` describes).
    #[test]
    fn regions_are_grouped_by_layout_field_in_order() {
        for w in REGION_PART.windows(2) {
            assert!(
                w[0] as usize <= w[1] as usize,
                "{:?} before {:?}",
                w[0],
                w[1]
            );
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
