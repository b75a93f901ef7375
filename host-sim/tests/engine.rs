//! The rollout engine's training episodes (`--batch-envs B`) against one episode at a time
//! (`train_episode`) and against gman-core's navigator run alone:
//!
//! * with `B = 1` a worker's update (gradient, episode statistics) is bit for bit the sum of
//!   its episodes run one at a time, for every configuration (FG or not, Full or Efficient
//!   mode, θ trained, spatial map, DAgger, the privileged feature, PS input);
//! * every episode of the methods without an inner loop takes the actions a gman-core
//!   navigator takes alone over the model (its own `step_map`; the shared lanes compute
//!   the step from its views);
//! * with `B > 1` every episode is bit for bit the episode the navigator runs alone, the
//!   gradient is the same sum in the new, pinned order (checked against the per-episode
//!   gradients summed in that order exactly, and within a float tolerance of the batch-1 sum),
//!   and a run is reproducible and resumes bit for bit;
//! * the same for the methods with an inner loop (`gman`, ...: one navigator per episode,
//!   per-row adapted heads and θ_i): `B = 1` is the one-at-a-time update bit for bit, with `B > 1` each episode (actions, inner updates, D after
//!   it) is the episode run alone, the gradient is the per-episode sum within float rounding,
//!   runs are reproducible and resume bit for bit; `--meta-order 2` refuses `B > 1`.

use gman_core::navigator::memory::AdaptMode;
use gman_core::navigator::{Efficient, Full, Mode, Navigator, NoiseMode};
use gman_core::Dims;
use gman_host_sim::model::{Method, NavModel, K};
use gman_host_sim::optim::adam::AdamConfig;
use gman_host_sim::optim::params::ParamSet;
use gman_host_sim::pretrain::generator::init_generator;
use gman_host_sim::sim::spatial::MapGrid;
use gman_host_sim::sim::{Env, EpisodeLimits, EpisodeSpec, RewardKind, World};
use gman_host_sim::train::a3c::{A3cConfig, Objective};
use gman_host_sim::train::engine::run_worker;
use gman_host_sim::train::lockstep::VecSettings;
use gman_host_sim::train::rollout::{EpisodeStats, Worker};
use gman_host_sim::train::state::{RunSettings, TrainState};
use gman_host_sim::train::trainer::train_episode;
use gman_host_sim::train::trainer::{train, TrainOptions};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

fn model(method: Method, dims: Dims, mode: AdaptMode, seed: u64) -> NavModel {
    let mut rng = gman_core::rng::Xoshiro128::seed_from_u64(seed);
    let g = init_generator(&dims, &mut rng).unwrap();
    let mut m = NavModel::init(method, dims, seed, Some(&g), None).unwrap();
    m.spec.adapt_mode = mode;
    m
}

fn sampler(world: &World, seed: u64) -> impl FnMut(u32) -> anyhow::Result<(EpisodeSpec, u32)> + '_ {
    sampler_max(world, seed, 30)
}

/// The batch-1 trainer's worker loop (trainer.rs) over the same episodes.
fn batch1(
    world: &World,
    m: &NavModel,
    objective: Objective,
    min_steps: u32,
    seed: u64,
) -> (ParamSet, Vec<EpisodeStats>) {
    let mut worker = Worker::new(m);
    let mut grads = m.params.zeros_like();
    let mut sample = sampler(world, seed);
    let (mut out, mut steps, mut e) = (Vec::new(), 0u32, 0u32);
    while e == 0 || steps < min_steps {
        let (spec, max) = sample(e).unwrap();
        let (st, _) = train_episode(
            world,
            &spec,
            m,
            RewardKind::Mixed,
            max,
            &A3cConfig::default(),
            objective,
            1,
            &mut worker,
            &mut grads,
        )
        .unwrap();
        steps += st.steps;
        e += 1;
        out.push(st);
    }
    (grads, out)
}

fn vectorised(
    world: &World,
    m: &NavModel,
    objective: Objective,
    min_steps: u32,
    seed: u64,
    b: usize,
) -> (ParamSet, Vec<EpisodeStats>) {
    let (g, done) = vectorised_with_disc(world, m, objective, min_steps, seed, b);
    (g, done.into_iter().map(|f| f.0).collect())
}

/// Each finished episode's statistics and D after it.
type Done = Vec<(EpisodeStats, Vec<Vec<f32>>)>;

fn vectorised_with_disc(
    world: &World,
    m: &NavModel,
    objective: Objective,
    min_steps: u32,
    seed: u64,
    b: usize,
) -> (ParamSet, Done) {
    vectorised_adapt(world, m, objective, min_steps, seed, 30, b)
}

fn same_bits(a: &ParamSet, b: &ParamSet, what: &str) {
    let mut nonzero = false;
    for (x, y) in a.tensors.iter().zip(&b.tensors) {
        assert_eq!(x.name, y.name);
        for (i, (u, v)) in x.data.iter().zip(&y.data).enumerate() {
            assert_eq!(
                u.to_bits(),
                v.to_bits(),
                "{what}: {}[{i}]: {u} vs {v}",
                x.name
            );
            nonzero |= *u != 0.0;
        }
    }
    assert!(nonzero, "{what}: the gradient is all zero");
}

fn same_episode(a: &EpisodeStats, b: &EpisodeStats, what: &str) {
    assert_eq!(a.actions, b.actions, "{what}: actions");
    assert_eq!(a.steps, b.steps, "{what}: steps");
    assert_eq!(a.success, b.success, "{what}: success");
    assert_eq!(
        a.total_reward.to_bits(),
        b.total_reward.to_bits(),
        "{what}: reward"
    );
    assert_eq!(a.loss, b.loss, "{what}: loss parts");
    assert_eq!(a.adaptations, b.adaptations, "{what}: inner updates");
    assert_eq!(a.rollbacks, b.rollbacks, "{what}: rollbacks");
    assert_eq!(
        a.disc_gap.to_bits(),
        b.disc_gap.to_bits(),
        "{what}: D's gap over the inner updates"
    );
    assert_eq!(
        a.adapt_loss.to_bits(),
        b.adapt_loss.to_bits(),
        "{what}: L_ad over the inner updates"
    );
    let fb = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
    assert_eq!(fb(&a.final_feature), fb(&b.final_feature), "{what}: x_t");
}

fn same_disc(a: &[Vec<f32>], b: &[Vec<f32>], what: &str) {
    assert_eq!(a.len(), b.len(), "{what}: D tensors");
    for (x, y) in a.iter().zip(b) {
        let fb = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
        assert_eq!(fb(x), fb(y), "{what}: D after the episode");
    }
}

struct Case {
    name: &'static str,
    method: Method,
    dims: Dims,
    mode: AdaptMode,
    objective: Objective,
    privileged: bool,
    noise: NoiseMode,
}

fn cases() -> Vec<Case> {
    let c = |name, method, dims, mode| Case {
        name,
        method,
        dims,
        mode,
        objective: Objective::A3c,
        privileged: false,
        noise: NoiseMode::Gaussian,
    };
    vec![
        c(
            "a3c-fg efficient",
            Method::A3cFg,
            Dims::MCU,
            AdaptMode::Efficient,
        ),
        c("a3c-fg full", Method::A3cFg, Dims::MCU, AdaptMode::Full),
        c("a3c", Method::A3c, Dims::MCU, AdaptMode::Efficient),
        c(
            "gman-noemd (trains G)",
            Method::GmanNoemd,
            Dims::MCU,
            AdaptMode::Efficient,
        ),
        c(
            "gman-noemd full",
            Method::GmanNoemd,
            Dims::MCU,
            AdaptMode::Full,
        ),
        c(
            "a3c-fg map 2x2",
            Method::A3cFg,
            Dims::MCU.with_map(2, 2, 4),
            AdaptMode::Full,
        ),
        Case {
            objective: Objective::Dagger,
            ..c(
                "a3c-fg dagger",
                Method::A3cFg,
                Dims::MCU,
                AdaptMode::Efficient,
            )
        },
        Case {
            privileged: true,
            ..c(
                "a3c-fg privileged",
                Method::A3cFg,
                Dims::MCU,
                AdaptMode::Efficient,
            )
        },
        Case {
            noise: NoiseMode::Zero,
            ..c(
                "gman-noemd zero noise",
                Method::GmanNoemd,
                Dims::MCU,
                AdaptMode::Full,
            )
        },
    ]
}

fn case_model(c: &Case) -> NavModel {
    let mut m = model(c.method, c.dims, c.mode, 3);
    m.privileged = c.privileged;
    m.spec.noise = c.noise;
    m
}

#[test]
fn batch_of_one_is_the_batch1_update_bit_for_bit() {
    let world = World::synthetic(7);
    for c in cases() {
        let m = case_model(&c);
        for seed in [1u64, 2] {
            let (ga, sa) = batch1(&world, &m, c.objective, 45, seed);
            let (gb, sb) = vectorised(&world, &m, c.objective, 45, seed, 1);
            assert!(sa.len() >= 2, "{}: several episodes per update", c.name);
            assert_eq!(sa.len(), sb.len(), "{}: episodes", c.name);
            for (k, (a, b)) in sa.iter().zip(&sb).enumerate() {
                same_episode(a, b, &format!("{} seed {seed} episode {k}", c.name));
            }
            same_bits(&ga, &gb, c.name);
        }
    }
}

#[test]
fn batched_episodes_are_the_episodes_run_alone() {
    let world = World::synthetic(7);
    for c in cases() {
        let m = case_model(&c);
        let b = 5;
        let (g, st) = vectorised(&world, &m, c.objective, 60, 4, b);
        assert!(st.len() >= b, "{}: at least B episodes", c.name);
        // Each episode alone, through the batch-1 runner (navigator) into its own gradient.
        let mut sum = m.params.zeros_like();
        let mut sample = sampler(&world, 4);
        for (k, s) in st.iter().enumerate() {
            let mut worker = Worker::new(&m);
            let mut ge = m.params.zeros_like();
            let (spec, max) = sample(k as u32).unwrap();
            let (alone, _) = train_episode(
                &world,
                &spec,
                &m,
                RewardKind::Mixed,
                max,
                &A3cConfig::default(),
                c.objective,
                1,
                &mut worker,
                &mut ge,
            )
            .unwrap();
            same_episode(s, &alone, &format!("{} episode {k}", c.name));
            assert_eq!(
                s.actions,
                navigator_actions(&world, &m, &spec, max),
                "{} episode {k}: the navigator alone",
                c.name
            );
            sum.add_assign(&ge).unwrap();
        }
        // The batched sum adds the same terms in another order: equal within float rounding.
        for (x, y) in g.tensors.iter().zip(&sum.tensors) {
            let scale = y.data.iter().fold(0.0f32, |a, v| a.max(v.abs())).max(1e-6);
            for (u, v) in x.data.iter().zip(&y.data) {
                assert!(
                    (u - v).abs() <= 1e-4 * scale,
                    "{}: {} {u} vs {v} (scale {scale})",
                    c.name,
                    x.name
                );
            }
        }
        // ... and the order is fixed: the same batch gives the same bits.
        let (g2, _) = vectorised(&world, &m, c.objective, 60, 4, b);
        same_bits(&g, &g2, c.name);
    }
}

/// The actions of the episode `spec` run by a gman-core navigator alone over the model (its
/// own `step_map`, no training): what every training lane must reproduce.
fn navigator_actions(world: &World, m: &NavModel, spec: &EpisodeSpec, max: u32) -> Vec<u8> {
    match m.spec.adapt_mode {
        AdaptMode::Full => navigator_actions_in::<Full>(world, m, spec, max),
        AdaptMode::Efficient => navigator_actions_in::<Efficient>(world, m, spec, max),
    }
}

fn navigator_actions_in<M: Mode>(
    world: &World,
    m: &NavModel,
    spec: &EpisodeSpec,
    max: u32,
) -> Vec<u8> {
    let mut arena = vec![0.0; m.arena_len()];
    let mut nav: Navigator<'_, M, K> =
        Navigator::new(m.weights().unwrap(), &mut arena, m.nav_config(true)).unwrap();
    nav.reset(world.attributes(spec.target), spec.seed).unwrap();
    if m.privileged {
        nav.fix_generated_feature(&world.object_feature(spec.scene, spec.target))
            .unwrap();
    }
    let mut env = Env::new(world, spec, RewardKind::Mixed, max);
    let grid = MapGrid {
        rows: m.dims.map_rows,
        cols: m.dims.map_cols,
    };
    let mut map = vec![0.0; m.dims.map_len()];
    let mut actions = Vec::new();
    while !env.is_done() {
        let obs = env.observe();
        if !grid.is_empty() {
            env.observe_map(grid, &mut map);
        }
        let out = nav.step_map(&obs.features, &map, &[]).unwrap();
        actions.push(out.action.index() as u8);
        env.step(out.action);
    }
    actions
}

fn opts(out: std::path::PathBuf, updates: u64, b: usize) -> TrainOptions {
    TrainOptions {
        updates,
        run: RunSettings {
            seed: 3,
            batch_envs: b,
            min_steps: 20,
            max_steps: Some(40),
            adam: AdamConfig {
                lr: 1e-3,
                ..AdamConfig::default()
            },
            ..RunSettings::default()
        },
        checkpoint_every: 2,
        out,
        progress: false,
    }
}

fn tmp(name: &str) -> std::path::PathBuf {
    let d = std::env::temp_dir().join(format!("gman-vec-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}

fn state(method: Method) -> TrainState {
    TrainState::new(
        model(method, Dims::MCU, AdaptMode::Efficient, 1),
        AdamConfig {
            lr: 1e-3,
            ..AdamConfig::default()
        },
    )
}

#[test]
fn batched_runs_are_reproducible_and_resume_bit_for_bit() {
    let world = World::synthetic(7);
    let a = tmp("straight");
    let mut sa = state(Method::GmanNoemd);
    train(&world, &opts(a.clone(), 4, 3), &mut sa).unwrap();
    let b = tmp("resumed");
    let mut sb = state(Method::GmanNoemd);
    train(&world, &opts(b.clone(), 2, 3), &mut sb).unwrap();
    let ck = gman_host_sim::train::run_dir::checkpoint_path(&b);
    let (mut sb, t) = TrainState::load_with_settings(&ck).unwrap();
    assert_eq!(t.run.batch_envs, 3, "B is stored in the checkpoint");
    train(&world, &opts(b.clone(), 4, 3), &mut sb).unwrap();
    assert_eq!(sa.env_steps, sb.env_steps);
    for (x, y) in sa.model.params.tensors.iter().zip(&sb.model.params.tensors) {
        let bx: Vec<u32> = x.data.iter().map(|v| v.to_bits()).collect();
        let by: Vec<u32> = y.data.iter().map(|v| v.to_bits()).collect();
        assert_eq!(bx, by, "{}", x.name);
    }
    // B = 3 is a different run from B = 1 (more episodes per update).
    let c = tmp("b1");
    let mut sc = state(Method::GmanNoemd);
    train(&world, &opts(c.clone(), 4, 1), &mut sc).unwrap();
    assert!(sc.episodes < sa.episodes);
    for d in [a, b, c] {
        let _ = std::fs::remove_dir_all(d);
    }
}

// ---------------------------------------------------------------------------------------
// The methods with an inner loop (one navigator per episode)
// ---------------------------------------------------------------------------------------

fn sampler_max(
    world: &World,
    seed: u64,
    max: u32,
) -> impl FnMut(u32) -> anyhow::Result<(EpisodeSpec, u32)> + '_ {
    move |e| {
        let mut rng = ChaCha8Rng::seed_from_u64(seed.wrapping_mul(1000).wrapping_add(e as u64));
        let spec = world.try_sample_train_episode_min(&mut rng, 1)?;
        let max = max.min(EpisodeLimits::default().for_room(spec.room));
        Ok((spec, max))
    }
}

/// Episode `e` alone through the batch-1 runner, into `grads`; its statistics and D after.
fn alone(
    world: &World,
    m: &NavModel,
    objective: Objective,
    spec_max: (EpisodeSpec, u32),
    grads: &mut ParamSet,
) -> (EpisodeStats, Vec<Vec<f32>>) {
    let mut worker = Worker::new(m);
    train_episode(
        world,
        &spec_max.0,
        m,
        RewardKind::Mixed,
        spec_max.1,
        &A3cConfig::default(),
        objective,
        1,
        &mut worker,
        grads,
    )
    .unwrap()
}

/// The batch-1 worker loop over `sampler_max(seed, max)`.
fn batch1_adapt(
    world: &World,
    m: &NavModel,
    objective: Objective,
    min_steps: u32,
    seed: u64,
    max: u32,
) -> (ParamSet, Done) {
    let mut grads = m.params.zeros_like();
    let mut sample = sampler_max(world, seed, max);
    let (mut out, mut steps, mut e) = (Vec::new(), 0u32, 0u32);
    while e == 0 || steps < min_steps {
        let (st, disc) = alone(world, m, objective, sample(e).unwrap(), &mut grads);
        steps += st.steps;
        e += 1;
        out.push((st, disc));
    }
    (grads, out)
}

fn vectorised_adapt(
    world: &World,
    m: &NavModel,
    objective: Objective,
    min_steps: u32,
    seed: u64,
    max: u32,
    b: usize,
) -> (ParamSet, Done) {
    let mut worker = Worker::new(m);
    let mut grads = m.params.zeros_like();
    let a3c = A3cConfig::default();
    let s = VecSettings {
        batch_envs: b,
        min_steps,
        reward: RewardKind::Mixed,
        a3c: &a3c,
        objective,
        meta_order: 1,
    };
    let sample = sampler_max(world, seed, max);
    let done = run_worker(world, m, &s, &mut worker, &mut grads, sample).unwrap();
    for (k, f) in done.iter().enumerate() {
        assert_eq!(f.0 as usize, k, "episodes are returned in index order");
    }
    (grads, done.into_iter().map(|f| (f.1, f.2)).collect())
}

/// The configurations of the methods with an inner loop. The actor's Done bias is lowered so
/// that episodes run long enough for inner updates (every k = 20 steps), and α is large
/// enough that each episode's adapted θ_i, φ_i differ visibly from θ, φ.
fn adapt_cases() -> Vec<(Case, f32)> {
    let c = |name, method, dims, mode| Case {
        name,
        method,
        dims,
        mode,
        objective: Objective::A3c,
        privileged: false,
        noise: NoiseMode::Gaussian,
    };
    vec![
        (
            c(
                "gman efficient",
                Method::Gman,
                Dims::MCU,
                AdaptMode::Efficient,
            ),
            0.05,
        ),
        (
            c("gman full", Method::Gman, Dims::MCU, AdaptMode::Full),
            0.01,
        ),
        (
            c(
                "gman-cossim",
                Method::GmanCossim,
                Dims::MCU,
                AdaptMode::Efficient,
            ),
            0.05,
        ),
        (
            c(
                "gman-fixed-g",
                Method::GmanFixedG,
                Dims::MCU,
                AdaptMode::Efficient,
            ),
            0.05,
        ),
        (
            c(
                "gman map 2x2",
                Method::Gman,
                Dims::MCU.with_map(2, 2, 4),
                AdaptMode::Full,
            ),
            0.01,
        ),
        (
            Case {
                objective: Objective::Dagger,
                ..c("gman dagger", Method::Gman, Dims::MCU, AdaptMode::Efficient)
            },
            0.05,
        ),
        (
            Case {
                noise: NoiseMode::Zero,
                ..c(
                    "gman zero noise",
                    Method::Gman,
                    Dims::MCU,
                    AdaptMode::Efficient,
                )
            },
            0.05,
        ),
    ]
}

fn adapt_model(c: &Case, inner_lr: f32) -> NavModel {
    let mut m = case_model(c);
    m.spec.inner_lr = inner_lr;
    let b = m.params.get_mut("ActorB").unwrap();
    b.data[gman_core::Action::Done.index()] -= 4.0;
    m
}

#[test]
fn adapting_batch_of_one_is_the_batch1_update_bit_for_bit() {
    let world = World::synthetic(7);
    for (c, lr) in adapt_cases() {
        let m = adapt_model(&c, lr);
        let (ga, sa) = batch1_adapt(&world, &m, c.objective, 50, 1, 45);
        let (gb, sb) = vectorised_adapt(&world, &m, c.objective, 50, 1, 45, 1);
        assert!(sa.len() >= 2, "{}: several episodes per update", c.name);
        assert!(
            sa.iter().map(|e| e.0.adaptations).sum::<u32>() >= 2,
            "{}: inner updates happen",
            c.name
        );
        assert_eq!(sa.len(), sb.len(), "{}: episodes", c.name);
        for (k, (a, b)) in sa.iter().zip(&sb).enumerate() {
            let what = format!("{} episode {k}", c.name);
            same_episode(&a.0, &b.0, &what);
            same_disc(&a.1, &b.1, &what);
        }
        same_bits(&ga, &gb, c.name);
    }
}

#[test]
fn adapting_batched_episodes_are_the_episodes_run_alone() {
    let world = World::synthetic(7);
    for (c, lr) in adapt_cases() {
        let m = adapt_model(&c, lr);
        let b = 5;
        let (g, st) = vectorised_adapt(&world, &m, c.objective, 120, 4, 45, b);
        assert!(st.len() >= b, "{}: at least B episodes", c.name);
        assert!(
            st.iter().filter(|e| e.0.adaptations > 0).count() >= 2,
            "{}: several episodes adapt",
            c.name
        );
        // Each episode alone, through the batch-1 runner (navigator) into its own gradient.
        let mut sum = m.params.zeros_like();
        let mut sample = sampler_max(&world, 4, 45);
        for (k, s) in st.iter().enumerate() {
            let mut ge = m.params.zeros_like();
            let (one, disc) = alone(&world, &m, c.objective, sample(k as u32).unwrap(), &mut ge);
            let what = format!("{} episode {k}", c.name);
            same_episode(&s.0, &one, &what);
            same_disc(&s.1, &disc, &what);
            sum.add_assign(&ge).unwrap();
        }
        // The batched sum adds the same terms in another order: equal within float rounding
        // (1e-4 of each tensor's largest value).
        let mut differs = false;
        for (x, y) in g.tensors.iter().zip(&sum.tensors) {
            let scale = y.data.iter().fold(0.0f32, |a, v| a.max(v.abs())).max(1e-6);
            for (u, v) in x.data.iter().zip(&y.data) {
                assert!(
                    (u - v).abs() <= 1e-4 * scale,
                    "{}: {} {u} vs {v} (scale {scale})",
                    c.name,
                    x.name
                );
                differs |= u.to_bits() != v.to_bits();
            }
        }
        assert!(differs, "{}: B > 1 sums in its own order", c.name);
        // ... and the order is fixed: the same batch gives the same bits.
        let (g2, _) = vectorised_adapt(&world, &m, c.objective, 120, 4, 45, b);
        same_bits(&g, &g2, c.name);
    }
}

#[test]
fn adapting_batched_runs_are_reproducible_and_resume_bit_for_bit() {
    let world = World::synthetic(7);
    for mode in [AdaptMode::Efficient, AdaptMode::Full] {
        let st = || {
            let mut m = model(Method::Gman, Dims::MCU, mode, 1);
            m.spec.inner_lr = 0.01;
            m.params.get_mut("ActorB").unwrap().data[gman_core::Action::Done.index()] -= 3.0;
            TrainState::new(
                m,
                AdamConfig {
                    lr: 1e-3,
                    ..AdamConfig::default()
                },
            )
        };
        let a = tmp("adapt-straight");
        let mut sa = st();
        train(&world, &opts(a.clone(), 4, 3), &mut sa).unwrap();
        let b = tmp("adapt-resumed");
        let mut sb = st();
        train(&world, &opts(b.clone(), 2, 3), &mut sb).unwrap();
        let ck = gman_host_sim::train::run_dir::checkpoint_path(&b);
        let (mut sb, t) = TrainState::load_with_settings(&ck).unwrap();
        assert_eq!(t.run.batch_envs, 3, "B is stored in the checkpoint");
        train(&world, &opts(b.clone(), 4, 3), &mut sb).unwrap();
        assert_eq!(sa.env_steps, sb.env_steps);
        let csv = std::fs::read_to_string(a.join("metrics.csv")).unwrap();
        assert!(
            csv.lines()
                .skip(1)
                .any(|l| l.split(',').nth(10) != Some("0")),
            "inner updates happen: {csv}"
        );
        for (x, y) in sa.model.params.tensors.iter().zip(&sb.model.params.tensors) {
            let bx: Vec<u32> = x.data.iter().map(|v| v.to_bits()).collect();
            let by: Vec<u32> = y.data.iter().map(|v| v.to_bits()).collect();
            assert_eq!(bx, by, "{mode:?} {}", x.name);
        }
        for d in [a, b] {
            let _ = std::fs::remove_dir_all(d);
        }
    }
}

#[test]
fn the_second_order_meta_gradient_refuses_batched_episodes() {
    let world = World::synthetic(7);
    let d = tmp("gman");
    let mut st = state(Method::Gman);
    st.model.spec.adapt_mode = AdaptMode::Full;
    let mut o = opts(d.clone(), 1, 4);
    o.run.meta_order = 2;
    let e = train(&world, &o, &mut st).unwrap_err();
    assert!(format!("{e:#}").contains("--batch-envs"), "{e:#}");
    let e = train(&world, &opts(d.clone(), 1, 0), &mut st).unwrap_err();
    assert!(format!("{e:#}").contains("--batch-envs"), "{e:#}");
    // First order: B > 1 runs.
    let mut st = state(Method::Gman);
    train(&world, &opts(d.clone(), 1, 4), &mut st).unwrap();
    assert_eq!(st.update, 1);
    let _ = std::fs::remove_dir_all(d);
}
