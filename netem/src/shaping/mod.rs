//! Shaping one direction of one connection (docs/design.md §5 "Shaping"), after noxious /
//! toxiproxy: every network effect is one file with one plain async function from an input stream
//! of [`chunk::Chunk`](crate::shaping::chunk::Chunk)s to an output sink;
//! [`pipeline`](crate::shaping::pipeline) joins them.

/// Bytes pass as fast as their budgets allow.
pub mod bandwidth;
/// Byte budgets on the simulated clock (governor).
pub mod budget;
/// Chunks, a direction's live parameters, the seeded generator of random effects.
pub mod chunk;
/// Flipping bits (`corrupt`).
pub mod corrupt;
/// The one harness every effect is tested through.
#[cfg(test)]
pub(crate) mod harness;
/// Holding chunks until they are due (`latency`, jitter).
pub mod latency;
/// The pipeline: source, stages, sink, one future per direction.
pub mod pipeline;
/// Cutting writes into smaller, spaced ones (`slicer`).
pub mod slicer;
/// Passing the sender's close on late (`slow_close`).
pub mod slow_close;

pub use budget::Budget;
pub use chunk::{Chunk, DirShape, Limit, Rng, Slicing, CHUNK_MAX};
