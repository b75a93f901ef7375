//! `gman eval`'s evaluator for Python.

use super::*;

/// Evaluates a built-in agent (`"random"`, `"oracle"`), a model file (`path`) or a blob
/// (`blob` bytes) on the official episodes of `split` with `gman eval`'s code: returns its
/// JSON report and the per-episode results as JSON.
/// `map`, when given, must be the model's own map grid (`(0, 0)`: none).
#[pyfunction]
#[pyo3(signature = (data, world_seed, split, agent, blob, seed, episodes_per_file, reward, max_steps_living_room, max_steps_other, map=None, domain_shift=1.0))]
#[allow(clippy::too_many_arguments)]
pub(crate) fn host_evaluate(
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
pub(crate) fn check_model_map(
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
pub(crate) fn host_evaluate_inner(
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
