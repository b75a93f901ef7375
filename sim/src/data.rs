//! Raw data files of the GMAN benchmark directory (`attributes.json`, `scenes/<split>/*.json`,
//! `episodes/<split>/*.jsonl`, the optional sidecar `objects_thor5/FloorPlanN.json`), parsed
//! with serde. Every error names the offending file.
//!
//! These are the files' contents as written; [`crate::world::World`] turns them into
//! simulator scenes and episodes.

use std::collections::BTreeMap;
use std::fs;
use std::path::{Path, PathBuf};

use anyhow::{bail, Context, Result};
use gman_core::ATTR_DIM;
use serde::Deserialize;

use super::types::{ObjectLayout, RoomType, Split, TargetKind};

/// Contents of `attributes.json`.
#[derive(Clone, Debug, Deserialize)]
pub struct RawAttributes {
    /// Width of every attribute vector (must equal [`ATTR_DIM`]).
    pub dim: usize,
    /// Attribute vector of every object category, by AI2THOR category name.
    pub categories: BTreeMap<String, Vec<f32>>,
    /// The official category split.
    pub split: RawSplit,
}

/// The `split` object of `attributes.json`.
#[derive(Clone, Debug, Deserialize)]
pub struct RawSplit {
    /// Training targets per room type (room name -> categories).
    pub train_targets_by_room: BTreeMap<String, Vec<String>>,
    /// Seen target categories of the val/test episodes.
    pub seen: Vec<String>,
    /// Unseen target categories; never present in training scenes.
    pub unseen: Vec<String>,
    /// Evaluation targets per room type and kind.
    #[serde(default)]
    pub by_room: BTreeMap<String, RawRoomTargets>,
}

/// Evaluation targets of one room type.
#[derive(Clone, Debug, Default, Deserialize)]
pub struct RawRoomTargets {
    /// Seen targets.
    #[serde(default)]
    pub seen: Vec<String>,
    /// Unseen targets.
    #[serde(default)]
    pub unseen: Vec<String>,
}

/// One object instance with a real position.
#[derive(Clone, Debug, Deserialize)]
pub struct RawObject {
    /// AI2THOR object id `Type|x|y|z`.
    pub id: String,
    /// Category name.
    #[serde(rename = "type")]
    pub category: String,
    /// Position x (metres).
    pub x: f32,
    /// Height (metres).
    pub y: f32,
    /// Position z (metres).
    pub z: f32,
}

/// Contents of one `scenes/<split>/FloorPlanN.json`.
#[derive(Clone, Debug, Deserialize)]
pub struct RawScene {
    /// Floor plan name, e.g. `FloorPlan22`.
    pub scene: String,
    /// Room type name.
    pub room: String,
    /// Grid step in metres (0.25).
    pub grid_size: f32,
    /// Reachable positions `[x, z]`.
    pub reachable: Vec<[f32; 2]>,
    /// Extra reachable positions (val: every episode start).
    #[serde(default)]
    pub reachable_sample: Vec<[f32; 2]>,
    /// Categories present in the scene.
    pub object_types: Vec<String>,
    /// Instances with real positions (openable objects).
    #[serde(default)]
    pub known_objects: Vec<RawObject>,
    /// Goal instances of the official episodes (val/test only).
    #[serde(default)]
    pub objects: Vec<RawObject>,
}

/// Start pose of an official episode.
#[derive(Clone, Debug, Deserialize)]
pub struct RawStart {
    /// x (metres).
    pub x: f32,
    /// Agent height (unused).
    #[serde(default)]
    pub y: f32,
    /// z (metres).
    pub z: f32,
    /// Heading in degrees (multiple of 45).
    pub rotation: f32,
    /// Camera horizon in degrees (0 or 30).
    pub horizon: f32,
}

/// One line of `episodes/<split>/<room>_<kind>.jsonl`.
#[derive(Clone, Debug, Deserialize)]
pub struct RawEpisode {
    /// Floor plan name.
    pub scene: String,
    /// Room type name.
    pub room: String,
    /// The split the episode belongs to (`val`, `test`; absent: the split of its directory).
    #[serde(default)]
    pub split: Option<String>,
    /// `seen` or `unseen`.
    pub target_kind: String,
    /// Target category name.
    pub target: String,
    /// AI2THOR ids of the goal instances named by the episode.
    pub target_ids: Vec<String>,
    /// Start pose.
    pub start: RawStart,
}

fn read_text(path: &Path) -> Result<String> {
    fs::read_to_string(path).with_context(|| format!("cannot read {}", path.display()))
}

/// Reads and checks `DIR/attributes.json`.
pub fn load_attributes(dir: &Path) -> Result<RawAttributes> {
    let path = dir.join("attributes.json");
    if !dir.is_dir() {
        bail!("data directory {} does not exist", dir.display());
    }
    let text = read_text(&path)?;
    let raw: RawAttributes = serde_json::from_str(&text)
        .with_context(|| format!("malformed JSON in {}", path.display()))?;
    if raw.dim != ATTR_DIM {
        bail!(
            "{}: dim is {}, expected {ATTR_DIM}",
            path.display(),
            raw.dim
        );
    }
    for (name, v) in &raw.categories {
        if v.len() != ATTR_DIM {
            bail!(
                "{}: category {name} has {} attributes, expected {ATTR_DIM}",
                path.display(),
                v.len()
            );
        }
        if let Some((i, x)) = v
            .iter()
            .enumerate()
            .find(|(_, x)| !(x.is_finite() && (0.0..=1.0).contains(*x)))
        {
            bail!(
                "{}: category {name}: attribute {i} is {x}; attribute values must lie in [0, 1]",
                path.display()
            );
        }
    }
    Ok(raw)
}

/// A content fingerprint of a data directory's world: 64-bit FNV-1a over `attributes.json`
/// and every `scenes/<split>/*.json` (names and bytes, in sorted order), as 16 hex digits.
/// Training stores it in its checkpoints so that `--resume` refuses other data. This is the
/// fingerprint of the `rule` layout ([`fingerprint_for`]).
pub fn fingerprint(dir: &Path) -> Result<String> {
    fingerprint_for(dir, ObjectLayout::Rule)
}

/// [`fingerprint`] of the world built with `layout`: under [`ObjectLayout::Thor5`] the
/// `objects_thor5/*.json` files are covered too; under [`ObjectLayout::Rule`] they are not (a
/// run trained before the sidecar existed resumes on the same data).
pub fn fingerprint_for(dir: &Path, layout: ObjectLayout) -> Result<String> {
    let json_in = |d: &Path| -> Vec<PathBuf> {
        fs::read_dir(d)
            .map(|rd| {
                rd.filter_map(|e| e.ok().map(|e| e.path()))
                    .filter(|p| p.extension().is_some_and(|e| e == "json"))
                    .collect()
            })
            .unwrap_or_default()
    };
    let mut files = vec![dir.join("attributes.json")];
    let mut scenes = Vec::new();
    for split in Split::ALL {
        scenes.extend(json_in(&scenes_dir(dir, split)));
    }
    scenes.sort();
    files.extend(scenes);
    if layout == ObjectLayout::Thor5 {
        let mut side = json_in(&thor5_dir(dir));
        side.sort();
        files.extend(side);
    }
    let mut h = super::util::Fnv::new();
    for f in &files {
        let rel = f.strip_prefix(dir).unwrap_or(f);
        h.eat(rel.to_string_lossy().as_bytes());
        h.eat(&[0]);
        h.eat(&fs::read(f).with_context(|| format!("cannot read {}", f.display()))?);
        h.eat(&[0]);
    }
    Ok(h.hex())
}

/// Largest coordinate (metres, absolute) accepted in a scene file; iTHOR rooms span a few
/// metres (the official files stay within 15 m).
pub const MAX_COORD: f32 = 1000.0;

/// Directory `DIR/scenes/<split>`.
pub fn scenes_dir(dir: &Path, split: Split) -> PathBuf {
    dir.join("scenes").join(split.name())
}

/// Directory `DIR/objects_thor5` (the AI2-THOR 5.0 object sidecar).
pub fn thor5_dir(dir: &Path) -> PathBuf {
    dir.join(THOR5_DIR)
}

/// Name of the sidecar directory of AI2-THOR 5.0 objects.
pub const THOR5_DIR: &str = "objects_thor5";

/// Directory `DIR/episodes/<split>`.
pub fn episodes_dir(dir: &Path, split: Split) -> PathBuf {
    dir.join("episodes").join(split.name())
}

/// Reads every `*.json` of `DIR/scenes/<split>`, sorted by file name. Errors if the directory
/// is missing or holds no scene.
pub fn load_scenes(dir: &Path, split: Split) -> Result<Vec<RawScene>> {
    let sdir = scenes_dir(dir, split);
    if !sdir.is_dir() {
        bail!(
            "split {}: scene directory {} does not exist (expected layout: attributes.json, scenes/<split>/, episodes/<split>/)",
            split.name(),
            sdir.display()
        );
    }
    let mut files: Vec<PathBuf> = fs::read_dir(&sdir)
        .with_context(|| format!("cannot list {}", sdir.display()))?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.extension().is_some_and(|e| e == "json"))
        .collect();
    files.sort();
    if files.is_empty() {
        bail!(
            "split {}: no scene files (*.json) in {}",
            split.name(),
            sdir.display()
        );
    }
    files
        .iter()
        .map(|p| {
            let text = read_text(p)?;
            let s: RawScene = serde_json::from_str(&text)
                .with_context(|| format!("malformed scene JSON in {}", p.display()))?;
            if s.grid_size.is_nan() || s.grid_size <= 0.0 {
                bail!("{}: grid_size must be positive", p.display());
            }
            if s.reachable.is_empty() && s.reachable_sample.is_empty() {
                bail!("{}: scene has no reachable positions", p.display());
            }
            let sane = |v: f32| v.is_finite() && v.abs() <= MAX_COORD;
            if let Some(q) = s
                .reachable
                .iter()
                .chain(&s.reachable_sample)
                .find(|q| !(sane(q[0]) && sane(q[1])))
            {
                bail!(
                    "{}: reachable position [{}, {}] is not a finite coordinate within {MAX_COORD} m",
                    p.display(),
                    q[0],
                    q[1]
                );
            }
            if let Some(o) = s
                .objects
                .iter()
                .chain(&s.known_objects)
                .find(|o| !(sane(o.x) && sane(o.y) && sane(o.z)))
            {
                bail!(
                    "{}: object {} is at ({}, {}, {}); coordinates must be finite and within {MAX_COORD} m",
                    p.display(),
                    o.id,
                    o.x,
                    o.y,
                    o.z
                );
            }
            Ok(s)
        })
        .collect()
}

/// One parsed episode line with the file and line it came from.
#[derive(Clone, Debug)]
pub struct RawEpisodeLine {
    /// The episode.
    pub episode: RawEpisode,
    /// File it was read from.
    pub file: PathBuf,
    /// 1-based line number.
    pub line: usize,
}

/// Reads every `*.jsonl` of `DIR/episodes/<split>` in sorted file order, keeping at most
/// `per_file` episodes of each file (in file order). With `every_room`, the benchmark's
/// eight files (each room type, seen and unseen) must all be there; without it (offline
/// data, which may cover fewer room types), only the rooms present.
pub fn load_raw_episodes(
    dir: &Path,
    split: Split,
    per_file: Option<usize>,
    every_room: bool,
) -> Result<Vec<RawEpisodeLine>> {
    let edir = episodes_dir(dir, split);
    if !edir.is_dir() {
        bail!(
            "split {}: episode directory {} does not exist",
            split.name(),
            edir.display()
        );
    }
    let mut files: Vec<PathBuf> = fs::read_dir(&edir)
        .with_context(|| format!("cannot list {}", edir.display()))?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.extension().is_some_and(|e| e == "jsonl"))
        .collect();
    files.sort();
    if files.is_empty() {
        bail!(
            "split {}: no episode files (*.jsonl) in {}",
            split.name(),
            edir.display()
        );
    }
    // The benchmark layout: one `<room>_<kind>.jsonl` per room type and target kind, no other
    // file (an unknown one would be merged into the totals, a missing one would leave a row of
    // zeros over 0 episodes).
    let expected: Vec<String> = RoomType::ALL
        .iter()
        .flat_map(|r| {
            [TargetKind::Seen, TargetKind::Unseen]
                .map(|k| format!("{}_{}.jsonl", r.name(), k.name()))
        })
        .collect();
    for p in &files {
        let name = p.file_name().map(|n| n.to_string_lossy().into_owned());
        if !name.as_ref().is_some_and(|n| expected.contains(n)) {
            bail!(
                "{}: not an episode file of the benchmark layout (expected <room>_<seen|unseen>.jsonl with room kitchen, living_room, bedroom or bathroom)",
                p.display()
            );
        }
    }
    for e in &expected {
        if !every_room {
            continue;
        }
        if !edir.join(e).is_file() {
            bail!(
                "split {}: episode file {} is missing (every room type needs a seen and an unseen file)",
                split.name(),
                edir.join(e).display()
            );
        }
    }
    let mut out = Vec::new();
    for p in files {
        let text = read_text(&p)?;
        if text.lines().all(|l| l.trim().is_empty()) {
            bail!("{}: episode file holds no episode", p.display());
        }
        let mut n = 0usize;
        for (i, line) in text.lines().enumerate() {
            if line.trim().is_empty() {
                continue;
            }
            if per_file.is_some_and(|m| n >= m) {
                break;
            }
            let episode: RawEpisode = serde_json::from_str(line).with_context(|| {
                format!("malformed episode JSON in {} line {}", p.display(), i + 1)
            })?;
            out.push(RawEpisodeLine {
                episode,
                file: p.clone(),
                line: i + 1,
            });
            n += 1;
        }
    }
    Ok(out)
}

/// One object of an `objects_thor5/FloorPlanN.json` file (AI2-THOR 5.0 default scene state).
#[derive(Clone, Debug, Deserialize)]
pub struct RawThor5Object {
    /// AI2-THOR 5.0 object type (every type, not only the 40 categories).
    #[serde(rename = "type")]
    pub object_type: String,
    /// AI2-THOR 5.0 object id `Type|+x.xx|+y.yy|+z.zz`.
    pub id: String,
    /// Position x (metres).
    pub x: f32,
    /// Position y, height (metres).
    pub y: f32,
    /// Position z (metres).
    pub z: f32,
    /// Centre of the axis-aligned bounding box (x, y, z, metres).
    pub aabb_center: [f32; 3],
    /// Size of the axis-aligned bounding box (x, y, z, metres; non-negative).
    pub aabb_size: [f32; 3],
    /// The receptacle the object rests on, if any.
    #[serde(default)]
    pub parent: Option<String>,
}

/// Contents of one `objects_thor5/FloorPlanN.json`.
#[derive(Clone, Debug, Deserialize)]
pub struct RawThor5Scene {
    /// Floor plan name; must match the file name.
    pub scene: String,
    /// Every object of the scene.
    pub objects: Vec<RawThor5Object>,
}

/// Largest box edge (metres) accepted in a sidecar file (iTHOR's largest objects, floors and
/// walls, span a few metres).
pub const MAX_BOX_SIZE: f32 = 100.0;

/// Reads and checks `DIR/objects_thor5/<scene>.json`. Errors name the file and, for a bad
/// value, the object and key; a missing file is an error (the directory exists, so every
/// scene needs its file).
pub fn load_thor5_scene(dir: &Path, scene: &str) -> Result<RawThor5Scene> {
    let path = thor5_dir(dir).join(format!("{scene}.json"));
    if !path.is_file() {
        bail!(
            "{}: missing: the object layout thor5 needs one AI2-THOR 5.0 object file per scene \
             (scene {scene} has none in {}); add it, or use --object-layout rule",
            path.display(),
            thor5_dir(dir).display()
        );
    }
    let text = read_text(&path)?;
    let raw: RawThor5Scene = serde_json::from_str(&text)
        .with_context(|| format!("malformed AI2-THOR 5.0 object JSON in {}", path.display()))?;
    if raw.scene != scene {
        bail!(
            "{}: key scene is {:?}, expected {scene:?} (the file's name)",
            path.display(),
            raw.scene
        );
    }
    let sane = |v: f32| v.is_finite() && v.abs() <= MAX_COORD;
    for (i, o) in raw.objects.iter().enumerate() {
        let at = || format!("{}: objects[{i}] ({})", path.display(), o.id);
        if o.object_type.is_empty() {
            bail!("{}: key type is empty", at());
        }
        for (key, v) in [("x", o.x), ("y", o.y), ("z", o.z)] {
            if !sane(v) {
                bail!(
                    "{}: key {key} is {v}; coordinates must be finite and within {MAX_COORD} m",
                    at()
                );
            }
        }
        for (k, &v) in o.aabb_center.iter().enumerate() {
            if !sane(v) {
                bail!(
                    "{}: key aabb_center[{k}] is {v}; coordinates must be finite and within {MAX_COORD} m",
                    at()
                );
            }
        }
        for (k, &v) in o.aabb_size.iter().enumerate() {
            if !(v.is_finite() && (0.0..=MAX_BOX_SIZE).contains(&v)) {
                bail!(
                    "{}: key aabb_size[{k}] is {v}; box sizes must be finite, non-negative and at most {MAX_BOX_SIZE} m",
                    at()
                );
            }
        }
    }
    Ok(raw)
}
