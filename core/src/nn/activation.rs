//! Element-wise activations and softmax, forward and backward.
//!
//! All transcendental functions come from `libm`, never from the platform, so host and
//! microcontroller builds compute the same bits.

use crate::error::{check_len, Result};

/// Negative slope of every LeakyReLU in GMAN (G's and D's hidden layers, paper Sec. 5.1).
pub const LEAKY_SLOPE: f32 = 0.2;

/// LeakyReLU(0.2).
#[inline]
pub fn leaky_relu(x: f32) -> f32 {
    if x > 0.0 {
        x
    } else {
        LEAKY_SLOPE * x
    }
}

/// Derivative of LeakyReLU(0.2), from the pre-activation *or* the output (same sign).
#[inline]
pub fn leaky_relu_grad(x: f32) -> f32 {
    if x > 0.0 {
        1.0
    } else {
        LEAKY_SLOPE
    }
}

/// Numerically stable logistic sigmoid.
#[inline]
pub fn sigmoid(x: f32) -> f32 {
    if x >= 0.0 {
        1.0 / (1.0 + libm::expf(-x))
    } else {
        let e = libm::expf(x);
        e / (1.0 + e)
    }
}

/// Hyperbolic tangent.
#[inline]
pub fn tanh(x: f32) -> f32 {
    libm::tanhf(x)
}

/// In-place LeakyReLU over a slice.
pub fn leaky_relu_inplace(x: &mut [f32]) {
    for v in x {
        *v = leaky_relu(*v);
    }
}

/// In-place sigmoid over a slice: [`sigmoid`] of every element, bit for bit, eight at a
/// time through [`expf8`] where every lane's argument is on `libm::expf`'s main path (the
/// others, and the tail, through [`sigmoid`] itself) on targets with f32 SIMD; elsewhere
/// element by element.
pub fn sigmoid_inplace(x: &mut [f32]) {
    if cfg!(not(any(
        target_arch = "x86_64",
        target_arch = "x86",
        target_arch = "aarch64"
    ))) {
        // No f32 SIMD (a Cortex-M): the eight lanes would run one after another anyway, so
        // the scalar form, the same bits in a fraction of the flash.
        x.iter_mut().for_each(|v| *v = sigmoid(*v));
        return;
    }
    let mut chunks = x.chunks_exact_mut(8);
    for ch in &mut chunks {
        let v: [f32; 8] = core::array::from_fn(|l| ch[l]);
        // The argument `sigmoid` gives `expf`: -x for x >= 0, else x.
        let arg: [f32; 8] = core::array::from_fn(|l| if v[l] >= 0.0 { -v[l] } else { v[l] });
        match expf8(arg) {
            Some(e) => {
                // 1 / (1 + e) for x >= 0, e / (1 + e) otherwise: one division per lane.
                for l in 0..8 {
                    let num = if v[l] >= 0.0 { 1.0 } else { e[l] };
                    ch[l] = num / (1.0 + e[l]);
                }
            }
            None => ch.iter_mut().for_each(|v| *v = sigmoid(*v)),
        }
    }
    for v in chunks.into_remainder() {
        *v = sigmoid(*v);
    }
}

// `libm::expf` (FreeBSD's e_expf.c, as ported by the `libm` crate): its constants.
const EXP_LN2_HI: f32 = f32::from_bits(0x3f31_7200); // 6.9314575195e-01
const EXP_LN2_LO: f32 = f32::from_bits(0x35bf_be8e); // 1.4286067653e-06
const EXP_INV_LN2: f32 = f32::from_bits(0x3fb8_aa3b); // 1.4426950216e+00
const EXP_P1: f32 = f32::from_bits(0x3e2a_aa8f); // 1.6666625440e-1
const EXP_P2: f32 = f32::from_bits(0xbb35_5215); // -2.7667332906e-3

/// `libm::expf` of eight values at once, **bit for bit**, when every lane takes that
/// function's main path (`2^-14 < |x| < 87.33655`, i.e. `0x39000000 < |x|.to_bits() <
/// 0x42aeac50`); `None` otherwise (the caller then uses `libm::expf` itself). The same f32
/// operations in the same order, with the branches of the argument reduction as selects
/// (for `k = 0` the reduction subtracts `0 * ln2` and adds `lo = 0`, which changes no bit of
/// a non-zero `x`) and `scalbnf(y, k)` as its one multiplication by `2^k` (`|k| <= 126` on
/// this path), so the compiler can run the lanes as one vector. `tests::expf8_is_libm_expf`
/// compares it with `libm::expf` on a stride of all 2^32 inputs (and on all of them when run
/// with `--ignored`).
#[inline]
pub fn expf8(x: [f32; 8]) -> Option<[f32; 8]> {
    if !x.iter().all(|v| {
        let h = v.to_bits() & 0x7fff_ffff;
        h > 0x3900_0000 && h < 0x42ae_ac50
    }) {
        return None;
    }
    // One operation per loop over the lanes (branch-free: the reduction's branches are
    // selects), so that the compiler runs each loop as one vector operation.
    let mut k = [0i32; 8];
    for l in 0..8 {
        let bits = x[l].to_bits();
        let h = bits & 0x7fff_ffff;
        let half = if bits >> 31 != 0 { -0.5 } else { 0.5 };
        // |x| > 1.5 ln2: round; |x| > 0.5 ln2: +-1; else 0.
        let kb = (EXP_INV_LN2 * x[l] + half) as i32;
        let km = if bits >> 31 != 0 { -1 } else { 1 };
        k[l] = if h > 0x3f85_1592 {
            kb
        } else if h > 0x3eb1_7218 {
            km
        } else {
            0
        };
    }
    let mut y = [0.0f32; 8];
    for l in 0..8 {
        let kf = k[l] as f32;
        let hi = x[l] - kf * EXP_LN2_HI;
        let lo = kf * EXP_LN2_LO;
        let r = hi - lo;
        let rr = r * r;
        let c = r - rr * (EXP_P1 + rr * EXP_P2);
        let yl = 1.0 + (r * c / (2.0 - c) - lo + hi);
        // scalbnf(y, k) for |k| <= 126: y * 2^k (exactly y for k = 0).
        y[l] = yl * f32::from_bits(((0x7f + k[l]) as u32) << 23);
    }
    Some(y)
}

/// `dpre = dout * LeakyReLU'(out)` given the activation's *output* `out`
/// (its sign equals the pre-activation's, so the output suffices).
pub fn leaky_relu_backward(out: &[f32], dout: &[f32], dpre: &mut [f32]) -> Result<()> {
    check_len("leaky_relu_backward.dout", out.len(), dout.len())?;
    check_len("leaky_relu_backward.dpre", out.len(), dpre.len())?;
    for ((d, &o), &g) in dpre.iter_mut().zip(out).zip(dout) {
        *d = g * leaky_relu_grad(o);
    }
    Ok(())
}

/// `dpre = dout * y (1 - y)` given the sigmoid's output `y`.
pub fn sigmoid_backward(y: &[f32], dout: &[f32], dpre: &mut [f32]) -> Result<()> {
    check_len("sigmoid_backward.dout", y.len(), dout.len())?;
    check_len("sigmoid_backward.dpre", y.len(), dpre.len())?;
    for ((d, &yi), &g) in dpre.iter_mut().zip(y).zip(dout) {
        *d = g * yi * (1.0 - yi);
    }
    Ok(())
}

/// Numerically stable softmax: `probs = exp(l - max l) / sum`.
/// A non-finite logit yields non-finite probabilities; callers that must not act on NaN
/// check the result (the navigator does).
pub fn softmax(logits: &[f32], probs: &mut [f32]) -> Result<()> {
    check_len("softmax.probs", logits.len(), probs.len())?;
    let mut m = f32::NEG_INFINITY;
    for &l in logits {
        if l > m {
            m = l;
        }
    }
    let mut s = 0.0f32;
    for (p, &l) in probs.iter_mut().zip(logits) {
        *p = libm::expf(l - m);
        s += *p;
    }
    let inv = 1.0 / s;
    for p in probs.iter_mut() {
        *p *= inv;
    }
    Ok(())
}

/// Natural log of the softmax, stable: `logp_i = l_i - max - ln(sum exp(l - max))`.
pub fn log_softmax(logits: &[f32], logp: &mut [f32]) -> Result<()> {
    check_len("log_softmax.logp", logits.len(), logp.len())?;
    let mut m = f32::NEG_INFINITY;
    for &l in logits {
        if l > m {
            m = l;
        }
    }
    let mut s = 0.0f32;
    for &l in logits {
        s += libm::expf(l - m);
    }
    let lse = m + libm::logf(s);
    for (o, &l) in logp.iter_mut().zip(logits) {
        *o = l - lse;
    }
    Ok(())
}

/// Backward of softmax: `dlogits_i = p_i (dp_i - sum_j p_j dp_j)`.
pub fn softmax_backward(probs: &[f32], dprobs: &[f32], dlogits: &mut [f32]) -> Result<()> {
    check_len("softmax_backward.dprobs", probs.len(), dprobs.len())?;
    check_len("softmax_backward.dlogits", probs.len(), dlogits.len())?;
    let mut s = 0.0f32;
    for (&p, &g) in probs.iter().zip(dprobs) {
        s += p * g;
    }
    for ((d, &p), &g) in dlogits.iter_mut().zip(probs).zip(dprobs) {
        *d = p * (g - s);
    }
    Ok(())
}

/// True when every value is finite.
#[inline]
pub fn all_finite(x: &[f32]) -> bool {
    x.iter().all(|v| v.is_finite())
}

#[cfg(test)]
mod tests {
    extern crate std;
    use super::*;

    /// Compares [`expf8`] with `libm::expf` on the inputs `bits(i)` for `i in 0..n`, eight
    /// at a time; returns how many went through the main path.
    fn compare(n: u64, bits: impl Fn(u64) -> u32) -> u64 {
        let mut main = 0;
        let mut i = 0;
        while i < n {
            let x: [f32; 8] = core::array::from_fn(|l| f32::from_bits(bits(i + l as u64)));
            if let Some(e) = expf8(x) {
                for l in 0..8 {
                    assert_eq!(
                        e[l].to_bits(),
                        libm::expf(x[l]).to_bits(),
                        "expf8({:e}) (bits {:#010x})",
                        x[l],
                        x[l].to_bits()
                    );
                }
                main += 8;
            } else {
                // Refused only when a lane is off the main path.
                assert!(x.iter().any(|v| {
                    let h = v.to_bits() & 0x7fff_ffff;
                    !(h > 0x3900_0000 && h < 0x42ae_ac50)
                }));
            }
            i += 8;
        }
        main
    }

    #[test]
    fn expf8_is_libm_expf() {
        // Every 1021st bit pattern (all exponents, both signs, NaN, inf) ...
        let main = compare(1 << 22, |i| (i * 1021) as u32);
        assert!(main > 100_000, "{main}");
        // ... and every input within 4096 ulps of each branch boundary, both signs.
        for b in [0x3900_0000u32, 0x3eb1_7218, 0x3f85_1592, 0x42ae_ac50] {
            for sign in [0, 0x8000_0000u32] {
                compare(8192, |i| (b - 4096 + i as u32) | sign);
            }
        }
    }

    /// All 2^32 inputs (about a minute in release: `cargo test --release -p gman-core
    /// expf8_is_libm_expf_everywhere -- --ignored`).
    #[test]
    #[ignore]
    fn expf8_is_libm_expf_everywhere() {
        // The main path in aligned groups of eight: 0x39000008 ..= 0x42aeac4f, both signs.
        assert_eq!(
            compare(1 << 32, |i| i as u32),
            2 * (0x42ae_ac50 - 0x3900_0008)
        );
    }

    #[test]
    fn sigmoid_inplace_is_sigmoid_bit_for_bit() {
        let specials = [
            0.0f32,
            -0.0,
            1e-6,
            -1e-6,
            f32::NAN,
            f32::from_bits(0x7fc0_1234),
            f32::INFINITY,
            f32::NEG_INFINITY,
            88.0,
            -88.0,
            200.0,
            -200.0,
        ];
        let mut v: std::vec::Vec<f32> = (0..4099u32)
            .map(|i| f32::from_bits(i.wrapping_mul(2_654_435_761)))
            .chain((0..2000).map(|i| (i as f32 - 1000.0) * 0.013))
            .collect();
        v.extend_from_slice(&specials);
        for start in 0..8 {
            let mut got = v[start..].to_vec();
            sigmoid_inplace(&mut got);
            for (g, &x) in got.iter().zip(&v[start..]) {
                assert_eq!(g.to_bits(), sigmoid(x).to_bits(), "sigmoid({x:e})");
            }
        }
    }
}
