//! Radio models: is a robot pair in communication range? (docs/design.md §5 "Radio models".)
//!
//! * `always`: unlimited range.
//! * `disk`: in range iff the distance is at most `range_m` (the thesis, 001, 004).
//! * `pathloss`: the log-distance path loss model with a wall attenuation factor that de Hoog,
//!   Cameron and Visser use in MRESim (paper 003, §VI-A, after Bahl & Padmanabhan's RADAR):
//!
//!   S = P(d₀) − 10·N·log₁₀(d / d₀) − min(nW, C)·WAF
//!
//!   with P(d₀) the reference signal strength at distance d₀, N the path loss exponent, nW the
//!   number of walls the straight line between the robots crosses on the *truth* map, C the most
//!   walls counted and WAF the attenuation per wall. The link is up iff S ≥ threshold. By
//!   default the threshold is derived from `radio.range_m` so that the free-space range equals
//!   `range_m` and walls only shorten it.
//!
//! Links that degrade (docs/guide/radio.md): with `pathloss`, each pair's signal is off the model's
//! by a fixed log-normal shadowing draw (σ = `radio.shadowing_db`, seeded by the scenario seed and
//! the pair, the same both ways), which moves its range; in each step a frame is delivered with
//! probability (1 − `radio.frame_loss`)·Φ(margin / σ_f), the margin being the shadowed signal above
//! the threshold and σ_f `radio.fading_db` ([`delivery`](crate::radio::delivery)). A lost frame is
//! sent again (netem's `channel`); each direction draws its own loss, so the two ways of a link
//! lose different frames. Every draw is a hash of the seed, the pair, the direction and the step:
//! the same scenario loses the same frames.
//!
//! A wall is a maximal run of non-free cells along the segment, so a thick wall counts once. The
//! segment is walked cell by cell with the workspace's grid traversal ([`proto::traverse`], the
//! plain variant: one side cell at an exact corner), clipped to the map first, so the work is
//! bounded by the map size whatever the poses.

use std::sync::Arc;

use proto::geom::{MapInfo, Pose};
use proto::grid::{Grid, Occ};
use proto::msg::RobotId;
use proto::scenario::RadioModel;
use serde::Serialize;

pub use proto::pathloss::{count_walls, PathLoss};

/// On the truth map every cell that is not free is wall (robots may count only what they saw).
pub fn truth_wall(o: Occ) -> bool {
    o != Occ::Free
}

/// A radio model with what it needs to decide.
#[derive(Clone, Debug)]
pub enum Model {
    Always,
    Disk { range_m: f64 },
    PathLoss(PathLoss),
}

/// The outcome of a range test.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct Verdict {
    pub in_range: bool,
    pub distance_m: f64,
    /// Walls crossed (path loss with a truth map only).
    pub walls: Option<u32>,
    /// With its shadowing (path loss only).
    pub signal_dbm: Option<f64>,
    /// The signal above the threshold, dB (path loss only).
    #[serde(skip)]
    pub margin_db: Option<f64>,
}

/// A radio model plus the truth map it counts walls on.
#[derive(Clone, Debug)]
pub struct Radio {
    pub model: Model,
    truth: Option<Arc<(MapInfo, Grid)>>,
    /// Log-normal shadowing: the seed and σ in dB (path loss only).
    shadowing: Option<(u64, f64)>,
}

impl Radio {
    pub fn new(model: Model, truth: Option<Arc<(MapInfo, Grid)>>) -> Radio {
        Radio {
            model,
            truth,
            shadowing: None,
        }
    }

    /// With each pair's signal off by a fixed draw of N(0, `sigma_db`²) ([`shadowing_db`]).
    pub fn with_shadowing(mut self, seed: u64, sigma_db: f64) -> Radio {
        self.shadowing = (sigma_db > 0.0).then_some((seed, sigma_db));
        self
    }

    /// The same radio with its range set to `range_m` (`disk`: the disk; `pathloss`: the
    /// threshold whose free-space range it is, walls and shadowing as they are; `always`: as
    /// it is) — how far a transmission interferes.
    pub fn with_range(&self, range_m: f64) -> Radio {
        let model = match &self.model {
            Model::Always => Model::Always,
            Model::Disk { .. } => Model::Disk { range_m },
            Model::PathLoss(p) => Model::PathLoss(PathLoss {
                threshold_dbm: PathLoss::threshold_for_range(
                    p.ref_dbm,
                    p.ref_distance_m,
                    p.exponent,
                    range_m,
                ),
                ..*p
            }),
        };
        Radio {
            model,
            ..self.clone()
        }
    }

    /// Whether robots `ids` = (a, b) at `a` and `b` can talk: [`Radio::evaluate`] with the
    /// pair's shadowing.
    pub fn evaluate_pair(&self, ids: (RobotId, RobotId), a: &Pose, b: &Pose) -> Verdict {
        let mut v = self.evaluate(a, b);
        if let (Some((seed, sigma)), Model::PathLoss(p), Some(s)) =
            (self.shadowing, &self.model, v.signal_dbm)
        {
            let s = s + shadowing_db(seed, ids.0, ids.1, sigma);
            v.signal_dbm = Some(s);
            v.margin_db = Some(s - p.threshold_dbm);
            v.in_range = s >= p.threshold_dbm;
        }
        v
    }

    /// The scenario's model name, for logs.
    pub fn kind(&self) -> RadioModel {
        match self.model {
            Model::Always => RadioModel::Always,
            Model::Disk { .. } => RadioModel::Disk,
            Model::PathLoss(_) => RadioModel::Pathloss,
        }
    }

    /// Whether robots at `a` and `b` can talk. Non-finite poses are out of range (except for
    /// `always`).
    pub fn evaluate(&self, a: &Pose, b: &Pose) -> Verdict {
        let distance_m = a.xy().dist(b.xy());
        let finite = distance_m.is_finite();
        match &self.model {
            Model::Always => Verdict {
                in_range: true,
                distance_m,
                walls: None,
                signal_dbm: None,
                margin_db: None,
            },
            Model::Disk { range_m } => Verdict {
                in_range: finite && distance_m <= *range_m,
                distance_m,
                walls: None,
                signal_dbm: None,
                margin_db: None,
            },
            Model::PathLoss(p) => {
                let walls = match (&self.truth, finite) {
                    (Some(t), true) => Some(count_walls(&t.0, &t.1, a.xy(), b.xy(), truth_wall)),
                    _ => None,
                };
                let s = p.signal_dbm(distance_m, walls.unwrap_or(0));
                Verdict {
                    in_range: finite && s >= p.threshold_dbm,
                    distance_m,
                    walls,
                    signal_dbm: finite.then_some(s),
                    margin_db: finite.then_some(s - p.threshold_dbm),
                }
            }
        }
    }
}

/// A uniform draw in [0, 1) that is a function of its inputs alone (splitmix64's finaliser
/// over them): the seed, a pair, a direction or salt, a step.
pub fn uniform(seed: u64, a: RobotId, b: RobotId, salt: u64, step: u64) -> f64 {
    let mix = |mut z: u64| {
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        z ^ (z >> 31)
    };
    let mut h = mix(seed ^ 0x9e37_79b9_7f4a_7c15);
    for v in [u64::from(a), u64::from(b), salt, step] {
        h = mix(h.wrapping_add(0x9e37_79b9_7f4a_7c15) ^ v);
    }
    (h >> 11) as f64 / (1u64 << 53) as f64
}

/// Pair (a, b)'s shadowing, dB: a draw of N(0, `sigma_db`²) fixed by the seed and the pair, the
/// same both ways (Box–Muller over two [`uniform`] draws; `libm` so that every machine draws
/// the same).
pub fn shadowing_db(seed: u64, a: RobotId, b: RobotId, sigma_db: f64) -> f64 {
    let (lo, hi) = (a.min(b), a.max(b));
    let u1 = 1.0 - uniform(seed, lo, hi, SALT_SHADOWING, 0);
    let u2 = uniform(seed, lo, hi, SALT_SHADOWING, 1);
    sigma_db * libm::sqrt(-2.0 * libm::log(u1)) * libm::cos(std::f64::consts::TAU * u2)
}

const SALT_SHADOWING: u64 = 0x5bad;
const SALT_LOSS: u64 = 0x1055;

/// The probability that a frame on a link is delivered in a step: (1 − `frame_loss`) times,
/// with fading of σ `fading_db` > 0 and a signal `margin_db` above the threshold, Φ(margin / σ)
/// — the chance that the faded signal is still above the threshold. A link at the edge of its
/// range delivers half its frames, one σ inside 84 %.
pub fn delivery(frame_loss: f64, fading_db: f64, margin_db: Option<f64>) -> f64 {
    let fading = match margin_db {
        Some(m) if fading_db > 0.0 => 0.5 * libm::erfc(-m / (fading_db * std::f64::consts::SQRT_2)),
        _ => 1.0,
    };
    (1.0 - frame_loss) * fading
}

/// Whether direction `dir` (0: a → b) of pair (a, b)'s frame of `step` is lost, for a delivery
/// probability `p`.
pub fn lost(seed: u64, (a, b): (RobotId, RobotId), dir: usize, step: u64, p: f64) -> bool {
    p < 1.0 && uniform(seed, a, b, SALT_LOSS + dir as u64, step) >= p
}

#[cfg(test)]
mod tests {
    use super::*;

    fn map(g: &Grid) -> MapInfo {
        MapInfo::at_origin(g.width(), g.height(), 1.0)
    }

    const ROOMS: &str = "
        ..#..#..
        ..#..#..
        ..##.#..
        ........
    ";

    #[test]
    fn disk_and_always() {
        let disk = Radio::new(Model::Disk { range_m: 5.0 }, None);
        let p = |x| Pose {
            x,
            y: 0.0,
            theta: 0.0,
        };
        assert!(disk.evaluate(&p(0.0), &p(5.0)).in_range);
        assert!(!disk.evaluate(&p(0.0), &p(5.01)).in_range);
        assert!(!disk.evaluate(&p(0.0), &p(f64::NAN)).in_range);
        let always = Radio::new(Model::Always, None);
        assert!(always.evaluate(&p(0.0), &p(1e9)).in_range);
    }

    #[test]
    fn pathloss_range_equals_range_m_in_free_space_and_walls_shorten_it() {
        let p = PathLoss {
            ref_dbm: -40.0,
            ref_distance_m: 1.0,
            exponent: 2.0,
            wall_attenuation_db: 3.1,
            max_walls: 4,
            threshold_dbm: PathLoss::threshold_for_range(-40.0, 1.0, 2.0, 6.0),
        };
        assert!((p.signal_dbm(6.0, 0) - p.threshold_dbm).abs() < 1e-9);
        assert!(p.signal_dbm(0.1, 0) == p.ref_dbm, "below d0 reads as d0");
        assert_eq!(
            p.signal_dbm(3.0, 9),
            p.signal_dbm(3.0, 4),
            "at most C walls count"
        );
        let g = Grid::from_ascii(ROOMS);
        let r = Radio::new(Model::PathLoss(p), Some(Arc::new((map(&g), g))));
        let at = |x, y| Pose { x, y, theta: 0.0 };
        let free = r.evaluate(&at(0.5, 0.5), &at(6.0, 0.5));
        assert!(free.in_range && free.walls == Some(0));
        let walled = r.evaluate(&at(0.5, 3.5), &at(6.0, 3.5));
        assert_eq!(walled.walls, Some(2));
        assert!(!walled.in_range, "5.5 m through two walls: {walled:?}");
        let near = r.evaluate(&at(1.5, 3.5), &at(3.5, 3.5));
        assert!(near.in_range, "2 m through one wall: {near:?}");
    }

    #[test]
    fn shadowing_is_fixed_per_pair_the_same_both_ways_and_of_its_sigma() {
        assert_eq!(shadowing_db(7, 1, 2, 6.0), shadowing_db(7, 2, 1, 6.0));
        assert_ne!(shadowing_db(7, 1, 2, 6.0), shadowing_db(8, 1, 2, 6.0));
        let draws: Vec<f64> = (0..2000u16)
            .flat_map(|a| [(a, a + 1)])
            .map(|(a, b)| shadowing_db(3, a, b, 6.0))
            .collect();
        let n = draws.len() as f64;
        let mean = draws.iter().sum::<f64>() / n;
        let sd = (draws.iter().map(|d| (d - mean).powi(2)).sum::<f64>() / (n - 1.0)).sqrt();
        // 2 000 draws: the mean within 4 standard errors of 0, σ within 6 %.
        assert!(mean.abs() < 4.0 * 6.0 / n.sqrt(), "mean {mean}");
        assert!((sd / 6.0 - 1.0).abs() < 0.06, "sd {sd}");
    }

    #[test]
    fn delivery_follows_the_margin_under_fading() {
        assert_eq!(delivery(0.0, 0.0, Some(-3.0)), 1.0);
        assert!((delivery(0.0, 4.0, Some(0.0)) - 0.5).abs() < 1e-12);
        assert!((delivery(0.0, 4.0, Some(4.0)) - 0.841_344_746).abs() < 1e-6);
        assert!((delivery(0.2, 4.0, Some(-4.0)) - 0.8 * 0.158_655_254).abs() < 1e-6);
        assert_eq!(delivery(0.25, 4.0, None), 0.75);
    }

    /// Over many steps the share of frames lost is the configured probability, within the
    /// binomial's 99.9 % interval; the two ways of a link lose different frames.
    #[test]
    fn the_loss_rate_over_many_steps_is_the_configured_probability() {
        let steps = 20_000u64;
        for p_loss in [0.01, 0.1, 0.3, 0.5] {
            let p = 1.0 - p_loss;
            let count = |dir| (0..steps).filter(|&t| lost(11, (2, 5), dir, t, p)).count();
            let (ab, ba) = (count(0), count(1));
            let half_width = 3.29 * (p_loss * (1.0 - p_loss) / steps as f64).sqrt();
            for k in [ab, ba] {
                let rate = k as f64 / steps as f64;
                assert!((rate - p_loss).abs() <= half_width, "{p_loss}: {rate}");
            }
            let both = (0..steps)
                .filter(|&t| lost(11, (2, 5), 0, t, p) && lost(11, (2, 5), 1, t, p))
                .count() as f64;
            let expected = p_loss * p_loss * steps as f64;
            assert!(
                (both - expected).abs() <= 4.0 * expected.sqrt() + 1.0,
                "{p_loss}: both {both}"
            );
        }
        assert!(!(0..1000).any(|t| lost(11, (2, 5), 0, t, 1.0)));
    }

    #[test]
    fn shadowing_moves_a_pairs_range_and_interference_has_its_own() {
        let p = PathLoss {
            ref_dbm: -40.0,
            ref_distance_m: 1.0,
            exponent: 2.0,
            wall_attenuation_db: 3.1,
            max_walls: 4,
            threshold_dbm: PathLoss::threshold_for_range(-40.0, 1.0, 2.0, 10.0),
        };
        let r = Radio::new(Model::PathLoss(p), None).with_shadowing(9, 8.0);
        let at = |x| Pose {
            x,
            y: 0.0,
            theta: 0.0,
        };
        // Some pairs at 9.5 m are cut and some at 10.5 m linked, by their shadowing alone.
        let cut = (0..40u16).filter(|&i| !r.evaluate_pair((i, i + 1), &at(0.0), &at(9.5)).in_range);
        let linked =
            (0..40u16).filter(|&i| r.evaluate_pair((i, i + 1), &at(0.0), &at(10.5)).in_range);
        assert!(cut.count() > 0 && linked.count() > 0);
        let v = r.evaluate_pair((3, 4), &at(0.0), &at(5.0));
        assert_eq!(v, r.evaluate_pair((4, 3), &at(5.0), &at(0.0)));
        let wide = Radio::new(Model::PathLoss(p), None).with_range(20.0);
        assert!(wide.evaluate(&at(0.0), &at(19.0)).in_range);
        assert!(
            !Radio::new(Model::PathLoss(p), None)
                .evaluate(&at(0.0), &at(19.0))
                .in_range
        );
    }
}
