//! The built-in synthetic demo world, used when no `--data` directory is given (a fresh clone
//! does not have the iTHOR data).
//!
//! Everything is generated from one seed:
//! * **Categories**: 40 made-up categories with 45-d attribute vectors: per room type 6 seen
//!   targets and 2 unseen targets, plus 8 distractors found in every room type. Attributes of a
//!   room's categories share a few "room" dimensions, so seen and unseen categories are related
//!   through their attributes, as in the real data.
//! * **Floor plans**: per room type 8 training and 3 val scenes: a rectangle (living rooms
//!   largest, bathrooms smallest) with 1-3 rectangular furniture blocks cut out, keeping the
//!   largest 4-connected region. Objects are placed by the same boundary rule as the real
//!   scenes' unknown objects ([`crate::scene`]). Unseen categories only occur in val scenes.
//! * **Val episodes**: per room type and kind (seen/unseen) `episodes_per_group` episodes
//!   (default 250): a random val scene, a random target of that kind present in it, a random
//!   start (horizon 0) from which the target can be reached but is not yet visible.

use std::collections::{BTreeMap, BTreeSet, VecDeque};

use gman_core::ATTR_DIM;
use rand::seq::SliceRandom;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use super::scene::SceneSource;
use super::tables::UNREACHABLE;
use super::types::{
    Category, CategoryId, CategoryProps, RoomType, Split, TargetKind, NUM_HEADINGS,
    STATES_PER_POSITION,
};
use super::util::{hash2, mix64};
use super::world::{EpisodeSpec, World, WorldParts, WorldSource};

/// Sizes of the synthetic world.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct SyntheticConfig {
    /// Training scenes per room type.
    pub train_scenes_per_room: usize,
    /// Val scenes per room type.
    pub val_scenes_per_room: usize,
    /// Val episodes per (room type, seen/unseen).
    pub episodes_per_group: usize,
}

impl Default for SyntheticConfig {
    fn default() -> Self {
        SyntheticConfig {
            train_scenes_per_room: 8,
            val_scenes_per_room: 3,
            episodes_per_group: 250,
        }
    }
}

const SEEN_PER_ROOM: usize = 6;
const UNSEEN_PER_ROOM: usize = 2;
const DISTRACTORS: usize = 8;

fn attributes(rng: &mut ChaCha8Rng, room_dims: &[usize]) -> [f32; ATTR_DIM] {
    let mut a = [0f32; ATTR_DIM];
    let mut dims: Vec<usize> = room_dims.to_vec();
    dims.shuffle(rng);
    for &d in dims.iter().take(4) {
        a[d] = rng.random_range(0.4f32..1.0);
    }
    for _ in 0..2 {
        a[rng.random_range(0..ATTR_DIM)] = rng.random_range(0.2f32..1.0);
    }
    a
}

fn props(rng: &mut ChaCha8Rng) -> CategoryProps {
    CategoryProps {
        height: rng.random_range(0.3f32..1.6),
        radius: rng.random_range(0.08f32..0.5),
        size: rng.random_range(0.3f32..1.6),
        instances: rng.random_range(1..=2),
    }
}

fn floor_plan(rng: &mut ChaCha8Rng, room: RoomType) -> Vec<(i32, i32)> {
    let (w, d) = match room {
        RoomType::Kitchen => (rng.random_range(12..18), rng.random_range(10..15)),
        RoomType::LivingRoom => (rng.random_range(18..26), rng.random_range(14..20)),
        RoomType::Bedroom => (rng.random_range(13..19), rng.random_range(11..16)),
        RoomType::Bathroom => (rng.random_range(7..11), rng.random_range(6..10)),
    };
    let mut free = vec![true; (w * d) as usize];
    for _ in 0..rng.random_range(1..=3) {
        let bw = rng.random_range(2..=(w / 3).max(2));
        let bd = rng.random_range(2..=(d / 3).max(2));
        let x0 = rng.random_range(1..(w - bw).max(2));
        let z0 = rng.random_range(1..(d - bd).max(2));
        for x in x0..(x0 + bw).min(w) {
            for z in z0..(z0 + bd).min(d) {
                free[(x * d + z) as usize] = false;
            }
        }
    }
    // Largest 4-connected region.
    let mut comp = vec![usize::MAX; free.len()];
    let mut best: Vec<(i32, i32)> = Vec::new();
    for start in 0..free.len() {
        if !free[start] || comp[start] != usize::MAX {
            continue;
        }
        let mut cells = Vec::new();
        let mut q = VecDeque::from([start]);
        comp[start] = start;
        while let Some(c) = q.pop_front() {
            let (x, z) = (c as i32 / d, c as i32 % d);
            cells.push((x, z));
            for (dx, dz) in [(1, 0), (-1, 0), (0, 1), (0, -1)] {
                let (nx, nz) = (x + dx, z + dz);
                if nx < 0 || nz < 0 || nx >= w || nz >= d {
                    continue;
                }
                let n = (nx * d + nz) as usize;
                if free[n] && comp[n] == usize::MAX {
                    comp[n] = start;
                    q.push_back(n);
                }
            }
        }
        if cells.len() > best.len() {
            best = cells;
        }
    }
    // Shift so the room is centred near the origin, as iTHOR rooms are.
    best.iter().map(|&(x, z)| (x - w / 2, z - d / 2)).collect()
}

impl World {
    /// The built-in synthetic demo world: [`generate`] with the default
    /// [`SyntheticConfig`]. (Defined here, beside the generator, so that `world.rs` does not
    /// depend on this module, which builds on it.)
    pub fn synthetic(seed: u64) -> World {
        generate(seed, &SyntheticConfig::default())
    }
}

/// Generates the synthetic world.
pub fn generate(seed: u64, cfg: &SyntheticConfig) -> World {
    let mut rng = ChaCha8Rng::seed_from_u64(mix64(seed ^ 0x5157));
    let mut dims: Vec<usize> = (0..ATTR_DIM).collect();
    dims.shuffle(&mut rng);
    let room_dims: Vec<Vec<usize>> = (0..4).map(|r| dims[r * 8..r * 8 + 8].to_vec()).collect();
    let misc_dims: Vec<usize> = dims[32..].to_vec();
    let mut categories = Vec::new();
    let mut train_targets: [Vec<CategoryId>; 4] = Default::default();
    let mut eval_targets: [(Vec<CategoryId>, Vec<CategoryId>); 4] = Default::default();
    let (mut seen, mut unseen) = (Vec::new(), Vec::new());
    for room in RoomType::ALL {
        for k in 0..SEEN_PER_ROOM + UNSEEN_PER_ROOM {
            let is_unseen = k >= SEEN_PER_ROOM;
            let id = categories.len() as CategoryId;
            let name = if is_unseen {
                format!("{}_unseen_{}", room.name(), k - SEEN_PER_ROOM)
            } else {
                format!("{}_seen_{k}", room.name())
            };
            categories.push(Category {
                name,
                attributes: attributes(&mut rng, &room_dims[room.index()]),
                unseen: is_unseen,
                props: props(&mut rng),
            });
            if is_unseen {
                unseen.push(id);
                eval_targets[room.index()].1.push(id);
            } else {
                seen.push(id);
                train_targets[room.index()].push(id);
                eval_targets[room.index()].0.push(id);
            }
        }
    }
    let distractors: Vec<CategoryId> = (0..DISTRACTORS)
        .map(|k| {
            categories.push(Category {
                name: format!("misc_{k}"),
                attributes: attributes(&mut rng, &misc_dims),
                unseen: false,
                props: props(&mut rng),
            });
            (categories.len() - 1) as CategoryId
        })
        .collect();
    let mut scenes = Vec::new();
    for room in RoomType::ALL {
        for (split, n) in [
            (Split::Train, cfg.train_scenes_per_room),
            (Split::Val, cfg.val_scenes_per_room),
        ] {
            for k in 0..n {
                let reachable = floor_plan(&mut rng, room);
                let (s, u) = &eval_targets[room.index()];
                let mut present: Vec<CategoryId> = s.clone();
                if split != Split::Train {
                    present.extend(u);
                }
                let mut d = distractors.clone();
                d.shuffle(&mut rng);
                present.extend(d.iter().take(rng.random_range(3..=5)));
                scenes.push(SceneSource {
                    name: format!("Synthetic-{}-{}-{k}", room.name(), split.name()),
                    room,
                    split,
                    reachable,
                    present,
                    known: Vec::new(),
                    exact: false,
                    thor5: None,
                });
            }
        }
    }
    let parts = WorldParts {
        source: WorldSource::Synthetic,
        seed,
        layout: super::types::ObjectLayout::Rule,
        categories,
        seen,
        unseen,
        train_targets,
        eval_targets,
        scenes,
    };
    let mut world = World::assemble(parts, BTreeMap::new());
    let episodes = generate_episodes(&world, seed, cfg.episodes_per_group);
    world.set_generated_episodes(Split::Val, episodes);
    world
}

fn generate_episodes(world: &World, seed: u64, per_group: usize) -> Vec<EpisodeSpec> {
    let mut rng = ChaCha8Rng::seed_from_u64(mix64(seed ^ 0xE915));
    let val: Vec<usize> = world
        .split_scenes(Split::Val)
        .map(|v| v.to_vec())
        .unwrap_or_default();
    let mut out = Vec::new();
    for room in RoomType::ALL {
        let scenes: Vec<usize> = val
            .iter()
            .copied()
            .filter(|&s| world.scenes[s].room == room)
            .collect();
        for kind in [TargetKind::Seen, TargetKind::Unseen] {
            let (s, u) = &world.eval_targets[room.index()];
            let targets = if kind == TargetKind::Seen { s } else { u };
            let mut made = 0;
            let mut tries = 0;
            while made < per_group
                && tries < per_group * 100
                && !scenes.is_empty()
                && !targets.is_empty()
            {
                tries += 1;
                let scene = scenes[rng.random_range(0..scenes.len())];
                let target = targets[rng.random_range(0..targets.len())];
                let sc = &world.scenes[scene];
                if sc.instances_of(target).next().is_none() {
                    continue;
                }
                let goal = world.goal_table(scene, target);
                let p = rng.random_range(0..sc.positions.len());
                let heading = rng.random_range(0..NUM_HEADINGS) as u8;
                let state = p * STATES_PER_POSITION + heading as usize * 2;
                let dist = goal.dist[state];
                if dist == UNREACHABLE || dist == 0 {
                    continue;
                }
                let target_ids: BTreeSet<String> = sc
                    .instances_of(target)
                    .flat_map(|i| sc.objects[i].ids.iter().cloned())
                    .collect();
                let index = out.len();
                out.push(EpisodeSpec {
                    index,
                    scene,
                    room,
                    kind,
                    target,
                    target_ids: target_ids.into_iter().collect(),
                    start: sc.state(state),
                    seed: hash2(seed, index as u64),
                });
                made += 1;
            }
        }
    }
    out
}
