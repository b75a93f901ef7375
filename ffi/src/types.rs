//! The C structs of the API (what `include/gman.h` declares).

use super::*;

/// What a blob holds ([`gman_inspect`]).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct gman_info {
    /// Format version of the blob (1 to the library's newest).
    pub format_version: u32,
    /// The blob's model flags (see the model's schema).
    pub flags: u32,
    /// CRC-32 (IEEE) of the payload, as the header records it.
    pub payload_crc: u32,
    /// Width of the attribute vector SE(y) ([`gman_reset`]'s `attr`).
    pub attr: u32,
    /// Width of the noise z.
    pub noise: u32,
    /// Width of an observation s_t ([`gman_step`]'s `obs`) and of a generated feature x_t.
    pub feat: u32,
    /// Hidden width of G.
    pub gen_hidden: u32,
    /// Hidden width of D.
    pub disc_hidden: u32,
    /// Width of the LSTM state.
    pub lstm_hidden: u32,
    /// Width of the policy's fused embedding.
    pub embed: u32,
    /// Width of the PS input ([`gman_step`]'s `ps`; 0: none).
    pub ps: u32,
    /// Rows of the spatial map (0: none).
    pub map_rows: u32,
    /// Columns of the spatial map (0: none).
    pub map_cols: u32,
    /// Channels of the per-cell layer.
    pub cell_embed: u32,
    /// Floats of one map ([`gman_step`]'s `map`): `map_rows * map_cols * feat`.
    pub map_len: u32,
    /// The model's settings the blob records ([`gman_inspect`]), or those the navigator runs
    /// ([`gman_nav_info`]: the blob's, with the commit delay the options chose).
    pub settings: gman_settings,
    /// Capacity of Ψ ([`GMAN_BUFFER_CAPACITY`]).
    pub buffer_capacity: u32,
    /// Bytes of arena a navigator over this blob needs ([`gman_arena_size`]).
    pub arena_bytes: u64,
}

/// The model's settings: how the navigator runs the weights (gman-core's `ModelSpec`, the
/// part a C program reads). A blob records them ([`gman_info::settings`]); the navigator runs
/// them exactly, so that the device adapts as the host trained and evaluated the model.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct gman_settings {
    /// 1: the model adapts at inference (the GMAN inner loop); 0: it does not.
    pub adapt: u32,
    /// Adaptation mode the model was trained in: 0 Efficient, 1 Full.
    pub adapt_mode: u32,
    /// What scores the generated features: 0 the discriminator D, 1 cosine similarity.
    pub emd: u32,
    /// Noise of G: 0 Gaussian, 1 zero.
    pub noise_mode: u32,
    /// At most this many inner updates per episode.
    pub max_inner_updates: u32,
    /// α1, the ascent rate of D.
    pub alpha_disc: f32,
    /// α2, the descent rate of θ and φ.
    pub alpha_adapt: f32,
    /// The commit delay d (0 to 63): the inner update that starts when Ψ fills at step t
    /// takes effect at the end of step t + d (0: within step t). A blob records it in bits
    /// 25..31 of [`gman_info::flags`].
    pub commit_delay: u32,
}

/// Longest key or value name of a [`gman_setting`], with its terminating NUL.
pub const GMAN_SETTING_TEXT: usize = 24;

/// One of a model's settings, by key ([`gman_blob_setting`]): every setting the blob
/// records, including those [`gman_settings`] does not carry, so that a program can list
/// them all without knowing them in advance.
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct gman_setting {
    /// The setting's key, NUL-terminated (e.g. `"commit_delay"`, the word `gman inspect`
    /// prints and `gman train`'s flag spells with dashes); empty past the last setting.
    pub key: [c_char; GMAN_SETTING_TEXT],
    /// Its type: 0 a count (`count`), 1 a rate (`rate`), 2 a name (`name`), 3 a switch
    /// (`count`, 0 or 1), 4 not set (`disc_lr` when α1 follows α2).
    pub kind: u32,
    /// The value of a count or a switch.
    pub count: u32,
    /// The value of a rate.
    pub rate: f32,
    /// The value of a name, NUL-terminated (e.g. `"per-group"`); empty for other types.
    pub name: [c_char; GMAN_SETTING_TEXT],
}

impl Default for gman_setting {
    fn default() -> Self {
        gman_setting {
            key: [0; GMAN_SETTING_TEXT],
            kind: 0,
            count: 0,
            rate: 0.0,
            name: [0; GMAN_SETTING_TEXT],
        }
    }
}

/// Options of [`gman_init`]; pass NULL for the defaults (all fields 0).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct gman_options {
    /// Action selection: 0 the most probable action (greedy), 1 a sample from the
    /// probabilities with the navigator's seeded generator.
    pub selection: u32,
    /// When the inner update runs: 0 (automatic) inside [`gman_step`]: with a commit delay
    /// d = 0 in the step that fills Ψ, with d > 0 one bounded slice in each of the d steps
    /// after it; 1 (manual) only when the caller calls [`gman_adapt_now`] (a step with a
    /// full buffer then fails with [`GMAN_ERR_CONFIG`]); 2 (background, needs d >= 1) the
    /// caller runs the slices with [`gman_adapt_slice`] from a context of lower priority
    /// than the control loop, and a step that would commit an unfinished update fails with
    /// [`GMAN_ERR_UPDATE_NOT_READY`], changing nothing. Other values are refused.
    pub schedule: u32,
    /// 1: refuse a blob whose checksum does not cover its header (formats v1-v3, where a
    /// flipped flag bit, rate or map size goes unnoticed) with [`GMAN_ERR_BLOB_VERSION`],
    /// before anything of it is read; `gman upgrade-blob IN OUT` rewrites such a blob in
    /// the current format. 0: accept every format this library reads. Other values are
    /// refused ([`GMAN_ERR_CONFIG`]).
    pub require_header_crc: u32,
    /// The settings the device chooses where the blob leaves the choice to it; all 0: the
    /// blob's. Only the commit delay is the device's to choose: `settings.commit_delay`
    /// (steps between Ψ filling and the inner update taking effect, 0 to 63) 0 runs the
    /// blob's recorded delay ([`gman_info::settings`]); a non-zero value runs at that delay
    /// when the blob records 0, and must equal the blob's delay when it records one (else
    /// [`GMAN_ERR_CONFIG`], as for a value above 63). Every other field must be 0
    /// ([`GMAN_ERR_CONFIG`]): the blob's settings are the model's.
    pub settings: gman_settings,
}

/// What one step returns ([`gman_step`]).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct gman_step_out {
    /// The chosen action: 0 MoveAhead, 1 RotateLeft, 2 RotateRight, 3 LookUp, 4 LookDown,
    /// 5 Done.
    pub action: u32,
    /// 1 when this step ended with an inner update (applied or rolled back).
    pub adapted: u32,
    /// The policy's action probabilities.
    pub probs: [f32; GMAN_NUM_ACTIONS],
    /// The critic's value estimate.
    pub value: f32,
}

/// Counters of a navigator, per episode (reset by [`gman_reset`]) and over its life.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct gman_counters {
    /// Steps in this episode.
    pub steps: u32,
    /// Inner updates applied in this episode.
    pub adaptations: u32,
    /// Adaptation steps rolled back in this episode.
    pub rollbacks: u32,
    /// Padding (always 0).
    pub reserved: u32,
    /// Steps over the navigator's life.
    pub total_steps: u64,
    /// Inner updates over the navigator's life.
    pub total_adaptations: u64,
    /// Rollbacks over the navigator's life.
    pub total_rollbacks: u64,
}

/// The schedule a navigator runs and the state of its pending inner update
/// ([`gman_get_schedule`]).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct gman_schedule_state {
    /// The schedule ([`gman_options::schedule`]): 0 automatic, 1 manual, 2 background (the
    /// commit delay it runs at: [`gman_nav_info`]'s `settings.commit_delay`).
    pub schedule: u32,
    /// 1 from the step that fills Ψ until its inner update commits (d > 0 only).
    pub pending: u32,
    /// Slices of the pending update still to run (0: none pending, or all have run).
    pub slices_left: u32,
}

/// Diagnostics of the last inner update ([`gman_last_adaptation`]).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct gman_adapt_report {
    /// L_D (Eq. 1) before D's ascent step.
    pub ld_loss: f32,
    /// E[D(s)] over the buffer's observations.
    pub ld_mean_real: f32,
    /// E[D(x)] over the generated features.
    pub ld_mean_fake: f32,
    /// The gradient penalty term of L_D.
    pub ld_penalty: f32,
    /// L_ad (Eq. 3) before the descent step.
    pub adapt_loss: f32,
    /// 1 when D's step was applied, 0 when it was rolled back.
    pub disc_applied: u32,
    /// 1 when the step on θ/φ was applied, 0 when it was rolled back.
    pub adapt_applied: u32,
}

/// An opaque navigator; it lives inside the caller's arena ([`gman_init`]).
pub struct gman_nav {
    _private: [u8; 0],
}
