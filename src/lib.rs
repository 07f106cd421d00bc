//! `swarm`: the launcher of swarm-explore. It starts every process of a run, follows the run on
//! the sim plane, evaluates the robots' maps against the truth and writes the run directory.
//! It also carries every role's entry point (`swarm world-server`, `swarm robot-agent`), so one
//! binary is all a machine needs.

/// Team awareness (de Hoog et al. 2010, Fig. 5): team coverage, shared knowledge, contact with
/// the base station.
pub mod awareness;
/// `swarm chaos`: random process and link faults, one run, a checker.
pub mod chaos;
/// Child processes: spawn, watch, reap.
pub mod children;
/// Who can talk over a step's links: the communication level (Rooker and Birk 2005) and the
/// `pack` leaders' link judgements checked against netem.
pub mod connectivity;
/// `[[curve]]` of a sweep report: a `metrics.csv` column over the steps, averaged over seeds.
pub mod curve;
/// Coverage and exploration time from telemetry.
pub mod evaluate;
/// `swarm export-mcap`: a run as MCAP in Foxglove's schemas, from its step log.
pub mod export_mcap;
/// Where the processes of a run go: the hosts file (`swarm run --hosts`) and its placement.
pub mod hosts;
/// `swarm netem`: the netem process and runtime link control over its HTTP API.
pub mod netemctl;
/// Charts (SVG and PNG) of a sweep's results.
pub mod plot;
/// Free ports (loopback, or a host's address).
pub mod ports;
/// Progress lines on stderr (`swarm run`, `swarm sweep`).
pub mod progress;
/// Starting processes on a host (ssh, a command prefix) and `swarm host-info`.
pub mod remote;
/// PNG pictures of grids and trajectories.
pub mod render;
/// `swarm replay`: one robot, no network, the mapping pipeline measured.
pub mod replay;
/// A sweep's report: plots, tables, report.md.
pub mod report;
/// A sweep's results: runs.csv and results.csv (means, std, 95 % intervals).
pub mod results;
/// `swarm run`.
pub mod run;
/// The run directory's files.
pub mod rundir;
/// The run's step log (`steps.log`): per step, robots, links and grid changes, for replay.
pub mod steplog;
/// Supervision and process faults: kill, restart, freeze, thaw; restarts by policy.
pub mod supervise;
/// `swarm sweep`: grids of runs × seeds, run a few at a time, resumable.
pub mod sweep;
/// A run step by step from its step-log records: frames, chart series, robot details (the viewer's).
pub mod timeline;
/// The run viewer: a web page following a run live (`swarm run --view`) or replaying one (`swarm view`).
pub mod view;
