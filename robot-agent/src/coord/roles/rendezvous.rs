//! Rendezvous (de Hoog, Cameron & Visser 2010, §III-D and §IV): where and by when a child (an
//! explorer, or a relay below another relay) meets its parent next. The child agrees it while the
//! two are in range, on its own planning grid — the map the two have just shared.
//!
//! * Where: the rendezvous points of the known free space ([`crate::coord::roles::skeleton`]:
//!   Hilditch's skeleton, its junctions and filling points, pruned); of the `candidates` points
//!   nearest the place the child heads for next (an explorer's next frontier), the one with the
//!   highest neighbour traversal T — the most important junction — and on ties the best estimated
//!   radio reach ([`crate::radio::reach::Reach`]), then the nearest. The fallback point is where
//!   the parent stands at the agreement: both have just been there.
//! * By when: the parent's trip — from where it stands to its own meeting point (the base station,
//!   or its parent's rendezvous), and from there to the new point — at the robots' speed, on the
//!   same map ([`agree`](crate::coord::roles::rendezvous::agree)). The paper's explorer uses that
//!   prediction to explore until it must turn back; so does ours ([`crate::coord::roles::robot`]).

use proto::grid::{Cell, Grid};
use proto::msg::{Rendezvous, Step};

use crate::coord::roles::skeleton;
use crate::nav::plan::{self, CostMap};
use crate::radio::reach::Reach;

/// Steps of slack added to a predicted trip (the parent's turn at its own meeting point).
const SLACK_STEPS: Step = 2;

/// How a child agrees a rendezvous (from `[coordination.roles]`, in cells and steps).
#[derive(Clone, Debug)]
pub struct Agreeing {
    pub candidates: usize,
    pub fill_cells: f64,
    pub prune_cells: f64,
    pub cells_per_step: f64,
    pub reach: Reach,
}

/// The rendezvous point among `points` (cell, T) near `toward`: of the `k` nearest, the highest
/// T, then the best `reach`, then the nearest, then the lowest `(y, x)`.
pub fn choose(
    points: &[(Cell, u8)],
    toward: Cell,
    k: usize,
    reach: impl Fn(Cell) -> f64,
) -> Option<Cell> {
    let dist = |c: Cell| c.dist(toward);
    let mut near: Vec<(Cell, u8)> = points.to_vec();
    near.sort_by(|a, b| {
        dist(a.0)
            .total_cmp(&dist(b.0))
            .then(key(a.0).cmp(&key(b.0)))
    });
    near.truncate(k.max(1));
    let scored: Vec<(Cell, u8, f64)> = near.into_iter().map(|(c, t)| (c, t, reach(c))).collect();
    scored
        .into_iter()
        .max_by(|a, b| {
            a.1.cmp(&b.1)
                .then(a.2.total_cmp(&b.2))
                .then(dist(b.0).total_cmp(&dist(a.0)))
                .then(key(b.0).cmp(&key(a.0)))
        })
        .map(|(c, _, _)| c)
}

fn key(c: Cell) -> (i32, i32) {
    (c.y, c.x)
}

/// Steps a trip of `cells` takes at `cells_per_step` (rounded up).
pub fn trip_steps(cells: f64, cells_per_step: f64) -> Step {
    if !(cells.is_finite() && cells > 0.0) || cells_per_step <= 0.0 {
        return 0;
    }
    (cells / cells_per_step)
        .ceil()
        .min(f64::from(Step::MAX / 2)) as Step
}

/// The path cost from `costs`' start to `to`, or the straight distance where the map has no
/// path yet (the parent may know a way the child's map does not).
fn cost_or_straight(costs: &CostMap, to: Cell) -> f64 {
    costs.cost(to).unwrap_or_else(|| {
        let s = costs.start();
        s.dist(to)
    })
}

/// The cell half way (by path cost) along the cheapest path from `costs`' start to `to`.
pub fn midway(costs: &CostMap, to: Cell) -> Option<Cell> {
    let path = plan::path_to(costs, to)?;
    let half = costs.cost(to)? / 2.0;
    path.into_iter()
        .find(|&c| costs.cost(c).is_some_and(|v| v >= half))
}

/// What the child knows when it agrees.
pub struct Meeting {
    pub step: Step,
    /// Where the child heads next (an explorer: its next frontier).
    pub toward: Cell,
    /// Where the parent stands now.
    pub parent_at: Cell,
    /// Where the parent meets its own parent next.
    pub parent_point: Cell,
}

/// The next rendezvous with the parent, agreed on the child's planning grid `g` (`mine`: the
/// child's path costs on it). `None` when no rendezvous point is reachable by the child.
pub fn agree(g: &Grid, mine: &CostMap, m: &Meeting, a: &Agreeing) -> Option<Rendezvous> {
    let skeleton = skeleton::thin(g);
    let points: Vec<(Cell, u8)> =
        skeleton::rendezvous_points(&skeleton, a.fill_cells, a.prune_cells)
            .into_iter()
            .filter(|&(c, _)| mine.cost(c).is_some())
            .collect();
    let primary = choose(&points, m.toward, a.candidates, |c| a.reach.estimate(g, c))?;
    let from_parent = plan::costs(g, m.parent_at);
    let from_point = plan::costs(g, m.parent_point);
    let trip =
        cost_or_straight(&from_parent, m.parent_point) + cost_or_straight(&from_point, primary);
    Some(Rendezvous {
        primary,
        fallback: m.parent_at,
        due: m
            .step
            .saturating_add(trip_steps(trip, a.cells_per_step))
            .saturating_add(SLACK_STEPS),
        made: m.step,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_point_near_the_frontier_with_the_highest_traversal_wins() {
        let points = [
            (Cell::new(0, 0), 4),
            (Cell::new(10, 0), 3),
            (Cell::new(12, 0), 1),
            (Cell::new(11, 1), 3),
        ];
        // Of the two nearest (12,0) and (11,1)/(10,0): T decides.
        assert_eq!(
            choose(&points, Cell::new(12, 0), 2, |_| 0.0),
            Some(Cell::new(11, 1))
        );
        // Equal T: the better reach.
        let reach = |c: Cell| if c == Cell::new(10, 0) { 9.0 } else { 5.0 };
        assert_eq!(
            choose(&points, Cell::new(12, 0), 3, reach),
            Some(Cell::new(10, 0))
        );
        // The far junction with T = 4 is not among the candidates near the frontier.
        assert_ne!(
            choose(&points, Cell::new(12, 0), 3, |_| 0.0),
            Some(Cell::new(0, 0))
        );
        assert_eq!(choose(&[], Cell::new(0, 0), 3, |_| 0.0), None);
    }

    #[test]
    fn the_due_step_is_the_parents_trip_there_and_back() {
        // A corridor 30 cells long: the parent stands at x = 10, its own meeting point is x = 1
        // (the base), the child heads for x = 28.
        let g = Grid::from_ascii(&format!(
            "{w}\n{w}\n#{c}#\n#{c}#\n#{c}#\n{w}\n{w}\n",
            w = "#".repeat(32),
            c = ".".repeat(30)
        ));
        let child = Cell::new(20, 2);
        let mine = plan::costs(&g, child);
        let m = Meeting {
            step: 100,
            toward: Cell::new(28, 3),
            parent_at: Cell::new(10, 3),
            parent_point: Cell::new(1, 3),
        };
        let a = Agreeing {
            candidates: 3,
            fill_cells: 4.0,
            prune_cells: 2.0,
            cells_per_step: 2.0,
            reach: Reach::Disk { range_cells: 10.0 },
        };
        let r = agree(&g, &mine, &m, &a).expect("a rendezvous");
        assert!(r.primary.x >= 22, "{r:?}");
        assert_eq!(r.fallback, m.parent_at);
        assert_eq!(r.made, 100);
        let back = plan::costs(&g, m.parent_point)
            .cost(r.primary)
            .expect("reachable");
        let expected = 100 + ((9.0 + back) / 2.0).ceil() as Step + SLACK_STEPS;
        assert_eq!(r.due, expected);
    }

    #[test]
    fn trips_round_up_and_tolerate_nonsense() {
        assert_eq!(trip_steps(5.0, 2.0), 3);
        assert_eq!(trip_steps(4.0, 2.0), 2);
        assert_eq!(trip_steps(f64::INFINITY, 2.0), 0);
        assert_eq!(trip_steps(3.0, 0.0), 0);
    }
}
