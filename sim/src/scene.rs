//! One floor plan: reachable grid, object instances and the discrete state graph.
//!
//! # Building rules (documented choices)
//! * **Reachable set**: the union of the file's `reachable` and `reachable_sample` positions,
//!   plus *gap filling*: a non-reachable cell whose two opposite 4-neighbours (left and right,
//!   or front and back) are both reachable is made reachable. One pass over the union, not
//!   iterated, so only one-cell-wide slits are closed (ALFRED's grid is slightly conservative).
//! * **Known instances**: positions in `objects` and `known_objects` are used as given.
//!   Instances of one category whose centres are within 0.3 m (horizontally and vertically)
//!   are one object seen by two AI2THOR versions: they are merged and keep every id.
//! * **Placed instances**: every category of `object_types` without a known instance gets
//!   [`CategoryProps::instances`](super::types::CategoryProps::instances) instances placed by a seeded rule: choose a *boundary slot*
//!   (a reachable cell and a side whose 4-neighbour is not reachable; unused slots first) and
//!   put the object's centre `0.2 m + radius` from the cell centre towards that side, jittered
//!   by up to +-0.1 m along the wall, at the category's typical height. The seed is a hash of
//!   the world seed, the scene name, the category name and the instance number.
//! * **Unseen categories** are removed from training scenes (types and instances).
//!
//! # Object layouts
//! The rules above are the `rule` layout ([`ObjectLayout::Rule`]). The `thor5` layout
//! ([`ObjectLayout::Thor5`]) reads the AI2-THOR 5.0 objects of `objects_thor5/FloorPlanN.json`
//! ([`Thor5Object`]) and changes two things:
//! * **Instances of the categories without a 2.x position** are the file's objects of that
//!   category, at their 5.0 positions with their axis-aligned boxes (5.0 type `Stool` counts as
//!   `Chair`, see [`thor5_category_name`]); only the categories of `object_types` are used,
//!   and a 5.0 object whose id a 2.x instance already has is not added again. A present
//!   category left without an instance is placed by the rule as above (listed in
//!   [`Scene::rule_fallback`]).
//! * **2.x instances keep their positions** (episode goals and `known_objects`) and take the box
//!   size of the nearest unused 5.0 object of their category within 0.5 m (horizontally and
//!   vertically), shifted by the 2.x-to-5.0 position offset; one without a match keeps the
//!   footprint circle of its category.
//!
//! Instances with a box are seen and measured by it ([`crate::geometry::appearance_box`]);
//! the others, and every instance under `rule`, by the footprint circle of their category.

use std::collections::{BTreeSet, HashMap};

use gman_core::{Action, NUM_ACTIONS};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use super::geometry::{heading_step, turn, Aabb, GRID};
use super::types::{
    AgentState, Category, CategoryId, ObjectLayout, RoomType, Split, NUM_HEADINGS,
    STATES_PER_POSITION,
};
use super::util::hash_str;

/// One object instance of a scene.
#[derive(Clone, Debug)]
pub struct ObjectInstance {
    /// AI2THOR ids of the instance (several after merging duplicates; a generated id
    /// `Type|placed|k` for placed instances).
    pub ids: Vec<String>,
    /// Category.
    pub category: CategoryId,
    /// Centre (x, y, z) in metres.
    pub pos: [f32; 3],
    /// True when the position comes from the data, false when placed by the seeded rule.
    pub known: bool,
    /// True when the instance comes from the AI2-THOR 5.0 sidecar (`thor5` layout).
    pub thor5: bool,
    /// Axis-aligned box (`thor5` layout; `None`: the category's footprint circle).
    pub aabb: Option<Aabb>,
}

/// One AI2-THOR 5.0 object of the 40 categories (`objects_thor5`), for the `thor5` layout.
#[derive(Clone, Debug, PartialEq)]
pub struct Thor5Object {
    /// AI2-THOR 5.0 id.
    pub id: String,
    /// Category.
    pub category: CategoryId,
    /// Position (x, y, z) in metres.
    pub pos: [f32; 3],
    /// Axis-aligned box.
    pub aabb: Aabb,
}

/// Our category name of an AI2-THOR 5.0 object type: the same name, except `Stool`, which
/// AI2-THOR 3.0 split off from `Chair` (the kitchens whose 2.x `object_types` list a Chair have
/// a Stool and no Chair in 5.0).
pub fn thor5_category_name(object_type: &str) -> &str {
    match object_type {
        "Stool" => "Chair",
        t => t,
    }
}

/// Largest distance (metres, horizontal and vertical) between a 2.x instance and the 5.0
/// object whose box it takes.
pub const THOR5_MATCH_DISTANCE: f32 = 0.5;

/// Inputs of [`Scene::build`]: a floor plan as read from a file or generated.
#[derive(Clone, Debug)]
pub struct SceneSource {
    /// Scene name.
    pub name: String,
    /// Room type.
    pub room: RoomType,
    /// Split the scene belongs to.
    pub split: Split,
    /// Reachable cells (grid indices).
    pub reachable: Vec<(i32, i32)>,
    /// Categories present.
    pub present: Vec<CategoryId>,
    /// Instances with known positions: (id, category, centre).
    pub known: Vec<(String, CategoryId, [f32; 3])>,
    /// Take the reachable cells and the instances exactly as given (the AI2THOR offline data,
    /// [`crate::offline`]): no gap filling, no merging of nearby instances, no placed
    /// instances. The unseen categories are still removed from training scenes.
    pub exact: bool,
    /// The `thor5` layout's AI2-THOR 5.0 objects (the 40 categories only); `None`: the
    /// `rule` layout.
    pub thor5: Option<Vec<Thor5Object>>,
}

/// A built scene.
#[derive(Clone, Debug)]
pub struct Scene {
    /// Scene name (`FloorPlan22`).
    pub name: String,
    /// Room type.
    pub room: RoomType,
    /// Split.
    pub split: Split,
    /// Reachable cells, sorted; a position index is an index into this list.
    pub positions: Vec<(i32, i32)>,
    /// Per position: true when the cell was added by gap filling.
    pub filled: Vec<bool>,
    /// Object instances.
    pub objects: Vec<ObjectInstance>,
    /// Categories present (sorted, unique).
    pub present: Vec<CategoryId>,
    /// Seed of the scene's appearance style.
    pub seed: u64,
    /// The object layout the scene was built with.
    pub layout: ObjectLayout,
    /// `thor5` layout: the present categories the 5.0 file lacks, placed by the rule instead
    /// (empty under `rule`).
    pub rule_fallback: Vec<CategoryId>,
    /// `thor5` layout: the 2.x instances that took the box of a 5.0 object.
    pub thor5_matched: usize,
    min_x: i32,
    min_z: i32,
    width: i32,
    depth: i32,
    cell_index: Vec<u32>,
}

const NONE: u32 = u32::MAX;

/// The cells added by gap filling (none when `exact`): unreachable cells inside the bounding
/// box whose left and right, or front and back, neighbours are both reachable.
fn fill_gaps(
    orig: &BTreeSet<(i32, i32)>,
    exact: bool,
    (min_x, max_x): (i32, i32),
    (min_z, max_z): (i32, i32),
) -> BTreeSet<(i32, i32)> {
    let mut filled_set = BTreeSet::new();
    for x in min_x..=max_x {
        for z in min_z..=max_z {
            if exact || orig.contains(&(x, z)) {
                continue;
            }
            let lr = orig.contains(&(x - 1, z)) && orig.contains(&(x + 1, z));
            let fb = orig.contains(&(x, z - 1)) && orig.contains(&(x, z + 1));
            if lr || fb {
                filled_set.insert((x, z));
            }
        }
    }
    filled_set
}

/// The known instances, merged when they are the same object (not when `exact`); their
/// categories are added to `present`. Banned categories (unseen ones in training scenes) are
/// dropped.
fn known_instances(
    known: Vec<(String, CategoryId, [f32; 3])>,
    exact: bool,
    banned: &dyn Fn(CategoryId) -> bool,
    present: &mut BTreeSet<CategoryId>,
) -> Vec<ObjectInstance> {
    let mut objects: Vec<ObjectInstance> = Vec::new();
    for (id, cat, pos) in known {
        if banned(cat) {
            continue;
        }
        present.insert(cat);
        if let Some(o) = objects.iter_mut().find(|o| {
            !exact
                && o.category == cat
                && ((o.pos[0] - pos[0]).powi(2) + (o.pos[2] - pos[2]).powi(2)).sqrt() < 0.3
                && (o.pos[1] - pos[1]).abs() < 0.3
        }) {
            if !o.ids.contains(&id) {
                o.ids.push(id);
            }
            continue;
        }
        objects.push(ObjectInstance {
            ids: vec![id],
            category: cat,
            pos,
            known: true,
            thor5: false,
            aabb: None,
        });
    }
    objects
}

/// The `thor5` layout on top of the 2.x instances: boxes for the 2.x instances that match a 5.0
/// object, the 5.0 objects of every present category without a 2.x instance. Returns the
/// number of matched 2.x instances.
fn thor5_instances(
    objects: &mut Vec<ObjectInstance>,
    thor5: &[Thor5Object],
    present: &BTreeSet<CategoryId>,
) -> usize {
    let mut used = vec![false; thor5.len()];
    let mut matched = 0;
    for o in objects.iter_mut() {
        let best = thor5
            .iter()
            .enumerate()
            .filter(|(i, t)| {
                !used[*i]
                    && t.category == o.category
                    && (t.pos[1] - o.pos[1]).abs() <= THOR5_MATCH_DISTANCE
            })
            .map(|(i, t)| (i, (t.pos[0] - o.pos[0]).hypot(t.pos[2] - o.pos[2])))
            .filter(|&(_, d)| d <= THOR5_MATCH_DISTANCE)
            .min_by(|a, b| a.1.total_cmp(&b.1).then(a.0.cmp(&b.0)));
        if let Some((i, _)) = best {
            used[i] = true;
            matched += 1;
            let t = &thor5[i];
            let mut center = t.aabb.center;
            for ((c, a), b) in center.iter_mut().zip(o.pos).zip(t.pos) {
                *c += a - b;
            }
            o.aabb = Some(Aabb {
                center,
                size: t.aabb.size,
            });
        }
    }
    let with_2x: BTreeSet<CategoryId> = objects.iter().map(|o| o.category).collect();
    let ids_2x: BTreeSet<String> = objects.iter().flat_map(|o| o.ids.clone()).collect();
    for t in thor5 {
        // A 5.0 object whose id a 2.x instance already has is that instance (the 2.x files
        // list some `Sink|...|SinkBasin` ids as a Sink): it is not added twice.
        if present.contains(&t.category)
            && !with_2x.contains(&t.category)
            && !ids_2x.contains(&t.id)
        {
            objects.push(ObjectInstance {
                ids: vec![t.id.clone()],
                category: t.category,
                pos: t.pos,
                known: true,
                thor5: true,
                aabb: Some(t.aabb),
            });
        }
    }
    matched
}

impl Scene {
    /// Builds a scene: fills gaps in the reachable set and places objects without positions.
    pub fn build(src: SceneSource, categories: &[Category], world_seed: u64) -> Scene {
        let orig: BTreeSet<(i32, i32)> = src.reachable.iter().copied().collect();
        let (mut min_x, mut max_x, mut min_z, mut max_z) = (i32::MAX, i32::MIN, i32::MAX, i32::MIN);
        for &(x, z) in &orig {
            min_x = min_x.min(x);
            max_x = max_x.max(x);
            min_z = min_z.min(z);
            max_z = max_z.max(z);
        }
        let filled_set = fill_gaps(&orig, src.exact, (min_x, max_x), (min_z, max_z));
        let all: BTreeSet<(i32, i32)> = orig.union(&filled_set).copied().collect();
        let positions: Vec<(i32, i32)> = all.iter().copied().collect();
        let filled = positions.iter().map(|p| filled_set.contains(p)).collect();
        // Grid with a one-cell margin.
        let (gx, gz) = (min_x - 1, min_z - 1);
        let width = max_x - min_x + 3;
        let depth = max_z - min_z + 3;
        let mut cell_index = vec![NONE; (width * depth) as usize];
        for (i, &(x, z)) in positions.iter().enumerate() {
            cell_index[((x - gx) * depth + (z - gz)) as usize] = i as u32;
        }
        let seed = hash_str(world_seed, &src.name);
        let mut scene = Scene {
            name: src.name,
            room: src.room,
            split: src.split,
            positions,
            filled,
            objects: Vec::new(),
            present: Vec::new(),
            seed,
            layout: if src.thor5.is_some() {
                ObjectLayout::Thor5
            } else {
                ObjectLayout::Rule
            },
            rule_fallback: Vec::new(),
            thor5_matched: 0,
            min_x: gx,
            min_z: gz,
            width,
            depth,
            cell_index,
        };
        let banned = |c: CategoryId| src.split == Split::Train && categories[c as usize].unseen;
        let mut present: BTreeSet<CategoryId> = src
            .present
            .iter()
            .copied()
            .filter(|&c| !banned(c))
            .collect();
        let mut objects = known_instances(src.known, src.exact, &banned, &mut present);
        if let Some(thor5) = &src.thor5 {
            scene.thor5_matched = thor5_instances(&mut objects, thor5, &present);
            scene.rule_fallback = present
                .iter()
                .copied()
                .filter(|&c| !objects.iter().any(|o| o.category == c))
                .collect();
        }
        scene.place_instances(&mut objects, &present, src.exact, categories);
        scene.objects = objects;
        scene.present = present.into_iter().collect();
        scene
    }

    /// Placed instances for the present categories without a known position (none when
    /// `exact`), on the scene's boundary slots.
    fn place_instances(
        &self,
        objects: &mut Vec<ObjectInstance>,
        present: &BTreeSet<CategoryId>,
        exact: bool,
        categories: &[Category],
    ) {
        let slots = self.boundary_slots();
        let mut used = vec![false; slots.len()];
        for &cat in present {
            if exact || objects.iter().any(|o| o.category == cat) || slots.is_empty() {
                continue;
            }
            let c = &categories[cat as usize];
            for k in 0..c.props.instances.max(1) {
                let mut rng = ChaCha8Rng::seed_from_u64(hash_str(
                    hash_str(self.seed, &c.name),
                    &k.to_string(),
                ));
                let mut s = rng.random_range(0..slots.len());
                for _ in 0..16 {
                    if !used[s] {
                        break;
                    }
                    s = rng.random_range(0..slots.len());
                }
                used[s] = true;
                let ((x, z), (dx, dz)) = slots[s];
                let off = 0.2 + c.props.radius;
                let jitter = rng.random_range(-0.1f32..0.1);
                let px = x as f32 * GRID + dx as f32 * off + dz as f32 * jitter;
                let pz = z as f32 * GRID + dz as f32 * off + dx as f32 * jitter;
                objects.push(ObjectInstance {
                    ids: vec![format!("{}|placed|{k}", c.name)],
                    category: cat,
                    pos: [px, c.props.height, pz],
                    known: false,
                    thor5: false,
                    aabb: None,
                });
            }
        }
    }

    /// Boundary slots: (reachable cell, direction to a non-reachable 4-neighbour).
    pub fn boundary_slots(&self) -> Vec<((i32, i32), (i32, i32))> {
        let mut out = Vec::new();
        for &(x, z) in &self.positions {
            for d in [(0, 1), (1, 0), (0, -1), (-1, 0)] {
                if self.position_index(x + d.0, z + d.1).is_none() {
                    out.push(((x, z), d));
                }
            }
        }
        out
    }

    /// Position index of grid cell (x, z), if reachable.
    #[inline]
    pub fn position_index(&self, x: i32, z: i32) -> Option<usize> {
        let (ix, iz) = (x - self.min_x, z - self.min_z);
        if ix < 0 || iz < 0 || ix >= self.width || iz >= self.depth {
            return None;
        }
        let v = self.cell_index[(ix * self.depth + iz) as usize];
        (v != NONE).then_some(v as usize)
    }

    /// True if the point (metres) lies on a reachable cell.
    #[inline]
    pub fn is_reachable_point(&self, x: f32, z: f32) -> bool {
        self.position_index((x / GRID).round() as i32, (z / GRID).round() as i32)
            .is_some()
    }

    /// Grid bounds (min x, min z, max x, max z) of the reachable cells, inclusive.
    pub fn bounds(&self) -> (i32, i32, i32, i32) {
        (
            self.min_x + 1,
            self.min_z + 1,
            self.min_x + self.width - 2,
            self.min_z + self.depth - 2,
        )
    }

    /// Number of discrete states (positions x 8 headings x 2 horizons).
    pub fn num_states(&self) -> usize {
        self.positions.len() * STATES_PER_POSITION
    }

    /// State index of an agent state, if its cell is reachable.
    pub fn state_index(&self, s: AgentState) -> Option<usize> {
        if s.heading as usize >= NUM_HEADINGS || s.horizon > 1 {
            return None;
        }
        self.position_index(s.x, s.z)
            .map(|p| p * STATES_PER_POSITION + s.heading as usize * 2 + s.horizon as usize)
    }

    /// Agent state of a state index.
    pub fn state(&self, idx: usize) -> AgentState {
        let (x, z) = self.positions[idx / STATES_PER_POSITION];
        let r = idx % STATES_PER_POSITION;
        AgentState {
            x,
            z,
            heading: (r / 2) as u8,
            horizon: (r % 2) as u8,
        }
    }

    /// Successor of state `idx` under `action` (a blocked move or Done leaves it unchanged).
    ///
    /// MoveAhead goes to the next cell along the heading (diagonal for odd headings) and fails
    /// if that cell is not reachable, as in AI2THOR's offline grid data (the move succeeds
    /// whenever the next grid point exists; ALFRED's grid is conservative, and some episode
    /// starts connect to the rest of the room only diagonally).
    pub fn successor(&self, idx: usize, action: Action) -> usize {
        let s = self.state(idx);
        match action {
            Action::Done => idx,
            Action::MoveAhead => {
                let (dx, dz) = heading_step(s.heading);
                let (nx, nz) = (s.x + dx, s.z + dz);
                let Some(p) = self.position_index(nx, nz) else {
                    return idx;
                };
                p * STATES_PER_POSITION + (idx % STATES_PER_POSITION)
            }
            a => {
                let (h, v) = turn(s.heading, s.horizon, a).expect("turn action");
                (idx / STATES_PER_POSITION) * STATES_PER_POSITION + h as usize * 2 + v as usize
            }
        }
    }

    /// Successor table of all states (index `[state][action]`).
    pub fn transition_table(&self) -> Vec<[u32; NUM_ACTIONS]> {
        (0..self.num_states())
            .map(|i| {
                let mut row = [0u32; NUM_ACTIONS];
                for a in Action::ALL {
                    row[a.index()] = self.successor(i, a) as u32;
                }
                row
            })
            .collect()
    }

    /// Indices of the instances of `category`.
    pub fn instances_of(&self, category: CategoryId) -> impl Iterator<Item = usize> + '_ {
        self.objects
            .iter()
            .enumerate()
            .filter(move |(_, o)| o.category == category)
            .map(|(i, _)| i)
    }

    /// Map from every instance id to its instance index.
    pub fn id_map(&self) -> HashMap<&str, usize> {
        let mut m = HashMap::new();
        for (i, o) in self.objects.iter().enumerate() {
            for id in &o.ids {
                m.insert(id.as_str(), i);
            }
        }
        m
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::catalog::props_of;

    fn cats() -> Vec<Category> {
        ["Mug", "Toilet"]
            .iter()
            .map(|n| Category {
                name: n.to_string(),
                attributes: [0.0; gman_core::ATTR_DIM],
                unseen: *n == "Toilet",
                props: props_of(n),
            })
            .collect()
    }

    fn source(cells: Vec<(i32, i32)>, split: Split) -> SceneSource {
        SceneSource {
            name: "T".into(),
            room: RoomType::Bathroom,
            split,
            reachable: cells,
            present: vec![0, 1],
            known: vec![],
            exact: false,
            thor5: None,
        }
    }

    #[test]
    fn gap_filling_closes_one_cell_slits_only() {
        // Row z=0: x=0..5 with a hole at x=2 (one-cell slit) and x=4..5 missing (not a slit).
        let cells = vec![(0, 0), (1, 0), (3, 0), (6, 0), (0, 1), (0, 2)];
        let s = Scene::build(source(cells, Split::Val), &cats(), 1);
        assert!(s.position_index(2, 0).is_some());
        assert!(s.filled[s.position_index(2, 0).unwrap()]);
        assert!(s.position_index(4, 0).is_none() && s.position_index(5, 0).is_none());
        // (0, 1) was already reachable; (1, 1) has only two reachable diagonal neighbours.
        assert!(s.position_index(1, 1).is_none());
        assert_eq!(s.positions.len(), 7);
    }

    #[test]
    fn unseen_removed_from_training_scenes_and_placed_elsewhere() {
        let cells: Vec<(i32, i32)> = (0..6).flat_map(|x| (0..4).map(move |z| (x, z))).collect();
        let train = Scene::build(source(cells.clone(), Split::Train), &cats(), 1);
        assert_eq!(train.present, vec![0]);
        assert!(train.objects.iter().all(|o| o.category == 0));
        let val = Scene::build(source(cells, Split::Val), &cats(), 1);
        assert_eq!(val.present, vec![0, 1]);
        assert_eq!(val.instances_of(1).count(), 1);
        // Placement is seeded: same seed, same positions; another seed moves objects.
        let again = Scene::build(source(val.positions.clone(), Split::Val), &cats(), 1);
        assert_eq!(val.objects[0].pos, again.objects[0].pos);
    }

    #[test]
    fn moves_follow_headings_and_fail_when_blocked() {
        let cells: Vec<(i32, i32)> = (0..3).flat_map(|x| (0..3).map(move |z| (x, z))).collect();
        let s = Scene::build(source(cells, Split::Val), &cats(), 1);
        let st = |x, z, heading| {
            s.state_index(AgentState {
                x,
                z,
                heading,
                horizon: 0,
            })
            .unwrap()
        };
        assert_eq!(s.successor(st(1, 1, 0), Action::MoveAhead), st(1, 2, 0));
        assert_eq!(s.successor(st(1, 1, 1), Action::MoveAhead), st(2, 2, 1));
        assert_eq!(s.successor(st(1, 2, 0), Action::MoveAhead), st(1, 2, 0));
        assert_eq!(s.successor(st(0, 0, 5), Action::MoveAhead), st(0, 0, 5));
        assert_eq!(s.successor(st(1, 1, 0), Action::RotateLeft), st(1, 1, 7));
        assert_eq!(s.successor(st(1, 1, 0), Action::Done), st(1, 1, 0));
    }
}
