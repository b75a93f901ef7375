//! The schedules through the C API: the commit delay in `gman_options` and `gman_info`, the
//! background schedule with `gman_adapt_slice`, `gman_settle`, `gman_get_schedule` and
//! `GMAN_ERR_UPDATE_NOT_READY`. Bad handles and options are refused with a status; a step
//! refused as not ready changes nothing; the background schedule computes bit for bit what
//! the automatic one does at the same delay, however its slices are spread over the steps.

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

/// Reads a postcard varint at `*at`, advancing it.
fn varint(b: &[u8], at: &mut usize) -> u32 {
    let (mut v, mut shift) = (0u32, 0);
    loop {
        let byte = b[*at];
        *at += 1;
        v |= ((byte & 0x7f) as u32) << shift;
        if byte & 0x80 == 0 {
            return v;
        }
        shift += 7;
    }
}

/// The blob with commit delay `d` recorded in its header flags (a v3 header: magic,
/// version, 8 dims, 3 map dims, then the flags; the CRC covers only the payload).
fn with_recorded_delay(blob: &[u8], d: u32) -> Vec<u8> {
    let mut at = 4;
    assert_eq!(varint(blob, &mut at), 3, "a v3 (map) blob");
    for _ in 0..11 {
        varint(blob, &mut at);
    }
    let start = at;
    let flags = varint(blob, &mut at);
    let mut f = (flags & !(0x3f << 25)) | (d << 25);
    let mut out = blob[..start].to_vec();
    loop {
        let low = (f & 0x7f) as u8;
        f >>= 7;
        if f == 0 {
            out.push(low);
            break;
        }
        out.push(low | 0x80);
    }
    out.extend_from_slice(&blob[at..]);
    out
}

/// A navigator in its own arena.
struct Nav {
    _arena: Vec<u8>,
    h: *mut gman_nav,
}

fn try_nav(blob: &[u8], opts: gman_options) -> Result<Nav, gman_status> {
    let i = info(blob);
    let mut arena = vec![0u8; i.arena_bytes as usize];
    let mut h = null_mut();
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
    if s == GMAN_OK {
        assert!(!h.is_null());
        Ok(Nav { _arena: arena, h })
    } else {
        assert!(h.is_null(), "a refused init left a handle");
        Err(s)
    }
}

fn opts(schedule: u32, commit_delay: u32) -> gman_options {
    gman_options {
        selection: 0,
        schedule,
        require_header_crc: 0,
        settings: gman_settings {
            commit_delay,
            ..gman_settings::default()
        },
    }
}

fn schedule_of(n: &Nav) -> gman_schedule_state {
    let mut s = gman_schedule_state::default();
    assert_eq!(unsafe { gman_get_schedule(n.h, &mut s) }, GMAN_OK);
    s
}

/// The schedule a navigator runs and its commit delay ([`gman_nav_info`]).
fn running(n: &Nav) -> (u32, u32) {
    let mut i = gman_info::default();
    assert_eq!(unsafe { gman_nav_info(n.h, &mut i) }, GMAN_OK);
    (schedule_of(n).schedule, i.settings.commit_delay)
}

fn reset(n: &Nav, i: &gman_info, seed: u64) {
    let attr = vec![0.4f32; i.attr as usize];
    assert_eq!(
        unsafe { gman_reset(n.h, attr.as_ptr(), attr.len(), seed) },
        GMAN_OK
    );
}

/// Step `t`'s inputs (the same for every navigator).
fn inputs(i: &gman_info, t: usize) -> (Vec<f32>, Vec<f32>) {
    let v = (t % 7) as f32 / 7.0;
    (vec![v; i.feat as usize], vec![1.0 - v; i.map_len as usize])
}

fn step(n: &Nav, i: &gman_info, t: usize, out: &mut gman_step_out) -> gman_status {
    let (obs, map) = inputs(i, t);
    unsafe {
        gman_step(
            n.h,
            obs.as_ptr(),
            obs.len(),
            map.as_ptr(),
            map.len(),
            null(),
            0,
            out,
        )
    }
}

fn counters(n: &Nav) -> gman_counters {
    let mut c = gman_counters::default();
    assert_eq!(unsafe { gman_get_counters(n.h, &mut c) }, GMAN_OK);
    c
}

fn feature(n: &Nav, i: &gman_info) -> Vec<u32> {
    let mut x = vec![0.0f32; i.feat as usize];
    assert_eq!(
        unsafe { gman_generated_feature(n.h, x.as_mut_ptr(), x.len()) },
        GMAN_OK
    );
    x.iter().map(|v| v.to_bits()).collect()
}

fn g_output(n: &Nav, i: &gman_info) -> Vec<u32> {
    let z = vec![0.0f32; i.noise as usize];
    let mut x = vec![0.0f32; i.feat as usize];
    assert_eq!(
        unsafe { gman_generator_output(n.h, z.as_ptr(), z.len(), x.as_mut_ptr(), x.len()) },
        GMAN_OK
    );
    x.iter().map(|v| v.to_bits()).collect()
}

fn report_bits(n: &Nav) -> [u32; 7] {
    let mut r = gman_adapt_report::default();
    assert_eq!(unsafe { gman_last_adaptation(n.h, &mut r) }, GMAN_OK);
    [
        r.ld_loss.to_bits(),
        r.ld_mean_real.to_bits(),
        r.ld_mean_fake.to_bits(),
        r.ld_penalty.to_bits(),
        r.adapt_loss.to_bits(),
        r.disc_applied,
        r.adapt_applied,
    ]
}

#[test]
fn new_functions_refuse_null_and_dead_handles() {
    let blob = model();
    let i = info(&blob);
    let mut more = 7u32;
    let mut st = gman_schedule_state::default();
    unsafe {
        assert_eq!(gman_adapt_slice(null_mut(), &mut more), GMAN_ERR_NULL);
        assert_eq!(gman_adapt_slice(null_mut(), null_mut()), GMAN_ERR_NULL);
        assert_eq!(gman_settle(null_mut()), GMAN_ERR_NULL);
        assert_eq!(gman_get_schedule(null_mut(), &mut st), GMAN_ERR_NULL);
    }
    assert_eq!(more, 7, "a refused call wrote its output");
    // Never initialised (zeroed and garbage arenas), misaligned.
    for fill in [0u8, 0xA5] {
        let mut dead = vec![fill; i.arena_bytes as usize];
        let h = dead.as_mut_ptr().cast::<gman_nav>();
        let odd = unsafe { dead.as_mut_ptr().add(1) }.cast::<gman_nav>();
        for h in [h, odd] {
            unsafe {
                assert_eq!(gman_adapt_slice(h, &mut more), GMAN_ERR_BAD_HANDLE);
                assert_eq!(gman_settle(h), GMAN_ERR_BAD_HANDLE);
                assert_eq!(gman_get_schedule(h, &mut st), GMAN_ERR_BAD_HANDLE);
            }
        }
    }
    let n = try_nav(&blob, opts(2, 20)).expect("background at d = 20");
    unsafe {
        assert_eq!(gman_get_schedule(n.h, null_mut()), GMAN_ERR_NULL);
        // Misaligned output.
        let mut words = [0u32; 6];
        let odd = (words.as_mut_ptr() as *mut u8).add(1) as *mut gman_schedule_state;
        assert_eq!(gman_get_schedule(n.h, odd), GMAN_ERR_ALIGNMENT);
        let odd = (words.as_mut_ptr() as *mut u8).add(1) as *mut u32;
        assert_eq!(gman_adapt_slice(n.h, odd), GMAN_ERR_ALIGNMENT);
    }
    // Nothing pending: a slice does nothing, settling does nothing, even before a reset.
    more = 7;
    assert_eq!(unsafe { gman_adapt_slice(n.h, &mut more) }, GMAN_OK);
    assert_eq!(more, 0);
    assert_eq!(unsafe { gman_adapt_slice(n.h, null_mut()) }, GMAN_OK);
    assert_eq!(unsafe { gman_settle(n.h) }, GMAN_OK);
    assert_eq!(
        schedule_of(&n),
        gman_schedule_state {
            schedule: 2,
            pending: 0,
            slices_left: 0
        }
    );
    assert_eq!(running(&n), (2, 20));
}

#[test]
fn options_choose_the_delay_and_the_blob_s_own_delay_wins() {
    let blob = model();
    assert_eq!(
        info(&blob).settings.commit_delay,
        0,
        "the shipped blob records d = 0"
    );
    // Out of range, unknown schedule, background without a delay.
    for (o, what) in [
        (opts(0, 64), "commit_delay 64"),
        (opts(0, u32::MAX), "commit_delay u32::MAX"),
        (opts(3, 20), "schedule 3"),
        (opts(2, 0), "background with d = 0"),
        (
            gman_options {
                settings: gman_settings {
                    max_inner_updates: 2,
                    ..gman_settings::default()
                },
                ..opts(0, 0)
            },
            "a setting other than the delay",
        ),
    ] {
        assert_eq!(
            try_nav(&blob, o).err(),
            Some(GMAN_ERR_CONFIG),
            "{what} accepted"
        );
    }
    for (o, want) in [
        (opts(0, 0), (0, 0)),
        (opts(0, 20), (0, 20)),
        (opts(1, 63), (1, 63)),
    ] {
        let n = try_nav(&blob, o).expect("valid options");
        assert_eq!(running(&n), want);
    }
    // A blob that records d = 7: reported, run by default, a contradiction refused.
    let b7 = with_recorded_delay(&blob, 7);
    let i7 = info(&b7);
    assert_eq!(i7.settings.commit_delay, 7);
    assert_eq!(i7.flags >> 25, 7);
    for (o, want) in [
        (opts(0, 0), (0, 7)),
        (opts(0, 7), (0, 7)),
        (opts(2, 0), (2, 7)),
    ] {
        let n = try_nav(&b7, o).expect("the blob's delay");
        assert_eq!(running(&n), want);
    }
    for d in [1, 6, 8, 20, 63] {
        assert_eq!(
            try_nav(&b7, opts(0, d)).err(),
            Some(GMAN_ERR_CONFIG),
            "d = {d} against a blob recording 7 accepted"
        );
    }
}

#[test]
fn a_step_not_ready_is_reported_and_changes_nothing() {
    let blob = model();
    let i = info(&blob);
    let (bg, auto) = (
        try_nav(&blob, opts(2, 20)).unwrap(),
        try_nav(&blob, opts(0, 20)).unwrap(),
    );
    reset(&bg, &i, 11);
    reset(&auto, &i, 11);
    let mut out = gman_step_out::default();
    let mut t = 0;
    let mut refused = 0;
    while t < 45 {
        let before = (
            counters(&bg),
            schedule_of(&bg),
            feature(&bg, &i),
            g_output(&bg, &i),
            report_bits(&bg),
        );
        let mut o = gman_step_out {
            action: 99,
            ..gman_step_out::default()
        };
        let s = step(&bg, &i, t, &mut o);
        if s == GMAN_ERR_UPDATE_NOT_READY {
            refused += 1;
            // The last step of the window (Ψ filled at t = 19, d = 20): slices were left.
            assert_eq!(t, 39);
            assert_eq!(o.action, 99, "a refused step wrote its output");
            let after = (
                counters(&bg),
                schedule_of(&bg),
                feature(&bg, &i),
                g_output(&bg, &i),
                report_bits(&bg),
            );
            assert_eq!(before, after, "a refused step changed the navigator");
            assert!(before.1.pending == 1 && before.1.slices_left > 0);
            let msg = unsafe { CStr::from_ptr(gman_last_error(bg.h)) }
                .to_str()
                .unwrap()
                .to_owned();
            assert!(
                msg.contains(&before.1.slices_left.to_string()) && msg.contains("gman_adapt_slice"),
                "{msg}"
            );
            // Refused again while slices remain.
            let mut more = 1;
            assert_eq!(unsafe { gman_adapt_slice(bg.h, &mut more) }, GMAN_OK);
            if more == 1 {
                assert_eq!(step(&bg, &i, t, &mut o), GMAN_ERR_UPDATE_NOT_READY);
            }
            let mut slices = 1;
            while more == 1 {
                assert_eq!(unsafe { gman_adapt_slice(bg.h, &mut more) }, GMAN_OK);
                slices += 1;
                assert!(slices < 100_000, "the update never completes");
            }
            assert_eq!(schedule_of(&bg).slices_left, 0);
            continue; // the same step again
        }
        assert_eq!(s, GMAN_OK, "step {t}");
        assert_eq!(step(&auto, &i, t, &mut out), GMAN_OK);
        assert_eq!(o.probs.map(f32::to_bits), out.probs.map(f32::to_bits));
        assert_eq!((o.action, o.adapted), (out.action, out.adapted), "step {t}");
        if t == 19 {
            let s = schedule_of(&bg);
            assert!(s.pending == 1 && s.slices_left > 0, "{s:?}");
        }
        t += 1;
    }
    assert_eq!(refused, 1);
    assert_eq!(counters(&bg), counters(&auto));
    assert_eq!(counters(&bg).adaptations, 1);
    assert_eq!(report_bits(&bg), report_bits(&auto));
    assert_eq!(g_output(&bg, &i), g_output(&auto, &i));
}

/// Runs every remaining slice of the pending update.
fn drain(n: &Nav) {
    let (mut more, mut slices) = (1, 0);
    while more == 1 {
        assert_eq!(unsafe { gman_adapt_slice(n.h, &mut more) }, GMAN_OK);
        slices += 1;
        assert!(slices < 100_000, "the update never completes");
    }
}

#[test]
fn settle_completes_the_discriminator_s_part() {
    // Ψ filled, the episode ends before the commit: settling runs D's ascent (the next
    // episode's bits show it), a navigator that settles behaves as one reset directly.
    let blob = model();
    let i = info(&blob);
    let (a, b) = (
        try_nav(&blob, opts(2, 20)).unwrap(),
        try_nav(&blob, opts(2, 20)).unwrap(),
    );
    let mut o = gman_step_out::default();
    for n in [&a, &b] {
        reset(n, &i, 5);
        for t in 0..25 {
            assert_eq!(step(n, &i, t, &mut o), GMAN_OK);
        }
        assert_eq!(schedule_of(n).pending, 1);
    }
    assert_eq!(unsafe { gman_settle(a.h) }, GMAN_OK);
    let s = schedule_of(&a);
    assert_eq!((s.pending, s.slices_left), (0, 0));
    reset(&a, &i, 6);
    reset(&b, &i, 6);
    for t in 0..45 {
        let (mut oa, mut ob) = (gman_step_out::default(), gman_step_out::default());
        let sa = step(&a, &i, t, &mut oa);
        let sb = step(&b, &i, t, &mut ob);
        assert_eq!(sa, sb, "step {t}");
        if sa == GMAN_ERR_UPDATE_NOT_READY {
            drain(&a);
            drain(&b);
            assert_eq!(step(&a, &i, t, &mut oa), GMAN_OK);
            assert_eq!(step(&b, &i, t, &mut ob), GMAN_OK);
        } else {
            assert_eq!(sa, GMAN_OK);
        }
        assert_eq!(oa.probs.map(f32::to_bits), ob.probs.map(f32::to_bits));
    }
    assert_eq!(report_bits(&a), report_bits(&b));
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 12, ..ProptestConfig::default() })]

    /// Background + gman_adapt_slice, slices spread over the steps at random (refused steps
    /// retried after draining), gives the bits of the automatic schedule at the same delay.
    #[test]
    fn background_slices_give_the_bits_of_auto(
        per_step in proptest::collection::vec(0u32..4, 100),
        d in prop::sample::select(vec![1u32, 3, 20]),
        seed in any::<u64>(),
    ) {
        let blob = model();
        let i = info(&blob);
        let bg = try_nav(&blob, opts(2, d)).unwrap();
        let auto = try_nav(&blob, opts(0, d)).unwrap();
        reset(&bg, &i, seed);
        reset(&auto, &i, seed);
        let mut refused = 0;
        for (t, &k) in per_step.iter().enumerate() {
            for _ in 0..k {
                prop_assert_eq!(unsafe { gman_adapt_slice(bg.h, null_mut()) }, GMAN_OK);
            }
            let (mut ob, mut oa) = (gman_step_out::default(), gman_step_out::default());
            let mut s = step(&bg, &i, t, &mut ob);
            if s == GMAN_ERR_UPDATE_NOT_READY {
                refused += 1;
                let mut more = 1;
                let mut n = 0;
                while more == 1 {
                    prop_assert_eq!(unsafe { gman_adapt_slice(bg.h, &mut more) }, GMAN_OK);
                    n += 1;
                    prop_assert!(n < 100_000, "the update never completes");
                }
                s = step(&bg, &i, t, &mut ob);
            }
            prop_assert_eq!(s, GMAN_OK);
            prop_assert_eq!(step(&auto, &i, t, &mut oa), GMAN_OK);
            prop_assert_eq!(ob.probs.map(f32::to_bits), oa.probs.map(f32::to_bits), "step {}", t);
            prop_assert_eq!(ob.value.to_bits(), oa.value.to_bits());
            prop_assert_eq!((ob.action, ob.adapted), (oa.action, oa.adapted));
            prop_assert_eq!(counters(&bg), counters(&auto));
            prop_assert_eq!(report_bits(&bg), report_bits(&auto));
        }
        prop_assert!(counters(&auto).adaptations >= 2);
        prop_assert_eq!(feature(&bg, &i), feature(&auto, &i));
        prop_assert_eq!(g_output(&bg, &i), g_output(&auto, &i));
        let _ = refused;
    }
}
