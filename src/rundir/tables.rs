//! The run directory's tables (`metrics.csv`, `links.csv`, `saves.csv`, `views.csv`,
//! `traffic.csv`, …) as serde rows. Each row type is written and read back through the same type.

use std::collections::BTreeMap;
use std::path::Path;

use anyhow::Context;
use proto::msg::{LinkState, NodeAir, RobotId, Step, Traffic};
use serde::{Deserialize, Serialize};

use crate::rundir::summary::*;

/// A row of `metrics.csv`: one robot's step as the evaluator scored it. The evaluator builds it
/// from the robot's telemetry ([`crate::score::evaluate`]), the launcher fills in the team columns,
/// and every reader reads the table back through this type (numbers are kept in memory as
/// computed and written with the precision the schema keeps).
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct MetricsRow {
    pub step: Step,
    pub robot: RobotId,
    /// Where the robot stood (metres).
    #[serde(serialize_with = "fixed::<3, _>")]
    pub x: f64,
    #[serde(serialize_with = "fixed::<3, _>")]
    pub y: f64,
    pub known_cells: u32,
    pub correct_known_cells: u32,
    /// The robot's target (metres); empty when it has none.
    #[serde(serialize_with = "fixed_opt::<3, _>")]
    pub target_x: Option<f64>,
    #[serde(serialize_with = "fixed_opt::<3, _>")]
    pub target_y: Option<f64>,
    pub bytes_sent: u64,
    pub bytes_received: u64,
    #[serde(serialize_with = "fixed::<3, _>")]
    pub coverage_pct: f64,
    #[serde(with = "flag")]
    pub idle: bool,
    pub neighbours: usize,
    /// The splitting frequency for the next step (polygon exchange).
    #[serde(serialize_with = "fixed_opt::<4, _>")]
    pub splits_per_step: Option<f64>,
    /// The largest backlog of any neighbour after the step's sending (bytes that waited).
    pub backlog_bytes: u64,
    /// `bids`: the robot decided alone (no fresh assignment from the executive).
    #[serde(with = "flag")]
    pub alone: bool,
    /// Team awareness (de Hoog et al. 2010, Fig. 5c): the share of this robot's known space that
    /// every robot knows; empty on the base station's rows. The columns from here on came
    /// later: tables written before them read back as empty (or 0).
    #[serde(serialize_with = "fixed_opt::<3, _>", default)]
    pub shared_pct: Option<f64>,
    /// Fig. 5d: steps since this robot's last contact with the base station, set once netem's
    /// report of the step is in; empty on the base station's rows and without a base station.
    #[serde(default)]
    pub steps_since_base: Option<Step>,
    /// Fig. 5a: the percentage of the reachable free cells that at least one robot knows (the
    /// union of the team's known space; the same on every robot row of a step in lockstep);
    /// empty on the base station's rows.
    #[serde(serialize_with = "fixed_opt::<3, _>", default)]
    pub team_pct: Option<f64>,
    /// Rooker and Birk 2005, Fig. 6: the percentage of robot pairs that can reach each other
    /// over the step's links (netem's `up`), directly or through others, set once netem's report
    /// of the step is in; empty on the base station's rows.
    #[serde(serialize_with = "fixed_opt::<3, _>", default)]
    pub comm_level_pct: Option<f64>,
    /// Map fidelity ([`crate::score::fidelity`]): the cells the planning grid holds free, those
    /// of them not free in the truth, and those of them occupied in the truth.
    #[serde(default)]
    pub free_cells: u32,
    #[serde(default)]
    pub false_free_cells: u32,
    #[serde(default)]
    pub on_wall_cells: u32,
    /// `false_free_cells` and `on_wall_cells` as percentages of `free_cells` (empty when the
    /// grid holds no free cell).
    #[serde(serialize_with = "fixed_opt::<3, _>", default)]
    pub false_free_pct: Option<f64>,
    #[serde(serialize_with = "fixed_opt::<3, _>", default)]
    pub on_walls_pct: Option<f64>,
    /// Payload bytes sent so far per traffic class ([`Traffic::ALL`] order): no column here
    /// (`traffic_by_type.csv` has them per step), empty when read back.
    #[serde(skip)]
    pub sent_by_type: Vec<u64>,
}

/// The run's per-step tables, written a step at a time as the run goes ([`StepTables::step`]):
/// `metrics.csv` (by step and robot), `traffic_by_type.csv` (the same), `saves.csv` and
/// `views.csv` (in the order reported), `links.csv` (by step and pair; a pair reported twice in
/// a step in arrival order) and — when netem shares the channel or loses frames (`radio.medium`
/// `shared`/`airtime`, `radio.frame_loss`, `radio.fading_db`) — `channel_nodes.csv` and
/// `channel_links.csv`, created with the first step that has them.
pub struct StepTables {
    dir: std::path::PathBuf,
    metrics: TableWriter,
    traffic: TableWriter,
    saves: TableWriter,
    views: TableWriter,
    links: TableWriter,
    /// `channel_nodes.csv` and `channel_links.csv`, once a step had them.
    channel: Option<(TableWriter, TableWriter)>,
    /// Per robot, its payload per class as of its last row written (for the per-step
    /// differences of `traffic_by_type.csv`).
    sent: BTreeMap<RobotId, Vec<u64>>,
}

/// One step of the run for [`StepTables::step`].
#[derive(Default)]
pub struct StepRows {
    pub step: Step,
    /// Its `metrics.csv` rows (any order: written by robot, robots reported twice in order).
    pub metrics: Vec<MetricsRow>,
    /// Save points and view changes reported at the step, in order.
    pub saves: Vec<(RobotId, u32, u64)>,
    pub views: Vec<(RobotId, proto::msg::View)>,
    /// netem's link states of the step, in arrival order, and its nodes' use of the channel.
    pub links: Vec<LinkState>,
    pub nodes: Vec<NodeAir>,
}

impl StepTables {
    /// Creates the tables (their headers) in `dir`.
    pub fn create(dir: &Path) -> anyhow::Result<StepTables> {
        let traffic_header = ["step", "robot"]
            .into_iter()
            .chain(Traffic::ALL.iter().map(|t| t.name()));
        Ok(StepTables {
            dir: dir.to_path_buf(),
            metrics: TableWriter::create::<MetricsRow>(&dir.join("metrics.csv"))?,
            // The class columns come from one list (serde names a sequence field's columns
            // no way).
            traffic: TableWriter::with_header(&dir.join("traffic_by_type.csv"), traffic_header)?,
            saves: TableWriter::create::<SaveCsv>(&dir.join("saves.csv"))?,
            views: TableWriter::create::<ViewCsv>(&dir.join("views.csv"))?,
            links: TableWriter::create::<LinkCsv>(&dir.join("links.csv"))?,
            channel: None,
            sent: BTreeMap::new(),
        })
    }

    /// Writes one step's rows and puts them on disk. A step is written once, after the steps
    /// before it (a step written again comes after the later ones).
    pub fn step(&mut self, s: &mut StepRows) -> anyhow::Result<()> {
        let step = s.step;
        s.metrics.sort_by_key(|r| r.robot);
        for r in &s.metrics {
            self.metrics.row(r)?;
        }
        for r in &s.metrics {
            let row = self.traffic_row(r);
            self.traffic.row(row)?;
        }
        for &(robot, log_len, digest) in &s.saves {
            self.saves.row(SaveCsv {
                step,
                robot,
                log_len,
                digest: Hex(digest),
            })?;
        }
        for &(robot, v) in &s.views {
            self.views.row(ViewCsv::of(step, robot, v))?;
        }
        s.links.sort_by_key(|l| (l.a, l.b));
        for l in &s.links {
            self.links.row(LinkCsv::of(step, l))?;
        }
        if !s.nodes.is_empty() && self.channel.is_none() {
            self.channel = Some((
                TableWriter::create::<ChannelNodeCsv>(&self.dir.join("channel_nodes.csv"))?,
                TableWriter::create::<ChannelLinkCsv>(&self.dir.join("channel_links.csv"))?,
            ));
        }
        if let Some((nodes, links)) = &mut self.channel {
            s.nodes.sort_by_key(|n| n.id);
            for n in &s.nodes {
                nodes.row(ChannelNodeCsv::of(step, n))?;
            }
            for l in s.links.iter().filter_map(|l| ChannelLinkCsv::of(step, l)) {
                links.row(l)?;
            }
            nodes.flush()?;
            links.flush()?;
        }
        for t in [
            &mut self.metrics,
            &mut self.traffic,
            &mut self.saves,
            &mut self.views,
            &mut self.links,
        ] {
            t.flush()?;
        }
        Ok(())
    }

    /// A robot's payload per class during the step of `r`: what it sent so far less what its
    /// previous row had (a counter that fell — a restarted robot — counts from 0).
    fn traffic_row(&mut self, r: &MetricsRow) -> TrafficCsv {
        let prev = self.sent.insert(r.robot, r.sent_by_type.clone());
        let bytes = (r.sent_by_type.iter().enumerate())
            .map(|(i, &now)| {
                let before = prev.as_ref().and_then(|p| p.get(i)).copied().unwrap_or(0);
                now.saturating_sub(before)
            })
            .collect();
        TrafficCsv {
            step: r.step,
            robot: r.robot,
            bytes,
        }
    }
}

/// What `summary.json` needs of netem's link reports, tallied report by report as their steps
/// are written ([`crate::run`]'s tables); the reports themselves are not kept (netem reports
/// every pair in range every step: a run's reports grow with steps × pairs).
#[derive(Default)]
pub struct LinkTally {
    /// Per pair: the totals of netem's earlier lives, and the current one's (a restarted netem
    /// counts from zero again: a pair's total that falls starts a new count).
    wire: BTreeMap<(RobotId, RobotId), (u64, u64)>,
    /// Per pair: (connected once, up at its last report, the step it came back up if it waits
    /// for a connection since).
    reconnect: BTreeMap<(RobotId, RobotId), (bool, bool, Option<Step>)>,
    reconnects: Reconnects,
    /// Reports with their nodes' use of the channel (netem shares it or loses frames).
    channel: Option<ChannelTally>,
    /// The pairs up, per step.
    up: BTreeMap<Step, Vec<(RobotId, RobotId)>>,
    last: Option<Step>,
}

#[derive(Default)]
struct ChannelTally {
    sum: crate::rundir::summary::ChannelSummary,
    /// Sum of every node's utilisation, and of each report's busiest; node rows; reports.
    utilisation: f64,
    busiest: f64,
    rows: usize,
    reports: usize,
    /// Frames of links that could carry them (a link direction a step).
    frames: usize,
}

impl LinkTally {
    /// One report of netem's: the links of `step` and its nodes' use of the channel.
    pub fn add(&mut self, step: Step, links: &[LinkState], nodes: &[NodeAir]) {
        self.last = Some(self.last.map_or(step, |l| l.max(step)));
        for l in links {
            let (done, now) = self.wire.entry((l.a, l.b)).or_default();
            if l.bytes_total < *now {
                *done += *now;
            }
            *now = l.bytes_total;
            self.reconnect_step(step, l);
        }
        let up = self.up.entry(step).or_default();
        up.extend(links.iter().filter(|l| l.up).map(|l| (l.a, l.b)));
        up.sort_unstable();
        up.dedup();
        if !nodes.is_empty() {
            let c = self.channel.get_or_insert_with(ChannelTally::default);
            for n in nodes {
                c.utilisation += f64::from(n.utilisation);
                c.sum.airtime_bytes += n.airtime;
                c.sum.frames_lost += u64::from(n.frames_lost);
                c.sum.retransmitted_bytes += n.retransmitted;
            }
            c.rows += nodes.len();
            c.reports += 1;
            c.busiest += (nodes.iter())
                .map(|n| f64::from(n.utilisation))
                .fold(0.0, f64::max);
        }
        if let Some(c) = &mut self.channel {
            c.frames += 2 * links.iter().filter(|l| l.air.is_some()).count();
        }
    }

    /// A pair's link at a step, for [`Reconnects`]: a link that had been connected, went down
    /// and came back up waits from that step until a step ends with it connected (or it goes
    /// down again first).
    fn reconnect_step(&mut self, step: Step, l: &LinkState) {
        let (was_connected, was_up, waiting) = self.reconnect.entry((l.a, l.b)).or_default();
        if l.up && !*was_up && *was_connected {
            *waiting = Some(step);
        }
        if let Some(since) = *waiting {
            if l.up && l.connected {
                self.reconnects.steps.push(step.saturating_sub(since));
                *waiting = None;
            } else if !l.up {
                self.reconnects.lost_before_reconnect += 1;
                *waiting = None;
            }
        }
        *was_connected |= l.up && l.connected;
        *was_up = l.up;
    }

    /// `summary.json`'s `channel`, when netem shared the channel or lost frames.
    pub fn channel_summary(&self) -> Option<crate::rundir::summary::ChannelSummary> {
        let c = self.channel.as_ref()?;
        let mut sum = c.sum;
        sum.utilisation_mean = c.utilisation / c.rows.max(1) as f64;
        sum.utilisation_busiest_mean = c.busiest / c.reports as f64;
        sum.frames_lost_pct = 100.0 * sum.frames_lost as f64 / c.frames.max(1) as f64;
        Some(sum)
    }

    /// The latest step reported.
    pub fn last_step(&self) -> Option<Step> {
        self.last
    }

    /// The pairs whose link was up, per step (sorted, so the same reports give the same map
    /// whatever order they came in).
    pub fn up_by_step(&self) -> &BTreeMap<Step, Vec<(RobotId, RobotId)>> {
        &self.up
    }

    /// The pairs up at `step`.
    pub fn up_at(&self, step: Step) -> &[(RobotId, RobotId)] {
        self.up.get(&step).map_or(&[], Vec::as_slice)
    }

    /// Bytes that crossed any link, both ways, up to the last report (every life of netem's).
    pub fn wire_total(&self) -> u64 {
        self.wire.values().map(|(done, now)| done + now).sum()
    }

    /// How long links took to reconnect after coming back up (see [`Reconnects`]).
    pub fn reconnects(&self) -> Reconnects {
        let mut r = self.reconnects.clone();
        r.pending_at_end = (self.reconnect.values())
            .filter(|(_, _, waiting)| waiting.is_some())
            .count();
        r
    }
}

/// A row of `saves.csv`: a save point of a robot's own log.
#[derive(Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct SaveCsv {
    pub step: Step,
    pub robot: RobotId,
    pub log_len: u32,
    /// Digest of the robot's approximation at the save point.
    pub digest: Hex,
}

/// A row of `views.csv`: what a robot shows of another owner, from the step it changed.
#[derive(Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct ViewCsv {
    pub step: Step,
    pub robot: RobotId,
    pub owner: RobotId,
    pub held: u32,
    pub shown: u32,
    pub digest: Hex,
}

impl ViewCsv {
    fn of(step: Step, robot: RobotId, v: proto::msg::View) -> ViewCsv {
        ViewCsv {
            step,
            robot,
            owner: v.owner,
            held: v.held,
            shown: v.shown,
            digest: Hex(v.digest),
        }
    }
}

/// A row of `traffic_by_type.csv`: the payload bytes a robot sent during a step, per traffic
/// class. Its columns after `step,robot` are the classes' names in [`Traffic::ALL`] order.
#[derive(Debug, PartialEq, Serialize)]
pub struct TrafficCsv {
    pub step: Step,
    pub robot: RobotId,
    pub bytes: Vec<u64>,
}

/// Bytes that crossed any link, both ways, from netem's `link_totals.csv` (`None` if it is
/// missing or not in the expected form: netem did not stop normally).
pub fn link_totals_wire(path: &Path) -> Option<u64> {
    let rows: Vec<netem::cli::LinkTotalsCsv> = read_rows(path).ok()?;
    Some(rows.iter().map(|r| r.bytes_a_to_b + r.bytes_b_to_a).sum())
}

/// A row of `links.csv`: one robot pair during one step.
#[derive(Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct LinkCsv {
    pub step: Step,
    pub a: RobotId,
    pub b: RobotId,
    pub up: Flag,
    pub connected: Flag,
    pub distance_m: Option<Fixed<3>>,
    pub bytes_a_to_b: u64,
    pub bytes_b_to_a: u64,
    pub queued_bytes: u64,
    pub bytes_total: u64,
}

impl LinkCsv {
    fn of(step: Step, l: &LinkState) -> LinkCsv {
        LinkCsv {
            step,
            a: l.a,
            b: l.b,
            up: Flag(l.up),
            connected: Flag(l.connected),
            distance_m: l.distance_m.map(Fixed),
            bytes_a_to_b: l.bytes_a_to_b,
            bytes_b_to_a: l.bytes_b_to_a,
            queued_bytes: l.queued_bytes,
            bytes_total: l.bytes_total,
        }
    }
}

/// A row of `channel_nodes.csv`: one node's use of the radio channel during one step.
#[derive(Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct ChannelNodeCsv {
    pub step: Step,
    pub node: RobotId,
    /// Its links' airtime shares, bytes (0: the channel is not shared).
    pub share_bytes: u64,
    /// Airtime used: frames beyond their headers, and frames sent again.
    pub airtime_bytes: u64,
    /// Airtime of every sender it hears, itself included, over the channel's capacity.
    pub utilisation: Fixed<4>,
    pub frames_lost: u32,
    pub retransmitted_bytes: u64,
}

impl ChannelNodeCsv {
    fn of(step: Step, n: &NodeAir) -> ChannelNodeCsv {
        ChannelNodeCsv {
            step,
            node: n.id,
            share_bytes: n.share,
            airtime_bytes: n.airtime,
            utilisation: Fixed(f64::from(n.utilisation)),
            frames_lost: n.frames_lost,
            retransmitted_bytes: n.retransmitted,
        }
    }
}

/// A row of `channel_links.csv`: one link's use of the channel during one step in which it
/// could carry something (up and not held).
#[derive(Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct ChannelLinkCsv {
    pub step: Step,
    pub a: RobotId,
    pub b: RobotId,
    /// Airtime shares, bytes (empty: the channel is not shared).
    pub share_a_to_b: Option<u32>,
    pub share_b_to_a: Option<u32>,
    pub airtime_a_to_b: u64,
    pub airtime_b_to_a: u64,
    pub lost_a_to_b: Flag,
    pub lost_b_to_a: Flag,
    pub delivery_a_to_b: Fixed<4>,
    pub delivery_b_to_a: Fixed<4>,
}

impl ChannelLinkCsv {
    /// The row of a link that could carry something (up and not held); `None` otherwise.
    fn of(step: Step, l: &LinkState) -> Option<ChannelLinkCsv> {
        let air = l.air?;
        Some(ChannelLinkCsv {
            step,
            a: l.a,
            b: l.b,
            share_a_to_b: air.share[0],
            share_b_to_a: air.share[1],
            airtime_a_to_b: air.airtime[0],
            airtime_b_to_a: air.airtime[1],
            lost_a_to_b: Flag(air.lost[0]),
            lost_b_to_a: Flag(air.lost[1]),
            delivery_a_to_b: Fixed(f64::from(air.delivery[0])),
            delivery_b_to_a: Fixed(f64::from(air.delivery[1])),
        })
    }
}

/// A number written with `D` decimals (the precision the schema keeps).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Fixed<const D: usize>(pub f64);

impl<const D: usize> Serialize for Fixed<D> {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        s.collect_str(&format_args!("{:.*}", D, self.0))
    }
}

impl<'de, const D: usize> Deserialize<'de> for Fixed<D> {
    fn deserialize<De: serde::Deserializer<'de>>(d: De) -> Result<Self, De::Error> {
        f64::deserialize(d).map(Fixed)
    }
}

/// Writes an `f64` field with `D` decimals (`#[serde(serialize_with = "fixed::<D, _>")]`).
fn fixed<const D: usize, S: serde::Serializer>(v: &f64, s: S) -> Result<S::Ok, S::Error> {
    Fixed::<D>(*v).serialize(s)
}

/// Writes an optional `f64` field with `D` decimals, empty when `None`.
fn fixed_opt<const D: usize, S: serde::Serializer>(
    v: &Option<f64>,
    s: S,
) -> Result<S::Ok, S::Error> {
    v.map(Fixed::<D>).serialize(s)
}

/// A `bool` field as a yes/no column (`#[serde(with = "flag")]`).
mod flag {
    use serde::{Deserialize, Serialize};

    pub fn serialize<S: serde::Serializer>(v: &bool, s: S) -> Result<S::Ok, S::Error> {
        super::Flag(*v).serialize(s)
    }

    pub fn deserialize<'de, D: serde::Deserializer<'de>>(d: D) -> Result<bool, D::Error> {
        super::Flag::deserialize(d).map(|f| f.0)
    }
}

/// A yes/no column, written `1`/`0`.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Flag(pub bool);

impl Serialize for Flag {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        s.serialize_u8(u8::from(self.0))
    }
}

impl<'de> Deserialize<'de> for Flag {
    fn deserialize<De: serde::Deserializer<'de>>(d: De) -> Result<Self, De::Error> {
        match u8::deserialize(d)? {
            0 => Ok(Flag(false)),
            1 => Ok(Flag(true)),
            v => Err(serde::de::Error::custom(format!("{v} is not 0 or 1"))),
        }
    }
}

/// A 64-bit digest, written as 16 hex digits.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub struct Hex(pub u64);

impl Serialize for Hex {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        s.collect_str(&format_args!("{:016x}", self.0))
    }
}

impl<'de> Deserialize<'de> for Hex {
    fn deserialize<De: serde::Deserializer<'de>>(d: De) -> Result<Self, De::Error> {
        let s = String::deserialize(d)?;
        u64::from_str_radix(&s, 16)
            .map(Hex)
            .map_err(|e| serde::de::Error::custom(format!("{s:?}: {e}")))
    }
}

/// Writes `rows` to `path` as CSV, the header from the row type's field names (written also
/// when there is no row).
pub fn write_rows<R: Serialize + Default>(
    path: &Path,
    rows: impl IntoIterator<Item = R>,
) -> anyhow::Result<()> {
    let mut w = TableWriter::create::<R>(path)?;
    for r in rows {
        w.row(r)?;
    }
    w.flush()
}

/// A table written row by row while a run goes on: its header at once, its rows as they come,
/// on disk at each [`TableWriter::flush`] (a run cut short keeps what was flushed).
pub struct TableWriter {
    w: csv::Writer<std::fs::File>,
    path: std::path::PathBuf,
}

impl TableWriter {
    /// Creates (or empties) `path`, the header from `H`'s field names.
    pub fn create<H: Serialize + Default>(path: &Path) -> anyhow::Result<TableWriter> {
        TableWriter::with_header(path, header::<H>()?)
    }

    /// Creates (or empties) `path` with the header given.
    pub fn with_header<S: AsRef<[u8]>>(
        path: &Path,
        header: impl IntoIterator<Item = S>,
    ) -> anyhow::Result<TableWriter> {
        let context = || format!("writing {}", path.display());
        let mut w = csv::WriterBuilder::new()
            .has_headers(false)
            .from_path(path)
            .with_context(context)?;
        w.write_record(header).with_context(context)?;
        Ok(TableWriter {
            w,
            path: path.to_path_buf(),
        })
    }

    pub fn row(&mut self, r: impl Serialize) -> anyhow::Result<()> {
        let path = &self.path;
        self.w
            .serialize(r)
            .with_context(|| format!("writing {}", path.display()))
    }

    pub fn flush(&mut self) -> anyhow::Result<()> {
        let path = &self.path;
        self.w
            .flush()
            .with_context(|| format!("writing {}", path.display()))
    }
}

/// The column names of a row type (serde's names of its fields, in order).
pub fn header<R: Serialize + Default>() -> anyhow::Result<Vec<String>> {
    let mut w = csv::Writer::from_writer(Vec::new());
    w.serialize(R::default())?;
    let text = w.into_inner().map_err(|e| anyhow::anyhow!("{e}"))?;
    let mut r = csv::Reader::from_reader(text.as_slice());
    Ok(r.headers()?.iter().map(str::to_string).collect())
}

/// Reads a CSV file written by [`write_rows`] (columns found by name).
pub fn read_rows<R: serde::de::DeserializeOwned>(path: &Path) -> anyhow::Result<Vec<R>> {
    let context = || format!("reading {}", path.display());
    let mut r = csv::Reader::from_path(path).with_context(context)?;
    r.deserialize()
        .collect::<Result<_, _>>()
        .with_context(context)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// docs/run-directory.md is the reference users script against: every column of every table
    /// and every field of summary.json (its top level) is named there, in backticks.
    #[test]
    fn every_column_and_summary_field_is_in_the_run_directory_reference() {
        let path = concat!(env!("CARGO_MANIFEST_DIR"), "/docs/run-directory.md");
        let doc = std::fs::read_to_string(path).expect("docs/run-directory.md");
        let mut names = Vec::new();
        for header in [
            header::<MetricsRow>(),
            header::<SaveCsv>(),
            header::<ViewCsv>(),
            header::<LinkCsv>(),
        ] {
            names.extend(header.expect("a header"));
        }
        let summary = serde_json::to_value(crate::rundir::summary::Summary::default())
            .expect("summary serializes");
        names.extend(summary.as_object().expect("an object").keys().cloned());
        let missing: Vec<&String> = names
            .iter()
            .filter(|n| !doc.contains(&format!("`{n}`")))
            .collect();
        assert!(
            missing.is_empty(),
            "not in docs/run-directory.md: {missing:?}"
        );
    }

    fn state(up: bool, connected: bool) -> LinkState {
        LinkState {
            a: 0,
            b: 1,
            up,
            distance_m: None,
            bytes_a_to_b: 0,
            bytes_b_to_a: 0,
            bytes_total: 0,
            queued_bytes: 0,
            connected,
            cut: None,
            air: None,
        }
    }

    #[test]
    fn traffic_rows_are_per_step_differences_per_robot() {
        let row = |step: Step, robot: u16, ins: u64, scan: u64| {
            let mut v = vec![0; Traffic::ALL.len()];
            v[Traffic::Ins as usize] = ins;
            v[Traffic::Scan as usize] = scan;
            MetricsRow {
                step,
                robot,
                sent_by_type: v,
                ..MetricsRow::default()
            }
        };
        let dir = std::env::temp_dir().join(format!("swarm-traffic-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap_or_else(|e| panic!("{e}"));
        let mut t = StepTables::create(&dir).unwrap_or_else(|e| panic!("{e}"));
        for (step, metrics) in [
            (0, vec![row(0, 1, 2, 0), row(0, 0, 10, 1)]),
            (1, vec![row(1, 1, 5, 0), row(1, 0, 25, 1)]),
        ] {
            t.step(&mut StepRows {
                step,
                metrics,
                ..StepRows::default()
            })
            .unwrap_or_else(|e| panic!("{e}"));
        }
        let text = std::fs::read_to_string(dir.join("traffic_by_type.csv")).unwrap_or_default();
        let _ = std::fs::remove_dir_all(&dir);
        let got: Vec<&str> = text.lines().collect();
        assert_eq!(
            got[0],
            "step,robot,ins,rep,del,em,chg,rm,conn,targ,save,scan,cells,mark,bid,task,role,move"
        );
        assert_eq!(
            &got[1..],
            [
                "0,0,10,0,0,0,0,0,0,0,0,1,0,0,0,0,0,0",
                "0,1,2,0,0,0,0,0,0,0,0,0,0,0,0,0,0,0",
                "1,0,15,0,0,0,0,0,0,0,0,0,0,0,0,0,0,0",
                "1,1,3,0,0,0,0,0,0,0,0,0,0,0,0,0,0,0",
            ]
        );
    }

    #[test]
    fn tables_have_the_documented_columns() {
        let h = |v: anyhow::Result<Vec<String>>| v.unwrap_or_default().join(",");
        assert_eq!(
            h(header::<MetricsRow>()),
            "step,robot,x,y,known_cells,correct_known_cells,target_x,target_y,bytes_sent,bytes_received,coverage_pct,idle,neighbours,splits_per_step,backlog_bytes,alone,shared_pct,steps_since_base,team_pct,comm_level_pct,free_cells,false_free_cells,on_wall_cells,false_free_pct,on_walls_pct"
        );
        assert_eq!(
            h(header::<LinkCsv>()),
            "step,a,b,up,connected,distance_m,bytes_a_to_b,bytes_b_to_a,queued_bytes,bytes_total"
        );
        assert_eq!(h(header::<SaveCsv>()), "step,robot,log_len,digest");
        assert_eq!(h(header::<ViewCsv>()), "step,robot,owner,held,shown,digest");
    }

    #[test]
    fn rows_are_written_as_before_and_read_back_through_the_same_type() {
        let dir = std::env::temp_dir().join(format!("swarm-rows-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap_or_else(|e| panic!("{e}"));
        let rows = vec![
            MetricsRow {
                step: 3,
                robot: 1,
                x: 1.23456,
                y: -2.0,
                target_x: Some(0.5),
                target_y: Some(7.0),
                coverage_pct: 12.3456,
                idle: true,
                splits_per_step: Some(0.25),
                backlog_bytes: 9,
                shared_pct: Some(62.5),
                steps_since_base: Some(4),
                team_pct: Some(87.5),
                comm_level_pct: Some(100.0),
                sent_by_type: vec![1, 2],
                ..MetricsRow::default()
            },
            MetricsRow::default(),
        ];
        let path = dir.join("metrics.csv");
        write_rows(&path, rows).unwrap_or_else(|e| panic!("{e}"));
        let text = std::fs::read_to_string(&path).unwrap_or_default();
        let lines: Vec<&str> = text.lines().collect();
        assert_eq!(
            lines[1],
            "3,1,1.235,-2.000,0,0,0.500,7.000,0,0,12.346,1,0,0.2500,9,0,62.500,4,87.500,100.000,0,0,0,,"
        );
        assert_eq!(
            lines[2],
            "0,0,0.000,0.000,0,0,,,0,0,0.000,0,0,,0,0,,,,,0,0,0,,"
        );
        let back: Vec<MetricsRow> = read_rows(&path).unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(
            (back[0].idle, back[0].target_y, back[1].target_x),
            (true, Some(7.0), None)
        );
        assert_eq!(back[0].splits_per_step, Some(0.25));
        assert!(
            back[0].sent_by_type.is_empty(),
            "no column: read back empty"
        );
        assert_eq!(
            (
                back[0].shared_pct,
                back[0].steps_since_base,
                back[1].shared_pct
            ),
            (Some(62.5), Some(4), None)
        );
        assert_eq!((back[0].team_pct, back[1].team_pct), (Some(87.5), None));
        // A table written before the awareness columns reads back without them.
        let old = "step,robot,x,y,known_cells,correct_known_cells,target_x,target_y,bytes_sent,bytes_received,coverage_pct,idle,neighbours,splits_per_step,backlog_bytes,alone\n\
                   3,1,1.235,-2.000,0,0,,,0,0,12.346,1,0,,9,0\n";
        std::fs::write(&path, old).unwrap_or_else(|e| panic!("{e}"));
        let back: Vec<MetricsRow> = read_rows(&path).unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(
            (
                back[0].backlog_bytes,
                back[0].steps_since_base,
                back[0].team_pct
            ),
            (9, None, None)
        );
        let saves = [SaveCsv {
            step: 1,
            robot: 2,
            log_len: 3,
            digest: Hex(0xabc),
        }];
        let path = dir.join("saves.csv");
        write_rows(&path, saves).unwrap_or_else(|e| panic!("{e}"));
        let text = std::fs::read_to_string(&path).unwrap_or_default();
        assert_eq!(text, "step,robot,log_len,digest\n1,2,3,0000000000000abc\n");
        let back: Vec<SaveCsv> = read_rows(&path).unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(back[0].digest, Hex(0xabc));
        write_rows(&path, Vec::<SaveCsv>::new()).unwrap_or_else(|e| panic!("{e}"));
        let text = std::fs::read_to_string(&path).unwrap_or_default();
        let _ = std::fs::remove_dir_all(&dir);
        assert_eq!(text, "step,robot,log_len,digest\n");
    }

    #[test]
    fn links_go_out_by_step_and_pair_and_the_tally_sums_every_life_of_netem() {
        let link = |a, b, total, d: Option<f64>| LinkState {
            a,
            b,
            distance_m: d,
            bytes_total: total,
            cut: Some(proto::msg::LinkCut::Range),
            ..state(false, false)
        };
        let dir = std::env::temp_dir().join(format!("swarm-links-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap_or_else(|e| panic!("{e}"));
        let mut t = StepTables::create(&dir).unwrap_or_else(|e| panic!("{e}"));
        let mut tally = LinkTally::default();
        // Step 3's reports in arrival order: netem, then netem again (a restart).
        let steps = [
            (2, vec![link(0, 2, 40, Some(0.1))]),
            (
                3,
                vec![
                    link(1, 2, 10, Some(2.345)),
                    link(0, 1, 7, None),
                    link(0, 1, 1, None),
                ],
            ),
            (4, vec![link(0, 1, 2, None)]),
        ];
        for (step, links) in &steps {
            tally.add(*step, links, &[]);
            t.step(&mut StepRows {
                step: *step,
                links: links.clone(),
                ..StepRows::default()
            })
            .unwrap_or_else(|e| panic!("{e}"));
        }
        let back: Vec<LinkCsv> =
            read_rows(&dir.join("links.csv")).unwrap_or_else(|e| panic!("{e}"));
        let _ = std::fs::remove_dir_all(&dir);
        let got: Vec<(Step, u16, u16, u64)> = back
            .iter()
            .map(|l| (l.step, l.a, l.b, l.bytes_total))
            .collect();
        assert_eq!(
            got,
            [
                (2, 0, 2, 40),
                (3, 0, 1, 7),
                (3, 0, 1, 1),
                (3, 1, 2, 10),
                (4, 0, 1, 2)
            ]
        );
        assert_eq!(back[3].distance_m, Some(Fixed(2.345)));
        assert_eq!(tally.last_step(), Some(4));
        // (0,1): 7, then a new life's 1 and 2; (0,2) 40; (1,2) 10.
        assert_eq!(tally.wire_total(), 7 + 2 + 40 + 10);
        assert!(tally.channel_summary().is_none());
    }

    #[test]
    fn reconnects_count_steps_from_up_again_to_connected() {
        let mut log = LinkTally::default();
        // (up, connected) per step: first connection (not counted), down, back up and
        // connected 2 steps later, down, up and connected at once, down, up but never again.
        let seq = [
            (true, false),
            (true, true),
            (false, false),
            (true, false),
            (true, false),
            (true, true),
            (false, false),
            (true, true),
            (false, true),
            (true, false),
        ];
        for (step, &(up, c)) in seq.iter().enumerate() {
            log.add(step as Step, &[state(up, c)], &[]);
        }
        let r = log.reconnects();
        assert_eq!(r.steps, vec![2, 0]);
        assert_eq!((r.lost_before_reconnect, r.pending_at_end), (0, 1));
        let s = ReconnectSummary::from(&r);
        assert_eq!(
            (s.events, s.max_steps, s.mean_steps),
            (2, Some(2), Some(1.0))
        );
    }
}
