//! The run's per-step tables written while it goes
//! ([`StepTables`](crate::rundir::tables::StepTables)): a step is written once it is *closed* — its
//! telemetry taken and netem's report of it in (netem reports a step when the next one opens) —
//! with the columns that need the step's links filled in (steps since contact with the base
//! station, the communication level). Its rows then leave the launcher's memory: what the summary
//! needs of them is kept as tallies ([`LinkTally`](crate::rundir::tables::LinkTally),
//! [`RowTally`](crate::run::tables::RowTally)). A launcher killed mid-run leaves every step it
//! closed on disk.

use std::collections::BTreeMap;
use std::path::Path;

use proto::msg::{LinkReport, RobotId, Step};

use crate::rundir::summary::{AwarenessSummary, CommLevel, FidelitySummary};
use crate::rundir::tables::{LinkTally, MetricsRow, StepRows, StepTables};
use crate::score::awareness::{Contact, StepMeans};
use crate::score::connectivity::comm_level_pct;
use crate::score::evaluate::Evaluator;

pub struct Tables {
    /// `None` once a write failed (the error is kept for the end; the run goes on).
    out: Option<StepTables>,
    error: Option<anyhow::Error>,
    /// netem's reports of steps not written yet, in arrival order.
    reports: BTreeMap<Step, Vec<LinkReport>>,
    /// The latest step netem reported.
    reported: Option<Step>,
    /// The next step to write.
    next: Step,
    contact: Option<Contact>,
    base: Option<RobotId>,
    robots: usize,
    nodes: usize,
    /// What the summary needs of the reports written.
    pub links: LinkTally,
    /// What the summary needs of the `metrics.csv` rows written.
    pub tally: RowTally,
}

/// What `summary.json` needs of the `metrics.csv` rows, tallied row by row as their steps are
/// written; the rows themselves are not kept (a run's rows grow with steps × robots). Kept: a
/// few numbers per robot, and per step the sums behind the means over steps (de Hoog et al.'s
/// curves, the communication level).
#[derive(Default)]
pub struct RowTally {
    robots: u16,
    base: Option<RobotId>,
    /// Over the rows of robots with a neighbour: the largest backlog, their sum and count.
    backlog: (u64, u64, u64),
    /// Per robot of the team, its latest row's step, `false_free_pct` and `on_walls_pct`.
    last: BTreeMap<RobotId, (Step, Option<f64>, Option<f64>)>,
    /// The base station's latest row's step and coverage.
    base_last: Option<(Step, f64)>,
    base_known: StepMeans,
    shared: StepMeans,
    since_base: StepMeans,
    since_base_max: Option<Step>,
    team: StepMeans,
    /// Per step, the communication level of its last row that has one.
    comm: BTreeMap<Step, f64>,
}

impl RowTally {
    /// The rows of a run of `robots` robots (ids `0..robots`) and the base station `base`.
    pub fn new(robots: u16, base: Option<RobotId>) -> RowTally {
        RowTally {
            robots,
            base,
            ..RowTally::default()
        }
    }

    pub fn add(&mut self, r: &MetricsRow) {
        if r.neighbours > 0 {
            let b = &mut self.backlog;
            *b = (b.0.max(r.backlog_bytes), b.1 + r.backlog_bytes, b.2 + 1);
        }
        if r.robot < self.robots {
            let e = self.last.entry(r.robot).or_insert((r.step, None, None));
            if r.step >= e.0 {
                *e = (r.step, r.false_free_pct, r.on_walls_pct);
            }
        }
        if let Some(c) = r.comm_level_pct {
            self.comm.insert(r.step, c);
        }
        if self.base == Some(r.robot) {
            if self.base_last.is_none_or(|(s, _)| r.step >= s) {
                self.base_last = Some((r.step, r.coverage_pct));
            }
            self.base_known.add(r.step, r.coverage_pct);
            return;
        }
        if let Some(v) = r.shared_pct {
            self.shared.add(r.step, v);
        }
        if let Some(v) = r.steps_since_base {
            self.since_base.add(r.step, f64::from(v));
            self.since_base_max = self.since_base_max.max(Some(v));
        }
        if let Some(v) = r.team_pct {
            self.team.add(r.step, v);
        }
    }

    /// The largest backlog of a robot with a neighbour, and the mean over such rows.
    pub fn backlogs(&self) -> (u64, f64) {
        let (max, sum, n) = self.backlog;
        (max, if n == 0 { 0.0 } else { sum as f64 / n as f64 })
    }

    /// `fidelity` in `summary.json`: over each robot's last row.
    pub fn fidelity(&self) -> FidelitySummary {
        crate::score::fidelity::summarize(self.last.values().map(|&(_, f, w)| (f, w)))
    }

    /// `awareness` in `summary.json` (with a base station).
    pub fn awareness(&self) -> Option<AwarenessSummary> {
        self.base.map(|_| AwarenessSummary {
            base_known_pct: self.base_last.map(|(_, c)| c),
            base_known_pct_mean: self.base_known.mean(),
            shared_pct_mean: self.shared.mean(),
            steps_since_base_mean: self.since_base.mean(),
            steps_since_base_max: self.since_base_max,
            team_pct_mean: self.team.mean(),
        })
    }

    /// `comm_level_pct` in `summary.json`: the lowest and the mean over the steps.
    pub fn comm_level(&self) -> Option<CommLevel> {
        let n = self.comm.len();
        (n > 0).then(|| CommLevel {
            min: self.comm.values().copied().fold(f64::INFINITY, f64::min),
            mean: self.comm.values().sum::<f64>() / n as f64,
        })
    }
}

impl Tables {
    /// The tables of a run of `robots` robots and `nodes` nodes (the base station, if any, is
    /// node `base`), in `dir`.
    pub fn create(
        dir: &Path,
        robots: usize,
        nodes: usize,
        base: Option<RobotId>,
    ) -> anyhow::Result<Tables> {
        Ok(Tables {
            out: Some(StepTables::create(dir)?),
            error: None,
            reports: BTreeMap::new(),
            reported: None,
            next: 0,
            contact: base.map(|b| Contact::new(nodes, b)),
            base,
            robots,
            nodes,
            links: LinkTally::default(),
            tally: RowTally::new(u16::try_from(robots).unwrap_or(u16::MAX), base),
        })
    }

    /// A report of netem's, kept until its step is written.
    pub fn report(&mut self, r: LinkReport) {
        self.reported = Some(self.reported.map_or(r.step, |s| s.max(r.step)));
        self.reports.entry(r.step).or_default().push(r);
    }

    /// The next step to write.
    pub fn next(&self) -> Step {
        self.next
    }

    /// The latest step netem reported.
    pub fn reported(&self) -> Option<Step> {
        self.reported
    }

    /// The steps netem's reports say are closed: up to its latest report (a run of fewer than
    /// two nodes has no links, and no reports to wait for).
    pub fn links_through(&self) -> Option<Step> {
        if self.nodes < 2 {
            Some(Step::MAX)
        } else {
            self.reported
        }
    }

    /// Drops the reports of steps after `last` (netem may have reported steps beyond the
    /// run's end while the launcher waited for the last one's reports).
    pub fn truncate(&mut self, last: Step) {
        self.reports.retain(|&s, _| s <= last);
    }

    /// The last step anything is held for (rows taken, reports in).
    pub fn held_through(&self, eval: &Evaluator) -> Option<Step> {
        let rows = eval.rows.iter().map(|r| r.step).max();
        rows.max(self.reports.keys().next_back().copied())
    }

    /// Writes every step up to `last`: its rows taken out of `eval` (the `metrics.csv` rows,
    /// save points and views of steps up to `last`), netem's reports of it. A step written
    /// already whose rows or reports come only now (a realtime report that came late, netem
    /// restarted) is written again, before the others, with what came.
    pub fn write_through(&mut self, last: Step, eval: &mut Evaluator) {
        let mut steps: BTreeMap<Step, StepRows> = BTreeMap::new();
        fn at(steps: &mut BTreeMap<Step, StepRows>, s: Step) -> &mut StepRows {
            steps.entry(s).or_insert_with(|| StepRows {
                step: s,
                ..StepRows::default()
            })
        }
        let (now, later) = std::mem::take(&mut eval.rows)
            .into_iter()
            .partition(|r| r.step <= last);
        eval.rows = later;
        for r in now {
            at(&mut steps, r.step).metrics.push(r);
        }
        for (s, robot, len, digest) in take_through(&mut eval.saves, last, |x| x.0) {
            at(&mut steps, s).saves.push((robot, len, digest));
        }
        for (s, robot, v) in take_through(&mut eval.views, last, |x| x.0) {
            at(&mut steps, s).views.push((robot, v));
        }
        let later = self.reports.split_off(&last.saturating_add(1));
        for (s, reports) in std::mem::replace(&mut self.reports, later) {
            let step = at(&mut steps, s);
            for r in reports {
                self.links.add(s, &r.links, &r.nodes);
                step.links.extend(r.links);
                step.nodes.extend(r.nodes);
            }
        }
        // Steps without anything to write still carry the contact with the base station.
        let mut since = BTreeMap::new();
        for s in self.next..=last {
            if let Some(c) = &mut self.contact {
                since.insert(s, c.step(self.links.up_at(s)));
            }
        }
        self.next = self.next.max(last.saturating_add(1));
        for (s, mut step) in steps {
            self.score(&mut step, since.get(&s).map(Vec::as_slice));
            if let Some(out) = &mut self.out {
                if let Err(e) = out.step(&mut step) {
                    tracing::warn!("{e:#}; no tables from here on");
                    self.error = Some(e);
                    self.out = None;
                }
            }
            for r in &step.metrics {
                self.tally.add(r);
            }
        }
    }

    /// Fills in the columns of a step's robot rows that need its links: the steps since each
    /// robot's last contact with the base station (`since`: with a base station, a step not
    /// written before) and the
    /// communication level (Rooker and Birk 2005, Fig. 6; a step without links up has every
    /// robot alone).
    fn score(&self, step: &mut StepRows, since: Option<&[Step]>) {
        let level = comm_level_pct(self.robots, self.nodes, self.links.up_at(step.step));
        for row in step
            .metrics
            .iter_mut()
            .filter(|r| Some(r.robot) != self.base)
        {
            row.comm_level_pct = Some(level);
            row.steps_since_base = since.and_then(|s| s.get(usize::from(row.robot)).copied());
        }
    }

    /// The first error writing the tables, if one failed (written no more since).
    pub fn check(&mut self) -> anyhow::Result<()> {
        self.error.take().map_or(Ok(()), Err)
    }
}

/// Takes out of `v` the items of steps up to `last` (the others stay), in order.
fn take_through<T>(v: &mut Vec<T>, last: Step, step: impl Fn(&T) -> Step) -> Vec<T> {
    let (now, later) = std::mem::take(v).into_iter().partition(|x| step(x) <= last);
    *v = later;
    now
}
