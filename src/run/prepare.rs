//! Before any process starts: the resolved scenario, the run directory with `scenario.toml` in
//! it, where each process runs (`--hosts`), and a free port for every endpoint of the run.

use std::collections::{BTreeMap, VecDeque};
use std::net::{IpAddr, Ipv4Addr, SocketAddr};
use std::path::PathBuf;
use std::time::Duration;

use anyhow::Context;
use proto::msg::RobotId;
use proto::scenario::{Process, Scenario};
use world_server::scenario::resolve;

use super::args::RunArgs;
use crate::process::hosts::{Host, Hosts, Placement};
use crate::process::ports::{endpoint, free_ports};
use crate::process::remote;

/// Everything decided before the first process starts.
pub struct Plan {
    pub scenario: Scenario,
    /// The map's name (its file stem), for messages and the default run directory.
    pub name: String,
    pub dir: PathBuf,
    /// `scenario.toml` in the run directory: what every process reads.
    pub scenario_file: PathBuf,
    pub ports: Ports,
    /// Where each process runs (`--hosts`); `None`: every process here, on loopback.
    pub placement: Option<Placement>,
}

impl Plan {
    pub fn robots(&self) -> RobotId {
        self.scenario.robots.count
    }

    /// The host of `process`, if the run is spread over hosts.
    pub fn host(&self, process: Process) -> Option<&Host> {
        self.placement.as_ref().and_then(|p| p.host(process))
    }

    /// Whether netem's API wants the run's bearer token: when the scenario says so, and always
    /// when the API listens beyond loopback.
    pub fn api_token(&self) -> bool {
        self.scenario.netem.api_token || !self.ports.http.ip().is_loopback()
    }

    /// A file under the run directory's `logs/`.
    pub fn log(&self, name: &str) -> PathBuf {
        self.dir.join("logs").join(format!("{name}.log"))
    }
}

/// The addresses of a run: the sim plane's router, netem's HTTP API, every radio node's
/// listener (robots, then the base station), and netem's proxy of every pair of nodes — each on
/// its process's host (loopback without a hosts file), on a port free there.
pub struct Ports {
    pub sim: SocketAddr,
    pub http: SocketAddr,
    pub radio: Vec<SocketAddr>,
    /// Every pair {a, b}, a < b, in order, with the address of its proxy.
    pub pairs: Vec<(RobotId, RobotId, SocketAddr)>,
}

impl Ports {
    /// Picks every port: on loopback here, or — with a placement — on each host's address, as
    /// that host answers (`swarm host-info`, which also checks its protocol version).
    fn pick(s: &Scenario, placement: Option<&Placement>) -> anyhow::Result<Ports> {
        let n = s.nodes();
        let node = |i: RobotId| {
            if Some(i) == s.base_id() {
                Process::BaseStation
            } else {
                Process::Robot(i)
            }
        };
        let pairs: Vec<(RobotId, RobotId)> = (0..n)
            .flat_map(|i| ((i + 1)..n).map(move |j| (i, j)))
            .collect();
        // Every address the run needs, by the process that binds it, in a fixed order.
        let mut wants = vec![Process::WorldServer, Process::Netem];
        wants.extend((0..n).map(node));
        wants.extend(pairs.iter().map(|_| Process::Netem));
        let mut pools: BTreeMap<String, (IpAddr, VecDeque<u16>)> = BTreeMap::new();
        match placement {
            None => {
                let ports = free_ports(wants.len())?;
                pools.insert(
                    String::new(),
                    (IpAddr::V4(Ipv4Addr::LOCALHOST), ports.into()),
                );
            }
            Some(p) => {
                let exe = std::env::current_exe().context("locating the swarm binary")?;
                for (name, procs) in p.by_host() {
                    let Some(host) = procs.first().and_then(|&q| p.host(q)) else {
                        continue;
                    };
                    let k = wants.iter().filter(|w| procs.contains(w)).count();
                    let info = remote::ask(host, &exe, k, HOST_INFO_WAIT)?;
                    pools.insert(name.to_string(), (host.address, info.ports.into()));
                }
            }
        }
        let mut next = |process: Process| -> anyhow::Result<SocketAddr> {
            let key = placement
                .and_then(|p| p.host(process))
                .map_or_else(String::new, |h| h.name.clone());
            let (ip, pool) = pools
                .get_mut(&key)
                .with_context(|| format!("no host for {process}"))?;
            let port = pool
                .pop_front()
                .with_context(|| format!("no port left for {process}"))?;
            Ok(SocketAddr::new(*ip, port))
        };
        let sim = next(Process::WorldServer)?;
        let http = next(Process::Netem)?;
        let radio = (0..n)
            .map(|i| next(node(i)))
            .collect::<anyhow::Result<_>>()?;
        let pairs = pairs
            .iter()
            .map(|&(a, b)| Ok((a, b, next(Process::Netem)?)))
            .collect::<anyhow::Result<_>>()?;
        Ok(Ports {
            sim,
            http,
            radio,
            pairs,
        })
    }

    /// The sim plane's endpoint (the world-server's router).
    pub fn sim_endpoint(&self) -> String {
        endpoint(self.sim)
    }

    /// netem's HTTP API address.
    pub fn http_addr(&self) -> String {
        self.http.to_string()
    }
}

/// How long a host may take to answer `swarm host-info` (an ssh login included).
const HOST_INFO_WAIT: Duration = Duration::from_secs(30);

/// Resolves the scenario, creates the run directory with its `scenario.toml`, picks the ports.
pub fn prepare(args: &RunArgs) -> anyhow::Result<Plan> {
    let resolved = resolve(args.scenario.as_deref(), &args.set)?;
    let name = resolved.name();
    let scenario = resolved.scenario;
    let dir = run_dir(args, &name, scenario.robots.count)?;
    let scenario_file = dir.join("scenario.toml");
    std::fs::write(&scenario_file, scenario.to_toml()).context("writing scenario.toml")?;
    let placement = match &args.hosts {
        Some(file) => Some(Hosts::load(file)?.place(&scenario)?),
        None => None,
    };
    let ports = Ports::pick(&scenario, placement.as_ref())?;
    Ok(Plan {
        scenario,
        name,
        dir,
        scenario_file,
        ports,
        placement,
    })
}

fn run_dir(args: &RunArgs, name: &str, robots: u16) -> anyhow::Result<PathBuf> {
    let dir = match &args.out {
        Some(d) => d.clone(),
        None => {
            let secs = std::time::SystemTime::now()
                .duration_since(std::time::UNIX_EPOCH)
                .map_or(0, |d| d.as_secs());
            PathBuf::from("runs").join(format!("{secs}-{name}-{robots}r"))
        }
    };
    std::fs::create_dir_all(dir.join("logs"))
        .with_context(|| format!("creating run directory {}", dir.display()))?;
    Ok(dir)
}
