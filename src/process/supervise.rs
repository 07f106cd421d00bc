//! Supervision and process faults: what the launcher does to the run's processes, and when.
//!
//! Three sources of actions, all on the world's clock (the step of the latest status):
//!
//! * the scenario's process faults (`[[faults]]` of kind `kill`, `restart`, `freeze`, `thaw`;
//!   [`proto::scenario::ProcessFault`]), carried out when the run reaches their step;
//! * the same faults asked for at runtime through netem's API (`POST /processes/<name>`, which
//!   netem hands on over the sim plane), carried out at the next step;
//! * supervision (`[supervise]`): a process of a supervised kind that dies unexpectedly — a
//!   crash, or a signal from outside the run — is started again `delay_steps` later, at most
//!   `max_restarts` times.
//!
//! A restarted process gets the flags, ports and log of its first life; a robot (or the base
//! station) also its life number, so that it writes a new log and takes its earlier lives' logs
//! back from its peers (`proto::msg::log_owner`). Everything done is an
//! [`Event`](crate::process::supervise::Event) in `summary.json`'s `process_events`.
//!
//! This module decides; `run::follow` carries the [`Action`](crate::process::supervise::Action)s
//! out on the children.
//!
//! **Invariant:** a process killed on purpose is never taken for a crash, and a process is
//! never restarted more often than its policy says, nor beyond [`proto::msg::MAX_LIVES`].

use std::collections::{BTreeMap, BTreeSet};

use proto::exit::ExitReason;
use proto::msg::{Step, MAX_LIVES};
use proto::scenario::{Process, ProcessAction, ProcessFault, Supervise};
use serde::{Deserialize, Serialize};

/// What the launcher is to do to a process now.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Action {
    /// SIGKILL (and reap).
    Kill(Process),
    /// Start it in its life `life`.
    Start(Process, u16),
    /// SIGSTOP.
    Freeze(Process),
    /// SIGCONT.
    Thaw(Process),
}

/// One thing that happened to a process, for `summary.json`.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Event {
    /// The world's step when it happened.
    pub step: Step,
    pub process: Process,
    pub event: EventKind,
    /// Why: `fault` (the scenario's `[[faults]]`), `api` (netem's API), `supervised`, or how
    /// it died.
    pub cause: String,
    /// The process's life after the event (a robot's life names the log it writes).
    pub life: u16,
}

/// What happened to a process: `event` in `summary.json`'s `process_events`, serialized as
/// [`EventKind::as_str`] (docs/run-directory.md lists these names; they do not change).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum EventKind {
    /// Killed (SIGKILL) by a process fault.
    Killed,
    /// A kill asked for a process that was not running: nothing was done.
    NotKilled,
    /// Started in its next life (`life`).
    Started,
    /// A start that could not be: the process had its most lives or restarts.
    NotRestarted,
    /// SIGSTOP.
    Frozen,
    /// SIGCONT.
    Thawed,
    /// Died without the launcher killing it (`cause`: its exit status).
    Died,
}

impl EventKind {
    pub const ALL: [EventKind; 7] = [
        EventKind::Killed,
        EventKind::NotKilled,
        EventKind::Started,
        EventKind::NotRestarted,
        EventKind::Frozen,
        EventKind::Thawed,
        EventKind::Died,
    ];

    /// The name in `summary.json` (the serde name).
    pub fn as_str(self) -> &'static str {
        match self {
            EventKind::Killed => "killed",
            EventKind::NotKilled => "not-killed",
            EventKind::Started => "started",
            EventKind::NotRestarted => "not-restarted",
            EventKind::Frozen => "frozen",
            EventKind::Thawed => "thawed",
            EventKind::Died => "died",
        }
    }
}

impl std::fmt::Display for EventKind {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.as_str())
    }
}

/// The launcher's bookkeeping of process faults and restarts.
#[derive(Debug)]
pub struct Supervisor {
    policy: Supervise,
    /// The scenario's process faults still to come, in step order.
    faults: Vec<ProcessFault>,
    next: usize,
    /// Starts due: (step, process, cause).
    due: Vec<(Step, Process, &'static str)>,
    /// Each process's current life (0 until its first restart).
    lives: BTreeMap<Process, u16>,
    /// Restarts supervision made, per process.
    restarts: BTreeMap<Process, u16>,
    frozen: BTreeSet<Process>,
    /// Processes that are not running (killed or died) and not yet started again.
    down: BTreeSet<Process>,
    /// Faults asked for at runtime ([`Supervisor::ask`]), for the next step.
    asked: Vec<ProcessAction>,
    step: Step,
    pub events: Vec<Event>,
}

impl Supervisor {
    pub fn new(policy: Supervise, faults: Vec<ProcessFault>) -> Supervisor {
        Supervisor {
            policy,
            faults,
            next: 0,
            due: Vec::new(),
            lives: BTreeMap::new(),
            restarts: BTreeMap::new(),
            frozen: BTreeSet::new(),
            down: BTreeSet::new(),
            asked: Vec::new(),
            step: 0,
            events: Vec::new(),
        }
    }

    /// `process`'s current life.
    pub fn life(&self, process: Process) -> u16 {
        self.lives.get(&process).copied().unwrap_or(0)
    }

    /// Every robot's lives so far, as (robot, life) pairs, first lives included.
    pub fn lives(&self) -> &BTreeMap<Process, u16> {
        &self.lives
    }

    /// The processes frozen now (to be thawed before the run is stopped).
    pub fn frozen(&self) -> impl Iterator<Item = Process> + '_ {
        self.frozen.iter().copied()
    }

    fn event(&mut self, process: Process, event: EventKind, cause: impl Into<String>) {
        self.events.push(Event {
            step: self.step,
            process,
            event,
            cause: cause.into(),
            life: self.life(process),
        });
    }

    /// The next life of `process`, if it may have one.
    fn next_life(&self, process: Process) -> Option<u16> {
        let next = self.life(process).checked_add(1)?;
        (next < MAX_LIVES).then_some(next)
    }

    /// Starts `process` in its next life now, recorded with `cause`.
    fn start(&mut self, process: Process, cause: &'static str, out: &mut Vec<Action>) {
        match self.next_life(process) {
            Some(life) => {
                self.lives.insert(process, life);
                self.down.remove(&process);
                self.frozen.remove(&process);
                self.event(process, EventKind::Started, cause);
                out.push(Action::Start(process, life));
            }
            None => self.event(
                process,
                EventKind::NotRestarted,
                format!("{cause}: it had its most lives ({MAX_LIVES})"),
            ),
        }
    }

    /// The world reached `step`: the scenario's faults of the step and the restarts due, as
    /// actions to carry out now, in order.
    pub fn on_step(&mut self, step: Step) -> Vec<Action> {
        self.step = self.step.max(step);
        let mut out = Vec::new();
        let due: Vec<_> = self.due.iter().filter(|d| d.0 <= step).copied().collect();
        self.due.retain(|d| d.0 > step);
        for (_, p, cause) in due {
            if self.down.contains(&p) {
                self.start(p, cause, &mut out);
            }
        }
        while let Some(f) = self
            .faults
            .get(self.next)
            .filter(|f| f.step <= step)
            .cloned()
        {
            self.next += 1;
            self.apply(step, f.action, "fault", &mut out);
        }
        for action in std::mem::take(&mut self.asked) {
            self.apply(step, action, "api", &mut out);
        }
        out
    }

    /// A process fault asked for at runtime (netem's API): carried out at the next step, after
    /// the scenario's faults of that step.
    pub fn ask(&mut self, action: ProcessAction) {
        self.asked.push(action);
    }

    /// Carries out a process fault at `step` (`cause`: `fault` or `api`).
    fn apply(
        &mut self,
        step: Step,
        action: ProcessAction,
        cause: &'static str,
        out: &mut Vec<Action>,
    ) {
        let p = action.process();
        match action {
            ProcessAction::Kill { restart_after, .. } => {
                if !self.down.insert(p) {
                    self.event(
                        p,
                        EventKind::NotKilled,
                        format!("{cause}: it was not running"),
                    );
                    return;
                }
                self.frozen.remove(&p);
                self.event(p, EventKind::Killed, cause);
                out.push(Action::Kill(p));
                if let Some(k) = restart_after {
                    self.due.push((step.saturating_add(k), p, cause));
                }
            }
            ProcessAction::Restart { .. } => {
                if self.down.insert(p) {
                    self.event(p, EventKind::Killed, cause);
                    out.push(Action::Kill(p));
                }
                self.start(p, cause, out);
            }
            ProcessAction::Freeze { .. } => {
                if !self.down.contains(&p) && self.frozen.insert(p) {
                    self.event(p, EventKind::Frozen, cause);
                    out.push(Action::Freeze(p));
                }
            }
            ProcessAction::Thaw { .. } => {
                if self.frozen.remove(&p) {
                    self.event(p, EventKind::Thawed, cause);
                    out.push(Action::Thaw(p));
                }
            }
        }
    }

    /// `process` died without the launcher killing it (`how`: its exit status). Returns the
    /// end of the run it means, if any: the world-server's loss always ends it, netem's when it
    /// is not restarted. A supervised process is started again `delay_steps` later.
    pub fn died(&mut self, process: Process, how: &str) -> Option<ExitReason> {
        self.down.insert(process);
        self.frozen.remove(&process);
        self.event(process, EventKind::Died, how);
        let supervised = self.policy.restart.contains(&process.kind());
        let used = self.restarts.get(&process).copied().unwrap_or(0);
        if supervised && used < self.policy.max_restarts && self.next_life(process).is_some() {
            *self.restarts.entry(process).or_default() += 1;
            let at = self.step.saturating_add(self.policy.delay_steps);
            self.due.push((at, process, "supervised"));
            return None;
        }
        if supervised {
            self.event(
                process,
                EventKind::NotRestarted,
                format!(
                    "supervised: it had its {} restarts (supervise.max_restarts)",
                    self.policy.max_restarts
                ),
            );
        }
        match process {
            Process::WorldServer => Some(ExitReason::WorldServerExited),
            Process::Netem => Some(ExitReason::NetemExited),
            Process::Robot(_) | Process::BaseStation => None,
        }
    }

    /// Whether a restart of `process` is still to come (it is down for now).
    pub fn restarting(&self, process: Process) -> bool {
        self.due.iter().any(|d| d.1 == process)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proto::scenario::ProcessKind;

    fn fault(step: Step, action: ProcessAction) -> ProcessFault {
        ProcessFault { step, action }
    }

    #[test]
    fn scheduled_faults_come_at_their_step_and_a_killed_robot_returns_in_its_next_life() {
        let r2 = Process::Robot(2);
        let mut s = Supervisor::new(
            Supervise::default(),
            vec![
                fault(
                    5,
                    ProcessAction::Kill {
                        process: r2,
                        restart_after: Some(3),
                    },
                ),
                fault(
                    6,
                    ProcessAction::Freeze {
                        process: Process::Robot(1),
                    },
                ),
                fault(
                    9,
                    ProcessAction::Thaw {
                        process: Process::Robot(1),
                    },
                ),
                fault(
                    9,
                    ProcessAction::Restart {
                        process: Process::Netem,
                    },
                ),
            ],
        );
        assert!(s.on_step(4).is_empty());
        assert_eq!(s.on_step(5), vec![Action::Kill(r2)]);
        assert_eq!(s.on_step(6), vec![Action::Freeze(Process::Robot(1))]);
        assert_eq!(s.frozen().collect::<Vec<_>>(), vec![Process::Robot(1)]);
        assert!(s.on_step(7).is_empty());
        assert_eq!(s.on_step(8), vec![Action::Start(r2, 1)]);
        assert_eq!(
            s.on_step(9),
            vec![
                Action::Thaw(Process::Robot(1)),
                Action::Kill(Process::Netem),
                Action::Start(Process::Netem, 1)
            ]
        );
        assert_eq!(s.life(r2), 1);
        let kinds: Vec<_> = s.events.iter().map(|e| (e.step, e.event)).collect();
        assert_eq!(
            kinds,
            vec![
                (5, EventKind::Killed),
                (6, EventKind::Frozen),
                (8, EventKind::Started),
                (9, EventKind::Thawed),
                (9, EventKind::Killed),
                (9, EventKind::Started)
            ]
        );
    }

    #[test]
    fn supervision_restarts_what_it_covers_as_often_as_it_may_and_the_world_never() {
        let policy = Supervise {
            restart: vec![ProcessKind::Robot],
            delay_steps: 2,
            max_restarts: 1,
        };
        let mut s = Supervisor::new(policy, Vec::new());
        s.on_step(10);
        assert_eq!(s.died(Process::Robot(0), "signal 9"), None);
        assert!(s.restarting(Process::Robot(0)));
        assert!(s.on_step(11).is_empty());
        assert_eq!(s.on_step(12), vec![Action::Start(Process::Robot(0), 1)]);
        // Its one restart is used: the second death is final (the run goes on without it).
        assert_eq!(s.died(Process::Robot(0), "exit code 101"), None);
        assert!(!s.restarting(Process::Robot(0)));
        assert!(s.on_step(20).is_empty());
        assert_eq!(
            s.events.last().map(|e| e.event),
            Some(EventKind::NotRestarted)
        );
        // netem is not covered by this policy; the world-server never is.
        assert_eq!(
            s.died(Process::Netem, "signal 9"),
            Some(ExitReason::NetemExited)
        );
        assert_eq!(
            s.died(Process::WorldServer, "signal 9"),
            Some(ExitReason::WorldServerExited)
        );
    }

    #[test]
    fn faults_asked_at_runtime_come_at_the_next_step_after_the_scheduled_ones() {
        let (r1, r2) = (Process::Robot(1), Process::Robot(2));
        let mut s = Supervisor::new(
            Supervise::default(),
            vec![fault(7, ProcessAction::Freeze { process: r1 })],
        );
        assert!(s.on_step(5).is_empty());
        s.ask(ProcessAction::Kill {
            process: r2,
            restart_after: Some(2),
        });
        s.ask(ProcessAction::Thaw { process: r1 });
        // Thawing a robot that is not frozen does nothing.
        assert_eq!(s.on_step(6), vec![Action::Kill(r2)]);
        s.ask(ProcessAction::Thaw { process: r1 });
        assert_eq!(s.on_step(7), vec![Action::Freeze(r1), Action::Thaw(r1)]);
        assert_eq!(s.on_step(8), vec![Action::Start(r2, 1)]);
        let causes: Vec<_> = s
            .events
            .iter()
            .map(|e| (e.step, e.process, e.event, e.cause.as_str()))
            .collect();
        assert_eq!(
            causes,
            vec![
                (6, r2, EventKind::Killed, "api"),
                (7, r1, EventKind::Frozen, "fault"),
                (7, r1, EventKind::Thawed, "api"),
                (8, r2, EventKind::Started, "api"),
            ]
        );
    }

    /// `process_events` in `summary.json` reads as it did when `event` was a `&'static str`:
    /// the same names, byte for byte, and they read back.
    #[test]
    fn events_serialize_to_the_documented_names_and_read_back() {
        let old = [
            (EventKind::Killed, "killed"),
            (EventKind::NotKilled, "not-killed"),
            (EventKind::Started, "started"),
            (EventKind::NotRestarted, "not-restarted"),
            (EventKind::Frozen, "frozen"),
            (EventKind::Thawed, "thawed"),
            (EventKind::Died, "died"),
        ];
        assert_eq!(old.map(|(k, _)| k), EventKind::ALL);
        for (kind, name) in old {
            let e = Event {
                step: 30,
                process: Process::Robot(2),
                event: kind,
                cause: "fault".into(),
                life: 1,
            };
            let text = serde_json::to_string(&e).unwrap_or_default();
            assert_eq!(
                text,
                format!(
                    r#"{{"step":30,"process":"robot-2","event":"{name}","cause":"fault","life":1}}"#
                )
            );
            assert_eq!(kind.as_str(), name);
            assert_eq!(kind.to_string(), name);
            assert_eq!(serde_json::from_str::<Event>(&text).ok(), Some(e));
        }
        let unknown = r#"{"step":1,"process":"netem","event":"exploded","cause":"x","life":0}"#;
        assert!(serde_json::from_str::<Event>(unknown).is_err());
    }

    #[test]
    fn a_killed_process_is_not_killed_twice_and_lives_are_bounded() {
        let r = Process::Robot(1);
        let mut faults = vec![
            fault(
                1,
                ProcessAction::Kill {
                    process: r,
                    restart_after: None,
                },
            ),
            fault(
                2,
                ProcessAction::Kill {
                    process: r,
                    restart_after: None,
                },
            ),
        ];
        faults.extend(
            (3..3 + u32::from(MAX_LIVES) + 2)
                .map(|t| fault(t, ProcessAction::Restart { process: r })),
        );
        let mut s = Supervisor::new(Supervise::default(), faults);
        assert_eq!(s.on_step(1), vec![Action::Kill(r)]);
        assert!(s.on_step(2).is_empty(), "already down");
        let mut starts = 0;
        for t in 3..3 + u32::from(MAX_LIVES) + 2 {
            starts += s
                .on_step(t)
                .iter()
                .filter(|a| matches!(a, Action::Start(..)))
                .count();
        }
        assert_eq!(starts, usize::from(MAX_LIVES) - 1, "lives 1..MAX_LIVES-1");
        assert_eq!(s.life(r), MAX_LIVES - 1);
    }
}
