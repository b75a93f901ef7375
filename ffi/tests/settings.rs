//! `gman_blob_setting`: every setting a blob records, listed by key through the C API, agrees
//! with gman-core's reading of the same blob; keys and names fit the C struct; bad input is
//! refused.

use std::ffi::CStr;
use std::ptr::{null, null_mut};

use gman_core::spec::schema::{AdaptLossKind, AdaptMode, Emd, NoiseMode, StepRule};
use gman_core::spec::{SettingValue, SETTING_KEYS};
use gman_core::Blob;
use gman_ffi::*;

fn shipped(name: &str) -> Vec<u8> {
    let p = format!("{}/../host-sim/models/{name}", env!("CARGO_MANIFEST_DIR"));
    std::fs::read(&p).unwrap_or_else(|e| panic!("{p}: {e}"))
}

fn text(t: &[std::ffi::c_char]) -> String {
    let bytes: Vec<u8> = t.iter().map(|&c| c as u8).collect();
    CStr::from_bytes_until_nul(&bytes)
        .expect("NUL-terminated")
        .to_str()
        .unwrap()
        .to_string()
}

/// Every setting of `blob` through the C API, until the empty key.
fn list(blob: &[u8]) -> Vec<gman_setting> {
    let mut all = Vec::new();
    for i in 0.. {
        let mut s = gman_setting::default();
        let st = unsafe { gman_blob_setting(blob.as_ptr(), blob.len(), i, &mut s) };
        assert_eq!(st, GMAN_OK, "setting {i}");
        if s.key[0] == 0 {
            break;
        }
        all.push(s);
        assert!(i < 1000, "the list does not end");
    }
    all
}

#[test]
fn every_setting_of_shipped_blobs_agrees_with_the_core() {
    let models = std::fs::read_dir(concat!(env!("CARGO_MANIFEST_DIR"), "/../host-sim/models"))
        .unwrap()
        .map(|e| e.unwrap().file_name().into_string().unwrap())
        .filter(|n| n.ends_with(".gman"))
        .collect::<Vec<_>>();
    assert!(models.len() >= 2);
    for name in models {
        let blob = shipped(&name);
        let spec = Blob::parse(&blob).unwrap().header().spec();
        let got = list(&blob);
        assert_eq!(got.len(), SETTING_KEYS.len(), "{name}");
        for (s, key) in got.iter().zip(SETTING_KEYS) {
            assert_eq!(text(&s.key), key, "{name}");
            match spec.get(key) {
                Some(SettingValue::U32(n)) => assert_eq!((s.kind, s.count), (0, n), "{name} {key}"),
                Some(SettingValue::F32(a)) => {
                    assert_eq!((s.kind, s.rate.to_bits()), (1, a.to_bits()), "{name} {key}")
                }
                Some(SettingValue::Name(n)) => {
                    assert_eq!((s.kind, text(&s.name)), (2, n.to_string()), "{name} {key}")
                }
                Some(SettingValue::Bool(b)) => {
                    assert_eq!((s.kind, s.count), (3, u32::from(b)), "{name} {key}")
                }
                None => assert_eq!(s.kind, 4, "{name} {key}"),
            }
        }
    }
}

#[test]
fn every_key_and_name_fits_the_c_struct() {
    let names = [Emd::NAME_LIST, NoiseMode::NAME_LIST, AdaptMode::NAME_LIST]
        .into_iter()
        .chain([StepRule::NAME_LIST, AdaptLossKind::NAME_LIST]);
    for n in SETTING_KEYS.iter().chain(names.flatten()) {
        assert!(
            n.len() < GMAN_SETTING_TEXT,
            "{n} does not fit {GMAN_SETTING_TEXT} bytes"
        );
    }
}

#[test]
fn bad_input_is_refused() {
    let blob = shipped("gman-map3-b16-mcu-int8-seed5.gman");
    let mut s = gman_setting::default();
    let st = unsafe { gman_blob_setting(blob.as_ptr(), blob.len(), 0, null_mut()) };
    assert_eq!(st, GMAN_ERR_NULL);
    let st = unsafe { gman_blob_setting(null(), blob.len(), 0, &mut s) };
    assert_eq!(st, GMAN_ERR_NULL);
    let mut bad = blob.clone();
    let last = bad.len() - 1;
    bad[last] ^= 1;
    let st = unsafe { gman_blob_setting(bad.as_ptr(), bad.len(), 0, &mut s) };
    assert_eq!(st, GMAN_ERR_BLOB_CRC);
    assert_eq!(s, gman_setting::default(), "a refused call writes nothing");
    let st = unsafe { gman_blob_setting(blob.as_ptr(), blob.len(), u32::MAX, &mut s) };
    assert_eq!(
        (st, s.key[0]),
        (GMAN_OK, 0),
        "past the last setting: an empty key"
    );
}
