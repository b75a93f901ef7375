//! The settings' names, bits, records and ranges: round trips and refusals.

use super::*;

#[test]
fn names_round_trip_and_unknown_names_list_the_known() {
    fn check<T: Named + FromStr<Err = UnknownName> + fmt::Debug>() {
        for &(v, name, _) in T::NAMES {
            assert_eq!(v.name(), name);
            assert_eq!(name.parse::<T>(), Ok(v));
        }
        assert!("sideways".parse::<T>().is_err());
    }
    check::<AdaptMode>();
    check::<NoiseMode>();
    check::<StepRule>();
    check::<AdaptLossKind>();
    assert_eq!(StepRule::PerGroup.name(), "per-group");
    let e = "x".parse::<StepRule>().unwrap_err();
    let mut s = heapless_string();
    fmt::write(&mut s, format_args!("{e}")).unwrap();
    assert_eq!(
        s.as_str(),
        "expected `gradient`, `normalized` or `per-group`"
    );
}

fn heapless_string() -> Buf {
    Buf([0; 96], 0)
}

struct Buf([u8; 96], usize);
impl Buf {
    fn as_str(&self) -> &str {
        core::str::from_utf8(&self.0[..self.1]).unwrap()
    }
}
impl fmt::Write for Buf {
    fn write_str(&mut self, s: &str) -> fmt::Result {
        let b = s.as_bytes();
        self.0[self.1..self.1 + b.len()].copy_from_slice(b);
        self.1 += b.len();
        Ok(())
    }
}

#[test]
fn every_setting_changed_changes_every_setting_within_its_range() {
    let changed = ModelSpec::EVERY_SETTING_CHANGED;
    assert_eq!(changed.validate(), Ok(()));
    for key in SETTING_KEYS {
        assert!(changed.get(key).is_some(), "{key}");
        let default = ModelSpec::BLOB_DEFAULT.get(key);
        assert_ne!(changed.get(key), default, "{key} keeps its default");
    }
}

#[test]
fn spec_round_trips_through_flags_and_settings() {
    let spec = ModelSpec::EVERY_SETTING_CHANGED;
    let back = ModelSpec::from_bits(spec.bits(), AdaptSettings::PAPER);
    assert!(back.adapt && back.emd == Emd::CosSim);
    assert_eq!(
        ModelSpec::from_bits(spec.bits(), spec.adapt_settings()),
        spec
    );
    let paper = ModelSpec::paper(AdaptMode::Full);
    assert_eq!(paper.adapt_settings(), AdaptSettings::PAPER);
    assert_eq!(paper.validate(), Ok(()));
    assert_eq!(spec.validate(), Ok(()));
}

#[test]
fn every_setting_key_reads_back_what_it_sets() {
    assert_eq!(SettingKey::DISC_STEPS.as_str(), "disc_steps");
    assert_eq!(SettingKey::COMMIT_DELAY.as_str(), "commit_delay");
    let mut spec = ModelSpec::BLOB_DEFAULT;
    spec.inner_rule.disc_lr = Some(0.5);
    let mut back = ModelSpec::BLOB_DEFAULT;
    for key in SETTING_KEYS {
        let k = SettingKey::named(key).unwrap();
        assert_eq!(k.as_str(), key);
        let v = spec.get(key).unwrap();
        assert_eq!(back.set(key, v), Ok(()));
        let wrong = match v {
            SettingValue::Bool(_) => SettingValue::U32(1),
            _ => SettingValue::Bool(true),
        };
        assert!(matches!(
            back.set(key, wrong),
            Err(SettingError::WrongType { .. })
        ));
    }
    assert_eq!(back, spec);
    // Every name of every name-valued setting reads back as itself.
    for (key, names) in [
        ("emd", Emd::NAME_LIST),
        ("noise", NoiseMode::NAME_LIST),
        ("adapt_mode", AdaptMode::NAME_LIST),
        ("step_rule", StepRule::NAME_LIST),
        ("adapt_loss", AdaptLossKind::NAME_LIST),
    ] {
        for name in names {
            let mut s = ModelSpec::BLOB_DEFAULT;
            assert_eq!(s.set(key, SettingValue::Name(name)), Ok(()));
            assert_eq!(s.get(key), Some(SettingValue::Name(name)), "{key}");
        }
    }
    assert_eq!(
        back.set("step_rule", SettingValue::Name("sideways")),
        Err(SettingError::UnknownName)
    );
    assert_eq!(
        back.set("warp", SettingValue::U32(1)),
        Err(SettingError::UnknownKey)
    );
    assert_eq!(SettingKey::named("warp"), None);
    assert_eq!(check_map_grid(16, 1), Ok(()));
    assert_eq!(
        check_map_grid(17, 3),
        Err(SpecError::MapGrid { rows: 17, cols: 3 })
    );
    assert!(check_map_grid(0, 3).is_err());
}

#[test]
fn validate_names_the_setting_out_of_range() {
    let mut s = ModelSpec::paper(AdaptMode::Full);
    s.inner_lr = 1e30;
    assert_eq!(s.validate(), Err(SpecError::InnerRate(1e30)));
    s.inner_lr = f32::NAN;
    assert!(matches!(s.validate(), Err(SpecError::InnerRate(_))));
    let mut s = ModelSpec::paper(AdaptMode::Full);
    s.inner_rule.disc_lr = Some(-1.0);
    assert_eq!(s.validate(), Err(SpecError::DiscRate(-1.0)));
    s.inner_rule.disc_lr = None;
    s.inner_rule.disc_steps = 0;
    assert_eq!(s.validate(), Err(SpecError::DiscSteps(0)));
    s.inner_rule.disc_steps = MAX_DISC_STEPS;
    s.inner_rule.commit_delay = MAX_COMMIT_DELAY + 1;
    assert_eq!(s.validate(), Err(SpecError::CommitDelay(64)));
}

/// [`ModelSpec::from_bits`] with the paper's rates.
fn of_bits(bits: u32) -> ModelSpec {
    ModelSpec::from_bits(bits, AdaptSettings::PAPER)
}

#[test]
fn flags_round_trip() {
    for bits in 0..16u32 {
        assert_eq!(of_bits(bits).bits(), bits);
    }
    assert_eq!(of_bits(0xF0).bits(), 0);
    // the inner-rule levers: every step count and both rules, next to the other bits
    for steps in [0u32, 1, 2, 5, 256] {
        for norm in [false, true] {
            let bits = 0b1011
                | (steps.saturating_sub(1) << DISC_STEPS_SHIFT)
                | if norm { FLAG_NORMALIZED_STEP } else { 0 };
            let f = of_bits(bits);
            let r = f.inner_rule;
            assert_eq!(r.disc_steps, steps.max(1));
            assert_eq!(r.step_rule == StepRule::Normalized, norm);
            assert!(f.adapt && f.adapt_mode == AdaptMode::Full);
            assert_eq!(f.bits(), bits);
        }
    }
    // the per-group step and D's head reset, with and without the other rule bits
    for (bits, rule) in [
        (FLAG_PER_GROUP_STEP, StepRule::PerGroup),
        (FLAG_NORMALIZED_STEP, StepRule::Normalized),
    ] {
        for reset in [false, true] {
            let bits = bits | FLAG_ADAPT | if reset { FLAG_DISC_HEAD_RESET } else { 0 };
            let f = of_bits(bits);
            let r = f.inner_rule;
            assert_eq!((r.step_rule, r.disc_head_reset), (rule, reset));
            assert_eq!(f.bits(), bits);
        }
    }
    // blobs written before the levers read as the paper's rule
    let old = of_bits(FLAG_ADAPT);
    assert_eq!(old.inner_rule, InnerRule::PAPER);
    assert_eq!(old.inner_rule.critic_scale(), 1.0);
    let r = FLAG_ADAPT | FLAG_REFERENCE_ADAPT_LOSS | FLAG_REFERENCE_CRITIC_SCALE;
    let f = of_bits(r);
    assert_eq!(
        (f.inner_rule.adapt_loss, f.inner_rule.critic_scale()),
        (AdaptLossKind::Reference, 10.0)
    );
    assert_eq!(f.bits(), r);
    assert!(!f.inner_rule.head_only);
    let h = of_bits(FLAG_ADAPT | FLAG_HEAD_ONLY);
    assert!(h.inner_rule.head_only && h.adapt);
    assert_eq!(h.bits(), FLAG_ADAPT | FLAG_HEAD_ONLY);
    let mut f = old;
    f.inner_rule.disc_steps = 1000;
    assert_eq!(of_bits(f.bits()).inner_rule.disc_steps, 256);
    // the commit delay: 0 in older blobs, round trips, saturates, leaves the rest alone
    for d in [1u32, 7, 20, MAX_COMMIT_DELAY] {
        let mut f = of_bits(r | FLAG_HEAD_ONLY);
        f.inner_rule.commit_delay = d;
        assert_eq!(of_bits(f.bits()), f);
        assert_eq!(f.bits() & !COMMIT_DELAY_MASK, r | FLAG_HEAD_ONLY);
    }
    let mut f = old;
    f.inner_rule.commit_delay = 1000;
    assert_eq!(of_bits(f.bits()).inner_rule.commit_delay, MAX_COMMIT_DELAY);
}
