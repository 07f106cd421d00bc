//! The run directory's tables (`metrics.csv`, `links.csv`, `saves.csv`, `views.csv`,
//! `traffic.csv`, …) as serde rows. Each row type is written and read back through the same type.

use std::collections::BTreeMap;
use std::path::Path;

use anyhow::Context;
use proto::msg::{LinkReport, LinkState, NodeAir, RobotId, Step, Traffic};
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
    /// Fig. 5d: steps since this robot's last contact with the base station, set once the
    /// run's links are all in; empty on the base station's rows and without a base station.
    #[serde(default)]
    pub steps_since_base: Option<Step>,
    /// Fig. 5a: the percentage of the reachable free cells that at least one robot knows (the
    /// union of the team's known space; the same on every robot row of a step in lockstep);
    /// empty on the base station's rows.
    #[serde(serialize_with = "fixed_opt::<3, _>", default)]
    pub team_pct: Option<f64>,
    /// Rooker and Birk 2005, Fig. 6: the percentage of robot pairs that can reach each other
    /// over the step's links (netem's `up`), directly or through others, set once the run's
    /// links are all in; empty on the base station's rows.
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

/// `metrics.csv`: one row per robot and step, by step and robot.
pub fn write_metrics(dir: &Path, rows: &[MetricsRow]) -> anyhow::Result<()> {
    let mut sorted: Vec<&MetricsRow> = rows.iter().collect();
    sorted.sort_by_key(|r| (r.step, r.robot));
    write_table::<MetricsRow, _>(&dir.join("metrics.csv"), sorted)
}

/// Every link report of a run, in arrival order, each kept packed (its links postcard-encoded:
/// some 25 bytes a link instead of 64 — netem reports every pair every step, 8 100 of them at
/// 128 robots, and the launcher holds the whole run until it ends).
#[derive(Default)]
pub struct LinkLog {
    reports: Vec<(Step, Box<[u8]>)>,
    /// Each report's nodes' use of the channel (only when netem shares it or loses frames).
    nodes: Vec<(Step, Vec<NodeAir>)>,
}

impl LinkLog {
    pub fn add(&mut self, r: LinkReport) {
        let packed = proto::msg::encode(&r.links).into_boxed_slice();
        self.reports.push((r.step, packed));
        if !r.nodes.is_empty() {
            self.nodes.push((r.step, r.nodes));
        }
    }

    /// Drops the reports of steps after `last`.
    pub fn truncate(&mut self, last: Step) {
        self.reports.retain(|(s, _)| *s <= last);
        self.nodes.retain(|(s, _)| *s <= last);
    }

    /// `summary.json`'s `channel`, when netem shared the channel or lost frames.
    pub fn channel_summary(&self) -> Option<crate::rundir::summary::ChannelSummary> {
        if self.nodes.is_empty() {
            return None;
        }
        let mut sum = crate::rundir::summary::ChannelSummary::default();
        let (mut util, mut busiest, mut rows) = (0.0, 0.0, 0usize);
        for (_, ns) in &self.nodes {
            for n in ns {
                util += f64::from(n.utilisation);
                sum.airtime_bytes += n.airtime;
                sum.frames_lost += u64::from(n.frames_lost);
                sum.retransmitted_bytes += n.retransmitted;
            }
            rows += ns.len();
            busiest += ns
                .iter()
                .map(|n| f64::from(n.utilisation))
                .fold(0.0, f64::max);
        }
        sum.utilisation_mean = util / rows.max(1) as f64;
        sum.utilisation_busiest_mean = busiest / self.nodes.len() as f64;
        let frames = 2 * self.rows().filter(|(_, l)| l.air.is_some()).count();
        sum.frames_lost_pct = 100.0 * sum.frames_lost as f64 / frames.max(1) as f64;
        Some(sum)
    }

    /// The latest step reported.
    pub fn last_step(&self) -> Option<Step> {
        self.reports.iter().map(|(s, _)| *s).max()
    }

    /// The links of one packed report (it was encoded here: it decodes).
    fn unpack(packed: &[u8]) -> Vec<LinkState> {
        proto::msg::decode(packed).unwrap_or_default()
    }

    /// Every link of every report, in arrival order.
    pub fn rows(&self) -> impl Iterator<Item = (Step, LinkState)> + '_ {
        self.reports
            .iter()
            .flat_map(|(step, packed)| Self::unpack(packed).into_iter().map(move |l| (*step, l)))
    }

    /// Every link, by step and pair (pairs reported twice in a step in arrival order), one
    /// step unpacked at a time.
    pub fn sorted_rows(&self) -> impl Iterator<Item = (Step, LinkState)> + '_ {
        let mut by_step: BTreeMap<Step, Vec<&[u8]>> = BTreeMap::new();
        for (step, packed) in &self.reports {
            by_step.entry(*step).or_default().push(packed);
        }
        by_step.into_iter().flat_map(|(step, reports)| {
            let mut links: Vec<LinkState> = reports.into_iter().flat_map(Self::unpack).collect();
            links.sort_by_key(|l| (l.a, l.b));
            links.into_iter().map(move |l| (step, l))
        })
    }

    /// The pairs whose link was up, per step (sorted, so the same log gives the same map
    /// whatever order the reports came in).
    pub fn up_by_step(&self) -> BTreeMap<Step, Vec<(RobotId, RobotId)>> {
        let mut up: BTreeMap<Step, Vec<(RobotId, RobotId)>> = BTreeMap::new();
        for (step, l) in self.rows().filter(|(_, l)| l.up) {
            up.entry(step).or_default().push((l.a, l.b));
        }
        for pairs in up.values_mut() {
            pairs.sort_unstable();
            pairs.dedup();
        }
        up
    }

    /// Bytes that crossed any link, both ways, up to the last report. A restarted netem counts
    /// from zero again: a pair's total that falls starts a new count, added to the old one.
    pub fn wire_total(&self) -> u64 {
        // Per pair: the totals of netem's earlier lives, and the current one's.
        let mut totals: BTreeMap<(u16, u16), (u64, u64)> = BTreeMap::new();
        for (_, l) in self.rows() {
            let (done, now) = totals.entry((l.a, l.b)).or_default();
            if l.bytes_total < *now {
                *done += *now;
            }
            *now = l.bytes_total;
        }
        totals.values().map(|(done, now)| done + now).sum()
    }

    /// How long links took to reconnect after coming back up (see [`Reconnects`]).
    pub fn reconnects(&self) -> Reconnects {
        // Per pair: (step, up, connected).
        type Rows = Vec<(Step, bool, bool)>;
        let mut by_pair: BTreeMap<(u16, u16), Rows> = BTreeMap::new();
        for (step, l) in self.rows() {
            by_pair
                .entry((l.a, l.b))
                .or_default()
                .push((step, l.up, l.connected));
        }
        let mut r = Reconnects::default();
        for rows in by_pair.values_mut() {
            rows.sort_by_key(|x| x.0);
            // (step the link came back up, since when it waits); only after it had been
            // connected once and then went down.
            let (mut was_connected, mut was_up, mut waiting) = (false, false, None);
            for &(step, up, connected) in rows.iter() {
                if up && !was_up && was_connected {
                    waiting = Some(step);
                }
                if let Some(since) = waiting {
                    if up && connected {
                        r.steps.push(step - since);
                        waiting = None;
                    } else if !up {
                        r.lost_before_reconnect += 1;
                        waiting = None;
                    }
                }
                was_connected |= up && connected;
                was_up = up;
            }
            r.pending_at_end += usize::from(waiting.is_some());
        }
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

/// `saves.csv` and `views.csv` (polygon exchange): every save point of every robot's own log
/// (its length and the digest of the approximation there), and every change of what a robot
/// shows of another owner (ops held, ops shown — up to a save point — and the digest of what it
/// shows). A view is atomic when its (owner, shown, digest) is one of the owner's save points.
pub fn write_saves_and_views(
    dir: &Path,
    saves: &[(Step, RobotId, u32, u64)],
    views: &[(Step, RobotId, proto::msg::View)],
) -> anyhow::Result<()> {
    let saves = saves.iter().map(|&(step, robot, log_len, digest)| SaveCsv {
        step,
        robot,
        log_len,
        digest: Hex(digest),
    });
    write_rows(&dir.join("saves.csv"), saves)?;
    let views = views.iter().map(|&(step, robot, v)| ViewCsv {
        step,
        robot,
        owner: v.owner,
        held: v.held,
        shown: v.shown,
        digest: Hex(v.digest),
    });
    write_rows(&dir.join("views.csv"), views)
}

/// A row of `traffic_by_type.csv`: the payload bytes a robot sent during a step, per traffic
/// class. Its columns after `step,robot` are the classes' names in [`Traffic::ALL`] order.
#[derive(Debug, PartialEq, Serialize)]
pub struct TrafficCsv {
    pub step: Step,
    pub robot: RobotId,
    pub bytes: Vec<u64>,
}

/// `traffic_by_type.csv`: per step and robot, the payload bytes the robot sent during the step
/// by traffic class (thesis Table 6.1's package types, `conn`, `targ`, and `scan`).
pub fn write_traffic(dir: &Path, rows: &[MetricsRow]) -> anyhow::Result<()> {
    let mut sorted: Vec<&MetricsRow> = rows.iter().collect();
    sorted.sort_by_key(|r| (r.robot, r.step));
    let mut before: Option<(u16, &[u64])> = None;
    let mut out: Vec<TrafficCsv> = Vec::new();
    for r in sorted {
        let prev = before
            .filter(|(robot, _)| *robot == r.robot)
            .map(|(_, v)| v);
        let bytes = (r.sent_by_type.iter().enumerate())
            .map(|(i, &now)| now.saturating_sub(prev.and_then(|p| p.get(i)).copied().unwrap_or(0)))
            .collect();
        out.push(TrafficCsv {
            step: r.step,
            robot: r.robot,
            bytes,
        });
        before = Some((r.robot, &r.sent_by_type));
    }
    out.sort_by_key(|t| (t.step, t.robot));
    let path = dir.join("traffic_by_type.csv");
    let context = || format!("writing {}", path.display());
    // The header is written by hand: its class columns come from one list (serde names a
    // sequence field's columns no way).
    let mut w = csv::WriterBuilder::new()
        .has_headers(false)
        .from_path(&path)
        .with_context(context)?;
    let head = ["step", "robot"]
        .into_iter()
        .chain(Traffic::ALL.iter().map(|t| t.name()));
    w.write_record(head).with_context(context)?;
    for r in out {
        w.serialize(r).with_context(context)?;
    }
    w.flush().with_context(context)
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

/// `links.csv`: one row per step and robot pair.
pub fn write_links(dir: &Path, log: &LinkLog) -> anyhow::Result<()> {
    let rows = log.sorted_rows().map(|(step, l)| LinkCsv {
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
    });
    write_rows(&dir.join("links.csv"), rows)
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

/// `channel_nodes.csv` and `channel_links.csv`, when netem shared the channel or lost frames
/// (`radio.medium` `shared`/`airtime`, `radio.frame_loss`, `radio.fading_db`); nothing
/// otherwise.
pub fn write_channel(dir: &Path, log: &LinkLog) -> anyhow::Result<()> {
    if log.nodes.is_empty() {
        return Ok(());
    }
    let mut nodes: Vec<ChannelNodeCsv> = (log.nodes.iter())
        .flat_map(|(step, ns)| {
            ns.iter().map(move |n| ChannelNodeCsv {
                step: *step,
                node: n.id,
                share_bytes: n.share,
                airtime_bytes: n.airtime,
                utilisation: Fixed(f64::from(n.utilisation)),
                frames_lost: n.frames_lost,
                retransmitted_bytes: n.retransmitted,
            })
        })
        .collect();
    nodes.sort_by_key(|r| (r.step, r.node));
    write_rows(&dir.join("channel_nodes.csv"), nodes)?;
    let links = log.sorted_rows().filter_map(|(step, l)| {
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
    });
    write_rows(&dir.join("channel_links.csv"), links)
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
    write_table::<R, R>(path, rows)
}

/// [`write_rows`] of rows of any form that serializes like `H` (borrowed rows, say), the header
/// from `H`'s field names.
fn write_table<H: Serialize + Default, R: Serialize>(
    path: &Path,
    rows: impl IntoIterator<Item = R>,
) -> anyhow::Result<()> {
    let context = || format!("writing {}", path.display());
    let mut w = csv::Writer::from_path(path).with_context(context)?;
    let mut empty = true;
    for r in rows {
        w.serialize(r).with_context(context)?;
        empty = false;
    }
    if empty {
        w.write_record(header::<H>()?).with_context(context)?;
    }
    w.flush().with_context(context)
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
        let rows = [
            row(1, 1, 5, 0),
            row(0, 0, 10, 1),
            row(1, 0, 25, 1),
            row(0, 1, 2, 0),
        ];
        write_traffic(&dir, &rows).unwrap_or_else(|e| panic!("{e}"));
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
    fn the_packed_link_log_gives_back_every_link_and_sorts_by_step_and_pair() {
        let link = |a, b, total, d: Option<f64>| LinkState {
            a,
            b,
            distance_m: d,
            bytes_total: total,
            cut: Some(proto::msg::LinkCut::Range),
            ..state(false, false)
        };
        let reports = [
            (3, vec![link(1, 2, 10, Some(2.345)), link(0, 1, 7, None)]),
            (2, vec![link(0, 2, u64::MAX, Some(0.1))]),
            // netem again (a restart): step 3 once more.
            (3, vec![link(0, 1, 1, Some(1.0))]),
            (4, vec![link(0, 1, 2, None)]),
        ];
        let mut log = LinkLog::default();
        for (step, links) in &reports {
            log.add(LinkReport {
                step: *step,
                links: links.clone(),
                nodes: Vec::new(),
            });
        }
        let added: Vec<(Step, LinkState)> = reports
            .iter()
            .flat_map(|(s, ls)| ls.iter().map(move |l| (*s, l.clone())))
            .collect();
        assert_eq!(log.rows().collect::<Vec<_>>(), added);
        let mut sorted = added.clone();
        sorted.sort_by_key(|(s, l)| (*s, l.a, l.b));
        assert_eq!(log.sorted_rows().collect::<Vec<_>>(), sorted);
        assert_eq!(log.last_step(), Some(4));
        log.truncate(3);
        assert_eq!(log.last_step(), Some(3));
        assert_eq!(log.rows().count(), 4);
    }

    #[test]
    fn reconnects_count_steps_from_up_again_to_connected() {
        let mut log = LinkLog::default();
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
            log.add(LinkReport {
                step: step as Step,
                links: vec![state(up, c)],
                nodes: Vec::new(),
            });
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
