//! Starting the processes of a run: the world-server (the sim plane's router) first, then —
//! once the launcher has joined the sim plane, fetched the truth and subscribed to what it
//! follows — netem and every robot-agent; each on its host (`--hosts`), or here.

use std::path::Path;
use std::time::{Duration, Instant};

use anyhow::{bail, Context};
use proto::confine::Principal;
use proto::grid::Grid;
use proto::keys;
use proto::msg::{RobotId, TruthMap};
use proto::node::{zerr, ZenohArgs};
use proto::scenario::Process;
use zenoh::handlers::FifoChannelHandler;
use zenoh::pubsub::Subscriber;
use zenoh::sample::Sample;
use zenoh::Session;

use super::prepare::Plan;
use super::secrets;
use crate::process::children::{describe, Children};
use crate::process::hosts::Start;
use crate::process::ports::endpoint;
use crate::process::remote;

/// A sim-plane subscription of the launcher.
pub type Sub = Subscriber<FifoChannelHandler<Sample>>;

/// The launcher's side of the sim plane.
pub struct Sim {
    pub session: Session,
    pub statuses: Sub,
    pub telemetry: Sub,
    pub link_reports: Sub,
    /// Process faults asked for through netem's API.
    pub process_orders: Sub,
}

/// A run whose processes are all started.
pub struct Started {
    pub children: Children,
    pub sim: Sim,
    pub truth: TruthMap,
    pub truth_grid: Grid,
    pub reachable: Grid,
}

/// Starts every process of the run.
pub async fn start(plan: &Plan) -> anyhow::Result<Started> {
    let exe = std::env::current_exe().context("locating the swarm binary")?;
    secrets::write_logins(plan)?;
    std::fs::write(
        plan.dir.join("sim.endpoint"),
        format!("{}\n", plan.ports.sim_endpoint()),
    )
    .context("writing sim.endpoint")?;
    let mut children = Children::default();
    spawn_on_host(
        plan,
        &mut children,
        Process::WorldServer,
        &exe,
        &world_server_argv(plan),
    )?;
    let session = join_sim(
        &sim_client(plan, Principal::Launcher),
        &mut children,
        &plan.dir,
    )
    .await?;
    let truth = fetch_truth(&session, &mut children, &plan.dir).await?;
    let truth_grid = Grid::from_rle(&truth.grid_rle).context("truth grid")?;
    let reachable = Grid::from_rle(&truth.reachable_rle).context("reachable grid")?;
    // Subscribed before the robots start, so that nothing they report is missed.
    let sim = subscribe(session).await?;

    // Radio plane: every robot pair {i, j} runs through netem's proxy for the pair: robot i
    // connects to the proxy, netem forwards to robot j's radio listener. No robot is given
    // another robot's radio endpoint.
    if plan.api_token() {
        secrets::write_token(&plan.dir.join("netem.token"))?;
    }
    send_host_files(plan, &exe)?;
    respawn(plan, &mut children, Process::Netem, 0)?;
    std::fs::write(
        plan.dir.join("netem.addr"),
        format!("{}\n", plan.ports.http_addr()),
    )
    .context("writing netem.addr")?;
    for i in 0..plan.robots() {
        respawn(plan, &mut children, Process::Robot(i), 0)?;
    }
    if plan.scenario.base_id().is_some() {
        respawn(plan, &mut children, Process::BaseStation, 0)?;
    }
    Ok(Started {
        children,
        sim,
        truth,
        truth_grid,
        reachable,
    })
}

/// Starts `process` of the run in its life `life` (0: at the start; a restart: the next one),
/// with the flags, ports and log of its first life. The world-server is started only once, by
/// [`start`].
pub fn respawn(
    plan: &Plan,
    children: &mut Children,
    process: Process,
    life: u16,
) -> anyhow::Result<u32> {
    let exe = std::env::current_exe().context("locating the swarm binary")?;
    let argv = match process {
        Process::Netem => netem_argv(plan),
        Process::Robot(i) => robot_argv(plan, i, life),
        Process::BaseStation => {
            let b = plan
                .scenario
                .base_id()
                .context("the scenario has no base station")?;
            let mut node = node_args(plan, b);
            node.life = life;
            let args = robot_agent::cli::BaseArgs { node };
            ["base-station".to_string()]
                .into_iter()
                .chain(args.to_argv())
                .collect()
        }
        Process::WorldServer => bail!("the world-server is started once, with the run"),
    };
    spawn_on_host(plan, children, process, &exe, &argv)
}

/// Starts `swarm argv…` as `process` on its host (here, without a hosts file).
fn spawn_on_host(
    plan: &Plan,
    children: &mut Children,
    process: Process,
    exe: &Path,
    argv: &[String],
) -> anyhow::Result<u32> {
    let name = process.to_string();
    let log = plan.log(&name);
    match plan.host(process) {
        None => children.spawn(&name, exe, argv, &log, false),
        Some(host) => {
            let (program, args, leashed) = remote::process_command(host, exe, argv, &plan.dir);
            children.spawn(&name, Path::new(&program), &args, &log, leashed)
        }
    }
}

/// How long an ssh host may take to take the run's files, or to remove them.
const HOST_FILES_WAIT: Duration = Duration::from_secs(30);

/// Copies to every ssh host what its processes read: `scenario.toml` and their own logins
/// (only theirs).
fn send_host_files(plan: &Plan, exe: &Path) -> anyhow::Result<()> {
    let Some(placement) = &plan.placement else {
        return Ok(());
    };
    let read = |path: &Path| -> anyhow::Result<remote::SentFile> {
        let rel = path.strip_prefix(&plan.dir).unwrap_or(path);
        Ok(remote::SentFile {
            path: rel.to_string_lossy().into_owned(),
            text: std::fs::read_to_string(path)
                .with_context(|| format!("reading {}", path.display()))?,
        })
    };
    for (_, procs) in placement.by_host() {
        let Some(host) = procs.first().and_then(|&p| placement.host(p)) else {
            continue;
        };
        if !matches!(host.start, Start::Ssh { .. }) {
            continue;
        }
        let mut files = vec![read(&plan.scenario_file)?];
        for &p in &procs {
            let id = match p {
                Process::Robot(i) => i,
                Process::BaseStation => match plan.scenario.base_id() {
                    Some(b) => b,
                    None => continue,
                },
                Process::WorldServer | Process::Netem => continue,
            };
            files.push(read(&secrets::credentials(plan, secrets::node(plan, id)))?);
        }
        remote::send_files(host, exe, &plan.dir, &files, HOST_FILES_WAIT)
            .context("copying the run's files over ssh")?;
    }
    Ok(())
}

/// Removes every ssh host's copy of the run directory (its logins with it); what fails is
/// returned as messages, after trying every host.
pub fn clean_hosts(plan: &Plan) -> Vec<String> {
    let Some(placement) = &plan.placement else {
        return Vec::new();
    };
    let Ok(exe) = std::env::current_exe() else {
        return vec!["locating the swarm binary".into()];
    };
    placement
        .used()
        .filter(|h| matches!(h.start, Start::Ssh { .. }))
        .filter_map(|h| {
            remote::remove_files(h, &exe, &plan.dir, HOST_FILES_WAIT)
                .err()
                .map(|e| format!("{e:#}"))
        })
        .collect()
}

async fn subscribe(session: Session) -> anyhow::Result<Sim> {
    let sub = |key: &'static str| {
        let session = session.clone();
        async move { session.declare_subscriber(key).await.map_err(zerr) }
    };
    Ok(Sim {
        statuses: sub(keys::STATUS).await?,
        telemetry: sub(keys::TELEMETRY_ALL).await?,
        link_reports: sub(keys::NETEM_LINKS).await?,
        process_orders: sub(keys::PROCESS_ORDERS).await?,
        session,
    })
}

/// A client of the run's sim plane, logged in as `who`.
fn sim_client(plan: &Plan, who: Principal) -> ZenohArgs {
    ZenohArgs {
        connect: vec![plan.ports.sim_endpoint()],
        credentials: Some(secrets::credentials(plan, who)),
        cfg: sim_lease(plan),
        ..ZenohArgs::default()
    }
}

/// Every sim-plane session's lease (each side declares its own): the scenario's
/// ([`proto::scenario::Scenario::sim_lease_ms`]).
fn sim_lease(plan: &Plan) -> Vec<String> {
    vec![format!(
        "transport/link/tx/lease:{}",
        plan.scenario.sim_lease_ms()
    )]
}

/// How long the world waits for every node to join, per node, when that is longer than its
/// default (60 s): 0.5 s.
const JOIN_S_PER_NODE: f64 = 0.5;

fn world_server_argv(plan: &Plan) -> Vec<String> {
    let router = ZenohArgs {
        listen: vec![plan.ports.sim_endpoint()],
        users: Some(secrets::users(plan)),
        cfg: sim_lease(plan),
        ..ZenohArgs::default()
    };
    let mut args = world_server::cli::Args::new(plan.scenario_file.clone(), router);
    // Every node must join before step 0: the launcher starts them one after the other, so a
    // big team takes longer (half a second a node on a loaded machine, beyond the default).
    let nodes = f64::from(plan.scenario.nodes());
    args.startup_timeout_s = args.startup_timeout_s.max(JOIN_S_PER_NODE * nodes);
    ["world-server".to_string()]
        .into_iter()
        .chain(args.to_argv())
        .collect()
}

fn netem_argv(plan: &Plan) -> Vec<String> {
    let mut args = netem::cli::Args::new(
        plan.scenario_file.clone(),
        sim_client(plan, Principal::Netem),
    );
    args.http = Some(plan.ports.http);
    args.totals_out = Some(plan.dir.join("link_totals.csv"));
    args.token_file = plan.api_token().then(|| plan.dir.join("netem.token"));
    args.nodes = (0..).zip(plan.ports.radio.iter().copied()).collect();
    args.proxy_host = plan.ports.proxy_host;
    ["netem".to_string(), "serve".to_string()]
        .into_iter()
        .chain(args.to_argv())
        .collect()
}

/// Node `i`'s flags: it listens on its radio port; it connects to netem's proxy of a pair in
/// which it has the lower id when a step's plan says where (the pair's link is up).
fn node_args(plan: &Plan, i: RobotId) -> robot_agent::cli::NodeArgs {
    let mut args = robot_agent::cli::NodeArgs::new(
        plan.scenario_file.clone(),
        sim_client(plan, secrets::node(plan, i)),
    );
    // The world may take its step wait to decide a step, and a robot waiting on its neighbours'
    // markers hears nothing meanwhile: it takes the world for gone only after two of them
    // (a big team's first step, every session forming at once, takes the start allowance;
    // the robot follows the wait from there, proto::step_wait).
    let start_s = plan.scenario.start_step_wait_ms() as f64 / 1000.0;
    args.idle_timeout_s = args.idle_timeout_s.max(2.0 * start_s);
    args.radio_listen = vec![endpoint(plan.ports.radio[usize::from(i)])];
    args
}

fn robot_argv(plan: &Plan, i: RobotId, life: u16) -> Vec<String> {
    let mut node = node_args(plan, i);
    node.life = life;
    let args = robot_agent::cli::Args { id: i, node };
    ["robot-agent".to_string()]
        .into_iter()
        .chain(args.to_argv())
        .collect()
}

/// The last non-empty line of a child's log (its error message, when it failed).
pub fn last_log_line(log: &Path) -> String {
    std::fs::read_to_string(log)
        .ok()
        .and_then(|t| {
            t.lines()
                .rev()
                .find(|l| !l.trim().is_empty())
                .map(str::to_string)
        })
        .unwrap_or_else(|| format!("see {}", log.display()))
}

/// Fails with the child's own last words if any child has exited.
fn check_started(children: &mut Children, dir: &Path) -> anyhow::Result<()> {
    if let Some((name, _, status)) = children.newly_exited().into_iter().next() {
        let why = last_log_line(&dir.join(format!("logs/{name}.log")));
        bail!(
            "{name} exited during start-up ({}): {why}",
            describe(status)
        );
    }
    Ok(())
}

/// Joins the sim plane in short attempts, watching the children meanwhile: a world-server that
/// fails at start-up is reported with its own error, not as a connection time-out.
async fn join_sim(
    zargs: &ZenohArgs,
    children: &mut Children,
    dir: &Path,
) -> anyhow::Result<Session> {
    let deadline = Instant::now() + Duration::from_secs(30);
    loop {
        check_started(children, dir)?;
        match zenoh::open(zargs.client(500)?).await {
            Ok(s) => return Ok(s),
            Err(e) if Instant::now() > deadline => {
                return Err(zerr(e)).context("joining the sim plane")
            }
            Err(_) => tokio::time::sleep(Duration::from_millis(100)).await,
        }
    }
}

async fn fetch_truth(
    session: &Session,
    children: &mut Children,
    dir: &Path,
) -> anyhow::Result<TruthMap> {
    let deadline = Instant::now() + Duration::from_secs(60);
    loop {
        check_started(children, dir)?;
        if let Some(t) = proto::node::query_once::<TruthMap>(session, keys::WORLD_TRUTH).await? {
            return Ok(t);
        }
        if Instant::now() > deadline {
            bail!(
                "the world-server did not answer {} within 60 s",
                keys::WORLD_TRUTH
            );
        }
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
}
