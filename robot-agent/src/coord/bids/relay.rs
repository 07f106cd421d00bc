//! Bids and assignments over a multi-hop radio (`bids`): Simmons et al. (2000) send bids to the
//! central executive and tasks back over a radio that reaches everyone; here a robot may reach
//! the base station only through others, so every node relays them — transitively, like the
//! maps, each stamped with the step it was made at so that its age is known wherever it
//! arrives.
//!
//! Every node holds the newest bid of every robot and the newest assignment table, and tells a
//! neighbour only what it lacks: per neighbour, the versions sent to it or heard from it. A
//! neighbour that comes (back) into range is assumed to hold nothing. Tables flood (they are
//! small and every robot needs one); bids go toward the base station only — to the base itself
//! when it is a neighbour, else to the neighbour the newest table came from (the reverse path of
//! the table's flood), and to every neighbour while no such neighbour is in range.

use std::collections::{BTreeMap, BTreeSet};

use proto::msg::{Bid, Bids, RobotId, Step, Tasks};

use crate::coord::{Addressed, CoordMsg, To};

/// What one neighbour holds, as far as this node knows.
#[derive(Clone, Debug, Default)]
struct Held {
    /// Per robot, the step of the newest bid of it the neighbour has.
    bids: BTreeMap<RobotId, Step>,
    /// The step of the newest table the neighbour has.
    tasks: Option<Step>,
}

#[derive(Clone, Debug)]
pub struct Relay {
    me: RobotId,
    base: RobotId,
    bids: BTreeMap<RobotId, Bid>,
    tasks: Option<Tasks>,
    held: BTreeMap<RobotId, Held>,
    /// The neighbour the newest table came from: toward the base station.
    uplink: Option<RobotId>,
}

impl Relay {
    /// The relay of node `me` in a run whose base station is node `base`.
    pub fn new(me: RobotId, base: RobotId) -> Relay {
        Relay {
            me,
            base,
            bids: BTreeMap::new(),
            tasks: None,
            held: BTreeMap::new(),
            uplink: None,
        }
    }

    /// Every robot's newest bid this node holds.
    pub fn bids(&self) -> &BTreeMap<RobotId, Bid> {
        &self.bids
    }

    /// The newest assignment table this node holds.
    pub fn tasks(&self) -> Option<&Tasks> {
        self.tasks.as_ref()
    }

    /// Keeps `bid` if it is newer than the one held of its robot; whether it was.
    pub fn put_bid(&mut self, bid: Bid) -> bool {
        if self
            .bids
            .get(&bid.robot)
            .is_some_and(|b| b.step >= bid.step)
        {
            return false;
        }
        self.bids.insert(bid.robot, bid);
        true
    }

    /// Keeps `tasks` if it is newer than the table held; whether it was.
    pub fn put_tasks(&mut self, tasks: Tasks) -> bool {
        if self.tasks.as_ref().is_some_and(|t| t.step >= tasks.step) {
            return false;
        }
        self.tasks = Some(tasks);
        true
    }

    /// Bids heard from neighbour `m.from`: the robots whose bid was news.
    pub fn on_bids(&mut self, m: &Bids) -> Vec<RobotId> {
        let held = self.held.entry(m.from).or_default();
        for b in &m.bids {
            let h = held.bids.entry(b.robot).or_insert(b.step);
            *h = (*h).max(b.step);
        }
        let me = self.me;
        let mut news = Vec::new();
        for b in m.bids.iter().filter(|b| b.robot != me) {
            if self.put_bid(b.clone()) {
                news.push(b.robot);
            }
        }
        news
    }

    /// A table heard from neighbour `m.from`; whether it was news.
    pub fn on_tasks(&mut self, m: &Tasks) -> bool {
        let held = self.held.entry(m.from).or_default();
        held.tasks = Some(held.tasks.map_or(m.step, |s| s.max(m.step)));
        let mut t = m.clone();
        t.from = self.me;
        let news = self.put_tasks(t);
        if news {
            self.uplink = Some(m.from);
        }
        news
    }

    /// What each of `neighbours` lacks, as messages; counted as held by them from now on. A
    /// neighbour not in the last call's set starts from nothing.
    pub fn messages(&mut self, neighbours: &BTreeSet<RobotId>) -> Vec<Addressed> {
        self.held.retain(|p, _| neighbours.contains(p));
        for &p in neighbours {
            self.held.entry(p).or_default();
        }
        let toward_base: Vec<RobotId> = if self.me == self.base {
            Vec::new()
        } else if neighbours.contains(&self.base) {
            vec![self.base]
        } else if let Some(up) = self.uplink.filter(|u| neighbours.contains(u)) {
            vec![up]
        } else {
            neighbours.iter().copied().collect()
        };
        let mut out = Vec::new();
        for (&peer, held) in self.held.iter_mut() {
            if toward_base.contains(&peer) {
                let lacking: Vec<Bid> = self
                    .bids
                    .values()
                    .filter(|b| b.robot != peer)
                    .filter(|b| held.bids.get(&b.robot).is_none_or(|&s| s < b.step))
                    .cloned()
                    .collect();
                for b in &lacking {
                    held.bids.insert(b.robot, b.step);
                }
                if !lacking.is_empty() {
                    out.push(Addressed {
                        to: To::Robot(peer),
                        msg: CoordMsg::Bids(Bids {
                            from: self.me,
                            bids: lacking,
                        }),
                    });
                }
            }
            if let Some(t) = &self.tasks {
                if held.tasks.is_none_or(|s| s < t.step) {
                    held.tasks = Some(t.step);
                    let mut t = t.clone();
                    t.from = self.me;
                    out.push(Addressed {
                        to: To::Robot(peer),
                        msg: CoordMsg::Tasks(t),
                    });
                }
            }
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proto::msg::TaskEntry;

    fn bid(robot: RobotId, step: Step) -> Bid {
        Bid {
            robot,
            step,
            offers: Vec::new(),
        }
    }

    fn tasks(from: RobotId, step: Step) -> Tasks {
        Tasks {
            from,
            step,
            tasks: vec![TaskEntry {
                robot: 0,
                task: None,
            }],
        }
    }

    fn set(ids: &[RobotId]) -> BTreeSet<RobotId> {
        ids.iter().copied().collect()
    }

    /// Who gets what: (addressee, "bids" of robots / "tasks" at step).
    fn summary(out: &[Addressed]) -> Vec<(RobotId, String)> {
        out.iter()
            .map(|a| {
                let To::Robot(to) = a.to else {
                    return (RobotId::MAX, String::new());
                };
                let what = match &a.msg {
                    CoordMsg::Bids(b) => format!(
                        "bids {:?}",
                        b.bids.iter().map(|b| (b.robot, b.step)).collect::<Vec<_>>()
                    ),
                    CoordMsg::Tasks(t) => format!("tasks {}", t.step),
                    CoordMsg::Team(_) => "team".into(),
                    CoordMsg::Role(_) => "role".into(),
                    CoordMsg::Pack(_) => "move".into(),
                };
                (to, what)
            })
            .collect()
    }

    #[test]
    fn a_bid_travels_toward_the_base_and_a_table_floods_back_once_per_version() {
        // Line 0 – 1 – 3 (base), node 1 relays; and 2 hangs off 1.
        let base = 3;
        let mut r1 = Relay::new(1, base);
        let mut r0 = Relay::new(0, base);
        r0.put_bid(bid(0, 5));
        // No table yet: robot 0 floods its bid to every neighbour (only 1 here).
        let out = r0.messages(&set(&[1]));
        assert_eq!(summary(&out), [(1, "bids [(0, 5)]".to_string())]);
        let CoordMsg::Bids(m) = &out[0].msg else {
            panic!("a bid message")
        };
        assert_eq!(r1.on_bids(m), [0]);
        assert_eq!(r1.on_bids(m), Vec::<RobotId>::new(), "old news");
        // 1 sees the base: the bid goes to the base only, not back to 0 and not to 2.
        let out = r1.messages(&set(&[0, 2, base]));
        assert_eq!(summary(&out), [(base, "bids [(0, 5)]".to_string())]);
        assert!(r1.messages(&set(&[0, 2, base])).is_empty(), "sent once");
        // A table from the base floods to 0 and 2, not back to the base.
        assert!(r1.on_tasks(&tasks(base, 6)));
        let out = r1.messages(&set(&[0, 2, base]));
        assert_eq!(
            summary(&out),
            [(0, "tasks 6".to_string()), (2, "tasks 6".to_string())]
        );
        assert!(!r1.on_tasks(&tasks(base, 6)), "old news");
        // 0 learns its uplink from the table: its next bid goes to 1 only (and 0 passes the
        // table on to its other neighbour).
        let CoordMsg::Tasks(t) = &out[0].msg else {
            panic!("a table")
        };
        assert!(r0.on_tasks(t));
        r0.put_bid(bid(0, 9));
        let out = r0.messages(&set(&[1, 4]));
        assert_eq!(
            summary(&out),
            [(1, "bids [(0, 9)]".to_string()), (4, "tasks 6".to_string())]
        );
    }

    #[test]
    fn a_neighbour_that_comes_back_is_told_again() {
        let mut r = Relay::new(1, 3);
        assert!(r.put_tasks(tasks(3, 2)));
        assert_eq!(r.messages(&set(&[0])).len(), 1);
        assert!(r.messages(&set(&[0])).is_empty());
        assert!(r.messages(&set(&[])).is_empty());
        assert_eq!(r.messages(&set(&[0])).len(), 1, "0 was out of range");
        assert!(!r.put_tasks(tasks(3, 1)), "an older table is not kept");
        assert_eq!(r.tasks().map(|t| t.step), Some(2));
    }
}
