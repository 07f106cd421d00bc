//! One robot's decision loop as a pure state machine (the steps of thesis Algorithm 10 that
//! exist so far): integrate the scan into G_s, exchange over the radio, build the planning grid,
//! pick a target, plan, move. [`crate::node`] feeds it from zenoh and sends what it returns.
//!
//! The agent composes parts and decides nothing itself: what is exchanged is
//! [`crate::exchange::sharing`]'s business (`raw-scans`, `polygon` or `grid-snapshots`); the planning grid
//! never lets a peer's data override a cell of G_s (thesis §5.2). Which frontier to go to is the
//! coordination strategy's ([`crate::coord`], `coordination.strategy`), given what was heard of
//! other robots; getting past other robots and refused moves is [`crate::nav::right_of_way`]'s; the
//! radio — neighbours, pacing, encoding and counting — is [`crate::radio::station`]'s.

use proto::geom::{Metres, Pose};
use proto::grid::{Cell, Grid, Occ, Rect};
use proto::grid_report::{GridReport, Reporter};
use proto::msg::{Cmd, RobotId, Scan, Step, Telemetry, WorldInfo};
use proto::scenario::{Relay, Scenario};

use crate::coord::{self, Coordinator, Heard, Situation, Status, Steer};
use crate::exchange::relay::RelayTree;
use crate::exchange::sharing::{self, Sharing};
use crate::mapping::grid::Evidence;
use crate::nav::plan;
use crate::nav::right_of_way::RightOfWay;
use crate::radio::station::{self, Msg, Outgoing, Radio, Received};

pub struct Agent {
    pub id: RobotId,
    /// The base station (`[base_station]`, node `robots.count`): it neither senses nor moves;
    /// it exchanges maps like any node and runs its strategy's executive, if there is one.
    base: bool,
    /// 0 for the process the run started; one more for each restart.
    life: u16,
    /// Recovery deliberately broken ([`crate::exchange::transitive::BROKEN_RECOVERY_ENV`]).
    broken_recovery: bool,
    world: WorldInfo,
    /// G_s: what this robot sensed itself, and the beam counts behind it.
    own: Grid,
    own_evidence: Evidence,
    /// Cells of G_s the last scan changed.
    own_changed: Vec<Cell>,
    /// The planning grid of the last step (built once per step, reused by telemetry).
    planning: Grid,
    /// The planning grid and G_s as last reported to the launcher (telemetry carries what
    /// changed since; the first also counts the planning grid's known cells), and this step's
    /// report of the planning grid, made when it was built.
    reported: [Reporter; 2],
    /// Per grid of `reported`, a rectangle outside which it is as last reported (`None`: all
    /// of it is): a report compares only those cells.
    unreported: [Option<Rect>; 2],
    planning_report: Option<GridReport>,
    /// The path costs of the last step, whose buffers the next step's search reuses.
    costs: plan::CostMap,
    /// The way to the target the robot last followed: a step later, the way there from a cell
    /// along it is searched by [`plan::path_along`].
    way: Vec<Cell>,
    /// The planning grid's frontier cells, kept as it changes.
    frontier_cells: plan::FrontierCells,
    /// What it shares and how peers' shares reach its planning grid (by exchange mode).
    sharing: Box<dyn Sharing>,
    /// Which neighbour sends it each owner's log, and to which it sends (`exchange.relay =
    /// "tree"`; `None`: the thesis's flooding).
    relay: Option<RelayTree>,
    /// How it picks its target (by coordination strategy).
    coordinator: Box<dyn Coordinator>,
    /// Other robots' announced targets.
    heard: Heard,
    right_of_way: RightOfWay,
    radio: Radio,
    pose: Pose,
    step: Step,
    target: Option<Cell>,
    /// Obstacle penalty of path costs: weight (0 = off) and σ in cells.
    obstacle: ObstaclePenalty,
    idle: bool,
}

/// The obstacle penalty of path costs ([`plan::obstacle_penalty`]).
#[derive(Clone, Copy, Debug, PartialEq)]
struct ObstaclePenalty {
    /// 0: off.
    weight: f64,
    sigma_cells: f64,
}

impl Agent {
    pub fn new(id: RobotId, world: WorldInfo, s: &Scenario) -> Agent {
        Agent::in_life(id, 0, world, s)
    }

    /// Robot `id` in its life `life` (0: the process the run started; one more for each
    /// restart): it writes the log of owner [`proto::msg::log_owner`]`(id, life)` and holds its
    /// earlier lives' logs like anyone else's, as its peers give them back.
    pub fn in_life(id: RobotId, life: u16, world: WorldInfo, s: &Scenario) -> Agent {
        let own_log = proto::msg::log_owner(id, life).unwrap_or(id);
        let empty = Grid::new(world.map.width, world.map.height, Occ::Unknown);
        let max_range_cells = world.laser.max_range_m / world.map.resolution_m;
        let base = s.base_id() == Some(id);
        Agent {
            id,
            base,
            own_evidence: Evidence::new(&empty),
            own_changed: Vec::new(),
            sharing: sharing::new(s, id, own_log, &world, station::budget_per_step(s, &world)),
            relay: (s.exchange.relay == Relay::Tree).then(|| RelayTree::new(id, own_log)),
            life,
            broken_recovery: std::env::var(crate::exchange::transitive::BROKEN_RECOVERY_ENV)
                .is_ok_and(|v| v == "forget-earlier-lives"),
            coordinator: coord::new(s, id, &world, max_range_cells),
            heard: Heard::default(),
            right_of_way: RightOfWay::new(id, s.robots.radius_m, world.map.resolution_m),
            radio: Radio::new(id, s, &world),
            obstacle: ObstaclePenalty {
                weight: s.coordination.obstacle_penalty,
                sigma_cells: s.coordination.obstacle_sigma_cells,
            },
            world,
            own: empty.clone(),
            planning: empty,
            reported: Default::default(),
            unreported: [None; 2],
            planning_report: None,
            costs: plan::CostMap::default(),
            way: Vec::new(),
            frontier_cells: plan::FrontierCells::default(),
            pose: Pose::default(),
            step: 0,
            target: None,
            idle: false,
        }
    }

    /// Integrates a scan, records it in the own log and decides the move for its step.
    pub fn on_scan(&mut self, scan: &Scan) -> Cmd {
        self.step = scan.step;
        self.pose = scan.pose;
        if self.base {
            // The base station's tick: nothing sensed, nothing logged, no move; its planning
            // grid is what reached it (telemetry), its strategy the executive.
            self.build_planning();
            return Cmd {
                step: scan.step,
                robot: self.id,
                waypoint: None,
            };
        }
        let w = &self.world;
        self.own_changed =
            self.own_evidence
                .integrate(&mut self.own, &w.map, scan.pose, &scan.ranges, &w.laser);
        self.sharing
            .after_scan(scan, &w.laser, &self.own, &self.own_changed);
        let changed = Rect::around(self.own_changed.iter().copied());
        self.unreported[1] = Rect::union_of(self.unreported[1], changed);
        self.right_of_way.on_move(scan.step, scan.last_move, &w.map);
        let waypoint = self.plan();
        Cmd {
            step: scan.step,
            robot: self.id,
            waypoint,
        }
    }

    /// The planning grid: G_s with what peers shared filling its unknown cells.
    pub fn planning_grid(&self) -> Grid {
        self.sharing.planning_grid(&self.own)
    }

    /// Builds this step's planning grid over the last one (once per step) and reports it for
    /// the step's telemetry; the reporter counts its known cells where they changed.
    fn build_planning(&mut self) {
        let changed = (self.sharing).update_planning_grid(&self.own, &mut self.planning);
        self.frontier_cells.update(&self.planning, &changed);
        let changed = changed
            .into_iter()
            .fold(None, |r, c| Rect::union_of(r, Some(c)));
        self.unreported[0] = Rect::union_of(self.unreported[0], changed);
        self.planning_report = Some(self.report(0));
    }

    fn my_cell(&self) -> Cell {
        self.world.map.cell_of(self.pose.xy())
    }

    /// This step's target and the waypoint toward it (or out of another robot's way).
    fn plan(&mut self) -> Option<Metres> {
        // The search's buffers are kept from step to step.
        let mut costs = std::mem::take(&mut self.costs);
        let waypoint = self.plan_with(&mut costs);
        self.costs = costs;
        waypoint
    }

    /// [`Self::plan`] with the path costs searched into `costs`.
    fn plan_with(&mut self, costs: &mut plan::CostMap) -> Option<Metres> {
        self.build_planning();
        let g = &self.planning;
        let me = self.my_cell();
        let ObstaclePenalty {
            weight,
            sigma_cells,
        } = self.obstacle;
        let penalty = (weight > 0.0).then(|| plan::obstacle_penalty(g, sigma_cells, weight));
        let detour = self.right_of_way.detour(g, me, &self.heard);
        let free = detour.as_ref().unwrap_or(g);
        self.right_of_way.give_up(&mut self.target);
        let usable = self.target.filter(|&t| self.right_of_way.usable(t, me));
        // A strategy that keeps a valid target needs only the way to it (a search bounded by
        // the way followed a step before, or an A*: the full search's path), and a search all
        // over only when the target is gone or the strategy looks at every frontier each step.
        let keep = usable.filter(|_| self.coordinator.keeps_valid_target());
        // A strategy that looks at the frontiers' costs alone needs the search only as far as
        // the farthest frontier.
        let everything = |costs: &mut plan::CostMap| {
            if self.coordinator.looks_at_frontier_costs_only() {
                let cells = &self.frontier_cells;
                plan::costs_to_frontiers(costs, free, me, penalty.as_deref(), cells);
            } else {
                plan::costs_into(costs, free, me, penalty.as_deref());
            }
        };
        let kept = keep
            .filter(|&t| g.is_frontier(t))
            .and_then(|t| plan::path_along(costs, free, me, penalty.as_deref(), t, &self.way));
        let mut frontiers = Vec::new();
        if kept.is_none() {
            everything(costs);
            frontiers = self.frontier_cells.reachable(costs);
            let valid = usable.is_some_and(|t| frontiers.contains(&t));
            let candidates = self.right_of_way.candidates(&frontiers, me);
            self.target = self.coordinator.choose(&Situation {
                id: self.id,
                step: self.step,
                me,
                grid: g,
                known: self.reported[0].known(),
                costs,
                penalty: penalty.as_deref(),
                candidates: &candidates,
                target: self.target,
                valid,
                neighbours: self.radio.neighbours(),
                heard: &self.heard,
            });
        }
        let w = &self.world;
        let steered = match self.coordinator.steer() {
            Steer::Target => None,
            Steer::Stay => Some(None),
            Steer::To(c) => Some((c != me).then(|| w.map.centre_of(c))),
        };
        if let Some(waypoint) = steered {
            // The strategy moves the robot itself: idle only when nothing is left to explore.
            self.idle = kept.is_none() && frontiers.is_empty();
            return waypoint;
        }
        let max_cells = w.max_speed_m_per_s * w.step_seconds / w.map.resolution_m;
        let at = self.pose.xy();
        if let Some(aside) = self
            .right_of_way
            .give_way(g, &w.map, at, me, &self.heard, max_cells)
        {
            self.idle = false;
            return aside.map(|n| w.map.centre_of(n));
        }
        self.idle = self.target.is_none();
        let path = match kept {
            Some(path) => path,
            None => plan::path_to(costs, self.target?)?,
        };
        let next = plan::next_waypoint(free, &w.map, at, &path, max_cells);
        self.way = path;
        next.and_then(|next| (next != me).then(|| w.map.centre_of(next)))
    }

    /// Messages to send this step: the strategy's, the target when it changed, periodic
    /// handshakes and the log suffixes each neighbour lacks, within the per-link budget.
    pub fn radio_step(&mut self) -> Vec<Outgoing> {
        let coord = self.coordinator.messages(&Status {
            id: self.id,
            step: self.step,
            me: self.my_cell(),
            target: self.target,
            neighbours: self.radio.neighbours(),
            backlog: self.radio.backlog(),
        });
        let mut routes = Vec::new();
        if let Some(tree) = &mut self.relay {
            let neighbours = self.radio.neighbours();
            tree.update(neighbours);
            for &peer in neighbours {
                self.sharing
                    .handshake_mut()
                    .leave_out(peer, tree.left_out(peer));
            }
            let held = self.sharing.knowledge().knowledge;
            let have = |owner| held.iter().find(|k| k.0 == owner).map_or(0, |k| k.1);
            routes = tree.announcements(neighbours, have);
        }
        let sharing = self.sharing.as_mut();
        self.radio
            .step(self.step, self.target, &coord, &routes, sharing)
    }

    /// A peer's radio liveliness token appeared: greet it with our knowledge vector and target.
    pub fn link_up(&mut self, peer: RobotId) -> Vec<Outgoing> {
        if let Some(tree) = self
            .relay
            .as_mut()
            .filter(|_| !self.radio.neighbours().contains(&peer))
        {
            tree.link_up(peer);
        }
        let sharing = self.sharing.as_mut();
        self.radio.link_up(peer, sharing, self.step, self.target)
    }

    /// Whether this robot hears `peer` (its radio token is seen: a session to it is up).
    pub fn hears(&self, peer: RobotId) -> bool {
        self.radio.neighbours().contains(&peer)
    }

    pub fn link_down(&mut self, peer: RobotId) {
        if let Some(tree) = &mut self.relay {
            tree.link_down(peer);
        }
        self.radio.link_down(peer, self.sharing.as_mut());
    }

    /// Lockstep: the link to `peer` carries `rate` bytes per simulated second (netem's plan;
    /// `None`: the scenario's bandwidth).
    pub fn set_rate(&mut self, peer: RobotId, rate: Option<u64>) {
        self.radio.set_rate(peer, rate);
    }

    /// Lockstep: what netem can carry to `peer` in this step (the plan's credit; `None`:
    /// unlimited).
    pub fn set_credit(&mut self, peer: RobotId, credit: Option<u32>) {
        self.radio.set_credit(peer, credit);
    }

    /// Lockstep: the step's neighbours are exactly `linked` (netem's plan). Links that went
    /// down are forgotten; new ones are greeted. Returns the greetings and the peers dropped.
    pub fn set_neighbours(&mut self, linked: &[RobotId]) -> (Vec<Outgoing>, Vec<RobotId>) {
        let gone: Vec<RobotId> = self
            .radio
            .neighbours()
            .iter()
            .copied()
            .filter(|p| !linked.contains(p))
            .collect();
        for &p in &gone {
            self.link_down(p);
        }
        let mut out = Vec::new();
        for &p in linked {
            out.extend(self.link_up(p));
        }
        (out, gone)
    }

    /// Lockstep with step markers: this step's frame to every neighbour, its messages and its
    /// marker ([`Radio::frames`](crate::radio::station::Radio::frames)).
    pub fn frames(&mut self) -> Vec<Outgoing> {
        self.radio.frames(self.step)
    }

    /// Bytes received on the radio under key segment `kind` (`hello`, `targ`, `delta`, ...):
    /// counted and decoded by the radio ([`Self::receive`]), then taken ([`Self::take`]).
    pub fn on_radio(&mut self, kind: &str, bytes: &[u8]) -> Vec<Outgoing> {
        let msgs = self.receive(kind, bytes).msgs;
        msgs.into_iter().flat_map(|m| self.take(m)).collect()
    }

    /// Counts and decodes bytes received under key segment `kind`: the messages, and a frame's
    /// marker (what does not decode counts as a decode error).
    pub fn receive(&mut self, kind: &str, bytes: &[u8]) -> Received {
        self.radio.receive(kind, bytes)
    }

    /// Takes a received message into the part it is for. A share that reveals a gap is answered
    /// with a handshake to its sender; one that cannot be taken counts as a decode error.
    pub fn take(&mut self, m: Msg) -> Vec<Outgoing> {
        match m {
            Msg::Hello(h) => {
                // A lossy radio: what we told a neighbour before its interest reached us may be
                // lost, so its greeting (or periodic handshake) gets all our routes again, as it
                // resets what we believe it holds.
                if let Some(tree) = self
                    .relay
                    .as_mut()
                    .filter(|_| h.reset && self.radio.lossy())
                {
                    tree.retell(h.from);
                }
                self.sharing.on_hello(&h)
            }
            Msg::Routes(r) => {
                if let Some(tree) = &mut self.relay {
                    tree.on_routes(&r);
                    for route in &r.routes {
                        if let Some(have) = route.have {
                            let ex = self.sharing.handshake_mut();
                            ex.holds(r.from, route.owner, have);
                        }
                    }
                }
            }
            Msg::Target(t) => self.heard.on_target(self.id, &t),
            Msg::Coord(m) => self.coordinator.on_message(self.id, &m),
            Msg::Share(share) => {
                let w = &self.world;
                let taken = self.sharing.on_share(&share, &w.map, &w.laser);
                if self.broken_recovery {
                    self.forget_earlier_lives();
                }
                match taken {
                    Ok(true) => {
                        let hello = Msg::Hello(self.sharing.knowledge());
                        return self.radio.send_one(share.from(), &hello);
                    }
                    Ok(false) => {}
                    Err(e) => {
                        self.radio.refused();
                        tracing::debug!("share from robot {} refused: {e}", share.from());
                    }
                }
            }
        }
        Vec::new()
    }

    /// The deliberately broken recovery ([`crate::exchange::transitive::BROKEN_RECOVERY_ENV`]): drops the
    /// logs of every robot's lives before the latest one this node has heard of.
    fn forget_earlier_lives(&mut self) {
        let owners: Vec<RobotId> = self
            .sharing
            .knowledge()
            .knowledge
            .iter()
            .map(|k| k.0)
            .collect();
        for &o in &owners {
            let (robot, life) = proto::msg::owner_life(o);
            let superseded = owners.iter().any(|&p| {
                proto::msg::owner_life(p).0 == robot && proto::msg::owner_life(p).1 > life
            });
            if superseded {
                self.sharing.handshake_mut().forget(o);
            }
        }
    }

    /// e_avg of the own approximation so far (polygon mode).
    pub fn approx_error_avg(&self) -> Option<f64> {
        self.sharing.approx_error_avg()
    }

    /// This step's report of the planning grid (0) or G_s (1).
    fn report(&mut self, which: usize) -> GridReport {
        let grid = [&self.planning, &self.own][which];
        let changed = self.unreported[which].take();
        self.reported[which].report_within(self.step, grid, changed)
    }

    /// This step's telemetry for the launcher: the planning grid the robot planned on this step
    /// and its own grid, each as what changed since the last report (or whole, now and then).
    pub fn telemetry(&mut self) -> Telemetry {
        let grid = match self.planning_report.take() {
            Some(report) => report,
            None => self.report(0),
        };
        let own = self.report(1);
        let c = self.radio.counters();
        Telemetry {
            robot: self.id,
            step: self.step,
            pose: self.pose,
            target: self.target.map(|t| self.world.map.centre_of(t)),
            known_cells: self.reported[0].known() as u32,
            bytes_sent: c.bytes_sent,
            bytes_received: c.bytes_received,
            grid,
            idle: self.idle,
            alone: self.coordinator.alone(),
            judged: self.coordinator.judged(),
            life: self.life,
            log_bytes: self.sharing.held_bytes(),
            neighbours: self.radio.neighbours().iter().copied().collect(),
            decode_errors: c.decode_errors,
            sent_by_type: c.sent_by_type.to_vec(),
            logs: self.sharing.knowledge().knowledge,
            approx_error_avg: self.sharing.approx_error_avg(),
            splits_per_step: self.sharing.splits_per_step(),
            backlog_bytes: self.radio.backlog().to_vec(),
            own,
            save: self.sharing.own_save(),
            views: self.sharing.views(),
        }
    }

    /// What it holds of every owner's polygonal approximation at its last step (polygon
    /// exchange; no owners in other modes): the answer to a viewer's question, never on the
    /// step's path.
    pub fn held(&self) -> proto::msg::Held {
        proto::msg::Held {
            robot: self.id,
            step: self.step,
            owners: self.sharing.held(),
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
    use crate::testutil::world_info;
    use proto::geom::MapInfo;
    use proto::msg::MoveOutcome;
    use world_server::laser;

    /// A 30 × 20 cell room (0.2 m cells) with a pillar.
    fn room() -> Grid {
        let mut g = Grid::new(30, 20, Occ::Occupied);
        for y in 1..19 {
            for x in 1..29 {
                g.set(Cell::new(x, y), Occ::Free);
            }
        }
        for y in 8..12 {
            for x in 13..17 {
                g.set(Cell::new(x, y), Occ::Occupied);
            }
        }
        g
    }

    #[test]
    fn a_peer_holds_the_owners_polygons_once_it_has_its_log_up_to_the_save_point() {
        let truth = room();
        let info = MapInfo::at_origin(truth.width(), truth.height(), 0.2);
        let s = Scenario::default();
        assert_eq!(s.exchange.mode, proto::scenario::ExchangeMode::Polygon);
        let world = world_info(&s, info, 2);
        let mut team = [Agent::new(0, world.clone(), &s), Agent::new(1, world, &s)];
        let mut out: Vec<Outgoing> = team.iter_mut().flat_map(|a| a.link_up(1 - a.id)).collect();
        let poses = [(1.0, 1.0), (5.0, 3.0)].map(|(x, y)| Pose { x, y, theta: 0.0 });
        let mut caught_up = None;
        for step in 0..200 {
            for (a, &pose) in team.iter_mut().zip(&poses) {
                let ranges = laser::cast(&truth, &info, pose, &s.laser(), None);
                let last_move = MoveOutcome::Stayed;
                let _ = a.on_scan(&Scan {
                    step,
                    pose,
                    ranges,
                    last_move,
                });
                out.extend(a.radio_step());
                out.extend(a.frames());
            }
            for o in std::mem::take(&mut out) {
                let kind = proto::keys::radio_kind(&o.key)
                    .expect("a radio key")
                    .to_string();
                out.extend(team[usize::from(o.to)].on_radio(&kind, &o.bytes));
            }
            let (own, peer) = (team[0].held(), team[1].held());
            assert_eq!((own.robot, own.step, peer.step), (0, step, step));
            let mine = &own.owners[0];
            assert_eq!((mine.owner, mine.held), (0, mine.shown));
            assert_eq!(
                peer.owners[0].owner, 1,
                "a robot's own approximation comes first"
            );
            if let Some(held) = peer.owners.iter().find(|h| h.owner == 0) {
                assert!(held.shown <= held.held && held.held <= mine.held);
                if held.shown == mine.shown && step > 10 {
                    assert_eq!(held.polygons, mine.polygons);
                    caught_up = Some(step);
                    break;
                }
            }
        }
        let step = caught_up.expect("robot 1 never showed robot 0's whole approximation");
        let own = team[0].held();
        assert!(
            !own.owners[0].polygons.is_empty(),
            "no polygons by step {step}"
        );
        assert!(own.owners[0].polygons.iter().any(|p| p.vertices.len() >= 3));
    }

    #[test]
    fn other_exchange_modes_hold_no_polygons() {
        let mut s = Scenario::default();
        s.exchange.mode = proto::scenario::ExchangeMode::RawScans;
        let world = world_info(&s, MapInfo::at_origin(30, 20, 0.2), 2);
        assert!(Agent::new(0, world, &s).held().owners.is_empty());
    }
}
