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
use gman_core::spec::{SettingValue, SETTING_KEYS};
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

mod evaluate;
mod lockstep;
mod navigator;
mod support;
mod vec_env;
mod world;

use evaluate::*;
use lockstep::*;
use navigator::*;
use support::*;
use vec_env::*;
use world::*;

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
