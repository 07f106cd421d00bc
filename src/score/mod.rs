//! What the robots know, scored against the truth, step by step.

/// Team awareness (de Hoog et al. 2010, Fig. 5): team coverage, shared knowledge, contact with
/// the base station.
pub mod awareness;
/// Who can talk over a step's links: the communication level (Rooker and Birk 2005) and the
/// `pack` leaders' link judgements checked against netem.
pub mod connectivity;
/// Coverage and exploration time from telemetry.
pub mod evaluate;
/// Map fidelity: whether what a robot's planning grid believes free is free in the truth.
pub mod fidelity;
/// The map the team has to learn, for the information floor of a run's radio bytes.
pub mod floor;
