//! Argument types shared by several commands (`--preset`, the world options).

use std::path::PathBuf;

use anyhow::Result;
use clap::{Args, ValueEnum};
use gman_core::Dims;
use gman_host_sim::sim::{World, DEFAULT_WORLD_SEED};

/// Network size preset.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum PresetArg {
    /// Microcontroller sizes (G hidden 256, D hidden 64).
    Mcu,
    /// The paper's sizes (G hidden 4096, D hidden 1024).
    Paper,
}

impl PresetArg {
    /// The sizes.
    pub fn dims(self) -> Dims {
        match self {
            PresetArg::Mcu => Dims::MCU,
            PresetArg::Paper => Dims::PAPER,
        }
    }

    /// The name.
    pub fn name(self) -> &'static str {
        match self {
            PresetArg::Mcu => "mcu",
            PresetArg::Paper => "paper",
        }
    }
}

/// Options that choose the world.
#[derive(Debug, Args, Clone)]
pub struct WorldArgs {
    /// Data directory (`attributes.json`, `scenes/<split>/`, `episodes/<split>/`), or AI2THOR
    /// offline data (`attributes.json`, `FloorPlanN/` folders, `episodes/<split>/`; needs the
    /// `offline` build feature). Without it the built-in synthetic demo world is used.
    #[arg(long, value_name = "DIR")]
    pub data: Option<PathBuf>,
    /// World seed: placement of objects without positions, feature model, scene styles (and the
    /// whole synthetic world).
    #[arg(long, default_value_t = DEFAULT_WORLD_SEED)]
    pub world_seed: u64,
}

impl WorldArgs {
    /// Loads the chosen world.
    pub fn load(&self) -> Result<World> {
        match &self.data {
            Some(dir) => World::load_with_seed(dir, self.world_seed),
            None => {
                eprintln!(
                    "note: no --data given, using the built-in synthetic demo world (seed {})",
                    self.world_seed
                );
                Ok(World::synthetic(self.world_seed))
            }
        }
    }
}
