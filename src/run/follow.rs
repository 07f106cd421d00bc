//! Following a run: status, telemetry and link reports from the sim plane (evaluated and
//! recorded), the children watched, progress shown — until the exploration is done, the step
//! limit, every robot idle or dead, a process the run cannot do without exited, or a signal.

use std::time::Duration;

use proto::exit::ExitReason;
use proto::msg::{decode, LinkReport, RobotId, Status, Telemetry};
use serde::de::DeserializeOwned;
use zenoh::sample::Sample;

use super::prepare::Plan;
use super::spawn::{last_log_line, Started};
use crate::children::{describe, Children};
use crate::evaluate::Evaluator;
use crate::progress::Progress;
use crate::rundir::LinkLog;

/// Steps every robot must be idle in a row before the run ends with `no-frontiers` (data still
/// in flight on the radio may give an idle robot new frontiers).
const IDLE_STEPS: u32 = 5;

/// What the launcher saw of a run.
pub struct Record {
    pub eval: Evaluator,
    pub last_status: Option<Status>,
    pub links: LinkLog,
    /// Every child that exited during the run, described.
    pub failed: Vec<String>,
    /// Every robot's poses, in step order.
    pub trajectories: Vec<Vec<(f64, f64)>>,
    /// The step since which every live robot has been idle.
    idle_since: Option<u32>,
}

impl Record {
    pub fn new(eval: Evaluator, robots: RobotId) -> Record {
        Record {
            eval,
            last_status: None,
            links: LinkLog::default(),
            failed: Vec::new(),
            trajectories: vec![Vec::new(); usize::from(robots)],
            idle_since: None,
        }
    }

    fn on_status(
        &mut self,
        st: Status,
        plan: &Plan,
        progress: &mut Progress,
    ) -> Option<ExitReason> {
        for r in &st.robots {
            if let Some(t) = self.trajectories.get_mut(usize::from(r.id)) {
                t.push((r.pose.x, r.pose.y));
            }
        }
        let alive = st.robots.iter().filter(|r| r.alive).count();
        progress.show(&format!(
            "step {:>5}/{}  best coverage {:5.1}% (robot {})  robots alive {alive}/{}",
            st.step,
            plan.scenario.max_steps,
            self.eval.best.0,
            self.eval.best.1,
            plan.robots()
        ));
        let done = st.step >= plan.scenario.max_steps;
        self.last_status = Some(st);
        if alive == 0 {
            return Some(ExitReason::AllRobotsDead);
        }
        done.then_some(ExitReason::MaxSteps)
    }

    fn on_telemetry(&mut self, t: Telemetry) -> Option<ExitReason> {
        let step = t.step;
        self.eval.add(t);
        if self.eval.exploration_step.is_some() {
            return Some(ExitReason::Explored);
        }
        // Every live robot idle (its latest telemetry says it sees no reachable frontier) for a
        // few steps in a row: nothing is left to explore.
        let alive: Vec<RobotId> = self.last_status.as_ref().map_or(Vec::new(), |s| {
            s.robots.iter().filter(|r| r.alive).map(|r| r.id).collect()
        });
        let all_idle = !alive.is_empty()
            && alive
                .iter()
                .all(|id| self.eval.last.get(id).is_some_and(|(_, t)| t.idle));
        if !all_idle {
            self.idle_since = None;
            return None;
        }
        let since = *self.idle_since.get_or_insert(step);
        (step >= since + IDLE_STEPS).then_some(ExitReason::NoFrontiers)
    }

    /// Records the children that exited since the last look; the run ends when the
    /// world-server or netem is among them.
    ///
    /// netem follows the world-server's sim plane and exits when it is gone, so when both are
    /// seen gone the world-server's exit is the cause. A child seen gone may have exited because
    /// another one, looked at just before it, went first: once a process the run needs is seen
    /// gone, the children are looked at once more, which then shows every earlier exit.
    fn on_exits(
        &mut self,
        children: &mut Children,
        plan: &Plan,
        progress: &mut Progress,
    ) -> Option<ExitReason> {
        let mut exits = children.newly_exited();
        if exits.iter().any(|(name, _, _)| needed(name).is_some()) {
            exits.extend(children.newly_exited());
        }
        for (name, pid, status) in &exits {
            let mut what = format!("{name} (pid {pid}) exited: {}", describe(*status));
            if status.code().is_some_and(|c| c != 0) {
                what = format!("{what}: {}", last_log_line(&plan.log(name)));
            }
            progress.event(&format!("swarm run: {what}"));
            self.failed.push(what);
        }
        exits
            .iter()
            .filter_map(|(name, _, _)| needed(name))
            .min_by_key(|&(rank, _)| rank)
            .map(|(_, r)| r)
    }
}

/// The end of the run a process's exit means, for the processes the run cannot go on without;
/// ordered by precedence (the smallest is the cause).
fn needed(process: &str) -> Option<(u8, ExitReason)> {
    match process {
        "world-server" => Some((0, ExitReason::WorldServerExited)),
        "netem" => Some((1, ExitReason::NetemExited)),
        _ => None,
    }
}

/// A sim-plane message: `Err` when the subscription has closed, `Ok(None)` when it did not
/// decode (logged).
fn message<T: DeserializeOwned, E>(s: Result<Sample, E>, what: &str) -> Result<Option<T>, ()> {
    let s = s.map_err(|_| ())?;
    match decode::<T>(&s.payload().to_bytes()) {
        Ok(m) => Ok(Some(m)),
        Err(e) => {
            tracing::warn!("bad {what}: {e}");
            Ok(None)
        }
    }
}

/// Follows the run until it ends; returns why it ended.
pub async fn follow(
    plan: &Plan,
    run: &mut Started,
    rec: &mut Record,
    progress: &mut Progress,
) -> anyhow::Result<ExitReason> {
    const CLOSED: ExitReason = ExitReason::SimPlaneClosed;
    let sim = &run.sim;
    let mut tick = tokio::time::interval(Duration::from_millis(200));
    let mut sigterm = tokio::signal::unix::signal(tokio::signal::unix::SignalKind::terminate())?;
    let reason = loop {
        let end = tokio::select! {
            s = sim.statuses.recv_async() => match message::<Status, _>(s, "status") {
                Err(()) => Some(CLOSED),
                Ok(st) => st.and_then(|st| rec.on_status(st, plan, progress)),
            },
            t = sim.telemetry.recv_async() => match message::<Telemetry, _>(t, "telemetry") {
                Err(()) => Some(CLOSED),
                Ok(t) => t.and_then(|t| rec.on_telemetry(t)),
            },
            r = sim.link_reports.recv_async() => match message::<LinkReport, _>(r, "link report") {
                Err(()) => Some(CLOSED),
                Ok(r) => {
                    if let Some(r) = r { rec.links.add(r) }
                    None
                }
            },
            _ = tick.tick() => rec.on_exits(&mut run.children, plan, progress),
            _ = tokio::signal::ctrl_c() => {
                progress.event("swarm run: interrupted, stopping every process");
                Some(ExitReason::Interrupted)
            }
            _ = sigterm.recv() => {
                progress.event("swarm run: terminated, stopping every process");
                Some(ExitReason::Terminated)
            }
        };
        if let Some(reason) = end {
            break reason;
        }
    };
    Ok(reason)
}
