//! The strategies by `coordination.strategy`: [`new`] builds the one a node runs.

use proto::msg::{RobotId, WorldInfo};
use proto::scenario::{Scenario, Strategy};

use crate::coord::utility::Params;
use crate::coord::{bids, burgard, decentralized, pack, roles, uncoordinated, Coordinator};

/// The strategy of node `id` in scenario `s` (`max_range_cells`: the laser's range in cells).
/// The base station runs the strategy's central part (`bids`: the executive) or nothing.
pub fn new(
    s: &Scenario,
    id: RobotId,
    world: &WorldInfo,
    max_range_cells: f64,
) -> Box<dyn Coordinator> {
    let c = &s.coordination;
    if let (Some(base), Strategy::Bids) = (s.base_id(), c.strategy) {
        let settings = bids::offer::Settings::new(s, world);
        return if id == base {
            Box::new(bids::executive::Executive::new(id, settings))
        } else {
            Box::new(bids::robot::Bidding::new(id, base, settings))
        };
    }
    if s.base_id() == Some(id) {
        return Box::new(uncoordinated::Uncoordinated);
    }
    let params = Params {
        beta: c.beta,
        max_range_cells,
        half_life_steps: Some(c.target_half_life_steps).filter(|&h| h > 0.0),
    };
    if let (Some(base), Strategy::Roles) = (s.base_id(), c.strategy) {
        let settings = roles::robot::Settings::new(s, world, params);
        return Box::new(roles::robot::Roles::new(id, base, settings));
    }
    match c.strategy {
        Strategy::Pack => Box::new(pack::Pack::new(id, pack::Settings::new(s, world))),
        // `bids` and `roles` need a base station (scenario validation says so); without one,
        // the nearest frontier.
        Strategy::Uncoordinated | Strategy::Bids | Strategy::Roles => {
            Box::new(uncoordinated::Uncoordinated)
        }
        Strategy::Decentralized => Box::new(decentralized::Decentralized::new(params)),
        Strategy::Burgard => Box::new(burgard::Burgard::new(
            params,
            c.burgard_search,
            c.search_tries,
            c.replan_every_steps,
        )),
    }
}
