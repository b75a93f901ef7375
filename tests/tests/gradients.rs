//! Finite-difference checks of every backward pass of gman-core against an independent f64
//! reference (`gman_tests::reference`): the core's analytic f32 gradients must match central
//! differences of the f64 reference within 1e-3 relative L2 error per tensor.

use gman_core::adapt::{adapt_generator_grad, AdaptLossKind, AdaptWork};
use gman_core::nets::discriminator::{DiscGrads, DiscScratch, Discriminator, LdConfig};
use gman_core::nets::generator::{Generator, GeneratorCache, GeneratorScratch};
use gman_core::nn::dense::{Dense, DenseGrads};
use gman_core::nn::lstm::{Lstm, LstmGrads};
use gman_core::nn::matrix::MatRef;
use gman_core::rng::{fill_gaussian, uniform, Xoshiro128};
use gman_tests::reference::*;

const TOL: f64 = 1e-3;
const H: f64 = 1e-6;

/// Random f32 values (kept as f32 so both sides see the same numbers).
fn rnd(rng: &mut Xoshiro128, n: usize, scale: f32) -> Vec<f32> {
    let mut v = vec![0.0f32; n];
    fill_gaussian(rng, &mut v);
    v.iter_mut().for_each(|x| *x *= scale);
    v
}

fn f64s(v: &[f32]) -> Vec<f64> {
    v.iter().map(|&x| x as f64).collect()
}

fn check(name: &str, analytic: &[f32], fd: &[f64]) {
    let e = rel_err(&f64s(analytic), fd, 1e-6);
    assert!(
        e < TOL,
        "{name}: relative error {e:.3e} (analytic {:?}.. fd {:?}..)",
        &analytic[..analytic.len().min(4)],
        &fd[..fd.len().min(4)]
    );
}

struct DenseP {
    rows: usize,
    cols: usize,
    w: Vec<f32>,
    b: Vec<f32>,
    gain: Option<Vec<f32>>,
}

impl DenseP {
    fn new(rng: &mut Xoshiro128, rows: usize, cols: usize, gain: bool) -> Self {
        DenseP {
            rows,
            cols,
            w: rnd(rng, rows * cols, 0.5),
            b: rnd(rng, rows, 0.3),
            gain: gain.then(|| rnd(rng, rows, 0.3).iter().map(|g| 1.0 + g).collect()),
        }
    }
    fn view(&self) -> Dense<'_> {
        Dense {
            w: MatRef::f32(self.rows, self.cols, &self.w).unwrap(),
            b: &self.b,
            gain: self.gain.as_deref(),
        }
    }
    fn r64(&self) -> Dense64 {
        Dense64 {
            rows: self.rows,
            cols: self.cols,
            w: f64s(&self.w),
            b: f64s(&self.b),
            gain: self.gain.as_ref().map(|g| f64s(g)),
        }
    }
}

/// Per-layer gradient buffers: (w, b) in full mode or (gain, b) in gain mode.
struct DG {
    a: Vec<f32>,
    b: Vec<f32>,
    gain_mode: bool,
}
impl DG {
    fn new(p: &DenseP, gain_mode: bool) -> Self {
        DG {
            a: vec![0.0; if gain_mode { p.rows } else { p.rows * p.cols }],
            b: vec![0.0; p.rows],
            gain_mode,
        }
    }
    fn grads(&mut self) -> DenseGrads<'_> {
        if self.gain_mode {
            DenseGrads::Gain {
                gain: &mut self.a,
                b: &mut self.b,
            }
        } else {
            DenseGrads::Full {
                w: &mut self.a,
                b: &mut self.b,
            }
        }
    }
}

#[test]
fn dense_backward_matches_finite_differences() {
    let mut rng = Xoshiro128::seed_from_u64(1);
    for gain_mode in [false, true] {
        let p = DenseP::new(&mut rng, 5, 7, gain_mode);
        let x1 = rnd(&mut rng, 3, 1.0);
        let x2 = rnd(&mut rng, 4, 1.0);
        let r = rnd(&mut rng, 5, 1.0);
        let (mut u, mut pre) = (vec![0.0; 5], vec![0.0; 5]);
        p.view().forward(&[&x1, &x2], &mut u, &mut pre).unwrap();
        let mut g = DG::new(&p, gain_mode);
        let (mut dx1, mut dx2) = (vec![0.0; 3], vec![0.0; 4]);
        let mut scratch = vec![0.0; 5];
        p.view()
            .backward(
                &[&x1, &x2],
                &u,
                &r,
                Some(&mut [&mut dx1, &mut dx2]),
                &mut g.grads(),
                &mut scratch,
            )
            .unwrap();
        let x: Vec<f64> = f64s(&x1).into_iter().chain(f64s(&x2)).collect();
        let r64 = f64s(&r);
        let base = p.r64();
        let loss = |d: &Dense64, x: &[f64]| {
            d.forward(x)
                .iter()
                .zip(&r64)
                .map(|(a, b)| a * b)
                .sum::<f64>()
        };
        check_dense("dense", &base, gain_mode, &g, |d| loss(&d, &x));
        let fd = finite_diff(&x, H, |v| loss(&base, v));
        let dx: Vec<f32> = dx1.iter().chain(&dx2).copied().collect();
        check("dense.x", &dx, &fd);
    }
}

#[test]
fn lstm_backward_matches_finite_differences() {
    let mut rng = Xoshiro128::seed_from_u64(2);
    let (inp, hd) = (5usize, 4usize);
    let wx = rnd(&mut rng, 4 * hd * inp, 0.5);
    let wh = rnd(&mut rng, 4 * hd * hd, 0.5);
    let b = rnd(&mut rng, 4 * hd, 0.3);
    let x = rnd(&mut rng, inp, 1.0);
    let h0 = rnd(&mut rng, hd, 0.5);
    let c0 = rnd(&mut rng, hd, 0.5);
    let rh = rnd(&mut rng, hd, 1.0);
    let rc = rnd(&mut rng, hd, 1.0);
    let cell = Lstm {
        wx: MatRef::f32(4 * hd, inp, &wx).unwrap(),
        wh: MatRef::f32(4 * hd, hd, &wh).unwrap(),
        b: &b,
    };
    let (mut gates, mut c, mut h) = (vec![0.0; 4 * hd], vec![0.0; hd], vec![0.0; hd]);
    cell.forward(&[&x], &h0, &c0, &mut gates, &mut c, &mut h)
        .unwrap();
    let r = Lstm64 {
        input: inp,
        hidden: hd,
        wx: f64s(&wx),
        wh: f64s(&wh),
        b: f64s(&b),
    };
    let (h64, c64) = r.step(&f64s(&x), &f64s(&h0), &f64s(&c0));
    assert!(rel_err(&f64s(&h), &h64, 1e-6) < 1e-5, "forward h");
    assert!(rel_err(&f64s(&c), &c64, 1e-6) < 1e-5, "forward c");
    let (mut gwx, mut gwh, mut gb) = (vec![0.0; wx.len()], vec![0.0; wh.len()], vec![0.0; b.len()]);
    let (mut dhp, mut dcp, mut dx, mut dg) = (
        vec![0.0; hd],
        vec![0.0; hd],
        vec![0.0; inp],
        vec![0.0; 4 * hd],
    );
    cell.backward(
        &[&x],
        &h0,
        &c0,
        &gates,
        &c,
        &rh,
        &rc,
        &mut dhp,
        &mut dcp,
        Some(&mut [&mut dx]),
        Some(LstmGrads {
            wx: &mut gwx,
            wh: &mut gwh,
            b: &mut gb,
        }),
        &mut dg,
    )
    .unwrap();
    let (rh, rc) = (f64s(&rh), f64s(&rc));
    let loss = |l: &Lstm64, x: &[f64], h: &[f64], c: &[f64]| {
        let (hn, cn) = l.step(x, h, c);
        hn.iter().zip(&rh).map(|(a, b)| a * b).sum::<f64>()
            + cn.iter().zip(&rc).map(|(a, b)| a * b).sum::<f64>()
    };
    let (x64, h064, c064) = (f64s(&x), f64s(&h0), f64s(&c0));
    check(
        "lstm.wx",
        &gwx,
        &finite_diff(&r.wx, H, |v| {
            loss(
                &Lstm64 {
                    wx: v.to_vec(),
                    ..r.clone()
                },
                &x64,
                &h064,
                &c064,
            )
        }),
    );
    check(
        "lstm.wh",
        &gwh,
        &finite_diff(&r.wh, H, |v| {
            loss(
                &Lstm64 {
                    wh: v.to_vec(),
                    ..r.clone()
                },
                &x64,
                &h064,
                &c064,
            )
        }),
    );
    check(
        "lstm.b",
        &gb,
        &finite_diff(&r.b, H, |v| {
            loss(
                &Lstm64 {
                    b: v.to_vec(),
                    ..r.clone()
                },
                &x64,
                &h064,
                &c064,
            )
        }),
    );
    check(
        "lstm.x",
        &dx,
        &finite_diff(&x64, H, |v| loss(&r, v, &h064, &c064)),
    );
    check(
        "lstm.h_prev",
        &dhp,
        &finite_diff(&h064, H, |v| loss(&r, &x64, v, &c064)),
    );
    check(
        "lstm.c_prev",
        &dcp,
        &finite_diff(&c064, H, |v| loss(&r, &x64, &h064, v)),
    );
}

/// Small G and D used by the remaining checks.
struct Nets {
    z: usize,
    a: usize,
    h: usize,
    f: usize,
    dh: usize,
    g1: DenseP,
    g2: DenseP,
    d1: DenseP,
    w2: Vec<f32>,
    b2: f32,
}

impl Nets {
    fn new(seed: u64, gain: bool) -> Self {
        let mut rng = Xoshiro128::seed_from_u64(seed);
        let (z, a, h, f, dh) = (3, 4, 6, 5, 7);
        Nets {
            z,
            a,
            h,
            f,
            dh,
            g1: DenseP::new(&mut rng, h, z + a, gain),
            g2: DenseP::new(&mut rng, f, h, gain),
            d1: DenseP::new(&mut rng, dh, f, gain),
            w2: rnd(&mut rng, dh, 0.5),
            b2: 0.1,
        }
    }
    fn gen(&self) -> Generator<'_> {
        Generator {
            l1: self.g1.view(),
            l2: self.g2.view(),
        }
    }
    fn disc(&self) -> Discriminator<'_> {
        Discriminator {
            l1: self.d1.view(),
            w2: &self.w2,
            b2: self.b2,
        }
    }
    fn gen64(&self) -> Gen64 {
        Gen64 {
            l1: self.g1.r64(),
            l2: self.g2.r64(),
        }
    }
    fn disc64(&self) -> Disc64 {
        Disc64 {
            l1: self.d1.r64(),
            w2: f64s(&self.w2),
            b2: self.b2 as f64,
        }
    }
}

struct Bufs {
    v: Vec<Vec<f32>>,
}
impl Bufs {
    fn new(lens: &[usize]) -> Self {
        Bufs {
            v: lens.iter().map(|&n| vec![0.0; n]).collect(),
        }
    }
}

/// The buffers of an [`AdaptWork`] for `n`'s shapes and `k` steps (see [`adapt_work`]).
fn adapt_bufs(n: &Nets, k: usize) -> Bufs {
    let (h, f, dh) = (n.h, n.f, n.dh);
    Bufs::new(&[h, h, f, f, f, h, h, h.max(f), dh, dh, dh, dh, f, f, k, k, f])
}

/// `b` (made by [`adapt_bufs`]) as the L_ad gradient's workspace.
fn adapt_work(b: &mut Bufs) -> AdaptWork<'_> {
    let [u1, h1, u2, x, dpre2, dh1, dpre1, tmp, du, dhh, dv, dw1g, dg, dmix, d, dd, dx] =
        &mut b.v[..]
    else {
        unreachable!()
    };
    AdaptWork {
        gen: GeneratorCache { u1, h1, u2, x },
        gen_scratch: GeneratorScratch {
            dpre2,
            dh1,
            dpre1,
            tmp,
        },
        disc: DiscScratch {
            u: du,
            h: dhh,
            v: dv,
            w1g: dw1g,
            g: dg,
            mix: dmix,
        },
        d,
        dd,
        dx,
    }
}

/// `k` random six-action distributions, one after another.
fn random_probs(rng: &mut Xoshiro128, k: usize) -> Vec<f32> {
    let mut probs = vec![0.0f32; k * 6];
    for t in 0..k {
        let l = rnd(rng, 6, 1.0);
        gman_core::nn::activation::softmax(&l, &mut probs[t * 6..(t + 1) * 6]).unwrap();
    }
    probs
}

/// Checks G's analytic gradients `grads` (layers 1 and 2: the gains in gain mode, else the
/// weights, and the biases) against central differences of `loss` around `g64`.
fn check_generator_grads(
    name: &str,
    g64: &Gen64,
    gain: bool,
    grads: [&DG; 2],
    loss: impl Fn(&Gen64) -> f64,
) {
    for (layer, gr) in [(1, grads[0]), (2, grads[1])] {
        let base = if layer == 1 { &g64.l1 } else { &g64.l2 };
        check_dense(&format!("{name}.l{layer}"), base, gain, gr, |d| {
            let mut g = g64.clone();
            if layer == 1 {
                g.l1 = d
            } else {
                g.l2 = d
            }
            loss(&g)
        });
    }
}

/// Checks a dense layer's analytic gradient `gr` (its gains in gain mode, else its weights,
/// and its biases) against central differences of `loss` as a function of the layer.
fn check_dense(name: &str, base: &Dense64, gain: bool, gr: &DG, loss: impl Fn(Dense64) -> f64) {
    let fd_a = if gain {
        finite_diff(base.gain.as_ref().unwrap(), H, |v| {
            loss(Dense64 {
                gain: Some(v.to_vec()),
                ..base.clone()
            })
        })
    } else {
        finite_diff(&base.w, H, |v| {
            loss(Dense64 {
                w: v.to_vec(),
                ..base.clone()
            })
        })
    };
    let a = if gain { "gain" } else { "w" };
    check(&format!("{name}.{a}"), &gr.a, &fd_a);
    let fd_b = finite_diff(&base.b, H, |v| {
        loss(Dense64 {
            b: v.to_vec(),
            ..base.clone()
        })
    });
    check(&format!("{name}.b"), &gr.b, &fd_b);
}

#[test]
fn generator_backward_matches_finite_differences() {
    for gain in [false, true] {
        let n = Nets::new(3, gain);
        let mut rng = Xoshiro128::seed_from_u64(33);
        let z = rnd(&mut rng, n.z, 1.0);
        let attr = rnd(&mut rng, n.a, 1.0);
        let r = rnd(&mut rng, n.f, 1.0);
        let mut b = Bufs::new(&[n.h, n.h, n.f, n.f, n.f, n.h, n.h, n.h.max(n.f)]);
        let [u1, h1, u2, x, dpre2, dh1, dpre1, tmp] = &mut b.v[..] else {
            unreachable!()
        };
        let mut cache = GeneratorCache { u1, h1, u2, x };
        n.gen().forward(&z, &attr, &mut cache).unwrap();
        let g64 = n.gen64();
        let x64 = g64.forward(&f64s(&z), &f64s(&attr));
        assert!(rel_err(&f64s(cache.x), &x64, 1e-6) < 1e-5);
        let mut gr1 = DG::new(&n.g1, gain);
        let mut gr2 = DG::new(&n.g2, gain);
        let mut s = GeneratorScratch {
            dpre2,
            dh1,
            dpre1,
            tmp,
        };
        n.gen()
            .backward(
                &z,
                &attr,
                &cache,
                &r,
                &mut gr1.grads(),
                &mut gr2.grads(),
                &mut s,
            )
            .unwrap();
        let (z64, a64, r64) = (f64s(&z), f64s(&attr), f64s(&r));
        let loss = |g: &Gen64| {
            g.forward(&z64, &a64)
                .iter()
                .zip(&r64)
                .map(|(a, b)| a * b)
                .sum::<f64>()
        };
        check_generator_grads("gen", &g64, gain, [&gr1, &gr2], loss);
    }
}

fn disc_scratch(b: &mut Bufs) -> DiscScratch<'_> {
    let [u, h, v, w1g, g, mix] = &mut b.v[..] else {
        unreachable!()
    };
    DiscScratch {
        u,
        h,
        v,
        w1g,
        g,
        mix,
    }
}

#[test]
fn discriminator_ld_with_gradient_penalty_matches_finite_differences() {
    for (gain, cs) in [(false, 1.0f32), (true, 1.0), (false, 10.0)] {
        let n = Nets::new(4, gain);
        let k = 4;
        let mut rng = Xoshiro128::seed_from_u64(44);
        let real: Vec<f32> = rnd(&mut rng, k * n.f, 1.0);
        let fake: Vec<f32> = rnd(&mut rng, k * n.f, 1.0);
        let eps: Vec<f32> = (0..k).map(|_| uniform(&mut rng)).collect();
        let cfg = LdConfig {
            lambda: 10.0,
            critic_scale: cs,
        };
        let mut b = Bufs::new(&[n.dh, n.dh, n.dh, n.dh, n.f, n.f]);
        let mut s = disc_scratch(&mut b);
        let mut g1 = DG::new(&n.d1, gain);
        let (mut gw2, mut gb2) = (vec![0.0; n.dh], 0.0f32);
        let val = {
            let mut grads = DiscGrads {
                l1: g1.grads(),
                w2: &mut gw2,
                b2: &mut gb2,
            };
            n.disc()
                .ld_loss(&real, &fake, &eps, cfg, &mut s, Some(&mut grads))
                .unwrap()
        };
        let d64 = n.disc64();
        let (r64, f64_, e64) = (f64s(&real), f64s(&fake), f64s(&eps));
        let ld = |d: &Disc64| d.ld(&r64, &f64_, &e64, 10.0, cs as f64);
        assert!(
            (val.loss as f64 - ld(&d64)).abs() < 1e-4 * (1.0 + ld(&d64).abs()),
            "L_D value"
        );
        assert!(val.penalty > 0.0);
        check_dense("ld.l1", &d64.l1, gain, &g1, |l1| {
            ld(&Disc64 { l1, ..d64.clone() })
        });
        let fd_w2 = finite_diff(&d64.w2, H, |v| {
            ld(&Disc64 {
                w2: v.to_vec(),
                ..d64.clone()
            })
        });
        check("ld.w2", &gw2, &fd_w2);
        let fd_b2 = finite_diff(&[d64.b2], H, |v| {
            ld(&Disc64 {
                b2: v[0],
                ..d64.clone()
            })
        });
        check("ld.b2", &[gb2], &fd_b2);
    }
}

#[test]
fn lg_input_gradient_matches_finite_differences() {
    let n = Nets::new(5, false);
    let mut rng = Xoshiro128::seed_from_u64(55);
    let fake = rnd(&mut rng, 3 * n.f, 1.0);
    let mut b = Bufs::new(&[n.dh, n.dh, n.dh, n.dh, n.f, n.f]);
    let mut s = disc_scratch(&mut b);
    let mut dfake = vec![0.0; fake.len()];
    let lg = n
        .disc()
        .lg_loss(&fake, 3, &mut s, Some(&mut dfake))
        .unwrap();
    let d64 = n.disc64();
    let f = n.f;
    let lg64 = |x: &[f64]| {
        -(0..3)
            .map(|t| d64.score(&x[t * f..(t + 1) * f]))
            .sum::<f64>()
            / 3.0
    };
    assert!((lg as f64 - lg64(&f64s(&fake))).abs() < 1e-5);
    check("lg.x", &dfake, &finite_diff(&f64s(&fake), H, lg64));
}

#[test]
fn adaptation_loss_gradients_match_finite_differences() {
    for (gain, kind, same_noise) in [
        (false, AdaptLossKind::Paper, false),
        (true, AdaptLossKind::Paper, false),
        (false, AdaptLossKind::Reference, false),
        (true, AdaptLossKind::Reference, true),
        (false, AdaptLossKind::Paper, true),
    ] {
        let n = Nets::new(6, gain);
        let k = 5;
        let mut rng = Xoshiro128::seed_from_u64(66);
        let attr = rnd(&mut rng, n.a, 1.0);
        let zs = if same_noise {
            rnd(&mut rng, n.z, 1.0).repeat(k)
        } else {
            rnd(&mut rng, k * n.z, 1.0)
        };
        let probs = random_probs(&mut rng, k);
        let mut b = adapt_bufs(&n, k);
        let mut w = adapt_work(&mut b);
        let mut gr1 = DG::new(&n.g1, gain);
        let mut gr2 = DG::new(&n.g2, gain);
        let mut dprobs = vec![0.0f32; k * 6];
        let loss = adapt_generator_grad(
            kind,
            &n.gen(),
            &n.disc(),
            &attr,
            &zs,
            &probs,
            &mut w,
            &mut gr1.grads(),
            &mut gr2.grads(),
            &mut dprobs,
        )
        .unwrap();
        let (g64, d64) = (n.gen64(), n.disc64());
        let (a64, z64, p64) = (f64s(&attr), f64s(&zs), f64s(&probs));
        let paper = kind == AdaptLossKind::Paper;
        let total = |g: &Gen64, p: &[f64]| {
            let d: Vec<f64> = (0..k)
                .map(|t| d64.score(&g.forward(&z64[t * n.z..(t + 1) * n.z], &a64)))
                .collect();
            adapt_loss(paper, &d, p)
        };
        assert!(
            (loss as f64 - total(&g64, &p64)).abs() < 1e-5 * (1.0 + loss.abs() as f64),
            "L_ad value"
        );
        check(
            "ladapt.probs",
            &dprobs,
            &finite_diff(&p64, H, |v| total(&g64, v)),
        );
        check_generator_grads(
            &format!("ladapt.gen ({kind:?}, gain={gain}, same={same_noise})"),
            &g64,
            gain,
            [&gr1, &gr2],
            |g| total(g, &p64),
        );
    }
}

/// The CosSim EMD variant: L_ad with cos(x_t, s_t) in place of D(x_t).
#[test]
fn cossim_adaptation_gradients_match_finite_differences() {
    use gman_core::adapt::adapt_generator_grad_cos;
    for (gain, kind) in [
        (false, AdaptLossKind::Paper),
        (true, AdaptLossKind::Reference),
    ] {
        let n = Nets::new(7, gain);
        let k = 4;
        let mut rng = Xoshiro128::seed_from_u64(77);
        let attr = rnd(&mut rng, n.a, 1.0);
        let zs = rnd(&mut rng, k * n.z, 1.0);
        let obs: Vec<f32> = (0..k * n.f).map(|_| uniform(&mut rng)).collect();
        let probs = random_probs(&mut rng, k);
        let mut b = adapt_bufs(&n, k);
        let mut w = adapt_work(&mut b);
        let mut gr1 = DG::new(&n.g1, gain);
        let mut gr2 = DG::new(&n.g2, gain);
        let mut dprobs = vec![0.0f32; k * 6];
        let loss = adapt_generator_grad_cos(
            kind,
            &n.gen(),
            &attr,
            &zs,
            &obs,
            &probs,
            &mut w,
            &mut gr1.grads(),
            &mut gr2.grads(),
            &mut dprobs,
        )
        .unwrap();
        let g64 = n.gen64();
        let (a64, z64, o64, p64) = (f64s(&attr), f64s(&zs), f64s(&obs), f64s(&probs));
        let paper = kind == AdaptLossKind::Paper;
        let total = |g: &Gen64, p: &[f64]| {
            let d: Vec<f64> = (0..k)
                .map(|t| {
                    let x = g.forward(&z64[t * n.z..(t + 1) * n.z], &a64);
                    let s = &o64[t * n.f..(t + 1) * n.f];
                    let dot: f64 = x.iter().zip(s).map(|(a, b)| a * b).sum();
                    dot / (x.iter().map(|v| v * v).sum::<f64>().sqrt()
                        * s.iter().map(|v| v * v).sum::<f64>().sqrt())
                })
                .collect();
            adapt_loss(paper, &d, p)
        };
        assert!((loss as f64 - total(&g64, &p64)).abs() < 1e-5 * (1.0 + loss.abs() as f64));
        check(
            "cossim.probs",
            &dprobs,
            &finite_diff(&p64, H, |v| total(&g64, v)),
        );
        check_generator_grads(
            &format!("cossim.gen ({kind:?}, gain={gain})"),
            &g64,
            gain,
            [&gr1, &gr2],
            |g| total(g, &p64),
        );
    }
}
