//! Assigning tasks (Simmons et al., "Coordination for multi-robot exploration and mapping", AAAI
//! 2000, section "Assigning Tasks"): the executive collects the robots' bids
//! ([`crate::coord::bids::robot`]) and assigns greedily — the bid location of highest net utility
//! (gain minus cost) goes to its robot; the remaining robots' gains are then discounted by the
//! regions already assigned, and the highest remaining net utility is chosen, until every robot has
//! a task or no task's discounted gain is above a minimum threshold.
//!
//! * Discount: d_j = Area(IGR_j ∩ ∪_{i∈R} IGR_i) / Area(IGR_j)
//!   ([`overlap`](crate::coord::bids::executive::overlap), exact), and the discounted utility u_j =
//!   (1 − d_j)·i_j − c_j (weighted by [`Weights`](crate::coord::bids::offer::Weights)). R holds the
//!   tasks assigned so far and, from the start, those of robots that keep their task because they
//!   sent no new bid.
//! * Hysteresis: an offer whose cell lies in the IGR of its robot's current task has its gain
//!   divided by h (0 < h ≤ 1), before discounting, so that a robot is less disposed to switch.
//! * Where the paper is silent: the threshold is on the weighted discounted gain (not on the
//!   net utility, which may be negative for a far but worthwhile task); ties in utility go to
//!   the lower robot id, then the lower `(y, x)`, then the lower cost.

use std::collections::{BTreeMap, BTreeSet};

use proto::grid::Cell;
use proto::msg::{RobotId, Step, TaskEntry, Tasks};

use crate::coord::bids::offer::{extent, from_wire, Igr, Offer, Settings, Weights};
use crate::coord::bids::relay::Relay;
use crate::coord::{Addressed, CoordMsg, Coordinator, Situation, Status};

/// Utilities within this fraction of each other (and of 1) count as equal, so that ties are
/// broken by robot and position rather than by rounding.
const UTILITY_TIE: f64 = 1e-9;

/// A task assigned to a robot: the offer it won.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Task {
    pub robot: RobotId,
    pub cell: Cell,
    pub igr: Igr,
    /// The offer's gain, undiscounted.
    pub gain_cells: u32,
    pub cost_cells: f64,
}

/// One robot's bid, as the executive sees it.
#[derive(Clone, Copy, Debug)]
pub struct Bidder<'a> {
    pub robot: RobotId,
    pub offers: &'a [Offer],
    /// The IGR of its current task if any (hysteresis).
    pub current: Option<Igr>,
}

/// Area of `igr` covered by the union of `assigned` (exact; rectangles may overlap each other),
/// as a fraction of its area, in [0, 1]; 0 for an empty `igr`.
///
/// Coordinate compression: the assigned rectangles are clipped to `igr`, and for every strip
/// between two consecutive x edges the covered length is the union of the y intervals of the
/// rectangles spanning it. O(n² log n) for n rectangles, whatever their size.
pub fn overlap(igr: &Igr, assigned: &[Igr]) -> f64 {
    let area = igr.area();
    if area == 0 {
        return 0.0;
    }
    // Half-open edges: a rectangle covers [min.x, max.x + 1) × [min.y, max.y + 1).
    let clipped: Vec<(i64, i64, i64, i64)> = assigned
        .iter()
        .filter_map(|a| a.intersection(igr))
        .map(|r| {
            (
                i64::from(r.min.x),
                i64::from(r.max.x) + 1,
                i64::from(r.min.y),
                i64::from(r.max.y) + 1,
            )
        })
        .collect();
    let mut xs: Vec<i64> = clipped.iter().flat_map(|&(a, b, _, _)| [a, b]).collect();
    xs.sort_unstable();
    xs.dedup();
    let mut covered: u64 = 0;
    let mut spans: Vec<(i64, i64)> = Vec::with_capacity(clipped.len());
    for strip in xs.windows(2) {
        let (x0, x1) = (strip[0], strip[1]);
        spans.clear();
        spans.extend(
            clipped
                .iter()
                .filter(|&&(a, b, _, _)| a <= x0 && x1 <= b)
                .map(|&(_, _, c, d)| (c, d)),
        );
        spans.sort_unstable();
        let mut length = 0;
        let mut run: Option<(i64, i64)> = None;
        for &(c, d) in &spans {
            run = match run {
                Some((s, e)) if c <= e => Some((s, e.max(d))),
                Some((s, e)) => {
                    length += e - s;
                    Some((c, d))
                }
                None => Some((c, d)),
            };
        }
        if let Some((s, e)) = run {
            length += e - s;
        }
        covered += ((x1 - x0) * length) as u64;
    }
    (covered as f64 / area as f64).clamp(0.0, 1.0)
}

/// Greedy assignment. `keep`: IGRs of tasks that stay (robots with a task and no new bid).
/// Returns one entry per bidder in bidder order: `Some(task)` or `None` (idle: nothing with
/// discounted gain above `min_gain`).
///
/// Each robot gets at most one task (a robot listed twice is served once, at its first entry to
/// win). An offer's gain is divided by `hysteresis` when its cell lies in that bidder's
/// `current` IGR, then discounted by [`overlap`] with `keep` and the tasks assigned so far; the
/// offer qualifies only when that gain times `weights.gain_weight` exceeds `min_gain`. Among
/// the qualifying offers the highest net utility `weights.net(discounted gain, cost)` wins;
/// ties go to the lower robot id, then the lower `(y, x)`, then the lower cost. A `hysteresis`
/// outside (0, 1] means none; offers whose utility is not finite never win.
pub fn assign(
    bidders: &[Bidder<'_>],
    keep: &[Igr],
    weights: Weights,
    min_gain: f64,
    hysteresis: f64,
) -> Vec<Option<Task>> {
    let mut out = vec![None; bidders.len()];
    for (b, task) in greedy(bidders, keep, weights, min_gain, hysteresis) {
        out[b] = Some(task);
    }
    out
}

/// An offer's gain in cells after hysteresis and the discount by `covered`.
fn discounted_gain(bidder: &Bidder<'_>, o: &Offer, covered: &[Igr], hysteresis: f64) -> f64 {
    let mut gain = f64::from(o.gain_cells);
    if bidder.current.is_some_and(|c| c.contains(o.cell)) {
        gain /= hysteresis;
    }
    (1.0 - overlap(&o.igr, covered)) * gain
}

/// [`assign`]'s tasks in the order they were assigned, each with its bidder's index.
fn greedy(
    bidders: &[Bidder<'_>],
    keep: &[Igr],
    weights: Weights,
    min_gain: f64,
    hysteresis: f64,
) -> Vec<(usize, Task)> {
    let h = if hysteresis > 0.0 && hysteresis <= 1.0 {
        hysteresis
    } else {
        1.0
    };
    let mut covered: Vec<Igr> = keep.to_vec();
    let mut done: Vec<RobotId> = Vec::new();
    let mut tasks = Vec::new();
    loop {
        // (utility, bidder, offer) of the best qualifying offer.
        let mut pick: Option<(f64, usize, &Offer)> = None;
        for (b, bidder) in bidders.iter().enumerate() {
            if done.contains(&bidder.robot) {
                continue;
            }
            for o in bidder.offers {
                let gain = discounted_gain(bidder, o, &covered, h);
                let qualifies = weights.gain_weight * gain > min_gain;
                if !qualifies {
                    continue;
                }
                let u = weights.net(gain, o.cost_cells);
                if !u.is_finite() {
                    continue;
                }
                let better = match pick {
                    None => true,
                    Some((best, pb, po)) => {
                        let tie = UTILITY_TIE * 1f64.max(u.abs()).max(best.abs());
                        if (u - best).abs() <= tie {
                            let key = |b: usize, o: &Offer| (bidders[b].robot, o.cell.y, o.cell.x);
                            key(b, o)
                                .cmp(&key(pb, po))
                                .then(o.cost_cells.total_cmp(&po.cost_cells))
                                .is_lt()
                        } else {
                            u > best
                        }
                    }
                };
                if better {
                    pick = Some((u, b, o));
                }
            }
        }
        let Some((_, b, o)) = pick else { break };
        let robot = bidders[b].robot;
        done.push(robot);
        covered.push(o.igr);
        tasks.push((
            b,
            Task {
                robot,
                cell: o.cell,
                igr: o.igr,
                gain_cells: o.gain_cells,
                cost_cells: o.cost_cells,
            },
        ));
    }
    tasks
}

/// The executive on the base station: it gathers the bids the radio brings, waits
/// `wait_steps` after a new one for others, then assigns the robots that bid anew (robots with
/// a task and no new bid keep it) and issues the whole table, stamped with its step. It issues
/// the table again every half timeout while nothing changes, so that robots in reach keep a
/// fresh assignment. A robot silent (no new bid) for a timeout is dropped from the table: its
/// region no longer discounts others.
pub struct Executive {
    me: RobotId,
    settings: Settings,
    relay: Relay,
    /// Robots with a bid not yet assigned on, and the step the first of them arrived.
    pending: BTreeSet<RobotId>,
    since: Option<Step>,
    /// Per robot: its task (`None`: idle) and the step of the bid it was assigned on.
    assigned: BTreeMap<RobotId, (Option<Task>, Step)>,
    issued: Option<Step>,
}

impl Executive {
    pub fn new(me: RobotId, settings: Settings) -> Executive {
        Executive {
            me,
            settings,
            relay: Relay::new(me, me),
            pending: BTreeSet::new(),
            since: None,
            assigned: BTreeMap::new(),
            issued: None,
        }
    }

    /// Assigns the pending robots; whether the table changed.
    fn assign_pending(&mut self) -> bool {
        let s = &self.settings;
        let offers: Vec<(RobotId, Vec<Offer>, Step)> = self
            .pending
            .iter()
            .filter_map(|r| {
                let b = self.relay.bids().get(r)?;
                Some((*r, b.offers.iter().map(from_wire).collect(), b.step))
            })
            .collect();
        let bidders: Vec<Bidder<'_>> = offers
            .iter()
            .map(|(robot, offers, _)| Bidder {
                robot: *robot,
                offers,
                current: self.assigned.get(robot).and_then(|(t, _)| t.map(|t| t.igr)),
            })
            .collect();
        let keep: Vec<Igr> = self
            .assigned
            .iter()
            .filter(|(r, _)| !self.pending.contains(r))
            .filter_map(|(_, (t, _))| t.map(|t| t.igr))
            .collect();
        let tasks = assign(&bidders, &keep, s.weights, s.min_gain, s.hysteresis);
        let mut changed = false;
        for ((robot, _, step), task) in offers.iter().zip(tasks) {
            let before = self.assigned.insert(*robot, (task, *step));
            changed |= before.is_none_or(|(t, _)| t != task);
        }
        self.pending.clear();
        self.since = None;
        changed
    }
}

impl Coordinator for Executive {
    fn choose(&mut self, _s: &Situation<'_>) -> Option<Cell> {
        None
    }

    fn messages(&mut self, s: &Status<'_>) -> Vec<Addressed> {
        let st = self.settings;
        let mut changed = false;
        if !self.pending.is_empty() {
            let since = *self.since.get_or_insert(s.step);
            if s.step >= since.saturating_add(st.wait_steps) {
                changed = self.assign_pending();
            }
        }
        // Robots silent for a timeout no longer hold their regions.
        let before = self.assigned.len();
        self.assigned
            .retain(|_, (_, bid)| s.step < bid.saturating_add(st.timeout_steps));
        let dropped = self.assigned.len() != before;
        let heartbeat = st.half_timeout();
        let due = changed
            || dropped
            || self
                .issued
                .is_none_or(|i| s.step >= i.saturating_add(heartbeat));
        if due && !self.assigned.is_empty() {
            let tasks = self
                .assigned
                .iter()
                .map(|(&robot, (t, _))| TaskEntry {
                    robot,
                    task: t.map(|t| (t.cell, t.igr.min, extent(&t.igr))),
                })
                .collect();
            self.relay.put_tasks(Tasks {
                from: self.me,
                step: s.step,
                tasks,
            });
            self.issued = Some(s.step);
        }
        self.relay.messages(s.neighbours)
    }

    fn on_message(&mut self, _me: RobotId, msg: &CoordMsg) {
        if let CoordMsg::Bids(b) = msg {
            self.pending.extend(self.relay.on_bids(b));
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::coord::bids::offer::{bid, information_gain};
    use crate::coord::bids::robot::{TWO_ROOMS, TWO_ROOMS_OPEN_AT_THE_BACK};
    use crate::nav::plan::{costs, frontiers};
    use proptest::prelude::*;
    use proto::grid::Grid;

    const UNIT: Weights = Weights {
        gain_weight: 1.0,
        cost_weight: 1.0,
    };

    /// Gain only: the tests of the discount and the hysteresis compare gains directly.
    const GAIN_ONLY: Weights = Weights {
        gain_weight: 1.0,
        cost_weight: 0.0,
    };

    const HYSTERESIS: f64 = 0.85;

    fn rect(x0: i32, y0: i32, x1: i32, y1: i32) -> Igr {
        Igr {
            min: Cell::new(x0, y0),
            max: Cell::new(x1, y1),
        }
    }

    fn offer(x: i32, y: i32, gain: u32, cost: f64, igr: Igr) -> Offer {
        Offer {
            cell: Cell::new(x, y),
            gain_cells: gain,
            cost_cells: cost,
            igr,
        }
    }

    fn bidder(robot: RobotId, offers: &[Offer]) -> Bidder<'_> {
        Bidder {
            robot,
            offers,
            current: None,
        }
    }

    fn left_room(c: Cell) -> bool {
        c.x < 5
    }

    #[test]
    fn two_robots_go_into_the_two_adjacent_rooms() {
        let g = Grid::from_ascii(TWO_ROOMS);
        // Both in the corridor, nearer the left room's door.
        let (r1, r2) = (Cell::new(2, 1), Cell::new(3, 1));
        let (c1, c2) = (costs(&g, r1), costs(&g, r2));
        let b1 = bid(&g, &frontiers(&g, &c1), &c1, 2.0, 5.0, 10, UNIT);
        let b2 = bid(&g, &frontiers(&g, &c2), &c2, 2.0, 5.0, 10, UNIT);
        // Alone, each would take the left room.
        assert!(
            left_room(b1[0].cell) && left_room(b2[0].cell),
            "{b1:?} {b2:?}"
        );
        // The two rooms' regions are disjoint: the wall stops the fill.
        for (a, b) in b1.iter().flat_map(|a| b1.iter().map(move |b| (a, b))) {
            if left_room(a.cell) != left_room(b.cell) {
                assert_eq!(a.igr.intersection(&b.igr), None, "{a:?} {b:?}");
            }
        }
        let tasks = assign(
            &[bidder(1, &b1), bidder(2, &b2)],
            &[],
            UNIT,
            0.0,
            HYSTERESIS,
        );
        let t1 = tasks[0].expect("robot 1 gets a task");
        let t2 = tasks[1].expect("robot 2 gets a task");
        assert_eq!((t1.robot, t2.robot), (1, 2));
        assert_ne!(left_room(t1.cell), left_room(t2.cell), "{tasks:?}");

        // With the rooms' unknown parts connected, frontier cells on the two sides of the wall
        // have overlapping regions.
        let open = Grid::from_ascii(TWO_ROOMS_OPEN_AT_THE_BACK);
        let (_, left) = information_gain(&open, Cell::new(4, 4), 5.0).expect("gain");
        let (_, right) = information_gain(&open, Cell::new(6, 4), 5.0).expect("gain");
        assert!(left.intersection(&right).is_some());
        assert!(overlap(&left, &[right]) > 0.0);
    }

    #[test]
    fn the_overlap_discount_halves_a_half_covered_bid() {
        let first = rect(0, 0, 3, 3);
        let half = rect(2, 0, 5, 3);
        assert_eq!(overlap(&half, &[first]), 0.5);
        // Robot 1 wins the first region; robot 2's offer in `half` is then worth 40 / 2 = 20.
        let o1 = [offer(1, 1, 100, 0.0, first)];
        let elsewhere = rect(20, 20, 23, 23);
        let valued = |other_gain: u32| {
            let o2 = [
                offer(4, 1, 40, 0.0, half),
                offer(21, 21, other_gain, 0.0, elsewhere),
            ];
            let tasks = assign(
                &[bidder(1, &o1), bidder(2, &o2)],
                &[],
                GAIN_ONLY,
                0.0,
                HYSTERESIS,
            );
            assert_eq!(tasks[0].map(|t| t.igr), Some(first));
            tasks[1].map(|t| t.igr)
        };
        assert_eq!(valued(21), Some(elsewhere), "21 beats 40 / 2");
        assert_eq!(valued(19), Some(half), "40 / 2 beats 19");
        // Alone, it qualifies only against a threshold below 20.
        let o2 = [offer(4, 1, 40, 0.0, half)];
        let with_min = |min_gain: f64| {
            assign(
                &[bidder(1, &o1), bidder(2, &o2)],
                &[],
                GAIN_ONLY,
                min_gain,
                HYSTERESIS,
            )[1]
        };
        assert!(with_min(19.9).is_some());
        assert_eq!(with_min(20.0), None);
        // A kept task discounts from the start, just like an assigned one.
        let kept = assign(&[bidder(2, &o2)], &[first], GAIN_ONLY, 19.9, HYSTERESIS);
        assert!(kept[0].is_some());
        let kept = assign(&[bidder(2, &o2)], &[first], GAIN_ONLY, 20.0, HYSTERESIS);
        assert_eq!(kept[0], None);
    }

    #[test]
    fn hysteresis_keeps_a_robot_on_its_task() {
        let task = rect(0, 0, 9, 9);
        let choose = |alternative: u32, cost: f64| {
            let offers = [
                offer(5, 5, 100, cost, rect(3, 3, 8, 8)),
                offer(40, 40, alternative, cost, rect(35, 35, 45, 45)),
            ];
            let b = Bidder {
                robot: 1,
                offers: &offers,
                current: Some(task),
            };
            assign(&[b], &[], UNIT, 0.0, HYSTERESIS)[0]
                .expect("a task")
                .cell
        };
        let on_task = Cell::new(5, 5);
        // 100 / 0.85 ≈ 117.6: an alternative 1.1 times better stays behind, 1.25 times wins.
        assert_eq!(choose(110, 0.0), on_task);
        assert_eq!(choose(125, 0.0), Cell::new(40, 40));
        // The same with equal costs: it is the gain that is divided.
        assert_eq!(choose(110, 30.0), on_task);
        assert_eq!(choose(125, 30.0), Cell::new(40, 40));
        // Without a current task the better alternative wins at once.
        let offers = [
            offer(5, 5, 100, 0.0, rect(3, 3, 8, 8)),
            offer(40, 40, 110, 0.0, rect(35, 35, 45, 45)),
        ];
        let t = assign(&[bidder(1, &offers)], &[], UNIT, 0.0, HYSTERESIS)[0];
        assert_eq!(t.map(|t| t.cell), Some(Cell::new(40, 40)));
    }

    #[test]
    fn ties_go_to_the_lower_robot_then_position() {
        let r = rect(0, 0, 3, 3);
        let o = [offer(2, 2, 10, 1.0, r), offer(1, 2, 10, 1.0, r)];
        let tasks = assign(&[bidder(7, &o), bidder(3, &o)], &[], UNIT, 0.0, 1.0);
        // Robot 3 first, at the lower (y, x); robot 7 then finds the region fully covered.
        assert_eq!(tasks[1].map(|t| t.cell), Some(Cell::new(1, 2)));
        assert_eq!(tasks[0], None);
        // A robot listed twice is served once.
        let tasks = assign(&[bidder(3, &o), bidder(3, &o)], &[], UNIT, -1.0, 1.0);
        assert_eq!(tasks.iter().flatten().count(), 1, "{tasks:?}");
    }

    /// The fraction of `igr`'s cells that some rectangle of `assigned` contains, cell by cell.
    fn brute_overlap(igr: &Igr, assigned: &[Igr]) -> f64 {
        let mut n = 0u64;
        for y in igr.min.y..=igr.max.y {
            for x in igr.min.x..=igr.max.x {
                if assigned.iter().any(|a| a.contains(Cell::new(x, y))) {
                    n += 1;
                }
            }
        }
        n as f64 / igr.area() as f64
    }

    fn arb_rect(span: i32) -> impl Strategy<Value = Igr> {
        (0..span, 0..span, 0..span / 2, 0..span / 2)
            .prop_map(|(x, y, w, h)| rect(x, y, x + w, y + h))
    }

    fn arb_offers() -> impl Strategy<Value = Vec<Offer>> {
        proptest::collection::vec(
            (
                arb_rect(12),
                0u32..40,
                0.0f64..20.0,
                any::<prop::sample::Index>(),
            ),
            0..5,
        )
        .prop_map(|v| {
            v.into_iter()
                .map(|(igr, gain, cost, at)| {
                    // The cell somewhere in (or just beside) its region.
                    let w = (igr.max.x - igr.min.x + 2) as usize;
                    let i = at.index(w * 2) as i32;
                    offer(
                        igr.min.x - 1 + i % w as i32,
                        igr.min.y + i / w as i32,
                        gain,
                        cost,
                        igr,
                    )
                })
                .collect()
        })
    }

    proptest! {
        #[test]
        fn overlap_is_an_exact_fraction(
            igr in arb_rect(10),
            assigned in proptest::collection::vec(arb_rect(10), 0..6),
        ) {
            let d = overlap(&igr, &assigned);
            prop_assert!((0.0..=1.0).contains(&d));
            prop_assert!((d - brute_overlap(&igr, &assigned)).abs() < 1e-12);
            if assigned.iter().all(|a| a.intersection(&igr).is_none()) {
                prop_assert_eq!(d, 0.0);
            }
            let outer = rect(igr.min.x - 1, igr.min.y, igr.max.x, igr.max.y + 2);
            let mut with_outer = assigned.clone();
            with_outer.push(outer);
            prop_assert_eq!(overlap(&igr, &with_outer), 1.0);
        }

        #[test]
        fn assign_gives_one_task_per_robot_above_the_threshold(
            bids in proptest::collection::vec(
                (0u16..4, arb_offers(), proptest::option::of(arb_rect(12))),
                0..5,
            ),
            keep in proptest::collection::vec(arb_rect(12), 0..3),
            min_gain in -5.0f64..30.0,
            gain_weight in 0.1f64..3.0,
            hysteresis in 0.5f64..=1.0,
        ) {
            let bidders: Vec<Bidder<'_>> = bids
                .iter()
                .map(|(robot, offers, current)| Bidder { robot: *robot, offers, current: *current })
                .collect();
            let weights = Weights { gain_weight, cost_weight: 1.0 };
            let tasks = assign(&bidders, &keep, weights, min_gain, hysteresis);
            prop_assert_eq!(tasks.len(), bidders.len());
            let ordered = greedy(&bidders, &keep, weights, min_gain, hysteresis);
            let mut robots: Vec<RobotId> = Vec::new();
            for (b, t) in tasks.iter().enumerate() {
                if let Some(t) = t {
                    prop_assert_eq!(t.robot, bidders[b].robot);
                    prop_assert!(!robots.contains(&t.robot), "robot {} twice", t.robot);
                    robots.push(t.robot);
                    prop_assert!(bidders[b].offers.iter().any(|o| o.cell == t.cell && o.igr == t.igr));
                }
            }
            prop_assert_eq!(robots.len(), ordered.len());
            // Replayed in assignment order, every task's discounted gain is above the threshold.
            let mut covered = keep.clone();
            for (b, t) in &ordered {
                prop_assert_eq!(tasks[*b], Some(*t));
                let mut gain = f64::from(t.gain_cells);
                if bidders[*b].current.is_some_and(|c| c.contains(t.cell)) {
                    gain /= hysteresis;
                }
                gain *= 1.0 - brute_overlap(&t.igr, &covered);
                prop_assert!(gain * gain_weight > min_gain, "{:?} at {}", t, gain);
                covered.push(t.igr);
            }
            // An idle robot had nothing left that qualified.
            for (b, t) in tasks.iter().enumerate() {
                if t.is_none() && !robots.contains(&bidders[b].robot) {
                    for o in bidders[b].offers {
                        let gain = discounted_gain(&bidders[b], o, &covered, hysteresis);
                        prop_assert!(gain * gain_weight <= min_gain, "{:?} left out", o);
                    }
                }
            }
        }
    }
}
