//! Edits of an existing weight blob that keep every tensor's bits (re-emitted through
//! gman-core's one encoder).

use std::path::Path;

use anyhow::{anyhow, bail, Result};
use gman_core::blob::{reencode, reencoded_len_bound, Blob, ChecksumScope, Quant};
#[cfg(doc)]
use gman_core::spec::schema::{FLAG_COMPACT_PSI, FLAG_INT8_ACTIVATIONS};

/// `bytes` (a weight blob) emitted again with [`FLAG_INT8_ACTIVATIONS`] and
/// [`FLAG_COMPACT_PSI`] set (`int8`) or both cleared: [`reencode_with_flags_of`] with Ψ's
/// compact form exactly when the activations are int8 (what `gman export` and the
/// firmware's build write).
pub fn reencode_with_activations(bytes: &[u8], int8: bool) -> Result<Vec<u8>> {
    reencode_with_flags_of(bytes, int8, int8)
}

/// Whether `gman export --activations auto` writes int8 activations
/// ([`FLAG_INT8_ACTIVATIONS`]) for a checkpoint: for the `mcu` preset with int8 weights, the
/// blob the default firmware runs (its integer path keeps a step within the 25 Hz cadence);
/// f32 otherwise.
pub fn default_int8_activations(mcu_preset: bool, int8_weights: bool) -> bool {
    mcu_preset && int8_weights
}

/// `bytes` (a weight blob) emitted again with [`FLAG_INT8_ACTIVATIONS`] set (`int8`) or
/// cleared and [`FLAG_COMPACT_PSI`] set (`compact_psi`) or cleared; every tensor, the other
/// flags and the inner-loop settings are kept. int8 activations need at least one int8
/// weight matrix.
pub fn reencode_with_flags_of(bytes: &[u8], int8: bool, compact_psi: bool) -> Result<Vec<u8>> {
    let blob = Blob::parse(bytes).map_err(|e| anyhow!("{e}"))?;
    let mut spec = blob.header().spec();
    spec.compact_psi = compact_psi;
    spec.int8_activations = int8;
    if int8 && !blob.tensors().any(|t| t.quant == Quant::I8) {
        bail!("the blob has no int8 weights; int8 activations need int8 weights (export with --quant int8)");
    }
    let mut out = vec![0u8; reencoded_len_bound(bytes)];
    let n = reencode(bytes, &spec, &mut out).map_err(|e| anyhow!("encoding the blob: {e}"))?;
    out.truncate(n);
    Ok(out)
}

/// The warning for a blob (`bytes`, read from `path`) whose CRC-32 does not cover its header
/// (formats v1-v3): a flipped flag bit, rate or map size in it loads unnoticed. `None` for a
/// blob of the current format, or one that does not parse (its error is reported where it
/// is read).
pub fn unprotected_header_warning(path: &Path, bytes: &[u8]) -> Option<String> {
    let blob = Blob::parse(bytes).ok()?;
    let h = blob.header();
    (h.checksum_scope() == ChecksumScope::Payload).then(|| {
        format!(
            "warning: {}: weight blob format v{} checksums the payload only, not the header: a changed flag, inner rate, cap or map size in it would load unnoticed; `gman upgrade-blob {} OUT.gman` rewrites it in format v{} (checksum over header and payload)",
            path.display(),
            h.version(),
            path.display(),
            gman_core::blob::FORMAT_VERSION
        )
    })
}

/// `bytes` (a weight blob of any format this build reads) rewritten in the current format:
/// the dims, every setting (named, format v5) and every tensor record byte for byte, the
/// checksum over the header and the payload.
pub fn upgrade_blob(bytes: &[u8]) -> Result<Vec<u8>> {
    let blob = Blob::parse(bytes).map_err(|e| anyhow!("{e}"))?;
    let mut out = vec![0u8; reencoded_len_bound(bytes)];
    let n = reencode(bytes, &blob.header().spec(), &mut out)
        .map_err(|e| anyhow!("encoding the blob: {e}"))?;
    out.truncate(n);
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;
    use gman_core::spec::schema::{FLAG_COMPACT_PSI, FLAG_INT8_ACTIVATIONS};

    fn shipped() -> Vec<u8> {
        let p = concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/../host-sim/models/gman-map3-b16-mcu-int8-seed5.gman"
        );
        std::fs::read(p).expect("shipped model")
    }

    #[test]
    fn int8_activations_set_one_flag_and_keep_every_tensor() {
        let orig = shipped();
        let q = reencode_with_activations(&orig, true).unwrap();
        let (a, b) = (Blob::parse(&orig).unwrap(), Blob::parse(&q).unwrap());
        assert_eq!(
            b.header().flags(),
            a.header().flags() | FLAG_INT8_ACTIVATIONS | FLAG_COMPACT_PSI
        );
        assert_eq!(a.header().adapt_settings(), b.header().adapt_settings());
        let ta: Vec<_> = a.tensors().map(|t| (t.id, t.data, t.scales)).collect();
        let tb: Vec<_> = b.tensors().map(|t| (t.id, t.data, t.scales)).collect();
        assert_eq!(ta, tb);
        // And back: the original's header fields and, byte for byte, its payload (the
        // re-emitted blob is format v5, whose checksum also covers the header).
        let back = reencode_with_activations(&q, false).unwrap();
        let c = Blob::parse(&back).unwrap();
        assert_eq!(c.header().flags(), a.header().flags());
        assert_eq!(c.dims(), a.dims());
        let plen = a.header().payload_len() as usize;
        assert_eq!(c.header().payload_len() as usize, plen);
        assert_eq!(back[back.len() - plen..], orig[orig.len() - plen..]);
    }
}
