//! Seeing a run: a web page following it live (`swarm run --view`) or replaying it
//! (`swarm view`), and the run as MCAP for Foxglove (`swarm export-mcap`).

/// `swarm export-mcap`: a run as MCAP in Foxglove's schemas, from its step log.
pub mod export_mcap;
/// The viewer's HTTP and WebSocket server.
pub mod server;
/// A run step by step from its step-log records: frames, chart series, robot details.
pub mod timeline;
