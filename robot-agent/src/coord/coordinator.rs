//! The interface between the agent and a coordination strategy ([`Coordinator`]), what a
//! strategy sees each step ([`Situation`], [`Status`]) and the messages strategies send
//! ([`CoordMsg`], addressed by [`To`]).

use std::collections::BTreeSet;

use proto::grid::{Cell, Grid};
use proto::msg::{
    decode, encode, Bids, DecodeError, Judged, Pack, RobotId, Role, Step, Tasks, Team, Traffic,
};

use crate::coord::utility::Heard;
use crate::nav::plan::CostMap;

/// How the agent talks to a coordination strategy, whichever it is.
///
/// A trait object rather than an enum: the strategies share no state (Burgard's sub-team table, a
/// bidding robot's open auctions, a relay's role are each one strategy's business), so an enum
/// would make every method a match over all of them and every new strategy an edit of each match.
/// With the trait, a strategy is one file implementing it, plus a line in
/// [`new`](crate::coord::registry::new) and, if it talks, a variant of [`CoordMsg`]. The agent asks
/// it once per step for a target ([`Coordinator::choose`], given the planning grid, this robot's
/// costs, the candidate frontiers and what was heard of other robots), once per step for its radio
/// messages ([`Coordinator::messages`], given this robot's state and neighbours), and hands it
/// every coordination message received ([`Coordinator::on_message`]). The radio encodes, counts and
/// decodes those messages ([`crate::radio::station`]); a strategy never sees bytes.
pub trait Coordinator: Send {
    /// This step's target: keep `s.target` or pick another (`None`: no target).
    fn choose(&mut self, s: &Situation<'_>) -> Option<Cell>;

    /// Whether [`Coordinator::choose`] keeps a valid target (`s.valid`) without looking at
    /// anything else. The agent then searches only for the way to that target while it stays
    /// a frontier ([`crate::nav::plan::path_until`]), and asks `choose` nothing: the step costs
    /// the way to the target, not everything explored.
    fn keeps_valid_target(&self) -> bool {
        false
    }

    /// Whether [`Coordinator::choose`] reads [`Situation::costs`] of the frontiers alone
    /// (the candidates are frontiers). The agent then searches only as far as the farthest
    /// frontier ([`crate::nav::plan::costs_to_frontiers`]), not over everything explored.
    fn looks_at_frontier_costs_only(&self) -> bool {
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
