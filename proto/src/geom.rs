//! Metric geometry shared by every process: poses in metres and the map frame that converts
//! between metres and grid cells.
//!
//! Two vocabularies, never mixed silently: [`Metres`] for a point of the map frame in metres
//! (and [`Pose`], whose `x`/`y` are metres), [`crate::grid::Cell`] for integer grid indices.
//! Fractional cell units — a bare `(f64, f64)` where cell `(x, y)` covers `[x, x+1) × [y, y+1)`
//! — appear only inside the grid walks ([`crate::traverse`]: swept moves, laser rays, scan
//! integration, lines of sight, wall counts); [`MapInfo`] converts between metres and cells
//! ([`MapInfo::cell_of`], [`MapInfo::in_cells`], [`MapInfo::centre_of`]).

use serde::{Deserialize, Serialize};

use crate::grid::Cell;

/// A point of the map frame, in metres. Encodes exactly like the tuple `(x, y)` of two `f64`.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Metres {
    pub x: f64,
    pub y: f64,
}

impl Metres {
    pub const fn new(x: f64, y: f64) -> Metres {
        Metres { x, y }
    }

    /// The Euclidean distance to `o`, in metres: `(self.x - o.x).hypot(self.y - o.y)`, exactly
    /// (the expression the world's and netem's distances were written with, so they keep their
    /// bits).
    pub fn dist(self, o: Metres) -> f64 {
        (self.x - o.x).hypot(self.y - o.y)
    }
}

/// A robot pose in the map frame: metres and radians.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize, Default)]
pub struct Pose {
    pub x: f64,
    pub y: f64,
    pub theta: f64,
}

impl Pose {
    /// Where the robot stands, without its heading.
    pub fn xy(&self) -> Metres {
        Metres::new(self.x, self.y)
    }
}

/// The frame of a grid: its size in cells, the cell side in metres and the metric position of
/// cell (0, 0)'s lower-left corner (ROS `origin`).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct MapInfo {
    pub width: u32,
    pub height: u32,
    pub resolution_m: f64,
    pub origin_x_m: f64,
    pub origin_y_m: f64,
}

impl MapInfo {
    /// A frame of `width × height` cells of `resolution_m` metres whose cell (0, 0) has its
    /// lower-left corner at the world origin.
    pub fn at_origin(width: u32, height: u32, resolution_m: f64) -> MapInfo {
        MapInfo {
            width,
            height,
            resolution_m,
            origin_x_m: 0.0,
            origin_y_m: 0.0,
        }
    }

    /// The cell containing a metric point (may lie outside the grid).
    pub fn cell_of(&self, p: Metres) -> Cell {
        Cell::new(
            ((p.x - self.origin_x_m) / self.resolution_m).floor() as i32,
            ((p.y - self.origin_y_m) / self.resolution_m).floor() as i32,
        )
    }

    /// A metric point in cell units, returned as a bare `(f64, f64)` tuple of *cell units* (not
    /// metres): cell `(x, y)` covers `[x, x+1) × [y, y+1)`. The one conversion the world's
    /// motion check and the robots' planner share before walking the grid.
    pub fn in_cells(&self, p: Metres) -> (f64, f64) {
        (
            (p.x - self.origin_x_m) / self.resolution_m,
            (p.y - self.origin_y_m) / self.resolution_m,
        )
    }

    /// The metric centre of a cell.
    pub fn centre_of(&self, c: Cell) -> Metres {
        Metres::new(
            self.origin_x_m + (f64::from(c.x) + 0.5) * self.resolution_m,
            self.origin_y_m + (f64::from(c.y) + 0.5) * self.resolution_m,
        )
    }

    /// Map diagonal in metres.
    pub fn diagonal_m(&self) -> f64 {
        let w = f64::from(self.width) * self.resolution_m;
        let h = f64::from(self.height) * self.resolution_m;
        (w * w + h * h).sqrt()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn cell_and_centre_agree() {
        let m = MapInfo {
            width: 10,
            height: 10,
            resolution_m: 0.2,
            origin_x_m: -1.0,
            origin_y_m: 0.5,
        };
        let c = Cell::new(3, 7);
        assert_eq!(m.cell_of(m.centre_of(c)), c);
        assert_eq!(m.cell_of(Metres::new(-1.01, 0.5)), Cell::new(-1, 0));
    }
}

/// The laser model, shared so that the world-server (which casts the beams) and the robots (which
/// integrate them) agree on every beam's angle.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct LaserSpec {
    pub beams: u32,
    pub fov_rad: f64,
    pub max_range_m: f64,
    pub noise_std_m: f64,
}

impl LaserSpec {
    /// Angle of beam `i` relative to the robot's heading. A full circle (fov ≥ 2π) spreads
    /// `beams` beams without repeating the first at the end; a partial fov spans both edges.
    pub fn beam_angle(&self, i: u32) -> f64 {
        let full = self.fov_rad >= std::f64::consts::TAU - 1e-9;
        if full || self.beams < 2 {
            -self.fov_rad.min(std::f64::consts::TAU) / 2.0
                + f64::from(i) * self.fov_rad.min(std::f64::consts::TAU)
                    / f64::from(self.beams.max(1))
        } else {
            -self.fov_rad / 2.0 + f64::from(i) * self.fov_rad / f64::from(self.beams - 1)
        }
    }
}
