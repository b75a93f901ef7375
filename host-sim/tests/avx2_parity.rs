//! The AVX2 build of gman-core's kernels (`gman_host_sim::simd`) gives the same bits as the
//! portable (SSE2 / Cortex-M4F) build: every kernel on many shapes, and whole navigator
//! episodes (steps and inner updates, both adaptation modes, f32 and int8 weights).
//! Skipped with a message on a CPU without AVX2.

use gman_core::blob::quant::quantize_rows;
use gman_core::blob::{encode, encoded_len_bound, Blob, TensorData, TensorId, TensorSpec};
use gman_core::navigator::{Efficient, Full, Mode, NavConfig, NavWeights, Navigator};
use gman_core::nn::batch::{matmul_acc, matmul_t_acc, outer_acc_batch_with, Kernels};
use gman_core::nn::matrix::{MatRef, Scales};
use gman_core::rng::{fill_gaussian, Xoshiro128};
use gman_core::spec::ModelSpec;
use gman_core::Dims;

fn avx2_or_skip() -> Option<&'static dyn Kernels> {
    let k = gman_host_sim::simd::avx2();
    if k.is_none() {
        eprintln!("SKIPPED: this CPU has no AVX2; the AVX2 kernels cannot run here");
    }
    k
}

fn randv(rng: &mut Xoshiro128, n: usize) -> Vec<f32> {
    let mut v = vec![0.0f32; n];
    fill_gaussian(rng, &mut v);
    v
}

fn bits(v: &[f32]) -> Vec<u32> {
    v.iter().map(|x| x.to_bits()).collect()
}

#[test]
fn every_kernel_gives_the_same_bits_with_and_without_avx2() {
    let Some(k) = avx2_or_skip() else { return };
    let mut rng = Xoshiro128::seed_from_u64(5);
    let shapes: &[(usize, &[usize], usize)] = &[
        (1, &[1], 1),
        (6, &[64], 1),
        (13, &[45, 45], 1),
        (17, &[7, 33, 0, 90], 3),
        (64, &[512], 20),
        (256, &[90], 20),
        (9, &[100, 9], 7),
        (33, &[24], 5),
        // The AVX2 matmul's tiles (8 x 1, 2 x 4) and their remainders.
        (5, &[64, 64], 4),
        (257, &[45, 45], 16),
        (64, &[512, 512, 512, 45, 6], 9),
        (3, &[5], 6),
        (11, &[8, 16], 2),
        (19, &[3, 64, 1], 1),
    ];
    for &(r, lens, n) in shapes {
        let c: usize = lens.iter().sum();
        let wv = randv(&mut rng, r * c);
        let le: Vec<u8> = wv.iter().flat_map(|v| v.to_le_bytes()).collect();
        let (mut q, mut s) = (vec![0u8; r * c], vec![0.0f32; r]);
        quantize_rows(&wv, r, c, &mut q, &mut s).unwrap();
        let sle: Vec<u8> = s.iter().flat_map(|v| v.to_le_bytes()).collect();
        let mats = [
            MatRef::f32(r, c, &wv).unwrap(),
            MatRef::f32_le(r, c, &le).unwrap(),
            MatRef::i8(r, c, &q, Scales::F32(&s)).unwrap(),
            MatRef::i8(r, c, &q, Scales::Le(&sle)).unwrap(),
        ];
        let xs: Vec<Vec<f32>> = lens.iter().map(|&l| randv(&mut rng, n * l)).collect();
        let segs: Vec<&[f32]> = xs.iter().map(|v| v.as_slice()).collect();
        let mut dy = randv(&mut rng, n * r);
        dy[0] = 0.0;
        for m in &mats {
            let y0 = randv(&mut rng, n * r);
            let (mut ya, mut yb) = (y0.clone(), y0.clone());
            matmul_acc(m, &segs, lens, n, &mut ya).unwrap();
            matmul_acc(&m.with_kernels(k), &segs, lens, n, &mut yb).unwrap();
            assert_eq!(bits(&ya), bits(&yb), "matmul {r}x{lens:?} n={n}");
            if n == 1 {
                let (mut va, mut vb) = (y0.clone(), y0.clone());
                m.matvec_acc(&segs, &mut va).unwrap();
                m.with_kernels(k).matvec_acc(&segs, &mut vb).unwrap();
                assert_eq!(bits(&va), bits(&vb), "matvec {r}x{lens:?}");
                assert_eq!(bits(&va), bits(&ya), "matvec vs matmul n=1");
            }
            let dx0: Vec<Vec<f32>> = lens.iter().map(|&l| randv(&mut rng, n * l)).collect();
            let (mut da, mut db) = (dx0.clone(), dx0.clone());
            {
                let mut pa: Vec<&mut [f32]> = da.iter_mut().map(|v| v.as_mut_slice()).collect();
                matmul_t_acc(m, &dy, n, &mut pa, lens).unwrap();
                let mut pb: Vec<&mut [f32]> = db.iter_mut().map(|v| v.as_mut_slice()).collect();
                matmul_t_acc(&m.with_kernels(k), &dy, n, &mut pb, lens).unwrap();
            }
            assert_eq!(da, db, "matmul_t {r}x{lens:?} n={n}");
            for (a, b) in da.iter().zip(&db) {
                assert_eq!(bits(a), bits(b));
            }
        }
        let dw0 = randv(&mut rng, r * c);
        let (mut wa, mut wb) = (dw0.clone(), dw0);
        outer_acc_batch_with(None, &mut wa, &dy, &segs, lens, n, 0.3).unwrap();
        outer_acc_batch_with(Some(k), &mut wb, &dy, &segs, lens, n, 0.3).unwrap();
        assert_eq!(bits(&wa), bits(&wb), "outer {r}x{lens:?} n={n}");
    }
}

/// Infinities and a NaN reach `y` in the same bits with and without AVX2 (one NaN source,
/// so that the result does not hang on which NaN operand an addition keeps).
#[test]
fn non_finite_values_give_the_same_bits_with_and_without_avx2() {
    let Some(k) = avx2_or_skip() else { return };
    let mut rng = Xoshiro128::seed_from_u64(9);
    for (r, lens, n) in [
        (6usize, [19usize, 64], 4usize),
        (9, [45, 45], 1),
        (4, [8, 3], 5),
    ] {
        let c: usize = lens.iter().sum();
        let mut wv = randv(&mut rng, r * c);
        wv[5] = f32::INFINITY;
        wv[c + 30 % c] = f32::NAN;
        let w = MatRef::f32(r, c, &wv).unwrap();
        let mut xs: Vec<Vec<f32>> = lens.iter().map(|&l| randv(&mut rng, n * l)).collect();
        xs[1][(n - 1) * lens[1] + 2] = f32::NEG_INFINITY;
        xs[0][1] = -0.0;
        let segs: Vec<&[f32]> = xs.iter().map(|v| v.as_slice()).collect();
        let y0 = randv(&mut rng, n * r);
        let (mut ya, mut yb) = (y0.clone(), y0);
        matmul_acc(&w, &segs, &lens, n, &mut ya).unwrap();
        matmul_acc(&w.with_kernels(k), &segs, &lens, n, &mut yb).unwrap();
        assert_eq!(bits(&ya), bits(&yb), "matmul {r}x{lens:?} n={n}");
        assert!(ya.iter().any(|v| v.is_nan()), "the NaN reaches y");
        assert!(ya.iter().any(|v| v.is_infinite()), "an infinity reaches y");
    }
}

const K: usize = 20;

/// A tensor in f32 and int8 (values, per-row scales).
type Quantised = (TensorId, Vec<f32>, Vec<u8>, Vec<f32>);

fn blob(d: &Dims, int8: bool) -> Vec<u8> {
    let mut rng = Xoshiro128::seed_from_u64(9);
    let t: Vec<Quantised> = TensorId::all_for(d)
        .map(|id| {
            let (r, c) = id.shape(d);
            let mut v = randv(&mut rng, r * c);
            v.iter_mut().for_each(|x| *x *= 0.05);
            let (mut q, mut s) = (vec![0u8; r * c], vec![0.0f32; r]);
            quantize_rows(&v, r, c, &mut q, &mut s).unwrap();
            (id, v, q, s)
        })
        .collect();
    let specs: Vec<TensorSpec<'_>> = t
        .iter()
        .map(|(id, v, q, s)| TensorSpec {
            id: *id,
            data: if int8 && !id.is_vector() {
                TensorData::I8 { q, scales: s }
            } else {
                TensorData::F32(v)
            },
        })
        .collect();
    let mut buf = vec![0u8; encoded_len_bound(&specs)];
    let n = encode(d, &specs, &mut buf).unwrap();
    buf.truncate(n);
    buf
}

/// Every output bit of a 45-step episode (two inner updates and five extra steps).
fn episode<M: Mode>(bytes: &[u8], k: Option<&'static dyn Kernels>) -> Vec<u32> {
    let d = Dims::MCU;
    let b = Blob::parse(bytes).unwrap();
    let mut w = NavWeights::from_blob(&b, &d).unwrap();
    if let Some(k) = k {
        w = w.with_kernels(k);
    }
    let mut arena = vec![0.0f32; Navigator::<M, K>::arena_len(&d)];
    let cfg = NavConfig {
        model: ModelSpec {
            adapt: true,
            ..NavConfig::default().model
        },
        ..NavConfig::default()
    };
    let mut nav: Navigator<'_, M, K> = Navigator::new(w, &mut arena, cfg).unwrap();
    nav.reset(&vec![0.5f32; d.attr], 3).unwrap();
    let mut rng = Xoshiro128::seed_from_u64(4);
    let mut out = Vec::new();
    for _ in 0..45 {
        let mut o = randv(&mut rng, d.feat);
        o.iter_mut().for_each(|v| *v = v.abs().min(1.0));
        let s = nav.step(&o, &[]).unwrap();
        out.extend(bits(&s.probs));
        out.push(s.value.to_bits());
        out.extend(bits(nav.generated_feature()));
        out.extend(bits(nav.hidden_state()));
        let a = nav.last_adaptation();
        out.extend([
            a.adapt_loss.to_bits(),
            a.ld.loss.to_bits(),
            a.ld.penalty.to_bits(),
        ]);
    }
    assert_eq!(nav.counters().adaptations, 2);
    out
}

#[test]
fn navigator_episodes_give_the_same_bits_with_and_without_avx2() {
    let Some(k) = avx2_or_skip() else { return };
    for int8 in [false, true] {
        let bytes = blob(&Dims::MCU, int8);
        assert_eq!(
            episode::<Full>(&bytes, None),
            episode::<Full>(&bytes, Some(k)),
            "Full int8={int8}"
        );
        assert_eq!(
            episode::<Efficient>(&bytes, None),
            episode::<Efficient>(&bytes, Some(k)),
            "Efficient int8={int8}"
        );
    }
}
