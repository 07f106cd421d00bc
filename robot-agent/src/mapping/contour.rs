//! Contour extraction: the exact polygonal model P_t of a ternary grid (thesis §4.1,
//! Table 4.1, Algorithms 1–3; docs/design.md §4.1).
//!
//! A *contour pixel* is an occupied or unknown cell with a free 4-neighbour. Every contour edge
//! (between a contour pixel `c` and a free neighbour in direction `n`) gets an *auxiliary point*
//! 0.25 cell from `c`'s centre toward the free side, `4c + 2 + n` in quarter cells
//! ([`QPoint`]). We trace with the non-free pixel on the left and the free cell on the right,
//! i.e. counter-clockwise around every obstacle; from each auxiliary point the successor is the
//! edge 90° right (around the free cell), else straight ahead, else 90° left — Table 4.1's
//! offsets (3m+3n, 4m, m−n in quarter cells, m the direction of movement). That order makes
//! obstacles 8-connected and free space 4-connected, so contours never cross or touch.
//!
//! The grid is read as if padded with one ring of unknown cells, so free space touching the
//! border is closed by contour pixels just outside the grid. Every cycle of auxiliary points is
//! one object: clockwise cycles enclose a free region (**inside objects**, one per 4-connected
//! free region), counter-clockwise cycles enclose obstacles or unknown islands (**outside
//! objects**). Extraction is linear in the number of contour pixels: [`ContourPixels`] keeps
//! the set of contour pixels in scan order and is updated from the cells a scan changed (the
//! thesis's Algorithm 3 step 1 examines every cell instead), and tracing marks each auxiliary
//! point in the point index as it goes (the thesis's `auxPointIndex`, where removal is
//! marking), so nothing is proportional to the grid's area.

use std::collections::{BTreeSet, HashMap};
use std::hash::{BuildHasherDefault, Hasher};

use proto::grid::{Cell, Grid, Occ};

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
#[derive(Clone, Debug, Default)]
pub struct Contours {
    objects: Vec<Contour>,
    index: HashMap<QPoint, (u32, u32), BuildHasherDefault<QHasher>>,
}

impl Contours {
    /// Extracts every object of `grid` (Algorithm 3), in the scan order of their first point.
    /// Examines every cell once; a caller that extracts every step keeps a [`ContourPixels`]
    /// and calls [`Contours::extract_at`].
    pub fn extract(grid: &Grid) -> Contours {
        Contours::extract_at(grid, &ContourPixels::scan(grid))
    }

    /// [`Contours::extract`] with the contour pixels of `grid` already known: time linear in
    /// their number. `pixels` must be up to date for `grid` (see [`ContourPixels::update`]).
    pub fn extract_at(grid: &Grid, pixels: &ContourPixels) -> Contours {
        let mut index: HashMap<QPoint, (u32, u32), BuildHasherDefault<QHasher>> =
            HashMap::with_capacity_and_hasher(pixels.len() * 2, Default::default());
        let mut objects = Vec::new();
        for c in pixels.iter() {
            for dir in 0..4 {
                let start = Aux { at: c, dir };
                if is_free(grid, step(c, dir)) && !index.contains_key(&start.point()) {
                    let contour = trace(grid, start, objects.len() as u32, &mut index);
                    objects.push(contour);
                }
            }
        }
        Contours { objects, index }
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
        self.index.get(&q).map(|&(o, i)| (o as usize, i as usize))
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
/// cells just outside the grid included — the starting points of Algorithm 3, kept up to date
/// from the cells that change instead of found by examining every cell each step.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct ContourPixels {
    width: u32,
    height: u32,
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
        ContourPixels {
            width: grid.width(),
            height: grid.height(),
            set,
        }
    }

    /// Brings the set up to date after the cells `changed` of `grid` changed (any other cell
    /// is as when the set was last up to date). A grid of another size is scanned afresh.
    pub fn update(&mut self, grid: &Grid, changed: impl IntoIterator<Item = Cell>) {
        if (grid.width(), grid.height()) != (self.width, self.height) {
            *self = ContourPixels::scan(grid);
            return;
        }
        for c in changed {
            for p in std::iter::once(c).chain(c.neighbours4()) {
                if is_contour(grid, p) {
                    self.set.insert((p.y, p.x));
                } else {
                    self.set.remove(&(p.y, p.x));
                }
            }
        }
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

/// Traces object number `obj` through `start` (Algorithm 2, iteratively), entering each of its
/// points in `index`.
fn trace(
    grid: &Grid,
    start: Aux,
    obj: u32,
    index: &mut HashMap<QPoint, (u32, u32), BuildHasherDefault<QHasher>>,
) -> Contour {
    let (mut points, mut occ) = (Vec::new(), Vec::new());
    let mut a = start;
    loop {
        let p = a.point();
        index.insert(p, (obj, points.len() as u32));
        points.push(p);
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

        /// The incrementally kept contour pixels equal a fresh scan after any sequence of
        /// cell changes, and extraction from them gives the same objects in the same order.
        #[test]
        fn updated_contour_pixels_equal_a_fresh_scan(
            g in arb_grid(12),
            edits in proptest::collection::vec(
                proptest::collection::vec((0i32..12, 0i32..12, 0u8..3), 0..20), 1..6)
        ) {
            let mut g = g;
            let mut pixels = ContourPixels::scan(&g);
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
                pixels.update(&g, changed);
                prop_assert_eq!(&pixels, &ContourPixels::scan(&g));
                let (a, b) = (Contours::extract_at(&g, &pixels), Contours::extract(&g));
                prop_assert_eq!(a.objects(), b.objects());
                assert_invariants(&g, &a);
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
