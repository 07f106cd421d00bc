//! Approximations painted over a grid and kept from step to step (thesis §5.2, steps (1)–(5)
//! of Algorithm 9, [`crate::mapping::render`]): a [`Painting`] holds what every approximation
//! it was given paints, over the whole grid, and repaints only the windows where an object
//! changed — so a step costs what changed, not everything held. The planning grid
//! ([`crate::mapping::merge::Merger`], the peers' approximations, bands kept) and the owner's
//! approximation error ([`crate::mapping::approx_error::KeptError`], its own, bands ignored)
//! are kept this way.
//!
//! A cell's painting depends only on the objects whose reach holds it (their cells, their
//! edges, the bands within their edges' error bounds): an object that changed between two
//! vertices it kept changes only cells within reach of its changed edges, old and new
//! ([`changed_windows`]); so a window holding those, painted afresh with every object that
//! reaches into it — each with the edges that reach the window's rows ([`EdgeRows`]) — is what
//! painting everything would give there.

use std::collections::BTreeMap;

use proto::grid::{Cell, Occ, Rect};
use proto::msg::RobotId;

use crate::mapping::approx::{Approximation, ObjectId, Polygon, Vertex};
use crate::mapping::qpoint::QPoint;
use crate::mapping::render::{paint_parts, Bands, Part};

/// What the approximations held paint, kept over a `width × height` grid.
#[derive(Clone, Debug)]
pub struct Painting {
    width: u32,
    height: u32,
    bands: Bands,
    /// Steps (1)–(5) of every approximation held, row-major over the whole grid.
    painted: Vec<Option<Occ>>,
    /// Per owner, the objects painted, each with its reach and its edges by rows.
    held: BTreeMap<RobotId, BTreeMap<ObjectId, Held>>,
}

impl Painting {
    /// Nothing painted over a `width × height` grid; `bands` as [`crate::mapping::render::paint`] takes them.
    pub fn new(width: u32, height: u32, bands: Bands) -> Painting {
        Painting {
            width,
            height,
            bands,
            painted: vec![None; width as usize * height as usize],
            held: BTreeMap::new(),
        }
    }

    /// The grid's size.
    pub fn size(&self) -> (u32, u32) {
        (self.width, self.height)
    }

    /// Takes the approximations of this step (owner, approximation; owners left out are
    /// dropped) and returns the windows to repaint ([`Painting::repaint`], each once, in any
    /// order) for the painting to be theirs.
    pub fn take(&mut self, others: &[(RobotId, &Approximation)]) -> Vec<Rect> {
        let mut dirty = Vec::new();
        self.take_into(others, &mut dirty);
        coalesce(dirty)
    }

    /// Steps (1)–(5) of every approximation held, row-major over the whole grid (`None`:
    /// undefined) — as of the windows repainted so far.
    pub fn painted(&self) -> &[Option<Occ>] {
        &self.painted
    }

    /// The cells some object held can paint (`None`: none).
    pub fn reach(&self) -> Option<Rect> {
        (self.held.values().flat_map(|objects| objects.values()))
            .fold(None, |r, h| Rect::union_of(r, Some(h.reach)))
    }

    /// Takes the approximations of this step: the windows where they differ from those held
    /// go to `dirty`, and they are held from now on.
    fn take_into(&mut self, others: &[(RobotId, &Approximation)], dirty: &mut Vec<Rect>) {
        let now: BTreeMap<RobotId, &Approximation> = others.iter().copied().collect();
        // Owners no longer held: everything they painted.
        self.held.retain(|owner, objects| {
            let kept = now.contains_key(owner);
            if !kept {
                dirty.extend(objects.values().map(|h| h.reach));
            }
            kept
        });
        for (&owner, a) in &now {
            let held = self.held.entry(owner).or_default();
            held.retain(|id, h| {
                let kept = a.objects.contains_key(id);
                if !kept {
                    dirty.push(h.reach);
                }
                kept
            });
            for (&id, poly) in &a.objects {
                match held.get(&id) {
                    Some(was) if &was.poly == poly => {}
                    was => {
                        dirty.extend(changed_windows(was.map(|w| &w.poly), poly, STRIP_ROWS));
                        match reach(poly) {
                            Some(reach) => {
                                let rows = (poly.vertices.len() > INDEXED_EDGES)
                                    .then(|| EdgeRows::new(poly, self.height, BUCKET_ROWS));
                                let poly = poly.clone();
                                held.insert(id, Held { poly, reach, rows });
                            }
                            None => {
                                held.remove(&id);
                            }
                        }
                    }
                }
            }
        }
    }

    /// Paints window `w` afresh with every object that reaches into it, each with its edges
    /// that reach the window's rows.
    pub fn repaint(&mut self, w: Rect) {
        let Some(w) = w.within(self.width, self.height) else {
            return;
        };
        let edges: Vec<Reaching<'_>> = (self.held.values())
            .map(|objects| {
                (objects.values())
                    .filter(|h| h.reach.intersects(w))
                    .map(|h| (h, h.rows.as_ref().map(|r| r.edges(w.min.y, w.max.y))))
                    .collect()
            })
            .collect();
        let parts: Vec<Vec<Part<'_>>> = (edges.iter())
            .map(|objects| {
                (objects.iter())
                    .map(|(h, e)| Part {
                        poly: &h.poly,
                        edges: e.as_deref(),
                        bounds: Some(h.reach),
                    })
                    .collect()
            })
            .collect();
        let fresh = paint_parts(&parts, w.min, w.width(), w.height(), self.bands);
        let (gw, ww) = (self.width as usize, w.width() as usize);
        for (y, row) in (w.min.y..=w.max.y).zip(fresh.chunks(ww)) {
            let at = y as usize * gw + w.min.x as usize;
            self.painted[at..at + ww].copy_from_slice(row);
        }
    }
}

/// An owner's objects that reach a window, each with its edges that reach the window's rows
/// (`None`: all).
type Reaching<'a> = Vec<(&'a Held, Option<Vec<u32>>)>;

/// An object painted: the polygon, the cells it can paint ([`reach`]) and its edges by the rows
/// they reach.
#[derive(Clone, Debug)]
struct Held {
    poly: Polygon,
    reach: Rect,
    rows: Option<EdgeRows>,
}

/// Objects of more edges than this are indexed by rows ([`EdgeRows`]); a smaller one is painted
/// with all its edges (an index would cost more than it saves).
const INDEXED_EDGES: usize = 128;

/// Rows of the grid per bucket of [`EdgeRows`].
const BUCKET_ROWS: i32 = 32;

/// An object's edges by the rows of the grid they reach — the rows their scan-line crossings,
/// their cells and their bands lie in — in buckets of [`BUCKET_ROWS`] rows: a window is painted
/// with the edges of the buckets of its rows, not with every edge of every object reaching it.
#[derive(Clone, Debug)]
struct EdgeRows {
    /// Rows per bucket.
    rows: i32,
    /// The first bucket held, and from it each bucket's edges (by first vertex, ascending).
    first: usize,
    buckets: Vec<Vec<u32>>,
}

impl EdgeRows {
    /// The edges of `p` over the rows `0..height`, in buckets of `rows` rows.
    fn new(p: &Polygon, height: u32, rows: i32) -> EdgeRows {
        let rows = rows.max(1);
        let n = p.vertices.len();
        let last_row = i32::try_from(height).unwrap_or(i32::MAX) - 1;
        let mut by_bucket: Vec<(usize, u32)> = Vec::new();
        for (i, v) in p.vertices.iter().enumerate() {
            let (a, b) = (v.p.cell().y, p.vertices[(i + 1) % n].p.cell().y);
            let grow = 1 + band_cells(v.bound);
            let lo = a.min(b).saturating_sub(grow).max(0);
            let hi = a.max(b).saturating_add(grow).min(last_row);
            let buckets = (lo / rows)..=(hi / rows);
            by_bucket.extend(
                (lo <= hi)
                    .then_some(buckets)
                    .into_iter()
                    .flatten()
                    .map(|k| (k as usize, i as u32)),
            );
        }
        let first = by_bucket.iter().map(|&(k, _)| k).min().unwrap_or(0);
        let count = by_bucket
            .iter()
            .map(|&(k, _)| k + 1 - first)
            .max()
            .unwrap_or(0);
        let mut buckets = vec![Vec::new(); count];
        for (k, i) in by_bucket {
            buckets[k - first].push(i);
        }
        EdgeRows {
            rows,
            first,
            buckets,
        }
    }

    /// The edges reaching the rows `y0..=y1` (and maybe a few more), each once, ascending.
    fn edges(&self, y0: i32, y1: i32) -> Vec<u32> {
        let bucket = |y: i32| (y.max(0) / self.rows) as usize;
        let (from, to) = (bucket(y0).max(self.first), bucket(y1));
        let mut out: Vec<u32> = (from..=to)
            .filter_map(|k| self.buckets.get(k.checked_sub(self.first)?))
            .flatten()
            .copied()
            .collect();
        if to > from {
            out.sort_unstable();
            out.dedup();
        }
        out
    }
}

/// The cells an object can paint: its cells and edges, and the bands within its edges' error
/// bounds ([`crate::mapping::render`]); `None` without vertices.
pub fn reach(p: &Polygon) -> Option<Rect> {
    let band = p.vertices.iter().map(|v| v.bound).max()?;
    Some(p.cell_bounds()?.grown(band_cells(band)))
}

/// Cells within an error bound (half cells) of an edge, beyond the edge's own cells.
fn band_cells(bound: u16) -> i32 {
    i32::from(bound) / 2 + 1
}

/// The windows where an object that was `was` (`None`: new) and is `now` paints differently.
///
/// The two vertex lists are aligned by the vertices they share, in order; between two shared
/// vertices the old chain of edges was replaced by the new one, and the cells whose painting
/// changed lie around those two chains (what they enclose, their edges, their bands) — the
/// windows of [`chain_windows`] per replaced run, the run across the lists' ends included. Its
/// whole reach, old and new, when nothing is shared.
fn changed_windows(was: Option<&Polygon>, now: &Polygon, strip_rows: i32) -> Vec<Rect> {
    let whole = |was: Option<&Polygon>| Rect::union_of(was.and_then(reach), reach(now));
    let Some(was) = was.filter(|w| w.kind == now.kind) else {
        return whole(was).into_iter().collect();
    };
    let (a, b) = (&was.vertices, &now.vertices);
    let matched = align(a, b);
    let (Some(&first), Some(&last)) = (matched.first(), matched.last()) else {
        return whole(Some(was)).into_iter().collect();
    };
    let mut out = Vec::new();
    // Between consecutive shared vertices (index pairs), and across the lists' ends.
    let wrap = (last, (first.0 + a.len(), first.1 + b.len()));
    for (p, q) in matched.windows(2).map(|w| (w[0], w[1])).chain([wrap]) {
        if q.0 == p.0 + 1 && q.1 == p.1 + 1 {
            continue; // the same edge
        }
        let old: Vec<Vertex> = (p.0..=q.0).map(|i| a[i % a.len()]).collect();
        let new: Vec<Vertex> = (p.1..=q.1).map(|j| b[j % b.len()]).collect();
        out.extend(chain_windows(&old, &new, strip_rows));
    }
    out
}

/// Rows (and columns) per strip or tile of [`chain_windows`] in the planning grid.
const STRIP_ROWS: i32 = 16;

/// Chains up to this many vertices are cut in tiles ([`chain_tiles`]), longer ones in strips.
const TILED_CHAIN: usize = 32;

/// Windows holding every cell that painting the run `new` instead of `old` (two chains between
/// the same two vertices) can change: what the closed chain — `old`, then `new` back — encloses,
/// the cells of edges that changed, and where an edge's band changed. The rectangle around
/// the chains, or — when that is cheaper — tiles of it ([`chain_tiles`], short chains) or
/// strips of `strip_rows` rows ([`chain_strips`]).
fn chain_windows(old: &[Vertex], new: &[Vertex], strip_rows: i32) -> Vec<Rect> {
    let both = || old.iter().chain(new);
    let band = both().map(|v| v.bound).max().unwrap_or(0);
    let grow = 1 + band_cells(band);
    let Some(around) = Rect::around(both().map(|v| v.p.cell())).map(|r| r.grown(grow)) else {
        return Vec::new();
    };
    if i64::from(around.height()) <= 2 * i64::from(strip_rows) {
        return vec![around];
    }
    let closed: Vec<QPoint> = old.iter().chain(new.iter().rev()).map(|v| v.p).collect();
    let cut = if old.len() + new.len() <= TILED_CHAIN {
        chain_tiles(old, new, &closed, around, strip_rows)
    } else {
        chain_strips(&closed, around, grow, strip_rows)
    };
    let cells: usize = cut.iter().map(|r| r.area()).sum();
    if cells < around.area() {
        cut
    } else {
        vec![around]
    }
}

/// The rows of `around` in strips of `rows`: (first row, last row).
fn row_strips(around: Rect, rows: i32) -> impl Iterator<Item = (i32, i32)> {
    let step = rows.max(1) as usize;
    (around.min.y..=around.max.y)
        .step_by(step)
        .map(move |y| (y, y.saturating_add(rows - 1).min(around.max.y)))
}

/// The leftmost and rightmost points (quarter cells) of the edges of the closed chain between
/// heights `lo` and `hi`: within those heights, what the chain encloses lies between them (a
/// scan line inside it meets an edge on either side).
fn closed_span(closed: &[QPoint], lo: f64, hi: f64) -> Option<(f64, f64)> {
    (0..closed.len())
        .filter_map(|i| x_span(closed[i], closed[(i + 1) % closed.len()], lo, hi))
        .reduce(|(l0, h0), (l1, h1)| (l0.min(l1), h0.max(h1)))
}

/// [`chain_windows`] in strips: per strip, the columns the chain's edges reach within the
/// strip's rows and `grow` cells beyond (bands, and an edge's cells, which may stray a cell
/// from the line) — a long thin change costs its length, not its rectangle's area.
fn chain_strips(closed: &[QPoint], around: Rect, grow: i32, strip_rows: i32) -> Vec<Rect> {
    let g = f64::from(grow);
    row_strips(around, strip_rows)
        .filter_map(|(y, top)| {
            let lo = 4.0 * (f64::from(y) - g);
            let hi = 4.0 * (f64::from(top) + 1.0 + g);
            let (l, h) = closed_span(closed, lo, hi)?;
            let x0 = (l / 4.0).floor() as i32 - grow - 1;
            let x1 = (h / 4.0).floor() as i32 + grow + 1;
            Some(Rect {
                min: Cell::new(x0.max(around.min.x), y),
                max: Cell::new(x1.min(around.max.x), top),
            })
        })
        .collect()
}

/// [`chain_windows`] in square tiles of `size` cells, each row's run of tiles kept as one
/// window. A tile is kept when it may hold a cell the change paints differently: within the
/// columns of what the closed chain encloses in its rows; near an edge of one chain that the
/// other lacks (its cells); or where the band of the chains may differ — unless every cell
/// centre of the tile lies beyond every band of both chains, or within a band of each. A vertex
/// whose error bound grew (the same edges, wider bands) costs the ring between the bands.
fn chain_tiles(
    old: &[Vertex],
    new: &[Vertex],
    closed: &[QPoint],
    around: Rect,
    size: i32,
) -> Vec<Rect> {
    let edges = |c: &[Vertex]| -> Vec<(QPoint, QPoint, Occ, f64)> {
        c.windows(2)
            .map(|w| (w[0].p, w[1].p, w[0].occ, 2.0 * f64::from(w[0].bound)))
            .collect()
    };
    let (eo, en) = (edges(old), edges(new));
    let lacks = |e: &(QPoint, QPoint, Occ, f64), other: &[(QPoint, QPoint, Occ, f64)]| {
        !other.iter().any(|o| (o.0, o.1, o.2) == (e.0, e.1, e.2))
    };
    let changed: Vec<_> = (eo.iter().filter(|e| lacks(e, &en)))
        .chain(en.iter().filter(|e| lacks(e, &eo)))
        .collect();
    let mut out = Vec::new();
    for (y, top) in row_strips(around, size) {
        let inside = closed_span(closed, 4.0 * f64::from(y), 4.0 * (f64::from(top) + 1.0));
        let mut run: Option<Rect> = None;
        for x in (around.min.x..=around.max.x).step_by(size.max(1) as usize) {
            let tile = Rect {
                min: Cell::new(x, y),
                max: Cell::new(x.saturating_add(size - 1).min(around.max.x), top),
            };
            let encloses = inside.is_some_and(|(l, h)| {
                f64::from(4 * tile.min.x) <= h + 4.0 && l - 4.0 <= f64::from(4 * tile.max.x + 4)
            });
            let keep = encloses
                || changed.iter().any(|e| tile_near(tile, e.0, e.1, 8.0))
                || band_may_differ(tile, &eo, &en);
            match (keep, &mut run) {
                (true, Some(r)) => r.max.x = tile.max.x,
                (true, None) => run = Some(tile),
                (false, _) => out.extend(run.take()),
            }
        }
        out.extend(run);
    }
    out
}

/// The centres of a tile's corner cells (quarter cells): the tile's centres lie in their hull.
fn corners(t: Rect) -> [QPoint; 4] {
    [
        QPoint::centre(t.min),
        QPoint::centre(Cell::new(t.max.x, t.min.y)),
        QPoint::centre(t.max),
        QPoint::centre(Cell::new(t.min.x, t.max.y)),
    ]
}

/// The distance (quarter cells) from `p` to segment `a`–`b`, in floating point (a peer's
/// coordinates may be anything).
fn seg_dist(p: QPoint, a: QPoint, b: QPoint) -> f64 {
    let f = |q: QPoint| (f64::from(q.x), f64::from(q.y));
    let ((px, py), (ax, ay), (bx, by)) = (f(p), f(a), f(b));
    let (dx, dy) = (bx - ax, by - ay);
    let len2 = dx * dx + dy * dy;
    let t = if len2 == 0.0 {
        0.0
    } else {
        (((px - ax) * dx + (py - ay) * dy) / len2).clamp(0.0, 1.0)
    };
    ((px - ax - t * dx).powi(2) + (py - ay - t * dy).powi(2)).sqrt()
}

/// Whether some cell centre of `tile` may lie within `reach` quarter cells of segment `a`–`b`:
/// the distance from the tile's middle less its half diagonal.
fn tile_near(tile: Rect, a: QPoint, b: QPoint, reach: f64) -> bool {
    let [lo, _, hi, _] = corners(tile);
    let mid = QPoint::new(lo.x / 2 + hi.x / 2, lo.y / 2 + hi.y / 2);
    let half = f64::from(hi.x - lo.x).hypot(f64::from(hi.y - lo.y)) / 2.0 + 2.0;
    seg_dist(mid, a, b) - half <= reach
}

/// Whether the bands of the edges `old` and `new` (start, end, occupancy, error bound in
/// quarter cells) may cover a cell centre of `tile` differently: not when the tile is beyond
/// every band, nor when all its centres lie within one band of each.
fn band_may_differ(
    tile: Rect,
    old: &[(QPoint, QPoint, Occ, f64)],
    new: &[(QPoint, QPoint, Occ, f64)],
) -> bool {
    let banded = |e: &&(QPoint, QPoint, Occ, f64)| e.3 > 0.0;
    let beyond = !(old.iter().chain(new).filter(banded)).any(|e| tile_near(tile, e.0, e.1, e.3));
    let within = |es: &[(QPoint, QPoint, Occ, f64)]| {
        es.iter()
            .filter(banded)
            .any(|e| corners(tile).iter().all(|&c| seg_dist(c, e.0, e.1) <= e.3))
    };
    !(beyond || within(old) && within(new))
}

/// The x extent (quarter cells) of segment `a`–`b` between the heights `lo` and `hi`.
fn x_span(a: QPoint, b: QPoint, lo: f64, hi: f64) -> Option<(f64, f64)> {
    let (ax, ay, bx, by) = (
        f64::from(a.x),
        f64::from(a.y),
        f64::from(b.x),
        f64::from(b.y),
    );
    if ay.max(by) < lo || ay.min(by) > hi {
        return None;
    }
    if ay == by {
        return Some((ax.min(bx), ax.max(bx)));
    }
    let at = |y: f64| ax + (bx - ax) * ((y.clamp(ay.min(by), ay.max(by)) - ay) / (by - ay));
    let (x0, x1) = (at(lo), at(hi));
    Some((x0.min(x1), x0.max(x1)))
}

/// How far [`align`] looks ahead for the next vertex both lists share.
const ALIGN_AHEAD: usize = 48;

/// Pairs of indices (into `a`, into `b`) of equal vertices, increasing in both: a greedy
/// alignment that skips the fewest vertices (up to [`ALIGN_AHEAD`]) to the next shared one.
fn align(a: &[Vertex], b: &[Vertex]) -> Vec<(usize, usize)> {
    let (mut i, mut j) = (0, 0);
    let mut out = Vec::new();
    'walk: while i < a.len() && j < b.len() {
        for d in 0..=ALIGN_AHEAD {
            for di in 0..=d {
                let (x, y) = (i + di, j + d - di);
                if x < a.len() && y < b.len() && a[x] == b[y] {
                    out.push((x, y));
                    (i, j) = (x + 1, y + 1);
                    continue 'walk;
                }
            }
        }
        break;
    }
    out
}

/// Windows merged where they overlap: each cell painted once per step. The strips or tiles of
/// one change ([`chain_windows`]) do not overlap and stay apart, unless another window joins
/// them.
fn coalesce(mut ws: Vec<Rect>) -> Vec<Rect> {
    let mut out: Vec<Rect> = Vec::with_capacity(ws.len());
    while let Some(mut w) = ws.pop() {
        // Grow w by every window it meets, while that is cheaper, until none is left.
        loop {
            let before = out.len() + ws.len();
            for list in [&mut out, &mut ws] {
                list.retain(|o| {
                    let merge = o.intersects(w);
                    if merge {
                        w = w.union(*o);
                    }
                    !merge
                });
            }
            if out.len() + ws.len() == before {
                break;
            }
        }
        out.push(w);
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mapping::contour::Contours;
    use crate::mapping::render::paint;
    use proptest::prelude::*;

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(128))]

        /// An object that changed paints differently only inside its changed windows, cut in
        /// strips of any height: the approximation with that one object changed paints every
        /// cell outside them as before.
        #[test]
        fn a_changed_object_paints_differently_only_inside_its_windows(
            steps in crate::testutil::arb_exploration(24, 5),
            s in prop_oneof![Just(0.0), Just(1.0), Just(4.0)],
            strip_rows in 1i32..5,
        ) {
            let (w, h) = (steps[0].width(), steps[0].height());
            let mut ax = crate::mapping::approximator::Approximator::new();
            let mut before: Option<Approximation> = None;
            let painted = |a: &Approximation| {
                paint(&[a.objects.values().collect()], Cell::new(0, 0), w, h, Bands::Kept)
            };
            for g in &steps {
                let now = ax.step(&Contours::extract(g), g, s).clone();
                if let Some(was) = &before {
                    for (id, poly) in &now.objects {
                        let Some(old) = was.objects.get(id).filter(|&o| o != poly) else { continue };
                        let windows = changed_windows(Some(old), poly, strip_rows);
                        let mut one = was.clone();
                        one.objects.insert(*id, poly.clone());
                        let (pa, pb) = (painted(was), painted(&one));
                        for (k, (x, y)) in pa.iter().zip(&pb).enumerate() {
                            let c = Cell::new((k % w as usize) as i32, (k / w as usize) as i32);
                            prop_assert!(x == y || windows.iter().any(|r| r.contains(c)),
                                "{:?} {:?} -> {:?} outside {:?}", c, x, y, windows);
                        }
                    }
                }
                before = Some(now);
            }
        }
    }

    proptest! {
        // Cheap cases; an index that leaves out an edge's band shows in few of them.
        #![proptest_config(ProptestConfig::with_cases(2048))]

        /// A window painted with each object's edges that reach its rows (by buckets of any
        /// height), each object bounded by its reach, is the window painted with every edge.
        #[test]
        fn a_window_painted_with_the_edges_of_its_rows_is_painted_with_every_edge(
            steps in crate::testutil::arb_exploration(24, 3),
            s in prop_oneof![Just(0.0), Just(1.0), Just(4.0)],
            rows in 1i32..6,
            (x, y, ww, wh) in (0i32..24, 0i32..24, 0i32..24, 0i32..24),
        ) {
            let g = steps.last().expect("a step");
            let (w, h) = (g.width(), g.height());
            let mut ax = crate::mapping::approximator::Approximator::new();
            let a = ax.step(&Contours::extract(g), g, s).clone();
            let min = Cell::new(x % w as i32, y % h as i32);
            let win = Rect { min, max: Cell::new(min.x + ww, min.y + wh) }.within(w, h).expect("inside");
            let index: Vec<(&Polygon, EdgeRows)> = (a.objects.values())
                .map(|p| (p, EdgeRows::new(p, h, rows)))
                .collect();
            let edges: Vec<Vec<u32>> = index.iter().map(|(_, e)| e.edges(win.min.y, win.max.y)).collect();
            let parts: Vec<Part<'_>> = (index.iter().zip(&edges))
                .map(|((p, _), e)| Part { poly: p, edges: Some(e), bounds: reach(p) })
                .collect();
            let whole: Vec<&Polygon> = a.objects.values().collect();
            let (ww, wh) = (win.width(), win.height());
            prop_assert_eq!(
                paint_parts(&[parts], win.min, ww, wh, Bands::Kept),
                paint(&[whole], win.min, ww, wh, Bands::Kept)
            );
        }
    }
}
