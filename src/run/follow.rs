//! Following a run: status, telemetry and link reports from the sim plane (evaluated and
//! recorded), the children watched, progress shown — until the exploration is done, the step
//! limit, every robot idle or dead, a process the run cannot do without exited, or a signal.

use std::time::{Duration, Instant};

use proto::exit::ExitReason;
use proto::geom::Metres;
use proto::msg::{decode, ProcessOrder, Status, Step, Telemetry};
use serde::de::DeserializeOwned;
use zenoh::sample::Sample;

use std::collections::BTreeMap;

use proto::msg::RobotId;
use proto::scenario::{Process, ProcessAction};

use super::prepare::Plan;
use super::spawn::{last_log_line, respawn, Started};
use super::steps::StepOrder;
use super::tables::Tables;
use crate::process::children::{describe, Children};
use crate::process::supervise::{Action, Supervisor};
use crate::run::progress::Progress;
use crate::rundir::steplog::StepLogWriter;
use crate::score::evaluate::Evaluator;

/// Steps every robot must be idle in a row before the run ends with `no-frontiers` or `stalled`
/// ([`Evaluator::idle_end`]; data still in flight on the radio may give an idle robot new
/// frontiers).
const IDLE_STEPS: u32 = 5;

/// How long the launcher waits, once the last step is known, for the rest of that step's reports
/// (the world's status after it, netem's link report of it).
const SETTLE: Duration = Duration::from_secs(5);

/// What the launcher saw of a run.
pub struct Record {
    pub eval: Evaluator,
    /// The per-step tables, written as the steps close.
    pub tables: Tables,
    /// Every child that exited during the run, described.
    pub failed: Vec<String>,
    /// Every status of the world, in step order.
    pub statuses: Vec<Status>,
    lockstep: bool,
    /// Telemetry, taken a whole step at a time (lockstep).
    order: StepOrder,
    /// The step since which every live robot has been idle.
    idle_since: Option<u32>,
    /// Realtime: the latest step whose telemetry was taken.
    newest: Option<Step>,
    /// The run's last step and why it ended there, once the telemetry of a step decided it
    /// (exploration done, nothing left to explore, the step limit).
    pub end: Option<(Step, ExitReason)>,
    /// The last step's reports all arrived before the launcher stopped the run (or there was no
    /// last step to wait for).
    pub settled_in_time: bool,
    /// Process faults and restarts.
    pub sup: Supervisor,
    /// Per robot life (robot, life): what it last reported of itself.
    pub lives: BTreeMap<(RobotId, u16), Life>,
    /// Per node life (node, life), per owner (its own log included): the most of the owner's
    /// log it reported holding at any step taken (up to the run's last step), in ops and —
    /// where the exchange measures them — encoded bytes.
    pub held_max: BTreeMap<(RobotId, u16), Held>,
    /// `steps.log`, written as the reports are taken (dropped, with a warning, if it cannot be
    /// written: the run goes on).
    pub log: Option<StepLogWriter>,
    /// The world-server exited cleanly before the launcher knew the run's end: when, and how
    /// (pid, status), until the statuses still on their way tell the end ([`Record::on_exits`]).
    world_gone: Option<(Instant, u32, std::process::ExitStatus)>,
}

/// Per log owner: (ops, encoded bytes if measured) of its log.
pub type Held = BTreeMap<RobotId, (u32, Option<u64>)>;

/// What one life of a robot reported last of what it sent.
#[derive(Clone, Debug, Default)]
pub struct Life {
    /// Radio payload it sent, in total and per traffic class.
    pub bytes_sent: u64,
    pub sent_by_type: Vec<u64>,
}

impl Record {
    /// `lockstep`: telemetry is taken a whole step at a time ([`StepOrder`]); else as it comes.
    pub fn new(eval: Evaluator, tables: Tables, lockstep: bool, sup: Supervisor) -> Record {
        Record {
            sup,
            lives: BTreeMap::new(),
            held_max: BTreeMap::new(),
            eval,
            tables,
            failed: Vec::new(),
            statuses: Vec::new(),
            lockstep,
            order: StepOrder::default(),
            idle_since: None,
            newest: None,
            end: None,
            world_gone: None,
            settled_in_time: true,
            log: None,
        }
    }

    /// Writes to the step log; on an error says so once and writes no more.
    fn log(&mut self, f: impl FnOnce(&mut StepLogWriter) -> anyhow::Result<()>) {
        if let Some(w) = &mut self.log {
            if let Err(e) = f(w) {
                tracing::warn!("{e:#}; no step log from here on");
                self.log = None;
            }
        }
    }

    /// The world's state at the end: the status after the last step's moves (or the latest).
    pub fn last_status(&self) -> Option<&Status> {
        let upto = self.end.map_or(Step::MAX, |(e, _)| e.saturating_add(1));
        self.statuses.iter().rev().find(|s| s.step <= upto)
    }

    /// Every robot's poses, in step order, up to the last status.
    pub fn trajectories(&self) -> Vec<Vec<Metres>> {
        let upto = self.last_status().map_or(0, |s| s.step);
        let robots = self.statuses.first().map_or(0, |s| s.robots.len());
        let mut t = vec![Vec::new(); robots];
        for st in self.statuses.iter().filter(|s| s.step <= upto) {
            for r in &st.robots {
                if let Some(t) = t.get_mut(usize::from(r.id)) {
                    t.push(r.pose.xy());
                }
            }
        }
        t
    }

    /// Telemetry reports that came after their step was taken: (step, robot).
    pub fn late_reports(&self) -> &[(Step, proto::msg::RobotId)] {
        &self.order.late
    }

    fn on_status(
        &mut self,
        st: Status,
        plan: &Plan,
        progress: &mut Progress,
    ) -> Option<ExitReason> {
        let alive = st.robots.iter().filter(|r| r.alive).count();
        progress.show(&format!(
            "step {:>5}/{}  best coverage {:5.1}% (robot {})  robots alive {alive}/{}",
            st.step,
            plan.scenario.step_limit(),
            self.eval.best.0,
            self.eval.best.1,
            plan.robots()
        ));
        self.order.on_status(&st);
        self.log(|w| w.status(&st));
        let step = st.step;
        self.statuses.push(st);
        if alive == 0 {
            return Some(ExitReason::AllRobotsDead);
        }
        if step >= plan.scenario.step_limit() && self.end.is_none() {
            self.end = Some((step.saturating_sub(1), ExitReason::MaxSteps));
        }
        // A status may complete a step (a robot found dead, or missed).
        self.take_complete_steps();
        None
    }

    fn on_telemetry(&mut self, t: Telemetry) {
        let life = self.lives.entry((t.robot, t.life)).or_default();
        if t.bytes_sent >= life.bytes_sent {
            life.bytes_sent = t.bytes_sent;
            life.sent_by_type.clone_from(&t.sent_by_type);
        }
        if !self.lockstep {
            // Realtime: reports are taken as they come (the run follows the wall clock anyway).
            if self.end.is_none() {
                let step = t.step;
                self.newest = Some(self.newest.map_or(step, |n| n.max(step)));
                self.took(step, vec![t]);
                self.write_closed_steps();
            }
            return;
        }
        if let Some(late) = self.order.on_telemetry(t) {
            // No row, but its grids: the robot's next reports are changes of them. The step
            // log, which did not record it, takes the robot's next grid whole.
            self.eval.take_late(&late);
            if let Some(w) = &mut self.log {
                w.forget(late.robot);
            }
        }
        self.take_complete_steps();
    }

    /// A report of netem's of the links at a step.
    fn on_link_report(&mut self, r: proto::msg::LinkReport) {
        self.log(|w| w.links(&r));
        self.tables.report(r);
        self.write_closed_steps();
    }

    /// Writes the steps that are closed: their telemetry taken (lockstep: the whole step;
    /// realtime: reports two steps on have come) and netem's report of them in — up to the
    /// run's last step once it is known.
    fn write_closed_steps(&mut self) {
        let taken = if self.lockstep {
            self.order.next().checked_sub(1)
        } else {
            self.newest.and_then(|n| n.checked_sub(2))
        };
        let Some(mut last) = taken.min(self.tables.links_through()) else {
            return;
        };
        if let Some((end, _)) = self.end {
            last = last.min(end);
        }
        if self.tables.next() <= last {
            self.tables.write_through(last, &mut self.eval);
        }
    }

    /// At the end: writes every step held (up to the run's last step, when it is known).
    pub fn write_the_rest(&mut self) {
        let held = self.tables.held_through(&self.eval);
        let last = match self.end {
            Some((end, _)) => Some(end),
            None => held,
        };
        if let Some(last) = last {
            self.tables.write_through(last, &mut self.eval);
        }
    }

    /// Lockstep: takes the steps that are complete, up to the last one once it is known.
    fn take_complete_steps(&mut self) {
        while self.lockstep && self.end.is_none_or(|(e, _)| self.order.next() <= e) {
            let Some((step, reports)) = self.order.take() else {
                break;
            };
            self.took(step, reports);
        }
        self.write_closed_steps();
    }

    /// Evaluates reports of `step`; decides the end if they show it (exploration done, or every
    /// live robot idle for a few steps in a row: nothing is left to explore).
    fn took(&mut self, step: Step, reports: Vec<Telemetry>) {
        let from = self.eval.rows.len();
        for t in reports {
            // What each node holds of each log, over the steps the run is scored on.
            let held = self.held_max.entry((t.robot, t.life)).or_default();
            for &(owner, n) in &t.logs {
                let bytes = t.log_bytes.iter().find(|b| b.0 == owner).map(|b| b.1);
                let most = held.entry(owner).or_default();
                most.0 = most.0.max(n);
                most.1 = most.1.max(bytes);
            }
            let (robot, scored) = (t.robot, self.eval.rows.len());
            let change = self.eval.add(t);
            let taken = change.zip(self.eval.last.get(&robot));
            let logged = taken
                .zip(self.log.as_mut())
                .map(|((c, l), w)| w.robot_step(&l.t, &l.planning.grid, &c));
            if let Some((mut r, grid)) = logged {
                r.coverage_pct = self
                    .eval
                    .rows
                    .get(scored)
                    .map(|row| row.coverage_pct as f32);
                self.log(|w| w.robot(r, grid));
            }
        }
        // Lockstep: the whole step is in, so every share compares grids of this step.
        // Realtime: one report, against every other robot's latest grid.
        self.eval.share_rows_since(from);
        if self.end.is_some() {
            return;
        }
        if self.eval.exploration_step.is_some() {
            self.end = Some((step, ExitReason::Explored));
            return;
        }
        let alive: Vec<_> = self.statuses.last().map_or(Vec::new(), |s| {
            s.robots.iter().filter(|r| r.alive).map(|r| r.id).collect()
        });
        let all_idle = !alive.is_empty()
            && alive
                .iter()
                .all(|id| self.eval.last.get(id).is_some_and(|l| l.t.idle));
        if !all_idle {
            self.idle_since = None;
            return;
        }
        let since = *self.idle_since.get_or_insert(step);
        if step >= since + IDLE_STEPS {
            let (reason, left) = self.eval.idle_end(&alive);
            if let Some((robot, c)) = left {
                eprintln!(
                    "every robot is idle, but robot {robot}'s planning grid still holds a \
                     frontier at cell ({}, {}) inside the world's reachable area: the run \
                     stalled",
                    c.x, c.y
                );
            }
            self.end = Some((step, reason));
        }
    }

    /// Whether everything of the steps up to the end has arrived: the telemetry, the status
    /// after the last step's moves and netem's report of the last step (realtime: at once).
    fn settled(&self) -> bool {
        let Some((e, _)) = self.end else {
            return false;
        };
        if !self.lockstep {
            return true;
        }
        let after = e.saturating_add(1);
        let status = self.statuses.iter().any(|s| s.step >= after);
        let links = self.tables.reported().is_some_and(|s| s >= e);
        // netem reports a step when the next one opens; a run without links has no reports.
        let no_links = self.statuses.first().is_some_and(|s| s.robots.len() < 2);
        self.order.next() > e && status && (links || no_links)
    }

    /// Drops what was recorded after the last step (the world may have run ahead while the
    /// launcher waited for the last step's reports).
    pub fn truncate(&mut self) {
        if let Some((e, _)) = self.end {
            self.tables.truncate(e);
        }
    }

    /// Records the children that exited since the last look (none the launcher killed itself):
    /// a supervised one is started again later ([`Supervisor::died`]); the run ends when the
    /// world-server, or netem without a restart to come, is among them.
    ///
    /// netem follows the world-server's sim plane and exits when it is gone, so when both are
    /// seen gone the world-server's exit is the cause. A child seen gone may have exited because
    /// another one, looked at just before it, went first: once a process the run needs is seen
    /// gone, the children are looked at once more, which then shows every earlier exit.
    ///
    /// The world-server exits cleanly (code 0) only once it ended the run, right after its last
    /// status: a launcher behind by a step or two (a loaded machine) sees the exit before that
    /// status, still on its way. Such an exit is held ([`Record::world_gone`]) until the
    /// statuses tell the run's end, or [`SETTLE`] passes ([`Record::world_gone_end`]); netem,
    /// which follows the world-server out, is then no cause either.
    fn on_exits(
        &mut self,
        children: &mut Children,
        plan: &Plan,
        progress: &mut Progress,
    ) -> Option<ExitReason> {
        let mut exits = children.newly_exited();
        if exits.iter().any(|(name, _, _)| needed(name)) {
            exits.extend(children.newly_exited());
        }
        // The world-server first: netem's exit after it is no cause of its own.
        exits.sort_by_key(|(name, _, _)| !matches!(name.parse(), Ok(Process::WorldServer)));
        let mut end = None;
        for (name, pid, status) in &exits {
            if self.world_gone.is_some() {
                // The others follow the world-server out: only a crash is recorded, as once the
                // end is known ([`Record::on_crashes`]).
                if !status.success() {
                    self.exited(name, *pid, *status, plan, progress);
                }
                continue;
            }
            if status.success() && matches!(name.parse(), Ok(Process::WorldServer)) {
                self.world_gone = Some((Instant::now(), *pid, *status));
                continue;
            }
            self.exited(name, *pid, *status, plan, progress);
            let Ok(process) = name.parse::<Process>() else {
                continue;
            };
            if end.is_some() {
                continue;
            }
            end = self.sup.died(process, &describe(*status));
            if self.sup.restarting(process) {
                progress.event(&format!(
                    "swarm run: {name} will be started again (supervise)"
                ));
            }
        }
        end
    }

    /// A process fault asked for through netem's API: carried out at the next step (netem
    /// checked it against the scenario; so does the launcher, the one that acts on it).
    fn asked(&mut self, action: ProcessAction, plan: &Plan, progress: &mut Progress) {
        let p = action.process();
        if let Err((value, why)) = plan.scenario.check_process_action(&action) {
            progress.event(&format!(
                "swarm run: ignored a process fault from netem's API: {value}: {why}"
            ));
            return;
        }
        if self.end.is_some() {
            progress.event(&format!(
                "swarm run: the run is ending: not doing {} {p} (netem's API)",
                action.name()
            ));
            return;
        }
        progress.event(&format!(
            "swarm run: {} {p} asked for through netem's API (at the next step)",
            action.name()
        ));
        self.sup.ask(action);
    }

    /// Carries out the supervisor's actions of the step; the end of the run if one of them
    /// killed the world-server.
    async fn act(
        &mut self,
        actions: Vec<Action>,
        children: &mut Children,
        plan: &Plan,
        progress: &mut Progress,
    ) -> Option<ExitReason> {
        let step = self.statuses.last().map_or(0, |s| s.step);
        for a in actions {
            let (p, what) = match a {
                Action::Kill(p) => {
                    children.kill(&p.to_string()).await;
                    (p, "killed".to_string())
                }
                Action::Start(p, life) => match respawn(plan, children, p, life) {
                    Ok(pid) => (p, format!("started again (life {life}, pid {pid})")),
                    Err(e) => (p, format!("could not be started again: {e:#}")),
                },
                Action::Freeze(p) => {
                    let sent = children.signal(&p.to_string(), libc::SIGSTOP);
                    (
                        p,
                        if sent {
                            "frozen"
                        } else {
                            "not frozen (not running)"
                        }
                        .to_string(),
                    )
                }
                Action::Thaw(p) => {
                    let sent = children.signal(&p.to_string(), libc::SIGCONT);
                    (
                        p,
                        if sent {
                            "thawed"
                        } else {
                            "not thawed (not running)"
                        }
                        .to_string(),
                    )
                }
            };
            progress.event(&format!("swarm run: step {step}: {p} {what}"));
            if a == Action::Kill(Process::WorldServer) {
                return Some(ExitReason::WorldServerExited);
            }
        }
        None
    }

    /// Once the last step is known, processes end by themselves (the world-server at the step
    /// limit, the others after it): only one that fails (an error exit or a signal) is recorded.
    fn on_crashes(&mut self, children: &mut Children, plan: &Plan, progress: &mut Progress) {
        for (name, pid, status) in children.newly_exited() {
            if !status.success() {
                self.exited(&name, pid, status, plan, progress);
            }
        }
    }

    fn exited(
        &mut self,
        name: &str,
        pid: u32,
        status: std::process::ExitStatus,
        plan: &Plan,
        progress: &mut Progress,
    ) {
        let mut what = format!("{name} (pid {pid}) exited: {}", describe(status));
        if status.code().is_some_and(|c| c != 0) {
            what = format!("{what}: {}", last_log_line(&plan.log(name)));
        }
        progress.event(&format!("swarm run: {what}"));
        self.failed.push(what);
    }
}

/// Whether the run cannot go on without the process (unless it is restarted).
fn needed(process: &str) -> bool {
    matches!(process.parse(), Ok(Process::WorldServer | Process::Netem))
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
    let sim = &run.sim;
    let mut tick = tokio::time::interval(Duration::from_millis(200));
    let mut sigterm = tokio::signal::unix::signal(tokio::signal::unix::SignalKind::terminate())?;
    let mut settle_by = None;
    let reason = loop {
        let end = tokio::select! {
            s = sim.statuses.recv_async() => match message::<Status, _>(s, "status") {
                Err(()) => Some(ExitReason::SimPlaneClosed),
                Ok(None) => None,
                Ok(Some(st)) => rec.status(st, &mut run.children, plan, progress).await,
            },
            t = sim.telemetry.recv_async() => received(message(t, "telemetry"), |t| {
                rec.on_telemetry(t)
            }),
            o = sim.process_orders.recv_async() => {
                received(message::<ProcessOrder, _>(o, "process fault"), |o| {
                    rec.asked(o.into(), plan, progress)
                })
            }
            r = sim.link_reports.recv_async() => received(message(r, "link report"), |r| {
                rec.on_link_report(r)
            }),
            _ = tick.tick() => rec.tick(&mut run.children, plan, progress),
            _ = tokio::signal::ctrl_c() => {
                progress.event("swarm run: interrupted, stopping every process");
                Some(ExitReason::Interrupted)
            }
            _ = sigterm.recv() => {
                progress.event("swarm run: terminated, stopping every process");
                Some(ExitReason::Terminated)
            }
        };
        if let Some(reason) = rec.settled_end(&mut settle_by) {
            break reason;
        }
        if let Some(reason) = rec.world_gone_end(plan, progress) {
            break reason;
        }
        // Once the last step is known, a process that exits (the world-server ends itself at
        // the step limit) or a signal does not change why the run ended.
        if let Some(reason) = end {
            break rec.end.map_or(reason, |(_, r)| r);
        }
    };
    Ok(reason)
}

/// One sim-plane message handed to `on` (a message that did not decode is skipped); the end of
/// the run when its subscription closed.
fn received<T>(m: Result<Option<T>, ()>, on: impl FnOnce(T)) -> Option<ExitReason> {
    match m {
        Err(()) => Some(ExitReason::SimPlaneClosed),
        Ok(t) => {
            if let Some(t) = t {
                on(t);
            }
            None
        }
    }
}

impl Record {
    /// The world's status after a step: recorded, and while the run goes on the supervisor's
    /// actions for the step carried out. The run's end, if that decided it.
    async fn status(
        &mut self,
        st: Status,
        children: &mut Children,
        plan: &Plan,
        progress: &mut Progress,
    ) -> Option<ExitReason> {
        let step = st.step;
        match self.on_status(st, plan, progress) {
            Some(end) => Some(end),
            None if self.end.is_none() => {
                let actions = self.sup.on_step(step);
                self.act(actions, children, plan, progress).await
            }
            None => None,
        }
    }

    /// The periodic look at the children: memory sampled, exits judged. Once the last step is
    /// known the processes may end by themselves (the world-server does at the step limit):
    /// their exits are the run's end, not failures; a crash still is one.
    fn tick(
        &mut self,
        children: &mut Children,
        plan: &Plan,
        progress: &mut Progress,
    ) -> Option<ExitReason> {
        children.sample_memory(self.statuses.last().map(|s| s.step));
        match self.end {
            None => self.on_exits(children, plan, progress),
            Some(_) => {
                self.on_crashes(children, plan, progress);
                None
            }
        }
    }

    /// The world-server exited cleanly and [`SETTLE`] passed with no status telling the run's
    /// end: its exit is the end after all ([`Record::on_exits`]).
    fn world_gone_end(&mut self, plan: &Plan, progress: &mut Progress) -> Option<ExitReason> {
        let (at, pid, status) = self.world_gone?;
        if self.end.is_some() || at.elapsed() < SETTLE {
            return None;
        }
        let name = Process::WorldServer.to_string();
        self.exited(&name, pid, status, plan, progress);
        self.sup.died(Process::WorldServer, &describe(status))
    }

    /// Once the run's end is known: its reason when everything of it has arrived, or when
    /// [`SETTLE`] has passed since (then not settled in time); `None` while waiting.
    fn settled_end(&mut self, settle_by: &mut Option<Instant>) -> Option<ExitReason> {
        let (_, reason) = self.end?;
        let by = *settle_by.get_or_insert_with(|| Instant::now() + SETTLE);
        if self.settled() {
            return Some(reason);
        }
        if Instant::now() >= by {
            self.settled_in_time = false;
            return Some(reason);
        }
        None
    }
}
