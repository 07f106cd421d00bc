//! The polygon exchange (thesis §5.1, Algorithm 10 step 6; docs/design.md §4.4): every robot's op
//! log of its incremental approximation (§4.2.3) travels over the transitive log exchange of
//! [`crate::exchange::transitive`], as [`OpChunk`](proto::msg::OpChunk)s in the compact op encoding
//! of [`crate::exchange::wire`]. For every other owner a robot keeps a
//! [`Replica`](crate::exchange::oplog::Replica) fed with that owner's ops in log order; what it
//! plans with is the replica's approximation **at its last complete save point** — a step whose ops
//! arrived only in part is never shown (atomicity).
//!
//! **Snapshots** (beyond the thesis; `exchange.snapshots`, docs/design.md §4.4): a peer far behind
//! on an owner's log — a link that just came up, a robot that heard nothing of that owner yet — is
//! sent the owner's approximation at the last save point we show, as the ops that build it from
//! nothing, when those are fewer than the ops of the history it lacks. A snapshot may take several
//! chunks; the receiver shows nothing of it until it is whole, then holds the owner's log from that
//! index on ([`LogExchange::install`](crate::exchange::transitive::LogExchange::install)) and
//! relays it onwards the same way to any peer that knows less than that. Ops after the snapshot
//! follow as usual. Either way the receiver ends with exactly the approximation that replaying the
//! whole log gives.
//!
//! A chunk whose ops do not decode, or whose op count disagrees with its header, is refused as a
//! whole (nothing is appended). Ops that decode but cannot be applied (possible only with bytes
//! corrupted in transit) are dropped from the owner's log back to its last save point, and the
//! sender is asked again (a handshake, as on a gap): the replica keeps showing the last committed
//! approximation meanwhile. Corrupted ops that happen to apply cannot be told from good ones
//! (the op encoding carries no checksum).

use std::collections::{BTreeMap, BTreeSet};
use std::sync::Arc;

use proto::msg::{Hello, LogDelta, OpChunk, RobotId, View};

use crate::exchange::delta::{diff, Op};
use crate::exchange::oplog::Replica;
use crate::exchange::transitive::{fill, DeltaOutcome, Handshake, LogExchange};
use crate::exchange::wire::{self, WireError};
use crate::mapping::approx::Approximation;

/// Why a received chunk was refused.
#[derive(Debug, thiserror::Error, PartialEq, Eq)]
pub enum ChunkError {
    #[error("ops do not decode: {0}")]
    Wire(#[from] WireError),
    #[error("header announces {want} ops, {got} decoded")]
    Count { want: u32, got: usize },
}

/// One robot's side of the polygon exchange.
#[derive(Clone, Debug)]
pub struct ApproxExchange {
    logs: LogExchange<Op>,
    /// Per other owner: its approximation rebuilt from its log.
    replicas: BTreeMap<RobotId, Follower>,
    /// Per owner: the encoded size of the ops we hold, measured as one chunk from the log's
    /// start (the encoding is relative to the op before), and how many ops it covers.
    sizes: BTreeMap<RobotId, (wire::Encoder, usize, u64)>,
    /// Our own approximation as our log builds it (what a snapshot of it holds), and the log
    /// index of its last save point.
    own_state: Replica,
    own_saved: u32,
    /// Whether a peer far behind may get a snapshot instead of the history (a peer that knows
    /// less of a log than we hold of it gets one whatever this says).
    snapshots: bool,
    /// Per (peer, owner): a snapshot on its way to the peer.
    sending: BTreeMap<(RobotId, RobotId), Sending>,
    /// Per owner: a snapshot on its way here.
    arriving: BTreeMap<RobotId, Arriving>,
    /// Per owner: the last snapshot made, for every peer that gets the same one; kept only
    /// while one is under way (a big team's snapshots would otherwise stay in memory).
    made: BTreeMap<RobotId, (u32, Arc<Vec<Op>>)>,
}

/// A snapshot being sent: the state at log index `at`, its `ops`, how many of them went.
#[derive(Clone, Debug)]
struct Sending {
    at: u32,
    ops: Arc<Vec<Op>>,
    sent: usize,
}

/// A snapshot being received from `from`: the state at log index `at`, its ops so far.
#[derive(Clone, Debug)]
struct Arriving {
    from: RobotId,
    at: u32,
    ops: Vec<Op>,
}

/// A snapshot is not even considered for a lag of fewer ops than this.
const SNAPSHOT_MIN_LAG: u32 = 32;

/// Another owner's approximation as rebuilt here.
#[derive(Clone, Debug, Default)]
struct Follower {
    replica: Replica,
    /// Ops of the owner's log applied, and how many of them up to the last save point (what
    /// the committed approximation reflects).
    applied: usize,
    shown: usize,
}

impl ApproxExchange {
    pub fn new(me: RobotId) -> ApproxExchange {
        ApproxExchange::owning(me, me)
    }

    /// Node `me` writing the log of owner `own` (a restarted robot's next life).
    pub fn owning(me: RobotId, own: RobotId) -> ApproxExchange {
        ApproxExchange {
            logs: LogExchange::owning(me, own),
            replicas: BTreeMap::new(),
            sizes: BTreeMap::new(),
            own_state: Replica::new(),
            own_saved: 0,
            snapshots: true,
            sending: BTreeMap::new(),
            arriving: BTreeMap::new(),
            made: BTreeMap::new(),
        }
    }

    /// With snapshots for peers far behind (`true`, the default) or the thesis's exchange, log
    /// suffixes only (`false`; a peer that knows less of a log than a relay holds still gets one).
    pub fn with_snapshots(mut self, on: bool) -> ApproxExchange {
        self.snapshots = on;
        self
    }

    pub fn id(&self) -> RobotId {
        self.logs.id()
    }

    /// The owner of our own log.
    pub fn own(&self) -> RobotId {
        self.logs.own()
    }

    /// Appends our own ops (one step's edit script and its save point) to our log.
    pub fn record_own(&mut self, ops: &[Op]) {
        for &op in ops {
            self.logs.record_own(op);
            if let Err(e) = self.own_state.apply(&op) {
                tracing::warn!("our own op does not apply ({e}): no snapshot of it");
            }
            if op == Op::Save {
                self.own_saved = self.logs.len(self.own());
            }
        }
        self.measure(self.own());
    }

    /// `owner`'s approximation at the last save point we show, and that save point's log index.
    fn latest(&self, owner: RobotId) -> Option<(u32, &Approximation)> {
        if owner == self.own() {
            return Some((self.own_saved, self.own_state.committed()));
        }
        let f = self.replicas.get(&owner)?;
        Some((
            u32::try_from(f.shown).unwrap_or(u32::MAX),
            f.replica.committed(),
        ))
    }

    /// A snapshot to start sending `peer`, who knows `known` ops of `owner`'s log: when it
    /// cannot have the ops it lacks from us (we hold the log from a later index), or when
    /// snapshots are on and the state takes fewer ops than the history it lacks.
    fn snapshot_for(&mut self, owner: RobotId, known: u32) -> Option<Sending> {
        let (at, state) = self.latest(owner)?;
        if known >= at {
            return None;
        }
        let must = known < self.logs.base(owner);
        if !must {
            let lag = at - known;
            // An approximation's ops from nothing: one per object and vertex, and the save.
            let ops = state.objects.len() + state.vertex_count() + 1;
            if !self.snapshots || lag < SNAPSHOT_MIN_LAG || ops >= lag as usize {
                return None;
            }
        }
        let ops = match self.made.get(&owner) {
            Some((made_at, ops)) if *made_at == at => ops.clone(),
            _ => {
                let mut ops = diff(&Approximation::default(), state);
                if ops.last() != Some(&Op::Save) {
                    ops.push(Op::Save);
                }
                let ops = Arc::new(ops);
                self.made.insert(owner, (at, ops.clone()));
                ops
            }
        };
        Some(Sending { at, ops, sent: 0 })
    }

    /// Brings the measured size of `owner`'s log up to what we hold (from scratch if the log
    /// was cut back).
    fn measure(&mut self, owner: RobotId) {
        let log = self.logs.log(owner);
        let (enc, counted, bytes) = self
            .sizes
            .entry(owner)
            .or_insert_with(|| (wire::Encoder::new(), 0, 0));
        if *counted > log.len() {
            *enc = wire::Encoder::new();
            *counted = 0;
            *bytes = 0;
        }
        for op in &log[*counted..] {
            *bytes += enc.measure(op) as u64;
        }
        *counted = log.len();
    }

    /// Per owner whose log we hold (our own included): the encoded bytes of the ops we hold.
    pub fn held_bytes(&self) -> Vec<(RobotId, u64)> {
        self.sizes.iter().map(|(&o, &(_, _, b))| (o, b)).collect()
    }

    /// The chunks to send `peer` now, within `budget_bytes` as measured by `size_of` (the size
    /// of one encoded chunk message), in the exchange's policy order.
    ///
    /// Snapshots go first (those under way, then new ones, in owner order); an owner whose
    /// snapshot is under way sends nothing else until it is whole.
    pub fn outgoing(
        &mut self,
        peer: RobotId,
        budget_bytes: usize,
        size_of: impl Fn(&OpChunk) -> usize,
    ) -> Vec<OpChunk> {
        let mut out = Vec::new();
        let mut used = 0usize;
        let mut busy = Vec::new();
        let mut full = false;
        let owners: Vec<RobotId> = self.logs.owners().collect();
        for owner in owners {
            let Some(known) = self.logs.known(peer, owner) else {
                return Vec::new();
            };
            if !self.logs.sends(peer, owner) {
                continue;
            }
            let job = match self.sending.remove(&(peer, owner)) {
                Some(job) if known < job.at => Some(job),
                _ => self.snapshot_for(owner, known),
            };
            let Some(mut job) = job else {
                continue;
            };
            busy.push(owner);
            if !full {
                let at = job.at;
                let (part, size, stopped) = fill(
                    self.id(),
                    owner,
                    u32::try_from(job.sent).unwrap_or(u32::MAX),
                    job.ops.get(job.sent..).unwrap_or_default(),
                    budget_bytes.saturating_sub(used),
                    &|d| size_of(&snapshot_chunk(d, at)),
                );
                if !part.records.is_empty() {
                    used += size;
                    job.sent += part.records.len();
                    out.push(snapshot_chunk(&part, at));
                }
                full = stopped;
            }
            if job.sent >= job.ops.len() {
                // Whole: the peer holds the log up to `at`, and takes what follows as usual.
                self.logs.sent_up_to(peer, owner, job.at);
                busy.pop();
            } else {
                self.sending.insert((peer, owner), job);
            }
        }
        self.made.retain(|_, (_, ops)| Arc::strong_count(ops) > 1);
        if !full {
            out.extend(
                self.logs
                    .outgoing_skipping(
                        peer,
                        budget_bytes.saturating_sub(used),
                        |d| size_of(&chunk(d)),
                        &busy,
                    )
                    .iter()
                    .map(chunk),
            );
        }
        out
    }

    /// Takes a received chunk: appends the new ops of its owner's log and brings that owner's
    /// replica up to date. A gap is reported as by [`LogExchange::on_delta`] (the caller answers
    /// with a handshake).
    pub fn on_chunk(&mut self, c: &OpChunk) -> Result<DeltaOutcome, ChunkError> {
        let records = wire::decode(&c.ops)?;
        if records.len() != c.count as usize {
            return Err(ChunkError::Count {
                want: c.count,
                got: records.len(),
            });
        }
        if let Some(offset) = c.snapshot {
            return Ok(self.on_snapshot_part(c, records, offset));
        }
        let outcome = self.logs.on_delta(&LogDelta {
            from: c.from,
            owner: c.owner,
            start: c.start,
            records,
        });
        if let DeltaOutcome::Appended { owner, .. } = outcome {
            let cut = self.catch_up(owner);
            self.measure(owner);
            if let Some(have) = cut {
                return Ok(DeltaOutcome::Gap {
                    owner,
                    have,
                    start: c.start,
                });
            }
        }
        Ok(outcome)
    }

    /// Takes part of a snapshot (ops `offset..` of it): kept until the snapshot is whole, then
    /// installed if it is ahead of what we hold. A part that does not follow on the one before
    /// drops what came of it and reports a gap (the sender, told by our handshake, starts over).
    fn on_snapshot_part(&mut self, c: &OpChunk, ops: Vec<Op>, offset: u32) -> DeltaOutcome {
        let owner = c.owner;
        // The sender holds the state at `start`, so the log up to there.
        self.logs.sent_up_to(c.from, owner, c.start);
        let have = self.logs.len(owner);
        if self.arriving.get(&owner).is_some_and(|a| a.at <= have) {
            self.arriving.remove(&owner);
        }
        if owner == self.own() || c.start <= have {
            return DeltaOutcome::Duplicate;
        }
        let gap = DeltaOutcome::Gap {
            owner,
            have,
            start: c.start,
        };
        match self.arriving.get_mut(&owner) {
            Some(a) if a.from == c.from && a.at == c.start && a.ops.len() == offset as usize => {
                a.ops.extend(ops);
            }
            _ if offset == 0 => {
                self.arriving.insert(
                    owner,
                    Arriving {
                        from: c.from,
                        at: c.start,
                        ops,
                    },
                );
            }
            _ => {
                self.arriving.remove(&owner);
                return gap;
            }
        }
        let whole = self
            .arriving
            .get(&owner)
            .map(|a| a.ops.last() == Some(&Op::Save));
        if whole != Some(true) {
            return DeltaOutcome::Arriving { owner };
        }
        let Some(a) = self.arriving.remove(&owner) else {
            return gap;
        };
        let mut replica = Replica::new();
        let saves = a.ops.iter().filter(|&&op| op == Op::Save).count();
        if saves != 1 || a.ops.iter().any(|op| replica.apply(op).is_err()) {
            tracing::warn!(
                "a snapshot of robot {owner} from robot {} does not apply",
                a.from
            );
            return gap;
        }
        self.logs.install(owner, a.at);
        let at = a.at as usize;
        self.replicas.insert(
            owner,
            Follower {
                replica,
                applied: at,
                shown: at,
            },
        );
        self.measure(owner);
        DeltaOutcome::Installed { owner, at: a.at }
    }

    /// Applies the ops of `owner`'s log the replica has not seen. If one does not apply, the
    /// log is cut back to the last save point and its length returned (to be asked for again).
    fn catch_up(&mut self, owner: RobotId) -> Option<u32> {
        if owner == self.own() {
            return None;
        }
        let base = self.logs.base(owner) as usize;
        let log = self.logs.log(owner);
        let f = self.replicas.entry(owner).or_default();
        for op in log
            .get(f.applied.saturating_sub(base)..)
            .unwrap_or_default()
        {
            if let Err(e) = f.replica.apply(op) {
                tracing::warn!(
                    "ops of robot {owner} do not apply ({e}): dropped back to its save point at \
                     op {} and asked again",
                    f.shown
                );
                f.replica.rewind();
                f.applied = f.shown;
                let have = u32::try_from(f.shown).unwrap_or(u32::MAX);
                self.logs.truncate(owner, have);
                return Some(have);
            }
            f.applied += 1;
            if *op == Op::Save {
                f.shown = f.applied;
            }
        }
        None
    }

    /// Per other owner: how many ops of its log we hold, how many of them the approximation we
    /// show reflects (up to the last save point), and that approximation's digest.
    pub fn views(&self) -> Vec<View> {
        (self.replicas.iter())
            .map(|(&owner, f)| View {
                owner,
                held: self.logs.len(owner),
                shown: u32::try_from(f.shown).unwrap_or(u32::MAX),
                digest: f.replica.committed_digest(),
            })
            .collect()
    }

    /// Per other owner, in id order: ops of its log we hold, how many of them the approximation
    /// we show reflects, and that approximation.
    pub fn shown(&self) -> impl Iterator<Item = (RobotId, u32, u32, &Approximation)> {
        self.replicas.iter().map(|(&owner, f)| {
            (
                owner,
                self.logs.len(owner),
                u32::try_from(f.shown).unwrap_or(u32::MAX),
                f.replica.committed(),
            )
        })
    }

    /// `owner`'s approximation at the last save point we hold (`None` for ourselves and for
    /// owners we have not heard of).
    pub fn approximation(&self, owner: RobotId) -> Option<&Approximation> {
        self.replicas.get(&owner).map(|f| f.replica.committed())
    }

    /// Every other owner's approximation at its last save point we hold, in id order.
    pub fn approximations(&self) -> impl Iterator<Item = (RobotId, &Approximation)> {
        self.replicas
            .iter()
            .map(|(&o, f)| (o, f.replica.committed()))
    }

    /// The ops of `owner`'s log we hold, from index [`Self::base`] on.
    pub fn log(&self, owner: RobotId) -> &[Op] {
        self.logs.log(owner)
    }

    /// The log index from which we hold `owner`'s ops (0 unless a snapshot was installed).
    pub fn base(&self, owner: RobotId) -> u32 {
        self.logs.base(owner)
    }

    /// Encoded bytes of the ops we hold that `peer` lacks (one chunk per owner, headers aside)
    /// and of the snapshots under way to it: what waits for that link. `None` before its
    /// handshake.
    pub fn backlog_bytes(&self, peer: RobotId) -> Option<u64> {
        let logs = self
            .logs
            .backlog(peer, |_, ops| wire::encode(ops).len() as u64)?;
        let snapshots: u64 = self
            .sending
            .range((peer, RobotId::MIN)..=(peer, RobotId::MAX))
            .map(|(_, j)| wire::encode(j.ops.get(j.sent..).unwrap_or_default()).len() as u64)
            .sum();
        Some(logs + snapshots)
    }

    /// Forgets the snapshots under way to `peer` (its link went, or came up again).
    fn drop_sending(&mut self, peer: RobotId) {
        self.sending.retain(|&(p, _), _| p != peer);
    }
}

/// The handshake is the op logs' (the approximations follow the logs).
impl Handshake for ApproxExchange {
    fn knowledge(&self) -> Hello {
        self.logs.knowledge()
    }

    /// A snapshot under way to the peer goes on unless the handshake says it holds the state
    /// already: a periodic handshake must not start a long snapshot over.
    fn on_hello(&mut self, h: &Hello) {
        self.logs.on_hello(h);
        self.sending.retain(|&(peer, owner), job| {
            peer != h.from
                || h.knowledge
                    .iter()
                    .all(|&(o, known)| o != owner || known < job.at)
        });
    }

    fn link_up(&mut self, peer: RobotId) {
        self.logs.link_up(peer);
        self.drop_sending(peer);
    }

    fn link_down(&mut self, peer: RobotId) {
        self.logs.link_down(peer);
        self.drop_sending(peer);
    }

    /// A snapshot under way to `peer` of an owner it now takes from another robot is dropped
    /// (were it taken up again, the peer would have dropped its parts meanwhile).
    fn leave_out(&mut self, peer: RobotId, owners: BTreeSet<RobotId>) {
        self.sending
            .retain(|&(p, owner), _| p != peer || !owners.contains(&owner));
        self.logs.leave_out(peer, owners);
    }

    fn holds(&mut self, peer: RobotId, owner: RobotId, at: u32) {
        self.logs.holds(peer, owner, at);
    }

    fn forget(&mut self, owner: RobotId) {
        if owner != self.own() {
            self.logs.forget(owner);
            self.replicas.remove(&owner);
            self.sizes.remove(&owner);
            self.arriving.remove(&owner);
            self.made.remove(&owner);
            self.sending.retain(|&(_, o), _| o != owner);
        }
    }

    fn lag(&self, peer: RobotId) -> Option<u64> {
        self.logs.lag(peer)
    }
}

/// The encoded bytes of each op in a chunk, by package type (for accounting).
pub fn op_bytes(c: &OpChunk) -> Vec<(proto::msg::Traffic, usize)> {
    let Ok(ops) = wire::decode(&c.ops) else {
        return Vec::new();
    };
    let mut e = wire::Encoder::new();
    ops.iter().map(|op| (op.kind(), e.push(op))).collect()
}

/// A log delta of ops as the radio message.
fn chunk(d: &LogDelta<Op>) -> OpChunk {
    OpChunk {
        from: d.from,
        owner: d.owner,
        start: d.start,
        count: u32::try_from(d.records.len()).unwrap_or(u32::MAX),
        ops: wire::encode(&d.records),
        snapshot: None,
    }
}

/// Ops of a snapshot of the state at log index `at`, from `d.start` on in the snapshot, as the
/// radio message.
fn snapshot_chunk(d: &LogDelta<Op>, at: u32) -> OpChunk {
    OpChunk {
        start: at,
        snapshot: Some(d.start),
        ..chunk(d)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::exchange::mapper::Mapper;
    use crate::exchange::oplog::OpLog;
    use crate::exchange::relay::RelayTree;
    use proptest::prelude::*;
    use proto::grid::{Cell, Grid};
    use proto::msg::encode;

    /// A robot's growing view of a small world, one frame per step.
    const FRAMES: [&str; 4] = [
        "????????????\n????????????\n???......???\n????????????\n????????????\n",
        "????????????\n??#......#??\n??#......#??\n??###..###??\n????????????\n",
        "?##########?\n?#........#?\n?#..##....#?\n?###....###?\n???#....#???\n",
        "############\n#..........#\n#..##....#.#\n###......###\n..#......#..\n",
    ];

    /// Robot 0's op log after mapping the frames, and its approximation after each step.
    fn owner_log() -> (Vec<Op>, Vec<Approximation>) {
        log_of(&FRAMES)
    }

    /// A long log whose history is much larger than its state: the world seen over and over,
    /// changing back and forth (every change rewrites vertices).
    fn churn_log() -> (Vec<Op>, Vec<Approximation>) {
        let frames: Vec<&str> = (0..24).map(|i| FRAMES[[1, 2, 3, 2][i % 4]]).collect();
        log_of(&frames)
    }

    /// The op log of a robot mapping `frames`, and its approximation after each step.
    fn log_of(frames: &[&str]) -> (Vec<Op>, Vec<Approximation>) {
        let mut m = Mapper::new(2.0);
        let mut states = Vec::new();
        let mut before = Grid::from_ascii(frames[0]);
        for &f in frames {
            let g = Grid::from_ascii(f);
            let w = g.width() as usize;
            let changed: Vec<Cell> = (0..g.len())
                .filter(|&i| g.cells()[i] != before.cells()[i])
                .map(|i| Cell::new((i % w) as i32, (i / w) as i32))
                .collect();
            m.step(&g, &changed);
            states.push(m.approximation().clone());
            before = g;
        }
        (m.log().since(0).to_vec(), states)
    }

    fn size(c: &OpChunk) -> usize {
        encode(c).len()
    }

    /// Moves everything `from` has for `to` (after handshakes both ways) in chunks of at most
    /// `budget` bytes; returns the chunks.
    fn transfer(from: &mut ApproxExchange, to: &mut ApproxExchange, budget: usize) -> Vec<OpChunk> {
        from.link_up(to.id());
        to.link_up(from.id());
        from.on_hello(&to.knowledge());
        to.on_hello(&from.knowledge());
        let mut sent = Vec::new();
        loop {
            let out = from.outgoing(to.id(), budget, size);
            if out.is_empty() {
                return sent;
            }
            for c in out {
                let got = to.on_chunk(&c);
                assert!(
                    matches!(
                        got,
                        Ok(DeltaOutcome::Appended { .. }
                            | DeltaOutcome::Arriving { .. }
                            | DeltaOutcome::Installed { .. })
                    ),
                    "{got:?}"
                );
                sent.push(c);
            }
        }
    }

    #[test]
    fn a_restarted_robot_gets_its_earlier_life_back_and_writes_a_new_log() {
        let (ops, states) = owner_log();
        let (mut a, mut b) = (ApproxExchange::new(0), ApproxExchange::new(1));
        a.record_own(&ops);
        assert_eq!(a.held_bytes(), vec![(0, wire::encode(&ops).len() as u64)]);
        transfer(&mut a, &mut b, 64);
        // Robot 0 dies; its next life starts empty and owns a log of its own.
        let second = proto::msg::log_owner(0, 1).expect("robot 0 has a second life");
        let mut a2 = ApproxExchange::owning(0, second);
        transfer(&mut b, &mut a2, 64);
        let last = states.last().cloned().unwrap_or_default();
        assert_eq!(
            a2.approximation(0),
            Some(&last),
            "its first life, as a replica"
        );
        assert_eq!(a2.log(0), ops.as_slice());
        assert!(a2.log(second).is_empty());
        // Its new ops go to the new log, which b takes as another owner's.
        a2.record_own(&ops[..3]);
        transfer(&mut a2, &mut b, 64);
        assert_eq!(b.log(second), &ops[..3]);
        assert_eq!(b.log(0), ops.as_slice());
        let held: BTreeMap<_, _> = b.held_bytes().into_iter().collect();
        assert_eq!(held[&0], wire::encode(&ops).len() as u64);
        assert_eq!(held[&second], wire::encode(&ops[..3]).len() as u64);
        // Nobody can write into our own log: a chunk of it is ignored.
        let forged = chunk(&LogDelta {
            from: 1,
            owner: second,
            start: 3,
            records: ops[3..5].to_vec(),
        });
        assert_eq!(a2.on_chunk(&forged), Ok(DeltaOutcome::Duplicate));
        assert_eq!(a2.log(second), &ops[..3]);
    }

    /// A peer that knows nothing of a long log gets the state it leads to, in fewer bytes than
    /// the history; a relay that holds the log only from there passes the state on; the ops that
    /// follow go as usual; and everyone shows what replaying the whole log gives.
    #[test]
    fn a_peer_far_behind_gets_the_state_not_the_history_and_passes_it_on() {
        let (ops, states) = churn_log();
        let last = states.last().cloned().unwrap_or_default();
        let history = wire::encode(&ops).len();
        let state = diff(&Approximation::default(), &last);
        assert!(
            ops.len() > 3 * state.len() + SNAPSHOT_MIN_LAG as usize,
            "a long history: {} ops for a state of {}",
            ops.len(),
            state.len()
        );
        let split = ops.len()
            - 1
            - ops[..ops.len() - 1]
                .iter()
                .rev()
                .position(|&o| o == Op::Save)
                .unwrap_or(0);
        let (mut a, mut b, mut c) = (
            ApproxExchange::new(0),
            ApproxExchange::new(1),
            ApproxExchange::new(2),
        );
        a.record_own(&ops[..split]);
        let sent = transfer(&mut a, &mut b, 64);
        assert!(
            sent.iter().all(|c| c.snapshot.is_some()),
            "only the snapshot"
        );
        let bytes: usize = sent.iter().map(|c| c.ops.len()).sum();
        assert!(
            bytes * 2 < history,
            "{bytes} bytes for a history of {history}"
        );
        assert_eq!(b.base(0), split as u32);
        assert!(b.log(0).is_empty());
        let views = b.views();
        assert_eq!(
            (views[0].held, views[0].shown),
            (split as u32, split as u32)
        );
        let mut log = OpLog::new();
        ops.iter().for_each(|&op| log.push(op));
        assert_eq!(b.approximation(0), log.state_at(split).ok().as_ref());
        // C learns A's map from B, who holds no history to send: the state again.
        let relayed = transfer(&mut b, &mut c, 64);
        assert!(relayed.iter().all(|c| c.snapshot.is_some()));
        assert_eq!(c.approximation(0), b.approximation(0));
        // A's next step goes as ops, and on through B.
        a.record_own(&ops[split..]);
        let more = transfer(&mut a, &mut b, 64);
        assert!(more
            .iter()
            .all(|c| c.snapshot.is_none() && c.start == split as u32));
        transfer(&mut b, &mut c, 64);
        assert_eq!(b.approximation(0), Some(&last));
        assert_eq!(c.approximation(0), Some(&last));
        assert_eq!(c.log(0), &ops[split..]);
        // The thesis's exchange sends the history.
        let (mut a, mut d) = (
            ApproxExchange::new(0).with_snapshots(false),
            ApproxExchange::new(3).with_snapshots(false),
        );
        a.record_own(&ops);
        let thesis = transfer(&mut a, &mut d, 64);
        assert!(thesis.iter().all(|c| c.snapshot.is_none()));
        assert_eq!(d.log(0), ops.as_slice());
        assert_eq!(d.approximation(0), Some(&last));
    }

    /// A snapshot cut off (its link went) is started over, never shown in part, and a part that
    /// does not follow on is reported as a gap.
    #[test]
    fn a_snapshot_is_shown_only_whole() {
        let (ops, states) = churn_log();
        let (mut a, mut b) = (ApproxExchange::new(0), ApproxExchange::new(1));
        a.record_own(&ops);
        for x in [&mut a, &mut b] {
            x.link_up(1 - x.id());
        }
        a.on_hello(&b.knowledge());
        b.on_hello(&a.knowledge());
        let first = a.outgoing(1, 16, size);
        assert!(!first.is_empty() && first.iter().all(|c| c.snapshot.is_some()));
        for c in &first {
            assert_eq!(b.on_chunk(c), Ok(DeltaOutcome::Arriving { owner: 0 }));
        }
        assert!(b.approximation(0).is_none(), "nothing shown of a part");
        // A part that skips ahead: what came is dropped, and B asks again.
        let mut skip = a.outgoing(1, 16, size).remove(0);
        skip.snapshot = skip.snapshot.map(|o| o + 1);
        assert!(matches!(
            b.on_chunk(&skip),
            Ok(DeltaOutcome::Gap { owner: 0, .. })
        ));
        // The link goes and comes back: the snapshot starts over and arrives whole.
        for x in [&mut a, &mut b] {
            x.link_down(1 - x.id());
        }
        transfer(&mut a, &mut b, 16);
        assert_eq!(b.approximation(0), states.last());
    }

    #[test]
    fn approximations_travel_transitively_through_a_relay() {
        let (ops, states) = owner_log();
        let (mut a, mut b, mut c) = (
            ApproxExchange::new(0),
            ApproxExchange::new(1),
            ApproxExchange::new(2),
        );
        a.record_own(&ops);
        transfer(&mut a, &mut b, 64);
        // C never meets A: it learns A's map from B.
        transfer(&mut b, &mut c, 64);
        let last = states.last().cloned().unwrap_or_default();
        assert_eq!(b.approximation(0), Some(&last));
        assert_eq!(c.approximation(0), Some(&last));
        assert_eq!(c.log(0), ops.as_slice());
        assert!(a.approximation(0).is_none(), "no replica of ourselves");
    }

    proptest! {
        /// However the log is cut into chunks and wherever the transfer stops, the receiver shows
        /// exactly the owner's approximation at the last save point it holds, never part of a step.
        #[test]
        fn a_receiver_only_ever_shows_a_complete_step(budget in 8usize..120, stop in 0usize..40) {
            let (ops, _) = owner_log();
            let mut log = OpLog::new();
            ops.iter().for_each(|&op| log.push(op));
            let (mut a, mut b) = (ApproxExchange::new(0), ApproxExchange::new(1));
            a.record_own(&ops);
            a.link_up(1);
            b.link_up(0);
            a.on_hello(&b.knowledge());
            for c in a.outgoing(1, budget, size).into_iter().take(stop.max(1)) {
                b.on_chunk(&c).map_err(|e| TestCaseError::fail(e.to_string()))?;
                let held = b.log(0).len();
                let want = log.state_at(held).map_err(|e| TestCaseError::fail(e.to_string()))?;
                prop_assert_eq!(b.approximation(0), Some(&want));
            }
        }

        /// However links come and go, how small each step's budget and wherever chunks are lost
        /// with a dropped link, once the robots stay connected (a chain, each robot reaching the
        /// others only through relays) every robot ends with every other owner's approximation in
        /// full detail: the transitive exchange delivers every log whole, eventually. With
        /// snapshots or without, relayed along the relay tree or flooded, what a robot shows of
        /// an owner at any time is exactly what replaying the owner's whole log up to the save
        /// point shown gives.
        #[test]
        fn every_approximation_arrives_in_full_detail_eventually(
            robots in 3usize..6,
            rounds in proptest::collection::vec(
                (proptest::collection::vec(any::<bool>(), 15), 8usize..80, any::<bool>()),
                0..30,
            ),
            snapshots in any::<bool>(),
            churn in any::<bool>(),
            burst in 1usize..30,
            tree in any::<bool>(),
        ) {
            let (ops, states) = if churn { churn_log() } else { owner_log() };
            let mut full = OpLog::new();
            ops.iter().for_each(|&op| full.push(op));
            let mut xs: Vec<ApproxExchange> = (0..robots)
                .map(|r| ApproxExchange::new(r as RobotId).with_snapshots(snapshots))
                .collect();
            let mut trees: Vec<Option<RelayTree>> = (0..robots)
                .map(|r| tree.then(|| RelayTree::new(r as RobotId, r as RobotId)))
                .collect();
            let pairs: Vec<(usize, usize)> = (0..robots)
                .flat_map(|a| (a + 1..robots).map(move |b| (a, b)))
                .collect();
            let mut up = vec![false; pairs.len()];
            // One round (a lockstep step): links change, owners append a step of their log, the
            // relay tree is brought up to date, every up link carries one budget each way, and the
            // routes told arrive with it; on a link going down this round, its chunks are lost.
            let mut written = vec![0usize; robots];
            let round = |xs: &mut Vec<ApproxExchange>, trees: &mut Vec<Option<RelayTree>>,
                         up: &mut Vec<bool>, want: &[bool], budget: usize, lose: bool,
                         written: &mut Vec<usize>| -> Result<(), TestCaseError> {
                for (r, x) in xs.iter_mut().enumerate() {
                    let next = (written[r] + burst + r).min(ops.len());
                    x.record_own(&ops[written[r]..next]);
                    written[r] = next;
                }
                let now: Vec<bool> = (0..pairs.len()).map(|k| want.get(k).copied().unwrap_or(false)).collect();
                let mut neighbours = vec![BTreeSet::new(); xs.len()];
                for (k, &(a, b)) in pairs.iter().enumerate() {
                    if now[k] && !up[k] {
                        for (x, y) in [(a, b), (b, a)] {
                            xs[x].link_up(y as RobotId);
                            if let Some(t) = trees[x].as_mut() {
                                t.link_up(y as RobotId);
                            }
                        }
                        let (ha, hb) = (xs[a].knowledge(), xs[b].knowledge());
                        xs[a].on_hello(&hb);
                        xs[b].on_hello(&ha);
                    }
                    if now[k] || up[k] {
                        neighbours[a].insert(b as RobotId);
                        neighbours[b].insert(a as RobotId);
                    }
                }
                let mut told = Vec::new();
                for (r, t) in trees.iter_mut().enumerate() {
                    let Some(t) = t.as_mut() else { continue };
                    t.update(&neighbours[r]);
                    for &p in &neighbours[r] {
                        xs[r].leave_out(p, t.left_out(p));
                    }
                    let held = xs[r].knowledge().knowledge;
                    let have = |o| held.iter().find(|k| k.0 == o).map_or(0, |k| k.1);
                    told.extend(t.announcements(&neighbours[r], have));
                }
                for (k, &(a, b)) in pairs.iter().enumerate() {
                    if now[k] || up[k] {
                        for (from, to) in [(a, b), (b, a)] {
                            let out = xs[from].outgoing(to as RobotId, budget, size);
                            if !now[k] && lose {
                                continue;
                            }
                            for c in out {
                                let got = xs[to]
                                    .on_chunk(&c)
                                    .map_err(|e| TestCaseError::fail(e.to_string()))?;
                                if matches!(got, DeltaOutcome::Gap { .. }) {
                                    let h = xs[to].knowledge();
                                    xs[from].on_hello(&h);
                                }
                            }
                        }
                    }
                    if !now[k] && up[k] {
                        for (x, y) in [(a, b), (b, a)] {
                            xs[x].link_down(y as RobotId);
                            if let Some(t) = trees[x].as_mut() {
                                t.link_down(y as RobotId);
                            }
                        }
                    }
                    up[k] = now[k];
                }
                for (to, routes) in told {
                    let to = usize::from(to);
                    let linked = pairs.iter().zip(up.iter()).any(|(&(a, b), &u)| {
                        u && (a, b) == (to.min(usize::from(routes.from)), to.max(usize::from(routes.from)))
                    });
                    if let (true, Some(t)) = (linked, trees[to].as_mut()) {
                        t.on_routes(&routes);
                        for r in &routes.routes {
                            if let Some(have) = r.have {
                                xs[to].holds(routes.from, r.owner, have);
                            }
                        }
                    }
                }
                Ok(())
            };
            let replayed = |xs: &[ApproxExchange]| -> Result<(), TestCaseError> {
                for x in xs {
                    for v in x.views() {
                        let want = full.state_at(v.shown as usize).map_err(|e| TestCaseError::fail(e.to_string()))?;
                        prop_assert_eq!(x.approximation(v.owner), Some(&want));
                        prop_assert!(v.shown <= v.held && v.held as usize <= ops.len());
                    }
                }
                Ok(())
            };
            for (links, budget, lose) in &rounds {
                round(&mut xs, &mut trees, &mut up, links, *budget, *lose, &mut written)?;
                replayed(&xs)?;
            }
            // Then a chain 0 – 1 – … – n−1 and nothing else, at a small budget.
            let chain: Vec<bool> = pairs.iter().map(|&(a, b)| b == a + 1).collect();
            for _ in 0..400 {
                round(&mut xs, &mut trees, &mut up, &chain, 64, false, &mut written)?;
            }
            replayed(&xs)?;
            let last = states.last().cloned().unwrap_or_default();
            for (r, x) in xs.iter().enumerate() {
                for owner in (0..robots).filter(|&o| o != r) {
                    let o = owner as RobotId;
                    let held = x.base(o) as usize + x.log(o).len();
                    prop_assert_eq!(held, ops.len(), "robot {} of {}", r, owner);
                    prop_assert_eq!(&ops[x.base(o) as usize..], x.log(o));
                    prop_assert_eq!(x.approximation(o), Some(&last));
                }
            }
        }

        /// Nothing a peer sends can crash the receiver: garbage is refused whole.
        #[test]
        fn arbitrary_chunks_are_refused_or_taken_never_a_panic(
            start in 0u32..50, count in 0u32..50, bytes in proptest::collection::vec(any::<u8>(), 0..200),
            snapshot in proptest::option::of(0u32..3),
        ) {
            let mut b = ApproxExchange::new(1);
            let c = OpChunk { from: 0, owner: 0, start, count, ops: bytes, snapshot };
            let before = b.log(0).len();
            if b.on_chunk(&c).is_err() {
                prop_assert_eq!(b.log(0).len(), before);
            }
        }
    }

    /// Ops corrupted in transit that still decode but do not apply: the receiver drops them back
    /// to the last save point, asks again, and recovers from the good copy.
    #[test]
    fn ops_that_do_not_apply_are_dropped_to_the_save_point_and_asked_again() {
        let (ops, states) = owner_log();
        let saves: Vec<usize> = (0..ops.len()).filter(|&i| ops[i] == Op::Save).collect();
        assert!(saves.len() >= 3, "{saves:?}");
        // Corrupt an op inside the third step (after the second save point).
        let bad_at = saves[1] + 1;
        let mut bad = ops.clone();
        bad[bad_at] = Op::Remove { id: 9999 };
        let chunk = |ops: &[Op], start: usize| OpChunk {
            from: 0,
            owner: 0,
            start: start as u32,
            count: ops.len() as u32,
            ops: wire::encode(ops),
            snapshot: None,
        };
        let mut b = ApproxExchange::new(1);
        let out = b.on_chunk(&chunk(&bad, 0));
        let have = (saves[1] + 1) as u32;
        assert_eq!(
            out,
            Ok(DeltaOutcome::Gap {
                owner: 0,
                have,
                start: 0
            })
        );
        assert_eq!(b.log(0).len(), have as usize, "cut back to the save point");
        assert_eq!(b.approximation(0), Some(&states[1]), "still shows step 2");
        // The sender, told by the handshake, resends from there.
        let again = b.on_chunk(&chunk(&ops[have as usize..], have as usize));
        assert!(
            matches!(again, Ok(DeltaOutcome::Appended { .. })),
            "{again:?}"
        );
        assert_eq!(b.approximation(0), states.last());
    }

    #[test]
    fn a_chunk_whose_count_disagrees_is_refused() {
        let (ops, _) = owner_log();
        let c = OpChunk {
            from: 0,
            owner: 0,
            start: 0,
            count: 3,
            ops: wire::encode(&ops[..2]),
            snapshot: None,
        };
        let mut b = ApproxExchange::new(1);
        assert_eq!(b.on_chunk(&c), Err(ChunkError::Count { want: 3, got: 2 }));
        assert!(b.log(0).is_empty());
    }
}
