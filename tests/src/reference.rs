//! An f64 reference of GMAN's networks and losses, written independently of gman-core's
//! kernels (plain loops, no segments, no int8), for gradient and agreement tests.

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
