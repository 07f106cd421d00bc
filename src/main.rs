//! `swarm`: command line of the launcher. Thin: parse, dispatch, map errors to exit codes.

use std::process::ExitCode;

use clap::{Parser, Subcommand};

/// swarm-explore: a team of robots explores an unknown world over a weak radio. Every robot is
/// its own OS process speaking zenoh; a world-server simulates the world.
#[derive(Parser, Debug)]
#[command(name = "swarm", version)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand, Debug)]
enum Command {
    /// Run one exploration: start the world-server and N robot-agents, follow them to the end,
    /// write the run directory. Exit code 0 if the exploration completed, 2 if it ended
    /// incomplete (step limit, all robots idle or dead, interrupted), 1 on error.
    Run(swarm::run::RunArgs),
    /// Replay one robot exploring alone, without network, through the mapping pipeline
    /// (contours, incremental approximation, edit ops): writes PNGs of G_s, P_t and A_t,
    /// replay.csv per step and replay.json with bytes per package type and e_avg.
    Replay(swarm::cmd::replay::ReplayArgs),
    /// Run an experiment: every combination of its grid of scenario overrides × seeds, a few
    /// runs at a time; resumable (finished runs are skipped); writes runs.csv and results.csv.
    Sweep(swarm::sweep::runner::SweepArgs),
    /// A chaos campaign: a random schedule of process faults (robots killed, restarted, frozen;
    /// netem restarted) and link faults (cuts, partitions, latency, bandwidth, resets) drawn
    /// from --seed, one run under it, then a checker — the exploration completes, no op another
    /// robot held is lost, no panic, no orphan process, memory bounded. Writes chaos.json; exit
    /// code 0 if every check passed, 2 if one failed, 1 on error.
    Chaos(swarm::cmd::chaos::ChaosArgs),
    /// Replay a finished run in the web viewer (the page `swarm run --view` serves live): a
    /// time slider over its steps.log. Prints the address it serves; stops on Ctrl-C.
    View(swarm::view::server::ViewArgs),
    /// Write a finished run as MCAP (RUN_DIR/run.mcap, or --out) from its steps.log: grids,
    /// poses, robots and links as Foxglove's well-known schemas, per-link byte counters — open
    /// it in Foxglove Studio. Prints the file and the messages per topic.
    ExportMcap(swarm::view::export_mcap::ExportArgs),
    /// Run a world-server process (what `swarm run` starts; use it to spread a run over machines).
    WorldServer(world_server::cli::Args),
    /// Run one robot-agent process (what `swarm run` starts, once per robot).
    RobotAgent(robot_agent::cli::Args),
    /// Run the base-station process (what `swarm run` starts when the scenario's
    /// [base_station] has enabled = true): a radio node that neither moves nor senses, node id
    /// robots.count; it holds and relays every map it hears of and hosts the `bids` executive.
    BaseStation(robot_agent::cli::BaseArgs),
    /// The netem link emulator: `serve` runs the process (what `swarm run` starts, one proxy
    /// per robot pair); `list`, `cut`, `restore`, `set`, `unset`, `reset` control the links of a
    /// running swarm through its HTTP API (--run RUN_DIR or --api ADDR).
    #[command(subcommand)]
    Netem(swarm::cmd::netemctl::NetemCommand),
    /// What a host of `swarm run --hosts` answers before the run: its protocol version and
    /// free ports on one of its addresses, as one JSON line.
    HostInfo(swarm::process::remote::HostInfoArgs),
    /// What the launcher runs on an ssh host before a run: writes the run's files that the
    /// host's processes read (sent as JSON on stdin) into its copy of the run directory.
    #[command(hide = true)]
    HostFiles(swarm::process::remote::HostFilesArgs),
    /// What the launcher runs on an ssh host for each process: runs it, signals it as stdin
    /// says (stop, cont, term, kill), and kills it when stdin ends.
    #[command(hide = true)]
    OnHost(swarm::process::remote::OnHostArgs),
}

fn main() -> ExitCode {
    match Cli::parse().command {
        Command::Run(args) => run(args),
        Command::Replay(args) => replay(&args),
        Command::Sweep(args) => match swarm::sweep::runner::sweep(&args) {
            Ok(dir) => {
                println!("sweep written to {}", dir.display());
                ExitCode::SUCCESS
            }
            Err(e) => {
                eprintln!("swarm sweep: {e:#}");
                ExitCode::FAILURE
            }
        },
        Command::Chaos(args) => match swarm::cmd::chaos::chaos(&args) {
            Ok((report, dir)) => {
                println!("{}", swarm::cmd::chaos::summary_line(&report, &dir));
                if report.pass {
                    ExitCode::SUCCESS
                } else {
                    ExitCode::from(2)
                }
            }
            Err(e) => {
                eprintln!("swarm chaos: {e:#}");
                ExitCode::FAILURE
            }
        },
        Command::View(args) => {
            proto::node::init_logging();
            let result = tokio::runtime::Runtime::new()
                .map_err(anyhow::Error::from)
                .and_then(|rt| rt.block_on(swarm::view::server::replay(&args)));
            match result {
                Ok(()) => ExitCode::SUCCESS,
                Err(e) => {
                    eprintln!("swarm view: {e:#}");
                    ExitCode::FAILURE
                }
            }
        }
        Command::ExportMcap(args) => match swarm::view::export_mcap::export(&args) {
            Ok((path, counts)) => {
                println!("written {}", path.display());
                for (topic, n) in counts {
                    println!("  {topic}: {n} messages");
                }
                ExitCode::SUCCESS
            }
            Err(e) => {
                eprintln!("swarm export-mcap: {e:#}");
                ExitCode::FAILURE
            }
        },
        Command::WorldServer(args) => world_server::cli::main(args),
        Command::RobotAgent(args) => robot_agent::cli::main(args),
        Command::BaseStation(args) => robot_agent::cli::base_main(args),
        Command::Netem(swarm::cmd::netemctl::NetemCommand::Serve(args)) => netem::cli::main(args),
        Command::HostInfo(args) => match swarm::process::remote::host_info(&args) {
            Ok(info) => {
                println!("{}", serde_json::to_string(&info).unwrap_or_default());
                ExitCode::SUCCESS
            }
            Err(e) => {
                eprintln!("swarm host-info: {e:#}");
                ExitCode::FAILURE
            }
        },
        Command::HostFiles(args) => {
            match swarm::process::remote::host_files(&args, std::io::stdin()) {
                Ok(_) => ExitCode::SUCCESS,
                Err(e) => {
                    eprintln!("swarm host-files: {e:#}");
                    ExitCode::FAILURE
                }
            }
        }
        Command::OnHost(args) => match swarm::process::remote::on_host(&args) {
            Ok(code) => ExitCode::from(u8::try_from(code).unwrap_or(1)),
            Err(e) => {
                eprintln!("swarm on-host: {e:#}");
                ExitCode::FAILURE
            }
        },
        Command::Netem(cmd) => match swarm::cmd::netemctl::control(&cmd) {
            Ok(()) => ExitCode::SUCCESS,
            Err(e) => {
                eprintln!("swarm netem: {e:#}");
                ExitCode::FAILURE
            }
        },
    }
}

fn replay(args: &swarm::cmd::replay::ReplayArgs) -> ExitCode {
    proto::node::init_logging();
    match swarm::cmd::replay::replay(args) {
        Ok((dir, s)) => {
            println!(
                "replay of {}: {} steps, coverage {:.1}%, {} ops, {} bytes, e_avg {}",
                s.map,
                s.steps,
                s.coverage_pct,
                s.ops,
                s.bytes,
                s.approx_error_avg.map_or("-".into(), |e| format!("{e:.4}"))
            );
            for (name, t) in &s.by_type {
                let mean = t.mean_bytes.map_or("-".into(), |m| format!("{m:.2}"));
                println!(
                    "  {name:>4}: {:>8} ops, mean {mean} bytes (thesis {})",
                    t.count, t.thesis_bytes
                );
            }
            println!("written to {}", dir.display());
            ExitCode::SUCCESS
        }
        Err(e) => {
            eprintln!("swarm: {e:#}");
            ExitCode::FAILURE
        }
    }
}

fn run(args: swarm::run::RunArgs) -> ExitCode {
    proto::node::init_logging();
    let runtime = match tokio::runtime::Runtime::new() {
        Ok(r) => r,
        Err(e) => {
            eprintln!("swarm: cannot start the runtime: {e}");
            return ExitCode::FAILURE;
        }
    };
    match runtime.block_on(swarm::run::run(args)) {
        Ok(out) => {
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
            if s.complete {
                ExitCode::SUCCESS
            } else {
                ExitCode::from(2)
            }
        }
        Err(e) => {
            eprintln!("swarm: {e:#}");
            ExitCode::FAILURE
        }
    }
}
