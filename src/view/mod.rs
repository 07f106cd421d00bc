//! Seeing a run: a web page following it live (`swarm run --view`) or replaying it
//! (`swarm view`), and the run in Foxglove — live (`swarm run --foxglove`), replayed
//! (`swarm view --foxglove`) or as MCAP (`swarm export-mcap`).

/// `swarm export-mcap`: a run as MCAP in Foxglove's schemas, from its step log.
pub mod export_mcap;
/// The step log as Foxglove messages through Foxglove's SDK, for a file or a live client.
pub mod foxglove;
/// The viewer's HTTP and WebSocket server.
pub mod server;
/// A run step by step from its step-log records: frames, chart series, robot details.
pub mod timeline;
