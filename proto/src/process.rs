//! The processes of a run by name (`robot-3`, `netem`, …), their kinds, and what a fault or an
//! order does to one: the vocabulary of `[[faults]]`, `[supervise]` and netem's process orders.

use serde::{Deserialize, Serialize};

/// A kind of process of a run.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum ProcessKind {
    Robot,
    Netem,
    BaseStation,
    WorldServer,
}

/// One process of a run, named as its log file in `logs/` is: `robot-<id>`, `netem`,
/// `world-server`, `base-station`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub enum Process {
    Robot(u16),
    Netem,
    BaseStation,
    WorldServer,
}

impl Process {
    pub fn kind(self) -> ProcessKind {
        match self {
            Process::Robot(_) => ProcessKind::Robot,
            Process::Netem => ProcessKind::Netem,
            Process::BaseStation => ProcessKind::BaseStation,
            Process::WorldServer => ProcessKind::WorldServer,
        }
    }
}

impl std::fmt::Display for Process {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Process::Robot(i) => write!(f, "robot-{i}"),
            Process::Netem => f.write_str("netem"),
            Process::BaseStation => f.write_str("base-station"),
            Process::WorldServer => f.write_str("world-server"),
        }
    }
}

impl std::str::FromStr for Process {
    type Err = String;
    fn from_str(s: &str) -> Result<Process, String> {
        match s {
            "netem" => Ok(Process::Netem),
            "base-station" => Ok(Process::BaseStation),
            "world-server" => Ok(Process::WorldServer),
            _ => s
                .strip_prefix("robot-")
                .and_then(|i| i.parse().ok())
                .map(Process::Robot)
                .ok_or_else(|| {
                    format!("{s:?} is no process: robot-<id>, netem, base-station or world-server")
                }),
        }
    }
}

impl Serialize for Process {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        s.collect_str(self)
    }
}

impl<'de> Deserialize<'de> for Process {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Process, D::Error> {
        String::deserialize(d)?
            .parse()
            .map_err(serde::de::Error::custom)
    }
}

/// The largest team (`robots.count`). Robot ids, the base station's included, stay below the
/// log owners' stride (`msg::LIFE_STRIDE`, 1 024). Ports no longer bound it: netem's proxy of a
/// pair listens only while the pair's link is up, on a free port, so the launcher picks one
/// port per process. What a big team costs is in ARCHITECTURE.md ("Team size").
pub const MAX_ROBOTS: u16 = 1000;

/// The `[[faults]]` kinds that act on processes (the launcher's); every other kind is a link
/// fault (netem's).
pub const PROCESS_FAULT_KINDS: [&str; 4] = ["kill", "restart", "freeze", "thaw"];

/// What a process fault does.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case", deny_unknown_fields)]
pub enum ProcessAction {
    /// SIGKILL; started again (same id, next life) after `restart_after` steps if given.
    Kill {
        process: Process,
        #[serde(default, skip_serializing_if = "Option::is_none")]
        restart_after: Option<u32>,
    },
    /// SIGKILL and started again at once (same ports; a robot in its next life).
    Restart { process: Process },
    /// SIGSTOP: the process stays, silent (a robot misses its steps and is declared dead after
    /// `clock.dead_after` of them).
    Freeze { process: Process },
    /// SIGCONT: a frozen process goes on (a robot declared dead meanwhile rejoins).
    Thaw { process: Process },
}

impl ProcessAction {
    pub fn process(&self) -> Process {
        match self {
            ProcessAction::Kill { process, .. }
            | ProcessAction::Restart { process }
            | ProcessAction::Freeze { process }
            | ProcessAction::Thaw { process } => *process,
        }
    }

    /// The kind's name in `[[faults]]`.
    pub fn name(&self) -> &'static str {
        match self {
            ProcessAction::Kill { .. } => "kill",
            ProcessAction::Restart { .. } => "restart",
            ProcessAction::Freeze { .. } => "freeze",
            ProcessAction::Thaw { .. } => "thaw",
        }
    }
}
