//! `bids` (Simmons et al., "Coordination for multi-robot exploration and mapping", AAAI 2000):
//! robots offer frontier cells with their cost and information gain, an executive in the base
//! station assigns tasks greedily with an overlap discount; bids and tasks travel over the
//! radio, relayed by robots in between.

/// The executive: greedy assignment with overlap discount and hysteresis ("Assigning Tasks").
pub mod executive;
/// Constructing bids: frontier cells, information-gain regions, costs ("Constructing Bids").
pub mod offer;
/// Relaying bids and tasks between robots out of the executive's range.
pub mod relay;
/// A bidding robot: it bids, follows its task, decides alone when cut off.
pub mod robot;
