//! The robot's side of the radio: who is in range, what each step sends them within each link's
//! budget, and every byte in and out counted once.
//!
//! * Neighbours: the robots whose radio liveliness token this robot sees
//!   ([`Radio::link_up`](crate::radio::station::Radio::link_up),
//!   [`Radio::link_down`](crate::radio::station::Radio::link_down)).
//! * Pacing: per neighbour, a budget on the simulated clock of the link's bandwidth with bursts of
//!   [`proto::budget::SAVE_STEPS`] steps (and at least the largest single-scan delta), kept by
//!   [`crate::radio::pacing::Pacer`]. On average a link is offered no more than its bandwidth,
//!   whatever the robot would like to send, so queues in netem and the kernel stay short and
//!   keep-alives are not stuck behind data. What does not fit waits in the exchange's logs: the
//!   backlog.
//! * Accounting: a message is encoded in one place
//!   ([`Msg::pack`](crate::radio::station::Msg::pack)), its bytes counted by package type, and
//!   handed to [`crate::node`] as an [`Outgoing`](crate::radio::station::Outgoing) (key and bytes).
//!   Incoming bytes come back with their key's kind
//!   ([`Radio::receive`](crate::radio::station::Radio::receive)), are counted and decoded here.
//! * Frames (lockstep with step markers): a step's messages to one neighbour wait in the radio and
//!   leave as one [`Frame`](proto::msg::Frame) with the step marker
//!   ([`Radio::frames`](crate::radio::station::Radio::frames)), so zenoh's framing and the marker
//!   are paid once per link and step; a frame received is unpacked into its messages and its
//!   [`Mark`](crate::radio::station::Mark).

use std::collections::{BTreeSet, HashMap};

use proto::grid::Cell;
use proto::keys::RADIO_KINDS;
use proto::msg::{
    decode, encode, DecodeError, Frame, Hello, RobotId, Routes, Step, Target, Traffic, WorldInfo,
};
use proto::scenario::Scenario;

use crate::coord::{Addressed, CoordMsg, To};
use crate::exchange::sharing::{Share, Sharing};
use crate::radio::pacing::Pacer;

/// What zenoh adds on the wire to one radio message, with batching off (lockstep with step
/// markers): the TCP link's length prefix, the transport frame with its sequence number, the
/// push with its key's declared id and QoS, the put's header and length. Measured: an empty
/// [`Frame`] (5 bytes) to `radio/1` is 17–18 bytes on the wire with zenoh's default 32-bit
/// sequence numbers, and a frame 3.2 bytes less with the 8-bit ones lockstep radio sessions
/// use (`proto::node`); pacing reckons it as this constant plus the key's length (13 for
/// `radio/1`; the key's string itself crosses once per session, when zenoh declares it), a
/// little more than it is. With step markers pacing counts it once per link and
/// step, so that a link's bytes on the wire, not only its payload, stay within its rate (netem
/// lets every step's traffic through, so nothing else would keep the wire rate).
pub const WIRE_OVERHEAD_BYTES: usize = 6;

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
    /// The relay tree's routes (`conn`).
    Routes(Routes),
}

/// A message encoded once, ready for any addressee.
#[derive(Clone)]
struct Packet {
    key: fn(RobotId) -> String,
    /// Its key's kind, as a frame's record names it (its index in [`RADIO_KINDS`]).
    kind: u8,
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
            Msg::Routes(r) => r.from,
        }
    }

    /// The one place where a radio message is encoded.
    fn pack(&self) -> Packet {
        let (key, bytes): (fn(RobotId) -> String, _) = match self {
            Msg::Hello(m) => (proto::keys::radio_hello, encode(m)),
            Msg::Target(m) => (proto::keys::radio_targ, encode(m)),
            Msg::Coord(m) => (m.key(), m.encode()),
            Msg::Share(m) => (m.key(), m.encode()),
            Msg::Routes(m) => (proto::keys::radio_route, encode(m)),
        };
        let n = bytes.len();
        let by_type = match self {
            Msg::Hello(_) | Msg::Routes(_) => vec![(Traffic::Conn, n)],
            Msg::Target(_) => vec![(Traffic::Targ, n)],
            Msg::Coord(m) => vec![(m.traffic(), n)],
            Msg::Share(m) => m.by_type(n),
        };
        let kind = proto::keys::radio_kind(&key(0))
            .and_then(|k| RADIO_KINDS.iter().position(|&r| r == k))
            .and_then(|i| u8::try_from(i).ok())
            .unwrap_or(u8::MAX);
        Packet {
            key,
            kind,
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
            "route" => Some(decode(bytes).map(Msg::Routes)),
            _ => CoordMsg::decode(kind, bytes)
                .map(|r| r.map(Msg::Coord))
                .or_else(|| Share::decode(kind, bytes).map(|r| r.map(Msg::Share))),
        }
    }
}

/// The end of a neighbour's traffic of a step, as its frame says: `from` sent `sent` messages
/// in `step` (the frame's that decoded). Once a robot holds a neighbour's mark of a step and
/// that many of its messages, it holds everything the neighbour sent it in the step.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Mark {
    pub from: RobotId,
    pub step: Step,
    pub sent: u32,
}

/// What one radio payload held: its messages, and for a step's frame its end (lockstep).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Received {
    pub msgs: Vec<Msg>,
    pub end: Option<Mark>,
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
    /// Lockstep with step markers: a step's messages leave in one [`Frame`] per neighbour.
    framed: bool,
    /// Framed: per addressee, the messages of this step waiting for its frame, in the order
    /// sent.
    queued: HashMap<RobotId, Vec<Packet>>,
    /// An undecodable payload was logged already.
    logged_bad: bool,
    /// Lockstep: per neighbour, what netem's budget can carry in this step (the plan's credit).
    credit: HashMap<RobotId, u32>,
    /// Radio nodes of the run (robots and the base station): the most owners a step's shares
    /// can carry logs of.
    nodes: usize,
}

pub use proto::msg::MARK_RESERVE_BYTES;

/// What a frame adds to a message of `len` bytes it carries: the kind's index and the length
/// (a varint).
fn record_overhead(len: usize) -> usize {
    1 + varint_len(len)
}

/// [`record_overhead`] of any message a frame of a link's credit can carry.
const RECORD_AT_MOST: usize = 4;

fn varint_len(mut v: usize) -> usize {
    let mut n = 1;
    while v >= 0x80 {
        v >>= 7;
        n += 1;
    }
    n
}

/// One more frame header for every further batch a frame of `len` bytes is fragmented over
/// (measured with 512-byte batches: a 600-byte message costs 29 bytes of framing over two
/// fragments, a 5-byte one 19).
fn fragments_framing(len: usize) -> usize {
    16 * (len / (proto::node::LOCKSTEP_RADIO_BATCH_BYTES as usize - 32))
}

/// Of `room` bytes in a frame, the payload `messages` messages may carry at the most.
fn payload_within(room: usize, messages: usize) -> usize {
    room.saturating_sub(messages * RECORD_AT_MOST)
}

impl Radio {
    /// Robot `id`'s radio in scenario `s` and `world`.
    pub fn new(id: RobotId, s: &Scenario, world: &WorldInfo) -> Radio {
        let burst_bytes = budget_per_step(s, world)
            .map_or(0, |b| (b * f64::from(proto::budget::SAVE_STEPS)) as u64)
            .max(proto::msg::largest_scan_delta_bytes(world.laser.beams) as u64);
        Radio {
            id,
            hello_every_steps: s.exchange.hello_every_steps,
            neighbours: BTreeSet::new(),
            pacer: Pacer::new(rate(s), burst_bytes, world.step_seconds),
            backlog: Vec::new(),
            announced: None,
            counters: Counters::default(),
            framed: s.clock.marked(),
            queued: HashMap::new(),
            logged_bad: false,
            credit: HashMap::new(),
            nodes: usize::from(s.robots.count) + usize::from(s.base_id().is_some()),
        }
    }

    /// Whether a message can be lost while its link is up (unframed: a put made before the
    /// peer's interest in it reached us, a realtime put dropped under congestion). Framed,
    /// nothing is.
    pub fn lossy(&self) -> bool {
        !self.framed
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

    /// Hands packet `p` to robot `to` (framed: queues it for the step's frame to `to`); returns
    /// what it costs the link: its payload, and framed its record in the frame (the frame's
    /// own cost is taken by [`Radio::frames`]).
    fn send(&mut self, to: RobotId, p: &Packet, out: &mut Vec<Outgoing>) -> usize {
        if self.framed {
            self.queued.entry(to).or_default().push(p.clone());
            return p.bytes.len() + record_overhead(p.bytes.len());
        }
        self.count(p);
        out.push(Outgoing {
            to,
            key: (p.key)(to),
            bytes: p.bytes.clone(),
        });
        p.bytes.len()
    }

    /// What the messages queued for `peer`'s frame take in it.
    fn queued_cost(&self, peer: RobotId) -> usize {
        self.queued.get(&peer).map_or(0, |q| {
            q.iter()
                .map(|p| p.bytes.len() + record_overhead(p.bytes.len()))
                .sum()
        })
    }

    /// Counts packet `p` as sent, by package type.
    fn count(&mut self, p: &Packet) {
        let c = &mut self.counters;
        c.bytes_sent += p.bytes.len() as u64;
        for &(t, n) in &p.by_type {
            c.sent_by_type[t as usize] += n as u64;
        }
    }

    /// Framed (lockstep with step markers): this step's frame to every neighbour — the
    /// messages queued for it, in the order sent, and the step marker — counted (the frame's
    /// own bytes as `mark`), with its framing taken off the link's budget. A frame never
    /// exceeds netem's credit for the link: netem would hold the rest of it, and with it the
    /// marker, until a step that cannot begin before the marker arrives. Messages beyond the
    /// credit stay queued, in order, for the next step's frame (the header always goes).
    /// Messages queued for a robot that is no longer a neighbour are dropped uncounted: nothing
    /// carries them. Unframed: nothing.
    pub fn frames(&mut self, step: Step) -> Vec<Outgoing> {
        if !self.framed {
            return Vec::new();
        }
        let mut queued = std::mem::take(&mut self.queued);
        let peers: Vec<RobotId> = self.neighbours.iter().copied().collect();
        let mut out = Vec::with_capacity(peers.len());
        for peer in peers {
            let key = proto::keys::radio_frame(peer);
            let mut packets = queued.remove(&peer).unwrap_or_default();
            if let Some(&credit) = self.credit.get(&peer) {
                let credit = credit as usize;
                let limit = credit.saturating_sub(
                    WIRE_OVERHEAD_BYTES + key.len() + 8 + fragments_framing(credit),
                );
                let empty = Frame {
                    from: self.id,
                    step,
                    records: Vec::new(),
                };
                // The header, and a record count that may take two bytes more.
                let mut size = encode(&empty).len() + 2;
                let fit = packets
                    .iter()
                    .take_while(|p| {
                        size += p.bytes.len() + record_overhead(p.bytes.len());
                        size <= limit
                    })
                    .count();
                let later = packets.split_off(fit);
                if !later.is_empty() {
                    self.queued.insert(peer, later);
                }
            }
            // The records were paid for when offered; the frame pays its header and framing.
            let (mut inner, mut carried) = (0, 0);
            for p in &packets {
                self.count(p);
                inner += p.bytes.len();
                carried += p.bytes.len() + record_overhead(p.bytes.len());
            }
            let frame = Frame {
                from: self.id,
                step,
                records: packets.into_iter().map(|p| (p.kind, p.bytes)).collect(),
            };
            let bytes = encode(&frame);
            let own = bytes.len() - inner;
            let c = &mut self.counters;
            c.bytes_sent += own as u64;
            c.sent_by_type[Traffic::Mark as usize] += own as u64;
            let framing = WIRE_OVERHEAD_BYTES + key.len();
            self.pacer.spend(peer, bytes.len() - carried + framing);
            out.push(Outgoing {
                to: peer,
                key,
                bytes,
            });
        }
        out
    }

    /// Sends one message to one robot, outside any budget.
    pub fn send_one(&mut self, to: RobotId, msg: &Msg) -> Vec<Outgoing> {
        let mut out = Vec::new();
        self.send(to, &msg.pack(), &mut out);
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
        self.queued.remove(&peer);
        self.pacer.forget(peer);
        if self.neighbours.remove(&peer) {
            sharing.link_down(peer);
        }
    }

    /// Messages to send after step `step`'s decision (`target`): the strategy's messages
    /// `coord`, the relay tree's `routes` per neighbour, the target when it changed, periodic
    /// handshakes, and the log suffixes each neighbour lacks, within the per-link budget.
    pub fn step(
        &mut self,
        step: Step,
        target: Option<Cell>,
        coord: &[Addressed],
        routes: &[(RobotId, Routes)],
        sharing: &mut dyn Sharing,
    ) -> Vec<Outgoing> {
        let mut out = Vec::new();
        let peers: Vec<RobotId> = self.neighbours.iter().copied().collect();
        self.pacer.at_step(step);
        // Framed, nothing is lost while a link is up, and what we sent in the step the peer's
        // handshake was made in arrives with it: the periodic handshake only raises what we
        // believe the peer holds (reset, it would undo that step's sending, which then went
        // again).
        let hello = step.is_multiple_of(self.hello_every_steps).then(|| {
            let mut h = sharing.knowledge();
            h.reset = self.lossy();
            Msg::Hello(h).pack()
        });
        let targ = (self.announced != Some(target)).then(|| self.target_msg(step, target).pack());
        self.announced = Some(target);
        let coord: Vec<(&To, Packet)> = coord
            .iter()
            .map(|a| (&a.to, Msg::Coord(a.msg.clone()).pack()))
            .collect();
        let routes: Vec<(RobotId, Packet)> = routes
            .iter()
            .map(|(to, r)| (*to, Msg::Routes(r.clone()).pack()))
            .collect();
        for &peer in &peers {
            let mine: Vec<&Packet> = coord
                .iter()
                .filter(|(to, _)| matches!(to, To::Neighbours) || **to == To::Robot(peer))
                .map(|(_, p)| p)
                .chain(routes.iter().filter(|(to, _)| *to == peer).map(|(_, p)| p))
                .collect();
            if hello.is_none() && targ.is_none() && mine.is_empty() && !sharing.has_pending(peer) {
                continue;
            }
            let budget = self.pacer.available(peer);
            // netem's credit, on the wire: what is left after the frame's header and zenoh's
            // framing of it (every fragment's), what waits for the frame already (answers,
            // greetings, what the last frame could not carry) and the messages outside the
            // budget.
            let waiting = self.queued_cost(peer);
            let mut room = self.credit.get(&peer).map(|&c| {
                (c.saturating_sub(MARK_RESERVE_BYTES) as usize)
                    .saturating_sub(fragments_framing(c as usize))
                    .saturating_sub(waiting)
            });
            let mut spent = 0usize;
            for p in mine.into_iter().chain(&targ).chain(&hello) {
                let cost = self.send(peer, p, &mut out);
                spent += cost;
                room = room.map(|r| r.saturating_sub(cost));
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

    /// Takes a payload received under key segment `kind`: counts it and decodes it; a frame
    /// into its messages and its marker, which counts the messages that decoded. A payload or
    /// record that does not decode counts as a decode error (the first one is logged) and
    /// yields nothing; so does one of a kind this build does not know, and a record that says
    /// it comes from another robot than its frame.
    pub fn receive(&mut self, kind: &str, bytes: &[u8]) -> Received {
        self.counters.bytes_received += bytes.len() as u64;
        if kind != "frame" {
            return Received {
                msgs: self.decoded(kind, bytes).into_iter().collect(),
                end: None,
            };
        }
        let frame: Frame = match decode(bytes) {
            Ok(f) => f,
            Err(e) => {
                self.bad(&e);
                return Received::default();
            }
        };
        let mut msgs = Vec::with_capacity(frame.records.len());
        for (k, payload) in &frame.records {
            let kind = RADIO_KINDS.get(usize::from(*k)).filter(|&&k| k != "frame");
            match kind.and_then(|k| self.decoded(k, payload)) {
                Some(m) if m.from() == frame.from => msgs.push(m),
                Some(_) => self.counters.decode_errors += 1,
                None if kind.is_none() => self.counters.decode_errors += 1,
                None => {}
            }
        }
        let end = Mark {
            from: frame.from,
            step: frame.step,
            sent: u32::try_from(msgs.len()).unwrap_or(u32::MAX),
        };
        Received {
            msgs,
            end: Some(end),
        }
    }

    /// Decodes one message of `kind` (`None`: it did not decode, counted as a decode error).
    fn decoded(&mut self, kind: &str, bytes: &[u8]) -> Option<Msg> {
        match Msg::decode(kind, bytes) {
            Some(Ok(m)) => Some(m),
            Some(Err(e)) => {
                self.bad(&e);
                None
            }
            None => {
                self.counters.decode_errors += 1;
                None
            }
        }
    }

    /// A payload did not decode: a decode error (the first one is logged).
    fn bad(&mut self, e: &DecodeError) {
        self.counters.decode_errors += 1;
        if !self.logged_bad {
            self.logged_bad = true;
            tracing::warn!("undecodable radio payload: {e}");
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
    use proto::geom::{LaserSpec, MapInfo};

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
        let (mut s, world) = world();
        s.clock.markers = false;
        let mut radio = Radio::new(0, &s, &world);
        let mut sharing = crate::exchange::sharing::new(&s, 0, 0, &world, None);
        let mut out = radio.link_up(1, sharing.as_mut(), 0, None);
        out.extend(radio.step(0, Some(Cell::new(3, 4)), &[], &[], sharing.as_mut()));
        assert!(radio.frames(0).is_empty(), "no frames without step markers");
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

    #[test]
    fn a_steps_messages_to_a_neighbour_leave_in_one_frame_that_unpacks_to_them() {
        let (s, world) = world();
        assert!(s.clock.marked());
        let mut radio = Radio::new(0, &s, &world);
        let mut sharing = crate::exchange::sharing::new(&s, 0, 0, &world, None);
        assert!(radio.link_up(1, sharing.as_mut(), 0, None).is_empty());
        assert!(radio.link_up(2, sharing.as_mut(), 0, None).is_empty());
        let target = Some(Cell::new(3, 4));
        assert!(radio.step(5, target, &[], &[], sharing.as_mut()).is_empty());
        // A message to a robot that is not a neighbour is dropped, uncounted.
        radio.send_one(7, &Msg::Hello(sharing.knowledge()));
        let frames = radio.frames(5);
        assert_eq!(frames.iter().map(|o| o.to).collect::<Vec<_>>(), [1, 2]);
        assert!(frames
            .iter()
            .all(|o| proto::keys::radio_kind(&o.key) == Some("frame")));
        let sent: usize = frames.iter().map(|o| o.bytes.len()).sum();
        let c = radio.counters().clone();
        assert_eq!(c.bytes_sent, sent as u64);
        assert_eq!(c.sent_by_type.iter().sum::<u64>(), sent as u64);
        assert!(c.sent_by_type[Traffic::Mark as usize] > 0);
        // The receiver gets the greeting and the target, and the step's end counting them.
        let mut other = Radio::new(1, &s, &world);
        let got = other.receive("frame", &frames[0].bytes);
        assert_eq!(
            got.msgs,
            [
                Msg::Hello(sharing.knowledge()),
                Msg::Target(Target {
                    from: 0,
                    step: 5,
                    cell: target
                })
            ]
        );
        assert_eq!(
            got.end,
            Some(Mark {
                from: 0,
                step: 5,
                sent: 2
            })
        );
        assert_eq!(
            other.counters().bytes_received,
            frames[0].bytes.len() as u64
        );
        assert_eq!(other.counters().decode_errors, 0);
        // Nothing is left queued: the next step's frames carry only their markers.
        let next = radio.frames(6);
        let empty = other.receive("frame", &next[0].bytes);
        assert!(empty.msgs.is_empty());
        assert_eq!(empty.end.map(|m| (m.step, m.sent)), Some((6, 0)));
    }

    /// A frame never exceeds netem's credit (netem would hold its marker): what does not fit
    /// goes in the next frames, in order.
    #[test]
    fn a_frame_stays_within_the_credit_and_the_rest_follows_in_order() {
        let (s, world) = world();
        let mut radio = Radio::new(0, &s, &world);
        let mut sharing = crate::exchange::sharing::new(&s, 0, 0, &world, None);
        radio.link_up(1, sharing.as_mut(), 0, None);
        let targ = |i: i32| {
            Msg::Target(Target {
                from: 0,
                step: 3,
                cell: Some(Cell::new(i, i)),
            })
        };
        for i in 0..10 {
            radio.send_one(1, &targ(i));
        }
        let mut other = Radio::new(1, &s, &world);
        let mut got = Vec::new();
        for step in 3..20 {
            radio.set_credit(1, Some(60));
            let frames = radio.frames(step);
            let f = &frames[0];
            assert!(
                f.bytes.len() + WIRE_OVERHEAD_BYTES + f.key.len() <= 60,
                "{} bytes",
                f.bytes.len()
            );
            let r = other.receive("frame", &f.bytes);
            assert_eq!(r.end.map(|m| m.sent as usize), Some(r.msgs.len()));
            got.extend(r.msgs);
        }
        let mut want = vec![Msg::Hello(sharing.knowledge())];
        want.extend((0..10).map(targ));
        assert_eq!(got, want, "the greeting, then the targets in order");
        assert_eq!(radio.queued_cost(1), 0);
    }

    #[test]
    fn a_frames_bad_records_are_decode_errors_and_its_marker_counts_the_good_ones() {
        let (s, world) = world();
        let mut radio = Radio::new(1, &s, &world);
        let targ = |from| {
            encode(&Target {
                from,
                step: 2,
                cell: None,
            })
        };
        let kind = |k: &str| {
            RADIO_KINDS
                .iter()
                .position(|&r| r == k)
                .expect("a radio kind") as u8
        };
        let frame = Frame {
            from: 0,
            step: 2,
            records: vec![
                (kind("targ"), targ(0)),
                (kind("targ"), targ(3)),
                (kind("hello"), vec![1, 2, 3]),
                (kind("frame"), targ(0)),
                (200, targ(0)),
            ],
        };
        let got = radio.receive("frame", &encode(&frame));
        assert_eq!(got.msgs.len(), 1);
        assert_eq!(got.end.map(|m| m.sent), Some(1));
        assert_eq!(radio.counters().decode_errors, 4);
        // A frame that does not decode yields no marker.
        assert_eq!(radio.receive("frame", &[1, 2, 3]), Received::default());
        assert_eq!(radio.counters().decode_errors, 5);
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
    fn a_record_costs_its_kind_and_length() {
        for len in [0, 5, 127, 128, 600, 16_383, 16_384, 2_000_000] {
            let frame = Frame {
                from: 0,
                step: 0,
                records: Vec::new(),
            };
            let one = Frame {
                records: vec![(1, vec![0; len])],
                ..frame.clone()
            };
            let extra = encode(&one).len() - encode(&frame).len();
            assert_eq!(extra, len + record_overhead(len), "{len}");
            assert!(record_overhead(len) <= RECORD_AT_MOST);
        }
        assert_eq!(payload_within(100, 2), 100 - 2 * RECORD_AT_MOST);
        assert_eq!(payload_within(3, 1), 0);
        // A frame within one batch costs no more; one over two batches another frame header.
        assert_eq!(fragments_framing(60_000), 0);
        assert_eq!(fragments_framing(70_000), 16);
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
        radio.step(1, None, &[], &[], &mut sharing);
        let own = sharing.budgets.pop().expect("offered");
        assert!(own > 200, "the pacer's own budget: {own}");
        radio.set_credit(1, Some(150));
        radio.step(2, None, &[], &[], &mut sharing);
        let capped = sharing.budgets.pop().expect("offered");
        assert!(
            capped <= payload_within(150 - MARK_RESERVE_BYTES as usize, 2),
            "{capped}"
        );
        assert!(capped > 0);
        radio.set_credit(1, Some(10));
        radio.step(3, None, &[], &[], &mut sharing);
        assert_eq!(sharing.budgets.pop(), Some(0));
        radio.set_credit(1, None);
        radio.step(4, None, &[], &[], &mut sharing);
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
        assert_eq!(radio.receive("targ", &bytes).msgs, [Msg::Target(t)]);
        // The same bytes under another kind do not decode; an unknown kind is refused.
        assert_eq!(radio.receive("hello", &bytes), Received::default());
        assert_eq!(radio.receive("nonsense", &bytes), Received::default());
        let c = radio.counters();
        assert_eq!(c.bytes_received, 3 * bytes.len() as u64);
        assert_eq!(c.decode_errors, 2);
    }
}
