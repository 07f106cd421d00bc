//! `swarm`: command line of the launcher. Thin: parse, dispatch, map errors to exit codes.

use std::process::ExitCode;

use clap::{Parser, Subcommand};
use proto::node::{entry, outcome};

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
    /// incomplete (step limit, all robots idle or dead, interrupted), 1 on error. Any team
    /// size runs without extra flags: the world waits for each step as long as the team and
    /// the machine need (docs/design.md §2.1).
    Run(swarm::run::RunArgs),
    /// Replay one robot exploring alone, without network, through the mapping pipeline
    /// (contours, incremental approximation, edit ops): writes PNGs of G_s, P_t and A_t,
    /// replay.csv per step and replay.json with bytes per package type and e_avg.
    Replay(swarm::cmd::replay::ReplayArgs),
    /// Run an experiment: every combination of its grid of scenario overrides × seeds, a few
    /// runs at a time, or as a Slurm job array (--slurm); resumable (finished runs are
    /// skipped); writes runs.csv, results.csv, plots and report.md.
    Sweep(swarm::sweep::runner::SweepArgs),
    /// What a task of `swarm sweep --slurm`'s job array runs: one run of the sweep.
    #[command(hide = true)]
    SweepTask(swarm::sweep::slurm::TaskArgs),
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
    /// List the worlds `world.map` can name: the real maps this binary carries (size in cells
    /// and metres, resolution, source, licence) and the generated worlds.
    Maps,
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

/// One line a subcommand: the library does the work, [`entry`] and [`outcome`] turn its result
/// into the exit code (an error printed once, as `swarm <sub>: …`).
fn main() -> ExitCode {
    proto::node::lean_zenoh_threads();
    use swarm::{cmd, process::remote, run, sweep, view};
    match Cli::parse().command {
        Command::Run(args) => entry("swarm", run::launch::command(args)),
        Command::Replay(args) => outcome("swarm", cmd::replay::command(&args)),
        Command::Sweep(args) => outcome("swarm sweep", sweep::runner::command(&args)),
        Command::SweepTask(args) => outcome("swarm sweep-task", sweep::slurm::task_command(&args)),
        Command::Chaos(args) => outcome("swarm chaos", cmd::chaos::command(&args)),
        Command::View(args) => entry("swarm view", view::server::command(args)),
        Command::ExportMcap(args) => {
            outcome("swarm export-mcap", view::export_mcap::command(&args))
        }
        Command::Maps => outcome("swarm maps", cmd::maps::command()),
        Command::WorldServer(args) => world_server::cli::main(args),
        Command::RobotAgent(args) => robot_agent::cli::main(args),
        Command::BaseStation(args) => robot_agent::cli::base_main(args),
        Command::Netem(cmd::netemctl::NetemCommand::Serve(args)) => netem::cli::main(*args),
        Command::Netem(c) => outcome("swarm netem", cmd::netemctl::command(&c)),
        Command::HostInfo(args) => outcome("swarm host-info", remote::host_info_command(&args)),
        Command::HostFiles(args) => outcome("swarm host-files", remote::host_files_command(&args)),
        Command::OnHost(args) => outcome("swarm on-host", remote::on_host_command(&args)),
    }
}
