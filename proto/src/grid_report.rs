//! A grid reported step after step as what changed (docs/design.md §6, "Telemetry"): a robot's
//! planning and own grids go to the launcher every step, and late in a run on a big map most of
//! such a grid is the same as a step before. So a report is the rectangle around the cells that
//! changed since the sender's last report ([`GridReport::Changed`]), and the whole grid
//! ([`GridReport::Whole`]) at a sender's first report and every [`KEYFRAME_STEPS`] steps after.
//! The sender keeps the grid as last reported ([`Reporter`]); the receiver keeps it too
//! ([`Received`]), applies each report to it and learns what changed where — so that what it
//! does with a report (scoring, the step log) costs the change, not the map.
//!
//! A change applies to the grid of the report it names (`since`): a receiver that missed a
//! report cannot apply the next ones, and waits for the next whole grid.

use serde::{Deserialize, Serialize};

use crate::grid::{Cell, Grid, Occ, Rect, RleError};
use crate::ids::Step;

/// A sender reports its whole grid at least this often, in steps (a receiver that missed a
/// report has the grid again within this many steps).
pub const KEYFRAME_STEPS: Step = 50;

/// One step's report of a grid.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum GridReport {
    /// The whole grid ([`Grid::to_rle`]).
    Whole(Vec<u8>),
    /// What changed since the sender's report of step `since`: the cells of a rectangle whose
    /// bottom-left cell is `at`, as a grid of the rectangle's size ([`Grid::to_rle`]);
    /// `window: None`, nothing changed.
    Changed {
        since: Step,
        window: Option<(Cell, Vec<u8>)>,
    },
}

impl Default for GridReport {
    fn default() -> GridReport {
        GridReport::Changed {
            since: 0,
            window: None,
        }
    }
}

/// The sender's side: the grid as last reported, and how many of its cells are known.
#[derive(Clone, Debug, Default)]
pub struct Reporter {
    /// The step and grid of the last report, and the step of the last whole one.
    last: Option<(Step, Grid, Step)>,
    known: usize,
}

impl Reporter {
    /// The report of `grid` at `step`.
    pub fn report(&mut self, step: Step, grid: &Grid) -> GridReport {
        self.report_within(step, grid, grid.whole())
    }

    /// [`Reporter::report`] of a grid whose cells outside `changed` are as last reported
    /// (`None`: every cell is): only the cells of `changed` are compared, so a report costs
    /// what the sender says may have changed, not the grid's known part. The same report as
    /// [`Reporter::report`] when that holds.
    pub fn report_within(&mut self, step: Step, grid: &Grid, changed: Option<Rect>) -> GridReport {
        let Some((since, last, _)) = self
            .last
            .as_mut()
            .filter(|(_, l, w)| same_size(l, grid) && step < w.saturating_add(KEYFRAME_STEPS))
        else {
            self.last = Some((step, grid.clone(), step));
            self.known = grid.len() - grid.count(Occ::Unknown);
            return GridReport::Whole(grid.to_rle());
        };
        let from = *since;
        *since = step;
        let region = changed.and_then(|c| c.within(grid.width(), grid.height()));
        let window = differing(last, grid, region).map(|r| {
            let w = window_of(grid, r);
            for y in r.min.y..=r.max.y {
                let (now, was) = (
                    grid.row(y, r.min.x, r.max.x),
                    last.row_mut(y, r.min.x, r.max.x),
                );
                self.known = self.known + known_in(now) - known_in(was);
                was.copy_from_slice(now);
            }
            (r.min, w.to_rle())
        });
        GridReport::Changed {
            since: from,
            window,
        }
    }

    /// The cells of the grid last reported that are not unknown.
    pub fn known(&self) -> usize {
        self.known
    }
}

/// The cells of `row` that are not unknown.
fn known_in(row: &[Occ]) -> usize {
    row.iter().map(|&c| usize::from(c != Occ::Unknown)).sum()
}

fn same_size(a: &Grid, b: &Grid) -> bool {
    a.width() == b.width() && a.height() == b.height()
}

/// The smallest rectangle around the cells of `region` where `old` and `new` (of one size)
/// differ.
fn differing(old: &Grid, new: &Grid, region: Option<Rect>) -> Option<Rect> {
    let known = Rect::union_of(old.known_bounds(), new.known_bounds())?;
    let r = region?.intersection(known)?;
    let mut out: Option<Rect> = None;
    for y in r.min.y..=r.max.y {
        let (a, b) = (old.row(y, r.min.x, r.max.x), new.row(y, r.min.x, r.max.x));
        // Without an early exit, so that the comparison runs many cells at a time.
        let differ = a
            .iter()
            .zip(b)
            .fold(0u8, |d, (&p, &q)| d | (p as u8 ^ q as u8));
        if differ == 0 {
            continue;
        }
        let first = a.iter().zip(b).position(|(p, q)| p != q).unwrap_or(0);
        let last = a.iter().zip(b).rposition(|(p, q)| p != q).unwrap_or(first);
        let row = Rect {
            min: Cell::new(r.min.x + first as i32, y),
            max: Cell::new(r.min.x + last as i32, y),
        };
        out = Some(out.map_or(row, |o| o.union(row)));
    }
    out
}

/// The cells of `r` (inside `grid`) as a grid of `r`'s size.
fn window_of(grid: &Grid, r: Rect) -> Grid {
    let mut w = Grid::new(r.width(), r.height(), Occ::Unknown);
    for y in r.min.y..=r.max.y {
        let row = grid.row(y, r.min.x, r.max.x);
        if row.iter().any(|&c| c != Occ::Unknown) {
            w.row_mut(y - r.min.y, 0, r.width() as i32 - 1)
                .copy_from_slice(row);
        }
    }
    w
}

/// Why a report could not be applied.
#[derive(Debug, thiserror::Error, PartialEq, Eq)]
pub enum ReportError {
    #[error("the grid does not decode: {0}")]
    Rle(#[from] RleError),
    #[error("a grid of {got:?} cells, not {want:?}")]
    Size { got: (u32, u32), want: (u32, u32) },
    #[error("a change since step {since}, and the grid held is of step {held:?}")]
    Gap { since: Step, held: Option<Step> },
    #[error("a change of {width}×{height} cells at ({x}, {y}) outside the grid")]
    Outside {
        x: i32,
        y: i32,
        width: u32,
        height: u32,
    },
}

/// What a report changed: the rectangle around the changed cells and what they were before,
/// row-major from its bottom row (every cell of the rectangle; `rect: None`, nothing changed).
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct Change {
    pub rect: Option<Rect>,
    pub before: Vec<Occ>,
}

/// The receiver's side: a sender's grid as last reported, and the step of that report.
#[derive(Clone, Debug)]
pub struct Received {
    pub grid: Grid,
    /// `None`: nothing received yet (the grid is all unknown).
    pub step: Option<Step>,
}

impl Received {
    /// A grid of `width × height` cells to be reported, nothing received yet.
    pub fn new(width: u32, height: u32) -> Received {
        Received {
            grid: Grid::new(width, height, Occ::Unknown),
            step: None,
        }
    }

    /// Applies `report` of step `step`: the grid becomes the reported one, and what changed
    /// is returned. A report that does not decode, is of another size, does not follow the
    /// grid held (a report missed) or does not fit it leaves the grid as it was.
    pub fn apply(&mut self, step: Step, report: &GridReport) -> Result<Change, ReportError> {
        match report {
            GridReport::Whole(rle) => {
                let grid = Grid::from_rle(rle)?;
                if !same_size(&grid, &self.grid) {
                    return Err(ReportError::Size {
                        got: (grid.width(), grid.height()),
                        want: (self.grid.width(), self.grid.height()),
                    });
                }
                let rect = Rect::union_of(self.grid.known_bounds(), grid.known_bounds());
                let before = rect.map_or_else(Vec::new, |r| cells_of(&self.grid, r));
                self.grid = grid;
                self.step = Some(step);
                Ok(Change { rect, before })
            }
            GridReport::Changed { since, window } => {
                if self.step != Some(*since) {
                    return Err(ReportError::Gap {
                        since: *since,
                        held: self.step,
                    });
                }
                let Some((at, rle)) = window else {
                    self.step = Some(step);
                    return Ok(Change::default());
                };
                let w = Grid::from_rle(rle)?;
                let r = Rect {
                    min: *at,
                    max: Cell::new(
                        at.x.saturating_add(w.width() as i32 - 1),
                        at.y.saturating_add(w.height() as i32 - 1),
                    ),
                };
                if w.is_empty() || r.within(self.grid.width(), self.grid.height()) != Some(r) {
                    return Err(ReportError::Outside {
                        x: at.x,
                        y: at.y,
                        width: w.width(),
                        height: w.height(),
                    });
                }
                let before = cells_of(&self.grid, r);
                for y in r.min.y..=r.max.y {
                    let row = w.row(y - r.min.y, 0, w.width() as i32 - 1);
                    self.grid.row_mut(y, r.min.x, r.max.x).copy_from_slice(row);
                }
                self.step = Some(step);
                Ok(Change {
                    rect: Some(r),
                    before,
                })
            }
        }
    }
}

/// The cells of `r` (inside `grid`), row-major from its bottom row.
fn cells_of(grid: &Grid, r: Rect) -> Vec<Occ> {
    let mut out = Vec::with_capacity(r.area());
    for y in r.min.y..=r.max.y {
        out.extend_from_slice(grid.row(y, r.min.x, r.max.x));
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn grid_of(w: u32, h: u32, cells: &[u8]) -> Grid {
        let mut g = Grid::new(w, h, Occ::Unknown);
        for (i, &c) in cells.iter().enumerate().take(g.len()) {
            let v = [Occ::Unknown, Occ::Free, Occ::Occupied][usize::from(c % 3)];
            if v != Occ::Unknown {
                g.set_index(i, v);
            }
        }
        g
    }

    #[test]
    fn a_report_after_a_missed_one_is_a_gap_until_the_next_whole_grid() {
        let mut rep = Reporter::default();
        let mut held = Received::new(4, 3);
        let g0 = grid_of(4, 3, &[1, 1, 0, 0]);
        let g1 = grid_of(4, 3, &[1, 1, 2, 0]);
        let first = rep.report(0, &g0);
        assert!(matches!(first, GridReport::Whole(_)));
        held.apply(0, &first).expect("a whole grid");
        let _missed = rep.report(1, &g1);
        let next = rep.report(2, &g1);
        assert_eq!(
            next,
            GridReport::Changed {
                since: 1,
                window: None
            }
        );
        assert_eq!(
            held.apply(2, &next),
            Err(ReportError::Gap {
                since: 1,
                held: Some(0)
            })
        );
        let whole = rep.report(KEYFRAME_STEPS, &g1);
        assert!(matches!(whole, GridReport::Whole(_)));
        held.apply(KEYFRAME_STEPS, &whole).expect("a whole grid");
        assert_eq!(held.grid.cells(), g1.cells());
    }

    #[test]
    fn a_change_outside_the_grid_undecodable_or_of_another_size_is_an_error_and_changes_nothing() {
        let g = grid_of(4, 3, &[1, 2]);
        let mut held = Received {
            grid: g.clone(),
            step: Some(5),
        };
        let bad = GridReport::Changed {
            since: 5,
            window: Some((Cell::new(3, 2), grid_of(2, 1, &[1, 1]).to_rle())),
        };
        assert!(matches!(
            held.apply(6, &bad),
            Err(ReportError::Outside { .. })
        ));
        let junk = GridReport::Changed {
            since: 5,
            window: Some((Cell::new(0, 0), vec![0xff])),
        };
        assert!(matches!(held.apply(6, &junk), Err(ReportError::Rle(_))));
        let other = GridReport::Whole(grid_of(3, 3, &[1]).to_rle());
        assert!(matches!(
            held.apply(6, &other),
            Err(ReportError::Size { .. })
        ));
        assert_eq!((held.step, held.grid.cells()), (Some(5), g.cells()));
    }

    proptest! {
        /// Told a rectangle holding every cell that changed since its last report, a reporter
        /// reports what one comparing every cell does, step after step.
        #[test]
        fn a_report_within_the_changed_cells_is_the_report_of_every_cell(
            w in 1u32..9,
            h in 1u32..7,
            steps in proptest::collection::vec(
                (proptest::collection::vec((0usize..64, 0u8..3), 0..6), 0i32..3), 1..80),
        ) {
            let (mut every, mut within) = (Reporter::default(), Reporter::default());
            let mut g = Grid::new(w, h, Occ::Unknown);
            for (step, (edits, wider)) in steps.iter().enumerate() {
                let mut touched = Vec::new();
                for &(i, v) in edits {
                    let v = [Occ::Unknown, Occ::Free, Occ::Occupied][usize::from(v)];
                    g.set_index(i % g.len(), v);
                    touched.push(g.cell_of(i % g.len()));
                }
                // The rectangle may be wider than the edits, and reach past the grid.
                let hint = Rect::around(touched).map(|r| r.grown(*wider));
                let step = step as Step;
                prop_assert_eq!(within.report_within(step, &g, hint), every.report(step, &g));
                prop_assert_eq!(within.known(), every.known());
            }
        }

        /// Whatever a grid goes through, the receiver holds the sender's grid after every
        /// report, each change's rectangle holds every cell that changed and `before` is what
        /// those cells were.
        #[test]
        fn the_receiver_holds_every_reported_grid(
            w in 1u32..9,
            h in 1u32..7,
            steps in proptest::collection::vec(
                proptest::collection::vec((0usize..64, 0u8..3), 0..6), 1..80),
        ) {
            let mut rep = Reporter::default();
            let mut held = Received::new(w, h);
            let mut g = Grid::new(w, h, Occ::Unknown);
            for (step, edits) in steps.iter().enumerate() {
                let before = g.clone();
                for &(i, v) in edits {
                    let v = [Occ::Unknown, Occ::Free, Occ::Occupied][usize::from(v)];
                    g.set_index(i % g.len(), v);
                }
                let step = step as Step;
                let change = held.apply(step, &rep.report(step, &g)).expect("a report");
                prop_assert_eq!(held.grid.cells(), g.cells());
                prop_assert_eq!(rep.known(), g.len() - g.count(Occ::Unknown));
                for (i, (&a, &b)) in before.cells().iter().zip(g.cells()).enumerate() {
                    let c = g.cell_of(i);
                    match change.rect {
                        Some(r) if r.contains(c) => {
                            let k = (c.y - r.min.y) as usize * r.width() as usize
                                + (c.x - r.min.x) as usize;
                            prop_assert_eq!(change.before[k], a);
                        }
                        _ => prop_assert_eq!(a, b, "cell {:?} changed outside", c),
                    }
                }
            }
        }
    }
}
