//! The netem instance: configuration, start, the per-step entry point, telemetry, runtime control
//! (applying faults through [`crate::control`]) and shutdown (docs/design.md §5). No zenoh here:
//! the binary reads poses from the sim plane and calls `Netem::on_step`; this library moves bytes.
//!
//! `start` binds every pair's listener (and the HTTP API), so a port conflict is an error at
//! start-up, not a silent dead link later. Each step the embedder calls `Netem::on_step` with
//! the poses: in lockstep that advances the simulated clock to `step × step_seconds`, then the
//! step's scheduled faults are applied and every link's range is re-evaluated. Then
//! `Netem::telemetry` gives the step's per-link counters (links.csv).

use std::collections::HashMap;
use std::net::SocketAddr;
use std::sync::atomic::AtomicU64;
use std::sync::{Arc, Mutex};
use std::time::Duration;

use proto::geom::{MapInfo, Pose};
use proto::grid::Grid;
use proto::msg::{LinkAir, LinkPlan, NodeAir, ProcessOrder, RobotId, Step};
use proto::scenario::{
    Clock, ClockMode, Medium, Netem as ScenarioNetem, Radio as ScenarioRadio, RadioModel,
};
use tokio::net::TcpListener;
use tokio::sync::{mpsc, watch};
use tokio::task::JoinHandle;

use crate::accounting::Dir;
use crate::channel::{Channel, ChannelConfig, OpenLink};
use crate::control::{
    burst_seconds, lock, NetemError, ProcessDesk, Shared, StepState, PROCESS_ORDERS_QUEUED,
};
use crate::faults::{self, BaseShape, Fault, Pair, ScheduledFault};
use crate::link::AirPlan;
use crate::link::{Link, LinkParams, LinkSnapshot, LinkState};
use crate::radio::{Model, PathLoss, Radio};
use crate::shaping::Budget;
use crate::telemetry::{telemetry_row, LinkTelemetry};
use proto::clock::{SimClock, SimTime};

/// One robot pair: robot `a` (the lower id) connects to `listen`; netem forwards to `target`,
/// robot `b`'s radio listener.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct PairSpec {
    pub a: RobotId,
    pub b: RobotId,
    /// Port 0 picks a free port; read it back with [`Netem::listen_addr`].
    pub listen: SocketAddr,
    pub target: SocketAddr,
    /// The proxy listens on a free port of `listen`'s address only while the link is up
    /// ([`Link::while_up`]); robot `a` learns it from each step's plan.
    pub while_up: bool,
}

/// Everything netem needs to run.
#[derive(Clone, Debug)]
pub struct NetemConfig {
    pub pairs: Vec<PairSpec>,
    /// The scenario's `[radio]`: model, range, bandwidth, medium, latency, jitter, path loss.
    pub radio: ScenarioRadio,
    /// The scenario's `[netem]`: buffer size, connect timeout.
    pub netem: ScenarioNetem,
    /// Seed of jitter, corruption and toxicity draws (the scenario's `seed`).
    pub seed: u64,
    /// The scenario's `[clock]`: its mode, seconds per step, speed-up (realtime) and whether
    /// lockstep runs with step markers ([`Clock::marked`]: the robots pace and wait for each
    /// step's traffic, and links let a larger burst through,
    /// [`LOCKSTEP_BURST_STEPS`](crate::control::LOCKSTEP_BURST_STEPS)).
    pub clock: Clock,
    /// The truth map, for path loss wall counts.
    pub truth: Option<(MapInfo, Grid)>,
    pub faults: Vec<ScheduledFault>,
    /// Where to serve the toxiproxy-compatible HTTP API (`None`: no API).
    pub http: Option<SocketAddr>,
    /// The bearer token every API request must carry (`None`: none needed).
    pub api_token: Option<String>,
    /// The largest message the robots' exchange sends whole (one scan's delta): a direction of
    /// a shared channel may save up this much airtime, so that no message waits forever.
    pub largest_message_bytes: u32,
}

impl NetemConfig {
    /// A lockstep configuration with 1 s steps, default `[netem]` knobs, no faults, no HTTP API.
    pub fn new(pairs: Vec<PairSpec>, radio: ScenarioRadio) -> NetemConfig {
        NetemConfig {
            pairs,
            radio,
            netem: ScenarioNetem::default(),
            seed: 1,
            clock: Clock {
                markers: false,
                ..Clock::default()
            },
            truth: None,
            faults: Vec::new(),
            http: None,
            api_token: None,
            largest_message_bytes: largest_message(&proto::scenario::Scenario::default()),
        }
    }

    /// Everything a scenario determines: `[radio]`, `[netem]`, `seed`, the clock and the
    /// `[[faults]]` (parsed here; a bad table is [`NetemError::BadFault`] naming its index).
    pub fn from_scenario(
        s: &proto::scenario::Scenario,
        pairs: Vec<PairSpec>,
        truth: Option<(MapInfo, Grid)>,
        http: Option<SocketAddr>,
    ) -> Result<NetemConfig, NetemError> {
        let faults = faults::parse_faults(&s.faults)
            .map_err(|(index, reason)| NetemError::BadFault { index, reason })?;
        Ok(NetemConfig {
            pairs,
            radio: s.radio.clone(),
            netem: s.netem.clone(),
            seed: s.seed,
            clock: s.clock.clone(),
            truth,
            faults,
            http,
            api_token: None,
            largest_message_bytes: largest_message(s),
        })
    }
}

/// The largest message the exchange of scenario `s` sends whole: one scan's delta.
fn largest_message(s: &proto::scenario::Scenario) -> u32 {
    u32::try_from(proto::msg::largest_scan_delta_bytes(s.sensor.beams)).unwrap_or(u32::MAX)
}

/// A running netem.
pub struct Netem {
    shared: Arc<Shared>,
    tasks: Vec<JoinHandle<()>>,
    http_addr: Option<SocketAddr>,
}

fn validate(cfg: &NetemConfig) -> Result<(), NetemError> {
    let bad = |m: String| Err(NetemError::Config(m));
    let scenario = |e: proto::scenario::ScenarioError| NetemError::Config(e.to_string());
    cfg.clock.validate().map_err(scenario)?;
    cfg.radio.validate().map_err(scenario)?;
    cfg.netem.validate().map_err(scenario)?;
    if !cfg.clock.marked() && (cfg.radio.medium == Medium::Airtime || cfg.radio.lossy()) {
        return bad(
            "radio.medium = \"airtime\", radio.frame_loss and radio.fading_db act through the step \
             plan: they need lockstep with markers"
                .into(),
        );
    }
    let mut seen = HashMap::new();
    for p in &cfg.pairs {
        if p.a >= p.b {
            return bad(format!("pair ({}, {}): a must be lower than b", p.a, p.b));
        }
        if seen.insert((p.a, p.b), ()).is_some() {
            return bad(format!("pair ({}, {}) given twice", p.a, p.b));
        }
    }
    for (index, f) in cfg.faults.iter().enumerate() {
        let known = |p: &Pair| seen.contains_key(&(p.0.min(p.1), p.0.max(p.1)));
        let robot = |r: &RobotId| cfg.pairs.iter().any(|p| p.a == *r || p.b == *r);
        let problem = match &f.fault {
            Fault::Cut { pair } | Fault::Restore { pair } if !known(pair) => {
                Some(format!("no link {}", faults::link_name(pair.0, pair.1)))
            }
            Fault::Reset { pair: Some(pair) }
            | Fault::AddToxic {
                pair: Some(pair), ..
            }
            | Fault::SetToxic {
                pair: Some(pair), ..
            }
            | Fault::RemoveToxic {
                pair: Some(pair), ..
            } if !known(pair) => Some(format!("no link {}", faults::link_name(pair.0, pair.1))),
            Fault::Partition { groups } => groups
                .iter()
                .flatten()
                .find(|r| !robot(r))
                .map(|r| format!("robot {r} is in no link")),
            _ => None,
        };
        if let Some(reason) = problem {
            return Err(NetemError::BadFault { index, reason });
        }
    }
    Ok(())
}

fn radio_model(cfg: &NetemConfig) -> Model {
    match cfg.radio.model {
        RadioModel::Always => Model::Always,
        RadioModel::Disk => Model::Disk {
            range_m: cfg.radio.range_m,
        },
        // `of` gives the model for exactly this variant.
        RadioModel::Pathloss => PathLoss::of(&cfg.radio).map_or(Model::Always, Model::PathLoss),
    }
}

/// Link (a, b)'s use of the channel from the directions of a step that closed.
fn link_air(
    air: &std::collections::BTreeMap<crate::channel::Dir, crate::channel::DirAir>,
    a: RobotId,
    b: RobotId,
) -> Option<LinkAir> {
    let ab = air.get(&(a, b));
    let ba = air.get(&(b, a));
    if ab.is_none() && ba.is_none() {
        return None;
    }
    let d = |x: Option<&crate::channel::DirAir>| x.copied().unwrap_or_default();
    let (ab, ba) = (d(ab), d(ba));
    Some(LinkAir {
        share: [ab.share, ba.share],
        airtime: [ab.airtime, ba.airtime],
        lost: [ab.lost, ba.lost],
        delivery: [ab.delivery as f32, ba.delivery as f32],
    })
}

/// The radio channel the scenario gives: airtime shared (`shared`, `airtime`) or not, lossy or not.
fn channel_config(cfg: &NetemConfig) -> ChannelConfig {
    ChannelConfig {
        capacity: cfg.radio.channel_capacity(&cfg.clock),
        everyone_hears: cfg.radio.medium == Medium::Shared,
        frame_loss: cfg.radio.frame_loss,
        fading_db: cfg.radio.fading_db,
        seed: cfg.seed,
        save_min_bytes: f64::from(cfg.largest_message_bytes),
    }
}

/// A pair whose link is down has a row in a step's report while its nodes are within this many
/// radio ranges of each other (`reported`).
pub const REPORT_RANGES: f64 = 2.0;

/// Whether a pair has a row in the report of the step that ends (`links.csv`): its link was up
/// as the step ended or is up now, it carried or holds bytes or a connection, or its nodes are
/// within `within_m` of each other (or netem has no poses for them yet; `None`: any distance).
/// The pairs far apart — most of a big team's — have none: a report grows with the pairs near
/// each other, not with the team's n(n−1)/2 pairs.
fn reported(row: &LinkTelemetry, up_now: bool, within_m: Option<f64>) -> bool {
    let near = match (within_m, row.distance_m) {
        (Some(m), Some(d)) => d <= m,
        _ => true,
    };
    near || row.up
        || up_now
        || row.bytes_a_to_b + row.bytes_b_to_a + row.queued_bytes > 0
        || row.connections > 0
}

/// How long [`Netem::shutdown`] waits for connections to end by themselves before it resets them.
pub const SHUTDOWN_GRACE: Duration = Duration::from_secs(1);

/// Binds every listener (and the HTTP API), spawns the tasks. Needs a tokio runtime.
pub async fn start(cfg: NetemConfig) -> Result<Netem, NetemError> {
    validate(&cfg)?;
    let clock = match cfg.clock.mode {
        ClockMode::Lockstep => SimClock::lockstep(),
        ClockMode::Realtime => SimClock::realtime(cfg.clock.speedup),
    };
    if cfg.radio.model == RadioModel::Pathloss && cfg.truth.is_none() {
        tracing::warn!("path loss without a truth map: walls are not counted");
    }
    let rate = cfg.radio.bandwidth_bytes_per_s;
    let channel = Channel::new(channel_config(&cfg));
    let (shutdown, shutdown_rx) = watch::channel(false);
    let (links, listeners): (Vec<_>, Vec<_>) = bind_links(&cfg, &clock, &shutdown_rx)
        .await?
        .into_iter()
        .unzip();
    let radio = Radio::new(radio_model(&cfg), cfg.truth.map(Arc::new))
        .with_shadowing(cfg.seed, cfg.radio.shadowing_db);
    let interference = (cfg.radio.medium == Medium::Airtime)
        .then_some(cfg.radio.interference_range_m)
        .flatten()
        .map(|r| radio.with_range(r));
    let mut faults = cfg.faults;
    faults.sort_by_key(|f| f.step);
    // Faults scheduled for step 0 hold from the start, before any robot can connect.
    let initial = faults.iter().take_while(|f| f.step == 0).count();
    let shared = Arc::new(Shared {
        clock,
        by_pair: links
            .iter()
            .enumerate()
            .map(|(i, l)| ((l.params.a, l.params.b), i))
            .collect(),
        links,
        radio,
        report_within_m: (cfg.radio.model != RadioModel::Always)
            .then_some(REPORT_RANGES * cfg.radio.range_m),
        interference,
        channel: Mutex::new(channel),
        nodes_air: Mutex::new(Vec::new()),
        step_seconds: cfg.clock.step_seconds,
        markers: cfg.clock.marked(),
        steps: Mutex::new(StepState {
            step: None,
            poses: HashMap::new(),
            faults,
            next: initial,
        }),
        toxic_ids: AtomicU64::new(1),
        shutdown,
        api_token: cfg.api_token.clone(),
        process_desk: Mutex::new(None),
    });
    let due: Vec<Fault> = lock(&shared.steps).faults[..initial]
        .iter()
        .map(|f| f.fault.clone())
        .collect();
    for f in &due {
        shared.apply(f)?;
    }
    let mut tasks: Vec<JoinHandle<()>> = shared
        .links
        .iter()
        .zip(listeners)
        .map(|(l, listener)| l.serve(listener))
        .collect();
    let mut http_addr = None;
    if let Some(addr) = cfg.http {
        let (bound, task) = serve_http(addr, &shared, shutdown_rx).await?;
        http_addr = Some(bound);
        tasks.push(task);
    }
    tracing::info!(links = shared.links.len(), model = ?shared.radio.kind(), rate, "netem started");
    Ok(Netem {
        shared,
        tasks,
        http_addr,
    })
}

/// Binds each pair's listener (a pair that listens while up: none yet) and makes its link,
/// shaped by the scenario's `[radio]`.
async fn bind_links(
    cfg: &NetemConfig,
    clock: &SimClock,
    shutdown: &watch::Receiver<bool>,
) -> Result<Vec<(Arc<Link>, Option<TcpListener>)>, NetemError> {
    let rate = cfg.radio.bandwidth_bytes_per_s;
    let burst = |rate| burst_seconds(rate, cfg.clock.step_seconds, cfg.clock.marked());
    // In lockstep with markers a shared channel is netem's step plan (`channel`), not a budget
    // that would hold markers back; `airtime` exists only there.
    let medium = (rate > 0
        && cfg.radio.medium == Medium::Shared
        && !cfg.radio.allocates_airtime(&cfg.clock))
    .then(|| Budget::new(rate, burst(rate), true, clock.clone()));
    let ns = |ms: f64| (ms * 1e6).round() as u64;
    let mut links = Vec::new();
    for (i, p) in cfg.pairs.iter().enumerate() {
        let base = |_| BaseShape {
            budget: (rate > 0 && cfg.radio.medium == Medium::PerLink)
                .then(|| Budget::new(rate, burst(rate), false, clock.clone())),
            medium: medium.clone(),
            latency_ns: ns(cfg.radio.latency_ms),
            jitter_ns: ns(cfg.radio.jitter_ms),
        };
        let params = LinkParams {
            a: p.a,
            b: p.b,
            target: p.target,
            base: [0, 1].map(base),
            buffer_bytes: cfg.netem.buffer_bytes as usize,
            connect_timeout: Duration::from_millis(cfg.netem.connect_timeout_ms.max(1)),
            seed: cfg.seed ^ (i as u64).wrapping_mul(0x2545_F491_4F6C_DD1D),
            markers: cfg.clock.marked(),
        };
        let state = LinkState {
            enabled: true,
            alive: true,
            radio: None,
            always: cfg.radio.model == RadioModel::Always,
        };
        if p.while_up {
            let link = Link::while_up(
                params,
                p.listen.ip(),
                clock.clone(),
                state,
                shutdown.clone(),
            );
            links.push((link, None));
            continue;
        }
        let listener = TcpListener::bind(p.listen)
            .await
            .map_err(|source| NetemError::Bind {
                what: format!("link {}", faults::link_name(p.a, p.b)),
                addr: p.listen,
                source,
            })?;
        let listen = listener.local_addr().unwrap_or(p.listen);
        let link = Link::new(params, listen, clock.clone(), state, shutdown.clone());
        links.push((link, Some(listener)));
    }
    Ok(links)
}

/// Binds the HTTP API at `addr` and serves it until netem stops: the address bound, the task.
async fn serve_http(
    addr: SocketAddr,
    shared: &Arc<Shared>,
    shutdown: watch::Receiver<bool>,
) -> Result<(SocketAddr, JoinHandle<()>), NetemError> {
    let listener = TcpListener::bind(addr)
        .await
        .map_err(|source| NetemError::Bind {
            what: "the HTTP API".into(),
            addr,
            source,
        })?;
    let bound = listener.local_addr().unwrap_or(addr);
    Ok((
        bound,
        crate::http::serve(Arc::clone(shared), listener, shutdown),
    ))
}

impl Netem {
    /// The process faults the HTTP API is asked for from now on (`POST /processes/<name>`),
    /// each checked against `scenario` (its process is one of the run's, the action suits it),
    /// for the caller to forward to the launcher. Before this is called the API answers `501`:
    /// there is nobody to carry them out.
    pub fn process_orders(
        &self,
        scenario: &proto::scenario::Scenario,
    ) -> mpsc::Receiver<ProcessOrder> {
        let (orders, rx) = mpsc::channel(PROCESS_ORDERS_QUEUED);
        *lock(&self.shared.process_desk) = Some(ProcessDesk {
            scenario: scenario.clone(),
            orders,
        });
        rx
    }

    /// Advances the simulated clock to `step × step_seconds` (lockstep), applies the scheduled
    /// faults up to this step, and re-evaluates every link from the poses. Robots missing from
    /// `poses` keep their last pose and liveness.
    pub fn on_step(&self, step: Step, poses: &[(RobotId, Pose, bool)]) {
        self.update_links(step, poses);
        self.advance_clock(step);
    }

    /// Closes the step that ends and opens `step`, in the order that keeps the accounting exact:
    /// the links' state during the ending step is read first; then faults and radio verdicts
    /// take effect (a cut link delivers nothing more); then the ending step's byte counters are
    /// taken; only then does the clock advance, so the new step's budget cannot be spent before
    /// its bytes are counted in it. Returns the ending step's rows (none before the first step).
    pub fn advance(&self, step: Step, poses: &[(RobotId, Pose, bool)]) -> Vec<LinkTelemetry> {
        let ending = self.shared.step();
        // The ending step's bytes are taken before any link changes: a link that comes up now
        // lets its robots connect at once, and their first bytes belong to the new step (taken
        // after, they would land in the ending step or the next as threads happen to run).
        let before: Vec<_> = (self.shared.links.iter())
            .map(|l| {
                let bytes = Dir::BOTH.map(|d| l.counters(d).take_step());
                (l.snapshot(), bytes)
            })
            .collect();
        let carried = (self.shared.links.iter().zip(&before))
            .flat_map(|(l, (_, bytes))| {
                let (a, b) = (l.params.a, l.params.b);
                [((a, b), bytes[0]), ((b, a), bytes[1])]
            })
            .collect();
        let (nodes, air) = lock(&self.shared.channel).close(&carried);
        self.update_links(step, poses);
        let rows = self
            .shared
            .links
            .iter()
            .zip(&before)
            .filter_map(|(l, (snap, bytes))| {
                let bytes = *bytes;
                l.open_credit(bytes, self.shared.step_seconds);
                // Queues and connection counts as they are now (a link going down drops its
                // queue now; one coming up has none yet); the link's state and its byte totals
                // as the step ended.
                let was = telemetry_row(ending, snap, [0, 0]);
                let now = telemetry_row(ending, &l.snapshot(), bytes);
                // A link that was down held nothing as the step ended; if it comes up now, its
                // robots connect at once, and their first bytes belong to the new step.
                let queued = |q: u64| if was.up { q } else { 0 };
                let row = LinkTelemetry {
                    queued_bytes: queued(now.queued_bytes),
                    queued_a_to_b: queued(now.queued_a_to_b),
                    queued_b_to_a: queued(now.queued_b_to_a),
                    up: was.up,
                    bytes_a_to_b_total: was.bytes_a_to_b_total,
                    bytes_b_to_a_total: was.bytes_b_to_a_total,
                    chunks_a_to_b_total: was.chunks_a_to_b_total,
                    chunks_b_to_a_total: was.chunks_b_to_a_total,
                    // The connection as the step ended (a link going down resets it now);
                    // none on a link that was down (a connection held there is not one).
                    connections: if was.up { was.connections } else { 0 },
                    down_reason: was.down_reason,
                    distance_m: was.distance_m,
                    signal_dbm: was.signal_dbm,
                    walls: was.walls,
                    air: link_air(&air, l.params.a, l.params.b),
                    ..now
                };
                reported(&row, now.up, self.shared.report_within_m).then_some(row)
            })
            .collect();
        if ending.is_some() {
            *lock(&self.shared.nodes_air) = nodes;
        }
        self.open_channel(step);
        self.advance_clock(step);
        if ending.is_some() {
            rows
        } else {
            Vec::new()
        }
    }

    /// The plan of the step the last [`Self::advance`] opened: every link that is up, as
    /// [`Link::planned`] gives it.
    pub fn plan(&self) -> LinkPlan {
        let sh = &self.shared;
        let step_ns = (sh.step_seconds * 1e9).round() as u64;
        LinkPlan {
            step: sh.step().unwrap_or(0),
            links: sh.links.iter().filter_map(|l| l.planned(step_ns)).collect(),
        }
    }

    /// Each node's use of the radio channel in the last step [`Self::advance`] closed (empty
    /// unless the channel is shared or lossy).
    pub fn nodes_air(&self) -> Vec<NodeAir> {
        lock(&self.shared.nodes_air).clone()
    }

    /// The channel's shares and lost frames of `step`, onto the links the plan reads.
    fn open_channel(&self, step: Step) {
        let sh = &self.shared;
        let poses = lock(&sh.steps).poses.clone();
        let nodes: Vec<RobotId> = (poses.iter())
            .filter(|(_, (_, alive))| *alive)
            .map(|(id, _)| *id)
            .collect();
        let links: Vec<OpenLink> = (sh.links.iter())
            .map(|l| {
                let snap = l.snapshot();
                OpenLink {
                    a: l.params.a,
                    b: l.params.b,
                    usable: snap.up && !snap.held,
                    margin_db: snap.verdict.and_then(|v| v.margin_db),
                }
            })
            .collect();
        let hear = |a: RobotId, b: RobotId| match (poses.get(&a), poses.get(&b)) {
            (Some((pa, _)), Some((pb, _))) => match &sh.interference {
                Some(r) => r.evaluate_pair((a, b), pa, pb).in_range,
                None => sh.radio.evaluate_pair((a, b), pa, pb).in_range,
            },
            _ => false,
        };
        let air = lock(&sh.channel).open(step, &nodes, hear, &links);
        for l in &sh.links {
            let (a, b) = (l.params.a, l.params.b);
            let plan = |d| {
                air.get(&d).map_or(AirPlan::default(), |x| AirPlan {
                    credit: x.share.map(|s| {
                        s.saturating_add(x.saved)
                            .saturating_add(proto::msg::MARK_RESERVE_BYTES)
                    }),
                    lost: x.lost,
                })
            };
            l.set_air([plan((a, b)), plan((b, a))]);
        }
    }

    fn advance_clock(&self, step: Step) {
        let sh = &self.shared;
        sh.clock
            .advance_to(SimTime::from_secs_f64(f64::from(step) * sh.step_seconds));
    }

    fn update_links(&self, step: Step, poses: &[(RobotId, Pose, bool)]) {
        let sh = &self.shared;
        let due: Vec<Fault> = {
            let mut st = lock(&sh.steps);
            st.step = Some(step);
            for (id, pose, alive) in poses {
                st.poses.insert(*id, (*pose, *alive));
            }
            let start = st.next;
            while st.next < st.faults.len() && st.faults[st.next].step <= step {
                st.next += 1;
            }
            st.faults[start..st.next]
                .iter()
                .map(|f| f.fault.clone())
                .collect()
        };
        for f in &due {
            if let Err(e) = sh.apply(f) {
                tracing::warn!("scheduled fault at step {step} failed: {e}");
            }
        }
        let poses = lock(&sh.steps).poses.clone();
        for l in &sh.links {
            let pa = poses.get(&l.params.a);
            let pb = poses.get(&l.params.b);
            let verdict = match (pa, pb) {
                (Some((a, _)), Some((b, _))) => {
                    Some(sh.radio.evaluate_pair((l.params.a, l.params.b), a, b))
                }
                _ => None,
            };
            let alive = pa.is_none_or(|p| p.1) && pb.is_none_or(|p| p.1);
            l.update(|s| {
                s.radio = verdict.or(s.radio);
                s.alive = alive;
            });
        }
    }

    /// One row per link: state and counters; the per-step byte counters restart from zero.
    pub fn telemetry(&self) -> Vec<LinkTelemetry> {
        let step = self.shared.step();
        self.shared
            .links
            .iter()
            .map(|l| {
                let step_bytes = Dir::BOTH.map(|d| l.counters(d).take_step());
                telemetry_row(step, &l.snapshot(), step_bytes)
            })
            .collect()
    }

    /// Like [`Netem::telemetry`] without resetting the per-step counters (their byte fields
    /// read 0; the totals are current).
    pub fn snapshot(&self) -> Vec<LinkTelemetry> {
        self.shared.rows()
    }

    /// Applies a fault now.
    pub fn apply(&self, fault: Fault) -> Result<(), NetemError> {
        self.shared.apply(&fault)
    }

    pub fn http_addr(&self) -> Option<SocketAddr> {
        self.http_addr
    }

    /// The address pair (a, b)'s listener is bound to (the port chosen for port 0).
    pub fn listen_addr(&self, a: RobotId, b: RobotId) -> Option<SocketAddr> {
        self.shared.link((a, b)).ok().map(|l| l.listen())
    }

    /// The simulated time now.
    pub fn sim_time(&self) -> SimTime {
        self.shared.clock.now()
    }

    /// Resets every connection, stops every listener and task.
    /// Stops accepting, closes every connection and returns each link's final snapshot (its
    /// counters can no longer change).
    pub async fn shutdown(mut self) -> Vec<(LinkSnapshot, Vec<u16>)> {
        self.shared.shutdown.send_replace(true);
        // At the end of a run the robots are told to stop at the same time as netem: give their
        // connections a moment to end by themselves (every byte written is then sent or counted
        // lost by its sink), so that a reset here does not race bytes still leaving the kernel.
        // Held connections carry nothing: the stop above ended them at once (waiting for them
        // too kept every run a second longer, see `Link::hold`).
        let grace = tokio::time::Instant::now() + SHUTDOWN_GRACE;
        while self
            .shared
            .links
            .iter()
            .any(|l| l.has_connections_through())
            && tokio::time::Instant::now() < grace
        {
            tokio::time::sleep(Duration::from_millis(5)).await;
        }
        for l in &self.shared.links {
            l.close_all(Duration::from_millis(500)).await;
        }
        for t in self.tasks.drain(..) {
            if tokio::time::timeout(Duration::from_secs(1), &mut Box::pin(t))
                .await
                .is_err()
            {
                tracing::warn!("a netem task did not stop in time");
            }
        }
        self.shared.totals()
    }
}

impl Drop for Netem {
    fn drop(&mut self) {
        // Listeners stop; connections end when their peers go (or at `shutdown`).
        self.shared.shutdown.send_replace(true);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::faults::{Toxic, ToxicKind};
    use crate::link::tests::ends_within;
    use crate::link::DownReason;
    use tokio::io::{AsyncReadExt, AsyncWriteExt};
    use tokio::net::TcpStream;
    use tokio::sync::mpsc;

    /// Robots' radio listeners on loopback; `accepted[i]` yields what robot i accepts.
    struct Robots {
        addrs: Vec<SocketAddr>,
        accepted: Vec<mpsc::Receiver<TcpStream>>,
    }

    async fn robots(n: usize) -> Robots {
        let mut addrs = Vec::new();
        let mut accepted = Vec::new();
        for _ in 0..n {
            let l = TcpListener::bind("127.0.0.1:0").await.unwrap();
            addrs.push(l.local_addr().unwrap());
            let (tx, rx) = mpsc::channel(8);
            tokio::spawn(async move {
                while let Ok((s, _)) = l.accept().await {
                    if tx.send(s).await.is_err() {
                        break;
                    }
                }
            });
            accepted.push(rx);
        }
        Robots { addrs, accepted }
    }

    fn all_pairs(r: &Robots) -> Vec<PairSpec> {
        let n = r.addrs.len() as RobotId;
        let mut v = Vec::new();
        for a in 0..n {
            for b in a + 1..n {
                v.push(PairSpec {
                    a,
                    b,
                    listen: "127.0.0.1:0".parse().unwrap(),
                    target: r.addrs[b as usize],
                    while_up: false,
                });
            }
        }
        v
    }

    /// Every pair of `r` under a 10 m disk range with no rate limit.
    fn disk_10m(r: &Robots) -> NetemConfig {
        NetemConfig::new(
            all_pairs(r),
            radio(RadioModel::Disk, 10.0, 0, Medium::PerLink),
        )
    }

    fn radio(model: RadioModel, range_m: f64, rate: u64, medium: Medium) -> ScenarioRadio {
        ScenarioRadio {
            model,
            range_m,
            bandwidth_bytes_per_s: rate,
            medium,
            ..ScenarioRadio::default()
        }
    }

    fn at(x: f64, y: f64) -> Pose {
        Pose { x, y, theta: 0.0 }
    }

    /// Robot a connects through netem; returns (a's stream, b's accepted stream).
    async fn connect(n: &Netem, r: &mut Robots, a: RobotId, b: RobotId) -> (TcpStream, TcpStream) {
        let s = TcpStream::connect(n.listen_addr(a, b).unwrap())
            .await
            .unwrap();
        let t = tokio::time::timeout(Duration::from_secs(2), r.accepted[b as usize].recv())
            .await
            .expect("accepted in time")
            .unwrap();
        (s, t)
    }

    /// Writes forever into `s`.
    fn flood(mut s: tokio::net::tcp::OwnedWriteHalf) -> JoinHandle<()> {
        tokio::spawn(async move {
            let block = vec![0x55u8; 8192];
            while s.write_all(&block).await.is_ok() {}
        })
    }

    /// Reads forever from `s`, publishing the running total.
    fn count(mut s: tokio::net::tcp::OwnedReadHalf) -> (watch::Receiver<u64>, JoinHandle<()>) {
        let (tx, rx) = watch::channel(0u64);
        let task = tokio::spawn(async move {
            let mut buf = vec![0u8; 65536];
            let mut total = 0;
            while let Ok(n) = s.read(&mut buf).await {
                if n == 0 {
                    break;
                }
                total += n as u64;
                tx.send_replace(total);
            }
        });
        (rx, task)
    }

    #[tokio::test]
    async fn shutdown_resets_held_connections_at_once_and_gives_the_others_their_grace() {
        let mut r = robots(3).await;
        let cfg = disk_10m(&r);
        let n = start(cfg).await.unwrap();
        // 0–1 in range, 0–2 and 1–2 out of it.
        n.on_step(
            0,
            &[
                (0, at(0.0, 0.0), true),
                (1, at(5.0, 0.0), true),
                (2, at(50.0, 0.0), true),
            ],
        );
        let (mut a, mut b) = connect(&n, &mut r, 0, 1).await;
        a.write_all(b"x").await.unwrap();
        let mut buf = [0u8; 1];
        tokio::time::timeout(Duration::from_secs(2), b.read_exact(&mut buf))
            .await
            .unwrap()
            .unwrap();
        let mut held = TcpStream::connect(n.listen_addr(0, 2).unwrap())
            .await
            .unwrap();
        held.write_all(b"hello").await.unwrap();
        tokio::time::sleep(Duration::from_millis(50)).await;
        let started = std::time::Instant::now();
        let stopping = tokio::spawn(n.shutdown());
        // The held connection goes at once; the one through waits for its robots to close it.
        assert!(ends_within(&mut held, Duration::from_millis(500)).await);
        tokio::time::sleep(Duration::from_millis(100)).await;
        assert!(
            !stopping.is_finished(),
            "the connection through has its grace"
        );
        drop((a, b));
        tokio::time::timeout(Duration::from_secs(2), stopping)
            .await
            .unwrap()
            .unwrap();
        assert!(
            started.elapsed() < SHUTDOWN_GRACE,
            "{:?}",
            started.elapsed()
        );
    }

    /// A step's report holds the pairs near each other (up, or down within two ranges), not
    /// the pairs far apart; with `always` every pair.
    #[tokio::test]
    async fn a_report_holds_the_pairs_near_each_other_not_every_pair() {
        let r = robots(4).await;
        let n = start(disk_10m(&r)).await.unwrap();
        // 0–1 in range; 1–2 down but within 20 m; 3 far from everyone.
        let mut poses = vec![
            (0, at(0.0, 0.0), true),
            (1, at(5.0, 0.0), true),
            (2, at(20.0, 0.0), true),
            (3, at(200.0, 0.0), true),
        ];
        let pairs = |rows: &[LinkTelemetry]| rows.iter().map(|l| (l.a, l.b)).collect::<Vec<_>>();
        n.advance(0, &poses);
        let rows = n.advance(1, &poses);
        assert_eq!(pairs(&rows), [(0, 1), (0, 2), (1, 2)]);
        assert!(rows[0].up && !rows[1].up && !rows[2].up);
        // 1 goes far away: the step that ends was the one before, so every row is still
        // there; the step after, 0–1 (down) and 1–2 have none.
        poses[1].1 = at(5.0, 500.0);
        assert_eq!(pairs(&n.advance(2, &poses)), [(0, 1), (0, 2), (1, 2)]);
        assert_eq!(pairs(&n.advance(3, &poses)), [(0, 2)]);
        let all = start(NetemConfig::new(
            all_pairs(&r),
            radio(RadioModel::Always, 10.0, 0, Medium::PerLink),
        ))
        .await
        .unwrap();
        all.advance(0, &poses);
        assert_eq!(all.advance(1, &poses).len(), 6);
    }

    /// A shared channel in the step plan (issue #39): 3 robots that hear each other and a pair
    /// far from them on one 900 B/s channel. Each of the 3 gets a third of the channel, split
    /// over its two links; each of the pair half, on its one link (spatial reuse); every credit
    /// has the frame header's allowance on top. With `shared` all 5 take one channel.
    #[tokio::test]
    async fn airtime_shares_reach_the_plan_and_a_lost_frame_is_a_step_late() {
        let plan_of = |medium, frame_loss| {
            let r_radio = ScenarioRadio {
                frame_loss,
                ..radio(RadioModel::Disk, 10.0, 900, medium)
            };
            async move {
                let r = robots(5).await;
                let mut cfg = NetemConfig::new(all_pairs(&r), r_radio);
                cfg.clock.markers = true;
                let n = start(cfg).await.unwrap();
                let poses = [
                    (0, at(0.0, 0.0), true),
                    (1, at(3.0, 0.0), true),
                    (2, at(0.0, 3.0), true),
                    (3, at(100.0, 0.0), true),
                    (4, at(103.0, 0.0), true),
                ];
                let mut plans = Vec::new();
                for step in 0..40 {
                    n.advance(step, &poses);
                    plans.push(n.plan());
                }
                plans
            }
        };
        let reserve = proto::msg::MARK_RESERVE_BYTES;
        let credit = |p: &LinkPlan, a, b| p.link(a, b).unwrap().credit_from(a).unwrap();
        let plans = plan_of(Medium::Airtime, 0.0).await;
        let p = &plans[0];
        assert_eq!(
            p.links.len(),
            4,
            "three links in the group, one in the pair"
        );
        assert_eq!(credit(p, 0, 1), 150 + reserve, "{p:?}");
        assert_eq!(credit(p, 2, 1), 150 + reserve, "{p:?}");
        assert_eq!(credit(p, 3, 4), 450 + reserve, "{p:?}");
        assert!(p
            .links
            .iter()
            .all(|l| l.delay == [0, 0] && l.rate == [None, None]));
        let plans = plan_of(Medium::Shared, 0.0).await;
        // 900 over five senders, 180 each: the group's split over two links.
        assert_eq!(credit(&plans[0], 0, 1), 90 + reserve, "{:?}", plans[0]);
        assert_eq!(credit(&plans[0], 4, 3), 180 + reserve, "{:?}", plans[0]);
        // Lost frames: a step late, in both ways apart, at about the rate configured.
        let plans = plan_of(Medium::PerLink, 0.5).await;
        let late: usize = (plans.iter().flat_map(|p| &p.links))
            .map(|l| l.delay.iter().filter(|&&d| d == 1).count())
            .sum();
        assert!(
            (100..220).contains(&late),
            "{late} of 320 frames late at 50 % loss"
        );
        assert!(plans
            .iter()
            .flat_map(|p| &p.links)
            .all(|l| l.delay.iter().all(|&d| d <= 1)));
    }

    #[tokio::test]
    async fn disk_range_cuts_holds_and_restores_a_link() {
        let mut r = robots(2).await;
        let cfg = disk_10m(&r);
        let n = start(cfg).await.unwrap();
        assert!(!n.snapshot()[0].up, "no poses yet");
        n.on_step(0, &[(0, at(0.0, 0.0), true), (1, at(5.0, 0.0), true)]);
        let (mut a, mut b) = connect(&n, &mut r, 0, 1).await;
        a.write_all(b"map delta").await.unwrap();
        let mut buf = [0u8; 9];
        tokio::time::timeout(Duration::from_secs(2), b.read_exact(&mut buf))
            .await
            .unwrap()
            .unwrap();
        let t = n.telemetry();
        assert!(t[0].up);
        assert_eq!(t[0].distance_m, Some(5.0));
        assert_eq!(t[0].bytes_a_to_b, 9);
        assert_eq!(
            n.telemetry()[0].bytes_a_to_b,
            0,
            "per-step counters restart"
        );
        assert_eq!(n.telemetry()[0].bytes_a_to_b_total, 9);

        n.on_step(1, &[(1, at(20.0, 0.0), true)]);
        let t = n.telemetry();
        assert!(!t[0].up);
        assert_eq!(t[0].down_reason, Some(DownReason::OutOfRange));
        assert!(ends_within(&mut a, Duration::from_secs(2)).await);
        assert!(ends_within(&mut b, Duration::from_secs(2)).await);
        // A connection while the link is down is held: nothing reaches robot 1, nothing counts.
        let gone = TcpStream::connect(n.listen_addr(0, 1).unwrap())
            .await
            .unwrap();
        let mut a = TcpStream::connect(n.listen_addr(0, 1).unwrap())
            .await
            .unwrap();
        a.write_all(b"hello ").await.unwrap();
        drop(gone); // a robot that gives up waiting: dropped, never forwarded
        tokio::time::sleep(Duration::from_millis(100)).await;
        assert!(r.accepted[1].try_recv().is_err(), "nothing forwarded");
        assert_eq!(n.telemetry()[0].bytes_a_to_b, 0);

        // In range again: what robot 0 sent meanwhile goes first, then the rest.
        n.on_step(2, &[(1, at(8.0, 0.0), true)]);
        let mut b = tokio::time::timeout(Duration::from_secs(2), r.accepted[1].recv())
            .await
            .expect("forwarded once up")
            .unwrap();
        a.write_all(b"again").await.unwrap();
        let mut buf = [0u8; 11];
        tokio::time::timeout(Duration::from_secs(2), b.read_exact(&mut buf))
            .await
            .unwrap()
            .unwrap();
        assert_eq!(&buf, b"hello again");
        assert_eq!(n.telemetry()[0].bytes_a_to_b, 11);
        assert!(
            r.accepted[1].try_recv().is_err(),
            "the dropped one never went"
        );
        n.on_step(3, &[(1, at(8.0, 0.0), false)]);
        assert_eq!(n.telemetry()[0].down_reason, Some(DownReason::Dead));
        n.shutdown().await;
    }

    /// Bytes delivered per simulated second through a real proxy, stepping with `pause` of wall
    /// time per step (measured over steps `warmup..=steps`).
    async fn rate_through_proxy(
        rate: u64,
        medium: Medium,
        robots_n: usize,
        pause: Duration,
        steps: u32,
    ) -> (f64, Vec<u64>) {
        let warmup = 5;
        let mut r = robots(robots_n).await;
        let cfg = NetemConfig::new(all_pairs(&r), radio(RadioModel::Always, 1.0, rate, medium));
        let n = start(cfg).await.unwrap();
        n.on_step(0, &[]);
        let mut counters = Vec::new();
        let mut tasks = Vec::new();
        let pairs: Vec<(RobotId, RobotId)> = all_pairs(&r).iter().map(|p| (p.a, p.b)).collect();
        for (a, b) in pairs {
            let (sa, sb) = connect(&n, &mut r, a, b).await;
            let (_ra, wa) = sa.into_split();
            let (rb, _wb) = sb.into_split();
            tasks.push(flood(wa));
            let (rx, t) = count(rb);
            tasks.push(t);
            counters.push((rx, _ra, _wb));
        }
        tokio::time::sleep(Duration::from_millis(30)).await;
        let mut at_warmup = Vec::new();
        for step in 1..=steps {
            if step == warmup {
                at_warmup = counters.iter().map(|c| *c.0.borrow()).collect();
            }
            n.on_step(step, &[]);
            tokio::time::sleep(pause).await;
        }
        tokio::time::sleep(Duration::from_millis(20)).await;
        let per_link: Vec<u64> = counters
            .iter()
            .zip(&at_warmup)
            .map(|(c, w)| *c.0.borrow() - w)
            .collect();
        let total: u64 = per_link.iter().sum();
        for t in tasks {
            t.abort();
        }
        n.shutdown().await;
        (total as f64 / f64::from(steps - warmup + 1), per_link)
    }

    #[tokio::test(flavor = "multi_thread", worker_threads = 2)]
    async fn per_link_rate_within_5_percent_at_any_simulation_speed() {
        for rate in [1000u64, 10_000] {
            for pause in [Duration::from_millis(2), Duration::from_millis(25)] {
                let (per_s, _) = rate_through_proxy(rate, Medium::PerLink, 2, pause, 40).await;
                let err = (per_s - rate as f64).abs() / rate as f64;
                assert!(
                    err <= 0.05,
                    "rate {rate}, {pause:?} per step: {per_s} B per simulated s"
                );
            }
        }
    }

    #[tokio::test(flavor = "multi_thread", worker_threads = 2)]
    async fn a_shared_medium_is_one_budget_for_all_links() {
        let rate = 6000;
        let (per_s, per_link) =
            rate_through_proxy(rate, Medium::Shared, 3, Duration::from_millis(10), 40).await;
        let err = (per_s - rate as f64).abs() / rate as f64;
        assert!(err <= 0.05, "sum {per_s} B per simulated s: {per_link:?}");
        assert!(
            per_link.iter().all(|&b| b > 0),
            "every link gets a share: {per_link:?}"
        );
    }

    #[tokio::test(flavor = "multi_thread", worker_threads = 2)]
    async fn realtime_mode_paces_by_wall_time_times_speedup() {
        let mut r = robots(2).await;
        let mut cfg = NetemConfig::new(
            all_pairs(&r),
            radio(RadioModel::Always, 1.0, 1000, Medium::PerLink),
        );
        cfg.clock.mode = ClockMode::Realtime;
        cfg.clock.speedup = 20.0;
        let n = start(cfg).await.unwrap();
        let (sa, sb) = connect(&n, &mut r, 0, 1).await;
        let (_ra, wa) = sa.into_split();
        let (rb, _wb) = sb.into_split();
        let f = flood(wa);
        let (rx, c) = count(rb);
        let t0 = n.sim_time();
        tokio::time::sleep(Duration::from_millis(1000)).await;
        let sim_s = (n.sim_time().0 - t0.0) as f64 / 1e9;
        let got = *rx.borrow() as f64;
        // One step's burst (1000 B) plus 1000 B per simulated second.
        let want = 1000.0 + 1000.0 * sim_s;
        assert!(
            (got - want).abs() / want < 0.1,
            "{got} B in {sim_s} simulated s"
        );
        f.abort();
        c.abort();
        n.shutdown().await;
    }

    #[tokio::test]
    async fn scheduled_faults_apply_at_their_step() {
        let r = robots(3).await;
        let mut cfg = NetemConfig::new(
            all_pairs(&r),
            radio(RadioModel::Always, 1.0, 0, Medium::PerLink),
        );
        cfg.faults = vec![
            ScheduledFault {
                step: 4,
                fault: Fault::Heal,
            },
            ScheduledFault {
                step: 2,
                fault: Fault::Partition {
                    groups: vec![vec![0, 1], vec![2]],
                },
            },
            ScheduledFault {
                step: 1,
                fault: Fault::Cut { pair: (0, 1) },
            },
            ScheduledFault {
                step: 3,
                fault: Fault::Restore { pair: (0, 1) },
            },
        ];
        let n = start(cfg).await.unwrap();
        let ups = |n: &Netem| n.telemetry().iter().map(|t| t.up).collect::<Vec<_>>();
        n.on_step(0, &[]);
        assert_eq!(ups(&n), [true, true, true]);
        n.on_step(1, &[]);
        assert_eq!(ups(&n), [false, true, true]);
        // Steps may be skipped: everything up to the current step applies, in order.
        n.on_step(3, &[]);
        assert_eq!(ups(&n), [true, false, false]);
        n.on_step(4, &[]);
        assert_eq!(ups(&n), [true, true, true]);
        assert!(n.apply(Fault::Cut { pair: (0, 7) }).is_err());
        assert!(n
            .apply(Fault::Partition {
                groups: vec![vec![9]]
            })
            .is_err());
        n.shutdown().await;
    }

    #[tokio::test]
    async fn toxics_through_apply_and_reset_all() {
        let mut r = robots(2).await;
        let cfg = NetemConfig::new(
            all_pairs(&r),
            radio(RadioModel::Always, 1.0, 0, Medium::PerLink),
        );
        let n = start(cfg).await.unwrap();
        n.on_step(0, &[]);
        let (mut a, mut b) = connect(&n, &mut r, 0, 1).await;
        n.apply(Fault::blackhole(Some((0, 1)))).unwrap();
        a.write_all(b"stuck").await.unwrap();
        let mut buf = [0u8; 5];
        assert!(
            tokio::time::timeout(Duration::from_millis(100), b.read_exact(&mut buf))
                .await
                .is_err()
        );
        assert_eq!(n.snapshot()[0].queued_a_to_b, 5);
        n.apply(Fault::RemoveToxic {
            pair: Some((0, 1)),
            name: "blackhole".into(),
        })
        .unwrap();
        tokio::time::timeout(Duration::from_secs(2), b.read_exact(&mut buf))
            .await
            .unwrap()
            .unwrap();
        assert_eq!(&buf, b"stuck");
        n.apply(Fault::limit_data(None, 3)).unwrap();
        assert!(matches!(
            n.apply(Fault::AddToxic {
                pair: None,
                toxic: Toxic::both(ToxicKind::LimitData { bytes: 1 })
            }),
            Err(NetemError::ToxicExists { .. })
        ));
        a.write_all(b"abcdef").await.unwrap();
        let mut got = Vec::new();
        let _ = tokio::time::timeout(Duration::from_secs(2), b.read_to_end(&mut got)).await;
        assert_eq!(got, b"abc");
        n.apply(Fault::ResetAll).unwrap();
        assert_eq!(n.snapshot()[0].toxics, 0);
        assert!(matches!(
            n.apply(Fault::RemoveToxic {
                pair: None,
                name: "nope".into()
            }),
            Err(NetemError::UnknownToxic { .. })
        ));
        n.apply(Fault::Reset { pair: None }).unwrap();
        n.shutdown().await;
    }

    #[tokio::test]
    async fn pathloss_counts_walls_on_the_truth_map() {
        let r = robots(2).await;
        let mut cfg = NetemConfig::new(
            all_pairs(&r),
            radio(RadioModel::Pathloss, 6.0, 0, Medium::PerLink),
        );
        let g = Grid::from_ascii("..#.....\n........\n");
        let map = MapInfo::at_origin(g.width(), g.height(), 1.0);
        cfg.truth = Some((map, g));
        cfg.radio.pathloss_wall_attenuation_db = 10.0;
        let n = start(cfg).await.unwrap();
        n.on_step(0, &[(0, at(0.5, 0.5), true), (1, at(5.5, 0.5), true)]);
        let t = &n.telemetry()[0];
        assert!(t.up, "5 m in free space: {t:?}");
        assert_eq!(t.walls, Some(0));
        n.on_step(1, &[(0, at(0.5, 1.5), true), (1, at(5.5, 1.5), true)]);
        let t = &n.telemetry()[0];
        assert!(!t.up, "5 m through a 10 dB wall: {t:?}");
        assert_eq!(t.walls, Some(1));
        n.shutdown().await;
    }

    #[tokio::test]
    async fn a_scenario_gives_the_config_and_its_faults_are_checked_at_start() {
        let r = robots(3).await;
        let fault: toml::Table = "step = 5\nkind = \"cut\"\npair = [0, 2]\n".parse().unwrap();
        let mut sc = proto::scenario::Scenario {
            seed: 9,
            faults: vec![fault],
            ..Default::default()
        };
        let cfg = NetemConfig::from_scenario(&sc, all_pairs(&r), None, None).unwrap();
        assert_eq!(cfg.seed, 9);
        assert_eq!(cfg.faults[0].fault, Fault::Cut { pair: (0, 2) });
        assert_eq!(cfg.radio, sc.radio);
        let n = start(cfg.clone()).await.unwrap();
        n.shutdown().await;
        sc.faults[0].insert("pair".into(), toml::Value::try_from([0, 7]).unwrap());
        let cfg = NetemConfig::from_scenario(&sc, all_pairs(&r), None, None).unwrap();
        let e = start(cfg).await.err().unwrap();
        assert!(matches!(e, NetemError::BadFault { index: 0, .. }), "{e}");
        sc.faults[0].insert("kind".into(), "nope".into());
        let e = NetemConfig::from_scenario(&sc, all_pairs(&r), None, None)
            .err()
            .unwrap();
        assert!(e.to_string().starts_with("faults[0]:"), "{e}");
    }

    #[tokio::test]
    async fn bad_configurations_and_taken_ports_are_errors() {
        let r = robots(2).await;
        let mut cfg = disk_10m(&r);
        cfg.clock.step_seconds = 0.0;
        assert!(matches!(
            start(cfg.clone()).await,
            Err(NetemError::Config(_))
        ));
        cfg.clock.step_seconds = 1.0;
        cfg.pairs[0].a = 1;
        assert!(matches!(
            start(cfg.clone()).await,
            Err(NetemError::Config(_))
        ));
        let taken = TcpListener::bind("127.0.0.1:0").await.unwrap();
        let mut cfg = disk_10m(&r);
        cfg.pairs[0].listen = taken.local_addr().unwrap();
        let e = start(cfg).await.err().unwrap();
        assert!(e.to_string().contains("r0-r1"), "{e}");
    }
}
