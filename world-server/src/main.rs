//! `world-server` binary: see [`world_server::cli`].

use clap::Parser;

fn main() -> std::process::ExitCode {
    world_server::cli::main(world_server::cli::Args::parse())
}
