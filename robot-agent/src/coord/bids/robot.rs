//! A bidding robot (Simmons et al. 2000): it bids what [`super::offer`](crate::coord::bids::offer)
//! constructs, follows the executive's assignment while it is fresh, and decides alone when cut
//! off.

use proto::grid::Cell;
use proto::msg::{encode, Bid, Bids, RobotId, Step};

use crate::coord::bids::executive::{assign, Bidder};
use crate::coord::bids::offer::*;
use crate::coord::bids::relay::Relay;
use crate::coord::{Addressed, CoordMsg, Coordinator, Situation, Status};

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
    use crate::nav::plan::{costs, frontiers, COST_TIE_QUANTUM};
    use proptest::prelude::*;
    use proto::grid::{Grid, Occ};

    /// Gain and cost in cells, one for one.
    const UNIT: Weights = Weights {
        gain_weight: 1.0,
        cost_weight: 1.0,
    };

    fn dist(a: Cell, b: Cell) -> f64 {
        a.dist(b)
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
