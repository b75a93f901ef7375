//! Recognition probe (the third ceiling of docs/ceilings.md): can "is the target visible now?" be read off the
//! observation and the target feature x_t at all, and how much does it matter whether x_t
//! comes from the pre-trained generator G or is the target's true feature in the scene?
//!
//! A linear probe (logistic regression, L2 1e-4, Adam, 30 epochs) is trained on views of the
//! training scenes (seen targets) and tested on views of the val scenes (seen and unseen
//! targets). Each example is a (scene, target category present in it, state) with label "an
//! instance of the target is visible in the success sense"; per (scene, target) up to
//! `PER` positive and `PER` random negative states, so the sets are balanced. Inputs:
//! * `pooled`: `[s; x; s ⊙ x]` (what the policy's fusion layer sees today);
//! * `map RxC`: `[s; x; s ⊙ x; M_c ⊙ x for every cell c]` (with the spatial map).
//!
//! x_t is either `G(SE(y), 0)` of the pre-trained generator (`gen`) or
//! `World::object_feature(scene, y)` (`true`, what a perfectly adapted G would give).
//! Balanced accuracy is reported (chance 50%).
//!
//! `cargo run --release -p gman-host-sim --example recognition_probe -- DATA_DIR FG_CKPT [RxC] [PER]`

use std::path::Path;

use anyhow::{bail, Result};
use gman_core::nets::generator::GeneratorCache;
use gman_core::Dims;
use gman_host_sim::pretrain::fg::load_generator;
use gman_host_sim::pretrain::generator::generator_view;
use gman_host_sim::sim::spatial::MapGrid;
use gman_host_sim::sim::{CategoryId, SceneId, Split, World};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

struct Example {
    scene: SceneId,
    target: CategoryId,
    state: usize,
    label: bool,
}

/// Up to `per` positive and `per` negative states for every (scene, target) of `targets`.
fn examples(
    world: &World,
    scenes: &[SceneId],
    targets: impl Fn(SceneId) -> Vec<CategoryId>,
    per: usize,
    rng: &mut ChaCha8Rng,
) -> Vec<Example> {
    let mut out = Vec::new();
    for &scene in scenes {
        let tables = world.tables(scene);
        for target in targets(scene) {
            let mut pos: Vec<usize> = (0..tables.num_states())
                .filter(|&s| tables.obs[s].is_visible(target))
                .collect();
            if pos.is_empty() {
                continue;
            }
            let mut neg: Vec<usize> = (0..tables.num_states())
                .filter(|&s| !tables.obs[s].is_visible(target))
                .collect();
            for v in [&mut pos, &mut neg] {
                for i in (1..v.len()).rev() {
                    v.swap(i, rng.random_range(0..=i));
                }
            }
            let n = per.min(pos.len()).min(neg.len());
            for (list, label) in [(&pos, true), (&neg, false)] {
                out.extend(list[..n].iter().map(|&state| Example {
                    scene,
                    target,
                    state,
                    label,
                }));
            }
        }
    }
    out
}

/// The probe's input for one example.
fn input(
    world: &World,
    e: &Example,
    x: &[f32],
    grid: Option<MapGrid>,
    map: &mut Vec<f32>,
) -> Vec<f32> {
    let s = &world.observation(e.scene, e.state).features;
    let mut v: Vec<f32> = s.to_vec();
    v.extend_from_slice(x);
    v.extend(s.iter().zip(x).map(|(a, b)| a * b));
    if let Some(g) = grid {
        map.resize(g.len(), 0.0);
        world.view_map(e.scene, e.state, g, map);
        for cell in map.chunks_exact(x.len()) {
            v.extend(cell.iter().zip(x).map(|(a, b)| a * b));
        }
    }
    v
}

/// Logistic regression by Adam on standardised inputs; returns (weights, bias, mean, std).
fn fit(xs: &[Vec<f32>], ys: &[bool], seed: u64) -> (Vec<f32>, f32, Vec<f32>, Vec<f32>) {
    let d = xs[0].len();
    let n = xs.len() as f32;
    let mut mean = vec![0f32; d];
    let mut sd = vec![0f32; d];
    for x in xs {
        mean.iter_mut().zip(x).for_each(|(m, v)| *m += v / n);
    }
    for x in xs {
        sd.iter_mut()
            .zip(x.iter().zip(&mean))
            .for_each(|(s, (v, m))| *s += (v - m) * (v - m) / n);
    }
    sd.iter_mut().for_each(|s| *s = s.sqrt().max(1e-4));
    let (mut w, mut b) = (vec![0f32; d], 0f32);
    let (mut m1, mut m2, mut bm1, mut bm2) = (vec![0f32; d], vec![0f32; d], 0f32, 0f32);
    let (lr, l2, b1, b2) = (1e-2f32, 1e-4f32, 0.9f32, 0.999f32);
    let mut order: Vec<usize> = (0..xs.len()).collect();
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut t = 0i32;
    let batch = 64;
    let mut g = vec![0f32; d];
    for _epoch in 0..30 {
        for i in (1..order.len()).rev() {
            order.swap(i, rng.random_range(0..=i));
        }
        for chunk in order.chunks(batch) {
            g.iter_mut().for_each(|v| *v = 0.0);
            let mut gb = 0f32;
            for &i in chunk {
                let z: f32 = b + xs[i]
                    .iter()
                    .zip(&w)
                    .zip(mean.iter().zip(&sd))
                    .map(|((x, w), (m, s))| w * (x - m) / s)
                    .sum::<f32>();
                let p = 1.0 / (1.0 + (-z).exp());
                let err = p - ys[i] as u8 as f32;
                g.iter_mut()
                    .zip(&xs[i])
                    .zip(mean.iter().zip(&sd))
                    .for_each(|((g, x), (m, s))| *g += err * (x - m) / s);
                gb += err;
            }
            t += 1;
            let k = chunk.len() as f32;
            for j in 0..d {
                let gj = g[j] / k + l2 * w[j];
                m1[j] = b1 * m1[j] + (1.0 - b1) * gj;
                m2[j] = b2 * m2[j] + (1.0 - b2) * gj * gj;
                let mh = m1[j] / (1.0 - b1.powi(t));
                let vh = m2[j] / (1.0 - b2.powi(t));
                w[j] -= lr * mh / (vh.sqrt() + 1e-8);
            }
            let gb = gb / k;
            bm1 = b1 * bm1 + (1.0 - b1) * gb;
            bm2 = b2 * bm2 + (1.0 - b2) * gb * gb;
            b -= lr * (bm1 / (1.0 - b1.powi(t))) / ((bm2 / (1.0 - b2.powi(t))).sqrt() + 1e-8);
        }
    }
    (w, b, mean, sd)
}

/// Balanced accuracy (mean of the true-positive and true-negative rates), in percent.
fn balanced_accuracy(
    model: &(Vec<f32>, f32, Vec<f32>, Vec<f32>),
    xs: &[Vec<f32>],
    ys: &[bool],
) -> f64 {
    let (w, b, mean, sd) = model;
    let (mut tp, mut p, mut tn, mut n) = (0u32, 0u32, 0u32, 0u32);
    for (x, &y) in xs.iter().zip(ys) {
        let z: f32 = b + x
            .iter()
            .zip(w)
            .zip(mean.iter().zip(sd))
            .map(|((x, w), (m, s))| w * (x - m) / s)
            .sum::<f32>();
        let pred = z > 0.0;
        if y {
            p += 1;
            tp += pred as u32;
        } else {
            n += 1;
            tn += !pred as u32;
        }
    }
    50.0 * (tp as f64 / p.max(1) as f64 + tn as f64 / n.max(1) as f64)
}

fn main() -> Result<()> {
    let args: Vec<String> = std::env::args().collect();
    let (Some(data), Some(fg)) = (args.get(1), args.get(2)) else {
        bail!("usage: recognition_probe DATA_DIR FG_CKPT [RxC] [PER]")
    };
    let grid = match args.get(3).map(String::as_str) {
        None | Some("none") => None,
        Some(s) => {
            let (r, c) = s
                .split_once('x')
                .ok_or_else(|| anyhow::anyhow!("grid must be RxC, got {s}"))?;
            Some(MapGrid {
                rows: r.parse()?,
                cols: c.parse()?,
            })
        }
    };
    let per: usize = args.get(4).map(|s| s.parse()).transpose()?.unwrap_or(20);
    let world = World::load(Path::new(data))?;
    let dims = Dims::MCU;
    let gen = load_generator(Path::new(fg), &dims)?;
    let g = generator_view(&gen)?;
    let gen_x = |c: CategoryId| -> Result<Vec<f32>> {
        let (mut h1, mut x) = (vec![0f32; dims.gen_hidden], vec![0f32; dims.feat]);
        g.forward(
            &vec![0f32; dims.noise],
            world.attributes(c),
            &mut GeneratorCache {
                u1: &mut [],
                h1: &mut h1,
                u2: &mut [],
                x: &mut x,
            },
        )?;
        Ok(x)
    };
    let mut rng = ChaCha8Rng::seed_from_u64(13);
    let train = examples(
        &world,
        world.split_scenes(Split::Train)?,
        |s| world.train_targets[world.scenes[s].room.index()].clone(),
        per,
        &mut rng,
    );
    let val_seen = examples(
        &world,
        world.split_scenes(Split::Val)?,
        |s| world.eval_targets[world.scenes[s].room.index()].0.clone(),
        per,
        &mut rng,
    );
    let val_unseen = examples(
        &world,
        world.split_scenes(Split::Val)?,
        |s| world.eval_targets[world.scenes[s].room.index()].1.clone(),
        per,
        &mut rng,
    );
    let name = grid.map_or("pooled".to_string(), |g| {
        format!("map {}x{}", g.rows, g.cols)
    });
    println!(
        "probe input: {name}; examples: train {} (seen targets, training scenes), val seen {}, val unseen {}",
        train.len(),
        val_seen.len(),
        val_unseen.len()
    );
    println!("| input | x_t | train acc | val seen acc | val unseen acc |");
    println!("|---|---|---:|---:|---:|");
    let mut map = Vec::new();
    for source in ["gen", "true"] {
        let x_of = |e: &Example| -> Result<Vec<f32>> {
            Ok(if source == "gen" {
                gen_x(e.target)?
            } else {
                world.object_feature(e.scene, e.target).to_vec()
            })
        };
        let mut set = |ex: &[Example]| -> Result<(Vec<Vec<f32>>, Vec<bool>)> {
            let mut xs = Vec::with_capacity(ex.len());
            for e in ex {
                xs.push(input(&world, e, &x_of(e)?, grid, &mut map));
            }
            Ok((xs, ex.iter().map(|e| e.label).collect()))
        };
        let (tx, ty) = set(&train)?;
        let (sx, sy) = set(&val_seen)?;
        let (ux, uy) = set(&val_unseen)?;
        let model = fit(&tx, &ty, 1);
        println!(
            "| {name} | {source} | {:.1} | {:.1} | {:.1} |",
            balanced_accuracy(&model, &tx, &ty),
            balanced_accuracy(&model, &sx, &sy),
            balanced_accuracy(&model, &ux, &uy)
        );
    }
    Ok(())
}
