//! Fuzz target: see `body.rs` for the properties checked. Run (outside CI) with
//! `cargo fuzz run blob_parse` from `core/` (needs cargo-fuzz; on a stable toolchain set
//! `RUSTC_BOOTSTRAP=1`); on stable Rust alone, `core/tests/fuzz_loop.rs` runs the same body
//! over generated and mutated blobs.
#![no_main]

#[path = "body.rs"]
mod body;

use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    body::check(data);
});
