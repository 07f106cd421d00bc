//! `robot-agent`: one robot of swarm-explore (DESIGN.md §4).
//!
//! The algorithms are pure modules, each named after its thesis concept: [`grid`] (scan
//! integration), [`plan`] (costs, frontiers, paths), [`raw_scans`] (the baseline exchange with
//! transitive logs). [`agent`] composes them into the per-step decision; [`node`] runs it over
//! zenoh; [`cli`] is the command line.

/// The per-step decision loop as a pure state machine.
pub mod agent;
/// Command line and process entry.
pub mod cli;
/// Ternary self-explored grid: laser scan integration.
pub mod grid;
/// The robot on its sim and radio planes.
pub mod node;
/// Path planning: Dijkstra costs, frontiers, waypoints.
pub mod plan;
/// The raw-scans exchange: per-owner logs, handshakes, sent-index table.
pub mod raw_scans;
