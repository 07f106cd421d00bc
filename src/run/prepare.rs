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
use crate::process::{remote, slurm};

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

/// The addresses of a run: the sim plane's router, netem's HTTP API and every radio node's
/// listener (robots, then the base station) — each on its process's host (loopback without a
/// hosts file), on a port free there — and the address netem's proxies listen on (netem picks a
/// pair's port when its link comes up).
pub struct Ports {
    pub sim: SocketAddr,
    pub http: SocketAddr,
    pub radio: Vec<SocketAddr>,
    /// The address netem's proxies listen on (each pair's on a free port while its link is up).
    pub proxy_host: IpAddr,
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
        // Every address the run needs, by the process that binds it, in a fixed order.
        let mut wants = vec![Process::WorldServer, Process::Netem];
        wants.extend((0..n).map(node));
        let mut pools: BTreeMap<IpAddr, VecDeque<u16>> = match placement {
            None => {
                let local = IpAddr::V4(Ipv4Addr::LOCALHOST);
                BTreeMap::from([(local, free_ports(wants.len())?.into())])
            }
            Some(p) => ask_hosts(p, &wants)?,
        };
        let mut next = |process: Process| -> anyhow::Result<SocketAddr> {
            let ip = placement
                .and_then(|p| p.host(process))
                .map_or(IpAddr::V4(Ipv4Addr::LOCALHOST), |h| h.address);
            let port = (pools.get_mut(&ip))
                .and_then(VecDeque::pop_front)
                .with_context(|| format!("no port left for {process} on {ip}"))?;
            Ok(SocketAddr::new(ip, port))
        };
        let sim = next(Process::WorldServer)?;
        let http = next(Process::Netem)?;
        let radio = (0..n)
            .map(|i| next(node(i)))
            .collect::<anyhow::Result<_>>()?;
        Ok(Ports {
            sim,
            proxy_host: http.ip(),
            http,
            radio,
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

/// Asks every host for the free ports its processes bind (`swarm host-info`, which also checks
/// its protocol version): hosts that share an address (one machine under several names, as
/// Slurm nodes on one host may be) share one pool, asked of the first of them, so that no two
/// processes get one port.
fn ask_hosts(p: &Placement, wants: &[Process]) -> anyhow::Result<BTreeMap<IpAddr, VecDeque<u16>>> {
    let exe = std::env::current_exe().context("locating the swarm binary")?;
    let mut by_address: BTreeMap<IpAddr, Vec<(&Host, usize)>> = BTreeMap::new();
    for procs in p.by_host().into_values() {
        let Some(host) = procs.first().and_then(|&q| p.host(q)) else {
            continue;
        };
        let k = wants.iter().filter(|w| procs.contains(w)).count();
        by_address.entry(host.address).or_default().push((host, k));
    }
    let mut pools = BTreeMap::new();
    for (ip, hosts) in by_address {
        let total = hosts.iter().map(|&(_, k)| k).sum();
        for (i, &(host, _)) in hosts.iter().enumerate() {
            let info = remote::ask(host, &exe, if i == 0 { total } else { 0 }, HOST_INFO_WAIT)?;
            if i == 0 {
                pools.insert(ip, info.ports.into());
            }
        }
    }
    Ok(pools)
}

/// How long a host may take to answer `swarm host-info` (an ssh login included).
const HOST_INFO_WAIT: Duration = Duration::from_secs(30);

/// Resolves the scenario, creates the run directory with its `scenario.toml`, picks the ports.
pub fn prepare(args: &RunArgs) -> anyhow::Result<Plan> {
    let resolved = resolve(args.scenario.as_deref(), &args.set)?;
    let name = resolved.name();
    let scenario = resolved.scenario;
    // Where everything goes is checked before the run directory is made.
    let placement = match &args.hosts {
        Some(word) if slurm::is_allocation(word) => Some(slurm::allocation()?.place(&scenario)?),
        Some(file) => Some(Hosts::load(file)?.place(&scenario)?),
        None => None,
    };
    let dir = run_dir(args, &name, scenario.robots.count)?;
    let scenario_file = dir.join("scenario.toml");
    std::fs::write(&scenario_file, scenario.to_toml()).context("writing scenario.toml")?;
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
