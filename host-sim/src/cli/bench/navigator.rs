//! The navigator rows (`step()` and one inner update on k = 20 buffered steps, per preset,
//! weight storage and adaptation mode) and the cache-resident kernel rows.

use gman_core::spec::ModelSpec;
use std::hint::black_box;
use std::time::Instant;

use anyhow::{anyhow, Result};
use gman_core::blob::quant::quantize_rows;
use gman_core::blob::{Blob, TensorId};
use gman_core::navigator::memory::{AdaptMode, Footprint};
use gman_core::navigator::{Efficient, Full, Mode, NavConfig, NavWeights, Navigator};
use gman_core::nn::matrix::MatRef;
use gman_core::rng::{fill_gaussian, uniform, Xoshiro128};
use gman_core::Dims;

use super::{median, BenchArgs, QuantArg, K};
use crate::cli::PresetArg;

/// Seeded weights, as in `core/benches/navigator.rs`.
fn tensors(d: &Dims) -> Vec<Vec<f32>> {
    let mut w = gman_core::blob::seeded::SeededWeights::new(1, 0.05);
    TensorId::all_for(d)
        .map(|id| {
            let mut v = vec![0.0f32; id.numel(d)];
            w.fill(&mut v);
            v
        })
        .collect()
}

/// Bytes of weight matrices one `step()` reads: G's two layers and the actor head from f32
/// RAM in `Full` mode (they adapt), from the blob otherwise; fusion, LSTM and critic always
/// from the blob (values plus int8 row scales). Biases and gains (< 0.1%) are left out.
fn weight_bytes_per_step<M: Mode>(w: &NavWeights<'_>) -> usize {
    let full = M::MODE == gman_core::navigator::memory::AdaptMode::Full;
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
pub struct NavRow {
    pub preset: &'static str,
    pub quant: &'static str,
    pub mode: String,
    pub macs: usize,
    pub weight_bytes: usize,
    pub step_s: f64,
    pub step_min_s: f64,
    pub adapt_s: f64,
    pub adapt_min_s: f64,
}

fn obs(d: &Dims) -> Vec<f32> {
    let mut rng = Xoshiro128::seed_from_u64(2);
    (0..d.feat).map(|_| uniform(&mut rng)).collect()
}

/// Median per-step latency: repetitions of `n` steps, `n` chosen so one lasts ≈ 10 ms.
fn time_steps<M: Mode>(w: NavWeights<'_>, fp: Footprint, reps: usize) -> Result<(f64, f64)> {
    let d = *w.dims();
    let mut arena = vec![0.0f32; Navigator::<M, K>::arena_len_for(&d, fp)];
    let cfg = NavConfig {
        model: ModelSpec {
            adapt: false,
            ..NavConfig::default().model
        },
        footprint: fp,
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
fn time_adapt<M: Mode>(w: NavWeights<'_>, fp: Footprint, reps: usize) -> Result<(f64, f64)> {
    let d = *w.dims();
    let mut arena = vec![0.0f32; Navigator::<M, { K + 1 }>::arena_len_for(&d, fp)];
    let cfg = NavConfig {
        footprint: fp,
        ..NavConfig::default()
    };
    let mut nav: Navigator<'_, M, { K + 1 }> =
        Navigator::new(w, &mut arena, cfg).map_err(|e| anyhow!("{e:?}"))?;
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

/// One row: `M` with footprint `fp` (the mode's name, with ", compact" for the
/// microcontroller's layout in Efficient mode, the only mode where the two differ).
fn nav_row<M: Mode>(
    preset: &'static str,
    quant: &'static str,
    w: impl Fn() -> Result<NavWeights<'static>>,
    fp: Footprint,
    (reps, adapt_reps): (usize, usize),
) -> Result<NavRow> {
    let weights = w()?;
    let d = *weights.dims();
    let weight_bytes = weight_bytes_per_step::<M>(&weights);
    let (step_s, step_min_s) = time_steps::<M>(weights, fp, reps)?;
    let (adapt_s, adapt_min_s) = time_adapt::<M>(w()?, fp, adapt_reps)?;
    let compact = fp == Footprint::Compact && M::MODE == AdaptMode::Efficient;
    Ok(NavRow {
        preset,
        quant,
        mode: format!("{:?}{}", M::MODE, if compact { ", compact" } else { "" }),
        macs: d.macs_per_step(),
        weight_bytes,
        step_s,
        step_min_s,
        adapt_s,
        adapt_min_s,
    })
}

pub fn nav_rows(a: &BenchArgs) -> Result<Vec<NavRow>> {
    let presets = if a.preset.is_empty() {
        vec![PresetArg::Mcu, PresetArg::Paper]
    } else {
        a.preset.clone()
    };
    let quants = if a.quant.is_empty() {
        vec![QuantArg::F32, QuantArg::Int8, QuantArg::Int8Act]
    } else {
        a.quant.clone()
    };
    let mut rows = Vec::new();
    for p in presets {
        let d = p.dims();
        // Leaked once per preset so the navigators can borrow them for 'static; the process
        // ends after the benchmark.
        let t: &'static [Vec<f32>] = Vec::leak(tensors(&d));
        let bytes: &'static [u8] = Vec::leak(gman_host_sim::seeded::int8_blob(&d, 1, 0.05)?);
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
                    QuantArg::Int8Act => {
                        NavWeights::from_blob(blob, &d).map(|w| w.with_int8_activations())
                    }
                }
                .map(|w| match gman_host_sim::simd::host_kernels() {
                    Some(k) => w.with_kernels(k),
                    None => w,
                })
                .map_err(|e| anyhow!("weights: {e:?}"))
            };
            eprintln!("bench: {} {} ...", p.name(), q.name());
            let r = (a.reps, adapt_reps);
            rows.push(nav_row::<Full>(p.name(), q.name(), w, Footprint::Fast, r)?);
            for fp in [Footprint::Fast, Footprint::Compact] {
                rows.push(nav_row::<Efficient>(p.name(), q.name(), w, fp, r)?);
            }
        }
    }
    Ok(rows)
}

// ---------------------------------------------------------------- kernels

/// One cache-resident kernel timing.
pub struct KernelRow {
    pub what: &'static str,
    pub quant: &'static str,
    pub kernels: &'static str,
    pub macs: usize,
    pub secs: f64,
}

/// Best-of timings of gman-core's dense kernels on a cache-resident 512 x 256 matrix (the
/// `mcu` G output layer), batch 1 and batch 20, with the portable build and, when the CPU has
/// it, the AVX2 build (`gman_host_sim::simd`).
pub fn kernel_rows(reps: usize) -> Result<Vec<KernelRow>> {
    use gman_core::nn::batch::{matmul_acc, matmul_t_acc, outer_acc_batch_with, Kernels};
    use gman_core::nn::matrix::Scales;
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
        let mqa = mq.with_int8_activations();
        for (quant, m) in [("f32", mf), ("int8", mq), ("int8-act", mqa)] {
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
