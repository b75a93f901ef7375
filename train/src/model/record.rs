//! What a navigator checkpoint records of its model (typed, serde-serialised metadata) and
//! the check of the model settings against the trainer's copy of them.

use anyhow::{bail, Result};
use gman_core::spec::ModelSpec;
use gman_core::Dims;
use serde::{Deserialize, Serialize};

use super::method::Method;

/// Default cap on inner updates per episode (gman-core's default).
#[cfg(test)]
pub(crate) const DEFAULT_MAX_INNER: u32 = gman_core::blob::AdaptSettings::PAPER.max_inner;

/// The `kind` of a navigator checkpoint's metadata.
pub(crate) const NAVIGATOR_KIND: &str = "gman-navigator";

/// The model settings of a navigator checkpoint (its metadata; the trainer adds its own
/// `trainer` object beside them), typed and serde-serialised. Written by
/// [`NavModel::metadata`](super::NavModel::metadata), read by
/// [`NavModel::from_checkpoint`](super::NavModel::from_checkpoint); the fields that did not
/// exist in the first checkpoints default to the values those runs had.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ModelMeta {
    /// Always `"gman-navigator"`.
    pub kind: String,
    /// The method (its preset name).
    pub method: Method,
    /// The sizes.
    pub dims: DimsMeta,
    /// Hidden width of the PS module (PS variants only; `null` otherwise).
    #[serde(default)]
    pub ps_hidden: Option<usize>,
    /// The privileged-feature bound (absent: false).
    #[serde(default)]
    pub privileged: bool,
    /// The model's switches (`noise`, `inner_lr`, `max_inner`, `adapt_mode`, `inner_rule`,
    /// each absent in the first checkpoints: gman-core's [`ModelSpec`] defaults).
    #[serde(flatten)]
    pub spec: ModelSpec,
}

/// [`Dims`] as stored in checkpoints: the eight sizes, and the spatial-map sizes only for a
/// model with a map (absent: no map), so checkpoints without one are byte for byte as before
/// maps existed.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct DimsMeta(pub Dims);

#[derive(Serialize, Deserialize)]
struct DimsRecord {
    attr: usize,
    noise: usize,
    gen_hidden: usize,
    feat: usize,
    disc_hidden: usize,
    lstm_hidden: usize,
    embed: usize,
    ps: usize,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    map_rows: Option<usize>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    map_cols: Option<usize>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    cell_embed: Option<usize>,
}

impl Serialize for DimsMeta {
    fn serialize<S: serde::Serializer>(&self, s: S) -> std::result::Result<S::Ok, S::Error> {
        let d = &self.0;
        let map = d.map_rows + d.map_cols + d.cell_embed > 0;
        DimsRecord {
            attr: d.attr,
            noise: d.noise,
            gen_hidden: d.gen_hidden,
            feat: d.feat,
            disc_hidden: d.disc_hidden,
            lstm_hidden: d.lstm_hidden,
            embed: d.embed,
            ps: d.ps,
            map_rows: map.then_some(d.map_rows),
            map_cols: map.then_some(d.map_cols),
            cell_embed: map.then_some(d.cell_embed),
        }
        .serialize(s)
    }
}

impl<'de> Deserialize<'de> for DimsMeta {
    fn deserialize<D: serde::Deserializer<'de>>(de: D) -> std::result::Result<Self, D::Error> {
        let r = DimsRecord::deserialize(de)?;
        Ok(DimsMeta(Dims {
            attr: r.attr,
            noise: r.noise,
            gen_hidden: r.gen_hidden,
            feat: r.feat,
            disc_hidden: r.disc_hidden,
            lstm_hidden: r.lstm_hidden,
            embed: r.embed,
            ps: r.ps,
            map_rows: r.map_rows.unwrap_or(0),
            map_cols: r.map_cols.unwrap_or(0),
            cell_embed: r.cell_embed.unwrap_or(0),
        }))
    }
}

/// The model settings of a checkpoint's metadata: every top-level key but `trainer`.
fn model_settings(metadata: &serde_json::Value) -> serde_json::Map<String, serde_json::Value> {
    let mut m = metadata.as_object().cloned().unwrap_or_default();
    m.remove("trainer");
    m
}

/// Refuses a checkpoint whose model settings differ from the copy the trainer stored beside
/// them (the trainer settings' `model`), naming the first setting that differs and both values.
/// Checkpoints without a copy (older builds, pre-training) pass.
pub(crate) fn check_model_record(metadata: &serde_json::Value) -> Result<()> {
    let Some(copy) = metadata
        .get("trainer")
        .and_then(|t| t.get("model"))
        .filter(|c| !c.is_null())
    else {
        return Ok(());
    };
    let now = serde_json::Value::Object(model_settings(metadata));
    let mut diffs = Vec::new();
    json_diffs("", &now, copy, &mut diffs);
    if let Some((key, a, b)) = diffs.first() {
        bail!(
            "the checkpoint's model settings were changed after training wrote it: {key} is {a} but was {b} when the checkpoint was written ({} setting(s) differ); the tensors were trained with the recorded settings",
            diffs.len()
        );
    }
    Ok(())
}

/// Leaves of `a` and `b` that differ, as (dotted key, value in `a`, value in `b`).
fn json_diffs(
    at: &str,
    a: &serde_json::Value,
    b: &serde_json::Value,
    out: &mut Vec<(String, String, String)>,
) {
    use serde_json::Value;
    match (a, b) {
        (Value::Object(x), Value::Object(y)) => {
            let keys: std::collections::BTreeSet<&String> = x.keys().chain(y.keys()).collect();
            for k in keys {
                let key = if at.is_empty() {
                    k.clone()
                } else {
                    format!("{at}.{k}")
                };
                let show = |v: Option<&Value>| v.map_or("absent".to_string(), |v| v.to_string());
                match (x.get(k), y.get(k)) {
                    (Some(p), Some(q)) => json_diffs(&key, p, q, out),
                    (p, q) => out.push((key, show(p), show(q))),
                }
            }
        }
        _ if a != b => out.push((at.to_string(), a.to_string(), b.to_string())),
        _ => {}
    }
}
