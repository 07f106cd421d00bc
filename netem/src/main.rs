//! `netem` binary: see [`netem::cli`].

use clap::Parser;

fn main() -> std::process::ExitCode {
    proto::node::lean_zenoh_threads();
    netem::cli::main(netem::cli::Args::parse())
}
