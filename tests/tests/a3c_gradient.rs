//! The A3C loss gradient of the trainer (`gman_host_sim::train::bptt::segment_backward`, BPTT
//! through gman-core's policy and generator kernels) against central finite differences of
//! the same loss computed by the independent f64 reference, on a tiny network.

use gman_core::blob::TensorId;
use gman_core::navigator::{Full, NavConfig, NavWeights, Navigator, Schedule, Selection};
use gman_core::nn::matrix::MatRef;
use gman_core::rng::{fill_gaussian, uniform, Xoshiro128};
use gman_core::Dims;
use gman_host_sim::optim::params::{Param, ParamSet};
use gman_host_sim::train::a3c::{output_grads, A3cConfig};
use gman_host_sim::train::bptt::segment_backward;
use gman_host_sim::train::step::StepRec;
use gman_tests::reference::{finite_diff, lrelu, rel_err, Dense64, Gen64, Lstm64};

const TINY: Dims = Dims {
    attr: 3,
    noise: 2,
    gen_hidden: 4,
    feat: 5,
    disc_hidden: 3,
    lstm_hidden: 3,
    embed: 4,
    ps: 3,
    map_rows: 0,
    map_cols: 0,
    cell_embed: 0,
};

fn params(dims: &Dims, seed: u64) -> ParamSet {
    let mut rng = Xoshiro128::seed_from_u64(seed);
    let mut set = ParamSet::new();
    for id in TensorId::all_for(dims) {
        let (r, c) = id.shape(dims);
        let mut p = Param::zeros(id.name(), r, c);
        fill_gaussian(&mut rng, &mut p.data);
        p.data.iter_mut().for_each(|v| *v *= 0.5);
        set.push(p).unwrap();
    }
    set
}

fn f64s(v: &[f32]) -> Vec<f64> {
    v.iter().map(|&x| x as f64).collect()
}

/// The f64 reference forward pass of the segment with tensor `name` replaced by `flat`:
/// per step the log-probabilities and the value.
fn forward64(
    p: &ParamSet,
    dims: &Dims,
    name: &str,
    flat: &[f64],
    seg: &[StepRec],
    attr: &[f64],
) -> Vec<(Vec<f64>, f64)> {
    let get = |n: &str| -> Vec<f64> {
        if n == name {
            flat.to_vec()
        } else {
            f64s(&p.tensor(n).unwrap().data)
        }
    };
    let dense = |w: &str, b: &str, id: TensorId| {
        let (rows, cols) = id.shape(dims);
        Dense64 {
            rows,
            cols,
            w: get(w),
            b: get(b),
            gain: None,
        }
    };
    let gen = Gen64 {
        l1: dense("GenW1", "GenB1", TensorId::GenW1),
        l2: dense("GenW2", "GenB2", TensorId::GenW2),
    };
    let fuse = dense("FuseW", "FuseB", TensorId::FuseW);
    let cell = (dims.map_cells() > 0).then(|| dense("CellW", "CellB", TensorId::CellW));
    let lstm = Lstm64 {
        input: dims.embed,
        hidden: dims.lstm_hidden,
        wx: get("LstmWx"),
        wh: get("LstmWh"),
        b: get("LstmB"),
    };
    let actor = dense("ActorW", "ActorB", TensorId::ActorW);
    let critic = dense("CriticW", "CriticB", TensorId::CriticW);
    let (mut h, mut c) = (f64s(&seg[0].h_prev), f64s(&seg[0].c_prev));
    let mut out = Vec::new();
    for s in seg {
        let obs = f64s(&s.obs);
        let x = gen.forward(&f64s(&s.z), attr);
        let mut inp = obs.clone();
        inp.extend(&x);
        inp.extend(obs.iter().zip(&x).map(|(a, b)| a * b));
        inp.extend(attr);
        inp.extend(f64s(&s.prev_probs));
        inp.extend(f64s(&s.ps));
        if let Some(cell) = &cell {
            // The shared per-cell layer on [M_c; M_c ⊙ x] for every map cell.
            for m in s.map.chunks_exact(dims.feat) {
                let m = f64s(m);
                let mut ci = m.clone();
                ci.extend(m.iter().zip(&x).map(|(a, b)| a * b));
                inp.extend(cell.forward(&ci).into_iter().map(lrelu));
            }
        }
        let e: Vec<f64> = fuse.forward(&inp).into_iter().map(lrelu).collect();
        let (hn, cn) = lstm.step(&e, &h, &c);
        h = hn;
        c = cn;
        let logits = actor.forward(&h);
        let m = logits.iter().cloned().fold(f64::NEG_INFINITY, f64::max);
        let lse = m + logits.iter().map(|l| (l - m).exp()).sum::<f64>().ln();
        let logp: Vec<f64> = logits.iter().map(|l| l - lse).collect();
        out.push((logp, critic.forward(&h)[0]));
    }
    out
}

/// The surrogate loss of the segment in f64 as a function of a flat parameter vector for one
/// tensor `name` (the others fixed): policy term with the advantages held fixed (`adv`),
/// entropy and value terms recomputed.
#[allow(clippy::too_many_arguments)]
fn loss64(
    p: &ParamSet,
    dims: &Dims,
    name: &str,
    flat: &[f64],
    seg: &[StepRec],
    attr: &[f64],
    adv: &[f64],
    rets: &[f64],
    cfg: &A3cConfig,
) -> f64 {
    let mut loss = 0.0;
    for (t, (s, (logp, v))) in seg
        .iter()
        .zip(forward64(p, dims, name, flat, seg, attr))
        .enumerate()
    {
        let ent: f64 = -logp.iter().map(|l| l.exp() * l).sum::<f64>();
        let policy = match &s.expert {
            // Imitation (DAgger): cross-entropy to the oracle's distribution, no entropy bonus.
            Some(e) => -e.iter().zip(&logp).map(|(&q, l)| q as f64 * l).sum::<f64>(),
            None => -logp[s.action] * adv[t] - cfg.entropy as f64 * ent,
        };
        loss += policy + cfg.value_coef as f64 * 0.5 * (rets[t] - v).powi(2);
    }
    loss
}

#[test]
fn a3c_segment_gradient_matches_finite_differences() {
    check_segment_gradient(&TINY, false);
}

/// The DAgger objective (cross-entropy to the oracle's action distribution) through the same
/// BPTT code.
#[test]
fn imitation_segment_gradient_matches_finite_differences() {
    check_segment_gradient(&TINY, true);
}

/// With a 2 x 2 spatial map: the per-cell layer's gradient, and its route into G through
/// `M_c ⊙ x_t`.
#[test]
fn spatial_map_segment_gradient_matches_finite_differences() {
    check_segment_gradient(&TINY.with_map(2, 2, 2), false);
    check_segment_gradient(&TINY.with_map(1, 3, 3), true);
}

fn check_segment_gradient(dims: &Dims, imitation: bool) {
    let p = params(dims, 1);
    let weights = NavWeights::from_fn(dims, |id| {
        let (r, c) = id.shape(dims);
        MatRef::f32(r, c, &p.tensor(id.name()).unwrap().data).unwrap()
    })
    .unwrap();
    let cfg = NavConfig {
        schedule: Schedule::Manual,
        selection: Selection::Sample,
        ..NavConfig::default()
    };
    let mut arena = vec![0.0f32; Navigator::<Full, 20>::arena_len(dims)];
    let mut nav: Navigator<'_, Full, 20> = Navigator::new(weights, &mut arena, cfg).unwrap();
    let attr = [0.3f32, 0.8, 0.1];
    nav.reset(&attr, 5).unwrap();
    let mut rng = Xoshiro128::seed_from_u64(9);
    let mut seg = Vec::new();
    for _ in 0..6 {
        let obs: Vec<f32> = (0..dims.feat).map(|_| uniform(&mut rng)).collect();
        let ps: Vec<f32> = (0..dims.ps).map(|_| uniform(&mut rng)).collect();
        let map: Vec<f32> = (0..dims.map_len()).map(|_| uniform(&mut rng)).collect();
        let (h_prev, c_prev, prev_probs) = (
            nav.hidden_state().to_vec(),
            nav.cell_state().to_vec(),
            nav.prev_probs().to_vec(),
        );
        let out = nav.step_map(&obs, &map, &ps).unwrap();
        seg.push(StepRec {
            obs,
            ps,
            map,
            x: nav.generated_feature().to_vec(),
            z: nav.noise().to_vec(),
            h_prev,
            c_prev,
            prev_probs,
            action: out.action.index(),
            reward: uniform(&mut rng) - 0.3,
            probs: out.probs,
            expert: imitation.then(|| {
                // A distribution over one or two "optimal" actions, as the oracle gives.
                let mut e = [0.0f32; 6];
                let a = (uniform(&mut rng) * 6.0) as usize % 6;
                let b = (a + 1 + (uniform(&mut rng) * 2.0) as usize) % 6;
                e[a] += 0.5;
                e[b] += 0.5;
                e
            }),
        });
    }
    let a3c = A3cConfig::default();
    let bootstrap = 0.4f32;
    let mut grads = p.zeros_like();
    segment_backward(&nav, &seg, bootstrap, &a3c, true, &mut grads).unwrap();

    // The returns R_t depend on rewards and bootstrap only: with all values 0 the trainer's
    // value gradient is c_v (0 − R_t).
    let (_, dv, _) = output_grads(&seg, &vec![0.0; seg.len()], bootstrap, &a3c);
    let rets: Vec<f64> = dv
        .iter()
        .map(|d| -(*d as f64) / a3c.value_coef as f64)
        .collect();
    // With τ = 1, GAE equals R_t − V_t; V_t at the unperturbed parameters from the f64 model.
    // The loss holds these advantages fixed (detached), as the trainer does.
    let attr64 = f64s(&attr);
    let base = |name: &str| f64s(&p.tensor(name).unwrap().data);
    let v_of: Vec<f64> = forward64(&p, dims, "", &[], &seg, &attr64)
        .into_iter()
        .map(|(_, v)| v)
        .collect();
    let adv: Vec<f64> = rets.iter().zip(&v_of).map(|(r, v)| r - v).collect();
    let mut names = vec![
        "FuseW", "FuseB", "LstmWx", "LstmWh", "LstmB", "ActorW", "ActorB", "CriticW", "CriticB",
        "GenW1", "GenB1", "GenW2", "GenB2",
    ];
    if dims.map_cells() > 0 {
        names.extend(["CellW", "CellB"]);
    }
    for name in names {
        let fd = finite_diff(&base(name), 1e-6, |v| {
            loss64(&p, dims, name, v, &seg, &attr64, &adv, &rets, &a3c)
        });
        let an = f64s(&grads.tensor(name).unwrap().data);
        let e = rel_err(&an, &fd, 1e-6);
        assert!(
            e < 1e-3,
            "{name}: relative error {e:.2e}\n analytic {an:?}\n fd {fd:?}"
        );
    }
    // The discriminator is not part of L_nav.
    assert!(grads
        .tensor("DiscW1")
        .unwrap()
        .data
        .iter()
        .all(|v| *v == 0.0));
}
