//! `swarm run`: one exploration run, every participant its own OS process.
//!
//! [`prepare`]: resolve the scenario, create the run directory, pick the ports →
//! [`spawn`]: start the world-server (sim-plane router), join the sim plane, fetch the truth,
//! start netem and the robots → [`follow`]: status and telemetry (evaluate, show progress,
//! watch children) until done, the step limit, a failure or a signal → [`finish`]: stop
//! everyone, reap every child, write the run directory.

mod finish;
mod follow;
mod prepare;
mod secrets;
mod spawn;
mod steps;

use std::path::PathBuf;
use std::time::Instant;

use crate::evaluate::Evaluator;
use crate::progress::Progress;
use crate::rundir::{run_digest, write_summary, Summary};
use crate::supervise::Supervisor;

/// Flags of `swarm run`.
#[derive(clap::Args, Debug, Clone, PartialEq)]
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
    /// Spread the run over hosts: a hosts file saying where each process runs and how it is
    /// started there (ssh, or a command prefix); see README "Running across machines".
    #[arg(long, value_name = "FILE")]
    pub hosts: Option<PathBuf>,
    /// Serve a live web viewer of the run at ADDR (default 127.0.0.1:0: a free port); the
    /// address is printed and written to the run directory as `view.addr`.
    #[arg(long, value_name = "ADDR", num_args = 0..=1, require_equals = true, default_missing_value = "127.0.0.1:0")]
    pub view: Option<std::net::SocketAddr>,
}

impl RunArgs {
    /// The flags that parse back into these arguments (how `swarm sweep` starts its runs).
    pub fn to_argv(&self) -> Vec<String> {
        let mut a = Vec::new();
        if let Some(out) = &self.out {
            a.extend(["--out".into(), out.to_string_lossy().into_owned()]);
        }
        for s in &self.set {
            a.extend(["--set".into(), s.clone()]);
        }
        if self.quiet {
            a.push("--quiet".into());
        }
        if let Some(h) = &self.hosts {
            a.extend(["--hosts".into(), h.to_string_lossy().into_owned()]);
        }
        if let Some(v) = self.view {
            a.push(format!("--view={v}"));
        }
        // Last, after `--`: a scenario path that starts with `-` is not taken for a flag.
        if let Some(s) = &self.scenario {
            a.extend(["--".into(), s.to_string_lossy().into_owned()]);
        }
        a
    }
}

/// How a run ended, for the exit code.
pub struct Outcome {
    pub dir: PathBuf,
    pub summary: Summary,
}

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
    let lockstep = plan.scenario.clock.mode == proto::scenario::ClockMode::Lockstep;
    let sup = Supervisor::new(
        plan.scenario.supervise.clone(),
        plan.scenario.process_faults()?,
    );
    let mut rec = follow::Record::new(eval, lockstep, sup);
    let mut log = crate::steplog::StepLogWriter::create(
        &plan.dir,
        run.truth.map,
        &run.truth_grid,
        plan.robots(),
        plan.scenario.clock.step_seconds,
    )?;
    let viewer = match args.view {
        Some(addr) => {
            let api = crate::view::NetemApi {
                addr: plan.ports.http,
                token: if plan.api_token() {
                    Some(
                        std::fs::read_to_string(plan.dir.join("netem.token"))?
                            .trim()
                            .to_string(),
                    )
                } else {
                    None
                },
            };
            let (viewer, feed) =
                crate::view::live(addr, log.header().clone(), api, run.sim.session.clone()).await?;
            std::fs::write(plan.dir.join("view.addr"), format!("{}\n", viewer.addr))?;
            progress.event(&format!("swarm run: viewer at http://{}/", viewer.addr));
            let f = feed.clone();
            log.tee = Some(Box::new(move |r| f.push(r.clone())));
            Some((viewer, feed))
        }
        None => None,
    };
    rec.log = Some(log);
    let exit_reason = follow::follow(&plan, &mut run, &mut rec, &mut progress).await?;
    let (truth, info) = (run.truth_grid.clone(), run.truth.map);
    let (processes, memory) = finish::stop(run, &mut rec, &mut progress).await;
    for e in spawn::clean_hosts(&plan) {
        progress.event(&format!("swarm run: {e}"));
    }
    rec.truncate();
    if let Some(Err(e)) = rec.log.take().map(crate::steplog::StepLogWriter::finish) {
        progress.event(&format!("swarm run: {e:#}"));
    }
    if let Some((viewer, feed)) = viewer {
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
    let up = rec.links.up_by_step();
    finish::score_contact(&plan, &mut rec, &up);
    finish::score_comm_level(&plan, &mut rec, &up);
    let mut summary = finish::summary(&plan, &rec, &up, exit_reason, started);
    finish::write_tables(&plan.dir, &rec)?;
    crate::rundir::write_rows(&plan.dir.join("processes.csv"), processes)?;
    crate::rundir::write_rows(&plan.dir.join("memory.csv"), memory)?;
    finish::write_pictures(&plan.dir, (&truth, info), &rec, &mut progress)?;
    summary.run_digest = run_digest(&plan.dir)?;
    summary.deterministic = summary.nondeterministic.is_empty();
    write_summary(&plan.dir, &summary)?;
    Ok(Outcome {
        dir: plan.dir,
        summary,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use clap::Parser;

    #[derive(clap::Parser)]
    struct Cli {
        #[command(flatten)]
        run: RunArgs,
    }

    #[test]
    fn flags_round_trip_through_to_argv() {
        let full = RunArgs {
            scenario: Some(PathBuf::from("configs/experiments/../default.toml")),
            out: Some(PathBuf::from("sweeps/x/runs/a=1-seed2")),
            set: vec!["robots.count=3".into(), "seed=2".into()],
            quiet: true,
            hosts: Some(PathBuf::from("lab/hosts.toml")),
            view: Some("127.0.0.1:0".parse().expect("an address")),
        };
        let bare = RunArgs {
            scenario: None,
            out: None,
            set: Vec::new(),
            quiet: false,
            hosts: None,
            view: None,
        };
        for args in [full, bare] {
            let argv = ["run".to_string()].into_iter().chain(args.to_argv());
            assert_eq!(Cli::parse_from(argv).run, args);
        }
    }
}
