//! Seedable randomness: a small PRNG for the device and Gaussian noise from any
//! [`rand_core::RngCore`].
//!
//! Gaussian samples use the Box–Muller transform with `libm`'s `logf`, `sqrtf`, `cosf` and
//! `sinf`, so the same generator state gives the same bits on every target.

use rand_core::RngCore;

/// Xoshiro128++ (Blackman & Vigna): 128 bits of state, 32-bit output, fast on a Cortex-M4.
/// Seeded through SplitMix64 so that any `u64` (including 0) gives a good state.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Xoshiro128 {
    s: [u32; 4],
}

impl Xoshiro128 {
    /// A generator whose state is derived from `seed`.
    pub fn seed_from_u64(seed: u64) -> Self {
        let mut x = seed;
        let mut next = || {
            x = x.wrapping_add(0x9E37_79B9_7F4A_7C15);
            let mut z = x;
            z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
            z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
            z ^ (z >> 31)
        };
        let a = next();
        let b = next();
        let mut s = [a as u32, (a >> 32) as u32, b as u32, (b >> 32) as u32];
        if s == [0; 4] {
            s[0] = 1;
        }
        Xoshiro128 { s }
    }

    /// The raw state (for checkpoints).
    pub fn state(&self) -> [u32; 4] {
        self.s
    }

    /// Restores a state saved with [`Xoshiro128::state`]; an all-zero state is replaced by a
    /// valid one.
    pub fn from_state(mut s: [u32; 4]) -> Self {
        if s == [0; 4] {
            s[0] = 1;
        }
        Xoshiro128 { s }
    }
}

impl RngCore for Xoshiro128 {
    fn next_u32(&mut self) -> u32 {
        let s = &mut self.s;
        let result = s[0].wrapping_add(s[3]).rotate_left(7).wrapping_add(s[0]);
        let t = s[1] << 9;
        s[2] ^= s[0];
        s[3] ^= s[1];
        s[1] ^= s[2];
        s[0] ^= s[3];
        s[2] ^= t;
        s[3] = s[3].rotate_left(11);
        result
    }

    fn next_u64(&mut self) -> u64 {
        let lo = self.next_u32() as u64;
        let hi = self.next_u32() as u64;
        lo | (hi << 32)
    }

    fn fill_bytes(&mut self, dst: &mut [u8]) {
        for chunk in dst.chunks_mut(4) {
            let v = self.next_u32().to_le_bytes();
            chunk.copy_from_slice(&v[..chunk.len()]);
        }
    }
}

/// A uniform sample in `(0, 1]` with 24 bits of resolution (never 0, so `ln` is finite).
#[inline]
pub fn uniform_open0<R: RngCore + ?Sized>(rng: &mut R) -> f32 {
    ((rng.next_u32() >> 8) + 1) as f32 * (1.0 / 16_777_216.0)
}

/// A uniform sample in `[0, 1)`.
#[inline]
pub fn uniform<R: RngCore + ?Sized>(rng: &mut R) -> f32 {
    (rng.next_u32() >> 8) as f32 * (1.0 / 16_777_216.0)
}

/// Fills `out` with independent standard normal samples (Box–Muller, both outputs used).
pub fn fill_gaussian<R: RngCore + ?Sized>(rng: &mut R, out: &mut [f32]) {
    let mut chunks = out.chunks_exact_mut(2);
    for pair in &mut chunks {
        let (a, b) = box_muller(rng);
        pair[0] = a;
        pair[1] = b;
    }
    if let [last] = chunks.into_remainder() {
        *last = box_muller(rng).0;
    }
}

/// One standard normal sample.
pub fn gaussian<R: RngCore + ?Sized>(rng: &mut R) -> f32 {
    box_muller(rng).0
}

fn box_muller<R: RngCore + ?Sized>(rng: &mut R) -> (f32, f32) {
    let u1 = uniform_open0(rng);
    let u2 = uniform(rng);
    let r = libm::sqrtf(-2.0 * libm::logf(u1));
    let th = 2.0 * core::f32::consts::PI * u2;
    (r * libm::cosf(th), r * libm::sinf(th))
}
