//! The rollout engine's lanes for the methods with an inner loop in training (`gman`,
//! `gman-cossim`, `gman-fixed-g`, `gman-ps`, ...): each episode runs on **its own gman-core
//! [`Navigator`]** (the device's code, in the mode the model records), its step split
//! around the engine's batched trunk:
//!
//! ```text
//! start: the slot's navigator: D from the model's ω, reset to θ, φ with the episode's seed
//! tick:  Navigator::begin_step_defer_g: x_t = G_θi(SE(y), z_t) from this episode's θ_i
//!          (in the Efficient mode G of all of them as one batch, Navigator::generate_batch)
//!        [the engine's batched trunk: fusion + LSTM, never adapted]
//!        Navigator::finish_step with its row's (h, c): its own adapted actor head, the
//!          critic, the action, Ψ (lines 8-13)
//! after a segment: Navigator::adapt_now, the inner update on its own Ψ (lines 14-20)
//! ```
//!
//! `begin_step` / `finish_step` are `step` split around the trunk (`tests/tests/navigator.rs`),
//! and the batched trunk gives every row the bits of the batch-1 one, so each episode is the
//! episode its navigator runs alone, bit for bit (actions, probabilities, inner updates, D
//! after it). A slot's navigator is reused across the slot's episodes: D is restored from the
//! model's ω and the navigator reset for each, the state a new navigator has. Every episode
//! starts from ω, and the outer step adds `Σ_e (ω_e − ω)` in episode order.
//!
//! **Whose parameters a segment's backward reads.** In the Efficient mode (the `mcu`
//! default) the adapted parameters are the per-unit gains and biases of the actor head and
//! of G's two layers, the matrices are the model's: with `B > 1` a complete segment keeps a
//! copy of them ([`OwnCopy`]) and waits for the update's batched BPTT, and G's activations
//! of every x_t are kept from the navigator's step (`Navigator::generator_activations`), so
//! the backward does not run G again. In the Full mode (the `paper` default) θ_i is all of G
//! (~154k floats for `mcu`), too large to copy per segment: the segments' backward runs at
//! once, each row through its navigator's live views, before that navigator's inner update.
//!
//! **Memory.** A worker holds `B` navigator arenas (`Navigator::arena_len_for` the host's
//! `Footprint::Fast`: 452 KiB each for `mcu` in the Efficient mode; in the Full mode each
//! holds a copy of G and D, 1.9 MiB for `mcu`), plus the waiting segments.

use anyhow::{bail, Result};
use gman_core::navigator::memory::AdaptMode;
use gman_core::navigator::{Mode, NavConfig, NavWeights, Navigator, NoiseMode};
use gman_core::nets::generator::Generator;
use gman_core::nets::policy::Policy;
use gman_core::spec::ModelSpec;
use gman_core::{Action, Dims, NUM_ACTIONS};

use super::bptt::{take_act, Adapted, GenBufs, Rows, Widths};
use super::inner::{finish_stats, inner_update, InnerTally};
use super::lanes::{drive, Job, LaneStep, Lanes, OwnCopy, Running};
use super::lockstep::{Finished, RowState};
use super::meta::{add_adapted, meta_backward, take_adapted, InnerSetup, InnerStep};
use super::rollout::{disc_after_episode, Worker};
use crate::model::episode::begin;
use crate::model::{NavModel, K};
use crate::optim::params::ParamSet;
use crate::sim::{EpisodeSpec, World};

/// What an episode keeps besides its navigator.
#[derive(Default)]
pub(super) struct NavEp {
    tally: InnerTally,
    // The navigator's state before this step.
    h_prev: Vec<f32>,
    c_prev: Vec<f32>,
    prev: Vec<f32>,
    /// Second order: each segment's θ, φ gradients and the inner steps between them.
    seg_grads: Vec<(Vec<f32>, Vec<f32>)>,
    inner_steps: Vec<Option<InnerStep>>,
}

/// The lanes of one navigator per slot.
struct PerNav<'a, 'f, M: Mode> {
    model: &'a NavModel,
    navs: Vec<Navigator<'a, M, K>>,
    /// The trunk and G of a navigator over the model's weights that does not adapt, for the
    /// waiting segments' backward.
    trunk: Policy<'f>,
    gen: Generator<'f>,
    w: Widths,
    d: Dims,
    second: bool,
    /// G ran in every begin_step (a new z_t each step): its activations are the step's.
    ran_g: bool,
    /// Slots whose x_t waits for the tick's batch.
    pending: Vec<usize>,
    gen_scratch: Vec<f32>,
}

/// The slots' navigators: `b` of them over the model, each in its own arena of `arenas`
/// (grown on first use).
fn slot_navigators<'a, M: Mode>(
    model: &NavModel,
    weights: NavWeights<'a>,
    cfg: NavConfig,
    arenas: &'a mut Vec<Vec<f32>>,
    b: usize,
) -> Result<Vec<Navigator<'a, M, K>>> {
    let alen = Navigator::<M, K>::arena_len_for(&model.dims, cfg.footprint);
    if arenas.len() < b {
        arenas.resize_with(b, Vec::new);
    }
    let mut navs: Vec<Navigator<'_, M, K>> = Vec::with_capacity(b);
    for a in arenas.iter_mut().take(b) {
        if a.len() < alen {
            a.resize(alen, 0.0);
        }
        navs.push(Navigator::new(weights, a, cfg)?);
    }
    Ok(navs)
}

/// The engine over one navigator per slot, in the adaptation mode `M`.
pub(super) fn run<M: Mode, F: FnMut(u32) -> Result<(EpisodeSpec, u32)>>(
    job: Job<'_, '_, '_, F>,
    worker: &mut Worker,
) -> Result<Vec<Finished>> {
    let (model, s) = (job.model, job.s);
    let second = s.meta_order == 2;
    if second && M::MODE != AdaptMode::Full {
        bail!("the second-order meta-gradient is implemented for the Full adaptation mode; use --adapt-mode full or --meta-order 1");
    }
    let cfg = model.nav_config(true);
    let weights = model.weights()?;
    let Worker { ps, arenas, .. } = worker;
    let navs = slot_navigators::<M>(model, weights, cfg, arenas, s.batch_envs)?;
    let d = *navs[0].dims();
    let w = Widths::of(&navs[0].policy()?, &d);
    let gbuf = GenBufs::new(&navs[0].generator()?, w.f);
    let mut fixed_arena =
        vec![0.0f32; Navigator::<M, K>::arena_len_for(&model.dims, cfg.footprint)];
    let fixed_nav: Navigator<'_, M, K> = Navigator::new(
        weights,
        &mut fixed_arena,
        NavConfig {
            model: ModelSpec {
                adapt: false,
                ..cfg.model
            },
            ..cfg
        },
    )?;
    let mut lanes = PerNav {
        model,
        navs,
        trunk: fixed_nav.policy()?,
        gen: fixed_nav.generator()?,
        w,
        d,
        second,
        ran_g: model.spec.noise == NoiseMode::Gaussian && !model.privileged,
        pending: Vec::new(),
        gen_scratch: Vec::new(),
    };
    drive(job, &mut lanes, gbuf, ps)
}

impl<'w, M: Mode> Lanes<'w> for PerNav<'_, '_, M> {
    type Ep = NavEp;

    fn widths(&self) -> &Widths {
        &self.w
    }

    fn dims(&self) -> &Dims {
        &self.d
    }

    fn start(&mut self, i: usize, world: &'w World, spec: &EpisodeSpec) -> Result<NavEp> {
        // The state of a new navigator over the model: D from ω, θ_i = θ, φ_i = φ, the
        // episode's seed.
        let nav = &mut self.navs[i];
        nav.reset_discriminator()?;
        begin(nav, world, spec, self.model)?;
        Ok(NavEp::default())
    }

    fn prepare(&mut self, i: usize, ep: &mut Running<'w, NavEp>) -> Result<()> {
        let nav = &mut self.navs[i];
        ep.lane.h_prev = nav.hidden_state().to_vec();
        ep.lane.c_prev = nav.cell_state().to_vec();
        ep.lane.prev = nav.prev_probs().to_vec();
        // Line 7: x_t from this episode's θ_i (here, or in the tick's batch).
        if nav.begin_step_defer_g(&ep.inp.obs, &ep.inp.map, &ep.inp.ps)? {
            self.pending.push(i);
        }
        Ok(())
    }

    fn generate(&mut self, _: &mut [Option<Running<'w, NavEp>>]) -> Result<()> {
        let need =
            Navigator::<M, K>::generate_batch_scratch_len(&self.model.dims, self.pending.len());
        if self.gen_scratch.len() < need {
            self.gen_scratch.resize(need, 0.0);
        }
        let r = Navigator::generate_batch(&mut self.navs, &self.pending, &mut self.gen_scratch);
        self.pending.clear();
        r.map_err(Into::into)
    }

    fn row<'s>(&'s self, i: usize, _: &'s Running<'w, NavEp>) -> RowState<'s> {
        let nav = &self.navs[i];
        RowState {
            feat: nav.generated_feature(),
            attr: nav.attr(),
            prev: nav.prev_probs(),
            h: nav.hidden_state(),
            c: nav.cell_state(),
        }
    }

    fn trunk(&self, i: usize) -> Result<Policy<'_>> {
        Ok(self.navs[i].policy()?)
    }

    fn act(
        &mut self,
        rows: &mut Rows,
        j: usize,
        i: usize,
        ep: &mut Running<'w, NavEp>,
    ) -> Result<(Action, [f32; NUM_ACTIONS])> {
        let hd = self.w.hd;
        let nav = &mut self.navs[i];
        let (h, c) = (&rows.h[j * hd..(j + 1) * hd], &rows.c[j * hd..(j + 1) * hd]);
        let out = nav.finish_step(&ep.inp.obs, h, c)?;
        row_heads(rows, j, &self.w, nav, &out.probs, out.value)?;
        Ok((out.action, out.probs))
    }

    fn after_act(
        &mut self,
        rows: &Rows,
        j: usize,
        i: usize,
        ep: &mut Running<'w, NavEp>,
        _: &[f32; NUM_ACTIONS],
    ) -> Result<LaneStep> {
        let nav = &self.navs[i];
        let mut act = take_act(rows, j, &self.w);
        if self.ran_g {
            // G's activations of this x_t, for the backward (instead of running G again).
            let (u1, h1, u2) = nav.generator_activations();
            act.gen = (u1.to_vec(), h1.to_vec(), u2.to_vec());
        }
        Ok(LaneStep {
            x: nav.generated_feature().to_vec(),
            z: nav.noise().to_vec(),
            h_prev: std::mem::take(&mut ep.lane.h_prev),
            c_prev: std::mem::take(&mut ep.lane.c_prev),
            prev_probs: std::mem::take(&mut ep.lane.prev),
            act,
        })
    }

    fn in_commit_window(&self, i: usize) -> bool {
        self.navs[i].in_commit_window()
    }

    fn segments_can_wait(&self) -> bool {
        M::MODE == AdaptMode::Efficient
    }

    fn own(&self, i: usize) -> Result<Option<OwnCopy>> {
        OwnCopy::of(&self.navs[i], &self.trunk, &self.gen).map(Some)
    }

    fn fixed(&self) -> Result<(Policy<'_>, Generator<'_>)> {
        Ok((self.trunk, self.gen))
    }

    fn live(&self, i: usize) -> Result<(Policy<'_>, Generator<'_>, Option<Adapted<'_>>)> {
        let nav = &self.navs[i];
        let (p, g) = (nav.policy()?, nav.generator()?);
        Ok((
            p,
            g,
            Some(Adapted {
                actor: p.actor,
                gen: g,
            }),
        ))
    }

    fn second_order(&self) -> bool {
        self.second
    }

    fn segment_grad(&mut self, ep: &mut NavEp, g: &mut ParamSet) -> Result<()> {
        ep.seg_grads.push(take_adapted(g)?);
        Ok(())
    }

    fn after_segment(&mut self, i: usize, ep: &mut Running<'w, NavEp>) -> Result<()> {
        // Lines 14-20: the inner update on Ψ, then Ψ emptied.
        let step = inner_update(&mut self.navs[i], self.second, &mut ep.lane.tally)?;
        if self.second {
            ep.lane.inner_steps.push(step);
        }
        Ok(())
    }

    fn finish(
        &mut self,
        i: usize,
        ep: Running<'w, NavEp>,
        grads: &mut ParamSet,
    ) -> Result<Finished> {
        let nav = &mut self.navs[i];
        if self.second {
            let l = &ep.lane;
            let (mt, mp) = meta_backward(&InnerSetup::of(nav), &l.inner_steps, &l.seg_grads)?;
            add_adapted(grads, &mt, &mp)?;
        }
        let mut stats = ep.stats;
        finish_stats(&mut stats, &ep.env, nav, &ep.lane.tally);
        // D learns from a buffer whose delayed update had not committed yet.
        nav.settle()?;
        Ok((ep.e, stats, disc_after_episode(nav)?))
    }
}

/// Row `j`'s heads at the episode's actor head, for the backward's activations (the bits
/// `finish_step` computed, `probs` and `value`: refused if they differ).
fn row_heads<M: Mode>(
    rows: &mut Rows,
    j: usize,
    w: &Widths,
    nav: &Navigator<'_, M, K>,
    probs_out: &[f32; NUM_ACTIONS],
    value_out: f32,
) -> Result<()> {
    let Rows {
        h,
        actor_u,
        logits,
        probs,
        value,
        ..
    } = rows;
    let (hd, au, na) = (w.hd, w.au, NUM_ACTIONS);
    nav.policy()?.heads(
        1,
        &h[j * hd..(j + 1) * hd],
        &mut actor_u[j * au..(j + 1) * au],
        &mut logits[j * na..(j + 1) * na],
        &mut probs[j * na..(j + 1) * na],
        &mut value[j..j + 1],
    )?;
    if probs[j * na..(j + 1) * na]
        .iter()
        .zip(probs_out)
        .any(|(a, b)| a.to_bits() != b.to_bits())
        || value[j].to_bits() != value_out.to_bits()
    {
        bail!("vectorised episode: the row's heads differ from the navigator's step");
    }
    Ok(())
}
