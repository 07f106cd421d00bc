//! Coordination: which frontier a robot goes to (thesis §4.4–4.5, Burgard et al. §II; DESIGN.md
//! §4.6). Pure functions over the planning grid, the frontiers and Dijkstra costs
//! ([`crate::plan`]); the agent supplies what it heard from other robots.
//!
//! * Utility (thesis eq. 4.4, Burgard eq. 1): every frontier cell starts at U = 1; a target t'
//!   chosen by another robot lowers the utility of every frontier t by P(‖t − t'‖), the
//!   probability that the robot at t' will see t: P(d) = 1 − d / max_range below the laser's
//!   range, 0 beyond it and 0 without line of sight (eq. 4.5).
//! * Trade-off (eq. 4.6): the robot picks argmax U_t − β·V_t. V is the Dijkstra cost normalized by
//!   the robot's largest frontier cost, so that U and V are on the same [0, 1] scale and β keeps the
//!   meaning Burgard et al. give it (exploration time flat for β in [0.01, 50]).
//! * `decentralized` (thesis §4.5.1): the other targets are those in the robot's table (heard as
//!   `targ` from robots in range). Beyond the thesis (its §7.2): a target's discount decays with
//!   its age, halving every `half_life` steps.
//! * `burgard` (Algorithm 1): the sub-team that can talk, transitively, assigns targets greedily
//!   — the best (robot, frontier) pair first, then the utilities discounted by it, and so on — on
//!   one robot's data; every member computes the same assignment and takes its own.
//!   [`permutation_search`] is Algorithm 2's alternative (randomized search with hill-climbing
//!   over Σ U − β·V², favouring balanced trajectories).
//! * `uncoordinated`: the nearest frontier ([`crate::plan::nearest`]).

use proto::grid::{Cell, Grid, Occ};

use crate::grid::supercover;
use crate::plan::CostMap;

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
    let centre = |c: Cell| (f64::from(c.x) + 0.5, f64::from(c.y) + 0.5);
    supercover(centre(a), centre(b))
        .into_iter()
        .all(|c| g.get(c) != Occ::Occupied)
}

/// How much another robot's target `other` lowers the utility of frontier `t`, weighted by
/// `weight` (the decay of an old target).
pub fn discount(g: &Grid, t: Cell, other: Cell, max_range: f64, weight: f64) -> f64 {
    let d = f64::from(t.x - other.x).hypot(f64::from(t.y - other.y));
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
fn normalized(frontiers: &[Cell], costs: &CostMap) -> Vec<Option<f64>> {
    let raw: Vec<Option<f64>> = frontiers.iter().map(|&t| costs.cost(t)).collect();
    let max = raw.iter().flatten().fold(0.0f64, |m, &v| m.max(v));
    let scale = if max > 0.0 { max } else { 1.0 };
    raw.into_iter().map(|v| v.map(|v| v / scale)).collect()
}

/// The best frontier by U − β·V; ties go to the lower cost, then to the lower `(y, x)`.
fn best(frontiers: &[Cell], utility: &[f64], cost: &[Option<f64>], beta: f64) -> Option<usize> {
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

/// Decentralized coordination (thesis §4.5.1): the frontier with the best U − β·V after the
/// targets `others` (cell, age in steps) have discounted the utilities.
pub fn decentralized(
    g: &Grid,
    frontiers: &[Cell],
    costs: &CostMap,
    others: &[(Cell, f64)],
    p: &Params,
) -> Option<Cell> {
    let utility: Vec<f64> = frontiers
        .iter()
        .map(|&t| {
            1.0 - others
                .iter()
                .map(|&(o, age)| {
                    discount(g, t, o, p.max_range_cells, decay(age, p.half_life_steps))
                })
                .sum::<f64>()
        })
        .collect();
    let cost = normalized(frontiers, costs);
    best(frontiers, &utility, &cost, p.beta).map(|i| frontiers[i])
}

/// Burgard et al. Algorithm 1: targets for robots with costs `costs` (one [`CostMap`] per
/// robot), after the targets `fixed` (of robots outside the team, cell and age) have discounted
/// the utilities. Returns one target per robot (`None`: no reachable frontier left for it).
pub fn greedy_assignment(
    g: &Grid,
    frontiers: &[Cell],
    costs: &[&CostMap],
    fixed: &[(Cell, f64)],
    p: &Params,
) -> Vec<Option<Cell>> {
    let mut utility: Vec<f64> = vec![1.0; frontiers.len()];
    let lower = |utility: &mut Vec<f64>, target: Cell, weight: f64| {
        for (u, &t) in utility.iter_mut().zip(frontiers) {
            *u -= discount(g, t, target, p.max_range_cells, weight);
        }
    };
    for &(o, age) in fixed {
        lower(&mut utility, o, decay(age, p.half_life_steps));
    }
    let norm: Vec<Vec<Option<f64>>> = costs.iter().map(|c| normalized(frontiers, c)).collect();
    let mut out = vec![None; costs.len()];
    let mut left: Vec<usize> = (0..costs.len()).collect();
    while !left.is_empty() {
        // The (robot, frontier) pair with the best trade-off; ties to the lower robot index.
        let mut pick: Option<(usize, usize, f64)> = None;
        for (k, &r) in left.iter().enumerate() {
            if let Some(i) = best(frontiers, &utility, &norm[r], p.beta) {
                let value = utility[i] - p.beta * norm[r][i].unwrap_or(f64::INFINITY);
                if pick.is_none_or(|(_, _, v)| value > v + 1e-12) {
                    pick = Some((k, i, value));
                }
            }
        }
        let Some((k, i, _)) = pick else { break };
        let r = left.remove(k);
        out[r] = Some(frontiers[i]);
        lower(&mut utility, frontiers[i], 1.0);
    }
    out
}

/// Burgard et al. Algorithm 2 by randomized search with hill-climbing: starting from the greedy
/// assignment, `tries` random changes of one robot's target (from a deterministic generator seeded
/// with `seed`) are kept when they raise Σ_i (U(t_i | others) − β·V_i(t_i)²).
pub fn permutation_search(
    g: &Grid,
    frontiers: &[Cell],
    costs: &[&CostMap],
    p: &Params,
    tries: usize,
    seed: u64,
) -> Vec<Option<Cell>> {
    let start = greedy_assignment(g, frontiers, costs, &[], p);
    let norm: Vec<Vec<Option<f64>>> = costs.iter().map(|c| normalized(frontiers, c)).collect();
    let index = |c: Cell| frontiers.iter().position(|&f| f == c);
    let mut current: Vec<Option<usize>> = start.iter().map(|t| t.and_then(index)).collect();
    let score = |a: &[Option<usize>]| -> f64 {
        let mut sum = 0.0;
        for (r, &ti) in a.iter().enumerate() {
            let Some(ti) = ti else { continue };
            let Some(v) = norm[r][ti] else {
                return f64::NEG_INFINITY;
            };
            let u = 1.0
                - a.iter()
                    .enumerate()
                    .filter(|&(o, t)| o != r && t.is_some())
                    .map(|(_, t)| {
                        let o = frontiers[t.unwrap_or_default()];
                        discount(g, frontiers[ti], o, p.max_range_cells, 1.0)
                    })
                    .sum::<f64>();
            sum += u - p.beta * v * v;
        }
        sum
    };
    if frontiers.is_empty() {
        return start;
    }
    let mut best_score = score(&current);
    let mut x = seed | 1;
    for _ in 0..tries {
        x ^= x << 13;
        x ^= x >> 7;
        x ^= x << 17;
        let r = (x % costs.len().max(1) as u64) as usize;
        let t = ((x >> 16) % frontiers.len() as u64) as usize;
        if norm[r][t].is_none() || current[r].is_none() {
            continue;
        }
        let before = current[r];
        current[r] = Some(t);
        let s = score(&current);
        if s > best_score {
            best_score = s;
        } else {
            current[r] = before;
        }
    }
    current
        .into_iter()
        .map(|t| t.map(|i| frontiers[i]))
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::plan::{costs, frontiers};

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
        let n1 = crate::plan::nearest(f.iter().copied(), &c1);
        let n2 = crate::plan::nearest(f.iter().copied(), &c2);
        assert_eq!(n1.map(door_side), n2.map(door_side));
        // Burgard's greedy assignment sends them to different rooms.
        let a = greedy_assignment(&g, &f, &[&c1, &c2], &[], &PARAMS);
        let sides: Vec<_> = a.iter().map(|t| t.map(door_side)).collect();
        assert!(sides[0].is_some() && sides[0] != sides[1], "{a:?}");
        // Decentralized: robot 1 knows robot 2's target and picks the other room.
        let t2 = a[1].unwrap_or(r2);
        let t1 = decentralized(&g, &f, &c1, &[(t2, 0.0)], &PARAMS);
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
