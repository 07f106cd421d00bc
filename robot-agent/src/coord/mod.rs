//! Coordination: which frontier a robot goes to (thesis §4.4–4.5, Burgard et al. §II;
//! docs/design.md §4.6). Pure functions over the planning grid, the frontiers and Dijkstra costs
//! ([`crate::nav::plan`]); the agent supplies what it heard from other robots.
//!
//! This module holds what every strategy shares — the utility and discount arithmetic below, the
//! table of other robots' announced targets ([`Heard`](crate::coord::utility::Heard)) and the
//! interface ([`Coordinator`](crate::coord::coordinator::Coordinator)) — and one file per strategy
//! holds its state and its messages: [`decentralized`](crate::coord::decentralized),
//! [`burgard`](crate::coord::burgard), [`uncoordinated`](crate::coord::uncoordinated),
//! [`bids`](crate::coord::bids) (with [`bids::executive`](crate::coord::bids::executive) and
//! [`bids::relay`](crate::coord::bids::relay)), [`roles`](crate::coord::roles) (with
//! [`roles::hierarchy`](crate::coord::roles::hierarchy)), [`pack`](crate::coord::pack);
//! [`team`](crate::coord::team) is the team table `burgard` and `pack` share.
//! [`new`](crate::coord::registry::new) registers them by `coordination.strategy`.
//!
//! * Utility (thesis eq. 4.4, Burgard eq. 1): every frontier cell starts at U = 1; a target t'
//!   chosen by another robot lowers the utility of every frontier t by P(‖t − t'‖), the
//!   probability that the robot at t' will see t: P(d) = 1 − d / max_range below the laser's
//!   range, 0 beyond it and 0 without line of sight (eq. 4.5).
//! * Trade-off (eq. 4.6): the robot picks argmax U_t − β·V_t. V is the Dijkstra cost normalized by
//!   the robot's largest frontier cost, so that U and V are on the same [0, 1] scale and β keeps
//!   the meaning Burgard et al. give it (exploration time flat for β in [0.01, 50]).
//! * `decentralized` (thesis §4.5.1): the other targets are those in the robot's table (heard as
//!   `targ` from robots in range). Beyond the thesis (its §7.2): a target's discount decays with
//!   its age, halving every `half_life` steps.
//! * `burgard` (Algorithm 1): the sub-team that can talk, transitively, assigns targets greedily —
//!   the best (robot, frontier) pair first, then the utilities discounted by it, and so on — on one
//!   robot's data; every member computes the same assignment and takes its own.
//!   [`permutation_search`](crate::coord::burgard::permutation_search) is Algorithm 2's alternative
//!   (randomized search with hill-climbing over Σ U − β·V², favouring balanced trajectories).
//! * `uncoordinated`: the nearest frontier ([`crate::nav::plan::nearest`]).

/// The interface between the agent and a strategy, and the messages strategies send.
pub mod coordinator;
/// The strategies by `coordination.strategy`.
pub mod registry;
/// Utility, discount and the table of heard targets, shared by every strategy.
pub mod utility;

/// `bids` (Simmons et al. 2000): bids to an executive in the base station.
pub mod bids;
/// `burgard` (Burgard et al. 2005, Algorithms 1–2): sub-team assignment.
pub mod burgard;
/// `decentralized` (thesis §4.5.1): discounted utility from the targets heard.
pub mod decentralized;
/// `pack` (Rooker and Birk 2005): each connected group's leader moves its group.
pub mod pack;
/// `roles` (de Hoog et al. 2010): explorers and relays below the base station.
pub mod roles;
/// The team table `burgard` and `pack` share.
pub mod team;
/// `uncoordinated`: the nearest frontier.
pub mod uncoordinated;

pub use coordinator::{Addressed, CoordMsg, Coordinator, Situation, Status, Steer, To};
pub use registry::new;
pub use utility::{
    best, coverage_probability, decay, discount, line_of_sight, normalized, Announcement, Heard,
    Params,
};
