//! `netem`: the link emulator of swarm-explore (DESIGN.md §5) — one TCP proxy per robot pair,
//! radio models, shaping, faults and byte accounting.
//!
//! **Not built yet** (issue #3). Until then `swarm run` links the robots' radio sessions
//! directly and reports `bytes_wire_total = null`.
