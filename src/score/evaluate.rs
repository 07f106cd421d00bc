//! The evaluator (docs/design.md §6): scores every robot's reported planning grid against the truth.
//!
//! Exploration time is the first step at which some robot knows at least `done_pct` % of the
//! truth's reachable free cells (the thesis: the first robot that knows the full map); the
//! steps to 50/90/95/100 % are kept too. A reachable free cell is *known* when the robot's
//! planning grid has it free or occupied: the polygon exchange's approximations may put a wall a
//! cell off (that is their error e_avg, eq. 6.1), and the cell was explored all the same. Whether
//! a known cell is also right is counted apart: a cell is known-correct when the robot's state
//! agrees with the truth (truth-unknown space is opaque in the simulation, so a robot that marks
//! it occupied is right).

use std::collections::BTreeMap;

use proto::exit::ExitReason;
use proto::grid::{Cell, Grid, Occ};
use proto::grid_report::{Change, Received};
use proto::msg::{Judged, RobotId, Step, Telemetry, View};

use crate::rundir::summary::THRESHOLDS;
use crate::rundir::tables::MetricsRow;
use crate::score::awareness::{knows, SharedKnowledge};
use crate::score::fidelity::Fidelity;

impl MetricsRow {
    /// The row of telemetry `t`, with the evaluator's counts; the team columns are set later
    /// ([`Evaluator::share_rows_since`], the launcher's link scoring).
    fn of(t: &Telemetry, fidelity: Fidelity, coverage_pct: f64) -> MetricsRow {
        MetricsRow {
            step: t.step,
            robot: t.robot,
            x: t.pose.x,
            y: t.pose.y,
            known_cells: t.known_cells,
            correct_known_cells: fidelity.correct,
            target_x: t.target.map(|p| p.x),
            target_y: t.target.map(|p| p.y),
            bytes_sent: t.bytes_sent,
            bytes_received: t.bytes_received,
            coverage_pct,
            idle: t.idle,
            neighbours: t.neighbours.len(),
            sent_by_type: t.sent_by_type.clone(),
            splits_per_step: t.splits_per_step,
            backlog_bytes: t.backlog_bytes.iter().map(|&(_, b)| b).max().unwrap_or(0),
            alone: t.alone,
            shared_pct: None,
            steps_since_base: None,
            team_pct: None,
            comm_level_pct: None,
            free_cells: fidelity.free,
            false_free_cells: fidelity.false_free,
            on_wall_cells: fidelity.on_walls,
            false_free_pct: fidelity.false_free_pct(),
            on_walls_pct: fidelity.on_walls_pct(),
        }
    }
}

/// What the evaluator holds of one robot.
pub struct Last {
    /// Its planning grid as reported (the truth's size).
    pub planning: Received,
    /// Its own grid G_s as reported, and why its last report could not be taken, if it could
    /// not (the grid is then of an earlier step, until the next whole one).
    pub own: (Received, Option<String>),
    /// Its last telemetry taken.
    pub t: Telemetry,
    /// The reachable cells its planning grid knows, and what the grid believes against the
    /// truth: kept up to date by the cells each report changed.
    known: usize,
    fidelity: Fidelity,
}

pub struct Evaluator {
    truth: Grid,
    reachable: Vec<bool>,
    reachable_count: usize,
    done_pct: f64,
    pub rows: Vec<MetricsRow>,
    /// Step at which some robot first reached each threshold.
    pub coverage_steps: BTreeMap<u32, Step>,
    pub exploration_step: Option<Step>,
    /// Best coverage so far, and the robot that has it.
    pub best: (f64, RobotId),
    /// Every robot's grids as reported, its last telemetry and its counts.
    pub last: BTreeMap<RobotId, Last>,
    pub bad_telemetry: u64,
    /// Polygon exchange, for `saves.csv`: every save point a robot reported of its own log
    /// (step, robot, log length, digest of A_t).
    pub saves: Vec<(Step, RobotId, u32, u64)>,
    /// For `views.csv`: every change of what a robot shows of another owner.
    pub views: Vec<(Step, RobotId, View)>,
    /// `pack`: every leader's judgement of its group's links.
    pub judged: Vec<Judged>,
    /// The base station's node id: its reports are recorded (its map, its bytes) but it is no
    /// robot, so its coverage is kept apart ([`Self::base_coverage_steps`]) and never decides
    /// the exploration time.
    pub base: Option<RobotId>,
    /// Step at which the base station first knew each threshold's share.
    pub base_coverage_steps: BTreeMap<u32, Step>,
    /// What every robot knows, from the latest grid of each (the base station is no member).
    shared: SharedKnowledge,
}

impl Evaluator {
    pub fn new(truth: Grid, reachable: &Grid, done_pct: f64) -> Evaluator {
        let reachable: Vec<bool> = reachable.cells().iter().map(|&c| c == Occ::Free).collect();
        let reachable_count = reachable.iter().filter(|&&r| r).count();
        Evaluator {
            truth,
            reachable,
            reachable_count,
            done_pct,
            rows: Vec::new(),
            coverage_steps: BTreeMap::new(),
            exploration_step: None,
            best: (0.0, 0),
            last: BTreeMap::new(),
            bad_telemetry: 0,
            saves: Vec::new(),
            views: Vec::new(),
            judged: Vec::new(),
            base: None,
            base_coverage_steps: BTreeMap::new(),
            shared: SharedKnowledge::default(),
        }
    }

    /// The team is robots `0..robots`: whose knowledge [`MetricsRow::shared_pct`] intersects.
    pub fn with_team(mut self, robots: u16) -> Evaluator {
        self.shared = SharedKnowledge::new(robots, self.reachable.len());
        self
    }

    /// Node `base` is the base station ([`Self::base`]).
    pub fn with_base(mut self, base: Option<RobotId>) -> Evaluator {
        self.base = base;
        self
    }

    pub fn reachable_cells(&self) -> usize {
        self.reachable_count
    }

    /// `cells` as a percentage of the reachable free cells (100 when there are none).
    fn pct_of_reachable(&self, cells: usize) -> f64 {
        if self.reachable_count == 0 {
            100.0
        } else {
            100.0 * cells as f64 / self.reachable_count as f64
        }
    }

    /// Scores one telemetry message: its planning grid's change is applied to the robot's grid
    /// and scored where it changed. What changed is returned; `None` for a report that could
    /// not be taken (a grid that does not decode, of another size than the truth, or a change
    /// after a report that was not taken), which is counted in [`Self::bad_telemetry`] and
    /// leaves the robot's grid as it was.
    pub fn add(&mut self, t: Telemetry) -> Option<Change> {
        let Some((mut l, change, first)) = self.take_grids(&t) else {
            self.bad_telemetry += 1;
            return None;
        };
        let pct = self.pct_of_reachable(l.known);
        self.reached(t.robot, t.step, pct);
        self.rows.push(MetricsRow::of(&t, l.fidelity, pct));
        self.judged.extend(t.judged.clone());
        self.record_changes(&t, (!first).then_some(&l.t));
        l.t = t;
        self.last.insert(l.t.robot, l);
        Some(change)
    }

    /// A report that came after its step was taken (its robot was not awaited then): it makes
    /// no row, but its grids are taken — and the counts moved by them — so that the robot's next
    /// reports, changes of these grids, apply.
    pub fn take_late(&mut self, t: &Telemetry) {
        match self.take_grids(t) {
            Some((l, _, _)) => {
                self.last.insert(t.robot, l);
            }
            None => self.bad_telemetry += 1,
        }
    }

    /// Applies `t`'s grid reports to its robot's grids and scores the change: the robot's
    /// [`Last`], taken out of [`Self::last`] for the caller to put back, what changed, and
    /// whether this was the robot's first report. `None` (its grids left as they were) when the
    /// planning grid's report cannot be applied.
    fn take_grids(&mut self, t: &Telemetry) -> Option<(Last, Change, bool)> {
        let (w, h) = (self.truth.width(), self.truth.height());
        let last = self.last.remove(&t.robot);
        let first = last.is_none();
        let mut l = last.unwrap_or_else(|| Last {
            planning: Received::new(w, h),
            own: (Received::new(w, h), None),
            t: t.clone(),
            known: 0,
            fidelity: Fidelity::default(),
        });
        let Ok(change) = l.planning.apply(t.step, &t.grid) else {
            if !first {
                self.last.insert(t.robot, l);
            }
            return None;
        };
        l.own.1 = l.own.0.apply(t.step, &t.own).err().map(|e| e.to_string());
        self.score_change(t.robot, &mut l, &change);
        Some((l, change, first))
    }

    /// Brings `l`'s counts, and the team's shared knowledge, up to its grid after `change`:
    /// only the cells of the change's rectangle.
    fn score_change(&mut self, robot: RobotId, l: &mut Last, change: &Change) {
        let Some(r) = change.rect else { return };
        let member = self.base != Some(robot);
        let w = self.truth.width() as usize;
        let (now, truth) = (l.planning.grid.cells(), self.truth.cells());
        let mut before = change.before.iter();
        for y in r.min.y..=r.max.y {
            let row = y as usize * w;
            for x in r.min.x..=r.max.x {
                let (i, was) = (
                    row + x as usize,
                    before.next().copied().unwrap_or(Occ::Unknown),
                );
                let is = now[i];
                if was == is {
                    continue;
                }
                l.fidelity.change(was, is, truth[i]);
                let reach = self.reachable[i];
                let (k0, k1) = (knows(was, reach), knows(is, reach));
                if k0 != k1 {
                    if k1 {
                        l.known += 1;
                    } else {
                        l.known -= 1;
                    }
                    if member {
                        self.shared.know(robot, i, k1);
                    }
                }
            }
        }
    }

    /// `robot` knew `pct` % of the reachable cells at `step`: the best coverage, the steps to
    /// each threshold and the exploration time (the base station's apart, never deciding it).
    fn reached(&mut self, robot: RobotId, step: Step, pct: f64) {
        let is_base = self.base == Some(robot);
        if pct > self.best.0 && !is_base {
            self.best = (pct, robot);
        }
        let steps = if is_base {
            &mut self.base_coverage_steps
        } else {
            &mut self.coverage_steps
        };
        for th in THRESHOLDS {
            if pct >= f64::from(th) {
                let e = steps.entry(th).or_insert(step);
                *e = (*e).min(step);
            }
        }
        if pct >= self.done_pct && !is_base {
            self.exploration_step = Some(self.exploration_step.map_or(step, |s| s.min(step)));
        }
    }

    /// The save points and views `t` reports that its robot's report before, `before` (`None`
    /// at its first report), did not.
    fn record_changes(&mut self, t: &Telemetry, before: Option<&Telemetry>) {
        if let Some((len, digest)) = t.save {
            if before.and_then(|b| b.save).map(|(l, _)| l) != Some(len) {
                self.saves.push((t.step, t.robot, len, digest));
            }
        }
        for v in &t.views {
            let same = before.is_some_and(|b| b.views.iter().any(|w| w == v));
            if !same {
                self.views.push((t.step, t.robot, *v));
            }
        }
    }

    /// Sets [`MetricsRow::shared_pct`] and [`MetricsRow::team_pct`] of the robot rows from
    /// `from` on, from the latest grid of every robot. Called once the reports taken together
    /// are all added: in lockstep a whole step's, so every share compares grids of the same step
    /// and every robot row of the step gets the same `team_pct`; in realtime each report as it
    /// comes, against the other robots' latest grids (which may be a step older or newer).
    pub fn share_rows_since(&mut self, from: usize) {
        // The union is kept up to date by the holder counts: no pass over the robots here.
        let team_pct = self.pct_of_reachable(self.shared.known_by_anyone());
        for row in self.rows.iter_mut().skip(from) {
            if self.base != Some(row.robot) {
                row.shared_pct = self.shared.share_pct(row.robot);
                row.team_pct = self.shared.is_member(row.robot).then_some(team_pct);
            }
        }
    }

    /// A frontier of `robot`'s last planning grid that lies inside the world's reachable area
    /// (the first in row-major order), if any: space the robot could reach and has not seen.
    pub fn reachable_frontier(&self, robot: RobotId) -> Option<Cell> {
        let grid = &self.last.get(&robot)?.planning.grid;
        let reachable = |c: Cell| self.truth.index(c).is_some_and(|i| self.reachable[i]);
        let r = grid.known_bounds()?;
        r.cells().find(|&c| reachable(c) && grid.is_frontier(c))
    }

    /// Why a run ends whose live robots `alive` have all been idle long enough: `no-frontiers`
    /// only when no planning grid of theirs holds a frontier inside the world's reachable area,
    /// else `stalled` — with the robot and the frontier cell that decided it.
    pub fn idle_end(&self, alive: &[RobotId]) -> (ExitReason, Option<(RobotId, Cell)>) {
        let left = alive
            .iter()
            .find_map(|&id| self.reachable_frontier(id).map(|c| (id, c)));
        match left {
            Some(_) => (ExitReason::Stalled, left),
            None => (ExitReason::NoFrontiers, None),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proto::geom::Pose;
    use proto::grid_report::GridReport;

    fn telemetry(robot: RobotId, step: Step, grid: &Grid) -> Telemetry {
        Telemetry {
            logs: Vec::new(),
            approx_error_avg: None,
            robot,
            step,
            pose: Pose::default(),
            target: None,
            known_cells: 0,
            bytes_sent: 0,
            bytes_received: 0,
            grid: GridReport::Whole(grid.to_rle()),
            idle: false,
            neighbours: vec![],
            decode_errors: 0,
            sent_by_type: vec![],
            splits_per_step: None,
            backlog_bytes: vec![],
            own: GridReport::Whole(vec![]),
            save: None,
            views: vec![],
            alone: false,
            judged: None,
            life: 0,
            log_bytes: Vec::new(),
        }
    }

    #[test]
    fn coverage_counts_reachable_free_cells_only() {
        let truth = Grid::from_ascii("#####\n#...#\n#.#.#\n#####\n");
        let reachable = Grid::from_ascii("?????\n?...?\n?.?.?\n?????\n");
        let mut ev = Evaluator::new(truth, &reachable, 99.0);
        assert_eq!(ev.reachable_cells(), 5);
        ev.add(telemetry(
            0,
            3,
            &Grid::from_ascii("#####\n#..??\n#????\n?????\n"),
        ));
        assert_eq!(ev.rows[0].coverage_pct, 40.0);
        assert_eq!(ev.rows[0].correct_known_cells, 9);
        assert_eq!(ev.exploration_step, None);
        ev.add(telemetry(
            1,
            7,
            &Grid::from_ascii("?????\n?...?\n?.?.?\n?????\n"),
        ));
        assert_eq!(ev.exploration_step, Some(7));
        assert_eq!(ev.coverage_steps.get(&50), Some(&7));
        assert_eq!(ev.coverage_steps.get(&100), Some(&7));
        assert_eq!(ev.best, (100.0, 1));
    }

    #[test]
    fn the_base_station_is_recorded_but_never_decides_the_exploration_time() {
        let truth = Grid::from_ascii("....\n");
        let mut ev = Evaluator::new(truth.clone(), &truth, 99.0).with_base(Some(2));
        ev.add(telemetry(2, 4, &truth));
        assert_eq!(ev.exploration_step, None);
        assert!(ev.coverage_steps.is_empty());
        assert_eq!(ev.base_coverage_steps.get(&100), Some(&4));
        assert_eq!(ev.rows.len(), 1, "its row is in metrics.csv");
        ev.add(telemetry(0, 6, &truth));
        assert_eq!(ev.exploration_step, Some(6));
        assert_eq!(ev.best, (100.0, 0));
    }

    #[test]
    fn a_step_s_shares_compare_the_robots_grids_of_that_step_and_skip_the_base_station() {
        let truth = Grid::from_ascii("....\n");
        let mut ev = Evaluator::new(truth.clone(), &truth, 99.0)
            .with_base(Some(2))
            .with_team(2);
        ev.add(telemetry(0, 0, &Grid::from_ascii("..??\n")));
        ev.add(telemetry(1, 0, &Grid::from_ascii(".#.?\n")));
        ev.add(telemetry(2, 0, &truth));
        ev.share_rows_since(0);
        let shares: Vec<Option<f64>> = ev.rows.iter().map(|r| r.shared_pct).collect();
        assert_eq!(shares, [Some(100.0), Some(200.0 / 3.0), None]);
        let from = ev.rows.len();
        ev.add(telemetry(0, 1, &Grid::from_ascii("?.??\n")));
        ev.share_rows_since(from);
        assert_eq!(ev.rows[from].shared_pct, Some(100.0));
        assert_eq!(
            ev.rows[0].shared_pct,
            Some(100.0),
            "earlier rows stay as they were"
        );
    }

    #[test]
    fn a_step_s_team_coverage_is_the_union_of_the_robots_known_cells_on_every_robot_row() {
        // 4 reachable cells; robot 0 knows cells 0–1, robot 1 cells 0 and 2, the base all.
        let truth = Grid::from_ascii("....\n");
        let mut ev = Evaluator::new(truth.clone(), &truth, 99.0)
            .with_base(Some(2))
            .with_team(2);
        ev.add(telemetry(0, 0, &Grid::from_ascii("..??\n")));
        ev.add(telemetry(1, 0, &Grid::from_ascii(".?#?\n")));
        ev.add(telemetry(2, 0, &truth));
        ev.share_rows_since(0);
        let team: Vec<Option<f64>> = ev.rows.iter().map(|r| r.team_pct).collect();
        assert_eq!(team, [Some(75.0), Some(75.0), None]);
        assert!(
            ev.rows
                .iter()
                .all(|r| r.team_pct >= Some(r.coverage_pct) || r.robot == 2),
            "the union holds what each robot knows"
        );
        // Robot 1 forgets nothing but robot 0 now knows the rest: the whole map.
        let from = ev.rows.len();
        ev.add(telemetry(0, 1, &Grid::from_ascii("...#\n")));
        ev.add(telemetry(1, 1, &Grid::from_ascii(".?#?\n")));
        ev.share_rows_since(from);
        assert_eq!(
            (ev.rows[from].team_pct, ev.rows[from + 1].team_pct),
            (Some(100.0), Some(100.0))
        );
        assert_eq!(ev.rows[0].team_pct, Some(75.0), "earlier rows stay");
    }

    /// The end rule: a run whose robots are all idle ends `no-frontiers` only when no planning
    /// grid holds a frontier inside the world's reachable area; a frontier outside it (a cell
    /// the truth has blocked, or free but cut off) does not count.
    #[test]
    fn no_frontiers_only_when_no_planning_grid_holds_a_frontier_inside_the_reachable_area() {
        let truth = Grid::from_ascii("#######\n#...#.#\n#.#.#.#\n#######\n");
        let reachable = Grid::from_ascii("???????\n?...???\n?.?.???\n???????\n");
        let mut ev = Evaluator::new(truth, &reachable, 99.0);
        // Robot 0 knows its room; robot 1 believes the wall cell (1, 3) free beside unknown
        // space and sees the cut-off cell (5, 2) free beside unknown: neither is reachable.
        ev.add(telemetry(
            0,
            3,
            &Grid::from_ascii("#####??\n#...#??\n#.#.#??\n#####??\n"),
        ));
        ev.add(telemetry(
            1,
            3,
            &Grid::from_ascii("?.?????\n?????.?\n???????\n???????\n"),
        ));
        assert_eq!(ev.reachable_frontier(0), None);
        assert_eq!(ev.reachable_frontier(1), None);
        assert_eq!(ev.idle_end(&[0, 1]), (ExitReason::NoFrontiers, None));
        // Robot 1 now holds a reachable free cell beside unknown space: the robots stalled.
        ev.add(telemetry(
            1,
            4,
            &Grid::from_ascii("???????\n???????\n?.?????\n???????\n"),
        ));
        assert_eq!(ev.reachable_frontier(1), Some(Cell::new(1, 1)));
        assert_eq!(
            ev.idle_end(&[0, 1]),
            (ExitReason::Stalled, Some((1, Cell::new(1, 1))))
        );
        // Only the live robots' grids count.
        assert_eq!(ev.idle_end(&[0]), (ExitReason::NoFrontiers, None));
    }

    /// Cells drawn from `v` (0 unknown, 1 free, 2 occupied).
    fn occ(v: u8) -> Occ {
        [Occ::Unknown, Occ::Free, Occ::Occupied][usize::from(v % 3)]
    }

    proptest::proptest! {
        /// Robots reporting their grids as changes get, row after row, the counts of scoring
        /// each whole grid afresh: coverage, fidelity and the share every robot knows.
        #[test]
        fn scoring_changes_counts_what_scoring_whole_grids_counts(
            truth in proptest::collection::vec(0u8..3, 24),
            reachable in proptest::collection::vec(proptest::bool::ANY, 24),
            steps in proptest::collection::vec(
                proptest::collection::vec((0u16..2, 0usize..24, 0u8..3), 0..6), 1..30),
        ) {
            let (w, h) = (6u32, 4u32);
            let mut t_grid = Grid::new(w, h, Occ::Unknown);
            let mut r_grid = Grid::new(w, h, Occ::Unknown);
            for i in 0..24 {
                t_grid.set_index(i, occ(truth[i]));
                if reachable[i] {
                    r_grid.set_index(i, Occ::Free);
                }
            }
            let mut ev = Evaluator::new(t_grid.clone(), &r_grid, 99.0).with_team(2);
            let mut grids = [Grid::new(w, h, Occ::Unknown), Grid::new(w, h, Occ::Unknown)];
            let mut reporters: [proto::grid_report::Reporter; 2] = Default::default();
            let reach: Vec<bool> = r_grid.cells().iter().map(|&c| c == Occ::Free).collect();
            let knows_of = |g: &Grid| -> Vec<bool> {
                g.cells().iter().zip(&reach).map(|(&c, &r)| knows(c, r)).collect()
            };
            for (step, edits) in steps.iter().enumerate() {
                let step = step as Step;
                for &(robot, i, v) in edits {
                    grids[usize::from(robot)].set_index(i, occ(v));
                }
                let from = ev.rows.len();
                for robot in 0..2u16 {
                    let g = &grids[usize::from(robot)];
                    let mut t = telemetry(robot, step, g);
                    t.grid = reporters[usize::from(robot)].report(step, g);
                    proptest::prop_assert!(ev.add(t).is_some());
                }
                ev.share_rows_since(from);
                let known: Vec<Vec<bool>> = grids.iter().map(&knows_of).collect();
                let common = (0..24).filter(|&i| known[0][i] && known[1][i]).count();
                for (k, row) in ev.rows[from..].iter().enumerate() {
                    let g = &grids[k];
                    let f = Fidelity::of(&proto::grid::KnownPart::of(g), &t_grid);
                    let n = known[k].iter().filter(|&&x| x).count();
                    proptest::prop_assert_eq!(row.coverage_pct, ev.pct_of_reachable(n));
                    proptest::prop_assert_eq!(
                        (row.free_cells, row.false_free_cells, row.on_wall_cells, row.correct_known_cells),
                        (f.free, f.false_free, f.on_walls, f.correct)
                    );
                    let share = if n == 0 { 100.0 } else { 100.0 * common as f64 / n as f64 };
                    proptest::prop_assert_eq!(row.shared_pct, Some(share));
                }
            }
        }
    }

    #[test]
    fn a_late_report_makes_no_row_but_the_changes_after_it_apply() {
        let truth = Grid::from_ascii("....\n");
        let mut ev = Evaluator::new(truth.clone(), &truth, 99.0);
        let mut rep = proto::grid_report::Reporter::default();
        let grids = ["..??\n", "...?\n", "....\n"].map(Grid::from_ascii);
        let report = |rep: &mut proto::grid_report::Reporter, step: Step| {
            let mut t = telemetry(0, step, &grids[step as usize]);
            t.grid = rep.report(step, &grids[step as usize]);
            t
        };
        assert!(ev.add(report(&mut rep, 0)).is_some());
        ev.take_late(&report(&mut rep, 1));
        assert!(
            ev.add(report(&mut rep, 2)).is_some(),
            "a change since the late one"
        );
        assert_eq!(ev.bad_telemetry, 0);
        let covered: Vec<(Step, f64)> = ev.rows.iter().map(|r| (r.step, r.coverage_pct)).collect();
        assert_eq!(covered, [(0, 50.0), (2, 100.0)]);
    }

    #[test]
    fn malformed_grids_are_counted_not_scored() {
        let truth = Grid::from_ascii("...\n");
        let mut ev = Evaluator::new(truth.clone(), &truth, 99.0);
        let mut t = telemetry(0, 1, &truth);
        t.grid = GridReport::Whole(vec![0xff]);
        ev.add(t);
        ev.add(telemetry(0, 1, &Grid::from_ascii("..\n")));
        assert_eq!(ev.bad_telemetry, 2);
        assert!(ev.rows.is_empty());
    }
}
