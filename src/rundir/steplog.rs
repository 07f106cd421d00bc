//! The run's step log, `steps.log` in the run directory: what a viewer needs to show a run again
//! step by step — where every robot stood and where it was going, every link's state and bytes, and
//! how every robot's planning grid changed. Changes, not whole grids: a robot's grid is written
//! whole at its first report, after a restart and every
//! [`KEYFRAME_STEPS`](crate::rundir::steplog::KEYFRAME_STEPS) steps (so a replay can seek),
//! otherwise as runs of the cells that changed since its last report.
//!
//! The launcher writes it as it takes the run's reports
//! ([`StepLogWriter`](crate::rundir::steplog::StepLogWriter)); `swarm view` and `swarm export-mcap`
//! read it ([`read`](crate::rundir::steplog::read)). The file is a sequence of records, each a
//! little-endian `u32` length and the record in postcard; the first is a
//! [`Header`](crate::rundir::steplog::Header). Reading is total: a file that is not a step log
//! gives an error naming the file and where it stops — never a panic. A log cut short mid-record (a
//! launcher that died) reads to its last whole record and says where it was cut
//! ([`StepLog::cut`](crate::rundir::steplog::StepLog::cut)); a log still being written (the
//! launcher flushes it at every step) the same way: [`read`](crate::rundir::steplog::read) is both.
//!
//! **Invariant:** replaying a robot's grid changes from its last whole grid gives exactly the grid
//! it reported at that step (property-tested: [`diff`](crate::rundir::steplog::diff) then
//! [`apply`](crate::rundir::steplog::apply)).

use std::collections::BTreeMap;
use std::fs::File;
use std::io::{BufWriter, Read, Write};
use std::path::{Path, PathBuf};

use proto::geom::MapInfo;
use proto::grid::{Grid, Occ};
use proto::grid_report::Change;
use proto::msg::{LinkAir, LinkReport, NodeAir, RobotId, Status, Step, Telemetry};
use serde::{Deserialize, Serialize};

/// The file's name in a run directory.
pub const FILE: &str = "steps.log";
/// Format version, in the header.
pub const VERSION: u32 = 1;
/// What the header's `magic` holds.
pub const MAGIC: [u8; 8] = *b"swarmlog";
/// A robot's grid is written whole at least this often (in its steps).
pub const KEYFRAME_STEPS: Step = 100;
/// The largest record a reader accepts (a whole grid of `MAX_CELLS` cells in RLE fits).
const MAX_RECORD_BYTES: usize = 256 << 20;

/// The first record.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Header {
    pub magic: [u8; 8],
    pub version: u32,
    /// The map's frame (every grid below is of this size).
    pub map: MapInfo,
    /// Robots in the run (ids `0..robots`); a base station, if any, is node `robots`.
    pub robots: u16,
    /// Simulated seconds per step.
    pub step_seconds: f64,
    /// The truth map, run-length encoded ([`Grid::to_rle`]).
    pub truth: Vec<u8>,
}

/// One record of the log.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub enum Record {
    Header(Header),
    /// The world's status before step `step`'s moves: every robot's pose and whether it lives.
    Poses {
        step: Step,
        robots: Vec<Pose>,
    },
    /// What a robot reported of a step, and how its planning grid changed.
    Robot(RobotStep, GridChange),
    /// netem's report of step `step`.
    Links {
        step: Step,
        links: Vec<LinkStep>,
    },
    /// How step `step` used the radio channel, as netem reported it: written right after the
    /// step's [`Record::Links`], only when netem shares the channel or loses frames. Last of the
    /// variants, so logs written before it read as they did.
    Channel {
        step: Step,
        /// Bytes the shared channel carries in a step; `None`: netem does not allocate its
        /// airtime (lossy links on their own budgets).
        capacity: Option<f64>,
        /// Each live node's use of the channel.
        nodes: Vec<NodeAir>,
        /// Each link's use of it, `(a, b, air)`: only links that could carry something.
        links: Vec<(RobotId, RobotId, LinkAir)>,
    },
}

impl Record {
    /// The step the record is of (none for the header).
    pub fn step(&self) -> Option<Step> {
        match self {
            Record::Poses { step, .. }
            | Record::Links { step, .. }
            | Record::Channel { step, .. } => Some(*step),
            Record::Robot(rs, _) => Some(rs.step),
            Record::Header(_) => None,
        }
    }
}

#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Pose {
    pub id: RobotId,
    pub x: f32,
    pub y: f32,
    pub theta: f32,
    pub alive: bool,
}

/// What robot `robot` reported of step `step` — the launcher's one record of a robot's step: built
/// from its telemetry ([`StepLogWriter::robot_step`]), written to `steps.log` (beside its grid's
/// change), read by the MCAP export, and served to the page as it is ([`crate::view::timeline`]).
/// Numbers are `f32`: the log keeps a run of 128 robots small, and a millimetre is finer than a
/// cell.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct RobotStep {
    pub step: Step,
    pub robot: RobotId,
    pub life: u16,
    /// Where the robot stood when it decided (metres, radians).
    pub x: f32,
    pub y: f32,
    pub theta: f32,
    pub target: Option<(f32, f32)>,
    pub idle: bool,
    pub known_cells: u32,
    pub bytes_sent: u64,
    pub bytes_received: u64,
    /// Polygon exchange: the splitting frequency for the next step.
    pub splits_per_step: Option<f32>,
    /// The largest backlog to any neighbour, bytes.
    pub backlog_bytes: u64,
    /// Payload bytes sent so far in this life, per traffic class ([`proto::msg::Traffic::ALL`]
    /// order).
    pub sent_by_type: Vec<u64>,
    /// Polygon exchange: per other owner, the ops of its log held and shown (up to its last
    /// save point held).
    pub views: Vec<ViewRow>,
    /// The evaluator's coverage of the report, % of the reachable free cells.
    pub coverage_pct: Option<f32>,
}

/// What a robot shows of another owner's log: the ops it holds and those it shows (polygon
/// exchange).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct ViewRow {
    pub owner: RobotId,
    pub held: u32,
    pub shown: u32,
}

/// How a robot's planning grid changed.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub enum GridChange {
    /// The whole grid, run-length encoded ([`Grid::to_rle`]).
    Whole(Vec<u8>),
    /// The cells that changed since the robot's last report, as runs.
    Runs(Vec<Run>),
}

/// `len` cells of value `occ`, starting `gap` cells after the end of the run before it (the
/// first: after cell 0), in row-major order.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct Run {
    pub gap: u32,
    pub len: u32,
    pub occ: Occ,
}

#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct LinkStep {
    pub a: RobotId,
    pub b: RobotId,
    pub up: bool,
    pub bytes_a_to_b: u64,
    pub bytes_b_to_a: u64,
    pub queued_bytes: u64,
    /// Why it carries nothing (down, or up but held).
    pub cut: Option<proto::msg::LinkCut>,
}

/// The runs that turn `old` into `new` (grids of one size), over the cells either may know.
pub fn diff(old: &Grid, new: &Grid) -> Vec<Run> {
    let Some(r) = proto::grid::Rect::union_of(old.known_bounds(), new.known_bounds()) else {
        return Vec::new();
    };
    runs_over(r, |y| old.row(y, r.min.x, r.max.x), new)
}

/// [`diff`] of a reported change: the runs that turn the cells `change.before` held into `new`
/// (the grid after the change), over the change's rectangle — outside it nothing changed.
pub fn diff_change(change: &Change, new: &Grid) -> Vec<Run> {
    let Some(r) = change.rect else {
        return Vec::new();
    };
    let w = r.width() as usize;
    runs_over(
        r,
        |y| &change.before[(y - r.min.y) as usize * w..][..w],
        new,
    )
}

/// The runs of the cells of `r` where `old_row(y)` (row `y` over `r`'s columns) and `new`
/// differ; a run stays within its row.
fn runs_over<'a>(r: proto::grid::Rect, old_row: impl Fn(i32) -> &'a [Occ], new: &Grid) -> Vec<Run> {
    let mut runs = Vec::new();
    let w = new.width() as usize;
    let mut end = 0usize; // the end of the last run
    for y in r.min.y..=r.max.y {
        let (a, b) = (old_row(y), new.row(y, r.min.x, r.max.x));
        let row = y as usize * w + r.min.x as usize;
        let mut x = 0;
        while x < b.len() {
            if a[x] == b[x] {
                x += 1;
                continue;
            }
            let occ = b[x];
            let mut len = 1;
            while x + len < b.len() && a[x + len] != b[x + len] && b[x + len] == occ {
                len += 1;
            }
            let i = row + x;
            runs.push(Run {
                gap: (i - end) as u32,
                len: len as u32,
                occ,
            });
            end = i + len;
            x += len;
        }
    }
    runs
}

/// Applies `runs` to `grid`; runs past its end are an error (a foreign or damaged log).
pub fn apply(grid: &mut Grid, runs: &[Run]) -> Result<(), String> {
    let mut at = 0usize;
    for r in runs {
        let start = at
            .checked_add(r.gap as usize)
            .ok_or("a run's position overflows")?;
        let end = start
            .checked_add(r.len as usize)
            .filter(|&e| e <= grid.len())
            .ok_or_else(|| format!("a run ends past the grid's {} cells", grid.len()))?;
        for i in start..end {
            grid.set_index(i, r.occ);
        }
        at = end;
    }
    Ok(())
}

/// What gets every record written after the header.
pub type Tee = Box<dyn FnMut(&Record) + Send>;

/// Writes `steps.log` as the launcher takes the run's reports.
pub struct StepLogWriter {
    out: BufWriter<File>,
    path: PathBuf,
    /// Per robot: the life of its last report, and the step its grid was last whole.
    last: BTreeMap<RobotId, (u16, Step)>,
    /// Bytes written so far.
    pub bytes: u64,
    header: Header,
    /// Bytes the shared channel carries in a step, for [`Record::Channel`].
    channel_capacity: Option<f64>,
    /// Get every record written after the header (the live viewers: the page, Foxglove).
    pub tees: Vec<Tee>,
}

impl StepLogWriter {
    pub fn create(
        dir: &Path,
        map: MapInfo,
        truth: &Grid,
        robots: u16,
        step_seconds: f64,
    ) -> anyhow::Result<StepLogWriter> {
        let path = dir.join(FILE);
        let file = File::create(&path)
            .map_err(|e| anyhow::anyhow!("cannot create {}: {e}", path.display()))?;
        let header = Header {
            magic: MAGIC,
            version: VERSION,
            map,
            robots,
            step_seconds,
            truth: truth.to_rle(),
        };
        let mut w = StepLogWriter {
            out: BufWriter::new(file),
            path,
            last: BTreeMap::new(),
            bytes: 0,
            header: header.clone(),
            channel_capacity: None,
            tees: Vec::new(),
        };
        w.write(&Record::Header(header))?;
        Ok(w)
    }

    /// The shared channel's capacity, bytes a step, that [`Record::Channel`] records carry
    /// (the scenario's [`proto::scenario::Radio::channel_capacity`]; `None`: not shared).
    pub fn with_channel_capacity(mut self, capacity: Option<f64>) -> StepLogWriter {
        self.channel_capacity = capacity;
        self
    }

    /// The log's header.
    pub fn header(&self) -> &Header {
        &self.header
    }

    fn write(&mut self, r: &Record) -> anyhow::Result<()> {
        let bytes = postcard::to_stdvec(r)?;
        let len = u32::try_from(bytes.len())?;
        self.out
            .write_all(&len.to_le_bytes())
            .and_then(|()| self.out.write_all(&bytes))
            .map_err(|e| anyhow::anyhow!("cannot write {}: {e}", self.path.display()))?;
        self.bytes += 4 + bytes.len() as u64;
        for tee in &mut self.tees {
            tee(r);
        }
        Ok(())
    }

    pub fn status(&mut self, st: &Status) -> anyhow::Result<()> {
        let robots = st
            .robots
            .iter()
            .chain(&st.base)
            .map(|r| Pose {
                id: r.id,
                x: r.pose.x as f32,
                y: r.pose.y as f32,
                theta: r.pose.theta as f32,
                alive: r.alive,
            })
            .collect();
        self.write(&Record::Poses {
            step: st.step,
            robots,
        })?;
        // A step's world status comes before the step's reports: everything of the steps
        // before it is in, so the file holds whole steps for whoever reads it while the run
        // goes on ([`read`]).
        self.out
            .flush()
            .map_err(|e| anyhow::anyhow!("cannot write {}: {e}", self.path.display()))
    }

    /// Robot `robot`'s grid changed without a record (a report taken late): its next record
    /// holds its grid whole.
    pub fn forget(&mut self, robot: RobotId) {
        self.last.remove(&robot);
    }

    /// A robot's report as a record (its grid as changes since its last report), for
    /// [`Self::robot`] once scored: `grid` is its planning grid after the report, `change` what
    /// the report changed of it (as the evaluator took it).
    pub fn robot_step(
        &mut self,
        t: &Telemetry,
        grid: &Grid,
        change: &Change,
    ) -> (RobotStep, GridChange) {
        let (change, whole_at) = match self.last.get(&t.robot) {
            Some(&(life, whole_at))
                if life == t.life && t.step < whole_at.saturating_add(KEYFRAME_STEPS) =>
            {
                (GridChange::Runs(diff_change(change, grid)), whole_at)
            }
            _ => (GridChange::Whole(grid.to_rle()), t.step),
        };
        self.last.insert(t.robot, (t.life, whole_at));
        let report = RobotStep {
            step: t.step,
            robot: t.robot,
            life: t.life,
            x: t.pose.x as f32,
            y: t.pose.y as f32,
            theta: t.pose.theta as f32,
            target: t.target.map(|p| (p.x as f32, p.y as f32)),
            idle: t.idle,
            known_cells: t.known_cells,
            bytes_sent: t.bytes_sent,
            bytes_received: t.bytes_received,
            splits_per_step: t.splits_per_step.map(|s| s as f32),
            backlog_bytes: t.backlog_bytes.iter().map(|b| b.1).max().unwrap_or(0),
            sent_by_type: t.sent_by_type.clone(),
            views: (t.views.iter())
                .map(|v| ViewRow {
                    owner: v.owner,
                    held: v.held,
                    shown: v.shown,
                })
                .collect(),
            coverage_pct: None,
        };
        (report, change)
    }

    /// Writes a robot's report.
    pub fn robot(&mut self, r: RobotStep, grid: GridChange) -> anyhow::Result<()> {
        self.write(&Record::Robot(r, grid))
    }

    /// Writes netem's report of a step: its links, then how the step used the radio channel
    /// when the report says (nodes on the channel, or links with their airtime or losses).
    pub fn links(&mut self, r: &LinkReport) -> anyhow::Result<()> {
        let links = r
            .links
            .iter()
            .map(|l| LinkStep {
                a: l.a,
                b: l.b,
                up: l.up,
                bytes_a_to_b: l.bytes_a_to_b,
                bytes_b_to_a: l.bytes_b_to_a,
                queued_bytes: l.queued_bytes,
                cut: l.cut,
            })
            .collect();
        self.write(&Record::Links {
            step: r.step,
            links,
        })?;
        let air: Vec<(RobotId, RobotId, LinkAir)> = (r.links.iter())
            .filter_map(|l| Some((l.a, l.b, l.air?)))
            .collect();
        if r.nodes.is_empty() && air.is_empty() {
            return Ok(());
        }
        self.write(&Record::Channel {
            step: r.step,
            capacity: self.channel_capacity,
            nodes: r.nodes.clone(),
            links: air,
        })
    }

    /// Flushes what is buffered; the size of the file.
    pub fn finish(mut self) -> anyhow::Result<u64> {
        self.out
            .flush()
            .map_err(|e| anyhow::anyhow!("cannot write {}: {e}", self.path.display()))?;
        Ok(self.bytes)
    }
}

/// A step log read back: its header and records in order.
#[derive(Clone, Debug)]
pub struct StepLog {
    pub header: Header,
    pub records: Vec<Record>,
    /// Where the file was cut short, if it was (a launcher that died mid-record): the records
    /// are the whole ones before it.
    pub cut: Option<String>,
}

impl StepLog {
    /// How many steps behind the latest step written before it any record came (netem's
    /// report of a step comes once the next step opens, and later on a loaded machine): how long
    /// a reader that goes through the records in order must hold a step back to have all of it.
    pub fn lateness(&self) -> Step {
        let mut latest: Option<Step> = None;
        let mut most = 0;
        for s in self.records.iter().filter_map(Record::step) {
            if let Some(l) = latest {
                most = most.max(l.saturating_sub(s));
            }
            latest = latest.max(Some(s));
        }
        most
    }

    /// What a reader of the log in `dir` tells its user if the log was cut short: where, and
    /// what it shows of it.
    pub fn cut_warning(&self, dir: &Path) -> Option<String> {
        self.cut.as_ref().map(|at| {
            format!(
                "{}: {at}: the run's launcher stopped mid-record; reading the {} whole records \
                 before it (up to step {})",
                dir.join(FILE).display(),
                self.records.len() + 1,
                self.reached().map_or("none".into(), |s| s.to_string())
            )
        })
    }

    /// The latest step whose world status the log holds: how far the run has come.
    pub fn reached(&self) -> Option<Step> {
        self.records
            .iter()
            .filter_map(|r| match r {
                Record::Poses { step, .. } => Some(*step),
                _ => None,
            })
            .max()
    }

    /// The last step any robot's report was taken for (the run's last step), if any.
    pub fn last_step(&self) -> Option<Step> {
        self.records
            .iter()
            .filter_map(|r| match r {
                Record::Robot(r, _) => Some(r.step),
                _ => None,
            })
            .max()
    }
}

impl Header {
    /// The truth map (checked to decode when a log is read; all unknown if it does not).
    pub fn truth(&self) -> Grid {
        Grid::from_rle(&self.truth)
            .unwrap_or_else(|_| Grid::new(self.map.width, self.map.height, Occ::Unknown))
    }
}

/// Every robot's planning grid, kept up to date record by record.
#[derive(Default)]
pub struct Grids {
    pub grids: BTreeMap<RobotId, Grid>,
}

impl Grids {
    /// Applies one robot report's grid change; an error names what does not fit.
    pub fn apply(
        &mut self,
        map: &MapInfo,
        r: &RobotStep,
        grid: &GridChange,
    ) -> Result<&Grid, String> {
        let at = |e: String| format!("robot {} step {}: {e}", r.robot, r.step);
        if matches!(grid, GridChange::Runs(_)) && !self.grids.contains_key(&r.robot) {
            return Err(at("changes before a whole grid".into()));
        }
        let slot = self
            .grids
            .entry(r.robot)
            .or_insert_with(|| Grid::new(map.width, map.height, Occ::Unknown));
        match grid {
            GridChange::Whole(rle) => {
                let g = Grid::from_rle(rle).map_err(|e| at(e.to_string()))?;
                if g.width() != map.width || g.height() != map.height {
                    return Err(at("a grid not of the map's size".into()));
                }
                *slot = g;
            }
            GridChange::Runs(runs) => apply(slot, runs).map_err(at)?,
        }
        Ok(slot)
    }
}

/// Reads `dir/steps.log` to its last whole record: a log its launcher left cut short mid-record
/// (killed) reads as far as it is whole, and says where it was cut ([`StepLog::cut`]); one that
/// is not a step log, or is damaged before its end, is an error.
pub fn read(dir: &Path) -> anyhow::Result<StepLog> {
    let path = dir.join(FILE);
    let mut bytes = Vec::new();
    File::open(&path)
        .and_then(|mut f| f.read_to_end(&mut bytes))
        .map_err(|e| anyhow::anyhow!("cannot read {}: {e}", path.display()))?;
    decode(&bytes).map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))
}

/// Decodes the whole records of a step log, leaving out a record cut short at its end (and
/// saying where, [`StepLog::cut`]). Total: any bytes give a log or an error.
pub fn decode(mut bytes: &[u8]) -> Result<StepLog, String> {
    let mut records = Vec::new();
    let mut at = 0usize;
    let mut cut_at = None;
    while !bytes.is_empty() {
        let cut =
            |records: &Vec<Record>| format!("cut short at byte {at} (record {})", records.len());
        let Some((len, rest)) = bytes.split_first_chunk::<4>() else {
            cut_at = Some(cut(&records));
            break;
        };
        let len = u32::from_le_bytes(*len) as usize;
        if len > MAX_RECORD_BYTES {
            return Err(format!(
                "record {} at byte {at} claims {len} bytes: not a step log",
                records.len()
            ));
        }
        let Some((body, rest)) = rest.split_at_checked(len) else {
            cut_at = Some(cut(&records));
            break;
        };
        let r: Record = postcard::from_bytes(body)
            .map_err(|e| format!("record {} at byte {at} does not decode: {e}", records.len()))?;
        records.push(r);
        at += 4 + len;
        bytes = rest;
    }
    let mut records = records.into_iter();
    let header = match records.next() {
        Some(Record::Header(h)) if h.magic == MAGIC => h,
        _ => return Err("not a step log (no header)".into()),
    };
    if header.version != VERSION {
        return Err(format!(
            "step log version {} (this swarm reads version {VERSION})",
            header.version
        ));
    }
    if u64::from(header.map.width) * u64::from(header.map.height) > proto::grid::MAX_CELLS {
        return Err("the map in its header is larger than any grid".into());
    }
    match Grid::from_rle(&header.truth) {
        Ok(g) if g.width() == header.map.width && g.height() == header.map.height => {}
        _ => return Err("the truth map in its header does not decode to the map's size".into()),
    }
    Ok(StepLog {
        header,
        records: records.collect(),
        cut: cut_at,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;
    use proto::grid_report::{GridReport, Received};

    fn grid_of(w: u32, h: u32, cells: &[u8]) -> Grid {
        let mut g = Grid::new(w, h, Occ::Unknown);
        for (i, &c) in cells.iter().enumerate().take(g.len()) {
            let v = match c % 3 {
                0 => Occ::Unknown,
                1 => Occ::Free,
                _ => Occ::Occupied,
            };
            if v != Occ::Unknown {
                g.set_index(i, v);
            }
        }
        g
    }

    proptest! {
        #[test]
        fn applying_the_diff_gives_the_new_grid(
            w in 1u32..20, h in 1u32..20,
            a in prop::collection::vec(0u8..9, 0..400),
            b in prop::collection::vec(0u8..9, 0..400),
        ) {
            let (old, new) = (grid_of(w, h, &a), grid_of(w, h, &b));
            let runs = diff(&old, &new);
            let mut g = old.clone();
            apply(&mut g, &runs).expect("test");
            prop_assert_eq!(g.cells(), new.cells());
            // Runs cover changed cells only.
            let changed = old.cells().iter().zip(new.cells()).filter(|(x, y)| x != y).count();
            prop_assert_eq!(runs.iter().map(|r| r.len as usize).sum::<usize>(), changed);
        }

        #[test]
        fn any_bytes_decode_or_give_an_error(bytes in prop::collection::vec(any::<u8>(), 0..300)) {
            let _ = decode(&bytes);
        }

        /// The runs of a reported change are the runs between the whole grids: a log written
        /// from changes is the log written from whole grids, byte for byte.
        #[test]
        fn a_changes_runs_are_the_runs_between_the_whole_grids(
            w in 1u32..12,
            h in 1u32..8,
            steps in prop::collection::vec(
                prop::collection::vec((0usize..96, 0u8..3), 0..8), 1..40),
        ) {
            let mut rep = proto::grid_report::Reporter::default();
            let mut held = Received::new(w, h);
            let mut g = Grid::new(w, h, Occ::Unknown);
            for (step, edits) in steps.iter().enumerate() {
                let old = g.clone();
                for &(i, v) in edits {
                    g.set_index(i % g.len(), [Occ::Unknown, Occ::Free, Occ::Occupied][usize::from(v)]);
                }
                let c = held.apply(step as Step, &rep.report(step as Step, &g)).expect("test");
                prop_assert_eq!(diff_change(&c, &held.grid), diff(&old, &g));
            }
        }
    }

    /// The bytes the first `n` records of `log` (its header first) take in the file.
    fn encoded_len(log: &StepLog, n: usize) -> usize {
        std::iter::once(Record::Header(log.header.clone()))
            .chain(log.records.iter().cloned())
            .take(n)
            .map(|r| 4 + postcard::to_stdvec(&r).expect("test").len())
            .sum()
    }

    #[test]
    fn a_log_reads_back_and_a_cut_one_names_where() {
        let dir = std::env::temp_dir().join(format!("steplog-{}", std::process::id()));
        std::fs::create_dir_all(&dir).expect("test");
        let map = MapInfo::at_origin(4, 3, 0.5);
        let truth = Grid::new(4, 3, Occ::Free);
        let mut w = StepLogWriter::create(&dir, map, &truth, 1, 1.0).expect("test");
        let mut g = Grid::new(4, 3, Occ::Unknown);
        g.set(proto::grid::Cell::new(1, 1), Occ::Free);
        let mut held = Received::new(4, 3);
        let mut t = Telemetry::default();
        let c = held.apply(0, &GridReport::Whole(g.to_rle())).expect("test");
        let (r, grid) = w.robot_step(&t, &held.grid, &c);
        w.robot(r, grid).expect("test");
        w.status(&Status {
            step: 1,
            robots: vec![],
            collisions_total: 0,
            blocked_total: 0,
            base: None,
            missed: vec![],
        })
        .expect("test");
        let so_far = read(&dir).expect("flushed at the step's status");
        assert_eq!((so_far.reached(), so_far.records.len()), (Some(1), 2));
        g.set(proto::grid::Cell::new(2, 1), Occ::Occupied);
        t.step = 1;
        let c = held.apply(1, &GridReport::Whole(g.to_rle())).expect("test");
        let (r, grid) = w.robot_step(&t, &held.grid, &c);
        w.robot(r, grid).expect("test");
        w.finish().expect("test");
        let log = read(&dir).expect("test");
        assert_eq!(log.header.map, map);
        let Record::Robot(_, grid) = &log.records[2] else {
            panic!("{:?}", log.records[2]);
        };
        assert_eq!(
            *grid,
            GridChange::Runs(vec![Run {
                gap: 6,
                len: 1,
                occ: Occ::Occupied
            }])
        );
        let bytes = std::fs::read(dir.join(FILE)).expect("test");
        std::fs::write(dir.join(FILE), &bytes[..bytes.len() - 1]).expect("test");
        let e = decode(&bytes[..bytes.len() - 1])
            .expect("the whole records")
            .cut;
        assert!(e.as_ref().is_some_and(|e| e.contains("cut short")), "{e:?}");
        // A reader reads it to its last whole record and says where it was cut.
        let torn = read(&dir).expect("the whole records");
        assert_eq!(torn.records.len(), log.records.len() - 1);
        let w = torn.cut_warning(&dir).expect("a warning");
        assert!(
            w.contains("steps.log")
                && w.contains("cut short at byte")
                && w.contains("up to step 1"),
            "{w}"
        );
        assert_eq!(log.cut, None);
        // Read so far: every whole record, at every cut.
        for cut in 0..bytes.len() {
            let whole = match decode(&bytes[..cut]) {
                Ok(l) => l.records.len() + 1,
                Err(_) => 0,
            };
            let want = (1..=log.records.len() + 1)
                .take_while(|&n| encoded_len(&log, n) <= cut)
                .last()
                .unwrap_or(0);
            assert_eq!(whole, want, "cut at byte {cut}");
        }
        std::fs::write(dir.join(FILE), b"PK\x03\x04 a zip file").expect("test");
        assert!(read(&dir).is_err());
        std::fs::remove_dir_all(&dir).expect("test");
    }

    #[test]
    fn the_channel_of_a_step_follows_its_links_only_when_netem_reports_it() {
        let dir = std::env::temp_dir().join(format!("steplog-air-{}", std::process::id()));
        std::fs::create_dir_all(&dir).expect("test");
        let map = MapInfo::at_origin(4, 3, 0.5);
        let truth = Grid::new(4, 3, Occ::Free);
        let mut w = StepLogWriter::create(&dir, map, &truth, 3, 0.5)
            .expect("test")
            .with_channel_capacity(Some(500.0));
        let link = |a, b, air| proto::msg::LinkState {
            a,
            b,
            up: true,
            distance_m: Some(2.0),
            bytes_a_to_b: 40,
            bytes_b_to_a: 0,
            bytes_total: 40,
            queued_bytes: 0,
            connected: true,
            cut: None,
            air,
        };
        let air = LinkAir {
            share: [Some(120), Some(80)],
            airtime: [30, 0],
            lost: [false, true],
            delivery: [0.9, 0.6],
        };
        let node = NodeAir {
            id: 1,
            share: 200,
            airtime: 30,
            utilisation: 0.25,
            frames_lost: 1,
            retransmitted: 12,
        };
        // A step on a channel netem neither shares nor loses frames on: its links only.
        w.links(&LinkReport {
            step: 0,
            links: vec![link(0, 1, None)],
            nodes: vec![],
        })
        .expect("test");
        w.links(&LinkReport {
            step: 1,
            links: vec![link(0, 1, Some(air)), link(0, 2, None)],
            nodes: vec![node],
        })
        .expect("test");
        w.finish().expect("test");
        let log = read(&dir).expect("test");
        assert_eq!(log.records.len(), 3, "{:?}", log.records);
        assert!(matches!(log.records[0], Record::Links { step: 0, .. }));
        assert!(matches!(log.records[1], Record::Links { step: 1, .. }));
        assert_eq!(
            log.records[2],
            Record::Channel {
                step: 1,
                capacity: Some(500.0),
                nodes: vec![node],
                links: vec![(0, 1, air)],
            }
        );
        // The last variant: every record of a log written before it keeps its tag.
        let bytes = postcard::to_stdvec(&log.records[2]).expect("test");
        assert_eq!(bytes[0], 4);
        std::fs::remove_dir_all(&dir).expect("test");
    }
}
