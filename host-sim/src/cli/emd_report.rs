//! `gman emd-report`: the paper's Fig. 3 as a measurement (see `gman_host_sim::emd_report`).

use std::path::PathBuf;

use anyhow::{bail, Context, Result};
use clap::Args;
use gman_core::spec::{ModelSpec, Named};
use gman_host_sim::emd_report::{self, Summary};
use gman_host_sim::model::{load_model, NavModel};
use gman_host_sim::sim::{Split, TargetKind, World};
use serde::ser::SerializeStruct;
use serde::{Serialize, Serializer};

use super::args::WorldArgs;
use super::model_args::ModelArgs;

/// `gman emd-report`.
#[derive(Debug, Args)]
#[command(mut_args(ModelArgs::emd_report_help))]
pub struct EmdReportArgs {
    /// World selection.
    #[command(flatten)]
    pub world: WorldArgs,
    /// A GMAN training checkpoint (or blob) whose inner loop is measured, in its own
    /// adaptation mode.
    #[arg(long, value_name = "MODEL")]
    pub agent: PathBuf,
    /// Treat the model as this method (e.g. measure an `a3c-fg` checkpoint as
    /// `gman-nometa`: the pre-trained G, adapted at test time only).
    #[arg(long, value_name = "METHOD", value_parser = super::args::method())]
    pub method: Option<gman_host_sim::model::Method>,
    /// Split whose official episodes are run (val or test).
    #[arg(long, default_value = "val")]
    pub split: String,
    /// At most N episodes per episode file (file order); all when omitted.
    #[arg(long, value_name = "N", default_value_t = 250)]
    pub episodes: usize,
    /// Overrides of the model's settings (default: the model's own).
    #[command(flatten)]
    pub model: ModelArgs,
    /// Write the Fig. 3 picture (two scenes, PCA) to this PNG.
    #[arg(long, value_name = "OUT.png")]
    pub png: Option<PathBuf>,
    /// Write every adapted episode's vectors (initial, adapted and true target feature, the
    /// kept views) as JSON, for analyses outside the tool.
    #[arg(long, value_name = "OUT.json")]
    pub dump: Option<PathBuf>,
    /// Write the summaries as JSON.
    #[arg(long, value_name = "OUT.json")]
    pub json: Option<PathBuf>,
}

/// The `--json` summary: the agent, the split, the model's inner-loop settings by their
/// keys, the summaries.
struct Report<'a> {
    agent: String,
    split: &'a str,
    spec: &'a ModelSpec,
    seen: Summary,
    unseen: Summary,
}

impl Serialize for Report<'_> {
    fn serialize<S: Serializer>(&self, s: S) -> std::result::Result<S::Ok, S::Error> {
        let mut r = s.serialize_struct("Report", 8)?;
        r.serialize_field("agent", &self.agent)?;
        r.serialize_field("split", self.split)?;
        r.serialize_field("inner_lr", &self.spec.inner_lr)?;
        r.serialize_field("max_inner", &self.spec.max_inner)?;
        r.serialize_field("inner_rule", &self.spec.inner_rule)?;
        r.serialize_field("mode", self.spec.adapt_mode.name())?;
        r.serialize_field("seen", &self.seen)?;
        r.serialize_field("unseen", &self.unseen)?;
        r.end()
    }
}

/// Runs `gman emd-report`.
pub fn cmd_emd_report(a: EmdReportArgs) -> Result<()> {
    let split = Split::parse(&a.split)?;
    if split == Split::Train {
        bail!("split train has no official episodes; use --split val or --split test");
    }
    for (flag, out) in [("--png", &a.png), ("--dump", &a.dump), ("--json", &a.json)] {
        if let Some(out) = out {
            super::args::refuse_output_over_inputs(flag, out, &[("--agent", &a.agent)])?;
        }
    }
    let world = a.world.load()?;
    let mut model = load_model(&a.agent, a.method)?;
    gman_host_sim::sim::spatial::check_grid_for_world(
        &world,
        model.dims.map_rows,
        model.dims.map_cols,
        &format!("model {}", a.agent.display()),
    )?;
    a.model.apply(&mut model.spec)?;
    let episodes = world.episodes(split, Some(a.episodes))?;
    eprintln!(
        "emd-report: {} episodes of {}, inner rate {} (α1 {}), cap {}, mode {:?}, {} D steps, {:?} step",
        episodes.len(),
        split.name(),
        model.spec.inner_lr,
        model.spec.inner_rule.disc_lr.unwrap_or(model.spec.inner_lr),
        model.spec.max_inner,
        model.spec.adapt_mode,
        model.spec.inner_rule.disc_steps,
        model.spec.inner_rule.step_rule
    );
    let records = emd_report::measure(&world, &model, &episodes)?;
    let seen = emd_report::summarize(&records, TargetKind::Seen);
    let unseen = emd_report::summarize(&records, TargetKind::Unseen);
    for (name, m) in [("seen", &seen), ("unseen", &unseen)] {
        println!(
            "{name}: {} adapted episodes; |G(y,0) - true target feature| {:.4} -> {:.4} ({:.2}% closed); G moved {:.5} (cosine to the true feature {:.3}, to the mean view {:.3}); the mean view is {:.4} from the true feature (the best point toward it closes {:.1}%); {:.1}% of G's dims saturated; {:.2} inner updates per episode, {:.3} rollbacks per update",
            m.episodes, m.before, m.after, m.closed_percent, m.moved, m.cos_to_true,
            m.cos_to_views, m.view_mean, m.best_toward_views_percent, m.saturated_percent,
            m.adaptations, m.rollbacks_per_update
        );
    }
    if records.is_empty() {
        println!("no episode reached an inner update (does the model adapt? is k larger than the episodes?)");
    }
    write_outputs(&a, &world, &model, split, &records, seen, unseen)
}

/// `--png` (Fig. 3), `--dump` (the records) and `--json` (the summaries).
fn write_outputs(
    a: &EmdReportArgs,
    world: &World,
    model: &NavModel,
    split: Split,
    records: &[emd_report::Record],
    seen: Summary,
    unseen: Summary,
) -> Result<()> {
    if let Some(png) = &a.png {
        let scenes = emd_report::busiest_scenes(records);
        let n = gman_host_sim::fig3::draw(&emd_report::figure(records, &scenes, world), png)?;
        let names: Vec<&str> = scenes
            .iter()
            .filter_map(|&s| world.scenes.get(s).map(|sc| sc.name.as_str()))
            .collect();
        println!(
            "wrote {}: Fig. 3 for {names:?} ({n} unseen-target episodes)",
            png.display()
        );
    }
    if let Some(path) = &a.dump {
        let text = serde_json::to_string(records)?;
        std::fs::write(path, text).with_context(|| format!("writing {}", path.display()))?;
        println!("wrote {} ({} episodes)", path.display(), records.len());
    }
    if let Some(path) = &a.json {
        let r = Report {
            agent: a.agent.display().to_string(),
            split: split.name(),
            spec: &model.spec,
            seen,
            unseen,
        };
        let text = serde_json::to_string_pretty(&r)?;
        std::fs::write(path, text).with_context(|| format!("writing {}", path.display()))?;
        println!("wrote {}", path.display());
    }
    Ok(())
}
