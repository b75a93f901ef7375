//! Reading a blob and describing it to C: `gman_inspect`, `gman_arena_size`, the C form of a model's settings.

use super::*;

pub(crate) fn blob_info(blob: &Blob<'_>) -> Result<gman_info, gman_status> {
    let h: &Header = blob.header();
    let d = h.dims();
    let arena = arena_bytes_for(&d, h.adapt_mode()).ok_or(GMAN_ERR_CONFIG)?;
    let u = |v: usize| u32::try_from(v).map_err(|_| GMAN_ERR_BLOB);
    Ok(gman_info {
        format_version: h.version() as u32,
        flags: h.flags(),
        payload_crc: h.payload_crc(),
        attr: u(d.attr)?,
        noise: u(d.noise)?,
        feat: u(d.feat)?,
        gen_hidden: u(d.gen_hidden)?,
        disc_hidden: u(d.disc_hidden)?,
        lstm_hidden: u(d.lstm_hidden)?,
        embed: u(d.embed)?,
        ps: u(d.ps)?,
        map_rows: u(d.map_rows)?,
        map_cols: u(d.map_cols)?,
        cell_embed: u(d.cell_embed)?,
        map_len: u(d.map_cells().checked_mul(d.feat).ok_or(GMAN_ERR_BLOB)?)?,
        settings: settings_of(&h.spec()),
        buffer_capacity: K as u32,
        arena_bytes: arena as u64,
    })
}

/// The C form of a model's settings.
pub(crate) fn settings_of(m: &ModelSpec) -> gman_settings {
    gman_settings {
        adapt: m.adapt as u32,
        adapt_mode: match m.adapt_mode {
            AdaptMode::Efficient => 0,
            AdaptMode::Full => 1,
        },
        emd: match m.emd {
            Emd::Discriminator => 0,
            Emd::CosSim => 1,
        },
        noise_mode: match m.noise {
            NoiseMode::Gaussian => 0,
            NoiseMode::Zero => 1,
        },
        max_inner_updates: m.max_inner,
        alpha_disc: m.alpha_disc(),
        alpha_adapt: m.inner_lr,
        commit_delay: m.inner_rule.commit_delay,
    }
}

/// Parses `blob`/`len` and describes it.
///
/// # Safety
/// See [`slice_in`].
pub(crate) unsafe fn parse_blob<'a>(
    blob: *const u8,
    len: usize,
    opts: ParseOptions,
) -> Result<(Blob<'a>, gman_info), gman_status> {
    if blob.is_null() {
        return Err(GMAN_ERR_NULL);
    }
    if blob_too_long(len) {
        return Err(GMAN_ERR_BLOB);
    }
    // SAFETY: forwarded from the caller: `blob` is readable for `len` bytes.
    let bytes = unsafe { slice_in(blob, len) }?;
    let b = Blob::parse_with(bytes, opts).map_err(|e| status_of_blob(&e))?;
    let info = blob_info(&b)?;
    Ok((b, info))
}

/// Validates the blob (`len` bytes at `blob`: header, format version, CRC, every tensor) and
/// describes it in `*out`.
///
/// # Safety
/// `blob` must be readable for `len` bytes; `out` writable (both may be null: an error).
#[no_mangle]
pub unsafe extern "C" fn gman_inspect(
    blob: *const u8,
    len: usize,
    out: *mut gman_info,
) -> gman_status {
    // SAFETY: forwarded from the caller.
    unsafe { describe(blob, len, out, |_, info| Ok(info)) }
}

/// The number of arena bytes a navigator over this blob needs, in `*out` (the blob is
/// validated as by [`gman_inspect`]).
///
/// # Safety
/// As [`gman_inspect`].
#[no_mangle]
pub unsafe extern "C" fn gman_arena_size(
    blob: *const u8,
    len: usize,
    out: *mut usize,
) -> gman_status {
    // SAFETY: forwarded from the caller.
    unsafe {
        describe(blob, len, out, |_, info| {
            usize::try_from(info.arena_bytes).map_err(|_| GMAN_ERR_CONFIG)
        })
    }
}

/// Setting number `index` (0, 1, ...) of the validated blob (`len` bytes at `blob`) in
/// `*out`: its key, type and value. Past the last setting `out->key` is empty (and the
/// call returns [`GMAN_OK`]), so a program lists every setting with
/// `for (i = 0; gman_blob_setting(blob, len, i, &s) == GMAN_OK && s.key[0]; i++)`.
/// The blob is validated on every call, as by [`gman_inspect`].
///
/// # Safety
/// As [`gman_inspect`].
#[no_mangle]
pub unsafe extern "C" fn gman_blob_setting(
    blob: *const u8,
    len: usize,
    index: u32,
    out: *mut gman_setting,
) -> gman_status {
    // SAFETY: forwarded from the caller.
    unsafe {
        describe(blob, len, out, |b, _| {
            Ok(setting_at(&b.header().spec(), index as usize))
        })
    }
}

/// The C form of setting number `i` of `m` (an empty key past the last).
pub(crate) fn setting_at(m: &ModelSpec, i: usize) -> gman_setting {
    let mut s = gman_setting::default();
    let Some(key) = SETTING_KEYS.get(i) else {
        return s;
    };
    c_text(key, &mut s.key);
    match m.get(key) {
        Some(SettingValue::U32(n)) => s.count = n,
        Some(SettingValue::F32(a)) => (s.kind, s.rate) = (1, a),
        Some(SettingValue::Name(n)) => {
            s.kind = 2;
            c_text(n, &mut s.name);
        }
        Some(SettingValue::Bool(b)) => (s.kind, s.count) = (3, u32::from(b)),
        None => s.kind = 4,
    }
    s
}

/// `text` into `out`, NUL-terminated (cut to fit; every key and name fits, a test checks).
fn c_text(text: &str, out: &mut [c_char; GMAN_SETTING_TEXT]) {
    for (o, &b) in out
        .iter_mut()
        .zip(text.as_bytes().iter().take(GMAN_SETTING_TEXT - 1))
    {
        *o = b as c_char;
    }
}

/// `*out = f(blob, info)` of the validated blob and its description `info`, as a status: the
/// body of [`gman_inspect`], [`gman_arena_size`] and [`gman_blob_setting`].
///
/// # Safety
/// `blob` readable for `len` bytes; `out` writable (both may be null: an error).
pub(crate) unsafe fn describe<T>(
    blob: *const u8,
    len: usize,
    out: *mut T,
    f: impl FnOnce(&Blob<'_>, gman_info) -> Result<T, gman_status>,
) -> gman_status {
    guard(|| {
        let r = if blob_too_long(len) {
            Err(GMAN_ERR_BLOB)
        } else {
            disjoint(Span::EMPTY, &[Span::of(blob, len)], &[Span::one(out)])
        };
        // SAFETY: forwarded from the caller.
        let r = r.and_then(|()| unsafe { out_ref(out) }).and_then(|o| {
            // SAFETY: forwarded from the caller.
            let (b, info) = unsafe { parse_blob(blob, len, ParseOptions::default()) }?;
            *o = f(&b, info)?;
            Ok(())
        });
        r.err().unwrap_or(GMAN_OK)
    })
}
