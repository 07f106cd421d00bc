//! The flags of `swarm run` and how a run ended.

use std::path::PathBuf;

use crate::rundir::summary::Summary;

/// Flags of `swarm run`.
#[derive(clap::Args, Debug, Clone, PartialEq)]
pub struct RunArgs {
    /// Scenario TOML file; without one, the embedded default (configs/default.toml: intel_lab, 4
    /// robots).
    pub scenario: Option<PathBuf>,
    /// Run directory to write (default: `runs/<time>-<map>-<N>r`).
    #[arg(long, value_name = "DIR")]
    pub out: Option<PathBuf>,
    /// Override a scenario key, e.g. --set robots.count=8 --set world.map=office (repeatable).
    #[arg(long = "set", value_name = "KEY=VALUE")]
    pub set: Vec<String>,
    /// Print only the final summary, no progress.
    #[arg(long, short)]
    pub quiet: bool,
    /// Spread the run over hosts: a hosts file saying where each process runs and how it is
    /// started there (ssh, or a command prefix); see docs/guide/hosts.md. `--hosts slurm`:
    /// the nodes of the Slurm allocation it runs in, robots started on them by srun (in an
    /// sbatch script or under salloc; docs/guide/slurm.md).
    #[arg(long, value_name = "FILE|slurm")]
    pub hosts: Option<PathBuf>,
    /// Serve a live web viewer of the run at ADDR (default 127.0.0.1:0: a free port); the
    /// address is printed and written to the run directory as `view.addr`.
    #[arg(long, value_name = "ADDR", num_args = 0..=1, require_equals = true, default_missing_value = "127.0.0.1:0")]
    pub view: Option<std::net::SocketAddr>,
    /// Serve the run live over the Foxglove WebSocket protocol at ADDR (default
    /// 127.0.0.1:8765, where Foxglove looks first; port 0: a free port): in Foxglove, "Open
    /// connection", "Foxglove WebSocket", ws://ADDR; the layout assets/foxglove/layout.json shows
    /// it as the web viewer does. The address is written to the run directory as `foxglove.addr`.
    #[arg(long, value_name = "ADDR", num_args = 0..=1, require_equals = true, default_missing_value = "127.0.0.1:8765")]
    pub foxglove: Option<std::net::SocketAddr>,
}

impl RunArgs {
    /// The flags that parse back into these arguments (how `swarm sweep` starts its runs).
    pub fn to_argv(&self) -> Vec<String> {
        let mut a = Vec::new();
        if let Some(out) = &self.out {
            a.extend(["--out".into(), out.to_string_lossy().into_owned()]);
        }
        for s in &self.set {
            a.extend(["--set".into(), s.clone()]);
        }
        if self.quiet {
            a.push("--quiet".into());
        }
        if let Some(h) = &self.hosts {
            a.extend(["--hosts".into(), h.to_string_lossy().into_owned()]);
        }
        if let Some(v) = self.view {
            a.push(format!("--view={v}"));
        }
        if let Some(v) = self.foxglove {
            a.push(format!("--foxglove={v}"));
        }
        // Last, after `--`: a scenario path that starts with `-` is not taken for a flag.
        if let Some(s) = &self.scenario {
            a.extend(["--".into(), s.to_string_lossy().into_owned()]);
        }
        a
    }
}

/// How a run ended, for the exit code.
pub struct Outcome {
    pub dir: PathBuf,
    pub summary: Summary,
}

#[cfg(test)]
mod tests {
    use super::*;
    use clap::Parser;

    #[derive(clap::Parser)]
    struct Cli {
        #[command(flatten)]
        run: RunArgs,
    }

    #[test]
    fn flags_round_trip_through_to_argv() {
        let full = RunArgs {
            scenario: Some(PathBuf::from("configs/experiments/../default.toml")),
            out: Some(PathBuf::from("sweeps/x/runs/a=1-seed2")),
            set: vec!["robots.count=3".into(), "seed=2".into()],
            quiet: true,
            hosts: Some(PathBuf::from("lab/hosts.toml")),
            view: Some("127.0.0.1:0".parse().expect("an address")),
            foxglove: Some("127.0.0.1:8765".parse().expect("an address")),
        };
        let bare = RunArgs {
            scenario: None,
            out: None,
            set: Vec::new(),
            quiet: false,
            hosts: None,
            view: None,
            foxglove: None,
        };
        for args in [full, bare] {
            let argv = ["run".to_string()].into_iter().chain(args.to_argv());
            assert_eq!(Cli::parse_from(argv).run, args);
        }
    }
}
