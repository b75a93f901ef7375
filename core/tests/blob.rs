//! Weight-blob round trips, quantisation error bounds and typed rejection of bad blobs.

mod common;
use common::*;
use gman_core::blob::{Blob, Quant, TensorId};
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
    assert!(
        bytes.len() < f32_bytes.len() / 2,
        "int8 blob should be much smaller"
    );
    let blob = Blob::parse(&bytes).unwrap();
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
        // Documented bound (gman_core::quant): |w - w_hat| <= max|w| / 254 per tensor
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
    let mut v = bytes.clone();
    v[4] = 2; // version varint follows the 4 magic bytes
    assert_eq!(
        Blob::parse(&v).unwrap_err(),
        BlobError::UnsupportedVersion { found: 2 }
    );
    let mut c = bytes.clone();
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
        let mut changed = false;
        for (i, b) in &edits {
            let at = hlen + i.index(plen);
            changed |= m[at] != *b;
            m[at] = *b;
        }
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
        let mut with_magic = b"GMAN\x01".to_vec();
        with_magic.extend_from_slice(&data);
        let _ = Blob::parse(&with_magic);
    }
}
