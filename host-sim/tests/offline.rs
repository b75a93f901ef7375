//! The AI2THOR offline world source (`--features offline`): the fixture written in the
//! SAVN/GMAN format loads with the state graph and visibility exactly as written, the oracle
//! reaches SR 100 along the graph's shortest paths, a short training run works, train ->
//! export -> eval runs through gman-core's blob, and bad files give errors that name them.
//!
//! Run: `cargo test -p gman-host-sim --features offline --test offline`.

use std::collections::{HashMap, HashSet, VecDeque};
use std::path::{Path, PathBuf};
use std::process::Command;
use std::sync::{Arc, Mutex, MutexGuard, OnceLock};

use gman_core::blob::Blob;
use gman_core::navigator::{Efficient, NavWeights, Navigator};
use gman_core::{Action, Dims, FEATURE_DIM};
use gman_host_sim::eval::agent::NavAgent;
use gman_host_sim::model::{load_model, Method, NavModel};
use gman_host_sim::optim::adam::AdamConfig;
use gman_host_sim::pretrain::generator::init_generator;
use gman_host_sim::sim::offline::fixture::{write_fixture, write_fixture_named, FixtureInfo};
use gman_host_sim::sim::offline::{self, h5, state_key, MAP_LEN, MAP_SHAPE};
use gman_host_sim::sim::spatial::MapGrid;
use gman_host_sim::sim::{
    evaluate, AgentState, Env, EpisodeLimits, EvalConfig, OracleAgent, RewardKind, Split, World,
    WorldSource,
};
use gman_host_sim::train::state::{RunSettings, TrainState};
use gman_host_sim::train::trainer::{train, TrainOptions};
use serde_json::Value;

/// One test at a time: HDF5 locks every file it opens (flock), and a `gman` child process
/// spawned by one test inherits the descriptors, and so the locks, of files that another test
/// has open at that moment, which would then fail to open ("unable to lock file").
fn serial() -> MutexGuard<'static, ()> {
    static M: Mutex<()> = Mutex::new(());
    M.lock().unwrap_or_else(|e| e.into_inner())
}

fn tmp(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("gman-offline-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}

/// The fixture, written once per test binary.
fn fixture() -> &'static (PathBuf, FixtureInfo) {
    static F: OnceLock<(PathBuf, FixtureInfo)> = OnceLock::new();
    F.get_or_init(|| {
        let d = tmp("fixture");
        let info = write_fixture(&d, 3).expect("write fixture");
        (d, info)
    })
}

fn world() -> &'static World {
    static W: OnceLock<World> = OnceLock::new();
    W.get_or_init(|| World::load(&fixture().0).expect("load fixture"))
}

fn read_json(p: &Path) -> Value {
    serde_json::from_str(&std::fs::read_to_string(p).unwrap()).unwrap()
}

/// (nodes, directed edges) of a written graph.json.
fn graph_of(dir: &Path) -> (HashSet<String>, HashSet<(String, String)>) {
    let g = read_json(&dir.join("graph.json"));
    let nodes = g["nodes"]
        .as_array()
        .unwrap()
        .iter()
        .map(|n| n["id"].as_str().unwrap().to_string())
        .collect();
    let links = g.get("links").or_else(|| g.get("edges")).unwrap();
    let edges = links
        .as_array()
        .unwrap()
        .iter()
        .map(|l| {
            (
                l["source"].as_str().unwrap().to_string(),
                l["target"].as_str().unwrap().to_string(),
            )
        })
        .collect();
    (nodes, edges)
}

/// Where an action would take the agent on an open grid (the test's own rules).
fn intended(s: AgentState, a: Action) -> AgentState {
    const STEP: [(i32, i32); 8] = [
        (0, 1),
        (1, 1),
        (1, 0),
        (1, -1),
        (0, -1),
        (-1, -1),
        (-1, 0),
        (-1, 1),
    ];
    let mut t = s;
    match a {
        Action::MoveAhead => {
            let (dx, dz) = STEP[s.heading as usize];
            t.x += dx;
            t.z += dz;
        }
        Action::RotateLeft => t.heading = (s.heading + 7) % 8,
        Action::RotateRight => t.heading = (s.heading + 1) % 8,
        Action::LookUp => t.horizon = 0,
        Action::LookDown => t.horizon = 1,
        Action::Done => {}
    }
    t
}

#[test]
fn state_graph_visibility_and_features_are_as_written() {
    let _serial = serial();
    let (dir, info) = fixture();
    let w = world();
    assert!(matches!(&w.source, WorldSource::Offline(d) if d == dir));
    assert_eq!(w.scenes.len(), 3);
    assert_eq!(w.split_scenes(Split::Train).unwrap().len(), 2);
    assert_eq!(w.split_scenes(Split::Val).unwrap().len(), 1);
    assert!(w.split_scenes(Split::Test).is_err());
    let mut checked_edges = 0;
    let mut blocked_seen = 0;
    for (sid, sc) in w.scenes.iter().enumerate() {
        let sdir = dir.join(&sc.name);
        let off = w.offline_scene(sid).expect("offline scene");
        let t = w.tables(sid);
        let (nodes, edges) = graph_of(&sdir);
        // Positions are grid.json's points, no gap filling.
        let grid = read_json(&sdir.join("grid.json"));
        assert_eq!(sc.positions.len(), grid.as_array().unwrap().len());
        // Every state with a key is a node; every node at horizon 0/30 is a state.
        let mut state_of: HashMap<String, usize> = HashMap::new();
        for s in 0..sc.num_states() {
            if let Some(k) = off.key(s) {
                assert!(nodes.contains(k), "{}: {k}", sc.name);
                assert_eq!(k, state_key(sc.state(s)));
                state_of.insert(k.to_string(), s);
            }
        }
        let usable = nodes.iter().filter(|k| !k.ends_with("|60")).count();
        assert_eq!(state_of.len(), usable, "{}", sc.name);
        assert_eq!(off.skipped_nodes, nodes.len() - usable);
        // Transitions: the intended state if the graph has that edge, else stay.
        for (k, &s) in &state_of {
            for a in &Action::ALL[..Action::Done.index()] {
                let next = t.next[s][a.index()] as usize;
                let want = state_key(intended(sc.state(s), *a));
                if edges.contains(&(k.clone(), want.clone())) {
                    assert_eq!(off.key(next), Some(want.as_str()), "{} {k} {a:?}", sc.name);
                    checked_edges += 1;
                } else {
                    assert_eq!(next, s, "{} {k} {a:?}: no edge to {want}", sc.name);
                }
            }
            assert_eq!(t.next[s][Action::Done.index()] as usize, s);
        }
        for (scene, from, to) in &info.blocked {
            if scene == &sc.name {
                let s = state_of[from];
                // The cell ahead is reachable, yet the graph blocks the move.
                assert!(state_of.contains_key(to));
                assert_eq!(t.next[s][Action::MoveAhead.index()] as usize, s);
                blocked_seen += 1;
            }
        }
        for (scene, key) in &info.absent {
            if scene == &sc.name {
                let st = offline::parse_state_key(key).unwrap().unwrap();
                let s = sc.state_index(st).expect("absent state is on the grid");
                assert!(!off.has_state(s));
                assert!(t.obs[s].features.iter().all(|&v| v == 0.0));
                assert!(t.predecessors(s).is_empty(), "no action leads to {key}");
                let mut up = st;
                up.horizon = 0;
                let u = sc.state_index(up).unwrap();
                assert_eq!(t.next[u][Action::LookDown.index()] as usize, u);
            }
        }
        // Visibility: exactly the written map (objects of known, allowed categories).
        let vis = read_json(&sdir.join("visible_object_map.json"));
        let ids = sc.id_map();
        let mut by_cat: HashMap<u16, HashSet<usize>> = HashMap::new();
        for (id, keys) in vis.as_object().unwrap() {
            let ty = id.split('|').next().unwrap();
            let listed: HashSet<usize> = keys
                .as_array()
                .unwrap()
                .iter()
                .map(|k| state_of[k.as_str().unwrap()])
                .collect();
            let Some(c) = w.category_id(ty) else {
                assert!(!ids.contains_key(id.as_str()), "{id} has no category");
                continue;
            };
            if sc.split == Split::Train && w.categories[c as usize].unseen {
                assert!(
                    !ids.contains_key(id.as_str()),
                    "unseen {id} in a training scene"
                );
                assert!(t.obs.iter().all(|o| !o.is_visible(c)));
                continue;
            }
            let inst = ids[id.as_str()];
            assert_eq!(sc.objects[inst].category, c);
            for s in 0..sc.num_states() {
                assert_eq!(
                    t.visible_instances[s].contains(&(inst as u16)),
                    listed.contains(&s),
                    "{} {id} state {s}",
                    sc.name
                );
            }
            by_cat.entry(c).or_default().extend(listed);
        }
        for s in 0..sc.num_states() {
            let mut want: Vec<u16> = by_cat
                .iter()
                .filter(|(_, v)| v.contains(&s))
                .map(|(c, _)| *c)
                .collect();
            want.sort_unstable();
            assert_eq!(t.obs[s].visible, want, "{} state {s}", sc.name);
        }
        // Features: the stored map (read independently) and its mean over the 49 cells.
        let f = hdf5::File::open(sdir.join("resnet18_featuremap.hdf5")).unwrap();
        let att = sdir.join("att_in_view_v2.hdf5");
        let att = att.exists().then(|| hdf5::File::open(att).unwrap());
        for (k, &s) in state_of.iter().take(40) {
            let ds = f.dataset(k).unwrap();
            assert_eq!(ds.shape(), MAP_SHAPE.to_vec());
            let raw: Vec<f32> = ds.read_raw().unwrap();
            assert_eq!(w.feature_map(sid, s).unwrap(), raw);
            for c in 0..FEATURE_DIM {
                let mean = raw[c * 49..(c + 1) * 49]
                    .iter()
                    .map(|&v| v as f64)
                    .sum::<f64>()
                    / 49.0;
                assert!((t.obs[s].features[c] as f64 - mean).abs() < 1e-6);
            }
            let ps = &t.obs[s].ps_target;
            match &att {
                Some(a) => {
                    let v: Vec<f32> = a.dataset(k).unwrap().read_raw().unwrap();
                    assert_eq!(ps.to_vec(), v);
                }
                None => {
                    let cats = &t.obs[s].visible;
                    for (d, &p) in ps.iter().enumerate() {
                        let m = cats.iter().map(|&c| w.attributes(c)[d]).sum::<f32>()
                            / cats.len().max(1) as f32;
                        assert!((p - m).abs() < 1e-6);
                    }
                }
            }
        }
        // Some states see objects.
        assert!(t.obs.iter().any(|o| !o.visible.is_empty()));
    }
    assert!(checked_edges > 1000, "{checked_edges}");
    assert_eq!(blocked_seen, info.blocked.len());
    assert!(w.feature_map(0, usize::MAX).is_err());
}

#[test]
fn oracle_reaches_sr_100_on_the_graphs_shortest_paths() {
    let _serial = serial();
    let (dir, info) = fixture();
    let w = world();
    let episodes = w.episodes(Split::Val, None).unwrap();
    assert_eq!(episodes.len(), info.episodes);
    assert!(episodes.len() >= 20);
    let cfg = EvalConfig {
        reward: RewardKind::Mixed,
        limits: EpisodeLimits::default(),
        progress: false,
    };
    let results = evaluate(w, &episodes, |_| Box::new(OracleAgent), &cfg);
    // BFS over the written graph, from the start key to any key where a target is visible.
    let sdir = dir.join("FloorPlan22");
    let (_, edges) = graph_of(&sdir);
    let mut adj: HashMap<&str, Vec<&str>> = HashMap::new();
    for (a, b) in &edges {
        adj.entry(a.as_str()).or_default().push(b.as_str());
    }
    let vis = read_json(&sdir.join("visible_object_map.json"));
    for (spec, r) in episodes.iter().zip(&results) {
        assert!(r.metrics.success, "episode {}", spec.index);
        assert_eq!(r.metrics.spl, 1.0);
        let target = w.category_name(spec.target);
        let goal: HashSet<&str> = vis
            .as_object()
            .unwrap()
            .iter()
            .filter(|(id, _)| id.split('|').next() == Some(target))
            .flat_map(|(_, ks)| ks.as_array().unwrap().iter().map(|k| k.as_str().unwrap()))
            .collect();
        let start = state_key(spec.start);
        let mut dist: HashMap<&str, u32> = HashMap::from([(start.as_str(), 0)]);
        let mut q = VecDeque::from([start.as_str()]);
        let mut found = None;
        while let Some(k) = q.pop_front() {
            if goal.contains(k) {
                found = Some(dist[k]);
                break;
            }
            for &n in adj.get(k).into_iter().flatten() {
                if !dist.contains_key(n) {
                    dist.insert(n, dist[k] + 1);
                    q.push_back(n);
                }
            }
        }
        let d = found.expect("target reachable in the graph");
        assert!(d >= 1);
        assert_eq!(r.metrics.shortest_path_length, Some(d + 1));
        assert_eq!(r.metrics.path_length, d + 1);
    }
}

fn opts(out: PathBuf, updates: u64) -> TrainOptions {
    TrainOptions {
        updates,
        run: RunSettings {
            seed: 3,
            min_steps: 20,
            max_steps: Some(30),
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

/// A short GMAN run on the offline fixture, export int8, and replay val episodes: the host
/// evaluation path and a bare gman-core navigator over the blob choose the same actions.
#[test]
fn short_training_run_then_blob_replays_through_gman_core() {
    let _serial = serial();
    let w = world();
    let dir = tmp("train");
    let mut rng = gman_core::rng::Xoshiro128::seed_from_u64(2);
    let g = init_generator(&Dims::MCU, &mut rng).unwrap();
    // With a 3 x 3 spatial map pooled from the stored 7 x 7 ResNet maps, meta-trained in
    // the device's mode.
    let dims = Dims::MCU.with_map(3, 3, 4);
    let mut model = NavModel::init(Method::Gman, dims, 2, Some(&g), None).unwrap();
    model.spec.inner_lr = 1e-2;
    model.spec.adapt_mode = gman_core::navigator::memory::AdaptMode::Efficient;
    let before = model.params.clone();
    let mut st = TrainState::new(
        model,
        AdamConfig {
            lr: 1e-3,
            ..AdamConfig::default()
        },
    );
    train(w, &opts(dir.clone(), 4), &mut st).unwrap();
    assert_eq!(st.update, 4);
    assert!(st.env_steps >= 4 * 2 * 20);
    assert!(st.model.params.all_finite());
    assert_ne!(
        before.tensor("ActorW").unwrap().data,
        st.model.params.tensor("ActorW").unwrap().data
    );
    let rows = std::fs::read_to_string(dir.join("metrics.csv")).unwrap();
    assert_eq!(rows.lines().count(), 5);

    let blob_bytes = st.model.to_blob(true).unwrap();
    let path = dir.join("model.gman");
    std::fs::write(&path, &blob_bytes).unwrap();
    let host = load_model(&path, None).unwrap();
    let episodes = w.episodes(Split::Val, Some(4)).unwrap();
    let mut steps = 0;
    for spec in &episodes {
        let mut env = Env::new(w, spec, RewardKind::Mixed, 40);
        env.record_trajectory(true);
        let mut agent = NavAgent::new(Arc::new(host.clone()));
        gman_host_sim::sim::eval::drive(&mut env, spec, &mut agent);
        assert_eq!(agent.errors, 0);
        let states = env.trajectory().to_vec();
        let blob = Blob::parse(&blob_bytes).unwrap();
        let weights = NavWeights::from_blob(&blob, &dims).unwrap();
        let mut arena = vec![0.0f32; Navigator::<Efficient, 20>::arena_len(&dims)];
        // The device's compact layout (the host agent ran the fast one): the same bits.
        let cfg = gman_core::navigator::NavConfig {
            footprint: gman_core::navigator::memory::Footprint::Compact,
            ..host.nav_config(false)
        };
        let mut nav: Navigator<'_, Efficient, 20> =
            Navigator::new(weights, &mut arena, cfg).unwrap();
        nav.reset(w.attributes(spec.target), spec.seed).unwrap();
        let mut env2 = Env::new(w, spec, RewardKind::Mixed, 40);
        let mut visited = vec![env2.agent_state()];
        let grid = MapGrid { rows: 3, cols: 3 };
        let mut map = vec![0.0f32; grid.len()];
        while !env2.is_done() {
            env2.observe_map(grid, &mut map);
            let out = nav.step_map(&env2.observe().features, &map, &[]).unwrap();
            env2.step(out.action);
            visited.push(env2.agent_state());
            steps += 1;
        }
        assert_eq!(env.metrics().path_length, env2.metrics().path_length);
        assert_eq!(env.metrics().success, env2.metrics().success);
        assert_eq!(states, visited[..states.len()].to_vec());
    }
    assert!(steps > 10, "{steps}");
}

/// The spatial map of an offline state is the stored ResNet map pooled to the grid: 7 x 7
/// is the map itself (cell-major), 1 x 1 its average, i.e. the pooled embedding.
#[test]
fn spatial_maps_pool_the_stored_feature_maps() {
    let _serial = serial();
    let w = world();
    let scene = w.split_scenes(Split::Val).unwrap()[0];
    for state in [0usize, 5, 17] {
        let stored = w.feature_map(scene, state).unwrap();
        let full = MapGrid { rows: 7, cols: 7 };
        let mut m = vec![0.0f32; full.len()];
        w.view_map(scene, state, full, &mut m);
        for cell in 0..49 {
            for ch in 0..512 {
                assert_eq!(m[cell * 512 + ch], stored[ch * 49 + cell]);
            }
        }
        let one = MapGrid { rows: 1, cols: 1 };
        let mut p = vec![0.0f32; one.len()];
        w.view_map(scene, state, one, &mut p);
        let pooled = &w.observation(scene, state).features;
        for (a, b) in p.iter().zip(pooled.iter()) {
            assert!((a - b).abs() < 1e-5, "{a} vs {b}");
        }
    }
}

fn gman(args: &[&str]) -> (bool, String, String) {
    let out = Command::new(env!("CARGO_BIN_EXE_gman"))
        .args(args)
        .output()
        .expect("run gman");
    (
        out.status.success(),
        String::from_utf8_lossy(&out.stdout).into_owned(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

/// The command line end to end on a fixture it writes itself: make-offline-fixture ->
/// pretrain-fg -> train (GMAN) -> export (int8 blob) -> eval with the blob (gman-core).
#[test]
fn cli_fixture_train_export_eval() {
    let _serial = serial();
    let d = tmp("cli");
    let data = d.join("data");
    let s = |p: &Path| p.to_str().unwrap().to_string();
    let (ok, out, err) = gman(&["make-offline-fixture", "--out", &s(&data)]);
    assert!(ok, "{err}");
    assert!(out.contains("FloorPlan22"), "{out}");
    let (ok, _, err) = gman(&[
        "pretrain-fg",
        "--data",
        &s(&data),
        "--iters",
        "20",
        "--out",
        &s(&d.join("fg")),
        "--quiet",
    ]);
    assert!(ok, "{err}");
    // A map finer than the stored 7 x 7 maps is refused up front.
    let (ok, _, err) = gman(&[
        "train",
        "--data",
        &s(&data),
        "--map",
        "9x9",
        "--out",
        &s(&d.join("run9")),
        "--quiet",
    ]);
    assert!(!ok && err.contains("7 x 7"), "{err}");
    let run = d.join("run");
    let (ok, _, err) = gman(&[
        "train",
        "--data",
        &s(&data),
        "--method",
        "gman",
        "--map",
        "3x3",
        "--fg",
        &s(&d.join("fg/fg.ckpt")),
        "--updates",
        "3",
        "--max-steps",
        "30",
        "--min-steps",
        "20",
        "--out",
        &s(&run),
        "--quiet",
    ]);
    assert!(ok, "{err}");
    let blob = d.join("model.gman");
    let (ok, _, err) = gman(&[
        "export",
        "--ckpt",
        &s(&run.join("checkpoint.ckpt")),
        "--out",
        &s(&blob),
    ]);
    assert!(ok, "{err}");
    let json = d.join("eval.json");
    let (ok, out, err) = gman(&[
        "eval",
        "--data",
        &s(&data),
        "--split",
        "val",
        "--agent",
        &s(&blob),
        "--quiet",
        "--json",
        &s(&json),
    ]);
    assert!(ok, "{err}");
    assert!(out.contains("kitchen"), "{out}");
    let v = read_json(&json);
    assert_eq!(v["episodes"], 30);
    for k in ["seen", "unseen"] {
        let sr = v["results"][k]["sr"].as_f64().unwrap();
        assert!((0.0..=100.0).contains(&sr));
        assert!(v["results"][k]["epa"].as_f64().unwrap() > 0.0);
    }
    // The oracle on the same data: SR 100.
    let (ok, out, err) = gman(&[
        "eval",
        "--data",
        &s(&data),
        "--split",
        "val",
        "--agent",
        "oracle",
        "--quiet",
    ]);
    assert!(ok, "{err}");
    assert!(out.contains("100.00  100.00"), "{out}");
}

/// A hand-made one-scene directory (2 grid points, all 32 states), written by the test
/// itself; `feature_keys` picks the datasets written and `shape` their shape.
fn mini(name: &str, feature_keys: impl Fn(&str) -> bool, shape: &[usize]) -> PathBuf {
    let d = tmp(name);
    std::fs::copy(
        fixture().0.join("attributes.json"),
        d.join("attributes.json"),
    )
    .unwrap();
    let sd = d.join("FloorPlan3");
    std::fs::create_dir_all(&sd).unwrap();
    std::fs::write(
        sd.join("grid.json"),
        r#"[{"x": 0.0, "y": 0.9, "z": 0.0}, {"x": 0.0, "y": 0.9, "z": 0.25}]"#,
    )
    .unwrap();
    let mut keys = Vec::new();
    for z in ["0.00", "0.25"] {
        for r in 0..8 {
            for h in [0, 30] {
                keys.push(format!("0.00|{z}|{}|{h}", r * 45));
            }
        }
    }
    let nodes: Vec<Value> = keys.iter().map(|k| serde_json::json!({"id": k})).collect();
    let links = vec![serde_json::json!({"source": "0.00|0.00|0|0", "target": "0.00|0.25|0|0"})];
    std::fs::write(
        sd.join("graph.json"),
        serde_json::json!({"directed": true, "multigraph": false, "graph": {},
                           "nodes": nodes, "links": links})
        .to_string(),
    )
    .unwrap();
    std::fs::write(
        sd.join("visible_object_map.json"),
        r#"{"Fridge|+00.00|+00.90|+01.00": ["0.00|0.25|0|0"]}"#,
    )
    .unwrap();
    let n: usize = shape.iter().product();
    let data = vec![0.5f32; n];
    let chosen: Vec<&String> = keys.iter().filter(|k| feature_keys(k)).collect();
    h5::write_datasets(
        &sd.join("resnet18_featuremap.hdf5"),
        chosen.iter().map(|k| (k.as_str(), shape, data.as_slice())),
    )
    .unwrap();
    d
}

fn load_err(d: &Path) -> String {
    format!("{:#}", World::load(d).unwrap_err())
}

#[test]
fn hand_made_scene_loads_and_bad_files_are_named() {
    let _serial = serial();
    // The valid hand-made scene loads: one move edge, Fridge visible from one state.
    let ok = mini("ok", |_| true, &MAP_SHAPE);
    let w = World::load(&ok).unwrap();
    let t = w.tables(0);
    let sc = &w.scenes[0];
    let s0 = sc
        .state_index(offline::parse_state_key("0.00|0.00|0|0").unwrap().unwrap())
        .unwrap();
    let s1 = t.next[s0][Action::MoveAhead.index()] as usize;
    assert_eq!(w.offline_scene(0).unwrap().key(s1), Some("0.00|0.25|0|0"));
    assert_eq!(t.next[s1][Action::MoveAhead.index()] as usize, s1);
    assert_eq!(
        t.next[s0][Action::RotateRight.index()] as usize,
        s0,
        "no edge"
    );
    assert_eq!(t.obs[s1].visible, vec![w.category_id("Fridge").unwrap()]);
    assert!(t.obs[s0].visible.is_empty());
    assert!(t.obs[s1].features.iter().all(|&v| (v - 0.5).abs() < 1e-6));
    assert_eq!(w.feature_map(0, s1).unwrap().len(), MAP_LEN);

    // A missing file.
    let d = mini("nofile", |_| true, &MAP_SHAPE);
    std::fs::remove_file(d.join("FloorPlan3/visible_object_map.json")).unwrap();
    let e = load_err(&d);
    assert!(
        e.contains("missing file") && e.contains("FloorPlan3/visible_object_map.json"),
        "{e}"
    );
    // A missing key.
    let d = mini("nokey", |k| k != "0.00|0.25|135|30", &MAP_SHAPE);
    let e = load_err(&d);
    assert!(
        e.contains("resnet18_featuremap.hdf5") && e.contains("no dataset \"0.00|0.25|135|30\""),
        "{e}"
    );
    // A wrong shape.
    let d = mini("shape", |_| true, &[512, 7, 7]);
    let e = load_err(&d);
    assert!(
        e.contains("resnet18_featuremap.hdf5")
            && e.contains("shape [512, 7, 7]")
            && e.contains("[1, 512, 7, 7]"),
        "{e}"
    );
    // A node off the grid and a visible key that is no node.
    let d = mini("offgrid", |_| true, &MAP_SHAPE);
    let g = d.join("FloorPlan3/graph.json");
    let text = std::fs::read_to_string(&g)
        .unwrap()
        .replace("\"0.00|0.25|0|30\"}", "\"0.00|0.50|0|30\"}");
    std::fs::write(&g, text).unwrap();
    let e = load_err(&d);
    assert!(
        e.contains("graph.json") && e.contains("0.00|0.50|0|30") && e.contains("grid.json"),
        "{e}"
    );
    let d = mini("viskey", |_| true, &MAP_SHAPE);
    std::fs::write(
        d.join("FloorPlan3/visible_object_map.json"),
        r#"{"Fridge|+00.00|+00.90|+01.00": ["0.00|0.75|0|0"]}"#,
    )
    .unwrap();
    let e = load_err(&d);
    assert!(
        e.contains("visible_object_map.json") && e.contains("0.00|0.75|0|0"),
        "{e}"
    );
    // A visible state written differently from the node id still maps to that state.
    std::fs::write(
        d.join("FloorPlan3/visible_object_map.json"),
        r#"{"Fridge|+00.00|+00.90|+01.00": ["0.0|0.250|0.0|0"]}"#,
    )
    .unwrap();
    let w = World::load(&d).unwrap();
    assert_eq!(
        w.tables(0).obs[s1].visible,
        vec![w.category_id("Fridge").unwrap()]
    );
    // Broken HDF5.
    let d = mini("broken", |_| true, &MAP_SHAPE);
    std::fs::write(d.join("FloorPlan3/resnet18_featuremap.hdf5"), b"not hdf5").unwrap();
    let e = load_err(&d);
    assert!(
        e.contains("resnet18_featuremap.hdf5") && e.contains("cannot open as HDF5"),
        "{e}"
    );
    // An official episode starting on a grid state that is no node of the graph.
    let d = mini("episode", |_| true, &MAP_SHAPE);
    let g = d.join("FloorPlan3/graph.json");
    let text = std::fs::read_to_string(&g)
        .unwrap()
        .replace("{\"id\":\"0.00|0.25|90|0\"},", "");
    std::fs::write(&g, text).unwrap();
    // FloorPlan3 is a training scene: evaluation needs a val scene, so rename it.
    std::fs::rename(d.join("FloorPlan3"), d.join("FloorPlan22")).unwrap();
    std::fs::create_dir_all(d.join("episodes/val")).unwrap();
    std::fs::write(
        d.join("episodes/val/kitchen_seen.jsonl"),
        r#"{"room": "kitchen", "scene": "FloorPlan22", "split": "val", "start": {"horizon": 0, "rotation": 90, "x": 0.0, "y": 0.9, "z": 0.25}, "target": "Fridge", "target_ids": ["Fridge|+00.00|+00.90|+01.00"], "target_kind": "seen"}"#,
    )
    .unwrap();
    let w = World::load(&d).unwrap();
    let e = format!("{:#}", w.episodes(Split::Val, None).unwrap_err());
    assert!(
        e.contains("0.00|0.25|90|0") && e.contains("is not a node") && e.contains("graph.json"),
        "{e}"
    );
}

/// The oracle's results on every val episode of `w`.
fn oracle_results(w: &World) -> Vec<gman_host_sim::sim::EpisodeResult> {
    let episodes = w.episodes(Split::Val, None).unwrap();
    let cfg = EvalConfig {
        reward: RewardKind::Mixed,
        limits: EpisodeLimits::default(),
        progress: false,
    };
    evaluate(w, &episodes, |_| Box::new(OracleAgent), &cfg)
}

#[test]
fn savn_folder_names_load_every_scene_and_the_oracle_scores_100() {
    let _serial = serial();
    let d = tmp("savn-names");
    let info = write_fixture_named(&d, 3, true, offline::VISIBLE_FILE).unwrap();
    // Every fixture scene is a kitchen: all folders are in SAVN's naming.
    for s in &info.scenes {
        assert!(d.join(format!("{s}_physics")).is_dir(), "{s}");
        assert!(!d.join(s).exists(), "{s}");
    }
    let w = World::load(&d).unwrap();
    let mut names: Vec<&str> = w.scenes.iter().map(|s| s.name.as_str()).collect();
    names.sort_unstable();
    let mut want: Vec<&str> = info.scenes.iter().map(String::as_str).collect();
    want.sort_unstable();
    assert_eq!(names, want, "scenes keep their FloorPlanN names");
    let results = oracle_results(&w);
    assert_eq!(results.len(), info.episodes);
    assert!(results
        .iter()
        .all(|r| r.metrics.success && r.metrics.spl == 1.0));
    // The same results as the GMAN-named fixture.
    let gman_sr: Vec<_> = oracle_results(world())
        .iter()
        .map(|r| (r.metrics.path_length, r.metrics.shortest_path_length))
        .collect();
    let savn_sr: Vec<_> = results
        .iter()
        .map(|r| (r.metrics.path_length, r.metrics.shortest_path_length))
        .collect();
    assert_eq!(gman_sr, savn_sr);

    // Mixed namings in one directory load too; one scene in both namings is refused.
    std::fs::rename(d.join("FloorPlan2_physics"), d.join("FloorPlan2")).unwrap();
    assert_eq!(World::load(&d).unwrap().scenes.len(), info.scenes.len());
    copy_dir(&d.join("FloorPlan2"), &d.join("FloorPlan2_physics"));
    let err = format!("{:#}", World::load(&d).unwrap_err());
    assert!(
        err.contains("FloorPlan2 is there twice") && err.contains("FloorPlan2_physics"),
        "{err}"
    );
}

fn copy_dir(from: &Path, to: &Path) {
    std::fs::create_dir_all(to).unwrap();
    for e in std::fs::read_dir(from).unwrap() {
        let e = e.unwrap();
        std::fs::copy(e.path(), to.join(e.file_name())).unwrap();
    }
}

#[test]
fn visibility_file_variant_is_chosen_by_a_flag() {
    let _serial = serial();
    let d = tmp("vis-1.5");
    let variant = "visible_object_map_1.5.json";
    let info = write_fixture_named(&d, 3, false, variant).unwrap();
    // The default file is missing: the error names the file and the flag.
    let err = format!("{:#}", World::load(&d).unwrap_err());
    assert!(
        err.contains("visible_object_map.json") && err.contains("--visible-file"),
        "{err}"
    );
    let opts = offline::OfflineOptions {
        visible_file: variant.to_string(),
    };
    let w = World::load_with_options(&d, gman_host_sim::sim::DEFAULT_WORLD_SEED, &opts).unwrap();
    let results = oracle_results(&w);
    assert_eq!(results.len(), info.episodes);
    assert!(results.iter().all(|r| r.metrics.success));
    // The command line: `--visible-file` reaches the loader.
    let (ok, out, err) = gman(&[
        "eval",
        "--data",
        d.to_str().unwrap(),
        "--visible-file",
        variant,
        "--agent",
        "oracle",
        "--quiet",
    ]);
    assert!(ok, "{err}");
    assert!(out.contains("100.00"), "{out}");
    let (ok, _, err) = gman(&["eval", "--data", d.to_str().unwrap(), "--quiet"]);
    assert!(!ok && err.contains("--visible-file"), "{err}");
}
