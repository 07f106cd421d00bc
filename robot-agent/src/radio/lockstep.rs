//! The step protocol of a lock-stepped robot (`clock.mode = "lockstep"`), as pure bookkeeping;
//! [`crate::node`] drives it from zenoh. Every byte still crosses netem; what makes a run a
//! function of its scenario is *when* the robot acts on what arrived:
//!
//! 1. Step t starts once the robot holds the world's scan for t and netem's
//!    [`LinkPlan`](proto::msg::LinkPlan) for t (which links are up during t).
//! 2. The neighbours of t are exactly the plan's. A link that is new in the plan is used once
//!    its zenoh session is up: the peer's radio liveliness token is seen (after the token of an
//!    earlier session, cut by netem, has gone) and zenoh lists a session to the peer itself
//!    (a token can also arrive through a third robot).
//! 3. The robot decides, then sends its traffic of t to each neighbour as one frame
//!    ([`proto::msg::Frame`]), which ends with the step: its [`Mark`](crate::radio::station::Mark).
//! 4. It waits for the frame of t from every neighbour: then it holds everything they sent in
//!    t; nothing of t+1 can have come, because no robot gets the scan of t+1 before every robot
//!    sent its command for t, which each sends only now.
//! 5. It takes what arrived since its last step, sender by sender in id order (each sender's
//!    messages in the order sent), sends its command and telemetry for t. Answers that taking
//!    them produces (a handshake after a gap) go out with its traffic of t+1.
//!
//! So the world, netem's clock and every robot move together: a step's bytes cross netem within the
//! step, and the world advances only when every robot has taken its neighbours' traffic of the
//! step. If the world goes on without this robot (its step timed out), a newer scan arrives while
//! it waits, and it gives the step up
//! ([`Lockstep::newer_than`](crate::radio::lockstep::Lockstep::newer_than)).

use std::collections::{BTreeMap, BTreeSet};

use proto::msg::{LinkPlan, RobotId, Scan, Step};

use crate::radio::station::{Mark, Msg};

/// One robot's bookkeeping of the lockstep protocol.
#[derive(Debug, Default)]
pub struct Lockstep {
    scans: BTreeMap<Step, Scan>,
    plans: BTreeMap<Step, LinkPlan>,
    /// Per step, the neighbours whose marker of it arrived, and how many messages each said
    /// it sent before it.
    marks: BTreeMap<Step, BTreeMap<RobotId, u32>>,
    /// Received messages (markers aside) in the order they arrived, already counted and
    /// decoded; each with the step it is to be acted on in, once its marker came.
    inbox: Vec<(Option<Step>, Msg)>,
    /// Per sender, how many of its messages in `inbox` have no step yet (arrived since the
    /// last [`Lockstep::take`]): what the barrier compares with a marker's count, kept as
    /// messages come so that a check costs the neighbours, not the inbox.
    undated: BTreeMap<RobotId, usize>,
    /// Peers whose radio liveliness token is seen (a stale one aside).
    tokens: BTreeSet<RobotId>,
    /// Peers this robot has a zenoh session with itself (a token can also come through
    /// another peer).
    direct: BTreeSet<RobotId>,
    /// Peers whose session the plan cut while its token was seen: the token must go before a
    /// new one counts (the old session may not have noticed the cut yet).
    stale: BTreeSet<RobotId>,
}

impl Lockstep {
    pub fn on_scan(&mut self, scan: Scan) {
        self.scans.insert(scan.step, scan);
    }

    pub fn on_plan(&mut self, plan: LinkPlan) {
        self.plans.insert(plan.step, plan);
    }

    /// A radio message arrived: it waits to be taken.
    pub fn on_radio(&mut self, m: Msg) {
        *self.undated.entry(m.from()).or_default() += 1;
        self.inbox.push((None, m));
    }

    /// A neighbour's traffic of a step ended (its frame arrived, after its messages).
    pub fn on_mark(&mut self, m: Mark) {
        self.marks.entry(m.step).or_default().insert(m.from, m.sent);
    }

    /// A peer's radio liveliness token appeared (`up`) or vanished.
    pub fn on_token(&mut self, peer: RobotId, up: bool) {
        if up {
            if !self.stale.contains(&peer) {
                self.tokens.insert(peer);
            }
        } else {
            // The session went with its token: a new one must be listed again.
            self.stale.remove(&peer);
            self.tokens.remove(&peer);
            self.direct.remove(&peer);
        }
    }

    /// The peers this robot has a session with, as zenoh lists them now.
    pub fn on_sessions(&mut self, direct: BTreeSet<RobotId>) {
        self.direct = direct;
    }

    /// Whether the radio session to `peer` is up: its token is seen and the session is this
    /// robot's own.
    fn present(&self, peer: &RobotId) -> bool {
        self.tokens.contains(peer) && self.direct.contains(peer)
    }

    /// The newest step that can start: its scan and plan are both here.
    pub fn ready(&self) -> Option<Step> {
        self.scans
            .keys()
            .rev()
            .copied()
            .find(|s| self.plans.contains_key(s))
    }

    /// Starts step `t`: its scan and plan. Older scans, plans and markers are dropped, and so
    /// are messages still delayed on a link that is down in `t` (netem's reset took them).
    pub fn start(&mut self, me: RobotId, t: Step) -> Option<(Scan, LinkPlan)> {
        let scan = self.scans.remove(&t)?;
        let plan = self.plans.remove(&t)?;
        self.scans.retain(|&s, _| s > t);
        self.plans.retain(|&s, _| s > t);
        self.marks.retain(|&s, _| s >= t);
        self.inbox
            .retain(|(due, m)| due.is_none() || plan.link(me, m.from()).is_some());
        Some((scan, plan))
    }

    /// The plan cut the links to `peers`: a session to one of them that is still up is stale.
    pub fn cut(&mut self, peers: &[RobotId]) {
        for p in peers {
            if self.tokens.remove(p) {
                self.stale.insert(*p);
            }
        }
    }

    /// Whether a session is up to each of `peers`.
    pub fn linked(&self, peers: &[RobotId]) -> bool {
        peers.iter().all(|p| self.present(p))
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
            complete || !self.present(p)
        })
    }

    /// Messages from `peer` whose marker has not come yet.
    fn arrived_from(&self, peer: RobotId) -> usize {
        self.undated.get(&peer).copied().unwrap_or(0)
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

    /// Closes step `t` (its markers are in): what arrived in it is due `delay` steps later,
    /// the delay of the sender's link in `plan`; then takes what is due by `t` from links not
    /// held, sender by sender in id order, each sender's messages in arrival order.
    pub fn take(&mut self, me: RobotId, t: Step, plan: &LinkPlan) -> Vec<Msg> {
        // A link does not reorder: a message is never due before one its sender sent earlier
        // that still waits (a shorter delay does not let it overtake).
        let mut floor: BTreeMap<RobotId, Step> = BTreeMap::new();
        for (due, m) in &self.inbox {
            if let Some(d) = due {
                let f = floor.entry(m.from()).or_default();
                *f = (*f).max(*d);
            }
        }
        // Every message gets its step now.
        self.undated.clear();
        for (due, m) in &mut self.inbox {
            if due.is_none() {
                let from = m.from();
                let delay = plan.link(me, from).map_or(0, |l| l.delay_from(from));
                let f = floor.entry(from).or_default();
                *f = t.saturating_add(delay).max(*f);
                *due = Some(*f);
            }
        }
        let ready = |(due, m): &(Option<Step>, Msg)| {
            due.is_some_and(|d| d <= t) && plan.link(me, m.from()).is_some_and(|l| !l.held)
        };
        let (mut now, later): (Vec<_>, Vec<_>) =
            std::mem::take(&mut self.inbox).into_iter().partition(ready);
        self.inbox = later;
        now.sort_by_key(|(_, m)| m.from());
        now.into_iter().map(|(_, m)| m).collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proto::geom::Pose;
    use proto::msg::{Hello, MoveOutcome, PlannedLink};

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
            reset: true,
        })
    }

    fn mark(from: RobotId, step: Step, sent: u32) -> Mark {
        Mark { from, step, sent }
    }

    #[test]
    fn a_step_starts_with_its_scan_and_plan_and_the_barrier_needs_every_mark() {
        let mut l = Lockstep::default();
        l.on_scan(scan(3));
        assert_eq!(l.ready(), None, "no plan yet");
        l.on_plan(LinkPlan::plain(3, &[(0, 1), (0, 2), (1, 2)]));
        assert_eq!(l.ready(), Some(3));
        let (s, plan) = l.start(0, 3).expect("step 3");
        let nb = plan.neighbours(0);
        assert_eq!((s.step, nb.as_slice()), (3, [1, 2].as_slice()));
        assert!(!l.linked(&nb));
        l.on_token(1, true);
        l.on_token(2, true);
        assert!(!l.linked(&nb), "tokens seen, sessions not listed yet");
        l.on_sessions([1, 2].into());
        assert!(l.linked(&nb));
        // A marker of step 3 can come before the robot starts step 3; one of step 2 is old.
        l.on_mark(mark(1, 3, 0));
        l.on_mark(mark(2, 2, 0));
        assert!(!l.marked(3, &nb));
        // A marker that counts a message not yet here does not complete the step.
        l.on_mark(mark(2, 3, 1));
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
        l.on_mark(mark(1, 0, 2));
        let plan = LinkPlan::plain(0, &[(0, 3), (1, 3), (2, 3)]);
        let order: Vec<Msg> = l.take(3, 0, &plan);
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
        assert!(l.take(3, 0, &plan).is_empty());
    }

    #[test]
    fn a_delayed_link_hands_messages_over_late_in_order_and_a_cut_drops_them() {
        let mut l = Lockstep::default();
        // The delay from 1 to 0; the other way has none.
        let plan = |step, delay, held| LinkPlan {
            step,
            links: vec![PlannedLink {
                a: 0,
                b: 1,
                rate: [None, None],
                delay: [0, delay],
                held,
                credit: [None, None],
                proxy: None,
            }],
        };
        // Sent in step 0 over a delay of 2: acted on in step 2.
        l.on_radio(hello(1, 0));
        assert!(l.take(0, 0, &plan(0, 2, false)).is_empty());
        // Sent in step 1 with no delay: it may not overtake the first.
        l.on_radio(hello(1, 1));
        assert!(l.take(0, 1, &plan(1, 0, false)).is_empty());
        // Held in step 2: nothing is handed over until the link is released.
        assert!(l.take(0, 2, &plan(2, 0, true)).is_empty());
        assert_eq!(l.take(0, 3, &plan(3, 0, false)), [hello(1, 0), hello(1, 1)]);
        // A message still on the air when the link goes down is lost with it.
        l.on_radio(hello(1, 2));
        assert!(l.take(0, 4, &plan(4, 3, false)).is_empty());
        l.on_scan(scan(5));
        l.on_plan(LinkPlan::plain(5, &[]));
        l.start(0, 5).expect("step 5");
        l.on_plan(plan(6, 0, false));
        l.on_scan(scan(6));
        l.start(0, 6).expect("step 6");
        assert!(l.take(0, 6, &plan(6, 0, false)).is_empty());
    }

    #[test]
    fn a_cut_session_counts_again_only_after_its_token_went() {
        let mut l = Lockstep::default();
        l.on_sessions([1].into());
        l.on_token(1, true);
        l.cut(&[1]);
        assert!(!l.linked(&[1]));
        l.on_token(1, true);
        assert!(!l.linked(&[1]), "the old session's token, seen again");
        l.on_token(1, false);
        l.on_token(1, true);
        assert!(!l.linked(&[1]), "the new session is not listed yet");
        l.on_sessions([1].into());
        assert!(l.linked(&[1]));
    }

    mod counts {
        use super::*;
        use proptest::prelude::*;

        /// One thing that happens to a robot's lockstep bookkeeping.
        #[derive(Clone, Debug)]
        enum Op {
            Radio(RobotId),
            Start(Step),
            Take(Step),
        }

        fn op() -> impl Strategy<Value = Op> {
            prop_oneof![
                4 => (0u16..4).prop_map(Op::Radio),
                1 => (0u32..6).prop_map(Op::Start),
                1 => (0u32..6).prop_map(Op::Take),
            ]
        }

        proptest! {
            /// The barrier's kept count of a sender's undated messages is the inbox's.
            #[test]
            fn the_kept_count_is_the_inboxs(ops in prop::collection::vec(op(), 0..60)) {
                let mut l = Lockstep::default();
                let plan = |t| LinkPlan::plain(t, &[(0, 1), (0, 2), (0, 3)]);
                let mut n = 0;
                for o in ops {
                    match o {
                        Op::Radio(from) => {
                            n += 1;
                            l.on_radio(hello(from, n));
                        }
                        Op::Start(t) => {
                            l.on_scan(scan(t));
                            l.on_plan(plan(t));
                            l.start(0, t);
                        }
                        Op::Take(t) => {
                            l.take(0, t, &plan(t));
                        }
                    }
                    for p in 0..4 {
                        let counted = l
                            .inbox
                            .iter()
                            .filter(|(due, m)| due.is_none() && m.from() == p)
                            .count();
                        prop_assert_eq!(l.arrived_from(p), counted);
                    }
                }
            }
        }
    }
}
