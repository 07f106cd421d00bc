//! `swarm run` from its flags to its outcome: the four stages in order.

use std::net::SocketAddr;
use std::time::Instant;

use crate::run::args::{Outcome, RunArgs};
use crate::run::tables::Tables;
use crate::run::{finish, follow, prepare, spawn};

use crate::process::supervise::Supervisor;
use crate::run::progress::Progress;
use crate::rundir::steplog::StepLogWriter;
use crate::rundir::summary::{run_digest, write_summary};
use crate::score::evaluate::Evaluator;
use crate::view::foxglove;
use crate::view::server::{live, Feed, NetemApi, Viewer};

/// Runs one scenario to the end. The caller turns the outcome into an exit code.
///
/// Processes: the world-server (sim-plane router), netem (one proxy per robot pair, HTTP API
/// on a free port written to `netem.addr`), and one robot-agent per robot.
pub async fn run(args: RunArgs) -> anyhow::Result<Outcome> {
    let started = Instant::now();
    let plan = prepare::prepare(&args)?;
    let mut progress = Progress::new(args.quiet);
    let mut run = spawn::start(&plan).await?;
    let eval = Evaluator::new(
        run.truth_grid.clone(),
        &run.reachable,
        plan.scenario.done_pct,
    )
    .with_base(plan.scenario.base_id())
    .with_team(plan.robots());
    if !args.quiet {
        eprintln!(
            "swarm run: {} robots on {} ({} reachable free cells), run directory {}, netem API http://{}",
            plan.robots(),
            plan.name,
            eval.reachable_cells(),
            plan.dir.display(),
            plan.ports.http_addr()
        );
    }
    let mut rec = record(&plan, eval)?;
    let mut log = StepLogWriter::create(
        &plan.dir,
        run.truth.map,
        &run.truth_grid,
        plan.robots(),
        plan.scenario.clock.step_seconds,
    )?
    .with_channel_capacity(plan.scenario.radio.channel_capacity(&plan.scenario.clock));
    let viewer = match args.view {
        Some(addr) => Some(start_viewer(addr, &plan, &run, &mut log, &mut progress).await?),
        None => None,
    };
    let foxglove = match args.foxglove {
        Some(addr) => Some(start_foxglove(addr, &plan, &mut log, &mut progress).await?),
        None => None,
    };
    rec.log = Some(log);
    let exit_reason = follow::follow(&plan, &mut run, &mut rec, &mut progress).await?;
    let (truth, info) = (run.truth_grid.clone(), run.truth.map);
    let reachable = run.reachable.clone();
    let (processes, memory) = finish::stop(run, &mut rec, &mut progress).await;
    for e in spawn::clean_hosts(&plan) {
        progress.event(&format!("swarm run: {e}"));
    }
    rec.truncate();
    rec.write_the_rest();
    if let Some(Err(e)) = rec.log.take().map(StepLogWriter::finish) {
        progress.event(&format!("swarm run: {e:#}"));
    }
    if let Some((viewer, feed)) = viewer {
        stop_viewer(viewer, &feed, &mut progress);
    }
    if let Some(server) = foxglove {
        stop_foxglove(server, &mut progress).await;
    }
    rec.tables.check()?;
    let mut summary = finish::summary(&plan, &rec, exit_reason, started);
    crate::rundir::tables::write_rows(&plan.dir.join("processes.csv"), processes)?;
    crate::rundir::tables::write_rows(&plan.dir.join("memory.csv"), memory)?;
    finish::write_pictures(&plan.dir, (&truth, info), &reachable, &rec, &mut progress)?;
    summary.run_digest = run_digest(&plan.dir)?;
    summary.deterministic = summary.nondeterministic.is_empty();
    write_summary(&plan.dir, &summary)?;
    Ok(Outcome {
        dir: plan.dir,
        summary,
    })
}

/// What the launcher records of the run: the evaluator's scores, the tables it writes as the
/// steps close, the supervisor of process faults and restarts.
fn record(plan: &prepare::Plan, eval: Evaluator) -> anyhow::Result<follow::Record> {
    let lockstep = plan.scenario.clock.mode == proto::scenario::ClockMode::Lockstep;
    let sup = Supervisor::new(
        plan.scenario.supervise.clone(),
        plan.scenario.process_faults()?,
    );
    let tables = Tables::create(
        &plan.dir,
        usize::from(plan.scenario.robots.count),
        usize::from(plan.scenario.nodes()),
        plan.scenario.base_id(),
    )?;
    Ok(follow::Record::new(eval, tables, lockstep, sup))
}

/// Serves the live viewer at `addr` and tees the step log into its feed; the address goes to
/// the run directory's `view.addr`.
async fn start_viewer(
    addr: SocketAddr,
    plan: &prepare::Plan,
    run: &spawn::Started,
    log: &mut StepLogWriter,
    progress: &mut Progress,
) -> anyhow::Result<(Viewer, Feed)> {
    let token = if plan.api_token() {
        let t = std::fs::read_to_string(plan.dir.join("netem.token"))?;
        Some(t.trim().to_string())
    } else {
        None
    };
    let api = NetemApi {
        addr: plan.ports.http,
        token,
    };
    let (viewer, feed) = live(addr, log.header().clone(), api, run.sim.session.clone()).await?;
    std::fs::write(plan.dir.join("view.addr"), format!("{}\n", viewer.addr))?;
    progress.event(&format!("swarm run: viewer at http://{}/", viewer.addr));
    let f = feed.clone();
    log.tees.push(Box::new(move |r| f.push(r.clone())));
    Ok((viewer, feed))
}

/// Serves the run over the Foxglove WebSocket protocol at `addr` and tees the step log into
/// it; the address goes to the run directory's `foxglove.addr`.
async fn start_foxglove(
    addr: SocketAddr,
    plan: &prepare::Plan,
    log: &mut StepLogWriter,
    progress: &mut Progress,
) -> anyhow::Result<foxglove::Server> {
    let name = format!("swarm-explore: {}", plan.name);
    let server = foxglove::Server::start(addr, log.header(), Default::default(), &name).await?;
    std::fs::write(plan.dir.join("foxglove.addr"), format!("{}\n", server.addr))?;
    progress.event(&format!(
        "swarm run: Foxglove WebSocket at ws://{} (Foxglove: Open connection)",
        server.addr
    ));
    log.tees.push(Box::new(server.feed()));
    Ok(server)
}

/// Sends the Foxglove server's last messages and stops it, saying how many it logged.
async fn stop_foxglove(server: foxglove::Server, progress: &mut Progress) {
    let clients = server.clients();
    let sent: u64 = server.stop().await.values().sum();
    progress.event(&format!(
        "swarm run: the Foxglove server logged {sent} messages ({clients} clients connected at the end)"
    ));
}

/// Ends the viewer's feed, says how many frames it sent, and stops serving.
fn stop_viewer(viewer: Viewer, feed: &Feed, progress: &mut Progress) {
    feed.finish();
    let st = feed.stats();
    if let Some(fps) = st.per_second() {
        progress.event(&format!(
            "swarm run: the viewer sent {} frames to its pages ({fps:.1} a second while one \
             was open); a page that fell behind skipped {}",
            st.sent, st.skipped
        ));
    }
    viewer.stop();
}

/// `swarm run`: one run, its one-line summary on stdout; exit code 0 when the exploration
/// completed, 2 when the run ended incomplete.
pub async fn command(args: RunArgs) -> anyhow::Result<std::process::ExitCode> {
    let out = run(args).await?;
    let s = &out.summary;
    let steps = s.exploration_steps.map_or("-".into(), |v| v.to_string());
    println!(
        "{}: {} after {} steps ({} robots); exploration steps {steps}; best coverage {:.1}%; {:.1} s wall; radio payload {} bytes; run directory {}",
        if s.complete { "complete" } else { "INCOMPLETE" },
        s.exit_reason,
        s.steps,
        s.robots,
        s.best_coverage_pct,
        s.wall_seconds,
        s.bytes_payload_total,
        out.dir.display()
    );
    Ok(if s.complete {
        std::process::ExitCode::SUCCESS
    } else {
        std::process::ExitCode::from(2)
    })
}
