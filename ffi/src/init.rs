//! Making a navigator inside the caller's arena: `gman_init` and its checks.

use super::*;

/// Makes a navigator over the blob (read in place) inside `arena` (`arena_len` bytes, at
/// least [`gman_arena_size`], any alignment) and stores its handle (a pointer into the
/// arena) in `*out`. The navigator runs the model with the settings the blob records
/// (adaptation, rates, cap, mode); `opts` (NULL: defaults) chooses the run-time options.
/// Call [`gman_reset`] before the first step.
///
/// Both the blob and the arena must stay valid and unmoved while the handle is used; the
/// arena must not be otherwise accessed.
///
/// # Safety
/// `blob` readable for `blob_len` bytes, `arena` writable for `arena_len` bytes, `opts` null
/// or readable, `out` writable.
#[no_mangle]
pub unsafe extern "C" fn gman_init(
    blob: *const u8,
    blob_len: usize,
    arena: *mut c_void,
    arena_len: usize,
    opts: *const gman_options,
    out: *mut *mut gman_nav,
) -> gman_status {
    guard(|| {
        // SAFETY: forwarded from the caller.
        let r = unsafe { init(blob, blob_len, arena as *mut u8, arena_len, opts, out) };
        r.err().unwrap_or(GMAN_OK)
    })
}

/// # Safety
/// See [`gman_init`].
pub(crate) unsafe fn init(
    blob: *const u8,
    blob_len: usize,
    arena: *mut u8,
    arena_len: usize,
    opts: *const gman_options,
    out: *mut *mut gman_nav,
) -> Result<(), gman_status> {
    if blob_too_long(blob_len) {
        return Err(GMAN_ERR_BLOB);
    }
    let (b, o, p) = (Span::of(blob, blob_len), Span::one(out), Span::one(opts));
    // The blob, the options and `*out` must lie outside the arena the caller gives.
    disjoint(Span::of(arena, arena_len), &[b, p], &[o])?;
    // SAFETY: forwarded from the caller.
    let out = unsafe { out_ref(out) }?;
    *out = ptr::null_mut();
    // SAFETY: forwarded from the caller.
    let opts = unsafe { read_options(opts) }?;
    if arena.is_null() {
        return Err(GMAN_ERR_NULL);
    }
    let parse = parse_options(&opts)?;
    // SAFETY: forwarded from the caller. The weights borrow the blob for as long as the
    // caller keeps the handle, which the API's contract makes the caller guarantee ('static
    // stands for "as long as the handle is used").
    let (blob, mut info) = unsafe { parse_blob::<'static>(blob, blob_len, parse) }?;
    let need = usize::try_from(info.arena_bytes).map_err(|_| GMAN_ERR_CONFIG)?;
    if arena_len < need {
        return Err(GMAN_ERR_ARENA_TOO_SMALL);
    }
    let used = Span::of(arena, need);
    let cfg = init_config(&blob, &opts)?;
    let dims = blob.dims();
    let weights = NavWeights::from_blob(&blob, &dims).map_err(|e| status_of(&e))?;
    let mode = info.settings.adapt_mode;
    // Every check of the settings before the arena is written: a refused call leaves a live
    // navigator in this arena untouched.
    match mode {
        0 => Navigator::<'static, Efficient, K>::check_settings(&weights, &cfg),
        _ => Navigator::<'static, Full, K>::check_settings(&weights, &cfg),
    }
    .map_err(|e| status_of(&e))?;
    // SAFETY: `arena` is non-null and the caller's `arena_len >= need` bytes there are
    // writable and exclusively ours while the handle is used; `need` is the blob's
    // `arena_bytes`, which counts the alignment pad and the handle's bytes.
    let (hp, ram) = unsafe { carve_arena(arena, need) };
    // SAFETY: `hp` is `carve_arena`'s handle region, aligned and inside the arena.
    let nav = unsafe { start_navigator(hp, mode, weights, ram, cfg) }?;
    info.arena_bytes = need as u64;
    info.settings = settings_of(&cfg.model);
    // SAFETY: as above; nothing else refers to the handle region.
    unsafe { write_handle(hp, used, info, nav) };
    *out = hp as *mut gman_nav;
    Ok(())
}

/// The run-time options at `opts` (NULL: the defaults; a misaligned pointer is
/// [`GMAN_ERR_ALIGNMENT`]).
///
/// # Safety
/// A non-null `opts` must be readable.
pub(crate) unsafe fn read_options(opts: *const gman_options) -> Result<gman_options, gman_status> {
    if opts.is_null() {
        Ok(gman_options::default())
    } else if !opts.is_aligned() {
        Err(GMAN_ERR_ALIGNMENT)
    } else {
        // SAFETY: non-null, aligned, readable per the caller; plain integers.
        Ok(unsafe { ptr::read(opts) })
    }
}

/// How `gman_init` parses the blob under `opts` (`require_header_crc` is 0 or 1, else
/// [`GMAN_ERR_CONFIG`]).
pub(crate) fn parse_options(opts: &gman_options) -> Result<ParseOptions, gman_status> {
    Ok(ParseOptions {
        require_header_crc: match opts.require_header_crc {
            0 => false,
            1 => true,
            _ => return Err(GMAN_ERR_CONFIG),
        },
    })
}

/// The first `need` bytes of `arena` as the handle's region (at the first 16-byte aligned
/// address) and the navigator's floats after its [`GMAN_HANDLE_BYTES`], zeroed.
///
/// # Safety
/// `arena` non-null and writable for `need` bytes, exclusively ours for as long as the handle
/// is used; `need` at least `GMAN_ARENA_ALIGN + GMAN_HANDLE_BYTES` (a blob's `arena_bytes`).
pub(crate) unsafe fn carve_arena(arena: *mut u8, need: usize) -> (*mut Handle, &'static mut [f32]) {
    let pad = (GMAN_ARENA_ALIGN - (arena as usize) % GMAN_ARENA_ALIGN) % GMAN_ARENA_ALIGN;
    let floats = (need - GMAN_ARENA_ALIGN - GMAN_HANDLE_BYTES) / 4;
    // SAFETY: `pad + GMAN_HANDLE_BYTES + 4 * floats <= need`, so both regions lie inside
    // the `need` bytes of the caller's arena, which it guarantees writable and exclusively
    // ours.
    let (hp, fp) = unsafe {
        let base = arena.add(pad);
        (base as *mut Handle, base.add(GMAN_HANDLE_BYTES) as *mut f32)
    };
    // SAFETY: the float region is 16-byte aligned (base is, GMAN_HANDLE_BYTES is a multiple
    // of 16), inside the arena, disjoint from the handle region; zeroed before the slice is
    // made so every element is an initialised f32.
    let ram: &'static mut [f32] = unsafe {
        ptr::write_bytes(fp, 0, floats);
        core::slice::from_raw_parts_mut(fp, floats)
    };
    (hp, ram)
}

/// The navigator over `weights` in `ram`, in the blob's adaptation mode (`mode` 0:
/// Efficient, else Full). A refusal poisons the handle region `hp`.
///
/// # Safety
/// `hp` aligned for a `Handle` and inside the caller's arena, which is ours.
pub(crate) unsafe fn start_navigator(
    hp: *mut Handle,
    mode: u32,
    weights: NavWeights<'static>,
    ram: &'static mut [f32],
    cfg: NavConfig,
) -> Result<Nav, gman_status> {
    let nav = match mode {
        0 => Navigator::new(weights, ram, cfg).map(Nav::Efficient),
        _ => Navigator::new(weights, ram, cfg).map(Nav::Full),
    };
    match nav {
        Ok(n) => Ok(n),
        Err(e) => {
            // Not reached (the checks in `init` are Navigator::new's): a navigator that lived
            // in this arena lost its state, so its handle must not run.
            // SAFETY: `hp` is aligned and inside the arena, which is ours; only the first
            // field's 8 bytes are written.
            unsafe { ptr::write(ptr::addr_of_mut!((*hp).magic), POISONED) };
            Err(status_of(&e))
        }
    }
}

/// Writes the complete handle of `nav` (its `info`, the arena bytes it uses `arena`, the
/// message "no error") at `hp`.
///
/// # Safety
/// `hp` aligned for a `Handle`, with `GMAN_HANDLE_BYTES` bytes of the caller's arena at it
/// that are ours.
pub(crate) unsafe fn write_handle(hp: *mut Handle, arena: Span, info: gman_info, nav: Nav) {
    let mut msg = [0u8; MSG_LEN];
    set_msg(&mut msg, format_args!("no error"));
    // SAFETY: `hp` is aligned (16 >= align_of::<Handle>()) and GMAN_HANDLE_BYTES >=
    // size_of::<Handle>() bytes of the arena are ours; `ptr::write` does not read the old
    // contents. The magic is part of the value written, so a reader only ever sees it on a
    // complete handle.
    unsafe {
        ptr::write(
            hp,
            Handle {
                magic: MAGIC,
                arena,
                info,
                msg,
                nav,
            },
        )
    };
}

/// The navigator configuration of `blob` with the run-time options `opts`.
pub(crate) fn init_config(blob: &Blob<'_>, opts: &gman_options) -> Result<NavConfig, gman_status> {
    let mut cfg = NavConfig::from_header(blob.header());
    cfg.selection = match opts.selection {
        0 => Selection::Greedy,
        1 => Selection::Sample,
        _ => return Err(GMAN_ERR_CONFIG),
    };
    cfg.schedule = match opts.schedule {
        0 => Schedule::Auto,
        1 => Schedule::Manual,
        2 => Schedule::Background,
        _ => return Err(GMAN_ERR_CONFIG),
    };
    let requested = opts.settings.commit_delay;
    let others = gman_settings {
        commit_delay: 0,
        ..opts.settings
    };
    if others != gman_settings::default() {
        return Err(GMAN_ERR_CONFIG);
    }
    let delay = &mut cfg.model.inner_rule.commit_delay;
    *delay = commit_delay(*delay, requested)?;
    Ok(cfg)
}

/// The commit delay a navigator runs at: the blob's `recorded` one, or the `requested` one
/// when the blob records none (0 requests nothing).
pub(crate) fn commit_delay(recorded: u32, requested: u32) -> Result<u32, gman_status> {
    if requested > gman_core::spec::schema::MAX_COMMIT_DELAY {
        return Err(GMAN_ERR_CONFIG);
    }
    match (recorded, requested) {
        (r, 0) => Ok(r),
        (0, q) => Ok(q),
        (r, q) if r == q => Ok(r),
        _ => Err(GMAN_ERR_CONFIG),
    }
}
