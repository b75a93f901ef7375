//! A refused call changes nothing: after a step (or a split step) that returns `Err`, a
//! navigator goes on bit for bit like one that never saw the call, with the same counters,
//! Ψ, LSTM state, previous probabilities and random stream. Also the parse option that
//! refuses blobs whose checksum skips the header.

mod common;
use common::*;
use gman_core::blob::{
    reencode_with_flags, reencoded_len_bound, Blob, ParseOptions, TensorId, FLAG_ADAPT,
};
use gman_core::navigator::{
    Efficient, Full, Mode, NavConfig, NavWeights, Navigator, NoiseMode, Schedule, Selection,
};
use gman_core::spec::{InnerRule, ModelSpec};
use gman_core::{BlobError, Error};

const K: usize = 20;

/// Everything a caller can read of a navigator between calls, as bits.
fn state<M: Mode>(n: &Navigator<'_, M, K>) -> Vec<u32> {
    let c = n.counters();
    let mut v = vec![
        c.steps,
        c.adaptations,
        c.rollbacks,
        c.total_steps as u32,
        n.buffered() as u32,
        n.slices_left(),
        n.update_pending() as u32,
    ];
    for s in [n.hidden_state(), n.cell_state(), n.prev_probs(), n.attr()] {
        v.extend(s.iter().map(|x| x.to_bits()));
    }
    let b = n.buffer();
    for s in [b.obs, b.noise, b.probs] {
        v.extend(s.iter().map(|x| x.to_bits()));
    }
    v
}

/// Small seeded weights whose fusion layer and critic are large enough (x 30) that an
/// observation entry of 3e38 or an LSTM state of `f32::MAX`, finite, overflows them;
/// adapting (`FLAG_ADAPT`).
fn overflowing_blob() -> Vec<u8> {
    let mut t = random_tensors(&SMALL, 11);
    for (id, v) in &mut t {
        if matches!(id, TensorId::FuseW | TensorId::CriticW) {
            v.iter_mut().for_each(|w| *w *= 30.0);
        }
    }
    let plain = make_blob(&SMALL, &t, false);
    let mut out = vec![0u8; reencoded_len_bound(&plain)];
    let n = reencode_with_flags(&plain, FLAG_ADAPT, &mut out).unwrap();
    out.truncate(n);
    out
}

fn obs_at(i: usize) -> Vec<f32> {
    (0..SMALL.feat)
        .map(|j| ((i * 7 + j * 3) % 11) as f32 / 11.0)
        .collect()
}

/// Runs 45 steps (two inner updates) on two navigators; `b` is also given a refused step
/// (an observation with one entry of 3e38, finite but overflowing the policy) before step
/// `at`. Every later output and the state must match `a`'s.
fn refused_step_changes_nothing<M: Mode>(cfg: NavConfig, at: usize) {
    let bytes = overflowing_blob();
    let blob = Blob::parse(&bytes).unwrap();
    let len = Navigator::<M, K>::arena_len(&SMALL);
    let (mut ra, mut rb) = (vec![0.0f32; len], vec![0.0f32; len]);
    let w = || NavWeights::from_blob(&blob, &SMALL).unwrap();
    let mut a = Navigator::<M, K>::new(w(), &mut ra, cfg).unwrap();
    let mut b = Navigator::<M, K>::new(w(), &mut rb, cfg).unwrap();
    let attr = [0.3f32, -0.2, 0.1, 0.5, 0.0];
    a.reset(&attr, 7).unwrap();
    b.reset(&attr, 7).unwrap();
    let ps = [0.1f32; 5];
    let mut refused = 0;
    for i in 0..45 {
        if i == at {
            let before = state(&b);
            let mut bad = obs_at(i);
            bad[2] = 3e38;
            let e = b.step(&bad, &ps).unwrap_err();
            assert!(matches!(e, Error::NumericalFault { .. }), "{e:?}");
            assert_eq!(state(&b), before, "a refused step changed the state");
            refused += 1;
        }
        if cfg.schedule == Schedule::Background {
            while a.adapt_slice().unwrap() {}
            while b.adapt_slice().unwrap() {}
        }
        let (sa, sb) = (a.step(&obs_at(i), &ps), b.step(&obs_at(i), &ps));
        let (sa, sb) = (sa.unwrap(), sb.unwrap());
        assert_eq!(sa.action, sb.action, "step {i}");
        assert_eq!(
            sa.probs.map(f32::to_bits),
            sb.probs.map(f32::to_bits),
            "step {i}: probabilities differ after a refused step"
        );
        assert_eq!(sa.value.to_bits(), sb.value.to_bits(), "step {i}");
        assert_eq!(sa.adapted, sb.adapted, "step {i}");
        assert_eq!(state(&a), state(&b), "step {i}");
        assert_eq!(
            a.generated_feature(),
            b.generated_feature(),
            "step {i}: x_t"
        );
    }
    assert_eq!(refused, 1);
    assert!(a.counters().adaptations >= 1);
}

#[test]
fn a_step_refused_as_numerical_changes_nothing() {
    for at in [0, 5, 19, 20, 33] {
        refused_step_changes_nothing::<Efficient>(NavConfig::default(), at);
        refused_step_changes_nothing::<Full>(NavConfig::default(), at);
        let sample = NavConfig {
            selection: Selection::Sample,
            ..NavConfig::default()
        };
        refused_step_changes_nothing::<Efficient>(sample, at);
        let zero = NavConfig {
            model: ModelSpec {
                noise: NoiseMode::Zero,
                ..NavConfig::default().model
            },
            ..NavConfig::default()
        };
        refused_step_changes_nothing::<Efficient>(zero, at);
        let delayed = NavConfig {
            model: ModelSpec {
                inner_rule: InnerRule {
                    commit_delay: 3,
                    ..InnerRule::PAPER
                },
                ..NavConfig::default().model
            },
            ..NavConfig::default()
        };
        refused_step_changes_nothing::<Efficient>(delayed, at);
        let background = NavConfig {
            model: ModelSpec {
                inner_rule: InnerRule {
                    commit_delay: 3,
                    ..InnerRule::PAPER
                },
                ..NavConfig::default().model
            },
            schedule: Schedule::Background,
            ..NavConfig::default()
        };
        refused_step_changes_nothing::<Efficient>(background, at);
    }
}

/// `finish_step` refused (a non-finite probability from a huge LSTM state) leaves the begun
/// step in place: `finish_step` again with a good state finishes it as if the refused call
/// never happened.
#[test]
fn a_refused_finish_step_leaves_the_begun_step() {
    let bytes = overflowing_blob();
    let blob = Blob::parse(&bytes).unwrap();
    let len = Navigator::<Efficient, K>::arena_len(&SMALL);
    let (mut ra, mut rb) = (vec![0.0f32; len], vec![0.0f32; len]);
    let w = || NavWeights::from_blob(&blob, &SMALL).unwrap();
    let cfg = NavConfig::default();
    let mut a = Navigator::<Efficient, K>::new(w(), &mut ra, cfg).unwrap();
    let mut b = Navigator::<Efficient, K>::new(w(), &mut rb, cfg).unwrap();
    let attr = [0.3f32, -0.2, 0.1, 0.5, 0.0];
    a.reset(&attr, 7).unwrap();
    b.reset(&attr, 7).unwrap();
    let ps = [0.1f32; 5];
    let (h, c) = ([0.25f32; 4], [0.5f32; 4]);
    a.begin_step(&obs_at(0), &[], &ps).unwrap();
    b.begin_step(&obs_at(0), &[], &ps).unwrap();
    let before = state(&b);
    let e = b.finish_step(&obs_at(0), &[f32::MAX; 4], &c).unwrap_err();
    assert!(matches!(e, Error::NumericalFault { .. }), "{e:?}");
    assert_eq!(state(&b), before);
    let (sa, sb) = (
        a.finish_step(&obs_at(0), &h, &c).unwrap(),
        b.finish_step(&obs_at(0), &h, &c).unwrap(),
    );
    assert_eq!(sa.probs.map(f32::to_bits), sb.probs.map(f32::to_bits));
    assert_eq!(state(&a), state(&b));
}

/// `ParseOptions::require_header_crc` refuses v1-v3 blobs (their CRC skips the header) before
/// reading their header, and accepts v4; the default accepts all.
#[test]
fn require_header_crc_refuses_formats_whose_checksum_skips_the_header() {
    let v4 = seeded_blob(&SMALL, 3, true, gman_core::spec::schema::FLAG_ADAPT);
    let strict = ParseOptions {
        require_header_crc: true,
    };
    assert!(Blob::parse_with(&v4, strict).is_ok());
    let old = legacy(&v4);
    let version = Blob::parse(&old).unwrap().header().version();
    assert!(version < 4, "legacy() gives an older format");
    assert_eq!(
        Blob::parse_with(&old, strict).unwrap_err(),
        BlobError::HeaderNotCovered { found: version }
    );
    let text = BlobError::HeaderNotCovered { found: version }.to_string();
    assert!(
        text.contains("payload only") && text.contains("upgrade-blob"),
        "{text}"
    );
    // A v3 header with a flipped byte is refused as well, not read.
    let mut flipped = old.clone();
    flipped[8] ^= 1;
    assert_eq!(
        Blob::parse_with(&flipped, strict).unwrap_err(),
        BlobError::HeaderNotCovered { found: version }
    );
}
