//! Why a run ended — one vocabulary for the world-server (which ends its own loop at the step
//! limit or when every robot is dead) and the launcher (which also ends a run when the map is
//! explored, every robot is idle, a process it cannot do without exited, or on a signal).
//! Serialized as `summary.json`'s `exit_reason` strings.

use serde::{Deserialize, Serialize};

#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum ExitReason {
    /// Some robot's planning grid knows `done_pct` % of the reachable free cells.
    Explored,
    /// The step limit (`max_steps`) was reached.
    MaxSteps,
    /// Every live robot saw no reachable frontier for a few steps in a row, and no robot's
    /// planning grid held a frontier inside the world's reachable area: nothing the robots could
    /// reach was left to explore.
    NoFrontiers,
    /// Every live robot saw no reachable frontier for a few steps in a row while some robot's
    /// planning grid still held a frontier inside the world's reachable area: the robots gave
    /// up space they could have reached (their maps closed a way that is open).
    Stalled,
    AllRobotsDead,
    /// The world-server process exited (it is the sim plane: nothing goes on without it).
    WorldServerExited,
    /// The netem process exited (no radio link is left).
    NetemExited,
    /// SIGINT (Ctrl-C).
    Interrupted,
    /// SIGTERM.
    Terminated,
    /// The launcher's own sim-plane subscription closed (not expected while it runs).
    SimPlaneClosed,
}

impl ExitReason {
    pub const ALL: [ExitReason; 10] = [
        ExitReason::Explored,
        ExitReason::MaxSteps,
        ExitReason::NoFrontiers,
        ExitReason::Stalled,
        ExitReason::AllRobotsDead,
        ExitReason::WorldServerExited,
        ExitReason::NetemExited,
        ExitReason::Interrupted,
        ExitReason::Terminated,
        ExitReason::SimPlaneClosed,
    ];

    /// The name in `summary.json` (the serde name).
    pub fn as_str(self) -> &'static str {
        match self {
            ExitReason::Explored => "explored",
            ExitReason::MaxSteps => "max-steps",
            ExitReason::NoFrontiers => "no-frontiers",
            ExitReason::Stalled => "stalled",
            ExitReason::AllRobotsDead => "all-robots-dead",
            ExitReason::WorldServerExited => "world-server-exited",
            ExitReason::NetemExited => "netem-exited",
            ExitReason::Interrupted => "interrupted",
            ExitReason::Terminated => "terminated",
            ExitReason::SimPlaneClosed => "sim-plane-closed",
        }
    }
}

impl std::fmt::Display for ExitReason {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.as_str())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_are_the_serde_names_and_parse_back() {
        #[derive(Serialize, Deserialize)]
        struct Row {
            r: ExitReason,
        }
        for r in ExitReason::ALL {
            let text = toml::to_string(&Row { r }).unwrap_or_default();
            assert_eq!(text.trim(), format!("r = \"{}\"", r.as_str()));
            let back: Result<Row, _> = toml::from_str(&text);
            assert_eq!(back.map(|b| b.r).ok(), Some(r));
        }
        assert_eq!(
            ExitReason::WorldServerExited.to_string(),
            "world-server-exited"
        );
    }
}
