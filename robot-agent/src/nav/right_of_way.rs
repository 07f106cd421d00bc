//! Right of way: how a robot gets past other robots and past moves the world keeps refusing.
//!
//! * Rejected moves: after `MAX_REJECTIONS` refused moves in a row (blocked, a collision, out
//!   of the map) the robot gives up its target, which stays blacklisted for
//!   `BLACKLIST_STEPS` steps (another robot may be standing in a narrow passage). A robot never
//!   stops while it sees a reachable frontier: when every one is blacklisted, they count again.
//! * A collision with another robot (a bump) shapes this robot's moves for `BUMP_STEPS` steps:
//!   it gives way ([`crate::nav::plan::give_way`]) when the other has the right of way — a lower id
//!   and a target, or a target not heard of — and plans around it ([`crate::nav::plan::around`])
//!   when the other has no target (an idle robot never moves, so it never learns it stands in
//!   somebody's way).
//!
//! The geometry (discs, detours, the way out) is [`crate::nav::plan`]'s; this module holds the
//! state and the rules.

use std::collections::HashMap;

use proto::geom::{MapInfo, Metres};
use proto::grid::{Cell, Grid};
use proto::msg::{MoveOutcome, RobotId, Step};

use crate::coord::Heard;
use crate::nav::plan;

/// After this many rejected moves in a row the robot gives up its target for a while.
const MAX_REJECTIONS: u32 = 3;
/// How long a given-up target stays excluded.
const BLACKLIST_STEPS: Step = 30;
/// How many steps a collision with another robot shapes this robot's moves.
const BUMP_STEPS: Step = 10;

/// What a robot knows of the target of a robot it bumped into (from its `targ` announcements).
#[derive(Clone, Copy, Debug, PartialEq)]
enum Heading {
    /// It announced no target: it stays where it is.
    Idle,
    /// Never heard of: it counts as having a target, somewhere unknown.
    Unknown,
    To(Cell),
}

/// A robot this one bumped into: where, and until when that counts.
#[derive(Clone, Copy, Debug)]
struct Bump {
    other: RobotId,
    at: Cell,
    until: Step,
}

/// One robot's right-of-way state.
#[derive(Clone, Debug)]
pub struct RightOfWay {
    id: RobotId,
    /// How far (in cells) robot centres keep apart: a robot's diameter and half a cell for
    /// positions inside cells.
    clearance_cells: f64,
    step: Step,
    rejections: u32,
    blacklist: HashMap<Cell, Step>,
    /// The last collision with another robot, while it counts.
    bump: Option<Bump>,
}

impl RightOfWay {
    /// Robot `id`'s, for robots of `radius_m` on a grid of `resolution_m`.
    pub fn new(id: RobotId, radius_m: f64, resolution_m: f64) -> RightOfWay {
        RightOfWay {
            id,
            clearance_cells: 2.0 * radius_m / resolution_m + 0.5,
            step: 0,
            rejections: 0,
            blacklist: HashMap::new(),
            bump: None,
        }
    }

    /// The outcome of the last move, reported with the scan of `step`.
    pub fn on_move(&mut self, step: Step, outcome: MoveOutcome, map: &MapInfo) {
        self.step = step;
        match outcome {
            MoveOutcome::Blocked | MoveOutcome::Collision { .. } | MoveOutcome::OutOfMap => {
                self.rejections += 1
            }
            _ => self.rejections = 0,
        }
        if let MoveOutcome::Collision { with, at_mm } = outcome {
            let m = |v: i32| f64::from(v) / 1000.0;
            self.bump = Some(Bump {
                other: with,
                at: map.cell_of(Metres::new(m(at_mm.0), m(at_mm.1))),
                until: step + BUMP_STEPS,
            });
        }
    }

    /// The robot last bumped into, while that counts, and where it is heading.
    fn bumped(&self, heard: &Heard) -> Option<(Bump, Heading)> {
        let b = self.bump.filter(|b| b.until > self.step)?;
        let heading = match heard.get(b.other) {
            Some(a) => a.target.map_or(Heading::Idle, Heading::To),
            None => Heading::Unknown,
        };
        Some((b, heading))
    }

    /// The grid to plan on when a robot bumped into has no target (it stays where it is: plan
    /// around it); `None`: plan on `g` itself.
    pub fn detour(&self, g: &Grid, me: Cell, heard: &Heard) -> Option<Grid> {
        self.bumped(heard)
            .filter(|&(_, heading)| heading == Heading::Idle)
            .map(|(b, _)| plan::around(g, me, b.at, self.clearance_cells))
    }

    /// Gives up `target` after too many rejected moves in a row, and forgets expired
    /// blacklist entries.
    pub fn give_up(&mut self, target: &mut Option<Cell>) {
        let step = self.step;
        self.blacklist.retain(|_, until| *until > step);
        if self.rejections >= MAX_REJECTIONS {
            if let Some(t) = target.take() {
                self.blacklist.insert(t, step + BLACKLIST_STEPS);
            }
            self.rejections = 0;
        }
    }

    /// Whether `t` may be a target of a robot at `me`: not where it is, not given up.
    pub fn usable(&self, t: Cell, me: Cell) -> bool {
        t != me && !self.blacklist.contains_key(&t)
    }

    /// The frontiers a robot at `me` may go to: the usable ones, or all but its own cell when
    /// every one is given up.
    pub fn candidates(&self, frontiers: &[Cell], me: Cell) -> Vec<Cell> {
        let usable: Vec<Cell> = frontiers
            .iter()
            .copied()
            .filter(|&t| self.usable(t, me))
            .collect();
        if usable.is_empty() {
            frontiers.iter().copied().filter(|&t| t != me).collect()
        } else {
            usable
        }
    }

    /// Giving way: the next cell toward the nearest cell out of the way of a robot with the
    /// right of way (`None` inside: stay), at most `max_cells` away; no decision when there is
    /// none to give way to, or no such cell.
    pub fn give_way(
        &self,
        g: &Grid,
        map: &MapInfo,
        at_m: Metres,
        me: Cell,
        heard: &Heard,
        max_cells: f64,
    ) -> Option<Option<Cell>> {
        let (b, heading) = self.bumped(heard).filter(|(b, _)| b.other < self.id)?;
        let theirs = match heading {
            Heading::Idle => return None,
            Heading::Unknown => None,
            Heading::To(c) => Some(c),
        };
        let (blocked, path) = plan::give_way(g, me, b.at, theirs, self.clearance_cells)?;
        let next = plan::next_waypoint(&blocked, map, at_m, &path, max_cells);
        Some(next.filter(|&n| n != me))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::agent::Agent;
    use proto::geom::Pose;
    use proto::grid::Occ;
    use proto::msg::{Scan, Target};
    use proto::scenario::{Scenario, Strategy};
    use world_server::{laser, motion};

    fn map(width: u32, height: u32) -> MapInfo {
        MapInfo::at_origin(width, height, 0.2)
    }

    fn collision(with: RobotId, at: Cell, info: &MapInfo) -> MoveOutcome {
        let p = info.centre_of(at);
        let mm = |v: f64| (v * 1000.0).round() as i32;
        MoveOutcome::Collision {
            with,
            at_mm: (mm(p.x), mm(p.y)),
        }
    }

    #[test]
    fn three_rejected_moves_blacklist_the_target_for_a_while() {
        let info = map(10, 10);
        let mut r = RightOfWay::new(1, 0.2, 0.2);
        let (me, t) = (Cell::new(1, 1), Cell::new(5, 5));
        let mut target = Some(t);
        for step in 0..3 {
            r.on_move(step, MoveOutcome::Blocked, &info);
            r.give_up(&mut target);
        }
        assert_eq!(target, None);
        assert!(!r.usable(t, me));
        // Every frontier given up: they count again (but never the robot's own cell).
        assert_eq!(r.candidates(&[t, me], me), vec![t]);
        r.on_move(3 + BLACKLIST_STEPS, MoveOutcome::Moved, &info);
        r.give_up(&mut target);
        assert!(r.usable(t, me));
    }

    #[test]
    fn only_a_robot_with_the_right_of_way_is_given_way_to() {
        let g = Grid::from_ascii(&"....................\n".repeat(9));
        let info = map(g.width(), g.height());
        // Robots of 0.2 m on 0.2 m cells keep 2.5 cells apart; they touched at 2 cells.
        let (me, other) = (Cell::new(8, 4), Cell::new(10, 4));
        let mut heard = Heard::default();
        let target = |from, cell| Target {
            from,
            step: 0,
            cell,
        };
        // Robot 0 (lower id) heading left through robot 1: robot 1 steps out of its way.
        let mut r1 = RightOfWay::new(1, 0.2, 0.2);
        r1.on_move(0, collision(0, other, &info), &info);
        heard.on_target(1, &target(0, Some(Cell::new(0, 4))));
        let aside = r1
            .give_way(&g, &info, info.centre_of(me), me, &heard, 2.0)
            .flatten()
            .expect("a way aside");
        let from_other = |c: Cell| c.dist(other);
        assert!(
            from_other(aside) > from_other(me),
            "{aside:?} is not away from {other:?}"
        );
        assert!(r1.detour(&g, me, &heard).is_none());
        // Robot 2 (higher id) does not get way from robot 1.
        let mut r1 = RightOfWay::new(1, 0.2, 0.2);
        r1.on_move(0, collision(2, other, &info), &info);
        heard.on_target(1, &target(2, Some(Cell::new(0, 4))));
        assert_eq!(
            r1.give_way(&g, &info, info.centre_of(me), me, &heard, 2.0),
            None
        );
        // An idle robot is planned around, not given way to.
        let mut r1 = RightOfWay::new(1, 0.2, 0.2);
        r1.on_move(0, collision(0, other, &info), &info);
        heard.on_target(1, &target(0, None));
        assert_eq!(
            r1.give_way(&g, &info, info.centre_of(me), me, &heard, 2.0),
            None
        );
        let detour = r1
            .detour(&g, me, &heard)
            .expect("an idle robot is planned around");
        assert_eq!(detour.get(other), Occ::Occupied);
        // A bump stops counting after BUMP_STEPS.
        r1.on_move(BUMP_STEPS, MoveOutcome::Moved, &info);
        assert!(r1.detour(&g, me, &heard).is_none());
    }

    /// Two rooms joined by a corridor one cell wide and longer than the laser reaches; robot 0
    /// starts in the left room, robot 1 in the right one.
    fn two_rooms() -> (Grid, [Cell; 2]) {
        let mut g = Grid::new(50, 11, Occ::Occupied);
        for y in 1..=9 {
            for x in (1..=10).chain(39..=48) {
                g.set(Cell::new(x, y), Occ::Free);
            }
        }
        for x in 11..=38 {
            g.set(Cell::new(x, 5), Occ::Free);
        }
        (g, [Cell::new(5, 5), Cell::new(44, 5)])
    }

    /// Runs two agents in lockstep on `truth` (laser and motion as the world-server computes
    /// them; only `targ` messages pass between them, so each has to see the other's room for
    /// itself) until both know every free cell; returns the steps that took, or `None` if they
    /// did not within `max_steps`.
    fn explore_together(truth: &Grid, starts: [Cell; 2], max_steps: Step) -> Option<Step> {
        let mut s = Scenario::default();
        s.sensor.max_range_m = 2.0;
        s.coordination.strategy = Strategy::Decentralized;
        // Messages one by one (no step frames), so that only the targets are handed over.
        s.clock.markers = false;
        let info = map(truth.width(), truth.height());
        let world = crate::testutil::world_info(&s, info, 2);
        let mut agents = [Agent::new(0, world.clone(), &s), Agent::new(1, world, &s)];
        agents[0].link_up(1);
        agents[1].link_up(0);
        let mut poses = starts.map(|c| {
            let Metres { x, y } = info.centre_of(c);
            Pose { x, y, theta: 0.0 }
        });
        let mut last = [MoveOutcome::Start; 2];
        let free: Vec<Cell> = (0..truth.len())
            .map(|i| truth.cell_of(i))
            .filter(|&c| truth.get(c) == Occ::Free)
            .collect();
        for step in 0..max_steps {
            let mut cmds = Vec::new();
            for (i, agent) in agents.iter_mut().enumerate() {
                let scan = Scan {
                    step,
                    pose: poses[i],
                    ranges: laser::cast(truth, &info, poses[i], &s.laser(), None),
                    last_move: last[i],
                };
                cmds.push(agent.on_scan(&scan));
            }
            let knows_all = |a: &Agent| free.iter().all(|&c| a.own_grid().get(c) != Occ::Unknown);
            if agents.iter().all(knows_all) {
                return Some(step);
            }
            for i in 0..2 {
                for out in agents[i].radio_step() {
                    if proto::keys::radio_kind(&out.key) == Some("targ") {
                        agents[usize::from(out.to)].on_radio("targ", &out.bytes);
                    }
                }
            }
            for i in 0..2 {
                let other = poses[1 - i];
                last[i] = match cmds[i].waypoint {
                    None => MoveOutcome::Stayed,
                    Some(to) => match motion::validate_move(
                        truth,
                        &info,
                        poses[i],
                        to,
                        s.robots.speed_m_per_s * s.clock.step_seconds,
                        &[(1 - i as RobotId, other.xy())],
                        s.robots.radius_m,
                    ) {
                        Ok(p) => {
                            poses[i] = p;
                            MoveOutcome::Moved
                        }
                        Err(why) => why,
                    },
                };
            }
        }
        None
    }

    #[test]
    fn robots_meeting_head_on_in_a_narrow_corridor_get_past_each_other() {
        // Each explores its own room, then heads for the other's room down the same corridor:
        // they meet in it. Robot 1 gives way to robot 0 (back into its room, the nearest place
        // out of robot 0's way); robot 0, done, stops near the corridor's end, and robot 1
        // plans around it. Without either rule they block each other for good.
        let (truth, starts) = two_rooms();
        let steps = explore_together(&truth, starts, 600);
        assert!(
            steps.is_some(),
            "the robots did not get past each other in 600 steps"
        );
    }
}
