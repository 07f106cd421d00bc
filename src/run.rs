//! `swarm run`: one exploration run, every participant its own OS process (DESIGN.md §6).
//!
//! Resolve the scenario → create the run directory → start the world-server (sim-plane router)
//! → join the sim plane, fetch the truth → start the robots, each with its radio endpoints →
//! follow status and telemetry (evaluate, show progress, watch children) until done, the step
//! limit, a failure or Ctrl-C → stop everyone, reap every child → write the run directory.

use std::io::IsTerminal;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use anyhow::{bail, Context};
use proto::grid::{Grid, Occ};
use proto::keys;
use proto::msg::{decode, encode, Control, LinkReport, RobotId, Status, Telemetry, TruthMap};
use proto::node::{zerr, ZenohArgs};
use proto::scenario::Scenario;
use zenoh::qos::CongestionControl;
use zenoh::Session;

use crate::children::{describe, Children};
use crate::evaluate::Evaluator;
use crate::ports::{endpoint, free_ports};
use crate::render::{robot_colour, Picture};
use crate::rundir::{
    bytes_by_type, coverage_steps, write_links, write_metrics, write_summary, LinkLog, Summary,
    SCHEMA_VERSION,
};

/// The embedded default scenario (`configs/default.toml`).
pub const DEFAULT_SCENARIO: &str = include_str!("../configs/default.toml");

/// Steps every robot must be idle in a row before the run ends with `no-frontiers` (data still
/// in flight on the radio may give an idle robot new frontiers).
const IDLE_STEPS: u32 = 5;

/// Flags of `swarm run`.
#[derive(clap::Args, Debug, Clone)]
pub struct RunArgs {
    /// Scenario TOML file; without one, the embedded default (configs/default.toml: intel_lab, 4 robots).
    pub scenario: Option<PathBuf>,
    /// Run directory to write (default: runs/<time>-<map>-<N>r).
    #[arg(long, value_name = "DIR")]
    pub out: Option<PathBuf>,
    /// Override a scenario key, e.g. --set robots.count=8 --set world.map=office (repeatable).
    #[arg(long = "set", value_name = "KEY=VALUE")]
    pub set: Vec<String>,
    /// Print only the final summary, no progress.
    #[arg(long, short)]
    pub quiet: bool,
}

/// How a run ended, for the exit code.
pub struct Outcome {
    pub dir: PathBuf,
    pub summary: Summary,
}

fn load_scenario(args: &RunArgs) -> anyhow::Result<(Scenario, PathBuf)> {
    let (mut s, base) = match &args.scenario {
        Some(p) => (
            Scenario::load(p, &args.set)?,
            p.parent().unwrap_or(Path::new(".")).to_path_buf(),
        ),
        None => (
            Scenario::from_toml(DEFAULT_SCENARIO, &args.set)?,
            PathBuf::from("."),
        ),
    };
    if !s.world_is_generated() {
        let map = world_server::cli::locate_map(&s.world.map, &base)?;
        let map = map
            .canonicalize()
            .with_context(|| format!("resolving {}", map.display()))?;
        s.world.map = map.to_string_lossy().into_owned();
    }
    if let Some(pct) = s.radio.range_pct_of_diagonal {
        s.radio.range_m = pct / 100.0 * environment_diagonal_m(&s)?;
    }
    let name = Path::new(&s.world.map)
        .file_stem()
        .map_or("run".into(), |n| n.to_string_lossy().into_owned());
    Ok((s, PathBuf::from(name)))
}

/// The diagonal of the environment's rectangle: a generated world's extent, or the bounding box
/// of a map's known (free or occupied) cells — the thesis's "maximum communication range".
fn environment_diagonal_m(s: &Scenario) -> anyhow::Result<f64> {
    if s.world_is_generated() {
        return Ok(s.world.width_m.hypot(s.world.height_m));
    }
    let map = world_server::map::load_ros_map(Path::new(&s.world.map))?;
    let g = &map.grid;
    let (mut x0, mut y0, mut x1, mut y1) = (u32::MAX, u32::MAX, 0, 0);
    for (i, &v) in g.cells().iter().enumerate() {
        if v != Occ::Unknown {
            let c = g.cell_of(i);
            (x0, y0) = (x0.min(c.x.unsigned_abs()), y0.min(c.y.unsigned_abs()));
            (x1, y1) = (x1.max(c.x.unsigned_abs()), y1.max(c.y.unsigned_abs()));
        }
    }
    if x0 > x1 {
        bail!("{}: the map has no known cell", s.world.map);
    }
    let cells = f64::from(x1 - x0 + 1).hypot(f64::from(y1 - y0 + 1));
    Ok(cells * map.info.resolution_m)
}

fn run_dir(args: &RunArgs, name: &Path, robots: u16) -> anyhow::Result<PathBuf> {
    let dir = match &args.out {
        Some(d) => d.clone(),
        None => {
            let secs = std::time::SystemTime::now()
                .duration_since(std::time::UNIX_EPOCH)
                .map_or(0, |d| d.as_secs());
            PathBuf::from("runs").join(format!("{secs}-{}-{robots}r", name.display()))
        }
    };
    std::fs::create_dir_all(dir.join("logs"))
        .with_context(|| format!("creating run directory {}", dir.display()))?;
    Ok(dir)
}

/// The last non-empty line of a child's log (its error message, when it failed).
fn last_log_line(log: &Path) -> String {
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

/// Progress on stderr: an updating line on a terminal, a line every few seconds otherwise.
struct Progress {
    tty: bool,
    quiet: bool,
    last: Instant,
}

impl Progress {
    fn show(&mut self, line: &str) {
        if self.quiet {
            return;
        }
        let every = if self.tty {
            Duration::from_millis(200)
        } else {
            Duration::from_secs(5)
        };
        if self.last.elapsed() >= every {
            self.last = Instant::now();
            if self.tty {
                eprint!("\r\x1b[2K{line}");
            } else {
                eprintln!("{line}");
            }
        }
    }

    fn event(&mut self, line: &str) {
        if self.tty && !self.quiet {
            eprint!("\r\x1b[2K");
        }
        eprintln!("{line}");
    }
}

/// Runs one scenario to the end. The caller turns the outcome into an exit code.
///
/// Processes: the world-server (sim-plane router), netem (one proxy per robot pair, HTTP API
/// on a free port written to `netem.addr`), and one robot-agent per robot.
pub async fn run(args: RunArgs) -> anyhow::Result<Outcome> {
    let started = Instant::now();
    let (scenario, name) = load_scenario(&args)?;
    let n = scenario.robots.count;
    let dir = run_dir(&args, &name, n)?;
    let scenario_path = dir.join("scenario.toml");
    std::fs::write(&scenario_path, scenario.to_toml()).context("writing scenario.toml")?;
    let exe = std::env::current_exe().context("locating the swarm binary")?;
    let pairs: Vec<(u16, u16)> = (0..n)
        .flat_map(|i| ((i + 1)..n).map(move |j| (i, j)))
        .collect();
    let ports = free_ports(2 + usize::from(n) + pairs.len())?;
    let sim = endpoint(ports[0]);
    let http = format!("127.0.0.1:{}", ports[1]);
    let radio_port = |i: u16| ports[2 + usize::from(i)];
    let pair_port = |k: usize| ports[2 + usize::from(n) + k];
    let scenario_arg = scenario_path.to_string_lossy().into_owned();
    let mut children = Children::default();
    let mut progress = Progress {
        tty: std::io::stderr().is_terminal(),
        quiet: args.quiet,
        last: Instant::now(),
    };

    children.spawn(
        "world-server",
        &exe,
        &[
            "world-server".into(),
            "--scenario".into(),
            scenario_arg.clone(),
            "--listen".into(),
            sim.clone(),
        ],
        &dir.join("logs/world-server.log"),
    )?;
    let zargs = ZenohArgs {
        connect: vec![sim.clone()],
        ..ZenohArgs::default()
    };
    let session = join_sim(&zargs, &mut children, &dir).await?;
    let truth = fetch_truth(&session, &mut children, &dir).await?;
    let truth_grid = Grid::from_rle(&truth.grid_rle).context("truth grid")?;
    let reachable = Grid::from_rle(&truth.reachable_rle).context("reachable grid")?;
    let mut eval = Evaluator::new(truth_grid.clone(), &reachable, scenario.done_pct);
    let statuses = session
        .declare_subscriber(keys::STATUS)
        .await
        .map_err(zerr)?;
    let telemetry = session
        .declare_subscriber(keys::TELEMETRY_ALL)
        .await
        .map_err(zerr)?;

    let link_reports = session
        .declare_subscriber(keys::NETEM_LINKS)
        .await
        .map_err(zerr)?;

    // Radio plane: every robot pair {i, j} runs through netem's proxy for the pair: robot i
    // connects to the proxy, netem forwards to robot j's radio listener. No robot is given
    // another robot's radio endpoint.
    let mut netem_args: Vec<String> = vec![
        "netem".into(),
        "serve".into(),
        "--scenario".into(),
        scenario_arg.clone(),
        "--connect".into(),
        sim.clone(),
        "--http".into(),
        http.clone(),
        "--totals-out".into(),
        dir.join("link_totals.csv").to_string_lossy().into_owned(),
    ];
    for (k, &(i, j)) in pairs.iter().enumerate() {
        netem_args.push("--pair".into());
        netem_args.push(format!(
            "{i}-{j}=127.0.0.1:{}>127.0.0.1:{}",
            pair_port(k),
            radio_port(j)
        ));
    }
    children.spawn("netem", &exe, &netem_args, &dir.join("logs/netem.log"))?;
    std::fs::write(dir.join("netem.addr"), format!("{http}\n")).context("writing netem.addr")?;
    for i in 0..n {
        let mut a: Vec<String> = vec![
            "robot-agent".into(),
            "--id".into(),
            i.to_string(),
            "--scenario".into(),
            scenario_arg.clone(),
            "--connect".into(),
            sim.clone(),
            "--radio-listen".into(),
            endpoint(radio_port(i)),
        ];
        for (k, _) in pairs.iter().enumerate().filter(|(_, &(a, _))| a == i) {
            a.push("--radio-connect".into());
            a.push(endpoint(pair_port(k)));
        }
        children.spawn(
            &format!("robot-{i}"),
            &exe,
            &a,
            &dir.join(format!("logs/robot-{i}.log")),
        )?;
    }
    if !args.quiet {
        eprintln!(
            "swarm run: {} robots on {} ({} reachable free cells), run directory {}, netem API http://{http}",
            n,
            name.display(),
            eval.reachable_cells(),
            dir.display()
        );
    }

    let mut last_status: Option<Status> = None;
    let mut links = LinkLog::default();
    let mut failed: Vec<String> = Vec::new();
    let mut trajectories: Vec<Vec<(f64, f64)>> = vec![Vec::new(); usize::from(n)];
    let mut idle_since: Option<u32> = None;
    let mut tick = tokio::time::interval(Duration::from_millis(200));
    let mut sigterm = tokio::signal::unix::signal(tokio::signal::unix::SignalKind::terminate())?;
    let exit_reason: String = loop {
        tokio::select! {
            s = statuses.recv_async() => {
                let Ok(s) = s else { break "sim-plane-closed".into() };
                match decode::<Status>(&s.payload().to_bytes()) {
                    Ok(st) => {
                        for r in &st.robots {
                            if let Some(t) = trajectories.get_mut(usize::from(r.id)) { t.push((r.pose.x, r.pose.y)); }
                        }
                        let alive = st.robots.iter().filter(|r| r.alive).count();
                        progress.show(&format!(
                            "step {:>5}/{}  best coverage {:5.1}% (robot {})  robots alive {alive}/{n}",
                            st.step, scenario.max_steps, eval.best.0, eval.best.1
                        ));
                        let done = st.step >= scenario.max_steps;
                        last_status = Some(st);
                        if alive == 0 { break "all-robots-dead".into(); }
                        if done { break "max-steps".into(); }
                    }
                    Err(e) => tracing::warn!("bad status: {e}"),
                }
            }
            t = telemetry.recv_async() => {
                let Ok(t) = t else { break "sim-plane-closed".into() };
                match decode::<Telemetry>(&t.payload().to_bytes()) {
                    Ok(t) => {
                        let step = t.step;
                        eval.add(t);
                        if eval.exploration_step.is_some() { break "explored".into(); }
                        // Every live robot idle (its latest telemetry says it sees no reachable
                        // frontier) for a few steps in a row: nothing is left to explore.
                        let alive: Vec<RobotId> = last_status.as_ref().map_or(Vec::new(), |s| s.robots.iter().filter(|r| r.alive).map(|r| r.id).collect());
                        let all_idle = !alive.is_empty() && alive.iter().all(|id| eval.last.get(id).is_some_and(|(_, t)| t.idle));
                        if all_idle {
                            let since = *idle_since.get_or_insert(step);
                            if step >= since + IDLE_STEPS { break "no-frontiers".into(); }
                        } else { idle_since = None; }
                    }
                    Err(e) => tracing::warn!("bad telemetry: {e}"),
                }
            }
            r = link_reports.recv_async() => {
                let Ok(r) = r else { break "sim-plane-closed".into() };
                match decode::<LinkReport>(&r.payload().to_bytes()) {
                    Ok(r) => links.add(r),
                    Err(e) => tracing::warn!("bad link report: {e}"),
                }
            }
            _ = tick.tick() => {
                let mut world_gone = None;
                for (name, pid, status) in children.newly_exited() {
                    let mut what = format!("{name} (pid {pid}) exited: {}", describe(status));
                    if status.code().is_some_and(|c| c != 0) {
                        what = format!("{what}: {}", last_log_line(&dir.join(format!("logs/{name}.log"))));
                    }
                    progress.event(&format!("swarm run: {what}"));
                    failed.push(what);
                    if name == "world-server" || name == "netem" { world_gone = Some(name); }
                }
                if let Some(name) = world_gone { break format!("{name}-exited"); }
            }
            _ = tokio::signal::ctrl_c() => { progress.event("swarm run: interrupted, stopping every process"); break "interrupted".into(); }
            _ = sigterm.recv() => { progress.event("swarm run: terminated, stopping every process"); break "terminated".into(); }
        }
    };

    let _ = session
        .put(keys::CONTROL, encode(&Control::Stop))
        .congestion_control(CongestionControl::Block)
        .await;
    let killed = children.shutdown(Duration::from_secs(5)).await;
    // Link reports that arrived while the processes were stopping.
    while let Ok(Some(r)) = link_reports.try_recv() {
        if let Ok(r) = decode::<LinkReport>(&r.payload().to_bytes()) {
            links.add(r);
        }
    }
    for name in killed {
        progress.event(&format!(
            "swarm run: {name} did not stop within 5 s and was killed"
        ));
    }
    proto::node::close_quickly(session).await;

    let last = last_status.unwrap_or(Status {
        step: 0,
        robots: Vec::new(),
        collisions_total: 0,
    });
    let per_robot_types: Vec<Vec<u64>> = eval
        .last
        .values()
        .map(|(_, t)| t.sent_by_type.clone())
        .collect();
    let by_type = bytes_by_type(&per_robot_types);
    let backlogs: Vec<u64> = eval
        .rows
        .iter()
        .filter(|r| r.neighbours > 0)
        .map(|r| r.backlog_bytes)
        .collect();
    let summary = Summary {
        schema_version: SCHEMA_VERSION,
        complete: eval.exploration_step.is_some(),
        exit_reason,
        robots: n,
        robots_alive_at_end: last.robots.iter().filter(|r| r.alive).count(),
        steps: last.step,
        wall_seconds: started.elapsed().as_secs_f64(),
        exploration_steps: eval.exploration_step,
        coverage_steps: coverage_steps(&eval.coverage_steps),
        best_coverage_pct: eval.best.0,
        reachable_cells: eval.reachable_cells(),
        // netem's final counters when it wrote them (they include what crossed while the
        // processes stopped), else the last per-step reports.
        bytes_wire_total: Some(
            crate::rundir::link_totals_wire(&dir.join("link_totals.csv"))
                .unwrap_or_else(|| links.wire_total()),
        ),
        bytes_payload_total: eval.last.values().map(|(_, t)| t.bytes_sent).sum(),
        traffic_shares_pct: crate::rundir::traffic_shares(&by_type),
        bytes_by_type: by_type,
        splits_per_step_final: eval
            .last
            .iter()
            .map(|(r, (_, t))| (r.to_string(), t.splits_per_step))
            .collect(),
        backlog_max_bytes: backlogs.iter().copied().max().unwrap_or(0),
        backlog_mean_bytes: if backlogs.is_empty() {
            0.0
        } else {
            backlogs.iter().sum::<u64>() as f64 / backlogs.len() as f64
        },
        // Mean over the robots of their own e_avg (polygon exchange only).
        approx_error_avg: {
            let e: Vec<f64> = eval
                .last
                .values()
                .filter_map(|(_, t)| t.approx_error_avg)
                .collect();
            (!e.is_empty()).then(|| e.iter().sum::<f64>() / e.len() as f64)
        },
        logs_held: eval
            .last
            .iter()
            .map(|(r, (_, t))| {
                (
                    r.to_string(),
                    t.logs.iter().map(|(o, n)| (o.to_string(), *n)).collect(),
                )
            })
            .collect(),
        collisions: last.collisions_total,
        distance_m: last.robots.iter().map(|r| r.distance_m).collect(),
        radio_decode_errors: eval.last.values().map(|(_, t)| t.decode_errors).sum(),
        reconnect: (&links.reconnects()).into(),
        failed_processes: failed,
    };
    write_summary(&dir, &summary)?;
    write_metrics(&dir, &eval.rows)?;
    crate::rundir::write_traffic(&dir, &eval.rows)?;
    crate::rundir::write_saves_and_views(&dir, &eval.saves, &eval.views)?;
    write_links(&dir, &links.rows)?;
    let mut truth_pic = Picture::of_grid(&truth_grid, truth.map);
    for (i, t) in trajectories.iter().enumerate() {
        truth_pic.path(t, robot_colour(i));
        if let Some(&(x, y)) = t.first() {
            truth_pic.marker(x, y, robot_colour(i));
        }
    }
    truth_pic.save(&dir.join("truth.png"))?;
    for (id, (grid, _)) in &eval.last {
        let mut pic = Picture::of_grid(grid, truth.map);
        let i = usize::from(*id);
        if let Some(t) = trajectories.get(i) {
            pic.path(t, robot_colour(i));
            if let Some(&(x, y)) = t.last() {
                pic.marker(x, y, robot_colour(i));
            }
        }
        pic.save(&dir.join(format!("robot_{id}.png")))?;
    }
    // Every robot's final planning grid and G_s as maps (grids/robot_<id>_{planning,own}.pgm).
    let grids = dir.join("grids");
    std::fs::create_dir_all(&grids).context("creating grids/")?;
    for (id, (planning, t)) in &eval.last {
        crate::rundir::write_pgm(&grids.join(format!("robot_{id}_planning.pgm")), planning)?;
        match Grid::from_rle(&t.own_rle) {
            Ok(own) => crate::rundir::write_pgm(&grids.join(format!("robot_{id}_own.pgm")), &own)?,
            Err(e) => progress.event(&format!(
                "swarm run: robot {id}'s own grid is unreadable: {e}"
            )),
        }
    }
    Ok(Outcome { dir, summary })
}
