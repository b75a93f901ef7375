//! Simulator rules: splits, solvability, actions, success, step limits, rewards, metrics,
//! sampling and determinism, on the real floor plans (skipped without data) and the
//! synthetic world.

mod common;

use gman_core::Action;
use gman_host_sim::sim::eval::{
    evaluate, run_episode, EvalConfig, EvalReport, OracleAgent, RandomAgent,
};
use gman_host_sim::sim::reward::{jaccard, STEP_PENALTY};
use gman_host_sim::sim::tables::UNREACHABLE;
use gman_host_sim::sim::{Agent, Env, RewardKind, Split, TargetKind, World};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

fn check_unseen_absent_from_training(world: &World) {
    assert!(!world.unseen.is_empty());
    for &s in world.split_scenes(Split::Train).unwrap() {
        let sc = &world.scenes[s];
        for &u in &world.unseen {
            assert!(
                !sc.present.contains(&u),
                "{} lists unseen {}",
                sc.name,
                world.category_name(u)
            );
            assert!(
                sc.instances_of(u).next().is_none(),
                "{} has an unseen {}",
                sc.name,
                world.category_name(u)
            );
        }
    }
}

#[test]
fn unseen_categories_never_in_training_scenes() {
    check_unseen_absent_from_training(&World::synthetic(1));
    if let Some(w) = common::real_world() {
        assert_eq!(w.unseen.len(), 12);
        assert_eq!(w.split_scenes(Split::Train).unwrap().len(), 80);
        assert_eq!(w.split_scenes(Split::Val).unwrap().len(), 20);
        check_unseen_absent_from_training(w);
        // The unseen categories do occur in val scenes (otherwise the check above is vacuous).
        let val_has_unseen = w
            .split_scenes(Split::Val)
            .unwrap()
            .iter()
            .any(|&s| w.unseen.iter().any(|&u| w.scenes[s].present.contains(&u)));
        assert!(val_has_unseen);
    }
}

#[test]
fn official_val_episodes_solvable_and_targets_resolve() {
    let Some(world) = common::real_world() else {
        return;
    };
    let eps = world.episodes(Split::Val, None).unwrap();
    assert_eq!(eps.len(), 8000);
    for e in &eps {
        let sc = &world.scenes[e.scene];
        assert_eq!(sc.split, Split::Val);
        let s = sc.state_index(e.start).expect("start reachable");
        assert_ne!(
            world.goal_table(e.scene, e.target).dist[s],
            UNREACHABLE,
            "unsolvable episode {} in {}",
            e.index,
            sc.name
        );
        let ids = sc.id_map();
        for id in &e.target_ids {
            let i = *ids
                .get(id.as_str())
                .unwrap_or_else(|| panic!("target id {id} missing in {}", sc.name));
            assert_eq!(sc.objects[i].category, e.target);
        }
        if e.kind == TargetKind::Unseen {
            assert!(world.unseen.contains(&e.target));
        }
    }
}

#[test]
fn synthetic_val_episodes_solvable() {
    let world = World::synthetic(11);
    let eps = world.episodes(Split::Val, None).unwrap();
    assert_eq!(eps.len(), 4 * 2 * 250);
    for e in &eps {
        let s = world.scenes[e.scene].state_index(e.start).unwrap();
        let d = world.goal_table(e.scene, e.target).dist[s];
        assert!(d != UNREACHABLE && d > 0);
    }
}

fn check_oracle(world: &World, per_file: usize) {
    let eps = world.episodes(Split::Val, Some(per_file)).unwrap();
    let res = evaluate(
        world,
        &eps,
        |_| Box::new(OracleAgent),
        &EvalConfig::default(),
    );
    let r = EvalReport::new("val", "oracle", &res);
    for k in [r.results.seen, r.results.unseen] {
        assert_eq!(k.sr, 100.0);
        assert!((k.spl - 100.0).abs() < 1e-9, "oracle SPL {}", k.spl);
        assert_eq!(k.dts, 0.0);
    }
}

#[test]
fn oracle_scores_sr_100_spl_100() {
    check_oracle(&World::synthetic(2), 40);
    if let Some(w) = common::real_world() {
        check_oracle(w, 100);
    }
}

#[test]
fn random_agent_is_deterministic_and_mostly_fails() {
    let world = World::synthetic(2);
    let eps = world.episodes(Split::Val, Some(50)).unwrap();
    let run = || {
        evaluate(
            &world,
            &eps,
            |_| Box::new(RandomAgent::new(9)),
            &EvalConfig::default(),
        )
    };
    let (a, b) = (run(), run());
    let ma: Vec<_> = a.iter().map(|r| r.metrics).collect();
    let mb: Vec<_> = b.iter().map(|r| r.metrics).collect();
    assert_eq!(ma, mb);
    let r = EvalReport::new("val", "random", &a);
    assert!(r.results.seen.sr < 50.0 && r.results.unseen.sr < 50.0);
    assert!(r.results.seen.epa > 0.0);
}

/// An agent that repeats one action.
struct Repeat(Action);
impl Agent for Repeat {
    fn begin_episode(
        &mut self,
        _e: &gman_host_sim::sim::Env<'_>,
        _t: &gman_host_sim::sim::TargetInfo,
    ) {
    }
    fn act(&mut self, _e: &gman_host_sim::sim::Env<'_>) -> Action {
        self.0
    }
}

#[test]
fn step_limit_and_no_op_actions() {
    let world = World::synthetic(3);
    let eps = world.episodes(Split::Val, None).unwrap();
    let cfg = EvalConfig::default();
    for e in eps.iter().take(40) {
        let env = run_episode(&world, e, &mut Repeat(Action::LookUp), &cfg);
        let m = env.metrics();
        assert_eq!(m.path_length, cfg.limits.for_room(e.room));
        assert!(!m.success);
        assert_eq!(
            env.agent_state(),
            e.start,
            "LookUp at horizon 0 must not change the state"
        );
        assert!((m.total_reward - STEP_PENALTY * m.path_length as f32).abs() < 1e-3);
    }
}

#[test]
fn blocked_move_fails_and_agent_stays() {
    let world = World::synthetic(4);
    let eps = world.episodes(Split::Val, Some(5)).unwrap();
    let e = &eps[0];
    let mut env = Env::new(&world, e, RewardKind::Mixed, 1000);
    // Walk straight until blocked: every room is bounded, so a move must fail eventually.
    let mut blocked = false;
    for _ in 0..200 {
        let before = env.agent_state();
        let out = env.step(Action::MoveAhead);
        if !out.moved {
            assert_eq!(env.agent_state(), before);
            blocked = true;
            break;
        }
        let after = env.agent_state();
        assert_eq!(
            (after.heading, after.horizon),
            (before.heading, before.horizon)
        );
        assert_eq!(
            (after.x - before.x).abs().max((after.z - before.z).abs()),
            1
        );
    }
    assert!(blocked);
}

#[test]
fn done_succeeds_only_when_target_visible_and_rewards_match() {
    let world = World::synthetic(5);
    let eps = world.episodes(Split::Val, Some(30)).unwrap();
    for e in &eps {
        // Done at the start: target not visible there (generated starts), so it fails.
        for kind in [RewardKind::Navigation, RewardKind::Mixed] {
            let mut env = Env::new(&world, e, kind, 100);
            assert!(!env.observe().is_visible(e.target));
            let sim = env.similarity_now();
            let out = env.step(Action::Done);
            assert!(out.done && !out.success);
            let expect = if kind == RewardKind::Mixed {
                STEP_PENALTY + 0.5 * sim
            } else {
                STEP_PENALTY
            };
            assert!((out.reward - expect).abs() < 1e-6);
            // Steps after the end change nothing.
            assert_eq!(env.step(Action::MoveAhead).reward, 0.0);
        }
        // Follow the oracle: distance rewards are paid for approaching, 5 on success.
        let mut env = Env::new(&world, e, RewardKind::Distance, 500);
        let mut last = 0.0;
        while !env.is_done() {
            let d_prev = env.oracle().distance_to_goal();
            let a = env.oracle().optimal_action();
            let out = env.step(a);
            if a != Action::Done {
                let d_now = env.oracle().distance_to_goal();
                let expect = STEP_PENALTY + (0.1 * (d_prev - d_now)).max(0.0);
                assert!((out.reward - expect).abs() < 1e-5);
            }
            last = out.reward;
        }
        assert!(env.metrics().success);
        assert_eq!(last, 5.0);
        assert!(env.observe().is_visible(e.target));
        assert!(env.metrics().dts == 0.0);
    }
}

#[test]
fn similarity_is_best_jaccard_over_visible() {
    let world = World::synthetic(6);
    let eps = world.episodes(Split::Val, None).unwrap();
    let mut checked = 0;
    for e in &eps {
        let env = Env::new(&world, e, RewardKind::Mixed, 100);
        let vis = &env.observe().visible;
        if vis.is_empty() {
            assert_eq!(env.similarity_now(), 0.0);
            continue;
        }
        let t = world.attributes(e.target);
        let best = vis
            .iter()
            .map(|&c| jaccard(t, world.attributes(c)))
            .fold(0.0, f32::max);
        assert_eq!(env.similarity_now(), best);
        checked += 1;
    }
    assert!(checked > 10);
}

#[test]
fn epa_counts_distinct_positions() {
    let world = World::synthetic(7);
    let e = &world.episodes(Split::Val, Some(1)).unwrap()[0];
    let n = world.scenes[e.scene].positions.len() as f32;
    let mut env = Env::new(&world, e, RewardKind::Mixed, 100);
    assert!((env.metrics().epa - 100.0 / n).abs() < 1e-4);
    // Turning in place does not explore.
    for _ in 0..8 {
        env.step(Action::RotateRight);
    }
    assert!((env.metrics().epa - 100.0 / n).abs() < 1e-4);
    let mut visited = std::collections::BTreeSet::from([(e.start.x, e.start.z)]);
    for a in [
        Action::MoveAhead,
        Action::RotateLeft,
        Action::MoveAhead,
        Action::RotateRight,
        Action::MoveAhead,
    ] {
        env.step(a);
        let s = env.agent_state();
        visited.insert((s.x, s.z));
    }
    assert!((env.metrics().epa - 100.0 * visited.len() as f32 / n).abs() < 1e-4);
}

#[test]
fn train_sampler_is_seeded_and_valid() {
    let world = World::synthetic(8);
    let sample = |seed| {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        (0..50)
            .map(|_| world.sample_train_episode(&mut rng))
            .collect::<Vec<_>>()
    };
    let a = sample(1);
    assert_eq!(a, sample(1));
    assert_ne!(a, sample(2));
    for e in &a {
        let sc = &world.scenes[e.scene];
        assert_eq!(sc.split, Split::Train);
        assert!(world.train_targets[sc.room.index()].contains(&e.target));
        assert_eq!(e.start.horizon, 0);
        let s = sc.state_index(e.start).unwrap();
        assert_ne!(world.goal_table(e.scene, e.target).dist[s], UNREACHABLE);
    }
    if let Some(w) = common::real_world() {
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        for _ in 0..200 {
            let e = w.sample_train_episode(&mut rng);
            assert_eq!(w.scenes[e.scene].split, Split::Train);
            assert!(!w.unseen.contains(&e.target));
        }
    }
}

#[test]
fn same_seed_same_world() {
    let (a, b, c) = (
        World::synthetic(9),
        World::synthetic(9),
        World::synthetic(10),
    );
    assert_eq!(
        a.episodes(Split::Val, None).unwrap(),
        b.episodes(Split::Val, None).unwrap()
    );
    assert_ne!(
        a.episodes(Split::Val, None).unwrap(),
        c.episodes(Split::Val, None).unwrap()
    );
    let s = a.split_scenes(Split::Val).unwrap()[0];
    assert_eq!(a.scenes[s].positions, b.scenes[s].positions);
    assert_eq!(a.object_feature(s, 0), b.object_feature(s, 0));
}

#[test]
fn placed_objects_lie_against_the_reachable_boundary() {
    let Some(world) = common::real_world_rule() else {
        return;
    };
    let mut placed = 0;
    for sc in &world.scenes {
        for o in sc.objects.iter().filter(|o| !o.known) {
            let props = &world.categories[o.category as usize].props;
            let near = sc.positions.iter().any(|&(x, z)| {
                let d = ((x as f32 * 0.25 - o.pos[0]).powi(2)
                    + (z as f32 * 0.25 - o.pos[2]).powi(2))
                .sqrt();
                (d - props.radius - 0.2).abs() < 0.11
            });
            assert!(
                near,
                "{} {} not against the boundary",
                sc.name,
                world.category_name(o.category)
            );
            assert!(!sc.is_reachable_point(o.pos[0], o.pos[2]) || props.radius < 0.1);
            assert_eq!(o.pos[1], props.height);
            placed += 1;
        }
        // Every present category has at least one instance.
        for &c in &sc.present {
            assert!(
                sc.instances_of(c).next().is_some(),
                "{} has no {}",
                sc.name,
                world.category_name(c)
            );
        }
    }
    assert!(placed > 100);
}
