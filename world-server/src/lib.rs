//! `world-server`: the simulated world of swarm-explore (docs/design.md §3).
//!
//! Pure modules (no I/O but reading map files): [`map`], [`generate`], [`reachable`], [`laser`],
//! [`motion`], [`world`]. The zenoh side: [`server`], and the refused logins it logs
//! ([`refusals`]); the command line: [`cli`].

/// Command line and process entry.
pub mod cli;
/// Generated worlds: unstructured, mixed, office.
pub mod generate;
/// Map images: PGM (P2/P5) and PNG decoding with map_server's classification.
pub mod image;
/// Laser ray casting on the truth map.
pub mod laser;
/// ROS map_server maps: loading and resampling.
pub mod map;
/// Move validation: straight segments through free cells, robot collisions.
pub mod motion;
/// The reachable free region and spawn placement.
pub mod reachable;
/// Refused logins on the sim plane, in the log: once per address, then counted.
pub mod refusals;
/// A scenario made ready to run: file or default, overrides, the map found, the range.
pub mod scenario;
/// The clock and the sim-plane protocol over zenoh.
pub mod server;
/// The maps the binary carries, and where a scenario's map comes from.
pub mod shipped;
/// The world's state and its step.
pub mod world;
