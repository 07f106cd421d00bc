//! Scan integration into the self-explored ternary grid G_s (thesis §4.1; docs/design.md §4, step
//! 1).
//!
//! Every step a robot marks the cells along each laser beam free and the cell a beam stops in
//! occupied. The thesis's contour extraction (§4.1) assumes that the free space seen from one pose
//! is a single 4-connected region, so beams are rasterized as 4-connected *supercover* lines (every
//! cell the segment touches, both cells at an exact corner crossing) rather than Bresenham lines,
//! whose diagonal steps would split the free region. The same
//! [`supercover`](crate::mapping::grid::supercover) is the planner's line-of-sight test
//! (`crate::nav::plan`), so "the robot may drive this segment" and "this beam saw these cells" mean
//! the same set of cells. The walk is the workspace's one grid traversal, [`proto::traverse`],
//! which the world-server's laser casts its rays with.
//!
//! The world-server reports the distance at which a ray *enters* its blocking cell, so a hit is
//! a boundary crossing: the hit cell is the cell entered at the crossing nearest to the reported
//! range. Taking "the cell containing the range plus a hundredth of a cell" instead goes wrong
//! whenever a ray grazes a wall cell's corner (the next crossing follows within that hundredth: the
//! wall cell is freed and the cell behind it marked), and whenever a range was rounded short on
//! the radio (`crate::exchange::raw_scans` quantizes to centimetres).
//!
//! Integration is a join on the lattice unknown < free < occupied: a cell becomes occupied if any
//! beam ever hit it, else free if any beam crossed it. Walls are therefore sticky (free never
//! overwrites occupied), and the result does not depend on the order of the beams or of the scans.

use proto::geom::{LaserSpec, MapInfo, Pose};
use proto::grid::{Cell, Grid, Occ};
use proto::traverse::{clip, Corners, Crossing, Traversal};

/// A hit whose range ends less than this (in cells) past the robot's own cell border is read as a
/// return from inside the robot's own cell, and ignored: the robot stands on free ground.
const OWN_CELL_MARGIN_CELLS: f64 = 0.01;

/// How far past the reported range (in cells) a hit beam is walked to find the nearest crossing.
/// Along any direction the crossings are at most √2 cells apart, so half a cell on either side of
/// the range covers the nearest crossing or one as near as it.
const SNAP_CELLS: f64 = 0.5;

/// Two boundary crossings closer than this (in units of the segment's parameter `t ∈ [0, 1]`)
/// count as one crossing through a cell corner, so both side cells are reported. Without the
/// tolerance a segment between two cell centres at 45° would pick one side cell by rounding noise.
const CORNER_EPS: f64 = 1e-9;

/// Coordinates (in cells) beyond this magnitude are rejected by [`supercover`]: they are not
/// grid cells of any map we accept, and they would overflow `i32` cell indices.
const MAX_COORD_CELLS: f64 = 1e9;

/// The cells a straight segment touches, in order from the cell of `from` to the cell of `to`.
///
/// Coordinates are in floating cell units: cell `(x, y)` covers `[x, x+1) × [y, y+1)`. The result
/// is 4-connected as a set and monotone in both axes; where the segment passes exactly through a
/// cell corner both side cells are listed (before the diagonal cell), so a line of free cells
/// never connects two cells only through a corner. A degenerate segment gives the one cell of
/// `from`. Non-finite coordinates, or coordinates beyond ±10⁹ cells, give an empty line. Work and
/// output are proportional to the number of cells touched; callers bound their segments.
pub fn supercover(from: (f64, f64), to: (f64, f64)) -> Vec<Cell> {
    let mut out = Vec::new();
    walk(from, to, &mut out);
    out.into_iter().map(|(c, _)| c).collect()
}

/// Whether `found` holds for a cell of [`supercover`]`(from, to)`, asked in its order and no
/// further than the first that holds — without the list (a line of sight stops at the first wall).
pub fn supercover_finds(
    from: (f64, f64),
    to: (f64, f64),
    mut found: impl FnMut(Cell) -> bool,
) -> bool {
    touched(from, to, |c, _| found(c))
}

/// [`supercover`] with the parameter `t ∈ [0, 1]` at which the segment enters each cell (0 for the
/// first cell; the two side cells and the diagonal cell of a corner crossing share one `t`).
/// Written into `out` (cleared first): a scan walks hundreds of beams into one buffer.
fn walk(from: (f64, f64), to: (f64, f64), out: &mut Vec<(Cell, f64)>) {
    out.clear();
    touched(from, to, |c, t| {
        out.push((c, t));
        false
    });
}

/// `each(cell, t)` for the cells of [`walk`] in order, until it returns true; whether it did.
fn touched(from: (f64, f64), to: (f64, f64), mut each: impl FnMut(Cell, f64) -> bool) -> bool {
    let usable = |v: f64| v.is_finite() && v.abs() <= MAX_COORD_CELLS;
    if ![from.0, from.1, to.0, to.1].into_iter().all(usable) {
        return false;
    }
    // The segment walk counts the remaining crossings per axis (rather than comparing against
    // `t = 1`), so it ends exactly in the cell of `to` whatever the rounding of the `t` values.
    let line = Traversal::segment(from, to, Corners::Supercover { eps: CORNER_EPS });
    if each(line.cell(), 0.0) {
        return true;
    }
    for Crossing { t, cell, corner } in line {
        // The parameter of this crossing, clamped against rounding past the segment's ends.
        let t = t.clamp(0.0, 1.0);
        // Through a corner the segment touches both side cells before it enters the diagonal one.
        if corner.into_iter().flatten().any(|side| each(side, t)) || each(cell, t) {
            return true;
        }
    }
    false
}

/// Integrates one laser scan taken at `pose` into `g`; returns how many cells changed.
///
/// Beam `i` points at `pose.theta + spec.beam_angle(i)`; beams beyond `spec.beams` or beyond
/// `ranges.len()` are ignored.
///
/// * A range `r ≥ max_range_m` (including `+∞`, and compared in `f32` as well, since ranges
///   travel as `f32`) is no return: the beam is free up to `max_range_m`.
/// * A range `r < max_range_m` is a hit in the cell the beam enters at the boundary crossing
///   nearest to `r` (ties go to the farther cell, so at an exact corner the diagonal cell); the
///   cells before it on the beam are free. A hit that ends inside the robot's own cell is ignored
///   (a robot stands on free ground; such a return can only be noise).
/// * NaN and negative ranges carry no information and are skipped.
///
/// Cells on a beam's free part become free unless occupied; hit cells become occupied. All hits
/// are applied before any free cell, so the result does not depend on the beam order. Cells
/// outside the grid are ignored, and beams are clipped to the grid first, so the work per beam is
/// bounded by the grid's size. A non-finite pose, or a frame or laser whose resolution or maximum
/// range is not positive and finite, changes nothing.
pub fn integrate_scan(
    g: &mut Grid,
    info: &MapInfo,
    pose: Pose,
    ranges: &[f32],
    spec: &LaserSpec,
) -> usize {
    let mut beams = Beams::default();
    trace_scan(g, info, pose, ranges, spec, &mut beams);
    let mut changed = 0;
    for c in beams.each().filter_map(|(_, hit)| hit) {
        if g.contains(c) && g.get(c) != Occ::Occupied {
            g.set(c, Occ::Occupied);
            changed += 1;
        }
    }
    for c in &beams.free {
        if g.contains(*c) && g.get(*c) == Occ::Unknown {
            g.set(*c, Occ::Free);
            changed += 1;
        }
    }
    changed
}

/// Every beam of a scan, traced in cell units into `beams` (none for an unusable pose or frame).
fn trace_scan(
    g: &Grid,
    info: &MapInfo,
    pose: Pose,
    ranges: &[f32],
    spec: &LaserSpec,
    beams: &mut Beams,
) {
    beams.free.clear();
    beams.ends.clear();
    let res = info.resolution_m;
    let max_range_m = spec.max_range_m;
    let sane = res.is_finite() && res > 0.0 && max_range_m.is_finite() && max_range_m > 0.0;
    if !sane || ![pose.x, pose.y, pose.theta].iter().all(|v| v.is_finite()) {
        return;
    }
    let robot = info.in_cells(pose.xy());
    for (&r, i) in ranges.iter().zip(0..spec.beams) {
        let angle = pose.theta + spec.beam_angle(i);
        let walked = &mut beams.walk;
        if let Some((free, hit)) = trace(g, robot, angle, r, res, max_range_m, walked) {
            (beams.free).extend(walked[..free].iter().map(|&(c, _)| c));
            beams.ends.push((beams.free.len(), hit));
        }
    }
}

/// Per-cell evidence: how many beams stopped in a cell and how many crossed it.
///
/// [`integrate_scan`]'s sticky walls turn every misplaced hit into a permanent false wall — and
/// hits are misplaced, rarely with exact ranges (a beam grazing a corner) and often with ranges
/// quantized for the radio. A false wall can close a doorway and hide everything behind it from
/// the frontier search. Counting lets later beams that cross such a cell correct it: a cell is
/// occupied while at least as many beams stopped in it as crossed it (ties stay occupied, the
/// conservative reading), free otherwise, unknown until observed. Counts saturate.
#[derive(Clone, Debug)]
pub struct Evidence {
    hits: Vec<u16>,
    passes: Vec<u16>,
    /// The buffers a scan is traced into, kept from scan to scan.
    beams: Beams,
}

impl Evidence {
    /// No evidence for any cell of a grid of `g`'s size.
    pub fn new(g: &Grid) -> Evidence {
        Evidence {
            hits: vec![0; g.len()],
            passes: vec![0; g.len()],
            beams: Beams::default(),
        }
    }

    fn state(&self, i: usize) -> Occ {
        match (self.hits[i], self.passes[i]) {
            (0, 0) => Occ::Unknown,
            (h, p) if h >= p => Occ::Occupied,
            _ => Occ::Free,
        }
    }

    /// Adds a scan's evidence and updates the cells of `g` it touched; returns the cells that
    /// changed (each once). `g` must be the grid this evidence was made for (same size).
    pub fn integrate(
        &mut self,
        g: &mut Grid,
        info: &MapInfo,
        pose: Pose,
        ranges: &[f32],
        spec: &LaserSpec,
    ) -> Vec<Cell> {
        if g.len() != self.hits.len() {
            return Vec::new();
        }
        let mut beams = std::mem::take(&mut self.beams);
        trace_scan(g, info, pose, ranges, spec, &mut beams);
        let mut touched = Vec::new();
        for (free, hit) in beams.each() {
            if let Some(i) = hit.and_then(|c| g.index(c)) {
                self.hits[i] = self.hits[i].saturating_add(1);
                touched.push(i);
            }
            for i in free.iter().filter_map(|&c| g.index(c)) {
                self.passes[i] = self.passes[i].saturating_add(1);
                touched.push(i);
            }
        }
        self.beams = beams;
        let mut changed = Vec::new();
        let w = g.width() as usize;
        for i in touched {
            let v = self.state(i);
            if g.cells()[i] != v {
                g.set_index(i, v);
                changed.push(Cell::new((i % w) as i32, (i / w) as i32));
            }
        }
        changed
    }
}

/// What the beams of a scan say, beam by beam: the cells each crossed and the cell it stopped
/// in (either may lie outside the grid). In flat buffers kept from scan to scan: a scan is
/// hundreds of beams of tens of cells each, and two vectors per beam were a good part of a
/// robot's allocations.
#[derive(Clone, Debug, Default)]
struct Beams {
    /// Every beam's free cells, one beam after another.
    free: Vec<Cell>,
    /// Per beam, where its free cells end in `free`, and the cell it stopped in.
    ends: Vec<(usize, Option<Cell>)>,
    /// One beam's walk ([`trace`]'s).
    walk: Vec<(Cell, f64)>,
}

impl Beams {
    /// Each beam's free cells and the cell it stopped in, in the scan's order.
    fn each(&self) -> impl Iterator<Item = (&[Cell], Option<Cell>)> {
        let mut start = 0;
        self.ends.iter().map(move |&(end, hit)| {
            let free = &self.free[start..end];
            start = end;
            (free, hit)
        })
    }
}

/// Traces one beam from `robot` (cell units) at `angle` into `cells` (the walk along it, with
/// [`walk`]'s parameters): how many of them the beam crossed free (they lead the walk) and the
/// cell it stopped in; `None` for a range without information.
fn trace(
    g: &Grid,
    robot: (f64, f64),
    angle: f64,
    range_m: f32,
    res: f64,
    max_range_m: f64,
    cells: &mut Vec<(Cell, f64)>,
) -> Option<(usize, Option<Cell>)> {
    if range_m.is_nan() || range_m < 0.0 {
        return None;
    }
    // Ranges travel as `f32`: a sender that writes `max_range_m as f32` for "no return" may round
    // it below the `f64` maximum, so both precisions count.
    let no_return = f64::from(range_m) >= max_range_m || range_m >= max_range_m as f32;
    let range_cells = f64::from(range_m) / res;
    let len_cells = if no_return {
        max_range_m / res
    } else {
        range_cells + SNAP_CELLS
    };
    let dir = (angle.cos(), angle.sin());
    let end = (robot.0 + len_cells * dir.0, robot.1 + len_cells * dir.1);
    // The walk is clipped to the grid grown by one cell, so that a beam leaving the grid always
    // enters an outside cell: that crossing competes for the nearest one like any other, and hits
    // or free cells outside the grid are dropped by the caller.
    let lo = (-1.0, -1.0);
    let hi = (f64::from(g.width()) + 1.0, f64::from(g.height()) + 1.0);
    let Some((t0, t1)) = clip(robot, end, lo, hi) else {
        return Some((0, None));
    };
    let at = |t: f64| {
        (
            robot.0 + t * len_cells * dir.0,
            robot.1 + t * len_cells * dir.1,
        )
    };
    walk(at(t0), at(t1), cells);
    if no_return {
        return Some((cells.len(), None));
    }
    // Distance (cells) from the robot at which the beam enters each cell of the clipped walk. The
    // robot's own cell is not entered at all; when the robot stands outside the grown grid the
    // walk starts with a crossing of its border.
    let entered = |t: f64| (t0 + t * (t1 - t0)) * len_cells;
    let robot_inside = t0 <= 0.0;
    let first_crossing = usize::from(robot_inside);
    let own_cell_ends = cells
        .get(first_crossing)
        .map_or(f64::INFINITY, |&(_, t)| entered(t));
    if robot_inside && range_cells + OWN_CELL_MARGIN_CELLS < own_cell_ends {
        return Some((cells.len().min(1), None));
    }
    // The nearest crossing; `<=` lets the farther of equally near crossings win.
    let mut best: Option<(usize, f64)> = None;
    for (k, &(_, t)) in cells.iter().enumerate().skip(first_crossing) {
        let miss = (entered(t) - range_cells).abs();
        match best {
            Some((_, m)) if miss > m => {}
            _ => best = Some((k, miss)),
        }
    }
    let hit = best.map(|(k, _)| k);
    Some((hit.unwrap_or(cells.len()), hit.map(|k| cells[k].0)))
}

/// A box world for the tests of the modules that integrate scans: a `w × h` grid whose ring of
/// border cells is wall, and the ranges the world-server's laser measures in it.
#[cfg(test)]
pub(crate) mod box_world {
    use proto::grid::Cell;

    /// A `w × h` box: a ring of wall cells around a free interior `[1, w-1) × [1, h-1)`.
    pub fn is_wall(c: Cell, w: i32, h: i32) -> bool {
        c.x == 0 || c.y == 0 || c.x == w - 1 || c.y == h - 1
    }

    /// The world-server's range for a beam inside the box: the distance (metres) at which the ray
    /// enters a wall cell, or `max_range_m` when that is farther.
    pub fn box_range(p: (f64, f64), angle: f64, w: i32, h: i32, res: f64, max_range_m: f64) -> f32 {
        (box_exit(p, angle, w, h) * res).min(max_range_m) as f32
    }

    /// The distance (cells) from `p` (cell units) along `angle` at which a ray enters a wall cell.
    pub fn box_exit(p: (f64, f64), angle: f64, w: i32, h: i32) -> f64 {
        let exit = |p: f64, d: f64, hi: i32| {
            if d > 0.0 {
                (f64::from(hi - 1) - p) / d
            } else if d < 0.0 {
                (1.0 - p) / d
            } else {
                f64::INFINITY
            }
        };
        exit(p.0, angle.cos(), w).min(exit(p.1, angle.sin(), h))
    }
}

#[cfg(test)]
mod tests {
    use super::box_world::{box_exit, box_range, is_wall};
    use super::*;
    use proptest::prelude::*;
    use std::collections::{BTreeSet, VecDeque};
    use std::f64::consts::{FRAC_PI_4, PI, TAU};

    /// A frame of one-metre cells at the origin, so that metres read as cells in the tests.
    fn unit_frame(g: &Grid) -> MapInfo {
        MapInfo::at_origin(g.width(), g.height(), 1.0)
    }

    fn one_beam(max_range_m: f64) -> LaserSpec {
        LaserSpec {
            beams: 1,
            fov_rad: 0.0,
            max_range_m,
            noise_std_m: 0.0,
        }
    }

    /// Integrates a scan (pose in cells, one-metre cells) into `before` and compares with
    /// `expected`; returns the number of changed cells.
    fn check(
        before: &str,
        (x, y, theta): (f64, f64, f64),
        spec: LaserSpec,
        ranges: &[f32],
        expected: &str,
    ) -> usize {
        let mut g = Grid::from_ascii(before);
        let info = unit_frame(&g);
        let changed = integrate_scan(&mut g, &info, Pose { x, y, theta }, ranges, &spec);
        assert_eq!(g.to_ascii(), Grid::from_ascii(expected).to_ascii());
        changed
    }

    fn cells(v: &[(i32, i32)]) -> Vec<Cell> {
        v.iter().map(|&(x, y)| Cell::new(x, y)).collect()
    }

    /// A segment and the cells its supercover should list, in order.
    type LineCase = ((f64, f64), (f64, f64), &'static [(i32, i32)]);

    #[test]
    fn supercover_lines() {
        let cases: &[LineCase] = &[
            ((0.5, 0.5), (3.5, 0.5), &[(0, 0), (1, 0), (2, 0), (3, 0)]),
            ((2.5, 0.5), (0.2, 0.5), &[(2, 0), (1, 0), (0, 0)]),
            ((1.0, 0.5), (-0.5, 0.5), &[(1, 0), (0, 0), (-1, 0)]),
            ((0.3, 0.3), (0.7, 0.9), &[(0, 0)]),
            ((0.5, 0.5), (2.5, 1.5), &[(0, 0), (1, 0), (1, 1), (2, 1)]),
            // Exact corner crossings list both side cells before the diagonal cell.
            (
                (0.5, 0.5),
                (2.5, 2.5),
                &[(0, 0), (1, 0), (0, 1), (1, 1), (2, 1), (1, 2), (2, 2)],
            ),
            (
                (0.5, 0.5),
                (-0.5, -0.5),
                &[(0, 0), (-1, 0), (0, -1), (-1, -1)],
            ),
            (
                (0.5, 0.5),
                (3.5, 1.5),
                &[(0, 0), (1, 0), (2, 0), (1, 1), (2, 1), (3, 1)],
            ),
        ];
        for &(from, to, expected) in cases {
            assert_eq!(supercover(from, to), cells(expected), "{from:?} -> {to:?}");
        }
    }

    #[test]
    fn supercover_rejects_unusable_coordinates() {
        assert!(supercover((0.0, 0.0), (f64::NAN, 1.0)).is_empty());
        assert!(supercover((0.0, f64::INFINITY), (1.0, 1.0)).is_empty());
        assert!(supercover((0.0, 0.0), (1e12, 1.0)).is_empty());
    }

    #[test]
    fn single_beam_to_a_wall() {
        let changed = check(
            "??????
             ??????
             ??????",
            (0.5, 1.5, 0.0),
            one_beam(10.0),
            &[2.5],
            "??????
             ...#??
             ??????",
        );
        assert_eq!(changed, 4);
    }

    #[test]
    fn hits_snap_to_the_nearest_crossing() {
        // A range rounded a little short or long still names the cell the ray entered.
        for r in [2.45, 2.5, 2.55, 2.9] {
            check("??????", (0.5, 0.5, 0.0), one_beam(10.0), &[r], "...#??");
        }
    }

    #[test]
    fn grazing_hit_names_the_wall_cell() {
        // The ray enters (3, 0) at y = 0.999 and leaves it through its top 0.005 cells later; a
        // point a hundredth of a cell past the range would already lie in (3, 1).
        let theta = (0.499_f64 / 2.5).atan();
        let range = (2.5 / theta.cos()) as f32;
        check(
            "?????
             ?????",
            (0.5, 0.5, theta),
            one_beam(10.0),
            &[range],
            "?????
             ...#?",
        );
    }

    #[test]
    fn no_return_is_free_up_to_max_range() {
        check("??????", (0.5, 0.5, 0.0), one_beam(4.0), &[4.0], ".....?");
        check(
            "??????",
            (0.5, 0.5, 0.0),
            one_beam(4.0),
            &[f32::INFINITY],
            ".....?",
        );
    }

    #[test]
    fn diagonal_beam_frees_both_cells_at_corners() {
        check(
            "????
             ????
             ????
             ????",
            (0.5, 0.5, FRAC_PI_4),
            one_beam(2.9),
            &[9.0],
            "????
             ?..?
             ...?
             ..??",
        );
    }

    #[test]
    fn evidence_corrects_a_misplaced_hit() {
        // A 1x5 corridor: one beam claims a hit in the middle, two later beams cross that cell.
        let mut g = Grid::new(5, 1, Occ::Unknown);
        let info = unit_frame(&g);
        let spec = one_beam(10.0);
        let mut ev = Evidence::new(&g);
        let pose = Pose {
            x: 0.5,
            y: 0.5,
            theta: 0.0,
        };
        ev.integrate(&mut g, &info, pose, &[1.5], &spec);
        assert_eq!(g.get(Cell::new(2, 0)), Occ::Occupied);
        ev.integrate(&mut g, &info, pose, &[3.5], &spec);
        assert_eq!(
            g.get(Cell::new(2, 0)),
            Occ::Occupied,
            "a tie stays occupied"
        );
        ev.integrate(&mut g, &info, pose, &[3.5], &spec);
        assert_eq!(
            g.get(Cell::new(2, 0)),
            Occ::Free,
            "more crossings than hits: free"
        );
        assert_eq!(g.get(Cell::new(4, 0)), Occ::Occupied);
        assert_eq!(g.get(Cell::new(0, 0)), Occ::Free);
    }

    #[test]
    fn walls_are_sticky() {
        let changed = check("?#???", (0.5, 0.5, 0.0), one_beam(4.5), &[9.0], ".#...");
        assert_eq!(changed, 4);
        // A hit turns a free cell into a wall; the cells before it stay free.
        let changed = check(".....", (0.5, 0.5, 0.0), one_beam(9.0), &[1.5], "..#..");
        assert_eq!(changed, 1);
    }

    #[test]
    fn unusable_ranges_and_own_cell_hits_carry_no_information() {
        check("???", (0.5, 0.5, 0.0), one_beam(9.0), &[f32::NAN], "???");
        check("???", (0.5, 0.5, 0.0), one_beam(9.0), &[-1.0], "???");
        check("???", (0.5, 0.5, 0.0), one_beam(9.0), &[0.2], ".??");
    }

    #[test]
    fn beams_leaving_the_grid_are_clipped() {
        // The hit lies outside the grid: every cell inside on the way is free.
        check("???", (0.5, 0.5, 0.0), one_beam(1e9), &[1e6], "...");
        // A robot outside the grid still frees the cells its beams cross inside it.
        check("???", (-2.5, 0.5, 0.0), one_beam(9.0), &[3.5], ".#?");
        // A hit just outside the grid's border is not pulled onto the border cell.
        check("???", (1.5, 0.5, PI), one_beam(9.0), &[1.5], "..?");
    }

    #[test]
    fn metric_frame_is_respected() {
        let mut g = Grid::new(6, 3, Occ::Unknown);
        let info = MapInfo {
            width: 6,
            height: 3,
            resolution_m: 0.1,
            origin_x_m: -1.0,
            origin_y_m: 2.0,
        };
        let pose = Pose {
            x: -0.95,
            y: 2.15,
            theta: 0.0,
        };
        assert_eq!(
            integrate_scan(&mut g, &info, pose, &[0.25], &one_beam(8.0)),
            4
        );
        assert_eq!(g.to_ascii(), "??????\n...#??\n??????\n");
    }

    #[test]
    fn integrating_twice_changes_nothing() {
        let mut g = Grid::new(20, 20, Occ::Unknown);
        let info = unit_frame(&g);
        let spec = LaserSpec {
            beams: 90,
            fov_rad: TAU,
            max_range_m: 6.0,
            noise_std_m: 0.0,
        };
        let ranges: Vec<f32> = (0..90).map(|i| 2.0 + (i % 7) as f32).collect();
        let pose = Pose {
            x: 10.2,
            y: 9.7,
            theta: 0.3,
        };
        assert!(integrate_scan(&mut g, &info, pose, &ranges, &spec) > 0);
        assert_eq!(integrate_scan(&mut g, &info, pose, &ranges, &spec), 0);
    }

    /// The free cells 4-connected to `from`.
    fn free_component(g: &Grid, from: Cell) -> BTreeSet<Cell> {
        let mut seen = BTreeSet::from([from]);
        let mut queue = VecDeque::from([from]);
        while let Some(c) = queue.pop_front() {
            for n in c.neighbours4() {
                if g.get(n) == Occ::Free && seen.insert(n) {
                    queue.push_back(n);
                }
            }
        }
        seen
    }

    fn random_scan() -> impl Strategy<Value = (Grid, MapInfo, Pose, Vec<f32>, LaserSpec)> {
        (4i32..30, 4i32..30, 0.05f64..0.3, -5.0f64..5.0, -5.0f64..5.0).prop_flat_map(
            |(w, h, res, ox, oy)| {
                let inner = (1.0 + 1e-6..f64::from(w - 1), 1.0 + 1e-6..f64::from(h - 1));
                (inner, -PI..PI, 0.5f64..10.0, 1u32..400).prop_map(
                    move |((px, py), theta, max_range_m, beams)| {
                        let g = Grid::new(w as u32, h as u32, Occ::Unknown);
                        let info = MapInfo {
                            width: w as u32,
                            height: h as u32,
                            resolution_m: res,
                            origin_x_m: ox,
                            origin_y_m: oy,
                        };
                        let pose = Pose {
                            x: ox + px * res,
                            y: oy + py * res,
                            theta,
                        };
                        let spec = LaserSpec {
                            beams,
                            fov_rad: TAU,
                            max_range_m,
                            noise_std_m: 0.0,
                        };
                        let ranges = (0..beams)
                            .map(|i| {
                                let angle = theta + spec.beam_angle(i);
                                box_range((px, py), angle, w, h, res, max_range_m)
                            })
                            .collect();
                        (g, info, pose, ranges, spec)
                    },
                )
            },
        )
    }

    /// Interior cells that some beam of the scan enters so close before the wall (closer than an
    /// `f32` range can tell apart, with a wide margin) that a hit in them is as right as one in
    /// the wall: a beam that nicks a cell's corner just before a wall corner.
    fn grazed_cells(
        info: &MapInfo,
        pose: Pose,
        spec: &LaserSpec,
        w: i32,
        h: i32,
    ) -> BTreeSet<Cell> {
        let p = info.in_cells(pose.xy());
        let mut out = BTreeSet::new();
        for i in 0..spec.beams {
            let angle = pose.theta + spec.beam_angle(i);
            let wall = box_exit(p, angle, w, h);
            let len = wall + 1.0;
            let end = (p.0 + len * angle.cos(), p.1 + len * angle.sin());
            let mut cells = Vec::new();
            walk(p, end, &mut cells);
            for (c, t) in cells {
                if !is_wall(c, w, h) && (t * len - wall).abs() < 1e-4 * wall.max(1.0) {
                    out.insert(c);
                }
            }
        }
        out
    }

    /// A case proptest found: beam 289 nicks cell (21, 1) 1.1·10⁻⁷ cells before it enters the
    /// bottom-right wall corner, less than the `f32` rounding of its range (7.5·10⁻⁷ cells), so
    /// the hit lands in (21, 1). No integrator can tell the two crossings apart from that range;
    /// the box test accepts such grazed cells, and this case pins that it is the only mistake.
    #[test]
    fn a_corner_nicked_closer_than_f32_can_tell() {
        let (w, h, res) = (23, 11, 0.295_413_179_178_673_55);
        let info = MapInfo {
            width: 23,
            height: 11,
            resolution_m: res,
            origin_x_m: 0.933_905_073_618_155_8,
            origin_y_m: 2.240_345_927_234_783_7,
        };
        let pose = Pose {
            x: 2.567_399_865_785_307_4,
            y: 4.263_700_736_618_365,
            theta: -1.873_488_475_669_617_3,
        };
        let spec = LaserSpec {
            beams: 384,
            fov_rad: TAU,
            max_range_m: 7.539_774_040_875_619,
            noise_std_m: 0.0,
        };
        let p = info.in_cells(pose.xy());
        let ranges: Vec<f32> = (0..spec.beams)
            .map(|i| {
                box_range(
                    p,
                    pose.theta + spec.beam_angle(i),
                    w,
                    h,
                    res,
                    spec.max_range_m,
                )
            })
            .collect();
        let mut g = Grid::new(23, 11, Occ::Unknown);
        integrate_scan(&mut g, &info, pose, &ranges, &spec);
        let wrong: Vec<Cell> = (0..g.len())
            .map(|i| g.cell_of(i))
            .filter(|&c| g.get(c) == Occ::Occupied && !is_wall(c, w, h))
            .collect();
        assert_eq!(wrong, vec![Cell::new(21, 1)]);
        assert!(grazed_cells(&info, pose, &spec, w, h).contains(&Cell::new(21, 1)));
    }

    proptest! {
        /// Asking the segment's cells one by one finds what searching its list finds, and asks
        /// no cell past the first found.
        #[test]
        fn supercover_finds_what_its_list_holds(
            a in (-20.0f64..20.0, -20.0f64..20.0),
            b in (-20.0f64..20.0, -20.0f64..20.0),
            walls in proptest::collection::btree_set((-21i32..21, -21i32..21), 0..60),
        ) {
            let wall = |c: Cell| walls.contains(&(c.x, c.y));
            let line = supercover(a, b);
            let mut asked = Vec::new();
            let found = supercover_finds(a, b, |c| {
                asked.push(c);
                wall(c)
            });
            prop_assert_eq!(found, line.iter().any(|&c| wall(c)));
            let first = line.iter().position(|&c| wall(c)).map_or(line.len(), |i| i + 1);
            prop_assert_eq!(&asked[..], &line[..first]);
        }

        #[test]
        fn supercover_touches_exactly_the_segment(
            a in (-20.0f64..20.0, -20.0f64..20.0),
            b in (-20.0f64..20.0, -20.0f64..20.0),
        ) {
            let line = supercover(a, b);
            let set: BTreeSet<Cell> = line.iter().copied().collect();
            prop_assert_eq!(set.len(), line.len(), "no cell twice");
            prop_assert_eq!(line.first(), Some(&Cell::new(a.0.floor() as i32, a.1.floor() as i32)));
            prop_assert_eq!(line.last(), Some(&Cell::new(b.0.floor() as i32, b.1.floor() as i32)));
            // Every sampled point of the segment lies in a listed cell.
            for k in 0..=200 {
                let t = f64::from(k) / 200.0;
                let p = (a.0 + t * (b.0 - a.0), a.1 + t * (b.1 - a.1));
                prop_assert!(set.contains(&Cell::new(p.0.floor() as i32, p.1.floor() as i32)));
            }
            // Every listed cell's closed square, grown by a hair, meets the segment.
            for c in &line {
                let lo = (f64::from(c.x) - 1e-6, f64::from(c.y) - 1e-6);
                let hi = (f64::from(c.x) + 1.0 + 1e-6, f64::from(c.y) + 1.0 + 1e-6);
                prop_assert!(clip(a, b, lo, hi).is_some(), "{:?} is off the segment", c);
            }
            // The cells form one 4-connected set.
            let mut seen = BTreeSet::from([line[0]]);
            let mut queue = VecDeque::from([line[0]]);
            while let Some(c) = queue.pop_front() {
                for n in c.neighbours4() {
                    if set.contains(&n) && seen.insert(n) {
                        queue.push_back(n);
                    }
                }
            }
            prop_assert_eq!(seen.len(), set.len());
        }

        #[test]
        fn full_scan_in_a_box((mut g, info, pose, ranges, spec) in random_scan()) {
            let (w, h) = (g.width() as i32, g.height() as i32);
            let changed = integrate_scan(&mut g, &info, pose, &ranges, &spec);
            prop_assert_eq!(changed, g.len() - g.count(Occ::Unknown));
            let robot = info.cell_of(pose.xy());
            prop_assert_eq!(g.get(robot), Occ::Free);
            let grazed = grazed_cells(&info, pose, &spec, w, h);
            for i in 0..g.len() {
                let c = g.cell_of(i);
                match g.get(c) {
                    Occ::Occupied => prop_assert!(
                        is_wall(c, w, h) || grazed.contains(&c),
                        "{:?} inside marked occupied",
                        c
                    ),
                    Occ::Free => prop_assert!(!is_wall(c, w, h), "wall {:?} marked free", c),
                    Occ::Unknown => {}
                }
            }
            let component = free_component(&g, robot);
            prop_assert_eq!(component.len(), g.count(Occ::Free), "free space is 4-connected");
        }

        #[test]
        fn integration_is_order_independent(
            (g, info, pose, ranges, spec) in random_scan(),
            dx in -3.0f64..3.0,
            dy in -3.0f64..3.0,
        ) {
            // A second scan from another pose, with the first scan's ranges: not a consistent
            // world, which is the point — the join must commute even for conflicting scans.
            let other = Pose { x: pose.x + dx * info.resolution_m, y: pose.y + dy * info.resolution_m, ..pose };
            let mut ab = g.clone();
            integrate_scan(&mut ab, &info, pose, &ranges, &spec);
            integrate_scan(&mut ab, &info, other, &ranges, &spec);
            let mut ba = g;
            integrate_scan(&mut ba, &info, other, &ranges, &spec);
            integrate_scan(&mut ba, &info, pose, &ranges, &spec);
            prop_assert_eq!(ab, ba);
        }
    }
}
