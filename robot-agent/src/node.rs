//! The robot on its two zenoh planes (docs/design.md §1): the sim plane (a client of the
//! world-server's router: scans in, commands and telemetry out) and the radio plane (a peer with
//! scouting off, linked only to the endpoints it was given: handshakes and log deltas). All
//! decisions are [`crate::agent::Agent`]'s; this module only moves bytes between zenoh and the agent
//! (the agent's radio encodes, decodes and counts them).

use std::cell::RefCell;
use std::collections::{BTreeMap, BTreeSet, HashMap};
use std::time::Duration;

use proto::keys;
use proto::msg::{decode, encode, Cmd, Control, LinkPlan, RobotId, Scan, Step, WorldInfo};
use proto::node::{zerr, ZenohError};
use proto::scenario::Scenario;
use proto::step_wait::StepWait;
use zenoh::handlers::FifoChannelHandler;
use zenoh::key_expr::KeyExpr;
use zenoh::pubsub::Subscriber;
use zenoh::qos::CongestionControl;
use zenoh::query::{Query, Queryable};
use zenoh::sample::{Sample, SampleKind};
use zenoh::session::ZenohId;
use zenoh::Session;

use crate::agent::Agent;
use crate::radio::dial::Dialer;
use crate::radio::lockstep::Lockstep;
use crate::radio::station::Outgoing;

/// Why the robot stopped.
#[derive(Debug, PartialEq, Eq)]
pub enum End {
    Stopped,
    /// No scan arrived for this long: the world is gone.
    WorldSilent,
    /// The world-server's liveliness token vanished.
    WorldGone,
}

/// Asks the world-server for [`WorldInfo`], retrying until `wait` has passed.
pub async fn world_info(sim: &Session, wait: Duration) -> Result<WorldInfo, ZenohError> {
    proto::node::query_retry(sim, keys::WORLD_INFO, wait).await
}

/// Puts encoded radio messages on the radio plane.
///
/// Realtime: a radio link may be gone at any moment, so messages are dropped rather than queued
/// (`CongestionControl::Drop`); the exchange's handshakes make losses harmless. Lockstep: a
/// message is never dropped (`Block`; the robots' pacing keeps the queues short) and never
/// batched with another (`express`), so that the bytes on the wire do not depend on timing.
async fn send_radio(radio: &Session, keys: &RadioKeys, out: Vec<Outgoing>, lockstep: bool) {
    let cc = if lockstep {
        CongestionControl::Block
    } else {
        CongestionControl::Drop
    };
    for Outgoing { key, bytes, .. } in out {
        let Some(expr) = keys.get(radio, &key).await else {
            tracing::debug!("radio key {key} is not a key expression");
            continue;
        };
        if let Err(e) = radio
            .put(expr, bytes)
            .congestion_control(cc)
            .express(lockstep)
            .await
        {
            tracing::debug!("radio put to {key} failed: {e}");
        }
    }
}

/// The radio keys a robot puts on and receives at, each declared once to its own session.
///
/// zenoh keeps the route of a key it has a resource for and works out the route of any other key
/// on every message, walking every subscription of the team: with 128 robots that was 30 % of a
/// robot's CPU. A declaration stays in the process (the session's own table); what goes on the
/// wire, and so every byte netem counts, is unchanged.
struct RadioKeys(RefCell<HashMap<String, KeyExpr<'static>>>);

impl RadioKeys {
    /// With this robot's inbox keys (`radio/<id>/<kind>` for every kind) declared, so that what
    /// arrives is routed on a kept route too.
    async fn with_inbox(radio: &Session, id: RobotId) -> RadioKeys {
        let keys = RadioKeys(RefCell::default());
        for kind in keys::RADIO_KINDS {
            keys.get(radio, &keys::radio_key(id, kind)).await;
        }
        keys
    }

    /// `key`, declared; undeclared if the session refuses the declaration (closing); `None` if
    /// it is not a key expression at all.
    async fn get(&self, radio: &Session, key: &str) -> Option<KeyExpr<'static>> {
        if let Some(expr) = self.0.borrow().get(key) {
            return Some(expr.clone());
        }
        match radio.declare_keyexpr(key.to_string()).await {
            Ok(expr) => {
                self.0.borrow_mut().insert(key.to_string(), expr.clone());
                Some(expr)
            }
            Err(e) => {
                tracing::debug!("declaring radio key {key} failed: {e}");
                KeyExpr::new(key.to_string()).ok()
            }
        }
    }
}

async fn put_sim(sim: &Session, key: String, bytes: Vec<u8>) -> Result<(), ZenohError> {
    sim.put(key, bytes)
        .congestion_control(CongestionControl::Block)
        .await
        .map_err(zerr)
}

/// How long a robot waits for the world-server's token to come back once it vanished: a
/// session to the router that dropped (this process was frozen past its lease) reconnects and
/// sees the token again; a world-server that is gone does not come back.
const WORLD_GRACE: Duration = Duration::from_secs(3);

/// The subscriptions of a robot on its two planes.
struct Subs {
    /// Since when the world-server's token has been gone (`None`: it is there).
    world_lost: std::cell::Cell<Option<tokio::time::Instant>>,
    /// The launcher paused the step clock ([`Control::Pause`]): no scan is due, so silence is
    /// not the world's end.
    paused: std::cell::Cell<bool>,
    scans: Subscriber<FifoChannelHandler<Sample>>,
    plans: Subscriber<FifoChannelHandler<Sample>>,
    ctl: Subscriber<FifoChannelHandler<Sample>>,
    world_alive: Subscriber<FifoChannelHandler<Sample>>,
    inbox: Subscriber<FifoChannelHandler<Sample>>,
    peers: Subscriber<FifoChannelHandler<Sample>>,
    /// A viewer's questions about what this robot holds ([`keys::held`]).
    asked: Queryable<FifoChannelHandler<Query>>,
}

/// Something that happened on either plane.
enum Event {
    Scan(Scan),
    Plan(LinkPlan),
    /// A radio payload: its key's kind and bytes.
    Radio(String, Vec<u8>),
    /// A peer's radio liveliness token appeared (`true`) or vanished.
    Peer(RobotId, bool),
    /// A viewer asks what the robot holds.
    Asked(Query),
    /// Nothing to do (an undecodable message, logged).
    Nothing,
    End(End),
}

/// The event a sim-plane sample carries: `wrap` of its decoded payload, `Nothing` (logged) if it
/// does not decode, the end once the subscription closed.
fn decoded<T: serde::de::DeserializeOwned, E>(
    sample: Result<Sample, E>,
    what: &str,
    wrap: impl FnOnce(T) -> Event,
) -> Event {
    let Ok(sample) = sample else {
        return Event::End(End::Stopped);
    };
    match decode::<T>(&sample.payload().to_bytes()) {
        Ok(m) => wrap(m),
        Err(e) => {
            tracing::warn!("bad {what}: {e}");
            Event::Nothing
        }
    }
}

impl Subs {
    async fn declare(id: RobotId, sim: &Session, radio: &Session) -> Result<Subs, ZenohError> {
        Ok(Subs {
            world_lost: std::cell::Cell::new(None),
            paused: std::cell::Cell::new(false),
            scans: sim.declare_subscriber(keys::scan(id)).await.map_err(zerr)?,
            plans: sim.declare_subscriber(keys::plan(id)).await.map_err(zerr)?,
            ctl: sim.declare_subscriber(keys::CONTROL).await.map_err(zerr)?,
            world_alive: sim
                .liveliness()
                .declare_subscriber(keys::WORLD_ALIVE)
                .history(true)
                .await
                .map_err(zerr)?,
            // Everything addressed to this robot on the radio, told apart by the key's last
            // segment.
            inbox: radio
                .declare_subscriber(keys::radio_inbox(id))
                .await
                .map_err(zerr)?,
            peers: radio
                .liveliness()
                .declare_subscriber(keys::RADIO_ALIVE_ALL)
                .history(true)
                .await
                .map_err(zerr)?,
            asked: sim.declare_queryable(keys::held(id)).await.map_err(zerr)?,
        })
    }

    /// The next event; `idle` without any scan (and the clock not paused): the world fell
    /// silent.
    async fn next(&self, idle: Duration) -> Event {
        let world_lost = self.world_lost.get();
        tokio::select! {
            sample = self.scans.recv_async() => decoded(sample, "scan", Event::Scan),
            sample = self.plans.recv_async() => decoded(sample, "link plan", Event::Plan),
            sample = self.inbox.recv_async() => {
                let Ok(sample) = sample else { return Event::End(End::Stopped) };
                let kind = keys::radio_kind(sample.key_expr().as_str()).unwrap_or_default().to_string();
                Event::Radio(kind, sample.payload().to_bytes().into_owned())
            }
            sample = self.peers.recv_async() => {
                let Ok(sample) = sample else { return Event::End(End::Stopped) };
                match keys::robot_of(sample.key_expr().as_str()) {
                    Some(peer) => Event::Peer(peer, sample.kind() == SampleKind::Put),
                    None => Event::Nothing,
                }
            }
            q = self.asked.recv_async() => match q {
                Ok(q) => Event::Asked(q),
                Err(_) => Event::End(End::Stopped),
            },
            c = self.ctl.recv_async() => {
                match c.map(|c| decode::<Control>(&c.payload().to_bytes())) {
                    Ok(Ok(Control::Stop)) | Err(_) => Event::End(End::Stopped),
                    Ok(Ok(Control::Pause)) => { self.paused.set(true); Event::Nothing }
                    Ok(Ok(Control::Resume)) => { self.paused.set(false); Event::Nothing }
                    Ok(Ok(Control::Step)) => Event::Nothing,
                    Ok(Err(e)) => { tracing::warn!("bad control message: {e}"); Event::Nothing }
                }
            }
            w = self.world_alive.recv_async() => match w {
                Err(_) => Event::End(End::WorldGone),
                Ok(w) if w.kind() == SampleKind::Delete => {
                    if world_lost.is_none() {
                        self.world_lost.set(Some(tokio::time::Instant::now() + WORLD_GRACE));
                    }
                    Event::Nothing
                }
                Ok(_) => {
                    self.world_lost.set(None);
                    Event::Nothing
                }
            },
            () = tokio::time::sleep_until(world_lost.unwrap_or_else(tokio::time::Instant::now)), if world_lost.is_some() => {
                Event::End(End::WorldGone)
            }
            _ = tokio::time::sleep(idle), if !self.paused.get() => Event::End(End::WorldSilent),
        }
    }
}

/// Lockstep: waits for netem's token, so that netem sees the world's first status and publishes
/// the links of every step (the robot waits for them).
async fn wait_for_netem(sim: &Session, wait: Duration) -> Result<(), ZenohError> {
    let netem = sim
        .liveliness()
        .declare_subscriber(keys::NETEM_ALIVE)
        .history(true)
        .await
        .map_err(zerr)?;
    let deadline = tokio::time::Instant::now() + wait;
    loop {
        match tokio::time::timeout_at(deadline, netem.recv_async()).await {
            Ok(Ok(s)) if s.kind() == SampleKind::Put => return Ok(()),
            Ok(Ok(_)) => {}
            Ok(Err(_)) | Err(_) => {
                return Err(ZenohError(format!(
                    "netem did not join the sim plane within {wait:?}: a lockstep robot needs it \
                     (it says which links are up each step)"
                )))
            }
        }
    }
}

/// Runs robot `id` in its life `life` until the launcher stops it or the world falls silent.
pub async fn run_robot(
    (id, life): (RobotId, u16),
    s: &Scenario,
    sim: Session,
    (radio, dialer): (Session, Dialer),
    world: WorldInfo,
    idle_timeout: Duration,
) -> Result<End, ZenohError> {
    let agent = Agent::in_life(id, life, world, s);
    let subs = Subs::declare(id, &sim, &radio).await?;
    let _radio_token = radio
        .liveliness()
        .declare_token(keys::radio_alive(id))
        .await
        .map_err(zerr)?;
    if s.clock.marked() {
        wait_for_netem(&sim, idle_timeout).await?;
    }
    // Declared last: the world-server starts the clock once every robot's token is there, and by
    // then this robot's subscribers exist (and, in lockstep, netem's).
    let _sim_token = sim
        .liveliness()
        .declare_token(keys::sim_alive(id))
        .await
        .map_err(zerr)?;
    let planes = Planes {
        id,
        sim: &sim,
        radio: &radio,
        radio_keys: RadioKeys::with_inbox(&radio, id).await,
        subs: &subs,
        idle: std::cell::Cell::new(idle_timeout),
        idle_floor: idle_timeout,
        dialer: RefCell::new(dialer),
        step_wait: s.step_wait(),
        peers: (0..s.nodes())
            .filter(|&r| r != id)
            .filter_map(|r| Some((proto::node::radio_zid(r).parse().ok()?, r)))
            .collect(),
    };
    if s.clock.marked() {
        lockstep(agent, &planes).await
    } else {
        as_it_comes(agent, &planes).await
    }
}

/// What a robot's loop works with.
struct Planes<'a> {
    id: RobotId,
    sim: &'a Session,
    radio: &'a Session,
    radio_keys: RadioKeys,
    subs: &'a Subs,
    /// How long the world may be silent before the robot takes it for gone: the node's idle
    /// timeout, or in lockstep twice the world's step wait as the robot sees its steps, if
    /// longer ([`Planes::patience`]).
    idle: std::cell::Cell<Duration>,
    /// The node's own idle timeout (`--idle-timeout-s`).
    idle_floor: Duration,
    /// Opens the sessions of links that come up.
    dialer: RefCell<Dialer>,
    /// The world's step wait before any step is seen.
    step_wait: StepWait,
    /// Every other robot of the run, by its radio session's zenoh id.
    peers: BTreeMap<ZenohId, RobotId>,
}

/// How soon a robot waiting for a link's session looks at zenoh's list of sessions again: at
/// first after 2 ms, then twice as long each time up to [`session_poll_max`]. Listing the
/// sessions costs a robot its number of sessions; every 2 ms, 128 robots with 127 sessions each
/// spent more than the two cores of the test machine on it and their sessions never formed.
const SESSION_POLL: Duration = Duration::from_millis(2);

/// The longest a robot of a team of `team` goes without looking (a session that forms is used
/// within it): 2 ms for every 4 robots, at most 64 ms — a small team takes a new link at once
/// (64 ms cost the default run's 4-robot team about 15 % of its wall time), a big one spends
/// less on listing sessions.
fn session_poll_max(team: usize) -> Duration {
    let fours = u32::try_from(team.div_ceil(4).max(1)).unwrap_or(u32::MAX);
    (SESSION_POLL * fours).min(Duration::from_millis(64))
}

impl Planes<'_> {
    /// Follows the world's step wait ([`proto::step_wait`]) from the steps this robot sees:
    /// it never takes the world for gone while the world may still be waiting for a robot.
    fn patience(&self, wait: &StepWait) {
        self.idle
            .set(self.idle_floor.max(wait.limit().saturating_mul(2)));
    }

    /// The robots this one has a radio session with (not through another robot).
    async fn sessions(&self) -> BTreeSet<RobotId> {
        self.radio
            .info()
            .peers_zid()
            .await
            .filter_map(|z| self.peers.get(&z).copied())
            .collect()
    }
}

/// Realtime (and lockstep without markers): acts on every scan as it comes and takes radio
/// traffic as it arrives.
async fn as_it_comes(mut agent: Agent, p: &Planes<'_>) -> Result<End, ZenohError> {
    loop {
        match p.subs.next(p.idle.get()).await {
            Event::Scan(scan) => {
                let cmd = agent.on_scan(&scan);
                put_sim(p.sim, keys::cmd(p.id), encode(&cmd)).await?;
                send_radio(p.radio, &p.radio_keys, agent.radio_step(), false).await;
                put_sim(p.sim, keys::telemetry(p.id), encode(&agent.telemetry())).await?;
            }
            Event::Radio(kind, bytes) => {
                let out = agent.on_radio(&kind, &bytes);
                send_radio(p.radio, &p.radio_keys, out, false).await;
            }
            Event::Peer(peer, true) => {
                let out = agent.link_up(peer);
                send_radio(p.radio, &p.radio_keys, out, false).await;
            }
            Event::Peer(peer, false) => agent.link_down(peer),
            Event::Asked(q) => answer(q, &agent),
            // A session is up once its token is seen (`Event::Peer`).
            Event::Plan(plan) => p.dialer.borrow_mut().dial(&plan, |peer| agent.hears(peer)),
            Event::Nothing => {}
            Event::End(e) => return Ok(e),
        }
    }
}

/// Lockstep: the step protocol of [`crate::radio::lockstep`].
async fn lockstep(mut agent: Agent, p: &Planes<'_>) -> Result<End, ZenohError> {
    let mut ls = Lockstep::default();
    // Answers produced while taking a step's arrivals: sent with the next step's traffic.
    let mut answers = Vec::new();
    // The world's step wait, from the steps as this robot sees them start.
    let (mut wait, mut last) = (p.step_wait.clone(), None::<(Step, tokio::time::Instant)>);
    loop {
        let t = loop {
            if let Some(t) = ls.ready() {
                break t;
            }
            if let Some(end) = note(&mut ls, &mut agent, p.subs.next(p.idle.get()).await) {
                return Ok(end);
            }
        };
        let now = tokio::time::Instant::now();
        if let Some((_, at)) = last.filter(|&(before, _)| before + 1 == t) {
            wait.whole(now - at);
            p.patience(&wait);
        }
        last = Some((t, now));
        let Some((scan, plan)) = ls.start(p.id, t) else {
            continue;
        };
        let (linked, greetings) = take_links(&mut agent, &mut ls, &plan, p.id);
        match await_sessions(&mut agent, &mut ls, p, (t, &plan), &linked).await? {
            Wait::Done => {}
            Wait::Skipped => continue,
            Wait::Ended(end) => return Ok(end),
        }
        let cmd = agent.on_scan(&scan);
        let mut out = std::mem::take(&mut answers);
        out.extend(greetings);
        out.extend(agent.radio_step());
        out.extend(agent.frames());
        tracing::debug!(
            "step {t}: sent {:?}",
            out.iter()
                .map(|o| (o.to, o.key.as_str(), o.bytes.len()))
                .collect::<Vec<_>>()
        );
        send_radio(p.radio, &p.radio_keys, out, true).await;
        match await_marks(&mut agent, &mut ls, p, t, &linked, &cmd).await? {
            Wait::Done => {}
            Wait::Skipped => continue,
            Wait::Ended(end) => return Ok(end),
        }
        for m in ls.take(p.id, t, &plan) {
            answers.extend(agent.take(m));
        }
        put_sim(p.sim, keys::cmd(p.id), encode(&cmd)).await?;
        put_sim(p.sim, keys::telemetry(p.id), encode(&agent.telemetry())).await?;
    }
}

/// What waiting within a lockstep step came to.
enum Wait {
    /// What was waited for is there.
    Done,
    /// The world went on without this step; the robot told it it lives (a late command).
    Skipped,
    /// The robot ends.
    Ended(End),
}

/// The step's links as netem's `plan` gives them to robot `me`: their rates and credits, the
/// neighbours greeted and the ones gone forgotten (a held link keeps its session, a link that is
/// down lost it). Returns the linked peers and the greetings to send.
fn take_links(
    agent: &mut Agent,
    ls: &mut Lockstep,
    plan: &LinkPlan,
    me: RobotId,
) -> (Vec<RobotId>, Vec<Outgoing>) {
    let linked = plan.neighbours(me);
    for &peer in &linked {
        let link = plan.link(me, peer);
        agent.set_rate(peer, link.and_then(|l| l.rate_from(me)));
        agent.set_credit(peer, link.and_then(|l| l.credit_from(me)));
    }
    let (greetings, gone) = agent.set_neighbours(&linked);
    let cut: Vec<RobotId> = gone
        .into_iter()
        .filter(|&peer| plan.link(me, peer).is_none())
        .collect();
    ls.cut(&cut);
    (linked, greetings)
}

/// Waits until every `linked` peer's radio session is up. zenoh's list of sessions is asked for
/// only while a link is not seen up, and zenoh tells no event when a session forms: look again
/// soon, then less often.
async fn await_sessions(
    agent: &mut Agent,
    ls: &mut Lockstep,
    p: &Planes<'_>,
    (t, plan): (Step, &LinkPlan),
    linked: &[RobotId],
) -> Result<Wait, ZenohError> {
    let mut poll = SESSION_POLL;
    let poll_max = session_poll_max(p.peers.len() + 1);
    while !ls.linked(linked) {
        ls.on_sessions(p.sessions().await);
        if ls.linked(linked) {
            break;
        }
        // The links whose sessions are not up yet: this robot opens those it is the lower
        // end of (again, if an attempt failed).
        p.dialer
            .borrow_mut()
            .dial(plan, |peer| ls.linked(std::slice::from_ref(&peer)));
        if ls.newer_than(t) {
            // The world went on while a link's session did not form (the peer was frozen or
            // hung before its first session came up). A late command, moving nowhere, tells the
            // world this robot lives (else the whole team would miss its steps with the one
            // that hangs, and be declared dead with it).
            let late = Cmd {
                step: t,
                robot: p.id,
                waypoint: None,
            };
            put_sim(p.sim, keys::cmd(p.id), encode(&late)).await?;
            return Ok(Wait::Skipped);
        }
        if let Ok(e) = tokio::time::timeout(poll, p.subs.next(p.idle.get())).await {
            if let Some(end) = note(ls, agent, e) {
                return Ok(Wait::Ended(end));
            }
        }
        poll = (poll * 2).min(poll_max);
    }
    Ok(Wait::Done)
}

/// Waits for step `t`'s marker from every `linked` peer.
async fn await_marks(
    agent: &mut Agent,
    ls: &mut Lockstep,
    p: &Planes<'_>,
    t: Step,
    linked: &[RobotId],
    cmd: &Cmd,
) -> Result<Wait, ZenohError> {
    while !ls.marked(t, linked) {
        if ls.newer_than(t) {
            // The world went on without this step (a neighbour's marker never came: it is
            // frozen or hung). The command, late, still tells the world this robot lives.
            put_sim(p.sim, keys::cmd(p.id), encode(cmd)).await?;
            return Ok(Wait::Skipped);
        }
        if let Some(end) = note(ls, agent, p.subs.next(p.idle.get()).await) {
            return Ok(Wait::Ended(end));
        }
    }
    tracing::debug!("step {t}: marked by {linked:?}");
    let missing = ls.unmarked(t, linked);
    if !missing.is_empty() {
        tracing::warn!("step {t}: no marker from {missing:?}: their sessions were lost");
    }
    Ok(Wait::Done)
}

/// Notes an event in the lockstep bookkeeping (a radio payload counted and decoded once, by
/// the agent's radio); `Some` when it ends the robot.
fn note(ls: &mut Lockstep, agent: &mut Agent, e: Event) -> Option<End> {
    match e {
        Event::Scan(s) => ls.on_scan(s),
        // netem sends each robot only its own links (`keys::plan`).
        Event::Plan(plan) => ls.on_plan(plan),
        Event::Radio(kind, bytes) => {
            let r = agent.receive(&kind, &bytes);
            r.msgs.into_iter().for_each(|m| ls.on_radio(m));
            if let Some(end) = r.end {
                ls.on_mark(end);
            }
        }
        Event::Peer(peer, up) => ls.on_token(peer, up),
        Event::Asked(q) => answer(q, agent),
        Event::Nothing => {}
        Event::End(e) => return Some(e),
    }
    None
}

/// Answers a viewer's question with what the agent holds ([`Agent::held`]); the reply goes out
/// from a task of its own, so the step never waits for it.
fn answer(q: Query, agent: &Agent) {
    let bytes = encode(&agent.held());
    tokio::spawn(async move {
        if let Err(e) = q.reply(q.key_expr().clone(), bytes).await {
            tracing::warn!("the answer to {} failed: {e}", q.key_expr());
        }
    });
}
