//! The robot's side of the radio: who is in range, what fits each link's budget, every byte
//! counted once, and the lockstep step protocol.

/// Opening radio sessions as links come up (netem's proxies listen while a link is up).
pub mod dial;
/// The step protocol of lockstep runs: markers, the barrier, the order arrivals are taken in.
pub mod lockstep;
/// Per-link byte budgets on the simulated clock (thesis §4.4, `proto::budget`).
pub mod pacing;
/// A robot's estimate of the radio from its own map: reach from a place, links between two.
pub mod reach;
/// Neighbours, pacing, backlog; every message encoded and counted once.
pub mod station;
