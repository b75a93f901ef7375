//! Pre-training of the PS module (`gman pretrain-ps`), and the network itself as the
//! navigation model uses it ([`PsModule`], re-exported from `ps_net.rs` beside this file).
//!
//! Trained supervised on `Observation::ps_target` (the mean attribute vector of the
//! categories in view, zeros when none) for views of **training** scenes only (which contain
//! only seen categories), with a binary cross-entropy loss on the sigmoid outputs
//! (`∂L/∂pre = y − t`, [`PsModule::backward_bce`]) and Adam.

use std::collections::HashSet;
use std::path::Path;
use std::time::Instant;

use anyhow::{bail, Context, Result};
use gman_core::nn::activation::leaky_relu_backward;
use gman_core::nn::dense::DenseGrads;
use gman_core::rng::Xoshiro128;
use gman_core::{ATTR_DIM, FEATURE_DIM};
use rand::RngCore;
use serde::Serialize;

use super::adam::{Adam, AdamConfig};
use super::checkpoint::{write_atomic, Checkpoint};
use super::fg::source_label;
use super::parallel::ChunkPool;
use super::params::ParamSet;
use super::rng_to_bytes;
use crate::progress::BarKind;
use crate::sim::util::hash2;
use crate::sim::{SceneId, Split, World};

pub use super::ps_net::{PsBuffers, PsModule};
pub(crate) use super::ps_net::{PS_B1, PS_B2, PS_W1, PS_W2};

impl PsModule {
    /// Accumulates the gradient of the BCE loss, weighted `coef`, of the sample in `buf`
    /// (after [`PsModule::forward_buf`] on `obs`) against `target` into `grads`. Returns the
    /// sample's mean BCE.
    pub fn backward_bce(
        &self,
        obs: &[f32],
        target: &[f32],
        coef: f32,
        buf: &mut PsBuffers,
        grads: &mut ParamSet,
    ) -> Result<f32> {
        let (l1, l2) = self.layers()?;
        let mut bce = 0.0f32;
        for ((d, &y), &t) in buf.dpre2.iter_mut().zip(&buf.y).zip(target) {
            *d = coef * (y - t);
            let yc = y.clamp(1e-7, 1.0 - 1e-7);
            bce -= t * yc.ln() + (1.0 - t) * (1.0 - yc).ln();
        }
        let [gw1, gb1, gw2, gb2] = grads.slices_mut([PS_W1, PS_B1, PS_W2, PS_B2])?;
        buf.dh.fill(0.0);
        l2.backward(
            &[&buf.h],
            &[],
            &buf.dpre2,
            Some(&mut [&mut buf.dh[..]]),
            &mut DenseGrads::Full { w: gw2, b: gb2 },
            &mut [],
        )?;
        leaky_relu_backward(&buf.h, &buf.dh, &mut buf.dpre1)?;
        l1.backward(
            &[obs],
            &[],
            &buf.dpre1,
            None,
            &mut DenseGrads::Full { w: gw1, b: gb1 },
            &mut [],
        )?;
        Ok(bce / ATTR_DIM as f32)
    }
}

/// One view: a state of a scene.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct PsView {
    /// Scene.
    pub scene: SceneId,
    /// State index.
    pub state: usize,
}

/// How [`collect_ps_data`] samples views.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct PsDataConfig {
    /// Distinct training-scene views (training plus held out).
    pub train_views: usize,
    /// Share of the training-scene views held out for the report.
    pub heldout: f32,
    /// Distinct val-scene views for the report.
    pub val_views: usize,
    /// Sampling seed.
    pub seed: u64,
}

impl Default for PsDataConfig {
    fn default() -> Self {
        PsDataConfig {
            train_views: 40_000,
            heldout: 0.1,
            val_views: 8_000,
            seed: 0,
        }
    }
}

/// Views for PS training and its report.
#[derive(Clone, Debug)]
pub struct PsData {
    /// Training views (training scenes).
    pub train: Vec<PsView>,
    /// Held-out training-scene views.
    pub heldout: Vec<PsView>,
    /// Val-scene views (report only).
    pub val: Vec<PsView>,
}

fn sample_views(world: &World, scenes: &[SceneId], n: usize, rng: &mut Xoshiro128) -> Vec<PsView> {
    let total: usize = scenes.iter().map(|&s| world.scenes[s].num_states()).sum();
    let n = n.min(total);
    let mut seen = HashSet::new();
    let mut out = Vec::with_capacity(n);
    while out.len() < n {
        let scene = scenes[(rng.next_u64() % scenes.len() as u64) as usize];
        let ns = world.scenes[scene].num_states();
        if ns == 0 {
            continue;
        }
        let v = PsView {
            scene,
            state: (rng.next_u64() % ns as u64) as usize,
        };
        if seen.insert(v) {
            out.push(v);
        }
    }
    out
}

/// Samples distinct random views (uniform over the states of the scenes of a split) of the
/// training scenes (split into training and held-out by a seeded hash) and of the val scenes.
pub fn collect_ps_data(world: &World, cfg: &PsDataConfig) -> Result<PsData> {
    if !(0.0..1.0).contains(&cfg.heldout) {
        bail!("held-out share must be in [0, 1), got {}", cfg.heldout);
    }
    let train_scenes = world.split_scenes(Split::Train)?;
    let val_scenes = world.split_scenes(Split::Val)?;
    let mut rng = Xoshiro128::seed_from_u64(cfg.seed);
    let all = sample_views(world, train_scenes, cfg.train_views, &mut rng);
    let cut = (cfg.heldout as f64 * (1u64 << 32) as f64) as u64;
    let (heldout, train): (Vec<_>, Vec<_>) = all.into_iter().partition(|v| {
        hash2(cfg.seed ^ 0x5053, ((v.scene as u64) << 32) | v.state as u64) & 0xFFFF_FFFF < cut
    });
    if train.is_empty() {
        bail!("no PS training views sampled");
    }
    let val = sample_views(world, val_scenes, cfg.val_views, &mut rng);
    Ok(PsData {
        train,
        heldout,
        val,
    })
}

/// Hyper-parameters of [`train_ps`].
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct PsTrainConfig {
    /// Hidden width.
    pub hidden: usize,
    /// Adam steps.
    pub iters: usize,
    /// Views per step.
    pub batch: usize,
    /// Adam.
    pub adam: AdamConfig,
    /// Seed of initialisation and batches.
    pub seed: u64,
    /// Gradient chunks per batch (the parallel grain).
    pub chunks: usize,
    /// Show a progress bar.
    #[serde(skip)]
    pub progress: bool,
}

impl Default for PsTrainConfig {
    fn default() -> Self {
        PsTrainConfig {
            hidden: 128,
            iters: 500,
            batch: 64,
            adam: AdamConfig {
                lr: 1e-3,
                ..AdamConfig::default()
            },
            seed: 0,
            chunks: 8,
            progress: false,
        }
    }
}

/// A logged training step.
#[derive(Clone, Copy, Debug, Serialize)]
pub struct PsLogPoint {
    /// Step (1-based).
    pub iter: usize,
    /// Mean BCE of the batch.
    pub bce: f64,
    /// Mean squared error of the batch.
    pub mse: f64,
}

/// Mean squared error of PS and of the mean-target baseline on a group of views.
#[derive(Clone, Debug, Default, Serialize)]
pub struct PsGroupEval {
    /// Views in the group.
    pub views: usize,
    /// Mean over views and dimensions of `(PS(s) − target)²`.
    pub mse: f64,
    /// The same for the constant prediction "mean training target".
    pub mse_mean_baseline: f64,
}

/// Held-out evaluation of PS.
#[derive(Clone, Debug, Serialize)]
pub struct PsEval {
    /// Held-out training-scene views.
    pub train_heldout: PsGroupEval,
    /// All val-scene views.
    pub val_all: PsGroupEval,
    /// Val views with nothing in view (target zeros).
    pub val_no_object: PsGroupEval,
    /// Val views whose objects in view are all seen (non-unseen) categories.
    pub val_seen_only: PsGroupEval,
    /// Val views with at least one unseen category in view.
    pub val_with_unseen: PsGroupEval,
}

/// Mean training target (the baseline predictor).
pub(crate) fn mean_target(world: &World, views: &[PsView]) -> [f32; ATTR_DIM] {
    let mut acc = [0f64; ATTR_DIM];
    for v in views {
        let t = &world.observation(v.scene, v.state).ps_target;
        acc.iter_mut().zip(t).for_each(|(a, &x)| *a += x as f64);
    }
    let mut out = [0f32; ATTR_DIM];
    for (o, a) in out.iter_mut().zip(acc) {
        *o = (a / views.len().max(1) as f64) as f32;
    }
    out
}

/// Scores `ps` and the mean-target baseline on the report groups.
pub(crate) fn evaluate_ps(
    world: &World,
    ps: &PsModule,
    data: &PsData,
    mean: &[f32; ATTR_DIM],
) -> Result<PsEval> {
    let mut buf = PsBuffers::new(ps.hidden);
    let mut group = |views: &mut dyn Iterator<Item = &PsView>| -> Result<PsGroupEval> {
        let mut e = PsGroupEval::default();
        for v in views {
            let o = world.observation(v.scene, v.state);
            ps.forward_buf(&o.features, &mut buf)?;
            let (mut a, mut b) = (0f64, 0f64);
            for ((&y, &t), &m) in buf.y.iter().zip(&o.ps_target).zip(mean) {
                a += ((y - t) as f64).powi(2);
                b += ((m - t) as f64).powi(2);
            }
            e.mse += a / ATTR_DIM as f64;
            e.mse_mean_baseline += b / ATTR_DIM as f64;
            e.views += 1;
        }
        let n = e.views.max(1) as f64;
        e.mse /= n;
        e.mse_mean_baseline /= n;
        Ok(e)
    };
    let has_unseen = |v: &PsView| {
        world
            .observation(v.scene, v.state)
            .in_view
            .iter()
            .any(|iv| world.categories[iv.category as usize].unseen)
    };
    let empty = |v: &PsView| world.observation(v.scene, v.state).in_view.is_empty();
    Ok(PsEval {
        train_heldout: group(&mut data.heldout.iter())?,
        val_all: group(&mut data.val.iter())?,
        val_no_object: group(&mut data.val.iter().filter(|v| empty(v)))?,
        val_seen_only: group(&mut data.val.iter().filter(|v| !empty(v) && !has_unseen(v)))?,
        val_with_unseen: group(&mut data.val.iter().filter(|v| has_unseen(v)))?,
    })
}

#[derive(Default)]
struct Sums {
    bce: f64,
    mse: f64,
}

impl std::ops::AddAssign for Sums {
    fn add_assign(&mut self, o: Sums) {
        self.bce += o.bce;
        self.mse += o.mse;
    }
}

/// Trains PS on `data.train`; returns the module, its Adam state, the RNG and the log.
pub fn train_ps(
    world: &World,
    data: &PsData,
    cfg: &PsTrainConfig,
) -> Result<(PsModule, Adam, Xoshiro128, Vec<PsLogPoint>)> {
    if cfg.batch == 0 {
        bail!("batch must be at least 1");
    }
    if data.train.is_empty() {
        bail!("no PS training views");
    }
    let mut rng = Xoshiro128::seed_from_u64(cfg.seed);
    let mut ps = PsModule::init(cfg.hidden, &mut rng)?;
    let mut adam = Adam::new(cfg.adam, &ps.params);
    let mut pool = ChunkPool::new(&ps.params, cfg.chunks, || PsBuffers::new(cfg.hidden));
    let mut grads = ps.params.zeros_like();
    let b = cfg.batch;
    let inv = 1.0 / b as f32;
    let mut idx = vec![0usize; b];
    let mut history = Vec::new();
    let log_every = (cfg.iters / 100).max(1);
    let pb = crate::progress::bar(BarKind::Pretrain, cfg.iters as u64, cfg.progress);
    let n = data.train.len() as u64;
    for it in 1..=cfg.iters {
        for i in idx.iter_mut() {
            *i = (rng.next_u64() % n) as usize;
        }
        let module = &ps;
        let sums = pool.accumulate(b, &mut grads, |range, g, buf| {
            let mut s = Sums::default();
            for t in range {
                let v = data.train[idx[t]];
                let o = world.observation(v.scene, v.state);
                module.forward_buf(&o.features, buf)?;
                s.mse += buf
                    .y
                    .iter()
                    .zip(&o.ps_target)
                    .map(|(&y, &t)| ((y - t) as f64).powi(2))
                    .sum::<f64>()
                    / ATTR_DIM as f64;
                s.bce += module.backward_bce(&o.features, &o.ps_target, inv, buf, g)? as f64;
            }
            Ok(s)
        })?;
        adam.step(&mut ps.params, &grads).context("PS update")?;
        let point = PsLogPoint {
            iter: it,
            bce: sums.bce / b as f64,
            mse: sums.mse / b as f64,
        };
        if it.is_multiple_of(log_every) || it == cfg.iters {
            history.push(point);
        }
        if it.is_multiple_of(50) {
            pb.set_message(format!("bce {:.4} mse {:.5}", point.bce, point.mse));
        }
        pb.inc(1);
    }
    pb.finish();
    Ok((ps, adam, rng, history))
}

/// The `ps_report.json` contents.
#[derive(Clone, Debug, Serialize)]
pub struct PsReport {
    /// Data source.
    pub data: String,
    /// World seed.
    pub world_seed: u64,
    /// View sampling.
    pub collect: PsDataConfig,
    /// Training hyper-parameters.
    pub train: PsTrainConfig,
    /// Views used: training, held out, val.
    pub views: [usize; 3],
    /// Seconds spent collecting, training and evaluating.
    pub seconds: serde_json::Value,
    /// Logged losses.
    pub history: Vec<PsLogPoint>,
    /// Before training (initial network).
    pub before: PsEval,
    /// After training.
    pub after: PsEval,
}

/// Everything `gman pretrain-ps` does: sample views, train, evaluate, write `out/ps.ckpt`
/// and `out/ps_report.json`.
pub fn run_pretrain_ps(
    world: &World,
    collect: &PsDataConfig,
    cfg: &PsTrainConfig,
    out: &Path,
) -> Result<PsReport> {
    std::fs::create_dir_all(out)
        .with_context(|| format!("cannot create output directory {}", out.display()))?;
    let t0 = Instant::now();
    let data = collect_ps_data(world, collect)?;
    let mean = mean_target(world, &data.train);
    let t_collect = t0.elapsed().as_secs_f64();
    let init = PsModule::init(cfg.hidden, &mut Xoshiro128::seed_from_u64(cfg.seed))?;
    let before = evaluate_ps(world, &init, &data, &mean)?;
    let t1 = Instant::now();
    let (ps, adam, rng, history) = train_ps(world, &data, cfg)?;
    let t_train = t1.elapsed().as_secs_f64();
    let t2 = Instant::now();
    let after = evaluate_ps(world, &ps, &data, &mean)?;
    let t_eval = t2.elapsed().as_secs_f64();
    let report = PsReport {
        data: source_label(world),
        world_seed: world.seed,
        collect: collect.clone(),
        train: cfg.clone(),
        views: [data.train.len(), data.heldout.len(), data.val.len()],
        seconds: serde_json::json!({"collect": t_collect, "train": t_train, "eval": t_eval}),
        history,
        before,
        after,
    };
    let mut ck = Checkpoint::new(serde_json::json!({
        "kind": "gman-ps-pretrain",
        "network": format!("{FEATURE_DIM} -> {} LeakyReLU(0.2) -> {ATTR_DIM} sigmoid", cfg.hidden),
        "hidden": cfg.hidden,
        "iterations": cfg.iters,
        "seed": cfg.seed,
        "world_seed": world.seed,
        "data": report.data,
        "collect": collect,
        "train": cfg,
    }));
    ck.add_tensors(&ps.params)?;
    ck.add_blob("adam", adam.to_bytes());
    ck.add_blob("rng", rng_to_bytes(&rng).to_vec());
    ck.save(&out.join("ps.ckpt"))?;
    let text = serde_json::to_string_pretty(&report)? + "\n";
    write_atomic(&out.join("ps_report.json"), |f| {
        use std::io::Write;
        f.write_all(text.as_bytes())
    })?;
    Ok(report)
}

/// The report as a text table.
pub fn report_table(r: &PsReport) -> String {
    let mut s = format!(
        "pretrain-ps (data {}): {} training views, {} held out, {} val views, {} steps\n",
        r.data, r.views[0], r.views[1], r.views[2], r.train.iters
    );
    s.push_str("group                              views |   MSE PS   MSE init  MSE mean-target\n");
    let rows = [
        (
            "training scenes, held-out views",
            &r.after.train_heldout,
            &r.before.train_heldout,
        ),
        ("val scenes, all views", &r.after.val_all, &r.before.val_all),
        (
            "val, nothing in view",
            &r.after.val_no_object,
            &r.before.val_no_object,
        ),
        (
            "val, only seen categories",
            &r.after.val_seen_only,
            &r.before.val_seen_only,
        ),
        (
            "val, an unseen category in view",
            &r.after.val_with_unseen,
            &r.before.val_with_unseen,
        ),
    ];
    for (name, a, b) in rows {
        s.push_str(&format!(
            "{name:<34} {:>5} | {:>8.5} {:>10.5} {:>16.5}\n",
            a.views, a.mse, b.mse, a.mse_mean_baseline
        ));
    }
    s
}
