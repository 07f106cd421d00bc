//! `robot-agent` binary: see [`robot_agent::cli`].

use clap::Parser;

fn main() -> std::process::ExitCode {
    proto::node::lean_zenoh_threads();
    robot_agent::cli::main(robot_agent::cli::Args::parse())
}
