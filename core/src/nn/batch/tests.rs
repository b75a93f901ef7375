//! The batched kernels against a plain transcription of the canonical order, bit for bit.

use super::outer_acc;
use super::*;
use crate::nn::matrix::MatRef;
use crate::nn::matrix::Scales;

fn vals(n: usize, seed: u32) -> [f32; 512] {
    let mut out = [0.0f32; 512];
    let mut s = seed.wrapping_mul(2654435761).wrapping_add(1);
    for v in out.iter_mut().take(n) {
        s ^= s << 13;
        s ^= s >> 17;
        s ^= s << 5;
        *v = (s % 2001) as f32 / 1000.0 - 1.0;
    }
    out
}

// W is 5 x 11 (segments 3 + 8), batch of 4.
const R: usize = 5;
const C: usize = 11;
const N: usize = 4;

#[test]
fn matmul_matches_matvec_bit_for_bit() {
    let wv = vals(R * C, 1);
    let w = MatRef::f32(R, C, &wv[..R * C]).unwrap();
    let a = vals(N * 3, 2);
    let b = vals(N * 8, 3);
    let mut y = vals(N * R, 4);
    let y0 = y;
    matmul_acc(&w, &[&a[..N * 3], &b[..N * 8]], &[3, 8], N, &mut y[..N * R]).unwrap();
    for k in 0..N {
        let mut yk = [0.0f32; R];
        yk.copy_from_slice(&y0[k * R..(k + 1) * R]);
        w.matvec_acc(&[&a[k * 3..k * 3 + 3], &b[k * 8..k * 8 + 8]], &mut yk)
            .unwrap();
        for r in 0..R {
            assert_eq!(y[k * R + r].to_bits(), yk[r].to_bits());
        }
    }
}

#[test]
fn matmul_t_matches_matvec_t_bit_for_bit() {
    let wv = vals(R * C, 5);
    let w = MatRef::f32(R, C, &wv[..R * C]).unwrap();
    let dy = vals(N * R, 6);
    let mut da = vals(N * 3, 7);
    let mut db = vals(N * 8, 8);
    let (da0, db0) = (da, db);
    {
        let (sa, sb) = (&mut da[..N * 3], &mut db[..N * 8]);
        matmul_t_acc(&w, &dy[..N * R], N, &mut [sa, sb], &[3, 8]).unwrap();
    }
    for k in 0..N {
        let mut ea = [0.0f32; 3];
        let mut eb = [0.0f32; 8];
        ea.copy_from_slice(&da0[k * 3..k * 3 + 3]);
        eb.copy_from_slice(&db0[k * 8..k * 8 + 8]);
        w.matvec_t_acc(&dy[k * R..(k + 1) * R], &mut [&mut ea, &mut eb])
            .unwrap();
        for i in 0..3 {
            assert_eq!(da[k * 3 + i].to_bits(), ea[i].to_bits());
        }
        for i in 0..8 {
            assert_eq!(db[k * 8 + i].to_bits(), eb[i].to_bits());
        }
    }
}

#[test]
fn outer_batch_matches_sequential_outer() {
    let dy = vals(N * R, 9);
    let a = vals(N * 3, 10);
    let b = vals(N * 8, 11);
    let mut dw = vals(R * C, 12);
    let mut want = dw;
    outer_acc_batch(
        &mut dw[..R * C],
        &dy[..N * R],
        &[&a[..N * 3], &b[..N * 8]],
        &[3, 8],
        N,
        0.5,
    )
    .unwrap();
    for k in 0..N {
        outer_acc(
            &mut want[..R * C],
            &dy[k * R..(k + 1) * R],
            &[&a[k * 3..k * 3 + 3], &b[k * 8..k * 8 + 8]],
            0.5,
        )
        .unwrap();
    }
    for i in 0..R * C {
        assert_eq!(dw[i].to_bits(), want[i].to_bits());
    }
}

#[test]
fn bad_shapes_are_errors() {
    let wv = vals(R * C, 1);
    let w = MatRef::f32(R, C, &wv[..R * C]).unwrap();
    let a = vals(N * 3, 2);
    let mut y = [0.0f32; N * R];
    // per-vector lengths that do not add up to cols
    assert!(matmul_acc(&w, &[&a[..N * 3]], &[3], N, &mut y).is_err());
    // a segment shorter than n * len
    assert!(matmul_acc(&w, &[&a[..N * 3], &a[..8]], &[3, 8], N, &mut y).is_err());
    // too many segments
    let many: [&[f32]; 9] = [&a[..N]; 9];
    assert!(matmul_acc(&w, &many, &[1; 9], N, &mut y).is_err());
}

// ---- against a plain transcription of the canonical order, every storage kind ----

/// The canonical `y += W x` of one vector, written out (no blocking).
fn ref_matvec(w: &MatRef<'_>, x: &[&[f32]], y: &mut [f32]) {
    use crate::nn::matrix::{dot, dot_i8, dot_le};
    if w.cols() == 0 {
        return;
    }
    for (i, yi) in y.iter_mut().enumerate() {
        let mut acc = 0.0f32;
        let mut off = 0;
        for seg in x {
            let l = seg.len();
            acc += match w.weights() {
                Weights::F32(d) => dot(&d[i * w.cols() + off..i * w.cols() + off + l], seg),
                Weights::F32Le(d) => dot_le(
                    &d[4 * (i * w.cols() + off)..4 * (i * w.cols() + off + l)],
                    seg,
                ),
                Weights::I8 { q, .. } => {
                    dot_i8(&q[i * w.cols() + off..i * w.cols() + off + l], seg)
                }
            };
            off += l;
        }
        match w.weights() {
            Weights::I8 { scales, .. } => *yi += acc * scales.get(i),
            _ => *yi += acc,
        }
    }
}

/// The canonical `dx += W[:, col0..]^T dy` of one vector.
fn ref_matvec_t(w: &MatRef<'_>, dy: &[f32], col0: usize, dx: &mut [f32]) {
    for (i, &g) in dy.iter().enumerate() {
        let c = match w.weights() {
            Weights::I8 { scales, .. } => g * scales.get(i),
            _ => g,
        };
        for (j, o) in dx.iter_mut().enumerate() {
            let wij = match w.weights() {
                Weights::I8 { q, .. } => q[i * w.cols() + col0 + j] as i8 as f32,
                _ => w.get(i, col0 + j),
            };
            *o += c * wij;
        }
    }
}

/// The canonical `dW += alpha dy x^T` of one vector.
fn ref_outer(dw: &mut [f32], dy: &[f32], x: &[f32], alpha: f32) {
    let cols = x.len();
    for (i, &g) in dy.iter().enumerate() {
        let a = alpha * g;
        if a == 0.0 {
            continue;
        }
        crate::nn::matrix::axpy(a, x, &mut dw[i * cols..(i + 1) * cols]);
    }
}

const BIG: usize = 4096;

fn big(n: usize, seed: u32) -> [f32; BIG] {
    let mut out = [0.0f32; BIG];
    out[..n.min(512)].copy_from_slice(&vals(n.min(512), seed)[..n.min(512)]);
    let mut s = seed.wrapping_mul(747796405).wrapping_add(3);
    for v in out.iter_mut().take(n).skip(512) {
        s ^= s << 13;
        s ^= s >> 17;
        s ^= s << 5;
        *v = (s % 4001) as f32 / 997.0 - 2.0;
    }
    // Special values the canonical order must treat identically.
    if n > 7 {
        out[1] = -0.0;
        out[3] = 0.0;
        out[n - 2] = 1.0e-39; // subnormal
    }
    out
}

/// Matrices of every kind over the same values: f32, little-endian f32, int8.
fn kinds<'a>(
    r: usize,
    c: usize,
    wv: &'a [f32],
    le: &'a mut [u8],
    q: &'a mut [u8],
    sc: &'a mut [f32],
) -> [MatRef<'a>; 3] {
    for (b, v) in le.chunks_exact_mut(4).zip(wv) {
        b.copy_from_slice(&v.to_le_bytes());
    }
    for (i, qv) in q.iter_mut().enumerate() {
        *qv = ((wv[i] * 60.0) as i32).clamp(-127, 127) as i8 as u8;
    }
    for (i, s) in sc.iter_mut().enumerate() {
        *s = 0.01 + i as f32 * 0.003;
    }
    [
        MatRef::f32(r, c, wv).unwrap(),
        MatRef::f32_le(r, c, le).unwrap(),
        MatRef::i8(r, c, q, Scales::F32(sc)).unwrap(),
    ]
}

/// Every kernel form (forward, transposed, outer product) against its batch-1 twin, bit
/// for bit, over every weight kind and a table of shapes with tails; long because it is
/// one loop over that table with one comparison per form, kept together so a new form
/// cannot skip a shape.
#[test]
fn blocked_kernels_keep_the_canonical_order_for_every_kind_and_shape() {
    // (rows, segment lengths, batch) with tails, short segments, empty segments.
    let cases: &[(usize, &[usize], usize)] = &[
        (1, &[1], 1),
        (3, &[7], 5),
        (5, &[3, 8], 4),
        (6, &[64], 20),
        (7, &[45, 45], 3),
        (9, &[17, 0, 6, 33], 6),
        (4, &[0], 2),
        (2, &[100, 9], 9),
        // more rows than a block of `matmul_t_acc_rows`
        (70, &[13], 3),
    ];
    for (ci, &(r, lens, n)) in cases.iter().enumerate() {
        let c: usize = lens.iter().sum();
        let wv = big(r * c, 100 + ci as u32);
        let mut le = [0u8; 4 * 1024];
        let mut q = [0u8; 1024];
        let mut sc = [0.0f32; 128];
        let mats = kinds(
            r,
            c,
            &wv[..r * c],
            &mut le[..4 * r * c],
            &mut q[..r * c],
            &mut sc[..r],
        );
        let xs: [[f32; BIG]; 4] = core::array::from_fn(|s| big(n * 128, 200 + s as u32));
        let segs: [&[f32]; 4] =
            core::array::from_fn(|s| &xs[s][..n * lens.get(s).copied().unwrap_or(0)]);
        let segs = &segs[..lens.len()];
        let dy = {
            let mut d = big(n * r, 300 + ci as u32);
            d[0] = 0.0; // a skipped outer-product row
            d
        };
        for (mi, m) in mats.iter().enumerate() {
            // y += W x
            let y0 = big(n * r, 400);
            let mut y = y0;
            matmul_acc(m, segs, lens, n, &mut y[..n * r]).unwrap();
            let mut y2 = y0;
            matmul_acc_blocked::<3, 5>(m, segs, n, &mut y2[..n * r]).unwrap();
            // the Cortex-M4F's lane-blocked loops, run here on the host
            let mut y3 = y0;
            matmul_acc_lanes::<2, 2, 4>(m, segs, n, &mut y3[..n * r]).unwrap();
            let mut y4 = y0;
            matmul_acc_lanes::<3, 1, 8>(m, segs, n, &mut y4[..n * r]).unwrap();
            for b in 0..n {
                let mut want = [0.0f32; 128];
                want[..r].copy_from_slice(&y0[b * r..(b + 1) * r]);
                let mut one: [&[f32]; 4] = [&[]; 4];
                for (s, &l) in lens.iter().enumerate() {
                    one[s] = &segs[s][b * l..(b + 1) * l];
                }
                ref_matvec(m, &one[..lens.len()], &mut want[..r]);
                let mut mv = [0.0f32; 128];
                mv[..r].copy_from_slice(&y0[b * r..(b + 1) * r]);
                m.matvec_acc(&one[..lens.len()], &mut mv[..r]).unwrap();
                let mut mp = [0.0f32; 128];
                mp[..r].copy_from_slice(&y0[b * r..(b + 1) * r]);
                matvec_acc_pairs(m, &one[..lens.len()], &mut mp[..r]).unwrap();
                for i in 0..r {
                    let w = want[i].to_bits();
                    assert_eq!(
                        y[b * r + i].to_bits(),
                        w,
                        "matmul case {ci} kind {mi} b {b} i {i}"
                    );
                    assert_eq!(y2[b * r + i].to_bits(), w, "matmul 3x5 case {ci} kind {mi}");
                    assert_eq!(
                        y3[b * r + i].to_bits(),
                        w,
                        "lanes 2x2x4 case {ci} kind {mi}"
                    );
                    assert_eq!(
                        y4[b * r + i].to_bits(),
                        w,
                        "lanes 3x1x8 case {ci} kind {mi}"
                    );
                    assert_eq!(mv[i].to_bits(), w, "matvec case {ci} kind {mi}");
                    assert_eq!(mp[i].to_bits(), w, "matvec pairs case {ci} kind {mi}");
                }
            }
            // dx += W^T dy
            let mut dxs: [[f32; BIG]; 4] = core::array::from_fn(|s| big(n * 128, 500 + s as u32));
            let dx0 = dxs;
            {
                let [a, b2, c2, d2] = &mut dxs;
                let mut parts: [&mut [f32]; 4] = [
                    &mut a[..n * lens.first().copied().unwrap_or(0)],
                    &mut b2[..n * lens.get(1).copied().unwrap_or(0)],
                    &mut c2[..n * lens.get(2).copied().unwrap_or(0)],
                    &mut d2[..n * lens.get(3).copied().unwrap_or(0)],
                ];
                matmul_t_acc(m, &dy[..n * r], n, &mut parts[..lens.len()], lens).unwrap();
            }
            let mut dxs2 = dx0;
            {
                let [a, b2, c2, d2] = &mut dxs2;
                let mut parts: [&mut [f32]; 4] = [
                    &mut a[..n * lens.first().copied().unwrap_or(0)],
                    &mut b2[..n * lens.get(1).copied().unwrap_or(0)],
                    &mut c2[..n * lens.get(2).copied().unwrap_or(0)],
                    &mut d2[..n * lens.get(3).copied().unwrap_or(0)],
                ];
                matmul_t_acc_blocked::<3, 2>(m, &dy[..n * r], n, &mut parts[..lens.len()], 0)
                    .unwrap();
            }
            let mut dxs3 = dx0;
            let mut dxs4 = dx0;
            for (dd, two) in [(&mut dxs3, true), (&mut dxs4, false)] {
                let [a, b2, c2, d2] = dd;
                let mut parts: [&mut [f32]; 4] = [
                    &mut a[..n * lens.first().copied().unwrap_or(0)],
                    &mut b2[..n * lens.get(1).copied().unwrap_or(0)],
                    &mut c2[..n * lens.get(2).copied().unwrap_or(0)],
                    &mut d2[..n * lens.get(3).copied().unwrap_or(0)],
                ];
                let p = &mut parts[..lens.len()];
                if two {
                    matmul_t_acc_rows::<2>(m, &dy[..n * r], n, p, 0).unwrap();
                } else {
                    matmul_t_acc_rows::<1>(m, &dy[..n * r], n, p, 0).unwrap();
                }
            }
            let mut off = 0;
            for (s, &l) in lens.iter().enumerate() {
                for b in 0..n {
                    let mut want = [0.0f32; 128];
                    want[..l].copy_from_slice(&dx0[s][b * l..(b + 1) * l]);
                    ref_matvec_t(m, &dy[b * r..(b + 1) * r], off, &mut want[..l]);
                    for j in 0..l {
                        assert_eq!(
                            dxs[s][b * l + j].to_bits(),
                            want[j].to_bits(),
                            "matmul_t case {ci} kind {mi} seg {s}"
                        );
                        assert_eq!(
                            dxs2[s][b * l + j].to_bits(),
                            want[j].to_bits(),
                            "matmul_t 3x2 case {ci} kind {mi}"
                        );
                        assert_eq!(
                            dxs3[s][b * l + j].to_bits(),
                            want[j].to_bits(),
                            "matmul_t rows x2 case {ci} kind {mi}"
                        );
                        assert_eq!(
                            dxs4[s][b * l + j].to_bits(),
                            want[j].to_bits(),
                            "matmul_t rows x1 case {ci} kind {mi}"
                        );
                    }
                }
                off += l;
            }
        }
        // dW += alpha sum_b dy_b x_b^T
        let dw0 = big(r * c, 600 + ci as u32);
        let mut dw = dw0;
        outer_acc_batch(&mut dw[..r * c], &dy[..n * r], segs, lens, n, 0.75).unwrap();
        let mut dw2 = dw0;
        outer_acc_batch_blocked::<3, 2>(&mut dw2[..r * c], &dy[..n * r], segs, n, 0.75).unwrap();
        let mut want = dw0;
        for b in 0..n {
            let mut xb = [0.0f32; 512];
            let mut off = 0;
            for (s, &l) in lens.iter().enumerate() {
                xb[off..off + l].copy_from_slice(&segs[s][b * l..(b + 1) * l]);
                off += l;
            }
            ref_outer(&mut want[..r * c], &dy[b * r..(b + 1) * r], &xb[..c], 0.75);
        }
        for i in 0..r * c {
            assert_eq!(
                dw[i].to_bits(),
                want[i].to_bits(),
                "outer case {ci} elem {i}"
            );
            assert_eq!(dw2[i].to_bits(), want[i].to_bits(), "outer 3x2 case {ci}");
        }
    }
}

#[test]
fn non_finite_values_propagate_exactly_as_the_canonical_order() {
    let (r, c, n) = (3, 19, 4);
    let mut wv = big(r * c, 7);
    wv[5] = f32::INFINITY;
    wv[30] = f32::NAN;
    let w = MatRef::f32(r, c, &wv[..r * c]).unwrap();
    let mut x = big(n * c, 8);
    x[c + 2] = f32::NEG_INFINITY;
    let mut y = [0.0f32; 12];
    matmul_acc(&w, &[&x[..n * c]], &[c], n, &mut y).unwrap();
    for b in 0..n {
        let mut want = [0.0f32; 3];
        ref_matvec(&w, &[&x[b * c..(b + 1) * c]], &mut want);
        for i in 0..r {
            assert_eq!(y[b * r + i].to_bits(), want[i].to_bits());
        }
    }
    assert!(y.iter().any(|v| v.is_nan()), "the NaN weight reaches y");
}
