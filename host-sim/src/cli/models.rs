//! Agents by name for `gman eval` and `gman scene`: the built-in `random` and `oracle`, and
//! model files (`--agent PATH`, with the model overrides).

use std::path::{Path, PathBuf};
use std::sync::Arc;

use anyhow::{bail, Context, Result};
use gman_host_sim::eval::agent::NavAgent;
use gman_host_sim::model::{load_model_with_ps, Method};
use gman_host_sim::sim::eval::AgentFactory;
use gman_host_sim::sim::{OracleAgent, RandomAgent};

use super::model_args::ModelArgs;

/// Evaluation-time changes to a loaded model (`gman eval --method` and the model's settings).
#[derive(Clone, Debug, Default)]
pub struct ModelOverrides {
    /// Treat the model as this method.
    pub method: Option<Method>,
    /// Settings that replace the model's own.
    pub model: ModelArgs,
    /// The PS module of a PS variant's blob (a checkpoint file holding its tensors).
    pub ps: Option<PathBuf>,
}

/// Model-file agents for `gman eval`: a checkpoint or a blob.
pub fn model_factory(path: &Path, ov: &ModelOverrides) -> Result<(AgentFactory, String)> {
    let mut model = load_model_with_ps(path, ov.method, ov.ps.as_deref())?;
    ov.model
        .apply(&mut model.spec)
        .context("the overridden settings")?;
    let model = Arc::new(model);
    let label = format!("{} ({})", model.method.name(), path.display());
    let factory: AgentFactory = Box::new(move |_| Box::new(NavAgent::new(model.clone())));
    Ok((factory, label))
}

/// Refuses a model agent (a checkpoint or a blob) whose map grid `world` cannot serve
/// ([`gman_host_sim::sim::spatial::check_grid_for_world`]); built-in agents pass.
pub fn check_agent_for_world(
    name: &str,
    world: &gman_host_sim::sim::World,
    ov: &ModelOverrides,
) -> Result<()> {
    if matches!(name, "random" | "oracle") || !Path::new(name).exists() {
        return Ok(());
    }
    let d = load_model_with_ps(Path::new(name), ov.method, ov.ps.as_deref())?.dims;
    gman_host_sim::sim::spatial::check_grid_for_world(
        world,
        d.map_rows,
        d.map_cols,
        &format!("agent {name}"),
    )
}

/// A built-in agent factory by name, or a model file's (a clear error when it is neither).
pub fn agent_factory(name: &str, seed: u64, ov: &ModelOverrides) -> Result<AgentFactory> {
    match name {
        "random" => Ok(Box::new(move |_| Box::new(RandomAgent::new(seed)))),
        "oracle" => Ok(Box::new(|_| Box::new(OracleAgent))),
        other => {
            let p = Path::new(other);
            if p.exists() {
                return Ok(model_factory(p, ov)?.0);
            }
            bail!("agent {other}: not `random` or `oracle`, and no such model file")
        }
    }
}
