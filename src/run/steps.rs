//! Telemetry taken a whole step at a time, in robot order (lockstep runs).
//!
//! Robots report each step on the sim plane, and their reports reach the launcher in whatever order
//! the processes and zenoh's queues happened to deliver them — a robot's report of step t can even
//! come after the world's status of t+2. What the launcher records and when it decides that a run
//! is over must not depend on that: it takes step t only once every robot alive at t has reported
//! it, and then the reports in robot id order. A robot is not awaited once a later status shows it
//! dead or says the world went on without its command for t (a timeout, which makes the run
//! nondeterministic anyway), nor once the world is
//! [`GIVE_UP_STEPS`](crate::run::steps::GIVE_UP_STEPS) steps further (a report that comes after
//! that is late, and said so).

use std::collections::{BTreeMap, BTreeSet};

use proto::msg::{RobotId, Status, Step, Telemetry};

/// How many steps the world may be ahead before a missing report is given up on.
pub const GIVE_UP_STEPS: Step = 50;

#[derive(Debug, Default)]
pub struct StepOrder {
    /// Per step, the robots whose reports are awaited: alive in its status, not since found
    /// dead or missed.
    alive: BTreeMap<Step, BTreeSet<RobotId>>,
    /// Reports not taken yet, by step and robot.
    pending: BTreeMap<Step, BTreeMap<RobotId, Telemetry>>,
    /// The next step to take.
    next: Step,
    /// The latest status's step.
    latest: Option<Step>,
    /// Reports that arrived after their step was taken: (step, robot).
    pub late: Vec<(Step, RobotId)>,
}

impl StepOrder {
    pub fn on_status(&mut self, st: &Status) {
        // Every node reports: the robots and the base station.
        let nodes = || st.robots.iter().chain(&st.base);
        let alive = nodes().filter(|r| r.alive).map(|r| r.id).collect();
        // Not awaited any more: nodes this status shows dead (at every earlier step), and
        // those the world went on without at the step before.
        let dead: Vec<RobotId> = nodes().filter(|r| !r.alive).map(|r| r.id).collect();
        for (&step, awaited) in self.alive.iter_mut() {
            awaited.retain(|id| !dead.contains(id));
            if step.saturating_add(1) == st.step {
                awaited.retain(|id| !st.missed.contains(id));
            }
        }
        self.alive.insert(st.step, alive);
        self.latest = Some(self.latest.map_or(st.step, |l| l.max(st.step)));
    }

    /// Keeps a report until its step is taken; one whose step was taken already is late: it is
    /// noted and handed back.
    pub fn on_telemetry(&mut self, t: Telemetry) -> Option<Telemetry> {
        if t.step < self.next {
            self.late.push((t.step, t.robot));
            return Some(t);
        }
        self.pending.entry(t.step).or_default().insert(t.robot, t);
        None
    }

    /// The next step that is complete, with its reports in robot order.
    pub fn take(&mut self) -> Option<(Step, Vec<Telemetry>)> {
        let step = self.next;
        let alive = self.alive.get(&step)?;
        let got = self.pending.get(&step);
        let all_in = alive
            .iter()
            .all(|id| got.is_some_and(|g| g.contains_key(id)));
        let world_moved_on = self
            .latest
            .is_some_and(|l| l >= step.saturating_add(GIVE_UP_STEPS));
        if !(all_in || world_moved_on) {
            return None;
        }
        self.alive.remove(&step);
        self.next = step + 1;
        let reports = self.pending.remove(&step).unwrap_or_default();
        Some((step, reports.into_values().collect()))
    }

    /// Steps taken so far (the next one to take).
    pub fn next(&self) -> Step {
        self.next
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proto::geom::Pose;
    use proto::msg::RobotStatus;

    fn status(step: Step, alive: &[RobotId]) -> Status {
        Status {
            step,
            robots: (0..3)
                .map(|id| RobotStatus {
                    id,
                    pose: Pose::default(),
                    alive: alive.contains(&id),
                    distance_m: 0.0,
                })
                .collect(),
            collisions_total: 0,
            blocked_total: 0,
            base: None,
            missed: Vec::new(),
        }
    }

    fn tel(step: Step, robot: RobotId) -> Telemetry {
        Telemetry {
            step,
            robot,
            ..Telemetry::default()
        }
    }

    #[test]
    fn a_step_is_taken_whole_and_in_robot_order_whatever_the_arrival_order() {
        let mut o = StepOrder::default();
        o.on_status(&status(0, &[0, 1, 2]));
        o.on_telemetry(tel(0, 2));
        o.on_telemetry(tel(1, 0));
        o.on_telemetry(tel(0, 0));
        assert!(o.take().is_none(), "robot 1 has not reported step 0");
        o.on_telemetry(tel(0, 1));
        let (step, reports) = o.take().expect("step 0 is complete");
        assert_eq!(step, 0);
        assert_eq!(
            reports.iter().map(|t| t.robot).collect::<Vec<_>>(),
            [0, 1, 2]
        );
        assert!(o.take().is_none(), "no status for step 1 yet");
    }

    #[test]
    fn dead_or_missed_robots_are_not_awaited_and_the_world_far_ahead_gives_up() {
        let mut o = StepOrder::default();
        o.on_status(&status(0, &[0, 2]));
        o.on_telemetry(tel(0, 0));
        o.on_telemetry(tel(0, 2));
        assert_eq!(o.take().map(|(s, r)| (s, r.len())), Some((0, 2)));
        o.on_status(&status(1, &[0, 2]));
        o.on_telemetry(tel(1, 0));
        o.on_status(&status(2, &[0, 2]));
        o.on_status(&status(3, &[0, 2]));
        assert!(
            o.take().is_none(),
            "robot 2's report of step 1 may still come"
        );
        let mut st = status(2, &[0, 2]);
        st.missed = vec![2];
        o.on_status(&st);
        assert_eq!(o.take().map(|(s, r)| (s, r.len())), Some((1, 1)));
        let late = o.on_telemetry(tel(1, 2));
        assert_eq!(late.map(|t| (t.step, t.robot)), Some((1, 2)), "handed back");
        assert_eq!(o.late, [(1, 2)]);
        o.on_telemetry(tel(2, 0));
        o.on_status(&status(4, &[0]));
        assert_eq!(
            o.take().map(|(s, r)| (s, r.len())),
            Some((2, 1)),
            "robot 2 died"
        );
        o.on_status(&status(3 + GIVE_UP_STEPS, &[0]));
        assert_eq!(o.take().map(|(s, r)| (s, r.len())), Some((3, 0)));
    }
}
