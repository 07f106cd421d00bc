//! The run directory: a stable, documented schema users script against (DESIGN.md §6,
//! documented in README.md). Names of files and fields do not change without a version bump
//! ([`SCHEMA_VERSION`]).

use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::path::Path;

use anyhow::Context;
use proto::msg::{LinkReport, LinkState, Step, Traffic};
use serde::Serialize;

use crate::evaluate::{MetricsRow, THRESHOLDS};

/// Version of the run-directory schema, written into `summary.json`.
pub const SCHEMA_VERSION: u32 = 1;

/// `summary.json`.
#[derive(Debug, Serialize)]
pub struct Summary {
    pub schema_version: u32,
    pub complete: bool,
    pub exit_reason: String,
    pub robots: u16,
    pub robots_alive_at_end: usize,
    pub steps: u32,
    pub wall_seconds: f64,
    pub exploration_steps: Option<u32>,
    pub coverage_steps: BTreeMap<String, Option<u32>>,
    pub best_coverage_pct: f64,
    pub reachable_cells: usize,
    /// Bytes netem forwarded between robots (both directions, all links): the radio plane's
    /// real TCP payload, zenoh's framing included.
    pub bytes_wire_total: Option<u64>,
    pub bytes_payload_total: u64,
    pub bytes_by_type: BTreeMap<String, u64>,
    /// Thesis eq. 6.1; `null` unless `exchange.mode = "polygon"`.
    pub approx_error_avg: Option<f64>,
    pub collisions: u64,
    pub distance_m: Vec<f64>,
    pub radio_decode_errors: u64,
    pub failed_processes: Vec<String>,
}

pub fn coverage_steps(reached: &BTreeMap<u32, u32>) -> BTreeMap<String, Option<u32>> {
    THRESHOLDS
        .iter()
        .map(|t| (t.to_string(), reached.get(t).copied()))
        .collect()
}

pub fn bytes_by_type(per_robot: &[Vec<u64>]) -> BTreeMap<String, u64> {
    Traffic::ALL
        .iter()
        .enumerate()
        .map(|(i, t)| {
            (
                t.name().to_string(),
                per_robot
                    .iter()
                    .map(|v| v.get(i).copied().unwrap_or(0))
                    .sum(),
            )
        })
        .collect()
}

pub fn write_summary(dir: &Path, s: &Summary) -> anyhow::Result<()> {
    let text = serde_json::to_string_pretty(s)?;
    std::fs::write(dir.join("summary.json"), text + "\n").context("writing summary.json")
}

/// `metrics.csv`: one row per robot and step, in the order telemetry arrived.
pub fn write_metrics(dir: &Path, rows: &[MetricsRow]) -> anyhow::Result<()> {
    let mut s = String::from(
        "step,robot,x,y,known_cells,correct_known_cells,target_x,target_y,bytes_sent,bytes_received,coverage_pct,idle,neighbours\n",
    );
    let mut sorted: Vec<&MetricsRow> = rows.iter().collect();
    sorted.sort_by_key(|r| (r.step, r.robot));
    for r in sorted {
        let (tx, ty) = r.target.map_or((String::new(), String::new()), |(x, y)| {
            (format!("{x:.3}"), format!("{y:.3}"))
        });
        let _ = writeln!(
            s,
            "{},{},{:.3},{:.3},{},{},{},{},{},{},{:.3},{},{}",
            r.step,
            r.robot,
            r.x,
            r.y,
            r.known_cells,
            r.correct_known_cells,
            tx,
            ty,
            r.bytes_sent,
            r.bytes_received,
            r.coverage_pct,
            u8::from(r.idle),
            r.neighbours
        );
    }
    std::fs::write(dir.join("metrics.csv"), s).context("writing metrics.csv")
}

/// Every link report of a run, in arrival order.
#[derive(Default)]
pub struct LinkLog {
    pub rows: Vec<(Step, LinkState)>,
    totals: BTreeMap<(u16, u16), u64>,
}

impl LinkLog {
    pub fn add(&mut self, r: LinkReport) {
        for l in r.links {
            let t = self.totals.entry((l.a, l.b)).or_default();
            *t = (*t).max(l.bytes_total);
            self.rows.push((r.step, l));
        }
    }

    /// Bytes that crossed any link, both ways.
    pub fn wire_total(&self) -> u64 {
        self.totals.values().sum()
    }
}

/// Bytes that crossed any link, both ways, from netem's `link_totals.csv` (`None` if it is
/// missing or not in the expected form: netem did not stop normally).
pub fn link_totals_wire(path: &Path) -> Option<u64> {
    let text = std::fs::read_to_string(path).ok()?;
    let mut lines = text.lines();
    let head: Vec<&str> = lines.next()?.split(',').collect();
    let col = |name: &str| head.iter().position(|h| *h == name);
    let (ab, ba) = (col("bytes_a_to_b")?, col("bytes_b_to_a")?);
    lines
        .map(|l| {
            let f: Vec<&str> = l.split(',').collect();
            Some(f.get(ab)?.parse::<u64>().ok()? + f.get(ba)?.parse::<u64>().ok()?)
        })
        .sum()
}

/// `links.csv`: one row per step and robot pair.
pub fn write_links(dir: &Path, rows: &[(Step, LinkState)]) -> anyhow::Result<()> {
    let mut s =
        String::from("step,a,b,up,distance_m,bytes_a_to_b,bytes_b_to_a,queued_bytes,bytes_total\n");
    let mut sorted: Vec<&(Step, LinkState)> = rows.iter().collect();
    sorted.sort_by_key(|(step, l)| (*step, l.a, l.b));
    for (step, l) in sorted {
        let d = l.distance_m.map_or(String::new(), |d| format!("{d:.3}"));
        let _ = writeln!(
            s,
            "{step},{},{},{},{d},{},{},{},{}",
            l.a,
            l.b,
            u8::from(l.up),
            l.bytes_a_to_b,
            l.bytes_b_to_a,
            l.queued_bytes,
            l.bytes_total
        );
    }
    std::fs::write(dir.join("links.csv"), s).context("writing links.csv")
}
