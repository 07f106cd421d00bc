//! `robot-agent`: one robot of swarm-explore (docs/design.md §4).
//!
//! The algorithms are pure modules, each named after its thesis concept: [`grid`] (scan
//! integration), [`contour`] (P_t, §4.1), [`approx`] (A_t), [`approximator`] + [`refine`] (A_t
//! from A_{t−1} and P_t, Douglas–Peucker, §4.2–4.3), [`delta`] + [`oplog`] + [`wire`] (edit
//! scripts, save points, encoding, §4.2.3), [`render`] + [`merge`] (approximations painted onto
//! cells, the planning grid, §5.2), [`approx_error`] (d_t and e_avg, eq. 6.1), [`plan`] (costs,
//! frontiers, paths), [`raw_scans`] (the baseline exchange with transitive logs). [`agent`]
//! composes them into the per-step decision with the parts around them — [`sharing`] (the
//! exchange modes), [`coord`] (the coordination strategies), [`right_of_way`] and [`radio`];
//! [`node`] runs it over zenoh; [`cli`] is the command line.
//!
//! The mapping modules import each other in one direction only, each from those before it:
//! [`contour`] → [`approx`] → [`render`] → [`refine`] → [`approximator`] → [`merge`] and
//! [`approx_error`] (the last two import only [`approx`] and [`render`]); [`mapper`] runs the
//! pipeline on top of them.

/// The per-step decision loop as a pure state machine.
pub mod agent;
/// Polygonal approximations A_t and edge occupancy (§4.2.2).
pub mod approx;
/// The approximation error d_t and e_avg (§6.1, eq. 6.1).
pub mod approx_error;
/// The polygon exchange: op logs of approximations, replicas shown at save points (§5.1).
pub mod approx_exchange;
/// The incremental approximation: A_t from A_{t−1} and P_t (§4.2.1).
pub mod approximator;
/// Command line and process entry.
pub mod cli;
/// Contour extraction: the exact polygonal model P_t (§4.1).
pub mod contour;
/// Coordination: the strategy interface, utilities and discounts (§4.4–4.5), one file per
/// strategy (decentralized, Burgard, uncoordinated).
pub mod coord;
/// Edit scripts between approximations: the delta ops (§4.2.3, Algorithms 4–5).
pub mod delta;
/// Transitive exchange of append-only logs (thesis §5.1.2, Algorithm 8).
pub mod exchange;
/// Ternary self-explored grid: laser scan integration.
pub mod grid;
/// The grid-snapshots baseline exchange: per-step changed cells of G_s (docs/design.md §4.8).
pub mod grid_snapshots;
/// The step protocol of lockstep runs: markers, the barrier, the order arrivals are taken in.
pub mod lockstep;
/// The mapping pipeline: P_t → A_t → ops + save point, with its costs (Algorithm 10, 2–5).
pub mod mapper;
/// The planning grid: Algorithm 9 (§5.2).
pub mod merge;
/// The robot on its sim and radio planes.
pub mod node;
/// The op log with save points and a receiver's replica (§4.2.3).
pub mod oplog;
/// Pacing: per-link byte budgets on the simulated clock (§4.4, `proto::budget`).
pub mod pacing;
/// Path planning: Dijkstra costs, frontiers, waypoints.
pub mod plan;
/// Quarter-cell integer coordinates of contour vertices.
pub mod qpoint;
/// The radio side: neighbours, pacing, backlog; every message encoded and counted once.
pub mod radio;
/// Rasterizing quarter-cell polygons onto cells (scan-line fill, edges).
pub mod raster;
/// The raw-scans exchange: per-owner logs, handshakes, sent-index table.
pub mod raw_scans;
/// A robot's estimate of the radio from its own map: reach from a place, links between two.
pub mod reach;
/// Douglas–Peucker refinement over all polygons with one priority queue (§4.3).
pub mod refine;
/// Painting approximations onto cells: Algorithm 9's steps (1)–(5), renders, exploration view.
pub mod render;
/// de Hoog et al. §III-D, §IV: where and by when a child meets its parent (rendezvous points,
/// estimated radio reach, the parent's predicted trip).
pub mod rendezvous;
/// Right of way: rejected moves and blacklist, bumps, giving way, planning around.
pub mod right_of_way;
/// What a robot shares over the radio: one implementation per exchange mode.
pub mod sharing;
/// de Hoog et al. §IV: Hilditch's thinning of the free space and rendezvous points on it.
pub mod skeleton;
/// The splitting frequency s from the bandwidth: eq. 5.5/5.6 or closed loop (§5.3).
pub mod splitting;
/// The compact wire encoding of delta ops (Table 6.1).
pub mod wire;

#[cfg(test)]
mod testutil;
