//! The storage of Ψ's observations: f32, or int16 with a per-entry scale
//! ([`crate::spec::schema::FLAG_COMPACT_PSI`]).

/// The int16 range of Ψ's compact observations ([`crate::spec::schema::FLAG_COMPACT_PSI`]).
pub(super) const PSI_Q: f32 = 32767.0;

/// One observation `s` into Ψ's compact form: `q_j = round(s_j * (32767 / a))` (halves
/// away from zero, to the f32 rounding of `|t| + 0.5`, at most 32767 in magnitude) with
/// `a = max |s_j|` (all `q_j` 0 when `a` is 0),
/// read back as `q_j * (a / 32767)`. With `scale` (the
/// [`crate::navigator::memory::Footprint::Minimal`] arena) `out` gets the `q_j` as int16,
/// two per float (entry `2i` in the low half of float `i`'s bits), and `scale` the scale;
/// without, `out` gets the values read back ([`psi_load`] gives the same bits from the
/// packed form). `s` is finite (the step checked it).
pub(super) fn psi_store(s: &[f32], out: &mut [f32], scale: Option<&mut f32>) {
    let mut a = 0.0f32;
    for &v in s {
        let m = libm::fabsf(v);
        if m > a {
            a = m;
        }
    }
    // (All zeros: `inv` is infinite, `0 * inv` NaN, which `as` turns into 0.)
    let (sc, inv) = (a / PSI_Q, PSI_Q / a);
    let packed = scale.is_some();
    if let Some(dst) = scale {
        *dst = sc;
    }
    for (j, &v) in s.iter().enumerate() {
        let t = v * inv;
        let m = ((libm::fabsf(t) + 0.5) as i32).min(PSI_Q as i32);
        let q = if t < 0.0 { -m } else { m };
        let (i, hi) = if packed {
            (j / 2, j % 2 == 1)
        } else {
            (j, false)
        };
        if let Some(o) = out.get_mut(i) {
            *o = if !packed {
                q as f32 * sc
            } else if hi {
                f32::from_bits(o.to_bits() & 0xffff | (q as u16 as u32) << 16)
            } else {
                f32::from_bits(q as u16 as u32)
            };
        }
    }
}

/// The observation [`psi_store`] packed into `packed` with scale `sc`, read back into `out`.
pub(super) fn psi_load(packed: &[f32], sc: f32, out: &mut [f32]) {
    for (o, p) in out.chunks_mut(2).zip(packed) {
        let b = p.to_bits();
        o[0] = (b as u16 as i16) as f32 * sc;
        if let Some(v) = o.get_mut(1) {
            *v = ((b >> 16) as u16 as i16) as f32 * sc;
        }
    }
}
