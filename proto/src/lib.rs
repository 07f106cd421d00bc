//! `proto`: everything that crosses a process boundary in swarm-explore.
//!
//! Only this crate's types derive serde for the wire; the algorithm crates use them as plain
//! values. See ARCHITECTURE.md for the map of processes and planes.

pub mod exit;
pub mod geom;
pub mod grid;
pub mod keys;
pub mod msg;
#[cfg(feature = "node")]
pub mod node;
pub mod scenario;
