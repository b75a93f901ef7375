//! The on-device navigator of gman-core against the independent f64 reference
//! (`gman_tests::reference::nav`), plus determinism, rollback and a synthetic check that the
//! inner loop does what Eq. 1-3 say.

use gman_core::adapt::AdaptLossKind;
use gman_core::blob::TensorId;
use gman_core::navigator::{
    Efficient, Full, Mode, NavConfig, NavWeights, Navigator, NoiseMode, Selection,
};
use gman_core::nets::policy::{PolicyCache, PolicyInput};
use gman_core::nn::dense::Dense;
use gman_core::nn::matrix::MatRef;
use gman_core::rng::{fill_gaussian, uniform, Xoshiro128};
use gman_core::spec::{InnerRule, ModelSpec};
use gman_core::{Dims, Error, NUM_ACTIONS};
use gman_tests::reference::nav::NavRef;
use gman_tests::reference::{Dense64, Disc64, Gen64, Lstm64};

/// Seeded f32 weights for every tensor of `dims` (N(0, scale²)).
fn weights(dims: &Dims, seed: u64, scale: f32) -> Vec<Vec<f32>> {
    let mut rng = Xoshiro128::seed_from_u64(seed);
    TensorId::all_for(dims)
        .map(|id| {
            let (r, c) = id.shape(dims);
            let mut v = vec![0.0f32; r * c];
            fill_gaussian(&mut rng, &mut v);
            v.iter_mut().for_each(|x| *x *= scale);
            v
        })
        .collect()
}

fn nav_weights<'a>(dims: &Dims, w: &'a [Vec<f32>]) -> NavWeights<'a> {
    NavWeights::from_fn(dims, |id| {
        let (r, c) = id.shape(dims);
        MatRef::f32(r, c, &w[id as usize]).unwrap()
    })
    .unwrap()
}

fn f64s(v: &[f32]) -> Vec<f64> {
    v.iter().map(|&x| x as f64).collect()
}

fn d64(dims: &Dims, w: &[Vec<f32>], id: TensorId, bias: TensorId, gain: bool) -> Dense64 {
    let (rows, cols) = id.shape(dims);
    Dense64 {
        rows,
        cols,
        w: f64s(&w[id as usize]),
        b: f64s(&w[bias as usize]),
        gain: gain.then(|| vec![1.0; rows]),
    }
}

fn reference(
    dims: &Dims,
    w: &[Vec<f32>],
    efficient: bool,
    cfg: &NavConfig,
    attr: &[f32],
) -> NavRef {
    let lh = dims.lstm_hidden;
    NavRef {
        gen: Gen64 {
            l1: d64(dims, w, TensorId::GenW1, TensorId::GenB1, efficient),
            l2: d64(dims, w, TensorId::GenW2, TensorId::GenB2, efficient),
        },
        disc: Disc64 {
            l1: d64(dims, w, TensorId::DiscW1, TensorId::DiscB1, efficient),
            w2: f64s(&w[TensorId::DiscW2 as usize]),
            b2: w[TensorId::DiscB2 as usize][0] as f64,
        },
        fuse: d64(dims, w, TensorId::FuseW, TensorId::FuseB, false),
        lstm: Lstm64 {
            input: dims.embed,
            hidden: lh,
            wx: f64s(&w[TensorId::LstmWx as usize]),
            wh: f64s(&w[TensorId::LstmWh as usize]),
            b: f64s(&w[TensorId::LstmB as usize]),
        },
        actor: d64(dims, w, TensorId::ActorW, TensorId::ActorB, efficient),
        critic: d64(dims, w, TensorId::CriticW, TensorId::CriticB, false),
        efficient,
        alpha_disc: cfg.model.alpha_disc() as f64,
        alpha_adapt: cfg.model.inner_lr as f64,
        lambda: cfg.ld_lambda as f64,
        paper_loss: cfg.model.inner_rule.adapt_loss == AdaptLossKind::Paper,
        h: vec![0.0; lh],
        c: vec![0.0; lh],
        prev: vec![0.0; 6],
        attr: f64s(attr),
        psi: Vec::new(),
    }
}

/// The adapted values of a core layer: (W or gain, b).
fn core_layer(d: &Dense<'_>, efficient: bool) -> (Vec<f64>, Vec<f64>) {
    let a = if efficient {
        f64s(d.gain.expect("gain"))
    } else {
        let (r, c) = (d.w.rows(), d.w.cols());
        (0..r * c).map(|i| d.w.get(i / c, i % c) as f64).collect()
    };
    (a, f64s(d.b))
}

fn ref_layer(d: &Dense64, efficient: bool) -> (Vec<f64>, Vec<f64>) {
    (
        if efficient {
            d.gain.clone().unwrap()
        } else {
            d.w.clone()
        },
        d.b.clone(),
    )
}

fn rel(a: &[f64], b: &[f64]) -> f64 {
    let d = a
        .iter()
        .zip(b)
        .map(|(x, y)| (x - y).powi(2))
        .sum::<f64>()
        .sqrt();
    d / b.iter().map(|y| y * y).sum::<f64>().sqrt().max(1e-12)
}

fn sub(a: &[f64], b: &[f64]) -> Vec<f64> {
    a.iter().zip(b).map(|(x, y)| x - y).collect()
}

/// Snapshot of all adapted parameters of the core navigator, in a fixed order.
fn core_snapshot<M: Mode, const K: usize>(
    nav: &Navigator<'_, M, K>,
    eff: bool,
) -> Vec<(Vec<f64>, Vec<f64>)> {
    let g = nav.generator().unwrap();
    let d = nav.discriminator().unwrap();
    let p = nav.policy().unwrap();
    vec![
        core_layer(&g.l1, eff),
        core_layer(&g.l2, eff),
        core_layer(&d.l1, eff),
        (f64s(d.w2), vec![d.b2 as f64]),
        core_layer(&p.actor, eff),
    ]
}

fn ref_snapshot(r: &NavRef) -> Vec<(Vec<f64>, Vec<f64>)> {
    let e = r.efficient;
    vec![
        ref_layer(&r.gen.l1, e),
        ref_layer(&r.gen.l2, e),
        ref_layer(&r.disc.l1, e),
        (r.disc.w2.clone(), vec![r.disc.b2]),
        ref_layer(&r.actor, e),
    ]
}

const NAMES: [&str; 5] = [
    "G layer 1",
    "G layer 2",
    "D layer 1",
    "D output",
    "actor head",
];

fn agree<M: Mode, const K: usize>(dims: Dims, kind: AdaptLossKind, seed: u64) {
    let eff = matches!(M::MODE, gman_core::navigator::memory::AdaptMode::Efficient);
    let w = weights(&dims, seed, 0.1);
    let cfg = NavConfig {
        model: ModelSpec {
            inner_lr: 0.05,
            noise: NoiseMode::Gaussian,
            inner_rule: InnerRule {
                disc_lr: Some(0.05),
                adapt_loss: kind,
                ..InnerRule::PAPER
            },
            ..NavConfig::default().model
        },
        selection: Selection::Greedy,
        ..NavConfig::default()
    };
    let mut arena = vec![0.0f32; Navigator::<M, K>::arena_len(&dims)];
    let mut nav: Navigator<'_, M, K> =
        Navigator::new(nav_weights(&dims, &w), &mut arena, cfg).unwrap();
    let mut rng = Xoshiro128::seed_from_u64(seed + 100);
    let mut attr = vec![0.0f32; dims.attr];
    attr.iter_mut().for_each(|a| *a = uniform(&mut rng));
    let mut r = reference(&dims, &w, eff, &cfg, &attr);
    let ep_seed = 7;
    nav.reset(&attr, ep_seed).unwrap();
    let mut rrng = Xoshiro128::seed_from_u64(ep_seed);
    let ps: Vec<f32> = (0..dims.ps).map(|_| uniform(&mut rng)).collect();
    let mut adaptations = 0;
    for step in 0..(2 * K + 3) {
        let obs: Vec<f32> = (0..dims.feat).map(|_| uniform(&mut rng)).collect();
        let before_core = core_snapshot(&nav, eff);
        let before_ref = ref_snapshot(&r);
        let out = nav.step(&obs, &ps).unwrap();
        let mut z = vec![0.0f32; dims.noise];
        fill_gaussian(&mut rrng, &mut z);
        let (x, probs, value) = r.step(&f64s(&obs), &f64s(&z), &f64s(&ps));
        assert!(
            rel(&f64s(nav.generated_feature()), &x) < 1e-4,
            "step {step}: x_t"
        );
        assert!(
            rel(&f64s(&out.probs), &probs) < 1e-4,
            "step {step}: probs {:?} vs {probs:?}",
            out.probs
        );
        assert!(
            (out.value as f64 - value).abs() < 1e-4 * (1.0 + value.abs()),
            "step {step}: value"
        );
        if r.psi.len() == K {
            let eps: Vec<f64> = (0..K).map(|_| uniform(&mut rrng) as f64).collect();
            r.adapt(&eps);
            assert!(out.adapted);
            adaptations += 1;
            let after_core = core_snapshot(&nav, eff);
            let after_ref = ref_snapshot(&r);
            for i in 0..5 {
                for part in 0..2 {
                    let (bc, br) = if part == 0 {
                        (&before_core[i].0, &before_ref[i].0)
                    } else {
                        (&before_core[i].1, &before_ref[i].1)
                    };
                    let (ac, ar) = if part == 0 {
                        (&after_core[i].0, &after_ref[i].0)
                    } else {
                        (&after_core[i].1, &after_ref[i].1)
                    };
                    assert!(rel(ac, ar) < 1e-4, "{}: parameters differ", NAMES[i]);
                    let (dc, dr) = (sub(ac, bc), sub(ar, br));
                    if dr.iter().any(|v| *v != 0.0) {
                        let e = rel(&dc, &dr);
                        assert!(
                            e < 2e-3,
                            "{} ({}): update differs by {e:.2e} ({M:?})",
                            NAMES[i],
                            if part == 0 { "w/gain" } else { "b" },
                            M = M::MODE
                        );
                    }
                }
            }
            assert_eq!(nav.counters().rollbacks, 0);
        }
    }
    assert_eq!(adaptations, 2);
    assert_eq!(nav.counters().adaptations, 2);
}

#[test]
fn mcu_full_size_agrees_with_f64_reference() {
    agree::<Full, 20>(Dims::MCU, AdaptLossKind::Paper, 1);
    agree::<Efficient, 20>(Dims::MCU, AdaptLossKind::Reference, 2);
}

#[test]
fn paper_preset_with_reduced_hidden_sizes_agrees_with_f64_reference() {
    let d = Dims {
        gen_hidden: 512,
        disc_hidden: 128,
        lstm_hidden: 64,
        embed: 64,
        ..Dims::PAPER.with_ps()
    };
    agree::<Full, 6>(d, AdaptLossKind::Reference, 3);
    agree::<Efficient, 6>(d, AdaptLossKind::Paper, 4);
}

fn run_episode(w: &[Vec<f32>], dims: &Dims, seed: u64) -> (Vec<u8>, Vec<u32>) {
    let cfg = NavConfig {
        model: ModelSpec {
            inner_lr: 1e-2,
            inner_rule: InnerRule {
                disc_lr: Some(1e-2),
                ..InnerRule::PAPER
            },
            ..NavConfig::default().model
        },
        selection: Selection::Sample,
        ..NavConfig::default()
    };
    let mut arena = vec![0.0f32; Navigator::<Full, 10>::arena_len(dims)];
    let mut nav: Navigator<'_, Full, 10> =
        Navigator::new(nav_weights(dims, w), &mut arena, cfg).unwrap();
    nav.reset(&[0.3; 45], seed).unwrap();
    let mut rng = Xoshiro128::seed_from_u64(99);
    let mut actions = Vec::new();
    for _ in 0..35 {
        let obs: Vec<f32> = (0..dims.feat).map(|_| uniform(&mut rng)).collect();
        actions.push(nav.step(&obs, &[]).unwrap().action as u8);
    }
    let g = nav.generator().unwrap();
    let bits = (0..g.l2.w.rows() * g.l2.w.cols())
        .map(|i| g.l2.w.get(i / g.l2.w.cols(), i % g.l2.w.cols()).to_bits())
        .collect();
    (actions, bits)
}

#[test]
fn same_seed_and_observations_give_identical_actions_and_parameters() {
    let dims = Dims::MCU;
    let w = weights(&dims, 5, 0.1);
    let a = run_episode(&w, &dims, 1);
    let b = run_episode(&w, &dims, 1);
    let c = run_episode(&w, &dims, 2);
    assert_eq!(a, b);
    assert_ne!(
        a.1, c.1,
        "another episode seed must give other noise and thus other updates"
    );
}

#[test]
fn bad_inputs_and_injected_nan_are_handled() {
    let dims = Dims::MCU;
    let mut w = weights(&dims, 6, 0.1);
    // Out-of-order call and bad inputs: typed errors.
    {
        let mut arena = vec![0.0f32; Navigator::<Efficient, 5>::arena_len(&dims)];
        let mut nav: Navigator<'_, Efficient, 5> =
            Navigator::new(nav_weights(&dims, &w), &mut arena, NavConfig::default()).unwrap();
        assert!(matches!(
            nav.step(&[0.0; 512], &[]),
            Err(Error::Config { .. })
        ));
        assert!(matches!(
            nav.reset(&[f32::NAN; 45], 1),
            Err(Error::NonFiniteInput { .. })
        ));
        nav.reset(&[0.1; 45], 1).unwrap();
        let mut obs = vec![0.5f32; 512];
        obs[100] = f32::NAN;
        assert_eq!(
            nav.step(&obs, &[]).unwrap_err(),
            Error::NonFiniteInput { what: "obs" }
        );
        assert!(matches!(nav.step(&[0.5; 100], &[]), Err(Error::Shape(_))));
        let mut small = vec![0.0f32; 10];
        assert!(Navigator::<Efficient, 5>::new(
            nav_weights(&dims, &w),
            &mut small,
            NavConfig::default()
        )
        .is_err());
    }
    // A loss bound that every step exceeds: both steps rolled back, parameters untouched.
    {
        let cfg = NavConfig {
            loss_bound: 1e-30,
            ..NavConfig::default()
        };
        let mut arena = vec![0.0f32; Navigator::<Full, 5>::arena_len(&dims)];
        let mut nav: Navigator<'_, Full, 5> =
            Navigator::new(nav_weights(&dims, &w), &mut arena, cfg).unwrap();
        nav.reset(&[0.1; 45], 1).unwrap();
        let before = core_snapshot(&nav, false);
        for _ in 0..5 {
            nav.step(&[0.5; 512], &[]).unwrap();
        }
        assert_eq!(nav.counters().adaptations, 1);
        assert_eq!(nav.counters().rollbacks, 2);
        assert_eq!(before, core_snapshot(&nav, false));
    }
    // NaN injected into D's weights: D's scores are NaN, both inner steps are rolled back,
    // the policy (which does not read D) keeps returning finite actions.
    w[TensorId::DiscW1 as usize][3] = f32::NAN;
    let mut arena = vec![0.0f32; Navigator::<Full, 5>::arena_len(&dims)];
    let mut nav: Navigator<'_, Full, 5> =
        Navigator::new(nav_weights(&dims, &w), &mut arena, NavConfig::default()).unwrap();
    nav.reset(&[0.1; 45], 1).unwrap();
    let before = core_snapshot(&nav, false);
    for _ in 0..10 {
        let out = nav.step(&[0.5; 512], &[]).unwrap();
        assert!(out.probs.iter().all(|p| p.is_finite()));
    }
    let c = nav.counters();
    assert_eq!((c.adaptations, c.rollbacks), (2, 4));
    assert!(!nav.last_adaptation().disc_applied && !nav.last_adaptation().adapt_applied);
    let after = core_snapshot(&nav, false);
    assert_eq!(before[0], after[0], "θ must be untouched");
    assert_eq!(before[4], after[4], "φ must be untouched");
}

/// Zero noise and up to 30 inner updates per episode at rates α2 = `inner_lr` and
/// α1 = `disc_lr` (α2 when `None`).
fn long_episode(inner_lr: f32, disc_lr: Option<f32>) -> NavConfig {
    NavConfig {
        model: ModelSpec {
            inner_lr,
            max_inner: 30,
            noise: NoiseMode::Zero,
            inner_rule: InnerRule {
                disc_lr,
                ..InnerRule::PAPER
            },
            ..NavConfig::default().model
        },
        ..NavConfig::default()
    }
}

/// The zero-step control of the domain-shift study (`gman eval --inner-lr 0`): at α1 = α2 = 0
/// every inner update runs, is applied (not rolled back), and moves no parameter and no bit
/// of x_t.
#[test]
fn zero_inner_rate_runs_every_update_and_moves_nothing() {
    let dims = Dims::MCU;
    let w = weights(&dims, 8, 0.05);
    let mut arena = vec![0.0f32; Navigator::<Full, 10>::arena_len(&dims)];
    let mut nav: Navigator<'_, Full, 10> =
        Navigator::new(nav_weights(&dims, &w), &mut arena, long_episode(0.0, None)).unwrap();
    nav.reset(&[0.4; 45], 3).unwrap();
    nav.step(&[0.5; 512], &[]).unwrap();
    let before = core_snapshot(&nav, false);
    let bits = |x: &[f32]| x.iter().map(|v| v.to_bits()).collect::<Vec<u32>>();
    let x0 = bits(nav.generated_feature());
    let mut rng = Xoshiro128::seed_from_u64(4);
    for _ in 0..99 {
        let obs: Vec<f32> = (0..512).map(|_| uniform(&mut rng)).collect();
        nav.step(&obs, &[]).unwrap();
    }
    let c = nav.counters();
    assert_eq!((c.adaptations, c.rollbacks), (10, 0));
    let r = nav.last_adaptation();
    assert!(r.disc_applied && r.adapt_applied, "{r:?}");
    assert_eq!(before, core_snapshot(&nav, false), "no parameter may move");
    assert_eq!(x0, bits(nav.generated_feature()), "x_t must keep its bits");
}

/// Observations share an offset from what G generates: D learns to separate them and G's
/// output follows the observations (Fig. 3 of the paper, in miniature).
#[test]
fn adaptation_moves_generated_feature_towards_observations() {
    let dims = Dims::MCU;
    let w = weights(&dims, 8, 0.05);
    let mut arena = vec![0.0f32; Navigator::<Full, 10>::arena_len(&dims)];
    let mut nav: Navigator<'_, Full, 10> = Navigator::new(
        nav_weights(&dims, &w),
        &mut arena,
        long_episode(0.2, Some(0.05)),
    )
    .unwrap();
    nav.reset(&[0.4; 45], 3).unwrap();
    nav.step(&[0.5; 512], &[]).unwrap();
    let x0: Vec<f32> = nav.generated_feature().to_vec();
    // Observations: G's initial output shifted by a per-dimension offset, plus small noise.
    let mut rng = Xoshiro128::seed_from_u64(4);
    let offset: Vec<f32> = (0..512)
        .map(|i| if i % 2 == 0 { 0.25 } else { -0.25 })
        .collect();
    let target: Vec<f32> = x0
        .iter()
        .zip(&offset)
        .map(|(x, o)| (x + o).clamp(0.0, 1.0))
        .collect();
    let dist = |x: &[f32]| {
        x.iter()
            .zip(&target)
            .map(|(a, b)| (a - b).powi(2))
            .sum::<f32>()
            .sqrt()
    };
    let d0 = dist(&x0);
    let mut gaps = Vec::new();
    let mut dists = Vec::new();
    for _ in 0..299 {
        let obs: Vec<f32> = target
            .iter()
            .map(|t| (t + 0.02 * (uniform(&mut rng) - 0.5)).clamp(0.0, 1.0))
            .collect();
        if nav.step(&obs, &[]).unwrap().adapted {
            let r = nav.last_adaptation();
            gaps.push(r.ld.mean_real - r.ld.mean_fake);
            dists.push(dist(nav.generated_feature()));
        }
    }
    let d1 = dist(nav.generated_feature());
    assert_eq!(nav.counters().adaptations, 30);
    assert_eq!(nav.counters().rollbacks, 0);
    eprintln!("distances {dists:?}");
    eprintln!("distance {d0} -> {d1}; D gaps E[D(s)] - E[D(x)]: {gaps:?}");
    // Eq. 1: D learns to score the observations above G's features.
    assert!(
        gaps.iter().skip(1).all(|g| *g > 0.0),
        "D must separate real from generated: {gaps:?}"
    );
    // Eq. 3: G follows D towards the observations, at every update.
    assert!(
        dists.windows(2).all(|w| w[1] < w[0]),
        "distance must shrink at every update: {dists:?}"
    );
    assert!(
        d1 < 0.7 * d0,
        "G's output must move towards the observations: {d0} -> {d1}"
    );
    // (With these deliberately large rates, running on past ~40 updates overshoots and
    // oscillates: plain simultaneous gradient steps on a WGAN do not converge. The device
    // runs at most `max_inner_updates` = 4 steps of rate 1e-4 per episode.)
}

/// `Navigator::generator_output` is G at the current θ: with z = 0 it equals x_t of the
/// zero-noise mode before and after inner updates, it moves when they move G, and probing it
/// changes nothing the navigator does next (the firmware prints it between steps).
#[test]
fn generator_output_probes_g_without_changing_the_episode() {
    let dims = Dims::MCU;
    let w = weights(&dims, 8, 0.05);
    let run = |probe: bool, noise: NoiseMode| {
        let cfg = NavConfig {
            model: ModelSpec {
                inner_lr: 0.2,
                max_inner: 3,
                noise,
                inner_rule: InnerRule {
                    disc_lr: Some(0.05),
                    ..InnerRule::PAPER
                },
                ..NavConfig::default().model
            },
            ..NavConfig::default()
        };
        let mut arena = vec![0.0f32; Navigator::<Efficient, 10>::arena_len(&dims)];
        let mut nav: Navigator<'_, Efficient, 10> =
            Navigator::new(nav_weights(&dims, &w), &mut arena, cfg).unwrap();
        nav.reset(&[0.4; 45], 3).unwrap();
        let z0 = vec![0.0f32; dims.noise];
        let mut x = vec![0.0f32; dims.feat];
        let mut rng = Xoshiro128::seed_from_u64(4);
        let mut trace = Vec::new();
        let mut probes = Vec::new();
        for _ in 0..35 {
            if probe {
                nav.generator_output(&z0, &mut x).unwrap();
                probes.push(x.clone());
            }
            let obs: Vec<f32> = (0..512).map(|_| uniform(&mut rng)).collect();
            let out = nav.step(&obs, &[]).unwrap();
            trace.push((
                out.action.index(),
                out.value.to_bits(),
                out.probs.map(f32::to_bits),
            ));
            // (A step that ran an inner update generated its x_t before the update.)
            if probe && noise == NoiseMode::Zero && !out.adapted {
                nav.generator_output(&z0, &mut x).unwrap();
                assert_eq!(
                    x.iter().map(|v| v.to_bits()).collect::<Vec<_>>(),
                    nav.generated_feature()
                        .iter()
                        .map(|v| v.to_bits())
                        .collect::<Vec<_>>(),
                    "G(SE(y), 0) is x_t in the zero-noise mode"
                );
            }
        }
        assert_eq!(nav.counters().adaptations, 3);
        let bits = nav
            .generated_feature()
            .iter()
            .map(|v| v.to_bits())
            .collect::<Vec<_>>();
        (trace, bits, probes)
    };
    for noise in [NoiseMode::Zero, NoiseMode::Gaussian] {
        let (t0, x0, _) = run(false, noise);
        let (t1, x1, probes) = run(true, noise);
        assert_eq!(t0, t1, "probing G must not change the episode ({noise:?})");
        assert_eq!(x0, x1);
        let moved = probes.first().zip(probes.last()).map(|(a, b)| {
            a.iter()
                .zip(b)
                .map(|(p, q)| (p - q).powi(2))
                .sum::<f32>()
                .sqrt()
        });
        assert!(moved.unwrap() > 1e-3, "the inner updates move G: {moved:?}");
    }
    let mut arena = vec![0.0f32; Navigator::<Efficient, 10>::arena_len(&dims)];
    let mut nav: Navigator<'_, Efficient, 10> =
        Navigator::new(nav_weights(&dims, &w), &mut arena, NavConfig::default()).unwrap();
    let mut x = vec![0.0f32; dims.feat];
    assert!(
        nav.generator_output(&[0.0; 45], &mut x).is_err(),
        "before reset"
    );
    nav.reset(&[0.4; 45], 3).unwrap();
    assert!(nav.generator_output(&[0.0; 44], &mut x).is_err(), "wrong z");
    assert!(
        nav.generator_output(&[f32::NAN; 45], &mut x).is_err(),
        "NaN z"
    );
    assert!(
        nav.generator_output(&[0.0; 45], &mut x[..511]).is_err(),
        "wrong out"
    );
}

/// `head_only` (the reference's default): the inner updates move the actor head and leave G
/// exactly at θ; without it both move.
#[test]
fn head_only_adapts_the_actor_head_and_not_g() {
    let dims = Dims::MCU;
    let w = weights(&dims, 8, 0.05);
    let run = |head_only: bool| {
        let cfg = NavConfig {
            model: ModelSpec {
                inner_lr: 0.2,
                max_inner: 3,
                inner_rule: InnerRule {
                    disc_lr: Some(0.05),
                    head_only,
                    ..InnerRule::PAPER
                },
                ..NavConfig::default().model
            },
            ..NavConfig::default()
        };
        let mut arena = vec![0.0f32; Navigator::<Efficient, 10>::arena_len(&dims)];
        let mut nav: Navigator<'_, Efficient, 10> =
            Navigator::new(nav_weights(&dims, &w), &mut arena, cfg).unwrap();
        nav.reset(&[0.4; 45], 3).unwrap();
        let z0 = vec![0.0f32; dims.noise];
        let (mut g0, mut g1) = (vec![0.0f32; dims.feat], vec![0.0f32; dims.feat]);
        nav.generator_output(&z0, &mut g0).unwrap();
        let head0 = core_layer(&nav.policy().unwrap().actor, true);
        let mut rng = Xoshiro128::seed_from_u64(4);
        for _ in 0..35 {
            let obs: Vec<f32> = (0..512).map(|_| uniform(&mut rng)).collect();
            nav.step(&obs, &[]).unwrap();
        }
        let c = nav.counters();
        assert_eq!(
            (c.adaptations, c.rollbacks),
            (3, 0),
            "head_only {head_only}"
        );
        nav.generator_output(&z0, &mut g1).unwrap();
        let head1 = core_layer(&nav.policy().unwrap().actor, true);
        let g_moved = g0.iter().zip(&g1).any(|(a, b)| a.to_bits() != b.to_bits());
        (g_moved, head0 != head1)
    };
    assert_eq!(
        run(true),
        (false, true),
        "head only: G fixed, the head moves"
    );
    assert_eq!(run(false), (true, true), "the paper: both move");
}

/// A host may run the policy trunk of many navigators as one batch
/// (`begin_step` / `Policy::forward_batch` / `finish_step`): every navigator then gives the
/// bits of its own `step`, inner updates included.
#[test]
fn batched_trunk_with_begin_and_finish_step_is_step_bit_for_bit() {
    batched_trunk_is_step(false);
}

/// The same with G of all navigators as one batch (`begin_step_defer_g`, `generate_batch`):
/// every navigator's own gains (adapted three times), the same bits as `step`.
#[test]
fn batched_generator_is_step_bit_for_bit() {
    batched_trunk_is_step(true);
}

fn batched_trunk_is_step(defer: bool) {
    let dims = Dims::MCU;
    let w = weights(&dims, 8, 0.05);
    let cfg = NavConfig {
        model: ModelSpec {
            inner_lr: 0.2,
            max_inner: 3,
            inner_rule: InnerRule {
                disc_lr: Some(0.05),
                ..InnerRule::PAPER
            },
            ..NavConfig::default().model
        },
        ..NavConfig::default()
    };
    const B: usize = 3;
    let alen = Navigator::<Efficient, 10>::arena_len(&dims);
    let mut arenas: Vec<Vec<f32>> = (0..2 * B).map(|_| vec![0.0f32; alen]).collect();
    let (ref_arenas, bat_arenas) = arenas.split_at_mut(B);
    fn mk<'a>(
        w: NavWeights<'a>,
        a: &'a mut [f32],
        cfg: NavConfig,
        b: usize,
    ) -> Navigator<'a, Efficient, 10> {
        let mut nav = Navigator::new(w, a, cfg).unwrap();
        nav.reset(&[0.1 + 0.2 * b as f32; 45], 3 + b as u64)
            .unwrap();
        nav
    }
    let nw = || nav_weights(&dims, &w);
    let mut refs: Vec<_> = (ref_arenas.iter_mut().enumerate())
        .map(|(b, a)| mk(nw(), a, cfg, b))
        .collect();
    let mut bats: Vec<_> = (bat_arenas.iter_mut().enumerate())
        .map(|(b, a)| mk(nw(), a, cfg, b))
        .collect();
    let (f, lh) = (dims.feat, dims.lstm_hidden);
    let mut rng = Xoshiro128::seed_from_u64(4);
    let mut adapted = 0;
    for t in 0..35 {
        let obs: Vec<Vec<f32>> = (0..B)
            .map(|_| (0..f).map(|_| uniform(&mut rng)).collect())
            .collect();
        if defer {
            let mut pending = Vec::new();
            for (b, (nav, o)) in bats.iter_mut().zip(&obs).enumerate() {
                if nav.begin_step_defer_g(o, &[], &[]).unwrap() {
                    pending.push(b);
                }
            }
            assert_eq!(pending, [0, 1, 2], "Efficient, Gaussian noise: G deferred");
            assert!(bats[0]
                .finish_step(&obs[0], &[0.0; 64], &[0.0; 64])
                .is_err());
            let mut scratch =
                vec![0.0f32; Navigator::<Efficient, 10>::generate_batch_scratch_len(&dims, B)];
            // Repeated or out-of-range indices and short scratch are refused.
            assert!(Navigator::generate_batch(&mut bats, &[0, 0], &mut scratch).is_err());
            assert!(Navigator::generate_batch(&mut bats, &[0, 7], &mut scratch).is_err());
            assert!(Navigator::generate_batch(&mut bats, &pending, &mut scratch[1..]).is_err());
            // In two groups, the second of two navigators: any grouping gives the same bits.
            Navigator::generate_batch(&mut bats, &pending[..1], &mut scratch).unwrap();
            assert!(Navigator::generate_batch(&mut bats, &pending[..1], &mut scratch).is_err());
            Navigator::generate_batch(&mut bats, &pending[1..], &mut scratch).unwrap();
        } else {
            for (nav, o) in bats.iter_mut().zip(&obs) {
                nav.begin_step(o, &[], &[]).unwrap();
            }
        }
        // The trunk of all B navigators in one batch (the view's actor head is the first
        // navigator's; only h and c are used).
        let cat = |g: &dyn Fn(usize) -> Vec<f32>| (0..B).flat_map(g).collect::<Vec<f32>>();
        let feat = cat(&|b| bats[b].generated_feature().to_vec());
        let attr = cat(&|b| bats[b].attr().to_vec());
        let prev = cat(&|b| bats[b].prev_probs().to_vec());
        let (hp, cp) = (
            cat(&|b| bats[b].hidden_state().to_vec()),
            cat(&|b| bats[b].cell_state().to_vec()),
        );
        let obs_cat: Vec<f32> = obs.concat();
        let e = dims.embed;
        let mut c1 = (
            vec![0.0; B * f],
            vec![0.0; B * e],
            vec![0.0; B * 4 * lh],
            vec![0.0; B * lh],
            vec![0.0; B * lh],
            vec![0.0; B * NUM_ACTIONS],
            vec![0.0; B * NUM_ACTIONS],
            vec![0.0; B * NUM_ACTIONS],
            vec![0.0; B],
        );
        {
            let policy = bats[0].policy().unwrap();
            let inp = PolicyInput {
                obs: &obs_cat,
                feat: &feat,
                attr: &attr,
                prev_probs: &prev,
                ps: &[],
                map: &[],
            };
            let mut cache = PolicyCache {
                prod: &mut c1.0,
                fuse: &mut c1.1,
                gates: &mut c1.2,
                c: &mut c1.3,
                h: &mut c1.4,
                actor_u: &mut c1.5,
                logits: &mut c1.6,
                probs: &mut c1.7,
                value: &mut c1.8,
                cell: &mut [],
                cell_prod: &mut [],
            };
            policy.forward_batch(B, &inp, &hp, &cp, &mut cache).unwrap();
        }
        for b in 0..B {
            let want = refs[b].step(&obs[b], &[]).unwrap();
            let (h, c) = (&c1.4[b * lh..(b + 1) * lh], &c1.3[b * lh..(b + 1) * lh]);
            let got = bats[b].finish_step(&obs[b], h, c).unwrap();
            assert_eq!(got.action, want.action, "t={t} b={b}");
            assert_eq!(got.value.to_bits(), want.value.to_bits(), "t={t} b={b}");
            assert_eq!(got.probs.map(f32::to_bits), want.probs.map(f32::to_bits));
            assert_eq!(got.adapted, want.adapted);
            adapted += got.adapted as u32;
        }
    }
    assert_eq!(adapted, 3 * B as u32, "every navigator adapted 3 times");
    for (a, b) in refs.iter().zip(&bats) {
        let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
        assert_eq!(bits(a.generated_feature()), bits(b.generated_feature()));
        assert_eq!(bits(a.hidden_state()), bits(b.hidden_state()));
    }
    // The order is enforced.
    assert!(bats[0]
        .finish_step(&[0.5; 512], &[0.0; 64], &[0.0; 64])
        .is_err());
}

/// The CosSim EMD variant adapts G and the actor head without touching D.
#[test]
fn cossim_variant_adapts_without_discriminator() {
    let dims = Dims::MCU;
    let w = weights(&dims, 9, 0.1);
    let cfg = NavConfig {
        model: ModelSpec {
            emd: gman_core::navigator::Emd::CosSim,
            inner_lr: 0.05,
            ..NavConfig::default().model
        },
        ..NavConfig::default()
    };
    let mut arena = vec![0.0f32; Navigator::<Full, 5>::arena_len(&dims)];
    let mut nav: Navigator<'_, Full, 5> =
        Navigator::new(nav_weights(&dims, &w), &mut arena, cfg).unwrap();
    nav.reset(&[0.2; 45], 1).unwrap();
    let before = core_snapshot(&nav, false);
    let mut rng = Xoshiro128::seed_from_u64(3);
    for _ in 0..10 {
        let obs: Vec<f32> = (0..512).map(|_| uniform(&mut rng)).collect();
        nav.step(&obs, &[]).unwrap();
    }
    let after = core_snapshot(&nav, false);
    let c = nav.counters();
    assert_eq!((c.adaptations, c.rollbacks), (2, 0));
    assert!(!nav.last_adaptation().disc_applied && nav.last_adaptation().adapt_applied);
    assert_eq!(before[2], after[2], "D layer 1 untouched");
    assert_eq!(before[3], after[3], "D output untouched");
    assert_ne!(before[0], after[0], "G adapted");
    assert_ne!(before[4], after[4], "actor head adapted");
}

/// The inner rule's levers: the normalised step moves the adapted parameters
/// (θ and the actor head) by exactly α2 in L2, the per-group step moves θ and the head by α2
/// each, more D steps move ω further, and D's head restarts at zero when asked.
#[test]
fn inner_rule_levers_do_what_they_say() {
    use gman_core::navigator::StepRule;
    let dims = Dims::MCU;
    let w = weights(&dims, 8, 0.05);
    let run_with = |disc_steps: u32, step_rule: StepRule, disc_head_reset: bool| {
        let cfg = NavConfig {
            model: ModelSpec {
                inner_lr: 0.3,
                max_inner: 1,
                noise: NoiseMode::Zero,
                inner_rule: InnerRule {
                    disc_lr: Some(0.05),
                    disc_steps,
                    step_rule,
                    disc_head_reset,
                    ..InnerRule::PAPER
                },
                ..NavConfig::default().model
            },
            ..NavConfig::default()
        };
        let mut arena = vec![0.0f32; Navigator::<Full, 10>::arena_len(&dims)];
        let mut nav: Navigator<'_, Full, 10> =
            Navigator::new(nav_weights(&dims, &w), &mut arena, cfg).unwrap();
        nav.reset(&[0.4; 45], 3).unwrap();
        let before = core_snapshot(&nav, false);
        let mut rng = Xoshiro128::seed_from_u64(4);
        while nav.counters().adaptations == 0 {
            let obs: Vec<f32> = (0..512).map(|_| uniform(&mut rng)).collect();
            nav.step(&obs, &[]).unwrap();
        }
        assert_eq!(nav.counters().rollbacks, 0);
        let after = core_snapshot(&nav, false);
        let moved = |layers: &[usize]| -> f64 {
            layers
                .iter()
                .map(|&l| {
                    let (a, b) = (&before[l], &after[l]);
                    let s: f64 = sub(&a.0, &b.0)
                        .iter()
                        .chain(sub(&a.1, &b.1).iter())
                        .map(|v| v * v)
                        .sum();
                    s
                })
                .sum::<f64>()
                .sqrt()
        };
        let head_zero = before[3].0.iter().chain(&before[3].1).all(|v| *v == 0.0);
        // The next episode: with the reset, D starts again from ω (layer 1) and zero (head);
        // without it, D keeps what it learned.
        nav.reset(&[0.4; 45], 4).unwrap();
        let next = core_snapshot(&nav, false);
        assert_eq!(
            (next[2] == before[2], next[3] == before[3]),
            (disc_head_reset, disc_head_reset),
            "D across episodes (reset: {disc_head_reset})"
        );
        (
            moved(&[0, 1, 4]),
            moved(&[2, 3]),
            moved(&[0, 1]),
            moved(&[4]),
            head_zero,
        )
    };
    let run = |disc_steps: u32, step_rule: StepRule| {
        let (both, omega, _, _, head_zero) = run_with(disc_steps, step_rule, false);
        assert!(!head_zero, "D's head is the weights' without the reset");
        (both, omega)
    };
    let (_, _, theta, head, _) = run_with(1, StepRule::PerGroup, false);
    assert!(
        (theta - 0.3).abs() < 1e-3 && (head - 0.3).abs() < 1e-3,
        "a per-group step of length 0.3 moved θ by {theta} and the head by {head}"
    );
    let (_, omega_reset, _, _, head_zero) = run_with(1, StepRule::Gradient, true);
    assert!(head_zero, "D's head restarts at zero with the episode");
    assert!(omega_reset > 0.0, "D still learns from the buffer");
    let (theta_norm, _) = run(1, StepRule::Normalized);
    assert!(
        (theta_norm - 0.3).abs() < 1e-3,
        "a normalised step of length 0.3 moved θ, φ by {theta_norm}"
    );
    let (theta_grad, omega_1) = run(1, StepRule::Gradient);
    assert!(
        (theta_grad - 0.3).abs() > 1e-2,
        "the gradient step is not normalised: {theta_grad}"
    );
    let (_, omega_3) = run(3, StepRule::Gradient);
    assert!(
        omega_1 > 0.0 && omega_3 > 1.05 * omega_1,
        "ω moved {omega_1} with 1 step, {omega_3} with 3"
    );
}

/// With zero noise the navigator keeps the fusion layer's terms of x_t and SE(y) between two
/// inner updates (the integer path, `Policy::fuse_terms`). Over two targets (a reset with
/// another SE(y)) and several commits, `step_map` and `step_map_u8` give the bits of the same
/// navigator driven through `begin_step` / `finish_step` with the trunk computed by
/// `Policy::forward` / `forward_map_u8`, which quantise every segment at every step.
#[test]
fn zero_noise_fusion_cache_is_recomputing_every_segment_bit_for_bit() {
    use gman_core::blob::Blob;
    let dims = Dims::MCU.with_map(3, 3, 8);
    let bytes = gman_host_sim::seeded::int8_blob(&dims, 5, 0.05).unwrap();
    let bytes = gman_host_sim::blob_edit::reencode_with_activations(&bytes, true).unwrap();
    let blob = Blob::parse(&bytes).unwrap();
    let cfg = NavConfig {
        model: ModelSpec {
            adapt: true,
            inner_lr: 0.5,
            max_inner: 10,
            noise: NoiseMode::Zero,
            inner_rule: InnerRule {
                disc_lr: Some(0.05),
                commit_delay: 0,
                ..InnerRule::PAPER
            },
            ..NavConfig::default().model
        },
        ..NavConfig::default()
    };
    for u8_map in [false, true] {
        const K: usize = 10;
        let alen = Navigator::<Efficient, K>::arena_len(&dims);
        let (mut a1, mut a2) = (vec![0.0f32; alen], vec![0.0f32; alen]);
        let w = || NavWeights::from_blob(&blob, &dims).unwrap();
        let mut cached: Navigator<'_, Efficient, K> = Navigator::new(w(), &mut a1, cfg).unwrap();
        let mut plain: Navigator<'_, Efficient, K> = Navigator::new(w(), &mut a2, cfg).unwrap();
        assert!(cached.policy().unwrap().keeps_fuse_terms(), "int8 path");
        let (f, e, lh) = (dims.feat, dims.embed, dims.lstm_hidden);
        let (cells, ce) = (dims.map_cells(), dims.cell_embed);
        let mut rng = Xoshiro128::seed_from_u64(21);
        let mut commits = 0;
        for (ep, steps) in [(0u64, 47usize), (1, 33)] {
            let attr: Vec<f32> = (0..dims.attr).map(|_| uniform(&mut rng)).collect();
            cached.reset(&attr, 70 + ep).unwrap();
            plain.reset(&attr, 70 + ep).unwrap();
            for t in 0..steps {
                let obs: Vec<f32> = (0..f).map(|_| uniform(&mut rng)).collect();
                let codes: Vec<u8> = (0..dims.map_len())
                    .map(|_| (uniform(&mut rng) * 255.0) as u8)
                    .collect();
                let scale = 1.0 / 255.0;
                let map: Vec<f32> = codes.iter().map(|&q| q as f32 * scale).collect();
                let want = if u8_map {
                    cached.step_map_u8(&obs, &codes, scale, &[]).unwrap()
                } else {
                    cached.step_map(&obs, &map, &[]).unwrap()
                };
                plain.begin_step(&obs, &map, &[]).unwrap();
                let mut c = (
                    vec![0.0; f],
                    vec![0.0; e],
                    vec![0.0; 4 * lh],
                    vec![0.0; lh],
                    vec![0.0; lh],
                    vec![0.0; NUM_ACTIONS],
                    vec![0.0; NUM_ACTIONS],
                    vec![0.0; NUM_ACTIONS],
                    vec![0.0; 1],
                    vec![0.0; cells * ce],
                    vec![0.0; f],
                );
                {
                    let policy = plain.policy().unwrap();
                    let inp = PolicyInput {
                        obs: &obs,
                        feat: plain.generated_feature(),
                        attr: plain.attr(),
                        prev_probs: plain.prev_probs(),
                        ps: &[],
                        map: if u8_map { &[] } else { &map },
                    };
                    let mut cache = PolicyCache {
                        prod: &mut c.0,
                        fuse: &mut c.1,
                        gates: &mut c.2,
                        c: &mut c.3,
                        h: &mut c.4,
                        actor_u: &mut c.5,
                        logits: &mut c.6,
                        probs: &mut c.7,
                        value: &mut c.8,
                        cell: &mut c.9,
                        cell_prod: &mut c.10,
                    };
                    let (hp, cp) = (plain.hidden_state(), plain.cell_state());
                    if u8_map {
                        let m = (&codes[..], scale);
                        policy.forward_map_u8(&inp, m, hp, cp, &mut cache).unwrap();
                    } else {
                        policy.forward(&inp, hp, cp, &mut cache).unwrap();
                    }
                }
                let got = plain.finish_step(&obs, &c.4, &c.3).unwrap();
                let at = format!("u8 map {u8_map}, episode {ep}, step {t}");
                assert_eq!(got.action, want.action, "{at}");
                assert_eq!(got.value.to_bits(), want.value.to_bits(), "{at}");
                assert_eq!(
                    got.probs.map(f32::to_bits),
                    want.probs.map(f32::to_bits),
                    "{at}"
                );
                assert_eq!(got.adapted, want.adapted, "{at}");
                commits += want.adapted as u32;
            }
        }
        assert!(commits >= 6, "u8 map {u8_map}: {commits} commits");
        let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
        assert_eq!(
            bits(cached.generated_feature()),
            bits(plain.generated_feature())
        );
        assert_eq!(bits(cached.hidden_state()), bits(plain.hidden_state()));
    }
}
