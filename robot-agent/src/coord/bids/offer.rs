//! Constructing bids (Simmons et al., "Coordination for multi-robot exploration and mapping",
//! AAAI 2000, section "Constructing Bids"): every robot offers the frontier cells it could
//! explore, each with its cost, its expected information gain and the region that gain lies in;
//! the executive ([`crate::coord::bids::executive`]) assigns the tasks.
//!
//! * Frontier cells ([`frontier_cells`](crate::coord::bids::offer::frontier_cells)): clear cells
//!   next to unknown ones, each at least a minimum distance (≈ the robot's radius) from all other
//!   frontier cells. The paper does not say how the spaced set is picked; here, greedily in order
//!   of increasing path cost (ties by `(y, x)`), so that the choice is deterministic and near cells
//!   win. "Next to" is 4-adjacency inside the grid, as in [`crate::nav::plan::frontiers`].
//! * Cost: the optimal path length from the robot, for all cells by one flood fill over clear
//!   cells ([`crate::nav::plan::costs`]).
//! * Information gain ([`information_gain`](crate::coord::bids::offer::information_gain)): the
//!   unknown cells within the nominal sensor range of the frontier cell that form a connected set
//!   with it — a flood fill that stops at clear and obstacle cells and beyond the range — and their
//!   bounding rectangle, the information-gain region ([`Igr`](crate::coord::bids::offer::Igr)). The
//!   paper leaves the connectivity open; here it is 4-connectivity, seeded at the frontier cell's
//!   unknown 4-neighbours, so that a fill does not leak through the diagonal gap between two wall
//!   cells.
//! * A bid ([`bid`](crate::coord::bids::offer::bid)): (cell, gain, cost, IGR) per frontier cell,
//!   the best ones by net utility ([`Weights`](crate::coord::bids::offer::Weights)).

use std::collections::HashMap;

use proto::grid::{Cell, Grid, Occ};
use proto::msg::{Offer as WireOffer, Step, WorldInfo};
use proto::scenario::Scenario;

use crate::nav::plan::{CostMap, COST_TIE_QUANTUM};

/// An information-gain region: the bounding rectangle of a frontier cell's gain, in cells, both
/// corners inclusive.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Igr {
    pub min: Cell,
    pub max: Cell,
}

impl Igr {
    /// The number of cells it covers (0 when a corner is inverted).
    pub fn area(&self) -> u64 {
        let w = i64::from(self.max.x) - i64::from(self.min.x) + 1;
        let h = i64::from(self.max.y) - i64::from(self.min.y) + 1;
        if w <= 0 || h <= 0 {
            0
        } else {
            w as u64 * h as u64
        }
    }

    pub fn contains(&self, c: Cell) -> bool {
        (self.min.x..=self.max.x).contains(&c.x) && (self.min.y..=self.max.y).contains(&c.y)
    }

    /// The cells both cover (`None`: none).
    pub fn intersection(&self, o: &Igr) -> Option<Igr> {
        let min = Cell::new(self.min.x.max(o.min.x), self.min.y.max(o.min.y));
        let max = Cell::new(self.max.x.min(o.max.x), self.max.y.min(o.max.y));
        (min.x <= max.x && min.y <= max.y).then_some(Igr { min, max })
    }
}

/// One entry of a bid.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Offer {
    /// The frontier cell.
    pub cell: Cell,
    /// Its information gain: unknown cells (of area) it may reveal.
    pub gain_cells: u32,
    /// The robot's path cost to it, in cells of path length.
    pub cost_cells: f64,
    /// Where that gain lies.
    pub igr: Igr,
}

/// How gain and cost are weighed against each other: the net utility of a task is
/// u = `gain_weight`·gain − `cost_weight`·cost.
///
/// The bids count gain in cells of area and cost in cells of path length, two different units;
/// the weights make them one. The strategy sets `gain_weight` to the cell's area in m² and
/// `cost_weight` to the cell's size in m times a scenario factor, so that u is "m² of unknown
/// area − factor × m of travel" (the paper subtracts cost from gain without saying how they are
/// scaled).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Weights {
    pub gain_weight: f64,
    pub cost_weight: f64,
}

impl Weights {
    /// The net utility of `gain` cells of area at `cost` cells of path length.
    pub fn net(&self, gain: f64, cost: f64) -> f64 {
        self.gain_weight * gain - self.cost_weight * cost
    }
}

/// Frontier cells per the paper, among `frontiers` (the cells of [`crate::nav::plan::frontiers`]:
/// free, ≥1 unknown 4-neighbour inside the grid; the agent's candidates): the reachable ones
/// (cost known), each at least `spacing_cells` (Euclidean, between cell centres) from every
/// other chosen one; chosen greedily in order of increasing cost (ties by `(y, x)`) so that the
/// choice is deterministic and prefers near cells. Returned in that order. A `spacing_cells` of
/// 0 or less keeps every reachable frontier cell.
pub fn frontier_cells(frontiers: &[Cell], costs: &CostMap, spacing_cells: f64) -> Vec<Cell> {
    let mut candidates: Vec<(i64, Cell)> = frontiers
        .iter()
        .filter_map(|&c| {
            let cost = costs.cost(c)?;
            Some(((cost / COST_TIE_QUANTUM).round() as i64, c))
        })
        .collect();
    candidates.sort_unstable_by_key(|&(q, c)| (q, c.y, c.x));
    if spacing_cells.is_nan() || spacing_cells <= 0.0 {
        return candidates.into_iter().map(|(_, c)| c).collect();
    }
    // Chosen cells by square bucket of side ≥ spacing: a chosen cell nearer than the spacing
    // lies in the same bucket or one of the eight around it.
    let side = spacing_cells.ceil().min(f64::from(i32::MAX)) as i32;
    let bucket = |c: Cell| (c.x.div_euclid(side), c.y.div_euclid(side));
    let mut chosen: Vec<Cell> = Vec::new();
    let mut buckets: HashMap<(i32, i32), Vec<Cell>> = HashMap::new();
    let min_sq = spacing_cells * spacing_cells;
    for (_, c) in candidates {
        let (bx, by) = bucket(c);
        let too_near = (-1..=1).any(|dy: i32| {
            (-1..=1).any(|dx: i32| {
                let key = (bx.saturating_add(dx), by.saturating_add(dy));
                buckets.get(&key).is_some_and(|cells| {
                    cells.iter().any(|o| {
                        let (ex, ey) = (f64::from(o.x - c.x), f64::from(o.y - c.y));
                        ex * ex + ey * ey < min_sq
                    })
                })
            })
        });
        if !too_near {
            chosen.push(c);
            buckets.entry((bx, by)).or_default().push(c);
        }
    }
    chosen
}

/// The information gain of frontier cell `f`: the unknown cells 4-connected to f's unknown
/// 4-neighbours through unknown cells, each within `range_cells` (Euclidean between centres) of
/// f; returns (count, IGR) — `None` when no unknown cell qualifies (in particular when
/// `range_cells` < 1). Only cells inside the grid count.
///
/// The fill never leaves the square of side 2·⌊range⌋ + 1 around f, and its visited marks cover
/// only that square (clipped to the grid): the work is proportional to the range's area, not the
/// map's.
pub fn information_gain(g: &Grid, f: Cell, range_cells: f64) -> Option<(u32, Igr)> {
    gain_with(g, f, range_cells, &mut Scratch::default())
}

/// The buffers of [`information_gain`], reused across the frontier cells of one bid.
#[derive(Default)]
struct Scratch {
    visited: Vec<bool>,
    stack: Vec<Cell>,
}

fn gain_with(g: &Grid, f: Cell, range_cells: f64, s: &mut Scratch) -> Option<(u32, Igr)> {
    // A 4-neighbour lies 1 cell away: below that nothing qualifies (NaN included).
    if range_cells.is_nan() || range_cells < 1.0 || g.is_empty() {
        return None;
    }
    let r = range_cells.floor().min(f64::from(i32::MAX)) as i64;
    let (fx, fy) = (i64::from(f.x), i64::from(f.y));
    let x0 = (fx - r).max(0);
    let y0 = (fy - r).max(0);
    let x1 = (fx + r).min(i64::from(g.width()) - 1);
    let y1 = (fy + r).min(i64::from(g.height()) - 1);
    if x0 > x1 || y0 > y1 {
        return None;
    }
    let w = (x1 - x0 + 1) as usize;
    let h = (y1 - y0 + 1) as usize;
    s.visited.clear();
    s.visited.resize(w * h, false);
    s.stack.clear();
    let range_sq = range_cells * range_cells;
    // The window's index of `c` when `c` qualifies: inside the window (so inside the grid),
    // unknown and within range.
    let slot = |c: Cell| -> Option<usize> {
        let (cx, cy) = (i64::from(c.x), i64::from(c.y));
        if cx < x0 || cx > x1 || cy < y0 || cy > y1 || g.get(c) != Occ::Unknown {
            return None;
        }
        let (dx, dy) = ((cx - fx) as f64, (cy - fy) as f64);
        (dx * dx + dy * dy <= range_sq).then(|| (cy - y0) as usize * w + (cx - x0) as usize)
    };
    let mut count: u32 = 0;
    let mut igr = Igr { min: f, max: f };
    for n in f.neighbours4() {
        if let Some(i) = slot(n) {
            if !s.visited[i] {
                s.visited[i] = true;
                s.stack.push(n);
            }
        }
    }
    while let Some(c) = s.stack.pop() {
        igr = if count == 0 {
            Igr { min: c, max: c }
        } else {
            Igr {
                min: Cell::new(igr.min.x.min(c.x), igr.min.y.min(c.y)),
                max: Cell::new(igr.max.x.max(c.x), igr.max.y.max(c.y)),
            }
        };
        count += 1;
        for n in c.neighbours4() {
            if let Some(i) = slot(n) {
                if !s.visited[i] {
                    s.visited[i] = true;
                    s.stack.push(n);
                }
            }
        }
    }
    (count > 0).then_some((count, igr))
}

/// A robot's bid: every spaced frontier cell of `frontiers` ([`frontier_cells`]) with its gain
/// ([`information_gain`]) on `g`, cost and IGR, the best `max_offers` by net utility
/// `weights.net(gain, cost)`, best first; ties go to the lower cost, then the lower `(y, x)`.
/// Frontier cells without gain (a range below one cell) offer nothing. Offers of negative net
/// utility stay in: whether a task is worth taking is the executive's call (its minimum gain).
pub fn bid(
    g: &Grid,
    frontiers: &[Cell],
    costs: &CostMap,
    spacing_cells: f64,
    range_cells: f64,
    max_offers: usize,
    weights: Weights,
) -> Vec<Offer> {
    let mut scratch = Scratch::default();
    let mut offers: Vec<(f64, Offer)> = frontier_cells(frontiers, costs, spacing_cells)
        .into_iter()
        .filter_map(|cell| {
            let cost_cells = costs.cost(cell)?;
            let (gain_cells, igr) = gain_with(g, cell, range_cells, &mut scratch)?;
            let offer = Offer {
                cell,
                gain_cells,
                cost_cells,
                igr,
            };
            Some((weights.net(f64::from(gain_cells), cost_cells), offer))
        })
        .collect();
    offers.sort_by(|(ua, a), (ub, b)| {
        ub.total_cmp(ua)
            .then(a.cost_cells.total_cmp(&b.cost_cells))
            .then((a.cell.y, a.cell.x).cmp(&(b.cell.y, b.cell.x)))
    });
    offers.truncate(max_offers);
    offers.into_iter().map(|(_, o)| o).collect()
}

/// The `bids` strategy's settings in cells (from `coordination.bids` and the map's resolution).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Settings {
    pub offers: usize,
    pub max_bid_bytes: usize,
    pub spacing_cells: f64,
    pub range_cells: f64,
    pub weights: Weights,
    /// The executive's minimum discounted gain, in `weights` units (m²).
    pub min_gain: f64,
    pub hysteresis: f64,
    pub wait_steps: Step,
    pub timeout_steps: Step,
    pub rebid_cells: usize,
}

impl Settings {
    pub fn new(s: &Scenario, world: &WorldInfo) -> Settings {
        let b = &s.coordination.bids;
        let res = world.map.resolution_m;
        Settings {
            offers: b.offers as usize,
            max_bid_bytes: b.max_bid_bytes as usize,
            spacing_cells: b.frontier_spacing_m / res,
            range_cells: b.gain_range_m / res,
            weights: Weights {
                gain_weight: res * res,
                cost_weight: b.cost_weight * res,
            },
            min_gain: b.min_gain_m2,
            hysteresis: b.hysteresis,
            wait_steps: b.wait_steps,
            timeout_steps: b.assignment_timeout_steps,
            rebid_cells: (b.rebid_changed_m2 / (res * res)).ceil() as usize,
        }
    }

    /// Half the assignment timeout (at least a step): how often the executive reissues its
    /// table and a robot bids at the least, so that neither's silence reads as absence.
    pub fn half_timeout(&self) -> Step {
        (self.timeout_steps / 2).max(1)
    }
}

/// An offer as it crosses the radio (cost in tenths of a cell, the region as corner + extent).
pub fn to_wire(o: &Offer) -> WireOffer {
    WireOffer {
        cell: o.cell,
        gain_cells: o.gain_cells,
        cost_decicells: (o.cost_cells * 10.0)
            .round()
            .clamp(0.0, f64::from(u32::MAX)) as u32,
        igr_min: o.igr.min,
        igr_extent: extent(&o.igr),
    }
}

/// An offer as received.
pub fn from_wire(o: &WireOffer) -> Offer {
    Offer {
        cell: o.cell,
        gain_cells: o.gain_cells,
        cost_cells: f64::from(o.cost_decicells) / 10.0,
        igr: region(o.igr_min, o.igr_extent),
    }
}

/// The width and height − 1 of a region, as the wire carries them.
pub fn extent(igr: &Igr) -> (u16, u16) {
    let d = |a: i32, b: i32| u16::try_from(b.saturating_sub(a).max(0)).unwrap_or(u16::MAX);
    (d(igr.min.x, igr.max.x), d(igr.min.y, igr.max.y))
}

/// The region of corner `min` and extent `e`.
pub fn region(min: Cell, e: (u16, u16)) -> Igr {
    Igr {
        min,
        max: Cell::new(
            min.x.saturating_add(i32::from(e.0)),
            min.y.saturating_add(i32::from(e.1)),
        ),
    }
}
