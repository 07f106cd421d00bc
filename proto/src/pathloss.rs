//! The log-distance path loss model with a wall attenuation factor (de Hoog, Cameron & Visser 2010,
//! §VI-A, after Bahl & Padmanabhan's RADAR, 2000): the signal at distance d through nW walls is
//!
//!   S = P(d₀) − 10·N·log₁₀(d / d₀) − min(nW, C)·WAF
//!
//! netem decides links with it on the truth map; a robot estimates with the same formula, on its
//! own map, how far it could be heard from a place (the `roles` strategy's rendezvous points).

use crate::geom::{MapInfo, Metres};
use crate::grid::{Cell, Grid, Occ};
use crate::scenario::{Radio, RadioModel};
use crate::traverse::{clip, Corners, Traversal};

/// Parameters of the path loss model (defaults: free space, RADAR's wall factor and cap).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PathLoss {
    /// P(d₀), dBm.
    pub ref_dbm: f64,
    /// d₀, metres.
    pub ref_distance_m: f64,
    /// N.
    pub exponent: f64,
    /// WAF, dB per wall.
    pub wall_attenuation_db: f64,
    /// C.
    pub max_walls: u32,
    /// Link up iff the signal is at least this, dBm.
    pub threshold_dbm: f64,
}

impl PathLoss {
    /// The threshold at which the free-space range is `range_m`.
    pub fn threshold_for_range(
        ref_dbm: f64,
        ref_distance_m: f64,
        exponent: f64,
        range_m: f64,
    ) -> f64 {
        ref_dbm - 10.0 * exponent * (range_m.max(1e-9) / ref_distance_m.max(1e-9)).log10()
    }

    /// S for a distance and a wall count, dBm. Distances below d₀ read as d₀.
    pub fn signal_dbm(&self, distance_m: f64, walls: u32) -> f64 {
        let d0 = self.ref_distance_m.max(1e-9);
        let d = distance_m.max(d0);
        self.ref_dbm
            - 10.0 * self.exponent * (d / d0).log10()
            - f64::from(walls.min(self.max_walls)) * self.wall_attenuation_db
    }
}

impl PathLoss {
    /// The scenario's path loss model (`None` unless `radio.model = "pathloss"`); the threshold
    /// defaults to the one at which the free-space range is `radio.range_m`.
    pub fn of(r: &Radio) -> Option<PathLoss> {
        (r.model == RadioModel::Pathloss).then(|| PathLoss {
            ref_dbm: r.pathloss_ref_dbm,
            ref_distance_m: r.pathloss_ref_distance_m,
            exponent: r.pathloss_exponent,
            wall_attenuation_db: r.pathloss_wall_attenuation_db,
            max_walls: r.pathloss_max_walls,
            threshold_dbm: r.pathloss_threshold_dbm.unwrap_or_else(|| {
                PathLoss::threshold_for_range(
                    r.pathloss_ref_dbm,
                    r.pathloss_ref_distance_m,
                    r.pathloss_exponent,
                    r.range_m,
                )
            }),
        })
    }
}

/// The number of walls — maximal runs of cells that `wall` says are solid — the segment `a`–`b`
/// (metres) crosses on `grid`. The parts of the segment outside the map cross nothing. netem
/// counts on the truth map (every non-free cell is wall); a robot on its own map (only cells it
/// knows occupied).
pub fn count_walls(
    map: &MapInfo,
    grid: &Grid,
    a: Metres,
    b: Metres,
    wall: impl Fn(Occ) -> bool,
) -> u32 {
    walls_along(map, grid, a, b, wall)
        .last()
        .map_or(0, |(_, walls)| walls)
}

/// The cells the segment `a`–`b` (metres) crosses on `grid`, in order, each with the number of
/// walls crossed up to and including it: [`count_walls`] step by step, for a caller that wants
/// the signal along the way (a robot's estimate of its reach). The parts of the segment outside
/// the map are left out. Lazy: netem counts every link's walls every step.
pub fn walls_along<'a>(
    map: &MapInfo,
    grid: &'a Grid,
    a: Metres,
    b: Metres,
    wall: impl Fn(Occ) -> bool + 'a,
) -> impl Iterator<Item = (Cell, u32)> + 'a {
    let (mut walls, mut in_wall) = (0, false);
    crossed(map, grid, a, b)
        .into_iter()
        .flatten()
        .map(move |cell| {
            let solid = wall(grid.get(cell));
            if solid && !in_wall {
                walls += 1;
            }
            in_wall = solid;
            (cell, walls)
        })
}

/// The cells of `grid` the segment `a`–`b` (metres) crosses, by the plain traversal: a wall is
/// counted where the line enters it, and a line through a corner between two wall cells crosses
/// one of them. `None` when no part of the segment lies on the map.
fn crossed(map: &MapInfo, grid: &Grid, a: Metres, b: Metres) -> Option<impl Iterator<Item = Cell>> {
    let res = map.resolution_m;
    if res.is_nan() || res <= 0.0 || grid.is_empty() {
        return None;
    }
    // Cell coordinates: cell (i, j) covers [i, i+1) × [j, j+1).
    let (p0, p1) = (map.in_cells(a), map.in_cells(b));
    let (w, h) = (f64::from(grid.width()), f64::from(grid.height()));
    let (t0, t1) = clip(p0, p1, (0.0, 0.0), (w, h))?;
    let (dx, dy) = (p1.0 - p0.0, p1.1 - p0.1);
    let (p0, p1) = (
        (p0.0 + t0 * dx, p0.1 + t0 * dy),
        (p0.0 + t1 * dx, p0.1 + t1 * dy),
    );
    // A clipped end on the map's far border lies in the last column (row), not beyond it.
    let last = |v: f64, n: f64| (v.floor() as i64).clamp(0, n as i64 - 1) as i32;
    let start = Cell::new(last(p0.0, w), last(p0.1, h));
    let end = Cell::new(last(p1.0, w), last(p1.1, h));
    let cells = Traversal::between(p0, start, p1, end, Corners::Thin).map(|x| x.cell);
    Some(std::iter::once(start).chain(cells))
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn map(g: &Grid) -> MapInfo {
        MapInfo::at_origin(g.width(), g.height(), 1.0)
    }

    const ROOMS: &str = "
        ..#..#..
        ..#..#..
        ..##.#..
        ........
    ";

    fn at(p: (f64, f64)) -> Metres {
        Metres::new(p.0, p.1)
    }

    fn walls(pic: &str, a: (f64, f64), b: (f64, f64)) -> u32 {
        let g = Grid::from_ascii(pic);
        count_walls(&map(&g), &g, at(a), at(b), |o| o != Occ::Free)
    }

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
        // Unknown counts as solid when the caller says so, and not otherwise.
        assert_eq!(walls("..?..\n", (0.5, 0.5), (4.5, 0.5)), 1);
        let g = Grid::from_ascii("..?#.\n");
        let seen = |o: Occ| o == Occ::Occupied;
        assert_eq!(
            count_walls(&map(&g), &g, at((0.5, 0.5)), at((4.5, 0.5)), seen),
            1
        );
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
            let n = count_walls(&m, &g, Metres::new(ax, ay), Metres::new(bx, by), |o| o != Occ::Free);
            prop_assert!(n <= 8);
            let back = count_walls(&m, &g, Metres::new(bx, by), Metres::new(ax, ay), |o| o != Occ::Free);
            // Corner-grazing segments may pick the other side cell when reversed.
            prop_assert!(n.abs_diff(back) <= 2, "{} vs {}", n, back);
        }

        /// The running count a robot's reach estimate reads along a ray is the count of the
        /// segment cut short inside each cell — the one wall rule, whether a caller counts a
        /// whole link (netem, `Reach::linked`) or walks a ray (`Reach::estimate`); the estimate
        /// once counted with a corner rule of its own.
        #[test]
        fn the_running_count_along_a_segment_is_the_count_of_the_segment_cut_there(
            cells in proptest::collection::vec(0u8..3, 64),
            ax in 0.01f64..7.99, ay in 0.01f64..7.99, bx in 0.01f64..7.99, by in 0.01f64..7.99,
        ) {
            let mut g = Grid::new(8, 8, Occ::Free);
            for (i, v) in cells.iter().enumerate() {
                let occ = [Occ::Free, Occ::Occupied, Occ::Unknown][*v as usize];
                g.set(g.cell_of(i), occ);
            }
            let (m, wall) = (map(&g), |o: Occ| o == Occ::Occupied);
            let along: Vec<(Cell, u32)> = walls_along(&m, &g, Metres::new(ax, ay), Metres::new(bx, by), wall).collect();
            for k in 1..=50 {
                let t = f64::from(k) / 50.0;
                let x = Metres::new(ax + t * (bx - ax), ay + t * (by - ay));
                let here = Cell::new(x.x.floor() as i32, x.y.floor() as i32);
                // The count where the walk is in the cell of x (the last visit if two).
                let Some(&(_, running)) = along.iter().rev().find(|(c, _)| *c == here) else {
                    continue; // x on a corner the walk passed by the other side cell
                };
                let cut = count_walls(&m, &g, Metres::new(ax, ay), x, wall);
                prop_assert_eq!(cut, running, "at t = {}, cell {:?}", t, here);
            }
        }
    }
}
