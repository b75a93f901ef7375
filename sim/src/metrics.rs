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
    /// The episode ended with Done (successful or not), not at the step limit.
    #[serde(default)]
    pub done_called: bool,
    /// The step after which the target was first visible (0: from the start), `None` if it
    /// never was.
    #[serde(default)]
    pub target_first_visible: Option<u32>,
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

/// The Wilson score interval (95%, z = 1.96) of a success rate: `successes` of `n` trials, in
/// percent. Unlike the normal approximation it stays inside [0, 100] and is not empty at 0 or
/// `n` successes; `(0, 100)` for `n = 0`.
pub fn wilson_interval(successes: usize, n: usize) -> (f64, f64) {
    if n == 0 {
        return (0.0, 100.0);
    }
    const Z: f64 = 1.959_963_984_540_054;
    let (k, n) = (successes as f64, n as f64);
    let p = k / n;
    let z2 = Z * Z;
    let centre = (p + z2 / (2.0 * n)) / (1.0 + z2 / n);
    let half = Z / (1.0 + z2 / n) * (p * (1.0 - p) / n + z2 / (4.0 * n * n)).sqrt();
    (
        (100.0 * (centre - half)).max(0.0),
        (100.0 * (centre + half)).min(100.0),
    )
}

/// The normal-approximation 95% interval of a mean (e.g. of per-episode SPL in [0, 1]), in
/// percent: mean ± 1.96 standard errors, clipped to [0, 100]; `(0, 100)` for fewer than two
/// values.
pub fn mean_interval(values: &[f64]) -> (f64, f64) {
    if values.len() < 2 {
        return (0.0, 100.0);
    }
    let n = values.len() as f64;
    let mean = values.iter().sum::<f64>() / n;
    let var = values.iter().map(|v| (v - mean) * (v - mean)).sum::<f64>() / (n - 1.0);
    let half = 1.959_963_984_540_054 * (var / n).sqrt();
    (
        (100.0 * (mean - half)).max(0.0),
        (100.0 * (mean + half)).min(100.0),
    )
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
    fn wilson_known_values() {
        // 8 of 100: the Wilson interval is [4.109 %, 14.998 %] (closed form, z = 1.96).
        let (lo, hi) = wilson_interval(8, 100);
        assert!((lo - 4.109).abs() < 0.01, "{lo}");
        assert!((hi - 14.998).abs() < 0.01, "{hi}");
        // 0 successes: lower bound 0, upper bound z^2 / (n + z^2).
        let (lo, hi) = wilson_interval(0, 50);
        assert_eq!(lo, 0.0);
        assert!((hi - 7.135).abs() < 0.01, "{hi}");
        let (lo, hi) = wilson_interval(50, 50);
        assert!((lo - 92.865).abs() < 0.01, "{lo}");
        assert_eq!(hi, 100.0);
        assert_eq!(wilson_interval(0, 0), (0.0, 100.0));
    }

    #[test]
    fn mean_interval_of_constant_and_spread() {
        assert_eq!(mean_interval(&[0.5, 0.5, 0.5]), (50.0, 50.0));
        // mean 0.5, sample sd 0.5345 over 8 values: half width 1.96 * 0.5345 / sqrt(8) = 0.3704.
        let v = [0.0, 1.0, 0.0, 1.0, 0.0, 1.0, 0.0, 1.0];
        let (lo, hi) = mean_interval(&v);
        assert!((lo - 12.96).abs() < 0.05, "{lo}");
        assert!((hi - 87.04).abs() < 0.05, "{hi}");
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
            done_called: true,
            target_first_visible: Some(1),
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
