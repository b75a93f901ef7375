//! Rewards of paper Sec. 5.1 (R_n, R_{n+d}, R_{n+s}, R_{n+d+s}) with the reference constants.

use std::fmt;
use std::str::FromStr;

use gman_core::ATTR_DIM;
use serde::{Deserialize, Serialize};

/// Penalty of every step (including Done when it fails).
pub const STEP_PENALTY: f32 = -0.01;
/// Reward of a successful Done.
pub const SUCCESS_REWARD: f32 = 5.0;
/// Scale of the distance term `max(0, 0.1 * (d_prev - d_now))`.
pub const DISTANCE_SCALE: f32 = 0.1;
/// Scale of the similarity term on an unsuccessful Done (`0.1 * 5 * S`).
pub const SIMILARITY_FAIL_SCALE: f32 = 0.1;

/// Which reward the environment pays.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum RewardKind {
    /// R_n: -0.01 per step, 5 on success.
    Navigation,
    /// R_{n+d}: R_n plus `max(0, 0.1 * (d_prev - d_now))` per step.
    Distance,
    /// R_{n+s}: R_n plus `0.1 * 5 * S` on an unsuccessful Done (`5 * S = 5` on success).
    Similarity,
    /// R_{n+d+s}: all terms (the paper's default).
    #[default]
    Mixed,
}

impl RewardKind {
    /// True if the distance term is paid.
    pub fn has_distance(self) -> bool {
        matches!(self, RewardKind::Distance | RewardKind::Mixed)
    }
    /// True if the similarity term is paid.
    pub fn has_similarity(self) -> bool {
        matches!(self, RewardKind::Similarity | RewardKind::Mixed)
    }
    /// Name (`navigation`, `distance`, `similarity`, `mixed`).
    pub fn name(self) -> &'static str {
        match self {
            RewardKind::Navigation => "navigation",
            RewardKind::Distance => "distance",
            RewardKind::Similarity => "similarity",
            RewardKind::Mixed => "mixed",
        }
    }
}

impl fmt::Display for RewardKind {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

impl FromStr for RewardKind {
    type Err = anyhow::Error;
    fn from_str(s: &str) -> anyhow::Result<Self> {
        Ok(match s {
            "navigation" | "n" => RewardKind::Navigation,
            "distance" | "n+d" => RewardKind::Distance,
            "similarity" | "n+s" => RewardKind::Similarity,
            "mixed" | "n+d+s" => RewardKind::Mixed,
            _ => anyhow::bail!("unknown reward {s:?} (navigation, distance, similarity, mixed)"),
        })
    }
}

/// Jaccard similarity of attribute vectors: mean over dimensions of `min/max`, a dimension
/// where both are 0 counting 1.
pub fn jaccard(u: &[f32; ATTR_DIM], v: &[f32; ATTR_DIM]) -> f32 {
    let s: f32 = u
        .iter()
        .zip(v)
        .map(|(&a, &b)| {
            let hi = a.max(b);
            if hi <= 0.0 {
                1.0
            } else {
                a.min(b) / hi
            }
        })
        .sum();
    s / ATTR_DIM as f32
}

/// Reward of a non-Done step that moved the agent from distance `d_prev` to `d_now` (metres to
/// the nearest goal instance; infinite distances pay no distance term).
pub fn step_reward(kind: RewardKind, d_prev: f32, d_now: f32) -> f32 {
    let mut r = STEP_PENALTY;
    if kind.has_distance() && d_prev.is_finite() && d_now.is_finite() {
        r += (DISTANCE_SCALE * (d_prev - d_now)).max(0.0);
    }
    r
}

/// Reward of Done: 5 on success (`5 * S`, S = 1 when the target is visible); otherwise the
/// step penalty plus, for the similarity rewards, `0.1 * 5 * S` where `S` is the best Jaccard
/// similarity between the target and the visible objects (0 if none).
pub fn done_reward(kind: RewardKind, success: bool, similarity: f32) -> f32 {
    if success {
        SUCCESS_REWARD
    } else if kind.has_similarity() {
        STEP_PENALTY + SIMILARITY_FAIL_SCALE * SUCCESS_REWARD * similarity
    } else {
        STEP_PENALTY
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn jaccard_rules() {
        let mut u = [0f32; ATTR_DIM];
        let mut v = [0f32; ATTR_DIM];
        assert_eq!(jaccard(&u, &v), 1.0);
        u[0] = 1.0;
        v[0] = 0.5;
        u[1] = 0.4;
        // dim0: 0.5, dim1: 0, others 1.
        let expect = (0.5 + 0.0 + (ATTR_DIM as f32 - 2.0)) / ATTR_DIM as f32;
        assert!((jaccard(&u, &v) - expect).abs() < 1e-6);
        assert_eq!(jaccard(&u, &v), jaccard(&v, &u));
    }

    #[test]
    fn reward_terms() {
        assert_eq!(step_reward(RewardKind::Navigation, 3.0, 2.0), STEP_PENALTY);
        assert!((step_reward(RewardKind::Mixed, 3.0, 2.0) - (STEP_PENALTY + 0.1)).abs() < 1e-6);
        assert_eq!(step_reward(RewardKind::Distance, 2.0, 3.0), STEP_PENALTY);
        assert_eq!(done_reward(RewardKind::Navigation, true, 1.0), 5.0);
        assert_eq!(done_reward(RewardKind::Distance, false, 0.8), STEP_PENALTY);
        assert!(
            (done_reward(RewardKind::Similarity, false, 0.8) - (STEP_PENALTY + 0.4)).abs() < 1e-6
        );
    }
}
