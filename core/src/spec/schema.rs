//! The model schema: every tensor of a navigation model, declared once.
//!
//! One table (llm.c style) names each tensor, gives its raw id, its shape as a function of
//! [`Dims`], its parameter group ([`Group`]: θ = G, ω = D, φ = the policy), whether the inner
//! loop of Algorithm 1 updates it ([`TensorId::inner`]) and whether it may be stored int8
//! ([`TensorId::is_vector`]: bias vectors are always f32). Everything else derives from it:
//! the blob's records and validation ([`crate::blob`]), the navigator's weight views
//! ([`crate::navigator::NavWeights`]), the host trainer's parameter names, checkpoints and
//! exporter (`gman-host-sim`), and the groups [`TensorId::GENERATOR`],
//! [`TensorId::DISCRIMINATOR`] and [`TensorId::ACTOR_HEAD`].
//!
//! The bits of a blob header's model flags ([`FLAG_ADAPT`], ...) are declared here too; the
//! one mapping between them and the settings they stand for is [`crate::spec::ModelSpec`]'s
//! (`bits`, `from_bits`).
//!
//! The PS module of the dagger variants (`gman-host-sim`'s `ps`) is a host-side
//! network: it is not part of this schema and never stored in a blob.

use crate::spec::preset::Dims;
use crate::NUM_ACTIONS;

/// The parameter group a tensor belongs to.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Group {
    /// θ: the feature generator G.
    Theta,
    /// ω: the environmental meta discriminator D.
    Omega,
    /// φ: the navigation policy (fusion, LSTM, actor and value heads, per-cell layer).
    Phi,
}

macro_rules! tensor_schema {
    (|$d:ident| $(
        $(#[$m:meta])* $name:ident = $v:literal, $group:ident, inner: $inner:literal,
        vector: $vector:literal, present: $present:expr, shape: ($r:expr, $c:expr);
    )*) => {
        /// Identifies a tensor of the model (and of a blob).
        #[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
        #[repr(u16)]
        pub enum TensorId { $($(#[$m])* $name = $v),* }

        impl TensorId {
            /// Every id, in storage order.
            pub const ALL: &'static [TensorId] = &[$(TensorId::$name),*];

            /// The id with raw value `v`.
            pub const fn from_raw(v: u16) -> Option<TensorId> {
                match v { $($v => Some(TensorId::$name),)* _ => None }
            }

            /// The name used by `gman inspect`, the trainer's parameters and checkpoints.
            pub const fn name(self) -> &'static str {
                match self { $(TensorId::$name => stringify!($name)),* }
            }

            /// The parameter group of this tensor.
            pub const fn group(self) -> Group {
                match self { $(TensorId::$name => Group::$group),* }
            }

            /// True when the inner loop of Algorithm 1 updates this tensor (all of θ and ω,
            /// and φ's actor head; in [`AdaptMode::Efficient`] through per-unit gains and
            /// biases over it).
            pub const fn inner(self) -> bool {
                match self { $(TensorId::$name => $inner),* }
            }

            /// True for bias vectors, which are always stored as f32 (never int8).
            pub const fn is_vector(self) -> bool {
                match self { $(TensorId::$name => $vector),* }
            }

            /// True when a model of these dims has this tensor: every id but the per-cell
            /// layer's, which exists only with a spatial map (its shape is `(0, 0)`
            /// otherwise, and blobs and checkpoints do not store it).
            pub const fn present(self, $d: &Dims) -> bool {
                match self { $(TensorId::$name => $present),* }
            }

            /// `(rows, cols)` of this tensor for the given dims; vectors have `cols == 1`; an
            /// absent tensor is `(0, 0)`. A width that does not fit in `usize` saturates at
            /// `usize::MAX` (such dims never come out of
            /// [`Blob::parse`](crate::blob::Blob::parse), see [`Dims::checked_sizes`]).
            pub const fn shape(self, $d: &Dims) -> (usize, usize) {
                if !self.present($d) {
                    return (0, 0);
                }
                match self { $(TensorId::$name => ($r, $c)),* }
            }
        }
    };
}

tensor_schema! { |d|
    /// G hidden layer weights, `gen_hidden x (noise + attr)` (noise columns first).
    GenW1 = 0, Theta, inner: true, vector: false, present: true,
        shape: (d.gen_hidden, d.gen_in());
    /// G hidden bias, `gen_hidden`.
    GenB1 = 1, Theta, inner: true, vector: true, present: true, shape: (d.gen_hidden, 1);
    /// G output weights, `feat x gen_hidden`.
    GenW2 = 2, Theta, inner: true, vector: false, present: true, shape: (d.feat, d.gen_hidden);
    /// G output bias, `feat`.
    GenB2 = 3, Theta, inner: true, vector: true, present: true, shape: (d.feat, 1);
    /// D hidden weights, `disc_hidden x feat`.
    DiscW1 = 4, Omega, inner: true, vector: false, present: true,
        shape: (d.disc_hidden, d.feat);
    /// D hidden bias, `disc_hidden`.
    DiscB1 = 5, Omega, inner: true, vector: true, present: true, shape: (d.disc_hidden, 1);
    /// D output weights, `1 x disc_hidden`.
    DiscW2 = 6, Omega, inner: true, vector: false, present: true, shape: (1, d.disc_hidden);
    /// D output bias, `1`.
    DiscB2 = 7, Omega, inner: true, vector: true, present: true, shape: (1, 1);
    /// Policy fusion weights, `embed x fuse_in`.
    FuseW = 8, Phi, inner: false, vector: false, present: true, shape: (d.embed, d.fuse_in());
    /// Policy fusion bias, `embed`.
    FuseB = 9, Phi, inner: false, vector: true, present: true, shape: (d.embed, 1);
    /// LSTM input weights, `4 lstm_hidden x embed`.
    LstmWx = 10, Phi, inner: false, vector: false, present: true,
        shape: (d.lstm_hidden.saturating_mul(4), d.embed);
    /// LSTM recurrent weights, `4 lstm_hidden x lstm_hidden`.
    LstmWh = 11, Phi, inner: false, vector: false, present: true,
        shape: (d.lstm_hidden.saturating_mul(4), d.lstm_hidden);
    /// LSTM bias, `4 lstm_hidden`.
    LstmB = 12, Phi, inner: false, vector: true, present: true,
        shape: (d.lstm_hidden.saturating_mul(4), 1);
    /// Actor head weights, `6 x lstm_hidden`.
    ActorW = 13, Phi, inner: true, vector: false, present: true,
        shape: (NUM_ACTIONS, d.lstm_hidden);
    /// Actor head bias, `6`.
    ActorB = 14, Phi, inner: true, vector: true, present: true, shape: (NUM_ACTIONS, 1);
    /// Value head ("critic" of the actor-critic) weights, `1 x lstm_hidden`.
    CriticW = 15, Phi, inner: false, vector: false, present: true, shape: (1, d.lstm_hidden);
    /// Value head bias, `1`.
    CriticB = 16, Phi, inner: false, vector: true, present: true, shape: (1, 1);
    /// Per-cell layer weights (shared by every map cell), `cell_embed x 2 feat`; only in
    /// models with a spatial observation map (format v3).
    CellW = 17, Phi, inner: false, vector: false, present: d.map_cells() > 0,
        shape: (d.cell_embed, d.cell_in());
    /// Per-cell layer bias, `cell_embed`; only with a map.
    CellB = 18, Phi, inner: false, vector: true, present: d.map_cells() > 0,
        shape: (d.cell_embed, 1);
}

/// Number of tensor ids.
pub const NUM_TENSORS: usize = TensorId::ALL.len();

/// The first `N` ids of [`TensorId::ALL`] in `group` (only those the inner loop updates when
/// `inner_only`), in storage order; the group constants of [`TensorId`] are built with it
/// (a unit test checks that none is cut short).
const fn select<const N: usize>(group: Group, inner_only: bool) -> [TensorId; N] {
    let mut out = [TensorId::GenW1; N];
    let (mut i, mut n) = (0, 0);
    while i < TensorId::ALL.len() && n < N {
        let id = TensorId::ALL[i];
        if id.group() as u8 == group as u8 && (id.inner() || !inner_only) {
            out[n] = id;
            n += 1;
        }
        i += 1;
    }
    out
}

impl TensorId {
    /// The tensors of G (θ), in storage order.
    pub const GENERATOR: [TensorId; 4] = select(Group::Theta, false);
    /// The tensors of D (ω), in storage order.
    pub const DISCRIMINATOR: [TensorId; 4] = select(Group::Omega, false);
    /// The part of φ the inner loop adapts: the actor head, in storage order.
    pub const ACTOR_HEAD: [TensorId; 2] = select(Group::Phi, true);

    /// The tensors of a model of these dims, in storage order ([`TensorId::ALL`] without
    /// the per-cell layer when there is no spatial map).
    pub fn all_for(d: &Dims) -> impl Iterator<Item = TensorId> + '_ {
        TensorId::ALL
            .iter()
            .copied()
            .filter(move |id| id.present(d))
    }

    /// The tensor named `name` ([`TensorId::name`]).
    pub fn from_name(name: &str) -> Option<TensorId> {
        TensorId::ALL.iter().copied().find(|id| id.name() == name)
    }

    /// Floats of this tensor for these dims (`rows * cols`, saturating).
    pub const fn numel(self, d: &Dims) -> usize {
        let (r, c) = self.shape(d);
        r.saturating_mul(c)
    }
}

/// The largest `rows * cols` and the largest `rows` over the tensors of `d` (saturating):
/// the scratch a tensor-by-tensor encoder needs.
pub const fn max_tensor_len(d: &Dims) -> (usize, usize) {
    let (mut n, mut rows, mut i) = (0, 0, 0);
    while i < TensorId::ALL.len() {
        let (r, c) = TensorId::ALL[i].shape(d);
        let len = r.saturating_mul(c);
        if len > n {
            n = len;
        }
        if r > rows {
            rows = r;
        }
        i += 1;
    }
    (n, rows)
}

/// True when, for every tensor of `d`, the widths, `rows * cols` and its byte lengths as f32
/// (`4 rows cols`) and as int8 (`rows cols + 4 rows`) fit in `usize` (part of
/// [`Dims::checked_sizes`]).
pub(crate) const fn checked_tensor_bytes(d: &Dims) -> bool {
    if d.checked_gen_in().is_none() || d.checked_fuse_in().is_none() {
        return false;
    }
    if d.lstm_hidden.checked_mul(4).is_none()
        || d.feat.checked_mul(2).is_none()
        || d.checked_cell_out().is_none()
        || d.checked_cell_params().is_none()
    {
        return false;
    }
    let mut i = 0;
    while i < TensorId::ALL.len() {
        let (r, c) = TensorId::ALL[i].shape(d);
        let n = match r.checked_mul(c) {
            Some(n) => n,
            None => return false,
        };
        let i8_bytes = match r.checked_mul(4) {
            Some(s) => n.checked_add(s),
            None => None,
        };
        if n.checked_mul(4).is_none() || i8_bytes.is_none() {
            return false;
        }
        i += 1;
    }
    true
}

/// Which parameters adaptation updates, and where they live. See [`crate::navigator::memory`].
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum AdaptMode {
    /// All of θ, ω and the actor head in f32 RAM.
    Full,
    /// Per-unit gain and bias over int8 base weights in flash.
    Efficient,
}

/// Noise z fed to G at navigation time.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Default)]
pub enum NoiseMode {
    /// A fresh N(0, I) sample every step (the paper's G(SE(y), z) with random z). Default.
    #[default]
    Gaussian,
    /// z = 0 always (the reference implementation); then x_t only changes when θ adapts.
    Zero,
}

/// What scores the generated features in L_ad (the EMD variants of the paper's Table 3).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Default)]
pub enum Emd {
    /// The learned discriminator D (GMAN). Default.
    #[default]
    Discriminator,
    /// The cosine similarity between x_t and s_t ("CosSim"); D is not used or updated.
    CosSim,
}

/// Which form of Eq. 3 to use ([`crate::adapt::ad_loss::adapt_loss`] computes both).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum AdaptLossKind {
    /// `−mean_t D(x_t) ‖a_t‖₂` (the paper's Eq. 3). Default.
    #[default]
    Paper,
    /// `‖ Σ_t a_t (−D(x_t)) ‖₂` (the reference implementation).
    Reference,
}

/// Bit of the blob header's flags: the model was meta-trained to adapt at inference (GMAN); a
/// loader should enable the inner loop ([`ModelSpec::adapt`](crate::spec::ModelSpec::adapt)).
pub const FLAG_ADAPT: u32 = 1;
/// Bit of the blob header's flags: G is driven with zero noise (the reference implementation's
/// choice) instead of fresh Gaussian noise ([`ModelSpec::noise`](crate::spec::ModelSpec::noise)).
pub const FLAG_ZERO_NOISE: u32 = 2;
/// Bit of the blob header's flags: the inner loop scores generated features with the cosine
/// similarity to the observation instead of D (the CosSim EMD variant,
/// [`ModelSpec::emd`](crate::spec::ModelSpec::emd)).
pub const FLAG_COSSIM: u32 = 4;
/// Bit of the blob header's flags: the model was meta-trained with the inner loop in the
/// [`AdaptMode::Full`] mode (every parameter of θ, ω and the actor head adapted in f32 RAM), so it
/// must run in that mode. Without it the model runs in the [`AdaptMode::Efficient`] mode (per-unit
/// gains and biases over the base weights), which is how every blob without the bit has always been
/// run on the device ([`ModelSpec::adapt_mode`](crate::spec::ModelSpec::adapt_mode)).
pub const FLAG_FULL_ADAPT: u32 = 8;

/// Bit of the blob header's flags: the inner loop's descent step on L_ad is normalised
/// ([`StepRule::Normalized`], [`InnerRule::step_rule`](crate::spec::InnerRule::step_rule)); without
/// it the paper's gradient step.
pub const FLAG_NORMALIZED_STEP: u32 = 1 << 16;

/// Bit of the blob header's flags: the descent step is normalised per parameter group
/// ([`StepRule::PerGroup`]; takes precedence over [`FLAG_NORMALIZED_STEP`]).
pub const FLAG_PER_GROUP_STEP: u32 = 1 << 17;

/// Bit of the blob header's flags: D restarts with every episode, layer 1 from ω and the output
/// layer (w2, b2) at zero
/// ([`InnerRule::disc_head_reset`](crate::spec::InnerRule::disc_head_reset)).
pub const FLAG_DISC_HEAD_RESET: u32 = 1 << 18;

/// Bit of the blob header's flags: L_ad takes the reference implementation's form
/// ([`AdaptLossKind::Reference`], [`InnerRule::adapt_loss`](crate::spec::InnerRule::adapt_loss));
/// without it the paper's Eq. 3.
pub const FLAG_REFERENCE_ADAPT_LOSS: u32 = 1 << 19;

/// Bit of the blob header's flags: L_D's critic terms are scaled by 10 as in the reference
/// implementation ([`InnerRule::critic_scale`](crate::spec::InnerRule::critic_scale)); without it
/// by 1, the paper's Eq. 1.
pub const FLAG_REFERENCE_CRITIC_SCALE: u32 = 1 << 20;

/// Bit of the blob header's flags: the inner loop's descent step on L_ad updates only the actor
/// head, G stays at θ (the reference implementation's default, whose G parameters get no inner
/// gradient; [`InnerRule::head_only`](crate::spec::InnerRule::head_only)); without it G and the
/// head, the paper.
pub const FLAG_HEAD_ONLY: u32 = 1 << 21;

/// Bit of the blob header's flags: the int8 weight matrices multiply int8 activations
/// (quantised per input segment at run time) into i32 accumulators, the integer path of
/// [`crate::nn::qkernel`]; without it int8 weights are widened to f32 and multiply f32
/// activations. A loader applies it to every int8 view
/// ([`crate::nn::matrix::MatRef::with_int8_activations`]; [`crate::navigator::NavWeights::from_blob`]
/// does). It changes no other setting of the navigator.
pub const FLAG_INT8_ACTIVATIONS: u32 = 1 << 24;

/// Bit of the blob header's flags: the navigator keeps Ψ's observations s_t in a compact
/// form, int16 with one scale per entry (`q_j = round(s_j * (32767 / max|s|))`, read back
/// as `q_j * (max|s| / 32767)`), so that the inner update sees those values instead of the
/// f32 ones; the firmware's [`crate::navigator::memory::Footprint::Minimal`] arena needs it. `gman
/// export` sets it with int8 activations. Like [`FLAG_INT8_ACTIVATIONS`] it says how a
/// blob is run ([`crate::navigator::NavWeights::from_blob`] reads it); without it every
/// path computes what it computed before the flag.
pub const FLAG_COMPACT_PSI: u32 = 1 << 23;

/// Bits 8..16 of the blob header's flags: D's ascent steps per inner update minus one
/// ([`InnerRule::disc_steps`](crate::spec::InnerRule::disc_steps), 1..=256; 0 in every blob written
/// before the setting, i.e. the paper's one step).
pub const DISC_STEPS_SHIFT: u32 = 8;
/// Mask of [`DISC_STEPS_SHIFT`]'s field.
pub const DISC_STEPS_MASK: u32 = 0xFF << DISC_STEPS_SHIFT;

/// Bits 25..31 of the blob header's flags: the inner update's commit delay d
/// ([`InnerRule::commit_delay`](crate::spec::InnerRule::commit_delay), 0..=[`MAX_COMMIT_DELAY`]; 0
/// in every blob written before the setting: the update takes effect in the step that fills Ψ).
pub const COMMIT_DELAY_SHIFT: u32 = 25;
/// Mask of [`COMMIT_DELAY_SHIFT`]'s field.
pub const COMMIT_DELAY_MASK: u32 = 0x3F << COMMIT_DELAY_SHIFT;
/// The largest commit delay a blob can record.
pub const MAX_COMMIT_DELAY: u32 = 63;

/// Every bit of the blob header's flags this build knows (the `FLAG_*` bits and the
/// [`DISC_STEPS_MASK`] and [`COMMIT_DELAY_MASK`] fields). The others (bits 4-7, 22 and 31)
/// are refused in a format v4 blob ([`crate::BlobError::UnknownFlagBit`]) and by the
/// encoder: a blob made by a newer build with a setting this one does not know is not run
/// as if the setting were off.
pub const KNOWN_FLAGS: u32 = FLAG_ADAPT
    | FLAG_ZERO_NOISE
    | FLAG_COSSIM
    | FLAG_FULL_ADAPT
    | DISC_STEPS_MASK
    | FLAG_NORMALIZED_STEP
    | FLAG_PER_GROUP_STEP
    | FLAG_DISC_HEAD_RESET
    | FLAG_REFERENCE_ADAPT_LOSS
    | FLAG_REFERENCE_CRITIC_SCALE
    | FLAG_HEAD_ONLY
    | FLAG_COMPACT_PSI
    | FLAG_INT8_ACTIVATIONS
    | COMMIT_DELAY_MASK;

/// [`crate::BlobError::UnknownFlagBit`] naming the lowest bit of `flags` outside
/// [`KNOWN_FLAGS`].
pub const fn check_known_flags(flags: u32) -> Result<(), crate::BlobError> {
    let unknown = flags & !KNOWN_FLAGS;
    if unknown == 0 {
        Ok(())
    } else {
        Err(crate::BlobError::UnknownFlagBit {
            bit: unknown.trailing_zeros() as u8,
            flags,
        })
    }
}

/// How the inner loop's descent step on L_ad (Eq. 3) is sized.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum StepRule {
    /// `θ ← θ − α2 ∇θ L_ad` (the paper).
    #[default]
    Gradient,
    /// `θ ← θ − α2 ∇/‖∇‖`, the norm over every adapted parameter (θ and φ together): α2 is
    /// the length of the step.
    Normalized,
    /// Each group normalised on its own: `θ ← θ − α2 ∇θ/‖∇θ‖` and `φ ← φ − α2 ∇φ/‖∇φ‖`, so
    /// G moves by α2 whatever the actor head's gradient (under [`StepRule::Normalized`] the
    /// head's larger gradient takes most of the length).
    PerGroup,
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn group_constants_are_complete_and_in_order() {
        let count = |g: Group, inner_only: bool| {
            TensorId::ALL
                .iter()
                .filter(|id| id.group() == g && (id.inner() || !inner_only))
                .count()
        };
        assert_eq!(count(Group::Theta, false), TensorId::GENERATOR.len());
        assert_eq!(count(Group::Omega, false), TensorId::DISCRIMINATOR.len());
        assert_eq!(count(Group::Phi, true), TensorId::ACTOR_HEAD.len());
        assert_eq!(
            TensorId::GENERATOR,
            [
                TensorId::GenW1,
                TensorId::GenB1,
                TensorId::GenW2,
                TensorId::GenB2
            ]
        );
        assert_eq!(TensorId::ACTOR_HEAD, [TensorId::ActorW, TensorId::ActorB]);
        assert_eq!(TensorId::DISCRIMINATOR[3], TensorId::DiscB2);
    }

    #[test]
    fn raw_ids_and_names_round_trip() {
        for (i, id) in TensorId::ALL.iter().enumerate() {
            assert_eq!(*id as usize, i);
            assert_eq!(TensorId::from_raw(i as u16), Some(*id));
            assert_eq!(TensorId::from_name(id.name()), Some(*id));
        }
        assert_eq!(TensorId::from_raw(NUM_TENSORS as u16), None);
        assert_eq!(TensorId::from_name("PsW1"), None);
    }
}
