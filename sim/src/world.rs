//! The navigation world: categories with attribute vectors, the seen/unseen split, scenes per
//! split, lazily built state tables, official episodes and the training task sampler.

use std::collections::{BTreeMap, HashMap};
use std::path::{Path, PathBuf};
use std::sync::OnceLock;

use anyhow::{anyhow, bail, Context, Result};
use gman_core::{ATTR_DIM, FEATURE_DIM};
use rand::Rng;

use super::catalog::props_of;
use super::data;
use super::features::{DomainShift, FeatureModel, SceneStyle};
use super::offline::{self, OfflineScene};
use super::scene::{thor5_category_name, Scene, SceneSource, Thor5Object};
use super::tables::{GoalTable, Observation, SceneTables, UNREACHABLE};
use super::types::{
    AgentState, Category, CategoryId, ObjectLayout, RoomType, SceneId, Split, TargetKind,
    NUM_HEADINGS, STATES_PER_POSITION,
};
use super::util::{hash2, hash_str};

/// Seed of the world (placement of unknown objects, feature model, scene styles) unless given.
pub const DEFAULT_WORLD_SEED: u64 = 2022;

/// One navigation task: a scene, a start state and a target category.
#[derive(Clone, Debug, PartialEq)]
pub struct EpisodeSpec {
    /// Position in the episode list it came from (official episodes: file order).
    pub index: usize,
    /// Scene.
    pub scene: SceneId,
    /// Room type of the scene.
    pub room: RoomType,
    /// Seen or unseen target (training episodes: seen).
    pub kind: TargetKind,
    /// Target category. Goal instances are all its instances in the scene.
    pub target: CategoryId,
    /// AI2THOR ids named by the official episode (empty for sampled episodes).
    pub target_ids: Vec<String>,
    /// Start state.
    pub start: AgentState,
    /// Per-episode seed (for agents that need randomness).
    pub seed: u64,
}

/// Where a world came from.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum WorldSource {
    /// A data directory with the GMAN/iTHOR layout.
    Data(PathBuf),
    /// A data directory with the AI2THOR offline scene folders of SAVN/GMAN
    /// ([`crate::offline`]).
    Offline(PathBuf),
    /// The built-in procedurally generated demo world.
    Synthetic,
}

/// A view of a scene where one object dominates (for feature collection).
#[derive(Clone, Debug)]
pub struct DominantView {
    /// State index of the view.
    pub state: usize,
    /// Agent state of the view.
    pub agent: AgentState,
    /// Instance index in the scene.
    pub instance: usize,
    /// Share of the view's embedding that comes from the instance (after the objects' total
    /// share is capped at 0.95), in [0, 0.95].
    pub weight: f32,
    /// The view's features.
    pub features: [f32; FEATURE_DIM],
}

/// Share of an observation's embedding contributed by an object of weight `w`.
pub fn view_share(obs: &Observation, w: f32) -> f32 {
    let total: f32 = obs.in_view.iter().map(|v| v.weight).sum();
    let cap = super::features::MAX_OBJECT_SHARE;
    if total > cap {
        w * cap / total
    } else {
        w
    }
}

/// Categories, splits, scenes, cached state tables and episodes.
pub struct World {
    /// Where the world came from.
    pub source: WorldSource,
    /// World seed.
    pub seed: u64,
    /// Object layout of the JSON floor plans (`rule` for the synthetic world and offline data).
    pub layout: ObjectLayout,
    /// All categories (AI2THOR order of `attributes.json`).
    pub categories: Vec<Category>,
    /// Seen evaluation targets.
    pub seen: Vec<CategoryId>,
    /// Unseen categories (never in training scenes).
    pub unseen: Vec<CategoryId>,
    /// Training targets per room type (index [`RoomType::index`]).
    pub train_targets: [Vec<CategoryId>; 4],
    /// Evaluation targets per room type: (seen, unseen).
    pub eval_targets: [(Vec<CategoryId>, Vec<CategoryId>); 4],
    /// All scenes of all loaded splits.
    pub scenes: Vec<Scene>,
    split_scenes: BTreeMap<Split, Vec<SceneId>>,
    scene_by_name: HashMap<String, SceneId>,
    model: FeatureModel,
    domain_shift: DomainShift,
    styles: Vec<SceneStyle>,
    tables: Vec<OnceLock<SceneTables>>,
    goals: Vec<Vec<OnceLock<GoalTable>>>,
    generated_episodes: BTreeMap<Split, Vec<EpisodeSpec>>,
    /// Per scene: its offline data, `None` for simulated scenes.
    offline: Vec<Option<OfflineScene>>,
}

impl std::fmt::Debug for World {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("World")
            .field("source", &self.source)
            .field("seed", &self.seed)
            .field("categories", &self.categories.len())
            .field("scenes", &self.scenes.len())
            .finish()
    }
}

/// Everything needed to assemble a world (used by the loader and the synthetic generator).
pub(crate) struct WorldParts {
    pub source: WorldSource,
    pub seed: u64,
    pub layout: ObjectLayout,
    pub categories: Vec<Category>,
    pub seen: Vec<CategoryId>,
    pub unseen: Vec<CategoryId>,
    pub train_targets: [Vec<CategoryId>; 4],
    pub eval_targets: [(Vec<CategoryId>, Vec<CategoryId>); 4],
    pub scenes: Vec<SceneSource>,
}

/// The start state of an episode (on the grid, a multiple of 45 degrees, horizon 0 or 30).
fn start_state(at: &dyn Fn() -> String, start: &data::RawStart) -> Result<AgentState> {
    // The agent's height is not used, but a value no room has is a broken file.
    if !(start.y.is_finite() && start.y.abs() <= data::MAX_COORD) {
        bail!(
            "{}: start y = {} is not a height in a room (at most {} m)",
            at(),
            start.y,
            data::MAX_COORD
        );
    }
    for (axis, v) in [("x", start.x), ("z", start.z)] {
        let cells = v / super::geometry::GRID;
        if !v.is_finite() || (cells - cells.round()).abs() * super::geometry::GRID > 1e-3 {
            bail!(
                "{}: start {axis} = {v} is not on the {} m grid",
                at(),
                super::geometry::GRID
            );
        }
    }
    let rot = start.rotation.rem_euclid(360.0);
    if (rot / 45.0 - (rot / 45.0).round()).abs() > 1e-3 {
        bail!(
            "{}: start rotation {} is not a multiple of 45",
            at(),
            start.rotation
        );
    }
    let horizon = match start.horizon.round() as i32 {
        0 => 0,
        30 => 1,
        h => bail!("{}: start horizon {h} is not 0 or 30", at()),
    };
    Ok(AgentState {
        x: (start.x / super::geometry::GRID).round() as i32,
        z: (start.z / super::geometry::GRID).round() as i32,
        heading: ((rot / 45.0).round() as usize % NUM_HEADINGS) as u8,
        horizon,
    })
}

/// The categories of `attributes.json`, in file order.
fn categories_of(raw: &data::RawAttributes) -> Vec<Category> {
    let unseen_names: Vec<&String> = raw.split.unseen.iter().collect();
    raw.categories
        .iter()
        .map(|(name, v)| {
            let mut attributes = [0f32; ATTR_DIM];
            attributes.copy_from_slice(v);
            Category {
                name: name.clone(),
                attributes,
                unseen: unseen_names.contains(&name),
                props: props_of(name),
            }
        })
        .collect()
}

/// The split of `attributes.json` as category ids.
struct SplitTargets {
    seen: Vec<CategoryId>,
    unseen: Vec<CategoryId>,
    train: [Vec<CategoryId>; 4],
    eval: [(Vec<CategoryId>, Vec<CategoryId>); 4],
}

impl SplitTargets {
    /// Resolves every name of `split` (an error naming `attr_path` for an unknown one).
    fn resolve(
        split: &data::RawSplit,
        by_name: &HashMap<&str, CategoryId>,
        attr_path: &Path,
    ) -> Result<Self> {
        let resolve = |names: &[String], what: &str| -> Result<Vec<CategoryId>> {
            names
                .iter()
                .map(|n| {
                    by_name.get(n.as_str()).copied().ok_or_else(|| {
                        anyhow!(
                            "{}: {what} names unknown category {n:?}",
                            attr_path.display()
                        )
                    })
                })
                .collect()
        };
        let seen = resolve(&split.seen, "split.seen")?;
        let unseen = resolve(&split.unseen, "split.unseen")?;
        let mut train: [Vec<CategoryId>; 4] = Default::default();
        let mut eval: [(Vec<CategoryId>, Vec<CategoryId>); 4] = Default::default();
        for room in RoomType::ALL {
            let tt = split
                .train_targets_by_room
                .get(room.name())
                .ok_or_else(|| {
                    anyhow!(
                        "{}: split.train_targets_by_room has no {}",
                        attr_path.display(),
                        room.name()
                    )
                })?;
            train[room.index()] = resolve(tt, "split.train_targets_by_room")?;
            if let Some(r) = split.by_room.get(room.name()) {
                eval[room.index()] = (
                    resolve(&r.seen, "split.by_room")?,
                    resolve(&r.unseen, "split.by_room")?,
                );
            }
        }
        Ok(SplitTargets {
            seen,
            unseen,
            train,
            eval,
        })
    }
}

/// The AI2-THOR 5.0 objects of the 40 categories in `objects_thor5/<scene>.json` (other types
/// are ignored; `Stool` counts as `Chair`, see [`thor5_category_name`]).
fn thor5_objects(
    dir: &Path,
    scene: &str,
    by_name: &HashMap<&str, CategoryId>,
) -> Result<Vec<Thor5Object>> {
    let raw = data::load_thor5_scene(dir, scene)?;
    Ok(raw
        .objects
        .iter()
        .filter_map(|o| {
            by_name
                .get(thor5_category_name(&o.object_type))
                .map(|&c| Thor5Object {
                    id: o.id.clone(),
                    category: c,
                    pos: [o.x, o.y, o.z],
                    aabb: super::geometry::Aabb {
                        center: o.aabb_center,
                        size: o.aabb_size,
                    },
                })
        })
        .collect())
}

/// The layout `auto` chooses for a data directory: `thor5` when `DIR/objects_thor5/` exists
/// (and `DIR` is not AI2THOR offline data, whose objects come from its own files), else `rule`.
pub fn auto_layout(dir: &Path) -> ObjectLayout {
    if data::thor5_dir(dir).is_dir() && !offline::is_offline_dir(dir) {
        ObjectLayout::Thor5
    } else {
        ObjectLayout::Rule
    }
}

/// The scenes of `scenes/<split>/` (the JSON floor plans).
fn json_scenes(
    dir: &Path,
    split: Split,
    by_name: &HashMap<&str, CategoryId>,
    layout: ObjectLayout,
) -> Result<Vec<SceneSource>> {
    let mut scenes = Vec::new();
    for s in data::load_scenes(dir, split)? {
        let file = data::scenes_dir(dir, split).join(format!("{}.json", s.scene));
        let room = RoomType::parse(&s.room).with_context(|| format!("in {}", file.display()))?;
        let g = s.grid_size;
        let cell = |p: &[f32; 2]| ((p[0] / g).round() as i32, (p[1] / g).round() as i32);
        let reachable = s
            .reachable
            .iter()
            .chain(&s.reachable_sample)
            .map(cell)
            .collect();
        let mut present = Vec::new();
        for t in &s.object_types {
            match by_name.get(t.as_str()) {
                Some(&c) => present.push(c),
                None => bail!(
                    "{}: object_types names unknown category {t:?}",
                    file.display()
                ),
            }
        }
        let mut known = Vec::new();
        for o in s.objects.iter().chain(&s.known_objects) {
            let Some(&c) = by_name.get(o.category.as_str()) else {
                bail!(
                    "{}: object {} has unknown category {:?}",
                    file.display(),
                    o.id,
                    o.category
                )
            };
            known.push((o.id.clone(), c, [o.x, o.y, o.z]));
        }
        let thor5 = match layout {
            ObjectLayout::Rule => None,
            ObjectLayout::Thor5 => Some(thor5_objects(dir, &s.scene, by_name)?),
        };
        scenes.push(SceneSource {
            name: s.scene.clone(),
            room,
            split,
            reachable,
            present,
            known,
            exact: false,
            thor5,
        });
    }
    Ok(scenes)
}

impl World {
    /// Loads the real floor plans from a data directory (`attributes.json`, `scenes/<split>/`,
    /// `episodes/<split>/`) with [`DEFAULT_WORLD_SEED`] and the object layout [`auto_layout`]
    /// chooses. Every split directory present under `scenes/` is loaded; at least one must
    /// exist. A directory without `scenes/` but with `FloorPlanN/` folders is read as AI2THOR
    /// offline data ([`crate::offline`]).
    pub fn load(dir: &Path) -> Result<World> {
        World::load_with_seed(dir, DEFAULT_WORLD_SEED)
    }

    /// [`World::load`] with an explicit world seed.
    pub fn load_with_seed(dir: &Path, seed: u64) -> Result<World> {
        World::load_with_options(dir, seed, &offline::OfflineOptions::default())
    }

    /// [`World::load_with_seed`] with the choices of how an offline directory is read
    /// (ignored for a directory of `scenes/`).
    pub fn load_with_options(
        dir: &Path,
        seed: u64,
        offline_opts: &offline::OfflineOptions,
    ) -> Result<World> {
        World::load_with_layout(dir, seed, offline_opts, auto_layout(dir))
    }

    /// [`World::load_with_options`] with an explicit object layout of the JSON floor plans
    /// ([`ObjectLayout`]; offline data takes its objects from its own files and refuses
    /// `thor5`). `thor5` needs `DIR/objects_thor5/` with one file per scene.
    pub fn load_with_layout(
        dir: &Path,
        seed: u64,
        offline_opts: &offline::OfflineOptions,
        layout: ObjectLayout,
    ) -> Result<World> {
        if layout == ObjectLayout::Thor5 {
            let t5 = data::thor5_dir(dir);
            if offline::is_offline_dir(dir) {
                bail!(
                    "{}: AI2THOR offline data takes its objects from its own files; the object \
                     layout thor5 is for the JSON floor plans (use --object-layout rule or auto)",
                    dir.display()
                );
            }
            if !t5.is_dir() {
                bail!(
                    "object layout thor5: directory {} does not exist (it holds the AI2-THOR 5.0 \
                     objects, objects_thor5/FloorPlanN.json); use --object-layout rule",
                    t5.display()
                );
            }
        }
        let raw = data::load_attributes(dir)?;
        let attr_path = dir.join("attributes.json");
        let categories = categories_of(&raw);
        let by_name: HashMap<&str, CategoryId> = categories
            .iter()
            .enumerate()
            .map(|(i, c)| (c.name.as_str(), i as CategoryId))
            .collect();
        let targets = SplitTargets::resolve(&raw.split, &by_name, &attr_path)?;
        let is_offline = offline::is_offline_dir(dir);
        let offline_raw = if is_offline {
            offline::load_scenes(dir, &by_name, offline_opts)?
        } else {
            Vec::new()
        };
        let mut scenes: Vec<SceneSource> = offline_raw.iter().map(|r| r.source.clone()).collect();
        for split in Split::ALL {
            if data::scenes_dir(dir, split).is_dir() {
                scenes.extend(json_scenes(dir, split, &by_name, layout)?);
            }
        }
        if scenes.is_empty() {
            bail!(
                "{}: no scenes found (expected scenes/train, scenes/val or scenes/test, or \
                 offline scene folders FloorPlanN/)",
                dir.display()
            );
        }
        let parts = WorldParts {
            source: if is_offline {
                WorldSource::Offline(dir.to_path_buf())
            } else {
                WorldSource::Data(dir.to_path_buf())
            },
            seed,
            layout: if is_offline {
                ObjectLayout::Rule
            } else {
                layout
            },
            categories,
            seen: targets.seen,
            unseen: targets.unseen,
            train_targets: targets.train,
            eval_targets: targets.eval,
            scenes,
        };
        let mut world = World::assemble(parts, BTreeMap::new());
        if is_offline {
            world.offline = offline::index_scenes(offline_raw, &world.scenes)?;
        }
        Ok(world)
    }

    pub(crate) fn assemble(
        parts: WorldParts,
        generated_episodes: BTreeMap<Split, Vec<EpisodeSpec>>,
    ) -> World {
        let model = FeatureModel::new(&parts.categories, parts.seed);
        let scenes: Vec<Scene> = parts
            .scenes
            .into_iter()
            .map(|s| Scene::build(s, &parts.categories, parts.seed))
            .collect();
        let styles = scenes
            .iter()
            .map(|s| SceneStyle::new(&model, s.seed))
            .collect();
        let mut split_scenes: BTreeMap<Split, Vec<SceneId>> = BTreeMap::new();
        let mut scene_by_name = HashMap::new();
        for (i, s) in scenes.iter().enumerate() {
            split_scenes.entry(s.split).or_default().push(i);
            scene_by_name.insert(s.name.clone(), i);
        }
        let n = scenes.len();
        let nc = parts.categories.len();
        World {
            source: parts.source,
            seed: parts.seed,
            layout: parts.layout,
            categories: parts.categories,
            seen: parts.seen,
            unseen: parts.unseen,
            train_targets: parts.train_targets,
            eval_targets: parts.eval_targets,
            scenes,
            split_scenes,
            scene_by_name,
            model,
            domain_shift: DomainShift::DEFAULT,
            styles,
            tables: (0..n).map(|_| OnceLock::new()).collect(),
            goals: (0..n)
                .map(|_| (0..nc).map(|_| OnceLock::new()).collect())
                .collect(),
            generated_episodes,
            offline: (0..n).map(|_| None).collect(),
        }
    }

    /// The strength of the scene style (`--domain-shift`, [`DomainShift`]).
    pub fn domain_shift(&self) -> DomainShift {
        self.domain_shift
    }

    /// Rebuilds every scene's style at domain shift `shift` (and drops the feature tables
    /// built so far). The AI2THOR offline data's real features have no synthetic style: any
    /// level but the default is refused there.
    pub fn set_domain_shift(&mut self, shift: DomainShift) -> Result<()> {
        if shift == self.domain_shift {
            return Ok(());
        }
        if matches!(self.source, WorldSource::Offline(_)) {
            bail!(
                "--domain-shift {shift}: the AI2THOR offline data carries real ResNet features, which have no synthetic scene style to scale (only the default 1 applies)"
            );
        }
        self.styles = self
            .scenes
            .iter()
            .map(|s| SceneStyle::with_shift(&self.model, s.seed, shift))
            .collect();
        self.tables = (0..self.scenes.len()).map(|_| OnceLock::new()).collect();
        let nc = self.categories.len();
        self.goals = (0..self.scenes.len())
            .map(|_| (0..nc).map(|_| OnceLock::new()).collect())
            .collect();
        self.domain_shift = shift;
        Ok(())
    }

    pub(crate) fn set_generated_episodes(&mut self, split: Split, episodes: Vec<EpisodeSpec>) {
        self.generated_episodes.insert(split, episodes);
    }

    /// Scenes of a split; a clear error if the split was not loaded.
    pub fn split_scenes(&self, split: Split) -> Result<&[SceneId]> {
        match self.split_scenes.get(&split) {
            Some(v) => Ok(v),
            None => match &self.source {
                WorldSource::Data(dir) => bail!(
                    "split {split}: no scenes loaded; directory {} does not exist",
                    data::scenes_dir(dir, split).display()
                ),
                WorldSource::Synthetic => bail!(
                    "split {split} does not exist in the synthetic world (train and val only)"
                ),
                WorldSource::Offline(dir) => bail!(
                    "split {split}: none of the FloorPlanN/ folders in {} is a {split} scene",
                    dir.display()
                ),
            },
        }
    }

    /// Scene id by name.
    pub fn scene_id(&self, name: &str) -> Option<SceneId> {
        self.scene_by_name.get(name).copied()
    }

    /// Category id by name.
    pub fn category_id(&self, name: &str) -> Option<CategoryId> {
        self.categories
            .iter()
            .position(|c| c.name == name)
            .map(|i| i as CategoryId)
    }

    /// Name of a category.
    pub fn category_name(&self, c: CategoryId) -> &str {
        &self.categories[c as usize].name
    }

    /// Attribute vector SE(c).
    pub fn attributes(&self, c: CategoryId) -> &[f32; ATTR_DIM] {
        &self.categories[c as usize].attributes
    }

    /// The cached state tables of a scene (built on first use; thread-safe).
    pub fn tables(&self, scene: SceneId) -> &SceneTables {
        self.tables[scene].get_or_init(|| match &self.offline[scene] {
            // The files were checked when the world was loaded; a read error now means they
            // changed or broke since.
            Some(o) => o
                .build_tables(&self.scenes[scene], &self.categories)
                .unwrap_or_else(|e| panic!("offline scene {}: {e:#}", self.scenes[scene].name)),
            None => SceneTables::build(
                &self.scenes[scene],
                &self.categories,
                &self.model,
                &self.styles[scene],
            ),
        })
    }

    /// The state tables of a scene like [`World::tables`], built now if they are not yet:
    /// for an offline scene whose files fail to read or hold bad values (NaN, 3e38), an
    /// error that names the file and the dataset instead of a panic.
    pub fn try_tables(&self, scene: SceneId) -> Result<&SceneTables> {
        if let (None, Some(o)) = (self.tables[scene].get(), &self.offline[scene]) {
            let t = o
                .build_tables(&self.scenes[scene], &self.categories)
                .with_context(|| format!("offline scene {}", self.scenes[scene].name))?;
            let _ = self.tables[scene].set(t);
        }
        Ok(self.tables(scene))
    }

    /// Builds the tables of the offline scenes among `scenes` now ([`World::try_tables`]), so
    /// that a broken feature file stops a command before it runs, with the file named.
    /// Simulated scenes are left to be built on first use.
    pub fn prepare_scenes(&self, scenes: impl IntoIterator<Item = SceneId>) -> Result<()> {
        for s in scenes {
            if self.offline[s].is_some() {
                self.try_tables(s)?;
            }
        }
        Ok(())
    }

    /// [`World::prepare_scenes`] for every scene of `split`.
    pub fn prepare_split(&self, split: Split) -> Result<()> {
        let scenes: Vec<SceneId> = (0..self.scenes.len())
            .filter(|&s| self.scenes[s].split == split)
            .collect();
        self.prepare_scenes(scenes)
    }

    /// A warning for the episodes that cannot succeed because no state reachable from their
    /// start shows an instance of the target (in offline data, typically an object whose
    /// visibility list is empty), `None` when every episode can succeed. Counts those whose
    /// target no state of the scene shows at all separately.
    pub fn unsolvable_episodes_warning(&self, episodes: &[EpisodeSpec]) -> Result<Option<String>> {
        let (mut unsolvable, mut nowhere) = (0usize, 0usize);
        let mut first = None;
        for e in episodes {
            self.try_tables(e.scene)?;
            let Some(start) = self.scenes[e.scene].state_index(e.start) else {
                continue;
            };
            let goal = self.goal_table(e.scene, e.target);
            if goal.dist[start] != UNREACHABLE {
                continue;
            }
            unsolvable += 1;
            if goal.dist.iter().all(|&d| d == UNREACHABLE) {
                nowhere += 1;
            }
            first.get_or_insert(e);
        }
        let Some(e) = first else {
            return Ok(None);
        };
        let vis = match &self.offline[e.scene] {
            Some(o) => format!(
                " (offline data: check the visibility lists of its instances under {})",
                o.dir.display()
            ),
            None => String::new(),
        };
        Ok(Some(format!(
            "{unsolvable} of the {} episodes cannot succeed: no state reachable from the start shows the target ({nowhere} of them: no state of the scene shows it at all); first: episode {}, {} in {}{vis}",
            episodes.len(),
            e.index,
            self.category_name(e.target),
            self.scenes[e.scene].name
        )))
    }

    /// The offline data of a scene (`None` for simulated scenes).
    pub fn offline_scene(&self, scene: SceneId) -> Option<&OfflineScene> {
        self.offline[scene].as_ref()
    }

    /// The full 512x7x7 feature map of a state of an offline scene, 512 x 49 channel-major
    /// ([`OfflineScene::feature_map`]); an error for simulated scenes.
    pub fn feature_map(&self, scene: SceneId, state: usize) -> Result<Vec<f32>> {
        match &self.offline[scene] {
            Some(o) => o.feature_map(state),
            None => bail!(
                "scene {} is simulated: it has no stored feature maps",
                self.scenes[scene].name
            ),
        }
    }

    /// The cached goal table of (scene, target category) (built on first use).
    pub fn goal_table(&self, scene: SceneId, category: CategoryId) -> &GoalTable {
        self.goals[scene][category as usize].get_or_init(|| {
            self.tables(scene)
                .goal_table(&self.scenes[scene], &self.categories, category)
        })
    }

    /// The feature model (attribute -> appearance network).
    pub fn feature_model(&self) -> &FeatureModel {
        &self.model
    }

    /// The appearance style of a scene.
    pub fn scene_style(&self, scene: SceneId) -> &SceneStyle {
        &self.styles[scene]
    }

    /// Observation of a state of a scene.
    pub fn observation(&self, scene: SceneId, state: usize) -> &Observation {
        &self.tables(scene).obs[state]
    }

    /// The spatial map of a state (the view as `grid` sectors, see [`crate::spatial`])
    /// into `out` (`grid.len()` floats, cell-major). For offline data, the stored 512 x 7 x 7
    /// ResNet map average-pooled to the grid ([`crate::spatial::pool_map`]); a stored
    /// map that fails to read after loading panics with the file named, as the tables do.
    pub fn view_map(
        &self,
        scene: SceneId,
        state: usize,
        grid: crate::spatial::MapGrid,
        out: &mut [f32],
    ) {
        match &self.offline[scene] {
            Some(o) => crate::spatial::pool_map(
                &o.feature_map(state).unwrap_or_else(|e| panic!("{e:#}")),
                grid,
                out,
            ),
            None => crate::spatial::view_map(self, scene, state, grid, out),
        }
    }

    /// The ideal target feature of `category` in `scene`: its appearance rendered with the
    /// scene's style, what a view filled by the object looks like (minus noise). See
    /// [`crate::features`].
    pub fn object_feature(&self, scene: SceneId, category: CategoryId) -> [f32; FEATURE_DIM] {
        self.styles[scene].render(&self.model, self.model.category_code(category as usize))
    }

    /// Mean of [`World::object_feature`] over the training scenes: the "general representation
    /// of all seen environments" a generator learns without adaptation.
    pub fn generic_object_feature(&self, category: CategoryId) -> [f32; FEATURE_DIM] {
        let ids: Vec<SceneId> = self
            .split_scenes
            .get(&Split::Train)
            .cloned()
            .unwrap_or_else(|| (0..self.scenes.len()).collect());
        let mut out = [0f32; FEATURE_DIM];
        for &s in &ids {
            let f = self.object_feature(s, category);
            out.iter_mut().zip(f.iter()).for_each(|(o, v)| *o += v);
        }
        out.iter_mut().for_each(|o| *o /= ids.len().max(1) as f32);
        out
    }

    /// Views of `scene` where an instance of `category` is the largest object in view, at most
    /// `per_instance` per instance, largest share first (the paper's feature collection: several
    /// egocentric views per object).
    pub fn dominant_views(
        &self,
        scene: SceneId,
        category: CategoryId,
        per_instance: usize,
    ) -> Vec<DominantView> {
        let t = self.tables(scene);
        let sc = &self.scenes[scene];
        let mut out = Vec::new();
        for inst in sc.instances_of(category) {
            let mut views: Vec<(usize, f32)> = t
                .obs
                .iter()
                .enumerate()
                .filter_map(|(s, o)| match o.in_view.first() {
                    Some(v) if v.instance as usize == inst => Some((s, view_share(o, v.weight))),
                    _ => None,
                })
                .collect();
            views.sort_by(|a, b| b.1.total_cmp(&a.1).then(a.0.cmp(&b.0)));
            for (s, w) in views.into_iter().take(per_instance) {
                out.push(DominantView {
                    state: s,
                    agent: sc.state(s),
                    instance: inst,
                    weight: w,
                    features: t.obs[s].features,
                });
            }
        }
        out
    }

    /// Official (or, in the synthetic world, generated) episodes of a split, in file order,
    /// at most `per_file` per file (per room and kind in the synthetic world).
    pub fn episodes(&self, split: Split, per_file: Option<usize>) -> Result<Vec<EpisodeSpec>> {
        match &self.source {
            WorldSource::Synthetic => {
                let all = self.generated_episodes.get(&split).ok_or_else(|| {
                    anyhow!("split {split} has no episodes in the synthetic world (val only)")
                })?;
                let mut count: HashMap<(RoomType, TargetKind), usize> = HashMap::new();
                let mut out = Vec::new();
                for e in all {
                    let c = count.entry((e.room, e.kind)).or_default();
                    if *c < per_file.unwrap_or(usize::MAX) {
                        *c += 1;
                        let mut e = e.clone();
                        e.index = out.len();
                        out.push(e);
                    }
                }
                Ok(out)
            }
            WorldSource::Data(dir) | WorldSource::Offline(dir) => {
                self.split_scenes(split)?;
                let every_room = matches!(self.source, WorldSource::Data(_));
                let raw = data::load_raw_episodes(dir, split, per_file, every_room)?;
                raw.iter()
                    .enumerate()
                    .map(|(i, r)| self.resolve_episode(i, split, r))
                    .collect()
            }
        }
    }

    /// A warning for the lines of a split's episode files that repeat an earlier line of
    /// their file (the same episode, field for field), `None` when there are none (and in the
    /// synthetic world). The official val files have 247 such lines among their 8000; they
    /// are kept, as the reference benchmark evaluates every line, so each repeat counts again
    /// in the results. `per_file` as in [`World::episodes`].
    pub fn repeated_episodes_warning(
        &self,
        split: Split,
        per_file: Option<usize>,
    ) -> Result<Option<String>> {
        let (WorldSource::Data(dir) | WorldSource::Offline(dir)) = &self.source else {
            return Ok(None);
        };
        let every_room = matches!(self.source, WorldSource::Data(_));
        let raw = data::load_raw_episodes(dir, split, per_file, every_room)?;
        // (file, repeats, first repeat (line, earlier line)) in file order.
        let mut files: Vec<(&Path, usize, (usize, usize))> = Vec::new();
        let mut seen: HashMap<(&Path, String), usize> = HashMap::new();
        for r in &raw {
            // The parsed fields (f32 printed exactly), so that formatting does not matter.
            let key = (r.file.as_path(), format!("{:?}", r.episode));
            let Some(&first) = seen.get(&key) else {
                seen.insert(key, r.line);
                continue;
            };
            match files.last_mut() {
                Some(f) if f.0 == r.file.as_path() => f.1 += 1,
                _ => files.push((r.file.as_path(), 1, (r.line, first))),
            }
        }
        if files.is_empty() {
            return Ok(None);
        }
        let total: usize = files.iter().map(|f| f.1).sum();
        let (file, _, (line, first)) = files[0];
        let per: Vec<String> = files
            .iter()
            .map(|(f, n, _)| {
                let name = f.file_name().unwrap_or_default().to_string_lossy();
                format!("{name} {n}")
            })
            .collect();
        Ok(Some(format!(
            "{total} of the {} episodes of split {split} repeat an earlier line of their file ({}; first: {} line {line} = line {first}); each line is evaluated, as in the reference benchmark, so a repeated episode counts again",
            raw.len(),
            per.join(", "),
            file.display()
        )))
    }

    fn resolve_episode(
        &self,
        index: usize,
        split: Split,
        r: &data::RawEpisodeLine,
    ) -> Result<EpisodeSpec> {
        let at = || format!("{} line {}", r.file.display(), r.line);
        let e = &r.episode;
        if let Some(s) = e.split.as_deref().filter(|s| *s != split.name()) {
            bail!(
                "{}: split {s:?} disagrees with the {split} episode directory it is in",
                at()
            );
        }
        let scene = self
            .scene_id(&e.scene)
            .filter(|&s| self.scenes[s].split == split)
            .ok_or_else(|| anyhow!("{}: scene {} is not a {split} scene", at(), e.scene))?;
        let room = RoomType::parse(&e.room).with_context(at)?;
        let kind = TargetKind::parse(&e.target_kind).with_context(at)?;
        let target = self
            .category_id(&e.target)
            .ok_or_else(|| anyhow!("{}: unknown target {:?}", at(), e.target))?;
        self.check_episode_target(&at, r, scene, room, kind, target)?;
        let start = start_state(&at, &e.start)?;
        let Some(start_index) = self.scenes[scene].state_index(start) else {
            bail!(
                "{}: start ({}, {}) is not reachable in {}",
                at(),
                e.start.x,
                e.start.z,
                e.scene
            );
        };
        if let Some(o) = &self.offline[scene] {
            if !o.has_state(start_index) {
                bail!(
                    "{}: start {} is not a node of {}",
                    at(),
                    offline::state_key(start),
                    o.dir.join(offline::GRAPH_FILE).display()
                );
            }
        }
        Ok(EpisodeSpec {
            index,
            scene,
            room,
            kind,
            target,
            target_ids: e.target_ids.clone(),
            start,
            seed: hash2(hash_str(self.seed, split.name()), index as u64),
        })
    }

    /// Checks an episode's file, room, target and target ids against its scene and the split
    /// of `attributes.json`.
    fn check_episode_target(
        &self,
        at: &dyn Fn() -> String,
        r: &data::RawEpisodeLine,
        scene: SceneId,
        room: RoomType,
        kind: TargetKind,
        target: CategoryId,
    ) -> Result<()> {
        let e = &r.episode;
        let file_stem = format!("{}_{}.jsonl", room.name(), kind.name());
        if r.file.file_name().is_some_and(|n| n != file_stem.as_str()) {
            bail!(
                "{}: a {} {} episode in the wrong file (it belongs in {file_stem})",
                at(),
                room.name(),
                kind.name()
            );
        }
        if self.scenes[scene].room != room {
            bail!(
                "{}: room {} disagrees with scene {}, which is a {}",
                at(),
                room.name(),
                e.scene,
                self.scenes[scene].room.name()
            );
        }
        // The split's target lists (DeskLamp is listed both seen and unseen, see
        // attributes.json `split.note`, so membership is what is checked).
        let (kind_list, room_list) = match kind {
            TargetKind::Seen => (&self.seen, &self.eval_targets[room.index()].0),
            TargetKind::Unseen => (&self.unseen, &self.eval_targets[room.index()].1),
        };
        if !kind_list.contains(&target) || !(room_list.is_empty() || room_list.contains(&target)) {
            bail!(
                "{}: target {} is not among the {} targets{} in the split of attributes.json",
                at(),
                e.target,
                kind.name(),
                if room_list.is_empty() {
                    String::new()
                } else {
                    format!(" of {} rooms", room.name())
                }
            );
        }
        if e.target_ids.is_empty() {
            bail!("{}: target_ids is empty", at());
        }
        if let Some(id) = e.target_ids.iter().find(|id| {
            !self.scenes[scene]
                .objects
                .iter()
                .any(|o| o.category == target && o.ids.iter().any(|i| i == *id))
        }) {
            bail!(
                "{}: target id {id:?} is not a {} of scene {}",
                at(),
                e.target,
                e.scene
            );
        }
        Ok(())
    }

    /// Samples a training task: a random training scene, a random training target of its room
    /// type present in it, and a random reachable start (position and heading, horizon 0) from
    /// which a goal-visible state can be reached.
    ///
    /// # Panics
    /// If the world has no training scene with a reachable start (never the case for the data
    /// directory or the synthetic world); [`World::try_sample_train_episode_min`] returns an
    /// error instead.
    pub fn sample_train_episode<R: Rng + ?Sized>(&self, rng: &mut R) -> EpisodeSpec {
        match self.try_sample_train_episode_min(rng, 0) {
            Ok(e) => e,
            Err(e) => panic!("{e:#}"),
        }
    }

    /// Like [`World::sample_train_episode`], but the start needs at least `min_actions`
    /// actions to reach a state where the target is visible (`1`: the target is not in view
    /// at the start, so that issuing Done at once never succeeds).
    ///
    /// # Panics
    /// When no start qualifies (see [`World::try_sample_train_episode_min`]).
    pub fn sample_train_episode_min<R: Rng + ?Sized>(
        &self,
        rng: &mut R,
        min_actions: u32,
    ) -> EpisodeSpec {
        match self.try_sample_train_episode_min(rng, min_actions) {
            Ok(e) => e,
            Err(e) => panic!("{e:#}"),
        }
    }

    /// Draws of [`World::try_sample_train_episode_min`] (scene and target choices, 32 starts
    /// each) before it gives up: far more than any satisfiable setting needs (on the real data
    /// and the synthetic world, `--min-start-actions` up to 10 is met within a few draws).
    pub const MAX_START_DRAWS: usize = 20_000;

    /// [`World::sample_train_episode_min`] with a bound: after
    /// [`World::MAX_START_DRAWS`] scene and target draws without a start that needs at least
    /// `min_actions` actions, an error says how far the farthest start seen was and that
    /// `--min-start-actions` must be lowered (the unbounded loop hung forever). For settings
    /// that can be met, the random draws and the result are those of the unbounded loop.
    pub fn try_sample_train_episode_min<R: Rng + ?Sized>(
        &self,
        rng: &mut R,
        min_actions: u32,
    ) -> Result<EpisodeSpec> {
        let train = match self.split_scenes.get(&Split::Train) {
            Some(t) if !t.is_empty() => t,
            _ => bail!("the world has no training scenes"),
        };
        let mut farthest: Option<u32> = None;
        for _ in 0..Self::MAX_START_DRAWS {
            let scene = train[rng.random_range(0..train.len())];
            let sc = &self.scenes[scene];
            let targets: Vec<CategoryId> = self.train_targets[sc.room.index()]
                .iter()
                .copied()
                .filter(|&c| sc.instances_of(c).next().is_some())
                .collect();
            if targets.is_empty() || sc.positions.is_empty() {
                continue;
            }
            let target = targets[rng.random_range(0..targets.len())];
            let goal = self.goal_table(scene, target);
            for _ in 0..32 {
                let p = rng.random_range(0..sc.positions.len());
                let heading = rng.random_range(0..NUM_HEADINGS) as u8;
                let state = p * STATES_PER_POSITION + heading as usize * 2;
                if goal.dist[state] != UNREACHABLE {
                    let d = goal.dist[state] as u32;
                    farthest = Some(farthest.map_or(d, |f| f.max(d)));
                    if d >= min_actions {
                        return Ok(EpisodeSpec {
                            index: 0,
                            scene,
                            room: sc.room,
                            kind: TargetKind::Seen,
                            target,
                            target_ids: Vec::new(),
                            start: sc.state(state),
                            seed: rng.random(),
                        });
                    }
                }
            }
        }
        match farthest {
            Some(f) => bail!(
                "no training start needs at least {min_actions} actions to see the target: the \
                 farthest of {} sampled starts needs {f}; lower --min-start-actions (to {f} or less)",
                Self::MAX_START_DRAWS * 32
            ),
            None => bail!(
                "no reachable training start with a visible target was found in {} draws",
                Self::MAX_START_DRAWS
            ),
        }
    }
}
