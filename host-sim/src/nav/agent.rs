//! The evaluation agent: a trained model (checkpoint or blob) behind the simulator's
//! [`Agent`] trait, running gman-core's navigator exactly as the device does.

use std::sync::Arc;

use gman_core::Action;

use super::model::NavModel;
use super::rollout::{eval_episode, Worker};
use crate::sim::{Agent, Env, EpisodeSpec, Observation, OracleView, TargetInfo};

/// A navigator agent for evaluation.
pub struct NavAgent {
    model: Arc<NavModel>,
    worker: Worker,
    /// Errors met (episodes ended early by a navigator error).
    pub errors: usize,
    last_error: Option<String>,
}

impl NavAgent {
    /// An agent over a shared model.
    pub fn new(model: Arc<NavModel>) -> NavAgent {
        let worker = Worker::new(&model);
        NavAgent {
            model,
            worker,
            errors: 0,
            last_error: None,
        }
    }
}

impl Agent for NavAgent {
    fn begin_episode(&mut self, _target: &TargetInfo) {}

    fn act(&mut self, _obs: &Observation, _oracle: &OracleView<'_>) -> Action {
        // Never called: `run_episode` drives the whole episode.
        Action::Done
    }

    fn run_episode(&mut self, env: &mut Env<'_>, spec: &EpisodeSpec) {
        if let Err(e) = eval_episode(env, spec, &self.model, &mut self.worker) {
            self.errors += 1;
            self.last_error = Some(format!("{e:#}"));
        }
    }

    fn take_error(&mut self) -> Option<String> {
        self.last_error.take()
    }
}
