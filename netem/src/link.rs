//! One robot pair's link: its TCP proxy, its state (up or down, and why), its toxics and its
//! counters (docs/design.md §1, §5: "one listener per unordered pair {i, j}; a connection is
//! forwarded to robot max(i,j)'s radio listener").
//!
//! The structure is tokio's `examples/proxy.rs` — an accept loop that spawns one task per
//! connection — with each direction run through the shaping pipeline (`shaping/`) instead of
//! `copy_bidirectional`, and a supervisor per connection that applies toxic changes and timers.
//!
//! **Link cut.** A link is up iff it is enabled (no cut, no partition), in radio range, and both
//! robots are alive. When it goes down, every connection is reset (RST both ways: what netem holds
//! and what the kernel has not sent yet is lost, as on a real radio). While it is down the listener
//! stays bound and a new connection is *accepted and held*: nothing is forwarded or counted, what
//! the robot sends is kept (its session's opening message, [`HELD_BYTES`](crate::link::HELD_BYTES)
//! at most), and when the link comes up netem connects to the peer and passes it on — the robot's
//! session opens as if the radio had been silent until then. A held connection the robot closes
//! (its handshake timed out) is dropped. A peer that does not listen yet (a robot being started
//! again) is tried again with a backoff, the connection held meanwhile. (Refusing a connection
//! instead, as netem once did, made every robot retry every link out of range every 20 ms — 8 000
//! pairs at 128 robots, 400 000 connections a second; closing the listener would risk losing the
//! port to another process and turn a reconnect into a rebind.)
//!
//! **A proxy while in range.** That is a link whose port was given (robots were told it at start
//! and keep trying it). A link given only its host
//! ([`Link::while_up`](crate::link::Link::while_up)) listens only while it is up: it binds a free
//! port the moment it comes up — before the step's plan is made, which tells robot a where to
//! connect ([`PlannedLink::proxy`](proto::msg::PlannedLink::proxy)) — and closes it when it goes
//! down, so netem holds descriptors for the pairs in range, not for every pair (`swarm run` makes
//! every link so). It binds the port it had before when it can.

use std::collections::HashMap;
use std::net::SocketAddr;
use std::sync::atomic::{AtomicU64, Ordering::Relaxed};
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::Duration;

use proto::msg::{PlannedLink, RobotId};
use serde::Serialize;
use tokio::net::tcp::OwnedWriteHalf;
use tokio::net::{TcpListener, TcpStream};
use tokio::sync::watch;
use tokio::task::{AbortHandle, JoinHandle};

use crate::accounting::{Buffer, Dir, DirCounters, DirSnapshot};
use crate::faults::{self, ActiveToxic, BaseShape, Kill, Toxic};
use crate::radio::Verdict;
use crate::shaping::pipeline::{self, PipeEnd};
use crate::shaping::DirShape;
use proto::clock::{SimClock, SimTime};

/// Most simultaneous connections per pair (zenoh opens one; a few more cover reconnect races).
pub const MAX_CONNECTIONS: usize = 8;
/// Most bytes netem keeps of a connection held while its link is down (a zenoh session's
/// opening message is a few dozen); beyond it, it stops reading and TCP pushes back.
pub const HELD_BYTES: usize = 4096;
/// Most toxics per link.
pub const MAX_TOXICS: usize = 32;

/// The fixed parameters of a link.
#[derive(Clone, Debug)]
pub struct LinkParams {
    pub a: RobotId,
    pub b: RobotId,
    pub target: SocketAddr,
    pub base: [BaseShape; 2],
    pub buffer_bytes: usize,
    pub connect_timeout: Duration,
    pub seed: u64,
    /// Lockstep with step markers: latency is announced in the step's plan and carried out by
    /// the receiving robot (it acts on a message `delay` steps after it was sent); the link
    /// forwards at once, so that what a step carries never depends on when netem read it (a
    /// slicer still cuts writes, without its delay).
    pub markers: bool,
}

/// Why a link is down.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum DownReason {
    /// Cut administratively (a fault, a partition, `enabled: false`).
    Disabled,
    /// A robot is declared dead by the world-server.
    Dead,
    /// The radio model says no.
    OutOfRange,
    /// A range model needs poses and netem has none yet.
    NoPose,
}

impl DownReason {
    pub fn as_str(self) -> &'static str {
        match self {
            DownReason::Disabled => "disabled",
            DownReason::Dead => "dead",
            DownReason::OutOfRange => "out_of_range",
            DownReason::NoPose => "no_pose",
        }
    }
}

/// The mutable state that decides whether a link is up.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LinkState {
    pub enabled: bool,
    pub alive: bool,
    /// `None`: no verdict yet (no poses); counts as in range only for the `always` model.
    pub radio: Option<Verdict>,
    pub always: bool,
}

impl LinkState {
    pub fn down_reason(&self) -> Option<DownReason> {
        if !self.enabled {
            Some(DownReason::Disabled)
        } else if !self.alive {
            Some(DownReason::Dead)
        } else if self.always {
            None
        } else {
            match self.radio {
                None => Some(DownReason::NoPose),
                Some(v) if !v.in_range => Some(DownReason::OutOfRange),
                Some(_) => None,
            }
        }
    }
}

struct ConnEntry {
    kill: watch::Sender<Option<Kill>>,
    abort: Option<AbortHandle>,
}

/// A pair's proxy.
pub struct Link {
    pub params: LinkParams,
    pub name: String,
    /// The address the proxy listens on.
    host: std::net::IpAddr,
    /// Every port the proxy has listened on, in order (`link_totals.csv`); the last is where it
    /// listens, or listened last ([`Link::listen`]).
    ports: Mutex<Vec<u16>>,
    /// Listens only while the link is up, on a port it binds then (see the module's doc).
    while_up: bool,
    /// Bound as the link came up, for the accept loop to take.
    fresh: Mutex<Option<std::net::TcpListener>>,
    clock: SimClock,
    counters: [Arc<DirCounters>; 2],
    state: Mutex<LinkState>,
    up: watch::Sender<bool>,
    toxics: watch::Sender<Arc<Vec<ActiveToxic>>>,
    conns: Mutex<HashMap<u64, ConnEntry>>,
    next_conn: AtomicU64,
    connects_total: AtomicU64,
    /// Accepted connections that reached the target (robot b's radio listener).
    established_total: AtomicU64,
    refused_total: AtomicU64,
    /// Per direction, what the link's budget can still carry (lockstep with markers).
    credit: Mutex<[Option<Credit>; 2]>,
    /// Per direction, the step's airtime share and whether its frame is lost (netem's
    /// [`Channel`](crate::channel::Channel)).
    air: Mutex<[AirPlan; 2]>,
    /// Connections through the link that reached robot b (see [`Link::serve`]).
    through: watch::Sender<usize>,
    /// netem's stop: the accept loop ends and connections held ([`Link::hold`]) end at once —
    /// they carry nothing, and a robot's zenoh does not close while an opening handshake on one
    /// is pending, so netem waiting for them would wait for itself.
    shutdown: watch::Receiver<bool>,
}

/// A direction's budget as netem reckons it from the bytes it carried, step by step: a token
/// bucket of the direction's rate and burst that refills one step's worth when a step opens
/// and loses the bytes counted in the step that ended. It is what the bandwidth shaping can
/// let through in the step (the shaping takes its grants in quanta as chunks come, which
/// depends on timing; the bytes of a step do not), so robots pace against it
/// ([`PlannedLink::credit`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Credit {
    pub level: f64,
}

impl Credit {
    /// The credit when a step opens: `prev` (a full bucket if none) less the `bytes` carried in
    /// the step that ended, plus one step of `step_seconds` at `rate`, at most `burst`. A
    /// direction whose rate or burst changed keeps what it had, within the new burst.
    pub fn open(
        prev: Option<Credit>,
        rate: u64,
        burst: u64,
        bytes: u64,
        step_seconds: f64,
    ) -> Credit {
        let before = prev.map_or(burst as f64, |c| c.level);
        let level = (before - bytes as f64 + rate as f64 * step_seconds).clamp(0.0, burst as f64);
        Credit { level }
    }
}

/// A direction's part of the shared channel in a step.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct AirPlan {
    /// The airtime share with the frame header's allowance, bytes: a cap on the credit
    /// (`None`: the channel is not shared).
    pub credit: Option<u32>,
    /// The frame of the step is lost once: its receiver acts on it a step later.
    pub lost: bool,
}

/// A copy of a link's state and counters.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct LinkSnapshot {
    pub a: RobotId,
    pub b: RobotId,
    pub name: String,
    pub listen: SocketAddr,
    pub target: SocketAddr,
    pub up: bool,
    pub enabled: bool,
    pub down_reason: Option<DownReason>,
    pub verdict: Option<Verdict>,
    pub dirs: [DirSnapshot; 2],
    pub connections: usize,
    pub connects_total: u64,
    pub established_total: u64,
    pub refused_total: u64,
    pub toxics: Vec<Toxic>,
    /// Up but held by a toxic (a blackhole: a `timeout` of 0).
    pub held: bool,
}

fn lock<T>(m: &Mutex<T>) -> MutexGuard<'_, T> {
    m.lock().unwrap_or_else(|p| p.into_inner())
}

impl Link {
    /// A link whose listener is bound at `listen`; call [`Link::serve`] to start accepting.
    /// It stops when `shutdown` becomes true.
    pub fn new(
        params: LinkParams,
        listen: SocketAddr,
        clock: SimClock,
        state: LinkState,
        shutdown: watch::Receiver<bool>,
    ) -> Arc<Link> {
        Self::make(params, listen, false, clock, state, shutdown)
    }

    /// A link that listens on a free port of `host` only while it is up (see the module's
    /// doc); call [`Link::serve`] (with no listener) to start accepting.
    pub fn while_up(
        params: LinkParams,
        host: std::net::IpAddr,
        clock: SimClock,
        state: LinkState,
        shutdown: watch::Receiver<bool>,
    ) -> Arc<Link> {
        let link = Self::make(
            params,
            SocketAddr::new(host, 0),
            true,
            clock,
            state,
            shutdown,
        );
        if link.is_up() {
            link.open_port();
        }
        link
    }

    fn make(
        params: LinkParams,
        listen: SocketAddr,
        while_up: bool,
        clock: SimClock,
        state: LinkState,
        shutdown: watch::Receiver<bool>,
    ) -> Arc<Link> {
        let up = state.down_reason().is_none();
        Arc::new(Link {
            name: faults::link_name(params.a, params.b),
            params,
            host: listen.ip(),
            ports: Mutex::new(Vec::from_iter(
                (listen.port() != 0).then_some(listen.port()),
            )),
            while_up,
            fresh: Mutex::new(None),
            clock,
            counters: [Arc::default(), Arc::default()],
            state: Mutex::new(state),
            up: watch::Sender::new(up),
            toxics: watch::Sender::new(Arc::new(Vec::new())),
            conns: Mutex::new(HashMap::new()),
            next_conn: AtomicU64::new(0),
            connects_total: AtomicU64::new(0),
            established_total: AtomicU64::new(0),
            refused_total: AtomicU64::new(0),
            credit: Mutex::new([None, None]),
            air: Mutex::new([AirPlan::default(); 2]),
            through: watch::Sender::new(0),
            shutdown,
        })
    }

    pub fn is_up(&self) -> bool {
        *self.up.borrow()
    }

    /// Where the proxy listens (or listened last; port 0: never yet).
    pub fn listen(&self) -> SocketAddr {
        SocketAddr::new(self.host, lock(&self.ports).last().copied().unwrap_or(0))
    }

    /// Whether the proxy listens or listened at `addr` (a proxy that listens while up: on its
    /// address, at any port it had, or port 0).
    pub fn listened_at(&self, addr: SocketAddr) -> bool {
        addr == self.listen()
            || (self.while_up
                && addr.ip() == self.host
                && (addr.port() == 0 || lock(&self.ports).contains(&addr.port())))
    }

    /// Every port the proxy has listened on, in order.
    pub fn ports(&self) -> Vec<u16> {
        lock(&self.ports).clone()
    }

    /// Binds the port of a link that listens while up: the one it had, else a free one. A
    /// failure is logged; the accept loop tries again ([`Link::bind_again`]).
    fn open_port(&self) {
        let was = self.listen();
        let bound = std::net::TcpListener::bind(was)
            .or_else(|_| std::net::TcpListener::bind(SocketAddr::new(self.host, 0)))
            .and_then(|l| l.set_nonblocking(true).map(|()| l));
        match bound.and_then(|l| l.local_addr().map(|a| (l, a))) {
            Ok((l, addr)) => {
                self.bound(addr);
                *lock(&self.fresh) = Some(l);
            }
            Err(e) => tracing::warn!(link = %self.name, "cannot listen on {}: {e}", self.host),
        }
    }

    /// Notes that the proxy listens at `addr` (on its host).
    fn bound(&self, addr: SocketAddr) {
        let mut ports = lock(&self.ports);
        if ports.last() != Some(&addr.port()) {
            ports.push(addr.port());
        }
    }

    pub fn counters(&self, dir: Dir) -> &DirCounters {
        &self.counters[dir.index()]
    }

    /// Changes the state; resets every connection if the link goes down. Returns whether it is up.
    pub fn update(&self, f: impl FnOnce(&mut LinkState)) -> bool {
        let up = {
            let mut st = lock(&self.state);
            f(&mut st);
            st.down_reason().is_none()
        };
        let conns = lock(&self.conns);
        let was = *self.up.borrow();
        if self.while_up && up && !was {
            // Bound before anyone hears the link is up: the step's plan gives its address.
            self.open_port();
        } else if self.while_up && !up {
            lock(&self.fresh).take();
        }
        // Only a change wakes those who wait on it (the accept loop, held connections).
        self.up.send_if_modified(|u| std::mem::replace(u, up) != up);
        if was && !up {
            tracing::info!(link = %self.name, "link down: resetting {} connection(s)", conns.len());
            for c in conns.values() {
                c.kill.send_replace(Some(Kill::Reset));
            }
        } else if !was && up {
            tracing::info!(link = %self.name, "link up");
        }
        up
    }

    pub fn state(&self) -> LinkState {
        *lock(&self.state)
    }

    /// Resets the current connections once (the link's state does not change).
    pub fn reset_connections(&self) {
        for c in lock(&self.conns).values() {
            c.kill.send_replace(Some(Kill::Reset));
        }
    }

    pub fn toxics(&self) -> Arc<Vec<ActiveToxic>> {
        Arc::clone(&self.toxics.borrow())
    }

    /// Replaces the toxic list (validated by the caller, at most [`MAX_TOXICS`]).
    pub fn set_toxics(&self, toxics: Vec<ActiveToxic>) {
        self.toxics.send_replace(Arc::new(toxics));
    }

    pub fn snapshot(&self) -> LinkSnapshot {
        let st = self.state();
        LinkSnapshot {
            a: self.params.a,
            b: self.params.b,
            name: self.name.clone(),
            listen: self.listen(),
            target: self.params.target,
            up: self.is_up(),
            enabled: st.enabled,
            down_reason: st.down_reason(),
            verdict: st.radio,
            dirs: [self.counters[0].snapshot(), self.counters[1].snapshot()],
            connections: lock(&self.conns).len(),
            connects_total: self.connects_total.load(Relaxed),
            established_total: self.established_total.load(Relaxed),
            refused_total: self.refused_total.load(Relaxed),
            toxics: self.toxics().iter().map(|t| t.toxic.clone()).collect(),
            held: self.planned(1).is_some_and(|p| p.held),
        }
    }

    /// Whether a connection through the link reached robot b (one that is held while the link
    /// is down, or while b does not listen, carries nothing yet).
    pub fn has_connections_through(&self) -> bool {
        *self.through.borrow() > 0
    }

    /// Resets every connection and waits (up to `wait`) until their tasks have ended; aborts the
    /// rest.
    pub async fn close_all(&self, wait: Duration) {
        self.reset_connections();
        let deadline = tokio::time::Instant::now() + wait;
        while !lock(&self.conns).is_empty() && tokio::time::Instant::now() < deadline {
            tokio::time::sleep(Duration::from_millis(2)).await;
        }
        for c in lock(&self.conns).values() {
            if let Some(a) = &c.abort {
                a.abort();
            }
        }
    }

    /// Spawns the accept loop on `listener`; it ends when netem stops.
    ///
    /// The listener is closed while the link is up and a connection through it has reached
    /// robot b — the port stays netem's, held by that connection — and bound again the moment
    /// the link goes down or no such connection is left. A link in use then costs netem two
    /// descriptors instead of three: 16 000 instead of 24 000 at 128 robots all in range (see
    /// [`crate::fds`]). (The launcher looks for free ports without `SO_REUSEADDR`, so it never
    /// takes a port a connection holds.)
    ///
    /// A link that listens while up ([`Link::while_up`]) is given no listener: it takes the one
    /// bound as the link came up, and closes it when the link goes down.
    pub fn serve(self: &Arc<Self>, listener: Option<TcpListener>) -> JoinHandle<()> {
        let link = Arc::clone(self);
        let mut shutdown = self.shutdown.clone();
        tokio::spawn(async move {
            let mut listener = listener;
            let mut up = link.up.subscribe();
            let mut through = link.through.subscribe();
            loop {
                let is_up = *up.borrow_and_update();
                let unused = *through.borrow_and_update() == 0;
                let needed = if link.while_up {
                    is_up && unused
                } else {
                    !is_up || unused
                };
                match (&listener, needed) {
                    (Some(_), false) => listener = None,
                    (None, true) => {
                        let fresh = lock(&link.fresh).take();
                        listener = match fresh.map(TcpListener::from_std) {
                            Some(Ok(l)) => Some(l),
                            _ => link.bind_again(&mut shutdown).await,
                        };
                    }
                    _ => {}
                }
                tokio::select! {
                    () = stopped(&mut shutdown) => break,
                    _ = up.changed() => {}
                    _ = through.changed() => {}
                    accepted = accept(listener.as_ref()) => match accepted {
                        Ok((stream, peer)) => link.admit(stream, peer),
                        Err(e) => {
                            // Out of descriptors and the like: back off instead of spinning.
                            tracing::warn!(link = %link.name, "accept failed: {e}");
                            tokio::time::sleep(Duration::from_millis(20)).await;
                        }
                    },
                }
            }
        })
    }

    /// Binds the link's port again (see [`Link::serve`]), retrying while it cannot; `None` once
    /// netem stops.
    async fn bind_again(&self, shutdown: &mut watch::Receiver<bool>) -> Option<TcpListener> {
        loop {
            match TcpListener::bind(self.listen()).await {
                Ok(l) => {
                    if let Ok(addr) = l.local_addr() {
                        self.bound(addr);
                    }
                    return Some(l);
                }
                Err(e) => tracing::warn!(link = %self.name, "cannot listen again: {e}"),
            }
            tokio::select! {
                () = stopped(shutdown) => return None,
                () = tokio::time::sleep(REBIND_RETRY) => {}
            }
        }
    }

    fn admit(self: &Arc<Self>, stream: TcpStream, peer: SocketAddr) {
        let mut conns = lock(&self.conns);
        if conns.len() >= MAX_CONNECTIONS {
            self.refused_total.fetch_add(1, Relaxed);
            tracing::debug!(link = %self.name, %peer, "refusing connection: too many");
            reset(&stream);
            return;
        }
        let id = self.next_conn.fetch_add(1, Relaxed);
        let (kill_tx, kill_rx) = watch::channel(None);
        conns.insert(
            id,
            ConnEntry {
                kill: kill_tx,
                abort: None,
            },
        );
        self.connects_total.fetch_add(1, Relaxed);
        let link = Arc::clone(self);
        let task = tokio::spawn(async move {
            let _guard = ConnGuard {
                link: Arc::clone(&link),
                id,
            };
            link.run_connection(stream, id, kill_rx).await;
        });
        if let Some(e) = conns.get_mut(&id) {
            e.abort = Some(task.abort_handle());
        }
    }

    /// Holds a connection while the link is down (see the module's doc), and at least until
    /// `until`: keeps what the robot sends meanwhile in `held`; false if the robot closed the
    /// connection or it was killed.
    async fn hold(
        &self,
        client: &mut TcpStream,
        kill: &mut watch::Receiver<Option<Kill>>,
        held: &mut Vec<u8>,
        until: tokio::time::Instant,
    ) -> bool {
        use tokio::io::AsyncReadExt;
        let mut up = self.up.subscribe();
        let mut stopping = self.shutdown.clone();
        let mut buf = [0u8; 512];
        loop {
            let waited = tokio::time::Instant::now() >= until;
            if waited && *up.borrow_and_update() {
                return true;
            }
            let room = HELD_BYTES.saturating_sub(held.len()).min(buf.len());
            tokio::select! {
                changed = up.changed() => if changed.is_err() { return false },
                () = tokio::time::sleep_until(until), if !waited => {}
                _ = killed(kill) => return false,
                () = stopped(&mut stopping) => return false,
                read = client.read(&mut buf[..room]), if room > 0 => match read {
                    Ok(0) | Err(_) => return false,
                    Ok(k) => held.extend_from_slice(&buf[..k]),
                },
            }
        }
    }

    /// Connects to robot b's listener once the link is up, holding the robot's connection
    /// meanwhile ([`Link::hold`]). A peer that does not listen — a robot being started again —
    /// is tried again after 20 ms, then twice as long each time up to [`TARGET_RETRY_MAX`],
    /// the robot's connection held all the while (resetting it made every peer of a restarted
    /// robot retry every 20 ms: millions of connections at 128 robots). `None`: the robot
    /// closed its connection, it was killed, or the peer could not be reached otherwise.
    async fn reach_target(
        &self,
        client: &mut TcpStream,
        kill: &mut watch::Receiver<Option<Kill>>,
        held: &mut Vec<u8>,
    ) -> Option<TcpStream> {
        let target = self.params.target;
        let mut retry = TARGET_RETRY_MIN;
        let mut until = tokio::time::Instant::now();
        loop {
            if !self.hold(client, kill, held, until).await {
                return None;
            }
            tokio::select! {
                r = tokio::time::timeout(self.params.connect_timeout, TcpStream::connect(target)) => match r {
                    Ok(Ok(s)) => return Some(s),
                    Ok(Err(e)) if e.kind() == std::io::ErrorKind::ConnectionRefused => {
                        tracing::debug!(link = %self.name, %target, "the target does not listen (yet)");
                    }
                    Ok(Err(e)) => {
                        tracing::debug!(link = %self.name, %target, "cannot reach the target: {e}");
                        return None;
                    }
                    Err(_) => {
                        tracing::debug!(link = %self.name, %target, "timed out connecting to the target");
                        return None;
                    }
                },
                _ = killed(kill) => return None,
            }
            until = tokio::time::Instant::now() + retry;
            retry = (retry * 2).min(TARGET_RETRY_MAX);
        }
    }

    /// One accepted connection: reaches robot b, then forwards and supervises both directions.
    async fn run_connection(
        self: &Arc<Self>,
        mut client: TcpStream,
        id: u64,
        mut kill: watch::Receiver<Option<Kill>>,
    ) {
        let mut held = Vec::new();
        let Some(server) = self.reach_target(&mut client, &mut kill, &mut held).await else {
            reset(&client);
            return;
        };
        self.established_total.fetch_add(1, Relaxed);
        let _through = Through::new(&self.through);
        let _ = client.set_nodelay(true);
        let _ = server.set_nodelay(true);
        let mut toxics_rx = self.toxics.subscribe();
        let toxics = Arc::clone(&toxics_rx.borrow_and_update());
        let shapes = Dir::BOTH.map(|d| watch::Sender::new(self.shape(&toxics, id, d)));
        let (dir_kill, dir_kill_rx) = watch::channel(None);
        let kills = [kill.clone(), dir_kill_rx];
        let [mut up, mut down] = self.spawn_directions(client, server, held, id, &shapes, kills);
        let mut timers = Timers::default();
        timers.update(&toxics, id, self.clock.now());
        let (mut up_done, mut down_done) = (false, false);
        while !(up_done && down_done) {
            let next = timers.next();
            tokio::select! {
                end = &mut up, if !up_done => {
                    up_done = true;
                    on_direction_end(&self.name, Dir::AtoB, end, &dir_kill);
                }
                end = &mut down, if !down_done => {
                    down_done = true;
                    on_direction_end(&self.name, Dir::BtoA, end, &dir_kill);
                }
                k = killed(&mut kill) => {
                    dir_kill.send_replace(Some(k));
                    // The running direction tasks now end at once. (A finished JoinHandle must
                    // not be polled again.)
                    if !up_done {
                        let _ = (&mut up).await;
                    }
                    if !down_done {
                        let _ = (&mut down).await;
                    }
                    break;
                }
                changed = toxics_rx.changed() => {
                    if changed.is_err() {
                        break;
                    }
                    let toxics = Arc::clone(&toxics_rx.borrow_and_update());
                    for d in Dir::BOTH {
                        shapes[d.index()].send_replace(self.shape(&toxics, id, d));
                    }
                    timers.update(&toxics, id, self.clock.now());
                }
                () = sleep_until_opt(&self.clock, next.map(|(t, _)| t)) => {
                    if let Some((_, k)) = next {
                        tracing::debug!(link = %self.name, conn = id, "toxic timer fired: {k:?}");
                        dir_kill.send_replace(Some(k));
                        timers.clear();
                    }
                }
            }
        }
    }

    /// Spawns connection `id`'s two directions: a→b (the `held` bytes first) and b→a.
    fn spawn_directions(
        &self,
        client: TcpStream,
        server: TcpStream,
        held: Vec<u8>,
        id: u64,
        shapes: &[watch::Sender<DirShape>; 2],
        kills: [watch::Receiver<Option<Kill>>; 2],
    ) -> [JoinHandle<Option<PipeEnd>>; 2] {
        let (client_r, client_w) = client.into_split();
        // What the robot sent while the link was down goes first.
        let client_r = tokio::io::AsyncReadExt::chain(std::io::Cursor::new(held), client_r);
        let (server_r, server_w) = server.into_split();
        let seed = self.params.seed ^ id.wrapping_mul(0xA076_1D64_78BD_642F);
        let up = tokio::spawn(direction(
            client_r,
            server_w,
            Buffer::new(self.params.buffer_bytes, Arc::clone(&self.counters[0])),
            shapes[0].subscribe(),
            self.clock.clone(),
            seed,
            kills.clone(),
        ));
        let down = tokio::spawn(direction(
            server_r,
            client_w,
            Buffer::new(self.params.buffer_bytes, Arc::clone(&self.counters[1])),
            shapes[1].subscribe(),
            self.clock.clone(),
            seed.rotate_left(17),
            kills,
        ));
        [up, down]
    }

    fn shape(&self, toxics: &[ActiveToxic], conn: u64, dir: Dir) -> DirShape {
        Link::shape_with(&self.params, toxics, conn, dir)
    }

    /// The shape of direction `dir` of connection `conn` of a link with `params`.
    fn shape_with(params: &LinkParams, toxics: &[ActiveToxic], conn: u64, dir: Dir) -> DirShape {
        let mut s = faults::fold(&params.base[dir.index()], toxics, conn, dir);
        if params.markers {
            s.latency_ns = 0;
            s.jitter_ns = 0;
            // Time stands still within a step: spaced slices would each wait for a step, and
            // the receiver, which waits for the whole frame, for ever. The cutting stays.
            if let Some(sl) = s.slicer.as_mut() {
                sl.delay_ns = 0;
            }
        }
        s
    }

    /// A step opens: each direction's [`Credit`] loses the `bytes` it carried in the step that
    /// ended and gains the new step's refill at its rate as the step's plan announces it (none
    /// if unlimited).
    pub fn open_credit(&self, bytes: [u64; 2], step_seconds: f64) {
        let toxics = self.toxics();
        let mut credit = lock(&self.credit);
        for d in Dir::BOTH {
            let shape = faults::planned(&self.params.base[d.index()], &toxics, d);
            let budget = shape
                .budgets
                .iter()
                .filter(|b| !b.is_shared())
                .min_by_key(|b| b.rate_bytes_per_s());
            let i = d.index();
            credit[i] = budget.map(|b| {
                let (rate, burst) = (b.rate_bytes_per_s(), b.burst_bytes());
                Credit::open(credit[i], rate, burst, bytes[i], step_seconds)
            });
        }
    }

    /// The step's airtime shares and lost frames, per direction.
    pub fn set_air(&self, air: [AirPlan; 2]) {
        *lock(&self.air) = air;
    }

    /// The link as a step's plan announces it (steps of `step_ns`), if it is up: per direction
    /// its own rate (a shared medium aside) and its latency with the jitter at the most,
    /// rounded up to whole steps, one more if its frame of the step is lost; its credit, within
    /// its airtime share on a shared channel; held if either direction is stalled. Every toxic
    /// counts, whatever its toxicity.
    pub fn planned(&self, step_ns: u64) -> Option<PlannedLink> {
        if !self.is_up() {
            return None;
        }
        let toxics = self.toxics();
        let shapes = Dir::BOTH.map(|d| faults::planned(&self.params.base[d.index()], &toxics, d));
        let rate = |s: &DirShape| {
            s.budgets
                .iter()
                .filter(|b| !b.is_shared())
                .map(|b| b.rate_bytes_per_s())
                .min()
        };
        let delay = |s: &DirShape| {
            let ns = s.latency_ns.saturating_add(s.jitter_ns);
            u32::try_from(ns.div_ceil(step_ns.max(1))).unwrap_or(u32::MAX)
        };
        let air = *lock(&self.air);
        let credit = lock(&self.credit).map(|c| c.map(|c| c.level.floor() as u32));
        let credit = [0, 1].map(|i| match (credit[i], air[i].credit) {
            (Some(c), Some(s)) => Some(c.min(s)),
            (c, s) => c.or(s),
        });
        Some(PlannedLink {
            a: self.params.a,
            b: self.params.b,
            rate: [rate(&shapes[0]), rate(&shapes[1])],
            delay: [0, 1].map(|i| delay(&shapes[i]).saturating_add(u32::from(air[i].lost))),
            held: shapes.iter().any(|s| s.stalled),
            credit,
            proxy: Some(self.listen()).filter(|l| self.while_up && l.port() != 0),
        })
    }
}

/// Accepts on `listener`, or never (no listener).
async fn accept(listener: Option<&TcpListener>) -> std::io::Result<(TcpStream, SocketAddr)> {
    match listener {
        Some(l) => l.accept().await,
        None => std::future::pending().await,
    }
}

/// The first and the longest wait before netem tries again to reach a peer that does not
/// listen ([`Link::reach_target`]).
const TARGET_RETRY_MIN: Duration = Duration::from_millis(20);
const TARGET_RETRY_MAX: Duration = Duration::from_millis(500);

/// How long netem waits before it tries again to bind a link's port that is taken.
const REBIND_RETRY: Duration = Duration::from_millis(100);

/// Counts a connection that reached robot b in its link's `through` for as long as it lives.
struct Through<'a>(&'a watch::Sender<usize>);

impl<'a> Through<'a> {
    fn new(count: &'a watch::Sender<usize>) -> Through<'a> {
        count.send_modify(|n| *n += 1);
        Through(count)
    }
}

impl Drop for Through<'_> {
    fn drop(&mut self) {
        self.0.send_modify(|n| *n = n.saturating_sub(1));
    }
}

/// Removes a connection from its link's table however its task ends.
struct ConnGuard {
    link: Arc<Link>,
    id: u64,
}

impl Drop for ConnGuard {
    fn drop(&mut self) {
        lock(&self.link.conns).remove(&self.id);
    }
}

/// Closes a socket with RST (SO_LINGER 0) instead of FIN.
fn reset(s: &TcpStream) {
    let _ = s.set_zero_linger();
}

fn on_direction_end(
    link: &str,
    dir: Dir,
    end: Result<Option<PipeEnd>, tokio::task::JoinError>,
    kill: &watch::Sender<Option<Kill>>,
) {
    match end {
        // The sender closed its side; its FIN was passed on. The other direction goes on
        // (TCP half-close) until its own sender closes.
        Ok(Some(PipeEnd::Eof)) | Ok(None) => {}
        Ok(Some(PipeEnd::LimitReached)) => {
            tracing::debug!(link, dir = dir.label(), "limit_data reached: closing");
            kill.send_replace(Some(Kill::Close));
        }
        Ok(Some(e)) => {
            tracing::debug!(link, dir = dir.label(), "connection failed: {e:?}");
            kill.send_replace(Some(Kill::Reset));
        }
        Err(e) => {
            tracing::warn!(
                link,
                dir = dir.label(),
                "direction task ended abnormally: {e}"
            );
            kill.send_replace(Some(Kill::Reset));
        }
    }
}

/// One direction of a connection: the pipeline from `reader` to `writer`, until it ends or a
/// kill arrives (`None` then). On `Kill::Reset` the writer's socket is closed with RST.
///
/// `[link, conn]` are the two kill signals: the link's (set synchronously when the link goes down;
/// it also gates every write, see [`shaping::sink`](crate::shaping::pipeline::sink)) and the
/// connection's own (toxic timers, the other direction's end).
async fn direction(
    reader: impl tokio::io::AsyncRead + Unpin,
    mut writer: OwnedWriteHalf,
    buffer: Arc<Buffer>,
    shape: watch::Receiver<DirShape>,
    clock: SimClock,
    seed: u64,
    [mut link, mut conn]: [watch::Receiver<Option<Kill>>; 2],
) -> Option<PipeEnd> {
    let killed = {
        let pipe = pipeline::pipeline(
            reader,
            &mut writer,
            buffer,
            shape,
            clock,
            seed,
            Some(link.clone()),
        );
        tokio::pin!(pipe);
        tokio::select! {
            biased;
            k = killed(&mut link) => k,
            k = killed(&mut conn) => k,
            end = &mut pipe => return Some(end),
        }
    };
    match killed {
        Kill::Reset => {
            let _ = writer.as_ref().set_zero_linger();
            // Do not send a FIN on the way out: the socket closes with RST once both halves go.
            writer.forget();
        }
        Kill::Close => {
            use tokio::io::AsyncWriteExt;
            let _ = writer.shutdown().await;
        }
    }
    None
}

/// The pending toxic timers of one connection: toxic id → (due time, action).
#[derive(Default)]
struct Timers(HashMap<u64, (SimTime, Kill)>);

impl Timers {
    /// Keeps the timers of toxics that still exist (their start time does not move), adds new ones.
    fn update(&mut self, toxics: &[ActiveToxic], conn: u64, now: SimTime) {
        let wanted = faults::timers(toxics, conn);
        self.0
            .retain(|id, _| wanted.iter().any(|(w, _, _)| w == id));
        for (id, kill, delay_ns) in wanted {
            self.0
                .entry(id)
                .or_insert((now.saturating_add_ns(delay_ns), kill));
        }
    }

    fn next(&self) -> Option<(SimTime, Kill)> {
        self.0.values().min_by_key(|(t, _)| *t).copied()
    }

    fn clear(&mut self) {
        self.0.clear();
    }
}

/// Completes with the kill signal (a gone sender counts as a reset). Copies the value out so that
/// no watch borrow lives across an await.
async fn killed(rx: &mut watch::Receiver<Option<Kill>>) -> Kill {
    let k = match rx.wait_for(Option::is_some).await {
        Ok(k) => *k,
        Err(_) => None,
    };
    k.unwrap_or(Kill::Reset)
}

/// Completes once `rx` reads true or its sender is gone.
pub(crate) async fn stopped(rx: &mut watch::Receiver<bool>) {
    let _ = rx.wait_for(|s| *s).await.map(|_| ());
}

async fn sleep_until_opt(clock: &SimClock, t: Option<SimTime>) {
    match t {
        Some(t) => clock.sleep_until(t).await,
        None => std::future::pending().await,
    }
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use crate::shaping::Budget;
    use tokio::io::{AsyncReadExt, AsyncWriteExt};

    #[test]
    fn a_credit_refills_a_step_at_a_time_loses_what_was_carried_and_stays_in_its_burst() {
        let c = Credit::open(None, 65, 780, 0, 1.0);
        assert_eq!(c.level, 780.0);
        // 68 bytes a step on a 65 B/s link: 3 bytes a step less.
        let mut c = c;
        for _ in 0..10 {
            c = Credit::open(Some(c), 65, 780, 68, 1.0);
        }
        assert_eq!(c.level, 750.0);
        // Never below nothing, never above the burst.
        let c = Credit::open(Some(c), 65, 780, 10_000, 1.0);
        assert_eq!(c.level, 0.0);
        let c = Credit::open(Some(c), 65, 780, 0, 100.0);
        assert_eq!(c.level, 780.0);
        // A new rate keeps what there was, within the new burst.
        let c = Credit::open(Some(c), 10, 120, 0, 1.0);
        assert_eq!(c.level, 120.0);
    }

    /// A target server that echoes nothing and records what it receives; returns its address and
    /// a channel of accepted streams.
    async fn target() -> (SocketAddr, tokio::sync::mpsc::Receiver<TcpStream>) {
        let l = TcpListener::bind("127.0.0.1:0").await.unwrap();
        let addr = l.local_addr().unwrap();
        let (tx, rx) = tokio::sync::mpsc::channel(8);
        tokio::spawn(async move {
            while let Ok((s, _)) = l.accept().await {
                if tx.send(s).await.is_err() {
                    break;
                }
            }
        });
        (addr, rx)
    }

    async fn link_with(
        base: [BaseShape; 2],
        clock: SimClock,
        buffer_bytes: usize,
    ) -> (
        Arc<Link>,
        tokio::sync::mpsc::Receiver<TcpStream>,
        watch::Sender<bool>,
    ) {
        let (target, accepted) = target().await;
        let (link, stop_tx) = link_to(target, base, clock, buffer_bytes).await;
        (link, accepted, stop_tx)
    }

    /// A link of robots 0 and 1, always in range, forwarding to `target`; serving until the
    /// sender is dropped or sends true.
    async fn link_to(
        target: SocketAddr,
        base: [BaseShape; 2],
        clock: SimClock,
        buffer_bytes: usize,
    ) -> (Arc<Link>, watch::Sender<bool>) {
        let listener = TcpListener::bind("127.0.0.1:0").await.unwrap();
        let params = LinkParams {
            a: 0,
            b: 1,
            target,
            base,
            buffer_bytes,
            connect_timeout: Duration::from_secs(2),
            seed: 1,
            markers: false,
        };
        let state = LinkState {
            enabled: true,
            alive: true,
            radio: None,
            always: true,
        };
        let (stop_tx, stop_rx) = watch::channel(false);
        let link = Link::new(
            params,
            listener.local_addr().unwrap(),
            clock,
            state,
            stop_rx,
        );
        link.serve(Some(listener));
        (link, stop_tx)
    }

    async fn connect(
        link: &Link,
        accepted: &mut tokio::sync::mpsc::Receiver<TcpStream>,
    ) -> (TcpStream, TcpStream) {
        let a = TcpStream::connect(link.listen()).await.unwrap();
        let b = tokio::time::timeout(Duration::from_secs(2), accepted.recv())
            .await
            .unwrap()
            .unwrap();
        (a, b)
    }

    async fn read_exact_timeout(s: &mut TcpStream, n: usize) -> Vec<u8> {
        let mut buf = vec![0u8; n];
        tokio::time::timeout(Duration::from_secs(2), s.read_exact(&mut buf))
            .await
            .expect("in time")
            .expect("read");
        buf
    }

    /// Reads until EOF or error; true if the stream ended (EOF or reset) within `wait`.
    pub(crate) async fn ends_within(s: &mut TcpStream, wait: Duration) -> bool {
        let mut buf = [0u8; 4096];
        let deadline = tokio::time::Instant::now() + wait;
        loop {
            match tokio::time::timeout_at(deadline, s.read(&mut buf)).await {
                Ok(Ok(0)) | Ok(Err(_)) => return true,
                Ok(Ok(_)) => continue,
                Err(_) => return false,
            }
        }
    }

    #[tokio::test]
    async fn forwards_both_ways_and_counts_bytes_and_chunks_per_direction() {
        let (link, mut acc, _stop) =
            link_with(Default::default(), SimClock::lockstep(), 4096).await;
        let (mut a, mut b) = connect(&link, &mut acc).await;
        a.write_all(b"hello from a").await.unwrap();
        assert_eq!(read_exact_timeout(&mut b, 12).await, b"hello from a");
        b.write_all(b"hi").await.unwrap();
        assert_eq!(read_exact_timeout(&mut a, 2).await, b"hi");
        let s = link.snapshot();
        assert_eq!(s.dirs[0].bytes_total, 12);
        assert_eq!(s.dirs[1].bytes_total, 2);
        assert!(s.dirs[0].chunks_total >= 1);
        assert_eq!(s.connections, 1);
        assert_eq!(link.counters(Dir::AtoB).take_step(), 12);
        assert_eq!(link.counters(Dir::AtoB).take_step(), 0);
        // Half-close passes through: a's FIN reaches b, b can still answer.
        a.shutdown().await.unwrap();
        let mut buf = [0u8; 1];
        assert_eq!(b.read(&mut buf).await.unwrap(), 0);
        b.write_all(b"bye").await.unwrap();
        assert_eq!(read_exact_timeout(&mut a, 3).await, b"bye");
    }

    #[tokio::test]
    async fn a_link_that_listens_while_up_binds_before_its_plan_and_closes_when_down() {
        let (target, mut accepted) = target().await;
        let params = LinkParams {
            a: 0,
            b: 1,
            target,
            base: Default::default(),
            buffer_bytes: 4096,
            connect_timeout: Duration::from_secs(2),
            seed: 1,
            markers: true,
        };
        let out_of_range = LinkState {
            enabled: true,
            alive: true,
            radio: None,
            always: false,
        };
        let (_stop, stop_rx) = watch::channel(false);
        let host = std::net::Ipv4Addr::LOCALHOST.into();
        let link = Link::while_up(params, host, SimClock::lockstep(), out_of_range, stop_rx);
        link.serve(None);
        assert_eq!(link.listen().port(), 0, "down from the start: no port");
        assert!(link.planned(1).is_none());
        let in_range = |up: bool| {
            move |st: &mut LinkState| {
                st.radio = Some(Verdict {
                    in_range: up,
                    distance_m: 1.0,
                    walls: None,
                    signal_dbm: None,
                    margin_db: None,
                })
            }
        };
        for round in 0..2 {
            assert!(link.update(in_range(true)));
            // The port is bound the moment the link comes up: the plan made next gives it.
            let proxy = link
                .planned(1)
                .and_then(|p| p.proxy)
                .expect("a proxy in the plan");
            assert_eq!(proxy, link.listen());
            let mut a = TcpStream::connect(proxy).await.unwrap();
            let mut b = tokio::time::timeout(Duration::from_secs(2), accepted.recv())
                .await
                .expect("forwarded to b")
                .unwrap();
            a.write_all(b"hi").await.unwrap();
            assert_eq!(read_exact_timeout(&mut b, 2).await, b"hi", "round {round}");
            // Down: the connection is reset and nobody listens on the port any more.
            assert!(!link.update(in_range(false)));
            assert!(link.planned(1).is_none());
            let mut buf = [0u8; 8];
            let ended = tokio::time::timeout(Duration::from_secs(2), b.read(&mut buf)).await;
            assert!(
                matches!(ended, Ok(Ok(0) | Err(_))),
                "b's connection ends: {ended:?}"
            );
            let refused = async {
                loop {
                    if TcpStream::connect(proxy).await.is_err() {
                        break;
                    }
                    tokio::time::sleep(Duration::from_millis(5)).await;
                }
            };
            tokio::time::timeout(Duration::from_secs(2), refused)
                .await
                .expect("the port is closed while the link is down");
        }
        assert!(!link.ports().is_empty());
    }

    #[tokio::test]
    async fn a_peer_that_listens_late_gets_the_held_connection() {
        // Robot b's port, free for now (a robot being started again).
        let port = TcpListener::bind("127.0.0.1:0").await.unwrap();
        let target = port.local_addr().unwrap();
        drop(port);
        let (link, _stop) = link_to(target, Default::default(), SimClock::lockstep(), 4096).await;
        let mut a = TcpStream::connect(link.listen()).await.unwrap();
        a.write_all(b"hel").await.unwrap();
        tokio::time::sleep(Duration::from_millis(150)).await;
        assert_eq!(link.snapshot().established_total, 0);
        // b listens: the held connection goes through, what a sent first.
        let b_listener = TcpListener::bind(target).await.unwrap();
        let (mut b, _) = tokio::time::timeout(Duration::from_secs(2), b_listener.accept())
            .await
            .expect("reached once b listens")
            .unwrap();
        a.write_all(b"lo").await.unwrap();
        assert_eq!(read_exact_timeout(&mut b, 5).await, b"hello");
        assert_eq!(link.snapshot().connects_total, 1, "one connection, held");
    }

    #[tokio::test]
    async fn cut_resets_both_sides_holds_reconnects_and_restore_lets_them_through() {
        let (link, mut acc, _stop) =
            link_with(Default::default(), SimClock::lockstep(), 4096).await;
        let (mut a, mut b) = connect(&link, &mut acc).await;
        a.write_all(b"x").await.unwrap();
        read_exact_timeout(&mut b, 1).await;
        assert!(!link.update(|s| s.enabled = false));
        assert!(
            ends_within(&mut a, Duration::from_secs(2)).await,
            "a sees the cut"
        );
        assert!(
            ends_within(&mut b, Duration::from_secs(2)).await,
            "b sees the cut"
        );
        // While down: accepted and held, never forwarded, nothing counted.
        let mut a = TcpStream::connect(link.listen()).await.unwrap();
        a.write_all(b"ba").await.unwrap();
        assert!(tokio::time::timeout(Duration::from_millis(50), acc.recv())
            .await
            .is_err());
        assert_eq!(link.snapshot().refused_total, 0);
        assert_eq!(link.snapshot().dirs[0].bytes_total, 1);
        assert_eq!(link.snapshot().down_reason, Some(DownReason::Disabled));
        // Restored: the held connection reaches b, what a sent meanwhile first.
        assert!(link.update(|s| s.enabled = true));
        let mut b = tokio::time::timeout(Duration::from_secs(2), acc.recv())
            .await
            .expect("forwarded once restored")
            .unwrap();
        a.write_all(b"ck").await.unwrap();
        assert_eq!(read_exact_timeout(&mut b, 4).await, b"back");
    }

    #[tokio::test]
    async fn timeout_toxic_stalls_then_closes_and_latency_toxic_delays_by_simulated_time() {
        let clock = SimClock::lockstep();
        let (link, mut acc, _stop) = link_with(Default::default(), clock.clone(), 4096).await;
        let (mut a, mut b) = connect(&link, &mut acc).await;
        link.set_toxics(vec![ActiveToxic {
            toxic: Toxic::both(faults::ToxicKind::Latency {
                latency_ms: 1500,
                jitter_ms: 0,
            }),
            id: 1,
            budgets: [None, None],
        }]);
        tokio::time::sleep(Duration::from_millis(20)).await;
        a.write_all(b"slow").await.unwrap();
        // Let netem read the bytes at time 0 (due at 1.5 s).
        tokio::time::sleep(Duration::from_millis(20)).await;
        let mut buf = [0u8; 4];
        clock.advance_to(SimTime::from_secs_f64(1.0));
        assert!(
            tokio::time::timeout(Duration::from_millis(50), b.read_exact(&mut buf))
                .await
                .is_err()
        );
        clock.advance_to(SimTime::from_secs_f64(2.0));
        assert_eq!(read_exact_timeout(&mut b, 4).await, b"slow");

        link.set_toxics(vec![ActiveToxic {
            toxic: Toxic::both(faults::ToxicKind::Timeout { timeout_ms: 3000 }),
            id: 2,
            budgets: [None, None],
        }]);
        tokio::time::sleep(Duration::from_millis(20)).await;
        b.write_all(b"zzz").await.unwrap();
        tokio::time::sleep(Duration::from_millis(20)).await;
        clock.advance_to(SimTime::from_secs_f64(4.0));
        assert!(
            !ends_within(&mut a, Duration::from_millis(50)).await,
            "stalled, not closed"
        );
        clock.advance_to(SimTime::from_secs_f64(5.5));
        assert!(
            ends_within(&mut a, Duration::from_secs(2)).await,
            "closed after the timeout"
        );
        assert!(ends_within(&mut b, Duration::from_secs(2)).await);
        assert!(
            link.snapshot().dirs[1].lost_bytes_total >= 3,
            "the stalled bytes are lost"
        );
    }

    /// Through a real link: a slicer cuts a write into many on the receiving socket, and a
    /// slow_close passes the sender's FIN on only when the simulated clock reaches its delay;
    /// with step markers the slicer's delay is dropped.
    #[tokio::test]
    async fn slicer_cuts_writes_and_slow_close_delays_the_fin_by_simulated_time() {
        let clock = SimClock::lockstep();
        let (link, mut acc, _stop) = link_with(Default::default(), clock.clone(), 8192).await;
        let (mut a, mut b) = connect(&link, &mut acc).await;
        let toxic = |kind, stream, id| ActiveToxic {
            toxic: Toxic {
                name: format!("t{id}"),
                kind,
                stream,
                toxicity: 1.0,
            },
            id,
            budgets: [None, None],
        };
        link.set_toxics(vec![
            toxic(
                faults::ToxicKind::Slicer {
                    average_size: 10,
                    size_variation: 0,
                    delay_us: 0,
                },
                faults::Stream::Upstream,
                1,
            ),
            toxic(
                faults::ToxicKind::SlowClose { delay_ms: 2000 },
                faults::Stream::Upstream,
                2,
            ),
        ]);
        tokio::time::sleep(Duration::from_millis(20)).await;
        a.write_all(&[9u8; 1000]).await.unwrap();
        assert_eq!(read_exact_timeout(&mut b, 1000).await, vec![9u8; 1000]);
        let d = link.snapshot().dirs[0];
        assert_eq!(d.bytes_total, 1000);
        assert!(
            d.chunks_total >= 100,
            "{} writes, of 10 bytes at most",
            d.chunks_total
        );
        a.shutdown().await.unwrap();
        // Let netem see the FIN at time 0 (passed on at 2 s).
        tokio::time::sleep(Duration::from_millis(20)).await;
        clock.advance_to(SimTime::from_secs_f64(1.0));
        assert!(
            !ends_within(&mut b, Duration::from_millis(100)).await,
            "the FIN waits for the clock"
        );
        clock.advance_to(SimTime::from_secs_f64(2.0));
        assert!(
            ends_within(&mut b, Duration::from_secs(2)).await,
            "then it passes"
        );
        // The other direction is untouched: b still reaches a, unsliced.
        b.write_all(&[7u8; 500]).await.unwrap();
        assert_eq!(read_exact_timeout(&mut a, 500).await, vec![7u8; 500]);
        assert!(link.snapshot().dirs[1].chunks_total <= 2);

        // With markers a slicer's delay is dropped: a second's delay would hold every slice.
        let mut markers = link.params.clone();
        markers.markers = true;
        let spaced = [toxic(
            faults::ToxicKind::Slicer {
                average_size: 10,
                size_variation: 0,
                delay_us: 1_000_000,
            },
            faults::Stream::Both,
            3,
        )];
        let plain = faults::fold(&markers.base[0], &spaced, 0, Dir::AtoB);
        assert_eq!(plain.slicer.map(|s| s.delay_ns), Some(1_000_000_000));
        assert_eq!(
            Link::shape_with(&markers, &spaced, 0, Dir::AtoB)
                .slicer
                .map(|s| (s.average_size, s.delay_ns)),
            Some((10, 0))
        );
    }

    /// Regression: a cut while one direction had already finished (half-close) polled that
    /// direction's JoinHandle a second time and panicked the connection task.
    #[tokio::test]
    async fn cut_after_half_close_ends_the_connection_cleanly() {
        // A panic in a spawned task does not fail the test by itself: watch for one on this
        // test's thread (a current-thread runtime runs every task here).
        let me = std::thread::current().id();
        let panicked = Arc::new(std::sync::atomic::AtomicBool::new(false));
        let flag = Arc::clone(&panicked);
        let previous = std::panic::take_hook();
        std::panic::set_hook(Box::new(move |info| {
            if std::thread::current().id() == me {
                flag.store(true, Relaxed);
            }
            eprintln!("{info}");
        }));
        let (link, mut acc, _stop) =
            link_with(Default::default(), SimClock::lockstep(), 4096).await;
        let (mut a, mut b) = connect(&link, &mut acc).await;
        a.shutdown().await.unwrap();
        let mut buf = [0u8; 1];
        assert_eq!(b.read(&mut buf).await.unwrap(), 0);
        tokio::time::sleep(Duration::from_millis(20)).await;
        link.update(|s| s.enabled = false);
        assert!(ends_within(&mut a, Duration::from_secs(2)).await);
        let deadline = tokio::time::Instant::now() + Duration::from_secs(2);
        while link.snapshot().connections > 0 {
            assert!(
                tokio::time::Instant::now() < deadline,
                "the connection task ended"
            );
            tokio::time::sleep(Duration::from_millis(5)).await;
        }
        drop(b);
        std::panic::set_hook(previous);
        assert!(!panicked.load(Relaxed), "a connection task panicked");
    }

    #[tokio::test]
    async fn a_sender_offering_ten_times_the_budget_is_held_back_with_flat_memory() {
        let clock = SimClock::lockstep();
        let rate = 1000;
        let budget = |_| BaseShape {
            budget: Some(Budget::new(rate, 1.0, false, clock.clone())),
            ..BaseShape::default()
        };
        let buffer = 8192;
        let (link, mut acc, _stop) = link_with([0, 1].map(budget), clock.clone(), buffer).await;
        let (mut a, mut b) = connect(&link, &mut acc).await;
        let sent = Arc::new(AtomicU64::new(0));
        let sent2 = Arc::clone(&sent);
        let writer = tokio::spawn(async move {
            let block = vec![0u8; 10 * 1000];
            while a.write_all(&block).await.is_ok() {
                sent2.fetch_add(block.len() as u64, Relaxed);
            }
        });
        let reader = tokio::spawn(async move {
            let mut buf = vec![0u8; 65536];
            let mut n_total = 0u64;
            while let Ok(Ok(n)) =
                tokio::time::timeout(Duration::from_millis(300), b.read(&mut buf)).await
            {
                if n == 0 {
                    break;
                }
                n_total += n as u64;
            }
            n_total
        });
        // Let the sender fill the pipe at time 0, so that step 0's budget is used too.
        tokio::time::sleep(Duration::from_millis(30)).await;
        for step in 1..=60u64 {
            clock.advance_to(SimTime::from_secs_f64(step as f64));
            tokio::time::sleep(Duration::from_millis(3)).await;
            assert!(link.snapshot().dirs[0].queued_bytes <= buffer as u64);
        }
        let s = link.snapshot();
        assert!(s.dirs[0].queued_max_bytes <= buffer as u64, "{s:?}");
        assert!(s.dirs[0].queued_max_bytes > 0);
        let delivered = s.dirs[0].bytes_total;
        assert_eq!(
            delivered,
            61 * rate,
            "one step's budget per step, steps 0..=60"
        );
        // The sender is stuck: what it managed to write is bounded by the kernel's socket
        // buffers plus ours, not by how long it tries.
        let offered = sent.load(Relaxed);
        assert!(offered < delivered + (16 << 20), "{offered}");
        writer.abort();
        drop(reader);
    }

    #[tokio::test]
    async fn toxic_changes_reach_live_connections() {
        let (link, mut acc, _stop) =
            link_with(Default::default(), SimClock::lockstep(), 4096).await;
        let (mut a, mut b) = connect(&link, &mut acc).await;
        link.set_toxics(vec![ActiveToxic {
            toxic: Toxic {
                name: "bh".into(),
                kind: faults::ToxicKind::Timeout { timeout_ms: 0 },
                stream: faults::Stream::Upstream,
                toxicity: 1.0,
            },
            id: 1,
            budgets: [None, None],
        }]);
        tokio::time::sleep(Duration::from_millis(20)).await;
        a.write_all(b"held").await.unwrap();
        let mut buf = [0u8; 4];
        assert!(
            tokio::time::timeout(Duration::from_millis(100), b.read(&mut buf))
                .await
                .is_err()
        );
        link.set_toxics(vec![]);
        assert_eq!(read_exact_timeout(&mut b, 4).await, b"held");
        // reset_peer after 2 simulated seconds.
        link.set_toxics(vec![ActiveToxic {
            toxic: Toxic::both(faults::ToxicKind::ResetPeer { timeout_ms: 2000 }),
            id: 2,
            budgets: [None, None],
        }]);
        tokio::time::sleep(Duration::from_millis(20)).await;
        link.clock.advance_to(SimTime::from_secs_f64(1.0));
        assert!(!ends_within(&mut a, Duration::from_millis(50)).await);
        link.clock.advance_to(SimTime::from_secs_f64(2.5));
        assert!(ends_within(&mut a, Duration::from_secs(2)).await);
        assert!(ends_within(&mut b, Duration::from_secs(2)).await);
    }
}
