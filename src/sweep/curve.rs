//! A sweep report's `[[curve]]`: one column of every run's `metrics.csv` over the steps,
//! averaged over the seeds of a grid point — de Hoog, Cameron and Visser (TAROS 2010) Fig. 5a–b:
//! what the team, or the base station, knows over time.
//!
//! A run's table is read once, row by row, into one value per step
//! ([`Rows`](crate::sweep::curve::Rows) says which rows of the step make it), so a sweep's tables
//! are never all in memory. The seeds of a point are then averaged step by step
//! ([`mean_over_runs`](crate::sweep::curve::mean_over_runs)) up to the last step of the point's
//! longest run; a run that ended sooner keeps its last value — it is finished, and what it had at
//! its end it has at every later step.

use std::collections::btree_map::Entry;
use std::collections::{BTreeMap, BTreeSet};
use std::path::Path;

use anyhow::{bail, Context};
use proto::msg::{RobotId, Step};
use serde::Deserialize;

use crate::sweep::plot::Mean;
use crate::sweep::results::stats;

/// `[[curve]]` in an experiment file.
#[derive(Clone, Debug, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CurveSpec {
    /// File stem under plots/.
    pub name: String,
    pub title: String,
    /// A `metrics.csv` column.
    pub column: String,
    /// Which rows of a step give the run's value (default `robots`).
    #[serde(default)]
    pub rows: Rows,
    pub y_label: Option<String>,
    /// A grid key: one line per value.
    pub series: Option<String>,
    /// The x axis ends at this step.
    pub max_step: Option<Step>,
}

/// Which rows of a step make a run's value of that step.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Rows {
    /// The mean over the robot rows.
    #[default]
    Robots,
    /// The base station's row (none without a base station).
    Base,
    /// The largest value of a robot row.
    Max,
    /// The robot row of the lowest id: for columns that are the same on every robot row of a
    /// step, like `team_pct`.
    First,
}

impl Rows {
    /// Which rows, in words, for the report.
    pub fn describe(self) -> &'static str {
        match self {
            Rows::Robots => "the mean of the robot rows",
            Rows::Base => "the base station's row",
            Rows::Max => "the largest robot row",
            Rows::First => "the first robot row",
        }
    }
}

/// The rows of one step seen so far.
#[derive(Clone, Copy, Debug)]
struct StepRows {
    sum: f64,
    n: u32,
    max: f64,
    /// The value of the lowest robot id.
    first: (RobotId, f64),
}

impl StepRows {
    fn new(robot: RobotId, v: f64) -> StepRows {
        StepRows {
            sum: v,
            n: 1,
            max: v,
            first: (robot, v),
        }
    }

    fn add(&mut self, robot: RobotId, v: f64) {
        self.sum += v;
        self.n += 1;
        self.max = self.max.max(v);
        if robot < self.first.0 {
            self.first = (robot, v);
        }
    }

    fn value(&self, rows: Rows) -> f64 {
        match rows {
            Rows::Robots => self.sum / f64::from(self.n),
            Rows::Max => self.max,
            // A step has one base station row; its first is it.
            Rows::Base | Rows::First => self.first.1,
        }
    }
}

/// One run's values per step, built one `metrics.csv` row at a time.
#[derive(Clone, Debug)]
pub struct RunSeries {
    rows: Rows,
    base: Option<RobotId>,
    by_step: BTreeMap<Step, StepRows>,
}

impl RunSeries {
    /// `base` is the run's base station id (`robots.count`), if it had one.
    pub fn new(rows: Rows, base: Option<RobotId>) -> RunSeries {
        RunSeries {
            rows,
            base,
            by_step: BTreeMap::new(),
        }
    }

    /// One row's value; rows of the other kind (base station or robot) and values that are
    /// not numbers are left out.
    pub fn add(&mut self, step: Step, robot: RobotId, v: f64) {
        let is_base = self.base == Some(robot);
        if is_base != (self.rows == Rows::Base) || !v.is_finite() {
            return;
        }
        match self.by_step.entry(step) {
            Entry::Vacant(e) => {
                e.insert(StepRows::new(robot, v));
            }
            Entry::Occupied(mut e) => e.get_mut().add(robot, v),
        }
    }

    /// (step, value) by step.
    pub fn finish(self) -> Vec<(Step, f64)> {
        let rows = self.rows;
        (self.by_step.into_iter())
            .map(|(s, r)| (s, r.value(rows)))
            .collect()
    }
}

/// One run's series from rows (step, robot, value).
pub fn run_series(
    rows: Rows,
    base: Option<RobotId>,
    table: impl IntoIterator<Item = (Step, RobotId, f64)>,
) -> Vec<(Step, f64)> {
    let mut s = RunSeries::new(rows, base);
    for (step, robot, v) in table {
        s.add(step, robot, v);
    }
    s.finish()
}

/// One run's series of `column` from its `metrics.csv`, streamed. A table without the column
/// (written before it existed) gives no values; an empty cell (e.g. `shared_pct` on the base
/// station's row) is left out.
pub fn read_series(
    metrics: &Path,
    column: &str,
    rows: Rows,
    base: Option<RobotId>,
) -> anyhow::Result<Vec<(Step, f64)>> {
    let context = || format!("reading {}", metrics.display());
    let mut r = csv::Reader::from_path(metrics).with_context(context)?;
    let head = r.headers().with_context(context)?.clone();
    let at = |name: &str| head.iter().position(|h| h == name);
    let (Some(step_at), Some(robot_at)) = (at("step"), at("robot")) else {
        bail!("{}: no step and robot columns", metrics.display());
    };
    let Some(value_at) = at(column) else {
        return Ok(Vec::new());
    };
    let mut series = RunSeries::new(rows, base);
    let mut record = csv::StringRecord::new();
    while r.read_record(&mut record).with_context(context)? {
        let line = record.position().map_or(0, |p| p.line());
        let field = |i: usize| record.get(i).unwrap_or("").trim();
        let value = field(value_at);
        if value.is_empty() {
            continue;
        }
        let parsed = (
            field(step_at).parse::<Step>(),
            field(robot_at).parse::<RobotId>(),
            value.parse::<f64>(),
        );
        let (Ok(step), Ok(robot), Ok(v)) = parsed else {
            bail!(
                "{} line {line}: step, robot or {column} is not a number",
                metrics.display()
            );
        };
        series.add(step, robot, v);
    }
    Ok(series.finish())
}

/// Per step, the mean over the runs and its 95 % t-interval. The steps are every step some run
/// has, up to `max_step`; a run counts from its first value on and, once it ended (or when a
/// step lacks its row), with its last value. Runs without values count nowhere.
pub fn mean_over_runs(runs: &[Vec<(Step, f64)>], max_step: Option<Step>) -> Vec<Mean> {
    let steps: BTreeSet<Step> = runs
        .iter()
        .flatten()
        .map(|&(s, _)| s)
        .filter(|&s| max_step.is_none_or(|m| s <= m))
        .collect();
    // Per run, the index of its latest value at or before the current step.
    let mut at: Vec<Option<usize>> = vec![None; runs.len()];
    let mut out = Vec::with_capacity(steps.len());
    for s in steps {
        let mut values = Vec::with_capacity(runs.len());
        for (run, i) in runs.iter().zip(at.iter_mut()) {
            let mut next = i.map_or(0, |i| i + 1);
            while run.get(next).is_some_and(|&(t, _)| t <= s) {
                *i = Some(next);
                next += 1;
            }
            if let Some(&(_, v)) = i.and_then(|i| run.get(i)) {
                values.push(v);
            }
        }
        if let Some((m, _, h)) = stats(&values) {
            out.push(Mean {
                x: f64::from(s),
                y: m,
                lo: m - h,
                hi: m + h,
            });
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Rows of two robots (0, 1) and a base station (2) over steps 0–1.
    fn table() -> Vec<(Step, RobotId, f64)> {
        vec![
            (0, 0, 10.0),
            (0, 1, 30.0),
            (0, 2, 5.0),
            (1, 1, 60.0),
            (1, 0, 20.0),
            (1, 2, 7.0),
        ]
    }

    #[test]
    fn the_four_row_modes_take_their_rows_of_each_step() {
        let base = Some(2);
        assert_eq!(
            run_series(Rows::Robots, base, table()),
            [(0, 20.0), (1, 40.0)]
        );
        assert_eq!(run_series(Rows::Base, base, table()), [(0, 5.0), (1, 7.0)]);
        assert_eq!(run_series(Rows::Max, base, table()), [(0, 30.0), (1, 60.0)]);
        assert_eq!(
            run_series(Rows::First, base, table()),
            [(0, 10.0), (1, 20.0)],
            "the lowest robot id, whatever the order of the rows"
        );
    }

    #[test]
    fn without_a_base_station_every_row_is_a_robot_s_and_base_gives_nothing() {
        assert_eq!(run_series(Rows::Base, None, table()), []);
        assert_eq!(run_series(Rows::Max, None, table()), [(0, 30.0), (1, 60.0)]);
        assert_eq!(
            run_series(Rows::Robots, None, [(3, 0, f64::NAN), (3, 1, 4.0)]),
            [(3, 4.0)]
        );
    }

    fn mean_ys(m: &[Mean]) -> Vec<(f64, f64)> {
        m.iter().map(|p| (p.x, p.y)).collect()
    }

    #[test]
    fn a_run_that_ended_keeps_its_last_value_to_the_longest_run_s_end() {
        let long = vec![(0, 0.0), (1, 20.0), (2, 40.0), (3, 60.0)];
        let short = vec![(0, 10.0), (1, 50.0)];
        let m = mean_over_runs(&[long.clone(), short.clone()], None);
        assert_eq!(
            mean_ys(&m),
            [(0.0, 5.0), (1.0, 35.0), (2.0, 45.0), (3.0, 55.0)]
        );
        // Two values: a t-interval around the mean; one value: none.
        assert!(m[3].lo < 55.0 && m[3].hi > 55.0);
        let one = mean_over_runs(std::slice::from_ref(&long), None);
        assert_eq!((one[3].lo, one[3].hi), (60.0, 60.0));
        assert_eq!(
            mean_ys(&mean_over_runs(&[long, short], Some(1))),
            [(0.0, 5.0), (1.0, 35.0)]
        );
    }

    #[test]
    fn a_run_counts_from_its_first_value_and_holds_it_over_missing_steps() {
        let late = vec![(2, 30.0), (4, 50.0)];
        let early = vec![(0, 10.0), (1, 10.0), (2, 10.0), (3, 10.0), (4, 10.0)];
        let m = mean_over_runs(&[late, early, Vec::new()], None);
        assert_eq!(
            mean_ys(&m),
            [
                (0.0, 10.0),
                (1.0, 10.0),
                (2.0, 20.0),
                (3.0, 20.0),
                (4.0, 30.0)
            ]
        );
        assert!(mean_over_runs(&[], None).is_empty());
    }

    #[test]
    fn a_table_is_read_by_column_name_and_a_missing_column_gives_nothing() {
        let dir = std::env::temp_dir().join(format!("swarm-curve-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap_or_else(|e| panic!("{e}"));
        let path = dir.join("metrics.csv");
        let text = "step,robot,coverage_pct,team_pct\n0,0,10.0,40.0\n0,1,30.0,40.0\n0,2,5.0,\n1,0,20.0,55.5\n";
        std::fs::write(&path, text).unwrap_or_else(|e| panic!("{e}"));
        let read = |column: &str, rows: Rows| {
            read_series(&path, column, rows, Some(2)).unwrap_or_else(|e| panic!("{e}"))
        };
        assert_eq!(read("coverage_pct", Rows::Base), [(0, 5.0)]);
        assert_eq!(read("team_pct", Rows::First), [(0, 40.0), (1, 55.5)]);
        assert_eq!(read("shared_pct", Rows::Robots), []);
        std::fs::write(&path, "step,robot,team_pct\n0,x,1\n").unwrap_or_else(|e| panic!("{e}"));
        let bad = read_series(&path, "team_pct", Rows::Robots, None);
        let _ = std::fs::remove_dir_all(&dir);
        assert!(bad.is_err_and(|e| e.to_string().contains("line 2")));
    }

    #[test]
    fn a_curve_spec_parses_with_its_defaults_and_refuses_unknown_keys() {
        let full: CurveSpec = toml::from_str(
            "name = \"fig5b-base\"\ntitle = \"Known at the base station\"\n\
             column = \"coverage_pct\"\nrows = \"base\"\ny_label = \"% of the environment\"\n\
             series = \"coordination.strategy\"\nmax_step = 1500\n",
        )
        .unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(
            full,
            CurveSpec {
                name: "fig5b-base".into(),
                title: "Known at the base station".into(),
                column: "coverage_pct".into(),
                rows: Rows::Base,
                y_label: Some("% of the environment".into()),
                series: Some("coordination.strategy".into()),
                max_step: Some(1500),
            }
        );
        let bare: CurveSpec =
            toml::from_str("name = \"a\"\ntitle = \"A\"\ncolumn = \"team_pct\"\n")
                .unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(
            (bare.rows, bare.series, bare.max_step),
            (Rows::Robots, None, None)
        );
        for (rows, want) in [
            ("robots", Rows::Robots),
            ("max", Rows::Max),
            ("first", Rows::First),
        ] {
            let s: Result<CurveSpec, _> = toml::from_str(&format!(
                "name = \"a\"\ntitle = \"A\"\ncolumn = \"x\"\nrows = \"{rows}\"\n"
            ));
            assert_eq!(s.map(|s| s.rows).ok(), Some(want));
        }
        for bad in ["rows = \"all\"", "colour = \"red\""] {
            let s: Result<CurveSpec, _> = toml::from_str(&format!(
                "name = \"a\"\ntitle = \"A\"\ncolumn = \"x\"\n{bad}\n"
            ));
            assert!(s.is_err(), "{bad}");
        }
    }
}
