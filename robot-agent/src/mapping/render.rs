//! Rendering polygonal approximations onto cells (thesis §5.2).
//!
//! An approximation A_t stands for a grid: the one Algorithm 9 ([`crate::mapping::merge`], where
//! its principles and steps are written down) paints from it. This module paints:
//! [`paint`](crate::mapping::render::paint) does steps (1)–(5) for any set of approximations over
//! any window of the grid frame, [`render`] is one approximation on its own (Algorithm 9 with an
//! empty G_s), [`render_window`](crate::mapping::render::render_window) a window of that, used to
//! score one split locally ([`crate::mapping::refine`]).
//! [`exploration_view`](crate::mapping::render::exploration_view) is the other side of the
//! comparison: G_s as any polygonal model can represent it.
//!
//! Place among the mapping modules (each imports only those before it): [`crate::mapping::contour`]
//! → [`crate::mapping::approx`] → `render` → [`crate::mapping::refine`] →
//! [`crate::mapping::approximator`] → [`crate::mapping::painting`] → [`crate::mapping::merge`],
//! [`crate::mapping::approx_error`].

use proto::grid::{Cell, Grid, Occ, Rect};

use crate::mapping::approx::{Approximation, Polygon, Vertex};
use crate::mapping::contour::Kind;
use crate::mapping::qpoint::{seg_dist2, QPoint};
use crate::mapping::raster;

/// A window `[x0, x0+width) × [y0, y0+height)` of the grid frame, its cells indexed row-major.
struct Canvas {
    x0: i32,
    y0: i32,
    width: u32,
    height: u32,
}

impl Canvas {
    fn new(origin: Cell, width: u32, height: u32) -> Canvas {
        Canvas {
            x0: origin.x,
            y0: origin.y,
            width,
            height,
        }
    }

    fn frame(r: Rect) -> Canvas {
        Canvas::new(r.min, r.width(), r.height())
    }

    fn len(&self) -> usize {
        self.width as usize * self.height as usize
    }

    /// The part of `r` (grid frame) inside the window.
    fn clip(&self, r: Rect) -> Option<Rect> {
        let min = Cell::new(r.min.x.max(self.x0), r.min.y.max(self.y0));
        let max = Cell::new(
            r.max.x.min(self.x0 + self.width as i32 - 1),
            r.max.y.min(self.y0 + self.height as i32 - 1),
        );
        (min.x <= max.x && min.y <= max.y).then_some(Rect { min, max })
    }

    fn index(&self, c: Cell) -> Option<usize> {
        let (x, y) = (c.x - self.x0, c.y - self.y0);
        let inside = x >= 0 && y >= 0 && (x as u32) < self.width && (y as u32) < self.height;
        inside.then(|| y as usize * self.width as usize + x as usize)
    }

    /// Every cell of the window whose centre lies inside `part`'s polygon, by index.
    fn fill(&self, part: &Part<'_>, mut f: impl FnMut(usize)) {
        let (x_end, w) = (self.x0 + self.width as i32 - 1, self.width as usize);
        let rows = self.y0..self.y0 + self.height as i32;
        let edges = part.edge_indices().map(|i| {
            let (v, next) = part.edge(i);
            (v.p, next)
        });
        raster::fill_edges(edges, rows, |y, xa, xb| {
            let row = (y - self.y0) as usize * w;
            for x in xa.max(self.x0)..=xb.min(x_end) {
                f(row + (x - self.x0) as usize);
            }
        });
    }

    /// Every cell of the window on an edge of `part`, by index, with the edge's occupancy.
    fn edges(&self, part: &Part<'_>, mut f: impl FnMut(usize, Occ)) {
        let lo = Cell::new(self.x0, self.y0);
        let hi = Cell::new(
            self.x0 + self.width as i32 - 1,
            self.y0 + self.height as i32 - 1,
        );
        for i in part.edge_indices() {
            let (v, next) = part.edge(i);
            raster::edge(v.p, next, lo, hi, |c| {
                if let Some(k) = self.index(c) {
                    f(k, v.occ);
                }
            });
        }
    }

    /// Every cell of the window whose centre lies within an edge's error bound of the edge of
    /// `part` ([`crate::mapping::approx::Vertex::spanning`]), on either side: where the contour the
    /// edge stands for may run.
    fn bands(&self, part: &Part<'_>, mut f: impl FnMut(usize)) {
        for i in part.edge_indices() {
            let (v, b) = part.edge(i);
            if v.bound == 0 {
                continue;
            }
            let a = v.p;
            // Half cells to quarter cells; cells of the box around the edge, within the window.
            let e = i64::from(v.bound) * 2;
            let grow = |q: i32, d: i64| {
                (i64::from(q) + d).clamp(i64::from(i32::MIN), i64::from(i32::MAX)) as i32
            };
            let lo = QPoint::new(grow(a.x.min(b.x), -e), grow(a.y.min(b.y), -e)).cell();
            let hi = QPoint::new(grow(a.x.max(b.x), e), grow(a.y.max(b.y), e)).cell();
            let (x0, x1) = (lo.x.max(self.x0), hi.x.min(self.x0 + self.width as i32 - 1));
            let (y0, y1) = (
                lo.y.max(self.y0),
                hi.y.min(self.y0 + self.height as i32 - 1),
            );
            let e2 = (e * e) as f64;
            for y in y0..=y1 {
                for x in x0..=x1 {
                    let q = QPoint::centre(Cell::new(x, y));
                    if seg_dist2(q, a, b) <= e2 {
                        if let Some(k) = self.index(Cell::new(x, y)) {
                            f(k);
                        }
                    }
                }
            }
        }
    }
}

/// Whether [`paint`] keeps the cells near an approximated edge from being painted free: for
/// peers' approximations (what a receiver merges), never for the owner's own rendering (its
/// error d_t against G_s, monotone refinement).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Bands {
    Kept,
    Ignored,
}

/// A polygon to paint over a window, with the edges that reach the window's rows (`None`: all
/// of them) and a rectangle holding its cells: a window is painted by the edges that cross its
/// rows (its scan lines' crossings) or whose cells or bands reach them, and no other edge
/// changes a cell of it.
#[derive(Clone, Copy, Debug)]
pub struct Part<'a> {
    pub poly: &'a Polygon,
    pub edges: Option<&'a [u32]>,
    pub bounds: Option<Rect>,
}

impl<'a> Part<'a> {
    /// All of `poly`.
    pub fn whole(poly: &'a Polygon) -> Part<'a> {
        Part {
            poly,
            edges: None,
            bounds: poly.cell_bounds(),
        }
    }

    /// The edges to paint, by the index of their first vertex.
    fn edge_indices(&self) -> impl Iterator<Item = usize> + '_ {
        let all = self.edges.is_none().then_some(0..self.poly.vertices.len());
        let some = self.edges.map(|e| e.iter().map(|&i| i as usize));
        all.into_iter().flatten().chain(some.into_iter().flatten())
    }

    /// Edge `i`: its vertex and the next one's point.
    fn edge(&self, i: usize) -> (Vertex, QPoint) {
        let v = &self.poly.vertices;
        (v[i], v[(i + 1) % v.len()].p)
    }
}

/// Steps (1)–(5) of Algorithm 9 ([`crate::mapping::merge`]) for `approximations`, each as the list
/// of its polygons, over the window of `width × height` cells at `origin`: per cell, row-major,
/// what they say together, `None` where none of them says anything (the thesis's `undefined`).
pub fn paint(
    approximations: &[Vec<&Polygon>],
    origin: Cell,
    width: u32,
    height: u32,
    bands: Bands,
) -> Vec<Option<Occ>> {
    let parts: Vec<Vec<Part<'_>>> = (approximations.iter())
        .map(|a| a.iter().map(|&p| Part::whole(p)).collect())
        .collect();
    paint_parts(&parts, origin, width, height, bands)
}

/// [`paint`] of parts of polygons ([`Part`]): the same cells as painting the whole polygons,
/// when each part has every edge that reaches the window's rows.
pub fn paint_parts(
    approximations: &[Vec<Part<'_>>],
    origin: Cell,
    width: u32,
    height: u32,
    bands: Bands,
) -> Vec<Option<Occ>> {
    let window = Canvas::new(origin, width, height);
    let mut any = vec![Marks::NONE; window.len()];
    for a in approximations {
        mark_into(&mut any, &window, a, bands);
    }
    any.into_iter().map(Marks::painted).collect()
}

/// What one approximation (the list of its polygons' parts) marks in the window `r`, row-major
/// ([`Marks`]).
pub fn marks(a: &[Part<'_>], r: Rect, bands: Bands) -> Vec<Marks> {
    let window = Canvas::frame(r);
    let mut out = vec![Marks::NONE; window.len()];
    mark_into(&mut out, &window, a, bands);
    out
}

/// What one approximation says of a cell in steps (2)–(5) of Algorithm 9, as marks: the cell's
/// painting is a function of the marks of all approximations together (their union,
/// [`Marks::painted`]), so a painting can count each mark per cell and take in one
/// approximation's change alone ([`crate::mapping::painting`]).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Marks(u8);

impl Marks {
    pub const NONE: Marks = Marks(0);
    /// On an occupied edge of one of its objects (steps (3) and (5)).
    pub const OCCUPIED: Marks = Marks(1);
    /// Inside one of its outside objects, or on an unknown edge of one (steps (2) and (3)).
    pub const UNKNOWN: Marks = Marks(2);
    /// Inside one of its inside objects and, with [`Bands::Kept`], beyond every error bound of
    /// its edges: free unless an approximation says unknown or occupied (step (4)).
    pub const FREE: Marks = Marks(4);
    /// [`Marks::FREE`] and inside an odd number of its polygons: free even where an
    /// approximation says unknown (step (4)).
    pub const FREE_OVER_UNKNOWN: Marks = Marks(8);
    /// Each mark, in the order of [`Marks::index`].
    pub const EACH: [Marks; 4] = [
        Marks::OCCUPIED,
        Marks::UNKNOWN,
        Marks::FREE,
        Marks::FREE_OVER_UNKNOWN,
    ];

    /// Whether every mark of `m` is one of these.
    pub fn has(self, m: Marks) -> bool {
        self.0 & m.0 == m.0
    }

    /// A mark's place in [`Marks::EACH`] (0–3).
    pub fn index(self) -> usize {
        self.0.trailing_zeros() as usize
    }

    /// The cell painted by steps (1)–(5) where the approximations' marks together are these
    /// (`None`: undefined): occupied on an occupied edge; otherwise free where some
    /// approximation frees it past what the others say; otherwise unknown where one says so.
    pub fn painted(self) -> Option<Occ> {
        if self.has(Marks::OCCUPIED) {
            Some(Occ::Occupied)
        } else if self.has(Marks::UNKNOWN) {
            Some(if self.has(Marks::FREE_OVER_UNKNOWN) {
                Occ::Free
            } else {
                Occ::Unknown
            })
        } else if self.has(Marks::FREE) {
            Some(Occ::Free)
        } else {
            None
        }
    }
}

impl std::ops::BitOr for Marks {
    type Output = Marks;
    fn bitor(self, o: Marks) -> Marks {
        Marks(self.0 | o.0)
    }
}

impl std::ops::BitOrAssign for Marks {
    fn bitor_assign(&mut self, o: Marks) {
        self.0 |= o.0;
    }
}

/// Adds what approximation `a` marks to `out` (the cells of `window`, row-major). Only the
/// cells of the window its parts span are looked at (a part's bounds hold its cells).
fn mark_into(out: &mut [Marks], window: &Canvas, a: &[Part<'_>], bands: Bands) {
    const INSIDE: u8 = 1;
    const ODD: u8 = 2;
    const BAND: u8 = 4;
    const OUTSIDE: u8 = 8;
    const OCCUPIED_EDGE: u8 = 16;
    const UNKNOWN_EDGE: u8 = 32;
    let spans = a.iter().fold(None, |r, o| Rect::union_of(r, o.bounds));
    let Some(r) = spans.and_then(|r| window.clip(r)) else {
        return;
    };
    // The flags over the window `r` alone, indexed by a frame of it.
    let frame = Canvas::frame(r);
    let mut flags = vec![0u8; frame.len()];
    for o in a {
        let bit = match o.poly.kind {
            Kind::Inside => INSIDE,
            Kind::Outside => OUTSIDE,
        };
        frame.fill(o, |k| flags[k] = (flags[k] | bit) ^ ODD);
    }
    if bands == Bands::Kept {
        for o in a {
            frame.bands(o, |k| flags[k] |= BAND);
        }
    }
    for o in a {
        let outside = o.poly.kind == Kind::Outside;
        frame.edges(o, |k, occ| match occ {
            Occ::Occupied => flags[k] |= OCCUPIED_EDGE,
            Occ::Unknown if outside => flags[k] |= UNKNOWN_EDGE,
            _ => {}
        });
    }
    let marks = |f: u8| {
        let mut m = Marks::NONE;
        if f & OCCUPIED_EDGE != 0 {
            m |= Marks::OCCUPIED;
        }
        if f & (OUTSIDE | UNKNOWN_EDGE) != 0 {
            m |= Marks::UNKNOWN;
        }
        if f & INSIDE != 0 && f & BAND == 0 {
            m |= Marks::FREE;
            if f & ODD != 0 {
                m |= Marks::FREE_OVER_UNKNOWN;
            }
        }
        m
    };
    let (w, rw) = (window.width as usize, r.width() as usize);
    let (rx, ry) = (
        (r.min.x - window.x0) as usize,
        (r.min.y - window.y0) as usize,
    );
    for (row, fs) in flags.chunks(rw).enumerate() {
        let at = (ry + row) * w + rx;
        for (cell, &f) in out[at..at + rw].iter_mut().zip(fs) {
            *cell |= marks(f);
        }
    }
}

/// [`render`] of the approximation made of `polys`, restricted to the window of `width × height`
/// cells at `origin`, row-major: inside the grid identical to the same cells of the full rendering,
/// at the cost of the window and one pass over the vertices — used to score a single split locally.
/// Each polygon is painted with the edges that reach the window's rows alone ([`paint_parts`]), and
/// one whose cells miss the window not at all: a small window of a big approximation costs the
/// edges near it, not every edge several times over.
pub fn render_window(polys: &[&Polygon], origin: Cell, width: u32, height: u32) -> Vec<Occ> {
    let Some(window) = window_of(origin, width, height) else {
        return Vec::new();
    };
    let near: Vec<(Vec<u32>, Option<Rect>)> = polys.iter().map(|p| near(p, window)).collect();
    render_near(polys, &near, origin, width, height)
}

/// The cells of a `width × height` window at `origin` (`None`: too big to address).
pub(crate) fn window_of(origin: Cell, width: u32, height: u32) -> Option<Rect> {
    let (Ok(w), Ok(h)) = (i32::try_from(width), i32::try_from(height)) else {
        return None;
    };
    Some(Rect {
        min: origin,
        max: Cell::new(
            origin.x.saturating_add(w - 1),
            origin.y.saturating_add(h - 1),
        ),
    })
}

/// [`render_window`] given each polygon's [`near`] edges and bounds for the window (as
/// [`EdgeRows`] finds them).
pub(crate) fn render_near(
    polys: &[&Polygon],
    near: &[(Vec<u32>, Option<Rect>)],
    origin: Cell,
    width: u32,
    height: u32,
) -> Vec<Occ> {
    let Some(window) = window_of(origin, width, height) else {
        return Vec::new();
    };
    let parts: Vec<Part<'_>> = (polys.iter().zip(near))
        .filter(|(_, (_, bounds))| bounds.is_some_and(|b| b.intersects(window)))
        .map(|(&poly, (edges, bounds))| Part {
            poly,
            edges: Some(edges),
            bounds: *bounds,
        })
        .collect();
    paint_parts(&[parts], origin, width, height, Bands::Ignored)
        .into_iter()
        .map(|p| p.unwrap_or(Occ::Unknown))
        .collect()
}

/// The rows edge `i` of `p` (from vertex i to the next, the last to the first) reaches when
/// painted: its scan-line crossings and its cells lie within its ends' rows, one more on either
/// side is kept, and with [`Bands::Kept`] the rows of its band ([`band_cells`]) too.
fn edge_rows(p: &Polygon, i: usize, bands: Bands) -> (i32, i32) {
    let n = p.vertices.len();
    let (v, b) = (&p.vertices[i], p.vertices[(i + 1) % n].p.cell());
    let a = v.p.cell();
    let grow = match bands {
        Bands::Kept => 1 + band_cells(v.bound),
        Bands::Ignored => 1,
    };
    (
        a.y.min(b.y).saturating_sub(grow),
        a.y.max(b.y).saturating_add(grow),
    )
}

/// Cells within an error bound (half cells) of an edge, beyond the edge's own cells.
pub(crate) fn band_cells(bound: u16) -> i32 {
    i32::from(bound) / 2 + 1
}

/// Whether rows `lo..=hi` meet the rows of `window`.
fn reaches((lo, hi): (i32, i32), window: Rect) -> bool {
    lo <= window.max.y && window.min.y <= hi
}

/// The edges of `p` that reach the rows of `window` ([`edge_rows`]) and `p`'s
/// [`Polygon::cell_bounds`]: a pass over its vertices ([`EdgeRows`] finds the same without).
pub(crate) fn near(p: &Polygon, window: Rect) -> (Vec<u32>, Option<Rect>) {
    let edges = (0..p.vertices.len())
        .filter(|&i| reaches(edge_rows(p, i, Bands::Ignored), window))
        .map(|i| i as u32)
        .collect();
    (edges, p.cell_bounds())
}

/// Rows per band of [`EdgeRows`].
const BAND: i32 = 16;

/// A polygon's edges by the rows they reach when painted ([`edge_rows`]), in bands of [`BAND`]
/// rows: the edges near a window are found from the window's bands rather than by a pass over
/// every vertex. The painting kept from step to step paints windows of objects with thousands of
/// edges ([`crate::mapping::painting`]), the refinement many small windows of its drafts, one
/// edge split at a time ([`EdgeRows::near_inserted`]).
#[derive(Clone, Debug)]
pub(crate) struct EdgeRows {
    bands: Bands,
    /// The band of the first one (rows `first * BAND ..`).
    first: i32,
    /// Band `k`'s edges (ascending: those whose rows reach it) are
    /// `edges[starts[k]..starts[k + 1]]`.
    starts: Vec<usize>,
    edges: Vec<u32>,
    /// The polygon's [`Polygon::cell_bounds`].
    bounds: Option<Rect>,
}

impl EdgeRows {
    /// `p`'s edges by the rows they reach among rows `0..height` (the grid's: windows lie in
    /// it, and a polygon received from a peer may reach anywhere), painted with or without
    /// bands.
    pub(crate) fn of(p: &Polygon, bands: Bands, height: u32) -> EdgeRows {
        let last_row = i32::try_from(height).unwrap_or(i32::MAX) - 1;
        let span = |(lo, hi): (i32, i32)| {
            let (lo, hi) = (lo.max(0), hi.min(last_row));
            (lo <= hi).then(|| (lo.div_euclid(BAND), hi.div_euclid(BAND)))
        };
        let rows: Vec<Option<(i32, i32)>> = (0..p.vertices.len())
            .map(|i| span(edge_rows(p, i, bands)))
            .collect();
        let first = rows.iter().flatten().map(|r| r.0).min().unwrap_or(0);
        let last = rows
            .iter()
            .flatten()
            .map(|r| r.1)
            .max()
            .unwrap_or(first - 1);
        // Counted per band, then placed: one buffer for all bands.
        let mut starts = vec![0; (last - first + 2) as usize];
        for &(lo, hi) in rows.iter().flatten() {
            for k in lo..=hi {
                starts[(k - first) as usize + 1] += 1;
            }
        }
        for k in 1..starts.len() {
            starts[k] += starts[k - 1];
        }
        let mut next = starts.clone();
        let mut edges = vec![0; starts[starts.len() - 1]];
        for (i, &(lo, hi)) in rows
            .iter()
            .enumerate()
            .filter_map(|(i, r)| Some((i, r.as_ref()?)))
        {
            for k in lo..=hi {
                let at = &mut next[(k - first) as usize];
                edges[*at] = i as u32;
                *at += 1;
            }
        }
        EdgeRows {
            bands,
            first,
            starts,
            edges,
            bounds: p.cell_bounds(),
        }
    }

    /// The edges of `p` (the polygon indexed) that reach the rows of `window` (within the
    /// indexed rows), ascending.
    pub(crate) fn reaching(&self, p: &Polygon, window: Rect) -> Vec<u32> {
        self.edges(p, window, None)
    }

    /// [`near`]`(p, window)`, `p` being the polygon indexed.
    pub(crate) fn near(&self, p: &Polygon, window: Rect) -> (Vec<u32>, Option<Rect>) {
        (self.reaching(p, window), self.bounds)
    }

    /// [`near`]`(q, window)`, `q` being the polygon indexed with a vertex inserted at position
    /// `at` (1 ≤ `at` ≤ its length before): its edge `at - 1` became edges `at - 1` and `at`,
    /// and the edges after it moved one place on.
    pub(crate) fn near_inserted(
        &self,
        q: &Polygon,
        at: usize,
        window: Rect,
    ) -> (Vec<u32>, Option<Rect>) {
        let added = q.vertices.get(at).map(|v| Rect::cell(v.p.cell()).grown(1));
        let bounds = Rect::union_of(self.bounds, added);
        (self.edges(q, window, Some(at)), bounds)
    }

    /// The edges of `q` reaching the rows of `window`: the indexed ones from the window's
    /// bands, each taken in the first of them it reaches, renumbered after an insertion at
    /// `at` (whose two new edges are tested apart).
    fn edges(&self, q: &Polygon, window: Rect, at: Option<usize>) -> Vec<u32> {
        let last = self.first + self.starts.len() as i32 - 2;
        let (b1, b2) = (
            window.min.y.div_euclid(BAND).max(self.first),
            window.max.y.div_euclid(BAND).min(last),
        );
        let mut out = Vec::new();
        for b in b1..=b2 {
            let k = (b - self.first) as usize;
            for &e in &self.edges[self.starts[k]..self.starts[k + 1]] {
                let e = match at {
                    Some(at) if e as usize + 1 == at => continue,
                    Some(at) if e as usize >= at => e as usize + 1,
                    _ => e as usize,
                };
                let rows = edge_rows(q, e, self.bands);
                if reaches(rows, window) && rows.0.div_euclid(BAND).max(b1) == b {
                    out.push(e as u32);
                }
            }
        }
        if let Some(at) = at {
            let split = [at - 1, at].into_iter();
            out.extend(
                split
                    .filter(|&e| reaches(edge_rows(q, e, self.bands), window))
                    .map(|e| e as u32),
            );
        }
        out.sort_unstable();
        out
    }
}

/// The grid an approximation stands for on its own (`width × height`, the owner's frame):
/// Algorithm 9 with an empty G_s. Paints only where its polygons lie.
pub fn render(a: &Approximation, width: u32, height: u32) -> Grid {
    let mut g = Grid::new(width, height, Occ::Unknown);
    if let Some(r) = a.cell_bounds().and_then(|r| r.within(width, height)) {
        render_into(&mut g, a, r);
    }
    g
}

/// Writes [`render`]`(a, ..)` of the cells of `r` into `g`.
fn render_into(g: &mut Grid, a: &Approximation, r: Rect) {
    let polys: Vec<&Polygon> = a.objects.values().collect();
    let cells = render_window(&polys, r.min, r.width(), r.height());
    for (c, v) in r.cells().zip(cells) {
        g.set(c, v);
    }
}

/// G_s as any polygonal model can represent it: non-free cells with no free 4-neighbour
/// (buried behind other non-free cells) read unknown. [`render`] of the unsimplified
/// approximation equals exactly this (exploration equivalence, docs/design.md §4.1). Reads only
/// the known part of `g` (the rest reads unknown in the view too).
pub fn exploration_view(g: &Grid) -> Grid {
    let mut out = Grid::new(g.width(), g.height(), Occ::Unknown);
    if let Some(r) = g.known_bounds() {
        for c in r.cells() {
            out.set(c, viewed(g, c));
        }
    }
    out
}

/// [`exploration_view`] of a grid kept up to date as the grid changes: a cell's view depends
/// only on the cell and its 4-neighbours, so a step that changed some cells re-reads those and
/// their neighbours — work in proportion to what changed, not to the grid's area.
///
/// **Invariant:** after [`ExplorationView::update`] with every cell that changed, the view
/// equals [`exploration_view`] of the grid.
#[derive(Clone, Debug)]
pub struct ExplorationView {
    view: Grid,
}

impl ExplorationView {
    pub fn new(g: &Grid) -> ExplorationView {
        ExplorationView {
            view: exploration_view(g),
        }
    }

    /// `g` after the cells `changed` changed (and no others).
    pub fn update(&mut self, g: &Grid, changed: impl IntoIterator<Item = Cell>) {
        for c in changed {
            for n in std::iter::once(c).chain(c.neighbours4()) {
                if g.contains(n) {
                    self.view.set(n, viewed(g, n));
                }
            }
        }
    }

    /// The view.
    pub fn grid(&self) -> &Grid {
        &self.view
    }
}

/// One cell of [`exploration_view`]`(g)`.
fn viewed(g: &Grid, c: Cell) -> Occ {
    let v = g.get(c);
    let exposed = c.neighbours4().iter().any(|&n| g.get(n) == Occ::Free);
    if v != Occ::Free && !exposed {
        Occ::Unknown
    } else {
        v
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mapping::contour::Contours;
    use crate::testutil::{arb_grid, arb_map_window};
    use proptest::prelude::*;

    fn exact(g: &Grid) -> Approximation {
        Approximation::exact(&Contours::extract(g))
    }

    /// Rendering the unsimplified approximation of `pic` gives back `pic` (buried cells read
    /// unknown).
    fn check(pic: &str) {
        let g = Grid::from_ascii(pic);
        let got = render(&exact(&g), g.width(), g.height());
        assert_eq!(
            got.to_ascii(),
            exploration_view(&g).to_ascii(),
            "render of\n{pic}"
        );
    }

    #[test]
    fn exact_renders_reproduce_the_grid() {
        check("...\n.#.\n...");
        check("?##\n...");
        check("....\n.#..\n..#.\n....");
        check("####\n#.##\n##.#\n####");
        check(".......\n.#####.\n.#...#.\n.#####.\n.......");
        check(".......\n.##?##.\n.#?.?#.\n.#####.\n.......");
        check("#####\n#???#\n#?#?#\n#...#\n#####");
    }

    /// Steps (1)–(5) of Algorithm 9 as the thesis writes them, one after the other over every
    /// cell of the window (the oracle of [`paint`], which paints from the marks' union).
    fn steps_in_order(
        approximations: &[Vec<&Polygon>],
        origin: Cell,
        width: u32,
        height: u32,
        bands: Bands,
    ) -> Vec<Option<Occ>> {
        let (w, h) = (width as i32, height as i32);
        let index = |c: Cell| {
            let (x, y) = (c.x - origin.x, c.y - origin.y);
            (x >= 0 && y >= 0 && x < w && y < h).then(|| (y * w + x) as usize)
        };
        let (lo, hi) = (origin, Cell::new(origin.x + w - 1, origin.y + h - 1));
        let inside = |p: &Polygon| {
            let mut cells = Vec::new();
            raster::fill(&p.points(), origin.y..origin.y + h, |y, x0, x1| {
                cells.extend((x0..=x1).filter_map(|x| index(Cell::new(x, y))));
            });
            cells
        };
        let on_edges = |p: &Polygon| {
            let (v, n) = (&p.vertices, p.vertices.len());
            let mut cells = Vec::new();
            for i in 0..n {
                raster::edge(v[i].p, v[(i + 1) % n].p, lo, hi, |c| {
                    cells.extend(index(c).map(|k| (k, v[i].occ)));
                });
            }
            cells
        };
        let mut plan: Vec<Option<Occ>> = vec![None; (w * h) as usize]; // (1)
        let all = || approximations.iter().flatten();
        let outside = || all().filter(|p| p.kind == Kind::Outside);
        for p in outside() {
            for k in inside(p) {
                plan[k] = Some(Occ::Unknown); // (2)
            }
        }
        for p in outside() {
            for (k, occ) in on_edges(p) {
                match occ {
                    Occ::Occupied => plan[k] = Some(Occ::Occupied), // (3)
                    Occ::Unknown if plan[k] != Some(Occ::Occupied) => plan[k] = Some(Occ::Unknown),
                    _ => {}
                }
            }
        }
        for a in approximations {
            // (4): inside one of its inside objects, an odd number of its polygons, a band.
            let (mut ins, mut odd, mut band) = (
                vec![false; plan.len()],
                vec![false; plan.len()],
                vec![false; plan.len()],
            );
            for p in a {
                for k in inside(p) {
                    ins[k] |= p.kind == Kind::Inside;
                    odd[k] = !odd[k];
                }
                for (i, v) in p.vertices.iter().enumerate() {
                    let b = p.vertices[(i + 1) % p.vertices.len()].p;
                    let e = f64::from(v.bound) * 2.0;
                    for (k, near) in band.iter_mut().enumerate() {
                        let c = Cell::new(origin.x + k as i32 % w, origin.y + k as i32 / w);
                        *near |= bands == Bands::Kept
                            && v.bound > 0
                            && seg_dist2(QPoint::centre(c), v.p, b) <= e * e;
                    }
                }
            }
            for k in 0..plan.len() {
                let free = !band[k]
                    && ins[k]
                    && match plan[k] {
                        None => true,
                        Some(Occ::Unknown) => odd[k],
                        Some(_) => false,
                    };
                if free {
                    plan[k] = Some(Occ::Free);
                }
            }
        }
        for p in all() {
            for (k, occ) in on_edges(p) {
                if occ == Occ::Occupied {
                    plan[k] = Some(Occ::Occupied); // (5)
                }
            }
        }
        plan
    }

    /// Arbitrary polygons near a 16 × 16 window: any kind, occupancy and error bound.
    fn arb_polygons() -> impl Strategy<Value = Vec<Polygon>> {
        let vertex = (-12i32..76, -12i32..76, 0u8..3, 0u16..6);
        proptest::collection::vec(
            (any::<bool>(), proptest::collection::vec(vertex, 0..7)),
            0..4,
        )
        .prop_map(|polys| {
            (polys.into_iter())
                .map(|(inside, vs)| Polygon {
                    kind: if inside { Kind::Inside } else { Kind::Outside },
                    vertices: (vs.into_iter())
                        .map(|(x, y, o, bound)| Vertex {
                            p: QPoint::new(x, y),
                            occ: [Occ::Free, Occ::Occupied, Occ::Unknown][usize::from(o)],
                            bound,
                        })
                        .collect(),
                })
                .collect()
        })
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(128))]

        #[test]
        fn exploration_equivalence_on_random_grids(g in arb_grid(16)) {
            let got = render(&exact(&g), g.width(), g.height());
            prop_assert_eq!(got.to_ascii(), exploration_view(&g).to_ascii());
        }

        #[test]
        fn exploration_equivalence_on_real_maps(g in arb_map_window(48, 48)) {
            let got = render(&exact(&g), g.width(), g.height());
            prop_assert_eq!(got.to_ascii(), exploration_view(&g).to_ascii());
        }

        #[test]
        fn the_kept_view_equals_the_view_from_scratch(
            g in arb_grid(14),
            edits in proptest::collection::vec(((0i32..14, 0i32..14), 0u8..3), 0..40)
        ) {
            let mut g = g;
            let mut kept = ExplorationView::new(&g);
            for ((x, y), v) in edits {
                let c = Cell::new(x, y);
                g.set(c, [Occ::Free, Occ::Occupied, Occ::Unknown][usize::from(v)]);
                kept.update(&g, [c]);
                prop_assert_eq!(kept.grid().to_ascii(), exploration_view(&g).to_ascii());
            }
        }

        /// The view and the rendering read only the explored part of a grid; they agree with
        /// reading every cell.
        #[test]
        fn bounded_views_and_renders_agree_with_every_cell(g in crate::testutil::arb_placed_grid(), splits in 0usize..12) {
            let every: Vec<Occ> = (0..g.len()).map(|i| viewed(&g, g.cell_of(i))).collect();
            prop_assert_eq!(exploration_view(&g).cells().to_vec(), every);
            let a = crate::mapping::approximator::approximate(&Contours::extract(&g), &g, splits);
            let polys: Vec<&Polygon> = a.objects.values().collect();
            let full = render_window(&polys, Cell::new(0, 0), g.width(), g.height());
            prop_assert_eq!(render(&a, g.width(), g.height()).cells().to_vec(), full);
        }

        #[test]
        fn window_renders_agree_with_full_renders(
            g in arb_grid(14), splits in 0usize..12, (x, y, w, h) in (0i32..14, 0i32..14, 1u32..8, 1u32..8)
        ) {
            let a = crate::mapping::approximator::approximate(&Contours::extract(&g), &g, splits);
            let full = render(&a, g.width(), g.height());
            let polys: Vec<&Polygon> = a.objects.values().collect();
            let win = render_window(&polys, Cell::new(x, y), w, h);
            for (k, got) in win.iter().enumerate() {
                let c = Cell::new(x + (k as u32 % w) as i32, y + (k as u32 / w) as i32);
                // A simplified outside polygon may reach past the grid; `render` clips there
                // and so does every caller of `render_window` (refine's windows).
                if !g.contains(c) {
                    continue;
                }
                prop_assert_eq!(*got, full.get(c), "cell {:?}", c);
            }
        }
    }

    /// A polygon received from a peer may reach anywhere: indexed over the grid's rows, its
    /// index holds those rows' bands, not a band per 16 rows of its own span.
    #[test]
    fn edges_by_rows_stay_within_the_grid_s_rows() {
        let vertex = |x: i32, y: i32| Vertex {
            p: QPoint::new(x, y),
            occ: Occ::Occupied,
            bound: 0,
        };
        let p = Polygon {
            kind: Kind::Inside,
            vertices: vec![
                vertex(0, -2_000_000_000),
                vertex(40, 2_000_000_000),
                vertex(80, 40),
            ],
        };
        let rows = EdgeRows::of(&p, Bands::Kept, 100);
        assert!(
            rows.starts.len() <= 100 / BAND as usize + 2,
            "{} bands",
            rows.starts.len()
        );
        let window = window_of(Cell::new(0, 0), 30, 100).expect("a window");
        assert_eq!(rows.reaching(&p, window), vec![0, 1, 2]);
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(512))]

        /// The edges near a window found by rows are [`near`]'s — of a polygon as indexed and
        /// of one with a vertex inserted since — and so are the bounds.
        #[test]
        fn edges_by_rows_are_the_edges_near_a_window(
            polys in arb_polygons(),
            (x, y, w, h) in (-30i32..160, 0i32..160, 1u32..40, 1u32..40),
            (at, nx, ny) in (1usize..8, -100i32..620, -100i32..620),
        ) {
            let window = window_of(Cell::new(x, y), w, h).expect("a small window");
            // Spread over several bands of rows: vertices 8 quarter cells (2 cells) apart.
            let spread = |mut p: Polygon| {
                p.vertices.iter_mut().for_each(|v| v.p = QPoint::new(8 * v.p.x, 8 * v.p.y));
                p
            };
            for p in &polys.into_iter().map(spread).collect::<Vec<_>>() {
                let rows = EdgeRows::of(p, Bands::Ignored, 200);
                prop_assert_eq!(rows.near(p, window), near(p, window));
                if p.vertices.is_empty() {
                    continue;
                }
                let at = at.min(p.vertices.len());
                let mut q = p.clone();
                q.vertices.insert(at, Vertex { p: QPoint::new(nx, ny), ..q.vertices[at - 1] });
                prop_assert_eq!(rows.near_inserted(&q, at, window), near(&q, window));
            }
        }

        /// Painting from the union of each approximation's marks is painting step after step:
        /// arbitrary polygons of up to four approximations, any window, bands kept or not.
        #[test]
        fn the_marks_paint_what_the_steps_in_order_paint(
            approximations in proptest::collection::vec(arb_polygons(), 0..5),
            (x, y, w, h) in (-4i32..12, -4i32..12, 1u32..18, 1u32..18),
            kept in any::<bool>(),
        ) {
            let bands = if kept { Bands::Kept } else { Bands::Ignored };
            let polys: Vec<Vec<&Polygon>> = approximations.iter().map(|a| a.iter().collect()).collect();
            let origin = Cell::new(x, y);
            prop_assert_eq!(
                paint(&polys, origin, w, h, bands),
                steps_in_order(&polys, origin, w, h, bands)
            );
        }

        /// The same for real approximations of explorations, at any splitting frequency, each
        /// robot's own.
        #[test]
        fn real_approximations_paint_by_marks_as_step_after_step(
            robots in proptest::collection::vec(crate::testutil::arb_exploration(16, 3), 1..4),
            s in prop_oneof![Just(0.0), Just(1.0), Just(4.0)],
        ) {
            let approximations: Vec<Approximation> = (robots.iter())
                .map(|steps| {
                    let mut ax = crate::mapping::approximator::Approximator::new();
                    let mut a = Approximation::default();
                    for g in steps {
                        a = ax.step(&Contours::extract(g), g, s).clone();
                    }
                    a
                })
                .collect();
            let polys: Vec<Vec<&Polygon>> = approximations.iter().map(|a| a.objects.values().collect()).collect();
            let (w, h) = (robots[0][0].width(), robots[0][0].height());
            prop_assert_eq!(
                paint(&polys, Cell::new(0, 0), w, h, Bands::Kept),
                steps_in_order(&polys, Cell::new(0, 0), w, h, Bands::Kept)
            );
        }
    }
}
