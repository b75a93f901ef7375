//! Content fingerprints of data directories: what a training checkpoint stores so that
//! `train --resume` refuses a world built from other data, and says which file differs.
//!
//! Two rules, each stored with its number:
//!
//! * **Rule 1** (directories of the `scenes/` layout, and what every checkpoint of an older
//!   build stored): 64-bit FNV-1a over `attributes.json` and every `scenes/<split>/*.json`
//!   ([`crate::data::fingerprint`]).
//! * **Rule 2** (offline data, [`crate::offline`]): FNV-1a over one digest per file
//!   the world is built from: `attributes.json`, and per scene (by scene name, so either
//!   folder naming gives the same digests) `graph.json`, `grid.json`, the chosen visibility
//!   file (all bytes), `resnet18_featuremap.hdf5` and, if present, `att_in_view_v2.hdf5`.
//!   An HDF5 file's digest is cheap: its size, the sorted names of its datasets, and the
//!   shape, element size and values of [`H5_SAMPLE`] datasets spread over the sorted names
//!   (first and last included). A change inside a dataset outside the sample that keeps the
//!   file's size is not seen.
//!
//! Both rules also list the per-file digests, so that a refusal names what differs.

use std::collections::BTreeMap;
use std::fs;
use std::path::Path;

use anyhow::{Context, Result};

use super::offline::{self, h5, ATT_FILE, FEATURE_FILE, GRAPH_FILE, GRID_FILE};
use super::types::Split;
use super::util::Fnv;
use super::ObjectLayout;

/// Datasets of an HDF5 file whose values a rule-2 digest reads.
pub const H5_SAMPLE: usize = 8;

/// The rule of a data directory's fingerprint.
pub const RULE_SCENES: u32 = 1;
/// The rule of an offline directory's fingerprint.
pub const RULE_OFFLINE: u32 = 2;

/// A data directory's fingerprint by its rule, with the digest of every file it covers.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct DataFingerprint {
    /// [`RULE_SCENES`] or [`RULE_OFFLINE`].
    pub rule: u32,
    /// 16 hex digits.
    pub fingerprint: String,
    /// Digest (16 hex digits) by file, relative to the directory (`FloorPlan22/graph.json`).
    pub files: BTreeMap<String, String>,
    /// The rule-1 fingerprint of the same directory (what older checkpoints stored).
    pub rule1: String,
}

fn file_digest(path: &Path) -> Result<String> {
    let mut h = Fnv::new();
    h.eat(&fs::read(path).with_context(|| format!("cannot read {}", path.display()))?);
    Ok(h.hex())
}

/// The cheap digest of an HDF5 file (see the module docs).
fn h5_digest(path: &Path) -> Result<String> {
    let mut h = Fnv::new();
    let len = fs::metadata(path)
        .with_context(|| format!("cannot read {}", path.display()))?
        .len();
    h.eat(&len.to_le_bytes());
    let f = h5::H5File::open(path)?;
    let names = f.names()?;
    for n in &names {
        h.eat(n.as_bytes());
        h.eat(&[0]);
    }
    let n = names.len();
    let picks: Vec<usize> = if n <= H5_SAMPLE {
        (0..n).collect()
    } else {
        let mut v: Vec<usize> = (0..H5_SAMPLE)
            .map(|i| i * (n - 1) / (H5_SAMPLE - 1))
            .collect();
        v.dedup();
        v
    };
    for i in picks {
        let key = &names[i];
        let (shape, size) = f.shape_and_size(key)?;
        for d in &shape {
            h.eat(&(*d as u64).to_le_bytes());
        }
        h.eat(&(size as u64).to_le_bytes());
        for x in f.read(key)? {
            h.eat(&x.to_bits().to_le_bytes());
        }
    }
    Ok(h.hex())
}

/// The fingerprint of `dir` by the rule of its layout, for the visibility file
/// `visible_file` of offline data; under the object layout [`ObjectLayout::Thor5`] rule 1
/// also covers the `objects_thor5/*.json` sidecar files
/// ([`crate::data::fingerprint_for`]).
pub fn of_dir(dir: &Path, visible_file: &str, layout: ObjectLayout) -> Result<DataFingerprint> {
    let rule1 = super::data::fingerprint(dir)?;
    let mut files = BTreeMap::new();
    files.insert(
        "attributes.json".to_string(),
        file_digest(&dir.join("attributes.json"))?,
    );
    if !offline::is_offline_dir(dir) {
        let mut dirs: Vec<std::path::PathBuf> = Split::ALL
            .iter()
            .map(|&split| super::data::scenes_dir(dir, split))
            .collect();
        if layout == ObjectLayout::Thor5 {
            dirs.push(super::data::thor5_dir(dir));
        }
        for sdir in dirs {
            let Ok(rd) = fs::read_dir(&sdir) else {
                continue;
            };
            for p in rd.filter_map(|e| e.ok().map(|e| e.path())) {
                if p.extension().is_some_and(|e| e == "json") {
                    let rel = p.strip_prefix(dir).unwrap_or(&p).to_string_lossy();
                    files.insert(rel.into_owned(), file_digest(&p)?);
                }
            }
        }
        return Ok(DataFingerprint {
            rule: RULE_SCENES,
            fingerprint: super::data::fingerprint_for(dir, layout)?,
            files,
            rule1,
        });
    }
    for (scene, folder) in offline::scene_folders(dir)? {
        for f in [GRAPH_FILE, GRID_FILE, visible_file] {
            files.insert(format!("{scene}/{f}"), file_digest(&folder.join(f))?);
        }
        files.insert(
            format!("{scene}/{FEATURE_FILE}"),
            h5_digest(&folder.join(FEATURE_FILE))?,
        );
        let att = folder.join(ATT_FILE);
        if offline::is_present(&att) {
            files.insert(format!("{scene}/{ATT_FILE}"), h5_digest(&att)?);
        }
    }
    let mut h = Fnv::new();
    for (name, d) in &files {
        h.eat(name.as_bytes());
        h.eat(&[0]);
        h.eat(d.as_bytes());
        h.eat(&[0]);
    }
    Ok(DataFingerprint {
        rule: RULE_OFFLINE,
        fingerprint: h.hex(),
        files,
        rule1,
    })
}

/// The files whose digests differ between `stored` and `now`, in words: `FloorPlan22/graph.json
/// changed`, `FloorPlan23/grid.json is new`, `... is gone`.
pub fn differences(
    stored: &BTreeMap<String, String>,
    now: &BTreeMap<String, String>,
) -> Vec<String> {
    let mut out = Vec::new();
    for (k, v) in stored {
        match now.get(k) {
            Some(w) if w == v => {}
            Some(_) => out.push(format!("{k} changed")),
            None => out.push(format!("{k} is gone")),
        }
    }
    for k in now.keys().filter(|k| !stored.contains_key(*k)) {
        out.push(format!("{k} is new"));
    }
    out
}
