//! The world-server's command line: flags → validated scenario → [`crate::server::serve`].

use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::time::Duration;

use anyhow::Context;
use clap::Parser;
use proto::node::{close_quickly, init_logging, zerr, ZenohArgs};
use proto::scenario::Scenario;

use crate::server::{serve, End, ServeOpts};
use crate::world::World;

/// The simulated world of swarm-explore: owns the truth map and the clock, casts every robot's
/// laser scan and applies its moves. Runs a zenoh router for the sim plane that robots, netem
/// and the launcher join as clients. Normally started by `swarm run`.
#[derive(Parser, Debug, Clone)]
#[command(name = "world-server", version)]
pub struct Args {
    /// Scenario TOML file (see configs/default.toml for every key).
    #[arg(long, value_name = "FILE")]
    pub scenario: PathBuf,
    /// Override a scenario key, e.g. --set robots.count=8 (repeatable).
    #[arg(long = "set", value_name = "KEY=VALUE")]
    pub set: Vec<String>,
    /// Seconds to wait for every robot to join before giving up.
    #[arg(long, default_value_t = 60.0, value_name = "SECONDS")]
    pub startup_timeout_s: f64,
    #[command(flatten)]
    pub zenoh: ZenohArgs,
}

/// Where shipped maps live in the source tree (for runs from a checkout).
pub const SHIPPED_MAPS: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/../configs/maps");

/// Finds the map YAML of `world.map`: a path (relative to `base`), or a map name looked up in
/// `base`, `base/maps`, `./configs/maps` and the source tree's `configs/maps`.
pub fn locate_map(name: &str, base: &Path) -> anyhow::Result<PathBuf> {
    let direct = base.join(name);
    if direct.is_file() {
        return Ok(direct);
    }
    let file = format!("{name}.yaml");
    let dirs = [
        base.to_path_buf(),
        base.join("maps"),
        PathBuf::from("configs/maps"),
        PathBuf::from(SHIPPED_MAPS),
    ];
    dirs.iter()
        .map(|d| d.join(&file))
        .find(|p| p.is_file())
        .with_context(|| {
            format!(
                "world.map = {name:?}: no such map file, and no {file} in {}",
                dirs.iter()
                    .map(|d| d.display().to_string())
                    .collect::<Vec<_>>()
                    .join(", ")
            )
        })
}

/// Builds the world of a scenario file (also used by tests and the launcher's dry checks).
pub fn build_world(args: &Args) -> anyhow::Result<(Scenario, World)> {
    let scenario = Scenario::load(&args.scenario, &args.set)?;
    let base = args.scenario.parent().unwrap_or(Path::new("."));
    let map = if scenario.world_is_generated() {
        None
    } else {
        Some(locate_map(&scenario.world.map, base)?)
    };
    let world = World::build(&scenario, map.as_deref())?;
    Ok((scenario, world))
}

async fn run(args: Args) -> anyhow::Result<End> {
    let (scenario, world) = build_world(&args)?;
    let session = zenoh::open(args.zenoh.router()?)
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

/// The whole process: one tokio runtime, logging, exit code.
pub fn main(args: Args) -> ExitCode {
    init_logging();
    let runtime = match tokio::runtime::Runtime::new() {
        Ok(r) => r,
        Err(e) => {
            eprintln!("world-server: cannot start the runtime: {e}");
            return ExitCode::FAILURE;
        }
    };
    match runtime.block_on(run(args)) {
        Ok(end) => {
            tracing::info!("world-server ended: {end:?}");
            ExitCode::SUCCESS
        }
        Err(e) => {
            eprintln!("world-server: {e:#}");
            ExitCode::FAILURE
        }
    }
}
