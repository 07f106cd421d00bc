//! Coordination: which frontier a robot goes to (thesis §4.4–4.5, Burgard et al. §II; docs/design.md
//! §4.6). Pure functions over the planning grid, the frontiers and Dijkstra costs
//! ([`crate::plan`]); the agent supplies what it heard from other robots.
//!
//! This module holds what every strategy shares — the utility and discount arithmetic below,
//! the table of other robots' announced targets ([`Heard`]) and the interface
//! ([`Coordinator`]) — and one file per strategy holds its state and its messages:
//! [`decentralized`], [`burgard`], [`uncoordinated`], [`bids`] (with [`executive`] and
//! [`relay`]), [`roles`] (with [`hierarchy`]), [`pack`]; [`team`] is the team table `burgard` and
//! `pack` share. [`new`] registers them by `coordination.strategy`.
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

use std::collections::{BTreeMap, BTreeSet};

use proto::grid::{Cell, Grid, Occ};
use proto::msg::{
    decode, encode, Bids, DecodeError, Judged, Pack, RobotId, Role, Step, Target, Tasks, Team,
    Traffic, WorldInfo,
};
use proto::scenario::{Scenario, Strategy};

use crate::grid::supercover;
use crate::plan::CostMap;

pub mod bids;
pub mod burgard;
pub mod decentralized;
pub mod executive;
pub mod hierarchy;
pub mod pack;
pub mod relay;
pub mod roles;
pub mod team;
pub mod uncoordinated;

/// How the agent talks to a coordination strategy, whichever it is.
///
/// A trait object rather than an enum: the strategies share no state (Burgard's sub-team table,
/// a bidding robot's open auctions, a relay's role are each one strategy's business), so an enum
/// would make every method a match over all of them and every new strategy an edit of each
/// match. With the trait, a strategy is one file implementing it, plus a line in [`new`] and,
/// if it talks, a variant of [`CoordMsg`]. The agent asks it once per step for a target
/// ([`Coordinator::choose`], given the planning grid, this robot's costs, the candidate
/// frontiers and what was heard of other robots), once per step for its radio messages
/// ([`Coordinator::messages`], given this robot's state and neighbours), and hands it every
/// coordination message received ([`Coordinator::on_message`]). The radio encodes, counts and
/// decodes those messages ([`crate::radio`]); a strategy never sees bytes.
pub trait Coordinator: Send {
    /// This step's target: keep `s.target` or pick another (`None`: no target).
    fn choose(&mut self, s: &Situation<'_>) -> Option<Cell>;

    /// Whether [`Coordinator::choose`] keeps a valid target (`s.valid`) without looking at
    /// anything else. The agent then searches only as far as that target while it stays a
    /// frontier ([`crate::plan::costs_until`]), and asks `choose` nothing: the step costs the
    /// way to the target, not everything explored.
    fn keeps_valid_target(&self) -> bool {
        false
    }

    /// The messages to send after this step's decision.
    fn messages(&mut self, _s: &Status<'_>) -> Vec<Addressed> {
        Vec::new()
    }

    /// A coordination message heard on the radio (this robot is `me`).
    fn on_message(&mut self, _me: RobotId, _msg: &CoordMsg) {}

    /// The robot decided alone at its last step although the strategy has it follow someone
    /// else's decisions (`bids`: no assignment younger than the timeout).
    fn alone(&self) -> bool {
        false
    }

    /// How the robot moves this step: toward the target `choose` named (planned by the agent,
    /// with the right of way), or as the strategy says (`pack`: the move the leader sent).
    fn steer(&self) -> Steer {
        Steer::Target
    }

    /// What the robot, leading its group, judged of the links of its last decision (`pack`).
    fn judged(&self) -> Option<Judged> {
        None
    }
}

/// How a robot moves in a step ([`Coordinator::steer`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Steer {
    /// Toward the target, along the agent's plan.
    Target,
    /// Nowhere.
    Stay,
    /// Straight to this cell's centre (within a step's length).
    To(Cell),
}

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
        let settings = bids::Settings::new(s, world);
        return if id == base {
            Box::new(executive::Executive::new(id, settings))
        } else {
            Box::new(bids::Bidding::new(id, base, settings))
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
        let settings = roles::Settings::new(s, world, params);
        return Box::new(roles::Roles::new(id, base, settings));
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

/// What a strategy sees when it picks a target (built by the agent once per step).
pub struct Situation<'a> {
    pub id: RobotId,
    pub step: Step,
    /// The robot's cell.
    pub me: Cell,
    /// The planning grid.
    pub grid: &'a Grid,
    /// How many of its cells are known (free or occupied).
    pub known: usize,
    /// This robot's path costs on the planning grid.
    pub costs: &'a CostMap,
    /// The obstacle penalty `costs` were computed with (for other robots' costs; `None`: off).
    pub penalty: Option<&'a [f32]>,
    /// The frontiers it may go to.
    pub candidates: &'a [Cell],
    /// The current target, and whether it is still a usable frontier.
    pub target: Option<Cell>,
    pub valid: bool,
    /// Robots in radio range.
    pub neighbours: &'a BTreeSet<RobotId>,
    /// Other robots' announced targets.
    pub heard: &'a Heard,
}

/// What a strategy may tell others about, after the step's decision.
pub struct Status<'a> {
    pub id: RobotId,
    pub step: Step,
    pub me: Cell,
    pub target: Option<Cell>,
    pub neighbours: &'a BTreeSet<RobotId>,
    /// Per neighbour, the bytes that waited for it after the last step's sending.
    pub backlog: &'a [(RobotId, u64)],
}

/// A coordination message, by strategy (a new strategy that talks adds its variant here, with
/// its radio key segment and package type).
#[derive(Clone, Debug, PartialEq)]
pub enum CoordMsg {
    /// `burgard`: the sub-team table.
    Team(Team),
    /// `bids`: robots' bids on their way to the executive.
    Bids(Bids),
    /// `bids`: the executive's assignment table.
    Tasks(Tasks),
    /// `roles`: a robot's role state, to a robot in range.
    Role(Role),
    /// `pack`: the pack table and the leader's moves.
    Pack(Pack),
}

impl CoordMsg {
    /// The robot that sent it.
    pub fn from(&self) -> RobotId {
        match self {
            CoordMsg::Team(t) => t.from,
            CoordMsg::Bids(b) => b.from,
            CoordMsg::Tasks(t) => t.from,
            CoordMsg::Role(r) => r.from,
            CoordMsg::Pack(p) => p.from,
        }
    }

    /// The package type its bytes are accounted to.
    pub fn traffic(&self) -> Traffic {
        match self {
            CoordMsg::Team(_) => Traffic::Targ,
            CoordMsg::Bids(_) => Traffic::Bid,
            CoordMsg::Tasks(_) => Traffic::Task,
            CoordMsg::Role(_) => Traffic::Role,
            CoordMsg::Pack(_) => Traffic::Move,
        }
    }

    /// The radio key it is sent on, by addressee.
    pub fn key(&self) -> fn(RobotId) -> String {
        match self {
            CoordMsg::Team(_) => proto::keys::radio_team,
            CoordMsg::Bids(_) => proto::keys::radio_bid,
            CoordMsg::Tasks(_) => proto::keys::radio_task,
            CoordMsg::Role(_) => proto::keys::radio_role,
            CoordMsg::Pack(_) => proto::keys::radio_move,
        }
    }

    pub fn encode(&self) -> Vec<u8> {
        match self {
            CoordMsg::Team(t) => encode(t),
            CoordMsg::Bids(b) => encode(b),
            CoordMsg::Tasks(t) => encode(t),
            CoordMsg::Role(r) => encode(r),
            CoordMsg::Pack(p) => encode(p),
        }
    }

    /// Decodes a payload received under key segment `kind` (`None`: not a coordination kind).
    pub fn decode(kind: &str, bytes: &[u8]) -> Option<Result<CoordMsg, DecodeError>> {
        match kind {
            "team" => Some(decode::<Team>(bytes).map(CoordMsg::Team)),
            "bid" => Some(decode::<Bids>(bytes).map(CoordMsg::Bids)),
            "task" => Some(decode::<Tasks>(bytes).map(CoordMsg::Tasks)),
            "role" => Some(decode::<Role>(bytes).map(CoordMsg::Role)),
            "move" => Some(decode::<Pack>(bytes).map(CoordMsg::Pack)),
            _ => None,
        }
    }
}

/// Where a strategy's message goes.
#[derive(Clone, Debug, PartialEq)]
pub enum To {
    /// Every robot in range, within each link's budget.
    Neighbours,
    /// One robot (in range or not: the radio decides whether it arrives).
    Robot(RobotId),
}

#[derive(Clone, Debug, PartialEq)]
pub struct Addressed {
    pub to: To,
    pub msg: CoordMsg,
}

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
pub(crate) fn normalized(frontiers: &[Cell], costs: &CostMap) -> Vec<Option<f64>> {
    let raw: Vec<Option<f64>> = frontiers.iter().map(|&t| costs.cost(t)).collect();
    let max = raw.iter().flatten().fold(0.0f64, |m, &v| m.max(v));
    let scale = if max > 0.0 { max } else { 1.0 };
    raw.into_iter().map(|v| v.map(|v| v / scale)).collect()
}

/// The best frontier by U − β·V; ties go to the lower cost, then to the lower `(y, x)`.
pub(crate) fn best(
    frontiers: &[Cell],
    utility: &[f64],
    cost: &[Option<f64>],
    beta: f64,
) -> Option<usize> {
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
    use super::burgard::{greedy_assignment, permutation_search};
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
