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

// The flag word's bits of each setting live beside the settings' keys.
pub use crate::spec::setting_key::{
    COMMIT_DELAY_MASK, COMMIT_DELAY_SHIFT, DISC_STEPS_MASK, DISC_STEPS_SHIFT, FLAG_ADAPT,
    FLAG_COMPACT_PSI, FLAG_COSSIM, FLAG_DISC_HEAD_RESET, FLAG_FULL_ADAPT, FLAG_HEAD_ONLY,
    FLAG_INT8_ACTIVATIONS, FLAG_NORMALIZED_STEP, FLAG_PER_GROUP_STEP, FLAG_REFERENCE_ADAPT_LOSS,
    FLAG_REFERENCE_CRITIC_SCALE, FLAG_ZERO_NOISE, KNOWN_FLAGS, MAX_COMMIT_DELAY,
};

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
