//! `netem` binary: not built yet (issue #3); it says so and exits with an error.

fn main() -> std::process::ExitCode {
    eprintln!("netem: the link emulator is not implemented yet (issue #3)");
    std::process::ExitCode::FAILURE
}
