//! `burgard` (Burgard et al., "Coordinated multi-robot exploration", 2005, Algorithm 1): the
//! sub-team that can talk, transitively, assigns targets greedily — the best (robot, frontier) pair
//! first, then the utilities discounted by it, and so on — on one robot's data; every member
//! computes the same assignment and takes its own.
//! [`permutation_search`](crate::coord::burgard::permutation_search) is Algorithm 2's alternative
//! (randomized search with hill-climbing over Σ U − β·V², favouring balanced trajectories).
//!
//! Its state is the sub-team table: every robot's latest report (step, cell, target, radio
//! neighbours), heard directly or relayed as [`Team`](proto::msg::Team) messages from neighbour to
//! neighbour. It replans when its target is no longer usable, when its sub-team changes and every
//! `replan_every_steps` steps.

use proto::grid::{Cell, Grid};
use proto::msg::{RobotId, Step, Team};

use crate::coord::team::{self, Table};
use crate::coord::{
    best, decay, discount, normalized, Addressed, CoordMsg, Coordinator, Params, Situation, Status,
    To,
};
use crate::nav::plan::{self, CostMap};

/// A sub-team table entry older than this many steps no longer counts (its robot is gone from
/// the sub-team).
const TEAM_FRESH_STEPS: Step = 3;

/// The sub-team of the last assignment and the step it was made at.
#[derive(Clone, Debug, Default, PartialEq)]
struct Assignment {
    team: Vec<RobotId>,
    step: Step,
}

pub struct Burgard {
    params: Params,
    /// Algorithm 2's search instead of the greedy Algorithm 1, with this many tries.
    search: bool,
    search_tries: u32,
    replan_every_steps: u32,
    /// The latest report of every robot heard of, directly or relayed.
    team: Table,
    assigned: Assignment,
}

impl Burgard {
    pub fn new(params: Params, search: bool, search_tries: u32, replan_every_steps: u32) -> Self {
        Burgard {
            params,
            search,
            search_tries,
            replan_every_steps,
            team: Table::new(TEAM_FRESH_STEPS),
            assigned: Assignment::default(),
        }
    }

    /// The robots this one can reach over current links, transitively (itself included,
    /// sorted), from its own neighbours and the fresh entries of its team table.
    fn sub_team(&self, s: &Situation<'_>) -> Vec<RobotId> {
        self.team.group(s.id, s.neighbours, s.step, None)
    }

    /// This robot's target in the sub-team's assignment, computed on its own planning grid from
    /// every member's cell; targets of robots outside the sub-team (last heard) discount the
    /// utilities first.
    fn assign(&self, s: &Situation<'_>, team: &[RobotId]) -> Option<Cell> {
        let maps: Vec<CostMap> = team
            .iter()
            .filter(|&&r| r != s.id)
            .filter_map(|&r| self.team.get(r, s.step))
            .map(|e| plan::costs_with(s.grid, e.cell, s.penalty))
            .collect();
        let mut costs: Vec<&CostMap> = Vec::with_capacity(team.len());
        let mut others = maps.iter();
        let mut me_at = 0;
        for (k, &r) in team.iter().enumerate() {
            if r == s.id {
                me_at = k;
                costs.push(s.costs);
            } else if let Some(m) = others.next() {
                costs.push(m);
            }
        }
        let fixed: Vec<(Cell, f64)> = self
            .team
            .all()
            .filter(|e| !team.contains(&e.robot))
            .filter_map(|e| Some((e.target?, f64::from(s.step.saturating_sub(e.step)))))
            .collect();
        let targets = if self.search {
            let seed = u64::from(s.step) << 16 | team.len() as u64;
            let tries = self.search_tries as usize;
            permutation_search(s.grid, s.candidates, &costs, &self.params, tries, seed)
        } else {
            greedy_assignment(s.grid, s.candidates, &costs, &fixed, &self.params)
        };
        targets.get(me_at).copied().flatten()
    }

    /// The team table to send: this robot's own entry and every fresh one it holds.
    fn team_msg(&self, s: &Status<'_>) -> Team {
        let own = team::entry(s.id, s.step, s.me, s.target, s.neighbours);
        Team {
            from: s.id,
            entries: self.team.to_send(own),
        }
    }
}

impl Coordinator for Burgard {
    fn choose(&mut self, s: &Situation<'_>) -> Option<Cell> {
        let team = self.sub_team(s);
        let due = s.step >= self.assigned.step + self.replan_every_steps;
        if !s.valid || due || team != self.assigned.team {
            let target = self.assign(s, &team);
            self.assigned = Assignment { team, step: s.step };
            target
        } else {
            s.target
        }
    }

    fn messages(&mut self, s: &Status<'_>) -> Vec<Addressed> {
        vec![Addressed {
            to: To::Neighbours,
            msg: CoordMsg::Team(self.team_msg(s)),
        }]
    }

    /// A neighbour's team table: newer reports replace older ones.
    #[allow(irrefutable_let_patterns)] // other strategies' messages are not for it
    fn on_message(&mut self, me: RobotId, msg: &CoordMsg) {
        let CoordMsg::Team(t) = msg else { return };
        self.team.merge(me, &t.entries);
    }
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
