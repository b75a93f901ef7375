//! The scripted navigation episode the firmware runs, shared verbatim with the host-side
//! parity test (`tests/tests/firmware_qemu.rs` includes this file with `#[path]`), so x86 and
//! the Cortex-M4F execute the same source on the same blob and the same observations and must
//! print the same bits.
//!
//! The observations are a replay: the feature vectors s_t of a known episode, recorded on the
//! host by `host-sim/examples/record_episode.rs` and embedded in flash. The navigator's actions
//! do not change what it sees next (a microcontroller cannot hold the scene), but everything
//! the navigator computes on the device — G, the policy, Ψ, the inner updates of Algorithm 1,
//! the rollback checks — runs exactly as it would in a closed loop.
//!
//! # Episode file (`firmware-example/data/episode.gmep`), all integers little-endian
//! ```text
//! offset  size        field
//!      0  4           magic "GMEP"
//!      4  2           version (1)
//!      6  2           n, number of steps
//!      8  2           feat, width of an observation (512)
//!     10  2           attr, width of SE(y) (45)
//!     12  8           seed passed to Navigator::reset
//!     20  2           L, length of the label
//!     22  4           CRC-32 (IEEE) of every byte from offset 26 to the end
//!     26  L           label, UTF-8 (scene, target, kind; for the log only)
//!    ...  4 attr      SE(y) of the target, f32
//!    ...  n           action the recording script took at each step (Action index; log only)
//!    ...  n feat      observations, u8: round(s * 255) of features s in [0, 1]
//! ```
//! Observations are stored as u8 because 40 steps of 512 f32 would be 80 KiB of flash, and
//! the simulator's features are in [0, 1] with ±0.02 noise, far coarser than 1/255. The
//! firmware and the host dequantise with the same expression (`b as f32 / 255.0`), so both
//! feed the navigator identical f32 bits.

use core::fmt;

use gman_core::blob::Blob;
use gman_core::crc32::crc32;
use gman_core::memory::{arena_len, AdaptMode};
use gman_core::navigator::{Counters, Efficient, NavConfig, NavWeights, Navigator};
use gman_core::{Action, Dims};

/// The model size the firmware runs.
pub const DIMS: Dims = Dims::MCU;
/// Capacity of the buffer Ψ: the paper's k = 20, so an inner update every 20 steps.
pub const K: usize = 20;
/// Floats of RAM the navigator needs ([`arena_len`] for `Mcu`, `Efficient`, [`K`]).
pub const ARENA_LEN: usize = arena_len(&DIMS, AdaptMode::Efficient, K);
/// Magic bytes of an episode file.
pub const MAGIC: [u8; 4] = *b"GMEP";
/// Version of the episode file format.
pub const VERSION: u16 = 1;
/// Bytes before the label.
pub const HEADER_LEN: usize = 26;

/// Why [`run`] stopped.
#[derive(Debug)]
pub enum Failure {
    /// The episode file is malformed.
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

/// A parsed episode file, borrowing from its bytes (no copy: the observations stay in flash).
#[derive(Clone, Copy, Debug)]
pub struct Episode<'a> {
    /// Seed for [`Navigator::reset`].
    pub seed: u64,
    /// Human-readable description.
    pub label: &'a str,
    attr: &'a [u8],
    script: &'a [u8],
    obs: &'a [u8],
}

fn u16_at(b: &[u8], at: usize) -> u16 {
    u16::from_le_bytes([b[at], b[at + 1]])
}

impl<'a> Episode<'a> {
    /// Parses and checks an episode file for [`DIMS`].
    pub fn parse(b: &'a [u8]) -> Result<Self, Failure> {
        if b.len() < HEADER_LEN || b[..4] != MAGIC {
            return Err(Failure::Episode("bad magic or truncated header"));
        }
        if u16_at(b, 4) != VERSION {
            return Err(Failure::Episode("unsupported version"));
        }
        let n = u16_at(b, 6) as usize;
        if u16_at(b, 8) as usize != DIMS.feat || u16_at(b, 10) as usize != DIMS.attr {
            return Err(Failure::Episode(
                "feature or attribute width differs from Mcu",
            ));
        }
        let mut seed = [0u8; 8];
        seed.copy_from_slice(&b[12..20]);
        let label_len = u16_at(b, 20) as usize;
        let crc = u32::from_le_bytes([b[22], b[23], b[24], b[25]]);
        let body = &b[HEADER_LEN..];
        if body.len() != label_len + 4 * DIMS.attr + n + n * DIMS.feat {
            return Err(Failure::Episode("length does not match the header"));
        }
        if crc32(body) != crc {
            return Err(Failure::Episode("CRC mismatch"));
        }
        let (label, rest) = body.split_at(label_len);
        let (attr, rest) = rest.split_at(4 * DIMS.attr);
        let (script, obs) = rest.split_at(n);
        Ok(Episode {
            seed: u64::from_le_bytes(seed),
            label: core::str::from_utf8(label).map_err(|_| Failure::Episode("label not UTF-8"))?,
            attr,
            script,
            obs,
        })
    }

    /// Number of steps.
    pub fn steps(&self) -> usize {
        self.script.len()
    }

    /// SE(y) of the target.
    pub fn attributes(&self, out: &mut [f32]) {
        for (o, c) in out.iter_mut().zip(self.attr.chunks_exact(4)) {
            *o = f32::from_le_bytes([c[0], c[1], c[2], c[3]]);
        }
    }

    /// The observation of step `t`, dequantised into `out` (`feat` floats).
    pub fn observation(&self, t: usize, out: &mut [f32]) {
        let f = DIMS.feat;
        for (o, &q) in out.iter_mut().zip(&self.obs[t * f..(t + 1) * f]) {
            *o = q as f32 / 255.0;
        }
    }

    /// The action the recording script took at step `t`.
    pub fn scripted_action(&self, t: usize) -> Option<Action> {
        Action::from_index(self.script[t] as usize)
    }
}

/// Where [`run`] reports: result lines (identical on every target) and the step boundaries
/// (for the firmware's instruction counts, which differ by target and are not results).
pub trait Probe {
    /// One result line.
    fn line(&mut self, args: fmt::Arguments<'_>);
    /// Called right before [`Navigator::step`].
    fn step_begin(&mut self) {}
    /// Called right after [`Navigator::step`] returned; `adapted` is true when that step ran
    /// an inner update.
    fn step_end(&mut self, _adapted: bool) {}
}

/// Runs the episode `episode_bytes` with a `Navigator<Efficient, K>` over the `Mcu` blob
/// `blob_bytes`, all mutable state in `arena` (at least [`ARENA_LEN`] floats). Prints every
/// action, the action probabilities' and the value's bits, the counters after each step and
/// the diagnostics of each inner update; returns the final counters.
pub fn run(
    blob_bytes: &[u8],
    episode_bytes: &[u8],
    arena: &mut [f32],
    probe: &mut dyn Probe,
) -> Result<Counters, Failure> {
    let ep = Episode::parse(episode_bytes)?;
    let blob = Blob::parse(blob_bytes)?;
    let weights = NavWeights::from_blob(&blob, &DIMS)?;
    // The configuration the blob asks for (adaptation on or off, EMD, noise, α1, α2 and the
    // cap on inner updates; v1 blobs: the paper's rates and cap), never this program's own
    // defaults: the host evaluated the model with exactly these settings.
    let cfg = NavConfig::from_header(blob.header());
    probe.line(format_args!(
        "episode: {} ({} steps, seed {})",
        ep.label,
        ep.steps(),
        ep.seed
    ));
    probe.line(format_args!(
        "navigator: Mcu, Efficient, K={}, max_inner_updates={}, arena {} floats",
        K, cfg.max_inner_updates, ARENA_LEN
    ));
    // Rates as f32 bits: exact, and no float formatting code in flash.
    probe.line(format_args!(
        "config from blob v{}: adapt={} emd={:?} noise={:?} alpha_disc={:08x} alpha_adapt={:08x}",
        blob.header().version(),
        cfg.adapt as u8,
        cfg.emd,
        cfg.noise,
        cfg.alpha_disc.to_bits(),
        cfg.alpha_adapt.to_bits(),
    ));
    let mut nav: Navigator<'_, Efficient, K> = Navigator::new(weights, arena, cfg)?;
    let mut attr = [0.0f32; DIMS.attr];
    ep.attributes(&mut attr);
    nav.reset(&attr, ep.seed)?;
    // G's output at z = 0 before any inner update, to show how far the updates move G
    // (Fig. 3 on the device): ‖G_θi(SE(y), 0) − G_θ(SE(y), 0)‖ after each update.
    let mut g0 = [0.0f32; DIMS.feat];
    nav.generator_output(&[0.0; DIMS.noise], &mut g0)?;
    probe.line(format_args!(
        "G(SE(y), 0) before adaptation: |x|={}",
        Fixed6(norm_from(&g0, None))
    ));
    let mut obs = [0.0f32; DIMS.feat];
    for t in 0..ep.steps() {
        ep.observation(t, &mut obs);
        probe.step_begin();
        let out = nav.step(&obs, &[])?;
        probe.step_end(out.adapted);
        let c = nav.counters();
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
            out.adapted as u8,
            c.adaptations,
            c.rollbacks,
            ep.scripted_action(t).map_or("?", Action::name),
        ));
        if out.adapted {
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
                Fixed6(g_moved(&mut nav, &g0)?)
            ));
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
