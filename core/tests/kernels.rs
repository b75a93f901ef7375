//! Kernel properties: int8 vs f32 agreement, segment handling, shape errors, determinism.

mod common;
use common::*;
use gman_core::blob::quant::{dequantize_rows, quantize_rows};
use gman_core::blob::{Blob, TensorId};
use gman_core::nets::discriminator::{DiscScratch, Discriminator, LdConfig};
use gman_core::nets::generator::{Generator, GeneratorCache};
use gman_core::nn::dense::Dense;
use gman_core::nn::matrix::{MatRef, Scales};
use gman_core::rng::{fill_gaussian, gaussian, Xoshiro128};
use gman_core::Error;
use rand_core::RngCore;

#[test]
fn int8_matvec_matches_dequantised_f32() {
    let mut rng = Xoshiro128::seed_from_u64(11);
    let (r, c) = (13, 37);
    let mut w = vec![0.0f32; r * c];
    fill_gaussian(&mut rng, &mut w);
    let (mut q, mut s) = (vec![0u8; r * c], vec![0.0f32; r]);
    quantize_rows(&w, r, c, &mut q, &mut s).unwrap();
    let mut wd = vec![0.0f32; r * c];
    dequantize_rows(&q, &s, c, &mut wd).unwrap();
    let mut x = vec![0.0f32; c];
    fill_gaussian(&mut rng, &mut x);
    let (x1, x2) = x.split_at(20);
    let mut yq = vec![0.5f32; r];
    let mut yf = vec![0.5f32; r];
    MatRef::i8(r, c, &q, Scales::F32(&s))
        .unwrap()
        .matvec_acc(&[x1, x2], &mut yq)
        .unwrap();
    MatRef::f32(r, c, &wd)
        .unwrap()
        .matvec_acc(&[&x], &mut yf)
        .unwrap();
    for (a, b) in yq.iter().zip(&yf) {
        assert!((a - b).abs() <= 1e-4 * (1.0 + b.abs()), "{a} vs {b}");
    }
    // Transposed product, int8 vs f32, and the LE-bytes f32 path.
    let mut dy = vec![0.0f32; r];
    fill_gaussian(&mut rng, &mut dy);
    let (mut dxq, mut dxf, mut dxl) = (vec![0.0f32; c], vec![0.0f32; c], vec![0.0f32; c]);
    MatRef::i8(r, c, &q, Scales::F32(&s))
        .unwrap()
        .matvec_t_acc(&dy, &mut [&mut dxq])
        .unwrap();
    MatRef::f32(r, c, &wd)
        .unwrap()
        .matvec_t_acc(&dy, &mut [&mut dxf])
        .unwrap();
    let le: Vec<u8> = wd.iter().flat_map(|v| v.to_le_bytes()).collect();
    MatRef::f32_le(r, c, &le)
        .unwrap()
        .matvec_t_acc(&dy, &mut [&mut dxl])
        .unwrap();
    for ((a, b), l) in dxq.iter().zip(&dxf).zip(&dxl) {
        assert!((a - b).abs() <= 1e-4 * (1.0 + b.abs()));
        assert_eq!(
            b.to_bits(),
            l.to_bits(),
            "LE bytes and f32 slices must agree bit for bit"
        );
    }
}

#[test]
fn shape_errors_are_typed_not_panics() {
    let w = vec![0.0f32; 6];
    assert!(matches!(MatRef::f32(2, 4, &w), Err(Error::Shape(_))));
    let m = MatRef::f32(2, 3, &w).unwrap();
    let mut y = vec![0.0; 2];
    assert!(matches!(
        m.matvec_acc(&[&[1.0, 2.0]], &mut y),
        Err(Error::Shape(_))
    ));
    let mut y3 = vec![0.0; 3];
    assert!(matches!(
        m.matvec_acc(&[&[1.0, 2.0, 3.0]], &mut y3),
        Err(Error::Shape(_))
    ));
    let b = vec![0.0; 3];
    let d = Dense {
        w: m,
        b: &b,
        gain: None,
    };
    assert!(matches!(d.validate(), Err(Error::Shape(_))));
}

#[test]
fn rng_is_deterministic_and_gaussian() {
    let mut a = Xoshiro128::seed_from_u64(42);
    let mut b = Xoshiro128::seed_from_u64(42);
    let mut c = Xoshiro128::seed_from_u64(43);
    let va: Vec<u32> = (0..100).map(|_| a.next_u32()).collect();
    let vb: Vec<u32> = (0..100).map(|_| b.next_u32()).collect();
    let vc: Vec<u32> = (0..100).map(|_| c.next_u32()).collect();
    assert_eq!(va, vb);
    assert_ne!(va, vc);
    let n = 200_000;
    let (mut s, mut s2) = (0.0f64, 0.0f64);
    for _ in 0..n {
        let g = gaussian(&mut a) as f64;
        s += g;
        s2 += g * g;
    }
    let mean = s / n as f64;
    let var = s2 / n as f64 - mean * mean;
    assert!(mean.abs() < 0.01, "mean {mean}");
    assert!((var - 1.0).abs() < 0.02, "var {var}");
    let st = a.state();
    let mut r = Xoshiro128::from_state(st);
    assert_eq!(r.next_u32(), a.next_u32());
}

/// Runs G and L_D from an int8 blob and returns every output's bits.
fn run_once(bytes: &[u8], seed: u64) -> Vec<u32> {
    let blob = Blob::parse(bytes).unwrap();
    let d = SMALL;
    let mut b1 = vec![0.0; d.gen_hidden];
    let mut b2 = vec![0.0; d.feat];
    blob.copy_f32(TensorId::GenB1, &mut b1).unwrap();
    blob.copy_f32(TensorId::GenB2, &mut b2).unwrap();
    let gen = Generator {
        l1: Dense {
            w: blob.matrix(TensorId::GenW1).unwrap(),
            b: &b1,
            gain: None,
        },
        l2: Dense {
            w: blob.matrix(TensorId::GenW2).unwrap(),
            b: &b2,
            gain: None,
        },
    };
    let mut db1 = vec![0.0; d.disc_hidden];
    let mut dw2 = vec![0.0; d.disc_hidden];
    blob.copy_f32(TensorId::DiscB1, &mut db1).unwrap();
    blob.copy_f32(TensorId::DiscW2, &mut dw2).unwrap();
    let disc = Discriminator {
        l1: Dense {
            w: blob.matrix(TensorId::DiscW1).unwrap(),
            b: &db1,
            gain: None,
        },
        w2: &dw2,
        b2: 0.0,
    };
    let mut rng = Xoshiro128::seed_from_u64(seed);
    let mut out = Vec::new();
    let (mut u1, mut h1, mut u2, mut x) =
        (vec![], vec![0.0; d.gen_hidden], vec![], vec![0.0; d.feat]);
    let mut fake = Vec::new();
    let mut real = vec![0.0f32; 4 * d.feat];
    fill_gaussian(&mut rng, &mut real);
    for _ in 0..4 {
        let mut z = vec![0.0f32; d.noise];
        fill_gaussian(&mut rng, &mut z);
        let attr = vec![0.5f32; d.attr];
        let mut cache = GeneratorCache {
            u1: &mut u1,
            h1: &mut h1,
            u2: &mut u2,
            x: &mut x,
        };
        gen.forward(&z, &attr, &mut cache).unwrap();
        fake.extend_from_slice(cache.x);
    }
    out.extend(fake.iter().map(|v| v.to_bits()));
    let eps: Vec<f32> = (0..4).map(|_| gman_core::rng::uniform(&mut rng)).collect();
    let mut s = [
        vec![0.0; d.disc_hidden],
        vec![0.0; d.disc_hidden],
        vec![0.0; d.disc_hidden],
        vec![0.0; d.disc_hidden],
        vec![0.0; d.feat],
        vec![0.0; d.feat],
    ];
    let [u, h, v, w1g, g, mix] = &mut s;
    let mut sc = DiscScratch {
        u,
        h,
        v,
        w1g,
        g,
        mix,
    };
    let ld = disc
        .ld_loss(&real, &fake, &eps, LdConfig::default(), &mut sc, None)
        .unwrap();
    out.extend([
        ld.loss.to_bits(),
        ld.penalty.to_bits(),
        ld.mean_real.to_bits(),
    ]);
    out
}

#[test]
fn same_inputs_and_seed_give_identical_bits() {
    let bytes = make_blob(&SMALL, &random_tensors(&SMALL, 9), true);
    let a = run_once(&bytes, 5);
    let b = run_once(&bytes, 5);
    let c = run_once(&bytes, 6);
    assert_eq!(a, b);
    assert_ne!(a, c);
}
