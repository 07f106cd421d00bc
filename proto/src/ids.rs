//! The two numbers every message and table is keyed by.

/// A node of the radio: robots `0..robots.count`, then the base station.
pub type RobotId = u16;
/// A step of the simulated clock.
pub type Step = u32;
