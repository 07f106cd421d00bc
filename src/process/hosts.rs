//! Where the processes of a run go: the hosts file of `swarm run --hosts FILE`.
//!
//! The scenario says what runs; the hosts file says where. Each host has a name, the address its
//! processes bind and are reached at, and how a process is started there:
//!
//! ```toml
//! [hosts.lab0]
//! address = "192.168.1.10"
//! # nothing else: started here, by the launcher itself
//!
//! [hosts.lab1]
//! address = "192.168.1.11"
//! ssh = "robot@192.168.1.11"          # ssh, as roslaunch's <machine> tags do
//! ssh_options = ["-p", "2222"]         # more flags for ssh (a key, a port, ...)
//! swarm = "/home/robot/bin/swarm"      # the swarm binary there (default: `swarm` on its PATH)
//! dir = "/tmp/swarm-runs"              # where the run's files go there (this is the default)
//!
//! [hosts.lab2]
//! address = "10.0.0.2"
//! command = ["ip", "netns", "exec", "lab2"]   # or a plain command prefix, run here
//!
//! [placement]
//! world-server = "lab0"                # default: the first host (by name)
//! netem = "lab0"                       # default: the world-server's host
//! base-station = "lab0"                # default: the world-server's host
//! robots = { lab1 = [0, 1], lab2 = "rest" }   # default: round-robin over every host
//! ```
//!
//! Over ssh only robots and the base station are started: the world-server and netem run on
//! the launcher's host or a command-prefix host (the world-server reads the map file, netem
//! writes `link_totals.csv`, and neither is carried over ssh).
//!
//! This module reads the file and decides the placement; it starts nothing.
//!
//! **Invariant:** every process of the run is placed on exactly one host of the file, and a
//! placement that names a host the file lacks, or a robot twice, or leaves a robot out, or the
//! world-server or netem on an ssh host, is refused before anything starts.

use std::collections::BTreeMap;
use std::net::IpAddr;
use std::path::{Path, PathBuf};

use proto::msg::RobotId;
use proto::scenario::{Process, Scenario};
use serde::Deserialize;

/// Where an ssh host keeps the run's files when its table does not say.
pub const DEFAULT_REMOTE_DIR: &str = "/tmp/swarm-runs";

#[derive(Debug, thiserror::Error)]
pub enum HostsError {
    #[error("reading {path}: {source}")]
    Read {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("{path}: {message}")]
    Invalid { path: PathBuf, message: String },
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct FileHosts {
    hosts: BTreeMap<String, FileHost>,
    #[serde(default)]
    placement: FilePlacement,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct FileHost {
    address: IpAddr,
    ssh: Option<String>,
    #[serde(default)]
    ssh_options: Vec<String>,
    command: Option<Vec<String>>,
    swarm: Option<String>,
    dir: Option<PathBuf>,
}

#[derive(Debug, Default, Deserialize)]
#[serde(deny_unknown_fields, rename_all = "kebab-case")]
struct FilePlacement {
    world_server: Option<String>,
    netem: Option<String>,
    base_station: Option<String>,
    robots: Option<BTreeMap<String, RobotsOn>>,
}

/// A host's robots: a list of ids, or `"rest"` (every robot no other host names).
#[derive(Debug, Deserialize)]
#[serde(untagged)]
enum RobotsOn {
    Ids(Vec<RobotId>),
    Rest(String),
}

/// How a process is started on a host.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Start {
    /// By the launcher itself, on its own machine.
    Local,
    /// `ssh [options] target -- <swarm> …`; the run's files are copied to the host first.
    Ssh {
        target: String,
        options: Vec<String>,
        /// The swarm binary on that host.
        swarm: String,
    },
    /// `command… <swarm> …`, run on the launcher's machine (e.g. `ip netns exec h1`): same
    /// file system, other network. `swarm`: the binary (default: the launcher's own).
    Prefix {
        command: Vec<String>,
        swarm: Option<String>,
    },
    /// `srun … --nodelist=<node> <swarm> on-host -- …`: a step of the Slurm allocation the
    /// launcher runs in (`swarm run --hosts slurm`, [`crate::process::slurm`]). The node sees
    /// the launcher's files (a shared file system) and runs the launcher's own binary path.
    Srun { node: String },
}

/// One host of the file.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Host {
    pub name: String,
    /// What its processes bind, and are reached at.
    pub address: IpAddr,
    pub start: Start,
    /// Where the run's files go on it (ssh hosts; the others share the launcher's).
    pub dir: PathBuf,
}

/// A hosts file, read and checked.
#[derive(Debug)]
pub struct Hosts {
    path: PathBuf,
    hosts: BTreeMap<String, Host>,
    placement: FilePlacement,
}

/// Every process of a run on its host.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Placement {
    on: BTreeMap<Process, String>,
    hosts: BTreeMap<String, Host>,
}

impl Placement {
    /// The host of `p` (every process of the run has one).
    pub fn host(&self, p: Process) -> Option<&Host> {
        self.on.get(&p).and_then(|h| self.hosts.get(h))
    }

    /// The processes on each host, by host name.
    pub fn by_host(&self) -> BTreeMap<&str, Vec<Process>> {
        let mut out: BTreeMap<&str, Vec<Process>> = BTreeMap::new();
        for (p, h) in &self.on {
            out.entry(h.as_str()).or_default().push(*p);
        }
        out
    }

    /// The hosts that have a process of the run.
    pub fn used(&self) -> impl Iterator<Item = &Host> {
        self.hosts
            .values()
            .filter(|h| self.on.values().any(|n| *n == h.name))
    }
}

impl Hosts {
    pub fn load(path: &Path) -> Result<Hosts, HostsError> {
        let text = std::fs::read_to_string(path).map_err(|source| HostsError::Read {
            path: path.to_path_buf(),
            source,
        })?;
        Hosts::parse(&text, path)
    }

    /// Reads `text` (the hosts file at `path`, named in errors).
    pub fn parse(text: &str, path: &Path) -> Result<Hosts, HostsError> {
        let bad = |message: String| HostsError::Invalid {
            path: path.to_path_buf(),
            message,
        };
        let file: FileHosts = toml::from_str(text).map_err(|e| {
            let msg = e.message().to_string();
            bad(match e.span() {
                Some(s) => {
                    let line = text[..s.start.min(text.len())].lines().count().max(1);
                    format!("line {line}: {msg}")
                }
                None => msg,
            })
        })?;
        if file.hosts.is_empty() {
            return Err(bad("no hosts: add a [hosts.<name>] table".into()));
        }
        let mut hosts = BTreeMap::new();
        for (name, h) in file.hosts {
            if h.ssh.is_none() && !h.ssh_options.is_empty() {
                return Err(bad(format!("hosts.{name}.ssh_options without ssh")));
            }
            let start = match (h.ssh, h.command) {
                (Some(_), Some(_)) => {
                    return Err(bad(format!(
                        "hosts.{name}: give ssh or command, not both"
                    )))
                }
                (Some(target), None) if target.trim().is_empty() => {
                    return Err(bad(format!("hosts.{name}.ssh is empty")))
                }
                (Some(target), None) => Start::Ssh {
                    target,
                    options: h.ssh_options,
                    swarm: h.swarm.unwrap_or_else(|| "swarm".into()),
                },
                (None, Some(command)) if command.is_empty() => {
                    return Err(bad(format!("hosts.{name}.command is empty")))
                }
                (None, Some(command)) => Start::Prefix {
                    command,
                    swarm: h.swarm,
                },
                (None, None) if h.swarm.is_some() => {
                    return Err(bad(format!(
                        "hosts.{name}.swarm: a host without ssh or command runs the launcher's own binary"
                    )))
                }
                (None, None) => Start::Local,
            };
            let dir = h.dir.unwrap_or_else(|| PathBuf::from(DEFAULT_REMOTE_DIR));
            hosts.insert(
                name.clone(),
                Host {
                    name,
                    address: h.address,
                    start,
                    dir,
                },
            );
        }
        Ok(Hosts {
            path: path.to_path_buf(),
            hosts,
            placement: file.placement,
        })
    }

    /// Hosts made by the launcher rather than read from a file (a Slurm allocation): `origin`
    /// names them in errors; the world-server (and netem, and the base station) go on
    /// `sim_host`, the robots round-robin over every host.
    pub fn assemble(origin: &str, hosts: Vec<Host>, sim_host: &str) -> Hosts {
        Hosts {
            path: PathBuf::from(origin),
            hosts: hosts.into_iter().map(|h| (h.name.clone(), h)).collect(),
            placement: FilePlacement {
                world_server: Some(sim_host.to_string()),
                ..FilePlacement::default()
            },
        }
    }

    /// Places every process of `scenario` (see the module's example for the defaults).
    pub fn place(&self, scenario: &Scenario) -> Result<Placement, HostsError> {
        let first = self.hosts.keys().next().cloned().unwrap_or_default();
        let p = &self.placement;
        let world = match &p.world_server {
            Some(h) => self.known("world-server", h)?,
            None => first,
        };
        let netem = match &p.netem {
            Some(h) => self.known("netem", h)?,
            None => world.clone(),
        };
        let mut on = BTreeMap::new();
        on.insert(Process::WorldServer, world.clone());
        on.insert(Process::Netem, netem);
        if scenario.base_station.enabled {
            let base = match &p.base_station {
                Some(h) => self.known("base-station", h)?,
                None => world,
            };
            on.insert(Process::BaseStation, base);
        } else if p.base_station.is_some() {
            return Err(self.bad("placement.base-station: the scenario has no base station".into()));
        }
        let n = scenario.robots.count;
        match &p.robots {
            None => {
                let names: Vec<&String> = self.hosts.keys().collect();
                for i in 0..n {
                    let h = names[usize::from(i) % names.len()];
                    on.insert(Process::Robot(i), h.clone());
                }
            }
            Some(table) => self.place_robots(table, n, &mut on)?,
        }
        self.no_sim_over_ssh(&on)?;
        Ok(Placement {
            on,
            hosts: self.hosts.clone(),
        })
    }

    /// An error about this hosts file.
    fn bad(&self, message: String) -> HostsError {
        HostsError::Invalid {
            path: self.path.clone(),
            message,
        }
    }

    /// `name`, when it is one of the file's hosts (`key` names the placement entry).
    fn known(&self, key: &str, name: &str) -> Result<String, HostsError> {
        if self.hosts.contains_key(name) {
            Ok(name.to_string())
        } else {
            Err(self.bad(format!(
                "placement.{key} = {name:?}: no such host (hosts: {})",
                self.names()
            )))
        }
    }

    /// Robots `0..n` placed by `placement.robots` (lists of ids, at most one host taking the
    /// rest): every robot on exactly one host.
    fn place_robots(
        &self,
        table: &BTreeMap<String, RobotsOn>,
        n: RobotId,
        on: &mut BTreeMap<Process, String>,
    ) -> Result<(), HostsError> {
        let mut rest = None;
        for (h, robots) in table {
            let h = self.known(&format!("robots.{h}"), h)?;
            match robots {
                RobotsOn::Rest(word) if word == "rest" => {
                    if let Some(other) = rest.replace(h.clone()) {
                        return Err(self.bad(format!(
                            "placement.robots: \"rest\" on both {other} and {h}"
                        )));
                    }
                }
                RobotsOn::Rest(word) => {
                    return Err(self.bad(format!(
                        "placement.robots.{h} = {word:?}: a list of robot ids, or \"rest\""
                    )))
                }
                RobotsOn::Ids(ids) => self.place_ids(ids, &h, n, on)?,
            }
        }
        let left: Vec<RobotId> = (0..n)
            .filter(|&i| !on.contains_key(&Process::Robot(i)))
            .collect();
        match rest {
            Some(h) => {
                for i in left {
                    on.insert(Process::Robot(i), h.clone());
                }
                Ok(())
            }
            None if !left.is_empty() => Err(self.bad(format!(
                "placement.robots places no host for robots {left:?} (add them, or a host = \"rest\")"
            ))),
            None => Ok(()),
        }
    }

    /// Robots `ids` on host `h`: each one of the run's `0..n`, and on no other host.
    fn place_ids(
        &self,
        ids: &[RobotId],
        h: &str,
        n: RobotId,
        on: &mut BTreeMap<Process, String>,
    ) -> Result<(), HostsError> {
        for &i in ids {
            if i >= n {
                return Err(self.bad(format!(
                    "placement.robots.{h}: robot {i}, but the run has robots 0..{}",
                    n.saturating_sub(1)
                )));
            }
            if let Some(other) = on.insert(Process::Robot(i), h.to_string()) {
                return Err(self.bad(format!(
                    "placement.robots: robot {i} on both {other} and {h}"
                )));
            }
        }
        Ok(())
    }

    /// The world-server and netem run on the launcher's host or a command-prefix host: over ssh
    /// only robots and the base station are started.
    fn no_sim_over_ssh(&self, on: &BTreeMap<Process, String>) -> Result<(), HostsError> {
        for p in [Process::WorldServer, Process::Netem] {
            let h = &on[&p];
            if matches!(self.hosts[h].start, Start::Ssh { .. }) {
                return Err(self.bad(format!(
                    "placement: {p} on {h}, an ssh host: over ssh only robots and the base \
                     station are started (the world-server reads the map file and netem writes \
                     link_totals.csv on its host); place {p} on the launcher's host or a \
                     command-prefix host"
                )));
            }
        }
        Ok(())
    }

    fn names(&self) -> String {
        self.hosts.keys().cloned().collect::<Vec<_>>().join(", ")
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn scenario(robots: u16, base: bool) -> Scenario {
        let mut s = Scenario::default();
        s.robots.count = robots;
        s.base_station.enabled = base;
        s
    }

    fn hosts(text: &str) -> Result<Hosts, String> {
        Hosts::parse(text, Path::new("hosts.toml")).map_err(|e| e.to_string())
    }

    fn placed(text: &str, s: &Scenario) -> Result<Placement, String> {
        hosts(text)?.place(s).map_err(|e| e.to_string())
    }

    const LAB: &str = r#"
        [hosts.h0]
        address = "10.0.0.1"
        [hosts.h1]
        address = "10.0.0.2"
        ssh = "robot@10.0.0.2"
        ssh_options = ["-p", "2222"]
        swarm = "/opt/swarm"
        [hosts.h2]
        address = "10.0.0.3"
        command = ["ip", "netns", "exec", "h2"]
        [placement]
        world-server = "h0"
        netem = "h0"
        robots = { h1 = [0, 1], h2 = "rest" }
    "#;

    #[test]
    fn the_example_places_every_process() {
        let p = placed(LAB, &scenario(5, false)).unwrap_or_else(|e| panic!("{e}"));
        let host = |q| p.host(q).map(|h| h.name.as_str());
        assert_eq!(host(Process::WorldServer), Some("h0"));
        assert_eq!(host(Process::Netem), Some("h0"));
        assert_eq!(host(Process::Robot(0)), Some("h1"));
        assert_eq!(host(Process::Robot(1)), Some("h1"));
        for i in 2..5 {
            assert_eq!(host(Process::Robot(i)), Some("h2"));
        }
        assert_eq!(host(Process::BaseStation), None, "no base station");
        let h1 = p.host(Process::Robot(0)).cloned();
        assert_eq!(
            h1.map(|h| (h.address.to_string(), h.start, h.dir)),
            Some((
                "10.0.0.2".to_string(),
                Start::Ssh {
                    target: "robot@10.0.0.2".into(),
                    options: vec!["-p".into(), "2222".into()],
                    swarm: "/opt/swarm".into()
                },
                PathBuf::from(DEFAULT_REMOTE_DIR)
            ))
        );
        assert_eq!(
            p.host(Process::Robot(4)).map(|h| h.start.clone()),
            Some(Start::Prefix {
                command: vec!["ip".into(), "netns".into(), "exec".into(), "h2".into()],
                swarm: None
            })
        );
        assert_eq!(p.used().count(), 3);
        assert_eq!(
            p.by_host()["h1"],
            vec![Process::Robot(0), Process::Robot(1)]
        );
    }

    #[test]
    fn without_a_placement_robots_go_round_robin_and_the_rest_to_the_first_host() {
        let text = "[hosts.b]\naddress = \"10.0.0.2\"\n[hosts.a]\naddress = \"10.0.0.1\"\n";
        let p = placed(text, &scenario(5, true)).unwrap_or_else(|e| panic!("{e}"));
        let host = |q| p.host(q).map(|h| h.name.clone()).unwrap_or_default();
        assert_eq!(host(Process::WorldServer), "a");
        assert_eq!(host(Process::Netem), "a");
        assert_eq!(host(Process::BaseStation), "a");
        let robots: Vec<String> = (0..5).map(|i| host(Process::Robot(i))).collect();
        assert_eq!(robots, ["a", "b", "a", "b", "a"]);
        assert_eq!(
            p.host(Process::Robot(0)).map(|h| &h.start),
            Some(&Start::Local)
        );
    }

    #[test]
    fn bad_files_and_placements_are_refused_naming_what_is_wrong() {
        let one = "[hosts.h0]\naddress = \"10.0.0.1\"\n";
        for (text, needle) in [
            ("", "missing field `hosts`"),
            ("[hosts]\n", "no hosts"),
            ("[hosts.h0]\naddress = \"ten\"\n", "line 2"),
            (
                "[hosts.h0]\naddress = \"10.0.0.1\"\nport = 3\n",
                "unknown field `port`",
            ),
            (
                "[hosts.h0]\naddress = \"10.0.0.1\"\nssh = \"a@b\"\ncommand = [\"x\"]\n",
                "not both",
            ),
            (
                "[hosts.h0]\naddress = \"10.0.0.1\"\ncommand = []\n",
                "command is empty",
            ),
            (
                "[hosts.h0]\naddress = \"10.0.0.1\"\nssh_options = [\"-v\"]\n",
                "ssh_options without ssh",
            ),
            (
                "[hosts.h0]\naddress = \"10.0.0.1\"\nswarm = \"/x\"\n",
                "launcher's own",
            ),
        ] {
            let err = hosts(text)
                .err()
                .unwrap_or_else(|| panic!("accepted: {text}"));
            assert!(
                err.contains(needle) && err.starts_with("hosts.toml"),
                "{text}: {err}"
            );
        }
        for (placement, robots, needle) in [
            ("world-server = \"h9\"", 2, "no such host (hosts: h0)"),
            ("netem = \"h9\"", 2, "placement.netem"),
            ("base-station = \"h0\"", 2, "no base station"),
            ("robots = { h9 = [0] }", 2, "placement.robots.h9"),
            ("robots = { h0 = [0, 0] }", 2, "robot 0 on both"),
            ("robots = { h0 = [5] }", 2, "robots 0..1"),
            ("robots = { h0 = [0] }", 3, "robots [1, 2]"),
            ("robots = { h0 = \"all\" }", 2, "\"rest\""),
        ] {
            let text = format!("{one}[placement]\n{placement}\n");
            let err = placed(&text, &scenario(robots, false))
                .err()
                .unwrap_or_else(|| panic!("accepted: {placement}"));
            assert!(err.contains(needle), "{placement}: {err}");
        }
        let two = format!(
            "{one}[hosts.h1]\naddress = \"10.0.0.2\"\n[placement]\nrobots = {{ h0 = \"rest\", h1 = \"rest\" }}\n"
        );
        let err = placed(&two, &scenario(2, false)).err().unwrap_or_default();
        assert!(err.contains("\"rest\" on both h0 and h1"), "{err}");
        let ssh =
            "[hosts.a]\naddress = \"10.0.0.1\"\nssh = \"u@a\"\n[hosts.b]\naddress = \"10.0.0.2\"\n";
        for (placement, needle) in [
            ("", "world-server on a, an ssh host"),
            (
                "world-server = \"b\"\nnetem = \"a\"",
                "netem on a, an ssh host",
            ),
        ] {
            let text = format!("{ssh}[placement]\n{placement}\n");
            let err = placed(&text, &scenario(2, false)).err().unwrap_or_default();
            assert!(err.contains(needle), "{placement}: {err}");
        }
    }
}
