//! `gman bench`: single-thread latency of the on-device navigator (`step()` and one inner
//! update on k = 20 buffered steps) for the `mcu` and `paper` presets, f32 and int8 weights,
//! `Full` and `Efficient` adaptation, next to this machine's limits measured in the same run
//! (a STREAM-like copy bandwidth, a read bandwidth and a peak multiply-add loop), plus the
//! training throughput of `gman train` (see `bench_train`) and the firmware's QEMU
//! instruction counts (quoted from `firmware-example/README.md`).
//!
//! Timing uses `std::time::Instant` and medians over repetitions; nothing here is a test.
//! The methods and a recorded run are in `host-sim/BENCHMARKS.md`.

use std::hint::black_box;
use std::path::PathBuf;
use std::time::Instant;

use anyhow::{anyhow, Context, Result};
use clap::{Args, ValueEnum};
use gman_core::blob::{Blob, TensorId};
use gman_core::matrix::MatRef;
use gman_core::navigator::{Efficient, Full, Mode, NavConfig, NavWeights, Navigator};
use gman_core::quant::quantize_rows;
use gman_core::rng::{fill_gaussian, uniform, Xoshiro128};
use gman_core::Dims;
use serde_json::{json, Value};

use crate::cli::PresetArg;

/// Buffer size of the inner update (the paper's k).
const K: usize = 20;

/// Firmware figures from `firmware-example/README.md` (QEMU `mps2-an386`, `-icount shift=0`,
/// `Mcu` preset, int8 weights in flash, `Efficient` mode); not re-measured by this command.
const FW_STEP_INSTR: f64 = 1_787_926.0;
const FW_ADAPT_INSTR: f64 = 108_888_800.0;
const FW_MHZ: f64 = 168.0;

/// `gman bench`.
#[derive(Debug, Args)]
pub struct BenchArgs {
    /// Presets to measure (repeat the flag; default: mcu and paper).
    #[arg(long, value_enum)]
    pub preset: Vec<PresetArg>,
    /// Weight storage to measure (repeat; default: f32 and int8).
    #[arg(long, value_enum)]
    pub quant: Vec<QuantArg>,
    /// Repetitions per timing (the median is reported).
    #[arg(long, default_value_t = 15)]
    pub reps: usize,
    /// Size of each array of the STREAM-like copy (MiB; source and destination each).
    #[arg(long, default_value_t = 256)]
    pub stream_mib: usize,
    /// Updates per training-throughput run (0: skip the training rows).
    #[arg(long, default_value_t = 150)]
    pub train_updates: u64,
    /// Also write every number as JSON to this file (`-` for stdout, then no table).
    #[arg(long, value_name = "OUT")]
    pub json: Option<PathBuf>,
}

/// Weight storage of the blob.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum QuantArg {
    /// f32 weights.
    F32,
    /// int8 weights with per-row scales.
    Int8,
}

impl QuantArg {
    fn name(self) -> &'static str {
        match self {
            QuantArg::F32 => "f32",
            QuantArg::Int8 => "int8",
        }
    }
}

/// Smallest value of a sample: the estimate of a machine limit (other jobs on the machine
/// can only slow a limit loop down).
fn best(v: &[f64]) -> f64 {
    v.iter().copied().fold(f64::INFINITY, f64::min)
}

/// Median of a non-empty sample (the upper middle for even lengths).
fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(|a, b| a.total_cmp(b));
    v.get(v.len() / 2).copied().unwrap_or(f64::NAN)
}

// ---------------------------------------------------------------- machine limits

/// Machine limits, measured in this run on one thread (best of the repetitions).
struct Limits {
    /// STREAM-like copy of two `stream_mib` arrays: (bytes read + written) / s.
    copy_gbs: f64,
    /// Read-only bandwidth over a `stream_mib` array (DRAM).
    read_gbs: f64,
    /// Read-only bandwidth over an 8 MiB array (L3-resident on this machine).
    read_l3_gbs: f64,
    /// Peak of separate f32 multiply and add (the instructions this build's kernels can use:
    /// baseline x86-64 = SSE2, 4 lanes, no FMA), GFLOP/s.
    peak_muladd_gflops: f64,
    /// Peak of separate f32 multiply and add with AVX2 (8 lanes, no FMA): the limit of the
    /// AVX2 build of the kernels (`gman_host_sim::simd`), GFLOP/s.
    peak_muladd_avx2_gflops: Option<f64>,
    /// Peak of fused multiply-add with AVX2+FMA when the CPU has it (the machine's limit for
    /// f32; AVX-512 on Zen 4 has the same FLOP/cycle), GFLOP/s.
    peak_fma_gflops: Option<f64>,
}

fn copy_bandwidth(mib: usize, reps: usize) -> f64 {
    let n = mib * (1 << 20) / 4;
    let src: Vec<f32> = (0..n).map(|i| i as f32).collect();
    let mut dst = vec![0.0f32; n];
    dst.copy_from_slice(&src); // fault in the pages first
    let times: Vec<f64> = (0..reps.max(3))
        .map(|_| {
            let t0 = Instant::now();
            dst.copy_from_slice(black_box(&src));
            black_box(&mut dst);
            t0.elapsed().as_secs_f64()
        })
        .collect();
    2.0 * (n * 4) as f64 / best(&times) / 1e9
}

fn read_bandwidth(bytes: usize, reps: usize) -> f64 {
    let n = bytes / 8;
    let v: Vec<u64> = (0..n as u64).collect();
    let sum = |v: &[u64]| {
        let mut acc = [0u64; 8];
        for c in v.chunks_exact(8) {
            for k in 0..8 {
                acc[k] = acc[k].wrapping_add(c[k]);
            }
        }
        acc.iter().fold(0u64, |a, &b| a.wrapping_add(b))
    };
    black_box(sum(&v));
    // Small arrays: repeat inside one timing so each sample is at least ~5 ms.
    let inner = (64 << 20) / bytes.max(1) + 1;
    let times: Vec<f64> = (0..reps.max(3))
        .map(|_| {
            let t0 = Instant::now();
            for _ in 0..inner {
                black_box(sum(black_box(&v)));
            }
            t0.elapsed().as_secs_f64() / inner as f64
        })
        .collect();
    (n * 8) as f64 / best(&times) / 1e9
}

/// Chains of `acc = acc * a + b` in SSE registers with a separate multiply and add (what a
/// baseline x86-64 build, and so gman-core's kernels, can use: SSE2, 4 lanes, no FMA):
/// 12 independent 4-lane chains, enough to cover the add and multiply latencies.
#[cfg(target_arch = "x86_64")]
#[inline(never)]
fn muladd_loop(iters: usize, a: f32, b: f32) -> f32 {
    use std::arch::x86_64::{_mm_add_ps, _mm_cvtss_f32, _mm_mul_ps, _mm_set1_ps};
    // SAFETY: SSE2 is part of the x86-64 baseline, so these intrinsics are always available.
    unsafe {
        let (va, vb) = (_mm_set1_ps(a), _mm_set1_ps(b));
        let mut acc = [_mm_set1_ps(0.5); 12];
        for _ in 0..iters {
            for v in acc.iter_mut() {
                *v = _mm_add_ps(_mm_mul_ps(*v, va), vb);
            }
        }
        acc.iter().map(|&v| _mm_cvtss_f32(v)).sum()
    }
}

/// Portable fallback: 48 scalar chains.
#[cfg(not(target_arch = "x86_64"))]
#[inline(never)]
fn muladd_loop(iters: usize, a: f32, b: f32) -> f32 {
    let mut acc = [0.5f32; 48];
    for _ in 0..iters {
        for v in acc.iter_mut() {
            *v = *v * a + b;
        }
    }
    acc.iter().sum()
}

/// 12 independent chains of 8-lane `acc = acc * a + b` with a separate multiply and add in
/// AVX2 registers (what the AVX2 build of gman-core's kernels can use).
///
/// # Safety
/// The CPU must support AVX2.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn muladd_loop_avx2(iters: usize, a: f32, b: f32) -> f32 {
    use std::arch::x86_64::{
        _mm256_add_ps, _mm256_castps256_ps128, _mm256_mul_ps, _mm256_set1_ps, _mm_cvtss_f32,
    };
    let (va, vb) = (_mm256_set1_ps(a), _mm256_set1_ps(b));
    let mut acc = [_mm256_set1_ps(0.5); 12];
    for _ in 0..iters {
        for v in acc.iter_mut() {
            *v = _mm256_add_ps(_mm256_mul_ps(*v, va), vb);
        }
    }
    acc.iter()
        .map(|&v| _mm_cvtss_f32(_mm256_castps256_ps128(v)))
        .sum()
}

/// 10 independent chains of 8-lane fused `acc = acc * a + b` in AVX2 registers (FMA latency 4
/// cycles, 2 per cycle: 8 chains suffice).
///
/// # Safety
/// The CPU must support AVX2 and FMA.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
unsafe fn fma_loop_avx2(iters: usize, a: f32, b: f32) -> f32 {
    use std::arch::x86_64::{
        _mm256_castps256_ps128, _mm256_fmadd_ps, _mm256_set1_ps, _mm_cvtss_f32,
    };
    let (va, vb) = (_mm256_set1_ps(a), _mm256_set1_ps(b));
    let mut acc = [_mm256_set1_ps(0.5); 10];
    for _ in 0..iters {
        for v in acc.iter_mut() {
            *v = _mm256_fmadd_ps(*v, va, vb);
        }
    }
    acc.iter()
        .map(|&v| _mm_cvtss_f32(_mm256_castps256_ps128(v)))
        .sum()
}

fn peak_gflops(flops_per_iter: f64, reps: usize, f: impl Fn(usize) -> f32) -> f64 {
    let iters = 10_000_000;
    black_box(f(iters / 10));
    let times: Vec<f64> = (0..reps.max(3))
        .map(|_| {
            let t0 = Instant::now();
            black_box(f(black_box(iters)));
            t0.elapsed().as_secs_f64()
        })
        .collect();
    flops_per_iter * iters as f64 / best(&times) / 1e9
}

fn measure_limits(a: &BenchArgs) -> Limits {
    let (ca, cb) = (black_box(0.999_9f32), black_box(1e-4f32));
    let peak_muladd_gflops = peak_gflops(2.0 * 48.0, a.reps, |n| muladd_loop(n, ca, cb));
    #[cfg(target_arch = "x86_64")]
    let peak_fma_gflops = if is_x86_feature_detected!("avx2") && is_x86_feature_detected!("fma") {
        // SAFETY: AVX2 and FMA were detected at run time just above.
        Some(peak_gflops(2.0 * 80.0, a.reps, |n| unsafe {
            fma_loop_avx2(n, ca, cb)
        }))
    } else {
        None
    };
    #[cfg(not(target_arch = "x86_64"))]
    let peak_fma_gflops = None;
    #[cfg(target_arch = "x86_64")]
    let peak_muladd_avx2_gflops = if is_x86_feature_detected!("avx2") {
        // SAFETY: AVX2 was detected at run time just above.
        Some(peak_gflops(2.0 * 96.0, a.reps, |n| unsafe {
            muladd_loop_avx2(n, ca, cb)
        }))
    } else {
        None
    };
    #[cfg(not(target_arch = "x86_64"))]
    let peak_muladd_avx2_gflops = None;
    Limits {
        peak_muladd_avx2_gflops,
        copy_gbs: copy_bandwidth(a.stream_mib, 7),
        read_gbs: read_bandwidth(a.stream_mib << 20, 7),
        read_l3_gbs: read_bandwidth(8 << 20, a.reps),
        peak_muladd_gflops,
        peak_fma_gflops,
    }
}

// ---------------------------------------------------------------- navigator

/// Seeded weights, as in `core/benches/navigator.rs`.
fn tensors(d: &Dims) -> Vec<Vec<f32>> {
    let mut w = gman_core::seeded::SeededWeights::new(1, 0.05);
    TensorId::all_for(d)
        .map(|id| {
            let mut v = vec![0.0f32; id.numel(d)];
            w.fill(&mut v);
            v
        })
        .collect()
}

/// The int8 blob of [`tensors`] (gman-core's one seeded-weights builder).
fn int8_blob(d: &Dims, _t: &[Vec<f32>]) -> Result<Vec<u8>> {
    let mut buf =
        vec![0u8; gman_core::blob::encoded_model_len_bound(d, gman_core::blob::Quant::I8)];
    let (nf, nb) = gman_core::blob::encode_model_scratch_len(d);
    let n = gman_core::seeded::encode_seeded(
        d,
        0,
        gman_core::blob::AdaptSettings::PAPER,
        gman_core::blob::Quant::I8,
        1,
        0.05,
        &mut buf,
        &mut vec![0.0; nf],
        &mut vec![0; nb],
    )
    .map_err(|e| anyhow!("encoding blob: {e:?}"))?;
    buf.truncate(n);
    Ok(buf)
}

/// Bytes of weight matrices one `step()` reads: G's two layers and the actor head from f32
/// RAM in `Full` mode (they adapt), from the blob otherwise; fusion, LSTM and critic always
/// from the blob (values plus int8 row scales). Biases and gains (< 0.1%) are left out.
fn weight_bytes_per_step<M: Mode>(w: &NavWeights<'_>) -> usize {
    let full = M::MODE == gman_core::memory::AdaptMode::Full;
    let adapted = [TensorId::GenW1, TensorId::GenW2, TensorId::ActorW];
    let fixed = [
        TensorId::FuseW,
        TensorId::LstmWx,
        TensorId::LstmWh,
        TensorId::CriticW,
    ];
    let a: usize = adapted
        .iter()
        .map(|&id| {
            let m = w.get(id);
            if full {
                m.rows() * m.cols() * 4
            } else {
                m.storage_bytes()
            }
        })
        .sum();
    a + fixed
        .iter()
        .map(|&id| w.get(id).storage_bytes())
        .sum::<usize>()
}

/// One navigator configuration's timings.
struct NavRow {
    preset: &'static str,
    quant: &'static str,
    mode: String,
    macs: usize,
    weight_bytes: usize,
    step_s: f64,
    step_min_s: f64,
    adapt_s: f64,
    adapt_min_s: f64,
}

fn obs(d: &Dims) -> Vec<f32> {
    let mut rng = Xoshiro128::seed_from_u64(2);
    (0..d.feat).map(|_| uniform(&mut rng)).collect()
}

/// Median per-step latency: repetitions of `n` steps, `n` chosen so one lasts ≈ 10 ms.
fn time_steps<M: Mode>(w: NavWeights<'_>, reps: usize) -> Result<(f64, f64)> {
    let d = *w.dims();
    let mut arena = vec![0.0f32; Navigator::<M, K>::arena_len(&d)];
    let cfg = NavConfig {
        adapt: false,
        ..NavConfig::default()
    };
    let mut nav: Navigator<'_, M, K> =
        Navigator::new(w, &mut arena, cfg).map_err(|e| anyhow!("{e:?}"))?;
    let o = obs(&d);
    nav.reset(&[0.3; 45], 1).map_err(|e| anyhow!("{e:?}"))?;
    let mut run = |n: usize| -> Result<f64> {
        let t0 = Instant::now();
        for _ in 0..n {
            black_box(nav.step(black_box(&o), &[]).map_err(|e| anyhow!("{e:?}"))?);
        }
        Ok(t0.elapsed().as_secs_f64())
    };
    let warm = run(3)? / 3.0;
    let n = ((0.01 / warm.max(1e-9)) as usize).clamp(1, 100_000);
    let mut per = Vec::with_capacity(reps);
    for _ in 0..reps {
        per.push(run(n)? / n as f64);
    }
    let min = per.iter().copied().fold(f64::INFINITY, f64::min);
    Ok((median(per), min))
}

/// Median latency of one inner update on exactly K buffered steps (`adapt_now()` on a
/// navigator of capacity K + 1, as in the criterion bench).
fn time_adapt<M: Mode>(w: NavWeights<'_>, reps: usize) -> Result<(f64, f64)> {
    let d = *w.dims();
    let mut arena = vec![0.0f32; Navigator::<M, { K + 1 }>::arena_len(&d)];
    let mut nav: Navigator<'_, M, { K + 1 }> =
        Navigator::new(w, &mut arena, NavConfig::default()).map_err(|e| anyhow!("{e:?}"))?;
    let o = obs(&d);
    let mut per = Vec::with_capacity(reps);
    for i in 0..reps + 1 {
        nav.reset(&[0.3; 45], 1).map_err(|e| anyhow!("{e:?}"))?;
        for _ in 0..K {
            nav.step(&o, &[]).map_err(|e| anyhow!("{e:?}"))?;
        }
        let t0 = Instant::now();
        black_box(nav.adapt_now().map_err(|e| anyhow!("{e:?}"))?);
        let t = t0.elapsed().as_secs_f64();
        if i > 0 {
            per.push(t); // the first one is a warm-up
        }
    }
    let min = per.iter().copied().fold(f64::INFINITY, f64::min);
    Ok((median(per), min))
}

fn nav_row<M: Mode>(
    preset: &'static str,
    quant: &'static str,
    w: impl Fn() -> Result<NavWeights<'static>>,
    reps: usize,
    adapt_reps: usize,
) -> Result<NavRow> {
    let weights = w()?;
    let d = *weights.dims();
    let weight_bytes = weight_bytes_per_step::<M>(&weights);
    let (step_s, step_min_s) = time_steps::<M>(weights, reps)?;
    let (adapt_s, adapt_min_s) = time_adapt::<M>(w()?, adapt_reps)?;
    Ok(NavRow {
        preset,
        quant,
        mode: format!("{:?}", M::MODE),
        macs: d.macs_per_step(),
        weight_bytes,
        step_s,
        step_min_s,
        adapt_s,
        adapt_min_s,
    })
}

fn nav_rows(a: &BenchArgs) -> Result<Vec<NavRow>> {
    let presets = if a.preset.is_empty() {
        vec![PresetArg::Mcu, PresetArg::Paper]
    } else {
        a.preset.clone()
    };
    let quants = if a.quant.is_empty() {
        vec![QuantArg::F32, QuantArg::Int8]
    } else {
        a.quant.clone()
    };
    let mut rows = Vec::new();
    for p in presets {
        let d = p.dims();
        // Leaked once per preset so the navigators can borrow them for 'static; the process
        // ends after the benchmark.
        let t: &'static [Vec<f32>] = Vec::leak(tensors(&d));
        let bytes: &'static [u8] = Vec::leak(int8_blob(&d, t)?);
        let blob: &'static Blob<'static> = Box::leak(Box::new(
            Blob::parse(bytes).map_err(|e| anyhow!("parsing blob: {e:?}"))?,
        ));
        let adapt_reps = match p {
            PresetArg::Mcu => a.reps,
            PresetArg::Paper => a.reps.div_ceil(2).max(3),
        };
        for &q in &quants {
            let w = move || -> Result<NavWeights<'static>> {
                match q {
                    QuantArg::F32 => NavWeights::from_fn(&d, |id| {
                        let (r, c) = id.shape(&d);
                        MatRef::f32(r, c, &t[id as usize]).unwrap_or_else(|_| unreachable!())
                    }),
                    QuantArg::Int8 => NavWeights::from_blob(blob, &d),
                }
                .map(|w| match gman_host_sim::simd::host_kernels() {
                    Some(k) => w.with_kernels(k),
                    None => w,
                })
                .map_err(|e| anyhow!("weights: {e:?}"))
            };
            eprintln!("bench: {} {} ...", p.name(), q.name());
            rows.push(nav_row::<Full>(p.name(), q.name(), w, a.reps, adapt_reps)?);
            rows.push(nav_row::<Efficient>(
                p.name(),
                q.name(),
                w,
                a.reps,
                adapt_reps,
            )?);
        }
    }
    Ok(rows)
}

// ---------------------------------------------------------------- kernels

/// One cache-resident kernel timing.
struct KernelRow {
    what: &'static str,
    quant: &'static str,
    kernels: &'static str,
    macs: usize,
    secs: f64,
}

/// Best-of timings of gman-core's dense kernels on a cache-resident 512 x 256 matrix (the
/// `mcu` G output layer), batch 1 and batch 20, with the portable build and, when the CPU has
/// it, the AVX2 build (`gman_host_sim::simd`).
fn kernel_rows(reps: usize) -> Result<Vec<KernelRow>> {
    use gman_core::batch::{matmul_acc, matmul_t_acc, outer_acc_batch_with, Kernels};
    use gman_core::matrix::Scales;
    let (r, c, n) = (512usize, 256usize, K);
    let mut rng = Xoshiro128::seed_from_u64(6);
    let mut w = vec![0.0f32; r * c];
    fill_gaussian(&mut rng, &mut w);
    let (mut q, mut sc) = (vec![0u8; r * c], vec![0.0f32; r]);
    quantize_rows(&w, r, c, &mut q, &mut sc).map_err(|e| anyhow!("{e:?}"))?;
    let mut x = vec![0.0f32; n * c];
    fill_gaussian(&mut rng, &mut x);
    let mut dy = vec![0.0f32; n * r];
    fill_gaussian(&mut rng, &mut dy);
    let (mut y, mut dx, mut dw) = (
        vec![0.0f32; n * r],
        vec![0.0f32; n * c],
        vec![0.0f32; r * c],
    );
    let sets: Vec<(&'static str, Option<&'static dyn Kernels>)> =
        std::iter::once(("portable", None))
            .chain(gman_host_sim::simd::avx2().map(|k| ("avx2", Some(k))))
            .collect();
    let time = |f: &mut dyn FnMut() -> gman_core::Result<()>| -> Result<f64> {
        let t0 = Instant::now();
        f().map_err(|e| anyhow!("{e:?}"))?;
        let inner = ((2e-3 / t0.elapsed().as_secs_f64().max(1e-9)) as usize).clamp(1, 10_000);
        let mut best = f64::INFINITY;
        for _ in 0..reps.max(3) {
            let t0 = Instant::now();
            for _ in 0..inner {
                f().map_err(|e| anyhow!("{e:?}"))?;
            }
            best = best.min(t0.elapsed().as_secs_f64() / inner as f64);
        }
        Ok(best)
    };
    let mut rows = Vec::new();
    for (name, k) in sets {
        let with = |m: MatRef<'static>| match k {
            Some(k) => m.with_kernels(k),
            None => m,
        };
        let wf: &'static [f32] = Vec::leak(w.clone());
        let qs: &'static [u8] = Vec::leak(q.clone());
        let ss: &'static [f32] = Vec::leak(sc.clone());
        let mf = with(MatRef::f32(r, c, wf).map_err(|e| anyhow!("{e:?}"))?);
        let mq = with(MatRef::i8(r, c, qs, Scales::F32(ss)).map_err(|e| anyhow!("{e:?}"))?);
        for (quant, m) in [("f32", mf), ("int8", mq)] {
            let t = time(&mut || m.matvec_acc(&[&x[..c]], &mut y[..r]))?;
            rows.push(KernelRow {
                what: "matvec (batch 1)",
                quant,
                kernels: name,
                macs: r * c,
                secs: t,
            });
            let t = time(&mut || matmul_acc(&m, &[&x], &[c], n, &mut y))?;
            rows.push(KernelRow {
                what: "matmul (batch 20)",
                quant,
                kernels: name,
                macs: r * c * n,
                secs: t,
            });
            let t = time(&mut || matmul_t_acc(&m, &dy, n, &mut [&mut dx], &[c]))?;
            rows.push(KernelRow {
                what: "matmul_t (batch 20)",
                quant,
                kernels: name,
                macs: r * c * n,
                secs: t,
            });
        }
        let t = time(&mut || outer_acc_batch_with(k, &mut dw, &dy, &[&x], &[c], n, 1e-6))?;
        rows.push(KernelRow {
            what: "outer (batch 20)",
            quant: "f32",
            kernels: name,
            macs: r * c * n,
            secs: t,
        });
    }
    black_box((&y, &dx, &dw));
    Ok(rows)
}

// ---------------------------------------------------------------- training

// The training-throughput rows live in `crate::bench_train`.

// ---------------------------------------------------------------- report

fn us(s: f64) -> String {
    if s < 1e-3 {
        format!("{:.1} µs", s * 1e6)
    } else {
        format!("{:.3} ms", s * 1e3)
    }
}

fn pct(x: f64) -> String {
    format!("{:.0}%", 100.0 * x)
}

/// Runs the benchmark.
pub fn cmd_bench(a: BenchArgs) -> Result<()> {
    let started = Instant::now();
    eprintln!("bench: machine limits ...");
    let lim = measure_limits(&a);
    eprintln!("bench: kernels ...");
    let krows = kernel_rows(a.reps)?;
    let rows = nav_rows(&a)?;
    let trains = if a.train_updates > 0 {
        crate::bench_train::rows(a.train_updates)?
    } else {
        Vec::new()
    };
    let fma = lim.peak_fma_gflops.unwrap_or(f64::NAN);

    let nav_json: Vec<Value> = rows
        .iter()
        .map(|r| {
            let gflops = 2.0 * r.macs as f64 / r.step_s / 1e9;
            let gbs = r.weight_bytes as f64 / r.step_s / 1e9;
            json!({
                "preset": r.preset, "quant": r.quant, "mode": r.mode,
                "step_us": r.step_s * 1e6, "step_min_us": r.step_min_s * 1e6,
                "adapt_ms": r.adapt_s * 1e3, "adapt_min_ms": r.adapt_min_s * 1e3,
                "macs_per_step": r.macs, "weight_bytes_per_step": r.weight_bytes,
                "gflops": gflops, "weight_gbs": gbs,
                "frac_peak_muladd": gflops / lim.peak_muladd_gflops,
                "frac_peak_fma": gflops / fma,
                "frac_copy_bw": gbs / lim.copy_gbs,
                "frac_read_bw": gbs / lim.read_gbs,
                "adapt_over_step": r.adapt_s / r.step_s,
            })
        })
        .collect();
    let train_json = crate::bench_train::json(&trains);
    let peak_for = |k: &str| {
        if k == "avx2" {
            lim.peak_muladd_avx2_gflops.unwrap_or(f64::NAN)
        } else {
            lim.peak_muladd_gflops
        }
    };
    let kernel_json: Vec<Value> = krows
        .iter()
        .map(|r| {
            let g = 2.0 * r.macs as f64 / r.secs / 1e9;
            json!({
                "kernel": r.what, "quant": r.quant, "kernels": r.kernels, "macs": r.macs,
                "us": r.secs * 1e6, "gflops": g, "frac_peak_muladd_same_isa": g / peak_for(r.kernels),
            })
        })
        .collect();
    let report = json!({
        "threads": 1,
        "navigator_kernels": gman_host_sim::simd::host_kernels_name(),
        "kernels": kernel_json,
        "k": K,
        "limits": {
            "copy_gbs": lim.copy_gbs, "copy_mib": a.stream_mib,
            "read_gbs": lim.read_gbs, "read_l3_8mib_gbs": lim.read_l3_gbs,
            "peak_muladd_gflops": lim.peak_muladd_gflops,
            "peak_muladd_avx2_gflops": lim.peak_muladd_avx2_gflops,
            "peak_fma_avx2_gflops": lim.peak_fma_gflops,
        },
        "navigator": nav_json,
        "train": train_json,
        "firmware_qemu": {
            "source": "firmware-example/README.md (mcu, int8, Efficient; not re-measured)",
            "step_instructions": FW_STEP_INSTR,
            "adapt_instructions": FW_ADAPT_INSTR,
            "step_ms_at_168mhz_1ipc": FW_STEP_INSTR / FW_MHZ / 1e3,
            "adapt_ms_at_168mhz_1ipc": FW_ADAPT_INSTR / FW_MHZ / 1e3,
            "instructions_per_mac": FW_STEP_INSTR / Dims::MCU.macs_per_step() as f64,
        },
        "elapsed_s": started.elapsed().as_secs_f64(),
    });
    match &a.json {
        Some(p) if p.as_os_str() == "-" => {
            println!("{}", serde_json::to_string_pretty(&report)?);
            return Ok(());
        }
        Some(p) => {
            std::fs::write(p, serde_json::to_string_pretty(&report)? + "\n")
                .with_context(|| format!("writing {}", p.display()))?;
        }
        None => {}
    }

    println!(
        "Machine limits (1 thread, this run): copy {:.1} GB/s ({} MiB arrays, read+write), \
         read {:.1} GB/s (DRAM), {:.1} GB/s (8 MiB, L3); peak f32 mul+add {:.1} GFLOP/s \
         (SSE2, the portable build's ISA), {} (AVX2 without FMA, the AVX2 build's), peak FMA {} \
         (AVX2+FMA)",
        lim.copy_gbs,
        a.stream_mib,
        lim.read_gbs,
        lim.read_l3_gbs,
        lim.peak_muladd_gflops,
        lim.peak_muladd_avx2_gflops
            .map_or("n/a".to_string(), |g| format!("{g:.1} GFLOP/s")),
        lim.peak_fma_gflops
            .map_or("n/a".to_string(), |g| format!("{g:.1} GFLOP/s")),
    );
    println!();
    println!(
        "| kernel (512 x 256, cache-resident) | weights | kernels | time (best) | GFLOP/s | % mul+add peak of that ISA |"
    );
    println!("|---|---|---|---:|---:|---:|");
    for r in &krows {
        let g = 2.0 * r.macs as f64 / r.secs / 1e9;
        println!(
            "| {} | {} | {} | {} | {:.1} | {} |",
            r.what,
            r.quant,
            r.kernels,
            us(r.secs),
            g,
            pct(g / peak_for(r.kernels)),
        );
    }
    println!();
    println!(
        "Navigator rows below use the {} kernels (`GMAN_KERNELS=portable` selects the portable build; same bits).",
        gman_host_sim::simd::host_kernels_name()
    );
    println!();
    println!(
        "| preset | weights | mode | step (median) | adaptation k=20 (median) | adapt/step | \
         MAC/step | GFLOP/s | % mul+add peak | % FMA peak | weight MB/step | GB/s | % copy BW |"
    );
    println!("|---|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|");
    for r in &rows {
        let gflops = 2.0 * r.macs as f64 / r.step_s / 1e9;
        let gbs = r.weight_bytes as f64 / r.step_s / 1e9;
        println!(
            "| {} | {} | {} | {} | {} | {:.0} | {} | {:.2} | {} | {} | {:.2} | {:.2} | {} |",
            r.preset,
            r.quant,
            r.mode,
            us(r.step_s),
            us(r.adapt_s),
            r.adapt_s / r.step_s,
            r.macs,
            gflops,
            pct(gflops / lim.peak_muladd_gflops),
            pct(gflops / fma),
            r.weight_bytes as f64 / 1e6,
            gbs,
            pct(gbs / lim.copy_gbs),
        );
    }
    println!(
        "| firmware M4F (QEMU) | int8 | Efficient | {:.0} instr ≈ {:.1} ms @168 MHz | {:.1} M instr ≈ {:.0} ms | {:.0} | {} | {:.1} instr/MAC | | | | | |",
        FW_STEP_INSTR,
        FW_STEP_INSTR / FW_MHZ / 1e3,
        FW_ADAPT_INSTR / 1e6,
        FW_ADAPT_INSTR / FW_MHZ / 1e3,
        FW_ADAPT_INSTR / FW_STEP_INSTR,
        Dims::MCU.macs_per_step(),
        FW_STEP_INSTR / Dims::MCU.macs_per_step() as f64,
    );
    crate::bench_train::print_table(&trains);
    println!();
    println!(
        "(1 thread for the navigator rows; medians of {} repetitions; firmware row quoted from \
         firmware-example/README.md; total {:.0} s)",
        a.reps,
        started.elapsed().as_secs_f64()
    );
    Ok(())
}
