//! `swarm sweep`: a grid of scenario overrides × seeds, run as separate `swarm run` processes,
//! a few at a time; resumable (a run whose `summary.json` exists is not run again) and robust (a
//! failed run is recorded and the sweep goes on). Writes `runs.csv`, `results.csv`
//! (`results`), and plots with `report.md` (`report`).
//!
//! An experiment file (TOML; the shipped ones are in configs/experiments/):
//!
//! ```toml
//! name = "e3-traffic"
//! scenario = "../default.toml"   # optional base scenario, relative to this file
//! seeds = 5                       # seeds 1..=seeds per grid point
//! set = ["radio.bandwidth_bytes_per_s=0"]          # overrides for every run
//! fields = ["traffic_shares_pct.vertex"]           # summary fields reported besides the standard ones
//! [grid]                          # every combination of these values is one grid point
//! "exchange.mode" = ["raw-scans", "polygon"]
//! "robots.count" = [3, 8]
//! [with]                          # extra overrides at the grid points where KEY=VALUE
//! "exchange.mode=raw-scans" = ["exchange.hello_every_steps=5"]
//! # a grid key "@name" is a label: no scenario key, only its [with] overrides apply
//! # ("@variant" = ["a", "b"] with "@variant=a" = [...] and "@variant=b" = [...])
//! [quick]                         # `--quick`: fewer seeds, extra overrides, fewer grid values
//! seeds = 2
//! set = ["max_steps=600"]
//! grid = { "robots.count" = [3] }
//! [[plot]]                        # a field against a grid key, a line per value of `series`
//! name = "traffic"
//! title = "Total traffic"
//! x = "robots.count"
//! y = "bytes_wire_total"
//! series = "exchange.mode"
//! log_y = true
//! [[timeline]]                    # per step: link load and backlog of each point's first seed
//! name = "load"
//! title = "Channel load"
//! series = "exchange.mode"
//! [[curve]]                       # per step: a metrics.csv column, mean over seeds
//! name = "team"
//! title = "Known by the team"
//! column = "team_pct"             # any metrics.csv column
//! rows = "first"                  # robots (mean) | base | max | first (lowest robot id)
//! y_label = "% of the environment"
//! series = "exchange.mode"
//! max_step = 1500                 # optional: the x axis ends here
//! [[table]]                       # fields' means in rows of grid keys
//! title = "Shares"
//! rows = ["robots.count"]
//! average_over = ["exchange.mode"]
//! columns = ["traffic_shares_pct.vertex"]
//! ```

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use anyhow::{bail, Context};
use serde::Deserialize;

use crate::run::progress::Progress;
use crate::rundir::summary::finished;
use crate::sweep::curve::CurveSpec;
use crate::sweep::report::{PlotSpec, Spec, TableSpec, TimelineSpec};
use crate::sweep::results::{check_field, points, Point, Results, Run, FIELDS};
use crate::sweep::slurm;
use world_server::scenario::resolve;

/// `swarm sweep` flags.
#[derive(clap::Args, Debug)]
pub struct SweepArgs {
    /// The experiment file (TOML; see configs/experiments/).
    pub experiment: PathBuf,
    /// Output directory (default: `sweeps/<name>`, or `sweeps/<name>-quick` with --quick).
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Runs at a time (default: half the cores, at least 1; each run is several processes).
    #[arg(long)]
    pub jobs: Option<usize>,
    /// Seeds per grid point (overrides the file).
    #[arg(long)]
    pub seeds: Option<u32>,
    /// The experiment's quick variant (its `[quick]` table): fewer seeds and points, smaller runs.
    #[arg(long)]
    pub quick: bool,
    /// Only the grid points where KEY is VALUE, e.g. --only robots.count=8 (repeatable; several
    /// values of one key are all kept). The runs go to the same directory as the whole grid's.
    #[arg(long, value_name = "KEY=VALUE")]
    pub only: Vec<String>,
    /// A scenario override for every run, after the file's `set` and before the grid point's
    /// values, e.g. --set exchange.edge_bounds=true (repeatable). It is part of the sweep's
    /// identity: give it its own --out.
    #[arg(long, value_name = "KEY=VALUE")]
    pub set: Vec<String>,
    /// Submit the runs to Slurm as one job array, a task per run, instead of running them
    /// here; wait for it, then write the results as a local sweep does (docs/guide/slurm.md).
    /// Resumable: finished runs, and runs still in Slurm's queue, are not submitted again.
    /// The sweep directory and the swarm binary must be on a file system every node sees;
    /// --jobs limits the tasks running at once.
    #[arg(long)]
    pub slurm: bool,
    /// With --slurm: an option for sbatch, e.g. --sbatch=--partition=short
    /// --sbatch=--time=0:30:00 (repeatable).
    #[arg(
        long,
        value_name = "OPTION",
        allow_hyphen_values = true,
        requires = "slurm"
    )]
    pub sbatch: Vec<String>,
    /// With --slurm: submit and return without waiting; --collect writes the results later.
    #[arg(long, requires = "slurm")]
    pub no_wait: bool,
    /// Write the results of the runs already in the sweep directory, running none (after
    /// --slurm --no-wait, or to see a partial sweep); runs not there are counted as failed.
    #[arg(long, conflicts_with = "slurm")]
    pub collect: bool,
}

/// Keeps only the values `only` names (`KEY=VALUE`, as the grid's values are written) of their
/// grid keys.
fn restrict(grid: &mut BTreeMap<String, Vec<String>>, only: &[String]) -> anyhow::Result<()> {
    let mut wanted: BTreeMap<&str, Vec<&str>> = BTreeMap::new();
    for o in only {
        let Some((k, v)) = o.split_once('=') else {
            bail!("--only {o:?}: expected KEY=VALUE");
        };
        wanted.entry(k.trim()).or_default().push(v.trim());
    }
    for (k, vs) in wanted {
        let Some(values) = grid.get_mut(k) else {
            let keys: Vec<&String> = grid.keys().collect();
            bail!("--only {k}: not a grid key (the grid has {keys:?})");
        };
        let kept: Vec<String> = values
            .iter()
            .filter(|x| vs.contains(&x.as_str()))
            .cloned()
            .collect();
        if kept.len() != vs.len() {
            bail!("--only {k}: {vs:?} are not all among the grid's values {values:?}");
        }
        *values = kept;
    }
    Ok(())
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct Experiment {
    name: String,
    scenario: Option<PathBuf>,
    #[serde(default = "one")]
    seeds: u32,
    #[serde(default)]
    set: Vec<String>,
    #[serde(default)]
    grid: BTreeMap<String, Vec<toml::Value>>,
    /// Extra overrides for the grid points where `KEY=VALUE` (e.g. a generated world's size
    /// that goes with its kind).
    #[serde(default)]
    with: BTreeMap<String, Vec<String>>,
    /// Summary fields (dotted paths) reported besides the standard ones.
    #[serde(default)]
    fields: Vec<String>,
    #[serde(default)]
    quick: Option<Quick>,
    #[serde(default)]
    plot: Vec<PlotSpec>,
    #[serde(default)]
    timeline: Vec<TimelineSpec>,
    #[serde(default)]
    curve: Vec<CurveSpec>,
    #[serde(default)]
    table: Vec<TableSpec>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct Quick {
    seeds: Option<u32>,
    #[serde(default)]
    set: Vec<String>,
    /// Grid keys whose values the quick variant replaces.
    #[serde(default)]
    grid: BTreeMap<String, Vec<toml::Value>>,
}

fn one() -> u32 {
    1
}

/// A TOML value as an override's right-hand side.
fn value_text(v: &toml::Value) -> String {
    match v {
        toml::Value::String(s) => s.clone(),
        other => other.to_string(),
    }
}

/// What every run of a sweep directory shares; a directory that holds runs of other settings
/// is refused rather than mixed into one table.
#[derive(Debug, PartialEq, serde::Serialize, Deserialize)]
struct Identity {
    name: String,
    scenario: Option<PathBuf>,
    set: Vec<String>,
    #[serde(default, skip_serializing_if = "BTreeMap::is_empty")]
    with: BTreeMap<String, Vec<String>>,
}

fn check_identity(out: &Path, id: &Identity) -> anyhow::Result<()> {
    let file = out.join("sweep.json");
    if let Ok(text) = std::fs::read_to_string(&file) {
        let old: Identity = serde_json::from_str(&text)
            .with_context(|| format!("{} is not a sweep record", file.display()))?;
        if &old != id {
            bail!(
                "{} holds runs of other settings ({:?}, set {:?}); choose another --out",
                out.display(),
                old.name,
                old.set
            );
        }
        return Ok(());
    }
    std::fs::write(&file, serde_json::to_string_pretty(id)?)
        .with_context(|| format!("writing {}", file.display()))
}

/// A drawn progress bar with the ETA and the last finished run.
struct Bar {
    total: usize,
    started: Instant,
}

impl Bar {
    fn line(&self, done: usize, failed: usize, note: &str) -> String {
        const WIDTH: usize = 30;
        let filled = (done * WIDTH).checked_div(self.total).unwrap_or(WIDTH);
        let eta = if done == 0 {
            "ETA -".to_string()
        } else {
            let per = self.started.elapsed().as_secs_f64() / done as f64;
            let left = (self.total - done) as f64 * per;
            format!("ETA {}", hms(left))
        };
        let failed = if failed > 0 {
            format!(", {failed} failed")
        } else {
            String::new()
        };
        format!(
            "[{}{}] {done}/{} runs, {eta}{failed}  {note}",
            "#".repeat(filled),
            ".".repeat(WIDTH - filled),
            self.total
        )
    }
}

/// Seconds as `1h02m`, `4m05s`, `12s`.
fn hms(s: f64) -> String {
    let s = s.max(0.0).round() as u64;
    match (s / 3600, s % 3600 / 60, s % 60) {
        (0, 0, s) => format!("{s}s"),
        (0, m, s) => format!("{m}m{s:02}s"),
        (h, m, _) => format!("{h}h{m:02}m"),
    }
}

/// The seeds, overrides for every run, and grid (values as override text) of an experiment, or
/// of its quick variant.
type Variant = (u32, Vec<String>, BTreeMap<String, Vec<String>>);

fn variant(exp: &Experiment, quick: bool) -> anyhow::Result<Variant> {
    let mut seeds = exp.seeds;
    let mut sets = exp.set.clone();
    let mut grid = exp.grid.clone();
    if quick {
        let Some(q) = &exp.quick else {
            bail!("no [quick] table");
        };
        seeds = q.seeds.unwrap_or(seeds);
        sets.extend(q.set.iter().cloned());
        for (k, vs) in &q.grid {
            if !grid.contains_key(k) {
                bail!("[quick] grid key {k:?} is not in [grid]");
            }
            grid.insert(k.clone(), vs.clone());
        }
    }
    let grid = grid
        .iter()
        .map(|(k, vs)| (k.clone(), vs.iter().map(value_text).collect()))
        .collect();
    Ok((seeds, sets, grid))
}

/// The overrides of grid point `p`: its values, then the `[with]` entries that match them. A
/// grid key that starts with `@` is a label, not a scenario key: it names a bundle of overrides
/// that `[with]` gives (e.g. `"@variant" = ["static", "dynamic"]` with
/// `"@variant=static" = ["coordination.roles.swap=false"]`), so that a grid can compare
/// settings that are not the values of one key.
fn point_sets(p: &Point, with: &BTreeMap<String, Vec<String>>) -> Vec<String> {
    let own: Vec<String> = p.0.iter().map(|(k, v)| format!("{k}={v}")).collect();
    let extra = own.iter().filter_map(|kv| with.get(kv)).flatten().cloned();
    own.iter()
        .filter(|kv| !kv.starts_with(LABEL))
        .cloned()
        .chain(extra)
        .collect()
}

/// The first character of a label grid key ([`point_sets`]).
const LABEL: char = '@';

/// Every `[with]` key names a grid key and one of its values.
fn check_with(
    with: &BTreeMap<String, Vec<String>>,
    grid: &BTreeMap<String, Vec<String>>,
) -> anyhow::Result<()> {
    for kv in with.keys() {
        let known = kv
            .split_once('=')
            .is_some_and(|(k, v)| grid.get(k).is_some_and(|vs| vs.iter().any(|x| x == v)));
        if !known {
            bail!("[with] key {kv:?} is not KEY=VALUE of a grid key and one of its values");
        }
    }
    Ok(())
}

/// Every point's scenario must load (keys, types, ranges) before any run starts: a typo would
/// otherwise fail every run.
fn check_points(
    scenario: Option<&Path>,
    sets: &[String],
    points: &[Point],
    with: &BTreeMap<String, Vec<String>>,
) -> anyhow::Result<()> {
    for p in points {
        let mut all = sets.to_vec();
        all.extend(point_sets(p, with));
        if let Err(e) = resolve(scenario, &all) {
            let at = if p.0.is_empty() {
                String::new()
            } else {
                format!(" at grid point {}", p.id())
            };
            bail!("the scenario{at}: {e:#}");
        }
    }
    Ok(())
}

/// Every summary field the experiment names besides the standard ones (`fields`) is a number of
/// `summary.json` (`plot.y` and `table.columns` are checked with the report's spec).
fn check_fields(fields: &[String]) -> anyhow::Result<()> {
    fields.iter().try_for_each(|f| check_field("fields", f))
}

/// A sweep made ready: the experiment read, its variant chosen and checked, the output
/// directory claimed.
struct Plan {
    exp: Experiment,
    /// The base scenario file, relative to the working directory.
    scenario: Option<PathBuf>,
    seeds: u32,
    sets: Vec<String>,
    points: Vec<Point>,
    spec: Spec,
    out: PathBuf,
}

/// One run of a sweep: its grid point (an index into the points), seed and run directory.
type Job = (usize, u32, PathBuf);

impl Plan {
    fn load(args: &SweepArgs) -> anyhow::Result<Plan> {
        let file = args.experiment.display();
        let text =
            std::fs::read_to_string(&args.experiment).with_context(|| format!("reading {file}"))?;
        let exp: Experiment =
            toml::from_str(&text).with_context(|| format!("experiment {file}"))?;
        let base_dir = args.experiment.parent().unwrap_or(Path::new("."));
        let scenario = exp.scenario.as_ref().map(|s| base_dir.join(s));
        let (seeds, mut sets, mut grid) =
            variant(&exp, args.quick).with_context(|| format!("experiment {file}"))?;
        sets.extend(args.set.iter().cloned());
        restrict(&mut grid, &args.only)?;
        let spec = Spec {
            name: exp.name.clone(),
            command: std::env::args().collect::<Vec<_>>().join(" "),
            plots: exp.plot.clone(),
            timelines: exp.timeline.clone(),
            curves: exp.curve.clone(),
            tables: exp.table.clone(),
        };
        check_fields(&exp.fields).with_context(|| format!("experiment {file}"))?;
        crate::sweep::report::check(&spec, &grid.keys().cloned().collect::<Vec<_>>())
            .with_context(|| format!("experiment {file}"))?;
        let full: BTreeMap<String, Vec<String>> = (exp.grid.iter())
            .map(|(k, vs)| (k.clone(), vs.iter().map(value_text).collect()))
            .collect();
        check_with(&exp.with, &full).with_context(|| format!("experiment {file}"))?;
        let points = points(&grid);
        check_points(scenario.as_deref(), &sets, &points, &exp.with)?;
        let out = args.out.clone().unwrap_or_else(|| {
            let quick = if args.quick { "-quick" } else { "" };
            PathBuf::from("sweeps").join(format!("{}{quick}", exp.name))
        });
        std::fs::create_dir_all(out.join("runs")).context("creating the sweep directory")?;
        let id = Identity {
            name: exp.name.clone(),
            scenario: scenario.clone(),
            set: sets.clone(),
            with: exp.with.clone(),
        };
        check_identity(&out, &id)?;
        Ok(Plan {
            seeds: args.seeds.unwrap_or(seeds).max(1),
            exp,
            scenario,
            sets,
            points,
            spec,
            out,
        })
    }

    /// Every run: each point × each seed.
    fn jobs(&self) -> Vec<Job> {
        let mut jobs = Vec::new();
        for (i, p) in self.points.iter().enumerate() {
            for seed in 1..=self.seeds {
                let dir = self.out.join("runs").join(format!("{}-seed{seed}", p.id()));
                jobs.push((i, seed, dir));
            }
        }
        jobs
    }

    /// The words after the binary that run one job: `run --quiet --out DIR --set …`.
    fn run_argv(&self, (point, seed, dir): &Job) -> Vec<String> {
        let set = (self.sets.iter().cloned())
            .chain(point_sets(&self.points[*point], &self.exp.with))
            .chain([format!("seed={seed}")])
            .collect();
        let args = crate::run::RunArgs {
            scenario: self.scenario.clone(),
            out: Some(dir.clone()),
            set,
            quiet: true,
            hosts: None,
            view: None,
            foxglove: None,
        };
        std::iter::once("run".to_string())
            .chain(args.to_argv())
            .collect()
    }

    /// `swarm run` of one job, its output thrown away (the run directory has it all).
    fn command(&self, exe: &Path, job: &Job) -> Command {
        let mut cmd = Command::new(exe);
        cmd.args(self.run_argv(job));
        cmd.stdout(Stdio::null()).stderr(Stdio::null());
        // Killing the sweep kills its runs; each run takes its own processes with it.
        crate::process::children::die_with_parent_std(&mut cmd);
        cmd
    }

    /// Runs the jobs not finished yet, `parallel` at a time, showing progress.
    fn run(&self, jobs: &[Job], parallel: usize) -> anyhow::Result<()> {
        let exe = std::env::current_exe().context("finding the swarm binary")?;
        let todo: Vec<&Job> = jobs.iter().filter(|(_, _, dir)| !finished(dir)).collect();
        eprintln!(
            "swarm sweep {}: {} points × {} seeds = {} runs, {} already done, {parallel} at a time; output {}",
            self.exp.name,
            self.points.len(),
            self.seeds,
            jobs.len(),
            jobs.len() - todo.len(),
            self.out.display()
        );
        let bar = Bar {
            total: todo.len(),
            started: Instant::now(),
        };
        let mut progress = Progress::every_state();
        let mut running: Vec<(Child, &Job)> = Vec::new();
        let mut queue = todo.iter().copied();
        let (mut done, mut failed) = (0usize, 0usize);
        loop {
            while running.len() < parallel {
                let Some(job) = queue.next() else { break };
                let _ = std::fs::remove_dir_all(&job.2);
                let child = self
                    .command(&exe, job)
                    .spawn()
                    .context("starting swarm run")?;
                running.push((child, job));
            }
            if running.is_empty() {
                return Ok(());
            }
            std::thread::sleep(Duration::from_millis(200));
            let mut i = 0;
            while i < running.len() {
                if running[i].0.try_wait().ok().flatten().is_none() {
                    i += 1;
                    continue;
                }
                let (_, (point, seed, dir)) = running.swap_remove(i);
                done += 1;
                let ok = finished(dir);
                failed += usize::from(!ok);
                let fail = if ok { "" } else { " FAILED" };
                let note = format!("{} seed {seed}{fail}", self.points[*point].id());
                progress.show(&bar.line(done, failed, &note));
                if done == bar.total {
                    progress.finish();
                }
            }
        }
    }

    /// Submits the jobs not finished to Slurm as a job array and, unless `--no-wait`, waits
    /// for it ([`slurm::submit`]); whether it waited.
    fn submit(&self, jobs: &[Job], args: &SweepArgs) -> anyhow::Result<bool> {
        let todo = (jobs.iter())
            .filter(|(_, _, dir)| !finished(dir))
            .map(|job| slurm::Task {
                label: format!("{} seed {}", self.points[job.0].id(), job.1),
                dir: job.2.clone(),
                argv: self.run_argv(job),
            })
            .collect();
        let opts = slurm::Options {
            name: &self.exp.name,
            out: &self.out,
            sbatch: &args.sbatch,
            at_once: args.jobs,
            wait: !args.no_wait,
        };
        slurm::submit(&opts, todo)
    }

    /// `runs.csv`, `results.csv`, the plots and `report.md`.
    fn write_results(self, jobs: Vec<Job>) -> anyhow::Result<PathBuf> {
        let mut fields: Vec<String> = FIELDS.iter().map(|f| f.to_string()).collect();
        for f in &self.exp.fields {
            if !fields.contains(f) {
                fields.push(f.clone());
            }
        }
        let results = Results {
            points: self.points,
            fields,
            runs: jobs
                .into_iter()
                .map(|(point, seed, dir)| Run::load(point, seed, dir))
                .collect::<anyhow::Result<_>>()?,
        };
        results.write_tables(&self.out)?;
        crate::sweep::report::write(&results, &self.spec, &self.out)?;
        Ok(self.out)
    }
}

/// Runs a sweep (here, or on Slurm); returns the output directory once its results are
/// written (`None`: submitted to Slurm without waiting).
pub fn sweep(args: &SweepArgs) -> anyhow::Result<Option<PathBuf>> {
    let plan = Plan::load(args)?;
    let jobs = plan.jobs();
    if args.collect {
        let missing = jobs.iter().filter(|(_, _, dir)| !finished(dir)).count();
        eprintln!(
            "swarm sweep {}: collecting {} runs, {missing} of them not finished",
            plan.exp.name,
            jobs.len()
        );
    } else if args.slurm {
        if !plan.submit(&jobs, args)? {
            return Ok(None);
        }
    } else {
        let parallel = args.jobs.unwrap_or_else(|| {
            std::thread::available_parallelism().map_or(1, |n| (n.get() / 2).max(1))
        });
        plan.run(&jobs, parallel)?;
    }
    plan.write_results(jobs).map(Some)
}

/// `swarm sweep`: runs the experiment and says where it is written.
pub fn command(args: &SweepArgs) -> anyhow::Result<std::process::ExitCode> {
    if let Some(dir) = sweep(args)? {
        println!("sweep written to {}", dir.display());
    }
    Ok(std::process::ExitCode::SUCCESS)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn only_keeps_the_named_values_and_refuses_what_the_grid_lacks() {
        let mut grid: BTreeMap<String, Vec<String>> = [
            (
                "robots.count".to_string(),
                vec!["3".to_string(), "8".to_string()],
            ),
            ("seedless".to_string(), vec!["a".to_string()]),
        ]
        .into();
        restrict(&mut grid, &["robots.count=8".into()]).expect("8 is a value");
        assert_eq!(grid["robots.count"], ["8"]);
        assert_eq!(grid["seedless"], ["a"]);
        for bad in ["robots.count=5", "nope=1", "robots.count"] {
            let mut g = grid.clone();
            let e = restrict(&mut g, &[bad.into()])
                .expect_err("refused")
                .to_string();
            assert!(e.contains("--only"), "{bad}: {e}");
        }
    }

    #[test]
    fn the_shipped_experiments_and_their_quick_variants_are_valid() {
        let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("configs/experiments");
        let mut n = 0;
        for e in std::fs::read_dir(&dir).into_iter().flatten().flatten() {
            let text = std::fs::read_to_string(e.path()).unwrap_or_default();
            let exp: Experiment =
                toml::from_str(&text).unwrap_or_else(|err| panic!("{}: {err}", e.path().display()));
            for quick in [false, true] {
                let (_, sets, grid) = variant(&exp, quick)
                    .unwrap_or_else(|err| panic!("{}: {err}", e.path().display()));
                let spec = Spec {
                    plots: exp.plot.clone(),
                    timelines: exp.timeline.clone(),
                    curves: exp.curve.clone(),
                    tables: exp.table.clone(),
                    ..Spec::default()
                };
                let keys: Vec<String> = grid.keys().cloned().collect();
                check_fields(&exp.fields)
                    .and_then(|()| crate::sweep::report::check(&spec, &keys))
                    .and_then(|()| check_points(None, &sets, &points(&grid), &exp.with))
                    .unwrap_or_else(|err| panic!("{} (quick {quick}): {err}", e.path().display()));
            }
            n += 1;
        }
        assert!(n >= 6, "{n} experiment files");
    }

    #[test]
    fn a_field_the_summary_does_not_have_is_refused_when_the_experiment_loads() {
        let dir = std::env::temp_dir().join(format!("swarm-sweep-fields-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap_or_else(|e| panic!("{e}"));
        let load = |body: &str| {
            let file = dir.join("x.toml");
            std::fs::write(&file, format!("name = \"x\"\n{body}"))
                .unwrap_or_else(|e| panic!("{e}"));
            let args = SweepArgs {
                experiment: file,
                out: Some(dir.join("out")),
                jobs: None,
                seeds: None,
                quick: false,
                only: Vec::new(),
                set: Vec::new(),
                slurm: false,
                sbatch: Vec::new(),
                no_wait: false,
                collect: false,
            };
            Plan::load(&args).map(|_| ()).map_err(|e| format!("{e:#}"))
        };
        let ok = load("fields = [\"traffic_shares_pct.vertex\", \"coverage_steps.90\"]\n");
        let field = load("fields = [\"traffic_share_pct.vertex\"]\n");
        let y = load(
            "[grid]\n\"robots.count\" = [2]\n[[plot]]\nname = \"p\"\ntitle = \"P\"\n\
             x = \"robots.count\"\ny = \"exploration_step\"\n",
        );
        let column = load(
            "[grid]\n\"robots.count\" = [2]\n[[table]]\ntitle = \"T\"\n\
             rows = [\"robots.count\"]\ncolumns = [\"awareness.team_pct\"]\n",
        );
        let _ = std::fs::remove_dir_all(&dir);
        assert!(ok.is_ok(), "{ok:?}");
        for (r, what, name) in [
            (field, "fields", "traffic_share_pct.vertex"),
            (y, "plot.y", "exploration_step"),
            (column, "table.columns", "awareness.team_pct"),
        ] {
            let e = r.expect_err(name);
            assert!(
                e.contains("x.toml")
                    && e.contains(what)
                    && e.contains(&format!("{name:?}"))
                    && e.contains("awareness.team_pct_mean")
                    && e.contains("wall_seconds"),
                "{name}: {e}"
            );
        }
    }

    #[test]
    fn set_overrides_follow_the_files_and_are_checked_before_any_run() {
        let dir = std::env::temp_dir().join(format!("swarm-sweep-set-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap_or_else(|e| panic!("{e}"));
        let file = dir.join("x.toml");
        std::fs::write(&file, "name = \"x\"\nset = [\"robots.count=2\"]\n")
            .unwrap_or_else(|e| panic!("{e}"));
        let load = |set: &str| {
            let args = SweepArgs {
                experiment: file.clone(),
                out: Some(dir.join("out")),
                jobs: None,
                seeds: None,
                quick: false,
                only: Vec::new(),
                set: vec![set.into()],
                slurm: false,
                sbatch: Vec::new(),
                no_wait: false,
                collect: false,
            };
            Plan::load(&args)
                .map(|p| p.sets)
                .map_err(|e| format!("{e:#}"))
        };
        let ok = load("exchange.edge_bounds=false");
        let typo = load("exchange.edge_bound=false");
        let _ = std::fs::remove_dir_all(&dir);
        assert_eq!(
            ok,
            Ok(vec![
                "robots.count=2".to_string(),
                "exchange.edge_bounds=false".to_string()
            ])
        );
        assert!(typo.is_err_and(|e| e.contains("exchange.edge_bound")));
    }

    #[test]
    fn a_typo_in_an_override_is_found_before_any_run() {
        let p = Point(vec![("robots.cont".into(), "3".into())]);
        let err = check_points(None, &[], &[p], &BTreeMap::new()).map_err(|e| e.to_string());
        assert!(err.is_err_and(|e| e.contains("robots.cont") && e.contains("grid point")));
    }

    #[test]
    fn with_adds_overrides_where_its_value_is_and_names_only_grid_values() {
        let with: BTreeMap<String, Vec<String>> = [(
            "world.map=empty".to_string(),
            vec!["world.width_m=20".to_string()],
        )]
        .into();
        let at = |map: &str| Point(vec![("world.map".into(), map.into())]);
        assert_eq!(
            point_sets(&at("empty"), &with),
            ["world.map=empty", "world.width_m=20"]
        );
        assert_eq!(point_sets(&at("corridor"), &with), ["world.map=corridor"]);
        let grid: BTreeMap<String, Vec<String>> = [(
            "world.map".to_string(),
            vec!["empty".to_string(), "corridor".to_string()],
        )]
        .into();
        assert!(check_with(&with, &grid).is_ok());
        let typo: BTreeMap<String, Vec<String>> = [("world.map=emtpy".to_string(), vec![])].into();
        assert!(check_with(&typo, &grid).is_err());
        let bad = [(
            "world.map=empty".to_string(),
            vec!["world.widht_m=20".to_string()],
        )]
        .into();
        let err = check_points(None, &[], &[at("empty")], &bad).map_err(|e| e.to_string());
        assert!(err.is_err_and(|e| e.contains("world.widht_m")));
    }

    #[test]
    fn a_label_key_brings_only_its_with_overrides() {
        let with: BTreeMap<String, Vec<String>> = [
            (
                "@variant=static".to_string(),
                vec![
                    "coordination.strategy=roles".to_string(),
                    "coordination.roles.swap=false".to_string(),
                    "base_station.enabled=true".to_string(),
                ],
            ),
            (
                "@variant=greedy".to_string(),
                vec!["coordination.strategy=burgard".to_string()],
            ),
        ]
        .into();
        let at = |v: &str| {
            Point(vec![
                ("@variant".into(), v.into()),
                ("robots.count".into(), "10".into()),
            ])
        };
        assert_eq!(
            point_sets(&at("static"), &with),
            [
                "robots.count=10",
                "coordination.strategy=roles",
                "coordination.roles.swap=false",
                "base_station.enabled=true"
            ]
        );
        assert_eq!(
            point_sets(&at("greedy"), &with),
            ["robots.count=10", "coordination.strategy=burgard"]
        );
        let ok = check_points(None, &[], &[at("static"), at("greedy")], &with);
        assert!(ok.is_ok(), "{ok:?}");
    }

    #[test]
    fn durations_read_short() {
        assert_eq!(hms(12.4), "12s");
        assert_eq!(hms(245.0), "4m05s");
        assert_eq!(hms(3_720.0), "1h02m");
        assert_eq!(hms(-3.0), "0s");
    }
}
