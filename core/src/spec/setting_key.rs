//! The keys of the model's settings, [`SettingKey`] and [`SETTING_KEYS`] (re-exported from
//! [`crate::spec`], where the settings themselves are declared), and each setting's bits in a
//! format v1-v4 header's flag word (`FLAG_*`, the fields' shifts and masks, [`KNOWN_FLAGS`];
//! re-exported from [`crate::spec::schema`]): what names a setting in a blob, in one place.
//! They live in a module of their own, below [`crate::error`], because an error names a
//! setting by its key ([`BlobError::SettingType`](crate::error::BlobError::SettingType),
//! ...): the errors build on the keys, the settings on the errors, and no module imports one
//! above it.

use core::fmt;

/// The key of every setting of a [`ModelSpec`](crate::spec::ModelSpec), in the order the blob
/// encoder writes them (the same words as the serde form's keys, and as the command line's
/// flags without the dashes and with `_` for `-`).
pub const SETTING_KEYS: [&str; 16] = [
    "adapt",
    "emd",
    "noise",
    "adapt_mode",
    "inner_lr",
    "disc_lr",
    "max_inner",
    "disc_steps",
    "step_rule",
    "disc_head_reset",
    "adapt_loss",
    "reference_critic",
    "head_only",
    "commit_delay",
    "int8_activations",
    "compact_psi",
];

/// The index of `s` in `list`: the one lookup of a name or a key (not inlined, so that
/// each table costs a call on a device, not an unrolled comparison per entry).
#[inline(never)]
pub(crate) fn index_of(list: &[&str], s: &[u8]) -> Option<usize> {
    list.iter().position(|n| n.as_bytes() == s)
}

/// A setting of a [`ModelSpec`](crate::spec::ModelSpec), by its index in [`SETTING_KEYS`] (one
/// byte, so that an error naming it stays small); shown as its key.
#[derive(Clone, Copy, PartialEq, Eq)]
pub struct SettingKey(u8);

impl SettingKey {
    /// `disc_steps`.
    pub const DISC_STEPS: SettingKey = SettingKey(7);
    /// `commit_delay`.
    pub const COMMIT_DELAY: SettingKey = SettingKey(13);
    /// `disc_lr`.
    pub const DISC_LR: SettingKey = SettingKey(5);

    /// The setting whose key is `key`.
    pub fn named(key: &str) -> Option<SettingKey> {
        SettingKey::of(key.as_bytes())
    }

    pub(crate) fn of(key: &[u8]) -> Option<SettingKey> {
        index_of(&SETTING_KEYS, key).map(|i| SettingKey(i as u8))
    }

    /// Its index in [`SETTING_KEYS`].
    pub fn index(self) -> usize {
        usize::from(self.0)
    }

    /// Its key.
    pub fn as_str(self) -> &'static str {
        SETTING_KEYS.get(self.index()).copied().unwrap_or("?")
    }
}

impl fmt::Display for SettingKey {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.as_str())
    }
}

impl fmt::Debug for SettingKey {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{:?}", self.as_str())
    }
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
/// [`AdaptMode::Full`](crate::spec::schema::AdaptMode::Full) mode (every parameter of θ, ω and the actor head adapted in f32 RAM), so it
/// must run in that mode. Without it the model runs in the [`AdaptMode::Efficient`](crate::spec::schema::AdaptMode::Efficient) mode (per-unit
/// gains and biases over the base weights), which is how every blob without the bit has always been
/// run on the device ([`ModelSpec::adapt_mode`](crate::spec::ModelSpec::adapt_mode)).
pub const FLAG_FULL_ADAPT: u32 = 8;

/// Bit of the blob header's flags: the inner loop's descent step on L_ad is normalised
/// ([`StepRule::Normalized`](crate::spec::schema::StepRule::Normalized), [`InnerRule::step_rule`](crate::spec::InnerRule::step_rule)); without
/// it the paper's gradient step.
pub const FLAG_NORMALIZED_STEP: u32 = 1 << 16;

/// Bit of the blob header's flags: the descent step is normalised per parameter group
/// ([`StepRule::PerGroup`](crate::spec::schema::StepRule::PerGroup); takes precedence over [`FLAG_NORMALIZED_STEP`]).
pub const FLAG_PER_GROUP_STEP: u32 = 1 << 17;

/// Bit of the blob header's flags: D restarts with every episode, layer 1 from ω and the output
/// layer (w2, b2) at zero
/// ([`InnerRule::disc_head_reset`](crate::spec::InnerRule::disc_head_reset)).
pub const FLAG_DISC_HEAD_RESET: u32 = 1 << 18;

/// Bit of the blob header's flags: L_ad takes the reference implementation's form
/// ([`AdaptLossKind::Reference`](crate::spec::schema::AdaptLossKind::Reference), [`InnerRule::adapt_loss`](crate::spec::InnerRule::adapt_loss));
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
