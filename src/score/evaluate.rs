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
use proto::grid::{Cell, Grid, KnownPart, Occ};
use proto::msg::{Judged, RobotId, Step, Telemetry, View};

use crate::rundir::summary::THRESHOLDS;
use crate::rundir::tables::MetricsRow;
use crate::score::awareness::{known_cells, SharedKnowledge};
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
    /// The last decoded grid (its known part) and telemetry of every robot.
    pub last: BTreeMap<RobotId, (KnownPart, Telemetry)>,
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

    /// Scores one telemetry message.
    pub fn add(&mut self, t: Telemetry) {
        // Decoded and scored over the grid's known part only: an unknown cell is neither
        // covered nor correct.
        let grid = match KnownPart::from_rle(&t.grid_rle) {
            Ok(g) if g.width() == self.truth.width() && g.height() == self.truth.height() => g,
            _ => {
                self.bad_telemetry += 1;
                return;
            }
        };
        let known = known_cells(&grid, self.truth.width(), &self.reachable);
        let pct = self.pct_of_reachable(known.count());
        if self.base != Some(t.robot) {
            self.shared.update(t.robot, known);
        }
        self.reached(t.robot, t.step, pct);
        let fidelity = Fidelity::of(&grid, &self.truth);
        self.rows.push(MetricsRow::of(&t, fidelity, pct));
        self.judged.extend(t.judged.clone());
        self.record_changes(&t);
        self.last.insert(t.robot, (grid, t));
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

    /// The save points and views `t` reports that its robot's last report did not.
    fn record_changes(&mut self, t: &Telemetry) {
        let before = self.last.get(&t.robot).map(|(_, b)| b);
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
        let (grid, _) = self.last.get(&robot)?;
        let reachable = |c: Cell| self.truth.index(c).is_some_and(|i| self.reachable[i]);
        grid.cells()
            .map(|(c, _)| c)
            .find(|&c| reachable(c) && grid.is_frontier(c))
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
            grid_rle: grid.to_rle(),
            idle: false,
            neighbours: vec![],
            decode_errors: 0,
            sent_by_type: vec![],
            splits_per_step: None,
            backlog_bytes: vec![],
            own_rle: vec![],
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

    #[test]
    fn malformed_grids_are_counted_not_scored() {
        let truth = Grid::from_ascii("...\n");
        let mut ev = Evaluator::new(truth.clone(), &truth, 99.0);
        let mut t = telemetry(0, 1, &truth);
        t.grid_rle = vec![0xff];
        ev.add(t);
        ev.add(telemetry(0, 1, &Grid::from_ascii("..\n")));
        assert_eq!(ev.bad_telemetry, 2);
        assert!(ev.rows.is_empty());
    }
}
