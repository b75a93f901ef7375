//! The body of the `blob_parse` fuzz target, shared with the stable loop test
//! `core/tests/fuzz_loop.rs` (which runs it without cargo-fuzz): the blob decoder must
//! return `Ok` or a typed `Err` for any bytes, a blob that parses must have non-degenerate
//! dims whose sizes fit and usable tensor views, and navigators built from it (both
//! adaptation modes, with the configuration the blob asks for and with `Schedule::Manual`)
//! must run steps, adaptations and more than `K` manual steps without a panic.

use gman_core::blob::{Blob, TensorId};
use gman_core::navigator::memory::{try_arena_len, AdaptMode};
use gman_core::navigator::{Efficient, Full, Mode, NavConfig, NavWeights, Navigator, Schedule};

/// Largest arena the target allocates (floats), so that a blob with big but valid dims does
/// not make the fuzzer run out of memory.
const MAX_ARENA: usize = 1 << 22;

/// Builds navigators of mode `M` and capacity `K` over `blob` and drives them.
pub fn run<M: Mode, const K: usize>(blob: &Blob<'_>, cfg: NavConfig, obs_fill: f32) {
    let dims = blob.dims();
    let Ok(w) = NavWeights::from_blob(blob, &dims) else {
        return;
    };
    let n = Navigator::<M, K>::arena_len(&dims);
    if n > MAX_ARENA {
        return;
    }
    let mut arena = vec![0.0f32; n];
    let Ok(mut nav) = Navigator::<M, K>::new(w, &mut arena, cfg) else {
        return;
    };
    let attr = vec![0.5f32; dims.attr];
    let obs = vec![obs_fill; dims.feat];
    let ps = vec![0.1f32; dims.ps];
    if dims.map_len() > MAX_ARENA {
        return;
    }
    let map = vec![obs_fill * 0.5; dims.map_len()];
    if nav.reset(&attr, 7).is_err() {
        return;
    }
    // More than K steps: under `Manual` the (K+1)-th must be refused, not panic.
    for _ in 0..(2 * K + 1) {
        let _ = nav.step(&obs, &ps);
    }
    if dims.map_cells() > 0 {
        for _ in 0..(K + 1) {
            let _ = nav.step_map(&obs, &map, &ps);
        }
    }
    let _ = nav.adapt_now();
    let _ = nav.step(&obs, &ps);
    nav.clear_buffer();
    let _ = nav.step(&obs, &ps);
}

/// Checks one input (panics on a violated property, which the fuzzer reports).
pub fn check(data: &[u8]) {
    if let Ok(blob) = Blob::parse(data) {
        let dims = blob.dims();
        assert!(dims.checked_sizes(), "parsed dims must have sizes that fit");
        assert_eq!(
            dims.degenerate_field(),
            None,
            "parsed dims must not be degenerate"
        );
        assert!(try_arena_len(&dims, AdaptMode::Full, 20).is_some());
        let _ = blob.check_dims(&gman_core::Dims::MCU);
        for t in blob.tensors() {
            let m = t.matrix().expect("validated tensor must form a matrix");
            assert_eq!((m.rows(), m.cols()), t.id.shape(&dims));
        }
        let mut buf = [0.0f32; 64];
        for id in TensorId::all_for(&dims) {
            let _ = blob.copy_f32(id, &mut buf);
        }
        let auto = blob.nav_config();
        let manual = NavConfig {
            schedule: Schedule::Manual,
            ..auto
        };
        let fill = data.last().map_or(0.25, |&b| (b as f32 - 128.0) / 64.0);
        run::<Efficient, 20>(&blob, auto, fill);
        run::<Full, 20>(&blob, auto, fill);
        run::<Efficient, 3>(&blob, manual, fill);
        run::<Full, 3>(&blob, manual, fill);
    }
}
