//! Map fidelity: how true what a robot plans on is. Coverage counts the cells a robot *knows*;
//! fidelity asks whether what it believes of them is so. A planning grid holds the robot's own
//! sensing (G_s, which the laser model keeps true) and its peers' polygonal approximations, which
//! are coarse where the radio was weak: an approximating edge may cut through a wall or fill a
//! block between corridors, and the robot then believes free what is not.
//!
//! Scored against the world's truth at simulation resolution, over the grid's known part:
//! * `free_cells` — the cells the grid holds free;
//! * `false_free_cells` — of those, the ones not free in the truth (occupied, or outside the
//!   world: truth-unknown space is opaque in the simulation);
//! * `on_wall_cells` — of those, the ones occupied in the truth;
//! * `correct_known_cells` — known cells whose state agrees with the truth (an occupied belief
//!   agrees with any truth that is not free).
//!
//! The percentages are of `free_cells`; `summary.json`'s `fidelity` gives the median and the
//! worst robot at the end of the run.

use proto::grid::{Cell, Grid, Occ};

use crate::rundir::summary::FidelitySummary;

/// What one planning grid believes, against the truth (cells).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Fidelity {
    pub correct: u32,
    pub free: u32,
    pub false_free: u32,
    pub on_walls: u32,
}

impl Fidelity {
    /// Scores the known part of a planning grid against the truth (grids of one size) afresh:
    /// what the evaluator's counts, moved by each change ([`Fidelity::change`]), are held to.
    #[cfg(test)]
    pub fn of(grid: &proto::grid::KnownPart, truth: &Grid) -> Fidelity {
        let mut f = Fidelity::default();
        let Some(r) = grid.rect() else { return f };
        for y in r.min.y..=r.max.y {
            let truth = truth.row(y, r.min.x, r.max.x);
            for (&seen, &truth) in grid.row(y).iter().zip(truth) {
                f.add(seen, truth);
            }
        }
        f
    }

    fn add(&mut self, seen: Occ, truth: Occ) {
        let c = Fidelity::cell(seen, truth);
        self.correct += c.correct;
        self.free += c.free;
        self.false_free += c.false_free;
        self.on_walls += c.on_walls;
    }

    /// A cell the grid believed `was` now believed `now` (`truth` in the world).
    pub fn change(&mut self, was: Occ, now: Occ, truth: Occ) {
        let c = Fidelity::cell(was, truth);
        self.correct -= c.correct;
        self.free -= c.free;
        self.false_free -= c.false_free;
        self.on_walls -= c.on_walls;
        self.add(now, truth);
    }

    /// What one cell believed `seen` counts, against the truth.
    fn cell(seen: Occ, truth: Occ) -> Fidelity {
        match seen {
            Occ::Unknown => Fidelity::default(),
            Occ::Free => Fidelity {
                free: 1,
                false_free: u32::from(false_free(seen, truth)),
                on_walls: u32::from(truth == Occ::Occupied),
                correct: u32::from(truth == Occ::Free),
            },
            Occ::Occupied => Fidelity {
                correct: u32::from(truth != Occ::Free),
                ..Fidelity::default()
            },
        }
    }

    /// `false_free` as a percentage of the cells believed free (`None`: none believed free).
    pub fn false_free_pct(&self) -> Option<f64> {
        pct(self.false_free, self.free)
    }

    /// `on_walls` as a percentage of the cells believed free.
    pub fn on_walls_pct(&self) -> Option<f64> {
        pct(self.on_walls, self.free)
    }
}

/// The one rule: a cell believed free that is not free in the truth.
fn false_free(seen: Occ, truth: Occ) -> bool {
    seen == Occ::Free && truth != Occ::Free
}

fn pct(part: u32, of: u32) -> Option<f64> {
    (of > 0).then(|| 100.0 * f64::from(part) / f64::from(of))
}

/// The cells a planning grid holds free that are not free in the truth (what the viewer marks).
pub fn false_free_cells(grid: &Grid, truth: &Grid) -> Vec<Cell> {
    (0..grid.height() as i32)
        .flat_map(|y| (0..grid.width() as i32).map(move |x| Cell::new(x, y)))
        .filter(|&c| false_free(grid.get(c), truth.get(c)))
        .collect()
}

/// The median and the worst robot of the team's last reports: each robot's last row's
/// `(false_free_pct, on_walls_pct)`.
pub fn summarize(last: impl IntoIterator<Item = (Option<f64>, Option<f64>)>) -> FidelitySummary {
    let (mut false_free, mut on_walls): (Vec<f64>, Vec<f64>) = (Vec::new(), Vec::new());
    for (f, w) in last {
        false_free.extend(f);
        on_walls.extend(w);
    }
    let of = |mut v: Vec<f64>| {
        v.sort_by(f64::total_cmp);
        (median(&v), v.last().copied())
    };
    let (false_free_pct_median, false_free_pct_worst) = of(false_free);
    let (on_walls_pct_median, on_walls_pct_worst) = of(on_walls);
    FidelitySummary {
        false_free_pct_median,
        false_free_pct_worst,
        on_walls_pct_median,
        on_walls_pct_worst,
    }
}

/// The median of sorted values (the mean of the two middle ones for an even count).
fn median(sorted: &[f64]) -> Option<f64> {
    let n = sorted.len();
    match n {
        0 => None,
        _ if n % 2 == 1 => Some(sorted[n / 2]),
        _ => Some((sorted[n / 2 - 1] + sorted[n / 2]) / 2.0),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rundir::tables::MetricsRow;
    use proto::grid::KnownPart;

    /// A hand-made case: a room whose planning grid a coarse peer approximation filled
    /// through its wall and beyond the world's edge.
    #[test]
    fn a_belief_filled_through_a_wall_counts_false_free_and_on_wall_cells() {
        // The truth: a 6×3 room, wall column at x = 3, unknown (outside the world) at x = 5.
        let truth = Grid::from_ascii("...#.?\n...#.?\n...#.?\n");
        // Believed: the left part right, the wall free on two rows, the outside free on one,
        // one truth-free cell believed occupied, one cell not known.
        let grid = Grid::from_ascii("....#.\n...#..\n.#.#.?\n");
        let known = KnownPart::from_rle(&grid.to_rle()).expect("a grid");
        let f = Fidelity::of(&known, &truth);
        // Lines are rows from the top (the first is y = 2). Free beliefs: y = 2 has x = 0,1,2,3,5
        // (5), y = 1 x = 0,1,2,4,5 (5), y = 0 x = 0,2,4 (3).
        assert_eq!(f.free, 13);
        // Not free in the truth: (3,2) wall, (5,2) outside, (5,1) outside.
        assert_eq!(f.false_free, 3);
        assert_eq!(f.on_walls, 1, "only (3, 2) is a truth wall believed free");
        // Correct: the 10 free beliefs on free truth, and of the occupied beliefs (3,1) and
        // (3,0) (walls) but not (4,2) or (1,0) (truth-free).
        assert_eq!(f.correct, 12);
        assert_eq!(f.false_free_pct(), Some(100.0 * 3.0 / 13.0));
        assert_eq!(f.on_walls_pct(), Some(100.0 / 13.0));
        assert_eq!(
            false_free_cells(&grid, &truth),
            [Cell::new(5, 1), Cell::new(3, 2), Cell::new(5, 2)]
        );
        assert_eq!(
            Fidelity::of(
                &KnownPart::from_rle(&truth.to_rle()).expect("a grid"),
                &truth
            )
            .false_free_pct(),
            Some(0.0),
            "the truth is true of itself"
        );
    }

    #[test]
    fn the_summary_takes_each_robots_last_row_and_leaves_the_base_station_out() {
        let row = |step, robot, ff: Option<f64>, w: Option<f64>| MetricsRow {
            step,
            robot,
            false_free_pct: ff,
            on_walls_pct: w,
            ..MetricsRow::default()
        };
        let rows = [
            row(5, 0, Some(10.0), Some(1.0)),
            row(1, 0, Some(90.0), Some(9.0)),
            row(5, 1, Some(2.0), Some(0.0)),
            row(5, 2, Some(4.0), Some(3.0)),
            row(5, 3, None, None),
            // The base station (node 4 of a 4-robot run): left out.
            row(5, 4, Some(99.0), Some(99.0)),
        ];
        let mut tally = crate::run::tables::RowTally::new(4, Some(4));
        for r in &rows {
            tally.add(r);
        }
        let s = tally.fidelity();
        assert_eq!(
            (s.false_free_pct_median, s.false_free_pct_worst),
            (Some(4.0), Some(10.0))
        );
        assert_eq!(
            (s.on_walls_pct_median, s.on_walls_pct_worst),
            (Some(1.0), Some(3.0))
        );
        assert_eq!(median(&[1.0, 3.0]), Some(2.0));
        assert_eq!(summarize([]), FidelitySummary::default());
    }
}
