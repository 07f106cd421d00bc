//! Contour extraction: the exact polygonal model P_t of a ternary grid (thesis §4.1,
//! Table 4.1, Algorithms 1–3; docs/design.md §4.1).
//!
//! A *contour pixel* is an occupied or unknown cell with a free 4-neighbour. Every contour edge
//! (between a contour pixel `c` and a free neighbour in direction `n`) gets an *auxiliary point*
//! 0.25 cell from `c`'s centre toward the free side, `4c + 2 + n` in quarter cells
//! ([`QPoint`](crate::mapping::qpoint::QPoint)). We trace with the non-free pixel on the left and
//! the free cell on the right, i.e. counter-clockwise around every obstacle; from each auxiliary
//! point the successor is the edge 90° right (around the free cell), else straight ahead, else 90°
//! left — Table 4.1's offsets (3m+3n, 4m, m−n in quarter cells, m the direction of movement). That
//! order makes obstacles 8-connected and free space 4-connected, so contours never cross or touch.
//!
//! The grid is read as if padded with one ring of unknown cells, so free space touching the border
//! is closed by contour pixels just outside the grid. Every cycle of auxiliary points is one
//! object: clockwise cycles enclose a free region (**inside objects**, one per 4-connected free
//! region), counter-clockwise cycles enclose obstacles or unknown islands (**outside objects**).
//! P_t is kept from step to step ([`Contours::update`](crate::mapping::contour::Contours::update)):
//! an object follows from the cells within one cell of its points, so only the objects next to the
//! cells a scan changed are traced anew — from the contour pixels next to those cells, each from
//! its first point in scan order, in the order a fresh extraction finds them. Tracing marks each
//! auxiliary point in the point index as it goes (the thesis's `auxPointIndex`, where removal is
//! marking), so nothing is proportional to the grid's area; a fresh extraction
//! ([`Contours::extract`](crate::mapping::contour::Contours::extract), the first step) examines
//! every cell once (the thesis's Algorithm 3 step 1).

use std::collections::{BTreeSet, HashMap};
use std::hash::{BuildHasherDefault, Hasher};

use proto::grid::{Cell, Grid, Occ, Rect};

use crate::mapping::qpoint::{area2, QPoint};

/// Unit steps right, up, left, down (the order of [`Cell::neighbours4`]); `d + 1` is 90° ccw.
const DIRS: [(i32, i32); 4] = [(1, 0), (0, 1), (-1, 0), (0, -1)];

/// Which side of the polygon is free.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Kind {
    /// Clockwise; encloses a free region (and the outside objects inside it).
    Inside,
    /// Counter-clockwise; encloses occupied or unknown space.
    Outside,
}

/// One object of P_t: its auxiliary points in tracing order and, per point, the occupancy of
/// the contour pixel it lies on (`Occupied` or `Unknown`).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Contour {
    pub kind: Kind,
    pub points: Vec<QPoint>,
    pub occ: Vec<Occ>,
}

/// The exact polygonal model P_t: all objects of a grid, and where each point lies.
///
/// Kept from step to step ([`Contours::update`]): an object is a function of the cells next to
/// its points, so only those passing next to a changed cell are traced anew. Each object has a
/// *slot*, its name in the point index while it lives, so that an object's place in scan order
/// may change without re-entering its points.
#[derive(Clone, Debug, Default)]
pub struct Contours {
    /// In the scan order of their first point (the order [`Contours::extract_at`] finds them).
    objects: Vec<Contour>,
    /// Per object, its slot.
    slots: Vec<u32>,
    /// Per slot, its object's place in `objects` ([`FREE`]: none; [`TRACED`]: traced in the
    /// update under way).
    place: Vec<u32>,
    /// Slots free for new objects.
    spare: Vec<u32>,
    /// Point → (slot, point index).
    index: HashMap<QPoint, (u32, u32), BuildHasherDefault<QHasher>>,
    /// The size of the grid the objects are of.
    size: (u32, u32),
}

/// A slot without an object ([`Contours::place`]).
const FREE: u32 = u32::MAX;

/// The slot of an object traced in this update, not yet given its place.
const TRACED: u32 = u32::MAX - 1;

impl Contours {
    /// Extracts every object of `grid` (Algorithm 3), in the scan order of their first point.
    /// Examines every cell once; a caller that extracts every step keeps the result and calls
    /// [`Contours::update`].
    pub fn extract(grid: &Grid) -> Contours {
        Contours::extract_at(grid, &ContourPixels::scan(grid))
    }

    /// [`Contours::extract`] with the contour pixels of `grid` already known
    /// ([`ContourPixels::scan`]): time linear in their number.
    pub fn extract_at(grid: &Grid, pixels: &ContourPixels) -> Contours {
        let mut p = Contours {
            index: HashMap::with_capacity_and_hasher(pixels.len() * 2, Default::default()),
            size: (grid.width(), grid.height()),
            ..Contours::default()
        };
        let mut found = Vec::new();
        for c in pixels.iter() {
            p.trace_from(grid, c, &mut found);
        }
        p.reorder(found);
        p
    }

    /// P_t of `grid` after the cells `changed` changed (any other cell as when `self` was
    /// extracted): the objects that pass next to no changed cell are kept, the others traced
    /// anew, in time proportional to the change and the objects traced — the same objects in
    /// the same order as [`Contours::extract`]. An object's points, and so the object, follow
    /// from the cells within one cell of them: one with no point next to a changed cell is
    /// unchanged, and every other object of the new grid has a contour pixel next to one.
    pub fn update(&mut self, grid: &Grid, changed: &[Cell]) {
        if (grid.width(), grid.height()) != self.size {
            *self = Contours::extract(grid);
            return;
        }
        // The cells next to a changed cell, each once.
        let mut near: Vec<Cell> = (changed.iter())
            .flat_map(|&c| Rect::cell(c).grown(1).cells())
            .collect();
        near.sort_unstable_by_key(|c| (c.y, c.x));
        near.dedup();
        let mut gone = BTreeSet::new();
        for &at in &near {
            for dir in 0..4 {
                if let Some(&(slot, _)) = self.index.get(&Aux { at, dir }.point()) {
                    gone.insert(slot);
                }
            }
        }
        // A gone object's points stay in the index, read as absent while its slot has no
        // place, and are written over as the objects through them are traced again; what is
        // left of them afterwards lies on the cells `near` (why: docs/design.md §4.1).
        for &slot in &gone {
            self.place[slot as usize] = FREE;
        }
        let mut found = Vec::new();
        for &at in &near {
            if is_contour(grid, at) {
                self.trace_from(grid, at, &mut found);
            }
        }
        // What is left of the gone objects: their points on the cells `near` that P_t lost.
        for &at in &near {
            for dir in 0..4 {
                let q = Aux { at, dir }.point();
                if (self.index.get(&q)).is_some_and(|&(slot, _)| self.place[slot as usize] == FREE)
                {
                    self.index.remove(&q);
                }
            }
        }
        // Slots freed here are given out from the next update on: while tracing, a point
        // under a freed slot is one of a gone object's.
        self.spare.extend(gone);
        self.reorder(found);
    }

    /// Whether `q` is a point of an object that lives (kept, or traced in this update).
    fn holds(&self, q: QPoint) -> bool {
        (self.index.get(&q)).is_some_and(|&(slot, _)| self.place[slot as usize] != FREE)
    }

    /// Traces, in [`DIRS`] order, every object through a point of contour pixel `c` that
    /// is not yet in the index, from its first point in scan order, in a new slot, appending
    /// it to `found`.
    fn trace_from(&mut self, grid: &Grid, c: Cell, found: &mut Vec<Contour>) {
        for dir in 0..4 {
            let start = Aux { at: c, dir };
            if !is_free(grid, step(c, dir)) || self.holds(start.point()) {
                continue;
            }
            let mut contour = trace(grid, start);
            let first = (contour.points.iter().enumerate())
                .min_by_key(|&(_, &q)| Aux::of(q).scan_order())
                .map_or(0, |(i, _)| i);
            contour.points.rotate_left(first);
            contour.occ.rotate_left(first);
            let slot = self.spare.pop().unwrap_or_else(|| {
                self.place.push(FREE);
                self.place.len() as u32 - 1
            });
            // Live, its place in the order given by `reorder`.
            self.place[slot as usize] = TRACED;
            for (i, &q) in contour.points.iter().enumerate() {
                self.index.insert(q, (slot, i as u32));
            }
            self.slots.push(slot);
            found.push(contour);
        }
    }

    /// Puts the objects kept (those whose slot still has a place) and those `found` (whose
    /// slots are the last of `slots`) in scan order of their first points.
    fn reorder(&mut self, found: Vec<Contour>) {
        let new_slots = self.slots.split_off(self.objects.len());
        let old = std::mem::take(&mut self.objects).into_iter();
        let old = old.zip(std::mem::take(&mut self.slots));
        let mut all: Vec<(Contour, u32)> = (old.filter(|&(_, s)| self.place[s as usize] != FREE))
            .chain(found.into_iter().zip(new_slots))
            .collect();
        // Two sorted runs: a merge.
        all.sort_by_key(|(c, _)| Aux::of(c.points[0]).scan_order());
        for (contour, slot) in all {
            self.place[slot as usize] = self.objects.len() as u32;
            self.objects.push(contour);
            self.slots.push(slot);
        }
    }

    pub fn objects(&self) -> &[Contour] {
        &self.objects
    }

    /// Total number of points of all objects.
    pub fn len(&self) -> usize {
        self.index.len()
    }

    pub fn is_empty(&self) -> bool {
        self.index.is_empty()
    }

    /// The (object, point index) of a point of P_t, or `None` if `q` is not on P_t.
    pub fn locate(&self, q: QPoint) -> Option<(usize, usize)> {
        (self.index.get(&q)).map(|&(slot, i)| (self.place[slot as usize] as usize, i as usize))
    }
}

/// Whether `c` is a free cell of `grid` (the frame around the grid reads unknown).
fn is_free(grid: &Grid, c: Cell) -> bool {
    grid.contains(c) && grid.get(c) == Occ::Free
}

/// The neighbour of `c` in direction `d` (an index into [`DIRS`]).
fn step(c: Cell, d: usize) -> Cell {
    Cell::new(c.x + DIRS[d].0, c.y + DIRS[d].1)
}

/// Whether `c` is a contour pixel of `grid`: not free, with a free 4-neighbour. Only cells in
/// the grid or in the one-cell ring around it can be.
fn is_contour(grid: &Grid, c: Cell) -> bool {
    !is_free(grid, c) && (0..4).any(|d| is_free(grid, step(c, d)))
}

/// The contour pixels of a grid in scan order (rows bottom-up, left to right), the ring of
/// cells just outside the grid included — the starting points of Algorithm 3.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct ContourPixels {
    /// (y, x): scan order.
    set: BTreeSet<(i32, i32)>,
}

impl ContourPixels {
    /// The contour pixels of `grid`, examining every cell once.
    pub fn scan(grid: &Grid) -> ContourPixels {
        let (w, h) = (grid.width() as i32, grid.height() as i32);
        let set = (-1..=h)
            .flat_map(|y| (-1..=w).map(move |x| (y, x)))
            .filter(|&(y, x)| is_contour(grid, Cell::new(x, y)))
            .collect();
        ContourPixels { set }
    }

    pub fn len(&self) -> usize {
        self.set.len()
    }

    pub fn is_empty(&self) -> bool {
        self.set.is_empty()
    }

    /// The contour pixels in scan order.
    pub fn iter(&self) -> impl Iterator<Item = Cell> + '_ {
        self.set.iter().map(|&(y, x)| Cell::new(x, y))
    }
}

/// An auxiliary point: a contour pixel and the direction (index into [`DIRS`]) of its free
/// side.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
struct Aux {
    at: Cell,
    dir: usize,
}

impl Aux {
    fn point(self) -> QPoint {
        let (dx, dy) = DIRS[self.dir];
        QPoint::new(4 * self.at.x + 2 + dx, 4 * self.at.y + 2 + dy)
    }

    /// The auxiliary point at `q` ([`Aux::point`]'s inverse).
    fn of(q: QPoint) -> Aux {
        let dir = match (q.x.rem_euclid(4), q.y.rem_euclid(4)) {
            (3, _) => 0,
            (_, 3) => 1,
            (1, _) => 2,
            _ => 3,
        };
        let (dx, dy) = DIRS[dir];
        let at = Cell::new((q.x - 2 - dx).div_euclid(4), (q.y - 2 - dy).div_euclid(4));
        Aux { at, dir }
    }

    /// Where it comes in [`Contours::extract_at`]'s scan: by pixel (rows bottom-up, left to
    /// right), then direction.
    fn scan_order(self) -> (i32, i32, usize) {
        (self.at.y, self.at.x, self.dir)
    }

    /// The successor: 90° right, else straight, else 90° left (Algorithm 1, Table 4.1).
    fn next(self, grid: &Grid) -> Aux {
        let n = self.dir;
        let m = (n + 1) % 4; // direction of movement: free side on the right
        let ahead = step(self.at, m);
        let diagonal = step(ahead, n);
        if !is_free(grid, diagonal) {
            Aux {
                at: diagonal,
                dir: (m + 2) % 4,
            }
        } else if !is_free(grid, ahead) {
            Aux { at: ahead, dir: n }
        } else {
            Aux {
                at: self.at,
                dir: m,
            }
        }
    }
}

/// Traces the object through `start` (Algorithm 2, iteratively).
fn trace(grid: &Grid, start: Aux) -> Contour {
    let (mut points, mut occ) = (Vec::new(), Vec::new());
    let mut a = start;
    loop {
        points.push(a.point());
        occ.push(grid.get(a.at));
        a = a.next(grid);
        if a == start {
            break;
        }
    }
    let kind = if area2(&points) < 0 {
        Kind::Inside
    } else {
        Kind::Outside
    };
    Contour { kind, points, occ }
}

/// FxHash-style hasher for [`QPoint`] keys: the index is rebuilt every step, so hashing speed
/// matters and HashDoS does not (the keys come from our own grid).
#[derive(Default)]
struct QHasher(u64);

impl Hasher for QHasher {
    fn finish(&self) -> u64 {
        self.0
    }

    fn write(&mut self, bytes: &[u8]) {
        for &b in bytes {
            self.write_u64(u64::from(b));
        }
    }

    fn write_i32(&mut self, v: i32) {
        self.write_u64(v as u32 as u64);
    }

    fn write_u64(&mut self, v: u64) {
        self.0 = (self.0.rotate_left(5) ^ v).wrapping_mul(0x517c_c1b7_2722_0a95);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::testutil::{arb_grid, arb_map_window, polygons_meet, self_intersection, winding};
    use proptest::prelude::*;

    /// Objects as "I<n>"/"O<n>" (kind, point count), sorted, space separated.
    fn summary(c: &Contours) -> String {
        let mut v: Vec<String> = c
            .objects()
            .iter()
            .map(|o| {
                format!(
                    "{}{}",
                    if o.kind == Kind::Inside { 'I' } else { 'O' },
                    o.points.len()
                )
            })
            .collect();
        v.sort();
        v.join(" ")
    }

    fn check(pic: &str, expect: &str) -> Contours {
        let g = Grid::from_ascii(pic);
        let c = Contours::extract(&g);
        assert_eq!(summary(&c), expect, "objects of\n{pic}");
        assert_invariants(&g, &c);
        c
    }

    /// How many distinct objects the auxiliary points of cell `c` belong to.
    fn lines_through(c: &Contours, cell: Cell) -> usize {
        let centre = QPoint::centre(cell);
        let mut objs: Vec<usize> = DIRS
            .iter()
            .filter_map(|&(dx, dy)| {
                c.locate(QPoint::new(centre.x + dx, centre.y + dy))
                    .map(|(o, _)| o)
            })
            .collect();
        objs.sort();
        objs.dedup();
        objs.len()
    }

    #[test]
    fn single_obstacle_is_traced_counter_clockwise() {
        let c = check("...\n.#.\n...", "I12 O4");
        let o = c
            .objects()
            .iter()
            .find(|o| o.kind == Kind::Outside)
            .map(|o| o.points.clone());
        let pts = [(7, 6), (6, 7), (5, 6), (6, 5)]
            .map(|(x, y)| QPoint::new(x, y))
            .to_vec();
        assert_eq!(o, Some(pts));
    }

    #[test]
    fn pixel_on_one_to_four_contour_lines() {
        // Fig. 4.1: the centre pixel borders 1, 2, 3, 4 free cells that are separate regions.
        let one = check("#####\n##.##\n#####\n#####\n#####", "I4");
        let two = check("#####\n##.##\n#.###\n#####\n#####", "I4 I4");
        let three = check("#####\n##.##\n#.#.#\n#####\n#####", "I4 I4 I4");
        let four = check("#####\n##.##\n#.#.#\n##.##\n#####", "I4 I4 I4 I4");
        for (c, n) in [(one, 1), (two, 2), (three, 3), (four, 4)] {
            assert_eq!(lines_through(&c, Cell::new(2, 2)), n);
        }
    }

    #[test]
    fn one_pixel_line_is_one_closed_object() {
        // Tracing pixel to pixel gets stuck at the end of a thin line; edges do not.
        check(".....\n.###.\n.....", "I16 O8");
        check(".......\n.#.#.#.\n..#.#..\n.......", "I22 O20");
    }

    #[test]
    fn critical_diagonal_case() {
        // Fig. 4.2(a): diagonal obstacles join (8-connected), diagonal free cells do not.
        check("....\n.#..\n..#.\n....", "I16 O8");
        check("####\n#.##\n##.#\n####", "I4 I4");
    }

    #[test]
    fn ring_encloses_a_second_free_region() {
        check(".......\n.#####.\n.#...#.\n.#####.\n.......", "I24 I8 O16");
    }

    #[test]
    fn free_space_at_the_border_is_closed_outside_the_grid() {
        let c = check("..\n..", "I8");
        let pts = &c.objects()[0].points;
        let outside = |p: &QPoint| !(0..2).contains(&p.cell().x) || !(0..2).contains(&p.cell().y);
        assert!(
            pts.iter().all(outside),
            "all contour pixels lie in the padding ring"
        );
        assert!(c.objects()[0].occ.iter().all(|&o| o == Occ::Unknown));
    }

    #[test]
    fn each_point_carries_its_cells_occupancy() {
        let c = check("?##\n...", "I8");
        let occ = &c.objects()[0].occ;
        assert_eq!(occ.iter().filter(|&&o| o == Occ::Occupied).count(), 2);
        assert_eq!(occ.iter().filter(|&&o| o == Occ::Unknown).count(), 6);
    }

    /// Closed (valid steps), simple, pairwise disjoint, consistently oriented: the winding
    /// number of all objects together is -1 at every free cell and 0 at every other cell.
    pub(crate) fn assert_invariants(g: &Grid, c: &Contours) {
        let objs = c.objects();
        for o in objs {
            let n = o.points.len();
            for i in 0..n {
                let (a, b) = (o.points[i], o.points[(i + 1) % n]);
                let d = ((b.x - a.x).abs(), (b.y - a.y).abs());
                assert!(
                    matches!(d, (4, 0) | (0, 4) | (1, 1) | (3, 3)),
                    "bad step {a:?}->{b:?}"
                );
            }
            assert_eq!(
                self_intersection(&o.points),
                None,
                "self-intersecting {:?}",
                o.points
            );
            assert_eq!(o.kind == Kind::Inside, area2(&o.points) < 0);
        }
        for i in 0..objs.len() {
            for j in i + 1..objs.len() {
                assert!(
                    !polygons_meet(&objs[i].points, &objs[j].points),
                    "objects {i}, {j} meet"
                );
            }
        }
        for y in 0..g.height() as i32 {
            for x in 0..g.width() as i32 {
                let cell = Cell::new(x, y);
                let w: i32 = objs
                    .iter()
                    .map(|o| winding(&o.points, QPoint::centre(cell)))
                    .sum();
                let want = if g.get(cell) == Occ::Free { -1 } else { 0 };
                assert_eq!(w, want, "winding at {cell:?}");
            }
        }
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(128))]

        #[test]
        fn random_grids_give_valid_contours(g in arb_grid(14)) {
            assert_invariants(&g, &Contours::extract(&g));
        }

        #[test]
        fn real_map_windows_give_valid_contours(g in arb_map_window(24, 24)) {
            assert_invariants(&g, &Contours::extract(&g));
        }
    }

    /// Whether `kept` is `fresh`: the same objects in the same order, each point located at
    /// the same object and index.
    fn same(kept: &Contours, fresh: &Contours) -> Result<(), TestCaseError> {
        prop_assert_eq!(kept.objects(), fresh.objects());
        prop_assert_eq!(kept.len(), fresh.len());
        for o in fresh.objects() {
            for &q in &o.points {
                prop_assert_eq!(kept.locate(q), fresh.locate(q));
            }
        }
        Ok(())
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(256))]

        /// P_t kept from step to step, only the objects next to changed cells traced anew, is
        /// P_t extracted afresh — objects, their order (which decides the approximation's ids)
        /// and every point's place — after any sequence of changes, on random grids and on
        /// windows of real maps (long walls, one big free region).
        #[test]
        fn contours_kept_from_step_to_step_are_the_contours_extracted_afresh(
            g in prop_oneof![arb_grid(12), arb_map_window(24, 24)],
            edits in proptest::collection::vec(
                proptest::collection::vec((0i32..24, 0i32..24, 0u8..3), 0..30), 1..8)
        ) {
            let mut g = g;
            let mut kept = Contours::extract(&g);
            for batch in edits {
                let mut changed = Vec::new();
                for (x, y, v) in batch {
                    let c = Cell::new(x, y);
                    let v = [Occ::Free, Occ::Occupied, Occ::Unknown][usize::from(v)];
                    if g.contains(c) && g.get(c) != v {
                        g.set(c, v);
                        changed.push(c);
                    }
                }
                kept.update(&g, &changed);
                same(&kept, &Contours::extract(&g))?;
                assert_invariants(&g, &kept);
            }
        }
    }

    #[test]
    fn contour_pixels_include_the_ring_outside_the_grid() {
        let g = Grid::from_ascii("..\n");
        let p = ContourPixels::scan(&g);
        // Every cell of the ring around the 2×1 free strip is a contour pixel except corners.
        let want = [(0, -1), (1, -1), (-1, 0), (2, 0), (0, 1), (1, 1)];
        let got: Vec<(i32, i32)> = p.iter().map(|c| (c.x, c.y)).collect();
        let mut want: Vec<(i32, i32)> = want.to_vec();
        want.sort_by_key(|&(x, y)| (y, x));
        assert_eq!(got, want);
    }
}
