//! `roles` (de Hoog, Cameron and Visser, "Autonomous multi-robot exploration in
//! communication-limited environments", TAROS 2010):
//! explorers and relays in branches below the base station, meeting at rendezvous points.

/// The hierarchy, the roster of places, the role swap rule.
pub mod hierarchy;
/// Where and by when a child meets its parent (§III-D, §IV).
pub mod rendezvous;
/// A robot's role, its state machines (Fig. 2), the strategy.
pub mod robot;
/// Hilditch's thinning of the free space and rendezvous points on it (§IV).
pub mod skeleton;
