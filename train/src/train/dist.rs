//! Training across processes: the group of ranks one run spans, and what the ranks exchange
//! at every update.
//!
//! A run with `T` workers may be split over `N` processes (ranks) of `W = T / N` workers
//! each; rank `r` steps the workers `r·W .. r·W + W` (global indices, so their episodes have
//! the seeds the one-process run gives those workers). After the rollouts every rank sends
//! its workers' gradients and episodes to every other rank ([`Group::all_gather`]); each rank
//! then holds all `T` gradients in global worker order and runs the same outer step as the
//! one-process path, so `N` ranks x `W` workers give the bits of one process with `T`
//! workers. Rank 0 writes `metrics.csv` and the checkpoints.
//!
//! [`Single`] is the one-process group; the MPI group (`--features mpi`) is
//! `train::mpi::MpiGroup`.

use anyhow::{bail, Result};

use super::a3c::SegmentLoss;
use super::rollout::EpisodeStats;
use crate::optim::params::ParamSet;

/// The processes of one training run.
pub trait Group {
    /// This process's rank, `0..size()`.
    fn rank(&self) -> usize;
    /// The number of ranks.
    fn size(&self) -> usize;
    /// Every rank's `local` bytes, in rank order (the same on every rank).
    fn all_gather(&mut self, local: &[u8]) -> Result<Vec<Vec<u8>>>;
    /// Waits until every rank has arrived.
    fn barrier(&mut self);
}

/// The one-process group: rank 0 of 1.
#[derive(Debug, Default)]
pub struct Single;

impl Group for Single {
    fn rank(&self) -> usize {
        0
    }
    fn size(&self) -> usize {
        1
    }
    fn all_gather(&mut self, local: &[u8]) -> Result<Vec<Vec<u8>>> {
        Ok(vec![local.to_vec()])
    }
    fn barrier(&mut self) {}
}

/// What a distributed run measured of its exchanges (rank 0's view).
#[derive(Clone, Debug, Default)]
pub struct CommStats {
    /// Updates exchanged.
    pub updates: u64,
    /// Bytes this rank sent, summed over the updates.
    pub bytes_sent: u64,
    /// Bytes this rank received from the other ranks, summed over the updates.
    pub bytes_received: u64,
    /// Seconds spent encoding and decoding the exchanged gradients and episodes.
    pub codec_secs: f64,
    /// Seconds waiting at the barrier before each exchange (the slowest rank's rollouts).
    pub wait_secs: f64,
    /// Seconds in the exchange itself (after every rank arrived).
    pub transfer_secs: f64,
    /// Seconds of the updates, rollouts to checkpoint, summed.
    pub update_secs: f64,
}

impl CommStats {
    /// One line for the end of a run: bytes per update and the exchange's time and share.
    pub fn summary(&self, ranks: usize) -> String {
        let n = self.updates.max(1) as f64;
        let us = |s: f64| 1e6 * s / n;
        let overhead = self.codec_secs + self.transfer_secs;
        format!(
            "{ranks} ranks, {} updates: {:.0} B sent and {:.0} B received per update and rank; \
             exchange {:.0} us per update (encode/decode {:.0} us, transfer {:.0} us) = {:.2}% of \
             the update ({:.0} us); waiting for the slowest rank {:.0} us",
            self.updates,
            self.bytes_sent as f64 / n,
            self.bytes_received as f64 / n,
            us(overhead),
            us(self.codec_secs),
            us(self.transfer_secs),
            100.0 * overhead / self.update_secs.max(1e-12),
            us(self.update_secs),
            us(self.wait_secs),
        )
    }
}

/// A worker's share of an update as exchanged: its gradient and its episodes (their
/// statistics and D after each).
pub(crate) type WorkerShare = (ParamSet, Vec<Episode>);

/// An episode's statistics and D after it.
pub type Episode = (EpisodeStats, Vec<Vec<f32>>);

/// Marks a D tensor equal, bit for bit, to the model's (every rank holds the same ω).
const SAME_AS_MODEL: u64 = u64::MAX;

/// Encodes a rank's workers' gradients and episodes (gradients as the f32 bits in the
/// parameter store's tensor order; an episode's statistics without its action list and final
/// feature, which the outer step and `metrics.csv` do not use; D after an episode as a marker
/// where it equals the model's `omega`, tensor by tensor, as in the methods without an inner
/// loop).
pub(crate) fn encode_shares(shares: &[(&ParamSet, &[Episode])], omega: &[&[f32]]) -> Vec<u8> {
    let mut b = Vec::new();
    put_u64(&mut b, shares.len() as u64);
    for (g, eps) in shares {
        put_u64(&mut b, g.tensors.len() as u64);
        for t in &g.tensors {
            put_f32s(&mut b, &t.data);
        }
        put_u64(&mut b, eps.len() as u64);
        for (st, disc) in eps.iter() {
            b.push(st.success as u8);
            put_u64(&mut b, st.steps as u64);
            put_u64(&mut b, st.total_reward.to_bits() as u64);
            put_u64(&mut b, st.adaptations as u64);
            put_u64(&mut b, st.rollbacks as u64);
            put_u64(&mut b, st.disc_gap.to_bits() as u64);
            put_u64(&mut b, st.adapt_loss.to_bits() as u64);
            put_u64(&mut b, st.loss.policy.to_bits());
            put_u64(&mut b, st.loss.value.to_bits());
            put_u64(&mut b, st.loss.entropy.to_bits());
            put_u64(&mut b, st.loss.steps as u64);
            put_u64(&mut b, disc.len() as u64);
            for (i, d) in disc.iter().enumerate() {
                if omega.get(i).is_some_and(|o| same_bits(o, d)) {
                    put_u64(&mut b, SAME_AS_MODEL);
                } else {
                    put_f32s(&mut b, d);
                }
            }
        }
    }
    b
}

/// Decodes what [`encode_shares`] wrote, the gradients into twins of `like`, D's tensors
/// marked unchanged as copies of `omega`.
pub(crate) fn decode_shares(
    bytes: &[u8],
    like: &ParamSet,
    omega: &[&[f32]],
    rank: usize,
) -> Result<Vec<WorkerShare>> {
    let mut r = Reader {
        b: bytes,
        at: 0,
        rank,
    };
    let n = r.u64()? as usize;
    let mut out = Vec::with_capacity(n.min(4096));
    for _ in 0..n {
        let mut g = like.zeros_like();
        if r.u64()? as usize != g.tensors.len() {
            bail!("rank {rank} sent a gradient with another number of tensors");
        }
        for t in &mut g.tensors {
            let v = r.f32s()?;
            if v.len() != t.data.len() {
                bail!(
                    "rank {rank} sent {} values for tensor {}, which has {}",
                    v.len(),
                    t.name,
                    t.data.len()
                );
            }
            t.data = v;
        }
        let ne = r.u64()? as usize;
        let mut eps = Vec::with_capacity(ne.min(4096));
        for _ in 0..ne {
            let success = r.byte()? != 0;
            let steps = r.u64()? as u32;
            let total_reward = f32::from_bits(r.u64()? as u32);
            let adaptations = r.u64()? as u32;
            let rollbacks = r.u64()? as u32;
            let disc_gap = f32::from_bits(r.u64()? as u32);
            let adapt_loss = f32::from_bits(r.u64()? as u32);
            let loss = SegmentLoss {
                policy: f64::from_bits(r.u64()?),
                value: f64::from_bits(r.u64()?),
                entropy: f64::from_bits(r.u64()?),
                steps: r.u64()? as usize,
            };
            let nd = r.u64()? as usize;
            let mut disc = Vec::with_capacity(nd.min(64));
            for i in 0..nd {
                if r.peek_u64()? == SAME_AS_MODEL {
                    r.u64()?;
                    let Some(o) = omega.get(i) else {
                        bail!(
                            "rank {rank} marked D tensor {i} unchanged, which has no model value"
                        );
                    };
                    disc.push(o.to_vec());
                } else {
                    disc.push(r.f32s()?);
                }
            }
            let st = EpisodeStats {
                success,
                steps,
                total_reward,
                adaptations,
                rollbacks,
                disc_gap,
                adapt_loss,
                loss,
                ..EpisodeStats::default()
            };
            eps.push((st, disc));
        }
        out.push((g, eps));
    }
    if r.at != bytes.len() {
        bail!("rank {rank} sent {} trailing bytes", bytes.len() - r.at);
    }
    Ok(out)
}

/// A 64-bit FNV-1a hash of `bytes` (the ranks' agreement check; not cryptographic).
pub(crate) fn fnv1a(bytes: &[u8]) -> u64 {
    let mut h = crate::sim::util::Fnv::new();
    h.eat(bytes);
    h.0
}

/// The hash of a parameter store's values (bits, in tensor order).
pub(crate) fn params_hash(p: &ParamSet) -> u64 {
    let mut b = Vec::with_capacity(4 * p.num_values());
    for t in &p.tensors {
        for v in &t.data {
            b.extend_from_slice(&v.to_le_bytes());
        }
    }
    fnv1a(&b)
}

fn same_bits(a: &[f32], b: &[f32]) -> bool {
    a.len() == b.len() && a.iter().zip(b).all(|(x, y)| x.to_bits() == y.to_bits())
}

fn put_u64(b: &mut Vec<u8>, v: u64) {
    b.extend_from_slice(&v.to_le_bytes());
}

fn put_f32s(b: &mut Vec<u8>, v: &[f32]) {
    put_u64(b, v.len() as u64);
    b.reserve(4 * v.len());
    for x in v {
        b.extend_from_slice(&x.to_le_bytes());
    }
}

struct Reader<'a> {
    b: &'a [u8],
    at: usize,
    rank: usize,
}

impl Reader<'_> {
    fn take(&mut self, n: usize) -> Result<&[u8]> {
        if self.b.len() - self.at < n {
            bail!(
                "the message of rank {} ends early ({} bytes)",
                self.rank,
                self.b.len()
            );
        }
        let s = &self.b[self.at..self.at + n];
        self.at += n;
        Ok(s)
    }
    fn byte(&mut self) -> Result<u8> {
        Ok(self.take(1)?[0])
    }
    fn u64(&mut self) -> Result<u64> {
        let s = self.take(8)?;
        let mut a = [0u8; 8];
        a.copy_from_slice(s);
        Ok(u64::from_le_bytes(a))
    }
    fn peek_u64(&mut self) -> Result<u64> {
        let at = self.at;
        let v = self.u64();
        self.at = at;
        v
    }
    fn f32s(&mut self) -> Result<Vec<f32>> {
        let n = self.u64()? as usize;
        let s = self.take(n.saturating_mul(4))?;
        Ok(s.chunks_exact(4)
            .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
            .collect())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::optim::params::Param;

    #[test]
    fn shares_round_trip_bit_for_bit() {
        let mut g = ParamSet::new();
        g.push(Param::zeros("a", 2, 3)).unwrap();
        g.push(Param::zeros("b", 1, 2)).unwrap();
        for (i, v) in g.tensors[0].data.iter_mut().enumerate() {
            *v = (i as f32 - 2.5) * 0.1;
        }
        g.tensors[1].data = vec![-0.0, f32::from_bits(1)];
        let st = EpisodeStats {
            success: true,
            steps: 7,
            total_reward: -1.25,
            disc_gap: f32::NAN,
            ..EpisodeStats::default()
        };
        let eps = [(st, vec![vec![1.0f32, 2.0], vec![3.0]])];
        let omega: [&[f32]; 2] = [&[9.0, 9.0], &[3.0]];
        let bytes = encode_shares(&[(&g, &eps[..])], &omega);
        let back = decode_shares(&bytes, &g, &omega, 1).unwrap();
        assert_eq!(back.len(), 1);
        for (x, y) in back[0].0.tensors.iter().zip(&g.tensors) {
            let xb: Vec<u32> = x.data.iter().map(|v| v.to_bits()).collect();
            let yb: Vec<u32> = y.data.iter().map(|v| v.to_bits()).collect();
            assert_eq!(xb, yb);
        }
        let (s, d) = &back[0].1[0];
        assert!(s.success && s.steps == 7 && s.total_reward == -1.25 && s.disc_gap.is_nan());
        assert_eq!(d, &vec![vec![1.0f32, 2.0], vec![3.0]]);
        assert!(decode_shares(&bytes[..bytes.len() - 1], &g, &omega, 1).is_err());
        // The second D tensor equals ω: sent as a marker (8 bytes), not as its values.
        let full = encode_shares(&[(&g, &eps[..])], &[]);
        assert_eq!(full.len(), bytes.len() + 4);
    }
}
