//! Agents and the parallel evaluator.
//!
//! The evaluator runs a list of episodes on a rayon pool; each worker owns one [`Agent`] made
//! by a factory closure (so a neural navigator with private state plugs in), and pulls episodes
//! from a shared counter. Results come back in episode order, independent of scheduling.

use std::collections::BTreeMap;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::Mutex;

use gman_core::{Action, ATTR_DIM, NUM_ACTIONS};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;
use serde::Serialize;

use super::env::{Env, EpisodeLimits};
use super::metrics::{EpisodeResult, Summary};
use super::reward::RewardKind;
use super::types::{CategoryId, RoomType, SceneId, TargetKind};
use super::util::hash2;
use super::world::{EpisodeSpec, World};
use crate::progress::BarKind;

/// What an agent is told at the start of an episode.
#[derive(Clone, Debug)]
pub struct TargetInfo {
    /// Target category.
    pub category: CategoryId,
    /// Target name.
    pub name: String,
    /// Semantic embedding SE(target).
    pub attributes: [f32; ATTR_DIM],
    /// Seen or unseen target.
    pub kind: TargetKind,
    /// Room type.
    pub room: RoomType,
    /// Scene.
    pub scene: SceneId,
    /// Per-episode seed (deterministic regardless of the worker that runs it).
    pub episode_seed: u64,
}

impl TargetInfo {
    /// Target info of an episode.
    pub fn of(world: &World, spec: &EpisodeSpec) -> TargetInfo {
        TargetInfo {
            category: spec.target,
            name: world.category_name(spec.target).to_string(),
            attributes: *world.attributes(spec.target),
            kind: spec.kind,
            room: spec.room,
            scene: spec.scene,
            episode_seed: spec.seed,
        }
    }
}

/// A navigation policy.
pub trait Agent {
    /// Called before the first step of every episode in `env` (whose world holds what a
    /// diagnostic agent may be given besides `target`, e.g. the target's true feature in the
    /// scene for the privileged-feature bound).
    fn begin_episode(&mut self, env: &Env<'_>, target: &TargetInfo);
    /// Chooses the next action in `env`'s current state. What an agent senses:
    /// [`Env::observe`] and [`Env::observe_map`]; [`Env::oracle`] is ground truth for
    /// scripted agents, which learned agents must not read.
    fn act(&mut self, env: &Env<'_>) -> Action;
    /// Runs a whole episode in `env`: [`Agent::begin_episode`], then [`Agent::act`] and a
    /// step until the episode ends (the per-step loop every agent here runs; an agent
    /// driving a whole episode elsewhere, e.g. through the C API, may override it).
    fn run_episode(&mut self, env: &mut Env<'_>, spec: &EpisodeSpec) {
        self.begin_episode(env, &TargetInfo::of(env.world(), spec));
        while !env.is_done() {
            let a = self.act(env);
            env.step(a);
        }
    }
    /// The error that ended the last episode early, if any (taken: a second call returns
    /// `None`). The evaluator records it in [`EpisodeResult::error`]; agents that cannot fail
    /// keep this default.
    fn take_error(&mut self) -> Option<String> {
        None
    }
}

/// A probe of what an agent does with the target's attributes: runs `inner` on every episode
/// as if the target were [`other_target`] (another evaluation target of the same room type and
/// kind: its attributes, name and category are what the agent is given), while success is
/// still judged on the episode's true target. An agent whose success rate does not drop under
/// it does not use the target input (`gman eval --target-input other`).
pub struct OtherTargetAgent {
    inner: Box<dyn Agent + Send>,
}

impl OtherTargetAgent {
    /// Wraps `inner`.
    pub fn new(inner: Box<dyn Agent + Send>) -> OtherTargetAgent {
        OtherTargetAgent { inner }
    }
}

impl Agent for OtherTargetAgent {
    fn begin_episode(&mut self, env: &Env<'_>, target: &TargetInfo) {
        self.inner.begin_episode(env, target)
    }
    fn act(&mut self, env: &Env<'_>) -> Action {
        self.inner.act(env)
    }
    fn run_episode(&mut self, env: &mut Env<'_>, spec: &EpisodeSpec) {
        let mut other = spec.clone();
        other.target = other_target(env.world(), spec);
        self.inner.run_episode(env, &other)
    }
    fn take_error(&mut self) -> Option<String> {
        self.inner.take_error()
    }
}

/// The next evaluation target after `spec`'s in its room type's list of the same kind (seen
/// or unseen), wrapping around; the room's targets of the other kind when the list has one
/// category only; the target itself when the room has no other target at all.
pub fn other_target(world: &World, spec: &EpisodeSpec) -> CategoryId {
    let (seen, unseen) = &world.eval_targets[spec.room.index()];
    let (same, rest) = match spec.kind {
        TargetKind::Seen => (seen, unseen),
        TargetKind::Unseen => (unseen, seen),
    };
    let pick = |list: &Vec<CategoryId>| {
        let i = list.iter().position(|&c| c == spec.target)?;
        (list.len() > 1).then(|| list[(i + 1) % list.len()])
    };
    pick(same)
        .or_else(|| rest.first().copied().filter(|&c| c != spec.target))
        .unwrap_or(spec.target)
}

/// A factory of agents, called once per evaluation worker with the worker index.
pub type AgentFactory = Box<dyn Fn(usize) -> Box<dyn Agent + Send> + Sync>;

/// Uniformly random over the six actions; seeded per episode.
#[derive(Clone, Debug)]
pub struct RandomAgent {
    seed: u64,
    rng: ChaCha8Rng,
}

impl RandomAgent {
    /// A random agent whose choices depend on `seed` and the episode seed.
    pub fn new(seed: u64) -> RandomAgent {
        RandomAgent {
            seed,
            rng: ChaCha8Rng::seed_from_u64(seed),
        }
    }
}

impl Agent for RandomAgent {
    fn begin_episode(&mut self, _env: &Env<'_>, target: &TargetInfo) {
        self.rng = ChaCha8Rng::seed_from_u64(hash2(self.seed, target.episode_seed));
    }
    fn act(&mut self, _env: &Env<'_>) -> Action {
        Action::ALL[self.rng.random_range(0..NUM_ACTIONS)]
    }
}

/// Follows a shortest path to the nearest goal-visible state, then issues Done.
#[derive(Clone, Copy, Debug, Default)]
pub struct OracleAgent;

impl Agent for OracleAgent {
    fn begin_episode(&mut self, _env: &Env<'_>, _target: &TargetInfo) {}
    fn act(&mut self, env: &Env<'_>) -> Action {
        env.oracle().optimal_action()
    }
}

/// Evaluation settings.
#[derive(Clone, Copy, Debug, Default)]
pub struct EvalConfig {
    /// Reward paid during evaluation (only affects `total_reward`).
    pub reward: RewardKind,
    /// Step limits.
    pub limits: EpisodeLimits,
    /// Show a progress bar on stderr.
    pub progress: bool,
}

/// Runs one episode with `agent`; returns the finished environment.
pub fn run_episode<'w>(
    world: &'w World,
    spec: &EpisodeSpec,
    agent: &mut dyn Agent,
    cfg: &EvalConfig,
) -> Env<'w> {
    let mut env = Env::new(world, spec, cfg.reward, cfg.limits.for_room(spec.room));
    drive(&mut env, spec, agent);
    env
}

/// Runs `agent` on a freshly created `env` of `spec` until the episode ends.
pub fn drive(env: &mut Env<'_>, spec: &EpisodeSpec, agent: &mut dyn Agent) {
    agent.run_episode(env, spec);
}

/// Evaluates `episodes`, one agent per rayon worker made by `factory(worker_index)` (as many
/// workers as the rayon pool has threads: every core by default). The results are in episode
/// order and, for agents whose episodes depend only on the episode (seeded per episode, like
/// every agent here), identical whatever the number of threads.
pub fn evaluate<F>(
    world: &World,
    episodes: &[EpisodeSpec],
    factory: F,
    cfg: &EvalConfig,
) -> Vec<EpisodeResult>
where
    F: Fn(usize) -> Box<dyn Agent + Send> + Sync,
{
    let next = AtomicUsize::new(0);
    let bar = crate::progress::bar(BarKind::Eval, episodes.len() as u64, cfg.progress);
    let out: Mutex<Vec<Option<EpisodeResult>>> = Mutex::new(vec![None; episodes.len()]);
    let workers = rayon::current_num_threads().max(1);
    (0..workers).into_par_iter().for_each(|w| {
        let mut agent = factory(w);
        let mut local = Vec::new();
        loop {
            let i = next.fetch_add(1, Ordering::Relaxed);
            if i >= episodes.len() {
                break;
            }
            let spec = &episodes[i];
            let env = run_episode(world, spec, agent.as_mut(), cfg);
            let error = agent.take_error();
            local.push(EpisodeResult {
                index: i,
                scene: world.scenes[spec.scene].name.clone(),
                room: spec.room,
                kind: spec.kind,
                target: world.category_name(spec.target).to_string(),
                metrics: env.metrics(),
                error,
            });
            bar.inc(1);
        }
        let mut o = out.lock().expect("result lock");
        for r in local {
            let i = r.index;
            o[i] = Some(r);
        }
    });
    bar.finish();
    out.into_inner()
        .expect("result lock")
        .into_iter()
        .map(|r| r.expect("every episode evaluated"))
        .collect()
}

/// Seen/unseen summaries.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
pub struct KindSummaries {
    /// Seen targets.
    pub seen: Summary,
    /// Unseen targets.
    pub unseen: Summary,
}

impl KindSummaries {
    /// Summaries of `results` split by target kind.
    pub fn of<'a>(results: impl IntoIterator<Item = &'a EpisodeResult> + Clone) -> KindSummaries {
        KindSummaries {
            seen: Summary::of(
                results
                    .clone()
                    .into_iter()
                    .filter(|r| r.kind == TargetKind::Seen)
                    .map(|r| &r.metrics),
            ),
            unseen: Summary::of(
                results
                    .into_iter()
                    .filter(|r| r.kind == TargetKind::Unseen)
                    .map(|r| &r.metrics),
            ),
        }
    }
}

/// A failed episode of an [`EvalReport`].
#[derive(Clone, Debug, Serialize)]
pub struct EpisodeFailure {
    /// Index in the evaluated episode list.
    pub index: usize,
    /// Scene name.
    pub scene: String,
    /// The error.
    pub error: String,
}

/// The JSON report of `gman eval`.
#[derive(Clone, Debug, Serialize)]
pub struct EvalReport {
    /// Split name.
    pub split: String,
    /// Agent name.
    pub agent: String,
    /// Number of episodes.
    pub episodes: usize,
    /// Episodes the agent could not run to their end (navigator errors); they are counted in
    /// the metrics as they ended. Non-zero makes `gman eval` exit with an error.
    pub failed_episodes: usize,
    /// The first (at most 10) failed episodes: index in the evaluated list and the error.
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub failures: Vec<EpisodeFailure>,
    /// Seen/unseen summaries (SR, SPL, EPA in percent, DTS in metres).
    pub results: KindSummaries,
    /// The same per room type.
    pub by_room: BTreeMap<String, KindSummaries>,
}

impl EvalReport {
    /// Aggregates per-episode results.
    pub fn new(split: &str, agent: &str, results: &[EpisodeResult]) -> EvalReport {
        let mut by_room = BTreeMap::new();
        for room in RoomType::ALL {
            let rs: Vec<&EpisodeResult> = results.iter().filter(|r| r.room == room).collect();
            if !rs.is_empty() {
                by_room.insert(
                    room.name().to_string(),
                    KindSummaries::of(rs.iter().copied()),
                );
            }
        }
        let failed: Vec<&EpisodeResult> = results.iter().filter(|r| r.error.is_some()).collect();
        EvalReport {
            split: split.to_string(),
            agent: agent.to_string(),
            episodes: results.len(),
            failed_episodes: failed.len(),
            failures: failed
                .iter()
                .take(10)
                .map(|r| EpisodeFailure {
                    index: r.index,
                    scene: r.scene.clone(),
                    error: r.error.clone().unwrap_or_default(),
                })
                .collect(),
            results: KindSummaries::of(results.iter()),
            by_room,
        }
    }

    /// The table in the paper's layout (Tab. 4): unseen then seen, SR/SPL/EPA/DTS. The first
    /// column widens to the agent's name (a model file's path keeps the columns aligned).
    pub fn table(&self) -> String {
        let mut s = String::new();
        let head = format!("{} ({})", "Method", self.split);
        let w = self
            .by_room
            .keys()
            .map(|r| r.len() + 2)
            .chain([22, self.agent.chars().count(), head.len()])
            .max()
            .unwrap_or(22);
        s.push_str(&format!(
            "{:<w$} | {:^30} | {:^30}\n",
            head, "Unseen Objects", "Seen Objects"
        ));
        s.push_str(&format!(
            "{:<w$} | {:>6} {:>7} {:>7} {:>7} | {:>6} {:>7} {:>7} {:>7}\n",
            "", "SR(%)", "SPL(%)", "EPA(%)", "DTS(m)", "SR(%)", "SPL(%)", "EPA(%)", "DTS(m)"
        ));
        let row = |name: &str, k: &KindSummaries| {
            format!(
                "{:<w$} | {:>6.2} {:>7.2} {:>7.2} {:>7.2} | {:>6.2} {:>7.2} {:>7.2} {:>7.2}\n",
                name,
                k.unseen.sr,
                k.unseen.spl,
                k.unseen.epa,
                k.unseen.dts,
                k.seen.sr,
                k.seen.spl,
                k.seen.epa,
                k.seen.dts
            )
        };
        s.push_str(&row(&self.agent, &self.results));
        for (room, k) in &self.by_room {
            s.push_str(&row(&format!("  {room}"), k));
        }
        s.push_str(&format!(
            "({} episodes: {} unseen, {} seen)\n",
            self.episodes, self.results.unseen.episodes, self.results.seen.episodes
        ));
        if self.failed_episodes > 0 {
            s.push_str(&format!(
                "FAILED: {} of {} episodes ended early with an error (counted above as they ended); first: episode {} ({}): {}\n",
                self.failed_episodes,
                self.episodes,
                self.failures.first().map_or(0, |f| f.index),
                self.failures.first().map_or("", |f| f.scene.as_str()),
                self.failures.first().map_or("", |f| f.error.as_str()),
            ));
        }
        s
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sim::metrics::EpisodeMetrics;

    #[test]
    fn table_columns_stay_aligned_with_a_long_agent_name() {
        let r = |room, kind| EpisodeResult {
            index: 0,
            scene: "FloorPlan22".into(),
            room,
            kind,
            target: "Mug".into(),
            metrics: EpisodeMetrics {
                success: true,
                path_length: 4,
                shortest_path_length: Some(2),
                spl: 0.5,
                epa: 10.0,
                dts: 0.0,
                total_reward: 0.0,
                done_called: true,
                target_first_visible: Some(2),
            },
            error: None,
        };
        let results = [
            r(RoomType::Kitchen, TargetKind::Seen),
            r(RoomType::LivingRoom, TargetKind::Unseen),
        ];
        let agent = "runs/some/long/path/to/a/model/checkpoint.ckpt";
        let t = EvalReport::new("val", agent, &results).table();
        let bars: Vec<Vec<usize>> = t
            .lines()
            .filter(|l| l.contains('|'))
            .map(|l| l.match_indices('|').map(|(i, _)| i).collect())
            .collect();
        assert!(bars.len() >= 4, "{t}");
        assert!(bars.iter().all(|b| *b == bars[0]), "{t}");
        assert!(t.contains(agent));
    }
}
