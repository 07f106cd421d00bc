//! Contour extraction: the exact polygonal model P_t of a ternary grid (thesis §4.1,
//! Table 4.1, Algorithms 1–3; DESIGN §4.1).
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
//! objects**). Extraction is linear: one scan over the cells finds the auxiliary points and a bit
//! per (cell, direction) marks the ones already traced (the thesis's `auxPointIndex`, where
//! removal is clearing that bit).

use std::collections::HashMap;
use std::hash::{BuildHasherDefault, Hasher};

use proto::grid::{Cell, Grid, Occ};

use crate::qpoint::{area2, QPoint};

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
    pub fn extract(grid: &Grid) -> Contours {
        let mut tracer = Tracer::new(grid);
        let mut objects = Vec::new();
        let (w, h) = (
            tracer.padded.width,
            tracer.padded.free.len() / tracer.padded.width,
        );
        for y in 0..h {
            for x in 0..w {
                let at = y * w + x;
                if tracer.padded.free[at] {
                    continue;
                }
                let sides = [x + 1 < w, y + 1 < h, x > 0, y > 0];
                for (dir, &inside) in sides.iter().enumerate() {
                    let start = Aux { at, dir };
                    let aux = inside && tracer.padded.free[tracer.padded.step(at, dir)];
                    if aux && !tracer.visited(start) {
                        objects.push(tracer.trace(start));
                    }
                }
            }
        }
        let total = objects.iter().map(|c: &Contour| c.points.len()).sum();
        let mut index = HashMap::with_capacity_and_hasher(total, Default::default());
        for (obj, c) in objects.iter().enumerate() {
            for (i, &p) in c.points.iter().enumerate() {
                index.insert(p, (obj as u32, i as u32));
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

/// An auxiliary point: contour pixel (index into the padded grid) and the direction (index
/// into [`DIRS`]) of its free side.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
struct Aux {
    at: usize,
    dir: usize,
}

/// The grid's free cells in a frame padded with one ring of non-free cells, so that every
/// neighbour of a contour pixel is an index step away.
struct Padded {
    width: usize,
    free: Vec<bool>,
}

impl Padded {
    fn new(grid: &Grid) -> Padded {
        let (w, h) = (grid.width() as usize, grid.height() as usize);
        let mut free = vec![false; (w + 2) * (h + 2)];
        for (i, &c) in grid.cells().iter().enumerate() {
            free[(i / w + 1) * (w + 2) + i % w + 1] = c == Occ::Free;
        }
        Padded { width: w + 2, free }
    }

    /// The neighbour of padded index `at` in direction `d` (callers stay inside the frame:
    /// the padding ring is never free, so a free cell's neighbours are all in it).
    fn step(&self, at: usize, d: usize) -> usize {
        match d {
            0 => at + 1,
            1 => at + self.width,
            2 => at - 1,
            _ => at - self.width,
        }
    }

    fn cell(&self, at: usize) -> Cell {
        Cell::new((at % self.width) as i32 - 1, (at / self.width) as i32 - 1)
    }

    fn point(&self, a: Aux) -> QPoint {
        let (c, (dx, dy)) = (self.cell(a.at), DIRS[a.dir]);
        QPoint::new(4 * c.x + 2 + dx, 4 * c.y + 2 + dy)
    }
}

/// Follows cycles of auxiliary points and remembers which ones it has traced.
struct Tracer<'g> {
    grid: &'g Grid,
    padded: Padded,
    visited: Vec<u64>,
}

impl<'g> Tracer<'g> {
    fn new(grid: &'g Grid) -> Tracer<'g> {
        let padded = Padded::new(grid);
        let words = (padded.free.len() * 4).div_ceil(64);
        Tracer {
            grid,
            padded,
            visited: vec![0; words],
        }
    }

    fn visited(&self, a: Aux) -> bool {
        let b = a.at * 4 + a.dir;
        self.visited[b / 64] & (1 << (b % 64)) != 0
    }

    fn mark(&mut self, a: Aux) {
        let b = a.at * 4 + a.dir;
        self.visited[b / 64] |= 1 << (b % 64);
    }

    /// The successor of `a`: 90° right, else straight, else 90° left (Algorithm 1).
    fn next(&self, a: Aux) -> Aux {
        let n = a.dir;
        let m = (n + 1) % 4; // direction of movement: free side on the right
        let ahead = self.padded.step(a.at, m);
        let diagonal = self.padded.step(ahead, n);
        if !self.padded.free[diagonal] {
            Aux {
                at: diagonal,
                dir: (m + 2) % 4,
            }
        } else if !self.padded.free[ahead] {
            Aux { at: ahead, dir: n }
        } else {
            Aux { at: a.at, dir: m }
        }
    }

    /// Traces the object through `start` (Algorithm 2, iteratively).
    fn trace(&mut self, start: Aux) -> Contour {
        let (mut points, mut occ) = (Vec::new(), Vec::new());
        let mut a = start;
        loop {
            self.mark(a);
            points.push(self.padded.point(a));
            occ.push(self.grid.get(self.padded.cell(a.at)));
            a = self.next(a);
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
}
