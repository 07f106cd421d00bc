//! The splitting frequency s: how many Douglas–Peucker splits a robot's approximation gets per
//! step (thesis §5.3; docs/design.md §4.7). More splits give finer approximations and more bytes; s
//! is how the polygon exchange fits the bandwidth.
//!
//! * `formula` — thesis eq. 5.5, s = b·p_comm·u / (r(r−1)·d), with p_comm from eq. 5.6 unless
//!   the scenario gives it. The thesis fixes d in advance; here d, the op-log bytes one split
//!   causes, is measured by the robot as it goes (starting from a prior), so s follows it.
//! * `adaptive` — beyond the thesis: a closed loop on what actually waits. While the largest
//!   backlog of any neighbour (bytes of logs it still lacks) exceeds two steps of its budget and
//!   is not draining, s shrinks; while it is under half a step, s grows; in between, or while a
//!   large backlog drains (a link that just came up, catching up on history), it holds. Without
//!   neighbours there is nothing to measure and s holds. It starts at the maximum, where idle
//!   links take it.
//! * `fixed` — s as given.
//!
//! Under unlimited bandwidth (and for a lone robot) the formula has no finite value: s is the
//! configured maximum.

use proto::scenario::{Bandwidth, SplitControl};

/// Weight of the prior d, in splits: the measured mean takes over after a few dozen splits.
const PRIOR_SPLITS: f64 = 10.0;
/// The adaptive control's band, in steps of link budget, and its factors.
const BACKLOG_HIGH_STEPS: f64 = 2.0;
const BACKLOG_LOW_STEPS: f64 = 0.5;
const SHRINK: f64 = 0.75;
const GROW: f64 = 1.1;

/// Thesis eq. 5.6: the probability that at least two of `robots` robots, spread evenly over a
/// `width_m` × `height_m` environment, are within `range_m` of each other in a step.
pub fn p_comm(range_m: f64, width_m: f64, height_m: f64, robots: u32) -> f64 {
    if width_m <= 0.0 || height_m <= 0.0 {
        return 1.0;
    }
    let pairs: f64 = (1..robots).map(f64::from).sum();
    ((range_m / width_m) * (range_m / height_m) * pairs).min(1.0)
}

/// Thesis eq. 5.5: s = b·p_comm·u / (r(r−1)·d), for `b` bytes per step. `None` when it has no
/// finite value (fewer than two robots, or no bytes per split).
pub fn formula(b: f64, p_comm: f64, u: f64, robots: u32, d: f64) -> Option<f64> {
    let r = f64::from(robots);
    let den = r * (r - 1.0) * d;
    (den > 0.0).then(|| b * p_comm * u / den)
}

/// One robot's splitting frequency and what it is derived from.
#[derive(Clone, Debug)]
pub struct SplittingFrequency {
    control: SplitControl,
    min: f64,
    max: f64,
    /// Link budget in bytes per step; `None`: unlimited.
    budget: Option<f64>,
    p_comm: f64,
    usage: f64,
    robots: u32,
    prior_d: f64,
    /// Op-log bytes and splits so far, for the measured d.
    bytes: f64,
    splits: f64,
    s: f64,
    /// The largest backlog at the last step, to tell a draining backlog from a growing one.
    last_backlog: Option<f64>,
}

impl SplittingFrequency {
    /// The control of `cfg` for `robots` robots, a link budget of `budget` bytes per step
    /// (`None`: unlimited) and `p_comm` (used when the scenario does not give one).
    pub fn new(cfg: &Bandwidth, robots: u32, budget: Option<f64>, p_comm: f64) -> Self {
        let mut f = SplittingFrequency {
            control: cfg.control,
            min: cfg.min_splits_per_step,
            max: cfg.max_splits_per_step,
            budget,
            p_comm: cfg.p_comm.unwrap_or(p_comm),
            usage: cfg.usage,
            robots,
            prior_d: cfg.split_bytes_prior,
            bytes: 0.0,
            splits: 0.0,
            s: cfg.splits_per_step,
            last_backlog: None,
        };
        f.s = match cfg.control {
            SplitControl::Formula => f.by_formula().unwrap_or(cfg.splits_per_step),
            // Links are idle when a run starts: the loop starts where idle links take it.
            SplitControl::Adaptive => f.max,
            SplitControl::Fixed => cfg.splits_per_step,
        };
        f
    }

    /// s for the next step.
    pub fn current(&self) -> f64 {
        self.s
    }

    /// d: op-log bytes per split, measured and blended with the prior.
    pub fn bytes_per_split(&self) -> f64 {
        (self.prior_d * PRIOR_SPLITS + self.bytes) / (PRIOR_SPLITS + self.splits)
    }

    /// Eq. 5.5 with the current d, within the bounds; the maximum under unlimited bandwidth.
    fn by_formula(&self) -> Option<f64> {
        let Some(b) = self.budget else {
            return Some(self.max);
        };
        if self.robots < 2 {
            return Some(self.max);
        }
        formula(
            b,
            self.p_comm,
            self.usage,
            self.robots,
            self.bytes_per_split(),
        )
        .map(|s| s.clamp(self.min, self.max))
    }

    /// The mapper made `splits` splits and appended `bytes` bytes of ops this step: d is
    /// updated, and with it the formula's s.
    pub fn record(&mut self, splits: usize, bytes: usize) {
        self.splits += splits as f64;
        self.bytes += bytes as f64;
        if self.control == SplitControl::Formula {
            if let Some(s) = self.by_formula() {
                self.s = s;
            }
        }
    }

    /// After the step's sending: the largest backlog of a neighbour is `backlog` bytes (`None`:
    /// no neighbour to measure). Moves the adaptive control's s.
    pub fn backlog(&mut self, backlog: Option<u64>) {
        if self.control != SplitControl::Adaptive {
            return;
        }
        let Some(b) = self.budget else {
            self.s = self.max;
            return;
        };
        let Some(backlog) = backlog else {
            self.last_backlog = None;
            return;
        };
        let backlog = backlog as f64;
        let draining = self.last_backlog.is_some_and(|last| backlog < last);
        self.last_backlog = Some(backlog);
        if backlog > BACKLOG_HIGH_STEPS * b && !draining {
            self.s = (self.s * SHRINK).max(self.min);
        } else if backlog < BACKLOG_LOW_STEPS * b {
            self.s = (self.s * GROW).min(self.max);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cfg(control: SplitControl) -> Bandwidth {
        Bandwidth {
            control,
            ..Bandwidth::default()
        }
    }

    #[test]
    fn eq_5_6_sums_the_pairs_and_caps_at_one() {
        // 10 m range in a 40 × 40 m world: (1/4)(1/4) per pair; 4 robots → 1+2+3 = 6.
        assert!((p_comm(10.0, 40.0, 40.0, 4) - 6.0 / 16.0).abs() < 1e-12);
        assert_eq!(p_comm(10.0, 40.0, 40.0, 1), 0.0);
        assert_eq!(p_comm(100.0, 40.0, 40.0, 3), 1.0);
    }

    #[test]
    fn eq_5_5_matches_a_hand_computation() {
        // b = 1000 B/step, p = 0.375, u = 0.5, r = 4, d = 10 → 187.5 / 120.
        let s = formula(1000.0, 0.375, 0.5, 4, 10.0).unwrap_or_default();
        assert!((s - 1.5625).abs() < 1e-12);
        assert_eq!(formula(1000.0, 0.375, 0.5, 1, 10.0), None);
    }

    #[test]
    fn the_formula_follows_the_measured_bytes_per_split() {
        let mut f = SplittingFrequency::new(&cfg(SplitControl::Formula), 4, Some(1000.0), 0.375);
        let start = f.current();
        // Splits that cost far more than the prior: s must fall toward b·p·u/(12·40).
        for _ in 0..100 {
            f.record(2, 80);
        }
        assert!(f.current() < start / 2.0, "{start} → {}", f.current());
        assert!((f.bytes_per_split() - 40.0).abs() < 2.0);
    }

    #[test]
    fn unlimited_bandwidth_and_a_lone_robot_get_the_maximum() {
        let c = cfg(SplitControl::Formula);
        assert_eq!(
            SplittingFrequency::new(&c, 4, None, 0.5).current(),
            c.max_splits_per_step
        );
        assert_eq!(
            SplittingFrequency::new(&c, 1, Some(10.0), 0.5).current(),
            c.max_splits_per_step
        );
    }

    #[test]
    fn fixed_never_moves() {
        let c = cfg(SplitControl::Fixed);
        let mut f = SplittingFrequency::new(&c, 4, Some(100.0), 1.0);
        for _ in 0..20 {
            f.record(5, 500);
            f.backlog(Some(1_000_000));
        }
        assert_eq!(f.current(), c.splits_per_step);
    }

    #[test]
    fn adaptive_shrinks_on_backlog_grows_when_drained_and_holds_alone() {
        let c = cfg(SplitControl::Adaptive);
        let mut f = SplittingFrequency::new(&c, 4, Some(1000.0), 0.375);
        let start = f.current();
        assert_eq!(start, c.max_splits_per_step, "idle links at the start");
        for _ in 0..10 {
            f.backlog(Some(5000));
        }
        let low = f.current();
        assert!(
            low < start * 0.1 && low >= c.min_splits_per_step,
            "{start} → {low}"
        );
        f.backlog(None);
        assert_eq!(f.current(), low, "no neighbour, no change");
        // A large backlog that drains (a link catching up) holds s; one that stays shrinks it.
        f.backlog(Some(6000));
        let low = f.current();
        for b in (0..10).rev() {
            f.backlog(Some(5000 + b * 100));
            assert_eq!(f.current(), low, "draining, no change");
        }
        f.backlog(Some(5000));
        assert!(f.current() < low, "not draining");
        let low = f.current();
        f.backlog(Some(1000));
        assert_eq!(f.current(), low, "inside the band, no change");
        for _ in 0..200 {
            f.backlog(Some(0));
        }
        assert_eq!(f.current(), c.max_splits_per_step);
    }
}
