//! Feature-generator pre-training (paper Sec. 4.1): data collection in the training scenes,
//! conditional WGAN-GP training of G(SE(y), z) against the host critic D_c(x, SE(y)), and the
//! held-out report.
//!
//! # Data
//! `D_train = {(x^s, SE(y^s))}`: for every seen category (the world's seen targets, minus any
//! category flagged unseen) and every instance of it in every **training** scene, the
//! `views_per_instance` views where the instance is the largest object in view
//! ([`World::dominant_views`]) and fills at least `min_weight` of the embedding. A seeded
//! `holdout` share of the instances of each category is kept out of training and used for the
//! report ("seen held-out"). The report also uses the same kind of views from the **val**
//! scenes, of seen and of unseen categories; those never enter training.
//!
//! # Training (f-CLSWGAN style)
//! Per generator step, `n_critic` critic steps minimise
//! `mean D_c(G(a, z), a) − mean D_c(x, a) + λ mean (‖∇_x D_c(x̂, a)‖ − 1)²` (real `x` with its
//! category's `a`, the fake generated from the same `a`). The generator step minimises
//! `−mean D_c(G(a, z), a) + reg · mean_i (1/F) ‖G(a_i, z_i) − μ_{y_i}‖²`, `μ_y` the mean
//! training feature of category y (the optional regression term; `reg = 0` is pure WGAN-GP).
//! Both use Adam. Every forward and backward of G and D_c runs on gman-core's kernels.

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{bail, Context, Result};
use gman_core::rng::{fill_gaussian, uniform, Xoshiro128};
use gman_core::Dims;
use rand::RngCore;
use rayon::prelude::*;
use serde::Serialize;

use super::adam::{Adam, AdamConfig};
use super::checkpoint::{write_atomic, Checkpoint};
use super::critic::{critic_grads, init_critic, CondCritic, CriticScratch, CriticSums};
use super::generator::{gen_names, generator_view, init_generator, GenBuffers};
use super::parallel::ChunkPool;
use super::params::ParamSet;
use super::{dims_json, rng_from_bytes, rng_to_bytes};
use crate::progress::BarKind;
use crate::sim::util::{hash2, mix64};
use crate::sim::{CategoryId, SceneId, Split, World, WorldSource};

/// One real object feature.
#[derive(Clone, Debug)]
pub struct FeatureSample {
    /// Scene of the view.
    pub scene: SceneId,
    /// State index of the view in the scene.
    pub state: usize,
    /// Category of the dominant object.
    pub category: CategoryId,
    /// Instance index of the dominant object in the scene.
    pub instance: usize,
    /// Share of the embedding the object fills.
    pub weight: f32,
    /// The view's 512-d features.
    pub features: Vec<f32>,
}

/// How [`collect_fg_data`] selects views.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct FgCollectConfig {
    /// Views per instance (the instance's dominant views with the largest share).
    pub views_per_instance: usize,
    /// Minimum share of the embedding the object must fill.
    pub min_weight: f32,
    /// Share of each seen category's training-scene instances held out for the report.
    pub holdout: f32,
    /// Seed of the held-out instance choice.
    pub seed: u64,
}

impl Default for FgCollectConfig {
    fn default() -> Self {
        FgCollectConfig {
            views_per_instance: 6,
            min_weight: 0.2,
            holdout: 0.2,
            seed: 0,
        }
    }
}

/// The feature data of pre-training and its report.
#[derive(Clone, Debug)]
pub struct FgDataset {
    /// Training samples: seen categories, training scenes, not held out.
    pub train: Vec<FeatureSample>,
    /// Held-out instances of seen categories in training scenes (report only).
    pub heldout: Vec<FeatureSample>,
    /// Seen categories in val scenes (report only).
    pub val_seen: Vec<FeatureSample>,
    /// Unseen categories in val scenes (report only).
    pub val_unseen: Vec<FeatureSample>,
    /// The seen categories used (those with training data).
    pub seen: Vec<CategoryId>,
    /// The unseen categories with val views.
    pub unseen: Vec<CategoryId>,
}

fn views_of(
    world: &World,
    scenes: &[SceneId],
    cats: &[CategoryId],
    cfg: &FgCollectConfig,
) -> Vec<FeatureSample> {
    let per_scene: Vec<Vec<FeatureSample>> = scenes
        .par_iter()
        .map(|&s| {
            let mut out = Vec::new();
            for &c in cats {
                for v in world.dominant_views(s, c, cfg.views_per_instance) {
                    if v.weight >= cfg.min_weight {
                        out.push(FeatureSample {
                            scene: s,
                            state: v.state,
                            category: c,
                            instance: v.instance,
                            weight: v.weight,
                            features: v.features.to_vec(),
                        });
                    }
                }
            }
            out
        })
        .collect();
    per_scene.into_iter().flatten().collect()
}

/// Collects the pre-training data (see the module docs). Training samples come only from
/// training scenes and seen categories; fails if there are none.
pub fn collect_fg_data(world: &World, cfg: &FgCollectConfig) -> Result<FgDataset> {
    if cfg.views_per_instance == 0 {
        bail!("views per instance must be at least 1");
    }
    if !(0.0..1.0).contains(&cfg.holdout) {
        bail!("held-out share must be in [0, 1), got {}", cfg.holdout);
    }
    let seen: Vec<CategoryId> = world
        .seen
        .iter()
        .copied()
        .filter(|&c| !world.categories[c as usize].unseen)
        .collect();
    let unseen: Vec<CategoryId> = world.unseen.clone();
    let train_scenes = world.split_scenes(Split::Train)?.to_vec();
    let val_scenes = world.split_scenes(Split::Val)?.to_vec();
    let all_train = views_of(world, &train_scenes, &seen, cfg);
    // Held-out instances: per category, a seeded shuffle of its (scene, instance) pairs; the
    // first `holdout` share (at least one when there are two or more) is held out.
    let mut held = std::collections::HashSet::new();
    for &c in &seen {
        let mut inst: Vec<(SceneId, usize)> = all_train
            .iter()
            .filter(|v| v.category == c)
            .map(|v| (v.scene, v.instance))
            .collect();
        inst.sort_unstable();
        inst.dedup();
        inst.sort_by_key(|&(s, i)| hash2(mix64(cfg.seed ^ c as u64), (s as u64) << 20 | i as u64));
        let k = if inst.len() >= 2 {
            ((cfg.holdout * inst.len() as f32).round() as usize)
                .clamp(usize::from(cfg.holdout > 0.0), inst.len() - 1)
        } else {
            0
        };
        held.extend(inst.into_iter().take(k));
    }
    let (heldout, train): (Vec<_>, Vec<_>) = all_train
        .into_iter()
        .partition(|v| held.contains(&(v.scene, v.instance)));
    if train.is_empty() {
        bail!(
            "no training views of seen categories in the training scenes (min weight {} too high?)",
            cfg.min_weight
        );
    }
    let seen_with_data: Vec<CategoryId> = seen
        .iter()
        .copied()
        .filter(|c| train.iter().any(|v| v.category == *c))
        .collect();
    let val_seen = views_of(world, &val_scenes, &seen_with_data, cfg);
    let val_unseen_all = views_of(world, &val_scenes, &unseen, cfg);
    let unseen_with_data: Vec<CategoryId> = unseen
        .iter()
        .copied()
        .filter(|c| val_unseen_all.iter().any(|v| v.category == *c))
        .collect();
    Ok(FgDataset {
        train,
        heldout,
        val_seen,
        val_unseen: val_unseen_all,
        seen: seen_with_data,
        unseen: unseen_with_data,
    })
}

/// Default weight of the feature-regression term: pure WGAN-GP (`reg = 0`) had not reached
/// the class-mean reference in 1500 steps on either world (see `docs/training.md`).
pub const DEFAULT_REG: f32 = 100.0;

/// Hyper-parameters of [`train_fg`].
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct FgTrainConfig {
    /// Generator steps.
    pub iters: usize,
    /// Samples per critic and generator step.
    pub batch: usize,
    /// Critic steps per generator step.
    pub n_critic: usize,
    /// Gradient-penalty coefficient λ.
    pub lambda: f32,
    /// Weight of the feature-regression term (0: pure WGAN-GP).
    pub reg: f32,
    /// Adam of G.
    pub adam_gen: AdamConfig,
    /// Adam of the critic.
    pub adam_critic: AdamConfig,
    /// Seed of initialisation, batches and noise.
    pub seed: u64,
    /// Fixed number of gradient chunks per batch (the parallel grain; results do not depend
    /// on the thread count).
    pub chunks: usize,
    /// Show a progress bar.
    #[serde(skip)]
    pub progress: bool,
}

impl FgTrainConfig {
    /// Defaults: Adam lr 5e-4, betas (0.5, 0.999), no AMSGrad for both networks, λ = 10,
    /// 5 critic steps, batch 64, regression weight [`DEFAULT_REG`].
    pub fn new(iters: usize, seed: u64) -> FgTrainConfig {
        let adam = AdamConfig {
            lr: 5e-4,
            beta1: 0.5,
            beta2: 0.999,
            eps: 1e-8,
            amsgrad: false,
            clip_norm: None,
        };
        FgTrainConfig {
            iters,
            batch: 64,
            n_critic: 5,
            lambda: 10.0,
            reg: DEFAULT_REG,
            adam_gen: adam,
            adam_critic: adam,
            seed,
            chunks: 8,
            progress: false,
        }
    }
}

/// Losses of one logged generator step.
#[derive(Clone, Copy, Debug, Default, Serialize)]
pub struct FgLogPoint {
    /// Generator step (1-based).
    pub iter: usize,
    /// Critic's Wasserstein estimate `mean D(real) − mean D(fake)` (last critic step).
    pub wasserstein: f64,
    /// Mean gradient penalty (last critic step).
    pub penalty: f64,
    /// Mean `‖∇_x D‖` at the interpolates (last critic step).
    pub grad_norm: f64,
    /// Generator's adversarial loss `−mean D(G(a, z), a)`.
    pub g_adv: f64,
    /// Mean `(1/F) ‖G(a, z) − μ_y‖²` over the generator batch (computed even when `reg = 0`).
    pub g_mse_to_mean: f64,
}

/// The trained networks and their optimiser and RNG state.
#[derive(Clone, Debug)]
pub struct FgState {
    /// G's tensors (`GenW1`, `GenB1`, `GenW2`, `GenB2`).
    pub gen: ParamSet,
    /// The critic's tensors (`CriticW1`, ...).
    pub critic: ParamSet,
    /// Adam of G.
    pub adam_gen: Adam,
    /// Adam of the critic.
    pub adam_critic: Adam,
    /// The training RNG after the last step.
    pub rng: Xoshiro128,
    /// Generator steps done.
    pub iters_done: usize,
    /// Logged losses.
    pub history: Vec<FgLogPoint>,
}

impl FgState {
    /// Fresh networks for `dims` from `cfg.seed`.
    pub fn new(dims: &Dims, cfg: &FgTrainConfig) -> Result<FgState> {
        let mut rng = Xoshiro128::seed_from_u64(cfg.seed);
        let gen = init_generator(dims, &mut rng)?;
        let critic = init_critic(dims, &mut rng)?;
        Ok(FgState {
            adam_gen: Adam::new(cfg.adam_gen, &gen),
            adam_critic: Adam::new(cfg.adam_critic, &critic),
            gen,
            critic,
            rng,
            iters_done: 0,
            history: Vec::new(),
        })
    }
}

#[derive(Default)]
struct GenSums {
    adv: f64,
    mse: f64,
}

impl std::ops::AddAssign for GenSums {
    fn add_assign(&mut self, o: GenSums) {
        self.adv += o.adv;
        self.mse += o.mse;
    }
}

/// Per-category mean feature of `samples` (rows indexed by category id; zeros when absent).
pub(crate) fn class_means(
    samples: &[FeatureSample],
    n_categories: usize,
    f: usize,
) -> Vec<Vec<f32>> {
    let mut sums = vec![vec![0f64; f]; n_categories];
    let mut counts = vec![0usize; n_categories];
    for s in samples {
        let c = s.category as usize;
        counts[c] += 1;
        sums[c]
            .iter_mut()
            .zip(&s.features)
            .for_each(|(a, &v)| *a += v as f64);
    }
    sums.into_iter()
        .zip(counts)
        .map(|(s, n)| {
            s.into_iter()
                .map(|v| if n > 0 { (v / n as f64) as f32 } else { 0.0 })
                .collect()
        })
        .collect()
}

struct Scratch {
    gb: GenBuffers,
    cs: CriticScratch,
    dx: Vec<f32>,
}

/// The working state of [`train_fg`]: the chunk pools, gradients and per-step draws.
struct FgSteps<'a> {
    world: &'a World,
    data: &'a FgDataset,
    cfg: &'a FgTrainConfig,
    /// Per-category mean training feature (the regression term's target).
    means: Vec<Vec<f32>>,
    cpool: ChunkPool<Scratch>,
    gpool: ChunkPool<Scratch>,
    cgrad: ParamSet,
    ggrad: ParamSet,
    idx: Vec<usize>,
    zs: Vec<f32>,
    eps: Vec<f32>,
    feat: usize,
    noise: usize,
}

impl<'a> FgSteps<'a> {
    fn new(
        world: &'a World,
        dims: &Dims,
        data: &'a FgDataset,
        cfg: &'a FgTrainConfig,
        state: &FgState,
    ) -> Self {
        let (f, a, z) = (dims.feat, dims.attr, dims.noise);
        let new_scratch = || Scratch {
            gb: GenBuffers::new(dims.gen_hidden, f),
            cs: CriticScratch::new(dims.disc_hidden, f, a),
            dx: vec![0.0; f],
        };
        FgSteps {
            world,
            data,
            cfg,
            means: class_means(&data.train, world.categories.len(), f),
            cpool: ChunkPool::new(&state.critic, cfg.chunks, new_scratch),
            gpool: ChunkPool::new(&state.gen, cfg.chunks, new_scratch),
            cgrad: state.critic.zeros_like(),
            ggrad: state.gen.zeros_like(),
            idx: vec![0usize; cfg.batch],
            zs: vec![0f32; cfg.batch * z],
            eps: vec![0f32; cfg.batch],
            feat: f,
            noise: z,
        }
    }

    /// Draws the batch's sample indices and noise.
    fn draw_batch(&mut self, state: &mut FgState) {
        let n = self.data.train.len() as u64;
        for i in self.idx.iter_mut() {
            *i = (state.rng.next_u64() % n) as usize;
        }
        fill_gaussian(&mut state.rng, &mut self.zs);
    }

    /// One critic step: the WGAN-GP loss on a fresh batch, then Adam.
    fn critic_step(&mut self, state: &mut FgState) -> Result<CriticSums> {
        let (f, z, b) = (self.feat, self.noise, self.cfg.batch);
        let inv_n = 1.0 / b as f32;
        self.draw_batch(state);
        for e in self.eps.iter_mut() {
            *e = uniform(&mut state.rng);
        }
        let gen = generator_view(&state.gen)?;
        let critic = CondCritic::from_params(&state.critic, f)?;
        let (world, data, cfg) = (self.world, self.data, self.cfg);
        let (idx, zs, eps) = (&self.idx, &self.zs, &self.eps);
        let sums = self.cpool.accumulate(b, &mut self.cgrad, |range, g, s| {
            let mut cg = critic_grads(g)?;
            let mut sums = CriticSums::default();
            for t in range {
                let smp = &data.train[idx[t]];
                let attr = world.attributes(smp.category);
                s.gb.forward(&gen, &zs[t * z..(t + 1) * z], attr)?;
                sums += critic.wgan_gp_accumulate(
                    &smp.features,
                    &s.gb.x,
                    attr,
                    &eps[t..t + 1],
                    cfg.lambda,
                    inv_n,
                    &mut s.cs,
                    &mut cg,
                )?;
            }
            Ok(sums)
        })?;
        state
            .adam_critic
            .step(&mut state.critic, &self.cgrad)
            .context("critic update")?;
        Ok(sums)
    }

    /// One generator step: the adversarial loss plus the regression to the category mean on
    /// a fresh batch, then Adam.
    fn generator_step(&mut self, state: &mut FgState) -> Result<GenSums> {
        let (f, z, b) = (self.feat, self.noise, self.cfg.batch);
        let inv_n = 1.0 / b as f32;
        self.draw_batch(state);
        let gen = generator_view(&state.gen)?;
        let critic = CondCritic::from_params(&state.critic, f)?;
        let reg_coef = self.cfg.reg * inv_n * 2.0 / f as f32;
        let (world, data, means) = (self.world, self.data, &self.means);
        let (idx, zs) = (&self.idx, &self.zs);
        let gs = self.gpool.accumulate(b, &mut self.ggrad, |range, g, s| {
            let mut sums = GenSums::default();
            for t in range {
                let smp = &data.train[idx[t]];
                let attr = world.attributes(smp.category);
                let zt = &zs[t * z..(t + 1) * z];
                s.gb.forward(&gen, zt, attr)?;
                sums.adv -= critic.score(&s.gb.x, attr, &mut s.cs)? as f64;
                critic.input_grad(&mut s.cs)?;
                let mu = &means[smp.category as usize];
                let mut mse = 0f64;
                for (((d, &gi), &x), &m) in s.dx.iter_mut().zip(&s.cs.g).zip(&s.gb.x).zip(mu) {
                    *d = -inv_n * gi + reg_coef * (x - m);
                    mse += ((x - m) as f64).powi(2);
                }
                sums.mse += mse / f as f64;
                let dx = std::mem::take(&mut s.dx);
                let r = s.gb.backward(&gen, zt, attr, &dx, g);
                s.dx = dx;
                r?;
            }
            Ok(sums)
        })?;
        state
            .adam_gen
            .step(&mut state.gen, &self.ggrad)
            .context("generator update")?;
        Ok(gs)
    }
}

/// Runs `cfg.iters - state.iters_done` generator steps (each after `cfg.n_critic` critic
/// steps) on `data.train`. Deterministic for a seed: batches and noise are drawn on the
/// calling thread and gradients are summed in a fixed order (`optim::parallel::ChunkPool`).
pub fn train_fg(
    world: &World,
    dims: &Dims,
    data: &FgDataset,
    cfg: &FgTrainConfig,
    state: &mut FgState,
) -> Result<()> {
    if data.train.is_empty() {
        bail!("no training samples");
    }
    if cfg.batch == 0 || cfg.n_critic == 0 {
        bail!("batch and n_critic must be at least 1");
    }
    let mut steps = FgSteps::new(world, dims, data, cfg, state);
    let todo = cfg.iters.saturating_sub(state.iters_done);
    let pb = crate::progress::bar(BarKind::Pretrain, todo as u64, cfg.progress);
    let log_every = (cfg.iters / 100).max(1);
    for _ in 0..todo {
        let mut last = CriticSums::default();
        for _ in 0..cfg.n_critic {
            last = steps.critic_step(state)?;
        }
        let gs = steps.generator_step(state)?;
        state.iters_done += 1;
        let bf = cfg.batch as f64;
        let point = FgLogPoint {
            iter: state.iters_done,
            wasserstein: (last.real - last.fake) / bf,
            penalty: last.penalty / bf,
            grad_norm: last.grad_norm / bf,
            g_adv: gs.adv / bf,
            g_mse_to_mean: gs.mse / bf,
        };
        if state.iters_done.is_multiple_of(log_every) || state.iters_done == cfg.iters {
            state.history.push(point);
        }
        if state.iters_done.is_multiple_of(10) {
            pb.set_message(format!(
                "W {:.3} gp {:.3} G {:.3} mse {:.4}",
                point.wasserstein, point.penalty, point.g_adv, point.g_mse_to_mean
            ));
        }
        pb.inc(1);
    }
    pb.finish();
    Ok(())
}

/// How well generated prototypes match real views of one group of categories.
#[derive(Clone, Debug, Default, Serialize)]
pub struct GroupEval {
    /// Real views evaluated.
    pub views: usize,
    /// Categories in the group (with views).
    pub categories: usize,
    /// Mean L2 distance of a view to its own category's prototype.
    pub l2_own: f64,
    /// Mean (over views) of the mean L2 distance to the other categories' prototypes.
    pub l2_other: f64,
    /// `l2_own / l2_other` (below 1: generated features are closer to their own category).
    pub own_over_other: f64,
    /// Mean cosine similarity to the own prototype.
    pub cos_own: f64,
    /// Mean cosine similarity to the other prototypes of the group.
    pub cos_other: f64,
    /// Share of views whose nearest prototype (L2, among the group's categories) is their own
    /// category's.
    pub nearest_acc: f64,
    /// Chance level of `nearest_acc` (1 / categories).
    pub chance: f64,
    /// Share of views whose nearest prototype among all seen and unseen categories is their
    /// own (generalised setting).
    pub nearest_acc_all: f64,
}

/// Euclidean distance, accumulated in f64.
pub(crate) fn l2(a: &[f32], b: &[f32]) -> f64 {
    a.iter()
        .zip(b)
        .map(|(x, y)| ((x - y) as f64).powi(2))
        .sum::<f64>()
        .sqrt()
}

fn cos(a: &[f32], b: &[f32]) -> f64 {
    let (mut ab, mut aa, mut bb) = (0f64, 0f64, 0f64);
    for (&x, &y) in a.iter().zip(b) {
        ab += x as f64 * y as f64;
        aa += x as f64 * x as f64;
        bb += y as f64 * y as f64;
    }
    ab / (aa.sqrt() * bb.sqrt()).max(1e-12)
}

/// Scores prototypes (`protos[c]` for category id `c`, `None` when absent) on `samples`:
/// `group` are the categories competing within the group, `all` the categories of the
/// generalised nearest-prototype test.
pub(crate) fn eval_group(
    protos: &[Option<Vec<f32>>],
    group: &[CategoryId],
    all: &[CategoryId],
    samples: &[FeatureSample],
) -> GroupEval {
    let cats: Vec<CategoryId> = group
        .iter()
        .copied()
        .filter(|&c| protos[c as usize].is_some() && samples.iter().any(|s| s.category == c))
        .collect();
    let mut e = GroupEval {
        categories: cats.len(),
        chance: 1.0 / cats.len().max(1) as f64,
        ..Default::default()
    };
    for s in samples.iter().filter(|s| cats.contains(&s.category)) {
        let own = protos[s.category as usize].as_deref().unwrap_or_default();
        let d_own = l2(&s.features, own);
        e.l2_own += d_own;
        e.cos_own += cos(&s.features, own);
        let (mut d_other, mut c_other, mut k) = (0.0, 0.0, 0usize);
        let mut best = (f64::MAX, s.category);
        for &c in &cats {
            let p = protos[c as usize].as_deref().unwrap_or_default();
            let d = l2(&s.features, p);
            if d < best.0 {
                best = (d, c);
            }
            if c != s.category {
                d_other += d;
                c_other += cos(&s.features, p);
                k += 1;
            }
        }
        if k > 0 {
            e.l2_other += d_other / k as f64;
            e.cos_other += c_other / k as f64;
        }
        e.nearest_acc += (best.1 == s.category) as u8 as f64;
        let mut best_all = (f64::MAX, s.category);
        for &c in all {
            if let Some(p) = &protos[c as usize] {
                let d = l2(&s.features, p);
                if d < best_all.0 {
                    best_all = (d, c);
                }
            }
        }
        e.nearest_acc_all += (best_all.1 == s.category) as u8 as f64;
        e.views += 1;
    }
    let v = e.views.max(1) as f64;
    for x in [
        &mut e.l2_own,
        &mut e.l2_other,
        &mut e.cos_own,
        &mut e.cos_other,
        &mut e.nearest_acc,
        &mut e.nearest_acc_all,
    ] {
        *x /= v;
    }
    e.own_over_other = if e.l2_other > 0.0 {
        e.l2_own / e.l2_other
    } else {
        f64::NAN
    };
    e
}

/// Generated prototype of every category in `cats`: the mean of `k` samples `G(SE(c), z)`
/// with noise from a fixed seed (indexed by category id; `None` for the others).
pub(crate) fn generated_prototypes(
    world: &World,
    gen: &ParamSet,
    dims: &Dims,
    cats: &[CategoryId],
    k: usize,
    seed: u64,
) -> Result<Vec<Option<Vec<f32>>>> {
    let g = generator_view(gen)?;
    let mut out = vec![None; world.categories.len()];
    let mut gb = GenBuffers::new(dims.gen_hidden, dims.feat);
    let mut z = vec![0f32; dims.noise];
    for &c in cats {
        let mut rng = Xoshiro128::seed_from_u64(hash2(seed, c as u64));
        let mut acc = vec![0f64; dims.feat];
        for _ in 0..k.max(1) {
            fill_gaussian(&mut rng, &mut z);
            gb.forward(&g, &z, world.attributes(c))?;
            acc.iter_mut().zip(&gb.x).for_each(|(a, &v)| *a += v as f64);
        }
        out[c as usize] = Some(
            acc.into_iter()
                .map(|v| (v / k.max(1) as f64) as f32)
                .collect(),
        );
    }
    Ok(out)
}

/// Evaluation of generated prototypes on the three report groups.
#[derive(Clone, Debug, Serialize)]
pub struct FgEval {
    /// Seen categories, held-out instances in training scenes.
    pub seen_heldout: GroupEval,
    /// Seen categories in val scenes.
    pub seen_val: GroupEval,
    /// Unseen categories in val scenes (never trained on).
    pub unseen_val: GroupEval,
}

/// Scores G (prototypes from `noise_samples` noise draws) on the dataset's report groups.
pub(crate) fn evaluate_fg(
    world: &World,
    gen: &ParamSet,
    dims: &Dims,
    data: &FgDataset,
    noise_samples: usize,
) -> Result<FgEval> {
    let all: Vec<CategoryId> = data.seen.iter().chain(&data.unseen).copied().collect();
    let protos = generated_prototypes(world, gen, dims, &all, noise_samples, 0xF6)?;
    Ok(FgEval {
        seen_heldout: eval_group(&protos, &data.seen, &all, &data.heldout),
        seen_val: eval_group(&protos, &data.seen, &all, &data.val_seen),
        unseen_val: eval_group(&protos, &data.unseen, &all, &data.val_unseen),
    })
}

/// Sizes of the collected data.
#[derive(Clone, Debug, Serialize)]
pub struct DatasetSummary {
    /// Training views.
    pub train_views: usize,
    /// Held-out views (seen categories, training scenes).
    pub heldout_views: usize,
    /// Val-scene views of seen categories.
    pub val_seen_views: usize,
    /// Val-scene views of unseen categories.
    pub val_unseen_views: usize,
    /// Seen category names.
    pub seen_categories: Vec<String>,
    /// Unseen category names.
    pub unseen_categories: Vec<String>,
}

/// The `fg_report.json` contents.
#[derive(Clone, Debug, Serialize)]
pub struct FgReport {
    /// Preset name.
    pub preset: String,
    /// Network sizes.
    pub dims: serde_json::Value,
    /// Data source (`synthetic` or the data directory).
    pub data: String,
    /// World seed.
    pub world_seed: u64,
    /// Data selection.
    pub collect: FgCollectConfig,
    /// Training hyper-parameters.
    pub train: FgTrainConfig,
    /// Data sizes.
    pub dataset: DatasetSummary,
    /// Seconds spent collecting data, training and evaluating.
    pub seconds: serde_json::Value,
    /// Logged losses.
    pub history: Vec<FgLogPoint>,
    /// Noise samples per generated prototype.
    pub noise_samples: usize,
    /// Generated prototypes before training (initial G).
    pub before: FgEval,
    /// Generated prototypes after training.
    pub after: FgEval,
    /// Reference: the mean real training view of each seen category as its prototype (what
    /// a perfect generator of seen training-scene features could reach; seen groups only).
    pub reference_train_mean: ReferenceEval,
}

/// The class-mean reference rows of the report.
#[derive(Clone, Debug, Serialize)]
pub struct ReferenceEval {
    /// Seen categories, held-out instances in training scenes.
    pub seen_heldout: GroupEval,
    /// Seen categories in val scenes.
    pub seen_val: GroupEval,
}

/// Data-source label of a world.
pub(crate) fn source_label(world: &World) -> String {
    match &world.source {
        WorldSource::Synthetic => "synthetic".into(),
        WorldSource::Data(d) | WorldSource::Offline(d) => d.display().to_string(),
    }
}

/// Everything `gman pretrain-fg` does, minus argument parsing: collect, train, evaluate,
/// write `out/fg.ckpt` and `out/fg_report.json`. Returns the report.
pub fn run_pretrain_fg(
    world: &World,
    preset: &str,
    dims: &Dims,
    collect: &FgCollectConfig,
    cfg: &FgTrainConfig,
    out: &Path,
) -> Result<FgReport> {
    std::fs::create_dir_all(out)
        .with_context(|| format!("cannot create output directory {}", out.display()))?;
    let t0 = Instant::now();
    let data = collect_fg_data(world, collect)?;
    let t_collect = t0.elapsed().as_secs_f64();
    let names = |v: &[CategoryId]| -> Vec<String> {
        v.iter()
            .map(|&c| world.category_name(c).to_string())
            .collect()
    };
    let dataset = DatasetSummary {
        train_views: data.train.len(),
        heldout_views: data.heldout.len(),
        val_seen_views: data.val_seen.len(),
        val_unseen_views: data.val_unseen.len(),
        seen_categories: names(&data.seen),
        unseen_categories: names(&data.unseen),
    };
    if cfg.progress {
        eprintln!(
            "collected {} training views of {} seen categories ({} held out, {} seen / {} unseen in val scenes) in {:.1} s",
            dataset.train_views, data.seen.len(), dataset.heldout_views, dataset.val_seen_views, dataset.val_unseen_views, t_collect
        );
    }
    let mut state = FgState::new(dims, cfg)?;
    let noise_samples = 16;
    let t1 = Instant::now();
    let before = evaluate_fg(world, &state.gen, dims, &data, noise_samples)?;
    train_fg(world, dims, &data, cfg, &mut state)?;
    let t_train = t1.elapsed().as_secs_f64();
    let t2 = Instant::now();
    let after = evaluate_fg(world, &state.gen, dims, &data, noise_samples)?;
    let means = class_means(&data.train, world.categories.len(), dims.feat);
    let mean_protos: Vec<Option<Vec<f32>>> = means
        .into_iter()
        .enumerate()
        .map(|(c, m)| data.seen.contains(&(c as CategoryId)).then_some(m))
        .collect();
    let reference = ReferenceEval {
        seen_heldout: eval_group(&mean_protos, &data.seen, &data.seen, &data.heldout),
        seen_val: eval_group(&mean_protos, &data.seen, &data.seen, &data.val_seen),
    };
    let t_eval = t2.elapsed().as_secs_f64();
    let report = FgReport {
        preset: preset.to_string(),
        dims: dims_json(dims),
        data: source_label(world),
        world_seed: world.seed,
        collect: collect.clone(),
        train: cfg.clone(),
        dataset,
        seconds: serde_json::json!({"collect": t_collect, "train": t_train, "eval": t_eval}),
        history: state.history.clone(),
        noise_samples,
        before,
        after,
        reference_train_mean: reference,
    };
    let mut ck = Checkpoint::new(serde_json::json!({
        "kind": "gman-fg-pretrain",
        "preset": preset,
        "dims": dims_json(dims),
        "iterations": state.iters_done,
        "seed": cfg.seed,
        "world_seed": world.seed,
        "data": report.data,
        "collect": collect,
        "train": cfg,
        "generator_tensors": gen_names(),
        "critic": "conditional WGAN-GP critic D_c([x; SE(y)]), LeakyReLU 0.2, tensors Critic*",
    }));
    ck.add_tensors(&state.gen)?;
    ck.add_tensors(&state.critic)?;
    ck.add_blob("adam_gen", state.adam_gen.to_bytes());
    ck.add_blob("adam_critic", state.adam_critic.to_bytes());
    ck.add_blob("rng", rng_to_bytes(&state.rng).to_vec());
    let ckpt_path = out.join("fg.ckpt");
    ck.save(&ckpt_path)?;
    let report_path = out.join("fg_report.json");
    let text = serde_json::to_string_pretty(&report)? + "\n";
    write_atomic(&report_path, |f| {
        use std::io::Write;
        f.write_all(text.as_bytes())
    })?;
    Ok(report)
}

/// Loads G's tensors (and checks them against `dims`) from an `fg.ckpt`.
pub fn load_generator(path: &Path, dims: &Dims) -> Result<ParamSet> {
    let ck = Checkpoint::load(path)?;
    let like = init_generator(dims, &mut Xoshiro128::seed_from_u64(0))?;
    Ok(ck.params_like(&like)?)
}

/// Restores the full training state saved by [`run_pretrain_fg`] (for resuming or
/// fine-tuning): both networks, both Adam states and the RNG.
pub fn load_fg_state(path: &Path, dims: &Dims) -> Result<FgState> {
    let ck = Checkpoint::load(path)?;
    let mut rng0 = Xoshiro128::seed_from_u64(0);
    let gen = ck.params_like(&init_generator(dims, &mut rng0)?)?;
    let critic = ck.params_like(&init_critic(dims, &mut rng0)?)?;
    let label = PathBuf::from(path).display().to_string();
    let adam_gen = Adam::from_bytes(ck.blob("adam_gen")?, &gen)
        .with_context(|| format!("{label}: adam_gen"))?;
    let adam_critic = Adam::from_bytes(ck.blob("adam_critic")?, &critic)
        .with_context(|| format!("{label}: adam_critic"))?;
    let rng = rng_from_bytes(ck.blob("rng")?).with_context(|| format!("{label}: rng"))?;
    let iters_done = ck
        .metadata
        .get("iterations")
        .and_then(|v| v.as_u64())
        .unwrap_or(0) as usize;
    Ok(FgState {
        gen,
        critic,
        adam_gen,
        adam_critic,
        rng,
        iters_done,
        history: Vec::new(),
    })
}

/// The report in plain words, for a first screen (`gman demo`): how often a view's nearest
/// generated feature is its own category's, before and after pre-training, against chance.
pub fn report_plain(r: &FgReport) -> String {
    let line = |what: &str, after: &GroupEval, before: &GroupEval| {
        format!(
            "  {what}: {:.1}% (chance {:.1}%, before pre-training {:.1}%)\n",
            100.0 * after.nearest_acc,
            100.0 * after.chance,
            100.0 * before.nearest_acc
        )
    };
    let mut s = format!(
        "pre-trained G, the feature generator: from a category's attribute vector it imagines \
         what that category looks like to the camera ({} steps on {} views of {} seen \
         categories).\nHow often the category whose imagined feature is closest to a camera view \
         is the view's own:\n",
        r.train.iters,
        r.dataset.train_views,
        r.dataset.seen_categories.len()
    );
    s.push_str(&line(
        "views of seen categories it did not train on",
        &r.after.seen_heldout,
        &r.before.seen_heldout,
    ));
    s.push_str(&line(
        "views of unseen categories (never in training)",
        &r.after.unseen_val,
        &r.before.unseen_val,
    ));
    s.push_str("(every measure, per group: `gman pretrain-fg`)\n");
    s
}

/// The report as a text table.
pub fn report_table(r: &FgReport) -> String {
    let mut s = String::new();
    s.push_str(&format!(
        "pretrain-fg ({} preset, data {}): {} training views of {} seen categories, {} generator steps\n",
        r.preset,
        r.data,
        r.dataset.train_views,
        r.dataset.seen_categories.len(),
        r.train.iters
    ));
    s.push_str(
        "group                         views cats | L2 own  L2 other own/other | cos own cos other | NN acc (chance) NN acc all\n",
    );
    let row = |s: &mut String, name: &str, e: &GroupEval| {
        s.push_str(&format!(
            "{name:<29} {:>5} {:>4} | {:>6.3} {:>8.3} {:>9.3} | {:>7.3} {:>9.3} | {:>6.1}% ({:>4.1}%) {:>9.1}%\n",
            e.views,
            e.categories,
            e.l2_own,
            e.l2_other,
            e.own_over_other,
            e.cos_own,
            e.cos_other,
            100.0 * e.nearest_acc,
            100.0 * e.chance,
            100.0 * e.nearest_acc_all
        ));
    };
    for (tag, ev) in [("init", &r.before), ("trained", &r.after)] {
        row(
            &mut s,
            &format!("{tag}: seen held-out (train)"),
            &ev.seen_heldout,
        );
        row(&mut s, &format!("{tag}: seen (val scenes)"), &ev.seen_val);
        row(
            &mut s,
            &format!("{tag}: UNSEEN (val scenes)"),
            &ev.unseen_val,
        );
    }
    row(
        &mut s,
        "ref: train mean, seen held-out",
        &r.reference_train_mean.seen_heldout,
    );
    row(
        &mut s,
        "ref: train mean, seen (val)",
        &r.reference_train_mean.seen_val,
    );
    s
}
