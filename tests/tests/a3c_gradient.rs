//! The A3C loss gradient of the trainer (`gman_host_sim::nav::a3c::segment_backward`, BPTT
//! through gman-core's policy and generator kernels) against central finite differences of
//! the same loss computed by the independent f64 reference, on a tiny network.

use gman_core::blob::TensorId;
use gman_core::matrix::MatRef;
use gman_core::navigator::{Full, NavConfig, NavWeights, Navigator, Schedule, Selection};
use gman_core::rng::{fill_gaussian, uniform, Xoshiro128};
use gman_core::Dims;
use gman_host_sim::nav::a3c::{output_grads, segment_backward, A3cConfig};
use gman_host_sim::nav::rollout::StepRec;
use gman_host_sim::train::params::{Param, ParamSet};
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
};

fn params(seed: u64) -> ParamSet {
    let mut rng = Xoshiro128::seed_from_u64(seed);
    let mut set = ParamSet::new();
    for &id in TensorId::ALL {
        let (r, c) = id.shape(&TINY);
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

/// The surrogate loss of the segment in f64 as a function of a flat parameter vector for one
/// tensor `name` (the others fixed): policy term with the advantages held fixed (`adv`),
/// entropy and value terms recomputed.
#[allow(clippy::too_many_arguments)]
fn loss64(
    p: &ParamSet,
    name: &str,
    flat: &[f64],
    seg: &[StepRec],
    attr: &[f64],
    adv: &[f64],
    rets: &[f64],
    cfg: &A3cConfig,
) -> f64 {
    let get = |n: &str| -> Vec<f64> {
        if n == name {
            flat.to_vec()
        } else {
            f64s(&p.tensor(n).unwrap().data)
        }
    };
    let dense = |w: &str, b: &str, id: TensorId| {
        let (rows, cols) = id.shape(&TINY);
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
    let lstm = Lstm64 {
        input: TINY.embed,
        hidden: TINY.lstm_hidden,
        wx: get("LstmWx"),
        wh: get("LstmWh"),
        b: get("LstmB"),
    };
    let actor = dense("ActorW", "ActorB", TensorId::ActorW);
    let critic = dense("CriticW", "CriticB", TensorId::CriticW);
    let (mut h, mut c) = (f64s(&seg[0].h_prev), f64s(&seg[0].c_prev));
    let mut loss = 0.0;
    for (t, s) in seg.iter().enumerate() {
        let obs = f64s(&s.obs);
        let x = gen.forward(&f64s(&s.z), attr);
        let mut inp = obs.clone();
        inp.extend(&x);
        inp.extend(obs.iter().zip(&x).map(|(a, b)| a * b));
        inp.extend(attr);
        inp.extend(f64s(&s.prev_probs));
        inp.extend(f64s(&s.ps));
        let e: Vec<f64> = fuse.forward(&inp).into_iter().map(lrelu).collect();
        let (hn, cn) = lstm.step(&e, &h, &c);
        h = hn;
        c = cn;
        let logits = actor.forward(&h);
        let m = logits.iter().cloned().fold(f64::NEG_INFINITY, f64::max);
        let lse = m + logits.iter().map(|l| (l - m).exp()).sum::<f64>().ln();
        let logp: Vec<f64> = logits.iter().map(|l| l - lse).collect();
        let ent: f64 = -logp.iter().map(|l| l.exp() * l).sum::<f64>();
        let v = critic.forward(&h)[0];
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
    check_segment_gradient(false);
}

/// The DAgger objective (cross-entropy to the oracle's action distribution) through the same
/// BPTT code.
#[test]
fn imitation_segment_gradient_matches_finite_differences() {
    check_segment_gradient(true);
}

fn check_segment_gradient(imitation: bool) {
    let p = params(1);
    let weights = NavWeights::from_fn(&TINY, |id| {
        let (r, c) = id.shape(&TINY);
        MatRef::f32(r, c, &p.tensor(id.name()).unwrap().data).unwrap()
    })
    .unwrap();
    let cfg = NavConfig {
        schedule: Schedule::Manual,
        selection: Selection::Sample,
        ..NavConfig::default()
    };
    let mut arena = vec![0.0f32; Navigator::<Full, 20>::arena_len(&TINY)];
    let mut nav: Navigator<'_, Full, 20> = Navigator::new(weights, &mut arena, cfg).unwrap();
    let attr = [0.3f32, 0.8, 0.1];
    nav.reset(&attr, 5).unwrap();
    let mut rng = Xoshiro128::seed_from_u64(9);
    let mut seg = Vec::new();
    for _ in 0..6 {
        let obs: Vec<f32> = (0..TINY.feat).map(|_| uniform(&mut rng)).collect();
        let ps: Vec<f32> = (0..TINY.ps).map(|_| uniform(&mut rng)).collect();
        let (h_prev, c_prev, prev_probs) = (
            nav.hidden_state().to_vec(),
            nav.cell_state().to_vec(),
            nav.prev_probs().to_vec(),
        );
        let out = nav.step(&obs, &ps).unwrap();
        seg.push(StepRec {
            obs,
            ps,
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
    let v_of = {
        let get = |n: &str| base(n);
        let d = |w: &str, b: &str, id: TensorId| {
            let (rows, cols) = id.shape(&TINY);
            Dense64 {
                rows,
                cols,
                w: get(w),
                b: get(b),
                gain: None,
            }
        };
        let gen = Gen64 {
            l1: d("GenW1", "GenB1", TensorId::GenW1),
            l2: d("GenW2", "GenB2", TensorId::GenW2),
        };
        let fuse = d("FuseW", "FuseB", TensorId::FuseW);
        let lstm = Lstm64 {
            input: TINY.embed,
            hidden: TINY.lstm_hidden,
            wx: get("LstmWx"),
            wh: get("LstmWh"),
            b: get("LstmB"),
        };
        let critic = d("CriticW", "CriticB", TensorId::CriticW);
        let (mut h, mut c) = (f64s(&seg[0].h_prev), f64s(&seg[0].c_prev));
        let mut vs = Vec::new();
        for s in &seg {
            let obs = f64s(&s.obs);
            let x = gen.forward(&f64s(&s.z), &attr64);
            let mut inp = obs.clone();
            inp.extend(&x);
            inp.extend(obs.iter().zip(&x).map(|(a, b)| a * b));
            inp.extend(&attr64);
            inp.extend(f64s(&s.prev_probs));
            inp.extend(f64s(&s.ps));
            let e: Vec<f64> = fuse.forward(&inp).into_iter().map(lrelu).collect();
            let (hn, cn) = lstm.step(&e, &h, &c);
            h = hn;
            c = cn;
            vs.push(critic.forward(&h)[0]);
        }
        vs
    };
    let adv: Vec<f64> = rets.iter().zip(&v_of).map(|(r, v)| r - v).collect();
    for name in [
        "FuseW", "FuseB", "LstmWx", "LstmWh", "LstmB", "ActorW", "ActorB", "CriticW", "CriticB",
        "GenW1", "GenB1", "GenW2", "GenB2",
    ] {
        let fd = finite_diff(&base(name), 1e-6, |v| {
            loss64(&p, name, v, &seg, &attr64, &adv, &rets, &a3c)
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
