//! The scripted navigation episode the firmware runs, shared verbatim with the host-side
//! parity test (`tests/tests/firmware_qemu.rs` includes this file with `#[path]`), so x86 and
//! the Cortex-M4F execute the same source on the same blob and the same observations and must
//! print the same bits.
//!
//! The observations are a replay: the pooled feature vector s_t and the spatial map of a known
//! episode, recorded on the host by `host-sim/examples/record_episode.rs`. The navigator's
//! actions do not change what it sees next (a microcontroller cannot hold the scene), but
//! everything the navigator computes on the device — G, the policy with its per-cell layer over
//! the map, Ψ, the inner updates of Algorithm 1, the rollback checks — runs exactly as it would
//! in a closed loop.
//!
//! The file is read through a [`Source`]: on the device from the host, step by step, through
//! semihosting (as a robot reads its camera: 40 steps of a 3 x 3 map are 200 KiB, which the
//! 512 KiB of flash beside a 337 KiB model cannot hold), on the host from memory.
//!
//! # Episode file (`firmware-example/data/episode.gmep`), all integers little-endian
//! ```text
//! offset  size        field
//!      0  4           magic "GMEP"
//!      4  2           version (2)
//!      6  2           n, number of steps
//!      8  2           feat, width of an observation (512)
//!     10  2           attr, width of SE(y) (45)
//!     12  8           seed passed to Navigator::reset
//!     20  2           cells, sectors of the spatial map (rows x cols; 0: none)
//!     22  2           L, length of the label (at most LABEL_MAX)
//!     24  4           CRC-32 (IEEE) of every byte from offset 28 to the end
//!     28  L           label, UTF-8 (scene, target, kind; for the log only)
//!    ...  4 attr      SE(y) of the target, f32
//!    ...  n           action the recording script took at each step (Action index; log only)
//!    ...  n (1+cells) feat
//!                     per step: the pooled observation s_t, then the map (cell-major),
//!                     u8: round(v * 255) of features v in [0, 1]
//! ```
//! Observations are stored as u8 because the simulator's features are in [0, 1] with ±0.02
//! noise, far coarser than 1/255, and f32 would be four times the bytes. The firmware and the
//! host dequantise with the same expression (`b as f32 / 255.0`), so both feed the navigator
//! identical f32 bits.

use core::fmt;

use gman_core::blob::crc32::crc32_update;
use gman_core::blob::Blob;
use gman_core::navigator::memory::{arena_len_with, AdaptMode, Footprint};
use gman_core::navigator::{
    Counters, Efficient, Emd, NavConfig, NavWeights, Navigator, NoiseMode, Schedule, StepOutput,
};
use gman_core::{Action, Dims};

/// The model size the firmware runs: the `Mcu` preset with the 3 x 3 spatial map and the
/// 8-channel per-cell layer the map models are trained with (`gman train --map 3x3`).
pub const DIMS: Dims = Dims::MCU.with_map(3, 3, 8);
/// Capacity of the buffer Ψ: the paper's k = 20, so an inner update every 20 steps.
pub const K: usize = 20;
/// The commit delay the firmware runs a blob with that records none
/// ([`InnerRule::commit_delay`](gman_core::spec::InnerRule::commit_delay) of
/// [`NavConfig::model`]; a blob's own non-zero delay wins): the inner update that
/// starts when Ψ fills is computed in slices inside the next 20 steps and takes effect at the
/// end of the 20th, so no step carries more than about a twentieth of it (see
/// `docs/device.md`; `gman eval --commit-delay 20` runs the same schedule on the host).
pub const COMMIT_DELAY: u32 = 20;
/// The navigator's arena layout: with the feature `int8-activations`, whose build embeds a
/// blob with [`FLAG_COMPACT_PSI`](gman_core::spec::schema::FLAG_COMPACT_PSI), the smallest,
/// [`Footprint::Minimal`] (no Ψ_x, Ψ's observations as int16; a blob without the flag is
/// refused with a typed error), else [`Footprint::Compact`]. (The host's run of this file
/// in the parity test has no such feature: it runs `Compact`, which gives the same bits.)
#[allow(unexpected_cfgs)] // (the parity test's crate has no such feature)
pub const FOOTPRINT: Footprint = if cfg!(feature = "int8-activations") {
    Footprint::Minimal
} else {
    Footprint::Compact
};
// The `navigator:` line names the map and K as literals (no formatting code for them).
const _: () = assert!(DIMS.map_rows == 3 && DIMS.map_cols == 3 && K == 20);
/// Floats of RAM the navigator needs ([`arena_len_with`] for [`DIMS`], `Efficient`, [`K`],
/// [`FOOTPRINT`]).
pub const ARENA_LEN: usize = arena_len_with(&DIMS, AdaptMode::Efficient, K, FOOTPRINT);
/// Magic bytes of an episode file.
pub const MAGIC: [u8; 4] = *b"GMEP";
/// Version of the episode file format.
pub const VERSION: u16 = 2;
/// Bytes before the label.
pub const HEADER_LEN: usize = 28;
/// Longest label accepted (bytes).
pub const LABEL_MAX: usize = 160;
/// Bytes read from the source at a time (one cell's features).
const CHUNK: usize = DIMS.feat;

/// Why [`run`] stopped.
#[derive(Debug)]
pub enum Failure {
    /// The episode file is malformed or cannot be read.
    Episode(&'static str),
    /// gman-core returned an error.
    Core(gman_core::Error),
}

impl From<gman_core::Error> for Failure {
    fn from(e: gman_core::Error) -> Self {
        Failure::Core(e)
    }
}

impl From<gman_core::BlobError> for Failure {
    fn from(e: gman_core::BlobError) -> Self {
        Failure::Core(e.into())
    }
}

impl fmt::Display for Failure {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Failure::Episode(what) => write!(f, "episode file: {what}"),
            Failure::Core(e) => write!(f, "gman-core: {e}"),
        }
    }
}

/// Random-access reads of an episode file.
pub trait Source {
    /// Length of the file in bytes.
    fn len(&mut self) -> Result<usize, Failure>;
    /// Fills `buf` with the bytes at `offset..offset + buf.len()` (an error if the file ends
    /// before).
    fn read_at(&mut self, offset: usize, buf: &mut [u8]) -> Result<(), Failure>;
}

/// An episode file in memory (the host parity test; the firmware reads from the host).
#[allow(dead_code)]
pub struct Bytes<'a>(pub &'a [u8]);

impl Source for Bytes<'_> {
    fn len(&mut self) -> Result<usize, Failure> {
        Ok(self.0.len())
    }
    fn read_at(&mut self, offset: usize, buf: &mut [u8]) -> Result<(), Failure> {
        let end = offset
            .checked_add(buf.len())
            .ok_or(Failure::Episode("read past the end"))?;
        let src = self
            .0
            .get(offset..end)
            .ok_or(Failure::Episode("read past the end"))?;
        buf.copy_from_slice(src);
        Ok(())
    }
}

/// A parsed and CRC-checked episode header; the observations stay in the [`Source`].
#[derive(Clone, Debug)]
pub struct Episode {
    /// Seed for [`Navigator::reset`].
    pub seed: u64,
    steps: usize,
    label: [u8; LABEL_MAX],
    label_len: usize,
    attr: [f32; DIMS.attr],
    script_at: usize,
    obs_at: usize,
}

fn u16_at(b: &[u8], at: usize) -> u16 {
    u16::from_le_bytes([b[at], b[at + 1]])
}

/// The scale of the map's u8 codes: feature `v` is stored as `round(v * 255)`.
pub const MAP_SCALE: f32 = 1.0 / 255.0;

/// Bytes of one step's observations: the pooled vector and the map.
const STEP_BYTES: usize = (1 + DIMS.map_cells()) * DIMS.feat;

impl Episode {
    /// Reads, parses and checks an episode file for [`DIMS`] (header, lengths, CRC).
    pub fn parse(src: &mut dyn Source) -> Result<Self, Failure> {
        let len = src.len()?;
        let mut h = [0u8; HEADER_LEN];
        if len < HEADER_LEN {
            return Err(Failure::Episode("truncated header"));
        }
        src.read_at(0, &mut h)?;
        if h[..4] != MAGIC {
            return Err(Failure::Episode("bad magic"));
        }
        if u16_at(&h, 4) != VERSION {
            return Err(Failure::Episode("unsupported version"));
        }
        let n = u16_at(&h, 6) as usize;
        if u16_at(&h, 8) as usize != DIMS.feat || u16_at(&h, 10) as usize != DIMS.attr {
            return Err(Failure::Episode(
                "feature or attribute width differs from the model's",
            ));
        }
        if u16_at(&h, 20) as usize != DIMS.map_cells() {
            return Err(Failure::Episode(
                "map cells differ from the model's (3 x 3 = 9)",
            ));
        }
        let mut seed = [0u8; 8];
        seed.copy_from_slice(&h[12..20]);
        let label_len = u16_at(&h, 22) as usize;
        if label_len > LABEL_MAX {
            return Err(Failure::Episode("label longer than LABEL_MAX"));
        }
        let crc = u32::from_le_bytes([h[24], h[25], h[26], h[27]]);
        let body = label_len + 4 * DIMS.attr + n + n * STEP_BYTES;
        if len - HEADER_LEN != body {
            return Err(Failure::Episode("length does not match the header"));
        }
        // The CRC over the body, read a chunk at a time.
        let (mut at, mut c) = (HEADER_LEN, 0u32);
        let mut chunk = [0u8; CHUNK];
        while at < len {
            let m = CHUNK.min(len - at);
            src.read_at(at, &mut chunk[..m])?;
            c = crc32_update(c, &chunk[..m]);
            at += m;
        }
        if c != crc {
            return Err(Failure::Episode("CRC mismatch"));
        }
        let mut label = [0u8; LABEL_MAX];
        src.read_at(HEADER_LEN, &mut label[..label_len])?;
        core::str::from_utf8(&label[..label_len])
            .map_err(|_| Failure::Episode("label not UTF-8"))?;
        let attr_at = HEADER_LEN + label_len;
        let mut raw = [0u8; 4 * DIMS.attr];
        src.read_at(attr_at, &mut raw)?;
        let mut attr = [0.0f32; DIMS.attr];
        for (o, c) in attr.iter_mut().zip(raw.chunks_exact(4)) {
            *o = f32::from_le_bytes([c[0], c[1], c[2], c[3]]);
        }
        let script_at = attr_at + 4 * DIMS.attr;
        Ok(Episode {
            seed: u64::from_le_bytes(seed),
            steps: n,
            label,
            label_len,
            attr,
            script_at,
            obs_at: script_at + n,
        })
    }

    /// Number of steps.
    pub fn steps(&self) -> usize {
        self.steps
    }

    /// Human-readable description.
    pub fn label(&self) -> &str {
        core::str::from_utf8(&self.label[..self.label_len]).unwrap_or("?")
    }

    /// SE(y) of the target.
    pub fn attributes(&self) -> &[f32; DIMS.attr] {
        &self.attr
    }

    /// The observations of step `t` read from `src`: the pooled vector dequantised into
    /// `obs` (`feat` floats), the map as the file stores it into `map` (`map_len` u8 codes of
    /// scale [`MAP_SCALE`], what [`Navigator::step_map_u8`] takes, as from a camera).
    pub fn observation(
        &self,
        src: &mut dyn Source,
        t: usize,
        obs: &mut [f32],
        map: &mut [u8],
    ) -> Result<(), Failure> {
        if t >= self.steps {
            return Err(Failure::Episode("step out of range"));
        }
        let mut chunk = [0u8; CHUNK];
        let at = self.obs_at + t * STEP_BYTES;
        src.read_at(at, &mut chunk)?;
        for (o, &q) in obs.iter_mut().zip(&chunk) {
            *o = q as f32 / 255.0;
        }
        src.read_at(at + DIMS.feat, map)?;
        Ok(())
    }

    /// The action the recording script took at step `t`.
    pub fn scripted_action(&self, src: &mut dyn Source, t: usize) -> Option<Action> {
        let mut b = [0u8; 1];
        src.read_at(self.script_at + t, &mut b).ok()?;
        Action::from_index(b[0] as usize)
    }
}

/// Where [`run`] reports: result lines (identical on every target) and the step boundaries
/// (for the firmware's instruction counts, which differ by target and are not results).
pub trait Probe {
    /// One result line.
    fn line(&mut self, args: fmt::Arguments<'_>);
    /// Called right before and right after [`Navigator::reset`] (with zero noise it runs G
    /// and the fusion layer's constant terms).
    fn reset_begin(&mut self) {}
    /// See [`Probe::reset_begin`].
    fn reset_end(&mut self) {}
    /// Called right before [`Navigator::step`].
    fn step_begin(&mut self) {}
    /// Called right after [`Navigator::step`] returned; `adapted` is true when that step
    /// committed an inner update, `working` when it computed (part of) one.
    fn step_end(&mut self, _adapted: bool, _working: bool) {}
    /// An inner update took effect `steps` steps after the step that filled Ψ (1: in that
    /// step itself, a commit delay of 0).
    fn update_committed(&mut self, _steps: u32) {}
}

/// Runs the episode read from `src` with a `Navigator<Efficient, K>` over the [`DIMS`] blob
/// `blob_bytes`, all mutable state in `arena` (at least [`ARENA_LEN`] floats). Prints every
/// action, the action probabilities' and the value's bits, the counters after each step and
/// the diagnostics of each inner update; returns the final counters.
pub fn run(
    blob_bytes: &[u8],
    src: &mut dyn Source,
    arena: &mut [f32],
    probe: &mut dyn Probe,
) -> Result<Counters, Failure> {
    run_with::<true>(blob_bytes, src, arena, probe)
}

/// [`run`] with the map given to [`Navigator::step_map`] as f32 values (`code as f32 /
/// 255.0`), as a program on the C API does (`tests/tests/firmware_c_qemu.rs` compares its
/// lines with these).
#[allow(dead_code)]
pub fn run_f32_map(
    blob_bytes: &[u8],
    src: &mut dyn Source,
    arena: &mut [f32],
    probe: &mut dyn Probe,
) -> Result<Counters, Failure> {
    run_with::<false>(blob_bytes, src, arena, probe)
}

/// [`run`] (`U8`: the map as u8 codes, [`Navigator::step_map_u8`]) or [`run_f32_map`].
fn run_with<const U8: bool>(
    blob_bytes: &[u8],
    src: &mut dyn Source,
    arena: &mut [f32],
    probe: &mut dyn Probe,
) -> Result<Counters, Failure> {
    let ep = Episode::parse(src)?;
    let blob = Blob::parse(blob_bytes)?;
    let weights = NavWeights::from_blob(&blob, &DIMS)?;
    // The configuration the blob asks for (adaptation on or off, EMD, noise, α1, α2 and the
    // cap on inner updates; v1 blobs: the paper's rates and cap), never this program's own
    // defaults: the host evaluated the model with exactly these settings.
    let mut cfg = NavConfig::from_header(blob.header());
    let blob_delay = cfg.model.inner_rule.commit_delay;
    if blob_delay == 0 {
        cfg.model.inner_rule.commit_delay = COMMIT_DELAY;
    }
    cfg.footprint = FOOTPRINT;
    print_config(&ep, &blob, &cfg, blob_delay, probe);
    let mut nav: Navigator<'_, Efficient, K> = Navigator::new(weights, arena, cfg)?;
    probe.reset_begin();
    nav.reset(ep.attributes(), ep.seed)?;
    probe.reset_end();
    // G's output at z = 0 before any inner update, to show how far the updates move G
    // (Fig. 3 on the device): ‖G_θi(SE(y), 0) − G_θ(SE(y), 0)‖ after each update.
    let mut g0 = [0.0f32; DIMS.feat];
    nav.generator_output(&[0.0; DIMS.noise], &mut g0)?;
    probe.line(format_args!(
        "G(SE(y), 0) before adaptation: |x|={}",
        Fixed6(norm_from(&g0, None))
    ));
    let mut obs = [0.0f32; DIMS.feat];
    let mut map = [0u8; DIMS.map_len()];
    // The step whose Ψ filled, while its update is pending.
    let mut filled_at: Option<usize> = None;
    for t in 0..ep.steps() {
        ep.observation(src, t, &mut obs, &mut map)?;
        let working = nav.update_pending();
        probe.step_begin();
        let out = if U8 {
            nav.step_map_u8(&obs, &map, MAP_SCALE, &[])?
        } else {
            let mut mf = [0.0f32; DIMS.map_len()];
            for (o, &q) in mf.iter_mut().zip(&map) {
                *o = q as f32 / 255.0;
            }
            nav.step_map(&obs, &mf, &[])?
        };
        probe.step_end(out.adapted, working || out.adapted);
        if out.adapted {
            let after = filled_at.take().map_or(1, |f| (t - f) as u32);
            probe.update_committed(after);
            probe.line(format_args!(
                "  update committed {after} steps after Ψ filled"
            ));
        } else if nav.update_pending() && filled_at.is_none() {
            filled_at = Some(t);
        }
        let scripted = ep.scripted_action(src, t).map_or("?", Action::name);
        print_step(t, &out, nav.counters(), scripted, probe);
        if out.adapted {
            print_update(&mut nav, &g0, probe)?;
        }
    }
    let c = nav.counters();
    let x = nav.generated_feature();
    let x_sum = x.iter().fold(0u32, |a, v| a.wrapping_add(v.to_bits()));
    probe.line(format_args!(
        "done: steps={} adaptations={} rollbacks={} x_t bit-sum={:08x}",
        c.steps, c.adaptations, c.rollbacks, x_sum
    ));
    Ok(c)
}

/// The episode's and the navigator's configuration lines: what the blob asks for and what the
/// device runs.
fn print_config(
    ep: &Episode,
    blob: &Blob<'_>,
    cfg: &NavConfig,
    blob_delay: u32,
    probe: &mut dyn Probe,
) {
    probe.line(format_args!(
        "episode: {} ({} steps, seed {})",
        ep.label(),
        ep.steps(),
        ep.seed
    ));
    probe.line(format_args!(
        "navigator: Mcu, 3x3 map, Efficient, K=20, max_inner_updates={}",
        cfg.model.max_inner
    ));
    // Rates as f32 bits: exact, and no float formatting code in flash. The enums by the
    // names their `Debug` prints, without linking those impls (flash).
    probe.line(format_args!(
        "config from blob v{}: adapt={} emd={} noise={} alpha_disc={:08x} alpha_adapt={:08x}",
        blob.header().version() as u32,
        cfg.model.adapt as u32,
        match cfg.model.emd {
            Emd::Discriminator => "Discriminator",
            Emd::CosSim => "CosSim",
        },
        match cfg.model.noise {
            NoiseMode::Gaussian => "Gaussian",
            NoiseMode::Zero => "Zero",
        },
        cfg.model.alpha_disc().to_bits(),
        cfg.model.inner_lr.to_bits(),
    ));
    probe.line(format_args!(
        "schedule: {}, commit_delay={} (blob: {})",
        match cfg.schedule {
            Schedule::Auto => "Auto",
            Schedule::Manual => "Manual",
            Schedule::Background => "Background",
        },
        cfg.model.inner_rule.commit_delay,
        blob_delay
    ));
}

/// One step's line: the action, the probabilities' and the value's bits, the counters and the
/// recorded episode's action at `t`.
fn print_step(t: usize, out: &StepOutput, c: Counters, scripted: &str, probe: &mut dyn Probe) {
    let p = out.probs.map(f32::to_bits);
    probe.line(format_args!(
        "t={:02} {:<11} p=[{:08x} {:08x} {:08x} {:08x} {:08x} {:08x}] v={:08x} adapted={} adaptations={} rollbacks={} (script {})",
        t,
        out.action.name(),
        p[0],
        p[1],
        p[2],
        p[3],
        p[4],
        p[5],
        out.value.to_bits(),
        out.adapted as u32,
        c.adaptations,
        c.rollbacks,
        scripted,
    ));
}

/// The lines of an inner update that just took effect: its losses and how far it moved G.
fn print_update(
    nav: &mut Navigator<'_, Efficient, K>,
    g0: &[f32],
    probe: &mut dyn Probe,
) -> Result<(), Failure> {
    let r = nav.last_adaptation();
    probe.line(format_args!(
        "  inner update: L_D={:08x} E[D(s)]={:08x} E[D(x)]={:08x} penalty={:08x} L_ad={:08x} D applied={} G/actor applied={}",
        r.ld.loss.to_bits(),
        r.ld.mean_real.to_bits(),
        r.ld.mean_fake.to_bits(),
        r.ld.penalty.to_bits(),
        r.adapt_loss.to_bits(),
        r.disc_applied,
        r.adapt_applied,
    ));
    probe.line(format_args!(
        "  G(SE(y), 0) moved by {} since the episode began",
        Fixed6(g_moved(nav, g0)?)
    ));
    Ok(())
}

/// ‖G_θi(SE(y), 0) − g0‖ at the navigator's current θ (its own buffer, so the episode's
/// stack holds only `g0`).
#[inline(never)]
fn g_moved(nav: &mut Navigator<'_, Efficient, K>, g0: &[f32]) -> Result<f32, Failure> {
    let mut x = [0.0f32; DIMS.feat];
    nav.generator_output(&[0.0; DIMS.noise], &mut x)?;
    Ok(norm_from(&x, Some(g0)))
}

/// ‖a − b‖ (‖a‖ without `b`), summed in order: the same bits on every target.
fn norm_from(a: &[f32], b: Option<&[f32]>) -> f32 {
    let mut s = 0.0f32;
    for (i, &v) in a.iter().enumerate() {
        let d = v - b.map_or(0.0, |b| b[i]);
        s += d * d;
    }
    libm::sqrtf(s)
}

/// A non-negative value printed with six decimals, rounded down, from integers (no float
/// formatting code in flash).
struct Fixed6(f32);

impl fmt::Display for Fixed6 {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let m = (self.0 * 1.0e6) as u64;
        write!(f, "{}.{:06}", m / 1_000_000, m % 1_000_000)
    }
}
