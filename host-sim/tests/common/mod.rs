//! Shared helpers of the integration tests.
#![allow(dead_code)]

pub mod scratch;

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

/// The real world under the `rule` object layout (the seeded placement), loaded once per
/// test binary.
pub fn real_world_rule() -> Option<&'static World> {
    static W: OnceLock<Option<World>> = OnceLock::new();
    W.get_or_init(|| {
        data_dir().map(|d| {
            World::load_with_layout(
                &d,
                gman_host_sim::sim::DEFAULT_WORLD_SEED,
                &Default::default(),
                gman_host_sim::sim::ObjectLayout::Rule,
            )
            .expect("load real world")
        })
    })
    .as_ref()
}

/// The real world (the default object layout), loaded once per test binary.
pub fn real_world() -> Option<&'static World> {
    static W: OnceLock<Option<World>> = OnceLock::new();
    W.get_or_init(|| data_dir().map(|d| World::load(&d).expect("load real world")))
        .as_ref()
}
