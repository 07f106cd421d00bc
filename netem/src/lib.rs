//! netem: the link emulator of swarm-explore (docs/design.md §5).
//!
//! A byte-level proxy, not a simulator: one TCP listener per unordered robot pair {a, b}
//! (a < b). Robot a's radio session connects to it; netem forwards to robot b's radio listener,
//! and every byte the robots exchange crosses it. Per link and direction netem shapes the bytes
//! on the *simulated* clock (bandwidth per link, or one channel shared in airtime, latency, jitter, lost frames), cuts the
//! link when the radio model says the robots are out of range, injects faults (toxiproxy's
//! toxics, over a toxiproxy-compatible HTTP API too), and counts what crossed. Only [`node`]
//! touches zenoh: it reads poses from the sim plane, calls [`Netem::on_step`] and publishes the
//! per-step link reports; [`cli`] is the command line.
//!
//! **Invariants:** memory is bounded — every connection direction holds at most
//! `buffer_bytes`, then netem stops reading and TCP pushes back on the sender; every channel and
//! table is bounded; nothing a peer or an API client sends can panic the process.
//!
//! Entry points: [`start`] with a [`NetemConfig`], then [`Netem::on_step`] once per step,
//! [`Netem::telemetry`] for links.csv, [`Netem::apply`] for runtime faults.

// Tests may unwrap (the brief); library code never does on anything from outside.
#![cfg_attr(test, allow(clippy::unwrap_used))]

/// Byte counters per link and direction, and the bounded per-connection buffer.
pub mod accounting;
/// Airtime on one shared channel: max-min fair shares over the interference graph (pure).
pub mod airtime;
/// The channel step by step in lockstep: shares and lost frames for the plan, use for the tables.
pub mod channel;
/// Command line and process entry.
pub mod cli;
/// The state the handle, the HTTP API and the tasks share; applying faults to links.
pub mod control;
/// The fault vocabulary: cut, partition, reset, and toxiproxy's toxics; folding them into shapes.
pub mod faults;
/// The file descriptors netem holds (two per pair) and raising the limit on them.
pub mod fds;
/// The toxiproxy-compatible HTTP API (on axum).
pub mod http;
/// One robot pair's proxy: accept loop, connections (held while the link is down), up/down
/// state, cut.
pub mod link;
/// Prometheus text exposition of the link counters.
pub mod metrics;
/// Configuration, start, per-step entry point, telemetry, runtime control, shutdown.
pub mod netem;
/// netem on the sim plane: poses in, link reports out.
pub mod node;
/// Radio models: always, disk, log-distance path loss with walls on the truth map; shadowing,
/// fading and the seeded loss draws.
pub mod radio;
/// The per-direction pipeline of network effects (corrupt, bandwidth, latency) and its harness.
pub mod shaping;
/// One link's row of links.csv: its state and counters at the end of a step.
pub mod telemetry;

pub use crate::control::NetemError;
pub use crate::faults::{Fault, Pair, ScheduledFault, Stream, Toxic, ToxicKind};
pub use crate::netem::{start, Netem, NetemConfig, PairSpec};
pub use crate::telemetry::LinkTelemetry;
