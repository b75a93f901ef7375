//! The `blob_parse` fuzz target's body (`core/fuzz/fuzz_targets/body.rs`) on stable Rust:
//! inputs generated from valid blobs (format v4 with and without a map, their v2/v3
//! rewrites, hand-written blobs with small and degenerate dims: zero widths, half a map, a
//! map without channels) by random bit flips (half of them in the header), byte writes,
//! truncations, insertions, and header tampering with the checksum recomputed (so that the
//! header's settings and dims, not only the CRC, are exercised).
//!
//! `fuzz_loop_smoke` runs 3,000 inputs in CI; the long run is by hand:
//! `GMAN_FUZZ_ITERS=10000000 cargo test --release -p gman-core --test fuzz_loop -- --ignored`

mod common;
use common::*;

#[path = "../fuzz/fuzz_targets/body.rs"]
#[allow(dead_code)]
mod body;

use gman_core::blob::{Blob, FLAG_ADAPT, FLAG_FULL_ADAPT, FLAG_ZERO_NOISE};
use gman_core::Dims;

/// xorshift64*: deterministic, dependency-free.
struct Rng(u64);
impl Rng {
    fn next(&mut self) -> u64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        self.0.wrapping_mul(0x2545_f491_4f6c_dd1d)
    }
    fn below(&mut self, n: usize) -> usize {
        (self.next() % n.max(1) as u64) as usize
    }
}

/// Tiny dims so that every input that parses runs its navigators quickly.
const TINY: Dims = Dims {
    attr: 3,
    noise: 2,
    gen_hidden: 4,
    feat: 5,
    disc_hidden: 3,
    lstm_hidden: 4,
    embed: 3,
    ps: 0,
    map_rows: 0,
    map_cols: 0,
    cell_embed: 0,
};

fn seeds() -> Vec<Vec<u8>> {
    let mut v = Vec::new();
    for (d, flags) in [
        (TINY, FLAG_ADAPT),
        (TINY.with_ps(), FLAG_ADAPT | FLAG_FULL_ADAPT),
        (TINY.with_map(2, 2, 2), FLAG_ADAPT | FLAG_ZERO_NOISE),
        (TINY, 0),
    ] {
        for int8 in [false, true] {
            let b = seeded_blob(&d, 7, int8, flags);
            v.push(legacy(&b));
            v.push(b);
        }
    }
    v
}

/// Hand-written blob with random small dims, some of them degenerate.
fn random_dims_blob(r: &mut Rng) -> Vec<u8> {
    let mut w = [0usize; 7];
    for x in &mut w {
        *x = if r.below(8) == 0 { 0 } else { 1 + r.below(4) };
    }
    let map = if r.below(3) == 0 {
        (r.below(3), r.below(3), r.below(3))
    } else {
        (0, 0, 0)
    };
    let d = Dims {
        attr: w[0],
        noise: w[1],
        gen_hidden: w[2],
        feat: w[3],
        disc_hidden: w[4],
        lstm_hidden: w[5],
        embed: w[6],
        ps: if r.below(2) == 0 { 0 } else { w[0] },
        ..TINY
    }
    .with_map(map.0, map.1, map.2);
    raw_blob(
        &d,
        [0, FLAG_ADAPT, FLAG_ADAPT | FLAG_FULL_ADAPT][r.below(3)],
    )
}

/// Header length of a blob that parses (`None` otherwise).
fn header_len(b: &[u8]) -> Option<(usize, usize, u32)> {
    let blob = Blob::parse(b).ok()?;
    let plen = blob.header().payload_len() as usize;
    Some((b.len() - plen, plen, blob.header().payload_crc()))
}

fn mutate(r: &mut Rng, seeds: &[Vec<u8>]) -> Vec<u8> {
    if r.below(6) == 0 {
        return random_dims_blob(r);
    }
    let mut b = seeds[r.below(seeds.len())].clone();
    let info = header_len(&b);
    let hlen = info.map_or(b.len(), |i| i.0);
    for _ in 0..1 + r.below(4) {
        match r.below(6) {
            0 | 1 => {
                // bit flip, half of them in the header
                let at = if r.below(2) == 0 {
                    r.below(hlen.min(b.len()))
                } else {
                    r.below(b.len())
                };
                b[at] ^= 1 << r.below(8);
            }
            2 => {
                let at = r.below(b.len());
                b[at] = r.next() as u8;
            }
            3 => {
                let n = r.below(b.len() + 1);
                b.truncate(n);
            }
            4 => {
                let at = r.below(b.len() + 1);
                b.insert(at, r.next() as u8);
            }
            _ => {
                // header tampering with a valid checksum: a header byte changed (not the
                // CRC's), then resealed
                if let Some((hl, plen, crc)) = info {
                    if b.len() == hl + plen && hl > 6 {
                        let at = 4 + r.below(hl - 6);
                        b[at] = r.next() as u8;
                        b = reseal(&b, plen, crc);
                    }
                }
            }
        }
        if b.is_empty() {
            break;
        }
    }
    b
}

fn run(iters: u64, seed: u64) -> (u64, u64) {
    let seeds = seeds();
    for s in &seeds {
        assert!(Blob::parse(s).is_ok());
        body::check(s);
    }
    let mut r = Rng(seed | 1);
    let mut parsed = 0u64;
    for _ in 0..iters {
        let b = mutate(&mut r, &seeds);
        if Blob::parse(&b).is_ok() {
            parsed += 1;
        }
        body::check(&b);
    }
    (iters, parsed)
}

#[test]
fn fuzz_loop_smoke() {
    let (n, parsed) = run(3_000, 0x5eed);
    assert!(parsed > 0, "no generated input parsed in {n}");
}

/// `GMAN_FUZZ_ITERS` executions (default 1,000,000), `GMAN_FUZZ_SEED` (default 1); prints
/// the count reached every 100,000 executions.
#[test]
#[ignore]
fn fuzz_loop_long() {
    let iters: u64 = std::env::var("GMAN_FUZZ_ITERS")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(1_000_000);
    let seed: u64 = std::env::var("GMAN_FUZZ_SEED")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(1);
    let chunk = 100_000u64;
    let mut done = 0u64;
    let mut parsed = 0u64;
    while done < iters {
        let n = chunk.min(iters - done);
        let (_, p) = run(n, seed.wrapping_mul(0x9e37_79b9).wrapping_add(done));
        done += n;
        parsed += p;
        eprintln!("fuzz_loop: {done} executions, {parsed} parsed, no panic");
    }
}
