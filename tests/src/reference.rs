//! An f64 reference of GMAN's networks and losses, written independently of gman-core's
//! kernels (plain loops, no segments, no int8), for gradient and agreement tests.
//! Index loops are deliberate here: the reference reads like the equations.
#![allow(clippy::needless_range_loop)]

/// LeakyReLU slope.
pub const SLOPE: f64 = 0.2;

/// LeakyReLU(0.2).
pub fn lrelu(x: f64) -> f64 {
    if x > 0.0 {
        x
    } else {
        SLOPE * x
    }
}

/// Derivative of LeakyReLU(0.2).
pub fn lrelu_d(x: f64) -> f64 {
    if x > 0.0 {
        1.0
    } else {
        SLOPE
    }
}

/// Logistic sigmoid.
pub fn sigmoid(x: f64) -> f64 {
    1.0 / (1.0 + (-x).exp())
}

/// `W x` for a row-major `rows x cols` matrix.
pub fn matvec(w: &[f64], rows: usize, cols: usize, x: &[f64]) -> Vec<f64> {
    assert_eq!(w.len(), rows * cols);
    assert_eq!(x.len(), cols);
    (0..rows)
        .map(|i| (0..cols).map(|j| w[i * cols + j] * x[j]).sum())
        .collect()
}

/// A dense layer `gain ⊙ (W x) + b` in f64.
#[derive(Clone, Debug)]
pub struct Dense64 {
    /// Rows (outputs).
    pub rows: usize,
    /// Columns (inputs).
    pub cols: usize,
    /// Weights, row-major.
    pub w: Vec<f64>,
    /// Bias.
    pub b: Vec<f64>,
    /// Optional per-output gain.
    pub gain: Option<Vec<f64>>,
}

impl Dense64 {
    /// Forward pass.
    pub fn forward(&self, x: &[f64]) -> Vec<f64> {
        let u = matvec(&self.w, self.rows, self.cols, x);
        (0..self.rows)
            .map(|i| self.gain.as_ref().map_or(1.0, |g| g[i]) * u[i] + self.b[i])
            .collect()
    }
}

/// G in f64.
#[derive(Clone, Debug)]
pub struct Gen64 {
    /// Hidden layer (input `[z; attr]`).
    pub l1: Dense64,
    /// Output layer.
    pub l2: Dense64,
}

impl Gen64 {
    /// `G(attr, z)`.
    pub fn forward(&self, z: &[f64], attr: &[f64]) -> Vec<f64> {
        let mut inp = z.to_vec();
        inp.extend_from_slice(attr);
        let h: Vec<f64> = self.l1.forward(&inp).into_iter().map(lrelu).collect();
        self.l2.forward(&h).into_iter().map(sigmoid).collect()
    }
}

/// D in f64.
#[derive(Clone, Debug)]
pub struct Disc64 {
    /// Hidden layer.
    pub l1: Dense64,
    /// Output weights.
    pub w2: Vec<f64>,
    /// Output bias.
    pub b2: f64,
}

impl Disc64 {
    /// `D(x)`.
    pub fn score(&self, x: &[f64]) -> f64 {
        let pre = self.l1.forward(x);
        pre.iter()
            .zip(&self.w2)
            .map(|(p, w)| lrelu(*p) * w)
            .sum::<f64>()
            + self.b2
    }

    /// `∇_x D(x)`, by the chain rule written out (this is part of the penalty's *definition*;
    /// its parameter gradient is what the tests finite-difference).
    pub fn input_grad(&self, x: &[f64]) -> Vec<f64> {
        let pre = self.l1.forward(x);
        let mut g = vec![0.0; self.l1.cols];
        for j in 0..self.l1.rows {
            let u = self.w2[j] * lrelu_d(pre[j]) * self.l1.gain.as_ref().map_or(1.0, |g| g[j]);
            for (i, gi) in g.iter_mut().enumerate() {
                *gi += u * self.l1.w[j * self.l1.cols + i];
            }
        }
        g
    }

    /// L_D of Eq. 1 over paired rows of `real` and `fake` (each `n x F`).
    pub fn ld(
        &self,
        real: &[f64],
        fake: &[f64],
        eps: &[f64],
        lambda: f64,
        critic_scale: f64,
    ) -> f64 {
        let f = self.l1.cols;
        let n = eps.len();
        let (mut r, mut fk, mut p) = (0.0, 0.0, 0.0);
        for t in 0..n {
            let s = &real[t * f..(t + 1) * f];
            let x = &fake[t * f..(t + 1) * f];
            r += self.score(s) / n as f64;
            fk += self.score(x) / n as f64;
            let mix: Vec<f64> = s
                .iter()
                .zip(x)
                .map(|(a, b)| eps[t] * a + (1.0 - eps[t]) * b)
                .collect();
            let g = self.input_grad(&mix);
            let norm = g.iter().map(|v| v * v).sum::<f64>().sqrt();
            p += (norm - 1.0).powi(2) / n as f64;
        }
        critic_scale * (r - fk) - lambda * p
    }
}

/// L_ad (Eq. 3): `paper = true` for `−mean D(x_t) ‖a_t‖`, `false` for the reference form
/// `‖Σ_t a_t (−D(x_t))‖`.
pub fn adapt_loss(paper: bool, d: &[f64], probs: &[f64]) -> f64 {
    let n = d.len();
    if paper {
        (0..n)
            .map(|t| {
                let a = &probs[t * 6..(t + 1) * 6];
                -d[t] * a.iter().map(|v| v * v).sum::<f64>().sqrt() / n as f64
            })
            .sum()
    } else {
        let mut v = [0.0f64; 6];
        for t in 0..n {
            for k in 0..6 {
                v[k] -= probs[t * 6 + k] * d[t];
            }
        }
        v.iter().map(|x| x * x).sum::<f64>().sqrt()
    }
}

/// LSTM cell in f64; gate rows `[i f g o]`.
#[derive(Clone, Debug)]
pub struct Lstm64 {
    /// Input size.
    pub input: usize,
    /// Hidden size.
    pub hidden: usize,
    /// `4H x in`.
    pub wx: Vec<f64>,
    /// `4H x H`.
    pub wh: Vec<f64>,
    /// `4H`.
    pub b: Vec<f64>,
}

impl Lstm64 {
    /// One step: returns `(h, c)`.
    pub fn step(&self, x: &[f64], h: &[f64], c: &[f64]) -> (Vec<f64>, Vec<f64>) {
        let hd = self.hidden;
        let a = matvec(&self.wx, 4 * hd, self.input, x);
        let r = matvec(&self.wh, 4 * hd, hd, h);
        let pre: Vec<f64> = (0..4 * hd).map(|i| a[i] + r[i] + self.b[i]).collect();
        let mut hn = vec![0.0; hd];
        let mut cn = vec![0.0; hd];
        for j in 0..hd {
            let i = sigmoid(pre[j]);
            let f = sigmoid(pre[hd + j]);
            let g = pre[2 * hd + j].tanh();
            let o = sigmoid(pre[3 * hd + j]);
            cn[j] = f * c[j] + i * g;
            hn[j] = o * cn[j].tanh();
        }
        (hn, cn)
    }
}

/// Central finite difference of `f` with respect to every element of `x`.
pub fn finite_diff(x: &[f64], h: f64, mut f: impl FnMut(&[f64]) -> f64) -> Vec<f64> {
    let mut v = x.to_vec();
    (0..x.len())
        .map(|i| {
            let o = v[i];
            v[i] = o + h;
            let up = f(&v);
            v[i] = o - h;
            let dn = f(&v);
            v[i] = o;
            (up - dn) / (2.0 * h)
        })
        .collect()
}

/// Relative L2 error `‖a − b‖ / max(‖b‖, floor)`.
pub fn rel_err(a: &[f64], b: &[f64], floor: f64) -> f64 {
    assert_eq!(a.len(), b.len());
    let d = a
        .iter()
        .zip(b)
        .map(|(x, y)| (x - y).powi(2))
        .sum::<f64>()
        .sqrt();
    let n = b.iter().map(|y| y * y).sum::<f64>().sqrt();
    d / n.max(floor)
}

/// Plain-loop f64 reference of the whole on-device navigator (policy step, buffer Ψ and the
/// inner update of Algorithm 1), written independently of gman-core's kernels. It replays
/// the core's random stream (noise and interpolation weights come from
/// `gman_core::rng::Xoshiro128`, the one shared piece) so the two can be compared step by step.
pub mod nav {
    use super::{lrelu, lrelu_d, matvec, sigmoid, Dense64, Disc64, Gen64, Lstm64};

    /// One entry of Ψ: observation s_t, noise z_t, probabilities p_t, LSTM state h_t.
    pub type PsiEntry = (Vec<f64>, Vec<f64>, Vec<f64>, Vec<f64>);

    /// The navigator's networks and settings in f64.
    #[derive(Clone, Debug)]
    pub struct NavRef {
        /// G.
        pub gen: Gen64,
        /// D.
        pub disc: Disc64,
        /// Fusion layer.
        pub fuse: Dense64,
        /// LSTM.
        pub lstm: Lstm64,
        /// Actor head.
        pub actor: Dense64,
        /// Critic head.
        pub critic: Dense64,
        /// Parameter-efficient mode (gains adapt, base weights frozen).
        pub efficient: bool,
        /// α1.
        pub alpha_disc: f64,
        /// α2.
        pub alpha_adapt: f64,
        /// λ.
        pub lambda: f64,
        /// Paper form of L_ad (else the reference form).
        pub paper_loss: bool,
        /// LSTM state h.
        pub h: Vec<f64>,
        /// LSTM state c.
        pub c: Vec<f64>,
        /// Previous probabilities.
        pub prev: Vec<f64>,
        /// Target attributes.
        pub attr: Vec<f64>,
        /// Ψ: (s_t, z_t, p_t, h_t).
        pub psi: Vec<PsiEntry>,
    }

    fn softmax(l: &[f64]) -> Vec<f64> {
        let m = l.iter().cloned().fold(f64::NEG_INFINITY, f64::max);
        let e: Vec<f64> = l.iter().map(|v| (v - m).exp()).collect();
        let s: f64 = e.iter().sum();
        e.iter().map(|v| v / s).collect()
    }

    impl NavRef {
        /// One step with noise `z`: returns (x_t, probs, value) and records Ψ.
        pub fn step(&mut self, obs: &[f64], z: &[f64], ps: &[f64]) -> (Vec<f64>, Vec<f64>, f64) {
            let x = self.gen.forward(z, &self.attr);
            let prod: Vec<f64> = obs.iter().zip(&x).map(|(a, b)| a * b).collect();
            let mut inp = obs.to_vec();
            inp.extend(&x);
            inp.extend(&prod);
            inp.extend(&self.attr);
            inp.extend(&self.prev);
            inp.extend(ps);
            let e: Vec<f64> = self.fuse.forward(&inp).into_iter().map(lrelu).collect();
            let (h, c) = self.lstm.step(&e, &self.h, &self.c);
            let probs = softmax(&self.actor.forward(&h));
            let value = self.critic.forward(&h)[0];
            self.psi
                .push((obs.to_vec(), z.to_vec(), probs.clone(), h.clone()));
            self.h = h;
            self.c = c;
            self.prev = probs.clone();
            (x, probs, value)
        }

        /// Gradient of `coef · D(v)` w.r.t. D's adapted parameters, added to `g`
        /// (`g.0` = W1 or gain, `g.1` = b1, `g.2` = w2, `g.3` = b2).
        fn disc_score_grad(
            &self,
            v: &[f64],
            coef: f64,
            g: &mut (Vec<f64>, Vec<f64>, Vec<f64>, f64),
        ) {
            let l1 = &self.disc.l1;
            let u = matvec(&l1.w, l1.rows, l1.cols, v);
            for j in 0..l1.rows {
                let gain = l1.gain.as_ref().map_or(1.0, |g| g[j]);
                let pre = gain * u[j] + l1.b[j];
                g.2[j] += coef * lrelu(pre);
                let dpre = coef * self.disc.w2[j] * lrelu_d(pre);
                g.1[j] += dpre;
                if self.efficient {
                    g.0[j] += dpre * u[j];
                } else {
                    for i in 0..l1.cols {
                        g.0[j * l1.cols + i] += dpre * gain * v[i];
                    }
                }
            }
            g.3 += coef;
        }

        /// Gradient of `coef · (‖∇_v D(v)‖ − 1)²` w.r.t. D's adapted parameters.
        fn disc_penalty_grad(
            &self,
            v: &[f64],
            coef: f64,
            g: &mut (Vec<f64>, Vec<f64>, Vec<f64>, f64),
        ) {
            let l1 = &self.disc.l1;
            let u = matvec(&l1.w, l1.rows, l1.cols, v);
            let m: Vec<f64> = (0..l1.rows)
                .map(|j| lrelu_d(l1.gain.as_ref().map_or(1.0, |g| g[j]) * u[j] + l1.b[j]))
                .collect();
            let gi = self.disc.input_grad(v);
            let n = gi.iter().map(|a| a * a).sum::<f64>().sqrt();
            if n == 0.0 {
                return;
            }
            let c = coef * 2.0 * (n - 1.0) / n;
            let wg = matvec(&l1.w, l1.rows, l1.cols, &gi);
            for j in 0..l1.rows {
                let gain = l1.gain.as_ref().map_or(1.0, |g| g[j]);
                g.2[j] += c * gain * m[j] * wg[j];
                if self.efficient {
                    g.0[j] += c * self.disc.w2[j] * m[j] * wg[j];
                } else {
                    for i in 0..l1.cols {
                        g.0[j * l1.cols + i] += c * gain * self.disc.w2[j] * m[j] * gi[i];
                    }
                }
            }
        }

        /// The inner update on Ψ with interpolation weights `eps` (one per entry); empties Ψ.
        pub fn adapt(&mut self, eps: &[f64]) {
            let k = self.psi.len();
            let l1 = self.disc.l1.clone();
            let mut g = (
                vec![
                    0.0;
                    if self.efficient {
                        l1.rows
                    } else {
                        l1.rows * l1.cols
                    }
                ],
                vec![0.0; l1.rows],
                vec![0.0; l1.rows],
                0.0,
            );
            let inv = 1.0 / k as f64;
            for t in 0..k {
                let s = self.psi[t].0.clone();
                let x = self.gen.forward(&self.psi[t].1, &self.attr);
                self.disc_score_grad(&s, inv, &mut g);
                self.disc_score_grad(&x, -inv, &mut g);
                let mix: Vec<f64> = s
                    .iter()
                    .zip(&x)
                    .map(|(a, b)| eps[t] * a + (1.0 - eps[t]) * b)
                    .collect();
                self.disc_penalty_grad(&mix, -self.lambda * inv, &mut g);
            }
            let a1 = self.alpha_disc;
            if self.efficient {
                let gain = self.disc.l1.gain.as_mut().expect("gain");
                gain.iter_mut().zip(&g.0).for_each(|(p, d)| *p += a1 * d);
            } else {
                self.disc
                    .l1
                    .w
                    .iter_mut()
                    .zip(&g.0)
                    .for_each(|(p, d)| *p += a1 * d);
            }
            self.disc
                .l1
                .b
                .iter_mut()
                .zip(&g.1)
                .for_each(|(p, d)| *p += a1 * d);
            self.disc
                .w2
                .iter_mut()
                .zip(&g.2)
                .for_each(|(p, d)| *p += a1 * d);
            self.disc.b2 += a1 * g.3;

            // L_ad with the updated D.
            let xs: Vec<Vec<f64>> = (0..k)
                .map(|t| self.gen.forward(&self.psi[t].1, &self.attr))
                .collect();
            let d: Vec<f64> = xs.iter().map(|x| self.disc.score(x)).collect();
            let (dd, dp): (Vec<f64>, Vec<Vec<f64>>) = if self.paper_loss {
                (0..k)
                    .map(|t| {
                        let p = &self.psi[t].2;
                        let n = p.iter().map(|v| v * v).sum::<f64>().sqrt();
                        (
                            -n / k as f64,
                            p.iter().map(|v| -d[t] / k as f64 * v / n).collect(),
                        )
                    })
                    .unzip()
            } else {
                let mut v = [0.0f64; 6];
                for t in 0..k {
                    for a in 0..6 {
                        v[a] -= self.psi[t].2[a] * d[t];
                    }
                }
                let n = v.iter().map(|a| a * a).sum::<f64>().sqrt();
                (0..k)
                    .map(|t| {
                        let p = &self.psi[t].2;
                        (
                            -(0..6).map(|a| p[a] * v[a] / n).sum::<f64>(),
                            (0..6).map(|a| -d[t] * v[a] / n).collect(),
                        )
                    })
                    .unzip()
            };
            // θ gradient through G.
            let (g1, g2) = (&self.gen.l1, &self.gen.l2);
            let mut gg1 = (
                vec![
                    0.0;
                    if self.efficient {
                        g1.rows
                    } else {
                        g1.rows * g1.cols
                    }
                ],
                vec![0.0; g1.rows],
            );
            let mut gg2 = (
                vec![
                    0.0;
                    if self.efficient {
                        g2.rows
                    } else {
                        g2.rows * g2.cols
                    }
                ],
                vec![0.0; g2.rows],
            );
            for t in 0..k {
                let z = &self.psi[t].1;
                let gx = self.disc.input_grad(&xs[t]);
                let mut inp = z.clone();
                inp.extend(&self.attr);
                let u1 = matvec(&g1.w, g1.rows, g1.cols, &inp);
                let pre1: Vec<f64> = (0..g1.rows)
                    .map(|j| g1.gain.as_ref().map_or(1.0, |g| g[j]) * u1[j] + g1.b[j])
                    .collect();
                let h1: Vec<f64> = pre1.iter().map(|&p| lrelu(p)).collect();
                let u2 = matvec(&g2.w, g2.rows, g2.cols, &h1);
                let mut dh1 = vec![0.0; g1.rows];
                for j in 0..g2.rows {
                    let gain = g2.gain.as_ref().map_or(1.0, |g| g[j]);
                    let xj = sigmoid(gain * u2[j] + g2.b[j]);
                    let dpre = dd[t] * gx[j] * xj * (1.0 - xj);
                    gg2.1[j] += dpre;
                    if self.efficient {
                        gg2.0[j] += dpre * u2[j];
                    } else {
                        for i in 0..g2.cols {
                            gg2.0[j * g2.cols + i] += dpre * gain * h1[i];
                        }
                    }
                    for i in 0..g2.cols {
                        dh1[i] += dpre * gain * g2.w[j * g2.cols + i];
                    }
                }
                for j in 0..g1.rows {
                    let gain = g1.gain.as_ref().map_or(1.0, |g| g[j]);
                    let dpre = dh1[j] * lrelu_d(pre1[j]);
                    gg1.1[j] += dpre;
                    if self.efficient {
                        gg1.0[j] += dpre * u1[j];
                    } else {
                        for i in 0..g1.cols {
                            gg1.0[j * g1.cols + i] += dpre * gain * inp[i];
                        }
                    }
                }
            }
            // φ (actor head) gradient.
            let a = &self.actor;
            let mut ga = (
                vec![
                    0.0;
                    if self.efficient {
                        a.rows
                    } else {
                        a.rows * a.cols
                    }
                ],
                vec![0.0; a.rows],
            );
            for t in 0..k {
                let p = &self.psi[t].2;
                let s: f64 = (0..6).map(|i| p[i] * dp[t][i]).sum();
                let h = &self.psi[t].3;
                let u = matvec(&a.w, a.rows, a.cols, h);
                for j in 0..6 {
                    let dl = p[j] * (dp[t][j] - s);
                    ga.1[j] += dl;
                    if self.efficient {
                        ga.0[j] += dl * u[j];
                    } else {
                        for i in 0..a.cols {
                            ga.0[j * a.cols + i] += dl * h[i];
                        }
                    }
                }
            }
            let a2 = self.alpha_adapt;
            let eff = self.efficient;
            let apply = |layer: &mut Dense64, g: &(Vec<f64>, Vec<f64>)| {
                let target = if eff {
                    layer.gain.as_mut().expect("gain")
                } else {
                    &mut layer.w
                };
                target.iter_mut().zip(&g.0).for_each(|(p, d)| *p -= a2 * d);
                layer.b.iter_mut().zip(&g.1).for_each(|(p, d)| *p -= a2 * d);
            };
            apply(&mut self.gen.l1, &gg1);
            apply(&mut self.gen.l2, &gg2);
            apply(&mut self.actor, &ga);
            self.psi.clear();
        }
    }
}
