//! What robots share and how (thesis §4.2.3, §5.1, §5.3): edit scripts between approximations,
//! op logs with save points, their compact encoding, the transitive exchange of logs, and one
//! implementation per exchange mode (`exchange.mode`).

/// Edit scripts between approximations: the delta ops (§4.2.3, Algorithms 4–5).
pub mod delta;
/// `grid-snapshots`: the second baseline, per-step changed cells of G_s.
pub mod grid_snapshots;
/// The mapping pipeline: P_t → A_t → ops + save point, with its costs (Algorithm 10, 2–5).
pub mod mapper;
/// The op log with save points and a receiver's replica (§4.2.3).
pub mod oplog;
/// `polygon`: op logs of approximations, replicas shown at save points (§5.1).
pub mod polygon;
/// `raw-scans`: the baseline, per-owner logs of laser scans.
pub mod raw_scans;
/// The relay tree: from which neighbour a robot takes each owner's log.
pub mod relay;
/// What a robot shares over the radio: the exchange modes behind one interface.
pub mod sharing;
/// The splitting frequency s from the bandwidth: eq. 5.5/5.6 or closed loop (§5.3).
pub mod splitting;
/// The transitive exchange of append-only logs (§5.1.2, Algorithm 8).
pub mod transitive;
/// The compact wire encoding of delta ops (Table 6.1).
pub mod wire;
