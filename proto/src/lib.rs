//! `proto`: everything that crosses a process boundary in swarm-explore.
//!
//! Only this crate's types derive serde for the wire; the algorithm crates use them as plain
//! values. Besides the wire, it holds the little geometry every process agrees on: grids and the
//! one way a line walks through them ([`traverse`]), and (feature `budget`) the byte budget on a
//! simulated clock that robots and netem meter bandwidth with. See ARCHITECTURE.md for the map of processes
//! and planes.

#[cfg(feature = "budget")]
pub mod budget;
#[cfg(feature = "budget")]
pub mod clock;
pub mod confine;
pub mod exit;
pub mod geom;
pub mod graph;
pub mod grid;
pub mod grid_report;
pub mod ids;
pub mod keys;
pub mod msg;
#[cfg(feature = "node")]
pub mod node;
pub mod pathloss;
pub mod process;
pub mod scenario;
/// How long a lockstep step may take on the wall clock: the world's wait, a robot's patience.
pub mod step_wait;
pub mod traverse;
