//! The polygon exchange (thesis §5.1, Algorithm 10 step 6; docs/design.md §4.4): every robot's op log
//! of its incremental approximation (§4.2.3) travels over the transitive log exchange of
//! [`crate::exchange::transitive`], as [`OpChunk`]s in the compact op encoding of [`crate::exchange::wire`]. For every
//! other owner a robot keeps a [`Replica`] fed with that owner's ops in log order; what it
//! plans with is the replica's approximation **at its last complete save point** — a step whose
//! ops arrived only in part is never shown (atomicity).
//!
//! A chunk whose ops do not decode, or whose op count disagrees with its header, is refused as a
//! whole (nothing is appended). Ops that decode but cannot be applied (possible only with bytes
//! corrupted in transit) are dropped from the owner's log back to its last save point, and the
//! sender is asked again (a handshake, as on a gap): the replica keeps showing the last committed
//! approximation meanwhile. Corrupted ops that happen to apply cannot be told from good ones
//! (the op encoding carries no checksum).

use std::collections::BTreeMap;

use proto::msg::{Hello, LogDelta, OpChunk, RobotId, View};

use crate::exchange::delta::Op;
use crate::exchange::oplog::Replica;
use crate::exchange::transitive::{DeltaOutcome, Handshake, LogExchange};
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
}

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
        }
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
        }
        self.measure(self.own());
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
    pub fn outgoing(
        &mut self,
        peer: RobotId,
        budget_bytes: usize,
        size_of: impl Fn(&OpChunk) -> usize,
    ) -> Vec<OpChunk> {
        self.logs
            .outgoing(peer, budget_bytes, |d| size_of(&chunk(d)))
            .iter()
            .map(chunk)
            .collect()
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

    /// Applies the ops of `owner`'s log the replica has not seen. If one does not apply, the
    /// log is cut back to the last save point and its length returned (to be asked for again).
    fn catch_up(&mut self, owner: RobotId) -> Option<u32> {
        if owner == self.own() {
            return None;
        }
        let log = self.logs.log(owner);
        let f = self.replicas.entry(owner).or_default();
        for op in log.get(f.applied..).unwrap_or_default() {
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
        self.shown()
            .map(|(owner, held, shown, a)| View {
                owner,
                held,
                shown,
                digest: a.digest(),
            })
            .collect()
    }

    /// Per other owner, in id order: ops of its log we hold, how many of them the approximation
    /// we show reflects, and that approximation.
    pub fn shown(&self) -> impl Iterator<Item = (RobotId, u32, u32, &Approximation)> {
        self.replicas.iter().map(|(&owner, f)| {
            (
                owner,
                u32::try_from(self.logs.log(owner).len()).unwrap_or(u32::MAX),
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

    /// The prefix of `owner`'s op log we hold.
    pub fn log(&self, owner: RobotId) -> &[Op] {
        self.logs.log(owner)
    }

    /// Encoded bytes of the ops we hold that `peer` lacks (one chunk per owner, headers aside):
    /// what waits for that link. `None` before its handshake.
    pub fn backlog_bytes(&self, peer: RobotId) -> Option<u64> {
        self.logs
            .backlog(peer, |_, ops| wire::encode(ops).len() as u64)
    }
}

/// The handshake is the op logs' (the approximations follow the logs).
impl Handshake for ApproxExchange {
    fn knowledge(&self) -> Hello {
        self.logs.knowledge()
    }

    fn on_hello(&mut self, h: &Hello) {
        self.logs.on_hello(h);
    }

    fn link_up(&mut self, peer: RobotId) {
        self.logs.link_up(peer);
    }

    fn link_down(&mut self, peer: RobotId) {
        self.logs.link_down(peer);
    }

    fn forget(&mut self, owner: RobotId) {
        if owner != self.own() {
            self.logs.forget(owner);
            self.replicas.remove(&owner);
            self.sizes.remove(&owner);
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
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::exchange::mapper::Mapper;
    use crate::exchange::oplog::OpLog;
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
        let mut m = Mapper::new(2.0);
        let mut states = Vec::new();
        let mut before = Grid::from_ascii(FRAMES[0]);
        for f in FRAMES {
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
                assert!(matches!(to.on_chunk(&c), Ok(DeltaOutcome::Appended { .. })));
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
        /// full detail: the transitive exchange delivers every log whole, eventually.
        #[test]
        fn every_approximation_arrives_in_full_detail_eventually(
            robots in 3usize..6,
            rounds in proptest::collection::vec(
                (proptest::collection::vec(any::<bool>(), 15), 8usize..80, any::<bool>()),
                0..30,
            ),
        ) {
            let (ops, states) = owner_log();
            let mut xs: Vec<ApproxExchange> =
                (0..robots).map(|r| ApproxExchange::new(r as RobotId)).collect();
            let pairs: Vec<(usize, usize)> = (0..robots)
                .flat_map(|a| (a + 1..robots).map(move |b| (a, b)))
                .collect();
            let mut up = vec![false; pairs.len()];
            // One round: links change, owners append a step of their log, every up link carries
            // one budget each way; on a link going down this round, its chunks are lost.
            let mut written = vec![0usize; robots];
            let round = |xs: &mut Vec<ApproxExchange>, up: &mut Vec<bool>, want: &[bool], budget: usize,
                         lose: bool, written: &mut Vec<usize>| -> Result<(), TestCaseError> {
                for (r, x) in xs.iter_mut().enumerate() {
                    let next = (written[r] + 1 + r).min(ops.len());
                    x.record_own(&ops[written[r]..next]);
                    written[r] = next;
                }
                for (k, &(a, b)) in pairs.iter().enumerate() {
                    let now = want.get(k).copied().unwrap_or(false);
                    if now && !up[k] {
                        xs[a].link_up(b as RobotId);
                        xs[b].link_up(a as RobotId);
                        let (ha, hb) = (xs[a].knowledge(), xs[b].knowledge());
                        xs[a].on_hello(&hb);
                        xs[b].on_hello(&ha);
                    }
                    if now || up[k] {
                        for (from, to) in [(a, b), (b, a)] {
                            let out = xs[from].outgoing(to as RobotId, budget, size);
                            if !now && lose {
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
                    if !now && up[k] {
                        xs[a].link_down(b as RobotId);
                        xs[b].link_down(a as RobotId);
                    }
                    up[k] = now;
                }
                Ok(())
            };
            for (links, budget, lose) in &rounds {
                round(&mut xs, &mut up, links, *budget, *lose, &mut written)?;
            }
            // Then a chain 0 – 1 – … – n−1 and nothing else, at a small budget.
            let chain: Vec<bool> = pairs.iter().map(|&(a, b)| b == a + 1).collect();
            for _ in 0..400 {
                round(&mut xs, &mut up, &chain, 64, false, &mut written)?;
            }
            let last = states.last().cloned().unwrap_or_default();
            for (r, x) in xs.iter().enumerate() {
                for owner in (0..robots).filter(|&o| o != r) {
                    prop_assert_eq!(x.log(owner as RobotId), ops.as_slice(), "robot {} of {}", r, owner);
                    prop_assert_eq!(x.approximation(owner as RobotId), Some(&last));
                }
            }
        }

        /// Nothing a peer sends can crash the receiver: garbage is refused whole.
        #[test]
        fn arbitrary_chunks_are_refused_or_taken_never_a_panic(
            start in 0u32..50, count in 0u32..50, bytes in proptest::collection::vec(any::<u8>(), 0..200)
        ) {
            let mut b = ApproxExchange::new(1);
            let c = OpChunk { from: 0, owner: 0, start, count, ops: bytes };
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
        };
        let mut b = ApproxExchange::new(1);
        assert_eq!(b.on_chunk(&c), Err(ChunkError::Count { want: 3, got: 2 }));
        assert!(b.log(0).is_empty());
    }
}
