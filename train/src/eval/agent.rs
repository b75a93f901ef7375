//! The evaluation agent: a trained model (checkpoint or blob) behind the simulator's
//! [`Agent`] trait, running gman-core's navigator exactly as the device does, one
//! [`Agent::act`] per step.
//!
//! The agent owns its navigator: the navigator owns its arena (a `Vec<f32>`, gman-core's
//! storage parameter) and reads the weights of the model the agent holds; the pair lives
//! in one self-referential cell. Each episode gets a fresh navigator over the same arena
//! with the device's schedule (inner update inside `step`), so D starts from the model's ω
//! in every episode and results depend neither on episode order nor on worker count. A
//! navigator error (at the start or in a step) ends the episode with Done and is reported
//! through [`Agent::take_error`].

use std::sync::Arc;

use anyhow::{anyhow, Result};
use gman_core::navigator::{Efficient, Full, Mode, Navigator};
use gman_core::Action;

use crate::model::episode::{begin_on, eval_mode_is_efficient, map_grid, ps_input};
use crate::model::{NavModel, K};
use crate::pretrain::ps::PsBuffers;
use crate::sim::{Agent, Env, TargetInfo};

/// A navigator that owns its arena, in the model's adaptation mode.
enum EvalNav<'m> {
    Efficient(Navigator<'m, Efficient, K, Vec<f32>>),
    Full(Navigator<'m, Full, K, Vec<f32>>),
}

impl<'m> EvalNav<'m> {
    /// A navigator over `model`'s weights (a blob's in place) and `arena`, started on the
    /// episode towards `target`.
    fn start(model: &'m NavModel, arena: Vec<f32>, env: &Env<'_>, t: &TargetInfo) -> Result<Self> {
        fn make<'m, M: Mode>(
            model: &'m NavModel,
            arena: Vec<f32>,
            env: &Env<'_>,
            t: &TargetInfo,
        ) -> Result<Navigator<'m, M, K, Vec<f32>>> {
            let mut nav =
                Navigator::with_storage(model.weights()?, arena, model.nav_config(false))?;
            begin_on(
                &mut nav,
                env.world(),
                t.scene,
                t.category,
                t.episode_seed,
                model,
            )?;
            Ok(nav)
        }
        Ok(if eval_mode_is_efficient(model) {
            EvalNav::Efficient(make(model, arena, env, t)?)
        } else {
            EvalNav::Full(make(model, arena, env, t)?)
        })
    }

    fn into_storage(self) -> Vec<f32> {
        match self {
            EvalNav::Efficient(n) => n.into_storage(),
            EvalNav::Full(n) => n.into_storage(),
        }
    }

    fn step(&mut self, obs: &[f32], map: &[f32], ps: &[f32]) -> gman_core::Result<Action> {
        Ok(match self {
            EvalNav::Efficient(n) => n.step_map(obs, map, ps)?.action,
            EvalNav::Full(n) => n.step_map(obs, map, ps)?.action,
        })
    }
}

/// The model and the navigator over it, in one value.
#[ouroboros::self_referencing]
struct Held {
    model: Arc<NavModel>,
    #[borrows(model)]
    #[not_covariant]
    nav: Option<EvalNav<'this>>,
}

/// A navigator agent for evaluation.
pub struct NavAgent {
    held: Held,
    /// The arena between episodes (the navigator's while one runs).
    arena: Vec<f32>,
    /// PS activations.
    ps: Option<PsBuffers>,
    /// The spatial map of the current step (empty for a model without a map).
    map: Vec<f32>,
    /// Errors met (episodes ended early by a navigator error).
    pub errors: usize,
    last_error: Option<String>,
}

impl NavAgent {
    /// An agent over a shared model.
    pub fn new(model: Arc<NavModel>) -> NavAgent {
        NavAgent {
            arena: vec![0.0; model.arena_len()],
            ps: model.ps.as_ref().map(|p| PsBuffers::new(p.hidden)),
            map: vec![0.0; model.dims.map_len()],
            held: Held::new(model, |_| None),
            errors: 0,
            last_error: None,
        }
    }

    fn fail(&mut self, e: anyhow::Error) {
        self.errors += 1;
        self.last_error = Some(format!("{e:#}"));
    }

    /// One step of the navigator on what `env` shows; `None` without a navigator.
    fn step(&mut self, env: &Env<'_>) -> Option<Result<Action>> {
        let NavAgent { held, ps, map, .. } = self;
        held.with_mut(|f| {
            let nav = f.nav.as_mut()?;
            let obs = env.observe();
            let grid = map_grid(f.model);
            if !grid.is_empty() {
                env.observe_map(grid, map);
            }
            Some(ps_input(f.model, ps, &obs.features).and_then(|p| {
                nav.step(&obs.features, map, &p)
                    .map_err(|e| anyhow!("navigator: {e}"))
            }))
        })
    }
}

impl Agent for NavAgent {
    fn begin_episode(&mut self, env: &Env<'_>, target: &TargetInfo) {
        let NavAgent { held, arena, .. } = self;
        let started = held.with_mut(|f| {
            // The arena back from the last episode's navigator.
            if let Some(nav) = f.nav.take() {
                *arena = nav.into_storage();
            }
            let a = std::mem::take(arena);
            EvalNav::start(f.model, a, env, target).map(|nav| *f.nav = Some(nav))
        });
        if let Err(e) = started {
            // The arena went with the failed navigator; a fresh one for the next episode.
            self.arena = vec![0.0; self.held.borrow_model().arena_len()];
            self.fail(e);
        }
    }

    fn act(&mut self, env: &Env<'_>) -> Action {
        match self.step(env) {
            Some(Ok(a)) => a,
            Some(Err(e)) => {
                // The episode ends here (Done); the next one starts a new navigator.
                self.fail(e);
                let NavAgent { held, arena, .. } = self;
                held.with_nav_mut(|n| {
                    if let Some(nav) = n.take() {
                        *arena = nav.into_storage();
                    }
                });
                Action::Done
            }
            // No navigator (it failed to start): the episode ends at once.
            None => Action::Done,
        }
    }

    fn take_error(&mut self) -> Option<String> {
        self.last_error.take()
    }
}
