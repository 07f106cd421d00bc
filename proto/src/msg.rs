//! Every message that crosses a process boundary, and its versioned postcard codec.
//!
//! Sim plane (world-server ⇄ robots ⇄ launcher): [`WorldInfo`], [`TruthMap`], [`Scan`], [`Cmd`],
//! [`Status`], [`Telemetry`], [`Control`], [`Held`]. Radio plane (robot ⇄ robot, through netem):
//! [`Hello`] (the thesis's `conn` handshake) and [`ScanDelta`] (the `raw-scans` exchange of
//! docs/design.md §4.8). Every payload starts with [`PROTOCOL_VERSION`] so that mixed builds fail
//! loudly instead of misreading each other.

use std::collections::BTreeMap;
use std::net::SocketAddr;

use serde::{de::DeserializeOwned, Deserialize, Serialize};

use crate::geom::{LaserSpec, MapInfo, Metres, Pose};
use crate::grid::Cell;
use crate::grid_report::GridReport;

/// Bumped whenever any message below changes shape.
pub const PROTOCOL_VERSION: u16 = 16;

pub use crate::ids::{RobotId, Step};

/// Reply to the `sim/world/info` query: everything a robot may know about the world before it
/// explores it (extent and resolution of the grid, its sensor, the clock).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct WorldInfo {
    pub map: MapInfo,
    pub laser: LaserSpec,
    pub step_seconds: f64,
    pub robots: u16,
    pub max_speed_m_per_s: f64,
}

/// Reply to the `sim/world/truth` query (launcher only: the evaluator needs ground truth).
/// `reachable_rle` is a grid whose `Free` cells are the reachable free region.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct TruthMap {
    pub map: MapInfo,
    pub grid_rle: Vec<u8>,
    pub reachable_rle: Vec<u8>,
}

/// What happened to a robot's last move command.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum MoveOutcome {
    /// No command had been sent yet (step 0).
    Start,
    Moved,
    /// The robot asked to stay.
    Stayed,
    /// The command did not arrive within `step_timeout` (lockstep) or the step period (realtime).
    Missed,
    /// The straight segment crosses a cell that is not free.
    Blocked,
    /// The end point is too close to another robot: which, and where it stands (millimetres; the
    /// robot feels what it bumped into, and needs to know where to plan around it).
    Collision {
        with: RobotId,
        at_mm: (i32, i32),
    },
    OutOfMap,
    /// The command named another step than the current one.
    WrongStep,
}

/// World → robot, every step: the robot's true pose and its laser scan.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Scan {
    pub step: Step,
    pub pose: Pose,
    /// One range per beam in metres; `>= laser.max_range_m` means no return.
    pub ranges: Vec<f32>,
    pub last_move: MoveOutcome,
}

/// Robot → world, every step: where to go (`None`: stay).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Cmd {
    pub step: Step,
    pub robot: RobotId,
    pub waypoint: Option<Metres>,
}

/// World → everyone, after each step's moves: the truth-side state.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Status {
    /// The step whose scans are published next.
    pub step: Step,
    pub robots: Vec<RobotStatus>,
    /// Moves refused so far because the robot would come too close to another robot.
    pub collisions_total: u64,
    /// Moves refused so far because their segment crosses a cell that is not free (walls).
    pub blocked_total: u64,
    /// The base station (node `robots.count`), if the run has one: where it stands and whether
    /// its process is up. It never moves.
    pub base: Option<RobotStatus>,
    /// Lockstep: the live robots whose command for the previous step did not come before
    /// `clock.step_timeout_ms` — the world went on without them, so a wall-clock timeout
    /// decided something and the run is not reproducible.
    pub missed: Vec<RobotId>,
}

#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct RobotStatus {
    pub id: RobotId,
    pub pose: Pose,
    pub alive: bool,
    pub distance_m: f64,
}

/// Robot → launcher, every step (sim plane; never counted as radio traffic).
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Telemetry {
    pub robot: RobotId,
    pub step: Step,
    pub pose: Pose,
    /// Where the robot is heading (the centre of its target cell), if anywhere.
    pub target: Option<Metres>,
    /// Cells of the planning grid that are not unknown.
    pub known_cells: u32,
    /// Radio payload bytes this robot handed to its radio session so far, and received.
    pub bytes_sent: u64,
    pub bytes_received: u64,
    /// The robot's planning grid: what changed since its last report, or the whole grid
    /// ([`crate::grid_report`]).
    pub grid: GridReport,
    /// True when the robot sees no reachable frontier in its planning grid.
    pub idle: bool,
    /// Peers whose radio liveliness token this robot currently sees.
    pub neighbours: Vec<RobotId>,
    /// Radio payloads that failed to decode so far.
    pub decode_errors: u64,
    /// Payload bytes sent so far per traffic class, in [`Traffic::ALL`] order.
    pub sent_by_type: Vec<u64>,
    /// Per owner, how many records of its log this robot holds (its own included): the
    /// knowledge vector of the exchange.
    pub logs: Vec<(RobotId, u32)>,
    /// e_avg of the robot's own approximation so far (polygon exchange; eq. 6.1).
    pub approx_error_avg: Option<f64>,
    /// The splitting frequency s for the next step (polygon exchange; thesis §5.3).
    pub splits_per_step: Option<f64>,
    /// Per neighbour, the bytes of log entries it still lacked after this step's sending: what
    /// waits for that link.
    pub backlog_bytes: Vec<(RobotId, u64)>,
    /// G_s, the self-explored grid, reported like `grid` (what the robot sensed itself, against
    /// which the launcher shows what it learned from others).
    pub own: GridReport,
    /// Polygon exchange: the robot's own log length after this step's save point and the digest
    /// of its approximation A_t there.
    pub save: Option<(u32, u64)>,
    /// Polygon exchange: what the robot shows of every other owner.
    pub views: Vec<View>,
    /// `bids`: the robot decided alone this step (no assignment from the executive younger
    /// than `coordination.bids.assignment_timeout_steps`).
    pub alone: bool,
    /// `pack`: what the robot, leading its group, judged of the links of the configuration it
    /// chose (checked by the launcher against netem's links of that step).
    pub judged: Option<Judged>,
    /// Which life of the robot this is: 0 for the process the run started, one more for each
    /// restart (its own log's owner is [`log_owner`]`(robot, life)`).
    pub life: u16,
    /// Polygon exchange: per owner whose log the robot holds (its own included), the encoded
    /// bytes of the ops it holds (each op's compact encoding, chunk headers aside).
    pub log_bytes: Vec<(RobotId, u64)>,
}

/// How many robot ids one life of the log owners spans: robot `r` in life `l` owns the log
/// `r + l * LIFE_STRIDE` ([`log_owner`]). Life 0 owns the log numbered like the robot, so runs
/// without restarts name owners exactly as robots.
pub const LIFE_STRIDE: u16 = 1024;

/// The most lives a robot can have (its restarts + 1) so that every owner fits in a [`RobotId`].
pub const MAX_LIVES: u16 = u16::MAX / LIFE_STRIDE + 1;

/// The owner of the log robot `robot` writes in its life `life` (0: the process the run
/// started). A restarted robot never appends to the log of an earlier life: its peers may hold
/// different prefixes of it, and indices it reused would clash with theirs. The earlier log
/// stays an owner like any other, relayed to everyone — the restarted robot included.
/// `None` if the robot id or the life is out of range.
pub fn log_owner(robot: RobotId, life: u16) -> Option<RobotId> {
    if robot >= LIFE_STRIDE {
        return None;
    }
    life.checked_mul(LIFE_STRIDE)?.checked_add(robot)
}

/// The robot and the life of a log owner (inverse of [`log_owner`]).
pub fn owner_life(owner: RobotId) -> (RobotId, u16) {
    (owner % LIFE_STRIDE, owner / LIFE_STRIDE)
}

/// A leader's judgement of its group's links at `step` (`pack`): among the pairs of `group`,
/// those it expects up — from its own map and the radio model's parameters, never the truth.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct Judged {
    pub step: Step,
    pub group: Vec<RobotId>,
    pub up: Vec<(RobotId, RobotId)>,
}

/// Robot → viewer, on request ([`crate::keys::held`]; sim plane, never radio traffic): every
/// polygonal approximation the robot holds at `step` — its own and each other owner's as far
/// as it has that owner's log (polygon exchange; empty in other exchange modes).
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct Held {
    pub robot: RobotId,
    pub step: Step,
    pub owners: Vec<HeldApprox>,
}

/// One owner's approximation as a robot holds it: `held` ops of the owner's log, of which the
/// first `shown` end at a save point and make up `polygons` (for the robot's own log both are
/// its length).
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct HeldApprox {
    pub owner: RobotId,
    pub held: u32,
    pub shown: u32,
    pub polygons: Vec<Outline>,
}

/// One polygon of an approximation: its vertices in quarter cells of the map's grid (cell
/// `(x, y)` spans `[4x, 4x + 4) × [4y, 4y + 4)`), each with f_occ of the edge that starts at
/// it. `outside`: the polygon encloses occupied or unknown space (else free space).
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct Outline {
    pub outside: bool,
    pub vertices: Vec<(i32, i32, crate::grid::Occ)>,
}

/// A receiver's view of another owner's approximation (telemetry): `held` ops of the owner's
/// log, of which the first `shown` end at a save point and make up the approximation shown
/// (digest `digest`, comparable with the owner's [`Telemetry::save`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct View {
    pub owner: RobotId,
    pub held: u32,
    pub shown: u32,
    pub digest: u64,
}

/// The package types every radio payload byte is accounted to: the nine of thesis Table 6.1 —
/// the seven op types of the polygon exchange's log ([`Traffic::OPS`]), `conn` (handshakes and
/// chunk headers) and `targ` (targets, coordination) — and `scan` and `cells` for the raw-scans
/// and grid-snapshots baselines — and `mark`, the step frames of lockstep runs ([`Frame`]: its
/// header, the step marker, and each record's kind and length; the simulator's own, not part of
/// any paper's protocol). The op log names its ops' types with it too, so there
/// is one enum for them.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
pub enum Traffic {
    Ins,
    Rep,
    Del,
    Em,
    Chg,
    Rm,
    Conn,
    Targ,
    Save,
    Scan,
    Cells,
    Mark,
    Bid,
    Task,
    Role,
    Move,
}

impl Traffic {
    pub const ALL: [Traffic; 16] = [
        Traffic::Ins,
        Traffic::Rep,
        Traffic::Del,
        Traffic::Em,
        Traffic::Chg,
        Traffic::Rm,
        Traffic::Conn,
        Traffic::Targ,
        Traffic::Save,
        Traffic::Scan,
        Traffic::Cells,
        Traffic::Mark,
        Traffic::Bid,
        Traffic::Task,
        Traffic::Role,
        Traffic::Move,
    ];

    /// The op types of the polygon exchange's log, in Table 6.1 order.
    pub const OPS: [Traffic; 7] = [
        Traffic::Ins,
        Traffic::Rep,
        Traffic::Del,
        Traffic::Em,
        Traffic::Chg,
        Traffic::Rm,
        Traffic::Save,
    ];

    /// Thesis Table 6.1: the size in bytes of one op of this type (`None`: not an op type).
    pub fn thesis_bytes(self) -> Option<f64> {
        match self {
            Traffic::Ins | Traffic::Rep => Some(6.0),
            Traffic::Em | Traffic::Chg => Some(5.0),
            Traffic::Del | Traffic::Rm => Some(2.0),
            Traffic::Save => Some(1.0),
            Traffic::Conn
            | Traffic::Targ
            | Traffic::Scan
            | Traffic::Cells
            | Traffic::Mark
            | Traffic::Bid
            | Traffic::Task
            | Traffic::Role
            | Traffic::Move => None,
        }
    }

    /// The name used in `summary.json` and `traffic_by_type.csv`.
    pub fn name(self) -> &'static str {
        match self {
            Traffic::Ins => "ins",
            Traffic::Rep => "rep",
            Traffic::Del => "del",
            Traffic::Em => "em",
            Traffic::Chg => "chg",
            Traffic::Rm => "rm",
            Traffic::Conn => "conn",
            Traffic::Targ => "targ",
            Traffic::Save => "save",
            Traffic::Scan => "scan",
            Traffic::Cells => "cells",
            Traffic::Mark => "mark",
            Traffic::Bid => "bid",
            Traffic::Task => "task",
            Traffic::Role => "role",
            Traffic::Move => "move",
        }
    }
}

/// netem → robots, when a step opens: the links that are up for it (lockstep with markers). A
/// robot talks to exactly the neighbours whose link is up and not held, and waits for each
/// one's `Mark`.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct LinkPlan {
    pub step: Step,
    /// The links that are up, `a < b`, each once.
    pub links: Vec<PlannedLink>,
}

/// One link that is up in a [`LinkPlan`]'s step: what the robots at its ends must know to use
/// it the way netem will carry it.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct PlannedLink {
    pub a: RobotId,
    pub b: RobotId,
    /// Each direction's rate (bytes per simulated second), `[a → b, b → a]`; `None`: unlimited.
    pub rate: [Option<u64>; 2],
    /// Each direction's latency (with its jitter at the most) in whole steps, `[a → b, b → a]`:
    /// a message sent in step t is acted on in step t + delay.
    pub delay: [u32; 2],
    /// Stalled (a blackhole): the session stays, nothing is sent either way.
    pub held: bool,
    /// Each direction's credit, `[a → b, b → a]`: the bytes netem's budget can still let
    /// through in the step (as netem reckons it from the bytes it carried, see netem's
    /// `Credit`), zenoh's framing included; `None`: unlimited. A robot's pacing estimates the
    /// framing; the credit keeps what it offers within what the link will carry, so that its
    /// step marker is never held back behind its data.
    pub credit: [Option<u32>; 2],
    /// Where robot `a` opens the link's session: netem's proxy of the pair, bound while the
    /// link is up (docs/design.md §1.1); `None` when `a` was given the address at its start.
    pub proxy: Option<SocketAddr>,
}

impl LinkPlan {
    /// The plan of links `(a, b)` with no rate, delay or hold.
    pub fn plain(step: Step, up: &[(RobotId, RobotId)]) -> LinkPlan {
        LinkPlan {
            step,
            links: up
                .iter()
                .map(|&(a, b)| PlannedLink {
                    a: a.min(b),
                    b: a.max(b),
                    ..PlannedLink::default()
                })
                .collect(),
        }
    }

    /// The plan each of `nodes` receives: the links it is an end of, in this plan's order (a
    /// node without a link that is up gets an empty plan). Costs the links plus the nodes.
    pub fn split(&self, nodes: impl IntoIterator<Item = RobotId>) -> BTreeMap<RobotId, LinkPlan> {
        let mut out: BTreeMap<RobotId, LinkPlan> = nodes
            .into_iter()
            .map(|id| {
                (
                    id,
                    LinkPlan {
                        step: self.step,
                        links: Vec::new(),
                    },
                )
            })
            .collect();
        for l in &self.links {
            for end in [l.a, l.b] {
                if let Some(p) = out.get_mut(&end) {
                    p.links.push(*l);
                }
            }
        }
        out
    }

    /// The robots `me` may talk to in the step (up and not held), in id order.
    pub fn neighbours(&self, me: RobotId) -> Vec<RobotId> {
        let mut n: Vec<RobotId> = self
            .links
            .iter()
            .filter(|l| !l.held)
            .filter_map(|l| l.other(me))
            .collect();
        n.sort_unstable();
        n.dedup();
        n
    }

    /// The link between `me` and `peer`, if it is up.
    pub fn link(&self, me: RobotId, peer: RobotId) -> Option<&PlannedLink> {
        self.links.iter().find(|l| l.other(me) == Some(peer))
    }
}

impl PlannedLink {
    /// The robot at the other end from `me`, if `me` is an end (and not both).
    pub fn other(&self, me: RobotId) -> Option<RobotId> {
        match (self.a == me, self.b == me) {
            (true, false) => Some(self.b),
            (false, true) => Some(self.a),
            _ => None,
        }
    }

    /// The index of the direction from `from` (a → b is 0).
    fn dir(&self, from: RobotId) -> usize {
        usize::from(from != self.a)
    }

    /// The rate of the direction from `from`.
    pub fn rate_from(&self, from: RobotId) -> Option<u64> {
        self.rate[self.dir(from)]
    }

    /// The delay of the direction from `from`.
    pub fn delay_from(&self, from: RobotId) -> u32 {
        self.delay[self.dir(from)]
    }

    /// The credit of the direction from `from`.
    pub fn credit_from(&self, from: RobotId) -> Option<u32> {
        self.credit[self.dir(from)]
    }
}

/// Of a link's credit, what a robot leaves for its [`Frame`]: the frame's header (the step
/// marker) with zenoh's framing, and a margin for the framing it does not foresee (sequence
/// numbers grow). On a shared channel netem gives each frame this much on top of its airtime
/// share: the marker is the lockstep protocol's, not the radio's, and costs no airtime.
pub const MARK_RESERVE_BYTES: u32 = 48;

/// Radio, lockstep with step markers: everything `from` sends one neighbour in `step`, as one
/// message, and the end of it (the step marker). zenoh's framing and the marker are paid once per
/// link and step, not once per message. Each record is a radio kind (its index in
/// [`crate::keys::RADIO_KINDS`]) and a payload of that kind, encoded as if sent alone. Once a
/// robot holds a neighbour's frame of a step, it holds everything the neighbour sent it in the
/// step.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct Frame {
    pub from: RobotId,
    pub step: Step,
    pub records: Vec<(u8, Vec<u8>)>,
}

/// netem → launcher, every step: the state of every robot pair's link (docs/design.md §5).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct LinkReport {
    pub step: Step,
    pub links: Vec<LinkState>,
    /// Each live node's use of the radio channel, when netem shares it or loses frames
    /// (`radio.medium` `shared`/`airtime`, `radio.frame_loss`, `radio.fading_db`); else empty.
    pub nodes: Vec<NodeAir>,
}

/// One node's use of the radio channel in a step (docs/guide/radio.md).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct NodeAir {
    pub id: RobotId,
    /// The airtime shares of its links, bytes (0 when the channel is not shared).
    pub share: u64,
    /// The airtime it used: its frames' bytes beyond their headers, and frames it sent again.
    pub airtime: u64,
    /// The airtime of every sender it hears (itself included) over the channel's capacity: how
    /// busy the channel was where it is (0 when the channel is not shared).
    pub utilisation: f32,
    /// Its frames lost in the step (each sent again in the next).
    pub frames_lost: u32,
    /// The bytes of its frames sent again in the step.
    pub retransmitted: u64,
}

/// One link's use of the radio channel in a step, `[a → b, b → a]`.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct LinkAir {
    /// The airtime share of each direction, bytes (`None`: the channel is not shared).
    pub share: [Option<u32>; 2],
    /// The airtime each direction used (its bytes beyond the frame header).
    pub airtime: [u64; 2],
    /// Each direction's frame of the step was lost (and sent again in the next).
    pub lost: [bool; 2],
    /// The probability that each direction's frame is delivered.
    pub delivery: [f32; 2],
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct LinkState {
    pub a: RobotId,
    pub b: RobotId,
    pub up: bool,
    pub distance_m: Option<f64>,
    /// Bytes delivered this step, each way, and in total.
    pub bytes_a_to_b: u64,
    pub bytes_b_to_a: u64,
    pub bytes_total: u64,
    /// Bytes netem holds for the pair (read from a sender, not yet delivered).
    pub queued_bytes: u64,
    /// A connection through netem's proxy for the pair is open at the end of the step (the
    /// robots' radio sessions are connected or handshaking).
    pub connected: bool,
    /// Why the link is down (`up` false), or that it is up but held (a blackhole).
    pub cut: Option<LinkCut>,
    /// Its use of the radio channel, when netem shares it or loses frames; `None` otherwise or
    /// when the link carried nothing in the step.
    pub air: Option<LinkAir>,
}

/// Why a link carries nothing in a step, as netem says.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum LinkCut {
    /// Out of the radio's range (or no poses yet).
    Range,
    /// Cut on purpose: a fault, a partition, `enabled: false` through the API.
    Fault,
    /// A robot of the pair is declared dead.
    Dead,
    /// Up but held: a blackhole (nothing crosses, the sessions stay).
    Blackhole,
}

impl LinkCut {
    pub fn as_str(self) -> &'static str {
        match self {
            LinkCut::Range => "range",
            LinkCut::Fault => "fault",
            LinkCut::Dead => "dead",
            LinkCut::Blackhole => "blackhole",
        }
    }
}

/// Launcher → everyone on `sim/ctl/**`.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub enum Control {
    /// End the run: every process finishes its step and exits 0.
    Stop,
    /// Hold the step clock: the world-server finishes the step it is in and starts no other
    /// until [`Control::Resume`] or [`Control::Step`]; robots wait without timing out.
    Pause,
    /// Let the clock go on.
    Resume,
    /// While paused: one step, then paused again (nothing when the clock runs).
    Step,
}

/// netem → launcher on [`crate::keys::PROCESS_ORDERS`]: a process fault asked for at runtime
/// through netem's API (`POST /processes/<name>`), carried out by the launcher at its next step
/// like a scheduled one ([`crate::process::ProcessAction`], whose TOML form does not fit the
/// wire: this is the same action, externally tagged).
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct ProcessOrder {
    pub process: crate::process::Process,
    pub order: Order,
}

/// What a [`ProcessOrder`] does; see [`crate::process::ProcessAction`].
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum Order {
    Kill { restart_after: Option<u32> },
    Restart,
    Freeze,
    Thaw,
}

impl From<&crate::process::ProcessAction> for ProcessOrder {
    fn from(a: &crate::process::ProcessAction) -> ProcessOrder {
        use crate::process::ProcessAction as A;
        let order = match *a {
            A::Kill { restart_after, .. } => Order::Kill { restart_after },
            A::Restart { .. } => Order::Restart,
            A::Freeze { .. } => Order::Freeze,
            A::Thaw { .. } => Order::Thaw,
        };
        ProcessOrder {
            process: a.process(),
            order,
        }
    }
}

impl From<ProcessOrder> for crate::process::ProcessAction {
    fn from(o: ProcessOrder) -> crate::process::ProcessAction {
        use crate::process::ProcessAction as A;
        let process = o.process;
        match o.order {
            Order::Kill { restart_after } => A::Kill {
                process,
                restart_after,
            },
            Order::Restart => A::Restart { process },
            Order::Freeze => A::Freeze { process },
            Order::Thaw => A::Thaw { process },
        }
    }
}

/// Radio: the knowledge vector {owner → number of log entries held} (thesis `conn`).
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct Hello {
    pub from: RobotId,
    pub knowledge: Vec<(RobotId, u32)>,
    /// `true`: the receiver's belief of what the sender holds becomes exactly this (on link-up,
    /// after a gap, and periodically where messages can be lost); `false`: it only rises to it
    /// (lockstep's periodic handshake, sent while the receiver's traffic of the same step is
    /// on its way and arrives).
    pub reset: bool,
}

/// Radio: how a robot is connected to the writers of the logs it knows of (the relay tree,
/// docs/design.md §4.4), sent to a neighbour when it changes and in full when a link comes up
/// (`conn`). Only what changed since the last `Routes` to that neighbour is listed.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct Routes {
    pub from: RobotId,
    pub routes: Vec<Route>,
}

/// One log owner's entry in [`Routes`]: the sender is `hops` radio hops from the robot that
/// writes `owner`'s log, and takes that log's records from its neighbour `via` (0 hops: it
/// writes the log itself, `via` is the sender). [`Route::NONE`] hops: it knows no way to the
/// writer any more. `have`, when `via` is new: how many records of the log the sender holds,
/// so that the robot it takes the log from now knows where to go on.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct Route {
    pub owner: RobotId,
    pub hops: u8,
    pub via: RobotId,
    pub have: Option<u32>,
}

impl Route {
    /// `hops` of an owner whose writer the sender no longer reaches.
    pub const NONE: u8 = u8::MAX;
}

/// Radio: the target a robot chose (thesis `targ`), sent to the robots in range when it changes
/// and on link-up; `cell` is `None` while the robot has no target. Not relayed.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct Target {
    pub from: RobotId,
    pub step: Step,
    pub cell: Option<Cell>,
}

/// Radio (`burgard` coordination): what a robot knows of the robots it can reach, relayed from
/// neighbour to neighbour so that every member of a sub-team knows the sub-team: each entry is
/// one robot's own report (its step, cell, target and radio neighbours then). Accounted as `targ`.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct Team {
    pub from: RobotId,
    pub entries: Vec<TeamEntry>,
}

#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct TeamEntry {
    pub robot: RobotId,
    pub step: Step,
    pub cell: Cell,
    pub target: Option<Cell>,
    pub neighbours: Vec<RobotId>,
}

/// Radio (`bids`, Simmons et al. 2000): robots' bids on their way to the executive in the base
/// station, relayed by every node (each holds the newest bid of every robot and passes it to the
/// neighbours that lack it). Accounted as `bid`.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct Bids {
    pub from: RobotId,
    pub bids: Vec<Bid>,
}

/// One robot's bid, made at `step`: its best frontier cells.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct Bid {
    pub robot: RobotId,
    pub step: Step,
    pub offers: Vec<Offer>,
}

/// One frontier cell of a bid: its expected information gain (unknown cells), its path cost
/// from the robot (tenths of a cell) and its information-gain region (`igr_min` and the
/// rectangle's width and height − 1, in cells).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct Offer {
    pub cell: Cell,
    pub gain_cells: u32,
    pub cost_decicells: u32,
    pub igr_min: Cell,
    pub igr_extent: (u16, u16),
}

/// Radio (`bids`): the executive's assignment table issued at `step`, relayed from the base
/// station by every node (the newest wins). Accounted as `task`.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct Tasks {
    pub from: RobotId,
    pub step: Step,
    pub tasks: Vec<TaskEntry>,
}

/// One robot's assignment: a frontier cell and its information-gain region (as in [`Offer`]),
/// or `None`: idle (nothing left worth its gain), it stays where it is.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct TaskEntry {
    pub robot: RobotId,
    pub task: Option<(Cell, Cell, (u16, u16))>,
}

/// Radio (`roles`, de Hoog, Cameron & Visser 2010): a robot's place in the team hierarchy, its
/// state and its meeting plans, sent to the robots in range when it changes and every few steps.
/// Not relayed as such; the roster it carries spreads from robot to robot. Accounted as `role`.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct Role {
    pub from: RobotId,
    pub step: Step,
    pub cell: Cell,
    /// Where it is heading (the role swap rule's goal); `None`: nowhere.
    pub goal: Option<Cell>,
    pub state: RoleState,
    /// Where it meets its own parent next: the base station's cell, or the rendezvous agreed with
    /// its parent relay (a child times its next meeting by the trip there and back).
    pub parent_point: Option<Cell>,
    /// A digest of every robot's place as the sender knows it ([`roster_digest`]) ...
    pub roster_digest: u32,
    /// ... and the places themselves, sent only to a robot whose digest differs.
    pub roster: Vec<Seat>,
    /// The sender has nothing more waiting for the addressee on the radio.
    pub caught_up: bool,
    pub swap: Option<Swap>,
}

/// Radio (`pack`, Rooker & Birk 2005): the pack table — every robot's newest report (cell and
/// radio neighbours), its own first, relayed from robot to robot like `burgard`'s sub-team table
/// — and the newest plan of the sender's leader it holds, which reaches the members a hop per
/// step. Accounted as `move`.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct Pack {
    pub from: RobotId,
    pub entries: Vec<TeamEntry>,
    pub plan: Option<Plan>,
}

/// A group leader's moves for the coming steps, made at step `made`.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct Plan {
    pub leader: RobotId,
    pub made: Step,
    /// By step, ascending.
    pub steps: Vec<StepMoves>,
}

/// The configuration change of one step: each member's move from one cell to another (a
/// member not listed stays).
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct StepMoves {
    pub step: Step,
    pub moves: Vec<Move>,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct Move {
    pub robot: RobotId,
    pub from: Cell,
    pub to: Cell,
}

/// A digest of a roster (FNV-1a over its seats in the order given): robots whose digests agree
/// need not send each other their rosters.
pub fn roster_digest(seats: &[Seat]) -> u32 {
    let mut h: u32 = 0x811c_9dc5;
    for s in seats {
        let bytes = [
            s.robot.to_le_bytes(),
            s.place.branch.to_le_bytes(),
            s.place.depth.to_le_bytes(),
        ]
        .concat();
        for b in bytes.into_iter().chain(s.since.to_le_bytes()) {
            h ^= u32::from(b);
            h = h.wrapping_mul(0x0100_0193);
        }
    }
    h
}

/// A place in the hierarchy: branch `branch` below the base station, `depth` hops down it (0: the
/// base station's child). The last place of a branch is its explorer, the others relays.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash, Serialize, Deserialize)]
pub struct Place {
    pub branch: u16,
    pub depth: u16,
}

/// Robot `robot` holds `place` since step `since` (the newest claim of a place wins).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct Seat {
    pub robot: RobotId,
    pub place: Place,
    pub since: Step,
}

/// A meeting agreed between a child and its parent: where (`primary`, else `fallback`), by which
/// step the parent is expected there (`due`), and when the child made the agreement (`made`,
/// its version).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct Rendezvous {
    pub primary: Cell,
    pub fallback: Cell,
    pub due: Step,
    pub made: Step,
}

/// What a robot is doing in its role (de Hoog et al. Fig. 2).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum Phase {
    /// Explorer: going to frontiers.
    Explore,
    /// Explorer: on its way to the rendezvous with its parent.
    Return,
    /// Explorer: at the rendezvous, waiting for its parent.
    Wait,
    /// Either role: the parent (or child) did not come; at or on the way to the fallback point.
    Fallback,
    /// Either role: met its parent, staying until what it carries has crossed.
    Deliver,
    /// Relay: on its way to its parent.
    ToParent,
    /// Relay: on its way to (or waiting at) the rendezvous with its child.
    ToChild,
}

/// A robot's role state — what a role swap hands over.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct RoleState {
    pub place: Place,
    pub phase: Phase,
    /// The step the phase began.
    pub since: Step,
    /// The meeting with its parent (agreed by this robot as the child).
    pub with_parent: Option<Rendezvous>,
    /// The meeting with its child (agreed by the child).
    pub with_child: Option<Rendezvous>,
}

/// The role swap handshake (de Hoog et al. §V): the lower id proposes with its state, the other
/// takes that state and answers with its own, which the proposer then takes. `stamp` is the
/// proposal's step.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum Swap {
    Propose {
        to: RobotId,
        stamp: Step,
        state: RoleState,
    },
    Accept {
        to: RobotId,
        stamp: Step,
        state: RoleState,
    },
}

/// One laser scan as shared on the radio in the `raw-scans` exchange. Ranges are quantized to
/// centimetres (`u16::MAX` = no return) so the baseline is not inflated by float noise.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct ScanRecord {
    pub step: Step,
    /// Pose in millimetres and milliradians.
    pub x_mm: i32,
    pub y_mm: i32,
    pub theta_mrad: i32,
    pub ranges_cm: Vec<u16>,
}

/// Radio: entries `start..start+records.len()` of `owner`'s log, sent by `from` (thesis §5.1.2:
/// the suffix of a log a peer lacks, relayed transitively).
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct LogDelta<R> {
    pub from: RobotId,
    pub owner: RobotId,
    pub start: u32,
    pub records: Vec<R>,
}

/// Radio, `raw-scans` exchange: a run of an owner's scan log.
pub type ScanDelta = LogDelta<ScanRecord>;

/// The encoded size of the largest delta that carries one scan of `beams` beams: the largest
/// message an exchange sends whole (the robots' radio lets one through after quiet steps, and
/// netem lets a direction of a shared channel save up this much airtime).
pub fn largest_scan_delta_bytes(beams: u32) -> usize {
    let worst = ScanDelta {
        from: RobotId::MAX,
        owner: RobotId::MAX,
        start: u32::MAX,
        records: vec![ScanRecord {
            step: Step::MAX,
            x_mm: i32::MIN,
            y_mm: i32::MIN,
            theta_mrad: i32::MIN,
            ranges_cm: vec![u16::MAX; beams as usize],
        }],
    };
    encode(&worst).len()
}

/// The cells of a robot's self-explored grid that one step changed, as shared in the
/// `grid-snapshots` exchange (docs/design.md §4.8): `cells` is a run of varints, each
/// `(index gap) << 2 | state`, the gap counted from the previous changed cell's row-major index
/// plus one (the first from 0), the state 0 unknown, 1 free, 2 occupied.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct GridPatch {
    pub step: Step,
    pub cells: Vec<u8>,
}

/// Radio: a run of an owner's grid patches (the `grid-snapshots` exchange).
pub type PatchDelta = LogDelta<GridPatch>;

/// Radio, `polygon` exchange: ops `start..start+count` of `owner`'s op log, sent by `from`, in
/// the compact op encoding of `robot_agent::exchange::wire` (thesis Table 6.1). With `snapshot`
/// `Some(offset)` the ops are instead ops `offset..offset+count` of a snapshot: the ops that
/// build `owner`'s approximation at log index `start` from nothing, ending with its one save
/// point (a peer far behind on the log gets the state instead of the history).
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct OpChunk {
    pub from: RobotId,
    pub owner: RobotId,
    pub start: u32,
    pub count: u32,
    pub ops: Vec<u8>,
    pub snapshot: Option<u32>,
}

#[derive(Debug, thiserror::Error, PartialEq, Eq)]
pub enum DecodeError {
    #[error("empty payload")]
    Empty,
    #[error("protocol version {got}, this build speaks {PROTOCOL_VERSION}")]
    Version { got: u16 },
    #[error("malformed payload: {0}")]
    Malformed(String),
}

/// Encodes a message with the protocol version in front.
pub fn encode<T: Serialize>(msg: &T) -> Vec<u8> {
    // Serializing our own plain data types into a Vec cannot fail.
    postcard::to_stdvec(&(PROTOCOL_VERSION, msg)).unwrap_or_default()
}

/// Decodes what [`encode`] wrote; total on arbitrary bytes.
pub fn decode<T: DeserializeOwned>(bytes: &[u8]) -> Result<T, DecodeError> {
    if bytes.is_empty() {
        return Err(DecodeError::Empty);
    }
    let (version, rest): (u16, &[u8]) =
        postcard::take_from_bytes(bytes).map_err(|e| DecodeError::Malformed(e.to_string()))?;
    if version != PROTOCOL_VERSION {
        return Err(DecodeError::Version { got: version });
    }
    let (msg, tail): (T, &[u8]) =
        postcard::take_from_bytes(rest).map_err(|e| DecodeError::Malformed(e.to_string()))?;
    if !tail.is_empty() {
        return Err(DecodeError::Malformed(format!(
            "{} trailing bytes",
            tail.len()
        )));
    }
    Ok(msg)
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn round_trip<T: Serialize + DeserializeOwned + PartialEq + std::fmt::Debug>(m: T) {
        let bytes = encode(&m);
        assert_eq!(decode::<T>(&bytes).as_ref(), Ok(&m));
    }

    fn map() -> MapInfo {
        MapInfo {
            width: 3,
            height: 4,
            resolution_m: 0.2,
            origin_x_m: -1.0,
            origin_y_m: 2.0,
        }
    }

    /// `Target` and `TeamEntry` carry [`Cell`]s where they carried `(i32, i32)` pairs; postcard
    /// encodes both alike, so the wire (and [`PROTOCOL_VERSION`]) is unchanged.
    #[test]
    fn a_cell_encodes_like_the_pair_it_replaced() {
        let cell = Cell::new(-3, 120);
        assert_eq!(encode(&cell), encode(&(-3i32, 120i32)));
        assert_eq!(encode(&Some(cell)), encode(&Some((-3i32, 120i32))));
    }

    /// `Cmd.waypoint` and `Telemetry.target` carry [`Metres`] where they carried `(f64, f64)`
    /// pairs; postcard encodes both alike, so the wire (and [`PROTOCOL_VERSION`]) is unchanged.
    #[test]
    fn metres_encode_like_the_pair_they_replaced() {
        let p = Metres::new(1.5, -2.0);
        assert_eq!(encode(&p), encode(&(1.5f64, -2.0f64)));
        assert_eq!(encode(&Some(p)), encode(&Some((1.5f64, -2.0f64))));
        assert_eq!(
            postcard::to_stdvec(&p).ok(),
            postcard::to_stdvec(&(1.5f64, -2.0f64)).ok()
        );
    }

    #[test]
    fn every_message_round_trips() {
        let pose = Pose {
            x: 1.5,
            y: -2.0,
            theta: 0.25,
        };
        round_trip(WorldInfo {
            map: map(),
            laser: LaserSpec {
                beams: 360,
                fov_rad: 1.5,
                max_range_m: 8.0,
                noise_std_m: 0.0,
            },
            step_seconds: 1.0,
            robots: 4,
            max_speed_m_per_s: 0.5,
        });
        round_trip(TruthMap {
            map: map(),
            grid_rle: vec![1, 2, 3],
            reachable_rle: vec![4],
        });
        for last_move in [
            MoveOutcome::Start,
            MoveOutcome::Moved,
            MoveOutcome::Stayed,
            MoveOutcome::Missed,
            MoveOutcome::Blocked,
            MoveOutcome::Collision {
                with: 3,
                at_mm: (-1200, 45_000),
            },
            MoveOutcome::OutOfMap,
            MoveOutcome::WrongStep,
        ] {
            round_trip(Scan {
                step: 7,
                pose,
                ranges: vec![1.0, 8.0],
                last_move,
            });
        }
        round_trip(Cmd {
            step: 3,
            robot: 1,
            waypoint: Some(Metres::new(0.5, 0.5)),
        });
        round_trip(Cmd {
            step: 3,
            robot: 1,
            waypoint: None,
        });
        use crate::process::{Process, ProcessAction};
        for action in [
            ProcessAction::Kill {
                process: Process::Robot(2),
                restart_after: Some(3),
            },
            ProcessAction::Kill {
                process: Process::WorldServer,
                restart_after: None,
            },
            ProcessAction::Restart {
                process: Process::Netem,
            },
            ProcessAction::Freeze {
                process: Process::BaseStation,
            },
            ProcessAction::Thaw {
                process: Process::Robot(0),
            },
        ] {
            let order = ProcessOrder::from(&action);
            round_trip(order.clone());
            assert_eq!(ProcessAction::from(order), action);
        }
        round_trip(Frame {
            from: 3,
            step: 7,
            records: vec![(0, vec![1, 2, 3]), (9, Vec::new())],
        });
        round_trip(LinkPlan {
            step: 4,
            links: vec![
                PlannedLink {
                    a: 0,
                    b: 1,
                    rate: [Some(1000), None],
                    delay: [2, 0],
                    held: false,
                    credit: [Some(11_000), None],
                    proxy: Some(([127, 0, 0, 1], 41234).into()),
                },
                PlannedLink {
                    a: 1,
                    b: 3,
                    rate: [None, None],
                    delay: [0, 0],
                    held: true,
                    credit: [None, None],
                    proxy: None,
                },
            ],
        });
        round_trip(Status {
            step: 9,
            robots: vec![RobotStatus {
                id: 0,
                pose,
                alive: true,
                distance_m: 3.5,
            }],
            collisions_total: 2,
            blocked_total: 5,
            base: Some(RobotStatus {
                id: 1,
                pose,
                alive: true,
                distance_m: 0.0,
            }),
            missed: vec![1],
        });
        round_trip(Telemetry {
            robot: 2,
            step: 5,
            pose,
            target: Some(Metres::new(1.0, 1.0)),
            known_cells: 100,
            bytes_sent: 1000,
            bytes_received: 2000,
            grid: GridReport::Changed {
                since: 4,
                window: Some((Cell::new(3, 1), vec![9, 9])),
            },
            idle: false,
            neighbours: vec![0, 1],
            decode_errors: 0,
            sent_by_type: vec![0, 0, 0, 0, 0, 0, 40, 0, 0, 960],
            logs: vec![(0, 12), (1, 3)],
            approx_error_avg: Some(0.05),
            splits_per_step: Some(1.5),
            backlog_bytes: vec![(0, 300), (1, 0)],
            own: GridReport::Whole(vec![9, 9]),
            save: Some((40, 0xdead_beef)),
            views: vec![View {
                owner: 0,
                held: 12,
                shown: 10,
                digest: 7,
            }],
            alone: true,
            judged: Some(Judged {
                step: 12,
                group: vec![0, 2, 3],
                up: vec![(0, 2), (2, 3)],
            }),
            life: 1,
            log_bytes: vec![(0, 480), (1026, 12)],
        });
        round_trip(Control::Stop);
        round_trip(Control::Pause);
        round_trip(Control::Resume);
        round_trip(Control::Step);
        round_trip(Held {
            robot: 2,
            step: 40,
            owners: vec![HeldApprox {
                owner: 1026,
                held: 12,
                shown: 9,
                polygons: vec![Outline {
                    outside: true,
                    vertices: vec![
                        (6, 10, crate::grid::Occ::Occupied),
                        (-2, 10, crate::grid::Occ::Unknown),
                    ],
                }],
            }],
        });
        round_trip(LinkReport {
            step: 3,
            links: vec![LinkState {
                a: 0,
                b: 2,
                up: true,
                distance_m: Some(4.5),
                bytes_a_to_b: 10,
                bytes_b_to_a: 20,
                bytes_total: 300,
                queued_bytes: 7,
                connected: true,
                cut: Some(LinkCut::Blackhole),
                air: Some(LinkAir {
                    share: [Some(120), None],
                    airtime: [100, 0],
                    lost: [true, false],
                    delivery: [0.75, 0.5],
                }),
            }],
            nodes: vec![NodeAir {
                id: 2,
                share: 120,
                airtime: 140,
                utilisation: 0.5,
                frames_lost: 1,
                retransmitted: 40,
            }],
        });
        round_trip(Hello {
            from: 1,
            knowledge: vec![(0, 5), (1, 7)],
            reset: true,
        });
        round_trip(PatchDelta {
            from: 1,
            owner: 2,
            start: 0,
            records: vec![GridPatch {
                step: 3,
                cells: vec![5, 9, 2],
            }],
        });
        round_trip(Target {
            from: 2,
            step: 40,
            cell: Some(Cell::new(-3, 120)),
        });
        round_trip(Target {
            from: 2,
            step: 41,
            cell: None,
        });
        round_trip(Bids {
            from: 2,
            bids: vec![Bid {
                robot: 1,
                step: 30,
                offers: vec![Offer {
                    cell: Cell::new(3, 4),
                    gain_cells: 120,
                    cost_decicells: 455,
                    igr_min: Cell::new(0, 1),
                    igr_extent: (10, 12),
                }],
            }],
        });
        round_trip(Tasks {
            from: 4,
            step: 31,
            tasks: vec![
                TaskEntry {
                    robot: 0,
                    task: Some((Cell::new(3, 4), Cell::new(0, 1), (10, 12))),
                },
                TaskEntry {
                    robot: 1,
                    task: None,
                },
            ],
        });
        let state = RoleState {
            place: Place {
                branch: 2,
                depth: 1,
            },
            phase: Phase::Fallback,
            since: 40,
            with_parent: Some(Rendezvous {
                primary: Cell::new(5, 6),
                fallback: Cell::new(-1, 2),
                due: 90,
                made: 41,
            }),
            with_child: None,
        };
        round_trip(Role {
            from: 3,
            step: 44,
            cell: Cell::new(7, 8),
            goal: Some(Cell::new(9, 1)),
            state,
            parent_point: Some(Cell::new(0, 0)),
            roster_digest: 7,
            roster: vec![Seat {
                robot: 3,
                place: state.place,
                since: 12,
            }],
            caught_up: true,
            swap: Some(Swap::Accept {
                to: 1,
                stamp: 43,
                state,
            }),
        });
        round_trip(Pack {
            from: 2,
            entries: vec![TeamEntry {
                robot: 0,
                step: 8,
                cell: Cell::new(3, 4),
                target: None,
                neighbours: vec![2],
            }],
            plan: Some(Plan {
                leader: 0,
                made: 8,
                steps: vec![StepMoves {
                    step: 9,
                    moves: vec![Move {
                        robot: 2,
                        from: Cell::new(5, 5),
                        to: Cell::new(7, 5),
                    }],
                }],
            }),
        });
        round_trip(Team {
            from: 1,
            entries: vec![TeamEntry {
                robot: 3,
                step: 9,
                cell: Cell::new(4, -5),
                target: Some(Cell::new(10, 11)),
                neighbours: vec![1, 2],
            }],
        });
        round_trip(ScanDelta {
            from: 1,
            owner: 0,
            start: 4,
            records: vec![ScanRecord {
                step: 4,
                x_mm: -100,
                y_mm: 2000,
                theta_mrad: 1571,
                ranges_cm: vec![0, 800, u16::MAX],
            }],
        });
    }

    #[test]
    fn wrong_version_is_rejected() {
        let bytes = postcard::to_stdvec(&(PROTOCOL_VERSION + 1, Control::Stop)).unwrap_or_default();
        assert_eq!(
            decode::<Control>(&bytes),
            Err(DecodeError::Version {
                got: PROTOCOL_VERSION + 1
            })
        );
        assert_eq!(decode::<Control>(&[]), Err(DecodeError::Empty));
    }

    proptest! {
        #[test]
        fn decoding_arbitrary_bytes_never_panics(bytes in proptest::collection::vec(any::<u8>(), 0..256)) {
            let _ = decode::<Telemetry>(&bytes);
            let _ = decode::<ScanDelta>(&bytes);
            let _ = decode::<PatchDelta>(&bytes);
            let _ = decode::<Hello>(&bytes);
            let _ = decode::<Target>(&bytes);
            let _ = decode::<Team>(&bytes);
            let _ = decode::<Bids>(&bytes);
            let _ = decode::<Tasks>(&bytes);
            let _ = decode::<Role>(&bytes);
            let _ = decode::<Pack>(&bytes);
            let _ = decode::<OpChunk>(&bytes);
            let _ = decode::<Scan>(&bytes);
            let _ = decode::<Status>(&bytes);
            let _ = decode::<Frame>(&bytes);
            let _ = decode::<LinkPlan>(&bytes);
        }
    }
}

#[cfg(test)]
mod link_plan_tests {
    use super::*;

    #[test]
    fn a_plan_names_each_robots_neighbours_in_id_order() {
        let mut p = LinkPlan::plain(0, &[(2, 3), (0, 2), (2, 1), (0, 1)]);
        assert_eq!(p.neighbours(2), [0, 1, 3]);
        assert_eq!(p.neighbours(0), [1, 2]);
        assert!(p.neighbours(4).is_empty());
        assert_eq!(p.link(1, 2).map(|l| (l.a, l.b)), Some((1, 2)));
        assert!(p.link(1, 3).is_none());
        // A held link is up but nobody talks over it.
        p.links[0].held = true;
        assert_eq!(p.neighbours(2), [0, 1]);
        assert!(p.link(3, 2).is_some_and(|l| l.held));
        let l = PlannedLink {
            a: 1,
            b: 4,
            rate: [Some(10), Some(20)],
            delay: [3, 0],
            held: false,
            credit: [Some(100), Some(7)],
            proxy: None,
        };
        assert_eq!((l.rate_from(1), l.delay_from(1)), (Some(10), 3));
        // Split per node: each keeps its own links, in order; a node without one gets none.
        let parts = p.split([0, 2, 4]);
        assert_eq!(parts.keys().copied().collect::<Vec<_>>(), [0, 2, 4]);
        for (&id, part) in &parts {
            assert_eq!(part.step, p.step);
            let mine: Vec<_> = p
                .links
                .iter()
                .filter(|l| l.other(id).is_some())
                .copied()
                .collect();
            assert_eq!(part.links, mine);
            assert_eq!(part.neighbours(id), p.neighbours(id));
        }
        assert!(parts[&4].links.is_empty());
        assert_eq!((l.credit_from(1), l.credit_from(4)), (Some(100), Some(7)));
        assert_eq!((l.rate_from(4), l.delay_from(4)), (Some(20), 0));
    }

    #[test]
    fn log_owners_name_robot_and_life_and_life_zero_is_the_robot() {
        assert_eq!(log_owner(3, 0), Some(3));
        assert_eq!(log_owner(3, 2), Some(3 + 2 * LIFE_STRIDE));
        assert_eq!(owner_life(3 + 2 * LIFE_STRIDE), (3, 2));
        assert_eq!(log_owner(LIFE_STRIDE, 0), None);
        assert_eq!(log_owner(LIFE_STRIDE - 1, MAX_LIVES - 1), Some(u16::MAX));
        assert_eq!(log_owner(0, MAX_LIVES), None);
        for owner in [0, 5, 1023, 1024, 4097, u16::MAX] {
            let (r, l) = owner_life(owner);
            assert_eq!(log_owner(r, l), Some(owner));
        }
    }
}
