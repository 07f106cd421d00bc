//! The transitive exchange of append-only logs (thesis §5.1.2, Algorithm 8; docs/design.md §4.4),
//! as a pure state machine generic over the record type: the caller moves the messages.
//!
//! Every robot keeps an append-only log of its own records and a copy of a prefix of every other
//! robot's log it has heard of, and relays what it knows, so that A's records reach C through B
//! even if A and C never meet. A sent-index table S\[peer\]\[owner\] records how far we believe
//! `peer` knows `owner`'s log; a handshake ([`Hello`](proto::msg::Hello), the thesis's `conn`)
//! tells the truth about the peer and replaces our belief, deltas we send raise it optimistically,
//! and deltas we receive raise it too (the sender holds what it sends). A receiver appends only
//! contiguous records, ignores duplicates and reports a gap, on which the caller sends a handshake
//! so the sender learns where to resume. Messages lost with a dropped link are harmless: the link's
//! S row is forgotten, and the next handshake re-establishes it.
//!
//! A log may be held from an index on rather than from its start
//! ([`LogExchange::install`](crate::exchange::transitive::LogExchange::install)): the polygon
//! exchange replaces a long history by the state it leads to (a snapshot), and a robot that took
//! one holds the owner's records only from there. Records below that base cannot be sent;
//! [`LogExchange::outgoing`](crate::exchange::transitive::LogExchange::outgoing) skips an owner a
//! peer knows less of than our base, and the caller serves it otherwise.
//!
//! [`crate::exchange::raw_scans`] instantiates it with laser scans (the baseline); its tests
//! exercise this module.

use std::collections::{BTreeMap, BTreeSet};
use std::ops::Range;

use proto::msg::{Hello, LogDelta, RobotId};

/// The log exchange of one robot.
#[derive(Clone, Debug)]
pub struct LogExchange<R> {
    /// Our node id: the sender of our deltas and handshakes.
    me: RobotId,
    /// The owner of the log we append to: `me` in the robot's first life, then
    /// [`proto::msg::log_owner`] of its life (a restarted robot holds its earlier lives' logs
    /// like anyone else's).
    own: RobotId,
    /// Per owner, the part of its log we hold (our own log is complete).
    logs: BTreeMap<RobotId, Held<R>>,
    /// S\[peer\]\[owner\]: how far we believe `peer` knows `owner`'s log. A peer has a row only
    /// after its handshake; an owner missing from a row counts as known up to 0.
    sent: BTreeMap<RobotId, BTreeMap<RobotId, u32>>,
    /// Per peer, the owners whose records it takes from another neighbour (the relay tree,
    /// [`crate::exchange::relay`]): we send it none of them, and they are no backlog of ours.
    left_out: BTreeMap<RobotId, BTreeSet<RobotId>>,
}

/// The part of one owner's log we hold: its records from index `base` on (0 unless the state at
/// `base` came as a whole, [`LogExchange::install`]).
#[derive(Clone, Debug)]
struct Held<R> {
    base: u32,
    records: Vec<R>,
}

impl<R> Default for Held<R> {
    fn default() -> Self {
        Held {
            base: 0,
            records: Vec::new(),
        }
    }
}

impl<R> Held<R> {
    /// How many records of the log we know of.
    fn end(&self) -> u32 {
        self.base.saturating_add(len_u32(&self.records))
    }

    /// The records from log index `from` on (`None` below the base: we do not hold them).
    fn since(&self, from: u32) -> Option<&[R]> {
        self.records.get(from.checked_sub(self.base)? as usize..)
    }
}

/// What became of a received [`LogDelta`].
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum DeltaOutcome {
    /// Records `new` of `owner`'s log (indices into [`LogExchange::log`]) are new; they
    /// directly follow what we held before.
    Appended { owner: RobotId, new: Range<u32> },
    /// Every record was already held (an empty delta too).
    Duplicate,
    /// The delta starts beyond our `have` records of `owner`'s log: nothing was appended, and the
    /// caller should send a handshake ([`LogExchange::knowledge`]) to the delta's sender.
    Gap {
        owner: RobotId,
        have: u32,
        start: u32,
    },
    /// Part of a snapshot of `owner`'s approximation came (the polygon exchange); nothing is
    /// shown of it until it is whole.
    Arriving { owner: RobotId },
    /// A snapshot came whole: we hold `owner`'s log from index `at` on, and show the state there.
    Installed { owner: RobotId, at: u32 },
}

impl<R: Clone> LogExchange<R> {
    /// An exchange for robot `me` in its first life, holding nothing yet.
    pub fn new(me: RobotId) -> LogExchange<R> {
        LogExchange::owning(me, me)
    }

    /// An exchange for node `me` appending to the log of owner `own`, holding nothing yet.
    pub fn owning(me: RobotId, own: RobotId) -> LogExchange<R> {
        LogExchange {
            me,
            own,
            logs: BTreeMap::from([(own, Held::default())]),
            sent: BTreeMap::new(),
            left_out: BTreeMap::new(),
        }
    }

    /// The index of the first record of `owner`'s log we hold (0 unless a snapshot was
    /// installed).
    pub fn base(&self, owner: RobotId) -> u32 {
        self.logs.get(&owner).map_or(0, |h| h.base)
    }

    /// How many records of `owner`'s log we know of: our base and the records held after it.
    pub fn len(&self, owner: RobotId) -> u32 {
        self.logs.get(&owner).map_or(0, Held::end)
    }

    /// From now on we hold `owner`'s log from index `at` on, and nothing before: the state at
    /// `at` came as a whole. Only forward (`at` beyond what we know of the log), never our own.
    pub fn install(&mut self, owner: RobotId, at: u32) {
        if owner == self.own || at <= self.len(owner) {
            return;
        }
        self.logs.insert(
            owner,
            Held {
                base: at,
                records: Vec::new(),
            },
        );
    }

    /// Whether `owner`'s records go to `peer` from us (not left out, [`Handshake::leave_out`]).
    pub fn sends(&self, peer: RobotId, owner: RobotId) -> bool {
        !self.left_out.get(&peer).is_some_and(|o| o.contains(&owner))
    }

    /// How far we believe `peer` knows `owner`'s log (`None` before its handshake).
    pub fn known(&self, peer: RobotId, owner: RobotId) -> Option<u32> {
        self.sent
            .get(&peer)
            .map(|row| row.get(&owner).copied().unwrap_or(0))
    }

    /// `peer` holds `owner`'s log up to `at` (we sent it the state there): S is raised.
    pub fn sent_up_to(&mut self, peer: RobotId, owner: RobotId, at: u32) {
        if let Some(row) = self.sent.get_mut(&peer) {
            let known = row.entry(owner).or_insert(0);
            *known = at.max(*known);
        }
    }

    /// The owner of our own log.
    pub fn own(&self) -> RobotId {
        self.own
    }

    /// Our own robot id.
    pub fn id(&self) -> RobotId {
        self.me
    }

    /// Appends a record to our own log.
    pub fn record_own(&mut self, rec: R) {
        self.logs.entry(self.own).or_default().records.push(rec);
    }

    /// The deltas to send `peer` now, within `budget_bytes` as measured by `size_of` (the size of
    /// one delta on the wire), and updates S optimistically for what is returned.
    ///
    /// Each delta carries a contiguous run of one owner's records that the peer lacks by S. Owners
    /// go in policy order (docs/design.md §4.4): largest lag first, ties → our own log, then the
    /// lowest id. Records are added while the deltas' total size stays within the budget; at the
    /// first record that does not fit, the call stops (later owners wait rather than overtake the
    /// policy). So a record larger than the whole budget blocks everything behind it until a call
    /// with a larger budget. Nothing is sent to a peer whose handshake we have not had, nor of an
    /// owner the peer knows less of than our base.
    pub fn outgoing(
        &mut self,
        peer: RobotId,
        budget_bytes: usize,
        size_of: impl Fn(&LogDelta<R>) -> usize,
    ) -> Vec<LogDelta<R>> {
        self.outgoing_skipping(peer, budget_bytes, size_of, &[])
    }

    /// [`Self::outgoing`], sending nothing of the owners in `skip`.
    pub fn outgoing_skipping(
        &mut self,
        peer: RobotId,
        budget_bytes: usize,
        size_of: impl Fn(&LogDelta<R>) -> usize,
        skip: &[RobotId],
    ) -> Vec<LogDelta<R>> {
        let Some(row) = self.sent.get(&peer) else {
            return Vec::new();
        };
        let mut order: Vec<(u64, RobotId, u32)> = self
            .logs
            .iter()
            .filter_map(|(&owner, held)| {
                let known = row.get(&owner).copied().unwrap_or(0);
                let lag = u64::from(held.end().saturating_sub(known));
                (lag > 0 && known >= held.base && !skip.contains(&owner) && self.sends(peer, owner))
                    .then_some((lag, owner, known))
            })
            .collect();
        let (me, own) = (self.me, self.own);
        order.sort_by_key(|&(lag, owner, _)| (std::cmp::Reverse(lag), owner != own, owner));

        let mut out = Vec::new();
        let mut used = 0usize;
        for (_, owner, start) in order {
            let Some(rest) = self.logs.get(&owner).and_then(|h| h.since(start)) else {
                continue;
            };
            let (delta, size, full) = fill(
                me,
                owner,
                start,
                rest,
                budget_bytes.saturating_sub(used),
                &size_of,
            );
            if !delta.records.is_empty() {
                used += size;
                out.push(delta);
            }
            if full {
                break;
            }
        }
        let row = self.sent.entry(peer).or_default();
        for d in &out {
            row.insert(d.owner, d.start.saturating_add(len_u32(&d.records)));
        }
        out
    }

    /// Takes a received delta: appends the records beyond what we hold if they follow on
    /// contiguously, and raises S\[d.from\]\[d.owner\] to the delta's end (the sender holds what it
    /// sent) if we have had the sender's handshake.
    ///
    /// Records of our own log are never taken from anyone (only we write it; a restarted robot
    /// writes a new owner's log and takes its earlier lives' back like any other owner's).
    pub fn on_delta(&mut self, d: &LogDelta<R>) -> DeltaOutcome {
        let end = d.start.saturating_add(len_u32(&d.records));
        if d.from != self.me {
            if let Some(row) = self.sent.get_mut(&d.from) {
                let known = row.entry(d.owner).or_insert(0);
                *known = end.max(*known);
            }
        }
        if d.owner == self.own {
            return DeltaOutcome::Duplicate;
        }
        let held = self.logs.entry(d.owner).or_default();
        let have = held.end();
        if d.start > have {
            return DeltaOutcome::Gap {
                owner: d.owner,
                have,
                start: d.start,
            };
        }
        if end <= have {
            return DeltaOutcome::Duplicate;
        }
        // `have - start < records.len()` because `end > have`.
        let skip = (have - d.start) as usize;
        held.records.extend(
            d.records
                .iter()
                .skip(skip)
                .take((end - have) as usize)
                .cloned(),
        );
        DeltaOutcome::Appended {
            owner: d.owner,
            new: have..held.end(),
        }
    }

    /// Takes a delta like [`Self::on_delta`], and returns with the outcome the records it
    /// appended to another robot's log (none for our own log: we made those records).
    pub fn take_delta(&mut self, d: &LogDelta<R>) -> (DeltaOutcome, &[R]) {
        let outcome = self.on_delta(d);
        let new = match &outcome {
            DeltaOutcome::Appended { owner, new } if *owner != self.own => self
                .logs
                .get(owner)
                .and_then(|h| h.since(new.start))
                .map_or(&[][..], |r| &r[..r.len().min(new.len())]),
            _ => &[],
        };
        (outcome, new)
    }

    /// Drops `owner`'s records from index `len` on (records found to be corrupt; never below
    /// our base); our next handshake asks for them again. Our own log is never cut.
    pub fn truncate(&mut self, owner: RobotId, len: u32) {
        if owner != self.own {
            if let Some(h) = self.logs.get_mut(&owner) {
                h.records.truncate(len.saturating_sub(h.base) as usize);
            }
        }
    }

    /// The records of `owner`'s log we hold, from index [`Self::base`] on (empty for an owner we
    /// have not heard of).
    pub fn log(&self, owner: RobotId) -> &[R] {
        self.logs.get(&owner).map_or(&[], |h| h.records.as_slice())
    }

    /// The owners whose logs we hold (at least ourselves), in id order.
    pub fn owners(&self) -> impl Iterator<Item = RobotId> + '_ {
        self.logs.keys().copied()
    }

    /// What we hold that `peer` lacks by S, weighed per owner by `weigh` (given the lacking
    /// records of that owner's log we hold; e.g. their encoded bytes); `None` before the peer's
    /// handshake.
    pub fn backlog(&self, peer: RobotId, weigh: impl Fn(RobotId, &[R]) -> u64) -> Option<u64> {
        let row = self.sent.get(&peer)?;
        Some(
            self.logs
                .iter()
                .filter(|&(&owner, _)| self.sends(peer, owner))
                .map(|(&owner, h)| {
                    let known = row.get(&owner).copied().unwrap_or(0);
                    let from = known.saturating_sub(h.base) as usize;
                    h.records.get(from..).map_or(0, |rest| weigh(owner, rest))
                })
                .sum(),
        )
    }
}

/// The handshake side of a log exchange (the thesis's `conn`), the same in every exchange mode:
/// what we hold, what a peer holds, and the links that come and go.
pub trait Handshake {
    /// The handshake: how many records of each owner's log we hold.
    fn knowledge(&self) -> Hello;
    /// Takes a peer's handshake as the truth about what it holds.
    fn on_hello(&mut self, h: &Hello);
    /// A link to `peer` came up.
    fn link_up(&mut self, peer: RobotId);
    /// The link to `peer` went down.
    fn link_down(&mut self, peer: RobotId);
    /// From now on `owners`' records go to `peer` from another robot, never from us (the relay
    /// tree, [`crate::exchange::relay`]); the set replaces the one before.
    fn leave_out(&mut self, peer: RobotId, owners: BTreeSet<RobotId>);
    /// `peer` says it holds `owner`'s log up to `at` (the relay tree's routes carry it): S is
    /// raised to it.
    fn holds(&mut self, peer: RobotId, owner: RobotId, at: u32);
    /// How many records we hold that `peer` lacks; `None` before its handshake.
    fn lag(&self, peer: RobotId) -> Option<u64>;
    /// Drops everything we hold of `owner`'s log (never our own). Only the deliberately broken
    /// recovery that tests `swarm chaos`'s checker calls it (`BROKEN_RECOVERY_ENV`).
    fn forget(&mut self, owner: RobotId);
}

/// The environment variable that breaks recovery on purpose, to show that `swarm chaos`'s
/// checker notices: set to `forget-earlier-lives`, a node that hears of a robot's later life
/// drops what it holds of that robot's earlier lives (what a careless "newest incarnation
/// wins" rule would do).
pub const BROKEN_RECOVERY_ENV: &str = "SWARM_CHAOS_BROKEN_RECOVERY";

impl<R: Clone> Handshake for LogExchange<R> {
    /// The handshake: how many records of each owner's log we hold.
    fn knowledge(&self) -> Hello {
        Hello {
            from: self.me,
            knowledge: self
                .logs
                .iter()
                .map(|(&owner, h)| (owner, h.end()))
                .collect(),
            reset: true,
        }
    }

    /// Takes a peer's handshake as the truth about what it holds: its S row becomes exactly the
    /// listed indices (owners it does not list are known up to 0), or with `reset` off only
    /// rises to them. If an owner is listed twice, the larger index counts. A handshake
    /// claiming to come from ourselves is ignored.
    fn on_hello(&mut self, h: &Hello) {
        if h.from == self.me {
            return;
        }
        let kept = self.sent.remove(&h.from).filter(|_| !h.reset);
        let mut row = kept.unwrap_or_default();
        for &(owner, index) in &h.knowledge {
            let known = row.entry(owner).or_insert(0);
            *known = index.max(*known);
        }
        self.sent.insert(h.from, row);
    }

    /// A link to `peer` came up. Nothing is assumed about the peer until its handshake arrives:
    /// any S row from an earlier contact is forgotten.
    fn link_up(&mut self, peer: RobotId) {
        self.sent.remove(&peer);
        self.left_out.remove(&peer);
    }

    /// The link to `peer` went down: forget its S row, since we cannot know which of the messages
    /// in flight arrived. The next handshake re-establishes it.
    fn link_down(&mut self, peer: RobotId) {
        self.sent.remove(&peer);
        self.left_out.remove(&peer);
    }

    fn holds(&mut self, peer: RobotId, owner: RobotId, at: u32) {
        self.sent_up_to(peer, owner, at);
    }

    fn leave_out(&mut self, peer: RobotId, owners: BTreeSet<RobotId>) {
        if owners.is_empty() {
            self.left_out.remove(&peer);
        } else {
            self.left_out.insert(peer, owners);
        }
    }

    /// How many records we hold that `peer` lacks by S — the per-peer backlog; `None` before
    /// the peer's handshake.
    fn lag(&self, peer: RobotId) -> Option<u64> {
        let row = self.sent.get(&peer)?;
        Some(
            self.logs
                .iter()
                .filter(|&(&owner, _)| self.sends(peer, owner))
                .map(|(owner, h)| {
                    let known = row.get(owner).copied().unwrap_or(0);
                    u64::from(h.end().saturating_sub(known))
                })
                .sum(),
        )
    }

    fn forget(&mut self, owner: RobotId) {
        if owner != self.own {
            self.logs.remove(&owner);
        }
    }
}

/// One delta of `owner`'s records `rest`, which start at index `start`, as many as fit into
/// `budget_bytes`; returns it, its size, and whether a record was left out for lack of budget.
///
/// A delta's size grows with every record it carries, so the largest run that fits is found by
/// bisection: O(log n) encodings of at most n records, where adding one record at a time would
/// encode the growing delta n times (quadratic in a long suffix, as after a long separation on
/// an unlimited link).
pub(crate) fn fill<R: Clone>(
    me: RobotId,
    owner: RobotId,
    start: u32,
    rest: &[R],
    budget_bytes: usize,
    size_of: &impl Fn(&LogDelta<R>) -> usize,
) -> (LogDelta<R>, usize, bool) {
    let delta = |n: usize| LogDelta {
        from: me,
        owner,
        start,
        records: rest[..n].to_vec(),
    };
    let all = delta(rest.len());
    let size = size_of(&all);
    if size <= budget_bytes {
        return (all, size, false);
    }
    // Invariant: `lo` records fit (0 always does: nothing is sent then), `hi` do not.
    let (mut lo, mut hi) = (0usize, rest.len());
    let mut lo_size = 0;
    while hi - lo > 1 {
        let mid = lo + (hi - lo) / 2;
        let s = size_of(&delta(mid));
        if s <= budget_bytes {
            (lo, lo_size) = (mid, s);
        } else {
            hi = mid;
        }
    }
    (delta(lo), lo_size, true)
}

/// A log length as the protocol's `u32` index (logs never reach 2³² records in practice; the
/// index saturates rather than wraps if one did).
fn len_u32<T>(v: &[T]) -> u32 {
    u32::try_from(v.len()).unwrap_or(u32::MAX)
}
