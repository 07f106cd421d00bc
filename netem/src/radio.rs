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
//! A wall is a maximal run of non-free cells along the segment, so a thick wall counts once. The
//! segment is walked cell by cell with the workspace's grid traversal ([`proto::traverse`], the
//! plain variant: one side cell at an exact corner), clipped to the map first, so the work is
//! bounded by the map size whatever the poses.

use std::sync::Arc;

use proto::geom::{MapInfo, Pose};
use proto::grid::{Grid, Occ};
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
    pub signal_dbm: Option<f64>,
}

/// A radio model plus the truth map it counts walls on.
#[derive(Clone, Debug)]
pub struct Radio {
    pub model: Model,
    truth: Option<Arc<(MapInfo, Grid)>>,
}

impl Radio {
    pub fn new(model: Model, truth: Option<Arc<(MapInfo, Grid)>>) -> Radio {
        Radio { model, truth }
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
            },
            Model::Disk { range_m } => Verdict {
                in_range: finite && distance_m <= *range_m,
                distance_m,
                walls: None,
                signal_dbm: None,
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
                }
            }
        }
    }
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
}
