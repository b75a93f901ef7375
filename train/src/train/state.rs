//! What a training run's checkpoint holds besides the model: the counters, Adam's state and
//! the run's settings, typed and serde-serialised ([`TrainerMeta`], the `trainer` object of
//! the checkpoint's metadata, beside the model's [`ModelMeta`](crate::model::ModelMeta)).
//!
//! # Versions of the `trainer` object
//! * **1** (no `version` key): written by every build before the settings were typed. The
//!   keys and their encoding are those of version 2, so such a checkpoint loads and resumes
//!   bit for bit; one that lacks a setting (a build older than that setting) is refused with
//!   an error naming the file, the version and the missing key.
//! * **2** ([`TRAINER_META_VERSION`]): the same keys plus `"version": 2`.
//!
//! A version this build does not know is refused with [`SettingsError::Version`].

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use anyhow::{anyhow, bail, Result};
use serde::{Deserialize, Serialize};

use super::a3c::{A3cConfig, Objective};
use crate::model::{Method, NavModel};
use crate::optim::adam::{Adam, AdamConfig};
use crate::optim::checkpoint::Checkpoint;
use crate::sim::features::DomainShift;
use crate::sim::{ObjectLayout, RewardKind};

/// Version of the `trainer` object written by this build (see the module docs).
pub const TRAINER_META_VERSION: u32 = 2;

/// The settings that shape a run's updates, stored in its checkpoint so that `--resume`
/// continues with exactly them (the options of one invocation, such as the update count or
/// the progress bar, are in [`super::trainer::TrainOptions`] only).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct RunSettings {
    /// Seed of the run.
    pub seed: u64,
    /// Parallel workers.
    pub workers: usize,
    /// Environments each worker steps in lockstep (`B`, see [`super::engine`]); 1 is
    /// one episode at a time. Absent in checkpoints from before vectorised episodes: 1.
    #[serde(default = "one_usize")]
    pub batch_envs: usize,
    /// Each worker runs whole episodes (tasks) until it has taken at least this many steps
    /// in the update (at least one episode).
    pub min_steps: u32,
    /// Reward (stored as the variant's name, `"Mixed"`).
    #[serde(with = "reward_name")]
    pub reward: RewardKind,
    /// Step limit of training episodes (`None`: the evaluation limits, 200/100).
    pub max_steps: Option<u32>,
    /// Training starts need at least this many actions to see the target (1: never in view at
    /// the start).
    pub min_start_actions: u32,
    /// Outer optimiser.
    pub adam: AdamConfig,
    /// A3C loss.
    pub a3c: A3cConfig,
    /// What the policy learns from: the A3C loss or imitation of the oracle (DAgger). Absent
    /// in checkpoints from before the objective existed: A3C.
    #[serde(default)]
    pub objective: Objective,
    /// Meta-gradient order: 1 (first-order MAML, the gradient at the adapted parameters
    /// applied to the pre-adaptation ones) or 2 (exact through the inner SGD steps, see
    /// [`super::meta`]).
    pub meta_order: u8,
}

fn one_usize() -> usize {
    1
}

impl Default for RunSettings {
    /// `gman train`'s defaults: seed 1, 2 workers, one environment each, at least 40 steps per
    /// worker and update, the mixed reward, the evaluation step limits, any training start,
    /// the default Adam (lr 1e-4, AMSGrad) and A3C loss, the A3C objective, first order.
    fn default() -> Self {
        RunSettings {
            seed: 1,
            workers: 2,
            batch_envs: 1,
            min_steps: 40,
            reward: RewardKind::Mixed,
            max_steps: None,
            min_start_actions: 1,
            adam: AdamConfig::default(),
            a3c: A3cConfig::default(),
            objective: Objective::default(),
            meta_order: 1,
        }
    }
}

/// [`RewardKind`] as its variant's name (`"Mixed"`), the encoding of every checkpoint so far.
mod reward_name {
    use crate::sim::RewardKind;
    use serde::{Deserialize, Deserializer, Serializer};

    pub fn serialize<S: Serializer>(r: &RewardKind, s: S) -> Result<S::Ok, S::Error> {
        s.serialize_str(&format!("{r:?}"))
    }

    pub fn deserialize<'de, D: Deserializer<'de>>(d: D) -> Result<RewardKind, D::Error> {
        let name = String::deserialize(d)?;
        name.to_ascii_lowercase()
            .parse::<RewardKind>()
            .map_err(|e| serde::de::Error::custom(format!("reward {name:?}: {e}")))
    }
}

/// The world a run trains on, stored so that a resumed run can refuse another one.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "lowercase")]
pub enum WorldId {
    /// The built-in synthetic world.
    Synthetic {
        /// `--world-seed`.
        world_seed: u64,
        /// `--domain-shift` (absent: the default 1, the only level of older builds).
        #[serde(default, skip_serializing_if = "DomainShift::is_default")]
        domain_shift: DomainShift,
    },
    /// A data directory.
    Data {
        /// `--world-seed`.
        world_seed: u64,
        /// Fingerprint of the directory's contents (the path may change, the data must not),
        /// by the rule `fingerprint_rule` ([`crate::sim::fingerprint`]).
        fingerprint: String,
        /// The path it was trained from (for messages).
        path: String,
        /// The rule of `fingerprint` (absent: 1, the only rule of older builds).
        #[serde(default = "rule_one", skip_serializing_if = "is_rule_one")]
        fingerprint_rule: u32,
        /// The digest of every file the fingerprint covers, so that a refusal names the
        /// files that differ (absent in checkpoints of older builds).
        #[serde(default, skip_serializing_if = "Option::is_none")]
        files: Option<BTreeMap<String, String>>,
        /// The directory's rule-1 fingerprint, to compare with checkpoints of older builds
        /// (computed, never stored).
        #[serde(skip)]
        rule1: Option<String>,
        /// The object layout (`--object-layout`; absent in checkpoints written before it
        /// existed, which were all `rule`).
        #[serde(default, skip_serializing_if = "is_rule")]
        object_layout: ObjectLayout,
        /// `--domain-shift` (absent: the default 1, the only level of older builds).
        #[serde(default, skip_serializing_if = "DomainShift::is_default")]
        domain_shift: DomainShift,
    },
}

fn is_rule(l: &ObjectLayout) -> bool {
    *l == ObjectLayout::Rule
}

fn rule_one() -> u32 {
    1
}

fn is_rule_one(r: &u32) -> bool {
    *r == 1
}

impl WorldId {
    /// The identity of data directory `dir` read with visibility file `visible_file` and
    /// object layout `layout`.
    pub fn of_data_dir(
        dir: &Path,
        world_seed: u64,
        visible_file: &str,
        layout: ObjectLayout,
        domain_shift: DomainShift,
    ) -> Result<WorldId> {
        let f = crate::sim::fingerprint::of_dir(dir, visible_file, layout)?;
        Ok(WorldId::Data {
            world_seed,
            fingerprint: f.fingerprint,
            path: dir.display().to_string(),
            fingerprint_rule: f.rule,
            files: Some(f.files),
            rule1: Some(f.rule1),
            object_layout: layout,
            domain_shift,
        })
    }

    /// The domain shift the world was built with.
    pub fn domain_shift(&self) -> DomainShift {
        match self {
            WorldId::Synthetic { domain_shift, .. } | WorldId::Data { domain_shift, .. } => {
                *domain_shift
            }
        }
    }

    /// Refuses to resume a run trained on `self` on `now`, in words a user can act on: which
    /// files differ when both sides list their files. `Ok(Some(warning))` when `self` was
    /// stored by an older build with a fingerprint rule that covers less than `now`'s and
    /// that older rule matches (the files it does not cover cannot be compared).
    pub fn check_same(&self, now: &WorldId) -> Result<Option<String>> {
        let refuse = |detail: String| -> Result<Option<String>> {
            bail!(
                "the run was trained on {}, but this resume selects {}{detail}; resume with the same --data and --world-seed",
                self.describe(),
                now.describe()
            )
        };
        let (sa, sb) = (self.domain_shift(), now.domain_shift());
        if sa != sb {
            bail!(
                "the run was trained at domain shift {sa}, but this resume selects {sb}; resume with --domain-shift {sa}"
            );
        }
        if let (
            WorldId::Data {
                object_layout: a, ..
            },
            WorldId::Data {
                object_layout: b, ..
            },
        ) = (self, now)
        {
            if a != b {
                bail!(
                    "the run was trained with the object layout {a}, but this resume selects {b}; resume with --object-layout {a}"
                );
            }
        }
        match (self, now) {
            (
                WorldId::Synthetic { world_seed: a, .. },
                WorldId::Synthetic { world_seed: b, .. },
            ) if a == b => Ok(None),
            (
                WorldId::Data {
                    world_seed: a,
                    fingerprint: fa,
                    fingerprint_rule: ra,
                    files: files_a,
                    ..
                },
                WorldId::Data {
                    world_seed: b,
                    fingerprint: fb,
                    fingerprint_rule: rb,
                    files: files_b,
                    rule1,
                    ..
                },
            ) if a == b => {
                if ra == rb && fa == fb {
                    return Ok(None);
                }
                if *ra == crate::sim::fingerprint::RULE_SCENES
                    && *rb != *ra
                    && files_a.is_none()
                    && rule1.as_ref() == Some(fa)
                {
                    return Ok(Some(format!(
                        "the checkpoint was written by an older build whose data fingerprint (rule 1) covers attributes.json and scenes/ only; those match, but the scene folders' graphs, grids, visibility and feature files cannot be compared with what the run was trained on (checkpoints written from now on fingerprint them, rule {rb})"
                    )));
                }
                if ra != rb {
                    return refuse(format!(
                        " (fingerprint rule {ra} in the checkpoint, rule {rb} for this directory: a directory of another layout)"
                    ));
                }
                match (files_a, files_b) {
                    (Some(x), Some(y)) => {
                        let d = crate::sim::fingerprint::differences(x, y);
                        let shown: Vec<&str> = d.iter().take(6).map(String::as_str).collect();
                        refuse(format!(
                            ": {}{}",
                            shown.join(", "),
                            if d.len() > shown.len() {
                                format!(" and {} more", d.len() - shown.len())
                            } else {
                                String::new()
                            }
                        ))
                    }
                    _ => refuse(String::new()),
                }
            }
            _ => refuse(String::new()),
        }
    }

    fn describe(&self) -> String {
        match self {
            WorldId::Data {
                world_seed,
                fingerprint,
                path,
                object_layout,
                ..
            } => format!(
                "the data directory {path} (content fingerprint {fingerprint}) with --world-seed {world_seed} and --object-layout {object_layout}"
            ),
            WorldId::Synthetic { world_seed, .. } => {
                format!("the synthetic world (no --data) with --world-seed {world_seed}")
            }
        }
    }
}

/// The `trainer` object of a training checkpoint's metadata (see the module docs).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct TrainerMeta {
    /// Format version of this object (absent: 1).
    #[serde(default = "version_one")]
    pub version: u32,
    /// Updates done.
    pub update: u64,
    /// Episodes run.
    pub episodes: u64,
    /// Environment steps taken.
    pub env_steps: u64,
    /// The run's settings.
    #[serde(flatten)]
    pub run: RunSettings,
    /// The method, also in the model's metadata: a relabelled one is refused. Absent in the
    /// first checkpoints.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub method: Option<Method>,
    /// The world trained on; absent when unknown (library use, older checkpoints).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub world: Option<WorldId>,
    /// The number of updates the run was asked for (`--updates`), so that a resumed run
    /// continues to it; absent when unknown (checkpoints that do not record it).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub target_updates: Option<u64>,
    /// A copy of the model's settings as the checkpoint was written (the metadata's top-level
    /// keys other than `trainer`), so that settings the tensors cannot show (a 3 x 3 map
    /// relabelled 1 x 9, the adaptation mode) are not changed unnoticed
    /// (`model::record::check_model_record`); absent in checkpoints of older builds.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub model: Option<serde_json::Value>,
}

fn version_one() -> u32 {
    1
}

/// Why the `trainer` object of a checkpoint could not be read. Every variant names the file.
#[derive(Debug, thiserror::Error)]
pub enum SettingsError {
    /// The object has a version this build does not read.
    #[error("{path}: trainer settings format version {found} is not supported (this build reads versions 1 to {TRAINER_META_VERSION}); resume it with the build that wrote it")]
    Version {
        /// The file.
        path: PathBuf,
        /// Version in the file.
        found: u64,
    },
    /// The object is missing or does not parse as its version says.
    #[error("{path}: trainer settings (format version {version}) cannot be read: {what}")]
    Malformed {
        /// The file.
        path: PathBuf,
        /// Version in the file (1 when it has none).
        version: u64,
        /// What is wrong.
        what: String,
    },
}

impl TrainerMeta {
    /// Reads the `trainer` object of `metadata` (of the checkpoint `path`), checking its
    /// version first.
    pub fn from_metadata(
        metadata: &serde_json::Value,
        path: &Path,
    ) -> Result<TrainerMeta, SettingsError> {
        let t = &metadata["trainer"];
        let version = match t.get("version") {
            None => 1,
            Some(v) => v.as_u64().ok_or_else(|| SettingsError::Malformed {
                path: path.to_path_buf(),
                version: 0,
                what: format!("version {v} is not a number"),
            })?,
        };
        if !(1..=TRAINER_META_VERSION as u64).contains(&version) {
            return Err(SettingsError::Version {
                path: path.to_path_buf(),
                found: version,
            });
        }
        let malformed = |what: String| SettingsError::Malformed {
            path: path.to_path_buf(),
            version,
            what,
        };
        if !t.is_object() {
            return Err(malformed(
                "the metadata has no `trainer` object (not a checkpoint of `gman train`)".into(),
            ));
        }
        serde_json::from_value(t.clone()).map_err(|e| malformed(e.to_string()))
    }
}

/// Everything a checkpoint restores.
pub struct TrainState {
    /// The model (θ, ω, φ and the PS module).
    pub model: NavModel,
    /// Adam over the model's parameters.
    pub adam: Adam,
    /// Updates done.
    pub update: u64,
    /// Episodes run.
    pub episodes: u64,
    /// Environment steps taken.
    pub env_steps: u64,
    /// What world the run trains on, stored in the checkpoint so that a resumed run can
    /// refuse another world; `None` when unknown (library use, older checkpoints).
    pub world: Option<WorldId>,
    /// The run's target update count, stored in the checkpoint ([`TrainerMeta::target_updates`]);
    /// `None` when unknown (library use, older checkpoints).
    pub target_updates: Option<u64>,
}

impl TrainState {
    /// A fresh state.
    pub fn new(model: NavModel, adam: AdamConfig) -> TrainState {
        let adam = Adam::new(adam, &model.params);
        TrainState {
            model,
            adam,
            update: 0,
            episodes: 0,
            env_steps: 0,
            world: None,
            target_updates: None,
        }
    }

    /// Counts one update that ran `episodes` episodes of `env_steps` steps in all. A counter
    /// that would pass `u64::MAX` (a corrupt or hand-edited checkpoint) is an error that names
    /// it; nothing is counted then.
    pub(crate) fn count_update(&mut self, episodes: u64, env_steps: u64) -> Result<()> {
        let add = |what: &str, now: u64, n: u64| {
            now.checked_add(n).ok_or_else(|| {
                anyhow!("the {what} counter ({now}) cannot count {n} more: it would pass u64::MAX; the checkpoint's counters are corrupt")
            })
        };
        let update = add("update", self.update, 1)?;
        let eps = add("episode", self.episodes, episodes)?;
        let steps = add("environment step", self.env_steps, env_steps)?;
        (self.update, self.episodes, self.env_steps) = (update, eps, steps);
        Ok(())
    }

    /// The `trainer` object of this state's checkpoint, for a run with settings `run`.
    pub(crate) fn trainer_meta(&self, run: &RunSettings) -> TrainerMeta {
        TrainerMeta {
            version: TRAINER_META_VERSION,
            update: self.update,
            episodes: self.episodes,
            env_steps: self.env_steps,
            run: run.clone(),
            method: Some(self.model.method),
            world: self.world.clone(),
            target_updates: self.target_updates,
            model: Some(self.model.metadata()),
        }
    }

    /// Writes the checkpoint atomically.
    pub fn save(&self, path: &Path, run: &RunSettings) -> Result<()> {
        let mut meta = self.model.metadata();
        meta["trainer"] = serde_json::to_value(self.trainer_meta(run))?;
        let mut ck = Checkpoint::new(meta);
        self.model.add_to_checkpoint(&mut ck)?;
        ck.add_blob("adam", self.adam.to_bytes());
        ck.save(path)?;
        Ok(())
    }

    /// Restores a state saved by [`TrainState::save`].
    pub fn load(path: &Path) -> Result<TrainState> {
        Ok(Self::load_with_settings(path)?.0)
    }

    /// Restores a state like [`TrainState::load`] and also returns the `trainer` object the
    /// run was last saved with (its [`RunSettings`]: seed, workers, reward, Adam and A3C
    /// settings, meta-gradient order, ...), so that a resumed run can continue with exactly
    /// the settings it was trained with.
    pub fn load_with_settings(path: &Path) -> Result<(TrainState, TrainerMeta)> {
        let ck = Checkpoint::load(path)?;
        let t = TrainerMeta::from_metadata(&ck.metadata, path)?;
        let model = NavModel::from_checkpoint(&ck)?;
        let adam = Adam::from_bytes(ck.blob("adam")?, &model.params)?;
        // The method is stored twice (model and trainer metadata): a relabelled one is refused.
        if let Some(m) = t.method {
            if m != model.method {
                bail!(
                    "{}: the model's method is {} but the run was trained as {}; the metadata was changed",
                    path.display(),
                    model.method.name(),
                    m.name()
                );
            }
        }
        let state = TrainState {
            model,
            adam,
            update: t.update,
            episodes: t.episodes,
            env_steps: t.env_steps,
            world: t.world.clone(),
            target_updates: t.target_updates,
        };
        Ok((state, t))
    }
}
