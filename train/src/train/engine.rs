//! The rollout engine: one worker's share of an update, `B` training episodes in lockstep
//! (`--batch-envs B`), the policy's forward and backward passes over them as matrices
//! (`Policy::forward_batch`, `Policy::backward_batch` on gman-core's batched kernels). Every
//! training episode runs here: `B = 1`, the methods without an inner loop and the
//! second-order meta-gradient are cases of it.
//!
//! ```text
//! while a slot is free and the worker's step budget is not spent: start episode e in it
//! every tick:
//!   each running episode: observation, PS input, map; its x_t = G_θi(SE(y), z_t)   (line 7)
//!     (G of all of them as one batch)
//!   one batched policy forward over the running episodes                        (line 8)
//!   each episode: its action (its own actor head, its own generator), the environment
//!     steps, the step recorded (lines 9-13)
//!   the episodes whose segment is complete (k = 20 steps, then a delayed update's commit
//!   window; or the episode ended):
//!     bootstrap values (one batched forward)
//!     their backward now (one batched BPTT over them, each row at the parameters it ran
//!       with), or they wait for one batched BPTT over the update
//!     then each of them (slot order): the episode ended -> its statistics and D, slot freed;
//!       else its inner update (lines 14-20)
//! at the end of the update: one batched BPTT over the waiting segments
//! ```
//!
//! **Two kinds of lanes** (`lanes::Lanes`) carry the episodes; the loop above is the same for both:
//! * `lanes_shared.rs`, the methods without an inner loop in training (`a3c`,
//!   `a3c-fg`, `gman-noemd`, ...): θ and φ stay at the outer parameters for the whole
//!   update, so the episodes share one set of parameter views (from a gman-core navigator
//!   over the model) and each keeps the navigator's per-episode state.
//! * `lanes_nav.rs`, the methods with an inner loop (`gman`, ...): each episode runs
//!   on its own gman-core [`Navigator`](gman_core::navigator::Navigator) (the device's code,
//!   in the model's adaptation mode), whose step is split around the batched trunk.
//!
//! Either way **each episode is bit for bit the episode the navigator runs alone** (same
//! actions, probabilities, rewards, inner updates): the batched kernels give every row the
//! bits of the batch-1 kernels (`tests/engine.rs`, `tests/tests/navigator.rs`).
//!
//! **When a segment's backward runs.** A segment's A3C gradient is taken at the parameters
//! it ran with (first-order meta-gradient: the gradient at the adapted parameters is summed
//! into that of the pre-adaptation ones).
//! * It **waits** (`B > 1` and `Lanes::segments_can_wait`) when the parameters cannot
//!   change under it or can be copied cheaply: without an inner loop (one set of
//!   parameters), and in the Efficient mode (the adapted parameters are the per-unit gains
//!   and biases of the actor head and of G, ~1.5k floats for `mcu`; a waiting segment keeps
//!   a copy, `OwnCopy`).
//!   All the update's waiting segments then join one batched BPTT at its end (or earlier,
//!   whenever `lockstep::MAX_PENDING_STEPS` steps wait), longest first, then in the order they
//!   completed (tick, then slot).
//! * Otherwise (the Full mode, whose θ_i is all of G; and `B = 1`) the segments completing
//!   at a tick run **now**, as one batched BPTT (longest first, then by slot), each row
//!   through its episode's live views, before the episode's inner update.
//!
//! Within a BPTT every tensor's gradient is summed step by step (last step first) and, within
//! a step, over the rows in order. The order is fixed by `(seed, update, worker, B)`, so runs
//! are reproducible and resume bit for bit; with `B > 1` the sum is the per-episode sum
//! within float rounding (`tests/engine.rs` checks 1e-4 of each tensor's largest value;
//! this module's tests pin the order).
//!
//! **The second-order meta-gradient** (`--meta-order 2`, `B = 1`, Full mode): each
//! segment's gradient is taken into a buffer of its own, its θ, φ parts kept with the
//! episode's inner steps, and at the end of the episode [`super::meta`]'s reverse recursion
//! adds them through the inner SGD steps.
//!
//! **Episodes per update.** A worker starts episodes (`e = 0, 1, ..`, from `sample(e)`) while
//! it has taken fewer than `min_steps` steps in the update, and the update ends when all its
//! running episodes have ended; so an update holds at least `B` episodes per worker.

use anyhow::{bail, Result};
use gman_core::navigator::memory::AdaptMode;
use gman_core::navigator::{Efficient, Full, Selection};

use super::lanes::{Hooks, Job};
use super::lockstep::{check_batch_envs, without_inner_loop, Finished, VecSettings};
use super::rollout::Worker;
use crate::model::NavModel;
use crate::optim::params::ParamSet;
use crate::sim::{EpisodeSpec, World};

/// Runs one worker's share of an update with `s.batch_envs` environments in lockstep (see
/// the module docs): episodes `e = 0, 1, ..` from `sample(e)` (spec and step limit), the A3C
/// gradient of every segment accumulated into `grads`. Returns the finished episodes sorted
/// by index, each with D after it (empty when it is the model's ω, see `lockstep::Finished`).
pub fn run_worker(
    world: &World,
    model: &NavModel,
    s: &VecSettings<'_>,
    worker: &mut Worker,
    grads: &mut ParamSet,
    sample: impl FnMut(u32) -> Result<(EpisodeSpec, u32)>,
) -> Result<Vec<Finished>> {
    run_hooked(world, model, s, worker, grads, sample, Hooks::default())
}

/// [`run_worker`] with the tests' hooks.
pub(super) fn run_hooked(
    world: &World,
    model: &NavModel,
    s: &VecSettings<'_>,
    worker: &mut Worker,
    grads: &mut ParamSet,
    sample: impl FnMut(u32) -> Result<(EpisodeSpec, u32)>,
    hooks: Hooks<'_>,
) -> Result<Vec<Finished>> {
    check_settings(model, s)?;
    let job = Job {
        world,
        model,
        s,
        grads,
        sample,
        hooks,
    };
    match (without_inner_loop(model), model.spec.adapt_mode) {
        (true, AdaptMode::Full) => super::lanes_shared::run::<Full, _>(job, worker),
        (true, AdaptMode::Efficient) => super::lanes_shared::run::<Efficient, _>(job, worker),
        (false, AdaptMode::Full) => super::lanes_nav::run::<Full, _>(job, worker),
        (false, AdaptMode::Efficient) => super::lanes_nav::run::<Efficient, _>(job, worker),
    }
}

/// The settings the engine refuses.
fn check_settings(model: &NavModel, s: &VecSettings<'_>) -> Result<()> {
    if !(1..=2).contains(&s.meta_order) {
        bail!("--meta-order must be 1 or 2, not {}", s.meta_order);
    }
    check_batch_envs(model, s.batch_envs, s.meta_order)?;
    if model.privileged && model.method.adapts_in_training() {
        bail!("the privileged-feature bound replaces G's output and cannot adapt G; use it with a method without inner loop (a3c-fg)");
    }
    if model.nav_config(true).selection != Selection::Sample {
        bail!("training episodes need a sampling navigator");
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::Method;
    use crate::model::K;
    use crate::pretrain::generator::init_generator;
    use crate::sim::EpisodeSpec;
    use crate::sim::RewardKind;
    use crate::train::a3c::A3cConfig;
    use crate::train::a3c::Objective;
    use crate::train::bptt::Segment;
    use crate::train::bptt::{Adapted, Backward, GenBufs, Widths};
    use crate::train::lanes::{Pending, TickLog};
    use gman_core::navigator::Navigator;
    use gman_core::nets::generator::Generator;
    use gman_core::nn::dense::Dense;
    use gman_core::nn::matrix::MatRef;
    use gman_core::rng::Xoshiro128;
    use gman_core::Dims;
    use gman_core::NUM_ACTIONS;
    use rand::SeedableRng;
    use rand_chacha::ChaCha8Rng;

    /// The deferred backward's order, pinned: the gradient of a `B > 1` update is that of
    /// one batched BPTT over all the update's segments sorted by length (longest first),
    /// then by the order they completed — and that order matters (the same segments one at
    /// a time give other bits).
    #[test]
    fn the_update_is_one_backward_over_its_segments_longest_first() {
        let world = World::synthetic(7);
        let d = Dims::MCU;
        let g = init_generator(&d, &mut Xoshiro128::seed_from_u64(5)).unwrap();
        for method in [Method::A3cFg, Method::GmanNoemd] {
            let mut model = NavModel::init(method, d, 3, Some(&g), None).unwrap();
            model.spec.adapt_mode = AdaptMode::Efficient;
            let a3c = A3cConfig::default();
            let s = VecSettings {
                batch_envs: 6,
                min_steps: 60,
                reward: RewardKind::Mixed,
                a3c: &a3c,
                objective: Objective::A3c,
                meta_order: 1,
            };
            let sample = |e: u32| -> Result<(EpisodeSpec, u32)> {
                let mut rng = ChaCha8Rng::seed_from_u64(900 + e as u64);
                Ok((world.try_sample_train_episode_min(&mut rng, 1)?, 45))
            };
            let run = |keep: Option<&mut Vec<Pending>>| {
                let mut grads = model.params.zeros_like();
                let mut worker = Worker::new(&model);
                let hooks = Hooks { keep, log: None };
                let done =
                    run_hooked(&world, &model, &s, &mut worker, &mut grads, sample, hooks).unwrap();
                (grads, done)
            };
            let (got, done) = run(None);
            // D is the model's ω: no copy of it per episode.
            assert!(done.iter().all(|f| f.2.is_empty()));
            let mut segs = Vec::new();
            let (none, _) = run(Some(&mut segs));
            assert!(
                none.bits().iter().all(|&b| b == 0),
                "nothing flushed before the end"
            );
            assert!(
                done.len() >= 6 && segs.len() >= done.len(),
                "{}",
                segs.len()
            );
            let lens: Vec<usize> = segs.iter().map(|p| p.steps.len()).collect();
            assert!(
                lens.iter().any(|&l| l != lens[0]),
                "segments of several lengths"
            );
            // The documented order, computed here.
            segs.sort_by_key(|p| (std::cmp::Reverse(p.steps.len()), p.seq));
            let weights = model.weights().unwrap();
            let mut arena = vec![0.0; crate::model::host_arena_len(&d)];
            let mut nav: Navigator<'_, Efficient, K> =
                Navigator::new(weights, &mut arena, model.nav_config(true)).unwrap();
            nav.reset(&vec![0.0; d.attr], 0).unwrap();
            let (policy, gen) = (nav.policy().unwrap(), nav.generator().unwrap());
            let w = Widths::of(&policy, &d);
            let train_g = method.trains_generator();
            fn seg(p: &Pending) -> Segment<'_> {
                Segment {
                    steps: &p.steps,
                    acts: &p.acts,
                    attr: &p.attr,
                    bootstrap: p.bootstrap,
                    own: None,
                }
            }
            let backward = |segs: &[Segment<'_>], grads: &mut ParamSet| {
                let mut gb = GenBufs::new(&gen, w.f);
                Backward::default()
                    .run(&policy, &gen, segs, &a3c, train_g, &w, &d, grads, &mut gb)
                    .unwrap();
            };
            let mut want = model.params.zeros_like();
            let all: Vec<Segment<'_>> = segs.iter().map(seg).collect();
            backward(&all, &mut want);
            assert_eq!(
                got.bits(),
                want.bits(),
                "{}: the pinned order",
                method.name()
            );
            // The rows given their own heads and G, all equal to the shared ones (the per-row
            // path of methods with an inner loop: heads row by row, then the trunk): the
            // same bits as the shared batched pass.
            let mut rows_own = model.params.zeros_like();
            let own: Vec<Segment<'_>> = segs
                .iter()
                .map(|p| Segment {
                    own: Some(crate::train::bptt::Adapted {
                        actor: policy.actor,
                        gen,
                    }),
                    ..seg(p)
                })
                .collect();
            backward(&own, &mut rows_own);
            assert_eq!(
                rows_own.bits(),
                want.bits(),
                "{}: per-row heads",
                method.name()
            );
            // One segment at a time (completion order): a different sum of the same terms.
            segs.sort_by_key(|p| p.seq);
            let mut one = model.params.zeros_like();
            for p in &segs {
                backward(&[seg(p)], &mut one);
            }
            assert_ne!(got.bits(), one.bits(), "{}: order-sensitive", method.name());
        }
    }

    type Copy3 = (Vec<f32>, Vec<f32>, Option<Vec<f32>>);

    /// A dense view over a copy, on the kernels of `like`.
    fn view<'a>(c: &'a Copy3, shape: (usize, usize), like: &MatRef<'_>) -> Dense<'a> {
        Dense {
            w: MatRef::f32(shape.0, shape.1, &c.0)
                .unwrap()
                .kernels_from(like),
            b: &c.1,
            gain: c.2.as_deref(),
        }
    }

    /// The order of a `B > 1` update, pinned: its gradient is, tick by tick, one batched
    /// BPTT over the segments completing at the tick (longest first, then by slot), each
    /// row at its own episode's adapted actor head and G (recomputed here from copies of
    /// them). Both matter: the same segments one at a time, or at the shared (unadapted)
    /// parameters, give other bits.
    #[test]
    fn each_tick_is_one_backward_over_its_segments_at_their_own_parameters() {
        let world = World::synthetic(7);
        let d = Dims::MCU;
        let g = init_generator(&d, &mut Xoshiro128::seed_from_u64(5)).unwrap();
        for mode in [AdaptMode::Efficient, AdaptMode::Full] {
            let mut model = NavModel::init(Method::Gman, d, 3, Some(&g), None).unwrap();
            model.spec.adapt_mode = mode;
            model.spec.inner_lr = 0.05;
            model.params.get_mut("ActorB").unwrap().data[gman_core::Action::Done.index()] -= 1.5;
            let a3c = A3cConfig::default();
            let s = VecSettings {
                batch_envs: 8,
                min_steps: 300,
                reward: RewardKind::Mixed,
                a3c: &a3c,
                objective: Objective::A3c,
                meta_order: 1,
            };
            let sample = |e: u32| -> Result<(EpisodeSpec, u32)> {
                let mut rng = ChaCha8Rng::seed_from_u64(900 + e as u64);
                Ok((world.try_sample_train_episode_min(&mut rng, 1)?, 45))
            };
            let mut got = model.params.zeros_like();
            let mut worker = Worker::new(&model);
            let mut log = Vec::new();
            let hooks = Hooks {
                keep: None,
                log: Some(&mut log),
            };
            let done =
                run_hooked(&world, &model, &s, &mut worker, &mut got, sample, hooks).unwrap();
            assert!(done.iter().filter(|f| f.1.adaptations > 0).count() >= 3);
            // Efficient: one backward for the update (copies of the gains and biases);
            // Full: one per tick that completes segments.
            match mode {
                AdaptMode::Efficient => assert_eq!(log.len(), 1),
                AdaptMode::Full => assert!(log.len() > 5, "{}", log.len()),
            }
            assert!(
                log.iter()
                    .any(|t| t.segs.len() >= 2
                        && t.segs.iter().any(|s| s.0.len() != t.segs[0].0.len())),
                "a tick completes segments of several lengths"
            );
            // The rows' parameters differ (adapted episodes).
            assert!(log
                .iter()
                .flat_map(|t| &t.params)
                .any(|p| p[0] != log[0].params[0][0]));
            // The trunk and the shapes from a navigator over the model.
            let weights = model.weights().unwrap();
            let mut nav_cfg = model.nav_config(true);
            nav_cfg.model.adapt = false;
            let mut arena = vec![0.0; Navigator::<Full, K>::arena_len(&d)];
            let mut nav: Navigator<'_, Full, K> =
                Navigator::new(weights, &mut arena, nav_cfg).unwrap();
            nav.reset(&vec![0.0; d.attr], 0).unwrap();
            let (trunk, gen0) = (nav.policy().unwrap(), nav.generator().unwrap());
            let mut w = Widths::of(&trunk, &d);
            // The actor's pre-gain output is kept when the episodes' heads have gains.
            w.au = if log[0].params[0][0].2.is_some() {
                NUM_ACTIONS
            } else {
                0
            };
            let shapes = [
                (trunk.actor.w.rows(), trunk.actor.w.cols()),
                (gen0.l1.w.rows(), gen0.l1.w.cols()),
                (gen0.l2.w.rows(), gen0.l2.w.cols()),
            ];
            let like = trunk.fuse.w;
            fn seg<'a>(
                t: &'a TickLog,
                k: usize,
                own: bool,
                shapes: &[(usize, usize); 3],
                like: &MatRef<'_>,
            ) -> Segment<'a> {
                let (steps, acts, attr, boot) = &t.segs[k];
                let p = &t.params[k];
                Segment {
                    steps,
                    acts,
                    attr,
                    bootstrap: *boot,
                    own: own.then(|| Adapted {
                        actor: view(&p[0], shapes[0], like),
                        gen: Generator {
                            l1: view(&p[1], shapes[1], like),
                            l2: view(&p[2], shapes[2], like),
                        },
                    }),
                }
            }
            let seg = |t, k, own| seg(t, k, own, &shapes, &like);
            // G's buffers sized as the episodes' G (with gains in the Efficient mode).
            let p0 = &log[0].params[0];
            let gen_rows = Generator {
                l1: view(&p0[1], shapes[1], &like),
                l2: view(&p0[2], shapes[2], &like),
            };
            let backward = |segs: &[Segment<'_>], grads: &mut ParamSet| {
                let mut gb = GenBufs::new(&gen_rows, w.f);
                Backward::default()
                    .run(&trunk, &gen0, segs, &a3c, true, &w, &d, grads, &mut gb)
                    .unwrap();
            };
            let mut want = model.params.zeros_like();
            for t in &log {
                let segs: Vec<Segment<'_>> = (0..t.segs.len()).map(|k| seg(t, k, true)).collect();
                backward(&segs, &mut want);
            }
            assert_eq!(got.bits(), want.bits(), "{mode:?}: the pinned order");
            // One segment at a time: a different sum of the same terms.
            let mut one = model.params.zeros_like();
            for t in &log {
                for k in 0..t.segs.len() {
                    backward(&[seg(t, k, true)], &mut one);
                }
            }
            assert_ne!(got.bits(), one.bits(), "{mode:?}: order-sensitive");
            // At the unadapted parameters: another gradient.
            let mut shared = model.params.zeros_like();
            for t in &log {
                let segs: Vec<Segment<'_>> = (0..t.segs.len()).map(|k| seg(t, k, false)).collect();
                backward(&segs, &mut shared);
            }
            assert_ne!(got.bits(), shared.bits(), "{mode:?}: per-row parameters");
        }
    }
}
