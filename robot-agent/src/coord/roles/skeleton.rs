//! The skeleton of the known free space and the rendezvous points on it (de Hoog, Cameron,
//! Visser, "Autonomous multi-robot exploration in communication-limited environments", TAROS
//! 2010, §IV and Algorithm 1).
//!
//! * [`thin`](crate::coord::roles::skeleton::thin): Hilditch's thinning (C. Hilditch, "Linear
//!   skeletons from square cupboards", 1969) of the free cells — a free cell is peeled off while it
//!   is a border cell whose removal keeps the shape connected and does not shorten a line to
//!   nothing, pass after pass until a pass removes nothing. A pass picks its candidates on the grid
//!   as the pass found it and removes each, in row order, only if it is still removable then
//!   (two-cell-thick lines would otherwise vanish from both sides at once). What stays is one cell
//!   wide, connected and centred.
//! * [`traversal`](crate::coord::roles::skeleton::traversal): the neighbour traversal T(p1), the
//!   number of free-after-blocked patterns in the ring p2, p3, …, p9, p2 around p1 (paper Fig. 3);
//!   on the skeleton, T ≥ 3 marks a junction.
//! * [`rendezvous_points`](crate::coord::roles::skeleton::rendezvous_points): Algorithm 1 — the
//!   junctions (T ≥ 3), then skeleton cells farther than `fill` cells from every point taken so far
//!   (filling long stretches), then pruning: a point is dropped when a point kept before it lies
//!   within `prune` cells. The paper's pruning removes a point when any other lies that close,
//!   which drops both of a close pair; here the earlier point (junctions first, higher T first)
//!   stays.

use proto::grid::{Cell, Grid, Occ};

/// The ring p2 … p9 around p1 as (dx, dy), clockwise from north (paper Fig. 3).
const RING: [(i32, i32); 8] = [
    (0, 1),
    (1, 1),
    (1, 0),
    (1, -1),
    (0, -1),
    (-1, -1),
    (-1, 0),
    (-1, 1),
];

/// Whether `c` is free in `g` (cells outside the grid are not).
fn on(g: &Grid, c: Cell) -> bool {
    g.get(c) == Occ::Free
}

/// The free cells of `g`, row by row from the bottom.
pub fn free_cells(g: &Grid) -> Vec<Cell> {
    (0..g.len())
        .map(|i| g.cell_of(i))
        .filter(|&c| on(g, c))
        .collect()
}

/// The ring around `c`: whether p2 … p9 are free in `g`.
fn ring(g: &Grid, c: Cell) -> [bool; 8] {
    RING.map(|(dx, dy)| on(g, Cell::new(c.x + dx, c.y + dy)))
}

/// T(p1): the number of (out, in) patterns in p2, p3, …, p9, p2.
pub fn traversal(g: &Grid, c: Cell) -> u8 {
    let r = ring(g, c);
    (0..8).filter(|&i| !r[i] && r[(i + 1) % 8]).count() as u8
}

/// Hilditch's conditions for removing free cell `c` of `g` (p2 = north, p4 = east, p6 = south,
/// p8 = west).
fn removable(g: &Grid, c: Cell) -> bool {
    let r = ring(g, c);
    let b = r.iter().filter(|&&v| v).count();
    if !(2..=6).contains(&b) || traversal(g, c) != 1 {
        return false;
    }
    let (p2, p4, p6, p8) = (r[0], r[2], r[4], r[6]);
    let north = Cell::new(c.x, c.y + 1);
    let east = Cell::new(c.x + 1, c.y);
    (!(p2 && p4 && p8) || traversal(g, north) != 1)
        && (!(p2 && p4 && p6) || traversal(g, east) != 1)
}

/// Hilditch's thinning of the free cells of `g` (see the module doc): `g` with the peeled cells
/// occupied, so that its free cells are the skeleton.
pub fn thin(g: &Grid) -> Grid {
    let mut m = g.clone();
    loop {
        let gone: Vec<Cell> = free_cells(&m)
            .into_iter()
            .filter(|&c| removable(&m, c))
            .collect();
        if gone.is_empty() {
            return m;
        }
        let mut removed = 0;
        for c in gone {
            if removable(&m, c) {
                m.set(c, Occ::Occupied);
                removed += 1;
            }
        }
        if removed == 0 {
            return m;
        }
    }
}

/// Algorithm 1 on a skeleton: (cell, T) of every rendezvous point, junctions first.
pub fn rendezvous_points(skeleton: &Grid, fill: f64, prune: f64) -> Vec<(Cell, u8)> {
    let dist = |a: Cell, b: Cell| a.dist(b);
    let cells = free_cells(skeleton);
    let mut points: Vec<(Cell, u8)> = cells
        .iter()
        .map(|&c| (c, traversal(skeleton, c)))
        .filter(|&(_, t)| t >= 3)
        .collect();
    points.sort_by_key(|&(c, t)| (std::cmp::Reverse(t), c.y, c.x));
    for &c in &cells {
        if points.iter().all(|&(p, _)| dist(p, c) >= fill) {
            points.push((c, traversal(skeleton, c)));
        }
    }
    let mut kept: Vec<(Cell, u8)> = Vec::new();
    for p in points {
        if kept.iter().all(|&(k, _)| dist(k, p.0) >= prune) {
            kept.push(p);
        }
    }
    kept
}

#[cfg(test)]
mod tests {
    use super::*;

    fn skeleton_of(pic: &str) -> Grid {
        thin(&Grid::from_ascii(pic))
    }

    /// Free cells of the skeleton connected (8-neighbourhood) as one piece.
    fn connected(m: &Grid) -> bool {
        let cells = free_cells(m);
        let Some(&first) = cells.first() else {
            return true;
        };
        let mut seen = vec![first];
        let mut i = 0;
        while i < seen.len() {
            let c = seen[i];
            for (dx, dy) in RING {
                let n = Cell::new(c.x + dx, c.y + dy);
                if on(m, n) && !seen.contains(&n) {
                    seen.push(n);
                }
            }
            i += 1;
        }
        seen.len() == cells.len()
    }

    #[test]
    fn a_corridor_thins_to_its_centre_line() {
        let m = skeleton_of(
            "\
####################
#..................#
#..................#
#..................#
#..................#
#..................#
####################
",
        );
        let cells = free_cells(&m);
        assert!(!cells.is_empty());
        assert!(connected(&m));
        // One cell wide: every column holds at most one skeleton cell, away from the ends.
        for x in 3..17 {
            let ys: Vec<i32> = cells.iter().filter(|c| c.x == x).map(|c| c.y).collect();
            assert_eq!(ys, [3], "column {x}: {ys:?}");
        }
    }

    #[test]
    fn a_t_thins_to_a_junction() {
        let m = skeleton_of(
            "\
#####################
#...................#
#...................#
#...................#
########.....########
########.....########
########.....########
########.....########
########.....########
#####################
",
        );
        assert!(connected(&m));
        let junctions: Vec<Cell> = free_cells(&m)
            .into_iter()
            .filter(|&c| traversal(&m, c) >= 3)
            .collect();
        assert!(!junctions.is_empty(), "{:?}", free_cells(&m));
        for j in &junctions {
            assert!((9..=11).contains(&j.x) && (6..=8).contains(&j.y), "{j:?}");
        }
    }

    /// The number of 8-connected pieces of `m`.
    fn pieces(m: &Grid) -> usize {
        let mut left = m.clone();
        let mut n = 0;
        for c in free_cells(m) {
            if !on(&left, c) {
                continue;
            }
            n += 1;
            let mut stack = vec![c];
            left.set(c, Occ::Occupied);
            while let Some(p) = stack.pop() {
                for (dx, dy) in RING {
                    let q = Cell::new(p.x + dx, p.y + dy);
                    if on(&left, q) {
                        left.set(q, Occ::Occupied);
                        stack.push(q);
                    }
                }
            }
        }
        n
    }

    proptest::proptest! {
        #![proptest_config(proptest::prelude::ProptestConfig::with_cases(64))]
        /// The skeleton lies in the free space, keeps its pieces (none vanishes, none splits)
        /// and is its own skeleton.
        #[test]
        fn thinning_keeps_pieces_and_is_idempotent(
            rects in proptest::collection::vec((1i32..18, 1i32..18, 1i32..8, 1i32..8), 1..6)
        ) {
            let mut g = Grid::new(20, 20, Occ::Occupied);
            for (x, y, w, h) in rects {
                for yy in y..(y + h).min(19) {
                    for xx in x..(x + w).min(19) {
                        g.set(Cell::new(xx, yy), Occ::Free);
                    }
                }
            }
            let free = g;
            let sk = thin(&free);
            proptest::prop_assert!(free_cells(&sk).iter().all(|&c| on(&free, c)));
            proptest::prop_assert_eq!(pieces(&sk), pieces(&free));
            proptest::prop_assert_eq!(thin(&sk), sk);
        }
    }

    #[test]
    fn traversal_counts_branches() {
        let m = Grid::from_ascii(".#.\n#.#\n.#.\n");
        assert_eq!(traversal(&m, Cell::new(1, 1)), 4);
        let m = Grid::from_ascii("...\n...\n...\n");
        assert_eq!(traversal(&m, Cell::new(1, 1)), 0);
        let m = Grid::from_ascii("###\n...\n###\n");
        assert_eq!(traversal(&m, Cell::new(1, 1)), 2);
    }

    #[test]
    fn rendezvous_points_keep_junctions_fill_stretches_and_prune() {
        // A long line with a branch at x = 10: the junction, points every 4 cells along the
        // line, none closer than 3 to another.
        let mut pic = String::new();
        for y in (0..7).rev() {
            for x in 0..30 {
                let on = (y == 3 && x > 0 && x < 29) || (x == 10 && y > 3 && y < 6);
                pic.push(if on { '.' } else { '#' });
            }
            pic.push('\n');
        }
        let m = Grid::from_ascii(&pic);
        let points = rendezvous_points(&m, 4.0, 3.0);
        assert_eq!(points.first(), Some(&(Cell::new(10, 3), 3)));
        let dist = |a: Cell, b: Cell| a.dist(b);
        for (i, &(a, _)) in points.iter().enumerate() {
            for &(b, _) in &points[i + 1..] {
                assert!(dist(a, b) >= 3.0, "{a:?} {b:?}");
            }
        }
        // Every skeleton cell is near a point (filling).
        for c in free_cells(&m) {
            assert!(points.iter().any(|&(p, _)| dist(p, c) < 4.0 + 3.0), "{c:?}");
        }
        assert!(points.len() >= 6, "{points:?}");
    }
}
