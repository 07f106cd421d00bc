//! A sweep's results: each run's summary fields, and per grid point their mean, standard
//! deviation and 95 % interval. Writes `runs.csv` (one row per run) and `results.csv` (one row
//! per grid point).

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use anyhow::Context;

use crate::rundir::summary::{read_summary, Summary};

/// The summary fields every sweep reports per run and aggregates per point. The `awareness`
/// ones (de Hoog et al. 2010, Fig. 5) are empty in runs without a base station,
/// `link_judgement` in runs of strategies other than `pack`, `channel` in runs whose channel is
/// neither shared nor lossy.
pub const FIELDS: [&str; 22] = [
    "exploration_steps",
    "steps",
    "bytes_wire_total",
    "bytes_payload_total",
    "approx_error_avg",
    "backlog_max_bytes",
    "wall_seconds",
    "awareness.base_known_pct",
    "awareness.base_known_pct_mean",
    "awareness.shared_pct_mean",
    "awareness.steps_since_base_mean",
    "awareness.steps_since_base_max",
    "awareness.team_pct_mean",
    "comm_level_pct.min",
    "comm_level_pct.mean",
    "link_judgement.wrong_pct",
    "fidelity.false_free_pct_median",
    "fidelity.on_walls_pct_median",
    "collisions_walls",
    "collisions_robots",
    "channel.utilisation_mean",
    "channel.frames_lost_pct",
];

/// One grid point: its overrides, as `KEY=VALUE`, in key order.
#[derive(Clone, Debug, PartialEq)]
pub struct Point(pub Vec<(String, String)>);

impl Point {
    /// A directory-safe id, e.g. `exchange.mode=polygon,robots.count=3`.
    pub fn id(&self) -> String {
        let s: Vec<String> = self.0.iter().map(|(k, v)| format!("{k}={v}")).collect();
        s.join(",")
            .chars()
            .map(|c| {
                if c.is_ascii_alphanumeric() || "=.,-_".contains(c) {
                    c
                } else {
                    '_'
                }
            })
            .collect()
    }

    /// The value of one grid key at this point.
    pub fn get(&self, key: &str) -> Option<&str> {
        self.0
            .iter()
            .find(|(k, _)| k == key)
            .map(|(_, v)| v.as_str())
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

/// A summary field by dotted path (`traffic_shares_pct.vertex`), as a number: a path lookup in
/// the JSON form of the typed [`Summary`] (`null` and what is not there are `None`; which paths
/// there are is checked when the experiment is loaded, [`check_field`]).
pub fn field(summary: &serde_json::Value, path: &str) -> Option<f64> {
    path.split('.')
        .try_fold(summary, |v, k| v.get(k))
        .and_then(serde_json::Value::as_f64)
}

/// `path`, named by an experiment file as `what` (`fields`, `plot.y`, `table.columns`), is a
/// number of `summary.json`; else an error naming it and listing the fields there are.
pub fn check_field(what: &str, path: &str) -> anyhow::Result<()> {
    crate::rundir::summary::check_number_path(path).with_context(|| what.to_string())
}

/// One run of a sweep: where it is, and its summary once it has finished.
pub struct Run {
    pub point: usize,
    pub seed: u32,
    pub dir: PathBuf,
    summary: Option<Summary>,
    /// `summary` as JSON, for [`field`].
    json: Option<serde_json::Value>,
}

impl Run {
    /// A run and its summary (`None`: it failed).
    pub fn new(point: usize, seed: u32, dir: PathBuf, summary: Option<Summary>) -> Run {
        let json = summary.as_ref().and_then(|s| serde_json::to_value(s).ok());
        Run {
            point,
            seed,
            dir,
            summary,
            json,
        }
    }

    /// The run in `dir`: without a `summary.json` it failed; one that does not read is an error.
    pub fn load(point: usize, seed: u32, dir: PathBuf) -> anyhow::Result<Run> {
        let summary = if dir.join("summary.json").exists() {
            Some(read_summary(&dir)?)
        } else {
            None
        };
        Ok(Run::new(point, seed, dir, summary))
    }

    /// Its summary; `None` if it failed.
    pub fn summary(&self) -> Option<&Summary> {
        self.summary.as_ref()
    }

    /// The base station's node id (`robots.count`) if the run had one: its summary's
    /// `awareness` is `null` without.
    pub fn base_station(&self) -> Option<proto::msg::RobotId> {
        let s = self.summary.as_ref()?;
        s.awareness.as_ref().map(|_| s.robots)
    }

    pub fn complete(&self) -> bool {
        self.summary.as_ref().is_some_and(|s| s.complete)
    }

    /// A field of this run, as the sweep counts it: exploration time only for complete runs.
    pub fn value(&self, f: &str) -> Option<f64> {
        if f == "exploration_steps" && !self.complete() {
            return None;
        }
        field(self.json.as_ref()?, f)
    }
}

/// The aggregated results of a sweep.
pub struct Results {
    pub points: Vec<Point>,
    pub fields: Vec<String>,
    pub runs: Vec<Run>,
}

impl Results {
    /// Runs, complete runs and per-field values of one point.
    pub fn of_point(&self, i: usize) -> impl Iterator<Item = &Run> {
        self.runs.iter().filter(move |r| r.point == i)
    }

    /// Mean, std and 95 % half-width of a field over the runs of the points `which` selects.
    pub fn stats_where(&self, which: impl Fn(&Point) -> bool, f: &str) -> Option<(f64, f64, f64)> {
        let xs: Vec<f64> = self
            .runs
            .iter()
            .filter(|r| which(&self.points[r.point]))
            .filter_map(|r| r.value(f))
            .collect();
        stats(&xs)
    }

    pub fn keys(&self) -> Vec<String> {
        self.points
            .first()
            .map(|p| p.0.iter().map(|(k, _)| k.clone()).collect())
            .unwrap_or_default()
    }

    /// Writes `runs.csv` and `results.csv` into `out`.
    ///
    /// Their columns depend on the experiment (its grid keys and fields), so their rows are
    /// records of text, not a row type.
    pub fn write_tables(&self, out: &Path) -> anyhow::Result<()> {
        let mut head: Vec<String> = self.keys();
        head.extend(["seed", "status", "complete", "exit_reason"].map(String::from));
        head.extend(self.fields.iter().cloned());
        let runs = self.runs.iter().map(|r| self.run_record(r));
        write_records(&out.join("runs.csv"), head, runs)?;

        let mut head: Vec<String> = self.keys();
        head.extend(["runs", "complete"].map(String::from));
        for f in &self.fields {
            head.extend([format!("{f}_mean"), format!("{f}_std"), format!("{f}_ci95")]);
        }
        let points = (0..self.points.len()).map(|i| self.point_record(i));
        write_records(&out.join("results.csv"), head, points)
    }

    /// A row of `runs.csv`.
    fn run_record(&self, r: &Run) -> Vec<String> {
        let mut rec: Vec<String> = self.points[r.point]
            .0
            .iter()
            .map(|(_, v)| v.clone())
            .collect();
        rec.push(r.seed.to_string());
        let Some(s) = &r.summary else {
            rec.extend(["failed".to_string(), String::new(), String::new()]);
            rec.extend(self.fields.iter().map(|_| String::new()));
            return rec;
        };
        rec.extend([
            "ok".to_string(),
            r.complete().to_string(),
            s.exit_reason.to_string(),
        ]);
        for f in &self.fields {
            let v = r.json.as_ref().and_then(|j| field(j, f));
            rec.push(v.map_or(String::new(), |v| v.to_string()));
        }
        rec
    }

    /// A row of `results.csv`.
    fn point_record(&self, i: usize) -> Vec<String> {
        let mut rec: Vec<String> = self.points[i].0.iter().map(|(_, v)| v.clone()).collect();
        let n = self.of_point(i).count();
        let complete = self.of_point(i).filter(|r| r.complete()).count();
        rec.extend([n.to_string(), complete.to_string()]);
        for f in &self.fields {
            let xs: Vec<f64> = self.of_point(i).filter_map(|r| r.value(f)).collect();
            match stats(&xs) {
                Some((m, sd, h)) => rec.extend([m, sd, h].map(|v| v.to_string())),
                None => rec.extend([String::new(), String::new(), String::new()]),
            }
        }
        rec
    }
}

/// Writes a header and records as CSV.
fn write_records(
    path: &Path,
    head: Vec<String>,
    records: impl Iterator<Item = Vec<String>>,
) -> anyhow::Result<()> {
    let context = || format!("writing {}", path.display());
    let mut w = csv::Writer::from_path(path).with_context(context)?;
    w.write_record(head).with_context(context)?;
    for r in records {
        w.write_record(r).with_context(context)?;
    }
    w.flush().with_context(context)
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
        assert_eq!(p[5].get("b"), Some("z"));
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

    #[test]
    fn fields_are_found_by_dotted_path() {
        let s = serde_json::json!({"a": 3, "b": {"c": 0.5}, "d": null});
        assert_eq!(field(&s, "a"), Some(3.0));
        assert_eq!(field(&s, "b.c"), Some(0.5));
        assert_eq!(field(&s, "d"), None);
        assert_eq!(field(&s, "b.x"), None);
    }

    #[test]
    fn exploration_time_counts_complete_runs_only() {
        let run = |complete: bool| {
            let s = Summary {
                complete,
                exploration_steps: Some(10),
                steps: 20,
                ..Summary::default()
            };
            Run::new(0, 1, PathBuf::new(), Some(s))
        };
        assert_eq!(run(true).value("exploration_steps"), Some(10.0));
        assert_eq!(run(false).value("exploration_steps"), None);
        assert_eq!(run(false).value("steps"), Some(20.0));
        assert_eq!(run(true).value("approx_error_avg"), None, "null");
        assert_eq!(Run::new(0, 1, PathBuf::new(), None).value("steps"), None);
    }

    #[test]
    fn the_base_station_is_node_robots_count_when_the_run_had_awareness() {
        let run = |awareness| {
            let s = Summary {
                robots: 3,
                awareness,
                ..Summary::default()
            };
            Run::new(0, 1, PathBuf::new(), Some(s))
        };
        let with = run(Some(crate::rundir::summary::AwarenessSummary {
            base_known_pct: Some(50.0),
            ..Default::default()
        }));
        assert_eq!(with.base_station(), Some(3));
        assert_eq!(with.value("awareness.base_known_pct"), Some(50.0));
        assert_eq!(run(None).base_station(), None);
    }

    #[test]
    fn the_standard_fields_are_numbers_of_the_summary_and_others_are_refused() {
        for f in FIELDS {
            check_field("FIELDS", f).unwrap_or_else(|e| panic!("{e:#}"));
        }
        for f in [
            "coverage_steps.90",
            "traffic_shares_pct.vertex",
            "bytes_by_type.move",
            "link_judgement.wrong_up",
            "logs_held.3.1026",
            "reconnect.histogram.0",
        ] {
            check_field("fields", f).unwrap_or_else(|e| panic!("{e:#}"));
        }
        for (f, why) in [
            ("exploration_step", "a typo"),
            ("awareness.team_pct", "not in awareness"),
            ("coverage_steps.80", "not a threshold"),
            ("bytes_by_type.nope", "not a traffic type"),
            ("exit_reason", "not a number"),
            ("awareness", "an object"),
            ("steps.x", "below a number"),
            ("logs_held.3", "an object"),
        ] {
            let e = check_field("fields", f).map_err(|e| format!("{e:#}"));
            assert!(
                e.as_ref().is_err_and(|e| e.contains(&format!("{f:?}"))
                    && e.contains("awareness.team_pct_mean")
                    && e.contains("coverage_steps.90")),
                "{f} ({why}): {e:?}"
            );
        }
    }
}
