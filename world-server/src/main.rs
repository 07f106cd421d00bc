//! `world-server` binary: see [`world_server::cli`].

use clap::Parser;

fn main() -> std::process::ExitCode {
    proto::node::lean_zenoh_threads();
    world_server::cli::main(world_server::cli::Args::parse())
}
