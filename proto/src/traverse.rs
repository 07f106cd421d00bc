//! Walking a straight line through grid cells: the one grid traversal and the one line clip of
//! the workspace.
//!
//! [`Traversal`] is the voxel traversal of Amanatides and Woo ("A Fast Voxel Traversal Algorithm
//! for Ray Tracing", Eurographics 1987) in two dimensions: per axis it keeps the line parameter
//! `t` of the next cell boundary and the spacing of the boundaries, and each step crosses the
//! nearer one. Coordinates are in cell units, cell `(x, y)` covering `[x, x+1) × [y, y+1)` as in
//! [`crate::grid`]. Three places walk lines and share it:
//!
//! * the world-server's laser casts rays ([`Traversal::ray`]) and stops at the first blocking
//!   cell; `t` is the distance travelled in cells;
//! * a robot's scan integration rasterizes beams as segments ([`Traversal::segment`]);
//! * netem's path-loss radio counts the walls on the segment between two robots
//!   ([`Traversal::between`], its end cells clamped into the map).
//!
//! They differ only in what a crossing exactly through a cell corner means ([`Corners`]): the
//! laser and the scan integration take the *supercover* (the two side cells are touched as well,
//! so nothing sees or moves through a diagonal gap), the radio takes the plain traversal (one of
//! the side cells, the y side). [`clip`] (Liang and Barsky, "A new concept and method for line
//! clipping", ACM TOG 1984) cuts a segment to a box first, so that a walk is bounded by the grid
//! whatever the end points.

use crate::grid::Cell;

/// What a crossing exactly through a cell corner (both boundaries at one `t`) touches.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Corners {
    /// Both side cells, then the diagonal cell ([`Crossing::corner`]). Crossings whose `t`
    /// differ by at most `eps` count as one corner crossing (`eps = 0`: exactly equal `t` only).
    Supercover { eps: f64 },
    /// One boundary at a time; at a tie the y boundary is crossed first. Consecutive cells are
    /// always 4-neighbours and [`Crossing::corner`] is always `None`.
    Thin,
}

/// One step of a [`Traversal`]: the line enters `cell` at parameter `t`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Crossing {
    /// The line parameter of the crossing (the units of the direction the walk was made with).
    pub t: f64,
    /// The cell entered.
    pub cell: Cell,
    /// For a supercover corner crossing: the two side cells touched at the same `t` before
    /// `cell` (the x neighbour of the previous cell first, then the y neighbour).
    pub corner: Option<[Cell; 2]>,
}

/// The cells a line crosses, in order, as an iterator of [`Crossing`]s (the start cell itself is
/// not yielded: it is [`Traversal::cell`] before the first step).
///
/// A [`Traversal::ray`] never ends by itself (callers stop at a range or at the grid's border);
/// a [`Traversal::segment`] ends in the cell of its end point, after exactly as many boundary
/// crossings per axis as the two end cells are apart, whatever the rounding of the `t` values.
#[derive(Clone, Debug)]
pub struct Traversal {
    cell: Cell,
    step: (i32, i32),
    /// Per axis: `t` of the next boundary crossing.
    next_t: (f64, f64),
    /// Per axis: `t` between two boundary crossings.
    delta_t: (f64, f64),
    /// Per axis, for a segment: the boundary crossings left to its end cell.
    left: Option<(u32, u32)>,
    corners: Corners,
}

impl Traversal {
    /// The ray from `start` along `dir` (`t` in units of `dir`; with a unit `dir`, in cells),
    /// starting in the cell of `start`. The coordinates should be finite.
    pub fn ray(start: (f64, f64), dir: (f64, f64), corners: Corners) -> Traversal {
        Traversal::new(start, floor_cell(start), dir, None, corners)
    }

    /// The segment `from → to` (`t ∈ [0, 1]` up to rounding), from the cell of `from` to the cell
    /// of `to`. The coordinates should be finite and within `i32` range.
    pub fn segment(from: (f64, f64), to: (f64, f64), corners: Corners) -> Traversal {
        Traversal::between(from, floor_cell(from), to, floor_cell(to), corners)
    }

    /// The segment `from → to` walked from `from_cell` to `to_cell`: the cells of the end points
    /// as the caller counts them (e.g. clamped into a grid for a point on its far border).
    pub fn between(
        from: (f64, f64),
        from_cell: Cell,
        to: (f64, f64),
        to_cell: Cell,
        corners: Corners,
    ) -> Traversal {
        let left = (
            to_cell.x.abs_diff(from_cell.x),
            to_cell.y.abs_diff(from_cell.y),
        );
        let delta = (to.0 - from.0, to.1 - from.1);
        Traversal::new(from, from_cell, delta, Some(left), corners)
    }

    fn new(
        start: (f64, f64),
        cell: Cell,
        dir: (f64, f64),
        left: Option<(u32, u32)>,
        corners: Corners,
    ) -> Traversal {
        let (sx, tx, dx) = axis(start.0, cell.x, dir.0);
        let (sy, ty, dy) = axis(start.1, cell.y, dir.1);
        Traversal {
            cell,
            step: (sx, sy),
            next_t: (tx, ty),
            delta_t: (dx, dy),
            left,
            corners,
        }
    }

    /// The cell the walk is in (the start cell before the first step).
    pub fn cell(&self) -> Cell {
        self.cell
    }
}

/// The cell containing `p` (saturating at the `i32` range).
fn floor_cell(p: (f64, f64)) -> Cell {
    Cell::new(p.0.floor() as i32, p.1.floor() as i32)
}

/// Per-axis set-up: the step direction, `t` of the first boundary crossing from `pos` in cell
/// `c` along `dir`, and `t` between crossings. An axis the line runs parallel to is never
/// crossed.
fn axis(pos: f64, c: i32, dir: f64) -> (i32, f64, f64) {
    if dir > 0.0 {
        (1, (f64::from(c) + 1.0 - pos) / dir, 1.0 / dir)
    } else if dir < 0.0 {
        (-1, (f64::from(c) - pos) / dir, -1.0 / dir)
    } else {
        (0, f64::INFINITY, f64::INFINITY)
    }
}

/// Which boundary a step crosses.
enum Step {
    X,
    Y,
    Corner,
}

impl Iterator for Traversal {
    type Item = Crossing;

    fn next(&mut self) -> Option<Crossing> {
        let (x_open, y_open) = match self.left {
            None => (true, true),
            Some((0, 0)) => return None,
            Some((lx, ly)) => (lx > 0, ly > 0),
        };
        let (tx, ty) = self.next_t;
        let step = match self.corners {
            Corners::Supercover { eps } => {
                if !y_open || (x_open && tx < ty - eps) {
                    Step::X
                } else if !x_open || (y_open && ty < tx - eps) {
                    Step::Y
                } else {
                    Step::Corner
                }
            }
            Corners::Thin if x_open && (!y_open || tx < ty) => Step::X,
            Corners::Thin => Step::Y,
        };
        let Cell { x, y } = self.cell;
        let (sx, sy) = self.step;
        let (t, corner) = match step {
            Step::X => (tx, None),
            Step::Y => (ty, None),
            Step::Corner => (
                tx.min(ty),
                Some([Cell::new(x + sx, y), Cell::new(x, y + sy)]),
            ),
        };
        if matches!(step, Step::X | Step::Corner) {
            self.cell.x += sx;
            self.next_t.0 += self.delta_t.0;
            if let Some(left) = &mut self.left {
                left.0 -= 1;
            }
        }
        if matches!(step, Step::Y | Step::Corner) {
            self.cell.y += sy;
            self.next_t.1 += self.delta_t.1;
            if let Some(left) = &mut self.left {
                left.1 -= 1;
            }
        }
        Some(Crossing {
            t,
            cell: self.cell,
            corner,
        })
    }
}

/// Liang–Barsky clipping of the segment `a → b` to the closed box `lo..=hi`: the parameters
/// `t0 ≤ t1` in `[0, 1]` of the part inside, or `None` when the segment misses the box or a
/// coordinate is not finite.
pub fn clip(a: (f64, f64), b: (f64, f64), lo: (f64, f64), hi: (f64, f64)) -> Option<(f64, f64)> {
    if ![a.0, a.1, b.0, b.1].iter().all(|v| v.is_finite()) {
        return None;
    }
    let (dx, dy) = (b.0 - a.0, b.1 - a.1);
    let (mut t0, mut t1) = (0.0_f64, 1.0_f64);
    for (p, q) in [
        (-dx, a.0 - lo.0),
        (dx, hi.0 - a.0),
        (-dy, a.1 - lo.1),
        (dy, hi.1 - a.1),
    ] {
        if p == 0.0 {
            if q < 0.0 {
                return None;
            }
        } else if p < 0.0 {
            t0 = t0.max(q / p);
        } else {
            t1 = t1.min(q / p);
        }
    }
    (t0 <= t1).then_some((t0, t1))
}

/// The cells a point moving along the closed segment `a`–`b` (in cell units) sweeps: every cell
/// whose closed square meets the segment, column by column (within each column's slice of the
/// segment, all rows its y-extent touches). A segment through a corner therefore yields all
/// four cells around it, one along a grid line the cells on both sides, and one ending on a
/// cell's border that cell too. Non-finite input gives no cells.
///
/// This is the walk of *motion*: the world-server refuses a move that sweeps a cell that is not
/// free, and a robot's planner checks its waypoints with the same walk, so that it never plans
/// a move the world refuses. Beams (the laser, scan integration) and radio paths take the
/// [`Traversal`] instead, where a cell is the half-open square `[x, x+1) × [y, y+1)`.
pub fn swept(a: (f64, f64), b: (f64, f64)) -> Vec<Cell> {
    if ![a.0, a.1, b.0, b.1].iter().all(|v| v.is_finite()) {
        return Vec::new();
    }
    let (x_lo, x_hi) = (a.0.min(b.0), a.0.max(b.0));
    // The y of the segment at abscissa x (the segment is not vertical where this is used).
    let y_at = |x: f64| a.1 + (x - a.0) * (b.1 - a.1) / (b.0 - a.0);
    let mut cells = Vec::new();
    for cx in (x_lo.ceil() as i32 - 1)..=(x_hi.floor() as i32) {
        let (s0, s1) = (x_lo.max(f64::from(cx)), x_hi.min(f64::from(cx) + 1.0));
        let (y0, y1) = if a.0 == b.0 {
            (a.1, b.1)
        } else {
            (y_at(s0), y_at(s1))
        };
        let (y_lo, y_hi) = (y0.min(y1), y0.max(y1));
        for cy in (y_lo.ceil() as i32 - 1)..=(y_hi.floor() as i32) {
            cells.push(Cell::new(cx, cy));
        }
    }
    cells
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    const SUPERCOVER: Corners = Corners::Supercover { eps: 0.0 };

    /// The cells a segment walk lists: the start cell, then per crossing the side cells and the
    /// cell entered.
    fn cells(from: (f64, f64), to: (f64, f64), corners: Corners) -> Vec<Cell> {
        let walk = Traversal::segment(from, to, corners);
        let mut out = vec![walk.cell()];
        for c in walk {
            out.extend(c.corner.into_iter().flatten());
            out.push(c.cell);
        }
        out
    }

    fn c(x: i32, y: i32) -> Cell {
        Cell::new(x, y)
    }

    fn neighbours(a: Cell, b: Cell) -> bool {
        a.x.abs_diff(b.x) + a.y.abs_diff(b.y) == 1
    }

    #[test]
    fn swept_cells() {
        let sorted = |mut v: Vec<Cell>| {
            v.sort();
            v
        };
        let c = Cell::new;
        assert_eq!(
            swept((0.5, 0.5), (2.5, 0.5)),
            vec![c(0, 0), c(1, 0), c(2, 0)]
        );
        assert_eq!(
            swept((0.5, 2.5), (0.5, 0.5)),
            vec![c(0, 0), c(0, 1), c(0, 2)]
        );
        assert_eq!(
            sorted(swept((0.5, 0.5), (1.5, 1.5))),
            vec![c(0, 0), c(0, 1), c(1, 0), c(1, 1)]
        );
        assert_eq!(
            swept((0.5, 1.0), (1.5, 1.0)),
            vec![c(0, 0), c(0, 1), c(1, 0), c(1, 1)],
            "along a grid line"
        );
        // Slope 1/3 passes exactly through the corner (2, 1).
        assert_eq!(
            swept((0.5, 0.5), (3.5, 1.5)),
            vec![c(0, 0), c(1, 0), c(1, 1), c(2, 0), c(2, 1), c(3, 1)]
        );
        assert_eq!(
            swept((0.5, 0.5), (3.5, 1.7)),
            vec![c(0, 0), c(1, 0), c(1, 1), c(2, 1), c(3, 1)]
        );
        assert_eq!(swept((0.2, 0.3), (0.2, 0.3)), vec![c(0, 0)]);
        assert!(swept((f64::NAN, 0.0), (1.0, 1.0)).is_empty());
    }

    proptest! {
        #[test]
        fn swept_contains_every_point_of_the_segment(
            ax in -20.0f64..20.0, ay in -20.0f64..20.0, bx in -20.0f64..20.0, by in -20.0f64..20.0,
        ) {
            let cells = swept((ax, ay), (bx, by));
            for k in 0..=100 {
                let s = f64::from(k) / 100.0;
                let (x, y) = (ax + s * (bx - ax), ay + s * (by - ay));
                let c = Cell::new(x.floor() as i32, y.floor() as i32);
                prop_assert!(cells.contains(&c), "point ({}, {}) in {:?} missing", x, y, c);
            }
            // Every cell returned is within the segment's bounding box grown by one cell.
            let (lo_x, hi_x) = (ax.min(bx).floor() as i32 - 1, ax.max(bx).floor() as i32 + 1);
            prop_assert!(cells.iter().all(|c| (lo_x..=hi_x).contains(&c.x)));
        }

    }

    #[test]
    fn corners_are_supercover_or_thin() {
        let diagonal = ((0.5, 0.5), (2.5, 2.5));
        assert_eq!(
            cells(diagonal.0, diagonal.1, SUPERCOVER),
            [
                c(0, 0),
                c(1, 0),
                c(0, 1),
                c(1, 1),
                c(2, 1),
                c(1, 2),
                c(2, 2)
            ]
        );
        assert_eq!(
            cells(diagonal.0, diagonal.1, Corners::Thin),
            [c(0, 0), c(0, 1), c(1, 1), c(1, 2), c(2, 2)]
        );
        // Along an axis both agree; a degenerate segment stays in its cell.
        let flat = ((0.5, 0.5), (-2.5, 0.5));
        let want = [c(0, 0), c(-1, 0), c(-2, 0), c(-3, 0)];
        assert_eq!(cells(flat.0, flat.1, SUPERCOVER), want);
        assert_eq!(cells(flat.0, flat.1, Corners::Thin), want);
        assert_eq!(cells((1.2, 3.4), (1.2, 3.4), SUPERCOVER), [c(1, 3)]);
    }

    #[test]
    fn a_ray_reports_the_distance_at_which_it_enters_each_cell() {
        let d = 0.5f64.atan();
        let ray = Traversal::ray((0.5, 0.5), (d.cos(), d.sin()), SUPERCOVER);
        let got: Vec<(Cell, f64)> = ray.take(3).map(|x| (x.cell, x.t)).collect();
        let per_x = 1.0 / d.cos();
        assert_eq!(got[0].0, c(1, 0));
        assert!((got[0].1 - 0.5 * per_x).abs() < 1e-12);
        assert_eq!(got[1].0, c(1, 1), "y = 1 is crossed at x = 1.5");
        assert!((got[1].1 - per_x).abs() < 1e-12);
        assert_eq!(got[2].0, c(2, 1));
        // The ray passes no cell corner, so the thin walk lists the same cells.
        let thin = Traversal::ray((0.5, 0.5), (d.cos(), d.sin()), Corners::Thin);
        assert_eq!(
            thin.take(3).map(|x| x.cell).collect::<Vec<_>>(),
            [c(1, 0), c(1, 1), c(2, 1)]
        );
    }

    #[test]
    fn the_corner_tolerance_merges_near_ties() {
        // Through (1 - 1e-12, 1): exactly, the y boundary comes a hair earlier.
        let (a, b) = ((0.5, 0.5 + 1e-12), (1.5, 1.5 + 1e-12));
        assert_eq!(cells(a, b, SUPERCOVER), [c(0, 0), c(0, 1), c(1, 1)]);
        assert_eq!(
            cells(a, b, Corners::Supercover { eps: 1e-9 }),
            [c(0, 0), c(1, 0), c(0, 1), c(1, 1)]
        );
    }

    #[test]
    fn clipping() {
        let unit = ((0.0, 0.0), (1.0, 1.0));
        assert_eq!(
            clip((0.2, 0.2), (0.8, 0.5), unit.0, unit.1),
            Some((0.0, 1.0))
        );
        assert_eq!(
            clip((-1.0, 0.5), (3.0, 0.5), unit.0, unit.1),
            Some((0.25, 0.5))
        );
        assert_eq!(clip((-1.0, 2.0), (3.0, 2.0), unit.0, unit.1), None);
        assert_eq!(clip((2.0, 2.0), (3.0, 3.0), unit.0, unit.1), None);
        assert_eq!(clip((f64::NAN, 0.5), (0.5, 0.5), unit.0, unit.1), None);
        // Touching the box at one point is inside (closed box).
        assert_eq!(
            clip((1.0, 1.0), (2.0, 2.0), unit.0, unit.1),
            Some((0.0, 0.0))
        );
    }

    fn coord() -> impl Strategy<Value = f64> {
        prop_oneof![
            -20.0f64..20.0,
            // Cell corners and boundaries, where the ties are.
            (-20i32..20).prop_map(f64::from),
            (-40i32..40).prop_map(|v| f64::from(v) / 2.0),
        ]
    }

    fn corners() -> impl Strategy<Value = Corners> {
        prop_oneof![
            Just(Corners::Thin),
            Just(SUPERCOVER),
            Just(Corners::Supercover { eps: 1e-9 }),
        ]
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(2048))]

        #[test]
        fn a_segment_walk_goes_by_neighbours_from_its_start_cell_to_its_end_cell(
            ax in coord(), ay in coord(), bx in coord(), by in coord(), corners in corners(),
        ) {
            let (a, b) = ((ax, ay), (bx, by));
            let walk = Traversal::segment(a, b, corners);
            let start = walk.cell();
            prop_assert_eq!(start, floor_cell(a));
            let crossings: Vec<Crossing> = walk.collect();
            let end = crossings.last().map_or(start, |x| x.cell);
            prop_assert_eq!(end, floor_cell(b));
            // Per axis exactly as many crossings as the end cells are apart, each one toward the end.
            let steps: u32 = crossings.iter().map(|x| if x.corner.is_some() { 2 } else { 1 }).sum();
            prop_assert_eq!(steps, start.x.abs_diff(end.x) + start.y.abs_diff(end.y));
            let mut prev = start;
            let mut prev_t = f64::NEG_INFINITY;
            for x in &crossings {
                match x.corner {
                    Some([side_x, side_y]) => {
                        prop_assert!(!matches!(corners, Corners::Thin));
                        prop_assert!(neighbours(prev, side_x) && neighbours(side_x, x.cell));
                        prop_assert!(neighbours(prev, side_y) && neighbours(side_y, x.cell));
                        prop_assert_eq!(side_x.y, prev.y);
                        prop_assert_eq!(side_y.x, prev.x);
                    }
                    None => prop_assert!(neighbours(prev, x.cell), "{:?} -> {:?}", prev, x.cell),
                }
                prop_assert!((x.cell.x - prev.x) * (end.x - start.x) >= 0);
                prop_assert!((x.cell.y - prev.y) * (end.y - start.y) >= 0);
                // t grows and lies on the segment (up to rounding).
                prop_assert!(x.t >= prev_t - 1e-9 && (-1e-9..=1.0 + 1e-9).contains(&x.t), "t {}", x.t);
                // The point at t lies on the boundary between the previous cell and this one.
                let p = (ax + x.t * (bx - ax), ay + x.t * (by - ay));
                if x.cell.x != prev.x {
                    prop_assert!((p.0 - f64::from(prev.x.max(x.cell.x))).abs() < 1e-6);
                }
                if x.cell.y != prev.y {
                    prop_assert!((p.1 - f64::from(prev.y.max(x.cell.y))).abs() < 1e-6);
                }
                prev = x.cell;
                prev_t = x.t;
            }
        }

        #[test]
        fn a_ray_walks_the_cells_of_the_segment_to_its_range(
            ax in coord(), ay in coord(), angle in -3.2f64..3.2, len in 0.0f64..25.0,
        ) {
            // The ray, stopped at `len`, lists the cells of the segment of that length (when no
            // boundary lies within rounding of the end point).
            let d = (angle.cos(), angle.sin());
            let b = (ax + len * d.0, ay + len * d.1);
            let near_boundary = |v: f64| (v - v.round()).abs() < 1e-6;
            prop_assume!(!near_boundary(b.0) && !near_boundary(b.1));
            let mut ray = vec![floor_cell((ax, ay))];
            for x in Traversal::ray((ax, ay), d, SUPERCOVER).take_while(|x| x.t <= len) {
                ray.extend(x.corner.into_iter().flatten());
                ray.push(x.cell);
            }
            let seg = cells((ax, ay), b, SUPERCOVER);
            prop_assert_eq!(ray.last(), seg.last());
            prop_assert_eq!(ray.len(), seg.len());
        }

        #[test]
        fn clipped_segments_lie_in_the_box_and_keep_what_is_inside(
            ax in coord(), ay in coord(), bx in coord(), by in coord(),
        ) {
            let (lo, hi) = ((-5.0, -3.0), (7.0, 4.0));
            let inside = |p: (f64, f64)| (lo.0 - 1e-9..=hi.0 + 1e-9).contains(&p.0)
                && (lo.1 - 1e-9..=hi.1 + 1e-9).contains(&p.1);
            let at = |t: f64| (ax + t * (bx - ax), ay + t * (by - ay));
            match clip((ax, ay), (bx, by), lo, hi) {
                Some((t0, t1)) => {
                    prop_assert!((0.0..=t1).contains(&t0) && t1 <= 1.0);
                    prop_assert!(inside(at(t0)) && inside(at(t1)) && inside(at((t0 + t1) / 2.0)));
                    let strictly = |p: (f64, f64)| (lo.0..=hi.0).contains(&p.0) && (lo.1..=hi.1).contains(&p.1);
                    if strictly((ax, ay)) { prop_assert_eq!(t0, 0.0); }
                    if strictly((bx, by)) { prop_assert_eq!(t1, 1.0); }
                }
                None => {
                    for k in 0..=100 {
                        let p = at(f64::from(k) / 100.0);
                        prop_assert!(!(lo.0 + 1e-9..=hi.0 - 1e-9).contains(&p.0)
                            || !(lo.1 + 1e-9..=hi.1 - 1e-9).contains(&p.1));
                    }
                }
            }
        }
    }
}
