//! `uncoordinated`: every robot goes to its nearest frontier ([`crate::nav::plan::nearest`]),
//! whatever the others do — the baseline the coordinated strategies are measured against. It
//! keeps its target while that is still a usable frontier.

use proto::grid::Cell;

use crate::coord::{Coordinator, Situation};
use crate::nav::plan;

pub struct Uncoordinated;

impl Coordinator for Uncoordinated {
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
        plan::nearest(s.candidates.iter().copied(), s.costs)
    }
}
