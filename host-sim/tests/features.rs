//! The observation feature model carries the structure GMAN exploits.

mod common;

use gman_core::FEATURE_DIM;
use gman_host_sim::sim::features::DomainShift;
use gman_host_sim::sim::{CategoryId, Split, World};

fn dist2(a: &[f32; FEATURE_DIM], b: &[f32; FEATURE_DIM]) -> f32 {
    a.iter().zip(b).map(|(x, y)| (x - y) * (x - y)).sum()
}

/// Nearest-prototype recognition of the dominant object in views of val scenes:
/// (accuracy with the scene's style known, accuracy with the generic prototype, views).
fn recognition(world: &World) -> (f64, f64, usize) {
    let cats: Vec<CategoryId> = (0..world.categories.len() as CategoryId).collect();
    let generic: Vec<[f32; FEATURE_DIM]> = cats
        .iter()
        .map(|&c| world.generic_object_feature(c))
        .collect();
    let (mut styled_ok, mut generic_ok, mut n) = (0usize, 0usize, 0usize);
    for &s in world.split_scenes(Split::Val).unwrap() {
        let styled: Vec<[f32; FEATURE_DIM]> =
            cats.iter().map(|&c| world.object_feature(s, c)).collect();
        for &c in &world.scenes[s].present {
            for v in world.dominant_views(s, c, 3) {
                if v.weight
                    < std::env::var("WMIN")
                        .map(|s| s.parse().unwrap())
                        .unwrap_or(0.5)
                {
                    continue;
                }
                let best = |protos: &[[f32; FEATURE_DIM]]| {
                    (0..protos.len())
                        .min_by(|&a, &b| {
                            dist2(&v.features, &protos[a])
                                .total_cmp(&dist2(&v.features, &protos[b]))
                        })
                        .unwrap()
                };
                styled_ok += (best(&styled) == c as usize) as usize;
                generic_ok += (best(&generic) == c as usize) as usize;
                n += 1;
            }
        }
    }
    (styled_ok as f64 / n as f64, generic_ok as f64 / n as f64, n)
}

fn check_recognition(world: &World) {
    let (styled, generic, n) = recognition(world);
    eprintln!("recognition over {n} dominant views: scene style known {styled:.3}, generic prototypes {generic:.3}");
    assert!(n >= 50, "too few dominant views: {n}");
    assert!(styled >= 0.8, "styled recognition {styled}");
    assert!(
        styled - generic >= 0.25,
        "style gap too small: styled {styled}, generic {generic}"
    );
    // Attributes still transfer: the generic prototypes are far better than chance.
    assert!(
        generic > 5.0 / world.categories.len() as f64,
        "generic recognition {generic}"
    );
}

#[test]
fn style_known_recognition_beats_generic_real() {
    let Some(world) = common::real_world() else {
        return;
    };
    check_recognition(world);
}

#[test]
fn style_known_recognition_beats_generic_synthetic() {
    check_recognition(&World::synthetic(5));
}

#[test]
fn features_in_unit_range_and_deterministic() {
    let a = World::synthetic(3);
    let b = World::synthetic(3);
    let s = a.split_scenes(Split::Val).unwrap()[0];
    let (mut lo, mut hi, mut sum, mut cnt) = (0usize, 0usize, 0f64, 0usize);
    for st in 0..a.scenes[s].num_states() {
        let fa = &a.observation(s, st).features;
        assert_eq!(fa, &b.observation(s, st).features);
        for &v in fa.iter() {
            assert!((0.0..=1.0).contains(&v));
            lo += (v == 0.0) as usize;
            hi += (v == 1.0) as usize;
            sum += v as f64;
            cnt += 1;
        }
    }
    let mean = sum / cnt as f64;
    eprintln!(
        "mean {mean:.3}, share at 0: {:.3}, at 1: {:.3}",
        lo as f64 / cnt as f64,
        hi as f64 / cnt as f64
    );
    assert!(mean > 0.1 && mean < 0.9);
    assert!(
        (hi as f64) < 0.2 * cnt as f64,
        "too many saturated dimensions"
    );
}

#[test]
fn object_filling_the_view_is_close_to_object_feature() {
    let Some(world) = common::real_world() else {
        return;
    };
    let s = world.scene_id("FloorPlan22").unwrap();
    let fridge = world.category_id("Fridge").unwrap();
    let v = &world.dominant_views(s, fridge, 1)[0];
    let target = world.object_feature(s, fridge);
    let d_target = dist2(&v.features, &target);
    // Much closer to the scene's fridge feature than to any other category's.
    for c in 0..world.categories.len() as CategoryId {
        if c != fridge {
            assert!(
                d_target < 0.5 * dist2(&v.features, &world.object_feature(s, c)),
                "{}",
                world.category_name(c)
            );
        }
    }
}

/// Recognition at each domain shift S (host-sim/SIMULATOR.md, "Domain shift"), printed for
/// the docs: (S, style known, generic prototype, views).
fn recognition_by_shift(mut world: World, levels: &[f32]) -> Vec<(f32, f64, f64, usize)> {
    levels
        .iter()
        .map(|&s| {
            world.set_domain_shift(DomainShift::new(s).unwrap()).unwrap();
            let (styled, generic, n) = recognition(&world);
            eprintln!(
                "domain shift {s}: recognition over {n} dominant views: scene style known {styled:.3}, generic prototypes {generic:.3}"
            );
            (s, styled, generic, n)
        })
        .collect()
}

/// S = 0 leaves nothing for adaptation to close (the generic prototype is the true one); the
/// gap between knowing the scene's style and not knowing it widens with S.
fn check_shift_levels(world: World) {
    let r = recognition_by_shift(world, &[0.0, 0.5, 1.0, 2.0]);
    let (_, styled0, generic0, _) = r[0];
    assert!(
        (styled0 - generic0).abs() < 0.02,
        "at S = 0 the style cannot matter: {styled0} vs {generic0}"
    );
    for w in r.windows(2) {
        assert!(
            w[1].2 <= w[0].2 + 0.02,
            "generic recognition rises with the shift: {w:?}"
        );
    }
    assert!(r[3].2 < r[1].2 - 0.1, "S = 2 not harder than 0.5: {r:?}");
}

#[test]
fn domain_shift_widens_the_style_gap_synthetic() {
    check_shift_levels(World::synthetic(5));
}

#[test]
fn domain_shift_widens_the_style_gap_real() {
    if common::real_world().is_none() {
        return;
    }
    let dir = common::data_dir().unwrap();
    let world = World::load(&dir).unwrap();
    check_shift_levels(world);
}

/// S = 1 is the simulator without the knob, bit for bit; S = 0 makes an object's feature the
/// same in every scene.
#[test]
fn domain_shift_one_is_the_default_and_zero_removes_the_style() {
    let base = World::synthetic(3);
    let mut one = World::synthetic(3);
    one.set_domain_shift(DomainShift::new(1.0).unwrap()).unwrap();
    let mut zero = World::synthetic(3);
    zero.set_domain_shift(DomainShift::new(0.0).unwrap()).unwrap();
    let mut half = World::synthetic(3);
    half.set_domain_shift(DomainShift::new(0.5).unwrap()).unwrap();
    for s in 0..base.scenes.len().min(6) {
        let st = (s * 100) % base.tables(s).obs.len();
        let (a, b) = (base.observation(s, st), one.observation(s, st));
        assert_eq!(
            a.features.map(f32::to_bits),
            b.features.map(f32::to_bits),
            "scene {s}"
        );
        assert_ne!(a.features, half.observation(s, st).features, "scene {s}");
        for c in 0..4 {
            assert_eq!(
                zero.object_feature(s, c).map(f32::to_bits),
                zero.object_feature(0, c).map(f32::to_bits),
                "scene {s}, category {c}"
            );
        }
    }
    for bad in [-0.1f32, 3.5, f32::NAN, f32::INFINITY] {
        let e = DomainShift::new(bad).unwrap_err();
        assert!(e.contains("[0, 3]"), "{e}");
    }
}
