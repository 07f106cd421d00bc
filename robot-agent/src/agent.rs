//! One robot's decision loop as a pure state machine (the steps of thesis Algorithm 10 that
//! exist so far): integrate the scan into G_s, exchange over the radio, build the planning grid,
//! pick a target, plan, move. [`crate::node`] feeds it from zenoh and sends what it returns.
//!
//! What is exchanged is [`crate::sharing`]'s business (`raw-scans` or `polygon`, DESIGN.md §4.8);
//! the planning grid never lets a peer's data override a cell of G_s (thesis §5.2).

use std::collections::{BTreeSet, HashMap};

use proto::geom::{LaserSpec, Pose};
use proto::grid::{Cell, Grid, Occ};
use proto::msg::{
    Cmd, Hello, MoveOutcome, RobotId, Scan, ScanDelta, Step, Telemetry, Traffic, WorldInfo,
};
use proto::scenario::Scenario;

use crate::grid::Evidence;
use crate::plan;
use crate::sharing::{Share, Sharing};

/// A message for the radio plane.
#[derive(Clone, Debug, PartialEq)]
pub enum RadioOut {
    Hello {
        to: RobotId,
        msg: Hello,
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

/// How many steps of unused radio budget a neighbour's credit can hold.
pub const BURST_STEPS: usize = 4;

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
    neighbours: BTreeSet<RobotId>,
    /// Radio budget per link and step in bytes (`usize::MAX`: unlimited).
    budget_per_step: usize,
    /// The sender's own pacing: per neighbour, budget not yet spent. Each step adds
    /// `budget_per_step`, up to `burst_bytes`; what is sent is taken off. On average a link is
    /// offered no more than its bandwidth, whatever the robot would like to send, so queues in
    /// netem and the kernel stay short and keep-alives are not stuck behind data.
    credit: HashMap<RobotId, usize>,
    /// The most credit a neighbour can hold: [`BURST_STEPS`] steps of budget, and at least the
    /// largest single-scan delta (so a scan bigger than one step's budget still goes, every few
    /// steps, instead of blocking the log forever).
    burst_bytes: usize,
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
        let per_step = s.radio.bandwidth_bytes_per_s as f64 * world.step_seconds;
        let budget_per_step = if per_step <= 0.0 {
            usize::MAX
        } else {
            (per_step as usize).max(1)
        };
        let burst_bytes = budget_per_step
            .saturating_mul(BURST_STEPS)
            .max(largest_delta_bytes(&world.laser));
        Agent {
            id,
            world,
            own_evidence: Evidence::new(&empty),
            own_changed: Vec::new(),
            sharing: Sharing::new(s.exchange.mode, id, &empty),
            own: empty.clone(),
            planning: empty,
            pose: Pose::default(),
            step: 0,
            target: None,
            rejections: 0,
            blacklist: HashMap::new(),
            neighbours: BTreeSet::new(),
            budget_per_step,
            credit: HashMap::new(),
            burst_bytes,
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

    fn plan(&mut self) -> Option<(f64, f64)> {
        self.planning = self.planning_grid();
        let g = &self.planning;
        let me = self.world.map.cell_of(self.pose.x, self.pose.y);
        let costs = plan::costs(g, me);
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
        if !self
            .target
            .is_some_and(|t| usable(&t) && frontiers.contains(&t))
        {
            self.target = plan::nearest(frontiers.iter().copied().filter(usable), &costs);
        }
        self.idle = self.target.is_none();
        let target = self.target?;
        let path = plan::path_to(&costs, target)?;
        let max_cells =
            self.world.max_speed_m_per_s * self.world.step_seconds / self.world.map.resolution_m;
        let next = plan::next_waypoint(g, &path, max_cells)?;
        (next != me).then(|| self.world.map.centre_of(next))
    }

    /// Messages to send this step: periodic handshakes and the log suffixes each neighbour lacks,
    /// within the per-link budget.
    pub fn radio_step(&mut self) -> Vec<RadioOut> {
        let mut out = Vec::new();
        let peers: Vec<RobotId> = self.neighbours.iter().copied().collect();
        for peer in peers {
            let credit = self.credit.entry(peer).or_insert(0);
            let mut budget = credit
                .saturating_add(self.budget_per_step)
                .min(self.burst_bytes);
            if self.step.is_multiple_of(self.hello_every_steps) {
                let msg = self.sharing.knowledge();
                budget = budget.saturating_sub(proto::msg::encode(&msg).len());
                out.push(RadioOut::Hello { to: peer, msg });
            }
            for msg in self.sharing.outgoing(peer, budget) {
                let bytes = msg.encode();
                budget = budget.saturating_sub(bytes.len());
                out.push(RadioOut::Share {
                    to: peer,
                    msg,
                    bytes,
                });
            }
            *credit = budget;
        }
        out
    }

    /// A peer's radio liveliness token appeared: greet it with our knowledge vector.
    pub fn link_up(&mut self, peer: RobotId) -> Vec<RadioOut> {
        if peer == self.id || !self.neighbours.insert(peer) {
            return Vec::new();
        }
        self.sharing.link_up(peer);
        vec![RadioOut::Hello {
            to: peer,
            msg: self.sharing.knowledge(),
        }]
    }

    pub fn link_down(&mut self, peer: RobotId) {
        self.credit.remove(&peer);
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
