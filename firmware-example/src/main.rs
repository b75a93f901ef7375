//! gman-rs firmware example for a Cortex-M4F (QEMU `mps2-an386`): the GMAN navigator on a
//! scripted episode, measured.
//!
//! 1. Paints the stack (for the peak-stack measurement) and starts SysTick as an instruction
//!    counter (see [`measure`]).
//! 2. With the feature `selftest`, runs the kernel self-test (`selftest.rs`): G, D and one
//!    gradient of L_D straight from the embedded `Mcu` int8 blob.
//! 3. Runs the navigator ([`episode`]): a `Navigator<Efficient, 20>` over the same blob (read in
//!    place from flash) and a statically sized arena, `reset` with the recorded target's
//!    attributes, then `step_map_u8` on each of the 40 observations (pooled vector and 3 x 3 map
//!    of u8 codes)
//!    of an episode recorded by the host simulator (`data/episode.gmep`, read from the host
//!    through semihosting step by step, as a robot reads its camera); two inner updates of
//!    Algorithm 1 happen, at steps 20 and 40. Every action, the probabilities' bits and the
//!    counters are printed.
//! 4. Prints the measurements as lines starting with `# ` (instructions per step and per
//!    inner update, flash, static RAM, peak stack), which differ by target and are therefore
//!    not compared with the host.
//!
//! Output goes through semihosting; QEMU exits with success, or with failure on any error,
//! panic or fault, so a test can trust the exit code. Run it with `-icount shift=0` for
//! meaningful instruction counts (`cargo run --release` does, see `.cargo/config.toml`).
#![no_std]
#![no_main]

use cortex_m_rt::{entry, exception, ExceptionFrame};
use cortex_m_semihosting::{debug, hprintln, syscall};
#[cfg(feature = "panic-messages")]
use panic_semihosting as _;

mod episode;
mod measure;
#[cfg(feature = "selftest")]
mod selftest;

use episode::{Failure, Probe, Source, ARENA_LEN};
use measure::{Clock, Stats, INSNS_PER_TICK};

/// The int8 weight blob (`build.rs`: the shipped trained model, seeded, or
/// `GMAN_FIRMWARE_BLOB`).
static BLOB: &[u8] = include_bytes!(concat!(env!("OUT_DIR"), "/model.gman"));
/// The recorded episode (`host-sim/examples/record_episode.rs`), opened on the host relative
/// to QEMU's working directory (NUL-terminated for the semihosting call).
const EPISODE_PATH: &str = "data/episode.gmep\0";

/// The episode file on the host, read through semihosting (`SYS_OPEN`, `SYS_SEEK`,
/// `SYS_READ`; QEMU needs `-semihosting-config enable=on,target=native`). Closed on drop.
struct HostFile {
    fd: usize,
}

impl HostFile {
    fn open(path: &str) -> Result<Self, Failure> {
        // SYS_OPEN: name, mode ("rb"), length without the NUL.
        // SAFETY: `path` is a live NUL-terminated string (EPISODE_PATH) and the length passed
        // excludes the NUL; the host only reads it during the call.
        let fd = unsafe {
            syscall!(
                OPEN,
                path.as_ptr(),
                cortex_m_semihosting::nr::open::R_BINARY,
                path.len() - 1
            )
        } as isize;
        if fd < 0 {
            return Err(Failure::Episode(
                "cannot open data/episode.gmep on the host (semihosting; run QEMU in firmware-example/)",
            ));
        }
        Ok(HostFile { fd: fd as usize })
    }
}

impl Source for HostFile {
    fn len(&mut self) -> Result<usize, Failure> {
        // SAFETY: FLEN takes a handle this value owns (opened by `open`, closed on drop) and
        // touches no memory of ours.
        let n = unsafe { syscall!(FLEN, self.fd) } as isize;
        usize::try_from(n).map_err(|_| Failure::Episode("semihosting FLEN failed"))
    }
    fn read_at(&mut self, offset: usize, buf: &mut [u8]) -> Result<(), Failure> {
        // SAFETY: SEEK takes our open handle and an offset; it touches no memory of ours.
        if unsafe { syscall!(SEEK, self.fd, offset) } != 0 {
            return Err(Failure::Episode("semihosting SEEK failed"));
        }
        // SYS_READ returns the number of bytes it did *not* read.
        // SAFETY: the host writes at most `buf.len()` bytes into `buf`, a live exclusive
        // borrow for the whole call; the handle is ours and open.
        if unsafe { syscall!(READ, self.fd, buf.as_mut_ptr(), buf.len()) } != 0 {
            return Err(Failure::Episode("read past the end (semihosting READ)"));
        }
        Ok(())
    }
}

impl Drop for HostFile {
    fn drop(&mut self) {
        // SAFETY: the handle is ours, open, and never used again after this call.
        unsafe { syscall!(CLOSE, self.fd) };
    }
}

/// Clock rate for the "implied time" lines: an STM32F4-class Cortex-M4F.
const CPU_HZ: u64 = 168_000_000;

#[entry]
fn main() -> ! {
    measure::paint_stack();
    let code = match run() {
        Ok(()) => {
            hprintln!("OK");
            debug::EXIT_SUCCESS
        }
        Err(e) => {
            hprintln!("ERROR: {}", e);
            debug::EXIT_FAILURE
        }
    };
    debug::exit(code);
    loop {
        cortex_m::asm::wfi();
    }
}

/// The control loop's rate: a step is released every `CPU_HZ / RATE_HZ` cycles.
const RATE_HZ: u64 = 25;
/// The period in SysTick ticks (at 1 instruction per cycle).
const PERIOD_TICKS: u32 = (CPU_HZ / RATE_HZ / INSNS_PER_TICK as u64) as u32;

/// The firmware's [`Probe`]: prints result lines, releases each `step()` at a fixed rate
/// ([`RATE_HZ`], a busy-waiting main-loop cadence on SysTick: one task, so no locking, and the
/// inner update's slices run inside the steps, each bounded) and times it.
struct Device<'c> {
    clock: &'c Clock,
    /// SysTick at the current step's release (`None` before the first step).
    release: Option<u32>,
    t0: u32,
    plain: Stats,
    update: Stats,
    all: Stats,
    /// Smallest slack before the next release, in ticks, and the steps that missed it.
    min_slack: u32,
    misses: u32,
    commit_steps: u32,
    /// SysTick ticks of the episode's `reset`.
    reset_ticks: u32,
}

impl Probe for Device<'_> {
    fn line(&mut self, args: core::fmt::Arguments<'_>) {
        hprintln!("{}", args);
    }
    fn reset_begin(&mut self) {
        self.t0 = self.clock.now();
    }
    fn reset_end(&mut self) {
        self.reset_ticks = self.clock.ticks_since(self.t0);
    }
    fn step_begin(&mut self) {
        // Wait for the release time: one period after the previous release.
        let r = match self.release {
            Some(prev) => {
                while self.clock.ticks_since(prev) < PERIOD_TICKS {}
                prev.wrapping_sub(PERIOD_TICKS) & 0x00FF_FFFF
            }
            None => self.clock.now(),
        };
        self.release = Some(r);
        self.t0 = self.clock.now();
    }
    fn step_end(&mut self, _adapted: bool, working: bool) {
        let dt = self.clock.ticks_since(self.t0);
        self.all.add(dt);
        if working {
            self.update.add(dt)
        } else {
            self.plain.add(dt)
        }
        // Time left before the next release (a late step counts as a miss).
        let used = self.release.map_or(dt, |r| self.clock.ticks_since(r));
        match PERIOD_TICKS.checked_sub(used) {
            Some(slack) => self.min_slack = self.min_slack.min(slack),
            None => {
                self.misses += 1;
                self.min_slack = 0;
            }
        }
    }
    fn update_committed(&mut self, steps: u32) {
        self.commit_steps = self.commit_steps.max(steps);
    }
}

/// The navigator's arena: a `static` (in `.bss`) by default, or on `main`'s stack with the
/// `stack-arena` feature; both measured in README.md.
#[cfg(not(feature = "stack-arena"))]
fn with_arena<R>(f: impl FnOnce(&mut [f32]) -> R) -> Option<R> {
    let arena: &'static mut [f32; ARENA_LEN] =
        cortex_m::singleton!(: [f32; ARENA_LEN] = [0.0; ARENA_LEN])?;
    Some(f(arena))
}

#[cfg(feature = "stack-arena")]
fn with_arena<R>(f: impl FnOnce(&mut [f32]) -> R) -> Option<R> {
    let mut arena = [0.0f32; ARENA_LEN];
    Some(f(&mut arena))
}

/// The kernel self-test (feature `selftest`). Not inlined, so its stack frame is gone before
/// the navigator runs and the two peaks are measured separately.
/// Its sample buffers live in the navigator's arena, which is not in use yet.
#[cfg(feature = "selftest")]
#[inline(never)]
fn selftest_phase(arena: &mut [f32]) -> Result<(), Failure> {
    Ok(selftest::run(BLOB, arena, &mut |line| {
        hprintln!("{}", line)
    })?)
}

/// Without the feature `selftest` the image goes straight to the navigator.
#[cfg(not(feature = "selftest"))]
fn selftest_phase(_arena: &mut [f32]) -> Result<(), Failure> {
    Ok(())
}

/// The scripted navigator episode (not inlined, for the same reason).
#[inline(never)]
fn navigator_phase(dev: &mut Device<'_>, arena: &mut [f32]) -> Result<u32, Failure> {
    let mut file = HostFile::open(EPISODE_PATH)?;
    let c = episode::run(BLOB, &mut file, arena, dev)?;
    Ok(c.adaptations)
}

/// Instructions of each weight layer of a step, one `matvec_acc` at a time on the blob's own
/// matrices (as the navigator views them: int8 activations when the blob says so) with
/// inputs of the step's shapes and signs (observations, map and G's output non-negative;
/// noise, hidden layers and LSTM state signed), and of two f32 parts (G's output sigmoid,
/// the noise draw). Printed as a `# kernel:` line; the step minus the layers is everything
/// else (activations, element-wise products, input checks, Ψ bookkeeping). Feature
/// `kernel-table` (about 10 KB of flash, so not in the images the budget is measured on).
#[cfg(feature = "kernel-table")]
#[inline(never)]
fn kernel_phase(clock: &Clock) -> Result<(), Failure> {
    use gman_core::blob::{Blob, TensorId};
    use gman_core::spec::schema::FLAG_INT8_ACTIVATIONS;
    const D: gman_core::Dims = episode::DIMS;
    let blob = Blob::parse(BLOB)?;
    let act8 = blob.header().flags() & FLAG_INT8_ACTIVATIONS != 0;
    let m = |id: TensorId| -> Result<gman_core::nn::matrix::MatRef<'_>, Failure> {
        let w = blob.matrix(id)?;
        Ok(if act8 { w.with_int8_activations() } else { w })
    };
    let pos = |i: usize| ((i * 37) % 101) as f32 / 101.0;
    let sgn = |i: usize| ((i * 53) % 97) as f32 / 48.5 - 1.0;
    let obs: [f32; D.feat] = core::array::from_fn(pos);
    let x: [f32; D.feat] = core::array::from_fn(|i| pos(i + 7));
    let prod: [f32; D.feat] = core::array::from_fn(|i| obs[i] * x[i]);
    let z: [f32; D.noise] = core::array::from_fn(sgn);
    let attr: [f32; D.attr] = core::array::from_fn(pos);
    let h1: [f32; D.gen_hidden] = core::array::from_fn(sgn);
    let probs = [1.0 / 6.0f32; gman_core::NUM_ACTIONS];
    let cells: [f32; 72] = core::array::from_fn(sgn);
    let small: [f32; D.embed] = core::array::from_fn(sgn);
    let h: [f32; D.lstm_hidden] = core::array::from_fn(|i| sgn(i + 3));
    let mut y = [0.0f32; 4 * D.lstm_hidden];
    let mut yf = [0.0f32; D.feat];
    let mut cell_prod = [0.0f32; D.feat];
    let time = |f: &mut dyn FnMut() -> gman_core::Result<()>| -> Result<u64, Failure> {
        let t0 = clock.now();
        f()?;
        Ok(clock.ticks_since(t0) as u64 * INSNS_PER_TICK as u64)
    };
    let (g1w, g2w, cw, fw) = (
        m(TensorId::GenW1)?,
        m(TensorId::GenW2)?,
        m(TensorId::CellW)?,
        m(TensorId::FuseW)?,
    );
    let (lx, lh, aw, crw) = (
        m(TensorId::LstmWx)?,
        m(TensorId::LstmWh)?,
        m(TensorId::ActorW)?,
        m(TensorId::CriticW)?,
    );
    let g1 = time(&mut || mv(&g1w, &[&z, &attr], &mut y[..D.gen_hidden]))?;
    let g2 = time(&mut || mv(&g2w, &[&h1], &mut yf))?;
    // The map layer: on int8 activations the integer path's own form over all cells
    // (`qkernel::cell_layer_int8`, the product of the quantised factors), else one product
    // per cell as the f32 path runs it.
    let map: [f32; D.map_len()] = core::array::from_fn(|i| pos(i + i / D.feat));
    let mut yc = [0.0f32; 72];
    let cell = time(&mut || {
        if act8 && gman_core::nn::qkernel::INT8_ACTIVATIONS {
            return gman_core::nn::qkernel::cell_layer_int8(&cw, &map, &x, &mut yc);
        }
        for mc in map.chunks_exact(D.feat) {
            for (p, (&a, &b)) in cell_prod.iter_mut().zip(mc.iter().zip(&x)) {
                *p = a * b;
            }
            mv(&cw, &[mc, &cell_prod], &mut y[..D.cell_embed])?;
        }
        Ok(())
    })?;
    let fuse = time(&mut || {
        mv(
            &fw,
            &[&obs, &x, &prod, &attr, &probs, &cells],
            &mut y[..D.embed],
        )
    })?;
    let lstm = time(&mut || {
        mv(&lx, &[&small], &mut y)?;
        mv(&lh, &[&h], &mut y)
    })?;
    let heads = time(&mut || {
        mv(&aw, &[&h], &mut y[..gman_core::NUM_ACTIONS])?;
        mv(&crw, &[&h], &mut y[..1])
    })?;
    let sig = time(&mut || {
        let f: fn(&mut [f32]) = core::hint::black_box(gman_core::nn::activation::sigmoid_inplace);
        f(&mut yf);
        Ok(())
    })?;
    let mut rng = gman_core::rng::Xoshiro128::seed_from_u64(1);
    let mut zn = [0.0f32; D.noise];
    let noise = time(&mut || {
        type Fill = fn(&mut gman_core::rng::Xoshiro128, &mut [f32]);
        let f: Fill =
            core::hint::black_box(gman_core::rng::fill_gaussian::<gman_core::rng::Xoshiro128>);
        f(&mut rng, &mut zn);
        Ok(())
    })?;
    hprintln!(
        "# kernel: g1_insns={} g2_insns={} cells_insns={} fuse_insns={} lstm_insns={} heads_insns={} layers_insns={} sigmoid512_insns={} noise_insns={}",
        g1, g2, cell, fuse, lstm, heads, g1 + g2 + cell + fuse + lstm + heads, sig, noise
    );
    Ok(())
}

/// One `matvec_acc`, not inlined: one copy of the kernels' dispatch for every layer timed.
#[cfg(feature = "kernel-table")]
#[inline(never)]
fn mv(w: &gman_core::nn::matrix::MatRef<'_>, x: &[&[f32]], y: &mut [f32]) -> gman_core::Result<()> {
    w.matvec_acc(x, y)
}

/// Whether the blob runs the integer path (a flagged blob on an image without it is refused
/// before the episode). Not inlined and called after the stack is measured, so the parsed
/// blob is in no frame that is live during the episode.
#[inline(never)]
fn blob_int8_activations() -> Result<bool, Failure> {
    let b = gman_core::blob::Blob::parse(BLOB)?;
    Ok(b.header().flags() & gman_core::spec::schema::FLAG_INT8_ACTIVATIONS != 0)
}

const STACK_SATURATED: Failure =
    Failure::Episode("stack reached the bottom of the painted window (measure::STACK_WINDOW)");

fn run() -> Result<(), Failure> {
    let cp = cortex_m::Peripherals::take().ok_or(Failure::Episode("peripherals taken"))?;
    let clock = Clock::start(cp.SYST);
    let calib = measure::calibrate(&clock);
    hprintln!(
        "# calibration: calib_insns={} calib_ticks={} (expected {} instructions per tick)",
        measure::CALIBRATION_INSNS,
        calib,
        INSNS_PER_TICK
    );

    hprintln!(
        "# int8 kernel: dsp_smlad={} (1: SXTB16 + SMLAD, gman-dsp)",
        gman_core::nn::qkernel::DSP_KERNEL as u32
    );

    let mut dev = Device {
        clock: &clock,
        release: None,
        t0: 0,
        plain: Stats::EMPTY,
        update: Stats::EMPTY,
        all: Stats::EMPTY,
        min_slack: u32::MAX,
        misses: 0,
        commit_steps: 0,
        reset_ticks: 0,
    };
    let (stack_selftest, updates) = with_arena(|arena| -> Result<(usize, u32), Failure> {
        selftest_phase(arena)?;
        // Peak stack of the start-up and the self-test, then paint again so the navigator's
        // own peak is measured separately.
        let stack_selftest = measure::stack_peak().ok_or(STACK_SATURATED)?;
        measure::paint_stack();
        Ok((stack_selftest, navigator_phase(&mut dev, arena)?))
    })
    .ok_or(Failure::Episode("arena already taken"))??;
    // The kernel table's input arrays (the whole map among them) are no part of the
    // navigator's stack: its peak is taken before them.
    #[cfg(feature = "kernel-table")]
    let stack_before_table = measure::stack_peak().ok_or(STACK_SATURATED)?;
    #[cfg(feature = "kernel-table")]
    kernel_phase(&clock)?;

    print_step_lines(&dev, updates);
    #[cfg(not(feature = "kernel-table"))]
    let stack_navigator = measure::stack_peak().ok_or(STACK_SATURATED)?;
    #[cfg(feature = "kernel-table")]
    let stack_navigator = stack_before_table;
    print_budget_lines(&dev, stack_selftest, stack_navigator)
}

/// The `# step ...`, `# reset`, `# inner update alone` and `# at ... MHz` lines of the
/// episode's steps (`updates`: the inner updates it committed).
fn print_step_lines(dev: &Device<'_>, updates: u32) {
    let (p, u) = (dev.plain, dev.update);
    let tick = INSNS_PER_TICK as u64;
    hprintln!(
        "# step without inner update: steps={} min_insns={} mean_insns={} max_insns={}",
        p.n,
        p.min as u64 * tick,
        p.mean_insns(),
        p.max as u64 * tick
    );
    hprintln!(
        "# step with inner update: steps={} min_insns={} mean_insns={} max_insns={}",
        u.n,
        u.min as u64 * tick,
        u.mean_insns(),
        u.max as u64 * tick
    );
    hprintln!(
        "# reset (before the first step): reset_insns={}",
        dev.reset_ticks as u64 * tick
    );
    // What the steps that computed an update took beyond plain steps, per update.
    let update_alone =
        (u.sum * tick).saturating_sub(u.n as u64 * p.mean_insns()) / updates.max(1) as u64;
    hprintln!(
        "# inner update alone (update steps - plain steps, per update): update_insns={}",
        update_alone
    );
    hprintln!(
        "# at {} MHz and 1 instruction per cycle: step {} us, step with update {} us, update {} us",
        CPU_HZ / 1_000_000,
        p.mean_insns() * 1_000_000 / CPU_HZ,
        u.mean_insns() * 1_000_000 / CPU_HZ,
        update_alone * 1_000_000 / CPU_HZ
    );
}

/// The `# model`, `# cadence`, `# budget`, `# stack` and `# memory` lines, from the episode's
/// measurements and the peak stack of the self-test and of the navigator.
fn print_budget_lines(
    dev: &Device<'_>,
    stack_selftest: usize,
    stack_navigator: usize,
) -> Result<(), Failure> {
    let all = dev.all;
    let tick = INSNS_PER_TICK as u64;
    let act8 = blob_int8_activations()?;
    hprintln!(
        "# model: macs_per_step={} map_cells={} int8_activations={}",
        episode::DIMS.macs_per_step(),
        episode::DIMS.map_cells(),
        act8 as u32
    );
    let stack = stack_selftest.max(stack_navigator);
    let (flash, stat) = (measure::flash_bytes(), measure::static_ram_bytes());
    hprintln!(
        "# cadence: rate_hz={} period_insns={} min_slack_insns={} deadline_misses={}",
        RATE_HZ,
        PERIOD_TICKS as u64 * tick,
        dev.min_slack as u64 * tick,
        dev.misses
    );
    hprintln!(
        "# budget: step_mean_insns={} step_max_insns={} update_commit_steps={} flash_bytes={} ram_bytes={}",
        all.mean_insns(),
        all.max as u64 * tick,
        dev.commit_steps,
        flash,
        stat + stack
    );
    hprintln!(
        "# stack: selftest_stack_bytes={} navigator_stack_bytes={}",
        stack_selftest,
        stack_navigator
    );
    hprintln!(
        "# memory: flash_bytes={} static_ram_bytes={} peak_stack_bytes={} ram_bytes={} arena_bytes={} blob_bytes={}",
        flash,
        stat,
        stack,
        stat + stack,
        ARENA_LEN * 4,
        BLOB.len()
    );
    Ok(())
}

/// A panic prints a fixed line and exits QEMU with failure. The [`core::panic::PanicInfo`] is
/// not looked at, so no panic message or location is formatted or kept in flash (feature
/// `panic-messages` prints them).
#[cfg(not(feature = "panic-messages"))]
#[panic_handler]
fn panic(_: &core::panic::PanicInfo<'_>) -> ! {
    hprintln!("panic");
    debug::exit(debug::EXIT_FAILURE);
    loop {
        cortex_m::asm::wfi();
    }
}

#[exception]
unsafe fn HardFault(_ef: &ExceptionFrame) -> ! {
    hprintln!("HardFault");
    debug::exit(debug::EXIT_FAILURE);
    loop {
        cortex_m::asm::wfi();
    }
}
