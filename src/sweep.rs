//! `swarm sweep`: a grid of scenario overrides × seeds, run as separate `swarm run` processes,
//! a few at a time; resumable (a run whose `summary.json` exists is not run again) and robust (a
//! failed run is recorded and the sweep goes on). Writes `runs.csv` (one row per run) and
//! `results.csv` (per grid point: mean, standard deviation and 95 % interval of the main
//! summary fields).
//!
//! An experiment file (TOML):
//!
//! ```toml
//! name = "e3-traffic"
//! scenario = "../default.toml"   # optional base scenario, relative to this file
//! seeds = 5                       # seeds 1..=seeds per grid point
//! set = ["radio.bandwidth_bytes_per_s=0"]          # overrides for every run
//! [grid]                          # every combination of these values is one grid point
//! "exchange.mode" = ["raw-scans", "polygon"]
//! "robots.count" = [3, 8]
//! [quick]                         # `--quick`: fewer seeds, extra overrides
//! seeds = 2
//! set = ["max_steps=600"]
//! ```

use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use anyhow::{bail, Context};
use serde::Deserialize;

/// `swarm sweep` flags.
#[derive(clap::Args, Debug)]
pub struct SweepArgs {
    /// The experiment file (TOML; see configs/experiments/).
    pub experiment: PathBuf,
    /// Output directory (default: sweeps/<name>).
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Runs at a time (default: half the cores, at least 1; each run is several processes).
    #[arg(long)]
    pub jobs: Option<usize>,
    /// Seeds per grid point (overrides the file).
    #[arg(long)]
    pub seeds: Option<u32>,
    /// The experiment's quick variant (its [quick] table).
    #[arg(long)]
    pub quick: bool,
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
    #[serde(default)]
    quick: Option<Quick>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct Quick {
    seeds: Option<u32>,
    #[serde(default)]
    set: Vec<String>,
}

fn one() -> u32 {
    1
}

/// One grid point: its overrides, as `KEY=VALUE`.
#[derive(Clone, Debug, PartialEq)]
pub struct Point(pub Vec<(String, String)>);

impl Point {
    /// A directory-safe id, e.g. `exchange.mode=polygon,robots.count=3`.
    fn id(&self) -> String {
        let s: Vec<String> = self.0.iter().map(|(k, v)| format!("{k}={v}")).collect();
        let s = s.join(",");
        s.chars()
            .map(|c| {
                if c.is_ascii_alphanumeric() || "=.,-_".contains(c) {
                    c
                } else {
                    '_'
                }
            })
            .collect()
    }
}

/// Every combination of the grid's values, in key order (the last key varies fastest).
pub fn points(grid: &BTreeMap<String, Vec<String>>) -> Vec<Point> {
    let mut out = vec![Point(Vec::new())];
    for (k, values) in grid {
        out = out
            .into_iter()
            .flat_map(|p| {
                values.iter().map(move |v| {
                    let mut q = p.0.clone();
                    q.push((k.clone(), v.clone()));
                    Point(q)
                })
            })
            .collect();
    }
    out
}

/// A TOML value as an override's right-hand side.
fn value_text(v: &toml::Value) -> String {
    match v {
        toml::Value::String(s) => s.clone(),
        other => other.to_string(),
    }
}

/// Mean, sample standard deviation and the half-width of the 95 % t-interval.
pub fn stats(xs: &[f64]) -> Option<(f64, f64, f64)> {
    let n = xs.len();
    if n == 0 {
        return None;
    }
    let mean = xs.iter().sum::<f64>() / n as f64;
    if n == 1 {
        return Some((mean, 0.0, 0.0));
    }
    let var = xs.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / (n - 1) as f64;
    let sd = var.sqrt();
    Some((mean, sd, t95(n - 1) * sd / (n as f64).sqrt()))
}

/// Two-sided 95 % quantile of Student's t with `df` degrees of freedom.
fn t95(df: usize) -> f64 {
    const T: [f64; 30] = [
        12.706, 4.303, 3.182, 2.776, 2.571, 2.447, 2.365, 2.306, 2.262, 2.228, 2.201, 2.179, 2.160,
        2.145, 2.131, 2.120, 2.110, 2.101, 2.093, 2.086, 2.080, 2.074, 2.069, 2.064, 2.060, 2.056,
        2.052, 2.048, 2.045, 2.042,
    ];
    T.get(df.saturating_sub(1)).copied().unwrap_or(1.96)
}

/// The summary fields a sweep reports per run and aggregates per point.
const FIELDS: [&str; 6] = [
    "exploration_steps",
    "steps",
    "bytes_wire_total",
    "bytes_payload_total",
    "approx_error_avg",
    "wall_seconds",
];

/// One run of the sweep.
struct Job {
    point: usize,
    seed: u32,
    dir: PathBuf,
}

/// Runs a sweep; returns the output directory.
pub fn sweep(args: &SweepArgs) -> anyhow::Result<PathBuf> {
    let text = std::fs::read_to_string(&args.experiment)
        .with_context(|| format!("reading {}", args.experiment.display()))?;
    let exp: Experiment = toml::from_str(&text)
        .with_context(|| format!("experiment {}", args.experiment.display()))?;
    let base_dir = args.experiment.parent().unwrap_or(Path::new("."));
    let scenario = exp.scenario.as_ref().map(|s| base_dir.join(s));
    let mut seeds = exp.seeds;
    let mut sets = exp.set.clone();
    if args.quick {
        let Some(q) = &exp.quick else {
            bail!("{} has no [quick] table", args.experiment.display());
        };
        seeds = q.seeds.unwrap_or(seeds);
        sets.extend(q.set.iter().cloned());
    }
    seeds = args.seeds.unwrap_or(seeds).max(1);
    let grid: BTreeMap<String, Vec<String>> = exp
        .grid
        .iter()
        .map(|(k, vs)| (k.clone(), vs.iter().map(value_text).collect()))
        .collect();
    let points = points(&grid);
    let out = args
        .out
        .clone()
        .unwrap_or_else(|| PathBuf::from("sweeps").join(&exp.name));
    std::fs::create_dir_all(out.join("runs")).context("creating the sweep directory")?;
    let jobs: Vec<Job> = points
        .iter()
        .enumerate()
        .flat_map(|(i, p)| {
            let out = &out;
            (1..=seeds).map(move |seed| Job {
                point: i,
                seed,
                dir: out.join("runs").join(format!("{}-seed{seed}", p.id())),
            })
        })
        .collect();
    let parallel = args.jobs.unwrap_or_else(|| {
        std::thread::available_parallelism().map_or(1, |n| (n.get() / 2).max(1))
    });
    let exe = std::env::current_exe().context("finding the swarm binary")?;
    let todo: Vec<&Job> = jobs
        .iter()
        .filter(|j| !j.dir.join("summary.json").exists())
        .collect();
    eprintln!(
        "swarm sweep {}: {} points × {seeds} seeds = {} runs, {} already done, {parallel} at a time; output {}",
        exp.name,
        points.len(),
        jobs.len(),
        jobs.len() - todo.len(),
        out.display()
    );
    let started = Instant::now();
    let mut running: Vec<(Child, &Job)> = Vec::new();
    let mut queue = todo.iter().copied();
    let mut done = 0usize;
    loop {
        while running.len() < parallel {
            let Some(job) = queue.next() else { break };
            let _ = std::fs::remove_dir_all(&job.dir);
            let mut cmd = Command::new(&exe);
            cmd.arg("run").arg("--quiet").arg("--out").arg(&job.dir);
            if let Some(s) = &scenario {
                cmd.arg(s);
            }
            for s in sets
                .iter()
                .cloned()
                .chain(points[job.point].0.iter().map(|(k, v)| format!("{k}={v}")))
            {
                cmd.arg("--set").arg(s);
            }
            cmd.arg("--set").arg(format!("seed={}", job.seed));
            cmd.stdout(Stdio::null()).stderr(Stdio::null());
            let child = cmd.spawn().context("starting swarm run")?;
            running.push((child, job));
        }
        if running.is_empty() {
            break;
        }
        std::thread::sleep(Duration::from_millis(200));
        let mut i = 0;
        while i < running.len() {
            if running[i].0.try_wait().ok().flatten().is_some() {
                running.swap_remove(i);
                done += 1;
                let per = started.elapsed().as_secs_f64() / done as f64;
                let left = (todo.len() - done) as f64 * per / parallel as f64;
                eprintln!("[{done}/{}] ETA {:.0} s", todo.len(), left);
            } else {
                i += 1;
            }
        }
    }
    write_tables(&out, &points, &jobs)?;
    Ok(out)
}

/// `runs.csv` and `results.csv` from the run directories.
fn write_tables(out: &Path, points: &[Point], jobs: &[Job]) -> anyhow::Result<()> {
    let keys: Vec<String> = points
        .first()
        .map(|p| p.0.iter().map(|(k, _)| k.clone()).collect())
        .unwrap_or_default();
    let mut runs = keys.join(",");
    if !runs.is_empty() {
        runs.push(',');
    }
    runs.push_str("seed,status,complete,exit_reason");
    for f in FIELDS {
        runs.push(',');
        runs.push_str(f);
    }
    runs.push('\n');
    let mut per_point: Vec<BTreeMap<&str, Vec<f64>>> = vec![BTreeMap::new(); points.len()];
    let mut complete = vec![0usize; points.len()];
    let mut count = vec![0usize; points.len()];
    for j in jobs {
        let p = &points[j.point];
        for (_, v) in &p.0 {
            runs.push_str(v);
            runs.push(',');
        }
        count[j.point] += 1;
        let summary = std::fs::read_to_string(j.dir.join("summary.json"))
            .ok()
            .and_then(|t| serde_json::from_str::<serde_json::Value>(&t).ok());
        let Some(s) = summary else {
            let _ = writeln!(runs, "{},failed,,{}", j.seed, ",".repeat(FIELDS.len()));
            continue;
        };
        let is_complete = s["complete"].as_bool() == Some(true);
        complete[j.point] += usize::from(is_complete);
        let _ = write!(
            runs,
            "{},ok,{},{}",
            j.seed,
            is_complete,
            s["exit_reason"].as_str().unwrap_or("")
        );
        for f in FIELDS {
            let v = s[f].as_f64();
            runs.push(',');
            if let Some(v) = v {
                let _ = write!(runs, "{v}");
                if is_complete || f != "exploration_steps" {
                    per_point[j.point].entry(f).or_default().push(v);
                }
            }
        }
        runs.push('\n');
    }
    std::fs::write(out.join("runs.csv"), runs).context("writing runs.csv")?;
    let mut res = keys.join(",");
    if !res.is_empty() {
        res.push(',');
    }
    res.push_str("runs,complete");
    for f in FIELDS {
        let _ = write!(res, ",{f}_mean,{f}_std,{f}_ci95");
    }
    res.push('\n');
    for (i, p) in points.iter().enumerate() {
        for (_, v) in &p.0 {
            res.push_str(v);
            res.push(',');
        }
        let _ = write!(res, "{},{}", count[i], complete[i]);
        for f in FIELDS {
            match per_point[i].get(f).and_then(|xs| stats(xs)) {
                Some((m, sd, h)) => {
                    let _ = write!(res, ",{m},{sd},{h}");
                }
                None => res.push_str(",,,"),
            }
        }
        res.push('\n');
    }
    std::fs::write(out.join("results.csv"), res).context("writing results.csv")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_grid_is_every_combination() {
        let g = BTreeMap::from([
            ("a".to_string(), vec!["1".to_string(), "2".to_string()]),
            (
                "b".to_string(),
                vec!["x".to_string(), "y".to_string(), "z".to_string()],
            ),
        ]);
        let p = points(&g);
        assert_eq!(p.len(), 6);
        assert_eq!(p[0].id(), "a=1,b=x");
        assert_eq!(p[5].id(), "a=2,b=z");
        assert_eq!(points(&BTreeMap::new()), vec![Point(Vec::new())]);
    }

    #[test]
    fn stats_give_the_t_interval() {
        let (m, sd, h) = stats(&[1.0, 2.0, 3.0]).unwrap_or_default();
        assert!((m - 2.0).abs() < 1e-12 && (sd - 1.0).abs() < 1e-12);
        assert!((h - 4.303 / 3f64.sqrt()).abs() < 1e-9);
        assert_eq!(stats(&[]), None);
        assert_eq!(stats(&[5.0]), Some((5.0, 0.0, 0.0)));
    }
}
