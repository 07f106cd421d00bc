//! Before any process starts: the resolved scenario, the run directory with `scenario.toml` in
//! it, and a free port for every endpoint of the run.

use std::path::PathBuf;

use anyhow::Context;
use proto::msg::RobotId;
use proto::scenario::Scenario;
use world_server::scenario::resolve;

use super::RunArgs;
use crate::ports::{endpoint, free_ports};

/// Everything decided before the first process starts.
pub struct Plan {
    pub scenario: Scenario,
    /// The map's name (its file stem), for messages and the default run directory.
    pub name: String,
    pub dir: PathBuf,
    /// `scenario.toml` in the run directory: what every process reads.
    pub scenario_file: PathBuf,
    pub ports: Ports,
}

impl Plan {
    pub fn robots(&self) -> RobotId {
        self.scenario.robots.count
    }

    /// A file under the run directory's `logs/`.
    pub fn log(&self, name: &str) -> PathBuf {
        self.dir.join("logs").join(format!("{name}.log"))
    }
}

/// The loopback ports of a run: the sim plane's router, netem's HTTP API, every radio node's
/// listener (robots, then the base station), and netem's proxy of every pair of nodes.
pub struct Ports {
    pub sim: u16,
    pub http: u16,
    pub radio: Vec<u16>,
    /// Every pair {a, b}, a < b, in order, with the port of its proxy.
    pub pairs: Vec<(RobotId, RobotId, u16)>,
}

impl Ports {
    fn pick(n: RobotId) -> anyhow::Result<Ports> {
        let pairs: Vec<(RobotId, RobotId)> = (0..n)
            .flat_map(|i| ((i + 1)..n).map(move |j| (i, j)))
            .collect();
        let ports = free_ports(2 + usize::from(n) + pairs.len())?;
        let (radio, proxies) = ports[2..].split_at(usize::from(n));
        Ok(Ports {
            sim: ports[0],
            http: ports[1],
            radio: radio.to_vec(),
            pairs: pairs
                .iter()
                .zip(proxies)
                .map(|(&(a, b), &p)| (a, b, p))
                .collect(),
        })
    }

    /// The sim plane's endpoint (the world-server's router).
    pub fn sim_endpoint(&self) -> String {
        endpoint(self.sim)
    }

    /// netem's HTTP API address.
    pub fn http_addr(&self) -> String {
        format!("127.0.0.1:{}", self.http)
    }
}

/// Resolves the scenario, creates the run directory with its `scenario.toml`, picks the ports.
pub fn prepare(args: &RunArgs) -> anyhow::Result<Plan> {
    let resolved = resolve(args.scenario.as_deref(), &args.set)?;
    let name = resolved.name();
    let scenario = resolved.scenario;
    let dir = run_dir(args, &name, scenario.robots.count)?;
    let scenario_file = dir.join("scenario.toml");
    std::fs::write(&scenario_file, scenario.to_toml()).context("writing scenario.toml")?;
    let ports = Ports::pick(scenario.nodes())?;
    Ok(Plan {
        scenario,
        name,
        dir,
        scenario_file,
        ports,
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
