//! Path planning on a ternary grid: costs, frontiers, paths and waypoints (docs/design.md §4.6,
//! first paragraph; thesis §4.5).
//!
//! Every coordination strategy needs the same three things from the planning grid G_p: the cost
//! V of reaching each cell from the robot's cell, the frontiers (reachable free cells next to
//! unknown space, Yamauchi's targets), and a way to get to the chosen target. The thesis computes V
//! by value iteration (Algorithm 7); with deterministic moves that is a shortest-path problem, so
//! here it is a Dijkstra over free cells, 8-connected with Euclidean step costs (1 and √2). A
//! diagonal step needs both orthogonal neighbours free: the robot never cuts a wall's corner, and a
//! diagonal step's straight segment (which passes through the shared corner) touches only free
//! cells — the same walk ([`proto::traverse::swept`]) the world-server applies to a move.
//!
//! The path to a target follows the Dijkstra predecessors;
//! [`next_waypoint`](crate::nav::plan::next_waypoint) then shortcuts it to the farthest path cell
//! that one move can reach along a verified straight segment.

use std::cmp::Ordering;
use std::collections::{BTreeSet, BinaryHeap};

use proto::grid::{Cell, Grid, Occ, Rect};

use proto::geom::{MapInfo, Metres};
use proto::traverse::swept;

/// Costs that differ by less than this count as equal when frontiers are ranked, so that the
/// tie-break by position is not decided by the rounding of sums of 1 and √2.
pub(crate) const COST_TIE_QUANTUM: f64 = 1e-6;

/// Marks a cell without predecessor (the start, and unreachable cells).
const NO_PRED: u32 = u32::MAX;

/// The eight moves as (dx, dy); orthogonal moves first.
const MOVES: [(i32, i32); 8] = [
    (1, 0),
    (0, 1),
    (-1, 0),
    (0, -1),
    (1, 1),
    (-1, 1),
    (-1, -1),
    (1, -1),
];

/// The cost (in cells) of reaching every cell from one start cell, with the shortest-path tree.
#[derive(Clone, Debug)]
pub struct CostMap {
    /// The window of the grid the search could reach (the explored part and the sources);
    /// every cell beyond it is unreachable.
    x0: i32,
    y0: i32,
    width: u32,
    height: u32,
    start: Cell,
    /// Per row-major cell index of the window, what the search knows of the cell: its
    /// cost and predecessor, valid when the cell's stamp is this search's (together, so that
    /// a relaxation touches one place in memory). A search costs what it reaches, not the
    /// window's area: the buffer is never cleared, only stamped anew.
    cells: Vec<Reached>,
    /// The current search's stamp (never 0 once a search began).
    search: u32,
    /// Dijkstra's queue, its buffers kept from search to search.
    queue: Buckets,
    /// A*'s queue ([`path_until`]), its buffer kept likewise.
    guided: BinaryHeap<Guided>,
    /// The search settled every cell up to this cost and stopped ([`costs_to_frontiers`]);
    /// costs beyond it are unknown and read as unreachable. `f64::INFINITY`: a full search;
    /// `f64::NEG_INFINITY`: none to read ([`path_until`]).
    limit: f64,
}

impl Default for CostMap {
    /// A map of nothing reachable, whose buffers a search fills ([`costs_into`]).
    fn default() -> CostMap {
        CostMap {
            x0: 0,
            y0: 0,
            width: 0,
            height: 0,
            start: Cell::new(-1, -1),
            cells: Vec::new(),
            queue: Buckets::default(),
            guided: BinaryHeap::new(),
            search: 0,
            limit: f64::INFINITY,
        }
    }
}

impl CostMap {
    /// The cell the costs are measured from.
    pub fn start(&self) -> Cell {
        self.start
    }

    /// The cost of the cheapest path from the start to `c` in cells; `None` when `c` is
    /// unreachable or outside the grid.
    pub fn cost(&self, c: Cell) -> Option<f64> {
        self.index(c)
            .map(|i| self.dist_at(i))
            .filter(|&d| d.is_finite() && d <= self.limit)
    }

    /// Whether the search covered every cell it could reach (not stopped early).
    pub fn is_complete(&self) -> bool {
        self.limit == f64::INFINITY
    }

    /// The cost of cell index `i` (`f64::INFINITY`: not reached).
    fn dist_at(&self, i: usize) -> f64 {
        let r = &self.cells[i];
        if r.stamp == self.search {
            r.dist
        } else {
            f64::INFINITY
        }
    }

    /// Cell index `i` reached at `cost` from `pred`.
    fn reach(&mut self, i: usize, cost: f64, pred: u32) {
        self.cells[i] = Reached {
            dist: cost,
            pred,
            stamp: self.search,
        };
    }

    fn index(&self, c: Cell) -> Option<usize> {
        let (x, y) = (c.x - self.x0, c.y - self.y0);
        let inside = x >= 0 && y >= 0 && (x as u32) < self.width && (y as u32) < self.height;
        inside.then(|| y as usize * self.width as usize + x as usize)
    }

    /// Starts a search from `sources` over `g`: the window — the known part and the sources
    /// inside the grid — no cell reached yet.
    fn begin(&mut self, g: &Grid, sources: &[Cell]) {
        let window = (sources.iter().filter(|&&c| g.contains(c)))
            .fold(g.known_bounds(), |r, &c| {
                Rect::union_of(r, Some(Rect::cell(c)))
            });
        let (x0, y0, width, height) =
            window.map_or((0, 0, 0, 0), |r| (r.min.x, r.min.y, r.width(), r.height()));
        let start = sources.first().copied().unwrap_or(Cell::new(-1, -1));
        (self.x0, self.y0, self.width, self.height, self.start) = (x0, y0, width, height, start);
        let cells = width as usize * height as usize;
        self.limit = f64::INFINITY;
        if self.cells.len() < cells {
            self.cells.resize(cells, Reached::default());
        }
        self.search = self.search.wrapping_add(1);
        if self.search == 0 {
            // Stamps wrapped around: none may read as this search's.
            self.cells.fill(Reached::default());
            self.search = 1;
        }
    }

    fn cell_of(&self, i: usize) -> Cell {
        let w = self.width as usize;
        Cell::new(self.x0 + (i % w) as i32, self.y0 + (i / w) as i32)
    }
}

/// A cell as a search reached it ([`CostMap::cells`]): its cost, its predecessor on a shortest
/// path ([`NO_PRED`] for a source) and the search that wrote them (`stamp`; 0: none).
#[derive(Clone, Copy, Debug, Default)]
struct Reached {
    dist: f64,
    pred: u32,
    stamp: u32,
}

/// A Dijkstra queue entry, ordered so that `BinaryHeap` pops the cheapest first and, among equal
/// costs, the lowest index (which keeps the search deterministic).
#[derive(Clone, Copy, Debug, PartialEq)]
struct Entry {
    cost: f64,
    index: usize,
}

impl Eq for Entry {}

impl Entry {
    /// (cost, index) as one integer in their order: the cost's bits as `f64::total_cmp` orders
    /// them (the sign bit flipped, the rest too for a negative cost), then the index — one
    /// comparison where [`Entry::cmp`] takes two and a float's bit twiddling each time.
    fn key(&self) -> u128 {
        let bits = self.cost.to_bits();
        let ordered = if bits >> 63 == 0 {
            bits | 1 << 63
        } else {
            !bits
        };
        u128::from(ordered) << 64 | self.index as u128
    }

    /// The entry whose [`Entry::key`] `key` is (the same bits).
    fn of_key(key: u128) -> Entry {
        let ordered = (key >> 64) as u64;
        let bits = if ordered >> 63 == 1 {
            ordered & !(1 << 63)
        } else {
            !ordered
        };
        Entry {
            cost: f64::from_bits(bits),
            index: key as u64 as usize,
        }
    }
}

impl Ord for Entry {
    fn cmp(&self, other: &Self) -> Ordering {
        other
            .cost
            .total_cmp(&self.cost)
            .then_with(|| other.index.cmp(&self.index))
    }
}

impl PartialOrd for Entry {
    fn partial_cmp(&self, other: &Self) -> Option<Ordering> {
        Some(self.cmp(other))
    }
}

/// An A* queue entry: an [`Entry`] of cost so far plus estimate, popped in its order, and the
/// cost so far, which tells a stale entry without the estimate.
#[derive(Clone, Copy, Debug)]
struct Guided {
    entry: Entry,
    g: f64,
}

impl PartialEq for Guided {
    fn eq(&self, other: &Self) -> bool {
        self.entry == other.entry
    }
}

impl Eq for Guided {}

impl Ord for Guided {
    fn cmp(&self, other: &Self) -> Ordering {
        self.entry.cmp(&other.entry)
    }
}

impl PartialOrd for Guided {
    fn partial_cmp(&self, other: &Self) -> Option<Ordering> {
        Some(self.cmp(other))
    }
}

/// Per set of free neighbours (bit k: the cell [`MOVES`]`[k]` away is free), the moves they
/// allow (bit k: move k) — [`moves`]' rule: into a free cell, a diagonal only between two free
/// orthogonal neighbours.
const ALLOWED: [u8; 256] = {
    let mut table = [0u8; 256];
    let mut open = 0;
    while open < 256 {
        let mut k = 0;
        while k < 8 {
            let (dx, dy) = MOVES[k];
            let free = is_open(open, (dx, dy));
            if free && (dx == 0 || dy == 0 || (is_open(open, (dx, 0)) && is_open(open, (0, dy)))) {
                table[open] |= 1 << k;
            }
            k += 1;
        }
        open += 1;
    }
    table
};

/// Whether the neighbour `m` away is free in the set `open` ([`ALLOWED`]'s bits).
const fn is_open(open: usize, m: (i32, i32)) -> bool {
    let mut j = 0;
    while j < 8 && !(MOVES[j].0 == m.0 && MOVES[j].1 == m.1) {
        j += 1;
    }
    j < 8 && open >> j & 1 == 1
}

/// The moves allowed out of `c`: into free cells, 8-connected, diagonals only between two free
/// orthogonal neighbours. Returns (neighbour, step cost). The rule, cell by cell: the search
/// reads it from the grid's cells over its window, and its property tests hold it to this.
fn moves(g: &Grid, c: Cell) -> impl Iterator<Item = (Cell, f64)> + '_ {
    let free = move |x: i32, y: i32| g.get(Cell::new(x, y)) == Occ::Free;
    MOVES.iter().filter_map(move |&(dx, dy)| {
        let n = Cell::new(c.x + dx, c.y + dy);
        if !free(n.x, n.y) {
            return None;
        }
        if dx != 0 && dy != 0 {
            (free(c.x + dx, c.y) && free(c.x, c.y + dy)).then_some((n, std::f64::consts::SQRT_2))
        } else {
            Some((n, 1.0))
        }
    })
}

/// Dijkstra from `start` over the free cells of `g` (8-connected, step costs 1 and √2, no corner
/// cutting). The start cell itself is traversable whatever its value — the robot stands on it —
/// but every other cell on a path is free. A start outside the grid reaches nothing.
pub fn costs(g: &Grid, start: Cell) -> CostMap {
    costs_with(g, start, None)
}

/// The penalty of being near obstacles (thesis §4.4.1: the planning map smoothed with a Gaussian
/// kernel, so that robots are punished for moving close to objects or through narrow corridors):
/// per cell, the occupied indicator blurred with a Gaussian of `sigma` cells (radius 3σ, a
/// separable filter), scaled by `weight`. A step into a cell costs (1 + penalty) times its length.
pub fn obstacle_penalty(g: &Grid, sigma: f64, weight: f64) -> Vec<f32> {
    let (w, h) = (g.width() as usize, g.height() as usize);
    if sigma <= 0.0 || weight <= 0.0 || w == 0 || h == 0 {
        return vec![0.0; g.len()];
    }
    let r = (3.0 * sigma).ceil() as isize;
    let kernel: Vec<f64> = (-r..=r)
        .map(|i| (-(i * i) as f64 / (2.0 * sigma * sigma)).exp())
        .collect();
    let sum: f64 = kernel.iter().sum();
    let kernel: Vec<f64> = kernel.iter().map(|k| k / sum).collect();
    let occ: Vec<f64> = g
        .cells()
        .iter()
        .map(|&c| if c == Occ::Occupied { 1.0 } else { 0.0 })
        .collect();
    let blur = |src: &[f64], horizontal: bool| -> Vec<f64> {
        let mut out = vec![0.0; src.len()];
        for y in 0..h {
            for x in 0..w {
                let mut acc = 0.0;
                for (k, kv) in kernel.iter().enumerate() {
                    let o = k as isize - r;
                    let (sx, sy) = if horizontal {
                        (x as isize + o, y as isize)
                    } else {
                        (x as isize, y as isize + o)
                    };
                    if sx >= 0 && sy >= 0 && (sx as usize) < w && (sy as usize) < h {
                        acc += kv * src[sy as usize * w + sx as usize];
                    }
                }
                out[y * w + x] = acc;
            }
        }
        out
    };
    let smooth = blur(&blur(&occ, true), false);
    smooth.iter().map(|&v| (v * weight) as f32).collect()
}

/// [`costs`] with a per-cell penalty ([`obstacle_penalty`]; `None`: none).
pub fn costs_with(g: &Grid, start: Cell, penalty: Option<&[f32]>) -> CostMap {
    let mut map = CostMap::default();
    dijkstra(&mut map, g, &[start], penalty, &mut Stop::Never);
    map
}

/// [`costs_with`] into `map`, in the buffers it has: a robot searches every step, and a new
/// map over a campus-sized known part is megabytes to allocate and touch each time.
pub fn costs_into(map: &mut CostMap, g: &Grid, start: Cell, penalty: Option<&[f32]>) {
    dijkstra(map, g, &[start], penalty, &mut Stop::Never);
}

/// [`costs_into`] that stops once every frontier cell of the planning grid (`frontiers`, kept with
/// it; `g` may be that grid or one with more cells blocked) is settled: what a strategy that looks
/// at the frontiers' costs alone needs, without settling the cells beyond the farthest frontier.
/// The cost of every frontier, the path to it and [`FrontierCells::reachable`] are [`costs_with`]'s
/// (Dijkstra settles cells in the same order up to there, and a settled cell's cost and predecessor
/// never change); costlier cells read as unreachable. When some frontier is not reachable the
/// search runs out by itself and the map is complete.
pub fn costs_to_frontiers(
    map: &mut CostMap,
    g: &Grid,
    start: Cell,
    penalty: Option<&[f32]>,
    frontiers: &FrontierCells,
) {
    let mut stop = Stop::Frontiers {
        of: frontiers,
        left: frontiers.len(),
    };
    dijkstra(map, g, &[start], penalty, &mut stop);
}

/// The path [`path_to`] finds to `target` after a full search from `start` ([`costs_with`]) —
/// the same cells, `None` when `target` is unreachable — searched by A* into `map`'s buffers:
/// a robot that keeps its target needs only the way there, and A* settles the cells that may lie
/// on a cheapest path (cost so far plus the straight-line estimate of the rest not beyond the
/// target's cost) rather than every cell cheaper than the target.
///
/// The same cells, not merely a path as cheap: equal-cost paths abound on a grid, and which
/// one Dijkstra's predecessors follow decides where the robot goes. Dijkstra settles cells by
/// (cost, index) and keeps the first predecessor that gives a cell its final cost, so a cell's
/// predecessor is, among the neighbours whose cost plus the step is exactly the cell's cost, the
/// one with the lowest (cost, index) — a rule of the final costs alone ([`traced`]). A* finds
/// those costs for every cell that can be such a neighbour of a cell on a cheapest path (all of
/// them have cost plus estimate within the target's cost, and it settles all of those), so the
/// rule, followed back from the target, gives Dijkstra's path. `map` holds no costs afterwards
/// ([`CostMap::cost`] is `None` everywhere): only its buffers are kept.
pub fn path_until(
    map: &mut CostMap,
    g: &Grid,
    start: Cell,
    penalty: Option<&[f32]>,
    target: Cell,
) -> Option<Vec<Cell>> {
    let reached = astar(map, g, start, penalty, target);
    let path = reached.then(|| traced(map, g, penalty, target)).flatten();
    map.limit = f64::NEG_INFINITY;
    path
}

/// [`path_until`] — the same cells, `None` alike — helped by a way to `target` that may still
/// hold (`way`, e.g. the one found a step before from a cell this way passes through): when
/// `start` lies on it and the rest of it is still a way over `g`, that rest's cost bounds the
/// target's, and a Dijkstra from `start` that leaves out every cell whose cost plus estimate
/// exceeds the bound, stopping once it settles the target, finds what the A* finds with a
/// bucket queue instead of a heap. Every cell on a cheapest path has cost plus estimate below
/// the target's cost, so none is left out and each is settled with its final cost before the
/// target: [`traced`] follows the same predecessors. Without such a way, or when the target is
/// not within the bound (the way is not the robot's any more), [`path_until`].
pub fn path_along(
    map: &mut CostMap,
    g: &Grid,
    start: Cell,
    penalty: Option<&[f32]>,
    target: Cell,
    way: &[Cell],
) -> Option<Vec<Cell>> {
    let rest = way.iter().position(|&c| c == start).map(|i| &way[i..]);
    let bound = rest
        .filter(|rest| rest.len() > 1 && rest.last() == Some(&target))
        .and_then(|rest| way_cost(g, penalty, rest));
    bound
        .and_then(|bound| bounded(map, g, start, penalty, target, bound))
        .or_else(|| path_until(map, g, start, penalty, target))
}

/// The path [`path_until`] finds when the target's cost is within `bound`, by the bounded
/// search of [`path_along`]; `None` when it is not (or the target is unreachable).
fn bounded(
    map: &mut CostMap,
    g: &Grid,
    start: Cell,
    penalty: Option<&[f32]>,
    target: Cell,
    bound: f64,
) -> Option<Vec<Cell>> {
    let mut stop = Stop::Within {
        target,
        bound,
        toward: None,
    };
    dijkstra(map, g, &[start], penalty, &mut stop);
    let reached = map.index(target).is_some_and(|t| map.dist_at(t) <= bound);
    let path = reached.then(|| traced(map, g, penalty, target)).flatten();
    map.limit = f64::NEG_INFINITY;
    path
}

/// The cost of going along `way` over `g` from its first cell, summed step by step as a search
/// sums it; `None` when a step of it is not a move over `g` (into a free cell, a diagonal
/// between two free cells).
fn way_cost(g: &Grid, penalty: Option<&[f32]>, way: &[Cell]) -> Option<f64> {
    way.windows(2).try_fold(0.0, |cost, pair| {
        let (_, length) = moves(g, pair[0]).find(|&(n, _)| n == pair[1])?;
        Some(cost + length * factor(penalty, g.index(pair[1])?))
    })
}

/// What a step into grid index `i` costs per cell of length: 1 plus the cell's penalty.
fn factor(penalty: Option<&[f32]>, i: usize) -> f64 {
    let extra = (penalty.and_then(|p| p.get(i))).map_or(0.0, |&p| f64::from(p));
    1.0 + extra
}

/// The estimate of the cost left from a window cell to a target: the octile distance (a lower
/// bound of a path's cost on the 8-connected grid with steps 1 and √2 when no step costs less
/// than its length), shrunk by a millionth so that float rounding never makes it exceed the
/// cost left — and so that a cell on a cheapest path has cost plus estimate below the
/// target's cost by a margin no rounding closes; with a negative penalty somewhere, none (0:
/// A* is then a Dijkstra, and the bounded search bounds the cost alone).
#[derive(Clone, Copy, Debug)]
struct Octile {
    w: usize,
    tx: usize,
    ty: usize,
    guided: bool,
}

impl Octile {
    /// Toward window index `t` of `map` (begun).
    fn to(map: &CostMap, t: usize, penalty: Option<&[f32]>) -> Octile {
        let w = map.width as usize;
        let guided = penalty.is_none_or(|p| p.iter().all(|&v| v >= 0.0));
        Octile {
            w,
            tx: t % w,
            ty: t / w,
            guided,
        }
    }

    fn estimate(&self, i: usize) -> f64 {
        self.estimate_at((i % self.w, i / self.w))
    }

    /// [`Octile::estimate`] of the window cell at `(x, y)`.
    fn estimate_at(&self, (x, y): (usize, usize)) -> f64 {
        // Window coordinates fit in u32 (`CostMap::width`, `height`): from there to f64 is one
        // instruction, from usize several.
        let (dx, dy) = (
            f64::from((x as u32).abs_diff(self.tx as u32)),
            f64::from((y as u32).abs_diff(self.ty as u32)),
        );
        let octile = dx.max(dy) + (std::f64::consts::SQRT_2 - 1.0) * dx.min(dy);
        if self.guided {
            octile * (1.0 - 1e-6)
        } else {
            0.0
        }
    }
}

/// A* from `start` over `g` until every cell whose cost plus estimate is within `target`'s
/// cost is settled; whether `target` was reached. The estimate is [`Octile`]'s.
fn astar(map: &mut CostMap, g: &Grid, start: Cell, penalty: Option<&[f32]>, target: Cell) -> bool {
    map.begin(g, &[start]);
    let (Some(s), Some(t)) = (map.index(start), map.index(target)) else {
        return false;
    };
    let octile = Octile::to(map, t, penalty);
    let mut heap = std::mem::take(&mut map.guided);
    heap.clear();
    map.reach(s, 0.0, NO_PRED);
    heap.push(Guided {
        entry: Entry {
            cost: octile.estimate(s),
            index: s,
        },
        g: 0.0,
    });
    let moves = Moves::new(map, g, penalty);
    let mut found = false;
    while let Some(Guided { entry, g: so_far }) = heap.pop() {
        let Entry { cost, index } = entry;
        if so_far > map.dist_at(index) {
            continue; // a cheaper way to it came later
        }
        if found && cost > map.dist_at(t) {
            break;
        }
        found |= index == t;
        moves.each(index, |ni, at, step| {
            let next = so_far + step;
            if next < map.dist_at(ni) {
                map.reach(ni, next, index as u32);
                heap.push(Guided {
                    entry: Entry {
                        cost: next + octile.estimate_at(at),
                        index: ni,
                    },
                    g: next,
                });
            }
        });
    }
    map.guided = heap;
    found
}

/// The path to window index of `target` by Dijkstra's predecessor rule over `map`'s final
/// costs ([`path_until`]): back from the target, each cell's predecessor is the neighbour a
/// move into it comes from whose cost plus the step is exactly its cost, the lowest by
/// (cost, index).
fn traced(map: &CostMap, g: &Grid, penalty: Option<&[f32]>, target: Cell) -> Option<Vec<Cell>> {
    let moves = Moves::new(map, g, penalty);
    let (w, h) = (map.width as isize, map.height as isize);
    let mut i = map.index(target)?;
    let mut path = vec![target];
    for _ in 0..map.cells.len() {
        if map.cell_of(i) == map.start {
            path.reverse();
            return Some(path);
        }
        let (cost, factor) = (map.dist_at(i), moves.factor(moves.in_grid(i)));
        let (x, y) = ((i % w as usize) as isize, (i / w as usize) as isize);
        let mut best: Option<(f64, usize)> = None;
        for &(_, _, (dx, dy), length) in &moves.offsets {
            let (nx, ny) = (x - dx, y - dy);
            if nx < 0 || ny < 0 || nx >= w || ny >= h {
                continue;
            }
            let n = (ny * w + nx) as usize;
            let from = map.dist_at(n);
            if !from.is_finite() || from + length * factor != cost {
                continue;
            }
            // A diagonal from `n` into `i` passes between the cells beside `i` toward `n`.
            let diagonal = dx != 0 && dy != 0;
            if diagonal && !(moves.is_free(i, (-dx, 0)) && moves.is_free(i, (0, -dy))) {
                continue;
            }
            if best.is_none_or(|(c, j)| from < c || (from == c && n < j)) {
                best = Some((from, n));
            }
        }
        i = best?.1;
        path.push(map.cell_of(i));
    }
    None
}

/// The cost of reaching every cell from the nearest of `sources` (a multi-source Dijkstra, no
/// penalty): e.g. the distance of every cell to the nearest frontier. Sources outside the grid
/// are left out; [`CostMap::start`] is the first source (a path leads to the nearest source
/// only through [`path_to`] from it, so do not ask for paths).
pub fn costs_from(g: &Grid, sources: &[Cell]) -> CostMap {
    let mut map = CostMap::default();
    dijkstra(&mut map, g, sources, None, &mut Stop::Never);
    map
}

/// When a search may stop.
enum Stop<'a> {
    /// When it runs out.
    Never,
    /// Once the last `left` frontier cells `of` are settled.
    Frontiers { of: &'a FrontierCells, left: usize },
    /// Once every cell that [`nearest`] could prefer among the cells `wanted` (by grid index)
    /// is settled: when a cell costlier by [`nearest`]'s key than the first wanted one comes
    /// up. The wanted cells settled go to `found`.
    Nearest {
        wanted: &'a dyn Fn(usize) -> bool,
        key: Option<i64>,
        found: &'a mut Vec<usize>,
    },
    /// Once `target` is settled, leaving out every cell whose cost plus estimate toward it
    /// (`toward`, set when the search begins) exceeds `bound` ([`path_along`]).
    Within {
        target: Cell,
        bound: f64,
        toward: Option<(Octile, usize)>,
    },
}

impl Stop<'_> {
    /// The search began over `map`'s window.
    fn begin(&mut self, map: &CostMap, penalty: Option<&[f32]>) {
        if let Stop::Within { target, toward, .. } = self {
            // A target off the window (never reached) leaves every cell out.
            *toward = map.index(*target).map(|t| (Octile::to(map, t, penalty), t));
        }
    }

    /// Whether the search takes in the window cell at `at` reached at `cost`.
    fn admits(&self, at: (usize, usize), cost: f64) -> bool {
        match self {
            Stop::Within { bound, toward, .. } => {
                toward.is_some_and(|(o, _)| cost + o.estimate_at(at) <= *bound)
            }
            _ => true,
        }
    }

    /// Whether the search stops now that it settled a cell (`window`: its index in the search's
    /// window; `here` works out its index in the grid, which only some stops read) at `cost`.
    fn settled(&mut self, window: usize, here: impl Fn() -> usize, cost: f64) -> bool {
        match self {
            Stop::Never => false,
            Stop::Frontiers { of, left } => {
                if of.holds(here()) {
                    *left = left.saturating_sub(1);
                }
                *left == 0
            }
            Stop::Within { toward, .. } => toward.is_some_and(|(_, t)| t == window),
            Stop::Nearest { wanted, key, found } => {
                if key.is_some_and(|first| tie_key(cost) > first) {
                    return true;
                }
                let here = here();
                if wanted(here) {
                    key.get_or_insert_with(|| tie_key(cost));
                    found.push(here);
                }
                false
            }
        }
    }
}

/// The search runs over a window of the grid — its known part and the sources — and costs in
/// proportion to the cells it reaches, not to the map or the window: every free cell is inside
/// the known part, a path steps only onto free cells, and the buffers are stamped, not cleared
/// ([`CostMap::cells`]). Window indices are row-major like the grid's, so the order in which
/// equal costs are settled is the grid's.
fn dijkstra(
    map: &mut CostMap,
    g: &Grid,
    sources: &[Cell],
    penalty: Option<&[f32]>,
    until: &mut Stop<'_>,
) {
    map.begin(g, sources);
    until.begin(map, penalty);
    let mut queue = std::mem::take(&mut map.queue);
    queue.reset(penalty.is_none());
    for &c in sources {
        if let Some(s) = map.index(c) {
            map.reach(s, 0.0, NO_PRED);
            queue.push(Entry {
                cost: 0.0,
                index: s,
            });
        }
    }
    let moves = Moves::new(map, g, penalty);
    while let Some(Entry { cost, index }) = queue.pop() {
        if cost > map.dist_at(index) {
            continue;
        }
        if until.settled(index, || moves.in_grid(index), cost) {
            // Every cell cheaper than this one is settled; one as cheap that is not yet has
            // its final cost already (it can only be lowered by a cheaper cell), so the limit
            // may include this cost.
            map.limit = cost;
            break;
        }
        moves.each(index, |ni, at, step| {
            let next = cost + step;
            if next < map.dist_at(ni) && until.admits(at, next) {
                map.reach(ni, next, index as u32);
                queue.push(Entry {
                    cost: next,
                    index: ni,
                });
            }
        });
    }
    map.queue = queue;
}

/// [`Buckets`] per unit of cost: a bucket is no wider than the cheapest step (1).
const PER_UNIT: f64 = 4.0;
/// [`Buckets`]' ring: the bucket being taken and those up to √2 + a bucket's width above it.
const RING: usize = 8;

/// Dijkstra's queue: entries come out by (cost, index), exactly as from a `BinaryHeap` of
/// [`Entry`], but kept in buckets of a quarter unit of cost ([`PER_UNIT`]). Without a penalty
/// every step costs 1 or √2, so an entry pushed while the bucket of costs in [k/4, (k + 1)/4)
/// is being taken lands in bucket k + 4 to k + 6: the bucket is complete when its turn comes and
/// is sorted once, taking it costs its sort rather than a heap's sifting per entry, and
/// [`RING`] buckets in a ring hold everything queued. (Narrower buckets sort less and are
/// switched more often: a quarter executed the fewest instructions in the campus benchmark,
/// docs/benchmarks.md.) With a penalty (steps of any length) a `BinaryHeap`.
#[derive(Clone, Debug)]
struct Buckets {
    unit: bool,
    /// Bucket k (costs in [k/4, (k + 1)/4)) at `ring[k % RING]`, its entries as their keys
    /// ([`Entry::key`]), which sort as the entries do.
    ring: [Vec<u128>; RING],
    /// The bucket being taken, whether it is sorted, and the entries queued in all.
    current: usize,
    sorted: bool,
    len: usize,
    heap: BinaryHeap<Entry>,
}

impl Default for Buckets {
    fn default() -> Buckets {
        Buckets {
            unit: false,
            ring: std::array::from_fn(|_| Vec::new()),
            current: 0,
            sorted: false,
            len: 0,
            heap: BinaryHeap::new(),
        }
    }
}

impl Buckets {
    /// Empty, for steps of 1 and √2 (`unit`) or of any length.
    fn reset(&mut self, unit: bool) {
        self.ring.iter_mut().for_each(Vec::clear);
        (self.unit, self.current, self.sorted, self.len) = (unit, 0, false, 0);
        self.heap.clear();
    }

    /// Queues `e`: into its bucket while every step costs 1 or √2 after the last entry taken
    /// (a few instructions, inlined into the search), else into the heap.
    #[inline]
    fn push(&mut self, e: Entry) {
        // Through u32, which is cheaper to convert to and far above any bucket held (a
        // cost beyond it, as beyond the ring, goes to the heap).
        let k = (e.cost * PER_UNIT) as u32 as usize;
        let taken = k < self.current || (k == self.current && self.sorted);
        if self.unit && !taken && k < self.current + RING {
            self.ring[k % RING].push(e.key());
            self.len += 1;
        } else {
            self.push_heap(e);
        }
    }

    /// [`Buckets::push`] into the heap. The first entry that is not a step of 1 or √2 after the
    /// last one taken moves every bucket into the heap, which keeps the order from there on.
    #[inline(never)]
    fn push_heap(&mut self, e: Entry) {
        if self.unit {
            self.unit = false;
            self.heap.extend(
                self.ring
                    .iter_mut()
                    .flat_map(|b| b.drain(..))
                    .map(Entry::of_key),
            );
        }
        self.heap.push(e);
    }

    fn pop(&mut self) -> Option<Entry> {
        if !self.unit {
            return self.heap.pop();
        }
        while self.len > 0 {
            let b = &mut self.ring[self.current % RING];
            if !self.sorted {
                // The cheapest last: take from the back.
                b.sort_unstable_by(|x, y| y.cmp(x));
                self.sorted = true;
            }
            if let Some(key) = b.pop() {
                self.len -= 1;
                return Some(Entry::of_key(key));
            }
            self.current += 1;
            self.sorted = false;
        }
        None
    }
}

/// The moves of a search's window ([`CostMap`]'s) over the grid's cells, read cell by cell:
/// into free cells, diagonals only between two free orthogonal neighbours, each step costing
/// its length times (1 + the penalty of the cell stepped into) — [`moves`]' rule.
struct Moves<'a> {
    cells: &'a [Occ],
    penalty: Option<&'a [f32]>,
    /// The window's corner in the grid, its size and the grid's width.
    x0: usize,
    y0: usize,
    w: usize,
    h: usize,
    gw: usize,
    offsets: [MoveOffsets; 8],
}

impl<'a> Moves<'a> {
    fn new(map: &CostMap, g: &'a Grid, penalty: Option<&'a [f32]>) -> Moves<'a> {
        Moves {
            cells: g.cells(),
            penalty,
            x0: map.x0 as usize,
            y0: map.y0 as usize,
            w: map.width as usize,
            h: map.height as usize,
            gw: g.width() as usize,
            offsets: move_offsets(map.width, g.width()),
        }
    }

    /// Where window index `index` lies ([`Place`]).
    fn place(&self, index: usize) -> Place {
        let (x, y) = (index % self.w, index / self.w);
        Place {
            x,
            y,
            here: (self.y0 + y) * self.gw + self.x0 + x,
            inner: x > 0 && y > 0 && x + 1 < self.w && y + 1 < self.h,
        }
    }

    /// The grid index of window index `index`.
    fn in_grid(&self, index: usize) -> usize {
        self.place(index).here
    }

    /// Whether the cell `(dx, dy)` from window index `index` is free.
    fn is_free(&self, index: usize, (dx, dy): (isize, isize)) -> bool {
        self.is_free_from(&self.place(index), (dx, dy), dy * self.gw as isize + dx)
    }

    /// Whether the cell `(dx, dy)` from the cell at `p` — `grid` away in the grid — is free (a
    /// cell off the window is not: the window holds the known part).
    fn is_free_from(&self, p: &Place, (dx, dy): (isize, isize), grid: isize) -> bool {
        let on = p.inner
            || (p.x.checked_add_signed(dx).is_some_and(|nx| nx < self.w)
                && p.y.checked_add_signed(dy).is_some_and(|ny| ny < self.h));
        on && self.cells[p.here.wrapping_add_signed(grid)] == Occ::Free
    }

    /// `step(neighbour, its (x, y) in the window, cost)` for each move out of window index
    /// `index`, in [`MOVES`]' order — each neighbour read once, the cell's [`Place`] worked
    /// out once, the moves its free neighbours allow looked up ([`ALLOWED`]).
    fn each(&self, index: usize, mut step: impl FnMut(usize, (usize, usize), f64)) {
        let p = self.place(index);
        let mut open = 0u8;
        for (k, &(_, gd, d, _)) in self.offsets.iter().enumerate() {
            open |= u8::from(self.is_free_from(&p, d, gd)) << k;
        }
        let mut allowed = ALLOWED[usize::from(open)];
        while allowed != 0 {
            let k = allowed.trailing_zeros() as usize;
            allowed &= allowed - 1;
            let (d, gd, (dx, dy), length) = self.offsets[k & 7];
            step(
                index.wrapping_add_signed(d),
                (p.x.wrapping_add_signed(dx), p.y.wrapping_add_signed(dy)),
                length * self.factor(p.here.wrapping_add_signed(gd)),
            );
        }
    }

    /// What a step into grid index `i` costs per cell of length ([`factor`]).
    fn factor(&self, i: usize) -> f64 {
        factor(self.penalty, i)
    }
}

/// Where a window cell lies: its (x, y) in the window, its grid index, and whether all eight
/// neighbours are inside the window.
struct Place {
    x: usize,
    y: usize,
    here: usize,
    inner: bool,
}

/// A move's offsets ([`move_offsets`]).
type MoveOffsets = (isize, isize, (isize, isize), f64);

/// Per move of [`MOVES`]: the neighbour's offset in a window `width` cells wide and in the grid
/// (`gw` wide), the move itself and the step's length. (Which moves a cell's free neighbours
/// allow is [`ALLOWED`]'s.)
fn move_offsets(width: u32, gw: u32) -> [MoveOffsets; 8] {
    let (w, gw) = (width as isize, gw as isize);
    MOVES.map(|(dx, dy)| {
        let step = if dx != 0 && dy != 0 {
            std::f64::consts::SQRT_2
        } else {
            1.0
        };
        let (dx, dy) = (dx as isize, dy as isize);
        (dy * w + dx, dy * gw + dx, (dx, dy), step)
    })
}

/// The frontier cells: reachable free cells with at least one unknown 4-neighbour inside the grid,
/// in row-major order (bottom row first). Cells beyond the grid's edge do not count as unknown:
/// the map's extent is known, and nothing lies out there to explore.
pub fn frontiers(g: &Grid, costs: &CostMap) -> Vec<Cell> {
    // Free cells lie in the known part of the grid, found a row at a time.
    let Some(r) = g.known_bounds() else {
        return Vec::new();
    };
    let mut out = Vec::new();
    for y in r.min.y..=r.max.y {
        let row = g.row(y, r.min.x, r.max.x);
        let free = (row.iter().enumerate()).filter(|(_, &c)| c == Occ::Free);
        let cells = free.map(|(i, _)| Cell::new(r.min.x + i as i32, y));
        out.extend(cells.filter(|&c| is_frontier(g, costs, c)));
    }
    out
}

/// The frontier cells of a grid — free cells with an unknown 4-neighbour inside it, reachable
/// or not — kept as the grid changes: whether a cell is one depends on it and its
/// 4-neighbours, so a change re-reads the changed cells and those around them. Listing the
/// reachable ones ([`FrontierCells::reachable`]) then costs the frontier, not the known part.
///
/// **Invariant:** after [`FrontierCells::update`] with rectangles holding every cell that
/// changed, the cells held are those [`Grid::is_frontier`] says are.
#[derive(Clone, Debug, Default)]
pub struct FrontierCells {
    /// By (y, x): row-major, as [`frontiers`] lists them.
    cells: BTreeSet<(i32, i32)>,
    /// Per cell of the grid (row-major), whether it is one.
    is: Vec<bool>,
    size: (u32, u32),
}

impl FrontierCells {
    /// `g` after the cells of `changed` changed (and no others; a grid of another size is
    /// read whole).
    pub fn update(&mut self, g: &Grid, changed: &[Rect]) {
        let size = (g.width(), g.height());
        if size != self.size {
            *self = FrontierCells {
                cells: BTreeSet::new(),
                is: vec![false; g.len()],
                size,
            };
            self.reread(g, g.whole());
            return;
        }
        for r in changed {
            self.reread(g, r.grown(1).within(size.0, size.1));
        }
    }

    fn reread(&mut self, g: &Grid, r: Option<Rect>) {
        for c in r.into_iter().flat_map(Rect::cells) {
            let Some(i) = g.index(c) else { continue };
            let now = g.is_frontier(c);
            if now != self.is[i] {
                self.is[i] = now;
                if now {
                    self.cells.insert((c.y, c.x));
                } else {
                    self.cells.remove(&(c.y, c.x));
                }
            }
        }
    }

    /// Whether the cell of grid index `i` is one.
    fn holds(&self, i: usize) -> bool {
        self.is.get(i).copied().unwrap_or(false)
    }

    /// How many there are.
    pub fn len(&self) -> usize {
        self.cells.len()
    }

    pub fn is_empty(&self) -> bool {
        self.cells.is_empty()
    }

    /// [`frontiers`]`(g, costs)` of the grid held: those `costs` reaches, row-major.
    pub fn reachable(&self, costs: &CostMap) -> Vec<Cell> {
        (self.cells.iter())
            .map(|&(y, x)| Cell::new(x, y))
            .filter(|&c| costs.cost(c).is_some())
            .collect()
    }
}

/// Whether `c` is one of [`frontiers`]`(g, costs)`.
pub fn is_frontier(g: &Grid, costs: &CostMap, c: Cell) -> bool {
    g.is_frontier(c) && costs.cost(c).is_some()
}

/// The cheapest frontier, ties broken by `(y, x)` (costs equal to within 10⁻⁶ cells count as
/// ties); `None` when no frontier is reachable.
pub fn nearest_frontier(g: &Grid, costs: &CostMap) -> Option<Cell> {
    nearest(frontiers(g, costs), costs)
}

/// The cheapest reachable cell among `cells`, with [`nearest_frontier`]'s tie-break.
pub fn nearest(cells: impl IntoIterator<Item = Cell>, costs: &CostMap) -> Option<Cell> {
    cells
        .into_iter()
        .filter(|&c| costs.cost(c).is_some())
        .min_by_key(|&c| (tie_key(costs.cost(c).unwrap_or(f64::INFINITY)), c.y, c.x))
}

/// A cost rounded to [`COST_TIE_QUANTUM`]: costs this close are a tie.
fn tie_key(cost: f64) -> i64 {
    (cost / COST_TIE_QUANTUM).round() as i64
}

/// The cells of a cheapest path from the start of `costs` to `target`, both included, following
/// the Dijkstra predecessors; `None` when `target` is unreachable.
pub fn path_to(costs: &CostMap, target: Cell) -> Option<Vec<Cell>> {
    costs.cost(target)?;
    let mut i = costs.index(target)?;
    let mut path = vec![target];
    // The predecessor tree has no cycles; the bound makes that an enforced invariant.
    for _ in 0..costs.width as usize * costs.height as usize {
        let p = costs.cells[i].pred;
        if p == NO_PRED {
            break;
        }
        i = p as usize;
        path.push(costs.cell_of(i));
    }
    path.reverse();
    (path.first() == Some(&costs.start)).then_some(path)
}

/// The farthest cell along `path` within `max_cells` (Euclidean, from the path's first cell) that
/// the robot, standing at `from_m` (metres, in the path's first cell) on `map`, can reach on one
/// straight move to the cell's centre: the cells the move sweeps ([`proto::traverse::swept`],
/// the world-server's own check of a move) are free, the robot's own cell exempt. The world's
/// walk, from where the robot really stands, so the planner never picks a move the world
/// refuses on the same map.
///
/// Only the leading part of the path up to the first cell beyond `max_cells` is considered, so the
/// waypoint never skips a stretch of the path the robot has not reached. When even the path's
/// second cell lies farther than `max_cells` (a diagonal first step, or a step shorter than a
/// cell), that cell: the world clips the move to the step, and the robot covers part of the way
/// (without it a robot whose step is under √2 cells never took a diagonal first move, and one
/// under a cell never moved). `None` when the path has fewer than two cells.
pub fn next_waypoint(
    g: &Grid,
    map: &MapInfo,
    from_m: Metres,
    path: &[Cell],
    max_cells: f64,
) -> Option<Cell> {
    let (&first, rest) = path.split_first()?;
    let &second = rest.first()?;
    if second.dist(first) > max_cells {
        return Some(second);
    }
    let from = map.in_cells(from_m);
    let reach = rest.iter().take_while(|&&c| {
        let (dx, dy) = (f64::from(c.x - first.x), f64::from(c.y - first.y));
        dx.hypot(dy) <= max_cells
    });
    let candidates: Vec<Cell> = reach.copied().collect();
    // The waypoint crosses the wire in metres: check the move the world will check, to the
    // centre as the world converts it back (at a corner crossing the last bit decides).
    candidates
        .into_iter()
        .rev()
        .find(|&c| move_is_free(g, from, map.in_cells(map.centre_of(c)), first))
}

/// Whether a straight move from `from` to `to` (cell units) sweeps only free cells of `g`
/// ([`proto::traverse::swept`], the world-server's check of a move), the robot's own cell
/// `exempt`. The one test of a move every planner and strategy applies.
pub fn move_is_free(g: &Grid, from: (f64, f64), to: (f64, f64), exempt: Cell) -> bool {
    swept(from, to)
        .into_iter()
        .all(|s| s == exempt || g.get(s) == Occ::Free)
}

/// Where a robot that must give way goes (robots are discs to each other, and a narrow passage
/// holds only one): the cheapest cell, reachable from `me` without coming within `clearance`
/// cells of `other`, that keeps at least `clearance` cells from the other robot's way — its
/// path over `g` to `their_target` when that is known and reachable, else the straight line
/// from `other` through `me` and on for [`GIVE_WAY_LINE_CELLS`] (it was coming this way).
/// Returns the path to that cell on the grid with the other robot's disc blocked, starting at
/// `me` (a single cell when `me` is already clear); `None` when no cell is clear. The other's
/// way is searched by A* ([`path_until`]) and the search from `me` stops once no cheaper clear
/// cell can come: both are the full searches' answers, at the cost of the way and the way aside.
pub fn give_way(
    g: &Grid,
    me: Cell,
    other: Cell,
    their_target: Option<Cell>,
    clearance: f64,
) -> Option<(Grid, Vec<Cell>)> {
    let mut search = CostMap::default();
    let their_way = their_target.and_then(|t| path_until(&mut search, g, other, None, t));
    let way: Vec<Cell> = match their_way {
        Some(path) => path,
        None => {
            let dx = f64::from(me.x) - f64::from(other.x);
            let dy = f64::from(me.y) - f64::from(other.y);
            let len = dx.hypot(dy).max(1.0);
            // Half-cell steps; no line on the grid is longer than its width plus its height, so
            // the cap changes nothing there and keeps a robot reported far off the map (a bad
            // scan) from walking a line of billions of cells.
            let most = f64::from(g.width()) + f64::from(g.height()) + GIVE_WAY_LINE_CELLS;
            let steps = ((len + GIVE_WAY_LINE_CELLS).min(most) * 2.0).ceil() as i32;
            (0..=steps)
                .map(|k| {
                    let t = f64::from(k) * 0.5 / len;
                    let x = f64::from(other.x) + dx * t;
                    let y = f64::from(other.y) + dy * t;
                    Cell::new(x.round() as i32, y.round() as i32)
                })
                .collect()
        }
    };
    // Both ways start at `other`.
    let mut in_the_way: Vec<usize> = (way.iter())
        .flat_map(|&at| disc(g, at, clearance))
        .filter_map(|c| g.index(c))
        .collect();
    in_the_way.sort_unstable();
    in_the_way.dedup();
    let blocked = around(g, me, other, clearance);
    let me_at = g.index(me);
    let clear = |i: usize| {
        (g.cells()[i] == Occ::Free || Some(i) == me_at) && in_the_way.binary_search(&i).is_err()
    };
    // The search from `me` stops once the nearest clear cell is certain: it costs the way
    // aside, not the known part.
    let mut found = Vec::new();
    let mut stop = Stop::Nearest {
        wanted: &clear,
        key: None,
        found: &mut found,
    };
    dijkstra(&mut search, &blocked, &[me], None, &mut stop);
    let aside = nearest(found.into_iter().map(|i| g.cell_of(i)), &search)?;
    Some((blocked, path_to(&search, aside)?))
}

/// `g` with the robot at `other` in it: the cells nearer than `clearance` to it are occupied,
/// except `me` (for planning around another robot).
pub fn around(g: &Grid, me: Cell, other: Cell, clearance: f64) -> Grid {
    let mut blocked = g.clone();
    for c in disc(g, other, clearance) {
        if c != me {
            blocked.set(c, Occ::Occupied);
        }
    }
    blocked
}

/// The cells of `g` whose centres lie nearer than `radius` cells to the centre of `at`.
fn disc(g: &Grid, at: Cell, radius: f64) -> impl Iterator<Item = Cell> + '_ {
    let r = radius.ceil() as i32;
    (-r..=r)
        .flat_map(move |dy| (-r..=r).map(move |dx| Cell::new(at.x + dx, at.y + dy)))
        .filter(move |&c| {
            let (dx, dy) = (f64::from(c.x - at.x), f64::from(c.y - at.y));
            g.contains(c) && dx.hypot(dy) < radius
        })
}

/// How far beyond the giving-way robot the other robot's way is assumed to go when its target
/// is not known ([`give_way`]).
pub const GIVE_WAY_LINE_CELLS: f64 = 10.0;

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    #[test]
    fn the_moves_a_set_of_free_neighbours_allows_are_the_rule_s() {
        // Every one of the 256 neighbourhoods of a free cell, the neighbours free by the bits.
        for (open, allowed) in ALLOWED.iter().enumerate() {
            let mut g = Grid::new(3, 3, Occ::Occupied);
            g.set(Cell::new(1, 1), Occ::Free);
            for (k, &(dx, dy)) in MOVES.iter().enumerate() {
                if open >> k & 1 == 1 {
                    g.set(Cell::new(1 + dx, 1 + dy), Occ::Free);
                }
            }
            let by_rule: Vec<Cell> = moves(&g, Cell::new(1, 1)).map(|(n, _)| n).collect();
            let by_table: Vec<Cell> = (MOVES.iter().enumerate())
                .filter(|(k, _)| allowed >> k & 1 == 1)
                .map(|(_, &(dx, dy))| Cell::new(1 + dx, 1 + dy))
                .collect();
            assert_eq!(by_table, by_rule, "free neighbours {open:08b}");
        }
    }

    #[test]
    fn the_obstacle_penalty_keeps_paths_off_walls() {
        // A wide corridor with a wall along its bottom: with the penalty, the path from left to
        // right runs along the middle rather than hugging the wall.
        let g = Grid::from_ascii(
            "\
############
#..........#
#..........#
#..........#
#..........#
#..........#
############
",
        );
        let p = obstacle_penalty(&g, 1.0, 5.0);
        let mid = p[3 * 12 + 5];
        let edge = p[12 + 5];
        assert!(edge > mid && mid >= 0.0, "edge {edge} mid {mid}");
        let (a, b) = (Cell::new(1, 1), Cell::new(10, 1));
        let plain = path_to(&costs(&g, a), b).unwrap_or_default();
        let careful = path_to(&costs_with(&g, a, Some(&p)), b).unwrap_or_default();
        let max_y = |path: &[Cell]| path.iter().map(|c| c.y).max().unwrap_or(0);
        assert_eq!(
            max_y(&plain),
            1,
            "the shortest path hugs the wall: {plain:?}"
        );
        assert!(
            max_y(&careful) >= 2,
            "the penalised path moves away: {careful:?}"
        );
        assert_eq!(obstacle_penalty(&g, 0.0, 5.0), vec![0.0; g.len()]);
    }

    /// The cells marked with one of `marks` in an ASCII picture (top line = top row), bottom row
    /// first.
    fn marked(pic: &str, marks: &[char]) -> Vec<Cell> {
        let lines: Vec<&str> = pic
            .lines()
            .map(str::trim)
            .filter(|l| !l.is_empty())
            .collect();
        let h = lines.len() as i32;
        let mut out = Vec::new();
        for (row, line) in lines.iter().enumerate() {
            for (x, ch) in line.chars().enumerate() {
                if marks.contains(&ch) {
                    out.push(Cell::new(x as i32, h - 1 - row as i32));
                }
            }
        }
        out.sort_by_key(|c| (c.y, c.x));
        out
    }

    /// Parses an ASCII map where `S` marks the (free) start cell, `T` a (free) target cell and
    /// `s` an unknown start cell; the other characters are those of [`Grid::from_ascii`].
    fn parse(pic: &str) -> (Grid, Cell, Option<Cell>) {
        let start = marked(pic, &['S', 's'])
            .first()
            .copied()
            .expect("map has a start");
        let target = marked(pic, &['T']).first().copied();
        let plain = pic.replace(['S', 'T'], ".").replace('s', "?");
        (Grid::from_ascii(&plain), start, target)
    }

    /// Compares the costs from `S` with a picture of costs, one token per cell: the cost with one
    /// decimal, or `-` where the cell is unreachable.
    fn check_costs(pic: &str, expected: &str) {
        let (g, start, _) = parse(pic);
        let map = costs(&g, start);
        let mut got = String::new();
        for y in (0..g.height() as i32).rev() {
            let row: Vec<String> = (0..g.width() as i32)
                .map(|x| {
                    map.cost(Cell::new(x, y))
                        .map_or("-".into(), |v| format!("{v:.1}"))
                })
                .collect();
            got.push_str(&row.join(" "));
            got.push('\n');
        }
        let want: Vec<Vec<&str>> = expected
            .lines()
            .map(|l| l.split_whitespace().collect::<Vec<_>>())
            .filter(|l| !l.is_empty())
            .collect();
        let have: Vec<Vec<&str>> = got
            .lines()
            .map(|l| l.split_whitespace().collect())
            .collect();
        assert_eq!(have, want, "costs:\n{got}");
    }

    /// Compares the frontiers (marked `F` in `expected`) and the nearest one (marked `N`).
    fn check_frontiers(pic: &str, expected: &str) {
        let (g, start, _) = parse(pic);
        let map = costs(&g, start);
        assert_eq!(frontiers(&g, &map), marked(expected, &['F', 'N']));
        assert_eq!(
            nearest_frontier(&g, &map),
            marked(expected, &['N']).first().copied()
        );
    }

    /// Plans from `S` to `T` and compares the waypoint within `max_cells` with `W` in `expected`
    /// (no `W`: no waypoint).
    fn check_waypoint(pic: &str, max_cells: f64, expected: &str) {
        let (g, start, target) = parse(pic);
        let map = costs(&g, start);
        let path = path_to(&map, target.expect("map has a target")).expect("target is reachable");
        let want = marked(expected, &['W']).first().copied();
        let info = MapInfo::at_origin(g.width(), g.height(), 1.0);
        let from = info.centre_of(start);
        assert_eq!(
            next_waypoint(&g, &info, from, &path, max_cells),
            want,
            "path {path:?}"
        );
    }

    #[test]
    fn costs_in_an_empty_room() {
        check_costs(
            "....
             ....
             S...",
            "2.0 2.4 2.8 3.8
             1.0 1.4 2.4 3.4
             0.0 1.0 2.0 3.0",
        );
    }

    #[test]
    fn costs_around_a_wall() {
        check_costs(
            ".....
             .###.
             ..S..",
            "4.0 5.0 6.0 5.0 4.0
             3.0 -   -   -   3.0
             2.0 1.0 0.0 1.0 2.0",
        );
    }

    #[test]
    fn corners_are_not_cut() {
        // The diagonal step from S to the upper right needs both orthogonal neighbours free.
        check_costs(
            "?.
             S#",
            "-   -
             0.0 -",
        );
        check_costs(
            "..
             S#",
            "1.0 2.0
             0.0 -",
        );
    }

    #[test]
    fn start_cell_need_not_be_free() {
        check_costs(
            "...
             .s.",
            "1.4 1.0 1.4
             1.0 0.0 1.0",
        );
        let g = Grid::from_ascii("...");
        assert_eq!(
            costs(&g, Cell::new(5, 0)).cost(Cell::new(0, 0)),
            None,
            "start off the grid"
        );
    }

    #[test]
    fn frontier_detection() {
        check_frontiers(
            "??????
             ?..#??
             ?S.#.?
             ......",
            "??????
             ?FF#??
             ?N.#F?
             F....F",
        );
        // Unreachable free cells next to unknown are no frontiers, and the grid's edge is none.
        check_frontiers(
            "..#.?
             S.#..",
            "..#.?
             ..#..",
        );
    }

    #[test]
    fn nearest_frontier_breaks_ties_by_row_then_column() {
        check_frontiers(
            "?.?
             .S.
             ?.?",
            "?F?
             FSF
             ?N?",
        );
    }

    #[test]
    fn unreachable_target_has_no_path() {
        let (g, start, _) = parse(
            "S.#.
             ..#.",
        );
        let map = costs(&g, start);
        assert_eq!(path_to(&map, Cell::new(3, 0)), None);
        assert_eq!(path_to(&map, Cell::new(2, 0)), None, "a wall");
        assert_eq!(path_to(&map, Cell::new(9, 9)), None, "off the grid");
        assert_eq!(path_to(&map, start), Some(vec![start]));
    }

    #[test]
    fn path_goes_around_a_wall() {
        let (g, start, target) = parse(
            "....
             .##.
             S#T.",
        );
        let map = costs(&g, start);
        let path = path_to(&map, target.expect("target")).expect("reachable");
        assert_eq!(path.first(), Some(&start));
        assert_eq!(path.last(), target.as_ref());
        // No diagonal helps: each one would cut a corner of the wall.
        assert_eq!(path.len(), 9);
        assert_eq!(map.cost(Cell::new(2, 0)), Some(8.0));
    }

    #[test]
    fn waypoints() {
        // A straight corridor: as far as the step allows.
        check_waypoint("S.....T", 3.0, "...W...");
        check_waypoint("S.....T", 10.0, "......W");
        // The diagonal first step (√2) does not fit into one cell's move: it is the waypoint
        // all the same (the world clips the move to the step).
        check_waypoint(
            "?.T
             .S.",
            1.2,
            "?.W
             ...",
        );
        check_waypoint("S.....T", 0.5, ".W.....");
        // Around a corner the waypoint stops where the straight segment would cross the wall.
        check_waypoint(
            "###T.
             S....",
            10.0,
            "###..
             ...W.",
        );
    }

    /// Gives way from `S` to a robot at `O` heading for `T` (no `T`: unknown) with a clearance
    /// of 2 cells, and compares where it goes with `A` in `expected` (no `A`: nowhere).
    fn check_give_way(pic: &str, expected: &str) {
        let (g, me, target) = parse(&pic.replace('O', "."));
        let other = marked(pic, &['O'])[0];
        let got = give_way(&g, me, other, target, 2.0).map(|(_, path)| path);
        let want = marked(expected, &['A']).first().copied();
        assert_eq!(
            got.as_ref().and_then(|p| p.last().copied()),
            want,
            "path {got:?}"
        );
    }

    #[test]
    fn giving_way_in_a_corridor() {
        // The other robot comes from the left and goes to T: the niche ahead of it, on its way
        // but off its path, is the nearest place clear of it.
        let niche = "##########.#####
                     ##########.#####
                     ......OS......T.";
        check_give_way(
            niche,
            "##########A#####
             ##########.#####
             ................",
        );
        // Its target unknown: it is assumed to come on through; the same niche.
        check_give_way(
            &niche.replace('T', "."),
            "##########A#####
             ##########.#####
             ................",
        );
        // Its target behind it: one step back keeps the clearance.
        check_give_way("T.....OS........", "T.......A.......");
        // A dead end, and the other robot's way runs to its end: nowhere to go.
        check_give_way("......OS.T", "..........");
        // The niche lies behind the other robot: out of reach past it.
        check_give_way(
            "##.#############
             ##.#############
             ......OS......T.",
            "##.#############
             ##.#############
             ................",
        );
    }

    #[test]
    fn giving_way_to_a_robot_reported_far_off_the_map_walks_no_endless_line() {
        // A bad scan (outside data) can put the other robot billions of cells away: the line
        // of its way stays within what the grid can hold (found by the sim_plane fuzz target,
        // which ran out of memory here).
        let (g, me, _) = parse("......S...");
        for other in [Cell::new(5, -1_000_000_000), Cell::new(i32::MIN, i32::MAX)] {
            let _ = give_way(&g, me, other, None, 2.0);
        }
    }

    fn arb_grid() -> impl Strategy<Value = Grid> {
        (1u32..14, 1u32..14).prop_flat_map(|(w, h)| {
            proptest::collection::vec(0u8..10, (w * h) as usize).prop_map(move |v| {
                let mut g = Grid::new(w, h, Occ::Unknown);
                for (c, b) in g.cells_mut().iter_mut().zip(v) {
                    *c = match b {
                        0..=6 => Occ::Free,
                        7 | 8 => Occ::Occupied,
                        _ => Occ::Unknown,
                    };
                }
                g
            })
        })
    }

    /// A grid (random, open or placed in a bigger one), two cells of it and an obstacle
    /// penalty weight (0: none): what the tests of the way to a target search over.
    fn arb_way_search() -> impl Strategy<Value = (Grid, Cell, Cell, f64)> {
        let grid = prop_oneof![
            arb_grid(),
            arb_open_grid(),
            crate::testutil::arb_placed_grid()
        ];
        let weight = prop_oneof![Just(0.0), Just(2.0), Just(0.37)];
        (grid, (0i32..40, 0i32..40, 0i32..40, 0i32..40), weight).prop_map(
            |(g, (ax, ay, bx, by), w)| {
                let cell = |x: i32, y: i32| Cell::new(x % g.width() as i32, y % g.height() as i32);
                let (a, b) = (cell(ax, ay), cell(bx, by));
                (g, a, b, w)
            },
        )
    }

    /// Grids up to 24 cells a side with few obstacles (one cell in `1/density`): many
    /// equal-cost paths between two cells.
    fn arb_open_grid() -> impl Strategy<Value = Grid> {
        (1u32..24, 1u32..24, 4u32..40).prop_flat_map(|(w, h, density)| {
            proptest::collection::vec(0..density, (w * h) as usize).prop_map(move |v| {
                let mut g = Grid::new(w, h, Occ::Free);
                for (c, b) in g.cells_mut().iter_mut().zip(v) {
                    *c = match b {
                        0 => Occ::Occupied,
                        1 => Occ::Unknown,
                        _ => Occ::Free,
                    };
                }
                g
            })
        })
    }

    /// Costs by Bellman–Ford relaxation, the plain definition Dijkstra must agree with.
    fn reference_costs(g: &Grid, start: Cell) -> Vec<f64> {
        let mut d = vec![f64::INFINITY; g.len()];
        let Some(s) = g.index(start) else { return d };
        d[s] = 0.0;
        for _ in 0..g.len() {
            for i in 0..g.len() {
                for (n, step) in moves(g, g.cell_of(i)) {
                    if let Some(ni) = g.index(n) {
                        d[ni] = d[ni].min(d[i] + step);
                    }
                }
            }
        }
        d
    }

    /// A grid, the robot that gives way, the other robot, the other's target, whether that is
    /// known, and the clearance.
    fn arb_giving_way() -> impl Strategy<Value = (Grid, Cell, Cell, Cell, bool, f64)> {
        let cells = proptest::collection::vec((0i32..14, 0i32..14), 3);
        (arb_grid(), cells, any::<bool>(), 0.5f64..3.0).prop_map(|(g, cells, known, clearance)| {
            let cell = |(x, y): (i32, i32)| Cell::new(x % g.width() as i32, y % g.height() as i32);
            let (me, other, target) = (cell(cells[0]), cell(cells[1]), cell(cells[2]));
            (g, me, other, target, known, clearance)
        })
    }

    proptest! {
        /// An entry's key orders entries as `Entry::cmp` does, reversed (that one is for the
        /// max-heap): by `f64::total_cmp` of the cost — any float, signed zeros and NaNs
        /// included — then by index; and it gives back the entry, bit for bit.
        #[test]
        fn an_entrys_key_orders_as_entries_do(
            a in proptest::num::f64::ANY, b in proptest::num::f64::ANY,
            same in proptest::bool::ANY, i in 0usize..1 << 40, j in 0usize..1 << 40
        ) {
            let b = if same { a } else { b };
            let (x, y) = (Entry { cost: a, index: i }, Entry { cost: b, index: j });
            prop_assert_eq!(x.key().cmp(&y.key()), y.cmp(&x));
            let back = Entry::of_key(x.key());
            prop_assert_eq!((back.cost.to_bits(), back.index), (a.to_bits(), i));
        }

        /// Searched over the explored part of a bigger map only, costs, paths and frontiers
        /// are those of the search over every cell — the robot may stand anywhere, even on an
        /// unknown cell beside the explored part.
        #[test]
        fn the_search_over_the_explored_part_is_the_search_over_every_cell(
            g in crate::testutil::arb_placed_grid(), sx in 0i32..40, sy in 0i32..40
        ) {
            let start = Cell::new(sx % g.width() as i32, sy % g.height() as i32);
            let mut every = g.clone();
            every.cells_mut();
            prop_assert_eq!(every.known_bounds(), every.whole());
            let (part, all) = (costs(&g, start), costs(&every, start));
            for i in 0..g.len() {
                let c = g.cell_of(i);
                prop_assert_eq!(part.cost(c), all.cost(c));
                prop_assert_eq!(path_to(&part, c), path_to(&all, c));
            }
            prop_assert_eq!(frontiers(&g, &part), frontiers(&every, &all));
        }

        /// The search is Dijkstra over [`moves`] (the rule of a move, read cell by cell from the
        /// grid), with or without the obstacle penalty: the same cost for every cell, the same
        /// path to it; and the frontiers are the reachable cells [`Grid::is_frontier`] says are.
        #[test]
        fn the_search_is_dijkstra_over_the_moves_and_its_frontiers_the_grid_s(
            g in crate::testutil::arb_placed_grid(), sx in 0i32..40, sy in 0i32..40, weight in prop_oneof![Just(0.0), Just(2.0)]
        ) {
            let start = Cell::new(sx % g.width() as i32, sy % g.height() as i32);
            let penalty = obstacle_penalty(&g, 1.0, weight);
            let got = costs_with(&g, start, Some(&penalty));
            // The reference: every cell of the grid, settled by (cost, index).
            let mut dist = vec![f64::INFINITY; g.len()];
            let mut pred = vec![NO_PRED; g.len()];
            let mut heap = BinaryHeap::new();
            let s = g.index(start).expect("inside");
            dist[s] = 0.0;
            heap.push(Entry { cost: 0.0, index: s });
            while let Some(Entry { cost, index }) = heap.pop() {
                if cost > dist[index] {
                    continue;
                }
                for (n, step) in moves(&g, g.cell_of(index)) {
                    let ni = g.index(n).expect("free cells are inside");
                    let next = cost + step * (1.0 + f64::from(penalty[ni]));
                    if next < dist[ni] {
                        (dist[ni], pred[ni]) = (next, index as u32);
                        heap.push(Entry { cost: next, index: ni });
                    }
                }
            }
            for (i, &d) in dist.iter().enumerate() {
                let c = g.cell_of(i);
                prop_assert_eq!(got.cost(c), d.is_finite().then_some(d), "{:?}", c);
                let mut way = vec![c];
                while let Some(&p) = pred.get(g.index(*way.last().expect("one")).expect("inside")).filter(|&&p| p != NO_PRED) {
                    way.push(g.cell_of(p as usize));
                }
                way.reverse();
                prop_assert_eq!(path_to(&got, c), d.is_finite().then_some(way), "{:?}", c);
            }
            let cells: Vec<Cell> = (0..g.len()).map(|i| g.cell_of(i))
                .filter(|&c| g.is_frontier(c) && got.cost(c).is_some())
                .collect();
            let mut row_major = cells.clone();
            row_major.sort_by_key(|c| (c.y, c.x));
            prop_assert_eq!(frontiers(&g, &got), row_major);
        }

        /// Kept through any edits, told rectangles holding the cells edited, the frontier
        /// cells are the grid's.
        #[test]
        fn kept_frontier_cells_are_the_grid_s(
            g in arb_grid(),
            edits in proptest::collection::vec(
                (proptest::collection::vec((0i32..14, 0i32..14, 0u8..3), 0..8), 0i32..2), 0..12),
        ) {
            let mut g = g;
            let mut kept = FrontierCells::default();
            kept.update(&g, &[]);
            let every = |g: &Grid| -> Vec<Cell> {
                let mut cells: Vec<Cell> = (0..g.len()).map(|i| g.cell_of(i)).filter(|&c| g.is_frontier(c)).collect();
                cells.sort_by_key(|c| (c.y, c.x));
                cells
            };
            let all = |k: &FrontierCells| k.cells.iter().map(|&(y, x)| Cell::new(x, y)).collect::<Vec<_>>();
            prop_assert_eq!(all(&kept), every(&g));
            for (step, wider) in edits {
                let mut touched = Vec::new();
                for (x, y, v) in step {
                    let c = Cell::new(x % g.width() as i32, y % g.height() as i32);
                    g.set(c, [Occ::Free, Occ::Occupied, Occ::Unknown][usize::from(v)]);
                    touched.push(c);
                }
                let rects: Vec<Rect> = Rect::around(touched).map(|r| r.grown(wider)).into_iter().collect();
                kept.update(&g, &rects);
                prop_assert_eq!(all(&kept), every(&g));
                for i in 0..g.len() {
                    prop_assert_eq!(kept.holds(i), g.is_frontier(g.cell_of(i)));
                }
            }
        }

        /// Stopped once every frontier of the planning grid is settled — searched over that
        /// grid or one with more cells blocked (a detour around robots) — the search gives
        /// every frontier the full search's cost and path, and the same reachable frontiers.
        #[test]
        fn a_search_to_the_frontiers_is_the_full_search_at_the_frontiers(
            g in crate::testutil::arb_placed_grid(), sx in 0i32..40, sy in 0i32..40,
            blocked in proptest::collection::vec((0i32..40, 0i32..40), 0..4),
        ) {
            let start = Cell::new(sx % g.width() as i32, sy % g.height() as i32);
            let mut free = g.clone();
            for (x, y) in blocked {
                free.set(Cell::new(x % g.width() as i32, y % g.height() as i32), Occ::Occupied);
            }
            let mut cells = FrontierCells::default();
            cells.update(&g, &[]);
            let mut to = CostMap::default();
            costs_to_frontiers(&mut to, &free, start, None, &cells);
            let all = costs(&free, start);
            prop_assert_eq!(cells.reachable(&to), frontiers(&g, &all));
            for f in frontiers(&g, &all) {
                prop_assert_eq!(to.cost(f), all.cost(f));
                prop_assert_eq!(path_to(&to, f), path_to(&all, f));
            }
        }

        /// One map searched again and again — over grids of other sizes and windows, from
        /// other starts, all over or for the way to a target — reports what a fresh search
        /// does: what an earlier search reached never shows through the stamps.
        #[test]
        fn a_map_searched_again_is_a_fresh_search(
            searches in proptest::collection::vec(
                (crate::testutil::arb_placed_grid(), 0i32..40, 0i32..40, proptest::option::of((0i32..40, 0i32..40))),
                1..6,
            )
        ) {
            let mut kept = CostMap::default();
            for (g, sx, sy, until) in searches {
                let cell = |x: i32, y: i32| Cell::new(x % g.width() as i32, y % g.height() as i32);
                let start = cell(sx, sy);
                let fresh = costs(&g, start);
                if let Some(t) = until.map(|(x, y)| cell(x, y)) {
                    let path = path_until(&mut kept, &g, start, None, t);
                    prop_assert_eq!(path, path_to(&fresh, t));
                    prop_assert!(!kept.is_complete());
                    prop_assert!((0..g.len()).all(|i| kept.cost(g.cell_of(i)).is_none()));
                    continue;
                }
                costs_into(&mut kept, &g, start, None);
                prop_assert!(kept.is_complete());
                for i in 0..g.len() {
                    let c = g.cell_of(i);
                    prop_assert_eq!(kept.cost(c), fresh.cost(c), "{:?}", c);
                    prop_assert_eq!(path_to(&kept, c), path_to(&fresh, c), "{:?}", c);
                }
            }
        }

        /// Dijkstra's bucket queue gives entries in the heap's order — by cost, then index —
        /// when every entry pushed costs one or √2 more than the last taken, as Dijkstra's
        /// without a penalty do (steps of other lengths hand the queue to a heap).
        #[test]
        fn the_bucket_queue_gives_the_heap_s_order(
            starts in proptest::collection::vec((0u32..100, 0usize..50), 1..6),
            steps in proptest::collection::vec((0usize..4, 0usize..50, 0u8..3), 0..200),
        ) {
            let (mut buckets, mut heap) = (Buckets::default(), BinaryHeap::new());
            buckets.reset(true);
            for (c, index) in starts {
                let e = Entry { cost: f64::from(c) / 100.0, index };
                buckets.push(e);
                heap.push(e);
            }
            for (takes, index, step) in steps {
                let mut last = None;
                for _ in 0..takes {
                    let (b, h) = (buckets.pop(), heap.pop());
                    prop_assert_eq!(b, h);
                    last = b.or(last);
                }
                let Some(last) = last else { continue };
                let length = [1.0, std::f64::consts::SQRT_2, 7.5][usize::from(step)];
                let e = Entry { cost: last.cost + length, index };
                buckets.push(e);
                heap.push(e);
            }
            while let Some(h) = heap.pop() {
                prop_assert_eq!(buckets.pop(), Some(h));
            }
            prop_assert_eq!(buckets.pop(), None);
        }

        /// The way to a kept target by A* is the very path the full search's predecessors
        /// give — not merely one as cheap: on open grids full of equal-cost paths, on mazes,
        /// with and without the obstacle penalty, from any start (even an unknown or occupied
        /// cell) to any target, reachable or not.
        #[test]
        fn the_way_to_a_target_is_the_full_search_s_path(
            (g, start, target, weight) in arb_way_search(),
        ) {
            let penalty = obstacle_penalty(&g, 1.0, weight);
            let penalty = (weight > 0.0).then_some(penalty.as_slice());
            let want = path_to(&costs_with(&g, start, penalty), target);
            let got = path_until(&mut CostMap::default(), &g, start, penalty, target);
            prop_assert_eq!(got, want);
        }

        /// The way to a kept target searched along the way of a step before is the full
        /// search's path as well: from a cell of that way or anywhere else, after cells of the
        /// grid changed (free ones blocked, blocked ones freed), with and without the penalty.
        #[test]
        fn the_way_along_the_last_one_is_the_full_search_s_path(
            (g, earlier, target, weight) in arb_way_search(),
            along in proptest::option::of(0usize..8), sx in 0i32..40, sy in 0i32..40,
            flips in proptest::collection::vec((0i32..40, 0i32..40), 0..4),
        ) {
            let cell = |x: i32, y: i32| Cell::new(x % g.width() as i32, y % g.height() as i32);
            let way = path_to(&costs(&g, earlier), target).unwrap_or_default();
            let mut now = g.clone();
            for &(x, y) in &flips {
                let c = cell(x, y);
                let flipped = if now.get(c) == Occ::Free { Occ::Occupied } else { Occ::Free };
                now.set(c, flipped);
            }
            let start = match along {
                Some(k) if !way.is_empty() => way[k.min(way.len() - 1)],
                _ => cell(sx, sy),
            };
            let penalty = obstacle_penalty(&now, 1.0, weight);
            let penalty = (weight > 0.0).then_some(penalty.as_slice());
            let want = path_to(&costs_with(&now, start, penalty), target);
            let got = path_along(&mut CostMap::default(), &now, start, penalty, target, &way);
            prop_assert_eq!(got, want);
        }

        /// A way still there bounds the search: from a cell along it, over the grid it was
        /// found in, the bounded search alone finds the full search's path (no A* after it).
        #[test]
        fn a_way_still_there_bounds_the_search(
            (g, earlier, target, weight) in arb_way_search(), k in 0usize..8,
        ) {
            let penalty = obstacle_penalty(&g, 1.0, weight);
            let penalty = (weight > 0.0).then_some(penalty.as_slice());
            let way = path_to(&costs_with(&g, earlier, penalty), target);
            prop_assume!(way.as_ref().is_some_and(|w| w.len() > 1));
            let way = way.unwrap_or_default();
            let rest = &way[k.min(way.len() - 2)..];
            let bound = way_cost(&g, penalty, rest);
            prop_assert!(bound.is_some());
            let got = bounded(&mut CostMap::default(), &g, rest[0], penalty, target, bound.unwrap_or(0.0));
            prop_assert_eq!(got, path_to(&costs_with(&g, rest[0], penalty), target));
        }

        /// The planner reaches exactly the cells of the one rule of reachability
        /// ([`Grid::reachable`], the evaluator's reachable area) from a free start.
        #[test]
        fn the_planner_reaches_what_the_one_rule_of_reachability_reaches(
            g in arb_grid(), sx in 0i32..14, sy in 0i32..14
        ) {
            let start = Cell::new(sx % g.width() as i32, sy % g.height() as i32);
            prop_assume!(g.get(start) == Occ::Free);
            let (map, rule) = (costs(&g, start), g.reachable(&[start]));
            for (i, &reached) in rule.iter().enumerate() {
                prop_assert_eq!(map.cost(g.cell_of(i)).is_some(), reached, "{:?}", g.cell_of(i));
            }
        }

        #[test]
        fn dijkstra_agrees_with_relaxation(g in arb_grid(), sx in 0i32..14, sy in 0i32..14) {
            let start = Cell::new(sx % g.width() as i32, sy % g.height() as i32);
            let map = costs(&g, start);
            let want = reference_costs(&g, start);
            for (i, w) in want.iter().enumerate() {
                match map.cost(g.cell_of(i)) {
                    Some(c) => prop_assert!((c - w).abs() < 1e-9),
                    None => prop_assert!(w.is_infinite()),
                }
            }
        }

        /// The planner and the world once walked a move's segment two ways (the world swept closed
        /// squares from where the robot stood, the planner a half-open supercover between cell
        /// centres): the planner could pick a waypoint the world refuses. Now, on the world's own
        /// map, from anywhere in its cell (not only the centre), on maps of any scale and origin,
        /// the robot's waypoint is a move the world-server does not refuse as blocked.
        #[test]
        fn the_world_never_refuses_a_waypoint_the_planner_picks(
            g in arb_grid(),
            sx in 0i32..14, sy in 0i32..14,
            off in (0.01f64..0.99, 0.01f64..0.99),
            pick in any::<prop::sample::Index>(),
            max_cells in 0.5f64..12.0,
            resolution_m in prop::sample::select(vec![0.05, 0.1, 0.192, 0.2, 0.25, 1.0]),
            origin_m in (-20.0f64..20.0, -20.0f64..20.0),
        ) {
            let start = Cell::new(sx % g.width() as i32, sy % g.height() as i32);
            prop_assume!(g.get(start) == Occ::Free);
            let info = MapInfo {
                width: g.width(),
                height: g.height(),
                resolution_m,
                origin_x_m: origin_m.0,
                origin_y_m: origin_m.1,
            };
            let from_m = Metres::new(
                info.origin_x_m + (f64::from(start.x) + off.0) * resolution_m,
                info.origin_y_m + (f64::from(start.y) + off.1) * resolution_m,
            );
            prop_assume!(info.cell_of(from_m) == start);
            let map = costs(&g, start);
            let reachable: Vec<Cell> = (0..g.len()).map(|i| g.cell_of(i)).filter(|&c| map.cost(c).is_some()).collect();
            let target = reachable[pick.index(reachable.len())];
            let path = path_to(&map, target).expect("reachable cells have paths");
            if let Some(w) = next_waypoint(&g, &info, from_m, &path, max_cells) {
                let pose = proto::geom::Pose { x: from_m.x, y: from_m.y, theta: 0.0 };
                let moved = world_server::motion::validate_move(
                    &g, &info, pose, info.centre_of(w), max_cells * resolution_m, &[], 0.2,
                );
                prop_assert!(
                    !matches!(moved, Err(proto::msg::MoveOutcome::Blocked)),
                    "the world refuses the move from {:?} to {:?} ({:?})", from_m, w, path
                );
            }
        }

        #[test]
        fn giving_way_keeps_clear(
            (g, me, other, target, known, clearance) in arb_giving_way(),
        ) {
            if let Some((blocked, path)) = give_way(&g, me, other, known.then_some(target), clearance) {
                prop_assert_eq!(path.first(), Some(&me));
                for pair in path.windows(2) {
                    prop_assert!(moves(&blocked, pair[0]).any(|(n, _)| n == pair[1]));
                }
                let aside = *path.last().unwrap_or(&me);
                let far = |a: Cell, b: Cell| a.dist(b) >= clearance;
                prop_assert!(far(aside, other), "{:?} is too near the other robot", aside);
                if let Some(way) = known.then(|| path_to(&costs(&g, other), target)).flatten() {
                    prop_assert!(way.iter().all(|&w| far(aside, w)), "{:?} is in the way", aside);
                }
            }
        }

        /// Giving way searches from `me` only until the nearest clear cell is certain, and the
        /// other robot's way by A*, yet finds what the full searches find: the same cell, the
        /// same path, the same blocked grid.
        #[test]
        fn giving_way_bounded_is_giving_way_over_full_searches(
            (g, me, other, target, known, clearance) in arb_giving_way(),
        ) {
            // The full searches: the other's way from a search of everything, then every clear
            // cell of a search of everything from `me`.
            let way = known.then(|| path_to(&costs(&g, other), target)).flatten();
            let way = way.unwrap_or_else(|| {
                let (dx, dy) = (f64::from(me.x - other.x), f64::from(me.y - other.y));
                let len = dx.hypot(dy).max(1.0);
                let steps = ((len + GIVE_WAY_LINE_CELLS) * 2.0).ceil() as i32;
                (0..=steps)
                    .map(|k| {
                        let t = f64::from(k) * 0.5 / len;
                        let at = |o: i32, d: f64| (f64::from(o) + d * t).round() as i32;
                        Cell::new(at(other.x, dx), at(other.y, dy))
                    })
                    .collect()
            });
            let in_the_way: Vec<Cell> = way.iter().flat_map(|&at| disc(&g, at, clearance)).collect();
            let blocked = around(&g, me, other, clearance);
            let from_me = costs(&blocked, me);
            let clear = (0..g.len())
                .map(|i| g.cell_of(i))
                .filter(|c| (g.get(*c) == Occ::Free || *c == me) && !in_the_way.contains(c));
            let full = nearest(clear, &from_me).and_then(|aside| path_to(&from_me, aside));
            let got = give_way(&g, me, other, known.then_some(target), clearance);
            prop_assert_eq!(got.as_ref().map(|(_, path)| path), full.as_ref());
            if let Some((b, _)) = got {
                prop_assert_eq!(b.to_ascii(), blocked.to_ascii());
            }
        }

        #[test]
        fn paths_and_waypoints_are_sound(
            g in arb_grid(),
            sx in 0i32..14,
            sy in 0i32..14,
            pick in any::<prop::sample::Index>(),
            max_cells in 0.0f64..12.0,
        ) {
            let start = Cell::new(sx % g.width() as i32, sy % g.height() as i32);
            let map = costs(&g, start);
            let reachable: Vec<Cell> = (0..g.len()).map(|i| g.cell_of(i)).filter(|&c| map.cost(c).is_some()).collect();
            let target = reachable[pick.index(reachable.len())];
            let path = path_to(&map, target).expect("reachable cells have paths");
            prop_assert_eq!(path.first(), Some(&start));
            prop_assert_eq!(path.last(), Some(&target));
            let mut total = 0.0;
            for pair in path.windows(2) {
                let (a, b) = (pair[0], pair[1]);
                let step = moves(&g, a).find(|&(n, _)| n == b);
                prop_assert!(step.is_some(), "{:?} -> {:?} is no legal move", a, b);
                total += step.map_or(0.0, |(_, s)| s);
            }
            prop_assert!((total - map.cost(target).unwrap_or(f64::NAN)).abs() < 1e-9);

            let info = MapInfo::at_origin(g.width(), g.height(), 1.0);
            let waypoint = next_waypoint(&g, &info, info.centre_of(start), &path, max_cells);
            let first_step = path.get(1).map(|b| b.dist(start));
            if let (Some(w), Some(step)) = (waypoint, first_step.filter(|&d| d > max_cells)) {
                prop_assert_eq!(Some(w), path.get(1).copied(), "a first step of {} > {} cells", step, max_cells);
            } else if let Some(w) = waypoint {
                prop_assert!(path[1..].contains(&w));
                prop_assert!(w.dist(start) <= max_cells);
                let line = swept(
                    start.centre(),
                    w.centre(),
                );
                for c in line {
                    prop_assert!(c == start || g.get(c) == Occ::Free, "{:?} on the segment is not free", c);
                }
            } else {
                prop_assert!(path.len() < 2, "a path of two cells or more always has a waypoint");
            }
        }
    }
}
