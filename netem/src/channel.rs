//! The radio channel step by step, in lockstep with markers (docs/guide/radio.md): each step's
//! airtime shares on a shared channel ([`crate::airtime`]) and its lost frames ([`crate::radio`]'s
//! draws), which netem's step plan announces, and what the step that ends used of the channel.
//!
//! A step opens ([`Channel::open`](crate::channel::Channel::open)): the nodes that hear each other
//! (`shared`: all of them; `airtime`: those within interference range) and each sender's claim —
//! its demand, estimated from the step before (`Channel::demand`), and what it has in the air
//! already (frames it sends again, what it ran over its share). [`crate::airtime::allocate`] gives
//! each sender its airtime, [`crate::airtime::split`] divides it among its links, and each
//! direction of a link gets a credit: its share plus
//! [`MARK_RESERVE_BYTES`](proto::msg::MARK_RESERVE_BYTES), the frame's header that the robot always
//! sends (the step marker is the lockstep protocol's, not the radio's: a real radio would not send
//! it, so it costs no airtime). Each direction also draws whether its frame of the step is lost: a
//! lost frame is sent again — its receiver acts on it a step later (the plan's delay plus one) and
//! it costs its airtime again in the next step, before anybody's share.
//!
//! A direction saves the share it leaves unused, up to [`SAVE_STEPS`](proto::budget::SAVE_STEPS) of
//! its share or the largest message the exchange sends whole, whichever is more, and its credit is
//! its share plus what it saved: a message larger than one step's share (a raw scan among 30
//! senders) goes out after quiet steps, as a link layer would send it in fragments over them,
//! instead of never. What it spends of its savings runs over its share, and is paid back like any
//! overrun.
//!
//! A step closes ([`Channel::close`](crate::channel::Channel::close)) with the bytes netem counted:
//! a direction's airtime is its bytes less [`MARK_RESERVE_BYTES`](proto::msg::MARK_RESERVE_BYTES);
//! what it ran over its share is taken off the channel in the next step. netem does not hold bytes
//! back on a shared channel in lockstep (a held marker would stall the step); the robots keep to
//! their credits, and a sender that runs over pays it back.

use std::collections::BTreeMap;

use proto::budget::SAVE_STEPS;
use proto::msg::{NodeAir, RobotId, Step, MARK_RESERVE_BYTES};

use crate::airtime::{allocate, split, Claim};

use crate::radio::{delivery, lost};

/// A link direction: (from, to).
pub type Dir = (RobotId, RobotId);

/// How the channel is shared, from the scenario.
#[derive(Clone, Debug)]
pub struct ChannelConfig {
    /// Bytes the channel carries a step; `None`: links are not shared (`per-link`, or no rate).
    pub capacity: Option<f64>,
    /// `shared`: every node hears every other; `airtime`: the interference verdicts decide.
    pub everyone_hears: bool,
    pub frame_loss: f64,
    pub fading_db: f64,
    pub seed: u64,
    /// What a direction may save at the least, bytes: the largest message sent whole.
    pub save_min_bytes: f64,
}

/// A link as a step opens.
#[derive(Clone, Copy, Debug)]
pub struct OpenLink {
    pub a: RobotId,
    pub b: RobotId,
    /// Up and not held: its robots send on it.
    pub usable: bool,
    /// The signal above the threshold (path loss), for the fading.
    pub margin_db: Option<f64>,
}

/// One direction of a link in a step.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct DirAir {
    /// Its airtime share, bytes (`None`: the channel is not shared).
    pub share: Option<u32>,
    /// Airtime it saved in earlier steps and may spend on top of its share, bytes.
    pub saved: u32,
    /// Its frame of the step is lost (and sent again in the next).
    pub lost: bool,
    /// The probability that its frame is delivered.
    pub delivery: f64,
    /// Airtime it used (set when the step closes).
    pub airtime: u64,
}

/// A direction's state for the step that is open.
#[derive(Clone, Copy, Debug)]
struct Open {
    air: DirAir,
    share: f64,
}

/// The channel's state between steps.
#[derive(Debug)]
pub struct Channel {
    cfg: ChannelConfig,
    /// The step that is open, its nodes (id order) and who hears whom among them.
    step: Option<Step>,
    nodes: Vec<RobotId>,
    hears: Vec<Vec<usize>>,
    dirs: BTreeMap<Dir, Open>,
    /// Per node: airtime in the air before anybody's share in the open step (frames sent again,
    /// overrun) and the part of it that is frames sent again.
    preload: BTreeMap<RobotId, (f64, u64)>,
    /// Per direction, from the step that closed: (share, airtime used).
    last: BTreeMap<Dir, (f64, u64)>,
    /// Per direction: the share it left unused and may still spend, bytes.
    saved: BTreeMap<Dir, f64>,
    /// Per node, over the run (for `/metrics`).
    totals: BTreeMap<RobotId, NodeTotals>,
}

/// A node's use of the channel over the run, and in the last step closed.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct NodeTotals {
    pub airtime_bytes: u64,
    pub frames_lost: u64,
    pub retransmitted_bytes: u64,
    /// In the last step closed.
    pub share_bytes: u64,
    pub utilisation: f64,
}

impl Channel {
    pub fn new(cfg: ChannelConfig) -> Channel {
        Channel {
            cfg,
            step: None,
            nodes: Vec::new(),
            hears: Vec::new(),
            dirs: BTreeMap::new(),
            preload: BTreeMap::new(),
            last: BTreeMap::new(),
            saved: BTreeMap::new(),
            totals: BTreeMap::new(),
        }
    }

    /// Whether the channel does anything: a shared capacity or lossy frames. An idle channel
    /// opens and closes nothing (the links are as netem's budgets make them).
    pub fn active(&self) -> bool {
        let c = &self.cfg;
        c.capacity.is_some() || c.frame_loss > 0.0 || c.fading_db > 0.0
    }

    /// Each node's use of the channel so far (empty if the channel is idle).
    pub fn totals(&self) -> &BTreeMap<RobotId, NodeTotals> {
        &self.totals
    }

    /// The demand of direction `d` in the step that opens, bytes: all it gets if it is new or
    /// used (nearly) all its share in the step before — the robot had more to say than it could
    /// send — else what it used.
    fn demand(&self, d: Dir) -> f64 {
        match self.last.get(&d) {
            Some(&(share, used)) if (used as f64) < share - (64.0 + share / 8.0) => used as f64,
            _ => f64::INFINITY,
        }
    }

    /// Opens `step`: `nodes` are the live nodes (any order), `hear(a, b)` whether a and b
    /// interfere (asked once per pair, a < b, unless everyone hears everyone), `links` every
    /// link. Returns each usable direction's share and loss.
    pub fn open(
        &mut self,
        step: Step,
        nodes: &[RobotId],
        mut hear: impl FnMut(RobotId, RobotId) -> bool,
        links: &[OpenLink],
    ) -> BTreeMap<Dir, DirAir> {
        if !self.active() {
            return BTreeMap::new();
        }
        self.step = Some(step);
        let mut ids = nodes.to_vec();
        ids.sort_unstable();
        ids.dedup();
        let index: BTreeMap<RobotId, usize> =
            ids.iter().enumerate().map(|(i, &id)| (id, i)).collect();
        let n = ids.len();
        let hears = if self.cfg.capacity.is_some() {
            conflict_graph(&ids, self.cfg.everyone_hears, &mut hear)
        } else {
            vec![Vec::new(); n]
        };
        // Each node's directions that it sends on, in id order.
        let mut out: Vec<Vec<(Dir, f64)>> = vec![Vec::new(); n];
        let mut usable: Vec<(Dir, Option<f64>)> = Vec::new();
        for l in links.iter().filter(|l| l.usable) {
            for d in [(l.a, l.b), (l.b, l.a)] {
                if let Some(&i) = index.get(&d.0) {
                    out[i].push((d, self.demand(d)));
                    usable.push((d, l.margin_db));
                }
            }
        }
        for o in &mut out {
            o.sort_by_key(|(d, _)| *d);
        }
        let mut shares: BTreeMap<Dir, f64> = BTreeMap::new();
        if let Some(cap) = self.cfg.capacity {
            let claims: Vec<Claim> = (0..n)
                .map(|i| Claim {
                    demand: out[i].iter().map(|(_, d)| d).sum(),
                    preload: self.preload.get(&ids[i]).map_or(0.0, |p| p.0),
                    linked: !out[i].is_empty(),
                })
                .collect();
            let x = allocate(cap, &hears, &claims);
            for (i, o) in out.iter().enumerate() {
                let demands: Vec<f64> = o.iter().map(|(_, d)| *d).collect();
                for ((d, _), s) in o.iter().zip(split(x[i], &demands)) {
                    shares.insert(*d, s);
                }
            }
        }
        self.dirs.clear();
        for (d, margin) in usable {
            let p = delivery(self.cfg.frame_loss, self.cfg.fading_db, margin);
            let (a, b) = (d.0.min(d.1), d.0.max(d.1));
            let dir = usize::from(d.0 != a);
            let share = shares.get(&d).copied();
            self.dirs.insert(
                d,
                Open {
                    air: DirAir {
                        share: share.map(|s| s.floor() as u32),
                        saved: share
                            .map_or(0, |_| self.saved.get(&d).map_or(0, |&v| v.floor() as u32)),
                        lost: lost(self.cfg.seed, (a, b), dir, u64::from(step), p),
                        delivery: p,
                        airtime: 0,
                    },
                    share: share.unwrap_or(f64::INFINITY),
                },
            );
        }
        self.nodes = ids;
        self.hears = hears;
        self.dirs.iter().map(|(d, o)| (*d, o.air)).collect()
    }

    /// Closes the open step with the bytes netem counted on each direction: each direction's
    /// airtime, each node's use of the channel; what is in the air before the next step's
    /// shares. Returns the step's nodes (empty if no step is open).
    pub fn close(&mut self, bytes: &BTreeMap<Dir, u64>) -> (Vec<NodeAir>, BTreeMap<Dir, DirAir>) {
        let Some(_) = self.step.take() else {
            return (Vec::new(), BTreeMap::new());
        };
        let mut airtime: BTreeMap<RobotId, u64> = BTreeMap::new();
        let mut share: BTreeMap<RobotId, u64> = BTreeMap::new();
        let mut frames_lost: BTreeMap<RobotId, u32> = BTreeMap::new();
        let mut next: BTreeMap<RobotId, (f64, u64)> = BTreeMap::new();
        let mut saved: BTreeMap<Dir, f64> = BTreeMap::new();
        // What a node had in the air before its share beyond one step's capacity is still owed.
        if let Some(cap) = self.cfg.capacity {
            for (id, (pre, _)) in &self.preload {
                if *pre > cap {
                    next.entry(*id).or_default().0 += pre - cap;
                }
            }
        }
        self.last.clear();
        for (d, o) in &mut self.dirs {
            let used = bytes
                .get(d)
                .map_or(0, |b| b.saturating_sub(u64::from(MARK_RESERVE_BYTES)));
            o.air.airtime = used;
            *airtime.entry(d.0).or_default() += used;
            *share.entry(d.0).or_default() += u64::from(o.air.share.unwrap_or(0));
            let carry = next.entry(d.0).or_default();
            if o.air.lost {
                *frames_lost.entry(d.0).or_default() += 1;
                carry.0 += used as f64;
                carry.1 += used;
            }
            if o.share.is_finite() {
                carry.0 += (used as f64 - o.share).max(0.0);
                let most = (f64::from(SAVE_STEPS) * o.share).max(self.cfg.save_min_bytes);
                let had = self.saved.get(d).copied().unwrap_or(0.0);
                let left = (had + o.share - used as f64).clamp(0.0, most);
                saved.insert(*d, left);
            }
            self.last.insert(*d, (o.share, used));
        }
        // A direction that is not usable any more forgets what it saved.
        self.saved = saved;
        // Frames sent again in this step took the air too.
        for (id, (_, again)) in &self.preload {
            *airtime.entry(*id).or_default() += again;
        }
        let cap = self.cfg.capacity;
        let nodes: Vec<NodeAir> = (self.nodes.iter().enumerate())
            .map(|(i, &id)| {
                let heard: u64 = std::iter::once(i)
                    .chain(self.hears[i].iter().copied())
                    .map(|u| airtime.get(&self.nodes[u]).copied().unwrap_or(0))
                    .sum();
                NodeAir {
                    id,
                    share: share.get(&id).copied().unwrap_or(0),
                    airtime: airtime.get(&id).copied().unwrap_or(0),
                    utilisation: cap.map_or(0.0, |c| heard as f64 / c) as f32,
                    frames_lost: frames_lost.get(&id).copied().unwrap_or(0),
                    retransmitted: self.preload.get(&id).map_or(0, |p| p.1),
                }
            })
            .collect();
        for n in &nodes {
            let t = self.totals.entry(n.id).or_default();
            t.airtime_bytes += n.airtime;
            t.frames_lost += u64::from(n.frames_lost);
            t.retransmitted_bytes += n.retransmitted;
            t.share_bytes = n.share;
            t.utilisation = f64::from(n.utilisation);
        }
        self.preload = next.into_iter().filter(|(_, p)| p.0 > 0.0).collect();
        let dirs = self.dirs.iter().map(|(d, o)| (*d, o.air)).collect();
        (nodes, dirs)
    }
}
/// Who hears whom among `ids` (indices into it), each pair asked once unless everyone hears
/// everyone.
fn conflict_graph(
    ids: &[RobotId],
    everyone_hears: bool,
    hear: &mut impl FnMut(RobotId, RobotId) -> bool,
) -> Vec<Vec<usize>> {
    let n = ids.len();
    let mut hears = vec![Vec::new(); n];
    for i in 0..n {
        for j in i + 1..n {
            if everyone_hears || hear(ids[i], ids[j]) {
                hears[i].push(j);
                hears[j].push(i);
            }
        }
    }
    hears
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    /// A channel of `capacity` bytes a step where everyone hears everyone.
    fn shared(capacity: f64) -> Channel {
        Channel::new(ChannelConfig {
            capacity: Some(capacity),
            everyone_hears: true,
            frame_loss: 0.0,
            fading_db: 0.0,
            seed: 1,
            save_min_bytes: 740.0,
        })
    }

    /// Links between every two of `n` nodes, all usable.
    fn mesh(n: u16) -> Vec<OpenLink> {
        let mut v = Vec::new();
        for a in 0..n {
            for b in a + 1..n {
                v.push(OpenLink {
                    a,
                    b,
                    usable: true,
                    margin_db: None,
                });
            }
        }
        v
    }

    /// A message larger than a step's share (740 B over 83 B shares: 4 nodes on 1 000 B, each
    /// split over three links) goes out after quiet steps instead of never, and what it spent
    /// of its savings it no longer has.
    #[test]
    fn a_message_larger_than_a_share_goes_after_quiet_steps() {
        let mut ch = shared(1000.0);
        let nodes = [0, 1, 2, 3];
        let links = mesh(4);
        let mut waited = 0;
        loop {
            let air = ch.open(waited, &nodes, |_, _| true, &links);
            let d = air[&(0, 1)];
            assert!(d.share.unwrap() <= 84, "{d:?}");
            if d.share.unwrap() + d.saved >= 740 {
                // It sends the message now; everybody else sends their whole share.
                let bytes: BTreeMap<Dir, u64> = air
                    .iter()
                    .map(|(k, v)| {
                        let used = if *k == (0, 1) {
                            740
                        } else {
                            u64::from(v.share.unwrap())
                        };
                        (*k, used + u64::from(MARK_RESERVE_BYTES))
                    })
                    .collect();
                ch.close(&bytes);
                break;
            }
            // Quiet on (0, 1), the others busy.
            let bytes: BTreeMap<Dir, u64> = air
                .iter()
                .filter(|(k, _)| **k != (0, 1))
                .map(|(k, v)| (*k, u64::from(v.share.unwrap() + MARK_RESERVE_BYTES)))
                .collect();
            ch.close(&bytes);
            waited += 1;
            assert!(waited < 30, "still waiting after {waited} steps");
        }
        // 740 / 83 = 9 steps at the share it had; a direction that saves looks idle to the
        // demand estimate, so its busy siblings take more of its node's share meanwhile.
        assert!((9..=20).contains(&waited), "{waited} steps");
        let air = ch.open(waited + 1, &nodes, |_, _| true, &links);
        assert!(air[&(0, 1)].saved < 100, "{:?}", air[&(0, 1)]);
        // The node ran over: the others' shares are smaller for it this step.
        let others: u32 = (air.iter().filter(|(k, _)| k.0 != 0))
            .map(|(_, v)| v.share.unwrap())
            .sum();
        assert!(f64::from(others) < 750.0 - 100.0, "{others}");
    }

    proptest! {
        /// Whatever the robots send within their credits, a direction's savings stay within
        /// their cap, and over the run the channel carries no more than its capacity a step
        /// plus what the nodes may still owe (their savings spent, not yet paid back).
        #[test]
        fn savings_stay_capped_and_the_channel_keeps_its_capacity(
            uses in proptest::collection::vec(proptest::collection::vec(0.0f64..=1.0, 12), 1..60),
        ) {
            let cap = 1000.0;
            let mut ch = shared(cap);
            let nodes = [0, 1, 2, 3];
            let links = mesh(4);
            let mut total = 0u64;
            for (step, u) in uses.iter().enumerate() {
                let air = ch.open(step as Step, &nodes, |_, _| true, &links);
                let mut bytes = BTreeMap::new();
                for ((d, a), f) in air.iter().zip(u) {
                    let share = f64::from(a.share.unwrap());
                    prop_assert!(f64::from(a.saved) <= (f64::from(SAVE_STEPS) * (share + 1.0)).max(740.0));
                    let used = (f * f64::from(a.share.unwrap() + a.saved)).floor() as u64;
                    total += used;
                    bytes.insert(*d, used + u64::from(MARK_RESERVE_BYTES));
                }
                ch.close(&bytes);
            }
            let steps = uses.len() as f64;
            let owed: f64 = ch.preload.values().map(|p| p.0).sum();
            prop_assert!(
                total as f64 <= steps * cap + owed + 12.0 * 740.0,
                "{total} bytes in {steps} steps, {owed} owed"
            );
        }
    }
}
