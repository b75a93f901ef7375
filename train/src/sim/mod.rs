//! The simulator: the gman-sim crate (world, features, episodes, rewards, metrics, the offline
//! reader) re-exported whole, with what it leaves to the host: [`eval`], the agents and the
//! parallel evaluator (rayon, progress through [`crate::progress`]). Top-down maps of scenes
//! are the gman-render crate's.

pub use gman_sim::*;

pub mod eval;

pub use eval::{
    evaluate, Agent, EvalConfig, EvalReport, OracleAgent, OtherTargetAgent, RandomAgent, TargetInfo,
};
