//! gman-sim: the navigation world, an AI2THOR-compatible discrete simulator on the real iTHOR
//! floor plans (or a built-in synthetic demo world), official GMAN episodes, rewards and
//! metrics. The simulator layer of gman-rs: it knows nothing of the model, the trainer or the
//! command line (no clap, plotters or indicatif); the evaluator that drives agents over it in
//! parallel is gman-train's `sim::eval`, the top-down renderer the gman-render crate.
//!
//! Module map:
//! * [`data`]: raw JSON files of a data directory.
//! * [`types`]: rooms, splits, ids, agent states.
//! * [`catalog`]: typical sizes and heights of the AI2THOR categories.
//! * [`geometry`]: headings, moves, field of view, line of sight.
//! * [`scene`]: floor plans (reachable set, object placement, state graph).
//! * [`features`]: the synthetic observation feature model.
//! * [`spatial`]: spatial observation maps (the view as a grid of sectors).
//! * [`tables`]: lazily cached per-scene state tables (observations, BFS goal distances).
//! * [`reward`], [`metrics`]: rewards (Sec. 5.1) and SR/SPL/EPA/DTS.
//! * [`world`]: the [`World`] (loading, episodes, training sampler).
//! * [`env`](mod@env): one episode ([`Env`]).
//! * [`synthetic`]: the built-in demo world.
//! * [`offline`]: the AI2THOR offline data of SAVN/GMAN (real ResNet18 feature maps) as a
//!   world source (HDF5 behind the `offline` feature).

#![warn(missing_docs)]
#![forbid(unsafe_code)]

pub mod catalog;
pub mod data;
pub mod env;
pub mod features;
pub mod fingerprint;
pub mod geometry;
pub mod metrics;
pub mod offline;
pub mod reward;
pub mod scene;
pub mod spatial;
pub mod synthetic;
pub mod tables;
pub mod types;
pub mod util;
pub mod world;

pub use env::{Env, EpisodeLimits, OracleView, StepOutcome};
pub use metrics::{mean_interval, wilson_interval, EpisodeMetrics, EpisodeResult, Summary};
pub use reward::RewardKind;
pub use tables::{InView, Observation};
pub use types::{
    AgentState, Category, CategoryId, ObjectLayout, RoomType, SceneId, Split, TargetKind,
};
pub use world::{DominantView, EpisodeSpec, World, WorldSource, DEFAULT_WORLD_SEED};
