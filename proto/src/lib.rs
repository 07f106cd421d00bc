//! `proto`: everything that crosses a process boundary in swarm-explore.
//!
//! Only this crate's types derive serde for the wire; the algorithm crates use them as plain
//! values. Besides the wire, it holds the little geometry every process agrees on: grids and the
//! one way a line walks through them ([`traverse`]). See ARCHITECTURE.md for the map of processes
//! and planes.

pub mod geom;
pub mod grid;
pub mod keys;
pub mod msg;
#[cfg(feature = "node")]
pub mod node;
pub mod scenario;
pub mod traverse;
