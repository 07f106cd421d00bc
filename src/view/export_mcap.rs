//! `swarm export-mcap RUN_DIR`: a run as an MCAP file, `run.mcap`, for Foxglove (or any MCAP
//! reader), from the run's step log ([`crate::rundir::steplog`]), written by Foxglove's SDK: the
//! topics and schemas are [`crate::view::foxglove`]'s, the same as a live run's. Uncompressed
//! chunks (the SDK's MCAP writer without its zstd/lz4 C builds); messages in log-time order.

use std::fs::File;
use std::io::BufWriter;
use std::path::{Path, PathBuf};

use anyhow::Context as _;
use foxglove::{Context, McapWriteOptions, McapWriter};

use crate::rundir::steplog::{self, Record, StepLog};
use crate::view::foxglove::{last_reports, Counts, Scene};

/// Flags of `swarm export-mcap`.
#[derive(clap::Args, Debug, Clone)]
pub struct ExportArgs {
    /// A finished run's directory (it holds steps.log).
    pub run_dir: PathBuf,
    /// Where to write (default: RUN_DIR/run.mcap).
    #[arg(long)]
    pub out: Option<PathBuf>,
}

/// Writes the MCAP of the run in `args.run_dir`; returns where and the messages per topic.
pub fn export(args: &ExportArgs) -> anyhow::Result<(PathBuf, Counts)> {
    let log = steplog::read(&args.run_dir)?;
    if let Some(w) = log.cut_warning(&args.run_dir) {
        eprintln!("swarm: {w}");
    }
    let out = args
        .out
        .clone()
        .unwrap_or_else(|| default_path(&args.run_dir));
    let file = File::create(&out).with_context(|| format!("cannot create {}", out.display()))?;
    let counts =
        write(&log, BufWriter::new(file)).with_context(|| format!("writing {}", out.display()))?;
    Ok((out, counts))
}

/// `swarm export-mcap`: writes the file and prints it with the messages per topic.
pub fn command(args: &ExportArgs) -> anyhow::Result<std::process::ExitCode> {
    let (path, counts) = export(args)?;
    println!("written {}", path.display());
    for (topic, n) in counts {
        println!("  {topic}: {n} messages");
    }
    Ok(std::process::ExitCode::SUCCESS)
}

/// Writes `log` as MCAP to `w`; the messages per topic.
pub fn write<W>(log: &StepLog, w: W) -> anyhow::Result<Counts>
where
    W: std::io::Write + std::io::Seek + Send + 'static,
{
    let ctx = Context::new();
    let options = McapWriteOptions::new().compression(None).profile("");
    let mcap = McapWriter::with_options(options).context(&ctx).create(w)?;
    let mut scene = Scene::new(&ctx, &log.header, last_reports(log), true);
    scene.hold_back(log.lateness());
    // The run's tables end at its last step with reports; so does the file.
    let end = log.last_step();
    for r in &log.records {
        let past_end = match r {
            Record::Poses { step, .. } => end.is_some_and(|e| *step > e.saturating_add(1)),
            Record::Links { step, .. } | Record::Channel { step, .. } => {
                end.is_some_and(|e| *step > e)
            }
            _ => false,
        };
        if !past_end {
            scene.push(r).map_err(anyhow::Error::msg)?;
        }
    }
    scene.finish();
    mcap.close()?;
    Ok(scene.counts().clone())
}

/// The path of a run directory's MCAP file.
pub fn default_path(run_dir: &Path) -> PathBuf {
    run_dir.join("run.mcap")
}
