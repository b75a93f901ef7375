//! The simulator: the gman-sim crate (world, features, episodes, rewards, metrics, the offline
//! reader) re-exported whole, with what it leaves to the host: [`eval`], the agents and the
//! parallel evaluator (rayon, a progress bar), and [`render`], top-down PNG maps (plotters).

pub use gman_sim::*;

pub mod eval;
pub mod render;

pub use eval::{
    evaluate, Agent, EvalConfig, EvalReport, OracleAgent, OtherTargetAgent, RandomAgent, TargetInfo,
};
