//! Weight-blob round trips, quantisation error bounds and typed rejection of bad blobs.

mod common;
use common::*;
use gman_core::blob::{
    encode_with_settings, encoded_len_bound, AdaptSettings, Blob, ChecksumScope, Quant, TensorData,
    TensorId, TensorSpec, FLAG_ADAPT, FLAG_COSSIM, FLAG_FULL_ADAPT, FLAG_ZERO_NOISE,
    FORMAT_VERSION, MAGIC, MAX_INNER_RATE,
};
use gman_core::navigator::memory::AdaptMode;
use gman_core::navigator::{Emd, NavConfig, NoiseMode, StepRule};
use gman_core::spec::schema::{DISC_STEPS_SHIFT, FLAG_NORMALIZED_STEP};
use gman_core::spec::{InnerRule, ModelSpec};
use gman_core::{BlobError, Dims};
use proptest::prelude::*;

#[test]
fn f32_round_trip_is_exact_and_zero_copy() {
    let t = random_tensors(&SMALL, 1);
    let bytes = make_blob(&SMALL, &t, false);
    let blob = Blob::parse(&bytes).unwrap();
    assert_eq!(blob.dims(), SMALL);
    blob.check_dims(&SMALL).unwrap();
    for (id, v) in &t {
        let view = blob.tensor(*id).unwrap();
        assert_eq!(view.quant, Quant::F32);
        // The view borrows from the blob bytes: its data pointer lies inside them.
        let range = bytes.as_ptr_range();
        assert!(range.contains(&view.data.as_ptr()), "{id:?} was copied");
        let mut out = vec![0.0; v.len()];
        blob.copy_f32(*id, &mut out).unwrap();
        assert_eq!(&out, v, "{id:?}");
    }
}

#[test]
fn int8_round_trip_respects_documented_error_bound() {
    let t = random_tensors(&SMALL, 2);
    let bytes = make_blob(&SMALL, &t, true);
    let f32_bytes = make_blob(&SMALL, &t, false);
    let blob = Blob::parse(&bytes).unwrap();
    let payload = |b: &[u8]| Blob::parse(b).unwrap().header().payload_len();
    assert!(
        payload(&bytes) < payload(&f32_bytes) / 2,
        "int8 blob should be much smaller"
    );
    for (id, v) in &t {
        let view = blob.tensor(*id).unwrap();
        let mut out = vec![0.0; v.len()];
        blob.copy_f32(*id, &mut out).unwrap();
        if id.is_vector() {
            assert_eq!(view.quant, Quant::F32);
            assert_eq!(&out, v);
            continue;
        }
        assert_eq!(view.quant, Quant::I8);
        // Documented bound (gman_core::blob::quant): |w - w_hat| <= max|w| / 254 per tensor
        // (per row: scale / 2), up to f32 rounding.
        let maxabs = v.iter().fold(0.0f32, |m, x| m.max(x.abs()));
        let bound = maxabs / 254.0 * (1.0 + 1e-5);
        let worst = v
            .iter()
            .zip(&out)
            .fold(0.0f32, |m, (a, b)| m.max((a - b).abs()));
        assert!(worst <= bound, "{id:?}: error {worst} > bound {bound}");
        assert!(worst <= view.max_rounding_error() * (1.0 + 1e-5) + 1e-12);
        assert!(
            worst > 0.0,
            "{id:?}: quantisation should not be lossless on random data"
        );
    }
}

#[test]
fn every_truncation_is_rejected() {
    let bytes = make_blob(&SMALL, &random_tensors(&SMALL, 3), true);
    for n in 0..bytes.len() {
        assert!(
            Blob::parse(&bytes[..n]).is_err(),
            "prefix of {n} bytes parsed"
        );
    }
    let mut longer = bytes.clone();
    longer.push(0);
    assert!(matches!(
        Blob::parse(&longer),
        Err(BlobError::PayloadLength { .. })
    ));
}

#[test]
fn bad_magic_version_checksum_and_dims_are_typed() {
    let bytes = make_blob(&SMALL, &random_tensors(&SMALL, 4), false);
    let mut m = bytes.clone();
    m[0] = b'X';
    assert_eq!(Blob::parse(&m).unwrap_err(), BlobError::BadMagic);
    assert_eq!(bytes[4], 5, "the encoder writes format v5");
    for bad in [0u8, 6, 9, 0x7f] {
        let mut v = bytes.clone();
        v[4] = bad; // version varint follows the 4 magic bytes
        assert_eq!(
            Blob::parse(&v).unwrap_err(),
            BlobError::UnsupportedVersion { found: bad as u16 }
        );
    }
    let mut c = bytes.clone();
    let last = c.len() - 1;
    c[last] ^= 0x55;
    assert!(matches!(
        Blob::parse(&c),
        Err(BlobError::HeaderChecksumMismatch { .. })
    ));
    let mut c = legacy(&bytes);
    let last = c.len() - 1;
    c[last] ^= 0x55;
    assert!(matches!(
        Blob::parse(&c),
        Err(BlobError::ChecksumMismatch { .. })
    ));
    let blob = Blob::parse(&bytes).unwrap();
    let other = Dims {
        gen_hidden: 9,
        ..SMALL
    };
    assert_eq!(
        blob.check_dims(&other).unwrap_err(),
        BlobError::DimensionMismatch {
            field: "gen_hidden",
            expected: 9,
            found: 8
        }
    );
}

#[test]
fn nan_scale_and_nan_weight_are_rejected() {
    let t = random_tensors(&SMALL, 5);
    let bytes = make_blob(&SMALL, &t, true);
    let blob = Blob::parse(&bytes).unwrap();
    let plen = blob.header().payload_len() as usize;
    let crc = blob.header().payload_crc();
    // Find the scales of GenW1 inside the blob and overwrite the first with NaN.
    let scales = blob.tensor(TensorId::GenW1).unwrap().scales;
    let off = scales.as_ptr() as usize - bytes.as_ptr() as usize;
    let mut bad = bytes.clone();
    bad[off..off + 4].copy_from_slice(&f32::NAN.to_le_bytes());
    let bad = reseal(&bad, plen, crc);
    assert_eq!(
        Blob::parse(&bad).unwrap_err(),
        BlobError::NonFiniteScale {
            id: TensorId::GenW1 as u16
        }
    );

    let fbytes = make_blob(&SMALL, &t, false);
    let fblob = Blob::parse(&fbytes).unwrap();
    let data = fblob.tensor(TensorId::LstmWh).unwrap().data;
    let off = data.as_ptr() as usize - fbytes.as_ptr() as usize;
    let mut bad = fbytes.clone();
    bad[off + 8..off + 12].copy_from_slice(&f32::INFINITY.to_le_bytes());
    let bad = reseal(
        &bad,
        fblob.header().payload_len() as usize,
        fblob.header().payload_crc(),
    );
    assert_eq!(
        Blob::parse(&bad).unwrap_err(),
        BlobError::NonFiniteWeight {
            id: TensorId::LstmWh as u16
        }
    );
}

#[test]
fn missing_tensor_is_reported() {
    let t: Vec<_> = random_tensors(&SMALL, 6)
        .into_iter()
        .filter(|(id, _)| *id != TensorId::ActorW)
        .collect();
    let blob_bytes = make_blob(&SMALL, &t, false);
    let blob = Blob::parse(&blob_bytes).unwrap();
    assert_eq!(
        blob.tensor(TensorId::ActorW).unwrap_err(),
        BlobError::MissingTensor {
            id: TensorId::ActorW as u16
        }
    );
    assert!(blob.has(TensorId::GenW1));
}

#[test]
fn encoder_rejects_what_the_parser_would() {
    use gman_core::blob::{encode, TensorData, TensorSpec};
    let v = vec![f32::NAN; 8];
    let mut out = vec![0u8; 1024];
    let spec = [TensorSpec {
        id: TensorId::GenB1,
        data: TensorData::F32(&v),
    }];
    assert_eq!(
        encode(&SMALL, &spec, &mut out).unwrap_err(),
        BlobError::NonFiniteWeight { id: 1 }
    );
    let short = vec![0.0f32; 3];
    let spec = [TensorSpec {
        id: TensorId::GenB1,
        data: TensorData::F32(&short),
    }];
    assert_eq!(
        encode(&SMALL, &spec, &mut out).unwrap_err(),
        BlobError::BadTensorShape { id: 1 }
    );
    let mut tiny = vec![0u8; 100];
    let ok = vec![0.0f32; 8 * 8];
    let spec = [TensorSpec {
        id: TensorId::GenW1,
        data: TensorData::F32(&ok),
    }];
    assert_eq!(
        encode(&SMALL, &spec, &mut tiny).unwrap_err(),
        BlobError::BufferTooSmall
    );
}

/// f32 specs of `tensors` (no quantisation).
fn f32_specs(tensors: &[(TensorId, Vec<f32>)]) -> Vec<TensorSpec<'_>> {
    tensors
        .iter()
        .map(|(id, v)| TensorSpec {
            id: *id,
            data: TensorData::F32(v),
        })
        .collect()
}

/// A v5 blob of `SMALL` f32 tensors with the given flags and settings.
fn blob_v5_with(flags: u32, settings: AdaptSettings, seed: u64) -> Vec<u8> {
    let t = random_tensors(&SMALL, seed);
    let specs = f32_specs(&t);
    let mut out = vec![0u8; encoded_len_bound(&specs)];
    let n = encode_with_settings(&SMALL, flags, settings, &specs, &mut out).unwrap();
    out.truncate(n);
    out
}

/// The same blob in format v4.
fn blob_v4_with(flags: u32, settings: AdaptSettings, seed: u64) -> Vec<u8> {
    as_v4(&blob_v5_with(flags, settings, seed))
}

/// The same blob in format v2 (what the encoders wrote before v4; CRC over the payload).
fn blob_with(flags: u32, settings: AdaptSettings, seed: u64) -> Vec<u8> {
    legacy(&blob_v4_with(flags, settings, seed))
}

/// Reads a postcard (LEB128) varint at `*at`.
fn read_varint(b: &[u8], at: &mut usize) -> u64 {
    let (mut v, mut shift) = (0u64, 0);
    loop {
        let byte = b[*at];
        *at += 1;
        v |= u64::from(byte & 0x7f) << shift;
        if byte & 0x80 == 0 {
            return v;
        }
        shift += 7;
    }
}

use common::varint as varint_bytes;

/// Offset of `alpha_disc` in a v2 blob: after magic, version, the 8 dims and the flags.
fn alpha_offset(bytes: &[u8]) -> usize {
    let mut at = 4;
    for _ in 0..(1 + 8 + 1) {
        read_varint(bytes, &mut at);
    }
    at
}

/// A tiny v1 encoder (test fixture): the v1 header is the v2 header without `alpha_disc`,
/// `alpha_adapt` and `max_inner`; the payload is the same. Rewrites the v2 blob `v2`.
fn v1_from_v2(v2: &[u8]) -> Vec<u8> {
    let blob = Blob::parse(v2).unwrap();
    let h = *blob.header();
    let d = h.dims();
    let mut out = MAGIC.to_vec();
    out.extend(varint_bytes(1));
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
        out.extend(varint_bytes(v as u64));
    }
    out.extend(varint_bytes(h.flags().into()));
    out.extend(varint_bytes(h.n_tensors().into()));
    out.extend(varint_bytes(h.payload_len().into()));
    out.extend(varint_bytes(h.payload_crc().into()));
    out.extend_from_slice(&v2[v2.len() - h.payload_len() as usize..]);
    out
}

#[test]
fn v2_round_trips_the_inner_loop_settings() {
    let settings = AdaptSettings {
        alpha_disc: 0.25,
        alpha_adapt: 3e-3,
        max_inner: 7,
    };
    let bytes = blob_with(FLAG_ADAPT | FLAG_COSSIM, settings, 11);
    let blob = Blob::parse(&bytes).unwrap();
    let h = blob.header();
    // The v2 rewrite of a blob keeps its settings (the encoders write FORMAT_VERSION, v4).
    assert_eq!(h.version(), 2);
    assert!(h.version() < FORMAT_VERSION);
    assert_eq!(h.checksum_scope(), ChecksumScope::Payload);
    assert!(h.has_adapt_settings());
    assert_eq!(h.adapt_settings(), settings);
    assert_eq!(h.alpha_disc().to_bits(), 0.25f32.to_bits());
    assert_eq!(h.alpha_adapt().to_bits(), 3e-3f32.to_bits());
    assert_eq!(h.max_inner(), 7);
    assert_eq!(h.flags(), FLAG_ADAPT | FLAG_COSSIM);
    // A large cap and a zero rate are valid too.
    let other = AdaptSettings {
        alpha_disc: 0.0,
        alpha_adapt: MAX_INNER_RATE,
        max_inner: u32::MAX,
    };
    let b2 = blob_with(0, other, 11);
    assert_eq!(Blob::parse(&b2).unwrap().header().adapt_settings(), other);
    // The plain encoders write v4 with the paper's settings.
    let plain = make_blob(&SMALL, &random_tensors(&SMALL, 11), true);
    let pb = Blob::parse(&plain).unwrap();
    assert_eq!(pb.header().version(), FORMAT_VERSION);
    assert_eq!(
        pb.header().checksum_scope(),
        ChecksumScope::HeaderAndPayload
    );
    assert_eq!(pb.header().adapt_settings(), AdaptSettings::PAPER);
    assert_eq!(AdaptSettings::default(), AdaptSettings::PAPER);
}

#[test]
fn v2_header_layout_is_the_documented_one() {
    let settings = AdaptSettings {
        alpha_disc: 0.125,
        alpha_adapt: 2e-4,
        max_inner: 300,
    };
    let bytes = blob_with(FLAG_ZERO_NOISE, settings, 12);
    let blob = Blob::parse(&bytes).unwrap();
    let h = blob.header();
    assert_eq!(bytes[..4], MAGIC);
    let mut at = 4;
    assert_eq!(read_varint(&bytes, &mut at), 2);
    let d = SMALL;
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
        assert_eq!(read_varint(&bytes, &mut at), v as u64);
    }
    assert_eq!(read_varint(&bytes, &mut at), u64::from(FLAG_ZERO_NOISE));
    assert_eq!(at, alpha_offset(&bytes));
    let f = |at: usize| f32::from_le_bytes(bytes[at..at + 4].try_into().unwrap());
    assert_eq!(f(at), 0.125);
    assert_eq!(f(at + 4), 2e-4);
    at += 8;
    assert_eq!(read_varint(&bytes, &mut at), 300);
    assert_eq!(read_varint(&bytes, &mut at), u64::from(h.n_tensors()));
    assert_eq!(read_varint(&bytes, &mut at), u64::from(h.payload_len()));
    assert_eq!(read_varint(&bytes, &mut at), u64::from(h.payload_crc()));
    assert_eq!(
        at,
        bytes.len() - h.payload_len() as usize,
        "CRC is the last field"
    );
}

#[test]
fn v1_blobs_still_parse_with_the_paper_settings() {
    let v2 = blob_with(
        FLAG_ADAPT | FLAG_ZERO_NOISE,
        AdaptSettings {
            alpha_disc: 0.5,
            alpha_adapt: 0.5,
            max_inner: 9,
        },
        13,
    );
    let v1 = v1_from_v2(&v2);
    assert_eq!(v1[4], 1);
    assert_eq!(
        v1.len(),
        v2.len() - 9,
        "v1 lacks 4 + 4 + 1 bytes of settings"
    );
    let b1 = Blob::parse(&v1).unwrap();
    let b2 = Blob::parse(&v2).unwrap();
    let h = b1.header();
    assert_eq!(h.version(), 1);
    assert!(!h.has_adapt_settings());
    assert_eq!(h.adapt_settings(), AdaptSettings::PAPER);
    assert_eq!(
        (h.alpha_disc(), h.alpha_adapt(), h.max_inner()),
        (1e-4, 1e-4, 4)
    );
    assert_eq!(h.flags(), FLAG_ADAPT | FLAG_ZERO_NOISE);
    assert_eq!(b1.dims(), SMALL);
    for (a, b) in b1.tensors().zip(b2.tensors()) {
        assert_eq!((a.id, a.data, a.scales), (b.id, b.data, b.scales));
    }
    // The navigator configuration of a v1 blob is NavConfig::default()'s inner loop.
    let cfg = NavConfig::from_header(h);
    let d = NavConfig::default();
    assert_eq!(
        (
            cfg.model.alpha_disc(),
            cfg.model.inner_lr,
            cfg.model.max_inner
        ),
        (d.model.alpha_disc(), d.model.inner_lr, d.model.max_inner)
    );
    assert_eq!(cfg.model.noise, NoiseMode::Zero);
    // The shipped GMAN model (v2, trained with the paper's inner loop) parses with those
    // settings, whichever version it is stored in.
    let shipped = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../host-sim/models/gman-mcu-int8-seed1.gman");
    let bytes = std::fs::read(shipped).expect("shipped model");
    let b = Blob::parse(&bytes).unwrap();
    assert_eq!(b.header().adapt_settings(), AdaptSettings::PAPER);
    // Every truncation of a v1 blob is rejected; a bad v1 checksum is typed.
    for n in 0..v1.len().min(200) {
        assert!(
            Blob::parse(&v1[..n]).is_err(),
            "v1 prefix of {n} bytes parsed"
        );
    }
    let mut c = v1.clone();
    let last = c.len() - 1;
    c[last] ^= 0x55;
    assert!(matches!(
        Blob::parse(&c),
        Err(BlobError::ChecksumMismatch { .. })
    ));
}

#[test]
fn bad_inner_rates_are_typed_errors() {
    let bytes = blob_with(FLAG_ADAPT, AdaptSettings::PAPER, 14);
    let at = alpha_offset(&bytes);
    for (off, field) in [(0, "alpha_disc"), (4, "alpha_adapt")] {
        for bad in [
            f32::NAN,
            f32::INFINITY,
            f32::NEG_INFINITY,
            -1.0,
            -1e-30,
            MAX_INNER_RATE * 1.0001,
            3.4e36,
        ] {
            let mut m = bytes.clone();
            m[at + off..at + off + 4].copy_from_slice(&bad.to_le_bytes());
            let e = Blob::parse(&m).unwrap_err();
            assert_eq!(
                e,
                BlobError::BadInnerRate {
                    field,
                    bits: bad.to_bits()
                },
                "{field} = {bad}"
            );
            let msg = e.to_string();
            assert!(
                msg.contains(field) && msg.contains("finite, non-negative and at most 1"),
                "{msg}"
            );
        }
    }
    // The encoder refuses what the parser would.
    let t = random_tensors(&SMALL, 14);
    let specs = f32_specs(&t);
    let mut out = vec![0u8; encoded_len_bound(&specs)];
    for (s, field) in [
        (
            AdaptSettings {
                alpha_disc: f32::NAN,
                ..AdaptSettings::PAPER
            },
            "alpha_disc",
        ),
        (
            AdaptSettings {
                alpha_adapt: -0.5,
                ..AdaptSettings::PAPER
            },
            "alpha_adapt",
        ),
    ] {
        assert!(matches!(
            encode_with_settings(&SMALL, 0, s, &specs, &mut out),
            Err(BlobError::BadInnerRate { field: f, .. }) if f == field
        ));
    }
}

#[test]
fn nav_config_follows_the_header() {
    let settings = AdaptSettings {
        alpha_disc: 0.03,
        alpha_adapt: 0.07,
        max_inner: 2,
    };
    for flags in 0..32u32 {
        // Bit 4 stands for bit 24 (int8 activations: how the weights run, which the model's
        // settings record too).
        let flags = (flags & 15) | if flags & 16 != 0 { 1 << 24 } else { 0 };
        let bytes = blob_with(flags, settings, 15);
        let blob = Blob::parse(&bytes).unwrap();
        let cfg = NavConfig::from_header(blob.header());
        assert_eq!(cfg, blob.nav_config());
        let expected = NavConfig {
            model: ModelSpec {
                adapt: flags & FLAG_ADAPT != 0,
                emd: if flags & FLAG_COSSIM != 0 {
                    Emd::CosSim
                } else {
                    Emd::Discriminator
                },
                noise: if flags & FLAG_ZERO_NOISE != 0 {
                    NoiseMode::Zero
                } else {
                    NoiseMode::Gaussian
                },
                inner_lr: 0.07,
                max_inner: 2,
                adapt_mode: if flags & FLAG_FULL_ADAPT != 0 {
                    AdaptMode::Full
                } else {
                    AdaptMode::Efficient
                },
                inner_rule: InnerRule {
                    disc_lr: Some(0.03),
                    ..InnerRule::PAPER
                },
                int8_activations: flags & (1 << 24) != 0,
                ..NavConfig::default().model
            },
            check_mode: true,
            ..NavConfig::default()
        };
        assert_eq!(cfg, expected, "flags {flags:#x}");
    }
    // The inner rule's levers: D's steps in bits 8..16 (minus one), the normalised step.
    for (bits, steps, rule) in [
        (0u32, 1u32, StepRule::Gradient),
        (4 << DISC_STEPS_SHIFT, 5, StepRule::Gradient),
        (FLAG_NORMALIZED_STEP, 1, StepRule::Normalized),
        (
            (255 << DISC_STEPS_SHIFT) | FLAG_NORMALIZED_STEP,
            256,
            StepRule::Normalized,
        ),
    ] {
        let bytes = blob_with(FLAG_ADAPT | bits, settings, 15);
        let cfg = Blob::parse(&bytes).unwrap().nav_config();
        assert_eq!(
            (
                cfg.model.inner_rule.disc_steps,
                cfg.model.inner_rule.step_rule
            ),
            (steps, rule),
            "flags {bits:#x}"
        );
    }
    // A blob with FLAG_ADAPT and the paper's settings asks for NavConfig::default() in the
    // mode it records.
    let bytes = blob_with(FLAG_ADAPT, AdaptSettings::PAPER, 15);
    assert_eq!(
        Blob::parse(&bytes).unwrap().nav_config(),
        NavConfig {
            model: ModelSpec {
                adapt_mode: AdaptMode::Efficient,
                ..NavConfig::default().model
            },
            check_mode: true,
            ..NavConfig::default()
        }
    );
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 512, .. ProptestConfig::default() })]

    /// Random byte edits and truncations: parsing returns (Ok or a typed Err), never panics,
    /// and an edited blob whose checksum was not fixed is always rejected.
    #[test]
    fn mutated_blobs_never_panic(edits in prop::collection::vec((any::<prop::sample::Index>(), any::<u8>()), 1..6),
                                 cut in any::<prop::sample::Index>(), int8 in any::<bool>(), fix_crc in any::<bool>()) {
        let bytes = make_blob(&SMALL, &random_tensors(&SMALL, 7), int8);
        let blob = Blob::parse(&bytes).unwrap();
        let (plen, crc) = (blob.header().payload_len() as usize, blob.header().payload_crc());
        let hlen = bytes.len() - plen;
        let mut m = bytes.clone();
        for (i, b) in &edits {
            m[hlen + i.index(plen)] = *b;
        }
        // (Two edits of one byte can put its value back: compare the results, not the edits.)
        let changed = m != bytes;
        if fix_crc {
            let m2 = reseal(&m, plen, crc);
            if let Ok(b) = Blob::parse(&m2) {
                for t in b.tensors() {
                    prop_assert!(t.matrix().is_ok());
                }
            }
        } else if changed {
            prop_assert!(Blob::parse(&m).is_err());
        }
        let n = cut.index(bytes.len());
        prop_assert!(Blob::parse(&bytes[..n]).is_err());
    }

    /// Arbitrary bytes never panic.
    #[test]
    fn arbitrary_bytes_never_panic(data in prop::collection::vec(any::<u8>(), 0..512)) {
        let _ = Blob::parse(&data);
        for version in [1u8, 2, 3] {
            let mut with_magic = MAGIC.to_vec();
            with_magic.push(version);
            with_magic.extend_from_slice(&data);
            let _ = Blob::parse(&with_magic);
        }
    }

    /// Any bits in the v2 rates: the blob parses with exactly those rates when they are finite
    /// and non-negative, and is rejected with `BadInnerRate` otherwise; never a panic.
    #[test]
    fn any_rate_bits_parse_or_are_rejected(a in any::<u32>(), b in any::<u32>(), cap in any::<u32>()) {
        let bytes = blob_with(FLAG_ADAPT, AdaptSettings { max_inner: cap, ..AdaptSettings::PAPER }, 16);
        let at = alpha_offset(&bytes);
        let mut m = bytes.clone();
        m[at..at + 4].copy_from_slice(&a.to_le_bytes());
        m[at + 4..at + 8].copy_from_slice(&b.to_le_bytes());
        let ok = |bits: u32| { let v = f32::from_bits(bits); v.is_finite() && (0.0..=MAX_INNER_RATE).contains(&v) };
        match Blob::parse(&m) {
            Ok(blob) => {
                prop_assert!(ok(a) && ok(b));
                let h = blob.header();
                prop_assert_eq!((h.alpha_disc().to_bits(), h.alpha_adapt().to_bits(), h.max_inner()), (a, b, cap));
            }
            Err(BlobError::BadInnerRate { field, bits }) => {
                prop_assert!(!(ok(a) && ok(b)));
                if ok(a) {
                    prop_assert_eq!((field, bits), ("alpha_adapt", b));
                } else {
                    prop_assert_eq!((field, bits), ("alpha_disc", a));
                }
            }
            Err(e) => prop_assert!(false, "unexpected error {e:?}"),
        }
    }
}

/// A model with a spatial map is written as format v3: the map dims round-trip, the per-cell
/// layer is stored and read in place, and a blob without a map may not carry it.
#[test]
fn v3_blobs_carry_the_spatial_map() {
    let dims = SMALL.with_map(2, 3, 4);
    let tensors = random_tensors(&dims, 21);
    assert!(tensors.iter().any(|(id, _)| *id == TensorId::CellW));
    for int8 in [false, true] {
        let bytes = make_blob(&dims, &tensors, int8);
        let blob = Blob::parse(&bytes).unwrap();
        assert_eq!(blob.header().version(), FORMAT_VERSION);
        let old = legacy(&bytes);
        let ob = Blob::parse(&old).unwrap();
        assert_eq!((ob.header().version(), ob.dims()), (3, dims));
        assert_eq!(blob.dims(), dims);
        assert_eq!(blob.dims().map_cells(), 6);
        let m = blob.matrix(TensorId::CellW).unwrap();
        assert_eq!((m.rows(), m.cols()), (4, 2 * dims.feat));
        assert!(blob.check_dims(&SMALL).is_err(), "map dims are checked");
    }
    // The same tensors without the map dims: the encoder refuses the per-cell layer.
    let mut out = vec![0u8; 1 << 20];
    let specs: Vec<TensorSpec<'_>> = tensors
        .iter()
        .map(|(id, v)| TensorSpec {
            id: *id,
            data: TensorData::F32(v),
        })
        .collect();
    assert!(matches!(
        gman_core::blob::encode(&SMALL, &specs, &mut out),
        Err(BlobError::BadTensorShape { .. }) | Err(BlobError::UnknownTensor { .. })
    ));
    // Truncations and single-byte corruptions of a v3 blob are typed errors, never panics.
    let bytes = make_blob(&dims, &tensors, true);
    for n in 0..bytes.len().min(200) {
        assert!(Blob::parse(&bytes[..n]).is_err());
    }
}

/// The one seeded-weights builder writes, byte for byte, the blobs the six hand-written
/// builders it replaced wrote: length and CRC-32 of the whole blob, pinned from the code
/// before the schema refactor (N(0, 0.05) weights, seed 1, `FLAG_ADAPT`, paper settings).
#[test]
fn seeded_builder_bytes_are_pinned() {
    use gman_core::blob::{encode_model_scratch_len, encoded_model_len_bound};
    for (d, int8, len, crc) in [
        (Dims::MCU, false, 1_291_718, 0x3909_b8dd),
        (Dims::MCU, true, 332_202, 0xde6c_960a),
        (Dims::PAPER, false, 23_650_521, 0x7cea_f01d),
        (Dims::PAPER, true, 5_978_364, 0x8b28_d7e6),
        (Dims::MCU.with_map(3, 3, 8), false, 1_342_968, 0xcdfa_e770),
        (Dims::MCU.with_map(3, 3, 8), true, 345_083, 0x843e_b694),
    ] {
        let quant = if int8 { Quant::I8 } else { Quant::F32 };
        let mut out = vec![0u8; encoded_model_len_bound(&d, quant)];
        let (nf, nb) = encode_model_scratch_len(&d);
        let n = gman_core::blob::seeded::encode_seeded(
            &d,
            FLAG_ADAPT,
            AdaptSettings::PAPER,
            quant,
            1,
            0.05,
            &mut out,
            &mut vec![0.0; nf],
            &mut vec![0; nb],
        )
        .unwrap();
        out.truncate(n);
        // Pinned in format v2/v3 (the layout they were written in): the v4 blob differs only
        // in its header, so its legacy rewrite must give the same bytes.
        let out = legacy(&out);
        assert_eq!(
            (out.len(), gman_core::blob::crc32::crc32(&out)),
            (len, crc),
            "{d:?} int8={int8}"
        );
    }
}

/// [`common::seeded_blob`] (the builder) equals encoding the spec list of
/// [`common::random_tensors`] by hand, for f32 and int8, with and without a map.
#[test]
fn seeded_builder_equals_the_spec_list_encoder() {
    for d in [SMALL, SMALL.with_map(2, 3, 4)] {
        for int8 in [false, true] {
            let by_hand = make_blob(&d, &random_tensors(&d, 9), int8);
            assert_eq!(seeded_blob(&d, 9, int8, 0), by_hand, "{d:?} int8={int8}");
        }
    }
}

/// Format v4: the CRC covers the header. Every single-bit flip anywhere in the header of a
/// v4 blob (flags, rates, the inner cap, the map's rows and cols, ...) is refused; in a v3
/// blob the same flip of α2's exponent went unnoticed (the CRC covered the payload only).
#[test]
fn v4_checksum_covers_every_header_bit() {
    let dims = SMALL.with_map(3, 3, 2);
    let v5 = make_blob(&dims, &random_tensors(&dims, 31), true);
    let bytes = as_v4(&v5);
    for (bytes, version) in [(&bytes, 4), (&v5, 5)] {
        let blob = Blob::parse(bytes).unwrap();
        assert_eq!(blob.header().version(), version);
        assert_eq!(
            blob.header().checksum_scope(),
            ChecksumScope::HeaderAndPayload
        );
        let hlen = bytes.len() - blob.header().payload_len() as usize;
        for byte in 0..hlen {
            for bit in 0..8 {
                let mut m = bytes.clone();
                m[byte] ^= 1 << bit;
                assert!(
                    Blob::parse(&m).is_err(),
                    "v{version}: header byte {byte} bit {bit} flipped and the blob still parsed"
                );
            }
        }
    }
    // The v3 rule: a flipped exponent bit of α2 (0.01 -> huge) is caught only by the rate
    // bound; a flipped flag bit is not caught at all (documented: v1-v3 cover the payload).
    let old = legacy(&bytes);
    let ob = Blob::parse(&old).unwrap();
    assert_eq!(ob.header().checksum_scope(), ChecksumScope::Payload);
    let mut at = 4;
    for _ in 0..(1 + 8 + 3) {
        read_varint(&old, &mut at);
    }
    let mut flag = old.clone();
    flag[at] ^= 1; // FLAG_ADAPT
    assert!(Blob::parse(&flag).is_ok());
    read_varint(&old, &mut at);
    let mut a2 = old.clone();
    a2[at + 4..at + 8].copy_from_slice(&0.01f32.to_le_bytes());
    a2[at + 7] ^= 0x40;
    assert!(matches!(
        Blob::parse(&a2),
        Err(BlobError::BadInnerRate {
            field: "alpha_adapt",
            ..
        })
    ));
}

/// Every model shipped in `host-sim/models/` parses by its own format's rule: the ones
/// written before v4 (v2/v3) by the payload-only checksum, the v4 ones by the whole blob's.
#[test]
fn shipped_models_still_parse_by_their_own_rule() {
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../host-sim/models");
    let (mut old, mut v4) = (0, 0);
    for e in std::fs::read_dir(&dir).unwrap() {
        let p = e.unwrap().path();
        if p.extension().is_some_and(|x| x == "gman") {
            let bytes = std::fs::read(&p).unwrap();
            let b = Blob::parse(&bytes).unwrap_or_else(|e| panic!("{}: {e}", p.display()));
            let (version, scope) = (b.header().version(), b.header().checksum_scope());
            if version <= 3 {
                assert_eq!(scope, ChecksumScope::Payload, "{}", p.display());
                old += 1;
            } else {
                assert!(matches!(version, 4 | 5), "{}", p.display());
                assert_eq!(scope, ChecksumScope::HeaderAndPayload, "{}", p.display());
                v4 += 1;
            }
        }
    }
    assert!(old > 0, "no pre-v4 model found in {}", dir.display());
    assert!(v4 > 0, "no v4 model found in {}", dir.display());
}

/// `v4` with its flags replaced by `flags` and the checksum recomputed (a header written on
/// purpose, e.g. by a newer build).
fn v4_with_raw_flags(v4: &[u8], flags: u32) -> Vec<u8> {
    let b = Blob::parse(v4).unwrap();
    let (pl, crc) = (b.header().payload_len() as usize, b.header().payload_crc());
    let mut at = 5; // magic, version 4
    for _ in 0..11 {
        read_varint(v4, &mut at); // dims, map
    }
    let start = at;
    read_varint(v4, &mut at);
    let mut edited = v4[..start].to_vec();
    edited.extend(varint_bytes(flags.into()));
    edited.extend_from_slice(&v4[at..]);
    reseal(&edited, pl, crc)
}

/// Unknown flag bits (4-7, 22, 31) in a v4 blob are a typed error naming the bit, also with
/// a valid checksum; the encoder refuses them; a v1-v3 blob's unknown bits are ignored as
/// before; every known bit parses.
#[test]
fn unknown_flag_bits_in_a_v4_blob_are_refused_naming_the_bit() {
    use gman_core::spec::schema::KNOWN_FLAGS;
    let v4 = blob_v4_with(FLAG_ADAPT, AdaptSettings::PAPER, 3);
    assert_eq!(KNOWN_FLAGS, !(0xF0 | 1 << 22 | 1 << 31));
    for bit in [4u8, 5, 6, 7, 22, 31] {
        let flags = FLAG_ADAPT | 1 << bit;
        let e = Blob::parse(&v4_with_raw_flags(&v4, flags)).unwrap_err();
        assert_eq!(e, BlobError::UnknownFlagBit { bit, flags });
        assert!(
            e.to_string()
                .contains(&format!("unknown model flag bit {bit}")),
            "{e}"
        );
        let t = random_tensors(&SMALL, 3);
        let specs = f32_specs(&t);
        let mut out = vec![0u8; encoded_len_bound(&specs)];
        assert_eq!(
            encode_with_settings(&SMALL, flags, AdaptSettings::PAPER, &specs, &mut out),
            Err(BlobError::UnknownFlagBit { bit, flags })
        );
    }
    // Several: the lowest is named.
    let flags = 1 << 31 | 1 << 22 | 1 << 5;
    assert_eq!(
        Blob::parse(&v4_with_raw_flags(&v4, flags)).unwrap_err(),
        BlobError::UnknownFlagBit { bit: 5, flags }
    );
    assert!(Blob::parse(&v4_with_raw_flags(&v4, KNOWN_FLAGS)).is_ok());
    // The older formats: read as they always were.
    let old = legacy(&v4);
    let mut at = 5;
    for _ in 0..8 {
        read_varint(&old, &mut at);
    }
    let start = at;
    read_varint(&old, &mut at);
    let mut edited = old[..start].to_vec();
    edited.extend(varint_bytes((FLAG_ADAPT | 1 << 22).into()));
    edited.extend_from_slice(&old[at..]);
    let b = Blob::parse(&edited).unwrap();
    assert_eq!(b.header().flags(), FLAG_ADAPT | 1 << 22);
}

/// A format-v5 blob with the dims and payload of `blob` and the setting records `records`
/// (each already encoded), written by hand with a valid checksum: it can hold what the
/// encoder never writes (an unknown key, a wrong type, an unknown name, a repeated key).
fn v5_with_records(blob: &[u8], records: &[Vec<u8>]) -> Vec<u8> {
    let h = *Blob::parse(blob).unwrap().header();
    let d = h.dims();
    let mut out = MAGIC.to_vec();
    out.extend(varint_bytes(5));
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
        out.extend(varint_bytes(v as u64));
    }
    out.extend(varint_bytes(
        records.iter().map(Vec::len).sum::<usize>() as u64
    ));
    for r in records {
        out.extend_from_slice(r);
    }
    out.extend(varint_bytes(h.n_tensors().into()));
    out.extend(varint_bytes(h.payload_len().into()));
    let payload = &blob[blob.len() - h.payload_len() as usize..];
    let crc = gman_core::blob::crc32::crc32_update(gman_core::blob::crc32::crc32(&out), payload);
    out.extend(varint_bytes(crc.into()));
    out.extend_from_slice(payload);
    out
}

/// One v5 setting record: the key, the value's type tag (0 u32, 1 f32, 2 name, 3 bool) and
/// the value's bytes.
fn record(key: &str, tag: u64, value: &[u8]) -> Vec<u8> {
    let mut r = varint_bytes(key.len() as u64);
    r.extend_from_slice(key.as_bytes());
    r.extend(varint_bytes(tag));
    r.extend_from_slice(value);
    r
}

/// A name value's bytes (length, then the name).
fn name_bytes(s: &str) -> Vec<u8> {
    let mut r = varint_bytes(s.len() as u64);
    r.extend_from_slice(s.as_bytes());
    r
}

/// Format v5 names every setting: the encoder's records round-trip every field of the
/// carrier, the v4 bit form of the same settings gives
/// the same navigator configuration, and a record this build does not understand (an
/// unknown key, a value of another type, an unknown name, a repeated key, a count out of
/// range) is a typed error naming it, with a valid checksum.
#[test]
fn v5_names_its_settings_and_refuses_what_it_does_not_know() {
    use gman_core::spec::{ModelSpec, SETTING_KEYS};
    let spec = ModelSpec::EVERY_SETTING_CHANGED;
    let t = random_tensors(&SMALL, 8);
    let specs = f32_specs(&t);
    let mut out = vec![0u8; encoded_len_bound(&specs)];
    let n = gman_core::blob::encode_spec(&SMALL, &spec, &specs, &mut out).unwrap();
    let v5 = out[..n].to_vec();
    let h = *Blob::parse(&v5).unwrap().header();
    assert_eq!((h.version(), h.spec()), (5, spec));
    // Every key is written, by name, in the header.
    let hlen = v5.len() - h.payload_len() as usize;
    for key in SETTING_KEYS {
        let found = v5[..hlen].windows(key.len()).any(|w| w == key.as_bytes());
        assert!(found, "{key} not named in the header");
    }
    let v4 = as_v4(&v5);
    let h4 = *Blob::parse(&v4).unwrap().header();
    assert_eq!(h4.flags(), h.flags());
    assert_eq!(NavConfig::from_header(&h4), NavConfig::from_header(&h));
    // No record: the documented defaults, which the encoder leaves out.
    let empty = v5_with_records(&v5, &[]);
    let empty = Blob::parse(&empty).unwrap();
    assert_eq!(empty.header().spec(), ModelSpec::BLOB_DEFAULT);
    let n = gman_core::blob::encode(&SMALL, &specs, &mut out).unwrap();
    assert_eq!(out[..n], v5_with_records(&v5, &[])[..]);
    let mut one = ModelSpec::BLOB_DEFAULT;
    one.inner_rule.commit_delay = 7;
    let n = gman_core::blob::encode_spec(&SMALL, &one, &specs, &mut out).unwrap();
    let seven = record("commit_delay", 0, &varint_bytes(7));
    assert_eq!(out[..n], v5_with_records(&v5, &[seven])[..]);
    let ok = record("commit_delay", 0, &varint_bytes(7));
    assert_eq!(
        Blob::parse(&v5_with_records(&v5, std::slice::from_ref(&ok)))
            .unwrap()
            .header()
            .spec()
            .inner_rule
            .commit_delay,
        7
    );
    let refused = |records: &[Vec<u8>]| Blob::parse(&v5_with_records(&v5, records)).unwrap_err();
    let key = |k: &str| gman_core::spec::SettingKey::named(k).unwrap();
    let e = refused(&[ok.clone(), record("warp_factor", 0, &varint_bytes(3))]);
    assert!(matches!(e, BlobError::UnknownSetting { key } if key.as_str() == "warp_factor"));
    assert_eq!(
        e.to_string(),
        "unknown model setting `warp_factor` (a setting of a newer build)"
    );
    let e = refused(&[record("step_rule", 2, &name_bytes("sideways"))]);
    assert!(
        matches!(e, BlobError::UnknownSettingValue { key, value } if key.as_str() == "step_rule" && value.as_str() == "sideways")
    );
    assert!(e.to_string().contains("`step_rule`") && e.to_string().contains("`sideways`"));
    assert_eq!(
        refused(&[record("commit_delay", 2, &name_bytes("soon"))]),
        BlobError::SettingType {
            key: key("commit_delay"),
            expected: "u32"
        }
    );
    assert_eq!(
        refused(&[record("commit_delay", 0, &varint_bytes(64))]),
        BlobError::SettingOutOfRange {
            key: key("commit_delay"),
            value: 64
        }
    );
    assert_eq!(
        refused(&[ok.clone(), ok]),
        BlobError::DuplicateSetting {
            key: key("commit_delay")
        }
    );
    let long = "a_setting_with_a_very_long_name_indeed";
    let e = refused(&[record(long, 3, &[1])]);
    assert!(e.to_string().contains("`a_setting_with_...`"), "{e}");
    // An unknown value type is a decoding error.
    assert_eq!(refused(&[record("adapt", 9, &[1])]), BlobError::Malformed);
}
