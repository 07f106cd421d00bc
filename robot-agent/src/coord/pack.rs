//! `pack` (Rooker and Birk, "Communicative exploration with robot packs", RoboCup 2005, §3):
//! exploration that keeps every robot in touch with the others, directly or through others.
//!
//! * A **configuration change** moves every robot of a group to one of its 9 candidate positions:
//!   stay, or one step of the robot's step length in one of 8 directions
//!   ([`offsets`](crate::coord::pack::offsets)).
//! * Each step the group's leader scores `k` random changes (and standing still) and takes the best
//!   ([`best_change`](crate::coord::pack::best_change)): each robot's new position scores
//!   `impossible` (into an obstacle or unknown space on the leader's map, or onto a teammate —
//!   [`Scoring::utility`](crate::coord::pack::Scoring::utility)), `frontier` or `other`; a change
//!   whose communication graph is not connected gets the disconnection penalty δ on top.
//! * **Frontier at our scale**: in the paper a robot senses only the cells around it, so the
//!   frontier is always a step away and "moves onto a frontier cell" is how the pack advances.
//!   Our robots' lasers see metres, so frontier cells lie metres away and a robot would hardly
//!   ever stand on one; a position scores `frontier` when it is a frontier cell or a step nearer
//!   the nearest one (path cost on the leader's map) than where the robot stands — the same
//!   pull toward unexplored space, at the sensor's scale.
//! * **Connectivity** is judged from what the pack knows ([`crate::radio::reach::Reach::linked`]:
//!   the radio model's parameters, walls counted on the leader's own map), never from the truth.
//!   The leader's judgement of the links it expects goes to the launcher (`Judged` in telemetry),
//!   which checks it against what netem then does.
//! * **Leader and moves**: a group is what the team table ([`crate::coord::team`]) says can talk,
//!   transitively; its leader is its lowest id. The leader's decisions travel over the radio
//!   (`Pack` messages, package type `move`), relayed member to member, one hop per step — so the
//!   leader of n robots, whose farthest member is at most n − 1 hops away, plans each change
//!   n − 1 steps ahead, on the positions its earlier changes will have produced (a pipeline of
//!   planned steps). A robot
//!   that holds no move of its leader for a step, or is not where the move starts, stays. When a
//!   group splits, each part's table soon says so and its lowest id leads it; parts that meet
//!   merge under the lower leader.
//!
//! Beyond the paper: standing still is always among the candidates (a change worse than that
//! is never taken); the world applies moves in id order, so a move that ends on a higher id's
//! current position is impossible too; robots outside the group are obstacles where last heard.

use std::collections::{BTreeMap, BTreeSet};

use proto::grid::{Cell, Grid};
use proto::msg::{Judged, Move, Pack as PackMsg, Plan, RobotId, Step, StepMoves, WorldInfo};
use proto::scenario::Scenario;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use crate::coord::team::{self, Table};
use crate::coord::utility;
use crate::coord::{Addressed, CoordMsg, Coordinator, Situation, Status, Steer, To};
use crate::nav::plan::{self, CostMap};
use crate::radio::reach::Reach;

/// Steps of planned moves kept behind the current step (the leader predicts a member's position
/// from its last report and the moves planned since).
const HISTORY_STEPS: Step = 64;

/// The utilities of Rooker and Birk's §3 (`coordination.pack`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Utilities {
    pub frontier: f64,
    pub other: f64,
    pub impossible: f64,
    /// δ, added when the configuration's communication graph is not connected.
    pub disconnect: f64,
}

/// The `pack` settings in cells and steps.
#[derive(Clone, Debug)]
pub struct Settings {
    pub configurations: usize,
    pub utilities: Utilities,
    /// The 9 candidate moves (dx, dy) in cells, staying first.
    pub offsets: [(i32, i32); 9],
    /// Robots whose centres are closer than this (cells) collide.
    pub collide_cells: f64,
    pub reach: Reach,
    /// Cells every distance the radio is judged at counts more: the leader judges between cell
    /// centres, and a robot stands anywhere in its cell (at the start, or where the world
    /// stopped it) — √2 cells for two positions — and a move it counted on may not have been
    /// made (the world refused it, or it came late) — one step.
    pub slack_cells: f64,
    /// Reports older than this no longer count (a hop per step across the team).
    pub fresh_steps: Step,
    pub seed: u64,
    /// The base station, if any: never a member.
    pub base: Option<RobotId>,
}

impl Settings {
    pub fn new(s: &Scenario, world: &WorldInfo) -> Settings {
        let p = &s.coordination.pack;
        let res = world.map.resolution_m;
        let step_cells = world.max_speed_m_per_s * world.step_seconds / res;
        Settings {
            configurations: p.configurations as usize,
            utilities: Utilities {
                frontier: p.frontier_utility,
                other: p.other_utility,
                impossible: p.impossible_utility,
                disconnect: p.disconnect_penalty,
            },
            offsets: offsets(step_cells),
            collide_cells: 2.0 * s.robots.radius_m / res,
            reach: Reach::new(s, res),
            slack_cells: std::f64::consts::SQRT_2 + step_cells,
            fresh_steps: Step::from(s.robots.count) + 1,
            seed: s.seed,
            base: s.base_id(),
        }
    }
}

/// The 9 moves of a robot whose step is `step_cells` long, as whole cells between cell centres
/// never longer than the step: stay, then E, NE, N, NW, W, SW, S, SE (at least one cell, even
/// when the step is shorter: the world then moves the robot as far as its speed allows).
pub fn offsets(step_cells: f64) -> [(i32, i32); 9] {
    let straight = (step_cells.floor() as i32).max(1);
    let diagonal = ((step_cells / std::f64::consts::SQRT_2).floor() as i32).max(1);
    let (s, d) = (straight, diagonal);
    [
        (0, 0),
        (s, 0),
        (d, d),
        (0, s),
        (-d, d),
        (-s, 0),
        (-d, -d),
        (0, -s),
        (d, -d),
    ]
}

/// What a configuration change is scored on: the leader's map, the distance of every cell to
/// the nearest frontier on it, the radio as the leader estimates it, and robots outside the group.
pub struct Scoring<'a> {
    pub grid: &'a Grid,
    pub to_frontier: &'a CostMap,
    pub reach: &'a Reach,
    pub utilities: Utilities,
    pub collide_cells: f64,
    /// Cells added to every distance the radio is judged at ([`Settings::slack_cells`]).
    pub slack: f64,
    /// Robots outside the group, where last heard: obstacles.
    pub others: &'a [Cell],
}

impl Scoring<'_> {
    /// U(P_i(t+1)) for member `i` of `from` (positions sorted by robot id) moving to `to[i]`.
    pub fn utility(&self, from: &[Cell], to: &[Cell], i: usize) -> f64 {
        let u = &self.utilities;
        if !self.possible(from, to, i) {
            return u.impossible;
        }
        let (here, there) = (self.to_frontier.cost(from[i]), self.to_frontier.cost(to[i]));
        let nearer = match (here, there) {
            (_, Some(0.0)) => true,
            (Some(h), Some(t)) => t < h - 1e-9,
            (None, Some(_)) => true,
            _ => false,
        };
        if nearer {
            u.frontier
        } else {
            u.other
        }
    }

    /// The move of member `i` stays on known free cells along its straight segment and ends
    /// clear of its teammates' new positions, of the current positions of those that move after
    /// it (the world applies moves in id order) and of robots outside the group.
    fn possible(&self, from: &[Cell], to: &[Cell], i: usize) -> bool {
        let (a, b) = (from[i], to[i]);
        if a != b && !plan::move_is_free(self.grid, a.centre(), b.centre(), a) {
            return false;
        }
        let near = |c: Cell| c.dist(b) < self.collide_cells.max(1e-9);
        let teammates = to
            .iter()
            .enumerate()
            .filter(|&(j, _)| j != i)
            .any(|(_, &c)| near(c));
        let later = from.iter().skip(i + 1).any(|&c| near(c));
        let strangers = self.others.iter().any(|&c| near(c));
        // A robot that stays where it stands is never the one that collides.
        !(teammates || (a != b && (later || strangers)))
    }

    /// Whether robots at `at` can all talk, directly or through others (the paper checks from a
    /// temporary base station; one component is the same).
    pub fn connected(&self, at: &[Cell]) -> bool {
        proto::graph::connected(at.len(), &self.links(at))
    }

    /// U(cfg_c) = δ + Σ U(P_i(t+1)).
    pub fn total(&self, from: &[Cell], to: &[Cell]) -> f64 {
        let sum: f64 = (0..from.len()).map(|i| self.utility(from, to, i)).sum();
        let delta = if self.connected(to) {
            0.0
        } else {
            self.utilities.disconnect
        };
        sum + delta
    }

    /// Pairs (indices into `at`) whose link the leader expects up.
    pub fn links(&self, at: &[Cell]) -> Vec<(usize, usize)> {
        let mut out = Vec::new();
        for i in 0..at.len() {
            for j in i + 1..at.len() {
                if self.reach.linked(self.grid, at[i], at[j], self.slack) {
                    out.push((i, j));
                }
            }
        }
        out
    }
}

/// The best of `k` random configuration changes of the robots at `from` (and of standing
/// still, scored first so that it wins ties): the new positions and their utility.
pub fn best_change(
    sc: &Scoring<'_>,
    offsets: &[(i32, i32); 9],
    from: &[Cell],
    k: usize,
    rng: &mut impl Rng,
) -> (Vec<Cell>, f64) {
    let mut best = (from.to_vec(), sc.total(from, from));
    for _ in 0..k {
        let to: Vec<Cell> = from
            .iter()
            .map(|c| {
                let (dx, dy) = offsets[rng.gen_range(0..offsets.len())];
                Cell::new(c.x + dx, c.y + dy)
            })
            .collect();
        let u = sc.total(from, &to);
        if u > best.1 {
            best = (to, u);
        }
    }
    best
}

/// The leader of a group: its lowest id.
pub fn leader(group: &[RobotId]) -> Option<RobotId> {
    group.iter().copied().min()
}

pub struct Pack {
    me: RobotId,
    st: Settings,
    table: Table,
    /// The newest plan heard of every leader.
    plans: BTreeMap<RobotId, Plan>,
    /// As a leader: the changes planned, by step (the future ones are the pipeline the members
    /// are told; the past ones predict where members are).
    planned: BTreeMap<Step, Vec<Move>>,
    /// This robot's move for the current step, decided in `choose`.
    steer: Steer,
    judged: Option<Judged>,
    /// The leader of this robot's group, as `choose` found it this step.
    leader: RobotId,
}

impl Pack {
    pub fn new(me: RobotId, st: Settings) -> Pack {
        Pack {
            me,
            table: Table::new(st.fresh_steps),
            st,
            plans: BTreeMap::new(),
            planned: BTreeMap::new(),
            steer: Steer::Stay,
            judged: None,
            leader: me,
        }
    }

    /// Where `robot` will stand at the start of step `at`: its last report, moved by every
    /// change this leader planned since that starts where it stands.
    fn predict(&self, robot: RobotId, cell: Cell, since: Step, at: Step) -> Cell {
        let mut c = cell;
        for (_, moves) in self.planned.range(since..at) {
            if let Some(m) = moves.iter().find(|m| m.robot == robot && m.from == c) {
                c = m.to;
            }
        }
        c
    }

    /// As the leader of `group`: plans the change of the first step every member can still hear
    /// of in time, unless the pipeline already reaches that far. A member is at most
    /// `group.len() − 1` hops away; the table's links would say how far each is, but they are
    /// reports of past steps, and a member whose move comes a step late stays while the leader
    /// counts on its move.
    fn lead(&mut self, s: &Situation<'_>, group: &[RobotId]) {
        let t = s.step;
        let far = Step::try_from(group.len().saturating_sub(1)).unwrap_or(Step::MAX);
        let at = t.saturating_add(far);
        if self.planned.range(at..).next().is_some() {
            return;
        }
        let from: Vec<Cell> = group
            .iter()
            .map(|&r| {
                if r == self.me {
                    self.predict(r, s.me, t, at)
                } else {
                    let e = self.table.get(r, t);
                    e.map_or(s.me, |e| self.predict(r, e.cell, e.step, at))
                }
            })
            .collect();
        let others: Vec<Cell> = self
            .table
            .fresh(t)
            .filter(|e| !group.contains(&e.robot) && Some(e.robot) != self.st.base)
            .map(|e| e.cell)
            .collect();
        let to_frontier = plan::costs_from(s.grid, s.candidates);
        let sc = Scoring {
            grid: s.grid,
            to_frontier: &to_frontier,
            reach: &self.st.reach,
            utilities: self.st.utilities,
            collide_cells: self.st.collide_cells,
            slack: self.st.slack_cells,
            others: &others,
        };
        let seed = self.st.seed ^ (u64::from(self.me) << 48) ^ u64::from(at);
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let (to, _) = best_change(
            &sc,
            &self.st.offsets,
            &from,
            self.st.configurations,
            &mut rng,
        );
        let moves: Vec<Move> = group
            .iter()
            .zip(from.iter().zip(&to))
            .filter(|(_, (a, b))| a != b)
            .map(|(&robot, (&from, &to))| Move { robot, from, to })
            .collect();
        self.planned.insert(at, moves);
        let up = sc
            .links(&to)
            .into_iter()
            .map(|(i, j)| (group[i], group[j]))
            .collect();
        self.judged = Some(Judged {
            step: at.saturating_add(1),
            group: group.to_vec(),
            up,
        });
    }

    /// The leader's plan as it goes on the radio: the changes from the next step on.
    fn own_plan(&self, step: Step) -> Plan {
        Plan {
            leader: self.me,
            made: step,
            steps: self
                .planned
                .range(step.saturating_add(1)..)
                .map(|(&step, moves)| StepMoves {
                    step,
                    moves: moves.clone(),
                })
                .collect(),
        }
    }

    /// This robot's move in the current step from `leader`'s plan, if it stands where it starts.
    fn my_move(&self, leader: RobotId, s: &Situation<'_>) -> Option<Cell> {
        let m = if leader == self.me {
            self.planned
                .get(&s.step)?
                .iter()
                .find(|m| m.robot == self.me)
                .copied()
        } else {
            let plan = self.plans.get(&leader)?;
            let step = plan.steps.iter().find(|m| m.step == s.step)?;
            step.moves.iter().find(|m| m.robot == self.me).copied()
        }?;
        // Its own map must not say the way is blocked (the world checks the truth anyway).
        let open = utility::line_of_sight(s.grid, m.from, m.to);
        (m.from == s.me && open).then_some(m.to)
    }
}

impl Coordinator for Pack {
    fn choose(&mut self, s: &Situation<'_>) -> Option<Cell> {
        self.judged = None;
        let base = self.st.base;
        let group = self.table.group(self.me, s.neighbours, s.step, base);
        let leader = leader(&group).unwrap_or(self.me);
        self.leader = leader;
        if leader == self.me {
            self.lead(s, &group);
        }
        self.steer = match self.my_move(leader, s) {
            Some(to) => Steer::To(to),
            None => Steer::Stay,
        };
        let keep = s.step.saturating_sub(HISTORY_STEPS);
        self.planned = self.planned.split_off(&keep);
        let stale = s.step.saturating_sub(self.st.fresh_steps);
        self.plans.retain(|_, p| p.made >= stale);
        None
    }

    fn steer(&self) -> Steer {
        self.steer
    }

    fn judged(&self) -> Option<Judged> {
        self.judged.clone()
    }

    fn messages(&mut self, st: &Status<'_>) -> Vec<Addressed> {
        let base = self.st.base;
        let mut neighbours: BTreeSet<RobotId> = st.neighbours.clone();
        neighbours.retain(|&n| Some(n) != base);
        if neighbours.is_empty() {
            return Vec::new();
        }
        let own = team::entry(self.me, st.step, st.me, None, &neighbours);
        let plan = if self.leader == self.me {
            Some(self.own_plan(st.step))
        } else {
            self.plans.get(&self.leader).cloned()
        };
        let msg = PackMsg {
            from: self.me,
            entries: self.table.to_send(own),
            plan: plan.filter(|p| !p.steps.is_empty()),
        };
        // Robots only: the base station takes no part.
        neighbours
            .into_iter()
            .map(|n| Addressed {
                to: To::Robot(n),
                msg: CoordMsg::Pack(msg.clone()),
            })
            .collect()
    }

    fn on_message(&mut self, me: RobotId, msg: &CoordMsg) {
        let CoordMsg::Pack(p) = msg else { return };
        self.table.merge(me, &p.entries);
        if let Some(plan) = &p.plan {
            if plan.leader != me
                && self
                    .plans
                    .get(&plan.leader)
                    .is_none_or(|old| old.made < plan.made)
            {
                self.plans.insert(plan.leader, plan.clone());
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;
    use proto::grid::Occ;

    const UTILITIES: Utilities = Utilities {
        frontier: 1.0,
        other: 0.0,
        impossible: -100.0,
        disconnect: -10.0,
    };

    /// Free space, unknown beyond x = 30: the frontier is the column x = 29.
    fn world() -> Grid {
        let mut g = Grid::new(40, 20, Occ::Unknown);
        for y in 0..20 {
            for x in 0..30 {
                g.set(Cell::new(x, y), Occ::Free);
            }
        }
        g
    }

    fn frontier_field(g: &Grid) -> CostMap {
        let frontier: Vec<Cell> = (0..20).map(|y| Cell::new(29, y)).collect();
        plan::costs_from(g, &frontier)
    }

    fn scoring<'a>(g: &'a Grid, field: &'a CostMap, reach: &'a Reach) -> Scoring<'a> {
        Scoring {
            grid: g,
            to_frontier: field,
            reach,
            utilities: UTILITIES,
            collide_cells: 1.5,
            slack: 0.0,
            others: &[],
        }
    }

    #[test]
    fn utilities_of_hand_made_configurations() {
        let mut g = world();
        g.set(Cell::new(12, 5), Occ::Occupied);
        let field = frontier_field(&g);
        let reach = Reach::Disk { range_cells: 10.0 };
        let sc = scoring(&g, &field, &reach);
        let from = [Cell::new(10, 5), Cell::new(10, 8), Cell::new(20, 8)];
        // Toward the frontier (+1 each), all in touch: 3.
        let east = [Cell::new(11, 5), Cell::new(11, 8), Cell::new(21, 8)];
        assert_eq!(sc.total(&from, &east), 3.0);
        // Away from it: 0 each.
        let west = [Cell::new(9, 5), Cell::new(9, 8), Cell::new(19, 8)];
        assert_eq!(sc.total(&from, &west), 0.0);
        // Into the obstacle: −100 for robot 0, +1 for the others.
        let wall = [Cell::new(12, 5), Cell::new(11, 8), Cell::new(21, 8)];
        assert_eq!(sc.utility(&from, &wall, 0), -100.0);
        assert_eq!(sc.total(&from, &wall), -98.0);
        // Into unknown space: impossible.
        let far = [Cell::new(10, 5), Cell::new(10, 8), Cell::new(31, 8)];
        assert_eq!(sc.utility(&from, &far, 2), -100.0);
        // Two robots on one cell: both impossible.
        let same = [Cell::new(10, 6), Cell::new(10, 6), Cell::new(20, 8)];
        assert_eq!(sc.utility(&from, &same, 0), -100.0);
        assert_eq!(sc.utility(&from, &same, 1), -100.0);
        // Robot 2 leaves radio range of the others (11 cells > 10): δ = −10 on top of +1.
        let split = [Cell::new(10, 5), Cell::new(10, 8), Cell::new(21, 9)];
        assert_eq!(sc.total(&from, &split), 1.0 - 10.0);
        // Standing still: nothing gained, nothing lost.
        assert_eq!(sc.total(&from, &from), 0.0);
        // On the frontier itself: +1, also when it stays there.
        let on = [Cell::new(29, 5)];
        assert_eq!(sc.total(&on, &on), 1.0);
    }

    #[test]
    fn moves_end_clear_of_robots_that_move_later_and_of_strangers() {
        let g = world();
        let field = frontier_field(&g);
        let reach = Reach::Disk { range_cells: 10.0 };
        let mut sc = scoring(&g, &field, &reach);
        // Robot 0 moves onto robot 1's cell while robot 1 moves away: the world moves 0 first.
        let from = [Cell::new(10, 5), Cell::new(12, 5)];
        let to = [Cell::new(12, 5), Cell::new(14, 5)];
        assert_eq!(sc.utility(&from, &to, 0), -100.0);
        // The other way round it is fine: robot 0 has left when robot 1 arrives.
        let from = [Cell::new(12, 5), Cell::new(10, 5)];
        let to = [Cell::new(14, 5), Cell::new(12, 5)];
        assert_eq!(sc.utility(&from, &to, 1), 1.0);
        let others = [Cell::new(16, 5)];
        sc.others = &others;
        let to = [Cell::new(16, 5), Cell::new(10, 5)];
        assert_eq!(
            sc.utility(&from, &to, 0),
            -100.0,
            "a robot of another group"
        );
    }

    #[test]
    fn a_disconnecting_change_is_never_chosen_when_a_connected_one_with_a_frontier_exists() {
        let g = world();
        let field = frontier_field(&g);
        let reach = Reach::Disk { range_cells: 6.0 };
        let sc = scoring(&g, &field, &reach);
        let offsets = offsets(2.5);
        // Robot 1 is at the edge of robot 0's range, to the east: moving east gains +1 but
        // leaves robot 0 behind unless robot 0 comes along.
        let from = [Cell::new(5, 5), Cell::new(11, 5)];
        for seed in 0..200 {
            let mut rng = ChaCha8Rng::seed_from_u64(seed);
            let (to, u) = best_change(&sc, &offsets, &from, 50, &mut rng);
            assert!(sc.connected(&to), "seed {seed}: {to:?} ({u})");
            assert!(u >= 0.0);
        }
        // With enough tries, a connected change where both advance is found.
        let mut rng = ChaCha8Rng::seed_from_u64(1);
        let (to, u) = best_change(&sc, &offsets, &from, 500, &mut rng);
        assert!(sc.connected(&to) && u == 2.0, "{to:?} {u}");
    }

    #[test]
    fn random_changes_respect_obstacles_and_each_other() {
        // A corridor one cell wide: most moves are into walls.
        let mut g = Grid::new(30, 5, Occ::Occupied);
        for x in 0..20 {
            g.set(Cell::new(x, 2), Occ::Free);
        }
        for x in 20..30 {
            g.set(Cell::new(x, 2), Occ::Unknown);
        }
        let field = plan::costs_from(&g, &[Cell::new(19, 2)]);
        let reach = Reach::Disk { range_cells: 8.0 };
        let sc = scoring(&g, &field, &reach);
        let offsets = offsets(2.5);
        let from = [Cell::new(4, 2), Cell::new(6, 2), Cell::new(8, 2)];
        for seed in 0..100 {
            let mut rng = ChaCha8Rng::seed_from_u64(seed);
            let (to, _) = best_change(&sc, &offsets, &from, 50, &mut rng);
            for (i, c) in to.iter().enumerate() {
                assert_eq!(g.get(*c), Occ::Free, "seed {seed}: robot {i} at {c:?}");
                assert!(sc.possible(&from, &to, i), "seed {seed}: robot {i}");
            }
            let cells: BTreeSet<(i32, i32)> = to.iter().map(|c| (c.x, c.y)).collect();
            assert_eq!(cells.len(), to.len(), "seed {seed}: {to:?}");
        }
    }

    #[test]
    fn the_leader_is_the_lowest_id_of_its_group() {
        assert_eq!(leader(&[3, 1, 4]), Some(1));
        assert_eq!(leader(&[]), None);
        // Groups from the team table: 0–1 and 2–3–4 split; each part has its own leader.
        let mut t = Table::new(5);
        let e = |robot, neighbours: &[RobotId]| proto::msg::TeamEntry {
            robot,
            step: 10,
            cell: Cell::new(0, 0),
            target: None,
            neighbours: neighbours.to_vec(),
        };
        t.merge(3, &[e(2, &[3]), e(4, &[3])]);
        let g = t.group(3, &BTreeSet::from([2, 4]), 10, None);
        assert_eq!(leader(&g), Some(2));
        // They meet robot 1 (its group 0–1): the merged group follows 0.
        t.merge(3, &[e(1, &[0, 4]), e(0, &[1])]);
        let g = t.group(3, &BTreeSet::from([2, 4]), 10, None);
        assert_eq!(g, [0, 1, 2, 3, 4]);
        assert_eq!(leader(&g), Some(0));
    }

    #[test]
    fn offsets_stay_within_the_step() {
        for step in [1.0, 2.5, 3.0, 5.7] {
            let o = offsets(step);
            assert_eq!(o[0], (0, 0));
            let distinct: BTreeSet<_> = o.iter().collect();
            assert_eq!(distinct.len(), 9);
            for &(dx, dy) in &o {
                let d = f64::from(dx).hypot(f64::from(dy));
                assert!(
                    d <= step.max(std::f64::consts::SQRT_2) + 1e-9,
                    "{step}: {dx},{dy}"
                );
            }
        }
    }

    proptest! {
        /// Whatever the map and wherever a connected group stands, the change the leader takes
        /// keeps it connected (by its own estimate) and asks no robot for an impossible move:
        /// standing still is always a candidate, and every worse change loses to it.
        #[test]
        fn the_chosen_change_keeps_a_connected_group_connected_and_possible(
            cells in proptest::collection::vec(0u8..10, 24 * 24),
            starts in proptest::collection::vec((0i32..24, 0i32..24), 1..6),
            seed in 0u64..1000,
            range in 3.0f64..10.0,
        ) {
            let mut g = Grid::new(24, 24, Occ::Free);
            for (i, v) in cells.iter().enumerate() {
                let occ = match v { 0 => Occ::Occupied, 1 => Occ::Unknown, _ => Occ::Free };
                g.set(g.cell_of(i), occ);
            }
            let mut from: Vec<Cell> = Vec::new();
            for &(x, y) in &starts {
                let c = Cell::new(x, y);
                let apart = from.iter().all(|o| f64::from(o.x - x).hypot(f64::from(o.y - y)) >= 1.5);
                if g.get(c) == Occ::Free && apart {
                    from.push(c);
                }
            }
            let frontier: Vec<Cell> = (0..g.len())
                .map(|i| g.cell_of(i))
                .filter(|&c| g.get(c) == Occ::Free
                    && c.neighbours4().iter().any(|&n| g.contains(n) && g.get(n) == Occ::Unknown))
                .collect();
            let field = plan::costs_from(&g, &frontier);
            let reach = Reach::Disk { range_cells: range };
            let sc = scoring(&g, &field, &reach);
            prop_assume!(!from.is_empty() && sc.connected(&from));
            let mut rng = ChaCha8Rng::seed_from_u64(seed);
            let (to, u) = best_change(&sc, &offsets(2.5), &from, 50, &mut rng);
            prop_assert!(sc.connected(&to), "{:?} -> {:?}", from, to);
            prop_assert!(u >= sc.total(&from, &from));
            for i in 0..to.len() {
                prop_assert!(sc.possible(&from, &to, i), "robot {} {:?} -> {:?}", i, from[i], to[i]);
            }
        }
    }
}
