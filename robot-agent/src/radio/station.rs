//! The robot's side of the radio: who is in range, what each step sends them within each link's
//! budget, and every byte in and out counted once.
//!
//! * Neighbours: the robots whose radio liveliness token this robot sees ([`Radio::link_up`],
//!   [`Radio::link_down`]).
//! * Pacing: per neighbour, a budget on the simulated clock of the link's bandwidth with bursts
//!   of [`BURST_STEPS`] steps (and at least the largest single-scan delta), kept by
//!   [`crate::radio::pacing::Pacer`]. On average a link is offered no more than its bandwidth, whatever
//!   the robot would like to send, so queues in netem and the kernel stay short and keep-alives
//!   are not stuck behind data. What does not fit waits in the exchange's logs: the backlog.
//! * Accounting: a message is encoded in one place ([`Msg::pack`]), its bytes counted there by
//!   package type, and handed to [`crate::node`] as an [`Outgoing`] (key and bytes). Incoming
//!   bytes come back with their key's kind ([`Radio::receive`]), are counted and decoded here.

use std::collections::{BTreeSet, HashMap};

use proto::geom::LaserSpec;
use proto::grid::Cell;
use proto::msg::{
    decode, encode, DecodeError, Hello, Mark, RobotId, ScanDelta, ScanRecord, Step, Target,
    Traffic, WorldInfo,
};
use proto::scenario::Scenario;

use crate::coord::{Addressed, CoordMsg, To};
use crate::exchange::sharing::{Share, Sharing};
use crate::radio::pacing::Pacer;

/// How many steps of unused radio budget a neighbour's credit can hold. Without step markers
/// netem smooths what a burst offers over the following steps; with them a step's traffic
/// crosses within the step, so after idle steps a link may carry up to this many steps' budget
/// in one (a log entry larger than one step's budget goes whole, and never starves).
pub const BURST_STEPS: usize = 4;

/// What zenoh adds on the wire to one radio message, with batching off (lockstep with step
/// markers): the TCP link's length prefix, the frame and the put headers, the key's id.
/// Measured: a 5-byte step marker is 24 bytes on the wire. With step markers pacing counts it,
/// so that a link's bytes on the wire, not only its payload, stay within its rate (netem lets
/// every step's traffic through, so nothing else would keep the wire rate).
pub const WIRE_OVERHEAD_BYTES: usize = 19;

/// The encoded size of the largest delta that carries one scan of `laser`.
fn largest_delta_bytes(laser: &LaserSpec) -> usize {
    let worst = ScanDelta {
        from: RobotId::MAX,
        owner: RobotId::MAX,
        start: u32::MAX,
        records: vec![ScanRecord {
            step: Step::MAX,
            x_mm: i32::MIN,
            y_mm: i32::MIN,
            theta_mrad: i32::MIN,
            ranges_cm: vec![u16::MAX; laser.beams as usize],
        }],
    };
    encode(&worst).len()
}

/// A link's budget in bytes per step in scenario `s` (`None`: unlimited).
pub fn budget_per_step(s: &Scenario, world: &WorldInfo) -> Option<f64> {
    rate(s).map(|b| b as f64 * world.step_seconds)
}

fn rate(s: &Scenario) -> Option<u64> {
    Some(s.radio.bandwidth_bytes_per_s).filter(|&b| b > 0)
}

/// A message for the radio plane, encoded: `bytes` on key `key`, for robot `to`.
#[derive(Clone, Debug, PartialEq)]
pub struct Outgoing {
    pub to: RobotId,
    pub key: String,
    pub bytes: Vec<u8>,
}

/// A message the radio plane carries.
#[derive(Clone, Debug, PartialEq)]
pub enum Msg {
    /// The knowledge vector (`conn`).
    Hello(Hello),
    /// The robot's target (`targ`), to the robots in range.
    Target(Target),
    /// A coordination strategy's own message.
    Coord(CoordMsg),
    /// What the exchange shares.
    Share(Share),
    /// Lockstep: the end of the sender's traffic of a step.
    Mark(Mark),
}

/// A message encoded once, ready for any addressee.
struct Packet {
    key: fn(RobotId) -> String,
    bytes: Vec<u8>,
    /// Its bytes by package type.
    by_type: Vec<(Traffic, usize)>,
}

impl Msg {
    /// The robot that sent it (as it says).
    pub fn from(&self) -> RobotId {
        match self {
            Msg::Hello(h) => h.from,
            Msg::Target(t) => t.from,
            Msg::Coord(c) => c.from(),
            Msg::Share(s) => s.from(),
            Msg::Mark(m) => m.from,
        }
    }

    /// The one place where a radio message is encoded.
    fn pack(&self) -> Packet {
        let (key, bytes): (fn(RobotId) -> String, _) = match self {
            Msg::Hello(m) => (proto::keys::radio_hello, encode(m)),
            Msg::Target(m) => (proto::keys::radio_targ, encode(m)),
            Msg::Coord(m) => (m.key(), m.encode()),
            Msg::Share(m) => (m.key(), m.encode()),
            Msg::Mark(m) => (proto::keys::radio_mark, encode(m)),
        };
        let n = bytes.len();
        let by_type = match self {
            Msg::Hello(_) => vec![(Traffic::Conn, n)],
            Msg::Target(_) => vec![(Traffic::Targ, n)],
            Msg::Coord(m) => vec![(m.traffic(), n)],
            Msg::Share(m) => m.by_type(n),
            Msg::Mark(_) => vec![(Traffic::Mark, n)],
        };
        Packet {
            key,
            bytes,
            by_type,
        }
    }

    /// Decodes a payload received under key segment `kind` (`None`: a kind this build does not
    /// know).
    fn decode(kind: &str, bytes: &[u8]) -> Option<Result<Msg, DecodeError>> {
        match kind {
            "hello" => Some(decode(bytes).map(Msg::Hello)),
            "targ" => Some(decode(bytes).map(Msg::Target)),
            "mark" => Some(decode(bytes).map(Msg::Mark)),
            _ => CoordMsg::decode(kind, bytes)
                .map(|r| r.map(Msg::Coord))
                .or_else(|| Share::decode(kind, bytes).map(|r| r.map(Msg::Share))),
        }
    }
}

/// What the radio counted so far.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Counters {
    pub bytes_sent: u64,
    pub bytes_received: u64,
    /// Payloads that did not decode, or could not be taken.
    pub decode_errors: u64,
    /// Payload bytes sent per package type ([`Traffic::ALL`] order).
    pub sent_by_type: [u64; Traffic::ALL.len()],
}

/// One robot's radio.
pub struct Radio {
    id: RobotId,
    hello_every_steps: u32,
    neighbours: BTreeSet<RobotId>,
    pacer: Pacer,
    /// Per neighbour, the bytes that waited for it after the last step's sending.
    backlog: Vec<(RobotId, u64)>,
    /// The target last announced to the robots in range (`None`: none announced yet).
    announced: Option<Option<Cell>>,
    counters: Counters,
    /// Bytes of framing a message costs its link besides its payload (see [`Radio::send`]).
    overhead: usize,
    /// An undecodable payload was logged already.
    logged_bad: bool,
    /// Lockstep: per neighbour, what netem's budget can carry in this step (the plan's credit).
    credit: HashMap<RobotId, u32>,
    /// Radio nodes of the run (robots and the base station): the most owners a step's shares
    /// can carry logs of.
    nodes: usize,
}

/// Of a link's credit, what a robot leaves for its step marker (a marker with zenoh's framing
/// and a margin for the framing it does not foresee).
pub const MARK_RESERVE_BYTES: u32 = 48;

/// zenoh's framing of one message of `len` payload bytes at the most, as the credit reckons it:
/// [`WIRE_OVERHEAD_BYTES`] and a margin (sequence numbers grow), plus [`fragments_framing`]
/// (measured: a 600-byte scan costs 29 bytes of framing over two fragments, a 5-byte marker 19).
fn framing_at_most(len: usize) -> usize {
    WIRE_OVERHEAD_BYTES + 8 + fragments_framing(len)
}

/// One more frame header for every further batch a message of `len` bytes is fragmented over.
fn fragments_framing(len: usize) -> usize {
    16 * (len / (proto::node::RADIO_BATCH_BYTES as usize - 32))
}

/// Of `room` bytes on the wire, the payload `messages` messages may carry at the most.
fn payload_within(room: usize, messages: usize) -> usize {
    room.saturating_sub(messages * framing_at_most(0) + fragments_framing(room))
}

impl Radio {
    /// Robot `id`'s radio in scenario `s` and `world`.
    pub fn new(id: RobotId, s: &Scenario, world: &WorldInfo) -> Radio {
        let burst_bytes = budget_per_step(s, world)
            .map_or(0, |b| (b * BURST_STEPS as f64) as u64)
            .max(largest_delta_bytes(&world.laser) as u64);
        Radio {
            id,
            hello_every_steps: s.exchange.hello_every_steps,
            neighbours: BTreeSet::new(),
            pacer: Pacer::new(rate(s), burst_bytes, world.step_seconds),
            backlog: Vec::new(),
            announced: None,
            counters: Counters::default(),
            overhead: if s.clock.marked() {
                WIRE_OVERHEAD_BYTES
            } else {
                0
            },
            logged_bad: false,
            credit: HashMap::new(),
            nodes: usize::from(s.robots.count) + usize::from(s.base_id().is_some()),
        }
    }

    pub fn neighbours(&self) -> &BTreeSet<RobotId> {
        &self.neighbours
    }

    pub fn counters(&self) -> &Counters {
        &self.counters
    }

    /// Per neighbour, the bytes that waited for it after the last step's sending.
    pub fn backlog(&self) -> &[(RobotId, u64)] {
        &self.backlog
    }

    /// Hands packet `p` to robot `to`, counting its bytes; returns how many.
    /// Encodes one message for `to`; returns what it costs the link: its payload, and with step
    /// markers zenoh's framing ([`WIRE_OVERHEAD_BYTES`]).
    fn send(&mut self, to: RobotId, p: &Packet, out: &mut Vec<Outgoing>) -> usize {
        let c = &mut self.counters;
        c.bytes_sent += p.bytes.len() as u64;
        for &(t, n) in &p.by_type {
            c.sent_by_type[t as usize] += n as u64;
        }
        out.push(Outgoing {
            to,
            key: (p.key)(to),
            bytes: p.bytes.clone(),
        });
        p.bytes.len() + self.overhead
    }

    /// Sends one message to one robot, outside any budget.
    pub fn send_one(&mut self, to: RobotId, msg: &Msg) -> Vec<Outgoing> {
        let mut out = Vec::new();
        self.send(to, &msg.pack(), &mut out);
        out
    }

    /// Sends one message to one robot whatever the budget, and takes it off the budget (a step
    /// marker: the link must carry it too).
    pub fn send_paced(&mut self, to: RobotId, msg: &Msg) -> Vec<Outgoing> {
        let mut out = Vec::new();
        let cost = self.send(to, &msg.pack(), &mut out);
        self.pacer.spend(to, cost);
        out
    }

    fn target_msg(&self, step: Step, target: Option<Cell>) -> Msg {
        Msg::Target(Target {
            from: self.id,
            step,
            cell: target,
        })
    }

    /// A peer's radio liveliness token appeared: greet it with our knowledge vector and target
    /// (at `step`, if one was announced).
    pub fn link_up(
        &mut self,
        peer: RobotId,
        sharing: &mut dyn Sharing,
        step: Step,
        target: Option<Cell>,
    ) -> Vec<Outgoing> {
        if peer == self.id || !self.neighbours.insert(peer) {
            return Vec::new();
        }
        sharing.link_up(peer);
        let mut out = self.send_one(peer, &Msg::Hello(sharing.knowledge()));
        if self.announced.is_some() {
            let targ = self.target_msg(step, target);
            out.extend(self.send_one(peer, &targ));
        }
        out
    }

    /// The link to `peer` carries `rate` bytes per simulated second (lockstep: the step's plan;
    /// `None`: the scenario's bandwidth).
    pub fn set_rate(&mut self, peer: RobotId, rate: Option<u64>) {
        match rate {
            Some(r) => self.pacer.set_rate(peer, Some(r)),
            None => self.pacer.default_rate(peer),
        }
    }

    /// Lockstep: in this step netem can carry `credit` bytes to `peer` (the plan; `None`:
    /// unlimited). What the robot offers beyond its messages outside the budget stays within it,
    /// less room for the step marker.
    pub fn set_credit(&mut self, peer: RobotId, credit: Option<u32>) {
        match credit {
            Some(c) => self.credit.insert(peer, c),
            None => self.credit.remove(&peer),
        };
    }

    pub fn link_down(&mut self, peer: RobotId, sharing: &mut dyn Sharing) {
        self.credit.remove(&peer);
        self.pacer.forget(peer);
        if self.neighbours.remove(&peer) {
            sharing.link_down(peer);
        }
    }

    /// Messages to send after step `step`'s decision (`target`): the strategy's messages
    /// `coord`, the target when it changed, periodic handshakes, and the log suffixes each
    /// neighbour lacks, within the per-link budget.
    pub fn step(
        &mut self,
        step: Step,
        target: Option<Cell>,
        coord: &[Addressed],
        sharing: &mut dyn Sharing,
    ) -> Vec<Outgoing> {
        let mut out = Vec::new();
        let peers: Vec<RobotId> = self.neighbours.iter().copied().collect();
        self.pacer.at_step(step);
        let hello = step
            .is_multiple_of(self.hello_every_steps)
            .then(|| Msg::Hello(sharing.knowledge()).pack());
        let targ = (self.announced != Some(target)).then(|| self.target_msg(step, target).pack());
        self.announced = Some(target);
        let coord: Vec<(&To, Packet)> = coord
            .iter()
            .map(|a| (&a.to, Msg::Coord(a.msg.clone()).pack()))
            .collect();
        for &peer in &peers {
            let mine: Vec<&Packet> = coord
                .iter()
                .filter(|(to, _)| matches!(to, To::Neighbours) || **to == To::Robot(peer))
                .map(|(_, p)| p)
                .collect();
            if hello.is_none() && targ.is_none() && mine.is_empty() && !sharing.has_pending(peer) {
                continue;
            }
            let budget = self.pacer.available(peer);
            // netem's credit, on the wire: what is left after the marker and the messages
            // outside the budget, with their framing at the most.
            let mut room = self
                .credit
                .get(&peer)
                .map(|&c| (c.saturating_sub(MARK_RESERVE_BYTES)) as usize);
            let mut spent = 0usize;
            for p in mine.into_iter().chain(&targ).chain(&hello) {
                spent += self.send(peer, p, &mut out);
                room =
                    room.map(|r| r.saturating_sub(p.bytes.len() + framing_at_most(p.bytes.len())));
            }
            // Shares: one message per log owner (a run's nodes, restarted lives aside).
            let shares_room = room.map_or(usize::MAX, |r| payload_within(r, self.nodes));
            for share in sharing.outgoing(peer, budget.saturating_sub(spent).min(shares_room)) {
                spent += self.send(peer, &Msg::Share(share).pack(), &mut out);
            }
            self.pacer.spend(peer, spent);
        }
        self.backlog = peers
            .iter()
            .filter_map(|&p| Some((p, sharing.backlog_bytes(p)?)))
            .collect();
        sharing.after_sending(self.backlog.iter().map(|&(_, b)| b).max());
        out
    }

    /// Takes a payload received under key segment `kind`: counts it and decodes it. One that
    /// does not decode counts as a decode error (the first one is logged) and yields nothing;
    /// so does one of a kind this build does not know.
    pub fn receive(&mut self, kind: &str, bytes: &[u8]) -> Option<Msg> {
        self.counters.bytes_received += bytes.len() as u64;
        match Msg::decode(kind, bytes) {
            Some(Ok(m)) => Some(m),
            Some(Err(e)) => {
                self.counters.decode_errors += 1;
                if !self.logged_bad {
                    self.logged_bad = true;
                    tracing::warn!("undecodable radio payload: {e}");
                }
                None
            }
            None => {
                self.counters.decode_errors += 1;
                None
            }
        }
    }

    /// A received message could not be taken: it counts as a decode error.
    pub fn refused(&mut self) {
        self.counters.decode_errors += 1;
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proto::geom::MapInfo;

    fn world() -> (Scenario, WorldInfo) {
        let s = Scenario::default();
        let world = WorldInfo {
            map: MapInfo::at_origin(20, 20, 0.2),
            laser: s.laser(),
            step_seconds: s.clock.step_seconds,
            robots: 2,
            max_speed_m_per_s: s.robots.speed_m_per_s,
        };
        (s, world)
    }

    #[test]
    fn every_byte_sent_is_counted_once_by_package_type() {
        let (s, world) = world();
        let mut radio = Radio::new(0, &s, &world);
        let mut sharing = crate::exchange::sharing::new(&s, 0, 0, &world, None);
        let mut out = radio.link_up(1, sharing.as_mut(), 0, None);
        out.extend(radio.step(0, Some(Cell::new(3, 4)), &[], sharing.as_mut()));
        let sent: usize = out.iter().map(|o| o.bytes.len()).sum();
        let c = radio.counters();
        assert_eq!(c.bytes_sent, sent as u64);
        assert_eq!(c.sent_by_type.iter().sum::<u64>(), sent as u64);
        let targ: usize = out
            .iter()
            .filter(|o| proto::keys::radio_kind(&o.key) == Some("targ"))
            .map(|o| o.bytes.len())
            .sum();
        assert!(targ > 0);
        assert_eq!(c.sent_by_type[Traffic::Targ as usize], targ as u64);
        assert!(out.iter().all(|o| o.to == 1));
    }

    use proto::grid::Grid;
    use proto::msg::Scan;

    /// A real sharing that records the budget it is offered and always has something pending.
    struct Recording {
        inner: Box<dyn Sharing>,
        budgets: Vec<usize>,
    }

    impl Sharing for Recording {
        fn after_scan(&mut self, scan: &Scan, laser: &LaserSpec, own: &Grid, changed: &[Cell]) {
            self.inner.after_scan(scan, laser, own, changed)
        }
        fn handshake(&self) -> &dyn crate::exchange::transitive::Handshake {
            self.inner.handshake()
        }
        fn handshake_mut(&mut self) -> &mut dyn crate::exchange::transitive::Handshake {
            self.inner.handshake_mut()
        }
        fn outgoing(&mut self, _peer: RobotId, budget: usize) -> Vec<Share> {
            self.budgets.push(budget);
            Vec::new()
        }
        fn on_share(
            &mut self,
            s: &Share,
            map: &MapInfo,
            laser: &LaserSpec,
        ) -> Result<bool, String> {
            self.inner.on_share(s, map, laser)
        }
        fn planning_grid_into(&self, own: &Grid, out: &mut Grid) {
            self.inner.planning_grid_into(own, out)
        }
        fn backlog_bytes(&self, _peer: RobotId) -> Option<u64> {
            Some(1_000_000)
        }
        fn has_pending(&self, _peer: RobotId) -> bool {
            true
        }
    }

    #[test]
    fn framing_is_reckoned_per_message_and_per_fragment() {
        assert_eq!(framing_at_most(5), WIRE_OVERHEAD_BYTES + 8);
        // The measured 29 bytes of a two-fragment scan are covered.
        assert!(framing_at_most(604) >= 29);
        assert_eq!(payload_within(100, 1), 100 - framing_at_most(0));
        assert!(payload_within(1000, 2) + 2 * framing_at_most(0) + 32 <= 1000);
        assert_eq!(payload_within(10, 1), 0);
    }

    #[test]
    fn a_links_credit_caps_what_is_offered_and_leaves_room_for_the_marker() {
        let (mut s, world) = world();
        s.radio.bandwidth_bytes_per_s = 1000;
        let mut radio = Radio::new(0, &s, &world);
        let mut sharing = Recording {
            inner: crate::exchange::sharing::new(&s, 0, 0, &world, None),
            budgets: Vec::new(),
        };
        radio.link_up(1, &mut sharing, 0, None);
        radio.step(1, None, &[], &mut sharing);
        let own = sharing.budgets.pop().expect("offered");
        assert!(own > 200, "the pacer's own budget: {own}");
        radio.set_credit(1, Some(150));
        radio.step(2, None, &[], &mut sharing);
        let capped = sharing.budgets.pop().expect("offered");
        assert!(
            capped <= payload_within(150 - MARK_RESERVE_BYTES as usize, 2),
            "{capped}"
        );
        assert!(capped < 150 - MARK_RESERVE_BYTES as usize - 2 * WIRE_OVERHEAD_BYTES);
        radio.set_credit(1, Some(10));
        radio.step(3, None, &[], &mut sharing);
        assert_eq!(sharing.budgets.pop(), Some(0));
        radio.set_credit(1, None);
        radio.step(4, None, &[], &mut sharing);
        assert!(sharing.budgets.pop().is_some_and(|b| b > 150));
    }

    #[test]
    fn received_bytes_are_decoded_by_kind_and_bad_ones_counted() {
        let (s, world) = world();
        let mut radio = Radio::new(1, &s, &world);
        let t = Target {
            from: 0,
            step: 7,
            cell: Some(Cell::new(1, 2)),
        };
        let bytes = encode(&t);
        assert_eq!(radio.receive("targ", &bytes), Some(Msg::Target(t)));
        // The same bytes under another kind do not decode; an unknown kind is refused.
        assert_eq!(radio.receive("hello", &bytes), None);
        assert_eq!(radio.receive("nonsense", &bytes), None);
        let c = radio.counters();
        assert_eq!(c.bytes_received, 3 * bytes.len() as u64);
        assert_eq!(c.decode_errors, 2);
    }
}
