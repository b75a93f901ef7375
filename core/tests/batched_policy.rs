//! The batched policy passes (`Policy::forward_batch`, `Policy::backward_batch`) against the
//! batch-1 ones, bit for bit: every step of a batch gets the bits of `Policy::forward` alone,
//! and the parameter gradients equal those of `Policy::backward` called for each step in
//! batch order. Covered: with and without the spatial map, with and without an actor gain,
//! f32 and int8 fusion weights, PS input present and absent.

mod common;
use common::vals;
use gman_core::nets::policy::{
    Policy, PolicyCache, PolicyGrads, PolicyInput, PolicyInputGrads, PolicyScratch,
};
use gman_core::nn::dense::{Dense, DenseGrads};
use gman_core::nn::lstm::{Lstm, LstmGrads};
use gman_core::nn::matrix::{MatRef, Scales};
use gman_core::NUM_ACTIONS;

const F: usize = 5;
const A: usize = 3;
const E: usize = 7;
const H: usize = 4;
const CE: usize = 2;
const N: usize = 3;

struct Params {
    fuse_w: Vec<f32>,
    fuse_q: Vec<u8>,
    fuse_s: Vec<f32>,
    fuse_b: Vec<f32>,
    wx: Vec<f32>,
    wh: Vec<f32>,
    lb: Vec<f32>,
    aw: Vec<f32>,
    ab: Vec<f32>,
    ag: Vec<f32>,
    cw: Vec<f32>,
    cb: Vec<f32>,
    cellw: Vec<f32>,
    cellb: Vec<f32>,
}

fn params(fuse_in: usize) -> Params {
    Params {
        fuse_w: vals(E * fuse_in, 1),
        fuse_q: vals(E * fuse_in, 2)
            .iter()
            .map(|v| ((v * 120.0) as i8) as u8)
            .collect(),
        fuse_s: vals(E, 3).iter().map(|v| 0.01 + v.abs() * 0.01).collect(),
        fuse_b: vals(E, 4),
        wx: vals(4 * H * E, 5),
        wh: vals(4 * H * H, 6),
        lb: vals(4 * H, 7),
        aw: vals(NUM_ACTIONS * H, 8),
        ab: vals(NUM_ACTIONS, 9),
        ag: vals(NUM_ACTIONS, 10)
            .iter()
            .map(|v| 1.0 + 0.3 * v)
            .collect(),
        cw: vals(H, 11),
        cb: vals(1, 12),
        cellw: vals(CE * 2 * F, 13),
        cellb: vals(CE, 14),
    }
}

struct Grads(Vec<Vec<f32>>);

impl Grads {
    fn new(fuse_in: usize) -> Grads {
        let sizes = [
            E * fuse_in,
            E,
            4 * H * E,
            4 * H * H,
            4 * H,
            NUM_ACTIONS * H,
            NUM_ACTIONS,
            H,
            1,
            CE * 2 * F,
            CE,
        ];
        Grads(sizes.iter().map(|&s| vec![0.0; s]).collect())
    }
    fn view(&mut self, gain: bool, map: bool) -> PolicyGrads<'_> {
        let [fw, fb, wx, wh, lb, aw, ab, cw, cb, clw, clb] = &mut self.0[..] else {
            unreachable!()
        };
        PolicyGrads {
            fuse: DenseGrads::Full { w: fw, b: fb },
            lstm: Some(LstmGrads { wx, wh, b: lb }),
            actor: if gain {
                // the adapted per-unit gain and bias (Efficient mode)
                DenseGrads::Gain {
                    gain: &mut aw[..NUM_ACTIONS],
                    b: ab,
                }
            } else {
                DenseGrads::Full { w: aw, b: ab }
            },
            critic: DenseGrads::Full { w: cw, b: cb },
            cell: if map {
                DenseGrads::Full { w: clw, b: clb }
            } else {
                DenseGrads::None
            },
        }
    }
}

/// The seven scratch buffers of a backward pass (`PolicyScratch`'s fields, in order).
type ScratchBufs = (
    Vec<f32>,
    Vec<f32>,
    Vec<f32>,
    Vec<f32>,
    Vec<f32>,
    Vec<f32>,
    Vec<f32>,
);

/// A `PolicyScratch` over `b` (without the x_t-gradient buffer when `dprod` is false).
fn scratch(b: &mut ScratchBufs, dprod: bool) -> PolicyScratch<'_> {
    PolicyScratch {
        de: &mut b.0,
        dgates: &mut b.1,
        dprod: if dprod { &mut b.2 } else { &mut [] },
        tmp: &mut b.3,
        dh: &mut b.4,
        dcell: &mut b.5,
        cell_tmp: &mut b.6,
    }
}

fn bits(v: &[f32]) -> Vec<u32> {
    v.iter().map(|x| x.to_bits()).collect()
}

/// `act8`: the int8 matrices (fusion, and the map's cell layer) run on int8 activations
/// (the cell layer then through `qkernel::cell_layer_int8`).
fn check(map: bool, gain: bool, int8: bool, act8: bool, ps: usize) {
    let cells = if map { 3 } else { 0 };
    let fuse_in = 3 * F + A + NUM_ACTIONS + ps + cells * CE;
    let p = params(fuse_in);
    let fuse_w = if int8 {
        let m = MatRef::i8(E, fuse_in, &p.fuse_q, Scales::F32(&p.fuse_s)).unwrap();
        if act8 {
            m.with_int8_activations()
        } else {
            m
        }
    } else {
        MatRef::f32(E, fuse_in, &p.fuse_w).unwrap()
    };
    let cell_q: Vec<u8> = p.cellw.iter().map(|v| ((v * 120.0) as i8) as u8).collect();
    let cell_s = vec![0.01f32; CE];
    let cell_w = if act8 {
        MatRef::i8(CE, 2 * F, &cell_q, Scales::F32(&cell_s))
            .unwrap()
            .with_int8_activations()
    } else {
        MatRef::f32(CE, 2 * F, &p.cellw).unwrap()
    };
    let policy = Policy {
        fuse: Dense {
            w: fuse_w,
            b: &p.fuse_b,
            gain: None,
        },
        lstm: Lstm {
            wx: MatRef::f32(4 * H, E, &p.wx).unwrap(),
            wh: MatRef::f32(4 * H, H, &p.wh).unwrap(),
            b: &p.lb,
        },
        actor: Dense {
            w: MatRef::f32(NUM_ACTIONS, H, &p.aw).unwrap(),
            b: &p.ab,
            gain: gain.then_some(&p.ag[..]),
        },
        critic: Dense {
            w: MatRef::f32(1, H, &p.cw).unwrap(),
            b: &p.cb,
            gain: None,
        },
        cell: map.then(|| Dense {
            w: cell_w,
            b: &p.cellb,
            gain: None,
        }),
    };
    // A batch of N independent steps.
    let obs = vals(N * F, 20);
    let feat: Vec<f32> = vals(N * F, 21).iter().map(|v| v.abs()).collect();
    let attr = vals(N * A, 22);
    let prev = vals(N * NUM_ACTIONS, 23);
    let psv = vals(N * ps, 24);
    let mapv = vals(N * cells * F, 25);
    let h_prev = vals(N * H, 26);
    let c_prev = vals(N * H, 27);
    let dlogits = vals(N * NUM_ACTIONS, 28);
    let dvalue = vals(N, 29);
    let dh_next = vals(N * H, 30);
    let dc_next = vals(N * H, 31);
    let au = if gain { NUM_ACTIONS } else { 0 };

    // Batched.
    let mut bc = (
        vec![0.0; N * F],
        vec![0.0; N * E],
        vec![0.0; N * 4 * H],
        vec![0.0; N * H],
        vec![0.0; N * H],
        vec![0.0; N * au],
        vec![0.0; N * NUM_ACTIONS],
        vec![0.0; N * NUM_ACTIONS],
        vec![0.0; N],
        vec![0.0; N * cells * CE],
        vec![0.0; N * cells * F],
    );
    let mut cache = PolicyCache {
        prod: &mut bc.0,
        fuse: &mut bc.1,
        gates: &mut bc.2,
        c: &mut bc.3,
        h: &mut bc.4,
        actor_u: &mut bc.5,
        logits: &mut bc.6,
        probs: &mut bc.7,
        value: &mut bc.8,
        cell: &mut bc.9,
        cell_prod: &mut bc.10,
    };
    let inp = PolicyInput {
        obs: &obs,
        feat: &feat,
        attr: &attr,
        prev_probs: &prev,
        ps: &psv,
        map: &mapv,
    };
    policy
        .forward_batch(N, &inp, &h_prev, &c_prev, &mut cache)
        .unwrap();
    let mut g_batch = Grads::new(fuse_in);
    let mut dfeat_b = vals(N * F, 40);
    let (mut dhp_b, mut dcp_b) = (vec![0.0; N * H], vec![0.0; N * H]);
    let mut sb = (
        vec![0.0; N * E],
        vec![0.0; N * 4 * H],
        vec![0.0; N * F],
        vec![0.0; N * E.max(NUM_ACTIONS)],
        vec![0.0; N * H],
        vec![0.0; N * cells * CE],
        vec![0.0; N * cells * F],
    );
    {
        let mut gv = g_batch.view(gain, map);
        let mut out = PolicyInputGrads {
            feat: &mut dfeat_b,
            h_prev: &mut dhp_b,
            c_prev: &mut dcp_b,
        };
        let mut s = scratch(&mut sb, true);
        policy
            .backward_batch(
                N, &inp, &h_prev, &c_prev, &cache, &dlogits, &dvalue, &dh_next, &dc_next, &mut gv,
                &mut out, &mut s,
            )
            .unwrap();
    }

    // A dc_next one row short is refused before anything is written: the heads' gradients
    // (accumulated first) stay zero.
    let mut g_short = Grads::new(fuse_in);
    {
        let mut gv = g_short.view(gain, map);
        let (mut dhp, mut dcp) = (vec![0.0; N * H], vec![0.0; N * H]);
        let mut dfeat = vec![0.0; N * F];
        let mut out = PolicyInputGrads {
            feat: &mut dfeat,
            h_prev: &mut dhp,
            c_prev: &mut dcp,
        };
        let mut s = scratch(&mut sb, true);
        assert!(policy
            .backward_batch(
                N,
                &inp,
                &h_prev,
                &c_prev,
                &cache,
                &dlogits,
                &dvalue,
                &dh_next,
                &dc_next[..(N - 1) * H],
                &mut gv,
                &mut out,
                &mut s,
            )
            .is_err());
    }
    assert!(
        g_short.0.iter().flatten().all(|&v| v == 0.0),
        "a refused backward_batch wrote gradients"
    );

    // Without a buffer for ∂L/∂x_t (G not trained) every other gradient keeps its bits.
    let mut g_nofeat = Grads::new(fuse_in);
    {
        let mut gv = g_nofeat.view(gain, map);
        let (mut dhp, mut dcp) = (vec![0.0; N * H], vec![0.0; N * H]);
        let mut out = PolicyInputGrads {
            feat: &mut [],
            h_prev: &mut dhp,
            c_prev: &mut dcp,
        };
        let mut s = scratch(&mut sb, false);
        policy
            .backward_batch(
                N, &inp, &h_prev, &c_prev, &cache, &dlogits, &dvalue, &dh_next, &dc_next, &mut gv,
                &mut out, &mut s,
            )
            .unwrap();
        assert_eq!((bits(&dhp), bits(&dcp)), (bits(&dhp_b), bits(&dcp_b)));
    }
    for (i, (a, b)) in g_nofeat.0.iter().zip(&g_batch.0).enumerate() {
        assert_eq!(
            bits(a),
            bits(b),
            "gradient tensor {i} without the x_t gradient"
        );
    }

    // Batch 1, step by step in batch order.
    let mut g_one = Grads::new(fuse_in);
    let dfeat_init = vals(N * F, 40);
    for b in 0..N {
        let r = |v: &[f32], w: usize| v[b * w..(b + 1) * w].to_vec();
        let (o, x, at, pp, pv, mv) = (
            r(&obs, F),
            r(&feat, F),
            r(&attr, A),
            r(&prev, NUM_ACTIONS),
            r(&psv, ps),
            r(&mapv, cells * F),
        );
        let one = PolicyInput {
            obs: &o,
            feat: &x,
            attr: &at,
            prev_probs: &pp,
            ps: &pv,
            map: &mv,
        };
        let mut c1 = (
            vec![0.0; F],
            vec![0.0; E],
            vec![0.0; 4 * H],
            vec![0.0; H],
            vec![0.0; H],
            vec![0.0; au],
            vec![0.0; NUM_ACTIONS],
            vec![0.0; NUM_ACTIONS],
            vec![0.0; cells * CE],
            vec![0.0; if map { F } else { 0 }],
        );
        let mut value = [0.0f32];
        let mut pc = PolicyCache {
            prod: &mut c1.0,
            fuse: &mut c1.1,
            gates: &mut c1.2,
            c: &mut c1.3,
            h: &mut c1.4,
            actor_u: &mut c1.5,
            logits: &mut c1.6,
            probs: &mut c1.7,
            value: &mut value,
            cell: &mut c1.8,
            cell_prod: &mut c1.9,
        };
        let (hp, cp) = (r(&h_prev, H), r(&c_prev, H));
        policy.forward(&one, &hp, &cp, &mut pc).unwrap();
        assert_eq!(
            bits(pc.probs),
            bits(&bc.7[b * 6..b * 6 + 6]),
            "probs row {b}"
        );
        assert_eq!(pc.value[0].to_bits(), bc.8[b].to_bits(), "value row {b}");
        assert_eq!(bits(pc.h), bits(&bc.4[b * H..(b + 1) * H]));
        assert_eq!(
            bits(pc.cell),
            bits(&bc.9[b * cells * CE..(b + 1) * cells * CE])
        );
        let mut dfeat = r(&dfeat_init, F);
        let (mut dhp, mut dcp) = (vec![0.0; H], vec![0.0; H]);
        let mut s1 = (
            vec![0.0; E],
            vec![0.0; 4 * H],
            vec![0.0; F],
            vec![0.0; E.max(NUM_ACTIONS)],
            vec![0.0; H],
            vec![0.0; cells * CE],
            vec![0.0; cells * F],
        );
        let mut gv = g_one.view(gain, map);
        let mut out = PolicyInputGrads {
            feat: &mut dfeat,
            h_prev: &mut dhp,
            c_prev: &mut dcp,
        };
        let mut s = scratch(&mut s1, true);
        policy
            .backward(
                &one,
                &hp,
                &cp,
                &pc,
                &dlogits[b * 6..b * 6 + 6],
                dvalue[b],
                &r(&dh_next, H),
                &r(&dc_next, H),
                &mut gv,
                &mut out,
                &mut s,
            )
            .unwrap();
        assert_eq!(
            bits(&dfeat),
            bits(&dfeat_b[b * F..(b + 1) * F]),
            "dfeat row {b}"
        );
        assert_eq!(
            bits(&dhp),
            bits(&dhp_b[b * H..(b + 1) * H]),
            "dh_prev row {b}"
        );
        assert_eq!(
            bits(&dcp),
            bits(&dcp_b[b * H..(b + 1) * H]),
            "dc_prev row {b}"
        );
    }
    for (i, (a, b)) in g_batch.0.iter().zip(&g_one.0).enumerate() {
        assert_eq!(bits(a), bits(b), "gradient tensor {i}");
        if i < 9 || map {
            assert!(a.iter().any(|v| *v != 0.0), "tensor {i} got no gradient");
        }
    }
}

#[test]
fn batched_policy_matches_batch1_bit_for_bit() {
    for map in [false, true] {
        for gain in [false, true] {
            for (int8, act8) in [(false, false), (true, false), (true, true)] {
                for ps in [0, 2] {
                    check(map, gain, int8, act8, ps);
                }
            }
        }
    }
}

#[test]
fn batched_policy_rejects_bad_shapes() {
    let fuse_in = 3 * F + A + NUM_ACTIONS;
    let p = params(fuse_in);
    let policy = Policy {
        fuse: Dense {
            w: MatRef::f32(E, fuse_in, &p.fuse_w).unwrap(),
            b: &p.fuse_b,
            gain: None,
        },
        lstm: Lstm {
            wx: MatRef::f32(4 * H, E, &p.wx).unwrap(),
            wh: MatRef::f32(4 * H, H, &p.wh).unwrap(),
            b: &p.lb,
        },
        actor: Dense {
            w: MatRef::f32(NUM_ACTIONS, H, &p.aw).unwrap(),
            b: &p.ab,
            gain: None,
        },
        critic: Dense {
            w: MatRef::f32(1, H, &p.cw).unwrap(),
            b: &p.cb,
            gain: None,
        },
        cell: None,
    };
    let obs = vals(N * F, 1);
    let attr = vals(N * A, 2);
    let prev = vals(N * NUM_ACTIONS, 3);
    let hs = vals(N * H, 4);
    let mut bc = (
        vec![0.0; N * F],
        vec![0.0; N * E],
        vec![0.0; N * 4 * H],
        vec![0.0; N * H],
        vec![0.0; N * H],
        vec![0.0; N * NUM_ACTIONS],
        vec![0.0; N * NUM_ACTIONS],
        vec![0.0; N],
    );
    let mut cache = PolicyCache {
        prod: &mut bc.0,
        fuse: &mut bc.1,
        gates: &mut bc.2,
        c: &mut bc.3,
        h: &mut bc.4,
        actor_u: &mut [],
        logits: &mut bc.5,
        probs: &mut bc.6,
        value: &mut bc.7,
        cell: &mut [],
        cell_prod: &mut [],
    };
    // feat one row short
    let short = PolicyInput {
        obs: &obs,
        feat: &obs[..(N - 1) * F],
        attr: &attr,
        prev_probs: &prev,
        ps: &[],
        map: &[],
    };
    assert!(policy
        .forward_batch(N, &short, &hs, &hs, &mut cache)
        .is_err());
    // the state of another batch size
    let ok = PolicyInput {
        feat: &obs,
        ..short
    };
    assert!(policy
        .forward_batch(N, &ok, &hs[..H], &hs, &mut cache)
        .is_err());
    assert!(policy.forward_batch(N, &ok, &hs, &hs, &mut cache).is_ok());
}
