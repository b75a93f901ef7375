//! `gman train`: train a navigation method, or resume a run exactly.

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{anyhow, bail, Context, Result};
use gman_host_sim::model::NavModel;
use gman_host_sim::optim::adam::AdamConfig;
use gman_host_sim::pretrain::fg::{self, FgCollectConfig, FgTrainConfig};
use gman_host_sim::pretrain::ps::{self, PsDataConfig, PsModule, PsTrainConfig};
use gman_host_sim::sim::World;
use gman_host_sim::train::dist::{Group, Single};
use gman_host_sim::train::run_dir::checkpoint_path;
use gman_host_sim::train::state::{RunSettings, TrainState, WorldId};
use gman_host_sim::train::trainer::{train_in, Distributed};

use super::args::{PresetArg, WorldArgs};
use super::train_config::{
    check_train_flags, check_train_numbers, flag_options, model_spec, updates_and_lr, RunConfig,
};
pub use super::train_config::{ConfigArg, TrainArgs, MAX_EPISODE_STEPS};

pub(super) fn preset_matches(model: &NavModel, preset: PresetArg) -> Result<()> {
    let d = preset.dims();
    let m = model.dims;
    if (m.gen_hidden, m.disc_hidden, m.lstm_hidden, m.embed, m.feat)
        != (d.gen_hidden, d.disc_hidden, d.lstm_hidden, d.embed, d.feat)
    {
        bail!(
            "the model has {:?} sizes, not the {} preset",
            m,
            preset.name()
        );
    }
    Ok(())
}

/// Pre-trains G into `dir` unless `given` names a checkpoint; returns its path. The report
/// goes to stderr as the table of `gman pretrain-fg`, or with `plain` in plain words (`gman demo`).
pub(super) fn ensure_fg(
    world: &World,
    preset: PresetArg,
    given: Option<&Path>,
    dir: &Path,
    tiny: bool,
    seed: u64,
    plain: bool,
) -> Result<PathBuf> {
    if let Some(p) = given {
        return Ok(p.to_path_buf());
    }
    let path = dir.join("fg.ckpt");
    if path.exists() {
        eprintln!(
            "using the generator pre-trained earlier in {}",
            path.display()
        );
        return Ok(path);
    }
    eprintln!(
        "no --fg given: pre-training the feature generator into {}",
        dir.display()
    );
    let iters = match (tiny, preset) {
        (true, _) => 400,
        (false, PresetArg::Mcu) => 1500,
        (false, PresetArg::Paper) => 300,
    };
    let mut cfg = FgTrainConfig::new(iters, seed);
    cfg.progress = true;
    let collect = FgCollectConfig {
        seed,
        ..FgCollectConfig::default()
    };
    let r = fg::run_pretrain_fg(world, preset.name(), &preset.dims(), &collect, &cfg, dir)?;
    if plain {
        eprint!("{}", fg::report_plain(&r));
    } else {
        eprint!("{}", fg::report_table(&r));
    }
    Ok(path)
}

/// Pre-trains the PS module into `dir` unless `given` names one; returns its path.
fn ensure_ps(world: &World, given: Option<&Path>, dir: &Path, seed: u64) -> Result<PathBuf> {
    if let Some(p) = given {
        return Ok(p.to_path_buf());
    }
    let path = dir.join("ps.ckpt");
    if path.exists() {
        return Ok(path);
    }
    eprintln!(
        "no --ps given: pre-training the PS module into {}",
        dir.display()
    );
    let cfg = PsTrainConfig {
        seed,
        progress: true,
        ..PsTrainConfig::default()
    };
    let collect = PsDataConfig {
        seed,
        ..PsDataConfig::default()
    };
    let r = ps::run_pretrain_ps(world, &collect, &cfg, dir)?;
    eprint!("{}", ps::report_table(&r));
    Ok(path)
}

/// What world `w` selects (loaded as `world`), as stored in a run's checkpoint: kind, world
/// seed and, for a data directory, its object layout and a fingerprint of the contents that
/// layout reads (the path may change, the data must not).
fn world_identity(w: &WorldArgs, world: &World) -> Result<WorldId> {
    Ok(match &w.data {
        Some(dir) => WorldId::of_data_dir(
            dir,
            w.world_seed,
            &w.visible_file,
            world.layout,
            world.domain_shift(),
        )?,
        None => WorldId::Synthetic {
            world_seed: w.world_seed,
            domain_shift: world.domain_shift(),
        },
    })
}

/// `gman train`. `explicit(id)` says whether the flag of field `id` was given on the command
/// line (on `--resume`, only those are checked against the checkpoint's settings). Started by
/// an MPI launcher (`mpirun`, `srun`; build with `--features mpi`), the run spans its ranks,
/// `--workers` per rank (see `docs/distributed.md`).
pub fn cmd_train(a: TrainArgs, explicit: &dyn Fn(&str) -> bool) -> Result<()> {
    #[cfg(feature = "mpi")]
    if gman_host_sim::train::mpi::launched_by_mpi() {
        let mut g = gman_host_sim::train::mpi::MpiGroup::init()?;
        let r = train_on(a, explicit, &mut g);
        if let Err(e) = &r {
            if g.size() > 1 {
                // The other ranks may wait in a collective: end the whole job.
                eprintln!("error (rank {}): {e:#}", g.rank());
                g.abort(1);
            }
        }
        return r;
    }
    #[cfg(not(feature = "mpi"))]
    if ["OMPI_COMM_WORLD_SIZE", "PMI_SIZE"]
        .iter()
        .any(|v| std::env::var(v).is_ok_and(|n| n != "1"))
    {
        bail!("this gman was built without MPI, so each of the launcher's processes would train alone; build it with `cargo build --release --features mpi`");
    }
    train_on(a, explicit, &mut Single)
}

/// [`cmd_train`] on the ranks of `group`.
fn train_on(
    mut a: TrainArgs,
    explicit: &dyn Fn(&str) -> bool,
    group: &mut dyn Group,
) -> Result<()> {
    check_train_flags(&a)?;
    check_train_numbers(&a)?;
    let (rank, ranks) = (group.rank(), group.size());
    let lead = rank == 0;
    // From here on `workers` counts the workers of all ranks, the number the run stores.
    let per_rank = a.workers;
    a.workers = per_rank.saturating_mul(ranks);
    RunConfig::from_flags(&a)?.validate()?;
    if a.resume.is_some() && lead {
        // Flags that only shape a new run have no effect here: said so, not silently dropped.
        for (flag, id) in [("--fg", "fg"), ("--ps", "ps"), ("--config", "config")] {
            if explicit(id) && !(id == "config" && a.updates.is_none()) {
                eprintln!("warning: {flag} is ignored on --resume: a resumed run keeps the networks and settings it was started with");
            }
        }
    }
    let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
    if per_rank > cores && lead {
        eprintln!(
            "warning: --workers {per_rank} runs {per_rank} threads on {cores} core(s); the run is reproducible for its worker count but slower than with --workers {cores}"
        );
    }
    if !lead {
        a.quiet = true;
    }
    let run_dir = a.resume.clone().or_else(|| a.out.clone());
    let _lock = match (&run_dir, lead) {
        (Some(d), true) => Some(gman_host_sim::train::run_dir::lock_run_dir(d)?),
        _ => None,
    };
    let world = load_world(&a)?;
    let world_id = world_identity(&a.world, &world)?;
    let mut opts = flag_options(&a);
    let mut state = match &a.resume {
        Some(dir) => {
            let (mut state, run) = open_resumed(&a, dir, &world_id, explicit)?;
            opts.out = dir.clone();
            opts.run = run;
            opts.updates = resumed_target(&a, &state, dir)?;
            state.target_updates = Some(opts.updates);
            state
        }
        None => {
            let out = a
                .out
                .clone()
                .ok_or_else(|| anyhow!("--out RUN_DIR is required"))?;
            // Rank 0 pre-trains G and the PS module into the run directory; the others
            // then load what it wrote.
            let mut state = None;
            if lead {
                state = Some(new_run(&a, &world, &out, world_id.clone())?);
            }
            group.barrier();
            let mut state = match state {
                Some(s) => s,
                None => new_run(&a, &world, &out, world_id)?,
            };
            state.target_updates = Some(opts.updates);
            opts.out = out;
            state
        }
    };
    let t0 = Instant::now();
    let steps0 = state.env_steps;
    let mut dist = Distributed {
        group,
        check_every: a.rank_check_every,
    };
    let comm = train_in(&world, &opts, &mut state, &mut dist)?;
    if lead {
        report_trained(&state, &opts.out, steps0, t0.elapsed().as_secs_f64());
        if ranks > 1 {
            eprintln!("mpi: {}", comm.summary(ranks));
        }
    }
    check_finite_run(&state, &opts.out)
}

/// The update count a resumed run trains to: `--updates` when given (refused below the
/// checkpoint's update), else the target stored in the checkpoint; a checkpoint of an older
/// build without one needs `--updates` (the preset's count could be below the checkpoint's
/// update, or far beyond what the run was asked for). Printed either way.
fn resumed_target(a: &TrainArgs, st: &TrainState, dir: &Path) -> Result<u64> {
    let target = match (a.updates, st.target_updates) {
        (Some(n), _) => {
            if n < st.update {
                bail!(
                    "--updates {n} on resuming {}: the checkpoint is already at update {}; give a target of at least {}{}",
                    dir.display(),
                    st.update,
                    st.update,
                    st.target_updates.map_or(String::new(), |t| format!(
                        " (or omit --updates to continue to the stored target, {t})"
                    ))
                );
            }
            n
        }
        (None, Some(t)) => t,
        (None, None) => bail!(
            "{}: its checkpoint predates stored targets (it does not record the run's --updates, so where the run was meant to stop is unknown); it is at update {}: give --updates N (at least {}) to resume",
            dir.display(),
            st.update,
            st.update
        ),
    };
    eprintln!(
        "target: update {target} ({} to go){}",
        target.saturating_sub(st.update),
        if a.updates.is_some() {
            " (--updates)"
        } else {
            " (stored in the checkpoint)"
        }
    );
    Ok(target)
}

/// Loads the world, refusing a map grid offline data cannot serve, and fails now (not after
/// pre-training) if no training start can satisfy `--min-start-actions` (a separate
/// generator: the run's own draws are untouched).
fn load_world(a: &TrainArgs) -> Result<World> {
    let world = a.world.load()?;
    gman_host_sim::sim::spatial::check_grid_for_world(
        &world,
        a.map.0,
        a.map.1,
        &format!("--map {}x{}", a.map.0, a.map.1),
    )?;
    // Offline scenes are read now: a feature file with bad values is an error naming it.
    world.prepare_split(gman_host_sim::sim::Split::Train)?;
    use rand::SeedableRng;
    let mut probe = rand_chacha::ChaCha8Rng::seed_from_u64(0);
    world.try_sample_train_episode_min(&mut probe, a.min_start_actions)?;
    Ok(world)
}

/// A new run in `out`: pre-trains (or loads) G and the PS module as the method needs, and
/// initialises the model with the flags' settings.
fn new_run(a: &TrainArgs, world: &World, out: &Path, world_id: WorldId) -> Result<TrainState> {
    std::fs::create_dir_all(out).with_context(|| format!("creating {}", out.display()))?;
    if checkpoint_path(out).exists() {
        bail!(
            "{} already holds a run; use --resume {} to continue it, or another --out",
            out.display(),
            out.display()
        );
    }
    let tiny = a.config == ConfigArg::Tiny;
    let gen = if a.method.uses_fg() {
        let p = ensure_fg(
            world,
            a.preset,
            a.fg.as_deref(),
            &out.join("fg"),
            tiny,
            a.seed,
            false,
        )?;
        Some(
            fg::load_generator(&p, &a.preset.dims())
                .with_context(|| format!("loading generator {}", p.display()))?,
        )
    } else {
        None
    };
    let psm = if a.method.uses_ps() {
        let p = ensure_ps(world, a.ps.as_deref(), &out.join("ps"), a.seed)?;
        Some(PsModule::load(&p).with_context(|| format!("loading PS module {}", p.display()))?)
    } else {
        None
    };
    let (rows, cols) = a.map;
    let dims = if rows > 0 {
        a.preset.dims().with_map(rows, cols, a.cell_embed)
    } else {
        a.preset.dims()
    };
    let mut model = NavModel::init(a.method, dims, a.seed, gen.as_ref(), psm)?;
    model.privileged = a.privileged_feature;
    model.spec = model_spec(a)?;
    let adam = AdamConfig {
        lr: updates_and_lr(a).1,
        ..AdamConfig::default()
    };
    let mut st = TrainState::new(model, adam);
    st.world = Some(world_id);
    Ok(st)
}

/// Opens the run in `dir` to continue it with its own settings (bit-exact resume): the
/// checkpoint's model and [`RunSettings`], checked against the world and against the flags
/// given explicitly.
fn open_resumed(
    a: &TrainArgs,
    dir: &Path,
    world_id: &WorldId,
    explicit: &dyn Fn(&str) -> bool,
) -> Result<(TrainState, RunSettings)> {
    let ck = checkpoint_path(dir);
    let (mut st, meta) = TrainState::load_with_settings(&ck)
        .with_context(|| format!("resuming {}", dir.display()))?;
    if let Some(w) = &st.world {
        if let Some(warning) = w
            .check_same(world_id)
            .with_context(|| format!("resuming {}", dir.display()))?
        {
            eprintln!("warning: resuming {}: {warning}", dir.display());
        }
        // The same data: from now on the checkpoint stores this build's fingerprint of it.
        st.world = Some(world_id.clone());
    }
    if explicit("preset") {
        preset_matches(&st.model, a.preset).with_context(|| {
            format!("--preset {} on resuming {}", a.preset.name(), dir.display())
        })?;
    }
    eprintln!(
        "resuming {} ({}) at update {}",
        dir.display(),
        st.model.method.name(),
        st.update
    );
    let run = RunConfig::stored(&st.model, &meta.run).resume(
        &RunConfig::from_flags(a)?,
        a.change_workers,
        explicit,
        &ck,
    )?;
    if !st.model.params.all_finite() {
        bail!(
            "{}: the model holds non-finite weights; the run diverged before this checkpoint and cannot be resumed",
            ck.display()
        );
    }
    if st.world.is_none() {
        // A checkpoint that does not record its world gets the one it resumes on.
        st.world = Some(world_id.clone());
    }
    Ok((st, run))
}

/// The closing line of a run.
/// Training that produced non-finite weights or NaN/inf metrics fails (exit non-zero),
/// naming what and where: its checkpoint and curve are not a valid result.
fn check_finite_run(state: &TrainState, out: &Path) -> Result<()> {
    if !state.model.params.all_finite() {
        bail!(
            "training produced non-finite weights (update {}); {} is not a valid model",
            state.update,
            checkpoint_path(out).display()
        );
    }
    let csv = out.join("metrics.csv");
    if let Ok(text) = std::fs::read_to_string(&csv) {
        let bad: Vec<usize> = text
            .lines()
            .enumerate()
            .skip(1)
            .filter(|(_, l)| {
                // success_rate ..= grad_norm are always numbers (disc_gap and adapt_loss are
                // NaN by design in updates without an inner update).
                l.split(',').skip(3).take(7).any(|f| {
                    let f = f.trim().to_ascii_lowercase();
                    f.contains("nan") || f.contains("inf")
                })
            })
            .map(|(i, _)| i + 1)
            .collect();
        if let Some(first) = bad.first() {
            bail!(
                "training produced NaN or infinite metrics: {} row(s) of {} (first: line {first}); the run diverged",
                bad.len(),
                csv.display()
            );
        }
    }
    Ok(())
}

fn report_trained(state: &TrainState, out: &Path, steps0: u64, secs: f64) {
    let d = state.model.dims;
    let preset_name = [PresetArg::Mcu, PresetArg::Paper]
        .into_iter()
        .find(|p| {
            let pd = p.dims();
            (pd.gen_hidden, pd.disc_hidden, pd.lstm_hidden, pd.embed)
                == (d.gen_hidden, d.disc_hidden, d.lstm_hidden, d.embed)
        })
        .map_or("custom", |p| p.name());
    eprintln!(
        "trained {} ({}) to update {}: {} episodes, {} env steps ({:.0} steps/s over this run, {:.1} s); wrote {} and {}",
        state.model.method.name(),
        preset_name,
        state.update,
        state.episodes,
        state.env_steps,
        (state.env_steps - steps0) as f64 / secs.max(1e-9),
        secs,
        out.join("metrics.csv").display(),
        checkpoint_path(out).display()
    );
}
