//! The C API under hostile input: null pointers, short and misaligned buffers, NaN
//! observations, corrupt and random blobs, dead handles. Every call must return a status
//! (never crash, never report success for bad input), and two navigators in one process
//! must not disturb each other.

use std::ffi::CStr;
use std::ptr::{null, null_mut};

use gman_ffi::*;
use proptest::prelude::*;

fn model() -> Vec<u8> {
    let p = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../host-sim/models/gman-map3-b16-mcu-int8-seed5.gman"
    );
    std::fs::read(p).expect("shipped model")
}

fn info(blob: &[u8]) -> gman_info {
    let mut i = gman_info::default();
    assert_eq!(
        unsafe { gman_inspect(blob.as_ptr(), blob.len(), &mut i) },
        GMAN_OK
    );
    i
}

/// A navigator in a fresh arena (boxed: stays put while the handle is used).
struct Nav {
    _arena: Vec<u8>,
    h: *mut gman_nav,
}

fn nav(blob: &[u8], offset: usize) -> Nav {
    let i = info(blob);
    let mut arena = vec![0u8; i.arena_bytes as usize + offset];
    let mut h = null_mut();
    let s = unsafe {
        gman_init(
            blob.as_ptr(),
            blob.len(),
            arena.as_mut_ptr().add(offset).cast(),
            i.arena_bytes as usize,
            null(),
            &mut h,
        )
    };
    assert_eq!(s, GMAN_OK);
    Nav { _arena: arena, h }
}

fn obs_for(i: &gman_info, v: f32) -> (Vec<f32>, Vec<f32>) {
    (vec![v; i.feat as usize], vec![v; i.map_len as usize])
}

fn step(n: &Nav, i: &gman_info, obs: &[f32], map: &[f32]) -> (gman_status, gman_step_out) {
    let mut o = gman_step_out::default();
    let s = unsafe {
        gman_step(
            n.h,
            obs.as_ptr(),
            obs.len(),
            map.as_ptr(),
            map.len(),
            null(),
            0,
            &mut o,
        )
    };
    let _ = i;
    (s, o)
}

#[test]
fn status_strings_are_static_and_distinct() {
    let mut seen = std::collections::HashSet::new();
    // The codes are stable: appended, never renumbered.
    assert_eq!(
        (GMAN_ERR_PANIC, GMAN_ERR_UPDATE_NOT_READY, GMAN_ERR_OVERLAP),
        (12, 13, 14)
    );
    for s in 0..=GMAN_ERR_OVERLAP {
        let t = unsafe { CStr::from_ptr(gman_status_str(s)) }
            .to_str()
            .unwrap();
        assert!(!t.is_empty() && seen.insert(t.to_string()), "{s}: {t}");
    }
    for s in [-7, GMAN_ERR_OVERLAP + 1] {
        let t = unsafe { CStr::from_ptr(gman_status_str(s)) };
        assert_eq!(t.to_str().unwrap(), "unknown status code");
    }
    let t = unsafe { CStr::from_ptr(gman_status_str(-7)) };
    assert_eq!(t.to_str().unwrap(), "unknown status code");
}

#[test]
fn arena_constants_match_the_library() {
    let blob = model();
    let mut n = 0usize;
    assert_eq!(
        unsafe { gman_arena_size(blob.as_ptr(), blob.len(), &mut n) },
        GMAN_OK
    );
    assert_eq!(n, GMAN_ARENA_BYTES_MCU_MAP3X3);
    assert_eq!(info(&blob).arena_bytes as usize, n);
    // The table in docs/integrate.md.
    use gman_core::{arena_len, AdaptMode, Dims};
    for (d, floats, bytes) in [
        (Dims::MCU, 37_111, GMAN_ARENA_BYTES_MCU),
        (
            Dims::MCU.with_map(3, 3, 8),
            37_703,
            GMAN_ARENA_BYTES_MCU_MAP3X3,
        ),
        (Dims::PAPER, 131_063, GMAN_ARENA_BYTES_PAPER),
    ] {
        assert_eq!(
            arena_len(&d, AdaptMode::Efficient, GMAN_BUFFER_CAPACITY),
            floats
        );
        assert_eq!(GMAN_ARENA_ALIGN + GMAN_HANDLE_BYTES + 4 * floats, bytes);
    }
}

#[test]
fn null_pointers_are_reported() {
    let blob = model();
    let mut i = gman_info::default();
    let mut n = 0usize;
    let mut h = null_mut();
    unsafe {
        assert_eq!(gman_inspect(null(), 10, &mut i), GMAN_ERR_NULL);
        assert_eq!(
            gman_inspect(blob.as_ptr(), blob.len(), null_mut()),
            GMAN_ERR_NULL
        );
        assert_eq!(gman_arena_size(null(), 0, &mut n), GMAN_ERR_NULL);
        assert_eq!(
            gman_arena_size(blob.as_ptr(), blob.len(), null_mut()),
            GMAN_ERR_NULL
        );
        assert_eq!(
            gman_init(
                blob.as_ptr(),
                blob.len(),
                null_mut(),
                1 << 20,
                null(),
                &mut h
            ),
            GMAN_ERR_NULL
        );
        assert_eq!(gman_reset(null_mut(), null(), 0, 0), GMAN_ERR_NULL);
        assert_eq!(
            gman_step(null_mut(), null(), 0, null(), 0, null(), 0, null_mut()),
            GMAN_ERR_NULL
        );
        assert_eq!(gman_adapt_now(null_mut(), null_mut()), GMAN_ERR_NULL);
        assert_eq!(gman_get_counters(null_mut(), null_mut()), GMAN_ERR_NULL);
        assert_eq!(gman_last_adaptation(null_mut(), null_mut()), GMAN_ERR_NULL);
        assert_eq!(gman_crc32(0, null(), 5), 0);
        assert!(!gman_last_error(null_mut()).is_null());
    }
    let n = nav(&blob, 0);
    let i = info(&blob);
    let attr = vec![0.5f32; i.attr as usize];
    unsafe {
        assert_eq!(gman_reset(n.h, null(), i.attr as usize, 1), GMAN_ERR_NULL);
        assert_eq!(gman_reset(n.h, attr.as_ptr(), attr.len(), 1), GMAN_OK);
        let (obs, map) = obs_for(&i, 0.5);
        assert_eq!(
            gman_step(
                n.h,
                obs.as_ptr(),
                obs.len(),
                map.as_ptr(),
                map.len(),
                null(),
                0,
                null_mut()
            ),
            GMAN_ERR_NULL
        );
        assert_eq!(
            gman_step(
                n.h,
                null(),
                obs.len(),
                map.as_ptr(),
                map.len(),
                null(),
                0,
                &mut gman_step_out::default()
            ),
            GMAN_ERR_NULL
        );
    }
}

#[test]
fn order_shape_nan_alignment_and_dead_handles() {
    let blob = model();
    let i = info(&blob);
    let n = nav(&blob, 3);
    let (obs, map) = obs_for(&i, 0.5);
    // A step before the first reset is out of order.
    assert_eq!(step(&n, &i, &obs, &map).0, GMAN_ERR_CONFIG);
    let msg = unsafe { CStr::from_ptr(gman_last_error(n.h)) }
        .to_str()
        .unwrap();
    assert!(msg.contains("reset"), "{msg}");
    let attr = vec![0.5f32; i.attr as usize];
    assert_eq!(
        unsafe { gman_reset(n.h, attr.as_ptr(), attr.len() - 1, 1) },
        GMAN_ERR_SHAPE
    );
    let mut bad = attr.clone();
    bad[3] = f32::NAN;
    assert_eq!(
        unsafe { gman_reset(n.h, bad.as_ptr(), bad.len(), 1) },
        GMAN_ERR_NON_FINITE
    );
    assert_eq!(
        unsafe { gman_reset(n.h, attr.as_ptr(), attr.len(), 1) },
        GMAN_OK
    );
    // Short observation, short map, NaN, infinity, misaligned floats.
    assert_eq!(step(&n, &i, &obs[1..], &map).0, GMAN_ERR_SHAPE);
    assert_eq!(step(&n, &i, &obs, &map[1..]).0, GMAN_ERR_SHAPE);
    let mut nan = obs.clone();
    nan[7] = f32::NAN;
    assert_eq!(step(&n, &i, &nan, &map).0, GMAN_ERR_NON_FINITE);
    let mut inf = map.clone();
    inf[100] = f32::INFINITY;
    assert_eq!(step(&n, &i, &obs, &inf).0, GMAN_ERR_NON_FINITE);
    let bytes = vec![0u8; 4 * obs.len() + 4];
    let mis = unsafe { bytes.as_ptr().add(1) } as *const f32;
    let mut o = gman_step_out::default();
    assert_eq!(
        unsafe {
            gman_step(
                n.h,
                mis,
                obs.len(),
                map.as_ptr(),
                map.len(),
                null(),
                0,
                &mut o,
            )
        },
        GMAN_ERR_ALIGNMENT
    );
    // After every refusal the navigator still steps.
    let (s, o) = step(&n, &i, &obs, &map);
    assert_eq!(s, GMAN_OK);
    assert!(o.action < 6 && o.probs.iter().all(|p| p.is_finite()));
    // Dead handles: an arena that was never initialised, or whose handle was overwritten.
    let mut zeros = vec![0u64; 1024];
    let h = zeros.as_mut_ptr() as *mut gman_nav;
    assert_eq!(
        step(&Nav { _arena: vec![], h }, &i, &obs, &map).0,
        GMAN_ERR_BAD_HANDLE
    );
    let odd = unsafe { (n.h as *mut u8).add(1) } as *mut gman_nav;
    assert_eq!(
        unsafe { gman_adapt_now(odd, null_mut()) },
        GMAN_ERR_BAD_HANDLE
    );
    // Unknown options are refused.
    let mut arena = vec![0u8; i.arena_bytes as usize];
    let mut h = null_mut();
    let opts = gman_options {
        selection: 7,
        schedule: 0,
        require_header_crc: 0,
        settings: gman_settings::default(),
    };
    let s = unsafe {
        gman_init(
            blob.as_ptr(),
            blob.len(),
            arena.as_mut_ptr().cast(),
            arena.len(),
            &opts,
            &mut h,
        )
    };
    assert_eq!(s, GMAN_ERR_CONFIG);
    assert!(h.is_null());
    let delayed = gman_options {
        selection: 0,
        schedule: 0,
        require_header_crc: 0,
        settings: gman_settings {
            commit_delay: 64,
            ..gman_settings::default()
        },
    };
    let s = unsafe {
        gman_init(
            blob.as_ptr(),
            blob.len(),
            arena.as_mut_ptr().cast(),
            arena.len(),
            &delayed,
            &mut h,
        )
    };
    assert_eq!(s, GMAN_ERR_CONFIG);
    // A short arena.
    let s = unsafe {
        gman_init(
            blob.as_ptr(),
            blob.len(),
            arena.as_mut_ptr().cast(),
            arena.len() - 1,
            null(),
            &mut h,
        )
    };
    assert_eq!(s, GMAN_ERR_ARENA_TOO_SMALL);
}

#[test]
fn corrupt_blobs_name_their_fault() {
    let blob = model();
    let mut i = gman_info::default();
    let mut c = blob.clone();
    let last = c.len() - 1;
    c[last] ^= 0x55;
    assert_eq!(
        unsafe { gman_inspect(c.as_ptr(), c.len(), &mut i) },
        GMAN_ERR_BLOB_CRC
    );
    let mut v = blob.clone();
    v[4] = 0xEE; // the version's low byte
    v[5] = 0x7F;
    let s = unsafe { gman_inspect(v.as_ptr(), v.len(), &mut i) };
    assert_eq!(s, GMAN_ERR_BLOB_VERSION);
    for cut in [0, 3, 16, 100, blob.len() / 2, blob.len() - 1] {
        let s = unsafe { gman_inspect(blob.as_ptr(), cut, &mut i) };
        assert_ne!(s, GMAN_OK, "a blob cut at {cut} bytes was accepted");
    }
}

#[test]
fn two_navigators_in_one_process_are_independent() {
    let blob = model();
    let i = info(&blob);
    let (a, b, solo) = (nav(&blob, 0), nav(&blob, 5), nav(&blob, 9));
    let attr = vec![0.25f32; i.attr as usize];
    let other = vec![0.75f32; i.attr as usize];
    unsafe {
        assert_eq!(gman_reset(a.h, attr.as_ptr(), attr.len(), 42), GMAN_OK);
        assert_eq!(gman_reset(b.h, other.as_ptr(), other.len(), 7), GMAN_OK);
        assert_eq!(gman_reset(solo.h, attr.as_ptr(), attr.len(), 42), GMAN_OK);
    }
    // `a` and `b` interleaved (b with other inputs), `solo` alone: a == solo bit for bit.
    for t in 0..45 {
        let v = (t % 7) as f32 / 7.0;
        let (obs, map) = obs_for(&i, v);
        let (obs2, map2) = obs_for(&i, 1.0 - v);
        let (sa, oa) = step(&a, &i, &obs, &map);
        let (sb, _) = step(&b, &i, &obs2, &map2);
        let (ss, os) = step(&solo, &i, &obs, &map);
        assert_eq!((sa, sb, ss), (GMAN_OK, GMAN_OK, GMAN_OK));
        assert_eq!(
            oa.probs.map(f32::to_bits),
            os.probs.map(f32::to_bits),
            "step {t}"
        );
        assert_eq!(oa.adapted, os.adapted);
    }
    let mut ca = gman_counters::default();
    unsafe { gman_get_counters(a.h, &mut ca) };
    assert_eq!(ca.steps, 45);
    assert_eq!(ca.adaptations, 2);
}

#[test]
fn manual_schedule_runs_the_update_only_on_request() {
    let blob = model();
    let i = info(&blob);
    let mut arena = vec![0u8; i.arena_bytes as usize];
    let mut h = null_mut();
    let opts = gman_options {
        selection: 0,
        schedule: 1,
        require_header_crc: 0,
        settings: gman_settings::default(),
    };
    let s = unsafe {
        gman_init(
            blob.as_ptr(),
            blob.len(),
            arena.as_mut_ptr().cast(),
            arena.len(),
            &opts,
            &mut h,
        )
    };
    assert_eq!(s, GMAN_OK);
    let n = Nav { _arena: vec![], h };
    let attr = vec![0.5f32; i.attr as usize];
    unsafe { gman_reset(n.h, attr.as_ptr(), attr.len(), 3) };
    let (obs, map) = obs_for(&i, 0.3);
    for _ in 0..GMAN_BUFFER_CAPACITY {
        let (s, o) = step(&n, &i, &obs, &map);
        assert_eq!((s, o.adapted), (GMAN_OK, 0));
    }
    // Ψ is full: the step refuses until the caller runs the update.
    assert_eq!(step(&n, &i, &obs, &map).0, GMAN_ERR_CONFIG);
    let mut buffered = 0;
    unsafe { gman_buffered(n.h, &mut buffered) };
    assert_eq!(buffered as usize, GMAN_BUFFER_CAPACITY);
    let mut ran = 0;
    assert_eq!(unsafe { gman_adapt_now(n.h, &mut ran) }, GMAN_OK);
    assert_eq!(ran, 1);
    let mut r = gman_adapt_report::default();
    unsafe { gman_last_adaptation(n.h, &mut r) };
    assert!(r.ld_loss != 0.0 && r.disc_applied == 1);
    assert_eq!(step(&n, &i, &obs, &map).0, GMAN_OK);
    drop(arena);
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 256, ..ProptestConfig::default() })]

    /// Random bytes as a blob (also behind a valid magic) are refused with a status.
    #[test]
    fn random_bytes_are_not_a_blob(mut bytes in proptest::collection::vec(any::<u8>(), 0..4096), magic in any::<bool>()) {
        if magic && bytes.len() >= 4 {
            bytes[..4].copy_from_slice(b"GMAN");
        }
        let mut i = gman_info::default();
        let s = unsafe { gman_inspect(bytes.as_ptr(), bytes.len(), &mut i) };
        prop_assert_ne!(s, GMAN_OK);
        let mut arena = vec![0u8; 8192];
        let mut h = null_mut();
        let s = unsafe { gman_init(bytes.as_ptr(), bytes.len(), arena.as_mut_ptr().cast(), arena.len(), null(), &mut h) };
        prop_assert_ne!(s, GMAN_OK);
        prop_assert!(h.is_null());
    }

    /// The shipped blob with a few bytes flipped: refused (CRC or structure) or, if the
    /// flip is in a part the CRC does not cover and still valid, a navigator that steps
    /// without crashing.
    #[test]
    fn flipped_blob_bytes_never_crash(flips in proptest::collection::vec((any::<prop::sample::Index>(), 1u8..=255), 1..4)) {
        let mut blob = model();
        for (at, x) in &flips {
            let k = at.index(blob.len());
            blob[k] ^= x;
        }
        let mut i = gman_info::default();
        if unsafe { gman_inspect(blob.as_ptr(), blob.len(), &mut i) } == GMAN_OK {
            let mut arena = vec![0u8; i.arena_bytes as usize];
            let mut h = null_mut();
            let s = unsafe { gman_init(blob.as_ptr(), blob.len(), arena.as_mut_ptr().cast(), arena.len(), null(), &mut h) };
            if s == GMAN_OK {
                let n = Nav { _arena: vec![], h };
                let attr = vec![0.5f32; i.attr as usize];
                unsafe { gman_reset(n.h, attr.as_ptr(), attr.len(), 1) };
                let (obs, map) = obs_for(&i, 0.5);
                let _ = step(&n, &i, &obs, &map);
            }
        }
    }

    /// Observations of any bits (NaN, infinities, subnormals, huge values) and any lengths:
    /// a status, never a crash; success only with the right lengths and finite values.
    #[test]
    fn any_observation_bits(bits in proptest::collection::vec(any::<u32>(), 0..6000), cut in 0usize..3) {
        let blob = model();
        let i = info(&blob);
        let n = nav(&blob, 1);
        let attr = vec![0.5f32; i.attr as usize];
        unsafe { gman_reset(n.h, attr.as_ptr(), attr.len(), 9) };
        let mut all: Vec<f32> = bits.iter().map(|b| f32::from_bits(*b)).collect();
        all.resize(i.feat as usize + i.map_len as usize, 0.5);
        let (obs, map) = all.split_at(i.feat as usize);
        let obs = &obs[..obs.len() - cut];
        let (s, o) = step(&n, &i, obs, map);
        if s == GMAN_OK {
            prop_assert!(cut == 0 && all.iter().all(|v| v.is_finite()));
            prop_assert!(o.action < 6);
        } else {
            prop_assert!(cut > 0 || !all.iter().all(|v| v.is_finite()) || s == GMAN_ERR_NUMERICAL, "status {}", s);
        }
    }
}

/// The blob needs no alignment: one byte off gives the same bits.
#[test]
fn a_misaligned_blob_gives_the_same_bits() {
    let blob = model();
    let mut shifted = vec![0u8; blob.len() + 1];
    shifted[1..].copy_from_slice(&blob);
    let off = &shifted[1..];
    let i = info(&blob);
    let (a, b) = (nav(&blob, 0), nav(off, 0));
    let attr = vec![0.5f32; i.attr as usize];
    unsafe {
        assert_eq!(gman_reset(a.h, attr.as_ptr(), attr.len(), 11), GMAN_OK);
        assert_eq!(gman_reset(b.h, attr.as_ptr(), attr.len(), 11), GMAN_OK);
    }
    for t in 0..22 {
        let (obs, map) = obs_for(&i, (t % 5) as f32 / 5.0);
        let (sa, oa) = step(&a, &i, &obs, &map);
        let (sb, ob) = step(&b, &i, &obs, &map);
        assert_eq!((sa, sb), (GMAN_OK, GMAN_OK));
        assert_eq!(oa.probs.map(f32::to_bits), ob.probs.map(f32::to_bits));
    }
}
