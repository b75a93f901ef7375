//! The batched environment: slots, the stepping context and the lockstep over every slot, with the GIL released.

use super::*;

/// One environment slot of a batch.
pub(crate) struct Slot {
    pub(crate) env: Env<'static>,
    pub(crate) spec: EpisodeSpec,
    pub(crate) rng: ChaCha8Rng,
    /// The episode ended at the last step: the next step resets it (next-step autoreset).
    pub(crate) needs_reset: bool,
}

/// Simulation state of a batch (no Python objects: it runs with the GIL released).
pub(crate) struct Sim {
    pub(crate) world: &'static World,
    pub(crate) split: Split,
    pub(crate) episodes: Vec<EpisodeSpec>,
    pub(crate) next_episode: usize,
    pub(crate) reward: RewardKind,
    pub(crate) limits: EpisodeLimits,
    pub(crate) grid: MapGrid,
    pub(crate) oracle: bool,
    /// Slots keep their episode's states (for `render`).
    pub(crate) record: bool,
    pub(crate) slots: Vec<Slot>,
    pub(crate) results: Vec<Option<EpisodeResult>>,
    pub(crate) recorded: usize,
}

/// Mutable views of the output arrays for one call.
pub(crate) struct Out<'a> {
    pub(crate) features: &'a mut [f32],
    pub(crate) target: &'a mut [f32],
    pub(crate) ps_target: &'a mut [f32],
    pub(crate) map: &'a mut [f32],
    pub(crate) reward: &'a mut [f32],
    pub(crate) terminated: &'a mut [bool],
    pub(crate) truncated: &'a mut [bool],
    pub(crate) success: &'a mut [bool],
    pub(crate) episode_start: &'a mut [bool],
    pub(crate) shortest_path: &'a mut [i32],
    pub(crate) target_category: &'a mut [i32],
    pub(crate) scene: &'a mut [i32],
    pub(crate) episode_index: &'a mut [i64],
    pub(crate) episode_seed: &'a mut [u64],
    pub(crate) steps: &'a mut [i32],
    pub(crate) oracle_action: &'a mut [i64],
}

/// Slots per rayon task when a training batch is stepped in parallel (below twice this, a
/// batch steps on the calling thread).
pub(crate) const PAR_CHUNK: usize = 64;

/// The read-only part of a batch, shared by the threads that step it.
#[derive(Clone, Copy)]
pub(crate) struct Ctx {
    pub(crate) world: &'static World,
    pub(crate) split: Split,
    pub(crate) reward: RewardKind,
    pub(crate) limits: EpisodeLimits,
    pub(crate) grid: MapGrid,
    pub(crate) oracle: bool,
    pub(crate) record: bool,
}

/// Splits every array of an [`Out`] after `mid` slots (a map of `map_len` floats per slot).
macro_rules! split_out {
    ($o:expr, $mid:expr, $map_len:expr) => {{
        let o = $o;
        let m = $mid;
        let (features1, features2) = o.features.split_at_mut(m * FEATURE_DIM);
        let (target1, target2) = o.target.split_at_mut(m * ATTR_DIM);
        let (ps1, ps2) = o.ps_target.split_at_mut(m * ATTR_DIM);
        let (map1, map2) = o.map.split_at_mut(m * $map_len);
        macro_rules! one {
            ($f:ident) => {
                o.$f.split_at_mut(m)
            };
        }
        let (reward1, reward2) = one!(reward);
        let (te1, te2) = one!(terminated);
        let (tr1, tr2) = one!(truncated);
        let (su1, su2) = one!(success);
        let (es1, es2) = one!(episode_start);
        let (sp1, sp2) = one!(shortest_path);
        let (tc1, tc2) = one!(target_category);
        let (sc1, sc2) = one!(scene);
        let (ei1, ei2) = one!(episode_index);
        let (sd1, sd2) = one!(episode_seed);
        let (st1, st2) = one!(steps);
        let (oa1, oa2) = one!(oracle_action);
        (
            Out {
                features: features1,
                target: target1,
                ps_target: ps1,
                map: map1,
                reward: reward1,
                terminated: te1,
                truncated: tr1,
                success: su1,
                episode_start: es1,
                shortest_path: sp1,
                target_category: tc1,
                scene: sc1,
                episode_index: ei1,
                episode_seed: sd1,
                steps: st1,
                oracle_action: oa1,
            },
            Out {
                features: features2,
                target: target2,
                ps_target: ps2,
                map: map2,
                reward: reward2,
                terminated: te2,
                truncated: tr2,
                success: su2,
                episode_start: es2,
                shortest_path: sp2,
                target_category: tc2,
                scene: sc2,
                episode_index: ei2,
                episode_seed: sd2,
                steps: st2,
                oracle_action: oa2,
            },
        )
    }};
}

impl Ctx {
    pub(crate) fn new_env(&self, spec: &EpisodeSpec) -> Env<'static> {
        let mut env = Env::new(
            self.world,
            spec,
            self.reward,
            self.limits.for_room(spec.room),
        );
        if self.record {
            env.record_trajectory(true);
        }
        env
    }

    /// Starts `spec` in slot `s` (index `i` of `out`) and writes its per-episode outputs and
    /// the zero reward and flags of a reset.
    pub(crate) fn begin(&self, s: &mut Slot, spec: EpisodeSpec, i: usize, out: &mut Out<'_>) {
        let env = self.new_env(&spec);
        let m = env.metrics();
        out.target[i * ATTR_DIM..(i + 1) * ATTR_DIM]
            .copy_from_slice(self.world.attributes(spec.target));
        out.shortest_path[i] = m.shortest_path_length.map_or(-1, |s| s as i32);
        out.target_category[i] = spec.target as i32;
        out.scene[i] = spec.scene as i32;
        out.episode_index[i] = if self.split == Split::Train {
            -1
        } else {
            spec.index as i64
        };
        out.episode_seed[i] = spec.seed;
        out.episode_start[i] = true;
        out.reward[i] = 0.0;
        out.terminated[i] = false;
        out.truncated[i] = false;
        out.success[i] = false;
        s.env = env;
        s.spec = spec;
        s.needs_reset = false;
    }

    /// Takes `action` in slot `s`; the episode's metrics when it ended.
    pub(crate) fn act(
        &self,
        s: &mut Slot,
        action: i64,
        i: usize,
        out: &mut Out<'_>,
    ) -> Option<EpisodeMetrics> {
        let a = Action::ALL[action as usize];
        let o = s.env.step(a);
        out.reward[i] = o.reward;
        out.success[i] = o.success;
        let term = o.done && a == Action::Done;
        out.terminated[i] = term;
        out.truncated[i] = o.done && !term;
        if o.done {
            s.needs_reset = true;
            Some(s.env.metrics())
        } else {
            None
        }
    }

    /// Writes the observation of slot `s`'s current state.
    pub(crate) fn observe(&self, s: &Slot, i: usize, out: &mut Out<'_>) {
        let env = &s.env;
        let obs = env.observe();
        out.features[i * FEATURE_DIM..(i + 1) * FEATURE_DIM].copy_from_slice(&obs.features);
        out.ps_target[i * ATTR_DIM..(i + 1) * ATTR_DIM].copy_from_slice(&obs.ps_target);
        let len = self.grid.len();
        if len > 0 {
            env.observe_map(self.grid, &mut out.map[i * len..(i + 1) * len]);
        }
        out.steps[i] = env.steps() as i32;
        if self.oracle {
            out.oracle_action[i] = env.oracle().optimal_action().index() as i64;
        }
    }

    /// One step of training slots (each samples its own next task from its own generator,
    /// so the result does not depend on how the slots are split between threads).
    pub(crate) fn step_train(
        &self,
        slots: &mut [Slot],
        actions: &[i64],
        mut out: Out<'_>,
    ) -> anyhow::Result<()> {
        if slots.len() >= 2 * PAR_CHUNK {
            let mid = slots.len() / 2;
            let (s1, s2) = slots.split_at_mut(mid);
            let (a1, a2) = actions.split_at(mid);
            let (o1, o2) = split_out!(out, mid, self.grid.len());
            let (r1, r2) = rayon::join(
                || self.step_train(s1, a1, o1),
                || self.step_train(s2, a2, o2),
            );
            return r1.and(r2);
        }
        for (i, (s, &action)) in slots.iter_mut().zip(actions).enumerate() {
            out.episode_start[i] = false;
            if s.needs_reset {
                let spec = self.world.try_sample_train_episode_min(&mut s.rng, 0)?;
                self.begin(s, spec, i, &mut out);
            } else {
                self.act(s, action, i, &mut out);
            }
            self.observe(s, i, &mut out);
        }
        Ok(())
    }
}

impl Sim {
    pub(crate) fn ctx(&self) -> Ctx {
        Ctx {
            world: self.world,
            split: self.split,
            reward: self.reward,
            limits: self.limits,
            grid: self.grid,
            oracle: self.oracle,
            record: self.record,
        }
    }

    pub(crate) fn next_spec(&mut self, slot: usize) -> anyhow::Result<EpisodeSpec> {
        if self.split == Split::Train {
            self.world
                .try_sample_train_episode_min(&mut self.slots[slot].rng, 0)
        } else {
            let n = self.episodes.len();
            let spec = self.episodes[self.next_episode % n].clone();
            self.next_episode += 1;
            Ok(spec)
        }
    }

    /// Starts a new episode in slot `i` (the next official one, or a sampled task).
    pub(crate) fn start(&mut self, i: usize, out: &mut Out<'_>) -> anyhow::Result<()> {
        let spec = self.next_spec(i)?;
        let ctx = self.ctx();
        ctx.begin(&mut self.slots[i], spec, i, out);
        Ok(())
    }

    pub(crate) fn record(&mut self, i: usize, metrics: EpisodeMetrics) {
        if self.split == Split::Train {
            return;
        }
        let spec = &self.slots[i].spec;
        let idx = spec.index;
        if idx < self.results.len() && self.results[idx].is_none() {
            self.results[idx] = Some(EpisodeResult {
                index: idx,
                scene: self.world.scenes[spec.scene].name.clone(),
                room: spec.room,
                kind: spec.kind,
                target: self.world.category_name(spec.target).to_string(),
                metrics,
                error: None,
            });
            self.recorded += 1;
        }
    }

    pub(crate) fn reset_all(
        &mut self,
        seed: Option<u64>,
        restart: bool,
        out: &mut Out<'_>,
    ) -> anyhow::Result<()> {
        if let Some(s) = seed {
            for (i, slot) in self.slots.iter_mut().enumerate() {
                slot.rng = ChaCha8Rng::seed_from_u64(s.wrapping_add(i as u64));
            }
        }
        if restart {
            self.next_episode = 0;
            self.results = vec![None; self.episodes.len()];
            self.recorded = 0;
        }
        let ctx = self.ctx();
        for i in 0..self.slots.len() {
            self.start(i, out)?;
            ctx.observe(&self.slots[i], i, out);
        }
        Ok(())
    }

    /// One step of every slot: training batches in parallel chunks, evaluation batches in
    /// slot order (the official episodes are handed out in that order).
    pub(crate) fn step_all(&mut self, actions: &[i64], out: &mut Out<'_>) -> anyhow::Result<()> {
        let ctx = self.ctx();
        if self.split == Split::Train {
            let o = Out {
                features: &mut *out.features,
                target: &mut *out.target,
                ps_target: &mut *out.ps_target,
                map: &mut *out.map,
                reward: &mut *out.reward,
                terminated: &mut *out.terminated,
                truncated: &mut *out.truncated,
                success: &mut *out.success,
                episode_start: &mut *out.episode_start,
                shortest_path: &mut *out.shortest_path,
                target_category: &mut *out.target_category,
                scene: &mut *out.scene,
                episode_index: &mut *out.episode_index,
                episode_seed: &mut *out.episode_seed,
                steps: &mut *out.steps,
                oracle_action: &mut *out.oracle_action,
            };
            return ctx.step_train(&mut self.slots, actions, o);
        }
        for (i, &action) in actions.iter().enumerate() {
            out.episode_start[i] = false;
            if self.slots[i].needs_reset {
                self.start(i, out)?;
            } else if let Some(m) = ctx.act(&mut self.slots[i], action, i, out) {
                self.record(i, m);
            }
            ctx.observe(&self.slots[i], i, out);
        }
        Ok(())
    }
}
