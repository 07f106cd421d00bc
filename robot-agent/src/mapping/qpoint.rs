//! Quarter-cell integer coordinates: the vocabulary of contour vertices (thesis §4.1).
//!
//! Auxiliary points sit 0.25 cell from a pixel centre, so every contour vertex has coordinates that
//! are multiples of a quarter cell. A [`QPoint`](crate::mapping::qpoint::QPoint) stores them as
//! integers in quarter cells in the frame of [`proto::grid::Grid`]: cell `(x, y)` covers `[4x,
//! 4x+4) × [4y, 4y+4)`, its centre is `(4x+2, 4y+2)`. Cells are [`Cell`](proto::grid::Cell)s,
//! metres are `f64`: never mixed silently.

use proto::grid::Cell;

/// A point in quarter cells (see the module docs for the frame).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord, Default)]
pub struct QPoint {
    pub x: i32,
    pub y: i32,
}

impl QPoint {
    pub const fn new(x: i32, y: i32) -> QPoint {
        QPoint { x, y }
    }

    /// The centre of a cell.
    pub const fn centre(c: Cell) -> QPoint {
        QPoint {
            x: 4 * c.x + 2,
            y: 4 * c.y + 2,
        }
    }

    /// The cell this point lies in (points on a cell border belong to the upper/right cell).
    pub const fn cell(self) -> Cell {
        Cell {
            x: self.x.div_euclid(4),
            y: self.y.div_euclid(4),
        }
    }

    /// Squared Euclidean distance in quarter cells².
    pub fn dist2(self, o: QPoint) -> i64 {
        let dx = i64::from(self.x) - i64::from(o.x);
        let dy = i64::from(self.y) - i64::from(o.y);
        dx * dx + dy * dy
    }
}

/// Squared distance (quarter cells²) from `p` to the segment `a`–`b` (the thesis's segment
/// distance d(p, e) of §4.3.2).
pub fn seg_dist2(p: QPoint, a: QPoint, b: QPoint) -> f64 {
    let (px, py) = (f64::from(p.x - a.x), f64::from(p.y - a.y));
    let (bx, by) = (f64::from(b.x - a.x), f64::from(b.y - a.y));
    let len2 = bx * bx + by * by;
    if len2 == 0.0 {
        return px * px + py * py;
    }
    let t = ((px * bx + py * by) / len2).clamp(0.0, 1.0);
    let (dx, dy) = (px - t * bx, py - t * by);
    dx * dx + dy * dy
}

/// Twice the signed area of a closed polygon (positive = counter-clockwise, y up).
pub fn area2(points: &[QPoint]) -> i64 {
    let n = points.len();
    (0..n)
        .map(|i| {
            let (a, b) = (points[i], points[(i + 1) % n]);
            i64::from(a.x) * i64::from(b.y) - i64::from(b.x) * i64::from(a.y)
        })
        .sum()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn cell_and_centre_agree() {
        for c in [Cell::new(0, 0), Cell::new(-1, 3), Cell::new(7, -2)] {
            assert_eq!(QPoint::centre(c).cell(), c);
            assert_eq!(QPoint::new(4 * c.x + 3, 4 * c.y + 1).cell(), c);
        }
    }

    #[test]
    fn segment_distance_clamps_to_endpoints() {
        let (a, b) = (QPoint::new(0, 0), QPoint::new(8, 0));
        assert_eq!(seg_dist2(QPoint::new(4, 3), a, b), 9.0);
        assert_eq!(seg_dist2(QPoint::new(-3, 4), a, b), 25.0);
        assert_eq!(seg_dist2(QPoint::new(1, 1), a, a), 2.0);
    }

    #[test]
    fn square_counter_clockwise_has_positive_area() {
        let sq = [
            QPoint::new(0, 0),
            QPoint::new(4, 0),
            QPoint::new(4, 4),
            QPoint::new(0, 4),
        ];
        assert_eq!(area2(&sq), 32);
    }
}
