//! The relay tree (docs/design.md §4.4): from which neighbour a robot takes each owner's log.
//!
//! The thesis's transitive exchange (Algorithm 8, [`crate::exchange::transitive`]) has every
//! robot send each neighbour whatever it holds that the neighbour lacks, as far as it knows. In
//! a group of robots in range of one another that sends most records several times: the writer
//! sends a record to all its neighbours in step t, and in step t+1 each of them sends it on to
//! the others, who hold it already but could not say so in time. With 8 robots exploring
//! intel_lab at unlimited bandwidth, 68 % of the op bytes a robot received were records it held.
//!
//! With the relay tree each robot takes each owner's records from one neighbour: the one fewest
//! radio hops from the robot that writes the log (a distance-vector protocol). A robot tells its
//! neighbours per owner how many hops it is from the writer and which neighbour it takes the log
//! from ([`Routes`](proto::msg::Routes); only what changed, all of it when a link comes up), and
//! sends owner O's records to neighbour P only if P takes O from it — or if P knows no way to O's
//! writer (a robot that is gone or out of reach, or before P's routes are heard), as the thesis
//! does. So a record crosses each link of the tree once. What is sent stays the exchange's business
//! (suffixes or snapshots, within the budget); the tree only says to whom.
//!
//! Ties go to the neighbour taken from already, then to the lowest id, so routes change only when
//! the topology does. A robot never takes an owner from a neighbour that takes it from the robot
//! itself (poisoned reverse), and a route longer than
//! [`MAX_HOPS`](crate::exchange::relay::MAX_HOPS) counts as none, so routes to a writer that went
//! away vanish within about [`MAX_HOPS`](crate::exchange::relay::MAX_HOPS) steps and its log is
//! then flooded like the thesis's. Routes lag the links by a step (a neighbour's routes of step t
//! reach us for step t+1): a record may then come twice, or a step late — never not at all, since
//! routes that do not deliver are replaced once the links are known.

use std::collections::{BTreeMap, BTreeSet};

use proto::msg::{RobotId, Route, Routes};

/// The longest route a robot keeps, in radio hops.
pub const MAX_HOPS: u8 = 32;

/// How far one robot is from an owner's writer, and through which neighbour.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
struct Way {
    hops: u8,
    via: RobotId,
}

/// One robot's side of the relay tree.
#[derive(Clone, Debug)]
pub struct RelayTree {
    me: RobotId,
    /// The log this robot writes (its owner id).
    own: RobotId,
    /// Per owner, our way to its writer.
    ways: BTreeMap<RobotId, Way>,
    /// Per neighbour, its ways as it last told us.
    heard: BTreeMap<RobotId, BTreeMap<RobotId, Way>>,
    /// Per neighbour, our ways as we last told it.
    told: BTreeMap<RobotId, BTreeMap<RobotId, Way>>,
}

impl RelayTree {
    /// Robot `me`, writing the log of owner `own`.
    pub fn new(me: RobotId, own: RobotId) -> RelayTree {
        RelayTree {
            me,
            own,
            ways: BTreeMap::from([(own, Way { hops: 0, via: me })]),
            heard: BTreeMap::new(),
            told: BTreeMap::new(),
        }
    }

    /// A link to `peer` came up: nothing is known of its routes, and it gets all of ours.
    pub fn link_up(&mut self, peer: RobotId) {
        self.heard.remove(&peer);
        self.told.remove(&peer);
    }

    /// `peer` gets all our routes again with the next announcements (a lossy radio: a route
    /// told once and lost would leave the neighbour taking a log the long way for good).
    pub fn retell(&mut self, peer: RobotId) {
        self.told.remove(&peer);
    }

    /// The link to `peer` went down.
    pub fn link_down(&mut self, peer: RobotId) {
        self.heard.remove(&peer);
        self.told.remove(&peer);
    }

    /// Takes a neighbour's routes (what changed since it last told us).
    pub fn on_routes(&mut self, r: &Routes) {
        if r.from == self.me {
            return;
        }
        let table = self.heard.entry(r.from).or_default();
        for route in &r.routes {
            if route.hops == Route::NONE {
                table.remove(&route.owner);
            } else {
                table.insert(
                    route.owner,
                    Way {
                        hops: route.hops,
                        via: route.via,
                    },
                );
            }
        }
    }

    /// Our ways from what `neighbours` (this step's) told us: per owner, the neighbour fewest
    /// hops from its writer (ties: the one we took it from already, then the lowest id), never
    /// one that takes it from us, never more than [`MAX_HOPS`].
    pub fn update(&mut self, neighbours: &BTreeSet<RobotId>) {
        self.heard.retain(|p, _| neighbours.contains(p));
        self.told.retain(|p, _| neighbours.contains(p));
        let mut ways = BTreeMap::from([(
            self.own,
            Way {
                hops: 0,
                via: self.me,
            },
        )]);
        let rank =
            |w: Way, before: Option<&Way>| (w.hops, before.map(|b| b.via) != Some(w.via), w.via);
        for (&peer, table) in &self.heard {
            for (&owner, way) in table {
                if owner == self.own || way.via == self.me || way.hops >= MAX_HOPS {
                    continue;
                }
                let offer = Way {
                    hops: way.hops + 1,
                    via: peer,
                };
                let before = self.ways.get(&owner);
                match ways.get(&owner) {
                    Some(&best) if rank(best, before) <= rank(offer, before) => {}
                    _ => {
                        ways.insert(owner, offer);
                    }
                }
            }
        }
        self.ways = ways;
    }

    /// Per neighbour in `neighbours`, the routes it has not heard from us (`None`: nothing
    /// changed), with how much of the owner's log we hold (`have`) where we take it from
    /// another neighbour than we told; what we no longer reach is sent as [`Route::NONE`].
    pub fn announcements(
        &mut self,
        neighbours: &BTreeSet<RobotId>,
        have: impl Fn(RobotId) -> u32,
    ) -> Vec<(RobotId, Routes)> {
        let mut out = Vec::new();
        for &peer in neighbours {
            let told = self.told.entry(peer).or_default();
            let mut routes: Vec<Route> = self
                .ways
                .iter()
                .filter(|&(owner, way)| told.get(owner) != Some(way))
                .map(|(&owner, w)| Route {
                    owner,
                    hops: w.hops,
                    via: w.via,
                    have: (told.get(&owner).map(|t| t.via) != Some(w.via)).then(|| have(owner)),
                })
                .collect();
            routes.extend(
                told.keys()
                    .filter(|o| !self.ways.contains_key(o))
                    .map(|&owner| Route {
                        owner,
                        hops: Route::NONE,
                        via: self.me,
                        have: None,
                    }),
            );
            routes.sort_by_key(|r| r.owner);
            if !routes.is_empty() {
                told.clone_from(&self.ways);
                out.push((
                    peer,
                    Routes {
                        from: self.me,
                        routes,
                    },
                ));
            }
        }
        out
    }

    /// Whether we send `owner`'s records to neighbour `peer`: it takes them from us, or it
    /// knows no way to their writer.
    pub fn relays(&self, peer: RobotId, owner: RobotId) -> bool {
        self.heard
            .get(&peer)
            .and_then(|t| t.get(&owner))
            .is_none_or(|w| w.via == self.me)
    }

    /// The owners whose records neighbour `peer` takes from another robot.
    pub fn left_out(&self, peer: RobotId) -> BTreeSet<RobotId> {
        self.heard.get(&peer).map_or_else(BTreeSet::new, |t| {
            t.iter()
                .filter(|(_, w)| w.via != self.me)
                .map(|(&o, _)| o)
                .collect()
        })
    }

    /// Our way to `owner`'s writer: hops and the neighbour we take its log from.
    pub fn way(&self, owner: RobotId) -> Option<(u8, RobotId)> {
        self.ways.get(&owner).map(|w| (w.hops, w.via))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    /// Runs the protocol on a static graph for `rounds` lockstep steps: every robot updates
    /// its ways from what it heard, then tells its neighbours, who take it before the next.
    fn settle(n: u16, links: &[(u16, u16)], rounds: usize) -> Vec<RelayTree> {
        let mut trees: Vec<RelayTree> = (0..n).map(|i| RelayTree::new(i, i)).collect();
        run(&mut trees, links, rounds);
        trees
    }

    /// `rounds` lockstep steps of `trees` on the graph of `links`.
    fn run(trees: &mut [RelayTree], links: &[(u16, u16)], rounds: usize) {
        let nb = neighbours(trees.len() as u16, links);
        for _ in 0..rounds {
            let mut mail = Vec::new();
            for (i, t) in trees.iter_mut().enumerate() {
                t.update(&nb[i]);
                mail.extend(t.announcements(&nb[i], |_| 0));
            }
            for (to, r) in mail {
                trees[usize::from(to)].on_routes(&r);
            }
        }
    }

    impl RelayTree {
        /// Links to every one of `nb` not heard from yet came up.
        fn link_up_all(&mut self, nb: &BTreeSet<RobotId>) {
            for &p in nb {
                if !self.heard.contains_key(&p) {
                    self.link_up(p);
                }
            }
        }
    }

    fn neighbours(n: u16, links: &[(u16, u16)]) -> Vec<BTreeSet<RobotId>> {
        let mut nb = vec![BTreeSet::new(); usize::from(n)];
        for &(a, b) in links {
            if a != b && a < n && b < n {
                nb[usize::from(a)].insert(b);
                nb[usize::from(b)].insert(a);
            }
        }
        nb
    }

    /// Hop distances from `from` by breadth-first search.
    fn bfs(n: u16, nb: &[BTreeSet<RobotId>], from: u16) -> Vec<Option<u8>> {
        let mut d = vec![None; usize::from(n)];
        d[usize::from(from)] = Some(0u8);
        let mut queue = std::collections::VecDeque::from([from]);
        while let Some(x) = queue.pop_front() {
            for &y in &nb[usize::from(x)] {
                if d[usize::from(y)].is_none() {
                    d[usize::from(y)] = d[usize::from(x)].map(|h| h + 1);
                    queue.push_back(y);
                }
            }
        }
        d
    }

    #[test]
    fn in_a_clique_everyone_takes_each_log_from_its_writer() {
        let links: Vec<(u16, u16)> = (0..5)
            .flat_map(|a| (a + 1..5).map(move |b| (a, b)))
            .collect();
        let trees = settle(5, &links, 3);
        for (i, t) in trees.iter().enumerate() {
            for o in 0..5u16 {
                let senders: Vec<u16> = (0..5u16)
                    .filter(|&s| s != i as u16 && trees[usize::from(s)].relays(i as u16, o))
                    .collect();
                if o == i as u16 {
                    assert!(
                        senders.is_empty(),
                        "robot {i} is sent its own log by {senders:?}"
                    );
                } else {
                    assert_eq!(senders, [o], "robot {i}, owner {o}");
                    assert_eq!(t.way(o), Some((1, o)));
                }
            }
        }
    }

    #[test]
    fn routes_are_told_once_and_a_writer_out_of_reach_is_forgotten() {
        // A line 0 - 1 - 2: robot 2 takes 0's log from 1.
        let mut trees = settle(3, &[(0, 1), (1, 2)], 4);
        assert_eq!(trees[2].way(0), Some((2, 1)));
        assert!(trees[1].relays(2, 0));
        assert!(
            !trees[0].relays(1, 2),
            "robot 1 takes 2's log from 2 itself"
        );
        // Nothing changed: nothing to tell.
        let nb = neighbours(3, &[(0, 1), (1, 2)]);
        for (i, t) in trees.iter_mut().enumerate() {
            t.update(&nb[i]);
            assert!(t.announcements(&nb[i], |_| 0).is_empty());
        }
        // Robot 0 leaves: after at most MAX_HOPS rounds nobody has a way to it, and its log is
        // sent by whoever holds it (routes unknown).
        run(&mut trees, &[(1, 2)], usize::from(MAX_HOPS) + 1);
        assert_eq!(trees[1].way(0), None);
        assert_eq!(trees[2].way(0), None);
        assert!(trees[1].relays(2, 0) && trees[2].relays(1, 0));
    }

    #[test]
    fn a_lost_announcement_leaves_a_long_way_until_the_routes_are_retold() {
        // A triangle whose 1 - 2 link comes up late, and robot 2's routes to 1 of that step are
        // lost (an unframed put before 1's interest reached 2).
        let all = [(0, 1), (0, 2), (1, 2)];
        let mut trees = settle(3, &all[..2], 3);
        assert_eq!(trees[1].way(2), Some((2, 0)));
        let nb = neighbours(3, &all);
        for (i, t) in trees.iter_mut().enumerate() {
            t.link_up_all(&nb[i]);
        }
        let mut mail = Vec::new();
        for (i, t) in trees.iter_mut().enumerate() {
            t.update(&nb[i]);
            mail.extend(t.announcements(&nb[i], |_| 0));
        }
        for (to, r) in mail {
            if !(r.from == 2 && to == 1) {
                trees[usize::from(to)].on_routes(&r);
            }
        }
        run(&mut trees, &all, 4);
        assert_eq!(trees[1].way(2), Some((2, 0)), "told once, lost for good");
        assert!(!trees[2].relays(1, 2));
        trees[2].retell(1);
        run(&mut trees, &all, 2);
        assert_eq!(trees[1].way(2), Some((1, 2)));
        assert!(trees[2].relays(1, 2) && !trees[0].relays(1, 2));
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(64))]

        /// On a static graph the routes settle, within as many rounds as robots, into a
        /// shortest-path tree per owner: every robot that reaches an owner's writer is sent
        /// that owner's log by exactly one neighbour, one hop nearer the writer; no robot is
        /// sent its own log; and a robot that cannot reach the writer is sent by every
        /// neighbour (nobody reaches it either).
        #[test]
        fn routes_settle_into_shortest_path_trees(
            n in 1u16..9,
            links in proptest::collection::vec((0u16..9, 0u16..9), 0..24),
        ) {
            let trees = settle(n, &links, usize::from(n) + 1);
            let nb = neighbours(n, &links);
            for o in 0..n {
                let dist = bfs(n, &nb, o);
                for p in 0..n {
                    let senders: Vec<u16> = nb[usize::from(p)]
                        .iter()
                        .copied()
                        .filter(|&s| trees[usize::from(s)].relays(p, o))
                        .collect();
                    match dist[usize::from(p)] {
                        Some(0) => prop_assert!(senders.is_empty()),
                        Some(h) => {
                            prop_assert_eq!(trees[usize::from(p)].way(o).map(|w| w.0), Some(h));
                            prop_assert_eq!(senders.len(), 1, "robot {} owner {}", p, o);
                            prop_assert_eq!(dist[usize::from(senders[0])], Some(h - 1));
                        }
                        None => {
                            prop_assert_eq!(trees[usize::from(p)].way(o), None);
                            prop_assert_eq!(senders.len(), nb[usize::from(p)].len());
                        }
                    }
                }
            }
        }
    }
}
