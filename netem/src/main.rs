//! `netem` binary: see [`netem::cli`].

use clap::Parser;

fn main() -> std::process::ExitCode {
    netem::cli::main(netem::cli::Args::parse())
}
