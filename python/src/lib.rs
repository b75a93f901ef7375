//! `gman._gman`: the native half of the `gman` Python package.
//!
//! A thin layer over the host crate's public API: [`VecCore`] steps a batch of
//! [`gman_train::sim::Env`]s with the GIL released and writes observations, rewards and
//! flags into numpy arrays it owns (allocated once); [`PyNavigator`] runs gman-core's
//! navigator over a weight blob exactly as `gman eval` does; [`host_evaluate`] is
//! `gman eval`'s evaluator. The Python wrapper (`gman/__init__.py`) adds gymnasium's classes
//! and the argument checks with Python-level messages.

use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex, OnceLock};

use gman_core::navigator::{Efficient, Full, Navigator};
use gman_core::{Action, ATTR_DIM, FEATURE_DIM, NUM_ACTIONS};
use gman_render::draw_scene_rgb;
use gman_train::eval::agent::NavAgent;
use gman_train::model::{load_model, model_from_blob, NavModel, K};
use gman_train::sim::eval::AgentFactory;
use gman_train::sim::features::DomainShift;
use gman_train::sim::spatial::{check_grid, check_grid_for_world, MapGrid, MAX_GRID_SIDE};
use gman_train::sim::{
    evaluate, Env, EpisodeLimits, EpisodeMetrics, EpisodeResult, EpisodeSpec, EvalConfig,
    EvalReport, OracleAgent, RandomAgent, RewardKind, Split, World,
};
use numpy::{Element, PyArray1, PyArray2, PyArray3, PyArrayMethods, PyReadonlyArray1};
use pyo3::exceptions::{PyFileNotFoundError, PyMemoryError, PyRuntimeError, PyValueError};
use pyo3::prelude::*;
use pyo3::types::{PyBytes, PyDict};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

fn borrow_err(e: numpy::BorrowError) -> PyErr {
    PyRuntimeError::new_err(format!(
        "an output array of the environment is borrowed elsewhere: {e}"
    ))
}

fn value_err(e: impl std::fmt::Display) -> PyErr {
    PyValueError::new_err(e.to_string())
}

/// `anyhow` chain as one message.
fn chain_err(e: anyhow::Error) -> PyErr {
    PyValueError::new_err(format!("{e:#}"))
}

/// Most environments in one batch (`num_envs`).
const MAX_ENVS: usize = 1 << 16;
/// Most floats of one batch's observation arrays, `num_envs * (512 + 2 * 45 + map cells *
/// 512)`: 2^28 floats, 1 GiB.
const MAX_BATCH_FLOATS: usize = 1 << 28;
/// Longest episode (`max_steps`): `info["steps"]` is an int32.
const MAX_STEPS: u32 = i32::MAX as u32;

/// The text of a caught panic's payload.
fn panic_text(p: &(dyn std::any::Any + Send)) -> String {
    p.downcast_ref::<&str>()
        .map(|s| s.to_string())
        .or_else(|| p.downcast_ref::<String>().cloned())
        .unwrap_or_else(|| "a panic without a message".to_string())
}

/// Runs `f`, turning a Rust panic into a `RuntimeError` naming `what`. A last resort: the
/// argument checks are meant to make every panic unreachable, so one is a bug of gman.
fn guard<T>(what: &str, f: impl FnOnce() -> PyResult<T>) -> PyResult<T> {
    std::panic::catch_unwind(std::panic::AssertUnwindSafe(f)).unwrap_or_else(|p| {
        Err(PyRuntimeError::new_err(format!(
            "{what}: internal error in gman (a Rust panic: {}); please report it",
            panic_text(p.as_ref())
        )))
    })
}

/// A zeroed vector of `n` elements, or a `MemoryError` naming `what` (instead of the abort
/// of a failed allocation).
fn try_filled<T: Clone>(n: usize, v: T, what: &str) -> PyResult<Vec<T>> {
    let mut out = Vec::new();
    out.try_reserve_exact(n)
        .map_err(|_| PyMemoryError::new_err(format!("{what}: cannot allocate {n} elements")))?;
    out.resize(n, v);
    Ok(out)
}

/// A 1-d numpy array of `n` copies of `v`, allocated fallibly (see [`try_filled`]).
fn arr1<'py, T: Element + Clone>(
    py: Python<'py>,
    n: usize,
    v: T,
    what: &str,
) -> PyResult<Bound<'py, PyArray1<T>>> {
    Ok(PyArray1::from_vec(py, try_filled(n, v, what)?))
}

/// A 2-d numpy array of `a x b` copies of `v`, allocated fallibly.
fn arr2<'py, T: Element + Clone>(
    py: Python<'py>,
    [a, b]: [usize; 2],
    v: T,
    what: &str,
) -> PyResult<Bound<'py, PyArray2<T>>> {
    let n = a.checked_mul(b).ok_or_else(|| too_large(what))?;
    arr1(py, n, v, what)?.reshape([a, b])
}

/// A 3-d numpy array of `a x b x c` copies of `v`, allocated fallibly.
fn arr3<'py, T: Element + Clone>(
    py: Python<'py>,
    [a, b, c]: [usize; 3],
    v: T,
    what: &str,
) -> PyResult<Bound<'py, PyArray3<T>>> {
    let n = a
        .checked_mul(b)
        .and_then(|n| n.checked_mul(c))
        .ok_or_else(|| too_large(what))?;
    arr1(py, n, v, what)?.reshape([a, b, c])
}

fn too_large(what: &str) -> PyErr {
    PyMemoryError::new_err(format!("{what}: the array's size overflows"))
}

/// The map grid rule of the Python argument `map` (`(0, 0)`: no map): the grid rule a
/// model's map obeys ([`check_grid`]), as a `ValueError` naming the argument.
#[pyfunction]
fn check_map(rows: usize, cols: usize) -> PyResult<()> {
    if (rows, cols) == (0, 0) {
        return Ok(());
    }
    check_grid(rows, cols, &format!("map = ({rows}, {cols})")).map_err(chain_err)
}

/// Panics inside a guarded call: the tests check that a panic surfaces as a `RuntimeError`.
#[pyfunction]
fn _panic_for_tests() -> PyResult<()> {
    guard("_panic_for_tests", || panic!("a panic raised on purpose"))
}

// ---------------------------------------------------------------------------------------
// Worlds: loaded once per (data directory, world seed) and shared for the process.
// ---------------------------------------------------------------------------------------

/// (data directory, world seed, domain shift's bits).
type WorldKey = (Option<PathBuf>, u64, u32);

fn worlds() -> &'static Mutex<HashMap<WorldKey, &'static World>> {
    static W: OnceLock<Mutex<HashMap<WorldKey, &'static World>>> = OnceLock::new();
    W.get_or_init(|| Mutex::new(HashMap::new()))
}

/// The world of `data` (None: the built-in synthetic world) and `seed`. Worlds are immutable
/// after loading (their per-scene tables are built lazily behind `OnceLock`s), so one copy
/// per key serves every environment of the process; it lives until the process ends.
fn world_of(
    py: Python<'_>,
    data: Option<&str>,
    seed: u64,
    domain_shift: f32,
) -> PyResult<&'static World> {
    let shift = DomainShift::new(domain_shift)
        .map_err(|e| value_err(format!("domain_shift = {domain_shift}: {e}")))?;
    let key: WorldKey = (
        data.map(|d| std::fs::canonicalize(d).unwrap_or_else(|_| PathBuf::from(d))),
        seed,
        shift.get().to_bits(),
    );
    if let Some(w) = worlds().lock().expect("world cache").get(&key) {
        return Ok(w);
    }
    let world = match &key.0 {
        Some(dir) => {
            if !dir.is_dir() {
                return Err(PyFileNotFoundError::new_err(format!(
                    "data directory {} does not exist",
                    dir.display()
                )));
            }
            let dir = dir.clone();
            py.detach(move || {
                let mut w = World::load_with_seed(&dir, seed)?;
                w.set_domain_shift(shift)?;
                Ok::<World, anyhow::Error>(w)
            })
            .map_err(|e| chain_err(e.context(format!("loading data {}", data.unwrap_or("")))))?
        }
        None => py
            .detach(move || {
                let mut w = World::synthetic(seed);
                w.set_domain_shift(shift).map(|()| w)
            })
            .map_err(chain_err)?,
    };
    let leaked: &'static World = Box::leak(Box::new(world));
    worlds()
        .lock()
        .expect("world cache")
        .entry(key)
        .or_insert(leaked);
    Ok(leaked)
}

fn parse_split(s: &str) -> PyResult<Split> {
    Split::parse(s).map_err(|_| {
        PyValueError::new_err(format!(
            "split must be \"train\", \"val\" or \"test\", got {s:?}"
        ))
    })
}

fn parse_reward(s: &str) -> PyResult<RewardKind> {
    s.parse::<RewardKind>().map_err(|e| {
        PyValueError::new_err(format!(
            "reward {s:?}: {e} (one of navigation, distance, similarity, mixed)"
        ))
    })
}

// ---------------------------------------------------------------------------------------
// The batched environment.
// ---------------------------------------------------------------------------------------

/// One environment slot of a batch.
struct Slot {
    env: Env<'static>,
    spec: EpisodeSpec,
    rng: ChaCha8Rng,
    /// The episode ended at the last step: the next step resets it (next-step autoreset).
    needs_reset: bool,
}

/// Simulation state of a batch (no Python objects: it runs with the GIL released).
struct Sim {
    world: &'static World,
    split: Split,
    episodes: Vec<EpisodeSpec>,
    next_episode: usize,
    reward: RewardKind,
    limits: EpisodeLimits,
    grid: MapGrid,
    oracle: bool,
    /// Slots keep their episode's states (for `render`).
    record: bool,
    slots: Vec<Slot>,
    results: Vec<Option<EpisodeResult>>,
    recorded: usize,
}

/// Mutable views of the output arrays for one call.
struct Out<'a> {
    features: &'a mut [f32],
    target: &'a mut [f32],
    ps_target: &'a mut [f32],
    map: &'a mut [f32],
    reward: &'a mut [f32],
    terminated: &'a mut [bool],
    truncated: &'a mut [bool],
    success: &'a mut [bool],
    episode_start: &'a mut [bool],
    shortest_path: &'a mut [i32],
    target_category: &'a mut [i32],
    scene: &'a mut [i32],
    episode_index: &'a mut [i64],
    episode_seed: &'a mut [u64],
    steps: &'a mut [i32],
    oracle_action: &'a mut [i64],
}

/// Slots per rayon task when a training batch is stepped in parallel (below twice this, a
/// batch steps on the calling thread).
const PAR_CHUNK: usize = 64;

/// The read-only part of a batch, shared by the threads that step it.
#[derive(Clone, Copy)]
struct Ctx {
    world: &'static World,
    split: Split,
    reward: RewardKind,
    limits: EpisodeLimits,
    grid: MapGrid,
    oracle: bool,
    record: bool,
}

/// Splits every array of an [`Out`] after `mid` slots (a map of `map_len` floats per slot).
macro_rules! split_out {
    ($o:expr, $mid:expr, $map_len:expr) => {{
        let o = $o;
        let m = $mid;
        let (features1, features2) = o.features.split_at_mut(m * FEATURE_DIM);
        let (target1, target2) = o.target.split_at_mut(m * ATTR_DIM);
        let (ps1, ps2) = o.ps_target.split_at_mut(m * ATTR_DIM);
        let (map1, map2) = o.map.split_at_mut(m * $map_len);
        macro_rules! one {
            ($f:ident) => {
                o.$f.split_at_mut(m)
            };
        }
        let (reward1, reward2) = one!(reward);
        let (te1, te2) = one!(terminated);
        let (tr1, tr2) = one!(truncated);
        let (su1, su2) = one!(success);
        let (es1, es2) = one!(episode_start);
        let (sp1, sp2) = one!(shortest_path);
        let (tc1, tc2) = one!(target_category);
        let (sc1, sc2) = one!(scene);
        let (ei1, ei2) = one!(episode_index);
        let (sd1, sd2) = one!(episode_seed);
        let (st1, st2) = one!(steps);
        let (oa1, oa2) = one!(oracle_action);
        (
            Out {
                features: features1,
                target: target1,
                ps_target: ps1,
                map: map1,
                reward: reward1,
                terminated: te1,
                truncated: tr1,
                success: su1,
                episode_start: es1,
                shortest_path: sp1,
                target_category: tc1,
                scene: sc1,
                episode_index: ei1,
                episode_seed: sd1,
                steps: st1,
                oracle_action: oa1,
            },
            Out {
                features: features2,
                target: target2,
                ps_target: ps2,
                map: map2,
                reward: reward2,
                terminated: te2,
                truncated: tr2,
                success: su2,
                episode_start: es2,
                shortest_path: sp2,
                target_category: tc2,
                scene: sc2,
                episode_index: ei2,
                episode_seed: sd2,
                steps: st2,
                oracle_action: oa2,
            },
        )
    }};
}

impl Ctx {
    fn new_env(&self, spec: &EpisodeSpec) -> Env<'static> {
        let mut env = Env::new(
            self.world,
            spec,
            self.reward,
            self.limits.for_room(spec.room),
        );
        if self.record {
            env.record_trajectory(true);
        }
        env
    }

    /// Starts `spec` in slot `s` (index `i` of `out`) and writes its per-episode outputs and
    /// the zero reward and flags of a reset.
    fn begin(&self, s: &mut Slot, spec: EpisodeSpec, i: usize, out: &mut Out<'_>) {
        let env = self.new_env(&spec);
        let m = env.metrics();
        out.target[i * ATTR_DIM..(i + 1) * ATTR_DIM]
            .copy_from_slice(self.world.attributes(spec.target));
        out.shortest_path[i] = m.shortest_path_length.map_or(-1, |s| s as i32);
        out.target_category[i] = spec.target as i32;
        out.scene[i] = spec.scene as i32;
        out.episode_index[i] = if self.split == Split::Train {
            -1
        } else {
            spec.index as i64
        };
        out.episode_seed[i] = spec.seed;
        out.episode_start[i] = true;
        out.reward[i] = 0.0;
        out.terminated[i] = false;
        out.truncated[i] = false;
        out.success[i] = false;
        s.env = env;
        s.spec = spec;
        s.needs_reset = false;
    }

    /// Takes `action` in slot `s`; the episode's metrics when it ended.
    fn act(
        &self,
        s: &mut Slot,
        action: i64,
        i: usize,
        out: &mut Out<'_>,
    ) -> Option<EpisodeMetrics> {
        let a = Action::ALL[action as usize];
        let o = s.env.step(a);
        out.reward[i] = o.reward;
        out.success[i] = o.success;
        let term = o.done && a == Action::Done;
        out.terminated[i] = term;
        out.truncated[i] = o.done && !term;
        if o.done {
            s.needs_reset = true;
            Some(s.env.metrics())
        } else {
            None
        }
    }

    /// Writes the observation of slot `s`'s current state.
    fn observe(&self, s: &Slot, i: usize, out: &mut Out<'_>) {
        let env = &s.env;
        let obs = env.observe();
        out.features[i * FEATURE_DIM..(i + 1) * FEATURE_DIM].copy_from_slice(&obs.features);
        out.ps_target[i * ATTR_DIM..(i + 1) * ATTR_DIM].copy_from_slice(&obs.ps_target);
        let len = self.grid.len();
        if len > 0 {
            env.observe_map(self.grid, &mut out.map[i * len..(i + 1) * len]);
        }
        out.steps[i] = env.steps() as i32;
        if self.oracle {
            out.oracle_action[i] = env.oracle().optimal_action().index() as i64;
        }
    }

    /// One step of training slots (each samples its own next task from its own generator,
    /// so the result does not depend on how the slots are split between threads).
    fn step_train(
        &self,
        slots: &mut [Slot],
        actions: &[i64],
        mut out: Out<'_>,
    ) -> anyhow::Result<()> {
        if slots.len() >= 2 * PAR_CHUNK {
            let mid = slots.len() / 2;
            let (s1, s2) = slots.split_at_mut(mid);
            let (a1, a2) = actions.split_at(mid);
            let (o1, o2) = split_out!(out, mid, self.grid.len());
            let (r1, r2) = rayon::join(
                || self.step_train(s1, a1, o1),
                || self.step_train(s2, a2, o2),
            );
            return r1.and(r2);
        }
        for (i, (s, &action)) in slots.iter_mut().zip(actions).enumerate() {
            out.episode_start[i] = false;
            if s.needs_reset {
                let spec = self.world.try_sample_train_episode_min(&mut s.rng, 0)?;
                self.begin(s, spec, i, &mut out);
            } else {
                self.act(s, action, i, &mut out);
            }
            self.observe(s, i, &mut out);
        }
        Ok(())
    }
}

impl Sim {
    fn ctx(&self) -> Ctx {
        Ctx {
            world: self.world,
            split: self.split,
            reward: self.reward,
            limits: self.limits,
            grid: self.grid,
            oracle: self.oracle,
            record: self.record,
        }
    }

    fn next_spec(&mut self, slot: usize) -> anyhow::Result<EpisodeSpec> {
        if self.split == Split::Train {
            self.world
                .try_sample_train_episode_min(&mut self.slots[slot].rng, 0)
        } else {
            let n = self.episodes.len();
            let spec = self.episodes[self.next_episode % n].clone();
            self.next_episode += 1;
            Ok(spec)
        }
    }

    /// Starts a new episode in slot `i` (the next official one, or a sampled task).
    fn start(&mut self, i: usize, out: &mut Out<'_>) -> anyhow::Result<()> {
        let spec = self.next_spec(i)?;
        let ctx = self.ctx();
        ctx.begin(&mut self.slots[i], spec, i, out);
        Ok(())
    }

    fn record(&mut self, i: usize, metrics: EpisodeMetrics) {
        if self.split == Split::Train {
            return;
        }
        let spec = &self.slots[i].spec;
        let idx = spec.index;
        if idx < self.results.len() && self.results[idx].is_none() {
            self.results[idx] = Some(EpisodeResult {
                index: idx,
                scene: self.world.scenes[spec.scene].name.clone(),
                room: spec.room,
                kind: spec.kind,
                target: self.world.category_name(spec.target).to_string(),
                metrics,
                error: None,
            });
            self.recorded += 1;
        }
    }

    fn reset_all(
        &mut self,
        seed: Option<u64>,
        restart: bool,
        out: &mut Out<'_>,
    ) -> anyhow::Result<()> {
        if let Some(s) = seed {
            for (i, slot) in self.slots.iter_mut().enumerate() {
                slot.rng = ChaCha8Rng::seed_from_u64(s.wrapping_add(i as u64));
            }
        }
        if restart {
            self.next_episode = 0;
            self.results = vec![None; self.episodes.len()];
            self.recorded = 0;
        }
        let ctx = self.ctx();
        for i in 0..self.slots.len() {
            self.start(i, out)?;
            ctx.observe(&self.slots[i], i, out);
        }
        Ok(())
    }

    /// One step of every slot: training batches in parallel chunks, evaluation batches in
    /// slot order (the official episodes are handed out in that order).
    fn step_all(&mut self, actions: &[i64], out: &mut Out<'_>) -> anyhow::Result<()> {
        let ctx = self.ctx();
        if self.split == Split::Train {
            let o = Out {
                features: &mut *out.features,
                target: &mut *out.target,
                ps_target: &mut *out.ps_target,
                map: &mut *out.map,
                reward: &mut *out.reward,
                terminated: &mut *out.terminated,
                truncated: &mut *out.truncated,
                success: &mut *out.success,
                episode_start: &mut *out.episode_start,
                shortest_path: &mut *out.shortest_path,
                target_category: &mut *out.target_category,
                scene: &mut *out.scene,
                episode_index: &mut *out.episode_index,
                episode_seed: &mut *out.episode_seed,
                steps: &mut *out.steps,
                oracle_action: &mut *out.oracle_action,
            };
            return ctx.step_train(&mut self.slots, actions, o);
        }
        for (i, &action) in actions.iter().enumerate() {
            out.episode_start[i] = false;
            if self.slots[i].needs_reset {
                self.start(i, out)?;
            } else if let Some(m) = ctx.act(&mut self.slots[i], action, i, out) {
                self.record(i, m);
            }
            ctx.observe(&self.slots[i], i, out);
        }
        Ok(())
    }
}

/// The numpy arrays a batch writes into (allocated once, filled in place).
struct Bufs {
    features: Py<PyArray2<f32>>,
    target: Py<PyArray2<f32>>,
    ps_target: Py<PyArray2<f32>>,
    map: Py<PyArray3<f32>>,
    reward: Py<PyArray1<f32>>,
    terminated: Py<PyArray1<bool>>,
    truncated: Py<PyArray1<bool>>,
    success: Py<PyArray1<bool>>,
    episode_start: Py<PyArray1<bool>>,
    shortest_path: Py<PyArray1<i32>>,
    target_category: Py<PyArray1<i32>>,
    scene: Py<PyArray1<i32>>,
    episode_index: Py<PyArray1<i64>>,
    episode_seed: Py<PyArray1<u64>>,
    steps: Py<PyArray1<i32>>,
    oracle_action: Py<PyArray1<i64>>,
}

/// Runs `f` over mutable views of every output array with the GIL released.
macro_rules! with_out {
    ($py:expr, $bufs:expr, |$out:ident| $body:expr) => {{
        let b = $bufs;
        let mut features = b.features.bind($py).try_readwrite().map_err(borrow_err)?;
        let mut target = b.target.bind($py).try_readwrite().map_err(borrow_err)?;
        let mut ps_target = b.ps_target.bind($py).try_readwrite().map_err(borrow_err)?;
        let mut map = b.map.bind($py).try_readwrite().map_err(borrow_err)?;
        let mut reward = b.reward.bind($py).try_readwrite().map_err(borrow_err)?;
        let mut terminated = b.terminated.bind($py).try_readwrite().map_err(borrow_err)?;
        let mut truncated = b.truncated.bind($py).try_readwrite().map_err(borrow_err)?;
        let mut success = b.success.bind($py).try_readwrite().map_err(borrow_err)?;
        let mut episode_start = b
            .episode_start
            .bind($py)
            .try_readwrite()
            .map_err(borrow_err)?;
        let mut shortest_path = b
            .shortest_path
            .bind($py)
            .try_readwrite()
            .map_err(borrow_err)?;
        let mut target_category = b
            .target_category
            .bind($py)
            .try_readwrite()
            .map_err(borrow_err)?;
        let mut scene = b.scene.bind($py).try_readwrite().map_err(borrow_err)?;
        let mut episode_index = b
            .episode_index
            .bind($py)
            .try_readwrite()
            .map_err(borrow_err)?;
        let mut episode_seed = b
            .episode_seed
            .bind($py)
            .try_readwrite()
            .map_err(borrow_err)?;
        let mut steps = b.steps.bind($py).try_readwrite().map_err(borrow_err)?;
        let mut oracle_action = b
            .oracle_action
            .bind($py)
            .try_readwrite()
            .map_err(borrow_err)?;
        let mut $out = Out {
            features: features.as_slice_mut()?,
            target: target.as_slice_mut()?,
            ps_target: ps_target.as_slice_mut()?,
            map: map.as_slice_mut()?,
            reward: reward.as_slice_mut()?,
            terminated: terminated.as_slice_mut()?,
            truncated: truncated.as_slice_mut()?,
            success: success.as_slice_mut()?,
            episode_start: episode_start.as_slice_mut()?,
            shortest_path: shortest_path.as_slice_mut()?,
            target_category: target_category.as_slice_mut()?,
            scene: scene.as_slice_mut()?,
            episode_index: episode_index.as_slice_mut()?,
            episode_seed: episode_seed.as_slice_mut()?,
            steps: steps.as_slice_mut()?,
            oracle_action: oracle_action.as_slice_mut()?,
        };
        $py.detach(|| $body).map_err(chain_err)
    }};
}

/// A batch of navigation episodes stepped in Rust (the engine of `gman.VecEnv`).
#[pyclass(module = "gman._gman")]
struct VecCore {
    sim: Sim,
    bufs: Bufs,
    /// An earlier call panicked (a bug): the state may be inconsistent, every call refuses.
    poisoned: bool,
}

/// The batch's sizes checked before anything is allocated: `num_envs` in 1..=[`MAX_ENVS`],
/// the map grid by [`check_map`]'s rule, the observation arrays within [`MAX_BATCH_FLOATS`].
fn check_batch(num_envs: usize, grid: MapGrid) -> PyResult<()> {
    if !(1..=MAX_ENVS).contains(&num_envs) {
        return Err(value_err(format!(
            "num_envs = {num_envs} is out of range: a batch has 1..={MAX_ENVS} environments"
        )));
    }
    check_map(grid.rows, grid.cols)?;
    let per_env = FEATURE_DIM + 2 * ATTR_DIM + grid.len();
    if num_envs.saturating_mul(per_env) > MAX_BATCH_FLOATS {
        return Err(value_err(format!(
            "num_envs = {num_envs} with map = ({}, {}): the observations would take {} floats per environment, and a batch holds at most {MAX_BATCH_FLOATS} floats (1 GiB): at most {} environments with this map",
            grid.rows,
            grid.cols,
            per_env,
            MAX_BATCH_FLOATS / per_env
        )));
    }
    Ok(())
}

/// `num_envs` slots holding a placeholder episode until the first reset (a real episode of
/// the world: the split's first, or a sampled training task), allocated fallibly.
fn placeholder_slots(
    world: &'static World,
    split: Split,
    episodes: &[EpisodeSpec],
    reward: RewardKind,
    limits: EpisodeLimits,
    num_envs: usize,
) -> PyResult<Vec<Slot>> {
    let mut rng0 = ChaCha8Rng::seed_from_u64(0);
    let spec0 = if split == Split::Train {
        world
            .try_sample_train_episode_min(&mut rng0, 0)
            .map_err(chain_err)?
    } else {
        episodes[0].clone()
    };
    let mut slots = Vec::new();
    slots.try_reserve_exact(num_envs).map_err(|_| {
        PyMemoryError::new_err(format!(
            "num_envs = {num_envs}: cannot allocate the environments"
        ))
    })?;
    slots.extend((0..num_envs).map(|i| Slot {
        env: Env::new(world, &spec0, reward, limits.for_room(spec0.room)),
        spec: spec0.clone(),
        rng: ChaCha8Rng::seed_from_u64(i as u64),
        needs_reset: true,
    }));
    Ok(slots)
}

impl Bufs {
    /// The output arrays of `b` environments with `cells` map cells, allocated fallibly.
    fn new(py: Python<'_>, b: usize, cells: usize) -> PyResult<Bufs> {
        let w = &format!("num_envs = {b}");
        Ok(Bufs {
            features: arr2(py, [b, FEATURE_DIM], 0f32, w)?.unbind(),
            target: arr2(py, [b, ATTR_DIM], 0f32, w)?.unbind(),
            ps_target: arr2(py, [b, ATTR_DIM], 0f32, w)?.unbind(),
            map: arr3(py, [b, cells, FEATURE_DIM], 0f32, w)?.unbind(),
            reward: arr1(py, b, 0f32, w)?.unbind(),
            terminated: arr1(py, b, false, w)?.unbind(),
            truncated: arr1(py, b, false, w)?.unbind(),
            success: arr1(py, b, false, w)?.unbind(),
            episode_start: arr1(py, b, false, w)?.unbind(),
            shortest_path: arr1(py, b, 0i32, w)?.unbind(),
            target_category: arr1(py, b, 0i32, w)?.unbind(),
            scene: arr1(py, b, 0i32, w)?.unbind(),
            episode_index: arr1(py, b, 0i64, w)?.unbind(),
            episode_seed: arr1(py, b, 0u64, w)?.unbind(),
            steps: arr1(py, b, 0i32, w)?.unbind(),
            oracle_action: arr1(py, b, -1i64, w)?.unbind(),
        })
    }
}

impl VecCore {
    /// [`VecCore::step`] after the copy of the actions: checks them, then steps.
    fn step_checked(&mut self, py: Python<'_>, a: &[i64]) -> PyResult<()> {
        let b = self.sim.slots.len();
        if a.len() != b {
            return Err(value_err(format!(
                "actions has {} entries, the batch has {b} environments",
                a.len()
            )));
        }
        if let Some((i, &v)) = a
            .iter()
            .enumerate()
            .find(|(_, &v)| !(0..NUM_ACTIONS as i64).contains(&v))
        {
            return Err(value_err(format!(
                "actions[{i}] = {v} is not an action (0..={}: MoveAhead, RotateLeft, RotateRight, LookUp, LookDown, Done)",
                NUM_ACTIONS - 1
            )));
        }
        let sim = &mut self.sim;
        with_out!(py, &self.bufs, |out| sim.step_all(a, &mut out))
    }

    /// Runs `f` on the batch unless an earlier call panicked; a panic of `f` marks the batch
    /// unusable and surfaces as a `RuntimeError` (see [`guard`]).
    fn run<T>(&mut self, what: &str, f: impl FnOnce(&mut Self) -> PyResult<T>) -> PyResult<T> {
        if self.poisoned {
            return Err(PyRuntimeError::new_err(format!(
                "{what}: an earlier internal error left this environment inconsistent; create a new one"
            )));
        }
        let r = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| f(self)));
        r.unwrap_or_else(|p| {
            self.poisoned = true;
            Err(PyRuntimeError::new_err(format!(
                "{what}: internal error in gman (a Rust panic: {}); please report it",
                panic_text(p.as_ref())
            )))
        })
    }
}

#[pymethods]
impl VecCore {
    #[new]
    #[pyo3(signature = (data, world_seed, split, num_envs, reward, max_steps_living_room, max_steps_other, map_rows, map_cols, oracle, episodes_per_file, record=false, domain_shift=1.0))]
    #[allow(clippy::too_many_arguments)]
    fn new(
        py: Python<'_>,
        data: Option<String>,
        world_seed: u64,
        split: &str,
        num_envs: usize,
        reward: &str,
        max_steps_living_room: u32,
        max_steps_other: u32,
        map_rows: usize,
        map_cols: usize,
        oracle: bool,
        episodes_per_file: Option<usize>,
        record: bool,
        domain_shift: f32,
    ) -> PyResult<VecCore> {
        guard("VecEnv", || {
            let grid = MapGrid {
                rows: map_rows,
                cols: map_cols,
            };
            check_batch(num_envs, grid)?;
            let limits = EpisodeLimits {
                living_room: max_steps_living_room,
                other: max_steps_other,
            };
            for (name, v) in [("living_room", limits.living_room), ("other", limits.other)] {
                if !(1..=MAX_STEPS).contains(&v) {
                    return Err(value_err(format!(
                        "max_steps ({name}) = {v} is out of range: 1..={MAX_STEPS}"
                    )));
                }
            }
            if episodes_per_file == Some(0) {
                return Err(value_err("episodes must be at least 1 (or None for all)"));
            }
            let split = parse_split(split)?;
            let reward = parse_reward(reward)?;
            let world = world_of(py, data.as_deref(), world_seed, domain_shift)?;
            check_grid_for_world(
                world,
                map_rows,
                map_cols,
                &format!("map = ({map_rows}, {map_cols})"),
            )
            .map_err(chain_err)?;
            let episodes = if split == Split::Train {
                Vec::new()
            } else {
                world
                    .episodes(split, episodes_per_file)
                    .map_err(chain_err)?
            };
            if split != Split::Train && episodes.is_empty() {
                return Err(value_err(format!(
                    "split {} has no episodes in this world",
                    split.name()
                )));
            }
            let slots = placeholder_slots(world, split, &episodes, reward, limits, num_envs)?;
            let bufs = Bufs::new(py, num_envs, grid.cells())?;
            let n = episodes.len();
            Ok(VecCore {
                sim: Sim {
                    world,
                    split,
                    episodes,
                    next_episode: 0,
                    reward,
                    limits,
                    grid,
                    oracle,
                    record,
                    slots,
                    results: vec![None; n],
                    recorded: 0,
                },
                bufs,
                poisoned: false,
            })
        })
    }

    /// The output arrays by name (the same objects every call; `step` and `reset` refill them).
    fn arrays<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let d = PyDict::new(py);
        let b = &self.bufs;
        d.set_item("features", b.features.bind(py))?;
        d.set_item("target", b.target.bind(py))?;
        d.set_item("ps_target", b.ps_target.bind(py))?;
        d.set_item("map", b.map.bind(py))?;
        d.set_item("reward", b.reward.bind(py))?;
        d.set_item("terminated", b.terminated.bind(py))?;
        d.set_item("truncated", b.truncated.bind(py))?;
        d.set_item("success", b.success.bind(py))?;
        d.set_item("episode_start", b.episode_start.bind(py))?;
        d.set_item("shortest_path", b.shortest_path.bind(py))?;
        d.set_item("target_category", b.target_category.bind(py))?;
        d.set_item("scene", b.scene.bind(py))?;
        d.set_item("episode_index", b.episode_index.bind(py))?;
        d.set_item("episode_seed", b.episode_seed.bind(py))?;
        d.set_item("steps", b.steps.bind(py))?;
        d.set_item("oracle_action", b.oracle_action.bind(py))?;
        Ok(d)
    }

    /// Starts a new episode in every slot. `seed` reseeds slot i's training sampler with
    /// `seed + i`; with `restart` an evaluation split restarts its episode list from the first
    /// episode (and forgets the finished ones), without it the slots take the next episodes.
    #[pyo3(signature = (seed=None, restart=true))]
    fn reset(&mut self, py: Python<'_>, seed: Option<u64>, restart: bool) -> PyResult<()> {
        self.run("reset", |c| {
            let sim = &mut c.sim;
            with_out!(py, &c.bufs, |out| sim.reset_all(seed, restart, &mut out))
        })
    }

    /// Steps every slot with `actions` (int64, one per slot, in 0..6); a slot whose episode
    /// ended at the previous call is reset instead (its action is ignored).
    fn step(&mut self, py: Python<'_>, actions: PyReadonlyArray1<'_, i64>) -> PyResult<()> {
        // A copy: the actions may be one of the output arrays (`info["oracle_action"]`).
        let a: Vec<i64> = actions.as_slice()?.to_vec();
        drop(actions);
        self.run("step", |c| c.step_checked(py, &a))
    }

    /// The top-down RGB view of slot `i`'s scene with its episode's path so far (`uint8`,
    /// `(height, width, 3)`; the size depends on the scene). Needs `record=True`.
    fn render<'py>(&mut self, py: Python<'py>, i: usize) -> PyResult<Bound<'py, PyArray3<u8>>> {
        self.run("render", |c| {
            let b = c.sim.slots.len();
            if i >= b {
                return Err(value_err(format!("render: slot {i} of a batch of {b}")));
            }
            if !c.sim.record {
                return Err(PyRuntimeError::new_err(
                    "render: this environment was made without render_mode=\"rgb_array\"",
                ));
            }
            let s = &c.sim.slots[i];
            let world = c.sim.world;
            let title = format!(
                "{}: find {}",
                world.scenes[s.spec.scene].name,
                world.category_name(s.spec.target)
            );
            let (px, w, h) = py
                .detach(|| {
                    draw_scene_rgb(
                        world,
                        s.spec.scene,
                        Some(s.spec.target),
                        s.env.trajectory(),
                        Some(&title),
                    )
                })
                .map_err(chain_err)?;
            PyArray1::from_vec(py, px).reshape([h as usize, w as usize, 3])
        })
    }

    /// Builds the world's lazily cached tables a long run would touch (every scene of the
    /// split, the goal tables of `samples` sampled training tasks or of every official
    /// episode), so that a measurement does not time their construction.
    #[pyo3(signature = (samples=20000))]
    fn warm_up(&self, py: Python<'_>, samples: usize) -> PyResult<()> {
        let sim = &self.sim;
        py.detach(|| -> anyhow::Result<()> {
            let w = sim.world;
            for &s in w.split_scenes(sim.split)? {
                w.tables(s);
            }
            if sim.split == Split::Train {
                let mut rng = ChaCha8Rng::seed_from_u64(u64::MAX);
                for _ in 0..samples {
                    let e = w.try_sample_train_episode_min(&mut rng, 0)?;
                    w.goal_table(e.scene, e.target);
                }
            } else {
                for e in &sim.episodes {
                    w.goal_table(e.scene, e.target);
                }
            }
            Ok(())
        })
        .map_err(chain_err)
    }

    /// Benchmark of the engine alone: `calls` batched steps with uniformly random actions
    /// (drawn before timing, seeded by `seed`), the same work as `step` (outputs written into
    /// the same arrays) but no Python between the calls. Returns the seconds taken.
    fn bench_steps(&mut self, py: Python<'_>, calls: usize, seed: u64) -> PyResult<f64> {
        use rand::Rng;
        let b = self.sim.slots.len();
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let actions: Vec<i64> = (0..calls * b)
            .map(|_| rng.random_range(0..NUM_ACTIONS as i64))
            .collect();
        let sim = &mut self.sim;
        with_out!(py, &self.bufs, |out| {
            let t0 = std::time::Instant::now();
            for c in actions.chunks_exact(b) {
                sim.step_all(c, &mut out)?;
            }
            Ok::<f64, anyhow::Error>(t0.elapsed().as_secs_f64())
        })
    }

    /// Number of environments.
    #[getter]
    fn num_envs(&self) -> usize {
        self.sim.slots.len()
    }

    /// Official episodes of the split (0 for train).
    #[getter]
    fn num_episodes(&self) -> usize {
        self.sim.episodes.len()
    }

    /// Official episodes finished at least once since the last reset.
    #[getter]
    fn completed(&self) -> usize {
        self.sim.recorded
    }

    /// Floats of one spatial map (0 without a map).
    #[getter]
    fn map_cells(&self) -> usize {
        self.sim.grid.cells()
    }

    /// Scene names by scene id.
    fn scene_names(&self) -> Vec<String> {
        self.sim
            .world
            .scenes
            .iter()
            .map(|s| s.name.clone())
            .collect()
    }

    /// Category names by category id.
    fn category_names(&self) -> Vec<String> {
        (0..self.sim.world.categories.len())
            .map(|c| self.sim.world.category_name(c as _).to_string())
            .collect()
    }

    /// `gman eval`'s JSON report (and the per-episode results as JSON) of the finished
    /// official episodes; an error unless every episode finished.
    fn report(&self, agent: &str) -> PyResult<(String, String)> {
        guard("report", || {
            if self.sim.split == Split::Train {
                return Err(value_err(
                    "the train split has no official episodes to report",
                ));
            }
            if self.sim.recorded < self.sim.results.len() {
                return Err(PyRuntimeError::new_err(format!(
                    "{} of {} episodes finished; step until all have",
                    self.sim.recorded,
                    self.sim.results.len()
                )));
            }
            let results: Vec<EpisodeResult> = self.sim.results.iter().flatten().cloned().collect();
            report_json(self.sim.split, agent, &results)
        })
    }
}

fn report_json(split: Split, agent: &str, results: &[EpisodeResult]) -> PyResult<(String, String)> {
    let report = EvalReport::new(split.name(), agent, results);
    let r = serde_json::to_string_pretty(&report).map_err(value_err)?;
    let e = serde_json::to_string(results).map_err(value_err)?;
    Ok((r, e))
}

// ---------------------------------------------------------------------------------------
// gman eval's evaluator.
// ---------------------------------------------------------------------------------------

/// Evaluates a built-in agent (`"random"`, `"oracle"`), a model file (`path`) or a blob
/// (`blob` bytes) on the official episodes of `split` with `gman eval`'s code: returns its
/// JSON report and the per-episode results as JSON.
/// `map`, when given, must be the model's own map grid (`(0, 0)`: none).
#[pyfunction]
#[pyo3(signature = (data, world_seed, split, agent, blob, seed, episodes_per_file, reward, max_steps_living_room, max_steps_other, map=None, domain_shift=1.0))]
#[allow(clippy::too_many_arguments)]
fn host_evaluate(
    py: Python<'_>,
    data: Option<String>,
    world_seed: u64,
    split: &str,
    agent: &str,
    blob: Option<Vec<u8>>,
    seed: u64,
    episodes_per_file: Option<usize>,
    reward: &str,
    max_steps_living_room: u32,
    max_steps_other: u32,
    map: Option<(usize, usize)>,
    domain_shift: f32,
) -> PyResult<(String, String)> {
    guard("evaluate", || {
        host_evaluate_inner(
            py,
            data,
            (world_seed, domain_shift),
            split,
            agent,
            blob,
            seed,
            episodes_per_file,
            reward,
            EpisodeLimits {
                living_room: max_steps_living_room,
                other: max_steps_other,
            },
            map,
        )
    })
}

/// Refuses a `map` argument that differs from `model`'s map grid, and a model whose grid
/// `world` cannot serve.
fn check_model_map(
    model: &NavModel,
    map: Option<(usize, usize)>,
    world: &World,
    name: &str,
) -> PyResult<()> {
    let own = (model.dims.map_rows, model.dims.map_cols);
    if let Some(m) = map.filter(|&m| m != own) {
        let grid = |(r, c): (usize, usize)| {
            if r == 0 {
                "no map".to_string()
            } else {
                format!("a {r} x {c} map")
            }
        };
        return Err(value_err(format!(
            "map = {m:?} contradicts the model {name}, which takes {} (pass map=None or map={own:?})",
            grid(own)
        )));
    }
    check_grid_for_world(world, own.0, own.1, &format!("model {name}")).map_err(chain_err)
}

#[allow(clippy::too_many_arguments)]
fn host_evaluate_inner(
    py: Python<'_>,
    data: Option<String>,
    (world_seed, domain_shift): (u64, f32),
    split: &str,
    agent: &str,
    blob: Option<Vec<u8>>,
    seed: u64,
    episodes_per_file: Option<usize>,
    reward: &str,
    limits: EpisodeLimits,
    map: Option<(usize, usize)>,
) -> PyResult<(String, String)> {
    let split = parse_split(split)?;
    if split == Split::Train {
        return Err(value_err(
            "split train has no official episodes; use split=\"val\" or \"test\"",
        ));
    }
    if episodes_per_file == Some(0) {
        return Err(value_err("episodes must be at least 1 (or None for all)"));
    }
    let reward = parse_reward(reward)?;
    let world = world_of(py, data.as_deref(), world_seed, domain_shift)?;
    let factory: AgentFactory = match (agent, blob) {
        (_, Some(bytes)) => {
            let m = model_from_blob(&bytes, None)
                .map_err(|e| chain_err(e.context("policy (blob bytes)")))?;
            check_model_map(&m, map, world, "blob")?;
            let m = Arc::new(m);
            Box::new(move |_| Box::new(NavAgent::new(m.clone())))
        }
        ("random", None) => Box::new(move |_| Box::new(RandomAgent::new(seed))),
        ("oracle", None) => Box::new(|_| Box::new(OracleAgent)),
        (path, None) => {
            if !Path::new(path).exists() {
                return Err(PyFileNotFoundError::new_err(format!(
                    "policy = {path:?}: not \"random\" or \"oracle\", and no such model file"
                )));
            }
            let m: NavModel = load_model(Path::new(path), None).map_err(chain_err)?;
            check_model_map(&m, map, world, path)?;
            let m = Arc::new(m);
            Box::new(move |_| Box::new(NavAgent::new(m.clone())))
        }
    };
    let episodes = world
        .episodes(split, episodes_per_file)
        .map_err(chain_err)?;
    let cfg = EvalConfig {
        reward,
        limits,
        progress: false,
    };
    let results = py.detach(|| evaluate(world, &episodes, |w| factory(w), &cfg));
    report_json(split, agent, &results)
}

// ---------------------------------------------------------------------------------------
// gman-core's navigator over a blob.
// ---------------------------------------------------------------------------------------

enum AnyNav<'a> {
    Full(Navigator<'a, Full, K>),
    Efficient(Navigator<'a, Efficient, K>),
}

#[ouroboros::self_referencing]
struct NavCell {
    model: Box<NavModel>,
    arena: Vec<f32>,
    #[borrows(model, mut arena)]
    #[not_covariant]
    nav: AnyNav<'this>,
}

fn core_err(e: gman_core::Error) -> PyErr {
    PyValueError::new_err(format!("navigator: {e}"))
}

/// gman-core's navigator over a weight blob, configured as `gman eval` runs it.
#[pyclass(module = "gman._gman", name = "NavigatorCore")]
struct PyNavigator {
    cell: NavCell,
    method: &'static str,
    efficient: bool,
    attr: usize,
    ps: usize,
    map_len: usize,
    map_rows: usize,
    map_cols: usize,
}

impl PyNavigator {
    /// Parses `blob` and builds the navigator ([`PyNavigator::from_blob`]).
    #[allow(clippy::borrowed_box)] // the builder's signature (ouroboros) takes the owner's Box
    fn build(blob: &[u8]) -> PyResult<PyNavigator> {
        let model = model_from_blob(blob, None).map_err(|e| chain_err(e.context("blob")))?;
        let efficient = gman_train::model::episode::eval_mode_is_efficient(&model);
        let method = model.method.name();
        let dims = model.dims;
        let arena = vec![0.0; model.arena_len()];
        let cell = NavCellTryBuilder {
            model: Box::new(model),
            arena,
            nav_builder: |model: &Box<NavModel>, arena: &mut Vec<f32>| -> PyResult<AnyNav<'_>> {
                let w = model.weights().map_err(chain_err)?;
                let cfg = model.nav_config(false);
                Ok(if efficient {
                    AnyNav::Efficient(Navigator::new(w, arena, cfg).map_err(core_err)?)
                } else {
                    AnyNav::Full(Navigator::new(w, arena, cfg).map_err(core_err)?)
                })
            },
        }
        .try_build()?;
        Ok(PyNavigator {
            cell,
            method,
            efficient,
            attr: dims.attr,
            ps: dims.ps,
            map_len: dims.map_len(),
            map_rows: dims.map_rows,
            map_cols: dims.map_cols,
        })
    }
}

#[pymethods]
impl PyNavigator {
    /// Parses `blob` and builds the navigator (the blob's method, inner-loop settings and
    /// adaptation mode, sampled actions: what `gman eval --agent BLOB` runs).
    #[staticmethod]
    fn from_blob(blob: &Bound<'_, PyBytes>) -> PyResult<PyNavigator> {
        guard("Navigator.from_blob", || Self::build(blob.as_bytes()))
    }

    /// Starts an episode: target attribute vector `attr` (float32, 45) and the episode seed.
    fn reset(&mut self, attr: PyReadonlyArray1<'_, f32>, seed: u64) -> PyResult<()> {
        let a = attr.as_slice()?;
        guard("Navigator.reset", || {
            self.cell
                .with_nav_mut(|nav| match nav {
                    AnyNav::Full(n) => n.reset(a, seed),
                    AnyNav::Efficient(n) => n.reset(a, seed),
                })
                .map_err(core_err)
        })
    }

    /// One control step: returns (action, probabilities, value, adapted). The binding reads
    /// its inputs before gman-core's `step_map` runs and writes nothing of the navigator.
    #[pyo3(signature = (obs, map=None, ps=None))]
    fn step<'py>(
        &mut self,
        py: Python<'py>,
        obs: PyReadonlyArray1<'py, f32>,
        map: Option<PyReadonlyArray1<'py, f32>>,
        ps: Option<PyReadonlyArray1<'py, f32>>,
    ) -> PyResult<(usize, Bound<'py, PyArray1<f32>>, f32, bool)> {
        let o = obs.as_slice()?;
        let m: &[f32] = match &map {
            Some(m) => m.as_slice()?,
            None => &[],
        };
        let p: &[f32] = match &ps {
            Some(p) => p.as_slice()?,
            None => &[],
        };
        let out = guard("Navigator.step", || {
            self.cell
                .with_nav_mut(|nav| match nav {
                    AnyNav::Full(n) => n.step_map(o, m, p),
                    AnyNav::Efficient(n) => n.step_map(o, m, p),
                })
                .map_err(core_err)
        })?;
        Ok((
            out.action.index(),
            PyArray1::from_slice(py, &out.probs),
            out.value,
            out.adapted,
        ))
    }

    /// Runs the inner update on the buffered steps now; True if it ran.
    fn adapt(&mut self) -> PyResult<bool> {
        guard("Navigator.adapt", || {
            self.cell
                .with_nav_mut(|nav| match nav {
                    AnyNav::Full(n) => n.adapt_now(),
                    AnyNav::Efficient(n) => n.adapt_now(),
                })
                .map_err(core_err)
        })
    }

    /// Length of the PS input the model takes (0: none).
    #[getter]
    fn ps_dim(&self) -> usize {
        self.ps
    }

    /// Steps buffered for the next inner update.
    #[getter]
    fn buffered(&mut self) -> usize {
        self.cell.with_nav_mut(|nav| match nav {
            AnyNav::Full(n) => n.buffered(),
            AnyNav::Efficient(n) => n.buffered(),
        })
    }

    /// The method the blob was trained as (e.g. "gman").
    #[getter]
    fn method(&self) -> &'static str {
        self.method
    }

    /// The adaptation mode ("efficient" or "full").
    #[getter]
    fn mode(&self) -> &'static str {
        if self.efficient {
            "efficient"
        } else {
            "full"
        }
    }

    /// Length of the attribute vector.
    #[getter]
    fn attr_dim(&self) -> usize {
        self.attr
    }

    /// (rows, cols) of the spatial map the model takes ((0, 0) without one).
    #[getter]
    fn map_shape(&self) -> (usize, usize) {
        (self.map_rows, self.map_cols)
    }

    /// Floats of the spatial map (rows * cols * 512).
    #[getter]
    fn map_len(&self) -> usize {
        self.map_len
    }
}

#[pymodule]
fn _gman(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<VecCore>()?;
    m.add_class::<PyNavigator>()?;
    m.add_function(wrap_pyfunction!(host_evaluate, m)?)?;
    m.add("FEATURE_DIM", FEATURE_DIM)?;
    m.add("ATTR_DIM", ATTR_DIM)?;
    m.add("NUM_ACTIONS", NUM_ACTIONS)?;
    m.add_function(wrap_pyfunction!(check_map, m)?)?;
    m.add_function(wrap_pyfunction!(_panic_for_tests, m)?)?;
    m.add("MAX_ENVS", MAX_ENVS)?;
    m.add("MAX_BATCH_FLOATS", MAX_BATCH_FLOATS)?;
    m.add("MAX_STEPS", MAX_STEPS)?;
    m.add("MAX_MAP_SIDE", MAX_GRID_SIDE)?;
    m.add("MAX_SEED", u64::MAX)?;
    m.add("MAX_DOMAIN_SHIFT", DomainShift::MAX)?;
    m.add("MAX_EPISODES", usize::MAX)?;
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    Ok(())
}
