//! Constructing bids (Simmons et al., "Coordination for multi-robot exploration and mapping",
//! AAAI 2000, section "Constructing Bids"): every robot offers the frontier cells it could
//! explore, each with its cost, its expected information gain and the region that gain lies in;
//! the executive ([`super::executive`]) assigns the tasks.
//!
//! * Frontier cells ([`frontier_cells`]): clear cells next to unknown ones, each at least a
//!   minimum distance (≈ the robot's radius) from all other frontier cells. The paper does not
//!   say how the spaced set is picked; here, greedily in order of increasing path cost (ties by
//!   `(y, x)`), so that the choice is deterministic and near cells win. "Next to" is 4-adjacency
//!   inside the grid, as in [`crate::plan::frontiers`].
//! * Cost: the optimal path length from the robot, for all cells by one flood fill over clear
//!   cells ([`crate::plan::costs`]).
//! * Information gain ([`information_gain`]): the unknown cells within the nominal sensor range of
//!   the frontier cell that form a connected set with it — a flood fill that stops at clear and
//!   obstacle cells and beyond the range — and their bounding rectangle, the information-gain
//!   region ([`Igr`]). The paper leaves the connectivity open; here it is 4-connectivity, seeded
//!   at the frontier cell's unknown 4-neighbours, so that a fill does not leak through the
//!   diagonal gap between two wall cells.
//! * A bid ([`bid`]): (cell, gain, cost, IGR) per frontier cell, the best ones by net utility
//!   ([`Weights`]).

use std::collections::HashMap;

use proto::grid::{Cell, Grid, Occ};
use proto::msg::{encode, Bid, Bids, Offer as WireOffer, RobotId, Step, WorldInfo};
use proto::scenario::Scenario;

use super::executive::{assign, Bidder};
use super::relay::Relay;
use super::{Addressed, CoordMsg, Coordinator, Situation, Status};
use crate::plan::{CostMap, COST_TIE_QUANTUM};

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

/// Frontier cells per the paper, among `frontiers` (the cells of [`crate::plan::frontiers`]:
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

/// The offers that fit in `max_bytes` once encoded as a [`Bid`] (best first, as given).
fn within_bytes(me: RobotId, step: Step, offers: &[Offer], max_bytes: usize) -> Bid {
    let mut bid = Bid {
        robot: me,
        step,
        offers: Vec::new(),
    };
    for o in offers {
        bid.offers.push(to_wire(o));
        if encode(&Bids {
            from: me,
            bids: vec![bid.clone()],
        })
        .len()
            > max_bytes
        {
            bid.offers.pop();
            break;
        }
    }
    bid
}

/// `bids` on a robot: it bids, follows the executive's assignment while one younger than the
/// timeout holds, and decides alone on its own bid otherwise.
///
/// When it bids (the rule the paper leaves to "each time the map is updated"): at its first
/// step; once `rebid_changed_m2` of its planning grid became known since its last bid; when
/// its target is reached or stops being a frontier; and after half a timeout without a bid.
/// Between an assignment that no longer holds (its cell explored) and the next one, it goes to
/// its own best offer.
pub struct Bidding {
    me: RobotId,
    settings: Settings,
    relay: Relay,
    /// Its own last bid (best first), the known cells of its planning grid then, and its step.
    own: Option<(Vec<Offer>, usize, Step)>,
    /// The region of the task it follows (hysteresis when it decides alone).
    task: Option<Igr>,
    alone: bool,
}

impl Bidding {
    pub fn new(me: RobotId, base: RobotId, settings: Settings) -> Bidding {
        Bidding {
            me,
            settings,
            relay: Relay::new(me, base),
            own: None,
            task: None,
            alone: false,
        }
    }

    /// The assignment for this robot in a table younger than the timeout: `Some(None)` is
    /// "idle".
    fn assignment(&self, step: Step) -> Option<Option<(Cell, Igr)>> {
        let t = self.relay.tasks()?;
        if step >= t.step.saturating_add(self.settings.timeout_steps) {
            return None;
        }
        let e = t.tasks.iter().find(|e| e.robot == self.me)?;
        Some(e.task.map(|(cell, min, ext)| (cell, region(min, ext))))
    }

    /// Its best own offer, with hysteresis toward its current task.
    fn own_choice(&self, candidates: &[Cell]) -> Option<(Cell, Igr)> {
        let (offers, _, _) = self.own.as_ref()?;
        let usable: Vec<Offer> = offers
            .iter()
            .filter(|o| candidates.contains(&o.cell))
            .copied()
            .collect();
        let s = &self.settings;
        let me = Bidder {
            robot: self.me,
            offers: &usable,
            current: self.task,
        };
        let t = assign(&[me], &[], s.weights, s.min_gain, s.hysteresis)
            .into_iter()
            .next()
            .flatten()?;
        Some((t.cell, t.igr))
    }
}

impl Coordinator for Bidding {
    fn choose(&mut self, s: &Situation<'_>) -> Option<Cell> {
        let known = s.known;
        // A robot that has not bid for half a timeout bids again, so that the executive does
        // not take its silence for absence.
        let keep_alive = self.settings.half_timeout();
        let changed = self.own.as_ref().is_none_or(|(_, k, at)| {
            known.abs_diff(*k) >= self.settings.rebid_cells
                || s.step >= at.saturating_add(keep_alive)
        });
        let lost = s.target.is_some() && !s.valid;
        if changed || lost {
            let st = &self.settings;
            let mut offers = bid(
                s.grid,
                s.candidates,
                s.costs,
                st.spacing_cells,
                st.range_cells,
                st.offers,
                st.weights,
            );
            let wire = within_bytes(self.me, s.step, &offers, st.max_bid_bytes);
            offers.truncate(wire.offers.len());
            self.relay.put_bid(wire);
            self.own = Some((offers, known, s.step));
        }
        let choice = match self.assignment(s.step) {
            Some(assigned) => {
                self.alone = false;
                match assigned {
                    Some((cell, igr)) if s.candidates.contains(&cell) => Some((cell, igr)),
                    // Its task is done (or unreachable): its own best until the next one.
                    Some(_) => self.own_choice(s.candidates),
                    None => None,
                }
            }
            None => {
                self.alone = true;
                self.own_choice(s.candidates)
            }
        };
        self.task = choice.map(|(_, igr)| igr);
        choice.map(|(cell, _)| cell)
    }

    fn messages(&mut self, s: &Status<'_>) -> Vec<Addressed> {
        self.relay.messages(s.neighbours)
    }

    fn on_message(&mut self, _me: RobotId, msg: &CoordMsg) {
        match msg {
            CoordMsg::Bids(b) => {
                self.relay.on_bids(b);
            }
            CoordMsg::Tasks(t) => {
                self.relay.on_tasks(t);
            }
            CoordMsg::Team(_) | CoordMsg::Role(_) | CoordMsg::Pack(_) => {}
        }
    }

    fn alone(&self) -> bool {
        self.alone
    }
}

/// Two rooms side by side above a corridor, separated by a wall; each has a clear part near
/// its door and an unexplored part at the back (Simmons et al.'s example of robots that
/// should go into two adjacent rooms).
#[cfg(test)]
pub(crate) const TWO_ROOMS: &str = "\
###########
#????#????#
#????#????#
#....#....#
#....#....#
##.#####.##
#.........#
###########
";

/// The same rooms, their unknown parts connected (the wall only between the clear parts).
#[cfg(test)]
pub(crate) const TWO_ROOMS_OPEN_AT_THE_BACK: &str = "\
###########
#?????????#
#?????????#
#....#....#
#....#....#
##.#####.##
#.........#
###########
";

#[cfg(test)]
mod tests {
    use super::*;
    use crate::plan::{costs, frontiers};
    use proptest::prelude::*;

    /// Gain and cost in cells, one for one.
    const UNIT: Weights = Weights {
        gain_weight: 1.0,
        cost_weight: 1.0,
    };

    fn dist(a: Cell, b: Cell) -> f64 {
        f64::from(a.x - b.x).hypot(f64::from(a.y - b.y))
    }

    /// The qualifying cells of [`information_gain`] by a flood fill over the whole grid, the
    /// plain definition the windowed fill must agree with.
    fn reference_gain(g: &Grid, f: Cell, range: f64) -> Vec<Cell> {
        let ok = |c: Cell| g.contains(c) && g.get(c) == Occ::Unknown && dist(c, f) <= range;
        let mut seen = vec![false; g.len()];
        let mut stack: Vec<Cell> = f.neighbours4().into_iter().filter(|&c| ok(c)).collect();
        let mut out = Vec::new();
        while let Some(c) = stack.pop() {
            let i = g.index(c).expect("qualifying cells lie inside the grid");
            if seen[i] {
                continue;
            }
            seen[i] = true;
            out.push(c);
            stack.extend(c.neighbours4().into_iter().filter(|&n| ok(n)));
        }
        out
    }

    fn bounding(cells: &[Cell]) -> Option<Igr> {
        let first = *cells.first()?;
        Some(cells.iter().fold(
            Igr {
                min: first,
                max: first,
            },
            |r, c| Igr {
                min: Cell::new(r.min.x.min(c.x), r.min.y.min(c.y)),
                max: Cell::new(r.max.x.max(c.x), r.max.y.max(c.y)),
            },
        ))
    }

    #[test]
    fn igr_area_containment_and_intersection() {
        let a = Igr {
            min: Cell::new(0, 0),
            max: Cell::new(3, 1),
        };
        let b = Igr {
            min: Cell::new(2, 1),
            max: Cell::new(5, 4),
        };
        assert_eq!(a.area(), 8);
        assert_eq!(b.area(), 16);
        assert!(a.contains(Cell::new(3, 1)) && !a.contains(Cell::new(4, 1)));
        let ab = Igr {
            min: Cell::new(2, 1),
            max: Cell::new(3, 1),
        };
        assert_eq!(a.intersection(&b), Some(ab));
        assert_eq!(b.intersection(&a), Some(ab));
        let far = Igr {
            min: Cell::new(4, 0),
            max: Cell::new(9, 0),
        };
        assert_eq!(a.intersection(&far), None);
        let inverted = Igr {
            min: Cell::new(3, 0),
            max: Cell::new(1, 0),
        };
        assert_eq!(inverted.area(), 0);
        assert_eq!(inverted.intersection(&a), None);
    }

    #[test]
    fn the_gain_region_stops_at_walls() {
        let g = Grid::from_ascii(TWO_ROOMS);
        let left = information_gain(&g, Cell::new(4, 4), 5.0).expect("the left room has gain");
        let right = information_gain(&g, Cell::new(6, 4), 5.0).expect("the right room has gain");
        let left_room = Igr {
            min: Cell::new(1, 5),
            max: Cell::new(4, 6),
        };
        let right_room = Igr {
            min: Cell::new(6, 5),
            max: Cell::new(9, 6),
        };
        assert_eq!(left, (8, left_room));
        assert_eq!(right, (8, right_room));
        assert_eq!(left.1.intersection(&right.1), None);

        // Unknown parts connected behind the wall: the same frontier cells see into both rooms.
        let g = Grid::from_ascii(TWO_ROOMS_OPEN_AT_THE_BACK);
        let (_, left) = information_gain(&g, Cell::new(4, 4), 5.0).expect("gain");
        let (_, right) = information_gain(&g, Cell::new(6, 4), 5.0).expect("gain");
        assert!(left.max.x > 5 && right.min.x < 5, "{left:?} {right:?}");
        assert!(left.intersection(&right).is_some());
    }

    #[test]
    fn the_gain_stops_at_clear_cells_and_at_the_range() {
        // Unknown beyond a clear strip is not connected to the frontier cell's unknown side.
        let g = Grid::from_ascii(
            "\
???????
.......
???????
.......
",
        );
        let f = Cell::new(3, 0);
        let (n, igr) = information_gain(&g, f, 2.0).expect("the row above");
        // Row y = 1 within 2 cells of (3, 0): x = 2, 3, 4 (√2 and 1); (1, 1) and (5, 1) are √5 away.
        assert_eq!(n, 3);
        assert_eq!(
            igr,
            Igr {
                min: Cell::new(2, 1),
                max: Cell::new(4, 1),
            }
        );
        // A wide open unknown area: everything counted lies within the range.
        let mut open = Grid::new(41, 41, Occ::Unknown);
        open.set(Cell::new(20, 20), Occ::Free);
        for range in [1.0, 2.5, 7.0, 12.3] {
            let f = Cell::new(20, 20);
            let (n, igr) = information_gain(&open, f, range).expect("open gain");
            let want = reference_gain(&open, f, range);
            assert_eq!(n as usize, want.len(), "range {range}");
            assert!(want.iter().all(|&c| dist(c, f) <= range));
            let r = range.floor() as i32;
            assert!(igr.min.x >= 20 - r && igr.max.x <= 20 + r, "{igr:?}");
            assert!(igr.min.y >= 20 - r && igr.max.y <= 20 + r, "{igr:?}");
        }
        assert_eq!(information_gain(&open, Cell::new(20, 20), 0.9), None);
        assert_eq!(information_gain(&open, Cell::new(20, 20), f64::NAN), None);
    }

    #[test]
    fn frontier_cells_keep_their_spacing() {
        let g = Grid::from_ascii(
            "\
????????????
............
............
............
",
        );
        let start = Cell::new(0, 0);
        let map = costs(&g, start);
        let all = frontiers(&g, &map);
        assert_eq!(all.len(), 12);
        let spaced = frontier_cells(&all, &map, 3.0);
        // The nearest first, then every third cell along the row.
        let xs: Vec<i32> = spaced.iter().map(|c| c.x).collect();
        assert_eq!(xs, vec![0, 3, 6, 9]);
        assert!(spaced.iter().all(|c| c.y == 2));
        for (i, &a) in spaced.iter().enumerate() {
            for &b in &spaced[i + 1..] {
                assert!(dist(a, b) >= 3.0, "{a:?} {b:?}");
            }
        }
        // Every frontier cell left out lies near a chosen one.
        assert!(all
            .iter()
            .all(|&c| spaced.iter().any(|&s| dist(c, s) < 3.0)));
        assert_eq!(frontier_cells(&frontiers(&g, &map), &map, 0.0).len(), 12);
        assert_eq!(
            frontier_cells(&frontiers(&g, &map), &map, f64::NAN).len(),
            12
        );
    }

    #[test]
    fn a_bid_ranks_by_net_utility() {
        let g = Grid::from_ascii(TWO_ROOMS);
        // In the corridor below the left room's door.
        let map = costs(&g, Cell::new(2, 1));
        let offers = bid(&g, &frontiers(&g, &map), &map, 2.0, 5.0, 10, UNIT);
        assert!(!offers.is_empty());
        let net = |o: &Offer| UNIT.net(f64::from(o.gain_cells), o.cost_cells);
        for pair in offers.windows(2) {
            assert!(net(&pair[0]) >= net(&pair[1]), "{offers:?}");
        }
        assert!(offers[0].cell.x < 5, "the near room first: {offers:?}");
        assert!(offers.iter().any(|o| o.cell.x > 5), "the far room too");
        for o in &offers {
            assert_eq!(map.cost(o.cell), Some(o.cost_cells));
            assert_eq!(
                information_gain(&g, o.cell, 5.0),
                Some((o.gain_cells, o.igr))
            );
        }
        let two = bid(&g, &frontiers(&g, &map), &map, 2.0, 5.0, 2, UNIT);
        assert_eq!(two, offers[..2].to_vec());
        assert!(
            bid(&g, &frontiers(&g, &map), &map, 2.0, 0.5, 10, UNIT).is_empty(),
            "no gain"
        );
    }

    fn arb_grid() -> impl Strategy<Value = Grid> {
        (1u32..16, 1u32..16).prop_flat_map(|(w, h)| {
            proptest::collection::vec(0u8..10, (w * h) as usize).prop_map(move |v| {
                let mut g = Grid::new(w, h, Occ::Unknown);
                for (c, b) in g.cells_mut().iter_mut().zip(v) {
                    *c = match b {
                        0..=4 => Occ::Free,
                        5 => Occ::Occupied,
                        _ => Occ::Unknown,
                    };
                }
                g
            })
        })
    }

    proptest! {
        #[test]
        fn the_gain_agrees_with_a_whole_grid_fill(
            g in arb_grid(),
            fx in -2i32..18,
            fy in -2i32..18,
            range in 0.0f64..9.0,
        ) {
            let f = Cell::new(fx, fy);
            let want = reference_gain(&g, f, range);
            let got = information_gain(&g, f, range);
            match bounding(&want) {
                None => prop_assert_eq!(got, None),
                Some(igr) => prop_assert_eq!(got, Some((want.len() as u32, igr))),
            }
            prop_assert!(want.iter().all(|&c| dist(c, f) <= range));
        }

        #[test]
        fn spaced_frontier_cells_are_frontiers_far_apart(
            g in arb_grid(),
            sx in 0i32..16,
            sy in 0i32..16,
            spacing in 0.0f64..5.0,
        ) {
            let start = Cell::new(sx % g.width() as i32, sy % g.height() as i32);
            let map = costs(&g, start);
            let all = frontiers(&g, &map);
            let spaced = frontier_cells(&all, &map, spacing);
            for (i, &a) in spaced.iter().enumerate() {
                prop_assert!(all.contains(&a));
                for &b in &spaced[i + 1..] {
                    prop_assert!(dist(a, b) >= spacing, "{:?} {:?}", a, b);
                }
            }
            // Greedy and maximal: every frontier cell left out is too near a chosen one.
            for &c in &all {
                prop_assert!(spaced.contains(&c) || spaced.iter().any(|&s| dist(c, s) < spacing));
            }
            let order: Vec<f64> = spaced.iter().map(|&c| map.cost(c).unwrap_or(f64::NAN)).collect();
            prop_assert!(order.windows(2).all(|p| p[0] <= p[1] + COST_TIE_QUANTUM));
        }
    }
}
