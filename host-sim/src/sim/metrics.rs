//! Episode metrics (SR, SPL, EPA, DTS) and their aggregation.
//!
//! * **SR**: share of successful episodes (percent).
//! * **SPL**: success weighted by `L* / max(L, L*)`. Path lengths count actions, including the
//!   final Done: `L*` is the BFS distance over the state graph (position, heading, horizon) from
//!   the start to the nearest state where an instance of the target category is visible, plus
//!   one for Done; `L` is the number of actions the agent took. Percent.
//! * **EPA** (exploration area): share of the scene's reachable positions (after gap filling)
//!   the agent stood on during the episode, start included, in percent.
//! * **DTS** (distance to success): `max(0, d_goal - 1.0)` metres at the end of the episode,
//!   `d_goal` being the horizontal distance to the nearest goal instance's footprint.

use serde::{Deserialize, Serialize};

use super::types::{RoomType, TargetKind};

/// Metrics of one finished episode.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct EpisodeMetrics {
    /// Done was issued while the target was visible.
    pub success: bool,
    /// Actions taken, Done included.
    pub path_length: u32,
    /// Shortest possible path length (actions, Done included); `None` if unsolvable.
    pub shortest_path_length: Option<u32>,
    /// Success weighted by path length, in [0, 1].
    pub spl: f32,
    /// Exploration area, percent of the scene's reachable positions visited.
    pub epa: f32,
    /// Distance to success at the end (metres).
    pub dts: f32,
    /// Sum of rewards.
    pub total_reward: f32,
}

/// SPL of one episode.
pub fn spl(success: bool, path_length: u32, shortest: Option<u32>) -> f32 {
    match (success, shortest) {
        (true, Some(l)) => l as f32 / path_length.max(l).max(1) as f32,
        _ => 0.0,
    }
}

/// Aggregated metrics (SR, SPL, EPA in percent; DTS in metres).
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Summary {
    /// Number of episodes.
    pub episodes: usize,
    /// Success rate (%).
    pub sr: f64,
    /// SPL (%).
    pub spl: f64,
    /// Exploration area (%).
    pub epa: f64,
    /// Distance to success (m).
    pub dts: f64,
}

impl Summary {
    /// Mean metrics of `items`.
    pub fn of<'a>(items: impl IntoIterator<Item = &'a EpisodeMetrics>) -> Summary {
        let mut s = Summary::default();
        for m in items {
            s.episodes += 1;
            s.sr += m.success as u8 as f64;
            s.spl += m.spl as f64;
            s.epa += m.epa as f64;
            s.dts += m.dts as f64;
        }
        if s.episodes > 0 {
            let n = s.episodes as f64;
            s.sr *= 100.0 / n;
            s.spl *= 100.0 / n;
            s.epa /= n;
            s.dts /= n;
        }
        s
    }
}

/// One evaluated episode: what it was and how it went.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct EpisodeResult {
    /// Index in the evaluated episode list.
    pub index: usize,
    /// Scene name.
    pub scene: String,
    /// Room type.
    pub room: RoomType,
    /// Seen or unseen target.
    pub kind: TargetKind,
    /// Target category name.
    pub target: String,
    /// Metrics.
    pub metrics: EpisodeMetrics,
    /// Why the agent could not run the episode to its end (a navigator error: a shape error,
    /// non-finite probabilities, ...); `None` for a normal episode. A failed episode still
    /// counts in the metrics (it ended where the error happened, usually as a failure), and
    /// `gman eval` reports and exits non-zero on it.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub error: Option<String>,
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn spl_rules() {
        assert_eq!(spl(true, 10, Some(5)), 0.5);
        assert_eq!(spl(true, 3, Some(5)), 1.0);
        assert_eq!(spl(false, 5, Some(5)), 0.0);
        assert_eq!(spl(true, 5, None), 0.0);
    }

    #[test]
    fn summary_means() {
        let a = EpisodeMetrics {
            success: true,
            path_length: 4,
            shortest_path_length: Some(2),
            spl: 0.5,
            epa: 10.0,
            dts: 0.0,
            total_reward: 0.0,
        };
        let b = EpisodeMetrics {
            success: false,
            spl: 0.0,
            epa: 20.0,
            dts: 1.0,
            ..a
        };
        let s = Summary::of([&a, &b]);
        assert_eq!(s.episodes, 2);
        assert_eq!(s.sr, 50.0);
        assert_eq!(s.spl, 25.0);
        assert_eq!(s.epa, 15.0);
        assert_eq!(s.dts, 0.5);
    }
}
