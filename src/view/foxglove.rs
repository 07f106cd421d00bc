//! A run in Foxglove, through Foxglove's official SDK (the `foxglove` crate): the step log's
//! records ([`crate::rundir::steplog`]) turned into messages of Foxglove's well-known schemas
//! (protobuf, as the SDK encodes them) and two plottable messages of ours, logged on the channels
//! of one SDK [`Context`](::foxglove::Context). What listens on the context decides where they go:
//! an MCAP file (`swarm export-mcap`, [`crate::view::export_mcap`]), or the SDK's WebSocket server
//! that Foxglove connects to, live while a run goes (`swarm run --foxglove`) or replaying a
//! finished one (`swarm view RUN_DIR --foxglove`).
//!
//! The topics, their schemas and when each is sent are listed once, for users, in
//! docs/guide/viewer.md; [`TEAM_TOPICS`](crate::view::foxglove::TEAM_TOPICS) and `Channels` are
//! what the code publishes.
//!
//! Times are the run's simulated clock (step × `clock.step_seconds`, from 0). Messages leave in
//! log-time order: a step's messages wait until the records of the step after next come (the
//! launcher takes a step's reports before the next step's, but the world's status of the next
//! step comes before the last of them), and no message is logged at a time before one already
//! logged. The frame is `map`: the map's metres, as in the scenario.

use std::collections::BTreeMap;
use std::sync::{Arc, Mutex};

use foxglove::bytes::Bytes;
use foxglove::messages::{
    line_primitive, packed_element_field, ArrowPrimitive, Color, FrameTransform, FrameTransforms,
    Grid as FoxGrid, LinePrimitive, PackedElementField, Point3, Pose, PoseInFrame, Quaternion,
    SceneEntity, SceneUpdate, TextPrimitive, Timestamp, Vector2, Vector3,
};
use foxglove::{Channel, Context, PartialMetadata};
use proto::geom::MapInfo;
use proto::grid::{Grid, Occ};
use proto::msg::{LinkAir, NodeAir, RobotId, Step};

use crate::rundir::steplog::{Grids, Header, LinkStep, Record, RobotStep};
use crate::view::timeline::{link_state, team_bytes};

/// The topics of the team (besides each robot's `/robot_<i>/grid` and `/robot_<i>/pose`).
pub const TEAM_TOPICS: [&str; 7] = [
    "/map/truth",
    "/tf",
    "/robots",
    "/trajectories",
    "/links",
    "/links/bytes",
    "/stats",
];

/// A robot's grid goes out every this many of its reports (and at its last, when known).
pub const GRID_EVERY: u32 = 10;
/// A robot's path goes out in pieces of this many reports; a finished piece stays drawn.
pub const TRAIL_PIECE: usize = 20;
/// A step's messages wait for records this many steps later before they go out.
const HOLD_STEPS: Step = 2;

/// Per link of a step, as netem reported it: plottable as
/// `/links/bytes.links[:]{name=="r0-r1"}.bytes_a_to_b`.
#[derive(foxglove::Encode, Clone, Debug, PartialEq)]
pub struct LinkBytes {
    pub step: u32,
    pub links: Vec<LinkStat>,
}

#[derive(foxglove::Encode, Clone, Debug, PartialEq)]
pub struct LinkStat {
    /// `r<a>-r<b>`, netem's proxy name.
    pub name: String,
    pub a: u32,
    pub b: u32,
    /// `up`, `blackhole`, or why it is down: `range`, `fault`, `dead`, `down`.
    pub state: String,
    pub bytes_a_to_b: u64,
    pub bytes_b_to_a: u64,
    pub queued_bytes: u64,
    /// The lower of its directions' probabilities that a frame is delivered (1 when netem
    /// reported no use of the radio channel for it).
    pub delivery: f32,
    /// How many of its directions lost their frame of the step (each is delivered a step late).
    pub frames_lost: u32,
}

/// A step's series, as the web viewer's charts draw them: plottable as `/stats.coverage_pct`,
/// `/stats.robots[:]{robot==0}.coverage_pct`, `/stats.bytes_by_class[:]{class=="ins"}.bytes`.
#[derive(foxglove::Encode, Clone, Debug, PartialEq)]
pub struct RunStats {
    pub step: u32,
    /// The best coverage of any robot, % of the reachable free cells.
    pub coverage_pct: f32,
    /// The largest backlog of any robot to any neighbour, bytes.
    pub backlog_max_bytes: u64,
    /// Payload bytes the team sent so far, per traffic class.
    pub bytes_by_class: Vec<ClassBytes>,
    /// The robots that reported the step.
    pub robots: Vec<RobotStats>,
}

#[derive(foxglove::Encode, Clone, Debug, PartialEq)]
pub struct ClassBytes {
    pub class: String,
    pub bytes: u64,
}

#[derive(foxglove::Encode, Clone, Debug, PartialEq)]
pub struct RobotStats {
    pub robot: u32,
    pub coverage_pct: f32,
    pub known_cells: u32,
    pub backlog_bytes: u64,
    pub bytes_sent: u64,
    pub bytes_received: u64,
    /// Polygon exchange: the splitting frequency for the next step (0 otherwise).
    pub splits_per_step: f32,
    /// Its use of the radio channel in the step, when netem shares it or loses frames (0
    /// otherwise): the airtime shares of its links, the airtime it used (bytes), how busy the
    /// channel was where it is (the airtime of every sender it hears over the channel's
    /// capacity), and its frames lost.
    pub airtime_share_bytes: u64,
    pub airtime_bytes: u64,
    pub channel_utilisation: f32,
    pub frames_lost: u32,
}

/// Messages written (or sent) per topic.
pub type Counts = BTreeMap<String, u64>;

/// A robot's channels.
struct RobotChannels {
    grid: Channel<FoxGrid>,
    pose: Channel<PoseInFrame>,
}

/// Every channel of a run, on one context.
struct Channels {
    truth: Channel<FoxGrid>,
    robots: BTreeMap<RobotId, RobotChannels>,
    tf: Channel<FrameTransforms>,
    scene: Channel<SceneUpdate>,
    trails: Channel<SceneUpdate>,
    links: Channel<SceneUpdate>,
    link_bytes: Channel<LinkBytes>,
    stats: Channel<RunStats>,
}

impl Channels {
    fn new(ctx: &Arc<Context>, robots: u16) -> Channels {
        let mut c = Channels {
            truth: ctx.channel_builder("/map/truth").build(),
            robots: BTreeMap::new(),
            tf: ctx.channel_builder("/tf").build(),
            scene: ctx.channel_builder("/robots").build(),
            trails: ctx.channel_builder("/trajectories").build(),
            links: ctx.channel_builder("/links").build(),
            link_bytes: ctx.channel_builder("/links/bytes").build(),
            stats: ctx.channel_builder("/stats").build(),
        };
        for id in 0..robots {
            c.robot(ctx, id);
        }
        c
    }

    fn robot(&mut self, ctx: &Arc<Context>, id: RobotId) -> &RobotChannels {
        self.robots.entry(id).or_insert_with(|| RobotChannels {
            grid: ctx.channel_builder(format!("/robot_{id}/grid")).build(),
            pose: ctx.channel_builder(format!("/robot_{id}/pose")).build(),
        })
    }
}

/// What one step sends, gathered as its records come.
#[derive(Default)]
struct StepOut {
    tf: Vec<FrameTransform>,
    poses: Vec<(RobotId, PoseInFrame)>,
    grids: Vec<(RobotId, FoxGrid)>,
    robots: Vec<SceneEntity>,
    trails: Vec<SceneEntity>,
    /// netem's links of the step, where the robots stood then; drawn when the step goes out,
    /// with the channel's use of the step if it comes.
    links: Option<(Vec<LinkStep>, Where, Timestamp)>,
    /// How the step used the radio channel: per node, per link.
    channel: Option<(Vec<NodeAir>, LinksAir)>,
    stats: Option<RunStats>,
}

/// What a live client gets when it subscribes: the truth, and each robot's latest grid.
#[derive(Default)]
pub struct Latest {
    truth: Option<FoxGrid>,
    grids: BTreeMap<RobotId, FoxGrid>,
}

/// Each link's use of the radio channel in a step, `(a, b, air)` ([`Record::Channel`]).
type LinksAir = Vec<(RobotId, RobotId, LinkAir)>;

/// Where every robot stood at the last status of the world, to draw links.
type Where = BTreeMap<RobotId, (f64, f64)>;

/// The step log turned into Foxglove messages on the channels of one context.
pub struct Scene {
    ctx: Arc<Context>,
    channels: Channels,
    map: MapInfo,
    step_seconds: f64,
    grids: Grids,
    /// Reports taken per robot, and the step of each robot's last report when known (a file).
    reports: BTreeMap<RobotId, u32>,
    last_report: BTreeMap<RobotId, Step>,
    /// Payload bytes per traffic class of every life of every robot, as last reported.
    sent: BTreeMap<(RobotId, u16), Vec<u64>>,
    /// Each robot's path piece being drawn: its number and its points.
    trails: BTreeMap<RobotId, (u32, Vec<Point3>)>,
    at: Where,
    pending: BTreeMap<Step, StepOut>,
    /// The latest log time logged (nothing goes out before it).
    logged_ns: u64,
    counts: Counts,
    latest: Arc<Mutex<Latest>>,
    /// Robot grids are built only when some sink takes them (live: a subscribed client).
    always: bool,
    /// A step's messages wait for records this many steps later ([`Scene::hold_back`]).
    hold: Step,
}

impl Scene {
    /// The scene of a run with `header`, on `ctx`; the truth goes out at once. `last_report`:
    /// each robot's last reported step, when known (a finished run), so its last grid goes
    /// out too. `always`: build every message even when no sink takes it (a file).
    pub fn new(
        ctx: &Arc<Context>,
        header: &Header,
        last_report: BTreeMap<RobotId, Step>,
        always: bool,
    ) -> Scene {
        let mut s = Scene {
            ctx: ctx.clone(),
            channels: Channels::new(ctx, header.robots),
            map: header.map,
            step_seconds: header.step_seconds,
            grids: Grids::default(),
            reports: BTreeMap::new(),
            last_report,
            sent: BTreeMap::new(),
            trails: BTreeMap::new(),
            at: Where::new(),
            pending: BTreeMap::new(),
            logged_ns: 0,
            counts: Counts::new(),
            latest: Arc::default(),
            always,
            hold: HOLD_STEPS,
        };
        s.log_truth(header);
        s
    }

    /// Starts the run again from its header (a replay's next play): the same channels, the
    /// truth sent again, nothing else remembered.
    pub fn restart(&mut self, header: &Header) {
        self.grids = Grids::default();
        self.reports.clear();
        self.sent.clear();
        self.trails.clear();
        self.at.clear();
        self.pending.clear();
        self.logged_ns = 0;
        *lock(&self.latest) = Latest::default();
        self.log_truth(header);
    }

    fn log_truth(&mut self, header: &Header) {
        let truth = grid_message(&header.truth(), &self.map, stamp(0));
        self.channels
            .truth
            .log_with_meta(&truth, PartialMetadata::with_log_time(0));
        *self.counts.entry("/map/truth".into()).or_default() += 1;
        lock(&self.latest).truth = Some(truth);
    }

    /// What a live client gets when it subscribes (see [`Subscribed`]).
    pub fn latest(&self) -> Arc<Mutex<Latest>> {
        self.latest.clone()
    }

    /// Messages logged so far, per topic.
    pub fn counts(&self) -> &Counts {
        &self.counts
    }

    fn ns(&self, step: Step) -> u64 {
        (f64::from(step) * self.step_seconds * 1e9).max(0.0) as u64
    }

    /// Takes the next record of the step log; an error names a record that does not fit (a
    /// grid change before a whole grid, a grid not of the map's size).
    pub fn push(&mut self, r: &Record) -> Result<(), String> {
        let step = match r {
            Record::Header(_) => return Ok(()),
            Record::Poses { step, robots } => {
                self.at = robots
                    .iter()
                    .map(|p| (p.id, (f64::from(p.x), f64::from(p.y))))
                    .collect();
                let ts = stamp(self.ns(*step));
                self.pending.entry(*step).or_default().tf = robots
                    .iter()
                    .filter(|p| p.alive)
                    .map(|p| FrameTransform {
                        timestamp: Some(ts),
                        parent_frame_id: "map".into(),
                        child_frame_id: format!("robot_{}", p.id),
                        translation: Some(vector(f64::from(p.x), f64::from(p.y))),
                        rotation: Some(yaw(f64::from(p.theta))),
                    })
                    .collect();
                *step
            }
            Record::Robot(rs, change) => {
                let ts = stamp(self.ns(rs.step));
                let grid = self.grids.apply(&self.map, rs, change)?;
                let n = self.reports.entry(rs.robot).or_default();
                let due = n.is_multiple_of(GRID_EVERY)
                    || self.last_report.get(&rs.robot) == Some(&rs.step);
                *n += 1;
                let channels = self.channels.robot(&self.ctx, rs.robot);
                let wanted = self.always || channels.grid.has_sinks();
                let grid = (due && wanted).then(|| grid_message(grid, &self.map, ts));
                if let Some(g) = &grid {
                    lock(&self.latest).grids.insert(rs.robot, g.clone());
                }
                self.sent
                    .insert((rs.robot, rs.life), rs.sent_by_type.clone());
                let trail = self.trail(rs, ts);
                let by_class = team_bytes(&self.sent);
                let out = self.pending.entry(rs.step).or_default();
                if let Some(g) = grid {
                    out.grids.push((rs.robot, g));
                }
                out.poses.push((
                    rs.robot,
                    PoseInFrame {
                        timestamp: Some(ts),
                        frame_id: "map".into(),
                        pose: Some(pose(f64::from(rs.x), f64::from(rs.y), f64::from(rs.theta))),
                    },
                ));
                out.robots.push(robot_entity(rs, ts));
                out.trails.push(trail);
                add_stats(&mut out.stats, rs, by_class);
                rs.step
            }
            Record::Links { step, links } => {
                let ts = stamp(self.ns(*step));
                self.pending.entry(*step).or_default().links =
                    Some((links.clone(), self.at.clone(), ts));
                *step
            }
            Record::Channel {
                step, nodes, links, ..
            } => {
                self.pending.entry(*step).or_default().channel =
                    Some((nodes.clone(), links.clone()));
                *step
            }
        };
        self.flush_before(step.saturating_sub(self.hold));
        Ok(())
    }

    /// Robot `rs.robot`'s current path piece with this report's point added.
    fn trail(&mut self, rs: &RobotStep, ts: Timestamp) -> SceneEntity {
        let p = Point3 {
            x: f64::from(rs.x),
            y: f64::from(rs.y),
            z: 0.0,
        };
        let (k, points) = self.trails.entry(rs.robot).or_default();
        if points.len() >= TRAIL_PIECE {
            // The finished piece stays as it was last sent; the next one starts where it ended.
            let last = points.last().copied();
            *k += 1;
            points.clear();
            points.extend(last);
        }
        points.push(p);
        entity(
            &format!("trail_{}_{}", rs.robot, k),
            ts,
            vec![line_strip(points.clone(), 2.0, colour(rs.robot, 0.7))],
            vec![],
            vec![],
        )
    }

    /// Logs every gathered step before `step`, in step order.
    fn flush_before(&mut self, step: Step) {
        while let Some(entry) = self.pending.first_entry() {
            if *entry.key() >= step {
                break;
            }
            let (s, out) = entry.remove_entry();
            self.log_step(s, out);
        }
    }

    /// Holds each step back until records `steps` steps later have come (at least [`HOLD_STEPS`]):
    /// a finished run's [`StepLog::lateness`](crate::rundir::steplog::StepLog::lateness), so that
    /// every record goes out with its step.
    pub fn hold_back(&mut self, steps: Step) {
        self.hold = steps.max(HOLD_STEPS);
    }

    /// Logs every step still gathered (the run has ended).
    pub fn finish(&mut self) {
        self.flush_before(Step::MAX);
    }

    fn log_step(&mut self, step: Step, mut out: StepOut) {
        let ns = self.ns(step).max(self.logged_ns);
        self.logged_ns = ns;
        let meta = || PartialMetadata::with_log_time(ns);
        let mut counted = |topic: &str| *self.counts.entry(topic.to_string()).or_default() += 1;
        let c = &self.channels;
        if !out.tf.is_empty() {
            c.tf.log_with_meta(&FrameTransforms { transforms: out.tf }, meta());
            counted("/tf");
        }
        for (id, p) in out.poses {
            if let Some(rc) = c.robots.get(&id) {
                rc.pose.log_with_meta(&p, meta());
                counted(&format!("/robot_{id}/pose"));
            }
        }
        for (id, g) in out.grids {
            if let Some(rc) = c.robots.get(&id) {
                rc.grid.log_with_meta(&g, meta());
                counted(&format!("/robot_{id}/grid"));
            }
        }
        if !out.robots.is_empty() {
            c.scene.log_with_meta(
                &SceneUpdate {
                    deletions: vec![],
                    entities: out.robots,
                },
                meta(),
            );
            counted("/robots");
            c.trails.log_with_meta(
                &SceneUpdate {
                    deletions: vec![],
                    entities: out.trails,
                },
                meta(),
            );
            counted("/trajectories");
        }
        let (nodes, air) = out.channel.unwrap_or_default();
        if let Some(stats) = &mut out.stats {
            add_air(stats, &nodes);
        }
        if let Some((links, at, ts)) = out.links {
            let (scene, bytes) = links_messages(step, &links, &air, &at, ts);
            c.links.log_with_meta(&scene, meta());
            counted("/links");
            c.link_bytes.log_with_meta(&bytes, meta());
            counted("/links/bytes");
        }
        if let Some(stats) = out.stats {
            c.stats.log_with_meta(&stats, meta());
            counted("/stats");
        }
    }
}

fn lock<T>(m: &Mutex<T>) -> std::sync::MutexGuard<'_, T> {
    m.lock().unwrap_or_else(std::sync::PoisonError::into_inner)
}

/// Sends a live client what it missed when it subscribes: the truth map, and a robot's latest
/// grid (grids otherwise go out every [`GRID_EVERY`] reports).
pub struct Subscribed {
    pub ctx: Arc<Context>,
    pub latest: Arc<Mutex<Latest>>,
}

impl foxglove::websocket::ServerListener for Subscribed {
    fn on_subscribe(
        &self,
        client: foxglove::websocket::Client,
        channel: foxglove::websocket::ChannelView,
    ) {
        let topic = channel.topic();
        let latest = lock(&self.latest);
        let grid = if topic == "/map/truth" {
            latest.truth.as_ref()
        } else {
            topic
                .strip_prefix("/robot_")
                .and_then(|t| t.strip_suffix("/grid"))
                .and_then(|id| id.parse::<RobotId>().ok())
                .and_then(|id| latest.grids.get(&id))
        };
        if let (Some(g), Some(ch)) = (grid, self.ctx.get_channel_by_topic(topic)) {
            let mut buf = Vec::new();
            if foxglove::Encode::encode(g, &mut buf).is_ok() {
                let ns = g.timestamp.map_or(0, |t| t.total_nanos());
                ch.log_with_meta_to_sink(
                    &buf,
                    PartialMetadata::with_log_time(ns),
                    client.sink_id(),
                );
            }
        }
    }
}

fn stamp(ns: u64) -> Timestamp {
    Timestamp::new(
        u32::try_from(ns / 1_000_000_000).unwrap_or(u32::MAX),
        (ns % 1_000_000_000) as u32,
    )
}

fn vector(x: f64, y: f64) -> Vector3 {
    Vector3 { x, y, z: 0.0 }
}

/// A rotation about z by `theta` as a quaternion.
fn yaw(theta: f64) -> Quaternion {
    let h = theta / 2.0;
    Quaternion {
        x: 0.0,
        y: 0.0,
        z: h.sin(),
        w: h.cos(),
    }
}

fn pose(x: f64, y: f64, theta: f64) -> Pose {
    Pose {
        position: Some(vector(x, y)),
        orientation: Some(yaw(theta)),
    }
}

fn point(x: f64, y: f64) -> Point3 {
    Point3 { x, y, z: 0.0 }
}

/// A robot's colour, as the run's pictures draw it.
fn colour(id: RobotId, a: f64) -> Color {
    let [r, g, b] = crate::rundir::render::robot_colour(usize::from(id));
    Color {
        r: f64::from(r) / 255.0,
        g: f64::from(g) / 255.0,
        b: f64::from(b) / 255.0,
        a,
    }
}

/// A `foxglove.Grid` of `g` in ROS occupancy values (int8: unknown -1, free 0, occupied 100).
pub fn grid_message(g: &Grid, map: &MapInfo, ts: Timestamp) -> FoxGrid {
    let data: Vec<u8> = g
        .cells()
        .iter()
        .map(|c| match c {
            Occ::Unknown => -1i8 as u8,
            Occ::Free => 0,
            Occ::Occupied => 100,
        })
        .collect();
    FoxGrid {
        timestamp: Some(ts),
        frame_id: "map".into(),
        pose: Some(pose(map.origin_x_m, map.origin_y_m, 0.0)),
        column_count: map.width,
        cell_size: Some(Vector2 {
            x: map.resolution_m,
            y: map.resolution_m,
        }),
        row_stride: map.width,
        cell_stride: 1,
        fields: vec![PackedElementField {
            name: "occupancy".into(),
            offset: 0,
            r#type: packed_element_field::NumericType::Int8 as i32,
        }],
        data: Bytes::from(data),
    }
}

/// An entity of a `foxglove.SceneUpdate` with only lines, arrows and texts.
fn entity(
    id: &str,
    ts: Timestamp,
    lines: Vec<LinePrimitive>,
    arrows: Vec<ArrowPrimitive>,
    texts: Vec<TextPrimitive>,
) -> SceneEntity {
    SceneEntity {
        timestamp: Some(ts),
        frame_id: "map".into(),
        id: id.into(),
        lines,
        arrows,
        texts,
        ..SceneEntity::default()
    }
}

fn line(
    kind: line_primitive::Type,
    points: Vec<Point3>,
    thickness: f64,
    c: Color,
) -> LinePrimitive {
    LinePrimitive {
        r#type: kind as i32,
        pose: Some(pose(0.0, 0.0, 0.0)),
        thickness,
        scale_invariant: true,
        points,
        color: Some(c),
        ..LinePrimitive::default()
    }
}

fn line_strip(points: Vec<Point3>, thickness: f64, c: Color) -> LinePrimitive {
    line(line_primitive::Type::LineStrip, points, thickness, c)
}

/// A robot's arrow, its id, and a line to its target.
fn robot_entity(r: &RobotStep, ts: Timestamp) -> SceneEntity {
    let (x, y) = (f64::from(r.x), f64::from(r.y));
    let arrow = ArrowPrimitive {
        pose: Some(pose(x, y, f64::from(r.theta))),
        shaft_length: 0.3,
        shaft_diameter: 0.08,
        head_length: 0.2,
        head_diameter: 0.2,
        color: Some(colour(r.robot, 1.0)),
    };
    let text = TextPrimitive {
        pose: Some(pose(x, y + 0.4, 0.0)),
        billboard: true,
        font_size: 14.0,
        scale_invariant: true,
        color: Some(colour(r.robot, 1.0)),
        text: r.robot.to_string(),
    };
    let target = r.target.map(|(tx, ty)| {
        line(
            line_primitive::Type::LineList,
            vec![point(x, y), point(f64::from(tx), f64::from(ty))],
            1.0,
            colour(r.robot, 0.6),
        )
    });
    entity(
        &format!("robot_{}", r.robot),
        ts,
        target.into_iter().collect(),
        vec![arrow],
        vec![text],
    )
}

/// A step's `/stats`, with report `rs` of the step taken in.
fn add_stats(stats: &mut Option<RunStats>, rs: &RobotStep, by_class: Vec<(&str, u64)>) {
    let s = stats.get_or_insert_with(|| RunStats {
        step: rs.step,
        coverage_pct: 0.0,
        backlog_max_bytes: 0,
        bytes_by_class: vec![],
        robots: vec![],
    });
    s.coverage_pct = s.coverage_pct.max(rs.coverage_pct.unwrap_or(0.0));
    s.backlog_max_bytes = s.backlog_max_bytes.max(rs.backlog_bytes);
    s.bytes_by_class = by_class
        .into_iter()
        .map(|(class, bytes)| ClassBytes {
            class: class.into(),
            bytes,
        })
        .collect();
    s.robots.push(RobotStats {
        robot: u32::from(rs.robot),
        coverage_pct: rs.coverage_pct.unwrap_or(0.0),
        known_cells: rs.known_cells,
        backlog_bytes: rs.backlog_bytes,
        bytes_sent: rs.bytes_sent,
        bytes_received: rs.bytes_received,
        splits_per_step: rs.splits_per_step.unwrap_or(0.0),
        airtime_share_bytes: 0,
        airtime_bytes: 0,
        channel_utilisation: 0.0,
        frames_lost: 0,
    });
}

/// Each robot's use of the radio channel in a step (`nodes`, netem's report) into its `/stats`.
fn add_air(stats: &mut RunStats, nodes: &[NodeAir]) {
    for r in &mut stats.robots {
        if let Some(n) = nodes.iter().find(|n| u32::from(n.id) == r.robot) {
            r.airtime_share_bytes = n.share;
            r.airtime_bytes = n.airtime;
            r.channel_utilisation = n.utilisation;
            r.frames_lost = n.frames_lost;
        }
    }
}

/// A link that is up: green, wider with more bytes; orange to red when it may lose frames
/// (redder the lower its delivery probability).
fn link_colour(delivery: f32) -> Color {
    if delivery < 1.0 {
        Color {
            r: 0.95,
            g: 0.55 * f64::from(delivery.max(0.0)),
            b: 0.1,
            a: 0.9,
        }
    } else {
        Color {
            r: 0.1,
            g: 0.6,
            b: 0.2,
            a: 0.8,
        }
    }
}

/// `/links` and `/links/bytes` of a step, with how its links used the radio channel (`air`):
/// a link that may lose frames drawn in orange to red, one that lost a frame in the step marked
/// "lost" at its middle.
fn links_messages(
    step: Step,
    links: &[LinkStep],
    air: &[(RobotId, RobotId, LinkAir)],
    at: &Where,
    ts: Timestamp,
) -> (SceneUpdate, LinkBytes) {
    let mut prims = Vec::new();
    let mut texts = Vec::new();
    let mut stats = Vec::new();
    for l in links {
        let x = air
            .iter()
            .find(|(a, b, _)| (*a, *b) == (l.a, l.b))
            .map(|(_, _, x)| x);
        let delivery = x.map_or(1.0, |x| x.delivery[0].min(x.delivery[1]));
        let lost = x.map_or(0, |x| x.lost.iter().filter(|&&l| l).count() as u32);
        stats.push(LinkStat {
            name: format!("r{}-r{}", l.a, l.b),
            a: u32::from(l.a),
            b: u32::from(l.b),
            state: link_state(l).into(),
            bytes_a_to_b: l.bytes_a_to_b,
            bytes_b_to_a: l.bytes_b_to_a,
            queued_bytes: l.queued_bytes,
            delivery,
            frames_lost: lost,
        });
        if let (true, Some(&(ax, ay)), Some(&(bx, by))) = (l.up, at.get(&l.a), at.get(&l.b)) {
            // Wider with more bytes: 1 px idle, about 1 px more per doubling.
            let per_step = (l.bytes_a_to_b + l.bytes_b_to_a) as f64;
            let thickness = 1.0 + (1.0 + per_step).log2() / 2.0;
            prims.push(line(
                line_primitive::Type::LineList,
                vec![point(ax, ay), point(bx, by)],
                thickness,
                link_colour(delivery),
            ));
            if lost > 0 {
                texts.push(TextPrimitive {
                    pose: Some(pose((ax + bx) / 2.0, (ay + by) / 2.0, 0.0)),
                    billboard: true,
                    font_size: 12.0,
                    scale_invariant: true,
                    color: Some(Color {
                        r: 0.85,
                        g: 0.1,
                        b: 0.1,
                        a: 1.0,
                    }),
                    text: "lost".into(),
                });
            }
        }
    }
    let scene = SceneUpdate {
        deletions: vec![],
        entities: vec![entity("links", ts, prims, vec![], texts)],
    };
    (scene, LinkBytes { step, links: stats })
}

/// Messages a live client may fall behind by before the server drops its oldest (the SDK's
/// per-client queue): a slow or absent client never slows the run.
pub const CLIENT_BACKLOG: usize = 4096;

/// A run served over the Foxglove WebSocket protocol by the SDK's server.
pub struct Server {
    pub addr: std::net::SocketAddr,
    handle: foxglove::WebSocketServerHandle,
    scene: Arc<Mutex<Scene>>,
}

impl Server {
    /// Serves `header`'s run on `addr` (port 0: any free port) under `name` (what Foxglove
    /// shows of the server). Records come through [`Server::feed`].
    pub async fn start(
        addr: std::net::SocketAddr,
        header: &Header,
        last_report: BTreeMap<RobotId, Step>,
        name: &str,
    ) -> anyhow::Result<Server> {
        let ctx = Context::new();
        let scene = Scene::new(&ctx, header, last_report, false);
        let listener = Subscribed {
            ctx: ctx.clone(),
            latest: scene.latest(),
        };
        let handle = foxglove::WebSocketServer::new()
            .name(name)
            .bind(addr.ip().to_string(), addr.port())
            .context(&ctx)
            .listener(Arc::new(listener))
            .message_backlog_size(CLIENT_BACKLOG)
            .start()
            .await
            .map_err(|e| {
                anyhow::anyhow!("cannot serve Foxglove's WebSocket protocol on {addr}: {e}")
            })?;
        let addr = std::net::SocketAddr::new(addr.ip(), handle.port());
        Ok(Server {
            addr,
            handle,
            scene: Arc::new(Mutex::new(scene)),
        })
    }

    /// What takes the step log's records (the launcher's tee): a record that does not fit is
    /// left out (the file keeps it; `swarm export-mcap` names it).
    pub fn feed(&self) -> impl FnMut(&Record) + Send + 'static {
        let scene = self.scene.clone();
        move |r| {
            let _ = lock(&scene).push(r);
        }
    }

    /// Clients connected now.
    pub fn clients(&self) -> usize {
        self.handle.client_count()
    }

    /// Sends what is still gathered and stops serving; the messages sent per topic.
    pub async fn stop(self) -> Counts {
        let counts = {
            let mut s = lock(&self.scene);
            s.finish();
            s.counts().clone()
        };
        self.handle.stop().wait().await;
        counts
    }

    /// Replays `log` to the clients at `steps_per_second`, from the first client's connect, and
    /// again from the start after the end while a client is connected (each play a new session,
    /// so Foxglove starts afresh); until the task is dropped.
    pub async fn replay(
        addr: std::net::SocketAddr,
        log: &crate::rundir::steplog::StepLog,
        steps_per_second: f64,
        name: &str,
        ready: impl FnOnce(std::net::SocketAddr),
    ) -> anyhow::Result<()> {
        let last = last_reports(log);
        let server = Server::start(addr, &log.header, last, name).await?;
        lock(&server.scene).hold_back(log.lateness());
        ready(server.addr);
        let pause = std::time::Duration::from_secs_f64(1.0 / steps_per_second.max(0.01));
        for play in 1u32.. {
            while server.clients() == 0 {
                tokio::time::sleep(std::time::Duration::from_millis(100)).await;
            }
            let mut at: Option<Step> = None;
            for r in &log.records {
                let step = r.step();
                if let (Some(s), Some(a)) = (step, at) {
                    if s > a {
                        tokio::time::sleep(pause * (s - a)).await;
                    }
                }
                at = step.max(at);
                let _ = lock(&server.scene).push(r);
            }
            lock(&server.scene).finish();
            // The next play: a fresh scene (the truth again) in a new session.
            tokio::time::sleep(std::time::Duration::from_secs(2)).await;
            server.handle.clear_session(Some(format!("replay-{play}")));
            lock(&server.scene).restart(&log.header);
        }
        Ok(())
    }
}

/// The step of every robot's last report in `log`.
pub fn last_reports(log: &crate::rundir::steplog::StepLog) -> BTreeMap<RobotId, Step> {
    let mut last = BTreeMap::new();
    for r in &log.records {
        if let Record::Robot(r, _) = r {
            last.insert(r.robot, r.step);
        }
    }
    last
}

#[cfg(test)]
mod tests {
    use super::*;

    fn link(a: RobotId, b: RobotId) -> LinkStep {
        LinkStep {
            a,
            b,
            up: true,
            bytes_a_to_b: 10,
            bytes_b_to_a: 0,
            queued_bytes: 0,
            cut: None,
        }
    }

    #[test]
    fn a_link_that_may_lose_frames_is_drawn_apart_and_one_that_lost_a_frame_marked() {
        let at: Where = [(0, (0.0, 0.0)), (1, (2.0, 0.0)), (2, (0.0, 2.0))].into();
        let air = LinkAir {
            share: [None, None],
            airtime: [10, 0],
            lost: [false, true],
            delivery: [0.5, 0.8],
        };
        let (scene, bytes) =
            links_messages(7, &[link(0, 1), link(0, 2)], &[(0, 1, air)], &at, stamp(0));
        let e = &scene.entities[0];
        let colours: Vec<Color> = e.lines.iter().filter_map(|l| l.color).collect();
        assert_eq!(colours[1], link_colour(1.0), "no air: as ever");
        assert_ne!(colours[0], colours[1], "lossy: apart");
        assert_eq!(colours[0], link_colour(0.5));
        assert_eq!(e.texts.len(), 1, "one link lost a frame");
        assert_eq!(
            e.texts[0].pose.and_then(|p| p.position).map(|p| p.x),
            Some(1.0)
        );
        let stat = |i: usize| (bytes.links[i].delivery, bytes.links[i].frames_lost);
        assert_eq!((stat(0), stat(1)), ((0.5, 1), (1.0, 0)));
    }

    #[test]
    fn a_robots_stats_carry_its_use_of_the_channel() {
        let mut stats = RunStats {
            step: 3,
            coverage_pct: 0.0,
            backlog_max_bytes: 0,
            bytes_by_class: vec![],
            robots: vec![],
        };
        let rs = RobotStep {
            step: 3,
            robot: 1,
            life: 0,
            x: 0.0,
            y: 0.0,
            theta: 0.0,
            target: None,
            idle: false,
            known_cells: 0,
            bytes_sent: 0,
            bytes_received: 0,
            splits_per_step: None,
            backlog_bytes: 0,
            sent_by_type: vec![],
            views: vec![],
            coverage_pct: None,
        };
        let mut some = Some(stats.clone());
        add_stats(&mut some, &rs, vec![]);
        stats = some.expect("test");
        add_air(
            &mut stats,
            &[NodeAir {
                id: 1,
                share: 300,
                airtime: 250,
                utilisation: 0.8,
                frames_lost: 2,
                retransmitted: 40,
            }],
        );
        let r = &stats.robots[0];
        assert_eq!(
            (r.airtime_share_bytes, r.airtime_bytes, r.frames_lost),
            (300, 250, 2)
        );
        assert_eq!(r.channel_utilisation, 0.8);
    }

    /// The layout shipped for Foxglove names only topics a run has.
    #[test]
    fn the_shipped_layout_names_only_topics_a_run_has() {
        let layout: serde_json::Value =
            serde_json::from_str(include_str!("../../assets/foxglove/layout.json"))
                .expect("the layout is JSON");
        let known = |t: &str| {
            super::TEAM_TOPICS.contains(&t)
                || t.strip_prefix("/robot_")
                    .and_then(|r| r.split_once('/'))
                    .is_some_and(|(id, kind)| {
                        id.parse::<u16>().is_ok() && ["grid", "pose"].contains(&kind)
                    })
        };
        let mut named = Vec::new();
        for panel in layout["configById"].as_object().expect("panels").values() {
            if let Some(topics) = panel["topics"].as_object() {
                named.extend(topics.keys().cloned());
            }
            for p in panel["paths"].as_array().into_iter().flatten() {
                let v = p["value"].as_str().expect("a path");
                let topic = v.split(['.', '[']).next().unwrap_or(v);
                named.push(topic.to_string());
            }
        }
        assert!(!named.is_empty());
        for t in &named {
            assert!(known(t), "the layout names {t}, which no run publishes");
        }
    }
}
