//! The batched inner update (`gman_core::adapt::inner`) against the batch-1 functions it replaces in
//! the navigator, bit for bit, for every batch size: `inner::generate` against
//! `Generator::forward` per entry, `inner::ld_grad_sum` against `Discriminator::ld_loss` on one
//! entry at a time (the navigator's former loop), `inner::adapt_grad` against
//! `adapt::adapt_generator_grad` and `adapt::adapt_generator_grad_cos`. Covered: f32 weights
//! with full gradients (the `Full` mode) and int8 weights with gains (`Efficient`), distinct
//! and repeated noise (consecutive identical noise vectors share one pass of G), both forms of
//! L_ad, batch sizes 1, 2, 3, n and more than n.

mod common;
use before::{adapt_generator_grad, adapt_generator_grad_cos};
use common::vals;
use gman_core::adapt::inner::{self, InnerWork};
use gman_core::adapt::{AdaptLossKind, AdaptWork};
use gman_core::nets::discriminator::{DiscGrads, DiscScratch, Discriminator, LdConfig, LdValue};
use gman_core::nets::generator::{Generator, GeneratorCache, GeneratorScratch};
use gman_core::nn::dense::{Dense, DenseGrads};
use gman_core::nn::matrix::{MatRef, Scales};
use gman_core::NUM_ACTIONS;

const Z: usize = 11;
const A: usize = 6;
const H: usize = 19;
const F: usize = 21;
const DH: usize = 13;
const N: usize = 7;

/// One layer's storage: f32 values, their int8 quantisation, scales, bias and gain.
struct Layer {
    w: Vec<f32>,
    q: Vec<u8>,
    s: Vec<f32>,
    b: Vec<f32>,
    g: Vec<f32>,
    rows: usize,
    cols: usize,
}

impl Layer {
    fn new(rows: usize, cols: usize, seed: u32) -> Layer {
        Layer {
            w: vals(rows * cols, seed).iter().map(|v| v * 0.6).collect(),
            q: vals(rows * cols, seed + 1)
                .iter()
                .map(|v| ((v * 120.0) as i8) as u8)
                .collect(),
            s: vals(rows, seed + 2)
                .iter()
                .map(|v| 0.004 + v.abs() * 0.004)
                .collect(),
            b: vals(rows, seed + 3).iter().map(|v| v * 0.2).collect(),
            g: vals(rows, seed + 4).iter().map(|v| 1.0 + v * 0.3).collect(),
            rows,
            cols,
        }
    }

    fn view(&self, efficient: bool) -> Dense<'_> {
        if efficient {
            Dense {
                w: MatRef::i8(self.rows, self.cols, &self.q, Scales::F32(&self.s)).unwrap(),
                b: &self.b,
                gain: Some(&self.g),
            }
        } else {
            Dense {
                w: MatRef::f32(self.rows, self.cols, &self.w).unwrap(),
                b: &self.b,
                gain: None,
            }
        }
    }
}

/// Gradient buffers of one layer (`a` is dW or dgain).
struct Grad {
    a: Vec<f32>,
    b: Vec<f32>,
    full: bool,
}

impl Grad {
    fn new(l: &Layer, efficient: bool) -> Grad {
        Grad {
            a: vec![0.0; if efficient { l.rows } else { l.rows * l.cols }],
            b: vec![0.0; l.rows],
            full: !efficient,
        }
    }
    fn grads(&mut self) -> DenseGrads<'_> {
        if self.full {
            DenseGrads::Full {
                w: &mut self.a,
                b: &mut self.b,
            }
        } else {
            DenseGrads::Gain {
                gain: &mut self.a,
                b: &mut self.b,
            }
        }
    }
    fn bits(&self) -> Vec<u32> {
        self.a.iter().chain(&self.b).map(|v| v.to_bits()).collect()
    }
}

struct Model {
    g1: Layer,
    g2: Layer,
    d1: Layer,
    w2: Vec<f32>,
}

fn model() -> Model {
    Model {
        g1: Layer::new(H, Z + A, 10),
        g2: Layer::new(F, H, 20),
        d1: Layer::new(DH, F, 30),
        w2: vals(DH, 40),
    }
}

fn gen<'a>(m: &'a Model, eff: bool) -> Generator<'a> {
    Generator {
        l1: m.g1.view(eff),
        l2: m.g2.view(eff),
    }
}

fn disc<'a>(m: &'a Model, eff: bool) -> Discriminator<'a> {
    Discriminator {
        l1: m.d1.view(eff),
        w2: &m.w2,
        b2: 0.125,
    }
}

/// Owned buffers of an `InnerWork` for batches of `b`.
struct Work {
    b: usize,
    v: Vec<Vec<f32>>,
}

impl Work {
    fn new(b: usize, full_d: bool) -> Work {
        let lens = [
            b * Z,
            b * A,
            b * H,
            b * H,
            b * F,
            b * F,
            b * H,
            b * H,
            3 * b * DH,
            3 * b * DH,
            3 * b * DH,
            b * DH,
            b * F,
            b * F,
            if full_d { 3 * b * F } else { 0 },
            if full_d { 3 * b * DH } else { 0 },
        ];
        Work {
            b,
            v: lens.iter().map(|&l| vec![f32::NAN; l]).collect(),
        }
    }
    fn view(&mut self) -> InnerWork<'_> {
        let [z, attr, u1, h1, u2, dpre2, dh1, dpre1, du, dh, dv, w1g, g, mix, outer_x, outer_dy] =
            &mut self.v[..]
        else {
            unreachable!()
        };
        InnerWork {
            b: self.b,
            z,
            attr,
            u1,
            h1,
            u2,
            dpre2,
            dh1,
            dpre1,
            du,
            dh,
            dv,
            w1g,
            g,
            mix,
            outer_x,
            outer_dy,
        }
    }
}

/// Noise: distinct rows, or runs of identical rows (entries 2..5 equal, 5..7 zero).
fn noises(repeated: bool) -> Vec<f32> {
    let mut z = vals(N * Z, 50);
    if repeated {
        let row: Vec<f32> = z[2 * Z..3 * Z].to_vec();
        for t in 3..5 {
            z[t * Z..(t + 1) * Z].copy_from_slice(&row);
        }
        z[5 * Z..].fill(0.0);
    }
    z
}

fn batch1_features(g: &Generator<'_>, zs: &[f32], attr: &[f32]) -> Vec<f32> {
    batch1_features_u2(g, zs, attr).0
}

/// The features and G's pre-gain layer-2 outputs of [`batch1_features`] (what a navigator's
/// steps record in Ψ with `Footprint::Fast`).
fn batch1_features_u2(g: &Generator<'_>, zs: &[f32], attr: &[f32]) -> (Vec<f32>, Vec<f32>) {
    let (mut u1, mut h1, mut u2) = (vec![0.0; H], vec![0.0; H], vec![0.0; F]);
    let mut xs = vec![0.0; N * F];
    let mut u2s = vec![0.0; N * F];
    for t in 0..N {
        let mut x = vec![0.0; F];
        let mut c = GeneratorCache {
            u1: &mut u1,
            h1: &mut h1,
            u2: &mut u2,
            x: &mut x,
        };
        g.forward(&zs[t * Z..(t + 1) * Z], attr, &mut c).unwrap();
        xs[t * F..(t + 1) * F].copy_from_slice(&x);
        u2s[t * F..(t + 1) * F].copy_from_slice(&u2);
    }
    (xs, u2s)
}

fn bits(v: &[f32]) -> Vec<u32> {
    v.iter().map(|x| x.to_bits()).collect()
}

#[test]
fn generate_matches_forward_per_entry() {
    let m = model();
    let attr = vals(A, 60);
    for eff in [false, true] {
        let g = gen(&m, eff);
        let zs = noises(false);
        let want = batch1_features(&g, &zs, &attr);
        for b in [1, 2, 3, N, N + 2] {
            let mut w = Work::new(b, !eff);
            let mut xs = vec![0.0; N * F];
            inner::generate(&g, &zs, &attr, &mut xs, &mut w.view()).unwrap();
            assert_eq!(bits(&xs), bits(&want), "eff={eff} b={b}");
        }
    }
}

/// L_D summed over the entries the way the navigator did before batching: `ld_loss` on each
/// entry alone, parts times `inv`.
#[allow(clippy::too_many_arguments)]
fn ld_batch1(
    d: &Discriminator<'_>,
    real: &[f32],
    fake: &[f32],
    eps: &[f32],
    cfg: LdConfig,
    gd: &mut Grad,
    w2: &mut [f32],
    b2: &mut f32,
) -> LdValue {
    let mut s = vec![vec![0.0f32; DH]; 4];
    let (mut sg, mut smix) = (vec![0.0; F], vec![0.0; F]);
    let inv = 1.0 / N as f32;
    let mut ld = LdValue::default();
    let mut grads = DiscGrads {
        l1: gd.grads(),
        w2,
        b2,
    };
    for t in 0..N {
        let [u, h, v, w1g] = &mut s[..] else {
            unreachable!()
        };
        let mut sc = DiscScratch {
            u,
            h,
            v,
            w1g,
            g: &mut sg,
            mix: &mut smix,
        };
        let v = d
            .ld_loss(
                &real[t * F..(t + 1) * F],
                &fake[t * F..(t + 1) * F],
                &eps[t..t + 1],
                cfg,
                &mut sc,
                Some(&mut grads),
            )
            .unwrap();
        ld.loss += v.loss * inv;
        ld.mean_real += v.mean_real * inv;
        ld.mean_fake += v.mean_fake * inv;
        ld.penalty += v.penalty * inv;
    }
    ld
}

fn ld_bits(v: &LdValue) -> [u32; 4] {
    [
        v.loss.to_bits(),
        v.mean_real.to_bits(),
        v.mean_fake.to_bits(),
        v.penalty.to_bits(),
    ]
}

#[test]
fn ld_grad_sum_matches_ld_loss_per_entry() {
    let m = model();
    let attr = vals(A, 61);
    let real: Vec<f32> = vals(N * F, 62).iter().map(|v| v.abs()).collect();
    let mut eps: Vec<f32> = vals(N, 63).iter().map(|v| v.abs()).collect();
    eps[1] = 0.0;
    eps[2] = 1.0;
    for eff in [false, true] {
        let g = gen(&m, eff);
        let d = disc(&m, eff);
        let fake = batch1_features(&g, &noises(false), &attr);
        for cfg in [
            LdConfig::default(),
            LdConfig {
                lambda: 0.0,
                critic_scale: 10.0,
            },
        ] {
            let mut gw = Grad::new(&m.d1, eff);
            let (mut w2, mut b2) = (vec![0.0; DH], 0.0f32);
            let want = ld_batch1(&d, &real, &fake, &eps, cfg, &mut gw, &mut w2, &mut b2);
            for b in [1, 2, 3, N, N + 2] {
                let mut gb = Grad::new(&m.d1, eff);
                let (mut w2b, mut b2b) = (vec![0.0; DH], 0.0f32);
                let mut w = Work::new(b, !eff);
                let mut grads = DiscGrads {
                    l1: gb.grads(),
                    w2: &mut w2b,
                    b2: &mut b2b,
                };
                let got = inner::ld_grad_sum(
                    &d,
                    &real,
                    &fake,
                    &eps,
                    cfg,
                    1.0 / N as f32,
                    &mut w.view(),
                    &mut grads,
                )
                .unwrap();
                let what = format!("eff={eff} b={b} cfg={cfg:?}");
                assert_eq!(ld_bits(&got), ld_bits(&want), "{what}");
                assert_eq!(gb.bits(), gw.bits(), "{what}");
                assert_eq!(bits(&w2b), bits(&w2), "{what}");
                assert_eq!(b2b.to_bits(), b2.to_bits(), "{what}");
            }
        }
    }
}

#[test]
fn adapt_grad_matches_the_batch1_functions() {
    let m = model();
    let attr = vals(A, 70);
    let obs: Vec<f32> = vals(N * F, 71).iter().map(|v| v.abs()).collect();
    let probs: Vec<f32> = {
        let p = vals(N * NUM_ACTIONS, 72);
        let mut out = vec![0.0; N * NUM_ACTIONS];
        for t in 0..N {
            let r = &p[t * NUM_ACTIONS..(t + 1) * NUM_ACTIONS];
            let e: Vec<f32> = r.iter().map(|v| v.exp()).collect();
            let s: f32 = e.iter().sum();
            for i in 0..NUM_ACTIONS {
                out[t * NUM_ACTIONS + i] = e[i] / s;
            }
        }
        out
    };
    for eff in [false, true] {
        let g = gen(&m, eff);
        let d = disc(&m, eff);
        for repeated in [false, true] {
            let zs = noises(repeated);
            let (xs, u2s) = batch1_features_u2(&g, &zs, &attr);
            for kind in [AdaptLossKind::Paper, AdaptLossKind::Reference] {
                for use_d in [true, false] {
                    // The reference (`before`) and the public batch-1 functions (the
                    // batched passes with a batch of one) must agree, then the batches.
                    let mut runs = Vec::new();
                    for public in [false, true] {
                        let fd = if public {
                            gman_core::adapt::adapt_generator_grad
                        } else {
                            adapt_generator_grad
                        };
                        let fc = if public {
                            gman_core::adapt::adapt_generator_grad_cos
                        } else {
                            adapt_generator_grad_cos
                        };
                        let mut bufs = vec![vec![0.0f32; F.max(H)]; 14];
                        let (mut g1, mut g2) = (Grad::new(&m.g1, eff), Grad::new(&m.g2, eff));
                        let (mut dv, mut ddv) = (vec![0.0; N], vec![0.0; N]);
                        let mut dprobs = vec![0.0; N * NUM_ACTIONS];
                        let want = {
                            let [u1, h1, u2, x, dpre2, dh1, dpre1, tmp, du, dh, ddv2, w1g, gg, mix] =
                                &mut bufs[..]
                            else {
                                unreachable!()
                            };
                            let mut aw = AdaptWork {
                                gen: GeneratorCache {
                                    u1: &mut u1[..H],
                                    h1: &mut h1[..H],
                                    u2: &mut u2[..F],
                                    x: &mut x[..F],
                                },
                                gen_scratch: GeneratorScratch {
                                    dpre2: &mut dpre2[..F],
                                    dh1: &mut dh1[..H],
                                    dpre1: &mut dpre1[..H],
                                    tmp,
                                },
                                disc: DiscScratch {
                                    u: &mut du[..DH],
                                    h: &mut dh[..DH],
                                    v: &mut ddv2[..DH],
                                    w1g: &mut w1g[..DH],
                                    g: &mut gg[..F],
                                    mix: &mut mix[..F],
                                },
                                d: &mut dv,
                                dd: &mut ddv,
                                dx: &mut [0.0; F],
                            };
                            if use_d {
                                fd(
                                    kind,
                                    &g,
                                    &d,
                                    &attr,
                                    &zs,
                                    &probs,
                                    &mut aw,
                                    &mut g1.grads(),
                                    &mut g2.grads(),
                                    &mut dprobs,
                                )
                                .unwrap()
                            } else {
                                fc(
                                    kind,
                                    &g,
                                    &attr,
                                    &zs,
                                    &obs,
                                    &probs,
                                    &mut aw,
                                    &mut g1.grads(),
                                    &mut g2.grads(),
                                    &mut dprobs,
                                )
                                .unwrap()
                            }
                        };
                        runs.push((
                            want.to_bits(),
                            bits(&dv),
                            bits(&ddv),
                            bits(&dprobs),
                            g1.bits(),
                            g2.bits(),
                            g1,
                            g2,
                            dv,
                            ddv,
                            dprobs,
                            want,
                        ));
                    }
                    let pub_run = runs.pop().unwrap();
                    let (wb, dvb, ddb, dpb, g1b, g2b, g1, g2, dv, ddv, dprobs, want) =
                        runs.pop().unwrap();
                    assert_eq!((wb, dvb, ddb, dpb, g1b, g2b), (pub_run.0, pub_run.1, pub_run.2, pub_run.3, pub_run.4, pub_run.5), "public batch-1 vs reference: eff={eff} repeated={repeated} kind={kind:?} use_d={use_d}");
                    // Regenerated features, recorded features, and recorded features with G's
                    // recorded pre-gain outputs (`Footprint::Fast`).
                    for (b, with_xs, with_u2) in [1, 2, 3, N, N + 2]
                        .into_iter()
                        .flat_map(|b| [(b, true, false), (b, false, false), (b, true, true)])
                    {
                        let (mut h1g, mut h2g) = (Grad::new(&m.g1, eff), Grad::new(&m.g2, eff));
                        let (mut d2, mut dd2) = (vec![0.0; N], vec![0.0; N]);
                        let mut dp2 = vec![0.0; N * NUM_ACTIONS];
                        let mut w = Work::new(b, !eff);
                        let got = inner::adapt_grad(
                            kind,
                            &g,
                            use_d.then_some(&d),
                            inner::AdaptInputs {
                                attr: &attr,
                                zs: &zs,
                                xs: with_xs.then_some(&xs[..]),
                                u2s: with_u2.then_some(&u2s[..]),
                                obs: &obs,
                                shared: false,
                            },
                            &probs,
                            (&mut d2, &mut dd2, &mut dp2),
                            &mut w.view(),
                            &mut h1g.grads(),
                            &mut h2g.grads(),
                        )
                        .unwrap();
                        let what = format!(
                            "eff={eff} repeated={repeated} kind={kind:?} use_d={use_d} b={b} xs={with_xs} u2s={with_u2}"
                        );
                        assert_eq!(got.to_bits(), want.to_bits(), "{what}");
                        assert_eq!(bits(&d2), bits(&dv), "{what}");
                        assert_eq!(bits(&dd2), bits(&ddv), "{what}");
                        assert_eq!(bits(&dp2), bits(&dprobs), "{what}");
                        assert_eq!(h1g.bits(), g1.bits(), "{what}");
                        assert_eq!(h2g.bits(), g2.bits(), "{what}");
                        assert!(g1.a.iter().any(|v| *v != 0.0), "{what}: a gradient at all");
                        // Without the θ gradient (the head-only rule): the same scores,
                        // loss and dL/da bits.
                        let (mut d3, mut dd3) = (vec![0.0; N], vec![0.0; N]);
                        let mut dp3 = vec![0.0; N * NUM_ACTIONS];
                        let mut w = Work::new(b, !eff);
                        let loss3 = inner::adapt_scores(
                            kind,
                            &g,
                            use_d.then_some(&d),
                            inner::AdaptInputs {
                                attr: &attr,
                                zs: &zs,
                                xs: with_xs.then_some(&xs[..]),
                                u2s: with_u2.then_some(&u2s[..]),
                                obs: &obs,
                                shared: false,
                            },
                            &probs,
                            (&mut d3, &mut dd3, &mut dp3),
                            &mut w.view(),
                        )
                        .unwrap();
                        assert_eq!(loss3.to_bits(), want.to_bits(), "scores {what}");
                        assert_eq!(bits(&d3), bits(&dv), "scores {what}");
                        assert_eq!(bits(&dd3), bits(&ddv), "scores {what}");
                        assert_eq!(bits(&dp3), bits(&dprobs), "scores {what}");
                    }
                }
            }
        }
    }
}

#[test]
fn short_buffers_are_errors_not_panics() {
    let m = model();
    let attr = vals(A, 80);
    let g = gen(&m, true);
    let zs = noises(false);
    let mut xs = vec![0.0; N * F];
    let mut w = Work::new(3, false);
    w.v[3].truncate(5); // h1
    assert!(inner::generate(&g, &zs, &attr, &mut xs, &mut w.view()).is_err());
    let mut w = Work::new(0, false);
    assert!(inner::generate(&g, &zs, &attr, &mut xs, &mut w.view()).is_err());
    // Full D gradient without the outer-product buffers.
    let d = disc(&m, false);
    let mut gd = Grad::new(&m.d1, false);
    let (mut w2, mut b2) = (vec![0.0; DH], 0.0f32);
    let mut w = Work::new(2, false);
    let r = inner::ld_grad_sum(
        &d,
        &xs,
        &xs,
        &[0.5; N],
        LdConfig::default(),
        1.0,
        &mut w.view(),
        &mut DiscGrads {
            l1: gd.grads(),
            w2: &mut w2,
            b2: &mut b2,
        },
    );
    assert!(r.is_err());
}

/// The batch-1 implementation the navigator ran before the batched inner update (and
/// `gman_core::adapt` before it became the batched passes with a batch of one), kept as the
/// reference transcription of the order of operations.
mod before {
    use gman_core::adapt::{adapt_loss, cosine, AdaptLossKind, AdaptWork};
    use gman_core::error::Result;
    use gman_core::nets::discriminator::{DiscScratch, Discriminator};
    use gman_core::nn::dense::DenseGrads;

    /// The reference runs on valid shapes only.
    fn check_len(what: &str, expected: usize, actual: usize) -> Result<()> {
        assert_eq!(expected, actual, "{what}");
        Ok(())
    }
    use gman_core::nets::generator::{Generator, GeneratorCache, GeneratorScratch};

    /// L_ad over a buffer of `n` steps and its gradient with respect to G's parameters θ and to
    /// the action probabilities.
    ///
    /// `zs` holds the `n` noise vectors (`n x Z`) the buffer's features were generated with;
    /// the features are regenerated from them (G is unchanged inside one adaptation window, so
    /// this is exact, and it spares the device the `n x H` activations). Entries with
    /// bit-identical noise (always the case with the reference's fixed zero noise) share one
    /// forward/backward pass of G with their `∂L/∂x` summed. `probs` is `n x 6`.
    /// The θ gradient is accumulated into `grads1`/`grads2`; `dprobs` (`n x 6`) is overwritten.
    #[allow(clippy::too_many_arguments)]
    pub fn adapt_generator_grad(
        kind: AdaptLossKind,
        gen: &Generator<'_>,
        disc: &Discriminator<'_>,
        attr: &[f32],
        zs: &[f32],
        probs: &[f32],
        w: &mut AdaptWork<'_>,
        grads1: &mut DenseGrads<'_>,
        grads2: &mut DenseGrads<'_>,
        dprobs: &mut [f32],
    ) -> Result<f32> {
        let n = w.d.len();
        let zdim = gen.in_dim().saturating_sub(attr.len());
        check_len("adapt.zs", n * zdim, zs.len())?;
        check_len("adapt.dd", n, w.dd.len())?;
        check_len("adapt.dx", gen.feat(), w.dx.len())?;
        check_len("adapt.disc_in", gen.feat(), disc.in_dim())?;
        // Pass 1: D(x_t) for every entry.
        for t in 0..n {
            let z = &zs[t * zdim..(t + 1) * zdim];
            gen.forward(z, attr, &mut w.gen)?;
            w.d[t] = disc.score(w.gen.x, &mut w.disc)?;
        }
        let loss = adapt_loss(kind, w.d, probs, w.dd, dprobs)?;
        // Pass 2: back-propagate ∂L/∂d_t · ∇D(x_t) through G, grouping identical noise.
        let AdaptWork {
            gen: cache,
            gen_scratch,
            disc: ds,
            dd,
            dx,
            ..
        } = w;
        backprop_scores(
            gen,
            disc,
            attr,
            zs,
            zdim,
            dd,
            cache,
            gen_scratch,
            ds,
            dx,
            grads1,
            grads2,
        )?;
        Ok(loss)
    }

    /// `∇_θ Σ_t coef_t D(G_θ(z_t))`, grouping consecutive bit-identical noise vectors.
    #[allow(clippy::too_many_arguments)]
    fn backprop_scores(
        gen: &Generator<'_>,
        disc: &Discriminator<'_>,
        attr: &[f32],
        zs: &[f32],
        zdim: usize,
        coef: &[f32],
        cache: &mut GeneratorCache<'_>,
        gen_scratch: &mut GeneratorScratch<'_>,
        ds: &mut DiscScratch<'_>,
        dx: &mut [f32],
        grads1: &mut DenseGrads<'_>,
        grads2: &mut DenseGrads<'_>,
    ) -> Result<()> {
        let n = coef.len();
        let mut t = 0;
        while t < n {
            let z = &zs[t * zdim..(t + 1) * zdim];
            let mut c = coef[t];
            let mut end = t + 1;
            while end < n && same_bits(&zs[end * zdim..(end + 1) * zdim], z) {
                c += coef[end];
                end += 1;
            }
            gen.forward(z, attr, cache)?;
            disc.score(cache.x, ds)?;
            disc.input_grad(ds)?;
            for (o, &g) in dx.iter_mut().zip(ds.g.iter()) {
                *o = c * g;
            }
            gen.backward(z, attr, cache, dx, grads1, grads2, gen_scratch)?;
            t = end;
        }
        Ok(())
    }

    fn same_bits(a: &[f32], b: &[f32]) -> bool {
        a.len() == b.len() && a.iter().zip(b).all(|(x, y)| x.to_bits() == y.to_bits())
    }

    /// L_ad with the cosine similarity `cos(x_t, s_t)` between each generated feature and the
    /// observation it was generated with, in place of `D(x_t)`: the "CosSim" variant of the
    /// environmental meta discriminator (paper Table 3). `obs` holds the buffer's observations
    /// (`n x F`); the other arguments are those of [`adapt_generator_grad`] (D's scratch in `w`
    /// is unused). Accumulates the θ gradient into `grads1`/`grads2`, overwrites `dprobs`.
    #[allow(clippy::too_many_arguments)]
    pub fn adapt_generator_grad_cos(
        kind: AdaptLossKind,
        gen: &Generator<'_>,
        attr: &[f32],
        zs: &[f32],
        obs: &[f32],
        probs: &[f32],
        w: &mut AdaptWork<'_>,
        grads1: &mut DenseGrads<'_>,
        grads2: &mut DenseGrads<'_>,
        dprobs: &mut [f32],
    ) -> Result<f32> {
        let n = w.d.len();
        let f = gen.feat();
        let zdim = gen.in_dim().saturating_sub(attr.len());
        check_len("adapt.zs", n * zdim, zs.len())?;
        check_len("adapt.obs", n * f, obs.len())?;
        check_len("adapt.dd", n, w.dd.len())?;
        check_len("adapt.dx", f, w.dx.len())?;
        for t in 0..n {
            gen.forward(&zs[t * zdim..(t + 1) * zdim], attr, &mut w.gen)?;
            w.d[t] = cosine(w.gen.x, &obs[t * f..(t + 1) * f], None)?;
        }
        let loss = adapt_loss(kind, w.d, probs, w.dd, dprobs)?;
        for t in 0..n {
            let z = &zs[t * zdim..(t + 1) * zdim];
            gen.forward(z, attr, &mut w.gen)?;
            cosine(w.gen.x, &obs[t * f..(t + 1) * f], Some(w.dx))?;
            let c = w.dd[t];
            w.dx.iter_mut().for_each(|v| *v *= c);
            gen.backward(z, attr, &w.gen, w.dx, grads1, grads2, &mut w.gen_scratch)?;
        }
        Ok(loss)
    }
}
