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
use proto::grid::{Cell, Grid, Occ};
use proto::scenario::RadioModel;
use proto::traverse::{clip, Corners, Traversal};
use serde::Serialize;

pub use proto::pathloss::PathLoss;

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
        let distance_m = (a.x - b.x).hypot(a.y - b.y);
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
                    (Some(t), true) => Some(count_walls(&t.0, &t.1, (a.x, a.y), (b.x, b.y))),
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

/// The number of walls (maximal runs of non-free cells) the segment `a`–`b` (metres) crosses on
/// `grid`. The parts of the segment outside the map cross nothing.
pub fn count_walls(map: &MapInfo, grid: &Grid, a: (f64, f64), b: (f64, f64)) -> u32 {
    let res = map.resolution_m;
    if res.is_nan() || res <= 0.0 || grid.is_empty() {
        return 0;
    }
    // Cell coordinates: cell (i, j) covers [i, i+1) × [j, j+1).
    let to_cell = |p: (f64, f64)| ((p.0 - map.origin_x_m) / res, (p.1 - map.origin_y_m) / res);
    let (p0, p1) = (to_cell(a), to_cell(b));
    let (w, h) = (f64::from(grid.width()), f64::from(grid.height()));
    let Some((t0, t1)) = clip(p0, p1, (0.0, 0.0), (w, h)) else {
        return 0;
    };
    let (dx, dy) = (p1.0 - p0.0, p1.1 - p0.1);
    let (p0, p1) = (
        (p0.0 + t0 * dx, p0.1 + t0 * dy),
        (p0.0 + t1 * dx, p0.1 + t1 * dy),
    );
    // A clipped end on the map's far border lies in the last column (row), not beyond it.
    let last = |v: f64, n: f64| (v.floor() as i64).clamp(0, n as i64 - 1) as i32;
    let start = Cell::new(last(p0.0, w), last(p0.1, h));
    let end = Cell::new(last(p1.0, w), last(p1.1, h));
    // The plain traversal: a wall is counted where the line enters it, and a line through a
    // corner between two wall cells crosses one of them.
    let cells = Traversal::between(p0, start, p1, end, Corners::Thin).map(|x| x.cell);
    let mut walls = 0;
    let mut in_wall = false;
    for cell in std::iter::once(start).chain(cells) {
        let solid = grid.get(cell) != Occ::Free;
        if solid && !in_wall {
            walls += 1;
        }
        in_wall = solid;
    }
    walls
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn map(g: &Grid) -> MapInfo {
        MapInfo::at_origin(g.width(), g.height(), 1.0)
    }

    fn walls(pic: &str, a: (f64, f64), b: (f64, f64)) -> u32 {
        let g = Grid::from_ascii(pic);
        count_walls(&map(&g), &g, a, b)
    }

    const ROOMS: &str = "
        ..#..#..
        ..#..#..
        ..##.#..
        ........
    ";

    #[test]
    fn walls_are_runs_of_non_free_cells_along_the_segment() {
        // Row y = 3 is the top line: two single walls.
        assert_eq!(walls(ROOMS, (0.5, 3.5), (7.5, 3.5)), 2);
        // A thick wall (x = 2..3 on row y = 1) counts once.
        assert_eq!(walls(ROOMS, (0.5, 1.5), (4.5, 1.5)), 1);
        // Along the free bottom row: none.
        assert_eq!(walls(ROOMS, (0.5, 0.5), (7.5, 0.5)), 0);
        // Symmetric.
        assert_eq!(walls(ROOMS, (7.5, 3.5), (0.5, 3.5)), 2);
        // Unknown counts as solid.
        assert_eq!(walls("..?..\n", (0.5, 0.5), (4.5, 0.5)), 1);
    }

    #[test]
    fn segments_outside_the_map_are_clipped() {
        assert_eq!(walls(ROOMS, (-100.5, 3.5), (100.5, 3.5)), 2);
        assert_eq!(walls(ROOMS, (-5.0, -5.0), (-1.0, -1.0)), 0);
        assert_eq!(walls(ROOMS, (f64::NAN, 0.0), (1.0, 1.0)), 0);
        assert_eq!(walls(ROOMS, (-1e6, 3.5), (1e6, 3.5)), 2);
        // Absurd poses cost nothing (precision is gone, the walk is bounded by the map).
        assert!(walls(ROOMS, (-1e300, 3.5), (1e300, 3.5)) <= 2);
    }

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

    proptest! {
        #[test]
        fn wall_count_is_bounded_symmetric_and_total(
            cells in proptest::collection::vec(0u8..3, 64),
            ax in -3.0f64..11.0, ay in -3.0f64..11.0, bx in -3.0f64..11.0, by in -3.0f64..11.0,
        ) {
            let mut g = Grid::new(8, 8, Occ::Free);
            for (i, v) in cells.iter().enumerate() {
                let occ = [Occ::Free, Occ::Occupied, Occ::Unknown][*v as usize];
                g.set(g.cell_of(i), occ);
            }
            let m = map(&g);
            let n = count_walls(&m, &g, (ax, ay), (bx, by));
            prop_assert!(n <= 8);
            let back = count_walls(&m, &g, (bx, by), (ax, ay));
            // Corner-grazing segments may pick the other side cell when reversed.
            prop_assert!(n.abs_diff(back) <= 2, "{} vs {}", n, back);
        }
    }
}
