//! Douglas–Peucker refinement of a valid approximation (thesis §4.3.2, Algorithm 6, §5.1.1).
//!
//! Every object already has ≥ 2 vertices, so each polygon is split into chains between consecutive
//! vertices (Fig. 4.11) and all chains of all polygons share **one priority queue**. An edge's
//! value is the maximum segment distance d(p, e), in cells, of the P_t points it spans; each split
//! pops the most valuable edge, inserts its farthest point and queues the two new edges. Beyond the
//! thesis, an edge whose spanned points mix occupied with non-occupied cells is worth at least
//! [`OCC_MIX_VALUE`](crate::mapping::refine::OCC_MIX_VALUE) (half a cell): precautious f_occ would
//! otherwise hide those walls forever, and with it unlimited splits reach d_t = 0. Such an edge is
//! split where the occupancy changes when its geometry is already within that half cell.
//!
//! **Monotone refinement** (beyond the thesis; on when a reference grid is given). A DP split can
//! raise d_t — a chord through a free corner cell drawn occupied, a triangle of cells flipping side
//! — so each split is scored by re-rendering just its window
//! ([`crate::mapping::render::render_window`]). Of the
//! [`LOOKAHEAD`](crate::mapping::refine::LOOKAHEAD) most valuable edges the split that lowers d_t
//! most is taken; one that would raise d_t is deferred (and retried when a later split touches its
//! window). When only deferred splits are left, the next splits in DP order are taken as one atomic
//! group, up to the first point where d_t is back at or below its value before the group (at the
//! latest when everything is exact and d_t = 0). A budget of k splits takes the longest prefix of
//! this sequence of groups that fits, so more splits never raise d_t on a fixed P_t. The price:
//! about 1–3 ms per step on 600×600 maps, and splits that would pay off only after a temporary rise
//! are postponed, so over a whole exploration the mean d_t can be higher than plain DP's (set
//! `Approximator::monotone = false` for the thesis's plain DP).

use std::cmp::Ordering;
use std::collections::BinaryHeap;

use proto::grid::{Cell, Grid, Occ};

use crate::mapping::approx::{ObjectId, Polygon, Vertex};
use crate::mapping::contour::{Contour, Contours};
use crate::mapping::qpoint::seg_dist2;
use crate::mapping::render::{self, render_near, window_of, Bands, EdgeRows};

/// How many of the most valuable edges are scored for each split (monotone mode).
pub const LOOKAHEAD: usize = 8;

/// The value in cells given to an edge that loses occupied cells to the precautious rule.
pub const OCC_MIX_VALUE: f64 = 0.5;

/// An object of A_t under construction: its vertices as point indices of P_t object `pobj`,
/// in P_t's cyclic order, and the polygon they stand for (kept in step).
#[derive(Clone, Debug, PartialEq, Eq)]
pub(crate) struct Draft {
    pub id: ObjectId,
    pub pobj: usize,
    pub idx: Vec<usize>,
    pub poly: Polygon,
}

impl Draft {
    pub(crate) fn new(id: ObjectId, pobj: usize, idx: Vec<usize>, c: &Contour) -> Draft {
        let n = idx.len();
        let vertices = (0..n)
            .map(|k| Vertex::spanning(c, idx[k], idx[(k + 1) % n]))
            .collect();
        Draft {
            id,
            pobj,
            idx,
            poly: Polygon {
                kind: c.kind,
                vertices,
            },
        }
    }

    /// Inserts point `split` after the vertex at point `from`; returns its position.
    fn insert(&mut self, c: &Contour, from: usize, split: usize) -> usize {
        let at = self
            .idx
            .iter()
            .position(|&i| i == from)
            .map_or(0, |k| k + 1);
        let to = self.idx[at % self.idx.len()];
        self.idx.insert(at, split);
        self.poly
            .vertices
            .insert(at, Vertex::spanning(c, split, to));
        self.poly.vertices[at - 1] = Vertex::spanning(c, from, split);
        at
    }

    /// Undoes [`Draft::insert`] at position `at`.
    fn remove(&mut self, c: &Contour, at: usize) {
        self.idx.remove(at);
        self.poly.vertices.remove(at);
        let (from, to) = (self.idx[at - 1], self.idx[at % self.idx.len()]);
        self.poly.vertices[at - 1] = Vertex::spanning(c, from, to);
    }
}

/// A queued edge of draft `draft` from point `from` to point `to`, and where to split it.
#[derive(Clone, Copy, Debug)]
struct Candidate {
    value: f64,
    draft: usize,
    from: usize,
    to: usize,
    split: usize,
}

impl PartialEq for Candidate {
    fn eq(&self, o: &Self) -> bool {
        self.cmp(o) == Ordering::Equal
    }
}

impl Eq for Candidate {}

impl PartialOrd for Candidate {
    fn partial_cmp(&self, o: &Self) -> Option<Ordering> {
        Some(self.cmp(o))
    }
}

impl Ord for Candidate {
    /// Highest value first; ties go to the lower draft, then the lower start point.
    fn cmp(&self, o: &Self) -> Ordering {
        self.value
            .total_cmp(&o.value)
            .then(o.draft.cmp(&self.draft))
            .then(o.from.cmp(&self.from))
    }
}

/// What a refinement did.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Refined {
    /// Vertices inserted.
    pub splits: usize,
    /// Stopped because the next atomic group did not fit the budget (keep the credit).
    pub waiting: bool,
}

/// Applies up to `budget` Douglas–Peucker splits to `drafts`; monotone in d_t against
/// `reference` (G_s in its exploration view) when one is given, plain DP otherwise.
pub(crate) fn refine(
    drafts: &mut [Draft],
    p: &Contours,
    reference: Option<&Grid>,
    budget: usize,
) -> Refined {
    if budget == 0 {
        return Refined {
            splits: 0,
            waiting: false,
        };
    }
    Refiner::new(drafts, p, reference).run(budget)
}

impl<'a> Refiner<'a> {
    /// A refiner of `drafts` with every edge queued.
    fn new(drafts: &'a mut [Draft], p: &'a Contours, reference: Option<&'a Grid>) -> Self {
        let count = drafts.len();
        let mut r = Refiner {
            p,
            drafts,
            reference,
            queue: BinaryHeap::new(),
            deferred: Vec::new(),
            scored: Vec::new(),
            rows: vec![None; count],
        };
        for d in 0..r.drafts.len() {
            let n = r.drafts[d].idx.len();
            for k in 0..n {
                let (from, to) = (r.drafts[d].idx[k], r.drafts[d].idx[(k + 1) % n]);
                r.queue.extend(evaluate(r.contour(d), d, from, to));
            }
        }
        r
    }
}

struct Refiner<'a> {
    p: &'a Contours,
    drafts: &'a mut [Draft],
    reference: Option<&'a Grid>,
    queue: BinaryHeap<Candidate>,
    deferred: Vec<Candidate>,
    /// Candidates scored ([`Refiner::delta`]) since the last split whose window meets theirs,
    /// with their score: a split changes the rendering within its window alone (the
    /// triangle it cuts off or adds and its edges lie there — what deferring relies on too), so
    /// the lookahead, which scores mostly the same candidates for every split, renders each
    /// once.
    scored: Vec<(Candidate, i64)>,
    /// Per draft, its edges by row, indexed when a score first renders near it and dropped
    /// when a split changes it: a window's rendering takes the edges of the window's rows
    /// from it, not a pass over every vertex of every draft.
    rows: Vec<Option<EdgeRows>>,
}

impl Refiner<'_> {
    fn contour(&self, d: usize) -> &Contour {
        &self.p.objects()[self.drafts[d].pobj]
    }

    fn run(&mut self, budget: usize) -> Refined {
        let mut used = 0;
        while used < budget {
            let Some(c) = self.next_split() else {
                if self.deferred.is_empty() {
                    break;
                }
                match self.group(budget - used) {
                    Some(n) => used += n,
                    None => {
                        return Refined {
                            splits: used,
                            waiting: true,
                        }
                    }
                }
                continue;
            };
            self.split(c);
            used += 1;
        }
        Refined {
            splits: used,
            waiting: false,
        }
    }

    /// Of the [`LOOKAHEAD`] most valuable queued edges, the one whose split lowers d_t most
    /// (ties in DP order); edges whose split would raise d_t are deferred. Without a reference
    /// simply the most valuable edge.
    fn next_split(&mut self) -> Option<Candidate> {
        if self.reference.is_none() {
            return self.queue.pop();
        }
        loop {
            let mut best: Option<(i64, Candidate)> = None;
            let mut rest = Vec::new();
            for _ in 0..LOOKAHEAD {
                let Some(c) = self.queue.pop() else { break };
                let d = self.score(c);
                match best {
                    _ if d > 0 => self.deferred.push(c),
                    Some((bd, _)) if d >= bd => rest.push(c),
                    _ => {
                        rest.extend(best.map(|(_, b)| b));
                        best = Some((d, c));
                    }
                }
            }
            self.queue.extend(rest);
            if best.is_some() || self.queue.is_empty() {
                return best.map(|(_, c)| c);
            }
        }
    }

    /// The next atomic group: splits in DP order until d_t is back at or below its value
    /// before the group; `None` (and nothing changed) if it needs more than `room` splits.
    fn group(&mut self, room: usize) -> Option<usize> {
        let saved = (
            self.drafts.to_vec(),
            self.queue.clone(),
            self.deferred.clone(),
            self.scored.clone(),
        );
        self.queue.extend(self.deferred.drain(..));
        let (mut n, mut total) = (0, 0);
        while let Some(c) = self.queue.pop() {
            total += self.score(c);
            self.split(c);
            n += 1;
            if total <= 0 || n > room {
                break;
            }
        }
        if n > room {
            self.drafts.clone_from_slice(&saved.0);
            self.rows.iter_mut().for_each(|r| *r = None);
            (self.queue, self.deferred, self.scored) = (saved.1, saved.2, saved.3);
            return None;
        }
        self.queue.extend(self.deferred.drain(..));
        Some(n)
    }

    /// Commits a split, queues the two new edges and retries deferred edges it may affect.
    fn split(&mut self, c: Candidate) {
        let p = self.p;
        let contour = &p.objects()[self.drafts[c.draft].pobj];
        self.drafts[c.draft].insert(contour, c.from, c.split);
        self.rows[c.draft] = None;
        self.queue
            .extend(evaluate(contour, c.draft, c.from, c.split));
        self.queue.extend(evaluate(contour, c.draft, c.split, c.to));
        let w = self.window(c);
        let scored = std::mem::take(&mut self.scored);
        self.scored = (scored.into_iter())
            .filter(|(k, _)| !same_edge(*k, c) && !overlap(w, self.window(*k)))
            .collect();
        let deferred = std::mem::take(&mut self.deferred);
        let (touched, kept): (Vec<_>, Vec<_>) = deferred
            .into_iter()
            .partition(|d| overlap(w, self.window(*d)));
        self.deferred = kept;
        self.queue.extend(touched);
    }

    /// [`Refiner::delta`], kept until a split's window meets `c`'s.
    fn score(&mut self, c: Candidate) -> i64 {
        if let Some(&(_, d)) = self.scored.iter().find(|(k, _)| same_edge(*k, c)) {
            return d;
        }
        let d = self.delta(c);
        self.scored.push((c, d));
        d
    }

    /// The change of d_t if `c` were split (0 without a reference).
    fn delta(&mut self, c: Candidate) -> i64 {
        let Some(reference) = self.reference else {
            return 0;
        };
        let (origin, w, h) = self.window(c);
        let before = self.window_error(reference, origin, w, h, None);
        let p = self.p;
        let contour = &p.objects()[self.drafts[c.draft].pobj];
        let at = self.drafts[c.draft].insert(contour, c.from, c.split);
        let after = self.window_error(reference, origin, w, h, Some((c.draft, at)));
        self.drafts[c.draft].remove(contour, at);
        after as i64 - before as i64
    }

    /// The cells of the window where the drafts' rendering and `reference` differ; `inserted`:
    /// a draft holds a vertex inserted at a position since its rows were indexed (a draft not
    /// indexed yet is indexed only when none is).
    fn window_error(
        &mut self,
        reference: &Grid,
        origin: Cell,
        w: u32,
        h: u32,
        inserted: Option<(usize, usize)>,
    ) -> usize {
        let Some(window) = window_of(origin, w, h) else {
            return 0;
        };
        let height = reference.height();
        let mut near = Vec::with_capacity(self.drafts.len());
        for (d, draft) in self.drafts.iter().enumerate() {
            if inserted.is_none() && self.rows[d].is_none() {
                self.rows[d] = Some(EdgeRows::of(&draft.poly, Bands::Ignored, height));
            }
            near.push(match (&self.rows[d], inserted) {
                (Some(rows), Some((k, at))) if k == d => {
                    rows.near_inserted(&draft.poly, at, window)
                }
                (Some(rows), _) => rows.near(&draft.poly, window),
                // Not indexed (only while a candidate's vertex is in): every vertex.
                (None, _) => render::near(&draft.poly, window),
            });
        }
        let polys: Vec<&Polygon> = self.drafts.iter().map(|d| &d.poly).collect();
        let got = render_near(&polys, &near, origin, w, h);
        let mut k = 0;
        let mut wrong = 0;
        for y in origin.y..origin.y + h as i32 {
            for x in origin.x..origin.x + w as i32 {
                wrong += usize::from(got[k] != reference.get(Cell::new(x, y)));
                k += 1;
            }
        }
        wrong
    }

    /// The cells a split of `c` can change: the bounding box of its three points' cells,
    /// clipped to the reference grid (empty when it lies outside).
    fn window(&self, c: Candidate) -> (Cell, u32, u32) {
        let pts = &self.contour(c.draft).points;
        let cells = [pts[c.from].cell(), pts[c.split].cell(), pts[c.to].cell()];
        let (gw, gh) = self
            .reference
            .map_or((0, 0), |g| (g.width() as i32, g.height() as i32));
        let x0 = cells.iter().map(|c| c.x).min().unwrap_or(0).max(0);
        let y0 = cells.iter().map(|c| c.y).min().unwrap_or(0).max(0);
        let x1 = cells.iter().map(|c| c.x).max().unwrap_or(0).min(gw - 1);
        let y1 = cells.iter().map(|c| c.y).max().unwrap_or(0).min(gh - 1);
        (
            Cell::new(x0, y0),
            (x1 - x0 + 1).max(0) as u32,
            (y1 - y0 + 1).max(0) as u32,
        )
    }
}

/// Whether `a` and `b` are the split of the same edge at the same point.
fn same_edge(a: Candidate, b: Candidate) -> bool {
    (a.draft, a.from, a.to, a.split) == (b.draft, b.from, b.to, b.split)
}

fn overlap(a: (Cell, u32, u32), b: (Cell, u32, u32)) -> bool {
    let ((pa, wa, ha), (pb, wb, hb)) = (a, b);
    pa.x < pb.x + wb as i32
        && pb.x < pa.x + wa as i32
        && pa.y < pb.y + hb as i32
        && pb.y < pa.y + ha as i32
}

/// The value of the edge `from`→`to` of `c` and its split point, or `None` if it is exact.
fn evaluate(c: &Contour, draft: usize, from: usize, to: usize) -> Option<Candidate> {
    let n = c.points.len();
    let (a, b) = (c.points[from], c.points[to]);
    let (mut far, mut far_d2) = (from, 0.0);
    let (mut change, mut occupied, mut other) = (None, c.occ[from] == Occ::Occupied, false);
    let mut k = (from + 1) % n;
    while k != to {
        let d2 = seg_dist2(c.points[k], a, b);
        if d2 > far_d2 {
            (far, far_d2) = (k, d2);
        }
        if change.is_none() && c.occ[k] != c.occ[(k + n - 1) % n] {
            change = Some(k);
        }
        if c.occ[k] == Occ::Occupied {
            occupied = true;
        } else {
            other = true;
        }
        k = (k + 1) % n;
    }
    other |= c.occ[from] != Occ::Occupied;
    let dist = far_d2.sqrt() / 4.0;
    let mixed = occupied && other;
    let (value, split) = match change {
        Some(at) if mixed && dist <= OCC_MIX_VALUE => (OCC_MIX_VALUE, at),
        _ => (dist, far),
    };
    (value > 0.0).then_some(Candidate {
        value,
        draft,
        from,
        to,
        split,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use proto::grid::Grid;

    fn drafts_of(p: &Contours) -> Vec<Draft> {
        let objs = p.objects();
        (0..objs.len())
            .map(|o| {
                Draft::new(
                    o as ObjectId,
                    o,
                    vec![0, objs[o].points.len() / 2],
                    &objs[o],
                )
            })
            .collect()
    }

    #[test]
    fn splits_go_to_the_worst_edge_over_all_polygons() {
        let g = Grid::from_ascii("..........\n.#........\n.....####.\n..........");
        let p = Contours::extract(&g);
        let mut d = drafts_of(&p);
        assert_eq!(refine(&mut d, &p, None, 1).splits, 1);
        // The inside object (10×4 cells) has the largest error, not the small islands.
        let grown: Vec<usize> = d.iter().map(|d| d.idx.len()).collect();
        let inside = p
            .objects()
            .iter()
            .position(|o| o.kind == crate::mapping::contour::Kind::Inside);
        assert_eq!(inside.map(|i| grown[i]), Some(3));
    }

    #[test]
    fn refinement_stops_when_exact() {
        let g = Grid::from_ascii("...\n.#.\n...");
        let p = Contours::extract(&g);
        let mut d = drafts_of(&p);
        let made = refine(&mut d, &p, None, usize::MAX).splits;
        assert!(made < 16);
        for dr in &d {
            let c = &p.objects()[dr.pobj];
            let n = dr.idx.len();
            for k in 0..n {
                assert!(evaluate(c, 0, dr.idx[k], dr.idx[(k + 1) % n]).is_none());
            }
        }
    }

    proptest::proptest! {
        /// A score the lookahead keeps is the score computed afresh after every split: a split
        /// changes the rendering within its window alone, so scores whose windows it misses
        /// stand (on windows of real maps, refined against their exploration view).
        #[test]
        fn a_kept_score_is_the_score_afresh(
            g in crate::testutil::arb_map_window(28, 28), splits in 1usize..40
        ) {
            let p = Contours::extract(&g);
            let view = crate::mapping::render::exploration_view(&g);
            let mut d = drafts_of(&p);
            let mut r = Refiner::new(&mut d, &p, Some(&view));
            for _ in 0..splits {
                let Some(c) = r.next_split() else { break };
                r.split(c);
                for (k, kept) in r.scored.clone() {
                    proptest::prop_assert_eq!(kept, r.delta(k));
                }
            }
        }
    }

    #[test]
    fn mixed_occupancy_is_split_where_it_changes() {
        let g = Grid::from_ascii("?????\n.##?#\n.....");
        let p = Contours::extract(&g);
        let c = &p.objects()[0];
        let occ_runs = (0..c.occ.len())
            .filter(|&i| c.occ[i] != c.occ[(i + 1) % c.occ.len()])
            .count();
        let mut d = drafts_of(&p);
        refine(&mut d, &p, None, usize::MAX);
        assert!(
            d[0].idx.len() >= occ_runs,
            "every occupancy change is a vertex"
        );
    }
}
