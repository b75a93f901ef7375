//! The inner update committed `commit_delay` steps after Ψ fills: computed in slices inside
//! the steps (`Schedule::Auto`), by the caller between steps (`Schedule::Background` +
//! `adapt_slice`) or at once at the commit (`Schedule::Manual` + `adapt_now`, the trainer's
//! way), the three give the same run bit for bit; a background update that is not ready at
//! its commit point is a typed error that changes nothing.

mod common;

use common::{make_blob, random_tensors, SMALL};
use gman_core::blob::Blob;
use gman_core::navigator::{
    Efficient, Full, Mode, NavConfig, NavWeights, Navigator, Schedule, Selection,
};
use gman_core::spec::{InnerRule, ModelSpec};
use gman_core::Error;

const K: usize = 5;
const STEPS: usize = 40;

fn obs(t: usize) -> [f32; 6] {
    core::array::from_fn(|i| ((t * 7 + i * 3) % 11) as f32 / 11.0)
}

/// Per step: the probabilities' bits and whether the step committed an update; then the
/// final generated feature's bits and the number of updates.
type Run = (Vec<([u32; 6], bool)>, Vec<u32>, u32);

fn run<M: Mode>(bytes: &[u8], schedule: Schedule, delay: u32) -> Run {
    let blob = Blob::parse(bytes).unwrap();
    let w = NavWeights::from_blob(&blob, &SMALL).unwrap();
    let mut arena = vec![0.0f32; Navigator::<M, K>::arena_len(&SMALL)];
    let cfg = NavConfig {
        model: ModelSpec {
            inner_lr: 0.05,
            max_inner: 100,
            inner_rule: InnerRule {
                commit_delay: delay,
                disc_lr: Some(0.05),
                ..InnerRule::PAPER
            },
            ..NavConfig::default().model
        },
        schedule,
        selection: Selection::Sample,
        ..NavConfig::default()
    };
    let mut nav = Navigator::<M, K>::new(w, &mut arena, cfg).unwrap();
    nav.reset(&[0.5, 0.1, 0.9, 0.3, 0.7], 3).unwrap();
    let ps = [0.0f32; 5];
    let mut out = Vec::new();
    let mut background_slices = 0;
    for t in 0..STEPS {
        match schedule {
            // One slice per period in the idle time, before the step.
            Schedule::Background if nav.update_pending() => {
                nav.adapt_slice().unwrap();
                background_slices += 1;
            }
            // The trainer's order: a full Ψ whose window is over commits.
            Schedule::Manual
                if nav.buffered() == K
                    && !nav.in_commit_window()
                    && (nav.update_pending() || delay == 0) =>
            {
                assert!(nav.adapt_now().unwrap());
            }
            _ => {}
        }
        let o = loop {
            match nav.step(&obs(t), &ps) {
                Ok(o) => break o,
                Err(Error::UpdateNotReady { slices_left }) => {
                    assert!(slices_left > 0);
                    nav.adapt_slice().unwrap();
                }
                Err(e) => panic!("{e:?}"),
            }
        };
        out.push((o.probs.map(f32::to_bits), o.adapted));
    }
    if schedule == Schedule::Background {
        assert!(background_slices > 0);
    }
    let x = nav
        .generated_feature()
        .iter()
        .map(|v| v.to_bits())
        .collect();
    (out, x, nav.counters().adaptations)
}

fn check<M: Mode>() {
    let bytes = make_blob(&SMALL, &random_tensors(&SMALL, 4), false);
    let at_once = run::<M>(&bytes, Schedule::Auto, 0);
    for delay in [1u32, 3, 6] {
        let auto = run::<M>(&bytes, Schedule::Auto, delay);
        assert!(auto.2 >= 2, "too few updates: {}", auto.2);
        // The commit points: k + d, 2 (k + d), ...
        for (t, (_, adapted)) in auto.0.iter().enumerate() {
            assert_eq!(
                *adapted,
                (t + 1) % (K + delay as usize) == 0,
                "t={t} d={delay}"
            );
        }
        // The delay changes what runs (the test can tell the schedules apart) ...
        assert_ne!(auto.0, at_once.0, "d={delay}");
        // ... and every way of computing the delayed update gives the same bits.
        let manual = run::<M>(&bytes, Schedule::Manual, delay);
        let background = run::<M>(&bytes, Schedule::Background, delay);
        // Manual reports no commit in the step (adapt_now does it).
        let strip = |r: &Run| r.0.iter().map(|p| p.0).collect::<Vec<_>>();
        assert_eq!(strip(&manual), strip(&auto), "manual d={delay}");
        assert_eq!(manual.1, auto.1);
        assert_eq!(background, auto, "background d={delay}");
    }
}

#[test]
fn every_schedule_commits_the_same_delayed_update_efficient() {
    check::<Efficient>();
}

#[test]
fn every_schedule_commits_the_same_delayed_update_full() {
    check::<Full>();
}

#[test]
fn background_update_not_ready_at_its_commit_point_changes_nothing() {
    let bytes = make_blob(&SMALL, &random_tensors(&SMALL, 5), false);
    let blob = Blob::parse(&bytes).unwrap();
    let w = NavWeights::from_blob(&blob, &SMALL).unwrap();
    let mut arena = vec![0.0f32; Navigator::<Efficient, K>::arena_len(&SMALL)];
    let cfg = NavConfig {
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
    let mut nav = Navigator::<Efficient, K>::new(w, &mut arena, cfg).unwrap();
    nav.reset(&[0.5; 5], 1).unwrap();
    let ps = [0.0f32; 5];
    for t in 0..K + 2 {
        assert!(!nav.step(&obs(t), &ps).unwrap().adapted);
    }
    assert!(nav.update_pending());
    let (h, steps) = (nav.hidden_state().to_vec(), nav.counters().steps);
    let e = nav.step(&obs(K + 2), &ps).unwrap_err();
    assert!(
        matches!(e, Error::UpdateNotReady { slices_left } if slices_left > 0),
        "{e:?}"
    );
    assert_eq!(nav.hidden_state(), &h[..]);
    assert_eq!(nav.counters().steps, steps);
    let mut slices = 0;
    while nav.adapt_slice().unwrap() {
        slices += 1;
    }
    assert!(slices > 1, "the update should take several slices");
    let o = nav.step(&obs(K + 2), &ps).unwrap();
    assert!(o.adapted);
    assert_eq!(nav.counters().adaptations, 1);
    assert!(!nav.update_pending());
    assert!(!nav.adapt_slice().unwrap());
}

#[test]
fn bad_delays_are_refused() {
    let bytes = make_blob(&SMALL, &random_tensors(&SMALL, 5), false);
    let blob = Blob::parse(&bytes).unwrap();
    for (schedule, delay) in [(Schedule::Background, 0), (Schedule::Auto, 64)] {
        let w = NavWeights::from_blob(&blob, &SMALL).unwrap();
        let mut arena = vec![0.0f32; Navigator::<Efficient, K>::arena_len(&SMALL)];
        let cfg = NavConfig {
            model: ModelSpec {
                inner_rule: InnerRule {
                    commit_delay: delay,
                    ..InnerRule::PAPER
                },
                ..NavConfig::default().model
            },
            schedule,
            ..NavConfig::default()
        };
        let e = Navigator::<Efficient, K>::new(w, &mut arena, cfg).err();
        assert!(matches!(e, Some(Error::Config { .. })), "{e:?}");
    }
}
