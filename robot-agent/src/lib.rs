//! `robot-agent`: one robot of swarm-explore (docs/design.md §4).
//!
//! The folders follow a robot's data, in the order it flows through a step (Meier, Stachniss and
//! Burgard 2005; "the thesis" is Meier's diploma thesis, whose numbering the code follows):
//!
//! scan → [`mapping`] (grid G_s, contours P_t, approximation A_t, painting, the planning grid) →
//! [`exchange`] (deltas and op logs, their wire encoding, the transitive exchange, the exchange
//! modes) → [`radio`] (neighbours, budgets, the step protocol) → [`coord`] (which frontier) →
//! [`nav`] (paths, right of way) → move.
//!
//! [`agent`] composes them into the per-step decision as a pure state machine; [`node`] runs it
//! over zenoh; [`cli`] is the command line. Within a folder, files import each other in one
//! direction only (checked by the layout test in the launcher's integration tests).

/// Coordination: which frontier a robot goes to (§4.4–4.5 and the strategies of four papers).
pub mod coord;
/// Delta ops and op logs, their encoding, the transitive exchange, the exchange modes (§4.2.3, §5).
pub mod exchange;
/// Scan integration, contours, the incremental polygonal approximation, painting, merging (§4).
pub mod mapping;
/// Navigation: Dijkstra costs, frontiers, waypoints, right of way.
pub mod nav;
/// The radio side: neighbours, pacing, the lockstep step protocol, reach estimates.
pub mod radio;

/// The per-step decision loop as a pure state machine.
pub mod agent;
/// Command line and process entry.
pub mod cli;
/// The robot on its sim and radio planes.
pub mod node;

#[cfg(test)]
mod testutil;
