//! Runs one navigator configuration in a loop, for a profiler (`perf record`), and prints
//! the time per step and per inner update (seeded weights, as `gman bench`):
//!
//! ```text
//! cargo run --release -p gman-host-sim --example nav_profile -- \
//!     mcu|paper f32|int8 full|efficient step|adapt SECONDS [fast|compact]
//! perf record target/release/examples/nav_profile paper int8 efficient adapt 5
//! ```
use gman_core::spec::ModelSpec;
use std::hint::black_box;
use std::time::Instant;

use gman_core::blob::{Blob, TensorId};
use gman_core::navigator::memory::Footprint;
use gman_core::navigator::{Efficient, Full, Mode, NavConfig, NavWeights, Navigator};
use gman_core::nn::matrix::MatRef;
use gman_core::rng::{uniform, Xoshiro128};
use gman_core::Dims;

const K: usize = 20;

fn run<M: Mode>(w: NavWeights<'_>, what: &str, secs: f64, fp: Footprint) {
    let d = *w.dims();
    let mut rng = Xoshiro128::seed_from_u64(2);
    let o: Vec<f32> = (0..d.feat).map(|_| uniform(&mut rng)).collect();
    let mut arena = vec![0.0f32; Navigator::<M, { K + 1 }>::arena_len_for(&d, fp)];
    let cfg = NavConfig {
        model: ModelSpec {
            adapt: what == "adapt",
            ..NavConfig::default().model
        },
        footprint: fp,
        ..NavConfig::default()
    };
    let mut nav: Navigator<'_, M, { K + 1 }> = Navigator::new(w, &mut arena, cfg).unwrap();
    let t0 = Instant::now();
    let (mut n, mut t_adapt) = (0usize, 0.0f64);
    while t0.elapsed().as_secs_f64() < secs {
        nav.reset(&[0.3; 45], 1).unwrap();
        for _ in 0..K {
            black_box(nav.step(black_box(&o), &[]).unwrap());
        }
        if what == "adapt" {
            let t = Instant::now();
            black_box(nav.adapt_now().unwrap());
            t_adapt += t.elapsed().as_secs_f64();
        }
        n += 1;
    }
    let el = t0.elapsed().as_secs_f64();
    println!(
        "{n} episodes of {K} steps in {el:.2} s: {:.2} us per step (incl. adapt), adapt {:.3} ms",
        el / (n * K) as f64 * 1e6,
        t_adapt / n as f64 * 1e3
    );
}

fn main() {
    let a: Vec<String> = std::env::args().collect();
    let ok = a.len() >= 6
        && ["mcu", "paper"].contains(&a[1].as_str())
        && ["f32", "int8"].contains(&a[2].as_str())
        && ["full", "efficient"].contains(&a[3].as_str())
        && ["step", "adapt"].contains(&a[4].as_str())
        && a[5].parse::<f64>().is_ok_and(|s| s > 0.0)
        && a.get(6).is_none_or(|f| f == "fast" || f == "compact");
    if !ok {
        eprintln!("usage: nav_profile mcu|paper f32|int8 full|efficient step|adapt SECONDS [fast|compact]");
        std::process::exit(2);
    }
    let d = if a[1] == "paper" {
        Dims::PAPER
    } else {
        Dims::MCU
    };
    let secs: f64 = a[5].parse().unwrap();
    let mut sw = gman_core::blob::seeded::SeededWeights::new(1, 0.05);
    let t: Vec<Vec<f32>> = TensorId::all_for(&d)
        .map(|id| {
            let mut v = vec![0.0f32; id.numel(&d)];
            sw.fill(&mut v);
            v
        })
        .collect();
    let buf = gman_host_sim::seeded::int8_blob(&d, 1, 0.05).unwrap();
    let blob = Blob::parse(&buf).unwrap();
    let w = if a[2] == "f32" {
        NavWeights::from_fn(&d, |id| {
            let (r, c) = id.shape(&d);
            MatRef::f32(r, c, &t[id as usize]).unwrap()
        })
        .unwrap()
    } else {
        NavWeights::from_blob(&blob, &d).unwrap()
    };
    let w = match gman_host_sim::simd::host_kernels() {
        Some(k) => w.with_kernels(k),
        None => w,
    };
    let fp = if a.get(6).map(|s| s.as_str()) == Some("compact") {
        Footprint::Compact
    } else {
        Footprint::Fast
    };
    if a[3] == "full" {
        run::<Full>(w, &a[4], secs, fp)
    } else {
        run::<Efficient>(w, &a[4], secs, fp)
    }
}
