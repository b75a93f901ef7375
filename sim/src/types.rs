//! Small shared types: room types, splits, target kinds, ids and agent states.

use std::fmt;

use anyhow::{bail, Result};
use gman_core::ATTR_DIM;
use serde::{Deserialize, Serialize};

/// Index of a category in [`crate::World::categories`].
pub type CategoryId = u16;
/// Index of a scene in [`crate::World::scenes`].
pub type SceneId = usize;

/// The four AI2THOR room types.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum RoomType {
    /// FloorPlan1-30.
    Kitchen,
    /// FloorPlan201-230.
    LivingRoom,
    /// FloorPlan301-330.
    Bedroom,
    /// FloorPlan401-430.
    Bathroom,
}

impl RoomType {
    /// All room types in the paper's order.
    pub const ALL: [RoomType; 4] = [
        RoomType::Kitchen,
        RoomType::LivingRoom,
        RoomType::Bedroom,
        RoomType::Bathroom,
    ];

    /// Name used in the data files (`kitchen`, `living_room`, `bedroom`, `bathroom`).
    pub fn name(self) -> &'static str {
        match self {
            RoomType::Kitchen => "kitchen",
            RoomType::LivingRoom => "living_room",
            RoomType::Bedroom => "bedroom",
            RoomType::Bathroom => "bathroom",
        }
    }

    /// Parses a data-file room name.
    pub fn parse(s: &str) -> Result<RoomType> {
        RoomType::ALL
            .into_iter()
            .find(|r| r.name() == s)
            .ok_or_else(|| {
                anyhow::anyhow!(
                    "unknown room type {s:?} (expected kitchen, living_room, bedroom or bathroom)"
                )
            })
    }

    /// Position in [`RoomType::ALL`].
    pub fn index(self) -> usize {
        self as usize
    }
}

impl fmt::Display for RoomType {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

/// Whether an evaluation target was a training target category (seen) or not (unseen).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum TargetKind {
    /// Seen category.
    Seen,
    /// Unseen category (never present in training scenes).
    Unseen,
}

impl TargetKind {
    /// `seen` or `unseen`.
    pub fn name(self) -> &'static str {
        match self {
            TargetKind::Seen => "seen",
            TargetKind::Unseen => "unseen",
        }
    }

    /// Parses `seen` / `unseen`.
    pub fn parse(s: &str) -> Result<TargetKind> {
        match s {
            "seen" => Ok(TargetKind::Seen),
            "unseen" => Ok(TargetKind::Unseen),
            _ => bail!("unknown target kind {s:?} (expected seen or unseen)"),
        }
    }
}

/// A data split.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Split {
    /// Training scenes (80 floor plans); episodes are sampled.
    Train,
    /// Validation scenes and official episodes.
    Val,
    /// Held-back test scenes and episodes (same format as val).
    Test,
}

impl Split {
    /// All splits.
    pub const ALL: [Split; 3] = [Split::Train, Split::Val, Split::Test];

    /// Directory name of the split.
    pub fn name(self) -> &'static str {
        match self {
            Split::Train => "train",
            Split::Val => "val",
            Split::Test => "test",
        }
    }

    /// Parses `train`, `val` or `test`.
    pub fn parse(s: &str) -> Result<Split> {
        Split::ALL
            .into_iter()
            .find(|x| x.name() == s)
            .ok_or_else(|| anyhow::anyhow!("unknown split {s:?} (expected train, val or test)"))
    }
}

impl fmt::Display for Split {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

/// An object category with its semantic embedding SE(y).
#[derive(Clone, Debug)]
pub struct Category {
    /// AI2THOR name (or a generated name in the synthetic world).
    pub name: String,
    /// Attribute vector, values in [0, 1].
    pub attributes: [f32; ATTR_DIM],
    /// True for the unseen categories (never placed in training scenes).
    pub unseen: bool,
    /// Physical properties used for placement and visibility.
    pub props: CategoryProps,
}

/// Physical properties of a category (typical values; see [`crate::scene`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CategoryProps {
    /// Typical height of the object's centre above the floor (metres).
    pub height: f32,
    /// Footprint radius (metres); distances are measured to this footprint.
    pub radius: f32,
    /// Apparent visual size (metres) that scales how much of a view the object fills.
    pub size: f32,
    /// Number of instances placed when no position is known.
    pub instances: u8,
}

/// Discrete agent state: grid cell, heading and camera horizon.
///
/// `x`, `z` are grid indices (metres / 0.25, rounded); `heading` is `rotation / 45` in 0..8
/// (0 faces +z, 2 faces +x, as AI2THOR's y rotation); `horizon` is 0 (level) or 1 (30 degrees
/// down).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
pub struct AgentState {
    /// Grid x index.
    pub x: i32,
    /// Grid z index.
    pub z: i32,
    /// Heading in 45 degree steps, 0..8.
    pub heading: u8,
    /// 0: camera level, 1: 30 degrees down.
    pub horizon: u8,
}

/// Number of headings (45 degree steps).
pub const NUM_HEADINGS: usize = 8;
/// Number of camera horizons (0 and 30 degrees down).
pub const NUM_HORIZONS: usize = 2;
/// Discrete states per grid position.
pub const STATES_PER_POSITION: usize = NUM_HEADINGS * NUM_HORIZONS;

/// Where the objects of the real floor plans come from, beyond the 2.x positions of the scene
/// files (episode goal instances and `known_objects`, which every layout keeps). Part of the
/// world's identity: a checkpoint stores it and a resumed run must use the same one.
#[derive(
    Clone, Copy, Debug, Default, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize,
)]
#[serde(rename_all = "snake_case")]
pub enum ObjectLayout {
    /// Every present category without a 2.x position is placed by the seeded rule against the
    /// walls ([`crate::scene`]); distances are measured to a footprint circle.
    #[default]
    Rule,
    /// The AI2-THOR 5.0 objects of `objects_thor5/FloorPlanN.json`: their positions and
    /// axis-aligned boxes for those categories, boxes for the 2.x instances they match, and
    /// visibility measured to the boxes. A present category the 5.0 file lacks falls back
    /// to the rule.
    Thor5,
}

impl ObjectLayout {
    /// `rule` or `thor5`.
    pub fn name(self) -> &'static str {
        match self {
            ObjectLayout::Rule => "rule",
            ObjectLayout::Thor5 => "thor5",
        }
    }
}

impl fmt::Display for ObjectLayout {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}
