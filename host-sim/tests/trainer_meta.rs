//! The typed trainer settings of a training checkpoint (`train::state::TrainerMeta`) against
//! the untyped `trainer` object of format version 1 (no `version` key):
//!
//! * the version-1 metadata of
//!   `gman train --method gman --config tiny --updates 3 --workers 1` parses, with every
//!   setting as that run had it, and has exactly the keys this build writes (less `version`);
//! * a checkpoint in the version-1 form resumes bit for bit like an uninterrupted run;
//! * an unknown version, and a version-1 object that lacks a setting, are refused with an
//!   error naming the file and the version.

use std::path::{Path, PathBuf};

use gman_core::navigator::memory::AdaptMode;
use gman_core::Dims;
use gman_host_sim::model::{Method, NavModel};
use gman_host_sim::optim::adam::AdamConfig;
use gman_host_sim::optim::checkpoint::Checkpoint;
use gman_host_sim::pretrain::generator::init_generator;
use gman_host_sim::sim::{RewardKind, World};
use gman_host_sim::train::run_dir::checkpoint_path;
use gman_host_sim::train::state::{
    RunSettings, TrainState, TrainerMeta, WorldId, TRAINER_META_VERSION,
};
use gman_host_sim::train::trainer::{train, TrainOptions};

const FIXTURE: &str = include_str!("fixtures/base-0460aca-gman-tiny.meta.json");

fn tmp(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("gman-tmeta-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}

fn state() -> TrainState {
    let dims = Dims::MCU;
    let mut rng = gman_core::rng::Xoshiro128::seed_from_u64(1);
    let g = init_generator(&dims, &mut rng).unwrap();
    let mut m = NavModel::init(Method::Gman, dims, 1, Some(&g), None).unwrap();
    m.spec.adapt_mode = AdaptMode::Efficient;
    TrainState::new(
        m,
        AdamConfig {
            lr: 1e-3,
            ..AdamConfig::default()
        },
    )
}

fn opts(out: PathBuf, updates: u64) -> TrainOptions {
    TrainOptions {
        updates,
        run: RunSettings {
            seed: 5,
            workers: 1,
            min_steps: 20,
            reward: RewardKind::Distance,
            max_steps: Some(40),
            adam: AdamConfig {
                lr: 1e-3,
                ..AdamConfig::default()
            },
            ..RunSettings::default()
        },
        checkpoint_every: 100,
        out,
        progress: false,
    }
}

/// Rewrites the checkpoint at `path` with `edit` applied to its `trainer` object.
fn edit_trainer(path: &Path, edit: impl FnOnce(&mut serde_json::Map<String, serde_json::Value>)) {
    let mut ck = Checkpoint::load(path).unwrap();
    edit(ck.metadata["trainer"].as_object_mut().unwrap());
    ck.save(path).unwrap();
}

#[test]
fn the_base_builds_trainer_object_parses_as_version_1() {
    let meta: serde_json::Value = serde_json::from_str(FIXTURE).unwrap();
    let t = TrainerMeta::from_metadata(&meta, Path::new("fixture")).unwrap();
    assert_eq!(t.version, 1);
    assert_eq!((t.update, t.episodes, t.env_steps), (3, 18, 139));
    assert_eq!(t.method, Some(Method::Gman));
    assert_eq!(
        t.world,
        Some(WorldId::Synthetic {
            world_seed: 2022,
            domain_shift: Default::default()
        })
    );
    let r = &t.run;
    assert_eq!(
        (r.seed, r.workers, r.batch_envs, r.min_steps),
        (1, 1, 1, 40)
    );
    assert_eq!(
        (r.max_steps, r.min_start_actions, r.meta_order),
        (None, 1, 1)
    );
    assert_eq!(r.reward, RewardKind::Mixed);
    assert_eq!(r.adam.lr, 1e-3);
    assert!(r.adam.amsgrad);
    assert_eq!(r.a3c, Default::default());
    assert_eq!(r.objective, Default::default());
    // The keys this build writes are the base build's plus `version`, with the same values
    // for the same settings (so version 1 is this format without the version).
    let again = serde_json::to_value(&t).unwrap();
    let mut keys: Vec<&String> = again.as_object().unwrap().keys().collect();
    keys.retain(|k| *k != "version");
    let base: Vec<&String> = meta["trainer"].as_object().unwrap().keys().collect();
    assert_eq!(keys, base);
    assert_eq!(again["version"], 1, "a parsed object keeps its version");
    let mut stripped = again.clone();
    stripped.as_object_mut().unwrap().remove("version");
    // (through the JSON text, as a checkpoint stores it: serde_json's parser may round the
    // last digit of an f64, the same way for both)
    let text = serde_json::to_string(&stripped).unwrap();
    assert_eq!(
        serde_json::from_str::<serde_json::Value>(&text).unwrap(),
        meta["trainer"]
    );
}

#[test]
fn a_version_1_checkpoint_resumes_bit_for_bit() {
    let world = World::synthetic(7);
    let a = tmp("straight");
    let mut sa = state();
    train(&world, &opts(a.clone(), 4), &mut sa).unwrap();
    let b = tmp("resumed");
    let mut sb = state();
    train(&world, &opts(b.clone(), 2), &mut sb).unwrap();
    let ck = checkpoint_path(&b);
    let v2 = TrainState::load_with_settings(&ck).unwrap().1;
    assert_eq!(v2.version, TRAINER_META_VERSION);
    // The version-1 form: no version key.
    edit_trainer(&ck, |t| {
        t.remove("version");
    });
    let (mut sb, t) = TrainState::load_with_settings(&ck).unwrap();
    assert_eq!(t.version, 1);
    assert_eq!(t.run, opts(b.clone(), 4).run);
    let mut o = opts(b.clone(), 4);
    o.run = t.run;
    train(&world, &o, &mut sb).unwrap();
    assert_eq!((sa.episodes, sa.env_steps), (sb.episodes, sb.env_steps));
    for (x, y) in sa.model.params.tensors.iter().zip(&sb.model.params.tensors) {
        let bx: Vec<u32> = x.data.iter().map(|v| v.to_bits()).collect();
        let by: Vec<u32> = y.data.iter().map(|v| v.to_bits()).collect();
        assert_eq!(bx, by, "{}", x.name);
    }
    assert_eq!(sa.adam.to_bytes(), sb.adam.to_bytes());
    // ... and it is written back in this build's version.
    let t = TrainState::load_with_settings(&ck).unwrap().1;
    assert_eq!(t.version, TRAINER_META_VERSION);
    for d in [a, b] {
        let _ = std::fs::remove_dir_all(d);
    }
}

#[test]
fn unknown_versions_and_incomplete_version_1_objects_are_refused_naming_the_file() {
    let world = World::synthetic(7);
    let d = tmp("refused");
    let mut s = state();
    train(&world, &opts(d.clone(), 1), &mut s).unwrap();
    let ck = checkpoint_path(&d);
    let name = ck.display().to_string();
    edit_trainer(&ck, |t| {
        t.insert("version".into(), serde_json::json!(99));
    });
    let e = format!("{:#}", TrainState::load(&ck).err().unwrap());
    assert!(
        e.contains(&name) && e.contains("format version 99") && e.contains("not supported"),
        "{e}"
    );
    edit_trainer(&ck, |t| {
        t.remove("version");
        t.remove("seed");
    });
    let e = format!("{:#}", TrainState::load(&ck).err().unwrap());
    assert!(
        e.contains(&name) && e.contains("format version 1") && e.contains("seed"),
        "{e}"
    );
    let _ = std::fs::remove_dir_all(d);
}
