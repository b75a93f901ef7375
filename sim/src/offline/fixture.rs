//! A small data directory in exactly the offline format ([`crate::offline`]), made by
//! the project (no copied data): `attributes.json` with 7 made-up attribute vectors (real
//! AI2THOR category names, so the catalog's sizes apply), three kitchens (`FloorPlan1`,
//! `FloorPlan2` train, `FloorPlan22` val) with real HDF5 feature files, and official-format
//! val episodes. `gman make-offline-fixture --out DIR` writes it.
//!
//! Each scene is a 5 x 3 grid of 0.25 m cells (x -0.50..0.50, z -0.25..0.25) minus one cell,
//! 14 positions x 16 states. Objects stand around the grid. The fixture's own rules:
//! * **Graph**: an edge for every action (MoveAhead, rotations, LookUp/LookDown) between two
//!   nodes, except some deliberately **blocked moves** (the cell ahead exists but the graph
//!   has no edge, as when furniture sits between two grid points) and one **absent state**
//!   (a grid point's state that is not a node). `FloorPlan1` also has nodes at horizon 60
//!   (which the loader ignores; they have no feature dataset) and lists its edges under
//!   `links`; the others under `edges` (networkx 3.6 naming).
//! * **Visibility**: an object is visible from a state when its footprint (centre distance
//!   minus the catalog radius) is within 1.0 m, it is at most 50 degrees off the heading,
//!   and, looking down, its centre is at most 1.2 m high.
//! * **Feature maps** (1, 512, 7, 7), values >= 0 like ReLU outputs: a per-scene, per-heading
//!   background (0.15 scale), per-state-and-cell noise (0.05), and for every visible object
//!   its category's fixed pattern (0.8 in the image column where the object is, 0.4 in the
//!   neighbouring columns).
//! * `FloorPlan22` has `att_in_view_v2.hdf5`: `0.25 + 0.5 x` the mean attribute vector of the
//!   visible categories (0.25 everywhere when nothing is visible), so that a test can tell it
//!   from the loader's fallback rule.
//! * `FloorPlan1` and `FloorPlan2` contain a `CoffeeMachine` (an unseen category: the loader
//!   must drop it from training scenes) and every scene a `CounterTop` (not in
//!   `attributes.json`: ignored).

use std::collections::{BTreeMap, HashMap, HashSet, VecDeque};
use std::fs;
use std::path::Path;

use anyhow::{bail, Context, Result};
use gman_core::{Action, ATTR_DIM, FEATURE_DIM};
use serde_json::{json, Value};

use super::{h5, state_key, ATT_FILE, FEATURE_FILE, GRAPH_FILE, GRID_FILE, MAP_LEN, VISIBLE_FILE};
use crate::catalog::props_of;
use crate::geometry::{heading_dir, heading_step, turn, GRID};
use crate::types::{AgentState, NUM_HEADINGS};
use crate::util::{hash2, hash_str, unit_f32};

/// Categories of the fixture: (name, unseen).
pub const CATEGORIES: [(&str, bool); 7] = [
    ("Fridge", false),
    ("Microwave", false),
    ("Sink", false),
    ("Television", false),
    ("Sofa", false),
    ("CoffeeMachine", true),
    ("Toaster", true),
];

/// A move the fixture's graph blocks: (scene, from key, to key).
pub type BlockedMove = (String, String, String);

/// What [`write_fixture`] wrote, for tests.
#[derive(Clone, Debug, Default)]
pub struct FixtureInfo {
    /// Scene folder names.
    pub scenes: Vec<String>,
    /// MoveAhead edges left out although the cell ahead is reachable.
    pub blocked: Vec<BlockedMove>,
    /// (scene, key) of grid states that are not graph nodes.
    pub absent: Vec<(String, String)>,
    /// Val episodes written (per kind file).
    pub episodes: usize,
}

struct SceneSpec {
    name: &'static str,
    objects: Vec<(&'static str, [f32; 3])>,
    blocked: Vec<(AgentState, AgentState)>,
    absent: Vec<AgentState>,
    horizon60: bool,
    att: bool,
    edges_key: &'static str,
}

fn st(x: i32, z: i32, heading: u8, horizon: u8) -> AgentState {
    AgentState {
        x,
        z,
        heading,
        horizon,
    }
}

fn cells() -> Vec<(i32, i32)> {
    let mut v = Vec::new();
    for x in -2..=2 {
        for z in -1..=1 {
            if (x, z) != (1, 1) {
                v.push((x, z));
            }
        }
    }
    v
}

fn specs() -> Vec<SceneSpec> {
    vec![
        SceneSpec {
            name: "FloorPlan1",
            objects: vec![
                ("Fridge", [-0.95, 0.9, 0.0]),
                ("Microwave", [0.0, 1.1, 0.7]),
                ("Sink", [0.9, 0.85, -0.3]),
                ("Television", [0.0, 1.0, -0.75]),
                ("CoffeeMachine", [0.3, 1.05, 0.7]),
                ("CounterTop", [0.55, 0.9, 0.7]),
            ],
            blocked: vec![(st(-2, 0, 2, 0), st(-1, 0, 2, 0))],
            absent: vec![],
            horizon60: true,
            att: false,
            edges_key: "links",
        },
        SceneSpec {
            name: "FloorPlan2",
            objects: vec![
                ("Sink", [-0.9, 0.85, 0.1]),
                ("Fridge", [0.95, 0.9, -0.1]),
                ("Television", [-0.2, 1.0, 0.75]),
                ("Microwave", [0.2, 1.1, -0.7]),
                ("CoffeeMachine", [-0.5, 1.05, -0.7]),
                ("CounterTop", [0.5, 0.9, -0.7]),
            ],
            blocked: vec![(st(0, -1, 0, 0), st(0, 0, 0, 0))],
            absent: vec![st(2, 1, 0, 1)],
            horizon60: false,
            att: false,
            edges_key: "edges",
        },
        SceneSpec {
            name: "FloorPlan22",
            objects: vec![
                ("Fridge", [0.1, 0.9, -0.8]),
                ("Microwave", [-0.9, 1.1, 0.2]),
                ("Sink", [0.3, 0.85, 0.7]),
                ("CoffeeMachine", [0.9, 1.05, 0.0]),
                ("Toaster", [0.6, 1.0, -0.65]),
                ("CounterTop", [-0.5, 0.9, 0.7]),
            ],
            blocked: vec![(st(-1, 0, 6, 0), st(-2, 0, 6, 0))],
            absent: vec![],
            horizon60: false,
            att: true,
            edges_key: "edges",
        },
    ]
}

/// AI2THOR-style object id `Type|+x.xx|+y.yy|+z.zz`.
fn object_id(ty: &str, p: [f32; 3]) -> String {
    format!("{ty}|{:+06.2}|{:+06.2}|{:+06.2}", p[0], p[1], p[2])
}

/// Signed angle (degrees) of the object off the heading, and the horizontal centre distance.
fn bearing(s: AgentState, p: [f32; 3]) -> (f32, f32) {
    let (px, pz) = (s.x as f32 * GRID, s.z as f32 * GRID);
    let (dx, dz) = (p[0] - px, p[2] - pz);
    let (hx, hz) = heading_dir(s.heading);
    let dist = (dx * dx + dz * dz).sqrt();
    let cross = hx * dz - hz * dx;
    let dot = hx * dx + hz * dz;
    (cross.atan2(dot).to_degrees(), dist)
}

fn visible(s: AgentState, ty: &str, p: [f32; 3]) -> bool {
    let (angle, dist) = bearing(s, p);
    let props = props_of(ty);
    dist - props.radius <= 1.0 && angle.abs() <= 50.0 && (s.horizon == 0 || p[1] <= 1.2)
}

fn attributes(seed: u64) -> BTreeMap<String, Vec<f32>> {
    CATEGORIES
        .iter()
        .map(|(name, _)| {
            let h = hash_str(seed, name);
            let v = (0..ATTR_DIM)
                .map(|d| {
                    let u = unit_f32(hash2(h, d as u64));
                    if u < 0.6 {
                        0.0
                    } else {
                        (u - 0.6) / 0.4
                    }
                })
                .collect();
            (name.to_string(), v)
        })
        .collect()
}

fn feature_map(seed: u64, scene: &str, s: AgentState, seen: &[(&str, [f32; 3])]) -> Vec<f32> {
    let sh = hash_str(seed, scene);
    let bg = hash2(sh, s.heading as u64 + 100 * s.horizon as u64);
    let noise = hash_str(sh, &state_key(s));
    let mut map = vec![0f32; MAP_LEN];
    for c in 0..FEATURE_DIM {
        let b = 0.15 * unit_f32(hash2(bg, c as u64));
        for cell in 0..49 {
            map[c * 49 + cell] = b + 0.05 * unit_f32(hash2(noise, (c * 49 + cell) as u64));
        }
    }
    for (ty, p) in seen {
        let (angle, _) = bearing(s, *p);
        // Angle -50 (left of the heading) -> column 0, +50 -> column 6.
        let col = (((-angle + 50.0) / 100.0) * 6.0).round().clamp(0.0, 6.0) as usize;
        let pat = hash_str(seed ^ 0xFEA7, ty);
        for c in 0..FEATURE_DIM {
            let v = unit_f32(hash2(pat, c as u64));
            for row in 0..7 {
                for dc in [-1i32, 0, 1] {
                    let cc = col as i32 + dc;
                    if (0..7).contains(&cc) {
                        let w = if dc == 0 { 0.8 } else { 0.4 };
                        map[c * 49 + row * 7 + cc as usize] += w * v;
                    }
                }
            }
        }
    }
    map
}

fn write_json(path: &Path, v: &Value) -> Result<()> {
    let text = serde_json::to_string_pretty(v)?;
    fs::write(path, text).with_context(|| format!("cannot write {}", path.display()))
}

/// The fixture's categories of each kind: (seen, unseen, the kitchens' seen targets).
struct Targets {
    seen: Vec<&'static str>,
    unseen: Vec<&'static str>,
    kitchen_seen: Vec<&'static str>,
}

impl Targets {
    fn new() -> Self {
        let names = |unseen: bool| -> Vec<&'static str> {
            CATEGORIES
                .iter()
                .filter(|c| c.1 == unseen)
                .map(|c| c.0)
                .collect()
        };
        Targets {
            seen: names(false),
            unseen: names(true),
            kitchen_seen: vec!["Fridge", "Microwave", "Sink"],
        }
    }
}

fn write_attributes(out: &Path, attrs: &BTreeMap<String, Vec<f32>>, t: &Targets) -> Result<()> {
    write_json(
        &out.join("attributes.json"),
        &json!({
            "dim": ATTR_DIM,
            "categories": attrs,
            "split": {
                "train_targets_by_room": {
                    "kitchen": ["Fridge", "Microwave", "Sink", "Television"],
                    "living_room": ["Sofa", "Television"],
                    "bedroom": [],
                    "bathroom": []
                },
                "seen": t.seen,
                "unseen": t.unseen,
                "by_room": {"kitchen": {"seen": t.kitchen_seen, "unseen": t.unseen}}
            },
            "note": "gman-rs offline fixture: made-up attribute vectors"
        }),
    )
}

/// One scene's state graph: its grid cells, its nodes (every state of every cell but the
/// absent ones) and its edges (every action's move between two nodes, but the blocked ones).
struct SceneGraph {
    cells: Vec<(i32, i32)>,
    nodes: Vec<AgentState>,
    edges: Vec<(AgentState, AgentState)>,
}

impl SceneGraph {
    fn new(spec: &SceneSpec) -> Self {
        let cells = cells();
        let cell_set: HashSet<(i32, i32)> = cells.iter().copied().collect();
        let absent: HashSet<AgentState> = spec.absent.iter().copied().collect();
        let mut nodes: Vec<AgentState> = Vec::new();
        for &(x, z) in &cells {
            for h in 0..NUM_HEADINGS as u8 {
                for v in 0..2 {
                    let s = st(x, z, h, v);
                    if !absent.contains(&s) {
                        nodes.push(s);
                    }
                }
            }
        }
        let node_set: HashSet<AgentState> = nodes.iter().copied().collect();
        let blocked: HashSet<(AgentState, AgentState)> = spec.blocked.iter().copied().collect();
        let mut edges: Vec<(AgentState, AgentState)> = Vec::new();
        for &s in &nodes {
            for a in &Action::ALL[..Action::Done.index()] {
                let t = match a {
                    Action::MoveAhead => {
                        let (dx, dz) = heading_step(s.heading);
                        if !cell_set.contains(&(s.x + dx, s.z + dz)) {
                            continue;
                        }
                        st(s.x + dx, s.z + dz, s.heading, s.horizon)
                    }
                    a => {
                        let (h, v) = turn(s.heading, s.horizon, *a).expect("turn");
                        st(s.x, s.z, h, v)
                    }
                };
                if t != s && node_set.contains(&t) && !blocked.contains(&(s, t)) {
                    edges.push((s, t));
                }
            }
        }
        SceneGraph {
            cells,
            nodes,
            edges,
        }
    }

    /// The grid file and the graph file (networkx node-link JSON).
    fn write(&self, dir: &Path, spec: &SceneSpec) -> Result<()> {
        write_json(
            &dir.join(GRID_FILE),
            &Value::Array(
                self.cells
                    .iter()
                    .map(|&(x, z)| json!({"x": x as f32 * GRID, "y": 0.9009996, "z": z as f32 * GRID}))
                    .collect(),
            ),
        )?;
        let mut node_keys: Vec<String> = self.nodes.iter().map(|&s| state_key(s)).collect();
        let mut links: Vec<Value> = self
            .edges
            .iter()
            .map(|(a, b)| json!({"source": state_key(*a), "target": state_key(*b)}))
            .collect();
        if spec.horizon60 {
            for &(x, z) in &self.cells {
                let k30 = format!("{:.2}|{:.2}|0|30", x as f32 * GRID, z as f32 * GRID);
                let k60 = format!("{:.2}|{:.2}|0|60", x as f32 * GRID, z as f32 * GRID);
                links.push(json!({"source": k30, "target": k60}));
                links.push(json!({"source": k60, "target": k30}));
                node_keys.push(k60);
            }
        }
        let mut graph = json!({
            "directed": true,
            "multigraph": false,
            "graph": {},
            "nodes": node_keys.iter().map(|k| json!({"id": k})).collect::<Vec<_>>(),
        });
        graph[spec.edges_key] = Value::Array(links);
        write_json(&dir.join(GRAPH_FILE), &graph)
    }
}

/// Visibility (per object, over nodes at horizons 0/30).
fn write_visibility(dir: &Path, spec: &SceneSpec, nodes: &[AgentState]) -> Result<()> {
    let mut vis: BTreeMap<String, Vec<String>> = BTreeMap::new();
    for (ty, p) in &spec.objects {
        let keys = nodes
            .iter()
            .filter(|&&s| visible(s, ty, *p))
            .map(|&s| state_key(s))
            .collect();
        vis.insert(object_id(ty, *p), keys);
    }
    write_json(&dir.join(VISIBLE_FILE), &serde_json::to_value(&vis)?)
}

/// The feature maps of every node.
fn write_features(dir: &Path, spec: &SceneSpec, nodes: &[AgentState], seed: u64) -> Result<()> {
    let maps: Vec<(String, Vec<f32>)> = nodes
        .iter()
        .map(|&s| {
            let seen: Vec<(&str, [f32; 3])> = spec
                .objects
                .iter()
                .filter(|(ty, p)| visible(s, ty, *p))
                .copied()
                .collect();
            (state_key(s), feature_map(seed, spec.name, s, &seen))
        })
        .collect();
    h5::write_datasets(
        &dir.join(FEATURE_FILE),
        maps.iter()
            .map(|(k, m)| (k.as_str(), &super::MAP_SHAPE[..], m.as_slice())),
    )
}

/// The PS targets of every node when the scene has them (an old file removed otherwise).
fn write_ps_targets(
    dir: &Path,
    spec: &SceneSpec,
    nodes: &[AgentState],
    attrs: &BTreeMap<String, Vec<f32>>,
) -> Result<()> {
    if !spec.att {
        let p = dir.join(ATT_FILE);
        if p.exists() {
            fs::remove_file(&p).with_context(|| format!("cannot remove {}", p.display()))?;
        }
        return Ok(());
    }
    let atts: Vec<(String, Vec<f32>)> = nodes
        .iter()
        .map(|&s| {
            let mut cats: Vec<&str> = spec
                .objects
                .iter()
                .filter(|(ty, p)| attrs.contains_key(*ty) && visible(s, ty, *p))
                .map(|o| o.0)
                .collect();
            cats.sort_unstable();
            cats.dedup();
            let mut v = vec![0f32; ATTR_DIM];
            for c in &cats {
                for (t, a) in v.iter_mut().zip(&attrs[*c]) {
                    *t += a / cats.len() as f32;
                }
            }
            v.iter_mut().for_each(|t| *t = 0.25 + 0.5 * *t);
            (state_key(s), v)
        })
        .collect();
    h5::write_datasets(
        &dir.join(ATT_FILE),
        atts.iter()
            .map(|(k, v)| (k.as_str(), &[ATTR_DIM][..], v.as_slice())),
    )
}

/// Val episodes of one scene: starts at horizon 0 that need at least one action to see the
/// target, up to 6 per target, added to `episodes` by kind.
fn val_episodes(
    spec: &SceneSpec,
    g: &SceneGraph,
    t: &Targets,
    episodes: &mut BTreeMap<&'static str, Vec<Value>>,
) {
    let nodes = &g.nodes;
    let index: HashMap<AgentState, usize> =
        nodes.iter().enumerate().map(|(i, &s)| (s, i)).collect();
    let mut pred: Vec<Vec<usize>> = vec![Vec::new(); nodes.len()];
    for (a, b) in &g.edges {
        pred[index[b]].push(index[a]);
    }
    for (kind, targets) in [("seen", &t.kitchen_seen), ("unseen", &t.unseen)] {
        for &target in targets {
            let goal: Vec<&(&str, [f32; 3])> =
                spec.objects.iter().filter(|o| o.0 == target).collect();
            let mut dist = vec![u32::MAX; nodes.len()];
            let mut q = VecDeque::new();
            for (i, &s) in nodes.iter().enumerate() {
                if goal.iter().any(|(ty, p)| visible(s, ty, *p)) {
                    dist[i] = 0;
                    q.push_back(i);
                }
            }
            while let Some(i) = q.pop_front() {
                for &p in &pred[i] {
                    if dist[p] == u32::MAX {
                        dist[p] = dist[i] + 1;
                        q.push_back(p);
                    }
                }
            }
            let starts: Vec<AgentState> = nodes
                .iter()
                .enumerate()
                .filter(|&(i, s)| s.horizon == 0 && dist[i] != u32::MAX && dist[i] >= 1)
                .map(|(_, &s)| s)
                .collect();
            for k in 0..starts.len().min(6) {
                let s = starts[(k * 7 + target.len()) % starts.len()];
                episodes.entry(kind).or_default().push(json!({
                    "room": "kitchen",
                    "scene": spec.name,
                    "split": "val",
                    "start": {
                        "horizon": 0,
                        "rotation": s.heading as u32 * 45,
                        "x": s.x as f32 * GRID,
                        "y": 0.9009996,
                        "z": s.z as f32 * GRID
                    },
                    "target": target,
                    "target_ids": goal.iter().map(|(ty, p)| object_id(ty, *p)).collect::<Vec<_>>(),
                    "target_kind": kind
                }));
            }
        }
    }
}

/// Writes the fixture into `out` (created; existing fixture files are replaced). `seed`
/// changes attribute vectors and feature values, not the layout.
pub fn write_fixture(out: &Path, seed: u64) -> Result<FixtureInfo> {
    write_fixture_with(out, seed, false)
}

/// The file [`write_fixture`] leaves in every directory it made: only such a directory may
/// be cleared with `force`.
pub const FIXTURE_MARKER: &str = ".gman-offline-fixture";

/// [`write_fixture`], refusing an `out` that exists and is not an empty directory: with
/// the README's layout (real `FloorPlan*` folders symlinked into a data directory), writing
/// into it would overwrite the user's feature maps through the links. With `force`, a
/// directory this tool made (it holds [`FIXTURE_MARKER`]) is cleared first (links inside it
/// are removed, never followed); any other non-empty directory is still refused.
pub fn write_fixture_with(out: &Path, seed: u64, force: bool) -> Result<FixtureInfo> {
    match fs::symlink_metadata(out) {
        Ok(m) if m.file_type().is_symlink() => bail!(
            "--out {} is a symbolic link; give a new or empty directory (the fixture never writes through links)",
            out.display()
        ),
        Ok(m) if !m.is_dir() => bail!("--out {} exists and is not a directory", out.display()),
        Ok(_) => {
            let non_empty = fs::read_dir(out)
                .with_context(|| format!("cannot read {}", out.display()))?
                .next()
                .is_some();
            if non_empty {
                let ours = fs::symlink_metadata(out.join(FIXTURE_MARKER)).is_ok_and(|m| m.is_file());
                if !(force && ours) {
                    bail!(
                        "--out {} is not empty; refusing to write a fixture into it (it could overwrite real data, also through symlinks){}",
                        out.display(),
                        if ours {
                            "; it is a fixture this tool wrote: add --force to replace it"
                        } else {
                            "; give a new or empty directory"
                        }
                    );
                }
                // remove_dir_all removes symlinks themselves, never what they point to.
                fs::remove_dir_all(out)
                    .with_context(|| format!("cannot clear {}", out.display()))?;
            }
        }
        Err(_) => {}
    }
    fs::create_dir_all(out).with_context(|| format!("cannot create {}", out.display()))?;
    fs::write(
        out.join(FIXTURE_MARKER),
        "made by `gman make-offline-fixture`; `--force` may replace this directory\n",
    )
    .with_context(|| format!("cannot write {}", out.join(FIXTURE_MARKER).display()))?;
    let attrs = attributes(seed);
    let targets = Targets::new();
    write_attributes(out, &attrs, &targets)?;
    let mut info = FixtureInfo::default();
    let mut episodes: BTreeMap<&str, Vec<Value>> = BTreeMap::new();
    for spec in specs() {
        let dir = out.join(spec.name);
        fs::create_dir_all(&dir).with_context(|| format!("cannot create {}", dir.display()))?;
        info.scenes.push(spec.name.to_string());
        for a in &spec.absent {
            info.absent.push((spec.name.to_string(), state_key(*a)));
        }
        for (a, b) in &spec.blocked {
            info.blocked
                .push((spec.name.to_string(), state_key(*a), state_key(*b)));
        }
        let g = SceneGraph::new(&spec);
        g.write(&dir, &spec)?;
        write_visibility(&dir, &spec, &g.nodes)?;
        write_features(&dir, &spec, &g.nodes, seed)?;
        write_ps_targets(&dir, &spec, &g.nodes, &attrs)?;
        if spec.name == "FloorPlan22" {
            val_episodes(&spec, &g, &targets, &mut episodes);
        }
    }
    let edir = out.join("episodes").join("val");
    fs::create_dir_all(&edir).with_context(|| format!("cannot create {}", edir.display()))?;
    for (kind, lines) in &episodes {
        let text: String = lines.iter().map(|l| format!("{l}\n")).collect();
        let p = edir.join(format!("kitchen_{kind}.jsonl"));
        fs::write(&p, text).with_context(|| format!("cannot write {}", p.display()))?;
        info.episodes += lines.len();
    }
    Ok(info)
}

/// Writes the fixture as [`write_fixture`] does, then renames it to another published naming:
/// with `savn_names` the kitchen and living-room folders become `FloorPlanN_physics` (SAVN's
/// download), and with `visible_file` other than [`VISIBLE_FILE`] each folder's visibility
/// file gets that name (e.g. `visible_object_map_1.5.json`, VTNet's and HOZ's). `out` must not
/// hold a fixture in another naming already.
pub fn write_fixture_named(
    out: &Path,
    seed: u64,
    savn_names: bool,
    visible_file: &str,
) -> Result<FixtureInfo> {
    write_fixture_named_with(out, seed, savn_names, visible_file, false)
}

/// [`write_fixture_named`] with [`write_fixture_with`]'s `force` (replace a fixture this
/// tool wrote; any other non-empty `out` is refused).
pub fn write_fixture_named_with(
    out: &Path,
    seed: u64,
    savn_names: bool,
    visible_file: &str,
    force: bool,
) -> Result<FixtureInfo> {
    let info = write_fixture_with(out, seed, force)?;
    for name in &info.scenes {
        let dir = out.join(name);
        if visible_file != VISIBLE_FILE {
            let (from, to) = (dir.join(VISIBLE_FILE), dir.join(visible_file));
            fs::rename(&from, &to)
                .with_context(|| format!("cannot rename {} to {}", from.display(), to.display()))?;
        }
        let n: u32 = name
            .strip_prefix("FloorPlan")
            .and_then(|n| n.parse().ok())
            .unwrap_or(0);
        if savn_names && n < 300 {
            let to = out.join(format!("{name}_physics"));
            fs::rename(&dir, &to)
                .with_context(|| format!("cannot rename {} to {}", dir.display(), to.display()))?;
        }
    }
    Ok(info)
}
