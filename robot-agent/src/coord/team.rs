//! The team table that `burgard` and `pack` share: every robot's newest report — its cell, its
//! target, its radio neighbours at a step — heard directly or relayed from neighbour to
//! neighbour, and the group that can talk, transitively, computed from it.
//!
//! A report older than the table's freshness no longer counts: its robot has left the group (or
//! its news has not come through for that long).

use std::collections::{BTreeMap, BTreeSet};

use proto::grid::Cell;
use proto::msg::{RobotId, Step, TeamEntry};

#[derive(Clone, Debug)]
pub struct Table {
    /// Reports at most this many steps old count.
    fresh_steps: Step,
    entries: BTreeMap<RobotId, TeamEntry>,
}

impl Table {
    pub fn new(fresh_steps: Step) -> Table {
        Table {
            fresh_steps,
            entries: BTreeMap::new(),
        }
    }

    fn is_fresh(&self, e: &TeamEntry, step: Step) -> bool {
        e.step.saturating_add(self.fresh_steps) >= step
    }

    /// Reports heard from a neighbour: newer ones replace older ones; `me`'s own are left out
    /// (a robot knows itself best).
    pub fn merge(&mut self, me: RobotId, entries: &[TeamEntry]) {
        for e in entries.iter().filter(|e| e.robot != me) {
            if self
                .entries
                .get(&e.robot)
                .is_none_or(|old| old.step < e.step)
            {
                self.entries.insert(e.robot, e.clone());
            }
        }
    }

    /// `robot`'s report if it is fresh at `step`.
    pub fn get(&self, robot: RobotId, step: Step) -> Option<&TeamEntry> {
        self.entries.get(&robot).filter(|e| self.is_fresh(e, step))
    }

    /// Every report fresh at `step`, by robot.
    pub fn fresh(&self, step: Step) -> impl Iterator<Item = &TeamEntry> {
        self.entries
            .values()
            .filter(move |e| self.is_fresh(e, step))
    }

    /// Every report, fresh or not, by robot.
    pub fn all(&self) -> impl Iterator<Item = &TeamEntry> {
        self.entries.values()
    }

    /// What to send: `own` first, then every fresh report.
    pub fn to_send(&self, own: TeamEntry) -> Vec<TeamEntry> {
        let step = own.step;
        let mut out = vec![own];
        out.extend(self.fresh(step).cloned());
        out
    }

    /// The robots `me` can reach over current links, transitively (itself included, sorted):
    /// its own `neighbours` and the links in the fresh reports; a robot counts once its own
    /// report (and so its cell) is known. `ignore` (the base station) is never a member and
    /// carries no link.
    pub fn group(
        &self,
        me: RobotId,
        neighbours: &BTreeSet<RobotId>,
        step: Step,
        ignore: Option<RobotId>,
    ) -> Vec<RobotId> {
        let edges = self.edges(me, neighbours, step, ignore);
        let mut group = vec![me];
        let mut i = 0;
        while i < group.len() {
            let r = group[i];
            for &(a, b) in &edges {
                let other = if a == r {
                    b
                } else if b == r {
                    a
                } else {
                    continue;
                };
                if !group.contains(&other) {
                    group.push(other);
                }
            }
            i += 1;
        }
        group.retain(|&r| r == me || self.get(r, step).is_some());
        group.sort_unstable();
        group
    }

    /// The links the group is made of: `me`'s and those of the fresh reports.
    fn edges(
        &self,
        me: RobotId,
        neighbours: &BTreeSet<RobotId>,
        step: Step,
        ignore: Option<RobotId>,
    ) -> Vec<(RobotId, RobotId)> {
        let mut edges: Vec<(RobotId, RobotId)> = neighbours.iter().map(|&n| (me, n)).collect();
        for e in self.fresh(step) {
            edges.extend(e.neighbours.iter().map(|&n| (e.robot, n)));
        }
        edges.retain(|&(a, b)| Some(a) != ignore && Some(b) != ignore && a != b);
        edges
    }
}

/// `robot`'s own report at `step`.
pub fn entry(
    robot: RobotId,
    step: Step,
    cell: Cell,
    target: Option<Cell>,
    neighbours: &BTreeSet<RobotId>,
) -> TeamEntry {
    TeamEntry {
        robot,
        step,
        cell,
        target,
        neighbours: neighbours.iter().copied().collect(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn report(robot: RobotId, step: Step, neighbours: &[RobotId]) -> TeamEntry {
        TeamEntry {
            robot,
            step,
            cell: Cell::new(i32::from(robot), 0),
            target: None,
            neighbours: neighbours.to_vec(),
        }
    }

    #[test]
    fn the_group_is_what_fresh_links_reach() {
        let mut t = Table::new(3);
        // 0 – 1 – 2, and 3 alone; 4's report is stale.
        t.merge(0, &[report(1, 10, &[0, 2]), report(2, 9, &[1])]);
        t.merge(0, &[report(3, 10, &[]), report(4, 5, &[2])]);
        let mine = BTreeSet::from([1]);
        assert_eq!(t.group(0, &mine, 10, None), [0, 1, 2]);
        assert_eq!(
            t.group(0, &mine, 13, None),
            [0, 1],
            "2's report is now stale"
        );
        // A newer report replaces an older one, an older one does not.
        t.merge(0, &[report(1, 11, &[0])]);
        t.merge(0, &[report(1, 8, &[0, 2, 3])]);
        assert_eq!(t.get(1, 11).map(|e| e.neighbours.clone()), Some(vec![0]));
        // A link counts from either end; the base station carries none.
        t.merge(0, &[report(2, 11, &[1, 9]), report(3, 11, &[9])]);
        assert_eq!(t.group(0, &BTreeSet::from([1, 9]), 11, Some(9)), [0, 1, 2]);
    }
}
