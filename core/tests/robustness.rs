//! "No panic on any input" for the parts of gman-core that take sizes and call sequences from
//! the outside: the navigator driven by arbitrary call sequences (`Schedule::Manual` and
//! `Auto`, both adaptation modes, hostile observations, mutated blobs) and every size derived
//! from a blob's dims (parameter counts, tensor bytes, RAM layout), with overflow checks on
//! (the test profile keeps them).
//!
//! The number of property cases is `GMAN_PROPTEST_CASES` (default 2000, which CI runs); the
//! 1 M-case run is done by hand, without `--release` (the test profile has overflow checks
//! and `opt-level = 2`):
//! `GMAN_PROPTEST_CASES=1000000 cargo test -p gman-core --test robustness`

mod common;
use common::*;
use gman_core::blob::Blob;
use gman_core::navigator::memory::{
    arena_len, checked_int8_weight_bytes, int8_weight_bytes, try_arena_len, AdaptMode, NavLayout,
};
use gman_core::navigator::{
    Efficient, Full, Mode, NavConfig, NavWeights, Navigator, NoiseMode, Schedule, Selection,
};
use gman_core::spec::{InnerRule, ModelSpec};
use gman_core::{BlobError, Dims, Error};
use proptest::prelude::*;

/// Property cases per test: `GMAN_PROPTEST_CASES`, default 2000.
fn cases() -> u32 {
    std::env::var("GMAN_PROPTEST_CASES")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(2000)
}

/// A header-only blob (no flags) with these raw dims.
fn header_only_blob(dims: [u32; 8]) -> Vec<u8> {
    common::header_only_blob(dims.map(u64::from), 0)
}

fn dims_of(v: [u32; 8]) -> Dims {
    Dims {
        attr: v[0] as usize,
        noise: v[1] as usize,
        gen_hidden: v[2] as usize,
        feat: v[3] as usize,
        disc_hidden: v[4] as usize,
        lstm_hidden: v[5] as usize,
        embed: v[6] as usize,
        ps: v[7] as usize,
        map_rows: 0,
        map_cols: 0,
        cell_embed: 0,
    }
}

/// Every size function on `d`: never panics; the saturating forms equal the checked ones when
/// those fit and are `usize::MAX` otherwise.
fn sizes_are_consistent(d: &Dims) -> Result<(), TestCaseError> {
    sizes_consistent_one(d)?;
    // The same dims with a spatial map (a small grid, the possibly huge embed width as the
    // per-cell channels), as a v3 header can carry.
    sizes_consistent_one(&d.with_map(d.attr % 4, d.noise % 4, d.embed))
}

fn sizes_consistent_one(d: &Dims) -> Result<(), TestCaseError> {
    let pairs = [
        (d.gen_in(), d.checked_gen_in()),
        (d.fuse_in(), d.checked_fuse_in()),
        (d.gen_params(), d.checked_gen_params()),
        (d.disc_params(), d.checked_disc_params()),
        (d.policy_params(), d.checked_policy_params()),
        (d.macs_per_step(), d.checked_macs_per_step()),
        (int8_weight_bytes(d), checked_int8_weight_bytes(d)),
    ];
    for (sat, checked) in pairs {
        prop_assert_eq!(sat, checked.unwrap_or(usize::MAX));
    }
    for mode in [AdaptMode::Full, AdaptMode::Efficient] {
        for k in [1usize, 20, usize::MAX] {
            let l = NavLayout::new(d, mode, k);
            match try_arena_len(d, mode, k) {
                Some(n) => {
                    // The larger of the two noise modes' layouts (`l` is the Gaussian one).
                    let z = NavLayout::try_new_noise(
                        d,
                        mode,
                        k,
                        gman_core::navigator::memory::Footprint::Compact,
                        gman_core::spec::schema::NoiseMode::Zero,
                    );
                    let zf = z.map_or(0, |z| z.total_floats());
                    prop_assert_eq!(arena_len(d, mode, k), n);
                    prop_assert_eq!(l.total_floats().max(zf), n);
                    prop_assert!(l.total_bytes() <= 4 * n);
                }
                None => {
                    // One of the two noise modes' layouts overflows.
                    prop_assert_eq!(arena_len(d, mode, k), usize::MAX);
                    let z = gman_core::navigator::memory::try_arena_len_noise(
                        d,
                        mode,
                        k,
                        gman_core::navigator::memory::Footprint::Compact,
                        gman_core::spec::schema::NoiseMode::Zero,
                    );
                    prop_assert!(l.total_bytes() == usize::MAX || z.is_none());
                }
            }
        }
    }
    for &id in gman_core::blob::TensorId::ALL {
        let _ = id.shape(d);
    }
    Ok(())
}

#[test]
fn huge_dims_are_rejected_by_parse_and_sizes_never_wrap() {
    // A blob header of huge dims: a valid v2 header with every dim u32::MAX and no tensors parsed,
    // and the sizes computed from its dims overflowed (wrapped without overflow checks).
    let bytes = header_only_blob([u32::MAX; 8]);
    assert_eq!(Blob::parse(&bytes).unwrap_err(), BlobError::DimsTooLarge);
    let d = dims_of([u32::MAX; 8]);
    assert!(!d.checked_sizes());
    assert_eq!(try_arena_len(&d, AdaptMode::Full, 20), None);
    assert_eq!(arena_len(&d, AdaptMode::Full, 20), usize::MAX);
    // (The Efficient arena of these dims does fit in a 64-bit usize; the Full one must never
    // come out smaller than it, which it did when the sum wrapped.)
    assert!(arena_len(&d, AdaptMode::Full, 20) >= arena_len(&d, AdaptMode::Efficient, 20));
    assert_eq!(checked_int8_weight_bytes(&d), None);
    assert_eq!(int8_weight_bytes(&d), usize::MAX);
    // The same header with the real sizes parses (no tensors: the loader reports them missing).
    let mcu = Dims::MCU;
    let ok = header_only_blob([45, 45, 256, 512, 64, 64, 64, 0]);
    let blob = Blob::parse(&ok).unwrap();
    assert_eq!(blob.dims(), mcu);
    assert!(mcu.checked_sizes() && Dims::PAPER.checked_sizes());
    assert_eq!(
        NavWeights::from_blob(&blob, &mcu).unwrap_err(),
        Error::Blob(BlobError::MissingTensor { id: 0 })
    );
}

/// Small weights for every tensor of `SMALL`, f32 or int8, as a parsed-able blob.
fn small_blob(seed: u64, int8: bool) -> Vec<u8> {
    make_blob(&SMALL, &random_tensors(&SMALL, seed), int8)
}

#[test]
fn manual_schedule_refuses_a_step_with_a_full_buffer() {
    // A full buffer under the manual schedule: the (K+1)-th step() without adapt_now()/clear_buffer() indexed past
    // Ψ ("range end index 10752 out of range for slice of length 10240" with MCU dims).
    const K: usize = 20;
    let bytes = small_blob(3, false);
    let blob = Blob::parse(&bytes).unwrap();
    let w = NavWeights::from_blob(&blob, &SMALL).unwrap();
    let mut arena = vec![0.0f32; Navigator::<Full, K>::arena_len(&SMALL)];
    let cfg = NavConfig {
        schedule: Schedule::Manual,
        ..NavConfig::default()
    };
    let mut nav = Navigator::<Full, K>::new(w, &mut arena, cfg).unwrap();
    nav.reset(&[0.5; 5], 1).unwrap();
    let obs = [0.1f32; 6];
    let ps = [0.0f32; 5];
    for _ in 0..K {
        nav.step(&obs, &ps).unwrap();
    }
    assert_eq!(nav.buffered(), K);
    let e = nav.step(&obs, &ps).unwrap_err();
    assert!(
        matches!(e, Error::Config { what } if what.contains("buffer full")),
        "{e:?}"
    );
    // Nothing changed, and the documented ways out work.
    assert_eq!(nav.buffered(), K);
    assert_eq!(nav.counters().steps, K as u32);
    assert!(nav.adapt_now().unwrap());
    nav.step(&obs, &ps).unwrap();
    for _ in 1..K {
        nav.step(&obs, &ps).unwrap();
    }
    assert!(nav.step(&obs, &ps).is_err());
    nav.clear_buffer();
    nav.step(&obs, &ps).unwrap();
}

/// One call on a navigator.
#[derive(Clone, Debug)]
enum Op {
    Step { obs: Vec<f32>, ps: Vec<f32> },
    AdaptNow,
    Clear,
    Reset { attr: Vec<f32>, seed: u64 },
    ResetDisc,
}

fn value() -> impl Strategy<Value = f32> {
    prop_oneof![
        8 => -2.0f32..2.0,
        1 => prop::sample::select(vec![
            f32::NAN, f32::INFINITY, f32::NEG_INFINITY, 1e30, -1e30, f32::MAX, f32::MIN_POSITIVE, 0.0
        ]),
    ]
}

fn vec_around(n: usize) -> impl Strategy<Value = Vec<f32>> {
    // Mostly the right length, sometimes not.
    prop_oneof![
        6 => prop::collection::vec(value(), n..=n),
        1 => prop::collection::vec(value(), 0..(n + 3)),
    ]
}

fn op() -> impl Strategy<Value = Op> {
    prop_oneof![
        12 => (vec_around(SMALL.feat), vec_around(SMALL.ps)).prop_map(|(obs, ps)| Op::Step { obs, ps }),
        2 => Just(Op::AdaptNow),
        2 => Just(Op::Clear),
        2 => (vec_around(SMALL.attr), any::<u64>()).prop_map(|(attr, seed)| Op::Reset { attr, seed }),
        1 => Just(Op::ResetDisc),
    ]
}

fn config() -> impl Strategy<Value = NavConfig> {
    (
        any::<bool>(),
        any::<bool>(),
        any::<bool>(),
        any::<bool>(),
        0u32..6,
        prop_oneof![
            Just(1e-4f32),
            Just(0.0),
            Just(10.0),
            Just(1e30),
            Just(f32::NAN)
        ],
        prop_oneof![Just(1e-4f32), Just(0.0), Just(100.0), Just(1e30)],
    )
        .prop_map(|(manual, adapt, zero, sample, cap, a1, a2)| NavConfig {
            model: ModelSpec {
                adapt,
                noise: if zero {
                    NoiseMode::Zero
                } else {
                    NoiseMode::Gaussian
                },
                max_inner: cap,
                inner_lr: a2,
                inner_rule: InnerRule {
                    disc_lr: Some(a1),
                    ..InnerRule::PAPER
                },
                ..NavConfig::default().model
            },
            schedule: if manual {
                Schedule::Manual
            } else {
                Schedule::Auto
            },
            selection: if sample {
                Selection::Sample
            } else {
                Selection::Greedy
            },
            ..NavConfig::default()
        })
}

/// Runs `ops` on a navigator over `blob`: every call returns `Ok` or a typed error.
fn drive<M: Mode, const K: usize>(blob: &Blob<'_>, cfg: NavConfig, ops: &[Op]) {
    let Ok(w) = NavWeights::from_blob(blob, &SMALL) else {
        return;
    };
    let mut arena = vec![0.0f32; Navigator::<M, K>::arena_len(&SMALL)];
    let Ok(mut nav) = Navigator::<M, K>::new(w, &mut arena, cfg) else {
        return;
    };
    for op in ops {
        match op {
            Op::Step { obs, ps } => {
                let before = nav.buffered();
                if let Ok(out) = nav.step(obs, ps) {
                    assert!(out.probs.iter().all(|p| p.is_finite()));
                    assert!(nav.buffered() <= K);
                } else {
                    assert_eq!(nav.buffered(), before);
                }
            }
            Op::AdaptNow => {
                let _ = nav.adapt_now();
            }
            Op::Clear => nav.clear_buffer(),
            Op::Reset { attr, seed } => {
                let _ = nav.reset(attr, *seed);
            }
            Op::ResetDisc => {
                let _ = nav.reset_discriminator();
            }
        }
        assert!(nav.buffered() <= K);
    }
}

proptest! {
    #![proptest_config(ProptestConfig { cases: cases(), failure_persistence: None, .. ProptestConfig::default() })]

    /// Arbitrary call sequences (including more than K steps without adapting under
    /// `Schedule::Manual`, wrong lengths, NaN/infinite/huge inputs, diverging rates) on
    /// navigators of both modes and two buffer sizes, over f32 and int8 blobs that may carry
    /// resealed random byte edits: every call returns Ok or a typed error, never a panic.
    #[test]
    fn navigator_call_sequences_never_panic(
        cfg in config(),
        ops in prop::collection::vec(op(), 0..48),
        int8 in any::<bool>(),
        efficient in any::<bool>(),
        small_k in any::<bool>(),
        edits in prop::collection::vec((any::<prop::sample::Index>(), any::<u8>()), 0..4),
    ) {
        let bytes = small_blob(11, int8);
        let parsed = Blob::parse(&bytes).unwrap();
        let (plen, crc) = (parsed.header().payload_len() as usize, parsed.header().payload_crc());
        let hlen = bytes.len() - plen;
        let mut m = bytes.clone();
        for (i, b) in &edits {
            m[hlen + i.index(plen)] = *b;
        }
        let m = if edits.is_empty() { m } else { reseal(&m, plen, crc) };
        let Ok(blob) = Blob::parse(&m) else { return Ok(()); };
        match (efficient, small_k) {
            (false, false) => drive::<Full, 20>(&blob, cfg, &ops),
            (false, true) => drive::<Full, 3>(&blob, cfg, &ops),
            (true, false) => drive::<Efficient, 20>(&blob, cfg, &ops),
            (true, true) => drive::<Efficient, 3>(&blob, cfg, &ops),
        }
    }

    /// Blob headers with arbitrary dims (small, large and near `u32::MAX`): parsing never
    /// panics; what parses has sizes that all fit (checked arithmetic), and for any dims the
    /// size functions never panic or wrap.
    #[test]
    fn blob_derived_sizes_never_overflow(
        raw in prop::array::uniform8(prop_oneof![
            4 => 0u32..64,
            2 => 0u32..100_000,
            1 => any::<u32>(),
            1 => (u32::MAX - 8)..=u32::MAX,
            1 => prop::sample::select(vec![1u32 << 16, 1 << 20, 1 << 24, 1 << 30, 1 << 31]),
        ]),
    ) {
        let d = dims_of(raw);
        sizes_are_consistent(&d)?;
        match Blob::parse(&header_only_blob(raw)) {
            Ok(blob) => {
                prop_assert!(d.checked_sizes());
                prop_assert_eq!(blob.dims(), d);
                for mode in [AdaptMode::Full, AdaptMode::Efficient] {
                    prop_assert!(try_arena_len(&d, mode, 1).is_some());
                }
                prop_assert!(checked_int8_weight_bytes(&d).is_some());
                // No tensors: every loader gets a typed error, never an allocation.
                prop_assert!(NavWeights::from_blob(&blob, &d).is_err());
            }
            Err(BlobError::DegenerateDims { field }) => {
                prop_assert_eq!(d.degenerate_field(), Some(field));
            }
            Err(e) => {
                prop_assert_eq!(e, BlobError::DimsTooLarge);
                prop_assert!(d.degenerate_field().is_none() && !d.checked_sizes());
            }
        }
    }

    /// Small and degenerate dims (zero widths, half a map, a map without channels) in
    /// complete blobs with a valid checksum: the parser refuses exactly the degenerate ones
    /// (`DegenerateDims`, naming the field), and navigators over the others run steps and
    /// inner updates in both modes without a panic.
    #[test]
    fn degenerate_dims_are_refused_and_small_ones_run(
        raw in prop::array::uniform8(0u32..4),
        map in prop::array::uniform3(0u32..3),
        flags in prop_oneof![Just(0u32), Just(gman_core::blob::FLAG_ADAPT)],
        ops in prop::collection::vec(op_for(), 0..24),
    ) {
        let mut d = dims_of(raw);
        d.ps = if raw[7] % 2 == 0 { 0 } else { d.attr };
        let d = d.with_map(map[0] as usize, map[1] as usize, map[2] as usize);
        let bytes = raw_blob(&d, flags);
        match Blob::parse(&bytes) {
            Ok(blob) => {
                prop_assert_eq!(d.degenerate_field(), None);
                let cfg = blob.nav_config();
                drive_dims::<Full, 3>(&blob, &d, cfg, &ops);
                drive_dims::<Efficient, 3>(&blob, &d, cfg, &ops);
            }
            Err(e) => {
                let field = d.degenerate_field();
                prop_assert!(field.is_some(), "{d:?} refused with {e:?}");
                prop_assert_eq!(e, BlobError::DegenerateDims { field: field.unwrap() });
            }
        }
    }
}

/// Ops whose vectors have the widths of whatever dims they are run on (scaled in
/// [`drive_dims`]): steps, updates, clears and resets.
fn op_for() -> impl Strategy<Value = u8> {
    0u8..4
}

/// Runs `ops` (0 step, 1 adapt_now, 2 clear, 3 reset) on a navigator of `dims` over `blob`.
fn drive_dims<M: Mode, const K: usize>(blob: &Blob<'_>, d: &Dims, cfg: NavConfig, ops: &[u8]) {
    let Ok(w) = NavWeights::from_blob(blob, d) else {
        return;
    };
    let mut arena = vec![0.0f32; Navigator::<M, K>::arena_len(d)];
    let cfg = NavConfig {
        schedule: Schedule::Manual,
        ..cfg
    };
    let Ok(mut nav) = Navigator::<M, K>::new(w, &mut arena, cfg) else {
        return;
    };
    let attr = vec![0.5f32; d.attr];
    let obs = vec![0.25f32; d.feat];
    let map = vec![0.1f32; d.map_len()];
    let ps = vec![0.1f32; d.ps];
    nav.reset(&attr, 3).unwrap();
    for op in ops {
        match op {
            0 => {
                let _ = if d.map_cells() > 0 {
                    nav.step_map(&obs, &map, &ps).map(|_| ())
                } else {
                    nav.step(&obs, &ps).map(|_| ())
                };
            }
            1 => {
                let _ = nav.adapt_now();
            }
            2 => nav.clear_buffer(),
            _ => nav.reset(&attr, 5).unwrap(),
        }
    }
    // K steps and an update always complete.
    nav.clear_buffer();
    for _ in 0..K {
        if d.map_cells() > 0 {
            nav.step_map(&obs, &map, &ps).unwrap();
        } else {
            nav.step(&obs, &ps).unwrap();
        }
    }
    nav.adapt_now().unwrap();
}

/// A blob with `disc_hidden = 0` (a zero-width D) parsed, and the first inner update
/// panicked ("chunk size must be non-zero"); it is refused when parsed, and
/// `Navigator::new` refuses such dims from any source.
#[test]
fn zero_width_dims_are_refused_by_parse_and_navigator() {
    for field in ["disc_hidden", "gen_hidden", "lstm_hidden", "embed"] {
        let mut d = SMALL;
        match field {
            "disc_hidden" => d.disc_hidden = 0,
            "gen_hidden" => d.gen_hidden = 0,
            "lstm_hidden" => d.lstm_hidden = 0,
            _ => d.embed = 0,
        }
        let bytes = raw_blob(&d, gman_core::blob::FLAG_ADAPT);
        assert_eq!(
            Blob::parse(&bytes).unwrap_err(),
            BlobError::DegenerateDims { field }
        );
        // The same weights handed to the navigator directly.
        let store: Vec<(gman_core::blob::TensorId, Vec<f32>)> =
            gman_core::blob::TensorId::all_for(&d)
                .map(|id| {
                    let (r, c) = id.shape(&d);
                    (id, vec![0.01f32; r * c])
                })
                .collect();
        let w = NavWeights::from_fn(&d, |id| {
            let (r, c) = id.shape(&d);
            let v = &store.iter().find(|(i, _)| *i == id).unwrap().1;
            gman_core::nn::matrix::MatRef::f32(r, c, v).unwrap()
        })
        .unwrap();
        let mut arena = vec![0.0f32; Navigator::<Full, 4>::arena_len(&d).max(1)];
        let Err(e) = Navigator::<Full, 4>::new(w, &mut arena, NavConfig::default()) else {
            panic!("{field}: accepted")
        };
        assert!(
            matches!(e, Error::Config { what } if what.contains("degenerate dims")),
            "{field}: {e:?}"
        );
    }
    // Half a map, and a map without channels.
    for (d, field) in [
        (SMALL.with_map(2, 0, 4), "map_cols"),
        (SMALL.with_map(0, 2, 4), "map_rows"),
        (SMALL.with_map(2, 2, 0), "cell_embed"),
    ] {
        assert_eq!(d.degenerate_field(), Some(field));
    }
}

/// `Navigator::new` accepted negative and absurd rates the blob parser refused, and
/// `adapt_now()` ran an inner update with `adapt == false`.
#[test]
fn navigator_settings_are_checked_like_a_blob_and_adapt_false_never_adapts() {
    let bytes = small_blob(4, false);
    let blob = Blob::parse(&bytes).unwrap();
    for (a1, a2) in [
        (-1e-4f32, 1e-4f32),
        (1e-4, -1e-4),
        (1e-4, 3.4e36),
        (f32::NAN, 1e-4),
        (1e-4, gman_core::blob::MAX_INNER_RATE * 2.0),
    ] {
        let w = NavWeights::from_blob(&blob, &SMALL).unwrap();
        let mut arena = vec![0.0f32; Navigator::<Full, 4>::arena_len(&SMALL)];
        let cfg = NavConfig {
            model: ModelSpec {
                inner_lr: a2,
                inner_rule: InnerRule {
                    disc_lr: Some(a1),
                    ..InnerRule::PAPER
                },
                ..NavConfig::default().model
            },
            ..NavConfig::default()
        };
        let Err(e) = Navigator::<Full, 4>::new(w, &mut arena, cfg) else {
            panic!("({a1}, {a2}) accepted")
        };
        assert!(
            matches!(e, Error::Config { what } if what.contains("MAX_INNER_RATE")),
            "({a1}, {a2}): {e:?}"
        );
    }
    let w = NavWeights::from_blob(&blob, &SMALL).unwrap();
    let mut arena = vec![0.0f32; Navigator::<Full, 4>::arena_len(&SMALL)];
    let cfg = NavConfig {
        model: ModelSpec {
            adapt: false,
            inner_lr: 0.5,
            inner_rule: InnerRule {
                disc_lr: Some(0.5),
                ..InnerRule::PAPER
            },
            ..NavConfig::default().model
        },
        schedule: Schedule::Manual,
        ..NavConfig::default()
    };
    let mut nav = Navigator::<Full, 4>::new(w, &mut arena, cfg).unwrap();
    nav.reset(&[0.5; 5], 1).unwrap();
    let obs = [0.1f32; 6];
    let before = nav.step(&obs, &[0.0; 5]).unwrap().probs.to_vec();
    for _ in 1..4 {
        nav.step(&obs, &[0.0; 5]).unwrap();
    }
    assert!(!nav.adapt_now().unwrap(), "adapt == false must not adapt");
    assert_eq!(nav.buffered(), 0);
    assert_eq!(nav.counters().adaptations, 0);
    nav.reset(&[0.5; 5], 1).unwrap();
    let after = nav.step(&obs, &[0.0; 5]).unwrap().probs.to_vec();
    assert_eq!(before, after, "the weights are unchanged");
}
