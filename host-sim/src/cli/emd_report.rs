//! `gman emd-report`: the paper's Fig. 3 as a measurement (see `gman_host_sim::emd_report`).

use std::path::PathBuf;

use anyhow::{bail, Context, Result};
use clap::Args;
use gman_host_sim::emd_report::{self, Summary};
use gman_host_sim::model::{load_model, NavModel};
use gman_host_sim::sim::{Split, TargetKind, World};
use serde::Serialize;

use super::args::WorldArgs;

/// `gman emd-report`.
#[derive(Debug, Args)]
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
    #[arg(long, value_name = "METHOD")]
    pub method: Option<gman_host_sim::model::Method>,
    /// Split whose official episodes are run (val or test).
    #[arg(long, default_value = "val")]
    pub split: String,
    /// At most N episodes per episode file (file order); all when omitted.
    #[arg(long, value_name = "N", default_value_t = 250)]
    pub episodes: usize,
    /// Override the inner-loop rate α (α1 = α2).
    #[arg(long, value_name = "ALPHA")]
    pub inner_lr: Option<f32>,
    /// Override α1 alone (D's ascent rate on L_D).
    #[arg(long, value_name = "ALPHA1")]
    pub disc_lr: Option<f32>,
    /// Override D's ascent steps per inner update.
    #[arg(long, value_name = "N")]
    pub disc_steps: Option<u32>,
    /// Override the descent step rule (`gradient` or `normalized`).
    #[arg(long, value_parser = super::args::named::<gman_core::navigator::StepRule>())]
    pub step_rule: Option<gman_core::navigator::StepRule>,
    /// Override the cap on inner updates per episode.
    #[arg(long, value_name = "N")]
    pub max_inner: Option<u32>,
    /// D restarts with every episode (layer 1 from ω, the output layer at zero): D starts with
    /// no opinion and its first ascent step on L_D sets the head from the episode's buffer.
    #[arg(long)]
    pub disc_head_reset: bool,
    /// The descent step adapts only the actor head (G stays at θ; the reference's default).
    #[arg(long)]
    pub adapt_head_only: bool,
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

#[derive(Serialize)]
struct Report<'a> {
    agent: String,
    split: &'a str,
    inner_lr: f32,
    max_inner: u32,
    inner_rule: gman_host_sim::model::InnerRule,
    mode: &'a str,
    seen: Summary,
    unseen: Summary,
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
    apply_inner_flags(&a, &mut model)?;
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

/// The inner-rule flags given on the command line, applied to `model` and checked.
fn apply_inner_flags(a: &EmdReportArgs, model: &mut NavModel) -> Result<()> {
    if let Some(lr) = a.inner_lr {
        model.spec.inner_lr = lr;
    }
    if let Some(n) = a.max_inner {
        model.spec.max_inner = n;
    }
    if a.disc_lr.is_some() {
        model.spec.inner_rule.disc_lr = a.disc_lr;
    }
    if let Some(n) = a.disc_steps {
        model.spec.inner_rule.disc_steps = n;
    }
    if let Some(r) = a.step_rule {
        model.spec.inner_rule.step_rule = r;
    }
    if a.disc_head_reset {
        model.spec.inner_rule.disc_head_reset = true;
    }
    if a.adapt_head_only {
        model.spec.inner_rule.head_only = true;
    }
    model.spec().validate()?;
    Ok(())
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
        let n = emd_report::plot(records, &scenes, world, png)?;
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
            inner_lr: model.spec.inner_lr,
            max_inner: model.spec.max_inner,
            inner_rule: model.spec.inner_rule,
            mode: gman_core::spec::Named::name(model.spec.adapt_mode),
            seen,
            unseen,
        };
        let text = serde_json::to_string_pretty(&r)?;
        std::fs::write(path, text).with_context(|| format!("writing {}", path.display()))?;
        println!("wrote {}", path.display());
    }
    Ok(())
}
