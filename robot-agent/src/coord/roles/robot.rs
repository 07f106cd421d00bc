//! `roles` (de Hoog, Cameron & Visser, "Autonomous multi-robot exploration in
//! communication-limited environments", TAROS 2010): explorers explore beyond radio range and
//! come back to agreed rendezvous points; relays ferry what they learn to the base station and
//! back; robots that meet swap roles when that shortens their ways.
//!
//! * The hierarchy, the roster of who holds which place, and the role swap rule:
//!   [`crate::coord::roles::hierarchy`]. Where and by when a child meets its parent:
//!   [`crate::coord::roles::rendezvous`].
//! * The state machines of Fig. 2 ([`explorer_next`](crate::coord::roles::robot::explorer_next),
//!   [`relay_next`](crate::coord::roles::robot::relay_next)), pure functions of what the robot
//!   senses this step ([`Sense`](crate::coord::roles::robot::Sense)):
//!   - explorer: `Explore` until the time left before the rendezvous is the trip back to it,
//!     then `Return`, `Wait` at the point, and `Deliver` once the parent is in range (it stays
//!     until what it carries has crossed, at most `linger_steps`). A parent that has not come
//!     `patience_steps` after the agreed step sends it to the `Fallback` point, then back to
//!     exploring with a new deadline one trip later. A chance meeting on the way (the parent
//!     comes into range earlier) delivers and agrees again at once.
//!   - relay: `ToChild` (to the rendezvous, and waiting there), a fresh agreement from the child
//!     in range sends it `ToParent`; it `Deliver`s to its parent (the base station, or the relay
//!     above) and goes back `ToChild`. A child that has not come by `patience_steps` after the
//!     agreed step sends it to the `Fallback` point, then to its parent with what it has. A
//!     relay in range of both its parent and its child stays where it is: the chain is
//!     connected, the radio carries everything.
//! * Agreements: the child agrees the next rendezvous whenever it comes into range of its parent
//!   and every `refresh_steps` while in range; the parent takes the newest.
//! * Swaps (§V, `swap = true`): of two robots in range, the lower id evaluates the rule on its
//!   own map and proposes with its state; the other takes that state and answers with its own,
//!   which the proposer then takes. Rosters carry the new places to the rest of the team. An
//!   answer that never arrives is repaired by the roster: a robot that hears a newer claim of
//!   itself elsewhere takes that place.
//!
//! Knowledge crosses only where the radio carries it: the strategy decides where robots go; the
//! map exchange (`exchange.mode`) moves the maps between whoever is in range.

use std::collections::BTreeMap;

use proto::geom::Metres;
use proto::grid::Cell;
use proto::msg::{Phase, Place, RobotId, Role as RoleMsg, RoleState, Step, Swap, WorldInfo};
use proto::scenario::Scenario;

use crate::coord::roles::hierarchy::{swap_pays, Role, Roster, Shape};
use crate::coord::roles::rendezvous::{self, Agreeing, Meeting};
use crate::coord::{
    decentralized, Addressed, CoordMsg, Coordinator, Params, Situation, Status, To,
};
use crate::nav::plan;
use crate::radio::reach::Reach;

/// A robot's message older than this (steps) is not acted on for an agreement.
const FRESH_STEPS: Step = 2;

/// A swap proposal not answered within this many steps is given up.
const PROPOSAL_STEPS: Step = 3;

/// The `roles` settings in cells and steps.
#[derive(Clone, Debug)]
pub struct Settings {
    pub shape: Shape,
    pub swap: bool,
    pub agreeing: Agreeing,
    pub timing: Timing,
    pub refresh: Step,
    pub status_every: Step,
    /// The base station's cell if the scenario places it (else: where this robot started).
    pub base_cell: Option<Cell>,
    /// The frontier choice of explorers (decentralized, with heard targets).
    pub params: Params,
}

/// Waiting limits of the state machines.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Timing {
    pub patience: Step,
    pub linger: Step,
}

impl Settings {
    pub fn new(s: &Scenario, world: &WorldInfo, params: Params) -> Settings {
        let r = &s.coordination.roles;
        let res = world.map.resolution_m;
        Settings {
            shape: Shape::new(s.robots.count, r.relays_per_branch),
            swap: r.swap,
            agreeing: Agreeing {
                candidates: r.candidates as usize,
                fill_cells: r.fill_m / res,
                prune_cells: r.prune_m / res,
                cells_per_step: world.max_speed_m_per_s * world.step_seconds / res,
                reach: Reach::new(s, res),
            },
            timing: Timing {
                patience: r.patience_steps,
                linger: r.linger_steps,
            },
            refresh: r.refresh_steps.max(1),
            status_every: r.status_every_steps.max(1),
            base_cell: s
                .base_station
                .pose
                .map(|[x, y]| world.map.cell_of(Metres::new(x, y))),
            params,
        }
    }
}

/// What a robot senses this step, for its state machine.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Sense {
    pub step: Step,
    /// Its parent (a robot, or the base station) is in radio range ...
    pub parent_met: bool,
    /// ... and was not at the last step.
    pub parent_met_new: bool,
    /// Nothing of its own waits for the parent on the radio.
    pub parent_caught_up: bool,
    /// Relay: its child is in range.
    pub child_met: bool,
    /// Relay: the child says nothing of its waits for this robot.
    pub child_caught_up: bool,
    /// Relay: the child agreed a rendezvous since the relay last left it, `fresh_for` steps ago.
    pub fresh: bool,
    pub fresh_for: Step,
    /// It stands at (within a step of) the point its phase heads for.
    pub at_goal: bool,
    /// That point is reachable on its map.
    pub reachable: bool,
    /// Explorer: the trip back to the rendezvous takes the time left, or nothing is left to
    /// explore.
    pub return_now: bool,
}

/// The explorer's next phase (Fig. 2), in phase `phase` since `since`, the rendezvous due at
/// `due`.
pub fn explorer_next(phase: Phase, since: Step, due: Option<Step>, i: &Sense, t: &Timing) -> Phase {
    let coming_back = matches!(phase, Phase::Return | Phase::Wait | Phase::Fallback);
    if i.parent_met && (coming_back || (i.parent_met_new && phase == Phase::Explore)) {
        return Phase::Deliver;
    }
    match phase {
        Phase::Deliver => {
            if !i.parent_met || i.parent_caught_up || i.step >= since.saturating_add(t.linger) {
                Phase::Explore
            } else {
                Phase::Deliver
            }
        }
        Phase::Explore if i.return_now && !i.parent_met => Phase::Return,
        Phase::Return if !i.reachable => Phase::Fallback,
        Phase::Return if i.at_goal => Phase::Wait,
        Phase::Wait => match due {
            Some(d) if i.step <= d.saturating_add(t.patience) => Phase::Wait,
            _ => Phase::Fallback,
        },
        Phase::Fallback if fallback_done(since, i, t) => Phase::Explore,
        // A relay's phases mean nothing to an explorer (after a swap they are replaced).
        Phase::ToParent | Phase::ToChild => Phase::Explore,
        p => p,
    }
}

/// The relay's next phase (Fig. 2), as [`explorer_next`].
pub fn relay_next(phase: Phase, since: Step, due: Option<Step>, i: &Sense, t: &Timing) -> Phase {
    let leave_child = i.child_met && i.fresh && (i.child_caught_up || i.fresh_for >= t.linger);
    match phase {
        Phase::ToParent if i.parent_met => Phase::Deliver,
        Phase::Deliver => {
            if !i.parent_met || i.parent_caught_up || i.step >= since.saturating_add(t.linger) {
                Phase::ToChild
            } else {
                Phase::Deliver
            }
        }
        Phase::ToChild | Phase::Fallback if leave_child => Phase::ToParent,
        Phase::ToChild => match due {
            Some(d) if !i.child_met && i.at_goal && i.step > d.saturating_add(t.patience) => {
                Phase::Fallback
            }
            _ => Phase::ToChild,
        },
        Phase::Fallback if fallback_done(since, i, t) => Phase::ToParent,
        Phase::Explore | Phase::Return | Phase::Wait => Phase::ToChild,
        p => p,
    }
}

/// A robot at the fallback point has waited there long enough (or could not get there).
fn fallback_done(since: Step, i: &Sense, t: &Timing) -> bool {
    let waited = i.step >= since.saturating_add(t.patience.saturating_mul(2));
    let stuck = i.step >= since.saturating_add(t.patience.saturating_mul(4));
    (i.at_goal && waited) || stuck || !i.reachable
}

/// The `roles` strategy of one robot.
pub struct Roles {
    me: RobotId,
    base: RobotId,
    st: Settings,
    state: RoleState,
    roster: Roster,
    /// The last message heard from each robot.
    heard: BTreeMap<RobotId, RoleMsg>,
    swaps_in: Vec<(RobotId, Swap)>,
    /// The frontier the explorer goes to while exploring.
    frontier: Option<Cell>,
    goal: Option<Cell>,
    step: Step,
    base_cell: Option<Cell>,
    parent_was_met: bool,
    /// Relay: the `made` of the child's agreement when it last left the child, and when the
    /// newest agreement arrived.
    delivered: Option<Step>,
    fresh_since: Step,
    /// This robot's open proposal: to whom, at which step.
    pending: Option<(RobotId, Step)>,
    /// An answer to send: to whom, the proposal's step, the state handed over.
    answer: Option<(RobotId, Step, RoleState)>,
    last_swap: Option<Step>,
    /// Per neighbour, the step of its message last weighed for a swap: each message is
    /// weighed once, so the neighbour's cost field is computed only when it says something new.
    weighed: BTreeMap<RobotId, Step>,
    /// Per neighbour, the last message sent (step, and the message with step and cell cleared).
    sent: BTreeMap<RobotId, (Step, RoleMsg)>,
    backlog: Vec<(RobotId, u64)>,
}

impl Roles {
    pub fn new(me: RobotId, base: RobotId, st: Settings) -> Roles {
        let seats = st.shape.dealt();
        let place = seats.iter().find(|s| s.robot == me).map_or(
            Place {
                branch: 0,
                depth: 0,
            },
            |s| s.place,
        );
        let phase = match st.shape.role(place) {
            Role::Explorer => Phase::Explore,
            Role::Relay => Phase::ToChild,
        };
        Roles {
            me,
            base,
            state: RoleState {
                place,
                phase,
                since: 0,
                with_parent: None,
                with_child: None,
            },
            roster: Roster::new(&seats),
            base_cell: st.base_cell,
            st,
            heard: BTreeMap::new(),
            swaps_in: Vec::new(),
            frontier: None,
            goal: None,
            step: 0,
            parent_was_met: false,
            delivered: None,
            fresh_since: 0,
            pending: None,
            answer: None,
            last_swap: None,
            weighed: BTreeMap::new(),
            sent: BTreeMap::new(),
            backlog: Vec::new(),
        }
    }

    pub fn state(&self) -> &RoleState {
        &self.state
    }

    fn role(&self) -> Role {
        self.st.shape.role(self.state.place)
    }

    /// The robot (or base station) above this one.
    fn parent(&self) -> Option<RobotId> {
        match self.st.shape.parent(self.state.place) {
            None => Some(self.base),
            Some(p) => self.roster.at(p),
        }
    }

    fn child(&self) -> Option<RobotId> {
        self.st
            .shape
            .child(self.state.place)
            .and_then(|c| self.roster.at(c))
    }

    /// A message from `robot` no older than [`FRESH_STEPS`].
    fn fresh(&self, robot: RobotId) -> Option<&RoleMsg> {
        self.recent(robot, FRESH_STEPS)
    }

    /// A message from `robot` no older than `steps`.
    fn recent(&self, robot: RobotId, steps: Step) -> Option<&RoleMsg> {
        self.heard
            .get(&robot)
            .filter(|m| self.step.saturating_sub(m.step) <= steps)
    }

    /// Where this robot meets its parent: the base station's cell, or the agreed rendezvous.
    fn parent_point(&self) -> Option<Cell> {
        if self.st.shape.parent(self.state.place).is_none() {
            return self.base_cell;
        }
        self.state.with_parent.map(|r| match self.state.phase {
            Phase::Fallback if self.role() == Role::Explorer => r.fallback,
            _ => r.primary,
        })
    }

    fn set_phase(&mut self, phase: Phase) {
        if phase != self.state.phase {
            tracing::debug!(
                "robot {} step {}: {:?} {:?} -> {:?} (parent {:?}, child {:?})",
                self.me,
                self.step,
                self.state.place,
                self.state.phase,
                phase,
                self.state.with_parent,
                self.state.with_child
            );
            self.state.phase = phase;
            self.state.since = self.step;
        }
    }

    /// Takes a place handed over (a swap, or a newer claim of this robot in the roster).
    fn take(&mut self, state: RoleState, since: Step) {
        self.state = RoleState {
            since: self.step,
            ..state
        };
        self.roster.set(self.me, state.place, since);
        self.frontier = None;
        self.delivered = None;
        self.last_swap = Some(self.step);
    }

    /// Swap messages heard since the last step, and a roster that says this robot was moved.
    fn settle_swaps(&mut self) {
        for (from, swap) in std::mem::take(&mut self.swaps_in) {
            match swap {
                Swap::Accept { to, stamp, state }
                    if to == self.me && self.pending == Some((from, stamp)) =>
                {
                    let mine = self.state.place;
                    self.take(state, stamp + 1);
                    self.roster.set(from, mine, stamp + 1);
                    self.pending = None;
                }
                Swap::Propose { to, stamp, state } if to == self.me => {
                    let cooled = self
                        .last_swap
                        .is_none_or(|l| self.step >= l.saturating_add(self.st.timing.patience));
                    let known =
                        self.st.shape.contains(state.place) && state.place != self.state.place;
                    if self.st.swap && self.pending.is_none() && cooled && known {
                        let mine = self.state;
                        self.take(state, stamp + 1);
                        self.roster.set(from, mine.place, stamp + 1);
                        self.answer = Some((from, stamp, mine));
                    }
                }
                _ => {}
            }
        }
        if let Some((_, at)) = self.pending {
            if self.step > at.saturating_add(PROPOSAL_STEPS) {
                self.pending = None;
            }
        }
        // A swap partner whose answer never arrived has told the others where this robot went.
        if let Some(seat) = self.roster.seat(self.me).copied() {
            if seat.place != self.state.place && self.st.shape.contains(seat.place) {
                let phase = match self.st.shape.role(seat.place) {
                    Role::Explorer => Phase::Explore,
                    Role::Relay => Phase::ToParent,
                };
                let state = RoleState {
                    place: seat.place,
                    phase,
                    since: self.step,
                    with_parent: None,
                    with_child: None,
                };
                self.take(state, seat.since);
                self.pending = None;
            }
        }
    }

    /// The child agrees the next rendezvous when it comes into range of its parent relay and
    /// every `refresh` steps while in range.
    fn agree(&mut self, s: &Situation<'_>, parent: RobotId, met_new: bool) {
        if parent == self.base {
            return;
        }
        let Some(p) = self.fresh(parent).cloned() else {
            return;
        };
        let due_again = self
            .state
            .with_parent
            .is_none_or(|r| s.step >= r.made.saturating_add(self.st.refresh));
        if !(met_new || due_again) {
            return;
        }
        let Some(parent_point) = p.parent_point else {
            return;
        };
        let toward = match self.role() {
            Role::Explorer => self.frontier.unwrap_or(s.me),
            Role::Relay => {
                let child_point = self.state.with_child.map_or(s.me, |r| r.primary);
                rendezvous::midway(&plan::costs(s.grid, parent_point), child_point).unwrap_or(s.me)
            }
        };
        let m = Meeting {
            step: s.step,
            toward,
            parent_at: p.cell,
            parent_point,
        };
        if let Some(r) = rendezvous::agree(s.grid, s.costs, &m, &self.st.agreeing) {
            self.state.with_parent = Some(r);
        }
    }

    /// The explorer's frontier: kept while it is a usable frontier, else the decentralized
    /// choice.
    fn pick_frontier(&mut self, s: &Situation<'_>) {
        if self.frontier.is_some_and(|f| s.candidates.contains(&f)) {
            return;
        }
        let others: Vec<(Cell, f64)> = s
            .heard
            .iter()
            .filter_map(|(_, a)| Some((a.target?, f64::from(s.step.saturating_sub(a.step)))))
            .collect();
        self.frontier =
            decentralized::target(s.grid, s.candidates, s.costs, &others, &self.st.params);
    }

    /// The point the current phase heads for (`None`: nowhere to go).
    fn goal_of(&self, s: &Situation<'_>) -> Option<Cell> {
        let st = &self.state;
        match (self.role(), st.phase) {
            (_, Phase::Deliver) => Some(s.me),
            (Role::Explorer, Phase::Explore) => self.frontier,
            (Role::Explorer, Phase::Return | Phase::Wait) => st.with_parent.map(|r| r.primary),
            (Role::Explorer, Phase::Fallback) => st.with_parent.map(|r| r.fallback),
            (Role::Relay, Phase::ToParent) => self.parent_point().or_else(|| {
                let parent = self.parent()?;
                self.heard.get(&parent).map(|h| h.cell)
            }),
            (Role::Relay, Phase::Fallback) => st.with_child.map(|r| r.fallback),
            (Role::Relay, _) => st.with_child.map(|r| r.primary).or_else(|| {
                self.child()
                    .and_then(|c| self.heard.get(&c))
                    .map(|h| h.cell)
            }),
            (Role::Explorer, _) => self.frontier,
        }
    }

    /// The lower id of two robots in range proposes a swap when the rule says it pays.
    fn consider_swap(&mut self, s: &Situation<'_>) {
        if !self.st.swap || self.pending.is_some() {
            return;
        }
        let cooled = self
            .last_swap
            .is_none_or(|l| s.step >= l.saturating_add(self.st.timing.patience));
        let Some(ga) = self.goal.filter(|_| cooled) else {
            return;
        };
        for &b in s.neighbours.range(self.me + 1..) {
            if b == self.base {
                continue;
            }
            // Robots in range repeat their state at least every `status_every` steps.
            let Some(m) = self.recent(b, self.st.status_every + 1) else {
                continue;
            };
            let (said, goal, place, cell) = (m.step, m.goal, m.state.place, m.cell);
            if self.weighed.insert(b, said) == Some(said) {
                continue;
            }
            let Some(gb) = goal else { continue };
            if place == self.state.place || !self.st.shape.contains(place) {
                continue;
            }
            let theirs = plan::costs_with(s.grid, cell, s.penalty);
            let (Some(a_ga), Some(a_gb), Some(b_gb), Some(b_ga)) = (
                s.costs.cost(ga),
                s.costs.cost(gb),
                theirs.cost(gb),
                theirs.cost(ga),
            ) else {
                continue;
            };
            if swap_pays(a_ga, b_gb, a_gb, b_ga) {
                self.pending = Some((b, s.step));
                return;
            }
        }
    }

    fn sense(&self, s: &Situation<'_>, parent: Option<RobotId>, child: Option<RobotId>) -> Sense {
        let parent_met = parent.is_some_and(|p| s.neighbours.contains(&p));
        let child_met = child.is_some_and(|c| s.neighbours.contains(&c));
        let waiting = |r: RobotId| self.backlog.iter().any(|&(p, b)| p == r && b > 0);
        let st = &self.state;
        let made = st.with_child.map(|r| r.made);
        Sense {
            step: s.step,
            parent_met,
            parent_met_new: parent_met && !self.parent_was_met,
            parent_caught_up: parent.is_none_or(|p| !waiting(p)),
            child_met,
            child_caught_up: child
                .and_then(|c| self.fresh(c))
                .is_some_and(|m| m.caught_up),
            fresh: made.is_some() && made > self.delivered,
            fresh_for: s.step.saturating_sub(self.fresh_since),
            at_goal: false,
            reachable: true,
            return_now: false,
        }
    }

    /// Fills in where the robot stands relative to `goal`.
    fn measure(&self, s: &Situation<'_>, goal: Option<Cell>, i: &mut Sense) {
        let step_cells = self.st.agreeing.cells_per_step;
        let cost = goal.and_then(|g| s.costs.cost(g));
        i.reachable = goal.is_none() || cost.is_some();
        i.at_goal = goal.is_some_and(|g| g == s.me || cost.is_some_and(|c| c <= step_cells));
    }
}

impl Coordinator for Roles {
    fn choose(&mut self, s: &Situation<'_>) -> Option<Cell> {
        self.step = s.step;
        self.base_cell.get_or_insert(s.me);
        self.settle_swaps();
        let (parent, child) = (self.parent(), self.child());
        let mut sense = self.sense(s, parent, child);
        if self.role() == Role::Explorer {
            self.pick_frontier(s);
        }
        if let Some(p) = parent.filter(|_| sense.parent_met) {
            self.agree(s, p, sense.parent_met_new);
        }
        let timing = self.st.timing;
        match self.role() {
            Role::Explorer => {
                let due = self.state.with_parent.map(|r| r.due);
                let back = self
                    .state
                    .with_parent
                    .and_then(|r| s.costs.cost(r.primary))
                    .map(|c| rendezvous::trip_steps(c, self.st.agreeing.cells_per_step));
                let late = match (due, back) {
                    (Some(d), Some(b)) => s.step.saturating_add(b).saturating_add(1) >= d,
                    _ => false,
                };
                let relay_parent = parent != Some(self.base);
                sense.return_now = relay_parent
                    && self.state.with_parent.is_some()
                    && (late || self.frontier.is_none());
                let goal = self.goal_of(s);
                self.measure(s, goal, &mut sense);
                let next = explorer_next(self.state.phase, self.state.since, due, &sense, &timing);
                if self.state.phase == Phase::Fallback && next == Phase::Explore {
                    // The parent did not come: explore one more trip, then try again.
                    if let Some(r) = self.state.with_parent.as_mut() {
                        r.due = s.step.saturating_add(r.due.saturating_sub(r.made));
                    }
                }
                self.set_phase(next);
            }
            Role::Relay => {
                let goal = self.goal_of(s);
                self.measure(s, goal, &mut sense);
                let due = self.state.with_child.map(|r| r.due);
                let next = relay_next(self.state.phase, self.state.since, due, &sense, &timing);
                if next == Phase::ToParent && self.state.phase != Phase::ToParent {
                    self.delivered = self.state.with_child.map(|r| r.made);
                }
                if next == Phase::ToChild && self.state.phase != Phase::ToChild {
                    // Back out to the child: a due step already past is one trip from now.
                    let step_cells = self.st.agreeing.cells_per_step;
                    if let Some(r) = self.state.with_child.as_mut() {
                        let trip = s
                            .costs
                            .cost(r.primary)
                            .map_or(0, |c| rendezvous::trip_steps(c, step_cells));
                        r.due = r.due.max(s.step.saturating_add(trip));
                    }
                }
                self.set_phase(next);
            }
        }
        self.parent_was_met = sense.parent_met;
        self.goal = self.goal_of(s);
        self.consider_swap(s);
        self.goal
    }

    fn messages(&mut self, st: &Status<'_>) -> Vec<Addressed> {
        self.backlog = st.backlog.to_vec();
        self.sent.retain(|r, _| st.neighbours.contains(r));
        if let Some((_, stamp, _)) = self.answer {
            if st.step > stamp.saturating_add(PROPOSAL_STEPS) {
                self.answer = None;
            }
        }
        let peers: Vec<RobotId> = st
            .neighbours
            .iter()
            .copied()
            .filter(|&n| n != self.base && n != self.me)
            .collect();
        let mut out = Vec::new();
        let seats = self.roster.seats();
        let digest = proto::msg::roster_digest(&seats);
        let parent = self.parent();
        for to in peers {
            let swap = match (self.pending, self.answer) {
                (Some((b, stamp)), _) if b == to => Some(Swap::Propose {
                    to,
                    stamp,
                    state: self.state,
                }),
                (_, Some((a, stamp, state))) if a == to => Some(Swap::Accept { to, stamp, state }),
                _ => None,
            };
            let msg = RoleMsg {
                from: self.me,
                step: st.step,
                cell: st.me,
                goal: self.goal,
                state: self.state,
                parent_point: self.parent_point(),
                roster_digest: digest,
                roster: if self
                    .heard
                    .get(&to)
                    .is_some_and(|h| h.roster_digest == digest)
                {
                    Vec::new()
                } else {
                    seats.clone()
                },
                // Only a parent reads it (it waits for its child's data before it leaves).
                caught_up: parent == Some(to)
                    && !self.backlog.iter().any(|&(p, b)| p == to && b > 0),
                swap,
            };
            let gist = RoleMsg {
                step: 0,
                cell: Cell::new(0, 0),
                ..msg.clone()
            };
            let due = match self.sent.get(&to) {
                None => true,
                Some((at, last)) => {
                    *last != gist
                        || msg.swap.is_some()
                        || st.step >= at.saturating_add(self.st.status_every)
                }
            };
            if due {
                self.sent.insert(to, (st.step, gist));
                out.push(Addressed {
                    to: To::Robot(to),
                    msg: CoordMsg::Role(msg),
                });
            }
        }
        out
    }

    fn on_message(&mut self, me: RobotId, msg: &CoordMsg) {
        let CoordMsg::Role(m) = msg else { return };
        if m.from == me || m.from == self.base {
            return;
        }
        if self.heard.get(&m.from).is_some_and(|h| h.step > m.step) {
            return;
        }
        self.roster.merge(&m.roster);
        if let Some(swap) = m.swap {
            self.swaps_in.push((m.from, swap));
        }
        // The child's newest agreement is the parent's.
        let is_child = self.st.shape.child(self.state.place) == Some(m.state.place)
            && self.roster.at(m.state.place) == Some(m.from);
        if is_child {
            if let Some(r) = m.state.with_parent {
                let newer = self.state.with_child.is_none_or(|h| r.made > h.made);
                if newer {
                    self.state.with_child = Some(r);
                    self.fresh_since = m.step;
                }
            }
        }
        self.heard.insert(m.from, m.clone());
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const T: Timing = Timing {
        patience: 5,
        linger: 3,
    };

    fn sense(step: Step) -> Sense {
        Sense {
            step,
            reachable: true,
            ..Sense::default()
        }
    }

    /// Runs the explorer's machine over `steps` senses from `phase`.
    fn run_explorer(mut phase: Phase, due: Option<Step>, steps: &[Sense]) -> Vec<Phase> {
        let mut since = steps.first().map_or(0, |s| s.step);
        let mut out = Vec::new();
        for i in steps {
            let next = explorer_next(phase, since, due, i, &T);
            if next != phase {
                since = i.step;
            }
            phase = next;
            out.push(phase);
        }
        out
    }

    #[test]
    fn explorer_on_time_returns_waits_and_delivers() {
        let due = Some(20);
        let mut steps: Vec<Sense> = (10..14).map(sense).collect();
        steps[1].return_now = true; // step 11: the trip back takes the time left
        steps[3].at_goal = true; // step 13: at the rendezvous
        let mut meet = sense(14);
        meet.at_goal = true;
        meet.parent_met = true;
        meet.parent_met_new = true;
        let mut done = meet;
        done.step = 15;
        done.parent_met_new = false;
        done.parent_caught_up = true;
        steps.extend([meet, done]);
        let phases = run_explorer(Phase::Explore, due, &steps);
        assert_eq!(
            phases,
            [
                Phase::Explore,
                Phase::Return,
                Phase::Return,
                Phase::Wait,
                Phase::Deliver,
                Phase::Explore
            ]
        );
    }

    #[test]
    fn explorer_meeting_early_delivers_at_once() {
        let mut early = sense(5);
        early.parent_met = true;
        early.parent_met_new = true;
        // Still inside its exploring time (no return_now), due at 30: it stops and delivers.
        assert_eq!(
            explorer_next(Phase::Explore, 0, Some(30), &early, &T),
            Phase::Deliver
        );
        // On the way back, too.
        assert_eq!(
            explorer_next(Phase::Return, 0, Some(30), &early, &T),
            Phase::Deliver
        );
        // In range all along (no new meeting): it keeps exploring.
        early.parent_met_new = false;
        assert_eq!(
            explorer_next(Phase::Explore, 0, Some(30), &early, &T),
            Phase::Explore
        );
        // Delivering until caught up or the linger ends.
        let mut d = sense(7);
        d.parent_met = true;
        assert_eq!(
            explorer_next(Phase::Deliver, 5, Some(30), &d, &T),
            Phase::Deliver
        );
        d.step = 8;
        assert_eq!(
            explorer_next(Phase::Deliver, 5, Some(30), &d, &T),
            Phase::Explore
        );
    }

    #[test]
    fn explorer_whose_parent_never_comes_tries_the_fallback_then_explores() {
        let due = Some(20);
        let mut w = sense(25);
        w.at_goal = true;
        assert_eq!(explorer_next(Phase::Wait, 15, due, &w, &T), Phase::Wait);
        w.step = 26;
        assert_eq!(explorer_next(Phase::Wait, 15, due, &w, &T), Phase::Fallback);
        // At the fallback point, it waits twice the patience.
        let mut f = sense(30);
        f.at_goal = true;
        assert_eq!(
            explorer_next(Phase::Fallback, 26, due, &f, &T),
            Phase::Fallback
        );
        f.step = 36;
        assert_eq!(
            explorer_next(Phase::Fallback, 26, due, &f, &T),
            Phase::Explore
        );
        // A rendezvous it cannot reach sends it to the fallback at once.
        let mut r = sense(12);
        r.reachable = false;
        assert_eq!(
            explorer_next(Phase::Return, 11, due, &r, &T),
            Phase::Fallback
        );
    }

    #[test]
    fn relay_ferries_between_child_and_parent() {
        // At the rendezvous, the child in range with a fresh agreement: once caught up, leave.
        let mut at = sense(20);
        at.child_met = true;
        at.fresh = true;
        at.fresh_for = 1;
        assert_eq!(
            relay_next(Phase::ToChild, 10, Some(20), &at, &T),
            Phase::ToChild
        );
        at.child_caught_up = true;
        assert_eq!(
            relay_next(Phase::ToChild, 10, Some(20), &at, &T),
            Phase::ToParent
        );
        // Not caught up, but lingered long enough.
        at.child_caught_up = false;
        at.fresh_for = 3;
        assert_eq!(
            relay_next(Phase::ToChild, 10, Some(20), &at, &T),
            Phase::ToParent
        );
        // On its way to the parent; in range: deliver; caught up: back to the child.
        let mut p = sense(30);
        assert_eq!(
            relay_next(Phase::ToParent, 21, Some(20), &p, &T),
            Phase::ToParent
        );
        p.parent_met = true;
        assert_eq!(
            relay_next(Phase::ToParent, 21, Some(20), &p, &T),
            Phase::Deliver
        );
        p.parent_caught_up = true;
        assert_eq!(
            relay_next(Phase::Deliver, 30, Some(20), &p, &T),
            Phase::ToChild
        );
    }

    #[test]
    fn relay_meeting_its_child_early_turns_back_at_once() {
        // On the way out, long before the due step, the child comes into range with an agreement.
        let mut early = sense(12);
        early.child_met = true;
        early.fresh = true;
        early.child_caught_up = true;
        assert_eq!(
            relay_next(Phase::ToChild, 10, Some(40), &early, &T),
            Phase::ToParent
        );
        // Without a fresh agreement (the old one already delivered) it goes on.
        early.fresh = false;
        assert_eq!(
            relay_next(Phase::ToChild, 10, Some(40), &early, &T),
            Phase::ToChild
        );
    }

    #[test]
    fn relay_whose_child_never_comes_tries_the_fallback_then_goes_home() {
        let mut w = sense(25);
        w.at_goal = true;
        assert_eq!(
            relay_next(Phase::ToChild, 10, Some(20), &w, &T),
            Phase::ToChild
        );
        w.step = 26;
        assert_eq!(
            relay_next(Phase::ToChild, 10, Some(20), &w, &T),
            Phase::Fallback
        );
        let mut f = sense(30);
        f.at_goal = true;
        assert_eq!(
            relay_next(Phase::Fallback, 26, Some(20), &f, &T),
            Phase::Fallback
        );
        f.step = 36;
        assert_eq!(
            relay_next(Phase::Fallback, 26, Some(20), &f, &T),
            Phase::ToParent
        );
        // The child turning up at the fallback point: a normal meeting.
        let mut m = sense(31);
        m.child_met = true;
        m.fresh = true;
        m.child_caught_up = true;
        assert_eq!(
            relay_next(Phase::Fallback, 26, Some(20), &m, &T),
            Phase::ToParent
        );
    }
}
