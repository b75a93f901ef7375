//! One navigation episode: `observe`, `step`, rewards and end-of-episode metrics.
//!
//! A step is a few table lookups: successor, observation, goal distance (all cached per scene
//! in [`crate::World`]).

use gman_core::Action;

use super::geometry::VISIBILITY_DISTANCE;
use super::metrics::{spl, EpisodeMetrics};
use super::reward::{done_reward, jaccard, step_reward, RewardKind};
use super::scene::Scene;
use super::tables::{GoalTable, Observation, SceneTables, UNREACHABLE};
use super::types::{AgentState, CategoryId, RoomType, SceneId, STATES_PER_POSITION};
use super::world::{EpisodeSpec, World};

/// Default step limits: 200 in living rooms, 100 elsewhere (reference evaluation).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct EpisodeLimits {
    /// Limit in living rooms.
    pub living_room: u32,
    /// Limit in kitchens, bedrooms and bathrooms.
    pub other: u32,
}

impl Default for EpisodeLimits {
    fn default() -> Self {
        EpisodeLimits {
            living_room: 200,
            other: 100,
        }
    }
}

impl EpisodeLimits {
    /// Step limit of a room type.
    pub fn for_room(&self, room: RoomType) -> u32 {
        if room == RoomType::LivingRoom {
            self.living_room
        } else {
            self.other
        }
    }
}

/// Result of one [`Env::step`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct StepOutcome {
    /// Reward of the step.
    pub reward: f32,
    /// The episode is over (Done issued or step limit reached).
    pub done: bool,
    /// The episode ended with a successful Done.
    pub success: bool,
    /// The action changed the state (false for a blocked move, a no-op look or Done).
    pub moved: bool,
}

/// Everything an oracle may know about the current state (for scripted and imitation agents).
#[derive(Clone, Copy, Debug)]
pub struct OracleView<'a> {
    tables: &'a SceneTables,
    goal: &'a GoalTable,
    state: usize,
}

impl<'a> OracleView<'a> {
    /// Fewest actions (Done excluded) to a state where the target is visible, `None` if
    /// unreachable.
    pub fn steps_to_goal(&self) -> Option<u32> {
        let d = self.goal.dist[self.state];
        (d != UNREACHABLE).then_some(d as u32)
    }

    /// True if the target is visible now (Done would succeed).
    pub fn goal_visible(&self) -> bool {
        self.goal.dist[self.state] == 0
    }

    /// Actions on a shortest path to a goal-visible state (`[Done]` when already there; empty
    /// when unreachable), in action order.
    pub fn optimal_actions(&self) -> Vec<Action> {
        let d = self.goal.dist[self.state];
        if d == 0 {
            return vec![Action::Done];
        }
        if d == UNREACHABLE {
            return Vec::new();
        }
        Action::ALL[..Action::Done.index()]
            .iter()
            .copied()
            .filter(|a| self.goal.dist[self.tables.next[self.state][a.index()] as usize] == d - 1)
            .collect()
    }

    /// The first of [`OracleView::optimal_actions`] (Done if the goal is unreachable).
    pub fn optimal_action(&self) -> Action {
        self.optimal_actions()
            .first()
            .copied()
            .unwrap_or(Action::Done)
    }

    /// Horizontal distance (metres) to the nearest goal instance's footprint.
    pub fn distance_to_goal(&self) -> f32 {
        self.goal.meters[self.state / STATES_PER_POSITION]
    }
}

/// One episode in progress.
#[derive(Clone, Debug)]
pub struct Env<'w> {
    world: &'w World,
    scene_id: SceneId,
    scene: &'w Scene,
    tables: &'w SceneTables,
    goal: &'w GoalTable,
    target: CategoryId,
    reward_kind: RewardKind,
    max_steps: u32,
    state: usize,
    start_state: usize,
    steps: u32,
    done: bool,
    success: bool,
    done_called: bool,
    first_visible: Option<u32>,
    total_reward: f32,
    visited: Vec<u64>,
    visited_count: u32,
    trajectory: Vec<AgentState>,
    record: bool,
}

impl<'w> Env<'w> {
    /// Starts `spec` in `world`. Panics if `spec` does not belong to `world` (scene id or
    /// start state invalid); specs from [`World::episodes`] and
    /// [`World::sample_train_episode`] always do.
    pub fn new(
        world: &'w World,
        spec: &EpisodeSpec,
        reward_kind: RewardKind,
        max_steps: u32,
    ) -> Env<'w> {
        let scene = &world.scenes[spec.scene];
        let tables = world.tables(spec.scene);
        let goal = world.goal_table(spec.scene, spec.target);
        let state = scene
            .state_index(spec.start)
            .expect("episode start is not a reachable state of its scene");
        let words = scene.positions.len().div_ceil(64);
        let mut env = Env {
            world,
            scene_id: spec.scene,
            scene,
            tables,
            goal,
            target: spec.target,
            reward_kind,
            max_steps,
            state,
            start_state: state,
            steps: 0,
            done: false,
            success: false,
            done_called: false,
            first_visible: None,
            total_reward: 0.0,
            visited: vec![0; words],
            visited_count: 0,
            trajectory: Vec::new(),
            record: false,
        };
        env.visit(state);
        env.note_visible();
        env
    }

    /// Records the step at which the target first became visible.
    fn note_visible(&mut self) {
        if self.first_visible.is_none() && self.goal.dist[self.state] == 0 {
            self.first_visible = Some(self.steps);
        }
    }

    /// Keep the list of visited states (for drawing paths); off by default.
    pub fn record_trajectory(&mut self, on: bool) {
        self.record = on;
        self.trajectory.clear();
        if on {
            self.trajectory.push(self.scene.state(self.state));
        }
    }

    /// States visited so far (start included) when recording is on.
    pub fn trajectory(&self) -> &[AgentState] {
        &self.trajectory
    }

    #[inline]
    fn visit(&mut self, state: usize) {
        let p = state / STATES_PER_POSITION;
        let (w, b) = (p / 64, p % 64);
        if self.visited[w] & (1 << b) == 0 {
            self.visited[w] |= 1 << b;
            self.visited_count += 1;
        }
    }

    /// Observation of the current state (cached; no computation).
    #[inline]
    pub fn observe(&self) -> &'w Observation {
        &self.tables.obs[self.state]
    }

    /// The spatial map of the current state (`grid` sectors) into `out` (`grid.len()`
    /// floats; computed on demand, see [`crate::spatial`]).
    pub fn observe_map(&self, grid: crate::spatial::MapGrid, out: &mut [f32]) {
        self.world.view_map(self.scene_id, self.state, grid, out);
    }

    /// Oracle knowledge of the current state.
    pub fn oracle(&self) -> OracleView<'w> {
        OracleView {
            tables: self.tables,
            goal: self.goal,
            state: self.state,
        }
    }

    /// Current agent state.
    pub fn agent_state(&self) -> AgentState {
        self.scene.state(self.state)
    }

    /// Current state index.
    pub fn state_index(&self) -> usize {
        self.state
    }

    /// Actions taken so far.
    pub fn steps(&self) -> u32 {
        self.steps
    }

    /// True once the episode is over.
    pub fn is_done(&self) -> bool {
        self.done
    }

    /// The scene of the episode.
    pub fn scene(&self) -> &'w Scene {
        self.scene
    }

    /// The world of the episode.
    pub fn world(&self) -> &'w World {
        self.world
    }

    #[inline]
    fn meters(&self, state: usize) -> f32 {
        self.goal.meters[state / STATES_PER_POSITION]
    }

    /// Best Jaccard similarity between the target and the visible categories (0 if none).
    pub fn similarity_now(&self) -> f32 {
        let t = self.world.attributes(self.target);
        self.observe()
            .visible
            .iter()
            .map(|&c| jaccard(t, self.world.attributes(c)))
            .fold(0.0, f32::max)
    }

    /// Takes `action`. After the episode is over, further steps return a zero-reward
    /// `done` outcome and change nothing.
    pub fn step(&mut self, action: Action) -> StepOutcome {
        if self.done {
            return StepOutcome {
                reward: 0.0,
                done: true,
                success: self.success,
                moved: false,
            };
        }
        self.steps += 1;
        let (reward, moved) = if action == Action::Done {
            self.done = true;
            self.done_called = true;
            self.success = self.observe().is_visible(self.target);
            let sim = if self.reward_kind.has_similarity() && !self.success {
                self.similarity_now()
            } else {
                0.0
            };
            (done_reward(self.reward_kind, self.success, sim), false)
        } else {
            let next = self.tables.next[self.state][action.index()] as usize;
            let r = step_reward(self.reward_kind, self.meters(self.state), self.meters(next));
            let moved = next != self.state;
            self.state = next;
            self.visit(next);
            self.note_visible();
            if self.record {
                self.trajectory.push(self.scene.state(next));
            }
            (r, moved)
        };
        if self.steps >= self.max_steps {
            self.done = true;
        }
        self.total_reward += reward;
        StepOutcome {
            reward,
            done: self.done,
            success: self.success,
            moved,
        }
    }

    /// Metrics of the episode so far (final once [`Env::is_done`]).
    pub fn metrics(&self) -> EpisodeMetrics {
        let d = self.goal.dist[self.start_state];
        let shortest = (d != UNREACHABLE).then_some(d as u32 + 1);
        let m = self.meters(self.state);
        EpisodeMetrics {
            success: self.success,
            path_length: self.steps,
            shortest_path_length: shortest,
            spl: spl(self.success, self.steps, shortest),
            epa: 100.0 * self.visited_count as f32 / self.scene.positions.len() as f32,
            dts: if m.is_finite() {
                (m - VISIBILITY_DISTANCE).max(0.0)
            } else {
                0.0
            },
            total_reward: self.total_reward,
            done_called: self.done_called,
            target_first_visible: self.first_visible,
        }
    }
}
