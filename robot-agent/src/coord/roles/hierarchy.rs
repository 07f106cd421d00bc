//! The team hierarchy of role-based exploration (de Hoog, Cameron & Visser, "Autonomous
//! multi-robot exploration in communication-limited environments", TAROS 2010, §III-B and §V):
//! a tree rooted at the base station whose root has any number of children and every other node
//! at most one — a branch is a chain of relays ending in an explorer.
//!
//! * [`Shape`](crate::coord::roles::hierarchy::Shape): the branches and their lengths, fixed for
//!   the run (`[coordination.roles]`). A [`Place`](proto::msg::Place) is a slot in it; the last
//!   place of a branch is the explorer's.
//! * [`Roster`](crate::coord::roles::hierarchy::Roster): which robot holds which place. Role swaps
//!   move robots between places, so every robot keeps its own roster and merges what it hears: for
//!   each robot, the newest claim wins (a [`Seat`](proto::msg::Seat)'s `since`). A robot's parent
//!   or child is whoever holds the place above or below its own in its roster.
//! * [`swap_pays`](crate::coord::roles::hierarchy::swap_pays): the role swap rule of §V.

use std::collections::BTreeMap;

use proto::msg::{Place, RobotId, Seat, Step};

/// What a place does.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Role {
    Explorer,
    Relay,
}

/// The hierarchy's shape: the length (relays + 1) of every branch.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Shape {
    lengths: Vec<u16>,
}

impl Shape {
    /// `robots` dealt into branches of `relays + 1` (the last one shorter if they do not divide
    /// evenly; the scenario's `branches`, when given, must be that number).
    pub fn new(robots: u16, relays: u32) -> Shape {
        let per = u16::try_from(relays.saturating_add(1)).unwrap_or(u16::MAX);
        let mut lengths = Vec::with_capacity(usize::from(robots.div_ceil(per)));
        let mut left = robots;
        while left > 0 {
            let n = left.min(per);
            lengths.push(n);
            left -= n;
        }
        Shape { lengths }
    }

    pub fn branches(&self) -> usize {
        self.lengths.len()
    }

    /// Whether `p` is a place of this shape.
    pub fn contains(&self, p: Place) -> bool {
        self.lengths
            .get(usize::from(p.branch))
            .is_some_and(|&n| p.depth < n)
    }

    pub fn role(&self, p: Place) -> Role {
        match self.lengths.get(usize::from(p.branch)) {
            Some(&n) if p.depth + 1 < n => Role::Relay,
            _ => Role::Explorer,
        }
    }

    /// The place above `p`; `None`: the base station.
    pub fn parent(&self, p: Place) -> Option<Place> {
        (p.depth > 0).then(|| Place {
            branch: p.branch,
            depth: p.depth - 1,
        })
    }

    /// The place below `p`; `None` for an explorer.
    pub fn child(&self, p: Place) -> Option<Place> {
        (self.role(p) == Role::Relay).then(|| Place {
            branch: p.branch,
            depth: p.depth + 1,
        })
    }

    /// The places as dealt at the start: robots in id order fill branch 0 from the base station
    /// down, then branch 1, and so on.
    pub fn dealt(&self) -> Vec<Seat> {
        let mut seats = Vec::new();
        let mut robot: RobotId = 0;
        for (b, &n) in self.lengths.iter().enumerate() {
            for depth in 0..n {
                seats.push(Seat {
                    robot,
                    place: Place {
                        branch: b as u16,
                        depth,
                    },
                    since: 0,
                });
                robot += 1;
            }
        }
        seats
    }
}

/// Which robot holds which place, as one robot knows it.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct Roster {
    seats: BTreeMap<RobotId, Seat>,
}

impl Roster {
    pub fn new(seats: &[Seat]) -> Roster {
        let mut r = Roster::default();
        r.merge(seats);
        r
    }

    /// Takes every claim newer than the one held for its robot; returns whether anything changed.
    pub fn merge(&mut self, seats: &[Seat]) -> bool {
        let mut changed = false;
        for s in seats {
            let newer = self.seats.get(&s.robot).is_none_or(|h| s.since > h.since);
            if newer {
                self.seats.insert(s.robot, *s);
                changed = true;
            }
        }
        changed
    }

    /// Robot `robot` holds `place` since `since` (whatever was held before).
    pub fn set(&mut self, robot: RobotId, place: Place, since: Step) {
        self.seats.insert(
            robot,
            Seat {
                robot,
                place,
                since,
            },
        );
    }

    pub fn seat(&self, robot: RobotId) -> Option<&Seat> {
        self.seats.get(&robot)
    }

    /// The robot at `place`: of several claims, the newest (then the lowest id).
    pub fn at(&self, place: Place) -> Option<RobotId> {
        self.seats
            .values()
            .filter(|s| s.place == place)
            .max_by_key(|s| (s.since, std::cmp::Reverse(s.robot)))
            .map(|s| s.robot)
    }

    pub fn seats(&self) -> Vec<Seat> {
        self.seats.values().copied().collect()
    }
}

/// The role swap rule (§V): robots A and B, heading for goals G_A and G_B, swap roles, states
/// and places when max(γ(A, G_A), γ(B, G_B)) > max(γ(A, G_B), γ(B, G_A)) — the longest of the
/// four paths is one they would otherwise drive. Arguments are the path costs γ(A, G_A),
/// γ(B, G_B), γ(A, G_B), γ(B, G_A).
pub fn swap_pays(a_ga: f64, b_gb: f64, a_gb: f64, b_ga: f64) -> bool {
    a_ga.max(b_gb) > a_gb.max(b_ga)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn place(branch: u16, depth: u16) -> Place {
        Place { branch, depth }
    }

    #[test]
    fn ten_robots_make_five_pairs_of_relay_and_explorer() {
        let s = Shape::new(10, 1);
        assert_eq!(s.branches(), 5);
        let seats = s.dealt();
        assert_eq!(seats.len(), 10);
        assert_eq!(seats[0].place, place(0, 0));
        assert_eq!(seats[1].place, place(0, 1));
        assert_eq!(seats[9].place, place(4, 1));
        assert_eq!(s.role(place(0, 0)), Role::Relay);
        assert_eq!(s.role(place(0, 1)), Role::Explorer);
        assert_eq!(s.parent(place(0, 0)), None);
        assert_eq!(s.parent(place(3, 1)), Some(place(3, 0)));
        assert_eq!(s.child(place(3, 0)), Some(place(3, 1)));
        assert_eq!(s.child(place(3, 1)), None);
    }

    #[test]
    fn an_odd_team_ends_with_a_shorter_branch_and_chains_are_allowed() {
        let s = Shape::new(5, 1);
        assert_eq!(s.branches(), 3);
        assert_eq!(s.role(place(2, 0)), Role::Explorer);
        assert!(!s.contains(place(2, 1)));
        let chain = Shape::new(6, 2);
        assert_eq!(chain.branches(), 2);
        assert_eq!(chain.role(place(0, 1)), Role::Relay);
        assert_eq!(chain.parent(place(0, 2)), Some(place(0, 1)));
        assert_eq!(chain.role(place(1, 2)), Role::Explorer);
        let alone = Shape::new(3, 0);
        assert_eq!(alone.branches(), 3);
        assert_eq!(alone.role(place(1, 0)), Role::Explorer);
        assert_eq!(alone.parent(place(1, 0)), None);
    }

    #[test]
    fn the_newest_claim_of_a_place_wins() {
        let s = Shape::new(4, 1);
        let mut r = Roster::new(&s.dealt());
        assert_eq!(r.at(place(0, 1)), Some(1));
        // Robots 1 and 3 (both explorers) swapped at step 20; robot 0 hears of robot 3 first.
        assert!(r.merge(&[Seat {
            robot: 3,
            place: place(0, 1),
            since: 20,
        }]));
        assert_eq!(r.at(place(0, 1)), Some(3));
        // An old claim changes nothing.
        assert!(!r.merge(&[Seat {
            robot: 3,
            place: place(1, 1),
            since: 0,
        }]));
        assert!(r.merge(&[Seat {
            robot: 1,
            place: place(1, 1),
            since: 20,
        }]));
        assert_eq!(r.at(place(1, 1)), Some(1));
        assert_eq!(r.seat(0).map(|s| s.place), Some(place(0, 0)));
    }

    #[test]
    fn the_swap_rule_drops_the_longest_of_the_four_paths() {
        // de Hoog et al. Fig. 4: the relay (B) is much nearer the new frontier (G_A) than the
        // explorer (A), and the explorer nearer the base (G_B): swap.
        assert!(swap_pays(40.0, 30.0, 5.0, 8.0));
        // Each already nearer its own goal: no swap.
        assert!(!swap_pays(5.0, 8.0, 40.0, 30.0));
        // Side by side: the same costs both ways, no swap (the rule is strict).
        assert!(!swap_pays(10.0, 20.0, 20.0, 10.0));
        // Only the longest path matters: A far from its goal, B's way to it even longer.
        assert!(!swap_pays(30.0, 1.0, 2.0, 31.0));
        assert!(swap_pays(30.0, 1.0, 2.0, 29.0));
    }
}
