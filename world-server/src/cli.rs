//! The world-server's command line: flags → validated scenario → [`crate::server::serve`].

use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Duration;

use anyhow::Context;
use clap::Parser;
use proto::confine::Principal;
use proto::node::{close_quickly, entry_logged, stderr_log, zerr, ScenarioArgs, ZenohArgs};
use proto::scenario::Scenario;

use crate::refusals::{Refusals, REPORT_EVERY};
use crate::scenario::resolve;
use crate::server::{serve, End, ServeOpts};
use crate::world::World;

/// The simulated world of swarm-explore: owns the truth map and the clock, casts every robot's
/// laser scan and applies its moves. Runs a zenoh router for the sim plane that robots, netem
/// and the launcher join as clients. Normally started by `swarm run`.
#[derive(Parser, Debug, Clone, PartialEq)]
#[command(name = "world-server", version)]
pub struct Args {
    #[command(flatten)]
    pub scenario: ScenarioArgs,
    /// Seconds to wait for every robot to join before giving up.
    #[arg(long, default_value_t = STARTUP_TIMEOUT_S, value_name = "SECONDS")]
    pub startup_timeout_s: f64,
    #[command(flatten)]
    pub zenoh: ZenohArgs,
}

/// Default of `--startup-timeout-s`.
pub const STARTUP_TIMEOUT_S: f64 = 60.0;

impl Args {
    /// A world-server of `scenario` with every other flag at its default.
    pub fn new(scenario: PathBuf, zenoh: ZenohArgs) -> Args {
        Args {
            scenario: ScenarioArgs::file(scenario),
            startup_timeout_s: STARTUP_TIMEOUT_S,
            zenoh,
        }
    }

    /// The flags that parse back into these arguments (how `swarm run` starts the process).
    pub fn to_argv(&self) -> Vec<String> {
        let mut a = self.scenario.to_argv();
        a.extend([
            "--startup-timeout-s".into(),
            self.startup_timeout_s.to_string(),
        ]);
        a.extend(self.zenoh.to_argv());
        a
    }
}

/// Builds the world of a scenario file (also used by tests and the launcher's dry checks).
pub fn build_world(args: &Args) -> anyhow::Result<(Scenario, World)> {
    let r = resolve(Some(&args.scenario.file), &args.scenario.set)?;
    let world = World::build(&r.scenario, r.map.as_ref())?;
    Ok((r.scenario, world))
}

async fn run(args: Args) -> anyhow::Result<End> {
    let (scenario, world) = build_world(&args)?;
    let principals = Principal::of_run(scenario.robots.count, scenario.base_id());
    let session = zenoh::open(args.zenoh.router(&principals)?)
        .await
        .map_err(zerr)
        .context("opening the sim-plane router")?;
    let end = serve(
        session.clone(),
        world,
        &scenario,
        ServeOpts {
            startup_timeout: Duration::from_secs_f64(args.startup_timeout_s.max(0.1)),
        },
    )
    .await?;
    close_quickly(session).await;
    Ok(end)
}

/// The whole process: one tokio runtime, logging (stderr, and the sim plane's refused logins:
/// [`crate::refusals`]), exit code.
pub fn main(args: Args) -> ExitCode {
    use tracing_subscriber::layer::SubscriberExt;
    use tracing_subscriber::util::SubscriberInitExt;
    let refusals = Refusals::default();
    let _ = tracing_subscriber::registry()
        .with(stderr_log())
        .with(refusals.layer())
        .try_init();
    entry_logged("world-server", async {
        let reporter = tokio::spawn(refusals.clone().report(REPORT_EVERY));
        let end = run(args).await;
        reporter.abort();
        // The refusals counted since the last report, so that none goes unlogged.
        refusals.flush();
        let end = end?;
        tracing::info!("world-server ended: {end:?}");
        anyhow::Ok(ExitCode::SUCCESS)
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn flags_round_trip_through_to_argv() {
        let mut args = Args::new(
            PathBuf::from("/tmp/run/scenario.toml"),
            ZenohArgs {
                listen: vec!["tcp/127.0.0.1:7447".into()],
                ..ZenohArgs::default()
            },
        );
        args.scenario.set = vec!["robots.count=2".into(), "seed=3".into()];
        args.startup_timeout_s = 2.5;
        let argv = std::iter::once("world-server".to_string()).chain(args.to_argv());
        assert_eq!(Args::parse_from(argv), args);
    }
}
