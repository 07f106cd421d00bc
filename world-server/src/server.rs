//! The world-server on the sim plane: the clock (lockstep or realtime, docs/design.md §2) driving
//! [`World`](crate::world::World) over zenoh.
//!
//! Per step t: publish every live robot's scan for t; collect commands for t until all live robots
//! answered (lockstep) or the step timed out (lockstep: [`proto::step_wait`], at least
//! `step_timeout_ms`; realtime: the step period); apply them; publish [`proto::msg::Status`] for
//! t+1. A robot whose sim-plane liveliness token vanishes is dead at once; one that misses
//! `dead_after` steps in a row too. A dead robot that shows life again — its token appears (a
//! restarted process) or it sends a command (a thawed one) — is alive again from the next step,
//! where it stood. Everything received is validated; bad input is counted and logged, never fatal.

use std::collections::{HashMap, HashSet};
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::Duration;

use proto::exit::ExitReason;
use proto::keys;
use proto::msg::{decode, encode, Cmd, Control, RobotId, Step};
use proto::node::{zerr, ZenohError};
use proto::scenario::{ClockMode, Scenario};
use tokio::time::{sleep_until, Instant};
use zenoh::handlers::FifoChannelHandler;
use zenoh::pubsub::Subscriber;
use zenoh::qos::CongestionControl;
use zenoh::sample::{Sample, SampleKind};
use zenoh::Session;

use crate::world::World;

/// How the world-server's loop ended.
#[derive(Debug, PartialEq, Eq)]
pub enum End {
    /// The launcher (or anybody on the sim plane) sent [`Control::Stop`]: the run ended for
    /// a reason the world does not know.
    Stopped { step: Step },
    /// The world ended the run: [`ExitReason::MaxSteps`] or [`ExitReason::AllRobotsDead`].
    Ended { step: Step, reason: ExitReason },
}

/// The step gate (the step clock's pause): what the launcher's [`Control::Pause`],
/// [`Control::Resume`] and [`Control::Step`] leave it at. A pause never cuts a step short; it holds
/// the next one.
#[derive(Debug, Default)]
struct StepGate {
    paused: bool,
    /// Paused, with one step let through.
    one_step: bool,
}

impl StepGate {
    fn order(&mut self, c: Control) {
        match c {
            Control::Pause => (self.paused, self.one_step) = (true, false),
            Control::Resume => (self.paused, self.one_step) = (false, false),
            Control::Step => self.one_step = self.paused,
            Control::Stop => {}
        }
    }

    /// Takes one sample of the control key (`None`: the subscription closed); true when the
    /// run ends there — a [`Control::Stop`], or nobody can send orders any more. An order that
    /// does not decode is bad input.
    fn control(&mut self, sample: Option<Sample>, bad: &mut BadInput) -> bool {
        let Some(sample) = sample else { return true };
        match decode::<Control>(&sample.payload().to_bytes()) {
            Ok(Control::Stop) => true,
            Ok(order) => {
                self.order(order);
                false
            }
            Err(e) => {
                bad.record(keys::CONTROL, e);
                false
            }
        }
    }

    /// Whether the next step may start (taking the one step a [`Control::Step`] let through).
    fn may_step(&mut self) -> bool {
        if !self.paused {
            return true;
        }
        std::mem::take(&mut self.one_step)
    }
}

/// Options of the serve loop that are not part of the scenario.
pub struct ServeOpts {
    /// How long to wait for all robots to join before giving up.
    pub startup_timeout: Duration,
}

async fn put(session: &Session, key: &str, bytes: Vec<u8>) -> Result<(), ZenohError> {
    session
        .put(key, bytes)
        .congestion_control(CongestionControl::Block)
        .await
        .map_err(zerr)
}

/// Answers `sim/world/info` and `sim/world/truth` until the session closes.
async fn answer_queries(session: Session, info: Vec<u8>, truth: Vec<u8>) -> Result<(), ZenohError> {
    let info_q = session
        .declare_queryable(keys::WORLD_INFO)
        .await
        .map_err(zerr)?;
    let truth_q = session
        .declare_queryable(keys::WORLD_TRUTH)
        .await
        .map_err(zerr)?;
    loop {
        let (query, bytes) = tokio::select! {
            q = info_q.recv_async() => (q, &info),
            q = truth_q.recv_async() => (q, &truth),
        };
        let Ok(query) = query else { return Ok(()) };
        if let Err(e) = query.reply(query.key_expr().clone(), bytes.clone()).await {
            tracing::warn!("reply to {} failed: {e}", query.key_expr());
        }
    }
}

/// Counts and logs (once per source) input that failed validation.
#[derive(Default)]
struct BadInput {
    count: u64,
    logged: HashSet<String>,
}

impl BadInput {
    fn record(&mut self, source: &str, what: impl std::fmt::Display) {
        self.count += 1;
        if self.logged.insert(source.to_string()) {
            tracing::warn!(
                "bad input from {source}: {what} (further errors from it are only counted)"
            );
        }
    }
}

/// Runs the world until stopped, `max_steps`, or every robot is dead.
pub async fn serve(
    session: Session,
    world: World,
    s: &Scenario,
    opts: ServeOpts,
) -> Result<End, ZenohError> {
    let queries = tokio::spawn(answer_queries(
        session.clone(),
        encode(&world.info()),
        encode(&world.truth_msg()),
    ));
    let cmds = session
        .declare_subscriber(keys::CMD_ALL)
        .await
        .map_err(zerr)?;
    let ctl = session
        .declare_subscriber(keys::CONTROL)
        .await
        .map_err(zerr)?;
    let live = session
        .liveliness()
        .declare_subscriber(keys::SIM_ALIVE_ALL)
        .history(true)
        .await
        .map_err(zerr)?;
    // netem's link reports: the run's last step is over once netem reported it. Only the
    // latest step is kept (a queue nobody reads during the run would fill and hold up the
    // router).
    let reported = std::sync::Arc::new(Reported::default());
    let r = reported.clone();
    let _links = session
        .declare_subscriber(keys::NETEM_LINKS)
        .callback(move |s| {
            if let Ok(report) = decode::<proto::msg::LinkReport>(&s.payload().to_bytes()) {
                r.step
                    .fetch_max(u64::from(report.step) + 1, Ordering::SeqCst);
                r.changed.notify_one();
            }
        })
        .await
        .map_err(zerr)?;
    let _alive = session
        .liveliness()
        .declare_token(keys::WORLD_ALIVE)
        .await
        .map_err(zerr)?;
    let mut plane = SimPlane {
        session: &session,
        cmds: &cmds,
        ctl: &ctl,
        live: &live,
        n: world.nodes(),
        world,
        s,
        gate: StepGate::default(),
        bad: BadInput::default(),
    };
    if let Some(end) = plane.join(opts.startup_timeout).await? {
        return Ok(end);
    }
    let end = plane.run().await?;
    if let End::Ended { step, .. } = end {
        if plane.n >= 2 {
            last_step_reported(&reported, &ctl, step.saturating_sub(1)).await;
        }
    }
    if plane.bad.count > 0 {
        tracing::warn!(
            "{} bad inputs were rejected during the run",
            plane.bad.count
        );
    }
    // This process is the sim plane's router: tell everyone the run is over (also when the stop
    // came from the launcher, so no robot depends on the order of forwarding), then give the
    // router a moment to deliver it before the session closes.
    put(&session, keys::CONTROL, encode(&Control::Stop)).await?;
    tokio::time::sleep(Duration::from_millis(200)).await;
    queries.abort();
    Ok(end)
}

/// How long the world waits at the end for netem's report of the last step.
const LAST_REPORT_WAIT: Duration = Duration::from_secs(5);

/// The latest step netem reported (+ 1; 0: none yet), and a wake-up when it changes.
#[derive(Default)]
struct Reported {
    step: AtomicU64,
    changed: tokio::sync::Notify,
}

/// Waits until netem reported step `last` (its links' bytes are counted), the launcher stopped
/// the run, or [`LAST_REPORT_WAIT`] passed. The world's stop makes every robot close its radio
/// sessions; sent before netem took the status that closes the last step, their closing frames
/// would be counted in it as threads happen to run.
async fn last_step_reported(reported: &Reported, ctl: &Sub, last: Step) {
    let deadline = Instant::now() + LAST_REPORT_WAIT;
    while reported.step.load(Ordering::SeqCst) <= u64::from(last) {
        tokio::select! {
            _ = reported.changed.notified() => {}
            _ = ctl.recv_async() => return,
            _ = sleep_until(deadline) => {
                tracing::warn!("netem did not report the last step ({last}) within {LAST_REPORT_WAIT:?}");
                return;
            }
        }
    }
}

/// A subscription of the sim plane, its samples queued.
type Sub = Subscriber<FifoChannelHandler<Sample>>;

/// The world-server's end of the sim plane during a run: the world and what drives it.
struct SimPlane<'a> {
    session: &'a Session,
    cmds: &'a Sub,
    ctl: &'a Sub,
    live: &'a Sub,
    /// Robots, then the base station: every node's token is awaited, and its command each step.
    n: usize,
    world: World,
    s: &'a Scenario,
    gate: StepGate,
    bad: BadInput,
}

impl SimPlane<'_> {
    /// Waits for every node's sim-plane token (declared once its subscribers are up); `Some`: stop.
    async fn join(&mut self, timeout: Duration) -> Result<Option<End>, ZenohError> {
        let n = self.n;
        let mut present = HashSet::new();
        let deadline = Instant::now() + timeout;
        while present.len() < n {
            tokio::select! {
                sample = self.live.recv_async() => {
                    let Ok(sample) = sample else { return Ok(Some(End::Stopped { step: 0 })) };
                    match keys::robot_of(sample.key_expr().as_str()) {
                        Some(id) if usize::from(id) < n && sample.kind() == SampleKind::Put => { present.insert(id); }
                        Some(id) if usize::from(id) < n => { present.remove(&id); }
                        _ => self.bad.record(sample.key_expr().as_str(), "unknown robot id"),
                    }
                }
                c = self.ctl.recv_async() => if self.gate.control(c.ok(), &mut self.bad) {
                    return Ok(Some(End::Stopped { step: 0 }));
                },
                _ = sleep_until(deadline) => {
                    let missing: Vec<usize> = (0..n).filter(|i| !present.contains(&(*i as RobotId))).collect();
                    return Err(ZenohError(format!("nodes {missing:?} did not join within {timeout:?} (robots 0..robots.count, then the base station)")));
                }
            }
        }
        tracing::info!("all {n} nodes joined");
        Ok(None)
    }

    /// Steps the world until the run ends: scans out, commands in, the world moved, status out.
    async fn run(&mut self) -> Result<End, ZenohError> {
        let clock = &self.s.clock;
        let period = Duration::from_secs_f64(clock.step_seconds / clock.speedup);
        let mut wait = self.s.step_wait();
        let max_steps = self.s.step_limit();
        let mut step: Step = 0;
        put(self.session, keys::STATUS, encode(&self.world.status(step))).await?;
        loop {
            if step >= max_steps {
                return Ok(End::Ended {
                    step,
                    reason: ExitReason::MaxSteps,
                });
            }
            let alive: Vec<RobotId> = self.world.alive().collect();
            if alive.is_empty() {
                return Ok(End::Ended {
                    step,
                    reason: ExitReason::AllRobotsDead,
                });
            }
            if !self.gate.may_step() && self.paused(step).await {
                return Ok(End::Stopped { step });
            }
            let started = Instant::now();
            let limit = match self.s.clock.mode {
                ClockMode::Lockstep => wait.limit(),
                ClockMode::Realtime => period,
            };
            self.publish_scans(&alive, step).await?;
            let Some(got) = self.commands(step, started + limit).await else {
                return Ok(End::Stopped { step });
            };
            // Lockstep: whom the world went on without (the step timed out).
            let missed: Vec<RobotId> = match self.s.clock.mode {
                ClockMode::Lockstep => (self.world.awaited())
                    .filter(|id| !got.contains_key(id))
                    .collect(),
                ClockMode::Realtime => Vec::new(),
            };
            if missed.is_empty() {
                wait.whole(started.elapsed());
            } else {
                tracing::warn!(
                    "step {step} timed out after {limit:?} without the commands of robots {missed:?}"
                );
            }
            self.world.apply(step, &got);
            for id in missed.iter().filter(|&&id| !self.world.is_awaited(id)) {
                tracing::warn!(
                    "robot {id} missed {} steps in a row: declared dead at step {step}",
                    self.s.clock.dead_after
                );
            }
            step += 1;
            let mut status = self.world.status(step);
            status.missed = missed;
            put(self.session, keys::STATUS, encode(&status)).await?;
        }
    }

    /// Holds `step` while the gate is paused, taking orders; true when one of them ends the run.
    async fn paused(&mut self, step: Step) -> bool {
        tracing::info!("the clock is paused before step {step}");
        let mut stop = false;
        while !stop && !self.gate.may_step() {
            stop = (self.gate).control(self.ctl.recv_async().await.ok(), &mut self.bad);
        }
        stop
    }

    /// Publishes step `step`'s scan of every robot in `alive`, then the base station's tick.
    async fn publish_scans(&mut self, alive: &[RobotId], step: Step) -> Result<(), ZenohError> {
        for &id in alive {
            if let Some(scan) = self.world.scan(id, step) {
                put(self.session, &keys::scan(id), encode(&scan)).await?;
            }
        }
        if let Some((id, tick)) = self.world.base_tick(step) {
            put(self.session, &keys::scan(id), encode(&tick)).await?;
        }
        Ok(())
    }

    /// Collects `step`'s commands until all came (lockstep) or `deadline`; `None`: the run ends.
    async fn commands(&mut self, step: Step, deadline: Instant) -> Option<HashMap<RobotId, Cmd>> {
        let mut got: HashMap<RobotId, Cmd> = HashMap::new();
        loop {
            let waiting = self.world.awaited().any(|id| !got.contains_key(&id));
            if self.s.clock.mode == ClockMode::Lockstep && !waiting {
                break;
            }
            tokio::select! {
                sample = self.cmds.recv_async() => {
                    let Ok(sample) = sample else { return None };
                    self.command(&sample, step, &mut got);
                }
                sample = self.live.recv_async() => {
                    let Ok(sample) = sample else { return None };
                    self.liveliness(&sample, step);
                }
                // Pausing takes effect once this step is done.
                c = self.ctl.recv_async() => if self.gate.control(c.ok(), &mut self.bad) {
                    return None;
                },
                _ = sleep_until(deadline) => break,
            }
        }
        Some(got)
    }

    /// Takes one command sample during `step`: into `got`, a late sign of life, or bad input.
    fn command(&mut self, sample: &Sample, step: Step, got: &mut HashMap<RobotId, Cmd>) {
        let key = sample.key_expr().as_str().to_string();
        match decode::<Cmd>(&sample.payload().to_bytes()) {
            Ok(cmd) if keys::robot_of(&key) != Some(cmd.robot) => {
                self.bad.record(&key, "robot id does not match the key")
            }
            Ok(cmd) if usize::from(cmd.robot) >= self.n => {
                self.bad.record(&key, "unknown robot id")
            }
            Ok(cmd) if cmd.step == step => {
                got.insert(cmd.robot, cmd);
            }
            Ok(cmd) if cmd.step < step => {
                // A robot declared dead that still commands (it was frozen, or too slow) is
                // back: alive from the next step.
                if self.world.rejoin(cmd.robot) {
                    tracing::warn!(
                        "robot {} commanded step {} while dead: it rejoins at step {}",
                        cmd.robot,
                        cmd.step,
                        step + 1
                    );
                } else {
                    // Late, so not applied; but the robot lives (it waited for a neighbour that
                    // did not answer): no miss towards dead_after.
                    self.world.heard_late(cmd.robot);
                    tracing::debug!("late command of robot {} for step {}", cmd.robot, cmd.step);
                }
            }
            Ok(cmd) => self
                .bad
                .record(&key, format!("command for future step {}", cmd.step)),
            Err(e) => self.bad.record(&key, e),
        }
    }

    /// Takes one liveliness sample during `step`: a token gone is death, one back is a rejoin.
    fn liveliness(&mut self, sample: &Sample, step: Step) {
        match (keys::robot_of(sample.key_expr().as_str()), sample.kind()) {
            (Some(id), SampleKind::Delete) => {
                tracing::warn!("robot {id} left the sim plane at step {step}: declared dead");
                self.world.kill(id);
            }
            // A restarted process: alive again from the next step.
            (Some(id), SampleKind::Put) if self.world.rejoin(id) => {
                tracing::warn!(
                    "robot {id} joined the sim plane again at step {step}: it rejoins at step {}",
                    step + 1
                );
            }
            _ => {}
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_pause_holds_steps_a_step_lets_one_through_and_resume_all() {
        let mut c = StepGate::default();
        assert!(c.may_step() && c.may_step());
        c.order(Control::Step);
        assert!(c.may_step(), "a step order while running changes nothing");
        c.order(Control::Pause);
        assert!(!c.may_step() && !c.may_step());
        c.order(Control::Step);
        assert!(c.may_step(), "one step");
        assert!(!c.may_step(), "then paused again");
        c.order(Control::Step);
        c.order(Control::Pause);
        assert!(!c.may_step(), "a pause takes back a step not yet taken");
        c.order(Control::Resume);
        assert!(c.may_step() && c.may_step());
    }
}
