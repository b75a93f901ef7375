//! The navigator's calls: reset, step, the inner update's schedule, counters and introspection.

use super::*;

/// Starts an episode towards the target with attribute vector `attr` (`attr_len` =
/// [`gman_info::attr`] floats, SE(y)) and seeds the navigator's generator with `seed`:
/// restores the meta-learned θ and φ, clears the LSTM state and the buffer Ψ.
///
/// # Safety
/// `nav` a handle from [`gman_init`] (or null); `attr` readable for `attr_len` floats.
#[no_mangle]
pub unsafe extern "C" fn gman_reset(
    nav: *mut gman_nav,
    attr: *const f32,
    attr_len: usize,
    seed: u64,
) -> gman_status {
    // SAFETY: forwarded from the caller.
    unsafe {
        with_handle(nav, |h| {
            want_len("gman_reset.attr", h.info.attr, attr_len)?;
            h.disjoint(&[Span::of(attr, attr_len)], &[])?;
            let attr = slice_in(attr, attr_len).map_err(ffi_err)?;
            each!(&mut h.nav, n => n.reset(attr, seed)).map_err(core_err)
        })
    }
}

/// One control step: the pooled observation `obs` ([`gman_info::feat`] floats), the spatial
/// map `map` ([`gman_info::map_len`] floats, cell-major; NULL and 0 for a model without a
/// map) and the PS input `ps` ([`gman_info::ps`] floats; NULL and 0 without one). Writes the
/// action, the probabilities and the value to `*out`. With the default schedule, every k-th
/// step ends with the inner update (`out->adapted` = 1).
///
/// Any status but [`GMAN_OK`] changes nothing a later call reads (counters, Ψ, the LSTM
/// state, the previous probabilities, the adapted parameters, the pending update, the
/// random generator): the inputs are checked before anything is written, and a step whose
/// probabilities come out non-finite ([`GMAN_ERR_NUMERICAL`], e.g. an observation entry of
/// 3e38) is undone. Only [`gman_generated_feature`] shows the refused step's x_t until the
/// next step. To recover, step again with a good input.
///
/// # Safety
/// `nav` a handle; each buffer readable for its length; `out` writable.
#[no_mangle]
pub unsafe extern "C" fn gman_step(
    nav: *mut gman_nav,
    obs: *const f32,
    obs_len: usize,
    map: *const f32,
    map_len: usize,
    ps: *const f32,
    ps_len: usize,
    out: *mut gman_step_out,
) -> gman_status {
    // SAFETY: forwarded from the caller.
    unsafe {
        let inputs = [
            Span::of(obs, obs_len),
            Span::of(map, map_len),
            Span::of(ps, ps_len),
        ];
        with_handle(nav, |h| {
            want_len("gman_step.obs", h.info.feat, obs_len)?;
            want_len("gman_step.map", h.info.map_len, map_len)?;
            want_len("gman_step.ps", h.info.ps, ps_len)?;
            h.disjoint(&inputs, &[Span::one(out)])?;
            let out = out_ref(out).map_err(ffi_err)?;
            let obs = slice_in(obs, obs_len).map_err(ffi_err)?;
            let map = slice_in(map, map_len).map_err(ffi_err)?;
            let ps = slice_in(ps, ps_len).map_err(ffi_err)?;
            let s: StepOutput =
                each!(&mut h.nav, n => n.step_map(obs, map, ps)).map_err(core_err)?;
            *out = gman_step_out {
                action: s.action.index() as u32,
                adapted: s.adapted as u32,
                probs: s.probs,
                value: s.value,
            };
            Ok(())
        })
    }
}

/// Runs the inner update now on the steps buffered in Ψ (whatever their number), then
/// empties Ψ; `*ran` (may be NULL) is 1 if anything was buffered. With
/// [`gman_options::schedule`] = 1 this is the only place the update runs, so a controller
/// can call it from a lower-priority task between steps.
///
/// # Safety
/// `nav` a handle; `ran` null or writable.
#[no_mangle]
pub unsafe extern "C" fn gman_adapt_now(nav: *mut gman_nav, ran: *mut u32) -> gman_status {
    // SAFETY: forwarded from the caller.
    unsafe {
        with_handle(nav, |h| {
            h.disjoint(&[], &[Span::one(ran)])?;
            let r = each!(&mut h.nav, n => n.adapt_now()).map_err(core_err)?;
            if !ran.is_null() {
                *out_ref(ran).map_err(ffi_err)? = r as u32;
            }
            Ok(())
        })
    }
}

/// Runs one bounded slice of the pending inner update (the call of the background schedule's
/// lower-priority context); `*more` (may be NULL) is 1 while slices remain. Without a pending
/// update it does nothing (`*more` = 0). The slices never change what a step reads: the
/// update takes effect at its commit, bit for bit the update the automatic schedule
/// computes. Must not overlap a call of [`gman_step`] on the same navigator.
///
/// # Safety
/// `nav` a handle; `more` null or writable.
#[no_mangle]
pub unsafe extern "C" fn gman_adapt_slice(nav: *mut gman_nav, more: *mut u32) -> gman_status {
    // SAFETY: forwarded from the caller.
    unsafe {
        with_handle(nav, |h| {
            h.disjoint(&[], &[Span::one(more)])?;
            let more = if more.is_null() {
                None
            } else {
                Some(out_ref(more).map_err(ffi_err)?)
            };
            let r = each!(&mut h.nav, n => n.adapt_slice()).map_err(core_err)?;
            if let Some(m) = more {
                *m = r as u32;
            }
            Ok(())
        })
    }
}

/// Completes the discriminator's part of a pending inner update and drops the rest (the
/// adapted parameters are restored by the next [`gman_reset`] anyway, which settles
/// itself). Call it after an episode's last step when D, which persists across episodes,
/// must have learnt from every buffer that filled before it is read or the navigator idles.
///
/// # Safety
/// `nav` a handle.
#[no_mangle]
pub unsafe extern "C" fn gman_settle(nav: *mut gman_nav) -> gman_status {
    // SAFETY: forwarded from the caller.
    unsafe {
        with_handle(nav, |h| {
            each!(&mut h.nav, n => n.settle()).map_err(core_err)
        })
    }
}

/// The navigator's schedule and the state of its pending inner update in `*out`.
///
/// # Safety
/// `nav` a handle; `out` writable.
#[no_mangle]
pub unsafe extern "C" fn gman_get_schedule(
    nav: *mut gman_nav,
    out: *mut gman_schedule_state,
) -> gman_status {
    // SAFETY: forwarded from the caller.
    unsafe {
        with_handle(nav, |h| {
            h.disjoint(&[], &[Span::one(out)])?;
            let o = out_ref(out).map_err(ffi_err)?;
            *o = each!(&h.nav, n => gman_schedule_state {
                schedule: match n.config().schedule {
                    Schedule::Auto => 0,
                    Schedule::Manual => 1,
                    Schedule::Background => 2,
                },
                pending: n.update_pending() as u32,
                slices_left: n.slices_left(),
            });
            Ok(())
        })
    }
}

/// Number of steps buffered in Ψ (0 to [`GMAN_BUFFER_CAPACITY`]) in `*out`.
///
/// # Safety
/// `nav` a handle; `out` writable.
#[no_mangle]
pub unsafe extern "C" fn gman_buffered(nav: *mut gman_nav, out: *mut u32) -> gman_status {
    // SAFETY: forwarded from the caller.
    unsafe {
        with_handle(nav, |h| {
            h.disjoint(&[], &[Span::one(out)])?;
            let o = out_ref(out).map_err(ffi_err)?;
            *o = each!(&h.nav, n => n.buffered()) as u32;
            Ok(())
        })
    }
}

/// The navigator's counters in `*out`.
///
/// # Safety
/// `nav` a handle; `out` writable.
#[no_mangle]
pub unsafe extern "C" fn gman_get_counters(
    nav: *mut gman_nav,
    out: *mut gman_counters,
) -> gman_status {
    // SAFETY: forwarded from the caller.
    unsafe {
        with_handle(nav, |h| {
            h.disjoint(&[], &[Span::one(out)])?;
            let o = out_ref(out).map_err(ffi_err)?;
            let c = each!(&h.nav, n => n.counters());
            *o = gman_counters {
                steps: c.steps,
                adaptations: c.adaptations,
                rollbacks: c.rollbacks,
                reserved: 0,
                total_steps: c.total_steps,
                total_adaptations: c.total_adaptations,
                total_rollbacks: c.total_rollbacks,
            };
            Ok(())
        })
    }
}

/// Diagnostics of the last inner update in `*out` (all zero before the first).
///
/// # Safety
/// `nav` a handle; `out` writable.
#[no_mangle]
pub unsafe extern "C" fn gman_last_adaptation(
    nav: *mut gman_nav,
    out: *mut gman_adapt_report,
) -> gman_status {
    // SAFETY: forwarded from the caller.
    unsafe {
        with_handle(nav, |h| {
            h.disjoint(&[], &[Span::one(out)])?;
            let o = out_ref(out).map_err(ffi_err)?;
            let r = each!(&h.nav, n => n.last_adaptation());
            *o = gman_adapt_report {
                ld_loss: r.ld.loss,
                ld_mean_real: r.ld.mean_real,
                ld_mean_fake: r.ld.mean_fake,
                ld_penalty: r.ld.penalty,
                adapt_loss: r.adapt_loss,
                disc_applied: r.disc_applied as u32,
                adapt_applied: r.adapt_applied as u32,
            };
            Ok(())
        })
    }
}

/// The description of the navigator's blob ([`gman_inspect`]) in `*out`, with the settings
/// the navigator runs: the blob's, and the commit delay the options chose
/// ([`gman_options::settings`]; [`gman_info::flags`] keeps the blob's bits).
///
/// # Safety
/// `nav` a handle; `out` writable.
#[no_mangle]
pub unsafe extern "C" fn gman_nav_info(nav: *mut gman_nav, out: *mut gman_info) -> gman_status {
    // SAFETY: forwarded from the caller.
    unsafe {
        with_handle(nav, |h| {
            h.disjoint(&[], &[Span::one(out)])?;
            *out_ref(out).map_err(ffi_err)? = h.info;
            Ok(())
        })
    }
}

/// The last step's generated feature x_t ([`gman_info::feat`] floats) copied to `out`.
///
/// # Safety
/// `nav` a handle; `out` writable for `out_len` floats.
#[no_mangle]
pub unsafe extern "C" fn gman_generated_feature(
    nav: *mut gman_nav,
    out: *mut f32,
    out_len: usize,
) -> gman_status {
    // SAFETY: forwarded from the caller.
    unsafe {
        with_handle(nav, |h| {
            want_len("gman_generated_feature.out", h.info.feat, out_len)?;
            h.disjoint(&[], &[Span::of(out, out_len)])?;
            let out = slice_out(out, out_len).map_err(ffi_err)?;
            let x = each!(&h.nav, n => n.generated_feature());
            out.copy_from_slice(x);
            Ok(())
        })
    }
}

/// G(SE(y), z) at the current, possibly adapted θ for the noise `z` ([`gman_info::noise`]
/// floats) into `out` ([`gman_info::feat`] floats), leaving the episode's state untouched
/// (a diagnostic: how far the inner updates moved G).
///
/// # Safety
/// `nav` a handle; `z` readable for `z_len` floats; `out` writable for `out_len` floats.
#[no_mangle]
pub unsafe extern "C" fn gman_generator_output(
    nav: *mut gman_nav,
    z: *const f32,
    z_len: usize,
    out: *mut f32,
    out_len: usize,
) -> gman_status {
    // SAFETY: forwarded from the caller.
    unsafe {
        with_handle(nav, |h| {
            want_len("gman_generator_output.z", h.info.noise, z_len)?;
            want_len("gman_generator_output.out", h.info.feat, out_len)?;
            h.disjoint(&[Span::of(z, z_len)], &[Span::of(out, out_len)])?;
            let z = slice_in(z, z_len).map_err(ffi_err)?;
            let out = slice_out(out, out_len).map_err(ffi_err)?;
            each!(&mut h.nav, n => n.generator_output(z, out)).map_err(core_err)
        })
    }
}

/// The message of the last failed call on `nav` (a NUL-terminated string inside the arena,
/// valid until the next call on `nav`), or a static text for a null or dead handle.
///
/// # Safety
/// `nav` null or a pointer as for the other functions.
#[no_mangle]
pub unsafe extern "C" fn gman_last_error(nav: *mut gman_nav) -> *const c_char {
    // SAFETY: forwarded from the caller.
    match unsafe { handle_ptr(nav) } {
        // SAFETY: a checked handle; only the address of its message is taken.
        Ok(h) => unsafe { ptr::addr_of!((*h).msg) as *const c_char },
        Err(s) => gman_status_str(s),
    }
}
