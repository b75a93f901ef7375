//! Shared helpers of the integration tests.
#![allow(dead_code)]

use std::path::PathBuf;
use std::sync::OnceLock;

use gman_host_sim::sim::World;

/// `/work/shared/data/gman` located from the crate: `<workspace>/../shared/data/gman`.
pub fn data_dir() -> Option<PathBuf> {
    let p = PathBuf::from(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../../shared/data/gman"
    ));
    if p.join("attributes.json").is_file() {
        Some(p)
    } else {
        eprintln!("SKIPPED: GMAN data not found at {} (tests on the real floor plans need ../shared/data/gman)", p.display());
        None
    }
}

/// The real world, loaded once per test binary.
pub fn real_world() -> Option<&'static World> {
    static W: OnceLock<Option<World>> = OnceLock::new();
    W.get_or_init(|| data_dir().map(|d| World::load(&d).expect("load real world")))
        .as_ref()
}
