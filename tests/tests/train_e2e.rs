//! End-to-end training tests on the built-in synthetic world: exact resume, a short run that
//! beats the random agent, and int8 export whose host evaluation path and bare gman-core
//! navigator agree action for action.

use std::path::PathBuf;
use std::sync::Arc;

use gman_core::blob::Blob;
use gman_core::navigator::memory::Footprint;
use gman_core::navigator::{Efficient, NavConfig, NavWeights, Navigator, NoiseMode, Selection};
use gman_core::Dims;
use gman_host_sim::eval::agent::NavAgent;
use gman_host_sim::model::{load_model, Method, NavModel};
use gman_host_sim::optim::adam::AdamConfig;
use gman_host_sim::pretrain::fg::{self, FgCollectConfig, FgTrainConfig};
use gman_host_sim::pretrain::generator::init_generator;
use gman_host_sim::sim::{
    evaluate, Env, EpisodeLimits, EvalConfig, EvalReport, RandomAgent, RewardKind, Split, World,
};
use gman_host_sim::train::state::{RunSettings, TrainState};
use gman_host_sim::train::trainer::{train, TrainOptions};

fn tmp(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("gman-e2e-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}

fn opts(out: PathBuf, updates: u64) -> TrainOptions {
    TrainOptions {
        updates,
        run: RunSettings {
            seed: 3,
            min_steps: 20,
            max_steps: Some(40),
            adam: AdamConfig {
                lr: 1e-3,
                ..AdamConfig::default()
            },
            ..RunSettings::default()
        },
        checkpoint_every: 3,
        out,
        progress: false,
    }
}

fn gman_model(seed: u64) -> NavModel {
    let mut rng = gman_core::rng::Xoshiro128::seed_from_u64(seed);
    let g = init_generator(&Dims::MCU, &mut rng).unwrap();
    let mut m = NavModel::init(Method::Gman, Dims::MCU, seed, Some(&g), None).unwrap();
    m.spec.inner_lr = 1e-2; // large enough that the inner loop visibly changes parameters
    m
}

/// A run stopped after 3 updates and resumed to 6 ends bit for bit where an uninterrupted
/// 6-update run ends (GMAN: inner loop, D learning across episodes, Adam state).
#[test]
fn resume_continues_bit_for_bit() {
    let world = World::synthetic(7);
    let a = tmp("straight");
    let mut sa = TrainState::new(
        gman_model(1),
        AdamConfig {
            lr: 1e-3,
            ..AdamConfig::default()
        },
    );
    train(&world, &opts(a.clone(), 6), &mut sa).unwrap();

    let b = tmp("resumed");
    let mut sb = TrainState::new(
        gman_model(1),
        AdamConfig {
            lr: 1e-3,
            ..AdamConfig::default()
        },
    );
    train(&world, &opts(b.clone(), 3), &mut sb).unwrap();
    drop(sb); // the process "dies" here; only the checkpoint survives
    let mut sb = TrainState::load(&b.join("checkpoint.ckpt")).unwrap();
    assert_eq!(sb.update, 3);
    train(&world, &opts(b.clone(), 6), &mut sb).unwrap();

    assert_eq!(sa.update, sb.update);
    assert_eq!(sa.env_steps, sb.env_steps);
    assert!(sa
        .model
        .params
        .tensors
        .iter()
        .zip(&sb.model.params.tensors)
        .all(|(x, y)| x.name == y.name
            && x.data
                .iter()
                .zip(&y.data)
                .all(|(p, q)| p.to_bits() == q.to_bits())));
    assert_eq!(sa.adam.to_bytes(), sb.adam.to_bytes());
    // The inner loop ran and D moved away from its initial values.
    let d0 = gman_model(1).params.tensor("DiscW1").unwrap().data.clone();
    assert_ne!(d0, sa.model.params.tensor("DiscW1").unwrap().data);
    // metrics.csv: same rows apart from wall time.
    let rows = |d: &PathBuf| -> Vec<String> {
        std::fs::read_to_string(d.join("metrics.csv"))
            .unwrap()
            .lines()
            .map(|l| {
                l.rsplit_once(',')
                    .map(|(a, _)| a.to_string())
                    .unwrap_or_default()
            })
            .collect()
    };
    assert_eq!(rows(&a), rows(&b));
    assert_eq!(rows(&a).len(), 7);
}

fn val_report(
    world: &World,
    factory: impl Fn(usize) -> Box<dyn gman_host_sim::sim::Agent + Send> + Sync,
) -> EvalReport {
    let episodes = world.episodes(Split::Val, Some(100)).unwrap();
    let cfg = EvalConfig {
        reward: RewardKind::Mixed,
        limits: EpisodeLimits::default(),
        progress: false,
    };
    EvalReport::new("val", "x", &evaluate(world, &episodes, factory, &cfg))
}

/// A short A3C+FG run (pre-trained G, a few hundred thousand environment steps at most)
/// finds seen objects in new scenes clearly more often than the random agent.
#[test]
fn short_training_beats_random_agent_on_seen_targets() {
    let world = World::synthetic(2022);
    let dir = tmp("short");
    let mut cfg = FgTrainConfig::new(300, 1);
    cfg.progress = false;
    fg::run_pretrain_fg(
        &world,
        "mcu",
        &Dims::MCU,
        &FgCollectConfig {
            seed: 1,
            ..FgCollectConfig::default()
        },
        &cfg,
        &dir.join("fg"),
    )
    .unwrap();
    let g = fg::load_generator(&dir.join("fg/fg.ckpt"), &Dims::MCU).unwrap();
    let model = NavModel::init(Method::A3cFg, Dims::MCU, 1, Some(&g), None).unwrap();
    let mut st = TrainState::new(
        model,
        AdamConfig {
            lr: 1e-3,
            ..AdamConfig::default()
        },
    );
    let base = opts(dir.join("run"), 1500);
    let o = TrainOptions {
        run: RunSettings {
            ..RunSettings::default()
        },
        checkpoint_every: 1000,
        ..base
    };
    train(&world, &o, &mut st).unwrap();
    let model = Arc::new(st.model);
    let trained = val_report(&world, |_| Box::new(NavAgent::new(model.clone())));
    let random = val_report(&world, |_| Box::new(RandomAgent::new(0)));
    eprintln!(
        "seen SR: trained {:.2} vs random {:.2}; unseen {:.2} vs {:.2}",
        trained.results.seen.sr,
        random.results.seen.sr,
        trained.results.unseen.sr,
        random.results.unseen.sr
    );
    assert!(
        trained.results.seen.sr > random.results.seen.sr + 2.0,
        "trained {:?} vs random {:?}",
        trained.results.seen,
        random.results.seen
    );
}

/// Train a tiny GMAN model, export int8, and replay an episode: the host evaluation path
/// (`gman eval --agent model.gman`) and a bare gman-core navigator over the blob (what the
/// firmware does) choose the same actions.
#[test]
fn exported_int8_blob_host_path_and_core_api_agree() {
    let world = World::synthetic(5);
    let dir = tmp("export");
    // Meta-trained in the mode the device runs (the mcu default of `gman train`).
    let mut model = gman_model(2);
    model.spec.adapt_mode = gman_core::navigator::memory::AdaptMode::Efficient;
    let mut st = TrainState::new(
        model,
        AdamConfig {
            lr: 1e-3,
            ..AdamConfig::default()
        },
    );
    train(&world, &opts(dir.clone(), 4), &mut st).unwrap();
    let blob_bytes = st.model.to_blob(true).unwrap();
    let path = dir.join("model.gman");
    std::fs::write(&path, &blob_bytes).unwrap();
    let host = load_model(&path, None).unwrap();
    assert_eq!(
        host.method,
        Method::Gman,
        "blob flags carry the adapting method"
    );
    // The blob carries the inner-loop settings the model was trained with (inner_lr 1e-2).
    assert_eq!(
        (host.spec.inner_lr, host.spec.max_inner),
        (1e-2, st.model.spec.max_inner)
    );
    assert_eq!(
        host.nav_config(false),
        NavConfig {
            // The host's run-time choices: sampled actions, and the RAM-for-speed layout,
            // which changes no bit (tests/tests/footprint.rs).
            selection: Selection::Sample,
            footprint: Footprint::Fast,
            ..Blob::parse(&blob_bytes).unwrap().nav_config()
        },
        "host evaluation and the device's NavConfig::from_header disagree"
    );

    let episodes = world.episodes(Split::Val, Some(3)).unwrap();
    let mut checked = 0;
    for spec in episodes.iter().take(6) {
        // Host path: the evaluation agent, recording what it saw and did.
        let mut env = Env::new(&world, spec, RewardKind::Mixed, 60);
        env.record_trajectory(true);
        let mut agent = NavAgent::new(Arc::new(host.clone()));
        gman_host_sim::sim::eval::drive(&mut env, spec, &mut agent);
        assert_eq!(agent.errors, 0);
        let states = env.trajectory().to_vec();
        // Core API: the firmware's loop over the same blob, fed the observations of the
        // states the host agent visited.
        let blob = Blob::parse(&blob_bytes).unwrap();
        let w = NavWeights::from_blob(&blob, &Dims::MCU).unwrap();
        let mut arena = vec![0.0f32; Navigator::<Efficient, 20>::arena_len(&Dims::MCU)];
        // The device's compact layout (the host agent ran the fast one): the same bits.
        let device_cfg = NavConfig {
            footprint: Footprint::Compact,
            ..host.nav_config(false)
        };
        let mut nav: Navigator<'_, Efficient, 20> =
            Navigator::new(w, &mut arena, device_cfg).unwrap();
        nav.reset(world.attributes(spec.target), spec.seed).unwrap();
        let mut env2 = Env::new(&world, spec, RewardKind::Mixed, 60);
        let mut visited = vec![env2.agent_state()];
        while !env2.is_done() {
            let out = nav.step(&env2.observe().features, &[]).unwrap();
            env2.step(out.action);
            visited.push(env2.agent_state());
            checked += 1;
        }
        assert_eq!(
            env.metrics().path_length,
            env2.metrics().path_length,
            "episode {}",
            spec.index
        );
        assert_eq!(env.metrics().success, env2.metrics().success);
        if !states.is_empty() {
            assert_eq!(
                states,
                visited[..states.len()].to_vec(),
                "episode {}: trajectories differ",
                spec.index
            );
        }
    }
    assert!(checked > 20, "too few steps compared: {checked}");

    // The host path reads the blob in place in the device's mode: probabilities agree bit for
    // bit with the bare navigator (a dequantised f32 copy in Full mode would not).
    assert!(gman_host_sim::model::episode::eval_mode_is_efficient(&host));
    let blob = Blob::parse(&blob_bytes).unwrap();
    // The host's fast layout against the device's compact one.
    let (mut a1, mut a2) = (
        vec![0.0f32; host.arena_len()],
        vec![0.0f32; Navigator::<Efficient, 20>::arena_len(&Dims::MCU)],
    );
    let mut n1: Navigator<'_, Efficient, 20> =
        Navigator::new(host.weights().unwrap(), &mut a1, host.nav_config(false)).unwrap();
    let mut n2: Navigator<'_, Efficient, 20> = Navigator::new(
        NavWeights::from_blob(&blob, &Dims::MCU).unwrap(),
        &mut a2,
        NavConfig {
            footprint: Footprint::Compact,
            ..host.nav_config(false)
        },
    )
    .unwrap();
    let spec = &episodes[0];
    n1.reset(world.attributes(spec.target), 9).unwrap();
    n2.reset(world.attributes(spec.target), 9).unwrap();
    let env = Env::new(&world, spec, RewardKind::Mixed, 60);
    let obs = env.observe().features;
    for _ in 0..45 {
        let (o1, o2) = (n1.step(&obs, &[]).unwrap(), n2.step(&obs, &[]).unwrap());
        assert_eq!(o1.probs.map(f32::to_bits), o2.probs.map(f32::to_bits));
    }
    assert_eq!(n1.counters().adaptations, 2);
}

/// `to_blob` stores the flags and the inner-loop settings, `model_from_blob` reads them back,
/// and the host's evaluation configuration of a blob-loaded model is what gman-core's
/// `NavConfig::from_header` (what the firmware runs) asks for, up to the host's sampled
/// action selection, for every method a blob can hold.
#[test]
fn blob_carries_the_inner_loop_settings_to_the_device_config() {
    let mut rng = gman_core::rng::Xoshiro128::seed_from_u64(4);
    let g = init_generator(&Dims::MCU, &mut rng).unwrap();
    for (method, noise, lr, cap, int8) in [
        (Method::Gman, NoiseMode::Gaussian, 0.05, 7, true),
        (Method::Gman, NoiseMode::Zero, 1e-4, 4, false),
        (Method::GmanCossim, NoiseMode::Gaussian, 3e-3, 0, true),
        (Method::A3cFg, NoiseMode::Gaussian, 2e-2, 9, true),
        (Method::GmanNoemd, NoiseMode::Zero, 1e-3, 1, false),
    ] {
        let mut m = NavModel::init(method, Dims::MCU, 5, Some(&g), None).unwrap();
        m.spec.noise = noise;
        m.spec.inner_lr = lr;
        m.spec.max_inner = cap;
        let bytes = m.to_blob(int8).unwrap();
        let blob = Blob::parse(&bytes).unwrap();
        let h = blob.header();
        assert_eq!(h.version(), gman_core::blob::FORMAT_VERSION);
        assert_eq!(
            (h.alpha_disc(), h.alpha_adapt(), h.max_inner()),
            (lr, lr, cap),
            "{method:?}"
        );
        let back = gman_host_sim::model::model_from_blob(&bytes, None).unwrap();
        assert_eq!(
            (back.spec.inner_lr, back.spec.max_inner, back.spec.noise),
            (lr, cap, noise)
        );
        // A blob does not say whether θ was trained by the outer loop: gman-noemd comes back
        // as a3c-fg, which runs the same navigator (no inner loop).
        let expected_method = if method == Method::GmanNoemd {
            Method::A3cFg
        } else {
            method
        };
        assert_eq!(back.method, expected_method);
        let device = NavConfig::from_header(h);
        assert_eq!(device.model.adapt, method.adapts_at_eval(), "{method:?}");
        assert_eq!(
            back.nav_config(false),
            NavConfig {
                selection: Selection::Sample,
                footprint: Footprint::Fast,
                ..device
            },
            "{method:?}: host evaluation and device configurations differ"
        );
        // ... and the original model evaluates with that configuration too.
        assert_eq!(m.nav_config(false), back.nav_config(false), "{method:?}");
    }
    // The host refuses settings a blob cannot hold, naming the setting.
    let mut m = NavModel::init(Method::Gman, Dims::MCU, 5, Some(&g), None).unwrap();
    m.spec.inner_lr = f32::NAN;
    let e = m.to_blob(true).unwrap_err().to_string();
    assert!(e.contains("inner_lr"), "{e}");
}

/// `--meta-order 2` on a real training episode: the fusion, LSTM and critic gradients are
/// those of order 1 (the same sum over segments), the actor head's too (v_φ passes through the
/// inner steps unchanged), and G's gradient differs (the inner steps' second-order terms);
/// a short order-2 run trains to finite parameters and records its order.
#[test]
fn meta_order_two_changes_only_the_generator_gradient() {
    use gman_host_sim::train::rollout::Worker;
    use gman_host_sim::train::trainer::train_episode;
    use rand::SeedableRng;
    let world = World::synthetic(7);
    let model = gman_model(1);
    let a3c = Default::default();
    let run = |spec: &gman_host_sim::sim::EpisodeSpec, order: u8| {
        let mut worker = Worker::new(&model);
        let mut g = model.params.zeros_like();
        let (st, _) = train_episode(
            &world,
            spec,
            &model,
            RewardKind::Mixed,
            80,
            &a3c,
            Default::default(),
            order,
            &mut worker,
            &mut g,
        )
        .unwrap();
        assert!(g.all_finite());
        (st.adaptations, g)
    };
    // The first sampled episode long enough for an inner update (followed by a segment).
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(11);
    let spec = (0..200)
        .map(|_| world.sample_train_episode_min(&mut rng, 1))
        .find(|s| run(s, 1).0 >= 1)
        .expect("an episode with an inner update");
    let grads: Vec<_> = [1u8, 2].iter().map(|&o| run(&spec, o).1).collect();
    let rel = |name: &str| {
        let (a, b) = (
            &grads[0].tensor(name).unwrap().data,
            &grads[1].tensor(name).unwrap().data,
        );
        let d: f64 = a.iter().zip(b).map(|(x, y)| ((x - y) as f64).powi(2)).sum();
        let n: f64 = a.iter().map(|x| (*x as f64).powi(2)).sum();
        (d / n.max(1e-30)).sqrt()
    };
    let mut same = 0.0f64;
    for name in ["FuseW", "LstmWx", "CriticW", "ActorW", "ActorB"] {
        assert!(
            rel(name) < 1e-6,
            "{name}: orders differ by {:.2e}",
            rel(name)
        );
        same = same.max(rel(name));
    }
    let (g1, g2) = (rel("GenW1"), rel("GenW2"));
    eprintln!("order 2 vs 1: GenW1 {g1:.2e}, GenW2 {g2:.2e}; shared blocks ≤ {same:.2e}");
    // The inner rate is 1e-2 here, so the second-order terms are small, but far above the
    // rounding differences of the shared blocks.
    assert!(g1.max(g2) > 1e-5, "G's gradient unchanged by order 2");

    let dir = tmp("order2");
    let mut st = TrainState::new(
        gman_model(1),
        AdamConfig {
            lr: 1e-3,
            ..AdamConfig::default()
        },
    );
    let base = opts(dir.clone(), 2);
    let o = TrainOptions {
        run: RunSettings {
            meta_order: 2,
            ..RunSettings::default()
        },
        ..base
    };
    train(&world, &o, &mut st).unwrap();
    assert!(st.model.params.all_finite());
    let ck =
        gman_host_sim::optim::checkpoint::Checkpoint::load(&dir.join("checkpoint.ckpt")).unwrap();
    assert_eq!(ck.metadata["trainer"]["meta_order"], 2);
}

/// The `gman-noemd` control trains G's θ through the policy loss like GMAN's outer loop but
/// never runs the inner loop; `a3c-fg` keeps θ frozen. Both facts are what make the control
/// separate "θ is trained" from "the EMD adapts".
#[test]
fn gman_noemd_trains_the_generator_without_adapting() {
    use gman_host_sim::train::rollout::Worker;
    use gman_host_sim::train::trainer::train_episode;
    use rand::SeedableRng;
    let world = World::synthetic(7);
    let mut rng = gman_core::rng::Xoshiro128::seed_from_u64(5);
    let g = init_generator(&Dims::MCU, &mut rng).unwrap();
    let mut srng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
    // Enough episodes that GMAN itself adapts in some (checked below).
    let specs: Vec<_> = (0..200)
        .map(|_| world.sample_train_episode_min(&mut srng, 1))
        .collect();
    let run = |method: Method| {
        let mut model = NavModel::init(method, Dims::MCU, 1, Some(&g), None).unwrap();
        model.spec.inner_lr = 1e-2;
        let mut worker = Worker::new(&model);
        let mut grads = model.params.zeros_like();
        let mut adaptations = 0;
        for spec in &specs {
            let (st, _) = train_episode(
                &world,
                spec,
                &model,
                RewardKind::Mixed,
                80,
                &Default::default(),
                Default::default(),
                1,
                &mut worker,
                &mut grads,
            )
            .unwrap();
            adaptations += st.adaptations;
        }
        let norm = |name: &str| -> f64 {
            grads
                .tensor(name)
                .unwrap()
                .data
                .iter()
                .map(|v| (*v as f64).powi(2))
                .sum::<f64>()
                .sqrt()
        };
        (adaptations, norm("GenW1") + norm("GenW2"), norm("ActorW"))
    };
    let (ad_gman, g_gman, _) = run(Method::Gman);
    let (ad_noemd, g_noemd, a_noemd) = run(Method::GmanNoemd);
    let (ad_fg, g_fg, a_fg) = run(Method::A3cFg);
    eprintln!("adaptations gman {ad_gman} noemd {ad_noemd} a3c-fg {ad_fg}; |dG| {g_gman:.3e} {g_noemd:.3e} {g_fg:.3e}");
    assert!(ad_gman > 0, "GMAN should adapt in these episodes");
    assert_eq!(ad_noemd, 0, "gman-noemd ran the inner loop");
    assert_eq!(ad_fg, 0);
    assert!(g_noemd > 0.0, "gman-noemd's θ gets no gradient");
    assert_eq!(g_fg, 0.0, "a3c-fg's θ must stay frozen");
    // Same policy gradients: without adaptation both methods compute the same A3C loss.
    assert!(
        (a_noemd - a_fg).abs() <= 1e-9 * a_fg.max(1.0),
        "{a_noemd} vs {a_fg}"
    );
    // The cap on inner updates survives a checkpoint round trip.
    let mut m = NavModel::init(Method::GmanNoemd, Dims::MCU, 1, Some(&g), None).unwrap();
    m.spec.max_inner = 7;
    m.spec.inner_lr = 0.05;
    let dir = tmp("noemd");
    let mut st = TrainState::new(m, AdamConfig::default());
    train(&world, &opts(dir.clone(), 1), &mut st).unwrap();
    let back = load_model(&dir.join("checkpoint.ckpt"), None).unwrap();
    assert_eq!(back.method, Method::GmanNoemd);
    assert_eq!(back.spec.max_inner, 7);
    assert_eq!(back.spec.inner_lr, 0.05);
}
