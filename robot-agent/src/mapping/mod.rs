//! The mapping core (thesis §4, Algorithm 10 steps 1–5; §5.2): from a laser scan to the grid a
//! robot plans on. Files import each other in one direction only, each from those listed before
//! it.

/// Polygonal approximations A_t and edge occupancy (§4.2.2).
pub mod approx;
/// The approximation error d_t and e_avg (§6.1, eq. 6.1).
pub mod approx_error;
/// The incremental approximation: A_t from A_{t−1} and P_t (§4.2.1).
pub mod approximator;
/// Contour extraction: the exact polygonal model P_t (§4.1).
pub mod contour;
/// Ternary self-explored grid G_s: laser scan integration.
pub mod grid;
/// The planning grid: G_s merged with the peers' approximations (Algorithm 9, §5.2).
pub mod merge;
/// Approximations painted and kept from step to step, repainted where an object changed.
pub mod painting;
/// Quarter-cell integer coordinates of contour vertices.
pub mod qpoint;
/// Rasterizing quarter-cell polygons onto cells (scan-line fill, edges).
pub mod raster;
/// Douglas–Peucker refinement over all polygons with one priority queue (§4.3).
pub mod refine;
/// Painting approximations onto cells: Algorithm 9's steps (1)–(5), renders, exploration view.
pub mod render;
