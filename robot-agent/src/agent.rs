//! One robot's decision loop as a pure state machine (the steps of thesis Algorithm 10 that
//! exist so far): integrate the scan into G_s, exchange over the radio, build the planning grid,
//! pick a target, plan, move. [`crate::node`] feeds it from zenoh and sends what it returns.
//!
//! What is exchanged is [`crate::sharing`]'s business (`raw-scans`, `polygon` or
//! `grid-snapshots`, DESIGN.md §4.8); the planning grid never lets a peer's data override a cell
//! of G_s (thesis §5.2). Which frontier to go to is [`crate::coord`]'s (`coordination.strategy`):
//! the agent keeps what it heard of other robots (their `targ` announcements; for `burgard` the
//! sub-team table relayed between neighbours) and replans when its target is reached, gone or no
//! longer a frontier (`burgard` also when its sub-team changes or every few steps).

use std::collections::{BTreeSet, HashMap};

use proto::geom::{LaserSpec, Pose};
use proto::grid::{Cell, Grid, Occ};
use proto::msg::{
    Cmd, Hello, MoveOutcome, RobotId, Scan, ScanDelta, Step, Target, Team, TeamEntry, Telemetry,
    Traffic, WorldInfo,
};
use proto::scenario::{Scenario, Strategy};

use crate::coord;
use crate::grid::Evidence;
use crate::pacing::Pacer;
use crate::plan;
use crate::sharing::{Share, Sharing};

/// A message for the radio plane.
#[derive(Clone, Debug, PartialEq)]
pub enum RadioOut {
    Hello {
        to: RobotId,
        msg: Hello,
    },
    /// The robot's target (`targ`), to a robot in range.
    Target {
        to: RobotId,
        msg: Target,
    },
    /// The sub-team table (`burgard`), to a robot in range.
    Team {
        to: RobotId,
        msg: Team,
    },
    /// `bytes`: the share as encoded for the radio ([`Share::encode`]).
    Share {
        to: RobotId,
        msg: Share,
        bytes: Vec<u8>,
    },
}

/// After this many rejected moves in a row the robot gives up its target for a while (another
/// robot may be standing in a narrow passage).
const MAX_REJECTIONS: u32 = 3;
/// How long a given-up target stays excluded.
const BLACKLIST_STEPS: Step = 30;

/// How many steps a collision with another robot shapes this robot's moves: it gives way
/// ([`plan::give_way`]) when the other has the right of way (a lower id and a target, or a
/// target not heard of), and plans around it ([`plan::around`]) when the other has no target
/// (an idle robot never moves, so it never learns it stands in somebody's way).
const BUMP_STEPS: Step = 10;

/// How many steps of unused radio budget a neighbour's credit can hold.
pub const BURST_STEPS: usize = 4;

/// A sub-team table entry older than this many steps no longer counts (its robot is gone from
/// the sub-team).
const TEAM_FRESH_STEPS: Step = 3;

/// The encoded size of the largest delta that carries one scan of `laser`.
fn largest_delta_bytes(laser: &LaserSpec) -> usize {
    let worst = ScanDelta {
        from: RobotId::MAX,
        owner: RobotId::MAX,
        start: u32::MAX,
        records: vec![proto::msg::ScanRecord {
            step: Step::MAX,
            x_mm: i32::MIN,
            y_mm: i32::MIN,
            theta_mrad: i32::MIN,
            ranges_cm: vec![u16::MAX; laser.beams as usize],
        }],
    };
    proto::msg::encode(&worst).len()
}

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

pub struct Agent {
    pub id: RobotId,
    world: WorldInfo,
    /// G_s: what this robot sensed itself, and the beam counts behind it.
    own: Grid,
    own_evidence: Evidence,
    /// Cells of G_s the last scan changed.
    own_changed: Vec<Cell>,
    /// The planning grid of the last step (built once per step, reused by telemetry).
    planning: Grid,
    /// What it shares and how peers' shares reach its planning grid (by exchange mode).
    sharing: Sharing,
    pose: Pose,
    step: Step,
    target: Option<Cell>,
    rejections: u32,
    blacklist: HashMap<Cell, Step>,
    /// The last collision with another robot, while it counts.
    bump: Option<Bump>,
    /// How far (in cells) robot centres keep apart: a robot's diameter and half a cell for
    /// positions inside cells.
    clearance_cells: f64,
    neighbours: BTreeSet<RobotId>,
    /// The sender's own pacing: per neighbour, a budget on the simulated clock of the link's
    /// bandwidth with bursts of [`BURST_STEPS`] steps (and at least the largest single-scan
    /// delta). On average a link is offered no more than its bandwidth, whatever the robot
    /// would like to send, so queues in netem and the kernel stay short and keep-alives are not
    /// stuck behind data.
    pacer: Pacer,
    /// Per neighbour, the bytes that waited for it after the last step's sending.
    backlog: Vec<(RobotId, u64)>,
    /// The target last announced to the robots in range (`None`: none announced yet).
    announced: Option<Option<Cell>>,
    /// Other robots' last announced targets and the step they were chosen at (thesis §4.5.1's
    /// table; heard directly from robots in range).
    pub others_targets: std::collections::BTreeMap<RobotId, (Option<Cell>, Step)>,
    /// How this robot picks its target (`coordination.*`).
    strategy: Strategy,
    params: coord::Params,
    burgard_search: bool,
    search_tries: u32,
    /// Obstacle penalty of path costs: (weight, σ in cells); weight 0 = off.
    obstacle: (f64, f64),
    replan_every_steps: u32,
    /// `burgard`: the latest report of every robot heard of, directly or relayed.
    team: std::collections::BTreeMap<RobotId, TeamEntry>,
    /// `burgard`: the sub-team of the last assignment and its step.
    assigned: (Vec<RobotId>, Step),
    hello_every_steps: u32,
    pub bytes_sent: u64,
    pub bytes_received: u64,
    pub decode_errors: u64,
    /// Payload bytes sent per traffic class ([`Traffic::ALL`] order).
    pub sent_by_type: [u64; Traffic::ALL.len()],
    idle: bool,
}

impl Agent {
    pub fn new(id: RobotId, world: WorldInfo, s: &Scenario) -> Agent {
        let empty = Grid::new(world.map.width, world.map.height, Occ::Unknown);
        let rate = Some(s.radio.bandwidth_bytes_per_s).filter(|&b| b > 0);
        let per_step = rate.map(|b| b as f64 * world.step_seconds);
        let clearance_cells = 2.0 * s.robots.radius_m / world.map.resolution_m + 0.5;
        let burst_bytes = per_step
            .map_or(0, |b| (b * BURST_STEPS as f64) as u64)
            .max(largest_delta_bytes(&world.laser) as u64);
        Agent {
            id,
            own_evidence: Evidence::new(&empty),
            own_changed: Vec::new(),
            sharing: Sharing::new(s, id, &world, per_step),
            pacer: Pacer::new(rate, burst_bytes, world.step_seconds),
            backlog: Vec::new(),
            announced: None,
            others_targets: Default::default(),
            strategy: s.coordination.strategy,
            params: coord::Params {
                beta: s.coordination.beta,
                max_range_cells: world.laser.max_range_m / world.map.resolution_m,
                half_life_steps: Some(s.coordination.target_half_life_steps).filter(|&h| h > 0.0),
            },
            burgard_search: s.coordination.burgard_search,
            obstacle: (
                s.coordination.obstacle_penalty,
                s.coordination.obstacle_sigma_cells,
            ),
            search_tries: s.coordination.search_tries,
            replan_every_steps: s.coordination.replan_every_steps,
            team: Default::default(),
            assigned: (Vec::new(), 0),
            world,
            own: empty.clone(),
            planning: empty,
            pose: Pose::default(),
            step: 0,
            target: None,
            rejections: 0,
            blacklist: HashMap::new(),
            bump: None,
            clearance_cells,
            neighbours: BTreeSet::new(),
            hello_every_steps: s.exchange.hello_every_steps,
            bytes_sent: 0,
            bytes_received: 0,
            decode_errors: 0,
            sent_by_type: [0; Traffic::ALL.len()],
            idle: false,
        }
    }

    /// Integrates a scan, records it in the own log and decides the move for its step.
    pub fn on_scan(&mut self, scan: &Scan) -> Cmd {
        self.step = scan.step;
        self.pose = scan.pose;
        self.own_changed = self.own_evidence.integrate(
            &mut self.own,
            &self.world.map,
            scan.pose,
            &scan.ranges,
            &self.world.laser,
        );
        self.sharing
            .after_scan(scan, &self.world.laser, &self.own, &self.own_changed);
        match scan.last_move {
            MoveOutcome::Blocked | MoveOutcome::Collision { .. } | MoveOutcome::OutOfMap => {
                self.rejections += 1
            }
            _ => self.rejections = 0,
        }
        if let MoveOutcome::Collision { with, at_mm } = scan.last_move {
            let m = |v: i32| f64::from(v) / 1000.0;
            self.bump = Some(Bump {
                other: with,
                at: self.world.map.cell_of(m(at_mm.0), m(at_mm.1)),
                until: scan.step + BUMP_STEPS,
            });
        }
        let waypoint = self.plan();
        Cmd {
            step: scan.step,
            robot: self.id,
            waypoint,
        }
    }

    /// The robot last bumped into, while that counts, and where it is heading.
    fn bumped(&self) -> Option<(Bump, Heading)> {
        let b = self.bump.filter(|b| b.until > self.step)?;
        let heading = match self.others_targets.get(&b.other) {
            Some(&(Some(c), _)) => Heading::To(c),
            Some(&(None, _)) => Heading::Idle,
            None => Heading::Unknown,
        };
        Some((b, heading))
    }

    /// Giving way: the waypoint toward the nearest cell out of the way of a robot with the right
    /// of way (`None` inside: stay); no decision when there is none to give way to, or no such
    /// cell.
    fn give_way(&self, g: &Grid, me: Cell, max_cells: f64) -> Option<Option<(f64, f64)>> {
        let (b, heading) = self.bumped().filter(|(b, _)| b.other < self.id)?;
        let theirs = match heading {
            Heading::Idle => return None,
            Heading::Unknown => None,
            Heading::To(c) => Some(c),
        };
        let (blocked, path) = plan::give_way(g, me, b.at, theirs, self.clearance_cells)?;
        let next = plan::next_waypoint(&blocked, &path, max_cells);
        Some(
            next.filter(|&n| n != me)
                .map(|n| self.world.map.centre_of(n)),
        )
    }

    /// The planning grid: G_s with what peers shared filling its unknown cells.
    pub fn planning_grid(&self) -> Grid {
        self.sharing.planning_grid(&self.own)
    }

    fn plan(&mut self) -> Option<(f64, f64)> {
        self.planning = self.planning_grid();
        let g = &self.planning;
        let me = self.world.map.cell_of(self.pose.x, self.pose.y);
        let penalty = (self.obstacle.0 > 0.0)
            .then(|| plan::obstacle_penalty(g, self.obstacle.1, self.obstacle.0));
        // A robot bumped into that has no target stays where it is: plan around it.
        let around = self
            .bumped()
            .filter(|&(_, heading)| heading == Heading::Idle)
            .map(|(b, _)| plan::around(g, me, b.at, self.clearance_cells));
        let free = around.as_ref().unwrap_or(g);
        let costs = plan::costs_with(free, me, penalty.as_deref());
        let step = self.step;
        self.blacklist.retain(|_, until| *until > step);
        if self.rejections >= MAX_REJECTIONS {
            if let Some(t) = self.target.take() {
                self.blacklist.insert(t, step + BLACKLIST_STEPS);
            }
            self.rejections = 0;
        }
        let frontiers: Vec<Cell> = plan::frontiers(g, &costs);
        let usable = |t: &Cell| *t != me && !self.blacklist.contains_key(t);
        let valid = self
            .target
            .is_some_and(|t| usable(&t) && frontiers.contains(&t));
        // A robot never stops while it sees a reachable frontier: when every one is blacklisted
        // (given up for a while after repeated rejected moves), they count again.
        let mut candidates: Vec<Cell> = frontiers.iter().copied().filter(usable).collect();
        if candidates.is_empty() {
            candidates = frontiers.into_iter().filter(|&t| t != me).collect();
        }
        match self.strategy {
            Strategy::Decentralized if !valid => {
                let others: Vec<(Cell, f64)> = self
                    .others_targets
                    .values()
                    .filter_map(|&(c, at)| Some((c?, f64::from(step.saturating_sub(at)))))
                    .collect();
                self.target = coord::decentralized(g, &candidates, &costs, &others, &self.params);
            }
            Strategy::Burgard => {
                let team = self.sub_team();
                let due = step >= self.assigned.1 + self.replan_every_steps;
                if !valid || due || team != self.assigned.0 {
                    self.target = self.assign(g, &candidates, &costs, &team, penalty.as_deref());
                    self.assigned = (team, step);
                }
            }
            _ if !valid => self.target = plan::nearest(candidates, &costs),
            _ => {}
        }
        let max_cells =
            self.world.max_speed_m_per_s * self.world.step_seconds / self.world.map.resolution_m;
        if let Some(aside) = self.give_way(g, me, max_cells) {
            self.idle = false;
            return aside;
        }
        self.idle = self.target.is_none();
        let target = self.target?;
        let path = plan::path_to(&costs, target)?;
        let next = plan::next_waypoint(free, &path, max_cells)?;
        (next != me).then(|| self.world.map.centre_of(next))
    }

    /// `burgard`: the robots this one can reach over current links, transitively (itself
    /// included, sorted), from its own neighbours and the fresh entries of its team table.
    fn sub_team(&self) -> Vec<RobotId> {
        let fresh = |e: &&TeamEntry| e.step + TEAM_FRESH_STEPS >= self.step;
        let mut edges: Vec<(RobotId, RobotId)> =
            self.neighbours.iter().map(|&n| (self.id, n)).collect();
        for e in self.team.values().filter(fresh) {
            edges.extend(e.neighbours.iter().map(|&n| (e.robot, n)));
        }
        let mut team = vec![self.id];
        let mut i = 0;
        while i < team.len() {
            let r = team[i];
            for &(a, b) in &edges {
                let other = if a == r {
                    b
                } else if b == r {
                    a
                } else {
                    continue;
                };
                if !team.contains(&other) {
                    team.push(other);
                }
            }
            i += 1;
        }
        // A member counts once its report (and so its cell) is known.
        team.retain(|r| *r == self.id || self.team.get(r).is_some_and(|e| fresh(&e)));
        team.sort_unstable();
        team
    }

    /// `burgard`: this robot's target in the sub-team's assignment, computed on its own
    /// planning grid from every member's cell; targets of robots outside the sub-team (last
    /// heard) discount the utilities first.
    fn assign(
        &self,
        g: &Grid,
        frontiers: &[Cell],
        mine: &plan::CostMap,
        team: &[RobotId],
        penalty: Option<&[f32]>,
    ) -> Option<Cell> {
        let maps: Vec<plan::CostMap> = team
            .iter()
            .filter(|&&r| r != self.id)
            .filter_map(|r| self.team.get(r))
            .map(|e| plan::costs_with(g, Cell::new(e.cell.0, e.cell.1), penalty))
            .collect();
        let mut costs: Vec<&plan::CostMap> = Vec::with_capacity(team.len());
        let mut others = maps.iter();
        let mut me_at = 0;
        for (k, &r) in team.iter().enumerate() {
            if r == self.id {
                me_at = k;
                costs.push(mine);
            } else if let Some(m) = others.next() {
                costs.push(m);
            }
        }
        let fixed: Vec<(Cell, f64)> = self
            .team
            .values()
            .filter(|e| !team.contains(&e.robot))
            .filter_map(|e| {
                let (x, y) = e.target?;
                Some((Cell::new(x, y), f64::from(self.step.saturating_sub(e.step))))
            })
            .collect();
        let targets = if self.burgard_search {
            let seed = u64::from(self.step) << 16 | team.len() as u64;
            coord::permutation_search(
                g,
                frontiers,
                &costs,
                &self.params,
                self.search_tries as usize,
                seed,
            )
        } else {
            coord::greedy_assignment(g, frontiers, &costs, &fixed, &self.params)
        };
        targets.get(me_at).copied().flatten()
    }

    /// `burgard`: the team table to send: this robot's own entry and every fresh one it holds.
    fn team_msg(&self) -> Team {
        let me = self.world.map.cell_of(self.pose.x, self.pose.y);
        let mut entries = vec![TeamEntry {
            robot: self.id,
            step: self.step,
            cell: (me.x, me.y),
            target: self.target.map(|c| (c.x, c.y)),
            neighbours: self.neighbours.iter().copied().collect(),
        }];
        entries.extend(
            self.team
                .values()
                .filter(|e| e.step + TEAM_FRESH_STEPS >= self.step)
                .cloned(),
        );
        Team {
            from: self.id,
            entries,
        }
    }

    /// A neighbour's team table: newer reports replace older ones.
    pub fn on_team(&mut self, t: &Team) {
        for e in &t.entries {
            if e.robot == self.id {
                continue;
            }
            if self.team.get(&e.robot).is_none_or(|old| old.step < e.step) {
                self.team.insert(e.robot, e.clone());
            }
        }
    }

    /// Messages to send this step: periodic handshakes and the log suffixes each neighbour lacks,
    /// within the per-link budget.
    pub fn radio_step(&mut self) -> Vec<RadioOut> {
        let mut out = Vec::new();
        let peers: Vec<RobotId> = self.neighbours.iter().copied().collect();
        self.pacer.at_step(self.step);
        let hello_due = self.step.is_multiple_of(self.hello_every_steps);
        let targ = (self.announced != Some(self.target)).then(|| self.target_msg());
        self.announced = Some(self.target);
        let team = (self.strategy == Strategy::Burgard).then(|| self.team_msg());
        for &peer in &peers {
            if !hello_due && targ.is_none() && team.is_none() && !self.sharing.has_pending(peer) {
                continue;
            }
            let budget = self.pacer.available(peer);
            let mut spent = 0usize;
            if let Some(msg) = &team {
                spent += proto::msg::encode(msg).len();
                out.push(RadioOut::Team {
                    to: peer,
                    msg: msg.clone(),
                });
            }
            if let Some(msg) = &targ {
                spent += proto::msg::encode(msg).len();
                out.push(RadioOut::Target {
                    to: peer,
                    msg: msg.clone(),
                });
            }
            if hello_due {
                let msg = self.sharing.knowledge();
                spent += proto::msg::encode(&msg).len();
                out.push(RadioOut::Hello { to: peer, msg });
            }
            for msg in self.sharing.outgoing(peer, budget.saturating_sub(spent)) {
                let bytes = msg.encode();
                spent += bytes.len();
                out.push(RadioOut::Share {
                    to: peer,
                    msg,
                    bytes,
                });
            }
            self.pacer.spend(peer, spent);
        }
        self.backlog = peers
            .iter()
            .filter_map(|&p| Some((p, self.sharing.backlog_bytes(p)?)))
            .collect();
        let largest = self.backlog.iter().map(|&(_, b)| b).max();
        self.sharing.after_sending(largest);
        out
    }

    /// The `targ` message for the current target.
    fn target_msg(&self) -> Target {
        Target {
            from: self.id,
            step: self.step,
            cell: self.target.map(|c| (c.x, c.y)),
        }
    }

    /// A peer's radio liveliness token appeared: greet it with our knowledge vector and target.
    pub fn link_up(&mut self, peer: RobotId) -> Vec<RadioOut> {
        if peer == self.id || !self.neighbours.insert(peer) {
            return Vec::new();
        }
        self.sharing.link_up(peer);
        let mut out = vec![RadioOut::Hello {
            to: peer,
            msg: self.sharing.knowledge(),
        }];
        if self.announced.is_some() {
            out.push(RadioOut::Target {
                to: peer,
                msg: self.target_msg(),
            });
        }
        out
    }

    /// A robot in range announced its target.
    pub fn on_target(&mut self, t: &Target) {
        if t.from != self.id {
            let cell = t.cell.map(|(x, y)| Cell::new(x, y));
            self.others_targets.insert(t.from, (cell, t.step));
        }
    }

    pub fn link_down(&mut self, peer: RobotId) {
        self.pacer.forget(peer);
        if self.neighbours.remove(&peer) {
            self.sharing.link_down(peer);
        }
    }

    pub fn on_hello(&mut self, h: &Hello) {
        self.sharing.on_hello(h);
    }

    /// Takes a peer's share (scans or ops, relayed from any owner); a gap is answered with a
    /// handshake to its sender. A share that cannot be taken counts as a decode error.
    pub fn on_share(&mut self, from: RobotId, share: &Share) -> Vec<RadioOut> {
        match self
            .sharing
            .on_share(share, &self.world.map, &self.world.laser)
        {
            Ok(true) => vec![RadioOut::Hello {
                to: from,
                msg: self.sharing.knowledge(),
            }],
            Ok(false) => Vec::new(),
            Err(e) => {
                self.decode_errors += 1;
                tracing::debug!("share from robot {from} refused: {e}");
                Vec::new()
            }
        }
    }

    /// e_avg of the own approximation so far (polygon mode).
    pub fn approx_error_avg(&self) -> Option<f64> {
        self.sharing.approx_error_avg()
    }

    /// This step's telemetry for the launcher: the planning grid the robot planned on this step.
    pub fn telemetry(&self) -> Telemetry {
        let g = &self.planning;
        Telemetry {
            robot: self.id,
            step: self.step,
            pose: self.pose,
            target: self.target.map(|t| self.world.map.centre_of(t)),
            known_cells: (g.len() - g.count(Occ::Unknown)) as u32,
            bytes_sent: self.bytes_sent,
            bytes_received: self.bytes_received,
            grid_rle: g.to_rle(),
            idle: self.idle,
            neighbours: self.neighbours.iter().copied().collect(),
            decode_errors: self.decode_errors,
            sent_by_type: self.sent_by_type.to_vec(),
            logs: self.sharing.knowledge().knowledge,
            approx_error_avg: self.sharing.approx_error_avg(),
            splits_per_step: self.sharing.splits_per_step(),
            backlog_bytes: self.backlog.clone(),
            own_rle: self.own.to_rle(),
            save: self.sharing.own_save(),
            views: self.sharing.views(),
        }
    }

    /// Accounts a payload about to be sent.
    pub fn count_sent(&mut self, class: Traffic, bytes: usize) {
        self.bytes_sent += bytes as u64;
        self.sent_by_type[class as usize] += bytes as u64;
    }

    /// Accounts a share of `bytes` encoded bytes: a scan delta to `scan`; an op chunk's ops each
    /// to its package type and the chunk's header (ids, start index, count) to `conn`, the
    /// exchange's own overhead.
    pub fn count_share_sent(&mut self, share: &Share, bytes: usize) {
        match share {
            Share::Scans(_) => self.count_sent(Traffic::Scan, bytes),
            Share::Patches(_) => self.count_sent(Traffic::Cells, bytes),
            Share::Ops(c) => {
                let mut ops = 0;
                for (kind, n) in crate::approx_exchange::op_bytes(c) {
                    self.count_sent(crate::mapper::traffic(kind), n);
                    ops += n;
                }
                self.count_sent(Traffic::Conn, bytes.saturating_sub(ops));
            }
        }
    }

    /// The robot saw no reachable frontier at its last step.
    pub fn is_idle(&self) -> bool {
        self.idle
    }

    /// G_s, the self-explored grid.
    pub fn own_grid(&self) -> &Grid {
        &self.own
    }

    /// The cells of G_s the last scan changed (for incremental contour pixels).
    pub fn own_changes(&self) -> &[Cell] {
        &self.own_changed
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proto::geom::MapInfo;
    use world_server::{laser, motion};

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
        let info = MapInfo {
            width: truth.width(),
            height: truth.height(),
            resolution_m: 0.2,
            origin_x_m: 0.0,
            origin_y_m: 0.0,
        };
        let world = WorldInfo {
            map: info,
            laser: s.laser(),
            step_seconds: s.clock.step_seconds,
            robots: 2,
            max_speed_m_per_s: s.robots.speed_m_per_s,
        };
        let mut agents = [Agent::new(0, world.clone(), &s), Agent::new(1, world, &s)];
        agents[0].link_up(1);
        agents[1].link_up(0);
        let mut poses = starts.map(|c| {
            let (x, y) = info.centre_of(c);
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
                    if let RadioOut::Target { to, msg } = out {
                        agents[usize::from(to)].on_target(&msg);
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
                        &[(1 - i as RobotId, (other.x, other.y))],
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
