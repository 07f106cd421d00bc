//! Every zenoh key expression of swarm-explore. Nobody formats a key by hand elsewhere.
//!
//! Sim plane: `sim/...` (not range-limited, not counted as radio traffic). Radio plane:
//! `radio/...` (only over netem's per-pair links).

use crate::ids::RobotId;

/// Queryable of the world-server: replies [`crate::msg::WorldInfo`].
pub const WORLD_INFO: &str = "sim/world/info";
/// Queryable of the world-server: replies [`crate::msg::TruthMap`] (launcher only).
pub const WORLD_TRUTH: &str = "sim/world/truth";
/// The world-server's per-step [`crate::msg::Status`].
pub const STATUS: &str = "sim/status";
/// netem's per-step [`crate::msg::LinkReport`].
pub const NETEM_LINKS: &str = "sim/netem/links";
/// netem's per-step [`crate::msg::LinkPlan`]s, one per node (see [`plan`]).
pub const PLAN_ALL: &str = "sim/robot/*/plan";
/// netem's liveliness token, declared once it follows the world's status (lockstep robots wait
/// for it before they join).
pub const NETEM_ALIVE: &str = "sim/netem/alive";
/// Every robot's telemetry.
pub const TELEMETRY_ALL: &str = "sim/telemetry/*";
/// Every robot's move command.
pub const CMD_ALL: &str = "sim/robot/*/cmd";
/// Control messages from the launcher.
pub const CONTROL: &str = "sim/ctl/run";
/// Process faults asked for at runtime through netem's API, which netem forwards to the
/// launcher ([`crate::msg::ProcessOrder`]).
pub const PROCESS_ORDERS: &str = "sim/ctl/process";
/// The world-server's liveliness token: when it vanishes, the run is over for everybody.
pub const WORLD_ALIVE: &str = "sim/world/alive";
/// Liveliness tokens of robots on the sim plane (the world-server waits for all of them).
pub const SIM_ALIVE_ALL: &str = "sim/alive/*";
/// Liveliness tokens on the radio plane: a peer's token vanishes when its link does.
pub const RADIO_ALIVE_ALL: &str = "radio/alive/*";

pub fn scan(id: RobotId) -> String {
    format!("sim/robot/{id}/scan")
}

/// netem's per-step [`crate::msg::LinkPlan`] for node `id`: which of its links are up for the
/// step (a lockstep robot waits for it before it acts). One per node, so that what a robot
/// receives grows with its neighbours, not with the team's pairs.
pub fn plan(id: RobotId) -> String {
    format!("sim/robot/{id}/plan")
}

pub fn cmd(id: RobotId) -> String {
    format!("sim/robot/{id}/cmd")
}

/// Robot `id` answers queries on this key with what it holds of every owner's polygonal
/// approximation ([`crate::msg::Held`]): asked by the viewer, never on the step's path.
pub fn held(id: RobotId) -> String {
    format!("sim/robot/{id}/held")
}

/// Every robot's [`held`] key (the launcher may ask any of them).
pub const HELD_ALL: &str = "sim/robot/*/held";

pub fn telemetry(id: RobotId) -> String {
    format!("sim/telemetry/{id}")
}

pub fn sim_alive(id: RobotId) -> String {
    format!("sim/alive/{id}")
}

pub fn radio_alive(id: RobotId) -> String {
    format!("radio/alive/{id}")
}

/// Where `to` receives handshakes.
pub fn radio_hello(to: RobotId) -> String {
    format!("radio/{to}/hello")
}

/// Where `to` receives log deltas.
pub fn radio_delta(to: RobotId) -> String {
    format!("radio/{to}/delta")
}

/// Radio: op chunks of the polygon exchange addressed to robot `to`.
pub fn radio_ops(to: RobotId) -> String {
    format!("radio/{to}/ops")
}

/// Radio: grid patches of the `grid-snapshots` exchange addressed to robot `to`.
pub fn radio_patch(to: RobotId) -> String {
    format!("radio/{to}/patch")
}

/// Radio: sub-team tables (`burgard` coordination) addressed to robot `to`.
pub fn radio_team(to: RobotId) -> String {
    format!("radio/{to}/team")
}

/// Radio: bids (`bids` coordination) addressed to node `to`.
pub fn radio_bid(to: RobotId) -> String {
    format!("radio/{to}/bid")
}

/// Radio: a robot's role state (`roles` coordination) addressed to node `to`.
pub fn radio_role(to: RobotId) -> String {
    format!("radio/{to}/role")
}

/// Radio: the pack table and the leader's moves (`pack` coordination) addressed to node `to`.
pub fn radio_move(to: RobotId) -> String {
    format!("radio/{to}/move")
}

/// Radio: the executive's assignments (`bids` coordination) addressed to node `to`.
pub fn radio_task(to: RobotId) -> String {
    format!("radio/{to}/task")
}

/// Radio: target announcements (`targ`) addressed to robot `to`.
pub fn radio_targ(to: RobotId) -> String {
    format!("radio/{to}/targ")
}

/// Radio: relay-tree routes ([`crate::msg::Routes`]) addressed to robot `to`.
pub fn radio_route(to: RobotId) -> String {
    format!("radio/{to}/route")
}

/// Radio: a step's frame ([`crate::msg::Frame`]: its messages and its marker, lockstep with step
/// markers) addressed to robot `to`: the robot's radio address itself. Its kind is `frame`.
/// (zenoh sends a declared key's string once per session, then its id: shortening the radio
/// plane's keys from `radio/` to `r/` saved 208 of the default run's 145 948 wire bytes.)
pub fn radio_frame(to: RobotId) -> String {
    format!("radio/{to}")
}

/// Every `<kind>` a `radio/<to>/<kind>` key of ours has (one per `radio_*` function above).
pub const RADIO_KINDS: &[&str] = &[
    "hello", "delta", "ops", "patch", "team", "bid", "role", "move", "task", "targ", "frame",
    "route",
];

/// Everything on the radio addressed to robot `to` (`radio/<to>` and `radio/<to>/<kind>`).
pub fn radio_inbox(to: RobotId) -> String {
    format!("radio/{to}/**")
}

/// The key of kind `kind` (one of [`RADIO_KINDS`]) addressed to robot `to`.
pub fn radio_key(to: RobotId, kind: &str) -> String {
    if kind == "frame" {
        radio_frame(to)
    } else {
        format!("radio/{to}/{kind}")
    }
}

/// The `<kind>` of a `radio/<to>/<kind>` key (`hello`, `delta`, `ops`, `patch`, `targ`, `team`,
/// ...), and `frame` for `radio/<to>`.
pub fn radio_kind(key: &str) -> Option<&str> {
    let mut parts = key.split('/');
    match (parts.next(), parts.next(), parts.next(), parts.next()) {
        (Some("radio"), Some(to), Some(kind), None) if to.parse::<RobotId>().is_ok() => Some(kind),
        (Some("radio"), Some(to), None, None) if to.parse::<RobotId>().is_ok() => Some("frame"),
        _ => None,
    }
}

/// The robot id at the end of a key such as `sim/alive/3` or `sim/telemetry/3`, or the middle
/// of `sim/robot/3/cmd`.
pub fn robot_of(key: &str) -> Option<RobotId> {
    let mut parts = key.split('/');
    match (parts.next(), parts.next(), parts.next(), parts.next()) {
        (Some("sim"), Some("robot"), Some(id), Some(_)) => id.parse().ok(),
        (Some(_), Some(_), Some(id), None) => id.parse().ok(),
        _ => None,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn radio_kinds_are_the_last_segment_of_our_radio_keys() {
        assert_eq!(radio_kind(&radio_hello(3)), Some("hello"));
        assert_eq!(radio_kind(&radio_ops(3)), Some("ops"));
        assert_eq!(radio_kind(&radio_team(0)), Some("team"));
        let ours: [fn(RobotId) -> String; 12] = [
            radio_hello,
            radio_delta,
            radio_ops,
            radio_patch,
            radio_team,
            radio_bid,
            radio_role,
            radio_move,
            radio_task,
            radio_targ,
            radio_frame,
            radio_route,
        ];
        let kinds: Vec<_> = ours.iter().map(|f| f(3)).collect();
        let kinds: Vec<_> = kinds.iter().filter_map(|k| radio_kind(k)).collect();
        assert_eq!(kinds, RADIO_KINDS);
        for kind in RADIO_KINDS {
            assert_eq!(radio_kind(&radio_key(5, kind)), Some(*kind));
        }
        assert_eq!(radio_kind("radio/alive"), None);
        assert_eq!(radio_kind("radio/alive/3"), None);
        assert_eq!(radio_kind("sim/robot/3/cmd"), None);
    }

    #[test]
    fn robot_of_parses_our_keys() {
        assert_eq!(robot_of(&sim_alive(3)), Some(3));
        assert_eq!(robot_of(&radio_alive(12)), Some(12));
        assert_eq!(robot_of(&telemetry(7)), Some(7));
        assert_eq!(robot_of(&cmd(5)), Some(5));
        assert_eq!(robot_of(&held(9)), Some(9));
        assert_eq!(robot_of("sim/alive/x"), None);
        assert_eq!(robot_of("sim"), None);
    }
}
