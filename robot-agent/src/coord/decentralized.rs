//! `decentralized` (thesis §4.5.1): every robot picks its own target, the frontier with the best
//! U − β·V after the targets other robots announced (`targ`, heard from robots in range) have
//! discounted the utilities; a target's discount decays with its age (beyond the thesis, its
//! §7.2). It keeps its target while that is still a usable frontier.

use proto::grid::{Cell, Grid};

use crate::coord::{best, decay, discount, normalized, Coordinator, Params, Situation};
use crate::nav::plan::CostMap;

pub struct Decentralized {
    params: Params,
}

impl Decentralized {
    pub fn new(params: Params) -> Decentralized {
        Decentralized { params }
    }
}

impl Coordinator for Decentralized {
    fn keeps_valid_target(&self) -> bool {
        true
    }

    fn looks_at_frontier_costs_only(&self) -> bool {
        true
    }

    fn choose(&mut self, s: &Situation<'_>) -> Option<Cell> {
        if s.valid {
            return s.target;
        }
        let others: Vec<(Cell, f64)> = s
            .heard
            .iter()
            .filter_map(|(_, a)| Some((a.target?, f64::from(s.step.saturating_sub(a.step)))))
            .collect();
        target(s.grid, s.candidates, s.costs, &others, &self.params)
    }
}

/// Decentralized coordination (thesis §4.5.1): the frontier with the best U − β·V after the
/// targets `others` (cell, age in steps) have discounted the utilities.
pub fn target(
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
