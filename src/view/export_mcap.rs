//! `swarm export-mcap RUN_DIR`: a run as an MCAP file, `run.mcap`, for Foxglove (or any MCAP
//! reader), from the run's step log ([`crate::rundir::steplog`]).
//!
//! Messages are JSON in Foxglove's well-known schemas (named so that Foxglove draws them), on
//! the run's simulated clock (step × `clock.step_seconds`):
//!
//! | topic | schema | when |
//! |---|---|---|
//! | `/map/truth` | `foxglove.Grid` | once, at step 0 |
//! | `/robot_<i>/grid` | `foxglove.Grid` (ROS occupancy values: -1, 0, 100) | every [`GRID_EVERY`] steps of the robot's reports and at its last one |
//! | `/robot_<i>/pose` | `foxglove.PoseInFrame` | every report of robot i (metrics.csv's rows) |
//! | `/robots` | `foxglove.SceneUpdate` (an arrow, the id and a line to the target per robot) | every step with reports |
//! | `/links` | `foxglove.SceneUpdate` (a line per link that is up) | every step netem reported (links.csv's steps) |
//! | `/links/bytes` | `swarm.LinkBytes` (per link: up, bytes each way, queued) | with `/links` |
//!
//! The frame is `map`: the map's metres, as in the scenario.

use std::collections::BTreeMap;
use std::fs::File;
use std::io::BufWriter;
use std::path::{Path, PathBuf};

use anyhow::Context;
use base64::Engine;
use proto::geom::MapInfo;
use proto::grid::{Grid, Occ};
use proto::msg::{RobotId, Step};
use serde_json::{json, Value};

use crate::rundir::steplog::{self, Grids, LinkStep, Record, RobotStep, StepLog};

/// A robot's grid goes to the file every this many of its reports (and at its last).
pub const GRID_EVERY: Step = 10;

/// Flags of `swarm export-mcap`.
#[derive(clap::Args, Debug, Clone)]
pub struct ExportArgs {
    /// A finished run's directory (it holds steps.log).
    pub run_dir: PathBuf,
    /// Where to write (default: RUN_DIR/run.mcap).
    #[arg(long)]
    pub out: Option<PathBuf>,
}

/// Messages written per topic.
pub type Counts = BTreeMap<String, u64>;

/// Writes the MCAP of the run in `args.run_dir`; returns where and the messages per topic.
pub fn export(args: &ExportArgs) -> anyhow::Result<(PathBuf, Counts)> {
    let log = steplog::read(&args.run_dir)?;
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

/// A JSON schema of ours for a Foxglove type: Foxglove recognises the type by its name; the
/// schema says what the fields are for any other reader.
fn schema(title: &str, properties: Value) -> Vec<u8> {
    json!({ "title": title, "type": "object", "properties": properties })
        .to_string()
        .into_bytes()
}

fn time(step: Step, step_seconds: f64) -> (u64, Value) {
    let ns = (f64::from(step) * step_seconds * 1e9).max(0.0) as u64;
    (
        ns,
        json!({ "sec": ns / 1_000_000_000, "nsec": ns % 1_000_000_000 }),
    )
}

fn position(x: f64, y: f64) -> Value {
    json!({ "x": x, "y": y, "z": 0.0 })
}

/// A rotation about z by `theta` as a quaternion.
fn yaw(theta: f64) -> Value {
    let h = theta / 2.0;
    json!({ "x": 0.0, "y": 0.0, "z": h.sin(), "w": h.cos() })
}

fn pose(x: f64, y: f64, theta: f64) -> Value {
    json!({ "position": position(x, y), "orientation": yaw(theta) })
}

/// A robot's colour, as the run's pictures draw it.
fn colour(id: RobotId, alpha: f64) -> Value {
    let [r, g, b] = crate::rundir::render::robot_colour(usize::from(id));
    json!({ "r": f64::from(r) / 255.0, "g": f64::from(g) / 255.0, "b": f64::from(b) / 255.0, "a": alpha })
}

/// A `foxglove.Grid` of `g` in ROS occupancy values (int8: unknown -1, free 0, occupied 100).
fn grid_message(g: &Grid, map: &MapInfo, stamp: &Value) -> Value {
    let data: Vec<u8> = g
        .cells()
        .iter()
        .map(|c| match c {
            Occ::Unknown => -1i8 as u8,
            Occ::Free => 0,
            Occ::Occupied => 100,
        })
        .collect();
    json!({
        "timestamp": stamp,
        "frame_id": "map",
        "pose": pose(map.origin_x_m, map.origin_y_m, 0.0),
        "column_count": map.width,
        "cell_size": { "x": map.resolution_m, "y": map.resolution_m },
        "row_stride": map.width,
        "cell_stride": 1,
        "fields": [{ "name": "occupancy", "offset": 0, "type": 2 }],
        "data": base64::engine::general_purpose::STANDARD.encode(data),
    })
}

/// An entity of a `foxglove.SceneUpdate` with only lines, arrows and texts.
fn entity(
    id: &str,
    stamp: &Value,
    lines: Vec<Value>,
    arrows: Vec<Value>,
    texts: Vec<Value>,
) -> Value {
    json!({
        "timestamp": stamp, "frame_id": "map", "id": id,
        "lifetime": { "sec": 0, "nsec": 0 }, "frame_locked": false, "metadata": [],
        "arrows": arrows, "cubes": [], "spheres": [], "cylinders": [], "lines": lines,
        "triangles": [], "texts": texts, "models": [],
    })
}

/// A line-list primitive through `points` (pairs).
fn lines(points: Vec<Value>, thickness: f64, colour: Value) -> Value {
    json!({
        "type": 2, "pose": pose(0.0, 0.0, 0.0), "thickness": thickness, "scale_invariant": true,
        "points": points, "color": colour, "colors": [], "indices": [],
    })
}

/// Where every robot stood at each step (from the world's status), to draw links.
type Where = BTreeMap<RobotId, (f64, f64)>;

struct Out<W: std::io::Write + std::io::Seek> {
    mcap: mcap::Writer<W>,
    channels: BTreeMap<String, u16>,
    schemas: BTreeMap<&'static str, u16>,
    counts: Counts,
}

impl<W: std::io::Write + std::io::Seek> Out<W> {
    /// A writer of MCAP to `w` with the schemas of every message it writes.
    fn create(w: W) -> anyhow::Result<Out<W>> {
        let mut out = Out {
            mcap: mcap::WriteOptions::new()
                .compression(None)
                .profile("")
                .create(w)?,
            channels: BTreeMap::new(),
            schemas: BTreeMap::new(),
            counts: Counts::new(),
        };
        for (name, props) in [
            (
                "foxglove.Grid",
                json!({ "timestamp": {"type": "object"}, "frame_id": {"type": "string"}, "pose": {"type": "object"}, "column_count": {"type": "integer"}, "cell_size": {"type": "object"}, "row_stride": {"type": "integer"}, "cell_stride": {"type": "integer"}, "fields": {"type": "array"}, "data": {"type": "string", "contentEncoding": "base64"} }),
            ),
            (
                "foxglove.PoseInFrame",
                json!({ "timestamp": {"type": "object"}, "frame_id": {"type": "string"}, "pose": {"type": "object"} }),
            ),
            (
                "foxglove.SceneUpdate",
                json!({ "deletions": {"type": "array"}, "entities": {"type": "array"} }),
            ),
            (
                "swarm.LinkBytes",
                json!({ "step": {"type": "integer"}, "links": {"type": "object", "description": "per link r<a>-r<b>: up, bytes_a_to_b, bytes_b_to_a, queued_bytes of the step"} }),
            ),
        ] {
            let id = out
                .mcap
                .add_schema(name, "jsonschema", &schema(name, props))?;
            out.schemas.insert(name, id);
        }
        Ok(out)
    }

    fn put(&mut self, topic: &str, schema: &'static str, ns: u64, v: &Value) -> anyhow::Result<()> {
        let channel = match self.channels.get(topic) {
            Some(&c) => c,
            None => {
                let s = self.schemas[schema];
                let c = self.mcap.add_channel(s, topic, "json", &BTreeMap::new())?;
                self.channels.insert(topic.to_string(), c);
                c
            }
        };
        let n = self.counts.entry(topic.to_string()).or_default();
        self.mcap.write_to_known_channel(
            &mcap::records::MessageHeader {
                channel_id: channel,
                sequence: *n as u32,
                log_time: ns,
                publish_time: ns,
            },
            &serde_json::to_vec(v)?,
        )?;
        *n += 1;
        Ok(())
    }
}

/// Writes `log` as MCAP to `w`; the messages per topic.
pub fn write<W: std::io::Write + std::io::Seek>(log: &StepLog, w: W) -> anyhow::Result<Counts> {
    let mut out = Out::create(w)?;
    let (map, dt) = (log.header.map, log.header.step_seconds);
    let (_, stamp0) = time(0, dt);
    out.put(
        "/map/truth",
        "foxglove.Grid",
        0,
        &grid_message(&log.header.truth(), &map, &stamp0),
    )?;
    let end = log.last_step();
    let mut grids = Grids::default();
    let mut reports: BTreeMap<RobotId, u32> = BTreeMap::new();
    let last_report = last_reports(log);
    let mut at: Where = BTreeMap::new();
    // Reports of one step, drawn together once the step's reports are all in.
    let mut step_robots: Vec<RobotStep> = Vec::new();
    for r in &log.records {
        match r {
            Record::Header(_) => {}
            Record::Poses { step, robots } => {
                if end.is_some_and(|e| *step > e.saturating_add(1)) {
                    continue;
                }
                at = robots
                    .iter()
                    .map(|p| (p.id, (f64::from(p.x), f64::from(p.y))))
                    .collect();
            }
            Record::Robot(rs, change) => {
                let grid = grids.apply(&map, rs, change).map_err(anyhow::Error::msg)?;
                let (ns, stamp) = time(rs.step, dt);
                let n = reports.entry(rs.robot).or_default();
                if n.is_multiple_of(GRID_EVERY) || last_report.get(&rs.robot) == Some(&rs.step) {
                    let m = grid_message(grid, &map, &stamp);
                    out.put(
                        &format!("/robot_{}/grid", rs.robot),
                        "foxglove.Grid",
                        ns,
                        &m,
                    )?;
                }
                *n += 1;
                let p = json!({ "timestamp": stamp, "frame_id": "map", "pose": pose(f64::from(rs.x), f64::from(rs.y), f64::from(rs.theta)) });
                out.put(
                    &format!("/robot_{}/pose", rs.robot),
                    "foxglove.PoseInFrame",
                    ns,
                    &p,
                )?;
                if step_robots.first().is_some_and(|f| f.step != rs.step) {
                    robots_scene(&mut out, &step_robots, dt)?;
                    step_robots.clear();
                }
                step_robots.push(rs.clone());
            }
            Record::Links { step, links } => {
                if end.is_some_and(|e| *step > e) {
                    continue;
                }
                links_scene(&mut out, *step, links, &at, dt)?;
            }
        }
    }
    robots_scene(&mut out, &step_robots, dt)?;
    out.mcap.finish()?;
    Ok(out.counts)
}

/// The step of every robot's last report in `log`.
fn last_reports(log: &StepLog) -> BTreeMap<RobotId, Step> {
    let mut last = BTreeMap::new();
    for r in &log.records {
        if let Record::Robot(r, _) = r {
            last.insert(r.robot, r.step);
        }
    }
    last
}

fn robots_scene<W: std::io::Write + std::io::Seek>(
    out: &mut Out<W>,
    robots: &[RobotStep],
    dt: f64,
) -> anyhow::Result<()> {
    let Some(first) = robots.first() else {
        return Ok(());
    };
    let (ns, stamp) = time(first.step, dt);
    let entities: Vec<Value> = robots
        .iter()
        .map(|r| {
            let (x, y) = (f64::from(r.x), f64::from(r.y));
            let arrow = json!({
                "pose": pose(x, y, f64::from(r.theta)), "shaft_length": 0.3, "shaft_diameter": 0.08,
                "head_length": 0.2, "head_diameter": 0.2, "color": colour(r.robot, 1.0),
            });
            let text = json!({
                "pose": pose(x, y + 0.4, 0.0), "billboard": true, "font_size": 14.0,
                "scale_invariant": true, "color": colour(r.robot, 1.0), "text": r.robot.to_string(),
            });
            let target = r.target.map(|(tx, ty)| {
                lines(
                    vec![position(x, y), position(f64::from(tx), f64::from(ty))],
                    1.0,
                    colour(r.robot, 0.6),
                )
            });
            entity(
                &format!("robot_{}", r.robot),
                &stamp,
                target.into_iter().collect(),
                vec![arrow],
                vec![text],
            )
        })
        .collect();
    out.put(
        "/robots",
        "foxglove.SceneUpdate",
        ns,
        &json!({ "deletions": [], "entities": entities }),
    )
}

fn links_scene<W: std::io::Write + std::io::Seek>(
    out: &mut Out<W>,
    step: Step,
    links: &[LinkStep],
    at: &Where,
    dt: f64,
) -> anyhow::Result<()> {
    let (ns, stamp) = time(step, dt);
    let mut prims = Vec::new();
    let mut bytes = serde_json::Map::new();
    for l in links {
        bytes.insert(
            format!("r{}-r{}", l.a, l.b),
            json!({ "up": l.up, "bytes_a_to_b": l.bytes_a_to_b, "bytes_b_to_a": l.bytes_b_to_a, "queued_bytes": l.queued_bytes }),
        );
        if let (true, Some(&(ax, ay)), Some(&(bx, by))) = (l.up, at.get(&l.a), at.get(&l.b)) {
            // Wider with more bytes: 1 px idle, about 1 px more per doubling.
            let per_step = (l.bytes_a_to_b + l.bytes_b_to_a) as f64;
            let thickness = 1.0 + (1.0 + per_step).log2() / 2.0;
            prims.push(lines(
                vec![position(ax, ay), position(bx, by)],
                thickness,
                json!({ "r": 0.1, "g": 0.6, "b": 0.2, "a": 0.8 }),
            ));
        }
    }
    let scene =
        json!({ "deletions": [], "entities": [entity("links", &stamp, prims, vec![], vec![])] });
    out.put("/links", "foxglove.SceneUpdate", ns, &scene)?;
    out.put(
        "/links/bytes",
        "swarm.LinkBytes",
        ns,
        &json!({ "step": step, "links": bytes }),
    )
}

/// The path of a run directory's MCAP file.
pub fn default_path(run_dir: &Path) -> PathBuf {
    run_dir.join("run.mcap")
}
