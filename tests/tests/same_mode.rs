//! What the trainer meta-learns is what the device runs: a training rollout (the trainer's
//! `train_episode`, Manual schedule, inner loop in the model's adaptation mode) and the same
//! episode run by gman-core's navigator from the exported f32 blob (Auto schedule, the mode
//! and settings the blob's header records) take the same actions and end with the same
//! adapted generator output, bit for bit, in both adaptation modes.

use gman_core::blob::Blob;
use gman_core::navigator::memory::AdaptMode;
use gman_core::navigator::StepRule;
use gman_core::navigator::{Efficient, Full, Mode, Navigator, Selection};
use gman_core::spec::schema::AdaptLossKind;
use gman_host_sim::model::K;
use gman_host_sim::model::{InnerRule, Method, NavModel};
use gman_host_sim::optim::params::{Init, ParamSet};
use gman_host_sim::sim::spatial::MapGrid;
use gman_host_sim::sim::{Env, EpisodeSpec, RewardKind, World};
use gman_host_sim::train::rollout::Worker;
use gman_host_sim::train::trainer::train_episode;
use rand::SeedableRng;

/// A GMAN model with a random (not zero) generator and a fast inner loop, so adaptation
/// visibly changes x_t within an episode.
fn model(mode: AdaptMode, dims: gman_core::Dims) -> NavModel {
    let mut rng = gman_core::rng::Xoshiro128::seed_from_u64(5);
    let mut gen = ParamSet::new();
    for id in gman_core::blob::TensorId::GENERATOR {
        let (r, c) = id.shape(&dims);
        let init = if id.is_vector() {
            Init::Zeros
        } else {
            Init::Normal(0.3 / (c as f32).sqrt())
        };
        gen.add(id.name(), r, c, init, &mut rng).unwrap();
    }
    let mut m = NavModel::init(Method::Gman, dims, 3, Some(&gen), None).unwrap();
    m.spec.inner_lr = 0.05;
    m.spec.adapt_mode = mode;
    // A policy that rarely stops, so episodes are long enough for inner updates.
    m.params.get_mut("ActorB").unwrap().data[gman_core::Action::Done.index()] = -4.0;
    m
}

/// Runs `spec` on the device side: the blob's own configuration (with sampled actions, as
/// the trainer samples), the mode `M` the header asks for.
fn device<M: Mode>(
    world: &World,
    spec: &EpisodeSpec,
    blob: &[u8],
    max: u32,
) -> (Vec<u8>, Vec<f32>, u32) {
    let b = Blob::parse(blob).unwrap();
    let dims = b.dims();
    let mut cfg = b.nav_config();
    cfg.selection = Selection::Sample;
    let weights = gman_core::navigator::NavWeights::from_blob(&b, &dims).unwrap();
    let mut arena = vec![0.0f32; Navigator::<M, K>::arena_len(&dims)];
    let mut nav: Navigator<'_, M, K> = Navigator::new(weights, &mut arena, cfg).unwrap();
    nav.reset(world.attributes(spec.target), spec.seed).unwrap();
    let mut env = Env::new(world, spec, RewardKind::Mixed, max);
    let grid = MapGrid {
        rows: dims.map_rows,
        cols: dims.map_cols,
    };
    let mut map = vec![0.0f32; grid.len()];
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
    (
        actions,
        nav.generated_feature().to_vec(),
        nav.counters().adaptations,
    )
}

fn check(mode: AdaptMode, dims: gman_core::Dims) {
    check_with(mode, dims, InnerRule::default());
}

fn check_with(mode: AdaptMode, dims: gman_core::Dims, rule: InnerRule) {
    let world = World::synthetic(11);
    let mut m = model(mode, dims);
    m.spec.inner_rule = rule;
    let cycle = K + rule.commit_delay as usize;
    let blob = m.to_blob(false).unwrap();
    assert_eq!(Blob::parse(&blob).unwrap().header().adapt_mode(), mode);
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(2);
    let (mut adapted, mut steps) = (0u32, 0usize);
    for _ in 0..12 {
        let spec = world.sample_train_episode(&mut rng);
        let max = 70;
        let mut worker = Worker::new(&m);
        let mut grads = m.params.zeros_like();
        let (st, _) = train_episode(
            &world,
            &spec,
            &m,
            RewardKind::Mixed,
            max,
            &Default::default(),
            Default::default(),
            1,
            &mut worker,
            &mut grads,
        )
        .unwrap();
        let (actions, x, n) = match mode {
            AdaptMode::Full => device::<Full>(&world, &spec, &blob, max),
            AdaptMode::Efficient => device::<Efficient>(&world, &spec, &blob, max),
        };
        assert_eq!(st.actions, actions, "actions differ ({mode:?})");
        let bits = |v: &[f32]| v.iter().map(|f| f.to_bits()).collect::<Vec<_>>();
        assert_eq!(
            bits(&st.final_feature),
            bits(&x),
            "adapted x_t differs ({mode:?})"
        );
        // The device also adapts at the very last step when an episode ends on a commit
        // step (k + d, 2 (k + d), ...); the trainer has no later segment to use it for.
        if actions.len() % cycle != 0 {
            assert_eq!(st.adaptations, n);
        }
        adapted += st.adaptations;
        steps += actions.len();
    }
    assert!(adapted > 0, "no inner update ran in {steps} steps");
}

#[test]
fn trainer_and_device_adapt_alike_in_efficient_mode() {
    check(AdaptMode::Efficient, gman_core::Dims::MCU);
}

#[test]
fn trainer_and_device_adapt_alike_in_full_mode() {
    check(AdaptMode::Full, gman_core::Dims::MCU);
}

#[test]
fn trainer_and_device_agree_with_a_spatial_map() {
    check(AdaptMode::Efficient, gman_core::Dims::MCU.with_map(2, 3, 4));
}

/// A blob meta-trained in one mode is refused by a navigator of the other.
#[test]
fn an_adapting_blob_refuses_the_other_mode() {
    let m = model(AdaptMode::Full, gman_core::Dims::MCU);
    let blob = m.to_blob(false).unwrap();
    let b = Blob::parse(&blob).unwrap();
    let w = gman_core::navigator::NavWeights::from_blob(&b, &b.dims()).unwrap();
    let mut arena = vec![0.0f32; Navigator::<Efficient, K>::arena_len(&b.dims())];
    assert!(Navigator::<Efficient, K>::new(w, &mut arena, b.nav_config()).is_err());
}

/// The inner rule's levers travel in the blob too: the per-group normalised step, D's head reset
/// with every episode, α1 ≠ α2, several D steps and the reference's L_ad form and critic
/// scale give the same run on both sides.
#[test]
fn trainer_and_device_agree_with_the_levers() {
    let rule = InnerRule {
        disc_lr: Some(0.1),
        disc_steps: 2,
        step_rule: StepRule::PerGroup,
        disc_head_reset: true,
        adapt_loss: AdaptLossKind::Reference,
        reference_critic: true,
        ..InnerRule::PAPER
    };
    check_with(AdaptMode::Efficient, gman_core::Dims::MCU, rule);
    // The reference's default: only the actor head adapts (with the normalised step, whose
    // length then comes from the head alone).
    let head_only = InnerRule {
        head_only: true,
        step_rule: StepRule::Normalized,
        ..InnerRule::default()
    };
    check_with(AdaptMode::Efficient, gman_core::Dims::MCU, head_only);
}

/// The inner update committed `d` steps after Ψ fills (computed in slices inside the steps
/// of the commit window on the device, at once at the end of the trainer's longer segment):
/// the same run on both sides, in both modes and with the map model.
#[test]
fn trainer_and_device_agree_with_a_commit_delay() {
    for d in [1u32, 13] {
        let rule = InnerRule {
            commit_delay: d,
            ..InnerRule::default()
        };
        check_with(AdaptMode::Efficient, gman_core::Dims::MCU, rule);
        check_with(AdaptMode::Full, gman_core::Dims::MCU, rule);
        check_with(
            AdaptMode::Efficient,
            gman_core::Dims::MCU.with_map(2, 3, 4),
            rule,
        );
    }
    // With the levers too (several D steps draw ε from the update's own generator).
    let rule = InnerRule {
        disc_lr: Some(0.1),
        disc_steps: 2,
        step_rule: StepRule::PerGroup,
        disc_head_reset: true,
        adapt_loss: AdaptLossKind::Reference,
        reference_critic: true,
        commit_delay: 7,
        ..InnerRule::PAPER
    };
    check_with(AdaptMode::Efficient, gman_core::Dims::MCU, rule);
}
