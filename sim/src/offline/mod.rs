//! The AI2THOR offline data that SAVN and GMAN train on, as a second world source: real
//! ResNet18 feature maps per state instead of the synthetic feature model.
//!
//! # Layout (`--data DIR`)
//!
//! ```text
//! DIR/attributes.json                  our attribute vectors and category split (required)
//! DIR/episodes/<split>/*.jsonl         our official episodes (needed for val/test evaluation)
//! DIR/FloorPlanN/                      one folder per scene, as in the GMAN download (SAVN's
//!                                      names kitchens and living rooms FloorPlanN_physics/;
//!                                      both are read, the scene is FloorPlanN either way):
//!     resnet18_featuremap.hdf5         one (1, 512, 7, 7) f32 dataset per state key
//!     graph.json                       networkx node-link data of the directed state graph
//!     grid.json                        the reachable points [{"x", "y", "z"}, ...]
//!     visible_object_map.json          object id "Type|x|y|z" -> state keys where visible
//!                                      (or a variant chosen by --visible-file, e.g. VTNet's
//!                                      and HOZ's visible_object_map_1.5.json)
//!     att_in_view_v2.hdf5              optional: one 45-d vector per state key (PS target)
//! ```
//!
//! A directory is read this way when it has no `scenes/` folder and at least one
//! `FloorPlanN/` folder ([`is_offline_dir`]). A state key is `"{x:.2f}|{z:.2f}|{rotation}|{horizon}"`
//! (metres, degrees), e.g. `"1.25|-0.50|135|0"`. Reading HDF5 needs the `offline` cargo feature
//! (the system HDF5 library through the `hdf5-metno` crate); without it loading such a
//! directory fails with an error that says so.
//!
//! # Rules (documented choices)
//!
//! * **Room type and split** follow from the floor plan number, as in the GMAN benchmark:
//!   1-30 kitchen, 201-230 living room, 301-330 bedroom, 401-430 bathroom; within a room type
//!   1-20 train, 22/24/26/28/30 val, 21/23/25/27/29 test ([`scene_room_split`]).
//! * **States**: the graph's nodes. A key's position must lie on the 0.25 m grid and be one of
//!   `grid.json`'s points; rotation must be a multiple of 45 degrees. Nodes with a horizon
//!   other than 0 or 30 degrees are ignored (our agent has those two, as the reference), and
//!   so are their edges. A grid point's states that are not graph nodes exist in our state
//!   layout (position x 8 headings x 2 horizons) but have no edges, so no action leads to
//!   them; their observation is all zeros and an official episode may not start there.
//! * **Transitions**: an action goes from state `s` to the state that it would reach on the
//!   grid (MoveAhead one cell along the heading, diagonally for odd headings; rotations of 45
//!   degrees; LookUp/LookDown between horizons 0 and 30) **only if `graph.json` has the edge
//!   `s -> that state`**; otherwise the agent stays. Edges that no action takes are unused.
//!   An undirected graph (`"directed": false`) has every edge both ways. Edges may be listed
//!   under `links` (networkx < 3.6 default) or `edges`.
//! * **Objects** are the ids of `visible_object_map.json`, `Type|x|y|z` with the position in
//!   metres (an id with a fifth part such as `Sink|...|SinkBasin` has the type of its last
//!   part). Types that `attributes.json` does not name are ignored; so are, in training
//!   scenes, the unseen categories (as the paper removes them from training scenes; the
//!   images are of course unchanged). **Visibility** is exactly the map: an instance is
//!   visible (success sense) in the states listed for it.
//! * **Observation**: [`Observation::features`] is the 512x7x7 map **average-pooled over its
//!   49 cells** (what the reference's discriminator sees); the full map is
//!   [`OfflineScene::feature_map`] (512 x 49, channel-major as stored). The PS target is the
//!   state's vector in `att_in_view_v2.hdf5` when the file exists, else the mean attribute
//!   vector of the distinct visible categories (zeros if none), the simulator's rule.
//!   [`Observation::in_view`] lists the visible instances weighted by the simulator's
//!   geometric estimate of the share of the view they fill (at least 0.05); it drives the
//!   feature collection of G's pre-training (dominant views).
//! * **Distances and rewards**: BFS over the transitions above (so shortest paths for SPL
//!   are paths in `graph.json`); the distance reward and DTS use the object positions of
//!   the ids and the category footprint radii, as in the simulator.
//!
//! Every file, key and dataset shape is checked when the world is loaded (HDF5 metadata only;
//! a scene's features are read when its tables are first built, where a non-finite value or
//! one beyond [`MAX_VALUE`] is refused). An error names the file and the key; a file that is
//! a link loop, a broken link, a directory or a device says so ([`check_file`]). A scene
//! folder named with a leading zero (`FloorPlan022`) is refused, and so is one floor plan in
//! two folders. `train` and `eval` build the tables of the scenes they use before they start
//! ([`crate::World::prepare_scenes`]), so that a bad feature file is an error; reading
//! one that changed or broke later panics with that error.

use std::collections::{BTreeMap, HashMap, HashSet};
use std::fs;
use std::path::{Path, PathBuf};

use anyhow::{anyhow, bail, Context, Result};
use gman_core::{Action, ATTR_DIM, FEATURE_DIM, NUM_ACTIONS};
use serde::Deserialize;
use serde_json::Value;

use super::geometry::{appearance, GRID, IN_VIEW_MIN_WEIGHT};
use super::scene::{Scene, SceneSource};
use super::tables::{InView, Observation, SceneTables};
use super::types::{AgentState, Category, CategoryId, RoomType, Split, NUM_HEADINGS};

pub mod h5;

#[cfg(feature = "offline")]
pub mod fixture;

/// Feature maps of a scene folder.
pub const FEATURE_FILE: &str = "resnet18_featuremap.hdf5";
/// State graph of a scene folder.
pub const GRAPH_FILE: &str = "graph.json";
/// Reachable points of a scene folder.
pub const GRID_FILE: &str = "grid.json";
/// Visibility of a scene folder.
pub const VISIBLE_FILE: &str = "visible_object_map.json";
/// Optional PS targets of a scene folder.
pub const ATT_FILE: &str = "att_in_view_v2.hdf5";
/// Cells of a feature map (7 x 7).
pub const MAP_CELLS: usize = 49;
/// Values of a feature map (512 channels x 49 cells).
pub const MAP_LEN: usize = FEATURE_DIM * MAP_CELLS;
/// Shape of a feature-map dataset.
pub const MAP_SHAPE: [usize; 4] = [1, FEATURE_DIM, 7, 7];
/// Accepted shapes of a PS-target dataset.
pub const ATT_SHAPES: [&[usize]; 2] = [&[ATTR_DIM], &[1, ATTR_DIM]];

/// The scene name of a scene folder: `FloorPlanN` for a folder `FloorPlanN` (GMAN's naming)
/// or `FloorPlanN_physics` (SAVN's naming of kitchens and living rooms), `None` otherwise.
pub fn scene_of_folder(folder: &str) -> Option<&str> {
    let name = folder.strip_suffix("_physics").unwrap_or(folder);
    name.strip_prefix("FloorPlan")
        .is_some_and(|n| !n.is_empty() && n.bytes().all(|b| b.is_ascii_digit()))
        .then_some(name)
}

/// Scene folders of `dir` (`FloorPlanN/` or `FloorPlanN_physics/`), as (scene name, folder),
/// sorted by scene name. Both namings of one scene in one directory is an error.
pub(crate) fn scene_folders(dir: &Path) -> Result<Vec<(String, PathBuf)>> {
    let out = scene_folders_unchecked(dir)?;
    if let Some(w) = out.windows(2).find(|w| w[0].0 == w[1].0) {
        bail!(
            "{}: scene {} is there twice, as {} and {} (keep one of the two namings)",
            dir.display(),
            w[0].0,
            w[0].1.display(),
            w[1].1.display()
        );
    }
    // `FloorPlan022` is floor plan 22 too: the same scene under a second name.
    let number = |name: &str| name["FloorPlan".len()..].parse::<u64>().ok();
    let mut by_number: BTreeMap<u64, &Path> = BTreeMap::new();
    for (name, path) in &out {
        let Some(n) = number(name) else {
            bail!("{}: {name} is not a floor plan number", path.display());
        };
        if let Some(other) = by_number.insert(n, path) {
            bail!(
                "{}: scene FloorPlan{n} is there twice, as {} and {} (floor plan numbers are written without leading zeros; remove one)",
                dir.display(),
                other.display(),
                path.display()
            );
        }
    }
    if let Some((name, path)) = out
        .iter()
        .find(|(name, _)| number(name).is_some_and(|n| name.as_str() != format!("FloorPlan{n}")))
    {
        bail!(
            "{}: {name} has a leading zero; name the folder FloorPlan{} (the episodes and the benchmark name scenes without one)",
            path.display(),
            number(name).unwrap_or_default()
        );
    }
    Ok(out)
}

/// [`scene_folders`] without the check for a scene in both namings.
fn scene_folders_unchecked(dir: &Path) -> Result<Vec<(String, PathBuf)>> {
    let mut out: Vec<(String, PathBuf)> = Vec::new();
    for e in fs::read_dir(dir).with_context(|| format!("cannot list {}", dir.display()))? {
        let e = e.with_context(|| format!("cannot list {}", dir.display()))?;
        let folder = e.file_name().to_string_lossy().into_owned();
        if let Some(name) = scene_of_folder(&folder) {
            if e.path().is_dir() {
                out.push((name.to_string(), e.path()));
            }
        }
    }
    out.sort();
    Ok(out)
}

/// True when `dir` holds offline scene folders (`FloorPlanN/` or `FloorPlanN_physics/`) and
/// no `scenes/` folder.
pub fn is_offline_dir(dir: &Path) -> bool {
    !dir.join("scenes").exists() && scene_folders_unchecked(dir).is_ok_and(|v| !v.is_empty())
}

/// Choices of how an offline directory is read.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct OfflineOptions {
    /// The visibility file of each scene folder: [`VISIBLE_FILE`] (SAVN, GMAN) or a variant of
    /// the projects built on the same data, e.g. `visible_object_map_1.5.json` (VTNet, HOZ:
    /// visibility within 1.5 m).
    pub visible_file: String,
}

impl Default for OfflineOptions {
    fn default() -> Self {
        OfflineOptions {
            visible_file: VISIBLE_FILE.to_string(),
        }
    }
}

/// Room type and split of a floor plan by its number (see the module docs).
pub fn scene_room_split(name: &str) -> Result<(RoomType, Split)> {
    let n: u32 = name
        .strip_prefix("FloorPlan")
        .and_then(|n| n.parse().ok())
        .ok_or_else(|| anyhow!("{name:?} is not a FloorPlanN name"))?;
    let room = match n / 100 {
        0 => RoomType::Kitchen,
        2 => RoomType::LivingRoom,
        3 => RoomType::Bedroom,
        4 => RoomType::Bathroom,
        _ => bail!("{name}: not an iTHOR floor plan (1-30, 201-230, 301-330, 401-430)"),
    };
    let k = n % 100;
    let split = match k {
        1..=20 => Split::Train,
        22 | 24 | 26 | 28 | 30 => Split::Val,
        21 | 23 | 25 | 27 | 29 => Split::Test,
        _ => bail!("{name}: not an iTHOR floor plan (1-30, 201-230, 301-330, 401-430)"),
    };
    Ok((room, split))
}

fn grid_index(v: f32, what: &str, key: &str) -> Result<i32> {
    let c = v / GRID;
    if !c.is_finite() || (c - c.round()).abs() > 0.05 {
        bail!("{what} {v} of {key:?} is not on the 0.25 m grid");
    }
    Ok(c.round() as i32)
}

/// Parses a state key `"x|z|rotation|horizon"`. `Ok(None)` for a state our agent does not
/// have (horizon other than 0 or 30 degrees); an error for a malformed key, a position off
/// the 0.25 m grid or a rotation that is not a multiple of 45 degrees.
pub fn parse_state_key(key: &str) -> Result<Option<AgentState>> {
    let parts: Vec<&str> = key.split('|').collect();
    let num = |i: usize, what: &str| -> Result<f32> {
        parts[i]
            .trim()
            .parse::<f32>()
            .ok()
            .filter(|v| v.is_finite())
            .ok_or_else(|| anyhow!("state key {key:?}: {what} {:?} is not a number", parts[i]))
    };
    if parts.len() != 4 {
        bail!("state key {key:?} is not \"x|z|rotation|horizon\"");
    }
    let (x, z, rot, hor) = (
        num(0, "x")?,
        num(1, "z")?,
        num(2, "rotation")?,
        num(3, "horizon")?,
    );
    let x = grid_index(x, "x", key)?;
    let z = grid_index(z, "z", key)?;
    let r = rot.rem_euclid(360.0) / 45.0;
    if (r - r.round()).abs() > 1e-3 {
        bail!("state key {key:?}: rotation {rot} is not a multiple of 45 degrees");
    }
    let horizon = match hor {
        h if h.abs() < 1e-3 => 0,
        h if (h - 30.0).abs() < 1e-3 => 1,
        _ => return Ok(None),
    };
    Ok(Some(AgentState {
        x,
        z,
        heading: (r.round() as usize % NUM_HEADINGS) as u8,
        horizon,
    }))
}

/// The state key of an agent state, `"{x:.2f}|{z:.2f}|{rotation}|{horizon}"`.
pub fn state_key(s: AgentState) -> String {
    format!(
        "{:.2}|{:.2}|{}|{}",
        s.x as f32 * GRID,
        s.z as f32 * GRID,
        s.heading as u32 * 45,
        s.horizon as u32 * 30
    )
}

/// Parses an AI2THOR object id `Type|x|y|z` (or `Parent|x|y|z|Type`): (type, centre).
pub fn parse_object_id(id: &str) -> Result<(String, [f32; 3])> {
    let parts: Vec<&str> = id.split('|').collect();
    let bad = || anyhow!("object id {id:?} is not \"Type|x|y|z\"");
    if parts.len() < 4 || parts[0].is_empty() {
        return Err(bad());
    }
    let mut pos = [0f32; 3];
    for (p, s) in pos.iter_mut().zip(&parts[1..4]) {
        *p = s
            .trim()
            .parse::<f32>()
            .ok()
            .filter(|v| v.is_finite())
            .ok_or_else(bad)?;
    }
    let ty = if parts.len() > 4 {
        parts[parts.len() - 1]
    } else {
        parts[0]
    };
    Ok((ty.to_string(), pos))
}

#[derive(Deserialize)]
struct RawGraph {
    #[serde(default)]
    directed: Option<bool>,
    nodes: Vec<RawNode>,
    #[serde(default)]
    links: Option<Vec<RawLink>>,
    #[serde(default)]
    edges: Option<Vec<RawLink>>,
}

#[derive(Deserialize)]
struct RawNode {
    id: Value,
}

#[derive(Deserialize)]
struct RawLink {
    source: Value,
    target: Value,
}

#[derive(Deserialize)]
struct RawPoint {
    x: f32,
    z: f32,
}

/// Checks that `path` is a regular file (after following links); otherwise an error that
/// says what it is: missing, a broken link, a link loop, a directory, a device, FIFO or
/// socket.
pub fn check_file(path: &Path) -> Result<()> {
    let p = path.display();
    let link = match fs::symlink_metadata(path) {
        Ok(m) => m.file_type().is_symlink(),
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => bail!("missing file {p}"),
        Err(e) => bail!("cannot read {p}: {e}"),
    };
    let m = match fs::metadata(path) {
        Ok(m) => m,
        Err(e) if link && e.kind() == std::io::ErrorKind::NotFound => {
            let to = fs::read_link(path).map(|t| t.display().to_string());
            bail!(
                "{p} is a broken symbolic link (to {}): its target does not exist",
                to.unwrap_or_else(|_| "?".into())
            )
        }
        // ELOOP: too many levels of symbolic links.
        Err(e) if link && e.raw_os_error() == Some(40) => {
            bail!("{p} is a symbolic link loop (it never reaches a file): {e}")
        }
        Err(e) => bail!("cannot read {p}: {e}"),
    };
    if m.is_dir() {
        bail!("{p} is a directory, not a file");
    }
    if !m.is_file() {
        bail!("{p} is not a regular file (a device, FIFO or socket), so it cannot be read as data");
    }
    Ok(())
}

/// True when something (a file, a link, even a broken one) is at `path`.
pub fn is_present(path: &Path) -> bool {
    fs::symlink_metadata(path).is_ok()
}

fn read_json<T: serde::de::DeserializeOwned>(path: &Path) -> Result<T> {
    check_file(path)?;
    let text =
        fs::read_to_string(path).with_context(|| format!("cannot read {}", path.display()))?;
    serde_json::from_str(&text).with_context(|| format!("malformed JSON in {}", path.display()))
}

fn node_id<'a>(v: &'a Value, path: &Path) -> Result<&'a str> {
    v.as_str()
        .ok_or_else(|| anyhow!("{}: node id {v} is not a string", path.display()))
}

/// One scene folder as read, before its [`Scene`] is built.
pub(crate) struct RawOfflineScene {
    /// What the scene is built from.
    pub source: SceneSource,
    dir: PathBuf,
    /// Graph nodes our agent has: (key, state).
    nodes: Vec<(String, AgentState)>,
    /// Edges between entries of `nodes`.
    edges: Vec<(u32, u32)>,
    /// Object id -> nodes where visible (objects of known categories only).
    visible: Vec<(String, Vec<u32>)>,
    features: h5::H5File,
    att: Option<h5::H5File>,
    skipped_nodes: usize,
}

/// Reads and checks every scene folder of `dir` (see the module docs).
pub(crate) fn load_scenes(
    dir: &Path,
    by_name: &HashMap<&str, CategoryId>,
    opts: &OfflineOptions,
) -> Result<Vec<RawOfflineScene>> {
    let folders = scene_folders(dir)?;
    if folders.is_empty() {
        bail!(
            "{}: no FloorPlanN/ or FloorPlanN_physics/ scene folders",
            dir.display()
        );
    }
    folders
        .iter()
        .map(|(name, path)| load_scene(name, path, by_name, opts))
        .collect()
}

fn load_scene(
    name: &str,
    dir: &Path,
    by_name: &HashMap<&str, CategoryId>,
    opts: &OfflineOptions,
) -> Result<RawOfflineScene> {
    let (room, split) = scene_room_split(name).with_context(|| format!("in {}", dir.display()))?;
    // Every required file first, so that a missing one is named before anything else fails.
    for f in [FEATURE_FILE, GRAPH_FILE, GRID_FILE] {
        check_file(&dir.join(f))?;
    }
    let vis = dir.join(&opts.visible_file);
    check_file(&vis).with_context(|| {
        format!(
            "the visibility file chosen by --visible-file {}",
            opts.visible_file
        )
    })?;
    let cells = read_cells(dir)?;
    let graph = SceneGraph::read(dir, &cells.iter().copied().collect())?;
    let (known, visible) = read_visibility(&vis, &graph, by_name)?;
    let (features, att) = open_features(dir, &graph.nodes)?;
    let mut present: Vec<CategoryId> = known.iter().map(|k| k.1).collect();
    present.sort_unstable();
    present.dedup();
    Ok(RawOfflineScene {
        source: SceneSource {
            name: name.to_string(),
            room,
            split,
            reachable: cells,
            present,
            known,
            exact: true,
            thor5: None,
        },
        dir: dir.to_path_buf(),
        nodes: graph.nodes,
        edges: graph.edges,
        visible,
        features,
        att,
        skipped_nodes: graph.skipped_nodes,
    })
}

/// The reachable points of the grid file, as grid cells.
fn read_cells(dir: &Path) -> Result<Vec<(i32, i32)>> {
    let grid_path = dir.join(GRID_FILE);
    let points: Vec<RawPoint> = read_json(&grid_path)?;
    if points.is_empty() {
        bail!("{}: no reachable points", grid_path.display());
    }
    let mut cells = Vec::with_capacity(points.len());
    for p in &points {
        let at = format!("point ({}, {})", p.x, p.z);
        let c = (
            grid_index(p.x, "x", &at).with_context(|| grid_path.display().to_string())?,
            grid_index(p.z, "z", &at).with_context(|| grid_path.display().to_string())?,
        );
        cells.push(c);
    }
    Ok(cells)
}

/// A scene's state graph as read: the nodes our agent has, and the edges between them.
struct SceneGraph {
    /// Graph nodes our agent has: (key, state).
    nodes: Vec<(String, AgentState)>,
    /// Index in `nodes` by key.
    node_of: HashMap<String, u32>,
    /// Key by state.
    state_of: HashMap<AgentState, String>,
    /// Every node key of the file (also the nodes our agent does not have).
    known_keys: HashSet<String>,
    /// Nodes of the file our agent does not have (other horizons).
    skipped_nodes: usize,
    /// Edges between entries of `nodes`.
    edges: Vec<(u32, u32)>,
}

impl SceneGraph {
    /// Reads the graph file; every node must sit on one of `cells`.
    fn read(dir: &Path, cell_set: &HashSet<(i32, i32)>) -> Result<Self> {
        let graph_path = dir.join(GRAPH_FILE);
        let graph: RawGraph = read_json(&graph_path)?;
        let mut g = SceneGraph {
            nodes: Vec::new(),
            node_of: HashMap::new(),
            state_of: HashMap::new(),
            known_keys: HashSet::new(),
            skipped_nodes: 0,
            edges: Vec::new(),
        };
        for n in &graph.nodes {
            let key = node_id(&n.id, &graph_path)?;
            g.known_keys.insert(key.to_string());
            let Some(s) = parse_state_key(key).with_context(|| graph_path.display().to_string())?
            else {
                g.skipped_nodes += 1;
                continue;
            };
            if !cell_set.contains(&(s.x, s.z)) {
                bail!(
                    "{}: node {key:?} is at a point that {} does not list",
                    graph_path.display(),
                    GRID_FILE
                );
            }
            if let Some(other) = g.state_of.insert(s, key.to_string()) {
                bail!(
                    "{}: nodes {other:?} and {key:?} are the same state",
                    graph_path.display()
                );
            }
            g.node_of.insert(key.to_string(), g.nodes.len() as u32);
            g.nodes.push((key.to_string(), s));
        }
        if g.nodes.is_empty() {
            bail!(
                "{}: no node with horizon 0 or 30 degrees",
                graph_path.display()
            );
        }
        let links = match (graph.links, graph.edges) {
            (Some(l), None) | (None, Some(l)) => l,
            (Some(_), Some(_)) => bail!(
                "{}: both \"links\" and \"edges\" are present",
                graph_path.display()
            ),
            (None, None) => bail!(
                "{}: no \"links\" (node-link edge list)",
                graph_path.display()
            ),
        };
        let directed = graph.directed.unwrap_or(true);
        g.edges = Vec::with_capacity(links.len() * if directed { 1 } else { 2 });
        for l in &links {
            let (a, b) = (
                node_id(&l.source, &graph_path)?,
                node_id(&l.target, &graph_path)?,
            );
            for k in [a, b] {
                if !g.known_keys.contains(k) {
                    bail!("{}: edge names unknown node {k:?}", graph_path.display());
                }
            }
            if let (Some(&i), Some(&j)) = (g.node_of.get(a), g.node_of.get(b)) {
                g.edges.push((i, j));
                if !directed {
                    g.edges.push((j, i));
                }
            }
        }
        Ok(g)
    }
}

/// Objects of known categories and the nodes each is visible from.
type Visibility = (Vec<(String, CategoryId, [f32; 3])>, Vec<(String, Vec<u32>)>);

/// Reads the visibility file: the objects of known categories and where each is visible.
fn read_visibility(
    vis_path: &Path,
    g: &SceneGraph,
    by_name: &HashMap<&str, CategoryId>,
) -> Result<Visibility> {
    let vis: BTreeMap<String, Vec<String>> = read_json(vis_path)?;
    let mut known = Vec::new();
    let mut visible = Vec::new();
    for (id, keys) in &vis {
        let (ty, pos) = parse_object_id(id).with_context(|| vis_path.display().to_string())?;
        let mut at = Vec::with_capacity(keys.len());
        for k in keys {
            // The same string as a node id, or (written differently) the same state.
            let node = g.node_of.get(k).copied().or_else(|| {
                let s = parse_state_key(k).ok().flatten()?;
                g.node_of.get(g.state_of.get(&s)?).copied()
            });
            match node {
                Some(i) => at.push(i),
                None if g.known_keys.contains(k) => {} // a node our agent does not have
                None => bail!(
                    "{}: object {id:?} lists state {k:?}, which is not a node of {}",
                    vis_path.display(),
                    GRAPH_FILE
                ),
            }
        }
        let Some(&cat) = by_name.get(ty.as_str()) else {
            continue; // a type without attributes: never a target, never counted
        };
        known.push((id.clone(), cat, pos));
        visible.push((id.clone(), at));
    }
    Ok((known, visible))
}

/// Opens the feature maps (and PS targets) and checks every node's dataset shape.
fn open_features(
    dir: &Path,
    nodes: &[(String, AgentState)],
) -> Result<(h5::H5File, Option<h5::H5File>)> {
    let features = h5::H5File::open(&dir.join(FEATURE_FILE))?;
    for (key, _) in nodes {
        features.check(key, &[&MAP_SHAPE])?;
    }
    let att_path = dir.join(ATT_FILE);
    let att = if is_present(&att_path) {
        let f = h5::H5File::open(&att_path)?;
        for (key, _) in nodes {
            f.check(key, &ATT_SHAPES)?;
        }
        Some(f)
    } else {
        None
    };
    Ok((features, att))
}

/// The offline data of one scene, indexed by the built scene's state indices.
#[derive(Debug)]
pub struct OfflineScene {
    /// The scene folder.
    pub dir: PathBuf,
    /// Graph nodes ignored for their horizon (not 0 or 30 degrees).
    pub skipped_nodes: usize,
    keys: Vec<Option<String>>,
    next: Vec<[u32; NUM_ACTIONS]>,
    visible_instances: Vec<Vec<u16>>,
    features: h5::H5File,
    att: Option<h5::H5File>,
}

impl OfflineScene {
    /// Indexes `raw` by the states of `scene` (built from `raw.source`).
    pub(crate) fn index(raw: RawOfflineScene, scene: &Scene) -> Result<OfflineScene> {
        let n = scene.num_states();
        let mut keys: Vec<Option<String>> = vec![None; n];
        let mut state_of_node = Vec::with_capacity(raw.nodes.len());
        for (key, s) in raw.nodes {
            let idx = scene.state_index(s).ok_or_else(|| {
                anyhow!(
                    "{}: state {key:?} is not a state of the scene",
                    raw.dir.display()
                )
            })?;
            state_of_node.push(idx as u32);
            keys[idx] = Some(key);
        }
        let edges: HashSet<(u32, u32)> = raw
            .edges
            .iter()
            .map(|&(a, b)| (state_of_node[a as usize], state_of_node[b as usize]))
            .collect();
        let next = (0..n)
            .map(|s| {
                let mut row = [s as u32; NUM_ACTIONS];
                if keys[s].is_some() {
                    for a in &Action::ALL[..Action::Done.index()] {
                        let t = scene.successor(s, *a) as u32;
                        if edges.contains(&(s as u32, t)) {
                            row[a.index()] = t;
                        }
                    }
                }
                row
            })
            .collect();
        let ids = scene.id_map();
        let mut visible_instances = vec![Vec::new(); n];
        for (id, at) in &raw.visible {
            // Absent: an unseen category removed from a training scene.
            let Some(&inst) = ids.get(id.as_str()) else {
                continue;
            };
            for &node in at {
                visible_instances[state_of_node[node as usize] as usize].push(inst as u16);
            }
        }
        for v in &mut visible_instances {
            v.sort_unstable();
            v.dedup();
        }
        Ok(OfflineScene {
            dir: raw.dir,
            skipped_nodes: raw.skipped_nodes,
            keys,
            next,
            visible_instances,
            features: raw.features,
            att: raw.att,
        })
    }

    /// The state key of state `state`, `None` if the state is not a node of the graph.
    pub fn key(&self, state: usize) -> Option<&str> {
        self.keys.get(state).and_then(|k| k.as_deref())
    }

    /// True if state `state` is a node of the graph.
    pub fn has_state(&self, state: usize) -> bool {
        self.key(state).is_some()
    }

    /// Successor table derived from the graph (`[state][action]`, see the module docs).
    pub fn next_table(&self) -> &[[u32; NUM_ACTIONS]] {
        &self.next
    }

    /// The full 512x7x7 ResNet18 map of state `state`, read from the feature file: 512 x 49
    /// values, channel-major as stored (`map[c * 49 + row * 7 + col]`).
    pub fn feature_map(&self, state: usize) -> Result<Vec<f32>> {
        let key = self.key(state).ok_or_else(|| {
            anyhow!(
                "{}: state {state} is not a node of {}",
                self.dir.display(),
                GRAPH_FILE
            )
        })?;
        let v = self.features.read(key)?;
        if v.len() != MAP_LEN {
            bail!(
                "{}: dataset {key:?} has {} values, expected {MAP_LEN}",
                self.features.path().display(),
                v.len()
            );
        }
        check_values(self.features.path(), key, &v)?;
        Ok(v)
    }

    /// Builds the scene's tables: pooled features, PS targets, visibility (see the module docs).
    pub(crate) fn build_tables(
        &self,
        scene: &Scene,
        categories: &[Category],
    ) -> Result<SceneTables> {
        let n = scene.num_states();
        let mut obs = Vec::with_capacity(n);
        for s in 0..n {
            let Some(key) = self.key(s) else {
                obs.push(Observation {
                    features: [0.0; FEATURE_DIM],
                    ps_target: [0.0; ATTR_DIM],
                    visible: Vec::new(),
                    in_view: Vec::new(),
                });
                continue;
            };
            let features = global_pool(&self.feature_map(s)?);
            let st = scene.state(s);
            let (px, pz) = (st.x as f32 * GRID, st.z as f32 * GRID);
            let mut in_view: Vec<InView> = self.visible_instances[s]
                .iter()
                .map(|&i| {
                    let o = &scene.objects[i as usize];
                    let props = &categories[o.category as usize].props;
                    let a = appearance(px, pz, st.heading, st.horizon, o.pos, props);
                    InView {
                        instance: i,
                        category: o.category,
                        weight: a.weight.max(IN_VIEW_MIN_WEIGHT),
                    }
                })
                .collect();
            in_view.sort_by(|a, b| b.weight.total_cmp(&a.weight));
            let mut visible: Vec<CategoryId> = in_view.iter().map(|v| v.category).collect();
            visible.sort_unstable();
            visible.dedup();
            let mut ps_target = [0f32; ATTR_DIM];
            match &self.att {
                Some(f) => {
                    let v = f.read(key)?;
                    if v.len() != ATTR_DIM {
                        bail!(
                            "{}: dataset {key:?} has {} values, expected {ATTR_DIM}",
                            f.path().display(),
                            v.len()
                        );
                    }
                    check_values(f.path(), key, &v)?;
                    ps_target.copy_from_slice(&v);
                }
                None if !visible.is_empty() => {
                    for &c in &visible {
                        for (t, a) in ps_target.iter_mut().zip(&categories[c as usize].attributes) {
                            *t += a;
                        }
                    }
                    let k = visible.len() as f32;
                    ps_target.iter_mut().for_each(|t| *t /= k);
                }
                None => {}
            }
            obs.push(Observation {
                features,
                ps_target,
                visible,
                in_view,
            });
        }
        Ok(SceneTables::from_parts(
            self.next.clone(),
            obs,
            self.visible_instances.clone(),
        ))
    }
}

/// Largest magnitude accepted in a feature map or PS-target dataset. ResNet18 activations
/// and attribute means are far below it; a larger value (3e38, an overflow or garbage) would
/// overflow the pooling's sums and every network input downstream.
pub const MAX_VALUE: f32 = 1e6;

/// Refuses a non-finite value or one beyond [`MAX_VALUE`] in dataset `key` of `path`,
/// naming the file, the key and the first bad value's index.
pub fn check_values(path: &Path, key: &str, v: &[f32]) -> Result<()> {
    if let Some((i, x)) = v
        .iter()
        .enumerate()
        .find(|(_, x)| !(x.is_finite() && x.abs() <= MAX_VALUE))
    {
        bail!(
            "{}: dataset {key:?} holds {x:e} at index {i} (of {}); values must be finite and at most {MAX_VALUE:e} in magnitude",
            path.display(),
            v.len()
        );
    }
    Ok(())
}

/// The pooled embedding s_t of a 512 x 49 channel-major map: each channel's average over its
/// 49 cells (f32 sum in cell order, divided by 49; [`crate::spatial::pool_map`] pools the same
/// map to a grid).
pub fn global_pool(map: &[f32]) -> [f32; FEATURE_DIM] {
    let mut out = [0f32; FEATURE_DIM];
    for (o, ch) in out.iter_mut().zip(map.chunks_exact(MAP_CELLS)) {
        *o = ch.iter().sum::<f32>() / MAP_CELLS as f32;
    }
    out
}

/// Indexes every raw scene by its built scene (same order).
pub(crate) fn index_scenes(
    raw: Vec<RawOfflineScene>,
    scenes: &[Scene],
) -> Result<Vec<Option<OfflineScene>>> {
    raw.into_iter()
        .zip(scenes)
        .map(|(r, s)| OfflineScene::index(r, s).map(Some))
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn keys_parse_and_print() {
        let s = parse_state_key("1.25|-0.50|135|0").unwrap().unwrap();
        assert_eq!(
            s,
            AgentState {
                x: 5,
                z: -2,
                heading: 3,
                horizon: 0
            }
        );
        assert_eq!(state_key(s), "1.25|-0.50|135|0");
        let t = parse_state_key("0.00|0.75|315.0|30").unwrap().unwrap();
        assert_eq!((t.heading, t.horizon), (7, 1));
        assert_eq!(state_key(t), "0.00|0.75|315|30");
        assert!(parse_state_key("0.00|0.00|0|60").unwrap().is_none());
        for bad in ["1.25|0.50|90", "a|0|0|0", "0.13|0.00|0|0", "0.00|0.00|30|0"] {
            assert!(parse_state_key(bad).is_err(), "{bad}");
        }
    }

    #[test]
    fn object_ids_and_splits() {
        let (t, p) = parse_object_id("Bathtub|-03.50|+00.15|+00.94").unwrap();
        assert_eq!((t.as_str(), p), ("Bathtub", [-3.5, 0.15, 0.94]));
        let (t, _) = parse_object_id("Sink|-01.90|+00.97|-01.50|SinkBasin").unwrap();
        assert_eq!(t, "SinkBasin");
        assert!(parse_object_id("Mug|1|2").is_err());
        assert_eq!(
            scene_room_split("FloorPlan7").unwrap(),
            (RoomType::Kitchen, Split::Train)
        );
        assert_eq!(
            scene_room_split("FloorPlan224").unwrap(),
            (RoomType::LivingRoom, Split::Val)
        );
        assert_eq!(
            scene_room_split("FloorPlan429").unwrap(),
            (RoomType::Bathroom, Split::Test)
        );
        assert!(scene_room_split("FloorPlan31").is_err());
        assert!(scene_room_split("FloorPlan_x").is_err());
    }

    /// Without the `offline` feature an offline directory is recognised and the error says
    /// how to build with HDF5 support.
    #[cfg(not(feature = "offline"))]
    #[test]
    fn without_the_feature_loading_says_how_to_get_it() {
        let d = std::env::temp_dir().join(format!("gman-offline-nofeature-{}", std::process::id()));
        let _ = fs::remove_dir_all(&d);
        let sd = d.join("FloorPlan1");
        fs::create_dir_all(&sd).unwrap();
        let attrs = serde_json::json!({
            "dim": ATTR_DIM,
            "categories": {"Fridge": vec![0.5f32; ATTR_DIM]},
            "split": {
                "train_targets_by_room": {
                    "kitchen": ["Fridge"], "living_room": [], "bedroom": [], "bathroom": []
                },
                "seen": ["Fridge"],
                "unseen": []
            }
        });
        fs::write(d.join("attributes.json"), attrs.to_string()).unwrap();
        fs::write(sd.join(GRID_FILE), r#"[{"x": 0.0, "y": 0.9, "z": 0.0}]"#).unwrap();
        fs::write(
            sd.join(GRAPH_FILE),
            r#"{"directed": true, "nodes": [{"id": "0.00|0.00|0|0"}], "links": []}"#,
        )
        .unwrap();
        fs::write(sd.join(VISIBLE_FILE), "{}").unwrap();
        fs::write(sd.join(FEATURE_FILE), b"not read").unwrap();
        assert!(is_offline_dir(&d));
        let e = format!("{:#}", crate::World::load(&d).unwrap_err());
        assert!(
            e.contains("--features offline") && e.contains(FEATURE_FILE),
            "{e}"
        );
        let _ = fs::remove_dir_all(&d);
    }

    #[test]
    fn pooling_is_the_cell_mean() {
        let map: Vec<f32> = (0..MAP_LEN).map(|i| (i % 97) as f32).collect();
        let p = global_pool(&map);
        for c in [0, 7, 511] {
            let want: f32 = map[c * 49..(c + 1) * 49].iter().sum::<f32>() / 49.0;
            assert_eq!(p[c], want);
        }
    }
}
