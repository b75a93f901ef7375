//! The keys of the model's settings: [`SettingKey`] and [`SETTING_KEYS`], re-exported from
//! [`crate::spec`], where the settings themselves are declared. They live in a module of their
//! own, below [`crate::error`], because an error names a setting by its key
//! ([`BlobError::SettingType`](crate::error::BlobError::SettingType), ...): the errors build on
//! the keys, the settings on the errors, and no module imports one above it.

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
