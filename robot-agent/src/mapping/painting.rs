//! Approximations painted over a grid and kept from step to step (thesis §5.2, steps (1)–(5) of
//! Algorithm 9, [`crate::mapping::render`]): a [`Painting`](crate::mapping::painting::Painting)
//! holds what every approximation it was given paints, over the whole grid, and repaints only the
//! windows where an object changed — so a step costs what changed, not everything held. The
//! planning grid ([`crate::mapping::merge::Merger`], the peers' approximations, bands kept) and the
//! owner's approximation error ([`crate::mapping::approx_error::KeptError`], its own, bands
//! ignored) are kept this way.
//!
//! A cell's painting is a function of what each approximation marks there, taken together
//! ([`crate::mapping::render::Marks`]), and an approximation's marks depend only on its objects
//! whose reach holds the cell (their cells, their edges, the bands within their edges' error
//! bounds): an object that changed between two vertices it kept changes its owner's marks only
//! within reach of its changed edges, old and new (`changed_windows`). With one owner, a
//! window holding those is painted from the owner's marks there; with more, the painting
//! counts per cell how many owners give each mark, and a changed owner's marks in its windows,
//! before and after — its objects reaching the window, each with the edges that reach the
//! window's rows (`EdgeRows`) — move the counts: a peer's change costs its own objects near
//! it, not every teammate's that overlap there.

use std::collections::{BTreeMap, BTreeSet};

use proto::grid::{Cell, Occ, Rect};
use proto::msg::RobotId;

use crate::mapping::approx::{Approximation, ObjectId, Polygon, Vertex};
use crate::mapping::qpoint::QPoint;
use crate::mapping::render::{band_cells, marks, Bands, EdgeRows, Marks, Part};

/// What the approximations held paint, kept over a `width × height` grid.
///
/// A cell's painting is a function of the union of every approximation's marks there
/// ([`Marks::painted`]); with two owners or more held, the painting counts per cell how many
/// owners give each mark, so an owner's change is taken in by its own marks alone, before and
/// after, in the windows where it changed — whatever else is painted there.
#[derive(Clone, Debug)]
pub struct Painting {
    width: u32,
    height: u32,
    bands: Bands,
    /// Steps (1)–(5) of every approximation held, row-major over the whole grid.
    painted: Vec<Option<Occ>>,
    /// Per cell, row-major, how many owners held give it each mark (by [`Marks::index`]),
    /// modulo 2^16 (a count of 2^16 would need every `RobotId` an owner) — kept once two owners
    /// were held at once (`None` until then: the one owner's marks are the painting).
    counts: Option<Vec<[u16; 4]>>,
    /// Per owner, the objects painted, each with its reach and its edges by rows.
    held: BTreeMap<RobotId, BTreeMap<ObjectId, Held>>,
    /// Taken and not yet repainted: an owner, a window where its marks may have changed
    /// (inside the grid; one owner's windows apart), and its marks there before (`None`
    /// without counts).
    taken: Vec<Taken>,
}

#[derive(Clone, Debug)]
struct Taken {
    owner: RobotId,
    window: Rect,
    before: Option<Vec<Marks>>,
}

impl Painting {
    /// Nothing painted over a `width × height` grid; `bands` as [`crate::mapping::render::paint`]
    /// takes them.
    pub fn new(width: u32, height: u32, bands: Bands) -> Painting {
        Painting {
            width,
            height,
            bands,
            painted: vec![None; width as usize * height as usize],
            counts: None,
            held: BTreeMap::new(),
            taken: Vec::new(),
        }
    }

    /// The grid's size.
    pub fn size(&self) -> (u32, u32) {
        (self.width, self.height)
    }

    /// Takes the approximations of this step (owner, approximation; owners left out are
    /// dropped) and returns the windows (inside the grid, apart) outside which the painting
    /// stays as it is when [`Painting::repaint`] makes it theirs.
    pub fn take(&mut self, others: &[(RobotId, &Approximation)]) -> Vec<Rect> {
        self.repaint();
        let now: BTreeMap<RobotId, &Approximation> = others.iter().copied().collect();
        let owners: BTreeSet<RobotId> = self.held.keys().chain(now.keys()).copied().collect();
        if self.counts.is_none() && owners.len() > 1 {
            self.count_held();
        }
        for owner in owners {
            let a = now.get(&owner).copied();
            let (dirty, changed) = dirty_windows(self.held.get(&owner), a);
            for window in coalesce(dirty) {
                let Some(window) = window.within(self.width, self.height) else {
                    continue;
                };
                let before = self.counts.is_some().then(|| self.marks(owner, window));
                self.taken.push(Taken {
                    owner,
                    window,
                    before,
                });
            }
            self.hold(owner, a, &changed);
        }
        coalesce(self.taken.iter().map(|t| t.window).collect())
    }

    /// Paints what the approximations taken last changed: per owner and window, the cells
    /// whose marks changed move their counts (or, with one owner, take its marks).
    pub fn repaint(&mut self) {
        for t in std::mem::take(&mut self.taken) {
            let after = self.marks(t.owner, t.window);
            match (&mut self.counts, t.before) {
                (Some(counts), Some(before)) => {
                    let (painted, width) = (&mut self.painted, self.width);
                    recount_window(counts, painted, width, t.window, &before, &after);
                }
                _ => {
                    let (gw, ww) = (self.width as usize, t.window.width() as usize);
                    let rows = (t.window.min.y..=t.window.max.y).zip(after.chunks(ww));
                    for (y, after) in rows {
                        let at = y as usize * gw + t.window.min.x as usize;
                        for (cell, &m) in self.painted[at..at + ww].iter_mut().zip(after) {
                            *cell = m.painted();
                        }
                    }
                }
            }
        }
    }

    /// Steps (1)–(5) of every approximation held, row-major over the whole grid (`None`:
    /// undefined) — as of the last [`Painting::repaint`].
    pub fn painted(&self) -> &[Option<Occ>] {
        &self.painted
    }

    /// The cells some object held can paint (`None`: none).
    pub fn reach(&self) -> Option<Rect> {
        (self.held.values().flat_map(|objects| objects.values()))
            .fold(None, |r, h| Rect::union_of(r, Some(h.reach)))
    }

    /// Starts counting: every owner held marks its objects' reach (the painting, up to date,
    /// is what the counts give).
    fn count_held(&mut self) {
        let mut counts = vec![[0u16; 4]; self.painted.len()];
        let mut painted = std::mem::take(&mut self.painted);
        for (&owner, objects) in &self.held {
            let reaches = objects.values().map(|h| h.reach).collect();
            for w in coalesce(reaches) {
                let Some(w) = w.within(self.width, self.height) else {
                    continue;
                };
                let after = self.marks(owner, w);
                let before = vec![Marks::NONE; after.len()];
                recount_window(&mut counts, &mut painted, self.width, w, &before, &after);
            }
        }
        (self.painted, self.counts) = (painted, Some(counts));
    }

    /// What `owner`'s objects held mark in window `w` (inside the grid), each painted with its
    /// edges that reach the window's rows.
    fn marks(&self, owner: RobotId, w: Rect) -> Vec<Marks> {
        let objects = self.held.get(&owner).into_iter().flat_map(|o| o.values());
        let edges: Vec<(&Held, Option<Vec<u32>>)> = objects
            .filter(|h| h.reach.intersects(w))
            .map(|h| (h, h.rows.as_ref().map(|r| r.reaching(&h.poly, w))))
            .collect();
        let parts: Vec<Part<'_>> = (edges.iter())
            .map(|(h, e)| Part {
                poly: &h.poly,
                edges: e.as_deref(),
                bounds: Some(h.reach),
            })
            .collect();
        marks(&parts, w, self.bands)
    }

    /// Holds `a` as `owner`'s approximation from now on (`None`: drops the owner), its objects
    /// `changed` (new or not as held; [`dirty_windows`]) taken again.
    fn hold(&mut self, owner: RobotId, a: Option<&Approximation>, changed: &[ObjectId]) {
        let Some(a) = a else {
            self.held.remove(&owner);
            return;
        };
        let held = self.held.entry(owner).or_default();
        held.retain(|id, _| a.objects.contains_key(id));
        for (id, poly) in changed
            .iter()
            .filter_map(|id| Some((*id, a.objects.get(id)?)))
        {
            match reach(poly) {
                Some(reach) => {
                    let rows = (poly.vertices.len() > INDEXED_EDGES)
                        .then(|| EdgeRows::of(poly, self.bands, self.height));
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

/// The counts of window `w` (inside a grid `width` cells wide, row-major like `counts` and
/// `painted`) moved from an owner's marks `before` to `after` (the window's cells, row-major),
/// and the cells whose marks changed painted from their counts.
fn recount_window(
    counts: &mut [[u16; 4]],
    painted: &mut [Option<Occ>],
    width: u32,
    w: Rect,
    before: &[Marks],
    after: &[Marks],
) {
    let ww = w.width() as usize;
    let rows = (w.min.y..=w.max.y).zip(after.chunks(ww).zip(before.chunks(ww)));
    for (y, (after, before)) in rows {
        let at = y as usize * width as usize + w.min.x as usize;
        for (i, (&a, &b)) in after.iter().zip(before).enumerate() {
            if a != b {
                painted[at + i] = recount(&mut counts[at + i], b, a);
            }
        }
    }
}

/// A cell's counts moved from an owner's marks `before` to `after`; the cell's painting.
fn recount(counts: &mut [u16; 4], before: Marks, after: Marks) -> Option<Occ> {
    let mut any = Marks::NONE;
    for m in Marks::EACH {
        let c = &mut counts[m.index()];
        match (before.has(m), after.has(m)) {
            (false, true) => *c = c.wrapping_add(1),
            (true, false) => *c = c.wrapping_sub(1),
            _ => {}
        }
        if *c != 0 {
            any |= m;
        }
    }
    any.painted()
}

/// The windows where an owner's objects held (`None`: none) and its approximation `a`
/// (`None`: the owner is dropped) mark cells differently, and the objects of `a` that are new or
/// not as held.
fn dirty_windows(
    held: Option<&BTreeMap<ObjectId, Held>>,
    a: Option<&Approximation>,
) -> (Vec<Rect>, Vec<ObjectId>) {
    let objects = held.into_iter().flatten();
    let Some(a) = a else {
        return (objects.map(|(_, h)| h.reach).collect(), Vec::new());
    };
    let mut dirty: Vec<Rect> = objects
        .filter(|(id, _)| !a.objects.contains_key(id))
        .map(|(_, h)| h.reach)
        .collect();
    let mut changed = Vec::new();
    for (&id, poly) in &a.objects {
        match held.and_then(|h| h.get(&id)) {
            Some(was) if &was.poly == poly => {}
            was => {
                dirty.extend(changed_windows(was.map(|w| &w.poly), poly, STRIP_ROWS));
                changed.push(id);
            }
        }
    }
    (dirty, changed)
}

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

/// The cells an object can paint: its cells and edges, and the bands within its edges' error
/// bounds ([`crate::mapping::render`]); `None` without vertices.
pub fn reach(p: &Polygon) -> Option<Rect> {
    let band = p.vertices.iter().map(|v| v.bound).max()?;
    Some(p.cell_bounds()?.grown(band_cells(band)))
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
    use crate::mapping::render::{paint, paint_parts};
    use proptest::prelude::*;

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(128))]

        /// An object that changed marks differently only inside its changed windows, cut in
        /// strips of any height: the approximation with that one object changed marks every
        /// cell outside them as before (and so paints it as before, alone or with others).
        #[test]
        fn a_changed_object_marks_differently_only_inside_its_windows(
            steps in crate::testutil::arb_exploration(24, 5),
            s in prop_oneof![Just(0.0), Just(1.0), Just(4.0)],
            strip_rows in 1i32..5,
        ) {
            let (w, h) = (steps[0].width(), steps[0].height());
            let mut ax = crate::mapping::approximator::Approximator::new();
            let mut before: Option<Approximation> = None;
            let grid = Rect { min: Cell::new(0, 0), max: Cell::new(w as i32 - 1, h as i32 - 1) };
            let painted = |a: &Approximation| {
                let parts: Vec<Part<'_>> = a.objects.values().map(Part::whole).collect();
                marks(&parts, grid, Bands::Kept)
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

        /// A window painted with each object's edges that reach its rows (found by bands of
        /// rows), each object bounded by its reach, is the window painted with every edge.
        #[test]
        fn a_window_painted_with_the_edges_of_its_rows_is_painted_with_every_edge(
            steps in crate::testutil::arb_exploration(24, 3),
            s in prop_oneof![Just(0.0), Just(1.0), Just(4.0)],
            (x, y, ww, wh) in (0i32..24, 0i32..24, 0i32..24, 0i32..24),
        ) {
            let g = steps.last().expect("a step");
            let (w, h) = (g.width(), g.height());
            let mut ax = crate::mapping::approximator::Approximator::new();
            let a = ax.step(&Contours::extract(g), g, s).clone();
            let min = Cell::new(x % w as i32, y % h as i32);
            let win = Rect { min, max: Cell::new(min.x + ww, min.y + wh) }.within(w, h).expect("inside");
            let index: Vec<(&Polygon, EdgeRows)> = (a.objects.values())
                .map(|p| (p, EdgeRows::of(p, Bands::Kept, h)))
                .collect();
            let edges: Vec<Vec<u32>> = index.iter().map(|(p, e)| e.reaching(p, win)).collect();
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
