//! What every episode of a model does, in training and in evaluation: the navigator started
//! on the episode's target (SE(y), the seed, the privileged feature), the PS module's input of
//! an observation, the map grid.

use anyhow::Result;
use gman_core::navigator::memory::AdaptMode;
use gman_core::navigator::{Mode, Navigator};

use super::{NavModel, K};
use crate::pretrain::ps::PsBuffers;
use crate::sim::spatial::MapGrid;
use crate::sim::{CategoryId, EpisodeSpec, SceneId, World};

/// Starts `nav` on `spec`'s target: SE(y) and the episode seed, and for the
/// privileged-feature bound the target's true feature in the scene as x_t.
pub(crate) fn begin<M: Mode>(
    nav: &mut Navigator<'_, M, K>,
    world: &World,
    spec: &EpisodeSpec,
    model: &NavModel,
) -> Result<()> {
    begin_on(nav, world, spec.scene, spec.target, spec.seed, model)
}

/// [`begin`] on the episode towards `target` in `scene` with seed `seed`, whoever holds
/// the navigator's arena.
pub(crate) fn begin_on<M: Mode, S: AsRef<[f32]> + AsMut<[f32]>>(
    nav: &mut Navigator<'_, M, K, S>,
    world: &World,
    scene: SceneId,
    target: CategoryId,
    seed: u64,
    model: &NavModel,
) -> Result<()> {
    nav.reset(world.attributes(target), seed)?;
    if model.privileged {
        nav.fix_generated_feature(&world.object_feature(scene, target))?;
    }
    Ok(())
}

/// The map grid of `model` (empty without a map).
pub(crate) fn map_grid(model: &NavModel) -> MapGrid {
    MapGrid {
        rows: model.dims.map_rows,
        cols: model.dims.map_cols,
    }
}

/// The PS module's output for `obs` (empty for a model without the PS module).
pub(crate) fn ps_input(
    model: &NavModel,
    buf: &mut Option<PsBuffers>,
    obs: &[f32],
) -> Result<Vec<f32>> {
    match (&model.ps, buf) {
        (Some(ps), Some(b)) => {
            ps.forward_buf(obs, b)?;
            Ok(b.y.clone())
        }
        _ => Ok(Vec::new()),
    }
}

/// True when `model` runs in the `Efficient` adaptation mode (what the microcontroller runs).
pub fn eval_mode_is_efficient(model: &NavModel) -> bool {
    model.spec.adapt_mode == AdaptMode::Efficient
}
