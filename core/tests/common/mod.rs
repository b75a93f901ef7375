//! Helpers shared by the core's integration tests (included with `mod common;`).
#![allow(dead_code)]

use gman_core::blob::quant::quantize_rows;
use gman_core::blob::seeded::{encode_seeded, SeededWeights};
use gman_core::blob::{encode, encoded_len_bound, TensorData, TensorId, TensorSpec};
use gman_core::blob::{encode_model_scratch_len, encoded_model_len_bound, AdaptSettings, Quant};
use gman_core::Dims;

/// Small dims so that tests are fast.
pub const SMALL: Dims = Dims {
    attr: 5,
    noise: 3,
    gen_hidden: 8,
    feat: 6,
    disc_hidden: 7,
    lstm_hidden: 4,
    embed: 5,
    ps: 5,
    map_rows: 0,
    map_cols: 0,
    cell_embed: 0,
};

/// Random f32 values for every tensor of `dims`.
pub fn random_tensors(dims: &Dims, seed: u64) -> Vec<(TensorId, Vec<f32>)> {
    let mut w = SeededWeights::new(seed, 0.1);
    TensorId::all_for(dims)
        .map(|id| {
            let mut v = vec![0.0f32; id.numel(dims)];
            w.fill(&mut v);
            (id, v)
        })
        .collect()
}

/// The blob of [`random_tensors`]`(dims, seed)` with model `flags` and the paper's inner-loop
/// settings, through gman-core's one builder ([`encode_seeded`]).
pub fn seeded_blob(dims: &Dims, seed: u64, int8: bool, flags: u32) -> Vec<u8> {
    let quant = if int8 { Quant::I8 } else { Quant::F32 };
    let mut out = vec![0u8; encoded_model_len_bound(dims, quant)];
    let (nf, nb) = encode_model_scratch_len(dims);
    let n = encode_seeded(
        dims,
        flags,
        AdaptSettings::PAPER,
        quant,
        seed,
        0.1,
        &mut out,
        &mut vec![0.0; nf],
        &mut vec![0; nb],
    )
    .unwrap();
    out.truncate(n);
    out
}

/// Encodes an arbitrary list of `tensors` (possibly incomplete or out of order, to test the
/// parser), int8-quantising the matrices when `int8` is set.
pub fn make_blob(dims: &Dims, tensors: &[(TensorId, Vec<f32>)], int8: bool) -> Vec<u8> {
    let quantised: Vec<(TensorId, Vec<u8>, Vec<f32>)> = tensors
        .iter()
        .filter(|(id, _)| int8 && !id.is_vector())
        .map(|(id, v)| {
            let (r, c) = id.shape(dims);
            let mut q = vec![0u8; v.len()];
            let mut s = vec![0.0f32; r];
            quantize_rows(v, r, c, &mut q, &mut s).unwrap();
            (*id, q, s)
        })
        .collect();
    let specs: Vec<TensorSpec<'_>> = tensors
        .iter()
        .map(
            |(id, v)| match quantised.iter().find(|(qid, _, _)| qid == id) {
                Some((_, q, s)) => TensorSpec {
                    id: *id,
                    data: TensorData::I8 { q, scales: s },
                },
                None => TensorSpec {
                    id: *id,
                    data: TensorData::F32(v),
                },
            },
        )
        .collect();
    let mut out = vec![0u8; encoded_len_bound(&specs)];
    let n = encode(dims, &specs, &mut out).unwrap();
    out.truncate(n);
    out
}

/// The postcard (LEB128) varint of `v`.
pub fn varint(mut v: u64) -> Vec<u8> {
    let mut o = Vec::new();
    loop {
        let b = (v & 0x7F) as u8;
        v >>= 7;
        if v == 0 {
            o.push(b);
            return o;
        }
        o.push(b | 0x80);
    }
}

/// Rewrites the header's CRC after the payload was modified (the CRC is the header's last
/// field), so that record validation, not the checksum, is what a test exercises.
pub fn reseal(blob: &[u8], payload_len: usize, old_crc: u32) -> Vec<u8> {
    let hlen = blob.len() - payload_len;
    let old = varint(old_crc.into());
    let prefix = &blob[..hlen - old.len()];
    let payload = &blob[hlen..];
    let mut out = prefix.to_vec();
    // v4, v5: the CRC covers the header bytes before it and the payload; v1-v3: the payload.
    let crc = if blob.get(4).is_some_and(|v| *v >= 4) {
        gman_core::blob::crc32::crc32_update(gman_core::blob::crc32::crc32(prefix), payload)
    } else {
        gman_core::blob::crc32::crc32(payload)
    };
    out.extend(varint(crc.into()));
    out.extend_from_slice(payload);
    out
}

/// A valid format-v2 blob with these raw dims and model flags, the paper's inner-loop
/// settings and no tensors (empty payload, CRC 0).
pub fn header_only_blob(dims: [u64; 8], flags: u64) -> Vec<u8> {
    let mut b = gman_core::blob::MAGIC.to_vec();
    b.extend(varint(2));
    for d in dims {
        b.extend(varint(d));
    }
    b.extend(varint(flags));
    b.extend(1e-4f32.to_le_bytes());
    b.extend(1e-4f32.to_le_bytes());
    b.extend(varint(4)); // max_inner
    b.extend(varint(0)); // n_tensors
    b.extend(varint(0)); // payload_len
    b.extend(varint(0)); // CRC-32 of the empty payload
    b
}

/// Deterministic values in `[-1, 1]` (xorshift), `n` of them from `seed`.
pub fn vals(n: usize, seed: u32) -> Vec<f32> {
    let mut s = seed.wrapping_mul(2654435761).wrapping_add(7);
    (0..n)
        .map(|_| {
            s ^= s << 13;
            s ^= s >> 17;
            s ^= s << 5;
            (s % 2001) as f32 / 1000.0 - 1.0
        })
        .collect()
}

/// The blob `v4` rewritten in the format the encoders wrote before v4 (test fixture): v2
/// without a map, v3 with one; the same fields, the CRC over the payload only, the same
/// payload bytes.
pub fn legacy(v4: &[u8]) -> Vec<u8> {
    let blob = gman_core::blob::Blob::parse(v4).unwrap();
    let h = *blob.header();
    let d = h.dims();
    let map = d.map_rows != 0;
    let mut out = gman_core::blob::MAGIC.to_vec();
    out.extend(varint(if map { 3 } else { 2 }));
    for v in [
        d.attr,
        d.noise,
        d.gen_hidden,
        d.feat,
        d.disc_hidden,
        d.lstm_hidden,
        d.embed,
        d.ps,
    ] {
        out.extend(varint(v as u64));
    }
    if map {
        for v in [d.map_rows, d.map_cols, d.cell_embed] {
            out.extend(varint(v as u64));
        }
    }
    out.extend(varint(h.flags().into()));
    out.extend(h.alpha_disc().to_le_bytes());
    out.extend(h.alpha_adapt().to_le_bytes());
    out.extend(varint(h.max_inner().into()));
    out.extend(varint(h.n_tensors().into()));
    out.extend(varint(h.payload_len().into()));
    let payload = &v4[v4.len() - h.payload_len() as usize..];
    out.extend(varint(gman_core::blob::crc32::crc32(payload).into()));
    out.extend_from_slice(payload);
    out
}

/// The blob `blob` (any version) written in format v4 (what the encoders wrote before v5:
/// the settings as flag bits and rates, the CRC over the header and the payload), by hand.
pub fn as_v4(blob: &[u8]) -> Vec<u8> {
    let b = gman_core::blob::Blob::parse(blob).unwrap();
    let h = *b.header();
    let d = h.dims();
    let mut out = gman_core::blob::MAGIC.to_vec();
    out.extend(varint(4));
    for v in [
        d.attr,
        d.noise,
        d.gen_hidden,
        d.feat,
        d.disc_hidden,
        d.lstm_hidden,
        d.embed,
        d.ps,
        d.map_rows,
        d.map_cols,
        d.cell_embed,
    ] {
        out.extend(varint(v as u64));
    }
    out.extend(varint(h.flags().into()));
    out.extend(h.alpha_disc().to_le_bytes());
    out.extend(h.alpha_adapt().to_le_bytes());
    out.extend(varint(h.max_inner().into()));
    out.extend(varint(h.n_tensors().into()));
    out.extend(varint(h.payload_len().into()));
    let payload = &blob[blob.len() - h.payload_len() as usize..];
    let crc = gman_core::blob::crc32::crc32_update(gman_core::blob::crc32::crc32(&out), payload);
    out.extend(varint(crc.into()));
    out.extend_from_slice(payload);
    out
}

/// A format-v2 blob (v3 with a map) with every tensor of `dims` (small f32 values), the
/// header and the records written by hand, not by the encoder: it can carry dims the
/// encoder refuses (zero widths, an inconsistent map), with a valid CRC.
pub fn raw_blob(dims: &Dims, flags: u32) -> Vec<u8> {
    let mut payload = Vec::new();
    let mut n = 0u64;
    for id in TensorId::all_for(dims) {
        let (r, c) = id.shape(dims);
        payload.extend(varint(id as u64));
        payload.extend(varint(r as u64));
        payload.extend(varint(c as u64));
        payload.push(0); // f32
        payload.extend(varint((4 * r * c) as u64));
        for i in 0..r * c {
            payload.extend((((i % 7) as f32 - 3.0) * 0.01).to_le_bytes());
        }
        payload.extend(varint(0)); // no scales
        n += 1;
    }
    let map = dims.map_rows != 0 || dims.map_cols != 0 || dims.cell_embed != 0;
    let mut b = gman_core::blob::MAGIC.to_vec();
    b.extend(varint(if map { 3 } else { 2 }));
    for v in [
        dims.attr,
        dims.noise,
        dims.gen_hidden,
        dims.feat,
        dims.disc_hidden,
        dims.lstm_hidden,
        dims.embed,
        dims.ps,
    ] {
        b.extend(varint(v as u64));
    }
    if map {
        for v in [dims.map_rows, dims.map_cols, dims.cell_embed] {
            b.extend(varint(v as u64));
        }
    }
    b.extend(varint(flags.into()));
    b.extend(1e-4f32.to_le_bytes());
    b.extend(1e-4f32.to_le_bytes());
    b.extend(varint(4));
    b.extend(varint(n));
    b.extend(varint(payload.len() as u64));
    b.extend(varint(gman_core::blob::crc32::crc32(&payload).into()));
    b.extend(payload);
    b
}
