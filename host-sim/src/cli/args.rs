//! Argument types and checks shared by several commands (`--preset`, the world options,
//! flag range checks).

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{bail, Result};
use clap::builder::{PossibleValue, PossibleValuesParser, TypedValueParser};
use clap::{Args, ValueEnum};
use gman_core::spec::Named;
use gman_core::Dims;
use gman_host_sim::model::Method;
use gman_host_sim::sim::features::DomainShift;
use gman_host_sim::sim::{ObjectLayout, World, DEFAULT_WORLD_SEED};

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

/// The value parser of a gman-core setting enum (`--noise`, `--adapt-mode`, `--step-rule`,
/// `--adapt-loss`): its names, each with its meaning, from the enum's one table
/// ([`Named::NAMES`]).
pub fn named<T: Named + Send + Sync>() -> impl TypedValueParser<Value = T> {
    PossibleValuesParser::new(
        T::NAMES
            .iter()
            .map(|&(_, name, help)| PossibleValue::new(name).help(help)),
    )
    .map(|s| T::from_name(&s).expect("a listed value"))
}

/// The value parser of `--method`: the presets of [`Method::PRESETS`] with their meaning, in
/// its order.
pub fn method() -> impl TypedValueParser<Value = Method> {
    PossibleValuesParser::new(
        Method::PRESETS
            .iter()
            .map(|&(name, _, help)| PossibleValue::new(name).help(help)),
    )
    .map(|s| Method::parse(&s).expect("a listed method"))
}

/// `--object-layout`: where the objects of the real floor plans come from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum LayoutArg {
    /// `thor5` when DIR/objects_thor5/ exists, else `rule`.
    Auto,
    /// AI2-THOR 5.0 positions and boxes (objects_thor5/) for the categories without a 2.x
    /// position; visibility measured to the boxes.
    Thor5,
    /// The seeded placement against the walls for the categories without a 2.x position.
    Rule,
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
    /// Visibility file read in each offline scene folder: `visible_object_map.json` (SAVN,
    /// GMAN) or a variant such as `visible_object_map_1.5.json` (VTNet, HOZ).
    #[arg(long, value_name = "FILE", default_value = gman_host_sim::sim::offline::VISIBLE_FILE)]
    pub visible_file: String,
    /// Object layout of the real floor plans: `thor5` (AI2-THOR 5.0 positions and boxes from
    /// DIR/objects_thor5/ for every category the 2.x scene files do not place; episode goals
    /// and known_objects keep their 2.x positions), `rule` (the seeded placement against the
    /// walls), or `auto` (thor5 when DIR/objects_thor5/ exists, else rule). Part of the world:
    /// a resumed run must use the layout it was trained with.
    #[arg(long, value_enum, default_value = "auto")]
    pub object_layout: LayoutArg,
    /// Domain shift S in [0, 3]: the strength of every scene's style (how differently one
    /// object looks from scene to scene; host-sim/SIMULATOR.md, "Domain shift"). 1: the
    /// simulator's default; 0: every object looks the same in every scene. Part of the world: a
    /// resumed run must use the level it was trained with
    #[arg(long, value_name = "S", default_value_t = DomainShift::DEFAULT)]
    pub domain_shift: DomainShift,
}

impl WorldArgs {
    /// Loads the chosen world.
    pub fn load(&self) -> Result<World> {
        let mut world = self.load_default_shift()?;
        world.set_domain_shift(self.domain_shift)?;
        Ok(world)
    }

    fn load_default_shift(&self) -> Result<World> {
        match &self.data {
            Some(dir) => {
                if self.visible_file.contains(['/', '\\']) {
                    bail!(
                        "--visible-file {:?} must be a file name inside each scene folder, not a path",
                        self.visible_file
                    );
                }
                let layout = match self.object_layout {
                    LayoutArg::Auto => gman_host_sim::sim::world::auto_layout(dir),
                    LayoutArg::Thor5 => ObjectLayout::Thor5,
                    LayoutArg::Rule => ObjectLayout::Rule,
                };
                World::load_with_layout(
                    dir,
                    self.world_seed,
                    &gman_host_sim::sim::offline::OfflineOptions {
                        visible_file: self.visible_file.clone(),
                    },
                    layout,
                )
            }
            None => {
                if self.object_layout == LayoutArg::Thor5 {
                    bail!("--object-layout thor5 needs --data DIR (the synthetic world has no AI2-THOR 5.0 objects)");
                }
                eprintln!(
                    "note: no --data given, using the built-in synthetic demo world (seed {})",
                    self.world_seed
                );
                Ok(World::synthetic(self.world_seed))
            }
        }
    }
}

/// Refuses a flag value outside [0, 1).
pub fn check_unit(name: &str, v: f32) -> Result<()> {
    if !(0.0..1.0).contains(&v) {
        bail!("--{name} must be in [0, 1), got {v}");
    }
    Ok(())
}

/// Refuses a flag value that is not a positive finite number.
pub fn check_positive(name: &str, v: f32) -> Result<()> {
    if !(v.is_finite() && v > 0.0) {
        bail!("--{name} must be a positive number, got {v}");
    }
    Ok(())
}

/// Says on stderr which files of `out` a command wrote and how long it took since `t0`.
pub fn report_written(out: &Path, files: &[&str], t0: Instant) {
    let names: Vec<String> = files
        .iter()
        .map(|f| out.join(f).display().to_string())
        .collect();
    eprintln!(
        "wrote {} ({:.1} s in all)",
        names.join(" and "),
        t0.elapsed().as_secs_f64()
    );
}

/// True when `a` and `b` name the same existing file (after resolving links: same device
/// and inode, so symlinks and hard links count).
pub fn same_file(a: &Path, b: &Path) -> bool {
    use std::os::unix::fs::MetadataExt;
    match (std::fs::metadata(a), std::fs::metadata(b)) {
        (Ok(x), Ok(y)) => x.dev() == y.dev() && x.ino() == y.ino(),
        _ => false,
    }
}

/// Refuses an output path (`out_flag`) that is one of the command's inputs: writing it
/// would destroy the input (a checkpoint replaced by a blob, a model by its report).
pub fn refuse_output_over_inputs(
    out_flag: &str,
    out: &Path,
    inputs: &[(&str, &Path)],
) -> Result<()> {
    for (flag, input) in inputs {
        if same_file(out, input) {
            bail!(
                "{out_flag} {} is the same file as {flag} {}: refusing to overwrite an input; choose another output path",
                out.display(),
                input.display()
            );
        }
    }
    Ok(())
}
