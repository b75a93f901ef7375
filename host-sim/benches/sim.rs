//! Simulator throughput: single-thread environment steps per second, features included
//! (every step reads the 512-d observation). Uses the real floor plans when
//! `../shared/data/gman` exists, else the synthetic world.

use std::hint::black_box;
use std::path::PathBuf;

use criterion::{criterion_group, criterion_main, Criterion, Throughput};
use gman_core::{Action, NUM_ACTIONS};
use gman_host_sim::sim::{Env, EpisodeLimits, RewardKind, Split, World};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

const STEPS: u64 = 10_000;

fn world() -> World {
    let p = PathBuf::from(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../../shared/data/gman"
    ));
    if p.join("attributes.json").is_file() {
        World::load(&p).expect("load data")
    } else {
        eprintln!(
            "bench: no data at {}, using the synthetic world",
            p.display()
        );
        World::synthetic(0)
    }
}

/// Runs `STEPS` steps of random training episodes (uniform over the 5 moves; Done ends only
/// by the step limit), summing the features so they are read.
fn run(world: &World, rng: &mut ChaCha8Rng) -> f32 {
    let limits = EpisodeLimits::default();
    let mut spec = world.sample_train_episode(rng);
    let mut env = Env::new(world, &spec, RewardKind::Mixed, limits.for_room(spec.room));
    let mut acc = 0.0f32;
    for _ in 0..STEPS {
        let obs = env.observe();
        acc += obs.features.iter().sum::<f32>() + obs.ps_target[0];
        let a = Action::ALL[rng.random_range(0..NUM_ACTIONS - 1)];
        let out = env.step(a);
        acc += out.reward;
        if out.done {
            spec = world.sample_train_episode(rng);
            env = Env::new(world, &spec, RewardKind::Mixed, limits.for_room(spec.room));
        }
    }
    acc
}

fn bench(c: &mut Criterion) {
    let world = world();
    // Build every training scene's tables up front (lazy caches), as a long training run has.
    let mut rng = ChaCha8Rng::seed_from_u64(0);
    for &s in world.split_scenes(Split::Train).unwrap() {
        world.tables(s);
    }
    for _ in 0..2000 {
        let e = world.sample_train_episode(&mut rng);
        world.goal_table(e.scene, e.target);
    }
    let mut g = c.benchmark_group("sim");
    g.throughput(Throughput::Elements(STEPS));
    g.bench_function("env_step_with_features", |b| {
        b.iter(|| black_box(run(&world, &mut rng)))
    });
    // The spatial map of a 3 x 3 and a 7 x 7 grid, computed on demand per step.
    for (rows, cols) in [(3usize, 3usize), (7, 7)] {
        let grid = gman_host_sim::sim::spatial::MapGrid { rows, cols };
        let mut map = vec![0.0f32; grid.len()];
        let train = world.split_scenes(Split::Train).unwrap().to_vec();
        g.bench_function(format!("view_map_{rows}x{cols}"), |b| {
            b.iter(|| {
                let mut acc = 0.0f32;
                for i in 0..STEPS as usize {
                    let scene = train[i % train.len()];
                    let n = world.tables(scene).num_states();
                    world.view_map(scene, (i * 7919) % n, grid, &mut map);
                    acc += map[i % map.len()];
                }
                black_box(acc)
            })
        });
    }
    g.finish();

    let val = world.split_scenes(Split::Val).unwrap()[0];
    c.bench_function("build_scene_tables_one_val_scene", |b| {
        b.iter(|| {
            let w = &world;
            black_box(gman_host_sim::sim::tables::SceneTables::build(
                &w.scenes[val],
                &w.categories,
                w.feature_model(),
                w.scene_style(val),
            ))
        })
    });
}

criterion_group! {
    name = benches;
    config = Criterion::default().sample_size(20);
    targets = bench
}
criterion_main!(benches);
