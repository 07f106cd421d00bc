//! Rasterizing polygons in quarter cells onto grid cells, for the merge of thesis §5.2
//! (Algorithm 9 renders filled objects and their contours).
//!
//! A cell belongs to a filled polygon when its centre does (even–odd rule, scan lines through
//! the cell centres; a centre exactly on an edge counts as inside to the left of it). Exact
//! contours (§4.1) never pass through a cell centre, so for them the rule never matters.
//! An edge covers the 8-connected Bresenham line between the cells of its end points,
//! half-open: the end cell belongs to the next edge. This way every vertex paints exactly its
//! own cell with its own edge's occupancy, and the 3/4-cell diagonal of a contour that wraps a
//! free cell does not paint that free cell.

use std::ops::Range;

use proto::grid::Cell;

use crate::mapping::qpoint::QPoint;

/// Calls `span(y, x0, x1)` for every maximal run of cells `x0..=x1` in row `y` whose centres
/// lie inside the closed polygon `poly`, for the rows in `rows` (columns are not clipped).
pub fn fill(poly: &[QPoint], rows: Range<i32>, span: impl FnMut(i32, i32, i32)) {
    let n = poly.len();
    fill_edges((0..n).map(|i| (poly[i], poly[(i + 1) % n])), rows, span);
}

/// [`fill`] from the polygon's edges: every edge that crosses a row of `rows` must be among
/// them (others are passed over).
pub fn fill_edges(
    edges: impl Iterator<Item = (QPoint, QPoint)>,
    rows: Range<i32>,
    mut span: impl FnMut(i32, i32, i32),
) {
    let mut crossings = crossings(edges, rows);
    crossings.sort_by(|a, b| a.0.cmp(&b.0).then(a.1.total_cmp(&b.1)));
    for pair in crossings.chunks_exact(2) {
        let ((y, c0), (y1, c1)) = (pair[0], pair[1]);
        debug_assert_eq!(y, y1, "every row has an even number of crossings");
        // Centres 4x+2 in (c0, c1].
        let x0 = ((c0 - 2.0) / 4.0).floor() as i32 + 1;
        let x1 = ((c1 - 2.0) / 4.0).floor() as i32;
        if x0 <= x1 {
            span(y, x0, x1);
        }
    }
}

/// (row, x) where the scan line through the centres of `row` crosses an edge; each edge owns
/// the rows with `y_lo <= 4·row+2 < y_hi`.
fn crossings(edges: impl Iterator<Item = (QPoint, QPoint)>, rows: Range<i32>) -> Vec<(i32, f64)> {
    let mut out = Vec::new();
    for (a, b) in edges {
        if a.y == b.y {
            continue;
        }
        let (lo, hi) = (i64::from(a.y.min(b.y)), i64::from(a.y.max(b.y)));
        let first = (lo - 2).div_euclid(4) + i64::from((lo - 2).rem_euclid(4) != 0);
        let last = (hi - 3).div_euclid(4);
        let (first, last) = (
            first.max(i64::from(rows.start)),
            last.min(i64::from(rows.end) - 1),
        );
        for row in first as i32..=last as i32 {
            let y = 4 * row + 2;
            let t = (f64::from(y) - f64::from(a.y)) / (f64::from(b.y) - f64::from(a.y));
            out.push((row, f64::from(a.x) + t * (f64::from(b.x) - f64::from(a.x))));
        }
    }
    out
}

/// Calls `cell(c)` for the cells of the half-open edge `a`→`b` (see the module docs) that lie
/// in the inclusive box `lo..=hi`. The line is the 8-connected one through the end cells: per
/// column (or row, for steep edges) the cell nearest the ideal line, ties rounding up. Only
/// columns (rows) inside the box are visited, so any coordinates — even a peer's absurd
/// ones — cost at most the box's size.
pub fn edge(a: QPoint, b: QPoint, lo: Cell, hi: Cell, mut cell: impl FnMut(Cell)) {
    let (from, to) = (a.cell(), b.cell());
    if from.x.max(to.x) < lo.x
        || from.x.min(to.x) > hi.x
        || from.y.max(to.y) < lo.y
        || from.y.min(to.y) > hi.y
    {
        // The edge's cells lie between its ends' cells: none is in the box.
        return;
    }
    let (d_major, d_minor, steep) = {
        let (dx, dy) = (i64::from(to.x - from.x), i64::from(to.y - from.y));
        if dx.abs() >= dy.abs() {
            (dx, dy, false)
        } else {
            (dy, dx, true)
        }
    };
    let (major0, minor0) = if steep {
        (from.y, from.x)
    } else {
        (from.x, from.y)
    };
    let (box_lo, box_hi) = if steep { (lo.y, hi.y) } else { (lo.x, hi.x) };
    let sign = if d_major < 0 { -1 } else { 1 };
    let len = d_major.abs().max(1); // a single cell when both ends share it
                                    // Steps k in [0, len) whose major coordinate major0 + sign·k lies in the box.
    let (k_a, k_b) = (
        (i64::from(box_lo) - i64::from(major0)) * sign,
        (i64::from(box_hi) - i64::from(major0)) * sign,
    );
    for k in k_a.min(k_b).max(0)..=k_a.max(k_b).min(len - 1) {
        let major = i64::from(major0) + sign * k;
        let minor = i64::from(minor0) + (2 * k * d_minor + len).div_euclid(2 * len);
        let (x, y) = if steep {
            (minor, major)
        } else {
            (major, minor)
        };
        if (i64::from(lo.x)..=i64::from(hi.x)).contains(&x)
            && (i64::from(lo.y)..=i64::from(hi.y)).contains(&y)
        {
            cell(Cell::new(x as i32, y as i32));
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn filled(poly: &[(i32, i32)], height: u32) -> Vec<(i32, i32, i32)> {
        let poly: Vec<QPoint> = poly.iter().map(|&(x, y)| QPoint::new(x, y)).collect();
        let mut v = Vec::new();
        fill(&poly, 0..height as i32, |y, x0, x1| v.push((y, x0, x1)));
        v
    }

    #[test]
    fn square_around_one_cell_fills_it() {
        assert_eq!(
            filled(&[(7, 6), (6, 7), (5, 6), (6, 5)], 3),
            vec![(1, 1, 1)]
        );
        assert_eq!(
            filled(&[(5, 5), (11, 5), (11, 11), (5, 11)], 4),
            vec![(1, 1, 2), (2, 1, 2)]
        );
    }

    #[test]
    fn rows_outside_the_grid_are_skipped() {
        assert_eq!(
            filled(&[(-7, -7), (7, -7), (7, 7), (-7, 7)], 1),
            vec![(0, -2, 1)]
        );
    }

    fn line(a: (i32, i32), b: (i32, i32), lo: (i32, i32), hi: (i32, i32)) -> Vec<(i32, i32)> {
        let mut v = Vec::new();
        let (lo, hi) = (Cell::new(lo.0, lo.1), Cell::new(hi.0, hi.1));
        edge(QPoint::new(a.0, a.1), QPoint::new(b.0, b.1), lo, hi, |c| {
            v.push((c.x, c.y))
        });
        v
    }

    #[test]
    fn edges_are_half_open_and_eight_connected() {
        let all = ((-9, -9), (99, 99));
        assert_eq!(
            line((2, 1), (5, -2), all.0, all.1),
            [(0, 0)],
            "skips the free corner cell"
        );
        assert_eq!(
            line((2, 2), (14, 6), all.0, all.1),
            [(0, 0), (1, 0), (2, 1)]
        );
        assert_eq!(line((2, 2), (3, 3), all.0, all.1), [(0, 0)]);
        assert_eq!(
            line((2, 2), (6, 42), all.0, all.1).len(),
            10,
            "steep: one cell per row"
        );
        assert_eq!(line((42, 2), (2, 6), all.0, all.1)[..2], [(10, 0), (9, 0)]);
    }

    #[test]
    fn edges_are_clipped_to_the_box_in_bounded_time() {
        assert_eq!(
            line((2, 2), (42, 2), (3, 0), (5, 0)),
            [(3, 0), (4, 0), (5, 0)]
        );
        let far = line((i32::MIN, i32::MIN), (i32::MAX, i32::MAX), (0, 0), (3, 3));
        assert_eq!(far, [(0, 0), (1, 1), (2, 2), (3, 3)]);
        let (lo, hi) = (
            QPoint::new(i32::MIN, i32::MIN),
            QPoint::new(i32::MAX, i32::MIN),
        );
        let mut rows = Vec::new();
        fill(&[lo, hi, QPoint::new(0, i32::MAX)], 0..2, |y, _, _| {
            rows.push(y)
        });
        assert_eq!(rows, [0, 1]);
    }
}
