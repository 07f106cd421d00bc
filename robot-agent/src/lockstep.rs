//! The step protocol of a lock-stepped robot (`clock.mode = "lockstep"`), as pure bookkeeping;
//! [`crate::node`] drives it from zenoh. Every byte still crosses netem; what makes a run a
//! function of its scenario is *when* the robot acts on what arrived:
//!
//! 1. Step t starts once the robot holds the world's scan for t and netem's [`LinkPlan`] for t
//!    (which links are up during t).
//! 2. The neighbours of t are exactly the plan's. A link that is new in the plan is used once
//!    its zenoh session is up (the peer's radio liveliness token is seen — after the token of
//!    an earlier session, cut by netem, has gone).
//! 3. The robot decides, then sends its traffic of t and last a [`Mark`] of t to each neighbour.
//! 4. It waits for the mark of t from every neighbour. One link is one ordered stream, so by then
//!    it holds everything they sent in t; nothing of t+1 can have come, because no robot gets
//!    the scan of t+1 before every robot sent its command for t, which each sends only now.
//! 5. It takes what arrived since its last step, sender by sender in id order (each sender's
//!    messages in the order sent), sends its command and telemetry for t. Answers that taking
//!    them produces (a handshake after a gap) go out with its traffic of t+1.
//!
//! So the world, netem's clock and every robot move together: a step's bytes cross netem
//! within the step, and the world advances only when every robot has taken its neighbours'
//! traffic of the step. If the world goes on without this robot (its step timed out), a newer
//! scan arrives while it waits, and it gives the step up ([`Lockstep::newer_than`]).

use std::collections::{BTreeMap, BTreeSet};

use proto::msg::{LinkPlan, RobotId, Scan, Step};

use crate::radio::Msg;

/// One robot's bookkeeping of the lockstep protocol.
#[derive(Debug, Default)]
pub struct Lockstep {
    scans: BTreeMap<Step, Scan>,
    plans: BTreeMap<Step, LinkPlan>,
    /// Per step, the neighbours whose marker of it arrived, and how many messages each said
    /// it sent before it.
    marks: BTreeMap<Step, BTreeMap<RobotId, u32>>,
    /// Received messages (markers aside) in the order they arrived, already counted and
    /// decoded.
    inbox: Vec<Msg>,
    /// Peers whose radio session is up (their liveliness token is seen).
    present: BTreeSet<RobotId>,
    /// Peers whose session the plan cut while it was up: their token must go before a new one
    /// counts (the old session may not have noticed the cut yet).
    stale: BTreeSet<RobotId>,
}

impl Lockstep {
    pub fn on_scan(&mut self, scan: Scan) {
        self.scans.insert(scan.step, scan);
    }

    pub fn on_plan(&mut self, plan: LinkPlan) {
        self.plans.insert(plan.step, plan);
    }

    /// A radio message arrived: a marker is noted, anything else waits to be taken.
    pub fn on_radio(&mut self, m: Msg) {
        match m {
            Msg::Mark(m) => {
                self.marks.entry(m.step).or_default().insert(m.from, m.sent);
            }
            m => self.inbox.push(m),
        }
    }

    /// A peer's radio liveliness token appeared (`up`) or vanished.
    pub fn on_token(&mut self, peer: RobotId, up: bool) {
        if up {
            if !self.stale.contains(&peer) {
                self.present.insert(peer);
            }
        } else {
            self.stale.remove(&peer);
            self.present.remove(&peer);
        }
    }

    /// The newest step that can start: its scan and plan are both here.
    pub fn ready(&self) -> Option<Step> {
        self.scans
            .keys()
            .rev()
            .copied()
            .find(|s| self.plans.contains_key(s))
    }

    /// Starts step `t`: its scan and this robot's neighbours in it. Older scans, plans and
    /// markers are dropped.
    pub fn start(&mut self, me: RobotId, t: Step) -> Option<(Scan, Vec<RobotId>)> {
        let scan = self.scans.remove(&t)?;
        let plan = self.plans.remove(&t)?;
        self.scans.retain(|&s, _| s > t);
        self.plans.retain(|&s, _| s > t);
        self.marks.retain(|&s, _| s >= t);
        Some((scan, plan.neighbours(me)))
    }

    /// The plan cut the links to `peers`: a session to one of them that is still up is stale.
    pub fn cut(&mut self, peers: &[RobotId]) {
        for p in peers {
            if self.present.remove(p) {
                self.stale.insert(*p);
            }
        }
    }

    /// Whether a session is up to each of `peers`.
    pub fn linked(&self, peers: &[RobotId]) -> bool {
        peers.iter().all(|p| self.present.contains(p))
    }

    /// Whether each of `peers` sent its marker of step `t` and every message it counted before
    /// it has arrived (messages of a link may overtake each other inside zenoh), or lost its
    /// session (then nothing more can come from it in this step).
    pub fn marked(&self, t: Step, peers: &[RobotId]) -> bool {
        let got = self.marks.get(&t);
        peers.iter().all(|p| {
            let complete = got
                .and_then(|g| g.get(p))
                .is_some_and(|&sent| self.arrived_from(*p) >= sent as usize);
            complete || !self.present.contains(p)
        })
    }

    /// Messages from `peer` waiting to be taken.
    fn arrived_from(&self, peer: RobotId) -> usize {
        self.inbox.iter().filter(|m| m.from() == peer).count()
    }

    /// The neighbours among `peers` whose marker of `t` did not come (their session was lost).
    pub fn unmarked(&self, t: Step, peers: &[RobotId]) -> Vec<RobotId> {
        let got = self.marks.get(&t);
        peers
            .iter()
            .copied()
            .filter(|p| !got.is_some_and(|g| g.contains_key(p)))
            .collect()
    }

    /// Whether the world went on past step `t` (a scan of a later step is here).
    pub fn newer_than(&self, t: Step) -> bool {
        self.scans.keys().any(|&s| s > t)
    }

    /// What arrived since the last take, sender by sender in id order, each sender's messages
    /// in arrival order.
    pub fn take(&mut self) -> Vec<Msg> {
        let mut all = std::mem::take(&mut self.inbox);
        all.sort_by_key(Msg::from);
        all
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proto::geom::Pose;
    use proto::msg::{Hello, Mark, MoveOutcome};

    fn scan(step: Step) -> Scan {
        Scan {
            step,
            pose: Pose::default(),
            ranges: Vec::new(),
            last_move: MoveOutcome::Start,
        }
    }

    /// A message from `from`, told apart by `n`.
    fn hello(from: RobotId, n: u32) -> Msg {
        Msg::Hello(Hello {
            from,
            knowledge: vec![(from, n)],
        })
    }

    fn mark(from: RobotId, step: Step, sent: u32) -> Msg {
        Msg::Mark(Mark { from, step, sent })
    }

    #[test]
    fn a_step_starts_with_its_scan_and_plan_and_the_barrier_needs_every_mark() {
        let mut l = Lockstep::default();
        l.on_scan(scan(3));
        assert_eq!(l.ready(), None, "no plan yet");
        l.on_plan(LinkPlan {
            step: 3,
            up: vec![(0, 1), (0, 2), (1, 2)],
        });
        assert_eq!(l.ready(), Some(3));
        let (s, nb) = l.start(0, 3).expect("step 3");
        assert_eq!((s.step, nb.as_slice()), (3, [1, 2].as_slice()));
        assert!(!l.linked(&nb));
        l.on_token(1, true);
        l.on_token(2, true);
        assert!(l.linked(&nb));
        // A marker of step 3 can come before the robot starts step 3; one of step 2 is old.
        l.on_radio(mark(1, 3, 0));
        l.on_radio(mark(2, 2, 0));
        assert!(!l.marked(3, &nb));
        // A marker that counts a message not yet here does not complete the step.
        l.on_radio(mark(2, 3, 1));
        assert!(!l.marked(3, &nb));
        l.on_radio(hello(2, 0));
        assert!(l.marked(3, &nb));
        // A lost session ends the wait for that neighbour too.
        l.on_token(2, false);
        assert!(l.marked(4, &[2]));
    }

    #[test]
    fn arrivals_are_taken_by_sender_then_in_arrival_order() {
        let mut l = Lockstep::default();
        for (from, n) in [(2, 0), (1, 1), (2, 2), (0, 3), (1, 4)] {
            l.on_radio(hello(from, n));
        }
        l.on_radio(mark(1, 0, 2));
        let order: Vec<Msg> = l.take();
        assert_eq!(
            order,
            [
                hello(0, 3),
                hello(1, 1),
                hello(1, 4),
                hello(2, 0),
                hello(2, 2)
            ]
        );
        assert!(l.take().is_empty());
    }

    #[test]
    fn a_cut_session_counts_again_only_after_its_token_went() {
        let mut l = Lockstep::default();
        l.on_token(1, true);
        l.cut(&[1]);
        assert!(!l.linked(&[1]));
        l.on_token(1, true);
        assert!(!l.linked(&[1]), "the old session's token, seen again");
        l.on_token(1, false);
        l.on_token(1, true);
        assert!(l.linked(&[1]));
    }
}
