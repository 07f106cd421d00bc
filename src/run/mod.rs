//! `swarm run`: one exploration run, every participant its own OS process.
//!
//! `prepare`: resolve the scenario, create the run directory, pick the ports →
//! `spawn`: start the world-server (sim-plane router), join the sim plane, fetch the truth,
//! start netem and the robots → `follow`: status and telemetry (evaluate, show progress,
//! watch children) until done, the step limit, a failure or a signal → `finish`: stop
//! everyone, reap every child, write the run directory.

/// The flags of `swarm run` and how a run ended.
pub mod args;
/// Stopping everyone and writing the run directory.
mod finish;
/// Following the run: status, telemetry, children.
mod follow;
/// `swarm run` from its flags to its outcome.
pub mod launch;
/// Resolving the scenario, the run directory, the ports.
mod prepare;
/// Progress lines on stderr (`swarm run`, `swarm sweep`).
pub mod progress;
/// The run's secrets: sim-plane logins, netem's token.
mod secrets;
/// Starting the world-server, netem and the robots.
mod spawn;
/// Telemetry taken a whole step at a time, in robot order (lockstep runs).
mod steps;
/// The per-step tables, written as the steps close.
pub(crate) mod tables;

pub use args::{Outcome, RunArgs};
pub use launch::run;
