//! Subcommands beside `swarm run`, `swarm sweep` and the viewer.

/// `swarm chaos`: random process and link faults, one run, a checker.
pub mod chaos;
/// `swarm maps`: the carried maps and the generated worlds.
pub mod maps;
/// `swarm netem`: the netem process and runtime link control over its HTTP API.
pub mod netemctl;
/// `swarm replay`: one robot, no network, the mapping pipeline measured.
pub mod replay;
