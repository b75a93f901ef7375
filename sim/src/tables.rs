//! Per-scene state tables, built lazily once and shared by every episode of the scene:
//! successors, observations (features, PS target, visible objects) and, per target category,
//! BFS distances to the states where an instance is visible.

use gman_core::{Action, ATTR_DIM, FEATURE_DIM, NUM_ACTIONS};

use super::features::{FeatureModel, SceneStyle};
use super::geometry::{
    appearance, appearance_box, footprint_distance, line_of_sight, Appearance, FEATURE_RANGE, GRID,
    IN_VIEW_MIN_WEIGHT, VISIBILITY_DISTANCE,
};
use super::scene::{ObjectInstance, Scene};
use super::types::{Category, CategoryId, CategoryProps, STATES_PER_POSITION};

/// An object that appears in a view.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct InView {
    /// Instance index in [`Scene::objects`].
    pub instance: u16,
    /// Category.
    pub category: CategoryId,
    /// Share of the view it fills (before normalisation), in [0, 1].
    pub weight: f32,
}

/// What the agent observes in one state.
#[derive(Clone, Debug)]
pub struct Observation {
    /// Synthetic ResNet-like embedding s_t, values in [0, 1] (see [`crate::features`]).
    pub features: [f32; FEATURE_DIM],
    /// PS module target: mean attribute vector of the distinct categories in view
    /// ([`Observation::in_view`]); zeros when nothing is in view.
    pub ps_target: [f32; ATTR_DIM],
    /// Distinct categories visible in the success sense (in the field of view, line of sight,
    /// footprint within 1.0 m), sorted.
    pub visible: Vec<CategoryId>,
    /// Objects that appear in the embedding with weight >= 0.05, largest first.
    pub in_view: Vec<InView>,
}

impl Observation {
    /// True if an instance of `category` is visible (success sense).
    #[inline]
    pub fn is_visible(&self, category: CategoryId) -> bool {
        self.visible.binary_search(&category).is_ok()
    }
}

/// Horizontal distance from (px, pz) to an instance: to its box when it has one (`thor5`
/// layout), else to its category's footprint circle.
pub fn instance_distance(px: f32, pz: f32, obj: &ObjectInstance, props: &CategoryProps) -> f32 {
    match &obj.aabb {
        Some(b) => b.horizontal_distance(px, pz),
        None => footprint_distance(px, pz, obj.pos, props),
    }
}

/// How an instance appears from a pose: [`appearance_box`] with a box, else [`appearance`].
pub fn instance_appearance(
    px: f32,
    pz: f32,
    heading: u8,
    horizon: u8,
    obj: &ObjectInstance,
    props: &CategoryProps,
) -> Appearance {
    match &obj.aabb {
        Some(b) => appearance_box(px, pz, heading, horizon, b, props),
        None => appearance(px, pz, heading, horizon, obj.pos, props),
    }
}

/// Line of sight from (px, pz) to an instance ([`line_of_sight`]): to its centre, or, for an
/// instance with a box, to its centre or to the box's nearest point.
fn instance_line_of_sight(scene: &Scene, px: f32, pz: f32, obj: &ObjectInstance) -> bool {
    let free = |a: f32, b: f32| scene.is_reachable_point(a, b);
    if line_of_sight(px, pz, obj.pos[0], obj.pos[2], free) {
        return true;
    }
    match &obj.aabb {
        Some(b) => {
            let (nx, nz) = b.nearest_point(px, pz);
            line_of_sight(px, pz, nx, nz, free)
        }
        None => false,
    }
}

/// Successors, observations and per-state visible instances of a scene.
#[derive(Debug)]
pub struct SceneTables {
    /// `next[state][action]`: successor state.
    pub next: Vec<[u32; NUM_ACTIONS]>,
    /// Observation of every state.
    pub obs: Vec<Observation>,
    /// Instances visible (success sense) in every state.
    pub visible_instances: Vec<Vec<u16>>,
    /// The scene-styled feature of every category present (what a view filled by it looks
    /// like), indexed by category; `None` for absent categories.
    styled: Vec<Option<Box<[f32; FEATURE_DIM]>>>,
    /// Reverse graph (CSR): predecessors of state `s` are `pred[pred_start[s]..pred_start[s+1]]`.
    pred_start: Vec<u32>,
    pred: Vec<u32>,
}

impl SceneTables {
    /// Builds every table of `scene`.
    pub fn build(
        scene: &Scene,
        categories: &[Category],
        model: &FeatureModel,
        style: &SceneStyle,
    ) -> SceneTables {
        let next = scene.transition_table();
        let n = next.len();
        let (min_x, _, max_x, _) = scene.bounds();
        let span = (max_x - min_x).max(1) as f32;
        let mut obs = Vec::with_capacity(n);
        let mut visible_instances = Vec::with_capacity(n);
        let mut los = vec![false; scene.objects.len()];
        let mut styled: Vec<Option<Box<[f32; FEATURE_DIM]>>> = vec![None; categories.len()];
        for o in &scene.objects {
            styled[o.category as usize].get_or_insert_with(|| {
                Box::new(style.render(model, model.category_code(o.category as usize)))
            });
        }
        for (p, &(x, z)) in scene.positions.iter().enumerate() {
            let (px, pz) = (x as f32 * GRID, z as f32 * GRID);
            for (o, obj) in scene.objects.iter().enumerate() {
                let props = &categories[obj.category as usize].props;
                los[o] = instance_distance(px, pz, obj, props) <= FEATURE_RANGE
                    && instance_line_of_sight(scene, px, pz, obj);
            }
            let fx = (x - min_x) as f32 / span;
            for r in 0..STATES_PER_POSITION {
                let (heading, horizon) = ((r / 2) as u8, (r % 2) as u8);
                let state = p * STATES_PER_POSITION + r;
                let mut in_view = Vec::new();
                let mut vis = Vec::new();
                for (o, obj) in scene.objects.iter().enumerate() {
                    if !los[o] {
                        continue;
                    }
                    let props = &categories[obj.category as usize].props;
                    let a = instance_appearance(px, pz, heading, horizon, obj, props);
                    if !a.in_fov {
                        continue;
                    }
                    if a.footprint_distance <= VISIBILITY_DISTANCE {
                        vis.push(o as u16);
                    }
                    if a.weight >= IN_VIEW_MIN_WEIGHT {
                        in_view.push(InView {
                            instance: o as u16,
                            category: obj.category,
                            weight: a.weight,
                        });
                    }
                }
                in_view.sort_by(|a, b| b.weight.total_cmp(&a.weight));
                let bg = style.background(fx, heading, horizon);
                let features = style.view_embedding(
                    &bg,
                    in_view.iter().map(|v| {
                        (
                            v.weight,
                            &**styled[v.category as usize].as_ref().expect("styled"),
                        )
                    }),
                    state as u64,
                );
                let mut cats: Vec<CategoryId> = in_view.iter().map(|v| v.category).collect();
                cats.sort_unstable();
                cats.dedup();
                let mut ps_target = [0f32; ATTR_DIM];
                if !cats.is_empty() {
                    for &c in &cats {
                        for (t, a) in ps_target.iter_mut().zip(&categories[c as usize].attributes) {
                            *t += a;
                        }
                    }
                    let k = cats.len() as f32;
                    ps_target.iter_mut().for_each(|t| *t /= k);
                }
                let mut visible: Vec<CategoryId> = vis
                    .iter()
                    .map(|&o| scene.objects[o as usize].category)
                    .collect();
                visible.sort_unstable();
                visible.dedup();
                obs.push(Observation {
                    features,
                    ps_target,
                    visible,
                    in_view,
                });
                visible_instances.push(vis);
            }
        }
        let mut t = SceneTables::from_parts(next, obs, visible_instances);
        t.styled = styled;
        t
    }

    /// Tables from successors, observations and visible instances (one entry per state);
    /// computes the reverse graph. Used by [`SceneTables::build`] and the offline data
    /// ([`crate::offline`]).
    pub fn from_parts(
        next: Vec<[u32; NUM_ACTIONS]>,
        obs: Vec<Observation>,
        visible_instances: Vec<Vec<u16>>,
    ) -> SceneTables {
        let n = next.len();
        debug_assert_eq!(obs.len(), n);
        debug_assert_eq!(visible_instances.len(), n);
        // Reverse graph.
        let mut count = vec![0u32; n + 1];
        for (s, row) in next.iter().enumerate() {
            for &t in row.iter().take(Action::Done.index()) {
                if t as usize != s {
                    count[t as usize + 1] += 1;
                }
            }
        }
        for i in 0..n {
            count[i + 1] += count[i];
        }
        let mut fill = count.clone();
        let mut pred = vec![0u32; count[n] as usize];
        for (s, row) in next.iter().enumerate() {
            for &t in row.iter().take(Action::Done.index()) {
                if t as usize != s {
                    pred[fill[t as usize] as usize] = s as u32;
                    fill[t as usize] += 1;
                }
            }
        }
        SceneTables {
            next,
            obs,
            visible_instances,
            styled: Vec::new(),
            pred_start: count,
            pred,
        }
    }

    /// The scene-styled feature of `category` (zeros for a category absent from the scene,
    /// which never appears in a view).
    pub fn styled(&self, category: CategoryId) -> &[f32; FEATURE_DIM] {
        const ZERO: [f32; FEATURE_DIM] = [0.0; FEATURE_DIM];
        self.styled
            .get(category as usize)
            .and_then(|s| s.as_deref())
            .unwrap_or(&ZERO)
    }

    /// Number of states.
    pub fn num_states(&self) -> usize {
        self.next.len()
    }

    /// Predecessors of state `s` (states with an action leading to `s`).
    pub fn predecessors(&self, s: usize) -> &[u32] {
        &self.pred[self.pred_start[s] as usize..self.pred_start[s + 1] as usize]
    }

    /// Goal table of `category`: multi-source reverse BFS from every state where an instance
    /// of the category is visible.
    pub fn goal_table(
        &self,
        scene: &Scene,
        categories: &[Category],
        category: CategoryId,
    ) -> GoalTable {
        let n = self.num_states();
        let mut dist = vec![UNREACHABLE; n];
        let mut queue = std::collections::VecDeque::new();
        for (s, o) in self.obs.iter().enumerate() {
            if o.is_visible(category) {
                dist[s] = 0;
                queue.push_back(s);
            }
        }
        while let Some(s) = queue.pop_front() {
            let d = dist[s];
            for &p in self.predecessors(s) {
                if dist[p as usize] == UNREACHABLE {
                    dist[p as usize] = d + 1;
                    queue.push_back(p as usize);
                }
            }
        }
        let props = &categories[category as usize].props;
        let meters = scene
            .positions
            .iter()
            .map(|&(x, z)| {
                scene
                    .instances_of(category)
                    .map(|i| {
                        instance_distance(
                            x as f32 * GRID,
                            z as f32 * GRID,
                            &scene.objects[i],
                            props,
                        )
                    })
                    .fold(f32::INFINITY, f32::min)
            })
            .collect();
        GoalTable { dist, meters }
    }
}

/// Marker for "no goal-visible state reachable" in [`GoalTable::dist`].
pub const UNREACHABLE: u16 = u16::MAX;

/// Distances to the goal of one (scene, target category).
#[derive(Clone, Debug)]
pub struct GoalTable {
    /// Per state: fewest actions to a state where an instance is visible ([`UNREACHABLE`] if none).
    pub dist: Vec<u16>,
    /// Per position: horizontal distance (metres) to the nearest instance's footprint
    /// (infinite when the category is absent).
    pub meters: Vec<f32>,
}
