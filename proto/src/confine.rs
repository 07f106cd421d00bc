//! Confinement of the sim plane: every process joins the world-server's router under its own
//! name and password, and the router lets it publish, subscribe, declare and ask only on its own
//! keys (robot `i`: its command, telemetry, scan, liveliness token and the answer to what it
//! holds; netem: the link plan and reports, and the process faults its API is asked for; the
//! launcher: control, and asking any robot what it holds; an observer: read-only). Everything
//! else is denied.
//!
//! This module is the table of who may do what ([`grants`]) and its rendering as zenoh's
//! `access_control` configuration ([`access_control`]); `node` applies it (the router reads the
//! run's user dictionary, each client logs in with its [`Credentials`]). zenoh checks a message
//! on the router at two places: *ingress* (from the client into the router: what the client
//! publishes, declares, asks) and *egress* (from the router to the client: what it receives). A
//! declaration with a wildcard is allowed only if a granted key includes it: robot 1 cannot
//! subscribe `sim/robot/*/scan` any more than `sim/robot/3/scan`.

use crate::ids::RobotId;
use crate::keys;

/// A process of a run, as the sim plane's router knows it (its user name).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Principal {
    /// Robot `id`.
    Robot(RobotId),
    /// The base station, node `id` of the radio (it is a robot that does not move).
    BaseStation(RobotId),
    Netem,
    /// `swarm run` itself: follows the run, stops it.
    Launcher,
    /// Read-only: may subscribe and ask everything on the sim plane, publish nothing (for tools
    /// that watch a run).
    Observer,
}

impl std::fmt::Display for Principal {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Principal::Robot(i) => write!(f, "robot-{i}"),
            Principal::BaseStation(_) => f.write_str("base-station"),
            Principal::Netem => f.write_str("netem"),
            Principal::Launcher => f.write_str("launcher"),
            Principal::Observer => f.write_str("observer"),
        }
    }
}

impl Principal {
    /// Every principal of a run with `robots` robots and (maybe) a base station.
    pub fn of_run(robots: u16, base: Option<RobotId>) -> Vec<Principal> {
        let mut all: Vec<Principal> = (0..robots).map(Principal::Robot).collect();
        all.extend(base.map(Principal::BaseStation));
        all.extend([Principal::Netem, Principal::Launcher, Principal::Observer]);
        all
    }
}

/// Which way a message goes through the router.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Flow {
    /// From the client into the router: what it publishes, declares and asks.
    Ingress,
    /// From the router to the client: what it is sent.
    Egress,
}

/// One permission: these kinds of message, this way, on these keys.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Grant {
    pub flow: Flow,
    /// zenoh's names of the message kinds (`put`, `declare_subscriber`, `query`, `reply`,
    /// `liveliness_token`, `declare_liveliness_subscriber`, `liveliness_query`, ...).
    pub messages: &'static [&'static str],
    pub keys: Vec<String>,
}

const PUT: &[&str] = &["put"];
const SUBSCRIBE: &[&str] = &["declare_subscriber"];
const QUERY: &[&str] = &["query"];
const REPLY: &[&str] = &["reply"];
const TOKEN: &[&str] = &["liveliness_token"];
const WATCH: &[&str] = &["declare_liveliness_subscriber", "liveliness_query"];
const ANSWER: &[&str] = &["declare_queryable"];
/// Declarations the router passes on so that a client knows somebody listens (they carry no
/// data: a publisher learns that its key has a subscriber).
const INTEREST: &[&str] = &["declare_subscriber", "declare_queryable"];

fn grant(flow: Flow, messages: &'static [&'static str], keys: &[&str]) -> Grant {
    Grant {
        flow,
        messages,
        keys: keys.iter().map(|k| k.to_string()).collect(),
    }
}

/// What `p` may do on the sim plane; anything not granted is denied.
pub fn grants(p: Principal) -> Vec<Grant> {
    use Flow::{Egress, Ingress};
    let mut g = vec![grant(Egress, INTEREST, &["sim/**"])];
    match p {
        Principal::Robot(i) | Principal::BaseStation(i) => g.extend(robot_grants(i)),
        Principal::Netem => g.extend([
            grant(
                Ingress,
                PUT,
                &[keys::PLAN_ALL, keys::NETEM_LINKS, keys::PROCESS_ORDERS],
            ),
            grant(Ingress, SUBSCRIBE, &[keys::STATUS, keys::CONTROL]),
            grant(Ingress, TOKEN, &[keys::NETEM_ALIVE]),
            grant(Ingress, WATCH, &[keys::WORLD_ALIVE]),
            grant(Ingress, QUERY, &[keys::WORLD_TRUTH]),
            grant(Egress, PUT, &[keys::STATUS, keys::CONTROL]),
            grant(Egress, TOKEN, &[keys::WORLD_ALIVE]),
            grant(Egress, REPLY, &[keys::WORLD_TRUTH]),
        ]),
        Principal::Launcher => g.extend([
            grant(Ingress, PUT, &[keys::CONTROL]),
            grant(
                Ingress,
                SUBSCRIBE,
                &[
                    keys::STATUS,
                    keys::TELEMETRY_ALL,
                    keys::NETEM_LINKS,
                    keys::PROCESS_ORDERS,
                ],
            ),
            grant(
                Ingress,
                QUERY,
                &[keys::WORLD_TRUTH, keys::WORLD_INFO, keys::HELD_ALL],
            ),
            grant(
                Egress,
                PUT,
                &[
                    keys::STATUS,
                    keys::TELEMETRY_ALL,
                    keys::NETEM_LINKS,
                    keys::PROCESS_ORDERS,
                ],
            ),
            grant(
                Egress,
                REPLY,
                &[keys::WORLD_TRUTH, keys::WORLD_INFO, keys::HELD_ALL],
            ),
        ]),
        Principal::Observer => g.extend([
            grant(Ingress, SUBSCRIBE, &["sim/**"]),
            grant(Ingress, QUERY, &["sim/**"]),
            grant(Ingress, WATCH, &["sim/**"]),
            grant(Egress, PUT, &["sim/**"]),
            grant(Egress, REPLY, &["sim/**"]),
            grant(Egress, TOKEN, &["sim/**"]),
        ]),
    }
    g
}

/// What robot (or base station) `i` may do on the sim plane beyond asking who is interested:
/// its own command, telemetry, scans, link plan, liveliness and held logs.
fn robot_grants(i: RobotId) -> [Grant; 11] {
    use Flow::{Egress, Ingress};
    let (cmd, telemetry, scan, plan, alive, held) = (
        keys::cmd(i),
        keys::telemetry(i),
        keys::scan(i),
        keys::plan(i),
        keys::sim_alive(i),
        keys::held(i),
    );
    [
        grant(Ingress, PUT, &[&cmd, &telemetry]),
        grant(Ingress, SUBSCRIBE, &[&scan, &plan, keys::CONTROL]),
        grant(Ingress, TOKEN, &[&alive]),
        grant(Ingress, WATCH, &[keys::WORLD_ALIVE, keys::NETEM_ALIVE]),
        grant(Ingress, QUERY, &[keys::WORLD_INFO]),
        // What it holds, for a viewer that asks.
        grant(Ingress, ANSWER, &[&held]),
        grant(Ingress, REPLY, &[&held]),
        grant(Egress, QUERY, &[&held]),
        grant(Egress, PUT, &[&scan, &plan, keys::CONTROL]),
        grant(Egress, TOKEN, &[keys::WORLD_ALIVE, keys::NETEM_ALIVE]),
        grant(Egress, REPLY, &[keys::WORLD_INFO]),
    ]
}

/// zenoh's `access_control` configuration (JSON5) for the principals of a run: default deny,
/// one subject per principal (by user name), its [`grants`] as allow rules.
pub fn access_control(principals: &[Principal]) -> String {
    let mut rules = Vec::new();
    let mut subjects = Vec::new();
    let mut policies = Vec::new();
    for p in principals {
        let mut ids = Vec::new();
        for (k, g) in grants(*p).iter().enumerate() {
            let id = format!("{p}-{k}");
            let quoted = |v: &[String]| {
                v.iter()
                    .map(|s| format!("{s:?}"))
                    .collect::<Vec<_>>()
                    .join(",")
            };
            let messages: Vec<String> = g.messages.iter().map(|m| m.to_string()).collect();
            let flow = match g.flow {
                Flow::Ingress => "ingress",
                Flow::Egress => "egress",
            };
            rules.push(format!(
                "{{id:{id:?},messages:[{}],flows:[{flow:?}],permission:\"allow\",key_exprs:[{}]}}",
                quoted(&messages),
                quoted(&g.keys)
            ));
            ids.push(format!("{id:?}"));
        }
        subjects.push(format!("{{id:\"{p}\",usernames:[\"{p}\"]}}"));
        policies.push(format!("{{rules:[{}],subjects:[\"{p}\"]}}", ids.join(",")));
    }
    format!(
        "{{enabled:true,default_permission:\"deny\",rules:[{}],subjects:[{}],policies:[{}]}}",
        rules.join(","),
        subjects.join(","),
        policies.join(",")
    )
}

/// A process's login on the sim plane: user name and password, kept in a file of one
/// `user:password` line (zenoh's dictionary format, one line of it).
#[derive(Clone, PartialEq, Eq)]
pub struct Credentials {
    pub user: String,
    pub password: String,
}

impl std::fmt::Debug for Credentials {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "Credentials {{ user: {:?}, password: <hidden> }}",
            self.user
        )
    }
}

impl Credentials {
    /// The file's line.
    pub fn line(&self) -> String {
        format!("{}:{}", self.user, self.password)
    }

    /// Parses a credentials file: one non-empty `user:password` line (surrounding blanks and
    /// blank lines ignored); neither part may be empty or contain blanks.
    pub fn parse(text: &str) -> Result<Credentials, String> {
        let mut lines = text.lines().map(str::trim).filter(|l| !l.is_empty());
        let line = lines
            .next()
            .ok_or("empty: expected one user:password line")?;
        if lines.next().is_some() {
            return Err("expected one user:password line, found more".into());
        }
        let (user, password) = line
            .split_once(':')
            .ok_or("expected user:password (no ':' found)")?;
        let ok = |s: &str| !s.is_empty() && !s.chars().any(char::is_whitespace);
        if !ok(user) || !ok(password) {
            return Err("user and password must be non-empty, without blanks".into());
        }
        Ok(Credentials {
            user: user.into(),
            password: password.into(),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn keys_of(p: Principal, flow: Flow, message: &str) -> Vec<String> {
        grants(p)
            .into_iter()
            .filter(|g| g.flow == flow && g.messages.contains(&message))
            .flat_map(|g| g.keys)
            .collect()
    }

    #[test]
    fn a_robot_may_publish_and_subscribe_only_its_own_keys() {
        let team = Principal::of_run(5, Some(5));
        for p in &team {
            let Principal::Robot(i) = *p else { continue };
            let puts = keys_of(*p, Flow::Ingress, "put");
            assert_eq!(puts, vec![keys::cmd(i), keys::telemetry(i)]);
            let subs = keys_of(*p, Flow::Ingress, "declare_subscriber");
            let received = keys_of(*p, Flow::Egress, "put");
            for j in (0..6).filter(|&j| j != i) {
                for k in [
                    keys::cmd(j),
                    keys::telemetry(j),
                    keys::scan(j),
                    keys::sim_alive(j),
                ] {
                    assert!(!puts.contains(&k) && !subs.contains(&k) && !received.contains(&k));
                }
            }
            assert!(subs.contains(&keys::scan(i)) && received.contains(&keys::scan(i)));
            // It answers for itself only.
            let answers = keys_of(*p, Flow::Ingress, "declare_queryable");
            assert_eq!(answers, vec![keys::held(i)]);
            assert_eq!(keys_of(*p, Flow::Ingress, "reply"), vec![keys::held(i)]);
            assert!(!subs.iter().any(|k| k.contains('*')));
        }
    }

    #[test]
    fn only_the_launcher_stops_a_run_and_the_observer_publishes_nothing() {
        for p in Principal::of_run(3, Some(3)) {
            let puts = keys_of(p, Flow::Ingress, "put");
            assert_eq!(
                puts.contains(&keys::CONTROL.to_string()),
                p == Principal::Launcher,
                "{p}"
            );
        }
        assert!(keys_of(Principal::Observer, Flow::Ingress, "put").is_empty());
        assert!(keys_of(Principal::Observer, Flow::Ingress, "liveliness_token").is_empty());
    }

    #[test]
    fn the_configuration_names_every_principal_once() {
        let team = Principal::of_run(3, None);
        let acl = access_control(&team);
        assert!(acl.starts_with("{enabled:true,default_permission:\"deny\""));
        for p in &team {
            assert_eq!(acl.matches(&format!("usernames:[\"{p}\"]")).count(), 1);
        }
        assert!(!acl.contains("base-station"));
    }

    #[test]
    fn credentials_files_parse_or_say_why_not() {
        let c = Credentials::parse("\n robot-3:0a1b2c \n\n").expect("parses");
        assert_eq!(
            (c.user.as_str(), c.password.as_str()),
            ("robot-3", "0a1b2c")
        );
        assert_eq!(Credentials::parse(&c.line()), Ok(c.clone()));
        assert!(!format!("{c:?}").contains("0a1b2c"));
        for bad in ["", "robot-3", ":pw", "robot-3:", "a b:pw", "a:pw\nb:pw"] {
            assert!(Credentials::parse(bad).is_err(), "{bad:?}");
        }
    }
}
