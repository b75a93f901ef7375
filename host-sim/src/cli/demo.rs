//! `gman demo`: the quick start (pre-train G, train A3C+FG and GMAN briefly, evaluate them
//! and a random agent on every val episode, with 95% intervals, pictures and a summary).

use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Instant;

use anyhow::{Context, Result};
use clap::Args;
use gman_host_sim::eval::agent::NavAgent;
use gman_host_sim::model::{Method, NavModel};
use gman_host_sim::optim::adam::AdamConfig;
use gman_host_sim::pretrain::fg::{self};
use gman_host_sim::sim::eval::drive;
use gman_host_sim::sim::{
    mean_interval, wilson_interval, Agent, EpisodeResult, EpisodeSpec, EvalReport, RewardKind,
    TargetKind, World,
};
use gman_host_sim::train::run_dir::checkpoint_path;
use gman_host_sim::train::state::{RunSettings, TrainState};
use gman_host_sim::train::trainer::{train, TrainOptions};
use gman_render::draw_scene;
use serde::Serialize;

use super::args::{PresetArg, WorldArgs};
use super::plot::{cmd_plot, PlotArgs};
use super::train::ensure_fg;

/// How to run the `gman` binary from a checkout (it is not on PATH after `cargo build`).
pub const GMAN_CMD: &str = "target/release/gman";

/// `gman demo`.
#[derive(Debug, Args)]
pub struct DemoArgs {
    /// World selection.
    #[command(flatten)]
    pub world: WorldArgs,
    /// Output directory (summary.json, curve.png, episode.png, the runs).
    #[arg(long, default_value = "runs/demo")]
    pub out: PathBuf,
    /// Training updates per method.
    #[arg(long, default_value_t = 1000)]
    pub updates: u64,
    /// Val episodes per file evaluated (room type x seen/unseen, 8 files); default: all of
    /// them (250 per file in the built-in world, 2000 in all).
    #[arg(long, value_name = "N")]
    pub episodes: Option<usize>,
}

/// A success rate or SPL with its 95% interval (percent).
#[derive(Clone, Copy, Debug, Serialize)]
pub struct Rate {
    /// The value (%).
    pub value: f64,
    /// Lower end of the 95% interval (%).
    pub lo: f64,
    /// Upper end of the 95% interval (%).
    pub hi: f64,
}

impl Rate {
    fn overlaps(&self, o: &Rate) -> bool {
        self.lo <= o.hi && o.lo <= self.hi
    }
    fn cell(&self) -> String {
        format!("{:5.1} [{:4.1}, {:4.1}]", self.value, self.lo, self.hi)
    }
}

/// One target kind of an agent in `summary.json`.
#[derive(Clone, Copy, Debug, Serialize)]
pub struct KindResult {
    /// Episodes evaluated.
    pub episodes: usize,
    /// Successful episodes.
    pub successes: usize,
    /// Success rate with its Wilson 95% interval.
    pub sr: Rate,
    /// SPL with its normal-approximation 95% interval.
    pub spl: Rate,
}

impl KindResult {
    fn of(results: &[EpisodeResult], kind: TargetKind) -> KindResult {
        let mine: Vec<&EpisodeResult> = results.iter().filter(|r| r.kind == kind).collect();
        let n = mine.len();
        let k = mine.iter().filter(|r| r.metrics.success).count();
        let spls: Vec<f64> = mine.iter().map(|r| r.metrics.spl as f64).collect();
        let (slo, shi) = mean_interval(&spls);
        let (lo, hi) = wilson_interval(k, n);
        KindResult {
            episodes: n,
            successes: k,
            sr: Rate {
                value: if n == 0 {
                    0.0
                } else {
                    100.0 * k as f64 / n as f64
                },
                lo,
                hi,
            },
            spl: Rate {
                value: if n == 0 {
                    0.0
                } else {
                    100.0 * spls.iter().sum::<f64>() / n as f64
                },
                lo: slo,
                hi: shi,
            },
        }
    }
}

/// One agent (row) of `summary.json`.
#[derive(Clone, Debug, Serialize)]
pub struct AgentResult {
    /// Agent name (`random`, `a3c-fg`, `gman`).
    pub agent: String,
    /// Episodes evaluated (unseen + seen).
    pub episodes: usize,
    /// Unseen targets.
    pub unseen: KindResult,
    /// Seen targets.
    pub seen: KindResult,
    /// Whether both its unseen and seen SR intervals lie above the random agent's.
    pub above_random: bool,
}

/// `runs/demo/summary.json`.
#[derive(Clone, Debug, Serialize)]
pub struct DemoSummary {
    /// Split evaluated.
    pub split: String,
    /// World (`synthetic` or the data directory).
    pub world: String,
    /// Training updates per method.
    pub updates: u64,
    /// How the intervals are computed.
    pub interval: String,
    /// One entry per agent.
    pub agents: Vec<AgentResult>,
    /// Whether GMAN and A3C+FG differ by more than their intervals on unseen or seen SR.
    pub gman_vs_a3c_fg_distinguishable: bool,
    /// The demo's verdict in words (also printed).
    pub verdict: Vec<String>,
    /// Wall-clock seconds of the whole demo.
    pub seconds: f64,
}

fn table(rows: &[AgentResult], split: &str) -> String {
    let mut s = format!(
        "{:<8} | {:^32} | {:^32} | {:>8}\n",
        split, "Unseen SR / SPL (%)", "Seen SR / SPL (%)", "episodes"
    );
    s.push_str(&format!(
        "{:<8} | {:^18} {:>13} | {:^18} {:>13} | {:>8}\n",
        "agent", "SR [95% CI]", "SPL", "SR [95% CI]", "SPL", ""
    ));
    for r in rows {
        s.push_str(&format!(
            "{:<8} | {} {:>13} | {} {:>13} | {:>8}\n",
            r.agent,
            r.unseen.sr.cell(),
            format!("{:.1}", r.unseen.spl.value),
            r.seen.sr.cell(),
            format!("{:.1}", r.seen.spl.value),
            r.episodes
        ));
    }
    s
}

/// Runs one episode with `agent`, recording the path.
fn walk(
    world: &World,
    spec: &EpisodeSpec,
    agent: &mut dyn Agent,
) -> (bool, Vec<gman_host_sim::sim::AgentState>) {
    let cfg = gman_host_sim::sim::EvalConfig::default();
    let mut env =
        gman_host_sim::sim::Env::new(world, spec, cfg.reward, cfg.limits.for_room(spec.room));
    env.record_trajectory(true);
    drive(&mut env, spec, agent);
    (env.metrics().success, env.trajectory().to_vec())
}

/// `episode.png`: the first val episode (file order) with an unseen target that the model
/// solves in at least 6 actions (else any such solved episode, else the first episode), drawn on its floor plan with the target.
fn draw_episode(
    world: &World,
    episodes: &[EpisodeSpec],
    results: &[EpisodeResult],
    model: &Arc<NavModel>,
    png: &Path,
) -> Result<String> {
    let pick = results
        .iter()
        .position(|r| {
            r.metrics.success && r.kind == TargetKind::Unseen && r.metrics.path_length >= 6
        })
        .or_else(|| {
            results
                .iter()
                .position(|r| r.metrics.success && r.metrics.path_length >= 6)
        })
        .or_else(|| results.iter().position(|r| r.metrics.success))
        .unwrap_or(0);
    let spec = &episodes[pick];
    let mut agent = NavAgent::new(model.clone());
    let (success, path) = walk(world, spec, &mut agent);
    let title = format!(
        "{}: {}, target {} ({}), {} actions, {}",
        world.scenes[spec.scene].name,
        model.method.name(),
        world.category_name(spec.target),
        spec.kind.name(),
        path.len().saturating_sub(1),
        if success { "success" } else { "failure" }
    );
    draw_scene(
        world,
        spec.scene,
        Some(spec.target),
        &path,
        png,
        Some(&title),
    )?;
    Ok(format!(
        "{}: {} episode {} in {}, target {} ({}), {} actions, {}",
        png.display(),
        model.method.name(),
        pick,
        world.scenes[spec.scene].name,
        world.category_name(spec.target),
        spec.kind.name(),
        path.len().saturating_sub(1),
        if success { "success" } else { "failure" }
    ))
}

/// `gman demo`: pre-train G, train A3C+FG and GMAN briefly, evaluate them and a random agent.
pub fn cmd_demo(a: DemoArgs) -> Result<()> {
    let t0 = Instant::now();
    let world = a.world.load()?;
    std::fs::create_dir_all(&a.out).with_context(|| format!("creating {}", a.out.display()))?;
    let fg_path = ensure_fg(
        &world,
        PresetArg::Mcu,
        None,
        &a.out.join("fg"),
        true,
        1,
        true,
    )?;
    let gen = fg::load_generator(&fg_path, &gman_core::Dims::MCU)?;
    let split = gman_host_sim::sim::Split::Val;
    let episodes = world.episodes(split, a.episodes)?;
    let cfg = gman_host_sim::sim::EvalConfig {
        reward: RewardKind::Mixed,
        limits: gman_host_sim::sim::EpisodeLimits::default(),
        progress: true,
    };
    let mut detail = String::new();
    let mut rows = Vec::new();
    eprintln!("evaluating random on {} val episodes", episodes.len());
    let rnd = gman_host_sim::sim::evaluate(
        &world,
        &episodes,
        |_| Box::new(gman_host_sim::sim::RandomAgent::new(0)),
        &cfg,
    );
    detail.push_str(&EvalReport::new(split.name(), "random", &rnd).table());
    rows.push(("random".to_string(), rnd));
    let mut last_model = None;
    for method in [Method::A3cFg, Method::Gman] {
        let model = train_method(&world, &a, method, &gen)?;
        eprintln!(
            "evaluating {} on {} val episodes",
            method.name(),
            episodes.len()
        );
        let res = gman_host_sim::sim::evaluate(
            &world,
            &episodes,
            |_| Box::new(NavAgent::new(model.clone())),
            &cfg,
        );
        detail.push_str(&EvalReport::new(split.name(), method.name(), &res).table());
        rows.push((method.name().to_string(), res));
        last_model = Some(model);
    }
    std::fs::write(a.out.join("table.txt"), &detail)
        .with_context(|| format!("writing {}", a.out.join("table.txt").display()))?;

    let agents = agent_results(&rows);
    let (verdict, distinguishable) = verdict(&agents, a.updates, episodes.len());
    let pictures = draw_pictures(&a, &world, &episodes, &rows, last_model.as_ref())?;
    let summary = DemoSummary {
        split: split.name().to_string(),
        world: a
            .world
            .data
            .as_ref()
            .map_or("synthetic".to_string(), |d| d.display().to_string()),
        updates: a.updates,
        interval: "95%: Wilson score interval for SR, mean ± 1.96 standard errors for SPL".into(),
        agents,
        gman_vs_a3c_fg_distinguishable: distinguishable,
        verdict,
        seconds: t0.elapsed().as_secs_f64(),
    };
    let sp = a.out.join("summary.json");
    std::fs::write(&sp, serde_json::to_string_pretty(&summary)? + "\n")
        .with_context(|| format!("writing {}", sp.display()))?;
    print_summary(&a, &summary, &rows[0].1, &sp, &pictures);
    Ok(())
}

/// Trains `method` for the demo's updates in `OUT/METHOD` (resuming its checkpoint when there
/// is one) and returns the trained model.
fn train_method(
    world: &World,
    a: &DemoArgs,
    method: Method,
    gen: &gman_host_sim::optim::params::ParamSet,
) -> Result<Arc<NavModel>> {
    let dir = a.out.join(method.name());
    let state_path = checkpoint_path(&dir);
    let mut state = if state_path.exists() {
        TrainState::load(&state_path)?
    } else {
        // The setting of the README's results: the mcu preset with a 3 x 3 spatial map, the
        // inner loop in the device's Efficient mode.
        let dims = gman_core::Dims::MCU.with_map(3, 3, 8);
        let mut model = NavModel::init(method, dims, 1, Some(gen), None)?;
        model.spec.adapt_mode = gman_core::navigator::memory::AdaptMode::Efficient;
        TrainState::new(
            model,
            AdamConfig {
                lr: 1e-3,
                ..AdamConfig::default()
            },
        )
    };
    eprintln!("training {} ({} updates)", method.name(), a.updates);
    let opts = TrainOptions {
        updates: a.updates,
        run: RunSettings {
            adam: AdamConfig {
                lr: 1e-3,
                ..AdamConfig::default()
            },
            ..RunSettings::default()
        },
        checkpoint_every: 100,
        out: dir,
        progress: true,
    };
    train(world, &opts, &mut state)?;
    Ok(Arc::new(state.model))
}

/// The rows of `summary.json`: every agent's unseen and seen results and whether both SR
/// intervals lie above the random agent's (`rows[0]`).
fn agent_results(rows: &[(String, Vec<EpisodeResult>)]) -> Vec<AgentResult> {
    let rnd_u = KindResult::of(&rows[0].1, TargetKind::Unseen);
    let rnd_s = KindResult::of(&rows[0].1, TargetKind::Seen);
    rows.iter()
        .map(|(name, res)| {
            let unseen = KindResult::of(res, TargetKind::Unseen);
            let seen = KindResult::of(res, TargetKind::Seen);
            AgentResult {
                agent: name.clone(),
                episodes: res.len(),
                above_random: name != "random"
                    && unseen.sr.lo > rnd_u.sr.hi
                    && seen.sr.lo > rnd_s.sr.hi,
                unseen,
                seen,
            }
        })
        .collect()
}

/// The verdict in words (random, a3c-fg, gman in `agents`) and whether gman and a3c-fg
/// differ by more than their intervals.
fn verdict(agents: &[AgentResult], updates: u64, episodes: usize) -> (Vec<String>, bool) {
    let mut verdict = Vec::new();
    for r in agents.iter().skip(1) {
        verdict.push(if r.above_random {
            format!(
                "{} is above random: its unseen and seen SR intervals lie above random's.",
                r.agent
            )
        } else {
            format!(
                "{} is NOT clearly above random at this budget: an SR interval overlaps random's.",
                r.agent
            )
        });
    }
    let (fg, gm) = (&agents[1], &agents[2]);
    let distinguishable =
        !fg.unseen.sr.overlaps(&gm.unseen.sr) || !fg.seen.sr.overlaps(&gm.seen.sr);
    verdict.push(if distinguishable {
        let better = |x: &Rate, y: &Rate| if x.value > y.value { "gman" } else { "a3c-fg" };
        format!(
            "gman vs a3c-fg: the intervals separate (higher unseen SR: {}, higher seen SR: {}).",
            better(&gm.unseen.sr, &fg.unseen.sr),
            better(&gm.seen.sr, &fg.seen.sr)
        )
    } else {
        format!(
            "gman and a3c-fg cannot be told apart at this budget ({updates} updates, {episodes} episodes): their 95% intervals overlap on unseen and seen SR, so their order in the table is noise. Telling them apart takes longer training (`gman train`) and several seeds.",
        )
    });
    (verdict, distinguishable)
}

/// `curve.png` (the two training curves) and `episode.png` (an episode of the last model);
/// returns a line per picture.
fn draw_pictures(
    a: &DemoArgs,
    world: &World,
    episodes: &[EpisodeSpec],
    rows: &[(String, Vec<EpisodeResult>)],
    last_model: Option<&Arc<NavModel>>,
) -> Result<Vec<String>> {
    let mut pictures = Vec::new();
    let curve = a.out.join("curve.png");
    cmd_plot(PlotArgs {
        runs: vec![
            a.out.join(Method::A3cFg.name()),
            a.out.join(Method::Gman.name()),
        ],
        png: curve.clone(),
        smooth: 50,
        by_method: false,
    })?;
    pictures.push(format!(
        "{}: training success rate and reward of a3c-fg (red) and gman (blue)",
        curve.display()
    ));
    if let Some(model) = last_model {
        pictures.push(draw_episode(
            world,
            episodes,
            &rows[2].1,
            model,
            &a.out.join("episode.png"),
        )?);
    }
    Ok(pictures)
}

/// Prints the table, the verdict and what was written.
fn print_summary(
    a: &DemoArgs,
    summary: &DemoSummary,
    random: &[EpisodeResult],
    sp: &Path,
    pictures: &[String],
) {
    let rnd_u = KindResult::of(random, TargetKind::Unseen);
    let rnd_s = KindResult::of(random, TargetKind::Seen);
    println!();
    print!("{}", table(&summary.agents, &summary.split));
    println!(
        "{} val episodes per agent ({} unseen, {} seen targets); [..] = 95% interval (Wilson); SR = success rate, SPL = success weighted by path length.",
        summary.agents[0].episodes, rnd_u.episodes, rnd_s.episodes
    );
    for v in &summary.verdict {
        println!("{v}");
    }
    println!();
    println!(
        "wrote {} (per room: {})",
        sp.display(),
        a.out.join("table.txt").display()
    );
    for p in pictures {
        println!("wrote {p}");
    }
    println!(
        "demo finished in {:.0} s. Evaluate a run yourself: `{GMAN_CMD} eval --agent {}/gman/checkpoint.ckpt` (or `cargo run --release -p gman-host-sim --bin gman -- eval ...`).",
        summary.seconds,
        a.out.display()
    );
}
