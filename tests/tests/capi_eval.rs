//! The C API in closed loop: an evaluation agent that drives the simulator through
//! `gman_init` / `gman_reset` / `gman_step` (with the options `gman eval` runs a blob with:
//! sampled actions, the automatic inner update) must take the same actions as `gman eval`'s
//! own agent on the same val episodes, so every episode's metrics (success, path length,
//! SPL, exploration area, distance to success, reward) are identical.

use std::ptr::{null, null_mut};
use std::sync::Arc;

use gman_ffi::*;
use gman_host_sim::eval::agent::NavAgent;
use gman_host_sim::model::load_model;
use gman_host_sim::sim::spatial::MapGrid;
use gman_host_sim::sim::{
    evaluate, Agent, Env, EpisodeSpec, EvalConfig, Split, TargetInfo, World, DEFAULT_WORLD_SEED,
};

const MODEL: &str = concat!(
    env!("CARGO_MANIFEST_DIR"),
    "/../host-sim/models/gman-map3-b16-mcu-int8-seed5.gman"
);

/// An agent over the C API: a fresh navigator per episode in its own arena.
struct CApiAgent {
    blob: Arc<Vec<u8>>,
    info: gman_info,
    arena: Vec<u8>,
    map: Vec<f32>,
    steps: u64,
}

impl CApiAgent {
    fn new(blob: Arc<Vec<u8>>) -> Self {
        let mut info = gman_info::default();
        // SAFETY: valid pointers and lengths.
        assert_eq!(
            unsafe { gman_inspect(blob.as_ptr(), blob.len(), &mut info) },
            GMAN_OK
        );
        CApiAgent {
            arena: vec![0u8; info.arena_bytes as usize],
            map: vec![0.0; info.map_len as usize],
            blob,
            info,
            steps: 0,
        }
    }
}

impl Agent for CApiAgent {
    fn begin_episode(&mut self, _env: &Env<'_>, _target: &TargetInfo) {}
    fn act(&mut self, _env: &Env<'_>) -> gman_core::Action {
        // Never called: `run_episode` drives the episode through the C API.
        gman_core::Action::Done
    }
    fn run_episode(&mut self, env: &mut Env<'_>, spec: &EpisodeSpec) {
        let opts = gman_options {
            selection: 1, // sampled, as `gman eval` runs
            schedule: 0,
            require_header_crc: 0,
            settings: gman_settings::default(),
        };
        let mut nav = null_mut();
        // SAFETY: the blob and the arena outlive the handle (both owned by self, unmoved
        // during the episode).
        let s = unsafe {
            gman_init(
                self.blob.as_ptr(),
                self.blob.len(),
                self.arena.as_mut_ptr().cast(),
                self.arena.len(),
                &opts,
                &mut nav,
            )
        };
        assert_eq!(s, GMAN_OK);
        let attr = env.world().attributes(spec.target);
        // SAFETY: a live handle and a valid slice.
        assert_eq!(
            unsafe { gman_reset(nav, attr.as_ptr(), attr.len(), spec.seed) },
            GMAN_OK
        );
        let grid = MapGrid {
            rows: self.info.map_rows as usize,
            cols: self.info.map_cols as usize,
        };
        while !env.is_done() {
            let obs = env.observe();
            env.observe_map(grid, &mut self.map);
            let mut out = gman_step_out::default();
            // SAFETY: a live handle, valid slices, a writable output.
            let s = unsafe {
                gman_step(
                    nav,
                    obs.features.as_ptr(),
                    obs.features.len(),
                    self.map.as_ptr(),
                    self.map.len(),
                    null(),
                    0,
                    &mut out,
                )
            };
            assert_eq!(s, GMAN_OK);
            self.steps += 1;
            env.step(gman_core::Action::from_index(out.action as usize).expect("action"));
        }
    }
}

#[test]
fn c_api_agent_matches_gman_eval_on_val_episodes() {
    let world = World::synthetic(DEFAULT_WORLD_SEED);
    let episodes: Vec<_> = world
        .episodes(Split::Val, Some(2))
        .expect("val episodes")
        .into_iter()
        .take(24)
        .collect();
    assert!(episodes.len() >= 8, "{} val episodes", episodes.len());
    let cfg = EvalConfig::default();
    let model = Arc::new(load_model(std::path::Path::new(MODEL), None).expect("model"));
    let rust = evaluate(
        &world,
        &episodes,
        |_| Box::new(NavAgent::new(model.clone())),
        &cfg,
    );
    let blob = Arc::new(std::fs::read(MODEL).expect("blob"));
    let c = evaluate(
        &world,
        &episodes,
        |_| Box::new(CApiAgent::new(blob.clone())),
        &cfg,
    );
    let mut steps = 0;
    for (r, c) in rust.iter().zip(&c) {
        assert!(r.error.is_none(), "gman eval: {:?}", r.error);
        assert_eq!(r.metrics, c.metrics, "episode {} ({})", r.index, r.scene);
        steps += r.metrics.path_length;
    }
    assert_eq!(rust.len(), c.len());
    let sr = rust.iter().filter(|r| r.metrics.success).count();
    eprintln!(
        "{} val episodes, {steps} steps, {sr} successes: identical through the C API",
        episodes.len()
    );
    // The episodes are long enough to run inner updates (k = 20).
    assert!(
        steps as usize > 20 * episodes.len() / 2,
        "{steps} steps in {} episodes",
        episodes.len()
    );
}
