//! `swarm replay`: one robot explores a world alone, without any network, while its mapping
//! pipeline (contours → incremental approximation → edit ops with save points) runs every step.
//! For people to look at (PNGs of G_s, P_t and A_t at chosen steps) and for measuring the
//! mapping core on real maps: ops and encoded bytes per package type (thesis Table 6.1) and the
//! approximation error e_avg (eq. 6.1).
//!
//! It uses the real robot decision loop ([`robot_agent::agent::Agent`]) and the real world
//! ([`world_server::world::World`]) in one process, stepping them directly: nothing here claims
//! to test the network.

use std::collections::HashMap;
use std::path::{Path, PathBuf};

use anyhow::Context;
use proto::geom::{MapInfo, Metres};
use proto::grid::{Grid, Occ};
use proto::msg::Traffic;
use robot_agent::agent::Agent;
use robot_agent::exchange::mapper::{Mapper, StepReport};
use robot_agent::mapping::contour::Kind;
use robot_agent::mapping::qpoint::QPoint;
use serde::Serialize;
use world_server::scenario::resolve;
use world_server::world::World;

use crate::rundir::render::Picture;
use crate::rundir::tables::write_rows;

/// Flags of `swarm replay`.
#[derive(clap::Args, Debug, Clone)]
pub struct ReplayArgs {
    /// Scenario TOML file (default: the embedded default); robots.count is forced to 1.
    pub scenario: Option<PathBuf>,
    /// Override a scenario key, e.g. --set world.map=fr079 (repeatable).
    #[arg(long = "set", value_name = "KEY=VALUE")]
    pub set: Vec<String>,
    /// Steps to simulate at most; the replay also ends when the robot sees no frontier.
    #[arg(long, default_value_t = 3000)]
    pub steps: u32,
    /// Douglas–Peucker splits per step (fractional values accumulate: 0.2 = one every 5 steps).
    #[arg(long, default_value_t = 2.0)]
    pub splits: f64,
    /// Steps at which to write PNGs of G_s, P_t and A_t, comma-separated (the last step always).
    #[arg(long, value_delimiter = ',', value_name = "STEPS")]
    pub png_at: Vec<u32>,
    /// Output directory (default: `runs/replay-<map>`).
    #[arg(long, value_name = "DIR")]
    pub out: Option<PathBuf>,
}

/// Per package type: how many ops, their mean encoded size, and the thesis's size.
#[derive(Debug, Serialize)]
pub struct OpTypeSummary {
    pub count: u64,
    pub bytes: u64,
    pub mean_bytes: Option<f64>,
    pub thesis_bytes: f64,
}

/// `replay.json`.
#[derive(Debug, Serialize)]
pub struct ReplaySummary {
    pub map: String,
    pub steps: u32,
    pub coverage_pct: f64,
    pub splits_per_step: f64,
    pub ops: usize,
    pub bytes: u64,
    pub by_type: std::collections::BTreeMap<String, OpTypeSummary>,
    pub approx_error_avg: Option<f64>,
}

/// Runs a replay and writes `replay.json`, `replay.csv` and the PNGs into the output directory.
pub fn replay(args: &ReplayArgs) -> anyhow::Result<(PathBuf, ReplaySummary)> {
    let mut set = args.set.clone();
    set.push("robots.count=1".into());
    let resolved = resolve(args.scenario.as_deref(), &set)?;
    if !(args.splits >= 0.0 && args.splits.is_finite()) {
        anyhow::bail!("--splits {}: must be a finite number ≥ 0", args.splits);
    }
    let mut world = World::build(&resolved.scenario, resolved.map.as_ref())?;
    let name = resolved.name();
    let mut scenario = resolved.scenario;
    scenario.world.map = name.clone();
    let dir = args
        .out
        .clone()
        .unwrap_or_else(|| PathBuf::from("runs").join(format!("replay-{name}")));
    std::fs::create_dir_all(&dir).with_context(|| format!("creating {}", dir.display()))?;
    let info = world.map();
    let mut agent = Agent::new(0, world.info(), &scenario);
    let mut mapper = Mapper::new(args.splits);
    let mut rows: Vec<ReplayCsv> = Vec::new();
    let mut idle_steps = 0;
    let mut step = 0;
    while step < args.steps && idle_steps < 5 {
        let Some(scan) = world.scan(0, step) else {
            break;
        };
        let cmd = agent.on_scan(&scan);
        let r = mapper.step(agent.own_grid(), agent.own_changes());
        rows.push(ReplayCsv::new(step, &r));
        if args.png_at.contains(&step) {
            pictures(&dir, step, agent.own_grid(), &mapper, info)?;
        }
        world.apply(step, &HashMap::from([(0, cmd)]));
        idle_steps = if agent.is_idle() { idle_steps + 1 } else { 0 };
        step += 1;
    }
    pictures(
        &dir,
        step.saturating_sub(1),
        agent.own_grid(),
        &mapper,
        info,
    )?;
    write_rows(&dir.join("replay.csv"), rows)?;
    let summary = summarize(&name, step, &world.reachable, agent.own_grid(), &mapper);
    std::fs::write(
        dir.join("replay.json"),
        serde_json::to_string_pretty(&summary)? + "\n",
    )
    .context("writing replay.json")?;
    Ok((dir, summary))
}

/// `swarm replay`: runs the replay and prints what it measured.
pub fn command(args: &ReplayArgs) -> anyhow::Result<std::process::ExitCode> {
    proto::node::init_logging();
    let (dir, s) = replay(args)?;
    println!(
        "replay of {}: {} steps, coverage {:.1}%, {} ops, {} bytes, e_avg {}",
        s.map,
        s.steps,
        s.coverage_pct,
        s.ops,
        s.bytes,
        s.approx_error_avg.map_or("-".into(), |e| format!("{e:.4}"))
    );
    for (name, t) in &s.by_type {
        let mean = t.mean_bytes.map_or("-".into(), |m| format!("{m:.2}"));
        println!(
            "  {name:>4}: {:>8} ops, mean {mean} bytes (thesis {})",
            t.count, t.thesis_bytes
        );
    }
    println!("written to {}", dir.display());
    Ok(std::process::ExitCode::SUCCESS)
}

/// A row of `replay.csv`: the mapping pipeline after one step.
#[derive(Debug, Default, PartialEq, Serialize, serde::Deserialize)]
pub struct ReplayCsv {
    pub step: u32,
    pub contour_points: usize,
    pub objects: usize,
    pub vertices: usize,
    pub ops: usize,
    pub bytes: usize,
    pub error_cells: usize,
    pub known_cells: usize,
}

impl ReplayCsv {
    fn new(step: u32, r: &StepReport) -> ReplayCsv {
        ReplayCsv {
            step,
            contour_points: r.contour_points,
            objects: r.objects,
            vertices: r.vertices,
            ops: r.ops,
            bytes: r.bytes,
            error_cells: r.error_cells,
            known_cells: r.known_cells,
        }
    }
}

fn summarize(map: &str, steps: u32, reachable: &Grid, own: &Grid, m: &Mapper) -> ReplaySummary {
    let target = reachable.count(Occ::Free).max(1);
    let seen = reachable
        .cells()
        .iter()
        .zip(own.cells())
        .filter(|(r, o)| **r == Occ::Free && **o == Occ::Free)
        .count();
    let by_type = Traffic::OPS
        .iter()
        .map(|&t| {
            let s = OpTypeSummary {
                count: m.stats.count[t as usize],
                bytes: m.stats.bytes[t as usize],
                mean_bytes: m.stats.mean_bytes(t),
                thesis_bytes: t.thesis_bytes().unwrap_or_default(),
            };
            (t.name().to_string(), s)
        })
        .collect();
    ReplaySummary {
        map: map.to_string(),
        steps,
        coverage_pct: 100.0 * seen as f64 / target as f64,
        splits_per_step: m.splits_per_step,
        ops: m.log().len(),
        bytes: m.stats.bytes.iter().sum(),
        by_type,
        approx_error_avg: m.error_avg(),
    }
}

/// Metric position of a quarter-cell point.
fn metres(q: QPoint, info: MapInfo) -> Metres {
    Metres::new(
        info.origin_x_m + f64::from(q.x) / 4.0 * info.resolution_m,
        info.origin_y_m + f64::from(q.y) / 4.0 * info.resolution_m,
    )
}

fn closed(points: impl Iterator<Item = QPoint>, info: MapInfo) -> Vec<Metres> {
    let mut v: Vec<Metres> = points.map(|q| metres(q, info)).collect();
    if let Some(&first) = v.first() {
        v.push(first);
    }
    v
}

const INSIDE: [u8; 3] = [30, 90, 220];
const OUTSIDE: [u8; 3] = [220, 40, 40];

/// `gs_<step>.png` (G_s), `pt_<step>.png` (P_t over G_s), `at_<step>.png` (A_t alone).
fn pictures(dir: &Path, step: u32, own: &Grid, m: &Mapper, info: MapInfo) -> anyhow::Result<()> {
    Picture::of_grid(own, info).save(&dir.join(format!("gs_{step:05}.png")))?;
    let mut pt = Picture::of_grid(own, info);
    for c in m.contours().map(|c| c.objects()).unwrap_or_default() {
        let col = if c.kind == Kind::Inside {
            INSIDE
        } else {
            OUTSIDE
        };
        pt.path(&closed(c.points.iter().copied(), info), col);
    }
    pt.save(&dir.join(format!("pt_{step:05}.png")))?;
    let mut at = Picture::of_grid(&Grid::new(own.width(), own.height(), Occ::Free), info);
    for p in m.approximation().objects.values() {
        let col = if p.kind == Kind::Inside {
            INSIDE
        } else {
            OUTSIDE
        };
        at.path(&closed(p.vertices.iter().map(|v| v.p), info), col);
    }
    at.save(&dir.join(format!("at_{step:05}.png")))?;
    Ok(())
}
