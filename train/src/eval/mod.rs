//! Evaluation of a trained model: [`agent::NavAgent`], the model behind the simulator's
//! [`Agent`](crate::sim::Agent) trait, one navigator step per simulator step with the
//! device's schedule. The episode loop and the metrics are the simulator's
//! ([`crate::sim::evaluate`]).

pub mod agent;
