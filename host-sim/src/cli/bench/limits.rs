//! This machine's limits, measured in the run on one thread: a STREAM-like copy bandwidth,
//! read bandwidths (DRAM and L3-sized) and peak multiply-add loops (SSE2, AVX2, AVX2+FMA).

use std::hint::black_box;
use std::time::Instant;

use super::{best, BenchArgs};

/// Machine limits, measured in this run on one thread (best of the repetitions).
pub struct Limits {
    /// STREAM-like copy of two `stream_mib` arrays: (bytes read + written) / s.
    pub copy_gbs: f64,
    /// Read-only bandwidth over a `stream_mib` array (DRAM).
    pub read_gbs: f64,
    /// Read-only bandwidth over an 8 MiB array (L3-resident on this machine).
    pub read_l3_gbs: f64,
    /// Peak of separate f32 multiply and add (the instructions this build's kernels can use:
    /// baseline x86-64 = SSE2, 4 lanes, no FMA), GFLOP/s.
    pub peak_muladd_gflops: f64,
    /// Peak of separate f32 multiply and add with AVX2 (8 lanes, no FMA): the limit of the
    /// AVX2 build of the kernels (`gman_host_sim::simd`), GFLOP/s.
    pub peak_muladd_avx2_gflops: Option<f64>,
    /// Peak of fused multiply-add with AVX2+FMA when the CPU has it (the machine's limit for
    /// f32; AVX-512 on Zen 4 has the same FLOP/cycle), GFLOP/s.
    pub peak_fma_gflops: Option<f64>,
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

/// Measures the limits (best of the repetitions).
pub fn measure_limits(a: &BenchArgs) -> Limits {
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
