//! Team awareness: how much the team knows together, how much of it is shared, and how long
//! robots have been out of touch with the base station — three of the four metrics of de Hoog,
//! Cameron and Visser, *Autonomous Multi-Robot Exploration in Communication-Limited
//! Environments* (TAROS 2010, Fig. 5; the fourth, the share known at the base station, is the
//! base station's own coverage, which the evaluator already gives).
//!
//! * **Team coverage** (Fig. 5a): the share of the truth's reachable free cells that at least one
//!   robot knows, |K_1 ∪ … ∪ K_N| — from the same per-cell holder counts, a counter of the cells
//!   with a holder
//!   ([`SharedKnowledge::known_by_anyone`](crate::score::awareness::SharedKnowledge::known_by_anyone)).
//! * **Shared knowledge** (Fig. 5c): for robot r with known space K_r, the share of K_r that every
//!   robot of the team knows, |K_1 ∩ … ∩ K_N| / |K_r| × 100 (100 when K_r is empty). K_q is what
//!   the evaluator counts as coverage: the truth's reachable free cells that robot q's planning
//!   grid has free or occupied ([`knows`](crate::score::awareness::knows)).
//!   [`SharedKnowledge`](crate::score::awareness::SharedKnowledge) keeps, per cell, how many robots
//!   know it, so that a robot's changed cells are told one by one and the intersection's size is a
//!   counter — never a comparison of every pair of robots.
//! * **Contact with the base station** (Fig. 5d): steps since a robot last had contact with the
//!   base station, directly or carried by robots in between
//!   ([`Contact`](crate::score::awareness::Contact)). Contact is transitive within a step (a chain
//!   of up links is a multi-hop route) and carried over time by mobile relays: a relay that touched
//!   the base at step 100 and meets the explorer at step 150 brings the explorer the base's state
//!   of step 100.

use std::collections::BTreeMap;

use proto::grid::Occ;
use proto::msg::{RobotId, Step};

/// The evaluator's notion of coverage: a robot knows a cell when the cell is reachable in the
/// truth and its planning grid has it free or occupied.
pub fn knows(seen: Occ, reachable: bool) -> bool {
    seen != Occ::Unknown && reachable
}

/// What every robot of a team knows, kept up to date one changed cell at a time.
#[derive(Clone, Debug, Default)]
pub struct SharedKnowledge {
    /// Per robot of the team (ids `0..team`): how many cells it knows.
    counts: Vec<usize>,
    /// Per cell, how many robots know it.
    holders: Vec<u16>,
    /// Cells every robot knows: |K_1 ∩ … ∩ K_N|.
    common: usize,
    /// Cells some robot knows: |K_1 ∪ … ∪ K_N|.
    anyone: usize,
}

impl SharedKnowledge {
    /// A team of `team` robots (ids `0..team`) over `cells` cells, none known yet.
    pub fn new(team: u16, cells: usize) -> SharedKnowledge {
        SharedKnowledge {
            counts: vec![0; usize::from(team)],
            holders: vec![0; cells],
            common: 0,
            anyone: 0,
        }
    }

    fn team(&self) -> usize {
        self.counts.len()
    }

    /// Robot `robot` came to know cell `i` (`now`) or no longer knows it; the caller tells only
    /// changes. A robot outside the team (the base station) and cells beyond `cells` are
    /// ignored.
    pub fn know(&mut self, robot: RobotId, i: usize, now: bool) {
        let team = self.team();
        let (Some(count), Some(h)) = (
            self.counts.get_mut(usize::from(robot)),
            self.holders.get_mut(i),
        ) else {
            return;
        };
        let everyone_before = usize::from(*h) == team;
        if now {
            *count += 1;
            *h += 1;
        } else {
            *count -= 1;
            *h -= 1;
        }
        let everyone_now = usize::from(*h) == team;
        match (everyone_before, everyone_now) {
            (false, true) => self.common += 1,
            (true, false) => self.common -= 1,
            _ => {}
        }
        // A cell joins the union with its first holder and leaves it with its last.
        match (now, *h) {
            (true, 1) => self.anyone += 1,
            (false, 0) => self.anyone -= 1,
            _ => {}
        }
    }

    /// |K_1 ∪ … ∪ K_N|: the cells at least one robot of the team knows.
    pub fn known_by_anyone(&self) -> usize {
        self.anyone
    }

    /// Whether `robot` is one of the team (the base station is not).
    pub fn is_member(&self, robot: RobotId) -> bool {
        usize::from(robot) < self.team()
    }

    /// |K_1 ∩ … ∩ K_N| / |K_robot| × 100: the share of what `robot` knows that every robot
    /// knows; 100 when it knows nothing (nothing of it is unshared). `None` outside the team.
    pub fn share_pct(&self, robot: RobotId) -> Option<f64> {
        let count = *self.counts.get(usize::from(robot))?;
        Some(if count == 0 {
            100.0
        } else {
            100.0 * self.common as f64 / count as f64
        })
    }
}

/// Every node's last contact with the base station (Fig. 5d), taken one step at a time.
///
/// Every node had contact at step 0 (the run starts at the base). At step s the base station's
/// own contact is s; the nodes that links up at s connect, directly or through others, share
/// the latest contact any of them has. A step without links carries nothing. Node ids from
/// `nodes` on (and a `base` outside them) are ignored.
pub struct Contact {
    base: RobotId,
    /// Per node, the step of its latest contact.
    latest: Vec<Step>,
    /// The next step to take.
    next: Step,
}

impl Contact {
    pub fn new(nodes: usize, base: RobotId) -> Contact {
        Contact {
            base,
            latest: vec![0; nodes],
            next: 0,
        }
    }

    /// The next step to take.
    pub fn next(&self) -> Step {
        self.next
    }

    /// Takes the next step with the links up at it: every node's steps since its last contact.
    pub fn step(&mut self, links: &[(RobotId, RobotId)]) -> Vec<Step> {
        let s = self.next;
        self.next = s.saturating_add(1);
        if let Some(c) = self.latest.get_mut(usize::from(self.base)) {
            *c = s;
        }
        carry_contact(&mut self.latest, links);
        self.latest.iter().map(|&c| s - c).collect()
    }
}

/// Every node takes the latest contact of the component the links put it in.
fn carry_contact(contact: &mut [Step], links: &[(RobotId, RobotId)]) {
    let roots = proto::graph::components(contact.len(), links);
    let mut latest: BTreeMap<usize, Step> = BTreeMap::new();
    for (&root, &c) in roots.iter().zip(contact.iter()) {
        let l = latest.entry(root).or_insert(c);
        *l = (*l).max(c);
    }
    for (c, root) in contact.iter_mut().zip(&roots) {
        if let Some(&l) = latest.get(root) {
            *c = l;
        }
    }
}

/// The mean over steps of each step's mean (every step weighs the same, however many values it
/// has), taken a value at a time: per step, the sum and the count of its values.
#[derive(Clone, Debug, Default)]
pub struct StepMeans(BTreeMap<Step, (f64, u32)>);

impl StepMeans {
    pub fn add(&mut self, step: Step, v: f64) {
        let e = self.0.entry(step).or_default();
        *e = (e.0 + v, e.1 + 1);
    }

    /// The mean over the steps of each step's mean (`None`: no value).
    pub fn mean(&self) -> Option<f64> {
        let n = self.0.len();
        (n > 0).then(|| {
            self.0
                .values()
                .map(|&(sum, k)| sum / f64::from(k))
                .sum::<f64>()
                / n as f64
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::score::connectivity::UpLinks;
    use proptest::prelude::*;

    /// Per step `0..=last`, every node's steps since its last contact with the base station
    /// (Fig. 5d): `[s][node]` ([`Contact`] over every step).
    fn steps_since_base(nodes: usize, base: RobotId, up: &UpLinks, last: Step) -> Vec<Vec<Step>> {
        let mut contact = Contact::new(nodes, base);
        (0..=last)
            .map(|s| contact.step(up.get(&s).map_or(&[][..], Vec::as_slice)))
            .collect()
    }

    use proto::grid::Grid;

    /// What a robot knows, one flag per cell.
    #[derive(Clone, Debug, PartialEq)]
    struct Known(Vec<bool>);

    impl Known {
        fn from_flags(_width: u32, flags: &[bool]) -> Known {
            Known(flags.to_vec())
        }
    }

    /// The cells `grid` knows over a world whose reachable cells are `reachable`.
    fn known_cells(grid: &Grid, reachable: &[bool]) -> Known {
        Known(
            grid.cells()
                .iter()
                .zip(reachable)
                .map(|(&seen, &r)| knows(seen, r))
                .collect(),
        )
    }

    /// A team told whole known sets: each robot's changed cells go to [`SharedKnowledge::know`].
    struct Team {
        s: SharedKnowledge,
        known: BTreeMap<RobotId, Vec<bool>>,
    }

    impl Team {
        fn new(team: u16, cells: usize) -> Team {
            Team {
                s: SharedKnowledge::new(team, cells),
                known: BTreeMap::new(),
            }
        }

        fn update(&mut self, robot: RobotId, k: Known) {
            let before = self.known.entry(robot).or_insert(vec![false; k.0.len()]);
            for (i, (&was, &now)) in before.iter().zip(&k.0).enumerate() {
                if was != now {
                    self.s.know(robot, i, now);
                }
            }
            *before = k.0;
        }

        fn share_pct(&self, robot: RobotId) -> Option<f64> {
            self.s.share_pct(robot)
        }

        fn known_by_anyone(&self) -> usize {
            self.s.known_by_anyone()
        }

        fn is_member(&self, robot: RobotId) -> bool {
            self.s.is_member(robot)
        }

        /// The team of one step's known sets over `cells` cells: robot i knows `known[i]`.
        fn of(known: &[Known], cells: usize) -> Team {
            let team = u16::try_from(known.len()).unwrap_or(u16::MAX);
            let mut t = Team::new(team, cells);
            for (r, k) in (0..team).zip(known) {
                t.update(r, k.clone());
            }
            t
        }
    }

    /// Each robot's share of its known space that every robot knows, for one step's sets.
    fn shared_pcts(known: &[Known], cells: usize) -> Vec<f64> {
        let t = Team::of(known, cells);
        let team = u16::try_from(known.len()).unwrap_or(u16::MAX);
        (0..team).filter_map(|r| t.share_pct(r)).collect()
    }

    /// Known sets of hand-drawn grids over an all-reachable 4×1 world.
    fn known(pics: &[&str]) -> Vec<Known> {
        pics.iter()
            .map(|p| known_cells(&Grid::from_ascii(p), &[true; 4]))
            .collect()
    }

    fn flags(f: &[bool]) -> Known {
        Known::from_flags(4, f)
    }

    #[test]
    fn disjoint_knowledge_is_not_shared() {
        assert_eq!(shared_pcts(&known(&["..??", "??.#"]), 4), [0.0, 0.0]);
    }

    #[test]
    fn overlapping_knowledge_is_shared_in_part() {
        // Robot 0 knows 3 cells, robot 1 knows 2, both know 1 (occupied counts as known).
        assert_eq!(
            shared_pcts(&known(&["..#?", "??#."]), 4),
            [100.0 / 3.0, 50.0]
        );
    }

    #[test]
    fn identical_knowledge_is_all_shared() {
        assert_eq!(shared_pcts(&known(&[".#.?", ".#.?"]), 4), [100.0, 100.0]);
    }

    #[test]
    fn a_robot_that_knows_nothing_has_nothing_unshared() {
        assert_eq!(shared_pcts(&known(&["????", "...."]), 4), [100.0, 0.0]);
    }

    #[test]
    fn a_cell_is_in_the_union_once_and_leaves_it_with_its_last_holder() {
        let mut s = Team::new(3, 4);
        s.update(0, flags(&[true, true, false, false]));
        s.update(1, flags(&[true, false, true, false]));
        assert_eq!(s.known_by_anyone(), 3, "cell 0 counts once");
        s.update(0, flags(&[false, false, false, false]));
        assert_eq!(
            s.known_by_anyone(),
            2,
            "cell 0 still has robot 1, cell 1 had only robot 0"
        );
        s.update(1, flags(&[false; 4]));
        assert_eq!(s.known_by_anyone(), 0);
        s.update(3, flags(&[true; 4]));
        assert_eq!(s.known_by_anyone(), 0, "the base station is no member");
        assert!(s.is_member(2) && !s.is_member(3));
    }

    #[test]
    fn unreachable_cells_are_not_known() {
        let k = known_cells(&Grid::from_ascii("..#."), &[true, false, true, false]);
        assert_eq!(k, flags(&[true, false, true, false]));
    }

    #[test]
    fn a_new_grid_replaces_what_a_robot_knew_and_the_base_station_is_no_member() {
        let mut s = Team::new(2, 4);
        s.update(0, flags(&[true, true, false, false]));
        s.update(1, flags(&[true, false, false, false]));
        assert_eq!(s.share_pct(0), Some(50.0));
        s.update(1, flags(&[true, true, true, false]));
        assert_eq!(
            (s.share_pct(0), s.share_pct(1)),
            (Some(100.0), Some(200.0 / 3.0))
        );
        s.update(0, flags(&[false, false, false, true]));
        assert_eq!(s.share_pct(0), Some(0.0));
        s.update(2, flags(&[true; 4]));
        assert_eq!(s.share_pct(2), None);
    }

    /// (step, [(a, b)]) links up, as `links.csv` would list them.
    fn up(links: &[(Step, &[(RobotId, RobotId)])]) -> UpLinks {
        links.iter().map(|&(s, l)| (s, l.to_vec())).collect()
    }

    #[test]
    fn direct_contact_resets_the_count() {
        // Robot 0 and the base (node 1) linked at steps 2 and 5 only.
        let since = steps_since_base(2, 1, &up(&[(2, &[(0, 1)]), (5, &[(0, 1)])]), 6);
        let robot: Vec<Step> = since.iter().map(|n| n[0]).collect();
        assert_eq!(robot, [0, 1, 0, 1, 2, 0, 1]);
        assert!(
            since.iter().all(|n| n[1] == 0),
            "the base is always in touch"
        );
    }

    #[test]
    fn a_relay_carries_the_contact_it_had() {
        // Explorer 0, relay 1, base 2: the relay meets the base at step 3, the explorer at 6.
        let since = steps_since_base(3, 2, &up(&[(3, &[(1, 2)]), (6, &[(0, 1)])]), 7);
        let explorer: Vec<Step> = since.iter().map(|n| n[0]).collect();
        let relay: Vec<Step> = since.iter().map(|n| n[1]).collect();
        assert_eq!(
            explorer,
            [0, 1, 2, 3, 4, 5, 3, 4],
            "contact of step 3, from the relay"
        );
        assert_eq!(relay, [0, 1, 2, 0, 1, 2, 3, 4]);
    }

    #[test]
    fn a_chain_of_links_is_contact_within_the_step() {
        let since = steps_since_base(3, 2, &up(&[(4, &[(0, 1), (1, 2)])]), 4);
        assert_eq!(since[4], [0, 0, 0]);
        assert_eq!(since[3], [3, 3, 0]);
    }

    #[test]
    fn a_robot_never_in_touch_counts_from_the_start_and_links_down_carry_nothing() {
        // Robots 0 and 1 meet at steps 1 and 3 but never the base (node 2).
        let since = steps_since_base(3, 2, &up(&[(1, &[(0, 1)]), (3, &[(0, 1)])]), 4);
        assert_eq!(
            since.iter().map(|n| n[0]).collect::<Vec<_>>(),
            [0, 1, 2, 3, 4]
        );
        // Links to nodes that do not exist are ignored.
        assert_eq!(steps_since_base(1, 0, &up(&[(0, &[(0, 9)])]), 0), [[0]]);
    }

    #[test]
    fn step_means_weigh_every_step_the_same() {
        let mean = |values: &[(Step, f64)]| {
            let mut m = StepMeans::default();
            for &(s, v) in values {
                m.add(s, v);
            }
            m.mean()
        };
        assert_eq!(mean(&[(0, 10.0), (0, 30.0), (1, 40.0)]), Some(30.0));
        assert_eq!(mean(&[]), None);
    }

    /// Fig. 5a counted the plain way: the cells some set holds.
    fn naive_union(known: &[Vec<bool>]) -> usize {
        (0..known[0].len())
            .filter(|&i| known.iter().any(|k| k[i]))
            .count()
    }

    /// Fig. 5c counted the plain way: the intersection of every set, over each set.
    fn naive(known: &[Vec<bool>]) -> Vec<f64> {
        let common = (0..known[0].len())
            .filter(|&i| known.iter().all(|k| k[i]))
            .count();
        known
            .iter()
            .map(|k| match k.iter().filter(|&&x| x).count() {
                0 => 100.0,
                n => 100.0 * common as f64 / n as f64,
            })
            .collect()
    }

    fn arb_links(nodes: u16) -> impl Strategy<Value = UpLinks> {
        proptest::collection::btree_map(
            0..40u32,
            proptest::collection::vec((0..nodes, 0..nodes), 0..4),
            0..20,
        )
    }

    proptest! {
        #[test]
        fn contact_is_within_the_run_and_the_base_component_is_in_touch(
            links in arb_links(5),
            base in 0..5u16,
        ) {
            let since = steps_since_base(5, base, &links, 40);
            for (s, nodes) in since.iter().enumerate() {
                let s = s as Step;
                prop_assert!(nodes.iter().all(|&n| n <= s));
                prop_assert_eq!(nodes[usize::from(base)], 0);
                let roots = proto::graph::components(5, links.get(&s).map_or(&[][..], Vec::as_slice));
                for (n, root) in roots.iter().enumerate() {
                    if *root == roots[usize::from(base)] {
                        prop_assert_eq!(nodes[n], 0, "node {} linked to the base at {}", n, s);
                    }
                }
            }
        }

        #[test]
        fn shares_are_percentages_the_union_holds_every_set_and_all_agree_when_all_know_the_same(
            known in proptest::collection::vec(proptest::collection::vec(any::<bool>(), 12), 1..5),
        ) {
            let ks: Vec<Known> = known.iter().map(|k| Known::from_flags(4, k)).collect();
            let pcts = shared_pcts(&ks, 12);
            for &p in &pcts {
                prop_assert!((0.0..=100.0).contains(&p), "{}", p);
            }
            prop_assert_eq!(pcts, naive(&known));
            let union = Team::of(&ks, 12).known_by_anyone();
            prop_assert_eq!(union, naive_union(&known));
            for k in &known {
                prop_assert!(union >= k.iter().filter(|&&x| x).count());
            }
            let same = vec![ks[0].clone(); known.len()];
            let pcts = shared_pcts(&same, 12);
            prop_assert!(pcts.iter().all(|&p| p == 100.0), "{:?}", pcts);
            let one = known[0].iter().filter(|&&x| x).count();
            prop_assert_eq!(Team::of(&same, 12).known_by_anyone(), one);
        }

        #[test]
        fn updating_in_place_agrees_with_counting_afresh(
            first in proptest::collection::vec(proptest::collection::vec(any::<bool>(), 8), 3),
            then in proptest::collection::vec(any::<bool>(), 8),
            who in 0..3u16,
        ) {
            let mut s = Team::new(3, 8);
            for (r, k) in (0..3).zip(&first) {
                s.update(r, Known::from_flags(4, k));
            }
            s.update(who, Known::from_flags(4, &then));
            let mut now = first.clone();
            now[usize::from(who)] = then;
            prop_assert_eq!((0..3).filter_map(|r| s.share_pct(r)).collect::<Vec<_>>(), naive(&now));
            prop_assert_eq!(s.known_by_anyone(), naive_union(&now));
        }
    }
}
