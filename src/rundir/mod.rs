//! The run directory: a stable, documented schema users script against (docs/run-directory.md).
//! Names of files and fields do not change without a version bump
//! ([`summary::SCHEMA_VERSION`](crate::rundir::summary::SCHEMA_VERSION)).

/// The grids (`grids/`) as ROS map_server maps: PGM and YAML.
pub mod grids;
/// PNG pictures of grids and trajectories.
pub mod render;
/// The run's step log (`steps.log`): per step, robots, links and grid changes, for replay.
pub mod steplog;
/// `summary.json`, typed.
pub mod summary;
/// The CSV tables as serde rows.
pub mod tables;
