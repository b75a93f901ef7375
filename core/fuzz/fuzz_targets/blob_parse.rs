//! Fuzz target: the blob decoder must return `Ok` or a typed `Err` for any bytes, and a blob
//! that parses must yield usable tensor views. Run (outside CI) with
//! `cargo fuzz run blob_parse` from `core/` (needs cargo-fuzz; on a stable toolchain set
//! `RUSTC_BOOTSTRAP=1`).
#![no_main]

use gman_core::blob::{Blob, TensorId};
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    if let Ok(blob) = Blob::parse(data) {
        let dims = blob.dims();
        let _ = blob.check_dims(&gman_core::Dims::MCU);
        for t in blob.tensors() {
            let m = t.matrix().expect("validated tensor must form a matrix");
            assert_eq!((m.rows(), m.cols()), t.id.shape(&dims));
        }
        let mut buf = [0.0f32; 64];
        for id in TensorId::all_for(&dims) {
            let _ = blob.copy_f32(id, &mut buf);
        }
    }
});
