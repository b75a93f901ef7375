//! A navigation model from a blob (int8 dequantised) or a checkpoint, with the PS module a
//! PS variant needs.

use std::path::Path;

use anyhow::{anyhow, bail, Context, Result};
use gman_core::blob::{Blob, TensorId};
use gman_core::spec::schema::Emd;
use gman_core::spec::ModelSpec;

use super::method::Method;
use super::nav_model::NavModel;
use crate::optim::checkpoint::Checkpoint;
use crate::optim::params::{Param, ParamSet};
use crate::pretrain::ps::PsModule;

/// Loads a model parameter set from the tensors of a blob (dequantising int8), so a blob can
/// be evaluated like a checkpoint. The method comes from the blob's flags (adapting or not)
/// and its PS width; `method` overrides it. The noise comes from the flags and `inner_lr` /
/// `max_inner` from the header's inner-loop settings (a v1 blob: 1e-4 and 4), so that
/// without an override [`NavModel::nav_config`]`(false)` is the blob's
/// `NavConfig::from_header` with sampled actions. A blob whose α1 and α2 differ is refused
/// (a `NavModel` has one inner rate).
pub fn model_from_blob(bytes: &[u8], method: Option<Method>) -> Result<NavModel> {
    model_from_blob_with_ps(bytes, method, None)
}

/// [`model_from_blob`] with the PS module a PS variant's blob needs (blobs do not carry it;
/// the PS variants are evaluated with the `ps.ckpt` they were trained with, or the tensors of
/// their training checkpoint). A PS module for a model without a PS input is refused.
pub(crate) fn model_from_blob_with_ps(
    bytes: &[u8],
    method: Option<Method>,
    ps: Option<PsModule>,
) -> Result<NavModel> {
    let blob = Blob::parse(bytes).map_err(|e| anyhow!("{e}"))?;
    let dims = blob.dims();
    let spec = ModelSpec::from_header(blob.header());
    // Every tensor must be present before anything is allocated from the header's dims
    // (present tensors were checked against the dims by the parser, so their sizes are backed
    // by bytes of the file).
    let missing: Vec<&str> = TensorId::all_for(&dims)
        .filter(|id| !blob.has(*id))
        .map(|id| id.name())
        .collect();
    if !missing.is_empty() {
        bail!(
            "the blob is not a complete navigator: tensor(s) {} missing",
            missing.join(", ")
        );
    }
    let mut params = ParamSet::new();
    for id in TensorId::all_for(&dims) {
        let (r, c) = id.shape(&dims);
        let mut p = Param::zeros(id.name(), r, c);
        blob.copy_f32(id, &mut p.data)
            .map_err(|e| anyhow!("{}: {e}", id.name()))?;
        params.push(p)?;
    }
    let method = method.unwrap_or(match (spec.adapt, dims.ps > 0) {
        (true, false) if spec.emd == Emd::CosSim => Method::GmanCossim,
        (true, false) => Method::Gman,
        (true, true) => Method::GmanPs,
        (false, false) => Method::A3cFg,
        (false, true) => Method::A3cFgPs,
    });
    match (method.uses_ps(), &ps) {
        (true, None) => bail!(
            "{} is a PS variant and blobs do not carry the PS module: give the one it was trained \
             with (`--ps ps.ckpt`, or its training checkpoint), or evaluate the checkpoint",
            method.name()
        ),
        (false, Some(_)) => bail!(
            "a PS module was given, but {} has no PS input",
            method.name()
        ),
        _ => {}
    }
    Ok(NavModel {
        method,
        dims,
        params,
        ps,
        spec,
        blob: Some(std::sync::Arc::new(bytes.to_vec())),
        privileged: false,
    })
}

/// Prints [`crate::blob_edit::unprotected_header_warning`] to stderr, once per file and
/// process (a command may load its model more than once).
fn warn_unprotected_header(path: &Path, bytes: &[u8]) {
    use std::collections::HashSet;
    use std::sync::Mutex;
    static WARNED: Mutex<Option<HashSet<std::path::PathBuf>>> = Mutex::new(None);
    let Some(text) = crate::blob_edit::unprotected_header_warning(path, bytes) else {
        return;
    };
    let mut warned = WARNED.lock().unwrap_or_else(|e| e.into_inner());
    if warned
        .get_or_insert_with(HashSet::new)
        .insert(path.to_path_buf())
    {
        eprintln!("{text}");
    }
}

/// Reads a model from a checkpoint (`.ckpt`) or a blob (`.gman`) file; a blob whose
/// checksum does not cover its header (formats v1-v3) loads with a warning on stderr.
pub fn load_model(path: &Path, method: Option<Method>) -> Result<NavModel> {
    load_model_with_ps(path, method, None)
}

/// [`load_model`]; a blob of a PS variant takes its PS module from the checkpoint file
/// `ps_path` (a `ps.ckpt` of `gman pretrain-ps`, or the run's training checkpoint). A
/// checkpoint carries its own PS module, so `ps_path` is refused with one.
pub fn load_model_with_ps(
    path: &Path,
    method: Option<Method>,
    ps_path: Option<&Path>,
) -> Result<NavModel> {
    let bytes = std::fs::read(path).with_context(|| format!("reading model {}", path.display()))?;
    if bytes.starts_with(&gman_core::blob::MAGIC) && !bytes.starts_with(b"GMANCKPT") {
        let ps = match ps_path {
            Some(p) => Some(
                PsModule::load(p).with_context(|| format!("loading PS module {}", p.display()))?,
            ),
            None => None,
        };
        warn_unprotected_header(path, &bytes);
        return model_from_blob_with_ps(&bytes, method, ps)
            .with_context(|| format!("blob {}", path.display()));
    }
    if let Some(p) = ps_path {
        bail!(
            "checkpoint {}: a checkpoint carries its own PS module; --ps {} is for blobs",
            path.display(),
            p.display()
        );
    }
    let ck = Checkpoint::from_bytes(&bytes, Some(path))?;
    let mut m =
        NavModel::from_checkpoint(&ck).with_context(|| format!("checkpoint {}", path.display()))?;
    if let Some(method) = method {
        if method.uses_ps() != m.method.uses_ps() {
            bail!(
                "checkpoint {}: it was trained as {} ({} the PS module) and cannot be evaluated as {}; \
                 use a method {} the PS module (e.g. gman-noemd-ps for gman-ps with adaptation off)",
                path.display(),
                m.method.name(),
                if m.method.uses_ps() { "with" } else { "without" },
                method.name(),
                if m.method.uses_ps() { "with" } else { "without" },
            );
        }
        m.method = method;
    }
    Ok(m)
}
