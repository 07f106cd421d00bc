//! `robot-agent` binary: see [`robot_agent::cli`].

use clap::Parser;

fn main() -> std::process::ExitCode {
    robot_agent::cli::main(robot_agent::cli::Args::parse())
}
