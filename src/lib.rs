//! `swarm`: the launcher of swarm-explore. It starts every process of a run, follows the run on
//! the sim plane, evaluates the robots' maps against the truth and writes the run directory.
//! It also carries every role's entry point (`swarm world-server`, `swarm robot-agent`), so one
//! binary is all a machine needs.
//!
//! The folders, in the order a run uses them: [`run`] starts and follows a run through
//! [`process`] (children, hosts, supervision); [`score`] evaluates what the robots know;
//! [`rundir`] writes what a run leaves; [`sweep`] runs grids of runs and reports them; [`view`]
//! shows a run; [`cmd`] holds the other subcommands.

/// The other subcommands: `swarm chaos`, `swarm replay`, `swarm netem`.
pub mod cmd;
/// Processes: children, free ports, hosts and ssh, supervision and process faults.
pub mod process;
/// `swarm run`: prepare, spawn, follow, finish.
pub mod run;
/// The run directory: `summary.json`, the CSV tables, `steps.log`, pictures.
pub mod rundir;
/// Scoring: coverage and exploration time, team awareness, connectivity.
pub mod score;
/// `swarm sweep`: grids of runs × seeds, results, reports, plots.
pub mod sweep;
/// Seeing a run: the viewer (live and replay), its timeline, MCAP export.
pub mod view;
