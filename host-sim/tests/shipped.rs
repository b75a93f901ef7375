//! Every model the repository ships loads and runs: the int8 blobs of `host-sim/models/` and
//! of `results/paper/models/` (the reference-budget runs; its PS variants with the PS module
//! kept beside them, `results/paper/ps/ps.ckpt`). Each loads as `gman eval` loads it
//! (header, CRC, every tensor, the method from its flags, the PS module) and then runs 45
//! steps of gman-core's navigator in its evaluation settings (two inner updates for the
//! models that adapt), every output finite.

use std::path::{Path, PathBuf};

use gman_core::navigator::memory::AdaptMode;
use gman_core::navigator::{Efficient, Full, Mode, Navigator};
use gman_host_sim::model::{load_model_with_ps, NavModel, K};

fn root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("..")
}

/// The `.gman` files of `dir`, sorted.
fn blobs(dir: &Path) -> Vec<PathBuf> {
    let mut v: Vec<PathBuf> = std::fs::read_dir(dir)
        .unwrap_or_else(|e| panic!("{}: {e}", dir.display()))
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|x| x == "gman"))
        .collect();
    v.sort();
    v
}

/// 45 evaluation steps of the model's navigator on seeded finite inputs; the number of
/// steps that ended with an inner update.
fn run<M: Mode>(m: &NavModel, name: &str) -> usize {
    let d = &m.dims;
    let mut arena = vec![0.0; m.arena_len()];
    let mut nav: Navigator<'_, M, K> =
        Navigator::new(m.weights().unwrap(), &mut arena, m.nav_config(false))
            .unwrap_or_else(|e| panic!("{name}: {e}"));
    let attr: Vec<f32> = (0..d.attr).map(|i| ((i * 7) % 5) as f32 * 0.2).collect();
    nav.reset(&attr, 3).unwrap();
    let map = vec![0.25; d.map_len()];
    let ps = vec![0.5; d.ps];
    let mut adapted = 0;
    for t in 0..45 {
        let obs: Vec<f32> = (0..d.feat)
            .map(|i| (((i * 31 + t * 17) % 97) as f32) / 97.0)
            .collect();
        let out = nav
            .step_map(&obs, &map, &ps)
            .unwrap_or_else(|e| panic!("{name}, step {t}: {e}"));
        assert!(
            out.value.is_finite() && out.probs.iter().all(|p| p.is_finite() && *p >= 0.0),
            "{name}, step {t}: {out:?}"
        );
        adapted += usize::from(out.adapted);
    }
    adapted
}

#[test]
fn every_shipped_blob_loads_and_runs() {
    let ps = root().join("results/paper/ps/ps.ckpt");
    let (mut n, mut adapting) = (0, 0);
    for dir in ["host-sim/models", "results/paper/models"] {
        for path in blobs(&root().join(dir)) {
            let name = path.display().to_string();
            let bytes = std::fs::read(&path).unwrap();
            let blob =
                gman_core::blob::Blob::parse(&bytes).unwrap_or_else(|e| panic!("{name}: {e}"));
            let with_ps = blob.dims().ps > 0;
            let m = load_model_with_ps(&path, None, with_ps.then_some(ps.as_path()))
                .unwrap_or_else(|e| panic!("{name}: {e:#}"));
            let adapted = match m.spec.adapt_mode {
                AdaptMode::Full => run::<Full>(&m, &name),
                AdaptMode::Efficient => run::<Efficient>(&m, &name),
            };
            if m.method.adapts_at_eval() {
                assert!(adapted >= 1, "{name}: no inner update in 45 steps");
                adapting += 1;
            } else {
                assert_eq!(adapted, 0, "{name}: an inner update without adaptation");
            }
            n += 1;
        }
    }
    // host-sim/models ships 24 blobs; results/paper/models one per finished run.
    assert!(n >= 24, "only {n} blobs found");
    // The GMAN blobs of host-sim/models alone: 5 gman, 3 gman-cossim, 1 pooled.
    assert!(adapting >= 9, "only {adapting} blobs adapt");
}
