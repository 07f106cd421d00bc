//! What every strategy shares: the utility and discount arithmetic (thesis eq. 4.4–4.6,
//! Burgard et al. eq. 1), the table of other robots' announced targets ([`Heard`]).

use std::collections::BTreeMap;

use proto::grid::{Cell, Grid, Occ};
use proto::msg::{RobotId, Step, Target};

use crate::mapping::grid::supercover_finds;
use crate::nav::plan::CostMap;

/// A target another robot announced (`targ`): the cell (`None`: it has none) and the step it
/// chose it at.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Announcement {
    pub target: Option<Cell>,
    pub step: Step,
}

/// Other robots' last announced targets (thesis §4.5.1's table; heard directly from robots in
/// range). Every strategy may read it; the right of way uses it too.
#[derive(Clone, Debug, Default)]
pub struct Heard {
    targets: BTreeMap<RobotId, Announcement>,
}

impl Heard {
    /// Robot `me` heard `t`.
    pub fn on_target(&mut self, me: RobotId, t: &Target) {
        if t.from != me {
            let a = Announcement {
                target: t.cell,
                step: t.step,
            };
            self.targets.insert(t.from, a);
        }
    }

    pub fn get(&self, robot: RobotId) -> Option<&Announcement> {
        self.targets.get(&robot)
    }

    /// Every announcement, by robot.
    pub fn iter(&self) -> impl Iterator<Item = (RobotId, &Announcement)> {
        self.targets.iter().map(|(&r, a)| (r, a))
    }
}

/// What a strategy needs besides the grid.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Params {
    /// β of eq. 4.6.
    pub beta: f64,
    /// The laser's range in cells (P(d) is 0 from there on).
    pub max_range_cells: f64,
    /// Steps after which a target's discount has halved (`None`: no decay).
    pub half_life_steps: Option<f64>,
}

/// Eq. 4.5: the probability that a robot at a target sees a cell `d` cells away.
pub fn coverage_probability(d: f64, max_range: f64) -> f64 {
    if d < max_range && max_range > 0.0 {
        1.0 - d / max_range
    } else {
        0.0
    }
}

/// No occupied cell lies on the straight segment between the centres of `a` and `b`.
pub fn line_of_sight(g: &Grid, a: Cell, b: Cell) -> bool {
    let centre = Cell::centre;
    !supercover_finds(centre(a), centre(b), |c| g.get(c) == Occ::Occupied)
}

/// How much another robot's target `other` lowers the utility of frontier `t`, weighted by
/// `weight` (the decay of an old target).
pub fn discount(g: &Grid, t: Cell, other: Cell, max_range: f64, weight: f64) -> f64 {
    let d = t.dist(other);
    let p = coverage_probability(d, max_range);
    if p > 0.0 && line_of_sight(g, t, other) {
        weight * p
    } else {
        0.0
    }
}

/// The weight of a target `age` steps old: 1, halved every `half_life` steps.
pub fn decay(age: f64, half_life: Option<f64>) -> f64 {
    match half_life {
        Some(h) if h > 0.0 => 0.5f64.powf(age.max(0.0) / h),
        _ => 1.0,
    }
}

/// Normalized costs of `frontiers` from `costs`: V / max V (unreachable frontiers: `None`).
pub fn normalized(frontiers: &[Cell], costs: &CostMap) -> Vec<Option<f64>> {
    let raw: Vec<Option<f64>> = frontiers.iter().map(|&t| costs.cost(t)).collect();
    let max = raw.iter().flatten().fold(0.0f64, |m, &v| m.max(v));
    let scale = if max > 0.0 { max } else { 1.0 };
    raw.into_iter().map(|v| v.map(|v| v / scale)).collect()
}

/// The best frontier by U − β·V; ties go to the lower cost, then to the lower `(y, x)`.
pub fn best(frontiers: &[Cell], utility: &[f64], cost: &[Option<f64>], beta: f64) -> Option<usize> {
    let mut best: Option<(usize, f64)> = None;
    for (i, (&u, v)) in utility.iter().zip(cost).enumerate() {
        let Some(v) = *v else { continue };
        let value = u - beta * v;
        let better = match best {
            None => true,
            Some((j, bv)) => {
                let key = |k: usize| {
                    (
                        cost[k].unwrap_or(f64::INFINITY),
                        frontiers[k].y,
                        frontiers[k].x,
                    )
                };
                value > bv + 1e-12
                    || ((value - bv).abs() <= 1e-12
                        && key(i).partial_cmp(&key(j)).is_some_and(|o| o.is_lt()))
            }
        };
        if better {
            best = Some((i, value));
        }
    }
    best.map(|(i, _)| i)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::coord::burgard::{greedy_assignment, permutation_search};
    use crate::coord::decentralized;
    use crate::nav::plan::{costs, frontiers};

    const PARAMS: Params = Params {
        beta: 1.0,
        max_range_cells: 8.0,
        half_life_steps: None,
    };

    /// A corridor with a room at each end, both unexplored beyond their doors (Burgard Figs. 2
    /// and 5): robots 1 and 2 stand in the corridor, 2 a little to the left.
    const CORRIDOR: &str = "\
##################################
#????????#################???????#
#????????#################???????#
#????????.................???????#
#????????#################???????#
##################################
";

    /// Cell `x` of the corridor row (row 3 from the top of the picture).
    fn cell_of(map: &str, x: i32) -> Cell {
        let rows = map.lines().count() as i32;
        Cell::new(x, rows - 1 - 3)
    }

    fn door_side(c: Cell) -> &'static str {
        if c.x < 17 {
            "left"
        } else {
            "right"
        }
    }

    #[test]
    fn two_robots_in_a_corridor_pick_different_rooms() {
        let g = Grid::from_ascii(CORRIDOR);
        let (r1, r2) = (cell_of(CORRIDOR, 15), cell_of(CORRIDOR, 14));
        let (c1, c2) = (costs(&g, r1), costs(&g, r2));
        let f = frontiers(&g, &c1);
        assert!(!f.is_empty());
        // Uncoordinated: both go to the same (nearest) room.
        let n1 = crate::nav::plan::nearest(f.iter().copied(), &c1);
        let n2 = crate::nav::plan::nearest(f.iter().copied(), &c2);
        assert_eq!(n1.map(door_side), n2.map(door_side));
        // Burgard's greedy assignment sends them to different rooms.
        let a = greedy_assignment(&g, &f, &[&c1, &c2], &[], &PARAMS);
        let sides: Vec<_> = a.iter().map(|t| t.map(door_side)).collect();
        assert!(sides[0].is_some() && sides[0] != sides[1], "{a:?}");
        // Decentralized: robot 1 knows robot 2's target and picks the other room.
        let t2 = a[1].unwrap_or(r2);
        let t1 = decentralized::target(&g, &f, &c1, &[(t2, 0.0)], &PARAMS);
        assert_ne!(t1.map(door_side), Some(door_side(t2)), "{t1:?} vs {t2:?}");
        // Algorithm 2's search keeps them apart too.
        let s = permutation_search(&g, &f, &[&c1, &c2], &PARAMS, 200, 7);
        let sides: Vec<_> = s.iter().map(|t| t.map(door_side)).collect();
        assert!(sides[0].is_some() && sides[0] != sides[1], "{s:?}");
    }

    #[test]
    fn a_frontier_behind_a_wall_gets_no_discount() {
        let g = Grid::from_ascii(
            "\
#########
#...#...#
#...#...#
#...#...#
#########
",
        );
        let (a, b, c) = (Cell::new(2, 2), Cell::new(6, 2), Cell::new(3, 1));
        assert!(!line_of_sight(&g, a, b));
        assert_eq!(discount(&g, a, b, 8.0, 1.0), 0.0);
        assert!(line_of_sight(&g, a, c));
        let d = f64::from(1).hypot(1.0);
        assert!((discount(&g, a, c, 8.0, 1.0) - (1.0 - d / 8.0)).abs() < 1e-12);
        assert_eq!(discount(&g, a, Cell::new(2, 2), 0.0, 1.0), 0.0);
    }

    #[test]
    fn the_discount_halves_after_the_half_life() {
        assert_eq!(decay(0.0, Some(20.0)), 1.0);
        assert!((decay(20.0, Some(20.0)) - 0.5).abs() < 1e-12);
        assert!((decay(40.0, Some(20.0)) - 0.25).abs() < 1e-12);
        assert_eq!(decay(1000.0, None), 1.0);
        let g = Grid::from_ascii("......\n......\n");
        let (t, o) = (Cell::new(0, 0), Cell::new(2, 0));
        let fresh = discount(&g, t, o, 8.0, decay(0.0, Some(10.0)));
        let old = discount(&g, t, o, 8.0, decay(10.0, Some(10.0)));
        assert!((old - fresh / 2.0).abs() < 1e-12);
    }

    #[test]
    fn p_of_d_is_linear_up_to_the_range() {
        assert_eq!(coverage_probability(0.0, 10.0), 1.0);
        assert!((coverage_probability(2.5, 10.0) - 0.75).abs() < 1e-12);
        assert_eq!(coverage_probability(10.0, 10.0), 0.0);
        assert_eq!(coverage_probability(12.0, 10.0), 0.0);
    }
}
