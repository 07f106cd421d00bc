//! The robot-agent's command line: flags → validated scenario → [`crate::node::run_robot`].

use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Duration;

use anyhow::Context;
use clap::Parser;
use proto::msg::RobotId;
use proto::node::{close_quickly, entry, radio_peer, zerr, ScenarioArgs, ZenohArgs};
use proto::scenario::Scenario;

use crate::node::{run_robot, world_info, End};
use crate::radio::dial::RadioPlane;

/// One robot of swarm-explore: maps what its laser sees, shares it with the robots in radio
/// range, and explores. Joins the world-server's sim plane as a client (--connect) and runs its
/// own radio-plane peer (--radio-listen / --radio-connect). Normally started by `swarm run`.
#[derive(Parser, Debug, Clone, PartialEq)]
#[command(name = "robot-agent", version)]
pub struct Args {
    /// This robot's id, 0..robots.count.
    #[arg(long)]
    pub id: RobotId,
    #[command(flatten)]
    pub node: NodeArgs,
}

/// The base station of a run (`[base_station] enabled = true`): a radio node that neither
/// moves nor senses, node id robots.count. It joins the radio plane through netem like a robot,
/// holds and relays every owner's map it hears of, and hosts the `bids` strategy's executive.
/// Normally started by `swarm run`.
#[derive(Parser, Debug, Clone, PartialEq)]
#[command(name = "base-station", version)]
pub struct BaseArgs {
    #[command(flatten)]
    pub node: NodeArgs,
}

/// The flags every radio node shares (robots and the base station).
#[derive(clap::Args, Debug, Clone, PartialEq)]
pub struct NodeArgs {
    #[command(flatten)]
    pub scenario: ScenarioArgs,
    /// Radio-plane endpoint this node listens on, e.g. tcp/127.0.0.1:7500 (repeatable).
    #[arg(long = "radio-listen", value_name = "ENDPOINT")]
    pub radio_listen: Vec<String>,
    /// Radio-plane endpoint to connect to (a peer, or netem's proxy for the pair); repeatable.
    #[arg(long = "radio-connect", value_name = "ENDPOINT")]
    pub radio_connect: Vec<String>,
    /// A zenoh JSON5 configuration file for the radio-plane session.
    #[arg(long = "radio-config", value_name = "FILE")]
    pub radio_config: Option<PathBuf>,
    /// Seconds without a scan (the base station: a tick) after which the node assumes the world
    /// is gone and exits.
    #[arg(long, default_value_t = IDLE_TIMEOUT_S, value_name = "SECONDS")]
    pub idle_timeout_s: f64,
    /// Which life of the node this process is: 0 for the one the run started, one more for
    /// each restart (the launcher's supervision and process faults). A node in a later life
    /// writes a new log and takes its earlier lives' logs back from its peers.
    #[arg(long, default_value_t = 0, value_name = "N")]
    pub life: u16,
    /// Sim-plane zenoh options (--connect the world-server's router).
    #[command(flatten)]
    pub zenoh: ZenohArgs,
}

/// Default of `--idle-timeout-s`.
pub const IDLE_TIMEOUT_S: f64 = 60.0;

impl NodeArgs {
    /// The node of `scenario` with every other flag at its default.
    pub fn new(scenario: PathBuf, zenoh: ZenohArgs) -> NodeArgs {
        NodeArgs {
            scenario: ScenarioArgs::file(scenario),
            radio_listen: Vec::new(),
            radio_connect: Vec::new(),
            radio_config: None,
            idle_timeout_s: IDLE_TIMEOUT_S,
            life: 0,
            zenoh,
        }
    }

    /// The flags that parse back into these arguments.
    pub fn to_argv(&self) -> Vec<String> {
        let mut a = self.scenario.to_argv();
        for e in &self.radio_listen {
            a.extend(["--radio-listen".into(), e.clone()]);
        }
        for e in &self.radio_connect {
            a.extend(["--radio-connect".into(), e.clone()]);
        }
        if let Some(f) = &self.radio_config {
            a.extend(["--radio-config".into(), f.to_string_lossy().into_owned()]);
        }
        a.extend(["--idle-timeout-s".into(), self.idle_timeout_s.to_string()]);
        if self.life > 0 {
            a.extend(["--life".into(), self.life.to_string()]);
        }
        a.extend(self.zenoh.to_argv());
        a
    }
}

impl Args {
    /// Robot `id` of `scenario` with every other flag at its default.
    pub fn new(id: RobotId, scenario: PathBuf, zenoh: ZenohArgs) -> Args {
        Args {
            id,
            node: NodeArgs::new(scenario, zenoh),
        }
    }

    /// The flags that parse back into these arguments (how `swarm run` starts the process).
    pub fn to_argv(&self) -> Vec<String> {
        let mut a = vec!["--id".into(), self.id.to_string()];
        a.extend(self.node.to_argv());
        a
    }
}

impl BaseArgs {
    /// The flags that parse back into these arguments (how `swarm run` starts the process).
    pub fn to_argv(&self) -> Vec<String> {
        self.node.to_argv()
    }
}

/// Which node a process is: robot `id`, or the scenario's base station.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Role {
    Robot(RobotId),
    Base,
}

async fn run(role: Role, args: NodeArgs) -> anyhow::Result<End> {
    let scenario = Scenario::load(&args.scenario.file, &args.scenario.set)?;
    let id = match role {
        Role::Robot(id) if id < scenario.robots.count => id,
        Role::Robot(id) => anyhow::bail!(
            "--id {id} is out of range: the scenario has robots.count = {}",
            scenario.robots.count
        ),
        Role::Base => scenario
            .base_id()
            .context("the scenario has no base station: set base_station.enabled = true")?,
    };
    let sim = zenoh::open(args.zenoh.client(20_000)?)
        .await
        .map_err(zerr)
        .context("joining the sim plane")?;
    let world = world_info(&sim, Duration::from_secs(20)).await?;
    let lockstep = scenario.clock.marked();
    let radio_cfg = radio_peer(
        id,
        scenario.nodes(),
        &args.radio_listen,
        &args.radio_connect,
        args.radio_config.as_deref(),
        &[],
        lockstep,
    )?;
    let radio = RadioPlane::open(radio_cfg)
        .await
        .context("opening the radio plane")?;
    let idle = Duration::from_secs_f64(args.idle_timeout_s.max(0.1));
    if proto::msg::log_owner(id, args.life).is_none() {
        anyhow::bail!(
            "--life {} is out of range: at most {}",
            args.life,
            proto::msg::MAX_LIVES - 1
        );
    }
    let end = run_robot(
        (id, args.life),
        &scenario,
        sim.clone(),
        (radio.session.clone(), radio.dialer(id)),
        world,
        idle,
    )
    .await?;
    radio.close().await;
    close_quickly(sim).await;
    Ok(end)
}

/// The whole process of robot `args.id`: one tokio runtime, logging, exit code.
pub fn main(args: Args) -> ExitCode {
    let name = format!("robot-agent {}", args.id);
    process(&name, Role::Robot(args.id), args.node)
}

/// The whole process of the base station.
pub fn base_main(args: BaseArgs) -> ExitCode {
    process("base-station", Role::Base, args.node)
}

fn process(name: &str, role: Role, args: NodeArgs) -> ExitCode {
    entry(name, async {
        anyhow::Ok(match run(role, args).await? {
            End::Stopped => ExitCode::SUCCESS,
            End::WorldGone => {
                eprintln!("{name}: the world-server is gone; exiting");
                ExitCode::SUCCESS
            }
            End::WorldSilent => {
                eprintln!("{name}: no scan from the world-server for too long; exiting");
                ExitCode::FAILURE
            }
        })
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn flags_round_trip_through_to_argv() {
        let mut args = Args::new(
            3,
            PathBuf::from("/tmp/run/scenario.toml"),
            ZenohArgs {
                connect: vec!["tcp/127.0.0.1:7447".into()],
                ..ZenohArgs::default()
            },
        );
        args.node.scenario.set = vec!["exchange.hello_every_steps=5".into()];
        args.node.radio_listen = vec!["tcp/127.0.0.1:7503".into()];
        args.node.radio_connect = vec!["tcp/127.0.0.1:7600".into(), "tcp/127.0.0.1:7601".into()];
        args.node.radio_config = Some(PathBuf::from("radio.json5"));
        args.node.idle_timeout_s = 0.25;
        args.node.life = 2;
        let argv = std::iter::once("robot-agent".to_string()).chain(args.to_argv());
        assert_eq!(Args::parse_from(argv), args);
        let base = BaseArgs { node: args.node };
        let argv = std::iter::once("base-station".to_string()).chain(base.to_argv());
        assert_eq!(BaseArgs::parse_from(argv), base);
    }
}
