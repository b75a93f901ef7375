//! Criterion benches of the on-device navigator: one `step()` (no adaptation) and one inner
//! update on a full buffer (k = 20), for the `mcu` and `paper` presets, f32 and int8 weights,
//! and the `Full` and `Efficient` adaptation modes.
//!
//! `cargo bench -p gman-core --bench navigator` (single thread). `gman bench` times the same
//! configurations next to the machine's measured limits; a recorded run, the PyTorch
//! comparison and what limits each number are in `host-sim/BENCHMARKS.md`.

use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion};
use gman_core::blob::seeded::{encode_seeded, SeededWeights};
use gman_core::blob::{
    encode_model_scratch_len, encoded_model_len_bound, AdaptSettings, Blob, Quant, TensorId,
};
use gman_core::navigator::{Efficient, Full, Mode, NavConfig, NavWeights, Navigator};
use gman_core::nn::matrix::MatRef;
use gman_core::rng::{uniform, Xoshiro128};
use gman_core::spec::ModelSpec;
use gman_core::Dims;
use std::hint::black_box;
use std::time::{Duration, Instant};

const K: usize = 20;

fn tensors(d: &Dims) -> Vec<Vec<f32>> {
    let mut w = SeededWeights::new(1, 0.05);
    TensorId::all_for(d)
        .map(|id| {
            let mut v = vec![0.0f32; id.numel(d)];
            w.fill(&mut v);
            v
        })
        .collect()
}

/// The int8 blob of [`tensors`].
fn int8_blob(d: &Dims) -> Vec<u8> {
    let mut buf = vec![0u8; encoded_model_len_bound(d, Quant::I8)];
    let (nf, nb) = encode_model_scratch_len(d);
    let n = encode_seeded(
        d,
        0,
        AdaptSettings::PAPER,
        Quant::I8,
        1,
        0.05,
        &mut buf,
        &mut vec![0.0; nf],
        &mut vec![0; nb],
    )
    .unwrap();
    buf.truncate(n);
    buf
}

fn obs(rng: &mut Xoshiro128, d: &Dims) -> Vec<f32> {
    (0..d.feat).map(|_| uniform(rng)).collect()
}

fn bench_one<M: Mode>(c: &mut Criterion, preset: &str, d: Dims, quant: &str, w: NavWeights<'_>) {
    let mode = format!("{:?}", M::MODE);
    let mut arena = vec![0.0f32; Navigator::<M, K>::arena_len(&d)];
    let cfg = NavConfig {
        model: ModelSpec {
            adapt: false,
            ..NavConfig::default().model
        },
        ..NavConfig::default()
    };
    let mut nav: Navigator<'_, M, K> = Navigator::new(w, &mut arena, cfg).unwrap();
    let mut rng = Xoshiro128::seed_from_u64(2);
    let o = obs(&mut rng, &d);
    nav.reset(&[0.3; 45], 1).unwrap();
    let mut g = c.benchmark_group(format!("{preset}/{quant}/{mode}"));
    g.sample_size(10)
        .measurement_time(Duration::from_secs(2))
        .warm_up_time(Duration::from_millis(300));
    g.bench_function(BenchmarkId::new("step", ""), |b| {
        b.iter(|| black_box(nav.step(black_box(&o), &[]).unwrap()))
    });
    g.finish();
}

/// One inner update on a buffer of exactly K = 20 steps. A navigator of capacity K + 1 holds
/// the 20 recorded steps without triggering its own update; `adapt_now` then runs it.
fn bench_adapt<M: Mode>(c: &mut Criterion, preset: &str, d: Dims, quant: &str, w: NavWeights<'_>) {
    let mode = format!("{:?}", M::MODE);
    let mut arena = vec![0.0f32; Navigator::<M, { K + 1 }>::arena_len(&d)];
    let mut nav: Navigator<'_, M, { K + 1 }> =
        Navigator::new(w, &mut arena, NavConfig::default()).unwrap();
    let mut rng = Xoshiro128::seed_from_u64(3);
    let o = obs(&mut rng, &d);
    let mut g = c.benchmark_group(format!("{preset}/{quant}/{mode}"));
    g.sample_size(10)
        .measurement_time(Duration::from_secs(2))
        .warm_up_time(Duration::from_millis(300));
    g.bench_function(BenchmarkId::new("adaptation_k20", ""), |b| {
        b.iter_custom(|iters| {
            let mut total = Duration::ZERO;
            for _ in 0..iters {
                nav.reset(&[0.3; 45], 1).unwrap();
                for _ in 0..K {
                    nav.step(&o, &[]).unwrap();
                }
                let t0 = Instant::now();
                black_box(nav.adapt_now().unwrap());
                total += t0.elapsed();
            }
            total
        })
    });
    g.finish();
}

fn benches(c: &mut Criterion) {
    for (preset, d) in [("mcu", Dims::MCU), ("paper", Dims::PAPER)] {
        let t = tensors(&d);
        let f32w = || {
            NavWeights::from_fn(&d, |id| {
                let (r, cc) = id.shape(&d);
                MatRef::f32(r, cc, &t[id as usize]).unwrap()
            })
            .unwrap()
        };
        let bytes = int8_blob(&d);
        let blob = Blob::parse(&bytes).unwrap();
        let i8w = || NavWeights::from_blob(&blob, &d).unwrap();
        bench_one::<Full>(c, preset, d, "f32", f32w());
        bench_adapt::<Full>(c, preset, d, "f32", f32w());
        bench_one::<Efficient>(c, preset, d, "f32", f32w());
        bench_adapt::<Efficient>(c, preset, d, "f32", f32w());
        bench_one::<Full>(c, preset, d, "int8", i8w());
        bench_adapt::<Full>(c, preset, d, "int8", i8w());
        bench_one::<Efficient>(c, preset, d, "int8", i8w());
        bench_adapt::<Efficient>(c, preset, d, "int8", i8w());
    }
}

criterion_group!(navigator, benches);
criterion_main!(navigator);
