//! A run step by step, from its step-log records ([`crate::rundir::steplog`]): what the viewer serves —
//! a step's frame (robots, links, how they used the radio channel, coverage, trajectories so
//! far), the series its charts draw,
//! a robot's details and planning grid at a step. Fed record by record: live by the launcher as
//! it writes `steps.log`, in a replay from the file, so both show the same thing.

use std::collections::BTreeMap;

use proto::grid::Grid;
use proto::msg::{LinkAir, NodeAir, RobotId, Step, Traffic};
use serde::Serialize;

use crate::rundir::steplog::{GridChange, Grids, Header, LinkStep, Record, RobotStep};

/// One step as the page draws it.
#[derive(Clone, Debug, Serialize)]
pub struct Frame {
    pub step: Step,
    pub robots: Vec<RobotFrame>,
    pub links: Vec<LinkFrame>,
    /// The best coverage of any robot at this step, %.
    pub coverage_pct: f32,
    /// Payload bytes sent so far by the team, per traffic class (classes with bytes only).
    pub bytes_by_type: BTreeMap<&'static str, u64>,
    /// The largest backlog of any robot at this step, bytes.
    pub backlog_max: u64,
    /// Bytes the shared channel carries in a step, when netem shares it (what a robot's
    /// airtime share is a part of).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub channel_capacity: Option<f64>,
    /// Every robot's positions up to this step (only when asked for: a seek).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub trails: Option<Vec<Vec<(f32, f32)>>>,
}

#[derive(Clone, Debug, Serialize)]
pub struct RobotFrame {
    pub id: RobotId,
    pub x: f32,
    pub y: f32,
    pub theta: f32,
    pub alive: bool,
    pub target: Option<(f32, f32)>,
    pub idle: bool,
    /// Its use of the radio channel in the links' step, when netem reported it.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub air: Option<RobotAir>,
}

/// A robot's use of the radio channel in a step ([`NodeAir`] without the id).
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct RobotAir {
    /// The airtime shares of its links, bytes (0 when the channel is not shared).
    pub share: u64,
    /// The airtime it used, bytes (frames sent again included).
    pub airtime: u64,
    /// How busy the channel was where it is: the airtime of every sender it hears over the
    /// channel's capacity (0 when the channel is not shared; above 1 while overruns are paid
    /// back).
    pub utilisation: f32,
    /// Its frames lost in the step (each sent again in the next).
    pub frames_lost: u32,
    /// The bytes of its frames sent again in the step.
    pub retransmitted: u64,
}

impl From<&NodeAir> for RobotAir {
    fn from(n: &NodeAir) -> RobotAir {
        RobotAir {
            share: n.share,
            airtime: n.airtime,
            utilisation: n.utilisation,
            frames_lost: n.frames_lost,
            retransmitted: n.retransmitted,
        }
    }
}

#[derive(Clone, Debug, Serialize)]
pub struct LinkFrame {
    pub a: RobotId,
    pub b: RobotId,
    /// `up`, `blackhole`, or why it is down: `range`, `fault`, `dead`.
    pub state: &'static str,
    pub bytes_a_to_b: u64,
    pub bytes_b_to_a: u64,
    pub queued_bytes: u64,
    /// Its use of the radio channel in the step, when netem reported it (the link could carry
    /// something, and the channel is shared or lossy).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub air: Option<LinkAirFrame>,
}

/// A link's use of the radio channel in a step.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct LinkAirFrame {
    /// The lower of its two directions' probabilities that a frame is delivered.
    pub delivery: f32,
    /// How many of its directions lost their frame of the step (0, 1 or 2; each is delivered a
    /// step late).
    pub lost: u8,
    /// Each direction's probability that a frame is delivered, and whether its frame was lost.
    pub delivery_a_to_b: f32,
    pub delivery_b_to_a: f32,
    pub lost_a_to_b: bool,
    pub lost_b_to_a: bool,
    /// Each direction's airtime share, bytes (`None`: the channel is not shared), and airtime
    /// used.
    pub share_a_to_b: Option<u32>,
    pub share_b_to_a: Option<u32>,
    pub airtime_a_to_b: u64,
    pub airtime_b_to_a: u64,
}

impl From<&LinkAir> for LinkAirFrame {
    fn from(a: &LinkAir) -> LinkAirFrame {
        LinkAirFrame {
            delivery: a.delivery[0].min(a.delivery[1]),
            lost: a.lost.iter().filter(|&&l| l).count() as u8,
            delivery_a_to_b: a.delivery[0],
            delivery_b_to_a: a.delivery[1],
            lost_a_to_b: a.lost[0],
            lost_b_to_a: a.lost[1],
            share_a_to_b: a.share[0],
            share_b_to_a: a.share[1],
            airtime_a_to_b: a.airtime[0],
            airtime_b_to_a: a.airtime[1],
        }
    }
}

/// The charts' data: per step with reports.
#[derive(Clone, Debug, Default, Serialize)]
pub struct Series {
    pub steps: Vec<Step>,
    pub coverage: Vec<f32>,
    pub bytes_by_type: BTreeMap<&'static str, Vec<u64>>,
    pub backlog_max: Vec<u64>,
}

/// What the page shows of one robot at a step: its report as the run logged it, and how many
/// frontier cells its planning grid held then.
#[derive(Clone, Debug, Serialize)]
pub struct RobotDetail<'a> {
    #[serde(flatten)]
    pub report: &'a RobotStep,
    pub frontier_cells: usize,
}

/// Where one step's records are.
#[derive(Clone, Debug, Default)]
struct StepAt {
    poses: Option<usize>,
    robots: Vec<usize>,
    links: Option<usize>,
    channel: Option<usize>,
}

/// A run's records, indexed by step.
pub struct Timeline {
    pub header: Header,
    records: Vec<Record>,
    steps: BTreeMap<Step, StepAt>,
    /// Per robot, the indices of its reports in order.
    reports: BTreeMap<RobotId, Vec<usize>>,
    /// Per robot life, its latest sent bytes per class (for the team's totals).
    sent: BTreeMap<(RobotId, u16), Vec<u64>>,
    series: Series,
}

/// `up`, `blackhole` (up but held), or why it is down: `range`, `fault`, `dead` (`down` if
/// netem did not say).
pub(crate) fn link_state(l: &LinkStep) -> &'static str {
    match (l.up, l.cut) {
        (true, Some(proto::msg::LinkCut::Blackhole)) => "blackhole",
        (true, _) => "up",
        (false, Some(c)) => c.as_str(),
        (false, None) => "down",
    }
}

impl Timeline {
    pub fn new(header: Header) -> Timeline {
        Timeline {
            header,
            records: Vec::new(),
            steps: BTreeMap::new(),
            reports: BTreeMap::new(),
            sent: BTreeMap::new(),
            series: Series::default(),
        }
    }

    /// Every record of a step log, in order.
    pub fn of(header: Header, records: Vec<Record>) -> Timeline {
        let mut t = Timeline::new(header);
        for r in records {
            t.push(r);
        }
        t
    }

    /// Takes the next record.
    pub fn push(&mut self, r: Record) {
        let i = self.records.len();
        match &r {
            Record::Header(_) => return,
            Record::Poses { step, .. } => self.steps.entry(*step).or_default().poses = Some(i),
            Record::Links { step, .. } => self.steps.entry(*step).or_default().links = Some(i),
            Record::Channel { step, .. } => self.steps.entry(*step).or_default().channel = Some(i),
            Record::Robot(rs, _) => {
                self.steps.entry(rs.step).or_default().robots.push(i);
                self.reports.entry(rs.robot).or_default().push(i);
                self.sent
                    .insert((rs.robot, rs.life), rs.sent_by_type.clone());
                self.add_to_series(rs);
            }
        }
        self.records.push(r);
    }

    /// A report of a step extends the series (a step's first report adds its point).
    fn add_to_series(&mut self, rs: &RobotStep) {
        let s = &mut self.series;
        if s.steps.last() != Some(&rs.step) {
            s.steps.push(rs.step);
            s.coverage.push(0.0);
            s.backlog_max.push(0);
            for v in s.bytes_by_type.values_mut() {
                v.push(0);
            }
        }
        let n = s.steps.len() - 1;
        s.coverage[n] = s.coverage[n].max(rs.coverage_pct.unwrap_or(0.0));
        s.backlog_max[n] = s.backlog_max[n].max(rs.backlog_bytes);
        for (ty, total) in team_bytes(&self.sent) {
            let col = s.bytes_by_type.entry(ty).or_insert_with(|| vec![0; n + 1]);
            col[n] = total;
        }
    }

    pub fn series(&self) -> &Series {
        &self.series
    }

    /// The first and the last step with reports.
    pub fn span(&self) -> Option<(Step, Step)> {
        Some((*self.series.steps.first()?, *self.series.steps.last()?))
    }

    fn robot_steps(&self, step: Step) -> impl Iterator<Item = &RobotStep> {
        self.steps
            .get(&step)
            .into_iter()
            .flat_map(|at| at.robots.iter())
            .filter_map(|&i| match &self.records[i] {
                Record::Robot(r, _) => Some(r),
                _ => None,
            })
    }

    /// The frame of `step` (the latest report of each robot up to it), with the trajectories up
    /// to it when `trails`.
    pub fn frame(&self, step: Step, trails: bool) -> Frame {
        let mut robots = self.robot_frames(step);
        // netem's latest report, and how its step used the channel (if it said).
        let (links, channel) = self
            .steps
            .range(..=step)
            .rev()
            .find_map(|(_, at)| Some((at.links?, at.channel)))
            .map_or((None, None), |(l, c)| {
                (Some(&self.records[l]), c.map(|c| &self.records[c]))
            });
        let (capacity, nodes, air) = match channel {
            Some(Record::Channel {
                capacity,
                nodes,
                links,
                ..
            }) => (*capacity, nodes.as_slice(), links.as_slice()),
            _ => (None, &[][..], &[][..]),
        };
        for n in nodes {
            if let Some(f) = robots.get_mut(&n.id) {
                f.air = Some(n.into());
            }
        }
        let s = &self.series;
        let n = s.steps.partition_point(|&x| x <= step);
        let at = n.checked_sub(1);
        Frame {
            step,
            robots: robots.into_values().collect(),
            links: link_frames(links, air),
            coverage_pct: at.map_or(0.0, |i| s.coverage[i]),
            bytes_by_type: at.map_or_else(BTreeMap::new, |i| {
                s.bytes_by_type
                    .iter()
                    .map(|(k, v)| (*k, v[i]))
                    .filter(|&(_, v)| v > 0)
                    .collect()
            }),
            backlog_max: at.map_or(0, |i| s.backlog_max[i]),
            channel_capacity: capacity,
            trails: trails.then(|| self.trails(step)),
        }
    }

    /// Each robot at `step`: alive as the world's latest status says, where and what it does as
    /// its own latest report says.
    fn robot_frames(&self, step: Step) -> BTreeMap<RobotId, RobotFrame> {
        let mut robots: BTreeMap<RobotId, RobotFrame> = BTreeMap::new();
        let frame = |id, x, y, theta, alive| RobotFrame {
            id,
            x,
            y,
            theta,
            alive,
            target: None,
            idle: false,
            air: None,
        };
        if let Some(Record::Poses { robots: poses, .. }) = self
            .steps
            .range(..=step)
            .rev()
            .find_map(|(_, at)| at.poses)
            .map(|i| &self.records[i])
        {
            for p in poses {
                robots.insert(p.id, frame(p.id, p.x, p.y, p.theta, p.alive));
            }
        }
        for r in self.robot_steps(step) {
            let f = robots
                .entry(r.robot)
                .or_insert_with(|| frame(r.robot, r.x, r.y, r.theta, true));
            (f.x, f.y, f.theta, f.target, f.idle) = (r.x, r.y, r.theta, r.target, r.idle);
        }
        robots
    }

    /// Every robot's positions from its reports up to `step`.
    fn trails(&self, step: Step) -> Vec<Vec<(f32, f32)>> {
        let mut t: Vec<Vec<(f32, f32)>> = Vec::new();
        for (id, idx) in &self.reports {
            let id = usize::from(*id);
            if t.len() <= id {
                t.resize(id + 1, Vec::new());
            }
            for &i in idx {
                if let Record::Robot(r, _) = &self.records[i] {
                    if r.step > step {
                        break;
                    }
                    t[id].push((r.x, r.y));
                }
            }
        }
        t
    }

    /// The latest report of `robot` at or before `step`.
    fn report(&self, robot: RobotId, step: Step) -> Option<(usize, &RobotStep)> {
        let idx = self.reports.get(&robot)?;
        let k = idx.partition_point(|&i| match &self.records[i] {
            Record::Robot(r, _) => r.step <= step,
            _ => false,
        });
        let i = *idx.get(k.checked_sub(1)?)?;
        match &self.records[i] {
            Record::Robot(r, _) => Some((k - 1, r)),
            _ => None,
        }
    }

    /// Robot `robot`'s planning grid as it reported it at or before `step`: its last whole grid
    /// with the changes after it applied. `None`: no such robot or no report yet.
    pub fn grid(&self, robot: RobotId, step: Step) -> Option<Grid> {
        let (k, _) = self.report(robot, step)?;
        let idx = &self.reports[&robot];
        let whole = idx[..=k]
            .iter()
            .rposition(|&i| matches!(&self.records[i], Record::Robot(_, GridChange::Whole(_))))?;
        let mut grids = Grids::default();
        for &i in &idx[whole..=k] {
            if let Record::Robot(r, change) = &self.records[i] {
                grids.apply(&self.header.map, r, change).ok()?;
            }
        }
        grids.grids.remove(&robot)
    }

    /// What the page shows of `robot` at `step`; `None`: no such robot or no report yet.
    pub fn robot(&self, robot: RobotId, step: Step) -> Option<RobotDetail<'_>> {
        let (_, report) = self.report(robot, step)?;
        let frontier_cells = self.grid(robot, step).map_or(0, |g| frontiers(&g).len());
        Some(RobotDetail {
            report,
            frontier_cells,
        })
    }

    /// Whether every robot alive at `step` (by the world's status of the step) has reported
    /// it; `false` before the status of the step came.
    pub fn complete(&self, step: Step) -> bool {
        let Some(Record::Poses { robots, .. }) = self
            .steps
            .get(&step)
            .and_then(|at| at.poses)
            .map(|i| &self.records[i])
        else {
            return false;
        };
        let reported: std::collections::BTreeSet<RobotId> =
            self.robot_steps(step).map(|r| r.robot).collect();
        robots
            .iter()
            .filter(|p| p.alive)
            .all(|p| reported.contains(&p.id))
    }

    /// The step the latest record is of.
    pub fn latest(&self) -> Option<Step> {
        self.series.steps.last().copied()
    }
}

/// The team's payload bytes per class: the sum over robot lives of each one's latest totals.
pub(crate) fn team_bytes(sent: &BTreeMap<(RobotId, u16), Vec<u64>>) -> Vec<(&'static str, u64)> {
    Traffic::ALL
        .iter()
        .enumerate()
        .map(|(i, ty)| {
            (
                ty.name(),
                sent.values().map(|v| v.get(i).copied().unwrap_or(0)).sum(),
            )
        })
        .collect()
}

/// The frontier cells of a planning grid ([`Grid::is_frontier`], the robots' own test; the
/// robots count only those they can reach, `robot_agent::nav::plan::is_frontier`; the page shows
/// all).
pub fn frontiers(g: &Grid) -> Vec<proto::grid::Cell> {
    let Some(r) = g.known_bounds() else {
        return Vec::new();
    };
    let mut out = Vec::new();
    for y in r.min.y..=r.max.y {
        for x in r.min.x..=r.max.x {
            let c = proto::grid::Cell::new(x, y);
            if g.is_frontier(c) {
                out.push(c);
            }
        }
    }
    out
}

/// netem's links as the viewer draws them, each with how it used the air (if the step said).
fn link_frames(links: Option<&Record>, air: &[(RobotId, RobotId, LinkAir)]) -> Vec<LinkFrame> {
    let air: BTreeMap<(RobotId, RobotId), &LinkAir> =
        air.iter().map(|(a, b, x)| ((*a, *b), x)).collect();
    match links {
        Some(Record::Links { links, .. }) => links
            .iter()
            .map(|l| LinkFrame {
                a: l.a,
                b: l.b,
                state: link_state(l),
                bytes_a_to_b: l.bytes_a_to_b,
                bytes_b_to_a: l.bytes_b_to_a,
                queued_bytes: l.queued_bytes,
                air: air.get(&(l.a, l.b)).map(|&x| x.into()),
            })
            .collect(),
        _ => Vec::new(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rundir::steplog::{diff, LinkStep, Pose, Run, ViewRow};
    use proto::geom::MapInfo;
    use proto::grid::{Cell, Occ};

    /// The page once marked free cells on the grid's edge as frontiers (its own test read cells
    /// beyond the edge as unknown); the robots never had them.
    #[test]
    fn the_grids_edge_is_no_frontier_on_the_page_as_for_the_robots() {
        let mut g = Grid::new(4, 3, Occ::Free);
        assert!(frontiers(&g).is_empty());
        g.set(Cell::new(3, 2), Occ::Unknown);
        assert_eq!(frontiers(&g), [Cell::new(3, 1), Cell::new(2, 2)]);
        // The same cells as the planner's, where every free cell is reachable.
        let costs = robot_agent::nav::plan::costs(&g, Cell::new(0, 0));
        assert_eq!(frontiers(&g), robot_agent::nav::plan::frontiers(&g, &costs));
    }

    fn header() -> Header {
        Header {
            magic: crate::rundir::steplog::MAGIC,
            version: crate::rundir::steplog::VERSION,
            map: MapInfo::at_origin(4, 3, 1.0),
            robots: 2,
            step_seconds: 1.0,
            truth: Grid::new(4, 3, Occ::Free).to_rle(),
        }
    }

    fn report(robot: RobotId, step: Step, x: f32, grid: GridChange, coverage: f32) -> Record {
        Record::Robot(
            RobotStep {
                step,
                robot,
                life: 0,
                x,
                y: 1.0,
                theta: 0.0,
                target: Some((3.0, 2.0)),
                idle: false,
                known_cells: 1,
                bytes_sent: 10,
                bytes_received: 5,
                splits_per_step: None,
                backlog_bytes: u64::from(step) * 7,
                sent_by_type: vec![u64::from(step) + 1, 2],
                views: vec![ViewRow {
                    owner: 1 - robot,
                    held: 3,
                    shown: 2,
                }],
                coverage_pct: Some(coverage),
            },
            grid,
        )
    }

    /// Two robots over three steps: robot 0 reports its grid whole, then as changes.
    fn timeline() -> (Timeline, Vec<Grid>) {
        let mut grids = vec![Grid::new(4, 3, Occ::Unknown)];
        for (i, c) in [(1, 1), (2, 1)].into_iter().enumerate() {
            let mut g = grids[i].clone();
            g.set(Cell::new(c.0, c.1), Occ::Free);
            grids.push(g);
        }
        let mut t = Timeline::new(header());
        t.push(Record::Poses {
            step: 0,
            robots: vec![
                Pose {
                    id: 0,
                    x: 0.5,
                    y: 0.5,
                    theta: 0.0,
                    alive: true,
                },
                Pose {
                    id: 1,
                    x: 2.5,
                    y: 0.5,
                    theta: 0.0,
                    alive: true,
                },
            ],
        });
        for step in 0..3u32 {
            let s = step as usize;
            let change = if step == 0 {
                GridChange::Whole(grids[0].to_rle())
            } else {
                GridChange::Runs(diff(&grids[s - 1], &grids[s]))
            };
            t.push(report(0, step, step as f32, change, 10.0 * step as f32));
            t.push(report(
                1,
                step,
                3.0,
                GridChange::Whole(grids[0].to_rle()),
                5.0,
            ));
            t.push(Record::Links {
                step,
                links: vec![LinkStep {
                    a: 0,
                    b: 1,
                    up: step != 1,
                    bytes_a_to_b: 100,
                    bytes_b_to_a: 0,
                    queued_bytes: 3,
                    cut: (step == 1).then_some(proto::msg::LinkCut::Fault),
                }],
            });
        }
        (t, grids)
    }

    #[test]
    fn a_robots_grid_at_a_step_is_its_whole_grid_with_the_changes_since() {
        let (t, grids) = timeline();
        for (step, g) in grids.iter().enumerate() {
            assert_eq!(
                t.grid(0, step as Step).map(|x| x.cells().to_vec()),
                Some(g.cells().to_vec())
            );
        }
        assert!(t.grid(5, 2).is_none(), "no such robot");
        // Changes with no whole grid before them cannot be replayed.
        let mut bad = Timeline::new(header());
        bad.push(report(
            0,
            0,
            0.0,
            GridChange::Runs(vec![Run {
                gap: 0,
                len: 1,
                occ: Occ::Free,
            }]),
            0.0,
        ));
        assert!(bad.grid(0, 0).is_none());
    }

    #[test]
    fn a_step_is_complete_once_every_robot_alive_in_it_reported() {
        let (t, _) = timeline();
        assert!(t.complete(0), "both robots reported step 0");
        assert!(!t.complete(1), "no status of step 1");
        let mut t = Timeline::new(header());
        let pose = |id, alive| Pose {
            id,
            x: 0.5,
            y: 0.5,
            theta: 0.0,
            alive,
        };
        let whole = || GridChange::Whole(Grid::new(4, 3, Occ::Unknown).to_rle());
        t.push(Record::Poses {
            step: 4,
            robots: vec![pose(0, true), pose(1, true)],
        });
        t.push(report(0, 4, 0.0, whole(), 1.0));
        assert!(!t.complete(4), "robot 1 has not reported");
        t.push(report(1, 4, 0.0, whole(), 1.0));
        assert!(t.complete(4));
        // A dead robot is not waited for.
        t.push(Record::Poses {
            step: 5,
            robots: vec![pose(0, true), pose(1, false)],
        });
        t.push(report(0, 5, 0.0, whole(), 1.0));
        assert!(t.complete(5));
    }

    #[test]
    fn a_frame_shows_each_robots_report_of_the_step_and_the_series_up_to_it() {
        let (t, _) = timeline();
        let f = t.frame(1, true);
        assert_eq!(f.robots.len(), 2);
        assert_eq!((f.robots[0].x, f.robots[0].target), (1.0, Some((3.0, 2.0))));
        assert_eq!(f.links[0].state, "fault");
        assert_eq!(t.frame(2, false).links[0].state, "up");
        assert_eq!(f.coverage_pct, 10.0);
        assert_eq!(f.backlog_max, 7);
        // Bytes per class: both robots' latest totals (ins = step + 1 each, rep = 2 each).
        assert_eq!(f.bytes_by_type.get("ins"), Some(&4));
        assert_eq!(f.bytes_by_type.get("rep"), Some(&4));
        assert_eq!(f.trails.as_ref().map(|t| t[0].len()), Some(2));
        assert_eq!(t.span(), Some((0, 2)));
        assert_eq!(t.series().coverage, vec![5.0, 10.0, 20.0]);
        let d = t.robot(0, 2).expect("robot 0 reported");
        assert_eq!(
            (d.report.step, d.report.known_cells, d.report.views.len()),
            (2, 1, 1)
        );
        assert_eq!(d.frontier_cells, 2, "both free cells border unknown ones");
        assert!(t.robot(0, 2).is_some() && t.robot(7, 2).is_none());
    }

    #[test]
    fn a_frame_shows_how_its_links_step_used_the_channel_when_netem_said() {
        let (mut t, _) = timeline();
        let node = |id, share, lost| NodeAir {
            id,
            share,
            airtime: share / 2,
            utilisation: 0.75,
            frames_lost: lost,
            retransmitted: 0,
        };
        t.push(Record::Channel {
            step: 2,
            capacity: Some(250.0),
            nodes: vec![node(0, 120, 0), node(1, 80, 1)],
            links: vec![(
                0,
                1,
                LinkAir {
                    share: [Some(120), Some(80)],
                    airtime: [60, 40],
                    lost: [false, true],
                    delivery: [0.9, 0.6],
                },
            )],
        });
        let f = t.frame(2, false);
        assert_eq!(f.channel_capacity, Some(250.0));
        let air = f.robots[1].air.expect("robot 1's air");
        assert_eq!((air.share, air.airtime, air.frames_lost), (80, 40, 1));
        assert_eq!(air.utilisation, 0.75);
        let l = f.links[0].air.expect("the link's air");
        assert_eq!((l.delivery, l.lost), (0.6, 1));
        assert_eq!((l.delivery_a_to_b, l.lost_b_to_a), (0.9, true));
        assert_eq!((l.share_a_to_b, l.airtime_b_to_a), (Some(120), 40));
        // A step before it has none, and the page's JSON leaves out what is absent.
        let before = t.frame(1, false);
        assert!(before.channel_capacity.is_none() && before.links[0].air.is_none());
        assert!(before.robots.iter().all(|r| r.air.is_none()));
        let json = serde_json::to_value(&before).expect("test");
        assert!(json.get("channel_capacity").is_none(), "{json}");
        assert!(json["links"][0].get("air").is_none() && json["robots"][0].get("air").is_none());
        assert_eq!(
            serde_json::to_value(&f).expect("test")["links"][0]["air"]["lost"],
            1
        );
        // The next step's links, with no channel reported for it: no air from step 2.
        t.push(Record::Links {
            step: 3,
            links: vec![],
        });
        let after = t.frame(3, false);
        assert!(after.channel_capacity.is_none() && after.robots.iter().all(|r| r.air.is_none()));
    }
}
