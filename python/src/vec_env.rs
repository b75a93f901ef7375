//! `VecCore`: the batch's numpy buffers and its Python methods.

use super::*;

/// The numpy arrays a batch writes into (allocated once, filled in place).
pub(crate) struct Bufs {
    pub(crate) features: Py<PyArray2<f32>>,
    pub(crate) target: Py<PyArray2<f32>>,
    pub(crate) ps_target: Py<PyArray2<f32>>,
    pub(crate) map: Py<PyArray3<f32>>,
    pub(crate) reward: Py<PyArray1<f32>>,
    pub(crate) terminated: Py<PyArray1<bool>>,
    pub(crate) truncated: Py<PyArray1<bool>>,
    pub(crate) success: Py<PyArray1<bool>>,
    pub(crate) episode_start: Py<PyArray1<bool>>,
    pub(crate) shortest_path: Py<PyArray1<i32>>,
    pub(crate) target_category: Py<PyArray1<i32>>,
    pub(crate) scene: Py<PyArray1<i32>>,
    pub(crate) episode_index: Py<PyArray1<i64>>,
    pub(crate) episode_seed: Py<PyArray1<u64>>,
    pub(crate) steps: Py<PyArray1<i32>>,
    pub(crate) oracle_action: Py<PyArray1<i64>>,
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
pub(crate) struct VecCore {
    pub(crate) sim: Sim,
    pub(crate) bufs: Bufs,
    /// An earlier call panicked (a bug): the state may be inconsistent, every call refuses.
    pub(crate) poisoned: bool,
}

/// The batch's sizes checked before anything is allocated: `num_envs` in 1..=[`MAX_ENVS`],
/// the map grid by [`check_map`]'s rule, the observation arrays within [`MAX_BATCH_FLOATS`].
pub(crate) fn check_batch(num_envs: usize, grid: MapGrid) -> PyResult<()> {
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
pub(crate) fn placeholder_slots(
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
    pub(crate) fn new(py: Python<'_>, b: usize, cells: usize) -> PyResult<Bufs> {
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
    pub(crate) fn step_checked(&mut self, py: Python<'_>, a: &[i64]) -> PyResult<()> {
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
    pub(crate) fn run<T>(
        &mut self,
        what: &str,
        f: impl FnOnce(&mut Self) -> PyResult<T>,
    ) -> PyResult<T> {
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

pub(crate) fn report_json(
    split: Split,
    agent: &str,
    results: &[EpisodeResult],
) -> PyResult<(String, String)> {
    let report = EvalReport::new(split.name(), agent, results);
    let r = serde_json::to_string_pretty(&report).map_err(value_err)?;
    let e = serde_json::to_string(results).map_err(value_err)?;
    Ok((r, e))
}
