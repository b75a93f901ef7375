//! `Navigator::step_map_u8`: the map as the camera quantised it (u8 codes, one scale).
//! On the f32 path it gives the bits of `step_map` on the codes' f32 values; on the integer
//! path it quantises the codes in integers (its own results, which the QEMU parity test
//! checks against the Cortex-M4F); bad inputs are typed errors.

mod common;
use common::*;
use gman_core::blob::Blob;
use gman_core::navigator::memory::arena_len;
use gman_core::navigator::{Efficient, NavConfig, NavWeights, Navigator};
use gman_core::spec::schema::{FLAG_ADAPT, FLAG_INT8_ACTIVATIONS};
use gman_core::{Dims, Error};

const K: usize = 5;
const SCALE: f32 = 1.0 / 255.0;

fn codes(t: usize, n: usize) -> Vec<u8> {
    (0..n).map(|i| ((i * 37 + t * 11) % 256) as u8).collect()
}

/// The probabilities' bits of `steps` steps, with the map given as f32 values (`u8: false`)
/// or as codes.
fn run(bytes: &[u8], dims: &Dims, u8_map: bool, steps: usize) -> Vec<[u32; 6]> {
    let blob = Blob::parse(bytes).expect("parse");
    let w = NavWeights::from_blob(&blob, dims).expect("weights");
    let mut arena =
        vec![0.0f32; arena_len(dims, gman_core::navigator::memory::AdaptMode::Efficient, K)];
    let cfg = NavConfig::from_header(blob.header());
    let mut nav: Navigator<'_, Efficient, K> = Navigator::new(w, &mut arena, cfg).unwrap();
    nav.reset(&vec![0.3; dims.attr], 7).unwrap();
    let mut out = Vec::new();
    for t in 0..steps {
        let obs: Vec<f32> = (0..dims.feat).map(|i| ((i + t) % 9) as f32 / 9.0).collect();
        let q = codes(t, dims.map_len());
        let o = if u8_map {
            nav.step_map_u8(&obs, &q, SCALE, &[]).unwrap()
        } else {
            let m: Vec<f32> = q.iter().map(|&v| v as f32 * SCALE).collect();
            nav.step_map(&obs, &m, &[]).unwrap()
        };
        out.push(o.probs.map(f32::to_bits));
    }
    out
}

#[test]
fn f32_path_gives_the_bits_of_step_map_on_the_codes_values() {
    let dims = Dims::MCU.with_map(3, 3, 8);
    let bytes = seeded_blob(&dims, 4, true, FLAG_ADAPT);
    // Past an inner update (k = 5).
    assert_eq!(run(&bytes, &dims, true, 12), run(&bytes, &dims, false, 12));
}

#[test]
fn integer_path_reads_the_codes_and_reacts_to_them() {
    if !cfg!(feature = "int8-activations") {
        return; // (the integer path is compiled out)
    }
    let dims = Dims::MCU.with_map(3, 3, 8);
    let bytes = seeded_blob(&dims, 4, true, FLAG_ADAPT | FLAG_INT8_ACTIVATIONS);
    let a = run(&bytes, &dims, true, 12);
    assert_eq!(a, run(&bytes, &dims, true, 12), "deterministic");
    // Its own quantisation of the cells, in integers: `p_j = round(q_j 127 / max q)` and
    // `s_m = max q · scale / 127` are, but for rounding ties, what quantising the codes' f32
    // values gives, so the two paths agree closely (here to the bit).
    let f = run(&bytes, &dims, false, 12);
    for (x, y) in a.iter().zip(&f) {
        for (&p, &q) in x.iter().zip(y) {
            assert!((f32::from_bits(p) - f32::from_bits(q)).abs() < 0.05);
        }
    }
}

#[test]
fn integer_cell_layer_follows_its_formula() {
    if !cfg!(feature = "int8-activations") {
        return; // (the integer path is compiled out)
    }
    use gman_core::nn::matrix::{MatRef, Scales};
    // A 3 x 8 int8 matrix over [m; m ⊙ x] (f = 4), two cells; one cell all zero codes.
    let (rows, f) = (3usize, 4usize);
    let wf: Vec<f32> = (0..rows * 2 * f)
        .map(|i| ((i * 7) % 11) as f32 / 11.0 - 0.4)
        .collect();
    let mut q = vec![0u8; rows * 2 * f];
    let mut scales = vec![0.0f32; rows];
    gman_core::blob::quant::quantize_rows(&wf, rows, 2 * f, &mut q, &mut scales).unwrap();
    let w = MatRef::i8(rows, 2 * f, &q, Scales::F32(&scales))
        .unwrap()
        .with_int8_activations();
    let map = [10u8, 200, 255, 3, 0, 0, 0, 0];
    let x = [0.5f32, 0.25, 1.0, 0.0];
    let scale = 0.01f32;
    let mut out = [0.0f32; 6];
    gman_core::nn::qkernel::cell_layer_int8_u8(&w, &map, scale, &x, &mut out).unwrap();
    // The canonical computation written out for cell 0 (one block: f < QCOLS).
    let a = 255u32;
    let r = ((127u32 << 16) + a / 2) / a;
    let p: Vec<i32> = map[..f]
        .iter()
        .map(|&v| ((v as u32 * r + (1 << 15)) >> 16) as i32)
        .collect();
    let sm = (a as f32 * scale) / 127.0;
    let (sx, inv) = gman_core::nn::qkernel::act_scale(&x);
    let px: Vec<i32> = x
        .iter()
        .map(|&v| gman_core::nn::qkernel::quantize_one(v, inv))
        .collect();
    for i in 0..rows {
        let qi = |j: usize| q[i * 2 * f + j] as i8 as i32;
        let acc_m: i32 = (0..f).map(|j| qi(j) * p[j]).sum();
        let acc_p: i32 = (0..f).map(|j| qi(f + j) * (p[j] * px[j])).sum();
        let mut y = 0.0f32;
        y += acc_m as f32 * (sm * scales[i]);
        y += acc_p as f32 * ((sm * sx) * scales[i]);
        assert_eq!(out[i].to_bits(), y.to_bits(), "row {i}");
        assert_eq!(out[rows + i], 0.0, "a cell of zero codes adds nothing");
    }
}

#[test]
fn bad_map_input_is_a_typed_error() {
    let dims = Dims::MCU.with_map(3, 3, 8);
    let bytes = seeded_blob(&dims, 4, true, FLAG_ADAPT);
    let blob = Blob::parse(&bytes).unwrap();
    let w = NavWeights::from_blob(&blob, &dims).unwrap();
    let mut arena =
        vec![0.0f32; arena_len(&dims, gman_core::navigator::memory::AdaptMode::Efficient, K)];
    let cfg = NavConfig::from_header(blob.header());
    let mut nav: Navigator<'_, Efficient, K> = Navigator::new(w, &mut arena, cfg).unwrap();
    nav.reset(&vec![0.3; dims.attr], 7).unwrap();
    let obs = vec![0.5f32; dims.feat];
    let q = codes(0, dims.map_len());
    let e = nav.step_map_u8(&obs, &q, f32::NAN, &[]).unwrap_err();
    assert!(matches!(e, Error::NonFiniteInput { .. }), "{e:?}");
    let e = nav.step_map_u8(&obs, &q, 0.0, &[]).unwrap_err();
    assert!(matches!(e, Error::Config { .. }), "{e:?}");
    let e = nav.step_map_u8(&obs, &q[1..], SCALE, &[]).unwrap_err();
    assert!(matches!(e, Error::Shape(_)), "{e:?}");
    assert_eq!(nav.counters().steps, 0, "a refused step changes nothing");
    nav.step_map_u8(&obs, &q, SCALE, &[]).unwrap();
}
