//! Navigation on the planning grid: where a robot can go and how it gets there.

/// Path planning: Dijkstra costs, frontiers, waypoints.
pub mod plan;
/// Right of way: rejected moves and blacklist, bumps, giving way, planning around.
pub mod right_of_way;
