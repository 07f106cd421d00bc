//! A sweep's report: the experiment file's `[[plot]]`, `[[timeline]]`, `[[curve]]` and
//! `[[table]]` entries drawn from its results, and `report.md` that embeds them with a table of
//! every grid point.
//!
//! * `[[plot]]`: a field's mean (95 % error bars) against a grid key `x`, one line per value of
//!   `series`; one chart per combination of the other grid keys.
//! * `[[timeline]]`: per step, the bytes crossing all links both ways (`links.csv`) and the largest backlog
//!   a robot holds (`metrics.csv`), of each point's first seed; one line per value of `series`.
//! * `[[curve]]`: per step, a `metrics.csv` column's mean over the seeds of a point (shaded: its
//!   95 % t-interval), one line per value of `series`, one chart per combination of the other
//!   grid keys ([`crate::sweep::curve`]: which rows, and finished runs keeping their last value).
//! * `[[table]]`: fields' means in rows of grid keys, pooling the runs of `average_over` keys.

use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::path::Path;

use anyhow::Context;
use serde::Deserialize;

use crate::rundir::tables::{header, read_rows, LinkCsv, MetricsRow};
use crate::sweep::curve::{mean_over_runs, read_series, CurveSpec};
use crate::sweep::plot::{draw, short_number, Chart, Line, Mean, XAxis};
use crate::sweep::results::{check_field, Point, Results};
use proto::msg::Step;

#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PlotSpec {
    /// File stem under plots/.
    pub name: String,
    pub title: String,
    /// A grid key.
    pub x: String,
    pub x_label: Option<String>,
    /// A summary field (dotted path).
    pub y: String,
    pub y_label: Option<String>,
    /// A grid key: one line per value.
    pub series: Option<String>,
    #[serde(default)]
    pub log_y: bool,
    /// Place x values by their numbers (default: evenly, in grid order, as the thesis draws them).
    #[serde(default)]
    pub numeric_x: bool,
}

#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TimelineSpec {
    pub name: String,
    pub title: String,
    /// A grid key: one line per value.
    pub series: Option<String>,
}

#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TableSpec {
    pub title: String,
    /// Grid keys that make a row.
    pub rows: Vec<String>,
    /// Grid keys whose runs a row pools.
    #[serde(default)]
    pub average_over: Vec<String>,
    /// Summary fields (dotted paths): one column each, the mean over the row's runs.
    pub columns: Vec<String>,
}

/// What the report shows besides the results.
#[derive(Clone, Debug, Default)]
pub struct Spec {
    pub name: String,
    pub command: String,
    pub plots: Vec<PlotSpec>,
    pub timelines: Vec<TimelineSpec>,
    pub curves: Vec<CurveSpec>,
    pub tables: Vec<TableSpec>,
}

/// Checks that every key a spec names is a grid key, every summary field (`plot.y`,
/// `table.columns`) a number of `summary.json`, and every curve's column a `metrics.csv` column.
pub fn check(spec: &Spec, keys: &[String]) -> anyhow::Result<()> {
    let known = |k: &String, what: &str| {
        anyhow::ensure!(
            keys.contains(k),
            "{what} = {k:?} is not a grid key (grid keys: {})",
            keys.join(", ")
        );
        Ok(())
    };
    for p in &spec.plots {
        known(&p.x, "plot.x")?;
        check_field("plot.y", &p.y)?;
        if let Some(s) = &p.series {
            known(s, "plot.series")?;
        }
    }
    for t in &spec.timelines {
        if let Some(s) = &t.series {
            known(s, "timeline.series")?;
        }
    }
    let columns = header::<MetricsRow>()?;
    for c in &spec.curves {
        if let Some(s) = &c.series {
            known(s, "curve.series")?;
        }
        anyhow::ensure!(
            columns.contains(&c.column),
            "curve.column = {:?} is not a metrics.csv column (columns: {})",
            c.column,
            columns.join(", ")
        );
    }
    for t in &spec.tables {
        for k in t.rows.iter().chain(&t.average_over) {
            known(k, "table.rows / average_over")?;
        }
        for c in &t.columns {
            check_field("table.columns", c)?;
        }
    }
    Ok(())
}

/// A grid value as a reader wants it: `1 kB/s`, `unlimited`, `8 robots`, `20 %`.
pub fn label(key: &str, value: &str) -> String {
    match key {
        "radio.bandwidth_bytes_per_s" => match value.parse::<f64>() {
            Ok(0.0) => "unlimited".into(),
            Ok(b) => format!("{} kB/s", short_number(b / 1000.0)),
            Err(_) => value.into(),
        },
        "robots.count" => format!("{value} robots"),
        "radio.range_pct_of_diagonal" => format!("{value} %"),
        _ => value.into(),
    }
}

/// The x position of a grid value: the number itself, or its index among the key's values.
fn x_of(values: &[String], v: &str, numeric: bool) -> f64 {
    if numeric {
        v.parse().unwrap_or(f64::NAN)
    } else {
        values.iter().position(|x| x == v).unwrap_or(0) as f64
    }
}

/// The values each grid key takes, in grid order.
fn values_of(points: &[Point]) -> BTreeMap<String, Vec<String>> {
    let mut out: BTreeMap<String, Vec<String>> = BTreeMap::new();
    for p in points {
        for (k, v) in &p.0 {
            let vs = out.entry(k.clone()).or_default();
            if !vs.contains(v) {
                vs.push(v.clone());
            }
        }
    }
    out
}

/// The combinations of the grid keys other than `except` ("facets"), each as (key, value) pairs.
fn facets(points: &[Point], except: &[&str]) -> Vec<Vec<(String, String)>> {
    let mut out: Vec<Vec<(String, String)>> = Vec::new();
    for p in points {
        let f: Vec<(String, String)> =
            p.0.iter()
                .filter(|(k, _)| !except.contains(&k.as_str()))
                .cloned()
                .collect();
        if !out.contains(&f) {
            out.push(f);
        }
    }
    out
}

/// A chart's title: `title`, then the facet's values if it has any.
fn facet_title(title: &str, f: &[(String, String)]) -> String {
    if f.is_empty() {
        return title.to_string();
    }
    let values: Vec<String> = f.iter().map(|(k, v)| label(k, v)).collect();
    format!("{title}: {}", values.join(", "))
}

fn facet_stem(name: &str, f: &[(String, String)]) -> String {
    let mut s = name.to_string();
    for (_, v) in f {
        s.push('-');
        s.extend(v.chars().map(|c| {
            if c.is_ascii_alphanumeric() || c == '.' {
                c
            } else {
                '_'
            }
        }));
    }
    s
}

fn matches(p: &Point, facet: &[(String, String)]) -> bool {
    facet.iter().all(|(k, v)| p.get(k) == Some(v.as_str()))
}

/// Draws one `[[plot]]`: returns (title, file stem) of each chart.
fn plot(r: &Results, spec: &PlotSpec, dir: &Path) -> anyhow::Result<Vec<(String, String)>> {
    let values = values_of(&r.points);
    let xs = values.get(&spec.x).cloned().unwrap_or_default();
    let numeric = spec.numeric_x && xs.iter().all(|v| v.parse::<f64>().is_ok());
    let series_values = spec
        .series
        .as_ref()
        .and_then(|s| values.get(s).cloned())
        .unwrap_or_else(|| vec![String::new()]);
    let mut except = vec![spec.x.as_str()];
    if let Some(s) = &spec.series {
        except.push(s);
    }
    let mut out = Vec::new();
    for facet in facets(&r.points, &except) {
        let mut lines = Vec::new();
        for sv in &series_values {
            let mut points = Vec::new();
            for xv in &xs {
                let which = |p: &Point| {
                    matches(p, &facet)
                        && p.get(&spec.x) == Some(xv.as_str())
                        && spec
                            .series
                            .as_ref()
                            .is_none_or(|s| p.get(s) == Some(sv.as_str()))
                };
                if let Some((m, _, h)) = r.stats_where(which, &spec.y) {
                    points.push(Mean {
                        x: x_of(&xs, xv, numeric),
                        y: m,
                        lo: m - h,
                        hi: m + h,
                    });
                }
            }
            let name = match &spec.series {
                Some(s) => label(s, sv),
                None => String::new(),
            };
            lines.push(Line { name, points });
        }
        let title = facet_title(&spec.title, &facet);
        let stem = facet_stem(&spec.name, &facet);
        let chart = Chart {
            title: title.clone(),
            x_label: spec.x_label.clone().unwrap_or_else(|| spec.x.clone()),
            y_label: spec.y_label.clone().unwrap_or_else(|| spec.y.clone()),
            x: if numeric {
                XAxis::Numeric
            } else {
                XAxis::Categories(xs.iter().map(|v| label(&spec.x, v)).collect())
            },
            log_y: spec.log_y,
            markers: true,
            band: false,
            lines,
        };
        draw(&chart, &dir.join(&stem))?;
        out.push((title, stem));
    }
    Ok(out)
}

/// (step, value) pairs.
type PerStep = Vec<(f64, f64)>;

/// Per step: bytes over all links, and the largest backlog a robot reports.
fn load_over_time(run: &Path) -> anyhow::Result<(PerStep, PerStep)> {
    let links: Vec<LinkCsv> = read_rows(&run.join("links.csv"))?;
    let mut load: BTreeMap<Step, f64> = BTreeMap::new();
    for l in links {
        *load.entry(l.step).or_insert(0.0) += (l.bytes_a_to_b + l.bytes_b_to_a) as f64;
    }
    let metrics: Vec<MetricsRow> = read_rows(&run.join("metrics.csv"))?;
    let mut backlog: BTreeMap<Step, f64> = BTreeMap::new();
    for m in metrics {
        let b = backlog.entry(m.step).or_insert(0.0);
        *b = b.max(m.backlog_bytes as f64);
    }
    let per_step =
        |by: BTreeMap<Step, f64>| by.into_iter().map(|(k, v)| (f64::from(k), v)).collect();
    Ok((per_step(load), per_step(backlog)))
}

/// The values of grid key `series` (one empty value without it), and the keys a facet leaves
/// out.
fn series_of<'a>(r: &Results, series: Option<&'a String>) -> (Vec<String>, Vec<&'a str>) {
    let values = values_of(&r.points);
    let series_values = series
        .and_then(|s| values.get(s).cloned())
        .unwrap_or_else(|| vec![String::new()]);
    (series_values, series.iter().map(|s| s.as_str()).collect())
}

/// Draws one `[[timeline]]`: two charts (link load, backlog) per facet.
fn timeline(r: &Results, spec: &TimelineSpec, dir: &Path) -> anyhow::Result<Vec<(String, String)>> {
    let (series_values, except) = series_of(r, spec.series.as_ref());
    let mut out = Vec::new();
    for facet in facets(&r.points, &except) {
        let mut load = Vec::new();
        let mut backlog = Vec::new();
        for sv in &series_values {
            let run = r
                .runs
                .iter()
                .filter(|run| run.summary().is_some())
                .find(|run| {
                    let p = &r.points[run.point];
                    matches(p, &facet)
                        && spec
                            .series
                            .as_ref()
                            .is_none_or(|s| p.get(s) == Some(sv.as_str()))
                });
            let Some(run) = run else { continue };
            let (l, b) = load_over_time(&run.dir)?;
            let name = match &spec.series {
                Some(s) => format!("{} (seed {})", label(s, sv), run.seed),
                None => format!("seed {}", run.seed),
            };
            let pts = |v: PerStep| {
                v.into_iter()
                    .map(|(x, y)| Mean { x, y, lo: y, hi: y })
                    .collect()
            };
            load.push(Line {
                name: name.clone(),
                points: pts(l),
            });
            backlog.push(Line {
                name,
                points: pts(b),
            });
        }
        for (what, lines, y_label) in [
            ("load", load, "bytes per step, all links"),
            ("backlog", backlog, "largest backlog of a robot (bytes)"),
        ] {
            let title = facet_title(&format!("{} ({what})", spec.title), &facet);
            let stem = facet_stem(&format!("{}-{what}", spec.name), &facet);
            let chart = Chart {
                title: title.clone(),
                x_label: "step".into(),
                y_label: y_label.into(),
                x: XAxis::Numeric,
                log_y: false,
                markers: false,
                band: false,
                lines,
            };
            draw(&chart, &dir.join(&stem))?;
            out.push((title, stem));
        }
    }
    Ok(out)
}

/// Draws one `[[curve]]`: a chart per facet, a line per series value, each line the mean over
/// the point's finished runs (failed runs have no summary and are left out).
fn curve(r: &Results, spec: &CurveSpec, dir: &Path) -> anyhow::Result<Vec<(String, String)>> {
    let (series_values, except) = series_of(r, spec.series.as_ref());
    let mut out = Vec::new();
    for facet in facets(&r.points, &except) {
        let mut lines = Vec::new();
        for sv in &series_values {
            let which = |p: &Point| {
                matches(p, &facet)
                    && spec
                        .series
                        .as_ref()
                        .is_none_or(|s| p.get(s) == Some(sv.as_str()))
            };
            // One point's runs at a time, each already reduced to a value per step.
            let runs = (r.runs.iter())
                .filter(|run| run.summary().is_some() && which(&r.points[run.point]))
                .map(|run| {
                    let metrics = run.dir.join("metrics.csv");
                    read_series(&metrics, &spec.column, spec.rows, run.base_station())
                })
                .collect::<anyhow::Result<Vec<_>>>()?;
            let points = mean_over_runs(&runs, spec.max_step);
            if points.is_empty() {
                continue;
            }
            let seeds = runs.iter().filter(|v| !v.is_empty()).count();
            let name = match &spec.series {
                Some(s) => format!("{} ({seeds} seeds)", label(s, sv)),
                None => format!("{seeds} seeds"),
            };
            lines.push(Line { name, points });
        }
        let title = facet_title(&spec.title, &facet);
        let stem = facet_stem(&spec.name, &facet);
        let chart = Chart {
            title: title.clone(),
            x_label: "step (a finished run keeps its last value)".into(),
            y_label: spec.y_label.clone().unwrap_or_else(|| spec.column.clone()),
            x: XAxis::Numeric,
            log_y: false,
            markers: false,
            band: true,
            lines,
        };
        draw(&chart, &dir.join(&stem))?;
        out.push((title, stem));
    }
    Ok(out)
}

/// One `[[table]]` as markdown.
fn table(r: &Results, spec: &TableSpec) -> String {
    let values = values_of(&r.points);
    let mut md = format!("### {}\n\n", spec.title);
    if !spec.average_over.is_empty() {
        let _ = writeln!(
            md,
            "Each row pools the runs over {}.\n",
            spec.average_over.join(", ")
        );
    }
    let mut head: Vec<String> = spec.rows.clone();
    head.push("runs".into());
    head.extend(spec.columns.iter().map(|c| short_field(c)));
    let _ = writeln!(md, "| {} |", head.join(" | "));
    let _ = writeln!(md, "|{}", "---|".repeat(head.len()));
    let mut rows: Vec<Vec<(String, String)>> = vec![Vec::new()];
    for k in &spec.rows {
        let vs = values.get(k).cloned().unwrap_or_default();
        rows = rows
            .into_iter()
            .flat_map(|row| {
                vs.iter().map(move |v| {
                    let mut row = row.clone();
                    row.push((k.clone(), v.clone()));
                    row
                })
            })
            .collect();
    }
    for row in rows {
        let runs = r
            .runs
            .iter()
            .filter(|run| run.summary().is_some() && matches(&r.points[run.point], &row))
            .count();
        let mut cells: Vec<String> = row.iter().map(|(k, v)| label(k, v)).collect();
        cells.push(runs.to_string());
        for c in &spec.columns {
            cells.push(
                r.stats_where(|p| matches(p, &row), c)
                    .map_or("–".into(), |(m, _, _)| format!("{m:.1}")),
            );
        }
        let _ = writeln!(md, "| {} |", cells.join(" | "));
    }
    md.push('\n');
    md
}

/// `traffic_shares_pct.vertex` → `vertex`.
fn short_field(f: &str) -> String {
    f.rsplit('.').next().unwrap_or(f).to_string()
}

/// The machine, for the report: CPU model and core count.
fn machine() -> String {
    let cpu = std::fs::read_to_string("/proc/cpuinfo")
        .ok()
        .and_then(|t| {
            t.lines()
                .find(|l| l.starts_with("model name"))
                .and_then(|l| l.split(':').nth(1))
                .map(|s| s.trim().to_string())
        })
        .unwrap_or_else(|| "unknown CPU".into());
    let cores = std::thread::available_parallelism().map_or(0, |n| n.get());
    format!("{cpu}, {cores} cores available")
}

/// Writes plots/ and report.md into `out`.
pub fn write(r: &Results, spec: &Spec, out: &Path) -> anyhow::Result<()> {
    let dir = out.join("plots");
    std::fs::create_dir_all(&dir).context("creating plots/")?;
    let mut md = format!("# Sweep `{}`\n\n", spec.name);
    let failed = r.runs.iter().filter(|x| x.summary().is_none()).count();
    let complete = r.runs.iter().filter(|x| x.complete()).count();
    let _ = writeln!(
        md,
        "Command: `{}`  \nMachine: {}  \nRuns: {} ({} points), {} complete, {} incomplete, {} failed. \
         Exploration time counts complete runs only; error bars are 95 % t-intervals over seeds.\n",
        spec.command,
        machine(),
        r.runs.len(),
        r.points.len(),
        complete,
        r.runs.len() - complete - failed,
        failed
    );
    for p in &spec.plots {
        let _ = writeln!(md, "## {}\n", p.title);
        for (title, stem) in plot(r, p, &dir)? {
            let _ = writeln!(md, "![{title}](plots/{stem}.svg)\n");
        }
    }
    for t in &spec.timelines {
        let _ = writeln!(md, "## {}\n", t.title);
        for (title, stem) in timeline(r, t, &dir)? {
            let _ = writeln!(md, "![{title}](plots/{stem}.svg)\n");
        }
    }
    for c in &spec.curves {
        let _ = writeln!(md, "## {}\n", c.title);
        let _ = writeln!(
            md,
            "`{}` of `metrics.csv` per step ({}), averaged over the seeds of each point \
             (shaded: 95 % t-interval). A run that ended before the longest run of its point \
             is finished and keeps its last value.\n",
            c.column,
            c.rows.describe()
        );
        for (title, stem) in curve(r, c, &dir)? {
            let _ = writeln!(md, "![{title}](plots/{stem}.svg)\n");
        }
    }
    for t in &spec.tables {
        md.push_str(&table(r, t));
    }
    md.push_str("## Every grid point\n\n");
    md.push_str(&points_table(r));
    std::fs::write(out.join("report.md"), md).context("writing report.md")
}

/// Mean ± 95 % of the main fields, one row per grid point.
fn points_table(r: &Results) -> String {
    let keys = r.keys();
    let cols = ["exploration_steps", "bytes_wire_total", "approx_error_avg"];
    let mut md = String::new();
    let mut head = keys.clone();
    head.extend(["runs", "complete"].map(String::from));
    head.extend(cols.map(String::from));
    let _ = writeln!(md, "| {} |", head.join(" | "));
    let _ = writeln!(md, "|{}", "---|".repeat(head.len()));
    for (i, p) in r.points.iter().enumerate() {
        let mut cells: Vec<String> = p.0.iter().map(|(k, v)| label(k, v)).collect();
        cells.push(r.of_point(i).count().to_string());
        cells.push(r.of_point(i).filter(|x| x.complete()).count().to_string());
        for c in cols {
            let xs: Vec<f64> = r.of_point(i).filter_map(|x| x.value(c)).collect();
            cells.push(match crate::sweep::results::stats(&xs) {
                Some((m, _, h)) if c == "approx_error_avg" => format!("{m:.4} ± {h:.4}"),
                Some((m, _, h)) => {
                    format!("{} ± {}", short_number(m.round()), short_number(h.round()))
                }
                None => "–".into(),
            });
        }
        let _ = writeln!(md, "| {} |", cells.join(" | "));
    }
    md
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn grid_values_read_as_words() {
        assert_eq!(label("radio.bandwidth_bytes_per_s", "0"), "unlimited");
        assert_eq!(label("radio.bandwidth_bytes_per_s", "1000"), "1 kB/s");
        assert_eq!(label("radio.bandwidth_bytes_per_s", "250"), "0.25 kB/s");
        assert_eq!(label("robots.count", "8"), "8 robots");
        assert_eq!(label("world.map", "office"), "office");
    }

    fn curve_spec(column: &str, series: &str) -> CurveSpec {
        CurveSpec {
            name: "c".into(),
            title: "C".into(),
            column: column.into(),
            rows: crate::sweep::curve::Rows::First,
            y_label: None,
            series: Some(series.into()),
            max_step: None,
        }
    }

    #[test]
    fn a_curve_names_a_grid_key_and_a_metrics_column() {
        let keys = ["coordination.strategy".to_string()];
        let spec = |c: CurveSpec| Spec {
            curves: vec![c],
            ..Spec::default()
        };
        assert!(check(
            &spec(curve_spec("team_pct", "coordination.strategy")),
            &keys
        )
        .is_ok());
        let e = check(&spec(curve_spec("team_pc", "coordination.strategy")), &keys);
        assert!(e.is_err_and(|e| e.to_string().contains("metrics.csv column")));
        assert!(check(&spec(curve_spec("team_pct", "robots.count")), &keys).is_err());
    }

    #[test]
    fn a_curve_draws_a_line_per_series_value_from_the_finished_runs() {
        let dir = std::env::temp_dir().join(format!("swarm-report-curve-{}", std::process::id()));
        let point = |v: &str| Point(vec![("k".into(), v.into())]);
        let mut runs = Vec::new();
        for (i, (p, seed, table)) in [
            (0, 1, "step,robot,team_pct\n0,0,10\n1,0,30\n"),
            (0, 2, "step,robot,team_pct\n0,0,20\n"),
            (1, 1, "step,robot,team_pct\n0,0,50\n"),
        ]
        .into_iter()
        .enumerate()
        {
            let run = dir.join(format!("run{i}"));
            std::fs::create_dir_all(&run).unwrap_or_else(|e| panic!("{e}"));
            std::fs::write(run.join("metrics.csv"), table).unwrap_or_else(|e| panic!("{e}"));
            let summary = crate::rundir::summary::Summary {
                robots: 1,
                ..Default::default()
            };
            runs.push(crate::sweep::results::Run::new(p, seed, run, Some(summary)));
        }
        // A failed run (no summary) and its missing table are left out.
        runs.push(crate::sweep::results::Run::new(
            1,
            2,
            dir.join("failed"),
            None,
        ));
        let r = Results {
            points: vec![point("a"), point("b")],
            fields: Vec::new(),
            runs,
        };
        let charts = curve(&r, &curve_spec("team_pct", "k"), &dir);
        let drawn = dir.join("c.svg").exists() && dir.join("c.png").exists();
        let _ = std::fs::remove_dir_all(&dir);
        let charts = charts.unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(charts, [("C".to_string(), "c".to_string())]);
        assert!(drawn);
    }

    #[test]
    fn facets_are_the_other_keys_combinations() {
        let p = |a: &str, b: &str, c: &str| {
            Point(vec![
                ("a".into(), a.into()),
                ("b".into(), b.into()),
                ("c".into(), c.into()),
            ])
        };
        let pts = vec![
            p("1", "x", "u"),
            p("1", "y", "u"),
            p("2", "x", "u"),
            p("2", "y", "v"),
        ];
        let f = facets(&pts, &["a", "c"]);
        assert_eq!(f.len(), 2);
        assert_eq!(facet_stem("plot", &f[0]), "plot-x");
        assert!(matches(&pts[2], &f[0]) && !matches(&pts[1], &f[0]));
    }
}
