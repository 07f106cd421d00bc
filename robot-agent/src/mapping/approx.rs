//! Polygonal approximations A_t and their edge occupancy (thesis §3.4, §4.2.2; docs/design.md
//! §4.2).
//!
//! An [`Approximation`](crate::mapping::approx::Approximation) is what a robot shares: objects
//! keyed by a stable [`ObjectId`](crate::mapping::approx::ObjectId), each a polygon of P_t's points
//! in P_t's order. Each [`Vertex`](crate::mapping::approx::Vertex) carries f_occ of the edge that
//! starts at it. f_occ is precautious (§4.2.2): an edge is occupied only if every P_t point it
//! spans (from its start up to, not including, its end) lies on an occupied cell; otherwise it is
//! free for an inside object and unknown for an outside object, so that exploration never stops
//! early because of a coarse edge.
//!
//! How A_t follows from A_{t−1} and P_t is [`crate::mapping::approximator`]'s; how it is painted
//! back onto cells, [`crate::mapping::render`]'s. This module is the model both share, and imports
//! no other mapping module but [`crate::mapping::contour`].

use std::collections::BTreeMap;

use proto::grid::{Occ, Rect};

use crate::mapping::contour::{Contour, Contours, Kind};
use crate::mapping::qpoint::{seg_dist2, QPoint};

/// Identity of an object across steps (docs/design.md §4.2): it persists while the object does.
pub type ObjectId = u32;

/// A polygon vertex, and f_occ and the error bound of the edge from it to its successor
/// ([`Vertex::spanning`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct Vertex {
    pub p: QPoint,
    pub occ: Occ,
    /// How far (half cells, rounded up) the contour the edge stands for strays from it: a
    /// receiver paints nothing free that close to it ([`crate::mapping::render`]).
    pub bound: u16,
}

/// One approximated object.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Polygon {
    pub kind: Kind,
    pub vertices: Vec<Vertex>,
}

/// A polygonal approximation A_t: the objects by id.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct Approximation {
    pub objects: BTreeMap<ObjectId, Polygon>,
}

impl Approximation {
    /// A 64-bit FNV-1a digest of the objects (ids, kinds, vertices and f_occ, in id order):
    /// equal approximations have equal digests, so an owner and a receiver can compare theirs
    /// from afar (telemetry) without shipping the polygons.
    pub fn digest(&self) -> u64 {
        let mut h: u64 = 0xcbf2_9ce4_8422_2325;
        let mut eat = |bytes: &[u8]| {
            for &b in bytes {
                h ^= u64::from(b);
                h = h.wrapping_mul(0x0100_0000_01b3);
            }
        };
        for (id, poly) in &self.objects {
            eat(&id.to_le_bytes());
            eat(&[u8::from(poly.kind == Kind::Outside)]);
            eat(&(poly.vertices.len() as u64).to_le_bytes());
            for v in &poly.vertices {
                eat(&v.p.x.to_le_bytes());
                eat(&v.p.y.to_le_bytes());
                eat(&[v.occ as u8]);
                eat(&v.bound.to_le_bytes());
            }
        }
        h
    }

    /// Every edge without its error bound: the thesis's approximation, which a receiver paints
    /// as it is.
    pub fn drop_bounds(&mut self) {
        for v in self
            .objects
            .values_mut()
            .flat_map(|p| p.vertices.iter_mut())
        {
            v.bound = 0;
        }
    }

    /// The objects in id order as the sim plane's [`proto::msg::Outline`]s (for a viewer).
    pub fn outlines(&self) -> Vec<proto::msg::Outline> {
        self.objects
            .values()
            .map(|p| proto::msg::Outline {
                outside: p.kind == Kind::Outside,
                vertices: p.vertices.iter().map(|v| (v.p.x, v.p.y, v.occ)).collect(),
            })
            .collect()
    }

    /// The unsimplified approximation: every point of P_t is a vertex (ids are object indices).
    pub fn exact(p: &Contours) -> Approximation {
        let objects = p
            .objects()
            .iter()
            .enumerate()
            .map(|(id, c)| {
                let n = c.points.len();
                let vertices = (0..n)
                    .map(|i| Vertex::spanning(c, i, (i + 1) % n))
                    .collect();
                (
                    id as ObjectId,
                    Polygon {
                        kind: c.kind,
                        vertices,
                    },
                )
            })
            .collect();
        Approximation { objects }
    }

    /// Total number of vertices.
    pub fn vertex_count(&self) -> usize {
        self.objects.values().map(|o| o.vertices.len()).sum()
    }

    /// A rectangle of cells outside which rendering it paints nothing (`None`: no object).
    pub fn cell_bounds(&self) -> Option<Rect> {
        self.objects
            .values()
            .fold(None, |r, o| Rect::union_of(r, o.cell_bounds()))
    }

    /// The polygons of one kind.
    pub fn of_kind(&self, kind: Kind) -> impl Iterator<Item = &Polygon> {
        self.objects.values().filter(move |o| o.kind == kind)
    }
}

impl Polygon {
    /// A rectangle of cells holding every cell its edges cross and every cell whose centre it
    /// holds: its vertices' cells and one more on every side (`None`: no vertex).
    pub fn cell_bounds(&self) -> Option<Rect> {
        Rect::around(self.vertices.iter().map(|v| v.p.cell())).map(|r| r.grown(1))
    }

    pub fn points(&self) -> Vec<QPoint> {
        self.vertices.iter().map(|v| v.p).collect()
    }
}

impl Vertex {
    /// The vertex at P_t point `from` of object `c`, with f_occ and the error bound of its edge to
    /// point `to` (cyclic; `from == to` spans the whole object), both from one pass over the
    /// points the edge spans.
    ///
    /// f_occ: occupied iff every point in `[from, to)` is occupied; otherwise precautious — free
    /// for inside objects, unknown for outside objects. The bound: the largest distance of a
    /// spanned point from the edge — the Douglas–Peucker criterion — in half cells rounded up (at
    /// most `u16::MAX`), 0 for an exact edge; why it bounds what a receiver's merge can get
    /// wrong is docs/design.md §4.5.
    pub fn spanning(c: &Contour, from: usize, to: usize) -> Vertex {
        let n = c.points.len();
        let (a, b) = (c.points[from], c.points[to]);
        let span = if to > from { to - from } else { to + n - from };
        let (mut all_occupied, mut worst) = (true, 0.0f64);
        for k in (from..from + span).map(|k| k % n) {
            all_occupied &= c.occ[k] == Occ::Occupied;
            worst = worst.max(seg_dist2(c.points[k], a, b));
        }
        let occ = match (all_occupied, c.kind) {
            (true, _) => Occ::Occupied,
            (false, Kind::Inside) => Occ::Free,
            (false, Kind::Outside) => Occ::Unknown,
        };
        let bound = (worst.sqrt() / 2.0).ceil().min(f64::from(u16::MAX)) as u16;
        Vertex { p: a, occ, bound }
    }
}
